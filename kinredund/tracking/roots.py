"""A bracketed root by Brent's method, :func:`brent_root`: the switching time of :mod:`~kinredund.tracking.switches`.

Brent (1973), *Algorithms for Minimization Without Derivatives*, ch. 4, in the variant of SciPy's ``brentq``
(C. Harris): inverse quadratic extrapolation or secant interpolation where it shrinks the bracket fast enough,
else bisection. The same decisions and the same arithmetic as ``scipy.optimize.brentq``, so the same iterates
(``tests/test_roots.py``), without its wrapper: ``brentq`` wraps the function in a closure that refers to itself,
a reference cycle that kept each search's function, and through it the states the switch search made, for the
cyclic garbage collector (whose collections hold the GIL: ``track_many``'s threads).
"""

from __future__ import annotations

import math
from collections.abc import Callable

from kinredund.errors import KinredundError, OptionError, SolverError

#: the switching time is solved to this accuracy [s] (:mod:`~kinredund.tracking.switches`): far below the 1e-9 s asked
#: for, plus SWITCH_RTOL |t| (4 machine epsilons, as SciPy's brentq's least rtol)
SWITCH_XTOL, SWITCH_RTOL = 1e-14, 4 * 2.220446049250313e-16


class RootBracketError(KinredundError, ValueError):
    """f has the same sign at both ends of the interval, or is not a number (NaN) where it is evaluated."""


class RootConvergenceError(SolverError):
    """The bracket did not shrink to the tolerance within the allowed iterations."""


def _value(f: Callable[[float], float], x: float) -> float:
    fx = f(x)
    if math.isnan(fx):
        raise RootBracketError(f"the function is not a number (NaN) at x = {x!r}; a root needs finite values")
    return fx


def brent_root(f: Callable[[float], float], a: float, b: float, xtol: float, rtol: float,
               maxiter: int = 100) -> float:
    """The zero of ``f`` within [a, b], where f(a) and f(b) differ in sign (or one is zero), to within
    ``xtol + rtol |x|`` (both > 0). f is called with floats and returns a float; it is evaluated at a, then b, then
    once per iteration. Signs are compared as signs (as brentq's ``signbit``), not by the sign of a product, which
    underflows for tiny values. Raises :class:`RootBracketError` where f(a) and f(b) have the same sign or f is NaN,
    :class:`RootConvergenceError` after ``maxiter`` iterations and :class:`~kinredund.errors.OptionError` for a
    tolerance <= 0 (all :class:`~kinredund.errors.KinredundError`; the first a ValueError, the second a
    RuntimeError)."""
    if not (xtol > 0.0 and rtol > 0.0):
        raise OptionError(f"brent_root: xtol and rtol must be > 0, got xtol={xtol!r}, rtol={rtol!r}")
    x_prev, x = float(a), float(b)
    f_prev, fx = _value(f, x_prev), _value(f, x)
    if f_prev == 0.0:
        return x_prev
    if fx == 0.0:
        return x
    if math.copysign(1.0, f_prev) == math.copysign(1.0, fx):
        raise RootBracketError(f"f has the same sign at both ends: f({x_prev!r}) = {f_prev!r}, f({x!r}) = {fx!r}")
    # x: the latest estimate; x_far: the other end of the bracket; x_prev: the estimate before x
    x_far = f_far = 0.0
    step_before = step = 0.0
    for _ in range(maxiter):
        if f_prev != 0.0 and fx != 0.0 and math.copysign(1.0, f_prev) != math.copysign(1.0, fx):
            # the root lies between x_prev and x: x_prev becomes the far end
            x_far, f_far = x_prev, f_prev
            step_before = step = x - x_prev
        if abs(f_far) < abs(fx):  # keep the smaller |f| at x
            x_prev, x, x_far = x, x_far, x
            f_prev, fx, f_far = fx, f_far, fx
        half_tol = (xtol + rtol * abs(x)) / 2
        half_bracket = (x_far - x) / 2
        if fx == 0.0 or abs(half_bracket) < half_tol:
            return float(x)
        bisect = True
        if abs(step_before) > half_tol and abs(fx) < abs(f_prev):
            if x_prev == x_far:  # secant through x_prev and x
                trial = -fx * (x - x_prev) / (fx - f_prev)
            else:  # inverse quadratic through the three points
                slope_prev = (f_prev - fx) / (x_prev - x)
                slope_far = (f_far - fx) / (x_far - x)
                trial = -fx * (f_far * slope_far - f_prev * slope_prev) / (slope_far * slope_prev * (f_far - f_prev))
            if 2 * abs(trial) < min(abs(step_before), 3 * abs(half_bracket) - half_tol):  # shrinks fast enough
                step_before, step, bisect = step, trial, False
        if bisect:
            step_before = step = half_bracket
        x_prev, f_prev = x, fx
        x += step if abs(step) > half_tol else (half_tol if half_bracket > 0 else -half_tol)
        fx = _value(f, x)
    raise RootConvergenceError(f"no root to within {xtol:g} + {rtol:g}|x| after {maxiter} iterations (last x = "
                               f"{float(x)!r}, f = {float(fx)!r}, bracket [{float(min(x, x_far))!r}, "
                               f"{float(max(x, x_far))!r}])")
