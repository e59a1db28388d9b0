"""The cell of a sweep: a collision scene carried to the workers and placed with the part at each placement.

Frames. A scene's world objects are given in the cell's world frame, which is the part frame of the sweep (the
frame its path is given in: the part, its fixtures and the table stay put together). A placement T is the
part frame's pose in the robot's base frame (:mod:`kinredund.sweep.placement`): putting the part at T is
putting the base at T^-1 in the cell. The robot's model knows only its base frame, so at each placement the
world objects are expressed in it: an object at X in the cell is at ``T @ X`` in the base frame, as the path's
points are (``PartPath``: p -> R p + o). Objects attached to a robot frame (a tool, a held part) ride on the
robot and are left as they are. Distances are invariant under a rigid motion of everything, so these are the
distances of the robot actually placed at T^-1 in the cell (checked in the tests with coal directly).

Travel to the workers. A :class:`~kinredund.geometry.Scene` holds a per-thread ``pin.GeometryData``, which does
not pickle (../shared/STACK.md). :class:`SweepScene` holds what rebuilds it through the Scene's public
methods: its objects (shape, parameters, pose, frame), the ignored pairs, the geometry kind and the self-pair
matrix (a plain dataclass: not recomputed on the workers). Each process rebuilds the scene once per thread
(:meth:`SweepScene.placed`); :func:`sweep_scene` rebuilds it once on the client as well and refuses a scene
that does not rebuild to the same distances (one made with another ``collision_urdf``, ``srdf`` or
``capsule_radius`` than the defaults). A mesh object names its file by an absolute path: a remote worker needs
the file at the same path.
"""

from __future__ import annotations

import hashlib
import pickle
import threading
from dataclasses import dataclass, replace

import numpy as np

from kinredund.errors import KinredundError
from kinredund.geometry import PairMatrix, Scene
from kinredund.model.robot import Robot

#: a rebuilt scene's distances at the robot's home may differ from the original's by this much [m] (the same
#: objects through the same coal calls: round-off only)
REBUILD_TOL = 1e-9


@dataclass(frozen=True)
class SweepScene:
    """A scene in a form that pickles: rebuilt around the job's robot where it is used.

    Attributes:
        robot: the robot's name (the scene's robot).
        geometry: ``"convex"`` or ``"mesh"`` (:class:`~kinredund.geometry.Scene`).
        objects: one (name, shape, params, pose as 16 numbers row by row [m], attach_to) per scene object; world
            objects' poses in the cell (part) frame.
        ignored: the pairs given to ``Scene.ignore``.
        pairs: the self-pair matrix.
        key: a SHA-256 of the rest (which scene a process has built).
    """

    robot: str
    geometry: str
    objects: tuple
    ignored: tuple
    pairs: PairMatrix
    key: str = ""

    def build(self, robot: Robot) -> Scene:
        """A new :class:`~kinredund.geometry.Scene` around ``robot`` with these objects, world objects in the cell."""
        scene = Scene(robot, geometry=self.geometry, pairs=self.pairs)
        for name, shape, params, pose, attach_to in self.objects:
            getattr(scene, f"add_{shape}")(name, **params, attach_to=attach_to)
            scene.move(name, np.reshape(pose, (4, 4)))
        for a, b in self.ignored:
            scene.ignore(a, b)
        return scene

    def placed(self, robot: Robot, pose: np.ndarray) -> Scene:
        """This thread's scene around ``robot`` with the part at ``pose`` (4x4 in the base frame): every world
        object X moved to ``pose @ X`` (module docstring). The scene is this thread's: valid until its next call."""
        cache = getattr(_local, "scene", None)
        if cache is None or cache[0] != self.key or cache[1] is not robot:
            cache = _local.scene = (self.key, robot, self.build(robot))
        scene = cache[2]
        T = np.asarray(pose, dtype=float)
        for name, _, _, X, attach_to in self.objects:
            if attach_to is None:
                scene.move(name, T @ np.reshape(X, (4, 4)))
        return scene

    def describe(self) -> dict:
        """A JSON-ready summary for the sweep file's header: the objects (name, shape, parameters, pose, frame)."""
        return {"robot": self.robot, "geometry": self.geometry, "ignored": [list(p) for p in self.ignored],
                "self_pairs": len(self.pairs.enabled),
                "objects": [{"name": n, "shape": s, **p, "pose": list(X), "attach_to": a}
                            for n, s, p, X, a in self.objects]}


_local = threading.local()


def sweep_scene(scene, robot: Robot) -> SweepScene | None:
    """The :class:`SweepScene` of ``scene`` for a sweep of ``robot`` (None for None), checked once.

    Raises:
        KinredundError: not a Scene, a scene built for another robot, or one that does not rebuild to the
            same distances (module docstring).
    """
    if scene is None:
        return None
    if not isinstance(scene, Scene):
        raise KinredundError(f"scene must be a kinredund Scene (kr.Scene(robot) or kr.load_scene(file, robot)) "
                             f"or None, got {type(scene).__name__}")
    other = scene.robot
    if other is not robot and (other.name != robot.name or other.nq != robot.nq
                               or tuple(other.joint_names) != tuple(robot.joint_names)):
        raise KinredundError(f"the scene was made for robot {other.name!r} ({other.nq} joints), not the swept "
                             f"{robot.name!r} ({robot.nq} joints): load the scene with the swept robot")
    objects = []
    for name in scene.objects:
        obj = scene.object(name)
        objects.append((name, obj.shape, dict(obj.params), tuple(float(v) for v in np.ravel(obj.pose)),
                        obj.attach_to))
    spec = SweepScene(robot.name, scene.geometry, tuple(objects), tuple(scene.ignored), scene.pair_matrix)
    spec = replace(spec, key=hashlib.sha256(pickle.dumps(spec, protocol=4)).hexdigest())
    try:
        rebuilt = spec.build(robot)
    except (KinredundError, OSError) as err:  # a mesh file gone, a frame the robot lacks
        raise KinredundError(f"the scene cannot be rebuilt for the sweep's workers: {err}") from err
    same = rebuilt.pairs == scene.pairs
    if same and scene.pairs:
        a, b = scene.distances(robot.home).distance, rebuilt.distances(robot.home).distance
        same = bool(np.all(np.abs(a - b) <= REBUILD_TOL))
    if not same:
        raise KinredundError("the scene does not rebuild from its objects and pair matrix to the same distances "
                             "(a robot model from a non-default collision_urdf, srdf or capsule_radius): a sweep "
                             "takes scenes of the robot's default collision model")
    return spec
