"""Chapter 5: operation counts (Eqs. 5.22-5.40) against the thesis's figures and instrumented counts."""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest
from conftest import configurations, robot

from kinredund.errors import TaskError
from kinredund.indices import JointDeviation
from kinredund.kinematics import closure, opcount
from kinredund.kinematics.recursive import _products

GRID = [(n, m) for n in range(1, 13) for m in range(1, min(n, 6) + 1)]


def _stage(n, m, name, **kw):
    return {s.stage: s for s in opcount.stage_counts(n, m, **kw)}[name]


# -- the thesis's figures (n = 7, m = 6, Eq. 5.41) ------------------------------------------------------
def test_thesis_example_first_point_reproduces_1837_and_1371():
    first, _ = opcount.thesis_procedure()
    assert first.floor().multiplications == opcount.THESIS_FIGURES["first"][0] == 1837
    assert first.floor().additions == opcount.THESIS_FIGURES["first"][1] == 1371
    # the printed totals are fractional: the thesis prints their integer parts
    assert first.multiplications == Fraction(1837) + Fraction(1, 3)


def test_thesis_example_later_points_reproduce_1532_and_1094_within_the_thesis_slip():
    first, after = opcount.thesis_procedure()
    assert after.floor().multiplications == opcount.THESIS_FIGURES["after"][0] == 1532
    # The printed least-squares stages (5.25), (5.28), (5.29) add to 278 additions; the thesis's own
    # figures differ by 277 (1371 - 1094): its 1094 is one more than its formulas give.
    ls_add = sum(s.printed_additions for s in opcount.stage_counts(7, 6) if s.least_squares)
    assert ls_add == 278
    assert after.floor().additions == opcount.THESIS_FIGURES["after"][1] - 1
    # multiplications: the thesis's 1837 - 1532 = 305 is exactly the least-squares stages
    ls_mul = sum(s.multiplications for s in opcount.stage_counts(7, 6) if s.least_squares)
    assert ls_mul == 1837 - 1532


def test_velocity_jacobian_stages_add_up_to_eq_5_22():
    for n in range(1, 15):
        k_stages = [s for s in opcount.stage_counts(n, 1)][:5]
        assert sum(s.multiplications for s in k_stages) == 52 * n - 46  # Eq. (5.22)
        assert sum(s.additions for s in k_stages) == 29 * (n - 1)


@pytest.mark.parametrize(("n", "m"), GRID)
def test_printed_totals_are_the_printed_stage_formulas_decoded(n, m):
    """(5.39)-(5.40) = printed stages without the triangularization (5.24)-(5.25), the twist twice, A_K = 26(n-1)."""
    stages = opcount.stage_counts(n, m)
    by = {s.stage: s for s in stages}
    mul = sum(s.printed_multiplications for s in stages) - by["householder_qr"].printed_multiplications + 32
    add = sum(s.printed_additions for s in stages) - by["householder_qr"].printed_additions + 16 - 3 * (n - 1)
    printed = opcount.printed_totals(n, m)
    assert printed.multiplications == mul
    assert printed.additions == add


def test_printed_lu_and_lambda2_formulas_are_not_operation_counts():
    """Why the adopted counts differ from the print: fractional LU counts, negative lambda2 counts."""
    lu = _stage(7, 6, "lu")
    assert lu.printed_multiplications.denominator != 1 and lu.printed_additions.denominator != 1
    assert _stage(16, 6, "lambda2_product").printed_multiplications < 0
    # ... and where the print is a valid count, the adopted one equals it
    for n, m in GRID:
        for s in opcount.stage_counts(n, m):
            if s.stage not in ("lu", "lambda2_product"):
                assert (s.multiplications, s.additions) == (s.printed_multiplications, s.printed_additions)
    for m in range(1, 7):
        lam2 = _stage(7, m, "lambda2_product")  # the print and the adopted count agree at n = 7
        assert (lam2.printed_multiplications, lam2.printed_additions) == (lam2.multiplications, lam2.additions)


# -- adopted counts --------------------------------------------------------------------------------------
@pytest.mark.parametrize(("n", "m"), GRID)
def test_adopted_totals_match_the_closed_forms(n, m):
    for h in (0, n, n * n):
        total = opcount.total_count(n, m, hessian_nonzeros=h)
        assert 6 * total.multiplications == (
            2 * n**3 + (6 * m + 60) * n**2 + (12 * m**2 + 24 * m + 238) * n + 9 * m**2 + 21 * m - 48
        )
        assert 6 * (total.additions - h) == (
            2 * n**3 + (6 * m + 39) * n**2 + (12 * m**2 + 18 * m + 133) * n + 3 * m**2 + 9 * m - 60
        )
        assert total.square_roots == m + 1
        after = opcount.total_count(n, m, hessian_nonzeros=h, first_point=False)
        ls = [s for s in opcount.stage_counts(n, m) if s.least_squares]
        assert total.multiplications - after.multiplications == sum(s.multiplications for s in ls)
        assert total.additions - after.additions == sum(s.additions for s in ls)
    assert opcount.total_count(n, m).additions == opcount.total_count(n, m, hessian_nonzeros=n * n).additions


