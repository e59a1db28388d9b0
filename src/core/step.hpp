// kinredund._core: the default mode's ordinary step in C++ (issue 28; kinredund/tracking/compiled.py drives it).
#pragma once

#include <nanobind/nanobind.h>

namespace kinredund {

// Binds the class StepCore into the module (called from NB_MODULE in module.cpp).
void bind_step(nanobind::module_& m);

}  // namespace kinredund
