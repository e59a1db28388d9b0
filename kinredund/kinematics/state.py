"""The kinematics layer: the one place where Pinocchio's compute-then-get calls happen (Chapter 2).

:class:`Kinematics` owns a ``pin.Data`` workspace for one model and one end-effector frame and returns
plain numpy arrays:

- the end-effector pose (Q, p): rotation matrix Q and the position p of point P [m];
- the velocity Jacobian K of Eq. (2.16), rows [omega; pdot] (the thesis's order; Pinocchio's is
  [v; omega]), taken in world axes at point P;
- its derivative tensor dK[a, i, k] = dK[a, i] / dtheta_k from Pinocchio's kinematic Hessian
  (Eqs. 4.38-4.41 and Appendix E computed by Pinocchio), with the memory-layout fix of eigenpy
  issue #557 (see ``docs/design.md``).

No other module calls ``pinocchio`` compute functions; solvers receive arrays.
"""

from __future__ import annotations

import threading

import numpy as np
import pinocchio as pin

#: Pinocchio's [v; omega] rows reordered into the thesis's [omega; v].
THESIS_ROWS = np.r_[3:6, 0:3]
_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


def fix_hessian_layout(H: np.ndarray) -> np.ndarray:
    """Return Pinocchio's kinematic Hessian with the layout H[a, i, k] = dJ[a, i] / dq_k.

    eigenpy exposes the column-major Eigen tensor with C strides (eigenpy issue #557); reading the
    buffer in C order and reshaping it in Fortran order restores the indices.
    """
    return np.reshape(H.ravel(order="C"), H.shape, order="F")


def _rows(J: np.ndarray, nv: int) -> np.ndarray:
    """[v; omega] -> [omega; v] (THESIS_ROWS); eigenpy returns a one-joint model's 6x1 Jacobian as shape (6,).

    Two slices concatenated: ``take`` (and fancy indexing) release the GIL at every call, however small the array,
    each release a point where another of ``track_many``'s threads takes the GIL and this one then waits for it
    (two threads ran ~5 % faster without it); ``take`` costs ~0.5 us less in one thread.
    """
    J6 = J.reshape(6, nv)
    return np.concatenate((J6[3:], J6[:3]))


