"""Joint limits as bounds: the Newton step of Appendix D as a box-constrained QP (proxsuite, dense).

Used only by solves with an index (Eq. 4.3), and only when their unconstrained step of Eqs.
(D.24)-(D.26) would leave the joint limits (the fast path needs no QP); pose-only solves hold and clip
joints instead (:func:`kinredund.ik.pose_only.pose_only`). Two problems, both over the step d (n,)
within lb <= d <= ub:

- equality form: min 1/2 d^T B d + c^T d  s.t.  G d = -e   (the linearised constraints, Eq. D.23);
- least-squares form, min 1/2 ||G d + e||^2 + mu/2 ||d||^2 (a damped Gauss-Newton step, always
  feasible): the step when the equality form is infeasible, and the restoration step on the
  constraints alone.

proxsuite's default ``eps_abs`` is 1e-5, far too loose for kinematics: it is set to 1e-11 here (see
``docs/design.md``). Solver objects are created once per solve and reused with ``update``; no warm
start is passed (each step is a new problem).

Speed: before calling proxsuite, both forms try cheap guesses of the active set (the joints at a limit,
then also those a guess pushes past one, or less the one it pulls off its bound) and keep one only if it
meets the QP's KKT conditions, in which case it *is* the QP's unique solution (both QPs are strictly
convex: B is positive definite) and no proxsuite call is made; proxsuite solves the others. The compiled
IK (src/core/ik.cpp) makes the same guesses.

Polishing (as OSQP's, Stellato et al. 2020): proxsuite's answer is within its tolerance of the solution, not on
it (~1e-9 rad off where the model's curvature is small), so it is polished: the same guesses, started from
proxsuite's active set (the joints within :data:`POLISH_GAP` of a bound whose multiplier pushes outwards) instead
of the joints at a limit, solve the KKT system on that set exactly and keep the step where it meets the KKT
conditions (then the QP's unique solution, to rounding), proxsuite's otherwise. So a step does not depend on
whether a guess or proxsuite found it: a guess that passes its KKT test on one side of a rounding difference and
fails it on the other (the compiled IK's against this module's, whose linear algebra rounds differently) gives the
same step to rounding. proxsuite's answer is polished whatever its status: a solution found from an equality form
it calls infeasible is one (its infeasibility test, at its default ``eps_primal_inf`` 1e-4, calls some feasible
ones infeasible; the compiled IK takes the least-squares step only where it certifies infeasibility).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import lapack

from kinredund.errors import SolverError

#: proxsuite absolute tolerance of the step [rad or m]
QP_EPS_ABS = 1e-11
QP_MAX_ITER = 1000
#: active-set guesses tried (and checked against the KKT conditions) before calling proxsuite (each one holds or
#: releases joints; 2 without releases held the Panda's and the xArm7's box steps of a plan 4 times in 10 off
#: proxsuite, 8 with them 9 in 10, one-off counts)
GUESS_ROUNDS = 8
#: the gap [rad or m] within which a joint of proxsuite's answer counts as on its bound when polishing (on the 273
#: equality-form box QPs it solved in 1,200 random bounded solves on the Panda and the xArm7, its active bounds were
#: met within 4e-9 at eps_abs 1e-11 and its free joints were 1e-2 and more from theirs; a joint put in the wrong set
#: is moved by the guesses' rounds, or the answer stays proxsuite's)
POLISH_GAP = 1e-6


class BoxStep:
    """Reusable dense proxsuite solvers for the bounded Newton step of one robot and task.

    Args:
        n: number of joints.
        m: rows of the linearised constraints G.
    """

    def __init__(self, n: int, m: int):
        self.n, self.m = n, m
        self._eq = None
        self._ls = None

    @staticmethod
    def _new(n: int, n_eq: int):
        try:
            import proxsuite
        except ImportError as err:  # pragma: no cover - proxsuite is a dependency
            raise SolverError("bounds=True needs proxsuite (pip install proxsuite)") from err
        qp = proxsuite.proxqp.dense.QP(n, n_eq, 0, True)
        qp.settings.eps_abs = QP_EPS_ABS
        qp.settings.eps_rel = 0.0
        qp.settings.max_iter = QP_MAX_ITER
        qp.settings.verbose = False
        return qp, proxsuite.proxqp.QPSolverOutput.PROXQP_SOLVED

    def equality(self, B, c, G, e, lb, ub) -> np.ndarray | None:
        """The step of min 1/2 d^T B d + c^T d s.t. G d = -e, lb <= d <= ub, or None where proxsuite does not solve it
        (infeasible) and polishing finds no solution either."""
        d = _equality_guess(B, c, G, e, lb, ub)
        if d is not None:
            return d
        if self._eq is None:
            self._eq = (*self._new(self.n, self.m), False)
        qp, solved, ready = self._eq
        if ready:
            qp.update(B, c, G, -e, None, None, None, lb, ub)
        else:
            qp.init(B, c, G, -e, None, None, None, lb, ub)
            self._eq = (qp, solved, True)
        qp.solve()
        d = _polished(qp.results, lb, ub, lambda held: _equality_guess(B, c, G, e, lb, ub, held))
        if d is None and qp.results.info.status == solved:
            d = np.clip(qp.results.x, lb, ub)  # not polished: proxsuite's answer
        return d

    def least_squares(self, G, e, mu, lb, ub) -> np.ndarray:
        """The step of min 1/2 ||G d + e||^2 + mu/2 ||d||^2 s.t. lb <= d <= ub (always feasible)."""
        H = G.T @ G + mu * np.eye(self.n)
        g = G.T @ e
        d = _active_set_guess(H, g, lb, ub)
        if d is not None:
            return d
        if self._ls is None:
            self._ls = (*self._new(self.n, 0), False)
        qp, solved, ready = self._ls
        if ready:
            qp.update(H, g, None, None, None, None, None, lb, ub)
        else:
            qp.init(H, g, None, None, None, None, None, lb, ub)
            self._ls = (qp, solved, True)
        qp.solve()
        d = _polished(qp.results, lb, ub, lambda held: _active_set_guess(H, g, lb, ub, held))
        # the QP is strictly convex and feasible: only the iteration limit can stop proxsuite short
        return np.clip(np.nan_to_num(qp.results.x), lb, ub) if d is None else d


def _initial_held(lbl: list, ubl: list) -> dict:
    """The joints at a limit (lb_i >= 0 or ub_i <= 0), held at it: {joint: bound}."""
    return {i: lbl[i] if lbl[i] >= 0.0 else ubl[i] for i in range(len(lbl)) if lbl[i] >= 0.0 or ubl[i] <= 0.0}


def _proxsuite_held(x: list, z: list, lbl: list, ubl: list) -> dict:
    """proxsuite's active set: the joints of its answer x within :data:`POLISH_GAP` of a bound whose box multiplier
    z_i is not of the wrong sign (proxsuite's Lagrangian gradient is H x + g + G^T y + z: z_i >= 0 pushes a joint
    outwards at its upper bound, z_i <= 0 at its lower), held at that bound: {joint: bound}."""
    held = {}
    for i, (xi, zi, lo, hi) in enumerate(zip(x, z, lbl, ubl, strict=True)):
        if xi - lo <= POLISH_GAP and zi <= 0.0 and xi - lo <= hi - xi:
            held[i] = lo
        elif hi - xi <= POLISH_GAP and zi >= 0.0:
            held[i] = hi
    return held


def _polished(results, lb: np.ndarray, ub: np.ndarray, guess) -> np.ndarray | None:
    """proxsuite's answer polished (see the module docstring): ``guess(held)``, one of the guesses started from
    proxsuite's active set, where it meets the KKT conditions (whatever proxsuite's status), else None."""
    x = np.clip(np.nan_to_num(results.x), lb, ub)
    z = np.nan_to_num(results.z[-x.shape[0]:])  # the box's multipliers follow the n_in inequalities' (none here)
    return guess(_proxsuite_held(x.tolist(), z.tolist(), lb.tolist(), ub.tolist()))


def _pushed_out(free: list, d: list, lbl: list, ubl: list) -> dict:
    """The free joints that the guess's d puts past a bound, with that bound."""
    return {i: (lbl[i] if d[i] < lbl[i] else ubl[i]) for i in free if not lbl[i] <= d[i] <= ubl[i]}


