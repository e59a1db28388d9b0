"""Placement-sweep benchmark: throughput serially and on a local Dask cluster, and the speed-up.

Usage::

    python benchmarks/sweep.py [--sides 3,5,8] [--workers 2] [--batch-size B] [--json FILE]

Problem: the Panda benchmark circle (``kinredund.problems.panda_circle``, 0.1 m at 0.1 m/s, 200 steps
per loop, z = 1/2 ||q - q_home||^2) given in its part frame, swept over grids of side n: n x n part
positions within +-0.3 m of the benchmark's circle centre in x and y, at yaw 0 and 0.5 rad (2 n^2
placements). Each placement: the bounded IK start (8 seeded starts), one loop of tracking, the record.

Per grid: the wall time [s] and throughput [placements/s] serially in this process (``workers=0``) and
on a local cluster of ``--workers`` single-threaded worker processes (OPENBLAS/OMP/MKL threads 1, as
in this process), the speed-up (serial time / cluster time; target >= 1.7 on 2 cores), and the cost
per placement. The cluster is started once, outside the timings (its start-up time is printed on its
own), and warmed up with a small sweep so each worker has imported kinredund; the timed sweeps include
scattering the job and every scheduling cost. A straight-line fit time = a + b N over the grids says how
the cost grows with the grid size N. The serial and cluster records are compared (feasibility and
cause must agree). Two figures say how far the machine let it go: the parallel capacity (how many
cores ``--workers`` busy processes get right now, from a busy loop: the ceiling of any speed-up) and
each timed cluster sweep's worker busy fraction (compute time per worker over the wall time, from
Dask's task stream: 1 means no worker ever waited for work), and the CPU share this process (client
and in-process scheduler) took meanwhile, which the workers do not get on a 2-core machine.

Per grid also the sweep's tracking runs alone (from the sweep's own starts): one by one as the sweep tracks
them, and in one ``kinredund.tracking.track_many`` call on ``max(2, --workers)`` threads, with the records
compared (joints bit for bit), their share of the serial sweep's time, and the serial sweep's placements per
second with its tracking done by ``track_many`` (:func:`tracking_figures`).

The figures are wall times: on a shared machine they move with the load (run it on a quiet one). The
default run (sides 3, 5, 8: 18, 50 and 128 placements) takes about 30 s on an unloaded 2-core machine.
"""

from __future__ import annotations

import os

if __name__ == "__main__":  # before numpy loads OpenBLAS: one thread here too, as on the workers
    for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[_name] = "1"

import logging  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
from _bench import parser, print_table, write_json  # noqa: E402

from kinredund.sweep import grid, sweep  # noqa: E402
from kinredund.sweep.cluster import WORKER_ENV  # noqa: E402
from kinredund.sweep.placement import panda_part_circle  # noqa: E402


def placements(side: int) -> np.ndarray:
    """The benchmark grid of side n: 2 n^2 part poses about the benchmark circle's centre."""
    c = panda_part_circle()[3][:3, 3]
    span = np.linspace(-0.3, 0.3, side)
    return grid(x=c[0] + span, y=span, z=c[2], yaw=[0.0, 0.5])


def start_cluster(workers: int):
    """A local cluster as :func:`kinredund.sweep.sweep` makes it, and its client; (cluster, client, start-up s)."""
    from distributed import Client, LocalCluster

    t0 = time.perf_counter()
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                           dashboard_address="127.0.0.1:0", silence_logs=logging.ERROR, env=WORKER_ENV)
    client = Client(cluster)
    client.wait_for_workers(workers)
    return cluster, client, time.perf_counter() - t0


#: a busy loop of a given CPU time; prints the wall time it took [s]
_SPIN = ("import time\nt, c = time.perf_counter(), time.process_time()\nwhile time.process_time() - c < {s}:\n"
         "    pass\nprint(time.perf_counter() - t)")


def _spin(count: int, seconds: float) -> float:
    """The longest wall time of ``count`` busy loops of ``seconds`` CPU each, run at once (processes)."""
    import subprocess
    import sys

    procs = [subprocess.Popen([sys.executable, "-c", _SPIN.format(s=seconds)], stdout=subprocess.PIPE, text=True)
             for _ in range(count)]
    return max(float(p.communicate()[0]) for p in procs)


def parallel_capacity(workers: int, seconds: float = 0.5) -> float:
    """How many cores ``workers`` busy processes get now: workers x (one's wall time) / (each's, all at once).

    ~``workers`` on a quiet machine; less when other jobs share it (then no speed-up can reach the target).
    """
    return workers * _spin(1, seconds) / _spin(workers, seconds)


def _busy(stream: list, wall: float) -> float:
    """The workers' mean busy fraction during a timed sweep: compute time per worker / wall time."""
    per = {}
    for task in stream:
        for ss in task.get("startstops", ()):
            if ss.get("action") == "compute":
                per[task["worker"]] = per.get(task["worker"], 0.0) + ss["stop"] - ss["start"]
    return float(np.mean(list(per.values())) / wall) if per else float("nan")


