"""Joint limits as bounds: the Newton step of Appendix D as a box-constrained QP (proxsuite, dense).

Used only when the unconstrained step of Eqs. (D.24)-(D.26) would leave the joint limits (the fast path
needs no QP). Two problems, both over the step d (n,) within lb <= d <= ub:

- equality form: min 1/2 d^T B d + c^T d  s.t.  G d = -e   (the linearised constraints, Eq. D.23);
- least-squares form, used when the equality form is infeasible inside the box (the target cannot be
  met to first order without leaving the limits): min 1/2 ||G d + e||^2 + mu/2 ||d||^2.

proxsuite's default ``eps_abs`` is 1e-5, far too loose for kinematics: it is set to 1e-11 here (see
``../shared/STACK.md``). Solver objects are created once per solve and reused with ``update``.
"""

from __future__ import annotations

import numpy as np

from .errors import SolverError

#: proxsuite absolute tolerance of the step [rad or m]
QP_EPS_ABS = 1e-11
QP_MAX_ITER = 1000


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
        if self._ls is None:
            self._ls = (*self._new(self.n, 0), False)
        qp, solved, ready = self._ls
        H = G.T @ G + mu * np.eye(self.n)
        g = G.T @ e
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
