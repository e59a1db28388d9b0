"""The Python stepper's corrector in the compiled core (issue 28): :class:`CoreCorrector`.

On the compiled backend (:mod:`kinredund.tracking.compiled`) the steps the core does not take are the Python stepper's:
a bound reached or released, a chord that failed, a jump, the watch's rejections; within them the switching-time
location (:mod:`kinredund.tracking.switches`: Brent's method, each evaluation a corrector solve) and the sub-steps of
the step control. The switching-time search itself runs in the core where it starts from the step's start
(:meth:`CoreCorrector.locate`: ``StepCore.locate``, Brent's method of ``src/core/brent.hpp`` with the iterates of
:func:`~kinredund.tracking.roots.brent_root`, each evaluation the Euler prediction and the corrector below, the watched
quantity read from the corrected point or, for a row's value, the rows' compiled check; Python's search runs where it
declines). Each of those corrector solves
(:meth:`~kinredund.tracking.predictor_corrector.PredictorCorrector._correct` with the limited stepper's wrapper,
:mod:`kinredund.tracking.limited`) is the core's ``StepCore.correct`` (``src/core/step.cpp``, the GIL released): from
the prediction, the held joints set on their bounds, one evaluation with dK, R's LU factors, the rates of Eq. (4.24),
the Newton update and the chord iterations, where those fail the fallback of ``_correct`` (``_newton`` from the
prediction and ``_rates``, the core's start route; the predictor's history cleared), and the bound multipliers at the
corrected point. The stepper stays independent of the core: :class:`CoreCorrector` is an optional ``corrector`` that
:class:`~kinredund.tracking.compiled.CompiledStep` installs on a limited stepper, whose ``_correct`` calls it first.
With a general row active it solves where the compiled step holds the rows too (a scene's, a sphere's, a plane's:
:mod:`kinredund.tracking.compiled_rows`, the same extended system and the rates afresh where the corrector ends far from
the prediction), else it declines (the extended system then stays Python's); the Newton solve after a switch
(:meth:`CoreCorrector.settle`) where the rows' check settles them too (not a scene's). It holds a StepCore of its own
(the compiled step's keeps its last step's factors for the watch's measurement), gives it the stepper's active set,
samples the path (and a time-varying reference) at the stepper's time and takes the core's result as ``_correct`` leaves
it (:meth:`~kinredund.tracking.predictor_corrector.PredictorCorrector.take_corrected`: q, lambda, their rates, M, the
evaluation as a :class:`~kinredund.tracking.compiled_point.CompiledPoint`, the label of the reduced system where joints
are held, R's LU factors and condition estimate, the bound multipliers). A solve the core cannot make ordinarily (a
singular or ill-conditioned R, non-finite rates, a fallback that fails too) is Python's own ``_correct`` from the same
inputs: every error, its message and its cause stay the Python stepper's.
"""

from __future__ import annotations

import numpy as np

from kinredund.tracking.ahead import core_orientation, core_reference
from kinredund.tracking.compiled_point import CompiledPoint
from kinredund.tracking.compiled_rows import HeldRows
from kinredund.tracking.compiled_start import make_step_core, row_slices
from kinredund.tracking.constraints.base import Constraint
from kinredund.tracking.roots import SWITCH_RTOL, SWITCH_XTOL
from kinredund.tracking.rows import ROW_TOL


