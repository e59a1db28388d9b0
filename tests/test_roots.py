"""kinredund.tracking.roots.brent_root: the iterates of scipy.optimize.brentq, its errors, and no reference cycle."""

from __future__ import annotations

import gc
import math
import os
import weakref

import numpy as np
import pytest
from scipy.optimize import brentq

from kinredund.errors import KinredundError, OptionError
from kinredund.tracking.roots import RootBracketError, RootConvergenceError, brent_root

EPS = np.finfo(float).eps


def _functions(rng, count: int):
    """Smooth and steep functions with a sign change on [-2, 2]: (f, a, b)."""
    out = []
    while len(out) < count:
        c, s = rng.normal(size=3), rng.uniform(-1.5, 1.5)
        kind = len(out) % 4
        if kind == 0:
            f = lambda x, c=c: math.sin(3 * x + c[0]) + 0.3 * c[1]  # noqa: E731
        elif kind == 1:  # a triple root, perturbed: slow for the secant, bisection decides
            f = lambda x, c=c, s=s: (x - s) ** 3 + 1e-3 * c[2] * (x - s)  # noqa: E731
        elif kind == 2:
            f = lambda x, c=c: math.exp(c[0] * x) - 1.5 + c[1] * x * x  # noqa: E731
        else:  # a near-step
            f = lambda x, s=s: math.tanh(40 * (x - s))  # noqa: E731
        if f(-2.0) * f(2.0) < 0:
            out.append((f, -2.0, 2.0))
    return out


class _Recorded:
    """f, and the points it was evaluated at, in order."""

    def __init__(self, f):
        self.f, self.points = f, []

    def __call__(self, x: float) -> float:
        self.points.append(x)
        return self.f(x)


@pytest.mark.parametrize("xtol", [1e-14, 1e-6])
def test_brent_root_makes_brentqs_evaluations(xtol):
    """The same decisions and the same arithmetic as scipy's brentq (the module's claim): the same points evaluated,
    in order, and the same root, on 400 functions; each root within the tolerance of a sign change of f."""
    rng = np.random.default_rng(5)
    for f, a, b in _functions(rng, 400):
        ours, theirs = _Recorded(f), _Recorded(f)
        x_ours = brent_root(ours, a, b, xtol, 4 * EPS)
        x_theirs = brentq(theirs, a, b, xtol=xtol, rtol=4 * EPS, maxiter=100)
        assert ours.points == theirs.points and x_ours == x_theirs
        tol = xtol + 4 * EPS * abs(x_ours)
        assert f(x_ours) == 0.0 or f(x_ours - tol) * f(x_ours + tol) <= 0.0


def test_brent_root_compares_signs_not_products():
    """Values so small that their products underflow to zero: the same answers as brentq (which compares sign
    bits), a root for a sign change, the same-sign error for none."""
    tiny = (lambda x: 1e-170 * (x - 0.5), lambda x: -1e-170 * (x - 0.5) ** 3, lambda x: 1e-300 * math.sin(3 * x + 1.0))
    for f in tiny:
        ours, theirs = _Recorded(f), _Recorded(f)
        x = brent_root(ours, -1.0, 2.0, 1e-14, 4 * EPS)
        assert x == brentq(theirs, -1.0, 2.0, xtol=1e-14, rtol=4 * EPS) and ours.points == theirs.points
        assert type(x) is float
    with pytest.raises(RootBracketError, match="same sign"):
        brent_root(lambda x: 1e-170 * (x * x + 1.0), -1.0, 2.0, 1e-14, 4 * EPS)
    with pytest.raises(ValueError, match="different signs"):  # brentq too
        brentq(lambda x: 1e-170 * (x * x + 1.0), -1.0, 2.0)


def test_brent_root_finds_known_roots():
    """Roots known in closed form, to the requested tolerance, either orientation of the bracket."""
    for f, a, b, root in ((lambda x: x * x - 2.0, 0.0, 2.0, math.sqrt(2.0)),
                          (lambda x: math.cos(x), 3.0, 1.0, math.pi / 2),
                          (lambda x: math.exp(x) - 10.0, 0.0, 5.0, math.log(10.0))):
        x = brent_root(f, a, b, 1e-15, 4 * EPS)
        assert abs(x - root) <= 2 * (1e-15 + 4 * EPS * abs(root))
    assert brent_root(lambda x: x - 1.0, 1.0, 3.0, 1e-12, 4 * EPS) == 1.0  # a zero at an end is that end


