"""Export (issue 16): CSV, JSON and ROS 2 bag give back the same numbers; bad outputs leave nothing behind.

Also the ``kinredund retime`` and ``kinredund export`` commands, run as a user runs them (a subprocess of
the installed console script).
"""

from __future__ import annotations

import functools
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import robot as cached_robot

from kinredund.export import DEFAULT_TOPIC, ExportError, JointSamples, read_bag, read_csv, write_bag, write_csv
from kinredund.problems import panda_circle
from kinredund.retime import limits_for, retime
from kinredund.tracking import track
from kinredund.trajectory import Trajectory

PANDA_AMAX = "15,7.5,10,12.5,15,20,20"
SCRIPT = Path(sys.executable).parent / "kinredund"


@functools.cache
def records() -> tuple[Trajectory, Trajectory]:
    """(tracked, retimed): the Panda circle at 1 m/s, retimed over two loops."""
    robot, path, index, q0 = panda_circle(cached_robot("panda"), speed=1.0)
    tr = track(robot, path, index, q0, steps_per_loop=100)
    res = retime(tr, limits_for(robot, [float(v) for v in PANDA_AMAX.split(",")]), robot=robot, loops=2)
    return tr, res.trajectory


def names() -> list[str]:
    return cached_robot("panda").joint_names


def samples() -> JointSamples:
    return JointSamples.from_trajectory(records()[1], names())


def test_csv_round_trip_is_exact(tmp_path):
    s = samples()
    write_csv(s, tmp_path / "r.csv")
    back = read_csv(tmp_path / "r.csv")
    assert back.equal_to(s) == 0.0  # repr-precision text reads back to the same doubles
    header = (tmp_path / "r.csv").read_text().splitlines()[0].split(",")
    assert header[:2] == ["t", "q_panda_joint1"] and header[-1] == "qddot_panda_joint7" and len(header) == 22


@pytest.mark.parametrize(("joint_names", "words"), [(["a", "b"], "2 names for a record of 7 joints"),
                                                     ([f"j{k}" for k in range(8)], "8 names for a record of 7 joints"),
                                                     ("abcdefg", "a list of names"), (7, "a list of names")])
def test_write_csv_says_the_joint_names_do_not_fit_the_record(tmp_path, joint_names, words):
    """joint_names of the wrong count or kind: an ExportError saying so (the count was reported as q of the wrong
    shape for a robot of 2 joints, a string as seven one-letter names), and no file."""
    with pytest.raises(ExportError, match=words):
        write_csv(records()[0], tmp_path / "r.csv", joint_names=joint_names)
    assert not (tmp_path / "r.csv").exists()


def test_bag_round_trip_message_type_and_joint_names(tmp_path):
    from rosbags.rosbag2 import Reader

    s = samples()
    write_bag(s, tmp_path / "bag")
    back = read_bag(tmp_path / "bag")
    assert back.equal_to(s) <= 1e-12  # times are whole nanoseconds; the rest are the same doubles
    assert back.joint_names == tuple(names()) == tuple(f"panda_joint{k}" for k in range(1, 8))
    with Reader(tmp_path / "bag") as reader:
        assert [(c.topic, c.msgtype, c.msgcount) for c in reader.connections] == [
            (DEFAULT_TOPIC, "trajectory_msgs/msg/JointTrajectory", 1)]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag"]  # the temporary folder is gone


