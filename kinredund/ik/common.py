"""The shared pieces of one start of the joint-level IK (Appendix D): its set-up and results, the
constants of the iterations, the Householder QR split of G (Eq. D.25), damped least-squares steps and the
first-order conditions with bounds (Eq. D.30). :mod:`kinredund.ik.newton` and :mod:`kinredund.ik.pose_only`
run the starts."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import lapack

from kinredund.ik.qp import BoxStep
from kinredund.indices import Index
from kinredund.tasks import TaskResidual

#: Armijo sufficient-decrease constant
ARMIJO = 1e-4
#: cap on the joint change (infinity norm) of each part of a step with an index: the minimum-norm
#: part x0 (larger: a restoration step instead), the null-space part L u, and the restoration and
#: bounded steps as a whole (see the module docstring: x0 + L u may reach 2 MAX_STEP) [rad or m]
MAX_STEP = 1.0
#: smallest step fraction tried by the backtracking line search
MIN_ALPHA = 2.0**-20
#: |R_ii| below this times max |R_ii| counts as rank deficiency of G
RANK_TOL = 1e-9
#: floor of the damping of least-squares steps, relative to max |G_ij|^2
DAMPING = 1e-6
#: a start with an index stops when its residual has not halved in 2 STALL_ITERS iterations; a
#: pose-only start that is the last one stops when ||e||^2 has not decreased by the fraction
#: PATIENT_DECREASE in STALL_ITERS iterations (the closest point to an unreachable target is approached
#: slowly)
STALL_ITERS = 10
PATIENT_DECREASE = 1e-9
#: weight of ||e||^2 in the damping of least-squares steps
LM_WEIGHT = 0.05
#: pose-only starts while other starts remain (or with a timeout): abandoned when ||e||^2 has not
#: halved in QUICK_STALL_ITERS iterations or after QUICK_MAX_ITER iterations (converging starts take
#: 5-15; a fresh start does better than a stuck one: a local minimum of the residual at the joint
#: limits, or a near-singular configuration) ...
QUICK_STALL_ITERS = 3
QUICK_MAX_ITER = 20
#: ... unless the start is already close (||e||^2 < SLOW_PHI) and still gaining (||e||^2 below
#: SLOW_RATIO times its value QUICK_STALL_ITERS iterations before): then it runs up to SLOW_MAX_ITER
#: iterations (targets whose every solution is near a singular configuration are approached slowly)
SLOW_PHI = 1e-3
SLOW_RATIO = 0.9
SLOW_MAX_ITER = 60
#: the Levenberg-Marquardt damping scale at which a pose-only start gives up: no step decreases ||e||
MAX_SCALE = 1e10
#: before abandoning a stuck pose-only start, turn once (TURNS times) the revolute joints held at a
#: limit whose range misses a full turn by less than TURN_GAP [rad] through 2 pi towards the other
#: limit (see :func:`_turn_past_limits`)
TURNS = 1
TURN_GAP = 1.0
#: joints within this distance of a limit count as at the limit [rad or m]
ACTIVE_TOL = 1e-9


@dataclass
class Setup:
    """Everything one start needs (built once per solve)."""

    kin: object
    res: TaskResidual
    index: Index | None
    lower: np.ndarray
    upper: np.ndarray
    bounds: bool
    rtol: float
    tol: float
    max_iter: int
    deadline: float | None
    #: the bounded-QP steps of solves with an index (None without bounds, and for pose-only solves)
    box: BoxStep | None
    #: abandon a pose-only start as soon as it looks stuck (set while other starts remain)
    quick_exit: bool = False
    #: revolute joints (n,) bool; None: no joint is turned past its limits
    revolute: np.ndarray | None = None
    #: the constrained iteration runs in the compiled core (:mod:`kinredund.ik.compiled`)
    compiled: bool = False

    def __post_init__(self):
        self.eye = np.eye(self.res.m)
        self.lower_list, self.upper_list = self.lower.tolist(), self.upper.tolist()
        spans = (self.upper - self.lower).tolist()
        revolute = [False] * len(spans) if self.revolute is None else np.asarray(self.revolute).tolist()
        self.turnable = [bool(r) and 2.0 * math.pi - w < TURN_GAP for r, w in zip(revolute, spans, strict=True)]


@dataclass(frozen=True)
class OptimalityTerms:
    """The first-order terms at one q with an index, from which the report of Eq. (D.33) follows.

    Attributes:
        normality: the normality (KKT) residual, Eqs. (D.9)/(D.30).
        objective: z(q).
        hessian: Hess z (n x n).
        dk: dK at q as a :class:`kinredund.kinematics.state.HessianContraction`.
        multipliers: lambda* on the task rows of K (K[rows]^T lambda* = -grad z, least squares).
        null_space: L (n x k), orthonormal basis of the null space of the constraint Jacobian and the
            held limits.
        active: mask (n,) of the joint limits that hold.
        extra: the part of d(G^T lambda)/dtheta that d(K^T lambda*)/dtheta at fixed lambda* leaves out
            (:meth:`kinredund.tasks.TaskResidual.extra_hessian`), or None.
    """

    normality: float
    objective: float
    hessian: np.ndarray
    dk: object
    multipliers: np.ndarray
    null_space: np.ndarray
    active: np.ndarray
    extra: np.ndarray | None = None


@dataclass
class StartOutcome:
    """The end of one start: where it stopped and why; ``terms``: those of a converged start with an
    index at its q (None otherwise)."""

    q: np.ndarray
    converged: bool
    iterations: int
    reason: str
    residual: float
    terms: OptimalityTerms | None = None


# -- linear algebra ------------------------------------------------------------------------------


def qr_split(G: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """Householder QR of G^T (n x m): (R, Y, L, well_conditioned) with G^T = Y R and G L = 0 (Eq. D.25).

    R is returned as the m x m block whose upper triangle is R (the strict lower triangle holds
    Householder vectors; the triangular solves below read the upper triangle only).
    """
    m, n = G.shape
    a, tau, _, _ = lapack.dgeqrf(G.T)
    full = np.zeros((n, n))
    full[:, :m] = a
    U, _, _ = lapack.dorgqr(full, tau)
    return a[:m, :m], U[:, :m], U[:, m:], _well_conditioned(a, m)


def _well_conditioned(a: np.ndarray, m: int) -> bool:
    diag = [abs(v) for v in a.diagonal()[:m].tolist()]
    return min(diag) > RANK_TOL * max(max(diag), 1e-300)


def solve_rt(R: np.ndarray, b: np.ndarray) -> np.ndarray:
    """w with R^T w = b (R upper triangular)."""
    return lapack.dtrtrs(R, b, trans=1)[0]


def solve_r(R: np.ndarray, b: np.ndarray) -> np.ndarray:
    """w with R w = b (R upper triangular)."""
    return lapack.dtrtrs(R, b)[0]


def damped_step(G: np.ndarray, e: np.ndarray) -> np.ndarray:
    """argmin ||G d + e||^2 + mu ||d||^2 (mu of :func:`lm_damping`): Householder least squares (LAPACK
    ``dgels``) on the stacked system [G; sqrt(mu) 1] d = [-e; 0] (no G G^T formed)."""
    m, n = G.shape
    A = np.zeros((m + n, n))
    A[:m] = G
    A[m:] = math.sqrt(lm_damping(G, e)) * np.eye(n)
    rhs = np.zeros(m + n)
    rhs[:m] = -e
    return lapack.dgels(A, rhs)[1][:n]


def lm_damping(G: np.ndarray, e: np.ndarray) -> float:
    """Levenberg-Marquardt damping of the least-squares steps: mu = LM_WEIGHT ||e||^2 + DAMPING max|G|^2
    (after Sugihara 2011: large far from the target, vanishing at it, so convergence stays quadratic)."""
    return LM_WEIGHT * float(e @ e) + DAMPING * float(np.abs(G).max()) ** 2


def cap_step(d: np.ndarray) -> np.ndarray:
    """Scale d so that no joint moves more than :data:`MAX_STEP` along it."""
    big = max(map(abs, d.tolist()))
    return d * (MAX_STEP / big) if big > MAX_STEP else d


def bound_kkt(A: np.ndarray, grad: np.ndarray, q: np.ndarray, lower, upper, bounds: bool):
    """First-order conditions with the joint limits that hold (grad z + A^T y + E^T nu = 0).

    Args:
        A: constraint Jacobian (m x n), rank m.
        grad: grad z (n,).
        q, lower, upper: joint values and limits; ``bounds`` False ignores the limits.

    Returns:
        (normality residual, y (m,), null-space basis (n x k) of A and the held limits, active mask).
        A limit whose multiplier pulls the wrong way is released (it would not hold).
    """
    m, n = A.shape
    act = np.zeros(n, dtype=bool)
    side = np.zeros(n)
    if bounds:
        lo, hi = q <= lower + ACTIVE_TOL, q >= upper - ACTIVE_TOL
        act, side = lo | hi, np.where(hi, 1.0, -1.0)
    while True:
        idx = np.flatnonzero(act)
        C = np.vstack([A, np.eye(n)[idx]]) if idx.size else A
        U, s, Vt = np.linalg.svd(C)
        rank = int(np.sum(s > RANK_TOL * max(s[0], 1e-300)))
        y = -(U[:, :rank] / s[:rank]) @ (Vt[:rank] @ grad)  # least squares of C^T y = -grad, Eq. (4.12)
        nu = y[m:]
        wrong = side[idx] * nu < -1e-12 * max(1.0, float(np.abs(grad).max()))
        if not wrong.any():
            break
        act[idx[np.argmin(side[idx] * nu)]] = False
    L = Vt[rank:].T
    return float(np.linalg.norm(L.T @ grad)), y[:m], L, act  # Eq. (D.30)


# -- the iterations ------------------------------------------------------------------------------


def stall(q, it, r, what: str, rtol: float = 0.0) -> StartOutcome:
    """A start that stopped short; the reason says whether q is on the target (residual < ``rtol``)."""
    where = ("on the target, so not for want of reach" if r < rtol else "target out of reach from here?")
    return StartOutcome(q, False, it, f"{what}; residual stalled at {r:.3g} ({where})", r)
