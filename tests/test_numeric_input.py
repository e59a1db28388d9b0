"""Numeric bad input to tracking and IK (issue 26): each refused in the project's words, or made to work,
never an internal error (exit 3) or a wrong path reported as success."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from conftest import robot

import kinredund
from kinredund.errors import OptionError, TaskError
from kinredund.indices import CustomIndex, JointDeviation
from kinredund.paths import Circle
from kinredund.tracking import Tracker
from kinredund.ui.cli import EXIT_FAILED, EXIT_USAGE, main


@pytest.mark.parametrize(("name", "task"), [("panda", None), ("ur5", None), ("xarm7", None), ("panda", "position")])
def test_track_ellipse_starts_at_the_tool_and_holds_its_orientation(name, task, tmp_path):
    """`--path ellipse` was an internal error on arms with orientation, and with --task position it was put at
    z = 0, at the base: it runs through the start point, in its horizontal plane, orientation held."""
    js = tmp_path / "e.json"
    argv = ["track", name, "--path", "ellipse", "--steps", "60", "--quiet", "--json", str(js)]
    assert main(argv + (["--task", task] if task else [])) == 0
    data = json.loads(js.read_text())
    r = kinredund.load_robot(name, task=task)
    start = r.fk(r.home)
    p_d = np.array(data["p_desired"])
    assert np.abs(p_d[0] - start[:3, 3]).max() < 1e-12  # through the tool's start point
    assert np.abs(p_d[:, 2] - start[2, 3]).max() < 1e-12  # in its horizontal plane
    assert np.ptp(p_d[:, 0]) == pytest.approx(0.2, rel=1e-3)  # 2 a = 2 x the default radius 0.1 m
    for k in (0, len(data["q"]) // 3, len(data["q"]) - 1):  # the record's joints do it (fresh FK)
        T = r.fk(np.array(data["q"][k]))
        assert np.linalg.norm(T[:3, 3] - p_d[k]) < 1e-9
        if r.task != "position":
            assert np.linalg.norm(T[:3, 2] - start[:3, 2]) < 1e-9  # the tool axis of the start, held


def test_track_refuses_a_time_step_out_of_range(capsys):
    assert main(["track", "panda", "--speed", "1e-300", "--quiet"]) == EXIT_USAGE  # was an OverflowError
    assert "time step" in capsys.readouterr().err
    r = robot("panda")
    path = Circle(r.fk(r.home)[:3, 3], 0.1, 1e-300, orientation=r.fk(r.home)[:3, :3])
    with pytest.raises(OptionError, match="outside the range the tracker computes in"):
        kinredund.track(r, path, JointDeviation(r.home), r.home)
    for dt in (1e-200, 1e200):  # a Tracker stepped by the user: the same range (it took 1e-200 s)
        with pytest.raises(OptionError, match=re.escape(f"time step {dt:.3g} s is outside the range")):
            Tracker(r, path, JointDeviation(r.home), r.home, dt)


def _panda_tracker(index, **kw):
    r = robot("panda")
    T = r.fk(r.home)
    path = Circle(T[:3, 3] - np.array([0.1, 0.0, 0.0]), 0.1, 0.1, orientation=T[:3, :3])
    return Tracker(r, path, index, r.home, 0.01, **kw)


def test_tracker_refuses_an_index_that_does_not_fit_the_arm():
    with pytest.raises(TaskError, match=r"7 joints; gradient/Hessian shapes \(7,\)/\(7, 7\) needed"):
        _panda_tracker(JointDeviation(np.zeros(5)))  # was numpy's broadcast ValueError
    wrong_grad = CustomIndex(lambda q: 0.0, lambda q: np.zeros(3), lambda q: np.eye(7))
    with pytest.raises(TaskError, match="shapes"):
        _panda_tracker(wrong_grad)
    not_a_number = CustomIndex(lambda q: "z", lambda q: np.zeros(7), lambda q: np.eye(7))
    with pytest.raises(TaskError, match="cannot be evaluated"):
        _panda_tracker(not_a_number)


def test_booleans_are_not_vectors_and_strings_are_not_flags():
    with pytest.raises(TaskError, match="not booleans"):
        kinredund.load_robot("ur5", task="axis", tool_axis=[True, False, False])
    r = robot("ur5", "axis")
    with pytest.raises(TaskError, match="bounds must be True or False"):
        kinredund.solve_ik(r, r.fk(r.home), None, bounds="yes")
    with pytest.raises(TaskError, match="bounds must be True or False"):
        kinredund.check_optimality(r, r.fk(r.home), r.home, bounds=1)
    with pytest.raises(OptionError, match="strict must be True or False"):
        _panda_tracker(JointDeviation(robot("panda").home), strict="no")
    assert kinredund.solve_ik(r, r.fk(r.home), None, bounds=np.bool_(True)).converged  # numpy's bool is one


def test_a_tracking_stop_exits_1_and_names_the_last_good_q(capsys):
    """`track panda --radius 0.5` stops where the bounded optimum is not strongly stable; the message printed
    a diverged corrector iterate 30-120 rad outside the limits as "q"."""
    assert main(["track", "panda", "--radius", "0.5", "--quiet"]) == EXIT_FAILED
    err = capsys.readouterr().err
    assert err.startswith("kinredund: tracking stopped:")
    qs = re.findall(r"q = \[([^\]]*)\]", err)
    assert qs, err
    r = robot("panda")
    for text in qs:  # every q the message prints is the last good point: inside the limits
        q = np.array([float(v) for v in text.split(",")])
        assert np.all(q >= r.lower - 1e-6) and np.all(q <= r.upper + 1e-6), text


def test_a_default_run_out_of_reach_says_what_to_change(capsys):
    assert main(["track", "kinova", "--quiet"]) == EXIT_FAILED
    err = capsys.readouterr().err
    assert "out_of_reach" in err and "Hint:" in err and "smaller --radius" in err
    assert main(["track", "kinova", "--radius", "0.05", "--steps", "100", "--quiet"]) == 0  # the hint works


def test_a_self_contradictory_path_is_named_so_not_a_fold():
    """A FunctionPath whose v is not the derivative of its p stopped with cause ``fold``."""
    from kinredund.indices import minimum_norm
    from kinredund.paths import FunctionPath

    r = robot("planar3r")
    q0 = np.array([0.2, 0.6, 0.6])
    p0 = r.fk(q0)[:2, 3]

    def fn(t):
        return p0 + np.array([0.3 * t, 0.0]), np.array([-3.0, 0.0])  # p moves at +0.3 m/s, v says -3

    with pytest.raises(kinredund.TrackingError, match="self-contradictory path") as err:
        kinredund.track(r, FunctionPath(fn), minimum_norm(3), q0, duration=1.0, steps=40)
    assert err.value.cause == "path_inconsistent"
