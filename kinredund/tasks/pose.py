"""The pose task: orientation and position of the end effector (m = 6; Chapters 2 and 4, Example 4.3).

Target: a 4x4 homogeneous matrix (Q_d, p_d), or a (Q, p) pair. Errors for the record in the thesis's
invariants: |tr Q - tr Q_d| and ||vect Q - vect Q_d|| (Example 4.3).

Tracking terms. Displacement-Jacobian scheme (``augmented``), pose task: the closure 7-vector g of Eq. (2.13) has one
dependent row (Eq. 2.10): its linearisation H(Q_d) has the unit left null vector
n = [vect(Q_d); cos(phi_d); 0] (n^T H = 0, from Eqs. 2.10 and 2.15). In base-frame components H
loses rank where the target rotation turns by pi (tr Q_d = -1: vect Q_d = 0 and tr(Q_d) 1 - Q_d is
singular) - Example 4.3 passes there at beta = pi/2. We therefore write the
closure equations with the invariants of the relative rotation Q_d^T Q (the same equations in the
target's frame): at the solution Q_d^T Q = 1, H = [2 1, 0; 0, 0; 0, 1] and the trace row is the
dependent one: we keep the other six rows (U = the 7x6 selection, lambda = U lambda_r).
Velocity-Jacobian scheme (``velocity``), pose task: r = [log(Q Q_d^T); p - p_d], J = K (Eq. 4.31),
dJ = dK (Eqs. 4.38-4.41); lambda* of Eq. (4.33).

Joint-level IK. The constraints g(theta) = x of Eq. (4.1) are linearised as G dx = -g, Eq. (D.23). For the planar and
position tasks g is the point position and G the matching rows of K. For the pose task the closure
7-vector of Eq. (2.13) has one dependent row (Eq. 2.10), so its 7 x n Jacobian J = H K never has full
row rank. The Newton steps therefore use a 6-D error on SE(3) instead,

    e = [log(Q Q_d^T); p - p_d],        G = [Jl^-1(log(Q Q_d^T)) K_omega; K_pdot],

where log is the rotation vector (axis times angle, world axes) and Jl^-1 the inverse left Jacobian
of SO(3), so that de/dt = G thetadot exactly. Both vanish together with the closure 7-vector, and at
e = 0 the null space of G is that of K and of J = H K. The residual *reported* for pose tasks is the
norm of the closure 7-vector.

Spurious zeros (points where a residual vanishes and the task is not done):

- IK error e: none. log(Q Q_d^T) is the rotation vector, of norm the angle in [0, pi]: zero only at
  Q = Q_d. The reported closure 7-vector has none either: vect(Q) = sin(phi) n and tr Q = 1 + 2 cos(phi)
  fix the rotation (Eq. 2.13), so it vanishes only at Q = Q_d.
- augmented tracking residual r = [2 vect(Q_d^T Q); p - p_d] (six rows of Eq. 2.13, the trace row left
  out): zero at Q_d^T Q = 1 and also at every half turn Q_d^T Q (vect = sin(pi) n = 0, tr = -1). Rejected
  by :meth:`PoseTask.branch_error` at the start of a run (tr(Q_d^T Q) <= 1, a turn of pi/2 or more);
  from there the run keeps the branch (r ~ 1e-12 at every step; reaching a half turn passes through
  turns where ||vect|| = 1).
- velocity tracking residual r = [log(Q Q_d^T); p - p_d]: none (as e).
"""

from __future__ import annotations

import math

import numpy as np

from kinredund.errors import TaskError, check_array
from kinredund.kinematics import closure
from kinredund.tasks.base import Target, Task, TaskResidual, TaskTerms

_KEEP = np.array([0, 1, 2, 4, 5, 6])  # the closure 7-vector without its trace row
#: U: the reduced multipliers of the augmented pose task to the closure 7-vector's (lambda_7 = U lambda)
U_REL = np.eye(7)[:, _KEEP]


def orientation_error(Q: np.ndarray, Q_d: np.ndarray) -> float:
    """The angle [rad] of Q_d^T Q: a frame-independent orientation error."""
    return closure.rotation_log(Q_d.T @ Q)[1]


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


