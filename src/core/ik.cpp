// The joint-level IK's constrained iteration in C++ (issue 28): kinredund/ik/newton.py `_iterate` operation by
// operation for the task kinds' IK residuals (kinredund/tasks/*: PointResidual, PoseResidual, AxisResidual) and the
// index JointDeviation: one Pinocchio evaluation per iteration (frame.hpp, shared with the compiled step), e and G,
// the Householder QR split of G^T (Eq. D.25), x0 (Eq. D.24), the least-squares multipliers (Eqs. 4.11-4.12) or
// bound_kkt (Eq. D.30), the Lagrangian Hessian M (Eqs. 4.20-4.26), the reduced Newton step of Eq. (D.26) with its
// eigenvalue fix, the merit search with second-order correction, the damped least-squares restoration step (with
// bounds, its box least squares where kinredund/ik/qp.py's active-set guess solves it), the box QP of a Newton step that
// leaves the bounds where qp.py's guesses solve it or certify it infeasible, cap_step and the stall and convergence
// tests. The algorithm is invariant under the choice of orthonormal bases
// (x0, L u, Y Y^T, the multipliers and ||L^T grad|| do not depend on them), so Eigen's QR, SVD and eigensolver give
// the Python reference's numbers (LAPACK's) to rounding.
//
// Whatever the iteration would do that is not here - a Newton step that leaves the bounds (the box QP of
// kinredund/ik/qp.py) that its guesses neither solve nor certify infeasible, a restoration step whose box least
// squares needs proxsuite, a stop of any kind but convergence (its reason is Python's to word), the rotation log near a
// half turn, a spurious zero of e - hands back to Python: run() returns the state at the start of that iteration,
// the Python iteration redoes it from there (newton.py `_iterate(..., state)`) and hands the next one back to run().
#include "ik.hpp"
#include "frame.hpp"

#include <nanobind/eigen/dense.h>
#include <nanobind/stl/tuple.h>

#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <Eigen/QR>
#include <Eigen/SVD>

#include <cmath>
#include <limits>
#include <string>
#include <time.h>
#include <vector>

namespace nb = nanobind;

namespace kinredund {

pinocchio::Model model_from_python(nb::handle obj);  // module.cpp

namespace {

using MatrixXd = Eigen::MatrixXd;
using VectorXd = Eigen::VectorXd;
using Matrix3d = Eigen::Matrix3d;
using Vector3d = Eigen::Vector3d;
using Vector6d = Eigen::Matrix<double, 6, 1>;
using CRef = Eigen::Ref<const VectorXd>;

// Task kinds (kinredund/ik/compiled.py TASK_CODES)
enum Task { PLANAR = 0, POSITION = 1, POSE = 2, AXIS = 3 };
// run()'s status: converged, or why the iteration is handed back to Python (kinredund/ik/compiled.py STATUS)
constexpr int CONVERGED = 0, LOG_NEAR_PI = 1, NOT_FINITE = 2, SPURIOUS = 3, MAX_ITER = 4, TIMEOUT = 5, STALLED = 6,
              SINGULAR = 7, RESTORE_BOX = 8, RESTORE_FAILED = 9, BOX_QP = 10, MERIT_FAILED = 11;

double now() {  // Python's time.perf_counter on Linux
  timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

double max_abs(const VectorXd& v) { return v.size() ? v.cwiseAbs().maxCoeff() : 0.0; }

// The certificate of an infeasible box QP (IKCore::infeasible): its damping relative to max|G|^2, and its margin
// [rad^2 or m^2] over proxsuite's tolerance (eps_abs 1e-11 on the residual: ~1e-21 on its square)
constexpr double INFEASIBLE_DAMPING = 1e-10, INFEASIBLE_MARGIN = 1e-12;
// The Farkas certificate's margin, relative to what a point within proxsuite's tolerance could reach (IKCore::farkas)
constexpr double FARKAS_MARGIN = 1e-10;

// The constants of kinredund/ik/common.py, passed in by the driver (one source)
struct Constants {
  double armijo, max_step, min_alpha, rank_tol, damping, lm_weight, active_tol;
  int stall_iters, guess_rounds;
};

// One iterate's evaluation (the first lines of `_iterate`)
struct Eval {
  Matrix3d Q, jl;
  Vector3d p, a;
  MatrixXd J6, K, G;
  pinocchio::Data::Tensor3x H;
  VectorXd e, grad;
  double ee = 0.0, r = 0.0, z = 0.0, a_z = 1.0;
};

// The iteration's state at the start of an iteration (what a hand-back gives Python)
struct State {
  VectorXd q, q_prev, on_q;
  double rho = 0.0, r_ref = std::numeric_limits<double>::infinity(), r_prev = std::numeric_limits<double>::infinity();
  double on_z = 0.0, on_r = 0.0;
  int since = 0;
  bool on = false;
};

// The first-order terms (`_first_order`)
struct FirstOrder {
  double normality = std::numeric_limits<double>::quiet_NaN();
  VectorXd lam, active;
  MatrixXd L;
  bool computed = false;
};

}  // namespace

class IKCore {
 public:
  IKCore(nb::handle model, int frame_id, CRef constants) : model_(model_from_python(model)), data_(model_) {
    if (model_.nq != model_.nv) throw nb::value_error("the compiled IK needs nq == nv (revolute and prismatic joints)");
    if (frame_id < 0 || frame_id >= static_cast<int>(model_.nframes)) throw nb::value_error("frame id out of range");
    if (constants.size() != 9) throw nb::value_error("constants: the 9 of kinredund.ik.compiled.CONSTANTS");
    fid_ = frame_id;
    n_ = model_.nv;
    c_ = Constants{constants[0], constants[1], constants[2], constants[3], constants[4], constants[5], constants[6],
                   static_cast<int>(constants[7]), static_cast<int>(constants[8])};
  }

