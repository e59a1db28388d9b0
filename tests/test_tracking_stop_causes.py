"""Stops among obstacles named by what happened, not by a corrector iterate's words, and naming the pair.

A branch of the held optimum that ends unannounced inside the sub-step floor is named by where it ends. Named case
``kinova_ball`` (a draw of tests/test_clearance_property.py's generator on the Kinova arm, an arm that
test never draws; pinned here): a 4.4 cm circle at 0.1 m/s, z = 1/2 ||q - q_home||^2, a 4 cm ball beside the
upper arm held 2 cm off. The ball's row is met at t = 0.23 s and held; at t ~ 0.75678 s the ball's witness point on
j2s6s200_link_2's hull passes onto another feature, the distance's curvature jumps (its row is continuously
differentiable, not twice), and the reduced Hessian's eigenvalue with the row's curvature jumps from 1.31 to about
0.03, then runs to zero at t ~ 0.75695 s: a fold, 0.35 ms after the last sub-step point, inside the floor's
sub-step (0.44 ms). The watch, which extrapolates smooth quantities, saw nothing coming; the corrector's iterates
past the fold diverged, and the stop was named after their singular R ("kinematic (J rank-deficient)
singularity", with sigma_min(J) 0.23 at the last good point).

The step control now follows the branch toward the failed time by bisection and names the stop by what fell by
its end (:func:`~kinredund.tracking.failure.branch_end`). Checked independently with the
joint-level IK with rows (:func:`~kinredund.ik.rows.solve_ik_rows`, its own reduced Hessian with the rows'
curvature): continued in small steps it finds the branch up to the reported end and its eigenvalue near zero
there, and just beyond it no optimum near the branch.

A row the redundancy cannot move is named as such. Named case ``ur5_axis_ball``: the UR5 with the tool-axis task
(n - m = 1: the redundancy is the tool's spin, joint 6 alone) on test_tracking_axis's circle, a 3.1 cm ball where
the wrist_1 link passes. When its row is met, [J; G] is singular while J is not (LICQ fails: joint 6 does not move
wrist_1): the stop said "kinematic (J rank-deficient) singularity"; it now says the constraints are dependent and
names the pair. Checked independently: the row's gradient on the null space of the task's Jacobian (central
differences of the tool's position and axis) vanishes at the last good point.

The same seen coming by the watch. Named case ``panda_axis_ball``: the Panda with the tool-axis task (n - m = 2) on
the same circle, a 5.1 cm ball where panda_link3 passes. Held, the smallest singular value of the watched Jacobian
(J with the active row's gradient below) runs to zero at t ~ 2.5157 s while J's own stays 0.23: the stop was
``kinematic_singularity``; it is now ``not_strongly_stable`` (the constraints become dependent), the pair named.
Checked independently: [J; G] from central differences of the tool's position and axis and the pair's gradient
loses rank toward the stop while J does not.

No saddle point recorded after a switch. Named case ``panda_switch_saddle`` (tests/test_clearance_property.py's
draw 213 on the Panda, pinned): a 7.1 cm ball held off panda_link6; within one step (100 a loop) panda_link7's row
is reached too at t = 0.320998 s. The switch's single prediction to the step's end (0.036 s from a kink of the path
of optima) landed 0.15 rad away on a saddle of the held problem (reduced Hessian -1.8), and it was recorded
(solve_ik_rows's check rejects it). The step's end is now measured exactly after its switches, and where it is no
strict minimum the path is followed again from the switch in checked pieces: on the true path both rows stay held
with positive multipliers (eigenvalue 0.4-1.1), and the run goes on until the path runs into the ball (the path
itself passes 3.5 cm inside it later), every recorded point a strict minimum.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
from conftest import robot
from test_clearance_property import CLEARANCE, SELF_CLEARANCE, margin
from test_tracking_axis import _case as axis_case

import kinredund as kr
from kinredund.errors import TrackingError
from kinredund.ik.rows import solve_ik_rows
from kinredund.indices import JointDeviation
from kinredund.paths import Circle

CIRCLE = dict(center=[0.059089045851722755, -0.10002163787536182, 0.4133806568786667], radius=0.04439334334678957,
              normal=(0.030957278655572327, 0.817373012511926, -0.5752764599002987),
              axis_x=(-0.9959306416821336, 0.0739625289803582, 0.05149467220444464))
Q0 = [-0.059578603642609286, 2.1596568037327315, 1.0074187801146517, 0.0027506322846885933, 4.506508909817697,
      0.428276363788403]
BALL = ([-0.13692999954042664, 0.36382399249722086, 0.4661864761637927], 0.039823458193293484)


@functools.cache
def stop():
    r = robot("kinova", "position")
    path = Circle(np.array(CIRCLE["center"]), CIRCLE["radius"], 0.1, normal=CIRCLE["normal"],
                  axis_x=CIRCLE["axis_x"])
    sc = kr.Scene(r)
    sc.add_sphere("ball", BALL[1], BALL[0])
    index = JointDeviation(r.home.copy())
    with pytest.raises(TrackingError) as info:
        kr.track(r, path, index, np.array(Q0), loops=1, steps_per_loop=100, scene=sc, clearance=CLEARANCE,
                 self_clearance=SELF_CLEARANCE)
    return r, path, index, sc, info.value


def _ik(r, path, index, rows, t, q):
    return solve_ik_rows(r, path(t).p, index, rows, q, tol=1e-12)


def test_the_stop_is_named_a_fold_where_the_branch_ends():
    r, path, index, sc, err = stop()
    assert err.cause == "collision" and err.watched["underlying_cause"] == "fold", str(err)
    assert "kinematic" not in str(err)  # the diverged iterates' words are not the cause
    t_sub, t_end = err.watched["substep_t"], err.watched["branch_end_t"]
    assert t_sub < t_end < err.watched["t_failed"]
    q_end = np.array(err.watched["branch_end_q"])  # a good point: on the path, clear, inside the limits
    assert np.linalg.norm(r.fk(q_end)[:3, 3] - path(t_end).p) <= 1e-10
    assert margin(sc, q_end) >= -1e-9  # each pair against its own clearance
    assert np.all(q_end >= r.lower - 1e-10) and np.all(q_end <= r.upper + 1e-10)


def test_the_branch_end_agrees_with_the_joint_level_ik():
    """Continued from the last sub-step point in 1e-5 s steps, the IK with rows stays on the branch (each move under
    1e-3 rad: the branch's other side is 8.5e-3 rad away) up to 1e-6 s before the reported end, where its reduced
    Hessian's least eigenvalue has fallen under 1e-2 (1.0 at the start; at a fold it goes as the square root of the
    time left) and its joints are within 1e-3 rad of the reported end's; 2e-6 s past the end it finds no optimum
    within 1e-3 rad of the branch (it fails, or lands on the other branch)."""
    r, path, index, sc, err = stop()
    rows = [kr.SceneClearance(sc, CLEARANCE, SELF_CLEARANCE)]
    t_sub, t_end = err.watched["substep_t"], err.watched["branch_end_t"]
    q = np.array(err.watched["substep_q"])
    first = _ik(r, path, index, rows, t_sub, q)
    assert first.converged and first.reduced_hessian_min_eig > 0.9
    for t in [*np.arange(t_sub + 1e-5, t_end - 1e-6, 1e-5), t_end - 1e-6]:
        res = _ik(r, path, index, rows, t, q)
        assert res.converged and np.linalg.norm(res.q - q) <= 1e-3, t
        q = res.q
    assert res.reduced_hessian_min_eig < 1e-2
    assert np.linalg.norm(q - np.array(err.watched["branch_end_q"])) <= 1e-3
    beyond = _ik(r, path, index, rows, t_end + 2e-6, q)
    assert not beyond.converged or np.linalg.norm(beyond.q - q) > 1e-3


def _axis_jacobian(r, q, h=1e-6):
    """The tool-axis task's Jacobian (position and axis, 6 rows of rank 5) by central differences."""
    def task(x):
        T = r.fk(x)
        return np.concatenate([T[:3, 3], T[:3, 2]])
    return np.column_stack([(task(q + h * e) - task(q - h * e)) / (2 * h) for e in np.eye(len(q))])


