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
its last iteration to the optimality report (:class:`OptimalityTerms`): no second kinematics pass. An iteration
that takes a restoration step off the target computes no multipliers (no first-order test can pass there).
Where the compiled core runs the iterations (:mod:`kinredund.ik.compiled`), this module takes over the
iterations that the core hands back, one at a time, with the same results.

A pose-only solve (no index) is the x0 part alone in its damped form, kept lean because multi-start
IK runs it many times (:func:`kinredund.ik.pose_only.pose_only`): Levenberg-Marquardt steps d = -G^T (G G^T + mu 1)^-1 e
with the damping adapted by the gain ratio (Nielsen 1999), accepted when they decrease ||e||; joint
limits by holding the joints that a step pushes out of their limits and clipping the rest into them
(as KDL's joint-limited Newton-Raphson solver in TRAC-IK, Beeson and Ames 2015). While other starts
remain, a start that stops halving ||e||^2 is abandoned for a fresh one (TRAC-IK's random restarts),
after one try at turning a joint stuck at a limit through a full turn to the far side of its range.
"""

from __future__ import annotations

import math
from time import perf_counter

import numpy as np

from kinredund.ik.common import (
    ARMIJO,
    MAX_STEP,
    MIN_ALPHA,
    STALL_ITERS,
    OptimalityTerms,
    Setup,
    StartOutcome,
    bound_kkt,
    cap_step,
    damped_step,
    lm_damping,
    qr_split,
    solve_r,
    solve_rt,
    stall,
)
from kinredund.ik.compiled import run_compiled
from kinredund.ik.pose_only import pose_only


def run_start(s: Setup, q: np.ndarray) -> StartOutcome:
    """Iterate from q until converged, stalled, out of iterations or out of time."""
    if s.index is None:
        return pose_only(s, q.copy())
    return _constrained_minimum(s, q.copy())


def _timed_out(s: Setup) -> bool:
    return s.deadline is not None and perf_counter() > s.deadline


def _in_box(s: Setup, q: np.ndarray) -> bool:
    return not ((q < s.lower).any() or (q > s.upper).any())


def _restore(s: Setup, q: np.ndarray, G: np.ndarray, e: np.ndarray, r: float, it: int):
    """A damped least-squares step on the constraints alone, backtracking on 1/2 ||e||^2.

    Returns the new q, or a :class:`StartOutcome` when no decrease is possible.
    """
    d = damped_step(G, e)
    if s.bounds and not _in_box(s, q + d):
        d = s.box.least_squares(G, e, lm_damping(G, e), s.lower - q, s.upper - q)
    d = cap_step(d)
    slope = float(e @ (G @ d))
    if not slope < 0.0:
        return stall(q, it, r, "no descent direction for the residual", s.rtol)
    phi = 0.5 * float(e @ e)
    alpha = 1.0
    while alpha >= MIN_ALPHA:
        qt = _clip(s, q + alpha * d)
        if 0.5 * s.res.error_terms(*s.kin.pose(qt))[1] <= phi + ARMIJO * alpha * slope:  # e only, no Jl^-1
            return qt
        alpha *= 0.5
    return stall(q, it, r, "line search failed", s.rtol)


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

    state = None
    while True:
        if s.compiled:  # the iterations in C++ up to convergence or to one they hand back (kinredund.ik.compiled)
            state = run_compiled(s, q, on_target, state)
            if isinstance(state, StartOutcome):
                return state
        out = _iterate(s, q, on_target, state)
        if isinstance(out, StartOutcome):
            return out if out.converged else give_up(out)
        state = out


def _iterate(s: Setup, q: np.ndarray, on_target: list, state: tuple | None = None) -> StartOutcome | tuple:
    """The iterations of :func:`_constrained_minimum`; ``on_target`` is updated with [q, z, r]. ``state``:
    where the compiled iteration handed back, (iteration, q, rho, r_ref, since, q_prev, r_prev) at its start;
    the iteration after it is handed back to the core (the state at its start returned)."""
    kin, res, index, rows = s.kin, s.res, s.index, s.res.rows
    # r_ref, since: the stall test's; q_prev, r_prev: the last iterate where the index was finite, and its residual
    it0, q, rho, r_ref, since, q_prev, r_prev = state or (0, q, 0.0, math.inf, 0, q, math.inf)
    for it in range(it0, s.max_iter + 1):
        if s.compiled and it > it0:
            return it, q, rho, r_ref, since, q_prev, r_prev
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
        if float(e @ e) < s.rtol * s.rtol and not r < s.rtol:
            why = res.spurious(Q, p)
            if why:  # e vanishes and the task is not done (the tool axis reversed): the next start
                return StartOutcome(q, False, it, why, r)
        if r < s.rtol and float(e @ e) < s.rtol * s.rtol and (not on_target or z < on_target[1]):
            on_target[:] = [q.copy(), float(z), r]
        G = res.jacobian(K, jl)
        R, Y, L, ok = qr_split(G)  # G^T = Y R, G L = 0, Eq. (D.25)
        x0 = Y @ solve_rt(R, -e) if ok else None  # minimum-norm part, Eq. (D.24)
        newton = x0 is not None and max(map(abs, x0.tolist())) <= MAX_STEP
        normality = math.nan
        if newton or r < s.rtol or it == s.max_iter:  # else a restoration step follows: no multipliers needed
            normality, lam, L_kkt, active = _first_order(s, G, grad, q, R, Y, L, ok)
        ntol = max(s.tol, 1e-13 * (1.0 + float(np.abs(grad).max())))
        if r < s.rtol and float(e @ e) < s.rtol * s.rtol and normality < ntol:
            if active is None:
                active = np.zeros(q.shape[0], dtype=bool)
            extra = res.extra_hessian(K, lam, jl)
            terms = OptimalityTerms(normality, float(z), H, dk, res.k_multipliers(lam, jl), L_kkt, active, extra)
            return StartOutcome(q, True, it, "", r, terms)  # the terms are for the report
        if it == s.max_iter:
            why = f"max_iter={s.max_iter} reached at residual {r:.3g}, normality residual {normality:.3g}"
            return StartOutcome(q, False, it, why, r)
        if _timed_out(s):
            return StartOutcome(q, False, it, "timeout", r)
        if r < 0.5 * r_ref or r < 1e3 * s.rtol:
            r_ref, since = r, 0
        elif since >= 2 * STALL_ITERS:  # far from g = x and not getting closer
            return stall(q, it, r, f"the residual did not halve in {2 * STALL_ITERS} iterations", s.rtol)
        since += 1
        if not ok and r < s.rtol:
            return StartOutcome(q, False, it, "on the target at a singular configuration (rank-deficient constraint "
                                f"Jacobian), where z still changes along the null space (normality residual "
                                f"{normality:.3g}): the step of Eq. (D.26) is undefined here; seed elsewhere", r)
        if not newton:
            # near-singular G or far from g = x: a damped restoration step on the constraints alone
            qn = _restore(s, q, G, e, r, it)
            if isinstance(qn, StartOutcome):
                return qn
            q = qn
            continue
        lam_k = res.k_multipliers(lam, jl)  # G^T lambda = K[rows]^T lambda*
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
            d = cap_step(dq if dq is not None else s.box.least_squares(G, e, lm_damping(G, e), lb, ub))
        Gd = G @ d
        slope = float(grad @ d) + rho * (float(e @ Gd) / enorm if enorm > 0.0 else math.sqrt(float(Gd @ Gd)))
        phi = z + rho * enorm
        qn = _merit_search(s, q, d, rho, phi, slope, R, Y)
        if qn is None:
            why = "no descent direction for the merit function" if slope >= 0.0 else "line search failed"
            return stall(q, it, r, f"{why} (normality residual {normality:.3g})", s.rtol)
        q = qn
    raise AssertionError("unreachable")  # pragma: no cover


def _first_order(s: Setup, G, grad, q, R, Y, L, ok: bool):
    """(normality residual, multipliers lambda, null space for the report, held limits or None) at one iterate.

    With bounds the limits that hold count; G rank-deficient (a singular configuration): the SVD's null space,
    which holds every direction tangent to g = x, so the test is stricter, not looser.
    """
    if s.bounds or not ok:
        return bound_kkt(G, grad, q, s.lower, s.upper, s.bounds)
    lam = -solve_r(R, Y.T @ grad)  # least-squares multipliers, Eqs. (4.11)-(4.12)
    return float(np.linalg.norm(L.T @ grad)), lam, L, None  # projected gradient, Eqs. (D.9), (D.30)


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
