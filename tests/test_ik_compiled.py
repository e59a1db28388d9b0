"""The IK's constrained iteration in C++ (issue 28, :mod:`kinredund.ik.compiled`): the same results as the Python
iteration (q, converged, reason, iterations), on several arms, task kinds, indices, with and without bounds; the
box QP of a step leaving the bounds is the core's where the Python iteration's guesses solve it or its equality form
is infeasible (a plan hands back few), with the same answers; the answers pass
check_optimality on their own; the backend's options and errors."""

from __future__ import annotations

import os
import warnings

import numpy as np
import pytest
from conftest import IK_TOL, robot, rounding

from kinredund.errors import ChoiceError, OptionError
from kinredund.ik import compiled
from kinredund.ik.qp import BoxStep
from kinredund.ik.solve import check_optimality, solve_ik
from kinredund.indices import CustomIndex, JointDeviation, mid_range, minimum_norm
from kinredund.planning.cyclic import plan
from kinredund.problems import near_seed_ik_problems, panda_circle

pytestmark = pytest.mark.skipif(compiled.core_module() is None and not os.environ.get("CI"),
                                reason="the compiled core is not built (CI requires it: test_core_build.py)")

#: joints of the two backends [rad or m]: both iterations take the same steps (the same decisions at every test)
#: and stop at the same iteration; they differ by the rounding of their linear algebra (LAPACK's against
#: Eigen's factorisations) carried through the Newton iterations, far below the residual tolerance (1e-10)
Q_BAR = 1e-10

#: (robot, task, index kind): 7-axis arms with the pose task and the position task, the axis task on the Panda and
#: on a 6-axis arm, the planar 3R (an HD table) with the planar task
CASES = [
    ("panda", None, "mid_range"),
    ("panda", "position", "minimum_norm"),
    ("panda", "axis", "weighted"),
    ("xarm7", None, "minimum_norm"),
    ("puma7", None, "mid_range"),
    ("ur5", "axis", "mid_range"),
    ("planar3r", None, "minimum_norm"),
    ("planar3r", None, "weighted"),
]


def _index(r, kind: str, rng) -> JointDeviation:
    if kind == "mid_range":
        return mid_range(r.lower, r.upper)
    if kind == "minimum_norm":
        return minimum_norm(r.nq)
    return JointDeviation(rng.uniform(-1.0, 1.0, r.nq), rng.uniform(0.2, 2.0, r.nq))


def _draw(r, rng, spread: float = 0.3):
    """A reachable target (the pose at a random q within the limits) and a seed near that q."""
    lo, hi = np.maximum(r.lower, -np.pi), np.minimum(r.upper, np.pi)
    qt = rng.uniform(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo))
    Q, p = r.kinematics.pose(qt)
    target = {"pose": (Q.copy(), p.copy()), "axis": (Q[:, 2].copy(), p.copy()), "position": p.copy(),
              "planar": p[:2].copy()}[r.task]
    q0 = np.clip(qt + rng.normal(0.0, spread, r.nq), r.lower, r.upper)
    return target, q0


def _same(r, target, index, q0, **kw):
    """The Python and compiled solves of one problem agree; returns (python, compiled, the core's outcomes)."""
    py = solve_ik(r, target, index, q0=q0, backend="python", **kw)
    before = dict(compiled.COUNTS)
    cc = solve_ik(r, target, index, q0=q0, backend="compiled", **kw)
    counts = {k: compiled.COUNTS.get(k, 0) - before.get(k, 0) for k in compiled.COUNTS}
    assert sum(counts.values()) >= cc.starts  # the core ran every start (again after each hand-back)
    assert (cc.converged, cc.reason, cc.iterations, cc.starts) == (py.converged, py.reason, py.iterations, py.starts)
    np.testing.assert_allclose(cc.q, py.q, rtol=0.0, atol=Q_BAR)
    g = float(np.abs(index.evaluate(py.q)[1]).max())
    assert abs(cc.objective - py.objective) <= Q_BAR * max(1.0, g)
    assert cc.reduced_hessian_pd == py.reduced_hessian_pd
    return py, cc, counts


def _check_answer(r, target, index, res, bounds: bool) -> None:
    """check_optimality's own evaluation: residual and normality within the solver's bars plus rounding."""
    opt = check_optimality(r, target, res.q, index, bounds=bounds)
    g = float(np.abs(index.evaluate(res.q)[1]).max())
    assert opt.residual <= IK_TOL + rounding(10.0)
    # the normality on K's null space (the solver's is on G's, which differs by O(residual), Eq. D.30)
    assert opt.normality_residual <= max(IK_TOL, 1e-13 * (1.0 + g)) + rounding(g) + 10.0 * g * opt.residual
    assert opt.reduced_hessian_pd
    if bounds:
        assert np.all(res.q >= r.lower) and np.all(res.q <= r.upper)


