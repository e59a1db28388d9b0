"""The bounded joint-level IK with general inequality rows: min z s.t. g(theta) = x, the limits, c(theta) >= 0.

The constraints are the tracker's (:class:`~kinredund.tracking.constraints.base.Constraint` of general rows: a
scene's clearances, :class:`~kinredund.tracking.constraints.scene.SceneClearance`), so that a minimum found here
is a point of the constrained optimum the tracker follows (issue 27). Newton-SQP from a seed (typically the
bounded minimum of :func:`~kinredund.ik.solve.solve_ik`, which may violate the rows): at each iterate the QP

    min 1/2 d^T B d + grad z^T d   s.t.  G d = -e,   c_i + a_i^T d >= 0 (rows within :data:`ROW_WINDOW`),
                                         lower - q <= d <= upper - q,   |d_j| <= :data:`MAX_STEP`,

with B the Lagrangian's Hessian Hess z + Lambda (Eq. 4.26, the task's multipliers) + sum_i w_i Hess c_i (w_i =
-nu_i, the rows' multipliers of the last QP; the rows' curvature from their constraint), made positive definite
on the whole space by rho [G; a_active]^T [G; a_active] where it is only so on the constraints' null space (the
same minimiser), solved through qpsolvers (proxqp to 1e-12), its multipliers the next iterate's. Near a strict
minimum with strict complementarity this is Newton's method on the first-order conditions (quadratic). The
answer is checked independently of the QP: the task residual, c >= -tol, and the first-order conditions on the
null space of [G; a_A; e_fixed] (rows within :data:`ACTIVE_TOL` of zero, joints on their limits) with
least-squares multipliers of the right sign (the rows push out, the limits hold their joints in), and the
reduced Hessian of the Lagrangian on that null space
positive definite (Eq. D.33 with the rows).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from kinredund.errors import OptionError
from kinredund.ik.common import RANK_TOL
from kinredund.ik.optimality import ik_target
from kinredund.ik.solve import IKResult
from kinredund.tasks import task_residual

#: the largest joint move of one iteration [rad or m]
MAX_STEP = 0.2
#: rows whose value is under this [m] enter the QP (the others are too far to be reached in one step)
ROW_WINDOW = 0.3
#: a row within this of zero [m] counts as active in the final check, a joint this close to a limit as on it
ACTIVE_TOL = 1e-9


@dataclass(frozen=True)
class RowsIKResult(IKResult):
    """The outcome of :func:`solve_ik_rows`: :class:`~kinredund.ik.solve.IKResult`'s fields (``converged``: the
    task residual, the rows (>= -tol), the first-order conditions on the null space of the task, the active rows
    and the held limits with multipliers of the right sign, and the reduced Hessian of the Lagrangian positive
    definite, all checked at q; ``iterations``: SQP iterations), and:

    Attributes:
        min_row: the least row value at q [m].
        active: the active rows (their numbers over the constraints, in order).
        multipliers: their multipliers nu >= 0 (least squares at q).
    """

    min_row: float = float("nan")
    active: tuple[int, ...] = ()
    multipliers: np.ndarray = field(default_factory=lambda: np.zeros(0))


def _rows(constraints, q):
    """(c, A) of every row of the constraints at q."""
    parts = [c.rows_at(q) for c in constraints]
    return np.concatenate([p[0] for p in parts]), np.vstack([p[1] for p in parts])


def _curvature(constraints, q, w_all):
    """sum_i w_i Hess c_i over the rows with w_i != 0 (n, n)."""
    n = len(q)
    H, k = np.zeros((n, n)), 0
    for c in constraints:
        w = w_all[k:k + c.size]
        rows = np.flatnonzero(w)
        if rows.size:
            H += c.curvature(q, w[rows], rows)
        k += c.size
    return H


class _Terms:
    """The task's and the index's terms at one q."""

    def __init__(self, robot, res, index, q):
        Q, p, self.K, self.dk = robot.kinematics.jacobian_hessian(q)
        self.e, self.jl = res.error(Q, p)
        self.r = res.residual(Q, p)
        self.G = res.jacobian(self.K, self.jl)
        z, grad, H = index.evaluate(q)
        self.z, self.grad, self.H = float(z), np.asarray(grad, float), np.asarray(H, float)

    def lagrangian_hessian(self, res, lam):
        """Hess z + Lambda (+ the task's extra term) for the task multipliers lam (Eq. 4.26)."""
        M = self.H + self.dk.contract(res.k_multipliers(lam, self.jl), res.rows)
        extra = res.extra_hessian(self.K, lam, self.jl)
        return M if extra is None else M + extra


def _qp(B, grad, G, e, A, c, lb, ub):
    """The SQP subproblem through qpsolvers (proxqp): (d, lambda, nu) or None."""
    import qpsolvers

    problem = qpsolvers.Problem(B, grad, G=-A if len(c) else None, h=c if len(c) else None, A=G, b=-e, lb=lb, ub=ub)
    sol = qpsolvers.solve_problem(problem, solver="proxqp", eps_abs=1e-12, eps_rel=0.0)
    if not sol.found or sol.x is None:
        return None
    return sol.x, np.asarray(sol.y, float), (np.asarray(sol.z, float) if len(c) else np.zeros(0))


def _convexified(M, C):
    """M symmetrised, plus rho C^T C (rho doubling from 1) until positive definite; else |eigenvalues|."""
    Ms = 0.5 * (M + M.T)
    B, rho = Ms, 1.0
    for _ in range(40):
        try:
            np.linalg.cholesky(B)
            return B
        except np.linalg.LinAlgError:
            B, rho = Ms + rho * C.T @ C, 2.0 * rho
    w, V = np.linalg.eigh(Ms)
    return (V * np.maximum(np.abs(w), 1e-8 * max(1.0, float(np.abs(w).max())))) @ V.T


def check_rows_optimality(robot, res, index, constraints, q) -> tuple:
    """(normality residual, active rows, their nu, the held limits' multipliers' least push outward (<= 0 where
    each holds its joint in), the reduced Hessian's least eigenvalue, least row) at q: the module docstring's
    independent check (least-squares multipliers on [G; a_A; e_fixed])."""
    t = _Terms(robot, res, index, q)
    c, A = _rows(constraints, q)
    act = np.flatnonzero(c <= ACTIVE_TOL)
    fixed = np.flatnonzero((q <= robot.lower + ACTIVE_TOL) | (q >= robot.upper - ACTIVE_TOL))
    m, n = t.G.shape[0], len(q)
    C = np.vstack([t.G, A[act], np.eye(n)[fixed]])
    U, s, Vt = np.linalg.svd(C)
    rank = int(np.sum(s > RANK_TOL * max(s[0], 1e-300)))
    y = -(U[:, :rank] / s[:rank]) @ (Vt[:rank] @ t.grad)  # C^T y = -grad z in least squares
    Z = Vt[rank:].T
    normality = float(np.linalg.norm(Z.T @ t.grad))
    lam, nu = y[:m], -y[m:m + len(act)]  # grad z + G^T lambda - a_A^T nu + e_fixed^T y_f = 0
    side = np.where(q[fixed] <= robot.lower[fixed] + ACTIVE_TOL, 1.0, -1.0)  # +1 on a lower limit
    outward = float(np.max(side * y[m + len(act):], initial=-np.inf))  # y_f <= 0 on a lower limit, >= 0 upper
    w = np.zeros(len(c))
    w[act] = -nu
    M = t.lagrangian_hessian(res, lam) + _curvature(constraints, q, w)
    eig = float(np.linalg.eigvalsh(Z.T @ (0.5 * (M + M.T)) @ Z).min()) if Z.shape[1] else np.inf
    return normality, tuple(int(i) for i in act), nu, outward, eig, float(c.min())


def solve_ik_rows(robot, target, index, constraints, q0, tol: float = 1e-10, max_iter: int = 60) -> RowsIKResult:
    """The within-limits minimum of z on the target that keeps every row c_i >= 0, from q0 (module docstring).

    Args:
        robot: the arm (its limits are the bounds: a robot with shrunk limits keeps inside them).
        target: the task target, as :func:`~kinredund.ik.solve.solve_ik` takes it.
        index: the performance index z.
        constraints: general-row constraints (``bounds()`` None), e.g. a scene's
            :class:`~kinredund.tracking.constraints.scene.SceneClearance`.
        q0: the seed [rad or m] (clipped into the limits).
        tol: the task residual, the rows (>= -tol) and the first-order conditions are met to this.
        max_iter: the most SQP iterations.

    Raises:
        OptionError: no index, no constraints, or a constraint of simple bounds.
    """
    if index is None:
        raise OptionError("solve_ik_rows needs a performance index (the minimum of z is what it finds)")
    constraints = list(constraints)
    if not constraints or any(c.bounds() is not None for c in constraints):
        raise OptionError("constraints must be general-row Constraints (the joint limits are the robot's own)")
    res = task_residual(ik_target(robot, target))
    q = np.clip(robot.check_q(q0, "q0"), robot.lower, robot.upper)
    w = None
    for it in range(max_iter + 1):
        t = _Terms(robot, res, index, q)
        c, A = _rows(constraints, q)
        near = np.flatnonzero((c < ROW_WINDOW) & np.any(A != 0.0, axis=1))
        if t.r <= tol and c.min() >= -tol:
            normality, act, nu, outward, eig, least = check_rows_optimality(robot, res, index, constraints, q)
            ntol = max(tol, 1e-13 * (1.0 + float(np.abs(t.grad).max())))
            if normality <= ntol and (nu >= -ntol).all() and outward <= ntol:
                ok = eig > 0.0
                why = "" if ok else f"a stationary point, not a minimum (reduced Hessian {eig:.3g})"
                return RowsIKResult(q, ok, it, t.r, normality, t.z, ok, eig, why, min_row=least, active=act,
                                    multipliers=nu)
        if it == max_iter:
            break
        # the multipliers of the last QP (at the first iterate: the task's least-squares ones, Eq. 4.12)
        lam = np.linalg.lstsq(t.G.T, -t.grad, rcond=None)[0] if w is None else w[0]
        curv = np.zeros(len(c)) if w is None else w[1]
        M = t.lagrangian_hessian(res, lam) + _curvature(constraints, q, curv)
        B = _convexified(M, np.vstack([t.G, A[near[curv[near] != 0.0]]]))
        lb = np.maximum(robot.lower - q, -MAX_STEP)
        ub = np.minimum(robot.upper - q, MAX_STEP)
        out = _qp(B, t.grad, t.G, t.e, A[near], c[near], lb, ub)
        if out is None:
            return _failed(q, it, t, c, "the QP of the step has no solution (the rows and the task cannot be met "
                           "together from here)")
        d, lam, nu = out
        curv = np.zeros(len(c))
        curv[near] = -nu
        w = (lam, curv)
        q = np.clip(q + d, robot.lower, robot.upper)
    t = _Terms(robot, res, index, q)
    return _failed(q, max_iter, t, _rows(constraints, q)[0], f"max_iter={max_iter} reached at residual {t.r:.3g}")


def _failed(q, it, t, c, why) -> RowsIKResult:
    return RowsIKResult(q, False, it, t.r, float("nan"), t.z, False, float("nan"), why, min_row=float(np.min(c)))