class TwistTerms(TaskTerms):
    """Velocity-Jacobian pose task: r = [log(Q Q_d^T); p - p_d], J = K (Eq. 4.31)."""

    __slots__ = ()

    def __init__(self, Q, p, K, dk, s):
        r = np.empty(6)
        r[:3] = closure.rotation_log(Q @ s.Q.T)[0]
        r[3:] = p - s.p
        xdot = np.empty(6)
        xdot[:3], xdot[3:] = s.omega, s.v
        self.r, self.J, self.xdot, self.basis, self._dk = r, K, xdot, None, dk

    def Lambda(self, lam):
        return self._hessian().contract(lam)  # Lambda*, Eq. (4.42)


class ClosureTerms(TaskTerms):
    """Displacement-Jacobian pose task in the target frame: six rows of Eq. (2.13), J = H K (Eq. 2.14)."""

    __slots__ = ("_W", "_floats")

    def __init__(self, Q, p, K, dk, s):
        # Eq. (2.13) written with the invariants of the relative rotation Q_d^T Q (target frame): same
        # zero set, but H stays well conditioned where Q_d itself turns by pi (Example 4.3 at
        # beta = pi/2). At the target Q_d^T Q = 1 the left null vector of H is the trace row, so the six
        # kept rows are [2 vect(Q_d^T Q); p - p_d], U = [e1 e2 e3 e5 e6 e7].
        # The 3 x 3 algebra runs in Python floats (a numpy call costs more on arrays this small).
        Qd_T = s.Q.T
        W = Qd_T @ K[:3]  # omega columns in the target frame
        rel = (Qd_T @ Q).tolist()  # Q_rel = Q_d^T Q
        (q00, q01, q02), (q10, q11, q12), (q20, q21, q22) = rel
        tr = q00 + q11 + q22
        A = ((tr - q00, -q01, -q02), (-q10, tr - q11, -q12), (-q20, -q21, tr - q22))  # tr(Q) 1 - Q, Eq. (2.15)
        v = (0.5 * (q21 - q12), 0.5 * (q02 - q20), 0.5 * (q10 - q01))  # vect(Q_rel), Eq. (2.8)
        Qd = s.Q.tolist()
        (d00, d01, d02), (d10, d11, d12), (d20, d21, d22) = Qd
        o0, o1, o2 = s.omega.tolist()
        w_d = (d00 * o0 + d10 * o1 + d20 * o2, d01 * o0 + d11 * o1 + d21 * o2,
               d02 * o0 + d12 * o1 + d22 * o2)  # Q_d^T omega_d: the target's angular velocity in its frame
        (p0, p1, p2), (e0, e1, e2) = p.tolist(), s.p.tolist()
        self.r = np.array([2.0 * v[0], 2.0 * v[1], 2.0 * v[2], p0 - e0, p1 - e1, p2 - e2])  # Eq. (2.13), vect(1) = 0
        self.J = np.concatenate((np.array(A) @ W, K[3:]))  # Eq. (2.14): H K, vect rows then position rows
        self.xdot = np.array([A[0][0] * w_d[0] + A[0][1] * w_d[1] + A[0][2] * w_d[2],  # -dr/dt at fixed theta
                              A[1][0] * w_d[0] + A[1][1] * w_d[1] + A[1][2] * w_d[2],
                              A[2][0] * w_d[0] + A[2][1] * w_d[1] + A[2][2] * w_d[2], *s.v.tolist()])
        self.basis, self._dk, self._W, self._floats = U_REL, dk, W, (rel, A, v, Qd, w_d)

    def Lambda(self, lam):
        return self.system(lam)[0]

    def dJdt_T(self, lam):
        return self.system(lam)[1]

    def system(self, lam):
        rel, A, v, Qd, (w0, w1, w2) = self._floats
        l0, l1, l2, lp0, lp1, lp2 = lam.tolist()
        # Lambda, Eq. (4.20); the trace row is not kept: lambda_7 = U lambda has l4 = 0
        (m0, m1, m2), G = closure.lambda_parts_floats(rel, A, (l0, l1, l2), 0.0, v)
        (d00, d01, d02), (d10, d11, d12), (d20, d21, d22) = Qd
        # dK_rel = [Q_d^T dK_omega; dK_v]: contract dK with [Q_d m; lp], here in Pinocchio's [v; omega] order
        mu = np.array([lp0, lp1, lp2, d00 * m0 + d01 * m1 + d02 * m2, d10 * m0 + d11 * m1 + d12 * m2,
                       d20 * m0 + d21 * m1 + d22 * m2])
        W = self._W
        Lam = self._hessian().contract_pinocchio(mu) - W.T @ (np.array(G) @ W)  # Eq. (4.20)
        # dJ/dt at fixed theta: Q_rel turns at -w_d and so do the columns W (Eq. 4.15 differentiated in
        # time needs it: d(J^T lambda)/dt has the term (dJ/dt)^T lambda besides Lambda thetadot).
        # dJ_vect/dt = (dA - A [w_d]x) W with dA = (2 v . w_d) 1 + [w_d]x Q_rel; for a row l,
        # l^T [w]x = (l x w)^T, so l^T (dA - A [w]x) = (2 v . w) l + (l x w) Q_rel - (A^T l) x w.
        (q00, q01, q02), (q10, q11, q12), (q20, q21, q22) = rel
        s = 2.0 * (v[0] * w0 + v[1] * w1 + v[2] * w2)
        x0, x1, x2 = l1 * w2 - l2 * w1, l2 * w0 - l0 * w2, l0 * w1 - l1 * w0  # l x w
        # A^T l is m (lambda_parts_floats with l4 = 0)
        c = np.array([s * l0 + x0 * q00 + x1 * q10 + x2 * q20 - (m1 * w2 - m2 * w1),
                      s * l1 + x0 * q01 + x1 * q11 + x2 * q21 - (m2 * w0 - m0 * w2),
                      s * l2 + x0 * q02 + x1 * q12 + x2 * q22 - (m0 * w1 - m1 * w0)])
        return Lam, W.T @ c


