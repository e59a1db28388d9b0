"""Chapter 5: the recursive velocity Jacobian (Eqs. 5.1-5.21) against Pinocchio and finite differences."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import SHIPPED, configurations, robot

from kinredund import robot_from_hd
from kinredund.errors import HDTableError, JointVectorError
from kinredund.kinematics.finite_diff import central_difference
from kinredund.kinematics.hd import HDTable
from kinredund.kinematics.recursive import recursive_jacobian, recursive_kinematics, rotation_products


def _random_qs(r, seed, count=20):
    rng = np.random.default_rng(seed)
    return [r.random_configuration(rng) for _ in range(count)]


@pytest.mark.parametrize("name", SHIPPED)
def test_recursive_jacobian_equals_pinocchio(name):
    r = robot(name)
    for q in _random_qs(r, seed=11):
        assert np.abs(recursive_jacobian(r.hd, q) - r.velocity_jacobian(q)).max() < 1e-12


@pytest.mark.parametrize("name", SHIPPED)
def test_recursion_gives_the_pose_and_rotation_products(name):
    r = robot(name)
    for q in _random_qs(r, seed=12, count=5):
        rk = recursive_kinematics(r.hd, q)
        T = r.fk(q)
        assert np.abs(rk.Q - T[:3, :3]).max() < 1e-12
        assert np.abs(rk.p - T[:3, 3]).max() < 1e-12
        # P_i against the plain HD product of Eq. (2.3), one link transform at a time
        prod = np.eye(4)
        P = rotation_products(r.hd, q)
        assert np.array_equal(rk.P[0], np.eye(3)) and np.array_equal(P[0], np.eye(3))
        for i in range(r.nq):
            prod = prod @ r.hd.link_transform(i, q[i])
            assert np.abs(rk.P[i + 1] - prod[:3, :3]).max() < 1e-12
            assert np.abs(P[i + 1] - prod[:3, :3]).max() < 1e-12
        # e_i, the axis of joint i, against Pinocchio's Jacobian: its angular column (revolute) or its
        # linear one (prismatic)
        K = r.velocity_jacobian(q)
        axes = np.where(r.revolute[:, None], K[:3].T, K[3:].T)
        assert np.abs(rk.e - axes).max() < 1e-12


@pytest.mark.parametrize("name", SHIPPED)
def test_r_vectors_point_from_each_joint_origin_to_p(name):
    r = robot(name)
    for q in _random_qs(r, seed=13, count=5):
        rk = recursive_kinematics(r.hd, q)
        origins = r.kinematics.joint_origins(q)  # joint origins O_1..O_n, then P
        assert np.abs(rk.r - (origins[-1] - origins[:-1])).max() < 1e-12


@pytest.mark.parametrize("name", ["puma7", "cybotech_p15"])
def test_recursive_jacobian_matches_finite_differences_without_pinocchio(name):
    """Linear rows: dp/dq of the recursion itself; angular rows: dQ/dq_k Q^T = [omega_k]x."""
    r = robot(name)
    for q in configurations(r, seed=14):
        K = recursive_jacobian(r.hd, q)
        dp = central_difference(lambda x: recursive_kinematics(r.hd, x).p, q)
        assert np.abs(dp - K[3:]).max() < 1e-8
        Q0 = recursive_kinematics(r.hd, q).Q
        dQ = central_difference(lambda x: recursive_kinematics(r.hd, x).Q, q)
        for k in range(r.nq):
            W = dQ[:, :, k] @ Q0.T
            assert np.abs(np.array([W[2, 1], W[0, 2], W[1, 0]]) - K[:3, k]).max() < 1e-8


def test_prismatic_joints_and_offsets_match_pinocchio():
    table = HDTable(
        alpha=[0.5, -1.2, 0.3, 1.1, 0.0], a=[0.1, 0.4, 0.0, 0.25, 0.2], b=[0.3, 0.0, 0.2, -0.1, 0.15],
        kinds="RPRPR", theta0=[0.2, 0.7, -0.4, 0.1, 0.0], name="mixed",
    )
    r = robot_from_hd(table)
    for q in _random_qs(r, seed=15, count=10):
        K = recursive_jacobian(table, q)
        assert np.abs(K - r.velocity_jacobian(q)).max() < 1e-12
        assert np.all(K[:3, [1, 3]] == 0.0)  # prismatic columns: [0; e_i]


@pytest.mark.parametrize("kind", ["R", "P"])
def test_single_joint_tables(kind):
    table = HDTable(alpha=[0.3], a=[0.5], b=[0.2], kinds=kind, name="one")
    r = robot_from_hd(table)
    q = np.array([0.4])
    K = recursive_jacobian(table, q)
    assert K.shape == (6, 1)
    assert np.abs(K - r.velocity_jacobian(q)).max() < 1e-12


def test_bad_input_raises_project_errors():
    r = robot("cybotech_p15")
    with pytest.raises(JointVectorError, match=r"shape \(7,\)"):
        recursive_jacobian(r.hd, np.zeros(6))
    with pytest.raises(JointVectorError, match="non-finite"):
        recursive_jacobian(r.hd, [np.nan] * 7)
    with pytest.raises(HDTableError, match="HDTable"):
        recursive_jacobian(robot("panda").hd, np.zeros(7))  # URDF robot: hd is None
