"""What a tracking record says about itself (issue 26): a closed path whose joints do not close is flagged
(record, warning, exit code, cause named), never a plain success."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from conftest import robot

import kinredund
from kinredund.indices import JointDeviation
from kinredund.paths import Circle
from kinredund.trajectory import LOOP_CLOSURE_TOL, RecordWarning
from kinredund.ui.cli import EXIT_FAILED, main

#: a Panda start found by a seeded search (numpy default_rng(1), trial 11): a circle of radius 0.108 m from
#: its pose, orientation held, z = 1/2 ||q - q_home||^2. Its branch of constrained minima is not periodic:
#: one loop ends ~1.9 rad from its start with no bound active (the same at 200 and 400 steps per loop),
#: the case of the issue (there: 1.42 rad)
OPEN_BRANCH_Q = np.array([-1.7312349645663159, -0.5977225265655738, 1.0673072162758395, -1.1549464505665732,
                          -1.5061831427348509, 1.5408934052687406, -0.32076022072475463])
RADIUS = 0.108


def _open_branch_case():
    r = robot("panda")
    T = r.fk(OPEN_BRANCH_Q)
    index = JointDeviation(r.home)
    start = kinredund.solve_ik(r, T, index, q0=OPEN_BRANCH_Q, bounds=True)
    assert start.converged
    path = Circle(T[:3, 3] - RADIUS * np.array([1.0, 0.0, 0.0]), RADIUS, 0.1, orientation=T[:3, :3])
    return r, path, index, start.q


def test_a_branch_that_does_not_close_is_flagged_with_its_cause():
    r, path, index, q0 = _open_branch_case()
    with pytest.warns(RecordWarning, match="branch of minima followed is not periodic") as caught:
        traj = kinredund.track(r, path, index, q0, steps_per_loop=200, loops=1)
    assert "kinredund.plan" in str(caught[0].message)
    # the drift itself, from the joints (revolute joints modulo 2 pi), not the record's own figure
    d = np.angle(np.exp(1j * (traj.q[-1] - traj.q[0])))
    assert np.abs(d).max() > 1.0  # far beyond LOOP_CLOSURE_TOL: another local minimum
    assert traj.loop_closed is False and traj.summary()["loop_closed"] is False
    assert "not periodic" in traj.meta["loop_not_closed"]
    # every point is on the path and no bound holds: nothing else is wrong with the run
    assert traj.position_error.max() < 1e-9
    assert not np.abs(traj.active_bounds).any()
    # the cause is the branch, not the step: the same drift with twice the steps
    with pytest.warns(RecordWarning):
        finer = kinredund.track(r, path, index, q0, steps_per_loop=400, loops=1)
    assert abs(finer.loop_drift[0] - traj.loop_drift[0]) < 1e-6


def test_a_closed_run_is_closed_and_quiet():
    r = robot("panda")
    T = r.fk(r.home)
    path = Circle(T[:3, 3] - np.array([0.05, 0.0, 0.0]), 0.05, 0.1, orientation=T[:3, :3])
    with warnings.catch_warnings():
        warnings.simplefilter("error", RecordWarning)
        traj = kinredund.track(r, path, JointDeviation(r.home), r.home, steps_per_loop=100, loops=2)
    assert traj.loop_closed is True and max(traj.loop_drift) <= LOOP_CLOSURE_TOL
    assert "loop_not_closed" not in traj.meta
    open_path = kinredund.Trajectory(robot="panda", task="pose", t=traj.t, q=traj.q, p=traj.p,
                                     p_desired=traj.p_desired)
    assert open_path.loop_closed is None  # no loops: nothing to say


def test_cli_track_exits_1_on_a_branch_that_does_not_close(capsys, tmp_path):
    js = tmp_path / "run.json"
    code = main(["track", "panda", "--q0=" + ",".join(map(repr, OPEN_BRANCH_Q.tolist())), "--radius", str(RADIUS),
                 "--quiet", "--json", str(js)])
    assert code == EXIT_FAILED
    out, err = capsys.readouterr()
    assert "loop_closed                False" in out
    assert "not periodic" in err and "kinredund.plan" in err
    assert js.exists()  # the record is written: it is the evidence
    assert kinredund.Trajectory.load_json(js).loop_closed is False


def _ur10_circle(speed: float):
    r = robot("ur10", "axis")
    T = r.fk(r.home)
    index = JointDeviation(r.home)
    path = Circle(T[:3, 3] - np.array([0.1, 0.0, 0.0]), 0.1, speed, orientation=T[:3, :3])
    start = kinredund.solve_ik(r, path(0.0), index, q0=r.home, bounds=True, starts=4)
    return r, kinredund.track(r, path, index, start.q, steps_per_loop=100, loops=1)


def test_a_record_over_the_velocity_limits_names_joint_ratio_and_time():
    """A UR10 circle at 2 m/s: a joint over its URDF velocity limit, flagged with the joint, the ratio and
    the time, recomputed here from the joints and the model's limits; the retimed record is within them."""
    from kinredund.retime import limits_for, retime

    r, traj = _ur10_circle(2.0)
    vmax = np.asarray(r.model.velocityLimit, float)
    speeds = np.abs(np.diff(traj.q, axis=0)) / np.diff(traj.t)[:, None] / vmax
    k, j = np.unravel_index(np.argmax(speeds), speeds.shape)
    ratio, joint, t = traj.speed_over_limits
    assert ratio > 1.0 and joint == j and abs(ratio - speeds[k, j]) <= 1e-12 * ratio and t == traj.t[k + 1]
    s = traj.summary()
    assert (s["speed_ratio_max"], s["speed_ratio_joint"], s["speed_ratio_t"]) == (ratio, joint, t)
    assert kinredund.Trajectory.from_json_dict(traj.to_json_dict()).speed_over_limits == (ratio, joint, t)
    timed = retime(traj, limits_for(r, 10.0), robot=r).trajectory
    assert timed.speed_over_limits[0] <= 1.0 + 1e-6  # TOPP-RA's law within the limits (its own tolerance)
    slow = _ur10_circle(0.5)[1].speed_over_limits
    assert slow[0] < 1.0 and slow[0] == pytest.approx(ratio / 4.0, rel=0.1)  # same joint path, a quarter the speed


