"""Step 6 of the cyclic planner: follow z's own bounded optimum wherever it exists and is strongly stable.

The tracked reference motion of :func:`kinredund.planning.cyclic.plan` follows the spline theta*(t)
through the chosen optima (Eqs. 6.23-6.28), which between its knots is not the optimum of z. Here:

1. **Measure.** At every recorded point of one period an independent bounded solve of z (Eq. 4.3 with
   the limits as bounds, :func:`kinredund.ik.solve_ik` from the planned configuration) gives z's
   optimum on the planned branch; a point is *good* where that solve converges within ``max_jump`` of
   the motion, inside the limits, with a reduced Hessian (Eq. D.33) whose smallest eigenvalue is at least
   :data:`STABLE_FRACTION` of its median over the loop (strongly stable: not near a fold), and where the
   task Jacobian keeps its rank (the solve converges).
2. **Blend.** :class:`BlendedIndex` b(theta, t) = w(t) z(theta, t) + (1 - w(t)) h(theta, t), with h the
   spline's index of Eq. (6.25) and w a C^2 weight (quintic ramps, :class:`Weight`) that is 1 on good
   stretches and 0 across every bad one (a fold, a singular stretch), the ramps inside the intervals
   reported. Where w = 1 the tracker follows z's own bounded optimum exactly.
3. **Track and check.** The blended index is tracked (with the joint limits), verified like the reference
   motion, and measured again: the intervals where w < 1, and any recorded point whose independent solve
   moves by more than :data:`FOLLOW_TOL`, are ``off_optimum``. With a scene, a point held at a clearance is
   measured against z's optimum with the clearances as constraints (:func:`measure`), so a stretch where a
   clearance is active is not off the optimum. Where the blended motion fails (a tracking
   stop or a failed check), the reference motion is kept and its measured intervals are reported.

Units: times [s], joints [rad or m].
"""

from __future__ import annotations

import numpy as np

from kinredund.errors import KinredundError
from kinredund.ik.rows import solve_ik_rows
from kinredund.ik.solve import solve_ik
from kinredund.indices import Index
from kinredund.planning.walk import inside_limits, target_at
from kinredund.tracking import track
from kinredund.tracking.rows import ROW_TOL
from kinredund.tracking.tracker import scene_constraints

#: a point is z's optimum where an independent bounded solve moves it by at most this [rad or m]
FOLLOW_TOL = 1e-7
#: strongly stable: the reduced Hessian's smallest eigenvalue at least this fraction of its loop median
STABLE_FRACTION = 0.05
#: the ramps of the weight last this fraction of a period (at least two recorded steps)
RAMP_FRACTION = 0.02


def _smooth(u: np.ndarray | float) -> tuple[float, float]:
    """The quintic step s(u) = 6u^5 - 15u^4 + 10u^3 on [0, 1] and its derivative (C^2 at both ends)."""
    u = float(min(max(u, 0.0), 1.0))
    return u * u * u * (10.0 - 15.0 * u + 6.0 * u * u), 30.0 * u * u * (1.0 - u) ** 2


class Weight:
    """w(t), periodic: 1 outside the intervals, 0 inside them but for quintic ramps of length ``ramp`` at
    their ends (``intervals`` [(A, B)] in [0, period], A < B, already holding the ramps)."""

    def __init__(self, intervals, period: float, ramp: float):
        self.intervals, self.period, self.ramp = tuple(intervals), float(period), float(ramp)

    def __call__(self, t: float) -> tuple[float, float]:
        """(w, dw/dt) at t [s]."""
        tm = float(t) % self.period
        for a, b in self.intervals:
            for shift in (0.0, self.period, -self.period):
                x = tm + shift
                if a <= x <= b:
                    left, right = x - a, b - x
                    s, ds = _smooth(min(left, right) / self.ramp)
                    return 1.0 - s, -ds / self.ramp * (1.0 if left <= right else -1.0)
        return 1.0, 0.0


