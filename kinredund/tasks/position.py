"""The position task: point P follows p(t) (m = 3; Chapter 4, Eqs. 2.16 and 4.20).

Residual p - p_d; Jacobian the pdot rows of K; Lambda = sum_a lambda_a dK[a] over those rows (Eq. 4.20).

Spurious zeros: none. The IK error, the reported residual and the tracking residual are all p - p_d,
zero exactly where the point is on its target (the orientation is no part of the task).
"""

from __future__ import annotations

import math

import numpy as np

from kinredund.errors import check_array
from kinredund.tasks.base import Target, Task, TaskResidual, TaskTerms


class PointTerms(TaskTerms):
    """Point tasks: rows of p - p_d, J = rows of K (Eq. 2.16)."""

    __slots__ = ("_rows",)

    def __init__(self, rows, p, K, dk, s):
        i = rows - 3
        self.r, self.J, self.xdot, self.basis = p[i] - s.p[i], K[rows], s.v[i], None
        self._dk, self._rows = dk, rows

    def Lambda(self, lam):
        return self._hessian().contract(lam, self._rows)  # Eq. (4.20): sum_a lam_a dK[a]


class PointResidual(TaskResidual):
    """e = p[rows] - x_d, G = K[rows] (Eq. D.23 for a point task)."""

    def __init__(self, target: Target, rows: np.ndarray):
        self.target = target
        self.rows = self.row_selection = rows
        self.m = rows.shape[0]
        self.x_d = target.p[rows - 3].copy()
        self.x_d_list = self.x_d.tolist()

    def error(self, Q, p):
        return p[self.rows - 3] - self.x_d, None

    def error_terms(self, Q, p):
        e = tuple(v - d for v, d in zip(p.tolist()[: self.m], self.x_d_list, strict=True))  # rows 3.. of K: x, y, z
        return e, sum(v * v for v in e)

    def jacobian(self, K, aux):
        return K[self.rows]

    def residual(self, Q, p):
        return math.sqrt(self.error_terms(Q, p)[1])


class PositionTask(Task):
    """Point P at p_d (3,) [m]."""

    name = "position"
    dim = 3
    point_rows = np.array([3, 4, 5])

    def make_target(self, target, *, z: float = 0.0) -> Target:
        x = check_array(target, (self.dim,), f"a {self.name} target")
        return Target(self.name, self._point(x, z))

    def _point(self, x: np.ndarray, z: float) -> np.ndarray:
        return x.copy()

    def ik_residual(self, target: Target) -> PointResidual:
        return PointResidual(target, self.point_rows)

    def tracking_terms(self, formulation, Q, p, K, dk, sample) -> PointTerms:
        return PointTerms(self.point_rows, p, K, dk, sample)
