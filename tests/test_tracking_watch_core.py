"""The watch's measurement in the compiled core (issue 28, ``src/core/watch.cpp``) against the Python watch's.

``Watch.measure`` with ``core=`` takes its inverse-iteration branch (one dgetrs with R's factors, the Rayleigh
quotient, sigma_min(J) from the last exact value or dgesvd) from the core. On the same matrices and watch state
the numbers must be the Python branch's: dgetrs and dgesvd are the same LAPACK routines (scipy's), so u and
sigma_min(J) agree to rounding of the normalisation; the Rayleigh quotient's sums run in another order than numpy's
BLAS (rounding of numbers of size max |M_ij|, the tolerance policy's kind 1).
"""

from __future__ import annotations

import copy
import zlib

import numpy as np
import pytest
import scipy.linalg
from conftest import rounding
from test_tracking_compiled import Q_BAR, assert_same_record, problem

from kinredund.tracking import Tracker, compiled, track
from kinredund.tracking import watch as watch_module
from kinredund.tracking.watch import J_GATE, Watch, reduce

core = compiled.load_core()
pytestmark = pytest.mark.skipif(core is None or not hasattr(core, "watch_measure"),
                                reason="the compiled core is not built")


class ArrayCore:
    """``StepCore.watch_measure``'s interface on given J, M and factors (``_core.watch_measure``)."""

    def __init__(self, J, M, lu, free):
        self.args = (J, M, np.asfortranarray(lu[0]), np.asarray(lu[1], np.int32), free.astype(np.int32))
        self.calls = 0

    def watch_measure(self, v, ref, sigma_ref, gate):
        self.calls += 1
        return core.watch_measure(*self.args, v, ref, sigma_ref, gate)


def _factors(J, M, fixed):
    """R of Eq. (4.24) of the free joints and its LU factors (LAPACK's, as the Python stepper's)."""
    Jr, Mr = reduce(J, M, fixed)
    m, nf = Jr.shape
    R = np.block([[Mr, Jr.T], [Jr, np.zeros((m, m))]])
    return scipy.linalg.lu_factor(R)


def _matrices(rng, n, m, fixed, kind, velocity):
    """J (m, n) and M (n, n): random, or near a fold (the reduced Hessian's smallest eigenvalue 1e-9) or near a
    kinematic singularity (sigma_min of the free joints' J 1e-7); M non-symmetric in the velocity form."""
    free = np.flatnonzero(~fixed)
    J = rng.standard_normal((m, n))
    if kind == "kinematic":
        U, _, Vt = np.linalg.svd(J[:, free], full_matrices=False)
        s = np.linspace(2.0, 1e-7, m)
        J[:, free] = (U * s) @ Vt
    A = rng.standard_normal((n, n))
    M = A @ A.T / n + np.eye(n)
    if kind == "fold":
        Jr, Mr = reduce(J, M, fixed)
        Z = np.linalg.qr(Jr.T, mode="complete")[0][:, m:]
        w, V = np.linalg.eigh(Z.T @ Mr @ Z)
        z = Z @ V[:, 0]
        M[np.ix_(free, free)] -= (w[0] - 1e-9) * np.outer(z, z)
    if velocity:
        S = rng.standard_normal((n, n))
        M = M + 0.3 * (S - S.T)  # a skew part: u^T M u is u^T sym(M) u
    return J, M


