// Runs of ordinary steps in one C++ call (issue 28; kinredund/tracking/runs.py drives it): the StepCore's step
// (step.cpp) repeated over presampled times with the GIL released, each step's output row written into a numpy
// array that the caller made, the predictor's history carried from step to step as the Python driver carries it
// (kinredund/tracking/compiled.py, CompiledStep._apply). The run ends at the first step that is not ordinary (its
// status, nothing written) or that the fold and singularity watch must measure (its row written: the caller
// finishes that step in Python), or after the last time given. With the watch's ``through`` flag the run goes on
// through the steps the watch measures exactly (every ``every``-th step): each is measured here, in the run, on the
// free joints' J and M of its row (watch.cpp's watch_exact, the routine of the compiled backend's single steps), and
// their indices and measurements are returned; the caller takes the watch's verdicts on them after the run and keeps
// the rows up to the first step the watch does not accept (kinredund/tracking/runs.py). Given the watch's inverse
// iteration's state too (its vector v, the reference J_ref and sigma_min there, J_GATE) the run goes on through the
// other measured steps as well: each is measured here by watch.cpp's watch_inverse with the step's R factors (the
// routine of StepCore.watch_measure, which the single steps call), the state carried from measurement to measurement
// as the watch carries it (Watch.took, Watch.keep_exact); where that measurement is not watch_measure's (v of another
// size, u not finite: the Python watch's exact branch) the run ends there as without it.
// With a row check (``guard``: the StepCore's RowSource, a scene's RowGuard, a frame's FrameRows or a RowStack of
// several: StepCore.set_guard) each step is checked right after it, as StepCore.step_guarded checks a single step (its
// clear_at on the same arrays, its smallest row value at the step's end written out): the run ends at the first step
// the check does not clear (GUARD_DUE, its row written: the caller's stepper searches it for a switch); it goes on
// through the steps the watch measures as an unguarded run does (the watch's verdicts are the run's, taken step by
// step, so a step the watch rejects ends the run before the check's value of it is kept; guarded runs ended after
// each measured step until the last stop). With general rows held in the core (StepCore.set_rows) the
// run goes on with them, the check leaving them out (as step_guarded does), a held row's release ending it with its
// status (step.cpp's ROW_RELEASE), and a step whose R has odd inertia (odd_inertia: a saddle of the held problem,
// maybe) ending it as one the watch must measure (WATCH_DUE: the caller measures it exactly,
// kinredund.tracking.compiled.CompiledStep.accept).
#include "loop.hpp"

#include <nanobind/ndarray.h>
#include <nanobind/stl/tuple.h>
#include <nanobind/stl/vector.h>

#include <string>
#include <vector>

#include "arrays.hpp"
#include "rows.hpp"
#include "step.hpp"
#include "watch.hpp"

namespace nb = nanobind;

