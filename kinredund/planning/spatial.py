"""Section 6.3: the spatial case - an arm of the CYBOTECH P-15 architecture around an elliptic cylinder.

- :func:`scaled_p15`: Table 4.1's architecture (the twists alpha) with every length multiplied by one
  scale factor. Table 4.1's lengths reach about 0.5 m; the task of Eqs. (6.45)-(6.50) lies 1.4-2.4 m
  from the base at a height of 1.19-1.37 m, so the thesis's example cannot have used them.
- :func:`section_path`: the trajectory, the intersection of the cylinder with an inclined plane,
  Eqs. (6.46)-(6.50):

      x = x_d cos psi - y_d sin psi + x0,   y = x_d sin psi + y_d cos psi + y0,   z = a cos(beta) sin(gamma) + h
      x_d = a cos(beta) cos(gamma),         y_d = b sin(beta)

  with gamma = 10 deg, psi = 0, h = 1.278 m, a = 0.508 m, b = 0.25 m, (x0, y0) = (1.9, 0) m and
  beta = start + rate t. The OCR of y_d reads "b sin beta cos gamma"; we drop the cos gamma because the
  thesis then states that the projection's semi-axes are 0.5 m and 0.25 m (a cos gamma = 0.5 m, and
  b = 0.25 m only without it), which also makes the curve lie on the cylinder whose directrix is that
  projection. The curve lies in the plane x - cot(gamma) z + (h cot(gamma) - x0) = 0, i.e.
  x - 5.671 z + 5.348 = 0; Eq. (6.45) prints 5.4, about 9 mm higher - within the OCR's rounding.
- :func:`section_cylinder`: the obstacle, the elliptic cylinder with semi-axes (a cos gamma, b) about the
  vertical axis through (x0, y0), from the floor z = 0 up to the cutting plane: the path is the rim of
  its inclined top ("the trajectory is the curve formed by the intersection of a plane and the
  cylinder"; "the whole surface of the cylinder is the obstacle"). A cylinder that went on above the
  plane, with the path on its side, admits no collision-free cyclic motion of this arm at any scale we
  tried (8-16): the arm cannot get over it.
- :func:`arm_plane_semi_axis_discriminant` and :func:`link2_semi_axis_discriminant`: the thesis's route
  to b - substitute the link's line into the ellipse and make the quadratic's discriminant vanish
  (Eqs. 6.7-6.15 and 6.30-6.36) - solved numerically, to check the closed form used by the policy.
- :func:`link4_direction_thesis`: the direction cosines of Eqs. (6.40)-(6.42) as read from the OCR,
  L = sgn(b5) (-c1 c23 s4 - s1 c4, c1 c4 - s1 c23 s4, -s23 s4), c23 = cos(theta2 + theta3). The model
  of Table 4.1 (alpha2 = 180 deg: axis 3 antiparallel to axis 2) gives instead
  L = (c1 c(2-3) s4 - s1 c4, s1 c(2-3) s4 + c1 c4, s(2-3) s4). Searching the twist signs (tests): the
  printed formula is the model's for alpha2 = 0 only, and then up to the overall sign - exactly for
  alpha = (90, 0, -90, -90, ...) deg, or for Table 4.1's alpha4 = +90 deg with b5 < 0. The policy uses
  the model's direction, not the printed formula.

Units: lengths [m], angles [rad].
"""

from __future__ import annotations

import math

import numpy as np

from kinredund.errors import TaskError, check_positive
from kinredund.model.catalog import P15_SCALE, cybotech_p15_scaled
from kinredund.model.robot import Robot, robot_from_hd
from kinredund.paths import FunctionPath
from kinredund.planning.clearance import link_model
from kinredund.planning.obstacles import EllipticCylinder, Obstacle, cut_cylinder
from kinredund.planning.policy import SpatialPolicy

#: Eqs. (6.49)-(6.50) and the cylinder's axis
GAMMA = math.radians(10.0)
PSI = 0.0
H = 1.278
A = 0.508
B = 0.25
CENTER_XY = (1.9, 0.0)


