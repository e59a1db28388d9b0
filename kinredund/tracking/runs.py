"""Runs of ordinary compiled steps in one call of the core (issue 28): the record written from C++ arrays.

:func:`stepping` gives :func:`~kinredund.tracking.run.track` its way to advance a run by up to ``count`` requested
steps, each recorded. On the compiled backend (:mod:`kinredund.tracking.compiled`) the steps that are ordinary by
what Python knows before them - no joint on a bound, no crossing the watch could predict before
:attr:`~kinredund.tracking.watch.Watch.safe_before` - are taken by the core's ``run_steps``
(``src/core/loop.cpp``): Python samples the path at all their times first (:meth:`~kinredund.paths.Path.sample_many`,
which a circle computes together, in one call of the core: ``src/core/paths.cpp``), and a time-varying reference, then
one C++ call steps through them with the GIL released (threads running other tasks compute meanwhile:
:func:`~kinredund.tracking.many.track_many`) and writes each step's output row (the layout of ``StepCore.step``)
into one array (the path sampled :data:`GRID` steps ahead). The rows go to the record in one call
(:meth:`~kinredund.tracking.recorder.Recorder.add_rows`) and the last becomes the stepper's state. The run stops
at the first step the core hands back (a bound reached, a jump, a failure: the Python stepper takes that step
from the same state, :meth:`~kinredund.tracking.compiled.CompiledStep.hand_back`). It goes on through the steps the
watch measures: exactly (every :data:`~kinredund.tracking.watch.EXACT_EVERY`-th: one SVD of J and the eigenvalue of
Z^T M Z, from the J and M of the step's row; ``watch_exact``, ``src/core/watch.cpp``: the routine of the compiled
backend's single steps, :meth:`~kinredund.tracking.watch.Watch.use_core`) and by the inverse iteration with the
step's R factors where R's condition drops (``watch_inverse``: the routine of the single steps'
``StepCore.watch_measure``, the watch's vector and reference J carried from one measurement to the next,
:attr:`~kinredund.tracking.watch.Watch.iteration`), both in the run (a measurement that is not one of these, the
Python watch's exact fallback, ends the run there: its row is finished in Python,
:meth:`~kinredund.tracking.compiled.CompiledStep.accept`). The run takes the watch's verdicts on them in order, as
the step control does one by one (the crossing test, the measurement kept, the history and its prediction:
``src/core/watch.cpp``'s WatchHistory, the Python watch's operations on the same floats, with the GIL released;
:meth:`~kinredund.tracking.watch.Watch.history` hands it the watch's state, which
:meth:`~kinredund.tracking.watch.Watch.take_run` takes back), and ends at the first measured step the watch rejects
(an exact one then goes through :meth:`~kinredund.tracking.compiled.CompiledStep.accept` as one by one, which
measures it again and hands it back; one of the inverse iteration is handed back as ``accept`` hands it back) or
before the first step its new prediction (:meth:`~kinredund.tracking.watch.Watch.ahead`) does not let through (left
to the next call, which hands it back). Every step is the
one :meth:`~kinredund.tracking.compiled.CompiledStep.step` would take, with the same operations: the record
and the state equal those of one-by-one steps (``tests/test_tracking_runs.py``). Runs go on through steps with
joints held on their bounds (the core's reduced system, the active set it was given: ``StepCore.set_active``); the
active set changes only at a step the core hands back (a bound reached or released, whose switch the Python stepper
locates), so it is the same throughout a run. With general rows (issue 27) runs take the steps with no row
active where the rows have the core's compiled check (``CompiledStep.guard``, :mod:`kinredund.tracking.compiled`, which
``StepCore.step_guarded`` runs after a single step): the run calls it after each step, as that single step does, and
writes each step's smallest row value (the check's ``smallest``: the record's, as ``keep_smallest`` keeps it); the first
step it does not clear is handed over with its verdict (``GUARD_DUE``:
:meth:`~kinredund.tracking.compiled.CompiledStep.accept`, whose search for a switch decides); a guarded run goes on
through the steps the watch measures as any run does (its verdicts taken in the run, step by step, a step it rejects
ending the run before the check's value of it is kept), so the check runs on exactly the steps, with the same arrays,
that single steps check. Where the core holds the rows active
(:mod:`kinredund.tracking.compiled_rows`) runs go on with them held, the output's layout the held rows' (their
multipliers recorded per step), the check leaving them out as ``StepCore.step_guarded`` does, a held row's release
(``row_release``) handed back, and a step whose R has odd inertia handed over for the watch's exact measurement
(``CompiledStep.accept``: ``odd_inertia``, as a single held step); a row active that the core does not hold is taken
one step at a time by the Python stepper. Like
:mod:`~kinredund.tracking.compiled`, it reads only the stepper's and the step control's public interface.
"""

from __future__ import annotations

import numpy as np

