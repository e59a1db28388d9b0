"""The base class of the tracker's constraints: inequalities c(theta) >= 0 held exactly along the path.

Along the path the joints follow theta*(t) = argmin z(theta) s.t. g(theta) = x(t), c(theta) >= 0. The
first-order conditions (Karush-Kuhn-Tucker, with the thesis's normality condition Eq. 4.5 as the case
without active inequalities) are

    grad z + J^T lambda - sum_j mu_j grad c_j = 0,   mu_j >= 0,   mu_j c_j = 0,

and between switching times the active inequalities are equalities: the thesis's system (4.24) with
their rows added (or, for simple bounds, the bound joints' columns removed). A constraint says how many
inequalities it has, their values and gradients at a configuration, and names them for messages.

Today the limited stepper (:mod:`kinredund.tracking.limited`) holds simple bounds only, through
:class:`~kinredund.tracking.constraints.joint_limits.JointLimits`'s ``lower`` and ``upper``: a general
inequality (an obstacle's clearance) needs its rows added to the reduced system, which this interface
describes but no stepper implements yet.
"""

from __future__ import annotations

import abc

import numpy as np


class Constraint(abc.ABC):
    """Inequalities c(theta) >= 0 on the joints [rad or m]; ``size`` of them."""

    @property
    @abc.abstractmethod
    def size(self) -> int:
        """The number of inequalities."""

    @abc.abstractmethod
    def values(self, q: np.ndarray) -> np.ndarray:
        """c(q) (size,): >= 0 where satisfied; the margin to each bound [rad or m]."""

    @abc.abstractmethod
    def gradients(self, q: np.ndarray) -> np.ndarray:
        """dc/dq (size, n)."""

    @abc.abstractmethod
    def names(self) -> list[str]:
        """A readable name per inequality (e.g. ``panda_joint4 >= -3.0718``)."""

    def violations(self, q: np.ndarray, tol: float = 0.0) -> list[tuple[str, float]]:
        """(name, amount) of each inequality violated by more than ``tol`` at q [rad or m]."""
        c = self.values(q)
        return [(name, float(-v)) for name, v in zip(self.names(), c, strict=True) if v < -tol]