@pytest.mark.parametrize(("n", "m"), GRID)
def test_adopted_stage_counts_are_nonnegative_integers(n, m):
    for s in opcount.stage_counts(n, m):
        for v in (s.multiplications, s.additions, s.square_roots):
            assert isinstance(v, int) and v >= 0, (s.stage, v)


@pytest.mark.parametrize("m", range(1, 7))
def test_counts_grow_with_n_as_a_cubic(m):
    ns = range(m, m + 30)
    for first_point in (True, False):
        tot = [opcount.total_count(n, m, first_point=first_point) for n in ns]
        mul = np.array([t.multiplications for t in tot])
        add = np.array([t.additions for t in tot])
        assert np.all(np.diff(mul) > 0) and np.all(np.diff(add) > 0)
        # leading term (n + m)^3 / 3 from the LU: the third difference in n is 3! * 2/6 = 2
        assert np.all(np.diff(mul, 3) == 2) and np.all(np.diff(add, 3) == 2)
    for a, b in zip(opcount.stage_counts(m + 5, m), opcount.stage_counts(m + 6, m), strict=True):
        assert b.multiplications >= a.multiplications and b.additions >= a.additions, a.stage


def test_thesis_size_adopted_figures():
    """The adopted counts for the thesis's example: every stage once, standard LU (see the module notes)."""
    first = opcount.total_count(7, 6, hessian_nonzeros=opcount.THESIS_HESSIAN_NONZEROS)
    after = opcount.total_count(7, 6, hessian_nonzeros=opcount.THESIS_HESSIAN_NONZEROS, first_point=False)
    lu = _stage(7, 6, "lu")
    assert lu.multiplications == (13**3 + 3 * 13**2 - 13) // 3
    # differences from the printed procedure: the triangularization counted once (not zero times), the
    # twist once (not twice), the cross-product additions, and the standard LU instead of (5.37)-(5.38)
    qr = _stage(7, 6, "householder_qr")
    printed_first, _ = opcount.thesis_procedure()
    lu_change = lu.multiplications - lu.printed_multiplications
    expected_mul = printed_first.multiplications + qr.multiplications - 32 + lu_change
    assert first.multiplications == expected_mul
    assert first.multiplications - after.multiplications == 305


def test_adopted_figures_quoted_in_the_docs_hold_for_eq_5_41_only():
    """docs/results.md, Chapter 5: 1915/1533 at the first point, 1610/1255 after - with Hess z of Eq. (5.41).

    The additions depend on the nonzeros of Hess z (one per entry of M* = Lambda* + Hess z); the
    multiplications do not. The figures are the closed forms of the module docstring at n = 7, m = 6, h = 4.
    """
    h = opcount.THESIS_HESSIAN_NONZEROS
    # Eq. (5.41): z = 1/2 sum_{i<=4} (theta_i - theta_i*)^2, so Hess z has h nonzero entries
    index = JointDeviation(np.zeros(7), weights=np.array([1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0]))
    assert np.count_nonzero(index.evaluate(np.zeros(7))[2]) == h
    first = opcount.total_count(7, 6, hessian_nonzeros=h)
    after = opcount.total_count(7, 6, hessian_nonzeros=h, first_point=False)
    assert (first.multiplications, first.additions) == (1915, 1533)
    assert (after.multiplications, after.additions) == (1610, 1255)
    full = opcount.total_count(7, 6)  # the default: a full Hess z, 49 nonzeros
    full_after = opcount.total_count(7, 6, first_point=False)
    assert (full.multiplications, full.additions) == (1915, 1533 + 49 - 4)
    assert (full_after.multiplications, full_after.additions) == (1610, 1255 + 49 - 4)


# -- instrumented counts ---------------------------------------------------------------------------------
class Counted:
    """A float that counts the multiplications (and divisions) and additions (and subtractions) made on it."""

    ops = {"mul": 0, "add": 0}

    def __init__(self, v):
        self.v = float(v)

    @classmethod
    def reset(cls):
        cls.ops = {"mul": 0, "add": 0}

    @staticmethod
    def _v(x):
        return x.v if isinstance(x, Counted) else x

    def _op(self, kind, value):
        Counted.ops[kind] += 1
        return Counted(value)

    def __mul__(self, o):
        return self._op("mul", self.v * self._v(o))

    __rmul__ = __mul__

    def __truediv__(self, o):
        return self._op("mul", self.v / self._v(o))

    def __add__(self, o):
        return self._op("add", self.v + self._v(o))

    __radd__ = __add__

    def __sub__(self, o):
        return self._op("add", self.v - self._v(o))

    def __rsub__(self, o):
        return self._op("add", self._v(o) - self.v)

    def __neg__(self):
        return Counted(-self.v)