def scaled_p15(scale: float = P15_SCALE, *, last_link: float | None = None, lower=None, upper=None,
               task: str = "position") -> Robot:
    """An arm of the CYBOTECH P-15 architecture (Table 4.1's twists) with its lengths times ``scale``.

    With scale 8: b1 = 1.28 m (shoulder height), a2 = 1.28 m, a3 = 1.6 m, b5 = 1.12 m (the link from
    the elbow-side wrist axis to the wrist centre P). This is the smallest integer scale for which every
    point of the Section 6.3 path has a collision-free configuration with several centimetres to spare
    (scales 5-7 leave points near beta = 0, the far side of the cylinder, with none or with millimetres).
    But the policy's last link cannot lie along the lateral normal there: its joint W = P + b5 n is
    3.52 m from O2, beyond links 2-3's reach 2.88 m (:func:`~kinredund.planning.planner.wrist_reach`;
    margin 0.36 s - |W - O2| = -0.64, -0.42, -0.21, 0.00, +0.20 m at scales 8-12), so :func:`plan`
    with the default policy fails at once below scale 12. For scales above 10, W at beta = pi lies
    behind the base and the aligned last link crosses link 1's axis: no uniform scale meets the policy
    exactly on the whole path (``last_link`` decouples b5 from the scale).

    Joint limits: Table 4.1's limits of axes 2-4 (+-45 deg, -45..135 deg, +-60 deg) leave the half of
    the path with y > 0 unreachable without collision, so axes 1-4 get [-pi, pi] and the wrist +-2 pi
    unless ``lower``/``upper`` are given.

    Args:
        scale: the factor on every length of Table 4.1 (> 0).
        last_link: the length b5 of the last positioning link [m] instead of ``scale`` * 0.14 m.
        lower, upper: joint limits [rad], shape (7,).
        task: the task kind (``position``: the wrist centre; the thesis positions it with axes 1-4).

    Raises:
        TaskError: a scale that is not a finite number > 0.
    """
    scale = check_positive(scale, "the scale", TaskError)
    if last_link is not None and not (isinstance(last_link, (int, float)) and math.isfinite(last_link)
                                      and last_link > 0):
        raise TaskError(f"last_link must be a finite length > 0 [m], got {last_link!r}")
    table = cybotech_p15_scaled(scale, last_link=last_link, lower=lower, upper=upper)
    return robot_from_hd(table, task=task)


def section_point(beta, *, a: float = A, b: float = B, gamma: float = GAMMA, psi: float = PSI, h: float = H,
                  center=CENTER_XY):
    """Points of the path at parameters beta, Eqs. (6.46)-(6.49): shape (..., 3) [m]."""
    beta = np.asarray(beta, float)
    xd = a * np.cos(beta) * math.cos(gamma)  # Eq. (6.48)
    yd = b * np.sin(beta)  # Eq. (6.49), without the OCR's cos(gamma) (module docstring)
    x = xd * math.cos(psi) - yd * math.sin(psi) + center[0]  # Eq. (6.46)
    y = xd * math.sin(psi) + yd * math.cos(psi) + center[1]  # Eq. (6.47)
    z = a * np.cos(beta) * math.sin(gamma) + h  # Eq. (6.48)
    return np.stack([x, y, z], axis=-1)


def section_path(rate: float = 1.0, start: float = 0.0, **shape) -> FunctionPath:
    """The closed path of Section 6.3: beta = start + rate t, period 2 pi / rate [s].

    Args:
        rate: d beta / dt [rad/s].
        start: beta at t = 0 [rad].
        **shape: a, b, gamma, psi, h, center of :func:`section_point`.
    """
    rate = check_positive(rate, "the rate [rad/s]", TaskError)
    a = shape.get("a", A)
    b = shape.get("b", B)
    gamma = shape.get("gamma", GAMMA)
    psi = shape.get("psi", PSI)

    def fn(t):
        beta = start + rate * t
        dxd = -a * math.sin(beta) * math.cos(gamma)
        dyd = b * math.cos(beta)
        dp = np.array([dxd * math.cos(psi) - dyd * math.sin(psi), dxd * math.sin(psi) + dyd * math.cos(psi),
                       -a * math.sin(beta) * math.sin(gamma)])  # d/d beta of Eqs. (6.46)-(6.49)
        return section_point(beta, **shape), rate * dp

    return FunctionPath(fn, period=2 * math.pi / rate)


def section_cylinder(*, a: float = A, b: float = B, gamma: float = GAMMA, psi: float = PSI, h: float = H,
                     center=CENTER_XY, bottom: float = 0.0) -> EllipticCylinder:
    """The obstacle: the elliptic cylinder (semi-axes a cos gamma, b) from the floor up to the cutting plane
    of Eq. (6.45), so that the path is the rim of its inclined top (a pipe cut obliquely)."""
    normal = np.array([-math.sin(gamma) * math.cos(psi), -math.sin(gamma) * math.sin(psi), math.cos(gamma)])
    return cut_cylinder(center, a * math.cos(gamma), b, psi, bottom=bottom, top_normal=normal, top_z=h)


