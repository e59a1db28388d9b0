"""Paths from the user's own functions of time: a pose or point path, and a point with a tool axis."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from kinredund.errors import PathError, check_flag, check_positive
from kinredund.paths.base import Path, PathSample
from kinredund.paths.sampled import ROTATION_TOL, rotation_gaps


@dataclass(frozen=True)
class FunctionPath(Path):
    """A user path: ``fn(t)`` returns (p, v) for position tasks or (Q, p, omega, v) for pose tasks.

    Args:
        fn: the callable.
        period: the period [s] of a closed path (a finite number > 0), or None.
        has_orientation: True when ``fn`` returns the 4-tuple.

    Raises:
        PathError: ``fn`` not callable, a period that is not a finite number > 0, ``has_orientation`` not a bool.
    """

    fn: Callable[[float], tuple]
    period: float | None = None
    has_orientation: bool = False

    def __post_init__(self) -> None:
        if not callable(self.fn):
            raise PathError(f"a user path's fn must be a function of t [s], got {type(self.fn).__name__}")
        if self.period is not None:
            object.__setattr__(self, "period", check_positive(self.period, "the path's period [s]", PathError))
        object.__setattr__(self, "has_orientation", check_flag(self.has_orientation, "has_orientation", PathError))

    def sample(self, t: float) -> PathSample:
        out = self.fn(t)
        try:
            if self.has_orientation:
                Q, p, omega, v = (np.asarray(x, float) for x in out)
                if Q.shape != (3, 3) or p.shape != (3,) or omega.shape != (3,) or v.shape != (3,):
                    raise ValueError("shapes")
            else:
                p, v = (np.asarray(x, float) for x in out)
                if p.shape == (2,):
                    p, v = np.append(p, 0.0), np.append(v, 0.0)
                if p.shape != (3,) or v.shape != (3,):
                    raise ValueError("shapes")
        except (TypeError, ValueError) as err:
            want = "(Q 3x3, p (3,), omega (3,), v (3,))" if self.has_orientation else "(p (2,) or (3,), v like p)"
            raise PathError(f"the user path must return {want} at t = {t:.6g} s, got {out!r}", t=t) from err
        if not self.has_orientation:
            return PathSample(p, v)
        if np.isfinite(Q).all():  # (non-finite entries: named by the path's own check, Path.__call__)
            gap, det = rotation_gaps(Q)
            if not (gap <= ROTATION_TOL and det > 0):  # (the tracker read 3 I as a half turn)
                raise PathError(f"the user path's Q at t = {t:.6g} s is not a rotation matrix (orthonormal, det +1): "
                                f"|Q Q^T - 1| = {gap:.3g}, det = {det:.3g}", t=t)
        return PathSample(p, v, Q, omega)


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
