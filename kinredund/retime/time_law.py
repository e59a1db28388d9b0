"""Time laws s(t) along a joint path: time-optimal (TOPP-RA), periodic for closed paths, jerk-limited.

A time law maps time t to the path parameter s of a :class:`~kinredund.retime.joint_path.JointPath`;
the joints then move as theta(t) = theta*(s(t)), with

    qdot = q'(s) sd,   qddot = q'(s) sdd + q''(s) sd^2,   qdddot = q'(s) sddd + 3 q''(s) sd sdd + q'''(s) sd^3

(' = d/ds, sd = ds/dt). The tool stays on its path whatever the law, since theta*(s) is the same curve.

- :func:`toppra_law`: time-optimal under joint velocity and acceleration limits (and a tool-speed limit),
  by TOPP-RA (Pham & Pham 2018, the ``toppra`` package) on the record's own samples as grid points,
  with the "interpolation" discretisation: each segment's constant path acceleration u_i holds the
  acceleration limits at both of its ends, so every sample is within them whichever segment one takes.
  The law has sd^2 piecewise linear in s (constant sdd on each segment).
  *Periodic law* for a closed path: TOPP-RA runs on three loops of the closed joint path from rest to
  rest, and the middle loop is kept. Once the profile of the first loop has met a limit (it must: the
  velocity limits bound sd), what follows depends only on the periodic constraints, so the middle loop
  starts and ends at the same speed (checked to 1e-9; five, then nine loops are tried if the ramps are
  longer than a loop). It is the time-optimal periodic law: a faster one would chain into a faster
  middle loop of the three-loop problem.
- *Exact limits*: TOPP-RA's solver and its forward-pass safeguards leave the samples within ~1e-7 of
  the limits, on either side; one uniform time scaling t -> kappa t (kappa >= 1 by that much) then puts
  every sample within them to round-off: qdot scales by 1/kappa, qddot by 1/kappa^2, qdddot by 1/kappa^3.
- :func:`jerk_law`: a time-optimal law has jumps of sdd, so infinite jerk. The smoothing used (justified
  here rather than ruckig, which plans point-to-point motions in joint space and would leave the path):
  sd^2 of the time-optimal law is eroded (a running minimum over 2w + 1 samples) then averaged over
  2w + 1 samples, which never raises it (each average is of minima over windows that contain the
  sample), so the speed limits still hold; a periodic cubic spline through it gives sdd = (sd^2)'/2
  continuous and sddd = sd (sd^2)''/2 bounded. One uniform time scaling then brings the velocity,
  acceleration and jerk at every sample within their limits. The window w is chosen among 1, 2, 3, 4, 6, 8, ...
  samples (steps of sqrt 2) for the shortest loop. Closed paths only (a periodic law, no stop).
- :func:`rest_to_rest_law`: chained loops of a closed path that start and end at rest (TOPP-RA over all
  of them), for a controller that starts from standstill.
"""

from __future__ import annotations

import contextlib
import logging
from dataclasses import dataclass, replace

import numpy as np
from scipy.interpolate import CubicSpline

from kinredund.retime.joint_path import JointPath
from kinredund.retime.limits import Limits, RetimeError

#: relative mismatch of the speeds at the start and end of the kept loop for a periodic law
PERIODIC_TOL = 1e-9
#: an upper bound on sd^2 where the tool does not move along the path (no tool-speed constraint there)
_NO_BOUND = 1e12
#: Gauss-Legendre nodes and weights on [0, 1] for the times of the smooth (jerk-limited) law
_GL_X, _GL_W = np.polynomial.legendre.leggauss(8)
_GL_X, _GL_W = 0.5 * (_GL_X + 1.0), 0.5 * _GL_W


