"""Rotation invariants, closure equations and the Jacobians built on K (Chapter 2, Chapter 4, Appendix E).

Pure functions of arrays; nothing here calls Pinocchio. Symbols (see ``docs/notation.md``):

- Q: end-effector rotation (3x3); p: position of point P [m]; K: velocity Jacobian (6 x n) with rows
  [omega; pdot] (Eq. 2.16); dK: its derivative tensor dK[a, i, k] = dK[a, i]/dtheta_k.
- g: the closure 7-vector of Eq. (2.13); H: the 7x6 matrix of Eq. (2.15); J = H K (Eq. 2.14), the
  displacement Jacobian (Eqs. 4.7-4.10); dJ its derivative tensor.
- Lambda = d(J^T lambda)/dtheta (Eqs. 4.20-4.26), symmetric; Lambda* = d(K^T lambda*)/dtheta
  (Eqs. 4.37-4.42), not symmetric in general.
"""

from __future__ import annotations

import math

import numpy as np

_EPS = np.zeros((3, 3, 3))
_EPS[0, 1, 2] = _EPS[1, 2, 0] = _EPS[2, 0, 1] = 1.0
_EPS[0, 2, 1] = _EPS[2, 1, 0] = _EPS[1, 0, 2] = -1.0
_EPS_T = _EPS.transpose(0, 2, 1).reshape(9, 3)  # [(a, c), b] = eps_abc


def vect(Q: np.ndarray) -> np.ndarray:
    """vect(Q) = u sin(phi), Eqs. (2.6) and (2.8)."""
    (_, q01, q02), (q10, _, q12), (q20, q21, _) = Q.tolist()  # Python floats: about twice as fast as fancy indexing
    return np.array([0.5 * (q21 - q12), 0.5 * (q02 - q20), 0.5 * (q10 - q01)])  # Eq. (2.8)


def trace_form(Q: np.ndarray) -> np.ndarray:
    """tr(Q) 1 - Q, the upper-left block of H in Eq. (2.15): d(2 vect Q)/dt = (tr(Q) 1 - Q) omega."""
    (q00, q01, q02), (q10, q11, q12), (q20, q21, q22) = Q.tolist()
    tr = q00 + q11 + q22
    return np.array([[tr - q00, -q01, -q02], [-q10, tr - q11, -q12], [-q20, -q21, tr - q22]])  # Eq. (2.15)


def cross_matrix(v: np.ndarray) -> np.ndarray:
    """The cross-product matrix of v: cross_matrix(v) @ w = v x w."""
    x, y, z = v.tolist()
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def natural_invariants(Q: np.ndarray) -> tuple[np.ndarray, float]:
    """The axis u and angle phi in [0, pi] of a rotation, Eqs. (2.4)-(2.7).

    Near phi = pi, where vect(Q) = u sin(phi) has lost its digits, the axis comes from the symmetric
    part of Q (:func:`_axis_from_symmetric_part`); at phi = 0 any axis is valid and (1, 0, 0) is returned.
    """
    q = vect(Q)
    c = float(np.clip(0.5 * (Q.trace() - 1.0), -1.0, 1.0))  # Eq. (2.7)
    s = float(np.linalg.norm(q))
    phi = math.atan2(s, c)
    if s > (_SMALL_SIN if c > 0 else _NEAR_PI_SIN):
        return q / s, phi
    if c > 0:
        return np.array([1.0, 0.0, 0.0]), 0.0
    u = _axis_from_symmetric_part(Q, c)
    return (-u if float(u @ q) < 0.0 else u), phi


def _axis_from_symmetric_part(Q: np.ndarray, c: float) -> np.ndarray:
    """The unit axis u (up to sign) of a rotation with cos(phi) = c < 1, from its symmetric part.

    Eq. (2.4): (Q + Q^T)/2 = c 1 + (1 - c) u u^T; the largest diagonal entry of u u^T gives the
    best-conditioned column.
    """
    B = (0.5 * (Q + Q.T) - c * np.eye(3)) / (1.0 - c)  # u u^T
    k = int(np.argmax(np.diag(B)))
    return B[:, k] / math.sqrt(B[k, k])


