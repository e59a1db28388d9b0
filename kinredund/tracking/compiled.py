"""The compiled backend of the default mode's step (issue 28): the ordinary step in C++, the rest in Python.

:class:`CompiledStep` runs a :class:`~kinredund.tracking.predictor_corrector.PredictorCorrector` (or its limited
subclass, :mod:`kinredund.tracking.limited`) whose common step is done by the compiled core ``kinredund._core``
(``src/core/step.cpp``): the Hermite predictor, the evaluation (Pinocchio's kinematics and kinematic Hessian,
the task terms of every task kind in both forms, the index terms of
:class:`~kinredund.indices.JointDeviation` and :class:`~kinredund.indices.TimeVaryingReference`), R of
Eq. (4.24) with its LU factors (LAPACK's algorithm and layout) and LAPACK's condition estimate, the rates, the Newton
update and the chord iterations, then the checks that make the step ordinary: no free joint beyond a bound, no
multiplier of a joint held on its bound below zero (nor of a general row held:
:mod:`kinredund.tracking.compiled_rows`), no jump (the step control's check, :mod:`kinredund.tracking.step_control`).
With joints on their bounds it runs on the reduced system of :mod:`kinredund.tracking.limited` (the held joints'
columns removed from R, their residual rows the bound multipliers') and returns the bound multipliers at the
corrected point. Python samples the path (in blocks of steps ahead where the path computes its samples together:
:mod:`kinredund.tracking.ahead`) and a time-varying
reference and passes them in; the active set goes to the core when it changes. The step's point
(:class:`~kinredund.tracking.compiled_point.CompiledPoint`) reads the core's output row only where someone asks for
it. The run's start is the core's too (:mod:`kinredund.tracking.compiled_start`): :func:`compiled_start` gives the
tracker a :class:`~kinredund.tracking.compiled_start.CompiledStart` for its stepper before the stepper is made, whose
StepCore the steps then use.

Where the watch measures the new point (every :data:`~kinredund.tracking.watch.EXACT_EVERY` steps, or where
R's condition drops) the core measures it (``StepCore.watch_measure``, ``src/core/watch.cpp``: the watch's inverse
iteration with R's factors and its gated SVD, with the LAPACK routines the Python watch calls) and the watch's
bookkeeping (the crossing test, the history) stays in Python; the exact measurement every
:data:`~kinredund.tracking.watch.EXACT_EVERY` is the core's too (``watch_exact``, Eigen's SVD and eigensolver:
:meth:`~kinredund.tracking.watch.Watch.use_core`), the routine the runs of steps measure with. Anything else is
handed to the Python reference from the same state (the stepper's, untouched until the compiled step is accepted, or put
back with the watch's where the watch rejects the step): a step the watch predicts trouble within or
rejects, a switch (a bound reached or released: located by the Python stepper's Brent search), a jump, a
corrector that needs fresh factorisations, a singular R, a failure. Those steps are the Python stepper's own, so
events happen at the same times with the same causes; their corrector solves (the step's, the sub-steps', each
evaluation of the switching-time search, the correction after a switch) are the core's again where no general row
is active or the core holds the rows (:mod:`kinredund.tracking.compiled_correct`: the stepper's ``corrector``, which
runs Python's own solve from the same inputs where the core declines one).

With general inequality rows (``constraints=``, ``scene=``: :mod:`kinredund.tracking.rows`) the run is a hybrid:
a step with a row active is the Python stepper's unless the core holds the rows too (a scene's, a sphere's or a
plane's: :mod:`kinredund.tracking.compiled_rows`, the extended system of :class:`~kinredund.tracking.rows.RowPoint`
in C++; reason ``row_release`` where a held row's multiplier turns negative). A step taken in C++ is then checked by
the stepper's own search for a switch within it (``pending_switches``: an event at its end, a row below zero
there, a row dipping below zero inside it), the call the Python step makes after its own step. Where it finds
one, the step is dropped (the state put back) and handed to the Python stepper (reason ``rows``), which locates
the switch itself. Where the rows' constraint has a compiled check
(:meth:`~kinredund.tracking.constraints.base.Constraint.row_guard`: a scene's, ``src/core/distances.cpp``; a frame
clearance's, ``src/core/frame_rows.cpp``), that
check runs first, before the step is applied: where it rules out a switch (every row above -ROW_TOL at the end and
none able to dip below it inside, by the constraint's lower bounds; the rows held left out, as the search leaves
them out) the step is taken without the search, else the search decides as above. The core holds the check
(``StepCore.set_guard``) and runs it in the same call as its step (``StepCore.step_guarded``: the row, the
verdict and the rows' smallest value at the step's end), so the check costs no call from Python of its own, and a
step kept hands that value to the stepper for the record (``keep_smallest``: the record's smallest row value there
without a query of its own; exact near the clearances, a lower bound elsewhere, as the constraint's values are).
``track()``'s runs of steps (:mod:`kinredund.tracking.runs`) make the same check inside the core's run and hand a step
it does not clear to :meth:`CompiledStep.accept` with the verdict, as a single step would.

The driver uses the stepper's public interface only: its state and ``accept`` (the step taken in C++ as its
own), the predictor's ``hermite`` weights, the limited stepper's ``active_set``, ``switch_limits``,
``reduced_label``, ``rows``, ``row_pairs``, ``pending_switches`` and ``general`` (its constraint's
``row_guard``), and the step control's ``snapshot``, ``restore``, ``watch_point`` and ``speed2``.

:func:`attach` picks the backend of a :class:`~kinredund.tracking.tracker.Tracker`: ``compiled`` where the
core loads and supports the problem, else ``python`` (``backend="compiled"`` then raises an
:class:`~kinredund.errors.OptionError` saying why; a core that cannot be loaded at all warns once). The
environment variable ``KINREDUND_BACKEND`` (``python``, ``compiled`` or ``auto``) is read where the caller
gives no backend (:func:`~kinredund.errors.check_backend`: its ``compiled`` insists on a core that loads, but a
problem the core cannot run is Python's, as under ``auto``: it holds for the whole program).
"""