@pytest.mark.parametrize("kind", ["random", "fold", "kinematic", "square"])
@pytest.mark.parametrize("held", [(), (3,), (1, 5)])
@pytest.mark.parametrize("velocity", [False, True])
def test_the_core_measures_what_the_python_watch_measures(kind, held, velocity):
    """A watch history over drifting matrices: each measurement by the core and by Python from the same state
    gives the same sigma_min(J), eigenvalue and vector; small drifts keep the gated sigma_min(J), large ones
    take dgesvd afresh (both branches are met); a square J of the free joints (the Panda's pose task with a joint
    held) has no null space: the exact branch's sigma_min(J) (dgesdd) and eigenvalue +inf."""
    rng = np.random.default_rng(zlib.crc32(repr((kind, held, velocity)).encode()))
    n = 7
    m = {"random": 3, "square": n - len(held)}.get(kind, 6 - len(held))  # square: no null space (eig = inf)
    fixed = np.zeros(n, bool)
    fixed[list(held)] = True
    J, M = _matrices(rng, n, m, fixed, kind, velocity)
    watch = Watch()
    watch.measure(J, M, None, fixed)  # exact: the inverse iteration's first vector
    watch.due(1.0)
    fresh, near = set(), None
    for j in range(8):
        drift = 1e-9 if j % 3 == 0 else 1e-1 if j % 3 == 1 else 1e-4
        J = J + drift * rng.standard_normal(J.shape)
        M = M + drift * rng.standard_normal(M.shape)
        lu = _factors(J, M, fixed)
        twin = Watch()
        twin.load(copy.deepcopy(watch.save()))
        expect = twin.measure(J, M, lu, fixed)
        arrays = ArrayCore(J, M, lu, np.flatnonzero(~fixed))
        got = watch.measure(J, M, None, fixed, core=arrays)
        assert arrays.calls == 1 and watch.core_measured == j + 1
        scale = float(np.abs(M).max())
        np.testing.assert_allclose(got[0], expect[0], rtol=1e-12, atol=0)
        assert got[1] == expect[1] if np.isinf(expect[1]) else abs(got[1] - expect[1]) <= rounding(scale)
        a, b = watch.save(), twin.save()
        np.testing.assert_allclose(a["_v"], b["_v"], rtol=0, atol=rounding(1.0))
        assert a["_fresh"] == b["_fresh"]
        np.testing.assert_allclose(a["sigma_max"], b["sigma_max"], rtol=1e-12)
        np.testing.assert_array_equal(a["_J_ref"], b["_J_ref"])  # a copy of J: copied, not computed
        fresh.add(a["_fresh"])
        near = expect if j == 0 else near  # the first step drifts by 1e-9: still next to the fold or singularity
        watch.due(1.0)
    assert fresh == ({True} if kind == "square" else {True, False})  # square: the exact branch each time
    if kind == "fold":
        assert abs(near[1]) < 1e-6  # the eigenvalue near zero is the one measured
    if kind == "kinematic":
        assert near[0] < 1e-5


def test_the_core_hands_back_what_it_cannot_measure():
    """Where v does not fit the free joints the core returns None (the Python watch then computes exactly); a
    non-finite u too."""
    rng = np.random.default_rng(3)
    J, M = rng.standard_normal((3, 7)), np.eye(7)
    fixed = np.zeros(7, bool)
    lu = _factors(J, M, fixed)
    free = np.arange(7, dtype=np.int32)
    args = (J, M, np.asfortranarray(lu[0]), lu[1].astype(np.int32), free)
    assert core.watch_measure(*args, np.full(7, np.nan), np.zeros((0, 0)), 1.0, J_GATE) is None
    with pytest.raises(ValueError, match="free joint"):
        core.watch_measure(*args, np.ones(6), np.zeros((0, 0)), 1.0, J_GATE)


@pytest.mark.parametrize("scheme", ["augmented", "velocity"])
def test_the_switching_circle_s_measured_steps_are_measured_in_the_core(scheme, monkeypatch):
    """One loop of the Panda circle on which joint 4 meets its limit and leaves it (R's rcond ~2.5e-5 while it is
    held: every held step is measured): each core measurement equals the Python watch's on the step's own J, M and
    the core's factors, from the same state; most measured steps (free and held) are the core's; the record is the
    Python backend's. (The watch is made without the start's rcond, as before it had it, so that the first step, on
    free joints, is measured: on this circle the gate measures no other free step.)"""
    r, path, index, q0 = problem("panda_pose_circle")
    original = Watch.measure
    made = Watch.__init__
    monkeypatch.setattr(Watch, "__init__", lambda self, rcond=None: made(self))
    seen = {"held": 0, "free": 0}

    def checked(self, J, M, lu=None, fixed=None, core=None):
        if core is None:
            return original(self, J, M, lu, fixed)
        twin = Watch()
        twin.load(copy.deepcopy(self.save()))
        expect = original(twin, J, M, core.factors(), fixed)
        before = self.core_measured
        got = original(self, J, M, lu, fixed, core)
        if self.core_measured > before:
            seen["held" if fixed is not None and fixed.any() else "free"] += 1
            assert abs(got[0] - expect[0]) <= 1e-12 * expect[0]
            assert got[1] == expect[1] if np.isinf(expect[1]) else abs(got[1] - expect[1]) <= rounding(np.abs(M).max())
        return got

    options = {"loops": 1, "steps_per_loop": 200, "scheme": scheme}
    b = track(r, path, index, q0, backend="compiled", **options)  # (runs of steps: measured in run_steps)
    a = track(r, path, index, q0, backend="python", **options)
    assert_same_record(a, b)
    held = int(np.any(a.active_bounds != 0, axis=1).sum())
    assert held >= 20
    monkeypatch.setattr(Watch, "measure", checked)  # single steps: each measurement through Watch.measure
    tracker = Tracker(r, path, index, q0, path.period / 200, scheme=scheme, backend="compiled")
    for _ in range(len(a.t) - 1):
        tracker.step()
    assert seen["held"] >= held - 8 * len(a.switch_times) - held // 16  # but steps at switches and exact ones
    assert seen["free"] >= 1
    assert tracker.stepper.control.watch.core_measured >= seen["held"]


