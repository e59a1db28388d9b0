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
import threading
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

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
    root = ET.fromstring(text.split("?>", 1)[-1])
    ET.indent(root, space="  ")
    header = (
        "<?xml version='1.0' encoding='utf-8'?>\n"
        f"<!-- generated by `kinredund generate-robots` from the HD table {table.name!r}; do not edit -->\n"
    )
    return header + ET.tostring(root, encoding="unicode") + "\n"


#: file descriptor 2 belongs to the whole process: one capture at a time. Without it, two threads
#: loading robots interleave their dup2 calls and the second restores fd 2 to the first one's deleted
#: temporary file, so everything the process prints on stderr afterwards is lost (issue 26).
_STDERR_LOCK = threading.Lock()


def _capture_stderr_fd(fn):
    """Run ``fn`` while capturing what C++ code prints on file descriptor 2; return (result, error, text).

    Serialised by a process-wide lock (fd 2 is shared by every thread): concurrent callers wait, and fd 2
    always points back at the process's stderr afterwards. While a capture runs, what another thread
    writes to fd 2 lands in the capture.
    """
    with _STDERR_LOCK, tempfile.TemporaryFile(mode="w+b") as tmp:
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


#: the limits [rad] given to a continuous joint turned into a revolute one: finite, so that every
#: difference of limits stays finite, and beyond the 1e10 above which ``Robot.sample_box`` treats a
#: limit as absent
UNBOUNDED_LIMIT = 1e12
_MOVING = ("revolute", "continuous", "prismatic")


class Mimic(NamedTuple):
    """A URDF ``<mimic>`` element: joint = multiplier * master + offset (an immutable value)."""

    master: str
    multiplier: float
    offset: float


@dataclass(frozen=True)
class URDFModel:
    """A parsed URDF: the Pinocchio model, the text it was built from, and facts Pinocchio drops.

    Attributes:
        model: the model; continuous joints are revolute joints with limits +-``UNBOUNDED_LIMIT``.
        text: the URDF text given to Pinocchio (after the continuous joints were rewritten).
        mimic: joint name -> :class:`Mimic`, for every joint with a ``<mimic>`` element.
        continuous: the names of the joints that were continuous in the file.
    """

    model: pin.Model
    text: str
    mimic: dict
    continuous: tuple


def _read_text(path: Path) -> str:
    try:
        data = path.read_bytes()
    except OSError as err:
        raise URDFError(str(path), f"cannot read the file ({err.strerror})") from err
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as err:
        raise URDFError(
            str(path), f"not UTF-8 text (byte 0x{data[err.start]:02x} at offset {err.start}): save it as UTF-8"
        ) from err


def _float_attr(element, name: str, default: float, where: str, path: str) -> float:
    raw = element.get(name)
    if raw is None:
        return default
    try:
        return float(raw)
    except ValueError as err:
        raise URDFError(path, f"{where}: {name}={raw!r} is not a number") from err


def _check_joints(root, path: str) -> dict:
    """Refuse what Pinocchio accepts silently; return the mimic relations.

    - two joints of one name (a closed chain written as a second joint to a link, or a copy-paste slip):
      Pinocchio keeps one of them without a word;
    - two joints with the same child link (a closed chain: URDF describes trees only);
    - a moving joint with a zero axis (the forward kinematics is then not a rigid motion);
    - lower > upper in a joint's ``<limit>``.
    """
    names, children, mimic = set(), {}, {}
    for joint in root.findall("joint"):  # children of <robot>: a <transmission>'s <joint> defines none
        name = joint.get("name")
        if name in names:
            raise URDFError(path, f"two joints are named {name!r} (a closed chain? URDF describes trees only)")
        names.add(name)
        child = joint.find("child")
        link = None if child is None else child.get("link")
        if link in children:
            raise URDFError(
                path, f"link {link!r} is the child of two joints, {children[link]!r} and {name!r}: a closed "
                "chain, which URDF (a tree) cannot describe"
            )
        children[link] = name
        kind = joint.get("type")
        if kind in _MOVING:
            axis = joint.find("axis")
            xyz = "1 0 0" if axis is None or axis.get("xyz") is None else axis.get("xyz")
            try:
                v = np.array([float(x) for x in xyz.split()])
            except ValueError as err:
                raise URDFError(path, f"joint {name!r}: axis {xyz!r} is not three numbers") from err
            if v.shape != (3,) or not np.all(np.isfinite(v)) or np.linalg.norm(v) < 1e-9:
                raise URDFError(path, f"joint {name!r} ({kind}) has axis {xyz!r}: it needs a non-zero finite 3-vector")
        limit = joint.find("limit")
        if limit is not None and kind in ("revolute", "prismatic"):
            where = f"joint {name!r}"
            lo = _float_attr(limit, "lower", 0.0, where, path)
            hi = _float_attr(limit, "upper", 0.0, where, path)
            if lo > hi:
                raise URDFError(path, f"joint {name!r} has lower limit {lo} > upper limit {hi}")
        tag = joint.find("mimic")
        if tag is not None:
            where = f"joint {name!r}: <mimic>"
            mimic[name] = Mimic(
                tag.get("joint", ""), _float_attr(tag, "multiplier", 1.0, where, path),
                _float_attr(tag, "offset", 0.0, where, path),
            )
    for name, m in mimic.items():
        if m.master not in names:
            raise URDFError(path, f"joint {name!r} mimics {m.master!r}, which is not a joint of the file")
    return mimic


