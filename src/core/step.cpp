// The default mode's ordinary step in C++ (issue 28): the Hermite predictor, one evaluation (Pinocchio's
// kinematics and Hessian, the task terms of every task kind in both forms, the index terms of JointDeviation and
// TimeVaryingReference), R of Eq. (4.24), its LU and condition estimate, the rates, the Newton update and the chord
// iterations, then the checks that make a step ordinary (no limit crossed, no jump). It mirrors the Python
// reference (kinredund/tracking/predictor_corrector.py, point.py, tasks/*, step_control.py) operation by operation;
// R's LU is LAPACK's unblocked algorithm in LAPACK's layout (the watch solves with it through scipy).
// With joints held on their bounds (kinredund/tracking/limited.py: set_active) the step runs on the reduced system:
// the held joints' columns leave R, their rows of the residual are the bound multipliers', and the multipliers
// mu_i = s_i (grad z + J^T lambda)_i come out at the corrected point; a multiplier below zero (a release) is a switch.
// Anything not ordinary returns a status code and the Python reference takes the step from the same state.
// The run's start (start_run: PredictorCorrector.__init__'s corrector onto the optimum, then the rates and the
// watch's first, exact measurement) runs here too, with the GIL released; a start that is not ordinary is the
// Python reference's likewise (it then names the failure). The Python stepper's own corrector solves (a handed-back
// step's, a sub-step's, the switching-time search's: kinredund/tracking/compiled_correct.py) run here as well
// (correct: advance()'s corrector without its verdicts, the fallback through start_at).
#include "brent.hpp"
#include "frame.hpp"
#include "rows.hpp"
#include "step.hpp"
#include "watch.hpp"

#include <nanobind/eigen/dense.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/vector.h>

#include <pinocchio/algorithm/frames.hpp>
#include <pinocchio/algorithm/jacobian.hpp>
#include <pinocchio/algorithm/kinematics-derivatives.hpp>
#include <pinocchio/algorithm/kinematics.hpp>
#include <pinocchio/multibody/data.hpp>
#include <pinocchio/multibody/model.hpp>

#include <Eigen/Eigenvalues>
#include <Eigen/LU>

#include <cmath>
#include <memory>
#include <stdexcept>
#include <vector>

namespace nb = nanobind;

namespace kinredund {

const pinocchio::Model& model_ref_from_python(nb::handle obj);  // module.cpp

namespace {

using MatrixXd = Eigen::MatrixXd;  // column-major: LAPACK's layout
using VectorXd = Eigen::VectorXd;
using VectorXi = Eigen::VectorXi;
using RowMatrixXd = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
using Matrix3d = Eigen::Matrix3d;
using Vector3d = Eigen::Vector3d;
using CRef = Eigen::Ref<const VectorXd>;
using Vec1 = nb::ndarray<const double, nb::ndim<1>, nb::c_contig, nb::device::cpu>;
using Mat3 = nb::ndarray<const double, nb::ndim<2>, nb::device::cpu>;  // any strides (a 3x3 rotation, or 0x0)

// Task kinds (kinredund/tasks/*): the codes compiled.py passes.
enum Task { PLANAR = 0, POSITION = 1, POSE = 2, AXIS = 3 };
// Why a step is handed back to the Python reference.
constexpr int OK = 0, FACTOR_SINGULAR = 1, RCOND_LOW = 2, NOT_FINITE = 3, CHORD_FAILED = 4, JUMP = 5, LIMIT = 6,
              LOG_NEAR_PI = 7, RELEASE = 11, ROW_RELEASE = 14;
// Why StepCore.locate left a switching-time search to Python (besides the corrector's codes and brent.hpp's): a time
// not after the anchor (the caller reads the anchor's own state there), a watched value that is NaN, a row the guard
// cannot hold (a scene's row without a pair: constant, so never the row of a search).
constexpr int LOCATE_AT_ANCHOR = 22, LOCATE_NAN = 23, LOCATE_NOT_HOLDABLE = 24;

struct Sample {
  Vector3d p, v, omega;
  Matrix3d Q;
};

}  // namespace

class StepCore {
  friend const int* step_core_free(const StepCore&, int&);
  friend RowSource* step_core_guard(const StepCore&);
  friend RowIndicesPtr step_core_held_rows(const StepCore&);
  friend const double* step_core_factors(const StepCore&, const int*&, int&);
  friend int step_core_advance(StepCore&, const StepInput&, const double*, const double*,
                               const std::vector<const double*>&, const double*, double, bool, double*);

 public:
  StepCore(nb::handle model, int frame_id, int task, bool velocity, CRef weights, CRef reference, bool time_varying,
           double tol, double dt, std::vector<VectorXd> hermite, CRef lo_tol, CRef hi_tol)
      : model_obj_(nb::borrow(model)), model_(model_ref_from_python(model)), fid_(frame_id), task_(task),
        velocity_(velocity),
        w_(weights), ref_(reference), time_varying_(time_varying), tol_(tol), dt_(dt), hermite_(std::move(hermite)),
        lo_(lo_tol), hi_(hi_tol) {
    n_ = model_.nv;
    if (model_.nq != n_) throw nb::value_error("the compiled step needs nq == nv (revolute and prismatic joints)");
    if (frame_id < 0 || frame_id >= static_cast<int>(model_.nframes)) throw nb::value_error("frame id out of range");
    if (task < PLANAR || task > AXIS) throw nb::value_error("unknown task code");
    m_ = mt_ = task == PLANAR ? 2 : task == POSITION ? 3 : task == POSE ? 6 : 5;
    if (w_.size() != n_ || ref_.size() != n_) throw nb::value_error("weights and reference must have n entries");
    limited_ = lo_.size() == n_;
    for (size_t k = 1; k < hermite_.size(); ++k)  // the predictor's weights through k + 1 points (linalg.py)
      if (hermite_[k].size() != static_cast<Eigen::Index>(2 * k + 2))
        throw nb::value_error("hermite[k] must hold the 2 k + 2 weights of the predictor through k + 1 points");
    if (hermite_.size() < 2) throw nb::value_error("hermite: the weights of at least two points");
    J6_.setZero(6, n_);
    K_.setZero(6, n_);
    free_.setLinSpaced(n_, 0, n_ - 1);
    bound_.setZero(n_);
    side_.setZero(n_);
  }

  int n() const { return n_; }
  int m() const { return m_; }
  // The size of advance()'s output (its layout at its end).
  Eigen::Index output_size() const {
    const Eigen::Index n = n_, N = n_ + m_;
    return 2 * N + n * n + m_ * n + n + 12 + 2 * n + 1 + 2;
  }

  // The active set of the simple bounds (LimitedPredictorCorrector.active_set): the free joints (ascending), the
  // bound values (n, read at the held joints) and the sides (n: +1 at a lower bound, -1 at an upper one, 0 free).
  void set_active(const Eigen::Ref<const VectorXi>& free, CRef bound, CRef side) {
    if (bound.size() != n_ || side.size() != n_) throw nb::value_error("bound and side must have n entries");
    if (free.size() < mt_ || free.size() > n_) throw nb::value_error("free: between m and n joint numbers");
    for (Eigen::Index k = 0; k < free.size(); ++k)
      if (free[k] < 0 || free[k] >= n_ || (k > 0 && free[k] <= free[k - 1]))
        throw nb::value_error("free: ascending joint numbers in [0, n)");
    free_ = free;
    bound_ = bound;
    side_ = side;
    held_.assign(n_, 0);
    for (int i = 0; i < n_; ++i) held_[i] = 1;
    for (Eigen::Index k = 0; k < free.size(); ++k) held_[free[k]] = 0;
    any_held_ = free.size() < n_;
  }

  // One ordinary step to time t (see the file's comment). ``prev``: the predictor's history (y, ydot, ...),
  // oldest first; ``qdot0``, ``speed2``: the rates at the step's start and the step control's last speed^2
  // (``check_jump``: the strict step control's jump check). Returns one array (its layout at the end) or the
  // status code that hands the step back to Python.
  nb::object step(double t, CRef sp, CRef sv, Mat3 sQ, CRef somega, CRef ref_t, CRef rate_t, CRef y, CRef yd,
                  nb::list prev_list, CRef qdot0, double speed2_prev, bool check_jump) {
    return step_checked(t, sp, sv, sQ, somega, ref_t, rate_t, y, yd, prev_list, qdot0, speed2_prev, check_jump,
                        nullptr, 0.0);
  }

