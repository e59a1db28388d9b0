"""No hang and no unbounded size on any input (issue 26): every file a user names is read only if it is a
regular file of bounded size (kinredund.io.read_input), every size a user can ask for is bounded in one
place (kinredund.errors.SIZES) and refused before any work, a Dask scheduler that never answers is an error.

The command-line checks run the installed script in a subprocess with a timeout, so a hang fails the test
instead of blocking the suite.
"""

from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from kinredund.errors import (
    MAX_JOINTS,
    MAX_PLACEMENTS,
    MAX_SAMPLES,
    MAX_WORKERS,
    SIZES,
    InputFileError,
    KinredundError,
    OptionError,
    TaskError,
    URDFError,
    check_array,
    check_size,
)
from kinredund.io import check_regular_file, read_input, read_json_object

SCRIPT = Path(sys.executable).parent / "kinredund"
#: [s] a refusal takes a second or two (imports, a robot); this only turns a hang into a failure
HANG = 120


def _run(*args, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run([str(SCRIPT), *map(str, args)], capture_output=True, text=True, timeout=HANG, cwd=cwd)


def _in_thread(fn, seconds: float = 20.0):
    """``fn()``'s exception (or None), failing if it is still running after ``seconds``: a hang fails."""
    box = {}

    def call():
        try:
            fn()
        except BaseException as err:  # noqa: BLE001 - handed back to the test
            box["error"] = err

    thread = threading.Thread(target=call, daemon=True)
    thread.start()
    thread.join(seconds)
    assert not thread.is_alive(), f"{fn} still blocked after {seconds} s"
    return box.get("error")


def _main(*args) -> int:
    """``kinredund ARGS`` in this process, in a thread (:func:`_in_thread`): its exit code."""
    from kinredund.ui.cli import main

    code = []
    assert _in_thread(lambda: code.append(main(list(map(str, args))))) is None
    return code[0]


@pytest.fixture
def fifo(tmp_path) -> Path:
    path = tmp_path / "pipe.urdf"
    os.mkfifo(path)
    return path


# -- input files -----------------------------------------------------------------------------------------
def test_a_fifo_is_refused_without_blocking(fifo):
    for reader in (read_input, read_json_object, check_regular_file):
        err = _in_thread(lambda reader=reader: reader(fifo))
        assert isinstance(err, InputFileError) and "a FIFO" in str(err) and "regular files" in str(err)
    from kinredund import load_robot

    err = _in_thread(lambda: load_robot(str(fifo)))
    assert isinstance(err, URDFError) and "a FIFO" in str(err)


def test_a_number_is_not_taken_as_a_file_descriptor(tmp_path):
    """os.stat takes an int as a file descriptor: read_path_file(k), k an open regular file's descriptor, passed the
    check and raised TypeError from os.open; True (descriptor 1) was called "a FIFO" where stdout was a pipe."""
    from kinredund import read_path_file
    from kinredund.export import ExportError, read_csv

    good = tmp_path / "path.json"
    good.write_text('{"t": [0, 1, 2, 3], "p": [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 0, 0]]}')
    with open(good) as fh:
        for value in (fh.fileno(), True):
            for reader in (read_input, check_regular_file, read_path_file):
                words = rf"cannot read '{value}': not a file path \({type(value).__name__}\)"
                with pytest.raises(InputFileError, match=words):
                    reader(value)
            with pytest.raises(ExportError, match=r"not a file path"):
                read_csv(value)


def test_devices_folders_missing_and_oversized_files_are_refused(tmp_path):
    for path, what in (("/dev/zero", "a character device"), (tmp_path, "a directory"),
                       (tmp_path / "none.json", "No such file")):
        err = _in_thread(lambda path=path: read_input(path))
        assert isinstance(err, InputFileError) and what in str(err), (path, err)
    big = tmp_path / "big.json"
    big.write_bytes(b"{}" + b" " * 98)
    assert read_input(big, limit=100) == big.read_bytes()
    with pytest.raises(InputFileError, match="100 bytes, more than the 99 bytes kinredund reads"):
        read_input(big, limit=99)
    with pytest.raises(InputFileError, match="the path is empty"):
        read_input("")


def test_cli_refuses_a_fifo_as_urdf(fifo, tmp_path):
    """`kinredund track FIFO` blocked for ever in open() (a FIFO waits for a writer)."""
    out = _run("track", fifo, "--quiet", cwd=tmp_path)
    assert out.returncode == 2 and "a FIFO: kinredund reads only regular files" in out.stderr, out.stderr


def test_cli_refuses_a_fifo_as_path_file_play_and_retime_input(fifo, tmp_path, capsys):
    """The same for --path-file, play and retime (run in a thread: a hang fails after a timeout)."""
    for args in (["track", "planar3r", "--path", "file", "--path-file", fifo, "--quiet"],
                 ["play", fifo, "--html", tmp_path / "x.html"], ["retime", fifo, "--amax", "5"]):
        assert _main(*args) == 2 and "a FIFO: kinredund reads only regular files" in capsys.readouterr().err, args
    assert not (tmp_path / "x.html").exists()


def test_a_record_naming_dev_zero_as_its_robot_is_refused(tmp_path, capsys):
    """play read /dev/zero as the robot's URDF until memory ran out."""
    import json

    from kinredund.ui.cli import main

    rec = tmp_path / "run.json"
    assert main(["track", "planar3r", "--steps", "8", "--json", str(rec), "--quiet"]) == 0
    capsys.readouterr()
    data = json.loads(rec.read_text())
    data["robot"] = "/dev/zero"
    rec.write_text(json.dumps(data))
    code = _main("play", rec, "--html", tmp_path / "x.html")
    err = capsys.readouterr().err
    assert code == 2 and "'/dev/zero'" in err and "a character device" in err, err


# -- sizes -------------------------------------------------------------------------------------------------
def test_sizes_are_bounded_in_one_place_with_the_reason():
    keys = ("samples", "placements", "workers", "joints")
    assert (MAX_SAMPLES, MAX_PLACEMENTS, MAX_WORKERS, MAX_JOINTS) == tuple(SIZES[k][0] for k in keys)
    from kinredund.ik.solve import MAX_STARTS
    from kinredund.tracking import MAX_STEPS

    assert MAX_STEPS == MAX_SAMPLES and MAX_STARTS == SIZES["starts"][0]
    assert check_size(MAX_SAMPLES, "steps", "samples") == MAX_SAMPLES
    with pytest.raises(OptionError, match=rf"steps must be at most {MAX_SAMPLES} \(a record holds every sample"):
        check_size(MAX_SAMPLES + 1, "steps", "samples")
    with pytest.raises(TaskError, match="must be an integer >= 1"):
        check_size(True, "starts", "starts", TaskError)


def test_the_ik_and_the_planner_bound_their_sizes_through_check_size(monkeypatch):
    """solve_ik and PlanOptions restated check_size's messages against limits they had copied at import: a limit
    changed in SIZES (the one place) did not reach them. Lowered here, every check follows it."""
    import kinredund as kr
    from kinredund.planning.options import PlanOptions

    monkeypatch.setitem(SIZES, "starts", (8, "each start is a whole local solve"))
    monkeypatch.setitem(SIZES, "samples", (1000, "a record holds every sample"))
    robot = kr.load_robot("planar3r")
    with pytest.raises(TaskError, match=r"^starts must be at most 8 \(each start is a whole local solve\), got 9$"):
        kr.solve_ik(robot, [1.0, 1.0], starts=9)
    with pytest.raises(OptionError, match=r"^starts must be at most 2 \(four times as many seed one pose-only solve, "
                                          r"which takes at most 8: each start is a whole local solve\), got 3$"):
        PlanOptions(starts=3)
    assert PlanOptions(starts=2).starts == 2
    with pytest.raises(OptionError, match=r"^loops x steps_per_loop \(3 x 400, whole cycles of 1: the record holds "
                                          r"every step\) must be at most 1000 \(a record holds every sample\), "
                                          r"got 1200$"):
        PlanOptions(starts=2, loops=3, steps_per_loop=400)


def test_track_bounds_its_steps_with_check_size_words():
    """track()'s closed and open runs refuse a record longer than SIZES["samples"] in errors.check_size's words
    (its own copy of the message said "the record holds every step"), before any step."""
    from kinredund.model.loader import load_robot
    from kinredund.paths import Circle
    from kinredund.tracking import track

    r = load_robot("planar3r")
    why = re.escape(SIZES["samples"][1])
    circle = Circle(center=[1.0, 0.5, 0.0], radius=0.1, speed=0.1)
    with pytest.raises(OptionError, match=rf"loops x steps_per_loop \(3 x {MAX_SAMPLES // 2}\) must be at most "
                                          rf"{MAX_SAMPLES} \({why}\), got {3 * (MAX_SAMPLES // 2)}"):
        track(r, circle, None, r.home, steps_per_loop=MAX_SAMPLES // 2, loops=3)
    with pytest.raises(OptionError, match=rf"steps must be at most {MAX_SAMPLES} \({why}\), got {MAX_SAMPLES + 1}"):
        track(r, circle, None, r.home, duration=1.0, steps=MAX_SAMPLES + 1)  # a duration: run as an open path


def test_retime_refuses_more_loops_than_a_record_may_hold():
    """retime --loops 10000 of a 200-step record needed ~17 GB: refused before the time law is computed."""
    from kinredund.retime import RetimeError, limits_for, retime
    from kinredund.thesis.chapter4 import load_example
    from kinredund.tracking import track

    ex = load_example("4.1")
    tr = track(ex.robot, ex.path, ex.index, ex.q0, steps_per_loop=20, limits=False)
    loops = MAX_SAMPLES // 20 + 1
    with pytest.raises(RetimeError, match=rf"samples \({loops} loops x 20 \+ 1\) must be at most {MAX_SAMPLES}"):
        retime(tr, limits_for(ex.robot, 5.0), robot=ex.robot, loops=loops)


def test_cli_refuses_sizes_before_any_work(tmp_path, capsys):
    """Refused by the parser (exit 2) with the limit named; only the first runs in its own process."""
    from kinredund.ui.cli import main

    cases = [(["sweep", "panda", "--grid", "0:1:10000,0:1:10000"], f"must be at most {MAX_PLACEMENTS}"),
             (["sweep", "panda", "--grid", f"0:1:{10**12},0:1:1"], f"count must be at most {MAX_PLACEMENTS}"),
             (["sweep", "panda", "--grid", "0:1:2,0:1:2", "--workers", str(MAX_WORKERS + 1)], f"at most {MAX_WORKERS}"),
             (["track", "panda", "--loops", str(MAX_SAMPLES + 1)], f"at most {MAX_SAMPLES}"),
             (["ik", "panda", "--target", "0.4,0.2,0.5", "--starts", "100000"], "at most 10000"),
             (["retime", tmp_path / "any.json", "--amax", "5", "--loops", "1000000000"], f"at most {MAX_SAMPLES}")]
    out = _run(*cases[0][0], cwd=tmp_path)
    assert out.returncode == 2 and cases[0][1] in out.stderr, out.stderr[-500:]
    for args, message in cases[1:]:
        with pytest.raises(SystemExit) as exit_:
            main(list(map(str, args)))
        assert exit_.value.code == 2 and message in capsys.readouterr().err, args


def test_grids_and_placements_are_bounded_before_they_are_built():
    from kinredund.sweep import PlacementError, check_placements, grid

    with pytest.raises(PlacementError, match=rf"placements \(10000 x 10000 x 1 x 1\) must be at most {MAX_PLACEMENTS}"):
        grid(x=np.zeros(10_000), y=np.zeros(10_000))
    assert grid(x=[0.3, 0.4], y=[0.0], yaw=[0.0, 0.5]).shape == (4, 4, 4)
    with pytest.raises(PlacementError, match=f"at most {MAX_PLACEMENTS}"):
        check_placements(np.broadcast_to(np.eye(4), (MAX_PLACEMENTS + 1, 4, 4)))


def test_a_sweeps_run_sizes_are_refused_before_any_placement_runs():
    """Each placement failed on its own (an error record each, exit 0) when loops x steps was too large."""
    from kinredund.sweep.evaluate import SweepOptions

    with pytest.raises(KinredundError, match=rf"\(2 x {MAX_SAMPLES}\) must be at most {MAX_SAMPLES}"):
        SweepOptions(steps_per_loop=MAX_SAMPLES, loops=2)
    with pytest.raises(KinredundError, match="starts must be at most 10000"):
        SweepOptions(starts=10**5)
    assert SweepOptions(steps_per_loop=MAX_SAMPLES).steps_per_loop == MAX_SAMPLES


def _chain_urdf(path: Path, n: int) -> Path:
    links = ['<robot name="chain">', '<link name="l0"/>']
    for i in range(n):
        links.append(f'<link name="l{i + 1}"/><joint name="j{i}" type="revolute"><parent link="l{i}"/>'
                     f'<child link="l{i + 1}"/><origin xyz="0 0 0.01"/><axis xyz="0 {i % 2} {1 - i % 2}"/>'
                     '<limit lower="-3" upper="3" effort="1" velocity="1"/></joint>')
    path.write_text("\n".join([*links, "</robot>"]))
    return path


def test_a_robot_with_too_many_joints_is_refused_with_the_limit(tmp_path):
    from kinredund import load_robot

    with pytest.raises(URDFError, match=rf"{MAX_JOINTS + 1} moving joints, more than the {MAX_JOINTS} kinredund takes"):
        load_robot(str(_chain_urdf(tmp_path / "long.urdf", MAX_JOINTS + 1)))
    # the joints kept are what counts: the arm's joints of a large model load
    r = load_robot(str(tmp_path / "long.urdf"), joints=[f"j{i}" for i in range(7)])
    assert r.nq == 7


def test_a_non_finite_entry_is_located_in_a_message_of_bounded_length():
    """One NaN in a 500,000-point record gave a 77 MB message that did not say where."""
    q = np.zeros((500_000, 7))
    q[123_456, 3] = np.nan
    q[400_000, 0] = np.inf
    with pytest.raises(TaskError) as err:
        check_array(q, (None, 7), "trajectory q")
    message = str(err.value)
    assert len(message) < 200 and "2 of 3500000" in message and "index (123456, 3)" in message
    with pytest.raises(TaskError, match=r"1 of 3, the first at index 1 \(nan\); all: \[0.0, nan, 1.0\]"):
        check_array([0.0, np.nan, 1.0], (3,), "q")


# -- a scheduler that never answers -------------------------------------------------------------------------
@pytest.fixture
def silent_server():
    """A TCP server that accepts connections and never says anything (as an HTTP server waiting for a request)."""
    srv = socket.create_server(("127.0.0.1", 0))
    accepted = []
    stop = threading.Event()

    def serve():
        srv.settimeout(0.1)
        while not stop.is_set():
            try:
                accepted.append(srv.accept()[0])
            except TimeoutError:
                continue

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    yield f"tcp://127.0.0.1:{srv.getsockname()[1]}"
    stop.set()
    thread.join(5)
    for conn in accepted:
        conn.close()
    srv.close()


def test_a_scheduler_that_never_answers_is_an_error(silent_server, monkeypatch):
    """Client() waited for the handshake for ever (past 90 s with an HTTP server on the port)."""
    from kinredund.sweep import cluster

    monkeypatch.setattr(cluster, "CONNECT_TIMEOUT", 0.5)
    err = _in_thread(lambda: cluster.connect(silent_server))
    assert isinstance(err, KinredundError) and "does not speak Dask's protocol" in str(err)
    for bad, message in (("tcp://[::1", "not a Dask scheduler address"), ("bogus://x:1", "unknown address scheme")):
        err = _in_thread(lambda bad=bad: cluster.connect(bad))
        assert isinstance(err, KinredundError) and message in str(err), err


def test_a_real_scheduler_still_connects():
    from distributed import LocalCluster

    from kinredund.sweep.cluster import connect

    with LocalCluster(n_workers=0, processes=False, protocol="tcp", host="127.0.0.1",
                      dashboard_address="127.0.0.1:0") as cluster:
        client = connect(cluster.scheduler_address)
        try:
            assert client.status == "running" and client.scheduler.address == cluster.scheduler_address
        finally:
            client.close()


@pytest.mark.slow
def test_cli_sweep_on_a_silent_server_stops_with_a_clear_error(silent_server, tmp_path):
    out = _run("sweep", "panda", "--grid", "0.4:0.4:1,0:0:1", "--starts", "1", "--scheduler", silent_server,
               "--quiet", cwd=tmp_path)
    assert out.returncode == 2 and "does not speak Dask's protocol" in out.stderr, out.stderr[-500:]


def test_values_read_from_a_file_are_shortened_in_messages():
    """A record's robot, task or solver of any size named in full (as the NaN case, a message of megabytes)."""
    from kinredund.errors import ChoiceError
    from kinredund.trajectory import Trajectory

    ok = {"robot": "planar3r", "task": "planar", "t": [0.0, 1.0], "q": [[0.0] * 3] * 2, "p": [[0.0] * 3] * 2,
          "p_desired": [[0.0] * 3] * 2}
    for key, bad, error in (("robot", [0.5] * 10**6, TaskError), ("task", "x" * 10**6, ChoiceError),
                            ("solver", {"lu": 1} | {str(k): k for k in range(10**5)}, TaskError)):
        with pytest.raises(error) as err:
            Trajectory.from_json_dict({**ok, key: bad})
        assert len(str(err.value)) < 400 and "..." in str(err.value), key


@pytest.mark.parametrize("suffix", [".jsonl", ".json"])
def test_a_sweep_file_nested_too_deeply_is_refused_not_an_internal_error(tmp_path, suffix):
    """A sweep file read on ``--resume`` whose JSON nests too deeply: a KinredundError naming it (it was a
    RecursionError from json.loads: exit 3, an internal error, for bad input)."""
    from kinredund.sweep.store import read_sweep_file

    deep = "[" * 200_000 + "]" * 200_000
    head = '{"kind": "kinredund-sweep", "schema_version": 2}'
    path = tmp_path / f"s{suffix}"
    path.write_text(f"{head}\n{deep}\n" if suffix == ".jsonl" else deep)
    with pytest.raises(KinredundError, match="too deeply"):
        read_sweep_file(path)


@pytest.mark.parametrize("name, value, size", [("samples", 10_001, "plan_samples"), ("refine_samples", 10_001,
                                                                                      "plan_samples"),
                                               ("max_candidates", 1_001, "candidates"), ("budget", 10_001,
                                                                                          "refinements"),
                                               ("rounds", 101, "rounds"), ("max_iter", 100_001, "iterations")])
def test_plan_options_sizes_are_bounded_with_the_reason(name, value, size):
    """Every size of a plan is bounded in errors.SIZES and refused when the options are made (before, samples=10**7
    or max_iter=10**9 started a run that could not end)."""
    from kinredund.planning.options import ObstacleOptions, PlanOptions, RoadmapOptions

    limit, why = SIZES[size]
    assert value == limit + 1
    for cls in (PlanOptions, ObstacleOptions):
        assert getattr(cls(**{name: limit}), name) == limit
        with pytest.raises(OptionError, match=rf"{name} must be at most {limit} \({re.escape(why)}\), got {value}"):
            cls(**{name: value})
    with pytest.raises(OptionError, match="samples x cycles"):
        PlanOptions(samples=5_001, cycles=2)
    with pytest.raises(OptionError, match="slices x grid"):
        RoadmapOptions(slices=2_000, grid=1_000)
    with pytest.raises(OptionError, match="must be an integer >= 0"):
        PlanOptions(budget=-1)
