// kinredund._core: the joint-level IK's constrained iteration in C++ (issue 28; kinredund/ik/compiled.py drives it).
#pragma once

#include <nanobind/nanobind.h>

namespace kinredund {

// Binds the class IKCore into the module (called from NB_MODULE in module.cpp).
void bind_ik(nanobind::module_& m);

}  // namespace kinredund
