"""A pose-only start of the joint-level IK (no index): Levenberg-Marquardt steps on the task error
alone, the damped form of the minimum-norm step x0 = -G^+ e of Eqs. (D.23)-(D.24) (see
:mod:`kinredund.ik.newton` for the whole start)."""

from __future__ import annotations

import math
from time import perf_counter

import numpy as np
from scipy.linalg import lapack

from kinredund.ik.common import (
    DAMPING,
    LM_WEIGHT,
    MAX_SCALE,
    PATIENT_DECREASE,
    QUICK_MAX_ITER,
    QUICK_STALL_ITERS,
    SLOW_MAX_ITER,
    SLOW_PHI,
    SLOW_RATIO,
    STALL_ITERS,
    TURNS,
    Setup,
    StartOutcome,
    stall,
)


def pose_only(s: Setup, q: np.ndarray) -> StartOutcome:
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
    own_g = res.m != (K.shape[0] if rows is None else len(rows))
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
            turned = turn_past_limits(s, q, held) if quick and turns < TURNS and since >= stall_iters else None
            if turned is None:
                r = res.residual(Q, p)
                if since >= stall_iters:
                    return stall(q, it, r, f"no progress in {since} iterations", s.rtol)
                return StartOutcome(q, False, it, f"max_iter={it} reached at residual {r:.3g}", r)
            q, held, turns = turned, [], turns + 1
            Q, p, K = jac(q)
            ev, phi = terms(Q, p)
            phi_ref, since, scale, nu = phi, 0, 1.0, 2.0
            history[-1] = phi
        since += 1
        if s.deadline is not None and perf_counter() > s.deadline:
            return StartOutcome(q, False, it, "timeout", res.residual(Q, p))
        # K's rows (the Jacobian up to Jl^-1), or the task's own G where e is no subset of them (tool axis)
        G = res.jacobian(K, res.error(Q, p)[1]) if own_g else (K if rows is None else K[rows])
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
                    qn, new_held = freeze_and_clip(s, q, qn, G, e, mu)
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
                return stall(q, it, res.residual(Q, p), "no step decreases the residual", s.rtol)
        q, Q, p, K, ev, phi, held = qn, Qn, pn, Kn, evn, phin, new_held
        history.append(phi)
        it += 1


def _outside(values: list, lower: list, upper: list) -> bool:
    """Whether any of the joint values lies outside its limits (a plain loop: faster than numpy on 7)."""
    for v, a, b in zip(values, lower, upper, strict=True):
        if v < a or v > b:
            return True
    return False


def freeze_and_clip(
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


def turn_past_limits(s: Setup, q: np.ndarray, held: list[int]) -> np.ndarray | None:
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
