"""Issue 26, outputs and files: no output silently lost, no file written that its own reader refuses, and
bad input (hostile records, addresses, folders) named as such with the documented exit codes.

Exit codes (docs/schema.md): 0 ok, 1 failed result, 2 bad arguments, input or output paths, 3 internal
error, 130 Ctrl-C. The command-line cases run the installed console script in a subprocess, as a user
runs it; each reproducer here failed before its fix (noted at the test).
"""

from __future__ import annotations

import errno
import functools
import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import robot as cached_robot

import kinredund as kr
from kinredund.errors import KinredundError, OutputPathError, PathError
from kinredund.export import ExportError, JointSamples, read_bag, read_csv, write_bag, write_csv
from kinredund.export.rosbag import MAX_DURATION, check_topic
from kinredund.export.samples import to_nanoseconds
from kinredund.io import check_outputs, output_batch, write_json
from kinredund.paths import Circle
from kinredund.sweep import grid, sweep
from kinredund.sweep.store import read_sweep_file, write_sweep_file
from kinredund.trajectory import Trajectory
from kinredund.ui.cli import EXIT_OK, EXIT_USAGE, main

SCRIPT = Path(sys.executable).parent / "kinredund"


def _run(*args, cwd=None, timeout=300) -> subprocess.CompletedProcess:
    return subprocess.run([str(SCRIPT), *args], capture_output=True, text=True, timeout=timeout, cwd=cwd)


@functools.cache
def _planar_record() -> Trajectory:
    """A short tracked record of the planar 3R arm (fast to make and to retime)."""
    robot = cached_robot("planar3r")
    T = robot.fk(robot.home)
    path = kr.Circle(T[:3, 3] - np.array([0.1, 0.0, 0.0]), 0.1, 0.2)
    start = kr.solve_ik(robot, path(0.0), kr.JointDeviation(robot.home))
    return kr.track(robot, path, kr.JointDeviation(robot.home), start.q, steps_per_loop=40)


