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

import math
from dataclasses import dataclass

import numpy as np

from kinredund.errors import (
    KinredundError,
    OptionError,
    PathError,
    SingularityError,
    check_choice,
    check_count,
    check_positive,
    check_size,
)
from kinredund.geometry import check_motion
from kinredund.ik.solve import solve_ik
from kinredund.indices import Index
from kinredund.model.robot import Robot
from kinredund.paths import Path
from kinredund.sweep.cell import SweepScene
from kinredund.sweep.placement import PartPath, pose_coordinates
from kinredund.sweep.record import PlacementRecord, clean_float
from kinredund.tasks import get_task
from kinredund.tracking import MODES, SCHEMES, track
from kinredund.tracking.constraints.joint_limits import JointLimits
from kinredund.tracking.tracker import check_limits_option
from kinredund.trajectory import Trajectory, fastest_joint

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
            default; False: the thesis's unconstrained scheme; True: held, which only the default mode's augmented
            and velocity schemes can: asked of another, the options are refused here, before any placement runs).
        speed_limit: a joint faster than its velocity limit makes the placement infeasible (cause
            ``speed``); by default the speed ratio is only reported (a slower path execution fixes it).
        starts, seed: multi-start of the start configuration's IK (:func:`kinredund.ik.solve_ik`).
        scene: the cell (:class:`~kinredund.sweep.cell.SweepScene`, made by :func:`~kinredund.sweep.cell.sweep_scene`
            from a Scene; world objects in the part frame), or None: no clearance checked.
        clearance: with a scene, a placement whose motion comes closer than this to an object or to itself
            (the scene's self pairs) [m] is infeasible (cause ``collision``); 0 (default): only contact is.
        clearance_resolution: the least clearance along a run is found to within this [m]
            (:func:`kinredund.geometry.check_motion`'s ``resolution``; its cost grows fast as it shrinks: on
            the Panda 1e-4 m took 5 to 20 times the evaluations of 1e-3 m); a run within it of contact touches.
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
    scene: SweepScene | None = None
    clearance: float = 0.0
    clearance_resolution: float = 1e-3

    def __post_init__(self) -> None:  # sizes bounded here, before any placement runs (errors.SIZES)
        spl = check_count(self.steps_per_loop, 1, "steps_per_loop", OptionError)
        loops = check_count(self.loops, 1, "loops", OptionError)
        check_size(spl * loops, f"loops x steps_per_loop ({loops} x {spl})", "samples", OptionError)
        check_size(self.starts, "starts", "starts", OptionError)
        check_count(self.seed, 0, "seed", OptionError)
        check_choice("scheme", self.scheme, SCHEMES)
        check_choice("mode", self.mode, MODES)
        if self.limits is not None and not isinstance(self.limits, (bool, np.bool_)):
            raise OptionError(f"limits must be None, True or False, got {self.limits!r}")
        check_limits_option(None if self.limits is None else bool(self.limits), self.mode, self.scheme)  # once
        if self.duration is not None:
            check_positive(self.duration, "duration [s]", OptionError)
            check_size(self.steps, "steps", "samples", OptionError)
        if self.scene is not None and not isinstance(self.scene, SweepScene):
            raise OptionError(f"SweepOptions.scene must be a SweepScene (sweep_scene(scene, robot)), got "
                                 f"{type(self.scene).__name__}")
        check_clearance(self.clearance, self.scene is not None)
        check_positive(self.clearance_resolution, "clearance_resolution [m]", OptionError)


def check_clearance(c, scene: bool) -> float:
    """``c`` if it is a finite distance >= 0 [m] (> 0 only with a ``scene``), else OptionError."""
    if isinstance(c, bool) or not isinstance(c, (int, float)) or not math.isfinite(c) or c < 0:
        raise OptionError(f"clearance must be a finite distance >= 0 [m], got {c!r}")
    if c > 0 and not scene:
        raise OptionError(f"clearance = {c:g} m needs a scene (scene=, --scene FILE): the distances are its")
    return float(c)


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
    fastest = fastest_joint(t, q, robot.model.velocityLimit)  # mean speed over each step against the limit
    if fastest is not None:
        out["speed_ratio"] = clean_float(fastest[0])
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


def clearance(robot: Robot, pose: np.ndarray, traj: Trajectory, options: SweepOptions) -> tuple[dict, dict | None]:
    """The run's least clearance in the cell at ``pose`` (between samples too), and the collision, if any.

    Returns:
        (figures, collision): the record's ``clearance`` [m], ``clearance_pair``, ``clearance_time`` [s] and
        ``clearance_q`` (empty without a scene; None values when the scene checks no pair); and None, or the
        record fields ``cause`` (``collision``; ``error`` when the motion could not be checked), ``message``,
        ``t_fail`` (the time of the least clearance) and ``q_last`` (the last recorded configuration before the
        first one under the clearance) when the motion comes within ``options.clearance`` or touches
        (:func:`kinredund.geometry.check_motion`: its least clearance is within its resolution of the true one,
        and ``contact`` when it is below that resolution).
    """
    if options.scene is None:
        return {}, None
    t, q = np.asarray(traj.t, float), np.asarray(traj.q, float)
    try:
        c = check_motion(options.scene.placed(robot, pose), t, q, resolution=options.clearance_resolution)
    except KinredundError as err:  # a stretch that cannot be proven within check_motion's budget of midpoints
        return {}, {"cause": "error", "message": f"the clearance could not be checked: {err}"}
    if c.min_pair is None:
        return {"clearance": None, "clearance_pair": None, "clearance_time": None, "clearance_q": None}, None
    qc = np.array([np.interp(c.min_time, t, q[:, j]) for j in range(q.shape[1])])  # joints linear between samples
    near = {"clearance": clean_float(c.min_distance), "clearance_pair": tuple(c.min_pair),
            "clearance_time": clean_float(c.min_time), "clearance_q": _last(qc)}
    if not (c.contact or c.min_distance < options.clearance):
        return near, None
    under = np.flatnonzero(c.distance < max(options.clearance, c.resolution))
    first = int(under[0]) if len(under) else int(np.searchsorted(t, c.min_time, side="right"))
    a, b = c.min_pair
    what = (f"touch (signed distance {c.min_distance:.4g} m)" if c.contact
            else f"come within {c.min_distance:.4g} m (the clearance is {options.clearance:g} m)")
    return near, {"cause": "collision", "message": f"{a} and {b} {what} at t = {c.min_time:.6g} s",
                  "t_fail": clean_float(c.min_time), "q_last": _last(q[first - 1]) if first > 0 else None}


def _last(q) -> tuple[float, ...] | None:
    return None if q is None else tuple(float(v) for v in q)


def evaluate_placement(robot: Robot, path: Path, index: Index | None, pose: np.ndarray, placement: int,
                       options: SweepOptions) -> PlacementRecord:
    """Track the part path ``path`` with the part at ``pose`` and return its record.

    A failure (no start, the tracker's exception, a joint outside its limits, a closed path whose joints
    do not close or a rate burst (the record's own checks), a run within the clearance of the cell with a
    scene, a joint too fast with ``speed_limit``: the first that applies, in this order) is a
    record with ``feasible=False`` and its cause, never an exception.
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
        ran = isinstance(partial, Trajectory) and len(partial.t)
        figs = {**figures(robot, part, index, partial), **clearance(robot, T, partial, options)[0]} if ran else {}
        # (the tracker's failure is the cause; the partial run's clearance is a figure)
        figs.pop("violation", None)
        return PlacementRecord(**where, feasible=False, cause=_cause(err), message=str(err),
                               t_fail=clean_float(getattr(err, "t", None)), q_last=_last(getattr(err, "q", None)),
                               **figs)
    figs = figures(robot, part, index, traj)
    violation = figs.pop("violation")
    near, collision = clearance(robot, T, traj, options)
    figs.update(near)
    if violation is not None:
        k, j = violation
        q = traj.q[k, j]
        return PlacementRecord(
            **where, feasible=False, cause="limits", t_fail=float(traj.t[k]), q_last=_last(traj.q[max(k - 1, 0)]),
            message=f"joint {j} ({robot.joint_names[j]}) left its limits [{robot.lower[j]:.6g}, "
                    f"{robot.upper[j]:.6g}] at t = {traj.t[k]:.6g} s (q = {q:.6g})", **figs)
    for check in ("loop_not_closed", "rate_burst"):  # a run that ended but is not what was asked
        if check in traj.meta:
            return PlacementRecord(**where, feasible=False, cause=check, message=traj.meta[check], **figs)
    if collision is not None:
        return PlacementRecord(**where, feasible=False, **collision, **figs)
    if options.speed_limit and figs.get("speed_ratio") is not None and figs["speed_ratio"] > 1.0:
        return PlacementRecord(**where, feasible=False, cause="speed",
                               message=f"a joint runs at {figs['speed_ratio']:.3g} times its velocity limit", **figs)
    return PlacementRecord(**where, feasible=True, **figs)
