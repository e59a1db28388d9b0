"""Switches of the active set within a step, located and stepped to exactly (a part of the constrained stepper).

After each step the stepper (:class:`~kinredund.tracking.limited.LimitedPredictorCorrector`) looks for a switch
within it: a free joint beyond its bound or a multiplier below zero (:mod:`kinredund.tracking.limited`), an
inactive general row below zero or an active row's multiplier below zero (:mod:`kinredund.tracking.rows`), or a
row that dips below zero inside the step and comes back (``GeneralRows._row_dips``). It solves for the
switching time on the corrected path (Brent's method on the joint's margin, the row's value or the multiplier,
each evaluation a corrector solve at that time; on the compiled backend the search is the core's, the stepper's
``corrector.locate``, and so are the solves, ``corrector``), steps to it, changes the active set there and steps
on to the end of the step. After a switch strict complementarity is checked: a reached bound's multiplier grows, a
released joint moves inward; where the LU route cannot tell (a rate ~0) the rate QP decides which set continues.
The step's end is then measured exactly (the step control watched the step with the active set it started with):
where it is no strict minimum of the problem with the new active set, the path is followed again from the switch in
checked pieces, and where none reaches the end the run stops at the step's start.
"""

from __future__ import annotations

import operator

import numpy as np

from kinredund.errors import KinredundError, PathError, SingularityError
from kinredund.tracking.failure import constraints_dependent, on_branch
from kinredund.tracking.linalg import bound_rate_qp
from kinredund.tracking.roots import SWITCH_RTOL, SWITCH_XTOL, brent_root
from kinredund.tracking.rows import ROW_TOL
from kinredund.tracking.state import ConstrainedState
from kinredund.tracking.step_control import MAX_HALVINGS

#: the most switches resolved within one step (more means chattering: the optimum is not strongly stable)
MAX_SWITCHES_PER_STEP = 8
#: where inside a step (fractions of it) a row that may dip below zero is sampled (``_row_dips``)
DIP_SAMPLES = (0.25, 0.5, 0.75)


def _hermite(s: float) -> np.ndarray:
    """The cubic Hermite basis at s in [0, 1]: weights of (y0, h y0', y1, h y1')."""
    return np.array([2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2])


_DIP_AT = np.linspace(0.0, 1.0, 65)
#: the quartic through a row's values at s = 0, DIP_SAMPLES, 1, evaluated at _DIP_AT
_DIP_FIT = np.vander(_DIP_AT, 5) @ np.linalg.inv(np.vander(np.array([0.0, *DIP_SAMPLES, 1.0]), 5))


def segment_move(q0: np.ndarray, q1: np.ndarray, v0: np.ndarray, v1: np.ndarray, h: float) -> np.ndarray:
    """Per joint, a bound of |q(tau) - q0| and |q(tau) - q1| along a step of h [s] from (q0, v0) to (q1, v1) on
    the cubic Hermite of the joints: max(|dq|, h max(|qdot_0|, |qdot_1|)) + h |qdot_1 - qdot_0| / 4 [rad or m]
    (the compiled row checks compute the same: ``segment_move`` in src/core/rows.hpp)."""
    return np.maximum(np.abs(q1 - q0), h * np.maximum(np.abs(v0), np.abs(v1))) + 0.25 * h * np.abs(v1 - v0)


