"""One start of the joint-level IK: the orthogonal-decomposition algorithm of Appendix D.

At each iteration the constraints are linearised, G dx = -e (Eq. D.23), and the step is split into two
orthogonal parts, dx = x0 + L u (Eq. D.24):

- x0, the minimum-norm solution of G x0 = -e, from the Householder QR factorisation G^T = [Y L] [R; 0]
  (LAPACK ``dgeqrf``/``dorgqr``): x0 = -Y R^-T e. J J^T is never formed.
- L u, a step in the null space of G (G L = 0, Eq. D.25). u minimises the second-order model of the
  objective along x0 + L u, Eq. (D.26) in its normal form with the Lagrangian Hessian (Newton-SQP):
  (L^T M L) u = -L^T (grad z + M x0), M = Hess z + Lambda, Lambda = d(G^T lambda)/dtheta (Eq. 4.26),
  lambda = -R^-1 Y^T grad z the least-squares multipliers of Eqs. (4.11)-(4.12). Where L^T M L is not
  positive definite its eigenvalues are replaced by their magnitudes (a descent step; D.33 fails there).

The step length is safeguarded by backtracking on the exact-penalty merit function
phi = z + rho ||e|| (Armijo test, with one second-order correction -Y R^-T e(theta + dx) against the
Maratos effect). Where x0 cannot be trusted (G near singular, or x0 moving a joint by more than
:data:`MAX_STEP`), a damped least-squares step on the constraints alone replaces the step
(Levenberg-Marquardt, damping mu = LM_WEIGHT ||e||^2 + DAMPING max|G|^2 after Sugihara 2011).
Step sizes: x0 is taken in full only when it moves no joint by more than :data:`MAX_STEP`, and the
null-space part L u is scaled down to that size on its own, so a step x0 + L u can move a joint by
up to 2 MAX_STEP (x0 still restores g = x to first order in full); the restoration steps and the
bounded steps below are scaled down to MAX_STEP as a whole. With joint limits as bounds, a step that
would leave them is recomputed as a box-constrained QP (:mod:`kinredund.ik.qp`); first-order
optimality then includes the multipliers of the active bounds. A converged start hands the terms of
its last iteration to the optimality report (:class:`OptimalityTerms`): no second kinematics pass.

A pose-only solve (no index) is the x0 part alone in its damped form, kept lean because multi-start
IK runs it many times (:func:`_pose_only`): Levenberg-Marquardt steps d = -G^T (G G^T + mu 1)^-1 e
with the damping adapted by the gain ratio (Nielsen 1999), accepted when they decrease ||e||; joint
limits by holding the joints that a step pushes out of their limits and clipping the rest into them
(as KDL's joint-limited Newton-Raphson solver in TRAC-IK, Beeson and Ames 2015). While other starts
remain, a start that stops halving ||e||^2 is abandoned for a fresh one (TRAC-IK's random restarts),
after one try at turning a joint stuck at a limit through a full turn to the far side of its range.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from time import perf_counter

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
    """argmin ||G d + e||^2 + mu ||d||^2 (mu of :func:`_mu`): Householder least squares (LAPACK
    ``dgels``) on the stacked system [G; sqrt(mu) 1] d = [-e; 0] (no G G^T formed)."""
    m, n = G.shape
    A = np.zeros((m + n, n))
    A[:m] = G
    A[m:] = math.sqrt(_mu(G, e)) * np.eye(n)
    rhs = np.zeros(m + n)
    rhs[:m] = -e
    return lapack.dgels(A, rhs)[1][:n]


def _mu(G: np.ndarray, e: np.ndarray) -> float:
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
def run_start(s: Setup, q: np.ndarray) -> StartOutcome:
    """Iterate from q until converged, stalled, out of iterations or out of time."""
    if s.index is None:
        return _pose_only(s, q.copy())
    return _constrained_minimum(s, q.copy())


def _timed_out(s: Setup) -> bool:
    return s.deadline is not None and perf_counter() > s.deadline


def _in_box(s: Setup, q: np.ndarray) -> bool:
    return not ((q < s.lower).any() or (q > s.upper).any())


def _stall(q, it, r, what: str, rtol: float = 0.0) -> StartOutcome:
    """A start that stopped short; the reason says whether q is on the target (residual < ``rtol``)."""
    where = ("on the target, so not for want of reach" if r < rtol else "target out of reach from here?")
    return StartOutcome(q, False, it, f"{what}; residual stalled at {r:.3g} ({where})", r)


def _pose_only(s: Setup, q: np.ndarray) -> StartOutcome:
    """Levenberg-Marquardt steps on the task error alone (index=None): the damped form of the Newton
    step x0 = -G^+ e of Eqs. (D.23)-(D.24), d = -G^T (G G^T + mu 1)^-1 e.

    Lean by design (an iteration is one Jacobian, one 6x6 Cholesky solve and a handful of small numpy
    calls): for pose tasks G is K itself, the Jacobian of e up to Jl^-1 = 1 + O(||e||), which keeps the
    convergence quadratic; mu = scale (LM_WEIGHT ||e||^2 + DAMPING max|G|^2) after Sugihara (2011), with
    the scale adapted by the gain ratio of Nielsen (1999). With bounds, a joint at a limit that the step
    pushes out is frozen there (its column of G dropped, the step recomputed) and the rest is clipped
    into the limits (the joint-limit handling of KDL's Newton-Raphson solver, as in TRAC-IK).
    """
    res, jac, terms, rows = s.res, s.kin.jacobian, s.res.error_terms, s.res.row_selection
    eye, bounds, lower_list, upper_list = s.eye, s.bounds, s.lower_list, s.upper_list
    rtol2 = s.rtol * s.rtol
    quick = s.quick_exit
    stall_iters = QUICK_STALL_ITERS if quick else STALL_ITERS
    max_iter = min(s.max_iter, QUICK_MAX_ITER) if quick else s.max_iter
    slow_max = max(max_iter, min(s.max_iter, SLOW_MAX_ITER)) if quick else max_iter
    Q, p, K = jac(q)
    ev, phi = terms(Q, p)
    history = [phi]  # ||e||^2 at each iterate
    phi_ref, since = phi, 0
    scale, nu, floor = 1.0, 2.0, -1.0
    held, turns = [], 0  # joints held at a limit by the last step; turns made
    it = 0
    while True:
        if phi < rtol2:
            r = res.residual(Q, p)
            if r < s.rtol:  # closure residual and SE(3) error
                return StartOutcome(q, True, it, "", r)
        if phi < (0.5 if quick else 1.0 - PATIENT_DECREASE) * phi_ref:
            phi_ref, since = phi, 0
        slow = quick and phi < SLOW_PHI and it < slow_max and phi < SLOW_RATIO * history[max(0, it - stall_iters)]
        if (since >= stall_iters or it >= max_iter) and not slow:
            turned = _turn_past_limits(s, q, held) if quick and turns < TURNS and since >= stall_iters else None
            if turned is None:
                r = res.residual(Q, p)
                if since >= stall_iters:
                    return _stall(q, it, r, f"no progress in {since} iterations", s.rtol)
                return StartOutcome(q, False, it, f"max_iter={it} reached at residual {r:.3g}", r)
            q, held, turns = turned, [], turns + 1
            Q, p, K = jac(q)
            ev, phi = terms(Q, p)
            phi_ref, since, scale, nu = phi, 0, 1.0, 2.0
            history[-1] = phi
        since += 1
        if s.deadline is not None and perf_counter() > s.deadline:
            return StartOutcome(q, False, it, "timeout", res.residual(Q, p))
        G = K if rows is None else K[rows]
        if floor < 0.0:
            floor = DAMPING * float(np.abs(G).max()) ** 2
        e = np.array(ev)
        GGt = G @ G.T
        while True:
            mu = scale * (LM_WEIGHT * phi + floor)
            x, info = lapack.dposv(GGt + mu * eye, e)[1:]  # (G G^T + mu 1) x = e
            if info == 0:
                qn = q - x @ G
                lin2 = mu * mu * float(x @ x)  # ||e + G d||^2 = ||mu x||^2 for d = -G^T x
                new_held = []
                if bounds and _outside(qn.tolist(), lower_list, upper_list):
                    qn, new_held = _freeze_and_clip(s, q, qn, G, e, mu)
                    lin = e + G @ (qn - q)
                    lin2 = float(lin @ lin)
                Qn, pn, Kn = jac(qn)
                evn, phin = terms(Qn, pn)
                if phin < phi:
                    pred = phi - lin2
                    rho = (phi - phin) / pred if pred > 0.0 else 0.0  # gain ratio
                    scale = max(1.0, scale * max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3))
                    nu = 2.0
                    break
            scale *= nu
            nu *= 2.0
            if scale > MAX_SCALE:
                return _stall(q, it, res.residual(Q, p), "no step decreases the residual", s.rtol)
        q, Q, p, K, ev, phi, held = qn, Qn, pn, Kn, evn, phin, new_held
        history.append(phi)
        it += 1


def _outside(values: list, lower: list, upper: list) -> bool:
    """Whether any of the joint values lies outside its limits (a plain loop: faster than numpy on 7)."""
    for v, a, b in zip(values, lower, upper, strict=True):
        if v < a or v > b:
            return True
    return False


def _freeze_and_clip(
    s: Setup, q: np.ndarray, qn: np.ndarray, G: np.ndarray, e: np.ndarray, mu: float
) -> tuple[np.ndarray, list[int]]:
    """The damped step recomputed with the joints that sit at a limit and would leave it held there
    (their columns of G dropped), then clipped into the limits. Returns (q + d, the held joints)."""
    lo, hi = s.lower_list, s.upper_list
    new, old = qn.tolist(), q.tolist()
    held = [j for j in range(len(new)) if (new[j] < lo[j] and old[j] <= lo[j]) or (new[j] > hi[j] and old[j] >= hi[j])]
    if held:
        Gf = G.copy()
        for j in held:
            Gf[:, j] = 0.0
        x, info = lapack.dposv(Gf @ Gf.T + mu * s.eye, e)[1:]
        if info == 0:
            qn = q - x @ Gf
    return np.minimum(np.maximum(qn, s.lower), s.upper), held


def _turn_past_limits(s: Setup, q: np.ndarray, held: list[int]) -> np.ndarray | None:
    """q with the held revolute joints turned by 2 pi away from their limit and clipped into the
    limits, or None when no held joint can turn.

    A joint held at its upper limit u by steps that push it further wants an angle u + delta, which is
    the angle u + delta - 2 pi: inside the limits beyond the gap 2 pi - (u - l) that the range misses
    of a full turn. Turning it to the far limit (or, for a range over a full turn, to the same angle
    there) continues its motion past the stop; worth a try before a fresh start when the gap is small
    (the Panda's joints 1, 3, 5, 7 miss a turn by 0.49 rad).
    """
    turn = [j for j in held if s.turnable[j]]
    if not turn:
        return None
    out = q.copy()
    for j in turn:
        v = out[j] - 2.0 * math.pi if out[j] >= s.upper_list[j] else out[j] + 2.0 * math.pi
        out[j] = min(max(v, s.lower_list[j]), s.upper_list[j])
    return out


def _restore(s: Setup, q: np.ndarray, G: np.ndarray, e: np.ndarray, r: float, it: int):
    """A damped least-squares step on the constraints alone, backtracking on 1/2 ||e||^2.

    Returns the new q, or a :class:`StartOutcome` when no decrease is possible.
    """
    d = damped_step(G, e)
    if s.bounds and not _in_box(s, q + d):
        d = s.box.least_squares(G, e, _mu(G, e), s.lower - q, s.upper - q)
    d = cap_step(d)
    slope = float(e @ (G @ d))
    if not slope < 0.0:
        return _stall(q, it, r, "no descent direction for the residual", s.rtol)
    phi = 0.5 * float(e @ e)
    alpha = 1.0
    while alpha >= MIN_ALPHA:
        qt = _clip(s, q + alpha * d)
        if 0.5 * s.res.error_terms(*s.kin.pose(qt))[1] <= phi + ARMIJO * alpha * slope:  # e only, no Jl^-1
            return qt
        alpha *= 0.5
    return _stall(q, it, r, "line search failed", s.rtol)


def _merit(s: Setup, q: np.ndarray, rho: float) -> tuple[float, tuple[float, ...]]:
    """phi = z + rho ||e|| at q, and e (a tuple: no Jl^-1 is needed here)."""
    e, ee = s.res.error_terms(*s.kin.pose(q))
    return s.index.value(q) + rho * math.sqrt(ee), e


def _constrained_minimum(s: Setup, q: np.ndarray) -> StartOutcome:
    """min z(theta) s.t. g(theta) = x by the orthogonal decomposition of Appendix D.

    A start that does not converge returns the lowest-z iterate that was on the target (g = x within
    the tolerance) if the run ended off it: an index unbounded below along the self-motion (e.g. a
    negative-definite one) trades the residual for z, and the seed must not come back worse than it went in.
    """
    on_target: list = []  # [q, z, r] of the lowest-z iterate on the target so far

    def give_up(out: StartOutcome) -> StartOutcome:
        if not on_target or out.residual < s.rtol:
            return out
        q_on, z_on, r_on = on_target
        what = out.reason.split("; residual stalled")[0]  # the stall's guess at an unreachable target is wrong here
        return StartOutcome(q_on, False, out.iterations, f"{what}, after leaving the target (residual "
                            f"{out.residual:.3g}) while z fell to {s.index.value(out.q):.6g}: is the index bounded "
                            f"below along the self-motion? The lowest-z point on the target is returned "
                            f"(z = {z_on:.6g})", r_on)

    out = _iterate(s, q, on_target)
    return out if out.converged else give_up(out)


def _iterate(s: Setup, q: np.ndarray, on_target: list) -> StartOutcome:
    """The iterations of :func:`_constrained_minimum`; ``on_target`` is updated with [q, z, r]."""
    kin, res, index, rows = s.kin, s.res, s.index, s.res.rows
    rho = 0.0
    r_ref, since = math.inf, 0
    q_prev, r_prev = q, math.inf  # the last iterate where the index was finite, and its residual
    for it in range(s.max_iter + 1):
        Q, p, K, dk = kin.jacobian_hessian(q)
        e, jl = res.error(Q, p)
        r = res.residual(Q, p)
        z, grad, H = index.evaluate(q)
        grad, H = np.asarray(grad, dtype=float), np.asarray(H, dtype=float)
        if not (math.isfinite(z) and np.isfinite(grad).all() and np.isfinite(H).all()):
            where = "the last point where it was finite is returned" if it else "a multi-start sample"
            return StartOutcome(q_prev, False, max(it - 1, 0), f"the index turned non-finite at q = {q.tolist()} "
                                f"(iteration {it}): {where}", r_prev)
        q_prev, r_prev = q, r
        if r < s.rtol and float(e @ e) < s.rtol * s.rtol and (not on_target or z < on_target[1]):
            on_target[:] = [q.copy(), float(z), r]
        G = res.jacobian(K, jl)
        R, Y, L, ok = qr_split(G)  # G^T = Y R, G L = 0, Eq. (D.25)
        L_kkt, active = L, None  # the null space and the held limits of the first-order conditions
        if s.bounds or not ok:
            # with bounds: the limits that hold count; G rank-deficient (a singular configuration): the SVD's
            # null space, which holds every direction tangent to g = x, so the test is stricter, not looser
            normality, lam, L_kkt, active = bound_kkt(G, grad, q, s.lower, s.upper, s.bounds)
        else:
            lam = -solve_r(R, Y.T @ grad)  # least-squares multipliers, Eqs. (4.11)-(4.12)
            normality = float(np.linalg.norm(L.T @ grad))  # projected gradient, Eqs. (D.9), (D.30)
        lam_k = res.k_multipliers(lam, jl)  # G^T lambda = K[rows]^T lambda*
        ntol = max(s.tol, 1e-13 * (1.0 + float(np.abs(grad).max())))
        if r < s.rtol and float(e @ e) < s.rtol * s.rtol and normality < ntol:
            if active is None:
                active = np.zeros(q.shape[0], dtype=bool)
            extra = res.extra_hessian(K, lam, jl)
            terms = OptimalityTerms(normality, float(z), H, dk, lam_k, L_kkt, active, extra)  # for the report
            return StartOutcome(q, True, it, "", r, terms)
        if it == s.max_iter:
            why = f"max_iter={s.max_iter} reached at residual {r:.3g}, normality residual {normality:.3g}"
            return StartOutcome(q, False, it, why, r)
        if _timed_out(s):
            return StartOutcome(q, False, it, "timeout", r)
        if r < 0.5 * r_ref or r < 1e3 * s.rtol:
            r_ref, since = r, 0
        elif since >= 2 * STALL_ITERS:  # far from g = x and not getting closer
            return _stall(q, it, r, f"the residual did not halve in {2 * STALL_ITERS} iterations", s.rtol)
        since += 1
        if not ok and r < s.rtol:
            return StartOutcome(q, False, it, "on the target at a singular configuration (rank-deficient constraint "
                                f"Jacobian), where z still changes along the null space (normality residual "
                                f"{normality:.3g}): the step of Eq. (D.26) is undefined here; seed elsewhere", r)
        x0 = Y @ solve_rt(R, -e) if ok else None  # minimum-norm part, Eq. (D.24)
        if x0 is None or max(map(abs, x0.tolist())) > MAX_STEP:
            # near-singular G or far from g = x: a damped restoration step on the constraints alone
            qn = _restore(s, q, G, e, r, it)
            if isinstance(qn, StartOutcome):
                return qn
            q = qn
            continue
        enorm = math.sqrt(float(e @ e))
        rho = max(rho, 1.5 * float(np.linalg.norm(lam)) + 1.0)  # exact penalty > ||lambda||; > 0 at grad z = 0
        M = H + dk.contract(lam_k, rows)  # Hess z + Lambda, Eqs. (4.20)-(4.26)
        extra = res.extra_hessian(K, lam, jl)
        if extra is not None:
            M = M + extra
        Br = L.T @ M @ L
        w, V = np.linalg.eigh(0.5 * (Br + Br.T))
        wmod = np.maximum(np.abs(w), 1e-8 * max(1.0, float(np.abs(w).max())))  # PD where D.33 fails
        gr = L.T @ grad
        u = -V @ ((V.T @ (gr + L.T @ (M @ x0))) / wmod)  # Eq. (D.26), Newton form
        d = x0 + cap_step(L @ u)  # the cap shortens the null-space part only: x0 restores g = x in full
        if float(grad @ d) - rho * enorm >= 0.0 and gr @ gr > 0.0:
            u = -V @ ((V.T @ gr) / wmod)  # drop the coupling term: a sure descent direction
            d = x0 + cap_step(L @ u)
        if s.bounds and not _in_box(s, q + d):
            lb, ub = s.lower - q, s.upper - q
            B = L @ (V * wmod) @ V.T @ L.T + Y @ Y.T  # the reduced model of Eq. (D.26), PD
            dq = s.box.equality(B, grad + L @ (L.T @ (M @ x0)), G, e, lb, ub)
            d = cap_step(dq if dq is not None else s.box.least_squares(G, e, _mu(G, e), lb, ub))
        Gd = G @ d
        slope = float(grad @ d) + rho * (float(e @ Gd) / enorm if enorm > 0.0 else math.sqrt(float(Gd @ Gd)))
        phi = z + rho * enorm
        qn = _merit_search(s, q, d, rho, phi, slope, R, Y)
        if qn is None:
            why = "no descent direction for the merit function" if slope >= 0.0 else "line search failed"
            return _stall(q, it, r, f"{why} (normality residual {normality:.3g})", s.rtol)
        q = qn
    raise AssertionError("unreachable")  # pragma: no cover


def _merit_search(s: Setup, q, d, rho, phi, slope, R, Y) -> np.ndarray | None:
    """Armijo backtracking on phi = z + rho ||e|| along q + alpha d, each trial point also tried with
    a second-order correction -Y R^-T e(q + alpha d) back towards g = x (against the Maratos effect and
    the drift off the constraints that curved self-motions cause).

    A step whose predicted decrease is at round-off level (|slope| <= 1e-12 (1 + |phi|), joints moving
    < 1e-6) is taken as it is: the merit function cannot resolve it and the iteration is converging.
    """
    alpha = 1.0
    while alpha >= MIN_ALPHA:
        qt = _clip(s, q + alpha * d)
        phit, et = _merit(s, qt, rho)
        goal = phi + ARMIJO * alpha * slope
        if phit <= goal or (alpha == 1.0 and -slope <= 1e-12 * (1.0 + abs(phi)) and float(np.abs(d).max()) < 1e-6):
            return qt
        qc = _clip(s, qt + Y @ solve_rt(R, -np.array(et)))  # second-order correction
        if _merit(s, qc, rho)[0] <= goal:
            return qc
        if not slope < 0.0:
            return None
        alpha *= 0.5
    return None


def _clip(s: Setup, q: np.ndarray) -> np.ndarray:
    """q clipped into the limits in place when bounds are on (np.clip is slower on short vectors)."""
    return np.minimum(np.maximum(q, s.lower, out=q), s.upper, out=q) if s.bounds else q
