"""The linear algebra of the augmented system of Chapter 4: R of Eq. (4.24), its LU and QP solutions.

    R = [[M, J^T], [J, 0]],   R [thetadot; lambdadot] = [-d(grad z)/dt; xdot],   M = Hess z + Lambda  (4.24)

- :func:`kkt_matrix` builds R; :func:`lu_solve` solves with R's LAPACK LU factors;
- :func:`multipliers`: lambda by Householder least squares (Eqs. 4.11-4.12);
- :func:`classify` labels a step by where the QP form of Theorem 2 (Eq. 4.28) holds (``qp``, ``qp_aug``,
  ``lu``); :class:`RateQP` solves that QP with proxsuite, :func:`solve_rates` either route;
  :func:`bound_rate_qp` is the same QP with the sign condition of a weakly active joint bound (the
  decider at a switch of :mod:`kinredund.tracking.limited`);
- :func:`null_space_eigs`: the eigenvalues of M projected on the null space of J (Theorem 2);
- :func:`hermite_weights`: the default mode's predictor (Hermite extrapolation along the optimal path).

The batched forms (:func:`eigs_many`, :func:`null_space_eigs_many`, :func:`labels_many`,
:func:`normality_many`) give the recorder its per-step diagnostics in a few numpy calls per run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.linalg import lapack


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
    return null_space_eigs_many(M[None], J[None])[0]


def lu_solve(lu, b: np.ndarray) -> np.ndarray:
    """Solve R x = b with R's LU factors ``(lu, piv)`` from LAPACK dgetrf."""
    return lapack.dgetrs(lu[0], lu[1], b)[0]


def kkt_matrix(M: np.ndarray, J: np.ndarray) -> np.ndarray:
    """R of Eq. (4.24): [[M, J^T], [J, 0]]."""
    n, m = M.shape[0], J.shape[0]
    R = np.zeros((n + m, n + m))
    R[:n, :n] = M
    R[:n, n:] = J.T
    R[n:, :n] = J
    return R


class RateQP:
    """A reused proxsuite dense QP for the rates of Theorem 2 (Eq. 4.28)."""

    def __init__(self, n: int, m: int):
        import proxsuite

        self.qp = proxsuite.proxqp.dense.QP(n, m, 0)
        self.qp.settings.eps_abs = 1e-12
        self.qp.settings.eps_rel = 0.0
        self.qp.settings.verbose = False
        self.initialised = False

    def solve(self, M, J, top, xdot):
        """min 1/2 v^T (M + rho J^T J) v - top^T v s.t. J v = xdot; returns (v, lambdadot) or None."""
        import proxsuite

        Ms = 0.5 * (M + M.T)
        rho = 1.0
        JtJ = J.T @ J
        for _ in range(60):
            H = Ms + rho * JtJ
            if cholesky_ok(H):
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


def convexified(M: np.ndarray, A: np.ndarray) -> np.ndarray | None:
    """sym(M) + rho A^T A for the least rho in 0, 1, 4, 16, ... below 1e12 that makes it positive definite (the same
    minimiser of 1/2 v^T M v - top^T v on A v = b), or None where none does: M is then not positive definite on the
    null space of A (Finsler's lemma), or nearly singular there (rho stops below 1e12; rates of ~1e7 there, next to a
    fold). Indefinite, a rate QP with one inequality besides A v = b is unbounded along a direction of negative
    curvature, which the inequality cannot bound in both senses (no solution); semidefinite, its minimiser is not
    unique (the rates not determined): either way the run stops there as not strongly stable."""
    Ms = 0.5 * (M + M.T)
    H, rho, convex = Ms, 1.0, cholesky_ok(Ms)
    while not convex and rho < 1e12:
        H, rho = Ms + rho * A.T @ A, rho * 4.0
        convex = cholesky_ok(H)
    return H if convex else None


