"""Chapter 2 and Appendix E: forward kinematics, invariants, closure equations and derivatives."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import ALL_ROBOTS, configurations, robot

from kinredund.kinematics import closure
from kinredund.kinematics.finite_diff import central_difference
from kinredund.kinematics.state import fix_hessian_layout

FD_TOL = 1e-7


def _well_conditioned(r, qs):
    """Drop configurations near a singularity of K (finite differences stay valid, but keep clear)."""
    keep = []
    for q in qs:
        s = np.linalg.svd(r.velocity_jacobian(q), compute_uv=False)
        if s[min(r.nq, 6) - 1 - (4 if r.task == "planar" else 0)] > 1e-3:
            keep.append(q)
    return keep or qs


@pytest.mark.parametrize("name", ALL_ROBOTS)
def test_velocity_jacobian_matches_finite_differences_of_pose(name):
    r = robot(name)
    for q in _well_conditioned(r, configurations(r, seed=1)):
        K = r.velocity_jacobian(q)
        R0 = r.fk(q)[:3, :3]
        # angular rows: omega_k from dQ/dtheta_k Q^T = [omega_k]x
        dT = central_difference(lambda x: r.fk(x), q)
        for k in range(r.nq):
            W = dT[:3, :3, k] @ R0.T
            omega = np.array([W[2, 1], W[0, 2], W[1, 0]])
            assert np.allclose(omega, K[:3, k], atol=FD_TOL)
            assert np.allclose(dT[:3, 3, k], K[3:, k], atol=FD_TOL)
        assert np.allclose(r.position_jacobian(q), K[3:])


@pytest.mark.parametrize("name", ALL_ROBOTS)
def test_dK_matches_finite_differences(name):
    r = robot(name)
    for q in configurations(r, seed=2):
        fd = central_difference(r.velocity_jacobian, q)
        assert np.abs(r.velocity_jacobian_derivative(q) - fd).max() < FD_TOL


@pytest.mark.parametrize("name", ALL_ROBOTS)
def test_pinocchio_tensor_equals_appendix_e_closed_form(name):
    r = robot(name)
    for q in configurations(r, seed=3):
        K = r.velocity_jacobian(q)
        dK = r.velocity_jacobian_derivative(q)
        assert np.abs(closure.appendix_e_tensor(K, r.revolute) - dK).max() < 1e-12


def test_hessian_layout_fix_is_needed():
    """eigenpy issue #557: without the fix the raw tensor is wrong by O(1); if eigenpy changes, this fails."""
    import pinocchio as pin

    r = robot("panda")
    q = configurations(r, seed=4)[0]
    kin = r.kinematics
    pin.computeJointJacobians(kin.model, kin.data, q)
    pin.computeJointKinematicHessians(kin.model, kin.data)
    raw = np.array(pin.getFrameKinematicHessian(kin.model, kin.data, kin.frame_id, pin.LOCAL_WORLD_ALIGNED))
    fixed = fix_hessian_layout(raw)
    fd = central_difference(
        lambda x: pin.computeFrameJacobian(kin.model, kin.data, x, kin.frame_id, pin.LOCAL_WORLD_ALIGNED), q
    )
    assert np.abs(fixed - fd).max() < FD_TOL
    assert np.abs(raw - fd).max() > 1e-2


def _closure_fn(r, q0):
    Q_d, p_d = r.kinematics.pose(q0)
    return lambda x: closure.closure_vector(*r.kinematics.pose(x), Q_d, p_d)


@pytest.mark.parametrize("name", ALL_ROBOTS)
def test_closure_vanishes_at_fk_and_J_is_its_jacobian(name):
    r = robot(name)
    for q in configurations(r, seed=5):
        g = _closure_fn(r, q)
        assert np.abs(g(q)).max() < 1e-14
        Q, p, K = r.kinematics.jacobian(q)
        J = closure.displacement_jacobian(Q, K)
        assert J.shape == (7, r.nq)
        assert np.abs(J - central_difference(g, q)).max() < FD_TOL
        assert np.abs(closure.closure_matrix(Q) @ K - J).max() < 1e-14  # J = H K, Eqs. (2.14)-(2.15)


@pytest.mark.parametrize("name", ALL_ROBOTS)
def test_dJ_and_lambda_matrices(name):
    r = robot(name)
    rng = np.random.default_rng(6)

    def J_of(x):
        Q, _, K = r.kinematics.jacobian(x)
        return closure.displacement_jacobian(Q, K)

    for q in configurations(r, seed=6):
        Q, p, K, dK = r.kinematics.jacobian_derivative(q)
        dJ = closure.displacement_jacobian_derivative(Q, K, dK)
        assert np.abs(dJ - central_difference(J_of, q)).max() < FD_TOL
        lam = rng.normal(size=7)
        Lam = closure.contract(lam, dJ)
        assert np.abs(Lam - central_difference(lambda x, lam=lam: J_of(x).T @ lam, q)).max() < FD_TOL
        # Lambda is the Hessian of lam . g: symmetric (Eq. 4.26)
        assert np.abs(Lam - Lam.T).max() < 1e-12
        lam_star = rng.normal(size=6)
        Lam_star = closure.contract(lam_star, dK)
        fd = central_difference(lambda x, ls=lam_star: r.velocity_jacobian(x).T @ ls, q)
        assert np.abs(Lam_star - fd).max() < FD_TOL