def test_cli_track_names_the_joint_over_its_limit_and_the_next_step(capsys, tmp_path):
    js = tmp_path / "fast.json"
    assert main(["track", "ur10", "--speed", "2", "--steps", "100", "--quiet", "--json", str(js)]) == 0
    out, err = capsys.readouterr()
    assert "speed_ratio_max" in out
    assert "joint shoulder_lift_joint runs at" in err and f"kinredund retime {js} --amax" in err


def test_a_fast_closed_record_is_a_closed_joint_path():
    """The loop's last sample was looked for within an absolute 1e-9 s: a loop shorter than that (a Panda
    circle at 1e9 m/s, period 6.3e-10 s) was refused as '1 samples per loop'."""
    from kinredund.retime.joint_path import joint_path

    r = robot("panda")
    T = r.fk(r.home)
    path = Circle(T[:3, 3] - np.array([0.1, 0.0, 0.0]), 0.1, 1e9, orientation=T[:3, :3])
    traj = kinredund.track(r, path, JointDeviation(r.home), r.home, steps_per_loop=100, loops=2)
    jp = joint_path(traj.checked(r.nq), r.revolute)
    assert jp.closed and len(jp.s) == 101
    assert abs(jp.period - path.period) <= 1e-12 * path.period


def _sampled(fn, steps: int, t_end: float = 1.0) -> kinredund.Trajectory:
    """A 2-joint record of q(t) = fn(t) at ``steps`` steps over [0, t_end]."""
    t = np.linspace(0.0, t_end, steps + 1)
    q = np.array([fn(tk) for tk in t])
    return kinredund.Trajectory(robot="planar3r", task="planar", t=t, q=q, p=np.zeros((len(t), 3)),
                                p_desired=np.zeros((len(t), 3)))


def test_a_square_root_point_is_named_a_rate_burst_and_a_smooth_burst_is_not():
    """q_1 = sqrt(t - t*) past t* (a bound releasing where the optimum is not strongly stable): its largest
    step shrinks sqrt(2)x when the step halves, and is named; a fast smooth bump (rates bounded) shrinks 2x
    and passes; a record without a candidate is never re-run."""
    from kinredund.tracking.record_checks import REFINED_SHRINK, say_rate_burst

    t_star = 0.5 + 1e-3  # just past a sample: the step across it carries sqrt(dt)

    def root(t):
        return np.array([0.1 * t, 0.1 * t + 0.5 * np.sqrt(max(t - t_star, 0.0))])

    def bump(t):
        return np.array([0.1 * t, 0.1 * t + 0.3 * np.exp(-((t - 0.5) / 0.01) ** 2)])

    rough = _sampled(root, 200)
    with pytest.warns(RecordWarning, match="rate burst") as caught:
        say_rate_burst(rough, lambda: _sampled(root, 400))
    assert "joint 1" in rough.meta["rate_burst"] and "square-root point" in str(caught[0].message)
    shrink = float(np.abs(np.diff(rough.q, axis=0)).max() / np.abs(np.diff(_sampled(root, 400).q, axis=0)).max())
    assert shrink < REFINED_SHRINK  # the fixture is what it claims: ~sqrt(2)

    smooth = _sampled(bump, 400)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RecordWarning)
        say_rate_burst(smooth, lambda: _sampled(bump, 800))  # a candidate (fast), resolved by refinement
        say_rate_burst(_sampled(lambda t: np.array([t, -t]), 200), lambda: pytest.fail("re-run without a candidate"))
    assert "rate_burst" not in smooth.meta


