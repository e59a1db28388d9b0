"""The meshcat side of playback: the one place that imports meshcat (lazily, in functions).

A scene is built on a :class:`meshcat.Visualizer` (a local server on 127.0.0.1): the robot's URDF
visuals through Pinocchio's ``MeshcatVisualizer``, the desired end-effector path as a line, the
obstacle of ``traj.meta["obstacle"]``, a camera that frames them all, and one
:class:`meshcat.animation.Animation` holding every visual's pose per frame.
"""

from __future__ import annotations

import contextlib
import io
import math
import warnings
from types import SimpleNamespace

import numpy as np

from kinredund.errors import KinredundError, SolverError, URDFError
from kinredund.model.robot import Robot
from kinredund.model.urdf import hd_to_urdf, load_urdf_model, load_urdf_text_model
from kinredund.tasks import get_task
from kinredund.trajectory import Trajectory
from kinredund.ui.viz.scene import (
    MAX_FRAMES,
    camera_view,
    obstacle_corner_points,
    obstacle_outline,
    read_obstacle,
    resample,
    to_camera_axes,
    unit_cylinder_transform,
)

ROBOT_NODE = "robot"
PATH_COLOR = 0x1F4FE0
TRACER_COLOR = 0x18A040
OBSTACLE_COLOR = 0x8A3FD0
BACKGROUND_TOP = (0.97, 0.97, 0.98)
BACKGROUND_BOTTOM = (0.78, 0.80, 0.84)


def import_meshcat() -> SimpleNamespace:
    """Import meshcat and Pinocchio's meshcat visualizer, hiding meshcat's zmq DeprecationWarning.

    Raises:
        KinredundError: meshcat is not installed (``pip install kinredund[viz]``).
    """
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*zmq.eventloop.*", category=DeprecationWarning)
        warnings.filterwarnings("ignore", message=".*is deprecated.*", category=DeprecationWarning)
        try:
            import meshcat
            import meshcat.animation
            import meshcat.geometry
            import meshcat.transformations
            from pinocchio.visualize import MeshcatVisualizer
        except ImportError as err:
            raise KinredundError(f"playback needs meshcat: pip install 'kinredund[viz]' ({err})") from err
    return SimpleNamespace(
        meshcat=meshcat, geometry=meshcat.geometry, animation=meshcat.animation,
        tf=meshcat.transformations, MeshcatVisualizer=MeshcatVisualizer,
    )


def start_visualizer():
    """Start a meshcat server on 127.0.0.1 (zmq and http) and return its ``Visualizer``, quietly.

    Raises:
        SolverError: the server process did not start.
    """
    mc = import_meshcat()
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            return mc.meshcat.Visualizer()
    except (RuntimeError, OSError) as err:
        raise SolverError(f"the meshcat server did not start: {err}") from err


def stop_visualizer(vis) -> None:
    """Kill the server process behind ``vis`` (by its PID) and reap it; close the zmq socket."""
    window = getattr(vis, "window", None)
    if window is None:
        return
    with contextlib.suppress(Exception):
        window.zmq_socket.close(linger=0)
    proc = getattr(window, "server_proc", None)
    if proc is not None and proc.poll() is None:
        proc.kill()
    if proc is not None:
        proc.wait()
        for stream in (proc.stdout, proc.stderr):
            if stream is not None:
                stream.close()


class RobotVisuals:
    """A robot's URDF visuals in a viewer, driven by the robot's joint vector.

    The visuals are parsed from ``robot.urdf_path`` (meshes through ``robot.package_dirs``) into a
    model of their own: for the Panda that model keeps the finger joints that ``load_robot`` drops,
    so joint values are copied across by joint name (the locked joints at ``robot.locked``).
    Robots without a URDF file are drawn from the URDF of their HD table.

    Raises:
        URDFError: the URDF (or its visuals) cannot be parsed, or it lacks one of the robot's joints.
    """

    def __init__(self, robot: Robot, vis, mc: SimpleNamespace):
        import pinocchio as pin

        self.vis = vis
        urdf_path = robot.urdf_path
        if urdf_path is not None:
            source = str(urdf_path)
            model, _ = load_urdf_model(urdf_path)
        elif robot.hd is not None:
            source = f"{robot.name} (URDF of its HD table)"
            text = hd_to_urdf(robot.hd)
            model = load_urdf_text_model(text)
        else:
            raise URDFError(robot.name, "the robot has neither a URDF file nor an HD table to draw")
        try:
            if urdf_path is not None:
                visual = pin.buildGeomFromUrdf(
                    model, source, pin.GeometryType.VISUAL, package_dirs=list(robot.package_dirs)
                )
            else:
                visual = pin.buildGeomFromUrdfString(model, text, pin.GeometryType.VISUAL)
        except ValueError as err:
            raise URDFError(source, f"cannot read its visuals: {err}") from err
        self.index = []
        for name in robot.joint_names:
            if not model.existJointName(name):
                raise URDFError(source, f"the visual model has no joint {name!r}")
            self.index.append(model.joints[model.getJointId(name)].idx_q)
        self.index = np.array(self.index, dtype=int)
        self.neutral = pin.neutral(model)
        for name, value in robot.locked.items():  # the joints load_robot locked sit where it locked them
            if model.existJointName(name) and model.joints[model.getJointId(name)].nq == 1:
                self.neutral[model.joints[model.getJointId(name)].idx_q] = value
        self.viz = mc.MeshcatVisualizer(model, None, visual)
        self.viz.initViewer(viewer=vis)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # unsupported shapes are skipped with a warning
            self.viz.loadViewerModel(rootNodeName=ROBOT_NODE)

    def full_q(self, q: np.ndarray) -> np.ndarray:
        """The visual model's configuration for the robot's joint vector ``q``."""
        out = self.neutral.copy()
        out[self.index] = q
        return out

    def display(self, q: np.ndarray, viewer=None) -> None:
        """Place every visual for ``q``, on ``viewer`` (an animation frame) or on the live viewer."""
        self.viz.viewer = self.vis if viewer is None else viewer
        try:
            self.viz.display(self.full_q(q))
        finally:
            self.viz.viewer = self.vis


