"""Operation counts of the resolved-rate scheme with the velocity Jacobian (Chapter 5, Eqs. 5.22-5.40).

Chapter 5 counts the multiplications (divisions included), additions (subtractions included) and
square roots that one step of the velocity-Jacobian scheme of Section 4.3 needs, for n axes and a task
of dimension m (all vectors in base coordinates, so that products with e_1 = (0, 0, 1) are free):

========================  =====================================  ==================================
stage                     multiplications                        additions
========================  =====================================  ==================================
rotations Q_i             4n                                     0
rotation_products P_i     24(n - 1)          Eqs. (5.1)-(5.16)   12(n - 1)
a_vectors a_i             2n                                     0
r_vectors r_i             16(n - 1)          Eqs. (5.17)-(5.21)  14(n - 1)
cross_products e_i x r_i  6(n - 1)                               3(n - 1)
  K, Eqs. (5.22)-(5.23)   52n - 46                               29(n - 1)
householder_qr [LS]       m[1 + m(3n + 3 - m)]/3   Eqs. (5.24)   m[5 + m(6n + 3 - 2m)]/6  (5.25)
                          and m square roots, Eq. (5.26)
householder_apply [LS]    m(2n - m + 3)            Eq. (5.27)    m(2n - m + 1)            (5.28)
back_substitution [LS]    m(m + 1)/2               Eq. (5.29)    m(m + 1)/2               (5.29)
dA_dtheta                 3n(n - 3) + 6            Eq. (5.32)    (n - 2)(3n - 3)/2        (5.33)
dB_dtheta                 3n(n - 1)                Eq. (5.34)    3n(n - 1)/2              (5.35)
lambda1_product           3n(n - 1)/2              Eq. (5.36)    n(n - 1)
lambda2_product           3n(n + 1)/2  (*)                       n(n + 1)  (*)
lambda_star_sum           0                                      n^2
m_star (+ Hess z)         0                                      nonzeros of Hess z (n^2 if full)
twist                     32, and 1 square root                  16
lu (N = n + m)            N(N^2 + 3N - 1)/3  (*)   Eq. (5.37)    N(N - 1)(2N + 5)/6  (*)  (5.38)
========================  =====================================  ==================================

[LS] marks the least-squares solution for lambda* (Eqs. 4.33-4.34): at the first point only, when
lambda* is afterwards integrated along with the joint rates (the thesis's "subsequent points").

**What the OCR shows and what is adopted here.** Each :class:`StageCount` carries both the adopted
count and the printed one (``printed_multiplications``, ``printed_additions``, exact fractions); they
differ only where marked (*):

- Eq. (5.22) reads M_K = 52n - 46; the r_i count reads "18n 16" and is taken as 16(n - 1), the only
  value that makes the text's stage counts add up to (5.22). Eq. (5.23) is unreadable: the adopted A_K
  is the text's 12(n - 1) + 14(n - 1) + 3(n - 1). ((5.40) decodes exactly with A_K = 26(n - 1), i.e.
  without the 3(n - 1) additions of the cross products: that is probably what (5.23) printed.)
- Eq. (5.26), the square roots S_t of the triangularization, and the sums (5.30)-(5.31) are
  unreadable: S_t = m (one per reflection) is adopted; the text says the total S_0 equals S_t.
- The products with lambda2 are printed as 3n(15 - n)/2 and n(15 - n), which are not operation counts
  (negative beyond n = 15); (dB_i/dtheta_k) . lambda2 is symmetric in (i, k) (dB_i/dtheta_k =
  e_min(i,k) x B_max(i,k), Eqs. 4.41 and E.15), so n(n + 1)/2 dot products: 3n(n + 1)/2 and
  n(n + 1), which equal the printed values at n = 7.
- The LU counts read (n + m)[2(n + m)^2 + 9(n + m + 1)]/6 and (n + m)[(n + m)^2 + 3(n + m - 4)]/3,
  which are not integers (1005 1/3 and 849 1/3 at n + m = 13). Adopted: the standard counts of LU
  decomposition plus forward and back substitution, N(N^2 + 3N - 1)/3 and N(N - 1)(2N + 5)/6
  (the tests count them on an instrumented elimination).
- The totals (5.39)-(5.40) read

      M_tot = [2n^3 + (6m + 45)n^2 + (6m^2 + 30m + 375)n + 2m^3 + 6m^2 + 30m + 144]/6
      A_tot = [2n^3 + (6m + 36)n^2 + (6m^2 + 24m + 180)n + 2m^3 + 3m^2 - 15m + 54]/6

  and equal, identically in n and m, the sum of the printed stage formulas *without* the Householder
  triangularization (5.24)-(5.25) and with the twist counted twice (and A_K = 26(n - 1)):
  :func:`printed_totals` returns them and the tests check this decoding.
- The thesis's figures for n = 7, m = 6 and z = 1/2 sum_{i<=4} (theta_i - theta_i*)^2 (Eq. 5.41, whose
  Hessian has 4 nonzero entries) follow from the printed formulas (:func:`thesis_procedure`): the first
  point is (5.39)-(5.40) with 4 additions for M*, 1837 1/3 and 1371 1/3, printed as 1837 and 1371; the
  subsequent points subtract the least-squares stages (305 multiplications, 278 additions), giving
  1532 1/3 and 1093 1/3, printed as 1532 and **1094**: one addition more than the printed stage
  formulas give (the thesis's 1371 - 1094 = 277 implies 277 additions for the least-squares stages, where
  (5.25), (5.28) and (5.29) sum to 278 at n = 7, m = 6).
- Adopted totals (the sums of the adopted stages; :func:`total_count`), with h the number of nonzero
  entries of Hess z:

      M = [2n^3 + (6m + 60)n^2 + (12m^2 + 24m + 238)n + 9m^2 + 21m - 48]/6
      A = [2n^3 + (6m + 39)n^2 + (12m^2 + 18m + 133)n + 3m^2 + 9m - 60]/6 + h
      square roots m + 1

  at the first point (1915 multiplications and 1533 additions for n = 7, m = 6, h = 4), and without the
  least-squares stages afterwards (1610 and 1255).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from fractions import Fraction

from kinredund.errors import TaskError, check_count

#: The thesis's figures for a 7-axis arm with a 6-D task and Eq. (5.41)'s index (end of Chapter 5):
#: (multiplications, additions) at the first point and at every point after.
THESIS_FIGURES = {"first": (1837, 1371), "after": (1532, 1094)}

#: Nonzero entries of the Hessian of Eq. (5.41), z = 1/2 sum_{i<=4} (theta_i - theta_i*)^2.
THESIS_HESSIAN_NONZEROS = 4

Count = int | Fraction


@dataclass(frozen=True)
class StageCount:
    """The operations of one stage of the scheme.

    Attributes:
        stage: a short key (``rotation_products``, ``lu``, ...).
        equations: the thesis equations that count it.
        description: what the stage computes.
        multiplications, additions, square_roots: the adopted counts.
        printed_multiplications, printed_additions: the counts as printed (exact; may be fractions).
        least_squares: True for the stages of the least-squares solution for lambda* (first point only).
    """

    stage: str
    equations: str
    description: str
    multiplications: int
    additions: int
    square_roots: int
    printed_multiplications: Fraction
    printed_additions: Fraction
    least_squares: bool = False


@dataclass(frozen=True)
class OperationCount:
    """Totals: multiplications (with divisions), additions (with subtractions) and square roots."""

    multiplications: Count
    additions: Count
    square_roots: Count

    def floor(self) -> OperationCount:
        """The integer parts (how the thesis prints its fractional totals)."""
        return OperationCount(*(math.floor(getattr(self, f.name)) for f in fields(self)))

    def __sub__(self, other: OperationCount) -> OperationCount:
        return OperationCount(*(getattr(self, f.name) - getattr(other, f.name) for f in fields(self)))


def _check_sizes(n, m, hessian_nonzeros) -> int:
    n = check_count(n, 1, "n (number of axes)", TaskError)
    m = check_count(m, 1, "m (task dimension)", TaskError)
    if m > min(n, 6):
        raise TaskError(f"the task dimension m must satisfy 1 <= m <= min(n, 6) = {min(n, 6)}, got m = {m}")
    if hessian_nonzeros is None:
        return n * n
    h = check_count(hessian_nonzeros, 0, "hessian_nonzeros", TaskError)
    if h > n * n:
        raise TaskError(f"hessian_nonzeros must be an integer in [0, n^2] = [0, {n * n}], got {hessian_nonzeros!r}")
    return h


def stage_counts(n: int, m: int, *, hessian_nonzeros: int | None = None) -> tuple[StageCount, ...]:
    """The operation counts of every stage of one step, Eqs. (5.22)-(5.38).

    Args:
        n: the number of axes.
        m: the task dimension, 1 <= m <= min(n, 6).
        hessian_nonzeros: nonzero entries of Hess z, i.e. the additions that form M* = Lambda* + Hess z;
            default n^2 (a full Hessian, as in Eq. 5.40).

    Returns:
        One :class:`StageCount` per stage, in the order of the computation.

    Raises:
        TaskError: n, m or hessian_nonzeros out of range.
    """
    h = _check_sizes(n, m, hessian_nonzeros)
    N = n + m
    F = Fraction
    rows = [
        # stage, equations, description, (M, A, S), printed (M, A) if different, least squares
        ("rotations", "Section 5 (text before Eq. 5.1)", "the rotation matrices Q_i", (4 * n, 0, 0), None, False),
        ("rotation_products", "Eqs. (5.1)-(5.16)", "P_i = Q_1 ... Q_i by recursion; e_i = P_(i-1) k",
         (24 * (n - 1), 12 * (n - 1), 0), None, False),
        ("a_vectors", "Eq. (2.2)", "[a_i]_i = (a_i cos theta_i, a_i sin theta_i, b_i)", (2 * n, 0, 0), None, False),
        ("r_vectors", "Eqs. (5.17)-(5.21)", "r_i by the Horner-like recursion, in base coordinates",
         (16 * (n - 1), 14 * (n - 1), 0), None, False),
        ("cross_products", "Eqs. (5.22)-(5.23)", "B_i = e_i x r_i (free for i = 1)",
         (6 * (n - 1), 3 * (n - 1), 0), None, False),
        ("householder_qr", "Eqs. (5.24)-(5.26)", "Householder triangularization of K^T (n x m) for lambda*",
         (F(m * (1 + m * (3 * n + 3 - m)), 3), F(m * (5 + m * (6 * n + 3 - 2 * m)), 6), m), None, True),
        ("householder_apply", "Eqs. (5.27)-(5.28)", "the m reflections applied to the n-vector grad z",
         (m * (2 * n - m + 3), m * (2 * n - m + 1), 0), None, True),
        ("back_substitution", "Eq. (5.29)", "lambda* from the triangular m x m system",
         (F(m * (m + 1), 2), F(m * (m + 1), 2), 0), None, True),
        ("dA_dtheta", "Eqs. (5.32)-(5.33)", "dA_i/dtheta_j = e_j x e_i (j < i), Eq. (E.7)",
         (3 * n * (n - 3) + 6, F((n - 2) * (3 * n - 3), 2), 0), None, False),
        ("dB_dtheta", "Eqs. (5.34)-(5.35)", "dB_i/dtheta_j = e_min x B_max, symmetric: Eqs. (4.41), (E.15)",
         (3 * n * (n - 1), F(3 * n * (n - 1), 2), 0), None, False),
        ("lambda1_product", "Eq. (5.36)", "(dA/dtheta)^T lambda1 (strictly triangular)",
         (F(3 * n * (n - 1), 2), n * (n - 1), 0), None, False),
        ("lambda2_product", "Eq. (5.36)", "(dB/dtheta)^T lambda2 (symmetric)",
         (F(3 * n * (n + 1), 2), n * (n + 1), 0), (F(3 * n * (15 - n), 2), n * (15 - n)), False),
        ("lambda_star_sum", "Eq. (4.37)", "Lambda* = sum of the two n x n matrices", (0, n * n, 0), None, False),
        ("m_star", "Eq. (4.36)", "M* = Lambda* + Hess z", (0, h, 0), None, False),
        ("twist", "Angeles et al. (1987)", "the twist t", (32, 16, 1), None, False),
        ("lu", "Eqs. (5.37)-(5.38)", "LU of the (n + m) x (n + m) matrix of Eq. (4.36) and the two substitutions",
         (F(N * (N * N + 3 * N - 1), 3), F(N * (N - 1) * (2 * N + 5), 6), 0),
         (F(N * (2 * N * N + 9 * (N + 1)), 6), F(N * (N * N + 3 * (N - 4)), 3)), False),
    ]
    out = []
    for stage, eqs, desc, (mul, add, sq), printed, ls in rows:
        pm, pa = printed if printed is not None else (mul, add)
        out.append(StageCount(
            stage, eqs, desc, _as_int(mul), _as_int(add), sq, Fraction(pm), Fraction(pa), least_squares=ls,
        ))
    return tuple(out)


def _as_int(value: Count) -> int:
    value = Fraction(value)
    if value.denominator != 1:  # the adopted formulas are integer-valued for every n, m
        raise ArithmeticError(f"operation count {value} is not an integer")
    return int(value)


def total_count(n: int, m: int, *, first_point: bool = True, hessian_nonzeros: int | None = None) -> OperationCount:
    """The adopted total for one step: the sum of :func:`stage_counts`.

    Args:
        n, m, hessian_nonzeros: as for :func:`stage_counts`.
        first_point: include the least-squares stages for lambda* (5.24)-(5.29); at later points
            lambda* is integrated with the joint rates and they are skipped.

    Raises:
        TaskError: n, m or hessian_nonzeros out of range.
    """
    stages = [s for s in stage_counts(n, m, hessian_nonzeros=hessian_nonzeros) if first_point or not s.least_squares]
    return OperationCount(
        sum(s.multiplications for s in stages), sum(s.additions for s in stages), sum(s.square_roots for s in stages)
    )


def printed_totals(n: int, m: int, *, hessian_nonzeros: int | None = None) -> OperationCount:
    """Eqs. (5.39)-(5.40) as printed (exact fractions), and the square roots S_0 = S_t = m.

    Eq. (5.40) assumes a full Hessian (n^2 additions for M*); ``hessian_nonzeros`` replaces that term.

    Raises:
        TaskError: n, m or hessian_nonzeros out of range.
    """
    h = _check_sizes(n, m, hessian_nonzeros)
    mul = Fraction(
        2 * n**3 + (6 * m + 45) * n**2 + (6 * m**2 + 30 * m + 375) * n + 2 * m**3 + 6 * m**2 + 30 * m + 144, 6
    )  # Eq. (5.39)
    add = Fraction(
        2 * n**3 + (6 * m + 36) * n**2 + (6 * m**2 + 24 * m + 180) * n + 2 * m**3 + 3 * m**2 - 15 * m + 54, 6
    )  # Eq. (5.40)
    return OperationCount(mul, add - n * n + h, m)


def thesis_procedure(
    n: int = 7, m: int = 6, *, hessian_nonzeros: int | None = THESIS_HESSIAN_NONZEROS
) -> tuple[OperationCount, OperationCount]:
    """(first point, later points) as the thesis computes its example figures, exact.

    The first point is :func:`printed_totals`; later points subtract the printed least-squares stages
    (5.24)-(5.29). Their integer parts are the thesis's 1837/1371 and 1532/1093 (printed 1094) for the
    defaults n = 7, m = 6 and the 4 Hessian entries of Eq. (5.41).

    Raises:
        TaskError: n, m or hessian_nonzeros out of range.
    """
    first = printed_totals(n, m, hessian_nonzeros=hessian_nonzeros)
    ls = [s for s in stage_counts(n, m) if s.least_squares]
    skipped = OperationCount(
        sum(s.printed_multiplications for s in ls),
        sum(s.printed_additions for s in ls),
        sum(s.square_roots for s in ls),
    )
    return first, first - skipped
