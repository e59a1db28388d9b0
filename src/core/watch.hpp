// kinredund._core: the fold and singularity watch's measurement of a step (issue 28; watch.cpp).
#pragma once

#include <nanobind/nanobind.h>

#include <vector>

namespace kinredund {

// The watch's inverse-iteration measurement (kinredund.tracking.watch.Watch.measure, the branch that reuses R's
// factors): J (m x nf, row-major), M (nf x nf, row-major) of the free joints, R's LU factors (N x N column-major,
// N = nf + m, LAPACK's layout) with 0-based pivots, the last vector v (nf), the last exact J_ref (m x nf,
// row-major; null where there is none or its shape differs) and sigma_min there, J_GATE. Returns None where the
// Python watch computes exactly instead (u = P v not finite or zero, J not square), else (sigma_min_J, eig, u,
// fresh, sigma_max or None, J or None, scale or None): ``fresh`` where sigma_min(J) was computed afresh (then the
// copy of J is the new reference; sigma_max where dgesvd gave it); where J is square (no null space) the exact
// branch's (dgesdd, eig = inf, u = 0, the fold floor's scale max(1, max |M_ij|)). LAPACK's dgetrs, dgesvd and dgesdd
// are scipy's (cython_lapack), the routines of the Python watch's calls (numpy's svd: dgesdd, another build).
nanobind::object watch_measure(const double* J, const double* M, const double* lu, const int* piv0, int nf, int m,
                               const double* v, const double* J_ref, double sigma_ref, double gate);

// watch_measure without Python objects (runs of steps call it with the GIL released, after watch_lapack()), where
// nf >= m: false where u = P v is not finite or zero (the exact computation's turn), else the measurement in
// ``out``: sigma_min_J (the reference's where ``fresh`` is false), the Rayleigh quotient, u and, where fresh (dgesvd
// on J), sigma_max; a fresh measurement's J is the new reference. Where J is square (``square``): the exact branch's
// sigma_min (dgesdd), eig = +inf, u = 0, fresh, the fold floor's ``scale`` (no sigma_max).
struct InverseMeasure {
  double sigma = 0.0, eig = 0.0, sigma_max = 0.0, scale = 1.0;
  bool fresh = false, square = false;
  std::vector<double> u;
};
bool watch_inverse(const double* J, const double* M, const double* lu, const int* piv0, int nf, int m,
                   const double* v, const double* J_ref, double sigma_ref, double gate, InverseMeasure& out);
// Loads scipy's LAPACK for watch_inverse (needs the GIL: call it before releasing the GIL around watch_inverse).
void watch_lapack();

// The watch's exact measurement (kinredund.tracking.watch.exact, the compiled backend's: Watch._exact with a core),
// without Python objects (runs of steps call it with the GIL released): one SVD of J (Eigen's JacobiSVD, full V)
// gives sigma_min(J) and Z, the last nf - m right singular vectors (a basis of J's null space); the smallest
// eigenvalue of Z^T sym(M) Z (Eq. (4.24)'s R is singular where it is zero; Eigen's SelfAdjointEigenSolver where
// nf - m > 1, the number z^T sym(M) z where nf - m = 1) and its eigenvector in joint space v = Z w; where nf <= m (no
// null space) eig = +inf and v = 0. ``scale``: the fold floor's max(1, max |M_ij|). A J (M) with an entry not finite
// gives sigma and eig (eig) NaN, which the watch counts as crossed.
struct ExactMeasure {
  double sigma = 0.0, eig = 0.0, scale = 1.0;
  std::vector<double> v;
};
// J (m x nf, row-major), M (nf x nf, row-major).
void watch_exact(const double* J, const double* M, int m, int nf, ExactMeasure& out);

// The watch's verdicts and history (kinredund.tracking.watch.Watch: crossed, push, crossings, ahead), for runs of
// steps that take them in the run (loop.cpp) with the GIL released: the same operations on the same doubles, so the
// same verdicts and the same history as the Python watch's. ``sigma_floor``, ``eig_floor``: SIGMA_FLOOR, EIG_FLOOR.
struct WatchHistory {
  std::vector<double> times, eig, sigma_times, sigma;  // the last two measurements (oldest first), as Watch keeps them
  double sigma_max = 1.0, scale = 1.0, safe = 0.0, sigma_floor = 0.0, eig_floor = 0.0;
  bool fresh = true;   // the newest sigma_min(J) was computed afresh (Watch._fresh)
  bool reset = false;  // the first push starts the history afresh (the active set differs from the history's)
  // Watch.floors's kinematic floor: SIGMA_FLOOR max(1, sigma_max)
  double kinematic_floor(double s_max) const;
  // Watch.crossed with the kinematic floor's sigma_max and the fold floor's scale given: a quantity at or below its
  // floor (NaN counts as crossed)
  bool crossed(double s, double e, double s_max, double fold_scale) const;
  // Watch.push(t, s, e) without a change of the active set (past the first push's ``reset``), and the earliest
  // predicted crossing (``safe``, Watch.safe_before) after it
  void push(double t, double s, double e);
  // Watch.ahead(t) is not None: a crossing predicted by t (the earliest, ``safe``, at or before it)
  bool ahead(double t) const { return safe <= t; }
};

// Binds watch_measure on arrays into the module (for tests: any J, M and factors).
void bind_watch(nanobind::module_& m);

}  // namespace kinredund
