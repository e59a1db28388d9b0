"""The shared stages of the Chapter 6 planners (Section 6.2.2): the result records, the tool-tip
allowance, and steps 2-4 (spline, resolved-rate tracking of the time-varying index of Eqs. (6.23)-(6.28),
independent clearance verification), used by :func:`kinredund.planning.planner.plan` and
:func:`kinredund.planning.roadmap.plan_roadmap`.

Units: times [s], joints [rad or m], lengths [m].
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from time import perf_counter

import numpy as np

from kinredund.errors import KinredundError, TaskError, check_choice
from kinredund.indices import TimeVaryingReference
from kinredund.io import json_ready
from kinredund.paths import Path
from kinredund.planning.clearance import ClearanceReport, LinkModel, verify_motion
from kinredund.planning.obstacles import Obstacle
from kinredund.planning.spline import JointSpline
from kinredund.tasks import get_task
from kinredund.tracking import track
from kinredund.trajectory import Trajectory


@dataclass(frozen=True)
class Samples:
    """The sample points S1..SN and the configurations chosen there.

    Attributes:
        t: sample times [s], shape (N,).
        p: end-point targets [m], shape (N, 3).
        q: chosen configurations, unwrapped one after the other, shape (N, n).
        turns: joint change over the loop (whole turns for revolute joints) [rad], shape (n,).
        candidates: the number of distinct collision-free local minima found at each sample.
        objective: the policy index at the chosen configurations.
        clearance: per-link clearance at the chosen configurations [m], shape (N, k).
        weights: (w1, w2) per sample, shape (N, 2) (nan for refinement samples).
        kind: per sample, ``policy`` (a local minimum of the policy index, Eq. 6.21/6.44) or ``refined``
            (inserted where consecutive samples jump: the configuration closest to the interpolated
            estimate, see :func:`plan`).
    """

    t: np.ndarray
    p: np.ndarray
    q: np.ndarray
    turns: np.ndarray
    candidates: tuple[int, ...]
    objective: np.ndarray
    clearance: np.ndarray
    weights: np.ndarray
    kind: tuple[str, ...] = ()

    def to_dict(self) -> dict:
        """JSON-ready form (arrays to lists, nan becomes None)."""
        return json_ready({f.name: getattr(self, f.name) for f in fields(self)})


#: the causes of a failed plan, one vocabulary for both planners ("" when a plan is ok): ``orientation_loop``
#: (no closed within-limits joint path for that many cycles), ``out_of_reach`` (a sample the arm cannot
#: reach as the policy needs), ``no_minimum`` (a sample without a candidate), ``no_closed_walk`` (no cyclic
#: sequence of candidates), ``tracking_failed``, ``verification`` (the motion failed its own check: limits,
#: path, closure, jumps) and ``collision`` (the motion touches the obstacle)
PLAN_CAUSES = ("", "orientation_loop", "out_of_reach", "no_minimum", "no_closed_walk", "tracking_failed",
               "verification", "collision")


def check_cause(ok: bool, cause: str) -> None:
    """A plan's cause is one of :data:`PLAN_CAUSES`, and empty exactly when the plan is ok.

    Raises:
        ChoiceError: an unknown cause; KinredundError: ok with a cause, or a failure without one.
    """
    check_choice("plan cause", cause, PLAN_CAUSES)
    if bool(ok) != (cause == ""):
        raise KinredundError(f"a plan is ok exactly when it has no cause, got ok={ok} cause={cause!r}")


@dataclass(frozen=True)
class PlanResult:
    """The outcome of :func:`plan`.

    Attributes:
        trajectory: the tracked motion (``meta["obstacle"]`` holds the obstacle), or None when the
            plan stopped before tracking.
        samples: the sample points and their configurations, or None when they could not be solved.
        q_spline: the spline's estimates at the trajectory's times, shape (N, n), or None.
        clearance: the full :class:`~kinredund.planning.clearance.ClearanceReport` (history), or None.
        link_names: the link names.
        spline_gap_max: the largest |q - q_spline| over the motion [rad] (nan without a trajectory).
        ok: the plan is complete and collision-free (certified positive clearance, no penetration).
        reason: "" when ok, else why not.
        timings: wall times of the stages [s].
        notes: remarks that are not failures.
        cause: why the plan failed, one of :data:`PLAN_CAUSES` ("" when ok).
    """

    trajectory: Trajectory | None
    samples: Samples | None
    q_spline: np.ndarray | None
    clearance: ClearanceReport | None
    link_names: tuple[str, ...]
    spline_gap_max: float
    ok: bool
    reason: str
    timings: dict = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    cause: str = ""

    def __post_init__(self) -> None:
        check_cause(self.ok, self.cause)

    @property
    def clearance_min(self) -> np.ndarray | None:
        """Per-link minimum clearance along the motion [m] (the last link without its tool tip), shape
        (k,): ``clearance.minimum``, or None without a verified motion."""
        return None if self.clearance is None else self.clearance.minimum

    def summary(self) -> dict:
        """Scalars and short lists: the figures a report or the CLI prints."""
        tr = self.trajectory
        c = self.clearance
        out = {
            "ok": self.ok,
            "reason": self.reason,
            "cause": self.cause,
            "samples": 0 if self.samples is None else int(len(self.samples.t)),
            "candidates": None if self.samples is None else list(self.samples.candidates),
            "links": list(self.link_names),
            "clearance_min": None if self.clearance_min is None else [float(v) for v in self.clearance_min],
            "clearance_lower_bound": None if c is None else [float(v) for v in c.lower_bound],
            "clearance_doubling_change": None if c is None or c.doubling_change is None
            else [float(v) for v in c.doubling_change],
            "penetration_max": None if c is None else float(c.penetration.max()),
            "spline_gap_max": float(self.spline_gap_max),
            "steps": None if tr is None else int(len(tr.t) - 1),
            "position_error_max": None if tr is None else float(np.max(tr.position_error)),
            "normality_residual_max": None if tr is None else float(np.max(tr.normality_residual)),
            "loop_drift": None if tr is None or tr.loop_drift is None else float(tr.loop_drift[0]),
            "timings_s": {k: float(v) for k, v in self.timings.items()},
        }
        return out


def tool_tip_length(model: LinkModel, tool_tip) -> float:
    """The last link's tip left out of its clearance [m]: default 1/6 of its length, else checked in
    [0, length)."""
    length = float(model.lengths[-1])
    if tool_tip is None:
        return length / 6.0
    try:
        tip = float(tool_tip)
    except (TypeError, ValueError) as err:
        raise TaskError(f"tool_tip must be a length [m], got {tool_tip!r}") from err
    if not (0.0 <= tip < length):
        raise TaskError(f"tool_tip must be in [0, {length:.4g}) m (the last link), got {tool_tip!r}")
    return tip


def winding(path: Path, obstacle: Obstacle, period: float, count: int = 720) -> float:
    """How many times the path goes around the obstacle's centre in the xy-plane over one period."""
    ts = np.linspace(0.0, period, count + 1)
    xy = np.array([path(t).p[:2] for t in ts]) - obstacle.center[:2]
    ang = np.unwrap(np.arctan2(xy[:, 1], xy[:, 0]))
    return float((ang[-1] - ang[0]) / (2 * np.pi))