def _pulled_in(held: dict, grad: list, lbl: list) -> int | None:
    """The held joint that the gradient of the Lagrangian pulls into the box hardest (its multiplier's sign
    wrong), or None where it pulls none."""
    tol = 1e-12 * (1.0 + max(map(abs, grad)))
    pull = {i: (grad[i] if v == lbl[i] else -grad[i]) for i, v in held.items()}  # > 0 pushes outwards
    worst = min(pull, key=pull.get, default=None)
    return worst if worst is not None and pull[worst] < -tol else None


def _equality_guess(B, c, G, e, lb, ub, held: dict | None = None) -> np.ndarray | None:
    """The solution of min 1/2 d^T B d + c^T d s.t. G d = -e, lb <= d <= ub (B positive definite) if a guess of
    its active set as in :func:`_active_set_guess` is right, else None (then proxsuite solves the QP). ``held``: the
    first guess ({joint: bound}; default: the joints at a limit).

    A guess holds some joints at a bound and solves the equality-constrained QP in the others (its KKT system
    [B_ff G_f^T; G_f 0] [d_f; y] = [-(c + B d_h)_f; -e - G d_h]); it is kept only where the free joints are within
    their bounds and the Lagrangian's gradient B d + c + G^T y pushes every held joint outwards (the QP's KKT
    conditions: then the unique solution).
    """
    n, m = c.shape[0], e.shape[0]
    lbl, ubl = lb.tolist(), ub.tolist()
    held = _initial_held(lbl, ubl) if held is None else held
    for _ in range(GUESS_ROUNDS):
        free = [i for i in range(n) if i not in held]
        if len(free) < m:  # G_f d_f = -e - G d_h has no solution in general
            return None
        d = np.zeros(n)
        if held:
            d[list(held)] = list(held.values())
        Gf, nf = G[:, free], len(free)
        A = np.zeros((nf + m, nf + m))
        A[:nf, :nf], A[:nf, nf:], A[nf:, :nf] = B[np.ix_(free, free)], Gf.T, Gf
        rhs = np.concatenate([-(c + B @ d)[free], -e - G @ d])
        _, _, x, info = lapack.dgesv(A, rhs)
        if info != 0:
            return None
        d[free] = x[:nf]
        out = _pushed_out(free, d.tolist(), lbl, ubl)
        if out:
            held.update(out)
            continue
        wrong = _pulled_in(held, (B @ d + c + G.T @ x[nf:]).tolist(), lbl)
        if wrong is None:
            return d
        del held[wrong]
    return None