def test_read_bag_refuses_what_is_not_a_bag_folder_of_regular_files(tmp_path):
    """read_bag goes through the project's input check (kinredund.inputs): a missing path, a file, a folder
    without metadata.yaml, a FIFO or a folder where metadata.yaml or a storage file should be: an ExportError naming
    the path and what a bag is. Reproducer: a FIFO metadata.yaml hung the reader (here cut by SIGALRM), a file gave
    "Unrecognized storage format '.json'", a folder in place of the database "disk I/O error"."""
    import shutil
    import signal

    write_bag(samples(), tmp_path / "bag")
    (tmp_path / "run.json").write_text("{}")
    (db,) = (p.name for p in (tmp_path / "bag").iterdir() if p.suffix == ".db3")

    def bag_with(name: str, make) -> Path:
        folder = tmp_path / f"bag_{make.__name__}_{name.replace('.', '_')}"
        shutil.copytree(tmp_path / "bag", folder)
        (folder / name).unlink()
        make(folder / name)
        return folder

    def hung(signum, frame):
        raise TimeoutError("read_bag blocked on a FIFO")

    cases = [(tmp_path / "nope", "nope", "no such folder"), (tmp_path / "run.json", "run.json", "a regular file"),
             (bag_with("metadata.yaml", lambda p: None), "metadata.yaml", "No such file"),
             (bag_with("metadata.yaml", os.mkfifo), "metadata.yaml", "a FIFO"),
             (bag_with(db, os.mkdir), db, "a directory"),
             (bag_with(db, os.mkfifo), db, "a FIFO")]  # last: sqlite blocked on it where no signal could cut it
    previous = signal.signal(signal.SIGALRM, hung)
    try:
        for folder, named, why in cases:
            signal.alarm(20)  # a hang guard, not a speed bar
            with pytest.raises(ExportError) as caught:
                read_bag(folder)
            signal.alarm(0)
            text = str(caught.value)
            assert named in text and why in text and "a ROS 2 bag is a folder" in text, text
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def test_json_csv_and_bag_agree(tmp_path):
    tr = records()[1]
    tr.save_json(tmp_path / "r.json")
    via_json = JointSamples.from_trajectory(Trajectory.load_json(tmp_path / "r.json"), names())
    write_csv(tr, tmp_path / "r.csv", names())
    write_bag(tr, tmp_path / "bag", names())
    for other in (read_csv(tmp_path / "r.csv"), read_bag(tmp_path / "bag")):
        assert other.equal_to(via_json) <= 1e-12


def test_a_record_without_rates_exports_positions_only(tmp_path):
    tr = records()[0]
    write_csv(tr, tmp_path / "t.csv", names())
    write_bag(tr, tmp_path / "bag", names())
    for back in (read_csv(tmp_path / "t.csv"), read_bag(tmp_path / "bag")):
        assert back.qdot is None and back.qddot is None
        assert np.abs(back.q - tr.q).max() == 0.0
    # the bag holds whole nanoseconds: the tracked times (multiples of T/100) move by < 0.5 ns
    assert np.abs(read_bag(tmp_path / "bag").t - tr.t).max() <= 0.5e-9


def test_an_existing_bag_folder_is_refused_and_left_alone(tmp_path):
    (tmp_path / "bag").mkdir()
    (tmp_path / "bag" / "mine.txt").write_text("keep")
    with pytest.raises(ExportError, match="exists already"):
        write_bag(samples(), tmp_path / "bag")
    assert [p.name for p in (tmp_path / "bag").iterdir()] == ["mine.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag"]


def test_a_failed_bag_write_leaves_nothing(tmp_path, monkeypatch):
    from rosbags.rosbag2 import Writer

    def broken(self, *args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(Writer, "write", broken)
    with pytest.raises(OSError, match="disk full"):
        write_bag(samples(), tmp_path / "bag")
    assert list(tmp_path.iterdir()) == []


def test_a_bag_lands_with_the_other_outputs_of_its_batch(tmp_path):
    """A bag written inside an output batch (as every CLI command runs) appears when the batch ends, with the
    batch's files, and not at all when it is interrupted (kinredund.io.atomic_write_dir)."""
    from kinredund.io import output_batch, write_json

    bag, other = tmp_path / "bag", tmp_path / "run.json"
    with pytest.raises(KeyboardInterrupt), output_batch():
        write_bag(samples(), bag)
        write_json(other, {"a": 1})
        assert not bag.exists() and not other.exists()  # staged
        raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []  # nothing, no temporary left
    with output_batch():
        write_bag(samples(), bag)
        assert not bag.exists()
    assert read_bag(bag).equal_to(samples()) <= 1e-12  # times are whole nanoseconds
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag"]


def test_files_that_are_not_exports_are_refused(tmp_path):
    (tmp_path / "a.csv").write_text("time,x\n0,1\n")
    with pytest.raises(ExportError, match="not a kinredund CSV export"):
        read_csv(tmp_path / "a.csv")
    (tmp_path / "b.csv").write_text("t,q_j1\n0,nan\n")
    with pytest.raises(ExportError, match="non-finite"):
        read_csv(tmp_path / "b.csv")
    with pytest.raises(ExportError, match="cannot read the bag"):
        read_bag(tmp_path)
    with pytest.raises(ExportError, match="Trajectory"):
        JointSamples.from_trajectory({"t": [0.0]}, names())
    with pytest.raises(ExportError, match="joint names"):
        JointSamples(("a", "a"), np.zeros(1), np.zeros((1, 2))).checked()


# -- the commands, as a user runs them -------------------------------------------------------------
def run(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(SCRIPT), *args], capture_output=True, text=True, cwd=cwd, timeout=300)


