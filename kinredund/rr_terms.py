"""Task terms of the resolved-rate schemes at one configuration and time (Chapter 4, Eqs. 4.5-4.42).

For a task kind and a scheme this module turns the kinematics (Q, p, K, dK) and a path sample into

- r: the task residual (actual minus desired), zero on the path;
- J: its Jacobian dr/dtheta (m x n, full row rank away from singularities);
- dJ: dJ/dtheta (m, n, n), for Lambda = d(J^T lambda)/dtheta (Eq. 4.20) or Lambda* (Eq. 4.42);
- xdot: the desired rate of the task coordinates (right-hand side of Eq. 4.15 / 4.31).

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

from . import closure
from .paths import PathSample
from .task import TASK_ROWS


def rotation_log(R: np.ndarray) -> np.ndarray:
    """The rotation vector u phi of R (phi in [0, pi]); accurate down to the smallest angles."""
    q = closure.vect(R)
    s = float(np.linalg.norm(q))
    c = 0.5 * (np.trace(R) - 1.0)
    if s < 1e-4 and c > 0:
        return q * (1.0 + s * s / 6.0)  # phi / sin(phi) = 1 + phi^2/6 + O(phi^4)
    u, phi = closure.natural_invariants(R)
    return u * phi


def task_terms(task: str, scheme: str, Q, p, K, dK, s: PathSample, need_dJ: bool = True):
    """(r, J, dJ or None, xdot, lam_basis, dJdt or None) at one configuration; see the module docstring.

    ``dJdt`` is the explicit time derivative of J at fixed theta (nonzero only for the augmented pose
    task, whose rows are written in the moving target frame), None where it vanishes.

    ``lam_basis`` maps the reduced multipliers to the closure 7-vector's (U) for the augmented pose
    task, else None.
    """
    if task != "pose":
        rows = TASK_ROWS[task]
        r = p[rows - 3] - s.p[rows - 3]
        return r, K[rows], (dK[rows] if need_dJ else None), s.v[rows - 3], None, None
    if scheme == "velocity":
        r = np.concatenate([rotation_log(Q @ s.Q.T), p - s.p])
        return r, K, (dK if need_dJ else None), np.concatenate([s.omega, s.v]), None, None
    # Eq. (2.13) written with the invariants of the relative rotation Q_d^T Q (target frame): same zero
    # set, but H stays well conditioned where Q_d itself turns by pi (Example 4.3 at beta = pi/2). At the
    # target Q_d^T Q = 1 the left null vector of H is n = [0, 0, 0, 1, 0, 0, 0] (the trace row), so the
    # six kept rows are [2 vect(Q_d^T Q); p - p_d], U = [e1 e2 e3 e5 e6 e7].
    Qd_T = s.Q.T
    Q_rel = Qd_T @ Q
    W = Qd_T @ K[:3]  # omega columns in the target frame
    A = (Q_rel[0, 0] + Q_rel[1, 1] + Q_rel[2, 2]) * _EYE3 - Q_rel  # Eq. (2.15): tr(Q) 1 - Q
    r = np.empty(6)
    r[0] = Q_rel[2, 1] - Q_rel[1, 2]  # 2 vect(Q_d^T Q), Eq. (2.13)
    r[1] = Q_rel[0, 2] - Q_rel[2, 0]
    r[2] = Q_rel[1, 0] - Q_rel[0, 1]
    r[3:] = p - s.p
    J = np.empty((6, K.shape[1]))
    J[:3] = A @ W  # Eq. (2.14), rows of H K
    J[3:] = K[3:]
    dJ = None
    if need_dJ:
        n = K.shape[1]
        dJ = np.empty((6, n, n))
        s_k = 0.5 * r[:3] @ W  # vect(Q_rel) . w_k
        QW = Q_rel @ W
        dJ[:3] = ((A @ Qd_T) @ dK[:3].reshape(3, n * n)).reshape(3, n, n)  # A dW/dtheta_k
        dJ[:3] -= 2.0 * s_k[None, None, :] * W[:, :, None]
        # minus [a, i, k] = (w_k x (Q_rel w_i))_a = eps_abc w_bk (Q_rel w_i)_c, as two matrix products
        dJ[:3] -= QW.T @ (_EPS_T @ W).reshape(3, 3, n)  # broadcasts over a: [a, i, k]
        dJ[3:] = dK[3:]
    w_d = Qd_T @ s.omega  # the target's angular velocity in its own frame
    xdot = np.empty(6)
    xdot[:3] = A @ w_d  # -dr/dt at fixed theta
    xdot[3:] = s.v
    dJdt = None
    if need_dJ:
        # dJ/dt at fixed theta: Q_rel turns at -w_d and so do the columns W (Eq. 4.15 differentiated
        # in time needs it: d(J^T lambda)/dt has the term (dJ/dt)^T lambda besides Lambda thetadot)
        Wx = _cross(w_d)
        dA = (r[:3] @ w_d) * _EYE3 + Wx @ Q_rel
        dJdt = np.zeros((6, K.shape[1]))
        dJdt[:3] = (dA - A @ Wx) @ W
    return r, J, dJ, xdot, _U_REL, dJdt


def _cross(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


_EYE3 = np.eye(3)
_EPS = np.zeros((3, 3, 3))
_EPS[0, 1, 2] = _EPS[1, 2, 0] = _EPS[2, 0, 1] = 1.0
_EPS[0, 2, 1] = _EPS[2, 1, 0] = _EPS[1, 0, 2] = -1.0
_EPS_T = _EPS.transpose(0, 2, 1).reshape(9, 3)  # [(a, c), b] = eps_abc
_U_REL = np.delete(np.eye(7), 3, axis=1)