  // One start of `_constrained_minimum` from q0 (see the file's comment); the tuple's layout is
  // kinredund/ik/compiled.py's (run_compiled).
  // ``it0``, ``rho``, ``r_ref``, ``since``, ``q_prev``, ``r_prev``, ``on_q`` (empty: none), ``on_z``, ``on_r``: the
  // state to go on from (that of `_iterate` at the start of iteration it0; a fresh start: 0, 0, inf, 0, q0, inf).
  nb::tuple run(CRef q0, int task, const Matrix3d& Qd, const Vector3d& pd, CRef weights, CRef reference, CRef lower,
                CRef upper, bool bounds, double rtol, double tol, int max_iter, double deadline, int it0, double rho,
                double r_ref, int since, CRef q_prev, double r_prev, CRef on_q, double on_z, double on_r) {
    const int n = n_;
    if (task < PLANAR || task > AXIS) throw nb::value_error("unknown task code");
    if (q0.size() != n || weights.size() != n || reference.size() != n || lower.size() != n || upper.size() != n ||
        q_prev.size() != n || (on_q.size() != 0 && on_q.size() != n))
      throw nb::value_error("q0, weights, reference, lower, upper, q_prev and on_q (or empty) must have n entries");
    task_ = task;
    m_ = task == PLANAR ? 2 : task == POSITION ? 3 : task == POSE ? 6 : 5;
    if (m_ >= n) throw nb::value_error("the constrained iteration needs n > m");
    Qd_ = Qd, QdT_ = Qd.transpose(), pd_ = pd, w_ = weights, ref_ = reference, lo_ = lower, hi_ = upper;
    bounds_ = bounds, rtol_ = rtol, tol_ = tol, max_iter_ = max_iter, deadline_ = deadline;
    vect_d_ = Vector3d(0.5 * (Qd(2, 1) - Qd(1, 2)), 0.5 * (Qd(0, 2) - Qd(2, 0)), 0.5 * (Qd(1, 0) - Qd(0, 1)));
    trace_d_ = Qd.trace();
    State st;
    st.q = q0;
    st.q_prev = q_prev;
    st.rho = rho, st.r_ref = r_ref, st.since = since, st.r_prev = r_prev;
    st.on = on_q.size() != 0;
    if (st.on) st.on_q = on_q, st.on_z = on_z, st.on_r = on_r;
    Eval ev;
    FirstOrder fo;
    int it = it0, status;
    {
      nb::gil_scoped_release release;  // touches no Python object
      status = iterate(st, ev, fo, it);
    }
    nb::object on_out = st.on ? nb::cast(st.on_q) : nb::none();
    if (status != CONVERGED)
      return nb::make_tuple(status, it, st.q, st.rho, st.r_ref, st.since, st.q_prev, st.r_prev, on_out, st.on_z, st.on_r);
    // converged: the terms of OptimalityTerms (k multipliers, null space, held limits, extra, dK's tensor)
    VectorXd lam_k;
    Vector6d mu;
    k_multipliers(ev, fo.lam, lam_k, mu);
    nb::object extra = task_ == AXIS ? nb::cast(axis_extra(ev, fo.lam)) : nb::none();
    VectorXd hbuf = Eigen::Map<const VectorXd>(ev.H.data(), 6 * n * n);
    nb::object active = fo.active.size() ? nb::cast(fo.active) : nb::none();
    return nb::make_tuple(status, it, st.q, ev.r, fo.normality, ev.z, lam_k, fo.L, active, extra, hbuf, on_out,
                          st.on_z, st.on_r);
  }

 private:
  // `_iterate`'s loop: CONVERGED (st.q the converged iterate, ev and fo its terms) or a hand-back status with st
  // the state at the start of iteration ``it``.
  int iterate(State& st, Eval& ev, FirstOrder& fo, int& it) {
    for (; it <= max_iter_; ++it) {
      const State start = st;
      int s = step(st, ev, fo, it);
      if (s == CONVERGED) return s;
      if (s > 0) {
        st = start;
        return s;
      }
    }
    return MAX_ITER;  // not reached: iteration max_iter hands back
  }

