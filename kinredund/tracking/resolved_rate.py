"""The resolved-rate scheme of Chapter 4: cyclic, optimal tracking of a path by a redundant arm.

Problem (4.3): min z(theta) s.t. g(theta) = x(t). Normality (4.5): grad z + J^T lambda = 0, lambda by
Householder least squares (Eqs. 4.11-4.12). Differentiated in time (Eqs. 4.14-4.24):

    [[M, J^T], [J, 0]] [thetadot; lambdadot] = [-d(grad z)/dt; xdot],   M = Hess z + Lambda   (4.24)

with Lambda = d(J^T lambda)/dtheta at fixed lambda (Eq. 4.26). The velocity-Jacobian form (4.30)-(4.42)
uses K, the twist t and lambda* instead; M* = Hess z + Lambda* is not symmetric.

Linear solver per step (Theorem 2): where M projected on the null space of J is positive definite the
rates solve the QP min 1/2 thetadot^T M thetadot s.t. J thetadot = xdot (4.28), solved either with
proxsuite on M + rho J^T J (same minimiser on the constraint) or by a direct factorisation of its KKT
system (``qp_backend="kkt"``); elsewhere LU of R. The step records ``qp``, ``qp_aug`` or ``lu``. The
default mode solves every step with the LU factors of R, which its corrector needs anyway; its record
labels each step by where the QP form holds (the rule ``linear_solver``), and ``qp_backend="proxsuite"``
is for thesis mode only.

Modes:
- ``thesis``: explicit Euler steps with the velocity correction of Eq. (4.29), lambda from least squares
  at every step - what the thesis ran (200 steps per loop).
- ``default``: a predictor (quintic Hermite extrapolation along the optimal path) and a Newton corrector
  on the full first-order system F(theta, lambda) = [grad z + J^T lambda; g(theta) - x(t)] = 0 at every
  step, reusing the step's factorisation of R (a chord iteration). The task and the normality condition
  are then both held to ~1e-12 and the joints close to machine precision loop after loop.

Baselines through the same interface: ``pseudoinverse`` (Whitney 1972) and ``liegeois`` gradient
projection (Liegeois 1977), Euler steps with the same velocity correction (thesis mode) or with a
minimum-norm Newton projection onto the task (default mode).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import lapack

from kinredund.errors import PathError, SingularityError, check_choice, check_positive
from kinredund.indices import Index
from kinredund.kinematics.angles import joint_drift
from kinredund.model.robot import Robot
from kinredund.paths import Path
from kinredund.tasks import get_task, task_terms
from kinredund.trajectory import Trajectory

SCHEMES = ("augmented", "velocity", "pseudoinverse", "liegeois")
MODES = ("default", "thesis")
QP_BACKENDS = ("proxsuite", "kkt")
LINEAR_SOLVERS = ("auto", "thesis", "lu", "qp")
#: points (values and slopes) of the default mode's Hermite predictor: 3 gives the quintic, whose O(h^6)
#: error lets one Newton update end the corrector on smooth paths at 200 steps per loop (median miss
#: ~1e-10 rad on Examples 4.1, 4.2 and the Panda circle; ~1e-5 on the fast Example 4.3, which needs
#: chord iterations): ``python benchmarks/resolved_rate.py`` prints both figures per robot
PREDICTOR_POINTS = 3


@dataclass(frozen=True)
class RateSolution:
    """The rates at one point: thetadot, lambdadot and the solver label used (``qp``, ``qp_aug``, ``lu``)."""

    thetadot: np.ndarray
    lamdot: np.ndarray
    solver: str


def multipliers(J: np.ndarray, grad: np.ndarray) -> tuple[np.ndarray, float]:
    """lambda minimising ||grad z + J^T lambda|| by Householder QR (Eqs. 4.11-4.12), and the residual norm.

    LAPACK directly (dgeqrf, dormqr, dtrtrs: about 6 us for a 7 x 6 problem, against 25 us through
    numpy.linalg.qr); J J^T is never formed. A rank-deficient J falls back to an SVD least squares.
    """
    m = J.shape[0]
    qr, tau, _, _ = lapack.dgeqrf(J.T)  # Householder: J^T = Y R
    c, _, _ = lapack.dormqr("L", "T", qr, tau, grad[:, None], lwork=max(64, m))  # Y^T grad
    lam, info = lapack.dtrtrs(qr[:m, :m], c[:m, 0])  # Eq. (4.12): R lambda = -Y^T grad
    if info != 0 or not math.isfinite(float(lam @ lam)):
        lam = np.linalg.lstsq(J.T, -grad, rcond=None)[0]
        return lam, float(np.linalg.norm(grad + J.T @ lam))
    res = c[m:, 0]
    return -lam, math.sqrt(float(res @ res))  # the residual is orthogonal to range(J^T)


def null_space_eigs(M: np.ndarray, J: np.ndarray) -> np.ndarray:
    """Eigenvalues of the symmetric part of M projected on the null space of J (Theorem 2), ascending."""
    _, s, Vt = np.linalg.svd(J)
    Z = Vt[J.shape[0]:].T
    Ms = 0.5 * (M + M.T)
    return np.linalg.eigvalsh(Z.T @ Ms @ Z)


def _lu_solve(lu, b: np.ndarray) -> np.ndarray:
    """Solve R x = b with R's LU factors from LAPACK dgetrf."""
    return lapack.dgetrs(lu[0], lu[1], b)[0]


