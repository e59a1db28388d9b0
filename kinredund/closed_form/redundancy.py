"""The redundancy of the Chapter 3 arm: theta3 and theta4 by constrained minimisation (Section 3.1.1).

Once theta1 is known, the wrist centre fixes rho^2 = xi^2 + eta^2 and leaves one constraint on
(theta3, theta4), Eq. (3.25): g = A + B cos(theta4) + C cos(theta3) + D cos(theta3 + theta4) = 0, with
A, B, C, D of Eqs. (3.26)-(3.29). Among its solutions (a closed curve on the torus) we take the one that
minimises

- ``angle``: z = 1/2 [(theta3 - theta3*)^2 + (theta4 - theta4*)^2], Eq. (3.30), the thesis's numerical
  choice (Section 3.2), over all of R^2: each angle is taken at its 2 pi representative nearest its
  reference, so |theta_i - theta_i*| <= pi;
- ``sincos``: z = 1/2 [(s3 - s3*)^2 + (c3 - c3*)^2 + (s4 - s4*)^2 + (c4 - c4*)^2], Eq. (3.31), the form
  whose stationary points the polynomial route of :mod:`kinredund.closed_form.polynomial` finds.

Method: the curve is parametrised exactly (theta4 over its feasible interval, theta3 from the linear
equation in cos theta3, sin theta3, two elbow branches), sampled with nodes clustered at its turning
points; every local minimum of z along the samples is refined by Newton's method on the
multiplier-free normality conditions g = 0, z_3 g_4 - z_4 g_3 = 0 (Eqs. 3.36-3.40 with lambda
eliminated); the lowest converged local minimum (positive curvature of the Lagrangian along the
curve) is returned, with its least-squares multiplier lambda of Eq. (3.40).

The default references are the isotropic configuration of links 2-4 (Section 3.2): the 2x3
positioning Jacobian has equal singular values iff sum_k r_k^2 = 0, with r_k the complex vector from
axis k to the wrist centre; :func:`isotropic_configuration` solves it.

Units: angles [rad], lengths [m].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

from kinredund.closed_form.positioning import ArmGeometry
from kinredund.errors import HDTableError, SolverError, check_choice
from kinredund.kinematics.angles import wrap_joints

OBJECTIVES = ("angle", "sincos")


# ---------------------------------------------------------------------------------------------------
# the isotropic references
@dataclass(frozen=True)
class IsotropicConfiguration:
    """An isotropic configuration of links 2-4 (equal singular values of their 2x3 Jacobian).

    Attributes:
        theta3, theta4: the chosen one [rad]: the largest common singular value, then theta3 > 0.
        sigma: its common singular value [m/rad].
        solutions: every isotropic (theta3, theta4, sigma) found, theta3 ascending.
    """

    theta3: float
    theta4: float
    sigma: float
    solutions: tuple[tuple[float, float, float], ...]


def positioning_jacobian(geom: ArmGeometry, theta3: float, theta4: float) -> np.ndarray:
    """The 2x3 Jacobian [m/rad] of the wrist centre in the arm plane w.r.t. (theta2, theta3, theta4),
    at theta2 = 0 (theta2 only rotates it: its singular values do not depend on theta2)."""
    angles = np.cumsum([0.0, theta3, theta4])
    links = np.array([geom.a2, geom.a3, geom.a4]) * np.exp(1j * angles)
    r = np.cumsum(links[::-1])[::-1]  # r_k: from axis k to the wrist centre, k = 2, 3, 4
    return np.vstack([-r.imag, r.real])


def _isotropy_residual(geom: ArmGeometry, t3: float, t4: float) -> tuple[complex, complex, complex]:
    """S = sum_k r_k^2 and its derivatives dS/dtheta3, dS/dtheta4 (theta2 = 0)."""
    r4 = geom.a4 * complex(math.cos(t3 + t4), math.sin(t3 + t4))
    r3 = geom.a3 * complex(math.cos(t3), math.sin(t3)) + r4
    r2 = geom.a2 + r3
    S = r2 * r2 + r3 * r3 + r4 * r4
    return S, 2j * (r2 * r3 + r3 * r3 + r4 * r4), 2j * r4 * (r2 + r3 + r4)


def isotropic_configuration(geom: ArmGeometry, samples: int = 721) -> IsotropicConfiguration:
    """Compute the isotropic configurations of links 2-4 and pick the reference of Section 3.2.

    With u = exp(i theta3), v = exp(i (theta3 + theta4)) and theta2 = 0, sum_k r_k^2 = 0 is the
    quadratic 3 a4^2 v^2 + 2 a4 (a2 + 2 a3 u) v + (a2 + a3 u)^2 + a3^2 u^2 = 0 in v; a root on the unit
    circle is an isotropic configuration. The roots of (|v1|^2 - 1)(|v2|^2 - 1) in theta3 are
    bracketed on a grid, found by Brent's method and polished by Newton's method on sum_k r_k^2 = 0.
    For a2 : a3 : a4 = 2 : sqrt(2) : 1 this gives theta3* = 94.089 deg, theta4* = 97.421 deg (the thesis
    prints 94.08 and 97.41 deg, which a3 = 1.414 m reproduces to all printed digits).

    Raises:
        HDTableError: the link lengths admit no isotropic configuration (give references instead).
    """
    a2, a3, a4 = geom.a2, geom.a3, geom.a4

    def v_roots(t3: float) -> np.ndarray:
        u = complex(math.cos(t3), math.sin(t3))
        return np.roots([3.0 * a4 * a4, 2.0 * a4 * (a2 + 2.0 * a3 * u), (a2 + a3 * u) ** 2 + (a3 * u) ** 2])

    def h(t3: float) -> float:
        v = v_roots(t3)
        return float((abs(v[0]) ** 2 - 1.0) * (abs(v[1]) ** 2 - 1.0))

    grid = np.linspace(-math.pi, math.pi, samples)
    values = np.array([h(t) for t in grid])
    found: list[tuple[float, float, float]] = []
    for k in np.flatnonzero(np.sign(values[:-1]) * np.sign(values[1:]) < 0):
        t3 = brentq(h, grid[k], grid[k + 1], xtol=1e-15)
        v = v_roots(t3)
        t4 = float(np.angle(v[np.argmin(np.abs(np.abs(v) - 1.0))])) - t3
        for _ in range(8):  # Newton polish of sum r_k^2 = 0 (two real equations)
            S, d3, d4 = _isotropy_residual(geom, t3, t4)
            step = np.linalg.solve([[d3.real, d4.real], [d3.imag, d4.imag]], [-S.real, -S.imag])
            t3, t4 = t3 + step[0], t4 + step[1]
        sv = np.linalg.svd(positioning_jacobian(geom, t3, t4), compute_uv=False)
        if sv[1] > 0 and sv[0] - sv[1] <= 1e-9 * sv[0]:
            t3, t4 = float(wrap_joints(t3)), float(wrap_joints(t4))
            if all(abs(t3 - s[0]) + abs(t4 - s[1]) > 1e-9 for s in found):
                found.append((t3, t4, float(sv[0])))
    if not found:
        raise HDTableError(
            f"links a2, a3, a4 = {a2:.6g}, {a3:.6g}, {a4:.6g} m have no isotropic configuration; "
            "give the references (theta3*, theta4*) explicitly"
        )
    found.sort()
    best = max(found, key=lambda s: (round(s[2], 9), s[0]))  # largest sigma, then theta3 > 0
    return IsotropicConfiguration(best[0], best[1], best[2], tuple(found))


# ---------------------------------------------------------------------------------------------------
# the constrained minimisation
@dataclass(frozen=True)
class RedundancySolution:
    """The constrained minimum (theta3, theta4) of the 2-D problem of Eqs. (3.25) and (3.30)/(3.31).

    Attributes:
        theta3, theta4: HD angles [rad] (the representatives nearest the references).
        objective: z at the minimum [rad^2].
        multiplier: lambda of Eq. (3.40), least squares of grad z + lambda grad g = 0 [1/m^2].
        constraint_residual: |g| of Eq. (3.25) [m^2].
        normality_residual: |grad z + lambda grad g|, the error e0 of Eq. (3.39).
        curvature: the Lagrangian's second derivative along the constraint curve (> 0: a minimum).
        stationary_points: how many distinct local minima the refinement found.
        singular: the constraint curve degenerates (links 2-4 stretched or folded: grad g = 0).
    """

    theta3: float
    theta4: float
    objective: float
    multiplier: float
    constraint_residual: float
    normality_residual: float
    curvature: float
    stationary_points: int
    singular: bool = False


def objective_terms(kind: str, theta3: float, theta4: float, ref3: float, ref4: float):
    """(z, z_3, z_4, z_33, z_44) of Eq. (3.30) (``angle``) or Eq. (3.31) (``sincos``); z_34 = 0."""
    e3, e4 = theta3 - ref3, theta4 - ref4
    if kind == "angle":
        return 0.5 * (e3 * e3 + e4 * e4), e3, e4, 1.0, 1.0  # Eq. (3.30)
    # Eq. (3.31): 1/2 |(s, c) - (s*, c*)|^2 = 1 - cos(e) = 2 sin^2(e/2)
    h3, h4 = math.sin(0.5 * e3), math.sin(0.5 * e4)
    return 2.0 * (h3 * h3 + h4 * h4), math.sin(e3), math.sin(e4), math.cos(e3), math.cos(e4)


def constraint_terms(coeffs, theta3: float, theta4: float):
    """(g, g_3, g_4, g_33, g_34, g_44): Eq. (3.25) and its derivatives (the row J of Eq. 3.37)."""
    A, B, C, D = coeffs
    c3, s3, c4, s4 = math.cos(theta3), math.sin(theta3), math.cos(theta4), math.sin(theta4)
    c34, s34 = c3 * c4 - s3 * s4, s3 * c4 + c3 * s4
    g = A + B * c4 + C * c3 + D * c34  # Eq. (3.25)
    return g, -C * s3 - D * s34, -B * s4 - D * s34, -C * c3 - D * c34, -D * c34, -B * c4 - D * c34


def theta4_interval(geom: ArmGeometry, rho2: float) -> tuple[float, float]:
    """The feasible |theta4| interval [rad] on the curve g = 0: |rho - a2| <= |a3 + a4 e^(i theta4)| <= rho + a2."""
    rho = math.sqrt(max(rho2, 0.0))
    c_of = lambda L: (L * L - geom.a3 ** 2 - geom.a4 ** 2) / (2.0 * geom.a3 * geom.a4)  # noqa: E731
    c_hi = max(min(c_of(rho + geom.a2), 1.0), -1.0)
    c_lo = min(max(c_of(abs(rho - geom.a2)), -1.0), c_hi)  # c_lo > c_hi only by rounding at the reach
    return math.acos(c_hi), math.acos(c_lo)


def constraint_curve(geom: ArmGeometry, rho2: float, samples: int = 96) -> list[np.ndarray]:
    """The constraint curve g = 0 as four arcs of (theta3, theta4) samples, each of shape (samples, 2).

    theta4 = +-tau with tau over its feasible interval (links 3-4 of length
    L34 = |a3 + a4 exp(i theta4)| must span |rho - a2| <= L34 <= rho + a2), nodes clustered at both
    ends where the arcs of the two elbow branches join; theta3 solves
    (A + B c4) + (C + D c4) c3 - D s4 s3 = 0, i.e. Eq. (3.25) for fixed theta4.
    """
    A, B, C, D = geom.constraint_coefficients(rho2)
    tau_lo, tau_hi = theta4_interval(geom, rho2)
    nodes = 0.5 * (1.0 - np.cos(np.linspace(0.0, math.pi, samples)))
    tau = tau_lo + max(tau_hi - tau_lo, 0.0) * nodes
    arcs = []
    for sign4 in (1.0, -1.0):
        t4 = sign4 * tau
        c4, s4 = np.cos(t4), np.sin(t4)
        P, Qc, S = A + B * c4, C + D * c4, -D * s4
        phi = np.arctan2(S, Qc)
        half = np.arccos(np.clip(-P / np.maximum(np.hypot(Qc, S), 1e-300), -1.0, 1.0))
        for elbow in (1.0, -1.0):
            arcs.append(np.column_stack([phi + elbow * half, t4]))
    return arcs


def _local_minima(raw: np.ndarray, zs: np.ndarray, samples: int) -> list[int]:
    """Indices of the sampled local minima of z along the curve, lowest first.

    Interior samples are compared with their two neighbours on their arc; an arc's end point with
    the neighbours of every arc that ends at the same point (mod 2 pi), since the arcs join there.
    """
    n_arcs = raw.shape[0] // samples
    z = zs.reshape(n_arcs, samples)
    inner = (z[:, 1:-1] <= z[:, :-2]) & (z[:, 1:-1] <= z[:, 2:])
    out = [i * samples + 1 + k for i, k in zip(*np.nonzero(inner), strict=True)]
    ends = np.array([i * samples + e for i in range(n_arcs) for e in (0, samples - 1)])
    nbrs = ends + np.tile([1, -1], n_arcs)  # each end point's neighbour on its own arc
    same = np.abs(wrap_joints(raw[ends][:, None, :] - raw[ends][None, :, :])).max(axis=2) < 1e-9
    taken = np.zeros(ends.shape[0], dtype=bool)
    for a in range(ends.shape[0]):
        if not taken[a]:
            taken |= same[a]
            if zs[ends[a]] <= zs[nbrs[same[a]]].min():
                out.append(int(ends[a]))
    return sorted(out, key=lambda k: zs[k])


def _newton(kind, coeffs, t3, t4, ref3, ref4, iterations: int = 40):
    """Newton's method on (g, z_3 g_4 - z_4 g_3) = 0; returns (t3, t4, converged)."""
    done = False
    for _ in range(iterations):
        _, z3, z4, z33, z44 = objective_terms(kind, t3, t4, ref3, ref4)
        g, g3, g4, g33, g34, g44 = constraint_terms(coeffs, t3, t4)
        f2 = z3 * g4 - z4 * g3  # Eqs. (3.36)-(3.40) with lambda eliminated
        j11, j12 = g3, g4
        j21 = z33 * g4 + z3 * g34 - z4 * g33
        j22 = z3 * g44 - z44 * g3 - z4 * g34
        det = j11 * j22 - j12 * j21
        if det == 0.0 or not math.isfinite(det):
            return t3, t4, False
        d3 = (-g * j22 + f2 * j12) / det
        d4 = (-f2 * j11 + g * j21) / det
        size = max(abs(d3), abs(d4))
        if size > 0.5:
            d3, d4 = 0.5 * d3 / size, 0.5 * d4 / size
        t3, t4 = t3 + d3, t4 + d4
        if done:  # one step after |step| < 1e-10: quadratic convergence gives full precision
            return t3, t4, True
        done = size < 1e-10
    return t3, t4, False