def test_retime_refuses_a_record_with_a_rate_burst():
    from kinredund.retime import RetimeError, limits_for, retime

    r, traj = _ur10_circle(0.5)
    traj.meta["rate_burst"] = "joint 3 moves 0.3 in one step"
    with pytest.raises(RetimeError, match="rate burst"):
        retime(traj, limits_for(r, 10.0), robot=r)


def test_a_jump_followed_with_strict_off_is_named_a_jump():
    """strict=False follows a path that jumps by 0.3 m at t = 0.5 s (test_resolved_rate's case): the record is
    on the path at every point, but its joints jump; the record names it instead of passing it as a step."""
    from kinredund.indices import minimum_norm
    from kinredund.paths import FunctionPath

    r = robot("planar3r")
    q0 = np.array([0.2, 0.6, 0.6])
    p0 = r.fk(q0)[:2, 3]

    def fn(t):
        return p0 + np.array([0.1 * t, 0.0]) + (np.array([0.0, 0.3]) if t >= 0.5 else 0.0), np.array([0.1, 0.0])

    with pytest.warns(RecordWarning, match="a jump"):
        traj = kinredund.track(r, FunctionPath(fn), minimum_norm(3), q0, duration=1.0, steps=40, strict=False)
    assert "t = 0.475 s to 0.5 s" in traj.meta["rate_burst"]
    assert traj.position_error.max() < 1e-11  # nothing else says anything is wrong


@pytest.mark.parametrize("check", ["loop_not_closed", "rate_burst"])
def test_a_sweep_placement_whose_record_fails_its_checks_is_infeasible(check, monkeypatch):
    """The sweep listed such placements as feasible (the issue: a reversed or open run ranked among the best)."""
    import kinredund.sweep.evaluate as evaluate_mod
    from kinredund.sweep.evaluate import SweepOptions
    from kinredund.sweep.placement import panda_part_circle

    real = evaluate_mod.run_tracker

    def tracked(*args, **kwargs):  # the real run, with what track() puts in the record when the check fails
        traj = real(*args, **kwargs)
        traj.meta[check] = f"the {check} message"
        return traj

    monkeypatch.setattr(evaluate_mod, "run_tracker", tracked)
    r, path, index, pose = panda_part_circle()
    rec = evaluate_mod.evaluate_placement(r, path, index, pose, 0, SweepOptions(steps_per_loop=50))
    assert not rec.feasible and rec.cause == check and rec.message == f"the {check} message"
    monkeypatch.setattr(evaluate_mod, "run_tracker", real)
    assert evaluate_mod.evaluate_placement(r, path, index, pose, 0, SweepOptions(steps_per_loop=50)).feasible


def test_reproduce_in_thesis_mode_notes_the_drift_and_keeps_its_exit_code(capsys):
    """The thesis's explicit scheme drifts (the comparison `reproduce` is for): a note with the cause, exit 0."""
    assert main(["reproduce", "4.1", "--mode", "thesis", "--quiet"]) == 0
    out, err = capsys.readouterr()
    assert "loop_closed                False" in out
    assert err.startswith("kinredund: note: the joints do not return") and "thesis mode" in err


def test_the_burst_check_s_median_is_numpy_s_to_the_bit():
    """record_checks.median (one partition) against np.median on odd and even lengths and on values spread over ten
    decades (its claim: the same float, the middle value or the mean of the middle two)."""
    from kinredund.tracking.record_checks import median

    rng = np.random.default_rng(26)
    for length in (1, 2, 3, 199, 200, 201, 400):
        for _ in range(50):
            d = rng.random(length) * 10.0 ** rng.uniform(-10.0, 0.0, length)
            assert median(d) == float(np.median(d)), length
    assert median(np.array([1.0, 3.0, 2.0, 10.0])) == 2.5


