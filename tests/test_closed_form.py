"""Chapter 3: hybrid closed-form IK of the PUMA-derived 7-axis arm (kinredund.closed_form)."""

from __future__ import annotations

import functools
import json
import math

import numpy as np
import pytest
from conftest import EPS, robot
from scipy.optimize import minimize

import kinredund
from kinredund.closed_form import (
    ArmGeometry,
    ClosedFormIK,
    UnreachableError,
    conditioning,
    isotropic_configuration,
    polynomial_route,
    solve_redundancy,
)
from kinredund.closed_form.polynomial import real_roots, stationary_points
from kinredund.closed_form.positioning import shoulder_branches, theta2_from
from kinredund.closed_form.redundancy import constraint_curve, objective_terms
from kinredund.errors import ChoiceError, HDTableError, JointVectorError, KinredundError, TaskError
from kinredund.kinematics.angles import wrap_joints
from kinredund.kinematics.finite_diff import central_difference
from kinredund.model.catalog import puma7

#: Section 3.2 as printed: the isotropic references [deg] (NOTES.md, Chapter 3)
THESIS_REFERENCES_DEG = (94.08, 97.41)
FK_TOL = 1e-12
#: |g| SLSQP's points may keep on the constraint of Eq. (3.25) [m^2]
SLSQP_FEASIBLE = 1e-10


@functools.cache
def _ik(d: float = 0.0) -> ClosedFormIK:
    r = robot("puma7") if d == 0.0 else kinredund.robot_from_hd(puma7(d))
    return ClosedFormIK(r)


def _geometry(a3: float = math.sqrt(2.0)) -> ArmGeometry:
    return ArmGeometry(b1=2.0, d=0.0, a2=2.0, a3=a3, a4=1.0, alpha7=0.0, theta0=(0.0,) * 7)


def constraint_value(geom: ArmGeometry, rho2: float, theta3: float, theta4: float) -> float:
    """The left-hand side of Eq. (3.25), A + B cos(theta4) + C cos(theta3) + D cos(theta3 + theta4) [m^2]."""
    A, B, C, D = geom.constraint_coefficients(rho2)
    return A + B * math.cos(theta4) + C * math.cos(theta3) + D * math.cos(theta3 + theta4)


def _helix(beta: float) -> np.ndarray:
    return np.array([1.5 * math.cos(beta), 1.5 * math.sin(beta), 3.0 / math.pi * beta + 2.0])


def _random_problems(seed: int, count: int, geom: ArmGeometry):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        rho = rng.uniform(0.1, geom.reach_max - 0.05)
        yield rho * rho, rng.uniform(-math.pi, math.pi, 2)


# -- forward kinematics of every branch ----------------------------------------------------------------
@pytest.mark.parametrize("d", [0.0, 0.3, -0.25])
def test_every_branch_reproduces_the_target_pose(d):
    ik = _ik(d)
    r = ik.robot
    rng = np.random.default_rng(11)
    for _ in range(25):
        T = r.fk(r.random_configuration(rng))
        branches = ik.solve_all(T)
        assert len({b.label for b in branches}) == 4
        for b in branches:
            assert np.abs(r.fk(b.q) - T).max() < FK_TOL
            assert b.fk_residual < FK_TOL
            assert b.within_limits
        # the redundancy depends on xi^2 + eta^2 only: the same (theta3, theta4) on every branch
        assert np.ptp([wrap_joints(b.q[2:4] - branches[0].q[2:4]) for b in branches]) < 1e-12