def _summary(kind, coeffs, t3, t4, ref3, ref4):
    """(z, lambda, |g|, normality residual, curvature) at (t3, t4)."""
    z, z3, z4, z33, z44 = objective_terms(kind, t3, t4, ref3, ref4)
    g, g3, g4, g33, g34, g44 = constraint_terms(coeffs, t3, t4)
    n2 = g3 * g3 + g4 * g4
    lam = -(z3 * g3 + z4 * g4) / n2 if n2 > 0 else 0.0  # Eq. (3.40)
    e0 = math.hypot(z3 + lam * g3, z4 + lam * g4)  # Eq. (3.39)
    # tangent (-g4, g3): curvature of L = z + lambda g along the curve
    curv = (z33 * g4 * g4 + z44 * g3 * g3 + lam * (g33 * g4 * g4 - 2.0 * g34 * g3 * g4 + g44 * g3 * g3))
    return z, lam, abs(g), e0, curv / n2 if n2 > 0 else 0.0


def solve_redundancy(
    geom: ArmGeometry, rho2: float, references, objective: str = "angle", samples: int = 96
) -> RedundancySolution:
    """Minimise Eq. (3.30) or (3.31) subject to Eq. (3.25) for one wrist-centre distance rho.

    Args:
        geom: the arm's dimensions.
        rho2: xi^2 + eta^2 [m^2] (reachable: see :func:`~.positioning.plane_radius2`).
        references: (theta3*, theta4*), HD angles [rad].
        objective: ``angle`` (Eq. 3.30) or ``sincos`` (Eq. 3.31).
        samples: nodes per arc of the constraint curve for the global search.

    Raises:
        ChoiceError: unknown objective.
        SolverError: no sampled minimum converged (not expected on a reachable, regular curve).
    """
    check_choice("objective", objective, OBJECTIVES)
    ref3, ref4 = (float(v) for v in references)
    coeffs = geom.constraint_coefficients(rho2)
    arcs = constraint_curve(geom, rho2, samples)
    pts = np.concatenate(arcs)
    if objective == "angle":  # the representatives nearest the references
        pts = np.column_stack([ref3 + wrap_joints(pts[:, 0] - ref3), ref4 + wrap_joints(pts[:, 1] - ref4)])
        zs = 0.5 * ((pts[:, 0] - ref3) ** 2 + (pts[:, 1] - ref4) ** 2)
    else:
        zs = 2.0 * (np.sin(0.5 * (pts[:, 0] - ref3)) ** 2 + np.sin(0.5 * (pts[:, 1] - ref4)) ** 2)
    starts = _local_minima(np.concatenate(arcs), zs, samples)
    best, minima = None, []
    for k in starts[:12]:
        t3, t4, ok = _newton(objective, coeffs, float(pts[k, 0]), float(pts[k, 1]), ref3, ref4)
        if objective == "angle":
            ok = ok and abs(t3 - ref3) <= math.pi and abs(t4 - ref4) <= math.pi
        else:  # Eq. (3.31) is 2 pi periodic: report the representatives nearest the references
            t3, t4 = ref3 + float(wrap_joints(t3 - ref3)), ref4 + float(wrap_joints(t4 - ref4))
        if not ok:
            continue
        summary = _summary(objective, coeffs, t3, t4, ref3, ref4)
        if summary[4] <= 0.0:  # a maximum or inflexion along the curve
            continue
        if all(abs(t3 - m[0]) + abs(t4 - m[1]) > 1e-8 for m in minima):
            minima.append((t3, t4))
        if best is None or summary[0] < best[2][0]:
            best = (t3, t4, summary)
    scale = geom.reach_max ** 2
    if best is None:
        k = int(np.argmin(zs))
        if math.hypot(*constraint_terms(coeffs, pts[k, 0], pts[k, 1])[1:3]) < 1e-6 * scale:
            # the curve shrinks to points (links 2-4 stretched or folded, grad g -> 0): the best
            # sample lies exactly on it; Newton's method has no regular system to solve there
            z, lam, g, e0, curv = _summary(objective, coeffs, pts[k, 0], pts[k, 1], ref3, ref4)
            return RedundancySolution(float(pts[k, 0]), float(pts[k, 1]), z, lam, g, e0, curv, 0, True)
        raise SolverError(f"no local minimum of the {objective} objective converged on the constraint "
                          f"curve for rho^2 = {rho2:.6g} m^2 (references {ref3:.6g}, {ref4:.6g} rad)")
    t3, t4, (z, lam, g, e0, curv) = best
    singular = math.hypot(*constraint_terms(coeffs, t3, t4)[1:3]) < 1e-9 * scale
    return RedundancySolution(t3, t4, z, lam, g, e0, curv, len(minima), singular)