  // The rows' check (rows.hpp's RowSource: a scene's RowGuard, distances.cpp, a frame's FrameRows, frame_rows.cpp,
  // or several stacked, row_stack.cpp; issue 27) that step_guarded runs after an ordinary step; None: none.
  void set_guard(nb::object guard) {
    if (guard.is_none()) {
      guard_ = nullptr;
    } else {
      RowSource& g = row_source(guard);
      if (g.nv() != n_) throw nb::value_error("the row guard's arrays must have the step's n entries");
      guard_ = &g;
    }
    guard_obj_ = guard;  // keeps the guard (and what it computes with) alive while it is used
    rows_.resize(0);
    na_ = 0;
    m_ = mt_;
  }

  // The general rows held (issue 27: GeneralRows.rows, kinredund/tracking/rows.py): the guard's rows `rows` (each
  // one it can hold: a scene's with a pair) appended to the task's equations, lam = [lambda; w], and their
  // curvature sum_i w_i Hess c_i (the guard's: SceneClearance.curvature's central differences with step eps, or a
  // frame clearance's analytic one) added to M, as RowPoint extends the evaluation; the step then has m = the
  // task's + len(rows) multipliers. Empty: none.
  void set_rows(const Eigen::Ref<const RowIndices>& rows, double eps) {
    if (rows.size() > 0 && guard_ == nullptr) throw nb::value_error("rows need the guard that computes them");
    if (!(eps > 0.0) || !std::isfinite(eps)) throw nb::value_error("eps must be a finite step > 0");
    for (Eigen::Index i = 0; i < rows.size(); ++i)
      if (rows[i] < 0 || rows[i] >= guard_->size() || !guard_->holdable(rows[i]))
        throw nb::value_error("rows: the guard's rows (each one it can hold)");
    rows_ = rows;
    eps_ = eps;
    na_ = static_cast<int>(rows.size());
    m_ = mt_ + na_;
  }
  // the number of rows held (set_rows)
  int held_rows() const { return na_; }

  // step() and, after an ordinary step, the guard's check of it (its clear_at from the step's start y[:n] with
  // rates qdot0 to its end, h [s] long; h < 0 or no guard: not cleared): the status code, or (array, cleared,
  // smallest), smallest the guard's least row value at the step's end (its smallest; NaN where it did not run).
  nb::object step_guarded(double h, double t, CRef sp, CRef sv, Mat3 sQ, CRef somega, CRef ref_t, CRef rate_t,
                          CRef y, CRef yd, nb::list prev_list, CRef qdot0, double speed2_prev, bool check_jump) {
    bool cleared = false;
    nb::object out = step_checked(t, sp, sv, sQ, somega, ref_t, rate_t, y, yd, prev_list, qdot0, speed2_prev,
                                  check_jump, &cleared, h);
    if (nb::isinstance<nb::int_>(out)) return out;
    const bool ran = guard_ != nullptr && h >= 0.0;  // (step_checked ran the guard on every ordinary step then)
    return nb::make_tuple(out, cleared, ran ? guard_->smallest() : std::numeric_limits<double>::quiet_NaN());
  }

 private:
  nb::object step_checked(double t, CRef sp, CRef sv, Mat3 sQ, CRef somega, CRef ref_t, CRef rate_t, CRef y,
                          CRef yd, nb::list prev_list, CRef qdot0, double speed2_prev, bool check_jump,
                          bool* cleared, double h) {
    const size_t np_ = nb::len(prev_list);
    if (np_ > 2 * hermite_.size() - 2 || np_ % 2) throw nb::value_error("prev: (y, ydot) pairs, at most two");
    Vec1 prev[4];
    for (size_t j = 0; j < np_; ++j) prev[j] = nb::cast<Vec1>(prev_list[j]);
    const int n = n_, N = n_ + m_;
    if (y.size() != N || yd.size() != N) throw nb::value_error("y and ydot must have n + m entries");
    set_sample(sp, sv, sQ, somega);
    set_reference(ref_t, rate_t);
    std::vector<const double*> prevp(np_);
    for (size_t j = 0; j < np_; ++j) {
      if (prev[j].shape(0) != static_cast<size_t>(N)) throw nb::value_error("prev entries must have n + m entries");
      prevp[j] = prev[j].data();
    }
    if (qdot0.size() != n) throw nb::value_error("qdot0 must have n entries");
    std::unique_ptr<VectorXd> out(new VectorXd(output_size()));
    int st;
    {
      nb::gil_scoped_release release;  // the step touches no Python object: trackers in threads step in parallel
      st = advance(y, yd, prevp, qdot0, speed2_prev, check_jump, *out);
      if (st == OK && cleared != nullptr && guard_ != nullptr && h >= 0.0)  // [q; lam] and its rates lead the row
        *cleared = guard_->clear_at(y.data(), out->data(), qdot0.data(), out->data() + N, h, &rows_);
    }
    if (st != OK) return nb::int_(st);
    return numpy_of(std::move(out));
  }

  // A row as a numpy array that owns it.
  static nb::object numpy_of(std::unique_ptr<VectorXd> out) {
    VectorXd* buf = out.release();
    nb::capsule owner(buf, [](void* p) noexcept { delete static_cast<VectorXd*>(p); });
    size_t shape[1] = {static_cast<size_t>(buf->size())};
    return nb::cast(nb::ndarray<nb::numpy, double, nb::ndim<1>>(buf->data(), 1, shape, owner),
                    nb::rv_policy::reference);
  }

 public:
  // The run's start at the time of the sample (start_run; kinredund/tracking/compiled.py's CompiledStart): from
  // y0 = [q0; lambda0] (the held joints on their bounds) the corrector onto F = 0 (Eq. 4.5 and the task), then the
  // rates there (Eq. 4.24), the bound multipliers of the held joints and the watch's exact measurement on the free
  // joints' J and M (watch_exact), with the GIL released. Returns (the output row of step(): the corrected point,
  // its rates, M and J there, the corrected joints as the predicted and evaluated ones, the pose there, mu, the label
  // verdict, rcond, |qdot|^2; (sigma_min_J, eig, v, scale)) or the status code that leaves the start to Python.
  nb::object start(CRef sp, CRef sv, Mat3 sQ, CRef somega, CRef ref_t, CRef rate_t, CRef y0) {
    if (y0.size() != n_ + m_) throw nb::value_error("y0 must have n + m entries");
    set_sample(sp, sv, sQ, somega);
    set_reference(ref_t, rate_t);
    std::unique_ptr<VectorXd> out(new VectorXd(output_size()));
    ExactMeasure e;
    int st;
    {
      nb::gil_scoped_release release;  // no Python object below: the starts of runs in threads overlap
      st = start_at(y0, *out, true);
      if (st == OK) {
        const int nf = static_cast<int>(free_.size()), n = n_;
        RowMatrixXd Jr(m_, nf), Mr(nf, nf);  // Watch.reduce: the free joints' columns of J, rows and columns of M
        for (int b = 0; b < nf; ++b) {
          Jr.col(b) = J_.col(free_[b]);
          for (int a = 0; a < nf; ++a) Mr(a, b) = (*out)[2 * (n + m_) + free_[a] * n + free_[b]];
        }
        watch_exact(Jr.data(), Mr.data(), m_, nf, e);
      }
    }
    if (st != OK) return nb::int_(st);
    auto* buf = new std::vector<double>(std::move(e.v));
    nb::capsule owner(buf, [](void* p) noexcept { delete static_cast<std::vector<double>*>(p); });
    nb::ndarray<nb::numpy, double, nb::ndim<1>> v(buf->data(), {buf->size()}, owner);
    return nb::make_tuple(numpy_of(std::move(out)), nb::make_tuple(e.sigma, e.eig, v, e.scale));
  }

  // PredictorCorrector._correct (LimitedPredictorCorrector's, on the reduced system where joints are held) at the
  // time of the sample from the prediction y = [q; lambda], with the GIL released (correct_at): the corrected point,
  // its rates and the bound multipliers there, without advance()'s LIMIT, RELEASE and JUMP verdicts (the Python
  // stepper, which calls it through kinredund/tracking/compiled_correct.py, judges those). Returns (the output row
  // of step(), restarted: the chord iterations failed and the fallback (_newton, _rates) made the point, R's LU
  // factors in LAPACK's layout (column-major), their 0-based pivots (int32)) or the status code that leaves the
  // corrector to Python (which then runs it from the same inputs: the core touched no Python state). ``newton``:
  // no prediction, the fallback's route from y itself (_newton, then _rates: start_at; restarted True), as after a
  // switch of the active set (kinredund/tracking/switches.py).
  nb::object correct(double t, CRef sp, CRef sv, Mat3 sQ, CRef somega, CRef ref_t, CRef rate_t, CRef y,
                     bool newton) {
    (void)t;  // (the sample is at t)
    if (y.size() != n_ + m_) throw nb::value_error("y must have n + m entries");
    set_sample(sp, sv, sQ, somega);
    set_reference(ref_t, rate_t);
    std::unique_ptr<VectorXd> out(new VectorXd(output_size()));
    bool restarted = false;
    int st;
    {
      nb::gil_scoped_release release;  // no Python object below
      restarted = newton;
      st = newton ? start_at(y, *out, false) : correct_at(y, *out, restarted);
    }
    if (st != OK) return nb::int_(st);
    MatrixXd lu = lu_;
    VectorXi piv = ipiv_;
    return nb::make_tuple(numpy_of(std::move(out)), restarted, lu, piv);
  }

