"""Checking a saved motion (kinredund.geometry.motion, ``kinredund check``): contact between samples is found,
the least clearance is bracketed, and the command's exit codes say free / contact / bad input."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

import kinredund as kr
from kinredund.errors import GeometryError
from kinredund.geometry.motion import RESOLUTION, check_motion


def sweep(n: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """The planar 3R's arm, stretched, turning from -0.5 to 0.5 rad at joint 1 in ``n`` samples."""
    t = np.linspace(0.0, 1.0, n)
    q = np.zeros((n, 3))
    q[:, 0] = np.linspace(-0.5, 0.5, n)
    return t, q


def cell(radius: float = 0.1, at: float = 3.0) -> kr.Scene:
    """A ball on the x axis at ``at`` [m]: on the stretched arm's way at q1 = 0, clear of it at q1 = +-0.5."""
    s = kr.Scene(kr.load_robot("planar3r"))
    s.add_sphere("ball", radius, [at, 0.0, 0.0])
    return s


def test_contact_between_two_free_samples_is_found():
    s = cell()
    t, q = sweep(2)
    assert min(s.min_distance(x) for x in q) > 1.0  # both samples are far from the ball
    c = check_motion(s, t, q)
    assert c.contact and c.min_distance < 0 and "ball" in c.min_pair and 0.0 < c.min_time < 1.0
    assert c.evaluations > 2


@pytest.mark.parametrize("at", [6.3, 6.6])
def test_least_clearance_is_bracketed(at):
    """Against a dense sampling of the same motion: the true least clearance is not below the reported one by
    more than the resolution (the reported one is an evaluated configuration's, so it is not below the truth)."""
    s = cell(radius=0.05, at=at)  # beyond the arm's 6 m reach (+ capsule radius): a clearance, no contact
    t, q = sweep(5)
    c = check_motion(s, t, q)
    dense = np.linspace(0.0, 1.0, 2001)
    qs = np.outer(1.0 - dense, q[0]) + np.outer(dense, q[-1])
    truth = min(s.min_distance(x) for x in qs)
    assert not c.contact
    assert truth >= c.min_distance - RESOLUTION
    assert c.min_distance <= min(c.distance)


def test_bad_motions_are_refused():
    s = cell()
    with pytest.raises(GeometryError, match="non-decreasing"):
        check_motion(s, [1.0, 0.0], np.zeros((2, 3)))
    with pytest.raises(GeometryError, match="shape"):
        check_motion(s, [0.0, 1.0], np.zeros((2, 4)))
    with pytest.raises(GeometryError, match="resolution"):
        check_motion(s, [0.0, 1.0], np.zeros((2, 3)), resolution=0.0)


def _record(path, t, q) -> None:
    r = kr.load_robot("planar3r")
    p = np.array([r.fk(x)[:3, 3] for x in q])
    kr.Trajectory(robot="planar3r", task="planar", t=t, q=q, p=p, p_desired=p.copy()).save_json(path)


def test_check_command_exit_codes(tmp_path):
    t, q = sweep(3)
    _record(tmp_path / "run.json", t, q)
    kr.save_scene(cell(), tmp_path / "hit.json")
    kr.save_scene(cell(at=7.0), tmp_path / "free.json")
    cmd = [sys.executable, "-m", "kinredund.ui.cli", "check", str(tmp_path / "run.json"), "--scene"]
    hit = subprocess.run([*cmd, str(tmp_path / "hit.json"), "--json", str(tmp_path / "out.json")],
                         capture_output=True, text=True, timeout=120)
    assert hit.returncode == 1 and "CONTACT" in hit.stdout, hit.stderr
    out = json.loads((tmp_path / "out.json").read_text())
    assert out["contact"] is True and out["min_distance"] < 0 and len(out["distance"]) == 3
    from kinredund.ui.cli import main  # the other exit codes in-process (a subprocess costs seconds)

    assert main(["check", str(tmp_path / "run.json"), "--scene", str(tmp_path / "free.json")]) == 0
    assert main(["check", str(tmp_path / "run.json"), "--scene", str(tmp_path / "missing.json")]) == 2
