"""The tracking package's public API: Tracker as a control-loop stepper, track()'s argument checks, the
example script, and the recorder's batched diagnostics against their one-point forms."""

from __future__ import annotations

import runpy
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import robot

import kinredund
from kinredund.errors import OptionError
from kinredund.indices import minimum_norm
from kinredund.paths import Circle
from kinredund.problems import panda_circle
from kinredund.thesis.chapter4 import load_example
from kinredund.tracking import MAX_STEPS, Tracker, track
from kinredund.tracking.linalg import classify, eigs_many, labels_many, multipliers, null_space_eigs

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def test_tracker_steps_like_track_records():
    """Tracker.step() gives the joints track() records, step for step (the same stepper underneath)."""
    r, path, index, q0 = panda_circle(wrist_amplitude=np.radians(15))
    tr = track(r, path, index, q0, steps_per_loop=100)
    tracker = Tracker(r, path, index, q0, path.period / 100)
    assert tracker.t == 0.0 and np.abs(tracker.q - tr.q[0]).max() == 0.0
    for k in range(1, 101):
        tracker.step()
        assert tracker.t == pytest.approx(tr.t[k], abs=1e-15)
        assert np.array_equal(tracker.q, tr.q[k])  # the same arithmetic: identical
    assert tracker.qdot.shape == (7,) and tracker.lam.shape == (6,) and tracker.solver in ("qp", "qp_aug", "lu")


def test_control_loop_example_runs_and_closes():
    out = subprocess.run([sys.executable, str(EXAMPLES / "control_loop.py")], capture_output=True, text=True,
                         timeout=120, check=True).stdout
    assert "largest position error" in out
    ns = runpy.run_path(str(EXAMPLES / "control_loop.py"))
    assert ns["worst"] < 1e-10  # the corrector holds the task to ~1e-12 m
    assert np.abs(ns["tracker"].q - ns["q0"]).max() < 1e-10  # a closed path gives a closed joint path


def _planar():
    r = robot("planar3r")
    ex = load_example("4.1")
    return r, ex.path, ex.index, ex.q0


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"loops": 2.0}, "loops must be an integer >= 1"),
    ({"loops": 0}, "loops must be an integer >= 1"),
    ({"steps_per_loop": 20.5}, "steps_per_loop must be an integer >= 1"),
    ({"loops": 10**9}, f"at most {MAX_STEPS}"),
    ({"tol": 0.0}, r"tol .* in \(0, 1\)"),
    ({"tol": float("nan")}, r"tol .* in \(0, 1\)"),
    ({"tol": -1e-12}, r"tol .* in \(0, 1\)"),
    ({"tol": 1.0}, r"tol .* in \(0, 1\)"),
    ({"tol": "1e-12"}, r"tol .* in \(0, 1\)"),
    ({"liegeois_gain": float("nan"), "scheme": "liegeois"}, "liegeois_gain"),
])
def test_bad_track_arguments_are_named_before_any_work(kwargs, match, monkeypatch):
    r, path, index, q0 = _planar()
    import kinredund.tracking.run as run

    monkeypatch.setattr(run, "Recorder", None)  # no work may start: the check comes first
    with pytest.raises(OptionError, match=match):
        track(r, path, index, q0, **kwargs)


def test_open_path_steps_must_be_an_integer():
    from kinredund.paths import FunctionPath

    r, _, index, q0 = _planar()
    p0 = r.fk(q0)[:2, 3]
    path = FunctionPath(lambda t: (p0 + np.array([0.1 * t, 0.0]), np.array([0.1, 0.0])))
    with pytest.raises(OptionError, match="steps must be an integer"):
        track(r, path, index, q0, duration=1.0, steps=10.5)
    with pytest.raises(kinredund.PathError, match="duration"):
        track(r, path, index, q0, duration=float("nan"), steps=10)
    assert len(track(r, path, index, q0, duration=1.0, steps=10).t) == 11


def test_q0_is_a_required_argument():
    r, path, index, _ = _planar()
    with pytest.raises(TypeError):
        track(r, path, index)  # q0 missing: the point of the test


