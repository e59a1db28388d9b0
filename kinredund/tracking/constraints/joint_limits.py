"""Joint position limits as tracker constraints: lower_i + margin <= theta_i <= upper_i - margin.

The limits come from the robot (its URDF, or the HD table's joint ranges); joints without finite limits
(|limit| >= 1e10, e.g. continuous joints) carry no inequality. Each bounded joint gives two inequalities,
``c = theta_i - lower_i`` (gradient e_i) and ``c = upper_i - theta_i`` (gradient -e_i).
"""

from __future__ import annotations

import numpy as np

from kinredund.errors import OptionError
from kinredund.model.robot import NO_LIMIT, Robot
from kinredund.tracking.constraints.base import Constraint

#: limits at or beyond this magnitude count as none (Pinocchio's default for unbounded joints is 1.8e308)


class JointLimits(Constraint):
    """The robot's position limits, shrunk by ``margin`` [rad or m] on each side.

    Attributes:
        joint: the joint index of each inequality, (size,).
        side: +1 for a lower bound (c = theta - bound), -1 for an upper bound (c = bound - theta).
        bound: the bound of each inequality [rad or m].
        lower, upper: the effective limits per joint (-inf / +inf where unbounded).

    Raises:
        OptionError: a negative or non-finite margin, or one that leaves no room between the limits.
    """

    def __init__(self, robot: Robot, margin: float = 0.0):
        margin = float(margin)
        if not (np.isfinite(margin) and margin >= 0.0):
            raise OptionError(f"the joint-limit margin must be a finite number >= 0 [rad or m], got {margin!r}")
        lo, hi = np.asarray(robot.lower, float), np.asarray(robot.upper, float)
        has_lo, has_hi = lo > -NO_LIMIT, hi < NO_LIMIT
        self.lower = np.where(has_lo, lo + margin, -np.inf)
        self.upper = np.where(has_hi, hi - margin, np.inf)
        narrow = np.flatnonzero(self.lower >= self.upper)
        if narrow.size:
            names = [robot.joint_names[i] for i in narrow]
            raise OptionError(f"a margin of {margin} leaves no room between the limits of {', '.join(names)}")
        self.robot_name, self.joint_names, self.margin = robot.name, list(robot.joint_names), margin
        lo_j, hi_j = np.flatnonzero(has_lo), np.flatnonzero(has_hi)
        self.joint = np.concatenate([lo_j, hi_j])
        self.side = np.concatenate([np.ones(len(lo_j)), -np.ones(len(hi_j))])
        self.bound = np.concatenate([self.lower[lo_j], self.upper[hi_j]])

    @property
    def size(self) -> int:
        return len(self.joint)

    def values(self, q: np.ndarray) -> np.ndarray:
        return self.side * (np.asarray(q, float)[self.joint] - self.bound)

    def gradients(self, q: np.ndarray) -> np.ndarray:
        G = np.zeros((self.size, len(q)))
        G[np.arange(self.size), self.joint] = self.side
        return G

    def bounds(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.joint, self.side, self.bound

    def names(self) -> list[str]:
        return [f"{self.joint_names[j]} {'>=' if s > 0 else '<='} {b:.6g}"
                for j, s, b in zip(self.joint, self.side, self.bound, strict=True)]

    def margins(self, q: np.ndarray) -> np.ndarray:
        """Per joint, the distance to the nearer limit [rad or m] (inf for unbounded joints; < 0 outside)."""
        q = np.asarray(q, float)
        return np.minimum(q - self.lower, self.upper - q)

    def project(self, q: np.ndarray) -> np.ndarray:
        """q clipped into the limits."""
        return np.clip(np.asarray(q, float), self.lower, self.upper)
