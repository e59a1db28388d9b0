"""Paths in closed form: the circle (Examples 4.1-4.3), the ellipse (Chapter 6) and the helix (Section 3.2)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kinredund.errors import PathError, check_array, check_positive
from kinredund.paths.base import Path, PathSample, Samples


def _center3(center, what: str) -> np.ndarray:
    """A centre as 3 finite numbers [m]; a 2-vector is taken in the plane z = 0."""
    c = check_array(center, (None,), f"{what} centre", PathError)
    if c.shape == (2,):
        c = np.append(c, 0.0)
    if c.shape != (3,):
        raise PathError(f"{what} centre must be 2 or 3 finite numbers, got {c.tolist()}")
    return c


def _positive(path, what: str, *names: str) -> None:
    """Check that each named field of a (frozen) path is a finite number > 0 and store it as a float."""
    for name in names:
        object.__setattr__(path, name, check_positive(getattr(path, name), f"{what} {name}", PathError))


def _set_period(path, what: str, period: float, made_of: str) -> None:
    """Store the period [s] the fields give; refused where it is not a finite number > 0 (fields finite and > 0 whose
    quotient over- or underflows: a radius of 1e-300 m at 1e300 m/s gave a period of 0)."""
    if not (math.isfinite(period) and period > 0.0):
        raise PathError(f"{what}: {made_of} gives the period {period!r} s; it must be a finite number > 0 (fields of "
                        "less extreme sizes)")
    object.__setattr__(path, "period", float(period))


def _real(path, what: str, *names: str) -> None:
    """Check that each named field is a finite real number and store it as a float."""
    for name in names:
        object.__setattr__(path, name, float(check_array(getattr(path, name), (), f"{what} {name}", PathError)))


def _unit(v, what: str) -> np.ndarray:
    u = check_array(v, (3,), what, PathError)
    norm = float(np.linalg.norm(u))
    if norm < 1e-12:
        raise PathError(f"{what} must be a non-zero 3-vector, got {u.tolist()}")
    return u / norm


def _frame(normal) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = _unit(normal, "circle normal")
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = helper - (helper @ n) * n
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(n, e1), n


def _read_only(values) -> np.ndarray:
    """``values`` as a new float array that cannot be written."""
    out = np.array(values, float)
    out.flags.writeable = False
    return out


_NO_Q0 = _read_only(np.zeros((0, 0)))  # circle_samples' Q0 of a circle without a constant orientation


@dataclass(frozen=True)
class Circle(Path):
    """A circle of ``radius`` about ``center``, traced counter-clockwise about ``normal`` at ``speed``.

    Args:
        center: (3,) [m] (a 2-vector is taken in the plane z = 0).
        radius: [m] > 0.
        speed: [m/s] > 0.
        start_angle: the angle beta of the start point from ``axis_x`` [rad].
        normal: unit normal of the circle's plane (default +z).
        axis_x: the in-plane direction of beta = 0 (default: a vector normal to ``normal``, +x for +z).
        frenet: if True the path has orientation Q_d = [e_n, e_t, e_n x e_t] (Eqs. 4.47-4.48): e_n the
            outward radial unit vector, e_t the tangent.
        orientation: a constant orientation Q_0 (3x3) instead, making it a pose path.
        roll_amplitude: with ``orientation``, Q_d = Q_0 Rz(roll_amplitude sin(2 pi t / T)): the tool
            turns back and forth about its own z axis once per loop [rad].
    """

    center: np.ndarray
    radius: float
    speed: float = 1.0
    start_angle: float = 0.0
    normal: tuple = (0.0, 0.0, 1.0)
    axis_x: tuple | None = None
    frenet: bool = False
    orientation: np.ndarray | None = None
    roll_amplitude: float = 0.0

    def __post_init__(self) -> None:
        _positive(self, "circle", "radius", "speed")  # first: a NaN radius is not the centre's fault
        c = _center3(self.center, "circle")
        e1, e2, n = _frame(self.normal)
        if self.axis_x is not None:
            e1 = _unit(self.axis_x, "circle axis_x")
            e1 = e1 - (e1 @ n) * n
            if np.linalg.norm(e1) < 1e-9:
                raise PathError(f"circle axis_x must not be parallel to the normal, got {self.axis_x!r}")
            e1 /= np.linalg.norm(e1)
            e2 = np.cross(n, e1)
        object.__setattr__(self, "center", c)
        object.__setattr__(self, "_plane_floats", (tuple(e1.tolist()), tuple(e2.tolist()), tuple(n.tolist())))
        object.__setattr__(self, "_center_floats", tuple(c.tolist()))
        # the same numbers as arrays for sample_many (read-only: a path is shared between runs and threads)
        object.__setattr__(self, "_plane_rows", _read_only(self._plane_floats))
        object.__setattr__(self, "_center", _read_only(self._center_floats))
        _set_period(self, "circle", 2 * np.pi * self.radius / self.speed, "2 pi radius / speed")
        _real(self, "circle", "start_angle", "roll_amplitude")  # [rad]
        if not isinstance(self.frenet, (bool, np.bool_)):
            raise PathError(f"circle frenet must be True or False, got {self.frenet!r}")
        if self.orientation is not None:
            Q0 = check_array(self.orientation, (3, 3), "circle orientation", PathError)
            if self.frenet or np.abs(Q0 @ Q0.T - np.eye(3)).max() > 1e-9 or np.linalg.det(Q0) <= 0:
                raise PathError("orientation must be a rotation matrix (3x3, orthonormal, det +1), and excludes "
                                f"frenet=True; got {Q0.tolist()}")
            object.__setattr__(self, "orientation", Q0)
            object.__setattr__(self, "_orientation_floats", tuple(tuple(row) for row in Q0.tolist()))
            object.__setattr__(self, "_orientation_rows", _read_only(self._orientation_floats))
        object.__setattr__(self, "has_orientation", bool(self.frenet) or self.orientation is not None)

    def sample(self, t: float) -> PathSample:
        w = self.speed / self.radius
        beta = self.start_angle + w * t
        c, s = math.cos(beta), math.sin(beta)
        # e_n = c e1 + s e2 (outward radial unit vector), e_t = c e2 - s e1 (tangent); Python floats
        # for these 3-vectors cost less than numpy calls
        (e1x, e1y, e1z), (e2x, e2y, e2z), _ = self._plane_floats
        en = (c * e1x + s * e2x, c * e1y + s * e2y, c * e1z + s * e2z)
        et = (c * e2x - s * e1x, c * e2y - s * e1y, c * e2z - s * e1z)
        cx, cy, cz = self._center_floats
        rad, sp = self.radius, self.speed
        p = np.array([cx + rad * en[0], cy + rad * en[1], cz + rad * en[2]])
        v = np.array([sp * et[0], sp * et[1], sp * et[2]])
        if self.orientation is not None:
            if self.roll_amplitude == 0.0:
                return PathSample(p, v, self.orientation, np.zeros(3))
            wl = w  # one roll cycle per loop: 2 pi / period = speed / radius
            ang = self.roll_amplitude * math.sin(wl * t)
            ca, sa = math.cos(ang), math.sin(ang)
            # Q = Q_0 Rz(ang): the first two columns turn by ang, the third (the roll axis) stays
            (x0, y0, z0), (x1, y1, z1), (x2, y2, z2) = self._orientation_floats
            Q = np.array([[ca * x0 + sa * y0, ca * y0 - sa * x0, z0], [ca * x1 + sa * y1, ca * y1 - sa * x1, z1],
                          [ca * x2 + sa * y2, ca * y2 - sa * x2, z2]])
            rate = self.roll_amplitude * wl * math.cos(wl * t)
            return PathSample(p, v, Q, np.array([rate * z0, rate * z1, rate * z2]))  # about Q_0's z axis
        if not self.frenet:
            return PathSample(p, v)
        n0, n1, n2 = self._plane_floats[2]
        # Eq. (4.47): [e_n, e_t, e_n x e_t], and e_n x e_t = e1 x e2 = n
        Q = np.array([[en[0], et[0], n0], [en[1], et[1], n1], [en[2], et[2], n2]])
        return PathSample(p, v, Q, np.array([w * n0, w * n1, w * n2]))  # Eq. (4.48): turns about n at beta-dot


    def sample_many(self, times: list[float]) -> Samples:
        """:meth:`sample` at each of ``times`` [s], computed together: the same operations, entry by entry, so the
        same numbers at a fraction of the cost (``Samples.sample(k)`` makes the k-th :class:`PathSample` from the
        rows where it is asked for). In one call of the compiled core where it is installed
        (``_core.circle_samples``, ``src/core/paths.cpp``), else, and where an angle is not finite, on numpy arrays
        (:meth:`_sample_arrays`)."""
        t = np.asarray(times, float)
        if _CORE is not None:
            k, kind = len(t), 1 if self.frenet else 0 if self.orientation is None else 2
            rows = 0 if kind == 0 else k  # (Q and omega only with orientation)
            P, V, Q, omega = np.empty((k, 3)), np.empty((k, 3)), np.empty((rows, 3, 3)), np.empty((rows, 3))
            Q0 = _NO_Q0 if kind != 2 else self.orientation if self.roll_amplitude == 0.0 else self._orientation_rows
            if _CORE.circle_samples(t, self.start_angle, self.speed / self.radius, self._plane_rows, self._center,
                                    self.radius, self.speed, kind, np.ascontiguousarray(Q0, float),
                                    self.roll_amplitude, P, V, Q.reshape(rows, 9), omega):
                return Samples(P, V) if kind == 0 else Samples(P, V, Q, omega)
        return self._sample_arrays(t)

    def _sample_arrays(self, t: np.ndarray) -> Samples:
        """:meth:`sample_many` on numpy arrays (the sines and cosines by ``math``'s functions, as :meth:`sample`
        takes them; each entry the one product or sum that :meth:`sample` makes of it), component by component over
        all times (row i of a transposed view: the i-th entry at each time), written into the stacked rows."""
        k = len(t)
        w = self.speed / self.radius
        c, s = _cos_sin(self.start_angle + w * t)
        e1, e2, n = self._plane_rows[:, :, None]  # (3, 1) columns
        en, et = e1 * c + e2 * s, e2 * c - e1 * s  # (3, k): e_n = c e1 + s e2 (outward), e_t = c e2 - s e1
        P, V = np.empty((k, 3)), np.empty((k, 3))
        np.add(self._center[:, None], self.radius * en, out=P.T)
        np.multiply(self.speed, et, out=V.T)
        if self.orientation is None and not self.frenet:
            return Samples(P, V)
        Q, omega = np.empty((k, 3, 3)), np.empty((k, 3))
        columns = Q.transpose(2, 1, 0)  # columns[j][i] = Q[:, i, j]
        if self.frenet:
            columns[0], columns[1], columns[2] = en, et, n  # Eq. (4.47): [e_n, e_t, e_n x e_t], e_n x e_t = n
            omega[:] = w * n[:, 0]  # Eq. (4.48): turns about n at beta-dot
            return Samples(P, V, Q, omega)
        if self.roll_amplitude == 0.0:
            Q[:], omega[:] = self.orientation, 0.0
            return Samples(P, V, Q, omega)
        cw, sw = _cos_sin(w * t)
        ca, sa = _cos_sin(self.roll_amplitude * sw)
        x, y, z = self._orientation_rows.T[:, :, None]  # Q_0's columns, (3, 1) each
        # Q = Q_0 Rz(ang): the first two columns turn by ang, the third (the roll axis) stays
        np.add(x * ca, y * sa, out=columns[0])
        np.subtract(y * ca, x * sa, out=columns[1])
        columns[2] = z
        np.multiply(z, self.roll_amplitude * w * cw, out=omega.T)  # about Q_0's z axis
        return Samples(P, V, Q, omega)


def _cos_sin(angles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(cos, sin) of each angle [rad] by ``math``'s functions (numpy's vectorised ones may round differently): in one
    call of the compiled core where it is installed (``_core.cos_sin``: the C functions that ``math.cos`` and
    ``math.sin`` call, the same numbers), else, and where an angle is not finite (``math.cos`` raises on +-inf), by
    ``math`` itself."""
    k = len(angles)
    if _CORE is not None:
        c, s = np.empty(k), np.empty(k)
        if _CORE.cos_sin(np.ascontiguousarray(angles, float), c, s):
            return c, s
    a = angles.tolist()
    return np.fromiter(map(math.cos, a), float, k), np.fromiter(map(math.sin, a), float, k)