  // SwitchLocation._crossing's search (kinredund/tracking/switches.py) in the core: the time in (a, b] where a switch's
  // watched quantity reaches zero on the corrected path, by Brent's method (brent.hpp, as roots.py's brent_root), each
  // evaluation at tau PredictorCorrector.euler_to from the anchor (t_a, y_a, yd_a): the Euler prediction
  // y_a + (tau - t_a) yd_a and correct_at() there, the GIL released. The quantity: sign (out[index] - level) of the
  // corrected point's output row (a joint's margin to its bound, a bound's or a held row's multiplier), or with row >= 0
  // the guard's value c of that row (GeneralRows._row_watch: c where c >= 0 or own_at(q) says the row stands for
  // itself at q, else stand_in; own_at None: it always does). fa, fb: the quantity at a and b (fb NaN: evaluated here);
  // sample_at(tau): the path's (p, v, Q, omega, ref, rate) at tau, as correct() takes them. Returns the time, or the
  // status code of anything else: a corrector solve that is not ordinary, a NaN, a time not after the anchor, no
  // bracket, no convergence (brent.hpp); the caller's own search then runs from the same inputs and meets it itself.
  nb::object locate(double t_a, CRef y_a, CRef yd_a, double a, double b, double fa, double fb, Eigen::Index index,
                    double sign, double level, Eigen::Index row, double stand_in, nb::callable sample_at,
                    nb::object own_at, double xtol, double rtol, int maxiter) {
    const Eigen::Index N = n_ + m_;
    if (y_a.size() != N || yd_a.size() != N) throw nb::value_error("y_a and yd_a must have n + m entries");
    if (row >= 0 && (guard_ == nullptr || row >= guard_->size()))
      throw nb::value_error("row: one of the guard's rows (a guard is needed)");
    if (row >= 0 && !guard_->holdable(row)) return nb::int_(LOCATE_NOT_HOLDABLE);  // (a constant row: never reached)
    if (row < 0 && (index < 0 || index >= output_size())) throw nb::value_error("index: an entry of the output row");
    VectorXd out(output_size()), c;
    RowMatrixXd G;
    RowIndices one(1);
    one[0] = row;
    auto phi = [&](double tau, double& value) -> int {
      if (!(tau > t_a)) return LOCATE_AT_ANCHOR;
      nb::tuple s = nb::cast<nb::tuple>(sample_at(tau));  // the path's sample (Python's, the GIL held)
      if (s.size() != 6) throw nb::value_error("sample_at must return (p, v, Q, omega, ref, rate)");
      set_sample(nb::cast<VectorXd>(s[0]), nb::cast<VectorXd>(s[1]), nb::cast<Mat3>(s[2]), nb::cast<VectorXd>(s[3]));
      set_reference(nb::cast<VectorXd>(s[4]), nb::cast<VectorXd>(s[5]));
      int st;
      {
        nb::gil_scoped_release release;  // no Python object below
        bool restarted;
        st = correct_at(y_a + (tau - t_a) * yd_a, out, restarted, false);  // PredictorCorrector.euler_to
        if (st == OK && row >= 0) guard_->rows_at(out.head(n_), one, c, G);
      }
      if (st != OK) return st;
      if (row < 0) {
        value = sign * (out[index] - level);
      } else {
        value = c[0];
        if (value < 0.0 && !own_at.is_none() && !nb::cast<bool>(own_at(VectorXd(out.head(n_))))) value = stand_in;
      }
      return std::isnan(value) ? LOCATE_NAN : OK;
    };
    if (std::isnan(fb)) {
      const int st = phi(b, fb);
      if (st != OK) return nb::int_(st);
    }
    double root = 0.0;
    const int st = brent_root(phi, a, b, fa, fb, xtol, rtol, maxiter, root);
    if (st != OK) return nb::int_(st);
    return nb::float_(root);
  }

 private:
  // start(): PredictorCorrector._newton (rounds of chord iterations, each with R factorised afresh at its first
  // iterate, at most 7 rounds of at most 8 updates) and _rates (LimitedPredictorCorrector's on the reduced system,
  // _update_mu at the corrected point); fills out (start()'s row) or returns the status. ``polish`` (the run's start:
  // _newton's polish): the first round's first update is made even where F is within the tolerance.
  int start_at(CRef y0, VectorXd& out, bool polish) {
    const int n = n_;
    VectorXd y = y0;
    RowMatrixXd M;
    VectorXd top;
    bool ok = false;
    for (int round = 0; round < 7 && !ok; ++round) {
      evaluate(y.head(n), true);
      if (task_ == POSE && velocity_ && !log_ok_) return LOG_NEAR_PI;
      system(y.tail(m_), M, top);
      const int st = factor(M);
      if (st != OK) return st;
      const double tol = tol_ * std::max(1.0, std::sqrt(grad_.dot(grad_)));
      VectorXd F = residual(y.tail(m_));
      for (int it = 0; it < 8; ++it) {  // _chord: the residual afresh (without dK) after each update
        if (it > 0) {
          evaluate(y.head(n), false);
          if (task_ == POSE && velocity_ && !log_ok_) return LOG_NEAR_PI;
          F = residual(y.tail(m_));
        }
        if (F.dot(F) <= tol * tol) {
          if (!(polish && round == 0 && it == 0)) {
            ok = true;
            break;
          }
          solve(F);  // polish: one Newton update from a point already within tol (F becomes the update d)
          y -= F;
          if (F.dot(F) <= tol) {  // corrector()'s criterion: an error of order tol^2
            ok = true;
            break;
          }
          continue;
        }
        solve(F);
        y -= F;
      }
      if (!ok && !std::isfinite(y.dot(y))) break;
    }
    if (!ok) return CHORD_FAILED;
    VectorXd sol, mu;
    const int st = rates_at(y, M, sol);  // _rates at the corrected point
    if (st != OK) return st;
    evaluated_multipliers(y, mu);
    // no prediction: the corrected joints as the predicted and evaluated ones, the pose of this evaluation
    write_row(out, y, sol, M, y.head(n), y.head(n), mu, sol.head(n).dot(sol.head(n)), false);
    return OK;
  }

  // _correct's corrector, shared by advance() and correct_at(): the held joints set on their bounds in the
  // prediction yp (LimitedPredictorCorrector._correct), one evaluation there with dK, R's LU (Eq. 4.24), the rates
  // sol, the Newton update and, where it is not small, the chord iterations with fresh residuals; yc: the corrected
  // point. M: the evaluation's (its J and M kept for the watch: Jw_, Mw_); grad_scale: switches._events' scale.
  int corrector(VectorXd& yp, VectorXd& yc, VectorXd& sol, RowMatrixXd& M, double& grad_scale) {
    const int n = n_, N = n_ + m_;
    if (any_held_)
      for (int i = 0; i < n; ++i)
        if (held_[i]) yp[i] = bound_[i];
    evaluate(yp.head(n), true);
    if (task_ == POSE && velocity_ && !log_ok_) return LOG_NEAR_PI;
    const VectorXd lam = yp.tail(m_);
    VectorXd top;
    system(lam, M, top);
    Jw_ = J_;  // the step's J and M (at the predicted point: the chord iterations evaluate afresh)
    Mw_ = M;
    grad_scale = std::max(1.0, grad_.cwiseAbs().maxCoeff());
    const int st = factor(M);
    if (st != OK) return st;
    sol.resize(N);
    sol << top, xdot_;
    solve(sol);  // Eq. (4.24)
    if (!std::isfinite(sol.dot(sol))) return NOT_FINITE;
    VectorXd F = residual(lam);
    const double tol = tol_ * std::max(1.0, std::sqrt(grad_.dot(grad_)));
    yc = yp;
    if (!(F.dot(F) <= tol * tol)) {
      VectorXd d = F;
      solve(d);
      yc = yp - d;
      if (!(d.dot(d) <= tol)) return chord(yc, tol);
    }
    return OK;
  }

  // LimitedPredictorCorrector._update_mu at the corrected point yc (an evaluation without dK): mu (n, 0 where free)
  int bound_multipliers(const VectorXd& yc, VectorXd& mu) {
    if (any_held_) {
      evaluate(yc.head(n_), false);
      if (task_ == POSE && velocity_ && !log_ok_) return LOG_NEAR_PI;
    }
    evaluated_multipliers(yc, mu);
    return OK;
  }

