"""The trajectory record: what a tracking run produced, step by step (Chapter 4 output).

A :class:`Trajectory` is a frozen record of arrays. Plots, playback, the CLI's ``--json`` output and
the benchmarks read it; nothing downstream recomputes the kinematics it holds. :meth:`Trajectory.checked`
is the one validation of a record (shapes, finite values, increasing times): reading a JSON file, the
plots and the playback all go through it. The diagnostics of a tracking run (``solver``, ``m_eigs``,
``m_null_eigs``, ``normality_residual``) and its per-point figures that the run itself does not read (``lam``,
the task's errors, ``active_bounds``, ``bound_multipliers``, ``limit_margins``) may be handed over as
:class:`Deferred` values: they are computed on first read (together, by whoever made the record) and are
then plain values; pickling, copying, comparing and writing a record read them first. :func:`write_json` (used
by ``save_json``) writes strict JSON through a temporary file and a rename, so a failed run never leaves a
half-written file.

JSON schema (``docs/schema.md`` has the full list): top-level keys are the field names below; arrays
become (nested) lists; ``meta`` is a free-form dict (example name, obstacle, parameters).
"""

from __future__ import annotations

from dataclasses import MISSING, dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from kinredund.errors import (
    JointVectorError,
    KinredundError,
    PathError,
    TaskError,
    check_array,
    check_choice,
    check_positive,
    shown,
)
from kinredund.io import json_ready, read_json_object, write_json
from kinredund.model.robot import NO_LIMIT
from kinredund.tasks import get_task, task_names

SCHEMA_VERSION = 1
#: Optional arrays with one row per recorded point, and their shape after the first axis.
_PER_POINT = {"lam": (None,), "m_eigs": (None,), "m_null_eigs": (None,), "position_error": (),
              "trace_error": (), "vect_error": (), "axis_error": (), "normality_residual": (),
              "active_bounds": (None,), "bound_multipliers": (None,), "limit_margins": (None,)}
#: The names of those optional per-point arrays (functions of the point on the path, not of its time).
PER_POINT_FIELDS = tuple(_PER_POINT)
#: largest joint drift over one loop [rad or m] for which a closed path's record counts as a closed joint
#: path: the default mode holds each point to ~1e-12 (its drift is round-off), and a periodic time law
#: (:mod:`kinredund.retime`) needs the loop closed to this
LOOP_CLOSURE_TOL = 1e-6


def fastest_joint(t: np.ndarray, q: np.ndarray, velocity_limit, qdot: np.ndarray | None = None):
    """The joint that runs fastest against its velocity limit: (ratio, joint, time [s]), or None where no
    joint has a limit (0, non-finite or >= NO_LIMIT in the URDF: none) or the record has one point.

    Speeds are the record's rates ``qdot`` where it has them (a retimed record), else the mean speed
    |q[k+1] - q[k]| / (t[k+1] - t[k]) over each step, what a controller that plays the record at its
    times commands (the time is then the end of that step).
    """
    vmax = np.asarray(velocity_limit, float)
    if vmax.shape != (q.shape[1],) or len(t) < 2:
        return None
    ok = np.isfinite(vmax) & (vmax > 0) & (vmax < NO_LIMIT)
    if not np.any(ok):
        return None
    if qdot is not None:
        ratio, times = np.abs(qdot[:, ok]) / vmax[ok], t
    else:
        ratio, times = (np.abs(np.diff(q, axis=0)) / np.diff(t)[:, None])[:, ok] / vmax[ok], t[1:]
    k, j = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
    return float(ratio[k, j]), int(np.flatnonzero(ok)[j]), float(times[k])


class RecordWarning(UserWarning):
    """A record that ran to its end but is not what was asked: a closed path whose joints do not close,
    joints faster than their velocity limits. The record says so too (:meth:`Trajectory.summary`)."""


