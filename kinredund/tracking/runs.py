"""Runs of ordinary compiled steps in one call of the core (issue 28): the record written from C++ arrays.

:func:`stepping` gives :func:`~kinredund.tracking.run.track` its way to advance a run by up to ``count`` requested
steps, each recorded. On the compiled backend (:mod:`kinredund.tracking.compiled`) the steps that are ordinary by
what Python knows before them - no joint on a bound, no crossing the watch could predict before
:attr:`~kinredund.tracking.watch.Watch.safe_before` - are taken by the core's ``run_steps``
(``src/core/loop.cpp``): Python samples the path at all their times first (:meth:`~kinredund.paths.Path.sample_many`,
which a circle computes together), and a time-varying reference, then
one C++ call steps through them with the GIL released (threads running other tasks compute meanwhile:
:func:`~kinredund.tracking.many.track_many`) and writes each step's output row (the layout of ``StepCore.step``)
into one array; the run samples twice the steps the last run took (the watch's measured steps end runs). The rows
go to the record in one call
(:meth:`~kinredund.tracking.recorder.Recorder.add_rows`) and the last becomes the stepper's state. The run stops
at the first step the core hands back (a bound reached, a jump, a failure: the Python stepper takes that step
from the same state, :meth:`~kinredund.tracking.compiled.CompiledStep.hand_back`) or that the watch measures
(its row is finished in Python: :meth:`~kinredund.tracking.compiled.CompiledStep.accept`). Every step is the
one :meth:`~kinredund.tracking.compiled.CompiledStep.step` would take, with the same operations: the record
and the state equal those of one-by-one steps (``tests/test_tracking_runs.py``). Like
:mod:`~kinredund.tracking.compiled`, it reads the stepper's and the step control's private state (``_sel``,
``_speed2``).
"""

from __future__ import annotations

import numpy as np

from kinredund.errors import PathError
from kinredund.tasks import get_task
from kinredund.tracking.compiled import load_core
from kinredund.tracking.predictor_corrector import PREDICTOR_POINTS
from kinredund.tracking.watch import EXACT_EVERY, RCOND_DROP, RCOND_NEAR

#: the most steps of one C++ call (the watch measures every EXACT_EVERY steps anyway)
MAX_RUN = EXACT_EVERY
#: the steps sampled for the first call; each call then samples twice the steps the last one took (at least 2,
#: at most MAX_RUN): where the watch measures often (R's condition moving), few samples go unused
FIRST_RUN = 8


def stepping(tracker, rec):
    """``advance(count)``: up to ``count`` >= 1 steps of ``tracker``, each recorded in ``rec``; returns the
    steps taken (>= 1). Raises what the tracker's step raises (the record holds the steps before it)."""
    compiled = getattr(tracker, "compiled", None)
    if compiled is None or not hasattr(load_core(), "run_steps"):  # the Python stepper (or an older core)
        return one_by_one(tracker, rec)
    return Runs(compiled, rec).advance


def one_by_one(tracker, rec):
    """``advance(count)`` of :func:`stepping` that takes one step (``tracker.step()``, then ``rec.add()``)."""
    step, add = tracker.step, rec.add

    def one(count: int) -> int:
        step()
        add()
        return 1

    return one


