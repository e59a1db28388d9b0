"""Files: atomic writes (temporary file, then rename) and strict JSON in and out.

Every file kinredund writes goes through :func:`atomic_write`, so no reader ever sees a half-written
file and a failed write leaves nothing behind.

What an output path may be, and the check of a command's outputs together: :mod:`kinredund.outputs`
(re-exported here); :func:`output_batch` refuses the same overlaps for library callers.

The temporary file lives next to the (resolved) target, named ``.NAME.XXXX.tmp``, and is removed on
any failure. Inside :func:`output_batch` the renames wait until the batch ends, so the outputs of one
command land together or none does; a checkpoint (``atomic_write(..., immediate=True)``: the sweep file,
written as a sweep goes so that an interrupted one can be resumed) is renamed at once, and the batch
lists it in ``kept``. A folder output (a ROS 2 bag) goes the same way through :func:`atomic_write_dir`:
built in a temporary folder, renamed into place with the batch; it never replaces anything.

Every file kinredund reads that a user names (a URDF, a record, a path file, a sweep file, a CSV export)
goes through :func:`kinredund.inputs.read_input` (re-exported here): a regular file of at most
:data:`MAX_INPUT_BYTES`, else an
:class:`~kinredund.errors.InputFileError` naming what it is. A FIFO would block the reader until something
writes to it (a hang), a device such as ``/dev/zero`` never ends (memory runs out): both are refused
before any byte is read.
"""

from __future__ import annotations

import contextlib
import contextvars
import json
import math
import os
import shutil
import stat
import tempfile
from pathlib import Path

import numpy as np

from kinredund.errors import OutputPathError
from kinredund.inputs import (  # noqa: F401  (the readers, here too for their callers)
    MAX_INPUT_BYTES,
    check_regular_file,
    file_kind,
    parse_json,
    read_input,
    read_json_object,
    read_text,
)
from kinredund.outputs import (  # noqa: F401  (the output checks, here too for their callers)
    check_new_folder,
    check_output_path,
    check_outputs,
    file_path,
    output_folder,
    overlap,
    real_path,
)

#: the renames waiting for the end of the innermost :func:`output_batch` (None outside one)
_BATCH: contextvars.ContextVar[Batch | None] = contextvars.ContextVar("kinredund_output_batch", default=None)


class Batch:
    """The outputs of one :func:`output_batch`: ``staged`` (temporary, target) renames waiting for its end,
    ``kept`` the checkpoints already renamed into place (they stay whatever happens)."""

    def __init__(self):
        self.staged: list[tuple[str, Path]] = []
        self.kept: list[Path] = []


@contextlib.contextmanager
def output_batch():
    """Within it, :func:`atomic_write` writes each file's temporary and renames them all when the block
    ends without an exception; on an exception (KeyboardInterrupt included) every temporary is removed
    and no output appears but the checkpoints (``immediate=True``), which the yielded :class:`Batch`
    lists in ``kept``. Files already written before the batch are untouched either way.
    """
    batch = Batch()
    token = _BATCH.set(batch)
    try:
        yield batch
    except BaseException:
        for tmp, _ in batch.staged:
            _remove(tmp)
        raise
    finally:
        _BATCH.reset(token)
    _commit(batch.staged)


def _commit(staged: list[tuple[str, Path]]) -> None:
    """Rename the staged temporaries onto their targets, all or none as far as POSIX allows: each file about to be
    replaced is first kept as a hard link (a copy where the file system has none) beside it; if a rename fails,
    the outputs already renamed are undone (the kept files put back, new paths removed) and every temporary and
    kept file is removed. A crash between two renames can still leave some: POSIX has no multi-file rename.

    Raises:
        OutputPathError: naming the output whose backup or rename the file system refused.
    """
    kept: dict[Path, str] = {}
    done: list[Path] = []
    try:
        for tmp, target in staged:
            if os.path.isfile(target) and not os.path.isdir(tmp):
                failed = target
                kept[target] = _keep(tmp, target)
        for tmp, target in staged:
            failed = target
            _rename(tmp, target)
            done.append(target)
    except OSError as err:
        lost = []
        for target in reversed(done):
            backup = kept.pop(target, None)
            try:
                os.replace(backup, target) if backup else _remove(str(target))
            except OSError:  # the file system refuses even that: say which output is left, and where the old one is
                lost.append(str(target) + (f" (its old content is in {backup})" if backup else ""))
        for tmp, _ in staged:
            _remove(tmp)
        for backup in kept.values():
            _remove(backup)
        outcome = f"could not undo {', '.join(lost)}" if lost else "no output of the batch was written"
        raise OutputPathError(failed, f"{err.strerror or err}; {outcome}") from err
    for backup in kept.values():
        _remove(backup)


