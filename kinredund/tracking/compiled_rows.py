"""General rows held in the compiled step (issues 27, 28): the steps with a row active in C++ as well.

With rows active the stepper runs the extended system of :mod:`kinredund.tracking.rows` (the rows' equations
under the task's, lam = [lambda; w], their curvature in M). Where the rows' constraint has a compiled check that
holds them too (``row_guard``, whose ``holds``: a scene's
:class:`~kinredund.tracking.constraints.scene.SceneClearance`, ``RowGuard`` in ``src/core/distances.cpp``; a
:class:`~kinredund.tracking.constraints.clearance.SphereClearance` or ``PlaneClearance``, ``FrameRows`` in
``src/core/frame_rows.cpp``), which the core already holds (``StepCore.set_guard``), the core extends its own
evaluation the same way (``StepCore.set_rows``, ``src/core/step.cpp``): the rows' values and gradients as the
constraint's ``rows_at`` gives them, their curvature sum_i w_i Hess c_i as its ``curvature`` gives it (a scene's
central differences, ``curvature="differences"``, the default; a frame clearance's analytic one), the rates afresh
at a corrected point far from the prediction (``GeneralRows._rates_stale``), and after the step the search's tests:
a held row's multiplier below zero (status ``row_release``) and, in the check, every other row's reach and dip with
the held rows left out, as ``pending_switches`` leaves them out. A step the check does not clear is searched by the
stepper itself, as one with no row held. :class:`HeldRows` gives the core the rows held and reads its output with
them.

Several constraints' checks are one (``RowStack``, ``src/core/row_stack.cpp``: the rows numbered as the stepper numbers
them, :func:`~kinredund.tracking.constraints.base.row_check`). Where a scene's curvature is taken another way
(``curvature="witness"``), or a constraint has no compiled check (a ``CornerClearance``: ``row_guard`` None), the
steps with a row held stay the Python stepper's.
"""

from __future__ import annotations

import numpy as np

from kinredund.tracking.compiled_point import CompiledRowPoint
from kinredund.tracking.compiled_start import row_slices
from kinredund.tracking.constraints.base import DIFFERENCE_STEP
from kinredund.tracking.rows import row_point


def held_rows(stepper, core, guard, m: int) -> HeldRows | None:
    """The :class:`HeldRows` of ``stepper`` (task dimension m) on ``core``, or None where its steps with a row held
    stay Python's (see the module docstring; ``guard``: the compiled driver's check, the constraint's ``row_guard``)."""
    if guard is None or not getattr(guard, "holds", False) or not hasattr(core, "set_rows"):
        return None
    return HeldRows(stepper, core, guard, m)


class HeldRows:
    """The rows the core holds (the stepper's ``rows``) and the layout of its output row with them.

    Attributes:
        rows: the rows the core holds (the stepper's numbers); ``layout``: a
            :class:`~kinredund.tracking.compiled_point.CompiledPoint`'s layout of the output row with them (its
            slices, (n, m)), set where the rows are given to the core.
    """

    def __init__(self, stepper, core, guard, m: int):
        self.stepper, self.core, self.guard, self.n, self.m = stepper, core, guard, stepper.n, m
        self.rows, self.layout, self._extend = (), None, None

    def valid(self) -> bool:
        """Does the check still describe the rows (a scene's: the scene unchanged; after a change the constraint's
        queries raise, and the Python stepper's step meets that error)?"""
        return self.guard.valid()

    def sync(self) -> None:
        """Give the core the stepper's rows held where they changed (a switch replaces the ``rows`` tuple)."""
        s = self.stepper
        rows = s.rows
        if rows == self.rows:
            return
        pairs = [s.row_pairs[f] for f in rows]
        self.core.set_rows(np.array(rows, dtype=np.int64), DIFFERENCE_STEP)  # (the stepper's numbers: row_check)
        self.rows = rows
        m = self.m + len(rows)
        self.layout = (row_slices(self.n, m), (self.n, m))
        general, ev = s.general, s.ev
        self._extend = lambda q, t: row_point(ev.point(q, t), general, pairs)  # RowPoint with these rows

    def point(self, out: np.ndarray, t: float, sample, basis, ahead) -> CompiledRowPoint:
        """The step's point from the core's output row ``out`` with the rows held (its extended J; the rest the
        extended evaluation's on first use)."""
        return CompiledRowPoint(self._extend, self.stepper.ev, out, t, sample, basis, self.layout, ahead)

    def factors(self) -> tuple[np.ndarray, np.ndarray]:
        """R's LU factors of the core's last step and their 0-based pivots (the step control's inertia test of a step
        with a row held, ``StepControl._indefinite``, reads them; so does the watch where the core does not measure)."""
        lu, piv = self.core.factors()
        return lu, piv.astype(np.int32)
