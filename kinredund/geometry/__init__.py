"""Collision geometry: the robot's collision model, the cell's obstacles and their signed distances.

The layer after ``model/`` (docs/architecture.md): :class:`Scene` (the robot, its self-collision pairs and
the cell's objects), :func:`load_scene` / :func:`save_scene` (scene files, docs/schema.md), the self-pair
matrix :class:`PairMatrix`, the records :class:`Distances` and :class:`DistanceRows`, and
:func:`check_motion` (a saved motion's least clearance, :class:`Clearance`). The robot's
collision model comes from its URDF's collision elements through Pinocchio's ``GeometryModel`` and coal
(meshes as convex hulls by default), or capsules for a robot without them.
"""

from kinredund.geometry.collision_model import CAPSULE_RADIUS, RobotGeometry, robot_geometry
from kinredund.geometry.motion import Clearance, check_motion
from kinredund.geometry.pairs import REASONS, PairMatrix, self_pairs
from kinredund.geometry.records import DistanceRows, Distances
from kinredund.geometry.scene import SHAPES, Scene, SceneObject
from kinredund.geometry.scene_file import load_scene, save_scene

__all__ = [
    "CAPSULE_RADIUS", "REASONS", "SHAPES", "Clearance", "DistanceRows", "Distances", "PairMatrix", "RobotGeometry",
    "Scene", "SceneObject", "check_motion", "load_scene", "robot_geometry", "save_scene", "self_pairs",
]
