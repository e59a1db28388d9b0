"""Output paths: what kinredund writes to, checked before any work (docs/schema.md); :mod:`kinredund.io` writes.

What an output path may be (:func:`check_output_path`):

- a new path (its missing folders are created), or an existing regular file that may be written, which is
  replaced (a write-protected one is refused, though a rename needs only the folder's permission);
- a symbolic link to a regular file: the link is followed, the file it points to is replaced and the
  link stays a link; a dangling link, or a link to anything else, is refused;
- anything else (a directory, a device such as ``/dev/null`` or ``/dev/full``, a FIFO, a socket) is
  refused with an :class:`~kinredund.errors.OutputPathError`: it is never replaced by a file.

The outputs of one command are checked together before any work (:func:`check_outputs`): paths resolved
(``sub/../a.json`` is ``a.json``, a link is its target), two outputs at one path or one inside a folder
output are refused. A folder output (a ROS 2 bag) never replaces anything (:func:`check_new_folder`).
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from kinredund.errors import OutputPathError
from kinredund.inputs import file_kind


def file_path(path) -> Path:
    """``path`` as a Path, refused (OutputPathError) if empty or if it names a folder: a text ending in a
    separator (``out.csv/``), which ``Path`` would silently turn into the file ``out.csv``."""
    if isinstance(path, (str, os.PathLike)) and not str(path).strip():
        raise OutputPathError(path, "the path is empty")
    text = os.fspath(path) if isinstance(path, (str, os.PathLike)) else None
    if isinstance(text, str) and text.endswith(("/", os.sep)):
        raise OutputPathError(path, "it ends with a path separator, so it names a folder: give a file name")
    try:
        return Path(path)
    except TypeError as err:
        raise OutputPathError(path, f"not a file path ({type(path).__name__})") from err


def real_path(path) -> Path:
    """``path`` absolute, with symbolic links, ``.`` and ``..`` resolved (lexically where it does not exist
    yet): two paths write the same place exactly when their real paths are equal."""
    return Path(os.path.realpath(os.fspath(path)))


def check_outputs(outputs) -> dict[str, Path]:
    """The one check of a command's outputs, before any work: each path on its own, then all together.

    Args:
        outputs: (label, path, kind) triples; ``kind`` is ``"file"`` (:func:`check_output_path`) or
            ``"folder"`` (a folder output such as a ROS 2 bag: :func:`check_new_folder`); a None path
            is skipped.

    Returns:
        label -> the real path (:func:`real_path`) each output will occupy.

    Raises:
        OutputPathError: a path refused on its own, or two outputs that would overwrite each other: the
            same real path (``sub/../a.json`` and ``a.json``, a link and its target, a file and a bag),
            or one inside the other (a ``--csv`` inside the ``--bag`` folder).
    """
    seen: dict[str, Path] = {}
    for label, path, kind in outputs:
        if path is None:
            continue
        real = real_path(check_new_folder(path) if kind == "folder" else check_output_path(path))
        for other, where in seen.items():
            how = overlap(real, where)
            if how == "same":
                raise OutputPathError(path, f"{other} and {label} name the same path {str(real)!r}: one "
                                            "would overwrite the other")
            if how is not None:
                mine, theirs = (label, real), (other, where)
                inner, outer = (mine, theirs) if how == "inside" else (theirs, mine)
                raise OutputPathError(path, f"{inner[0]} ({str(inner[1])!r}) lies inside {outer[0]} "
                                            f"({str(outer[1])!r}): give separate paths")
        seen[label] = real
    return seen


def overlap(real: Path, other: Path) -> str | None:
    """How two real paths overlap: ``same``, ``inside`` (real lies inside other), ``contains``, or None."""
    if real == other:
        return "same"
    return "inside" if other in real.parents else "contains" if real in other.parents else None


def check_output_path(path) -> Path:
    """The file that writing to ``path`` replaces or creates (a symlink resolved), or OutputPathError.

    Nothing is created: a folder that does not exist yet is fine as long as its nearest existing
    ancestor is a folder.

    Raises:
        OutputPathError: ``path`` is empty, a directory, a device, a FIFO or a socket, a dangling symlink,
            or a symlink to one of those, a write-protected file (no write bit, or one this user may not write),
            or lies under something that is not a folder.
    """
    path = file_path(path)
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
        raise OutputPathError(path, f"{file_kind(st.st_mode)}{via}: kinredund writes only a regular file or a new path")
    if st is not None and (not st.st_mode & 0o222 or not os.access(target, os.W_OK)):  # a rename would replace it
        raise OutputPathError(path, f"it is write-protected (mode {stat.S_IMODE(st.st_mode):04o}): kinredund does "
                                    "not replace a file you may not write; make it writable or give another path")
    folder = target.parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if folder.exists() and not folder.is_dir():
        raise OutputPathError(path, f"{str(folder)!r} is not a folder")
    return target


def check_new_folder(path) -> Path:
    """``path`` as a Path if nothing exists there (a folder output never replaces anything), else
    OutputPathError."""
    if not os.fspath(path).strip():  # the text given: Path("") would be "." (the current folder)
        raise OutputPathError(path, "the path is empty")
    path = Path(path)
    if path.exists() or path.is_symlink():
        raise OutputPathError(path, "it exists already: give a new folder (a folder output is never overwritten)")
    check_output_path(path)  # a path under a file is refused here
    return path


def output_folder(path) -> Path:
    """The folder ``path`` that a command writes its files into (``demo --out``), created if missing.

    Raises:
        OutputPathError: ``path`` is empty, or exists and is not a folder (a regular file, a device, a
            dangling link), or the folder cannot be created (a path under a file, no permission).
    """
    if not os.fspath(path).strip():  # the text given: Path("") would be "." (the current folder)
        raise OutputPathError(path, "the path is empty")
    path = Path(path)
    if os.path.lexists(path) and not path.is_dir():
        raise OutputPathError(path, "it exists and is not a folder: give a folder (new or existing) for the outputs")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise OutputPathError(path, err.strerror or str(err)) from err
    return path
