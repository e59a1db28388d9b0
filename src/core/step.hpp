// kinredund._core: the default mode's ordinary step in C++ (issue 28; kinredund/tracking/compiled.py drives it).
#pragma once

#include <nanobind/nanobind.h>

#include <Eigen/Core>

#include <cstdint>

#include <vector>

namespace kinredund {

// Binds the class StepCore into the module (called from NB_MODULE in module.cpp).
void bind_step(nanobind::module_& m);

// For runs of steps in C++ (loop.cpp): a StepCore used through these functions, which touch no Python object.
class StepCore;
// One step's inputs as raw arrays: the path sample's p, v (3), Q (3x3 row-major) and omega (3) (Q and omega null
// for a task without orientation), and a time-varying index's theta*(t) and its rate (n; null otherwise).
struct StepInput {
  const double *p, *v, *Q, *omega, *ref, *rate;
};
// The StepCore that a Python object holds (TypeError otherwise; needs the GIL).
StepCore& step_core(nanobind::handle obj);
// (n, m, the length of one step's output row: StepCore.step's array).
void step_core_sizes(const StepCore& core, int& n, int& m, int& row);
// The general rows the core holds (StepCore.set_rows; m counts them), or null: none.
class RowSource;
using RowIndicesPtr = const Eigen::Matrix<std::int64_t, Eigen::Dynamic, 1>*;
RowIndicesPtr step_core_held_rows(const StepCore& core);
// The row check that step_guarded runs after a step (StepCore.set_guard; rows.hpp), or null: none.
RowSource* step_core_guard(const StepCore& core);
// The free joints' numbers (ascending; all n where no joint is held: StepCore.set_active), nf of them.
const int* step_core_free(const StepCore& core, int& nf);
// R's LU factors of the last step (N x N column-major, LAPACK's layout) and their 0-based pivots (StepCore.factors).
const double* step_core_factors(const StepCore& core, const int*& piv, int& N);
// StepCore.step without Python objects: writes the output row into ``out`` and returns the status (0: ordinary).
int step_core_advance(StepCore& core, const StepInput& in, const double* y, const double* yd,
                      const std::vector<const double*>& prev, const double* qdot0, double speed2, bool check_jump,
                      double* out);

}  // namespace kinredund
