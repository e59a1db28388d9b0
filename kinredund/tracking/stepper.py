"""The state and the checks every tracking scheme shares (Chapter 4).

A :class:`Stepper` holds the explicit state of one run: the time ``t = t0 + k dt`` (no accumulated
rounding), the joints ``q``, the multipliers ``lam``, the rates ``qdot`` and ``lamdot``, and the last
evaluation ``pt``. Its subclasses are the schemes (one class per mode and scheme):
:class:`~kinredund.tracking.predictor_corrector.PredictorCorrector` (default mode, augmented and velocity
forms), :class:`~kinredund.tracking.explicit.ExplicitEuler` (thesis mode, Eq. 4.29) and the baselines of
:mod:`kinredund.tracking.baselines`. Each implements :meth:`Stepper.step`.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import lapack

from kinredund.errors import PathError, SingularityError
from kinredund.tracking.failure import singular_start, step_too_long
from kinredund.tracking.linalg import RateQP, classify, multipliers, solve_rates
from kinredund.tracking.point import Evaluator, Point
from kinredund.tracking.state import StepState, apply, capture
from kinredund.tracking.watch import SIGMA_FLOOR


def max_abs(a: np.ndarray) -> float:
    """max |a_i| of a short vector, as ``float(np.abs(a).max())`` (NaN where an entry is NaN), in Python floats (a
    numpy call costs more on a few entries)."""
    v = a.tolist()
    total = sum(map(abs, v))  # NaN exactly where an entry is NaN (magnitudes: no inf - inf)
    if total != total:
        return math.nan
    return max(map(abs, v))


class Stepper:
    """One run's state, advanced by :meth:`step`; the start is checked on the path and regular.

    Args:
        evaluator: the terms of the scheme (robot, path, index, formulation).
        q0: the checked starting configuration (a fresh array, owned by the stepper).
        dt: the time step [s].
        t0: the starting time [s].
        tol: the corrector's tolerance on ||F|| (default mode) or the projection's (baselines).
        linear_solver: the rule of :func:`~kinredund.tracking.linalg.classify`.
        qp_backend: ``proxsuite`` or ``kkt``.
    """

    #: is M symmetric (the augmented form) or not (the velocity form's M*)
    symmetric = True
    #: the record of :attr:`state` (a subclass with more state extends it)
    state_class: type[StepState] = StepState

    def __init__(self, evaluator: Evaluator, q0: np.ndarray, dt: float, *, t0: float = 0.0, tol: float = 1e-12,
                 linear_solver: str = "auto", qp_backend: str = "kkt"):
        self.ev, self.dt, self.n = evaluator, dt, evaluator.n
        self.tol, self.linear_solver, self.qp_backend = tol, linear_solver, qp_backend
        self.prox: RateQP | None = None
        self.t0, self.k = float(t0), 0  # t = t0 + k dt (no accumulated rounding in the clock)
        self.t = self.t0
        self.q = q0
        self.qdot = self.lamdot = self.M = None
        self.y = self.yd = self.lu = self.rcond = None
        self.prev: list[np.ndarray] = []
        self.label: str | None = None
        evaluator.checked_sample(self.t)  # the evaluation's sample (Evaluator.sample keeps it)
        self.pt = self._start_point()
        self._check_on_path(self.pt, "the starting configuration")
        try:
            lam = self._check_start(self.pt)
        except SingularityError as err:  # a TrackingError with its cause and a one-point record
            raise singular_start(evaluator, self.q, self.t, str(err), mode=self._mode_name()) from err
        if evaluator.path.period is not None and dt > evaluator.path.period:
            raise step_too_long(evaluator, self.q, self.t, dt, mode=self._mode_name())
        if evaluator.index is None:
            self.lam = np.zeros(len(self.pt.r))
        else:  # Eqs. (4.11)-(4.12)
            self.lam = lam if lam is not None else multipliers(self.pt.J, self.pt.grad)[0]
        m = len(self.pt.base.r)  # the task's rows (an active constraint row is not in R's workspace)
        # the workspace of R, Eq. (4.24) (np.full: np.zeros of 1 KiB or more releases the GIL around its calloc,
        # handing it to another of track_many's threads, which this one then waits for)
        self._R = np.full((self.n + m, self.n + m), 0.0)

    def _mode_name(self) -> str:
        """``default`` or ``thesis``: the mode a start failure names."""
        return "default" if hasattr(self, "plain_step") or getattr(self, "project", False) else "thesis"

    def _start_point(self) -> Point:
        """The evaluation at the start (q0, t0) that its checks read (and the first step or correction, where full)."""
        return self.evaluate(self.q, self.t)

    def _check_start(self, pt: Point) -> np.ndarray | None:
        """:meth:`_check_rank` at the start; returns lambda there where it was computed with the check (the same
        numbers as :func:`~kinredund.tracking.linalg.multipliers`), else None (the stepper computes it)."""
        self._check_rank(pt)
        return None

    @property
    def state(self) -> StepState:
        """The state as one frozen value (:mod:`kinredund.tracking.state`); assign one to go back to it."""
        return capture(self, self.state_class)

    @state.setter
    def state(self, value: StepState) -> None:
        apply(self, value)
        self._state_applied()

    def _state_applied(self) -> None:
        """After :attr:`state` is assigned: derived quantities (a subclass's, e.g. the free rows of R)."""

    @property
    def task_lam(self) -> np.ndarray:
        """The task's multipliers lambda (a stepper with constraint rows holds their multipliers after them)."""
        return self.lam

    def evaluate(self, q: np.ndarray, t: float, need_dJ: bool = True) -> Point:
        """The scheme's evaluation at (q, t) (with dK: the optimal schemes need Lambda; ``need_dJ=False``
        for the residual only). A stepper with constraint rows extends it (:mod:`kinredund.tracking.rows`)."""
        return self.ev.point(q, t, need_dJ=need_dJ)

    def step(self) -> None:
        """One time step: from (q, lambda) at t to t + dt."""
        raise NotImplementedError

    def _next_time(self) -> float:
        self.k += 1
        return self.t0 + self.k * self.dt

    @property
    def solver(self) -> str:
        """The step's linear-solver label (``qp``, ``qp_aug``, ``lu``; ``lstsq`` for the baselines).

        The default mode's corrector solves with R's LU factors and labels the step by the rule of
        :func:`~kinredund.tracking.linalg.classify` only when asked (:attr:`label_pending`).
        """
        if self.label is None:
            self.label = classify(self.M, self.pt.J, self.linear_solver, symmetric=self.symmetric)
        return self.label

    @property
    def label_pending(self) -> bool:
        """True where :attr:`solver` would classify (the recorder then classifies all steps at the end)."""
        return self.label is None

    def record_point(self) -> Point:
        """The terms at the current (q, t), for the record: the step's own evaluation where it was made
        there, else a fresh one (without dK)."""
        if self.pt.q is self.q and self.pt.t == self.t:
            return self.pt
        return self.ev.point(self.q, self.t, need_dJ=False)

    # -- the optimal schemes' rates (Eq. 4.24) ----------------------------------------------------
    def _solve_rates(self, pt: Point, xdot: np.ndarray) -> None:
        """Solve Eq. (4.24) at pt for the rates with the current lambda (LU of R, or the QP of Eq. 4.28)."""
        self.pt = pt
        M, top = pt.system(self.lam)  # Eqs. (4.23), (4.37)
        lu = self._factor(pt, M)
        label = classify(M, pt.J, self.linear_solver, symmetric=self.symmetric)
        if self.qp_backend == "proxsuite" and label != "lu" and self.prox is None:
            self.prox = RateQP(self.n, len(pt.r))
        rs = solve_rates(M, pt.J, top, xdot, label=label, backend=self.qp_backend, prox=self.prox, lu=lu)
        self.qdot, self.lamdot, self.label, self.M = rs.thetadot, rs.lamdot, rs.solver, M

    # -- checks -------------------------------------------------------------------------------------
    def _check_on_path(self, pt: Point, what: str, limit: float | None = None) -> None:
        """Raise PathError if pt is farther than ``limit`` (default 1e-6 of the path's scale) from the path, or
        on a spurious zero of the task residual (:meth:`~kinredund.tasks.Task.branch_error`)."""
        err = max_abs(pt.r)
        scale = max(1.0, max_abs(pt.sample.p))
        if limit is None:
            limit = 1e-6 * scale
        if not math.isfinite(err) or err > limit:
            raise PathError(
                f"{what} is {err:.3g} away from the path at t = {pt.t:.6g} s (allowed {limit:.3g}); "
                "the path may leave the workspace, or the steps are too coarse", t=pt.t, q=pt.q)
        why = self.ev.branch_error(pt)
        if why:  # r vanishes there, but the task is not done (a spurious zero: the tool axis reversed)
            raise PathError(f"{what} is not on the path at t = {pt.t:.6g} s: {why}; start from a solution of "
                            "solve_ik (which rejects these) or another seed", t=pt.t, q=pt.q)

    def _check_rank(self, pt: Point) -> None:
        """Raise SingularityError where J loses rank (a kinematic singularity: the watch's floor)."""
        J = pt.J
        sJ, info = lapack.dgesvd(J, compute_uv=0, full_matrices=0)[1::2] if np.isfinite(J).all() else (None, 1)
        if info != 0:  # (LAPACK's dgesvd without vectors, as the watch's: numpy's svd costs twice as much)
            sJ = np.full(2, np.nan)
        if not sJ[-1] > SIGMA_FLOOR * max(1.0, sJ[0]):  # "not >": NaN is singular too
            raise SingularityError(
                f"kinematic singularity at t = {pt.t:.6g} s: smallest singular value of J {sJ[-1]:.3g}; "
                f"q = {np.round(pt.q, 6).tolist()}", t=pt.t, q=pt.q, sigma_min=float(sJ[-1]))

    def _check_finite(self, q_before: np.ndarray) -> None:
        """Raise PathError (the path's own message if its sample is not finite) on non-finite joints or rates."""
        if not math.isfinite(float(self.q @ self.q) + float(self.qdot @ self.qdot)):  # BLAS: no FP warnings
            self.ev.check_sample(self.t)
            raise PathError(f"non-finite joint values or rates at t = {self.t:.6g} s", t=self.t, q=q_before)

    def _singularity(self, pt: Point, R: np.ndarray, J: np.ndarray, force: bool = False) -> None:
        """Raise SingularityError (kinematic or algorithmic) unless R turns out regular enough."""
        if not np.all(np.isfinite(R)):
            self.ev.check_sample(pt.t)  # a non-finite path sample says so itself
            raise PathError(f"non-finite terms of Eq. (4.24) at t = {pt.t:.6g} s; q = {np.round(pt.q, 6).tolist()}",
                            t=pt.t, q=pt.q)
        sR = np.linalg.svd(R, compute_uv=False)
        if not force and sR[-1] > 1e-11 * sR[0]:
            return  # the estimate was pessimistic: R is regular enough
        sJ = np.linalg.svd(J, compute_uv=False)
        base = getattr(pt, "base", None)  # J = [J_task; G_A] with active rows: the task's rows first
        of = "[J; G_A]" if base is not None and len(base.r) < J.shape[0] else "J"
        kind = f"kinematic ({of} rank-deficient) singularity" if not sJ[-1] > SIGMA_FLOOR * max(1.0, sJ[0]) else \
            f"algorithmic (R singular while {of} has full rank) singularity"
        if of != "J" and kind.startswith("kinematic"):
            sT = np.linalg.svd(J[: len(base.r)], compute_uv=False)
            if sT[-1] > SIGMA_FLOOR * max(1.0, sT[0]):  # J alone keeps its rank: the rows are dependent (LICQ)
                kind = ("dependent constraints (LICQ fails: J with the active rows' gradients below loses rank while "
                        "J alone keeps it; the redundancy left cannot move those pairs apart: the path runs into them)")
        raise SingularityError(
            f"{kind} at t = {pt.t:.6g} s: smallest singular value of R {sR[-1]:.3g}, "
            f"of {of} {sJ[-1]:.3g}; q = {np.round(pt.q, 6).tolist()}", t=pt.t, q=pt.q, sigma_min=float(sR[-1]))

    def _factor(self, pt: Point, M: np.ndarray):
        """The LU factors of R (Eq. 4.24) at pt with M; raises SingularityError where R is (numerically) singular.

        LAPACK dgetrf (partial pivoting) and its 1-norm condition estimate dgecon; the exact SVD only
        when the estimate says R is near singular.
        """
        n = self.n
        R = self._R
        R[:n, :n] = M  # R of Eq. (4.24): [[M, J^T], [J, 0]]
        R[:n, n:] = pt.J.T
        R[n:, :n] = pt.J
        return self._factor_matrix(pt, R, pt.J)

    def _factor_matrix(self, pt: Point, R: np.ndarray, J: np.ndarray):
        """dgetrf of R with the singularity checks of :meth:`_factor`; ``J`` names the constraint rows."""
        lu, piv, info = lapack.dgetrf(R)
        if info > 0:
            self._singularity(pt, R, J, force=True)
        rcond = lapack.dgecon(lu, lapack.dlange("1", R))[0]
        if not rcond > 1e-12:  # also catches NaN
            self._singularity(pt, R, J)
        self.lu, self.rcond = (lu, piv), rcond  # the last factors and estimate (the watch reuses them)
        return self.lu