class SwitchLocation:
    """The switch location of :class:`~kinredund.tracking.limited.LimitedPredictorCorrector` (a mixin: it uses the
    stepper's state, ``euler_to``, ``_newton``, ``_rates`` and the rows' hooks of
    :class:`~kinredund.tracking.rows.GeneralRows`)."""

    def _events(self, reach: bool = True) -> list[tuple[int, str]]:
        """The switches the state at t shows: (joint, ``lower``/``upper``) reached, or (joint, ``release``);
        (row, ``row_reach``/``row_release``) of the general rows (``reach`` False: their releases only)."""
        q = self.q
        if self._sel is None:  # no joint on a bound: every joint within its switch limits (the common case)
            lo, hi = self._switch_floats  # (as lists of floats: a numpy call costs more on a few entries)
            x = q.tolist()
            if all(map(operator.le, lo, x)) and all(map(operator.le, x, hi)):
                return self._row_events(reach)
        free = ~self.fixed
        scale = max(1.0, float(np.abs(self.pt.grad).max()))
        out = [(int(i), "lower") for i in np.flatnonzero(free & (q < self._lo_tol))]
        out += [(int(i), "upper") for i in np.flatnonzero(free & (q > self._hi_tol))]
        out += [(int(i), "release") for i in np.flatnonzero(self.fixed & (self.mu < -1e-12 * scale))]
        return out + self._row_events(reach)

    def _watch(self, joint: int, kind: str) -> float:
        """The quantity whose zero is the switch: the margin to the bound, or the multiplier (>= 0 before)."""
        if kind == "lower":
            return float(self.q[joint] - self.lo[joint])
        if kind == "upper":
            return float(self.hi[joint] - self.q[joint])
        if kind == "release":
            return float(self.mu[joint])
        return self._row_watch(joint, kind)

    def _corrected_to(self, tau: float, reach: float = np.inf, anchors: list | None = None) -> float:
        """From the current state to the corrected path at ``tau`` (within the step): one Euler prediction and
        the corrector, or where the corrector fails from that prediction, the same in 2, 4, ... equal pieces
        down to the step control's floor (dt / 2**MAX_HALVINGS). Pieces start no longer than ``reach`` [s];
        returns the longest that worked, and appends the states between the pieces to ``anchors`` (for the
        next call of the same search, which starts from the latest anchor before its time).

        One prediction from the step's start reaches any time within a smooth step; where the optimum moves
        fast (rates of tens of rad/s just before a bound, the joints 0.4 rad apart across the step) a
        prediction far into the step diverges while the step itself was accepted (its Hermite predictor, or
        its sub-steps): the pieces follow the path as the sub-steps do.
        """
        start = self.state
        span = tau - start.t
        if not span > 0.0:
            return reach
        pieces = 1 if span <= reach else 2 ** int(np.ceil(np.log2(span / reach)))
        kept = None if anchors is None else len(anchors)
        while True:
            try:
                for k in range(1, pieces):
                    self.euler_to(start.t + span * k / pieces)
                    if anchors is not None:
                        anchors.append(self.state)
                self.euler_to(tau)
                return span / pieces if pieces > 1 else reach
            except (PathError, SingularityError):
                if anchors is not None:
                    del anchors[kept:]
                if span / pieces <= self.dt / 2**MAX_HALVINGS:
                    raise
                self.state, pieces = start, 2 * pieces

    def _crossing(self, snap: ConstrainedState, t_end: float, joint: int, kind: str) -> float:
        """The time in (snap t, t_end] where the watched quantity of (joint, kind) reaches zero (Brent)."""
        reach, anchors = [np.inf], [snap]  # what this search learnt of the path within the step (_corrected_to)

        def phi(tau):
            self.state = max((a for a in anchors if a.t <= tau), key=lambda a: a.t)
            reach[0] = self._corrected_to(tau, reach[0], anchors)
            return self._watch(joint, kind)

        t_start = snap.t
        f = phi(t_start)
        if f <= 0.0:
            # zero at the start to rounding (switched there: a row's multiplier from 0, a joint leaving its
            # bound) and below zero at t_end: it went up and came back within the step (a short contact)
            inside = self._positive_inside(phi, t_start, t_end) if f >= -self._zero_of(kind) else None
            if inside is None:
                return t_start
            t_start, f = inside, np.nan
        f_end = phi(t_end) if kind == "row_reach" else np.nan
        if f_end > 0.0:  # below zero at the end as another row (GeneralRows._row_watch)
            below = self._under_inside(phi, t_start, t_end)
            if below is None:
                return np.inf  # not an event of its own
            t_end, f_end = below, np.nan
        locate = getattr(self.corrector, "locate", None)  # the core's search (CoreCorrector.locate), where only the
        if locate is not None and f == f and len(anchors) == 1 and reach[0] == np.inf:  # step's start is known
            tau = locate(snap, t_start, t_end, f, f_end, joint, kind)
            if tau is not None:
                return tau
        try:
            return brent_root(phi, t_start, t_end, SWITCH_XTOL, SWITCH_RTOL)
        except (ValueError, RuntimeError, KinredundError) as err:
            self.state = snap
            raise self._failure("switch_not_resolved", f"the switch of {self._event_name(joint, kind)} "
                                f"({kind}) within ({t_start:.6g}, {t_end:.6g}] s could not be located: {err}") from err

    def _row_dips(self, snap: ConstrainedState) -> list[tuple[int, float]]:
        """(row, tau) of each general row inactive at both ends of the step from ``snap`` to now, >= 0 at both,
        that dips below zero inside it: c < -ROW_TOL at time tau on the corrected path.

        A row is looked at where its constraint's lower bound along the step
        (:meth:`~kinredund.tracking.constraints.base.Constraint.segment_lower_bounds`, for the joints' motion
        max(|dq|, h max(|qdot_0|, |qdot_1|)) + h |qdot_1 - qdot_0| / 4) is below zero, or unknown: its values at
        the points of :data:`DIP_SAMPLES` on the cubic Hermite of the joints through the ends and their rates,
        with the ends', give a quartic in time; where its least value on the step is below -ROW_TOL, the path
        is corrected at that time (an Euler prediction from the start and the corrector) and the row's value
        there decides. A dip narrower than the samples resolve (a quartic through five points) is missed.
        """
        h = self.t - snap.t
        if not self.row_pairs or snap.qdot is None or not h > 0.0:
            return []
        q0, q1, v0, v1 = snap.q, self.q, snap.qdot, self.qdot
        c1, c0 = self._row_values(q1), self._row_values(q0)  # c0: the last step's end, kept
        move = segment_move(q0, q1, v0, v1, h)
        bound = self._segment_bounds(q0, q1, c0, c1, move)
        if not bound.min() < -ROW_TOL:  # the common case: no row can dip (one reduction)
            return []
        maybe = bound < -ROW_TOL
        maybe[list(set(self.rows) | set(snap.rows))] = False
        maybe &= (c0 >= -ROW_TOL) & (c1 >= -ROW_TOL)
        if not maybe.any():
            return []
        ends = np.array([q0, h * v0, q1, h * v1])
        C = np.vstack([c0, *[self._values_at(_hermite(s) @ ends) for s in DIP_SAMPLES], c1])[:, maybe]
        fit = _DIP_FIT @ C
        low = fit.min(axis=0) < -ROW_TOL
        if not low.any():
            return []
        state_end, out = self.state, []
        for row, at in zip(np.flatnonzero(maybe)[low].tolist(), fit.argmin(axis=0)[low].tolist(), strict=True):
            tau = snap.t + float(_DIP_AT[at]) * h
            self.state = snap
            self._corrected_to(tau)
            if self._values_at(self.q)[row] < -ROW_TOL:
                out.append((row, tau))
        self.state = state_end
        return out

    def _zero_of(self, kind: str) -> float:
        """The rounding of a watched quantity that is zero by construction where it was switched: a
        multiplier's (the corrector's tolerance on grad z), a row's (ROW_TOL), a joint's margin (exact)."""
        if kind in ("release", "row_release"):
            return 1e-12 * max(1.0, float(np.abs(self.pt.grad).max()))
        return ROW_TOL if kind == "row_reach" else 0.0

    @staticmethod
    def _under_inside(phi, t_start: float, t_end: float) -> float | None:
        """The first time inside (t_start, t_end) where phi < 0, from 7 evenly spaced ones and then 12 halvings of
        the distance to t_end (a row under the one it equals at t_end is so just before it), or None."""
        taus = [t_start + (t_end - t_start) * k / 8 for k in range(1, 8)]
        taus += [t_end - (t_end - t_start) * 0.5 ** k for k in range(4, 16)]
        for tau in taus:
            if phi(tau) < 0.0:
                return tau
        return None

    @staticmethod
    def _positive_inside(phi, t_start: float, t_end: float, samples: int = 8) -> float | None:
        """The first of ``samples - 1`` evenly spaced times inside (t_start, t_end) where phi > 0, or None."""
        taus = (t_start + (t_end - t_start) * k / samples for k in range(1, samples))
        return next((tau for tau in taus if phi(tau) > 0.0), None)

    def pending_switches(self, snap: ConstrainedState) -> tuple[list, list]:
        """(events, dips): the switches the step from ``snap`` to now holds, as the step looks for them after it
        is taken: the events at its end (:meth:`_events`), then the general rows that dip below zero inside it
        only (:meth:`_row_dips`); neither of a row where the rows' compiled check rules it out (``_rows_cleared``).
        Both empty: the step holds no switch. The compiled driver asks this of a step taken in C++."""
        if self._rows_cleared(snap):
            return self._events(reach=False), []
        return self._events(), self._row_dips(snap)

    def _first_switch(self, snap: ConstrainedState) -> tuple[float, int, str] | None:
        """(tau, joint or row, kind) of the earliest switch within the step from ``snap`` to now (the state at its
        end, kept), or None where the step holds none (:meth:`pending_switches`, each located by :meth:`_crossing`)."""
        events, dips = self.pending_switches(snap)
        if not (events or dips):
            return None
        state_end, t_end = self.state, self.t
        times = [(self._crossing(snap, t_end, j, kind), j, kind) for j, kind in events]
        times += [(self._crossing(snap, tau, j, "row_reach"), j, "row_reach") for j, tau in dips]
        hidden = [(j, kind) for t, j, kind in times if not np.isfinite(t)]
        times = [x for x in times if np.isfinite(x[0])]
        if times and hidden:  # under zero only as another row at the end: on its own before the first switch?
            first = min(times)[0]
            times += [(self._crossing(snap, first, j, kind), j, kind) for j, kind in hidden]
        self.state = state_end
        return min(times) if times else None

    def switch_within(self, t_next: float, since: ConstrainedState) -> bool | None:
        """A switch inside a (sub-)step the step control rejects for the watch (a fold or a singularity predicted,
        or met, for the current active set), located before that is declared: the step from the current state to
        ``t_next`` is taken anyway (an Euler prediction and the corrector) and the whole of the requested step
        so far, from ``since`` (its start: the sub-steps accepted within it are not searched until it ends) or
        from the last switch located within it, is searched as an accepted step is (:meth:`_first_switch`).

        Where it holds a switch, the stepper is left at the (first) switching time with the active set changed
        there (:meth:`_switch`: the predicted fold may be the old set's only), ``switch_anchor`` is that
        state (the search of the rest of the step starts there,
        :meth:`~kinredund.tracking.limited.LimitedPredictorCorrector.step`) and True is returned; else the state
        is put back and False returned (the step holds no switch) or None (the step or the search failed: a
        shorter one may not)."""
        snap = self.state
        since = since if self.switch_anchor is None else self.switch_anchor
        try:
            self.euler_to(t_next)
            first = self._first_switch(since)
            if first is not None:
                self.state = since
                self._corrected_to(first[0])
                self._switch(*first[1:])
        except KinredundError:  # the step's or the search's failure: the step control's rejection stands
            self.state = snap
            return None
        if first is None:
            self.state = snap
            return False
        self.switch_anchor = self.state
        return True

    def _resolve_switches(self, snap: ConstrainedState) -> None:
        t_end, k_end = self.t, self.k  # the saved states before it keep the step's start count
        followed = False
        for n_switches in range(MAX_SWITCHES_PER_STEP):
            first = self._first_switch(snap)
            if first is None:
                if n_switches and not self._settled(snap, t_end, followed):
                    followed = True  # followed again from the last switch in checked pieces: its switches afresh
                    self.t, self.k = t_end, k_end
                    continue
                return
            tau, joint, kind = first
            self.state = snap
            self._corrected_to(tau)
            self._switch(joint, kind)
            snap = self.state
            self._corrected_to(t_end)
            self.t, self.k = t_end, k_end
        raise self._failure("not_strongly_stable", f"more than {MAX_SWITCHES_PER_STEP} switches of the active set "
                            f"within one step before t = {t_end:.6g} s (chattering)")

    def _strict_minimum(self) -> tuple[str | None, float, float]:
        """(what the watch's floors say at the current point measured exactly: None for a strict minimum with J
        regular, else ``fold`` or ``kinematic``; sigma_min of J with the active rows; the reduced-Hessian eigenvalue).
        """
        J, M, _ = self.system_at(self.q, self.t, self.lam)
        sigma, eig = self.control.watch.measure_exact(J, M, self.fixed)
        return self.control.watch.crossed(sigma, eig), sigma, eig

    def _settled(self, after: ConstrainedState, t_end: float, followed: bool) -> bool:
        """Is the step's end, reached from the state ``after`` its last switch, a strict minimum (measured exactly)?
        The step control watched the step with the active set it started with, and the quantities jump at a switch
        (the null space changes; a row's curvature enters with its multiplier); a single prediction from the switch
        (a kink of the path of optima) to the step's end may also land on another branch. Where it is not, the path
        is followed again from ``after`` in 2, 4, ... checked pieces (:meth:`_followed_to`): False then (the caller
        looks for switches afresh). Where that fails down to the floor, or the end was followed so already, the run
        stops: ``fold`` (a saddle, the reduced Hessian indefinite), or where the watched Jacobian loses rank
        ``not_strongly_stable`` with J itself regular, else ``kinematic_singularity``; the last good point is the
        step's start. True: the watch's history starts afresh from this measurement."""
        ctl = self.control
        if ctl is None or self.ev.index is None:
            return True
        kind, sigma, eig = self._strict_minimum()
        if kind is None:
            ctl.watch.reset()
            ctl.watch.push(self.t, sigma, eig, self.fixed, exact=True)
            ctl.speed2 = float(self.qdot @ self.qdot)
            return True
        if not followed and self._followed_to(after, t_end):
            return False
        dependent = kind == "kinematic" and constraints_dependent(self, self.q, self.t) is not None
        cause = "fold" if kind == "fold" else "not_strongly_stable" if dependent else "kinematic_singularity"
        raise self._failure(cause, f"after the switch of the active set at t = {after.t:.9g} s no strict minimum is "
                            f"followed to t = {t_end:.6g} s (at its end: reduced-Hessian eigenvalue {eig:.3g}, "
                            f"sigma_min of J with the active rows {sigma:.3g})")

    def _followed_to(self, start: ConstrainedState, t_end: float) -> bool:
        """From ``start`` to ``t_end`` in 2, 4, ... pieces down to the step control's floor, each checked: no jump onto
        another branch (:func:`~kinredund.tracking.failure.on_branch`) and a strict minimum at its end
        (:meth:`_strict_minimum`). True with the state at ``t_end``; False with the state back at ``start``."""
        span, pieces = t_end - start.t, 2
        while span / pieces >= self.dt / 2**MAX_HALVINGS * (1.0 - 1e-9):
            self.state = start
            try:
                for k in range(1, pieces + 1):
                    prev = self.state
                    self.euler_to(t_end if k == pieces else start.t + span * k / pieces)
                    if not on_branch(prev, self) or self._strict_minimum()[0] is not None:
                        break
                else:
                    return True
            except (PathError, SingularityError):
                pass
            pieces *= 2
        self.state = start
        return False

    def _apply_switch(self, joint: int, kind: str) -> float:
        """Change the active set: fix a joint on its bound, free it, or a row (``GeneralRows._apply_row_switch``)."""
        if kind in ("row_reach", "row_release"):
            return self._apply_row_switch(joint, kind)
        if kind == "release":
            side = self.side[joint]
            self._free(joint)
        else:
            side = 1.0 if kind == "lower" else -1.0
            self.q = self.q.copy()
            self.q[joint] = self.lo[joint] if side > 0 else self.hi[joint]
            self._fix(joint, side)
        return side

    def _switch(self, joint: int, kind: str) -> None:
        """Change the active set at the current time (a switching time) and correct onto it."""
        side = self._apply_switch(joint, kind)
        what = "release" if kind in ("release", "row_release") else "reach"
        if kind.startswith("row"):
            entry = {"row": joint, "name": self.row_names((joint,))[0], "constraint": True}
        else:
            entry = {"joint": joint, "name": self.joint_names[joint], "bound": "lower" if side > 0 else "upper"}
        self.switches += ({"t": float(self.t), **entry, "kind": what, "q": self.q.tolist()},)
        self.prev.clear()  # the optimal path has a kink here: the predictor starts afresh
        self._newton_rates()
        self._check_direction(joint, kind, side)

    def _check_direction(self, joint: int, kind: str, side: float) -> None:
        """Strict complementarity after the switch: a reached bound's multiplier grows, a released joint
        moves inward. Where the LU route cannot tell (a rate ~0), the rate QP decides."""
        if kind.startswith("row"):
            self._check_row_direction(joint, kind)
            return
        if kind == "release":
            rate = side * float(self.qdot[joint])  # inward: > 0
        else:
            rate = float(self._mu_rates()[joint])  # the multiplier grows: > 0
        if rate > 0.0:
            return
        stay = self._qp_keeps_bound(joint, side)
        if stay == bool(self.fixed[joint]):
            return
        if stay:
            self.q = self.q.copy()
            self.q[joint] = self.lo[joint] if side > 0 else self.hi[joint]
            self._fix(joint, side)
        else:
            self._free(joint)
        self._newton_rates()

    def _qp_keeps_bound(self, joint: int, side: float) -> bool:
        """The rate QP at a weakly active bound (:func:`~kinredund.tracking.linalg.bound_rate_qp`) over the
        free joints and ``joint``: True where the bound stays active (its rate 0, its multiplier > 0)."""
        pt = self.evaluate(self.q, self.t)
        M, top = pt.system(self.lam)
        keep = np.flatnonzero(~self.fixed | (np.arange(self.n) == joint))
        out = bound_rate_qp(M[np.ix_(keep, keep)], top[keep], pt.J[:, keep], pt.xdot,
                            int(np.flatnonzero(keep == joint)[0]), side)
        name = self.joint_names[joint]
        if out is None:
            raise self._failure("not_strongly_stable", f"the rate QP at the switch of joint {name} "
                                f"(t = {self.t:.6g} s) has no solution")
        rate, mult = out
        if abs(rate) <= 1e-12 and abs(mult) <= 1e-12:
            raise self._failure("not_strongly_stable", f"joint {name} is weakly active at t = {self.t:.6g} s "
                                "(rate and multiplier both zero): the active set is not determined")
        return rate <= 1e-12
