"""The path interface: a :class:`PathSample` (pose and twist) at each time t [s]."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kinredund.errors import PathError


@dataclass(frozen=True)
class PathSample:
    """The desired pose and twist at one time: p [m], v [m/s], Q (3x3) or None, omega [rad/s] or None."""

    p: np.ndarray
    v: np.ndarray
    Q: np.ndarray | None = None
    omega: np.ndarray | None = None


@dataclass(frozen=True)
class Samples:
    """The path at several times, one row per time: p, v (k, 3) [m], [m/s]; Q (k, 3, 3) and omega (k, 3) [rad/s],
    or None for a path without orientation; ``listed``: the :class:`PathSample` of each time where the path made
    them (else :meth:`sample` makes one from the rows)."""

    p: np.ndarray
    v: np.ndarray
    Q: np.ndarray | None = None
    omega: np.ndarray | None = None
    listed: list | None = None

    def sample(self, k: int) -> PathSample:
        """The :class:`PathSample` of the k-th time."""
        if self.listed is not None:
            return self.listed[k]
        if self.Q is None:
            return PathSample(self.p[k], self.v[k])
        return PathSample(self.p[k], self.v[k], self.Q[k], self.omega[k])


class Path:
    """Base class of paths: :meth:`sample` gives the pose and twist at time t."""

    period: float | None = None
    has_orientation: bool = False

    def sample(self, t: float) -> PathSample:
        """Desired pose and twist at time t [s]."""
        raise NotImplementedError

    def computes_together(self) -> bool:
        """Does :meth:`sample_many` compute the samples together by the path's own formulas, the numbers of
        :meth:`sample`? True where one class of the path's own defines both (a subclass that overrides
        :meth:`sample` alone gets False: its parent's ``sample_many`` would not follow it); the base class's loop
        over :meth:`sample` gains nothing, and a caller's own :meth:`sample` is never called ahead of time."""
        cls = type(self)
        owner = next(c for c in cls.__mro__ if "sample_many" in c.__dict__)
        return owner is not Path and next(c for c in cls.__mro__ if "sample" in c.__dict__) is owner

    def sample_many(self, times: list[float]) -> Samples:
        """:meth:`sample` at each of ``times`` [s], and the fields stacked; a path may compute them together (the
        same numbers). Raises PathError where the samples do not stack (no orientation at some of the times)."""
        samples = [self.sample(t) for t in times]
        try:
            p, v = np.array([x.p for x in samples], float), np.array([x.v for x in samples], float)
            if samples[0].Q is None:
                return Samples(p, v, listed=samples)
            return Samples(p, v, np.array([x.Q for x in samples], float), np.array([x.omega for x in samples], float),
                           samples)
        except (TypeError, ValueError) as err:
            raise PathError(f"the path's samples at t = {times[0]:.6g} to {times[-1]:.6g} s do not stack "
                            f"(p, v of 3 entries, Q 3x3 and omega 3 at every time or at none): {err}") from err

    def __call__(self, t: float) -> PathSample:
        return checked(self.sample(t), t)


#: a sample whose entries' magnitudes sum to below this passes :func:`checked` without its dot products (the
#: squares of its at most 18 entries then sum to below 1e301: no overflow)
SMALL_SUM = 1e150


def checked(s: PathSample, t: float) -> PathSample:
    """``s``, the path's sample at t [s], if its entries are finite and their squares do not overflow, else
    PathError saying which field and when (what calling a path checks)."""
    p, v, Q, omega = s.p, s.v, s.Q, s.omega
    if type(p) is np.ndarray and type(v) is np.ndarray and (Q is None or (type(Q) is np.ndarray and
                                                                         type(omega) is np.ndarray)):
        entries = p.tolist() + v.tolist() if Q is None else p.tolist() + v.tolist() + Q.ravel().tolist() + \
            omega.tolist()
        if sum(map(abs, entries)) < SMALL_SUM:  # the common case in Python floats (a numpy call costs more); NaN fails
            return s
    # one dot product per array: finite iff every entry is finite and below ~1e154 (its square overflows)
    with np.errstate(over="ignore", invalid="ignore"):
        total = float(s.p @ s.p) + float(s.v @ s.v)
        if s.Q is not None:
            total += float(s.Q.ravel() @ s.Q.ravel()) + float(s.omega @ s.omega)
    if not math.isfinite(total):
        names = [name for name in ("p", "v", "Q", "omega") if getattr(s, name) is not None]
        bad = [name for name in names if not np.all(np.isfinite(getattr(s, name)))]
        if bad:
            raise PathError(f"the path gives non-finite {', '.join(bad)} at t = {t:.6g} s", t=t)
        big = ", ".join(f"|{name}| = {float(np.abs(getattr(s, name)).max()):.3g}" for name in names)
        raise PathError(f"the path gives values too large for any robot at t = {t:.6g} s ({big}; their squares "
                        "overflow)", t=t)
    return s