  // One iteration from st.q: CONVERGED, a hand-back status, or -1 (st.q is the next iterate).
  int step(State& st, Eval& ev, FirstOrder& fo, int it) {
    const int n = n_, m = m_;
    const VectorXd q = st.q;
    if (!evaluate(q, ev)) return LOG_NEAR_PI;
    if (!(std::isfinite(ev.z) && ev.grad.allFinite() && w_.allFinite())) return NOT_FINITE;
    st.q_prev = q, st.r_prev = ev.r;
    const double r = ev.r, rt2 = rtol_ * rtol_;
    if (ev.ee < rt2 && !(r < rtol_) && task_ == AXIS && !(ev.a_z > 0.0)) return SPURIOUS;  // AxisResidual.spurious
    if (r < rtol_ && ev.ee < rt2 && (!st.on || ev.z < st.on_z)) st.on = true, st.on_q = q, st.on_z = ev.z, st.on_r = r;
    // qr_split: G^T = Y R, G L = 0 (Eq. D.25)
    Eigen::HouseholderQR<MatrixXd> qr(ev.G.transpose());
    const MatrixXd U = qr.householderQ();
    const MatrixXd Y = U.leftCols(m), L = U.rightCols(n - m);
    const MatrixXd R = qr.matrixQR().topRows(m).triangularView<Eigen::Upper>();
    const VectorXd diag = R.diagonal().cwiseAbs();
    const bool ok = diag.minCoeff() > c_.rank_tol * std::max(diag.maxCoeff(), 1e-300);
    VectorXd x0;
    if (ok) x0 = Y * solve_rt(R, -ev.e);  // minimum-norm part, Eq. (D.24)
    const bool newton = ok && max_abs(x0) <= c_.max_step;
    fo = FirstOrder();
    if (newton || r < rtol_ || it == max_iter_) first_order(ev, q, R, Y, L, ok, fo);
    const double ntol = std::max(tol_, 1e-13 * (1.0 + max_abs(ev.grad)));
    if (r < rtol_ && ev.ee < rt2 && fo.normality < ntol) return CONVERGED;
    if (it == max_iter_) return MAX_ITER;
    if (std::isfinite(deadline_) && now() > deadline_) return TIMEOUT;
    if (r < 0.5 * st.r_ref || r < 1e3 * rtol_) {
      st.r_ref = r, st.since = 0;
    } else if (st.since >= 2 * c_.stall_iters) {
      return STALLED;
    }
    st.since += 1;
    if (!ok && r < rtol_) return SINGULAR;
    if (!newton) return restore(st, ev);
    return newton_step(st, ev, fo, R, Y, L, x0);
  }

  // Kinematics.jacobian_hessian, the residual's error, jacobian and residual, and the index at q
  bool evaluate(const VectorXd& q, Eval& ev) {
    frame_jacobian_hessian(model_, data_, fid_, q, ev.J6, ev.H);
    const auto& oMf = data_.oMf[fid_];
    ev.Q = oMf.rotation();
    ev.p = oMf.translation();
    ev.K.resize(6, n_);
    ev.K.topRows(3) = ev.J6.bottomRows(3);  // thesis rows [omega; pdot] (Eq. 2.16)
    ev.K.bottomRows(3) = ev.J6.topRows(3);
    if (!error(ev.Q, ev.p, ev.e, ev.ee, &ev)) return false;
    ev.r = residual(ev);
    jacobian(ev);
    const VectorXd f = q - ref_;
    ev.grad = w_.cwiseProduct(f);
    ev.z = 0.5 * f.dot(ev.grad);  // JointDeviation, Eq. (4.45)
    return true;
  }

  // TaskResidual.error / error_terms: e and ||e||^2 at (Q, p); with ``ev``, also Jl^-1 (pose) and a, a^ (axis)
  bool error(const Matrix3d& Q, const Vector3d& p, VectorXd& e, double& ee, Eval* ev) const {
    e.resize(m_);
    if (task_ == PLANAR || task_ == POSITION) {
      e = (p - pd_).head(m_);
    } else if (task_ == POSE) {
      Vector3d w;
      double phi = 0.0;
      if (!rotation_log(Q * QdT_, w, &phi)) return false;
      e << w, p - pd_;
      if (ev != nullptr) ev->jl = inverse_left_jacobian(w, phi);
    } else {
      const Vector3d a = Q.col(2), ah = QdT_ * a;
      e << ah[0], ah[1], p - pd_;
      if (ev != nullptr) ev->a = a, ev->a_z = ah[2];
    }
    ee = e.dot(e);
    return true;
  }