  // _update_mu at the last evaluation, made at y's joints: mu_i = s_i (grad z + J^T lambda)_i on the held joints
  // (n, 0 where free)
  void evaluated_multipliers(const VectorXd& y, VectorXd& mu) const {
    const int n = n_;
    mu = VectorXd::Zero(n);
    if (!any_held_) return;
    const VectorXd g = grad_ + J_.transpose() * y.tail(m_);
    for (int i = 0; i < n; ++i)
      if (held_[i]) mu[i] = side_[i] * g[i];
  }

  // _rates at y = [q; lambda]: one evaluation with dK, R's LU, Eq. (4.24) for the rates sol; the evaluation's J and M
  // become the step's (the watch measures them: watch_measure)
  int rates_at(const VectorXd& y, RowMatrixXd& M, VectorXd& sol) {
    evaluate(y.head(n_), true);
    if (task_ == POSE && velocity_ && !log_ok_) return LOG_NEAR_PI;
    VectorXd top;
    system(y.tail(m_), M, top);
    Jw_ = J_;
    Mw_ = M;
    const int st = factor(M);
    if (st != OK) return st;
    sol.resize(n_ + m_);
    sol << top, xdot_;
    solve(sol);  // Eq. (4.24)
    return std::isfinite(sol.dot(sol)) ? OK : NOT_FINITE;
  }

  // One buffer (one array for Python to slice: small arrays would each be copied through numpy), the layout of
  // row_slices (kinredund/tracking/compiled_start.py): [y (N), sol (N), M (n*n, row-major), J (m*n, row-major: the
  // evaluation's, Jw_), q_pred (n), Q (9, row-major) and p (3) at the corrected joints (forward kinematics there
  // with ``fk``, else the last evaluation's, made there), the evaluation's point qe (n: q_pred with the held joints
  // on their bounds), the bound multipliers mu (n, 0 where free), the label verdict (1: label_code), rcond, speed2]
  // (output_size()); R's factors stay here (factors()).
  void write_row(VectorXd& out, const VectorXd& y, const VectorXd& sol, const RowMatrixXd& M, CRef q_pred, CRef qe,
                 const VectorXd& mu, double speed2, bool fk) {
    const int n = n_, N = n_ + m_;
    if (out.size() != output_size()) out.resize(output_size());
    double* o = out.data();
    Eigen::Map<VectorXd>(o, N) = y;
    Eigen::Map<VectorXd>(o + N, N) = sol;
    o += 2 * N;
    Eigen::Map<RowMatrixXd>(o, n, n) = M;
    o += n * n;
    Eigen::Map<RowMatrixXd>(o, m_, n) = Jw_;
    o += m_ * n;
    Eigen::Map<VectorXd>(o, n) = q_pred;
    o += n;
    Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor>> Qc(o);
    Eigen::Map<Vector3d> pc(o + 9);
    if (fk) {
      pinocchio::Data& data = this->data();
      pinocchio::forwardKinematics(model_, data, y.head(n));
      const auto& oMf = pinocchio::updateFramePlacement(model_, data, fid_);
      Qc = oMf.rotation();
      pc = oMf.translation();
    } else {
      Qc = Q_;
      pc = p_;
    }
    o += 12;
    Eigen::Map<VectorXd>(o, n) = qe;
    Eigen::Map<VectorXd>(o + n, n) = mu;
    o[2 * n] = (any_held_ || na_ > 0) && !velocity_ ? label_code(M) : 0.0;  // (rows held: the reduced route's label)
    o[2 * n + 1] = rcond_;
    o[2 * n + 2] = speed2;
  }

  // PredictorCorrector._correct (with LimitedPredictorCorrector's wrapper) at the sample's time from the prediction
  // y: the corrector (corrector()); where its chord iterations fail, the fallback from the prediction (the held
  // joints on their bounds): _newton, then _rates, which start_at() makes (``restarted``: the caller clears the
  // predictor's history); the bound multipliers at the corrected point. No LIMIT, RELEASE or JUMP verdict: the
  // caller judges those. Fills out (advance()'s layout) or returns the status. ``pose``: the pose at the corrected
  // joints written into the row (a forward kinematics pass); without it the evaluation's (locate reads no pose).
  int correct_at(CRef y, VectorXd& out, bool& restarted, bool pose = true) {
    const int n = n_;
    VectorXd yp = y, yc, sol, mu;
    RowMatrixXd M;
    double grad_scale;
    restarted = false;
    int st = corrector(yp, yc, sol, M, grad_scale);
    if (st == CHORD_FAILED) {
      restarted = true;
      return start_at(yp, out, false);
    }
    if (st != OK) return st;
    bool rerated = false;
    st = rerate(yp, yc, sol, M, grad_scale, rerated);
    if (st != OK) return st;
    if (rerated)
      evaluated_multipliers(yc, mu);
    else if ((st = bound_multipliers(yc, mu)) != OK)
      return st;
    write_row(out, yc, sol, M, y.head(n), rerated ? VectorXd(yc.head(n)) : VectorXd(yp.head(n)), mu,
              sol.head(n).dot(sol.head(n)), pose);
    return OK;
  }

  // With rows held, GeneralRows._rates_stale after the corrector: where it ended farther than 1e-8 from the
  // prediction yp, the rates afresh at the corrected point yc (LimitedPredictorCorrector._rates: one evaluation with
  // dK, R's LU, Eq. 4.24), which becomes the step's evaluation (its J and M the watch's; grad_scale its own).
  int rerate(const VectorXd& yp, const VectorXd& yc, VectorXd& sol, RowMatrixXd& M, double& grad_scale,
             bool& rerated) {
    rerated = false;
    if (na_ == 0) return OK;
    const VectorXd d = yc.head(n_) - yp.head(n_);
    if (!(d.dot(d) > 1e-16)) return OK;
    const int st = rates_at(yc, M, sol);
    if (st != OK) return st;
    grad_scale = std::max(1.0, grad_.cwiseAbs().maxCoeff());
    rerated = true;
    return OK;
  }

 public:
  // The step itself (no Python object touched: called with the GIL released); fills ``out`` (see step()).
  int advance(CRef y, CRef yd, const std::vector<const double*>& prev, CRef qdot0, double speed2_prev,
              bool check_jump, VectorXd& out) {
    const int n = n_, N = n_ + m_;
    const size_t np_ = prev.size();
    if (out.size() != output_size()) out.resize(output_size());
    // the Hermite predictor (Euler at the first step): predictor_corrector.plain_step
    VectorXd yp(N);
    if (np_ == 0) {
      yp = y + dt_ * yd;
    } else {
      const VectorXd& w = hermite_[np_ / 2];
      yp.setZero();
      for (size_t j = 0; j < np_; ++j) yp += w[j] * Eigen::Map<const VectorXd>(prev[j], N);
      yp += w[np_] * y + w[np_ + 1] * yd;
    }
    const VectorXd q_pred = yp.head(n);
    VectorXd yc, sol, mu;
    RowMatrixXd M;
    double grad_scale;
    int st = corrector(yp, yc, sol, M, grad_scale);  // _correct (the held joints on their bounds in yp)
    if (st != OK) return st;
    bool rerated = false;
    st = rerate(yp, yc, sol, M, grad_scale, rerated);
    if (st != OK) return st;
    const auto q = yc.head(n);
    // a free joint beyond its bound (a held one is on it exactly)
    if (limited_ && ((q.array() < lo_.array()).any() || (q.array() > hi_.array()).any())) return (LIMIT);
    if (rerated)
      evaluated_multipliers(yc, mu);
    else if ((st = bound_multipliers(yc, mu)) != OK)
      return st;
    if (any_held_)
      for (int i = 0; i < n; ++i)
        if (held_[i] && mu[i] < -1e-12 * grad_scale) return (RELEASE);  // switches._events: a bound to release
    for (int i = 0; i < na_; ++i)  // GeneralRows._row_events: a held row's multiplier nu = -w below zero
      if (-yc[n + mt_ + i] < -1e-12 * grad_scale) return ROW_RELEASE;
    const auto qd1 = sol.head(n);
    const double speed2 = qd1.dot(qd1);
    if (check_jump) {  // step_control.StepControl._attempt on a whole step
      VectorXd mv = q - q_pred;
      if (!(mv.dot(mv) <= (0.01 * dt_) * (0.01 * dt_) * std::max(speed2_prev, speed2))) {
        VectorXd dq = q - y.head(n);
        VectorXd e = dq - (0.5 * dt_) * (qdot0 + qd1);
        double move2 = dq.dot(dq), miss2 = e.dot(e);
        double scale2 = std::max(move2, dt_ * dt_ * std::max(speed2_prev, speed2));
        if (!(miss2 <= 0.25 * 0.25 * scale2 + 1e-24)) return (JUMP);
      }
    }
    // the pose at the corrected joints; the evaluation's point: the corrected one where the rates were made afresh
    write_row(out, yc, sol, M, q_pred, rerated ? VectorXd(yc.head(n)) : VectorXd(yp.head(n)), mu, speed2, true);
    return OK;
  }

