"""The base class of the tracker's constraints: inequalities c(theta) >= 0 held exactly along the path.

Along the path the joints follow theta*(t) = argmin z(theta) s.t. g(theta) = x(t), c(theta) >= 0. The
first-order conditions (Karush-Kuhn-Tucker, with the thesis's normality condition Eq. 4.5 as the case
without active inequalities) are

    grad z + J^T lambda - sum_j mu_j grad c_j = 0,   mu_j >= 0,   mu_j c_j = 0,

and between switching times the active inequalities are equalities: the thesis's system (4.24) with
their rows added (or, for simple bounds, the bound joints' columns removed). A constraint says how many
inequalities it has, their values and gradients at a configuration, and names them for messages.

The constrained stepper (:mod:`kinredund.tracking.limited`) sees a constraint only through this class.
Two kinds are held, told apart by :meth:`Constraint.bounds`:

- simple bounds on single joints (:class:`~kinredund.tracking.constraints.joint_limits.JointLimits`): an
  active one fixes its joint, whose column leaves the system;
- general rows (:mod:`kinredund.tracking.constraints.clearance`): an active row i adds the equation
  c_i(theta) = 0 to the system, its gradient G_i as a row under J and w_i = -mu_i as a multiplier after
  lambda, and w_i Hess c_i to M (:meth:`Constraint.curvature`).

A new constraint is one subclass: ``size``, ``values``, ``gradients``, ``names`` and, for general rows,
``curvature`` (analytic; the default takes central differences of the gradients) and ``cause`` (the
TrackingError cause a run that cannot hold it stops with). Optional: ``segment_lower_bounds`` (lower bounds
along a step, which spare the stepper sampling the values inside it to find a row that dips below zero
and comes back) and ``discontinuities`` (where a row's gradient jumps: asked only when a run stops with
the row active, to say why in the stop's message).
"""

from __future__ import annotations

import abc

import numpy as np

#: the step [rad or m] of :meth:`Constraint.curvature`'s central differences
DIFFERENCE_STEP = 1e-6


def weighted_differences(w: np.ndarray, D: np.ndarray) -> np.ndarray:
    """sum_i w_i Hess c_i (n, n) from the central differences D (n, rows, n) of the rows' gradients, D[k] =
    G(q + h e_k) - G(q - h e_k) with h = :data:`DIFFERENCE_STEP`: column k is w @ D[k] / (2 h), then the symmetric
    part (:meth:`Constraint.curvature`; the compiled scene rows' differences are summed here too, the same way).
    One row (the common case) in one product: w @ D[k] is then w_0 D[k, 0], the same numbers."""
    n = len(D)
    if D.shape[1] == 1:
        H = (w[0] * D[:, 0, :]).T / (2 * DIFFERENCE_STEP)
        return 0.5 * (H + H.T)
    H = np.empty((n, n))
    for k in range(n):
        H[:, k] = w @ D[k] / (2 * DIFFERENCE_STEP)
    return 0.5 * (H + H.T)


class RowCheck:
    """A constraint's compiled check of a step (:meth:`Constraint.row_guard`'s answer): ``compiled``, the core's
    ``RowSource`` (a scene's ``kinredund._core.RowGuard``, a frame clearance's ``FrameRows``), which the compiled
    step holds (``StepCore.set_guard``); ``holds``, whether the core can hold the rows too, as the stepper's extended
    system (:mod:`kinredund.tracking.compiled_rows`); ``settles``, whether the core may make the Newton solve after a
    switch with them too (``CoreCorrector.settle``: not a scene's, whose stops' diagnosis, a bisection of witness
    points, follows the rounding of the switch's point, so that the two backends' stops name the same words)."""

    __slots__ = ("compiled", "holds", "settles")

    def __init__(self, compiled, holds: bool, settles: bool = True):
        self.compiled, self.holds, self.settles = compiled, holds, settles

    def valid(self) -> bool:
        """Does the check still describe the constraint? (Always, unless a subclass says otherwise; the core's
        verdict counts only where this holds.)"""
        return True

    def clear(self, q0: np.ndarray, q1: np.ndarray, v0: np.ndarray, v1: np.ndarray, h: float, held=()) -> bool:
        """True where no row can switch within the step from (q0, v0) to (q1, v1), h [s] long (``compiled.clear``),
        the rows ``held`` (their numbers) left out."""
        return self.valid() and self.compiled.clear(q0, q1, v0, v1, h, np.asarray(held, dtype=np.int64))


class _StackedCheck(RowCheck):
    """The checks of several constraints as one (``kinredund._core.RowStack``: their rows numbered in turn, as the
    stepper numbers them), valid while each is; it holds the rows (and settles them) only where every part can."""

    __slots__ = ("_parts",)

    def __init__(self, compiled, parts: list[RowCheck]):
        super().__init__(compiled, all(p.holds for p in parts), all(p.settles for p in parts))
        self._parts = parts

    def valid(self) -> bool:
        return all(p.valid() for p in self._parts)


