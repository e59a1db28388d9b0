"""Obstacles of Chapter 6: an ellipse (planar case, Section 6.2) and an elliptic cylinder (Section 6.3).

Both are convex solids described by the ellipse of Eqs. (6.3)-(6.5): centre (x0, y0), semi-axes a
(major) and b, the major axis at angle psi to X. The cylinder's axis is parallel to Z and it spans the
heights [z_bottom, z_top].

Distances are exact (to round-off), not sampled:

- :meth:`Obstacle.signed_distance` of points: the exact point-to-ellipse distance (the closest point
  by the root of the ellipse's normal equation, bisected to machine precision, after D. Eberly,
  *Distance from a Point to an Ellipse, an Ellipsoid, or a Hyperellipsoid*, 2013), negative inside.
  For the cylinder the 2-D signed distance is combined with the height interval (the exact signed
  distance of an extruded convex set).
- :meth:`Obstacle.segment_distance`: the minimum over a segment (a link) of the signed distance
  (:func:`segment_minimum`). The signed distance of a convex set is a convex function, so along a
  segment it is convex in the segment parameter; a golden-section search keeps a bracket of the
  minimiser and stops when it is narrower than :data:`SEGMENT_TOL`. Since the signed distance is
  1-Lipschitz, the value returned exceeds the true minimum by at most ``length * SEGMENT_TOL``
  (reported as :data:`SEGMENT_TOL` per metre). A capsule of radius r is the segment distance minus r.
  Zero or negative means contact or penetration.

For coal (``kinredund.geometry``): :meth:`Obstacle.prism_points` gives a prism holding the obstacle, for
``Scene.add_convex``; tests/test_geometry.py checks these distances against coal's on it.

Units: lengths [m], angles [rad].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kinredund.errors import TaskError, check_array, check_choice, check_positive
from kinredund.planning.ellipse import (
    ellipse_closest_point,
    ellipse_signed_distance,
    principal_axes,
    signed_from_closest,
)

#: width of the final bracket of the segment parameter (relative, in [0, 1]); the segment distance is
#: then at most ``length * SEGMENT_TOL`` above the exact minimum (the signed distance is 1-Lipschitz)
SEGMENT_TOL = 1e-10
_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0
OBSTACLE_KINDS = ("ellipse", "elliptic_cylinder")


@dataclass(frozen=True)
class Obstacle:
    """Base of the elliptic obstacles: the ellipse of Eqs. (6.3)-(6.5) and its principal frame.

    Attributes:
        center: centre [m], shape (3,) (for the cylinder: the middle of its height).
        a, b: semi-axes [m].
        angle: psi, the major axis's angle from X [rad] (Eqs. 6.4-6.5).
    """

    center: np.ndarray
    a: float
    b: float
    angle: float = 0.0

    def __post_init__(self) -> None:
        what = "obstacle center [m] (2 or 3 numbers)"
        c = check_array(self.center, (None,), what)
        object.__setattr__(self, "center", check_array(np.append(c, 0.0) if c.size == 2 else c, (3,), what))
        object.__setattr__(self, "a", check_positive(self.a, "obstacle semi-axis a [m]"))
        object.__setattr__(self, "b", check_positive(self.b, "obstacle semi-axis b [m]"))
        try:
            ang = float(self.angle)
        except (TypeError, ValueError):
            ang = math.nan
        if not math.isfinite(ang):
            raise TaskError(f"obstacle angle must be a finite number [rad], got {self.angle!r}")
        object.__setattr__(self, "angle", ang)

    # -- the ellipse ----------------------------------------------------------------------------
    @property
    def ratio(self) -> float:
        """r = a / b, Eq. (6.6)."""
        return self.a / self.b

    def axes(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit vectors of the major and minor axes in the base frame (xy), Eqs. (6.4)-(6.5)."""
        return principal_axes(self.angle)

    def local(self, xy) -> tuple[np.ndarray, np.ndarray]:
        """(x_d, y_d) of Eqs. (6.4)-(6.5): points (..., 2 or 3) in the ellipse's principal frame [m]."""
        xy = np.asarray(xy, float)
        dx = xy[..., 0] - self.center[0]
        dy = xy[..., 1] - self.center[1]
        c, s = math.cos(self.angle), math.sin(self.angle)
        return dx * c + dy * s, -dx * s + dy * c  # Eqs. (6.4)-(6.5)

    def boundary(self, beta) -> tuple[np.ndarray, np.ndarray]:
        """Point and outward unit normal of the ellipse at eccentric angle beta (Eq. 6.19), in xy [m]."""
        beta = np.asarray(beta, float)
        e1, e2 = self.axes()
        cb, sb = np.cos(beta), np.sin(beta)
        p = self.center[:2] + np.multiply.outer(self.a * cb, e1) + np.multiply.outer(self.b * sb, e2)
        n = np.multiply.outer(self.b * cb, e1) + np.multiply.outer(self.a * sb, e2)  # Eq. (6.19)
        return p, n / np.linalg.norm(n, axis=-1, keepdims=True)

    def normal_at(self, points) -> np.ndarray:
        """Outward unit normal of the ellipse (the cylinder's lateral surface) at the boundary point
        closest to each point, in the xy-plane: shape (..., 3) with z = 0 (Eq. 6.19)."""
        u, v = self.local(points)
        xu, xv = ellipse_closest_point(self.a, self.b, u, v)
        nu, nv = xu / self.a**2, xv / self.b**2  # the gradient of Eq. (6.3)
        e1, e2 = self.axes()
        n = np.multiply.outer(nu, e1) + np.multiply.outer(nv, e2)
        n = n / np.linalg.norm(n, axis=-1, keepdims=True)
        return np.concatenate([n, np.zeros(n.shape[:-1] + (1,))], axis=-1)

    def ellipse_distance(self, xy) -> np.ndarray:
        """Signed distance [m] of points (..., 2 or 3) to the ellipse in the xy-plane (negative inside)."""
        u, v = self.local(xy)
        return ellipse_signed_distance(self.a, self.b, u, v)

    # -- what subclasses define -----------------------------------------------------------------
    def signed_distance(self, points) -> np.ndarray:
        """Exact signed distance [m] of points (..., 3) to the obstacle: > 0 outside, < 0 inside."""
        return self.ellipse_distance(points)

    def to_dict(self) -> dict:
        """The JSON form drawn by playback (``Trajectory.meta["obstacle"]``)."""
        raise NotImplementedError

    def heights(self, xy) -> tuple[np.ndarray, np.ndarray]:
        """(bottom, top) heights [m] of the solid over points (..., 2 or 3) of its directrix."""
        raise NotImplementedError

    def prism_points(self, segments: int = 64) -> np.ndarray:
        """Vertices [m], shape (2 segments, 3), of a prism holding the obstacle, for coal (``Scene.add_convex``).

        Its section is the polygon circumscribing the ellipse (a regular polygon around the unit circle, which
        holds the circle, stretched by a, b: an affine map keeps the containment); it runs from the bottom to the
        top (an inclined top's plane for a cut cylinder). It exceeds the obstacle by at most
        max(a, b) (1 / cos(pi / segments) - 1) [m].
        """
        k = np.arange(segments)
        t = (2 * k + 1) * np.pi / segments
        r = 1.0 / np.cos(np.pi / segments)
        e1, e2 = self.axes()
        xy = (self.center[:2] + np.multiply.outer(r * self.a * np.cos(t), e1)
              + np.multiply.outer(r * self.b * np.sin(t), e2))
        bottom, top = self.heights(xy)
        return np.concatenate([np.column_stack([xy, bottom]), np.column_stack([xy, top])])

    # -- segments ---------------------------------------------------------------------------------
    def segment_distance(self, p0, p1, radius: float = 0.0) -> np.ndarray:
        """Minimum signed distance [m] between segments p0-p1 (shape (..., 3)) and the obstacle:
        :func:`segment_minimum` of :meth:`signed_distance` (exact to within ``length * SEGMENT_TOL``).

        Args:
            p0, p1: end points, broadcastable to one shape (..., 3) [m].
            radius: capsule radius [m] >= 0.

        Returns:
            The distances (...,) [m] (negative: penetration depth of the segment's deepest point, for
            the 2-D ellipse; for the cylinder the exact signed distance of that point).
        """
        return segment_minimum(self.signed_distance, p0, p1, radius)