#: the ball of ``ur5_axis_ball``: center [m], radius [m]
UR5_BALL = ([0.3052264560843312, 0.2987061378748938, 0.43822667631077344], 0.030826773397292048)


def axis_ball_stop(name: str, ball):
    """(robot, path, the scene, the stop) of test_tracking_axis's circle on ``name`` with a ball (center [m], radius
    [m]) in the way, held at the default clearances; the stop is a collision whose underlying cause is
    not_strongly_stable (the constraints dependent)."""
    r, path, index, q0 = axis_case(name)
    sc = kr.Scene(r)
    sc.add_sphere("ball", ball[1], ball[0])
    with pytest.raises(TrackingError) as info:
        kr.track(r, path, index, q0, loops=1, scene=sc)
    err = info.value
    assert err.cause == "collision" and err.watched["underlying_cause"] == "not_strongly_stable", str(err)
    return r, path, sc, err


def test_a_row_the_redundancy_cannot_move_is_named_dependent():
    r, path, sc, err = axis_ball_stop("ur5", UR5_BALL)
    assert "dependent constraints" in str(err) and "kinematic" not in str(err)
    pair = "wrist_1_link_0 and ball kept 0.02 m apart"
    assert err.watched["constraints"] == [pair] and pair in str(err)
    q = np.asarray(err.q, float)
    assert margin(sc, q) >= -1e-9 and np.linalg.norm(r.fk(q)[:3, 3] - path(err.t).p) <= 1e-10
    _, sv, Vt = np.linalg.svd(_axis_jacobian(r, q))  # independently: the task's Jacobian and its null space
    assert sv[4] > 0.1 and sv[5] < 1e-8  # rank 5: one redundant direction
    c = kr.SceneClearance(sc, CLEARANCE, SELF_CLEARANCE)
    k = c.names().index(pair)
    G = c.gradients(q)[k]
    assert np.linalg.norm(G) > 0.1 and abs(G @ Vt[5]) <= 1e-8 * np.linalg.norm(G)