namespace kinredund {

namespace {


// The status of a step the watch measures (after step.cpp's codes, RELEASE = 11 among them, and the driver's 8-13).
constexpr int WATCH_DUE = 20;
// The status of a step the scene's row check does not clear (its row and its smallest row value written).
constexpr int GUARD_DUE = 21;
// The status of a step measured by the inverse iteration whose measurement the watch rejects (compiled.py's
// WATCH_REJECTS: the caller hands it back, its row not kept).
constexpr int WATCH_REJECTS = 9;
// The status of a step the watch predicts a crossing within (Watch.ahead, after a measurement of the run): not taken,
// left to the caller's next call (which hands it back).
constexpr int AHEAD = -1;

// Does the step's R have a reduced Hessian with an odd number of negative eigenvalues, by the signs of its LU
// factors' diagonal and the pivots' swaps (kinredund.tracking.step_control.odd_inertia; nf: the free joints)?
bool odd_inertia(const StepCore& core, int nf) {
  int N = 0;
  const int* piv = nullptr;
  const double* lu = step_core_factors(core, piv, N);
  int flips = 0;
  for (int i = 0; i < N; ++i) flips += (lu[static_cast<size_t>(i) * N + i] < 0.0) + (piv[i] != i);
  return (flips + N - nf) % 2 == 1;  // the parity of flips - (N - nf)
}

void check_rows(const InMat& a, size_t k, size_t width, const char* name) {
  if (a.shape(0) != k || a.shape(1) != width)
    throw nb::value_error((std::string(name) + " must have shape (" + std::to_string(k) + ", " +
                           std::to_string(width) + ")").c_str());
}

const double* vector_of(const InVec& a, size_t size, const char* name) {
  if (a.shape(0) != size)
    throw nb::value_error((std::string(name) + " must have " + std::to_string(size) + " entries").c_str());
  return a.data();
}

// The watch's gate (kinredund.tracking.watch.Watch.due_next): is a step with rcond measured?
struct Gate {
  bool on;
  double near, drop, last;
  long count, every;
  bool through;  // go on through the steps measured exactly (their indices returned)
  bool due(double rcond) const {
    return !(rcond > near) || rcond < drop * last || (count + 1) % every == 0;
  }
  bool exact_next() const { return through && (count + 1) % every == 0; }
};

// The watch's inverse iteration's state (Watch._v, _J_ref, _sigma_ref), carried through a run's measurements.
struct Inverse {
  bool on = false;
  std::vector<double> v, J_ref;  // J_ref empty: none (or of another shape)
  double sigma_ref = 0.0, gate = 0.0;
};

Inverse inverse_of(const nb::tuple& watch, int m, int nf) {
  Inverse s;
  if (nb::len(watch) < 11 || watch[7].is_none()) return s;
  const InVec v = nb::cast<InVec>(watch[7]);
  const InMat ref = nb::cast<InMat>(watch[8]);
  s.on = true;
  s.v.assign(v.data(), v.data() + v.shape(0));
  if (ref.shape(0) == static_cast<size_t>(m) && ref.shape(1) == static_cast<size_t>(nf))
    s.J_ref.assign(ref.data(), ref.data() + ref.shape(0) * ref.shape(1));
  s.sigma_ref = nb::cast<double>(watch[9]);
  s.gate = nb::cast<double>(watch[10]);
  return s;
}

// The watch's history and floors (the watch tuple's 12th entry: (times, eig, sigma_times, sigma, sigma_max, scale,
// safe_before, reset, SIGMA_FLOOR, EIG_FLOOR), Watch's), whose verdicts the run takes.
WatchHistory history_of(const nb::tuple& watch) {
  WatchHistory h;
  const nb::tuple w = nb::cast<nb::tuple>(watch[11]);
  h.times = nb::cast<std::vector<double>>(w[0]);
  h.eig = nb::cast<std::vector<double>>(w[1]);
  h.sigma_times = nb::cast<std::vector<double>>(w[2]);
  h.sigma = nb::cast<std::vector<double>>(w[3]);
  h.sigma_max = nb::cast<double>(w[4]);
  h.scale = nb::cast<double>(w[5]);
  h.safe = nb::cast<double>(w[6]);
  h.reset = nb::cast<bool>(w[7]);
  h.sigma_floor = nb::cast<double>(w[8]);
  h.eig_floor = nb::cast<double>(w[9]);
  return h;
}

nb::ndarray<nb::numpy, double> array_of(const std::vector<double>& a, size_t rows, size_t cols) {
  auto* buf = new std::vector<double>(a);
  nb::capsule owner(buf, [](void* p) noexcept { delete static_cast<std::vector<double>*>(p); });
  const size_t shape[2] = {rows, cols};
  return nb::ndarray<nb::numpy, double>(buf->data(), cols ? 2 : 1, shape, owner);
}

}  // namespace

// run(core, t (K), p, v (K x 3), Q (K x 9 or 0 x 9), omega (K x 3 or 0 x 3), ref, rate (K x n or 0 x n), y, yd,
//     prev (list of arrays), qdot0, speed2, check_jump, watch (on, near, drop, last rcond, count, every[, through[,
//     v or None, J_ref, sigma_ref, gate, history]]), out, guard (None, or (the time of the run's start [s], smallest:
//     an array of >= K entries that receives each checked step's guard smallest))) -> (steps done, status, the
// watch's state after the run's measurements or None where it kept none). The watch's verdicts on its measurements
// are taken in the run, as the step control takes them one by one (Watch.crossed, then Watch.keep_exact or
// Watch.took, Watch.push; the history's: WatchHistory, watch.cpp): an exact measurement the watch rejects ends the run
// there with WATCH_DUE (its row written: the caller measures it again from its row, CompiledStep.accept, and hands it
// back), one of the inverse iteration with WATCH_REJECTS (handed back), and after a measurement a step predicted into
// a crossing (Watch.ahead) ends it with AHEAD, before that step. The state: (times, eig, sigma_times, sigma,
// sigma_max, scale, safe_before, v, J_ref (m x nf) or None where unchanged, sigma_ref, fresh, the measurements of the
// inverse iteration among them (Watch.core_measured), the measurements kept). Status 0 after all K steps, else that of
// step ``done`` (WATCH_DUE, GUARD_DUE: its row is written).
nb::tuple run_steps(nb::handle core_obj, InVec t, InMat p, InMat v, InMat Q, InMat omega, InMat ref, InMat rate,
                    InVec y0, InVec yd0, nb::list prev_list, InVec qdot0, double speed2, bool check_jump, nb::tuple watch,
                    OutMat out, nb::object guard_arg) {
  StepCore& core = step_core(core_obj);
  const RowIndicesPtr held = step_core_held_rows(core);  // general rows held through the run (StepCore.set_rows)
  if (held != nullptr && guard_arg.is_none())
    throw nb::value_error("run_steps: the core holds general rows (StepCore.set_rows); a run with rows needs guard");
  int n, m, row;
  step_core_sizes(core, n, m, row);
  const size_t N = static_cast<size_t>(n + m), K = t.shape(0);
  check_rows(p, K, 3, "p");
  check_rows(v, K, 3, "v");
  const bool oriented = Q.shape(0) != 0;
  if (oriented) {
    check_rows(Q, K, 9, "Q");
    check_rows(omega, K, 3, "omega");
  }
  const bool varying = ref.shape(0) != 0;
  if (varying) {
    check_rows(ref, K, n, "ref");
    check_rows(rate, K, n, "rate");
  }
  if (out.shape(0) < K || out.shape(1) != static_cast<size_t>(row))
    throw nb::value_error(("out must have at least " + std::to_string(K) + " rows of " + std::to_string(row) +
                           " entries").c_str());
  const size_t np_ = nb::len(prev_list);
  if (np_ % 2 || np_ > 4) throw nb::value_error("prev: (y, ydot) pairs, at most two");
  std::vector<InVec> keep(np_);  // the arrays stay alive while their pointers are used
  std::vector<const double*> prev(np_);
  for (size_t j = 0; j < np_; ++j) {
    keep[j] = nb::cast<InVec>(prev_list[j]);
    prev[j] = vector_of(keep[j], N, "prev entries");
  }
  const double* y = vector_of(y0, N, "y");
  const double* yd = vector_of(yd0, N, "yd");
  const double* qd = vector_of(qdot0, n, "qdot0");
  Gate gate{nb::cast<bool>(watch[0]), nb::cast<double>(watch[1]), nb::cast<double>(watch[2]),
            nb::cast<double>(watch[3]), nb::cast<long>(watch[4]), nb::cast<long>(watch[5]),
            nb::len(watch) > 6 && nb::cast<bool>(watch[6])};
  if (gate.every < 1) throw nb::value_error("the watch's exact interval must be >= 1");
  RowSource* guard = nullptr;
  double t_start = 0.0;
  OutVec smallest;  // (kept alive while its pointer is used)
  if (!guard_arg.is_none()) {
    guard = step_core_guard(core);
    if (guard == nullptr) throw nb::value_error("guard: the StepCore holds no row guard (StepCore.set_guard)");
    nb::tuple g = nb::cast<nb::tuple>(guard_arg);
    if (nb::len(g) != 2) throw nb::value_error("guard: (the run's start time, the array of smallest values)");
    t_start = nb::cast<double>(g[0]);
    smallest = nb::cast<OutVec>(g[1]);
    if (smallest.shape(0) < K)
      throw nb::value_error(("guard: the smallest values' array needs at least " + std::to_string(K) +
                             " entries").c_str());
  }
  size_t done = 0;
  int status = 0;
  int nf = 0;
  const int* free = step_core_free(core, nf);
  Inverse inv = inverse_of(watch, m, nf);
  if (gate.on && nb::len(watch) < 12) throw nb::value_error("watch: the history (its 12th entry) is needed");
  WatchHistory hist = gate.on ? history_of(watch) : WatchHistory();
  size_t kept = 0, by_inverse = 0;  // measurements kept; of them, the inverse iteration's
  bool new_ref = false;  // a measurement kept made its J the reference
  if (inv.on) watch_lapack();  // (with the GIL: its first call loads scipy's LAPACK)
  std::vector<double> Jr(static_cast<size_t>(m) * nf), Mr(static_cast<size_t>(nf) * nf);
  const size_t oM = 2 * N, oJ = oM + static_cast<size_t>(n) * n;  // M (n x n) and J (m x n) in the row
  {
    nb::gil_scoped_release release;  // no Python object below: runs in threads compute in parallel
    for (; done < K; ++done) {
      const size_t k = done;
      if (kept && hist.ahead(t.data()[k])) {  // CompiledStep.step's Watch.ahead (before safe_before: none)
        status = AHEAD;
        break;
      }
      StepInput in{p.data() + 3 * k, v.data() + 3 * k, oriented ? Q.data() + 9 * k : nullptr,
                   oriented ? omega.data() + 3 * k : nullptr, varying ? ref.data() + n * k : nullptr,
                   varying ? rate.data() + n * k : nullptr};
      double* o = out.data() + row * k;
      status = step_core_advance(core, in, y, yd, prev, qd, speed2, check_jump, o);
      if (status != 0) break;
      if (guard != nullptr) {  // StepCore.step_guarded's check: from [q; lam] with rates qd to the row's, h [s] long
        const double h = t.data()[k] - (k ? t.data()[k - 1] : t_start);
        const bool clear = guard->clear_at(y, o, qd, o + N, h, held);  // (the held rows left out)
        smallest.data()[k] = guard->smallest();
        if (!clear) {
          status = GUARD_DUE;
          break;
        }
      }
      if (held != nullptr && gate.on && odd_inertia(core, nf)) {  // a saddle of the held problem, maybe:
        status = WATCH_DUE;  // measured exactly by the caller (CompiledStep.accept: StepControl.watch_point)
        break;
      }
      const double rcond = o[row - 2];
      if (gate.on && gate.due(rcond)) {
        const bool exact = gate.exact_next();
        // Watch.measure's inverse iteration with the core (StepCore.watch_measure), where it would be taken
        if (!exact && !(inv.on && nf >= m && inv.v.size() == static_cast<size_t>(nf))) {
          status = WATCH_DUE;
          break;
        }
        for (int i = 0; i < m; ++i)  // Watch.reduce: the free joints' columns of J, rows and columns of M
          for (int b = 0; b < nf; ++b)
            Jr[static_cast<size_t>(i) * nf + b] = o[oJ + static_cast<size_t>(i) * n + free[b]];
        for (int a = 0; a < nf; ++a)
          for (int b = 0; b < nf; ++b)
            Mr[static_cast<size_t>(a) * nf + b] = o[oM + static_cast<size_t>(free[a]) * n + free[b]];
        double sigma = 0.0, eig = 0.0;
        if (exact) {
          ExactMeasure e;
          watch_exact(Jr.data(), Mr.data(), m, nf, e);
          if (hist.crossed(e.sigma, e.eig, hist.sigma_max, e.scale)) {  // measured again from its row by the caller
            status = WATCH_DUE;
            break;
          }
          inv.v = e.v;  // Watch.keep_exact: the vector, the reference J, the fold floor's scale
          inv.J_ref = Jr;
          inv.sigma_ref = e.sigma;
          hist.scale = e.scale;
          hist.fresh = new_ref = true;
          sigma = e.sigma, eig = e.eig;
        } else {
          int N_lu = 0;
          const int* piv = nullptr;
          const double* lu = step_core_factors(core, piv, N_lu);
          InverseMeasure r;
          if (N_lu != nf + m || !watch_inverse(Jr.data(), Mr.data(), lu, piv, nf, m, inv.v.data(),
                                                inv.J_ref.empty() ? nullptr : inv.J_ref.data(), inv.sigma_ref,
                                                inv.gate, r)) {
            status = WATCH_DUE;  // the exact branch's: this step is the caller's
            break;
          }
          // Watch.took's floors (sigma_max where dgesvd gave it, the scale where J is square), then its verdict
          const double s_max = r.fresh && !r.square ? r.sigma_max : hist.sigma_max;
          const double scale = r.square ? r.scale : hist.scale;
          if (hist.crossed(r.sigma, r.eig, s_max, scale)) {  // the watch as it was before it: handed back
            status = WATCH_REJECTS;
            break;
          }
          inv.v = r.u;  // Watch.took
          if (r.fresh) {
            inv.J_ref = Jr;
            inv.sigma_ref = r.sigma;
            new_ref = true;
          }
          hist.sigma_max = s_max, hist.scale = scale, hist.fresh = r.fresh;
          sigma = r.sigma, eig = r.eig;
          ++by_inverse;
        }
        hist.push(t.data()[k], sigma, eig);
        ++kept;
      }
      // the driver's bookkeeping (CompiledStep._apply): (y, ydot) joins the history, which keeps two pairs
      prev.push_back(y);
      prev.push_back(yd);
      if (prev.size() == 6) prev.erase(prev.begin(), prev.begin() + 2);
      y = o;
      yd = o + N;
      qd = o + N;
      if (gate.on) {
        speed2 = o[row - 1];
        gate.last = rcond;
        ++gate.count;
      }
    }
  }
  if (!kept) return nb::make_tuple(done, status, nb::none());
  const nb::object J_ref = new_ref ? nb::cast(array_of(inv.J_ref, m, nf)) : nb::none();
  nb::tuple state = nb::make_tuple(nb::cast(hist.times), nb::cast(hist.eig), nb::cast(hist.sigma_times),
                                   nb::cast(hist.sigma), hist.sigma_max, hist.scale, hist.safe,
                                   array_of(inv.v, inv.v.size(), 0), J_ref, inv.sigma_ref, hist.fresh, by_inverse, kept);
  return nb::make_tuple(done, status, state);
}

void bind_loop(nb::module_& m) {
  m.attr("WATCH_DUE") = WATCH_DUE;
  m.attr("GUARD_DUE") = GUARD_DUE;
  m.attr("AHEAD") = AHEAD;
  m.def("run_steps", &run_steps, nb::arg("core"), nb::arg("t"), nb::arg("p"), nb::arg("v"), nb::arg("Q"),
        nb::arg("omega"), nb::arg("ref"), nb::arg("rate"), nb::arg("y"), nb::arg("yd"), nb::arg("prev"),
        nb::arg("qdot0"), nb::arg("speed2"), nb::arg("check_jump"), nb::arg("watch"), nb::arg("out"),
        nb::arg("guard") = nb::none(),
        "Ordinary steps of a StepCore over presampled times, the GIL released (see src/core/loop.cpp).");
}

}  // namespace kinredund
