"""Positioning of the wrist centre of the PUMA-derived arm: theta1 and theta2 in closed form (Chapter 3).

The arm of Table 3.1 (``kinredund.model.catalog.puma7``) has axis 1 vertical and axes 2-4 parallel and
horizontal, so links 2-4 move in one vertical plane, offset by the shoulder offset d from axis 1. The
positioning problem of Section 3.1.1 then splits into

- theta1, Eqs. (3.3)-(3.7): turn the arm plane so that it contains the wrist centre O_w. The foot point
  O2' = (x', y') of the plane on the shoulder circle x'^2 + y'^2 = d^2 solves the quadratic Eq. (3.6);
  its two roots are the two branches of theta1 (``front``: the arm plane's x axis points at the wrist,
  xi >= 0; ``back``: reaching over the top, xi < 0). Imaginary roots mean O_w lies inside the inner
  cylinder of radius |d| about axis 1 (Fig. 3.4): :class:`UnreachableError`.
- the planar 3R problem in frame 2: the wrist centre at (xi, eta), Eqs. (3.14)-(3.15), which fixes
  rho^2 = xi^2 + eta^2 and leaves one constraint on (theta3, theta4), Eqs. (3.25)-(3.29), solved in
  :mod:`kinredund.closed_form.redundancy`; theta2 then follows from Eqs. (3.17)-(3.24).

Sign convention: our HD row 2 carries the offset as b2 = d along z2 = (sin theta1, -cos theta1, 0), so
O2' = d (sin theta1, -cos theta1) and theta1 = atan2(x'/d, -y'/d) = atan2(y', x') + pi/2 for d > 0;
the thesis's "- pi/2" in Eq. (3.7) measures d the other way.

Units: lengths [m], angles [rad]. Angles here are the HD angles theta_i (joint value + theta0_i).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kinredund.errors import HDTableError, KinredundError
from kinredund.kinematics.hd import HDTable

#: HD twist angles alpha_i [deg] of the Chapter 3 architecture (PUMA7_NOTES in kinredund.model.catalog)
ARCHITECTURE_ALPHA_DEG = (90.0, 0.0, 0.0, 90.0, -90.0, 90.0)
_TOL = 1e-12


class UnreachableError(KinredundError, ValueError):
    """A wrist-centre position the arm cannot reach; ``reason`` says which boundary it violates.

    Attributes:
        position: the wrist-centre position [m].
        reason: ``inner_cylinder`` (inside the cylinder of radius |d| about axis 1, Fig. 3.4: the
            roots of Eq. (3.6) are imaginary), ``outer_reach`` (farther than a2 + a3 + a4 from axis 2)
            or ``inner_reach`` (closer to axis 2 than links 2-4 can fold).
    """

    def __init__(self, message: str, *, position, reason: str):
        self.position = [float(v) for v in position]
        self.reason = reason
        super().__init__(message)


@dataclass(frozen=True)
class ArmGeometry:
    """The dimensions of the Chapter 3 arm that the closed form uses (Table 3.1).

    Attributes:
        b1: height of axis 2 above the base [m] (first link, vertical).
        d: shoulder offset [m], the sum b2 + b3 + b4 of offsets along the parallel axes 2-4.
        a2, a3, a4: lengths of links 2-4 [m] (a4 ends at the wrist centre).
        alpha7: twist of the last row [rad] (only turns the end-effector frame).
        theta0: HD angle offsets [rad], theta_i = q_i + theta0_i, shape (7,).
    """

    b1: float
    d: float
    a2: float
    a3: float
    a4: float
    alpha7: float
    theta0: tuple[float, ...]

    @classmethod
    def from_hd(cls, table: HDTable | None) -> ArmGeometry:
        """Read the dimensions from an HD table, checking that it has the Chapter 3 architecture.

        Raises:
            HDTableError: the table is missing, or is not a 7-axis revolute arm with axis 1
                vertical, axes 2-4 parallel and a spherical wrist at point P (``PUMA7_NOTES``).
        """
        expected = (
            "7 revolute axes with alpha_1..6 = (90, 0, 0, 90, -90, 90) deg, a1 = a5 = a6 = a7 = 0, "
            "b5 = b6 = b7 = 0 and a2, a3, a4 > 0 (see kinredund.model.catalog.PUMA7_NOTES)"
        )
        if table is None:
            raise HDTableError(f"the closed-form solver needs a robot built from an HD table with {expected}")
        problems = []
        if table.n != 7 or table.kinds != "R" * 7:
            problems.append(f"{table.n} joints of kinds {table.kinds!r}")
        else:
            alpha = np.degrees(table.alpha[:6])
            if np.abs(alpha - ARCHITECTURE_ALPHA_DEG).max() > 1e-9:
                problems.append(f"alpha_1..6 = {np.round(alpha, 6).tolist()} deg")
            zero_a = np.abs(table.a[[0, 4, 5, 6]]).max()
            zero_b = np.abs(table.b[[4, 5, 6]]).max()
            if zero_a > _TOL or zero_b > _TOL:
                problems.append(f"a1, a5, a6, a7 = {table.a[[0, 4, 5, 6]].tolist()}, "
                                f"b5, b6, b7 = {table.b[[4, 5, 6]].tolist()}")
            if np.any(table.a[1:4] <= 0):
                problems.append(f"a2, a3, a4 = {table.a[1:4].tolist()}")
        if problems:
            raise HDTableError(f"HD table {table.name!r} does not have the Chapter 3 architecture "
                               f"({'; '.join(problems)}); the closed form needs {expected}")
        return cls(
            b1=float(table.b[0]), d=float(table.b[1] + table.b[2] + table.b[3]),
            a2=float(table.a[1]), a3=float(table.a[2]), a4=float(table.a[3]),
            alpha7=float(table.alpha[6]), theta0=tuple(float(v) for v in table.theta0),
        )

    @property
    def reach_max(self) -> float:
        """The largest distance [m] of the wrist centre from O2 in the arm plane: a2 + a3 + a4."""
        return self.a2 + self.a3 + self.a4

    @property
    def reach_min(self) -> float:
        """The smallest such distance [m]: max(0, 2 max(a2, a3, a4) - (a2 + a3 + a4))."""
        return max(0.0, 2.0 * max(self.a2, self.a3, self.a4) - self.reach_max)

    def constraint_coefficients(self, rho2: float) -> tuple[float, float, float, float]:
        """(A, B, C, D) of Eqs. (3.26)-(3.29) for rho^2 = xi^2 + eta^2 [m^2]."""
        a2, a3, a4 = self.a2, self.a3, self.a4
        return a2 * a2 + a3 * a3 + a4 * a4 - rho2, 2.0 * a3 * a4, 2.0 * a2 * a3, 2.0 * a2 * a4


@dataclass(frozen=True)
class ShoulderBranch:
    """One branch of theta1 (Eqs. 3.3-3.7) and the wrist centre in the arm plane (Eqs. 3.14-3.15).

    Attributes:
        theta1: HD angle of axis 1 [rad].
        foot: (x', y') [m], the point O2' of Eqs. (3.5)-(3.6) (zero when d = 0).
        xi, eta: coordinates [m] of the wrist centre in frame 2, Eqs. (3.14)-(3.15).
        label: ``front`` (xi >= 0) or ``back``.
        axis1_singular: the wrist centre is on axis 1 with d = 0, so theta1 is free (set to the hint).
    """

    theta1: float
    foot: tuple[float, float]
    xi: float
    eta: float
    label: str
    axis1_singular: bool = False


def _stable_quadratic(a: float, b: float, c: float, disc: float) -> tuple[float, float]:
    """Both roots of a x^2 + b x + c = 0 given disc = b^2 - 4ac >= 0, without cancellation."""
    q = -0.5 * (b + math.copysign(math.sqrt(max(disc, 0.0)), b))
    if q == 0.0:
        return 0.0, 0.0
    return q / a, c / q


def _inner_cylinder_error(x: float, y: float, z: float, d: float) -> UnreachableError:
    return UnreachableError(
        f"wrist centre ({x:.6g}, {y:.6g}, {z:.6g}) m is inside the inner cylinder of the workspace "
        f"(Fig. 3.4): its distance {math.hypot(x, y):.6g} m from axis 1 is less than the shoulder offset "
        f"|d| = {abs(d):.6g} m, so Eq. (3.6) has imaginary roots; reachable points have "
        "sqrt(x^2 + y^2) >= |d|",
        position=(x, y, z), reason="inner_cylinder",
    )


def foot_points(
    x: float, y: float, d: float, z: float = math.nan
) -> tuple[tuple[float, float], tuple[float, float]]:
    """The two roots (x', y') of Eqs. (3.5)-(3.6): O2' on the circle of radius |d|, with O2'O_w normal to it.

    Eq. (3.6) is (x^2 + y^2) y'^2 - 2 d^2 y y' + d^2 (d^2 - x^2) = 0 with x' = (d^2 - y y')/x, Eq. (3.5);
    when |y| > |x| the mirror quadratic in x' is solved instead (the thesis's x = 0 case, generalised),
    so the division is always by the larger coordinate. Its discriminant is
    4 d^2 x^2 (x^2 + y^2 - d^2): negative strictly inside the inner cylinder (Fig. 3.4).

    Raises:
        UnreachableError: x^2 + y^2 < d^2 (imaginary roots of Eq. 3.6).
    """
    rho2 = x * x + y * y
    d2 = d * d
    if rho2 < d2 * (1.0 - 4.0 * _TOL):
        raise _inner_cylinder_error(x, y, z, d)
    swap = abs(y) > abs(x)
    u, v = (y, x) if swap else (x, y)  # solve for the coordinate paired with the smaller one
    disc = 4.0 * d2 * u * u * max(rho2 - d2, 0.0)  # discriminant of Eq. (3.6)
    roots = _stable_quadratic(rho2, -2.0 * d2 * v, d2 * (d2 - u * u), disc)  # Eq. (3.6)
    out = []
    for w in roots:
        other = (d2 - v * w) / u  # Eq. (3.5)
        out.append((w, other) if swap else (other, w))
    return out[0], out[1]


def shoulder_branches(geom: ArmGeometry, wrist_centre, theta1_hint: float = 0.0) -> tuple[ShoulderBranch, ...]:
    """Both branches of theta1 for a wrist-centre position, front branch first (Eqs. 3.3-3.7).

    Args:
        geom: the arm's dimensions.
        wrist_centre: (x, y, z) of O_w in the base frame [m].
        theta1_hint: theta1 [rad] used when it is free (d = 0 and O_w on axis 1).

    Raises:
        UnreachableError: O_w is inside the inner cylinder (|d| > 0 only).
    """
    x, y, z = (float(v) for v in wrist_centre)
    d = geom.d
    eta = z - geom.b1  # Eq. (3.15)
    scale = max(1.0, geom.reach_max)
    if abs(d) <= _TOL * scale:
        rho = math.hypot(x, y)
        singular = rho <= _TOL * scale
        phi = theta1_hint if singular else math.atan2(y, x)  # Eq. (3.7), d = 0
        thetas = [(phi, (0.0, 0.0)), (phi + math.pi, (0.0, 0.0))]
    else:
        singular = False
        thetas = [(math.atan2(fx / d, -fy / d), (fx, fy)) for fx, fy in foot_points(x, y, d, z)]  # Eq. (3.7)
    out = []
    for theta1, foot in thetas:
        theta1 = math.remainder(theta1, 2.0 * math.pi)
        xi = x * math.cos(theta1) + y * math.sin(theta1)  # Eq. (3.14)
        out.append(ShoulderBranch(theta1, foot, xi, eta, "front" if xi >= 0.0 else "back", singular))
    if out[0].label == "back" and out[1].label == "front":
        out.reverse()
    if out[0].label == out[1].label:  # on the inner cylinder: one double root, xi = 0
        out[1] = ShoulderBranch(out[1].theta1, out[1].foot, out[1].xi, eta, "back", singular)
    return tuple(out)


def plane_radius2(geom: ArmGeometry, wrist_centre) -> float:
    """rho^2 = xi^2 + eta^2 [m^2], the same for both theta1 branches, after checking the reach.

    Raises:
        UnreachableError: O_w is inside the inner cylinder, beyond the outer reach a2 + a3 + a4 of
            links 2-4 about O2, or inside their inner reach.
    """
    x, y, z = (float(v) for v in wrist_centre)
    h2 = x * x + y * y - geom.d * geom.d
    if h2 < -4.0 * _TOL * geom.d * geom.d:
        raise _inner_cylinder_error(x, y, z, geom.d)
    rho2 = max(h2, 0.0) + (z - geom.b1) ** 2  # xi^2 + eta^2, Eqs. (3.14)-(3.15)
    rho = math.sqrt(rho2)
    hi, lo = geom.reach_max, geom.reach_min
    if rho > hi * (1.0 + _TOL):
        raise UnreachableError(
            f"wrist centre ({x:.6g}, {y:.6g}, {z:.6g}) m is beyond the outer reach: it is {rho:.6g} m from the "
            f"shoulder circle, and links 2-4 reach at most a2 + a3 + a4 = {hi:.6g} m",
            position=(x, y, z), reason="outer_reach",
        )
    if rho < lo * (1.0 - _TOL):
        raise UnreachableError(
            f"wrist centre ({x:.6g}, {y:.6g}, {z:.6g}) m is inside the inner reach: it is {rho:.6g} m from the "
            f"shoulder circle, and links 2-4 cannot fold closer than {lo:.6g} m",
            position=(x, y, z), reason="inner_reach",
        )
    return min(max(rho2, lo * lo), hi * hi)


def theta2_from(geom: ArmGeometry, xi: float, eta: float, theta3: float, theta4: float) -> float:
    """theta2 [rad] from Eqs. (3.17)-(3.24), given theta3 and theta4 (HD angles).

    Returns 0 when xi = eta = 0 (the wrist centre on axis 2: theta2 is then free).
    """
    K1 = geom.a4 * math.cos(theta3 + theta4)  # Eq. (3.22)
    K2 = geom.a4 * math.sin(theta3 + theta4)  # Eq. (3.23)
    a3c3, a3s3 = geom.a3 * math.cos(theta3), geom.a3 * math.sin(theta3)
    n_s = K1 * eta - K2 * xi + eta * a3c3 - xi * a3s3 + geom.a2 * eta  # Eq. (3.19)
    n_c = K1 * xi + K2 * eta + xi * a3c3 + eta * a3s3 + geom.a2 * xi  # Eq. (3.20)
    return math.atan2(n_s, n_c)  # Eq. (3.24); sin and cos share the denominator D of Eq. (3.21)

