"""The placement record: what a sweep found at one part pose, and the ranking of placements.

A :class:`PlacementRecord` is small and frozen: feasible or why not, and the quality figures of the
run at that placement. Its JSON form (:meth:`PlacementRecord.to_json_dict`) holds Python floats (their
``repr`` round-trips exactly), ``None`` for a figure that does not apply or was not reached, so a
record read back from a sweep file equals the one written.
"""

from __future__ import annotations

import math
import reprlib
from dataclasses import dataclass, fields

from kinredund.errors import KinredundError, check_choice

#: Failure causes the sweep itself gives (a limited tracker's ``TrackingError.cause`` is kept as it is):
#: ``start`` no start configuration at the path's first point (out of reach, or not within the limits),
#: ``path`` the tracker lost the path (it leaves the workspace), ``singularity`` R or J singular,
#: ``limits`` a joint left its limits, ``speed`` a joint exceeded its velocity limit (only with
#: ``speed_limit=True``), ``error`` another kinredund error, ``internal`` an unexpected exception,
#: ``worker`` the Dask worker running the placement was lost.
CAUSES = ("start", "path", "singularity", "limits", "speed", "error", "internal", "worker")

#: criterion -> (record field, True when larger is better)
CRITERIA = {
    "margin": ("limit_margin", True),
    "sigma_min": ("sigma_min", True),
    "speed": ("speed_ratio", False),
    "mean_z": ("mean_z", False),
    "drift": ("loop_drift", False),
}


@dataclass(frozen=True)
class PlacementRecord:
    """The outcome of one placement.

    Attributes:
        placement: its position in the sweep's list of placements.
        pose: the part pose, 16 numbers (the 4x4 transform row by row) [m].
        x, y, z, yaw: the pose's origin [m] and the yaw of its x axis about base z [rad].
        feasible: the whole path was tracked within the joint limits (and, if asked, the joint speeds).
        cause: why not (one of :data:`CAUSES`, or a limited tracker's own cause), None when feasible.
        message: the failure's message ("" when feasible).
        t_fail: the time of the failure on the path [s], None when feasible or before tracking started.
        q_last: the last good configuration of a failed run [rad or m], None when feasible.
        steps: steps tracked (of the run asked for; the partial run's for a failure).
        loop_drift: the largest joint drift at the end of a loop [rad] (revolute joints modulo 2 pi).
        position_error: the largest |p - p_d| along the run [m].
        orientation_error: the largest orientation error: the vect invariant (Example 4.3) of a pose
            task, the tool-axis angle [rad] of an axis task.
        limit_margin: the smallest distance of a joint to its limits along the run [rad or m]; < 0
            outside them.
        sigma_min: the smallest singular value of J along the run (of the task's rows of K, with J's row
            space: ``Task.span_rows``; pose tasks mix [rad/rad] and [m/rad] rows).
        speed_ratio: the largest |thetadot_i| / (velocity limit of joint i) along the run.
        mean_z: the time average of the index z over the loop [rad^2 for joint deviations].
    """

    placement: int
    pose: tuple[float, ...]
    x: float
    y: float
    z: float
    yaw: float
    feasible: bool
    cause: str | None = None
    message: str = ""
    t_fail: float | None = None
    q_last: tuple[float, ...] | None = None
    steps: int = 0
    loop_drift: float | None = None
    position_error: float | None = None
    orientation_error: float | None = None
    limit_margin: float | None = None
    sigma_min: float | None = None
    speed_ratio: float | None = None
    mean_z: float | None = None

    def value(self, criterion: str) -> float | None:
        """The figure ``criterion`` ranks by (see :data:`CRITERIA`), or None."""
        check_choice("sweep criterion", criterion, tuple(CRITERIA))
        return getattr(self, CRITERIA[criterion][0])

    def to_json_dict(self) -> dict:
        """The record as a JSON-ready dict (floats, ints, strings, lists and None only)."""
        out = {}
        for f in fields(self):
            v = getattr(self, f.name)
            out[f.name] = list(v) if isinstance(v, tuple) else v
        return out

    @classmethod
    def from_json_dict(cls, data: dict) -> PlacementRecord:
        """The record of :meth:`to_json_dict`, every field checked (a sweep file may have been edited).

        Raises:
            KinredundError: not an object, a missing or unknown key, or a value of the wrong kind: a
                number that is not finite (JSON readers accept ``NaN``), a bool or string for a number,
                a pose that is not 16 numbers, a negative placement or step count.
        """
        if not isinstance(data, dict):
            raise KinredundError(f"a placement record must be a JSON object, got {reprlib.repr(data)}")
        names = [f.name for f in fields(cls)]
        missing = [k for k in ("placement", "pose", "x", "y", "z", "yaw", "feasible") if k not in data]
        unknown = sorted(set(data) - set(names))
        if missing or unknown:
            raise KinredundError(f"not a placement record: missing keys {missing}, unknown keys {unknown}")
        return cls(**{k: _checked_field(k, v) for k, v in data.items()})


