"""Placement sweeps (kinredund.sweep): records serially, on a local Dask cluster and on a real one; known
feasible and infeasible placements; resuming; the adapter to a tracker with hard joint limits; the CLI."""

from __future__ import annotations

import functools
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import load_benchmark

import kinredund.sweep.evaluate as evaluate_mod
from kinredund.errors import ChoiceError, KinredundError, PathError
from kinredund.sweep import (
    PartPath,
    PlacementError,
    best,
    check_placements,
    evaluate_placement,
    grid,
    placement_pose,
    read_sweep_file,
    sweep,
)
from kinredund.sweep.evaluate import LIMIT_TOL, SweepOptions
from kinredund.sweep.placement import panda_part_circle
from kinredund.trajectory import Trajectory
from kinredund.ui.cli import main


@functools.cache
def problem():
    """The Panda benchmark circle in its part frame, and the part pose of the benchmark."""
    return panda_part_circle()


def panda_grid() -> np.ndarray:
    """50 placements about the benchmark circle: x, y +-0.3 m (5 x 5), yaw 0 and 0.5 rad."""
    c = problem()[3][:3, 3]
    return grid(x=c[0] + np.linspace(-0.3, 0.3, 5), y=np.linspace(-0.3, 0.3, 5), z=c[2], yaw=[0.0, 0.5])


# Records of two runs agree to round-off, not bit for bit: the start configuration comes from the bounded IK,
# whose box-constrained QP steps (proxsuite dense) were measured to return results that differ in the last
# bits for identical inputs, from one call to the next (the tracker itself repeats bit for bit). The tracker
# maps the start smoothly over one loop, so the figures differ by round-off times its conditioning (~1e-15
# measured): the bars are 1e-9 relative on the O(1) figures and 1e-11 absolute on the figures that are
# themselves round-off (drift, tracking errors, ~1e-13); everything discrete must be equal.
DISCRETE = ("placement", "pose", "x", "y", "z", "yaw", "feasible", "cause", "steps", "t_fail")
ROUND_OFF = ("loop_drift", "position_error", "orientation_error")
FIGURES = ("limit_margin", "sigma_min", "speed_ratio", "mean_z")


def assert_same_records(a, b) -> None:
    assert len(a) == len(b)
    for ra, rb in zip(a, b, strict=True):
        for name in DISCRETE:
            assert getattr(ra, name) == getattr(rb, name), (ra.placement, name)
        assert re.sub(r"[-+.\de]+", "#", ra.message) == re.sub(r"[-+.\de]+", "#", rb.message)
        for names, rtol, atol in ((ROUND_OFF, 0.0, 1e-11), (FIGURES, 1e-9, 1e-12)):
            for name in names:
                va, vb = getattr(ra, name), getattr(rb, name)
                assert (va is None) == (vb is None), (ra.placement, name)
                if va is not None:
                    assert vb == pytest.approx(va, rel=rtol, abs=atol), (ra.placement, name)
        assert (ra.q_last is None) == (rb.q_last is None)
        if ra.q_last is not None:
            np.testing.assert_allclose(ra.q_last, rb.q_last, rtol=0, atol=1e-9)


def run_panda(placements=None, **kw):
    robot, path, index, _ = problem()
    return sweep(robot, path, index, panda_grid() if placements is None else placements, **kw)


@functools.cache
def serial_records():
    return tuple(run_panda(workers=0))


