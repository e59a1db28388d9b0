"""Writing the shipped robots' URDF from their HD tables (``kinredund generate-robots``)."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from kinredund.errors import URDFError
from kinredund.io import atomic_write_text, output_folder
from kinredund.kinematics.hd import HDTable
from kinredund.kinematics.state import Kinematics
from kinredund.model.catalog import SHIPPED_TABLES
from kinredund.model.urdf import EE_FRAME, hd_to_model, hd_to_urdf, load_urdf_text_model


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


def generate_robots(out_dir: str | Path) -> list[Path]:
    """Write every shipped robot's URDF into ``out_dir`` (created if missing); return the paths written.

    Raises:
        OutputPathError: ``out_dir`` is empty or exists and is not a folder (:func:`kinredund.io.output_folder`).
    """
    out_dir = output_folder(out_dir)
    written = []
    for name, make in SHIPPED_TABLES.items():
        path = out_dir / f"{name}.urdf"
        atomic_write_text(path, validated_urdf(make()))
        written.append(path)
    return written
