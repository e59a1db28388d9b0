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

Compiled: where the compiled core (``kinredund._core``) is importable, :meth:`Workspace.query`,
:meth:`Workspace.closest` and :meth:`Workspace.differences` (the central differences of some pairs' rows) run in one
C++ call (``_core.DistanceQuery``, src/core/distances.cpp) on this
workspace's own Pinocchio objects: the same Pinocchio and coal calls with the same requests, so the same
distances, witness points, normals and rows (to rounding); without the core, the Python path below.
"""

from __future__ import annotations

import importlib
from operator import attrgetter

import coal
import numpy as np
import pinocchio as pin

from kinredund.errors import GeometryError, OptionError
from kinredund.geometry.gjk import GJK_TOLERANCE, fresh_starts, no_warm_start
from kinredund.kinematics.state import point_curvature

#: below this distance [m] a pair's normal is coal's own, not (p_b - p_a) / d: the witness points' rounding
#: (~1e-16 of their size) over d tilts the latter (1e-6 at d = 1e-11 m, a zero vector at d <= 1e-12 m)
NEAR_CONTACT = 1e-6


def unit_normals(d: np.ndarray, n: np.ndarray, pa: np.ndarray, pb: np.ndarray) -> np.ndarray:
    """coal's normals, made sure: (p_b - p_a) / d for pairs farther apart than :data:`NEAR_CONTACT`
    (|p_b - p_a| = d); nearer ones (touching or penetrating too) take coal's own ``n`` where it is a unit
    vector, else (coal leaves it unset between two exact meshes) (p_b - p_a) / |p_b - p_a| while apart, else
    zeros."""
    diff = pb - pa
    out = diff / np.where(d > NEAR_CONTACT, d, 1.0)[:, None]
    near = np.flatnonzero(d <= NEAR_CONTACT)
    if len(near):
        m, g = n[near], diff[near]
        unit = np.abs(np.einsum("ka,ka->k", m, m) - 1.0) < 1e-6
        length = np.sqrt(np.einsum("ka,ka->k", g, g))
        apart = (d[near] > 0) & (length > 0)
        points = g / np.where(apart, length, 1.0)[:, None] * apart[:, None]
        out[near] = np.where(unit[:, None], m, points)
    return out


def compiled_core():
    """The compiled core ``kinredund._core``, or None where the package was installed without it."""
    try:
        return importlib.import_module("kinredund._core")
    except ImportError:
        return None


_CORE = compiled_core()


def _layout(model: pin.Model, geometry: pin.GeometryModel, joints: np.ndarray, centres: np.ndarray, radii: np.ndarray,
            first: np.ndarray, second: np.ndarray) -> dict:
    """A :class:`Workspace`'s arrays that follow from its geometry alone (read, never written: workspaces of one
    geometry share them: a Workspace's ``layout``): the broadphase's sphere pairs and centres, the joints' columns
    per pair, the pair matrix's cells, the output widths."""
    n, m = centres.shape[:2]
    # every sphere centre in one product: the poses of the joints that carry objects (J, 4, 4) times the
    # centres in homogeneous coordinates (4, n*m); sphere s is column s of its joint's block, rows 0-2
    pose_joints = sorted(set(joints.tolist()))
    block = np.searchsorted(pose_joints, np.repeat(joints, m))
    moving = [j for j in pose_joints if j > 0]  # the world's pose (joint 0) is the identity
    fixed = [np.eye(4)] if 0 in pose_joints else []
    s = np.arange(n * m)
    local = np.vstack([centres.reshape(n * m, 3).T, np.ones(n * m)])
    centre_index = (block * 4 * n * m)[:, None] + (np.arange(3) * n * m)[None, :] + s[:, None]  # (n*m, 3)
    # the broadphase's sphere pairs, flattened: pair p's m*m sphere pairs are rows p*m*m ... (p+1)*m*m - 1
    i, j = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
    sa = (first[:, None] * m + i.ravel()[None, :]).ravel()
    sb = (second[:, None] * m + j.ravel()[None, :]).ravel()
    radii_ = radii.reshape(-1)[sa] + radii.reshape(-1)[sb]
    # the centres of each sphere pair's a and b as flat indices into the product of the poses and centres
    pair_centres = centre_index.ravel()[np.stack([sa, sb])[:, :, None] * 3 + np.arange(3)]
    mm = m * m
    # which columns of q move each joint's body (the world's row is all zeros), and per pair the first
    # object's columns negated and the second's: rows of pair k are sum_s (coef_s J)[k] * _signed[k, s]
    supports = np.zeros((model.njoints, model.nv))
    for jt in range(1, model.njoints):
        for t in model.supports[jt].tolist()[1:]:
            supports[jt, model.idx_vs[t]:model.idx_vs[t] + model.nvs[t]] = 1.0
    signed = np.stack([-supports[joints[first]], supports[joints[second]]], axis=1)
    n_obj = len(geometry.geometryObjects)
    map_shape, map_size = (n_obj, n_obj), n_obj * n_obj
    cell_ab, cell_ba = first * n_obj + second, second * n_obj + first
    ones = np.ones((2 * len(first), 1))
    width = (10, 10 + model.nv)  # the compiled query's output row without and with the distance row
    return {"_moving": moving, "_fixed": fixed, "_local": local, "_sa": sa, "_sb": sb, "_radii": radii_,
            "_pair_centres": pair_centres, "_mm": mm, "_signed": signed, "_map_shape": map_shape,
            "_map_size": map_size, "_cell_ab": cell_ab, "_cell_ba": cell_ba, "_ones": ones, "_width": width}


class Workspace:
    """Pinocchio and coal data for one geometry model (not shared between threads).

    Args:
        model: the robot's ``pin.Model``.
        geometry: the ``pin.GeometryModel`` with its collision pairs.
        joints: each object's parent joint, shape (n_objects,).
        centres, radii: each object's bounding spheres in its joint's frame [m], shapes (n_objects, slabs, 3) and
            (n_objects, slabs) (``shapes.bounding_spheres``).
        first, second: the objects of each collision pair, in the order of ``geometry.collisionPairs``.
        compiled: run :meth:`query` and :meth:`closest` in the compiled core (True: it must be there), in
            Python (False), or in the core where it is importable (None).
        layout: the ``layout`` of a workspace of the same arguments (its arrays that follow from them, shared), or
            None to make them.
    """

    def __init__(self, model: pin.Model, geometry: pin.GeometryModel, joints: np.ndarray, centres: np.ndarray,
                 radii: np.ndarray, first: np.ndarray, second: np.ndarray, compiled: bool | None = None,
                 layout: dict | None = None):
        self.model, self.geometry = model, geometry
        self.data = model.createData()
        self.gdata = pin.GeometryData(geometry)
        requests = self.gdata.distanceRequests
        for req in requests:
            req.enable_signed_distance = True
            req.gjk_tolerance = GJK_TOLERANCE
        no_warm_start(requests)
        self.joints, self.first, self.second = joints, first, second
        self.centres, self.radii = centres, radii
        # the arrays that follow from the geometry: made here, or those of another workspace of it (Scene.workspace)
        self.layout = _layout(model, geometry, joints, centres, radii, first, second) if layout is None else layout
        self.__dict__.update(self.layout)
        self._reach = (None, None)  # (limit, (radii + limit)^2) of the last broadphase distance
        self._points = np.empty((0, 3))
        self.polytopes: dict = {}  # object index -> its kinredund.geometry.polytopes.Polytope or None, on first use
        self._core = self._compiled_query(compiled)

    def _compiled_query(self, compiled: bool | None):
        """The compiled core's query on this workspace's objects, or None for the Python path."""
        if not (compiled or (compiled is None and _CORE is not None)):
            return None
        if _CORE is None:
            raise GeometryError("compiled=True, but kinredund was installed without its compiled core "
                                "(kinredund._core): reinstall with pin[build] and nanobind, or pass compiled=None")
        n, m = self.centres.shape[:2]
        i64 = np.int64
        return _CORE.DistanceQuery(self.model, self.data, self.geometry, self.gdata, self.joints.astype(i64),
                                   np.ascontiguousarray(self.centres.reshape(n * m, 3), dtype=float),
                                   np.ascontiguousarray(self.radii.reshape(-1), dtype=float),
                                   self.first.astype(i64), self.second.astype(i64))

    @property
    def compiled(self) -> bool:
        """Whether :meth:`query` and :meth:`closest` run in the compiled core."""
        return self._core is not None

    def row_guard(self, row_of_pair: np.ndarray, clearances: np.ndarray, influence: float, bound: np.ndarray,
                  extent: np.ndarray, tol: float, skip: float):
        """The compiled core's check of a tracker's step for a switch of distance rows on this workspace's query
        (``kinredund._core.RowGuard``, src/core/distances.cpp; used by :mod:`kinredund.tracking.compiled`), or
        None where the queries run in Python. ``row_of_pair``: each pair's row (-1: none); ``clearances`` [m] per
        row; ``influence`` [m] the broadphase distance; ``bound`` (rows, nv) [m/rad] the motion bound valid for
        |q| <= ``extent``; ``tol`` [m] how far below zero a row counts; ``skip`` [m] the margin above which lowered
        values stand in for exact ones."""
        if self._core is None:
            return None
        rows = np.asarray(row_of_pair, dtype=np.int64)
        clearances, bound = np.asarray(clearances, dtype=float), np.ascontiguousarray(bound, dtype=float)
        extent = np.asarray(extent, dtype=float)
        taken = rows[rows >= 0]
        if len(np.unique(taken)) != len(taken):  # a row's value is its one pair's distance (no min over pairs)
            raise OptionError(f"row_of_pair names a row twice ({np.sort(taken).tolist()}): each row is one pair's")
        for what, a, top in (("clearances", clearances, "finite"), ("bound", bound, "finite"),
                             ("extent", extent, "or inf (no side)")):
            ok = np.isfinite(a) if top == "finite" else ~np.isnan(a)
            if not (ok.all() and (a >= 0.0).all()):  # lowered values must stay lower bounds
                raise OptionError(f"the row guard's {what} must be >= 0 and {top}, got {a.tolist()}")
        return _CORE.RowGuard(self._core, rows, clearances, float(influence), bound, extent, float(tol), float(skip))

    def query(self, q: np.ndarray, limit: float | None, rows: bool = False, only: np.ndarray | None = None):
        """(pairs, signed distances [m], unit normals, p_first, p_second [m], rows G [m/rad] or None) at q: the
        pairs (indices, shape (k,)) within ``limit`` [m] by the broadphase (:meth:`near_pairs`; every pair when
        None), their :meth:`distances` and, with ``rows``, their :meth:`rows` (shape (k, nv)). ``only``: the
        pairs to consider (increasing indices, int64), or None for every pair; a pair's numbers do not depend on
        which others are computed.

        One call of the compiled core where it is used, else :meth:`place`, :meth:`near_pairs`, :meth:`distances`
        and :meth:`rows` in turn.

        Raises:
            GeometryError: ``only`` not increasing pair indices; in the compiled core also a q of another length
                or a limit < 0 or NaN.
        """
        if self._core is not None:  # the arrays made here, filled there: row r = [d, n, p_a, p_b, G row]
            index, out = np.empty(len(self.first), dtype=np.int64), np.empty((len(self.first), self._width[rows]))
            try:
                k = self._core.query(q, limit, rows, index, out, only)
            except ValueError as e:  # (checked there: no cost here on the hot path)
                raise GeometryError(str(e)) from None
            P = out[:k].copy()  # (a record kept from each query then holds k rows, not one per pair)
            return index[:k].copy(), P[:, 0], P[:, 1:4], P[:, 4:7], P[:, 7:10], (P[:, 10:] if rows else None)
        if only is not None:
            only = np.asarray(only)
            if only.ndim != 1 or (len(only) and not (np.issubdtype(only.dtype, np.integer) and only.min() >= 0
                                                     and only.max() < len(self.first) and np.all(np.diff(only) > 0))):
                raise GeometryError(f"only must be increasing pair indices 0..{len(self.first) - 1}, got "
                                    f"{only.tolist()}")
        self.place(q)
        ks = np.arange(len(self.first)) if limit is None else self.near_pairs(limit)
        if only is not None:
            ks = np.intersect1d(ks, only, assume_unique=True)
        d, n, pa, pb = self.distances(ks)
        return ks, d, n, pa, pb, (self.rows(ks, n) if rows else None)

    def differences(self, q: np.ndarray, limit: float, ks, step: float) -> np.ndarray | None:
        """The central differences of the rows of pairs ``ks`` (repeats allowed) at q, shape (n, len(ks), n)
        [m/rad]: D[j, i] = G_i(q + step e_j) - G_i(q - step e_j), each G_i as :meth:`query` (``limit``, rows) gives
        it at that point, zero for a pair beyond ``limit`` there; one call of the compiled core
        (``DistanceQuery.differences``), which computes only those pairs. None where the queries run in Python, or
        the model has other positions than velocities.

        Raises:
            GeometryError: a pair index out of range, a step not > 0 or a limit < 0.
        """
        if self._core is None or self.model.nq != self.model.nv:
            return None
        ks = np.asarray(ks)
        if ks.ndim != 1 or (len(ks) and ks.dtype.kind not in "iu"):
            raise GeometryError(f"pairs must be pair indices 0..{len(self.first) - 1}, got {ks.tolist()}")
        try:  # (the indices, step and limit are checked there: no cost here on the hot path)
            D = self._core.differences(q, float(limit), ks.astype(np.int64, copy=False), float(step))
        except ValueError as e:
            raise GeometryError(str(e)) from None
        n = self.model.nv
        return D.reshape(n, len(ks), n)

    def place(self, q: np.ndarray) -> None:
        """Forward kinematics and every object's world pose at q."""
        pin.updateGeometryPlacements(self.model, self.data, self.geometry, self.gdata, q)

    def _centre_products(self) -> np.ndarray:
        """The poses of the joints that carry objects times every local centre, shape (4 J, n_objects * slabs)."""
        oMi = self.data.oMi
        poses = np.array(self._fixed + [oMi[j].homogeneous for j in self._moving])
        return poses.reshape(-1, 4) @ self._local

    def _gaps(self) -> np.ndarray:
        """Centre of sphere a less centre of sphere b for every sphere pair [m], shape (pairs * m * m, 3)."""
        ab = self._centre_products().take(self._pair_centres)
        return ab[0] - ab[1]

    def near_pairs(self, limit: float) -> np.ndarray:
        """The pairs (indices) whose bounding spheres come within ``limit`` [m], after :meth:`place`: every other
        pair is farther apart than ``limit`` (``shapes.bounding_spheres``). Compared squared, without roots."""
        diff = self._gaps()
        if self._reach[0] != limit:
            reach = self._radii + limit
            self._reach = (limit, reach * reach)
        close = (diff * diff) @ _ONES3 <= self._reach[1]
        return np.flatnonzero(close.reshape(-1, self._mm).any(axis=1))

    def lower_bounds(self) -> np.ndarray:
        """A lower bound [m] on each pair's distance, after :meth:`place`: the least gap between their bounding
        spheres (every point of an object is in one of its spheres), less 1e-9 m for rounding."""
        diff = self._gaps()
        gap = np.sqrt((diff * diff) @ _ONES3) - self._radii
        return gap.reshape(-1, self._mm).min(axis=1) - 1e-9

    def distances(self, ks) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(signed distances [m], unit normals from first to second object, p_first, p_second) of pairs ``ks``,
        shapes (k,), (k, 3), (k, 3), (k, 3), after :meth:`place`.

        Three reads per pair (Python's access to coal's results costs about a microsecond each): the normal
        of a pair apart is (p_b - p_a) / d; coal's own is read only for pairs within :data:`NEAR_CONTACT`. The
        witness points are kept (``_points``, p_first rows then p_second rows) for :meth:`rows`.
        """
        ks = ks.tolist()
        k = len(ks)
        gm, gd, one = self.geometry, self.gdata, pin.computeDistance
        fresh_starts(gd.distanceRequests, ks)
        results = [one(gm, gd, pair) for pair in ks]  # references into gdata.distanceResults
        d = np.array(list(map(_DISTANCE, results)))
        P = np.array(list(map(_POINT1, results)) + list(map(_POINT2, results))).reshape(2 * k, 3)
        self._points = P
        pa, pb = P[:k], P[k:]
        if k and d.min() > NEAR_CONTACT:  # all apart: the common case, without unit_normals' masks
            return d, (pb - pa) / d[:, None], pa, pb
        n = np.zeros((k, 3))
        for r in np.flatnonzero(d <= NEAR_CONTACT).tolist():
            n[r] = results[r].normal
        return d, unit_normals(d, n, pa, pb), pa, pb

    def closest(self, q: np.ndarray) -> tuple[int, float]:
        """(pair index, signed distance [m]) of the closest pair at q, the first of equals in pair order.

        Bounded by :meth:`lower_bounds`: the pair of the least bound is computed first, giving d_0; a pair whose
        bound exceeds max(d_0, 0) is farther than d_0 (below 0 a bound says nothing about how deep two objects
        penetrate), and coal computes the others in one Pinocchio call (``gdata.activeCollisionPairs`` is left
        set to them). The same answer as computing every pair (``pin.computeDistances`` over all of them).
        The compiled core, where it is used, gives the same answer from fewer exact distances: after ruling
        pairs out by one sphere around each object, it takes the others in the order of their bounds and stops
        at the first bound above max(least distance so far, 0), leaving active only the pairs it computed.
        """
        if self._core is not None:
            return self._core.closest(q)
        self.place(q)
        lb = self.lower_bounds()
        gm, gd, first = self.geometry, self.gdata, int(lb.argmin())
        fresh_starts(gd.distanceRequests, [first])
        bound = max(pin.computeDistance(gm, gd, first).min_distance, 0.0)
        active = lb <= bound
        fresh_starts(gd.distanceRequests, np.flatnonzero(active).tolist())  # (the pairs computed below only)
        cells = np.zeros(self._map_size, dtype=bool)
        cells[self._cell_ab] = active  # both (a, b) and (b, a): whichever triangle Pinocchio reads
        cells[self._cell_ba] = active
        gd.setActiveCollisionPairs(gm, cells.reshape(self._map_shape))
        k = pin.computeDistances(gm, gd)
        return k, gd.distanceResults[k].min_distance

    def rows(self, ks: np.ndarray, normal: np.ndarray, points: np.ndarray | None = None) -> np.ndarray:
        """Rows n^T (J_b(p_b) - J_a(p_a)) [m/rad] of pairs ``ks``, shape (k, nv) (module docstring), after
        :meth:`distances` of the same pairs (its witness points) at the placed configuration, or at ``points``
        ((2k, 3): the k points p_a, then the k points p_b [m], world frame) at the placed configuration.

        From Pinocchio's world-frame joint Jacobians ``data.J`` ([v; omega], v the velocity of the body point at
        the world origin, every joint's column), kept to the joints that move each body:
        n^T J(p) = (n^T J_v + (p x n)^T J_omega) restricted to the supports of the body's joint. The
        coefficients [n, p x n] are bilinear in (1, p) and n: one product of their outer product with
        ``_LIFT`` @ J.
        """
        pin.computeJointJacobians(self.model, self.data)  # from the placement's forward kinematics
        k = len(ks)
        if not k:  # (the reshape below cannot infer the width of no rows)
            return np.zeros((0, self.model.nv))
        n2 = np.concatenate([normal, normal])
        ones = self._ones[:2 * k] if 2 * k <= len(self._ones) else np.ones((2 * k, 1))  # (more rows than pairs)
        P = np.concatenate([ones, self._points if points is None else points], axis=1)  # (1, p) per row
        outer = (P[:, :, None] * n2[:, None, :]).reshape(2 * k, 12)
        both = (outer @ (_LIFT @ self.data.J)).reshape(2, k, -1)
        return np.einsum("skc,ksc->kc", both, self._signed.take(ks, axis=0))


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


def _lift() -> np.ndarray:
    """E (12, 6) with [n, p x n] = (outer((1, p), n)).ravel() @ E: n from the row for 1, p x n from the rows
    for p (the Levi-Civita symbol)."""
    E = np.zeros((4, 3, 6))
    E[0, :, :3] = np.eye(3)
    for i, j, sign in ((0, 1, 1), (1, 2, 1), (2, 0, 1), (1, 0, -1), (2, 1, -1), (0, 2, -1)):
        E[1 + i, j, 3 + 3 - i - j] = sign  # (p x n)_m = eps_mij p_i n_j
    return E.reshape(12, 6)


_LIFT = _lift()
# coal's result accessors, mapped over a list of results (faster than attribute lookups in a loop)
_DISTANCE = attrgetter("min_distance")
_POINT1, _POINT2 = coal.DistanceResult.getNearestPoint1, coal.DistanceResult.getNearestPoint2
_ONES3 = np.ones(3)  # (diff * diff) @ _ONES3: squared norms of rows, half the time of einsum at ~1000 rows