class Deferred:
    """A field value computed on first read: ``compute()`` returns it, and the record keeps the result. A
    subclass may stand for several fields of a record at once (:meth:`value_for` then gets each by its name).

    The tracker's recorder hands its diagnostics over this way, so that ``track()`` costs little more
    than its steps and a caller who never reads them never pays for them.
    """

    __slots__ = ("compute",)

    def __init__(self, compute):
        self.compute = compute

    def value_for(self, name: str):
        """The value of the record's field ``name``: ``compute()``'s."""
        return self.compute()


class _DeferrableField:
    """A dataclass field (a data descriptor) whose stored value may be a :class:`Deferred`, resolved and
    kept on first read. The value lives in the instance's ``__dict__`` under the field's own name."""

    def __init__(self, default):
        self.default = default

    def __set_name__(self, owner, name):
        self.name = name

    def __get__(self, obj, owner=None):
        if obj is None:
            return self.default  # the dataclass's default for the field
        try:
            value = obj.__dict__[self.name]
        except KeyError:  # not set yet (a bare object.__new__): what getattr and hasattr expect
            raise AttributeError(f"{type(obj).__name__!r} object has no attribute {self.name!r}") from None
        if isinstance(value, Deferred):
            value = value.value_for(self.name)
            obj.__dict__[self.name] = value
        return value

    def __set__(self, obj, value):
        obj.__dict__[self.name] = value


