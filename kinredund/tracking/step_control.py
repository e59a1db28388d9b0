"""Step control of the strict tracker: sub-steps, the jump check and the watch's stop (issue 15).

:class:`StepControl` runs each step of the default mode's
:class:`~kinredund.tracking.predictor_corrector.PredictorCorrector` (both forms) and accepts it only if

1. the corrector converged (no ``PathError``/``SingularityError`` from the predictor-corrector step) and, on
   the constrained stepper, the step raised none of its own stops (a ``TrackingError`` naming the limits'
   cause: a shorter step may get past what a whole step cannot, so it is retried in sub-steps like any
   rejected step; only where no sub-step down to the floor passes is that stop raised, with the limits'
   cause, at the last requested time);
2. it is no jump: the displacement agrees with the rates at both ends by the trapezoidal rule,
   |Delta q - h (qdot_k + qdot_{k+1}) / 2| <= :data:`TRAPEZOID_TOL` max(|Delta q|, h max(|qdot_k|,
   |qdot_{k+1}|)) (2-norms). On a smooth step the miss is h^3 |q'''| / 12 (the rule is exact for
   quadratics), of relative size O(h^2); a step that lands on another branch of the optimum misses by
   the jump itself, however large the rates are there. A smooth but under-resolved step is rejected
   and sub-stepped too (the results at the requested times are the same); a jump that persists at the
   floor is a discontinuity of the optimum (or of the path). A whole step whose corrected joints are
   within :data:`PREDICTED_TOL` h |qdot| of the predictor's point (the Hermite extrapolation of the
   past points) is consistent with the smooth past and skips this check (two vector operations);
3. the watch (:mod:`kinredund.tracking.watch`) finds sigma_min(J) and the reduced Hessian's eigenvalue
   nearest zero both above their floors at the new point (a step onto a branch where Z^T M Z is not
   positive definite, a saddle or a maximum of z, is rejected). With general rows active the point is also
   measured (exactly) wherever the inertia of R from its LU factors says Z^T M Z has an odd number of negative
   eigenvalues (:meth:`StepControl._indefinite`), which R's condition, the watch's gate, misses when a step
   passes over a crossing.

A rejected step, or one the watch predicts a crossing within, is retried from the last good point in
sub-steps: h = dt/2, halved on each rejection, doubled back after each accepted sub-step (at most dt),
down to the floor dt / 2**:data:`MAX_HALVINGS` (dt/64). Sub-steps use the Euler predictor (the Hermite
history is cleared, as after a jump, and again at the end so the next step restarts it) and are not
recorded: the record stays on the requested times t0 + k dt. Below the floor the run stops with a
:class:`~kinredund.errors.TrackingError` at the last good point (on the path, optimal, inside the
limits), the stepper put back at the last requested time: ``fold`` (the reduced Hessian's eigenvalue is
predicted to cross, or the step keeps jumping at the floor: the optimum is discontinuous there),
``kinematic_singularity`` or ``out_of_reach`` (sigma_min(J) predicted to cross; out of reach where the
path point at the end of the step, or one step after the stop, cannot be reached: task-only
Levenberg-Marquardt, :func:`~kinredund.tracking.failure.task_residual_min`), else (the corrector fails
with neither quantity near zero) ``out_of_reach`` if the path cannot be reached there, else the branch is
followed toward the failed time by bisection and the stop named by what has fallen at its end (``fold`` or
``kinematic_singularity``: a quantity that jumps within a sub-step, which the watch cannot extrapolate), else
``step_control_exhausted``; a jump where the path's own position jumps is ``path_discontinuity``.

On a step with no trouble the control costs the watch (see :mod:`kinredund.tracking.watch`), the jump
check (three vector norms) and the stepper's state as one value (:mod:`kinredund.tracking.state`: references
and a tuple of the predictor's list), which a rejected (sub-)step is put back to as a whole.
"""

from __future__ import annotations

import math

import numpy as np

from kinredund.errors import PathError, SingularityError, TrackingError
from kinredund.tracking.failure import (
    branch_end,
    constraints_dependent,
    out_of_reach,
    path_contradiction,
    path_jumps,
    watched_at,
)
from kinredund.tracking.watch import Watch, free_columns

