"""Hartenberg-Denavit tables in the thesis's convention (Chapter 2, Eqs. 2.1-2.3).

Link i carries frame i and joint i turns (or slides) about z_i. The frame-to-frame transform is

    Q_i = Rz(theta_i) Rx(alpha_i),        [a_i]_i = (a_i cos theta_i, a_i sin theta_i, b_i)   Eqs. (2.1)-(2.2)

so that the end point is p = a_1 + Q_1 a_2 + Q_1 Q_2 a_3 + ... (Eq. 2.3) and the end-effector rotation
is Q = Q_1 ... Q_n. For a revolute joint theta_i = q_i + theta0_i; for a prismatic one b_i = q_i + b_i
(theta_i = theta0_i fixed). This is the classical (distal) Denavit-Hartenberg form
Rz(theta) Tz(b) Tx(a) Rx(alpha).

Notation: alpha [rad], a [m], b [m], theta0 [rad]; joint limits [rad] or [m].
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from kinredund.errors import HDTableError, check_array

REVOLUTE = "R"
PRISMATIC = "P"
JOINT_KINDS = (REVOLUTE, PRISMATIC)


def _row(name: str, values, n: int | None) -> np.ndarray:
    """One finite HD column (n,) (any length for alpha, n = None), or :class:`HDTableError`."""
    owner = "" if n is None else f"{n} joints (alpha's length)"
    return check_array(values, (n,), f"HD column {name!r}", HDTableError, owner)


@dataclass(frozen=True)
class HDTable:
    """A manipulator's architecture as 3n Hartenberg-Denavit parameters plus joint kinds and limits.

    Args:
        alpha: twist angles alpha_i [rad], shape (n,).
        a: link lengths a_i [m], shape (n,).
        b: offsets b_i [m], shape (n,); for a prismatic joint, the offset at q_i = 0.
        kinds: joint kinds, a string or sequence of "R" (revolute) and "P" (prismatic); default all "R".
        theta0: joint-angle offsets [rad], theta_i = q_i + theta0_i; default zeros.
        lower, upper: joint limits [rad or m]; default -pi, pi for revolute and -1, 1 m for prismatic.
        name: a short name, used for the URDF robot name.
    """

    alpha: np.ndarray
    a: np.ndarray
    b: np.ndarray
    kinds: str = ""
    theta0: np.ndarray | None = None
    lower: np.ndarray | None = None
    upper: np.ndarray | None = None
    name: str = "hd_arm"
    notes: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        alpha = _row("alpha", self.alpha, None)
        n = alpha.shape[0]
        if n == 0:
            raise HDTableError("an HD table needs at least one joint (alpha is empty)")
        kinds = "".join(self.kinds) if self.kinds else REVOLUTE * n
        kinds = kinds.upper()
        if len(kinds) != n or any(k not in JOINT_KINDS for k in kinds):
            raise HDTableError(
                f"joint kinds {self.kinds!r} must be {n} letters, each one of {', '.join(JOINT_KINDS)}"
            )
        default_lo = np.where(np.array(list(kinds)) == REVOLUTE, -np.pi, -1.0)
        lower = default_lo if self.lower is None else _row("lower", self.lower, n)
        upper = -default_lo if self.upper is None else _row("upper", self.upper, n)
        if np.any(lower >= upper):
            raise HDTableError(f"joint limits need lower < upper, got lower={lower}, upper={upper}")
        object.__setattr__(self, "alpha", alpha)
        object.__setattr__(self, "a", _row("a", self.a, n))
        object.__setattr__(self, "b", _row("b", self.b, n))
        object.__setattr__(self, "kinds", kinds)
        object.__setattr__(self, "theta0", np.zeros(n) if self.theta0 is None else _row("theta0", self.theta0, n))
        object.__setattr__(self, "lower", lower)
        object.__setattr__(self, "upper", upper)

    @property
    def n(self) -> int:
        """The number of joints."""
        return self.alpha.shape[0]

    def link_transform(self, i: int, qi: float) -> np.ndarray:
        """The 4x4 transform from frame i to frame i+1 (0-based i): Eqs. (2.1)-(2.2)."""
        theta = self.theta0[i] + (qi if self.kinds[i] == REVOLUTE else 0.0)
        b = self.b[i] + (qi if self.kinds[i] == PRISMATIC else 0.0)
        ct, st = np.cos(theta), np.sin(theta)
        ca, sa = np.cos(self.alpha[i]), np.sin(self.alpha[i])
        T = np.eye(4)
        T[:3, :3] = [[ct, -ca * st, sa * st], [st, ca * ct, -sa * ct], [0.0, sa, ca]]  # Eq. (2.1)
        T[:3, 3] = [self.a[i] * ct, self.a[i] * st, b]  # Eq. (2.2)
        return T

    def fk(self, q) -> np.ndarray:
        """End-effector pose by the HD product, Eq. (2.3): a plain reference used by the tests."""
        q = np.asarray(q, dtype=float)
        T = np.eye(4)
        for i in range(self.n):
            T = T @ self.link_transform(i, q[i])
        return T

    def fixed_transform(self, i: int) -> np.ndarray:
        """The joint-independent part Tz(b_i) Tx(a_i) Rx(alpha_i) that follows joint i (and Rz(theta0_i))."""
        theta0 = self.theta0[i]
        ct, st = np.cos(theta0), np.sin(theta0)
        Rz = np.array([[ct, -st, 0.0], [st, ct, 0.0], [0.0, 0.0, 1.0]])
        T = np.eye(4)
        T[:3, :3] = Rz
        ca, sa = np.cos(self.alpha[i]), np.sin(self.alpha[i])
        rest = np.eye(4)
        rest[:3, :3] = [[1.0, 0.0, 0.0], [0.0, ca, -sa], [0.0, sa, ca]]
        rest[:3, 3] = [self.a[i], 0.0, self.b[i]]
        return T @ rest
