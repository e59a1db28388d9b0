"""Retiming a tracked record: a new time law along the same optimal joint path (issue 16).

For a time-invariant index the optimal joint path theta*(x) depends on the geometric path only, so
retiming is a new time law s(t) along it: the tool stays on the path and a closed path keeps giving a
closed joint path. :func:`retime` keeps the record's own samples, which are exact points
theta*(x(s_k)) of that path (the tracker holds the task and the normality condition (4.5) to ~1e-12),
and gives each a new time t_k from the time law (:mod:`kinredund.retime.time_law`), with
qdot = q'(s) sd and qddot = q'(s) sdd + q''(s) sd^2 there. Between samples, the shipped interpolation
(:meth:`RetimeResult.interpolate`) is the time law evaluated as it is defined and the quintic spline
theta(s) of the samples (:mod:`kinredund.retime.joint_path`): on the Panda benchmark circle at 200
samples per loop the tool is within ~1e-13 m of its path there.

A periodic law's loops start and end at the loop's speed; ``rest_to_rest=True`` makes one time-optimal
law over all the chained loops instead, from rest to rest (what a controller starting from standstill
can run as it is).

The output times are whole nanoseconds (a ROS ``builtin_interfaces/Duration`` holds no finer), moved by
less than 0.5 ns from the time law's: far below any controller's period, and the exported files give
back exactly the record's times.

*A time-varying index* (the Chapter 6 reference theta*(t) of Eq. (6.25), ``TimeVaryingReference``):
there the optimal joint path depends on the timing itself. Retiming then retimes the tracked joint
path as a geometric curve: the tool still follows its path (the same joint positions), but the motion no
longer follows its reference theta*(t) at the new times, and is no longer the optimum of that index.
The result's ``notes`` say so (a record with ``meta["planner"]``, or ``index.time_varying``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from kinredund.export.samples import ExportError, distinct_nanoseconds, from_nanoseconds
from kinredund.kinematics.angles import joint_drift
from kinredund.retime.joint_path import JointPath, joint_path
from kinredund.retime.limits import Limits, RetimeError
from kinredund.retime.time_law import TimeLaw, jerk_law, rest_to_rest_law, sample_ratios, toppra_law
from kinredund.trajectory import PER_POINT_FIELDS, Trajectory

#: a record's loop drift [rad] above which the result notes it (below: round-off of the tracker)
DRIFT_NOTE = 1e-12
#: a limit counts as active at a sample within this fraction of it (the time-optimality measure)
ACTIVE_WITHIN = 0.01
TIME_VARYING_NOTE = ("time-varying index (the Chapter 6 reference theta*(t), Eq. 6.25): the joint path was retimed as "
                     "a geometric curve; the tool stays on its path, but at the new times the motion no longer follows "
                     "the reference theta*(t)")


@dataclass(frozen=True)
class RetimeResult:
    """A retimed record and how it was made.

    Attributes:
        trajectory: the retimed :class:`~kinredund.trajectory.Trajectory` (``loops`` loops chained for a
            closed path), with ``qdot`` and ``qddot``.
        path: the joint path theta*(s) it follows.
        law: the time law of one loop (or of the open path, or of all the loops from rest to rest).
        limits: the limits it holds at every sample.
        loops: loops chained (1 for an open path).
        rest_to_rest: the chained loops start and end at rest (one law over all of them).
        active_fraction: the fraction of a loop's samples where some limit is within 1 % (time-optimal
            laws have one active almost everywhere).
        notes: remarks (a time-varying index, the record's own loop drift).
    """

    trajectory: Trajectory
    path: JointPath
    law: TimeLaw
    limits: Limits
    loops: int
    active_fraction: float
    notes: tuple[str, ...] = ()
    rest_to_rest: bool = False

    @property
    def loop_duration(self) -> float:
        """The time of one loop (of the whole open path; of all the loops from rest to rest) [s]."""
        return self.law.duration

    @property
    def duration(self) -> float:
        """The time of the whole retimed record [s]."""
        return float(self.trajectory.t[-1] - self.trajectory.t[0])

    def path_parameter(self) -> np.ndarray:
        """s at each output sample, counted on over chained loops [s], shape (N_out,)."""
        return _samples(self.path, self.law, self.loops, self.rest_to_rest)[1]

    def jerk(self) -> np.ndarray | None:
        """qdddot at each output sample (jerk-limited law), shape (N_out, n), else None."""
        if self.law.sddd is None:
            return None
        rows, s, _ = _samples(self.path, self.law, self.loops, self.rest_to_rest)
        sd, sdd, sddd = self.law.sd[rows], self.law.sdd[rows], self.law.sddd[rows]
        p = self.path
        return p(s, 1) * sddd[:, None] + 3.0 * p(s, 2) * (sd * sdd)[:, None] + p(s, 3) * (sd ** 3)[:, None]

    def law_at(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(s, sd, sdd) at the retimed record's times t [s]: the path parameter counted on over chained loops
        [s], its rate [1] and acceleration [1/s] (:meth:`TimeLaw.at`, loop by loop for a periodic law)."""
        t = np.atleast_1d(np.asarray(t, dtype=float)) - float(self.trajectory.t[0])
        T = self.law.duration
        periodic = self.path.closed and not self.rest_to_rest
        k = np.clip(np.floor(t / T), 0, self.loops - 1) if periodic else np.zeros_like(t)
        s, sd, sdd = self.law.at(t - k * T)
        return s + k * self.path.period, sd, sdd

    def interpolate(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, qdot, qddot) at times t [s] between the samples: the shipped interpolation.

        s(t) from the time law as it is defined between samples (:meth:`TimeLaw.at`), then the quintic
        spline theta*(s) of the samples and its derivatives. Times are those of the retimed record
        (0 to its end; chained loops repeat the loop's law).
        """
        return self.interpolate_with_s(t)[:3]

    def interpolate_with_s(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`interpolate` and the path parameter s(t) it evaluated the spline at (one law evaluation)."""
        s, sd, sdd = self.law_at(t)
        p = self.path
        q1 = p(s, 1)
        return p(s), q1 * sd[:, None], q1 * sdd[:, None] + p(s, 2) * (sd * sd)[:, None], s


def retime(traj: Trajectory, limits: Limits, *, robot=None, loops: int | None = None, closed: bool | None = None,
           rest_to_rest: bool = False, index=None) -> RetimeResult:
    """Retime a tracked record under ``limits``: time-optimal (TOPP-RA), or jerk-limited if ``limits.jerk``.

    Args:
        traj: a tracking record (``kinredund.tracking.track`` or its JSON).
        limits: the limits (:func:`kinredund.retime.limits.limits_for` builds them from the URDF).
        robot: the robot (default: loaded from ``traj.robot``); gives the joint count and kinds.
        loops: loops to chain for a closed path (default: as many as the record holds).
        closed: False retimes a closed record as an open path from rest to rest (one pass over all of it).
        rest_to_rest: for a closed path, the chained loops start and end at rest: one time-optimal law over
            all of them (the first loop speeds up, the last slows down); default a periodic loop law,
            whose loops chain without a stop but start and end at the loop's speed.
        index: the index the record was tracked with, if known (a time-varying one gets a note).

    Returns:
        The :class:`RetimeResult`.

    Raises:
        RetimeError: bad limits, a record that is not a joint path, or no time law under the limits.
        KinredundError: a record that :meth:`Trajectory.checked` rejects, or an unknown robot.
    """
    if not isinstance(traj, Trajectory):
        raise RetimeError(f"retime takes a kinredund Trajectory, got {type(traj).__name__}")
    if robot is None:
        from kinredund.model.robot import load_robot

        robot = load_robot(traj.robot, task=traj.task)
    traj = traj.checked(robot.nq)
    if not isinstance(limits, Limits) or limits.velocity.shape != (robot.nq,):
        raise RetimeError(f"limits must be a kinredund.retime.Limits for {robot.nq} joints (limits_for builds them)")
    jp = joint_path(traj, robot.revolute, closed)
    n_loops = 1
    if jp.closed:
        n_loops = loops if loops is not None else max(1, int(round((traj.t[-1] - traj.t[0]) / jp.period)))
        if isinstance(n_loops, bool) or int(n_loops) != n_loops or n_loops < 1:
            raise RetimeError(f"loops must be an integer >= 1, got {loops!r}")
        n_loops = int(n_loops)
    rest = bool(rest_to_rest) and jp.closed
    if rest and limits.jerk is not None:
        raise RetimeError("the jerk-limited law is periodic: it does not start or stop at rest (drop rest_to_rest or "
                          "the jerk limit)")
    law = rest_to_rest_law(jp, limits, n_loops) if rest else toppra_law(jp, limits)
    if limits.jerk is not None:
        law = jerk_law(jp, limits, law)
    ratios = sample_ratios(jp, law, limits)
    worst = np.max(np.stack(list(ratios.values())), axis=0)
    loop = worst[:-1] if jp.closed and not rest else worst  # a periodic loop's last sample is its first
    active = float(np.mean(loop >= 1.0 - ACTIVE_WITHIN))
    notes = []
    if (index is not None and getattr(index, "time_varying", False)) or "planner" in traj.meta:
        notes.append(TIME_VARYING_NOTE)
    if jp.closed and jp.drift > DRIFT_NOTE:
        notes.append(f"the record's joints drift by {jp.drift:.3g} rad over its first loop; the retimed loops "
                     "close exactly on its first sample")
    out = _chained_record(traj, jp, law, limits, n_loops, rest, robot.revolute, active, notes)
    return RetimeResult(out, jp, law, limits, n_loops, active, tuple(notes), rest)


def _samples(jp: JointPath, law: TimeLaw, loops: int, rest: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rows, s, t) of the output samples: the law's row of each, its path parameter [s] and time [s].

    A periodic loop law repeats over the loops (the last sample closing on the first); a rest-to-rest law
    and an open path's law have a row for every output sample.
    """
    N = len(jp.s) - 1
    if not jp.closed:
        return np.arange(N + 1), jp.s, law.t
    k = np.arange(loops * N + 1)
    s = jp.s[k % N] + (k // N) * jp.period
    if rest:
        return k, s, law.t
    return k % N, s, law.t[k % N] + (k // N) * law.duration


def _chained_record(traj: Trajectory, jp: JointPath, law: TimeLaw, limits: Limits, loops: int, rest: bool,
                    revolute, active: float, notes: list) -> Trajectory:
    """The retimed record: the loop's samples chained ``loops`` times (closing on the first sample)."""
    N = len(jp.s) - 1
    rows, s, t = _samples(jp, law, loops, rest)
    k = np.arange(len(s))
    lap = k // N if jp.closed else np.zeros(len(s), dtype=int)
    src = k % N if jp.closed else k  # the record's rows (sample k of the joint path is row k)
    q = traj.q[src] + np.outer(lap, 2.0 * np.pi * jp.turns)
    q1, q2 = jp(s, 1), jp(s, 2)
    sd, sdd = law.sd[rows], law.sdd[rows]
    qdot = q1 * sd[:, None]
    qddot = q1 * sdd[:, None] + q2 * (sd * sd)[:, None]
    try:  # whole nanoseconds, as a bag holds them: exports read back exactly
        t = from_nanoseconds(distinct_nanoseconds(t))
    except ExportError as err:  # times beyond int64 nanoseconds, or two samples in one nanosecond
        raise RetimeError(f"the retimed record cannot be stored: {err}") from err
    kw = {name: getattr(traj, name)[src] for name in PER_POINT_FIELDS if getattr(traj, name) is not None}
    drift = None
    if jp.closed:
        drift = np.array([joint_drift(q[0], q[(i + 1) * N], revolute) for i in range(loops)])
    meta = {key: value for key, value in traj.meta.items() if key != "dt"}
    meta["retime"] = {"law": law.kind, "limits": limits.to_dict(), "loop_duration": law.duration,
                      "original_duration": jp.period, "scale": law.scale, "window": law.window,
                      "active_fraction": active, "loops": loops, "closed": jp.closed, "rest_to_rest": rest,
                      "notes": list(notes)}
    return replace(traj, t=t, q=q, qdot=qdot, qddot=qddot, p=traj.p[src], p_desired=traj.p_desired[src],
                   solver=tuple(traj.solver[i] for i in src) if traj.solver else (), loop_drift=drift,
                   loop_period=law.duration if jp.closed and not rest else None, meta=meta, **kw).checked()