#: the record's fields by the kind of value they hold (``placement`` and ``steps``: counts >= 0)
_NUMBERS = ("x", "y", "z", "yaw")
_OPTIONAL_NUMBERS = ("t_fail", "loop_drift", "position_error", "orientation_error", "limit_margin", "sigma_min",
                     "speed_ratio", "mean_z")


def _finite(key: str, v) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise KinredundError(f"placement record: {key} must be a finite number, got {reprlib.repr(v)}")
    return float(v)


def _checked_field(key: str, v):
    """The value of field ``key`` read from JSON, checked (KinredundError naming the field otherwise)."""
    if key in ("placement", "steps"):
        if isinstance(v, bool) or not isinstance(v, int) or v < 0:
            raise KinredundError(f"placement record: {key} must be an integer >= 0, got {reprlib.repr(v)}")
        return v
    if key == "feasible":
        if not isinstance(v, bool):
            raise KinredundError(f"placement record: feasible must be true or false, got {reprlib.repr(v)}")
        return v
    if key in ("cause", "message"):
        if not (isinstance(v, str) or (v is None and key == "cause")):
            raise KinredundError(f"placement record: {key} must be a string, got {reprlib.repr(v)}")
        return v
    if key in ("pose", "q_last"):
        if v is None and key == "q_last":
            return None
        if not isinstance(v, list) or (key == "pose" and len(v) != 16):
            raise KinredundError(f"placement record: {key} must be a list of {'16 ' if key == 'pose' else ''}"
                                 f"numbers, got {reprlib.repr(v)}")
        return tuple(_finite(key, x) for x in v)
    if v is None and key in _OPTIONAL_NUMBERS:
        return None
    return _finite(key, v)


def clean_float(v) -> float | None:
    """A Python float, or None for None and non-finite values (a record never holds NaN or inf)."""
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None


def best(records, criterion: str = "margin", count: int | None = None) -> list[PlacementRecord]:
    """The feasible placements ranked by ``criterion``, best first (ties keep placement order).

    Args:
        records: placement records (e.g. :func:`kinredund.sweep.sweep`'s result).
        criterion: ``margin`` (largest smallest margin to the joint limits first), ``sigma_min``
            (farthest from singular first), ``speed`` (smallest speed ratio first), ``mean_z`` (smallest
            mean index first) or ``drift`` (smallest loop drift first).
        count: keep the first ``count`` (all by default).

    Raises:
        ChoiceError: an unknown criterion (lists the known ones).
    """
    check_choice("sweep criterion", criterion, tuple(CRITERIA))
    name, larger = CRITERIA[criterion]
    ranked = [r for r in records if r.feasible and getattr(r, name) is not None]
    ranked.sort(key=lambda r: -getattr(r, name) if larger else getattr(r, name))  # sort is stable
    return ranked if count is None else ranked[:count]