def bound_rate_qp(M: np.ndarray, top: np.ndarray, J: np.ndarray, xdot: np.ndarray, joint: int,
                  side: float) -> tuple[float, float] | None:
    """The rate QP at a weakly active joint bound: min 1/2 v^T M v - top^T v s.t. J v = xdot, side v_joint >= 0.

    Eq. (4.24)'s rates as a QP (Theorem 2, Eq. 4.28) with the sign condition of the bound (``side`` +1 at
    a lower bound, -1 at an upper one), over the joints not held on a bound. M is replaced by
    sym(M) + rho J^T J where it is not positive definite (the same minimiser on J v = xdot: :func:`convexified`).
    Solved with proxsuite to 1e-12. Returns (side v_joint, the bound's multiplier >= 0), or None if unsolved, also
    without calling the solver where no rho makes it convex (unbounded: proxsuite iterated to its limit, seconds,
    on such QPs of random tasks before it gave up).
    """
    import proxsuite

    H = convexified(M, J)
    if H is None:
        return None
    C = np.zeros((1, M.shape[0]))
    C[0, joint] = side
    qp = proxsuite.proxqp.dense.QP(M.shape[0], J.shape[0], 1)
    qp.settings.eps_abs, qp.settings.eps_rel, qp.settings.verbose = 1e-12, 0.0, False
    qp.init(H, -top, J, xdot, C, np.zeros(1), np.full(1, 1e20))
    qp.solve()
    if qp.results.info.status != proxsuite.proxqp.PROXQP_SOLVED:
        return None
    return float(C[0] @ qp.results.x), float(-qp.results.z[0])  # proxsuite's z <= 0 on an active lower side


def solve_rates(M, J, top, xdot, *, label: str, backend: str, prox: RateQP | None, lu=None) -> RateSolution:
    """Solve Eq. (4.24) for the rates: the QP of Theorem 2 (Eq. 4.28) for ``qp``/``qp_aug``, else LU of R.

    ``lu``: R's LU factors (from LAPACK dgetrf) if the caller has them; otherwise R is factorised here.
    """
    n = M.shape[0]
    if label != "lu" and backend == "proxsuite" and prox is not None:
        out = prox.solve(M, J, top, xdot)
        if out is not None:
            return RateSolution(out[0], out[1], label)
    rhs = np.concatenate([top, xdot])
    sol = lu_solve(lu, rhs) if lu is not None else np.linalg.solve(kkt_matrix(M, J), rhs)  # LU, partial pivoting
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
    if cholesky_ok(M):
        return "qp"
    if rule == "thesis":
        return "lu"
    return "qp_aug" if _projected_pd(M, J) else "lu"


def labels_many(Ms: list, Js: list, rule: str, symmetric: bool, m_eigs: np.ndarray | None = None,
                m_null_eigs: np.ndarray | None = None) -> list[str]:
    """:func:`classify` of each (M, J) pair.

    Where the eigenvalues of M (``m_eigs``) and of its projection (``m_null_eigs``, :func:`eigs_many` and
    :func:`null_space_eigs_many` of the same pairs) are given and clearly away from zero (by 1e-8 of the
    scale of M), their signs give the verdicts; nearer zero, :func:`classify` decides, so the labels are
    :func:`classify`'s own.
    """
    if m_eigs is None or m_null_eigs is None or rule == "lu" or not symmetric:
        return [classify(M, J, rule, symmetric) for M, J in zip(Ms, Js, strict=True)]
    out = []
    for M, J, e, en in zip(Ms, Js, m_eigs, m_null_eigs, strict=True):
        margin = 1e-8 * max(1.0, abs(e[0]), abs(e[-1]))
        en0 = en[0] if len(en) else np.inf  # n = m: no null space, the projection is vacuously definite
        if e[0] > margin:
            out.append("qp")
        elif e[0] < -margin and (rule == "thesis" or en0 < -margin):
            out.append("lu")
        elif e[0] < -margin and en0 > margin:
            out.append("qp_aug")
        else:
            out.append(classify(M, J, rule, symmetric))
    return out