  // R's LU factors of the last step in LAPACK's layout: (lu column-major N x N, 0-based pivots as doubles)
  nb::tuple factors() const {
    MatrixXd lu = lu_;
    Eigen::VectorXd piv = ipiv_.cast<double>();
    return nb::make_tuple(lu, piv);
  }

  // The watch's measurement of the last step (Watch.measure's inverse iteration; watch.cpp): its J and M (at the
  // predicted point, as the step's output has them) reduced to the free joints, R's factors. ``v``: the watch's
  // vector (nf); ``J_ref``: its last exact J (m x nf; another shape: none). None where the sizes do not fit or u is
  // not finite (the Python watch then computes exactly), else watch.cpp's tuple.
  nb::object watch_measure(CRef v, const Eigen::Ref<const RowMatrixXd>& J_ref, double sigma_ref, double gate) const {
    const int nf = static_cast<int>(free_.size());
    if (v.size() != nf || lu_.rows() != nf + m_ || Jw_.rows() != m_) return nb::none();
    RowMatrixXd Jr(m_, nf), Mr(nf, nf);
    for (int b = 0; b < nf; ++b) {
      Jr.col(b) = Jw_.col(free_[b]);
      for (int a = 0; a < nf; ++a) Mr(a, b) = Mw_(free_[a], free_[b]);
    }
    const bool ref = J_ref.rows() == m_ && J_ref.cols() == nf;
    return kinredund::watch_measure(Jr.data(), Mr.data(), lu_.data(), ipiv_.data(), nf, m_, v.data(),
                                    ref ? J_ref.data() : nullptr, sigma_ref, gate);
  }

  // failure.task_residual_min (kinredund/tracking/failure.py) operation by operation, with the GIL released: at the
  // time of the sample (p, v, Q, omega), from q0, Levenberg-Marquardt on 1/2 |r|^2 of the task alone (r and J of the
  // augmented form, without dK), at most max_iter iterations: (min |r| [m], the configuration reaching it). The
  // stop's diagnosis calls it (out_of_reach: up to 13 starts at each time looked at), the GIL-held Python part of a
  // failing run that cost most of a sweep's tracking.
  nb::tuple residual_min(CRef q0, CRef sp, CRef sv, Mat3 sQ, CRef somega, int max_iter) {
    if (q0.size() != n_) throw nb::value_error("q must have n entries");
    if (velocity_) throw nb::value_error("residual_min needs a StepCore of the augmented form");
    if (na_ > 0) throw nb::value_error("residual_min is the task's alone: a StepCore without rows held");
    set_sample(sp, sv, sQ, somega);
    VectorXd q = q0;
    double f;
    {
      nb::gil_scoped_release release;  // no Python object below
      evaluate(q, false);
      RowMatrixXd J = J_;
      VectorXd r = r_;
      f = r.dot(r);
      double mu = 1e-3;
      const Eigen::Index n = n_;
      for (int it = 0; it < max_iter; ++it) {
        const VectorXd g = J.transpose() * r;
        if (!std::isfinite(f) || g.dot(g) <= 1e-30 || f <= 1e-30) break;
        MatrixXd A = J.transpose() * J;
        A += mu * MatrixXd::Identity(n, n);  // J^T J + mu I
        const VectorXd dq = A.partialPivLu().solve(-g);  // (numpy's solve: LU with partial pivoting)
        const VectorXd trial = q + dq;
        evaluate(trial, false);
        const double f_new = r_.dot(r_);
        if (f_new < f) {
          q = trial, J = J_, r = r_, f = f_new, mu = std::max(mu / 3.0, 1e-12);
          if (dq.dot(dq) <= 1e-28) break;
        } else {
          mu *= 4.0;
          if (mu > 1e12) break;
        }
      }
    }
    return nb::make_tuple(std::sqrt(f), q);
  }

  // The evaluation at q (t of the last step's sample): (r, J, xdot, grad, Lambda+Hess (M) for lam, top) - for tests.
  nb::tuple evaluate_at(CRef q, CRef lam, CRef sp, CRef sv, Mat3 sQ, CRef somega, CRef ref_t, CRef rate_t) {
    set_sample(sp, sv, sQ, somega);
    set_reference(ref_t, rate_t);
    if (q.size() != n_ || lam.size() != m_) throw nb::value_error("q and lam must have n and m entries");
    evaluate(q, true);
    RowMatrixXd M;
    VectorXd top;
    system(lam, M, top);
    RowMatrixXd J = J_;
    return nb::make_tuple(r_, J, xdot_, grad_, M, top);
  }

 private:
  void set_reference(CRef ref_t, CRef rate_t) {  // a time-varying index's theta*(t) and its rate
    if (!time_varying_) return;
    if (ref_t.size() != n_ || rate_t.size() != n_)
      throw nb::value_error("the time-varying reference and its rate must have n entries");
    tv_ref_ = ref_t;
    tv_rate_ = rate_t;
  }

  void set_sample(CRef sp, CRef sv, Mat3 sQ, CRef somega) {
    if (sp.size() != 3 || sv.size() != 3) throw nb::value_error("the sample's p and v must have 3 entries");
    s_.p = sp;
    s_.v = sv;
    if (task_ == POSE || task_ == AXIS) {
      if (sQ.shape(0) != 3 || sQ.shape(1) != 3 || somega.size() != 3)
        throw nb::value_error("a task with orientation needs the sample's Q (3x3) and omega (3)");
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) s_.Q(i, j) = sQ(i, j);
      s_.omega = somega;
    }
  }

  // Point.__init__ / Evaluator.point: kinematics, task terms, index terms at q (with the Hessian: need_dJ)
  void evaluate(const Eigen::Ref<const VectorXd>& q, bool need_dJ) {
    pinocchio::Data& data = this->data();
    if (need_dJ) {
      frame_jacobian_hessian(model_, data, fid_, q, J6_, H_);  // frame.hpp (shared with the compiled IK)
    } else {
      J6_.setZero();
      pinocchio::computeFrameJacobian(model_, data, q, fid_, pinocchio::LOCAL_WORLD_ALIGNED, J6_);
      pinocchio::updateFramePlacement(model_, data, fid_);
    }
    const auto& oMf = data.oMf[fid_];
    Q_ = oMf.rotation();
    p_ = oMf.translation();
    K_.topRows(3) = J6_.bottomRows(3);  // thesis rows [omega; v] (Eq. 2.16)
    K_.bottomRows(3) = J6_.topRows(3);
    task_terms();
    if (time_varying_) {
      grad_ = w_.cwiseProduct(q - tv_ref_);  // Eq. (6.25)
    } else {
      grad_ = w_.cwiseProduct(q - ref_);  // Eq. (4.45)
    }
    if (na_ > 0) {  // RowPoint: the rows held under the task's, r = [r; c], J = [J; G], xdot = [xdot; 0]
      qe_ = q;
      guard_->rows_at(qe_, rows_, c_, G_);
      r_.conservativeResize(m_);
      r_.tail(na_) = c_;
      J_.conservativeResize(m_, n_);
      J_.bottomRows(na_) = G_;
      xdot_.conservativeResize(m_);
      xdot_.tail(na_).setZero();
    }
  }

  // RowPoint.system's share of the rows held: M += sum_i w_i Hess c_i at the evaluation's q (the guard's)
  void add_curvature(const VectorXd& w, RowMatrixXd& M) { guard_->add_curvature(qe_, rows_, w, eps_, M); }