def kkt_matrix(M: np.ndarray, J: np.ndarray) -> np.ndarray:
    """R of Eq. (4.24): [[M, J^T], [J, 0]]."""
    n, m = M.shape[0], J.shape[0]
    R = np.zeros((n + m, n + m))
    R[:n, :n] = M
    R[:n, n:] = J.T
    R[n:, :n] = J
    return R


class _ProxQP:
    """A reused proxsuite dense QP for the rates of Theorem 2 (Eq. 4.28)."""

    def __init__(self, n: int, m: int):
        import proxsuite

        self.qp = proxsuite.proxqp.dense.QP(n, m, 0)
        self.qp.settings.eps_abs = 1e-12
        self.qp.settings.eps_rel = 0.0
        self.qp.settings.verbose = False
        self.initialised = False

    def solve(self, M, J, top, xdot):
        """min 1/2 v^T (M + rho J^T J) v - top^T v s.t. J v = xdot; returns (v, lambdadot)."""
        import proxsuite

        Ms = 0.5 * (M + M.T)
        rho = 1.0
        JtJ = J.T @ J
        for _ in range(60):
            H = Ms + rho * JtJ
            if _cholesky_ok(H):
                break
            rho *= 4.0
        g = -top
        if not self.initialised:
            self.qp.init(H, g, J, xdot, None, None, None)
            self.initialised = True
        else:
            self.qp.update(H, g, J, xdot, None, None, None)
        self.qp.solve()
        if self.qp.results.info.status != proxsuite.proxqp.PROXQP_SOLVED:
            return None
        # stationarity: (M + rho J^T J) v - top + J^T y = 0 and J^T J v = J^T xdot, so lambdadot = y + rho xdot
        return self.qp.results.x.copy(), self.qp.results.y.copy() + rho * xdot


def solve_rates(M, J, top, xdot, *, label: str, backend: str, prox: _ProxQP | None, lu=None) -> RateSolution:
    """Solve Eq. (4.24) for the rates: the QP of Theorem 2 (Eq. 4.28) for ``qp``/``qp_aug``, else LU of R.

    ``lu``: R's LU factors (from LAPACK dgetrf) if the caller has them; otherwise R is factorised here.
    """
    n = M.shape[0]
    if label != "lu" and backend == "proxsuite" and prox is not None:
        out = prox.solve(M, J, top, xdot)
        if out is not None:
            return RateSolution(out[0], out[1], label)
    rhs = np.concatenate([top, xdot])
    sol = _lu_solve(lu, rhs) if lu is not None else np.linalg.solve(kkt_matrix(M, J), rhs)  # LU, partial pivoting
    return RateSolution(sol[:n], sol[n:], label)


def classify(M: np.ndarray, J: np.ndarray, rule: str, symmetric: bool = True) -> str:
    """The solver label of one step.

    ``qp``: M is positive definite, the QP of Theorem 2 as stated. ``qp_aug``: M is indefinite but
    positive definite on the null space of J - still a convex QP once M + rho J^T J replaces M (same
    minimiser on J thetadot = xdot). ``lu``: neither (or M not symmetric: the velocity form's M*).
    Rules: ``thesis`` (QP only where M itself is positive definite, as the thesis ran it), ``auto``
    (all three), ``lu`` (always LU), ``qp`` (QP wherever its projection is positive definite).
    """
    if rule == "lu" or not symmetric:
        return "lu"
    if _cholesky_ok(M):
        return "qp"
    if rule == "thesis":
        return "lu"
    return "qp_aug" if _projected_pd(M, J) else "lu"