class BlendedIndex(Index):
    """b(theta, t) = w(t) z(theta, t) + (1 - w(t)) h(theta, t): z where w = 1, the reference h where w = 0."""

    time_varying = True

    def __init__(self, index: Index, reference: Index, weight: Weight):
        self.index, self.reference, self.weight = index, reference, weight

    def evaluate(self, theta, t=0.0):
        w, _ = self.weight(t)
        if w == 1.0:
            return self.index.evaluate(theta, t)
        vh, gh, Hh = self.reference.evaluate(theta, t)
        if w == 0.0:
            return vh, gh, Hh
        vz, gz, Hz = self.index.evaluate(theta, t)
        return w * vz + (1.0 - w) * vh, w * gz + (1.0 - w) * gh, w * Hz + (1.0 - w) * Hh

    def time_derivative_of_gradient(self, theta, t=0.0):
        w, dw = self.weight(t)
        out = (1.0 - w) * self.reference.time_derivative_of_gradient(theta, t)
        if w > 0.0 and self.index.time_varying:
            out = out + w * self.index.time_derivative_of_gradient(theta, t)
        if dw != 0.0:
            out = out + dw * (self.index.gradient(theta, t) - self.reference.gradient(theta, t))
        return out


def measure(robot, path, index: Index, t, q, max_jump: float, rows=()) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(moved, stable, eig) per recorded point: how far an independent bounded solve of z from it moves
    it [rad or m] (inf where it fails or leaves ``max_jump``), whether it converged inside the limits, and
    the reduced Hessian's smallest eigenvalue there. With ``rows`` (a plan's clearances: general-row
    constraints), where that solve's minimum violates a row the solve is the bounded IK with the rows
    (:func:`~kinredund.ik.rows.solve_ik_rows`): a point held at a clearance is at z's constrained optimum."""
    moved, ok, eig = np.full(len(t), np.inf), np.zeros(len(t), bool), np.zeros(len(t))
    for k, (tk, qk) in enumerate(zip(t, q, strict=True)):
        target = target_at(robot, path, float(tk))
        res = solve_ik(robot, target, index, q0=qk, bounds=True)
        good, qr, e = res.converged and res.reduced_hessian_pd, res.q, float(res.reduced_hessian_min_eig)
        if rows and min(float(c.values(res.q).min()) for c in rows) < -ROW_TOL:
            held = solve_ik_rows(robot, target, index, rows, qk)
            good, qr, e = held.converged, held.q, float(held.reduced_hessian_min_eig)
        d = float(np.abs(qr - qk).max())
        if good and inside_limits(robot, qr) and d <= max_jump:
            moved[k], ok[k], eig[k] = d, True, e
    return moved, ok, eig


def bad_intervals(t, bad, period: float, ramp: float) -> list[tuple[float, float]]:
    """The intervals [s] around the runs of ``bad`` points (from the good point before each run to the good
    point after it), widened by ``ramp`` on both sides and merged; all the period where no point is good."""
    n = len(t)
    if bad.all():
        return [(0.0, period)]
    out = []
    k = 0
    while k < n:
        if bad[k]:
            j = k
            while j < n and bad[j]:
                j += 1
            a = t[k - 1] if k > 0 else t[0] - (t[1] - t[0])
            b = t[j] if j < n else t[-1] + (t[1] - t[0])
            out.append([a - ramp, b + ramp])
            k = j
        else:
            k += 1
    merged: list[list[float]] = []
    for a, b in out:
        if merged and a <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], b)
        else:
            merged.append([a, b])
    if len(merged) > 1 and merged[-1][1] - period >= merged[0][0]:  # runs at both ends: one run through t = 0
        last = merged.pop()
        merged[0] = [last[0] - period, max(merged[0][1], last[1] - period)]
    return [(float(a), float(b)) for a, b in merged]


