"""The polynomial route of Section 3.1.1: Eqs. (3.50)-(3.81), built numerically, and its conditioning.

With the sin/cos objective Eq. (3.31), the normality conditions (3.36)-(3.45) reduce (away from the
spurious factor of Eq. 3.46, grad g = 0) to Eq. (3.47): z_3 g_4 - z_4 g_3 = 0 with z_i = sin(theta_i -
theta_i*). The half-tangent substitution t_i = tan(theta_i / 2), Eq. (3.50), turns

- Eq. (3.47), multiplied by (1 + t3^2)^2 (1 + t4^2)^2, into a quartic in t3 whose coefficients are
  quartics in t4 (Eq. 3.51; :attr:`HalfTangentSystem.quartic`), and
- the constraint Eq. (3.33) into (E + G t4^2) t3^2 + H t4 t3 + (F t4^2 + J) = 0 (Eqs. 3.74-3.79).

The thesis substitutes the root t3 of the quadratic, Eq. (3.80), into the quartic and clears the
square root: P + Q sqrt(Delta) = 0 -> P^2 - Q^2 Delta = 0, a polynomial of degree 24 in t4 (Eq. 3.81,
coefficients in Appendix B). We build it with numpy polynomial arithmetic (:func:`thesis_polynomial`),
and the Sylvester resultant of the two equations in t3 by evaluation at roots of unity and a discrete
Fourier transform (:func:`polynomial_route`). They satisfy P^2 - Q^2 Delta = 256 (E + G t4^2)^4 Res(t4), and
Res(t4) = (1 + t4^2)^2 R12(t4): of the thesis's 24 roots, 8 are the spurious quadruple pair
t4 = +-sqrt(-E/G) introduced by clearing the denominator 2 (E + G t4^2) of Eq. (3.80), 4 are t4 = +-i
(double) from the half-tangent denominators, and only the 12 roots of R12 are stationary points of the
augmented function of Eq. (3.35). :func:`conditioning` measures how badly the degree-24 route behaves.

Notation: bivariate polynomials are arrays c[i, j], the coefficient of t3^i t4^j; univariate ones are
ascending coefficient arrays (numpy.polynomial convention).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.polynomial import polynomial as npoly

from kinredund.closed_form.positioning import ArmGeometry
from kinredund.kinematics.angles import wrap_joints


def _mul2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Product of two bivariate polynomials c[i, j] (t3^i t4^j)."""
    out = np.zeros((a.shape[0] + b.shape[0] - 1, a.shape[1] + b.shape[1] - 1))
    for (i, j), v in np.ndenumerate(a):
        if v != 0.0:
            out[i:i + b.shape[0], j:j + b.shape[1]] += v * b
    return out


def _add2(*terms: np.ndarray) -> np.ndarray:
    out = np.zeros((max(t.shape[0] for t in terms), max(t.shape[1] for t in terms)))
    for t in terms:
        out[:t.shape[0], :t.shape[1]] += t
    return out


def _in_t3(c) -> np.ndarray:
    return np.asarray(c, dtype=float).reshape(-1, 1)


def _in_t4(c) -> np.ndarray:
    return np.asarray(c, dtype=float).reshape(1, -1)


@dataclass(frozen=True)
class HalfTangentSystem:
    """Eqs. (3.51) and (3.74) in t3 = tan(theta3/2), t4 = tan(theta4/2).

    Attributes:
        quartic: (5, 5) coefficients c[i, j] of t3^i t4^j of Eq. (3.47) times (1 + t3^2)^2 (1 + t4^2)^2.
        E, F, G, H, J: the constraint's coefficients, Eqs. (3.75)-(3.79).
    """

    quartic: np.ndarray
    E: float
    F: float
    G: float
    H: float
    J: float

    def quadratic(self, t4):
        """(q0, q1, q2) with q(t3) = q2 t3^2 + q1 t3 + q0, Eq. (3.74), at t4 (scalar or array)."""
        t4 = np.asarray(t4)
        return self.J + self.F * t4 * t4, self.H * t4, self.E + self.G * t4 * t4


