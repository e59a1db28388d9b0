"""The geometry layer's one Pinocchio and coal workspace: placements, broadphase, exact distances, point Jacobians.

A :class:`Workspace` owns a ``pin.Data`` and a ``pin.GeometryData`` for one geometry model (one per thread,
as ``Robot.kinematics``). Per query it places every object (one ``pin.updateGeometryPlacements``: forward
kinematics and the objects' world poses), tests bounding spheres in numpy (the broadphase), and computes
exact signed distances with coal only for the pairs asked for.

The rate of a distance: for a pair (a, b) with witness points p_a, p_b and unit normal n from a to b
(coal's convention: d = n . (p_b - p_a) for separated objects), the distance changes as

    d_dot = n^T (J_b(p_b) - J_a(p_a)) q_dot,

with J_x(p) the Jacobian of the velocity of the material point of body x at p (world axes):
J(p) = J_v - [p]_x J_omega over the joints that move the body, from Pinocchio's world-frame joint Jacobians
(J_v the velocity of the body point passing through the world origin). A world object has J = 0. This holds
where the witness points are unique (smooth shapes, or polytopes away from parallel faces); the rates are
checked against central differences in the tests.
"""

from __future__ import annotations

import coal
import numpy as np
import pinocchio as pin

from kinredund.kinematics.state import point_curvature

#: GJK's stopping tolerance (coal's default is 1e-6): separated distances to ~1e-9 m, at no measurable cost on
#: the Panda's hulls, so that the rates can be checked by central differences
GJK_TOLERANCE = 1e-9


def no_warm_start(request) -> None:
    """GJK from its default guess at every call, never from the previous call's result.

    With coal 3.0.3's warm start (the default), the distance between a hull and a box came out alternately
    0.0819774 and 0.0820143 m on consecutive calls at configurations 5e-5 rad apart (GJK stopping early from
    the cached support vertices), which ruins the rates' central differences; from the default guess it is
    the same, smallest value every time, at no measurable cost. coal marks ``enable_cached_gjk_guess`` as
    deprecated, but ``gjk_initial_guess = DefaultGuess`` alone does not stop the support-function cache.
    """
    import warnings

    request.gjk_initial_guess = coal.GJKInitialGuess.DefaultGuess
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        request.enable_cached_gjk_guess = False


