"""The strict tracker's failures (issue 15): each cause named, the last good point on the path, a partial
record that plays; sub-steps recovering a coarse run; a jump reported, never recorded.

The cases are on the planar 3R (links 3, 2, 1 m: reach 6 m) and were found with small searches:

- a fold: z = 1/2 (q - q0)^T (J0^T J0 + c n n^T) (q - q0), n the null vector of J0 = J(q0), c = 0.1: at q0
  the reduced Hessian is c > 0; along a 0.3 m circle through p(q0) it reaches zero near t = 1.62 s (the
  plain corrector meets R singular there);
- a kinematic singularity: a 1 m circle inside the 6 m reach, touching it at half the period (the arm
  stretched), from its far side with minimum norm;
- out of reach: a 1.5 m circle from p(q0) reaching 3 m further out, beyond the reach;
- a non-optimal start: a configuration on the path that Newton's corrector takes to a saddle of z;
- a step longer than the period;
- step control: a 1 m circle at 4 steps per loop, which the plain corrector fails (R singular at the
  predicted point) and sub-steps complete, equal at the requested times to a run at 64 steps per loop;
- a silent jump: a circle of the fold family on which the plain corrector jumps 0.8 rad onto another
  branch and reports success; and a path that itself jumps.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import rounding

import kinredund
from kinredund import load_robot
from kinredund.errors import PathError, SingularityError, TrackingError
from kinredund.ik.solve import solve_ik
from kinredund.indices import CustomIndex, minimum_norm
from kinredund.paths import Circle, FunctionPath
from kinredund.tracking import Tracker, track
from kinredund.tracking.watch import Watch, exact

#: the stepper's on-path bar (1e-6 of the path's scale) is what "on the path" means for the last good point
ON_PATH = 1e-6


@pytest.fixture(scope="module")
def arm():
    return load_robot("planar3r")


def _check_failure(arm, err: TrackingError, cause: str) -> None:
    """Its cause, a last good point on the path and inside the limits, and a partial record that plays."""
    assert err.cause == cause, str(err)
    assert isinstance(err, SingularityError) and isinstance(err, PathError)  # old callers still catch it
    q = np.asarray(err.q)
    assert q.shape == (3,) and np.all(np.isfinite(q)) and np.abs(q).max() < 10.0
    assert np.all(q >= arm.lower) and np.all(q <= arm.upper)
    p = arm.fk(q)[:2, 3]
    path = err.partial_path
    assert np.linalg.norm(p - path(err.t).p[:2]) <= ON_PATH
    traj = err.partial.checked(nq=3)
    assert traj.t[-1] <= err.t + 1e-12
    # the record's points are on the path too (the strict tracker records only corrected points)
    assert traj.position_error.max() <= ON_PATH
    assert {"sigma_min_J", "reduced_hessian_min", "task_residual"} <= set(err.watched)


def _fails(arm, path, index, q0, **kwargs) -> TrackingError:
    with pytest.raises(TrackingError) as info:
        track(arm, path, index, q0, **kwargs)
    info.value.partial_path = path
    return info.value


def _fold_case(arm):
    q0 = np.array([0.3, 0.8, 0.9])
    J0 = arm.position_jacobian(q0)[:2]
    n = np.linalg.svd(J0)[2][-1]
    A = J0.T @ J0 + 0.1 * np.outer(n, n)
    index = CustomIndex(lambda q: 0.5 * (q - q0) @ A @ (q - q0), lambda q: A @ (q - q0), lambda q: A)
    p0 = arm.fk(q0)[:2, 3]
    return Circle(p0 - np.array([0.3, 0.0]), 0.3, 1.0, axis_x=(1.0, 0.0, 0.0)), index, q0


@pytest.mark.parametrize("scheme", ["augmented", "velocity"])
def test_fold(arm, scheme):
    path, index, q0 = _fold_case(arm)
    err = _fails(arm, path, index, q0, scheme=scheme)
    _check_failure(arm, err, "fold")
    # it stops before the crossing: the plain corrector meets R singular a little later
    with pytest.raises(SingularityError, match="algorithmic") as plain:
        track(arm, path, index, q0, strict=False, scheme=scheme)
    assert err.t < plain.value.t
    assert "e+" not in str(err)  # the message quotes no diverged corrector iterate
    # the nearest good sub-step point: the eigenvalue near zero, still positive; the error's own point is the
    # last requested time before it (where the partial record ends)
    assert 0.0 < err.watched["substep_reduced_hessian_min"] < 1e-2
    assert err.t <= err.watched["substep_t"] < err.t + path.period / 200
    assert err.t == err.partial.t[-1] and np.array_equal(err.q, err.partial.q[-1])


@pytest.mark.parametrize("scheme", ["augmented", "velocity"])
def test_kinematic_singularity(arm, scheme):
    path = Circle(np.array([5.0, 0.0, 0.0]), 1.0, 1.0, start_angle=np.pi)  # touches the 6 m reach at T/2
    index = minimum_norm(3)
    q0 = solve_ik(arm, path(0.0).p[:2], index, starts=12, seed=0).q
    err = _fails(arm, path, index, q0, scheme=scheme)
    _check_failure(arm, err, "kinematic_singularity")
    assert abs(err.watched["substep_t"] - path.period / 2) < path.period / 200  # at the stretched point
    assert err.watched["substep_sigma_min_J"] < 1e-2 and err.t <= err.watched["substep_t"]


@pytest.mark.parametrize("scheme", ["augmented", "velocity"])
def test_out_of_reach(arm, scheme):
    q0 = np.array([0.2, 0.6, 0.6])
    p0 = arm.fk(q0)[:2, 3]
    d = p0 / np.linalg.norm(p0)
    path = Circle(np.append(p0 + 1.5 * d, 0.0), 1.5, 1.0, axis_x=(-d[0], -d[1], 0.0))
    index = minimum_norm(3)
    q0 = solve_ik(arm, p0, index, q0=q0).q
    err = _fails(arm, path, index, q0, scheme=scheme)
    _check_failure(arm, err, "out_of_reach")
    assert err.watched["reach_residual"] > 1e-3  # the arm cannot close that gap [m]


def test_non_optimal_start(arm):
    q0 = np.array([0.82, -1.38, -2.75])  # on its path, far from a minimum of z: the corrector ends on a saddle
    path = Circle(np.append(arm.fk(q0)[:2, 3] - np.array([0.3, 0.0]), 0.0), 0.3, 1.0)
    err = _fails(arm, path, minimum_norm(3), q0)
    _check_failure(arm, err, "non_optimal_start")
    assert err.t == 0.0 and np.allclose(err.q, q0) and len(err.partial.t) == 1


def test_step_longer_than_the_period(arm):
    q0 = np.array([0.2, 0.6, 0.6])
    index = minimum_norm(3)
    q0 = solve_ik(arm, arm.fk(q0)[:2, 3], index, q0=q0).q
    path = Circle(np.append(arm.fk(q0)[:2, 3] - np.array([0.5, 0.0]), 0.0), 0.5, 1.0)
    with pytest.raises(TrackingError) as info:
        Tracker(arm, path, index, q0, 1.5 * path.period)
    info.value.partial_path = path
    _check_failure(arm, info.value, "step_too_long")


def test_sub_steps_recover_a_coarse_run(arm):
    """4 steps per loop: the plain corrector fails, sub-steps finish, equal to a 64-step run at its times."""
    q0 = np.array([0.2, 0.6, 0.6])
    index = minimum_norm(3)
    q0 = solve_ik(arm, arm.fk(q0)[:2, 3], index, q0=q0).q
    path = Circle(np.append(arm.fk(q0)[:2, 3] - np.array([1.0, 0.0]), 0.0), 1.0, 1.0)
    with pytest.raises(SingularityError):
        track(arm, path, index, q0, steps_per_loop=4, strict=False)
    coarse = track(arm, path, index, q0, steps_per_loop=4, loops=2)
    fine = track(arm, path, index, q0, steps_per_loop=64, loops=2)
    assert len(coarse.t) == 9  # the record stays on the requested times
    np.testing.assert_allclose(coarse.t, fine.t[::16], rtol=0, atol=1e-12)
    # both sit on the same locally unique optimum, each corrected to ~1e-12: 1e-9 leaves room for its conditioning
    assert np.abs(coarse.q - fine.q[::16]).max() < 1e-9
    assert coarse.position_error.max() < 1e-10


def test_branch_jump_is_reported_not_recorded(arm):
    """A circle on which the plain corrector jumps 0.80 rad in one step (50 times its neighbours) onto another
    branch of the optimum and still tracks to 1e-12 and closes: the issue's silent jump. The strict tracker
    stops before it with ``fold`` (found by a random search over the fold family of :func:`_fold_case`)."""
    c, rad, ang = 0.40824732527422036, 0.6979609370363795, 5.8055571968886825
    q0 = np.array([1.3323790752341345, -1.793304243522416, 1.3103806554368416])
    J0 = arm.position_jacobian(q0)[:2]
    n = np.linalg.svd(J0)[2][-1]
    A = J0.T @ J0 + c * np.outer(n, n)
    index = CustomIndex(lambda q: 0.5 * (q - q0) @ A @ (q - q0), lambda q: A @ (q - q0), lambda q: A)
    d = np.array([np.cos(ang), np.sin(ang)])
    path = Circle(arm.fk(q0)[:2, 3] - rad * d, rad, 1.0, axis_x=(d[0], d[1], 0.0))
    plain = track(arm, path, index, q0, loops=2, strict=False)
    steps = np.linalg.norm(np.diff(plain.q, axis=0), axis=1)
    assert steps.max() > 30 * np.median(steps) and plain.position_error.max() < 1e-10  # recorded as success
    err = _fails(arm, path, index, q0, loops=2)
    _check_failure(arm, err, "fold")
    assert err.t < plain.t[1 + int(np.argmax(steps))]  # before the jump
    kept = np.linalg.norm(np.diff(err.partial.q, axis=0), axis=1)
    # nothing of it is recorded: the steps grow as the fold nears (the optimum moves like sqrt(t* - t)), the
    # largest kept one (0.09 rad) far below the jump
    assert kept.max() < 0.2 * steps.max()


def test_path_jump_is_reported_not_recorded(arm):
    """A path that jumps by 0.3 m at t = 0.5 s: the joints would jump; the strict tracker stops before it."""
    q0 = np.array([0.2, 0.6, 0.6])
    p0 = arm.fk(q0)[:2, 3]

    def fn(t):
        return p0 + np.array([0.1 * t, 0.0]) + (np.array([0.0, 0.3]) if t >= 0.5 else 0.0), np.array([0.1, 0.0])

    path = FunctionPath(fn)
    q0 = solve_ik(arm, p0, minimum_norm(3), q0=q0).q
    err = _fails(arm, path, minimum_norm(3), q0, duration=1.0, steps=40)
    assert err.cause == "path_discontinuity" and err.t < 0.5
    assert np.abs(np.diff(err.partial.q, axis=0)).max() < 0.05  # nothing of the jump is recorded
    plain = track(arm, path, minimum_norm(3), q0, duration=1.0, steps=40, strict=False)
    assert np.abs(np.diff(plain.q, axis=0)).max() > 0.05  # the plain tracker records it


def test_strict_changes_nothing_on_a_regular_run():
    """Where nothing happens the strict step is the plain one: the Panda benchmark circle, identical records."""
    from kinredund.problems import panda_circle

    robot, path, index, q0 = panda_circle(wrist_amplitude=np.radians(15))
    strict = track(robot, path, index, q0, steps_per_loop=100, diagnostics=False)
    plain = track(robot, path, index, q0, steps_per_loop=100, diagnostics=False, strict=False)
    assert np.array_equal(strict.q, plain.q) and np.array_equal(strict.lam, plain.lam)


def test_thesis_mode_reports_through_the_same_error(arm):
    path = Circle(np.array([5.0, 0.0, 0.0]), 1.0, 1.0, start_angle=np.pi)
    index = minimum_norm(3)
    q0 = solve_ik(arm, path(0.0).p[:2], index, starts=12, seed=0).q
    with pytest.raises(TrackingError) as info:
        track(arm, path, index, q0, mode="thesis")
    assert info.value.cause == "kinematic_singularity" and info.value.partial.checked(nq=3) is not None
    # thesis mode's explicit steps stay within ~1e-3 of the path (its accuracy), not the strict tracker's 1e-6
    assert np.linalg.norm(arm.fk(info.value.q)[:2, 3] - path(info.value.t).p[:2]) < 1e-2


def test_partial_record_plays(arm, tmp_path):
    """The fold's partial record goes through the replay (meshcat's static HTML)."""
    pytest.importorskip("meshcat")
    from kinredund.ui.viz import replay_html

    path, index, q0 = _fold_case(arm)
    err = _fails(arm, path, index, q0)
    err.partial.save_json(tmp_path / "fold.json")
    back = kinredund.Trajectory.load_json(tmp_path / "fold.json")  # what `kinredund play` reads
    out = replay_html(back, tmp_path / "fold.html", robot=arm, max_frames=20)
    assert out.stat().st_size > 1000 and np.array_equal(back.q, err.partial.q)


def test_cli_track_writes_the_partial_record(arm, tmp_path):
    """``kinredund track`` on a circle leaving the reach: exit code of an error, the partial record written."""
    import json

    from kinredund.ui.cli import EXIT_FAILED, main

    out = tmp_path / "partial.json"
    code = main(["track", "planar3r", "--radius", "2.5", "--index", "min-norm", "--partial", str(out)])
    assert code == EXIT_FAILED  # a run that stopped is a result that failed, not bad input (2)
    data = json.loads(out.read_text())
    assert data["failure"]["cause"] == "out_of_reach"  # a 2.5 m circle from the home pose leaves the 6 m reach
    assert kinredund.Trajectory.load_json(out).checked(nq=3).t[-1] <= data["failure"]["t"]
    assert main(["play", str(out), "--html", str(tmp_path / "partial.html")]) == 0


def test_tracking_error_pickles():
    import pickle

    err = TrackingError("x", cause="fold", t=1.0, q=[0.1, 0.2], watched={"sigma_min_J": 0.5})
    back = pickle.loads(pickle.dumps(err))
    assert back.cause == "fold" and back.t == 1.0 and np.allclose(back.q, [0.1, 0.2]) and back.sigma_min == 0.5
    with pytest.raises(kinredund.ChoiceError):
        TrackingError("x", cause="unknown")


@pytest.mark.parametrize("mode", ["default", "thesis"])
def test_singular_start_is_a_tracking_error(arm, mode):
    """A start at a kinematic singularity (the arm stretched on the 6 m reach, where the path begins) is a
    TrackingError like every other stop: its cause, the start as the last point, sigma_min(J) against the
    watch's floor (watch.SIGMA_FLOOR of sigma_max(J)) and a one-point record that plays; still a
    SingularityError for callers that catch that."""
    from kinredund.tracking.watch import SIGMA_FLOOR

    path = Circle(np.array([5.0, 0.0, 0.0]), 1.0, 1.0)  # p(0) = (6, 0): only q = 0 reaches it
    with pytest.raises(SingularityError) as info:
        track(arm, path, minimum_norm(3), np.zeros(3), mode=mode)
    err = info.value
    assert isinstance(err, TrackingError) and err.cause == "kinematic_singularity" and err.t == 0.0
    w = err.watched
    assert w["sigma_min_J"] <= SIGMA_FLOOR * w["sigma_max_J"] and w["sigma_max_J"] > 1.0
    assert w["task_residual"] < 1e-12 and np.abs(np.asarray(err.q)).max() == 0.0
    assert err.partial.checked(nq=3).position_error.max() < 1e-12


def test_a_named_failure_at_the_start_keeps_its_cause(monkeypatch):
    """A TrackingError raised while the start is corrected (here the limits' ``not_strongly_stable``, made
    to happen by a stand-in for R's factorisation) is reported with its own cause, not renamed by the
    start's diagnosis (TrackingError is a SingularityError and a PathError too). The Python stepper's start: the
    compiled backend's start and corrector solves are the core's, which the stand-in does not reach."""
    from kinredund.problems import panda_circle
    from kinredund.tracking.limited import LimitedPredictorCorrector

    def not_stable(self, pt, M):
        raise self._failure("not_strongly_stable", "stand-in: the reduced R is singular")

    monkeypatch.setattr(LimitedPredictorCorrector, "_factor", not_stable)
    robot, path, index, q0 = panda_circle(wrist_amplitude=np.radians(15))
    with pytest.raises(TrackingError) as info:
        track(robot, path, index, q0, steps_per_loop=20, backend="python")
    assert info.value.cause == "not_strongly_stable" and "stand-in" in str(info.value)


@pytest.mark.parametrize(("m", "n"), [(2, 3), (6, 7), (3, 7), (5, 5)])
def test_the_watch_measures_what_a_qr_null_basis_gives(m, n):
    """The watch's exact measurement (one SVD of J: sigma_min and the null-space basis together) against the
    same quantities computed another way: a QR null basis Z of J and the eigenvalues of Z^T sym(M) Z, which do not
    depend on the orthonormal basis (rounding of numbers of size |M| cond(J), the tolerance policy's kind 1); its
    vector is a unit vector in the null space of J whose Rayleigh quotient is the eigenvalue."""
    rng = np.random.default_rng(m * 10 + n)
    for _ in range(5):
        J, M = rng.standard_normal((m, n)), rng.standard_normal((n, n))
        sigma, eig, v = exact(J, M)
        s = np.linalg.svd(J, compute_uv=False)
        assert abs(sigma - s[-1]) <= rounding(s[0])
        if n == m:
            assert eig == np.inf and not v.any()
            continue
        Z = np.linalg.qr(J.T, mode="complete")[0][:, m:]
        S = Z.T @ (0.5 * (M + M.T)) @ Z
        bar = rounding(np.abs(M).max() * n * s[0] / s[-1])
        assert abs(eig - np.linalg.eigvalsh(S)[0]) <= bar
        assert abs(v @ v - 1.0) <= rounding() and np.linalg.norm(J @ v) <= rounding(s[0])
        assert abs(v @ (0.5 * (M + M.T)) @ v - eig) <= bar


def test_the_watch_names_the_crossing_predicted_first():
    """Both quantities heading to zero: ``ahead`` names the one whose extrapolated crossing comes first, whichever
    is checked first. The histories are the corner run's last two sub-step points (tests/test_tracking_corners.py:
    sigma_min 0.0210 -> 0.0167, the eigenvalue 0.753 -> 0.553 from t = 7.02446 to 7.02512 s), where the held optimum
    folds; with the two histories swapped, sigma_min goes first. Crossing times by hand from the v^2-linear
    extrapolation (here the earlier of the watch's two, v and v^2 linear)."""
    times = [7.0244649298625195, 7.0251192647074]
    sigma, eig = [0.021002700769252577, 0.01666967412650829], [0.7533603598097082, 0.5530735112037583]

    def watch(sig, e):
        w = Watch()
        for t, s, v in zip(times, sig, e, strict=True):
            w.push(t, s, v)
        return w

    def crossing(v):  # v^2 linear through both points, to zero (the floors, ~1e-8, move it by < 1e-12 s)
        return times[1] + v[1] ** 2 * (times[1] - times[0]) / (v[0] ** 2 - v[1] ** 2)

    w = watch(sigma, eig)
    t_fold, t_sigma = crossing(eig), crossing(sigma)
    assert t_fold < t_sigma  # 7.02588 < 7.02623 s
    assert w.ahead(t_fold - 1e-6) is None and w.ahead(t_fold + 1e-6) == "fold" and w.ahead(7.07) == "fold"
    assert abs(w.crossings()["fold"] - t_fold) <= 1e-9 and abs(w.crossings()["kinematic"] - t_sigma) <= 1e-9
    w = watch([v * 0.05 for v in eig], [v * 40 for v in sigma])  # the same shapes, the roles swapped
    assert w.ahead(7.07) == "kinematic" and w.ahead(t_fold - 1e-6) is None


def test_every_error_of_the_family_pickles_with_its_fields():
    """An error whose __init__ takes other arguments than its message (ChoiceError(what, value, allowed), the file
    errors (path, reason), ...) pickled, but unpickling called __init__ with the message alone (TypeError): in
    track_many(processes=) a worker's ChoiceError then broke the pool, reported as a worker 'killed, or out of
    memory'. Each unpickles as its own class with its message and fields."""
    import pickle

    from kinredund.errors import (
        ChoiceError,
        FrameNotFoundError,
        InputFileError,
        OutputPathError,
        PathError,
        UnknownRobotError,
        URDFError,
    )

    for err in (ChoiceError("scheme", "bogus", ["augmented", "velocity"]), UnknownRobotError("x", ["panda"]),
                URDFError("a.urdf", "bad"), FrameNotFoundError("ee", ["a", "b"], "note"), InputFileError("f", "gone"),
                OutputPathError("g", "full"), PathError("off", t=0.5, q=[1.0])):
        back = pickle.loads(pickle.dumps(err))
        assert type(back) is type(err) and str(back) == str(err) and back.args == err.args
        assert vars(back).keys() == vars(err).keys()
        assert all(np.array_equal(getattr(back, k), v) for k, v in vars(err).items())