def segment_minimum(distance, p0, p1, radius: float = 0.0) -> np.ndarray:
    """The minimum of a convex function ``distance`` of points over segments p0-p1, minus ``radius``.

    A signed distance to a convex set (or a lower bound of one that is convex too, such as
    :meth:`EllipticCylinder.surface_bound`) is convex along a segment, so a golden-section search on
    the segment parameter finds its minimum; for a 1-Lipschitz ``distance`` the value is exact to
    within ``length * SEGMENT_TOL``. With ``radius`` the segment is a capsule of that radius.

    Args:
        distance: ``distance(points (..., 3)) -> (...)`` [m].
        p0, p1: end points, broadcastable to one shape (..., 3) [m].
        radius: capsule radius [m] >= 0.

    Returns:
        The minima (...,) [m].
    """
    p0, p1 = np.broadcast_arrays(np.asarray(p0, float), np.asarray(p1, float))
    d = p1 - p0

    def f(s):
        return distance(p0 + s[..., None] * d)
    shape = p0.shape[:-1]
    lo, hi = np.zeros(shape), np.ones(shape)
    x1 = hi - _GOLDEN * (hi - lo)
    x2 = lo + _GOLDEN * (hi - lo)
    f1, f2 = f(x1), f(x2)
    for _ in range(int(math.ceil(math.log(SEGMENT_TOL) / math.log(_GOLDEN)))):
        left = f1 <= f2  # the minimiser lies in [lo, x2], else in [x1, hi]
        hi = np.where(left, x2, hi)
        lo = np.where(left, lo, x1)
        nx1 = np.where(left, hi - _GOLDEN * (hi - lo), x2)
        nx2 = np.where(left, x1, lo + _GOLDEN * (hi - lo))
        fe = f(np.where(left, nx1, nx2))
        f1, f2 = np.where(left, fe, f2), np.where(left, f1, fe)
        x1, x2 = nx1, nx2
    # end points too (the minimum of a convex function on [0, 1] may sit there)
    s_in = 0.5 * (lo + hi)
    cand = np.stack([np.zeros(shape), s_in, np.ones(shape)], axis=-1)
    vals = np.stack([f(cand[..., k]) for k in range(3)], axis=-1)
    return vals.min(axis=-1) - float(radius)