class PoseResidual(TaskResidual):
    """e = [log(Q Q_d^T); p - p_d], G = [Jl^-1 K_omega; K_pdot]; the reported residual is the norm of
    the closure 7-vector (Eq. 2.13).

    Args:
        target: a pose :class:`~kinredund.tasks.base.Target`.
    """

    def __init__(self, target: Target):
        self.target = target
        self.rows, self.row_selection = np.arange(6), None
        self.m = 6
        self.QdT = np.ascontiguousarray(target.Q.T)
        self.vect_d = closure.vect(target.Q)
        self.vect_d_list = self.vect_d.tolist()
        self.trace_d = float(np.trace(target.Q))
        self.p_d = target.p.copy()
        self.p_d_list = self.p_d.tolist()

    def _rotation_error(self, Q: np.ndarray) -> tuple[tuple[float, float, float], float]:
        """log(Q Q_d^T) as Python floats (world axes) and its angle [rad]."""
        R = Q @ self.QdT
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = R.tolist()
        return closure.log_scalars(r00, r01, r02, r10, r11, r12, r20, r21, r22, R)

    def error(self, Q: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """(e, Jl^-1): the Newton error and the inverse left Jacobian at it."""
        w, phi = self._rotation_error(Q)
        px, py, pz = p.tolist()
        dx, dy, dz = self.p_d_list
        return np.array([*w, px - dx, py - dy, pz - dz]), inverse_left_jacobian(w, phi)

    def error_terms(self, Q: np.ndarray, p: np.ndarray) -> tuple[tuple[float, ...], float]:
        """(e, ||e||^2) with e as a tuple of floats: the cheap form of :meth:`error` for the iterations
        and line searches that need neither Jl^-1 nor a numpy vector."""
        (a, b, c), _ = self._rotation_error(Q)
        px, py, pz = p.tolist()
        dx, dy, dz = self.p_d_list
        px, py, pz = px - dx, py - dy, pz - dz
        return (a, b, c, px, py, pz), a * a + b * b + c * c + px * px + py * py + pz * pz

    def jacobian(self, K: np.ndarray, jl_inv: np.ndarray) -> np.ndarray:
        """G = de/dtheta (6 x n): [Jl^-1 K_omega; K_pdot]."""
        G = K.copy()
        G[:3] = jl_inv @ K[:3]
        return G

    def k_multipliers(self, lam: np.ndarray, jl_inv: np.ndarray) -> np.ndarray:
        """lambda* with G^T lambda = K^T lambda*, for Lambda* = d(K^T lambda*)/dtheta (Eq. 4.37)."""
        return np.concatenate([jl_inv.T @ lam[:3], lam[3:]])

    def residual(self, Q: np.ndarray, p: np.ndarray) -> float:
        """||g(theta) - x||: the closure 7-vector of Eq. (2.13) (the entries of
        :func:`kinredund.kinematics.closure.closure_vector`, unrolled: the constrained iteration evaluates
        it at every step)."""
        (q00, q01, q02), (q10, q11, q12), (q20, q21, q22) = Q.tolist()
        vx, vy, vz = self.vect_d_list
        a, b, c = q21 - q12 - 2.0 * vx, q02 - q20 - 2.0 * vy, q10 - q01 - 2.0 * vz  # 2 vect(Q) - 2 vect(Q_d)
        t = q00 + q11 + q22 - self.trace_d  # Eq. (2.13)
        px, py, pz = p.tolist()
        dx, dy, dz = self.p_d_list
        dx, dy, dz = px - dx, py - dy, pz - dz
        return math.sqrt(a * a + b * b + c * c + t * t + dx * dx + dy * dy + dz * dz)


class PoseTask(Task):
    """Orientation and position: a 4x4 homogeneous target (Q_d, p_d)."""

    name = "pose"
    dim = 6
    has_orientation = True
    error_names = ("position_error", "trace_error", "vect_error")
    holds_rotation = True

    def make_target(self, target, *, z: float = 0.0) -> Target:
        """Validate a 4x4 homogeneous pose (or a (Q, p) pair).

        Raises:
            TaskError: not numeric, wrong size, non-finite entries, a 4x4 whose last row is not
                (0, 0, 0, 1), or a rotation that is not orthonormal.
        """
        if isinstance(target, tuple) and len(target) == 2:
            Q = check_array(target[0], (3, 3), "a pose target's rotation Q")
            p = check_array(target[1], (3,), "a pose target's position p [m]")
        else:
            T = check_array(target, (4, 4), "a pose target (a 4x4 homogeneous matrix, or (Q, p))")
            if np.abs(T[3] - (0.0, 0.0, 0.0, 1.0)).max() > 1e-9:
                raise TaskError(f"a pose target's last row must be (0, 0, 0, 1), got {T[3].tolist()}")
            Q, p = T[:3, :3], T[:3, 3]
        if np.abs(Q @ Q.T - np.eye(3)).max() > 1e-8 or np.linalg.det(Q) < 0:
            raise TaskError("the pose target's rotation is not a proper orthonormal matrix (Q Q^T = 1, det Q = +1)")
        return Target(self.name, p.copy(), Q.copy())

    def errors_many(self, Q, p, Q_d, p_d):
        out = super().errors_many(Q, p, Q_d, p_d)
        out["trace_error"] = np.abs(np.trace(Q, axis1=1, axis2=2) - np.trace(Q_d, axis1=1, axis2=2))
        D = Q - Q_d  # vect(Q) - vect(Q_d) = vect(Q - Q_d), Eq. (2.8)
        v = 0.5 * np.stack([D[:, 2, 1] - D[:, 1, 2], D[:, 0, 2] - D[:, 2, 0], D[:, 1, 0] - D[:, 0, 1]], axis=1)
        out["vect_error"] = np.linalg.norm(v, axis=1)
        return out

    def branch_error(self, Q, Q_d):
        """The end frame turned by pi/2 or more from Q_d (tr(Q_d^T Q) <= 1), where the augmented residual's
        half-turn zeros lie (module docstring)."""
        tr = float((Q * Q_d).sum())  # tr(Q_d^T Q) (np.sum's reduction, without its Python wrapper)
        if tr > 1.0:
            return ""
        angle = math.degrees(math.acos(max(-1.0, min(1.0, 0.5 * (tr - 1.0)))))
        return (f"the end frame is turned by {angle:.4g} deg from the path's orientation: the residual "
                "[2 vect(Q_d^T Q); p - p_d] vanishes at half turns too (spurious zeros), so a start must be "
                "within pi/2 of it")

    def orientation_angles(self, Q, Q_d):
        """The angle of Q_d^T Q [rad] at each point (the vect error is not an angle)."""
        return np.array([orientation_error(a, b) for a, b in zip(Q, Q_d, strict=True)])

    def span_rows(self, Q, K, Q_d):
        """K itself: J = K (velocity form) or H K with H invertible near the path (Eq. 2.14)."""
        return K

    def ik_residual(self, target: Target) -> PoseResidual:
        return PoseResidual(target)

    def tracking_terms(self, formulation, Q, p, K, dk, sample):
        if formulation == "velocity":
            return TwistTerms(Q, p, K, dk, sample)
        return ClosureTerms(Q, p, K, dk, sample)
