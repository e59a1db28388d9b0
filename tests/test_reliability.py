"""Reliability (issue 18): output files, the CLI's exit codes, and bad input named in the project's words.

The CLI's exit codes and file behaviour checked here are those docs/schema.md states.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import IK_TOL

import kinredund
from kinredund.errors import JointVectorError, KinredundError, OutputPathError, PathError, TaskError
from kinredund.ik.solve import MAX_STARTS, solve_ik
from kinredund.indices import CustomIndex, minimum_norm
from kinredund.io import atomic_write_text, output_batch, read_json_object, write_json
from kinredund.ui.cli import EXIT_FAILED, EXIT_INTERNAL, EXIT_OK, EXIT_SIGINT, EXIT_SIGPIPE, EXIT_USAGE, main

SCRIPT = Path(sys.executable).parent / "kinredund"  # the console script pip installed next to the interpreter


def _run(*args, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([str(SCRIPT), *args], capture_output=True, text=True, timeout=300, **kw)


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(".tmp"))


# -- output files -----------------------------------------------------------------------------------
@pytest.mark.parametrize("device", ["/dev/null", "/dev/full"])
def test_a_device_is_refused_and_stays_a_device(device):
    if not os.path.exists(device):
        pytest.skip(f"no {device} here")
    before = os.stat(device)
    with pytest.raises(OutputPathError, match="character device"):
        write_json(device, {"a": 1})
    after = os.stat(device)
    assert (after.st_mode, after.st_rdev, after.st_ino) == (before.st_mode, before.st_rdev, before.st_ino)


def test_a_directory_and_a_fifo_are_refused(tmp_path):
    with pytest.raises(OutputPathError, match="a directory"):
        atomic_write_text(tmp_path, "x")
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    with pytest.raises(OutputPathError, match="a FIFO"):
        write_json(fifo, [1])
    assert fifo.is_fifo() and _leftovers(tmp_path) == []
    with pytest.raises(OutputPathError, match="not a folder|Not a directory"):
        write_json(tmp_path / "pipe" / "under.json", [1])


def test_a_symlink_is_followed_to_its_regular_file_and_stays_a_link(tmp_path):
    real = tmp_path / "real.json"
    real.write_text("{}")
    real.chmod(0o640)
    link = tmp_path / "link.json"
    link.symlink_to(real)
    assert write_json(link, {"b": 2}) == link
    assert link.is_symlink() and json.loads(real.read_text()) == {"b": 2}
    assert (real.stat().st_mode & 0o777) == 0o640  # a replaced file keeps its permissions
    dangling = tmp_path / "dangling.json"
    dangling.symlink_to(tmp_path / "nowhere.json")
    with pytest.raises(OutputPathError, match="does not exist"):
        write_json(dangling, {})
    to_dir = tmp_path / "to_dir"
    to_dir.symlink_to(tmp_path)
    with pytest.raises(OutputPathError, match="a directory .through the symbolic link"):
        write_json(to_dir, {})
    assert not (tmp_path / "nowhere.json").exists() and _leftovers(tmp_path) == []


def test_a_failed_write_removes_its_temporary_and_keeps_the_old_file(tmp_path):
    target = tmp_path / "out.json"
    target.write_text('"old"')

    def fail(fh):
        fh.write("half")
        raise RuntimeError("disk on fire")

    from kinredund.io import atomic_write

    with pytest.raises(RuntimeError):
        atomic_write(target, fail)
    assert target.read_text() == '"old"' and _leftovers(tmp_path) == []


def test_an_unwritable_folder_is_an_output_path_error(tmp_path):
    if os.geteuid() == 0:  # root writes anywhere: use a path under a regular file instead
        (tmp_path / "file").write_text("")
        bad = tmp_path / "file" / "x.json"
    else:
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        bad = locked / "x.json"
    with pytest.raises(OutputPathError) as err:
        write_json(bad, {})
    assert str(bad) in str(err.value) and ".tmp" not in str(err.value)


def test_a_batch_lands_every_file_or_none(tmp_path):
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    with pytest.raises(ValueError), output_batch():
        write_json(a, 1)
        assert not a.exists()  # staged: renamed only when the batch ends
        raise ValueError("the second output failed")
    assert not a.exists() and _leftovers(tmp_path) == []
    with output_batch():
        write_json(a, 1)
        write_json(b, 2)
        write_json(a, 3)  # the last write of a path wins
    assert json.loads(a.read_text()) == 3 and json.loads(b.read_text()) == 2 and _leftovers(tmp_path) == []


# -- reading JSON ---------------------------------------------------------------------------------
def test_non_utf8_and_deeply_nested_json_are_named_errors(tmp_path):
    bad = tmp_path / "latin1.json"
    bad.write_bytes(b'{"t": "\xe9"}')
    with pytest.raises(KinredundError, match="not UTF-8"):
        read_json_object(bad)
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(KinredundError, match="too deeply"):
        read_json_object(deep)
    assert main(["track", "planar3r", "--path", "file", "--path-file", str(bad)]) == EXIT_USAGE
    assert main(["play", str(deep), "--html", str(tmp_path / "x.html")]) == EXIT_USAGE


# -- the CLI's exit codes -----------------------------------------------------------------------------
def test_exit_0_and_1_say_what_they_mean(tmp_path):
    ok = _run("ik", "planar3r", "--target", "3.8,3")
    assert ok.returncode == EXIT_OK and json.loads(ok.stdout)["converged"] is True
    far = _run("ik", "planar3r", "--target", "30,30", "--json", str(tmp_path / "far.json"))
    assert far.returncode == EXIT_FAILED and "IK did not converge" in far.stderr
    assert json.loads((tmp_path / "far.json").read_text())["converged"] is False  # a failed check is still written


@pytest.mark.parametrize("where", ["dir", "device", "under_a_file", "bad_suffix"])
def test_an_invalid_output_path_exits_2_before_any_work(tmp_path, where):
    (tmp_path / "file").write_text("")
    plot = {"dir": str(tmp_path), "device": "/dev/full", "under_a_file": str(tmp_path / "file" / "x.png"),
            "bad_suffix": str(tmp_path / "x.bmp")}[where]
    js = tmp_path / "out.json"
    out = _run("reproduce", "4.1", "--steps", "20", "--json", str(js), "--plot", plot)
    assert out.returncode == EXIT_USAGE, out.stderr
    assert out.stderr.startswith("kinredund: error:") and ".tmp" not in out.stderr and "internal" not in out.stderr
    assert not js.exists() and _leftovers(tmp_path) == []
    if where == "device":
        assert Path("/dev/full").is_char_device()


def test_json_is_not_left_behind_when_a_later_output_fails(tmp_path, monkeypatch, capsys):
    import kinredund.ui.plots as plots

    def broken(*args, **kw):
        raise OutputPathError(args[1], "No space left on device")

    monkeypatch.setattr(plots, "plot_joint_histories", broken)
    js, png = tmp_path / "t.json", tmp_path / "t.png"
    code = main(["track", "planar3r", "--radius", "0.5", "--speed", "0.5", "--steps", "20", "--json", str(js),
                 "--plot", str(png)])
    assert code == EXIT_USAGE and "No space left" in capsys.readouterr().err
    assert not js.exists() and not png.exists() and _leftovers(tmp_path) == []


def test_an_internal_error_exits_3_and_asks_for_a_report(monkeypatch, capsys):
    import kinredund.model.loader as loader

    def bug():
        raise ZeroDivisionError("a bug")

    monkeypatch.setattr(loader, "robot_table", bug)  # what `kinredund robots` lists
    assert main(["robots"]) == EXIT_INTERNAL
    err = capsys.readouterr().err
    assert "internal error: ZeroDivisionError" in err and "please report it" in err


def test_bad_input_exits_2_naming_it(tmp_path):
    out = _run("ik", "planar3r", "--target", "3.8,3", "--seed", "-1")
    assert out.returncode == EXIT_USAGE and "seed" in out.stderr
    out = _run("ik", "planar3r", "--target", "3.8,3", "--starts", str(10 * MAX_STARTS))
    assert out.returncode == EXIT_USAGE and f"at most {MAX_STARTS}" in out.stderr
    out = _run("track", "planar3r", "--radius", "nan")
    assert out.returncode == EXIT_USAGE and "radius" in out.stderr and "centre" not in out.stderr


def test_sigint_exits_130_with_a_short_message(tmp_path):
    js = tmp_path / "long.json"
    # an unreachable pose from MAX_STARTS starts: minutes of work on the Python iteration (the compiled one takes
    # seconds, kinredund.ik.compiled), so the interrupt always comes first
    proc = subprocess.Popen([str(SCRIPT), "ik", "panda", "--target", "3,3,3", "--rpy", "0,0,0", "--index", "home",
                             "--starts", str(MAX_STARTS), "--json", str(js)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "KINREDUND_BACKEND": "python"})
    time.sleep(6.0)  # past the imports (about 1 s) and into the run
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == EXIT_SIGINT
    assert "interrupted" in err and "Traceback" not in err and len(err.splitlines()) <= 3
    assert not js.exists() and _leftovers(tmp_path) == []


def test_a_closed_stdout_exits_quietly():
    out = subprocess.run(f"'{SCRIPT}' robots | head -c 1 >/dev/null; echo \"${{PIPESTATUS[0]}}\"",
                         shell=True, executable="/bin/bash", capture_output=True, text=True, timeout=300)
    assert out.stderr == "" and int(out.stdout) in (EXIT_OK, EXIT_SIGPIPE)


# -- bad input in the library -----------------------------------------------------------------------
@pytest.mark.parametrize("q", [[True, 0, 1], ["1", "2", "3"], [1 + 2j, 0, 0], [1 + 0j, 0, 0], [1, "2", 3],
                               np.array([True, False, True]), [10**400, 0, 0]])
def test_joint_vectors_must_be_real_numbers(q):
    r = kinredund.load_robot("planar3r")
    with pytest.raises(JointVectorError):
        r.fk(q)


def test_a_path_file_with_a_non_rotation_is_refused(tmp_path):
    from kinredund.paths import read_path_file

    t = np.linspace(0, 1, 6)
    p = np.column_stack([np.cos(2 * np.pi * t), np.sin(2 * np.pi * t), np.zeros(6)])
    f = tmp_path / "path.json"
    f.write_text(json.dumps({"t": t.tolist(), "p": p.tolist(), "Q": [(2 * np.eye(3)).tolist()] * 6}))
    with pytest.raises(PathError, match="not a rotation matrix"):
        read_path_file(f)
    f.write_text(json.dumps({"t": t.tolist(), "p": p.tolist(), "Q": [np.eye(3).tolist()] * 6}))
    assert read_path_file(f)[0](0.3).Q is not None


def test_a_nan_radius_is_blamed_on_the_radius():
    from kinredund.paths import Circle

    with pytest.raises(PathError, match="radius"):
        Circle([float("nan")] * 3, float("nan"))


def test_seed_and_starts_are_checked():
    r = kinredund.load_robot("planar3r")
    for bad in ({"seed": -1}, {"seed": 1.5}, {"starts": MAX_STARTS + 1}, {"timeout": True}):
        with pytest.raises(TaskError):
            solve_ik(r, [3.8, 3.0], **bad)


# -- IK reports that agree with themselves ----------------------------------------------------------
def test_an_exact_solution_from_a_singular_seed_is_converged():
    r = kinredund.load_robot("planar3r")
    q = np.zeros(3)  # stretched: the constraint Jacobian has rank 1; z = |q|^2 / 2 is at its minimum 0 there
    res = solve_ik(r, r.fk(q)[:2, 3], minimum_norm(3), q0=q)
    assert res.converged and res.iterations == 0 and res.reason == ""
    assert res.residual == 0.0 and res.normality_residual == 0.0  # computed from exact zeros: no rounding


def test_an_index_unbounded_below_does_not_return_a_point_worse_than_its_seed():
    r = kinredund.load_robot("puma7").with_task("position")
    neg = CustomIndex(lambda q: -0.5 * q @ q, lambda q: -q, lambda q: -np.eye(7))
    rng = np.random.default_rng(1)
    for _ in range(3):
        q0 = r.random_configuration(rng, 0.1)
        res = solve_ik(r, r.fk(q0)[:3, 3], neg, q0=q0)
        # on the target (the seed is, exactly) and no higher z than the seed; not converged: there is no minimum
        assert res.residual < IK_TOL and res.objective <= neg.value(q0)
        assert not res.converged and "bounded below" in res.reason and "out of reach" not in res.reason


def test_an_index_that_turns_nan_is_reported_not_silent():
    r = kinredund.load_robot("planar3r")
    q0 = np.array([0.3, 0.5, 0.4])

    def grad(q):
        return np.full(3, np.nan) if np.abs(q - q0).max() > 0.05 else 2 * q

    idx = CustomIndex(lambda q: float(q @ q), grad, lambda q: 2 * np.eye(3))
    res = solve_ik(r, r.fk(np.array([0.5, 0.7, 0.2]))[:2, 3], idx, q0=q0)
    assert not res.converged and "non-finite" in res.reason
    assert np.isfinite(res.normality_residual) and np.abs(res.q - q0).max() <= 0.05


# -- records ----------------------------------------------------------------------------------------
def test_a_record_of_a_relative_urdf_replays_from_another_folder(tmp_path, monkeypatch):
    from kinredund.model.loader import shipped_robot_dir
    from kinredund.trajectory import Trajectory

    work, elsewhere = tmp_path / "work", tmp_path / "elsewhere"
    work.mkdir()
    elsewhere.mkdir()
    (work / "arm.urdf").write_text((shipped_robot_dir() / "planar3r.urdf").read_text())
    monkeypatch.chdir(work)
    assert main(["track", "arm.urdf", "--task", "planar", "--radius", "0.5", "--speed", "0.5", "--steps", "20",
                 "--q0", "0.3,1,1", "--json", "rec.json"]) == EXIT_OK
    assert Trajectory.load_json(work / "rec.json").robot == str(work / "arm.urdf")
    monkeypatch.chdir(elsewhere)
    from kinredund.model.loader import load_robot

    assert load_robot(Trajectory.load_json(work / "rec.json").robot).nq == 3


def test_a_sweep_file_that_is_not_utf8_is_a_named_error(tmp_path):
    from kinredund.sweep import read_sweep_file

    bad = tmp_path / "s.jsonl"
    bad.write_bytes(b'{"kind": "\xff"}\n')
    with pytest.raises(KinredundError, match="not UTF-8 text"):
        read_sweep_file(bad)
