"""One placement: the start configuration, the tracking run and its record (the sweep's adapter).

:func:`evaluate_placement` is the only place the sweep calls the solvers: :func:`kinredund.ik.solve_ik`
for the start (the constrained minimum of z at the path's first point, Eq. 4.3, within the joint
limits, seeded multi-start so the records repeat, to round-off: see :mod:`kinredund.sweep.run`) and
the tracker's ``track`` for the run (Chapter 4; :mod:`kinredund.tracking`, imported in one place
below). Whatever the tracker returns or raises becomes a :class:`~kinredund.sweep.record.PlacementRecord`:

- the tracker holds the joint limits (``limits=options.limits``); its ``TrackingError`` carries
  ``cause``, ``t``, ``q`` and the ``partial`` run, which the record keeps (the figures are those of the partial run);
- the figures (margins, singular values, speeds) are computed here from the recorded joints, so they
  are right whichever tracker ran: a run that leaves the limits is infeasible with cause ``limits``,
  never feasible, even if the tracker did not hold them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kinredund.errors import KinredundError, PathError, SingularityError, check_choice, check_count, check_positive
from kinredund.ik.solve import solve_ik
from kinredund.indices import Index
from kinredund.model.robot import NO_LIMIT, Robot
from kinredund.paths import Path
from kinredund.sweep.placement import PartPath, pose_coordinates
from kinredund.sweep.record import PlacementRecord, clean_float
from kinredund.tasks import get_task
from kinredund.tracking import MODES, SCHEMES, track
from kinredund.tracking.constraints.joint_limits import JointLimits
from kinredund.trajectory import Trajectory

#: a joint counts as outside its limits beyond this [rad or m]: round-off of a tracker that holds them
#: (its steps land on a bound to ~1e-12), far below any physical margin
LIMIT_TOL = 1e-9


@dataclass(frozen=True)
class SweepOptions:
    """How each placement is run (the same for all of a sweep's placements).

    Attributes:
        steps_per_loop, loops: the run of a closed path (see :func:`kinredund.tracking.track`).
        duration, steps: the run of an open path [s], [-] (None for closed paths).
        scheme, mode: the tracker's scheme and mode.
        limits: the tracker's ``limits`` (None: held by the default mode's optimal schemes, the tracker's
            default; False: the thesis's unconstrained scheme).
        speed_limit: a joint faster than its velocity limit makes the placement infeasible (cause
            ``speed``); by default the speed ratio is only reported (a slower path execution fixes it).
        starts, seed: multi-start of the start configuration's IK (:func:`kinredund.ik.solve_ik`).
    """

    steps_per_loop: int = 200
    loops: int = 1
    duration: float | None = None
    steps: int | None = None
    scheme: str = "augmented"
    mode: str = "default"
    limits: bool | None = None
    speed_limit: bool = False
    starts: int = 8
    seed: int = 0

    def __post_init__(self) -> None:
        check_count(self.steps_per_loop, 1, "steps_per_loop", KinredundError)
        check_count(self.loops, 1, "loops", KinredundError)
        check_count(self.starts, 1, "starts", KinredundError)
        check_count(self.seed, 0, "seed", KinredundError)
        check_choice("scheme", self.scheme, SCHEMES)
        check_choice("mode", self.mode, MODES)
        if self.duration is not None:
            check_positive(self.duration, "duration [s]", KinredundError)
            check_count(self.steps, 1, "steps", KinredundError)


def run_tracker(robot: Robot, path: Path, index: Index | None, q0: np.ndarray, options: SweepOptions) -> Trajectory:
    """The tracking run of one placement: the one call of the tracker (switching trackers happens here)."""
    kw = {"scheme": options.scheme, "mode": options.mode, "diagnostics": False}
    if options.duration is None:
        kw.update(steps_per_loop=options.steps_per_loop, loops=options.loops)
    else:
        kw.update(duration=options.duration, steps=options.steps)
    kw["limits"] = options.limits
    return track(robot, path, index, q0, **kw)


#: a limited tracker's causes that the sweep reports under its own name
TRACKER_CAUSES = {"limits_infeasible": "limits"}


def _cause(err: KinredundError) -> str:
    """The failure cause of a tracker exception: its own ``cause`` if it has one (TrackingError; the
    path cannot be followed within the limits is ``limits``, as when the sweep finds a joint outside them)."""
    cause = getattr(err, "cause", None)
    if cause:
        return TRACKER_CAUSES.get(str(cause), str(cause))
    if isinstance(err, SingularityError):
        return "singularity"
    if isinstance(err, PathError):
        return "path"
    return "error"


def start_configuration(robot: Robot, path: Path, index: Index | None, options: SweepOptions):
    """The IK result at the path's first point: within the limits, seeded multi-start (Eq. 4.3)."""
    s0 = path(0.0)
    if get_task(robot.task).has_orientation and s0.Q is None:
        raise PathError(f"{robot.name} has a {robot.task!r} task: the path needs an orientation")
    return solve_ik(robot, s0, index, bounds=True, starts=options.starts, seed=options.seed)  # its point (and Q)


def figures(robot: Robot, path: Path, index: Index | None, traj: Trajectory) -> dict:
    """The record's quality figures over a (possibly partial) run of ``path``, and the first joint-limit
    violation.

    Returns a dict of :class:`PlacementRecord` fields plus ``"violation"``: None, or (k, joint) of the
    first recorded point outside the limits by more than :data:`LIMIT_TOL`.
    """
    q, t = np.asarray(traj.q, float), np.asarray(traj.t, float)
    lim = JointLimits(robot)  # unbounded sides are infinitely far
    bounded = np.isfinite(lim.lower) | np.isfinite(lim.upper)
    out = {"steps": int(len(t) - 1), "violation": None}
    if np.any(bounded):
        gap = lim.margins(q)[:, bounded]  # (points, joints): the distance to the nearer limit, < 0 outside
        out["limit_margin"] = clean_float(gap.min())
        bad = np.argwhere(gap < -LIMIT_TOL)
        if bad.size:
            k, j = bad[0]
            out["violation"] = (int(k), int(np.flatnonzero(bounded)[j]))
    if len(t) > 1:
        vmax = np.asarray(robot.model.velocityLimit, float)
        ok = np.isfinite(vmax) & (vmax > 0) & (vmax < NO_LIMIT)
        if np.any(ok):
            speed = np.abs(np.diff(q, axis=0)) / np.diff(t)[:, None]  # mean speed over each step [rad/s]
            out["speed_ratio"] = clean_float((speed[:, ok] / vmax[ok]).max())
    kin, task = robot.kinematics, get_task(robot.task)
    J = []
    for qk, tk in zip(q, t, strict=True):
        Q, _, K = kin.jacobian(qk)
        J.append(task.span_rows(Q, K, path.sample(tk).Q))  # rows with J's row space (the task's rows of K)
    out["sigma_min"] = clean_float(np.linalg.svd(np.array(J), compute_uv=False)[:, -1].min())
    if index is not None:
        z = np.array([index.value(qk, tk) for qk, tk in zip(q, t, strict=True)])
        if traj.loop_period is not None and traj.loop_drift is not None:
            # whole loops: the last point repeats the first, and the rectangle rule over a period is the
            # time average (spectrally accurate for a smooth periodic z)
            out["mean_z"] = clean_float(z[:-1].mean())
        elif len(t) > 1:
            out["mean_z"] = clean_float(0.5 * float((z[1:] + z[:-1]) @ np.diff(t)) / (t[-1] - t[0]))  # trapezoids
        else:
            out["mean_z"] = clean_float(z[0])
    if traj.loop_drift is not None and len(traj.loop_drift):
        out["loop_drift"] = clean_float(np.max(traj.loop_drift))
    if traj.position_error is not None and len(traj.position_error):
        out["position_error"] = clean_float(np.max(traj.position_error))
    name = get_task(robot.task).orientation_error_name  # the field that sums up the task's orientation error
    orientation = None if name is None else getattr(traj, name)
    if orientation is not None and len(orientation):
        out["orientation_error"] = clean_float(np.max(orientation))
    return out


def _last(q) -> tuple[float, ...] | None:
    return None if q is None else tuple(float(v) for v in q)


def evaluate_placement(robot: Robot, path: Path, index: Index | None, pose: np.ndarray, placement: int,
                       options: SweepOptions) -> PlacementRecord:
    """Track the part path ``path`` with the part at ``pose`` and return its record.

    A failure (no start, the tracker's exception, a joint outside its limits, a joint too fast with
    ``speed_limit``) is a record with ``feasible=False`` and its cause, never an exception.
    """
    T = np.asarray(pose, float)
    x, y, z, yaw = pose_coordinates(T)
    where = {"placement": int(placement), "pose": tuple(float(v) for v in T.ravel()), "x": x, "y": y, "z": z,
             "yaw": yaw}
    part = PartPath(path, T)
    try:
        ik = start_configuration(robot, part, index, options)
    except KinredundError as err:
        return PlacementRecord(**where, feasible=False, cause="start", message=str(err))
    if not ik.converged:
        return PlacementRecord(**where, feasible=False, cause="start",
                               message=f"no start configuration within the limits at the path's first point "
                                       f"({ik.reason}; residual {ik.residual:.3g})", q_last=_last(ik.q))
    try:
        traj = run_tracker(robot, part, index, ik.q, options)
    except KinredundError as err:
        partial = getattr(err, "partial", None)
        figs = figures(robot, part, index, partial) if isinstance(partial, Trajectory) and len(partial.t) else {}
        figs.pop("violation", None)
        return PlacementRecord(**where, feasible=False, cause=_cause(err), message=str(err),
                               t_fail=clean_float(getattr(err, "t", None)), q_last=_last(getattr(err, "q", None)),
                               **figs)
    figs = figures(robot, part, index, traj)
    violation = figs.pop("violation")
    if violation is not None:
        k, j = violation
        q = traj.q[k, j]
        return PlacementRecord(
            **where, feasible=False, cause="limits", t_fail=float(traj.t[k]), q_last=_last(traj.q[max(k - 1, 0)]),
            message=f"joint {j} ({robot.joint_names[j]}) left its limits [{robot.lower[j]:.6g}, "
                    f"{robot.upper[j]:.6g}] at t = {traj.t[k]:.6g} s (q = {q:.6g})", **figs)
    if options.speed_limit and figs.get("speed_ratio") is not None and figs["speed_ratio"] > 1.0:
        return PlacementRecord(**where, feasible=False, cause="speed",
                               message=f"a joint runs at {figs['speed_ratio']:.3g} times its velocity limit", **figs)
    return PlacementRecord(**where, feasible=True, **figs)
