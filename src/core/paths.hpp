// kinredund._core: a path's samples at many times together (issue 28; paths.cpp).
#pragma once

#include <nanobind/nanobind.h>

namespace kinredund {

// Binds cos_sin and circle_samples into the module (called from NB_MODULE in module.cpp).
void bind_paths(nanobind::module_& m);

}  // namespace kinredund