def _discriminant_root(disc, b_hi: float) -> float:
    """The b in (0, b_hi] where disc(b) changes sign (bisection); disc(b) > 0 means intersection."""
    lo, hi = 1e-12, b_hi
    if disc(hi) <= 0:
        return hi
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if disc(mid) > 0:
            hi = mid
        else:
            lo = mid
    return 0.5 * (lo + hi)


def _line_discriminant(obstacle: Obstacle, point, angle: float, b: float) -> float:
    """B^2 - 4AC of the line through ``point`` at ``angle`` met with the concentric ellipse (r b, b)."""
    r = obstacle.ratio
    # points of the line: point + tau u, u = (cos angle, sin angle); in the ellipse frame (Eqs. 6.4-6.5)
    pu, pv = (float(v) for v in obstacle.local(np.asarray(point, float)))
    u = np.array([math.cos(angle), math.sin(angle)])
    e1, e2 = obstacle.axes()
    uu, uv = float(u @ e1), float(u @ e2)
    qa = uu**2 / (r * b) ** 2 + uv**2 / b**2  # Eq. (6.3) as a quadratic in tau (6.7 / 6.30)
    qb = 2 * (pu * uu / (r * b) ** 2 + pv * uv / b**2)
    qc = pu**2 / (r * b) ** 2 + pv**2 / b**2 - 1.0
    return qb * qb - 4 * qa * qc  # Eq. (6.15) / (6.36)


def link2_semi_axis_discriminant(obstacle: Obstacle, l1: float, theta1: float, theta2: float) -> float:
    """b of Eq. (6.16) by the thesis's route: the discriminant (6.15) of link 2's line and the ellipse."""
    E = (l1 * math.cos(theta1), l1 * math.sin(theta1))
    far = 10.0 * (np.linalg.norm(obstacle.center[:2]) + l1 + 1.0)
    return _discriminant_root(lambda b: _line_discriminant(obstacle, E, theta1 + theta2, b), far)


def arm_plane_semi_axis_discriminant(obstacle: Obstacle, theta1: float) -> float:
    """b of Eq. (6.37) by the thesis's route: the projected link k2 (y - x tan theta1 = 0, Eq. 6.29)."""
    far = 10.0 * (np.linalg.norm(obstacle.center[:2]) + 1.0)
    return _discriminant_root(lambda b: _line_discriminant(obstacle, (0.0, 0.0), theta1, b), far)


def link4_direction_thesis(theta, b5: float = 1.0) -> np.ndarray:
    """Direction cosines of the fourth link, Eqs. (6.40)-(6.42) as read (module docstring)."""
    t1, t2, t3, t4 = (float(v) for v in np.asarray(theta, float)[:4])
    c1, s1, c4, s4 = math.cos(t1), math.sin(t1), math.cos(t4), math.sin(t4)
    c23, s23 = math.cos(t2 + t3), math.sin(t2 + t3)
    sg = math.copysign(1.0, b5)
    return sg * np.array([-c23 * c1 * s4 - s1 * c4, c1 * c4 - c23 * s1 * s4, -s23 * s4])  # Eqs. (6.40)-(6.42)


def top_normal_policy(robot, obstacle, normal, weights):
    """A policy factory for :func:`~kinredund.planning.planner.plan` (its ``policy=``): Eq. (6.44) with the
    last link along the normal of the cut cylinder's inclined *top* at P (the other side of the rim)
    instead of the lateral surface's, and w1 = 0.

    The path of Section 6.3 is the rim of the cut, where the outward normals span the cone between the
    lateral normal n and the top's normal; this picks the top's, so W = P + l n_top lies above the cut
    and the arm can stay above the obstacle. The term w1 / b(theta1)^2 is dropped: it is infinite when
    the arm plane passes over the cylinder's axis (b = 0), which reaching over the top requires.

    Raises:
        TaskError: an obstacle without an inclined top (``top_normal``).
    """
    top = getattr(obstacle, "top_normal", None)
    if top is None:
        raise TaskError("top_normal_policy needs a cut cylinder (EllipticCylinder with top_normal), "
                        f"got {type(obstacle).__name__} without one")
    pair = link_model(robot).pairs[-1]
    return SpatialPolicy(robot, obstacle, np.asarray(top, float), link=(int(pair[0]), int(pair[1])),
                         weights=(0.0, float(weights[1])))
