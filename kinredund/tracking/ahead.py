"""The path's samples at the next steps' times, computed together (issue 28): :class:`SamplesAhead`.

The compiled step (:mod:`kinredund.tracking.compiled`) passes the path's sample at each step's time to the core.
Sampling a circle one time at a time costs more than its share of the step (a few numpy arrays and a
:class:`~kinredund.paths.PathSample` per call); :meth:`~kinredund.paths.Path.sample_many` computes the samples of
a block of steps together, the same numbers (as the runs of :mod:`kinredund.tracking.runs` sample them).
"""

from __future__ import annotations

import numpy as np

from kinredund.errors import PathError
from kinredund.indices import TimeVaryingReference
from kinredund.paths import Path

#: the most steps sampled in one call of Path.sample_many
BLOCK = 64
#: the fewest: a call's own cost is that of ~10 single samples of a circle, so shorter blocks are sampled step by step
MIN_BLOCK = 16
#: the core's Q and omega of a sample without orientation (src/core/step.cpp reads them for oriented tasks only)
NO_Q, NO_OMEGA = np.zeros((0, 0)), np.zeros(3)
#: no weights, no bounds, no reference: the core's empty argument (read-only: shared)
EMPTY = np.zeros(0)
for _constant in (NO_Q, NO_OMEGA, EMPTY):
    _constant.flags.writeable = False
del _constant


def core_orientation(sample) -> tuple[np.ndarray, np.ndarray]:
    """The sample's Q and omega as the core reads them: :data:`NO_Q` and :data:`NO_OMEGA` where it has none."""
    return (NO_Q if sample.Q is None else sample.Q), (NO_OMEGA if sample.omega is None else sample.omega)


def core_reference(index, t: float) -> tuple[np.ndarray, np.ndarray]:
    """A time-varying reference's value and rate at t [s] as float arrays for the core; :data:`EMPTY` twice for
    an index whose reference is fixed (the core's weights and reference are its own then)."""
    if isinstance(index, TimeVaryingReference):
        return np.asarray(index.reference(t), float), np.asarray(index.rate(t), float)
    return EMPTY, EMPTY


class SamplesAhead:
    """The path's samples at the requested times t0 + k dt [s] of a block of steps k, k + 1, ... (the clock of
    :class:`~kinredund.tracking.stepper.Stepper`), refilled where a step outside the block is asked for.

    Blocks grow while the steps come one after another: a step that does not follow the last block (the first,
    or one after a run of steps taken elsewhere: :mod:`kinredund.tracking.runs`) starts a block of one step, and
    each block that follows its predecessor is twice as long, up to ``block``; blocks shorter than
    :data:`MIN_BLOCK` are not sampled ahead (``samples`` None), so a step between runs costs no block it won't use.

    Only a path that computes its samples together (:meth:`~kinredund.paths.Path.computes_together`, e.g.
    :class:`~kinredund.paths.Circle`) is sampled ahead: the base class's loops over ``sample``, which gains
    nothing and would call a path of the caller's own code ahead of time. Elsewhere, and where the samples of a
    block do not stack (:class:`~kinredund.errors.PathError`), ``samples`` is None: the step samples itself.

    Attributes:
        first: the step number of the block's first row; ``count``: the block's steps.
        samples: the block's :class:`~kinredund.paths.base.Samples` (row j: step ``first + j``), or None.
        rows: per step of the block, (p, v, Q, omega) as the core takes them (views of ``samples``' rows; Q and
            omega of a path without orientation: :data:`NO_Q`, :data:`NO_OMEGA`).
    """

    def __init__(self, path: Path, t0: float, dt: float, block: int = BLOCK):
        self.path, self.t0, self.dt, self.block = path, t0, dt, block
        self.own = path.computes_together()  # Path.computes_together: never a caller's sample() ahead of time
        self.first, self.count, self.samples, self.rows = 0, 0, None, []

    def fill(self, k: int) -> None:
        """Start the block of step k (see the class docstring; ``samples`` None where it is not sampled ahead)."""
        count = min(2 * self.count, self.block) if k == self.first + self.count else 1
        self.first, self.count, self.samples, self.rows = k, count, None, []
        if count < MIN_BLOCK or not self.own:
            return
        at = sample_block(self.path, step_times(self.t0, self.dt, k, count))
        if at is None:
            return
        if at.Q is None:
            self.rows = [(p, v, NO_Q, NO_OMEGA) for p, v in zip(at.p, at.v, strict=True)]
        else:
            self.rows = list(zip(at.p, at.v, at.Q, at.omega, strict=True))
        self.samples = at


def step_times(t0: float, dt: float, first: int, count: int) -> list[float]:
    """The requested times t0 + k dt [s] of steps k = first, ..., first + count - 1 (the clock of
    :class:`~kinredund.tracking.stepper.Stepper`: no accumulated rounding), as floats."""
    return step_time_array(t0, dt, first, count).tolist()


#: the step numbers 0, 1, ... that :func:`step_time_array` offsets (np.arange releases the GIL at every call, handing
#: it to another of track_many's threads; an addition on fewer than 500 entries does not)
_STEPS = np.arange(256)
_STEPS.flags.writeable = False


def step_time_array(t0: float, dt: float, first: int, count: int) -> np.ndarray:
    """:func:`step_times` as an array: each entry the one product k dt (k exact as a float) and the one sum that
    the stepper's ``t0 + k * dt`` makes, so the same floats."""
    k = first + _STEPS[:count] if count <= len(_STEPS) else np.arange(first, first + count)
    return t0 + k * dt


def sample_block(path: Path, times: list[float]):
    """``path.sample_many(times)`` where its fields stack as the core takes them (p and v (k, 3); Q (k, 3, 3) and
    omega (k, 3), or no orientation at all), else None (:class:`~kinredund.errors.PathError`: the samples do not
    stack; or fields of other shapes): the steps then sample one by one, and the step says what is wrong."""
    try:
        at = path.sample_many(times)
    except PathError:
        return None
    k = len(times)
    if at.p.shape != (k, 3) or at.v.shape != (k, 3):
        return None
    if at.Q is not None and (at.Q.shape != (k, 3, 3) or at.omega is None or at.omega.shape != (k, 3)):
        return None
    return at
