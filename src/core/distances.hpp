// The compiled distance query of kinredund.geometry (issue 24): placements, the bounding-sphere broadphase,
// coal's exact signed distances, witness points, unit normals and the distance rows, in one call per query.
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <nanobind/nanobind.h>

namespace kinredund {

// Adds the classes `DistanceQuery` and `RowGuard` to the module (kinredund/geometry/engine.py describes what they
// compute).
void bind_distances(nanobind::module_& m);

// For the core's step (step.cpp): a scene's row check of a step (issue 27), used through these functions.
class RowGuard;
// The RowGuard that a Python object holds (TypeError otherwise; needs the GIL).
RowGuard& row_guard(nanobind::handle obj);
// The number of joint velocities its arrays have.
Eigen::Index row_guard_nv(const RowGuard& guard);
// RowGuard.clear on raw arrays of nv entries, touching no Python object (call it with the GIL released); `held`: the
// rows held during the step, left out of its tests (null: none).
using RowIndices = Eigen::Matrix<std::int64_t, Eigen::Dynamic, 1>;
bool row_guard_clear(RowGuard& guard, const double* q0, const double* q1, const double* v0, const double* v1,
                     double h, const RowIndices* held = nullptr);
// RowGuard.smallest: min c at the last check's end [m] (exact at or below skip, else a lower bound; NaN: no values).
double row_guard_smallest(const RowGuard& guard);

// For the core's step with a scene's rows held (issue 28; call them with the GIL released):
using RowMajorMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
// the guard's number of rows, and whether row `row` has a pair (a row without one is constant)
Eigen::Index row_guard_size(const RowGuard& guard);
bool row_guard_has_pair(const RowGuard& guard, Eigen::Index row);
// rows' values c [m] and gradients G (rows x nv) [m/rad] at q, as SceneClearance._query gives them
void row_guard_rows(RowGuard& guard, const Eigen::Ref<const Eigen::VectorXd>& q, const RowIndices& rows,
                    Eigen::VectorXd& c, RowMajorMatrix& G);
// the central differences of the rows' gradients at q, step eps (nv blocks of rows x nv: DistanceQuery.differences)
void row_guard_differences(RowGuard& guard, const Eigen::Ref<const Eigen::VectorXd>& q, const RowIndices& rows,
                           double eps, RowMajorMatrix& D);

}  // namespace kinredund