# -- the exact measurement (src/core/watch.cpp's watch_exact: Eigen) -------------------------------------------------

EPS = np.finfo(float).eps


@pytest.mark.parametrize("kind", ["random", "fold", "kinematic"])
@pytest.mark.parametrize(("m", "n", "held"), [(6, 7, ()), (6, 7, (3,)), (6, 8, (2,)), (3, 7, ()), (3, 7, (1, 5)),
                                              (2, 3, ())])
def test_the_core_s_exact_measurement_is_numpy_s(kind, m, n, held):
    """``_core.watch_exact`` (one JacobiSVD of J with V, Z^T sym(M) Z, SelfAdjointEigenSolver) against
    :func:`watch.exact` (numpy's LAPACK) on the free joints' J and M: n - m free = 0 (no null space: eig +inf,
    v = 0), 1 and > 1. An SVD is backward stable: the singular values move by at most ~eps ||J||_2, the null space
    by an angle ~eps ||J||_2 / sigma_min (Wedin), which moves the eigenvalue by ~||M||_2 times that and its
    eigenvector besides by ~eps ||M||_2 / (the gap to the next eigenvalue); the vectors are compared up to sign."""
    from kinredund.tracking.watch import exact

    rng = np.random.default_rng(zlib.crc32(f"{kind}{m}{n}{held}".encode()))
    fixed = np.zeros(n, bool)
    fixed[list(held)] = True
    nf = n - len(held)
    J, M = _matrices(rng, n, m, fixed, "random" if kind == "fold" and nf == m else kind, velocity=True)
    Jr, Mr = reduce(J, M, fixed)
    sigma, eig, v, scale = core.watch_exact(Jr, Mr)
    s_a, e_a, v_a = exact(Jr, Mr)
    sJ = np.linalg.svd(Jr, compute_uv=False)
    assert abs(sigma - s_a) <= 32 * EPS * sJ[0]
    assert scale == max(1.0, np.abs(Mr).max())
    assert v.shape == (nf,)
    if nf == m:
        assert eig == e_a == np.inf and not v.any()
        return
    angle = 32 * EPS * sJ[0] / sJ[-1]  # the null space's
    norm_M = np.linalg.norm(Mr, 2)
    assert abs(eig - e_a) <= 4 * norm_M * angle + rounding(norm_M)
    Z = np.linalg.svd(Jr)[2][m:].T
    w = np.linalg.eigvalsh(Z.T @ (0.5 * (Mr + Mr.T)) @ Z)
    gap = w[1] - w[0] if len(w) > 1 else np.inf
    assert min(np.linalg.norm(v - v_a), np.linalg.norm(v + v_a)) <= 4 * angle * (1 + norm_M / gap) + 32 * EPS * (
        norm_M / gap)
    assert abs(np.linalg.norm(v) - 1.0) <= 32 * EPS and np.linalg.norm(Jr @ v) <= 32 * EPS * sJ[0]