@pytest.mark.parametrize("d", [0.3, -0.25, 1.2])
def test_theta1_branches_of_eq_3_6_put_the_wrist_in_the_arm_plane(d):
    geom = _ik(d).geometry
    rng = np.random.default_rng(12)
    points = [rng.uniform(-3, 3, 3) for _ in range(30)] + [np.array([0.0, 2.0, 1.0]), np.array([2.0, 0.0, 1.0])]
    for p in points:
        x, y, _ = p
        if math.hypot(x, y) < abs(d) * 1.001:
            continue
        branches = shoulder_branches(geom, p)
        assert [b.label for b in branches] == ["front", "back"]
        for b in branches:
            s1, c1 = math.sin(b.theta1), math.cos(b.theta1)
            assert abs(x * s1 - y * c1 - d) < 1e-12  # the arm plane is offset by d from axis 1
            assert abs(np.hypot(*b.foot) - abs(d)) < 1e-12  # O2' on the shoulder circle, Eq. (3.4)
            assert abs(abs(b.xi) - math.sqrt(x * x + y * y - d * d)) < 1e-12


def test_theta2_of_eqs_3_17_to_3_24_closes_the_planar_chain():
    geom = _geometry()
    rng = np.random.default_rng(13)
    for t2, t3, t4 in rng.uniform(-math.pi, math.pi, (50, 3)):
        w = geom.a2 * np.exp(1j * t2) + geom.a3 * np.exp(1j * (t2 + t3)) + geom.a4 * np.exp(1j * (t2 + t3 + t4))
        assert abs(constraint_value(geom, abs(w) ** 2, t3, t4)) < 1e-12  # Eq. (3.25)
        assert abs(wrap_joints(theta2_from(geom, w.real, w.imag, t3, t4) - t2)) < 1e-12


# -- the 2-D problem -------------------------------------------------------------------------------------
@pytest.mark.parametrize("objective", ["angle", "sincos"])
def test_redundancy_solution_satisfies_first_and_second_order_conditions(objective):
    geom = _geometry()
    for rho2, ref in _random_problems(14, 15, geom):
        sol = solve_redundancy(geom, rho2, ref, objective)
        x = np.array([sol.theta3, sol.theta4])
        g = lambda v, r2=rho2: np.array(constraint_value(geom, r2, v[0], v[1]))  # noqa: E731
        z = lambda v, r=ref: np.array(objective_terms(objective, v[0], v[1], *r)[0])  # noqa: E731
        grad_g, grad_z = central_difference(g, x), central_difference(z, x)
        lam = -(grad_g @ grad_z) / (grad_g @ grad_g)  # least squares of Eq. (3.40)
        assert abs(g(x)) < 1e-12
        assert np.abs(grad_z + lam * grad_g).max() < 1e-7  # normality, Eq. (3.36)
        assert abs(lam - sol.multiplier) < 1e-6 * max(1.0, abs(lam))
        assert sol.curvature > 0.0
        # global: no point of a dense sampling of the curve does better
        pts = np.concatenate(constraint_curve(geom, rho2, 4001))
        dev = wrap_joints(pts - ref)
        dense = 0.5 * (dev ** 2).sum(1) if objective == "angle" else 2.0 * (np.sin(0.5 * dev) ** 2).sum(1)
        assert sol.objective <= dense.min() + 1e-12


