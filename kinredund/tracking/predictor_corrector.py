"""The default mode of the optimal schemes: predictor along the optimal path, Newton corrector (Chapter 4).

Each step predicts y = [theta; lambda] at t + dt by Hermite extrapolation through the last points and
their rates (quintic once three are known; Euler at the first step), then corrects onto the first-order
system F(theta, lambda) = [grad z + J^T lambda; g(theta) - x(t)] = 0 (Eq. 4.5 and the task) with R of
Eq. (4.24) factorised at the predicted point; the same LU factors give the rates for the next
prediction. The task and the normality condition are then both held to ~1e-12 and the joints close to
machine precision loop after loop. Both the displacement form (``augmented``: J, M = Hess z + Lambda)
and the velocity form (``velocity``: K, lambda*, M* = Hess z + Lambda*, Eqs. 4.30-4.42) run here; the
:class:`~kinredund.tracking.point.Evaluator`'s formulation says which.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from kinredund.errors import PathError, SingularityError, TrackingError
from kinredund.tracking.failure import start_failure
from kinredund.tracking.linalg import hermite_weights, lu_solve
from kinredund.tracking.point import Evaluator, Point
from kinredund.tracking.step_control import StepControl
from kinredund.tracking.stepper import Stepper

#: points (values and slopes) of the default mode's Hermite predictor: 3 gives the quintic, whose O(h^6)
#: error lets one Newton update end the corrector on smooth paths at 200 steps per loop (median miss
#: ~1e-10 rad on Examples 4.1, 4.2 and the Panda circle; ~1e-5 on the fast Example 4.3, which needs
#: chord iterations): ``python benchmarks/resolved_rate.py`` prints both figures per robot
PREDICTOR_POINTS = 3


@functools.lru_cache(maxsize=64)
def predictor_weights(dt: float) -> tuple:
    """(None, then the weights of the Hermite extrapolation through 2, ..., PREDICTOR_POINTS points:
    :func:`~kinredund.tracking.linalg.hermite_weights`) for the time step dt [s]: made once per dt, read-only, and
    shared by the runs with that step."""
    weights = [hermite_weights(dt, k + 1) for k in range(1, PREDICTOR_POINTS)]
    for w in weights:
        w.flags.writeable = False
    return (None, *weights)


class PredictorCorrector(Stepper):
    """The default mode's stepper (augmented or velocity form): Hermite predictor, Newton corrector.

    State besides :class:`~kinredund.tracking.stepper.Stepper`'s: ``prev`` (y and ydot of up to
    ``PREDICTOR_POINTS - 1`` earlier points, oldest first, a flat list) and ``_y``, ``_yd`` (the current
    point and its rates). The start is corrected onto the optimal manifold before the first step.
    ``strict`` (default): each step runs through the :class:`~kinredund.tracking.step_control.StepControl`
    (sub-steps, the jump check, the fold and singularity watch; failures are a
    :class:`~kinredund.errors.TrackingError`); ``strict=False`` is the plain predictor-corrector step.
    ``start``: called with the stepper where it would correct its start and solve for the rates; where it returns
    True it made them itself (the compiled core's :class:`~kinredund.tracking.compiled_start.CompiledStart`, through
    :meth:`take_start`), else this stepper does; its ``checks`` make the start's rank check and lambda where J is
    clearly of full rank (:meth:`_check_start`).
    """

    #: the corrector solves made elsewhere, or None (this stepper's own): the compiled backend's
    #: :class:`~kinredund.tracking.compiled_correct.CoreCorrector`, which the limited stepper's ``_correct`` calls
    #: first with the prediction (True: it made the solve) and :meth:`_newton_rates` with none (``settle``); also the
    #: switching-time search (``locate``, :mod:`kinredund.tracking.switches`) and the evaluations of :meth:`system_at`
    corrector = None

    def __init__(self, evaluator: Evaluator, q0: np.ndarray, dt: float, strict: bool = True, start=None, **kwargs):
        self._start = start  # (its start checks run in the base class's __init__: _check_start)
        super().__init__(evaluator, q0, dt, **kwargs)
        self.symmetric = evaluator.formulation == "augmented"
        self._hermite = predictor_weights(self.dt)
        self.control = None
        self.start_measure = None  # the watch's exact measurement at the start where take_start gave it
        try:
            if start is None or not start(self):  # the compiled core's start (take_start), else this one
                # exactly onto the optimal manifold (Eq. 4.5), one Newton update at least: a start within the
                # corrector's tolerance (an IK answer) would else stay up to tol / sigma_min(R) off the point the
                # run comes back to after a loop, and a closed path would not close to rounding
                self._newton(self.pt if start is None else None, polish=True)
                self._rates()
            if strict and evaluator.index is not None:
                self.control = StepControl(self)
                self.start_measure = None  # kept by the control's watch
                if self.control.start_verdict() is not None:  # a saddle or maximum of z, or a singular start
                    raise SingularityError(f"the corrected start is not a regular constrained minimum "
                                           f"({self.control.start_verdict()})")
        except TrackingError:  # already named (a subclass of both below: not to be renamed as a start failure)
            raise
        except (PathError, SingularityError) as err:
            if not strict:
                raise
            evaluator.check_sample(self.t0)  # a non-finite path sample says so itself
            raise start_failure(self, q0, err) from err

    def _start_point(self) -> Point:
        """With a compiled start, the evaluation without dK that its checks read (the core evaluates afresh; a start
        left to Python evaluates again, the same numbers): :meth:`Evaluator.start_point`."""
        if self._start is None:
            return super()._start_point()
        return self.ev.start_point(self.q, self.t)

    def _check_start(self, pt: Point) -> np.ndarray | None:
        """The start's rank check and lambda, by the compiled start where there is one (``checks``: the same
        LAPACK calls with the GIL released), else :meth:`Stepper._check_start`."""
        if self._start is None:
            return super()._check_start(pt)
        clear, lam = self._start.checks(pt)
        if not clear:  # near the floor (or not finite): the Python check decides, and names a singularity
            self._check_rank(pt)
        return lam

    def step(self) -> None:
        """One step; with ``strict``, under the step control (:mod:`kinredund.tracking.step_control`)."""
        if self.control is None:
            self.plain_step()
        else:
            self.control.step()

    def plain_step(self) -> None:
        """Predict y at t + dt (Euler at the first step, then Hermite: cubic, then quintic) and correct."""
        h = self.dt
        y, yd = self.y, self.yd
        prev = self.prev  # [y, ydot, y, ydot, ...], oldest first
        y_p = self._hermite[len(prev) // 2] @ np.array(prev + [y, yd]) if prev else y + h * yd
        self._advance()
        self.q_pred = y_p[: self.n]  # the step control compares the corrected joints with it
        self._correct(y_p)  # checks its results for non-finite values

    def _advance(self) -> None:
        """The current point and its rates join the predictor's history (the oldest pair leaves when full) and the
        clock moves on a requested step: t = t0 + (k + 1) dt (one call: it runs at every step)."""
        prev = self.prev
        prev += (self.y, self.yd)
        if len(prev) == 2 * PREDICTOR_POINTS:
            del prev[:2]
        self.k = k = self.k + 1
        self.t = self.t0 + k * self.dt

    @property
    def hermite(self) -> tuple:
        """The predictor's weights: entry k (k >= 1) those of the Hermite extrapolation through k + 1 points (of
        (y, ydot) pairs, oldest first; :func:`~kinredund.tracking.linalg.hermite_weights`; read-only), entry 0 None
        (Euler)."""
        return self._hermite

    def accept(self, y: np.ndarray, yd: np.ndarray, pt: Point, M: np.ndarray, q_pred: np.ndarray, rcond: float,
               label: str | None = None, lu=None, **_) -> None:
        """Take a whole step computed elsewhere (the compiled core, :mod:`kinredund.tracking.compiled`) as this
        stepper's own, leaving the state as :meth:`plain_step` leaves it: the predictor's history, the clock
        (t0 + (k + 1) dt), the corrected ``y`` = [q; lambda] and its rates ``yd``, the step's evaluation ``pt``
        and M there, the predicted joints ``q_pred`` and R's condition estimate ``rcond`` (its factors ``lu``
        are None unless given: ``lu`` = (lu, piv) in LAPACK's layout). ``label``: the step's solver label, if known."""
        self._advance()
        self.q_pred = q_pred
        self._take(y, yd, pt, M, rcond, label)
        self.lu = lu

    def take_start(self, y: np.ndarray, yd: np.ndarray, pt: Point, M: np.ndarray, rcond: float,
                   label: str | None = None, exact: tuple | None = None, **_) -> None:
        """Take the start corrected onto the optimum and its rates, made elsewhere (the compiled core:
        :class:`~kinredund.tracking.compiled_start.CompiledStart`), as :meth:`_newton` and :meth:`_rates` leave
        them: y = [q; lambda] at t0, its rates ``yd``, the evaluation ``pt`` and M there, R's condition estimate
        ``rcond`` (``lu`` None). ``exact``: the watch's exact measurement there (sigma_min_J, eig, v, scale: the core's
        ``watch_exact`` on the free joints), which the step control keeps instead of measuring."""
        self._take(y, yd, pt, M, rcond, label)
        self.start_measure = exact

    def take_corrected(self, y: np.ndarray, yd: np.ndarray, pt: Point, M: np.ndarray, lu, rcond: float,
                       label: str | None = None, **_) -> None:
        """Take a corrector solve made elsewhere (the compiled core: :mod:`kinredund.tracking.compiled_correct`) as
        :meth:`_correct` leaves the state: the corrected ``y`` = [q; lambda] and its rates ``yd``, the evaluation
        ``pt`` and M there, R's LU factors ``lu`` = (lu, piv) in LAPACK's layout and their condition estimate
        ``rcond``; ``label``: the step's solver label, if known (the caller clears the predictor's history where the
        solve needed the fallback)."""
        self._take(y, yd, pt, M, rcond, label)
        self.lu = lu

    def system_at(self, q: np.ndarray, t: float, lam: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(J, M, top) of Eq. (4.24) at (q, t) with the multipliers ``lam``: the full evaluation's (with the active
        rows' where the stepper holds some), made by the :attr:`corrector` where it makes them (the core's, the same
        numbers to rounding), else by this stepper's ``evaluate``."""
        made = None if self.corrector is None else self.corrector.system_at(q, t, lam)
        if made is not None:
            return made
        pt = self.evaluate(q, t)
        M, top = pt.system(lam)
        return pt.J, M, top

    def _take(self, y, yd, pt, M, rcond, label) -> None:
        n = self.n
        self.q, self.lam, self.y, self.yd = y[:n], y[n:], y, yd
        self.qdot, self.lamdot, self.label, self.M, self.pt = yd[:n], yd[n:], label, M, pt
        self.lu, self.rcond = None, rcond

    def euler_to(self, t_next: float) -> None:
        """From the current point to t_next: Euler prediction y + (t_next - t) ydot, then the corrector (a
        sub-step of the step control, a step to a switching time of the limits)."""
        h = t_next - self.t
        self.t = t_next
        self._correct(self.y + h * self.yd)

    def _rates(self) -> None:
        """Evaluate the full system at the current point and solve Eq. (4.24) for the rates."""
        pt = self.evaluate(self.q, self.t)
        self._solve_rates(pt, pt.xdot)
        self.y, self.yd = np.concatenate([self.q, self.lam]), np.concatenate([self.qdot, self.lamdot])

    def _solve(self, lu, b: np.ndarray) -> np.ndarray:
        """Solve R x = b with R's LU factors (:meth:`_factor`); b and x of size n + m."""
        return lu_solve(lu, b)

    def _residual(self, pt: Point, lam: np.ndarray) -> np.ndarray:
        """The first-order residual F = [grad z + J^T lambda; r] the corrector drives to zero."""
        return pt.residual(lam)

    def _tol(self, pt: Point) -> float:
        """The corrector's tolerance on ||F||_2, scaled by the gradient: tol max(1, ||grad z||)."""
        return self.tol * max(1.0, math.sqrt(float(pt.grad @ pt.grad)))

    def _newton(self, pt: Point | None = None, max_fresh: int = 6, polish: bool = False) -> None:
        """Corrector onto F(theta, lambda) = [grad z + J^T lambda; r] = 0 at self.t from (self.q, self.lam).

        Rounds of chord iterations (:meth:`_chord`), each with R factorised afresh at its first iterate;
        ``pt`` is the full evaluation at the current point when the caller has it. ``polish``: the first round
        makes its first update even where F is already within the tolerance (a Newton update, R being factorised
        there: the point then lies on the manifold to rounding; the run's start).
        """
        n = self.n
        y = np.concatenate([self.q, self.lam])
        for _ in range(max_fresh + 1):
            if pt is None:
                pt = self.evaluate(y[:n], self.t)
            lu = self._factor(pt, pt.system(y[n:])[0])
            y, ok = self._chord(y, lu, self._tol(pt), F=self._residual(pt, y[n:]), polish=polish)
            polish = False
            if ok:
                self.q, self.lam = y[:n], y[n:]
                return
            pt = None
            if not math.isfinite(float(y @ y)):
                break
        raise PathError(
            f"the corrector did not converge at t = {self.t:.6g} s: the path leaves the workspace or crosses a "
            "singularity", t=self.t, q=self.q)

    def _newton_rates(self) -> None:
        """:meth:`_newton` from the current point, then :meth:`_rates` (the :attr:`corrector`'s ``settle`` where it
        makes them)."""
        if self.corrector is None or not self.corrector.settle():
            self._newton()
            self._rates()

    def _correct(self, y: np.ndarray) -> None:
        """Corrector at self.t from the predicted y = [q; lambda], then the rates for the next step.

        One evaluation at the predicted point gives R (Eq. 4.24), the residual F = [grad z + J^T lambda; r]
        and the right-hand side of Eq. (4.24); R's LU factors give both the Newton update d and the rates
        (all at the predicted point, within the corrector's step of the corrected one).
        A Newton update with |d|^2 <= tol (scaled) leaves an error of order tol (quadratic convergence)
        and ends the iteration - the tests check the recorded residuals, evaluated afresh, stay ~1e-12;
        otherwise chord iterations with fresh residuals follow, then fresh factorisations
        (:meth:`_newton`). Norms are 2-norms (one dot product each).
        """
        n = self.n
        lam = y[n:]
        pt = self.evaluate(y[:n], self.t)
        M, top = pt.system(lam)  # Eqs. (4.23), (4.37)
        lu, piv = self._factor(pt, M)
        # one right-hand side per solve: dgetrs with two goes through a level-3 triangular solve, slower
        # on these sizes and, with OpenBLAS threads, prone to millisecond waits on a busy machine
        sol = self._solve((lu, piv), np.concatenate((top, pt.xdot)))  # Eq. (4.24)
        if not math.isfinite(float(sol @ sol)):  # the rates are finite iff the step's terms are
            self.ev.check_sample(self.t)
            raise PathError(f"non-finite joint rates at t = {self.t:.6g} s", t=self.t, q=y[:n])
        F = self._residual(pt, lam)
        tol = self._tol(pt)
        if not float(F @ F) <= tol * tol:  # "not <=": a NaN residual is not converged
            d = self._solve((lu, piv), F)
            y_pred, y = y, y - d
            if not float(d @ d) <= tol:
                y, ok = self._chord(y, (lu, piv), tol)
                if not ok:  # no convergence with this factorisation: fresh ones from the prediction
                    self.q, self.lam = y_pred[:n], y_pred[n:]
                    self.prev.clear()  # the predictor missed (a jump in the path?): restart it with Euler
                    self._newton()
                    self._rates()
                    return
        self.q, self.lam = y[:n], y[n:]
        self.y, self.yd = y, sol
        self.qdot, self.lamdot, self.label, self.M, self.pt = sol[:n], sol[n:], None, M, pt

    def _chord(self, y: np.ndarray, lu, tol: float, F: np.ndarray | None = None,
               max_iter: int = 8, polish: bool = False) -> tuple[np.ndarray, bool]:
        """Chord iterations on F with fresh residuals and R's factors kept: (last iterate, converged).

        The factors belong to another point, so the iteration converges only linearly: it ends on the
        residual itself (||F|| <= tol), never on the size of the update. ``F``: the residual at ``y``
        if the caller has it. ``polish``: the first update is made whatever F (:meth:`_newton`); from a point already
        within the tolerance it ends the iteration where it is small (|d|^2 <= tol, as in :meth:`_correct`). A
        non-finite path sample is reported (PathError) when it fails.
        """
        n = self.n
        for k in range(max_iter):
            if F is None:
                F = self._residual(self.evaluate(y[:n], self.t, need_dJ=False), y[n:])
            if float(F @ F) <= tol * tol:
                if not (polish and k == 0):
                    return y, True
                d = self._solve(lu, F)  # polish: one Newton update from a point already within tol
                y = y - d
                if float(d @ d) <= tol:  # _correct's criterion: an error of order tol^2 (quadratic convergence)
                    return y, True
                F = None
                continue
            y = y - self._solve(lu, F)
            F = None
        self.ev.check_sample(self.t)  # a non-finite path sample says so itself
        return y, False
