// What a finished run says about itself (issue 26), in one call (issue 28): kinredund/tracking/record_checks.py's
// burst_candidate on a record's joints, which track() checks after every run with the GIL held (numpy's reductions
// over a record's few joints, row by row, cost more than the check). The same numbers as numpy's: the differences,
// their absolute values and maxima are exact; the median is the middle value or the mean (a + b) / 2 of the middle
// two, as record_checks.median takes it.
#include "record_checks.hpp"

#include <nanobind/ndarray.h>

#include <algorithm>
#include <cmath>
#include <vector>

namespace nb = nanobind;

namespace kinredund {

namespace {

using Joints = nb::ndarray<const double, nb::ndim<2>, nb::c_contig, nb::device::cpu>;

// The step k (from row k to k + 1) whose largest joint change max_j |q[k+1, j] - q[k, j]| is the largest (the first
// such) where it is more than ``ratio`` times the median of them all; -1 where there is none, and where a change is
// not a number (numpy's largest would be that NaN, which is no burst). At least two rows.
long burst_candidate(const Joints& q, double ratio) {
  const size_t rows = q.shape(0), n = q.shape(1);
  if (rows < 2 || n < 1) throw nb::value_error("q must have at least 2 rows and 1 column");
  const size_t steps = rows - 1;
  std::vector<double> d(steps);
  const double* a = q.data();
  for (size_t k = 0; k < steps; ++k) {
    const double* row = a + k * n;
    double m = std::fabs(row[n] - row[0]);
    for (size_t j = 1; j < n; ++j) {
      const double x = std::fabs(row[n + j] - row[j]);
      if (std::isnan(x)) return -1;
      if (x > m) m = x;
    }
    if (std::isnan(m)) return -1;
    d[k] = m;
  }
  const size_t k = static_cast<size_t>(std::max_element(d.begin(), d.end()) - d.begin());  // the first largest
  const double largest = d[k];
  const size_t h = steps / 2;
  std::nth_element(d.begin(), d.begin() + h, d.end());
  double median = d[h];
  if (steps % 2 == 0) median = (*std::max_element(d.begin(), d.begin() + h) + median) / 2.0;
  return largest > ratio * median ? static_cast<long>(k) : -1;
}

}  // namespace

void bind_record_checks(nb::module_& m) {
  m.def("burst_candidate", &burst_candidate, nb::arg("q"), nb::arg("ratio"),
        "record_checks.burst_candidate's step, -1 for none (see src/core/record_checks.cpp).");
}

}  // namespace kinredund
