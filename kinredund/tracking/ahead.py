"""The path's samples at the next steps' times, computed together (issue 28): :class:`SamplesAhead`.

The compiled step (:mod:`kinredund.tracking.compiled`) passes the path's sample at each step's time to the core.
Sampling a circle one time at a time costs more than its share of the step (a few numpy arrays and a
:class:`~kinredund.paths.PathSample` per call); :meth:`~kinredund.paths.Path.sample_many` computes the samples of
a block of steps together, the same numbers (as the runs of :mod:`kinredund.tracking.runs` sample them).
"""

from __future__ import annotations

from kinredund.errors import PathError
from kinredund.paths import Path

#: the steps sampled in one call of Path.sample_many
BLOCK = 64


class SamplesAhead:
    """The path's samples at the requested times t0 + k dt [s] of steps k .. k + ``block`` - 1 (the clock of
    :class:`~kinredund.tracking.stepper.Stepper`), refilled where a step outside the block is asked for.

    Only a path with its own ``sample_many`` (one that computes the samples together, e.g.
    :class:`~kinredund.paths.Circle`) is sampled ahead: the base class's loops over ``sample``, which gains
    nothing and would call a path of the caller's own code ahead of time. Elsewhere, and where the samples of a
    block do not stack (:class:`~kinredund.errors.PathError`), ``samples`` is None: the step samples itself.

    Attributes:
        first: the step number of the block's first row; ``count``: the block's steps.
        samples: the block's :class:`~kinredund.paths.base.Samples` (row j: step ``first + j``), or None.
    """

    def __init__(self, path: Path, t0: float, dt: float, block: int = BLOCK):
        self.path, self.t0, self.dt, self.block = path, t0, dt, block
        self.own = type(path).sample_many is not Path.sample_many
        self.first, self.count, self.samples = 0, 0, None

    def fill(self, k: int) -> None:
        """Sample the block of steps k .. k + ``block`` - 1 (``samples`` None where it cannot be sampled ahead)."""
        self.first, self.count, self.samples = k, self.block, None
        if not self.own:
            return
        t0, dt = self.t0, self.dt
        try:
            at = self.path.sample_many([t0 + j * dt for j in range(k, k + self.block)])
        except PathError:
            return
        if at.p.shape == at.v.shape == (self.block, 3) and (at.Q is None or at.Q.shape == (self.block, 3, 3)):
            self.samples = at
