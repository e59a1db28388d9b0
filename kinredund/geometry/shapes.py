"""Collision shapes and poses: coal primitives and meshes from validated numbers and files.

Everything here checks its input and raises :class:`~kinredund.errors.GeometryError` naming the object and
what is allowed: sizes are finite and > 0 [m], a pose is a rigid transform (a rotation matrix with
determinant +1 and a translation [m]), a mesh file exists and reads as triangles.

A pose is given as

- ``None`` (the identity), a 3-vector (a position [m], no rotation),
- a 4x4 homogeneous matrix (rotation orthonormal to 1e-6, last row 0 0 0 1),
- a dict ``{"xyz": [x, y, z]}`` [m] with either ``"rpy": [roll, pitch, yaw]`` [rad] (fixed axes x, y, z,
  as URDF: R = Rz(yaw) Ry(pitch) Rx(roll)) or ``"quat": [x, y, z, w]`` (unit to 1e-6), or neither,
- a ``pinocchio.SE3``.
"""

from __future__ import annotations

from pathlib import Path

import coal
import numpy as np
import pinocchio as pin

from kinredund.errors import GeometryError, InputFileError, check_array, check_positive
from kinredund.inputs import check_regular_file

#: the largest departure from orthonormality accepted in a rotation matrix, and from 1 in a quaternion's norm
RIGID_TOL = 1e-6
#: what ``geometry=`` accepts: meshes as convex hulls, or exact (BVH) meshes
GEOMETRY_KINDS = ("convex", "mesh")
#: the mesh file types :func:`load_mesh` reads (through trimesh)
MESH_SUFFIXES = (".stl", ".obj", ".dae", ".ply", ".off", ".glb", ".gltf")


def vector(value, n: int, what: str) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as err:
        raise GeometryError(f"{what} must be {n} numbers, got {value!r}") from err
    if v.shape != (n,) or not np.all(np.isfinite(v)):
        raise GeometryError(f"{what} must be {n} finite numbers, got {value!r}")
    return v


def positive(value, what: str) -> float:
    """``value`` as a float if finite and > 0, else GeometryError naming ``what``."""
    return check_positive(value, what, GeometryError)