def _projected_pd(M, J, tol=1e-10) -> bool:
    """Is M positive definite on the null space of J? (Finsler: M + rho J^T J > 0 for some rho.)"""
    Ms = 0.5 * (M + M.T)
    scale = max(1.0, float(np.abs(Ms).max()))
    JtJ = J.T @ J
    s2 = max(float(np.linalg.eigvalsh(J @ J.T)[0]), 1e-300)
    shift = tol * scale * np.eye(M.shape[0])
    return any(cholesky_ok(Ms + rho * JtJ - shift) for rho in (scale / s2, 1e2 * scale / s2, 1e4 * scale / s2))


def cholesky_ok(A: np.ndarray) -> bool:
    """Is the symmetric A (its lower triangle) positive definite? LAPACK dpotrf's verdict."""
    return lapack.dpotrf(A, lower=1)[1] == 0


def eigs_many(M: np.ndarray) -> np.ndarray:
    """Eigenvalues of each M[k] (N, n, n), ascending: eigvalsh where M[k] is symmetric, else sorted real parts.

    Symmetric as ``np.allclose(M[k], M[k].T)`` decides (|a - b| <= 1e-8 + 1e-5 |b| everywhere).
    """
    MT = np.swapaxes(M, 1, 2)
    sym = np.all(np.abs(M - MT) <= 1e-8 + 1e-5 * np.abs(MT), axis=(1, 2))
    out = np.empty(M.shape[:2])
    if sym.all():
        return np.linalg.eigvalsh(M)
    if sym.any():
        out[sym] = np.linalg.eigvalsh(M[sym])
    out[~sym] = np.sort(np.linalg.eigvals(M[~sym]).real, axis=1)
    return out


def null_space_bases(J: np.ndarray) -> np.ndarray:
    """Orthonormal bases Z[k] (n, n - m) of the null spaces of each J[k] (N, m, n) of full row rank.

    The last n - m columns of the complete QR factor of J[k]^T (Householder; about half the cost of an SVD).
    """
    Q = np.linalg.qr(np.swapaxes(J, 1, 2), mode="complete")[0]
    return Q[:, :, J.shape[1]:]


def null_space_eigs_many(M: np.ndarray, J: np.ndarray, Z: np.ndarray | None = None) -> np.ndarray:
    """Eigenvalues of Z^T sym(M) Z for each step (Theorem 2), ascending; ``Z`` from :func:`null_space_bases`."""
    Z = null_space_bases(J) if Z is None else Z
    Ms = 0.5 * (M + np.swapaxes(M, 1, 2))
    return np.linalg.eigvalsh(np.swapaxes(Z, 1, 2) @ Ms @ Z)


def normality_many(Z: np.ndarray, grad: np.ndarray) -> np.ndarray:
    """||(1 - J^+ J) grad z|| for each step: the normality residual of Eq. (4.5), with Z a null basis of J."""
    return np.linalg.norm((grad[:, None, :] @ Z)[:, 0, :], axis=1)  # ||Z^T grad|| per step


def hermite_weights(h: float, points: int) -> np.ndarray:
    """Weights w of the Hermite extrapolation to +h through values and slopes at ``points`` past times.

    y(+h) = w @ (y(-(k-1) h), y'(-(k-1) h), ..., y(0), y'(0)) for k = ``points``, exact for polynomials
    of degree 2k - 1: k = 2 gives the cubic (5, 2h, -4, 4h), k = 3 the quintic
    (10, 3h, 9, 18h, -18, 9h).
    """
    w = _unit_hermite_weights(points).copy()
    w[1::2] *= h
    return w


@lru_cache(maxsize=8)
def _unit_hermite_weights(points: int) -> np.ndarray:
    """:func:`hermite_weights` for h = 1 (the slopes' weights scale with h), solved once per ``points``."""
    nodes = np.arange(1 - points, 1, dtype=float)
    powers = np.arange(2 * points)
    value = nodes[:, None] ** powers  # rows: y at each node, in the monomial basis of s = time / h
    slope = powers * nodes[:, None] ** np.maximum(powers - 1, 0)  # rows: h y' at each node
    V = np.stack([value, slope], axis=1).reshape(2 * points, 2 * points)
    w = np.linalg.solve(V.T, np.ones(2 * points))  # the monomials at s = 1
    w.flags.writeable = False
    return w