def _keep(tmp: str, target: Path) -> str:
    """A second name for the file ``target`` (a hard link, else a copy), next to its temporary ``tmp``."""
    backup = tmp + ".old"
    try:
        os.link(target, backup)
    except FileExistsError:
        raise
    except OSError:
        shutil.copy2(target, backup)
    return backup


def _rename(tmp: str, target: Path) -> None:
    """A file replaces its target; a folder (a temporary folder holding it) takes a path that is free."""
    if not os.path.isdir(tmp):
        os.replace(tmp, target)
        return
    if os.path.lexists(target):
        raise FileExistsError(17, "it appeared while the output was written: not replacing it")
    os.rename(os.path.join(tmp, target.name), target)
    shutil.rmtree(tmp, ignore_errors=True)


def _remove(tmp: str) -> None:
    if os.path.isdir(tmp):
        shutil.rmtree(tmp, ignore_errors=True)
        return
    with contextlib.suppress(FileNotFoundError):
        os.unlink(tmp)


def _stage(tmp: str, target: Path, immediate: bool = False) -> None:
    """Rename now (outside a batch, or a checkpoint) or when the batch ends (the last write of a path wins)."""
    batch = _BATCH.get()
    if batch is None or immediate:
        _rename(tmp, target)
        if batch is not None and target not in batch.kept:
            batch.kept.append(target)
        return
    for earlier in [entry for entry in batch.staged if entry[1] == target]:  # a file written again
        _remove(earlier[0])
        batch.staged.remove(earlier)
    batch.staged.append((tmp, target))


def _check_batch(target: Path, folder: bool) -> None:
    """Refuse (before anything is created) an output of the current batch that would overwrite another:
    a folder output and a file at one real path, or one inside the other. A file written again to the
    same path is fine (the last write wins)."""
    batch = _BATCH.get()
    if batch is None:
        return
    real = real_path(target)
    for tmp, other in batch.staged:
        how = overlap(real, real_path(other))
        if how == "same" and not folder and not os.path.isdir(tmp):
            continue
        if how is not None:
            raise OutputPathError(target, f"it overlaps {str(other)!r}, another output of this command")


def atomic_write_dir(path, build) -> Path:
    """Write a folder output: ``build(folder)`` fills a fresh ``folder`` (a path inside a temporary folder
    next to ``path``, not created yet), which is then renamed to ``path`` (inside :func:`output_batch`, when
    the batch ends). ``path`` must not exist (:func:`check_new_folder`); on any failure nothing is left."""
    path = check_new_folder(path)
    _check_batch(path, folder=True)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = tempfile.mkdtemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as err:
        raise OutputPathError(path, err.strerror or str(err)) from err
    with _removed_on_failure(tmp, path):
        build(Path(tmp) / path.name)
        _stage(tmp, path)
    return path


@contextlib.contextmanager
def _removed_on_failure(tmp: str, path: Path):
    """Remove the temporary ``tmp`` if the block fails; a file-system error becomes OutputPathError(path)."""
    try:
        yield
    except OutputPathError:
        _remove(tmp)
        raise
    except OSError as err:
        _remove(tmp)
        raise OutputPathError(path, err.strerror or str(err)) from err
    except BaseException:
        _remove(tmp)
        raise


def atomic_write(path: Path, write, mode: str = "w", *, immediate: bool = False) -> Path:
    """Write a file through a temporary file and a rename, so no reader sees it half-written.

    Args:
        path: the destination (its missing folders are created); see the module docstring for what it
            may be (:func:`check_output_path`).
        write: called with the open temporary file object.
        mode: ``"w"`` (text, UTF-8) or ``"wb"`` (binary).
        immediate: a checkpoint: renamed at once even inside :func:`output_batch` (listed in its ``kept``).

    Returns:
        ``path`` (as given: a symlink stays the path returned, its target is what is written).

    Raises:
        OutputPathError: a path that is not a regular file or a new one, or the file system refuses the
            write (no permission, a full disk); the temporary file is removed.
    """
    path = Path(path)
    target = check_output_path(path)
    _check_batch(target, folder=False)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=".tmp")
    except OSError as err:
        raise OutputPathError(path, err.strerror or str(err)) from err
    with _removed_on_failure(tmp, path):
        with os.fdopen(fd, mode, **({"encoding": "utf-8"} if "b" not in mode else {})) as fh:
            write(fh)
        try:
            perms = stat.S_IMODE(os.stat(target).st_mode)  # replacing a file keeps its permissions
        except FileNotFoundError:
            umask = os.umask(0)
            os.umask(umask)
            perms = 0o666 & ~umask  # mkstemp creates 0600; give a new file the usual permissions
        os.chmod(tmp, perms)
        _stage(tmp, target, immediate)
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
