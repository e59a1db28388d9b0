"""The cell: a robot's collision model, obstacles and attached objects, and their signed distances.

``kr.Scene(robot)`` holds the robot's own objects (:mod:`kinredund.geometry.collision_model`), its self pairs
(:mod:`kinredund.geometry.pairs`) and the scene's objects: world obstacles (``add_box``, ``add_sphere``,
``add_cylinder``, ``add_capsule``, ``add_mesh``) and objects attached to a robot frame (``attach_to=frame``:
a tool, a held part). Checked pairs are the enabled self pairs, every scene object against every robot object
that can move relative to it, and attached objects against world obstacles; a pair whose objects ride on one
rigid body (two world objects, a world object and the robot's base, an attached object and its link) is not
checked, nor a pair given to :meth:`Scene.ignore`.

Queries (:meth:`Scene.distances`, :meth:`Scene.min_distance`, :meth:`Scene.distance_rows`) run in a
per-thread workspace (:mod:`kinredund.geometry.engine`); with ``influence=`` a bounding-sphere broadphase
skips the pairs that are surely farther apart. A scene is changed from one thread at a time.
"""

from __future__ import annotations

import copy
import threading
from dataclasses import dataclass, field
from math import isfinite
from pathlib import Path

import numpy as np
import pinocchio as pin

from kinredund.errors import ChoiceError, FrameNotFoundError, GeometryError
from kinredund.geometry import shapes
from kinredund.geometry.collision_model import CAPSULE_RADIUS, robot_geometry
from kinredund.geometry.engine import Workspace
from kinredund.geometry.pairs import PairMatrix, self_pairs
from kinredund.geometry.records import DistanceRows, Distances
from kinredund.model.robot import Robot

_F64 = np.dtype(np.float64)
SHAPES = ("box", "sphere", "cylinder", "capsule", "convex", "mesh")


@dataclass(frozen=True)
class SceneObject:
    """One object of a scene.

    Attributes:
        name: unique in the scene (and not a robot object's name).
        shape: one of :data:`SHAPES`.
        params: the shape's numbers: ``size`` (box, full sides [m]), ``radius`` [m], ``length`` [m] (cylinder,
            capsule: along the object's z axis), ``points`` (convex, [m]), ``file``, ``scale`` and ``convex`` (mesh).
        pose: 4x4 pose [m] in the world, or in ``attach_to``'s frame.
        attach_to: a robot frame's name, or None for a world obstacle.
    """

    name: str
    shape: str
    params: dict
    pose: np.ndarray
    attach_to: str | None = None
    geometry: object = field(default=None, repr=False, compare=False)


def _make_shape(shape: str, params: dict):
    if shape == "box":
        return shapes.box(params["size"])
    if shape == "sphere":
        return shapes.sphere(params["radius"])
    if shape == "cylinder":
        return shapes.cylinder(params["radius"], params["length"])
    if shape == "capsule":
        return shapes.capsule(params["radius"], params["length"])
    if shape == "convex":
        return shapes.convex(params["points"])
    return shapes.load_mesh(params["file"], params.get("scale", 1.0), convex=params.get("convex", True))