# -- the real cluster ------------------------------------------------------------------------------
class DaskCluster:
    """``dask scheduler`` and two ``dask worker`` processes on 127.0.0.1, from this venv's bin."""

    def __init__(self, tmp: Path):
        dask = Path(sys.executable).parent / "dask"
        env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
        self.file = tmp / "scheduler.json"
        log = open(tmp / "dask.log", "w")  # noqa: SIM115 - closed in stop()
        self.log = log
        self.procs = [subprocess.Popen([str(dask), "scheduler", "--host", "127.0.0.1", "--port", "0",
                                        "--no-dashboard", "--dashboard-address", "127.0.0.1:0",
                                        "--scheduler-file", str(self.file)],
                                       stdout=log, stderr=log, env=env)]
        deadline = time.monotonic() + 60
        while not self.file.exists() and time.monotonic() < deadline:
            time.sleep(0.2)
        for _ in range(2):
            self.procs.append(subprocess.Popen(
                [str(dask), "worker", "--scheduler-file", str(self.file), "--host", "127.0.0.1", "--nthreads", "1",
                 "--nworkers", "1", "--no-dashboard", "--dashboard-address", "127.0.0.1:0", "--memory-limit", "0"],
                stdout=log, stderr=log, env=env))
        self.address = json.loads(self.file.read_text())["address"]

    def listening(self) -> set[str]:
        """The addresses the cluster's processes (nannies' workers too) listen on."""
        import psutil  # a dependency of distributed

        procs = [psutil.Process(p.pid) for p in self.procs]
        procs += [c for p in procs for c in p.children(recursive=True)]
        return {c.laddr.ip for p in procs for c in p.net_connections(kind="tcp") if c.status == psutil.CONN_LISTEN}

    def stop(self) -> None:
        for p in reversed(self.procs):  # workers first, then the scheduler; each by its own pid
            p.terminate()
        for p in self.procs:
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        self.log.close()


@pytest.mark.slow
def test_panda_sweep_is_the_same_serially_on_a_local_cluster_and_on_a_real_cluster(tmp_path):
    from distributed import Client

    serial = serial_records()
    assert len(serial) >= 50 and [r.placement for r in serial] == list(range(len(serial)))  # placement order
    assert any(r.feasible for r in serial) and not all(r.feasible for r in serial)
    assert_same_records(serial, run_panda(workers=2))
    cluster = DaskCluster(tmp_path)
    try:
        assert cluster.address.startswith("tcp://127.0.0.1:")
        with Client(cluster.address, timeout="30s") as client:
            client.wait_for_workers(2, timeout=60)
            workers = client.scheduler_info()["workers"]
            assert len(workers) == 2 and all(a.startswith("tcp://127.0.0.1:") for a in workers)  # loopback only
            assert_same_records(serial, run_panda(client=client))  # client=: the caller's client, left open
            assert client.status == "running"
        assert_same_records(serial, run_panda(scheduler=cluster.address, batch_size=3))
        assert cluster.listening() == {"127.0.0.1"}  # scheduler, nannies, workers and their HTTP routes
    finally:
        cluster.stop()
    assert all(p.poll() is not None for p in cluster.procs)


def test_no_feasible_record_leaves_the_joint_limits():
    for r in serial_records():
        if r.feasible:
            assert r.limit_margin >= -LIMIT_TOL and r.cause is None and r.steps == 200
        else:
            assert r.cause and r.message  # the sweep's causes, or a limited tracker's own
        if r.limit_margin is not None and r.limit_margin < -LIMIT_TOL:
            assert not r.feasible and r.cause == "limits"


def test_a_run_that_leaves_the_limits_is_named_at_its_first_excursion():
    """The sweep's own limit check (evaluate.figures): the first recorded point beyond a limit by more than
    LIMIT_TOL, and the record's margin; an excursion within LIMIT_TOL is not one."""
    from kinredund.problems import panda_circle

    robot, path, _, q0 = panda_circle()
    q = np.tile(np.clip(q0, robot.lower, robot.upper), (6, 1))
    q[2, 3] = robot.upper[3] + 0.5 * LIMIT_TOL  # within the tolerance: not an excursion
    q[4, 3] = robot.upper[3] + 1e-6
    q[5, 1] = robot.lower[1] - 1e-6
    traj = Trajectory(robot="panda", task="pose", t=np.linspace(0.0, 0.5, 6), q=q, p=np.zeros((6, 3)),
                      p_desired=np.zeros((6, 3)))
    figs = evaluate_mod.figures(robot, path, None, traj)
    assert figs["violation"] == (4, 3)
    assert abs(figs["limit_margin"] + 1e-6) <= 1e-15


