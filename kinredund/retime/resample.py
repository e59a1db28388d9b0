"""A retimed motion at uniform times, each sample an exact point of the optimal joint path.

:func:`kinredund.retime.retime` keeps the record's own samples at new, uneven times. A controller that
streams at a fixed rate wants samples at t_k = k dt instead: :func:`resample` takes s(t_k) from the time
law and solves the joint-level problem (4.3), min z(theta) s.t. g(theta) = x(s(t_k)), with
:func:`kinredund.ik.solve_ik` warm-started from the joint spline's value there (within ~1e-13 rad of the
optimum, so Newton's method converges to that same local optimum at once - on the Panda benchmark the
spline's value already meets both optimality conditions to 1e-12 and the solve certifies it as it is;
a start that moves further than :data:`SAME_OPTIMUM` is refused as another optimum). The velocities and accelerations
are the time law's with the spline's derivatives (q'(s) sd, q'(s) sdd + q''(s) sd^2).

This needs the path and the index (a record holds neither), and a time-invariant index (a time-varying
one's optimum depends on the time itself). Between TOPP-RA's grid points (the record's samples) the
limits hold only approximately: on the Panda benchmark circle at 200 samples per loop the uniform
samples reach ~1.0002 times the velocity and acceleration limits.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from kinredund.errors import check_positive
from kinredund.retime.limits import RetimeError
from kinredund.retime.retime import RetimeResult
from kinredund.trajectory import PER_POINT_FIELDS, Trajectory

#: how far [rad] the joint-level solve may move the spline's value before it counts as another optimum
SAME_OPTIMUM = 1e-6


def resample(result: RetimeResult, dt: float, robot, path, index, *, tol: float = 1e-12) -> Trajectory:
    """The retimed motion at times 0, dt, 2 dt, ... (and its end), each sample solved exactly.

    Args:
        result: a :func:`~kinredund.retime.retime` result.
        dt: the sample period [s] > 0 (times are whole nanoseconds: dt is rounded to them).
        robot: the robot the record was tracked with.
        path: the path it tracked (``path(s)`` at the path parameter s: the record's own time).
        index: the (time-invariant) index it tracked.
        tol: the joint-level solve's tolerance (residual and normality residual).

    Returns:
        A :class:`~kinredund.trajectory.Trajectory` with ``qdot`` and ``qddot``, ``position_error``
        against the path, and ``meta["resample"]``: dt, the largest move of a solve from the spline, the
        largest task and normality residuals of the solves (:class:`~kinredund.ik.solve.IKResult`).

    Raises:
        RetimeError: a bad dt, a time-varying index, or a sample whose solve fails or lands on another
            optimum (says when and where, with the samples done so far in ``partial``).
    """
    from kinredund.ik.solve import solve_ik

    dt_ns = int(round(check_positive(dt, "resampling period dt [s]", RetimeError) * 1e9))
    if dt_ns < 1:
        raise RetimeError(f"resampling period dt must be at least 1 ns, got {dt!r} s")
    if index is None or getattr(index, "time_varying", False):
        raise RetimeError("resampling at new times needs the time-invariant index the record was tracked with: a "
                          "time-varying index's optimum depends on the time itself")
    tr = result.trajectory
    end_ns = int(round((tr.t[-1] - tr.t[0]) * 1e9))
    ticks = np.arange(0, end_ns, dt_ns, dtype=np.int64)
    ticks = np.append(ticks, end_ns) if ticks[-1] != end_ns else ticks
    t = ticks / 1e9
    q_spline, qdot, qddot, s = result.interpolate_with_s(t + tr.t[0])  # one evaluation of the time law
    q = np.empty_like(q_spline)
    p, p_desired = np.empty((len(t), 3)), np.empty((len(t), 3))
    moved = residual = normality = 0.0
    for k in range(len(t)):
        sample = path(float(s[k]))
        res = solve_ik(robot, sample, index, q0=q_spline[k], tol=tol)
        move = float(np.abs(res.q - q_spline[k]).max()) if res.converged else np.inf
        if not move <= SAME_OPTIMUM:
            why = res.reason if not res.converged else f"it moved {move:.3g} rad from the joint path (another optimum)"
            err = RetimeError(f"resampling failed at t = {t[k]:.6g} s (path parameter {s[k]:.6g} s): {why}; "
                              f"last good sample at t = {t[k - 1] if k else float('nan'):.6g} s")
            err.t, err.q, err.partial = float(t[k]), res.q.tolist(), (t[:k].copy(), q[:k].copy())
            raise err
        q[k], moved = res.q, max(moved, move)
        residual, normality = max(residual, res.residual), max(normality, res.normality_residual)
        p[k], p_desired[k] = robot.fk(res.q)[:3, 3], sample.p
    meta = dict(tr.meta, resample={"dt": dt_ns / 1e9, "max_move_from_spline": moved, "max_residual": residual,
                                   "max_normality_residual": normality, "tol": tol})
    cleared = dict.fromkeys(name for name in PER_POINT_FIELDS if name != "position_error")
    return replace(tr, t=t + tr.t[0], q=q, qdot=qdot, qddot=qddot, p=p, p_desired=p_desired, solver=(),
                   position_error=np.linalg.norm(p - p_desired, axis=1), loop_drift=None, meta=meta,
                   **cleared).checked()