  // tasks/pose.py inverse_left_jacobian
  static Matrix3d inverse_left_jacobian(const Vector3d& w, double phi) {
    const double kappa = phi < SMALL_ANGLE ? 1.0 / 12.0 + phi * phi / 720.0
                                           : 1.0 / (phi * phi) - std::cos(0.5 * phi) / (2.0 * phi * std::sin(0.5 * phi));
    const double x = w[0], y = w[1], z = w[2], d = 1.0 - kappa * phi * phi;
    const double kx = kappa * x, ky = kappa * y, kz = kappa * z;
    Matrix3d J;
    J << d + kx * x, ky * x + 0.5 * z, kz * x - 0.5 * y, kx * y - 0.5 * z, d + ky * y, kz * y + 0.5 * x,
        kx * z + 0.5 * y, ky * z - 0.5 * x, d + kz * z;
    return J;
  }

  // TaskResidual.residual: ||g - x|| (the closure 7-vector of Eq. 2.13 for pose; the axis's a - a_d)
  double residual(const Eval& ev) const {
    if (task_ == POSE) {
      const Matrix3d& Q = ev.Q;
      const double a = Q(2, 1) - Q(1, 2) - 2.0 * vect_d_[0], b = Q(0, 2) - Q(2, 0) - 2.0 * vect_d_[1],
                   c = Q(1, 0) - Q(0, 1) - 2.0 * vect_d_[2], t = Q.trace() - trace_d_;  // Eq. (2.13)
      const Vector3d dp = ev.p - pd_;
      return std::sqrt(a * a + b * b + c * c + t * t + dp.dot(dp));
    }
    if (task_ == AXIS) return std::sqrt(ev.ee + (1.0 - ev.a_z) * (1.0 - ev.a_z));
    return std::sqrt(ev.ee);
  }

  // TaskResidual.jacobian: G = de/dtheta (m x n)
  void jacobian(Eval& ev) const {
    const int n = n_;
    ev.G.resize(m_, n);
    if (task_ == PLANAR || task_ == POSITION) {
      ev.G = ev.K.middleRows(3, m_);
    } else if (task_ == POSE) {
      ev.G.topRows(3) = ev.jl * ev.K.topRows(3);
      ev.G.bottomRows(3) = ev.K.bottomRows(3);
    } else {
      const Vector3d ah = QdT_ * ev.a;
      Eigen::Matrix<double, 2, 3> S;  // -[a^]x, x and y rows
      S << 0.0, ah[2], -ah[1], -ah[2], 0.0, ah[0];
      ev.G.topRows(2) = S * (QdT_ * ev.K.topRows(3));
      ev.G.bottomRows(3) = ev.K.bottomRows(3);
    }
  }

  // TaskResidual.k_multipliers (lambda* with G^T lambda = K[rows]^T lambda*), and lambda* in Pinocchio's [v; omega]
  // row order over all of K (HessianContraction.contract's ``rows``)
  void k_multipliers(const Eval& ev, const VectorXd& lam, VectorXd& lam_k, Vector6d& mu) const {
    mu.setZero();
    if (task_ == PLANAR || task_ == POSITION) {
      lam_k = lam;
      mu.head(m_) = lam;
    } else if (task_ == POSE) {
      lam_k.resize(6);
      lam_k << ev.jl.transpose() * lam.head(3), lam.tail(3);
      mu << lam_k.tail(3), lam_k.head(3);
    } else {
      const Vector3d m3 = Qd_ * Vector3d(lam[0], lam[1], 0.0);
      lam_k.resize(6);
      lam_k << cross3(ev.a, m3), lam.tail(3);
      mu << lam_k.tail(3), lam_k.head(3);
    }
  }

  // AxisResidual.extra_hessian: K_omega^T (a m^T - (a . m) 1) K_omega
  MatrixXd axis_extra(const Eval& ev, const VectorXd& lam) const {
    const Vector3d m3 = Qd_ * Vector3d(lam[0], lam[1], 0.0);
    const Matrix3d C = ev.a * m3.transpose() - ev.a.dot(m3) * Matrix3d::Identity();
    const auto Ko = ev.K.topRows(3);
    return Ko.transpose() * C * Ko;
  }

  static VectorXd solve_rt(const MatrixXd& R, const VectorXd& b) {
    return R.triangularView<Eigen::Upper>().transpose().solve(b);
  }

  // `_first_order`: the least-squares multipliers (Eqs. 4.11-4.12) and ||L^T grad|| (Eqs. D.9, D.30), or bound_kkt
  void first_order(const Eval& ev, const VectorXd& q, const MatrixXd& R, const MatrixXd& Y, const MatrixXd& L, bool ok,
                   FirstOrder& fo) const {
    fo.computed = true;
    if (bounds_ || !ok) return bound_kkt(ev.G, ev.grad, q, fo);
    fo.lam = -R.triangularView<Eigen::Upper>().solve(Y.transpose() * ev.grad);
    fo.normality = (L.transpose() * ev.grad).norm();
    fo.L = L;
    fo.active.resize(0);
  }

