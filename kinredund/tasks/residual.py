"""The residual that the joint-level IK drives to zero, and its Jacobian (Chapter 4.2, Appendix D).

The constraints g(theta) = x of Eq. (4.1) are linearised as G dx = -g, Eq. (D.23). For the planar and
position tasks g is the point position and G the matching rows of K. For the pose task the closure
7-vector of Eq. (2.13) has one dependent row (Eq. 2.10), so its 7 x n Jacobian J = H K never has full
row rank. The Newton steps therefore use a 6-D error on SE(3) instead,

    e = [log(Q Q_d^T); p - p_d],        G = [Jl^-1(log(Q Q_d^T)) K_omega; K_pdot],

where log is the rotation vector (axis times angle, world axes) and Jl^-1 the inverse left Jacobian
of SO(3), so that de/dt = G thetadot exactly. Both vanish together with the closure 7-vector, and at
e = 0 the null space of G is that of K and of J = H K. The residual *reported* for pose tasks is the
norm of the closure 7-vector.

This is the library's one task-residual layer: :mod:`kinredund.tasks.target` validates the targets, and the
closure 7-vector and J = H K themselves are :func:`kinredund.closure.closure_vector` and
:func:`kinredund.kinematics.closure.displacement_jacobian`.

Symbols: Q (3x3), p [m], K (6 x n) rows [omega; pdot] (Eq. 2.16), e (m,), G (m x n).
"""

from __future__ import annotations

import math

import numpy as np

from kinredund.kinematics import closure
from kinredund.tasks.target import TASK_ROWS, Target


def inverse_left_jacobian(w, phi: float) -> np.ndarray:
    """Jl^-1(w) of SO(3): d log(R)/dt = Jl^-1 omega when dR/dt = [omega]x R.

    Jl^-1 = 1 - [w]x / 2 + kappa [w]x^2 = (1 - kappa phi^2) 1 - [w]x / 2 + kappa w w^T,
    kappa = 1/phi^2 - cot(phi/2) / (2 phi).
    """
    if phi < closure.SMALL_ANGLE:
        kappa = 1.0 / 12.0 + phi * phi / 720.0
    else:
        kappa = 1.0 / (phi * phi) - math.cos(0.5 * phi) / (2.0 * phi * math.sin(0.5 * phi))
    x, y, z = (float(v) for v in w)
    d = 1.0 - kappa * phi * phi
    kx, ky, kz = kappa * x, kappa * y, kappa * z
    return np.array([
        [d + kx * x, ky * x + 0.5 * z, kz * x - 0.5 * y],
        [kx * y - 0.5 * z, d + ky * y, kz * y + 0.5 * x],
        [kx * z + 0.5 * y, ky * z - 0.5 * x, d + kz * z],
    ])


class TaskResidual:
    """e(theta), G(theta) and the reported residual for one validated target.

    Args:
        target: a :class:`kinredund.tasks.target.Target`.
    """

    def __init__(self, target: Target):
        self.target = target
        self.pose = target.task == "pose"
        if self.pose:
            self.rows = np.arange(6)
            self.QdT = np.ascontiguousarray(target.Q.T)
            self.vect_d = closure.vect(target.Q)
            self.vect_d_list = self.vect_d.tolist()
            self.trace_d = float(np.trace(target.Q))
            self.p_d = target.p.copy()
            self.p_d_list = self.p_d.tolist()
        else:
            self.rows = TASK_ROWS[target.task]
            self.x_d = target.p[self.rows - 3].copy()
            self.x_d_list = self.x_d.tolist()
        self.m = self.rows.shape[0]

    def _rotation_error(self, Q: np.ndarray) -> tuple[tuple[float, float, float], float]:
        """log(Q Q_d^T) as Python floats (world axes) and its angle [rad]."""
        R = Q @ self.QdT
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = R.tolist()
        return closure.log_scalars(r00, r01, r02, r10, r11, r12, r20, r21, r22, R)

    def error(self, Q: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """(e, Jl^-1): the Newton error and, for pose tasks, the inverse left Jacobian at it."""
        if not self.pose:
            return p[self.rows - 3] - self.x_d, None
        w, phi = self._rotation_error(Q)
        px, py, pz = p.tolist()
        dx, dy, dz = self.p_d_list
        return np.array([*w, px - dx, py - dy, pz - dz]), inverse_left_jacobian(w, phi)

    def error_terms(self, Q: np.ndarray, p: np.ndarray) -> tuple[tuple[float, ...], float]:
        """(e, ||e||^2) with e as a tuple of floats: the cheap form of :meth:`error` for the iterations
        and line searches that need neither Jl^-1 nor a numpy vector."""
        if self.pose:
            (a, b, c), _ = self._rotation_error(Q)
            px, py, pz = p.tolist()
            dx, dy, dz = self.p_d_list
            px, py, pz = px - dx, py - dy, pz - dz
            return (a, b, c, px, py, pz), a * a + b * b + c * c + px * px + py * py + pz * pz
        e = tuple(v - d for v, d in zip(p.tolist()[: self.m], self.x_d_list, strict=True))  # rows 3.. of K: x, y, z
        return e, sum(v * v for v in e)

    def jacobian(self, K: np.ndarray, jl_inv: np.ndarray | None) -> np.ndarray:
        """G = de/dtheta (m x n): rows of K, or [Jl^-1 K_omega; K_pdot] for pose tasks."""
        if not self.pose:
            return K[self.rows]
        G = K.copy()
        G[:3] = jl_inv @ K[:3]
        return G

    def k_multipliers(self, lam: np.ndarray, jl_inv: np.ndarray | None) -> np.ndarray:
        """lambda* with G^T lambda = K[rows]^T lambda*, for Lambda* = d(K^T lambda*)/dtheta (Eq. 4.37)."""
        if not self.pose:
            return lam
        return np.concatenate([jl_inv.T @ lam[:3], lam[3:]])

    def residual(self, Q: np.ndarray, p: np.ndarray) -> float:
        """||g(theta) - x||: the closure 7-vector of Eq. (2.13) for pose tasks (the entries of
        :func:`kinredund.closure.closure_vector`, unrolled: the constrained iteration evaluates it at every
        step), else the position error."""
        if not self.pose:
            return math.sqrt(self.error_terms(Q, p)[1])
        (q00, q01, q02), (q10, q11, q12), (q20, q21, q22) = Q.tolist()
        vx, vy, vz = self.vect_d_list
        a, b, c = q21 - q12 - 2.0 * vx, q02 - q20 - 2.0 * vy, q10 - q01 - 2.0 * vz  # 2 vect(Q) - 2 vect(Q_d)
        t = q00 + q11 + q22 - self.trace_d  # Eq. (2.13)
        px, py, pz = p.tolist()
        dx, dy, dz = self.p_d_list
        dx, dy, dz = px - dx, py - dy, pz - dz
        return math.sqrt(a * a + b * b + c * c + t * t + dx * dx + dy * dy + dz * dz)

    def scale(self) -> float:
        """A length scale of the target [m] for rounding-aware tolerances."""
        return float(np.abs(self.target.p).max())