def _projected_pd(M, J, tol=1e-10) -> bool:
    """Is M positive definite on the null space of J? (Finsler: M + rho J^T J > 0 for some rho.)"""
    Ms = 0.5 * (M + M.T)
    scale = max(1.0, float(np.abs(Ms).max()))
    JtJ = J.T @ J
    s2 = max(float(np.linalg.eigvalsh(J @ J.T)[0]), 1e-300)
    shift = tol * scale * np.eye(M.shape[0])
    return any(_cholesky_ok(Ms + rho * JtJ - shift) for rho in (scale / s2, 1e2 * scale / s2, 1e4 * scale / s2))


def _cholesky_ok(A: np.ndarray) -> bool:
    """Is the symmetric A (its lower triangle) positive definite? LAPACK dpotrf's verdict."""
    return lapack.dpotrf(A, lower=1)[1] == 0


class _Point:
    """Everything the scheme evaluates at one (theta, t): kinematics, task terms, index terms."""

    __slots__ = ("q", "t", "Q", "p", "sample", "terms", "r", "J", "xdot", "basis", "grad", "hess", "dgrad_dt")

    def __init__(self, q, t, Q, p, sample, terms, grad, hess, dgrad_dt):
        self.q, self.t, self.Q, self.p, self.sample, self.terms = q, t, Q, p, sample, terms
        self.r, self.J, self.xdot, self.basis = terms.r, terms.J, terms.xdot, terms.basis
        self.grad, self.hess, self.dgrad_dt = grad, hess, dgrad_dt

    def system(self, lam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(M, top) of Eq. (4.24) at this point for the multipliers lam.

        M = Hess z + Lambda (Eqs. 4.23, 4.37); top = -d(grad z)/dt - (dJ/dt)^T lambda at fixed theta, the
        upper right-hand side (``dgrad_dt`` is None for a time-invariant index: d(grad z)/dt = 0).
        """
        Lam, extra = self.terms.system(lam)
        if extra is None:
            top = np.zeros(len(self.grad)) if self.dgrad_dt is None else -self.dgrad_dt
        else:
            top = -extra if self.dgrad_dt is None else -self.dgrad_dt - extra
        return self.hess + Lam, top

    def residual(self, lam: np.ndarray) -> np.ndarray:
        """F = [grad z + J^T lambda; r]: the normality condition (4.5) and the task, zero on the optimum."""
        return np.concatenate([self.grad + self.J.T @ lam, self.r])


class _Scheme:
    """Evaluates the terms of the scheme for one robot, path, index and formulation."""

    def __init__(self, robot: Robot, path: Path, index: Index | None, formulation: str):
        self.robot, self.path, self.index = robot, path, index
        self.task = robot.task
        self.formulation = formulation  # "augmented" or "velocity" (baselines use "augmented" terms)
        self.n = robot.nq
        self._cache_t, self._cache = None, None
        self._zeros, self._zeros2 = np.zeros(self.n), np.zeros((self.n, self.n))

    def sample(self, t: float):
        """The path sample at t, cached (the corrector evaluates the same time several times).

        Not checked for finite values here (that costs a few microseconds per step): the stepper
        checks its results and calls :meth:`check_sample` to say where a non-finite value came from.
        """
        if self._cache_t != t:
            self._cache = self.path.sample(t)
            self._cache_t = t
        return self._cache

    def check_sample(self, t: float) -> None:
        """Raise PathError if the path's sample at t is not finite (says when)."""
        self.path(t)

    def point(self, q: np.ndarray, t: float, need_dJ: bool = True) -> _Point:
        kin = self.robot.kinematics
        s = self.sample(t)
        if need_dJ:
            Q, p, K, dk = kin.jacobian_hessian(q)
        else:
            (Q, p, K), dk = kin.jacobian(q), None
        terms = task_terms(self.task, self.formulation, Q, p, K, dk, s)
        if self.index is None:
            grad, hess, dgdt = self._zeros, self._zeros2, self._zeros
        else:
            _, grad, hess = self.index.evaluate(q, t)
            dgdt = self.index.time_derivative_of_gradient(q, t) if self.index.time_varying else None
        return _Point(q, t, Q, p, s, terms, grad, hess, dgdt)


def hermite_weights(h: float, points: int) -> np.ndarray:
    """Weights w of the Hermite extrapolation to +h through values and slopes at ``points`` past times.

    y(+h) = w @ (y(-(k-1) h), y'(-(k-1) h), ..., y(0), y'(0)) for k = ``points``, exact for polynomials
    of degree 2k - 1: k = 2 gives the cubic (5, 2h, -4, 4h), k = 3 the quintic
    (10, 3h, 9, 18h, -18, 9h).
    """
    nodes = np.arange(1 - points, 1, dtype=float)
    powers = np.arange(2 * points)
    value = nodes[:, None] ** powers  # rows: y at each node, in the monomial basis of s = time / h
    slope = powers * nodes[:, None] ** np.maximum(powers - 1, 0)  # rows: h y' at each node
    V = np.stack([value, slope], axis=1).reshape(2 * points, 2 * points)
    w = np.linalg.solve(V.T, np.ones(2 * points))  # the monomials at s = 1
    w[1::2] *= h
    return w


class _Recorder:
    def __init__(self, diagnostics: bool):
        self.diagnostics = diagnostics
        self.rows = {k: [] for k in ("t", "q", "p", "p_desired", "lam", "solver", "m_eigs", "m_null_eigs",
                                     "position_error", "trace_error", "vect_error", "axis_error",
                                     "normality_residual")}

    def add(self, pt: _Point, lam_full, solver: str, M: np.ndarray | None, task):
        """Record the point; M may come from the step's predictor (within the corrector's step of pt)."""
        rows = self.rows
        rows["t"].append(pt.t)
        rows["q"].append(pt.q.copy())
        rows["p"].append(pt.p.copy())
        rows["p_desired"].append(pt.sample.p.copy())
        rows["lam"].append(None if lam_full is None else np.asarray(lam_full, float).copy())
        rows["solver"].append(solver)
        s = pt.sample  # already a valid sample: target_from_sample does not re-validate it
        e = task.error_values(pt.Q, pt.p, task.target_from_sample(s))
        for name in ("position_error", "trace_error", "vect_error", "axis_error"):
            rows[name].append(e.get(name))
        rows["normality_residual"].append(multipliers(pt.J, pt.grad)[1])
        if self.diagnostics and M is not None:
            rows["m_eigs"].append(np.sort(np.linalg.eigvals(M).real) if not np.allclose(M, M.T)
                                  else np.linalg.eigvalsh(M))
            rows["m_null_eigs"].append(null_space_eigs(M, pt.J))


class ResolvedRate:
    """One tracking run, advanced step by step (``advance``); :func:`track` drives it and records.

    Args:
        robot: the arm (its ``task`` sets m).
        path: the path; pose tasks need a path with orientation.
        index: the performance index z (required for ``augmented``/``velocity``/``liegeois``).
        q0: the starting configuration (on the path; for the optimal schemes, at the constrained
            minimum - see :func:`kinredund.ik.solve_ik`).
        dt: the time step [s].
        scheme, mode: see the module docstring.
        linear_solver: the rule of :func:`classify`: ``auto`` (default mode's default), ``thesis`` (thesis
            mode's default), ``lu`` or ``qp``.
        qp_backend: ``proxsuite`` or ``kkt`` (default: proxsuite in thesis mode, kkt in default mode, which
            solves with R's LU factors and does not take ``proxsuite``).
        tol: the corrector's tolerance on ||F|| (default mode).
        liegeois_gain: the gradient-projection gain k of the Liegeois baseline [1/s].
    """

    def __init__(self, robot, path, index, q0, dt, *, scheme="augmented", mode="default",
                 linear_solver=None, qp_backend=None, tol=1e-12, liegeois_gain=1.0, t0=0.0):
        check_choice("scheme", scheme, SCHEMES)
        check_choice("mode", mode, MODES)
        linear_solver = linear_solver or ("thesis" if mode == "thesis" else "auto")
        check_choice("linear solver", linear_solver, LINEAR_SOLVERS)
        qp_backend = qp_backend or ("proxsuite" if mode == "thesis" else "kkt")
        check_choice("QP backend", qp_backend, QP_BACKENDS)
        if mode == "default":  # it solves with R's LU factors, which its corrector needs
            check_choice("QP backend of mode='default' (proxsuite is for mode='thesis')", qp_backend, ("kkt",))
        if get_task(robot.task).has_orientation and not path.has_orientation:
            raise PathError(f"a {robot.task} task needs a path with orientation (e.g. Circle(..., frenet=True))")
        if index is None and scheme in ("augmented", "velocity", "liegeois"):
            raise PathError(f"the {scheme} scheme needs a performance index")
        dt = check_positive(dt, "the time step [s]", PathError)
        self.robot, self.dt, self.mode, self.scheme = robot, dt, mode, scheme
        self.linear_solver, self.qp_backend, self.tol, self.gain = linear_solver, qp_backend, tol, liegeois_gain
        self.n = robot.nq
        self.sys = _Scheme(robot, path, index, "velocity" if scheme == "velocity" else "augmented")
        self.prox = None
        self.t0, self.k = float(t0), 0  # t = t0 + k dt (no accumulated rounding in the clock)
        self.t = self.t0
        self.q = robot.check_q(q0, "starting configuration").copy()
        # y, ydot of up to PREDICTOR_POINTS - 1 previous points, y = [q; lambda], oldest first (a flat list),
        # and the predictor's weights by how many points there are
        self.prev = []
        self._hermite = [None] + [hermite_weights(self.dt, k + 1) for k in range(1, PREDICTOR_POINTS)]
        self.sys.check_sample(self.t)
        self.pt = self.sys.point(self.q, self.t)
        self._check_on_path(self.pt, "the starting configuration")
        self._check_rank(self.pt)
        self.lam = multipliers(self.pt.J, self.pt.grad)[0] if index is not None else np.zeros(len(self.pt.r))
        m = len(self.pt.r)
        self._R = np.zeros((self.n + m, self.n + m))  # the workspace of R, Eq. (4.24)
        if mode == "default" and scheme in ("augmented", "velocity"):
            self._newton(self.pt)  # put the start exactly on the optimal manifold
        self._rates()

    @property
    def solver(self) -> str:
        """The step's linear-solver label (``qp``, ``qp_aug``, ``lu``; ``lstsq`` for the baselines).

        The default mode's corrector solves with R's LU factors and labels the step by the rule of
        :func:`classify` only when asked (the record asks at every step; a bare ``advance`` loop does not).
        """
        if self._solver is None:
            self._solver = classify(self.M, self.pt.J, self.linear_solver, symmetric=self.scheme == "augmented")
        return self._solver

    # -- helpers -----------------------------------------------------------------------------------
    def _check_on_path(self, pt: _Point, what: str, limit: float | None = None) -> None:
        err = float(np.abs(pt.r).max())
        scale = max(1.0, float(np.abs(pt.sample.p).max()))
        if limit is None:
            limit = 1e-6 * scale
        if not np.isfinite(err) or err > limit:
            raise PathError(
                f"{what} is {err:.3g} away from the path at t = {pt.t:.6g} s (allowed {limit:.3g}); "
                "the path may leave the workspace", t=pt.t, q=pt.q)

    def _check_rank(self, pt: _Point) -> None:
        """Raise SingularityError where J loses rank (a kinematic singularity)."""
        sJ = np.linalg.svd(pt.J, compute_uv=False)
        if sJ[-1] < 1e-8 * max(1.0, sJ[0]):
            raise SingularityError(
                f"kinematic singularity at t = {pt.t:.6g} s: smallest singular value of J {sJ[-1]:.3g}; "
                f"q = {np.round(pt.q, 6).tolist()}", t=pt.t, q=pt.q, sigma_min=float(sJ[-1]))

    def _singularity(self, pt: _Point, R: np.ndarray, force: bool = False) -> None:
        """Raise SingularityError (kinematic or algorithmic) unless R turns out regular enough."""
        if not np.all(np.isfinite(R)):
            self.sys.check_sample(pt.t)  # a non-finite path sample says so itself
            raise PathError(f"non-finite terms of Eq. (4.24) at t = {pt.t:.6g} s; q = {np.round(pt.q, 6).tolist()}",
                            t=pt.t, q=pt.q)
        sR = np.linalg.svd(R, compute_uv=False)
        if not force and sR[-1] > 1e-11 * sR[0]:
            return  # the estimate was pessimistic: R is regular enough
        sJ = np.linalg.svd(pt.J, compute_uv=False)
        kind = "kinematic (J rank-deficient)" if sJ[-1] < 1e-8 * max(1.0, sJ[0]) else \
            "algorithmic (R singular while J has full rank)"
        raise SingularityError(
            f"{kind} singularity at t = {pt.t:.6g} s: smallest singular value of R {sR[-1]:.3g}, "
            f"of J {sJ[-1]:.3g}; q = {np.round(pt.q, 6).tolist()}", t=pt.t, q=pt.q, sigma_min=float(sR[-1]))

    def _factor(self, pt: _Point, M: np.ndarray):
        """The LU factors of R (Eq. 4.24) at pt with M; raises SingularityError where R is (numerically) singular.

        LAPACK dgetrf (partial pivoting) and its 1-norm condition estimate dgecon; the exact SVD only
        when the estimate says R is near singular.
        """
        n = self.n
        R = self._R
        R[:n, :n] = M  # R of Eq. (4.24): [[M, J^T], [J, 0]]
        R[:n, n:] = pt.J.T
        R[n:, :n] = pt.J
        lu, piv, info = lapack.dgetrf(R)
        if info > 0:
            self._singularity(pt, R, force=True)
        rcond = lapack.dgecon(lu, lapack.dlange("1", R))[0]
        if not rcond > 1e-12:  # also catches NaN
            self._singularity(pt, R)
        return lu, piv

    def _tol(self, pt: _Point) -> float:
        """The corrector's tolerance on ||F||_2, scaled by the gradient: tol max(1, ||grad z||)."""
        return self.tol * max(1.0, math.sqrt(float(pt.grad @ pt.grad)))

    def _newton(self, pt: _Point | None = None, max_fresh: int = 6) -> None:
        """Corrector onto F(theta, lambda) = [grad z + J^T lambda; r] = 0 at self.t from (self.q, self.lam).

        Rounds of chord iterations (:meth:`_chord`), each with R factorised afresh at its first iterate;
        ``pt`` is the full evaluation at the current point when the caller has it.
        """
        n = self.n
        y = np.concatenate([self.q, self.lam])
        for _ in range(max_fresh + 1):
            if pt is None:
                pt = self.sys.point(y[:n], self.t)
            lu = self._factor(pt, pt.system(y[n:])[0])
            y, ok = self._chord(y, lu, self._tol(pt), F=pt.residual(y[n:]))
            if ok:
                self.q, self.lam = y[:n], y[n:]
                return
            pt = None
            if not math.isfinite(float(y @ y)):
                break
        raise PathError(
            f"the corrector did not converge at t = {self.t:.6g} s: the path leaves the workspace or crosses a "
            "singularity", t=self.t, q=self.q)

    def _correct(self, y: np.ndarray) -> None:
        """Default-mode corrector at self.t from the predicted y = [q; lambda], then the rates for the next step.

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
        pt = self.sys.point(y[:n], self.t)
        M, top = pt.system(lam)  # Eqs. (4.23), (4.37)
        lu, piv = self._factor(pt, M)
        # one right-hand side per solve: dgetrs with two goes through a level-3 triangular solve, slower
        # on these sizes and, with OpenBLAS threads, prone to millisecond waits on a busy machine
        sol = _lu_solve((lu, piv), np.concatenate((top, pt.xdot)))  # Eq. (4.24)
        if not math.isfinite(float(sol @ sol)):  # the rates are finite iff the step's terms are
            self.sys.check_sample(self.t)
            raise PathError(f"non-finite joint rates at t = {self.t:.6g} s", t=self.t, q=y[:n])
        F = pt.residual(lam)
        tol = self._tol(pt)
        if not float(F @ F) <= tol * tol:  # "not <=": a NaN residual is not converged
            d = _lu_solve((lu, piv), F)
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
        self._y, self._yd = y, sol
        self.qdot, self.lamdot, self._solver, self.M, self.pt = sol[:n], sol[n:], None, M, pt

    def _chord(self, y: np.ndarray, lu, tol: float, F: np.ndarray | None = None,
               max_iter: int = 8) -> tuple[np.ndarray, bool]:
        """Chord iterations on F with fresh residuals and R's factors kept: (last iterate, converged).

        The factors belong to another point, so the iteration converges only linearly: it ends on the
        residual itself (||F|| <= tol), never on the size of the update. ``F``: the residual at ``y``
        if the caller has it. A non-finite path sample is reported (PathError) when it fails.
        """
        n = self.n
        for _ in range(max_iter):
            if F is None:
                F = self.sys.point(y[:n], self.t, need_dJ=False).residual(y[n:])
            if float(F @ F) <= tol * tol:
                return y, True
            y = y - _lu_solve(lu, F)
            F = None
        self.sys.check_sample(self.t)  # a non-finite path sample says so itself
        return y, False

    def _rates(self, pt: _Point | None = None) -> None:
        """Evaluate the full system at the current point and solve for the rates (Eq. 4.24 or baseline).

        ``pt``: the baselines' evaluation at the current point when the caller has it (no dK needed).
        """
        baseline = self.scheme in ("pseudoinverse", "liegeois")
        if pt is None:
            pt = self.sys.point(self.q, self.t, need_dJ=not baseline)
        self.pt = pt
        xdot = pt.xdot
        if self.mode == "thesis":
            xdot = xdot - pt.r / self.dt  # velocity correction, Eq. (4.29)
            if self.sys.index is not None:
                self.lam = multipliers(pt.J, pt.grad)[0]  # Eqs. (4.11)-(4.12)
        if self.scheme in ("pseudoinverse", "liegeois"):
            Jp = np.linalg.pinv(pt.J)
            with np.errstate(invalid="ignore", over="ignore"):  # a non-finite xdot: reported by the caller
                qd = Jp @ xdot
            if self.scheme == "liegeois":
                qd -= self.gain * (pt.grad - Jp @ (pt.J @ pt.grad))  # gradient projection (Liegeois 1977)
            self.qdot, self.lamdot, self._solver, self.M = qd, np.zeros_like(self.lam), "lstsq", None
            return
        M, top = pt.system(self.lam)  # Eqs. (4.23), (4.37)
        lu = self._factor(pt, M)
        label = classify(M, pt.J, self.linear_solver, symmetric=self.scheme == "augmented")
        if self.qp_backend == "proxsuite" and label != "lu" and self.prox is None:
            self.prox = _ProxQP(self.n, len(pt.r))
        rs = solve_rates(M, pt.J, top, xdot, label=label, backend=self.qp_backend, prox=self.prox, lu=lu)
        self.qdot, self.lamdot, self._solver, self.M = rs.thetadot, rs.lamdot, rs.solver, M
        self._y, self._yd = np.concatenate([self.q, self.lam]), np.concatenate([self.qdot, self.lamdot])

    # -- the step ----------------------------------------------------------------------------------
    def advance(self) -> None:
        """One time step: from (q, lambda) at t to t + dt."""
        h = self.dt
        q = self.q
        self.k += 1
        t_next = self.t0 + self.k * h
        if self.mode == "thesis":
            self.q = q + h * self.qdot  # explicit Euler
            self.t = t_next
        elif self.scheme in ("pseudoinverse", "liegeois"):
            self.q = q + h * self.qdot
            self.t = t_next
            pt = self._project_task()
        else:
            y, yd = self._y, self._yd
            # predictor: Euler at the first step, then Hermite extrapolation (cubic, then quintic)
            prev = self.prev  # [y, ydot, y, ydot, ...], oldest first
            y_p = self._hermite[len(prev) // 2] @ np.array(prev + [y, yd]) if prev else y + h * yd
            prev += (y, yd)
            if len(prev) == 2 * PREDICTOR_POINTS:
                del prev[:2]
            self.t = t_next
            self._correct(y_p)  # checks its results for non-finite values
            return
        self._check_finite(q)
        self._rates(pt if self.mode == "default" else None)
        self._check_finite(q)
        step = max(1.0, float(np.abs(self.pt.xdot).max())) * h
        self._check_on_path(self.pt, "the tracked configuration", limit=max(1e-3, 50.0 * step))
        self._check_rank(self.pt)

    def _check_finite(self, q_before: np.ndarray) -> None:
        """Raise PathError (the path's own message if its sample is not finite) on non-finite joints or rates."""
        if not math.isfinite(float(self.q @ self.q) + float(self.qdot @ self.qdot)):  # BLAS: no FP warnings
            self.sys.check_sample(self.t)
            raise PathError(f"non-finite joint values or rates at t = {self.t:.6g} s", t=self.t, q=q_before)

    def _project_task(self, max_iter: int = 20) -> _Point:
        """Minimum-norm Newton projection onto the task at self.t (default-mode baselines); the final point."""
        for _ in range(max_iter):
            pt = self.sys.point(self.q, self.t, need_dJ=False)
            err = float(np.abs(pt.r).max())
            if err <= self.tol * max(1.0, float(np.abs(pt.sample.p).max())):
                return pt
            if not math.isfinite(err):
                self.sys.check_sample(self.t)
                raise PathError(f"non-finite task residual at t = {self.t:.6g} s", t=self.t, q=self.q)
            self.q = self.q - np.linalg.lstsq(pt.J, pt.r, rcond=None)[0]
        raise PathError(f"the task projection did not converge at t = {self.t:.6g} s", t=self.t, q=self.q)

    def record_point(self) -> _Point:
        """The terms at the current (q, t), for the record.

        The step's own evaluation where it was made at (q, t) (thesis mode, baselines); the default mode's
        is at the predicted point, so the record evaluates afresh.
        """
        if self.pt.q is self.q and self.pt.t == self.t:
            return self.pt
        return self.sys.point(self.q, self.t, need_dJ=False)

    def lam_full(self) -> np.ndarray:
        """lambda in the closure 7-vector's coordinates (augmented pose task), else lambda itself."""
        return self.pt.basis @ self.lam if self.pt.basis is not None else self.lam


def _errors(name: str, values: list) -> np.ndarray | None:
    """A recorded error series. The task's own errors as recorded; where the task does not hold one, the
    trace and vect errors are zeros (as the record has always held them for point tasks) and the axis
    error is None."""
    if values and values[0] is None:
        return None if name == "axis_error" else np.zeros(len(values))
    return np.array(values)


def _loadable_name(robot: Robot) -> str:
    """What :func:`kinredund.load_robot` reloads the robot from: its name if known, else its URDF file."""
    from kinredund.model.robot import known_robots

    if robot.name in known_robots() or robot.urdf_path is None:
        return robot.name
    return str(robot.urdf_path)


def track(robot: Robot, path: Path, index: Index | None = None, q0=None, *, scheme: str = "augmented",
          mode: str = "default", steps_per_loop: int = 200, loops: int = 1, duration: float | None = None,
          steps: int | None = None, linear_solver: str | None = None, qp_backend: str | None = None,
          tol: float = 1e-12, diagnostics: bool = True, liegeois_gain: float = 1.0, progress=None,
          meta: dict | None = None) -> Trajectory:
    """Track ``path`` from ``q0`` and return the :class:`~kinredund.trajectory.Trajectory`.

    Closed paths (with a ``period``) run ``loops`` loops of ``steps_per_loop`` steps and record the joint
    drift at the end of each loop; open paths need ``duration`` [s] and ``steps``.

    Raises:
        PathError: the path is malformed, non-finite, or leaves the workspace (says when and where).
        SingularityError: R or J becomes singular (time, configuration, smallest singular value).
    """
    if path.period is not None and duration is None:
        if int(steps_per_loop) < 1 or int(loops) < 1:
            raise PathError(f"steps_per_loop and loops must be >= 1, got {steps_per_loop}, {loops}")
        dt = path.period / int(steps_per_loop)
        total = int(steps_per_loop) * int(loops)
    else:
        if duration is None or steps is None or steps < 1 or not duration > 0:
            raise PathError("an open path needs duration > 0 [s] and steps >= 1")
        dt, total = duration / steps, int(steps)
    if q0 is None:
        raise PathError("a starting configuration q0 is needed (see kinredund.ik.solve_ik)")
    rr = ResolvedRate(robot, path, index, q0, dt, scheme=scheme, mode=mode, linear_solver=linear_solver,
                      qp_backend=qp_backend, tol=tol, liegeois_gain=liegeois_gain)
    rec = _Recorder(diagnostics)
    task = get_task(robot.task)
    rec.add(rr.record_point(), rr.lam_full(), rr.solver, rr.M, task)
    for k in range(total):
        rr.advance()
        rec.add(rr.record_point(), rr.lam_full(), rr.solver, rr.M, task)
        if progress is not None:
            progress(k + 1, total)
    rows = rec.rows
    q = np.array(rows["q"])
    drift = None
    if path.period is not None and duration is None:
        drift = np.array([joint_drift(q[0], q[(i + 1) * steps_per_loop], robot.revolute) for i in range(loops)])
    lam = None if any(v is None for v in rows["lam"]) else np.array(rows["lam"])
    return Trajectory(
        robot=_loadable_name(robot),
        task=robot.task, t=np.array(rows["t"]), q=q, p=np.array(rows["p"]), p_desired=np.array(rows["p_desired"]),
        scheme=scheme, mode=mode, solver=tuple(rows["solver"]), lam=lam,
        m_eigs=np.array(rows["m_eigs"]) if rows["m_eigs"] else None,
        m_null_eigs=np.array(rows["m_null_eigs"]) if rows["m_null_eigs"] else None,
        **{name: _errors(name, rows[name]) for name in ("position_error", "trace_error", "vect_error", "axis_error")},
        normality_residual=np.array(rows["normality_residual"]),
        loop_drift=drift, loop_period=path.period, meta=dict(meta or {}, dt=dt, steps=total),
    )