class Kinematics:
    """Forward kinematics, the velocity Jacobian and its derivative for one frame of one model.

    Args:
        model: the Pinocchio model (not modified).
        frame_id: the end-effector frame's index in ``model.frames``.

    The methods take a validated joint vector (``Robot.check_q`` validates) and return fresh arrays.
    """

    def __init__(self, model: pin.Model, frame_id: int):
        self.model = model
        self.frame_id = frame_id
        self.data = model.createData()

    def pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """End-effector rotation Q (3x3) and position p (3,) [m]."""
        pin.forwardKinematics(self.model, self.data, q)
        T = pin.updateFramePlacement(self.model, self.data, self.frame_id).homogeneous  # a fresh 4x4 array
        return T[:3, :3], T[:3, 3]

    def jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(Q, p, K): the pose and the velocity Jacobian K of Eq. (2.16), rows [omega; pdot]."""
        J = pin.computeFrameJacobian(self.model, self.data, q, self.frame_id, _LWA)
        T = pin.updateFramePlacement(self.model, self.data, self.frame_id).homogeneous  # a fresh 4x4 array
        return T[:3, :3], T[:3, 3], _rows(J, self.model.nv)  # Eq. (2.16)

    def jacobian_joints(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(Q, p, K) by :meth:`jacobian_hessian`'s passes without the Hessian: its K bit for bit (:meth:`jacobian`'s
        one pass rounds K otherwise in the last bits), for a caller that needs no dK now and the same numbers."""
        model, data, fid = self.model, self.data, self.frame_id
        pin.computeJointJacobians(model, data, q)
        M = pin.updateFramePlacement(model, data, fid)
        T = M.homogeneous  # a fresh 4x4 array
        return T[:3, :3], T[:3, 3], _rows(pin.getFrameJacobian(model, data, fid, _LWA), model.nv)

    def jacobian_derivative(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(Q, p, K, dK) with dK[a, i, k] = dK[a, i]/dtheta_k, the third-rank tensor of Eqs. (4.38)-(4.41)."""
        Q, p, K, dk = self.jacobian_hessian(q)
        return Q, p, K, dk.tensor()

    def jacobian_hessian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, HessianContraction]:
        """(Q, p, K, dk): the pose, K, and dK kept as a :class:`HessianContraction` (no tensor copy).

        The solvers only ever need contractions sum_a mu_a dK[a, i, k] (Eqs. 4.20, 4.42); this saves
        the layout fix and the row reordering of the whole (6, n, n) tensor at every step.
        """
        model, data, fid = self.model, self.data, self.frame_id
        pin.computeJointJacobians(model, data, q)
        M = pin.updateFramePlacement(model, data, fid)
        J = pin.getFrameJacobian(model, data, fid, _LWA)
        pin.computeJointKinematicHessians(model, data)
        H = pin.getFrameKinematicHessian(model, data, fid, _LWA)  # a fresh array (a copy of data's)
        # a fresh 4x4 array: one call instead of two (.rotation, .translation); a Pinocchio call costs
        # ~2 us between numpy calls (cold caches), four times its cost in a tight loop
        T = M.homogeneous
        return T[:3, :3], T[:3, 3], _rows(J, model.nv), HessianContraction(H)

    def lambda_star(self, q: np.ndarray, lam_star: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(Q, p, K, Lambda*) with Lambda* = d(K^T lambda*)/dtheta (Eq. 4.37), lambda* held fixed.

        The same as ``closure.contract(lam_star, jacobian_derivative(q)[3])`` without copying the tensor.
        """
        Q, p, K, dk = self.jacobian_hessian(q)
        return Q, p, K, dk.contract(np.asarray(lam_star, float))  # Eq. (4.42)

    def joint_origins(self, q: np.ndarray) -> np.ndarray:
        """World positions [m] of every joint origin followed by point P, shape (njoints, 3)."""
        pin.forwardKinematics(self.model, self.data, q)
        return self._origins(pin.updateFramePlacement(self.model, self.data, self.frame_id))

    def _origins(self, M) -> np.ndarray:
        """The joint origins in ``data`` (after a forward-kinematics pass) and P at the frame placement M."""
        pts = [self.data.oMi[j].translation.copy() for j in range(1, self.model.njoints)]
        pts.append(M.translation.copy())
        return np.array(pts)

    def jacobian_and_origins(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(K, origins): :meth:`jacobian`'s K (Eq. 2.16) and :meth:`joint_origins` from one kinematics pass."""
        model, data, fid = self.model, self.data, self.frame_id
        pin.computeJointJacobians(model, data, q)  # runs the forward kinematics: data.oMi too
        M = pin.updateFramePlacement(model, data, fid)
        J = pin.getFrameJacobian(model, data, fid, _LWA)
        return _rows(J, model.nv), self._origins(M)


def point_curvature(model: pin.Model, data, joints: np.ndarray, points: np.ndarray, coef: np.ndarray) -> np.ndarray:
    """sum_k coef_k^T Hess p_k (n, n): the second derivatives of material points' positions, contracted.

    p_k is the point of joint ``joints[k]``'s body at world position ``points[k]`` [m] (it moves with that
    body), ``coef[k]`` a 3-vector (e.g. a distance row's normal, with its multiplier). With the body's
    world-frame Jacobian [v; omega] (v the velocity of the body point at the world origin),
    dp/dq_i = v_i + omega_i x p, so

        d2p/dq_i dq_k = dv_i/dq_k + domega_i/dq_k x p + omega_i x (v_k + omega_k x p),

    from Pinocchio's kinematic Hessians (layout fixed as :func:`fix_hessian_layout`). Needs ``data`` after
    ``pin.computeJointJacobians(model, data, q)`` at the q of the points; symmetrised (the exact Hessian is).
    """
    pin.computeJointKinematicHessians(model, data)
    n = model.nv
    H = np.zeros((n, n))
    world = pin.ReferenceFrame.WORLD
    for j in np.unique(joints):
        if j == 0:  # the world: a fixed point
            continue
        mine = np.flatnonzero(joints == j)
        a = coef[mine].sum(axis=0)
        b = np.cross(points[mine], coef[mine]).sum(axis=0)  # sum_k p_k x c_k
        dJ = fix_hessian_layout(pin.getJointKinematicHessian(model, data, int(j), world))  # [a, i, k]
        H += np.tensordot(np.concatenate([a, b]), dJ, axes=(0, 0))  # c.dv_i/dq_k + (p x c).domega_i/dq_k
        J = pin.getJointJacobian(model, data, int(j), world).reshape(6, n)
        v, w = J[:3], J[3:]
        for k in mine:  # c . (omega_i x Jp_k) = omega_i . (Jp_k x c)
            Jp = v + np.cross(w.T, points[k]).T
            H += w.T @ np.cross(Jp.T, coef[k]).T
    return 0.5 * (H + H.T)


class HessianContraction:
    """dK of one configuration in Pinocchio's buffer, contracted on demand: sum_a mu_a dK[a, i, k].

    eigenpy's C-order buffer of the column-major (6, n, n) kinematic Hessian (the layout of eigenpy
    issue #557) holds entry (a, i, k) at a + 6 (i + n k): one matrix-vector product with mu in
    Pinocchio's [v; omega] row order gives the (n, n) contraction (Eqs. 4.20, 4.42).
    """

    __slots__ = ("_H", "_flat", "_n")

    def __init__(self, H: np.ndarray):
        n = H.shape[1]
        # a view: the array eigenpy returns is C-contiguous, so its C-order ravel is its buffer
        self._H, self._flat, self._n = H, H.reshape(n * n, 6), n

    def contract(self, mu: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """sum_a mu_a dK[a, i, k] for mu (6,) in the thesis's [omega; v] order, shape (n, n) (Eq. 4.42).

        With ``rows``, mu holds the multipliers of those rows of K only (a task on some of its rows).
        """
        if rows is not None:
            full = np.zeros(6)
            full[rows] = mu
            mu = full
        return self.contract_pinocchio(mu.take(THESIS_ROWS))

    def contract_pinocchio(self, mu: np.ndarray) -> np.ndarray:
        """:meth:`contract` for mu in Pinocchio's [v; omega] row order (callers that build mu anyway)."""
        n = self._n
        # [i + n k] -> [i, k]: the C-order (k, i) reshape, transposed (a view)
        return (self._flat @ mu).reshape(n, n).T

    def tensor(self) -> np.ndarray:
        """The whole tensor dK[a, i, k] (thesis row order), as :meth:`Kinematics.jacobian_derivative` gives it."""
        return fix_hessian_layout(self._H)[THESIS_ROWS]


class PerThread:
    """:class:`Kinematics` of one model and frame, one per thread, made on first use in each thread.

    A workspace shared between threads would mix their forward-kinematics passes (wrong poses with right
    joint values). It pickles as its model and frame: a thread's workspace is not part of it.
    """

    def __init__(self, model: pin.Model, frame_id: int):
        self.model, self.frame_id = model, frame_id
        self._local = threading.local()

    def get(self) -> Kinematics:
        """This thread's workspace."""
        try:
            return self._local.kinematics
        except AttributeError:
            kin = self._local.kinematics = Kinematics(self.model, self.frame_id)
            return kin

    def __getstate__(self) -> dict:
        return {"model": self.model, "frame_id": self.frame_id}

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["model"], state["frame_id"])
