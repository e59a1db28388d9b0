"""The ellipse of Eqs. (6.3)-(6.5) in its principal frame: closest point and signed distance.

The closest point solves the ellipse's normal equation by its root, bisected to machine precision and
finished by monotone Newton steps (after D. Eberly, *Distance from a Point to an Ellipse, an Ellipsoid,
or a Hyperellipsoid*, 2013). Units: lengths [m], angles [rad].
"""

from __future__ import annotations

import math

import numpy as np

#: bisection steps of the ellipse root, then monotone Newton steps (quadratic convergence from the left)
_BISECT = 24
_NEWTON = 8


def principal_axes(angle: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors of the major and minor axes of an ellipse whose major axis is at ``angle`` [rad] to X
    (Eqs. 6.4-6.5)."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([c, s]), np.array([-s, c])


def ellipse_closest_point(a: float, b: float, u, v) -> tuple[np.ndarray, np.ndarray]:
    """The closest point of the ellipse u^2/a^2 + v^2/b^2 = 1 (Eq. 6.3) to each point (u, v).

    Works in the first quadrant by symmetry; the root s of
    F(s) = (r0 z0 / (s + r0))^2 + (z1 / (s + 1))^2 - 1, z = (u/a, v/b), r0 = (a/b)^2, is bisected
    to machine precision (Eberly 2013). Points on the major axis inside the evolute use the closed form.

    Args:
        a, b: semi-axes [m] (either may be the larger).
        u, v: coordinates in the ellipse's principal frame [m], arrays of one shape.

    Returns:
        (xu, xv), the closest boundary points, same shape as u.
    """
    u = np.asarray(u, float)
    v = np.asarray(v, float)
    if a < b:  # work with the major axis first
        xv, xu = ellipse_closest_point(b, a, v, u)
        return xu, xv
    su, sv = np.sign(u), np.sign(v)
    su = np.where(su == 0, 1.0, su)
    sv = np.where(sv == 0, 1.0, sv)
    y0, y1 = np.abs(u), np.abs(v)
    z0, z1 = y0 / a, y1 / b
    r0 = (a / b) ** 2
    n0 = r0 * z0
    g = z0 * z0 + z1 * z1 - 1.0
    lo = np.maximum(z1 - 1.0, n0 - r0)  # F(lo) >= 0 (one term equals 1 there)
    hi = np.where(g < 0, 0.0, np.hypot(n0, z1) - 1.0)  # F(hi) <= 0
    lo = np.minimum(lo, hi)
    with np.errstate(divide="ignore", invalid="ignore"):
        for _ in range(_BISECT):
            mid = 0.5 * (lo + hi)
            f = (n0 / (mid + r0)) ** 2 + (z1 / (mid + 1.0)) ** 2 - 1.0
            pos = f > 0
            lo = np.where(pos, mid, lo)
            hi = np.where(pos, hi, mid)
        # F is convex and decreasing: Newton from the left end (F(lo) >= 0) rises monotonically to the root
        s_ = lo
        for _ in range(_NEWTON):
            a0, a1 = n0 / (s_ + r0), z1 / (s_ + 1.0)
            f = a0 * a0 + a1 * a1 - 1.0
            df = -2.0 * (a0 * a0 / (s_ + r0) + a1 * a1 / (s_ + 1.0))
            step = np.where((f > 0) & (df < 0), -f / df, 0.0)
            step = np.where(np.isfinite(step), step, 0.0)  # at the pole s = -1 (points on the major axis)
            s_ = np.minimum(s_ + step, hi)
        s = s_
        x0 = r0 * y0 / (s + r0)
        x0 = np.minimum(x0, a)
        well = (s + 1.0) > 1e-3
        x1 = np.where(well, y1 / (s + 1.0), b * np.sqrt(np.maximum(0.0, 1.0 - (x0 / a) ** 2)))
    # degenerate cases: on the minor axis, and on the major axis (inside the evolute or not)
    on_minor = y0 == 0.0
    x0 = np.where(on_minor, 0.0, x0)
    x1 = np.where(on_minor, b, x1)
    on_major = (y1 == 0.0) & ~on_minor
    numer = a * y0
    denom = a * a - b * b
    inside_evolute = on_major & (numer < denom)
    with np.errstate(divide="ignore", invalid="ignore"):
        xe = np.where(inside_evolute, a * a * y0 / np.where(denom > 0, denom, 1.0), a)
        ye = np.where(inside_evolute, b * np.sqrt(np.maximum(0.0, 1.0 - (xe / a) ** 2)), 0.0)
    x0 = np.where(on_major, xe, x0)
    x1 = np.where(on_major, ye, x1)
    return su * x0, sv * x1


def ellipse_signed_distance(a: float, b: float, u, v) -> np.ndarray:
    """Exact signed distance [m] from points (u, v) (principal frame) to the ellipse; negative inside."""
    u = np.asarray(u, float)
    v = np.asarray(v, float)
    return signed_from_closest(a, b, u, v, *ellipse_closest_point(a, b, u, v))


def signed_from_closest(a: float, b: float, u, v, xu, xv) -> np.ndarray:
    """The signed distance of (u, v) given its closest ellipse point (xu, xv); negative inside."""
    d = np.hypot(u - xu, v - xv)
    inside = (u / a) ** 2 + (v / b) ** 2 < 1.0
    return np.where(inside, -d, d)