@dataclass(frozen=True)
class Trajectory:
    """A tracked path.

    Attributes:
        robot: the robot's name (or URDF path) for :func:`kinredund.load_robot`.
        task: the task kind (``planar``, ``position``, ``pose``, ``axis``).
        t: times [s], shape (N,).
        q: joint values, shape (N, n) [rad or m].
        p: end-effector positions reached, shape (N, 3) [m].
        p_desired: positions asked for, shape (N, 3) [m].
        scheme: ``augmented`` (displacement Jacobian), ``velocity`` (velocity Jacobian), ``pseudoinverse``,
            ``liegeois``, ``closed_form``, ``planner``.
        mode: ``default`` or ``thesis``.
        solver: per recorded point, the linear-solver label of its rates (``qp``, ``qp_aug``, ``lu``,
            ``lstsq``), length N: ``solver[0]`` is the start's, ``solver[k]`` the end of step k's.
        lam: Lagrange multipliers per step, shape (N, r), or None.
        m_eigs: eigenvalues of (the symmetric part of) M per step, shape (N, n), or None.
        m_null_eigs: eigenvalues of M projected on the null space of J, shape (N, n - m), or None.
        position_error: |p - p_desired| per step [m].
        trace_error, vect_error: orientation errors in the invariants (Example 4.3), per step (pose tasks).
        axis_error: the angle between the tool axis and the desired one per step [rad] (axis tasks), or None.
        normality_residual: the norm of the first-order normality residual per step (Eq. 4.5).
        loop_drift: joint drift at the end of each loop [rad], revolute joints compared modulo 2 pi.
        loop_period: the period of the closed path [s], or None for open paths.
        active_bounds: per step and joint, -1 at its lower limit, +1 at its upper limit, 0 free, shape
            (N, n), or None (a run without limits).
        bound_multipliers: per step and joint, the multiplier mu >= 0 of its active bound (0 where free),
            shape (N, n), or None.
        limit_margins: per step and joint, the distance to the nearer limit [rad or m] (1e10 where a joint
            has none), shape (N, n), or None.
        switch_times: the times [s] where the active set changed (``meta["switches"]`` says which joint and
            how), or None (times of the run as tracked: a retimed record keeps them as they were).
        qdot: joint velocities, shape (N, n) [rad/s or m/s], or None (a retimed record has them:
            :func:`kinredund.retime.retime`).
        qddot: joint accelerations, shape (N, n) [rad/s^2 or m/s^2], or None.
        meta: free-form parameters (example, index, obstacle, step count, timing).
    """

    robot: str
    task: str
    t: np.ndarray = _DeferrableField(MISSING)  # (required: MISSING is the dataclass's "no default")
    q: np.ndarray
    p: np.ndarray = _DeferrableField(MISSING)
    p_desired: np.ndarray = _DeferrableField(MISSING)
    scheme: str = "augmented"
    mode: str = "default"
    solver: tuple[str, ...] = _DeferrableField(())
    lam: np.ndarray | None = _DeferrableField(None)
    m_eigs: np.ndarray | None = _DeferrableField(None)
    m_null_eigs: np.ndarray | None = _DeferrableField(None)
    position_error: np.ndarray | None = _DeferrableField(None)
    trace_error: np.ndarray | None = _DeferrableField(None)
    vect_error: np.ndarray | None = _DeferrableField(None)
    axis_error: np.ndarray | None = _DeferrableField(None)
    normality_residual: np.ndarray | None = _DeferrableField(None)
    loop_drift: np.ndarray | None = None
    loop_period: float | None = None
    meta: dict = field(default_factory=dict)
    active_bounds: np.ndarray | None = _DeferrableField(None)
    bound_multipliers: np.ndarray | None = _DeferrableField(None)
    limit_margins: np.ndarray | None = _DeferrableField(None)
    switch_times: np.ndarray | None = _DeferrableField(None)
    qdot: np.ndarray | None = None
    qddot: np.ndarray | None = None

    @classmethod
    def assemble(cls, **values) -> Trajectory:
        """``Trajectory(**values)`` made in one step rather than field by field (the recorder makes one per
        ``track()`` run, where a frozen dataclass's ``__init__`` costs several times as much): the same record.

        Raises:
            TypeError: a name that is not a field, or a required field (``robot``, ``task``, ``t``, ``q``, ``p``,
                ``p_desired``) missing, as ``Trajectory(**values)`` would.
        """
        if not _REQUIRED <= values.keys() <= _FIELDS:
            raise TypeError(f"Trajectory fields missing: {sorted(_REQUIRED - values.keys())}, not fields: "
                            f"{sorted(values.keys() - _FIELDS)}")
        obj = object.__new__(cls)
        kept = obj.__dict__  # where __init__ and the deferrable fields keep the values
        kept.update(_DEFAULTS)  # (in the fields' order, as __init__ sets them)
        kept["meta"] = {}
        kept.update(values)
        return obj

    def __getstate__(self) -> dict:
        """Every field's value, :class:`Deferred` ones computed (a pickled record holds no callables)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @property
    def q0(self) -> np.ndarray:
        """The starting configuration."""
        return self.q[0]

    @property
    def loop_closed(self) -> bool | None:
        """Whether the joints return within :data:`LOOP_CLOSURE_TOL` at the end of every loop (None: no
        loops, an open path). A closed path whose record is not closed has ``meta["loop_not_closed"]``,
        the cause, from the tracker (:func:`kinredund.tracking.track`)."""
        if self.loop_drift is None or len(self.loop_drift) == 0:
            return None
        return bool(np.max(self.loop_drift) <= LOOP_CLOSURE_TOL)  # "<=": a NaN drift is not closed

    @property
    def speed_over_limits(self) -> tuple[float, int, float] | None:
        """(ratio, joint, time [s]) of the joint that runs fastest against its URDF velocity limit
        (:func:`fastest_joint`; the tracker records the limits in ``meta["velocity_limit"]``), or None
        where the record has no limits. A ratio above 1 is a motion the arm cannot run at these times:
        retime it (:func:`kinredund.retime.retime`, ``kinredund retime``)."""
        vmax = self.meta.get("velocity_limit") if isinstance(self.meta, dict) else None
        if vmax is None:
            return None
        return fastest_joint(np.asarray(self.t, float), np.asarray(self.q, float), vmax,
                             None if self.qdot is None else np.asarray(self.qdot, float))

    def summary(self) -> dict:
        """Scalar figures: maxima of the errors (None for an error the task does not hold), the drift per
        loop and whether it closes (:attr:`loop_closed`), the fastest joint against its velocity limit
        (``speed_ratio_max``, ``speed_ratio_joint``, ``speed_ratio_t``: :attr:`speed_over_limits`), the
        number of LU steps.

        ``lu_steps`` counts the steps (``solver[1:]``, one label per step; ``solver[0]`` is the start's)
        labelled ``lu``, so a run of 200 steps has at most 200.
        """
        def mx(a):
            return None if a is None or len(a) == 0 else float(np.max(a))

        held = get_task(self.task).error_names  # an error the task does not hold is None, not 0

        def err(name):
            return mx(getattr(self, name)) if name in held else None

        return {
            "steps": int(len(self.t) - 1),
            "position_error_max": mx(self.position_error),
            "trace_error_max": err("trace_error"),
            "vect_error_max": err("vect_error"),
            "axis_error_max": err("axis_error"),
            "normality_residual_max": mx(self.normality_residual),
            "loop_drift": None if self.loop_drift is None else [float(v) for v in self.loop_drift],
            "loop_closed": self.loop_closed,
            **_speed_figures(self.speed_over_limits),
            "lu_steps": int(sum(1 for s in self.solver[1:] if s == "lu")),
        }

    def to_json_dict(self) -> dict:
        """A JSON-ready dict: arrays as lists, plus ``schema_version``, ``q0`` and the summary figures."""
        out = {}
        for f in fields(self):
            v = getattr(self, f.name)
            out[f.name] = json_ready(v)
        out["schema_version"] = SCHEMA_VERSION
        out["robot"] = _absolute_urdf(self.robot)  # `kinredund play` reloads it from any folder
        out["q0"] = json_ready(self.q0)
        out["m_min_eig"] = None if self.m_eigs is None else json_ready(np.min(self.m_eigs, axis=1))
        out.update({k: v for k, v in self.summary().items() if k not in out})
        return out

    def save_json(self, path: str | Path, extra: dict | None = None) -> None:
        """Write the record (and ``extra`` keys) as JSON, atomically (:func:`write_json`)."""
        data = self.to_json_dict()
        if extra:
            data.update(extra)
        write_json(path, data)

    def checked(self, nq: int | None = None) -> Trajectory:
        """The record validated, with its arrays as float numpy arrays (a new record; ``self`` is left as it is).

        Checks: ``t`` a non-empty, finite, strictly increasing 1-D array; ``q`` finite of shape (N, n)
        (n = ``nq`` when given); ``p`` and ``p_desired`` finite of shape (N, 3); each optional per-point
        array (``lam``, ``m_eigs``, ``m_null_eigs``, ``position_error``, ``trace_error``, ``vect_error``,
        ``axis_error``, ``normality_residual``) finite with N rows; ``qdot`` and ``qddot`` None or finite of
        q's shape; ``solver`` empty or N strings; ``loop_drift`` finite and 1-D; ``loop_period`` None or
        > 0; ``task`` a task kind (:func:`kinredund.tasks.task_names`); ``robot`` a string and ``meta`` a dict.

        Raises:
            PathError: bad times, positions or loop figures.
            JointVectorError: q of the wrong shape (for a robot of ``nq`` joints) or not finite.
            TaskError, ChoiceError: a bad per-point array, solver list, robot name, task kind or meta.
        """
        if not isinstance(self.robot, str):
            raise TaskError(f"a trajectory's robot must be a name or URDF path (a string), got {shown(self.robot)}")
        check_choice("trajectory task", self.task, task_names())
        if not isinstance(self.meta, dict):
            raise TaskError(f"a trajectory's meta must be a dict, got {type(self.meta).__name__}")
        t = check_array(self.t, (None,), "trajectory times t [s]", PathError)
        if len(t) == 0:
            raise PathError("trajectory times t [s] must have at least one entry, got none")
        if np.any(np.diff(t) <= 0.0):
            k = int(np.argmax(np.diff(t) <= 0.0))
            raise PathError(f"trajectory times must increase strictly; t[{k + 1}] = {t[k + 1]} <= t[{k}] = {t[k]}",
                            t=float(t[k + 1]))
        with np.errstate(over="ignore"):
            span = float(t[-1] - t[0])
        if not np.isfinite(span):  # t from -1e308 to 1e308: each time finite, the duration not a number
            raise PathError(f"trajectory times span from {t[0]:.6g} s to {t[-1]:.6g} s: the duration overflows "
                            "a float (times must span a finite duration)", t=float(t[-1]))
        n = len(t)
        out = {"t": t, "q": check_array(self.q, (n, nq), "trajectory q", JointVectorError,
                                          f"robot {self.robot!r} (one row per time)")}
        for name in ("p", "p_desired"):
            out[name] = check_array(getattr(self, name), (n, 3), f"trajectory {name} [m]", PathError)
        for name in ("qdot", "qddot"):
            if getattr(self, name) is not None:
                out[name] = check_array(getattr(self, name), out["q"].shape, f"trajectory {name}", JointVectorError,
                                        f"robot {self.robot!r} (q's shape: one row per time)")
        for name, rest in _PER_POINT.items():
            value = getattr(self, name)
            if value is not None:
                out[name] = check_array(value, (n, *rest), f"trajectory {name} (one entry per time)", TaskError)
        if len(self.solver) not in (0, n) or not all(isinstance(s, str) for s in self.solver):
            raise TaskError(f"a trajectory's solver must be empty or {n} labels (one per time), got "
                            f"{len(self.solver)} entries")
        if self.loop_drift is not None:
            out["loop_drift"] = check_array(self.loop_drift, (None,), "trajectory loop_drift [rad]", PathError)
        if self.switch_times is not None:
            out["switch_times"] = check_array(self.switch_times, (None,), "trajectory switch_times [s]", PathError)
        if self.loop_period is not None:
            out["loop_period"] = check_positive(self.loop_period, "trajectory loop_period [s]", PathError)
        return replace(self, solver=tuple(self.solver), **out)

    @classmethod
    def from_json_dict(cls, data: dict) -> Trajectory:
        """Rebuild a record from :meth:`to_json_dict` output, validated by :meth:`checked`.

        Raises:
            KinredundError: a required key is missing, or :meth:`checked` rejects the record.
        """
        names = {f.name for f in fields(cls)}
        missing = [k for k in ("robot", "task", "t", "q", "p", "p_desired") if k not in data]
        if missing:
            raise KinredundError(f"not a kinredund trajectory: missing keys {', '.join(missing)}")
        kw = {k: data[k] for k in names & set(data)}
        if kw.get("meta") is None:
            kw.pop("meta", None)
        if "solver" in kw:
            if not isinstance(kw["solver"], list):
                raise TaskError(f"a trajectory's solver must be a list of labels, got {shown(kw['solver'])}")
            kw["solver"] = tuple(kw["solver"])
        return cls(**kw).checked()

    @classmethod
    def load_json(cls, path: str | Path) -> Trajectory:
        """Read a record written by :meth:`save_json`."""
        return cls.from_json_dict(read_json_object(path))


#: for Trajectory.assemble: the fields, those without a default, and every field's default in the fields' order
#: (MISSING for those without; ``meta``'s factory makes a new dict in assemble)
_FIELDS = frozenset(f.name for f in fields(Trajectory))
_REQUIRED = frozenset(f.name for f in fields(Trajectory) if f.default is MISSING and f.default_factory is MISSING)
_DEFAULTS = {f.name: f.default for f in fields(Trajectory)}


def _speed_figures(fastest) -> dict:
    if fastest is None:
        return {"speed_ratio_max": None, "speed_ratio_joint": None, "speed_ratio_t": None}
    return {"speed_ratio_max": fastest[0], "speed_ratio_joint": fastest[1], "speed_ratio_t": fastest[2]}


__all__ = ["LOOP_CLOSURE_TOL", "PER_POINT_FIELDS", "Deferred", "RecordWarning", "Trajectory", "fastest_joint"]


def _absolute_urdf(robot: str) -> str:
    """A relative URDF path made absolute (against the current folder); a robot name as it is."""
    import os

    if Path(robot).suffix.lower() in (".urdf", ".xml") and not os.path.isabs(robot):
        return os.path.abspath(robot)
    return robot