class Runs:
    """Advances one compiled run in runs of ordinary steps (see the module docstring)."""

    def __init__(self, compiled, rec):
        self.c, self.rec = compiled, rec
        self.core = load_core()
        s = compiled.stepper
        self.s, self.ctl = s, s.control
        self.oriented = get_task(s.ev.task).has_orientation  # the core reads Q and omega
        self.none = np.zeros((0, 3)), np.zeros((0, 9)), np.zeros((0, s.n))
        self.size = FIRST_RUN

    def _ordinary(self, count: int) -> list[float]:
        """The times of the next steps (at most ``count``) that are ordinary as far as Python can tell."""
        s, ctl = self.s, self.ctl
        if getattr(s, "_sel", None) is not None:  # a joint on a bound: the Python stepper's
            return []
        t0, k, dt = s.t0, s.k, s.dt
        times = [t0 + (k + j) * dt for j in range(1, min(count, self.size) + 1)]
        if ctl is not None:
            safe = ctl.watch.safe_before
            times = [t for t in times if t < safe]
        return times

    def advance(self, count: int) -> int:
        """Up to ``count`` steps, recorded; the number taken (>= 1)."""
        c, rec = self.c, self.rec
        times = self._ordinary(count)
        at = self._inputs(times) if len(times) >= 2 else None
        if at is None:  # a single step (a sample the core cannot take: the step says what is wrong)
            c.step()
            rec.add()
            return 1
        at, arrays = at
        s, ctl = self.s, self.ctl
        out = np.empty((len(times), int(c.slices[-1].stop) + 2))  # the core's row: the fields, rcond, speed^2
        if ctl is None:
            watch, speed2 = (False, RCOND_NEAR, RCOND_DROP, 0.0, 0, EXACT_EVERY), 0.0
        else:
            watch, speed2 = (True, RCOND_NEAR, RCOND_DROP, *ctl.watch.gate, EXACT_EVERY), ctl._speed2
        done, status = self.core.run_steps(c.core, np.asarray(times), *arrays, s.y, s.yd, s.prev, s.qdot, speed2,
                                           ctl is not None, watch, out)
        self.size = min(MAX_RUN, max(2, 2 * (done + 1)))
        if done:
            self._commit(out[:done], at, times[:done])
        if status == self.core.WATCH_DUE:
            c.accept(out[done], at.sample(done), times[done])
        elif status:
            c.hand_back(status)
        else:
            return done
        rec.add()
        return done + 1

    def _inputs(self, times: list[float]):
        """(the path's :class:`~kinredund.paths.base.Samples`, (p, v, Q, omega, ref, rate) as the core's arrays) at
        ``times``, or None where the samples do not stack or a task with orientation has none."""
        s = self.s
        try:
            at = s.ev.path.sample_many(times)  # Evaluator.sample's samples, computed together where the path can
        except PathError:
            return None
        no3, no9, non = self.none
        Q, omega = no9, no3
        if self.oriented:
            if at.Q is None:
                return None
            Q, omega = at.Q.reshape(len(times), 9), at.omega
        ref = rate = non
        if self.c._tv:
            index = s.ev.index
            ref = np.array([index.reference(t) for t in times], float)
            rate = np.array([index.rate(t) for t in times], float)
        if at.p.shape != (len(times), 3) or at.v.shape != at.p.shape:
            return None
        return at, (at.p, at.v, Q, omega, ref, rate)

    def _commit(self, out: np.ndarray, at, times: list[float]) -> None:
        """The run's rows as the record's and the last as the stepper's state (as one-by-one steps leave it)."""
        c, s, ctl = self.c, self.s, self.ctl
        sy, ssol, sM, sJ, _, sQ, sp = c.slices
        n, m, _ = c.shapes
        K = len(times)
        Y, SOL = out[:, sy], out[:, ssol]
        self.rec.add_rows(times, Y[:, :n], Y[:, n:], out[:, sM].reshape(K, n, n), out[:, sJ].reshape(K, m, n),
                          (out[:, sQ].reshape(K, 3, 3), out[:, sp]), (at.p[:K], None if at.Q is None else at.Q[:K]),
                          SOL[:, :n])
        if K > 1:  # the state before the last row: the predictor's history as the steps between carried it
            hist = [*s.prev, s.y, s.yd]
            for j in range(K - 2):
                hist += (Y[j], SOL[j])
            s.prev[:] = hist[-2 * (PREDICTOR_POINTS - 1):]
            s.y, s.yd = Y[K - 2], SOL[K - 2]
            s.k += K - 1
            c.steps += K - 1
        last = out[K - 1]
        rcond = float(last[-2])
        c.apply(last, at.sample(K - 1), times[-1], rcond)
        if ctl is not None:
            ctl.watch.passed(K, rcond)
            ctl._speed2 = float(last[-1])
