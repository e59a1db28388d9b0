// The fold and singularity watch's measurement of a step in C++ (issue 28): the branch of
// kinredund.tracking.watch.Watch.measure that reuses R's LU factors, operation by operation. One step of inverse
// iteration u = P v with P the top block of R^{-1} (LAPACK dgetrs on the factors, the Python watch's call), u
// normalised, the Rayleigh quotient u^T M u (the reduced Hessian's eigenvalue nearest zero, Eq. (4.24)'s R singular
// where it is zero), and sigma_min(J): the last exact value while ||J - J_ref||_F < J_GATE sigma_ref (Weyl), else
// LAPACK dgesvd without vectors. dgetrs and dgesvd are scipy's own (scipy.linalg.cython_lapack's capsules, the
// library behind scipy.linalg.lapack), so the numbers are the Python watch's to rounding of the vector operations.
// The exact branch (one SVD of J for sigma_min and the null basis, the eigenvalue of Z^T sym(M) Z; every EXACT_EVERY
// measurements) is watch_exact, in Eigen: the compiled backend's single steps (Watch._exact with a core) and its
// runs of steps (loop.cpp, the GIL released) call the same routine, so both give the same bits; the Python backend
// keeps numpy's LAPACK (the values agree to the SVD's rounding, ~eps ||J||, and the eigensolver's, ~eps ||M||; the
// vectors up to sign: only the inverse iteration's start reads them, whose Rayleigh quotient does not see the sign).
#include "watch.hpp"

#include <nanobind/ndarray.h>
#include <nanobind/stl/tuple.h>

#include <Python.h>

#include <Eigen/Eigenvalues>
#include <Eigen/SVD>

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

namespace nb = nanobind;