from __future__ import annotations

import warnings

import numpy as np

from kinredund.errors import KinredundError, OptionError, check_backend
from kinredund.indices import JointDeviation, TimeVaryingReference
from kinredund.tracking.ahead import SamplesAhead, core_orientation, core_reference
from kinredund.tracking.compiled_correct import CoreCorrector
from kinredund.tracking.compiled_point import CompiledPoint
from kinredund.tracking.compiled_rows import held_rows
from kinredund.tracking.compiled_start import TASK_CODES, CompiledStart, make_step_core, row_slices
from kinredund.tracking.constraints.base import row_check
from kinredund.tracking.predictor_corrector import PredictorCorrector
from kinredund.tracking.rows import ROW_TOL
from kinredund.tracking.step_control import odd_inertia

#: why the core handed a step back (its status codes), for :attr:`CompiledStep.handed_back`
STATUS = {1: "factor_singular", 2: "rcond_low", 3: "not_finite", 4: "chord_failed", 5: "jump", 6: "limit",
          7: "log_near_pi", 8: "watch_ahead", 9: "watch_rejects", 11: "release", 12: "row_active", 13: "rows",
          14: "row_release"}
#: the driver's own reasons (codes the core does not return): a general row is active and the core does not hold it;
#: the stepper's row checks find a switch within the compiled step (a row reached or dipping below zero)
ROW_ACTIVE, ROWS = 12, 13
#: the watch's measurement of a core's step crossed a floor: the step is handed back (:mod:`kinredund.tracking.runs`)
WATCH_REJECTS = 9


class BackendWarning(UserWarning):
    """The compiled core cannot be loaded: the (slower) Python stepper runs, with the same results."""


