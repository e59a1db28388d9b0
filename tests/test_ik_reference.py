"""The bounded IK's minima, checked independently, where restoration iterations skip the first-order conditions.

The Newton iteration (:mod:`kinredund.ik.newton`) no longer computes the first-order conditions (bound_kkt's
SVD) in iterations that take a restoration step: nothing reads them there. Random problems on three arms: the
Panda (pose task), the Kinova (tool-axis task) and the P-15 x8 (an HD-table arm, position task): a
within-limits configuration q*, its task target, a random reference of the joint-deviation index and a seed
q* + U(-0.3, 0.3) clipped into the limits (``np.random.default_rng(28)``, as :func:`problems` draws them);
each answer is checked afresh (the task's residual from a new kinematics pass, the limits, the independent
optimality check of :mod:`kinredund.ik.optimality`).
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import IK_TOL, robot, rounding

from kinredund.ik.optimality import ik_target
from kinredund.ik.solve import check_optimality, solve_ik
from kinredund.indices import JointDeviation
from kinredund.tasks import task_residual

ARMS = ("panda", "kinova", "cybotech_p15_x8")
def problems(r, count: int = 4):
    """(target, index, seed) of the module docstring's random problems on r."""
    lo, hi = r.sample_box(0.0)
    rng = np.random.default_rng(28)
    out = []
    for _ in range(count):
        qs, ref = rng.uniform(lo, hi), rng.uniform(lo, hi)
        seed = np.clip(qs + rng.uniform(-0.3, 0.3, r.nq), lo, hi)
        T = r.fk(qs)
        out.append((T[:3, 3] if r.task == "position" else T, JointDeviation(ref), seed))
    return out


@pytest.mark.parametrize("name", ARMS)
def test_bounded_minima_are_minima(name):
    r = robot(name)
    for target, index, seed in problems(r):
        res = solve_ik(r, target, index, q0=seed, bounds=True, max_iter=60)
        assert res.converged, res.reason
        task = task_residual(ik_target(r, target))
        Q, p, _ = r.kinematics.jacobian(res.q)
        # the task's residual from a fresh kinematics pass (the pose's closure, the tool axis, the point)
        assert task.residual(Q, p) <= IK_TOL + rounding(float(np.abs(p).max()))
        assert res.reduced_hessian_pd and res.reduced_hessian_min_eig > 0.0
        assert np.all(res.q >= r.lower - 1e-12) and np.all(res.q <= r.upper + 1e-12)
        # the independent check (kinredund.ik.optimality, the SVD of [K; held limits]) at the answer: within the
        # solver's bar max(tol, 1e-13 (1 + |grad z|)) plus the rounding of a fresh evaluation
        g = float(np.abs(index.evaluate(res.q)[1]).max())
        opt = check_optimality(r, target, res.q, index, bounds=True)
        assert opt.normality_residual <= max(IK_TOL, 1e-13 * (1.0 + g)) + rounding(g)
        assert opt.reduced_hessian_pd


def test_max_iter_reason_reports_a_finite_normality_residual():
    """A start cut off by max_iter in a restoration step still reports its normality residual (computed at the
    last iteration even though restoration iterations skip it)."""
    r = robot("panda")
    target, index, seed = problems(r, 1)[0]
    far = np.clip(seed + 2.0, r.lower, r.upper)
    res = solve_ik(r, target, index, q0=far, bounds=True, max_iter=1)
    assert not res.converged and res.reason.startswith("max_iter=1 reached")
    assert "normality residual nan" not in res.reason