def test_redundancy_agrees_with_scipy_slsqp_on_the_2d_problem():
    geom = _geometry()
    rng = np.random.default_rng(15)
    for rho2, ref in _random_problems(16, 8, geom):
        sol = solve_redundancy(geom, rho2, ref)
        _, B, C, D = geom.constraint_coefficients(rho2)
        cons = {"type": "eq", "fun": lambda v, r2=rho2: constraint_value(geom, r2, v[0], v[1]),
                "jac": lambda v, B=B, C=C, D=D: np.array([-C * math.sin(v[0]) - D * math.sin(v[0] + v[1]),
                                                          -B * math.sin(v[1]) - D * math.sin(v[0] + v[1])])}
        best = None
        for _ in range(12):
            res = minimize(lambda v, r=ref: 0.5 * float(((v - r) ** 2).sum()), ref + rng.uniform(-3, 3, 2),
                           jac=lambda v, r=ref: v - r, method="SLSQP", constraints=[cons],
                           options={"ftol": 1e-16, "maxiter": 500})
            if res.success and abs(cons["fun"](res.x)) < SLSQP_FEASIBLE and (best is None or res.fun < best.fun):
                best = res
        # SLSQP stops on the change of z, which it resolves only to rounding (ftol=1e-16 < eps): along the
        # curve z grows as curvature/2 * delta^2, so its point is only known to delta = sqrt(2 ROUND_Z / curvature)
        # (observed 6e-16 to 1.4e-9 over these problems, varying with the BLAS kernel), plus the shift
        # SLSQP_FEASIBLE / |grad g| that its allowed constraint violation makes
        x = np.array([sol.theta3, sol.theta4])
        round_z = 8 * EPS * max(1.0, sol.objective)
        bar = math.sqrt(2 * round_z / sol.curvature) + SLSQP_FEASIBLE / np.linalg.norm(cons["jac"](x))
        assert np.abs(best.x - x).max() < bar
        # and the closed form is the global minimum: SLSQP's z is lower only by what its constraint violation
        # buys to first order (|lambda| |g|) and rounding
        assert sol.objective <= best.fun + abs(sol.multiplier) * SLSQP_FEASIBLE + round_z


def test_closed_form_agrees_with_the_joint_level_ik_solver():
    from kinredund.ik.solve import solve_ik
    from kinredund.indices import JointDeviation

    ik = _ik()
    r = ik.robot
    reference = np.zeros(7)
    reference[2:4] = ik.references
    index = JointDeviation(reference, np.array([0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0]))  # Eq. (3.30)
    rng = np.random.default_rng(17)
    for _ in range(3):
        q = r.random_configuration(rng, 0.1)
        T = r.fk(q)
        result = solve_ik(r, T, index, q0=q, starts=6, seed=1)
        assert result.converged
        nearest = min(ik.solve_all(T), key=lambda b: np.abs(wrap_joints(b.q - result.q)).max())
        assert np.abs(wrap_joints(nearest.q - result.q)).max() < 1e-9
        assert abs(nearest.objective - result.objective) < 1e-9


# -- the isotropic references ----------------------------------------------------------------------------
def test_isotropic_references_of_section_3_2():
    iso = isotropic_configuration(_ik().geometry)
    deg = np.degrees([iso.theta3, iso.theta4])
    # exact sqrt(2): within 0.012 deg of the printed values (the thesis rounded a3 to 1.414, below)
    assert np.abs(deg - THESIS_REFERENCES_DEG).max() < 0.012
    # links 2-4 at the references, by Pinocchio: the 3x2 block of the position Jacobian of axes 2-4
    # (the arm plane) has two equal non-zero singular values
    r = _ik().robot
    q = np.array([0.4, -0.7, iso.theta3, iso.theta4, 0.1, 0.2, 0.3])
    sv = np.linalg.svd(r.position_jacobian(q)[:, 1:4], compute_uv=False)
    assert abs(sv[0] - sv[1]) < 1e-12 * sv[0] and sv[2] < 1e-12
    assert abs(sv[0] - iso.sigma) < 1e-12


def test_isotropic_references_with_a3_rounded_as_printed():
    iso = isotropic_configuration(_geometry(a3=1.414))
    assert tuple(np.round(np.degrees([iso.theta3, iso.theta4]), 2)) == THESIS_REFERENCES_DEG


@pytest.mark.parametrize("d", [0.0, 0.3])
def test_default_references_make_links_2_to_4_isotropic(d):
    """The solver's default references, as joint values, put links 2-4 in an isotropic configuration:
    by Pinocchio, the position Jacobian of axes 2-4 has two equal non-zero singular values, wherever
    the other joints are."""
    ik = _ik(d)
    r = ik.robot
    rng = np.random.default_rng(41)
    for _ in range(3):
        q = r.random_configuration(rng, 0.1)
        q[2:4] = ik.references
        sv = np.linalg.svd(r.position_jacobian(q)[:, 1:4], compute_uv=False)
        assert abs(sv[0] - sv[1]) < 1e-12 * sv[0] and sv[2] < 1e-12 * sv[0]


