"""The tool-axis task tracked: a 6-axis arm (UR5, n - m = 1) and the Panda (n - m = 2) follow a circle
with the tool axis held normal to its plane; the joints close loop after loop and the spin about the
axis is used."""

from __future__ import annotations

import numpy as np
import pytest

import kinredund
from kinredund.ik import solve_ik
from kinredund.indices import JointDeviation
from kinredund.paths import Circle
from kinredund.tasks import make_target
from kinredund.tasks.axis import frame_with_axis
from kinredund.tracking import track

#: a regular, well-conditioned start (the UR5's all-zero pose is singular)
STARTS = {"ur5": np.array([0.3, -1.2, 1.5, -1.9, -1.57, 0.3]), "panda": None}


def _case(name: str):
    if name == "ur5":
        r = kinredund.load_robot("ur5")  # the axis task is its default
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


@pytest.mark.parametrize("scheme", ["augmented", "velocity", "pseudoinverse"])
def test_a_non_redundant_task_tracks_its_unique_solution(scheme):
    """The UR5 pose task (n = m = 6): the index is irrelevant, every scheme tracks the unique solution
    and the joints close (the recorder's labels with an empty null space)."""
    r = kinredund.load_robot("ur5", task="pose")
    T = r.fk(r.home)
    path = Circle(T[:3, 3] - np.array([0.05, 0.0, 0.0]), 0.05, 0.1, orientation=T[:3, :3])
    index = JointDeviation(r.home)
    start = solve_ik(r, path(0.0), index)
    assert start.converged and "n = m" in start.notes
    tr = track(r, path, None if scheme == "pseudoinverse" else index, start.q, scheme=scheme, loops=2)
    assert tr.loop_drift.max() <= 1e-10 and tr.position_error.max() <= 1e-10
    if scheme != "pseudoinverse":
        assert tr.m_null_eigs.shape == (len(tr.t), 0)


def _tilting_axis_path(r):
    """A 5 cm circle whose tool axis leans 0.2 rad out of the vertical and turns with the point."""
    c = r.fk(r.home)[:3, 3] - np.array([0.05, 0.0, 0.0])
    w = 2.0 * np.pi / 3.0

    def fn(t):
        ct, st = np.cos(w * t), np.sin(w * t)
        p = c + 0.05 * np.array([ct, st, 0.0])
        v = 0.05 * w * np.array([-st, ct, 0.0])
        a = np.array([0.2 * ct, 0.2 * st, -1.0])
        adot = np.array([-0.2 * w * st, 0.2 * w * ct, 0.0])
        return p, v, a, adot

    return kinredund.AxisPath(fn, period=3.0)


def test_an_axis_path_gives_a_consistent_frame():
    """Q_d's z axis is the normalised axis, and omega is Q_d's true angular velocity (central differences)."""
    r = kinredund.load_robot("ur5")
    path = _tilting_axis_path(r)
    for t in (0.0, 0.7, 2.1):
        s = path(t)
        a = np.array([0.2 * np.cos(2 * np.pi * t / 3), 0.2 * np.sin(2 * np.pi * t / 3), -1.0])
        assert np.abs(s.Q[:, 2] - a / np.linalg.norm(a)).max() < 1e-15
        assert np.abs(s.Q.T @ s.Q - np.eye(3)).max() < 1e-15
        h = 1e-6
        Qdot = (path(t + h).Q - path(t - h).Q) / (2 * h)
        W = Qdot @ s.Q.T  # [omega]x
        assert np.abs(np.array([W[2, 1], W[0, 2], W[1, 0]]) - s.omega).max() < 1e-8
    with pytest.raises(kinredund.PathError, match="nonzero"):
        kinredund.AxisPath(lambda t: (np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3)))


def test_the_ur5_follows_a_tilting_tool_axis_given_alone():
    r = kinredund.load_robot("ur5")
    path = _tilting_axis_path(r)
    index = JointDeviation(r.home)
    start = solve_ik(r, path(0.0), index)
    assert start.converged, start.reason
    tr = track(r, path, index, start.q, loops=10)
    assert tr.loop_drift.max() <= 1e-10 and tr.position_error.max() <= 1e-10 and tr.axis_error.max() <= 1e-10