@pytest.mark.parametrize("name", ALL_ROBOTS)
def test_fused_lambda_star_matches_finite_differences(name):
    """Kinematics.lambda_star reads Pinocchio's buffer directly (layout of eigenpy #557): d(K^T lam*)/dtheta."""
    r = robot(name)
    rng = np.random.default_rng(12)
    for q in configurations(r, seed=12):
        lam_star = rng.normal(size=6)
        Q, p, K, L = r.kinematics.lambda_star(q, lam_star)
        fd = central_difference(lambda x, ls=lam_star: r.velocity_jacobian(x).T @ ls, q)
        assert np.abs(L - fd).max() < FD_TOL
        assert np.abs(K - r.velocity_jacobian(q)).max() < 1e-14 and np.abs(r.fk(q)[:3, 3] - p).max() < 1e-14


@pytest.mark.parametrize("name", ALL_ROBOTS)
def test_hessian_contraction_matches_the_tensor_and_the_fused_lambda(name):
    """HessianContraction.contract (flat mat-vec) = lam . dK of its tensor; displacement_lambda = lam . dJ."""
    r = robot(name)
    rng = np.random.default_rng(13)
    for q in configurations(r, seed=13):
        Q, p, K, dk = r.kinematics.jacobian_hessian(q)
        dK = dk.tensor()  # checked against finite differences in test_dK_matches_finite_differences
        mu = rng.normal(size=6)
        assert np.abs(dk.contract(mu) - closure.contract(mu, dK)).max() < 1e-13
        lam = rng.normal(size=7)  # all seven closure rows, the trace row included
        dJ = closure.displacement_jacobian_derivative(Q, K, dK)
        L = closure.displacement_lambda(Q, K, lam, dk.contract)
        assert np.abs(L - closure.contract(lam, dJ)).max() < 1e-12
        assert np.abs(L - L.T).max() < 1e-12  # Lambda is a Hessian (Eq. 4.26)


@pytest.mark.parametrize("name", ["puma7", "cybotech_p15", "panda", "xarm7"])
def test_lambda_star_is_not_symmetric_for_spatial_arms(name):
    """K is not the Jacobian of any function (Section 4.2): Lambda* = d(K^T lam*)/dtheta is not symmetric."""
    r = robot(name)
    q = configurations(r, seed=7)[0]
    lam_star = np.random.default_rng(7).normal(size=6)
    L = closure.contract(lam_star, r.velocity_jacobian_derivative(q))
    assert np.abs(L - L.T).max() > 1e-3


def test_invariants_round_trip_and_identity():
    rng = np.random.default_rng(8)
    for _ in range(20):
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        phi = rng.uniform(0.0, np.pi)
        Q = closure.rotation_from_invariants(u, phi)
        assert np.allclose(Q @ Q.T, np.eye(3), atol=1e-14) and np.isclose(np.linalg.det(Q), 1.0)
        q = closure.vect(Q)
        assert np.allclose(q, u * np.sin(phi), atol=1e-14)  # Eq. (2.6)
        assert np.isclose((np.trace(Q) - 1) / 2, np.cos(phi))  # Eq. (2.7)
        assert np.isclose(q @ q + (np.trace(Q) - 1) ** 2 / 4, 1.0)  # Eq. (2.10)
        u2, phi2 = closure.natural_invariants(Q)
        assert np.allclose(closure.rotation_from_invariants(u2, phi2), Q, atol=1e-12)
        e = closure.euler_parameters(Q)
        assert np.isclose(e @ e, 1.0) and np.isclose(e[3], np.sqrt((1 + np.cos(phi)) / 2))  # Eq. (2.12)
    # phi = pi: vect vanishes, the axis comes from the symmetric part
    u = np.array([0.0, 0.6, 0.8])
    u2, phi2 = closure.natural_invariants(closure.rotation_from_invariants(u, np.pi))
    assert np.isclose(phi2, np.pi) and np.isclose(abs(u2 @ u), 1.0)


@pytest.mark.parametrize("name", ["planar3r", "planar3r_ch6", "puma7", "cybotech_p15"])
def test_shipped_models_follow_the_hd_product(name):
    r = robot(name)
    for q in configurations(r, seed=9):
        assert np.abs(r.fk(q) - r.hd.fk(q)).max() < 1e-12