# -- errors ----------------------------------------------------------------------------------------------
def test_unreachable_targets_raise_a_clear_error():
    pose = np.eye(4)
    cases = [
        (0.3, (0.1, 0.1, 3.0), "inner_cylinder", "inner cylinder"),
        (0.0, (5.0, 0.0, 2.0), "outer_reach", "outer reach"),
        (0.3, (0.0, 3.0, 7.0), "outer_reach", "outer reach"),
    ]
    for d, p, reason, words in cases:
        pose[:3, 3] = p
        for call in (lambda p=p, d=d: _ik(d).position_all(p), lambda d=d: _ik(d).solve_all(pose)):
            with pytest.raises(UnreachableError) as info:
                call()
            assert info.value.reason == reason and words in str(info.value)
            assert isinstance(info.value, KinredundError) and isinstance(info.value, ValueError)
    # an arm whose links cannot fold back to the shoulder (a2 > a3 + a4): the inner reach
    table = puma7()
    folded = kinredund.HDTable(alpha=table.alpha, a=[0, 3.0, 1.0, 0.5, 0, 0, 0], b=table.b, name="folded")
    with pytest.raises(UnreachableError, match="inner reach") as info:
        ClosedFormIK(kinredund.robot_from_hd(folded), references=(0.0, 0.0)).position_all((1.0, 0.0, 2.0))
    assert info.value.reason == "inner_reach"


def test_bad_input_raises_errors_of_the_family():
    ik = _ik()
    with pytest.raises(TaskError, match="rotation"):
        ik.solve_all(np.diag([1.0, 2.0, 1.0, 1.0]))
    with pytest.raises(TaskError, match="4x4"):
        ik.solve_all(np.eye(3))
    bottom = np.eye(4)
    bottom[3, :3] = [0.0, 0.1, 0.0]
    with pytest.raises(TaskError, match=r"last row must be \(0, 0, 0, 1\)"):
        ik.solve_all(bottom)
    with pytest.raises(TaskError, match="numeric"):
        ik.solve_all("abc")
    with pytest.raises(TaskError):
        ik.position_all((1.0, np.nan, 2.0))
    with pytest.raises(TaskError, match="wrist-centre position"):
        ik.position_all("abc")
    with pytest.raises(HDTableError, match="Chapter 3 architecture"):
        ClosedFormIK(robot("cybotech_p15"))
    with pytest.raises(ChoiceError, match="objective"):
        ClosedFormIK(ik.robot, objective="cubic")
    with pytest.raises(JointVectorError, match="references"):
        ClosedFormIK(ik.robot, references=(1.0, 2.0, 3.0))
    with pytest.raises(JointVectorError, match="references .* must be numeric"):
        ClosedFormIK(ik.robot, references="ab")
    T = ik.robot.fk(ik.robot.home)
    with pytest.raises(ChoiceError, match="pick"):
        ik.solve(T, pick="best")
    with pytest.raises(JointVectorError, match="q_near"):
        ik.solve(T, pick="nearest")
    with pytest.raises(JointVectorError, match="q_near must be numeric"):
        ik.position((1.0, 0.5, 2.5), pick="nearest", q_near="abc")
    with pytest.raises(JointVectorError, match="q_near must have 4 or 7 joint values"):
        ik.position((1.0, 0.5, 2.5), pick="nearest", q_near=[0.0, 0.0])
    with pytest.raises(JointVectorError, match="q_near must have 7 joint values"):
        ik.solve(T, pick="nearest", q_near=np.zeros(4))
    with pytest.raises(JointVectorError, match="non-finite"):
        ik.solve(T, pick="nearest", q_near=[0.0, np.nan, 0, 0, 0, 0, 0])