  // common.bound_kkt: grad z + A^T y + E^T nu = 0 on the limits that hold, releasing those that pull the wrong way
  void bound_kkt(const MatrixXd& A, const VectorXd& grad, const VectorXd& q, FirstOrder& fo) const {
    const int m = static_cast<int>(A.rows()), n = n_;
    std::vector<char> act(n, 0);
    VectorXd side = VectorXd::Constant(n, -1.0);
    if (bounds_)
      for (int i = 0; i < n; ++i) {
        const bool lo = q[i] <= lo_[i] + c_.active_tol, hi = q[i] >= hi_[i] - c_.active_tol;
        act[i] = lo || hi;
        if (hi) side[i] = 1.0;
      }
    const double gscale = std::max(1.0, max_abs(grad));
    while (true) {
      std::vector<int> idx;
      for (int i = 0; i < n; ++i)
        if (act[i]) idx.push_back(i);
      const int k = static_cast<int>(idx.size());
      MatrixXd C = MatrixXd::Zero(m + k, n);
      C.topRows(m) = A;
      for (int j = 0; j < k; ++j) C(m + j, idx[j]) = 1.0;
      Eigen::JacobiSVD<MatrixXd> svd(C, Eigen::ComputeFullU | Eigen::ComputeFullV);
      const VectorXd& s = svd.singularValues();
      int rank = 0;
      const double floor = c_.rank_tol * std::max(s.size() ? s[0] : 0.0, 1e-300);
      for (int i = 0; i < s.size(); ++i) rank += s[i] > floor;
      const MatrixXd& V = svd.matrixV();
      // least squares of C^T y = -grad, Eq. (4.12)
      const VectorXd c = (V.leftCols(rank).transpose() * grad).cwiseQuotient(s.head(rank));
      const VectorXd y = -(svd.matrixU().leftCols(rank) * c);
      int worst = -1;
      double lowest = 0.0;
      bool wrong = false;
      for (int j = 0; j < k; ++j) {
        const double v = side[idx[j]] * y[m + j];
        if (v < -1e-12 * gscale) wrong = true;
        if (worst < 0 || v < lowest) worst = j, lowest = v;
      }
      if (!wrong) {
        fo.L = V.rightCols(n - rank);
        fo.normality = (fo.L.transpose() * grad).norm();  // Eq. (D.30)
        fo.lam = y.head(m);
        fo.active.resize(n);
        for (int i = 0; i < n; ++i) fo.active[i] = act[i] ? 1.0 : 0.0;
        return;
      }
      act[idx[worst]] = 0;
    }
  }

  bool in_box(const VectorXd& q) const {
    return !((q.array() < lo_.array()).any() || (q.array() > hi_.array()).any());
  }

  void clip(VectorXd& q) const {
    if (bounds_) q = q.cwiseMax(lo_).cwiseMin(hi_);
  }

  static VectorXd cap_step(const VectorXd& d, double max_step) {
    const double big = max_abs(d);
    return big > max_step ? VectorXd(d * (max_step / big)) : d;
  }

  // ||e||^2 and e at q from the pose alone (Kinematics.pose, TaskResidual.error_terms); false near a half turn
  bool error_at(const VectorXd& q, VectorXd& e, double& ee) {
    pinocchio::forwardKinematics(model_, data_, q);
    const auto& oMf = pinocchio::updateFramePlacement(model_, data_, fid_);
    return error(oMf.rotation(), oMf.translation(), e, ee, nullptr);
  }

  // The joints at a limit, held there (qp._initial_held): 0 free, -1 held at lb, +1 held at ub
  static std::vector<int> initial_held(const VectorXd& lb, const VectorXd& ub) {
    std::vector<int> held(lb.size(), 0);
    for (int i = 0; i < lb.size(); ++i)
      if (lb[i] >= 0.0) held[i] = -1;
      else if (ub[i] <= 0.0) held[i] = 1;
    return held;
  }

  // d with the held joints at their bounds and the free ones zero; the free joints' indices
  static VectorXd held_part(const std::vector<int>& held, const VectorXd& lb, const VectorXd& ub,
                            std::vector<int>& free) {
    VectorXd d = VectorXd::Zero(lb.size());
    free.clear();
    for (int i = 0; i < lb.size(); ++i)
      if (held[i]) d[i] = held[i] < 0 ? lb[i] : ub[i];
      else free.push_back(i);
    return d;
  }

  // qp._pushed_out: hold the free joints that d puts past a bound there; whether any was
  static bool push_out(const std::vector<int>& free, const VectorXd& d, const VectorXd& lb, const VectorXd& ub,
                       std::vector<int>& held) {
    bool out = false;
    for (const int i : free)
      if (!(lb[i] <= d[i] && d[i] <= ub[i])) held[i] = d[i] < lb[i] ? -1 : 1, out = true;
    return out;
  }