namespace kinredund {

namespace {

using getrs_t = void (*)(char*, int*, int*, double*, int*, int*, double*, int*, int*);
using gesvd_t = void (*)(char*, char*, int*, int*, double*, int*, double*, double*, int*, double*, int*, double*,
                         int*, int*);

using gesdd_t = void (*)(char*, int*, int*, double*, int*, double*, double*, int*, double*, int*, double*, int*, int*,
                         int*);

using geqrf_t = void (*)(int*, int*, double*, int*, double*, double*, int*, int*);
using ormqr_t = void (*)(char*, char*, int*, int*, int*, double*, int*, double*, double*, int*, double*, int*, int*);
using trtrs_t = void (*)(char*, char*, char*, int*, int*, double*, int*, double*, int*, int*);

struct Lapack {
  getrs_t getrs = nullptr;
  gesvd_t gesvd = nullptr;
  gesdd_t gesdd = nullptr;
  geqrf_t geqrf = nullptr;
  ormqr_t ormqr = nullptr;
  trtrs_t trtrs = nullptr;
};

void* capsule_pointer(nb::handle capi, const char* name) {
  nb::object cap = capi[name];
  void* p = PyCapsule_GetPointer(cap.ptr(), PyCapsule_GetName(cap.ptr()));
  if (p == nullptr) throw nb::python_error();
  return p;
}

// scipy's LAPACK (needs the GIL the first time: every caller of watch_measure holds it)
const Lapack& lapack() {
  static Lapack L;
  if (L.getrs == nullptr) {
    nb::object capi = nb::module_::import_("scipy.linalg.cython_lapack").attr("__pyx_capi__");
    L.gesvd = reinterpret_cast<gesvd_t>(capsule_pointer(capi, "dgesvd"));
    L.gesdd = reinterpret_cast<gesdd_t>(capsule_pointer(capi, "dgesdd"));
    L.geqrf = reinterpret_cast<geqrf_t>(capsule_pointer(capi, "dgeqrf"));
    L.ormqr = reinterpret_cast<ormqr_t>(capsule_pointer(capi, "dormqr"));
    L.trtrs = reinterpret_cast<trtrs_t>(capsule_pointer(capi, "dtrtrs"));
    L.getrs = reinterpret_cast<getrs_t>(capsule_pointer(capi, "dgetrs"));  // (last: set means all are)
  }
  return L;
}

// The singular values of J (m x n, row-major) by dgesvd('N', 'N') on a column-major copy with scipy's default lwork
// (scipy.linalg.lapack.dgesvd(J, compute_uv=0, full_matrices=0)): min(m, n) of them into sv, descending; info.
int svd_values(const Lapack& L, const double* J, int m, int n, std::vector<double>& sv) {
  int mm = m, nn = n, minmn = std::min(m, n), lda = std::max(1, m), ldu = 1, ldvt = 1, info = 0;
  int lwork = std::max({3 * minmn + std::max(m, n), 5 * minmn, 1});
  std::vector<double> Jc(static_cast<size_t>(m) * n), work(lwork), uu1(1), vt1(1);
  sv.assign(std::max(minmn, 1), 0.0);
  for (int i = 0; i < m; ++i)
    for (int k = 0; k < n; ++k) Jc[static_cast<size_t>(k) * m + i] = J[static_cast<size_t>(i) * n + k];
  char jn = 'N';
  L.gesvd(&jn, &jn, &mm, &nn, Jc.data(), &lda, sv.data(), uu1.data(), &ldu, vt1.data(), &ldvt, work.data(), &lwork,
          &info);
  return info;
}

using Vec = nb::ndarray<const double, nb::ndim<1>, nb::c_contig, nb::device::cpu>;
using Mat = nb::ndarray<const double, nb::ndim<2>, nb::c_contig, nb::device::cpu>;
using FMat = nb::ndarray<const double, nb::ndim<2>, nb::f_contig, nb::device::cpu>;
using Out1 = nb::ndarray<nb::numpy, double, nb::ndim<1>>;
using Out2 = nb::ndarray<nb::numpy, double, nb::ndim<2>>;

template <class A>
A owned(std::vector<double>&& data, std::initializer_list<size_t> shape) {
  auto* buf = new std::vector<double>(std::move(data));
  nb::capsule owner(buf, [](void* p) noexcept { delete static_cast<std::vector<double>*>(p); });
  return A(buf->data(), shape, owner);
}

// Watch._exact's sigma_min where J is square (m x m, row-major: no null space, the eigenvalue is +inf, the vector
// zero): numpy.linalg.svd's dgesdd('N'), and the fold floor's scale max(1, max |M_ij|).
void exact_square(const Lapack& L, const double* J, const double* M, int m, InverseMeasure& out) {
  const size_t mn = static_cast<size_t>(m) * m;
  std::vector<double> Jc(mn), sv(std::max(m, 1)), u1(1), vt1(1);
  for (int i = 0; i < m; ++i)
    for (int k = 0; k < m; ++k) Jc[static_cast<size_t>(k) * m + i] = J[static_cast<size_t>(i) * m + k];
  int mm = m, lda = std::max(1, m), one = 1, info = 0, lwork = -1;
  std::vector<int> iw(8 * static_cast<size_t>(std::max(m, 1)));
  double query = 0.0;
  char jobz = 'N';
  L.gesdd(&jobz, &mm, &mm, Jc.data(), &lda, sv.data(), u1.data(), &one, vt1.data(), &one, &query, &lwork, iw.data(),
          &info);
  lwork = std::max(1, static_cast<int>(query));
  std::vector<double> work(lwork);
  L.gesdd(&jobz, &mm, &mm, Jc.data(), &lda, sv.data(), u1.data(), &one, vt1.data(), &one, work.data(), &lwork,
          iw.data(), &info);
  out.sigma = info == 0 && m > 0 ? sv[m - 1] : std::nan("");
  out.scale = 1.0;
  for (size_t k = 0; k < mn; ++k) out.scale = std::max(out.scale, std::abs(M[k]));
  out.eig = INFINITY;
  out.u.assign(static_cast<size_t>(m), 0.0);
  out.fresh = out.square = true;
}

}  // namespace

void watch_exact(const double* J, const double* M, int m, int nf, ExactMeasure& out) {
  using RowMat = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  const Eigen::Map<const RowMat> Jm(J, m, nf), Mm(M, nf, nf);
  out.scale = 1.0;
  for (Eigen::Index k = 0; k < Mm.size(); ++k) out.scale = std::max(out.scale, std::abs(M[k]));
  out.v.assign(static_cast<size_t>(nf), 0.0);
  const int r = std::min(m, nf);
  if (r == 0) {
    out.sigma = std::nan("");
    out.eig = INFINITY;
    return;
  }
  if (!Jm.allFinite()) {  // (Eigen's SVD leaves its values unset on such input) NaN: the watch counts it crossed
    out.sigma = out.eig = std::nan("");
    return;
  }
  const Eigen::MatrixXd Jc = Jm;
  if (nf <= m) {  // no null space (Watch's exact where J is square): sigma_min, eig = +inf, v = 0
    Eigen::JacobiSVD<Eigen::MatrixXd> svd(Jc);
    out.sigma = svd.singularValues()(r - 1);
    out.eig = INFINITY;
    return;
  }
  Eigen::JacobiSVD<Eigen::MatrixXd> svd(Jc, Eigen::ComputeFullV);
  out.sigma = svd.singularValues()(r - 1);  // (descending)
  if (!Mm.allFinite()) {
    out.eig = std::nan("");
    return;
  }
  const Eigen::MatrixXd Z = svd.matrixV().rightCols(nf - m);
  const Eigen::MatrixXd S = Z.transpose() * (0.5 * (Mm + Mm.transpose())) * Z;  // Z^T sym(M) Z
  if (nf - m == 1) {
    out.eig = S(0, 0);
    Eigen::Map<Eigen::VectorXd>(out.v.data(), nf) = Z.col(0);
    return;
  }
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(S);
  if (es.info() != Eigen::Success) {
    out.eig = std::nan("");
    return;
  }
  out.eig = es.eigenvalues()(0);  // (ascending)
  Eigen::Map<Eigen::VectorXd>(out.v.data(), nf) = Z * es.eigenvectors().col(0);
}

void watch_lapack() { lapack(); }

bool watch_inverse(const double* J, const double* M, const double* lu, const int* piv0, int nf, int m,
                   const double* v, const double* J_ref, double sigma_ref, double gate, InverseMeasure& out) {
  const Lapack& L = lapack();
  if (nf == m) {  // u = P v is zero: the Python watch's exact branch
    exact_square(L, J, M, m, out);
    return true;
  }
  out.square = false;
  int N = nf + m, one = 1, info = 0;
  // u = P v: the top block of R^{-1} [v; 0] (Watch.measure: lapack.dgetrs(lu, piv, b) with b = [v; 0])
  std::vector<double> b(N, 0.0);
  std::vector<int> piv(N);
  for (int i = 0; i < N; ++i) piv[i] = piv0[i] + 1;  // scipy's wrapper passes LAPACK's 1-based pivots
  std::copy(v, v + nf, b.begin());
  char trans = 'N';  // dgetrs reads the factors only
  L.getrs(&trans, &N, &one, const_cast<double*>(lu), &N, piv.data(), b.data(), &N, &info);
  std::vector<double>& u = out.u;
  u.assign(b.begin(), b.begin() + nf);
  double uu = 0.0;
  for (double e : u) uu += e * e;
  if (!(uu > 0.0 && std::isfinite(uu))) return false;  // the Python watch computes exactly
  const double s = std::sqrt(uu);
  for (double& e : u) e /= s;
  double eig = 0.0;  // the Rayleigh quotient u^T (M u) on the null space of J (u = P v lies in it)
  for (int i = 0; i < nf; ++i) {
    double mi = 0.0;
    for (int k = 0; k < nf; ++k) mi += M[static_cast<size_t>(i) * nf + k] * u[k];
    eig += u[i] * mi;
  }
  out.eig = eig;
  const size_t mn = static_cast<size_t>(m) * nf;
  if (J_ref != nullptr) {  // Watch._sigma: the last exact value while J stays within J_GATE of it (Weyl)
    double d2 = 0.0;
    for (size_t k = 0; k < mn; ++k) d2 += (J[k] - J_ref[k]) * (J[k] - J_ref[k]);
    if (d2 < (gate * sigma_ref) * (gate * sigma_ref)) {
      out.sigma = sigma_ref;
      out.fresh = false;
      return true;
    }
  }
  // dgesvd('N', 'N') on J (column-major copy, scipy's default lwork)
  std::vector<double> sv;
  const int minmn = std::min(m, nf);
  info = svd_values(L, J, m, nf, sv);
  out.sigma = info == 0 ? sv[minmn - 1] : std::nan("");
  out.sigma_max = info == 0 ? sv[0] : std::nan("");
  out.fresh = true;
  return true;
}

nb::object watch_measure(const double* J, const double* M, const double* lu, const int* piv0, int nf, int m,
                         const double* v, const double* J_ref, double sigma_ref, double gate) {
  InverseMeasure r;
  if (!watch_inverse(J, M, lu, piv0, nf, m, v, J_ref, sigma_ref, gate, r)) return nb::none();
  Out1 u = owned<Out1>(std::move(r.u), {static_cast<size_t>(nf)});
  if (!r.fresh) return nb::make_tuple(r.sigma, r.eig, u, false, nb::none(), nb::none(), nb::none());
  std::vector<double> Jcopy(J, J + static_cast<size_t>(m) * nf);
  Out2 J_new = owned<Out2>(std::move(Jcopy), {static_cast<size_t>(m), static_cast<size_t>(nf)});
  if (r.square) return nb::make_tuple(r.sigma, r.eig, u, true, nb::none(), J_new, r.scale);
  return nb::make_tuple(r.sigma, r.eig, u, true, r.sigma_max, J_new, nb::none());
}

namespace {

// watch_measure(J (m x n), M (n x n), lu (N x N, column-major), piv (N, 0-based), free (int32, ascending),
//               v (nf), J_ref (m x nf, or any other shape: none), sigma_ref, gate): the free joints' J and M taken
// as Watch.reduce takes them, then watch_measure above.
nb::object measure_arrays(Mat J, Mat M, FMat lu, nb::ndarray<const int, nb::ndim<1>, nb::c_contig> piv,
                          nb::ndarray<const int, nb::ndim<1>, nb::c_contig> free, Vec v, Mat J_ref, double sigma_ref,
                          double gate) {
  const int m = static_cast<int>(J.shape(0)), n = static_cast<int>(J.shape(1)), nf = static_cast<int>(free.shape(0));
  const int N = nf + m;
  if (M.shape(0) != static_cast<size_t>(n) || M.shape(1) != static_cast<size_t>(n))
    throw nb::value_error("M must be n x n (J: m x n)");
  if (lu.shape(0) != static_cast<size_t>(N) || lu.shape(1) != static_cast<size_t>(N) ||
      piv.shape(0) != static_cast<size_t>(N))
    throw nb::value_error("lu and piv: the factors of the reduced R (nf + m rows)");
  if (v.shape(0) != static_cast<size_t>(nf)) throw nb::value_error("v must have one entry per free joint");
  for (int k = 0; k < nf; ++k)
    if (free(k) < 0 || free(k) >= n || (k > 0 && free(k) <= free(k - 1)))
      throw nb::value_error("free: ascending joint numbers in [0, n)");
  for (int i = 0; i < N; ++i)
    if (piv(i) < 0 || piv(i) >= N) throw nb::value_error("piv: 0-based row numbers in [0, N)");
  std::vector<double> Jr(static_cast<size_t>(m) * nf), Mr(static_cast<size_t>(nf) * nf);
  for (int i = 0; i < m; ++i)
    for (int k = 0; k < nf; ++k) Jr[static_cast<size_t>(i) * nf + k] = J(i, free(k));
  for (int i = 0; i < nf; ++i)
    for (int k = 0; k < nf; ++k) Mr[static_cast<size_t>(i) * nf + k] = M(free(i), free(k));
  const bool ref = J_ref.shape(0) == static_cast<size_t>(m) && J_ref.shape(1) == static_cast<size_t>(nf);
  return watch_measure(Jr.data(), Mr.data(), lu.data(), piv.data(), nf, m, v.data(), ref ? J_ref.data() : nullptr,
                       sigma_ref, gate);
}

// watch_exact(J (m x nf), M (nf x nf)) -> (sigma_min_J, eig, v (nf), scale).
nb::tuple exact_arrays(Mat J, Mat M) {
  const int m = static_cast<int>(J.shape(0)), nf = static_cast<int>(J.shape(1));
  if (M.shape(0) != static_cast<size_t>(nf) || M.shape(1) != static_cast<size_t>(nf))
    throw nb::value_error(("M must be " + std::to_string(nf) + " x " + std::to_string(nf) + " (J: " +
                           std::to_string(m) + " x " + std::to_string(nf) + ")").c_str());
  ExactMeasure e;
  watch_exact(J.data(), M.data(), m, nf, e);
  return nb::make_tuple(e.sigma, e.eig, owned<Out1>(std::move(e.v), {static_cast<size_t>(nf)}), e.scale);
}

// A run's start checks (kinredund/tracking/stepper.py: Stepper.__init__), with scipy's LAPACK and the GIL released:
// lambda minimising ||grad z + J^T lambda|| by Householder QR (linalg.multipliers, Eqs. 4.11-4.12: dgeqrf on J^T,
// dormqr, dtrtrs), the calls and arguments of scipy.linalg.lapack's wrappers there, so the same numbers; and from the
// same QR (J^T = Y R: R has J's singular values) whether J is clearly of full rank: 1 / ||R^-1||_F <= sigma_min(J)
// and ||J||_F >= sigma_max(J), so 1 / ||R^-1||_F > floor max(1, ||J||_F) gives sigma_min(J) > floor max(1,
// sigma_max(J)) (R^-1 by back substitution; the caller's floor carries the margin over the rounding). Returns (clear;
// lambda (m) or None where the Python reference decides: J or grad not finite, m > n, dtrtrs fails, or an entry of
// lambda not below 1e150 in magnitude, multipliers' finiteness test squaring them). Not clear: the Python check decides.
nb::tuple start_checks(Mat J, Vec grad, double floor) {
  const int m = static_cast<int>(J.shape(0)), n = static_cast<int>(J.shape(1));
  if (grad.shape(0) != static_cast<size_t>(n)) throw nb::value_error("grad must have one entry per column of J");
  const Lapack& L = lapack();
  const size_t mn = static_cast<size_t>(m) * n;
  std::vector<double> lam;
  bool clear = false;
  const bool ok = std::all_of(J.data(), J.data() + mn, [](double x) { return std::isfinite(x); }) &&
                  std::all_of(grad.data(), grad.data() + n, [](double x) { return std::isfinite(x); });
  if (ok && m <= n && m > 0) {
    nb::gil_scoped_release release;  // no Python object below
    // dgeqrf(J^T): J^T (n x m) column-major is J's row-major data; scipy's default lwork max(3 m, 1)
    std::vector<double> A(J.data(), J.data() + mn), tau(m), c(grad.data(), grad.data() + n);
    int nn = n, mm = m, one = 1, info = 0, lwork = std::max(3 * m, 1);
    std::vector<double> work(lwork);
    L.geqrf(&nn, &mm, A.data(), &nn, tau.data(), work.data(), &lwork, &info);
    // dormqr('L', 'T', qr, tau, grad[:, None], lwork=max(64, m)): Y^T grad
    int lwork2 = std::max(64, m);
    std::vector<double> work2(lwork2);
    char left = 'L', trans = 'T';
    L.ormqr(&left, &trans, &nn, &one, &mm, A.data(), &nn, tau.data(), c.data(), &nn, work2.data(), &lwork2, &info);
    // dtrtrs(qr[:m, :m], c[:m, 0]): the upper triangle, copied contiguous (lda m) as scipy's wrapper passes it
    std::vector<double> R(static_cast<size_t>(m) * m);
    for (int k = 0; k < m; ++k)
      for (int i = 0; i < m; ++i) R[static_cast<size_t>(k) * m + i] = A[static_cast<size_t>(k) * n + i];
    lam.assign(c.begin(), c.begin() + m);
    char up = 'U', no = 'N';
    L.trtrs(&up, &no, &no, &mm, &one, R.data(), &mm, lam.data(), &mm, &info);
    const bool small = std::all_of(lam.begin(), lam.end(), [](double x) { return std::abs(x) < 1e150; });
    if (info != 0 || !small) {
      lam.clear();
    } else {
      for (double& x : lam) x = -x;  // Eq. (4.12): R lambda = -Y^T grad
    }
    // ||R^-1||_F: column k of R^-1 solves R x = e_k (upper triangular: x_i = 0 below k)
    double inv2 = 0.0, j2 = 0.0;
    std::vector<double> x(m);
    for (int k = 0; k < m; ++k) {
      for (int i = k; i >= 0; --i) {
        double v = i == k ? 1.0 : 0.0;
        for (int l = i + 1; l <= k; ++l) v -= R[static_cast<size_t>(l) * m + i] * x[l];
        x[i] = v / R[static_cast<size_t>(i) * m + i];
        inv2 += x[i] * x[i];
      }
    }
    for (size_t k = 0; k < mn; ++k) j2 += J.data()[k] * J.data()[k];
    clear = std::isfinite(inv2) && inv2 > 0.0 && 1.0 / std::sqrt(inv2) > floor * std::max(1.0, std::sqrt(j2));
  }
  nb::object lam_out = nb::none();
  if (!lam.empty()) lam_out = nb::cast(owned<Out1>(std::move(lam), {static_cast<size_t>(m)}));
  return nb::make_tuple(clear, lam_out);
}

}  // namespace

// WatchHistory (watch.hpp): kinredund.tracking.watch's _keep, _crossing_time, Watch.floors, crossed and push.
namespace {

// watch._keep: (t, v) as the newest of at most two; a second value at the same time replaces the newest
void keep(std::vector<double>& times, double t, std::vector<double>& values, double v) {
  if (!times.empty() && times.back() == t) {
    values.back() = v;
    return;
  }
  times.push_back(t);
  values.push_back(v);
  if (times.size() > 2) {
    times.erase(times.begin());
    values.erase(values.begin());
  }
}

// watch._crossing_time: when v or v^2, extrapolated linearly from its last two values, reaches ``floor`` (-inf at or
// below it or NaN, +inf where v does not decrease); min(a, b) as Python's, b where b < a, else a
double crossing_time(const std::vector<double>& times, const std::vector<double>& values, double floor) {
  const double inf = std::numeric_limits<double>::infinity();
  if (values.empty()) return inf;
  const double v1 = values.back();
  if (!(v1 > floor)) return -inf;
  if (values.size() < 2) return inf;
  const double v0 = values[values.size() - 2], t0 = times[times.size() - 2], t1 = times.back();
  if (!(v1 < v0 && t1 > t0)) return inf;
  const double slope = (v1 - v0) / (t1 - t0), slope2 = (v1 * v1 - v0 * v0) / (t1 - t0);
  const double a = t1 + (floor - v1) / slope, b = t1 + (floor * floor - v1 * v1) / slope2;
  return b < a ? b : a;
}

}  // namespace

double WatchHistory::kinematic_floor(double s_max) const { return sigma_floor * (s_max > 1.0 ? s_max : 1.0); }

bool WatchHistory::crossed(double s, double e, double s_max, double fold_scale) const {
  return !(s > kinematic_floor(s_max)) || !(e > eig_floor * fold_scale);
}

void WatchHistory::push(double t, double s, double e) {
  if (reset) {  // Watch.reset: the history starts afresh
    times.clear(), eig.clear(), sigma_times.clear(), sigma.clear();
    reset = false;
  }
  if (fresh || sigma.empty()) keep(sigma_times, t, sigma, s);
  keep(times, t, eig, e);
  const double kinematic = crossing_time(sigma_times, sigma, kinematic_floor(sigma_max));
  const double fold = crossing_time(times, eig, eig_floor * scale);
  safe = fold < kinematic ? fold : kinematic;  // min(crossings().values()): the first where neither is smaller
}

void bind_watch(nb::module_& m) {
  m.def("start_checks", &start_checks, nb::arg("J"), nb::arg("grad"), nb::arg("floor"),
        "A run's start checks with scipy's LAPACK, the GIL released: (J clearly of full rank against the floor, "
        "lambda by least squares or None) - see src/core/watch.cpp.");
  m.def("watch_exact", &exact_arrays, nb::arg("J"), nb::arg("M"),
        "The watch's exact measurement (kinredund.tracking.watch.exact) in Eigen: (sigma_min_J, eig, v, scale).");
  m.def("watch_measure", &measure_arrays, nb::arg("J"), nb::arg("M"), nb::arg("lu"), nb::arg("piv"), nb::arg("free"),
        nb::arg("v"), nb::arg("J_ref"), nb::arg("sigma_ref"), nb::arg("gate"),
        "The watch's inverse-iteration measurement (kinredund.tracking.watch.Watch.measure) on given matrices: "
        "None (the exact computation's turn) or (sigma_min_J, eig, u, fresh, sigma_max, J or None).");
}

}  // namespace kinredund