def test_known_feasible_and_known_infeasible_placements():
    robot, path, index, pose = problem()
    far = placement_pose(3.0, 0.0, 0.5)  # 3 m from the base: out of the Panda's reach (~0.85 m)
    feasible, out_of_reach = run_panda(np.array([pose, far]), workers=0)
    assert not out_of_reach.feasible and out_of_reach.cause == "start" and out_of_reach.steps == 0
    assert feasible.feasible and feasible.steps == 200
    # the benchmark circle starts at the home pose, where z = 1/2 ||q - q_home||^2 = 0 is the constrained
    # minimum: the run starts at home, so its smallest margin is at most home's and z averages above 0
    home_margin = float(np.min(np.minimum(robot.home - robot.lower, robot.upper - robot.home)))
    assert 0.0 < feasible.limit_margin <= home_margin
    assert feasible.mean_z > 0.0
    # the default mode closes the joint path and holds the task to ~1e-12 (tracking module docstring)
    assert feasible.loop_drift < 1e-9 and feasible.position_error < 1e-9 and feasible.orientation_error < 1e-9
    assert feasible.sigma_min > 0.0
    assert 0.0 < feasible.speed_ratio < 1.0  # 0.1 m/s on a 0.1 m circle: far below the Panda's joint speeds


def test_speed_ratio_and_sigma_min_against_a_direct_evaluation():
    """The record's figures against the same run recomputed by hand (finite differences, numpy's SVD)."""
    robot, path, index, pose = problem()
    rec = evaluate_placement(robot, path, index, pose, 0, SweepOptions())
    part = PartPath(path, pose)
    traj = evaluate_mod.run_tracker(robot, part, index, robot.home, SweepOptions())
    qdot = np.diff(traj.q, axis=0) / np.diff(traj.t)[:, None]
    v = np.asarray(robot.model.velocityLimit)
    assert rec.speed_ratio == pytest.approx(np.max(np.abs(qdot) / v), rel=1e-9)
    sig = min(np.linalg.svd(robot.velocity_jacobian(q), compute_uv=False)[-1] for q in traj.q)
    assert rec.sigma_min == pytest.approx(sig, rel=1e-9)


def test_resuming_an_interrupted_sweep_gives_the_same_final_file(tmp_path):
    placements = panda_grid()[:12]
    whole = tmp_path / "whole.jsonl"
    run_panda(placements, workers=0, batch_size=2, out=whole)
    part = tmp_path / "part.jsonl"
    calls = []

    def interrupt(done, total):
        calls.append(done)
        if done >= 6:
            raise KeyboardInterrupt

    from kinredund.io import output_batch

    with pytest.raises(KeyboardInterrupt), output_batch() as batch:  # as the CLI runs it: outputs batched
        run_panda(placements, workers=0, batch_size=2, out=part, progress=interrupt)
    assert batch.kept == [part]  # the sweep file is a checkpoint: it lands as the sweep goes, not with the batch
    head, kept = read_sweep_file(part)
    assert [r.placement for r in kept] == list(range(6))  # the partial file: what was done, in order
    partial_lines = part.read_text().splitlines()
    first = len(calls)
    resumed = run_panda(placements, workers=0, batch_size=2, out=part, resume=True,
                         progress=lambda done, total: calls.append(done))
    assert calls[first] == 6 and calls[-1] == 12  # it started from the 6 kept placements
    lines, whole_lines = part.read_text().splitlines(), whole.read_text().splitlines()
    assert lines[: len(partial_lines)] == partial_lines  # header and kept records untouched, byte for byte
    assert lines[0] == whole_lines[0] and len(lines) == len(whole_lines) == 13
    assert_same_records(resumed, read_sweep_file(whole)[1])
    assert_same_records(read_sweep_file(part)[1], resumed)  # the file holds what was returned
    # a file of another sweep is refused
    with pytest.raises(KinredundError, match="another sweep"):
        run_panda(placements[:5], workers=0, out=part, resume=True)


