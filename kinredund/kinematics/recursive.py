"""The recursive velocity Jacobian of Chapter 5 (Eqs. 5.1-5.21): K from an HD table, without Pinocchio.

An alternative path to the velocity Jacobian K of Eq. (2.16), in plain numpy, following the recursive
scheme that Chapter 5 counts operations for (see :mod:`kinredund.kinematics.opcount`). All vectors are in base
(first-frame) coordinates:

- the rotation products P_i = Q_1 Q_2 ... Q_i, computed recursively as P_i = P_(i-1) Q_i with the
  column formulas of Eqs. (5.3)-(5.16) (24 multiplications and 12 additions each);
- the joint axes e_i: the third column of P_(i-1) (e_1 = (0, 0, 1));
- the vectors r_i from the origin O_i (a point of axis i) to the end point P, by the Horner-like
  recursion of Eq. (5.17), [r_i]_i = [a_i]_i + Q_i [r_(i+1)]_(i+1), then taken to the base frame,
  Eq. (5.18), [r_i]_1 = P_(i-1) [r_i]_i;
- the columns of K: [e_i; e_i x r_i] for a revolute joint and [0; e_i] for a prismatic one (Eq. 2.16).

The HD convention is the thesis's (see :mod:`kinredund.kinematics.hd`): Q_i = Rz(theta_i) Rx(alpha_i) and
[a_i]_i = (a_i cos theta_i, a_i sin theta_i, b_i), Eqs. (2.1)-(2.2).

Units: q [rad or m], lengths [m]; K's angular rows are dimensionless, its linear rows [m/rad] or [1].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kinredund.errors import HDTableError, check_joint_vector
from kinredund.kinematics.hd import PRISMATIC, HDTable


@dataclass(frozen=True)
class RecursiveKinematics:
    """What the recursion of Eqs. (5.1)-(5.21) produces at one configuration.

    Attributes:
        P: rotation products, shape (n + 1, 3, 3); P[0] = 1 and P[i] = Q_1 ... Q_i (Eq. 5.1).
        e: unit vectors of the joint axes in the base frame, shape (n, 3); e[i] = P[i][:, 2].
        r: vectors from O_i to the end point P in the base frame [m], shape (n, 3) (Eqs. 5.17-5.21).
        p: the end point P [m], shape (3,) (p = r_1 + O_1 with O_1 at the base origin, Eq. 2.3).
        K: the velocity Jacobian, shape (6, n), rows [omega; pdot] (Eq. 2.16).
    """

    P: np.ndarray
    e: np.ndarray
    r: np.ndarray
    p: np.ndarray
    K: np.ndarray

    @property
    def Q(self) -> np.ndarray:
        """The end-effector rotation Q = Q_1 ... Q_n."""
        return self.P[-1]


def _check(table: HDTable, q) -> np.ndarray:
    if not isinstance(table, HDTable):
        raise HDTableError(
            f"the recursive Jacobian needs an HDTable (robot.hd), got {type(table).__name__}; "
            "URDF robots without an HD table have robot.hd = None"
        )
    return check_joint_vector(q, table.n, table.name)


def _joint_values(table: HDTable, q: np.ndarray) -> tuple[list[float], list[float], list[bool]]:
    """(theta, b, prismatic): theta_i = q_i + theta0_i (revolute), b_i = b_i + q_i (prismatic), Eq. (2.2)."""
    prismatic = [k == PRISMATIC for k in table.kinds]
    qs = q.tolist()
    theta = [t0 + (0.0 if pr else qi) for t0, qi, pr in zip(table.theta0.tolist(), qs, prismatic, strict=True)]
    b = [b0 + (qi if pr else 0.0) for b0, qi, pr in zip(table.b.tolist(), qs, prismatic, strict=True)]
    return theta, b, prismatic


def rotation_products(table: HDTable, q) -> np.ndarray:
    """P_i = Q_1 ... Q_i for i = 0..n, by the recursion of Eqs. (5.1)-(5.16); shape (n + 1, 3, 3).

    Each step forms P_i = P_(i-1) Q_i (Eq. 5.2) from the columns [p_1 p_2 p_3] of P_(i-1) with
    lambda = cos(alpha_i), mu = sin(alpha_i):

        u = p_1 sin(theta_i) - p_2 cos(theta_i)                      Eqs. (5.5)-(5.7)
        P_i = [p_1 cos(theta_i) + p_2 sin(theta_i),  mu p_3 - lambda u,  mu u + lambda p_3]
                                                                     Eqs. (5.8)-(5.16)

    Raises:
        HDTableError: ``table`` is not an HDTable.
        JointVectorError: ``q`` has the wrong shape or non-finite entries.
    """
    q = _check(table, q)
    theta = _joint_values(table, q)[0]
    ct, st = [math.cos(t) for t in theta], [math.sin(t) for t in theta]
    P = _products(ct, st, _cos_alpha(table), _sin_alpha(table))
    return np.array(P).reshape(table.n + 1, 3, 3)


def _cos_alpha(table: HDTable) -> list[float]:
    return np.cos(table.alpha).tolist()


def _sin_alpha(table: HDTable) -> list[float]:
    return np.sin(table.alpha).tolist()


def _products(ct: list[float], st: list[float], lam: list[float], mu: list[float]) -> list[tuple]:
    """Row-major 9-tuples of P_0 = 1, P_1, ..., P_n (scalar arithmetic: faster than numpy at 3x3)."""
    P = [(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)]
    for c, s, lm, m in zip(ct, st, lam, mu, strict=True):  # Eq. (5.2): P_i = P_(i-1) Q_i
        p11, p12, p13, p21, p22, p23, p31, p32, p33 = P[-1]
        u1, u2, u3 = p11 * s - p12 * c, p21 * s - p22 * c, p31 * s - p32 * c  # Eqs. (5.5)-(5.7)
        P.append((
            p11 * c + p12 * s, m * p13 - lm * u1, m * u1 + lm * p13,  # Eqs. (5.8), (5.11), (5.14)
            p21 * c + p22 * s, m * p23 - lm * u2, m * u2 + lm * p23,  # Eqs. (5.9), (5.12), (5.15)
            p31 * c + p32 * s, m * p33 - lm * u3, m * u3 + lm * p33,  # Eqs. (5.10), (5.13), (5.16)
        ))
    return P


def _recursion(table: HDTable, q: np.ndarray) -> tuple[list[tuple], np.ndarray]:
    """(P as row-major 9-tuples, the (n, 9) array of e_i, r_i and e_i x r_i) by Eqs. (5.1)-(5.21)."""
    theta, b, prismatic = _joint_values(table, q)
    n = table.n
    ct, st = [math.cos(t) for t in theta], [math.sin(t) for t in theta]
    lam, mu = _cos_alpha(table), _sin_alpha(table)
    a = table.a.tolist()
    P = _products(ct, st, lam, mu)
    # Eq. (5.17): Horner-like recursion from the tip, [r_i]_i = [a_i]_i + Q_i [r_(i+1)]_(i+1),
    # with [a_i]_i = (a_i cos theta_i, a_i sin theta_i, b_i) (Eq. 2.2) and Q_i = Rz(theta_i) Rx(alpha_i)
    x = y = z = 0.0
    r_local = [None] * n
    for i in range(n - 1, -1, -1):
        y, z = lam[i] * y - mu[i] * z, mu[i] * y + lam[i] * z  # Rx(alpha_i) [r_(i+1)]_(i+1)
        x, y = ct[i] * x - st[i] * y, st[i] * x + ct[i] * y  # Rz(theta_i) (...)
        x, y, z = x + a[i] * ct[i], y + a[i] * st[i], z + b[i]  # + [a_i]_i
        r_local[i] = (x, y, z)
    rows = []
    for i in range(n):
        p11, p12, p13, p21, p22, p23, p31, p32, p33 = P[i]
        x, y, z = r_local[i]
        # Eq. (5.18): [r_i]_1 = P_(i-1) [r_i]_i; e_i = (p13, p23, p33) is the third column of P_(i-1)
        r1, r2, r3 = p11 * x + p12 * y + p13 * z, p21 * x + p22 * y + p23 * z, p31 * x + p32 * y + p33 * z
        if prismatic[i]:  # Eq. (2.16): [0; e_i] for a prismatic joint
            rows.append((p13, p23, p33, r1, r2, r3, 0.0, 0.0, 0.0, p13, p23, p33))
        else:  # [e_i; e_i x r_i] for a revolute joint
            rows.append((p13, p23, p33, r1, r2, r3, p13, p23, p33,
                         p23 * r3 - p33 * r2, p33 * r1 - p13 * r3, p13 * r2 - p23 * r1))
    return P, np.array(rows)


def recursive_kinematics(table: HDTable, q) -> RecursiveKinematics:
    """P_i, e_i, r_i, p and K at q by the recursive scheme of Eqs. (5.1)-(5.21).

    Args:
        table: the robot's HD table (``robot.hd``).
        q: joint values, shape (n,) [rad or m].

    Returns:
        A :class:`RecursiveKinematics` record.

    Raises:
        HDTableError: ``table`` is not an HDTable.
        JointVectorError: ``q`` has the wrong shape or non-finite entries.
    """
    P, rows = _recursion(table, _check(table, q))
    return RecursiveKinematics(
        P=np.array(P).reshape(table.n + 1, 3, 3), e=rows[:, 0:3], r=rows[:, 3:6], p=rows[0, 3:6].copy(),
        K=rows[:, 6:].T.copy(),
    )


def recursive_jacobian(table: HDTable, q) -> np.ndarray:
    """The velocity Jacobian K (6 x n, rows [omega; pdot]) by the recursion of Eqs. (5.1)-(5.21).

    Equals ``robot.velocity_jacobian(q)`` (Pinocchio) for a robot built from ``table``.

    Raises:
        HDTableError: ``table`` is not an HDTable.
        JointVectorError: ``q`` has the wrong shape or non-finite entries.
    """
    return _recursion(table, _check(table, q))[1][:, 6:].T.copy()