#: below this angle [rad] phi / sin(phi) is taken to second order
SMALL_ANGLE = 1e-4
#: sin(phi) below which the axis is taken from the symmetric part near phi = pi (vect Q has lost its digits)
_NEAR_PI_SIN = 1e-6
#: sin(phi) below which a rotation near the identity is the identity (any axis)
_SMALL_SIN = 1e-9


def rotation_log(R: np.ndarray) -> tuple[np.ndarray, float]:
    """The rotation vector w = u phi of R (phi in [0, pi]) and its angle phi [rad] (Eqs. 2.4-2.8)."""
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = R.tolist()
    w, phi = log_scalars(r00, r01, r02, r10, r11, r12, r20, r21, r22, R)
    return np.array(w), phi


def log_scalars(r00, r01, r02, r10, r11, r12, r20, r21, r22, R) -> tuple[tuple[float, float, float], float]:
    """:func:`rotation_log` on the nine entries as Python floats (the IK's inner loop has them)."""
    vx, vy, vz = 0.5 * (r21 - r12), 0.5 * (r02 - r20), 0.5 * (r10 - r01)  # vect(R), Eq. (2.8)
    c = 0.5 * (r00 + r11 + r22 - 1.0)  # cos(phi), Eq. (2.7)
    s = math.sqrt(vx * vx + vy * vy + vz * vz)  # sin(phi)
    phi = math.atan2(s, c)
    if phi < SMALL_ANGLE:
        f = 1.0 + phi * phi / 6.0  # phi / sin(phi) to second order
    elif s > _NEAR_PI_SIN:
        f = phi / s
    else:  # phi ~ pi: vect(R) has lost its digits; the axis from the symmetric part of R
        u = _axis_from_symmetric_part(np.asarray(R), c)
        if u[0] * vx + u[1] * vy + u[2] * vz < 0.0:
            u = -u
        return (float(u[0] * phi), float(u[1] * phi), float(u[2] * phi)), phi
    return (f * vx, f * vy, f * vz), phi


def euler_parameters(Q: np.ndarray) -> np.ndarray:
    """Euler parameters (r, r0) = (sin(phi/2) u, cos(phi/2)), Eqs. (2.11)-(2.12), with r0 >= 0."""
    u, phi = natural_invariants(Q)
    return np.concatenate([np.sin(0.5 * phi) * u, [np.cos(0.5 * phi)]])


def rotation_from_invariants(u: np.ndarray, phi: float) -> np.ndarray:
    """Q = u u^T + cos(phi)(1 - u u^T) + sin(phi) [u]x, Eq. (2.4)."""
    u = np.asarray(u, dtype=float) / np.linalg.norm(u)
    uu = np.outer(u, u)
    return uu + np.cos(phi) * (np.eye(3) - uu) + np.sin(phi) * cross_matrix(u)  # Eq. (2.4)


def closure_vector(Q: np.ndarray, p: np.ndarray, Q_d: np.ndarray, p_d: np.ndarray) -> np.ndarray:
    """The closure 7-vector of Eq. (2.13) for the target pose (Q_d, p_d); zero at the target.

    [2 vect(Q) - 2 u sin(phi); tr(Q) - 1 - 2 cos(phi); p - r] with u sin(phi) = vect(Q_d) and
    2 cos(phi) = tr(Q_d) - 1.
    """
    g = np.empty(7)
    g[:3] = 2.0 * (vect(Q) - vect(Q_d))  # Eq. (2.13)
    g[3] = Q.trace() - Q_d.trace()
    g[4:] = p - p_d
    return g


def closure_matrix(Q: np.ndarray) -> np.ndarray:
    """H of Eq. (2.15), 7x6, such that the closure 7-vector's rate is H t, t = [omega; pdot].

    d(2 vect Q)/dt = (tr(Q) 1 - Q) omega and d tr(Q)/dt = -2 vect(Q) . omega.
    """
    H = np.zeros((7, 6))
    H[:3, :3] = trace_form(Q)  # Eq. (2.15)
    H[3, :3] = -2.0 * vect(Q)
    H[4:, 3:] = np.eye(3)
    return H


