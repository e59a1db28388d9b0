"""Task terms of the resolved-rate schemes at one configuration and time (Chapter 4, Eqs. 4.5-4.42).

For a task kind and a scheme this module turns the kinematics (Q, p, K, dK) and a path sample into

- r: the task residual (actual minus desired), zero on the path;
- J: its Jacobian dr/dtheta (m x n, full row rank away from singularities);
- dJ: dJ/dtheta (m, n, n), for Lambda = d(J^T lambda)/dtheta (Eq. 4.20) or Lambda* (Eq. 4.42);
- xdot: the desired rate of the task coordinates (right-hand side of Eq. 4.15 / 4.31).

Displacement-Jacobian scheme (``augmented``), pose task: the closure 7-vector g of Eq. (2.13) has one
dependent row (Eq. 2.10). Its linearisation H(Q_d) has the unit left null vector
n = [vect(Q_d); cos(phi_d); 0] (n^T H = 0, from Eqs. 2.10 and 2.15), so we keep the six equations
U^T g = 0, U an orthonormal basis of n's complement (a Householder reflector), and lambda = U lambda_r.
In base-frame components H loses rank where the target rotation turns by pi (tr Q_d = -1: vect Q_d = 0
and tr(Q_d) 1 - Q_d is singular) - Example 4.3 passes there at beta = pi/2. We therefore write the
closure equations with the invariants of the relative rotation Q_d^T Q (the same equations in the
target's frame): at the solution Q_d^T Q = 1, H = [2 1, 0; 0, 0; 0, 1] and the trace row is the
dependent one.
Velocity-Jacobian scheme (``velocity``), pose task: r = [log(Q Q_d^T); p - p_d], J = K (Eq. 4.31),
dJ = dK (Eqs. 4.38-4.41); lambda* of Eq. (4.33).
"""

from __future__ import annotations

import numpy as np

from . import closure
from .paths import PathSample
from .task import TASK_ROWS


def null_complement(n: np.ndarray) -> np.ndarray:
    """An orthonormal basis (columns) of the complement of the unit vector n, by a Householder reflector."""
    k = int(np.argmax(np.abs(n)))
    w = n.copy()
    w[k] += np.copysign(1.0, n[k])
    P = np.eye(n.shape[0]) - (2.0 / (w @ w)) * np.outer(w, w)
    return np.delete(P, k, axis=1)


def closure_basis(Q_d: np.ndarray) -> np.ndarray:
    """U (7x6): the six independent directions of the closure 7-vector at the target rotation Q_d."""
    n = np.zeros(7)
    n[:3] = closure.vect(Q_d)
    n[3] = 0.5 * (np.trace(Q_d) - 1.0)  # n^T H(Q_d) = 0
    return null_complement(n / np.linalg.norm(n))


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
    """(r, J, dJ or None, xdot, lam_basis) at one configuration; see the module docstring.

    ``lam_basis`` maps the reduced multipliers to the closure 7-vector's (U) for the augmented pose
    task, else None.
    """
    if task != "pose":
        rows = TASK_ROWS[task]
        r = p[rows - 3] - s.p[rows - 3]
        return r, K[rows], (dK[rows] if need_dJ else None), s.v[rows - 3], None
    if scheme == "velocity":
        r = np.concatenate([rotation_log(Q @ s.Q.T), p - s.p])
        return r, K, (dK if need_dJ else None), np.concatenate([s.omega, s.v]), None
    # Eq. (2.13) written with the invariants of the relative rotation Q_d^T Q (target frame): same zero
    # set, but H stays well conditioned where Q_d itself turns by pi (Example 4.3 at beta = pi/2).
    Qd_T = s.Q.T
    Q_rel = Qd_T @ Q
    K_rel = np.vstack([Qd_T @ K[:3], K[3:]])
    U = closure_basis(np.eye(3))
    g = closure.closure_vector(Q_rel, p, np.eye(3), s.p)  # Eq. (2.13)
    J = U.T @ closure.displacement_jacobian(Q_rel, K_rel)  # Eq. (2.14), six independent rows
    dJ = None
    if need_dJ:
        dK_rel = np.concatenate([np.einsum("ab,bik->aik", Qd_T, dK[:3]), dK[3:]])
        dJ7 = closure.displacement_jacobian_derivative(Q_rel, K_rel, dK_rel)
        dJ = (U.T @ dJ7.reshape(7, -1)).reshape(6, *dJ7.shape[1:])
    xdot = U.T @ (closure.closure_matrix(np.eye(3)) @ np.concatenate([Qd_T @ s.omega, s.v]))
    return U.T @ g, J, dJ, xdot, U