from kinredund.tasks import get_task
from kinredund.tracking.ahead import sample_block, step_time_array
from kinredund.tracking.compiled import load_core
from kinredund.tracking.predictor_corrector import PREDICTOR_POINTS
from kinredund.tracking.watch import EXACT_EVERY, RCOND_DROP, RCOND_NEAR

#: the path is sampled for this many steps ahead in one call (Path.sample_many), or for the rest of the run
GRID = 256
#: the most steps of one C++ call (it goes on through the watch's measurements)
MAX_RUN = GRID
#: the fewest samples taken ahead that a run uses before it samples afresh (:meth:`Runs._window`)
REFILL = 32


def stepping(tracker, rec):
    """``advance(count)``: up to ``count`` >= 1 steps of ``tracker``, each recorded in ``rec``; returns the
    steps taken (>= 1). Raises what the tracker's step raises (the record holds the steps before it)."""
    compiled = getattr(tracker, "compiled", None)
    if compiled is None or not hasattr(load_core(), "run_steps"):  # the Python stepper (or an older core)
        return one_by_one(tracker, rec)
    if compiled.rows and compiled.guard is None:  # general rows without a compiled check: each step searched in Python
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
        self.grid = None  # (the first step's number, the Samples, the core's arrays) of the steps sampled ahead
        # Path.computes_together (the driver's samples ahead asked it of this path): sampled GRID steps ahead, the
        # times as an array (the path's own sample_many takes one); a caller's path gets the run's times as floats
        self.together = compiled.ahead.own

    def _ordinary(self, count: int) -> int:
        """How many of the next steps (at most ``count``) are ordinary as far as Python can tell."""
        s, ctl, c = self.s, self.ctl, self.c
        if c.rows and (s.qdot is None or not c.guard.valid() or (s.rows and (c.held is None or not c.held.valid()))):
            return 1  # the step cannot be checked in the run, or a row active the core does not hold: a single step
        K = min(count, MAX_RUN)
        if ctl is not None:
            t0, k, dt, safe = s.t0, s.k, s.dt, ctl.watch.safe_before
            if not t0 + (k + K) * dt < safe:  # (the times grow with j: where the last is before safe, all are)
                K = sum(1 for j in range(1, K + 1) if t0 + (k + j) * dt < safe)  # Watch.ahead is None before safe
        return K

    def advance(self, count: int) -> int:
        """Up to ``count`` steps, recorded; the number taken (>= 1)."""
        c, rec, s, ctl = self.c, self.rec, self.s, self.ctl
        K = self._ordinary(count)
        window = self._window(K, count) if K >= 2 else None
        if window is None:  # a single step (or a sample the core cannot take: the step says what is wrong)
            c.step()
            rec.add()
            return 1
        times, at, i, arrays = window
        K = len(times)  # (a run ends where the samples taken ahead end: _window)
        if c.held is not None:
            c.held.sync()  # the rows held now (a switch taken by the Python stepper replaces them)
        out = np.empty((K, int(c.output_layout()[0][-1].stop) + 2))  # the core's row: the fields, rcond, speed^2
        fixed = getattr(s, "fixed", None)
        if ctl is None:
            watch, speed2 = (False, RCOND_NEAR, RCOND_DROP, 0.0, 0, EXACT_EVERY, False), 0.0
        else:  # on through the steps the watch measures, its verdicts taken in the run (Watch.history)
            watch, speed2 = (True, RCOND_NEAR, RCOND_DROP, *ctl.watch.gate, EXACT_EVERY, True,
                             *ctl.watch.iteration, ctl.watch.history(fixed)), ctl.speed2
        if c.limited:
            c.sync_active()  # a release taken by the Python stepper: the core holds none now
        smallest = guard = None
        if c.rows:  # the core's check of each step (StepCore.step_guarded's), its smallest row value written here
            smallest = np.empty(K)
            guard = (s.t, smallest)
        done, status, kept = self.core.run_steps(c.core, *arrays, s.y, s.yd, s.prev, s.qdot, speed2, ctl is not None,
                                                 watch, out, guard)
        if kept is not None:  # the watch after the measurements the run kept (their verdicts: the core's)
            ctl.watch.take_run(kept, fixed)
        if done:
            self._commit(out[:done], at, i, times[:done], smallest)
        checked = {}  # the check's verdict on the step handed over (it ran: a step is checked once)
        if guard is not None and status in (self.core.WATCH_DUE, self.core.GUARD_DUE):
            checked = {"cleared": status == self.core.WATCH_DUE, "smallest": float(smallest[done])}
        if status in (self.core.WATCH_DUE, self.core.GUARD_DUE):
            c.accept(out[done], at.sample(i + done), times[done], **checked)
        elif status > 0:
            c.hand_back(status)
        else:
            return done
        rec.add()
        return done + 1

    def _window(self, K: int, count: int):
        """(times, the Samples, the offset of the next step in them, (t, p, v, Q, omega, ref, rate) of the next K
        steps as the core's arrays), sampled ahead (:data:`GRID` steps or the ``count`` left) where the last grid
        ends; or None where the samples do not stack or a task with orientation has none. A run that would go past
        the end of the samples taken ahead is cut there where at least :data:`REFILL` of them are left (a run handed
        back every few steps would otherwise sample GRID steps ahead at every start)."""
        j0 = self.s.k + 1
        if self.grid is not None and self.grid[0] <= j0:
            left = self.grid[0] + len(self.grid[2]) - j0
            if left >= min(K, REFILL):
                K = min(K, left)
        if self.grid is None or not self.grid[0] <= j0 <= j0 + K <= self.grid[0] + len(self.grid[2]):
            ahead = min(count, GRID) if self.together else K  # a caller's path: no further
            self.grid = self._sample(j0, max(K, ahead))
        first, at, times, arrays = self.grid
        if at is None:
            return None
        i = j0 - first
        return times[i:i + K], at, i, tuple(a if len(a) == 0 else a[i:i + K] for a in arrays)

    def _sample(self, j0: int, count: int) -> tuple:
        """(j0, Samples, times, the core's arrays) of steps j0 .. j0 + count - 1 (Samples None where unusable)."""
        s = self.s
        clock = step_time_array(s.t0, s.dt, j0, count)
        times = clock.tolist()
        # Evaluator.sample's samples, computed together where the path can
        at = sample_block(s.ev.path, clock if self.together else times)
        if at is None or (self.oriented and at.Q is None):
            return j0, None, times, ()
        no3, no9, non = self.none
        Q, omega = no9, no3
        if self.oriented:
            Q, omega = at.Q.reshape(count, 9), at.omega
        ref = rate = non
        if self.c.time_varying:
            index = s.ev.index
            ref = np.array([index.reference(t) for t in times], float)
            rate = np.array([index.rate(t) for t in times], float)
        return j0, at, times, (clock, at.p, at.v, Q, omega, ref, rate)

    def _commit(self, out: np.ndarray, at, i: int, times: list[float], smallest: np.ndarray | None) -> None:
        """The run's rows as the record's and the last as the stepper's state (as one-by-one steps leave it);
        ``at``: the path's samples, the run's first at ``i``; ``smallest``: with general rows, the rows' smallest
        value at each step's end (the core's check's, as :meth:`~kinredund.tracking.compiled.CompiledStep.apply`
        keeps it)."""
        c, s, ctl = self.c, self.s, self.ctl
        rows = c.rows and bool(s.rows)  # rows held through the run: the output's layout with them
        slices, (n, m) = c.output_layout()
        sy, ssol, sM, sJ, _, sQ, sp = slices[:7]
        mt = c.shapes[1]  # the task's multipliers (the rows' after them)
        K = len(times)
        Y, SOL = out[:, sy], out[:, ssol]
        M, J = out[:, sM].reshape(K, n, n), out[:, sJ].reshape(K, m, n)
        held = self._held(out, M, J, slices) if c.limited and s.any_active else None
        if smallest is not None:
            smallest = smallest[:K].tolist()
        self.rec.add_rows(times, Y[:, :n], Y[:, n:n + mt], M, J[:, :mt], (out[:, sQ].reshape(K, 3, 3), out[:, sp]),
                          (at.p[i:i + K], None if at.Q is None else at.Q[i:i + K]), SOL[:, :n], held, smallest,
                          -Y[:, n + mt:] if rows else None)
        if K > 1:  # the state before the last row: the predictor's history as the steps between carried it
            keep = PREDICTOR_POINTS - 1  # the (y, ydot) pairs the history holds: the rows before them drop out
            hist = [*s.prev, s.y, s.yd]
            for j in range(max(0, K - 2 - keep), K - 2):
                hist += (Y[j], SOL[j])
            s.prev[:] = hist[-2 * keep:]
            s.y, s.yd = Y[K - 2], SOL[K - 2]
            s.k += K - 1
            c.steps += K - 1
            c.held_steps += (K - 1) * (held is not None)
            c.row_steps += (K - 1) * rows
        last = out[K - 1]
        rcond = float(last[-2])
        c.apply(last, at.sample(i + K - 1), times[-1], rcond, smallest=None if smallest is None else smallest[-1])
        if ctl is not None:
            ctl.watch.passed(K, rcond)
            ctl.speed2 = float(last[-1])

    def _held(self, out: np.ndarray, M: np.ndarray, J: np.ndarray, slices: tuple) -> tuple:
        """(solver labels, active bounds, bound multipliers (K, n)) of a run's rows with joints or general rows held,
        as :meth:`~kinredund.tracking.compiled.CompiledStep.apply` gives each step (the reduced system's label from
        the core's verdict, on J with the rows held) and :meth:`~kinredund.tracking.recorder.Recorder.add` records
        it; ``slices``: the output's layout."""
        s, (*_, s_mu, s_label) = self.s, slices
        codes = out[:, s_label][:, 0].astype(int)
        labels = [s.reduced_label(M[j], J[j], int(codes[j])) for j in range(len(out))]
        return labels, s.active_bounds(), out[:, s_mu]