def _reported(intervals, period: float) -> tuple[tuple[float, float], ...]:
    """Intervals on [0, period]: one that wraps around is split at 0 and the period."""
    out = []
    for a, b in intervals:
        pieces = [(a + period, period), (0.0, b)] if a < 0 else [(a, period), (0.0, b - period)] if b > period else \
            [(a, b)]
        out += [(max(0.0, x), min(period, y)) for x, y in pieces if y > x]
    return tuple(sorted(out))


def _off(robot, path, index, traj, per: int, max_jump: float, stable_min: float | None, rows=()):
    """(bad points of one period, eig) of a motion: the points off z's optimum (or not strongly stable)."""
    moved, ok, eig = measure(robot, path, index, traj.t[:per], traj.q[:per], max_jump, rows)
    if stable_min is None:
        stable_min = STABLE_FRACTION * float(np.median(eig[ok])) if ok.any() else np.inf
    return ~ok | (eig < stable_min), moved, stable_min


def follow_optimum(robot, path, index: Index, reference: Index, traj, per: int, loops: int, max_jump: float,
                   accept, progress=None, meta=None, enabled: bool = True, track_kw: dict | None = None):
    """Steps 1-3 of the module docstring: (trajectory, off_optimum, note) for the tracked reference
    motion ``traj`` (``per`` recorded steps per period, ``loops`` periods); ``accept(trajectory)`` is the
    planner's own verification (limits, task error, closure, no jump), which the blended motion must pass.
    ``enabled`` False: the reference motion is kept and only measured. ``track_kw``: more arguments of the
    tracking (a plan's scene and clearances)."""
    period = float(path.period)
    ramp = max(RAMP_FRACTION * period, 2.0 * period / per)
    t = traj.t[:per]
    kw = track_kw or {}
    rows = scene_constraints(robot, kw["scene"], kw.get("clearance"), kw.get("self_clearance")) \
        if kw.get("scene") is not None else []
    bad, moved, stable_min = _off(robot, path, index, traj, per, max_jump, None, rows)
    if not enabled:
        return traj, _measured(t, moved, bad, period, ramp), ""
    intervals = bad_intervals(t, bad, period, ramp)
    if bad.all():
        return traj, ((0.0, period),), "z's optimum is not strongly stable anywhere near the motion: the motion " \
                                       "follows its reference all along"
    weight = Weight(intervals, period, ramp)
    blended = BlendedIndex(index, reference, weight)
    start = solve_ik(robot, target_at(robot, path, 0.0), blended, q0=traj.q[0], bounds=True)
    try:
        if not start.converged:
            raise KinredundError(f"no start on the blended optimum: {start.reason}")
        out = track(robot, path, blended, start.q, steps_per_loop=per, loops=loops, progress=progress,
                    meta=dict(meta or {}, follows="z where w = 1"), limits=True, **(track_kw or {}))
    except KinredundError as err:
        return traj, _measured(t, moved, bad, period, ramp), f"following z's optimum failed ({err}): the motion " \
                                                             "follows its reference"
    if not accept(out):
        return traj, _measured(t, moved, bad, period, ramp), "following z's optimum did not pass the check: the " \
                                                             "motion follows its reference"
    _, moved2, _ = _off(robot, path, index, out, per, max_jump, stable_min, rows)
    w_one = np.array([weight(tk)[0] == 1.0 for tk in out.t[:per]])
    strays = w_one & (moved2 > FOLLOW_TOL)
    off = _reported(bad_intervals(out.t[:per], ~w_one | strays, period, 0.0), period) if strays.any() or \
        not w_one.all() else ()
    return out, off, ""


def _measured(t, moved, bad, period: float, ramp: float):
    """The reported intervals of a reference motion: where it is not z's optimum to FOLLOW_TOL."""
    off = bad | (moved > FOLLOW_TOL)
    return _reported(bad_intervals(t, off, period, 0.0), period) if off.any() else ()