#: the sub-step floor is dt / 2**MAX_HALVINGS (dt / 64)
MAX_HALVINGS = 6
#: switches of the active set found in a row at one time inside rejected sub-steps before the sub-step is halved
MAX_SWITCHES_AT_ONCE = 4
#: a step whose displacement misses the trapezoidal rule's h (qdot_k + qdot_{k+1}) / 2 by more than this
#: fraction of max(|Delta q|, h |qdot|) is rejected (see the module docstring)
TRAPEZOID_TOL = 0.25
#: a whole step whose corrected joints lie within this fraction of h |qdot| of the predictor's point
#: (extrapolated from the smooth past) is no jump, and the trapezoidal check is skipped
PREDICTED_TOL = 0.01


class StepControl:
    """Sub-stepping, jump check and watch for one
    :class:`~kinredund.tracking.predictor_corrector.PredictorCorrector` (``stepper``).

    Attributes:
        watch: the :class:`~kinredund.tracking.watch.Watch`.
        floor: the smallest sub-step [s].
        speed2: |qdot|^2 [1/s^2] at the last accepted point (the jump check's scale).

    A step taken elsewhere (the compiled core, :mod:`kinredund.tracking.compiled`) goes through the same
    checks with :meth:`snapshot`, :meth:`restore` and :meth:`watch_point`.
    """

    def __init__(self, stepper):
        self.s = stepper
        self.watch = Watch(math.inf if stepper.rcond is None else stepper.rcond)  # the start's R (both backends)
        self.floor = stepper.dt / 2**MAX_HALVINGS
        self._bounded = None  # see step()
        self._searched = None  # (start, end) of the last sub-step searched for a switch without one (_switch_inside)
        self._stuck = 0  # switches found in a row at one time (_moved)
        s = stepper
        fixed = s.fixed if getattr(s, "any_active", False) else None  # (no joint held: as no mask, without asking it)
        if s.start_measure is None:
            sigma, eig = self.watch.measure(s.pt.J, s.M, s.lu, fixed)
        else:  # the compiled start's exact measurement (Watch.measure's first is exact: no vector yet)
            sigma, eig = self.watch.keep_exact(free_columns(s.pt.J, fixed), *s.start_measure)
        self.watch.push(s.t, sigma, eig, fixed)
        self.speed2 = float(s.qdot @ s.qdot)

    def start_verdict(self) -> str | None:
        """``kinematic`` or ``fold`` where the corrected start is not a regular constrained minimum."""
        return self.watch.crossed(self.watch.sigma[-1], self.watch.eig[-1])

    # -- the state ------------------------------------------------------------------------------------
    def snapshot(self) -> tuple:
        """The stepper's whole state (:mod:`kinredund.tracking.state`) and the control's last speed."""
        return self.s.state, self.speed2

    def restore(self, snap: tuple) -> None:
        self.s.state, self.speed2 = snap

    # -- one step --------------------------------------------------------------------------------------
    def step(self) -> None:
        """One requested step from t to t0 + (k + 1) dt (see the module docstring)."""
        s = self.s
        t_to = s.t0 + (s.k + 1) * s.dt
        snap = self.snapshot()
        self._bounded = None  # (the first, the last stop of the bounded stepper in this step, the last's start)
        if self.watch.ahead(t_to) is None or self._refreshed_ahead(t_to) is None:
            reason = self._attempt(s.plain_step, snap, s.dt)
            if reason is None:
                return
            self.restore(snap)
        else:
            reason = (self.watch.ahead(t_to), "predicted within the step")
            self.restore(snap)
        self._substeps(snap, t_to, reason)

    def _attempt(self, advance, snap: tuple, h: float):
        """Run ``advance`` and check its point: None if accepted (and pushed to the watch), else (kind, why)."""
        s = self.s
        try:
            advance()
        except TrackingError as err:  # the limits' stop (a bounded stepper names its own): a shorter step may pass
            first = err if self._bounded is None else self._bounded[0]  # the whole step's, if it had one
            self._bounded = (first, err, snap[0].t, snap[0].q)
            return "bounded", str(err).split("; last good point")[0]
        except (PathError, SingularityError) as err:
            s.ev.check_sample(s.t)  # a non-finite path sample is the caller's input: its PathError propagates
            # the message without the diverged iterate, its joints and its R's and J's smallest singular values: those
            # follow the rounding of whichever backend (or BLAS run) took the iterate off the path, not the path (two
            # runs of one stop gave 3.7e-17 and 7.3e-16, J 0.037 and 0.15); the error reports the last good point's
            return "corrector", str(err).split("; q = ")[0].split(": smallest singular value")[0]
        speed2 = float(s.qdot @ s.qdot)
        if h == s.dt:  # a whole step: where the corrector ended next to the predictor's point, no jump
            m = s.q - s.q_pred
            if float(m @ m) <= (PREDICTED_TOL * h) ** 2 * max(self.speed2, speed2):
                return self.watch_point(h, speed2)
        jump = self._jump(snap, h)
        return ("jump", jump) if jump is not None else self.watch_point(h, speed2)

    def _jump(self, snap: tuple, h: float) -> str | None:
        """Why the (sub-)step of length h from ``snap`` to the current point is a jump (the trapezoidal check of
        the module docstring), or None."""
        s = self.s
        qd0, qd1 = snap[0].qdot, s.qdot
        dq = s.q - snap[0].q
        e = dq - (0.5 * h) * (qd0 + qd1)  # the trapezoidal rule's miss: h^3 |q'''| / 12 on a smooth step
        move2, miss2 = float(dq @ dq), float(e @ e)
        scale2 = max(move2, h * h * max(self.speed2, float(qd1 @ qd1)))
        if not miss2 <= TRAPEZOID_TOL**2 * scale2 + 1e-24:
            return (f"the joints moved {math.sqrt(move2):.3g} in {h:.3g} s, {math.sqrt(miss2):.3g} away from what the "
                    "rates at both ends give (trapezoidal rule)")
        return None

    def watch_point(self, h: float, speed2: float, core=None):
        """The watch's verdict on the new point (measured where due): None if accepted, else (kind, why).
        ``core``: the compiled core that took the step (its measurement: :meth:`Watch.measure`)."""
        s = self.s
        indefinite = self._indefinite()
        if not (self.watch.due(s.rcond) or h < s.dt or indefinite):
            self.speed2 = speed2
            return None
        if h < s.dt or indefinite:  # sub-steps (near trouble): exactly, at the corrected point (not the Euler's)
            pt = s.evaluate(s.q, s.t)
            sigma, eig = self.watch.measure_exact(pt.J, pt.system(s.lam)[0], getattr(s, "fixed", None))
        else:
            sigma, eig = self.watch.measure(s.pt.J, s.M, s.lu, getattr(s, "fixed", None), core)
        kind = self.watch.crossed(sigma, eig)
        if kind is not None:
            return kind, f"sigma_min(J) = {sigma:.3g}, reduced-Hessian eigenvalue {eig:.3g} at t = {s.t:.6g} s"
        self.watch.push(s.t, sigma, eig, getattr(s, "fixed", None), exact=h < s.dt or indefinite)
        self.speed2 = speed2
        return None

    def _indefinite(self) -> bool:
        """With general rows active (the Python stepper's steps and the compiled ones that hold the rows: both give
        R's factors): does the inertia of R (Eq. 4.24) say Z^T M Z has an odd number of negative eigenvalues
        (:func:`odd_inertia`)? The watch's gate (R's condition) sees a crossing only near it, and a step over one,
        where an active row's curvature grows with its multiplier or jumps, went unmeasured: the record held saddle
        points of the held problem."""
        s = self.s
        if not getattr(s, "rows", None) or s.lu is None:
            return False
        fixed = getattr(s, "fixed", None)
        return odd_inertia(*s.lu, s.n - (0 if fixed is None else int(np.count_nonzero(fixed))))

    def _refreshed_ahead(self, t_next: float) -> str | None:
        """The prediction again after an exact measurement at the current point (the gated history may be old)."""
        s = self.s
        if not self.watch.exact_at(s.t):  # a sub-step's point is measured exactly already: not again
            pt = s.evaluate(s.q, s.t)
            self.watch.refresh(s.t, pt.J, pt.system(s.lam)[0], getattr(s, "fixed", None))
        return self.watch.ahead(t_next)

    def _substeps(self, snap_step: tuple, t_to: float, reason) -> None:
        s = self.s
        s.prev.clear()  # the Hermite history does not fit sub-steps: Euler, as after a jump
        t, h, t_tried = snap_step[0].t, 0.5 * s.dt, t_to
        self._searched = None
        self._stuck = 0  # switches found in a row at one time (_moved)
        while t_to - t > 1e-12 * s.dt:
            if h < self.floor * (1.0 - 1e-9):
                raise self._exhausted(snap_step, t_to, reason, t_tried)
            t_next = t_tried = t_to if h >= (t_to - t) * (1.0 - 1e-9) else t + h
            kind = self.watch.ahead(t_next) and self._refreshed_ahead(t_next)
            if kind is not None:
                if self._switch_inside(t_next, snap_step) and self._moved(t, s.t):
                    t = s.t
                    continue
                reason, h = (kind, f"predicted before t = {t_next:.6g} s"), 0.5 * h
                continue
            snap = self.snapshot()
            why = self._attempt(lambda tn=t_next: s.euler_to(tn), snap, t_next - t)
            if why is not None:
                self.restore(snap)
                if why[0] in ("fold", "kinematic") and self._switch_inside(t_next, snap_step) and self._moved(t, s.t):
                    t = s.t
                    continue
                reason, h = why, 0.5 * h
                continue
            t, h = t_next, min(2.0 * h, s.dt)
        s.t, s.k = t_to, snap_step[0].k + 1
        s.prev.clear()  # the next step restarts the predictor from this point

    def _moved(self, t: float, t_switch: float) -> bool:
        """Carry the sub-steps on from a switch found at ``t_switch`` (from a sub-step start t)? Yes where it moved
        time forward; at t itself (two rows swapping at a corner, a reach at the start) up to
        :data:`MAX_SWITCHES_AT_ONCE` in a row, then the sub-step is halved as any rejected one (two active sets
        switching back and forth at one time never loop)."""
        self._stuck = 0 if t_switch > t else self._stuck + 1
        return self._stuck <= MAX_SWITCHES_AT_ONCE

    def _switch_inside(self, t_next: float, snap_step: tuple) -> bool:
        """Before a (sub-)step to ``t_next`` is rejected for the watch (a fold or singularity predicted or met for
        the current active set): does the stepper find a switch of the active set inside it, or inside the sub-steps
        of the requested step (from ``snap_step``) accepted before it (``switch_within`` of a stepper with limits or
        rows, :mod:`kinredund.tracking.switches`)? Where it does, the stepper is at the
        switching time with the new active set, and the watch's history starts afresh there (an exact
        measurement: the quantities jump at a switch). A step from one point searched without a switch up to a
        time is not searched again up to an earlier one (the search locates any switch before its end)."""
        s = self.s
        within = getattr(s, "switch_within", None)
        if within is None or (self._searched is not None and self._searched[0] == s.t and
                              t_next <= self._searched[1]):
            return False
        t = s.t
        found = within(t_next, snap_step[0])
        if not found:
            self._searched = None if found is None else (t, t_next)
            return False
        self.watch.reset()
        self._refreshed_ahead(t_next)
        self.speed2 = float(s.qdot @ s.qdot)
        return True

    # -- the stop ---------------------------------------------------------------------------------------
    def _exhausted(self, snap_step: tuple, t_to: float, reason, t_fail: float) -> TrackingError:
        """The error, the stepper put back at the last requested time (the last recorded, good point).

        ``t`` and ``q`` are that point's (the partial record ends there); ``watched`` holds its quantities
        and those of the nearest good sub-step point (``substep_t``, ``substep_q``, ``substep_sigma_min_J``,
        ``substep_reduced_hessian_min``), the time of the failed attempt (``t_failed``) and the reason.
        """
        s = self.s
        kind, why = reason
        if self._bounded is not None:  # the limits' stop met in this step: theirs, whatever failed last
            return self._bounded_stop(snap_step, t_fail)
        near = watched_at(s)
        t_near, q_near = s.t, s.q.copy()
        cause = {"fold": "fold", "jump": "fold"}.get(kind)
        if kind == "jump" and path_jumps(s.ev, t_near, t_fail):
            cause = "path_discontinuity"
        contradiction = "" if cause == "path_discontinuity" else path_contradiction(s.ev, t_near, t_fail)
        if contradiction:  # the path's own fault, before the arm's
            cause, why = "path_inconsistent", f"{contradiction} ({why})"
        extra = {}
        if cause is None:
            ahead = self._refreshed_ahead(t_near + s.dt)  # a crossing predicted within a whole step names it
            # R singular with J of full rank (Z^T M Z singular), unless sigma_min(J) is the one heading to zero
            if kind == "corrector" and (ahead == "fold" or (ahead is None and "algorithmic" in why)):
                cause = "fold"
                if ahead == "fold":  # the corrector's words say where its iterate went (off the ended branch)
                    why = (f"the corrector failed ({why}) with the reduced-Hessian eigenvalue predicted to reach zero "
                           f"at t = {self.watch.crossings()['fold']:.6g} s")
            else:
                # an open path is not sampled beyond the requested step
                probe = [t_to] if s.ev.path.period is None else [t_to, t_near + s.dt]
                far, res, at = out_of_reach(s.ev, q_near, probe)
                extra = {"reach_residual": res, "reach_checked_at": at}
                if far:
                    cause = "out_of_reach"
                elif kind == "kinematic" or ahead == "kinematic":
                    cause = "kinematic_singularity"
                elif kind == "corrector":
                    cause, why, branch = branch_end(self, t_fail, near, why)
                    extra.update(branch)
                else:
                    cause = "step_control_exhausted"
        s_task = constraints_dependent(s, q_near, t_near) if cause == "kinematic_singularity" else None
        if s_task is not None:  # J of the free joints, or with the active rows below, loses rank; J does not (LICQ)
            cause, why = "not_strongly_stable", (f"{why}: the constraints become dependent (LICQ fails: the watched "
                                                 f"Jacobian, J's free columns with the active rows' gradients below, "
                                                 f"loses rank while J's own smallest singular value is {s_task:.3g})")
        rows = bool(getattr(s, "rows", None))  # the watched Jacobian has the active rows' gradients below J
        self.restore(snap_step)
        s.prev.clear()
        watched = watched_at(s)
        own = getattr(s, "_watched", None)  # a subclass's own quantities (the limits': active set, multipliers)
        if own is not None:
            watched.update(own())
        watched.update(extra, t_failed=float(t_fail), min_substep=self.floor, reason=why, substep_t=float(t_near),
                       substep_q=q_near.tolist(), substep_sigma_min_J=near.get("sigma_min_J"),
                       substep_reduced_hessian_min=near.get("reduced_hessian_min"))
        return TrackingError(
            f"tracking stopped after t = {s.t:.6g} s ({cause}): {why}; no sub-step down to {self.floor:.3g} s "
            f"gets past it (nearest good point at t = {t_near:.6g} s: sigma_min({'[J; G_A]' if rows else 'J'}) "
            f"{near.get('sigma_min_J', float('nan')):.3g}, reduced-Hessian eigenvalue "
            f"{near.get('reduced_hessian_min', float('nan')):.3g})",
            cause=cause, t=s.t, q=s.q.copy(), watched=watched)

    def _bounded_stop(self, snap_step: tuple, t_fail: float) -> TrackingError:
        """The bounded stepper's own stop (the limits' cause), where no sub-step down to the floor gets past it: the
        first one of the step (the whole step's), the stepper put back at the last requested time, where the
        stepper's step says it (its last good point, its watched quantities). Where sub-steps got further, the
        start of the last failed one is ``substep_t`` and ``substep_q`` of ``watched``, why it failed
        ``substep_reason``."""
        s = self.s
        err, last, t_sub, q_sub = self._bounded
        self.restore(snap_step)
        s.prev.clear()
        extra = {"t_failed": float(t_fail), "min_substep": self.floor}
        if t_sub != s.t:
            extra.update(substep_t=float(t_sub), substep_q=np.asarray(q_sub, float).tolist(),
                         substep_reason=str(last).split("; last good point")[0])
        err.watched = dict(err.watched or {}) | extra
        return err


def odd_inertia(lu: np.ndarray, piv: np.ndarray, free: int) -> bool:
    """Does R = [[M, A^T], [A, 0]] on ``free`` joints, A of full row rank r (the task's rows and the active rows'),
    from its LU factors ``lu`` and 0-based pivots ``piv`` (LAPACK's getrf), have a reduced Hessian Z^T M Z with an
    odd number of negative eigenvalues? det R = (-1)^r det(Z^T M Z) times a positive number, so sign(det R) is
    (-1)^r exactly where that count is even (zero where it is positive definite; one eigenvalue crossing flips it).
    Free: the signs of U's diagonal and the pivots' swaps (:meth:`StepControl._indefinite`; the compiled step's
    held rows, :mod:`kinredund.tracking.compiled`)."""
    flips = int(np.count_nonzero(np.diag(lu) < 0.0)) + int(np.count_nonzero(piv != np.arange(len(piv))))
    return (flips - (lu.shape[0] - free)) % 2 == 1
