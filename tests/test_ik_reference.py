"""The bounded IK's minima against the reference numbers of the code before issue 28's speed-up.

The Newton iteration (:mod:`kinredund.ik.newton`) no longer computes the first-order conditions (bound_kkt's
SVD) in iterations that take a restoration step: nothing reads them there. The minima must not move. The
REFERENCE rows were printed by ``solve_ik`` at commit 7642016 (before the change) on random problems on three
arms: the Panda (pose task), the Kinova (tool-axis task) and the P-15 x8 (an HD-table arm, position task):
a within-limits configuration q*, its task target, a random reference of the joint-deviation index and a seed
q* + U(-0.3, 0.3) clipped into the limits (``np.random.default_rng(28)``, as :func:`problems` draws them).
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
#: solve_ik's q at commit 7642016 for the problems of :func:`problems`, per arm in order
REFERENCE = {
    "panda": [
        [1.900290612314112, 0.5279400202688764, 1.9158253087589274, -2.8889859872648285, -2.118400087001955,
         1.8140997833210946, 2.6658775346158192],
        [0.43444484772889586, -0.9364856300802272, -0.5516649308398117, -2.9299414241975104, 0.3477884080450062,
         2.61075943890802, -0.5456669639190841],
        [0.2113400031829526, 0.0786042741747252, -0.4926068584422882, -0.4169353895749473, 1.4415195208635887,
         3.1831600800829345, -2.496368719621195],
        [1.8981064141124555, 0.75339540196256, 2.25692983548682, -2.47817610328424, -1.9982221114266163,
         2.8384999817941274, -0.7312741679016697],
    ],
    "kinova": [
        [2.140473018736419, 4.659909709358406, 3.8125852855764024, -2.6855586509969704, 0.7636164100735298,
         -1.0893324436501988],
        [0.8311810178120487, 2.4294420270961385, 4.845863710453625, -1.6462241124608477, 1.8560473184647799,
         2.802900394469671],
        [3.04345614527608, 3.276435450933589, 5.297213180589986, 0.9221987010867558, 1.2718470804171713,
         3.2384633299332166],
        [2.3164312833758216, 4.49485749649865, 5.8198313143189, -0.34553797869607344, 2.2725749808878124,
         -2.0999218682932765],
    ],
    "cybotech_p15_x8": [
        [3.0194644191788553, 2.272104842343305, 0.7817609810141044, -2.356008509465643, 3.997152637001305,
         3.9802991032462742, -5.3693460578071965],
        [-1.1041064292859795, -1.3889701239120427, 1.1805095108628783, -2.860067345389633, -5.205375450414997,
         -2.0295470755657705, -4.470981765884546],
        [2.228532055104937, 0.3917602028819531, -2.0228721997364056, 1.377657654379651, 6.2271911108296845,
         5.484810232072016, 4.59069378210058],
        [1.3304515757357902, 1.1813803213278786, 2.4003089759211824, -1.4902027141763758, 5.5431985253811105,
         1.8739801882510303, 2.341163975623111],
    ],
}
#: the reduced Hessian (Eq. D.33) at these minima is >= 0.5 and the task Jacobian's least singular value well
#: above 1e-3 (checked below): two points that each meet the residual and normality tests to IK_TOL lie within
#: IK_TOL / 0.5 + IK_TOL / 1e-3 ~ 1e-7 of each other (kind 2 of the tolerance policy)
Q_BAR = 1e-7


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
def test_bounded_minima_match_the_reference(name):
    r = robot(name)
    for (target, index, seed), q_ref in zip(problems(r), REFERENCE[name], strict=True):
        res = solve_ik(r, target, index, q0=seed, bounds=True, max_iter=60)
        assert res.converged, res.reason
        task = task_residual(ik_target(r, target))
        Q, p, K = r.kinematics.jacobian(res.q)
        # the task's residual from a fresh kinematics pass (the pose's closure, the tool axis, the point)
        assert task.residual(Q, p) <= IK_TOL + rounding(float(np.abs(p).max()))
        assert res.reduced_hessian_pd and res.reduced_hessian_min_eig >= 0.5  # the premise of Q_BAR
        G = task.jacobian(K, task.error(Q, p)[1])  # the constraint Jacobian of the iteration
        assert np.linalg.svd(G, compute_uv=False).min() > 1e-3  # the premise of Q_BAR
        assert np.abs(res.q - np.array(q_ref)).max() <= Q_BAR
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