def rpy_matrix(rpy: np.ndarray) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll) (URDF's fixed-axis roll, pitch, yaw [rad])."""
    return pin.rpy.rpyToMatrix(*[float(a) for a in rpy])


def to_pose(value, what: str = "pose") -> pin.SE3:
    """A rigid transform from any accepted form (module docstring), or GeometryError saying why not."""
    if value is None:
        return pin.SE3.Identity()
    if isinstance(value, pin.SE3):
        return _checked(value.homogeneous, what)
    if isinstance(value, dict):
        unknown = set(value) - {"xyz", "rpy", "quat"}
        if unknown or ("rpy" in value and "quat" in value):
            raise GeometryError(f"{what}: a pose dict has 'xyz' [m] and at most one of 'rpy' [rad] or 'quat' "
                                f"[x, y, z, w], got keys {sorted(value)}")
        p = vector(value.get("xyz", (0.0, 0.0, 0.0)), 3, f"{what} xyz [m]")
        if "quat" in value:
            x = vector(value["quat"], 4, f"{what} quat [x, y, z, w]")
            if abs(np.linalg.norm(x) - 1.0) > RIGID_TOL:
                raise GeometryError(f"{what} quat must be a unit quaternion [x, y, z, w], norm {np.linalg.norm(x):.9g}")
            x = x / np.linalg.norm(x)  # within RIGID_TOL of unit: made exactly unit
            R = pin.Quaternion(x[3], x[0], x[1], x[2]).toRotationMatrix()
        else:
            R = rpy_matrix(vector(value.get("rpy", (0.0, 0.0, 0.0)), 3, f"{what} rpy [rad]"))
        return pin.SE3(R, p)
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as err:
        raise GeometryError(f"{what} must be a 4x4 matrix, a position, a dict or a pin.SE3, got {value!r}") from err
    if arr.shape == (3,):
        return pin.SE3(np.eye(3), vector(arr, 3, f"{what} position [m]"))
    return _checked(arr, what)


def _checked(T: np.ndarray, what: str) -> pin.SE3:
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise GeometryError(f"{what} must be a finite 4x4 homogeneous matrix (or a position, a dict, a pin.SE3), "
                            f"got shape {T.shape}")
    R = T[:3, :3]
    if (np.max(np.abs(R.T @ R - np.eye(3))) > RIGID_TOL or np.linalg.det(R) < 0
            or np.max(np.abs(T[3] - (0.0, 0.0, 0.0, 1.0))) > 0):
        raise GeometryError(f"{what} is not a rigid transform: its rotation must be orthonormal with determinant +1 "
                            f"(to {RIGID_TOL:g}) and its last row 0 0 0 1")
    U, _, Vt = np.linalg.svd(R)  # within RIGID_TOL of a rotation: the nearest one (polar factor)
    return pin.SE3(U @ Vt, T[:3, 3].copy())


def pose_dict(T: np.ndarray) -> dict:
    """The scene-file form of a 4x4 pose: ``{"xyz": [m], "quat": [x, y, z, w]}``."""
    q = pin.Quaternion(np.asarray(T, dtype=float)[:3, :3])
    return {"xyz": np.asarray(T, dtype=float)[:3, 3].tolist(), "quat": [q.x, q.y, q.z, q.w]}


# -- shapes -----------------------------------------------------------------------------------------
def box(size) -> coal.Box:
    """A box of full side lengths ``size`` = (x, y, z) [m], centred on its frame."""
    s = vector(size, 3, "box size [m]")
    if np.any(s <= 0):
        raise GeometryError(f"box size [m] must be three numbers > 0, got {s.tolist()}")
    return coal.Box(*s)


def sphere(radius) -> coal.Sphere:
    """A sphere of ``radius`` [m] centred on its frame."""
    return coal.Sphere(positive(radius, "sphere radius [m]"))


def cylinder(radius, length) -> coal.Cylinder:
    """A cylinder about its frame's z axis, ``length`` [m] in all, centred on the frame."""
    return coal.Cylinder(positive(radius, "cylinder radius [m]"), positive(length, "cylinder length [m]"))


def capsule(radius, length) -> coal.Capsule:
    """A capsule about its frame's z axis: a segment of ``length`` [m] centred on the frame, swept by ``radius``."""
    return coal.Capsule(positive(radius, "capsule radius [m]"), positive(length, "capsule length [m]"))


def convex(points) -> coal.ConvexBase:
    """The convex hull of ``points`` [m], shape (N, 3), N >= 4 not all in one plane (through qhull)."""
    P = check_array(points, (None, 3), "convex points [m]", GeometryError)
    if len(P) < 4:
        raise GeometryError(f"convex points [m] must number at least 4, got {len(P)}")
    if np.linalg.matrix_rank(P[1:] - P[0], tol=1e-9) < 3:
        raise GeometryError("convex points [m] all lie in one plane (or line): they bound no volume")
    vs = coal.StdVec_Vec3s()
    for p in P:
        vs.append(p)
    return coal.Convex.convexHull(vs, True, "Qt")


def load_mesh(file, scale=1.0, *, convex: bool = True):
    """A mesh file (STL, OBJ, DAE...) read through trimesh as a coal BVH, or its convex hull.

    Args:
        file: the mesh file.
        scale: one factor or three (x, y, z), > 0, applied to the file's vertices (a file in mm: 0.001).
        convex: True for the convex hull (fast distances, never farther than the mesh), False for the exact
            triangles (a BVH; distances are slower, and 0 rather than negative inside).

    Raises:
        GeometryError: the file is missing, not a regular file (a FIFO, a device), larger than
            :data:`kinredund.inputs.MAX_INPUT_BYTES`, of an unknown type, unreadable, or holds no triangles;
            a bad scale.
    """
    import trimesh

    path = Path(file)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise GeometryError(f"mesh file {str(file)!r}: unknown type {path.suffix!r}; "
                            f"allowed: {', '.join(MESH_SUFFIXES)}")
    try:  # a regular file of bounded size: a FIFO would hang trimesh, a huge file exhaust memory
        check_regular_file(path)
    except InputFileError as err:
        why = err.reason if path.exists() else "does not exist"
        raise GeometryError(f"mesh file {str(file)!r}: {why}") from err
    s = np.broadcast_to(np.asarray(scale, dtype=float), (3,)) if np.ndim(scale) == 0 else vector(scale, 3, "scale")
    if not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise GeometryError(f"mesh scale must be one or three finite numbers > 0, got {scale!r}")
    try:
        mesh = trimesh.load(str(path), force="mesh", process=False)
        V = np.asarray(mesh.vertices, dtype=float) * s
        F = np.asarray(mesh.faces, dtype=np.int64)
    except Exception as err:  # noqa: BLE001 - trimesh and its loaders raise many kinds for a corrupt file
        raise GeometryError(f"cannot read mesh file {str(file)!r}: {type(err).__name__}: {err}") from err
    if len(F) == 0 or len(V) < 4 or not np.all(np.isfinite(V)):
        raise GeometryError(f"mesh file {str(file)!r} holds no usable triangles ({len(F)} faces, {len(V)} vertices)")
    bvh = coal.BVHModelOBBRSS()
    bvh.beginModel(len(F), len(V))
    bvh.addVertices(V)
    bvh.addTriangles(F)
    bvh.endModel()
    return as_kind(bvh, "convex" if convex else "mesh")


def as_kind(geom, kind: str):
    """``geom`` as asked: a BVH mesh becomes its convex hull for ``"convex"``; anything else is kept."""
    if kind == "convex" and isinstance(geom, coal.BVHModelBase):
        return convex_hull(geom)
    return geom


def convex_hull(bvh):
    """The convex hull of a BVH mesh's vertices, through qhull (``BVHModelBase.buildConvexHull``).

    Not ``buildConvexRepresentation``: that wraps the mesh's own triangles as a "convex" shape without taking
    the hull, and coal's support function then climbs the mesh's (non-convex) vertex graph and can stop at a
    local maximum: a torus came out 0.26 m farther than its mesh (tests/test_geometry.py).
    """
    try:
        bvh.buildConvexHull(True, "Qt")  # returns whether every vertex is on the hull, not success
    except Exception as err:  # noqa: BLE001 - qhull's errors arrive as RuntimeError or ValueError
        raise GeometryError(f"qhull could not build the convex hull of a mesh (flat or degenerate?): {err}") from err
    if bvh.convex is None or bvh.convex.num_points < 4:
        raise GeometryError("qhull could not build the convex hull of a mesh (flat or degenerate?)")
    return bvh.convex


#: spheres per object in the broadphase: the object's box cut into this many slabs along its longest side
SLABS = 3


def bounding_spheres(geom, placement: pin.SE3, slabs: int = SLABS) -> tuple[np.ndarray, np.ndarray]:
    """(centres in the parent frame [m], shape (slabs, 3); radii [m], shape (slabs,)): spheres whose union
    holds ``geom`` placed at ``placement``.

    The shape's local box is cut into ``slabs`` equal slabs along its longest side and each slab gets the
    sphere through its corners: every point of the shape lies in its box, hence in one slab and its sphere.
    An elongated link gets spheres about a third of one sphere's radius across. A sphere is its own cover.
    """
    if isinstance(geom, coal.Sphere):
        return np.tile(placement.translation, (slabs, 1)), np.full(slabs, float(geom.radius))
    geom.computeLocalAABB()
    lo, hi = np.asarray(geom.aabb_local.min_, dtype=float), np.asarray(geom.aabb_local.max_, dtype=float)
    axis = int(np.argmax(hi - lo))
    cuts = np.linspace(lo[axis], hi[axis], slabs + 1)
    centres = np.tile(0.5 * (lo + hi), (slabs, 1))
    centres[:, axis] = 0.5 * (cuts[:-1] + cuts[1:])
    half = np.tile(0.5 * (hi - lo), (slabs, 1))
    half[:, axis] = 0.5 * np.diff(cuts)
    return (placement.rotation @ centres.T).T + placement.translation, np.linalg.norm(half, axis=1)
