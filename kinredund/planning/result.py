"""The one result of the planning pipeline (:mod:`kinredund.planning.pipeline`): the sample record, the
plan's outcome and its cause vocabulary, for every configuration (``kr.plan``, the Chapter 6 obstacle
planner, the roadmap of Section 6.3).

Units: times [s], joints [rad or m], lengths [m].
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import ClassVar

import numpy as np

from kinredund.errors import KinredundError, check_choice
from kinredund.io import json_ready
from kinredund.trajectory import Trajectory

#: the causes of a failed plan, one vocabulary for every configuration ("" when a plan is ok):
#: ``orientation_loop`` (no closed within-limits joint path for that many cycles), ``out_of_reach`` (a sample
#: the arm cannot reach as the policy needs), ``no_minimum`` (a sample without a candidate), ``no_closed_walk``
#: (no cyclic sequence of candidates), ``tracking_failed``, ``verification`` (the motion failed its own check:
#: limits, path, closure, jumps) and ``collision`` (the motion touches the obstacle or comes under a clearance)
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
class PlanSamples:
    """The spline's knots, the samples and their candidates (one record for every configuration).

    Attributes:
        t: the knot times [s], shape (M,) (the samples, refined and inserted knots, sorted).
        q: the chosen configurations there, unwrapped one after the other, shape (M, n).
        kind: per knot ``optimum`` (a local minimum of the configuration's index: z, or the obstacle policy of
            Eq. 6.21/6.44), ``refined`` (inserted where consecutive knots jump: the configuration on the path
            closest to its neighbours' mean, Eq. 6.25), ``limit`` (inserted where a tracked motion left the
            limits) or ``roadmap`` (a node of the self-motion roadmap, Section 6.3).
        branch: per knot the chosen candidate's number at its sample (-1 for inserted knots).
        sample_t: the N sample times [s].
        candidates: per sample the candidates found, each an array (c_k, n), lowest index value first.
        objective: per sample the index value of each candidate.
        turns: the joint change over one period (whole turns of revolute joints) [rad], shape (n,).
        clearance: per knot the per-link clearance to the obstacle [m], shape (M, k), or None without one.
        weights: per sample the policy's (w1, w2) (Eq. 6.21/6.44), shape (N, 2), or None without a policy.
    """

    t: np.ndarray
    q: np.ndarray
    kind: tuple[str, ...]
    branch: tuple[int, ...]
    sample_t: np.ndarray
    candidates: tuple[np.ndarray, ...] = ()
    objective: tuple[np.ndarray, ...] = ()
    turns: np.ndarray | None = None
    clearance: np.ndarray | None = None
    weights: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.turns is None:
            object.__setattr__(self, "turns", np.zeros(np.shape(self.q)[1] if np.ndim(self.q) == 2 else 0))

    def to_dict(self) -> dict:
        """JSON-ready form (arrays to lists, nan becomes None)."""
        return json_ready({f.name: getattr(self, f.name) for f in fields(self)})


@dataclass(frozen=True)
class PlanResult:
    """The outcome of a plan (``kr.plan``, :func:`kinredund.planning.planner.plan`, ``plan_roadmap``).

    Attributes:
        ok: the motion is complete and passed its verification: inside the limits, on the path, closed after
            every loop and without a joint jump (``check``), and clear of the configuration's obstacle or
            scene (``clearance``).
        reason: "" when ok, else why not.
        trajectory: the tracked motion (None when planning stopped before tracking).
        samples: the samples and chosen branches (None when a sample has no candidate).
        check: the independent verification of ``trajectory`` (:class:`~kinredund.planning.verify.MotionCheck`:
            limits, task error, closure, jumps), or None without one.
        off_optimum: the time intervals [s] where the motion follows its reference rather than a local
            minimum of the index; empty when it follows the optima throughout.
        notes: remarks that are not failures.
        timings: wall times of the stages [s].
        partial: what the tracker returned before it failed, when it failed and gave one.
        cycles: the joint motion repeats every ``cycles`` loops of the path.
        cause: why the plan failed, one of :data:`PLAN_CAUSES` ("" when ok).
        clearance: the clearance verification of ``trajectory``: a scene's
            (:class:`~kinredund.planning.keepout.ClearanceCheck`) or an obstacle's
            (:class:`~kinredund.planning.clearance.ClearanceReport`), or None without either.
        q_spline: the spline's estimates at the trajectory's times, shape (N, n), or None.
        link_names: the links an obstacle's clearance is reported for (empty without an obstacle).
        spline_gap_max: the largest |q - q_spline| over the motion [rad] (nan without a trajectory).
    """

    ok: bool
    reason: str
    trajectory: Trajectory | None = None
    samples: PlanSamples | None = None
    check: object = None
    off_optimum: tuple[tuple[float, float], ...] = ()
    notes: tuple[str, ...] = ()
    timings: dict = field(default_factory=dict)
    partial: Trajectory | None = None
    cycles: int = 1
    cause: str = ""
    clearance: object = None
    q_spline: np.ndarray | None = None
    link_names: tuple[str, ...] = ()
    spline_gap_max: float = float("nan")

    #: the failure causes ("" when ok), as TrackingError.CAUSES
    CAUSES: ClassVar[tuple[str, ...]] = PLAN_CAUSES

    def __post_init__(self) -> None:
        check_cause(self.ok, self.cause)

    @property
    def clearance_min(self) -> np.ndarray | None:
        """Per-link minimum clearance to the obstacle along the motion [m] (the last link without its tool tip),
        or None without an obstacle's verified motion."""
        return getattr(self.clearance, "minimum", None)

    def summary(self) -> dict:
        """Scalars and short lists: the figures a report or the CLI prints."""
        s, tr, c = self.samples, self.trajectory, self.clearance
        obstacle = self.clearance_min is not None
        out = {"ok": self.ok, "reason": self.reason, "cause": self.cause, "cycles": self.cycles,
               "samples": None if s is None else int(s.sample_t.size),
               "knots": None if s is None else int(s.t.size),
               "refined": None if s is None else int(sum(k == "refined" for k in s.kind)),
               "limit_knots": None if s is None else int(sum(k == "limit" for k in s.kind)),
               "candidates": None if s is None else [int(len(cands)) for cands in s.candidates],
               "off_optimum": [list(iv) for iv in self.off_optimum],
               "check": None if self.check is None else self.check.to_dict(),
               "clearance": None if c is None or obstacle else c.to_dict()}
        if self.link_names:  # an obstacle's figures (Chapter 6)
            out.update({
                "links": list(self.link_names),
                "clearance_min": None if not obstacle else [float(v) for v in c.minimum],
                "clearance_lower_bound": None if not obstacle else [float(v) for v in c.lower_bound],
                "clearance_doubling_change": None if not obstacle or c.doubling_change is None
                else [float(v) for v in c.doubling_change],
                "penetration_max": None if not obstacle else float(c.penetration.max()),
                "spline_gap_max": float(self.spline_gap_max),
                "steps": None if tr is None else int(len(tr.t) - 1),
                "position_error_max": None if tr is None else float(np.max(tr.position_error)),
                "normality_residual_max": None if tr is None else float(np.max(tr.normality_residual)),
                "loop_drift": None if tr is None or tr.loop_drift is None else float(tr.loop_drift[0])})
        out["notes"] = list(self.notes)
        out["timings_s"] = {k: float(v) for k, v in self.timings.items()}
        return out


__all__ = ["PLAN_CAUSES", "PlanResult", "PlanSamples", "check_cause"]
