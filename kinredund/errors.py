"""The exception family of kinredund.

Every error raised on bad input derives from :class:`KinredundError`. Subclasses carry the offending
value and, where there is a finite set of valid choices, the list of them, so that callers (and the
command line) can report precisely what is wrong and what is allowed.
"""

from __future__ import annotations

import os
from collections.abc import Sequence


class KinredundError(Exception):
    """Base class of every error kinredund raises on purpose."""

    def __reduce__(self):  # (an __init__ of other arguments than the message could not be called with its args)
        return _rebuilt, (type(self), self.args, self.__dict__)


def _rebuilt(cls: type, args: tuple, fields: dict) -> KinredundError:
    """An error of ``cls`` unpickled with its ``args`` and its fields, without calling its ``__init__``: a subclass
    taking (what, value, allowed) or (path, reason) would be called with its message alone and fail, which broke
    :func:`~kinredund.tracking.many.track_many`'s worker processes."""
    err = cls.__new__(cls, *args)
    err.args = args
    err.__dict__.update(fields)
    return err


def shown(value) -> str:
    """``repr(value)`` shortened for a message (long strings, lists and arrays cut with ``...``): a value read
    from a file can be of any size, and a message must stay readable."""
    import reprlib

    r = reprlib.Repr()
    r.maxstring, r.maxother, r.maxlist, r.maxtuple, r.maxdict = 200, 200, 12, 12, 12
    return r.repr(value)


class UnknownRobotError(KinredundError, KeyError):
    """A robot name that is neither shipped, nor in example-robot-data, nor an existing file."""

    def __init__(self, name: str, known: Sequence[str]):
        self.name = name
        self.known = list(known)
        super().__init__(
            f"unknown robot {name!r}: not a file, and not one of the known names {', '.join(self.known)}"
        )

    def __str__(self) -> str:  # KeyError would quote the message
        return self.args[0]


class URDFError(KinredundError, ValueError):
    """A URDF that cannot be parsed or turned into a model; ``reason`` says why."""

    def __init__(self, path: str, reason: str):
        self.path = path
        self.reason = reason
        super().__init__(f"cannot load URDF {path!r}: {reason}")


class FrameNotFoundError(KinredundError, KeyError):
    """An end-effector frame name that the model does not have; ``frames`` lists those it has."""

    def __init__(self, frame: str, frames: Sequence[str], note: str = ""):
        self.frame = frame
        self.frames = list(frames)
        tail = f" ({note})" if note else ""
        super().__init__(f"no frame {frame!r} in the model; its frames are: {', '.join(self.frames)}{tail}")

    def __str__(self) -> str:
        return self.args[0]


class HDTableError(KinredundError, ValueError):
    """A Hartenberg-Denavit table with wrong shapes, non-finite values or unknown joint kinds."""


class JointVectorError(KinredundError, ValueError):
    """A joint vector of the wrong length, or with non-finite entries."""


class TaskError(KinredundError, ValueError):
    """A task or target that does not fit the robot (wrong size, non-finite, unknown task kind)."""


class ChoiceError(KinredundError, ValueError):
    """A string option that is not one of the allowed choices."""

    def __init__(self, what: str, value: object, allowed: Sequence[str]):
        self.what = what
        self.value = value
        self.allowed = list(allowed)
        super().__init__(f"unknown {what} {shown(value)}; allowed: {', '.join(self.allowed)}")


class GeometryError(KinredundError, ValueError):
    """A collision shape, pose, mesh file or scene that cannot be used (a negative size, a pose that is not a
    rigid transform, a missing or unreadable mesh); the message names the object and what is allowed."""


class SingularityError(KinredundError, ArithmeticError):
    """A (kinematic or algorithmic) singularity met by a solver; fields say where."""

    def __init__(self, message: str, *, t: float | None = None, q=None, sigma_min: float | None = None):
        self.t = t
        self.q = None if q is None else [float(v) for v in q]
        self.sigma_min = sigma_min
        super().__init__(message)


class PathError(KinredundError, ValueError):
    """A path that is malformed, non-finite or leaves the workspace; fields say where."""

    def __init__(self, message: str, *, t: float | None = None, q=None):
        self.t = t
        self.q = None if q is None else [float(v) for v in q]
        super().__init__(message)


class SolverError(KinredundError, RuntimeError):
    """A numerical backend failed in a way that is not the user's input."""


class OptionError(KinredundError, ValueError):
    """A numeric option outside its allowed range (the message names the option and the range)."""