@dataclass(frozen=True)
class EllipseObstacle(Obstacle):
    """The planar obstacle of Section 6.2: the region inside an ellipse in the xy-plane.

    Args:
        center: (x0, y0) or (x0, y0, 0) [m].
        a, b: semi-axes [m].
        angle: psi, the major axis's angle from X [rad].
        thickness: the drawn thickness [m] (``height`` in :meth:`to_dict`).
    """

    thickness: float = 0.02

    def heights(self, xy) -> tuple[np.ndarray, np.ndarray]:
        """The drawn slab: ``thickness`` about the centre's height [m]."""
        z = np.full(np.shape(xy)[:-1], float(self.center[2]))
        return z - 0.5 * self.thickness, z + 0.5 * self.thickness

    def to_dict(self) -> dict:
        return {"kind": "ellipse", "center": [float(v) for v in self.center], "a": self.a, "b": self.b,
                "angle": self.angle, "axis": [0.0, 0.0, 1.0], "height": float(self.thickness)}


@dataclass(frozen=True)
class EllipticCylinder(Obstacle):
    """The obstacle of Section 6.3: an elliptic cylinder with its axis parallel to Z.

    Its bottom is the plane z = center_z - height/2. Its top is either the plane z = center_z + height/2
    or, with ``top_normal``, an inclined plane through (x0, y0, top_z) - the cylinder cut obliquely, as in
    Eqs. (6.45)-(6.50) where the path is the cut's rim. ``center`` and ``height`` then describe the
    bounding right cylinder (what playback draws); :meth:`to_dict` adds the plane as ``top_plane``.

    Args:
        center: the centre of the (bounding) cylinder [m], shape (3,).
        a, b: semi-axes of its directrix [m].
        angle: psi [rad].
        height: the (bounding) height [m] > 0.
        top_normal: the inclined top's upward unit normal (3,) (z component > 0), or None.
        top_z: the height of the inclined top on the axis [m].
    """

    height: float = 1.0
    top_normal: np.ndarray | None = None
    top_z: float | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "height", check_positive(self.height, "obstacle height [m]"))
        if self.top_normal is not None:
            n = check_array(self.top_normal, (3,), "top_normal")
            if n[2] <= 0:
                raise TaskError(f"top_normal must be 3 finite numbers with z > 0, got {self.top_normal!r}")
            if self.top_z is None or not math.isfinite(float(self.top_z)):
                raise TaskError("an inclined top needs top_z, its height on the axis [m]")
            object.__setattr__(self, "top_normal", n / np.linalg.norm(n))
            object.__setattr__(self, "top_z", float(self.top_z))
            object.__setattr__(self, "_rim", self._rim_frame())

    @property
    def z_range(self) -> tuple[float, float]:
        """(z_bottom, z_top) of the (bounding) cylinder [m]."""
        h = 0.5 * self.height
        return float(self.center[2] - h), float(self.center[2] + h)

    def heights(self, xy) -> tuple[np.ndarray, np.ndarray]:
        """The bottom plane and the top (flat or inclined) over points of the directrix [m]."""
        return np.full(np.shape(xy)[:-1], self.z_range[0]), self.top_height(xy)

    def top_height(self, xy) -> np.ndarray:
        """The height of the top above points (..., 2 or 3) [m]."""
        xy = np.asarray(xy, float)
        if self.top_normal is None:
            return np.full(xy.shape[:-1], self.z_range[1])
        n = self.top_normal
        return self.top_z - (n[0] * (xy[..., 0] - self.center[0]) + n[1] * (xy[..., 1] - self.center[1])) / n[2]

    def _rim_frame(self):
        """Centre, principal directions (3, 2) and semi-axes of the top rim (an ellipse in the top plane)."""
        e1, e2 = self.axes()
        c = np.array([self.center[0], self.center[1], self.top_z])
        lift = []
        for e, s in ((e1, self.a), (e2, self.b)):
            v = np.array([e[0], e[1], 0.0]) * s
            v[2] = -(self.top_normal[0] * v[0] + self.top_normal[1] * v[1]) / self.top_normal[2]
            lift.append(v)
        U, S, _ = np.linalg.svd(np.column_stack(lift), full_matrices=False)  # conjugate -> principal semi-axes
        return c, U, S

    def _surfaces(self, points):
        """(dxy, dtop, dbot, (xu, xv)): the signed distances of points (..., 3) to the lateral surface,
        the top plane and the bottom plane [m], and the closest directrix points (principal frame)."""
        u, v = self.local(points)
        xu, xv = ellipse_closest_point(self.a, self.b, u, v)
        dxy = signed_from_closest(self.a, self.b, u, v, xu, xv)
        dbot = self.z_range[0] - points[..., 2]
        if self.top_normal is None:
            dtop = points[..., 2] - self.z_range[1]
        else:
            dtop = (points - self._rim[0]) @ self.top_normal  # signed distance to the inclined top plane
        return dxy, dtop, dbot, (xu, xv)

    def surface_bound(self, points) -> np.ndarray:
        """max of the signed distances to the three surfaces [m]: the exact signed distance inside, and
        outside a lower bound of it (never more than the true distance) - cheap screening."""
        dxy, dtop, dbot, _ = self._surfaces(np.asarray(points, float))
        return np.maximum(np.maximum(dxy, dtop), dbot)

    def signed_distance(self, points) -> np.ndarray:
        points = np.asarray(points, float)
        dxy, dtop, dbot, (xu, xv) = self._surfaces(points)
        if self.top_normal is None:
            dz = np.maximum(dbot, dtop)
            inside = np.minimum(np.maximum(dxy, dz), 0.0)
            return inside + np.hypot(np.maximum(dxy, 0.0), np.maximum(dz, 0.0))  # exact for an extrusion
        n = self.top_normal
        c, U, S = self._rim
        inner = np.maximum(np.maximum(dxy, dtop), dbot)  # exact inside: the nearest of the three surfaces
        # outside: the nearest of the five boundary pieces (each candidate is a point of the solid)
        cand = []
        lat_ok = (points[..., 2] >= self.z_range[0]) & (points[..., 2] <= self._top_above(xu, xv))
        cand.append(np.where(lat_ok, np.abs(dxy), np.inf))  # lateral surface
        foot = points - dtop[..., None] * n
        cand.append(np.where(self.ellipse_distance(foot) <= 0, np.abs(dtop), np.inf))  # top face
        cand.append(np.where(dxy <= 0, np.abs(dbot), np.inf))  # bottom face
        rel = foot - c
        d_in = np.abs(ellipse_signed_distance(S[0], S[1], rel @ U[:, 0], rel @ U[:, 1]))
        cand.append(np.hypot(dtop, d_in))  # top rim
        cand.append(np.hypot(dbot, np.abs(dxy)))  # bottom rim
        outside = np.min(np.stack(cand, axis=-1), axis=-1)
        return np.where(inner <= 0, inner, outside)

    def _top_above(self, xu, xv) -> np.ndarray:
        """The top's height above directrix points (xu, xv) given in the principal frame [m]."""
        e1, e2 = self.axes()
        x = self.center[0] + xu * e1[0] + xv * e2[0]
        y = self.center[1] + xu * e1[1] + xv * e2[1]
        return self.top_height(np.stack([x, y], axis=-1))

    def to_dict(self) -> dict:
        out = {"kind": "elliptic_cylinder", "center": [float(v) for v in self.center], "a": self.a, "b": self.b,
               "angle": self.angle, "axis": [0.0, 0.0, 1.0], "height": self.height}
        if self.top_normal is not None:
            out["top_plane"] = {"point": [float(self.center[0]), float(self.center[1]), self.top_z],
                                "normal": [float(v) for v in self.top_normal]}
        return out