  // qp._pulled_in: the held joint that the Lagrangian's gradient pulls into the box hardest (its multiplier's sign
  // wrong), or -1 where it pulls none
  static int pulled_in(const std::vector<int>& held, const VectorXd& grad) {
    const double tol = 1e-12 * (1.0 + max_abs(grad));
    int worst = -1;
    double least = 0.0;
    for (int i = 0; i < grad.size(); ++i) {
      if (!held[i]) continue;
      const double pull = held[i] < 0 ? grad[i] : -grad[i];  // > 0 pushes outwards
      if (worst < 0 || pull < least) worst = i, least = pull;
    }
    return worst >= 0 && least < -tol ? worst : -1;
  }

  // qp._active_set_guess: min 1/2 d^T H d + g^T d within lb <= d <= ub (H positive definite) where a guess of the
  // active set (the joints at a limit; then also those the guess pushes past one, or less the held one pulled in
  // hardest) meets the QP's KKT conditions (then the QP's unique solution). False: no guess did.
  bool box_guess(const MatrixXd& H, const VectorXd& g, const VectorXd& lb, const VectorXd& ub, VectorXd& d) const {
    std::vector<int> held = initial_held(lb, ub), free;
    for (int round = 0; round < c_.guess_rounds; ++round) {
      d = held_part(held, lb, ub, free);
      const int nf = static_cast<int>(free.size());
      if (nf == 0) return false;
      MatrixXd Hff(nf, nf);
      VectorXd rhs(nf);
      const VectorXd Hd = H * d;
      for (int a = 0; a < nf; ++a) {
        rhs[a] = -(g[free[a]] + Hd[free[a]]);
        for (int b = 0; b < nf; ++b) Hff(a, b) = H(free[a], free[b]);
      }
      Eigen::LLT<MatrixXd> llt(Hff);  // dposv's Cholesky solve of the free block
      if (llt.info() != Eigen::Success) return false;
      const VectorXd x = llt.solve(rhs);
      for (int a = 0; a < nf; ++a) d[free[a]] = x[a];
      if (push_out(free, d, lb, ub, held)) continue;
      const int wrong = pulled_in(held, H * d + g);
      if (wrong < 0) return true;
      held[wrong] = 0;  // released
    }
    return false;
  }

  // qp._equality_guess: min 1/2 d^T B d + c^T d s.t. G d = -e within lb <= d <= ub (B positive definite) where a
  // guess of the active set meets the QP's KKT conditions; the free joints from the KKT system
  // [B_ff G_f^T; G_f 0] [d_f; y] = [-(c + B d_h)_f; -e - G d_h] (LU with partial pivoting, as dgesv).
  bool box_equality(const MatrixXd& B, const VectorXd& c, const MatrixXd& G, const VectorXd& e, const VectorXd& lb,
                    const VectorXd& ub, VectorXd& d) const {
    const int m = static_cast<int>(e.size());
    std::vector<int> held = initial_held(lb, ub), free;
    for (int round = 0; round < c_.guess_rounds; ++round) {
      d = held_part(held, lb, ub, free);
      const int nf = static_cast<int>(free.size());
      if (nf < m) return false;  // G_f d_f = -e - G d_h has no solution in general
      MatrixXd A = MatrixXd::Zero(nf + m, nf + m);
      VectorXd rhs(nf + m);
      const VectorXd Bd = B * d;
      for (int a = 0; a < nf; ++a) {
        rhs[a] = -(c[free[a]] + Bd[free[a]]);
        for (int b = 0; b < nf; ++b) A(a, b) = B(free[a], free[b]);
        A.block(nf, a, m, 1) = G.col(free[a]);
        A.block(a, nf, 1, m) = G.col(free[a]).transpose();
      }
      rhs.tail(m) = -e - G * d;
      Eigen::PartialPivLU<MatrixXd> lu(A);
      const VectorXd x = lu.solve(rhs);
      if (!x.allFinite()) return false;
      for (int a = 0; a < nf; ++a) d[free[a]] = x[a];
      if (push_out(free, d, lb, ub, held)) continue;
      const int wrong = pulled_in(held, B * d + c + G.transpose() * x.tail(m));
      if (wrong < 0) return true;
      held[wrong] = 0;  // released
    }
    return false;
  }

