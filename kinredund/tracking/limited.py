"""Hard joint limits (and general inequality rows) in the default mode: the constrained optimum followed exactly.

Along the path the joints follow theta*(t) = argmin z(theta) s.t. g(theta) = x(t), lower <= theta <= upper.
With the active set A (the joints on a bound, side s_i = +1 at a lower bound, -1 at an upper one) the
first-order conditions are

    grad z + J^T lambda - sum_{i in A} s_i mu_i e_i = 0,   g(theta) = x(t),   theta_A = bound_A,   mu_A >= 0,

so between switching times the free joints F solve the thesis's equality system with the active joints'
columns removed: R_F = [[M_FF, J_F^T], [J_F, 0]] (Eq. 4.24 reduced), the predictor and the Newton
corrector of :mod:`kinredund.tracking.predictor_corrector` running on it, and the bound multipliers
are mu_i = s_i (grad z + J^T lambda)_i. After each step the stepper looks for a switch within it: a free
joint beyond its bound, or a multiplier below zero. It then solves for the switching time on the
corrected path (Brent's method on the joint's margin or on the multiplier, each evaluation a corrector
solve at that time), steps to it, changes the active set there and steps on to the end of the step, so
no joint overshoots its bound and no multiplier of the wrong sign survives. At a switch the rate QP of
the weakly active bound decides which set continues (min 1/2 v^T M v - top^T v s.t. J v = xdot and the
sign condition of that bound's rate; proxsuite), where the LU route cannot tell. The switches' location
is :mod:`kinredund.tracking.switches`.

General rows c_i(theta) >= 0 (an obstacle's clearance) are held the same way, their equations added to
the system instead of columns removed (:mod:`kinredund.tracking.rows`). Thesis mode with limits is not
offered (explicit steps have no corrector to hold the bounds): the Tracker refuses it.
"""

from __future__ import annotations

import operator
import weakref
from dataclasses import dataclass

import numpy as np

from kinredund.errors import PathError, SingularityError, TrackingError
from kinredund.tracking.constraints.base import Constraint
from kinredund.tracking.constraints.joint_limits import JointLimits
from kinredund.tracking.failure import watched_at
from kinredund.tracking.linalg import classify, lu_solve
from kinredund.tracking.point import Evaluator, Point
from kinredund.tracking.predictor_corrector import PredictorCorrector
from kinredund.tracking.rows import GeneralRows
from kinredund.tracking.state import ConstrainedState
from kinredund.tracking.switches import SwitchLocation

#: a joint within this distance of its bound at the start counts as on it [rad or m]; a start outside
#: the limits by at most this much is put on the bound
ON_BOUND = 1e-10


@dataclass(frozen=True)
class Bounds:
    """What the stepper derives from its limits' ``bounds()`` alone, made once per limits object and shared by its
    runs and threads (read-only arrays, (n,)): ``lo``, ``hi`` per joint [rad or m] (-inf, +inf where unbounded);
    ``lo_tol``, ``hi_tol`` beyond which a free joint is a switch (rounding below 1e-13 is not), and ``switch``, the
    two as lists of floats; ``inside``: (lower, upper) as floats, strictly between which a start has no joint on or
    beyond a bound (``ON_BOUND``); ``free``: (fixed, side, mu) of a start with every joint free (zeros)."""

    lo: np.ndarray
    hi: np.ndarray
    lo_tol: np.ndarray
    hi_tol: np.ndarray
    switch: tuple
    inside: tuple
    free: tuple


_BOUNDS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # limits -> (its bounds() arrays, n, Bounds)


def limit_bounds(limits: Constraint | None, n: int) -> Bounds:
    """The :class:`Bounds` of ``limits`` (None: no bound) for n joints, kept per limits object while its ``bounds()``
    arrays stay the same objects (a JointLimits is not changed after it is made: :func:`~kinredund.tracking.tracker.
    robot_limits`)."""
    got = None if limits is None else limits.bounds()
    try:
        kept = _BOUNDS.get(limits) if limits is not None else None
    except TypeError:  # an unhashable constraint: made afresh
        kept = None
    if kept is not None and kept[1] == n:
        (joint, side, bound), now = kept[0], got
        if joint is now[0] and side is now[1] and bound is now[2]:
            return kept[2]
    lo, hi = np.full(n, -np.inf), np.full(n, np.inf)
    if got is not None:  # the bounds through the base class: side (theta_joint - bound) >= 0
        joint, side, bound = got
        lo[joint[side > 0]], hi[joint[side < 0]] = bound[side > 0], bound[side < 0]
    lo_tol, hi_tol = lo - 1e-13, hi + 1e-13
    made = Bounds(lo, hi, lo_tol, hi_tol, (lo_tol.tolist(), hi_tol.tolist()),
                  ((lo + ON_BOUND).tolist(), (hi - ON_BOUND).tolist()), (np.zeros(n, bool), np.zeros(n), np.zeros(n)))
    for a in (made.lo, made.hi, made.lo_tol, made.hi_tol, *made.free):
        a.flags.writeable = False
    if limits is not None:
        try:
            _BOUNDS[limits] = (got, n, made)
        except TypeError:
            pass
    return made


