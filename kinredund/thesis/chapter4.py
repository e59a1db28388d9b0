"""Examples 4.1-4.3 of Chapter 4, with the parameters adopted in ``docs/thesis_readings.md``.

- 4.1: planar 3R (links 2 m); circle of radius 0.8 m about (3, 3) m from (3.8, 3) m, counter-clockwise,
  1 m/s; z = 1/2 sum theta_i^2 (Eq. 4.45).
- 4.2: the same arm; circle of radius 0.8 m about (1.5, 1.5) m from (2.3, 1.5) m; z = 1/2[(theta2 -
  pi/2)^2 + (theta3 - pi)^2] (Eq. 4.46).
- 4.3: CYBOTECH P-15 (Table 4.1); p = (0.16, 0.14 cos beta, 0.36 + 0.14 sin beta) m, beta = t/0.14 s,
  about +x, Frenet orientation Q_d = [e_n, e_t, e_n x e_t] (Eqs. 4.47-4.48); z = 1/2 sum_{i<=4}
  (theta_i - mid_i)^2 (Eq. 4.49).

The starting configuration is the global constrained minimum of z at the path's start, found by the
joint-level IK (multi-start, :func:`kinredund.ik.solve_ik`); the paths and the start problems live in
:mod:`kinredund.thesis.starts`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kinredund.errors import ChoiceError, KinredundError
from kinredund.indices import Index
from kinredund.model.robot import Robot
from kinredund.paths import Path
from kinredund.thesis import starts
from kinredund.thesis.starts import EXAMPLES, example_path
from kinredund.tracking import track
from kinredund.trajectory import Trajectory

#: what the thesis reports for each example (thesis mode, 200 steps per loop)
THESIS_FIGURES = {
    "4.1": {"steps_per_loop": 200, "note": "cyclic joint path (Figs. 4.3-4.4)"},
    "4.2": {"steps_per_loop": 200, "m_indefinite_s": (2.3, 4.0), "note": "LU where M is indefinite (Fig. 4.6)"},
    "4.3": {"steps_per_loop": 200, "position_error": 1e-5, "trace_error": 1e-4, "vect_error": 1e-3},
}


@dataclass(frozen=True)
class Example:
    """An example: its robot, path, index and the starting configuration at the constrained minimum."""

    name: str
    robot: Robot
    path: Path
    index: Index
    q0: np.ndarray
    start_residual: float
    start_normality: float


def load_example(name: str, starts_count: int = 24, seed: int = 0) -> Example:
    """Build an example and solve its starting configuration (global constrained minimum)."""
    from kinredund.ik.solve import solve_ik

    makers = {"4.1": starts.example_4_1_start, "4.2": starts.example_4_2_start, "4.3": starts.example_4_3_start}
    if name not in makers:
        raise ChoiceError("example", name, EXAMPLES)
    robot, target, index = makers[name]()
    # No bounds: with Table 4.1 and the limits as read (NOTES.md), every stationary point of Example
    # 4.3 has theta2 beyond +-45 deg (the global minimum: theta2 = 58.8 deg), so a bound-constrained start
    # would not satisfy the normality conditions (4.5) the scheme follows. See docs/results.md.
    res = solve_ik(robot, target, index, starts=starts_count, seed=seed)
    if not res.converged:
        raise KinredundError(f"the starting configuration of Example {name} was not found: {res.reason}")
    return Example(name, robot, example_path(name), index, res.q, res.residual, res.normality_residual)


def run_example(ex: Example, *, loops: int = 1, steps_per_loop: int = 200, mode: str = "default",
                scheme: str = "augmented", diagnostics: bool = True, progress=None) -> Trajectory:
    """Track the example's path from its optimal start."""
    return track(ex.robot, ex.path, ex.index, ex.q0, scheme=scheme, mode=mode, steps_per_loop=steps_per_loop,
                 loops=loops, diagnostics=diagnostics, progress=progress, limits=False,
                 meta={"example": ex.name, "start_normality": ex.start_normality})


def indefinite_interval(traj: Trajectory) -> tuple[float, float] | None:
    """The first and last time [s] of the first loop where M has a negative eigenvalue, or None."""
    if traj.m_eigs is None:
        return None
    per = traj.loop_period or traj.t[-1]
    mask = (traj.m_eigs.min(axis=1) < 0) & (traj.t <= per + 1e-12)
    if not mask.any():
        return None
    return float(traj.t[mask].min()), float(traj.t[mask].max())


def reproduce(name: str, *, loops: int = 1, steps_per_loop: int = 200, mode: str = "default",
              scheme: str = "augmented", json_path=None, progress=None) -> Trajectory:
    """Run Example 4.1, 4.2 or 4.3 and write its JSON record (:func:`kinredund.ui.reproduce.example` adds
    the plot).

    The JSON holds the trajectory record (``t``, ``q``, ``q0``, ``solver``, ``m_min_eig``,
    ``position_error_max``, ``trace_error_max``, ``vect_error_max``, ``loop_drift``, ...; see
    ``docs/schema.md``) plus ``example`` and ``thesis`` (the thesis's figures). Files are written only
    after the run succeeded, each atomically.
    """
    ex = load_example(name)
    traj = run_example(ex, loops=loops, steps_per_loop=steps_per_loop, mode=mode, scheme=scheme,
                       progress=progress)
    interval = indefinite_interval(traj)
    extra = {"example": name, "thesis": THESIS_FIGURES[name],
             "m_indefinite_interval": None if interval is None else list(interval)}
    if json_path is not None:
        traj.save_json(json_path, extra=extra)
    return traj