def test_json_file_round_trip(tmp_path):
    out = tmp_path / "sweep.json"
    placements = [problem()[3], placement_pose(3.0, 0.0, 0.5)]
    records = run_panda(placements, workers=0, out=out)
    head, back = read_sweep_file(out)
    assert back == records and head["placements"] == 2 and head["robot"] == "panda"


def test_a_failing_placement_is_a_record(monkeypatch):
    original = evaluate_mod.evaluate_placement

    def flaky(robot, path, index, pose, placement, options):
        if placement == 1:
            raise RuntimeError("boom")
        return original(robot, path, index, pose, placement, options)

    import kinredund.sweep.run as run_mod

    monkeypatch.setattr(run_mod, "evaluate_placement", flaky)
    a, b = run_panda([problem()[3]] * 2, workers=0)
    assert a.feasible and not b.feasible and b.cause == "internal" and "boom" in b.message


class FakeTrackingError(KinredundError):
    """What the limited tracker raises: cause, t, q, watched, partial."""

    def __init__(self, message, *, cause, t, q, watched, partial):
        super().__init__(message)
        self.cause, self.t, self.q, self.watched, self.partial = cause, t, q, watched, partial


def test_adapter_passes_limits_and_keeps_the_tracker_failure(monkeypatch):
    robot, path, index, pose = problem()
    real = evaluate_mod.track
    seen = {}

    def limited(robot, path, index=None, q0=None, *, limits=False, **kw):
        seen["limits"] = limits
        traj = real(robot, path, index, q0, **kw)
        partial = Trajectory(robot=traj.robot, task=traj.task, t=traj.t[:51], q=traj.q[:51], p=traj.p[:51],
                             p_desired=traj.p_desired[:51], position_error=traj.position_error[:51],
                             loop_period=traj.loop_period)
        raise FakeTrackingError("joint 3 at its limit", cause="limits_infeasible", t=float(traj.t[50]), q=traj.q[50],
                                watched=[3], partial=partial)

    monkeypatch.setattr(evaluate_mod, "track", limited)
    rec = evaluate_placement(robot, path, index, pose, 7, SweepOptions(limits=True))
    assert seen["limits"] is True
    assert not rec.feasible and rec.cause == "limits" and rec.message == "joint 3 at its limit"
    assert rec.steps == 50 and rec.t_fail == pytest.approx(50 * path.period / 200, rel=1e-12)
    assert rec.q_last is not None and len(rec.q_last) == 7 and rec.limit_margin > 0


def test_today_tracker_errors_become_causes(monkeypatch):
    robot, path, index, pose = problem()

    def lost(*args, **kw):
        raise PathError("the corrector did not converge", t=1.5, q=robot.home)

    monkeypatch.setattr(evaluate_mod, "track", lost)
    rec = evaluate_placement(robot, path, index, pose, 0, SweepOptions())
    assert rec.cause == "path" and rec.t_fail == 1.5 and rec.q_last == tuple(robot.home) and rec.steps == 0


def test_best_ranks_feasible_placements():
    records = serial_records()
    ranked = best(records, "margin")
    assert ranked and all(r.feasible for r in ranked)
    assert [r.limit_margin for r in ranked] == sorted((r.limit_margin for r in ranked), reverse=True)
    speed = best(records, "speed", 3)
    assert len(speed) == 3 and speed[0].speed_ratio <= speed[1].speed_ratio <= speed[2].speed_ratio
    with pytest.raises(ChoiceError, match="margin"):
        best(records, "reach")


def test_bad_sweep_arguments_are_refused():
    with pytest.raises(KinredundError, match="at most one"):
        run_panda([problem()[3]], workers=0, scheduler="tcp://127.0.0.1:8786")
    with pytest.raises(PlacementError, match="4x4"):
        run_panda(np.eye(3), workers=0)
    with pytest.raises(KinredundError, match="resume=True needs out="):
        run_panda([problem()[3]], workers=0, resume=True)
    with pytest.raises(ChoiceError, match="scheme"):
        run_panda([problem()[3]], workers=0, scheme="newton")


