"""The geometric joint path theta*(x(s)) of a tracked record, as a function of the path parameter s.

For a time-invariant index the optimal joint path depends on the end-effector path only (thesis
Section 4.1: the normality condition (4.5) and the task g(theta) = x involve no time), so a record
tracked at one timing holds exact points theta*(x(s_k)) of a curve that any other timing follows too.
The path parameter s is the record's own time t - t_0 [s]: the tracked timing is one time law, s = t.

Between the samples the curve is a quintic interpolating spline (scipy ``make_interp_spline``, k = 5;
periodic for a closed path), whose derivatives q'(s), q''(s), q'''(s) are continuous: what TOPP-RA
and the jerk check need. Its interpolation error is O(h^6); on the Panda benchmark circle at the
default 200 samples per loop the joints lie within ~2e-13 rad of the optimal path between samples and
the tool within ~1e-13 m of its path (``tests/test_retime.py`` measures it against points tracked at
the midpoints).

A closed path gives a closed joint path (the resolved-rate scheme's cyclicity, Chapter 4): the last
sample of the first loop must return to the first one within :data:`CLOSURE_TOL`; a revolute joint
may come back turned by whole turns (its spline then carries the turns as a linear term).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.interpolate import make_interp_spline

from kinredund.kinematics.angles import joint_drift
from kinredund.retime.limits import RetimeError
from kinredund.trajectory import LOOP_CLOSURE_TOL, Trajectory

#: largest joint drift over one loop [rad] for which a closed record counts as a closed joint path
CLOSURE_TOL = LOOP_CLOSURE_TOL
#: largest joint step between consecutive samples [rad or m]: more is a jump, not a sampled curve
MAX_STEP = 0.5
#: fewest samples a quintic interpolating spline needs (and TOPP-RA a few segments)
MIN_SAMPLES = 8


@dataclass(frozen=True)
class JointPath:
    """A record's joint path over one loop (closed) or its whole length (open).

    Attributes:
        s: path parameters of the samples, from 0 [s], shape (N + 1,): sample k is the record's row k.
        q: the samples, shape (N + 1, n); for a closed path q[N] = q[0] + 2 pi turns.
        p: the tool's path points at the samples (the record's ``p_desired``), shape (N + 1, 3) [m].
        closed: True for one loop of a closed path.
        turns: whole turns of each joint over a loop (0 for prismatic joints and open paths), shape (n,).
        drift: the record's joint drift over that loop [rad] (0.0 for open paths).
    """

    s: np.ndarray
    q: np.ndarray
    p: np.ndarray
    closed: bool
    turns: np.ndarray
    drift: float

    def __post_init__(self) -> None:
        s, q = self.s, self.q
        rate = 2.0 * np.pi * self.turns / self.period if self.closed else np.zeros(q.shape[1])
        r = q - np.outer(s, rate)
        bc = None
        if self.closed:
            r = r.copy()
            r[-1] = r[0]  # closes within CLOSURE_TOL; exactly for the periodic spline
            bc = "periodic"
        object.__setattr__(self, "_rate", rate)
        object.__setattr__(self, "_spline", make_interp_spline(s, r, k=5, bc_type=bc))

    @cached_property
    def _tool(self):
        """The quintic spline of the tool's path points (built when a tool-speed limit asks for it)."""
        p = self.p.copy()
        if self.closed:
            p[-1] = p[0]
        return make_interp_spline(self.s, p, k=5, bc_type="periodic" if self.closed else None)

    @property
    def period(self) -> float:
        """The length of the parameter range [s] (the loop period for a closed path)."""
        return float(self.s[-1])

    @property
    def n(self) -> int:
        """The number of joints."""
        return self.q.shape[1]

    def __call__(self, s, order: int = 0) -> np.ndarray:
        """theta*(s) (order 0) or its derivative d^order theta*/ds^order, shape (len(s), n)."""
        s = np.atleast_1d(np.asarray(s, dtype=float))
        if self.closed:
            loops = np.floor(s / self.period)
            out = self._spline(s - loops * self.period, order)
            if order == 0:
                out = out + np.outer(s, self._rate)
            elif order == 1:
                out = out + self._rate
            return out
        out = self._spline(s, order)
        return out

    def tool_derivative(self, s, order: int = 1) -> np.ndarray:
        """d^order p / ds^order of the tool's path points [m/s^order], shape (len(s), 3)."""
        s = np.atleast_1d(np.asarray(s, dtype=float))
        if self.closed:
            s = s - np.floor(s / self.period) * self.period
        return self._tool(s, order)


def joint_path(traj: Trajectory, revolute, closed: bool | None = None) -> JointPath:
    """The joint path of a tracked record (its first loop when the path is closed).

    Args:
        traj: a checked :class:`~kinredund.trajectory.Trajectory` (``loop_period`` set for closed paths).
        revolute: per joint, True for revolute (compared modulo 2 pi).
        closed: None (default) takes a record with a ``loop_period`` as a closed path; False takes the
            whole record as an open path (a motion from rest to rest).

    Raises:
        RetimeError: the record is not a joint path: too few samples, a jump between samples, no sample
            at the loop period, or a loop whose joints do not return (drift > :data:`CLOSURE_TOL`).
    """
    t, q = traj.t, traj.q
    if len(t) < MIN_SAMPLES:
        raise RetimeError(f"not a joint path to retime: {len(t)} samples, at least {MIN_SAMPLES} are needed")
    steps = np.abs(np.diff(q, axis=0))
    if steps.size and steps.max() > MAX_STEP:
        k, j = np.unravel_index(int(np.argmax(steps)), steps.shape)
        raise RetimeError(f"not a sampled joint path: joint {j} jumps by {steps[k, j]:.3g} between t = {t[k]:.6g} s "
                          f"and t = {t[k + 1]:.6g} s (at most {MAX_STEP} per sample: track with more steps)")
    s = t - t[0]
    p = np.asarray(traj.p_desired, float)
    if traj.loop_period is None or closed is False:
        return JointPath(s, q, p, False, np.zeros(q.shape[1]), 0.0)
    period = float(traj.loop_period)
    # the sample at the loop period, t0 + N dt: within 1e-9 of the period relative to it, plus the rounding of
    # the record's times (never an absolute tolerance: a fast record's whole loop may last less than 1e-9 s)
    at_period = 1e-9 * period + 64.0 * float(np.finfo(float).eps) * float(np.abs(t).max())
    hits = np.flatnonzero(np.abs(s - period) <= at_period)
    if hits.size == 0:
        raise RetimeError(f"not a closed joint path: the record has no sample at its loop period {period:.6g} s "
                          f"(its times run to {s[-1]:.6g} s)")
    N = int(hits[0])
    if N + 1 < MIN_SAMPLES:
        raise RetimeError(f"not a joint path to retime: {N + 1} samples per loop, at least {MIN_SAMPLES} are needed")
    rev = np.asarray(revolute, dtype=bool)
    drift = joint_drift(q[0], q[N], rev)
    if drift > CLOSURE_TOL:
        raise RetimeError(f"not a closed joint path: the joints drift by {drift:.3g} rad over a loop (at most "
                          f"{CLOSURE_TOL:g} for a periodic time law); retime it as an open path (closed=False, "
                          "kinredund retime --open)")
    turns = np.where(rev, np.round((q[N] - q[0]) / (2.0 * np.pi)), 0.0)
    return JointPath(s[: N + 1], q[: N + 1], p[: N + 1], True, turns, drift)
