// kinredund._core: the record's checks after a run (issue 28; record_checks.cpp).
#pragma once

#include <nanobind/nanobind.h>

namespace kinredund {

// Binds burst_candidate into the module (called from NB_MODULE in module.cpp).
void bind_record_checks(nanobind::module_& m);

}  // namespace kinredund
