"""Files: atomic writes (temporary file, then rename) and strict JSON in and out.

Every file kinredund writes goes through :func:`atomic_write`, so no reader ever sees a half-written
file and a failed write leaves nothing behind.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np

from kinredund.errors import KinredundError


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


def json_ready(v):
    """JSON-ready copy of ``v``: arrays to lists, numpy scalars to Python, non-finite floats to None.

    ``json.dumps(json_ready(v), allow_nan=False)`` then always succeeds for numeric content. (A
    trajectory record holds finite arrays only: :meth:`Trajectory.from_json_dict` rejects a null in one.)
    """
    if isinstance(v, dict):
        return {str(k): json_ready(x) for k, x in v.items()}
    if isinstance(v, (list, tuple, np.ndarray)):
        return [json_ready(x) for x in v]
    if isinstance(v, (float, np.floating)):
        return float(v) if math.isfinite(v) else None
    if isinstance(v, np.integer):
        return int(v)
    if isinstance(v, np.bool_):
        return bool(v)
    return v


def write_json(path: str | Path, obj, indent: int | None = None) -> Path:
    """Write ``obj`` as strict JSON to ``path`` atomically (temporary file + rename); return the path.

    ``obj`` goes through :func:`json_ready` (arrays to lists, non-finite floats to null) and
    ``json.dumps(..., allow_nan=False)``, so the file never holds ``NaN`` or ``Infinity``.
    """
    path = Path(path)
    atomic_write_text(path, json.dumps(json_ready(obj), allow_nan=False, indent=indent))
    return path


def read_json_object(path: str | Path) -> dict:
    """The JSON object in ``path``; KinredundError (naming the file) if unreadable, not JSON or not an object."""
    try:
        data = json.loads(Path(path).read_text())
    except OSError as err:
        raise KinredundError(f"cannot read {path}: {err.strerror}") from err
    except json.JSONDecodeError as err:
        raise KinredundError(f"{path} is not valid JSON: {err}") from err
    if not isinstance(data, dict):
        raise KinredundError(f"{path} does not hold a JSON object")
    return data