_CORE: list = []  # [module or None, the import error's text]


def load_core():
    """The compiled module ``kinredund._core``, or None where it cannot be loaded (:func:`core_error` says why)."""
    if not _CORE:
        try:
            import kinredund._core as core
        except ImportError as err:
            _CORE.extend([None, f"{type(err).__name__}: {err}"])
        else:
            _CORE.extend([core if hasattr(core, "StepCore") else None, "kinredund._core has no StepCore"])
    return _CORE[0]


def core_error() -> str:
    """Why :func:`load_core` returned None ("" where it loads)."""
    return "" if load_core() is not None else _CORE[1]


def unsupported(tracker) -> str:
    """Why the compiled step cannot run ``tracker``'s problem ("" where it can)."""
    s = tracker.stepper
    return unsupported_problem(type(s), s.ev, tracker.mode, tracker.scheme)


def unsupported_problem(stepper_class: type, ev, mode: str, scheme: str) -> str:
    """Why the compiled step cannot run a stepper of ``stepper_class`` on ``ev``'s problem ("" where it can): the
    rule of :func:`unsupported`, before the stepper is made (:func:`compiled_start`)."""
    if not issubclass(stepper_class, PredictorCorrector):
        return f"it compiles the default mode's augmented and velocity schemes, not mode={mode!r}, scheme={scheme!r}"
    index = ev.index
    if type(index) not in (JointDeviation, TimeVaryingReference):
        return f"it knows the indices JointDeviation (minimum_norm, mid_range) and TimeVaryingReference, not " \
               f"{type(index).__name__}"
    model = ev.robot.model
    if model.nq != model.nv:
        return f"the robot's configuration has nq = {model.nq} != nv = {model.nv} entries"
    if ev.task not in TASK_CODES:
        return f"unknown task kind {ev.task!r}"
    return ""


def compiled_start(backend: str | None, stepper_class: type, ev, mode: str, scheme: str):
    """The :class:`CompiledStart` for a stepper of ``stepper_class`` where :func:`attach` will give it the compiled
    backend (the core loads and runs the problem), else None (its start is Python's; :func:`attach` says why where
    ``backend`` insists). Raises ChoiceError: an unknown backend."""
    backend = check_backend(backend)[0]
    if backend == "python" or unsupported_problem(stepper_class, ev, mode, scheme):
        return None
    core = load_core()
    if core is None or not (hasattr(core, "start_run") and hasattr(core, "start_checks")):
        return None
    return CompiledStart(core)


def attach(tracker, backend: str | None, start: CompiledStart | None = None) -> str:
    """Pick ``tracker``'s backend (see the module docstring) and set ``tracker.step``; returns its name.
    ``start``: the stepper's :class:`CompiledStart` (:func:`compiled_start`), whose StepCore the steps use.

    Raises:
        OptionError: ``backend="compiled"`` where the core cannot run the problem or cannot be loaded.
        ChoiceError: an unknown backend.
    """
    if start is not None:  # compiled_start checked the backend, the problem and the core for this stepper's class
        return _compiled(tracker, start.module, start)
    backend, forced = check_backend(backend)
    if backend == "python":
        return "python"
    why = unsupported(tracker)
    if why:
        if forced:
            raise OptionError(f"backend='compiled' cannot run this problem: {why}; use backend='python' or 'auto'")
        return "python"
    core = load_core()
    if core is None:
        if backend == "compiled":
            raise OptionError(f"backend='compiled': the compiled core cannot be loaded ({core_error()}); reinstall "
                              "kinredund with pin[build] and nanobind beside pin, or use backend='python'")
        _warn_once()
        return "python"
    return _compiled(tracker, core, start)


def _compiled(tracker, core, start: CompiledStart | None) -> str:
    tracker.compiled = CompiledStep(tracker.stepper, core, start)
    tracker.step = tracker.compiled.step
    return "compiled"


