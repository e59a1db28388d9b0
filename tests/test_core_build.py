"""The compiled core (kinredund._core, issue 28) is built and loads; its kinematics equal Pinocchio's from Python.

In CI (CI=true) the core must be there: a fresh clone that silently lost its compiled core fails here.
"""

import os

import numpy as np
import pinocchio as pin
import pytest

import kinredund as kr

if not os.environ.get("CI"):  # outside CI a machine without the core runs the Python stepper
    pytest.importorskip("kinredund._core")



def _core():
    from kinredund import _core  # in CI an ImportError here fails the test: no silent fallback

    return _core


def test_core_is_built_against_the_running_pinocchio():
    assert _core().pinocchio_version.split(".")[:2] == pin.__version__.split(".")[:2]


@pytest.mark.parametrize("name", ["panda", "ur5", "kinova"])
def test_core_kinematics_match_pinocchio(name):
    robot = kr.load_robot(name)
    kin = robot.kinematics
    k = _core().Kinematics(kin.model, kin.frame_id)
    q = pin.randomConfiguration(kin.model, np.full(kin.model.nq, -2.0), np.full(kin.model.nq, 2.0))
    T, J, H = k.jacobian_hessian(q)
    pin.computeJointJacobians(kin.model, kin.data, q)
    T0 = pin.updateFramePlacement(kin.model, kin.data, kin.frame_id).homogeneous
    J0 = pin.getFrameJacobian(kin.model, kin.data, kin.frame_id, pin.LOCAL_WORLD_ALIGNED)
    # the Hessian against central differences of J (H[a, i*n + k] = dJ[a, i] / dq_k), round-off of Pinocchio's
    n, h = kin.model.nv, 1e-6
    fd = np.empty((6, n, n))
    for i in range(n):
        e = np.zeros(n)
        e[i] = h
        Jp = pin.computeFrameJacobian(kin.model, kin.data, q + e, kin.frame_id, pin.LOCAL_WORLD_ALIGNED)
        Jm = pin.computeFrameJacobian(kin.model, kin.data, q - e, kin.frame_id, pin.LOCAL_WORLD_ALIGNED)
        fd[:, :, i] = (Jp - Jm) / (2 * h)
    np.testing.assert_allclose(T, T0, atol=1e-14)
    np.testing.assert_allclose(J, J0, atol=1e-14)
    np.testing.assert_allclose(H.reshape(6, n, n), fd, atol=1e-8)  # central differences: O(h^2) + round-off/h
    with pytest.raises(ValueError, match="entries"):
        k.jacobian_hessian(q[:-1])
