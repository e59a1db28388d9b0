"""The geometry layer's one Pinocchio and coal workspace: placements, broadphase, exact distances, point Jacobians.

A :class:`Workspace` owns a ``pin.Data`` and a ``pin.GeometryData`` for one geometry model (one per thread,
as ``Robot.kinematics``). Per query it places every object (one ``pin.updateGeometryPlacements``: forward
kinematics and the objects' world poses), tests bounding spheres in numpy (the broadphase), and computes
exact signed distances with coal only for the pairs asked for.

The rate of a distance: for a pair (a, b) with witness points p_a, p_b and unit normal n from a to b
(coal's convention: d = n . (p_b - p_a) for separated objects), the distance changes as

    d_dot = n^T (J_b(p_b) - J_a(p_a)) q_dot,

with J_x(p) the Jacobian of the velocity of the material point of body x at p (world axes):
J(p) = J_v(o_j) - [p - o_j]_x J_omega for the body's joint j at o_j (Pinocchio LOCAL_WORLD_ALIGNED). A world
object has J = 0. This holds where the witness points are unique (smooth shapes, or polytopes away from
parallel faces); rates are checked against central differences in the tests.
"""

from __future__ import annotations

import coal
import numpy as np
import pinocchio as pin

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
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
    """coal's normals, made sure: (p_b - p_a) / d for separated pairs (coal leaves the normal unset between two
    exact meshes), coal's own for touching or penetrating pairs where it is a unit vector, else zeros."""
    gap = pb - pa
    norm = np.linalg.norm(gap, axis=1)
    apart = (d > 0) & (norm > 1e-12)
    out = np.where(np.abs(np.linalg.norm(n, axis=1) - 1.0)[:, None] < 1e-6, n, 0.0)
    out[apart] = gap[apart] / norm[apart, None]
    return out


class Workspace:
    """Pinocchio and coal data for one geometry model (not shared between threads).

    Args:
        model: the robot's ``pin.Model``.
        geometry: the ``pin.GeometryModel`` with its collision pairs.
        joints: each object's parent joint, shape (n_objects,).
        centres, radii: each object's bounding sphere in its joint's frame [m], shapes (n_objects, 3), (n_objects,).
    """

    def __init__(self, model: pin.Model, geometry: pin.GeometryModel, joints: np.ndarray, centres: np.ndarray,
                 radii: np.ndarray):
        self.model, self.geometry = model, geometry
        self.data = model.createData()
        self.gdata = pin.GeometryData(geometry)
        for req in self.gdata.distanceRequests:
            req.enable_signed_distance = True
            req.gjk_tolerance = GJK_TOLERANCE
            no_warm_start(req)
        self.joints, self.centres, self.radii = joints, centres, radii
        self._used = np.unique(joints)

    def place(self, q: np.ndarray) -> None:
        """Forward kinematics and every object's world pose at q."""
        pin.updateGeometryPlacements(self.model, self.data, self.geometry, self.gdata, q)

    def sphere_centres(self) -> np.ndarray:
        """World centres of the objects' bounding spheres [m], shape (n_objects, 3), after :meth:`place`."""
        R = np.empty((self.model.njoints, 3, 3))
        p = np.zeros((self.model.njoints, 3))
        R[0] = np.eye(3)
        for j in self._used:
            if j:
                M = self.data.oMi[int(j)]
                R[j], p[j] = M.rotation, M.translation
        return np.einsum("kab,kb->ka", R[self.joints], self.centres) + p[self.joints]

    def sphere_gaps(self, first: np.ndarray, second: np.ndarray) -> np.ndarray:
        """Lower bounds of the pairs' distances [m]: centre distance minus both radii, after :meth:`place`."""
        c = self.sphere_centres()
        return np.linalg.norm(c[first] - c[second], axis=1) - self.radii[first] - self.radii[second]

    def distances(self, ks) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(signed distances [m], unit normals from first to second object, p_first, p_second) of pairs ``ks``,
        shapes (k,), (k, 3), (k, 3), (k, 3), after :meth:`place`."""
        d, n, pa, pb = [], [], [], []
        gm, gd, one = self.geometry, self.gdata, pin.computeDistance
        for k in ks:
            res = one(gm, gd, int(k))
            d.append(res.min_distance)
            n.append(res.normal)
            pa.append(res.getNearestPoint1())
            pb.append(res.getNearestPoint2())
        if not d:
            return np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3))
        d, n, pa, pb = np.array(d), np.array(n), np.array(pa), np.array(pb)
        return d, unit_normals(d, n, pa, pb), pa, pb

    def closest(self, q: np.ndarray) -> tuple[int, float]:
        """(pair index, signed distance [m]) of the closest pair at q: every pair computed in one Pinocchio call."""
        k = pin.computeDistances(self.model, self.data, self.geometry, self.gdata, q)
        return k, self.gdata.distanceResults[k].min_distance

    def rows(self, q: np.ndarray, normal: np.ndarray, joints_a: np.ndarray, point_a: np.ndarray,
             joints_b: np.ndarray, point_b: np.ndarray) -> np.ndarray:
        """Rows n^T (J_b(p_b) - J_a(p_a)) [m/rad], shape (k, nv) (module docstring), after :meth:`place`.

        With J(p) = J_v(o_j) - [p - o_j]_x J_omega: n^T J(p) = n^T J_v + ((p - o_j) x n)^T J_omega.
        """
        nj, nv = self.model.njoints, self.model.nv
        Jv, Jw, o = np.zeros((nj, 3, nv)), np.zeros((nj, 3, nv)), np.zeros((nj, 3))
        pin.computeJointJacobians(self.model, self.data, q)
        for j in np.unique(np.concatenate([joints_a, joints_b])):
            if j:
                J = pin.getJointJacobian(self.model, self.data, int(j), _LWA).reshape(6, nv)
                Jv[j], Jw[j], o[j] = J[:3], J[3:], self.data.oMi[int(j)].translation

        def side(joints, points):
            c = np.cross(points - o[joints], normal)
            return np.einsum("ka,kan->kn", normal, Jv[joints]) + np.einsum("ka,kan->kn", c, Jw[joints])

        return side(joints_b, point_b) - side(joints_a, point_a)
