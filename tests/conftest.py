"""Shared fixtures (robots are loaded once per session: the Panda's URDF takes ~50 ms) and the tolerance policy.

Tolerance policy: every bar says where it comes from, next to it, in one of these kinds (after the way
qpsolvers documents its test tolerances). The suite must give the same verdicts under any BLAS kernel
(OPENBLAS_CORETYPE) and CPU, and in any order.

1. Rounding: two computations that agree in exact arithmetic (a quantity computed two ways, two passes
   of Pinocchio, a value that is 0 by construction) differ by rounding only: bar ``ROUND_ULPS * EPS *
   scale`` (:func:`rounding`), scale the size of the numbers involved (1 m, 1 rad, |grad z|, ...). Never
   ``==`` on a computed float: a different kernel sums in another order. ``==`` stays right for values
   that are copied, not computed (a stored record read back, a clipped joint equal to its limit, a
   count, an exact literal the code returns as such).
2. An iterative method: bar from what the method guarantees at its stopping test, not the stopping
   tolerance itself asserted back: e.g. a Newton-corrected tracker that stops at residual r has the
   pose error it reports; an optimiser that resolves z to ``d`` places its point only to
   ``sqrt(2 d / curvature)`` (SLSQP against the closed form in test_closed_form.py).
3. Finite differences: central differences of step h carry O(h^2) truncation and O(EPS / h) rounding;
   bars are a stated multiple of that (kinredund.kinematics.finite_diff).
4. A physical allowance from the thesis or the code (a clearance, PENETRATION_TOL, a joint limit) is
   asserted with its name, not a fresh literal.
5. No wall-clock bar in a test: speed is measured by benchmarks/. A test may compare two clocks of the
   same run (a sum of per-step times within the run's wall time) or give a solver a timeout of 1e-9 s
   (which must time out on any machine), never assert that something is fast.
"""

from __future__ import annotations

import functools
import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

import kinredund

#: machine epsilon of float64
EPS = float(np.finfo(float).eps)
#: units of round-off allowed between two computations that agree in exact arithmetic: a chain of up to
#: ~100 floating-point operations on numbers of the scale given, each rounding by at most EPS/2
ROUND_ULPS = 64


def rounding(scale: float = 1.0) -> float:
    """The rounding bar of kind 1 of the tolerance policy, for numbers of size ``scale``."""
    return ROUND_ULPS * EPS * max(1.0, abs(scale))


#: kinredund.ik.solve.solve_ik's default tol (residual and normality residual) [m, and task units]
IK_TOL = 1e-10


def assert_ik_converged(r: kinredund.Robot, target, res, tol: float = IK_TOL) -> None:
    """An IK result checked by what convergence guarantees, not by its own numbers asserted back (kind 2).

    ``converged`` means the solver's residual and normality residual passed its test at ``tol``. Checked
    independently: a fresh forward kinematics pass puts the end point within ``tol`` of the target (the
    position error is a part of the residual) plus the rounding of that pass; for a pose target the whole
    closure 7-vector (Eq. 2.13, the residual the solver reports) recomputed from that pass is within ``tol``.
    """
    from kinredund.kinematics import closure

    assert res.converged, res.reason
    T = r.fk(res.q)
    Q_d = None
    if isinstance(target, tuple):
        Q_d, p_d = np.asarray(target[0], dtype=float), np.asarray(target[1], dtype=float)
    else:
        target = np.asarray(getattr(target, "vector", target), dtype=float)
        Q_d, p_d = (target[:3, :3], target[:3, 3]) if target.shape == (4, 4) else (None, target)
    err = float(np.linalg.norm(T[: p_d.size, 3] - p_d))
    assert err <= tol + rounding(float(np.abs(p_d).max())), f"position error {err:.3g} m"
    if Q_d is not None and Q_d.shape == (3, 3):
        c = float(np.linalg.norm(closure.closure_vector(T[:3, :3], T[:3, 3], Q_d, p_d)))
        assert c <= tol + rounding(float(np.abs(p_d).max())), f"closure residual {c:.3g}"


#: what the tracker's default mode holds the task and the normality condition to [m, task units]: its
#: corrector stops at ||F|| <= tol max(1, |grad z|) with tol = 1e-12 (kinredund.tracking.predictor_corrector),
#: F holding the task error and the projected gradient, so 1e-9 covers |grad z| up to 1e3 on the paths here
TRACK_HOLD = 1e3 * 1e-12


SHIPPED = ["planar3r", "planar3r_ch6", "puma7", "cybotech_p15"]
ALL_ROBOTS = SHIPPED + ["panda", "xarm7"]


@functools.cache
def robot(name: str, task: str | None = None) -> kinredund.Robot:
    """A cached robot (tests must not rely on its workspace state between calls)."""
    return kinredund.load_robot(name, task=task)


def configurations(r: kinredund.Robot, seed: int, count: int = 3, margin: float = 0.1) -> list[np.ndarray]:
    """Seeded random configurations inside the limits (away from the bounds), for derivative checks."""
    rng = np.random.default_rng(seed)
    lo = np.maximum(r.lower, -np.pi)
    hi = np.minimum(r.upper, np.pi)
    span = hi - lo
    return [rng.uniform(lo + margin * span, hi - margin * span) for _ in range(count)]


BENCHMARKS = Path(__file__).resolve().parent.parent / "benchmarks"


@functools.cache
def load_benchmark(name: str):
    """The module of ``benchmarks/NAME.py`` (the scripts import their sibling ``_bench``)."""
    if str(BENCHMARKS) not in sys.path:
        sys.path.insert(0, str(BENCHMARKS))
    spec = importlib.util.spec_from_file_location(f"kinredund_bench_{name}", BENCHMARKS / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up there
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(params=ALL_ROBOTS)
def any_robot(request) -> kinredund.Robot:
    return robot(request.param)