def _continuous_as_revolute(root) -> tuple[str, ...]:
    """Rewrite every continuous joint as a revolute one with limits +-UNBOUNDED_LIMIT (in place).

    Pinocchio models a continuous joint by (cos, sin) (nq = 2, nv = 1); as a revolute joint its
    coordinate is the angle itself, so that nq = nv and the drift, limits and plots treat it as every
    other revolute joint. The forward kinematics is the same (same axis and placement).
    """
    names = []
    for joint in root.findall("joint"):
        if joint.get("type") != "continuous":
            continue
        joint.set("type", "revolute")
        limit = joint.find("limit")
        if limit is None:
            limit = ET.SubElement(joint, "limit", {"effort": "0", "velocity": "0"})
        limit.set("lower", repr(-UNBOUNDED_LIMIT))
        limit.set("upper", repr(UNBOUNDED_LIMIT))
        names.append(joint.get("name"))
    return tuple(names)


def load_urdf(path: str | os.PathLike) -> URDFModel:
    """Parse a URDF file with Pinocchio, after the checks Pinocchio does not make.

    Continuous joints become revolute joints without limits (see :data:`UNBOUNDED_LIMIT`).

    Raises:
        URDFError: the file cannot be read, is not UTF-8, is not a URDF, has duplicated joint names, a
            closed chain, a zero joint axis, lower > upper limits, a mimic of a missing joint, or
            Pinocchio (urdfdom) refuses it; the message says which and why.
    """
    path = Path(path)
    text = _read_text(path)
    try:
        root = ET.fromstring(text)
    except ET.ParseError as err:
        raise URDFError(str(path), f"not well-formed XML: {err}") from err
    if root.tag != "robot":
        raise URDFError(str(path), f"the root element is <{root.tag}>, a URDF needs <robot>")
    mimic = _check_joints(root, str(path))
    continuous = _continuous_as_revolute(root)
    if continuous:
        text = ET.tostring(root, encoding="unicode")

    def build():
        with contextlib.redirect_stderr(io.StringIO()):
            return pin.buildModelFromXML(text)

    model, error, reason = _capture_stderr_fd(build)
    if error is not None:
        detail = reason or str(error)
        raise URDFError(str(path), detail.replace("\n", " ")) from error
    return URDFModel(model, text, mimic, continuous)


def load_urdf_model(path: str | os.PathLike, package_dirs=None) -> tuple[pin.Model, str]:
    """:func:`load_urdf`'s model and text (continuous joints as revolute ones).

    Returns:
        The model and the URDF text.
    """
    parsed = load_urdf(path)
    return parsed.model, parsed.text


def load_urdf_text_model(text: str) -> pin.Model:
    """Parse URDF text with Pinocchio (used to validate generated URDF)."""
    model, error, reason = _capture_stderr_fd(lambda: pin.buildModelFromXML(text))
    if error is not None:
        raise URDFError("<string>", (reason or str(error)).replace("\n", " ")) from error
    return model
