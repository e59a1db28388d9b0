"""The tool-axis task tracked: a 6-axis arm (UR5, n - m = 1) and the Panda (n - m = 2) follow a circle
with the tool axis held normal to its plane; the joints close loop after loop and the spin about the
axis is used."""

from __future__ import annotations

import numpy as np
import pytest

import kinredund
from kinredund.ik import solve_ik
from kinredund.indices import JointDeviation
from kinredund.model.robot import erd_share_dir
from kinredund.paths import Circle
from kinredund.tasks import make_target
from kinredund.tasks.axis import frame_with_axis
from kinredund.tracking.resolved_rate import track

#: a regular, well-conditioned start (the UR5's all-zero pose is singular)
STARTS = {"ur5": np.array([0.3, -1.2, 1.5, -1.9, -1.57, 0.3]), "panda": None}


def _case(name: str):
    if name == "ur5":
        r = kinredund.load_robot(erd_share_dir() / "ur_description/urdf/ur5_robot.urdf", task="axis")
    else:
        r = kinredund.load_robot("panda", task="axis")
    seed = r.home if STARTS[name] is None else STARTS[name]
    T = r.fk(seed)
    normal = np.array([0.0, 0.0, 1.0])
    # the tool points down, normal to the circle's plane: the path's rotation has z axis -normal
    path = Circle(T[:3, 3] - np.array([0.06, 0.0, 0.0]), 0.06, 0.12, normal=tuple(normal),
                  orientation=frame_with_axis(-normal))
    index = JointDeviation(seed + 0.2)  # not the start itself: the optimum pulls on every joint
    s0 = path(0.0)
    start = solve_ik(r, make_target("axis", (s0.Q, s0.p)), index, q0=seed)
    assert start.converged, start.reason
    return r, path, index, start.q


def _spin(Q: np.ndarray) -> float:
    """The tool's spin about its axis: the angle of its x axis in the plane normal to -e_z [rad]."""
    x = Q[:, 0]
    return float(np.arctan2(x[1], x[0]))


@pytest.mark.parametrize("name", ["ur5", "panda"])
@pytest.mark.parametrize("scheme", ["augmented", "velocity"])
def test_axis_task_tracks_a_circle_and_closes(name, scheme):
    r, path, index, q0 = _case(name)
    tr = track(r, path, index, q0, scheme=scheme, loops=10)
    # the default mode's corrector holds the task and normality to ~1e-12 (Newton to 1e-12 scaled)
    assert tr.position_error.max() <= 1e-10 and tr.axis_error.max() <= 1e-10
    assert tr.loop_drift.max() <= 1e-10
    assert tr.normality_residual.max() <= 1e-9
    axes = np.array([r.fk(q)[:3, 2] for q in tr.q[::20]])
    assert np.abs(axes - (0.0, 0.0, -1.0)).max() < 1e-10  # held normal to the plane
    spins = np.unwrap([_spin(r.fk(q)[:3, :3]) for q in tr.q[: 201 : 10]])
    assert np.ptp(spins) > 1e-2  # the free spin is used: it changes along the loop
