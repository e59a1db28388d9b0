"""The baselines, through the same interface as the optimal schemes (Chapter 4's comparisons).

- :class:`Pseudoinverse`: thetadot = J^+ xdot (Whitney 1972), the minimum-norm rates;
- :class:`Liegeois`: thetadot = J^+ xdot - k (1 - J^+ J) grad z, gradient projection (Liegeois 1977).

Thesis mode: Euler steps with the velocity correction of Eq. (4.29), lambda by least squares at every
step (Liegeois). Default mode: Euler steps followed by a minimum-norm Newton projection onto the task.
Neither follows the constrained optimum, so neither closes the joint path.
"""

from __future__ import annotations

import math

import numpy as np

from kinredund.errors import PathError
from kinredund.tracking.explicit import ExplicitStepper
from kinredund.tracking.linalg import multipliers
from kinredund.tracking.point import Point


class Pseudoinverse(ExplicitStepper):
    """The minimum-norm rates J^+ xdot (Whitney 1972); ``project``: the default mode's task projection."""

    def __init__(self, evaluator, q0, dt, *, project: bool, **kwargs):
        self.project = project
        super().__init__(evaluator, q0, dt, **kwargs)
        self._rates(None)

    def evaluate(self, q: np.ndarray, t: float, need_dJ: bool = False) -> Point:
        return self.ev.point(q, t, need_dJ=False)  # no Lambda: dK is not needed

    def direction(self, pt: Point, Jp: np.ndarray, xdot: np.ndarray) -> np.ndarray:
        """The joint rates from the pseudoinverse Jp of J and the task rate xdot."""
        with np.errstate(invalid="ignore", over="ignore"):  # a non-finite xdot: reported by the caller
            return Jp @ xdot

    def _rates(self, pt: Point | None) -> None:
        if pt is None:
            pt = self.evaluate(self.q, self.t)
        self.pt = pt
        xdot = pt.xdot
        if not self.project:
            xdot = xdot - pt.r / self.dt  # velocity correction, Eq. (4.29)
            if self.ev.index is not None:
                self.lam = multipliers(pt.J, pt.grad)[0]  # Eqs. (4.11)-(4.12)
        self.qdot = self.direction(pt, np.linalg.pinv(pt.J), xdot)
        self.lamdot, self.label, self.M = np.zeros_like(self.lam), "lstsq", None

    def advance(self) -> None:
        q = self.q
        t_next = self._next_time()
        self.q = q + self.dt * self.qdot
        self.t = t_next
        pt = self._project_task() if self.project else None
        self._check_finite(q)
        self._rates(pt)
        self._check_finite(q)
        self._check_tracked(self.pt)

    def _project_task(self, max_iter: int = 20) -> Point:
        """Minimum-norm Newton projection onto the task at self.t (default-mode baselines); the final point."""
        for _ in range(max_iter):
            pt = self.evaluate(self.q, self.t)
            err = float(np.abs(pt.r).max())
            if err <= self.tol * max(1.0, float(np.abs(pt.sample.p).max())):
                return pt
            if not math.isfinite(err):
                self.ev.check_sample(self.t)
                raise PathError(f"non-finite task residual at t = {self.t:.6g} s", t=self.t, q=self.q)
            self.q = self.q - np.linalg.lstsq(pt.J, pt.r, rcond=None)[0]
        raise PathError(f"the task projection did not converge at t = {self.t:.6g} s", t=self.t, q=self.q)


class Liegeois(Pseudoinverse):
    """Gradient projection (Liegeois 1977): J^+ xdot - k (1 - J^+ J) grad z, gain k [1/s]."""

    def __init__(self, evaluator, q0, dt, *, gain: float, **kwargs):
        self.gain = gain
        super().__init__(evaluator, q0, dt, **kwargs)

    def direction(self, pt, Jp, xdot):
        qd = super().direction(pt, Jp, xdot)
        qd -= self.gain * (pt.grad - Jp @ (pt.J @ pt.grad))  # gradient projection (Liegeois 1977)
        return qd
