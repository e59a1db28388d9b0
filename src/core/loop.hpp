// kinredund._core: runs of ordinary steps in one call, the GIL released (issue 28; loop.cpp).
#pragma once

#include <nanobind/nanobind.h>

namespace kinredund {

// Binds run_steps into the module (called from NB_MODULE in module.cpp).
void bind_loop(nanobind::module_& m);

}  // namespace kinredund