def test_brent_root_errors_say_why():
    """The project's own errors (KinredundError), naming what is wrong; still a ValueError and a RuntimeError, as
    brentq's, for callers that catch those."""
    assert issubclass(RootBracketError, (KinredundError, ValueError)) and issubclass(RootConvergenceError, RuntimeError)
    assert issubclass(RootConvergenceError, KinredundError)
    with pytest.raises(RootBracketError, match="same sign at both ends"):
        brent_root(lambda x: x * x + 1.0, -1.0, 1.0, 1e-12, 4 * EPS)
    with pytest.raises(RootBracketError, match="not a number"):
        brent_root(lambda x: math.nan if x > 0.5 else x - 0.7, 0.0, 1.0, 1e-12, 4 * EPS)
    with pytest.raises(RootConvergenceError, match="after 3 iterations"):
        brent_root(lambda x: math.tanh(40 * (x - 0.3)), -2.0, 2.0, 1e-14, 4 * EPS, maxiter=3)
    with pytest.raises(OptionError, match="xtol and rtol must be > 0"):
        brent_root(lambda x: x, -1.0, 1.0, 0.0, 4 * EPS)


def test_brent_root_leaves_no_cyclic_garbage():
    """A search's function and what it refers to are freed by reference counting as the last reference goes (scipy's
    brentq leaves its wrapper closure, and with it the function, for the cyclic collector). Watched by a weak
    reference, not by gc.collect's count: other threads of the suite (Dask's event loop) make garbage of their own."""

    class Payload:
        offset = -0.25

    def searched(solve) -> weakref.ref:
        payload = Payload()

        def f(x):
            return x + payload.offset

        root = solve(f)
        assert abs(root - 0.25) <= 1e-14
        return weakref.ref(payload)

    gc.disable()
    try:
        assert searched(lambda f: brent_root(f, 0.0, 1.0, 1e-14, 4 * EPS))() is None
        kept = searched(lambda f: brentq(f, 0.0, 1.0, xtol=1e-14))  # the baseline: the check can fail
        if kept() is None:
            pytest.skip("this scipy's brentq leaves no reference cycle: no baseline for the check")
        gc.collect()
        assert kept() is None
    finally:
        gc.enable()


def _core_brent():
    from kinredund.tracking.compiled import load_core

    core = load_core()
    if core is None or not hasattr(core, "brent_root"):
        if os.environ.get("CI"):
            pytest.fail("the compiled core is not built (CI builds it)")
        pytest.skip("the compiled core is not built")
    return core.brent_root


@pytest.mark.parametrize("xtol", [1e-14, 1e-6])
def test_the_cores_brent_makes_brent_roots_evaluations(xtol):
    """src/core/brent.hpp (the switching-time search in the core, StepCore.locate) against brent_root: the same points
    evaluated, in order, and the same root, on the 400 functions and the tiny ones whose products underflow. Exact
    equality is the claim: both make the same IEEE operations on the same doubles, each rounded on its own (Python's
    floats; the core built with -ffp-contract=off), so on any CPU the points are the same bits."""
    brent = _core_brent()
    rng = np.random.default_rng(5)
    tiny = [(lambda x: 1e-170 * (x - 0.5), -1.0, 2.0), (lambda x: -1e-170 * (x - 0.5) ** 3, -1.0, 2.0)]
    for f, a, b in _functions(rng, 400) + tiny:
        ours, core = _Recorded(f), _Recorded(f)
        x = brent_root(ours, a, b, xtol, 4 * EPS)
        assert brent(core, a, b, xtol, 4 * EPS, 100) == x and core.points == ours.points


def test_the_cores_brent_says_why_it_found_none():
    """The core's codes where brent_root raises: no sign change (20), no convergence (21), a NaN (23); a zero at an end
    is that end."""
    brent = _core_brent()
    assert brent(lambda x: x * x + 1.0, -1.0, 1.0, 1e-12, 4 * EPS, 100) == 20
    assert brent(lambda x: math.tanh(40 * (x - 0.3)), -2.0, 2.0, 1e-14, 4 * EPS, 3) == 21
    assert brent(lambda x: math.nan if x > 0.5 else x - 0.7, 0.0, 1.0, 1e-12, 4 * EPS, 100) == 23
    assert brent(lambda x: x - 1.0, 1.0, 3.0, 1e-12, 4 * EPS, 100) == 1.0  # (the end itself, returned: f(1) = 0)