@pytest.mark.parametrize("name,task,kind", CASES)
@pytest.mark.parametrize("bounds", [False, True])
def test_compiled_iteration_gives_the_python_results(name, task, kind, bounds):
    r = robot(name, task)
    rng = np.random.default_rng(sum(map(ord, f"{name}{task}{kind}{bounds}")))
    converged = 0
    for _ in range(3):
        target, q0 = _draw(r, rng)
        index = _index(r, kind, rng)
        _, cc, _ = _same(r, target, index, q0, bounds=bounds)
        if cc.converged:
            converged += 1
            _check_answer(r, target, index, cc, bounds)
    assert converged >= 2  # reachable targets from nearby seeds: most converge


def _box_qp_calls(monkeypatch) -> list:
    """A list that grows by one at each call of the Python iteration's box QP of the Newton step (BoxStep.equality)."""
    calls = []
    original = BoxStep.equality

    def counted(self, *args):
        calls.append(1)
        return original(self, *args)

    monkeypatch.setattr(BoxStep, "equality", counted)
    return calls


def test_a_bound_active_box_qp_is_solved_in_the_core_with_the_same_answer(monkeypatch):
    """An index pulling every joint beyond its upper limit: the unconstrained step leaves the box and the core
    solves the box QP itself (qp.py's active-set guesses, as the Python iteration does first) where the Python
    iteration calls it, with the Python iteration's answer, on limits. (Before the core had the box QP, each such
    step was handed back to the Python iteration.)"""
    r = robot("panda", "position")  # four dimensions of self-motion: the minimum sits on limits
    rng = np.random.default_rng(7)
    calls = _box_qp_calls(monkeypatch)
    python_calls = core_calls = converged = 0
    for _ in range(3):
        target, q0 = _draw(r, rng)
        index = JointDeviation(r.upper + 1.0, np.ones(r.nq))
        n0 = len(calls)
        py = solve_ik(r, target, index, q0=q0, bounds=True, backend="python")
        n1 = len(calls)
        _, cc, counts = _same(r, target, index, q0, bounds=True)
        python_calls += n1 - n0
        core_calls += len(calls) - 2 * n1 + n0  # _same's Python solve calls it n1 - n0 times again
        if cc.converged:
            converged += 1
            _check_answer(r, target, index, cc, True)  # with the limits that hold (Eq. D.30)
            assert counts.get("converged", 0) == 1 and py.converged
            assert np.any(cc.q >= r.upper - 1e-9)  # a limit holds at the answer
    assert python_calls >= 3 and core_calls < python_calls and converged >= 1


def test_a_plan_takes_its_box_steps_in_the_core(monkeypatch):
    """kr.plan on the Panda benchmark circle (its samples' IK with bounds): the same joint path with the compiled
    IK as with the Python one, and the core takes the box steps of the Newton iteration itself, both where the
    guesses solve the box QP and where its equality form is infeasible (certified in the core, then the box least
    squares): it hands back a small fraction of the steps that call the Python iteration's box QP."""
    robot_, path, index, _ = panda_circle()
    calls = _box_qp_calls(monkeypatch)
    runs = {}
    for backend in ("python", "auto"):
        monkeypatch.setenv("KINREDUND_BACKEND", backend)
        n0, before = len(calls), dict(compiled.COUNTS)
        result = plan(robot_, path, index, samples=8)
        runs[backend] = (result, len(calls) - n0, compiled.COUNTS.get("box_qp", 0) - before.get("box_qp", 0),
                         sum(compiled.COUNTS.values()) - sum(before.values()))
    (py, py_calls, _, _), (cc, cc_calls, handed, core_runs) = runs["python"], runs["auto"]
    assert py.ok and cc.ok and core_runs > 0  # the core ran (CI builds it)
    np.testing.assert_allclose(cc.trajectory.q, py.trajectory.q, rtol=0.0, atol=Q_BAR)
    # the Python iteration's box QP calls left: those handed back, and the follow stage's (a blended index, Python's)
    assert py_calls >= 20 and handed <= 0.1 * py_calls and cc_calls <= 0.3 * py_calls