def test_the_core_s_burst_candidate_is_numpy_s(monkeypatch):
    """burst_candidate by the compiled core (``_core.burst_candidate``) and by numpy (largest_steps, argmax,
    median) name the same step, or none, on records of odd and even lengths with a spike, with ties, with a step
    just above and just below BURST_RATIO times the median, with two bursts equal to rounding (the first named:
    BURST_TIE), and with a NaN (no burst); and largest_steps is the
    largest absolute joint change of each step."""
    from kinredund.tracking import record_checks
    from kinredund.tracking.compiled import load_core

    if load_core() is None or not hasattr(load_core(), "burst_candidate"):
        pytest.skip("the compiled core is not built")
    rng = np.random.default_rng(28)
    records = []
    for rows in (9, 10, 60, 201, 202):
        for joints in (1, 7):
            q = np.cumsum(rng.normal(0.0, 0.01, (rows, joints)), axis=0)
            spiked = q.copy()
            spiked[rows // 2:] += 0.5 * rng.choice([-1.0, 1.0], joints)  # one step 50x the others
            records += [q, spiked]
    steady = np.outer(np.arange(20.0), [0.01, -0.02])  # every step the same: ties, no burst
    edge = steady.copy()
    d0 = float(np.median(record_checks.largest_steps(steady)))
    for factor in (10.0 * (1 + 1e-12), 10.0 * (1 - 1e-12)):  # just over and just under BURST_RATIO times the median
        bumped = edge.copy()
        bumped[12:, 1] -= factor * d0 - d0
        records.append(bumped)
    with_nan = records[3].copy()
    with_nan[4, 0] = np.nan
    two_loops = np.outer(np.arange(40.0), [0.01, 0.0])  # the same burst in each of two loops, the second's larger by
    for k, extra in ((9, 0.5), (29, 0.5 * (1 + 4e-16))):  # rounding (two backends' records differed so): the first
        two_loops[k + 1:, 1] += extra
    records += [two_loops, steady, with_nan]
    core_says = [record_checks.burst_candidate(q) for q in records]
    monkeypatch.setattr(record_checks, "load_core", lambda: None)
    numpy_says = [record_checks.burst_candidate(q) for q in records]
    assert core_says == numpy_says
    assert None in core_says and any(k is not None for k in core_says)
    assert core_says[-5] == 11 and core_says[-4] is None and core_says[-3] == 9
    assert core_says[-2] is None and core_says[-1] is None
    q = records[1]
    want = [max(abs(q[k + 1, j] - q[k, j]) for j in range(q.shape[1])) for k in range(len(q) - 1)]
    assert record_checks.largest_steps(q).tolist() == want


def test_the_core_s_record_extremes_are_numpy_s_to_the_bit(monkeypatch):
    """The record's loop drifts and fastest rates by the compiled core (``_core.record_extremes``) and by numpy
    (loop_drifts, the largest |qdot| per joint) are the same floats (compared as bytes) on records of one to three
    loops with revolute and prismatic joints, differences that wrap past +-pi by many turns, that sit exactly on
    +-pi and on zero, and a NaN (numpy's max then gives NaN: so does the core); open runs and runs without rates
    give None."""
    from kinredund.tracking import record_checks

    if record_checks.load_core() is None or not hasattr(record_checks.load_core(), "record_extremes"):
        pytest.skip("the compiled core is not built")
    rng = np.random.default_rng(28)
    cases = []
    for loops, spl, joints in ((1, 200, 7), (2, 8, 3), (3, 5, 1)):
        rows = loops * spl + 1 + rng.integers(0, 3)
        q = rng.normal(0.0, 1.0, (rows, joints)) * 10.0 ** rng.uniform(-3.0, 2.0, joints)
        qdot = rng.normal(0.0, 3.0, (rows, joints))
        cases.append((q, qdot, rng.random(joints) < 0.7, spl, loops))
    q = np.zeros((9, 4))
    q[0] = [0.5, -0.5, 1.0, 0.0]
    q[8] = q[0] + np.array([np.pi, -np.pi, 7.0 * np.pi, 0.0])  # on +-pi, many turns, no change
    cases.append((q, -q, np.ones(4, bool), 8, 1))
    with_nan = cases[0][0].copy(), cases[0][1].copy()
    with_nan[0][200, 3] = with_nan[1][17, 2] = np.nan
    cases.append((*with_nan, np.ones(7, bool), 200, 1))
    cases.append((cases[1][0], None, cases[1][2], None, None))  # an open run without rates
    core_says = [record_checks.record_extremes(*case) for case in cases]
    monkeypatch.setattr(record_checks, "load_core", lambda: None)
    numpy_says = [record_checks.record_extremes(*case) for case in cases]
    for (drift, fast), (want_drift, want_fast) in zip(core_says, numpy_says, strict=True):
        assert (drift is None) == (want_drift is None) and (fast is None) == (want_fast is None)
        if drift is not None:
            assert drift.dtype == want_drift.dtype and drift.tobytes() == want_drift.tobytes()
        if fast is not None:
            assert np.array(fast).tobytes() == np.array(want_fast).tobytes()
    assert np.isnan(core_says[-2][0][0]) and np.isnan(core_says[-2][1][2]) and not np.isnan(core_says[-2][1][3])
    assert core_says[-1] == (None, None)
    assert core_says[-3][0][0] == np.pi  # the largest wrapped change: -pi wraps to -pi (|.| = pi), 7 pi to -pi