def _active_set_guess(H: np.ndarray, g: np.ndarray, lb: np.ndarray, ub: np.ndarray,
                      held: dict | None = None) -> np.ndarray | None:
    """The solution of min 1/2 d^T H d + g^T d, lb <= d <= ub (H positive definite) if a cheap guess
    of its active set is right, else None (then proxsuite solves the QP).

    First guess: the joints already at a limit (lb_i = 0 or ub_i = 0) are held there; next guesses:
    the free joints that the previous one pushed past a bound are held at it too, or, where none was, the
    held joint that the gradient H d + g pulls into the box hardest is released. A guess is returned
    only if it meets the QP's KKT conditions (free joints within their bounds, the gradient H d + g
    pushing every held joint outwards): it is then the QP's unique solution. ``held``: the first guess
    ({joint: bound}) instead of the joints at a limit.
    """
    n = g.shape[0]
    lbl, ubl = lb.tolist(), ub.tolist()
    held = _initial_held(lbl, ubl) if held is None else held
    for _ in range(GUESS_ROUNDS):
        free = [i for i in range(n) if i not in held]
        if not free:
            return None
        d = np.zeros(n)
        if held:
            d[list(held)] = list(held.values())
        Hf = H[free]
        c, x, info = lapack.dposv(Hf[:, free], -(g[free] + Hf @ d))  # Cholesky solve of the free block
        if info != 0:
            return None
        d[free] = x
        out = _pushed_out(free, d.tolist(), lbl, ubl)
        if out:
            held.update(out)
            continue
        wrong = _pulled_in(held, (H @ d + g).tolist(), lbl)
        if wrong is None:
            return d
        del held[wrong]
    return None