# -- the wrist and the picks -----------------------------------------------------------------------------
def test_wrist_singularity_is_detected_and_reported():
    ik = _ik()
    r = ik.robot
    arm = ik.position((1.2, 0.8, 3.1)).q  # the optimal front arm for this wrist centre
    for theta6 in (0.0, math.pi, 1e-10):
        q = np.concatenate([arm, [0.4, theta6, -0.9]])
        T = r.fk(q)
        hint = np.zeros(7)
        hint[4] = 0.4
        branches = ik.solve_all(T, q_hint=hint)
        front = [b for b in branches if b.shoulder == "front"]
        assert all(b.wrist_singular and b.sin_theta6 < 1e-8 for b in front)
        assert len(front) == (2 if theta6 == 1e-10 else 1)
        for b in branches:
            assert np.abs(r.fk(b.q) - T).max() < FK_TOL
        if theta6 != 1e-10:
            assert front[0].wrist == "singular" and abs(front[0].q[4] - 0.4) < 1e-12  # theta5 from the hint
    regular = ik.solve_all(r.fk(np.concatenate([arm, [0.4, 0.8, -0.9]])))
    assert not any(b.wrist_singular for b in regular if b.shoulder == "front")


def test_solve_picks_lowest_and_nearest():
    ik = _ik()
    r = ik.robot
    rng = np.random.default_rng(18)
    T = r.fk(r.random_configuration(rng))
    branches = ik.solve_all(T)
    assert ik.solve(T).label == branches[0].label  # equal objectives: the first in solve_all order
    for b in branches:
        near = b.q + rng.normal(0.0, 1e-3, 7)
        assert ik.solve(T, pick="nearest", q_near=near).label == b.label


# -- the polynomial route --------------------------------------------------------------------------------
@pytest.mark.parametrize("beta", np.linspace(0.0, math.pi / 2, 4))
def test_polynomial_real_roots_contain_the_constrained_minimum(beta):
    ik = _ik()
    geom = ik.geometry
    p = _helix(beta)
    rho2 = (p[0] ** 2 + p[1] ** 2) + (p[2] - geom.b1) ** 2
    refs = ik.references
    minimum = solve_redundancy(geom, rho2, refs, "sincos")  # Eq. (3.31) minimised directly
    route = polynomial_route(geom, rho2, refs)
    assert route.thesis.shape == (25,) and route.thesis[24] != 0.0  # degree 24, Eq. (3.81)
    t_min = math.tan(0.5 * minimum.theta4)
    assert np.abs(real_roots(route.thesis) - t_min).min() < 1e-8 * (1.0 + abs(t_min))
    assert np.abs(real_roots(route.reduced) - t_min).min() < 1e-12 * (1.0 + abs(t_min))
    # every real root of the degree-12 factor is a stationary point; the lowest is the minimum
    values = []
    for t3, t4 in stationary_points(route.system, route.reduced):
        z, z3, z4, _, _ = objective_terms("sincos", t3, t4, *refs)
        g3 = central_difference(lambda v: np.array(constraint_value(geom, rho2, v[0], v[1])), np.array([t3, t4]))
        assert abs(constraint_value(geom, rho2, t3, t4)) < 1e-10
        assert abs(z3 * g3[1] - z4 * g3[0]) < 1e-6  # Eq. (3.47)
        values.append(z)
    assert abs(min(values) - minimum.objective) < 1e-12


def test_thesis_polynomial_is_the_resultant_times_spurious_factors():
    geom = _geometry()
    for rho2, ref in _random_problems(19, 10, geom):
        route = polynomial_route(geom, rho2, ref)
        assert route.factor_residual < 1e-10  # Eq. (3.81) = 256 (E + G t4^2)^4 Res(t4)
        assert route.division_residual < 1e-12  # Res(t4) = (1 + t4^2)^2 R12(t4)