class Scene:
    """A robot and the objects of its cell, with signed distances and their rates (module docstring).

    Args:
        robot: the robot.
        geometry: ``"convex"`` (meshes as convex hulls: fast, never farther than the meshes) or ``"mesh"``
            (exact triangle meshes, for final checks). Primitives are exact either way.
        pairs: the self-pair matrix: a :class:`~kinredund.geometry.pairs.PairMatrix`, the path of one saved
            with ``PairMatrix.save``, or None to compute it (seeded, :func:`~kinredund.geometry.pairs.self_pairs`).
        capsule_radius: capsule radius [m] for a robot without collision elements (HD-table robots).
        collision_urdf, srdf: see :func:`~kinredund.geometry.collision_model.robot_geometry`.
        compiled: queries in the compiled core (True: it must be installed), in Python (False), or in the core
            where it is installed (None); the same results either way (:mod:`kinredund.geometry.engine`).
    """

    def __init__(self, robot: Robot, *, geometry: str = "convex", pairs=None, capsule_radius: float = CAPSULE_RADIUS,
                 collision_urdf=None, srdf=None, compiled: bool | None = None):
        self.robot = robot
        self._compiled = compiled
        self._q_shape = (robot.nq,)
        self.geometry = geometry
        self._options = {"capsule_radius": capsule_radius, "collision_urdf": collision_urdf, "srdf": srdf}
        self._robot_geom = robot_geometry(robot, geometry, capsule_radius=capsule_radius,
                                          collision_urdf=collision_urdf, srdf=srdf)
        if pairs is None:
            pairs = self_pairs(robot, self._robot_geom)
        elif isinstance(pairs, (str, Path)):
            pairs = PairMatrix.load(pairs)
        if not isinstance(pairs, PairMatrix):
            raise GeometryError("pairs must be a PairMatrix, the path of a saved one, or None; "
                                f"got {type(pairs).__name__}")
        if tuple(pairs.objects) != self._robot_geom.names:
            raise GeometryError(f"the pair matrix (robot {pairs.robot!r}) names objects {list(pairs.objects)[:5]}..., "
                                f"not this robot's {list(self._robot_geom.names)[:5]}...: compute it for this robot")
        self.pair_matrix = pairs
        self._objects: dict[str, SceneObject] = {}
        self._ignored: set[frozenset] = set()
        self._local = threading.local()
        self._build()

    # -- pickling (a sweep's workers, Dask) ------------------------------------------------------
    def __getstate__(self) -> dict:
        """What rebuilds the scene: the robot, the geometry's options, the pair matrix, the objects (coal's
        shapes left out: made again from their shape and numbers; a mesh from its file, which must be there
        where it is unpickled) and the ignored pairs. The per-thread workspaces are not part of it."""
        return {"robot": self.robot, "geometry": self.geometry, "pairs": self.pair_matrix, "options": self._options,
                "objects": [(o.name, o.shape, o.params, o.pose, o.attach_to) for o in self._objects.values()],
                "ignored": [tuple(sorted(p)) for p in self._ignored]}

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["robot"], geometry=state["geometry"], pairs=state["pairs"], **state["options"])
        for name, shape, params, pose, attach_to in state["objects"]:
            self._objects[name] = SceneObject(name, shape, params, np.asarray(pose, float), attach_to,
                                              _make_shape(shape, params))
        self._ignored = {frozenset(p) for p in state["ignored"]}
        self._build()

    # -- objects --------------------------------------------------------------------------------
    @property
    def objects(self) -> tuple[str, ...]:
        """The scene objects' names (not the robot's), in the order added."""
        return tuple(self._objects)

    @property
    def robot_objects(self) -> tuple[str, ...]:
        """The robot's collision objects' names."""
        return self._robot_geom.names

    def object(self, name: str) -> SceneObject:
        """The scene object ``name``, or ChoiceError listing them."""
        if name not in self._objects:
            raise ChoiceError("scene object", name, list(self._objects) or ["(none)"])
        return self._objects[name]

    def add_box(self, name: str, size, pose=None, *, attach_to: str | None = None) -> SceneObject:
        """A box of full sides ``size`` (x, y, z) [m] centred at ``pose`` (see :mod:`~kinredund.geometry.shapes`)."""
        size = shapes.vector(size, 3, f"{name}: box size [m]").tolist()
        return self._add(name, "box", {"size": size}, pose, attach_to)

    def add_sphere(self, name: str, radius: float, position=None, *, attach_to: str | None = None) -> SceneObject:
        """A sphere of ``radius`` [m] centred at ``position`` [m] (a 3-vector, or any pose)."""
        return self._add(name, "sphere", {"radius": radius}, position, attach_to)

    def add_cylinder(self, name: str, radius: float, length: float, pose=None, *,
                     attach_to: str | None = None) -> SceneObject:
        """A cylinder of ``radius`` and ``length`` [m] along the z axis of ``pose``, centred on it."""
        return self._add(name, "cylinder", {"radius": radius, "length": length}, pose, attach_to)

    def add_capsule(self, name: str, radius: float, length: float, pose=None, *,
                    attach_to: str | None = None) -> SceneObject:
        """A capsule: a segment of ``length`` [m] along the z axis of ``pose``, centred on it, swept by ``radius``."""
        return self._add(name, "capsule", {"radius": radius, "length": length}, pose, attach_to)

    def add_convex(self, name: str, points, pose=None, *, attach_to: str | None = None) -> SceneObject:
        """The convex hull of ``points`` [m] (N, 3) in the frame of ``pose`` (e.g. a thesis obstacle's prism)."""
        pts = np.asarray(points, dtype=float).tolist() if np.ndim(points) == 2 else points
        return self._add(name, "convex", {"points": pts}, pose, attach_to)

    def add_mesh(self, name: str, file, pose=None, *, scale=1.0, convex: bool | None = None,
                 attach_to: str | None = None) -> SceneObject:
        """A mesh file (STL, OBJ, DAE...) at ``pose``, its vertices times ``scale`` (one factor or three).

        ``convex``: its convex hull (default for ``geometry="convex"``) or its exact triangles (default for
        ``"mesh"``).
        """
        convex = self.geometry == "convex" if convex is None else bool(convex)
        scale = scale if np.ndim(scale) == 0 else list(np.asarray(scale, dtype=float))
        return self._add(name, "mesh", {"file": str(Path(file).resolve()), "scale": scale, "convex": convex},
                         pose, attach_to)

    def _add(self, name, shape, params, pose, attach_to) -> SceneObject:
        if not isinstance(name, str) or not name:
            raise GeometryError(f"an object's name must be a non-empty string, got {name!r}")
        if name in self._objects or name in self._robot_geom.names:
            raise GeometryError(f"an object named {name!r} is already in the scene (robot objects included)")
        if attach_to is not None:
            self._frame(attach_to)
        obj = SceneObject(name, shape, params, shapes.to_pose(pose, f"pose of {name!r}").homogeneous, attach_to,
                          _make_shape(shape, params))
        self._objects[name] = obj
        self._build()
        return obj

    def _frame(self, name: str) -> int:
        model = self.robot.model
        if not isinstance(name, str) or not model.existFrame(name):
            raise FrameNotFoundError(str(name), [f.name for f in model.frames], "attach_to takes a robot frame")
        return model.getFrameId(name)

    def remove(self, name: str) -> None:
        """Take object ``name`` out of the scene (ChoiceError if there is none)."""
        self.object(name)
        del self._objects[name]
        self._ignored = {p for p in self._ignored if name not in p}
        self._build()

    def move(self, name: str, pose) -> None:
        """Put object ``name`` at ``pose`` (in the world, or in its frame for an attached object)."""
        obj = self.object(name)
        M = shapes.to_pose(pose, f"pose of {name!r}")
        self._objects[name] = SceneObject(obj.name, obj.shape, obj.params, M.homogeneous, obj.attach_to, obj.geometry)
        self._build()

    def ignore(self, a: str, b: str) -> None:
        """Stop checking pair (a, b) (either order; ChoiceError if the scene does not check it)."""
        self._pair_index(a, b)
        self._ignored.add(frozenset((a, b)))
        self._build()

    def only(self, pairs) -> Scene:
        """A copy of this scene that checks only those of its pairs in ``pairs`` ((a, b) in either order), the others
        ignored; the objects and the robot's geometry are shared (neither is changed in place), the workspace is not.
        """
        keep = {frozenset(p) for p in pairs}
        clone = copy.copy(self)
        clone._objects = dict(self._objects)
        clone._ignored = set(self._ignored) | {frozenset(p) for p in self._pair_names if frozenset(p) not in keep}
        clone._build()
        return clone

    @property
    def ignored(self) -> tuple[tuple[str, str], ...]:
        """The pairs given to :meth:`ignore`."""
        return tuple(tuple(sorted(p)) for p in self._ignored)

    # -- the geometry model ------------------------------------------------------------------------
    def _build(self) -> None:
        model = self.robot.model
        gm = pin.GeometryModel()
        for g in self._robot_geom.model.geometryObjects:
            gm.addGeometryObject(pin.GeometryObject(g))
        for obj in self._objects.values():
            M = pin.SE3(obj.pose)
            if obj.attach_to is None:
                gm.addGeometryObject(pin.GeometryObject(obj.name, 0, 0, M, obj.geometry))
            else:
                fid = model.getFrameId(obj.attach_to)
                f = model.frames[fid]
                gm.addGeometryObject(pin.GeometryObject(obj.name, f.parentJoint, fid, f.placement * M, obj.geometry))
        names = [g.name for g in gm.geometryObjects]
        index = {n: i for i, n in enumerate(names)}
        joints = np.array([g.parentJoint for g in gm.geometryObjects], dtype=int)
        pairs = [(index[a], index[b]) for a, b in self.pair_matrix.enabled]
        n_robot = len(self._robot_geom.names)
        for k in range(n_robot, len(names)):  # objects on one rigid body (world included) never move apart
            pairs += [(i, k) for i in range(k) if joints[i] != joints[k]]
        pairs = [(i, j) for i, j in pairs if frozenset((names[i], names[j])) not in self._ignored]
        for i, j in pairs:
            gm.addCollisionPair(pin.CollisionPair(i, j))
        spheres = [shapes.bounding_spheres(g.geometry, g.placement) for g in gm.geometryObjects]
        self._gm, self._names = gm, names
        self._first = np.array([i for i, _ in pairs], dtype=int)
        self._second = np.array([j for _, j in pairs], dtype=int)
        self._pair_names = tuple((names[i], names[j]) for i, j in pairs)
        self._spheres = (joints, np.array([c for c, _ in spheres]), np.array([r for _, r in spheres]))
        self._local = threading.local()

    @property
    def compiled(self) -> bool | None:
        """Where the queries run: the compiled core (True), Python (False) or the core where it is installed
        (None); setting it takes effect at the next query of every thread."""
        return self._compiled

    @compiled.setter
    def compiled(self, value: bool | None) -> None:
        self._compiled = value
        self._local = threading.local()

    def workspace(self, own: bool = False) -> Workspace:
        """This thread's workspace (:class:`~kinredund.geometry.engine.Workspace`), made on first use; ``own``: a
        new one, not kept (for one user that keeps it, e.g. the compiled tracker's row check)."""
        ws = None if own else getattr(self._local, "workspace", None)
        if ws is None:  # (the arrays that follow from the geometry made once per build: Workspace.layout)
            kept = self.__dict__.get("_layout")
            layout = kept[1] if kept is not None and kept[0] is self._gm else None
            ws = Workspace(self.robot.model, self._gm, *self._spheres, self._first, self._second,
                           compiled=self._compiled, layout=layout)
            self._layout = (self._gm, ws.layout)
            if not own:
                self._local.workspace = ws
        return ws

    @property
    def pairs(self) -> tuple[tuple[str, str], ...]:
        """Every pair the scene checks: enabled self pairs, then the scene objects' pairs."""
        return self._pair_names

    def _names_of(self, ks: np.ndarray) -> tuple[tuple[str, str], ...]:
        names = self._pair_names
        return tuple([names[k] for k in ks.tolist()])

    def _pair_index(self, a: str, b: str) -> int:
        for k, p in enumerate(self._pair_names):
            if p == (a, b) or p == (b, a):
                return k
        near = [p for p in self._pair_names if a in p or b in p] or list(self._pair_names)
        raise ChoiceError("pair (the scene does not check it)", (a, b), [f"({x}, {y})" for x, y in near])

    def object_pose(self, name: str, q) -> np.ndarray:
        """The world pose (4x4, [m]) of object ``name`` (a scene object or a robot object) at q."""
        if name not in self._names:
            raise ChoiceError("object", name, self._names)
        ws = self.workspace()
        ws.place(self._q(q))
        return ws.gdata.oMg[self._names.index(name)].homogeneous

    def object_reach(self, extent=None) -> np.ndarray:
        """L (objects, n) [m/rad or m/m]: along a straight joint path, joint j moves every point of object o
        (in the geometry model's order: the robot's objects, then the scene's) by at most L[o, j] |dq_j|: an
        object's points lie within its bounding spheres' farthest reach of its joint's origin
        (:meth:`~kinredund.model.robot.Robot.reach`; ``extent`` as there).
        """
        joints, centres, radii = self._spheres
        far = (np.linalg.norm(centres, axis=2) + radii).max(axis=1, initial=0.0)
        return np.array([self.robot.reach(k, float(f), extent) for k, f in zip(joints.tolist(), far, strict=True)]
                        ).reshape(len(joints), self.robot.model.nv)

    def motion_bound(self, extent=None) -> np.ndarray:
        """B (pairs, n) [m/rad or m/m]: along a straight joint path from q to q', the distance of checked pair k
        changes by at most sum_j B[k, j] |q'_j - q_j| (in the order of :attr:`pairs`).

        From :meth:`object_reach` (``extent`` as there: by default, for paths within the joint box). A joint
        that moves both objects of a pair moves them rigidly together and leaves their distance alone. Kept for the
        scene as it is (its objects and pairs, rebuilt at every change) and ``extent``: a copy is returned.
        """
        key = None if extent is None else np.asarray(extent, float).tobytes()
        kept = self.__dict__.get("_bound")
        if kept is None or kept[0] is not self._spheres or kept[1] != key:
            L = self.object_reach(extent)
            a, b = L[self._first], L[self._second]
            kept = self._bound = (self._spheres, key, np.where((a > 0) & (b > 0), 0.0, a + b))
        return kept[2].copy()

    # -- queries --------------------------------------------------------------------------------
    @staticmethod
    def _influence(influence) -> float | None:
        if influence is None:
            return None
        influence = float(influence)
        if not isfinite(influence) or influence < 0:
            raise GeometryError(f"influence must be a finite distance >= 0 [m] or None, got {influence!r}")
        return influence

    def _q(self, q) -> np.ndarray:
        """q validated: a finite float array of the robot's length as is (the hot path), else ``robot.check_q``."""
        if type(q) is np.ndarray and q.dtype is _F64 and q.shape == self._q_shape and isfinite(q.dot(q)):
            return q  # (q.q is inf or nan when an entry is; an overflow of huge values goes to check_q)
        return self.robot.check_q(q)

    def distances(self, q, influence: float | None = None) -> Distances:
        """Signed distances [m] of the checked pairs at q, with witness points and normals.

        Args:
            q: a configuration [rad or m], shape (n,).
            influence: compute exactly only pairs whose bounding spheres are within this distance [m] (the
                others are surely farther); None computes every checked pair.
        """
        q, influence = self._q(q), self._influence(influence)
        ks, d, n, pa, pb, _ = self.workspace().query(q, influence)
        return Distances(q.copy(), self._names_of(ks), d, pa, pb, n, influence, len(self._pair_names))

    def pair_distances(self, q, influence: float | None = None, only=None) -> tuple[np.ndarray, np.ndarray]:
        """(the pairs' positions in :attr:`pairs`, their signed distances [m]): :meth:`distances` without the
        record (names, witness points), for a caller that takes values at every step (``only``: distance_rows')."""
        ks, d, *_ = self.workspace().query(self._q(q), self._influence(influence), only=only)
        return ks, d

    def min_distance(self, q) -> float:
        """The smallest signed distance [m] over every checked pair at q (inf when the scene checks none)."""
        if not self._pair_names:
            return float("inf")
        return float(self.workspace().closest(self._q(q))[1])

    def closest(self, q) -> tuple[tuple[str, str] | None, float]:
        """(the closest pair, its signed distance [m]) at q ((None, inf) when the scene checks no pair)."""
        if not self._pair_names:
            return None, float("inf")
        k, d = self.workspace().closest(self._q(q))
        return self._pair_names[k], float(d)

    def distance_rows(self, q, influence: float | None = None, only=None) -> DistanceRows:
        """Distances d [m] and rows G [m/rad] with d_dot = G q_dot, for the pairs within ``influence`` [m].

        ``G[k] = n_k^T (J_b(p_b) - J_a(p_a))`` at the witness points (``kinredund.geometry.engine``); ``only``:
        the pairs to consider (increasing positions in :attr:`pairs`, int64; None: all), the others not computed.
        """
        q, influence = self._q(q), self._influence(influence)
        ks, d, n, pa, pb, G = self.workspace().query(q, influence, rows=True, only=only)
        if not len(ks):
            return DistanceRows((), d, np.zeros((0, self.robot.nq)), influence, np.zeros(0, int), n, pa, pb)
        return DistanceRows(self._names_of(ks), d, G, influence, np.asarray(ks), n, pa, pb)

    def distance_curvature(self, q, rows: DistanceRows, weights) -> np.ndarray:
        """sum_k w_k n_k^T (Hess p_b - Hess p_a) [m/rad^2] (n, n): the second-order term of the distance rows
        ``rows`` (from :meth:`distance_rows` at the same q), the witness points held fixed to their bodies.

        It leaves out the surfaces' curvature at the witness points (exact for flat faces); as a constraint's
        share of the tracker's system it changes the Newton corrector's rate only
        (:meth:`~kinredund.geometry.engine.Workspace.curvature`).
        """
        q = self._q(q)
        w = np.asarray(weights, dtype=float)
        if rows.index is None or w.shape != (len(rows.pairs),):
            raise GeometryError(f"weights must be one number per row ({len(rows.pairs)}) of a distance_rows() record")
        ws = self.workspace()
        return ws.curvature(q, rows.index, w, rows.normal, rows.point_a, rows.point_b)