class CoreCorrector:
    """A limited stepper's corrector solve in the core (see the module docstring); ``stepper.corrector``.

    Attributes:
        used: the solves the core made; declined: those it left to Python (a status other than OK); restarts: the
            solves (of ``used``) whose chord iterations failed, made by the fallback (fresh factorisations);
            row_solves: those (of ``used``) with general rows held; settled: the Newton solves after a switch
            (:meth:`settle`) of ``used``.
    """

    def __init__(self, stepper, module, guard=None):
        self.stepper, self.module, self._guard = stepper, module, guard  # guard: the compiled step's row check,
        self.held = None  # with which the core holds the rows (HeldRows, made with the core); None: rows are Python's
        self.core = None  # made on the first solve (a run without a handed-back step makes none)
        self._fixed = None  # the active set the core holds (the stepper's ``fixed``)
        n, m = stepper.n, len(stepper.task_lam)
        self.n, self.layout = n, (row_slices(n, m), (n, m))
        self._basis = stepper.pt.basis
        self.used = self.declined = self.restarts = self.row_solves = self.settled = 0
        self.located = self.locates_declined = 0

    def __call__(self, y: np.ndarray) -> bool:
        """The stepper's corrector at its time t from the prediction ``y`` = [q; lambda]; False (the stepper
        untouched) where the core leaves it to Python."""
        return self._solve(y, False)

    def settle(self) -> bool:
        """:meth:`~kinredund.tracking.predictor_corrector.PredictorCorrector._newton` from the stepper's point at
        its time t, then ``_rates`` there (after a switch of the active set): the core's route of ``_correct``'s
        fallback; False (the stepper untouched) where the core leaves them to Python, or with general rows whose
        check does not settle them (a scene's: its stops' diagnosis, a bisection of witness points near parallel
        faces, follows the rounding of the switch's point, and the two backends' stops name the same words;
        ``RowCheck.settles``)."""
        s = self.stepper
        if s.row_pairs and (self._guard is None or not self._guard.settles):
            return False
        made = self._solve(np.concatenate([s.q, s.lam]), True)
        self.settled += made
        return made

    def locate(self, anchor, a: float, b: float, fa: float, fb: float, key: int, kind: str) -> float | None:
        """The switching-time search of :meth:`~kinredund.tracking.switches.SwitchLocation._crossing` in the core
        (``StepCore.locate``, ``src/core/brent.hpp``: Brent's method as ``roots.brent_root``, the GIL released but for
        the path's samples): the time in (a, b] where the watched quantity of (``key``, ``kind``) reaches zero, each
        evaluation ``euler_to`` from ``anchor`` (a state at a, the stepper's active set) as this corrector's solve.
        ``fa``, ``fb``: the quantity at a and b (fb NaN where the search has not evaluated it). None where the core
        leaves the search to Python (a solve it declines, a row it does not compute, no bracket, no convergence, an
        error raised by the path's sample or a user's function): the caller's own search then runs from the same
        inputs and meets it itself."""
        s = self.stepper
        if anchor.yd is None or (kind.startswith("row") and self._guard is None) or not self._ready():
            return None
        n, m = self.n, len(s.task_lam)
        row, own, index, sign, level = -1, None, 0, 1.0, 0.0
        if kind == "lower":
            index, level = key, float(s.lo[key])
        elif kind == "upper":
            index, sign, level = key, -1.0, float(s.hi[key])
        elif kind == "release":
            index = (self.held.layout if s.rows else self.layout)[0][8].start + key  # the bound multipliers
        elif kind == "row_release":
            index, sign = n + m + s.rows.index(key), -1.0  # its w: nu = -w
        else:  # row_reach: the row's value c, or 2 ROW_TOL where it does not stand for itself (GeneralRows._row_watch;
            row = key  # today's compiled checks are of constraints whose rows always do: own stays None for them)
            ci, ri = s.row_pairs[key]
            con = s.general[ci]
            if type(con).representative is not Constraint.representative:
                own = lambda q: con.representative(q, ri) == ri  # noqa: E731
        sample_at = self._sample_at
        try:
            got = self.core.locate(anchor.t, anchor.y, anchor.yd, a, b, fa, fb, index, sign, level, row, 2 * ROW_TOL,
                                   sample_at, own, SWITCH_XTOL, SWITCH_RTOL, 100)
        except Exception:  # noqa: BLE001 (the path's sample or a user's function raised: Python's search, which
            got = None  # makes the same evaluations, meets it and names it, switch_not_resolved as before)
        if type(got) is not float:
            self.locates_declined += 1
            return None
        self.located += 1
        return got

    def system_at(self, q: np.ndarray, t: float, lam: np.ndarray) -> tuple | None:
        """(J, M, top) of the stepper's :meth:`~kinredund.tracking.predictor_corrector.PredictorCorrector.system_at`
        in the core (``StepCore.evaluate``: the evaluation with the rows held, M with their curvature); None where
        the core does not hold the rows active."""
        if not self._ready():
            return None
        _, J, _, _, M, top = self.core.evaluate(q, lam, *self._sample_at(t))
        return J, M, top

    def _sample_at(self, t: float) -> tuple:
        """The path's sample and the index's reference at t as the core's ``correct`` takes them."""
        s = self.stepper
        sample = s.ev.sample(t)
        return (sample.p, sample.v, *core_orientation(sample), *core_reference(s.ev.index, t))

    def _ready(self) -> bool:
        """The core made and given the stepper's active set and rows; False where a row is active that it does not
        hold (the solve is Python's then)."""
        s = self.stepper
        if s.rows and (self._guard is None or not self._guard.valid()):  # a row active the core does not hold
            return False
        if self.core is None:
            self.core = make_step_core(s, self.module)
            if self._guard is not None:
                self.core.set_guard(self._guard.compiled)
                self.held = HeldRows(s, self.core, self._guard, len(s.task_lam))
        if self.held is not None:
            self.held.sync()  # the rows active now (a switch replaces the ``rows`` tuple)
        if s.fixed is not self._fixed:  # a switch replaces ``fixed``: the core's active set follows
            fixed, side, bound = s.active_set()
            self.core.set_active(np.flatnonzero(~fixed).astype(np.int32), bound, side)
            self._fixed = fixed
        return True

    def _solve(self, y: np.ndarray, newton: bool) -> bool:
        s = self.stepper
        if not self._ready():
            return False
        t = s.t
        sample = s.ev.sample(t)
        Q, omega = core_orientation(sample)
        ref, rate = core_reference(s.ev.index, t)
        got = self.core.correct(t, sample.p, sample.v, Q, omega, ref, rate, y, newton)
        if type(got) is int:
            self.declined += 1
            return False
        out, restarted, lu, piv = got
        if restarted and not newton:  # the predictor missed (PredictorCorrector._correct's fallback): Euler next
            s.prev.clear()
            self.restarts += 1
        n = self.n
        if s.rows:  # the extended evaluation's point (its J with the rows')
            sl = self.held.layout[0]
            pt = self.held.point(out, t, sample, self._basis, None)
        else:
            sl = self.layout[0]
            pt = CompiledPoint(s.ev, out, t, sample, self._basis, self.layout)
        M = out[sl[2]].reshape(n, n)
        label = s.reduced_label(M, pt.J, int(out[sl[9]][0])) if s.any_active else None
        s.take_corrected(out[sl[0]], out[sl[1]], pt, M, (lu, piv), float(out[-2]), label=label, mu=out[sl[8]])
        self.used += 1
        self.row_solves += bool(s.rows)
        return True