_WARNED: list = []


def _warn_once() -> None:
    if not _WARNED:
        _WARNED.append(True)
        warnings.warn(f"kinredund's compiled core cannot be loaded ({core_error()}): tracking runs on the Python "
                      "stepper (same results, slower)", BackendWarning, stacklevel=4)


class CompiledStep:
    """The ordinary step of ``stepper`` in the compiled core; other steps are the stepper's own.

    Attributes:
        stepper: the Python stepper (its state is the run's state, as with the Python backend).
        steps, handed_back: steps taken in C++, and the steps handed back by reason (:data:`STATUS`).
        held_steps: of the steps taken in C++, those on the reduced route (a joint held on its bound, or a row held).
        row_steps: of the steps taken in C++, those with a general row held.
        held: the rows held in the core (:class:`~kinredund.tracking.compiled_rows.HeldRows`), or None: the steps
            with a row active are the Python stepper's.
        guard: the rows' compiled check of a step (the constraints' ``row_guard``, stacked by ``row_check``; held by
            the core: ``StepCore.set_guard``), or None.
    """

    def __init__(self, stepper: PredictorCorrector, core, start: CompiledStart | None = None):
        ev = stepper.ev
        n = stepper.n
        self.stepper, self.n = stepper, n
        self._python_step = stepper.step
        self.time_varying = isinstance(ev.index, TimeVaryingReference)
        limited = getattr(stepper, "lo", None) is not None
        made = start is not None and start.core is not None  # the start's StepCore, with the active set it holds
        self.core = start.core if made else make_step_core(stepper, core)
        self._fixed = start.fixed if made else None  # the active set the core holds (the stepper's ``fixed``)
        self.limited = limited
        self.rows = bool(getattr(stepper, "row_pairs", None))  # general rows: each step checked for a switch
        # the constraints' compiled check of a step, where each has one
        self.guard = row_check(stepper.general, ROW_TOL, core) if self.rows else None
        if self.guard is not None:  # the core runs the check right after its step (StepCore.step_guarded), and the
            self.core.set_guard(self.guard.compiled)  # stepper before its own search of a step (GeneralRows.step_check)
            stepper.step_check = self.guard
        self._basis = stepper.pt.basis
        self.ahead = SamplesAhead(ev.path, stepper.t0, stepper.dt)  # the path's samples of the next steps
        m = len(stepper.task_lam)  # the task's (a row active at the start appends its multiplier to lam)
        self.slices = row_slices(n, m)
        self.shapes = (n, m, n + m)
        self.layout = (self.slices, (n, m))  # what a CompiledPoint reads its fields with
        self.held = held_rows(stepper, self.core, self.guard, m)  # the steps with a row active in the core too
        self.steps = self.held_steps = self.row_steps = 0
        self.handed_back: dict[str, int] = {}
        if limited and stepper.qp_backend == "kkt" and hasattr(core.StepCore, "correct"):  # (proxsuite: the rates
            # of _correct's fallback are its QP's, not R's LU); where the rows are held here, it holds them too
            stepper.corrector = CoreCorrector(stepper, core, None if self.held is None else self.guard)
        if stepper.control is not None and hasattr(core, "watch_exact"):  # the exact measurements the runs' own
            stepper.control.watch.use_core(core)

    def hand_back(self, status: int) -> None:
        """The step as the Python stepper's, counted under ``status``'s reason (:data:`STATUS`)."""
        why = STATUS[status]
        self.handed_back[why] = self.handed_back.get(why, 0) + 1
        self._python_step()

    def step(self) -> None:
        """One step from t to t0 + (k + 1) dt: in C++ where it is ordinary, else the Python stepper's."""
        s = self.stepper
        ctl = s.control
        k = s.k + 1
        t_to = s.t0 + k * s.dt
        if self.rows and s.rows and (self.held is None or not self.held.valid()):  # a row active, in Python
            return self.hand_back(ROW_ACTIVE)
        if ctl is not None and ctl.watch.ahead(t_to) is not None:
            return self.hand_back(8)
        if self.limited and s.fixed is not self._fixed:
            self.sync_active()
        if self.held is not None:
            self.held.sync()
        ahead = self.ahead
        row = k - ahead.first
        if not 0 <= row < ahead.count:
            ahead.fill(k)
            row = 0
        at = ahead.samples
        if at is None:  # sampled here (a path not sampled ahead)
            sample = s.ev.sample(t_to)
            p, v = sample.p, sample.v
            Q, omega = core_orientation(sample)
        else:  # the PathSample itself is made only where the step's point is read (CompiledPoint)
            sample = None
            p, v, Q, omega = ahead.rows[row]
        ref, rate = core_reference(s.ev.index, t_to)
        args = (t_to, p, v, Q, omega, ref, rate, s.y, s.yd, s.prev, s.qdot, 0.0 if ctl is None else ctl.speed2,
                ctl is not None)
        cleared = smallest = None
        if self.guard is None:
            out = self.core.step(*args)
        else:  # the step and the scene's check of it in one call (h < 0: no check, not cleared; the rows held
            guard = self.guard  # are left out of it, as the stepper's search leaves them out)
            h = t_to - s.t if s.qdot is not None and guard.valid() else -1.0
            out = self.core.step_guarded(h, *args)
            if type(out) is not int:
                out, cleared, smallest = out
        if type(out) is int:
            return self.hand_back(out)
        return self.accept(out, sample, t_to, (at, row), cleared, smallest)

    def accept(self, out: np.ndarray, sample, t_to: float, ahead: tuple | None = None,
               cleared: bool | None = None, smallest: float | None = None) -> None:
        """The core's ordinary step to ``t_to`` (its output row ``out``, R's factors still in the core) as the
        stepper's new state, then the checks that may still hand it back to the Python stepper (from the state
        before it): with general rows, the stepper's own search for a switch within the step
        (``pending_switches``: a row reached, a row dipping below zero inside the step) unless the compiled check
        ruled one out (``cleared``: its verdict, which the core gives with the step wherever the rows have a check;
        None: there is none); the
        watch's measurement where due. Either rejection gives the Python stepper's step, which runs both itself.
        ``sample``: the path sample at ``t_to``, or None with ``ahead`` = (Samples, row) holding it. ``smallest``:
        the check's least row value at the step's end (its ``smallest``), handed to the stepper with a step
        it keeps (``keep_smallest``: the record's smallest value there, no query of its own)."""
        s = self.stepper
        ctl = s.control
        rcond = float(out[-2])
        held = self.rows and bool(s.rows)
        lu = self.held.factors() if held and ctl is not None else None  # (the inertia test's: odd_inertia)
        # nothing to check: the watch's gate passes it and, with a row held, R's inertia says no saddle (what
        # watch_point, which the Python step calls, would find: StepControl._indefinite on the same factors)
        if ctl is not None and (not self.rows or cleared) and not ctl.watch.due_next(rcond) and not (
                held and odd_inertia(*lu, self.n - int(np.count_nonzero(s.fixed)))):
            ctl.watch.passes(rcond)
            self.apply(out, sample, t_to, rcond, ahead, smallest, lu)
            ctl.speed2 = float(out[-1])
            return None
        measured = ctl is not None and (held or ctl.watch.due_next(rcond))
        look = self.rows and not cleared  # the stepper's search for a row switch is needed
        saved = None
        if measured or look:  # what a rejected step goes back to (the state, the control's speed)
            saved = ctl.snapshot() if ctl is not None else (s.state,)
        self.apply(out, sample, t_to, rcond, ahead, smallest, lu)
        if look and self._switch_within(saved[0]):
            return self._undo(saved, ROWS)
        if not measured:
            if ctl is not None:
                ctl.watch.passed(1, rcond)  # Watch.due of an unmeasured step
                ctl.speed2 = float(out[-1])
            return None
        watch = ctl.watch.save()  # the watch measures the new point: the step may still be rejected
        # the core measures with its J, M and R's factors (StepCore.watch_measure); the exact branch is Python's
        if ctl.watch_point(s.dt, float(out[-1]), self.core) is not None:  # rejected: the Python stepper's step
            ctl.watch.load(watch)
            return self._undo(saved, 9)
        return None

    def _switch_within(self, start) -> bool:
        """Does the stepper find a switch within the step from ``start`` to now? (A failure of its search, a
        corrector within the step that does not converge, is the Python step's to meet and name: True.)"""
        try:
            events, dips = self.stepper.pending_switches(start)
        except KinredundError:
            return True
        return bool(events or dips)

    def _undo(self, saved: tuple, status: int) -> None:
        """Drop the step just applied (back to ``saved``: the step control's snapshot, or the stepper's state in
        a 1-tuple without one) and hand it to the Python stepper."""
        ctl = self.stepper.control
        if ctl is not None:
            ctl.restore(saved)
        else:
            self.stepper.state = saved[0]
        self.steps -= 1
        self.held_steps -= self.limited and self.stepper.any_active
        self.row_steps -= self.rows and bool(self.stepper.rows)
        return self.hand_back(status)

    def output_layout(self) -> tuple:
        """(slices, (n, m)) of the core's output row now: with the rows the stepper holds where it holds any (they are
        the core's then: :class:`~kinredund.tracking.compiled_rows.HeldRows`, synced before a step), else the task's."""
        return self.held.layout if self.rows and self.stepper.rows else self.layout

    def sync_active(self) -> None:
        """Give the core the stepper's active set where it changed (a switch replaces the ``fixed`` array)."""
        if self.stepper.fixed is self._fixed:  # the common case, without making the bound values
            return
        fixed, side, bound = self.stepper.active_set()
        self.core.set_active(np.flatnonzero(~fixed).astype(np.int32), bound, side)
        self._fixed = fixed

    def apply(self, out: np.ndarray, sample, t_to: float, rcond: float, ahead: tuple | None = None,
              smallest: float | None = None, lu: tuple | None = None) -> None:
        """The core's step as the stepper's new state (:meth:`PredictorCorrector.accept`). R's factors stay in
        the core but with a row held (``lu``: fetched by :meth:`accept` for the step control's inertia test; without
        one only the watch's measurement reads them, and the step fetches them for it).
        ``sample``, ``ahead``: the path sample at ``t_to``; ``smallest``: the rows' least value there, where the
        compiled check has it (see :meth:`accept`; a step put back later leaves it with a q no longer current)."""
        s = self.stepper
        held = self.rows and bool(s.rows)
        sy, ssol, sM, _, sq, _, _, _, s_mu, s_label = self.output_layout()[0]
        n = self.n
        M = out[sM].reshape(n, n)
        if held:  # the extended evaluation (the rows held at this step) where more than J is read
            pt = self.held.point(out, t_to, sample, self._basis, ahead)
        else:
            pt = CompiledPoint(s.ev, out, t_to, sample, self._basis, self.layout, ahead)
        if self.limited and s.any_active:  # joints held: the reduced system's label, the bound multipliers
            label = s.reduced_label(M, pt.J, int(out[s_label][0]))
            s.accept(out[sy], out[ssol], pt, M, out[sq], rcond, label=label, mu=out[s_mu], lu=lu)
            self.held_steps += 1
        else:
            s.accept(out[sy], out[ssol], pt, M, out[sq], rcond)
        self.row_steps += held
        if smallest is not None and smallest == smallest:  # (NaN: the check stopped before its values)
            s.keep_smallest(smallest)
        self.steps += 1
