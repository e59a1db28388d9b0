"""The spherical wrist of the Chapter 3 arm in closed form (Section 3.1; rows 5-7 of PUMA7_NOTES).

The thesis leaves the wrist to "any standard procedure" (Section 3.1). Our rows 5-7 have
alpha = (-90, 90, alpha7) deg and a = b = 0, so

    Q5 Q6 Q7 = Rz(theta5) Rx(-pi/2) Rz(theta6) Rx(pi/2) Rz(theta7) Rx(alpha7)
             = Rz(theta5) Ry(theta6) Rz(theta7) Rx(alpha7),

a ZYZ Euler-angle wrist: with W = (Q1 Q2 Q3 Q4)^T Q_d Rx(alpha7)^T,

    cos theta6 = W33,   sin theta6 = +-sqrt(W13^2 + W23^2),   theta5 = atan2(W23 / s6, W13 / s6),

and theta7 from Rz(theta7) = Ry(-theta6) Rz(-theta5) W (rather than atan2(W32 / s6, -W31 / s6), which
loses the consistency of theta5 and theta7 near the singularity).

The two signs of sin theta6 are the two wrist branches (``theta6+``, ``theta6-``). Where
sin theta6 = 0 axes 5 and 7 are aligned (the wrist singularity): only theta5 + theta7 (cos theta6 = 1)
or theta5 - theta7 (cos theta6 = -1) is determined; theta5 is then set to a hint and the solution is
flagged ``singular``.

Units: angles [rad].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class WristSolution:
    """One wrist branch.

    Attributes:
        theta5, theta6, theta7: HD angles [rad].
        label: ``theta6+``, ``theta6-`` or ``singular``.
        sin_theta6: |sin theta6| = |det [e5 e6 e7]|, the distance from the wrist singularity.
        singular: |sin theta6| below the solver's tolerance.
    """

    theta5: float
    theta6: float
    theta7: float
    label: str
    sin_theta6: float
    singular: bool


def rot_x(angle: float) -> np.ndarray:
    """Rotation by ``angle`` [rad] about x."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def zyz(theta5: float, theta6: float, theta7: float) -> np.ndarray:
    """Rz(theta5) Ry(theta6) Rz(theta7)."""
    c5, s5, c6, s6, c7, s7 = (f(a) for a in (theta5, theta6, theta7) for f in (math.cos, math.sin))
    return np.array([
        [c5 * c6 * c7 - s5 * s7, -c5 * c6 * s7 - s5 * c7, c5 * s6],
        [s5 * c6 * c7 + c5 * s7, -s5 * c6 * s7 + c5 * c7, s5 * s6],
        [-s6 * c7, s6 * s7, c6],
    ])


def solve_wrist(W: np.ndarray, theta5_hint: float = 0.0, singular_tol: float = 1e-8) -> tuple[WristSolution, ...]:
    """Both wrist branches for W = Rz(theta5) Ry(theta6) Rz(theta7), ``theta6+`` first.

    Args:
        W: the rotation the wrist must produce, 3x3.
        theta5_hint: theta5 [rad] used at the singularity, where only theta5 +- theta7 is determined.
        singular_tol: |sin theta6| below which the solution is flagged singular.

    Returns:
        Two solutions, or one labelled ``singular`` when sin theta6 vanishes to rounding.
    """
    s6 = math.hypot(W[0, 2], W[1, 2])
    c6 = float(W[2, 2])
    if s6 <= 1e-14:  # exactly singular: axes 5 and 7 aligned, theta5 from the hint
        options = [(math.remainder(theta5_hint, 2.0 * math.pi), 0.0 if c6 > 0.0 else math.pi, "singular")]
    else:
        options = [(math.atan2(W[1, 2], W[0, 2]), math.atan2(s6, c6), "theta6+"),
                   (math.atan2(-W[1, 2], -W[0, 2]), math.atan2(-s6, c6), "theta6-")]
    out = []
    for t5, t6, label in options:
        # theta7 from Rz(theta7) = Ry(-theta6) Rz(-theta5) W: consistent with theta5 even where
        # theta5 alone is ill-conditioned (sin theta6 ~ 0), so the product stays exact
        M = zyz(0.0, -t6, 0.0) @ zyz(-t5, 0.0, 0.0) @ W
        t7 = math.atan2(M[1, 0], M[0, 0])
        out.append(WristSolution(t5, t6, t7, label, s6, s6 < singular_tol))
    return tuple(out)