def half_tangent_system(geom: ArmGeometry, rho2: float, references) -> HalfTangentSystem:
    """Eqs. (3.47) and (3.33) after the half-tangent substitution of Eq. (3.50).

    Args:
        geom: the arm's dimensions; rho2: xi^2 + eta^2 [m^2]; references: (theta3*, theta4*) [rad].
    """
    A, B, C, D = geom.constraint_coefficients(rho2)  # Eqs. (3.26)-(3.29)
    r3, r4 = (float(v) for v in references)
    one3, one4 = _in_t3([1.0, 0.0, 1.0]), _in_t4([1.0, 0.0, 1.0])  # 1 + t^2
    s3, c3 = _in_t3([0.0, 2.0]), _in_t3([1.0, 0.0, -1.0])  # Eq. (3.50) numerators
    s4, c4 = _in_t4([0.0, 2.0]), _in_t4([1.0, 0.0, -1.0])
    # z_i = sin(theta_i - theta_i*) = s_i c_i* - c_i s_i*, numerators over (1 + t_i^2)
    z3 = _in_t3([-math.sin(r3), 2.0 * math.cos(r3), math.sin(r3)])
    z4 = _in_t4([-math.sin(r4), 2.0 * math.cos(r4), math.sin(r4)])
    s34 = _add2(_mul2(s3, c4), _mul2(c3, s4))  # sin(theta3 + theta4), over (1 + t3^2)(1 + t4^2)
    g3 = _add2(-C * _mul2(s3, one4), -D * s34)  # dg/dtheta3, Eq. (3.37)
    g4 = _add2(-B * _mul2(one3, s4), -D * s34)  # dg/dtheta4
    quartic = _add2(_mul2(_mul2(z3, g4), one4), -_mul2(_mul2(z4, g3), one3))  # Eq. (3.47) -> (3.51)
    return HalfTangentSystem(quartic, A + B - C - D, A - B + C - D, A - B - C + D, -4.0 * D,
                             A + B + C + D)  # Eqs. (3.75)-(3.79)


def thesis_polynomial(system: HalfTangentSystem) -> np.ndarray:
    """The thesis's degree-24 polynomial in t4, Eq. (3.81), ascending coefficients A_0..A_24.

    t3 = (u + s)/w with u = -H t4, w = 2 (E + G t4^2), s^2 = Delta = H^2 t4^2 - 4 (E + G t4^2)(F t4^2 + J)
    (Eq. 3.80); w^4 times the quartic is P + Q s with (u + s)^k = a_k + b_k s, and Eq. (3.81) is
    P^2 - Q^2 Delta = 0 (both signs of s at once).
    """
    E, F, G, H, J = system.E, system.F, system.G, system.H, system.J
    u = np.array([0.0, -H])
    w = np.array([2.0 * E, 0.0, 2.0 * G])
    delta = npoly.polysub([0.0, 0.0, H * H], 4.0 * npoly.polymul([E, 0.0, G], [J, 0.0, F]))
    a, b = [np.array([1.0])], [np.array([0.0])]
    for k in range(4):
        a.append(npoly.polyadd(npoly.polymul(u, a[k]), npoly.polymul(delta, b[k])))
        b.append(npoly.polyadd(a[k], npoly.polymul(u, b[k])))
    P, Q = np.zeros(1), np.zeros(1)
    for k in range(5):
        ck = npoly.polymul(system.quartic[k], npoly.polypow(w, 4 - k))
        P = npoly.polyadd(P, npoly.polymul(ck, a[k]))
        Q = npoly.polyadd(Q, npoly.polymul(ck, b[k]))
    out = np.zeros(25)
    poly = npoly.polysub(npoly.polymul(P, P), npoly.polymul(npoly.polymul(Q, Q), delta))  # Eq. (3.81)
    out[:min(25, poly.shape[0])] = poly[:25]
    return out


def _sylvester_values(system: HalfTangentSystem, t4: np.ndarray) -> np.ndarray:
    """Res_t3(quartic, quadratic) at complex points t4: 6x6 Sylvester determinants."""
    powers = t4[:, None] ** np.arange(system.quartic.shape[1])[None, :]
    p = powers @ system.quartic.T  # (K, 5): coefficients of t3^0..t3^4
    q = np.stack(system.quadratic(t4), axis=1)  # (K, 3)
    S = np.zeros((t4.shape[0], 6, 6), dtype=complex)
    for r in range(2):
        S[:, r, r:r + 5] = p[:, ::-1]
    for r in range(4):
        S[:, 2 + r, r:r + 3] = q[:, ::-1]
    return np.linalg.det(S)