  // Whether G d = -e has no solution within lb <= d <= ub, certified (Farkas): y = G d + e of a step d (the box least
  // squares') with y^T (G d' + e) >= y^T e + sum_i min(lb_i a_i, ub_i a_i) > 0 for every d' in the box (a = G^T y),
  // by a margin far above what proxsuite's tolerance (eps_abs 1e-11 on G d' + e and on the box) could close: then
  // qp.BoxStep.equality's proxsuite call does not solve the QP. Else, the same from the box least squares with the
  // tiny damping mu' = INFEASIBLE_DAMPING max|G|^2 (by box_guess): ||G d + e||^2 + mu' ||d||^2 above mu' ||d_f||^2 for
  // every d_f in the box. False: not certified.
  bool infeasible(const Eval& ev, const VectorXd& d, const VectorXd& lb, const VectorXd& ub) const {
    if (farkas(ev, d, lb, ub)) return true;
    const double mu = INFEASIBLE_DAMPING * std::pow(ev.G.cwiseAbs().maxCoeff(), 2);
    MatrixXd H = ev.G.transpose() * ev.G;
    H.diagonal().array() += mu;
    VectorXd dt;
    if (!box_guess(H, ev.G.transpose() * ev.e, lb, ub, dt)) return false;
    const double reach = lb.cwiseAbs().cwiseMax(ub.cwiseAbs()).squaredNorm();  // max ||d_f||^2 over the box
    return (ev.G * dt + ev.e).squaredNorm() + mu * dt.squaredNorm() > mu * reach + INFEASIBLE_MARGIN ||
           farkas(ev, dt, lb, ub);
  }

  bool farkas(const Eval& ev, const VectorXd& d, const VectorXd& lb, const VectorXd& ub) const {
    const VectorXd y = ev.G * d + ev.e, a = ev.G.transpose() * y;
    const double h = y.dot(ev.e) + lb.cwiseProduct(a).cwiseMin(ub.cwiseProduct(a)).sum();
    return h > FARKAS_MARGIN * (std::sqrt(static_cast<double>(m_)) * y.norm() + a.cwiseAbs().sum());
  }

  // BoxStep.least_squares where qp._active_set_guess solves it: min 1/2 ||G d + e||^2 + mu/2 ||d||^2 within
  // lo - q <= d <= hi - q. False: no guess did (then proxsuite, Python's).
  bool box_least_squares(const Eval& ev, double mu, const VectorXd& q, VectorXd& d) const {
    MatrixXd H = ev.G.transpose() * ev.G;
    H.diagonal().array() += mu;
    return box_guess(H, ev.G.transpose() * ev.e, lo_ - q, hi_ - q, d);
  }

  double lm_damping(const Eval& ev) const {
    return c_.lm_weight * ev.ee + c_.damping * std::pow(ev.G.cwiseAbs().maxCoeff(), 2);
  }

  // `_restore`: a damped least-squares step on the constraints alone, backtracking on 1/2 ||e||^2
  int restore(State& st, const Eval& ev) {
    const int m = m_, n = n_;
    const double mu = lm_damping(ev);
    MatrixXd A = MatrixXd::Zero(m + n, n);  // damped_step: [G; sqrt(mu) 1] d = [-e; 0]
    A.topRows(m) = ev.G;
    A.bottomRows(n).diagonal().setConstant(std::sqrt(mu));
    VectorXd rhs = VectorXd::Zero(m + n);
    rhs.head(m) = -ev.e;
    VectorXd d = A.householderQr().solve(rhs);
    // the box least squares where the active-set guess solves it (else Python's, with proxsuite)
    if (bounds_ && !in_box(st.q + d) && !box_least_squares(ev, mu, st.q, d)) return RESTORE_BOX;
    d = cap_step(d, c_.max_step);
    const double slope = ev.e.dot(ev.G * d);
    if (!(slope < 0.0)) return RESTORE_FAILED;
    const double phi = 0.5 * ev.ee;
    VectorXd et;
    double eet;
    for (double alpha = 1.0; alpha >= c_.min_alpha; alpha *= 0.5) {
      VectorXd qt = st.q + alpha * d;
      clip(qt);
      if (!error_at(qt, et, eet)) return LOG_NEAR_PI;
      if (0.5 * eet <= phi + c_.armijo * alpha * slope) {
        st.q = qt;
        return -1;
      }
    }
    return RESTORE_FAILED;
  }

