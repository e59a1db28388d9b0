"""The compiled core's StepCore, its output row read in Python, and a run's start in the core (issue 28).

:func:`make_step_core` makes the core's ``StepCore`` of a stepper's problem; :func:`row_slices` is the layout of its
output row (``src/core/step.cpp``: StepCore's step and start write it), which
:class:`~kinredund.tracking.compiled_point.CompiledPoint` reads lazily as a step's evaluation. :class:`CompiledStart`
makes a run's start in the core with the GIL released (``start_run``: the correction onto the optimum, the rates,
the watch's first, exact measurement), the work that held the GIL in
:func:`~kinredund.tracking.many.track_many`'s threads. The driver of the steps is :mod:`kinredund.tracking.compiled`,
which picks the backend (its ``compiled_start`` gives the tracker a CompiledStart) and steps with the StepCore the
start made.
"""

from __future__ import annotations

import functools

import numpy as np

from kinredund.indices import TimeVaryingReference
from kinredund.tracking.ahead import EMPTY, core_orientation, core_reference
from kinredund.tracking.compiled_point import CompiledPoint
from kinredund.tracking.predictor_corrector import PredictorCorrector
from kinredund.tracking.watch import SIGMA_FLOOR

#: the task kinds' codes in the core (src/core/step.cpp)
TASK_CODES = {"planar": 0, "position": 1, "pose": 2, "axis": 3}


def core_hermite(weights) -> list:
    """The predictor's Hermite weights (:func:`~kinredund.tracking.predictor_corrector.predictor_weights`: None,
    then float arrays) as the core takes them: :data:`~kinredund.tracking.ahead.EMPTY` for None."""
    return [EMPTY if w is None else w for w in weights]


def make_step_core(stepper: PredictorCorrector, core):
    """The core's ``StepCore`` of ``stepper``'s problem (its robot, task, index, tolerance, time step, predictor
    weights and the limits' switch bounds): made once the stepper has set these, before its start."""
    ev = stepper.ev
    index = ev.index
    n = stepper.n
    if isinstance(index, TimeVaryingReference):
        weights = np.ones(n) if index.weights is None else np.asarray(index.weights, float)
        reference = np.zeros(n)
    else:
        weights, reference = index.weights, index.reference
    limited = getattr(stepper, "lo", None) is not None
    lo_tol, hi_tol = stepper.switch_limits if limited else (EMPTY, EMPTY)
    hermite = core_hermite(stepper.hermite)
    return core.StepCore(ev.robot.model, int(ev.robot.ee_frame_id), TASK_CODES[ev.task],
                         ev.formulation == "velocity", np.asarray(weights, float), np.asarray(reference, float),
                         isinstance(index, TimeVaryingReference), stepper.tol, stepper.dt, hermite, lo_tol, hi_tol)


@functools.lru_cache(maxsize=64)
def row_slices(n: int, m: int) -> tuple[slice, ...]:
    """The fields of the core's output row (``src/core/step.cpp``, StepCore's step and start) for n joints and a task
    of dimension m: y and its rates (n + m each), M (n x n), J (m x n), the predicted joints (n), the pose's Q (9)
    and p (3) at the corrected joints, the evaluation's point (n), the bound multipliers (n), the label verdict (1);
    rcond and |qdot|^2 follow them. Made once per (n, m)."""
    N = n + m
    ends = np.cumsum([N, N, n * n, m * n, n, 9, 3, n, n, 1]).tolist()
    return tuple(slice(a, b) for a, b in zip([0, *ends[:-1]], ends, strict=True))


class CompiledStart:
    """The start of a run in the core (``start_run``: ``src/core/step.cpp``, the GIL released): the
    :class:`~kinredund.tracking.predictor_corrector.PredictorCorrector` calls it with itself where its Python start
    would correct onto the optimum (``_newton``), solve for the rates (``_rates``) and then measure with the watch.

    The core makes the ``StepCore`` (:func:`make_step_core`; :class:`~kinredund.tracking.compiled.CompiledStep` then
    steps with it), gives it the stepper's active set, and from the stepper's [q; lambda] at t0 and the path's sample
    there (the stepper's first evaluation's) makes the corrector's rounds, the rates and the bound multipliers at the
    corrected point and the watch's exact measurement there, as the Python start does them (to rounding:
    ``tests/test_tracking_compiled.py``). The stepper takes them
    (:meth:`~kinredund.tracking.predictor_corrector.PredictorCorrector.take_start`), its step control the measurement. A
    start the core cannot make ordinarily (a singular or ill-conditioned R, a corrector that does not converge,
    non-finite rates) is the Python stepper's: it meets and names the failure as on the Python backend. (The tracker
    gives a stepper with general rows, :mod:`kinredund.tracking.rows`, none: their extended system is Python's.)

    Attributes:
        core: the StepCore (None until called); fixed: the stepper's ``fixed`` array whose active set the core
            holds (None: all joints free).
    """

    def __init__(self, module):
        self.module, self.core, self.fixed = module, None, None

    def checks(self, pt) -> tuple[bool, np.ndarray | None]:
        """The start's rank check and lambda at ``pt`` (the stepper's first evaluation) in the core (``start_checks``,
        the GIL released: scipy's LAPACK calls of :func:`~kinredund.tracking.linalg.multipliers`, the same numbers,
        and from their QR a bound on sigma_min(J)): (J clearly of full rank: sigma_min(J) certainly above 4x the
        stepper's floor, so that its own check passes; lambda, or None where the stepper computes it)."""
        return self.module.start_checks(pt.J, pt.grad, 4.0 * SIGMA_FLOOR)

    def __call__(self, stepper: PredictorCorrector) -> bool:
        """Make ``stepper``'s start in the core; False (the stepper's state untouched) where it is Python's."""
        core = self.core = make_step_core(stepper, self.module)
        active = getattr(stepper, "any_active", False)
        if active:
            fixed, side, bound = stepper.active_set()
            core.set_active(np.flatnonzero(~fixed).astype(np.int32), bound, side)
            self.fixed = fixed
        else:  # a new StepCore holds every joint free: the limited stepper's ``fixed`` as it is (none held), so that
            self.fixed = getattr(stepper, "fixed", None)  # CompiledStep.sync_active has nothing to give the core
        pt, t = stepper.pt, stepper.t
        sample = pt.sample
        Q, omega = core_orientation(sample)
        ref, rate = core_reference(stepper.ev.index, t)
        got = self.module.start_run(core, sample.p, sample.v, Q, omega, ref, rate,
                                    np.concatenate([stepper.q, stepper.lam]))
        if type(got) is int:
            return False
        out, exact = got
        n, m = stepper.n, len(stepper.lam)
        slices = row_slices(n, m)
        sy, ssol, sM = slices[:3]
        M = out[sM].reshape(n, n)
        point = CompiledPoint(stepper.ev, out, t, sample, pt.basis, (slices, (n, m)))
        label = None
        if active:
            label = stepper.reduced_label(M, point.J, int(out[slices[9]][0]))
        stepper.take_start(out[sy], out[ssol], point, M, float(out[-2]), label=label, mu=out[slices[8]],
                           exact=exact)
        return True
