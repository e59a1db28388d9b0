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
from kinredund.ui.viz.meshes import MeshPart, compact_mesh
from kinredund.ui.viz.scene import (
    MAX_FRAMES,
    FloorGrid,
    camera_view,
    floor_grid,
    obstacle_corner_points,
    obstacle_outline,
    read_obstacle,
    resample,
    to_camera_axes,
    unit_cylinder_transform,
)

ROBOT_NODE = "robot"
FLOOR_NODE = "floor"
PATH_COLOR = 0x1F4FE0
TRACER_COLOR = 0x18A040
FLOOR_COLOR = 0x8C96A5
#: Dots of the traced path drawn along one playback, at most.
TRACE_DOTS = 60
OBSTACLE_COLOR = 0x8A3FD0
BACKGROUND_TOP = (0.97, 0.97, 0.98)
BACKGROUND_BOTTOM = (0.78, 0.80, 0.84)


def import_meshcat() -> SimpleNamespace:
    """Import meshcat and Pinocchio's meshcat visualizer, hiding meshcat's zmq DeprecationWarning.

    Raises:
        KinredundError: meshcat is not installed (a core dependency: reinstall kinredund).
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
            raise KinredundError(f"playback needs meshcat (a dependency of kinredund): pip install meshcat ({err})") \
                from err
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
        # what loadViewerModel sets, without its loading: meshes go in compact (mesh_object), the rest
        # through Pinocchio's own loader
        self.viz.viewerRootNodeName = ROBOT_NODE
        self.viz.viewerVisualGroupName = f"{ROBOT_NODE}/visuals"
        self.viz.viewerCollisionGroupName = f"{ROBOT_NODE}/collisions"
        self.viz.display_collisions, self.viz.display_visuals, self.viz.display_frames = False, True, False
        for geom in visual.geometryObjects:
            node = vis[self.viz.getViewerNodeName(geom, pin.GeometryType.VISUAL)]
            if not load_compact(node, geom, mc):
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", UserWarning)  # unsupported shapes are skipped with a warning
                    self.viz.loadViewerGeometryObject(geom, pin.GeometryType.VISUAL)

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


def _packed(array: np.ndarray, item_size: int) -> dict:
    """A typed array as meshcat's msgpack extension (the codes of its viewer: 20 Uint16, 22 Uint32, 23 Float32)."""
    import umsgpack  # meshcat's own msgpack (u-msgpack-python)

    code, name = {np.dtype(np.uint16): (20, "Uint16Array"), np.dtype(np.uint32): (22, "Uint32Array"),
                  np.dtype(np.float32): (23, "Float32Array")}[array.dtype]
    return {"itemSize": item_size, "type": name, "array": umsgpack.Ext(code, np.ascontiguousarray(array).tobytes()),
            "normalized": False}


def _binary_mesh_geometry(mc, part: MeshPart):
    """A meshcat geometry of ``part``'s triangles: float32 corners, 16-bit indices when they fit.

    meshcat's own ``TriangularMeshGeometry`` always sends 32-bit indices; the viewer computes the
    normals of a geometry sent without them.
    """

    class BinaryMesh(mc.geometry.Geometry):
        def lower(self, object_data):
            return {"uuid": self.uuid, "type": "BufferGeometry",
                    "data": {"attributes": {"position": _packed(part.vertices, 3)},
                             "index": _packed(part.faces.reshape(-1), 1)}}

    return BinaryMesh()


def _hex_color(rgba) -> int:
    r, g, b = (int(round(255 * float(np.clip(c, 0.0, 1.0)))) for c in rgba[:3])
    return (r << 16) + (g << 8) + b


def load_compact(node, geom, mc) -> bool:
    """Put the mesh file of the Pinocchio geometry object ``geom`` on ``node`` in compact form.

    One child per colour (:func:`kinredund.ui.viz.meshes.compact_mesh`); a Collada file keeps its own
    colours unless the URDF overrides its material, other formats take the URDF's colour. Returns False
    when the file cannot be read that way (the caller falls back to Pinocchio's loader).
    """
    path = getattr(geom, "meshPath", "")
    parts = compact_mesh(path) if path else None
    if not parts:
        return False
    own_colors = path.lower().endswith(".dae") and not geom.overrideMaterial
    for k, part in enumerate(parts):
        rgba = part.color if own_colors else np.asarray(geom.meshColor, dtype=float)
        material = mc.geometry.MeshPhongMaterial(color=_hex_color(rgba))
        if float(rgba[3]) < 1.0:
            material.transparent, material.opacity = True, float(rgba[3])
        target = node if k == 0 else node[f"part{k}"]
        target.set_object(mc.geometry.Mesh(_binary_mesh_geometry(mc, part), material))
    return True


def _floor_segments(center_xy: np.ndarray, half: float, spacing: float) -> np.ndarray:
    """End points of a square grid's lines on z = 0, as (2 * lines, 3) [m] pairs for ``LineSegments``."""
    ticks = np.arange(-half, half + 0.5 * spacing, spacing)
    segs = []
    for v in ticks:
        segs += [(center_xy[0] + v, center_xy[1] - half, 0.0), (center_xy[0] + v, center_xy[1] + half, 0.0),
                 (center_xy[0] - half, center_xy[1] + v, 0.0), (center_xy[0] + half, center_xy[1] + v, 0.0)]
    return np.array(segs, dtype=np.float32)


