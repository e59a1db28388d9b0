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
        r = np.concatenate([closure.rotation_log(Q @ s.Q.T)[0], p - s.p])
        return r, K, (dK if need_dJ else None), np.concatenate([s.omega, s.v]), None, None
    # Eq. (2.13) written with the invariants of the relative rotation Q_d^T Q (target frame): same zero
    # set, but H stays well conditioned where Q_d itself turns by pi (Example 4.3 at beta = pi/2). At the
    # target Q_d^T Q = 1 the left null vector of H is n = [0, 0, 0, 1, 0, 0, 0] (the trace row), so the
    # six kept rows are [2 vect(Q_d^T Q); p - p_d], U = [e1 e2 e3 e5 e6 e7].
    Qd_T = s.Q.T
    Q_rel = Qd_T @ Q
    W = Qd_T @ K[:3]  # omega columns in the target frame
    K_rel = np.concatenate([W, K[3:]])
    r = closure.closure_vector(Q_rel, p, _EYE3, s.p)[_KEEP]  # Eq. (2.13), the six independent rows
    J = closure.displacement_jacobian(Q_rel, K_rel)[_KEEP]  # Eq. (2.14)
    dJ = None
    if need_dJ:
        n = K.shape[1]
        dK_rel = np.concatenate([(Qd_T @ dK[:3].reshape(3, n * n)).reshape(3, n, n), dK[3:]])
        dJ = closure.displacement_jacobian_derivative(Q_rel, K_rel, dK_rel)[_KEEP]
    A = Q_rel.trace() * _EYE3 - Q_rel  # Eq. (2.15): tr(Q) 1 - Q
    w_d = Qd_T @ s.omega  # the target's angular velocity in its own frame
    xdot = np.empty(6)
    xdot[:3] = A @ w_d  # -dr/dt at fixed theta
    xdot[3:] = s.v
    dJdt = None
    if need_dJ:
        # dJ/dt at fixed theta: Q_rel turns at -w_d and so do the columns W (Eq. 4.15 differentiated
        # in time needs it: d(J^T lambda)/dt has the term (dJ/dt)^T lambda besides Lambda thetadot)
        Wx = closure.cross_matrix(w_d)
        dA = (r[:3] @ w_d) * _EYE3 + Wx @ Q_rel
        dJdt = np.zeros((6, K.shape[1]))
        dJdt[:3] = (dA - A @ Wx) @ W
    return r, J, dJ, xdot, _U_REL, dJdt


_EYE3 = np.eye(3)
_KEEP = np.array([0, 1, 2, 4, 5, 6])  # the closure 7-vector without its trace row
_U_REL = np.eye(7)[:, _KEEP]
