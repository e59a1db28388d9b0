"""Thesis mode: explicit Euler steps with the velocity correction of Eq. (4.29) (Chapter 4, as run there).

theta_{k+1} = theta_k + dt thetadot_k, where thetadot_k solves Eq. (4.24) (or Eq. 4.36 in the velocity
form) at (theta_k, t_k) with xdot replaced by xdot - r / dt (Eq. 4.29), and lambda from Householder least
squares at every step (Eqs. 4.11-4.12). The linear solver follows the thesis's rule by default: the QP of
Theorem 2 (Eq. 4.28) with proxsuite where M is positive definite, else LU of R. What the thesis ran, at
200 steps per loop; its errors are of order 1e-4 and the joints drift a little every loop.

Thesis mode with joint limits is refused (:class:`~kinredund.tracking.tracker.Tracker` says so): the
explicit scheme has no corrector to hold the bounds and the first-order conditions with them.
"""

from __future__ import annotations

import numpy as np

from kinredund.errors import PathError, SingularityError, TrackingError
from kinredund.tracking.failure import explicit_failure
from kinredund.tracking.linalg import multipliers
from kinredund.tracking.point import Point
from kinredund.tracking.stepper import Stepper

#: the largest distance from the path an explicit step may leave, as a fraction of the path's scale
#: (max(1, |p|) [m]): Examples 4.1-4.3 stay below 1e-3 of it at 200 steps per loop; a coarser step
#: that leaves the path by more is an error, however large the velocity correction (4.29) asks for
ON_PATH_ALLOWANCE = 1e-2


class ExplicitStepper(Stepper):
    """The checks after an explicit step (thesis mode and the thesis-mode baselines)."""

    def _check_tracked(self, pt: Point) -> None:
        """The step's point is finite, within :data:`ON_PATH_ALLOWANCE` of the path and regular."""
        scale = max(1.0, float(np.abs(pt.sample.p).max()))
        self._check_on_path(pt, "the tracked configuration", limit=ON_PATH_ALLOWANCE * scale)
        self._check_rank(pt)

    def step(self) -> None:
        """One explicit step (the subclass's ``advance``); a tracking failure is a TrackingError at the step's start."""
        q, t, k = self.q, self.t, self.k
        try:
            self.advance()
        except TrackingError:
            raise
        except (PathError, SingularityError) as err:
            self.ev.check_sample(self.t)  # a non-finite path sample is the caller's input: its PathError propagates
            self.q, self.t, self.k = q, t, k
            raise explicit_failure(self, err) from err


class ExplicitEuler(ExplicitStepper):
    """Thesis mode of the optimal schemes (augmented or velocity form): Euler steps, Eq. (4.29)."""

    def __init__(self, evaluator, q0, dt, **kwargs):
        super().__init__(evaluator, q0, dt, **kwargs)
        self.symmetric = evaluator.formulation == "augmented"
        self._rates()

    def _rates(self) -> None:
        pt = self.evaluate(self.q, self.t)
        xdot = pt.xdot - pt.r / self.dt  # velocity correction, Eq. (4.29)
        self.lam = multipliers(pt.J, pt.grad)[0]  # Eqs. (4.11)-(4.12)
        self._solve_rates(pt, xdot)

    def advance(self) -> None:
        q = self.q
        t_next = self._next_time()
        self.q = q + self.dt * self.qdot  # explicit Euler
        self.t = t_next
        self._check_finite(q)
        self._rates()
        self._check_finite(q)
        self._check_tracked(self.pt)