@dataclass(frozen=True)
class TimeLaw:
    """s(t) on the samples of a joint path.

    Attributes:
        s: path parameters of the samples [s], shape (N + 1,).
        t: the times of the samples from 0 [s], shape (N + 1,).
        sd, sdd: ds/dt [1] and d^2s/dt^2 [1/s] at the samples; for a TOPP-RA law sdd is that of the
            segment leaving the sample (at the last sample: the first segment's for a periodic law, the
            last one's for an open path).
        sddd: d^3s/dt^3 [1/s^2] at the samples (jerk-limited law), or None.
        u: the TOPP-RA law's constant sdd on each segment, shape (N,), or None.
        periodic: True for a closed path's loop law (sd[N] = sd[0]).
        kind: ``toppra`` or ``jerk``.
        scale: the uniform time scaling kappa >= 1 applied to put every sample within the limits.
        window: the jerk law's smoothing half-width [samples] (0 for TOPP-RA).
    """

    s: np.ndarray
    t: np.ndarray
    sd: np.ndarray
    sdd: np.ndarray
    sddd: np.ndarray | None
    u: np.ndarray | None
    periodic: bool
    kind: str
    scale: float = 1.0
    window: int = 0

    @property
    def duration(self) -> float:
        """The time from the first sample to the last [s] (one loop for a periodic law)."""
        return float(self.t[-1])

    def scaled(self, kappa: float) -> TimeLaw:
        """The same law run kappa times slower (t -> kappa t)."""
        k2 = kappa * kappa
        return replace(self, t=self.t * kappa, sd=self.sd / kappa, sdd=self.sdd / k2,
                       sddd=None if self.sddd is None else self.sddd / (k2 * kappa),
                       u=None if self.u is None else self.u / k2, scale=self.scale * kappa)

    def _x_spline(self) -> CubicSpline:
        return CubicSpline(self.s, self.sd ** 2, bc_type="periodic")

    def at(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(s, sd, sdd) at times t in [0, duration] [s]: the law between the samples as it is defined.

        TOPP-RA: s = s_i + sd_i tau + u_i tau^2 / 2 on segment i (tau = t - t_i), exactly. Jerk-limited:
        t(s) = t_i + int_{s_i}^{s} ds / sd(s) with sd^2 the cubic spline, inverted by Newton's method.
        """
        t = np.atleast_1d(np.asarray(t, dtype=float))
        k = np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, len(self.s) - 2)
        tau = t - self.t[k]
        if self.u is not None:
            u = self.u[k]
            return self.s[k] + self.sd[k] * tau + 0.5 * u * tau * tau, self.sd[k] + u * tau, u
        X = self._x_spline()
        h = self.s[k + 1] - self.s[k]
        s = self.s[k] + h * np.clip(tau / (self.t[k + 1] - self.t[k]), 0.0, 1.0)
        for _ in range(30):
            step = (tau - _elapsed(X, self.s[k], s)) * np.sqrt(X(s))
            s = np.clip(s + step, self.s[k], self.s[k + 1])
            if np.all(np.abs(step) <= 1e-15 * max(1.0, float(self.s[-1]))):
                break
        x = X(s)
        return s, np.sqrt(x), 0.5 * X(s, 1)


def _elapsed(X: CubicSpline, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """int_a^b ds / sqrt(X(s)) by 8-point Gauss-Legendre (X > 0 and smooth on each segment)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    nodes = a[..., None] + (b - a)[..., None] * _GL_X
    return (b - a) * (X(nodes) ** -0.5 @ _GL_W)


@contextlib.contextmanager
def _quiet_toppra():
    """toppra logs its solver's retries as warnings; keep them off the user's console during a call."""
    logger = logging.getLogger("toppra")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(level)


def _toppra_classes():
    """The toppra path and tool-speed constraint classes (toppra is imported on first use)."""
    import toppra
    from toppra.constraint import LinearConstraint

    class LoopPath(toppra.interpolator.AbstractGeometricPath):
        """``loops`` laps of a joint path (one lap for an open path), in toppra's interface, on the parameter
        sigma = s / period (one unit per lap): d^k q / d sigma^k = period^k q^(k)(s)."""

        def __init__(self, jp: JointPath, loops: int):
            self.jp, self.loops = jp, loops

        def __call__(self, path_positions, order=0):
            c = self.jp.period
            out = self.jp(np.asarray(path_positions) * c, order) * c**order
            return out[0] if np.ndim(path_positions) == 0 else out

        @property
        def dof(self):
            return self.jp.n

        @property
        def path_interval(self):
            return np.array([0.0, float(self.loops)])

    class ToolSpeed(LinearConstraint):
        """|dp/d sigma| sigma-dot <= v_tool: an upper bound on x = sigma-dot^2 at each grid point."""

        def __init__(self, jp: JointPath, speed: float):
            super().__init__()
            self.jp, self.speed, self.dof = jp, speed, jp.n

        def compute_constraint_params(self, path, gridpoints, *args, **kwargs):
            c = self.jp.period
            rate = np.linalg.norm(self.jp.tool_derivative(np.asarray(gridpoints) * c, 1), axis=1) * c
            with np.errstate(divide="ignore"):
                xmax = np.where(rate > 1e-12, (self.speed / rate) ** 2, _NO_BOUND)
            return None, None, None, None, None, None, np.column_stack([np.zeros_like(xmax), xmax])

    return toppra, LoopPath, ToolSpeed


def _toppra_run(jp: JointPath, limits: Limits, loops: int) -> tuple[np.ndarray, np.ndarray]:
    """(grid, sd) of TOPP-RA over ``loops`` laps from rest to rest.

    TOPP-RA runs on sigma = s / period (one unit per lap), not on the record's time s: it works with
    x = sigma-dot^2 and its solver's tolerances are absolute, so a record whose loop lasts a microsecond
    (x ~ 1e12 in s) had no law. The law is the same: s-dot = period sigma-dot.
    """
    toppra, LoopPath, ToolSpeed = _toppra_classes()
    period, N = jp.period, len(jp.s) - 1
    grid = np.concatenate([jp.s[:N] + k * period for k in range(loops)] + [[loops * period]])
    constraints = [toppra.constraint.JointVelocityConstraint(limits.velocity),
                   toppra.constraint.JointAccelerationConstraint(
                       limits.acceleration, discretization_scheme=toppra.constraint.DiscretizationType.Interpolation)]
    if limits.tool_speed is not None:
        constraints.append(ToolSpeed(jp, limits.tool_speed))
    with _quiet_toppra():
        algo = toppra.algorithm.TOPPRA(constraints, LoopPath(jp, loops), gridpoints=grid / period,
                                       solver_wrapper="seidel")
        _, sigma_dot, _ = algo.compute_parameterization(0.0, 0.0)
    if sigma_dot is None or not np.all(np.isfinite(sigma_dot)):
        raise RetimeError("TOPP-RA found no time law along this joint path under these limits (the path is not "
                          "controllable or badly conditioned: check the joint path and the limits)")
    return grid, period * sigma_dot  # s-dot = period sigma-dot


def _with_times(s: np.ndarray, sd: np.ndarray, periodic: bool) -> TimeLaw:
    """The TOPP-RA law of speeds sd at the samples s: u_i = (sd_{i+1}^2 - sd_i^2) / (2 ds), times by segment."""
    x = sd * sd
    ds = np.diff(s)
    u = np.diff(x) / (2.0 * ds)
    pair = sd[1:] + sd[:-1]
    if np.any(pair <= 0.0):
        k = int(np.argmax(pair <= 0.0))
        raise RetimeError(f"the time law stops inside the path (segment {k} at s = {s[k]:.6g} s): the limits leave "
                          "no motion there")
    t = np.concatenate([[0.0], np.cumsum(2.0 * ds / pair)])  # constant sdd on each segment
    sdd = np.append(u, u[0] if periodic else u[-1])
    return TimeLaw(s, t, sd, sdd, None, u, periodic, "toppra")


def sample_ratios(jp: JointPath, law: TimeLaw, limits: Limits) -> dict[str, np.ndarray]:
    """|quantity| / limit at each sample, the largest over the joints: ``velocity``, ``acceleration``,
    and, where they apply, ``jerk`` and ``tool_speed``; each of shape (N + 1,).

    For a TOPP-RA law the acceleration counts both segments that meet at a sample.
    """
    s, sd = law.s, law.sd
    q1, q2 = jp(s, 1), jp(s, 2)
    x = sd * sd
    out = {"velocity": np.max(np.abs(q1 * sd[:, None]) / limits.velocity, axis=1)}
    acc = np.max(np.abs(q1 * law.sdd[:, None] + q2 * x[:, None]) / limits.acceleration, axis=1)
    if law.u is not None:  # the arriving segment's acceleration too
        arriving = np.concatenate([[law.u[-1] if law.periodic else law.u[0]], law.u])
        acc = np.maximum(acc, np.max(np.abs(q1 * arriving[:, None] + q2 * x[:, None]) / limits.acceleration, axis=1))
    out["acceleration"] = acc
    if law.sddd is not None and limits.jerk is not None:
        jerk = q1 * law.sddd[:, None] + 3.0 * q2 * (sd * law.sdd)[:, None] + jp(s, 3) * (x * sd)[:, None]
        out["jerk"] = np.max(np.abs(jerk) / limits.jerk, axis=1)
    if limits.tool_speed is not None:
        out["tool_speed"] = np.linalg.norm(jp.tool_derivative(s, 1), axis=1) * sd / limits.tool_speed
    return out


def _scale_into_limits(jp: JointPath, law: TimeLaw, limits: Limits) -> TimeLaw:
    """The law uniformly slowed (kappa >= 1) so that every sample is within every limit."""
    r = sample_ratios(jp, law, limits)
    kappa = max(1.0, float(r["velocity"].max()), float(np.sqrt(r["acceleration"].max())))
    if "jerk" in r:
        kappa = max(kappa, float(np.cbrt(r["jerk"].max())))
    if "tool_speed" in r:
        kappa = max(kappa, float(r["tool_speed"].max()))
    return law.scaled(kappa * (1.0 + 4.0 * np.finfo(float).eps)) if kappa > 1.0 else law


def toppra_law(jp: JointPath, limits: Limits) -> TimeLaw:
    """The time-optimal law along ``jp`` (periodic for a closed path, rest to rest for an open one).

    Raises:
        RetimeError: TOPP-RA finds no law, or no periodic one within nine loops.
    """
    N = len(jp.s) - 1
    if not jp.closed:
        _, sd = _toppra_run(jp, limits, 1)
        return _scale_into_limits(jp, _with_times(jp.s, sd, False), limits)
    for loops in (3, 5, 9):
        _, sd = _toppra_run(jp, limits, loops)
        mid = loops // 2
        sd = sd[mid * N: (mid + 1) * N + 1].copy()
        if abs(sd[-1] - sd[0]) <= PERIODIC_TOL * max(sd[0], 1e-300) and sd[0] > 0:
            sd[-1] = sd[0]
            return _scale_into_limits(jp, _with_times(jp.s, sd, True), limits)
    raise RetimeError("no periodic time law found: the speed at the start of a loop still differs from the speed at "
                      f"its end after 9 chained loops ({sd[0]:.6g} against {sd[-1]:.6g})")


def rest_to_rest_law(jp: JointPath, limits: Limits, loops: int) -> TimeLaw:
    """The time-optimal law over ``loops`` laps of a closed joint path, from rest to rest.

    One TOPP-RA run over all the laps (their samples as grid points): the first lap speeds up, the last
    slows down, and the laps in between repeat the periodic law of :func:`toppra_law` once the ramps
    fit in a lap. What a controller that starts and ends at rest can run as it is.

    Raises:
        RetimeError: an open path, or TOPP-RA finds no law.
    """
    if not jp.closed:
        raise RetimeError("a rest-to-rest law over loops needs a closed path (an open path is always retimed from rest "
                          "to rest)")
    grid, sd = _toppra_run(jp, limits, loops)
    return _scale_into_limits(jp, _with_times(grid, sd, False), limits)


def _running(x: np.ndarray, w: int, how) -> np.ndarray:
    """A periodic running ``how`` (np.min or np.mean) over 2w + 1 samples of the periodic sequence x."""
    return how(np.stack([np.roll(x, k) for k in range(-w, w + 1)]), axis=0)


def _smooth_law(jp: JointPath, x: np.ndarray, w: int) -> TimeLaw:
    """The law whose sd^2 is the periodic cubic spline through x (N + 1 values, x[N] = x[0])."""
    s = jp.s
    X = CubicSpline(s, x, bc_type="periodic")
    sd = np.sqrt(x)
    t = np.concatenate([[0.0], np.cumsum(_elapsed(X, s[:-1], s[1:]))])
    return TimeLaw(s, t, sd, 0.5 * X(s, 1), 0.5 * sd * X(s, 2), None, True, "jerk", window=w)


def jerk_law(jp: JointPath, limits: Limits, base: TimeLaw | None = None) -> TimeLaw:
    """A jerk-limited periodic law from the time-optimal one (see the module docstring).

    Raises:
        RetimeError: no jerk limit given, or an open path (the smoothing keeps a periodic law).
    """
    if limits.jerk is None:
        raise RetimeError("a jerk-limited law needs jerk limits")
    if not jp.closed:
        raise RetimeError("the jerk-limited law is for closed paths (a periodic law); retime an open path without a "
                          "jerk limit")
    base = base or toppra_law(jp, limits)
    x0 = (base.sd ** 2)[:-1]
    N = len(x0)
    best = None
    widths = sorted({int(round(2 ** (k / 2))) for k in range(40)} & set(range(1, (N // 2 - 1) // 2 + 1)))
    for w in widths:  # 1, 2, 3, 4, 6, 8, 11, 16, ...: steps of sqrt(2)
        xs = _running(_running(x0, w, np.min), w, np.mean)
        law = _scale_into_limits(jp, _smooth_law(jp, np.append(xs, xs[0]), w), limits)
        if best is None or law.duration < best.duration:
            best = law
    if best is None:
        raise RetimeError(f"a jerk-limited law needs at least 6 samples per loop, got {N}")
    return best