def displacement_jacobian(Q: np.ndarray, K: np.ndarray) -> np.ndarray:
    """J = H K, Eq. (2.14): the 7 x n Jacobian of the closure 7-vector (Eqs. 4.7-4.10), by row blocks."""
    W = K[:3]
    J = np.empty((7, K.shape[1]))
    J[:3] = trace_form(Q) @ W  # Eq. (2.14) with H of Eq. (2.15)
    J[3] = -2.0 * (vect(Q) @ W)
    J[4:] = K[3:]
    return J


def displacement_jacobian_derivative(Q: np.ndarray, K: np.ndarray, dK: np.ndarray) -> np.ndarray:
    """dJ[a, i, k] = dJ[a, i]/dtheta_k for J = H K: dH/dtheta_k K + H dK/dtheta_k.

    With omega_k = K[:3, k]: d(tr Q 1 - Q)/dtheta_k = -2 (vect Q . omega_k) 1 - [omega_k]x Q and
    d(-2 vect Q)/dtheta_k = -(tr Q 1 - Q) omega_k.
    """
    n = K.shape[1]
    W = K[:3]  # angular columns omega_k (unit axes for revolute joints, 0 for prismatic)
    A = trace_form(Q)
    q = vect(Q)
    dW = dK[:3].reshape(3, n * n)
    dJ = np.empty((7, n, n))
    dJ[:3] = (A @ dW).reshape(3, n, n)  # H dK/dtheta_k, row blocks of Eq. (2.15)
    dJ[3] = (-2.0 * (q @ dW)).reshape(n, n)
    dJ[4:] = dK[3:]
    dJ[:3] -= 2.0 * (q @ W)[None, None, :] * W[:, :, None]
    # minus [a, i, k] = (omega_k x (Q omega_i))_a = eps_abc W[b, k] (Q W)[c, i], as two matrix products
    dJ[:3] -= (Q @ W).T @ (_EPS_T @ W).reshape(3, 3, n)  # broadcasts over a
    dJ[3] -= W.T @ (A @ W)  # [i, k] = omega_i . (tr Q 1 - Q) omega_k
    return dJ


def displacement_lambda(Q: np.ndarray, K: np.ndarray, lam: np.ndarray, contract_dK) -> np.ndarray:
    """Lambda = d(J^T lam)/dtheta at fixed lam for J = H K (Eqs. 4.20, 4.26), without the tensor dJ.

    ``contract_dK(mu)`` returns sum_a mu_a dK[a, i, k] (e.g. ``HessianContraction.contract``).
    Lambda = contract_dK(mu) - W^T G W with W = K[:3] and (mu, G) of :func:`lambda_parts_floats`: the
    same derivatives as :func:`displacement_jacobian_derivative`, contracted first (one (n, n) result
    instead of the 7 n^2 tensor). lam = [l3; l4; lp] holds the closure 7-vector's multipliers.
    """
    W = K[:3]
    m, G = lambda_parts_floats(Q.tolist(), trace_form(Q).tolist(), lam[:3].tolist(), float(lam[3]), vect(Q).tolist())
    mu = np.array([*m, *lam[4:].tolist()])  # mu = H^T lam, Eq. (2.15)
    return contract_dK(mu) - W.T @ (np.array(G) @ W)  # Eq. (4.20)