  // TaskTerms of each kind (r, J, xdot and what system() needs)
  void task_terms() {
    const int n = n_;
    if (task_ == PLANAR || task_ == POSITION) {  // tasks/position.py PointTerms
      const int k = mt_;
      r_ = p_.head(k) - s_.p.head(k);
      J_ = K_.block(3, 0, k, n);
      xdot_ = s_.v.head(k);
      return;
    }
    if (task_ == POSE && velocity_) {  // tasks/pose.py TwistTerms
      Vector3d w;
      log_ok_ = rotation_log(Q_ * s_.Q.transpose(), w);
      r_.resize(6);
      r_ << w, p_ - s_.p;
      J_ = K_;
      xdot_.resize(6);
      xdot_ << s_.omega, s_.v;
      return;
    }
    const Matrix3d QdT = s_.Q.transpose();
    W_ = QdT * K_.topRows(3);  // angular columns in the target frame
    if (task_ == POSE) {  // tasks/pose.py ClosureTerms, Eqs. (2.13)-(2.15)
      rel_ = QdT * Q_;
      const double tr = rel_.trace();
      A_ = tr * Matrix3d::Identity() - rel_;
      v_ = Vector3d(0.5 * (rel_(2, 1) - rel_(1, 2)), 0.5 * (rel_(0, 2) - rel_(2, 0)), 0.5 * (rel_(1, 0) - rel_(0, 1)));
      wd_ = QdT * s_.omega;
      r_.resize(6);
      r_ << 2.0 * v_, p_ - s_.p;
      J_.resize(6, n);
      J_.topRows(3) = A_ * W_;
      J_.bottomRows(3) = K_.bottomRows(3);
      xdot_.resize(6);
      xdot_ << A_ * wd_, s_.v;
      return;
    }
    // tasks/axis.py AxisTerms
    a_ = Q_.col(2);
    ah_ = QdT * a_;
    const Vector3d wd = QdT * s_.omega;
    Eigen::Matrix<double, 2, 3> rows;
    if (velocity_) {
      rows << 0.0, 1.0, 0.0, -1.0, 0.0, 0.0;
    } else {
      rows << 0.0, ah_[2], -ah_[1], -ah_[2], 0.0, ah_[0];  // -[a^]x, x and y rows
    }
    r_.resize(5);
    r_ << ah_[0], ah_[1], p_ - s_.p;
    J_.resize(5, n);
    J_.topRows(2) = rows * W_;
    J_.bottomRows(3) = K_.bottomRows(3);
    const Vector3d c = cross3(wd, ah_);
    xdot_.resize(5);
    xdot_ << c[0], c[1], s_.v;
  }

  void contract(const Eigen::Matrix<double, 6, 1>& mu, RowMatrixXd& out) const { contract_hessian(H_, n_, mu, out); }

  // Point.system: (M, top) of Eq. (4.24) for lam
  void system(const VectorXd& lam_all, RowMatrixXd& M, VectorXd& top) {
    const int n = n_;
    const VectorXd lam = lam_all.head(mt_);  // the task's lambda (the rows' w after it: add_curvature)
    Eigen::Matrix<double, 6, 1> mu = Eigen::Matrix<double, 6, 1>::Zero();
    RowMatrixXd Lam;
    VectorXd extra;  // (dJ/dt)^T lam where J depends on time
    bool has_extra = false;
    if (task_ == PLANAR || task_ == POSITION) {
      for (int j = 0; j < mt_; ++j) mu[j] = lam[j];  // rows 3.. of K are Pinocchio's 0..
      contract(mu, Lam);  // Eq. (4.20)
    } else if (task_ == POSE && velocity_) {
      mu << lam.tail(3), lam.head(3);
      contract(mu, Lam);  // Eq. (4.42)
    } else if (task_ == POSE) {
      const double l0 = lam[0], l1 = lam[1], l2 = lam[2];
      const Matrix3d& q = rel_;
      const Vector3d l(l0, l1, l2);
      const Vector3d m3 = A_.transpose() * l;  // closure.lambda_parts_floats with l4 = 0
      Matrix3d G;
      G << q(1, 0) * l2 - q(2, 0) * l1 + 2.0 * l0 * v_[0], q(2, 0) * l0 - q(0, 0) * l2 + 2.0 * l0 * v_[1],
          q(0, 0) * l1 - q(1, 0) * l0 + 2.0 * l0 * v_[2],
          q(1, 1) * l2 - q(2, 1) * l1 + 2.0 * l1 * v_[0], q(2, 1) * l0 - q(0, 1) * l2 + 2.0 * l1 * v_[1],
          q(0, 1) * l1 - q(1, 1) * l0 + 2.0 * l1 * v_[2],
          q(1, 2) * l2 - q(2, 2) * l1 + 2.0 * l2 * v_[0], q(2, 2) * l0 - q(0, 2) * l2 + 2.0 * l2 * v_[1],
          q(0, 2) * l1 - q(1, 2) * l0 + 2.0 * l2 * v_[2];
      mu << lam.segment(3, 3), s_.Q * m3;
      contract(mu, Lam);
      Lam -= W_.transpose() * (G * W_);  // Eq. (4.20)
      const Vector3d& w = wd_;
      const double s = 2.0 * v_.dot(w);
      const Vector3d x = cross3(l, w);
      const Vector3d c = s * l + q.transpose() * x - cross3(m3, w);
      extra = W_.transpose() * c;
      has_extra = true;
    } else {  // AXIS
      Vector3d mu3(lam[0], lam[1], 0.0);
      Vector3d m3 = velocity_ ? Vector3d(s_.Q * Vector3d(-mu3[1], mu3[0], 0.0)) : Vector3d(s_.Q * mu3);
      const auto Ko = K_.topRows(3);
      Vector3d w;
      if (velocity_) {
        w = m3;  // Eq. (4.42)
        extra = Ko.transpose() * cross3(s_.omega, m3);
      } else {
        w = cross3(a_, m3);
        extra = Ko.transpose() * cross3(a_, cross3(s_.omega, m3));
      }
      has_extra = true;
      mu << lam.segment(2, 3), w;
      contract(mu, Lam);
      if (!velocity_) {
        Matrix3d C = a_ * m3.transpose() - a_.dot(m3) * Matrix3d::Identity();
        Lam += Ko.transpose() * C * Ko;  // d a / d theta_j = omega_j x a
      }
    }
    M = Lam;
    M.diagonal() += w_;  // Hess z = diag(w) (Eqs. 4.45, 6.25) + Lambda (Eq. 4.23)
    if (na_ > 0) add_curvature(lam_all.tail(na_), M);  // the rows' share (rows.py: Eqs. 4.23, 4.24 extended)
    if (time_varying_) {
      VectorXd dgdt = -w_.cwiseProduct(tv_rate_);  // Eq. (6.27)
      top = has_extra ? VectorXd(-dgdt - extra) : VectorXd(-dgdt);
    } else {
      top = has_extra ? VectorXd(-extra) : VectorXd(VectorXd::Zero(n));
    }
  }

  // Stepper._factor: R = [[M, J^T], [J, 0]], its LU factors with partial pivoting in LAPACK's layout (dgetf2's
  // unblocked algorithm: at these sizes scipy's dgetrf + dgecon cost ~3.6 us, this ~0.5 us; the factors agree to
  // rounding and the pivots are the same) and the 1-norm condition estimate of LAPACK's dgecon (Hager-Higham).
  int factor(const RowMatrixXd& M) {
    const int nf = static_cast<int>(free_.size()), N = nf + m_;
    if (R_.rows() != N) R_.setZero(N, N);
    if (any_held_) {  // LimitedPredictorCorrector._factor: Eq. (4.24) with the held joints' columns removed
      for (int b = 0; b < nf; ++b) {
        for (int a = 0; a < nf; ++a) R_(a, b) = M(free_[a], free_[b]);
        for (int r = 0; r < m_; ++r) R_(nf + r, b) = R_(b, nf + r) = J_(r, free_[b]);
      }
    } else {
      R_.topLeftCorner(nf, nf) = M;
      R_.topRightCorner(nf, m_) = J_.transpose();
      R_.bottomLeftCorner(m_, nf) = J_;
    }
    R_.bottomRightCorner(m_, m_).setZero();
    const double anorm = R_.cwiseAbs().colwise().sum().maxCoeff();  // dlange('1')
    lu_ = R_;
    ipiv_.resize(N);
    double* a = lu_.data();
    for (int j = 0; j < N; ++j) {
      int p = j;
      double big = std::abs(a[j + N * j]);
      for (int i = j + 1; i < N; ++i)
        if (std::abs(a[i + N * j]) > big) big = std::abs(a[i + N * j]), p = i;
      ipiv_[j] = p;
      if (a[p + N * j] == 0.0 || !std::isfinite(a[p + N * j])) return FACTOR_SINGULAR;
      if (p != j)
        for (int k = 0; k < N; ++k) std::swap(a[j + N * k], a[p + N * k]);
      const double inv = 1.0 / a[j + N * j];
      for (int i = j + 1; i < N; ++i) a[i + N * j] *= inv;
      for (int k = j + 1; k < N; ++k) {
        const double ajk = a[j + N * k];
        if (ajk != 0.0)
          for (int i = j + 1; i < N; ++i) a[i + N * k] -= a[i + N * j] * ajk;
      }
    }
    rcond_ = rcond(anorm);
    if (!(rcond_ > 1e-12)) return RCOND_LOW;
    return OK;
  }