def test_guided_batches_cover_the_placements_in_order():
    from kinredund.sweep.run import MAX_BATCH, batches

    for count, threads in ((50, 2), (1000, 2), (7, 16)):
        cut = batches(list(range(count)), None, threads)
        sizes = [len(b) for b in cut]
        assert [k for b in cut for k in b] == list(range(count))
        assert sizes == sorted(sizes, reverse=True) and sizes[-1] == 1 and max(sizes) <= MAX_BATCH
    assert [len(b) for b in batches(list(range(10)), 3, 2)] == [3, 3, 3, 1]


def test_grid_order_and_rigid_placements():
    P = grid(x=[0.1, 0.2], y=[0.0, 0.5, 1.0], z=0.3, yaw=[0.0, np.pi / 2])
    assert P.shape == (12, 4, 4)
    k = np.ravel_multi_index((1, 2, 0, 1), (2, 3, 1, 2))  # x outermost, yaw innermost
    np.testing.assert_allclose(P[k][:3, 3], [0.2, 1.0, 0.3])
    np.testing.assert_allclose(P[k][:3, 0], [0.0, 1.0, 0.0], atol=1e-15)
    bad = np.eye(4)
    bad[0, 0] = 2.0
    with pytest.raises(PlacementError, match="placement 1"):
        check_placements([np.eye(4), bad])
    with pytest.raises(PlacementError, match="axis yaw"):
        grid(yaw=[])


def test_part_path_twist_is_the_derivative_of_its_pose():
    """v = dp/dt and omega = vee(dQ/dt Q^T) by central differences (step 1e-5 s: error O(h^2) ~1e-10)."""
    _, path, _, _ = problem()
    pose = placement_pose(0.4, -0.2, 0.3, 0.7)
    part = PartPath(path, pose)
    h = 1e-5
    for t in (0.0, 1.3, 4.0):
        s, a, b = part(t), part(t - h), part(t + h)
        np.testing.assert_allclose(s.v, (b.p - a.p) / (2 * h), atol=1e-9)
        W = (b.Q - a.Q) / (2 * h) @ s.Q.T
        np.testing.assert_allclose(s.omega, [W[2, 1], W[0, 2], W[1, 0]], atol=1e-9)
        np.testing.assert_allclose(s.p, pose[:3, :3] @ path(t).p + pose[:3, 3], atol=1e-15)


def test_cli_sweep_writes_the_file_and_the_map(tmp_path, capsys):
    out, png = tmp_path / "s.jsonl", tmp_path / "map.png"
    code = main(["sweep", "panda", "--grid", "0.3:0.5:2,-0.2:0.2:2", "--workers", "0", "--starts", "2",
                 "--json", str(out), "--plot", str(png), "--criterion", "sigma_min"])
    text = capsys.readouterr().out
    assert code == 0 and "4 placements" in text and "best by sigma_min" in text
    head, records = read_sweep_file(out)
    assert len(records) == 4 and head["options"]["starts"] == 2
    assert png.stat().st_size > 10_000


def test_cli_sweep_rejects_a_bad_grid(capsys):
    with pytest.raises(SystemExit) as err:
        main(["sweep", "panda", "--grid", "0.3:0.5,1"])
    assert err.value.code == 2 and "start:stop:count" in capsys.readouterr().err


@pytest.mark.slow
def test_unreachable_scheduler_is_an_error(capsys):
    code = main(["sweep", "panda", "--grid", "0.4:0.4:1,0:0:1", "--starts", "1", "--scheduler", "tcp://127.0.0.1:9"])
    assert code == 2 and "cannot reach the Dask scheduler" in capsys.readouterr().err