#: the ball of ``panda_axis_ball``: center [m], radius [m]
PANDA_BALL = ([-0.3229500137438989, -0.012906303399802612, 0.4955021017608718], 0.050936807120492436)


def test_rows_becoming_dependent_on_the_task_are_named_so():
    r, path, sc, err = axis_ball_stop("panda", PANDA_BALL)
    pair = "panda_link3_0 and ball kept 0.02 m apart"
    assert "constraints become dependent" in str(err) and pair in str(err)
    c = kr.SceneClearance(sc, CLEARANCE, SELF_CLEARANCE)
    k = c.names().index(pair)
    q_good, q_near = np.asarray(err.q, float), np.array(err.watched["substep_q"])
    assert margin(sc, q_near) >= -1e-9 and abs(c.values(q_near)[k]) <= 1e-9  # held on the row, clear

    def least(q):  # [J; G] restricted to the row space of J (rank 5): its 6th singular value, and J's 5th
        Jt = _axis_jacobian(r, q)
        U, sv, Vt = np.linalg.svd(Jt)
        A = np.vstack([Vt[:5] * sv[:5, None], c.gradients(q)[k]])
        return np.linalg.svd(A, compute_uv=False)[-1], sv[4]

    (a_good, j_good), (a_near, j_near) = least(q_good), least(q_near)
    assert j_near > 0.1 and j_good > 0.1  # J regular
    # the row falls into J's row space toward the stop: 0.0098 -> 0.0019 against J's 0.23 (measured)
    assert a_near < 0.02 * j_near and a_near < 0.5 * a_good


#: ``panda_switch_saddle``: the circle (center, radius, normal, axis_x), the start and the ball (center, radius)
SADDLE_CIRCLE = ([0.23604045233690363, -0.21129461260899526, 0.37644072455980765], 0.09465158713899309,
                 (-0.33669385474093894, 0.470606307765529, 0.8155776794830667),
                 (-0.018419664036611556, 0.8626909742257547, -0.5053958834084391))
