// A constraint's general rows as the core's step sees them (issues 27, 28): the check of a step for a row switch
// and, for the rows held, their values, gradients and curvature. Two sources implement it: a scene's distance rows
// (distances.cpp's RowGuard) and a frame origin's clearance of a sphere or a plane (frame_rows.cpp's FrameRows);
// several constraints' rows are one source (row_stack.cpp's RowStack).
// The step (step.cpp, StepCore.set_guard and set_rows) and its runs (loop.cpp) call them with the GIL released.
#pragma once

#include <nanobind/nanobind.h>

#include <Eigen/Core>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>

namespace kinredund {

using RowIndices = Eigen::Matrix<std::int64_t, Eigen::Dynamic, 1>;
using RowMajorMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

class RowSource {
 public:
  virtual ~RowSource() = default;
  // the number of joint velocities its arrays have, and of its rows
  virtual Eigen::Index nv() const = 0;
  virtual Eigen::Index size() const = 0;
  // can the step hold row `row` (a scene's row needs its pair: a row without one is constant)?
  virtual bool holdable(Eigen::Index row) const = 0;
  // The check of a step on raw arrays of nv entries, touching no Python object: true where no row can switch within
  // it (none below -tol at q1, none able to dip below -tol between, by the constraint's segment_lower_bounds over the
  // step's joint motion). `held`: the rows held during the step, left out of both tests (null: none).
  virtual bool clear_at(const double* q0, const double* q1, const double* v0, const double* v1, double h,
                        const RowIndices* held) = 0;
  // min c at the last check's end [m] (NaN where that check stopped before its values)
  virtual double smallest() const = 0;
  // rows' values c [m] and gradients G (rows x nv) [m/rad] at q, as the constraint's rows_at gives them
  virtual void rows_at(const Eigen::Ref<const Eigen::VectorXd>& q, const RowIndices& rows, Eigen::VectorXd& c,
                       RowMajorMatrix& G) = 0;
  // M += sum_i w_i Hess c_i (n x n, symmetrised) over `rows` at q, as the constraint's curvature gives it (`eps`: the
  // step of central differences where the constraint takes them)
  virtual void add_curvature(const Eigen::Ref<const Eigen::VectorXd>& q, const RowIndices& rows,
                             const Eigen::VectorXd& w, double eps, RowMajorMatrix& M) = 0;
};

// The least entry of v but the held rows' (they are left out of a check's tests; null: none). A NaN is returned
// where it is met, so that the test on the result fails.
inline double least_but(const Eigen::VectorXd& v, const RowIndices* held) {
  if (held == nullptr || held->size() == 0) return v.hasNaN() ? std::numeric_limits<double>::quiet_NaN() : v.minCoeff();
  double out = std::numeric_limits<double>::infinity();
  for (Eigen::Index r = 0; r < v.size(); ++r) {
    bool skip = false;
    for (Eigen::Index i = 0; i < held->size(); ++i) skip = skip || (*held)[i] == r;
    if (skip) continue;
    if (std::isnan(v[r])) return v[r];
    out = std::min(out, v[r]);
  }
  return out;
}

// The joints' motion bound along a step of h [s] from q0 with rates v0 to q1 with rates v1 (switches.segment_move):
// max(|q1 - q0|, h max(|v0|, |v1|)) + h |v1 - v0| / 4, per joint.
template <class V>
void segment_move(const V& q0, const V& q1, const V& v0, const V& v1, double h, Eigen::VectorXd& move) {
  move = (q1 - q0).cwiseAbs().cwiseMax(h * v0.cwiseAbs().cwiseMax(v1.cwiseAbs())) + 0.25 * h * (v1 - v0).cwiseAbs();
}

// The RowSource that a Python object holds (TypeError otherwise; needs the GIL).
RowSource& row_source(nanobind::handle obj);

// Binds the base class RowSource (before the classes derived from it).
void bind_row_source(nanobind::module_& m);

// Adds the class FrameRows to the module (frame_rows.cpp).
void bind_frame_rows(nanobind::module_& m);

// Adds the class RowStack to the module (row_stack.cpp).
void bind_row_stack(nanobind::module_& m);

}  // namespace kinredund