def _interpolate(values: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """Coefficients c_0..c_{K-1} of the polynomial through values at the K shifted roots of unity."""
    K = nodes.shape[0]
    return (values[None, :] * nodes[None, :] ** -np.arange(K)[:, None]).sum(axis=1) / K


def _unit_nodes(K: int) -> np.ndarray:
    return np.exp(2j * math.pi * (np.arange(K) + 0.5) / K)  # avoid t4 = +-i, +-1


def _truncate(c: np.ndarray, degree: int) -> tuple[np.ndarray, float]:
    """(real coefficients 0..degree, max |c_j| for j > degree relative to max |c_j|, j <= degree)."""
    return c[:degree + 1].real.copy(), float(np.abs(c[degree + 1:]).max() / np.abs(c[:degree + 1]).max())


#: interpolation nodes of the resultant (degree 16): twice its coefficients, so the tail measures exactness
NODES = 32


def _resultant_and_reduced(system: HalfTangentSystem) -> tuple[tuple, tuple]:
    """From one evaluation of the Sylvester determinants at :data:`NODES` points: ((Res, tail),
    (R12, tail)), with Res = Res_t3 of Eqs. (3.51) and (3.74), degree 16 in t4, and
    R12 = Res / (1 + t4^2)^2, degree 12, whose roots are the stationary points. Each tail is
    max |c_j| beyond the degree relative to max |c_j| within it: ~1e-16 when the interpolation (and,
    for R12, the division by (1 + t4^2)^2) is exact."""
    z = _unit_nodes(NODES)
    values = _sylvester_values(system, z)
    res = _truncate(_interpolate(values, z), 16)
    red = _truncate(_interpolate(values / (1.0 + z * z) ** 2, z), 12)
    return res, red


def real_roots(coeffs: np.ndarray, tol: float = 1e-7) -> np.ndarray:
    """Real roots (|imag| <= tol (1 + |root|)) of an ascending polynomial, by np.roots (companion matrix)."""
    r = np.roots(np.trim_zeros(np.asarray(coeffs, dtype=float), "b")[::-1])
    return np.sort(r[np.abs(r.imag) <= tol * (1.0 + np.abs(r))].real)


def stationary_points(system: HalfTangentSystem, coeffs: np.ndarray, tol: float = 1e-7) -> list[tuple[float, float]]:
    """(theta3, theta4) [rad] of every real root t4 of ``coeffs``, with t3 from Eq. (3.80).

    Of the two roots t3 of the quadratic, the one where the quartic (3.51) is smaller is kept.
    """
    out = []
    for t4 in real_roots(coeffs, tol):
        q0, q1, q2 = system.quadratic(t4)
        roots = np.roots([q2, q1, q0])
        roots = roots[np.abs(roots.imag) <= 1e-6 * (1.0 + np.abs(roots))].real
        if roots.size == 0:
            continue
        quartic_at = [abs(npoly.polyval2d(t3, t4, system.quartic)) for t3 in roots]
        t3 = roots[int(np.argmin(quartic_at))]
        out.append((2.0 * math.atan(t3), 2.0 * math.atan(t4)))  # Eq. (3.50) inverted
    return out


# ---------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PolynomialRoute:
    """Everything the polynomial route builds for one wrist-centre distance.

    Attributes:
        system: Eqs. (3.51) and (3.74).
        thesis: the degree-24 coefficients A_0..A_24 of Eq. (3.81).
        resultant: the degree-16 Sylvester resultant.
        reduced: the degree-12 factor whose roots are the stationary points.
        factor_residual: max |thesis - 256 (E + G t4^2)^4 resultant| / max |thesis|.
        division_residual: interpolation tail of ``reduced`` (exactness of the (1 + t4^2)^2 factor).
    """

    system: HalfTangentSystem
    thesis: np.ndarray
    resultant: np.ndarray
    reduced: np.ndarray
    factor_residual: float
    division_residual: float


def polynomial_route(geom: ArmGeometry, rho2: float, references) -> PolynomialRoute:
    """Build Eqs. (3.51), (3.74), (3.81), the resultant and its degree-12 factor."""
    system = half_tangent_system(geom, rho2, references)
    p24 = thesis_polynomial(system)
    (res, _), (red, tail) = _resultant_and_reduced(system)  # the determinants once
    spurious = npoly.polypow([system.E, 0.0, system.G], 4)
    factor = npoly.polymul(256.0 * spurious, res)
    factor_residual = float(np.abs(factor[:25] - p24).max() / np.abs(p24).max())
    return PolynomialRoute(system, p24, res, red, factor_residual, tail)


@dataclass(frozen=True)
class Conditioning:
    """Numbers that show how the degree-24 route conditions the minimum (vs the degree-12 factor).

    Attributes:
        coefficient_spread_24, coefficient_spread_12: max |c| / min |c| over nonzero coefficients.
        root_condition_24, root_condition_12: relative condition number of the minimum's root t4,
            sum |c_i| |t|^i / (|t| |p'(t)|): relative root change per relative coefficient change.
        root_error_24, root_error_12: |2 atan(t) - theta4_min| [rad] of the nearest np.roots root.
        perturbed_error_24, perturbed_error_12: the largest such error [rad] after perturbing every
            coefficient by a relative ``eps`` (seeded random signs and sizes).
        spurious_cluster_24: spread of the np.roots cluster around the quadruple spurious root
            (an exact quadruple root splits by ~ eps_machine^(1/4)).
        t4_power_24: tan(3 pi / 8)^24, the thesis's example of a large power (1.5368e9).
        eps: the relative perturbation used.
    """

    coefficient_spread_24: float
    coefficient_spread_12: float
    root_condition_24: float
    root_condition_12: float
    root_error_24: float
    root_error_12: float
    perturbed_error_24: float
    perturbed_error_12: float
    spurious_cluster_24: float
    t4_power_24: float
    eps: float


def _spread(c: np.ndarray) -> float:
    a = np.abs(c[np.abs(c) > 0])
    return float(a.max() / a.min())


def _root_condition(c: np.ndarray, t: float) -> float:
    powers = np.abs(t) ** np.arange(c.shape[0])
    return float((np.abs(c) * powers).sum() / (abs(t) * abs(npoly.polyval(t, npoly.polyder(c)))))


def _nearest_error(c: np.ndarray, theta4: float) -> float:
    r = np.roots(np.trim_zeros(c, "b")[::-1])
    d = 2.0 * np.arctan(r.astype(complex)) - theta4
    return float(np.min(np.hypot(wrap_joints(d.real), d.imag)))


def conditioning(route: PolynomialRoute, theta4_min: float, eps: float = 1e-12, trials: int = 20,
                 seed: int = 0) -> Conditioning:
    """Measure the conditioning of the minimum's root in the degree-24 and degree-12 polynomials.

    Args:
        route: from :func:`polynomial_route`.
        theta4_min: theta4 [rad] of the constrained minimum of Eq. (3.31), found directly
            (:func:`~.redundancy.solve_redundancy` with ``objective="sincos"``).
        eps: relative coefficient perturbation.
        trials: random perturbations per polynomial.
        seed: seed of ``np.random.default_rng``.
    """
    rng = np.random.default_rng(seed)
    t = math.tan(0.5 * theta4_min)
    perturbed = []
    for c in (route.thesis, route.reduced):
        worst = 0.0
        for _ in range(trials):
            worst = max(worst, _nearest_error(c * (1.0 + eps * rng.standard_normal(c.shape)), theta4_min))
        perturbed.append(worst)
    system = route.system
    cluster = 0.0
    if system.G != 0.0:
        centre = np.sqrt(complex(-system.E / system.G))
        r = np.roots(route.thesis[::-1])
        near = np.sort(np.abs(r - centre))[:4]
        cluster = float(near.max())
    return Conditioning(
        _spread(route.thesis), _spread(route.reduced),
        _root_condition(route.thesis, t), _root_condition(route.reduced, t),
        _nearest_error(route.thesis, theta4_min), _nearest_error(route.reduced, theta4_min),
        perturbed[0], perturbed[1], cluster, math.tan(3.0 * math.pi / 8.0) ** 24, eps,
    )
