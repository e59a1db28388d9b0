"""Playback and plot costs: standalone HTML replays and the Chapter 4 figures.

Usage::

    python benchmarks/viz.py [--json FILE] [--repeat R]

For synthetic trajectories (joints moving sinusoidally, p from forward kinematics; 10 s, 1001 steps):

- ``replay_html`` for the planar 3R (cylinder visuals) and the Panda (meshes): wall time [s] (it starts
  and stops a meshcat server each time), the file size [MB] and the number of keyframes;
- each plot of ``kinredund.ui.plots`` written as PNG: wall time [s] and file size [kB].

Each time is the median of ``--repeat`` runs (``_bench.time_calls``, no warm-up run). Prints a table;
with ``--json FILE`` writes the figures atomically (``_bench.write_json``).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from _bench import parser, print_table, time_calls, write_json

import kinredund
from kinredund.trajectory import Trajectory
from kinredund.ui import plots
from kinredund.ui.viz import replay_html, resample


def synthetic(name: str, duration: float = 10.0, steps: int = 1001) -> tuple[kinredund.Robot, Trajectory]:
    """Five loops of sinusoidal joints, p from FK, with every field the plots read (as ``track`` records them)."""
    r = kinredund.load_robot(name)
    rng = np.random.default_rng(0)
    t = np.linspace(0.0, duration, steps)
    loops = 5
    w = 2.0 * np.pi * t / (duration / loops)
    q = np.clip(r.home, r.lower + 0.7, r.upper - 0.7) + 0.5 * np.sin(w[:, None] + rng.uniform(0, 6, r.nq))
    p = np.array([r.fk(qi)[:3, 3] for qi in q])
    eigs = np.column_stack([0.4 * np.sin(w) - 0.1, 1.0 + 0.0 * w])
    return r, Trajectory(
        robot=name, task=r.task, t=t, q=q, p=p, p_desired=p, solver=tuple("lu" if e < 0 else "qp" for e in eigs[:, 0]),
        m_eigs=eigs, m_null_eigs=eigs[:, :1], position_error=1e-6 * (1 + np.abs(np.sin(w))),
        loop_drift=1e-15 * np.arange(1, loops + 1), loop_period=duration / loops,
    )


def seconds(fn, repeat: int) -> float:
    """Median wall time [s] of ``repeat`` calls ``fn()``."""
    return time_calls(fn, repeat=repeat, warmup=0)["median_us"] * 1e-6


def main() -> None:
    ap = parser(__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    if args.smoke:
        args.repeat = 1
    rows, figures = [], {}
    steps = 101 if args.smoke else 1001
    with tempfile.TemporaryDirectory() as tmp:
        for name in ("planar3r", "panda"):
            r, traj = synthetic(name, steps=steps)
            out = Path(tmp) / f"{name}.html"
            wall = seconds(lambda r=r, traj=traj, out=out: replay_html(traj, out, r), args.repeat)
            size = out.stat().st_size / 1e6
            frames = len(resample(traj).times)
            rows.append([f"replay_html {name}", wall, f"{size:.2f} MB", frames])
            figures[f"replay_html_{name}"] = {"seconds": wall, "megabytes": size, "keyframes": frames}
        _, traj = synthetic("planar3r", steps=steps)
        jobs = {
            "joint_histories": lambda out: plots.plot_joint_histories(traj, out),
            "errors": lambda out: plots.plot_errors(traj, out),
            "m_eigenvalues": lambda out: plots.plot_m_eigenvalues(traj, out),
            "loop_drift": lambda out: plots.plot_loop_drift([traj, traj], out),
        }
        for key, job in jobs.items():
            out = Path(tmp) / f"{key}.png"
            wall = seconds(lambda job=job, out=out: job(out), args.repeat)
            size = out.stat().st_size / 1e3
            rows.append([f"plot {key}", wall, f"{size:.0f} kB", "-"])
            figures[f"plot_{key}"] = {"seconds": wall, "kilobytes": size}
    print_table(rows, ["job", "median [s]", "file", "keyframes"])
    write_json(args.json, {"viz": figures})


if __name__ == "__main__":
    main()
