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

Speed: before calling proxsuite, the least-squares form tries a cheap guess of the active set (the
joints at a limit, then also those the guess pushes past one) and keeps it only if it meets the QP's
KKT conditions, in which case it *is* the QP's unique solution (the QP is strictly convex) and no
proxsuite call is made; proxsuite solves the others.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import lapack

from kinredund.errors import SolverError

#: proxsuite absolute tolerance of the step [rad or m]
QP_EPS_ABS = 1e-11
QP_MAX_ITER = 1000
#: active-set guesses tried (and checked against the KKT conditions) before calling proxsuite
GUESS_ROUNDS = 2


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
        """The step of min 1/2 d^T B d + c^T d s.t. G d = -e, lb <= d <= ub, or None if not solved."""
        if self._eq is None:
            self._eq = (*self._new(self.n, self.m), False)
        qp, solved, ready = self._eq
        if ready:
            qp.update(B, c, G, -e, None, None, None, lb, ub)
        else:
            qp.init(B, c, G, -e, None, None, None, lb, ub)
            self._eq = (qp, solved, True)
        qp.solve()
        if qp.results.info.status != solved:
            return None
        return np.clip(qp.results.x, lb, ub)

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
        if qp.results.info.status != solved:
            # the QP is strictly convex and feasible: only the iteration limit can stop it
            return np.clip(np.nan_to_num(qp.results.x), lb, ub)
        return np.clip(qp.results.x, lb, ub)


def _active_set_guess(H: np.ndarray, g: np.ndarray, lb: np.ndarray, ub: np.ndarray) -> np.ndarray | None:
    """The solution of min 1/2 d^T H d + g^T d, lb <= d <= ub (H positive definite) if a cheap guess
    of its active set is right, else None (then proxsuite solves the QP).

    First guess: the joints already at a limit (lb_i = 0 or ub_i = 0) are held there; next guesses:
    the free joints that the previous one pushed past a bound are held at it too. A guess is returned
    only if it meets the QP's KKT conditions (free joints within their bounds, the gradient H d + g
    pushing every held joint outwards): it is then the QP's unique solution.
    """
    n = g.shape[0]
    lbl, ubl = lb.tolist(), ub.tolist()
    held = {i: lbl[i] if lbl[i] >= 0.0 else ubl[i] for i in range(n) if lbl[i] >= 0.0 or ubl[i] <= 0.0}
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
        dl = d.tolist()
        out = {i: (lbl[i] if dl[i] < lbl[i] else ubl[i]) for i in free if not lbl[i] <= dl[i] <= ubl[i]}
        if out:
            held.update(out)
            continue
        grad = (H @ d + g).tolist()
        tol = 1e-12 * (1.0 + max(map(abs, grad)))
        if any((grad[i] < -tol) if v == lbl[i] else (grad[i] > tol) for i, v in held.items()):
            return None
        return d
    return None