def _lu_solve(A, b):
    """Doolittle LU without pivoting, then forward and back substitution, on Counted numbers."""
    N = len(b)
    A = [row[:] for row in A]
    for k in range(N):
        for i in range(k + 1, N):
            A[i][k] = A[i][k] / A[k][k]
            for j in range(k + 1, N):
                A[i][j] = A[i][j] - A[i][k] * A[k][j]
    y = []
    for i in range(N):
        acc = b[i]
        for j in range(i):
            acc = acc - A[i][j] * y[j]
        y.append(acc)
    x = [None] * N
    for i in range(N - 1, -1, -1):
        acc = y[i]
        for j in range(i + 1, N):
            acc = acc - A[i][j] * x[j]
        x[i] = acc / A[i][i]
    return x


@pytest.mark.parametrize("N", range(2, 10))
def test_adopted_lu_counts_equal_an_instrumented_elimination(N):
    rng = np.random.default_rng(N)
    A = rng.normal(size=(N, N)) + N * np.eye(N)
    b = rng.normal(size=N)
    Counted.reset()
    x = _lu_solve([[Counted(v) for v in row] for row in A], [Counted(v) for v in b])
    assert np.allclose([xi.v for xi in x], np.linalg.solve(A, b), atol=1e-12)
    lu = _stage(N - 1, 1, "lu")
    assert (Counted.ops["mul"], Counted.ops["add"]) == (lu.multiplications, lu.additions)


def test_rotation_product_recursion_takes_24_multiplications_and_12_additions_per_axis():
    """Eqs. (5.3)-(5.16) in kinredund.kinematics.recursive: the per-axis cost of stage rotation_products."""
    rng = np.random.default_rng(5)
    counts = []
    for n in (3, 4):
        vals = [[Counted(v) for v in rng.uniform(-1, 1, n)] for _ in range(4)]
        Counted.reset()
        _products(*vals)
        counts.append((Counted.ops["mul"], Counted.ops["add"]))
    per_axis = (counts[1][0] - counts[0][0], counts[1][1] - counts[0][1])
    s3, s4 = _stage(3, 1, "rotation_products"), _stage(4, 1, "rotation_products")
    assert per_axis == (s4.multiplications - s3.multiplications, s4.additions - s3.additions) == (24, 12)


def test_lambda_star_structure_behind_the_lambda_counts():
    """(dA/dtheta)^T lambda1 is strictly triangular and (dB/dtheta)^T lambda2 symmetric (Eq. 4.41)."""
    r = robot("cybotech_p15")
    rng = np.random.default_rng(7)
    for q in configurations(r, seed=8):
        dK = r.velocity_jacobian_derivative(q)
        lam1 = np.concatenate([rng.normal(size=3), np.zeros(3)])
        lam2 = np.concatenate([np.zeros(3), rng.normal(size=3)])
        L1, L2 = closure.contract(lam1, dK), closure.contract(lam2, dK)
        assert np.abs(np.triu(L1)).max() < 1e-14  # nonzero only for k < i: n(n-1)/2 dot products
        assert np.abs(L2 - L2.T).max() < 1e-12  # symmetric: n(n+1)/2 dot products


# -- bad input -------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("n", "m", "h", "words"),
    [
        (0, 1, None, "n (number of axes) must be an integer >= 1"),
        (2.5, 1, None, "n (number of axes) must be an integer >= 1"),
        (7.0, 1, None, "n (number of axes) must be an integer >= 1"),
        (True, 1, None, "n (number of axes) must be an integer >= 1"),
        (7, 0, None, "m (task dimension) must be an integer >= 1"),
        (3, 4, None, "min(n, 6)"),
        (9, 7, None, "min(n, 6)"),
        (7, 6, -1, "hessian_nonzeros must be an integer >= 0"),
        (7, 6, 49.0, "hessian_nonzeros must be an integer >= 0"),
        (7, 6, 50, "hessian_nonzeros must be an integer in"),
    ],
)
def test_bad_sizes_raise_task_error(n, m, h, words):
    for fn in (opcount.stage_counts, opcount.total_count, opcount.printed_totals):
        with pytest.raises(TaskError, match=words.replace("(", r"\(").replace(")", r"\)")):
            fn(n, m, hessian_nonzeros=h)