SADDLE_Q0 = [-0.24517045397756196, -0.5004210750298848, -0.24946301595196108, -2.754235153209326,
             -0.10263901554396951, 1.5403650948045484, 0.785]
SADDLE_BALL = ([0.1732207126001722, -0.2795524449373935, 0.4332241375014671], 0.07096232423881145)


@pytest.mark.parametrize("backend", ["compiled", "python"])
def test_no_saddle_point_is_recorded_after_a_switch(backend):
    r = robot("panda", "position")
    center, radius, normal, axis_x = SADDLE_CIRCLE
    path = Circle(np.array(center), radius, 0.1, normal=normal, axis_x=axis_x)
    index = JointDeviation(r.home.copy())
    sc = kr.Scene(r)
    sc.add_sphere("ball", SADDLE_BALL[1], SADDLE_BALL[0])
    with pytest.raises(TrackingError) as info:
        kr.track(r, path, index, np.array(SADDLE_Q0), loops=1, steps_per_loop=100, scene=sc, clearance=CLEARANCE,
                 self_clearance=SELF_CLEARANCE, backend=backend)
    err = info.value
    assert err.cause == "collision" and "panda_link7_0 and ball" in str(err), str(err)
    rows = [kr.SceneClearance(sc, CLEARANCE, SELF_CLEARANCE)]
    tr = err.partial
    both = [k for k, a in enumerate(tr.meta["constraints"]["active"]) if len(a) == 2]
    assert tr.t[both[0]] < 0.357 < err.t  # past the step that recorded the saddle, both rows held
    for t, q in zip(tr.t, tr.q, strict=True):  # every recorded point a strict minimum, independently
        res = solve_ik_rows(r, path(t).p, index, rows, q, tol=1e-12)
        assert res.converged and res.reduced_hessian_min_eig > 0.5 and np.linalg.norm(res.q - q) <= 1e-9, t


@pytest.mark.parametrize("seed", range(6))
def test_the_inertia_of_r_tells_an_indefinite_reduced_hessian(seed):
    """StepControl._indefinite reads sign(det R) off R's LU factors (dgetrf, as the stepper keeps them): R =
    [[M_F, A_F^T], [A_F, 0]] on the free joints, A = [J; G_A] of full row rank. Checked against the eigenvalues of
    Z^T M_F Z (Z an SVD null basis of A_F) on random M with 0, 1 or 2 negative eigenvalues there: it says
    indefinite exactly where their count is odd (det R's sign sees parity: an even count needs the watch's
    measurement, which a crossing's zero triggers on the way)."""
    from types import SimpleNamespace

    from scipy.linalg import lu_factor

    from kinredund.tracking.step_control import StepControl

    rng = np.random.default_rng(seed)
    n, m = 7, int(rng.integers(2, 5))
    fixed = np.zeros(n, bool)
    fixed[rng.choice(n, int(rng.integers(0, 2)), replace=False)] = True
    F = np.flatnonzero(~fixed)
    A = rng.normal(size=(m, len(F)))
    Z = np.linalg.svd(A)[2][m:].T
    for negatives in (0, 1, 2):
        d = rng.uniform(0.5, 2.0, Z.shape[1])
        d[:negatives] *= -1.0
        Q = np.linalg.qr(rng.normal(size=(Z.shape[1],) * 2))[0]
        S = Q @ np.diag(d) @ Q.T  # Z^T M Z with ``negatives`` negative eigenvalues
        Y = np.linalg.svd(A)[2][:m].T  # the row space of A: M's other blocks are anything (Haynsworth's inertia)
        C, E = rng.normal(size=(m, m)), rng.normal(size=(m, Z.shape[1]))
        M = Z @ S @ Z.T + Y @ (C + C.T) @ Y.T + Y @ E @ Z.T + Z @ E.T @ Y.T
        R = np.block([[M, A.T], [A, np.zeros((m, m))]])
        stub = SimpleNamespace(s=SimpleNamespace(rows=(0,), lu=lu_factor(R), fixed=fixed, n=n))
        assert np.sum(np.linalg.eigvalsh(Z.T @ M @ Z) < 0) == negatives
        assert StepControl._indefinite(stub) == (negatives % 2 == 1), negatives