def tracking_figures(robot, path, index, P: np.ndarray, threads: int = 2) -> dict:
    """The sweep's tracking runs of the placements ``P`` (from the sweep's own starts) one by one, as the sweep
    tracks them, and in one ``track_many`` call on ``threads`` threads (issue 28); both timed, the results compared.

    The starts (the bounded IK, the larger part of a placement's cost) are computed first and not timed; the
    placements per second of the whole serial sweep with its tracking done by ``track_many`` follow as
    N / (serial sweep time - tracking one by one + tracking by ``track_many``).
    """
    from kinredund.errors import KinredundError
    from kinredund.sweep.evaluate import SweepOptions, start_configuration
    from kinredund.sweep.placement import PartPath
    from kinredund.tracking import track_many

    options = SweepOptions()
    kw = {"steps_per_loop": options.steps_per_loop, "loops": options.loops, "diagnostics": False}
    jobs = []
    for T in P:
        part = PartPath(path, T)
        try:
            ik = start_configuration(robot, part, index, options)
        except KinredundError:
            continue
        if ik.converged:
            jobs.append((robot, part, index, ik.q))
    t0 = time.perf_counter()
    alone = track_many(jobs, threads=1, **kw)  # one track() after another, in this thread
    t_alone = time.perf_counter() - t0
    t0 = time.perf_counter()
    many = track_many(jobs, threads=threads, **kw)
    t_many = time.perf_counter() - t0
    same = all(type(a) is type(b) and np.array_equal(np.asarray(a.q), np.asarray(b.q)) for a, b in zip(alone, many,
                                                                                                      strict=True))
    return {"tracked": len(jobs), "track_alone_s": t_alone, "track_many_s": t_many, "track_threads": threads,
            "track_many_speedup": t_alone / t_many if t_many > 0 else float("nan"), "track_many_same": bool(same)}


def bench(sides, workers: int = 2, batch_size: int | None = None) -> dict:
    """The figures of every grid (see the module docstring)."""
    from distributed import get_task_stream

    capacity = parallel_capacity(workers)
    robot, path, index, _ = panda_part_circle()
    cluster, client, startup = start_cluster(workers)
    try:
        t0 = time.perf_counter()
        sweep(robot, path, index, placements(2)[:2 * workers], client=client)  # warm-up: imports, robot cache
        warmup = time.perf_counter() - t0
        rows = []
        for side in sides:
            P = placements(side)
            t0 = time.perf_counter()
            serial = sweep(robot, path, index, P, workers=0, batch_size=batch_size)
            t_serial = time.perf_counter() - t0
            with get_task_stream(client=client) as stream:
                t0, c0 = time.perf_counter(), time.process_time()
                parallel = sweep(robot, path, index, P, client=client, batch_size=batch_size)
                t_cluster, c_client = time.perf_counter() - t0, time.process_time() - c0
            agree = all(a.feasible == b.feasible and a.cause == b.cause for a, b in zip(serial, parallel, strict=True))
            tracking = tracking_figures(robot, path, index, P, threads=max(2, workers))
            t_with_many = t_serial - tracking["track_alone_s"] + tracking["track_many_s"]
            rows.append({**tracking, "serial_track_many_per_s": len(P) / t_with_many,
                         "track_share": tracking["track_alone_s"] / t_serial, "side": side, "placements": len(P),
                         "serial_s": t_serial, "cluster_s": t_cluster,
                         "serial_per_s": len(P) / t_serial, "cluster_per_s": len(P) / t_cluster,
                         "speedup": t_serial / t_cluster, "serial_ms_per_placement": 1e3 * t_serial / len(P),
                         "feasible": sum(r.feasible for r in serial), "records_agree": agree,
                         "worker_busy": _busy(stream.data, t_cluster), "client_cpu": c_client / t_cluster})
    finally:
        client.close()
        cluster.close()
    n = np.array([r["placements"] for r in rows], float)
    fits = {}
    for key in ("serial_s", "cluster_s"):
        if len(rows) > 1:
            b, a = np.polyfit(n, [r[key] for r in rows], 1)  # time = a + b N
            fits[key] = {"intercept_s": float(a), "per_placement_ms": float(1e3 * b)}
    return {"workers": workers, "parallel_capacity": capacity, "cluster_startup_s": startup, "warmup_s": warmup,
            "grids": rows, "fits": fits, "largest_grid": int(n.max())}


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--sides", default="3,5,8", help="grid sides n (2 n^2 placements each), comma-separated")
    p.add_argument("--workers", type=int, default=2, help="worker processes of the local cluster (default 2)")
    p.add_argument("--batch-size", type=int, default=None, help="placements per task (default: the sweep's)")
    args = p.parse_args()
    if args.smoke:
        args.sides, args.workers = "1", 1
    sides = [int(s) for s in args.sides.split(",") if s]
    res = bench(sides, args.workers, args.batch_size)
    print(f"parallel capacity now: {res['parallel_capacity']:.2f} cores for {res['workers']} busy processes "
          "(the most any speed-up can reach)")
    print(f"local cluster of {res['workers']} workers: start-up {res['cluster_startup_s']:.2f} s, "
          f"warm-up sweep {res['warmup_s']:.2f} s (not in the timings)")
    print_table([[r["placements"], r["serial_s"], r["cluster_s"], r["serial_per_s"], r["cluster_per_s"],
                  r["speedup"], r["serial_ms_per_placement"], r["worker_busy"], r["client_cpu"], r["feasible"],
                  r["records_agree"]] for r in res["grids"]],
                ["placements", "serial s", "cluster s", "serial /s", "cluster /s", "speed-up", "ms each", "busy",
                 "client cpu", "feasible", "agree"])
    print("the sweep's tracking runs (from its starts) one by one and in one track_many call; the serial sweep's "
          "placements/s with its tracking by track_many:")
    print_table([[r["placements"], r["tracked"], r["track_share"], r["track_alone_s"], r["track_many_s"],
                  r["track_threads"], r["track_many_speedup"], r["serial_per_s"], r["serial_track_many_per_s"],
                  r["track_many_same"]] for r in res["grids"]],
                ["placements", "tracked", "track share", "one by one s", "track_many s", "threads", "speed-up",
                 "serial /s", "with track_many /s", "same"])
    for key, fit in res["fits"].items():
        print(f"{key}: {fit['intercept_s']:.3f} s + {fit['per_placement_ms']:.2f} ms x N")
    write_json(args.json, res)


if __name__ == "__main__":
    main()
