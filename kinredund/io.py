"""Files: atomic writes (temporary file, then rename) and strict JSON in and out.

Every file kinredund writes goes through :func:`atomic_write`, so no reader ever sees a half-written
file and a failed write leaves nothing behind.

What an output path may be (:func:`check_output_path`, docs/schema.md):

- a new path (its missing folders are created), or an existing regular file, which is replaced;
- a symbolic link to a regular file: the link is followed, the file it points to is replaced and the
  link stays a link; a dangling link, or a link to anything else, is refused;
- anything else (a directory, a device such as ``/dev/null`` or ``/dev/full``, a FIFO, a socket) is
  refused with an :class:`~kinredund.errors.OutputPathError`: it is never replaced by a file.

The temporary file lives next to the (resolved) target, named ``.NAME.XXXX.tmp``, and is removed on
any failure. Inside :func:`output_batch` the renames wait until the batch ends, so the outputs of one
command land together or none does.
"""

from __future__ import annotations

import contextlib
import contextvars
import json
import math
import os
import stat
import tempfile
from pathlib import Path

import numpy as np

from kinredund.errors import KinredundError, OutputPathError

#: the renames waiting for the end of the innermost :func:`output_batch` (None outside one)
_BATCH: contextvars.ContextVar[list | None] = contextvars.ContextVar("kinredund_output_batch", default=None)


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISDIR, "a directory"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def check_output_path(path) -> Path:
    """The file that writing to ``path`` replaces or creates (a symlink resolved), or OutputPathError.

    Nothing is created: a folder that does not exist yet is fine as long as its nearest existing
    ancestor is a folder.

    Raises:
        OutputPathError: ``path`` is empty, a directory, a device, a FIFO or a socket, a dangling symlink,
            or a symlink to one of those, or lies under something that is not a folder.
    """
    if isinstance(path, (str, os.PathLike)) and not str(path).strip():
        raise OutputPathError(path, "the path is empty")
    try:
        path = Path(path)
    except TypeError as err:
        raise OutputPathError(path, f"not a file path ({type(path).__name__})") from err
    target = path
    try:
        if path.is_symlink():
            target = path.resolve()
            if not target.exists():
                raise OutputPathError(path, f"a symbolic link to {str(target)!r}, which does not exist: "
                                            "kinredund follows a link only to an existing regular file")
        st = os.stat(target)
    except FileNotFoundError:
        st = None
    except (OSError, RuntimeError) as err:  # a symlink loop, a path under a file, no permission
        raise OutputPathError(path, getattr(err, "strerror", None) or str(err)) from err
    if st is not None and not stat.S_ISREG(st.st_mode):
        via = f" (through the symbolic link to {str(target)!r})" if target != path else ""
        raise OutputPathError(path, f"{_kind(st.st_mode)}{via}: kinredund writes only a regular file or a new path")
    folder = target.parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if folder.exists() and not folder.is_dir():
        raise OutputPathError(path, f"{str(folder)!r} is not a folder")
    return target


@contextlib.contextmanager
def output_batch():
    """Within it, :func:`atomic_write` writes each file's temporary and renames them all when the block
    ends without an exception; on an exception (KeyboardInterrupt included) every temporary is removed
    and no output appears. Files already written before the batch are untouched either way.
    """
    staged: list[tuple[str, Path]] = []
    token = _BATCH.set(staged)
    try:
        yield
    except BaseException:
        for tmp, _ in staged:
            _remove(tmp)
        raise
    finally:
        _BATCH.reset(token)
    for k, (tmp, target) in enumerate(staged):
        try:
            os.replace(tmp, target)
        except OSError as err:
            for later, _ in staged[k:]:
                _remove(later)
            raise OutputPathError(target, err.strerror or str(err)) from err


def _remove(tmp: str) -> None:
    with contextlib.suppress(FileNotFoundError):
        os.unlink(tmp)


def atomic_write(path: Path, write, mode: str = "w") -> Path:
    """Write a file through a temporary file and a rename, so no reader sees it half-written.

    Args:
        path: the destination (its missing folders are created); see the module docstring for what it
            may be (:func:`check_output_path`).
        write: called with the open temporary file object.
        mode: ``"w"`` (text, UTF-8) or ``"wb"`` (binary).

    Returns:
        ``path`` (as given: a symlink stays the path returned, its target is what is written).

    Raises:
        OutputPathError: a path that is not a regular file or a new one, or the file system refuses the
            write (no permission, a full disk); the temporary file is removed.
    """
    path = Path(path)
    target = check_output_path(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=".tmp")
    except OSError as err:
        raise OutputPathError(path, err.strerror or str(err)) from err
    try:
        with os.fdopen(fd, mode, **({"encoding": "utf-8"} if "b" not in mode else {})) as fh:
            write(fh)
        try:
            perms = stat.S_IMODE(os.stat(target).st_mode)  # replacing a file keeps its permissions
        except FileNotFoundError:
            umask = os.umask(0)
            os.umask(umask)
            perms = 0o666 & ~umask  # mkstemp creates 0600; give a new file the usual permissions
        os.chmod(tmp, perms)
        staged = _BATCH.get()
        if staged is None:
            os.replace(tmp, target)
        else:
            for earlier in [entry for entry in staged if entry[1] == target]:  # the last write of a path wins
                _remove(earlier[0])
                staged.remove(earlier)
            staged.append((tmp, target))
    except OSError as err:
        _remove(tmp)
        raise OutputPathError(path, err.strerror or str(err)) from err
    except BaseException:
        _remove(tmp)
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
        data = json.loads(Path(path).read_bytes().decode("utf-8"))
    except OSError as err:
        raise KinredundError(f"cannot read {path}: {err.strerror}") from err
    except UnicodeDecodeError as err:
        raise KinredundError(f"{path} is not UTF-8 text (byte {err.start}): a JSON file must be UTF-8") from err
    except json.JSONDecodeError as err:
        raise KinredundError(f"{path} is not valid JSON: {err}") from err
    except RecursionError as err:
        raise KinredundError(f"{path} nests JSON arrays or objects too deeply to read") from err
    if not isinstance(data, dict):
        raise KinredundError(f"{path} does not hold a JSON object")
    return data