def test_thesis_mode_does_not_report_metre_errors_as_success():
    """At 4 steps per loop the explicit scheme leaves the path by metres: an error, not a record."""
    ex = load_example("4.1")
    with pytest.raises(kinredund.PathError, match="away from the path") as err:
        track(ex.robot, ex.path, ex.index, ex.q0, mode="thesis", steps_per_loop=4, limits=False)
    # a TrackingError (issue 15): t is the last good point's, the failed step's time is watched
    assert err.value.t is not None and err.value.watched["t_failed"] > err.value.t


def test_batched_task_errors_against_the_invariants():
    """Task.errors_many against independent one-point formulas: ||p - p_d||, |tr Q - tr Q_d| and
    ||vect Q - vect Q_d|| (Eq. 2.8, closure.vect), and the axis angle arccos(a . a_d)."""
    from kinredund.kinematics import closure
    from kinredund.tasks import get_task

    r, path, _, q0 = panda_circle(wrist_amplitude=np.radians(15))
    rng = np.random.default_rng(3)
    qs = [q0 + 0.05 * rng.normal(size=7) for _ in range(5)]
    ts = rng.uniform(0, path.period, size=5)
    Qp = [r.kinematics.pose(q) for q in qs]
    samples = [path(t) for t in ts]
    Q, p = np.array([a for a, _ in Qp]), np.array([b for _, b in Qp])
    Q_d, p_d = np.array([s.Q for s in samples]), np.array([s.p for s in samples])
    pose = get_task("pose").errors_many(Q, p, Q_d, p_d)
    axis = get_task("axis").errors_many(Q, p, Q_d, p_d)
    planar = get_task("planar").errors_many(Q, p, None, p_d)
    for k in range(5):
        assert abs(pose["position_error"][k] - np.linalg.norm(p[k] - p_d[k])) < 1e-15
        assert abs(planar["position_error"][k] - np.linalg.norm(p[k, :2] - p_d[k, :2])) < 1e-15
        assert abs(pose["trace_error"][k] - abs(np.trace(Q[k]) - np.trace(Q_d[k]))) < 1e-14
        assert abs(pose["vect_error"][k] - np.linalg.norm(closure.vect(Q[k]) - closure.vect(Q_d[k]))) < 1e-14
        # arccos loses digits near 0 (here the angles are ~0.05-0.3 rad): 1e-12
        assert abs(axis["axis_error"][k] - np.arccos(np.clip(Q[k][:, 2] @ Q_d[k][:, 2], -1, 1))) < 1e-12
    assert set(axis) == {"position_error", "axis_error"} and set(planar) == {"position_error"}


def test_batched_diagnostics_equal_the_one_point_forms():
    """eigs_many / null_space_eigs / labels_many / the normality residual against their one-point forms."""
    rng = np.random.default_rng(8)
    Ms, Js, grads = [], [], []
    for k in range(30):
        A, Jk = rng.normal(size=(7, 7)), rng.normal(size=(6, 7))
        z = np.linalg.svd(Jk)[2][6:]
        # positive definite (qp), indefinite but positive on the null space of J (qp_aug), random (lu)
        Ms.append([A @ A.T + np.eye(7), 2.0 * z.T @ z - Jk.T @ Jk, A + A.T][k % 3])
        Js.append(Jk)
        grads.append(rng.normal(size=7))
    M, J = np.array(Ms), np.array(Js)
    e = eigs_many(M)
    assert np.abs(e - np.array([np.linalg.eigvalsh(m) for m in Ms])).max() < 1e-12
    en = np.array([null_space_eigs(m, j) for m, j in zip(Ms, Js, strict=True)])
    Z = np.linalg.svd(J)[2][:, 6:]  # an independent null basis (SVD)
    want = np.array([np.linalg.eigvalsh(z @ m @ z.T) for z, m in zip(Z, Ms, strict=True)])
    assert np.abs(en - want).max() < 1e-10
    for rule in ("auto", "thesis"):
        labels = labels_many(Ms, Js, rule, True, e, en)
        assert labels == [classify(m, j, rule) for m, j in zip(Ms, Js, strict=True)]
        assert len(set(labels)) == (3 if rule == "auto" else 2)
    from kinredund.tracking.linalg import normality_many, null_space_bases

    res = normality_many(null_space_bases(J), np.array(grads))
    assert np.abs(res - [multipliers(j, g)[1] for j, g in zip(Js, grads, strict=True)]).max() < 1e-12


