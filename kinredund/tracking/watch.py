"""The fold and singularity watch of the strict tracker (Chapter 4, Theorem 2; issue 15).

Per accepted step the watch measures two quantities at the step's point and predicts whether either
crosses zero within the next step:

- ``sigma_min_J``, the smallest singular value of J (kinematic: where it reaches zero the arm is
  stretched or folded and J loses rank);
- ``reduced_hessian_min``, the eigenvalue nearest zero of the reduced Hessian Z^T M Z on the null space
  of J (and of the active bounds: the columns of fixed joints are removed), M = Hess z + Lambda (Eq.
  4.23; its symmetric part in the velocity form, whose Z^T M* Z equals the augmented one on the optimal
  manifold). Where it reaches zero the local minimum of z on the self-motion manifold ceases to exist
  (a fold; second-order sufficiency, Theorem 2, fails) and R of Eq. (4.24) is singular.

Cost per step (the step already has J, M and R's LU factors): ``reduced_hessian_min`` by one step of
inverse iteration with R's factors, warm-started from the previous step's vector: the top block of
R^{-1} is P = Z (Z^T M Z)^{-1} Z^T, so one triangular solve (LAPACK dgetrs) gives u = P v, whose
direction converges to the eigenvector of the eigenvalue nearest zero, and the Rayleigh quotient
u^T M u / u^T u estimates it (exact when n - m = 1, and the more accurate the nearer that eigenvalue is
to zero, where it matters; refreshed exactly every :data:`EXACT_EVERY` steps). ``sigma_min_J`` by an
SVD of J (LAPACK dgesvd, no vectors) only when J has moved, in the Frobenius norm, by more than
:data:`J_GATE` of the last exact value since it was taken: by Weyl's inequality sigma_min(J) changes by
at most ||J - J_ref||_2 <= ||J - J_ref||_F, so between exact values it stays above 3/4 of the last one.
Where J moves slowly that is one triangular solve and a few vector operations per measured step.

The prediction extrapolates each quantity v from its last two values linearly, and v^2 linearly (a
fold's eigenvalue and sigma_min at a workspace boundary behave like sqrt(t* - t), whose square is
linear), to the next step's time; a value at or below its floor there is a predicted crossing. The
step control (:mod:`kinredund.tracking.step_control`) then approaches with halved steps and stops
before the crossing, at the last good point.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import lapack

#: the watch measures where the condition estimate of R (dgecon's rcond, free with the step's LU) is below
#: this, or fell below RCOND_DROP of the previous step's (the first step: of the start's, Watch's ``rcond``), or every
#: EXACT_EVERY steps; elsewhere it skips
RCOND_NEAR = 1e-4
RCOND_DROP = 0.8
#: an exact eigenvalue computation (one SVD of J for sigma_min and the null-space basis, eigh) every this many
#: measurements resets the inverse iteration's vector (where n - m > 1 a second eigenvalue may come nearer zero)
EXACT_EVERY = 32
#: the exact sigma_min(J) is recomputed once ||J - J_ref||_F exceeds this fraction of the last exact value
J_GATE = 0.25
#: sigma_min(J) at or below this fraction of sigma_max(J) (at least 1) is a kinematic singularity
SIGMA_FLOOR = 1e-8
#: an eigenvalue of Z^T M Z at or below this fraction of max(1, max |M_ij|) is a fold
EIG_FLOOR = 1e-10


def reduce(J: np.ndarray, M: np.ndarray, fixed: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """J and M with the fixed joints' columns (and M's rows) removed (``fixed``: a bool mask, or None)."""
    if fixed is None or not fixed.any():
        return J, M
    free = np.flatnonzero(~fixed)
    return J[:, free], M[np.ix_(free, free)]


def free_columns(J: np.ndarray, fixed: np.ndarray | None) -> np.ndarray:
    """J of :func:`reduce` alone (where M is not needed: an exact measurement made elsewhere, kept with its J)."""
    if fixed is None or not fixed.any():
        return J
    return J[:, np.flatnonzero(~fixed)]


def exact(J: np.ndarray, M: np.ndarray) -> tuple[float, float, np.ndarray]:
    """(sigma_min(J), smallest eigenvalue of Z^T sym(M) Z, its eigenvector in joint space), exactly.

    One SVD of J gives both sigma_min(J) and Z, the last n - m right singular vectors (an orthonormal basis of the
    null space of J; the eigenvalues of Z^T sym(M) Z do not depend on which). Where n - m = 1 the reduced Hessian
    is the number z^T sym(M) z and z its eigenvector."""
    m, n = J.shape
    if n == m:
        sJ = np.linalg.svd(J, compute_uv=False)
        return float(sJ[-1]), math.inf, np.zeros(n)
    sJ, Vt = np.linalg.svd(J)[1:]
    Z = Vt[m:].T
    S = Z.T @ (0.5 * (M + M.T)) @ Z
    if n - m == 1:
        return float(sJ[-1]), float(S[0, 0]), Z[:, 0]
    w, V = np.linalg.eigh(S)
    return float(sJ[-1]), float(w[0]), Z @ V[:, 0]


_NO_REF = np.zeros((0, 0))  # no reference J yet (the core's argument)


class Watch:
    """The watched quantities along one run, their history and the crossing prediction.

    Attributes:
        times, eig: the last two measurement times [s] and reduced-Hessian values (oldest first).
        sigma_times, sigma: the last two exact values of sigma_min(J) and their times.
        sigma_max: the largest singular value of J at the last exact SVD (the kinematic floor's scale).
        scale: max(1, max |M_ij|) at the last exact eigenvalue (the fold floor's scale).
        core_measured: the measurements the compiled core made (``measure``'s ``core``), of those kept.

    ``rcond``: R's condition estimate where the first measurement is taken (a run's start, whose R is factored for its
    rates), which the gate compares the first step's with as it compares every later step's with the step before
    (:meth:`due_next`): a first step whose R is not nearer singular than the start's goes unmeasured as any later one.
    Without it (+inf) the first step is always measured.
    """

    def __init__(self, rcond: float = math.inf):
        self.times: list[float] = []
        self.eig: list[float] = []
        self.sigma_times: list[float] = []
        self.sigma: list[float] = []
        self._fresh = True
        self._v = None
        self._J_ref, self._sigma_ref, self.sigma_max, self.scale = None, 0.0, 1.0, 1.0
        self._count = 0
        self._rcond = rcond
        self._b = None
        self._safe = -math.inf  # nothing measured yet: ahead() checks the history itself
        self._exact_at = None
        self._key = None  # the active set of the history (None: no joint on a bound)
        self.core_measured = 0  # measurements the compiled core made (:meth:`took`)
        self._core_exact = None  # the core's exact measurement (:meth:`use_core`), or None: numpy's (:func:`exact`)

    def due(self, rcond: float) -> bool:
        """Should this step be measured? (The cheap gate: R's condition estimate, see :data:`RCOND_NEAR`.)"""
        out = self.due_next(rcond)
        self._rcond = rcond
        self._count += 1
        return out

    def due_next(self, rcond: float) -> bool:
        """What :meth:`due` would say of a step with ``rcond``, without counting the step."""
        return not rcond > RCOND_NEAR or rcond < RCOND_DROP * self._rcond or (self._count + 1) % EXACT_EVERY == 0

    def passes(self, rcond: float) -> bool:
        """Does a step with ``rcond`` go unmeasured? Where it does (:meth:`due` would say False), it is counted as
        :meth:`due` counts it; where it does not, nothing is counted (:meth:`due` is then called by the measurement).
        """
        if self.due_next(rcond):
            return False
        self._count += 1
        self._rcond = rcond
        return True

    @property
    def gate(self) -> tuple[float, int]:
        """(the last step's rcond, steps counted): what :meth:`due_next` reads besides the step's own rcond."""
        return self._rcond, self._count

    @property
    def safe_before(self) -> float:
        """Steps ending before this time [s] have no crossing ahead (:meth:`ahead` is None there; -inf before
        the first measurement, when :meth:`ahead` checks the history itself)."""
        return self._safe

    def passed(self, count: int, rcond: float) -> None:
        """``count`` steps were taken unmeasured (:meth:`due` was False for each), the last with ``rcond``."""
        self._count += count
        self._rcond = rcond

    def save(self) -> dict:
        """The watch's state (its attributes but the routine of :meth:`use_core`; the histories are changed only
        by :meth:`push` and :meth:`reset`, which a step that is undone has not reached)."""
        state = dict(vars(self))
        del state["_core_exact"]
        return state

    def load(self, saved: dict) -> None:
        """Back to a state of :meth:`save` (a measured step that was rejected after all)."""
        vars(self).update(saved)

    def reset(self) -> None:
        """Forget the history (after a restart: the next prediction starts afresh)."""
        for hist in (self.times, self.eig, self.sigma_times, self.sigma):
            hist.clear()
        self._safe = -math.inf

    def measure(self, J: np.ndarray, M: np.ndarray, lu=None, fixed: np.ndarray | None = None,
                core=None) -> tuple[float, float]:
        """(sigma_min_J, reduced_hessian_min) at a point with J (m, n), M (n, n) and R's LU factors there.

        ``fixed``: the joints on a bound (their columns leave J and M, and ``lu`` must be the factors of
        the reduced R). Without ``lu`` (or where its size does not fit) the eigenvalue is computed exactly.
        ``core``: the compiled core (``kinredund._core.StepCore``) whose last step's J, M and R's factors these
        are; it computes the inverse-iteration branch below in C++ with the same LAPACK calls
        (``StepCore.watch_measure``, ``src/core/watch.cpp``), and this watch keeps its results.
        """
        if core is not None and self._v is not None and self._count % EXACT_EVERY != 0:
            out = core.watch_measure(*self.iteration)
            if out is not None:
                return self.took(*out)
            lu = None  # sizes that do not fit, or u not finite: exactly, as below
        J, M = reduce(J, M, fixed)
        m, n = J.shape
        v = self._v
        if v is None or len(v) != n or lu is None or lu[0].shape[0] != n + m or self._count % EXACT_EVERY == 0:
            return self._exact(J, M)
        b = self._b
        if b is None or len(b) != n + m:
            b = self._b = np.zeros(n + m)
        b[:n] = v
        u = lapack.dgetrs(lu[0], lu[1], b)[0][:n]  # u = P v (top block of R^-1)
        uu = float(u @ u)
        if not (uu > 0.0 and math.isfinite(uu)):
            return self._exact(J, M)
        u /= math.sqrt(uu)
        self._v = u
        eig = float(u @ (M @ u))  # Rayleigh quotient on the null space of J (u = P v lies in it)
        return self._sigma(J), eig

    @property
    def iteration(self) -> tuple:
        """(the vector v or None, the reference J or an empty array, sigma_min(J) there, :data:`J_GATE`): the inverse
        iteration's state that :meth:`measure` hands the core (``StepCore.watch_measure``) and a run of steps carries
        through its measurements (``run_steps``: :mod:`kinredund.tracking.runs`)."""
        return self._v, _NO_REF if self._J_ref is None else self._J_ref, self._sigma_ref, J_GATE

    def took(self, sigma: float, eig: float, u: np.ndarray, fresh: bool, sigma_max, J, scale) -> tuple[float, float]:
        """Keep a measurement of the compiled core (``_core.watch_measure``'s tuple: the vector u; where sigma_min(J)
        was computed afresh J, the new reference, and sigma_max where dgesvd gave it; the fold floor's scale where
        the exact branch gave it, J square); returns (sigma, eig)."""
        self._v, self._fresh = u, fresh
        self.core_measured += 1
        if fresh:
            self._J_ref, self._sigma_ref = J, sigma
        if sigma_max is not None:
            self.sigma_max = sigma_max
        if scale is not None:
            self.scale = scale
        return sigma, eig

    def history(self, fixed: np.ndarray | None) -> tuple:
        """(times, eig, sigma_times, sigma, sigma_max, scale, :attr:`safe_before`, whether the next :meth:`push` with
        ``fixed`` starts the history afresh, :data:`SIGMA_FLOOR`, :data:`EIG_FLOOR`): what a run of steps takes the
        watch's verdicts with in the core (``run_steps``, ``src/core/watch.cpp``'s WatchHistory: :meth:`crossed`,
        :meth:`push`, :meth:`ahead`; :mod:`kinredund.tracking.runs`), then hands back to :meth:`take_run`."""
        return (self.times, self.eig, self.sigma_times, self.sigma, self.sigma_max, self.scale, self._safe,
                _key(fixed) != self._key, SIGMA_FLOOR, EIG_FLOOR)

    def take_run(self, state: tuple, fixed: np.ndarray | None) -> None:
        """The watch after a run of steps whose measurements the core kept, with their verdicts and pushes
        (``run_steps``'s state, the active set ``fixed`` throughout): the histories, the floors' scales,
        :attr:`safe_before`, the vector v, the reference J and sigma_min(J) there where a measurement made a new one,
        whether the newest sigma_min(J) was afresh, how many of them were the inverse iteration's (:meth:`took`) and
        how many were kept: as :meth:`keep_exact` or :meth:`took` and then :meth:`push` leave it after each."""
        times, eig, sigma_times, sigma, self.sigma_max, self.scale, self._safe, self._v, J_ref, sigma_ref, \
            self._fresh, by_core, _ = state
        self.times[:], self.eig[:], self.sigma_times[:], self.sigma[:] = times, eig, sigma_times, sigma
        if J_ref is not None:
            self._J_ref, self._sigma_ref = J_ref, sigma_ref
        self.core_measured += by_core
        self._key, self._exact_at = _key(fixed), None

    def refresh(self, t: float, J: np.ndarray, M: np.ndarray, fixed: np.ndarray | None = None) -> None:
        """Measure exactly at t and push it (before a prediction is acted on: the history may be stale)."""
        if self._exact_at == t:
            return
        self.push(t, *self.measure_exact(J, M, fixed), fixed=fixed, exact=True)

    def exact_at(self, t: float) -> bool:
        """Is the newest measurement an exact one taken at t (so that :meth:`refresh` there has nothing to do)?"""
        return self._exact_at == t

    def measure_exact(self, J: np.ndarray, M: np.ndarray, fixed: np.ndarray | None = None) -> tuple[float, float]:
        """(sigma_min_J, reduced_hessian_min) exactly (one SVD of J, eigh where n - m > 1), at the caller's point."""
        self._exact_at = None
        return self._exact(*reduce(J, M, fixed))

    def use_core(self, core) -> None:
        """Measure exactly with the compiled core's ``watch_exact`` (``src/core/watch.cpp``, Eigen) instead of
        :func:`exact` (numpy's LAPACK): the compiled backend's, whose runs of steps measure with the same routine
        in C++ (:mod:`kinredund.tracking.runs`), so that runs and single steps give the same bits."""
        self._core_exact = core.watch_exact

    def _exact(self, J, M) -> tuple[float, float]:
        if self._core_exact is None:
            sigma, eig, v = exact(J, M)
            scale = max(1.0, float(np.abs(M).max()))
        else:
            sigma, eig, v, scale = self._core_exact(np.ascontiguousarray(J, float), np.ascontiguousarray(M, float))
        return self.keep_exact(J, sigma, eig, v, scale)

    def keep_exact(self, J: np.ndarray, sigma: float, eig: float, v: np.ndarray, scale: float) -> tuple[float, float]:
        """Keep an exact measurement at J (the free joints'): :func:`exact`'s (sigma, eig, v) and the fold floor's
        scale max(1, max |M_ij|) (the core's ``watch_exact`` gives all four); returns (sigma, eig)."""
        self._v = v
        self.scale = scale
        self._J_ref, self._sigma_ref, self._fresh = J.copy(), sigma, True
        return sigma, eig

    def _sigma(self, J: np.ndarray) -> float:
        """sigma_min(J): the last exact value while J stays within :data:`J_GATE` of it (Weyl), else afresh."""
        ref = self._J_ref
        if ref is not None and ref.shape == J.shape:
            D = (J - ref).ravel()
            if float(D @ D) < (J_GATE * self._sigma_ref) ** 2:
                self._fresh = False
                return self._sigma_ref
        self._fresh = True
        s = lapack.dgesvd(J, compute_uv=0, full_matrices=0)[1]
        self._J_ref, self._sigma_ref, self.sigma_max = J.copy(), float(s[-1]), float(s[0])
        return self._sigma_ref

    def push(self, t: float, sigma: float, eig: float, fixed: np.ndarray | None = None, exact: bool = False) -> None:
        """Keep (t, sigma, eig) as the newest measurement (two of each are kept; sigma_min(J) only where
        it was computed afresh, so that its secant spans the steps since the previous exact value).

        ``exact``: the values came from :meth:`measure_exact` at t (a :meth:`refresh` there is then skipped).
        ``fixed``: the joints on a bound there. Where the active set differs from the last measurement's,
        the null space changed at a switching time and the history starts afresh (the quantities jump
        there: a secant across the switch would predict a crossing that is not there).
        """
        key = _key(fixed)
        if key != self._key:
            self.reset()
            self._key = key
        if self._fresh or not self.sigma:
            _keep(self.sigma_times, t, self.sigma, sigma)
        _keep(self.times, t, self.eig, eig)
        self._safe = min(self.crossings().values())
        self._exact_at = t if exact else None

    def floors(self) -> tuple[float, float]:
        """(kinematic floor, fold floor): values at or below them count as crossed."""
        return SIGMA_FLOOR * max(1.0, self.sigma_max), EIG_FLOOR * self.scale

    def crossed(self, sigma: float, eig: float, scale: float | None = None) -> str | None:
        """``kinematic``, ``fold`` or None: which quantity (if any) is at or below its floor; ``scale``: the fold
        floor's scale of an exact measurement not yet kept (:meth:`keep_exact` makes it the watch's ``scale``)."""
        fs, fe = self.floors()
        if scale is not None:
            fe = EIG_FLOOR * scale
        if not sigma > fs:  # "not >": NaN counts as crossed
            return "kinematic"
        if not eig > fe:
            return "fold"
        return None

    def crossings(self) -> dict[str, float]:
        """{``kinematic``: t, ``fold``: t}: when each quantity, extrapolated from its last two values (v and v^2
        linearly, the module docstring), reaches its floor [s] (-inf: at or below it now; +inf: not decreasing)."""
        fs, fe = self.floors()
        return {"kinematic": _crossing_time(self.sigma_times, self.sigma, fs),
                "fold": _crossing_time(self.times, self.eig, fe)}

    def ahead(self, t_next: float) -> str | None:
        """``kinematic``, ``fold`` or None: the quantity predicted to cross zero by ``t_next`` [s]; where both are, the
        one predicted to cross first (:meth:`crossings`; a tie, both at their floors already, is ``kinematic``, as in
        :meth:`crossed`), so that a stop looking a whole step ahead names the quantity that goes first, not the one
        checked first (a fold was named a singularity: :mod:`kinredund.tracking.constraints.pieces`)."""
        if t_next < self._safe:  # the earliest predicted crossing, computed at the last push
            return None
        when = self.crossings()
        kind = min(when, key=when.get)  # dicts keep their order: kinematic first in a tie
        return kind if when[kind] <= t_next else None


def _key(fixed: np.ndarray | None) -> bytes | None:
    """The active set's key of a history (None: no joint fixed)."""
    return None if fixed is None or not fixed.any() else fixed.tobytes()


def _keep(times: list[float], t: float, values: list[float], v: float) -> None:
    if times and times[-1] == t:  # a second measurement at the same time (exact after estimated) replaces it
        values[-1] = v
        return
    times.append(t)
    values.append(v)
    if len(times) > 2:
        del times[0], values[0]


def _crossing_time(times: list[float], values: list[float], floor: float) -> float:
    """The earliest time [s] at which v or v^2, extrapolated linearly from its last two values, reaches ``floor``
    (-inf where the last value is at or below it or not a number, +inf where v does not decrease)."""
    if not values:
        return math.inf
    v1 = values[-1]
    if not v1 > floor:
        return -math.inf
    if len(values) < 2:
        return math.inf
    v0, t0, t1 = values[-2], times[-2], times[-1]
    if not (v1 < v0 and t1 > t0):
        return math.inf
    slope, slope2 = (v1 - v0) / (t1 - t0), (v1 * v1 - v0 * v0) / (t1 - t0)
    return min(t1 + (floor - v1) / slope, t1 + (floor * floor - v1 * v1) / slope2)