def test_random_bounded_solves_agree_on_both_backends():
    """1,000 random bounded solves per arm (Panda, xArm7; kinredund.problems.near_seed_ik_problems: seeds 0.3 rad
    (sd) from a configuration reaching the target, three indices, two pulling joints onto their limits): every solve
    that converges on one backend converges on the other at the same q to 1e-9 rad, and a start that fails on both
    fails for the same cause. A box QP the core hands back (its guesses failed) is solved again by the Python
    iteration at a point a rounding away, where the guesses may pass, and the Python backend may meet it the other
    way round: proxsuite's answer, polished, is the guesses' step to rounding (kinredund.ik.qp). Without polishing,
    a Panda solve here converged on one backend and stopped at max_iter on the other."""
    for name in ("panda", "xarm7"):
        r = robot(name)
        converged = 0
        for k, (target, q0, index) in enumerate(near_seed_ik_problems(r, 1000, seed=2028)):
            py, cc = (solve_ik(r, target, index, q0=q0, bounds=True, tol=1e-8, backend=b)
                      for b in ("python", "compiled"))
            assert cc.converged == py.converged, (name, k, py.reason, cc.reason)
            if py.converged:
                converged += 1
                assert np.abs(cc.q - py.q).max() <= 1e-9, (name, k)
            else:
                assert cc.cause == py.cause, (name, k, py.reason, cc.reason)
        assert converged >= 950  # nearby seeds: nearly all converge


def test_stops_that_are_not_convergence_are_the_python_iterations():
    """max_iter and an unreachable target: handed back, with the Python iteration's reasons and counts."""
    r = robot("panda", "position")
    index = minimum_norm(r.nq)
    _, cc, counts = _same(r, np.array([3.0, 0.0, 0.5]), index, r.home)  # beyond the reach
    assert not cc.converged and counts.get("converged", 0) == 0
    target, q0 = _draw(r, np.random.default_rng(3))
    _, cc, counts = _same(r, target, index, q0, max_iter=1)
    assert not cc.converged and counts["max_iter"] == 1


def test_multi_start_picks_the_same_start():
    r = robot("planar3r")
    _same(r, np.array([2.5, 1.5]), minimum_norm(3), r.home, starts=6, seed=4)


def test_the_core_runs_the_constrained_iteration_where_it_is_expected():
    """In CI (which builds the core) and wherever it loads, backend auto runs the iteration in C++: fails where
    the Python iteration ran instead."""
    r = robot("panda")
    target, q0 = _draw(r, np.random.default_rng(1))
    before = sum(compiled.COUNTS.values())
    with warnings.catch_warnings():
        warnings.simplefilter("error", compiled.IKBackendWarning)
        res = solve_ik(r, target, mid_range(r.lower, r.upper), q0=q0, backend="auto")
    assert res.converged and sum(compiled.COUNTS.values()) == before + 1


def test_backend_options(monkeypatch):
    monkeypatch.delenv("KINREDUND_BACKEND", raising=False)
    r = robot("panda")
    target, q0 = _draw(r, np.random.default_rng(2))
    custom = CustomIndex(lambda q: 0.5 * float(q @ q), lambda q: q.copy(), lambda q: np.eye(r.nq))
    with pytest.raises(OptionError, match="CustomIndex"):
        solve_ik(r, target, custom, q0=q0, backend="compiled")
    with pytest.raises(ChoiceError):
        solve_ik(r, target, minimum_norm(r.nq), q0=q0, backend="fast")
    before = sum(compiled.COUNTS.values())
    solve_ik(r, target, custom, q0=q0)  # auto: an index the core does not know runs in Python
    solve_ik(r, target, None, q0=q0, backend="compiled")  # pose-only: Python's under every backend
    monkeypatch.setenv("KINREDUND_BACKEND", "python")
    solve_ik(r, target, minimum_norm(r.nq), q0=q0)
    assert sum(compiled.COUNTS.values()) == before
    monkeypatch.setenv("KINREDUND_BACKEND", "compiled")  # a whole program's (a plan's blended index among it)
    assert solve_ik(r, target, custom, q0=q0).converged  # the index the core does not know: Python's, no error
    assert sum(compiled.COUNTS.values()) == before
    solve_ik(r, target, minimum_norm(r.nq), q0=q0)
    assert sum(compiled.COUNTS.values()) == before + 1
    with pytest.raises(OptionError, match="CustomIndex"):  # the caller's own "compiled" still insists
        solve_ik(r, target, custom, q0=q0, backend="compiled")


@pytest.mark.parametrize("name,task", [("panda", None), ("xarm7", None), ("panda", "position")])
def test_far_seeds_with_bounds(name, task):
    """Seeds far from the target: restoration steps (their box least squares in C++ where the active-set guess
    solves it, else Python's), stalls and multi-start, all with the Python iteration's results."""
    r = robot(name, task)
    rng = np.random.default_rng(11)
    for _ in range(3):
        target, q0 = _draw(r, rng, spread=1.5)
        _same(r, target, mid_range(r.lower, r.upper), q0, bounds=True, starts=2, seed=1)