def test_cli_retime_writes_json_csv_bag_and_plot(tmp_path):
    records()[0].save_json(tmp_path / "tr.json")
    out = run("retime", "tr.json", "--amax", PANDA_AMAX, "--loops", "3", "--json", "r.json", "--csv", "r.csv",
              "--bag", "rb", "--plot", "r.png", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert "time-optimal" in out.stdout and "periodic" in out.stdout
    rec = Trajectory.load_json(tmp_path / "r.json")
    assert len(rec.t) == 3 * 100 + 1 and rec.qdot is not None
    vmax = np.asarray(cached_robot("panda").model.velocityLimit)
    assert np.max(np.abs(rec.qdot) / vmax) <= 1 + 1e-6
    s = JointSamples.from_trajectory(rec, names())
    assert read_csv(tmp_path / "r.csv").equal_to(s) == 0.0
    assert read_bag(tmp_path / "rb").equal_to(s) <= 1e-12
    assert (tmp_path / "r.png").read_bytes()[:4] == b"\x89PNG"


def test_cli_retime_rest_to_rest_bag_starts_and_ends_at_rest(tmp_path):
    records()[0].save_json(tmp_path / "tr.json")
    out = run("retime", "tr.json", "--amax", PANDA_AMAX, "--loops", "2", "--rest-to-rest", "--bag", "rb", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert "from rest to rest" in out.stdout
    back = read_bag(tmp_path / "rb")
    assert back.t[0] == 0.0 and len(back.t) == 2 * 100 + 1
    assert np.abs(back.qdot[0]).max() == 0.0 and np.abs(back.qdot[-1]).max() == 0.0


def test_cli_export(tmp_path):
    records()[1].save_json(tmp_path / "r.json")
    out = run("export", "r.json", "--csv", "r.csv", "--bag", "rb", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert read_csv(tmp_path / "r.csv").equal_to(samples()) == 0.0
    assert read_bag(tmp_path / "rb").equal_to(samples()) <= 1e-12
    out = run("export", "r.json", cwd=tmp_path)
    assert out.returncode == 2 and "--csv FILE and/or --bag FOLDER" in out.stderr


def test_cli_export_of_a_partial_record_is_refused_unless_allowed_and_says_where_it_stopped(tmp_path, capsys):
    """A stopped run's partial record (track --partial) was exported as if complete: nothing in the CSV or the
    bag, nor on the terminal, said that its samples end where the run stopped."""
    from kinredund.ui.cli import main

    part = tmp_path / "part.json"
    assert main(["track", "planar3r", "--radius", "2.5", "--index", "min-norm", "--quiet", "--steps", "40",
                 "--partial", str(part)]) == 1  # out of reach: a run that stopped
    stop = json.loads(part.read_text())["failure"]
    said = f"{part} is a partial record: its run stopped at t = {stop['t']:.6g} s ({stop['cause']})"
    capsys.readouterr()
    for argv in (["export", str(part), "--csv", str(tmp_path / "p.csv")],
                 ["retime", str(part), "--amax", "5", "--json", str(tmp_path / "r.json")]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert said in err and "--allow-partial" in err, err
        assert not Path(argv[-1]).exists()
    assert main(["export", str(part), "--csv", str(tmp_path / "p.csv"), "--allow-partial"]) == 0
    assert said in capsys.readouterr().err
    back = Trajectory.load_json(part)
    assert np.array_equal(read_csv(tmp_path / "p.csv").q, back.q) and back.t[-1] <= stop["t"]
    back.save_json(tmp_path / "lib.json")  # a library run's err.partial.save_json(): marked partial in its meta
    assert main(["export", str(tmp_path / "lib.json"), "--bag", str(tmp_path / "bag")]) == 2
    assert "lib.json is a partial record: its run stopped at a time it did not record" in capsys.readouterr().err
    data = json.loads(part.read_text())
    (tmp_path / "bad.json").write_text(json.dumps({**data, "failure": 3}))  # a malformed stop is no stop to drop
    assert main(["export", str(tmp_path / "bad.json"), "--csv", str(tmp_path / "b.csv"), "--allow-partial"]) == 2
    assert "'failure' (a partial record's stop) must be an object with its 'cause', got 3" in capsys.readouterr().err


@pytest.mark.parametrize("amax", ["0", "-1", "nan", "1,2"])
def test_cli_bad_limits_write_nothing(tmp_path, amax):
    records()[0].save_json(tmp_path / "tr.json")
    out = run("retime", "tr.json", f"--amax={amax}", "--json", "r.json", "--csv", "r.csv", "--bag", "rb", cwd=tmp_path)
    assert out.returncode == 2 and "kinredund: error:" in out.stderr and "acceleration limit" in out.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tr.json"]


def test_cli_existing_bag_folder_writes_nothing(tmp_path):
    records()[0].save_json(tmp_path / "tr.json")
    (tmp_path / "rb").mkdir()
    out = run("retime", "tr.json", "--amax", "10", "--json", "r.json", "--bag", "rb", cwd=tmp_path)
    assert out.returncode == 2 and "exists already" in out.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rb", "tr.json"] and not any((tmp_path / "rb").iterdir())


def test_cli_input_that_is_not_a_joint_trajectory(tmp_path):
    (tmp_path / "ik.json").write_text(json.dumps({"robot": "panda", "q": [0.0] * 7}))
    out = run("retime", "ik.json", "--amax", "10", "--csv", "r.csv", cwd=tmp_path)
    assert out.returncode == 2 and "not a kinredund record" in out.stderr
    assert not (tmp_path / "r.csv").exists()


def test_cli_help_texts():
    out = subprocess.run([str(SCRIPT), "retime", "--help"], capture_output=True, text=True)
    text = " ".join(out.stdout.split())  # argparse wraps lines (and breaks words at hyphens)
    assert out.returncode == 0 and "--amax" in text and "--tool-speed" in text and "same optimal joint path" in text
    out = subprocess.run([str(SCRIPT), "export", "--help"], capture_output=True, text=True)
    assert out.returncode == 0 and "--bag" in out.stdout and "JointTrajectory" in out.stdout


def test_a_topic_without_a_bag_is_refused_before_any_work(tmp_path, monkeypatch, capsys):
    """``--topic`` names the bag's topic: given without ``--bag`` (export, retime) it is refused, not ignored
    (both exited 0 and wrote only the CSV or JSON, the topic dropped)."""
    from kinredund.ui.cli import EXIT_USAGE, main

    monkeypatch.chdir(tmp_path)
    assert main(["track", "planar3r", "--steps", "20", "--json", "run.json", "--quiet"]) == 0
    capsys.readouterr()
    for argv in (["export", "run.json", "--csv", "x.csv", "--topic", "/arm/cmd"],
                 ["retime", "run.json", "--amax", "5", "--json", "t.json", "--topic", "/arm/cmd"]):
        assert main(argv) == EXIT_USAGE, argv
        err = capsys.readouterr().err
        assert "--topic names the bag's topic" in err and "--bag FOLDER" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.json"]
    assert main(["export", "run.json", "--bag", "b", "--topic", "/arm/cmd"]) == 0
    assert read_bag(tmp_path / "b", topic="/arm/cmd").q.shape == (21, 3)