def _names(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


# -- 1. outputs silently lost ------------------------------------------------------------------------
# Before the fix each of these exited 0 having written one output over the other (or, for the bag,
# failed after the work with a false reason and left the folder B); `--csv out.csv/` wrote out.csv.
@pytest.mark.parametrize(("outputs", "needle"), [
    (["--json", "out", "--bag", "out"], "name the same path"),
    (["--csv", "X", "--bag", "X"], "name the same path"),
    (["--json", "a.json", "--plot", "sub/../a.json"], "name the same path"),
    (["--bag", "B", "--csv", "B/x.csv"], "lies inside --bag"),
    (["--csv", "out.csv/"], "names a folder"),
])
def test_outputs_that_would_overwrite_each_other_are_refused_before_any_work(tmp_path, outputs, needle):
    _planar_record().save_json(tmp_path / "run.json")
    out = _run("retime", "run.json", "--amax", "5", "--vmax", "2", *outputs, cwd=tmp_path)
    assert out.returncode == EXIT_USAGE and needle in out.stderr, out.stderr
    assert _names(tmp_path) == ["run.json"]  # nothing written, no folder made


def test_the_output_check_compares_resolved_paths_and_nesting(tmp_path):
    (tmp_path / "real.json").write_text("{}")
    (tmp_path / "link.json").symlink_to(tmp_path / "real.json")
    with pytest.raises(OutputPathError, match="same path"):
        check_outputs([("--json", tmp_path / "real.json", "file"), ("--html", tmp_path / "link.json", "file")])
    with pytest.raises(OutputPathError, match="lies inside"):
        check_outputs([("--csv", tmp_path / "B" / "x.csv", "file"), ("--bag", tmp_path / "B", "folder")])
    ok = check_outputs([("--json", tmp_path / "a.json", "file"), ("--bag", tmp_path / "a", "folder"),
                        ("--plot", None, "file")])
    assert set(ok) == {"--json", "--bag"}


def test_a_library_batch_refuses_a_file_inside_a_bag_folder_and_leaves_nothing(tmp_path):
    tr = _planar_record()
    with pytest.raises(OutputPathError, match="overlaps"), output_batch():
        write_bag(tr, tmp_path / "B", cached_robot("planar3r").joint_names)
        write_json(tmp_path / "B" / "x.json", 1)
    assert _names(tmp_path) == []


def test_a_batch_whose_rename_fails_midway_puts_back_the_files_it_replaced(tmp_path):
    """All or nothing: the batch renames its temporaries in turn; the second rename fails (a folder appeared at
    its path while the outputs were written), and the first output, already renamed over an existing file,
    is put back. Reproducer: a.json held the new content while b.json was missing (one output of two)."""
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    write_json(a, {"old": 1})
    os.chmod(a, 0o640)
    with pytest.raises(OutputPathError) as caught, output_batch():
        write_json(a, {"new": 1})
        write_json(tmp_path / "c.json", {"new": 1})
        write_json(b, {"new": 1})
        b.mkdir()  # the file system refuses the rename of b.json's temporary (a directory is in the way)
    assert caught.value.path == str(b) and "no output of the batch was written" in str(caught.value)
    assert json.loads(a.read_text()) == {"old": 1}
    assert os.stat(a).st_mode & 0o777 == 0o640  # the same file, put back
    assert _names(tmp_path) == ["a.json", "b.json"]  # c.json is gone again, no temporary or backup is left
    assert b.is_dir() and not list(b.iterdir())


def test_an_output_that_is_an_input_of_the_command_is_refused(tmp_path, monkeypatch, capsys):
    """An output naming the record, scene, path file or pair matrix the command reads (compared resolved) is
    refused before any work, and the input is untouched. Reproducer: `export run.json --csv run.json`, `play
    run.json --html run.json` and `check run.json --scene cell.json --json cell.json` exited 0 having replaced
    their input."""
    monkeypatch.chdir(tmp_path)
    assert main(["track", "planar3r", "--steps", "20", "--json", "run.json", "--quiet"]) == EXIT_OK
    (tmp_path / "cell.json").write_text(json.dumps({"format": "kinredund-scene", "version": 1, "objects": [
        {"name": "ball", "shape": "sphere", "radius": 0.1, "pose": {"xyz": [5.0, 0.0, 0.0]}}]}))
    (tmp_path / "sub").mkdir()
    kept = {name: (tmp_path / name).read_text() for name in ("run.json", "cell.json")}
    capsys.readouterr()
    for argv, output, read in (
            (["export", "run.json", "--csv", "run.json"], "--csv", "the record"),
            (["play", "run.json", "--html", "sub/../run.json"], "--html", "the record"),
            (["retime", "run.json", "--amax", "5", "--json", "run.json"], "--json", "the record"),
            (["check", "run.json", "--scene", "cell.json", "--json", "cell.json"], "--json", "--scene"),
            (["track", "planar3r", "--scene", "cell.json", "--partial", "cell.json"], "--partial", "--scene"),
            (["check", "run.json", "--scene", "cell.json", "--pairs", "pairs.json", "--plot", "sub/x.png",
              "--json", "./pairs.json"], "--json", "--pairs")):
        assert main(argv) == EXIT_USAGE, argv
        err = capsys.readouterr().err
        assert f"{output} names {read} this command reads" in err, (argv, err)
    assert {name: (tmp_path / name).read_text() for name in kept} == kept
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cell.json", "run.json", "sub"]


def test_a_write_protected_output_is_refused_before_any_work(tmp_path):
    """An existing output file with no write permission (chmod 444, or one this user may not write) is refused
    with the reason and what to do, before the command runs; the file is untouched. Reproducer: `kinredund track
    planar3r --json ro.json` exited 0 having replaced the protected file (a rename needs only the folder's
    permission)."""
    protected = tmp_path / "ro.json"
    protected.write_text('{"kept": true}')
    protected.chmod(0o444)
    run = subprocess.run([str(SCRIPT), "track", "planar3r", "--steps", "20", "--json", str(protected)],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == EXIT_USAGE, run.stderr
    assert f"cannot write {str(protected)!r}: it is write-protected" in run.stderr
    assert "track planar3r: tracking" not in run.stderr  # refused before the work
    assert json.loads(protected.read_text()) == {"kept": True} and _names(tmp_path) == ["ro.json"]
    with pytest.raises(OutputPathError, match="write-protected"):
        write_json(protected, {})


def test_a_sweep_that_fails_before_computing_keeps_the_existing_sweep_file(tmp_path, monkeypatch):
    """Reproducer: `sweep panda --scheduler tcp://127.0.0.1:1 --json finished.jsonl` replaced a finished
    sweep file by its bare header (an unreachable scheduler, simulated here without the 10 s timeout)."""
    from kinredund.sweep import run as sweep_run

    robot = cached_robot("planar3r")
    path = Circle(np.zeros(3), 0.05, 0.1)
    placements = grid(x=[1.5, 1.6], y=[0.0], z=0.0)
    done = tmp_path / "finished.jsonl"
    first = sweep(robot, path, kr.JointDeviation(robot.home), placements, steps_per_loop=20, workers=0, out=done)
    before = done.read_bytes()

    def unreachable(*args, **kw):
        raise KinredundError("cannot reach the Dask scheduler at 'tcp://127.0.0.1:1'")

    monkeypatch.setattr(sweep_run, "dask_client", unreachable)
    with pytest.raises(KinredundError, match="cannot reach"):
        sweep(robot, path, kr.JointDeviation(robot.home), placements, steps_per_loop=20, scheduler="tcp://127.0.0.1:1",
              out=done)
    assert done.read_bytes() == before and len(read_sweep_file(done)[1]) == len(first)


# -- 2. files their own reader refuses -------------------------------------------------------------------
def _samples(t, names=("j1", "j2")) -> JointSamples:
    t = np.asarray(t, float)
    return JointSamples(tuple(names), t, np.column_stack([np.sin(t + k) for k in range(len(names))]))


def test_times_within_one_nanosecond_are_refused_before_a_bag_is_written(tmp_path):
    """Reproducer: `track panda --speed 1e9` then `export --bag` wrote a bag whose stamps coincide (exit 0)."""
    with pytest.raises(ExportError, match="samples 1 and 2 .* same nanosecond"):
        write_bag(_samples([0.0, 1e-6, 1e-6 + 3e-10, 1e-5]), tmp_path / "bag")
    assert _names(tmp_path) == []


def test_cli_export_of_a_record_sampled_below_a_nanosecond_exits_2(tmp_path):
    tr = _planar_record()
    fast = Trajectory(**{**tr.__dict__, "t": tr.t * 1e-12})  # the same record tracked 1e12 times faster
    fast.save_json(tmp_path / "fast.json")
    out = _run("export", "fast.json", "--bag", "b", cwd=tmp_path)
    assert out.returncode == EXIT_USAGE and "same nanosecond" in out.stderr and not (tmp_path / "b").exists()


def test_times_past_a_ros_duration_or_int64_nanoseconds_are_named(tmp_path):
    """Before: t = 3e9 s wrapped the Duration's int32 seconds (exit 3); t = 1e10 s wrapped int64
    nanoseconds silently and was reported by retime as 'sampled too finely'."""
    with pytest.raises(ExportError, match="32-bit"):
        write_bag(_samples([0.0, MAX_DURATION + 1.0]), tmp_path / "bag")
    with pytest.raises(ExportError, match=r"int64"):
        to_nanoseconds([0.0, 1e10])
    with pytest.raises(ExportError, match="finite"):
        to_nanoseconds([0.0, np.inf])
    assert to_nanoseconds([0.0, 9e9])[1] == 9_000_000_000_000_000_000
    assert _names(tmp_path) == []


def test_retimed_times_past_int64_nanoseconds_are_named_not_called_too_finely_sampled(tmp_path, capsys):
    """Before: retime under tiny limits wrapped int64 nanoseconds and said 'sampled too finely'."""
    _planar_record().save_json(tmp_path / "run.json")
    assert main(["retime", str(tmp_path / "run.json"), "--amax", "1e-18", "--vmax", "1e-12",
                 "--json", str(tmp_path / "r.json")]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert "int64" in err and "too finely" not in err and not (tmp_path / "r.json").exists()


def test_joint_names_with_commas_quotes_and_newlines_read_back_from_csv(tmp_path):
    """Before: a name with ',' or a newline broke the header; read_csv refused the file written."""
    s = _samples(np.linspace(0.0, 1.0, 5), names=("a,b", 'say "hi"', "two\nlines", " spaced "))
    write_csv(s, tmp_path / "x.csv")
    back = read_csv(tmp_path / "x.csv")
    assert back.joint_names == s.joint_names and back.equal_to(s) == 0.0


@pytest.mark.parametrize("topic", ["", " ", "a b", "/a b", "//x", "/x//y", "/a\nb", "/1a", "/a/", "/", "rel",
                                   "/a__b", "~/x", "/{ns}/x", "/a-b"])
def test_a_topic_that_is_not_a_ros2_name_is_refused(topic):
    with pytest.raises(ExportError, match="topic"):
        check_topic(topic)


def test_valid_topics_pass_and_cli_refuses_a_bad_one_before_any_work(tmp_path):
    for topic in ("/joint_trajectory_controller/joint_trajectory", "/a", "/_x/y_1/Z"):
        assert check_topic(topic) == topic
    s = _samples(np.linspace(0.0, 1.0, 3))
    write_bag(s, tmp_path / "ok", topic="/arm/cmd")
    assert read_bag(tmp_path / "ok", topic="/arm/cmd").equal_to(s) == 0.0
    _planar_record().save_json(tmp_path / "run.json")
    out = _run("export", "run.json", "--bag", "b", "--topic", "//x", cwd=tmp_path)
    assert out.returncode == EXIT_USAGE and "--topic" in out.stderr and not (tmp_path / "b").exists()


# -- 4. bad input that gave internal errors ---------------------------------------------------------------
@pytest.mark.parametrize("fail", [OSError(errno.ENOSPC, "No space left on device"),
                                  sqlite3.OperationalError("database or disk is full")])
def test_a_full_disk_while_writing_a_bag_is_a_clear_error_and_leaves_nothing(tmp_path, monkeypatch, fail):
    """Before: the sqlite error of a full disk escaped as an internal error (exit 3)."""
    from rosbags.rosbag2 import Writer

    def full(self, *args, **kw):
        raise fail

    monkeypatch.setattr(Writer, "write", full)
    with pytest.raises(OutputPathError, match="bag could not be written"):
        write_bag(_samples(np.linspace(0.0, 1.0, 3)), tmp_path / "bag")
    assert _names(tmp_path) == []  # neither the bag nor its temporary folder
    _planar_record().save_json(tmp_path / "run.json")
    assert main(["export", str(tmp_path / "run.json"), "--bag", str(tmp_path / "b"),
                 "--csv", str(tmp_path / "r.csv")]) == EXIT_USAGE
    assert _names(tmp_path) == ["run.json"]  # the CSV of the same command does not land either


@pytest.mark.parametrize("address", ["foo", "tcp://host:notaport", "tcp://[::1", "http://127.0.0.1:8786", "",
                                     "tcp://127.0.0.1:99999"])
def test_a_malformed_scheduler_address_is_bad_input(address):
    from kinredund.sweep.cluster import check_scheduler

    with pytest.raises(KinredundError, match="scheduler"):
        check_scheduler(address)


def test_cli_sweep_with_a_malformed_scheduler_exits_2(tmp_path):
    """Before: distributed's ValueError came out as an internal error (exit 3)."""
    out = _run("sweep", "planar3r", "--grid", "1.5:1.6:2,0:0:1", "--scheduler", "http://127.0.0.1:1",
               "--json", "s.jsonl", cwd=tmp_path)
    assert out.returncode == EXIT_USAGE and "not a Dask scheduler address" in out.stderr, out.stderr
    assert "Traceback" not in out.stderr and _names(tmp_path) == []


_PLAN_OR_HELIX = {
    "plan_q_scalar": {"example": "6.3", "q": 1},
    "plan_wrong_joints": {"example": "6.3", "q": [[1, 2]], "t": [0]},
    "plan_t_text": {"example": "6.2", "q": [[0.0, 0.0, 0.0]], "t": "x"},
    "plan_t_decreasing": {"example": "6.2", "q": [[0.0, 0.0, 0.0]] * 2, "t": [1.0, 0.0]},
    "helix_centre_scalar": {"example": "3.2", "wrist_centre": 5},
    "helix_q_flat": {"example": "3.2", "wrist_centre": [[0, 0, 0]], "t": [0], "q": [1, 2]},
    "helix_other_robot": {"example": "3.2", "wrist_centre": [[0, 0, 0]], "t": [0], "q": [[1, 2]], "robot": "panda"},
}


@pytest.mark.parametrize("name", sorted(_PLAN_OR_HELIX))
def test_play_of_a_file_posing_as_a_plan_or_helix_record_exits_2(tmp_path, name, capsys):
    """Before: numpy and Pinocchio errors escaped as internal errors (exit 3)."""
    (tmp_path / "r.json").write_text(json.dumps(_PLAN_OR_HELIX[name]))
    assert main(["play", str(tmp_path / "r.json"), "--html", str(tmp_path / "r.html")]) == EXIT_USAGE
    assert "kinredund: error:" in capsys.readouterr().err and _names(tmp_path) == ["r.json"]


@pytest.mark.parametrize(("key", "value"), [("placement", "a"), ("placement", True), ("pose", [1, 2]),
                                            ("x", float("nan")), ("feasible", "yes"), ("steps", -1),
                                            ("loop_drift", "0"), ("q_last", [1, None]), ("cause", 3), ("yaw", None)])
def test_hostile_sweep_records_are_refused_on_resume(tmp_path, key, value):
    """Before: wrong types or NaN in a sweep file gave TypeError/ValueError (exit 3) or were kept on resume."""
    robot = cached_robot("planar3r")
    path = Circle(np.zeros(3), 0.05, 0.1)
    placements = grid(x=[1.5], y=[0.0], z=0.0)
    out = tmp_path / "s.jsonl"
    sweep(robot, path, kr.JointDeviation(robot.home), placements, steps_per_loop=20, workers=0, out=out)
    head, rows = out.read_text().splitlines()[0], [json.loads(line) for line in out.read_text().splitlines()[1:]]
    rows[0][key] = value
    out.write_text(head + "\n" + "".join(json.dumps(r) + "\n" for r in rows))  # json writes NaN as NaN
    with pytest.raises(KinredundError, match=f"placement record: {key}"):
        sweep(robot, path, kr.JointDeviation(robot.home), placements, steps_per_loop=20, workers=0, out=out,
              resume=True)


def test_a_record_repeated_in_a_sweep_file_is_refused(tmp_path):
    robot = cached_robot("planar3r")
    path = Circle(np.zeros(3), 0.05, 0.1)
    placements = grid(x=[1.5, 1.6], y=[0.0], z=0.0)
    out = tmp_path / "s.jsonl"
    records = sweep(robot, path, kr.JointDeviation(robot.home), placements, steps_per_loop=20, workers=0, out=out)
    head = read_sweep_file(out)[0]
    write_sweep_file(out, {k: v for k, v in head.items() if k not in ("kind", "schema_version")}, [records[0]] * 2)
    with pytest.raises(KinredundError, match="two records"):
        sweep(robot, path, kr.JointDeviation(robot.home), placements, steps_per_loop=20, workers=0, out=out,
              resume=True)


def test_demo_out_naming_a_file_exits_2_and_keeps_the_file(tmp_path, capsys):
    """Before: FileExistsError from mkdir (exit 3)."""
    target = tmp_path / "notes.txt"
    target.write_text("mine")
    assert main(["demo", "--out", str(target), "--quick", "--quiet"]) == EXIT_USAGE
    assert "not a folder" in capsys.readouterr().err and target.read_text() == "mine"


def test_replay_times_spanning_an_overflowing_duration_are_refused(tmp_path, capsys):
    """Before: t from -1e308 to 1e308 s (each finite) overflowed the replay's frame count (exit 3)."""
    tr = _planar_record()
    s = np.linspace(0.0, 1.0, len(tr.t))
    wide = Trajectory(**{**tr.__dict__, "t": -1e308 * (1.0 - s) + 1e308 * s})  # each time finite
    with pytest.raises(PathError, match="duration overflows"):
        wide.checked()
    wide.save_json(tmp_path / "wide.json")
    assert main(["play", str(tmp_path / "wide.json"), "--html", str(tmp_path / "w.html")]) == EXIT_USAGE
    assert "duration overflows" in capsys.readouterr().err


def test_a_record_of_a_custom_chain_reloads_that_chain_for_export_and_retime(tmp_path):
    """Before: the record named 'panda:custom', which no reader could load (exit 2 on a valid record)."""
    keep = [f"panda_joint{k}" for k in range(1, 7)]
    robot = kr.load_robot("panda", joints=keep, locked={"panda_joint7": 0.3}, task="position")
    again = kr.load_robot(robot.source, task="position")  # the task is a field of the record
    assert again.joint_names == keep and again.locked == robot.locked and again.task == "position"
    q = robot.home + 0.1
    assert np.abs(again.fk(q) - robot.fk(q)).max() == 0.0  # the same model, built again
    p0 = robot.fk(robot.home)[:3, 3]
    path = Circle(p0 - np.array([0.03, 0.0, 0.0]), 0.03, 0.1)
    traj = kr.track(robot, path, kr.JointDeviation(robot.home), robot.home, steps_per_loop=30)
    assert traj.robot == robot.source
    traj.save_json(tmp_path / "run.json")
    assert main(["export", str(tmp_path / "run.json"), "--csv", str(tmp_path / "r.csv")]) == EXIT_OK
    assert read_csv(tmp_path / "r.csv").joint_names == tuple(keep)
    assert main(["retime", str(tmp_path / "run.json"), "--amax", "5", "--json", str(tmp_path / "t.json")]) == EXIT_OK


def _zero_range_urdf(folder: Path) -> Path:
    joint = ('<joint name="{n}" type="revolute"><parent link="{a}"/><child link="{b}"/><origin xyz="{x} 0 0"/>'
             '<axis xyz="0 0 1"/><limit lower="{lo}" upper="{hi}" effort="1" velocity="1"/></joint>')
    links = "".join(f'<link name="{n}"/>' for n in ("base", "l1", "l2", "l3", "ee"))
    joints = "".join(joint.format(n=n, a=a, b=b, x=x, lo=lo, hi=hi) for n, a, b, x, lo, hi in (
        ("j1", "base", "l1", 0, -3, 3), ("j2", "l1", "l2", 1, 0.5, 0.5), ("j3", "l2", "l3", 1, -3, 3),
        ("j4", "l3", "ee", 1, -3, 3)))
    path = folder / "zero_range.urdf"
    path.write_text(f'<robot name="zr">{links}{joints}</robot>')
    return path


def test_a_zero_range_joint_is_locked_not_refused_with_a_margin_never_given(tmp_path):
    """Before: `track` refused the arm with 'a margin of 0.0 leaves no room between the limits of j2'."""
    urdf = _zero_range_urdf(tmp_path)
    robot = kr.load_robot(urdf, "ee", task="planar")
    assert robot.joint_names == ["j1", "j3", "j4"] and robot.locked == {"j2": 0.5}
    with pytest.raises(kr.URDFError, match="j2 have lower = upper"):
        kr.load_robot(urdf, "ee", task="planar", joints=["j1", "j2", "j3"])
    assert main(["track", str(urdf), "--ee-frame", "ee", "--task", "planar", "--steps", "40", "--quiet"]) == EXIT_OK


@pytest.mark.slow
def test_the_closing_of_a_killed_cluster_logs_no_traceback_and_the_levels_come_back(caplog):
    """CI once caught a Ctrl-C on a Dask sweep printing distributed's CommClosedError traceback: the client's
    batched send to a killed worker, logged at INFO while the cluster closed (a race). The teardown runs with
    distributed's loggers quiet, and their levels are put back after it."""
    import logging

    from kinredund.sweep.cluster import _quiet_distributed

    batched = logging.getLogger("distributed.batched")
    before = batched.level
    with caplog.at_level(logging.DEBUG, logger="distributed.batched"):
        batched.setLevel(logging.INFO)
        with _quiet_distributed():
            batched.info("Batched Comm Closed", exc_info=RuntimeError("CommClosedError"))
        assert not caplog.records
        batched.info("after the teardown")
        assert [r.getMessage() for r in caplog.records] == ["after the teardown"]
    batched.setLevel(before)


def test_ctrl_c_on_a_dask_sweep_is_quiet_and_names_the_file_kept(tmp_path):
    """Before: every worker printed its own KeyboardInterrupt traceback. The terminal's Ctrl-C goes to the
    whole process group: sent here with killpg once the cluster has written its first batch."""
    proc = subprocess.Popen([str(SCRIPT), "sweep", "panda", "--grid", "0.3:0.6:10,-0.2:0.2:10", "--workers", "2",
                             "--json", "s.jsonl", "--quiet"], cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        for _ in range(1200):  # the first batches land within ~20 s on 2 busy cores
            if (tmp_path / "s.jsonl").exists() or proc.poll() is not None:
                break
            time.sleep(0.1)
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    assert "kept" in err and "s.jsonl" in err
