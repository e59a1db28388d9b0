"""Chapter 6 examples: off-line planning with collision avoidance, planar (6.2) and spatial (6.3).

Parameters adopted (``docs/thesis_readings.md``; the OCR lost several):

- 6.2: the planar 3R of Chapter 6 (links 0.5, 0.6, 0.3 m); the obstacle is the region inside an ellipse
  centred at (0.9, 0) m with its major axis at 20 deg to X; we choose semi-axes a = 0.3 m, b = 0.15 m
  (a/b = 2) and the end point traces the ellipse itself, once per 2 pi s.
- 6.3: see :mod:`kinredund.planning.spatial` (scaled CYBOTECH P-15 architecture, elliptic cylinder,
  the plane-cut trajectory of Eqs. 6.45-6.50).

Two facts decide the planar case before any planning (:func:`planar_feasibility`):

1. *Reach.* With the last link along the outward normal at the end point (Eqs. 6.19-6.20), joint 3
   sits at W = P + l3 n. On the far side of an obstacle centred 0.9 m from the base, |W| >= 0.9 + l3 =
   1.2 m > l1 + l2 = 1.1 m whatever the semi-axes: the policy cannot be met on the far side with these
   link lengths.
2. *Topology.* A planar chain anchored outside a convex obstacle whose end point goes once around it
   and whose joints come back to their start must sweep over every interior point of the obstacle at
   some time (the chain would otherwise contract the end point's loop, which winds once around that
   point, in the plane minus the point). So no closed collision-free plan of Section 6.2 exists for any
   link lengths; the planner reports the penetration it finds.

Both are reported as the failure's reason; the plan is never called done.
"""

from __future__ import annotations

import math

import numpy as np

from kinredund.errors import check_choice
from kinredund.io import write_json
from kinredund.model.loader import load_robot
from kinredund.model.robot import Robot
from kinredund.paths import Ellipse
from kinredund.planning import spatial
from kinredund.planning.clearance import link_model
from kinredund.planning.obstacles import EllipseObstacle, Obstacle
from kinredund.planning.planner import plan, wrist_reach
from kinredund.planning.result import PlanResult
from kinredund.planning.roadmap import plan_roadmap

CASES = ("6.2", "6.3")
PLANAR_CENTER = (0.9, 0.0)
PLANAR_ANGLE = math.radians(20.0)
PLANAR_A, PLANAR_B = 0.3, 0.15


def planar_setup(a: float = PLANAR_A, b: float = PLANAR_B):
    """(robot, path, obstacle) of Section 6.2."""
    robot = load_robot("planar3r_ch6")
    obstacle = EllipseObstacle(center=PLANAR_CENTER, a=a, b=b, angle=PLANAR_ANGLE)
    path = Ellipse(PLANAR_CENTER, a, b, angle=PLANAR_ANGLE, rate=1.0)
    return robot, path, obstacle


def case_setup(case: str) -> tuple[Robot, object, Obstacle]:
    """(robot, path, obstacle) of Section 6.2 or 6.3 (6.3: the scaled P-15 of
    :func:`kinredund.planning.spatial.scaled_p15`, which :func:`kinredund.load_robot` loads by name as
    ``cybotech_p15_x8``).

    Raises:
        ChoiceError: an unknown case.
    """
    check_choice("planning case", case, CASES)
    if case == "6.2":
        return planar_setup()
    return spatial.scaled_p15(), spatial.section_path(), spatial.section_cylinder()


def case_robot(case: str) -> Robot:
    """The robot of Section 6.2 or 6.3 (for playback of the planned trajectory)."""
    return case_setup(case)[0]


