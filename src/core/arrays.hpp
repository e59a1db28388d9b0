// The numpy arrays the core's bindings take (nanobind): C-contiguous doubles on the CPU, read or written in place.
#pragma once

#include <nanobind/ndarray.h>

namespace kinredund {

using InVec = nanobind::ndarray<const double, nanobind::ndim<1>, nanobind::c_contig, nanobind::device::cpu>;
using InMat = nanobind::ndarray<const double, nanobind::ndim<2>, nanobind::c_contig, nanobind::device::cpu>;
using OutVec = nanobind::ndarray<double, nanobind::ndim<1>, nanobind::c_contig, nanobind::device::cpu>;
using OutMat = nanobind::ndarray<double, nanobind::ndim<2>, nanobind::c_contig, nanobind::device::cpu>;

}  // namespace kinredund