class TrackingError(SingularityError, PathError, RuntimeError):
    """A tracking run stopped: why, when, the last good state and the record up to there.

    A subclass of :class:`SingularityError` and :class:`PathError` (multiple inheritance), so callers that
    caught the tracker's failures as those still catch them; input errors (a malformed or non-finite path,
    an option out of range) keep their own classes and are never a TrackingError.

    Attributes:
        cause: one of :attr:`CAUSES`: ``kinematic_singularity`` (J loses rank: a stretched or folded arm),
            ``fold`` (the smallest eigenvalue of the reduced Hessian Z^T M Z reaches zero: the local optimum
            of z ceases to exist, or a step jumped to another branch), ``out_of_reach`` (the path leaves the
            workspace: the task residual cannot be driven to zero), ``limits_infeasible`` (the path cannot be
            followed within the joint limits, or the start is outside them), ``step_control_exhausted`` (the
            corrector failed down to the smallest sub-step with no other cause found), ``non_optimal_start``
            (the start is on the path but cannot be corrected onto a constrained minimum),
            ``step_too_long`` (a time step longer than the path's period), ``not_strongly_stable`` (the
            constrained optimum loses linear independence of the active constraints or second-order
            sufficiency), ``switch_not_resolved`` (a switching time of the active set could not be located),
            ``path_discontinuity`` (the path itself jumps: the joints cannot follow it continuously),
            ``collision`` (a clearance constraint cannot be held: the start violates it, or the run stops
            with it active; ``watched["constraints"]`` names it, ``watched["underlying_cause"]`` says how).
            ``path_inconsistent`` (the path's velocity or angular velocity is not the derivative of its
            position or rotation: a self-contradictory path, e.g. a FunctionPath returning a wrong v).
        t: the time [s] of the last good state.
        q: the last good configuration (on the path, inside the limits) as a float array, or None.
        watched: the watched quantities there (``sigma_min_J``, ``reduced_hessian_min``, ...: floats and lists).
        partial: the :class:`~kinredund.trajectory.Trajectory` up to ``t`` (on the requested times), or None.
        sigma_min: the field of :class:`SingularityError`: ``watched["sigma_min_R"]`` (R's smallest singular
            value, where an R singular at the failure reported it), else ``watched["sigma_min_J"]``, else None.
    """

    CAUSES = ("kinematic_singularity", "fold", "out_of_reach", "limits_infeasible", "step_control_exhausted",
              "non_optimal_start", "step_too_long", "not_strongly_stable", "switch_not_resolved",
              "path_discontinuity", "collision", "path_inconsistent")

    def __init__(self, message: str, *, cause: str, t: float | None = None, q=None, watched: dict | None = None,
                 partial=None):
        import numpy as np

        if cause not in self.CAUSES:
            raise ChoiceError("tracking failure cause", cause, self.CAUSES)
        self.cause = cause
        self.t = None if t is None else float(t)
        self.q = None if q is None else np.array(q, dtype=float)
        self.watched = dict(watched or {})
        self.partial = partial
        self.sigma_min = self.watched.get("sigma_min_R", self.watched.get("sigma_min_J"))
        Exception.__init__(self, message)  # (pickled with its fields: KinredundError.__reduce__)


