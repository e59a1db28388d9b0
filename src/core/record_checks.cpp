// What a finished run says about itself (issue 26), in one call (issue 28): kinredund/tracking/record_checks.py's
// burst_candidate on a record's joints, which track() checks after every run with the GIL held (numpy's reductions
// over a record's few joints, row by row, cost more than the check). The same numbers as numpy's: the differences,
// their absolute values and maxima are exact; the median is the middle value or the mean (a + b) / 2 of the middle
// two, as record_checks.median takes it. And the record's loop drifts and each joint's fastest rate
// (kinredund/tracking/recorder.py: Recorder.trajectory), numpy's numbers (see record_extremes). Both keep the GIL:
// they take a few microseconds, less than handing the GIL to another of track_many's threads and waiting to get it
// back (each release is a hand-over where another thread waits for it).
#include "record_checks.hpp"

#include "arrays.hpp"

#include <nanobind/ndarray.h>

#include <algorithm>
#include <cmath>
#include <vector>

namespace nb = nanobind;

namespace kinredund {

namespace {

using Joints = nb::ndarray<const double, nb::ndim<2>, nb::c_contig, nb::device::cpu>;

// The step k (from row k to k + 1) whose largest joint change max_j |q[k+1, j] - q[k, j]| is the largest (the first
// within a factor 1 - tie of it: equal steps of two loops differ by rounding, which must not choose between them)
// where it is more than ``ratio`` times the median of them all; -1 where there is none, and where a change is not a
// number (numpy's largest would be that NaN, which is no burst). At least two rows.
long burst_candidate(const Joints& q, double ratio, double tie) {
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
  const double largest = *std::max_element(d.begin(), d.end());
  const double near = largest * (1.0 - tie);
  const size_t k = static_cast<size_t>(std::find_if(d.begin(), d.end(), [near](double x) { return x >= near; }) -
                                       d.begin());  // the first as large as the largest, to the tie
  const size_t h = steps / 2;
  std::nth_element(d.begin(), d.begin() + h, d.end());
  double median = d[h];
  if (steps % 2 == 0) median = (*std::max_element(d.begin(), d.begin() + h) + median) / 2.0;
  return largest > ratio * median ? static_cast<long>(k) : -1;
}

using Mask = nb::ndarray<const bool, nb::ndim<1>, nb::c_contig, nb::device::cpu>;

// numpy's float remainder x % b (npy_divmod's: fmod, then the divisor's sign), for b > 0
double remainder(double x, double b) {
  double mod = std::fmod(x, b);
  if (mod != 0.0) {
    if ((b < 0.0) != (mod < 0.0)) mod += b;
  } else {
    mod = std::copysign(0.0, b);
  }
  return mod;
}

// max(a, b) as numpy's maximum: a NaN in either is the result
double nan_max(double a, double b) { return (std::isnan(a) || a >= b) ? a : b; }

// Recorder.trajectory's extremes of a record, numpy's numbers (kinredund.kinematics.angles.loop_drifts; the fastest
// |qdot| per joint): drift[i] = max_j |wrap(q[(i + 1) spl, j] - q[0, j])| for i < drift's size (wrap: the revolute
// joints' differences into [-pi, pi) as (d + pi) % (2 pi) - pi, numpy's remainder), fastest[j] = max_k |qdot[k, j]|
// (NaN where an entry is NaN, as numpy's max). qdot with no rows leaves fastest unwritten.
void record_extremes(const Joints& q, const Joints& qdot, const Mask& revolute, long steps_per_loop, OutVec drift,
                     OutVec fastest) {
  const size_t rows = q.shape(0), n = q.shape(1), loops = drift.shape(0);
  if (revolute.shape(0) != n) throw nb::value_error("revolute must have an entry per column of q");
  if (loops > 0 && (steps_per_loop < 1 || loops * static_cast<size_t>(steps_per_loop) >= rows))
    throw nb::value_error("q must have more than loops x steps_per_loop rows");
  if (qdot.shape(0) > 0 && (qdot.shape(1) != n || fastest.shape(0) != n))
    throw nb::value_error("qdot and fastest must have q's columns");
  const double pi = M_PI, two_pi = 2.0 * M_PI;
  const double* a = q.data();
  const bool* rev = revolute.data();
  double* out = drift.data();
  for (size_t i = 0; i < loops; ++i) {
    const double* end = a + (i + 1) * static_cast<size_t>(steps_per_loop) * n;
    double m = 0.0;
    for (size_t j = 0; j < n; ++j) {
      const double d = end[j] - a[j];
      const double x = std::fabs(rev[j] ? remainder(d + pi, two_pi) - pi : d);
      m = j == 0 ? x : nan_max(m, x);
    }
    out[i] = m;
  }
  const size_t k = qdot.shape(0);
  if (k == 0) return;
  const double* r = qdot.data();
  double* f = fastest.data();
  for (size_t j = 0; j < n; ++j) f[j] = std::fabs(r[j]);
  for (size_t s = 1; s < k; ++s)
    for (size_t j = 0; j < n; ++j) f[j] = nan_max(f[j], std::fabs(r[s * n + j]));
}

}  // namespace

void bind_record_checks(nb::module_& m) {
  m.def("burst_candidate", &burst_candidate, nb::arg("q"), nb::arg("ratio"), nb::arg("tie"),
        "record_checks.burst_candidate's step, -1 for none (see src/core/record_checks.cpp).");
  m.def("record_extremes", &record_extremes, nb::arg("q"), nb::arg("qdot"), nb::arg("revolute"),
        nb::arg("steps_per_loop"), nb::arg("drift"), nb::arg("fastest"),
        "A record's loop drifts and each joint's fastest |qdot| into drift and fastest (see "
        "src/core/record_checks.cpp).");
}

}  // namespace kinredund
