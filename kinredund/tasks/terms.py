"""Task terms of the resolved-rate schemes at one configuration and time (Chapter 4, Eqs. 4.5-4.42).

For a task kind and a scheme, :func:`task_terms` turns the kinematics (Q, p, K and dK as a
:class:`~kinredund.kinematics.state.HessianContraction`) and a path sample into a :class:`TaskTerms`:

- r: the task residual (actual minus desired), zero on the path;
- J: its Jacobian dr/dtheta (m x n, full row rank away from singularities);
- xdot: the desired rate of the task coordinates (right-hand side of Eq. 4.15 / 4.31);
- Lambda(lam) = d(J^T lam)/dtheta at fixed lam (Eq. 4.20) or Lambda* (Eq. 4.42), contracted straight
  from Pinocchio's Hessian (the tensor dJ is never formed);
- dJdt_T(lam): (dJ/dt)^T lam at fixed theta, where J depends on time (else None).

Displacement-Jacobian scheme (``augmented``), pose task: the closure 7-vector g of Eq. (2.13) has one
dependent row (Eq. 2.10): its linearisation H(Q_d) has the unit left null vector
n = [vect(Q_d); cos(phi_d); 0] (n^T H = 0, from Eqs. 2.10 and 2.15). In base-frame components H
loses rank where the target rotation turns by pi (tr Q_d = -1: vect Q_d = 0 and tr(Q_d) 1 - Q_d is
singular) - Example 4.3 passes there at beta = pi/2. We therefore write the
closure equations with the invariants of the relative rotation Q_d^T Q (the same equations in the
target's frame): at the solution Q_d^T Q = 1, H = [2 1, 0; 0, 0; 0, 1] and the trace row is the
dependent one: we keep the other six rows (U = the 7x6 selection, lambda = U lambda_r).
Velocity-Jacobian scheme (``velocity``), pose task: r = [log(Q Q_d^T); p - p_d], J = K (Eq. 4.31),
dJ = dK (Eqs. 4.38-4.41); lambda* of Eq. (4.33).
"""

from __future__ import annotations

import numpy as np

from kinredund.errors import KinredundError
from kinredund.kinematics import closure
from kinredund.paths import PathSample
from kinredund.tasks.target import TASK_ROWS


class TaskTerms:
    """r, J, xdot and the multiplier basis at one point; Lambda and (dJ/dt)^T lambda on demand."""

    __slots__ = ("r", "J", "xdot", "basis", "_dk")

    def Lambda(self, lam: np.ndarray) -> np.ndarray:
        """d(J^T lam)/dtheta at fixed lam, (n, n): Lambda of Eq. (4.20) or Lambda* of Eq. (4.42)."""
        raise NotImplementedError

    def dJdt_T(self, lam: np.ndarray) -> np.ndarray | None:
        """(dJ/dt)^T lam at fixed theta, or None where J does not depend on time."""
        return None

    def system(self, lam: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """(Lambda(lam), dJdt_T(lam)) together: what one evaluation of Eq. (4.24) needs."""
        return self.Lambda(lam), self.dJdt_T(lam)

    def _hessian(self):
        if self._dk is None:
            raise KinredundError("these task terms were evaluated without dK (need_dJ=False)")
        return self._dk


class _RowTerms(TaskTerms):
    """Planar and position tasks: rows of p - p_d, J = rows of K (Eq. 2.16)."""

    __slots__ = ("_rows",)

    def __init__(self, rows, p, K, dk, s: PathSample):
        i = rows - 3
        self.r, self.J, self.xdot, self.basis = p[i] - s.p[i], K[rows], s.v[i], None
        self._dk, self._rows = dk, rows

    def Lambda(self, lam):
        return self._hessian().contract(lam, self._rows)  # Eq. (4.20): sum_a lam_a dK[a]


class _TwistTerms(TaskTerms):
    """Velocity-Jacobian pose task: r = [log(Q Q_d^T); p - p_d], J = K (Eq. 4.31)."""

    __slots__ = ()

    def __init__(self, Q, p, K, dk, s: PathSample):
        r = np.empty(6)
        r[:3] = closure.rotation_log(Q @ s.Q.T)[0]
        r[3:] = p - s.p
        xdot = np.empty(6)
        xdot[:3], xdot[3:] = s.omega, s.v
        self.r, self.J, self.xdot, self.basis, self._dk = r, K, xdot, None, dk

    def Lambda(self, lam):
        return self._hessian().contract(lam)  # Lambda*, Eq. (4.42)


class _ClosureTerms(TaskTerms):
    """Displacement-Jacobian pose task in the target frame: six rows of Eq. (2.13), J = H K (Eq. 2.14)."""

    __slots__ = ("_W", "_floats")

    def __init__(self, Q, p, K, dk, s: PathSample):
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
        self.basis, self._dk, self._W, self._floats = _U_REL, dk, W, (rel, A, v, Qd, w_d)

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


def task_terms(task: str, scheme: str, Q, p, K, dk, s: PathSample) -> TaskTerms:
    """The :class:`TaskTerms` at one configuration; ``dk`` may be None where Lambda is not needed.

    ``basis`` maps the reduced multipliers to the closure 7-vector's (U) for the augmented pose
    task, else None.
    """
    if task != "pose":
        return _RowTerms(TASK_ROWS[task], p, K, dk, s)
    if scheme == "velocity":
        return _TwistTerms(Q, p, K, dk, s)
    return _ClosureTerms(Q, p, K, dk, s)


_KEEP = np.array([0, 1, 2, 4, 5, 6])  # the closure 7-vector without its trace row
_U_REL = np.eye(7)[:, _KEEP]