  // x := inv(LU) x (trans false) or inv(LU)^T x, without the row interchanges (dgecon's two solves)
  void lu_apply(double* x, bool trans) const {
    const int N = static_cast<int>(lu_.rows());
    const double* a = lu_.data();
    if (!trans) {
      for (int j = 0; j < N; ++j)  // unit lower
        for (int i = j + 1; i < N; ++i) x[i] -= a[i + N * j] * x[j];
      for (int j = N - 1; j >= 0; --j) {  // upper
        x[j] /= a[j + N * j];
        for (int i = 0; i < j; ++i) x[i] -= a[i + N * j] * x[j];
      }
    } else {
      for (int j = 0; j < N; ++j) {  // U^T: lower
        double v = x[j];
        for (int i = 0; i < j; ++i) v -= a[i + N * j] * x[i];
        x[j] = v / a[j + N * j];
      }
      for (int j = N - 1; j >= 0; --j) {  // L^T: unit upper
        double v = x[j];
        for (int i = j + 1; i < N; ++i) v -= a[i + N * j] * x[i];
        x[j] = v;
      }
    }
  }

  // LAPACK's dgecon (norm '1') with dlacn2: the reciprocal 1-norm condition estimate of R from its factors
  double rcond(double anorm) const {
    const int N = static_cast<int>(lu_.rows());
    if (N == 0) return 1.0;
    if (!(anorm > 0.0)) return 0.0;
    std::vector<double> x(N, 1.0 / N), v(N);
    std::vector<int> isgn(N);
    auto dasum = [&](const std::vector<double>& z) { double t = 0.0; for (double e : z) t += std::abs(e); return t; };
    auto idamax = [&]() { int k = 0; for (int i = 1; i < N; ++i) if (std::abs(x[i]) > std::abs(x[k])) k = i; return k; };
    auto sgn = [](double e) { return e >= 0.0 ? 1.0 : -1.0; };
    double est = 0.0;
    lu_apply(x.data(), false);  // kase 1
    if (N == 1) {
      est = std::abs(x[0]);
    } else {
      est = dasum(x);
      for (int i = 0; i < N; ++i) x[i] = sgn(x[i]), isgn[i] = static_cast<int>(x[i]);
      lu_apply(x.data(), true);  // kase 2
      int j = idamax(), iter = 2;
      bool alt = false;
      while (true) {  // L50
        std::fill(x.begin(), x.end(), 0.0);
        x[j] = 1.0;
        lu_apply(x.data(), false);
        v = x;
        const double estold = est;
        est = dasum(v);
        bool same = true;
        for (int i = 0; i < N; ++i)
          if (static_cast<int>(sgn(x[i])) != isgn[i]) { same = false; break; }
        if (same || est <= estold) { alt = true; break; }  // converged, or cycling
        for (int i = 0; i < N; ++i) x[i] = sgn(x[i]), isgn[i] = static_cast<int>(x[i]);
        lu_apply(x.data(), true);
        const int jlast = j;
        j = idamax();
        if (x[jlast] != std::abs(x[j]) && iter < 5) { ++iter; continue; }
        alt = true;
        break;
      }
      if (alt) {  // L120: the alternating-sign vector
        double altsgn = 1.0;
        for (int i = 0; i < N; ++i) x[i] = altsgn * (1.0 + static_cast<double>(i) / (N - 1)), altsgn = -altsgn;
        lu_apply(x.data(), false);
        const double temp = 2.0 * (dasum(x) / (3.0 * N));
        if (temp > est) est = temp;
      }
    }
    return est != 0.0 ? (1.0 / est) / anorm : 0.0;
  }

  // dgetrs: the interchanges, then L and U; with joints held, on the free rows (LimitedPredictorCorrector._solve:
  // the held joints' entries of the solution are zero)
  void solve(VectorXd& b) const {
    const int N = static_cast<int>(lu_.rows()), nf = static_cast<int>(free_.size());
    double* x = b.data();
    VectorXd sub;
    if (any_held_) {
      sub.resize(N);
      for (int a = 0; a < nf; ++a) sub[a] = b[free_[a]];
      sub.tail(m_) = b.tail(m_);
      x = sub.data();
    }
    for (int i = 0; i < N; ++i)
      if (ipiv_[i] != i) std::swap(x[i], x[ipiv_[i]]);
    lu_apply(x, false);
    if (any_held_) {
      b.head(n_).setZero();
      for (int a = 0; a < nf; ++a) b[free_[a]] = sub[a];
      b.tail(m_) = sub.tail(m_);
    }
  }

  // Point.residual: [grad z + J^T lambda; r]; with joints held their rows are zero (the bound multipliers')
  VectorXd residual(const VectorXd& lam) const {
    VectorXd F(n_ + m_);
    F << grad_ + J_.transpose() * lam, r_;
    if (any_held_)
      for (int i = 0; i < n_; ++i)
        if (held_[i]) F[i] = 0.0;
    return F;
  }

  // linalg.classify's verdict on the free joints' system where it is clear, without asking LAPACK (0.0: not clear,
  // Python's classify decides): 1.0 M_FF positive definite (dpotrf succeeds: ``qp``); 2.0 M_FF not positive
  // definite (dpotrf fails) but M_FF + rho J_F^T J_F - shift is for one of _projected_pd's rho (Finsler: ``qp_aug``,
  // or ``lu`` under the rule ``thesis``). Clear: the smallest eigenvalue beyond 1e-8 n max|A_ij| from zero, far
  // beyond what Cholesky's backward error (~n eps ||A||) or the rounding of the matrices' entries could change.
  double label_code(const RowMatrixXd& M) const {
    const int nf = static_cast<int>(free_.size());
    MatrixXd A(nf, nf);
    for (int b = 0; b < nf; ++b)
      for (int a = b; a < nf; ++a) A(a, b) = A(b, a) = M(free_[a], free_[b]);  // dpotrf reads the lower triangle
    if (definite_side(A) > 0) return 1.0;
    if (definite_side(A) >= 0) return 0.0;
    MatrixXd Ms(nf, nf), JF(m_, nf);
    for (int b = 0; b < nf; ++b) {
      for (int a = 0; a < nf; ++a) Ms(a, b) = 0.5 * (M(free_[a], free_[b]) + M(free_[b], free_[a]));
      JF.col(b) = Jw_.col(free_[b]).transpose();  // the step's J, M's (reduced_label(M, pt.J))
    }
    const double scale = std::max(1.0, Ms.cwiseAbs().maxCoeff());
    const MatrixXd JtJ = JF.transpose() * JF;
    const MatrixXd JJt = JF * JF.transpose();
    Eigen::SelfAdjointEigenSolver<MatrixXd> es(JJt, Eigen::EigenvaluesOnly);
    const double s2 = std::max(es.eigenvalues()(0), 1e-300);
    for (double f : {1.0, 1e2, 1e4}) {
      MatrixXd B = Ms + (f * scale / s2) * JtJ;
      B.diagonal().array() -= 1e-10 * scale;
      if (definite_side(B) > 0) return 2.0;
    }
    return 0.0;
  }

  // +1 where the symmetric A is clearly positive definite, -1 where clearly not, 0 in between (label_code)
  static int definite_side(const MatrixXd& A) {
    Eigen::SelfAdjointEigenSolver<MatrixXd> es(A, Eigen::EigenvaluesOnly);
    const double lo = es.eigenvalues()(0), margin = 1e-8 * A.rows() * A.cwiseAbs().maxCoeff();
    return lo > margin ? 1 : lo < -margin ? -1 : 0;
  }

  // PredictorCorrector._chord with fresh residuals (need_dJ=False), R's factors kept: OK (converged),
  // CHORD_FAILED, or LOG_NEAR_PI at an iterate
  int chord(VectorXd& y, double tol) {
    for (int it = 0; it < 8; ++it) {
      evaluate(y.head(n_), false);
      if (task_ == POSE && velocity_ && !log_ok_) return LOG_NEAR_PI;
      VectorXd F = residual(y.tail(m_));
      if (F.dot(F) <= tol * tol) return OK;
      solve(F);
      y -= F;
    }
    return CHORD_FAILED;
  }

  // Pinocchio's workspace, made on first use (inside the GIL-free calls: start_run, a step), not with the StepCore
  pinocchio::Data& data() {
    if (!data_) data_ = std::make_unique<pinocchio::Data>(model_);
    return *data_;
  }

