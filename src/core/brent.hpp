// Brent's method on a bracketed root (issue 28): kinredund/tracking/roots.py's brent_root in C++, the switching-time
// search of kinredund/tracking/switches.py run in the core (StepCore.locate, step.cpp). Brent (1973), *Algorithms for
// Minimization Without Derivatives*, ch. 4, in the variant of SciPy's brentq (C. Harris): the same decisions and the
// same arithmetic as roots.py (each product and sum rounded on its own: step.cpp, which includes it, is compiled with
// -ffp-contract=off, CMakeLists.txt), so the same iterates from the same values (tests/test_roots.py: _core.brent_root).
#pragma once

#include <algorithm>
#include <cmath>

namespace kinredund {

// Why brent_root found no root: the ends' values of one sign, or no convergence within maxiter iterations (roots.py's
// RootBracketError and RootConvergenceError; the caller's own search then runs and names them).
constexpr int BRENT_NOT_BRACKETED = 20, BRENT_NOT_CONVERGED = 21;

// The zero of f within [a, b] to within xtol + rtol |x|, from f's values fa, fb at the ends (one of them zero, or of
// opposite signs). `f(x, fx)` evaluates into fx and returns 0, or a status that ends the search with it (a NaN
// value is the caller's to refuse there). Returns 0 with the zero in `root`, or a status.
template <class F>
int brent_root(F&& f, double a, double b, double fa, double fb, double xtol, double rtol, int maxiter, double& root) {
  double x_prev = a, x = b, f_prev = fa, fx = fb;  // x: the latest estimate; x_prev: the one before
  if (f_prev == 0.0) {
    root = x_prev;
    return 0;
  }
  if (fx == 0.0) {
    root = x;
    return 0;
  }
  if (std::copysign(1.0, f_prev) == std::copysign(1.0, fx)) return BRENT_NOT_BRACKETED;
  double x_far = 0.0, f_far = 0.0, step_before = 0.0, step = 0.0;  // x_far: the bracket's other end
  for (int it = 0; it < maxiter; ++it) {
    if (f_prev != 0.0 && fx != 0.0 && std::copysign(1.0, f_prev) != std::copysign(1.0, fx)) {
      x_far = x_prev;  // the root lies between x_prev and x: x_prev becomes the far end
      f_far = f_prev;
      step_before = step = x - x_prev;
    }
    if (std::abs(f_far) < std::abs(fx)) {  // keep the smaller |f| at x
      x_prev = x;
      x = x_far;
      x_far = x_prev;
      f_prev = fx;
      fx = f_far;
      f_far = f_prev;
    }
    const double half_tol = (xtol + rtol * std::abs(x)) / 2;
    const double half_bracket = (x_far - x) / 2;
    if (fx == 0.0 || std::abs(half_bracket) < half_tol) {
      root = x;
      return 0;
    }
    bool bisect = true;
    if (std::abs(step_before) > half_tol && std::abs(fx) < std::abs(f_prev)) {
      double trial;
      if (x_prev == x_far) {  // secant through x_prev and x
        trial = -fx * (x - x_prev) / (fx - f_prev);
      } else {  // inverse quadratic through the three points
        const double slope_prev = (f_prev - fx) / (x_prev - x);
        const double slope_far = (f_far - fx) / (x_far - x);
        trial = -fx * (f_far * slope_far - f_prev * slope_prev) / (slope_far * slope_prev * (f_far - f_prev));
      }
      if (2 * std::abs(trial) < std::min(std::abs(step_before), 3 * std::abs(half_bracket) - half_tol)) {
        step_before = step;  // shrinks fast enough
        step = trial;
        bisect = false;
      }
    }
    if (bisect) step_before = step = half_bracket;
    x_prev = x;
    f_prev = fx;
    x += std::abs(step) > half_tol ? step : (half_bracket > 0 ? half_tol : -half_tol);
    const int st = f(x, fx);
    if (st != 0) return st;
  }
  return BRENT_NOT_CONVERGED;
}

}  // namespace kinredund