def row_check(constraints: list, tol: float, core) -> RowCheck | None:
    """The compiled check of the general rows of ``constraints`` together (each one's :meth:`Constraint.row_guard`;
    two or more stacked by ``core.RowStack``), or None where one of them has none (the stepper's own search then
    checks every step) or the core has no ``RowStack``."""
    checks = [c.row_guard(tol) for c in constraints]
    if not checks or any(x is None for x in checks):
        return None
    if len(checks) == 1:
        return checks[0]
    if not hasattr(core, "RowStack"):
        return None
    return _StackedCheck(core.RowStack([x.compiled for x in checks]), checks)


class Constraint(abc.ABC):
    """Inequalities c(theta) >= 0 on the joints [rad or m]; ``size`` of them."""

    #: the :class:`~kinredund.errors.TrackingError` cause of a run that cannot hold the constraint
    cause = "limits_infeasible"

    @property
    @abc.abstractmethod
    def size(self) -> int:
        """The number of inequalities."""

    @abc.abstractmethod
    def values(self, q: np.ndarray) -> np.ndarray:
        """c(q) (size,): >= 0 where satisfied; the margin to each bound [rad or m]."""

    @abc.abstractmethod
    def gradients(self, q: np.ndarray) -> np.ndarray:
        """dc/dq (size, n)."""

    @abc.abstractmethod
    def names(self) -> list[str]:
        """A readable name per inequality (e.g. ``panda_joint4 >= -3.0718``)."""

    def start_hint(self, rows) -> str:
        """What a user can do where the start violates the inequalities ``rows`` (their indices) of this constraint,
        for the tracker's message; '' where there is nothing to add (the default)."""
        return ""

    def violations(self, q: np.ndarray, tol: float = 0.0) -> list[tuple[str, float]]:
        """(name, amount) of each inequality violated by more than ``tol`` at q [rad or m]."""
        c = self.values(q)
        bad = np.flatnonzero(c < -tol)
        if not bad.size:  # (the names are made only where one is violated)
            return []
        names = self.names()
        return [(names[i], float(-c[i])) for i in bad]

    def rows_at(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(values, gradients) at q together (a subclass computes both from one kinematics pass)."""
        return self.values(q), self.gradients(q)

    def bounds(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """(joint, side, bound) per inequality where every one is a simple bound ``side (theta_joint - bound)
        >= 0`` (side +1 lower, -1 upper), held by fixing the joint; None for general rows (the default)."""
        return None

    def curvature(self, q: np.ndarray, w: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """sum_i w_i Hess c_i(q) over the inequalities ``rows`` (n, n): their share of M in the system.

        The default takes central differences of :meth:`gradients` (step :data:`DIFFERENCE_STEP`; O(1e-10)
        relative error); a subclass with analytic second derivatives overrides it (the corrector's rate of
        convergence depends on it, its result does not).
        """
        q = np.asarray(q, float)
        n, eps = len(q), DIFFERENCE_STEP
        D = np.empty((n, len(rows), n))
        for k in range(n):
            e = np.zeros(n)
            e[k] = eps
            D[k] = self.gradients(q + e)[rows] - self.gradients(q - e)[rows]
        return weighted_differences(w, D)

    def segment_lower_bounds(self, q0: np.ndarray, q1: np.ndarray, c0: np.ndarray, c1: np.ndarray,
                             move: np.ndarray) -> np.ndarray | None:
        """Lower bounds (size,) on c along a joint path from q0 to q1 on which joint j moves by at most
        ``move[j]`` [rad or m], given c at the ends (``c0``, ``c1``: values, or lower bounds of them); None
        (the default) where the constraint knows none.

        The stepper checks the rows only at the ends of a step; a row that could dip below zero inside it
        (its bound < 0, or None) is sampled inside the step (:mod:`kinredund.tracking.switches`). A bound
        spares that sampling where it shows no dip is possible.
        """
        return None

    def row_guard(self, tol: float) -> RowCheck | None:
        """A compiled check that a step holds no switch of these rows (a :class:`RowCheck`: ``clear(q0, q1, v0, v1,
        h)``, none reached below -``tol`` [m] at q1, none able to dip below it between;
        :mod:`kinredund.tracking.compiled`), or None: the default, where the stepper's own search checks every
        step."""
        return None

    def representative(self, q: np.ndarray, row: int) -> int:
        """The inequality that stands for inequality ``row`` at q where another one joins the active set: ``row``
        itself (the default), or, for a constraint whose rows can coincide (two pieces of one distance equal in
        value and rate there, :mod:`kinredund.tracking.constraints.pieces`), the one to hold."""
        return int(row)

    def discontinuities(self, q: np.ndarray, dq: np.ndarray, rows) -> list[str]:
        """Messages for those of the inequalities ``rows`` whose gradient jumps on the segment from q to q + dq.

        The stepper holds a row by Newton's method on its value and gradient, so a row whose gradient is
        discontinuous where the optimum presses on it cannot be held as one row; a run that stops with rows
        active asks this to name that. The default (continuous gradients, as the joint limits and the frame
        clearances have) finds none.
        """
        return []