def _line(mc, points: np.ndarray, color: int):
    g = mc.geometry
    return g.Line(g.PointsGeometry(np.asarray(points, dtype=np.float32).T), g.LineBasicMaterial(color=color))


def build_scene(
    vis,
    traj: Trajectory,
    robot: Robot,
    *,
    fps: float = 30.0,
    show_path: bool = True,
    max_frames: int = MAX_FRAMES,
    realtime: bool = True,
):
    """Draw the robot, path, obstacle and camera on ``vis``; return the animation.

    Raises:
        JointVectorError, PathError: the trajectory does not fit the robot (:meth:`Trajectory.checked`).
        TaskError, ChoiceError: a malformed obstacle in ``traj.meta`` (read by ``obstacle_from_dict``).
        URDFError: the robot's visuals cannot be read.
    """
    mc = import_meshcat()
    traj = traj.checked(robot.nq)
    frames = resample(traj, fps, max_frames, realtime)
    obstacle = read_obstacle(traj)
    # the joint origins of about 60 frames, the first at the start, frame the camera; the start's and
    # the desired path's extent sizes the tracer
    joints = [robot.kinematics.joint_origins(q) for q in frames.q[:: max(1, len(frames.q) // 60)]]
    size = max(float(np.ptp(np.vstack([joints[0], traj.p_desired]), axis=0).max()), 0.1)
    scene_points = [*joints, traj.p_desired, frames.p, np.zeros((1, 3))]
    if obstacle is not None:
        scene_points.append(obstacle_corner_points(obstacle))

    robot_visuals = RobotVisuals(robot, vis, mc)
    robot_visuals.display(frames.q[0])
    if show_path:
        vis["path/desired"].set_object(_line(mc, traj.p_desired, PATH_COLOR))
    tracer = vis["path/tracer"]
    tracer.set_object(mc.geometry.Sphere(0.015 * size), mc.geometry.MeshLambertMaterial(color=TRACER_COLOR))
    tracer.set_transform(mc.tf.translation_matrix(frames.p[0]))
    if obstacle is not None:
        node = vis["obstacle"]
        node.set_object(
            mc.geometry.Cylinder(1.0, 1.0),
            mc.geometry.MeshLambertMaterial(color=OBSTACLE_COLOR, opacity=0.55, transparent=True),
        )
        node.set_transform(unit_cylinder_transform(obstacle))
        vis["obstacle_outline"].set_object(_line(mc, obstacle_outline(obstacle), OBSTACLE_COLOR))

    center, offset = camera_view(np.vstack(scene_points), planar=get_task(robot.task).planar)
    # meshcat 0.3.2's orbit controls always look at the world origin (whatever the transform of
    # /Cameras/default), so the scene is shifted instead: the centre of attention becomes the origin.
    shift = mc.tf.translation_matrix(-center)
    for node in ("/meshcat", "/Grid", "/Axes"):
        vis[node].set_transform(shift)
    vis["/Cameras/default/rotated/<object>"].set_property("position", to_camera_axes(offset))
    vis["/Background"].set_property("top_color", list(BACKGROUND_TOP))
    vis["/Background"].set_property("bottom_color", list(BACKGROUND_BOTTOM))
    far = max(100.0, 4.0 * float(np.linalg.norm(offset)))
    vis["/Cameras/default/rotated/<object>"].set_property("far", far)

    anim = mc.animation.Animation(default_framerate=fps)
    for k, (clock, q, p) in enumerate(zip(frames.times, frames.q, frames.p, strict=True)):
        # keyframe times are in frames of `fps`; a fractional frame keeps the trajectory's own clock
        key = float(clock * fps) if realtime else k
        with anim.at_frame(vis, key) as frame:
            robot_visuals.display(q, viewer=frame)
            frame["path/tracer"].set_transform(mc.tf.translation_matrix(p))
    return anim


def set_animation(vis, anim, loop: bool) -> None:
    """Send the animation, playing; ``loop`` repeats it forever, else it plays once and stops on its last frame."""
    vis.set_animation(anim, play=True, repetitions=math.inf if loop else 1)


def animated_visualizer(traj: Trajectory, robot: Robot | None, *, loop: bool, **scene):
    """A new local meshcat server playing ``traj`` (:func:`build_scene` with ``scene``'s options).

    ``robot`` defaults to ``kinredund.load_robot(traj.robot)``. The server is stopped again if the
    scene cannot be built; otherwise the caller stops it (:func:`stop_visualizer`).
    """
    if robot is None:
        from kinredund.model.robot import load_robot

        robot = load_robot(traj.robot)
    vis = start_visualizer()
    try:
        set_animation(vis, build_scene(vis, traj, robot, **scene), loop=loop)
    except BaseException:
        stop_visualizer(vis)
        raise
    return vis
