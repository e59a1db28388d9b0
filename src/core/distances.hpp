// The compiled distance query of kinredund.geometry (issue 24): placements, the bounding-sphere broadphase,
// coal's exact signed distances, witness points, unit normals and the distance rows, in one call per query.
#pragma once

#include <Eigen/Core>
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
// RowGuard.clear on raw arrays of nv entries, touching no Python object (call it with the GIL released).
bool row_guard_clear(RowGuard& guard, const double* q0, const double* q1, const double* v0, const double* v1,
                     double h);
// RowGuard.smallest: min c at the last check's end [m] (exact at or below skip, else a lower bound; NaN: no values).
double row_guard_smallest(const RowGuard& guard);

}  // namespace kinredund