def test_degree_24_route_is_ill_conditioned():
    geom = _geometry()
    rho2 = 1.0
    for theta3_ref_deg in (179.0, 179.9):  # references on the curve, next to where it crosses theta3 = pi
        t3 = math.radians(theta3_ref_deg)
        t4 = _brent_on_curve(geom, rho2, t3)
        minimum = solve_redundancy(geom, rho2, (t3, t4), "sincos")
        assert minimum.objective < 1e-20  # the reference itself
        c = conditioning(polynomial_route(geom, rho2, (t3, t4)), minimum.theta4, eps=1e-12, trials=10)
        assert c.root_condition_24 > 1e3 * c.root_condition_12
        assert c.perturbed_error_24 > 1e2 * c.perturbed_error_12
        assert c.root_error_12 < 1e-12
    # the Section 3.2 case: coefficients spread over many more decades than those of the factor
    p = _helix(0.0)
    route = polynomial_route(geom, p[0] ** 2 + (p[2] - 2.0) ** 2, _ik().references)
    c = conditioning(route, solve_redundancy(geom, 1.5 ** 2, _ik().references, "sincos").theta4)
    assert c.coefficient_spread_24 > 1e3 * c.coefficient_spread_12
    assert c.spurious_cluster_24 > 1e-5  # the quadruple spurious root splits by ~ eps^(1/4)


def _brent_on_curve(geom, rho2, t3):
    from scipy.optimize import brentq

    grid = np.linspace(-math.pi, math.pi, 721)
    vals = [constraint_value(geom, rho2, t3, t) for t in grid]
    k = next(i for i in range(720) if vals[i] * vals[i + 1] < 0)
    return brentq(lambda t: constraint_value(geom, rho2, t3, t), grid[k], grid[k + 1], xtol=1e-16)


# -- Section 3.2 -----------------------------------------------------------------------------------------
def test_section_3_2_helix(tmp_path):
    from kinredund.ui.reproduce import helix as reproduce

    data = reproduce(samples=19, json_path=tmp_path / "h.json", plot_path=tmp_path / "h.png")
    saved = json.loads((tmp_path / "h.json").read_text())
    assert saved["beta"] == data["beta"] and len(saved["q"]) == 19
    assert (tmp_path / "h.png").read_bytes()[:4] == b"\x89PNG"
    r = _ik().robot
    beta = np.array(saved["beta"])
    q = np.array(saved["q"])
    assert np.abs(q[:, 0] - beta).max() < 1e-12  # front branch, d = 0: theta1 = beta
    for b, qi in zip(beta, q, strict=True):
        p = r.fk(np.concatenate([qi, np.zeros(3)]))[:3, 3]
        assert np.abs(p - _helix(b)).max() < FK_TOL
    assert max(saved["normality_residual"]) < 1e-12
    # smooth, no branch switch: no joint moves more per sample than theta1 (= beta)
    assert np.abs(np.diff(q, axis=0)).max() <= np.diff(beta).max() + 1e-12


def test_section_3_2_writes_strict_json_and_checks_its_sample_count(tmp_path, monkeypatch):
    """Non-finite numbers are written as null (strict JSON, no NaN/Infinity tokens); the sample count
    must be an integer >= 2 (19.0 and 1 are refused)."""
    from kinredund.errors import PathError
    from kinredund.thesis import helix_3_2

    monkeypatch.setattr(helix_3_2, "_polynomial_route",
                        lambda *a: {"root_condition_24": [float("inf")], "eps": float("nan")})
    helix_3_2.reproduce(samples=3, json_path=tmp_path / "h.json")

    def refuse(token):
        raise AssertionError(f"non-standard JSON token {token}")

    saved = json.loads((tmp_path / "h.json").read_text(), parse_constant=refuse)
    assert saved["polynomial_route"] == {"root_condition_24": [None], "eps": None}
    for bad in (19.0, 1, "19", True):
        with pytest.raises(PathError, match="integer >= 2"):
            helix_3_2.reproduce(samples=bad)
