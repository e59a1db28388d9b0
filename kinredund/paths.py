"""End-effector paths as functions of time: pose and twist (Chapter 4 examples, Section 3.2, Chapter 6).

A path returns, at time t, a :class:`PathSample`: the position p_d [m] of point P, its velocity
v_d [m/s], and for pose tasks the rotation Q_d and angular velocity omega_d [rad/s] (world axes).
Closed paths have a ``period`` [s].

- :class:`Circle`: a circle in a plane through its centre with unit normal n, constant speed,
  counter-clockwise about n (Examples 4.1-4.2 in the xy-plane; Example 4.3 about +x with the Frenet
  frame Q_d = [e_n, e_t, e_n x e_t], Eqs. 4.47-4.48).
- :class:`Ellipse`: an ellipse in the xy-plane (Chapter 6), constant angular rate of its parameter.
- :class:`Helix`: the helix of Section 3.2.
- :class:`FunctionPath`: a user path from a callable t -> (p, v) or (Q, p, omega, v).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from kinredund.errors import PathError, check_array, check_positive

#: largest |Q Q^T - 1| entry accepted for a sampled rotation (6 significant digits in a file give ~1e-6)
ROTATION_TOL = 1e-5


@dataclass(frozen=True)
class PathSample:
    """The desired pose and twist at one time: p [m], v [m/s], Q (3x3) or None, omega [rad/s] or None."""

    p: np.ndarray
    v: np.ndarray
    Q: np.ndarray | None = None
    omega: np.ndarray | None = None


class Path:
    """Base class of paths: :meth:`sample` gives the pose and twist at time t."""

    period: float | None = None
    has_orientation: bool = False

    def sample(self, t: float) -> PathSample:
        """Desired pose and twist at time t [s]."""
        raise NotImplementedError

    def __call__(self, t: float) -> PathSample:
        s = self.sample(t)
        # one dot product per array: finite iff every entry is (BLAS raises no floating-point warnings)
        total = float(s.p @ s.p) + float(s.v @ s.v)
        if s.Q is not None:
            total += float(s.Q.ravel() @ s.Q.ravel()) + float(s.omega @ s.omega)
        if not math.isfinite(total):
            bad = [name for name in ("p", "v", "Q", "omega") if getattr(s, name) is not None
                   and not np.all(np.isfinite(getattr(s, name)))]
            raise PathError(f"the path gives non-finite {', '.join(bad)} at t = {t:.6g} s", t=t)
        return s


def _center3(center, what: str) -> np.ndarray:
    """A centre as 3 finite numbers [m]; a 2-vector is taken in the plane z = 0."""
    c = check_array(center, (None,), f"{what} centre", PathError)
    if c.shape == (2,):
        c = np.append(c, 0.0)
    if c.shape != (3,):
        raise PathError(f"{what} centre must be 2 or 3 finite numbers, got {center!r}")
    return c


def _positive(path, what: str, *names: str) -> None:
    """Check that each named field of a (frozen) path is a finite number > 0 and store it as a float."""
    for name in names:
        object.__setattr__(path, name, check_positive(getattr(path, name), f"{what} {name}", PathError))


def _real(path, what: str, *names: str) -> None:
    """Check that each named field is a finite real number and store it as a float."""
    for name in names:
        object.__setattr__(path, name, float(check_array(getattr(path, name), (), f"{what} {name}", PathError)))


def _unit(v, what: str) -> np.ndarray:
    u = check_array(v, (3,), what, PathError)
    norm = float(np.linalg.norm(u))
    if norm < 1e-12:
        raise PathError(f"{what} must be a non-zero 3-vector, got {v!r}")
    return u / norm


def _frame(normal) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = _unit(normal, "circle normal")
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = helper - (helper @ n) * n
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(n, e1), n


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
        object.__setattr__(self, "period", 2 * np.pi * self.radius / self.speed)
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
        object.__setattr__(self, "period", 2 * np.pi / self.rate)

    def sample(self, t: float) -> PathSample:
        s = self.start + self.rate * t
        ca, sa = np.cos(self.angle), np.sin(self.angle)
        local = np.array([self.a * np.cos(s), self.b * np.sin(s)])
        dlocal = self.rate * np.array([-self.a * np.sin(s), self.b * np.cos(s)])
        R = np.array([[ca, -sa], [sa, ca]])
        p = self.center + np.append(R @ local, 0.0)
        return PathSample(p, np.append(R @ dlocal, 0.0))


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
        p = np.array([self.radius * np.cos(beta), self.radius * np.sin(beta), self.pitch * beta + self.z0])
        v = self.rate * np.array([-self.radius * np.sin(beta), self.radius * np.cos(beta), self.pitch])
        return PathSample(p, v)


@dataclass(frozen=True)
class FunctionPath(Path):
    """A user path: ``fn(t)`` returns (p, v) for position tasks or (Q, p, omega, v) for pose tasks.

    Args:
        fn: the callable.
        period: the period [s] of a closed path, or None.
        has_orientation: True when ``fn`` returns the 4-tuple.
    """

    fn: Callable[[float], tuple]
    period: float | None = None
    has_orientation: bool = False

    def sample(self, t: float) -> PathSample:
        out = self.fn(t)
        try:
            if self.has_orientation:
                Q, p, omega, v = (np.asarray(x, float) for x in out)
                if Q.shape != (3, 3) or p.shape != (3,) or omega.shape != (3,) or v.shape != (3,):
                    raise ValueError("shapes")
                return PathSample(p, v, Q, omega)
            p, v = (np.asarray(x, float) for x in out)
            if p.shape == (2,):
                p, v = np.append(p, 0.0), np.append(v, 0.0)
            if p.shape != (3,) or v.shape != (3,):
                raise ValueError("shapes")
            return PathSample(p, v)
        except (TypeError, ValueError) as err:
            want = "(Q 3x3, p (3,), omega (3,), v (3,))" if self.has_orientation else "(p (2,) or (3,), v like p)"
            raise PathError(f"the user path must return {want} at t = {t:.6g} s, got {out!r}", t=t) from err


class SampledPath(Path):
    """A path through sampled points (a closed loop when ``closed``), interpolated by cubic splines.

    Positions use a (periodic) cubic spline in time; orientations, when given, scipy's RotationSpline
    (its angular rate is the twist's omega).

    Args:
        t: sample times [s], strictly increasing.
        p: positions, shape (N, 2) or (N, 3) [m].
        Q: rotations, shape (N, 3, 3), or None.
        closed: the path is periodic with period t[-1] - t[0]; the last sample must equal the first.
    """

    def __init__(self, t, p, Q=None, closed: bool = True):
        from scipy.interpolate import CubicSpline

        if not isinstance(closed, (bool, np.bool_)):
            raise PathError(f"closed must be True or False, got {closed!r}")
        t = check_array(t, (None,), "sample times", PathError)
        if t.shape[0] < 4 or np.any(np.diff(t) <= 0):
            raise PathError("a sampled path needs at least 4 strictly increasing, finite times")
        p = check_array(p, (t.shape[0], None), "sampled positions", PathError)
        if p.shape[1] not in (2, 3):
            raise PathError(f"sampled positions must be finite, of shape ({t.shape[0]}, 2 or 3), got {p.shape}")
        if p.shape[1] == 2:
            p = np.column_stack([p, np.zeros(len(p))])
        if closed and np.abs(p[0] - p[-1]).max() > 1e-9:
            raise PathError("a closed sampled path must end where it starts (last sample = first sample)")
        self._t0, self._t1 = t[0], t[-1]
        self.period = float(t[-1] - t[0]) if closed else None
        self._spline = CubicSpline(t, p, bc_type="periodic" if closed else "not-a-knot")
        self._rot = None
        self.has_orientation = Q is not None
        if Q is not None:
            from scipy.spatial.transform import Rotation, RotationSpline

            Q = check_array(Q, (t.shape[0], 3, 3), "sampled rotations", PathError)
            # rotations, not merely matrices (Rotation.from_matrix would quietly orthonormalise 2 I): entries
            # read from a file carry ~1e-9 of rounding at most, so ROTATION_TOL leaves room for 6 printed digits
            gap = np.abs(Q @ Q.transpose(0, 2, 1) - np.eye(3)).max(axis=(1, 2))
            bad = np.flatnonzero((gap > ROTATION_TOL) | (np.linalg.det(Q) <= 0))
            if bad.size:
                k = int(bad[0])
                raise PathError(f"sampled rotation {k} (of {len(Q)}) is not a rotation matrix (orthonormal, det +1): "
                                f"|Q Q^T - 1| = {gap[k]:.3g}, det = {np.linalg.det(Q[k]):.3g}", t=float(t[k]))
            if closed and np.abs(Q[0] - Q[-1]).max() > 1e-9:
                raise PathError("a closed sampled path must end with the rotation it starts with")
            self._rot = RotationSpline(t, Rotation.from_matrix(Q))

    def sample(self, t: float) -> PathSample:
        if self.period is not None:
            t = self._t0 + (t - self._t0) % self.period
        elif not (self._t0 - 1e-12 <= t <= self._t1 + 1e-12):
            raise PathError(f"t = {t:.6g} s is outside the sampled path's times [{self._t0}, {self._t1}]", t=t)
        p, v = self._spline(t), self._spline(t, 1)
        if self._rot is None:
            return PathSample(p, v)
        Q = self._rot(t).as_matrix()
        omega = Q @ self._rot(t, 1)  # RotationSpline's rate is in the body frame
        return PathSample(p, v, Q, omega)


def read_path_file(file) -> tuple[SampledPath, float]:
    """The sampled path of a JSON file (``kinredund track --path file``) and its duration [s].

    The file holds an object with ``t`` (sample times [s], strictly increasing), ``p`` (positions,
    N x 2 or N x 3 [m]), optionally ``Q`` (rotations, N x 3 x 3) and ``closed`` (true or false,
    default true: the last sample must then equal the first). The times are shifted to start at 0,
    where tracking starts.

    Returns:
        The :class:`SampledPath` and its duration t[-1] - t[0] [s] (the period of a closed path; what
        an open path is tracked over).

    Raises:
        KinredundError: the file cannot be read or is not a JSON object; PathError: a missing key, a
            ``closed`` that is not true or false, or samples :class:`SampledPath` rejects.
    """
    from kinredund.io import read_json_object

    data = read_json_object(file)
    if "t" not in data or "p" not in data:
        raise PathError(f"{file} must hold a JSON object with 't' and 'p' (and optionally 'Q' and 'closed')")
    closed = data.get("closed", True)
    if not isinstance(closed, bool):
        raise PathError(f"'closed' in {file} must be true or false, got {closed!r}")
    t = check_array(data["t"], (None,), f"sample times 't' in {file}", PathError)
    if t.size == 0:
        raise PathError(f"'t' in {file} holds no sample time")
    path = SampledPath(t - t[0], data["p"], data.get("Q"), closed=closed)
    return path, float(t[-1] - t[0])


@dataclass(frozen=True)
class AxisPath(Path):
    """A path given by its point and a tool axis alone (the tool-axis task, ``task="axis"``).

    ``fn(t)`` returns (p, v, a, adot): the point [m], its velocity [m/s], the tool axis a (any nonzero
    length: it is normalised) and its rate [1/s]. The sample's rotation is the frame Q_d = [x, a x x, a]
    whose x axis is a fixed seed direction made orthogonal to a (the coordinate axis least aligned with
    a at t = 0), and omega its true angular velocity,

        omega = -(y . adot) x + (x . adot) y + (xdot . y) a,        y = a x x,

    so Q_d and omega agree (dQ_d/dt = [omega]x Q_d) as the tracker's terms need; only Q_d's z axis
    enters the task. The seed must never be parallel to a along the path (a PathError says when).

    Args:
        fn: the callable.
        period: the period [s] of a closed path, or None.
    """

    fn: Callable[[float], tuple]
    period: float | None = None
    has_orientation: bool = True

    def __post_init__(self) -> None:
        if self.period is not None:
            object.__setattr__(self, "period", check_positive(self.period, "the path's period [s]", PathError))
        p, v, a, adot = self._parts(0.0)
        object.__setattr__(self, "_seed", np.eye(3)[int(np.argmin(np.abs(a)))])

    def _parts(self, t: float):
        out = self.fn(t)
        try:
            p, v, a, adot = (np.asarray(x, float) for x in out)
            if p.shape != (3,) or v.shape != (3,) or a.shape != (3,) or adot.shape != (3,):
                raise ValueError("shapes")
        except (TypeError, ValueError) as err:
            raise PathError(f"an axis path's function must return (p, v, a, adot), four 3-vectors, at t = {t:.6g} s, "
                            f"got {out!r}", t=t) from err
        na = float(np.linalg.norm(a))
        if not na > 1e-12:
            raise PathError(f"the tool axis must be a nonzero vector, got {a.tolist()} at t = {t:.6g} s", t=t)
        a = a / na
        return p, v, a, (adot - a * float(a @ adot)) / na  # the rate of the unit axis

    def sample(self, t: float) -> PathSample:
        p, v, a, adot = self._parts(t)
        s = self._seed
        xt = s - float(s @ a) * a
        nx = float(np.linalg.norm(xt))
        if not nx > 1e-6:
            raise PathError(f"the tool axis {a.tolist()} is parallel to the frame's seed direction at t = {t:.6g} s",
                            t=t)
        x = xt / nx
        y = np.cross(a, x)
        xt_dot = -float(s @ adot) * a - float(s @ a) * adot
        x_dot = (xt_dot - x * float(x @ xt_dot)) / nx
        omega = -float(y @ adot) * x + float(x @ adot) * y + float(x_dot @ y) * a
        return PathSample(p, v, np.column_stack([x, y, a]), omega)