def _compiled_core():
    """The compiled core ``kinredund._core`` where it is installed with ``cos_sin`` and ``circle_samples``, else
    None."""
    try:
        import kinredund._core as core
    except ImportError:
        return None
    return core if hasattr(core, "circle_samples") else None


_CORE = _compiled_core()


@dataclass(frozen=True)
class Ellipse(Path):
    """An ellipse in the xy-plane: semi-axes a, b, major axis at ``angle`` to X, parameter rate ``rate``.

    p(t) = c + R(angle) (a cos s, b sin s, 0), s = start + rate t; counter-clockwise.
    """

    center: np.ndarray
    a: float
    b: float
    angle: float = 0.0
    rate: float = 1.0
    start: float = 0.0

    def __post_init__(self) -> None:
        _positive(self, "ellipse", "a", "b", "rate")
        _real(self, "ellipse", "angle", "start")  # [rad]
        object.__setattr__(self, "center", _center3(self.center, "ellipse"))
        _set_period(self, "ellipse", 2 * np.pi / self.rate, "2 pi / rate")

    def sample(self, t: float) -> PathSample:
        s = self.start + self.rate * t
        ca, sa = math.cos(self.angle), math.sin(self.angle)
        cs, ss = math.cos(s), math.sin(s)
        lx, ly = self.a * cs, self.b * ss  # (a cos s, b sin s) and its rate
        dx, dy = self.rate * (-self.a * ss), self.rate * (self.b * cs)
        cx, cy, cz = self.center.tolist()
        return PathSample(np.array([cx + (ca * lx - sa * ly), cy + (sa * lx + ca * ly), cz]),
                          np.array([ca * dx - sa * dy, sa * dx + ca * dy, 0.0]))

    def sample_many(self, times: list[float]) -> Samples:
        """:meth:`sample` at each of ``times`` [s], computed together (the same operations on arrays)."""
        cs, ss = _cos_sin(self.start + self.rate * np.asarray(times, float))
        ca, sa = math.cos(self.angle), math.sin(self.angle)
        lx, ly = self.a * cs, self.b * ss
        dx, dy = self.rate * (-self.a * ss), self.rate * (self.b * cs)
        cx, cy, cz = self.center.tolist()
        P = np.stack([cx + (ca * lx - sa * ly), cy + (sa * lx + ca * ly), np.full(len(cs), cz)], axis=1)
        V = np.stack([ca * dx - sa * dy, sa * dx + ca * dy, np.zeros(len(cs))], axis=1)
        return Samples(P, V)