def lambda_parts_floats(Q, A, l3, l4: float, v) -> tuple[tuple, tuple]:
    """(m, G) with d(J^T lam)/dtheta = contract_dK([m; lp]) - W^T G W, lam = [l3; l4; lp] (Eqs. 4.20, 4.26).

    With A = tr(Q) 1 - Q and v = vect(Q) (Eqs. 2.8, 2.15): J^T lam = K^T mu, mu = H^T lam =
    [A^T l3 - 2 l4 v; lp]; moving Q by omega_k changes A by dA_k = -2 (v . omega_k) 1 - [omega_k]x Q and
    v by A omega_k / 2, so d(W^T (A^T l3 - 2 l4 v))/dtheta_k at fixed W adds -W^T G omega_k with
    G = Q^T [l3]x + 2 l3 v^T + l4 A.

    In Python floats (a dozen numpy calls cost more on arrays this small): Q and A as three rows of
    three, l3 and v as three floats; returns m = A^T l3 - 2 l4 v (three floats) and G (three rows).
    """
    (q00, q01, q02), (q10, q11, q12), (q20, q21, q22) = Q
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = A
    (l0, l1, l2), (v0, v1, v2) = l3, v
    m = (l0 * a00 + l1 * a10 + l2 * a20 - 2.0 * l4 * v0,  # H^T lam, angular part: A^T l3 - 2 l4 v (Eq. 2.15)
         l0 * a01 + l1 * a11 + l2 * a21 - 2.0 * l4 * v1,
         l0 * a02 + l1 * a12 + l2 * a22 - 2.0 * l4 * v2)
    # row i of Q^T [l3]x is (Q e_i) x l3; then + 2 l3 v^T + l4 A
    G = ((q10 * l2 - q20 * l1 + 2.0 * l0 * v0 + l4 * a00, q20 * l0 - q00 * l2 + 2.0 * l0 * v1 + l4 * a01,
          q00 * l1 - q10 * l0 + 2.0 * l0 * v2 + l4 * a02),
         (q11 * l2 - q21 * l1 + 2.0 * l1 * v0 + l4 * a10, q21 * l0 - q01 * l2 + 2.0 * l1 * v1 + l4 * a11,
          q01 * l1 - q11 * l0 + 2.0 * l1 * v2 + l4 * a12),
         (q12 * l2 - q22 * l1 + 2.0 * l2 * v0 + l4 * a20, q22 * l0 - q02 * l2 + 2.0 * l2 * v1 + l4 * a21,
          q02 * l1 - q12 * l0 + 2.0 * l2 * v2 + l4 * a22))
    return m, G


def contract(lam: np.ndarray, dK: np.ndarray) -> np.ndarray:
    """d(K^T lam)/dtheta with lam fixed: sum_a lam_a dK[a, i, k] (Eq. 4.20 / 4.42), shape (n, n)."""
    m, n, _ = dK.shape
    return (lam @ dK.reshape(m, n * n)).reshape(n, n)


def appendix_e_tensor(K: np.ndarray, revolute: np.ndarray | None = None) -> np.ndarray:
    """dK/dtheta from K alone, the closed forms of Eqs. (4.40)-(4.41) and Appendix E (E.7, E.15).

    For a serial chain with columns K_i = [A_i; B_i] (A_i = e_i, B_i = e_i x r_i for revolute joints;
    A_i = 0, B_i = e_i for prismatic ones), ordered from base to tip:

        dA_i/dtheta_j = A_j x A_i  (j < i),   0  (j >= i)            Eq. (4.40), (E.7)
        dB_i/dtheta_j = A_j x B_i  (j < i),   A_i x B_j  (j >= i)     Eq. (4.41), (E.15)

    Returns dK[a, i, j] = dK[a, i]/dtheta_j, shape (6, n, n).
    """
    A, B = K[:3].T, K[3:].T  # (n, 3)
    if revolute is not None:
        A = A * np.asarray(revolute, dtype=float)[:, None]
    n = A.shape[0]
    lower = np.tril(np.ones((n, n)), -1)[:, :, None]  # [i, j] = 1 where j < i
    AjAi = np.cross(A[None, :, :], A[:, None, :])  # [i, j] = A_j x A_i
    AjBi = np.cross(A[None, :, :], B[:, None, :])  # [i, j] = A_j x B_i
    AiBj = np.cross(A[:, None, :], B[None, :, :])  # [i, j] = A_i x B_j
    dA = lower * AjAi  # Eq. (E.7)
    dB = lower * AjBi + (1.0 - lower) * AiBj  # Eq. (E.15)
    return np.concatenate([dA, dB], axis=2).transpose(2, 0, 1)
