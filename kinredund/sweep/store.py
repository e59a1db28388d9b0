"""Sweep files: the header of a sweep and its placement records, as JSON lines or one JSON object.

A file whose name ends in ``.jsonl`` holds the header object on its first line and one record per
line after it; any other name holds ``{"sweep": header, "records": [...]}``. Records are in placement
order. The file is rewritten whole through :func:`kinredund.io.atomic_write` each time (no reader
ever sees half a file), so a partial file is a valid file with fewer records, and resuming from it and
finishing gives the same bytes as an uninterrupted sweep.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from kinredund.errors import KinredundError
from kinredund.io import atomic_write, parse_json, read_text
from kinredund.sweep.record import PlacementRecord

KIND = "kinredund-sweep"
#: 2 added the clearance fields and the options clearance, clearance_resolution and scene (version-1 files read
#: alike: the new fields are None)
SCHEMA_VERSION = 2


def _dumps(obj) -> str:
    return json.dumps(obj, allow_nan=False, separators=(",", ":"))


def write_sweep_file(path: str | Path, header: dict, records) -> Path:
    """Write ``header`` and ``records`` (in the order given) to ``path`` atomically; return the path.

    A checkpoint: renamed into place at once even inside a command's output batch
    (:func:`kinredund.io.atomic_write` with ``immediate``), so an interrupted sweep can be resumed."""
    path = Path(path)
    rows = [r.to_json_dict() for r in records]
    head = {"kind": KIND, "schema_version": SCHEMA_VERSION, **header}
    if path.suffix == ".jsonl":
        text = "".join(_dumps(x) + "\n" for x in [head, *rows])
    else:
        text = _dumps({"sweep": head, "records": rows}) + "\n"
    atomic_write(path, lambda fh: fh.write(text), immediate=True)
    return path


def read_sweep_file(path: str | Path) -> tuple[dict, list[PlacementRecord]]:
    """(header, records) of a sweep file; KinredundError (naming the file) if it is not one."""
    path = Path(path)
    text = read_text(path)
    if path.suffix == ".jsonl":
        lines = [parse_json(line, f"{path} line {k}") for k, line in enumerate(text.splitlines(), 1) if line.strip()]
        head, rows = (lines[0], lines[1:]) if lines else ({}, [])
    else:
        data = parse_json(text, path)
        head, rows = (data.get("sweep", {}), data.get("records", [])) if isinstance(data, dict) else ({}, [])
    if not isinstance(head, dict) or head.get("kind") != KIND or not isinstance(rows, list):
        raise KinredundError(f"{path} is not a kinredund sweep file (no header of kind {KIND!r})")
    try:
        records = [PlacementRecord.from_json_dict(r) for r in rows]
    except (KinredundError, TypeError) as err:
        raise KinredundError(f"{path}: a bad placement record: {err}") from err
    return head, records


def resumable_records(path: str | Path, header: dict, placements: np.ndarray) -> dict[int, PlacementRecord]:
    """The records of ``path`` a sweep with ``header`` and ``placements`` can keep, by placement number.

    Raises:
        KinredundError: the file belongs to another sweep (another robot, path, index, options, set of
            placements, or a tracker with(out) hard joint limits): resuming from it would mix two sweeps.
    """
    head, records = read_sweep_file(path)
    for key in ("token", "placements"):  # same job (its options included), same placements
        if head.get(key) != header[key]:
            raise KinredundError(
                f"{path} was written by another sweep ({key}: {head.get(key)!r} here, {header[key]!r} now): "
                "resume from its own sweep, or start afresh (resume=False)")
    kept = {}
    for r in records:
        if not (0 <= r.placement < len(placements)) or not np.array_equal(np.reshape(r.pose, (4, 4)),
                                                                           placements[r.placement]):
            raise KinredundError(f"{path}: record of placement {r.placement} does not match this sweep's placement")
        if r.placement in kept:
            raise KinredundError(f"{path}: placement {r.placement} has two records: the file was edited or mixed")
        kept[r.placement] = r
    return kept