@dataclass(frozen=True)
class Helix(Path):
    """The helix of Section 3.2: x = r cos(beta), y = r sin(beta), z = pitch beta + z0, beta = rate t."""

    radius: float = 1.5
    pitch: float = 3.0 / np.pi
    z0: float = 2.0
    rate: float = 1.0

    def __post_init__(self) -> None:
        _positive(self, "helix", "radius", "rate")
        _real(self, "helix", "pitch", "z0")

    def sample(self, t: float) -> PathSample:
        beta = self.rate * t
        c, s = math.cos(beta), math.sin(beta)
        r = self.radius
        return PathSample(np.array([r * c, r * s, self.pitch * beta + self.z0]),
                          np.array([self.rate * (-r * s), self.rate * (r * c), self.rate * self.pitch]))

    def sample_many(self, times: list[float]) -> Samples:
        """:meth:`sample` at each of ``times`` [s], computed together (the same operations on arrays)."""
        beta = self.rate * np.asarray(times, float)
        c, s = _cos_sin(beta)
        r = self.radius
        P = np.stack([r * c, r * s, self.pitch * beta + self.z0], axis=1)
        V = np.stack([self.rate * (-r * s), self.rate * (r * c), np.full(len(beta), self.rate * self.pitch)], axis=1)
        return Samples(P, V)
