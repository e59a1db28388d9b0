"""Switches of the active set within a step, located and stepped to exactly (a part of the constrained stepper).

After each step the stepper (:class:`~kinredund.tracking.limited.LimitedPredictorCorrector`) looks for a switch
within it: a free joint beyond its bound or a multiplier below zero (:mod:`kinredund.tracking.limited`), an
inactive general row below zero or an active row's multiplier below zero (:mod:`kinredund.tracking.rows`), or a
row that dips below zero inside the step and comes back (:meth:`GeneralRows._row_dips`). It solves for the
switching time on the corrected path (Brent's method on the joint's margin, the row's value or the multiplier,
each evaluation a corrector solve at that time), steps to it, changes the active set there and steps on to the
end of the step. After a switch strict complementarity is checked: a reached bound's multiplier grows, a
released joint moves inward; where the LU route cannot tell (a rate ~0) the rate QP decides which set continues.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import brentq

from kinredund.errors import KinredundError
from kinredund.tracking.linalg import bound_rate_qp
from kinredund.tracking.state import ConstrainedState

#: the switching time is solved to this accuracy [s] (Brent's method): far below the 1e-9 s asked for
SWITCH_XTOL = 1e-14
#: the most switches resolved within one step (more means chattering: the optimum is not strongly stable)
MAX_SWITCHES_PER_STEP = 8


class SwitchLocation:
    """The switch location of :class:`~kinredund.tracking.limited.LimitedPredictorCorrector` (a mixin: it uses the
    stepper's state, ``euler_to``, ``_newton``, ``_rates`` and the rows' hooks of
    :class:`~kinredund.tracking.rows.GeneralRows`)."""

    def _events(self) -> list[tuple[int, str]]:
        """The switches the state at t shows: (joint, ``lower``/``upper``) reached, or (joint, ``release``);
        (row, ``row_reach``/``row_release``) of the general rows."""
        q = self.q
        if self._sel is None:  # no joint on a bound: one comparison per side (the common case)
            if not ((q < self._lo_tol).any() or (q > self._hi_tol).any()):
                return self._row_events()
        free = ~self.fixed
        scale = max(1.0, float(np.abs(self.pt.grad).max()))
        out = [(int(i), "lower") for i in np.flatnonzero(free & (q < self._lo_tol))]
        out += [(int(i), "upper") for i in np.flatnonzero(free & (q > self._hi_tol))]
        out += [(int(i), "release") for i in np.flatnonzero(self.fixed & (self.mu < -1e-12 * scale))]
        return out + self._row_events()

    def _watch(self, joint: int, kind: str) -> float:
        """The quantity whose zero is the switch: the margin to the bound, or the multiplier (>= 0 before)."""
        if kind == "lower":
            return float(self.q[joint] - self.lo[joint])
        if kind == "upper":
            return float(self.hi[joint] - self.q[joint])
        if kind == "release":
            return float(self.mu[joint])
        return self._row_watch(joint, kind)

    def _crossing(self, snap: ConstrainedState, t_end: float, joint: int, kind: str) -> float:
        """The time in (snap t, t_end] where the watched quantity of (joint, kind) reaches zero (Brent)."""
        def phi(tau):
            self.state = snap
            if tau > snap.t:
                self.euler_to(tau)
            return self._watch(joint, kind)

        t_start = snap.t
        if phi(t_start) <= 0.0:
            return t_start
        try:
            return float(brentq(phi, t_start, t_end, xtol=SWITCH_XTOL, rtol=4 * np.finfo(float).eps, maxiter=100))
        except (ValueError, RuntimeError, KinredundError) as err:
            self.state = snap
            raise self._failure("switch_not_resolved", f"the switch of {self._event_name(joint, kind)} "
                                f"({kind}) within ({t_start:.6g}, {t_end:.6g}] s could not be located: {err}") from err

    def _resolve_switches(self, snap: ConstrainedState) -> None:
        t_end, k_end = self.t, self.k  # the saved states before it keep the step's start count
        for _ in range(MAX_SWITCHES_PER_STEP):
            events = self._events()
            if not events:
                return
            state_end = self.state
            times = [(self._crossing(snap, t_end, j, kind), j, kind) for j, kind in events]
            self.state = state_end
            tau, joint, kind = min(times)
            self.state = snap
            if tau > snap.t:
                self.euler_to(tau)
            self._switch(joint, kind)
            snap = self.state
            if t_end > tau:
                self.euler_to(t_end)
            self.t, self.k = t_end, k_end
        raise self._failure("not_strongly_stable", f"more than {MAX_SWITCHES_PER_STEP} switches of the active set "
                            f"within one step before t = {t_end:.6g} s (chattering)")

    def _apply_switch(self, joint: int, kind: str) -> float:
        """Change the active set: fix a joint on its bound, free it, or a row (:meth:`_apply_row_switch`)."""
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
        self._newton()
        self._rates()
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
        self._newton()
        self._rates()

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