def test_non_symmetric_M_eigs_are_the_sorted_real_parts():
    rng = np.random.default_rng(1)
    M = rng.normal(size=(4, 5, 5))
    want = np.array([np.sort(np.linalg.eigvals(m).real) for m in M])
    assert np.abs(eigs_many(M) - want).max() < 1e-12


def test_tracker_checks_its_options():
    r, path, index, q0 = _planar()
    with pytest.raises(OptionError, match="t0"):
        Tracker(r, path, index, q0, 0.01, t0=float("inf"))
    with pytest.raises(kinredund.PathError, match="time step"):
        Tracker(r, path, index, q0, 0.0)
    with pytest.raises(kinredund.ChoiceError, match="kkt"):
        Tracker(r, path, index, q0, 0.01, qp_backend="proxsuite")
    with pytest.raises(kinredund.PathError, match="needs a performance index"):
        Tracker(r, Circle((3.0, 3.0), 0.8, 1.0), None, q0, 0.01)
    assert minimum_norm(3) is not None


def test_deferred_diagnostics_against_a_fresh_evaluation():
    """track()'s diagnostics are computed on first read (kinredund.trajectory.Deferred): read, they equal
    an independent evaluation at the recorded joints - ||(1 - K^+ K) grad z|| by SVD (Eq. 4.5; J = H K
    spans K's rows on the pose path), the eigenvalues of M, the labels classify() gives at the step's
    (M, J) - and they are kept once read and survive pickling, copying, replace() and JSON as values."""
    import copy
    import dataclasses
    import pickle

    from kinredund.trajectory import Deferred, Trajectory

    r, path, index, q0 = panda_circle(wrist_amplitude=np.radians(15))
    tr = track(r, path, index, q0, steps_per_loop=50)
    names = ("solver", "m_eigs", "m_null_eigs", "normality_residual")
    assert all(isinstance(tr.__dict__[n], Deferred) for n in names)  # not computed by track()
    res = tr.normality_residual
    assert isinstance(tr.__dict__["normality_residual"], np.ndarray)  # kept once read
    for k in range(0, 51, 5):
        _, grad, _ = index.evaluate(tr.q[k], tr.t[k])
        K = r.kinematics.jacobian(tr.q[k])[2]
        Z = np.linalg.svd(K)[2][6:].T  # an independent null basis
        assert abs(res[k] - np.linalg.norm(Z.T @ grad)) < 1e-12 * max(1.0, np.linalg.norm(grad))
    assert res.max() < 1e-9  # the optimum is held (Eq. 4.5), not only recorded
    assert tr.m_eigs.shape == (51, 7) and tr.m_null_eigs.shape == (51, 1)
    tracker = Tracker(r, path, index, q0, path.period / 50)
    for k in range(1, 51):
        tracker.step()
        s = tracker.stepper
        assert np.abs(tr.m_eigs[k] - np.linalg.eigvalsh(s.M)).max() < 1e-12 * max(1.0, np.abs(s.M).max())
        assert tr.solver[k] == classify(s.M, s.pt.J, "auto")
    # a record read nowhere yet pickles, copies and converts with its values, not with callables
    fresh = track(r, path, index, q0, steps_per_loop=50)
    state = fresh.__getstate__()
    assert not any(isinstance(v, Deferred) for v in state.values())
    for other in (pickle.loads(pickle.dumps(track(r, path, index, q0, steps_per_loop=50))),
                  copy.deepcopy(track(r, path, index, q0, steps_per_loop=50)),
                  dataclasses.replace(track(r, path, index, q0, steps_per_loop=50), meta={}),
                  Trajectory.from_json_dict(track(r, path, index, q0, steps_per_loop=50).to_json_dict())):
        assert other.solver == tr.solver
        assert np.abs(other.normality_residual - res).max() < 1e-15
        assert np.abs(other.m_eigs - tr.m_eigs).max() < 1e-12