def failure(reason, names, timings, samples=None, trajectory=None, notes=(), *, cause: str) -> PlanResult:
    """A :class:`PlanResult` with ``ok=False``, ``reason`` and ``cause``, without a verified motion."""
    return PlanResult(trajectory, samples, None, None, names, float("nan"), False, reason, timings, tuple(notes),
                      cause)


def track_and_verify(robot, path: Path, obstacle: Obstacle, smp: Samples, model: LinkModel, *, planner: str,
                      spline: str, steps_per_loop: int, substeps: int, link_radius: float, tool_tip: float,
                      check_doubling: bool, progress, meta: dict, timings: dict, t_start: float,
                      notes=()) -> PlanResult:
    """Steps 2-4 of the off-line procedure from the samples, for :func:`plan` and
    :func:`~kinredund.planning.roadmap.plan_roadmap`.

    The spline estimates theta*(t) (Section 6.2.2.2), the resolved-rate tracking of
    h = 1/2 ||theta - theta*(t)||^2 with the spline's rate as feed-forward (Eqs. 6.23-6.28), and the
    clearance verification, independent of the indices. ``planner`` and ``meta`` (the caller's entries,
    then the user's) go into ``Trajectory.meta``; the stages' wall times are added to ``timings``.
    """
    names = model.names
    notes = list(notes)
    # -- step 2: the spline estimates (Section 6.2.2.2) -------------------------------------------
    spl = JointSpline(smp.t, smp.q, float(path.period), smp.turns, spline)

    # -- step 3: resolved-rate tracking of h = 1/2 ||theta - theta*(t)||^2 (Eqs. 6.23-6.28) -------
    t1 = perf_counter()
    info = {"planner": planner, "obstacle": obstacle.to_dict(), "samples": smp.to_dict(), "spline": spline,
            "links": list(names), "link_lengths": model.lengths.tolist(), "link_radius": float(link_radius),
            "tool_tip": float(tool_tip), **meta}
    try:
        traj = track(robot, path, TimeVaryingReference(spl, spl.rate), smp.q[0], steps_per_loop=steps_per_loop,
                     loops=1, progress=None if progress is None else lambda d, n: progress(d, n, "tracking"),
                     meta=info, limits=False)
    except KinredundError as err:
        timings["tracking_s"] = perf_counter() - t1
        return failure(f"the tracking failed: {err}", names, timings, smp, notes=notes, cause="tracking_failed")
    timings["tracking_s"] = perf_counter() - t1
    q_spline = spl.values(traj.t)
    gap = float(np.abs(traj.q - q_spline).max())

    # -- step 4: verification, independent of the indices ----------------------------------------
    t2 = perf_counter()
    if progress is not None:
        progress(0, 1, "clearance")
    rep = verify_motion(robot, obstacle, traj.t, traj.q, substeps=substeps, radius=link_radius,
                        tool_tip=tool_tip, check_doubling=check_doubling, path=path)
    timings["clearance_s"] = perf_counter() - t2
    if progress is not None:
        progress(1, 1, "clearance")
    timings["total_s"] = perf_counter() - t_start
    reason = ""
    if not rep.collision_free:
        parts = [f"{nm} for t in [{a:.4g}, {b:.4g}] s (depth {d:.3g} m)" for nm, a, b, d in rep.intervals()[:6]]
        if not parts:
            k = int(np.argmin(rep.lower_bound))
            parts.append(f"{names[k]}: certified clearance {rep.lower_bound[k]:.3g} m is not positive")
        reason = "the motion touches or penetrates the obstacle: " + "; ".join(parts)
        if get_task(robot.task).planar and abs(winding(path, obstacle, float(path.period))) > 0.5:
            reason += (" - unavoidable here: a planar arm whose end point goes around a convex obstacle and "
                       "whose joints return to their start sweeps over every point of the obstacle "
                       "(see kinredund.planning.planner)")
    if traj.loop_drift is not None and traj.loop_drift[0] > 1e-6:
        notes.append(f"the joint path does not close: drift {traj.loop_drift[0]:.3g} rad after one loop")
    return PlanResult(traj, smp, q_spline, rep, names, gap, not reason, reason, timings, tuple(notes),
                      "collision" if reason else "")