def planar_feasibility(robot, path, obstacle, samples: int = 720) -> dict:
    """The reach of joint 3 needed by the normal-tool policy, against what links 1-2 can reach
    (:func:`kinredund.planning.planner.wrist_reach` along the path).

    Returns:
        {"wrist_reach_needed": max |P + l3 n - O1| [m], "wrist_reach_available": l1 + l2 [m],
         "reachable": bool, "worst_t": time of the worst point [s], "reason": str}
    """
    ts = np.linspace(0.0, path.period, samples, endpoint=False)
    p = np.array([path(t).p for t in ts])
    wr = wrist_reach(robot, p, obstacle.normal_at(p))  # joint 3 at W = P + l3 n (Eqs. 6.19-6.20)
    k = int(np.argmax(wr.distance))
    need, available = float(wr.distance[k]), float(wr.reach)
    reachable = bool(need <= available)
    reason = "" if reachable else (
        f"the policy puts joint 3 at P + l3 n, {need:.3f} m from the base at t = {ts[k]:.3f} s, beyond the "
        f"{available:.3f} m that links 1-2 reach; and a planar chain whose end point goes once around a convex "
        "obstacle with closing joints must sweep over the obstacle (see kinredund.thesis.chapter6)")
    return {"wrist_reach_needed": need, "wrist_reach_available": available, "reachable": reachable,
            "worst_t": float(ts[k]), "reason": reason}


def _run(case: str, samples: int, progress) -> tuple[PlanResult, dict, Robot, Obstacle]:
    robot, path, obstacle = case_setup(case)
    if case == "6.2":
        check = planar_feasibility(robot, path, obstacle)
        extra = {"links": [float(v) for v in np.abs(robot.hd.a)], "feasibility": check,
                 "obstacle": obstacle.to_dict()}
        if not check["reachable"]:
            return (PlanResult(False, check["reason"], cause="out_of_reach", link_names=link_model(robot).names), extra,
                    robot, obstacle)
        result = plan(robot, path, obstacle, samples=samples, progress=progress, meta={"example": "6.2"})
        return result, extra, robot, obstacle
    # the policy's optima at the samples do not join into a collision-free loop on this arm; the branch
    # comes from a roadmap of the self-motion manifold (kinredund.planning.roadmap)
    result = plan_roadmap(robot, path, obstacle, progress=progress, meta={"example": "6.3"})
    return result, {"links": None, "obstacle": obstacle.to_dict(), "scale": spatial.P15_SCALE}, robot, obstacle


def run_case(case: str, samples: int = 9, progress=None) -> tuple[PlanResult, dict]:
    """Plan Section 6.2 or 6.3 (``samples`` sample points for 6.2; 6.3 plans on a roadmap); returns the
    result and extra figures for the report.

    Raises:
        ChoiceError: an unknown case.
    """
    result, extra, _, _ = _run(case, samples, progress)
    return result, extra


def to_json_dict(case: str, result: PlanResult, extra: dict) -> dict:
    """The JSON record of ``kinredund reproduce 6.x`` (docs/schema.md)."""
    tr = result.trajectory
    summary = result.summary()
    return {
        "example": case,
        "ok": result.ok,
        "reason": result.reason,
        "t": [] if tr is None else tr.t.tolist(),
        "q": [] if tr is None else tr.q.tolist(),
        "q_spline": [] if result.q_spline is None else np.asarray(result.q_spline).tolist(),
        "samples": None if result.samples is None else result.samples.to_dict(),
        "clearance_min": summary["clearance_min"],
        "links": extra.get("links"),
        "obstacle": extra["obstacle"],
        "summary": summary,
        **{k: v for k, v in extra.items() if k not in ("links", "obstacle")},
    }


def reproduce(case: str, json_path=None, progress=None, samples: int = 9) -> tuple[PlanResult, dict, Robot, Obstacle]:
    """Run Section 6.2 or 6.3 and write its JSON (atomically, also for a failed plan); returns the result,
    the extra figures, the robot and the obstacle (:func:`kinredund.ui.reproduce.plan_case` adds the plots).

    ``progress(done, total, stage)`` follows the whole run (see :func:`kinredund.planning.planner.plan`).
    """
    result, extra, robot, obstacle = _run(case, samples, progress)
    if json_path is not None:
        if progress is not None:
            progress(0, 1, "writing the JSON")
        write_json(json_path, to_json_dict(case, result, extra))
    return result, extra, robot, obstacle
