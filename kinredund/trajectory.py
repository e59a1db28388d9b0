"""The trajectory record: what a tracking run produced, step by step (Chapter 4 output).

A :class:`Trajectory` is a frozen record of arrays. Plots, playback, the CLI's ``--json`` output and
the benchmarks read it; nothing downstream recomputes the kinematics it holds. ``save_json`` writes
through a temporary file and a rename, so a failed run never leaves a half-written file.

JSON schema (``docs/schema.md`` has the full list): top-level keys are the field names below; arrays
become (nested) lists; ``meta`` is a free-form dict (example name, obstacle, parameters).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from .errors import KinredundError

SCHEMA_VERSION = 1


@dataclass(frozen=True)
class Trajectory:
    """A tracked path.

    Attributes:
        robot: the robot's name (or URDF path) for :func:`kinredund.load_robot`.
        task: the task kind (``planar``, ``position``, ``pose``).
        t: times [s], shape (N,).
        q: joint values, shape (N, n) [rad or m].
        p: end-effector positions reached, shape (N, 3) [m].
        p_desired: positions asked for, shape (N, 3) [m].
        scheme: ``augmented`` (displacement Jacobian), ``velocity`` (velocity Jacobian), ``pseudoinverse``,
            ``liegeois``, ``closed_form``, ``planner``.
        mode: ``default`` or ``thesis``.
        solver: per step, the linear solver used (``qp``, ``lu``, ``lstsq``, ...), length N.
        lam: Lagrange multipliers per step, shape (N, r), or None.
        m_eigs: eigenvalues of (the symmetric part of) M per step, shape (N, n), or None.
        m_null_eigs: eigenvalues of M projected on the null space of J, shape (N, n - m), or None.
        position_error: |p - p_desired| per step [m].
        trace_error, vect_error: orientation errors in the invariants (Example 4.3), per step.
        normality_residual: the norm of the first-order normality residual per step (Eq. 4.5).
        loop_drift: joint drift at the end of each loop [rad], revolute joints compared modulo 2 pi.
        loop_period: the period of the closed path [s], or None for open paths.
        meta: free-form parameters (example, index, obstacle, step count, timing).
    """

    robot: str
    task: str
    t: np.ndarray
    q: np.ndarray
    p: np.ndarray
    p_desired: np.ndarray
    scheme: str = "augmented"
    mode: str = "default"
    solver: tuple[str, ...] = ()
    lam: np.ndarray | None = None
    m_eigs: np.ndarray | None = None
    m_null_eigs: np.ndarray | None = None
    position_error: np.ndarray | None = None
    trace_error: np.ndarray | None = None
    vect_error: np.ndarray | None = None
    normality_residual: np.ndarray | None = None
    loop_drift: np.ndarray | None = None
    loop_period: float | None = None
    meta: dict = field(default_factory=dict)

    @property
    def q0(self) -> np.ndarray:
        """The starting configuration."""
        return self.q[0]

    def summary(self) -> dict:
        """Scalar figures: maxima of the errors, the last loop drift, the number of LU steps."""
        def mx(a):
            return None if a is None or len(a) == 0 else float(np.max(a))

        return {
            "steps": int(len(self.t) - 1),
            "position_error_max": mx(self.position_error),
            "trace_error_max": mx(self.trace_error),
            "vect_error_max": mx(self.vect_error),
            "normality_residual_max": mx(self.normality_residual),
            "loop_drift": None if self.loop_drift is None else [float(v) for v in self.loop_drift],
            "lu_steps": int(sum(1 for s in self.solver if s == "lu")),
        }

    def to_json_dict(self) -> dict:
        """A JSON-ready dict: arrays as lists, plus ``schema_version``, ``q0`` and the summary figures."""
        out = {}
        for f in fields(self):
            v = getattr(self, f.name)
            out[f.name] = json_ready(v)
        out["schema_version"] = SCHEMA_VERSION
        out["q0"] = json_ready(self.q0)
        out["m_min_eig"] = None if self.m_eigs is None else json_ready(np.min(self.m_eigs, axis=1))
        out.update({k: v for k, v in self.summary().items() if k not in out})
        return out

    def save_json(self, path: str | Path, extra: dict | None = None) -> None:
        """Write the record (and ``extra`` keys) as JSON, atomically."""
        from .generate import atomic_write_text

        data = self.to_json_dict()
        if extra:
            data.update(json_ready(extra))
        atomic_write_text(Path(path), json.dumps(data, allow_nan=False))

    @classmethod
    def from_json_dict(cls, data: dict) -> Trajectory:
        """Rebuild a record from :meth:`to_json_dict` output."""
        names = {f.name for f in fields(cls)}
        missing = [k for k in ("robot", "task", "t", "q", "p", "p_desired") if k not in data]
        if missing:
            raise KinredundError(f"not a kinredund trajectory: missing keys {', '.join(missing)}")
        kw = {}
        for k in names & set(data):
            v = data[k]
            if k in ("robot", "task", "scheme", "mode", "meta", "loop_period"):
                kw[k] = v
            elif k == "solver":
                kw[k] = tuple(v)
            else:
                kw[k] = None if v is None else np.asarray(v, dtype=float)
        return cls(**kw)

    @classmethod
    def load_json(cls, path: str | Path) -> Trajectory:
        """Read a record written by :meth:`save_json`."""
        return cls.from_json_dict(read_json_object(path))


def json_ready(v):
    """JSON-ready copy of ``v``: arrays to lists, numpy scalars to Python, non-finite floats to None.

    ``json.dumps(json_ready(v), allow_nan=False)`` then always succeeds for numeric content (a NaN
    read back into a float array by :meth:`Trajectory.from_json_dict` is NaN again).
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


def wrap_joints(d, revolute=True) -> np.ndarray:
    """Joint values or differences with the revolute entries brought into [-pi, pi) [rad]."""
    d = np.asarray(d, float)
    return np.where(revolute, (d + np.pi) % (2 * np.pi) - np.pi, d)


def joint_drift(q_start: np.ndarray, q_end: np.ndarray, revolute: np.ndarray) -> float:
    """max |q_end - q_start| with revolute joints compared modulo 2 pi [rad]."""
    return float(np.max(np.abs(wrap_joints(np.asarray(q_end, float) - np.asarray(q_start, float), revolute))))


__all__ = ["Trajectory", "joint_drift", "json_ready", "read_json_object", "wrap_joints"]
