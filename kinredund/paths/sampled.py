"""Paths through samples (data, path files): splines of the points and rotations."""

from __future__ import annotations

import numpy as np

from kinredund.errors import PathError, check_array
from kinredund.paths.base import Path, PathSample

#: largest |Q Q^T - 1| entry accepted for a sampled rotation (6 significant digits in a file give ~1e-6)
ROTATION_TOL = 1e-5
#: [m] how far a closed path's last sample may lie from its first (and a planar task's file path from one plane z)
POINT_TOL = 1e-9


def rotation_gaps(Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(largest |Q Q^T - 1| entry, det Q) of each of the rotations Q (..., 3, 3): a rotation matrix, not merely a
    matrix (Rotation.from_matrix would quietly orthonormalise 2 I), has the first <= ROTATION_TOL and the second > 0."""
    return np.abs(Q @ np.swapaxes(Q, -1, -2) - np.eye(3)).max(axis=(-2, -1)), np.linalg.det(Q)


class SampledPath(Path):
    """A path through sampled points (a closed loop when ``closed``), interpolated by cubic splines.

    Positions use a (periodic) cubic spline in time; orientations, when given, scipy's RotationSpline
    (its angular rate is the twist's omega).

    Args:
        t: sample times [s], strictly increasing.
        p: positions, shape (N, 2) or (N, 3) [m] (z = 0 where only x, y are given); kept as ``points`` (N, 3).
        Q: rotations, shape (N, 3, 3), or None.
        closed: the path is periodic with period t[-1] - t[0]; the last sample must equal the first.
    """

    def __init__(self, t, p, Q=None, closed: bool = True):
        from scipy.interpolate import CubicSpline

        if not isinstance(closed, (bool, np.bool_)):
            raise PathError(f"closed must be True or False, got {closed!r}")
        t = check_array(t, (None,), "sample times", PathError)
        if t.shape[0] < 4 or np.any(np.diff(t) <= 0):
            raise PathError("a sampled path needs at least 4 strictly increasing, finite times")
        p = check_array(p, (t.shape[0], None), "sampled positions", PathError)
        if p.shape[1] not in (2, 3):
            raise PathError(f"sampled positions must be finite, of shape ({t.shape[0]}, 2 or 3), got {p.shape}")
        if p.shape[1] == 2:
            p = np.column_stack([p, np.zeros(len(p))])
        if closed and np.abs(p[0] - p[-1]).max() > POINT_TOL:
            raise PathError("a closed sampled path must end where it starts (last sample = first sample)")
        self.points = p  # the samples [m], (N, 3): z = 0 where they were given in x, y only
        self._t0, self._t1 = t[0], t[-1]
        self.period = float(t[-1] - t[0]) if closed else None
        self._spline = CubicSpline(t, p, bc_type="periodic" if closed else "not-a-knot")
        self._rot = None
        self.has_orientation = Q is not None
        if Q is not None:
            from scipy.spatial.transform import Rotation, RotationSpline

            Q = check_array(Q, (t.shape[0], 3, 3), "sampled rotations", PathError)
            # rotations, not merely matrices (Rotation.from_matrix would quietly orthonormalise 2 I): entries
            # read from a file carry ~1e-9 of rounding at most, so ROTATION_TOL leaves room for 6 printed digits
            gap, det = rotation_gaps(Q)
            bad = np.flatnonzero((gap > ROTATION_TOL) | (det <= 0))
            if bad.size:
                k = int(bad[0])
                raise PathError(f"sampled rotation {k} (of {len(Q)}) is not a rotation matrix (orthonormal, det +1): "
                                f"|Q Q^T - 1| = {gap[k]:.3g}, det = {det[k]:.3g}", t=float(t[k]))
            if closed and np.abs(Q[0] - Q[-1]).max() > 1e-9:
                raise PathError("a closed sampled path must end with the rotation it starts with")
            self._rot = RotationSpline(t, Rotation.from_matrix(Q))

    def sample(self, t: float) -> PathSample:
        if self.period is not None:
            t = self._t0 + (t - self._t0) % self.period
        elif not (self._t0 - 1e-12 <= t <= self._t1 + 1e-12):
            raise PathError(f"t = {t:.6g} s is outside the sampled path's times [{self._t0}, {self._t1}]", t=t)
        p, v = self._spline(t), self._spline(t, 1)
        if self._rot is None:
            return PathSample(p, v)
        Q = self._rot(t).as_matrix()
        omega = Q @ self._rot(t, 1)  # RotationSpline's rate is in the body frame
        return PathSample(p, v, Q, omega)


def read_path_file(file) -> tuple[SampledPath, float]:
    """The sampled path of a JSON file (``kinredund track --path file``) and its duration [s].

    The file holds an object with ``t`` (sample times [s], strictly increasing), ``p`` (positions,
    N x 2 or N x 3 [m]), optionally ``Q`` (rotations, N x 3 x 3) and ``closed`` (true or false,
    default true: the last sample must then equal the first). The times are shifted to start at 0,
    where tracking starts.

    Returns:
        The :class:`SampledPath` and its duration t[-1] - t[0] [s] (the period of a closed path; what
        an open path is tracked over).

    Raises:
        KinredundError: the file cannot be read or is not a JSON object; PathError: a missing key, a
            ``closed`` that is not true or false, or samples :class:`SampledPath` rejects.
    """
    from kinredund.io import read_json_object

    data = read_json_object(file)
    if "t" not in data or "p" not in data:
        raise PathError(f"{file} must hold a JSON object with 't' and 'p' (and optionally 'Q' and 'closed')")
    closed = data.get("closed", True)
    if not isinstance(closed, bool):
        raise PathError(f"'closed' in {file} must be true or false, got {closed!r}")
    t = check_array(data["t"], (None,), f"sample times 't' in {file}", PathError)
    if t.size == 0:
        raise PathError(f"'t' in {file} holds no sample time")
    path = SampledPath(t - t[0], data["p"], data.get("Q"), closed=closed)
    return path, float(t[-1] - t[0])