def unit_normals(d: np.ndarray, n: np.ndarray, pa: np.ndarray, pb: np.ndarray) -> np.ndarray:
    """coal's normals, made sure: (p_b - p_a) / d for separated pairs (|p_b - p_a| = d; coal leaves the normal
    unset between two exact meshes), coal's own for touching or penetrating pairs where it is a unit vector,
    else zeros."""
    out = (pb - pa) / np.where(d > 1e-12, d, 1.0)[:, None]
    inside = np.flatnonzero(d <= 1e-12)
    if len(inside):
        m = n[inside]
        unit = np.abs(np.einsum("ka,ka->k", m, m) - 1.0) < 1e-6
        out[inside] = np.where(unit[:, None], m, 0.0)
    return out


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise a x b of (k, 3) arrays (``np.cross`` costs ~20 us of argument handling at this size)."""
    return a[:, _YZX] * b[:, _ZXY] - a[:, _ZXY] * b[:, _YZX]


_YZX, _ZXY = np.array([1, 2, 0]), np.array([2, 0, 1])


class Workspace:
    """Pinocchio and coal data for one geometry model (not shared between threads).

    Args:
        model: the robot's ``pin.Model``.
        geometry: the ``pin.GeometryModel`` with its collision pairs.
        joints: each object's parent joint, shape (n_objects,).
        centres, radii: each object's bounding spheres in its joint's frame [m], shapes (n_objects, slabs, 3) and
            (n_objects, slabs) (``shapes.bounding_spheres``).
        first, second: the objects of each collision pair, in the order of ``geometry.collisionPairs``.
    """

    def __init__(self, model: pin.Model, geometry: pin.GeometryModel, joints: np.ndarray, centres: np.ndarray,
                 radii: np.ndarray, first: np.ndarray, second: np.ndarray):
        self.model, self.geometry = model, geometry
        self.data = model.createData()
        self.gdata = pin.GeometryData(geometry)
        for req in self.gdata.distanceRequests:
            req.enable_signed_distance = True
            req.gjk_tolerance = GJK_TOLERANCE
            no_warm_start(req)
        self.joints, self.first, self.second = joints, first, second
        self.centres, self.radii = centres, radii
        n, m = centres.shape[:2]
        # the broadphase's sphere pairs, flattened: pair p's m*m sphere pairs are rows p*m*m ... (p+1)*m*m - 1
        self._centres = centres.reshape(n * m, 3)
        self._sphere_joint = np.repeat(joints, m)
        i, j = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
        self._sa = (first[:, None] * m + i.ravel()[None, :]).ravel()
        self._sb = (second[:, None] * m + j.ravel()[None, :]).ravel()
        self._radii = radii.reshape(-1)[self._sa] + radii.reshape(-1)[self._sb]
        self._mm = m * m
        self._poses = None
        # which columns of q move each joint's body (the world's row is all zeros)
        self._supports = np.zeros((model.njoints, model.nv))
        for j in range(1, model.njoints):
            for s in model.supports[j].tolist()[1:]:
                self._supports[j, model.idx_vs[s]:model.idx_vs[s] + model.nvs[s]] = 1.0

    def place(self, q: np.ndarray) -> None:
        """Forward kinematics and every object's world pose at q."""
        pin.updateGeometryPlacements(self.model, self.data, self.geometry, self.gdata, q)
        self._poses = None

    def joint_poses(self) -> np.ndarray:
        """Every joint's world pose, shape (njoints, 4, 4), after :meth:`place` (read once per placement)."""
        if self._poses is None:
            oMi = self.data.oMi
            self._poses = np.array([oMi[j].homogeneous for j in range(self.model.njoints)])
        return self._poses

    def near_pairs(self, limit: float) -> np.ndarray:
        """The pairs (indices) whose bounding spheres come within ``limit`` [m], after :meth:`place`: every other
        pair is farther apart than ``limit`` (``shapes.bounding_spheres``). Compared squared, without roots."""
        M = self.joint_poses().take(self._sphere_joint, axis=0)  # take: 3x faster than fancy indexing here
        c = np.einsum("kab,kb->ka", M[:, :3, :3], self._centres) + M[:, :3, 3]
        diff = c.take(self._sa, axis=0) - c.take(self._sb, axis=0)
        reach = self._radii + limit
        close = np.einsum("ka,ka->k", diff, diff) <= reach * reach
        return np.flatnonzero(close.reshape(-1, self._mm).any(axis=1))

    def distances(self, ks) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(signed distances [m], unit normals from first to second object, p_first, p_second) of pairs ``ks``,
        shapes (k,), (k, 3), (k, 3), (k, 3), after :meth:`place`.

        Three reads per pair (Python's access to coal's results costs about a microsecond each): the normal
        of a separated pair is (p_b - p_a) / d; coal's own is read only for pairs in contact.
        """
        d, pa, pb = [], [], []
        gm, gd, one = self.geometry, self.gdata, pin.computeDistance
        for k in ks:
            res = one(gm, gd, int(k))
            d.append(res.min_distance)
            pa.append(res.getNearestPoint1())
            pb.append(res.getNearestPoint2())
        if not d:
            return np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3))
        d, pa, pb = np.array(d), np.array(pa), np.array(pb)
        n = np.zeros_like(pa)
        for r in np.flatnonzero(d <= 0):
            n[r] = gd.distanceResults[int(ks[r])].normal
        return d, unit_normals(d, n, pa, pb), pa, pb

    def closest(self, q: np.ndarray) -> tuple[int, float]:
        """(pair index, signed distance [m]) of the closest pair at q: every pair computed in one Pinocchio call."""
        k = pin.computeDistances(self.model, self.data, self.geometry, self.gdata, q)
        return k, self.gdata.distanceResults[k].min_distance

    def rows(self, q: np.ndarray, ks: np.ndarray, normal: np.ndarray, point_a: np.ndarray,
             point_b: np.ndarray) -> np.ndarray:
        """Rows n^T (J_b(p_b) - J_a(p_a)) [m/rad] of pairs ``ks``, shape (k, nv) (module docstring), after
        :meth:`place`.

        From Pinocchio's world-frame joint Jacobians ``data.J`` ([v; omega], v the velocity of the body point at
        the world origin, every joint's column), kept to the joints that move each body:
        n^T J(p) = (n^T J_v + (p x n)^T J_omega) restricted to the supports of the body's joint.
        """
        pin.computeJointJacobians(self.model, self.data, q)
        k = len(ks)
        joints = np.concatenate([self.joints.take(self.first.take(ks)), self.joints.take(self.second.take(ks))])
        n = np.concatenate([-normal, normal])  # the first object's rows count negatively
        p = np.concatenate([point_a, point_b])
        coef = np.concatenate([n, _cross(p, n)], axis=1)  # (2k, 6) against the rows [v; omega]
        both = (coef @ self.data.J) * self._supports.take(joints, axis=0)
        return both[:k] + both[k:]

    def curvature(self, q: np.ndarray, ks: np.ndarray, weight: np.ndarray, normal: np.ndarray, point_a: np.ndarray,
                  point_b: np.ndarray) -> np.ndarray:
        """sum_k w_k n_k^T (Hess p_b - Hess p_a) (n, n) over pairs ``ks`` at q: the witness points held fixed to
        their bodies (:func:`~kinredund.kinematics.state.point_curvature`; a world object's point is fixed).

        The distance's own Hessian adds the surfaces' curvature at the witness points (and the turning of the
        normal), which this leaves out: it is exact for a pair of flat faces, and for a distance row used as a
        constraint it changes only the Newton corrector's rate, not the point it converges to.
        """
        pin.computeJointJacobians(self.model, self.data, q)
        joints = np.concatenate([self.joints.take(self.first.take(ks)), self.joints.take(self.second.take(ks))])
        coef = np.concatenate([-normal, normal]) * np.concatenate([weight, weight])[:, None]
        return point_curvature(self.model, self.data, joints, np.concatenate([point_a, point_b]), coef)
