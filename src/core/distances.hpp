// The compiled distance query of kinredund.geometry (issue 24): placements, the bounding-sphere broadphase,
// coal's exact signed distances, witness points, unit normals and the distance rows, in one call per query.
#pragma once

#include <nanobind/nanobind.h>

namespace kinredund {

// Adds the classes `DistanceQuery` and `RowGuard` to the module (kinredund/geometry/engine.py describes what they
// compute). RowGuard is a RowSource (rows.hpp): the core's step holds it through that interface.
void bind_distances(nanobind::module_& m);

}  // namespace kinredund