class LimitedPredictorCorrector(SwitchLocation, GeneralRows, PredictorCorrector):
    """The default-mode stepper with hard joint limits and general inequality rows (augmented or velocity form).

    Args (besides :class:`~kinredund.tracking.predictor_corrector.PredictorCorrector`'s):
        limits: a :class:`~kinredund.tracking.constraints.base.Constraint` of simple bounds (its ``bounds()``;
            the robot's :class:`~kinredund.tracking.constraints.JointLimits`), or None.
        constraints: constraints of general rows (``bounds()`` None; :mod:`kinredund.tracking.rows`).
        qp_solver: the QP solver of the rate QP at a weakly active row (qpsolvers: ``proxqp`` or ``daqp``).

    State besides :class:`~kinredund.tracking.predictor_corrector.PredictorCorrector`'s (one value,
    :class:`~kinredund.tracking.state.ConstrainedState`): ``fixed`` (n,) bool, ``side`` (n,) (+1 at a lower
    bound, -1 at an upper bound, 0 free), ``switches`` (a tuple of dicts: time [s], joint, ``reach`` or
    ``release``, side) and ``mu`` (n,), the bound multipliers at t. The arrays are replaced, never changed
    in place. With no joint on a bound every operation is the unlimited stepper's own.
    """

    state_class = ConstrainedState

    def __init__(self, evaluator: Evaluator, q0: np.ndarray, dt: float, *, limits: Constraint | None = None,
                 constraints=(), qp_solver: str = "proxqp", **kwargs):
        self.limits = limits
        n = evaluator.n
        self._m = evaluator.robot.task_dim
        self.joint_names = evaluator.robot.joint_names
        bounds = limit_bounds(limits, n)
        self.lo, self.hi = bounds.lo, bounds.hi
        # a free joint beyond its bound by more than 1e-13 rad is a switch (rounding below that is not)
        self._lo_tol, self._hi_tol, self._switch_floats = bounds.lo_tol, bounds.hi_tol, bounds.switch
        self.fixed, self.side, self._no_mu = bounds.free  # read-only: a switch replaces them (_fix, _free)
        self.mu = self._no_mu
        self.switches: tuple[dict, ...] = ()
        self.switch_anchor = None  # see step()
        self._sel = None  # the free rows of R (None: all joints free)
        lower, upper = bounds.inside
        q = q0.tolist()
        inside = all(map(operator.lt, lower, q)) and all(map(operator.lt, q, upper))
        if not (inside and type(limits) in (JointLimits, type(None))):  # else no joint on a bound or beyond one
            q0 = self._start_inside(q0, evaluator)
        self._init_rows(constraints, q0, qp_solver)
        if not (inside and not self.rows):  # (inside with no row on its constraint: every joint free, _sel None)
            for i in np.flatnonzero(q0 <= self.lo + ON_BOUND):
                self._fix(i, +1.0)
            for i in np.flatnonzero(q0 >= self.hi - ON_BOUND):
                self._fix(i, -1.0)
            self._update_sel()  # rows on their constraint at the start are active too
            q0 = np.where(self.fixed, np.where(self.side > 0, self.lo, self.hi), q0)
        super().__init__(evaluator, q0, dt, **kwargs)
        self._settle_start()

    def _settle_start(self) -> None:
        """Put the corrected start on the constrained optimum: fix a free joint beyond its bound, free a
        bound joint whose multiplier has the wrong sign (the most violated first), correct, repeat."""
        for _ in range(2 * self.n + 2):
            events = self._events()
            if not events:
                return
            joint, kind = min(events, key=lambda e: self._watch(*e))
            self._apply_switch(joint, kind)
            self.prev.clear()
            self._newton_rates()
        raise TrackingError("no constrained optimum within the joint limits and constraints was found at the start",
                            cause=self._cause(), t=self.t, q=None, watched=self._watched())

    # -- the active set ----------------------------------------------------------------------------
    def _start_inside(self, q0: np.ndarray, ev: Evaluator) -> np.ndarray:
        out = [] if self.limits is None else self.limits.violations(q0, ON_BOUND)
        if out:
            what = "; ".join(f"{name} by {amount:.3g}" for name, amount in out)
            raise TrackingError(f"the starting configuration is outside the joint limits: {what} [rad or m] "
                                "(pass project_start=True to put it on the limits, or start inside them)",
                                cause="limits_infeasible", t=0.0, q=None, watched={"violations": dict(out)})
        return np.clip(q0, self.lo, self.hi)

    def _fix(self, i: int, side: float) -> None:
        self.fixed, self.side = self.fixed.copy(), self.side.copy()  # a saved state keeps its own
        self.fixed[i], self.side[i] = True, side
        self._update_sel()

    def _free(self, i: int) -> None:
        self.fixed, self.side = self.fixed.copy(), self.side.copy()
        self.fixed[i], self.side[i] = False, 0.0
        self.mu = self.mu.copy()
        self.mu[i] = 0.0
        self._update_sel()

    def _update_sel(self) -> None:
        """The free joints' rows of R and of [q; lambda; w] (None: every joint free and no row active, the
        unlimited route)."""
        n = len(self.fixed)
        free = np.flatnonzero(~self.fixed)
        if len(free) == n and not self.rows:
            self._sel = None
            return
        m = self._m + len(self.rows)
        if len(free) < m:
            raise self._failure(self._cause(), f"{n - len(free)} joints on their limits leave {len(free)} free "
                                f"joints for a task of dimension {self._m} and {len(self.rows)} active rows "
                                f"({self._names_fixed()})")
        self._free_idx = free
        self._sel = np.concatenate([free, n + np.arange(m)])

    def _names_fixed(self) -> str:
        names = self.joint_names
        bounds = [f"{names[i]} ({'lower' if self.side[i] > 0 else 'upper'})" for i in np.flatnonzero(self.fixed)]
        return ", ".join(bounds + self.row_names(self.rows))

    def _bound_values(self) -> np.ndarray:
        return np.where(self.side > 0, self.lo, self.hi)

    def active_set(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(fixed, side, bound): the joints on a bound ((n,) bool), their sides ((n,): +1 lower, -1 upper, 0 free)
        and the bound values there ((n,) [rad or m], the lower limit where free). The arrays are replaced at a
        switch, never changed in place: ``fixed`` staying the same object means the same active set."""
        return self.fixed, self.side, self._bound_values()

    @property
    def switch_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) [rad or m]: a free joint below or above these is beyond its bound (a switch; the
        limits widened by 1e-13, the rounding that is not one)."""
        return self._lo_tol, self._hi_tol

    def reduced_label(self, M: np.ndarray, J: np.ndarray, verdict: int = 0) -> str:
        """The solver label (:func:`~kinredund.tracking.linalg.classify`) of the system with the joints on their
        bounds removed, from the full M (n, n) and J (m, n). ``verdict``: what the caller knows of the free
        joints' block M_FF where it is clear (the compiled core's): 1 positive definite, 2 not positive definite
        but positive definite on the null space of J_F; 0 nothing (classify decides)."""
        if not self.symmetric or self.linear_solver == "lu":
            return "lu"  # classify's first rule, without the reduction
        if verdict == 1:
            return "qp"
        if verdict == 2:
            return "lu" if self.linear_solver == "thesis" else "qp_aug"
        F = self._free_idx
        return classify(M[np.ix_(F, F)], J[:, F], self.linear_solver, symmetric=self.symmetric)

    def accept(self, y, yd, pt, M, q_pred, rcond, label=None, mu=None, lu=None, **_) -> None:
        """:meth:`PredictorCorrector.accept`, and the bound multipliers ``mu`` (n,) at the new point where a
        joint is on a bound (else none)."""
        super().accept(y, yd, pt, M, q_pred, rcond, label, lu)
        self.mu = self._no_mu if self._sel is None else mu

    def take_corrected(self, y, yd, pt, M, lu, rcond, label=None, mu=None, **_) -> None:
        """:meth:`PredictorCorrector.take_corrected`, and the bound multipliers ``mu`` (n,) at the corrected point
        where a joint is on a bound (else none), as :meth:`_correct` leaves them."""
        super().take_corrected(y, yd, pt, M, lu, rcond, label)
        self.mu = self._no_mu if self._sel is None else mu

    def take_start(self, y, yd, pt, M, rcond, label=None, exact=None, mu=None, **_) -> None:
        """:meth:`PredictorCorrector.take_start`, and the bound multipliers ``mu`` (n,) at the start where a joint
        is on a bound (else none)."""
        super().take_start(y, yd, pt, M, rcond, label, exact)
        self.mu = self._no_mu if self._sel is None else mu

    @property
    def any_active(self) -> bool:
        """Is any joint on a bound now?"""
        return self._sel is not None

    def active_bounds(self) -> np.ndarray:
        """(n,) ints: -1 at the lower limit, +1 at the upper limit, 0 free."""
        return (-self.side).astype(int)

    # -- the reduced system (hooks of PredictorCorrector) ------------------------------------------
    def _factor(self, pt: Point, M: np.ndarray):
        if self._sel is None:
            return super()._factor(pt, M)
        F = self._free_idx
        JF = pt.J[:, F]
        R = np.zeros((len(F) + JF.shape[0],) * 2)
        nf = len(F)
        R[:nf, :nf] = M[np.ix_(F, F)]  # Eq. (4.24) with the active joints' columns removed
        R[:nf, nf:] = JF.T
        R[nf:, :nf] = JF
        try:
            return self._factor_matrix(pt, R, JF)
        except SingularityError as err:
            if self.rows:  # a corrector iterate's: the step control retries in sub-steps, then names the stop
                raise
            # the singular R is at a corrector iterate, which may have diverged far out of the limits (its M and
            # J say nothing of the path there): step names the last good point and says what is singular there
            raise self._failure("not_strongly_stable", f"the constrained optimum is not strongly stable at t = "
                                f"{pt.t:.6g} s with joints {self._names_fixed()} on their limits: R of Eq. (4.24) "
                                f"on the free joints turned singular at a corrector iterate (its smallest singular "
                                f"value {err.sigma_min:.3g})") from err

    def _solve(self, lu, b: np.ndarray) -> np.ndarray:
        if self._sel is None:
            return lu_solve(lu, b)
        x = np.zeros_like(b)
        x[self._sel] = lu_solve(lu, b[self._sel])
        return x

    def _residual(self, pt: Point, lam: np.ndarray) -> np.ndarray:
        F = pt.residual(lam)
        if self._sel is not None:
            F[: self.n][self.fixed] = 0.0  # the bound multipliers take these rows up
        return F

    def _correct(self, y: np.ndarray) -> None:
        if self.corrector is not None and self.corrector(y):  # (PredictorCorrector.corrector)
            return  # the compiled core's solve (kinredund.tracking.compiled_correct), as below (the rows' too)
        if self._sel is not None:
            y = y.copy()
            y[: self.n][self.fixed] = self._bound_values()[self.fixed]
        super()._correct(y)
        if self.rows and self.q is not y[: self.n] and self._rates_stale(y):
            self._rates()  # the rates afresh at the corrected point (see GeneralRows._rates_stale)
        if self._sel is not None and self.label is None:  # the label of the reduced system, now
            self.label = self.reduced_label(self.M, self.pt.J)
        self._update_mu()

    def _rates(self) -> None:
        if self._sel is None:
            super()._rates()
        else:
            pt = self.evaluate(self.q, self.t)
            self.pt = pt
            M, top = pt.system(self.lam)  # Eqs. (4.23), (4.37)
            lu = self._factor(pt, M)
            sol = self._solve(lu, np.concatenate([top, pt.xdot]))
            self.qdot, self.lamdot, self.M = sol[: self.n], sol[self.n:], M
            self.label = self.reduced_label(M, pt.J)
            self.y, self.yd = np.concatenate([self.q, self.lam]), sol
        self._update_mu()

    def _update_mu(self) -> None:
        """mu_i = s_i (grad z + J^T lambda)_i on the active joints (the multipliers of the bounds), at q."""
        if self._sel is None:
            self.mu = self._no_mu
            return
        pt = self.pt
        if pt.q is not self.q:
            pt = self.evaluate(self.q, self.t, need_dJ=False)
        g = pt.grad + pt.J.T @ self.lam
        self.mu = np.where(self.fixed, self.side * g, 0.0)

    def _mu_rates(self) -> np.ndarray:
        """d mu / dt on the active joints from the current rates: s_i (M qdot + J^T lamdot - top)_i."""
        J, M, top = self.system_at(self.q, self.t, self.lam)
        return np.where(self.fixed, self.side * (M @ self.qdot + J.T @ self.lamdot - top), 0.0)

    # -- the step and its switches -----------------------------------------------------------------
    def _state_applied(self) -> None:
        self._update_sel()

    def step(self) -> None:
        """One step to t + dt; a switch of the active set within it is located and stepped to exactly."""
        if self.rows:  # a row that equals another there is held as that one (:meth:`GeneralRows._representatives`)
            self._representatives()
        snap = self.state
        bounded = self._sel is not None or bool(self.switches)  # a failure then is the limits' to name
        self.switch_anchor = None  # a switch the step control located inside a rejected sub-step (switch_within)
        try:
            super().step()
            # the rest of the step, from the last switch located inside a rejected sub-step (if any)
            self._resolve_switches(snap if self.switch_anchor is None else self.switch_anchor)
        except TrackingError as err:
            inside = err.q is None  # raised within the step (a corrector iterate's): said at the step's start
            if inside:
                err.t, err.q = snap.t, np.array(snap.q, dtype=float)  # (a float array, as TrackingError makes it)
                err.watched = self._watched(snap) | dict(err.watched or {})  # the step control's own entries kept
                err.args = (f"{err.args[0]}; last good point t = {err.t:.6g} s, q = "
                            f"{np.round(np.asarray(err.q), 6).tolist()}",)
            self._name_row_failure(err, snap)
            self.state = snap  # back at the last requested time: t = t0 + k dt
            if inside:
                self._diagnose(err)
            raise
        except (PathError, SingularityError) as err:
            rows = self._rows_involved(snap)  # before the state goes back (the step's switches with it)
            if not (bounded or rows):  # as the unlimited scheme reports it: none met
                raise
            self.state = snap
            cause = "kinematic_singularity" if "kinematic" in str(err) else \
                "not_strongly_stable" if isinstance(err, SingularityError) else "limits_infeasible"
            stop = TrackingError(f"tracking within the joint limits and constraints stopped after t = {snap.t:.6g} s: "
                                 f"{err}", cause=cause, t=snap.t, q=snap.q, watched=self._watched(snap))
            self._name_row_failure(stop, snap, rows)
            raise stop from err

    # -- failures ------------------------------------------------------------------------------------
    def _watched(self, snap: ConstrainedState | None = None) -> dict:
        state = snap if snap is not None else self.state
        q = state.q
        out = {"active": (-np.asarray(state.side)).astype(int).tolist(),
               "bound_multipliers": np.asarray(state.mu).tolist(),
               "limit_margins": np.minimum(np.minimum(q - self.lo, self.hi - q), 1e10).tolist()}
        return out | self._rows_watched(state)

    def _diagnose(self, err: TrackingError) -> None:
        """What is singular at the last good point (the stepper's state) of a stop raised within a step: the
        watched quantities on the free joints (:func:`~kinredund.tracking.failure.watched_at`: ``sigma_min_J`` of
        the Jacobian of the free joints, the reduced Hessian on its null space), and J's own smallest singular
        value (``sigma_min_J_all_joints``), which stays away from zero where only the free joints lose rank."""
        w = watched_at(self)
        J = self.evaluate(self.q, self.t, need_dJ=False).J
        s_all = float(np.linalg.svd(J, compute_uv=False)[-1])
        err.watched.update(w, sigma_min_J_all_joints=s_all)
        if "sigma_min_J" not in w:  # no index: no R to diagnose
            return
        free, m = int(np.count_nonzero(~self.fixed)), J.shape[0]
        said = (f"; there the Jacobian of the {free} free joints has smallest singular value {w['sigma_min_J']:.3g} "
                f"(J of all {self.n}: {s_all:.3g})")
        if free == m:  # R = [[M_F, J_F^T], [J_F, 0]] with J_F square: det R = +-det(J_F)^2
            said += ", as many as the rows they must meet: R is singular exactly where this Jacobian is (LICQ fails)"
        elif np.isfinite(w["reduced_hessian_min"]):
            said += f", the reduced Hessian on its null space smallest eigenvalue {w['reduced_hessian_min']:.3g}"
        err.args = (err.args[0] + said,) + tuple(err.args[1:])

    def _failure(self, cause: str, message: str) -> TrackingError:
        """A TrackingError; its last good state is filled in by :meth:`step` (the step's start)."""
        return TrackingError(message, cause=cause)