def test_the_core_s_exact_measurement_refuses_mismatched_matrices_and_says_nan_where_not_finite():
    with pytest.raises(ValueError, match=r"M must be 7 x 7 \(J: 6 x 7\)"):
        core.watch_exact(np.ones((6, 7)), np.ones((6, 6)))
    rng = np.random.default_rng(7)
    J, M = rng.standard_normal((6, 7)), np.eye(7)
    sigma, eig, v, _ = core.watch_exact(np.where(np.arange(7) == 2, np.nan, J), M)  # (Eigen leaves garbage else)
    assert np.isnan(sigma) and np.isnan(eig) and not v.any()
    sigma, eig, _, scale = core.watch_exact(J, np.where(np.eye(7) > 0, np.inf, 0.0))
    assert sigma == core.watch_exact(J, M)[0] and np.isnan(eig) and scale == np.inf
    watch = Watch()
    assert watch.crossed(np.nan, 1.0) == "kinematic" and watch.crossed(1.0, np.nan) == "fold"  # NaN: crossed


def test_the_compiled_backend_measures_exactly_in_the_core(monkeypatch):
    """Every exact measurement of a compiled run is the core's (numpy's :func:`watch.exact` is not called): the
    start's inside the core's start (``start_run``, not through ``watch_exact``'s binding), then in single steps and
    in runs of steps alike, so they give the same bits; the record is the Python backend's (whose measurements stay
    numpy's) to the backends' bars."""
    from kinredund.tracking import runs
    from kinredund.tracking.recorder import Recorder
    from kinredund.tracking.watch import EXACT_EVERY

    r, path, index, q0 = problem("panda_pose_circle")
    dt = path.period / 200
    inner, numpy_exact, calls = core.watch_exact, watch_module.exact, {"core": 0, "numpy": 0}

    def counted(key, fn):
        return lambda J, M: calls.__setitem__(key, calls[key] + 1) or fn(J, M)

    monkeypatch.setattr(core, "watch_exact", counted("core", inner))
    monkeypatch.setattr(watch_module, "exact", counted("numpy", numpy_exact))
    single, batched = (Tracker(r, path, index, q0, dt, backend="compiled") for _ in range(2))
    assert calls == {"core": 0, "numpy": 0}  # the starts' measurements: inside start_run
    for _ in range(200):
        single.step()
    assert calls["numpy"] == 0 and calls["core"] >= 200 // EXACT_EVERY
    advance, done = runs.stepping(batched, Recorder(batched.stepper)), 0
    while done < 200:
        done += advance(200 - done)
    assert calls["numpy"] == 0
    a, b = single.stepper, batched.stepper
    np.testing.assert_array_equal(b.q, a.q)
    python = Tracker(r, path, index, q0, dt, backend="python")  # numpy's measurements: the same run to the bars
    for _ in range(200):
        python.step()
    np.testing.assert_allclose(python.stepper.q, a.q, rtol=0, atol=Q_BAR)
    wa, wb = a.control.watch.save(), b.control.watch.save()
    for key in wa:
        np.testing.assert_array_equal(wb[key], wa[key], err_msg=key)


# -- the gate's first step (the start's rcond) ------------------------------------------------------------------------
def test_the_first_step_is_gated_against_the_start_s_rcond():
    """The watch's gate compares the first step's rcond with the start's R's (both backends seed the watch with
    their start's): a first step whose R is not nearer singular goes unmeasured (no second point in the history, no
    call of ``Watch.measure``), one whose rcond drops below RCOND_DROP of the start's, or below RCOND_NEAR, is
    measured; a watch made without it measures its first step."""
    watch = Watch(1e-2)
    assert not watch.due_next(0.9e-2) and watch.due_next(0.7e-2) and watch.due_next(0.5 * watch_module.RCOND_NEAR)
    assert Watch().due_next(1.0)
    r, path, index, q0 = problem("panda_pose_circle")
    for backend in ("python", "compiled"):
        tracker = Tracker(r, path, index, q0, path.period / 200, backend=backend)
        s = tracker.stepper
        watch, start_rcond = s.control.watch, s.rcond
        assert watch.gate == (start_rcond, 0) and start_rcond > watch_module.RCOND_NEAR
        tracker.step()
        assert s.rcond > watch_module.RCOND_DROP * start_rcond  # so the gate lets it pass
        assert len(watch.times) == 1 and watch.core_measured == 0, backend  # the start's measurement only
        assert watch.gate == (s.rcond, 1)
