// A path's samples at many times in one call (issue 28): kinredund/paths/analytic.py's sample_many of the circle
// (Circle.sample's operations, entry by entry: the same numbers) and the cosines and sines of the other paths. The
// runs of steps (kinredund/tracking/runs.py) sample the path ahead once per run with the GIL held (a run's 200 samples
// take ~20 us: releasing the GIL there hands it to another of track_many's threads, which this one then waits for,
// and two threads ran slower so: benchmarks/many.py); numpy's calls on rows of three cost more than the sampling.
//
// The same numbers as Python's: cos and sin are the C library's, called through pointers as math.cos and math.sin
// call them (the compiler can neither fuse a pair into one sincos nor vectorise them), and each product and sum is
// rounded on its own as Python rounds it (this file is compiled with -ffp-contract=off: no fused multiply-add,
// CMakeLists.txt). An angle that is not finite writes nothing and returns false: the caller takes Python's route,
// where math.cos raises on +-inf as Circle.sample does.
#include "paths.hpp"

#include "arrays.hpp"

#include <nanobind/ndarray.h>

#include <cmath>
#include <string>

namespace nb = nanobind;

namespace kinredund {

namespace {


double (*volatile cos_of)(double) = &::cos;
double (*volatile sin_of)(double) = &::sin;

void check_shape(size_t rows, size_t cols, size_t want_rows, size_t want_cols, const char* name) {
  if (rows != want_rows || cols != want_cols)
    throw nb::value_error((std::string(name) + " must have shape (" + std::to_string(want_rows) + ", " +
                           std::to_string(want_cols) + ")").c_str());
}

// cos and sin of each angle into c and s; false, nothing written, where an angle is not finite.
bool cos_sin(const InVec& a, OutVec c, OutVec s) {
  const size_t k = a.shape(0);
  if (c.shape(0) != k || s.shape(0) != k)
    throw nb::value_error(("c and s must have " + std::to_string(k) + " entries, as the angles").c_str());
  const double* x = a.data();
  for (size_t i = 0; i < k; ++i)
    if (!std::isfinite(x[i])) return false;
  double* cv = c.data();
  double* sv = s.data();
  for (size_t i = 0; i < k; ++i) cv[i] = cos_of(x[i]);
  for (size_t i = 0; i < k; ++i) sv[i] = sin_of(x[i]);
  return true;
}

// Circle.sample at each time t[j] into row j of P, V (k, 3) and, for a circle with orientation, Q (k, 9: row-major
// 3x3) and omega (k, 3) (else (0, 9) and (0, 3), not written). ``plane``: the rows e1, e2, n; ``w`` = speed / radius;
// ``kind``: 0 position only, 1 the Frenet frame (Eqs. 4.47-4.48), 2 the orientation Q0 turned by roll sin(w t) about
// its z axis. False where an angle is not finite (rows partly written: the caller drops them).
bool circle_samples(const InVec& t, double start, double w, const InMat& plane, const InVec& center, double radius,
                    double speed, int kind, const InMat& Q0, double roll, OutMat P, OutMat V, OutMat Q, OutMat omega) {
  const size_t k = t.shape(0);
  if (kind < 0 || kind > 2) throw nb::value_error("kind must be 0 (position), 1 (Frenet) or 2 (orientation)");
  check_shape(plane.shape(0), plane.shape(1), 3, 3, "plane");
  check_shape(center.shape(0), 3, 3, 3, "center");
  check_shape(P.shape(0), P.shape(1), k, 3, "P");
  check_shape(V.shape(0), V.shape(1), k, 3, "V");
  const size_t kq = kind == 0 ? 0 : k;
  check_shape(Q.shape(0), Q.shape(1), kq, 9, "Q");
  check_shape(omega.shape(0), omega.shape(1), kq, 3, "omega");
  if (kind == 2) check_shape(Q0.shape(0), Q0.shape(1), 3, 3, "Q0");
  const double* e1 = plane.data();
  const double* e2 = e1 + 3;
  const double* n = e1 + 6;
  const double* c0 = center.data();
  const double* q0 = kind == 2 ? Q0.data() : nullptr;
  const double* tv = t.data();
  double* p = P.data();
  double* v = V.data();
  double* q = Q.data();
  double* om = omega.data();
  for (size_t j = 0; j < k; ++j, p += 3, v += 3, q += 9, om += 3) {
    const double beta = start + w * tv[j];
    if (!std::isfinite(beta)) return false;
    const double c = cos_of(beta), s = sin_of(beta);
    double en[3], et[3];
    for (int i = 0; i < 3; ++i) {
      en[i] = c * e1[i] + s * e2[i];  // the outward radial unit vector
      et[i] = c * e2[i] - s * e1[i];  // the tangent
      p[i] = c0[i] + radius * en[i];
      v[i] = speed * et[i];
    }
    if (kind == 1) {
      for (int i = 0; i < 3; ++i) {  // Eq. (4.47): [e_n, e_t, e_n x e_t], e_n x e_t = n; Eq. (4.48): omega = w n
        q[3 * i] = en[i], q[3 * i + 1] = et[i], q[3 * i + 2] = n[i];
        om[i] = w * n[i];
      }
    } else if (kind == 2 && roll == 0.0) {
      for (int i = 0; i < 9; ++i) q[i] = q0[i];
      for (int i = 0; i < 3; ++i) om[i] = 0.0;
    } else if (kind == 2) {  // Q = Q0 Rz(ang): each row's first two entries turn by ang, the third stays
      const double wt = w * tv[j];
      if (!std::isfinite(wt)) return false;
      const double ang = roll * sin_of(wt);
      const double ca = cos_of(ang), sa = sin_of(ang);
      const double rate = roll * w * cos_of(wt);
      for (int i = 0; i < 3; ++i) {
        const double x = q0[3 * i], y = q0[3 * i + 1], z = q0[3 * i + 2];
        q[3 * i] = ca * x + sa * y, q[3 * i + 1] = ca * y - sa * x, q[3 * i + 2] = z;
        om[i] = rate * z;  // about Q0's z axis
      }
    }
  }
  return true;
}

}  // namespace

void bind_paths(nb::module_& m) {
  m.def("cos_sin", &cos_sin, nb::arg("angles"), nb::arg("c"), nb::arg("s"),
        "cos and sin of each angle into c and s by math.cos's and math.sin's C functions; False where one is not "
        "finite (see src/core/paths.cpp).");
  m.def("circle_samples", &circle_samples, nb::arg("t"), nb::arg("start"), nb::arg("w"), nb::arg("plane"),
        nb::arg("center"), nb::arg("radius"), nb::arg("speed"), nb::arg("kind"), nb::arg("Q0"), nb::arg("roll"),
        nb::arg("P"), nb::arg("V"), nb::arg("Q"), nb::arg("omega"),
        "Circle.sample at each time into the rows of P, V, Q, omega; False where an angle is not finite (see "
        "src/core/paths.cpp).");
}

}  // namespace kinredund