def draw_floor(vis, mc, points: np.ndarray) -> FloorGrid:
    """A grid on the plane z = 0 of the robot's base frame, under the scene, replacing meshcat's ``/Grid``.

    meshcat's own grid is a 20 m square: from a camera a metre from the robot, most of its lines have an
    end behind the camera, and such lines are not drawn at all (seen in headless Chromium: a 2 m grid
    draws whole, a 5 m one loses its near lines, the 20 m one keeps only a thin strip near the horizon,
    which the replays showed above the robot; the camera's near plane makes no difference). This grid
    spans the scene's footprint instead (:func:`floor_grid`) and is drawn in the robot's frame, so it
    stays on z = 0 whatever the camera shift.
    """
    grid = floor_grid(points)
    segs = _floor_segments(grid.center, grid.half, grid.spacing)
    g = mc.geometry
    vis["/Grid"].set_property("visible", False)
    vis[FLOOR_NODE].set_object(g.LineSegments(g.PointsGeometry(segs.T), g.LineBasicMaterial(color=FLOOR_COLOR)))
    return grid


def prune_static_tracks(anim) -> int:
    """Drop the animation tracks whose value never changes (a base link, a still obstacle); return how many.

    Such a node keeps the pose set before the animation, so the page loses nothing and gets smaller.
    """
    dropped = 0
    for path in list(anim.clips):
        clip = anim.clips[path]
        for name in list(clip.tracks):
            values = np.asarray(clip.tracks[name].values, dtype=float)
            if len(values) and np.all(np.abs(values - values[0]) <= 1e-12):
                del clip.tracks[name]
                dropped += 1
        if not clip.tracks:
            del anim.clips[path]
    return dropped


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
    draw_floor(vis, mc, np.vstack(scene_points))
    if show_path:
        vis["path/desired"].set_object(_line(mc, traj.p_desired, PATH_COLOR))
        # the traced path as dots over the desired line, so both stay visible where they coincide
        dots = np.asarray(frames.p[:: max(1, len(frames.p) // TRACE_DOTS)], np.float32)
        rgb = np.array([(TRACER_COLOR >> s) & 0xFF for s in (16, 8, 0)], np.float32) / 255.0
        g = mc.geometry  # meshcat's points take per-vertex colours (vertexColors)
        vis["path/traced"].set_object(g.Points(g.PointsGeometry(dots.T, np.tile(rgb, (len(dots), 1)).T),
                                               g.PointsMaterial(size=0.007 * size)))
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
    for node in ("/meshcat", "/Axes"):
        vis[node].set_transform(shift)
    camera = vis["/Cameras/default/rotated/<object>"]
    camera.set_property("position", to_camera_axes(offset))
    vis["/Background"].set_property("top_color", list(BACKGROUND_TOP))
    vis["/Background"].set_property("bottom_color", list(BACKGROUND_BOTTOM))
    distance = float(np.linalg.norm(offset))
    camera.set_property("far", max(100.0, 4.0 * distance))
    camera.set_property("near", min(0.01, 0.01 * distance))

    anim = mc.animation.Animation(default_framerate=fps)
    for k, (clock, q, p) in enumerate(zip(frames.times, frames.q, frames.p, strict=True)):
        # keyframe times are in frames of `fps`; a fractional frame keeps the trajectory's own clock
        key = float(clock * fps) if realtime else k
        with anim.at_frame(vis, key) as frame:
            robot_visuals.display(q, viewer=frame)
            frame["path/tracer"].set_transform(mc.tf.translation_matrix(p))
    prune_static_tracks(anim)
    return anim


def set_animation(vis, anim, loop: bool) -> None:
    """Send the animation, playing; ``loop`` repeats it forever, else it plays once and stops on its last frame."""
    vis.set_animation(anim, play=True, repetitions=math.inf if loop else 1)


def animated_visualizer(traj: Trajectory, robot: Robot | None, *, loop: bool, cell=None, **scene):
    """A new local meshcat server playing ``traj`` (:func:`build_scene` with ``scene``'s options).

    ``robot`` defaults to ``kinredund.load_robot(traj.robot)``; ``cell``, a :class:`kinredund.Scene`, adds its
    objects and the closest pair (:func:`kinredund.ui.viz.cell.draw_cell`). The server is stopped again if the
    scene cannot be built; otherwise the caller stops it (:func:`stop_visualizer`).
    """
    if robot is None:
        from kinredund.model.robot import load_robot

        robot = load_robot(traj.robot)
    vis = start_visualizer()
    try:
        anim = build_scene(vis, traj, robot, **scene)
        if cell is not None:
            from kinredund.ui.viz.cell import draw_cell

            fps, realtime = scene.get("fps", 30.0), scene.get("realtime", True)
            frames = resample(traj.checked(robot.nq), fps, scene.get("max_frames", MAX_FRAMES), realtime)
            keys = [float(c * fps) if realtime else k for k, c in enumerate(frames.times)]  # as build_scene's
            draw_cell(vis, import_meshcat(), cell, frames, anim, keys)
        set_animation(vis, anim, loop=loop)
    except BaseException:
        stop_visualizer(vis)
        raise
    return vis