def cut_cylinder(center_xy, a: float, b: float, angle: float, *, bottom: float, top_normal, top_z: float
                 ) -> EllipticCylinder:
    """An elliptic cylinder from z = ``bottom`` up to an inclined plane (normal ``top_normal`` through
    (x0, y0, top_z)); its ``center``/``height`` bound it (they reach the top's highest point)."""
    n = np.asarray(top_normal, float)
    n = n / np.linalg.norm(n)
    # the top's highest point over the directrix: maximise -(n_xy . d)/n_z over the ellipse
    e1, e2 = principal_axes(angle)
    g = n[:2]
    rise = math.hypot(a * (g @ e1), b * (g @ e2)) / n[2]
    top = top_z + rise
    if top <= bottom:
        raise TaskError(f"the cut plane lies below the bottom ({bottom} m)")
    return EllipticCylinder((center_xy[0], center_xy[1], 0.5 * (bottom + top)), a, b, angle, height=top - bottom,
                            top_normal=n, top_z=top_z)


def obstacle_from_dict(data: dict) -> Obstacle:
    """Rebuild an obstacle from :meth:`Obstacle.to_dict` output.

    Raises:
        ChoiceError: unknown kind; TaskError: missing or bad values.
    """
    if not isinstance(data, dict):
        raise TaskError(f"an obstacle must be a dict with kind, center, a, b, got {type(data).__name__}")
    kind = check_choice("obstacle kind", data.get("kind"), OBSTACLE_KINDS)
    missing = [k for k in ("center", "a", "b") if k not in data]
    if missing:
        raise TaskError(f"obstacle dict misses {', '.join(missing)}; needs kind, center, a, b, angle, height")
    axis = check_array(data.get("axis", [0.0, 0.0, 1.0]), (3,), "obstacle axis")
    if np.linalg.norm(axis[:2]) > 1e-12 or axis[2] <= 0:
        raise TaskError(f"only obstacles with their axis along +Z are supported, got axis {data.get('axis')!r}")
    if kind == "ellipse":
        return EllipseObstacle(data["center"], data["a"], data["b"], data.get("angle", 0.0),
                               thickness=data.get("height", 0.02))
    top = data.get("top_plane")
    if top is not None:
        if not (isinstance(top, dict) and "normal" in top and "point" in top):
            raise TaskError(f"an obstacle's top_plane must be a dict with normal and point, got {top!r}")
        point = check_array(top["point"], (3,), "top_plane point [m]")
        return EllipticCylinder(data["center"], data["a"], data["b"], data.get("angle", 0.0),
                                height=data.get("height", 1.0), top_normal=top["normal"], top_z=point[2])
    return EllipticCylinder(data["center"], data["a"], data["b"], data.get("angle", 0.0),
                            height=data.get("height", 1.0))