def test_a_record_does_not_change_when_the_recorder_goes_on():
    """The record made mid-run (the partial record of a failure) keeps its length when the recorder
    records more points before its diagnostics are first read."""
    from kinredund.tracking.recorder import Recorder

    r, path, index, q0 = panda_circle(wrist_amplitude=np.radians(15))
    tracker = Tracker(r, path, index, q0, path.period / 40)
    rec = Recorder(tracker.stepper)
    rec.add()
    for _ in range(10):
        tracker.step()
        rec.add()
    part = rec.trajectory(robot_name="panda", scheme="augmented", mode="default", loops=None, steps_per_loop=None,
                          period=None, meta={})
    for _ in range(10):
        tracker.step()
        rec.add()
    assert len(part.solver) == len(part.normality_residual) == len(part.m_eigs) == len(part.t) == 11
    assert part.normality_residual.max() < 1e-9


def test_a_record_does_not_follow_its_inputs_after_the_run():
    """The deferred diagnostics depend on the run alone: changing the caller's q0 (the index's reference
    array here), or the record's own q, before they are read changes nothing; and JointDeviation keeps
    its own read-only copy of the reference."""
    r, path, index, q0 = panda_circle(wrist_amplitude=np.radians(15))
    ref = track(r, path, index, q0, steps_per_loop=40)
    want = ref.normality_residual
    tr = track(r, path, index, q0, steps_per_loop=40)
    q0 += 0.2  # the caller reuses its array (e.g. to warm-start the next run)
    tr.q[:] += 0.1
    assert np.abs(tr.normality_residual - want).max() < 1e-15 and want.max() < 1e-9
    assert not index.reference.flags.writeable and np.abs(index.reference - (q0 - 0.2)).max() < 1e-15
    # the deferred per-point fields too (the same code on the same inputs: bit for bit)
    for name in ("t", "p", "p_desired", "position_error", "vect_error", "lam", "limit_margins", "active_bounds"):
        assert np.array_equal(getattr(tr, name), getattr(ref, name)), name


def test_an_index_that_can_change_is_read_at_the_run_end():
    """grad z of an index that may change after the run (a CustomIndex over the caller's array) is taken at the
    run's end: changing the array before the record's diagnostics are read changes nothing. Only an index that
    cannot change (Index.fixed: JointDeviation, frozen with read-only copies) is read when they are."""
    from kinredund.indices import CustomIndex, Index, JointDeviation

    r, path, _, q0 = panda_circle(wrist_amplitude=np.radians(15))
    ref = r.home.copy()
    index = CustomIndex(lambda q: 0.5 * float((q - ref) @ (q - ref)), lambda q: q - ref, lambda q: np.eye(7))
    want = track(r, path, index, q0, steps_per_loop=40).normality_residual
    tr = track(r, path, index, q0, steps_per_loop=40)
    ref += 0.3  # the index's z changes: a record read now must not follow it
    assert np.array_equal(tr.normality_residual, want)
    assert not index.fixed and not Index.fixed and JointDeviation(q0).fixed


def test_the_deferred_per_point_fields_against_a_fresh_evaluation():
    """The fields track() does not read are computed on first read (PerPoint) and equal an independent
    evaluation: the times k dt, the pose at the recorded joints (forward kinematics), the path's, the task's errors
    from them, the margins to the limits, the switch times of meta; lambda as U lambda (the closure 7-vector's)."""
    from kinredund.tracking.tracker import robot_limits
    from kinredund.trajectory import Deferred

    r, path, index, q0 = panda_circle(wrist_amplitude=np.radians(15))
    tr = track(r, path, index, q0, steps_per_loop=60)
    names = ("t", "p", "p_desired", "lam", "position_error", "trace_error", "vect_error", "axis_error",
             "active_bounds", "bound_multipliers", "limit_margins", "switch_times")
    assert all(isinstance(tr.__dict__[n], Deferred) for n in names)  # not computed by track()
    dt = path.period / 60
    assert np.abs(tr.t - dt * np.arange(61)).max() < 1e-15
    lim = robot_limits(r)
    for k in range(0, 61, 6):
        Q, p = r.kinematics.pose(tr.q[k])
        s = path(tr.t[k])
        assert np.abs(tr.p[k] - p).max() < 1e-12 and np.abs(tr.p_desired[k] - s.p).max() < 1e-12
        assert abs(tr.position_error[k] - np.linalg.norm(p - s.p)) < 1e-12
        assert abs(tr.trace_error[k] - abs(np.trace(Q) - np.trace(s.Q))) < 1e-12
        margins = np.minimum(tr.q[k] - lim.lower, lim.upper - tr.q[k])
        assert np.abs(tr.limit_margins[k] - np.minimum(margins, 1e10)).max() < 1e-15
    assert tr.axis_error is None and tr.lam.shape == (61, 7) and tr.active_bounds.shape == (61, 7)
    assert list(tr.switch_times) == [w["t"] for w in tr.meta["switches"]]
    assert isinstance(tr.__dict__["p"], np.ndarray)  # kept once read


