"""The point a compiled step leaves (issue 28): :class:`CompiledPoint`, read from the core's output row on first use.

:mod:`kinredund.tracking.compiled` takes the default mode's ordinary step in C++ and hands the stepper the step's
evaluation (and a corrector solve's in the core: :mod:`kinredund.tracking.compiled_correct`) as a
:class:`CompiledPoint` over the core's output row: the fields a step is read for (q, J, the path
sample, the pose at the corrected joints for the record: :class:`RecordedPose`) are read from the row where someone
asks for them, the rest evaluated in Python (:meth:`~kinredund.tracking.point.Evaluator.point`) on first use.
"""

from __future__ import annotations

import numpy as np

from kinredund.tracking.point import Point


class RecordedPose:
    """What the record keeps of a compiled step: the path sample and the pose (Q, p) at the corrected joints
    (:class:`~kinredund.tracking.recorder.Recorder` then needs no forward kinematics of its own)."""

    __slots__ = ("sample", "pose")

    def __init__(self, sample, pose):
        self.sample, self.pose = sample, pose


class CompiledPoint(Point):
    """The step's evaluation as the core left it (its output row ``out``): t and the basis set, q (the predicted
    point), J, the path sample and ``recorded`` (the :class:`RecordedPose` at the corrected joints) read from the
    row on first use, grad z from the index alone (:meth:`~kinredund.tracking.point.Evaluator.gradient`); the
    rest (pose, task and index terms, :meth:`~kinredund.tracking.point.Point.system`) is evaluated in Python at
    (q, t) on first use. A step whose point nobody reads makes none of them.

    Args:
        layout: (the slices of ``out``'s fields, (n, m)): ``CompiledStep.layout``.
        sample: the path sample at t, or None with ``ahead`` = (Samples, row) to make it from on first use.
    """

    # q, J, sample and recorded: properties over slots of their own (an unset one None), read at every recorded
    # step: a property costs less than __getattr__ after a missed slot (Recorder.add reads all four)
    __slots__ = ("_ev", "_out", "_layout", "_ahead", "_q", "_J", "_sample", "_recorded", "_grad")

    def __init__(self, ev, out, t, sample, basis, layout, ahead=None):
        self._ev, self._out, self.t, self.basis, self._layout, self._ahead = ev, out, t, basis, layout, ahead
        self._sample, self._q, self._J, self._recorded, self._grad = sample, None, None, None, None

    @property
    def q(self) -> np.ndarray:
        if self._q is None:
            self._q = self._out[self._layout[0][7]]
        return self._q

    @q.setter
    def q(self, value) -> None:
        self._q = value

    @property
    def J(self) -> np.ndarray:
        if self._J is None:
            sl, (n, m) = self._layout
            self._J = self._out[sl[3]].reshape(m, n)
        return self._J

    @J.setter
    def J(self, value) -> None:
        self._J = value

    @property
    def grad(self) -> np.ndarray:  # (the switch search's scale, switches._events: the index alone, not the point)
        if self._grad is None:
            self._grad = self._ev.gradient(self.q, self.t)
        return self._grad

    @grad.setter
    def grad(self, value) -> None:
        self._grad = value

    @property
    def sample(self):
        if self._sample is None:
            at, row = self._ahead
            self._sample = at.sample(row)
        return self._sample

    @sample.setter
    def sample(self, value) -> None:
        self._sample = value

    @property
    def recorded(self) -> RecordedPose:
        if self._recorded is None:
            out, sl = self._out, self._layout[0]
            self._recorded = RecordedPose(self.sample, (out[sl[5]].reshape(3, 3), out[sl[6]]))
        return self._recorded

    def __getattr__(self, name):  # an unset slot of the rest: the full evaluation fills them all
        if name not in Point.__slots__:  # (also an instance without its own slots: a copy)
            raise AttributeError(name)
        full = self._full_point()
        for key in ("Q", "p", "terms", "r", "xdot", "grad", "hess", "dgrad_dt"):
            setattr(self, key, getattr(full, key))
        return getattr(self, name)

    def _full_point(self) -> Point:
        """The evaluation the unread fields come from: the Python evaluator's at (q, t)."""
        return self._ev.point(self.q, self.t, sample=self.sample)


class CompiledRowPoint(CompiledPoint):
    """A compiled step's point with general rows held (:mod:`kinredund.tracking.rows`): J is the core's extended one
    ([J; G], m + the rows' count rows: ``layout``), and the rest, :meth:`system` included, is the extended evaluation
    ``evaluate(q, t)`` gives (a :class:`~kinredund.tracking.rows.RowPoint` with the rows held at the step) on first
    use, as the Python stepper's point of that step would have them."""

    __slots__ = ("_evaluate", "_full")

    def __init__(self, evaluate, ev, out, t, sample, basis, layout, ahead=None):
        super().__init__(ev, out, t, sample, basis, layout, ahead)
        self._evaluate, self._full = evaluate, None

    def _full_point(self) -> Point:
        """The extended evaluation at (q, t), made once."""
        if self._full is None:
            self._full = self._evaluate(self.q, self.t)
        return self._full

    def system(self, lam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The extended evaluation's (M with the rows' curvature, top)."""
        return self._full_point().system(lam)