@pytest.mark.slow
def test_benchmark_reports_throughput_and_speedup():
    res = load_benchmark("sweep").bench([2], workers=2)
    row = res["grids"][0]
    assert row["placements"] == 8 and row["records_agree"] and res["largest_grid"] == 8
    assert 0.0 < res["parallel_capacity"] and 0.0 < row["worker_busy"] <= 1.0
    assert np.isfinite(row["speedup"]) and row["serial_s"] > 0 and row["cluster_s"] > 0  # a wall-time ratio


def test_speed_ratio_scales_with_the_path_speed_and_speed_limit_makes_it_infeasible():
    """Ten times the speed over the same circle: the same joint path (the index does not depend on time, the
    steps fall on the same points), so ten times the joint speeds, to the corrector's 1e-12 on the points."""
    from kinredund.sweep.placement import part_circle

    robot, path, index, pose = problem()
    fast = part_circle(robot, path.radius, 10 * path.speed, normal=(1.0, 0.0, 0.0), axis_x=(0.0, 1.0, 0.0))
    slow_rec = evaluate_placement(robot, path, index, pose, 0, SweepOptions())
    fast_rec = evaluate_placement(robot, fast, index, pose, 0, SweepOptions())
    assert fast_rec.feasible and fast_rec.speed_ratio == pytest.approx(10 * slow_rec.speed_ratio, rel=1e-6)
    assert fast_rec.speed_ratio > 1.0
    limited = evaluate_placement(robot, fast, index, pose, 0, SweepOptions(speed_limit=True))
    assert not limited.feasible and limited.cause == "speed" and "velocity limit" in limited.message


@pytest.mark.parametrize("mode, scheme", [("thesis", "augmented"), ("default", "pseudoinverse"),
                                          ("default", "liegeois")])
def test_limits_a_run_cannot_hold_are_refused_once_before_any_placement(mode, scheme, monkeypatch):
    """Before, SweepOptions took mode="thesis" with limits=True and every placement was recorded infeasible
    (the tracker refused the same options once per placement); now the options are refused up front."""
    from kinredund.errors import OptionError

    with pytest.raises(OptionError, match="limits=False"):
        SweepOptions(mode=mode, scheme=scheme, limits=True)
    with pytest.raises(OptionError, match="limits must be None, True or False"):
        SweepOptions(limits="yes")
    assert SweepOptions(mode=mode, scheme=scheme, limits=False).limits is False
    assert SweepOptions(mode=mode, scheme=scheme).limits is None  # the tracker's default: held where it can be
    calls = []
    monkeypatch.setattr(evaluate_mod, "track", lambda *a, **k: calls.append(1))
    robot, path, index, pose = problem()[:4]
    with pytest.raises(OptionError, match="limits=False"):
        sweep(robot, path, index, [pose, pose], mode=mode, scheme=scheme, workers=0)  # limits default True
    assert calls == []


def test_a_batch_lost_on_the_cluster_is_recorded_as_the_workers_cause(monkeypatch):
    """On Dask, a batch whose task fails (here its run raises) gives records of cause 'worker' naming the error, and
    the other batches' records as they are: the loop reads results as as_completed's thread gathered them (no
    fut.result(), whose sync() a Ctrl-C could catch before distributed's own future existed)."""
    from distributed import Client

    import kinredund.sweep.run as run_mod

    def run_batch(job, items):
        if any(k == 1 for k, _ in items):
            raise ValueError("this batch's worker was lost")
        return [("ok", k) for k, _ in items]

    monkeypatch.setattr(run_mod, "run_batch", run_batch)
    T = [np.eye(4) for _ in range(3)]
    got = []
    with Client(processes=False, n_workers=1, threads_per_worker=1, dashboard_address=None) as client:
        run_mod._run_on_dask(None, T, [0, 1, 2], 1, got.extend, client, None, None)
    lost = [r for r in got if not isinstance(r, tuple)]
    assert sorted(r[1] for r in got if isinstance(r, tuple)) == [0, 2]
    assert len(lost) == 1 and lost[0].placement == 1 and lost[0].cause == "worker" and not lost[0].feasible
    assert lost[0].message == "ValueError: this batch's worker was lost"
