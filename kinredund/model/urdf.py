"""Robot models: an HD table or a URDF file turned into a Pinocchio model (Chapter 2).

Two routes lead from an :class:`~kinredund.kinematics.hd.HDTable` to Pinocchio: directly (:func:`hd_to_model`)
and through URDF written with yourdfpy (:func:`hd_to_urdf`, then :func:`load_urdf_model`). The tests
check that both give the same forward kinematics. Simple visual shapes (cylinders along the links and
the joint axes) are written into the URDF so that playback shows the HD robots.
"""

from __future__ import annotations

import contextlib
import io
import os
import tempfile
from pathlib import Path

import numpy as np
import pinocchio as pin

from kinredund.errors import URDFError
from kinredund.kinematics.hd import PRISMATIC, HDTable

EE_FRAME = "ee"


def _joint_model(kind: str):
    return pin.JointModelPZ() if kind == PRISMATIC else pin.JointModelRZ()


def hd_to_model(table: HDTable) -> pin.Model:
    """Build a Pinocchio model with one joint per HD row and an end-effector frame named ``ee``."""
    model = pin.Model()
    model.name = table.name
    parent = 0
    placement = pin.SE3.Identity()
    for i in range(table.n):
        jid = model.addJoint(
            parent,
            _joint_model(table.kinds[i]),
            placement,
            f"joint_{i + 1}",
            np.array([1e3]),
            np.array([1e3]),
            np.array([table.lower[i]]),
            np.array([table.upper[i]]),
        )
        model.appendBodyToJoint(jid, pin.Inertia.Zero(), pin.SE3.Identity())
        model.addFrame(pin.Frame(f"link_{i + 1}", jid, pin.SE3.Identity(), pin.FrameType.BODY))
        parent = jid
        placement = pin.SE3(table.fixed_transform(i))
    model.addFrame(pin.Frame(EE_FRAME, parent, placement, pin.FrameType.OP_FRAME))
    return model



def _origin(T: np.ndarray) -> np.ndarray:
    return np.asarray(T, dtype=float).copy()


def _cylinder_between(p0, p1, radius: float, name: str):
    """A yourdfpy cylinder visual from p0 to p1 (in the link frame), or None if they coincide."""
    import yourdfpy

    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    d = p1 - p0
    length = float(np.linalg.norm(d))
    if length < 1e-9:
        return None
    z = d / length
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = 0.5 * (p0 + p1)
    return yourdfpy.Visual(
        name=name,
        origin=T,
        geometry=yourdfpy.Geometry(cylinder=yourdfpy.Cylinder(radius=radius, length=length)),
        material=yourdfpy.Material(name="link"),
    )


def _scale(table: HDTable) -> float:
    reach = float(np.sum(np.abs(table.a)) + np.sum(np.abs(table.b)))
    return max(reach, 1e-3)


def hd_to_urdf(table: HDTable) -> str:
    """Write the HD table as URDF text with yourdfpy (links ``link_i``, joints ``joint_i``, frame ``ee``)."""
    import yourdfpy

    radius = 0.02 * _scale(table)
    links = [yourdfpy.Link(name="base_link", visuals=[])]
    joints = []
    axis_len = 3.0 * radius
    for i in range(table.n):
        visuals = []
        axis = _cylinder_between([0, 0, -axis_len], [0, 0, axis_len], 1.4 * radius, f"axis_{i + 1}")
        visuals.append(axis)
        T = table.fixed_transform(i)
        corner = np.array([0.0, 0.0, table.b[i]])
        for k, (p0, p1) in enumerate([(np.zeros(3), corner), (corner, T[:3, 3])]):
            vis = _cylinder_between(p0, p1, radius, f"link_{i + 1}_{k}")
            if vis is not None:
                visuals.append(vis)
        links.append(yourdfpy.Link(name=f"link_{i + 1}", visuals=visuals))
        origin = np.eye(4) if i == 0 else _origin(table.fixed_transform(i - 1))
        joints.append(
            yourdfpy.Joint(
                name=f"joint_{i + 1}",
                type="prismatic" if table.kinds[i] == PRISMATIC else "revolute",
                parent="base_link" if i == 0 else f"link_{i}",
                child=f"link_{i + 1}",
                origin=origin,
                axis=np.array([0.0, 0.0, 1.0]),
                limit=yourdfpy.Limit(
                    effort=1000.0, velocity=1000.0, lower=float(table.lower[i]), upper=float(table.upper[i])
                ),
            )
        )
    links.append(yourdfpy.Link(name=EE_FRAME, visuals=[]))
    joints.append(
        yourdfpy.Joint(
            name="ee_joint",
            type="fixed",
            parent=f"link_{table.n}",
            child=EE_FRAME,
            origin=_origin(table.fixed_transform(table.n - 1)),
        )
    )
    materials = [yourdfpy.Material(name="link", color=yourdfpy.Color(rgba=np.array([0.9, 0.55, 0.1, 1.0])))]
    robot = yourdfpy.Robot(name=table.name, links=links, joints=joints, materials=materials)
    urdf = yourdfpy.URDF(robot=robot, build_scene_graph=False, load_meshes=False)
    text = urdf.write_xml_string()
    if isinstance(text, bytes):
        text = text.decode()
    import xml.etree.ElementTree as ET

    root = ET.fromstring(text.split("?>", 1)[-1])
    ET.indent(root, space="  ")
    header = (
        "<?xml version='1.0' encoding='utf-8'?>\n"
        f"<!-- generated by `kinredund generate-robots` from the HD table {table.name!r}; do not edit -->\n"
    )
    return header + ET.tostring(root, encoding="unicode") + "\n"


def _capture_stderr_fd(fn):
    """Run ``fn`` while capturing what C++ code prints on file descriptor 2; return (result, text)."""
    with tempfile.TemporaryFile(mode="w+b") as tmp:
        saved = os.dup(2)
        try:
            os.dup2(tmp.fileno(), 2)
            try:
                result = fn()
                error = None
            except Exception as err:  # noqa: BLE001 - re-raised by the caller with the captured reason
                result, error = None, err
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        tmp.seek(0)
        text = tmp.read().decode(errors="replace").strip()
    return result, error, text


def load_urdf_model(path: str | os.PathLike, package_dirs=None) -> tuple[pin.Model, str]:
    """Parse a URDF file with Pinocchio; on failure raise :class:`URDFError` with urdfdom's reason.

    Returns:
        The model and the URDF text.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as err:
        raise URDFError(str(path), f"cannot read the file ({err.strerror})") from err
    try:
        import xml.etree.ElementTree as ET

        root = ET.fromstring(text)
    except ET.ParseError as err:
        raise URDFError(str(path), f"not well-formed XML: {err}") from err
    if root.tag != "robot":
        raise URDFError(str(path), f"the root element is <{root.tag}>, a URDF needs <robot>")

    def build():
        with contextlib.redirect_stderr(io.StringIO()):
            return pin.buildModelFromXML(text)

    model, error, reason = _capture_stderr_fd(build)
    if error is not None:
        detail = reason or str(error)
        raise URDFError(str(path), detail.replace("\n", " ")) from error
    return model, text


def load_urdf_text_model(text: str) -> pin.Model:
    """Parse URDF text with Pinocchio (used to validate generated URDF)."""
    model, error, reason = _capture_stderr_fd(lambda: pin.buildModelFromXML(text))
    if error is not None:
        raise URDFError("<string>", (reason or str(error)).replace("\n", " ")) from error
    return model