def check_array(value, shape: tuple, what: str, error: type[KinredundError] = TaskError, owner: str = ""):
    """Return ``value`` as a finite float array of ``shape``, or raise ``error`` saying what is wrong.

    Args:
        value: anything numpy can read as numbers.
        shape: the required shape; ``None`` in an axis accepts any length there.
        what: the name used in the message (e.g. ``"wrist-centre position [m]"``).
        error: the exception class (of the kinredund family) to raise.
        owner: appended to the shape message as ``for {owner}`` (e.g. the robot's name).
    """
    import numpy as np

    arr = _real_array(value, what, error)
    if arr.ndim != len(shape) or any(w is not None and g != w for g, w in zip(arr.shape, shape, strict=True)):
        want = "(" + ", ".join("n" if w is None else str(w) for w in shape) + ("," if len(shape) == 1 else "") + ")"
        raise error(f"{what} must have shape {want}{f' for {owner}' if owner else ''}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise error(f"{what} has non-finite entries: {describe_non_finite(arr)}")
    return arr


def describe_non_finite(arr) -> str:
    """Where ``arr``'s non-finite entries are, in a message of bounded length: how many, the first's index and
    value (a record of a million points with one NaN gave a 77 MB message that did not say where)."""
    import numpy as np

    bad = ~np.isfinite(arr)
    first = tuple(int(i) for i in np.argwhere(bad)[0])
    where = first[0] if len(first) == 1 else first
    listed = f"; all: {arr.tolist()}" if arr.size <= 12 else ""
    return f"{int(bad.sum())} of {arr.size}, the first at index {where} ({arr[first]}){listed}"


def _real_array(value, what: str, error: type[KinredundError]):
    """``value`` as a float array, refusing what numpy would quietly turn into numbers: booleans, strings
    (``"1"``), complex values (numpy drops the imaginary part with a warning) and non-numeric objects."""
    import numpy as np

    try:
        raw = np.asarray(value)
        kind = raw.dtype.kind
        if not isinstance(value, np.ndarray) and kind in "iufO":  # [True, 0, 1] is an int array to numpy
            kind = next((_kind_of(v) for v in _leaves(value) if _kind_of(v) != "f"), kind)
        if kind == "b":
            raise error(f"{what} must be numbers, not booleans; got {shown(value)}")
        if kind == "c":
            raise error(f"{what} must be real numbers, got complex values {shown(value)} (pass the real part)")
        if kind not in "iufO":
            raise error(f"{what} must be numeric, got {shown(value)}")
        return raw.astype(float) if kind == "O" else np.asarray(raw, dtype=float)
    except (TypeError, ValueError, OverflowError) as err:
        if isinstance(err, KinredundError):
            raise
        raise error(f"{what} must be numeric, got {shown(value)}") from err


def _leaves(value):
    """The scalars of nested lists and tuples (numpy arrays inside are taken as they are)."""
    if isinstance(value, (list, tuple)):
        for v in value:
            yield from _leaves(v)
    else:
        yield value


def _kind_of(v) -> str:
    """'b' for a boolean, 'c' complex, 'U' a string or bytes, else 'f' (numpy judges the rest)."""
    import numpy as np

    if isinstance(v, (bool, np.bool_)):
        return "b"
    if isinstance(v, (complex, np.complexfloating)):
        return "c"
    if isinstance(v, (str, bytes)):
        return "U"
    if isinstance(v, np.ndarray) and v.dtype.kind in "bcUS":
        return "c" if v.dtype.kind == "c" else "b" if v.dtype.kind == "b" else "U"
    return "f"


def check_positive(value, what: str, error: type[KinredundError] = TaskError) -> float:
    """Return ``value`` as a float if it is a finite number > 0, else raise ``error`` naming ``what``."""
    import math

    if isinstance(value, (str, bytes, bool)):
        raise error(f"{what} must be a finite number > 0, got {value!r}")
    try:
        arr = _real_array(value, what, error)  # no numpy booleans or complex values either
        if arr.ndim:
            raise TypeError("not a scalar")
        v = float(arr)
    except (TypeError, KinredundError) as err:
        raise error(f"{what} must be a finite number > 0, got {value!r}") from err
    if not (math.isfinite(v) and v > 0):
        raise error(f"{what} must be a finite number > 0, got {value!r}")
    return v


def check_count(value, minimum: int, what: str, error: type[KinredundError] = TaskError) -> int:
    """Return ``value`` as an int if it is an integer (not a bool, not a float) >= ``minimum``, else raise."""
    if type(value) is int and value >= minimum:  # the common case, without the abstract class's check below
        return value
    from numbers import Integral

    if isinstance(value, bool) or not isinstance(value, Integral) or value < minimum:
        raise error(f"{what} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def check_flag(value, what: str, error: type[KinredundError] = OptionError) -> bool:
    """Return ``value`` as a bool if it is one (Python's or numpy's), else raise: ``"yes"``, ``0`` or ``None``
    are not flags (a string is always true to ``bool``)."""
    import numpy as np

    if not isinstance(value, (bool, np.bool_)):
        raise error(f"{what} must be True or False, got {value!r}")
    return bool(value)


def check_hooks(progress, meta, error: type[KinredundError] = OptionError) -> None:
    """Refuse (``error``) a ``progress`` that is neither None nor callable and a ``meta`` that is neither None nor a
    mapping: an entry point's check before any work (else the first step's call of ``progress(done, total)``, or
    the record's ``dict(meta)``, fails as Python's TypeError after the work)."""
    from collections.abc import Mapping

    if progress is not None and not callable(progress):
        raise error(f"progress must be a function progress(done, total, ...) or None, got {type(progress).__name__}")
    if meta is not None and not isinstance(meta, Mapping):
        raise error(f"meta must be a dict of extra entries for the record's meta or None, got {type(meta).__name__}")


# -- the sizes a user can ask for -------------------------------------------------------------------------
#: The largest value of every size a user can ask for, and why; the library checks them (:func:`check_size`)
#: and the command line's options use the same numbers, so that a size too large is refused before any work.
SIZES = {
    # measured: a retimed 7-axis record of 50,000 samples peaks at 0.6 GB (writing its JSON), 1.2 KB per sample
    # on disk; 2 million samples needed ~17 GB
    "samples": (200_000, "a record holds every sample: about 8 KiB each at its peak on a 7-axis arm"),
    "starts": (10_000, "each start is a whole local solve"),
    "placements": (100_000, "each placement is an IK solve and a tracking run, about 0.1-1 s"),
    "workers": (64, "each worker is a Python process of about 150 MB"),
    "joints": (100, "each step forms n x n matrices and the 6 x n x n Hessian; redundant arms have a few dozen"),
    # the planners' sizes (kinredund.planning.options.PlanOptions): a plan's cost is about samples x starts local
    # solves, each ~10 ms on a 7-axis arm (24 x 8 takes seconds), plus the walk's edges and the re-tracks
    "plan_samples": (10_000, "each sample time is starts bounded local solves of ~10 ms and a candidate pool "
                             "compared with its neighbours'"),
    "candidates": (1_000, "the closed walk compares every candidate with every candidate of the next sample"),
    "refinements": (10_000, "each inserted point is a closest-point solve of ~10 ms"),
    "rounds": (100, "each round tracks and verifies the whole motion again"),
    "iterations": (100_000, "each iteration of a local solve is a QP step, and every sample runs many solves"),
    "roadmap": (1_000_000, "slices x grid nodes of the roadmap, each with its candidate edges held in memory"),
}
MAX_SAMPLES, MAX_STARTS, MAX_PLACEMENTS, MAX_WORKERS, MAX_JOINTS = (
    SIZES[k][0] for k in ("samples", "starts", "placements", "workers", "joints"))


def check_size(value, what: str, size: str, error: type[KinredundError] = OptionError, minimum: int = 1,
               per: tuple[int, str] = (1, "")) -> int:
    """``value`` as an int in ``minimum`` .. ``SIZES[size]``, else ``error`` naming ``what``, the limit and why.

    Args:
        value: the size asked for (an integer, not a bool).
        what: its name in the message (e.g. ``"loops x samples per loop"``).
        size: a key of :data:`SIZES` (``samples``, ``starts``, ``placements``, ``workers``, ``joints``, and the
            planners' ``plan_samples``, ``candidates``, ``refinements``, ``rounds``, ``iterations``, ``roadmap``).
        per: (k, why) where each unit of ``value`` is k of ``size`` later (e.g. a planner's start count seeds one
            solve of 4 x as many starts): the limit is ``SIZES[size] // k``, and the message says why.
    """
    n = check_count(value, minimum, what, error)
    (full, why), (k, share) = SIZES[size], per
    if n > full // k:
        why = f"{share}, which takes at most {full}: {why}" if k > 1 else why
        raise error(f"{what} must be at most {full // k} ({why}), got {n}")
    return n


def check_joint_vector(q, n: int, owner: str, what: str = "joint vector"):
    """Return q as a float array of shape (n,), or raise :class:`JointVectorError` saying what is wrong."""
    return check_array(q, (n,), what, JointVectorError, owner)


def check_choice(what: str, value: str, allowed: Sequence[str]) -> str:
    """Return ``value`` if it is one of ``allowed`` (a string), else raise :class:`ChoiceError`."""
    if not isinstance(value, str) or value not in allowed:  # an array would make `in` ambiguous
        raise ChoiceError(what, value, allowed)
    return value


#: the backends of the compiled core's users (the tracker's step, the IK's iteration)
BACKENDS = ("auto", "compiled", "python")


def check_backend(backend: str | None) -> tuple[str, bool]:
    """(the backend asked for, whether a problem the core cannot run is an error). The caller's ``backend``, else
    the environment variable ``KINREDUND_BACKEND``, else ``auto``. Only the caller's own ``"compiled"`` makes an
    unsupported problem an error: the environment's ``compiled`` holds for a whole program (every tracker and IK
    solve in it, a plan's stages among them), so there it asks for the core wherever it can run the problem (and
    for a core that loads), the rest running in Python as under ``auto``. Raises ChoiceError: an unknown name."""
    forced = backend == "compiled"
    if backend is None:
        backend = os.environ.get("KINREDUND_BACKEND") or "auto"
    return check_choice("backend", backend, BACKENDS), forced


class _FileError(KinredundError, OSError):
    """A file kinredund will not ``VERB``: ``path`` is the path given, ``reason`` why (the file system's words
    where it refused)."""

    VERB = "use"

    def __init__(self, path, reason: str):
        self.path = str(path)
        self.reason = reason
        super().__init__(f"cannot {self.VERB} {self.path!r}: {reason}")

    def __str__(self) -> str:  # OSError would format its args as (errno, strerror)
        return self.args[0]


class OutputPathError(_FileError):
    """An output path kinredund will not write: not a regular file or a new path, or the write failed.

    ``path`` is the path given, ``reason`` why (the file system's words where it refused).
    """

    VERB = "write"


class InputFileError(_FileError):
    """An input file kinredund will not read: missing, unreadable, not a regular file (a FIFO, a device, a
    folder) or too large. ``path`` is the path given, ``reason`` why."""

    VERB = "read"