def test_deferred_diagnostics_read_from_several_threads():
    """Threads reading one record's deferred fields at once all get the same values, each group (the diagnostics,
    the per-point fields) computed once."""
    from concurrent.futures import ThreadPoolExecutor

    from kinredund.tracking import recorder

    r, path, index, q0 = panda_circle(wrist_amplitude=np.radians(15))
    calls, runs = [], {kind: kind._run for kind in (recorder.Diagnostics, recorder.PerPoint)}

    def counted(kind):
        def run(self, *args):
            calls.append(kind)
            return runs[kind](self, *args)
        return run

    for kind in runs:
        kind._run = counted(kind)
    try:
        records = [track(r, path, index, q0, steps_per_loop=20) for _ in range(4)]
        names = ("solver", "m_eigs", "position_error", "normality_residual", "p", "lam") * 4
        with ThreadPoolExecutor(8) as pool:
            got = list(pool.map(lambda a: getattr(records[a[0]], a[1]), [(k, n) for k in range(4) for n in names]))
    finally:
        for kind, run in runs.items():
            kind._run = run
    assert sorted(calls, key=id) == sorted(list(runs) * 4, key=id)  # each group once per record
    assert all(got[24 * k + 3] is records[k].normality_residual for k in range(4))
    assert all(got[24 * k + 4] is records[k].p for k in range(4))


def test_a_bare_record_object_has_no_diagnostics_attribute():
    from kinredund.trajectory import Trajectory

    bare = object.__new__(Trajectory)
    assert not hasattr(bare, "solver") and getattr(bare, "m_eigs", "absent") == "absent"


def test_assemble_makes_the_record_the_dataclass_makes():
    """Trajectory.assemble (the recorder's one-step construction) gives the record Trajectory(**values) gives:
    the same values in the same order, the defaults (a new meta dict each), and a TypeError for a missing or an
    unknown field."""
    from kinredund.trajectory import Deferred, Trajectory

    q = np.zeros((3, 2))
    values = {"robot": "planar3", "task": "planar", "t": np.arange(3.0), "q": q, "p": np.zeros((3, 3)),
              "p_desired": Deferred(lambda: np.ones((3, 3))), "lam": q, "loop_period": 2.0}
    a, b = Trajectory(**values), Trajectory.assemble(**values)
    assert list(a.__dict__) == list(b.__dict__) and all(a.__dict__[k] is b.__dict__[k] for k in values)
    assert b.p_desired.sum() == 9.0 and b.mode == "default" and b.solver == () and b.qdot is None
    assert b.meta == {} and b.meta is not Trajectory.assemble(**values).meta
    with pytest.raises(TypeError, match="missing: \\['q'\\]"):
        Trajectory.assemble(**{k: v for k, v in values.items() if k != "q"})
    with pytest.raises(TypeError, match="not fields: \\['speed'\\]"):
        Trajectory.assemble(**values, speed=1.0)


def test_loop_drifts_are_joint_drift_per_loop():
    """angles.loop_drifts (one pass over the loops) is joint_drift at each loop's end, bit for bit (the same
    arithmetic), revolute joints compared modulo 2 pi across the wrap, a prismatic one as it is."""
    from kinredund.kinematics.angles import joint_drift, loop_drifts

    rng = np.random.default_rng(5)
    q = rng.uniform(-4.0, 4.0, size=(3 * 7 + 1, 3))
    q[7, 0] = q[0, 0] + 2 * np.pi - 1e-3  # a turn and a bit: a drift of 1e-3 rad
    revolute = np.array([True, True, False])
    got = loop_drifts(q, 7, 3, revolute)
    assert got.shape == (3,) and got.dtype == float
    assert list(got) == [joint_drift(q[0], q[7 * (i + 1)], revolute) for i in range(3)]
    assert loop_drifts(q, 7, 0, revolute).shape == (0,)
