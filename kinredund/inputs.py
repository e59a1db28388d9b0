"""Input files: every file kinredund reads that a user names (a URDF, a record, a path file, a sweep file,
a CSV export, a scene file) goes through :func:`read_input`: a regular file of at most
:data:`MAX_INPUT_BYTES`, else an :class:`~kinredund.errors.InputFileError` naming what it is. A FIFO would
block the reader until something writes to it (a hang), a device such as ``/dev/zero`` never ends (memory
runs out): both are refused before any byte is read. :mod:`kinredund.io` holds the writers.
"""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path

from kinredund.errors import InputFileError, KinredundError

#: [bytes] the largest file kinredund reads: 4x the largest record it writes (errors.MAX_SAMPLES x ~1.2 KB)
MAX_INPUT_BYTES = 2**30
_CHUNK = 2**24  # [bytes] read at a time


def file_kind(mode: int) -> str:
    """What a file of stat mode ``mode`` is, in words (``"a FIFO"``, ``"a directory"``, ...)."""
    for test, name in ((stat.S_ISDIR, "a directory"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def check_regular_file(path, limit: int = MAX_INPUT_BYTES) -> Path:
    """``path`` as a Path if it names a regular file (a symlink to one is fine) of at most ``limit`` bytes.

    Nothing is opened: a FIFO is refused without blocking. :func:`read_input` checks again on the open file
    (the path may change in between); use this to refuse a bad input before any work starts.

    Raises:
        InputFileError: the path is empty, does not exist, cannot be read, is a directory, a FIFO, a device
            or a socket, or is larger than ``limit``.
    """
    if isinstance(path, (str, os.PathLike)) and not str(path).strip():
        raise InputFileError(path, "the path is empty")
    if not isinstance(path, (str, bytes, os.PathLike)):  # os.stat(1) is stdout's file descriptor, True is 1
        raise InputFileError(path, f"not a file path ({type(path).__name__})")
    try:
        st = os.stat(path)
    except (OSError, ValueError) as err:  # ValueError: a NUL byte in the path
        raise InputFileError(path, getattr(err, "strerror", None) or str(err)) from err
    except TypeError as err:
        raise InputFileError(path, f"not a file path ({type(path).__name__})") from err
    _check_input_stat(path, st, limit)
    return Path(path)


def _check_input_stat(path, st: os.stat_result, limit: int) -> None:
    if not stat.S_ISREG(st.st_mode):
        raise InputFileError(path, f"{file_kind(st.st_mode)}: kinredund reads only regular files")
    if st.st_size > limit:
        raise InputFileError(path, f"{st.st_size} bytes, more than the {limit} bytes kinredund reads")


def read_input(path, limit: int = MAX_INPUT_BYTES) -> bytes:
    """The bytes of the regular file ``path``, at most ``limit`` of them (:func:`check_regular_file`).

    The file is opened without blocking (``O_NONBLOCK``: a FIFO does not wait for a writer) and checked on
    the open descriptor, so what is read is the regular file that was checked; reading stops after
    ``limit`` bytes even if the file grows meanwhile.

    Raises:
        InputFileError: see :func:`check_regular_file`; also a file that grew past ``limit`` while read.
    """
    check_regular_file(path, limit)
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except OSError as err:
        raise InputFileError(path, err.strerror or str(err)) from err
    try:
        _check_input_stat(path, os.fstat(fd), limit)
        chunks, size = [], 0
        while size <= limit:  # in chunks: read(limit + 1) would allocate limit + 1 bytes at once
            chunk = os.read(fd, min(_CHUNK, limit + 1 - size))
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
    except OSError as err:
        raise InputFileError(path, err.strerror or str(err)) from err
    finally:
        os.close(fd)
    data = b"".join(chunks)
    if len(data) > limit:
        raise InputFileError(path, f"it grew past the {limit} bytes kinredund reads while it was read")
    return data


def read_text(path: str | Path) -> str:
    """The UTF-8 text of ``path`` (:func:`read_input`); KinredundError (naming the file) if it cannot be read,
    is not a regular file or is not UTF-8."""
    try:
        return read_input(path).decode("utf-8")
    except UnicodeDecodeError as err:
        raise KinredundError(f"{path} is not UTF-8 text (byte {err.start}): a JSON file must be UTF-8") from err


def parse_json(text: str, where) -> object:
    """The JSON value of ``text`` read from ``where`` (a file, a line of one); KinredundError naming ``where``
    if it is not JSON or nests arrays or objects too deeply to read (Python's parser recurses: a
    RecursionError otherwise)."""
    try:
        return json.loads(text)
    except json.JSONDecodeError as err:
        raise KinredundError(f"{where} is not valid JSON: {err}") from err
    except RecursionError as err:
        raise KinredundError(f"{where} nests JSON arrays or objects too deeply to read") from err


def read_json_object(path: str | Path) -> dict:
    """The JSON object in ``path``; KinredundError (naming the file) if unreadable, not JSON or not an object."""
    data = parse_json(read_text(path), path)
    if not isinstance(data, dict):
        raise KinredundError(f"{path} does not hold a JSON object")
    return data