  // the robot's pin.Model itself, not a copy (a run's set-up holds the GIL: a copy per run serialised the threads):
  // a Robot's model is never modified (kinredund/model/robot.py), and model_obj_ keeps it alive while it is used
  nb::object model_obj_;
  const pinocchio::Model& model_;
  std::unique_ptr<pinocchio::Data> data_;
  pinocchio::FrameIndex fid_;
  int task_;
  bool velocity_;
  VectorXd w_, ref_, tv_ref_, tv_rate_;
  bool time_varying_;
  double tol_, dt_;
  std::vector<VectorXd> hermite_;
  VectorXd lo_, hi_;
  bool limited_ = false;
  // the active set (set_active): free joints, bound values and sides, which joints are held
  VectorXi free_;
  VectorXd bound_, side_;
  std::vector<char> held_;
  bool any_held_ = false;
  int n_ = 0, m_ = 0, mt_ = 0;  // joints, multipliers (the task's and the rows held), the task's dimension
  // the general rows held (set_rows): the guard's rows, their number, the differences' step; the evaluation's q and
  // the rows' values, gradients and differences there
  RowIndices rows_;
  int na_ = 0;
  double eps_ = 1e-6;
  VectorXd qe_, c_;
  RowMatrixXd G_;
  // the evaluation
  Sample s_;
  MatrixXd J6_;
  RowMatrixXd K_;
  pinocchio::Data::Tensor3x H_;
  Matrix3d Q_, rel_, A_;
  Vector3d p_, v_, wd_, a_, ah_;
  RowMatrixXd W_, J_, Jw_, Mw_;
  VectorXd r_, xdot_, grad_;
  bool log_ok_ = true;
  // R and its factors
  MatrixXd R_, lu_;
  VectorXi ipiv_;
  double rcond_ = 0.0;
  RowSource* guard_ = nullptr;  // set_guard's (held by guard_obj_)
  nb::object guard_obj_;
};

StepCore& step_core(nb::handle obj) {
  if (!nb::isinstance<StepCore>(obj)) throw nb::type_error("expected a kinredund._core.StepCore");
  return *nb::inst_ptr<StepCore>(obj);
}

void step_core_sizes(const StepCore& c, int& n, int& m, int& row) {
  n = c.n(), m = c.m();
  row = static_cast<int>(c.output_size());  // StepCore::step's layout
}

const int* step_core_free(const StepCore& c, int& nf) {
  nf = static_cast<int>(c.free_.size());
  return c.free_.data();
}

RowSource* step_core_guard(const StepCore& c) { return c.guard_; }

RowIndicesPtr step_core_held_rows(const StepCore& c) { return c.na_ > 0 ? &c.rows_ : nullptr; }

const double* step_core_factors(const StepCore& c, const int*& piv, int& N) {
  N = static_cast<int>(c.lu_.rows());
  piv = c.ipiv_.data();
  return c.lu_.data();
}

int step_core_advance(StepCore& c, const StepInput& in, const double* y, const double* yd,
                      const std::vector<const double*>& prev, const double* qdot0, double speed2, bool check_jump,
                      double* out) {
  const int n = c.n_, N = c.n_ + c.m_;
  c.s_.p = Eigen::Map<const Vector3d>(in.p);
  c.s_.v = Eigen::Map<const Vector3d>(in.v);
  if (in.Q != nullptr) {
    c.s_.Q = Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(in.Q);
    c.s_.omega = Eigen::Map<const Vector3d>(in.omega);
  }
  if (c.time_varying_) {
    c.tv_ref_ = Eigen::Map<const VectorXd>(in.ref, n);
    c.tv_rate_ = Eigen::Map<const VectorXd>(in.rate, n);
  }
  int row, mm, nn;
  step_core_sizes(c, nn, mm, row);
  VectorXd buf(row);
  const int st = c.advance(Eigen::Map<const VectorXd>(y, N), Eigen::Map<const VectorXd>(yd, N), prev,
                           Eigen::Map<const VectorXd>(qdot0, n), speed2, check_jump, buf);
  if (st == 0) std::copy(buf.data(), buf.data() + row, out);
  return st;
}

void bind_step(nb::module_& m) {
  nb::class_<StepCore>(m, "StepCore")
      .def(nb::init<nb::handle, int, int, bool, CRef, CRef, bool, double, double, std::vector<VectorXd>, CRef,
                    CRef>(),
           nb::arg("model"), nb::arg("frame_id"), nb::arg("task"), nb::arg("velocity"), nb::arg("weights"),
           nb::arg("reference"), nb::arg("time_varying"), nb::arg("tol"), nb::arg("dt"), nb::arg("hermite"),
           nb::arg("lo_tol"), nb::arg("hi_tol"))
      .def_prop_ro("n", &StepCore::n)
      .def_prop_ro("m", &StepCore::m)
      .def("step", &StepCore::step, nb::arg("t"), nb::arg("p"), nb::arg("v"), nb::arg("Q"), nb::arg("omega"),
           nb::arg("ref"), nb::arg("rate"), nb::arg("y"), nb::arg("yd"), nb::arg("prev"), nb::arg("qdot0"),
           nb::arg("speed2"), nb::arg("check_jump"))
      .def("step_guarded", &StepCore::step_guarded, nb::arg("h"), nb::arg("t"), nb::arg("p"), nb::arg("v"),
           nb::arg("Q"), nb::arg("omega"), nb::arg("ref"), nb::arg("rate"), nb::arg("y"), nb::arg("yd"),
           nb::arg("prev"), nb::arg("qdot0"), nb::arg("speed2"), nb::arg("check_jump"))
      .def("set_guard", &StepCore::set_guard, nb::arg("guard").none())
      .def("set_rows", &StepCore::set_rows, nb::arg("rows"), nb::arg("eps"))
      .def_prop_ro("held_rows", &StepCore::held_rows)
      .def("set_active", &StepCore::set_active, nb::arg("free"), nb::arg("bound"), nb::arg("side"))
      .def("factors", &StepCore::factors)
      .def("correct", &StepCore::correct, nb::arg("t"), nb::arg("p"), nb::arg("v"), nb::arg("Q"), nb::arg("omega"),
           nb::arg("ref"), nb::arg("rate"), nb::arg("y"), nb::arg("newton") = false)
      .def("locate", &StepCore::locate, nb::arg("t_a"), nb::arg("y_a"), nb::arg("yd_a"), nb::arg("a"), nb::arg("b"),
           nb::arg("fa"), nb::arg("fb"), nb::arg("index"), nb::arg("sign"), nb::arg("level"), nb::arg("row"),
           nb::arg("stand_in"), nb::arg("sample_at"), nb::arg("own_at").none(), nb::arg("xtol"), nb::arg("rtol"),
           nb::arg("maxiter"))
      .def("watch_measure", &StepCore::watch_measure, nb::arg("v"), nb::arg("J_ref"), nb::arg("sigma_ref"),
           nb::arg("gate"))
      .def("residual_min", &StepCore::residual_min, nb::arg("q"), nb::arg("p"), nb::arg("v"), nb::arg("Q"),
           nb::arg("omega"), nb::arg("max_iter"))
      .def("evaluate", &StepCore::evaluate_at, nb::arg("q"), nb::arg("lam"), nb::arg("p"), nb::arg("v"),
           nb::arg("Q"), nb::arg("omega"), nb::arg("ref"), nb::arg("rate"));
  m.def("brent_root", [](nb::callable f, double a, double b, double xtol, double rtol, int maxiter) {
          auto g = [&](double x, double& fx) -> int {
            fx = nb::cast<double>(f(x));
            return std::isnan(fx) ? LOCATE_NAN : OK;
          };
          double fa = 0.0, fb = 0.0, root = 0.0;
          int st = g(a, fa);
          if (st == OK) st = g(b, fb);
          if (st == OK) st = brent_root(g, a, b, fa, fb, xtol, rtol, maxiter, root);
          return st == OK ? nb::object(nb::float_(root)) : nb::object(nb::int_(st));
        }, nb::arg("f"), nb::arg("a"), nb::arg("b"), nb::arg("xtol"), nb::arg("rtol"), nb::arg("maxiter"),
        "brent.hpp's Brent search of StepCore.locate on a Python function f (for the tests: roots.py's brent_root "
        "makes the same calls): the root, or the status code (20: not bracketed, 21: no convergence, 23: a NaN).");
  m.def("start_run", [](StepCore& core, CRef p, CRef v, Mat3 Q, CRef omega, CRef ref, CRef rate, CRef y0) {
          return core.start(p, v, Q, omega, ref, rate, y0);
        }, nb::arg("core"), nb::arg("p"), nb::arg("v"), nb::arg("Q"), nb::arg("omega"), nb::arg("ref"),
        nb::arg("rate"), nb::arg("y0"),
        "A run's start in the core, the GIL released: StepCore.start (see src/core/step.cpp).");
}

}  // namespace kinredund
