"""Writing the shipped robots' URDF from their HD tables (``kinredund generate-robots``)."""

from __future__ import annotations

import io
import os
import tempfile
from pathlib import Path

import numpy as np

from .catalog import SHIPPED_TABLES
from .errors import URDFError
from .hd import HDTable
from .kinematics import Kinematics
from .models import EE_FRAME, hd_to_model, hd_to_urdf, load_urdf_text_model


def atomic_write(path: Path, write, mode: str = "w") -> Path:
    """Write a file through a temporary file and a rename, so no reader sees it half-written.

    Args:
        path: the destination (its folder is created).
        write: called with the open temporary file object.
        mode: ``"w"`` (text) or ``"wb"`` (binary).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, mode) as fh:
            write(fh)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600; give the file the usual permissions
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (see :func:`atomic_write`)."""
    atomic_write(path, lambda fh: fh.write(text), "w")


def validated_urdf(table: HDTable, rng_seed: int = 0, samples: int = 5) -> str:
    """URDF text for ``table``, validated with yourdfpy and Pinocchio against the direct model.

    Raises:
        URDFError: the generated text does not validate, or its forward kinematics differ from the
            HD product (Eq. 2.3) by more than 1e-12.
    """
    import yourdfpy

    text = hd_to_urdf(table)
    parsed = yourdfpy.URDF.load(io.BytesIO(text.encode()), load_meshes=False, build_collision_scene_graph=False)
    if not parsed.validate():
        raise URDFError(table.name, "yourdfpy does not validate the generated URDF")
    model = load_urdf_text_model(text)
    direct = hd_to_model(table)
    rng = np.random.default_rng(rng_seed)
    from_urdf, from_hd = Kinematics(model, model.getFrameId(EE_FRAME)), Kinematics(direct, direct.getFrameId(EE_FRAME))
    for _ in range(samples):
        q = rng.uniform(table.lower, table.upper)
        (Q1, p1), (Q2, p2) = from_urdf.pose(q), from_hd.pose(q)
        err = max(np.abs(Q1 - Q2).max(), np.abs(p1 - p2).max())
        if err > 1e-12:
            raise URDFError(table.name, f"URDF and HD forward kinematics differ by {err:.3g}")
    return text


def generate_robots(out_dir: Path) -> list[Path]:
    """Write every shipped robot's URDF into ``out_dir``; return the paths written."""
    written = []
    for name, make in SHIPPED_TABLES.items():
        path = Path(out_dir) / f"{name}.urdf"
        atomic_write_text(path, validated_urdf(make()))
        written.append(path)
    return written