  // The Newton-SQP step x0 + L u of Eq. (D.26) and the merit search (`_iterate`'s second half, `_merit_search`)
  int newton_step(State& st, const Eval& ev, const FirstOrder& fo, const MatrixXd& R, const MatrixXd& Y,
                  const MatrixXd& L, const VectorXd& x0) {
    const int n = n_;
    VectorXd lam_k;
    Vector6d mu;
    k_multipliers(ev, fo.lam, lam_k, mu);
    const double enorm = std::sqrt(ev.ee);
    st.rho = std::max(st.rho, 1.5 * fo.lam.norm() + 1.0);  // exact penalty > ||lambda||
    const double rho = st.rho;
    MatrixXd M;
    contract_hessian(ev.H, n, mu, M);  // Lambda, Eqs. (4.20)-(4.26)
    M.diagonal() += w_;                // + Hess z
    if (task_ == AXIS) M += axis_extra(ev, fo.lam);
    const MatrixXd Br = L.transpose() * M * L;
    Eigen::SelfAdjointEigenSolver<MatrixXd> es(0.5 * (Br + Br.transpose()));
    const VectorXd& w = es.eigenvalues();
    const MatrixXd& V = es.eigenvectors();
    const VectorXd wmod = w.cwiseAbs().cwiseMax(1e-8 * std::max(1.0, max_abs(w)));  // PD where D.33 fails
    const VectorXd gr = L.transpose() * ev.grad;
    VectorXd u = -V * ((V.transpose() * (gr + L.transpose() * (M * x0))).cwiseQuotient(wmod));  // Eq. (D.26)
    VectorXd d = x0 + cap_step(L * u, c_.max_step);
    if (ev.grad.dot(d) - rho * enorm >= 0.0 && gr.dot(gr) > 0.0) {
      u = -V * ((V.transpose() * gr).cwiseQuotient(wmod));  // a sure descent direction
      d = x0 + cap_step(L * u, c_.max_step);
    }
    if (bounds_ && !in_box(st.q + d)) {  // the box QP: BoxStep.equality, else BoxStep.least_squares
      const VectorXd lb = lo_ - st.q, ub = hi_ - st.q;
      const MatrixXd LV = L * V;
      const MatrixXd B = LV * wmod.asDiagonal() * LV.transpose() + Y * Y.transpose();  // Eq. (D.26)'s model, PD
      const VectorXd c = ev.grad + L * (L.transpose() * (M * x0));
      VectorXd dq;
      if (box_equality(B, c, ev.G, ev.e, lb, ub, dq) ||
          (box_least_squares(ev, lm_damping(ev), st.q, dq) && infeasible(ev, dq, lb, ub)))
        d = cap_step(dq, c_.max_step);
      else
        return BOX_QP;  // proxsuite's (Python's)
    }
    const VectorXd Gd = ev.G * d;
    const double slope = ev.grad.dot(d) + rho * (enorm > 0.0 ? ev.e.dot(Gd) / enorm : Gd.norm());
    const double phi = ev.z + rho * enorm;
    // _merit_search: Armijo backtracking with a second-order correction at each trial point
    VectorXd et;
    for (double alpha = 1.0; alpha >= c_.min_alpha; alpha *= 0.5) {
      VectorXd qt = st.q + alpha * d;
      clip(qt);
      double phit;
      if (!merit(qt, rho, phit, et)) return LOG_NEAR_PI;
      const double goal = phi + c_.armijo * alpha * slope;
      if (phit <= goal || (alpha == 1.0 && -slope <= 1e-12 * (1.0 + std::abs(phi)) && max_abs(d) < 1e-6)) {
        st.q = qt;
        return -1;
      }
      VectorXd qc = qt + Y * solve_rt(R, -et);  // second-order correction
      clip(qc);
      double phic;
      VectorXd ec;
      if (!merit(qc, rho, phic, ec)) return LOG_NEAR_PI;
      if (phic <= goal) {
        st.q = qc;
        return -1;
      }
      if (!(slope < 0.0)) return MERIT_FAILED;
    }
    return MERIT_FAILED;
  }

  // `_merit`: phi = z + rho ||e|| at q, and e
  bool merit(const VectorXd& q, double rho, double& phi, VectorXd& e) {
    double ee;
    if (!error_at(q, e, ee)) return false;
    const VectorXd f = q - ref_;
    phi = 0.5 * f.dot(w_.cwiseProduct(f)) + rho * std::sqrt(ee);
    return true;
  }

  pinocchio::Model model_;
  pinocchio::Data data_;
  pinocchio::FrameIndex fid_ = 0;
  int n_ = 0, m_ = 0, task_ = 0, max_iter_ = 0;
  Constants c_{};
  Matrix3d Qd_, QdT_;
  Vector3d pd_, vect_d_;
  VectorXd w_, ref_, lo_, hi_;
  double trace_d_ = 0.0, rtol_ = 0.0, tol_ = 0.0, deadline_ = 0.0;
  bool bounds_ = false;
};

void bind_ik(nb::module_& m) {
  nb::class_<IKCore>(m, "IKCore")
      .def(nb::init<nb::handle, int, CRef>(), nb::arg("model"), nb::arg("frame_id"), nb::arg("constants"))
      .def("run", &IKCore::run, nb::arg("q0"), nb::arg("task"), nb::arg("Qd"), nb::arg("pd"), nb::arg("weights"),
           nb::arg("reference"), nb::arg("lower"), nb::arg("upper"), nb::arg("bounds"), nb::arg("rtol"), nb::arg("tol"),
           nb::arg("max_iter"), nb::arg("deadline"), nb::arg("it0"), nb::arg("rho"), nb::arg("r_ref"), nb::arg("since"),
           nb::arg("q_prev"), nb::arg("r_prev"), nb::arg("on_q"), nb::arg("on_z"), nb::arg("on_r"));
}

}  // namespace kinredund
