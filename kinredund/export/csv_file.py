"""CSV export: one row per sample, columns t, q_<joint>..., qdot_<joint>..., qddot_<joint>....

The header names the columns after the robot's joints (``q_panda_joint1``); ``qdot_`` and ``qddot_``
columns are there when the record has velocities and accelerations (a retimed record has both). Numbers
are printed as Python's ``repr`` of the float, the shortest text that reads back to the same double,
so :func:`read_csv` gives back exactly the numbers written. A joint name holding a comma, a quote or a
line break is quoted in the header as RFC 4180 says (Python's ``csv`` module reads it back). Units:
[s], [rad or m], [rad/s or m/s], [rad/s^2 or m/s^2]. The file is written atomically (a temporary file, then a rename).
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from kinredund.errors import KinredundError
from kinredund.export.samples import ExportError, JointSamples
from kinredund.io import atomic_write_text, read_text
from kinredund.outputs import file_path
from kinredund.trajectory import Trajectory

_GROUPS = ("q", "qdot", "qddot")


def write_csv(data: JointSamples | Trajectory, path: str | Path, joint_names=None) -> Path:
    """Write the samples (or a record's: ``joint_names`` default to its robot's) as CSV; return the path.

    Raises:
        ExportError: a record that is not a joint trajectory.
        OutputPathError: ``path`` is not a file path (None, empty, ending in a separator).
    """
    path = file_path(path)  # (None or '' refused before the work, as OutputPathError)
    samples = data.checked() if isinstance(data, JointSamples) else JointSamples.from_trajectory(data, joint_names)
    groups = [g for g in _GROUPS if getattr(samples, g) is not None]
    header = ["t"] + [f"{g}_{name}" for g in groups for name in samples.joint_names]
    table = np.column_stack([samples.t] + [getattr(samples, g) for g in groups])
    text = io.StringIO()
    csv.writer(text, lineterminator="\n").writerow(header)  # a name with a comma, quote or newline is quoted
    text.write("".join(",".join(repr(float(v)) for v in row) + "\n" for row in table))
    atomic_write_text(path, text.getvalue())
    return path


def read_csv(path: str | Path) -> JointSamples:
    """The samples of a CSV file written by :func:`write_csv`.

    Raises:
        ExportError: the file cannot be read, or its header or rows are not those of a kinredund export.
    """
    try:
        with io.StringIO(read_text(path), newline="") as fh:
            lines = [row for row in csv.reader(fh) if row]
    except csv.Error as err:
        raise ExportError(f"cannot read {path}: {err}") from err
    except KinredundError as err:  # not a regular file (a FIFO would hang), unreadable, not UTF-8
        raise ExportError(str(err)) from err
    if len(lines) < 2:
        raise ExportError(f"{path} holds no samples (a header and one row per sample are expected)")
    header = lines[0]
    names = [c[2:] for c in header[1:] if c.startswith("q_")]
    groups = [g for g in _GROUPS if f"{g}_{names[0] if names else ''}" in header]
    expected = ["t"] + [f"{g}_{name}" for g in groups for name in names]
    if not names or header != expected:
        raise ExportError(f"{path} is not a kinredund CSV export: its header must be t, q_<joint>..., then optionally "
                          f"qdot_<joint>... and qddot_<joint>...; got {','.join(header)[:200]!r}")
    try:
        table = np.array([[float(v) for v in line] for line in lines[1:]])
    except ValueError as err:
        raise ExportError(f"{path} has a row that is not numbers: {err}") from err
    if table.ndim != 2 or table.shape[1] != len(header):
        raise ExportError(f"{path}: every row must have {len(header)} numbers, as the header")
    n = len(names)
    arrays = {g: table[:, 1 + k * n: 1 + (k + 1) * n] for k, g in enumerate(groups)}
    return JointSamples(tuple(names), table[:, 0], **arrays).checked()
