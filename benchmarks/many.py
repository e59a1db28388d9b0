"""Many tracking runs in one call: ``track_many`` on 1 and 2 threads.

Usage::

    python benchmarks/many.py [--runs 8] [--loops 1] [--repeat 3] [--processes] [--sphere] [--json FILE]

Problem: ``--runs`` variants of the Panda benchmark circle (``kinredund.problems.panda_circle``, 200 steps per
loop, limits held), the k-th turning the tool about its axis by up to 2 k degrees along the loop. Each round
times ``track_many(problems, threads=1)`` and ``threads=2`` in turn; the figures are the medians over the
rounds of runs per second, and the speed-up (2 threads over 1: at most 2 on 2 cores, less where others load
the machine). The compiled core makes each run's start (the correction onto the optimum, the rates, the watch's
first measurement: ``start_run``) and runs the ordinary steps in runs (:mod:`kinredund.tracking.runs`; the watch's
measurements and verdicts inside them), each one C++ call with the GIL released, as are the start's checks; the rest
(the rest of each run's set-up, the path's samples, the record, the steps it hands back) holds it.
``--sphere``: instead, ``--runs`` copies of clearance_peers.py's elbow case (a 13.3 cm Panda circle whose optimum's
elbow is kept out of a 0.1 m sphere, ``SphereClearance``), ``--loops`` loops of 200 steps each: the rows are held in
the core's runs, but each switch of the active set (a row reached or released, about four a loop) is located by the
Python stepper's switching-time search (``kinredund.tracking.switches``), which holds the GIL but for its corrector
solves.
The records of both thread counts are compared with the runs one by one (joints, bit for bit). Also the share of
a run's CPU time (``time.thread_time``: the load of other processes does not count) spent in those calls of the
core (C++, the GIL released: :data:`GIL_FREE`; numpy's LAPACK calls release it as well), which bounds the
speed-up on two threads.
``--processes`` also times the problems split between two worker processes, which share no GIL: the ceiling
threads could reach on this machine (the records not sent back); and ``track_many(problems, processes=2)``, which
sends them back (pickled: the records' lazily computed fields are computed in the workers), its records compared
with the runs one by one. On a shared machine the speed-up moves with the others' load
(``parallel capacity`` in ``benchmarks/sweep.py``).
"""

from __future__ import annotations

import time

import numpy as np
from _bench import machine, parser, print_table, write_json

from kinredund.errors import TrackingError
from kinredund.problems import panda_circle
from kinredund.tracking import track, track_many


def problems(count: int) -> list:
    """``count`` Panda circle problems (see the module docstring)."""
    return [panda_circle(wrist_amplitude=float(np.radians(2.0 * k))) for k in range(count)]


#: the core's calls that release the GIL for the whole of their work: the runs' start, its checks, their runs of steps
GIL_FREE = ("start_run", "start_checks", "run_steps")


def gil_free_share(jobs: list, options: dict) -> tuple[float, float]:
    """(share, GIL-held ms per run): the share of the runs' CPU time (one by one, this thread's:
    ``time.thread_time``, which other processes' load does not count) spent in the core's calls of :data:`GIL_FREE`
    (the start: its correction, rates and first watch measurement; the runs of steps, with the watch's
    measurements and their verdicts; the start's checks), where the GIL is released, and the rest of a run's CPU
    time [ms], which holds the GIL. With a
    GIL-held share g the speed-up on two threads is at most min(2, 1 / g); in practice less, as two threads rarely
    take turns without waiting for each other."""
    import kinredund._core as core

    inner, spent = {name: getattr(core, name) for name in GIL_FREE if hasattr(core, name)}, [0.0]

    def timed(fn):
        def call(*args):
            t0 = time.thread_time()
            try:
                return fn(*args)
            finally:
                spent[0] += time.thread_time() - t0

        return call

    for name, fn in inner.items():
        setattr(core, name, timed(fn))
    try:
        t0 = time.thread_time()
        for job in jobs:
            try:
                track(*job, **options)
            except TrackingError:
                pass
        total = time.thread_time() - t0
    finally:
        for name, fn in inner.items():
            setattr(core, name, fn)
    return spent[0] / total, 1e3 * (total - spent[0]) / len(jobs)


_FORKED_JOBS: list = []  # the problems, inherited by :func:`process_rate`'s forked workers (not pickled per call)


def _track_all(which: list, options: dict) -> int:
    """Track the jobs numbered ``which`` in this process (a worker of :func:`process_rate`); the number that ran to
    the end."""
    done = 0
    for job in (_FORKED_JOBS[i] for i in which):
        try:
            track(*job, **options)
            done += 1
        except TrackingError:
            pass
    return done


def process_rate(jobs: list, options: dict, repeat: int) -> float:
    """Runs per second with the problems split between two worker processes (forked, warmed up; no GIL shared):
    the ceiling that threads could reach on this machine. The problems are inherited through the fork and the
    records are not sent back (only counts), so no robot or record is pickled in the timed calls."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    _FORKED_JOBS[:] = jobs  # before the fork: the workers inherit the problems and get only their numbers
    halves = [list(range(0, len(jobs), 2)), list(range(1, len(jobs), 2))]
    rates = []
    with ProcessPoolExecutor(2, mp_context=mp.get_context("fork")) as pool:
        list(pool.map(_track_all, halves, [options] * 2))  # each worker's first runs (imports, caches)
        for _ in range(repeat):
            t0 = time.perf_counter()
            list(pool.map(_track_all, halves, [options] * 2))
            rates.append(len(jobs) / (time.perf_counter() - t0))
    return float(np.median(rates))


def sphere_problems(count: int) -> tuple[list, list]:
    """(``count`` copies of clearance_peers.py's elbow case, the constraints for ``track``): see ``--sphere``."""
    from clearance_peers import elbow_case

    robot, path, index, q0, sphere = elbow_case()
    return [(robot, path, index, q0)] * count, [sphere]


def bench(runs: int = 8, loops: int = 1, repeat: int = 3, processes: bool = False, sphere: bool = False) -> dict:
    options = {"loops": loops}
    if sphere:
        jobs, options["constraints"] = sphere_problems(runs)
    else:
        jobs = problems(runs)
    alone = track_many(jobs, threads=1, **options)  # one track() after another, in this thread
    rates = {1: [], 2: []}
    same = True
    for _ in range(repeat):
        for threads in (1, 2):
            t0 = time.perf_counter()
            got = track_many(jobs, threads=threads, **options)
            rates[threads].append(len(jobs) / (time.perf_counter() - t0))
            same &= all(type(a) is type(b) and np.array_equal(np.asarray(a.q), np.asarray(b.q))
                        for a, b in zip(alone, got, strict=True))
    one, two = (float(np.median(rates[k])) for k in (1, 2))
    share, held_ms = gil_free_share(jobs, options)
    in_processes = []
    for _ in range(repeat if processes else 0):
        t0 = time.perf_counter()
        got = track_many(jobs, processes=2, **options)
        in_processes.append(len(jobs) / (time.perf_counter() - t0))
        same &= all(type(a) is type(b) and np.array_equal(np.asarray(a.q), np.asarray(b.q))
                    for a, b in zip(alone, got, strict=True))
    return {"case": "sphere" if sphere else "circle", "runs": runs, "steps_per_run": 200 * loops,
            "runs_per_s_1_thread": one, "runs_per_s_2_threads": two,
            "speedup_2_over_1": two / one, "same_as_one_by_one": bool(same), "core_runs_share": share,
            "gil_held_ms_per_run": held_ms,
            "stopped": sum(isinstance(a, TrackingError) for a in alone), "machine": machine(),
            "runs_per_s_2_processes": process_rate(jobs, options, repeat) if processes else None,
            "runs_per_s_track_many_processes": float(np.median(in_processes)) if processes else None}


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=8, help="tracking runs per call (default 8)")
    p.add_argument("--loops", type=int, default=1, help="loops of each run (default 1)")
    p.add_argument("--repeat", type=int, default=3, help="rounds (default 3)")
    p.add_argument("--processes", action="store_true", help="also time two worker processes (threads' ceiling)")
    p.add_argument("--sphere", action="store_true", help="clearance_peers.py's elbow sphere case instead (module "
                                                        "docstring)")
    args = p.parse_args()
    if args.smoke:
        args.runs, args.loops, args.repeat = 2, 1, 1
    res = bench(args.runs, args.loops, args.repeat, args.processes, args.sphere)
    print_table([[res["runs"], res["steps_per_run"], res["runs_per_s_1_thread"], res["runs_per_s_2_threads"],
                  res["speedup_2_over_1"], res["core_runs_share"], res["gil_held_ms_per_run"], res["stopped"],
                  res["same_as_one_by_one"]]],
                ["runs", "steps each", "runs/s 1 thread", "runs/s 2 threads", "speed-up", "in core runs",
                 "GIL-held ms/run", "stopped", "same"])
    print("in core runs: the share of a run's CPU time (1 thread) in the core's start and runs of steps, C++ with the "
          "GIL released;\nGIL-held ms/run: the rest of a run's CPU time (1 thread), which threads cannot overlap")
    if res["runs_per_s_2_processes"] is not None:
        print(f"2 processes: {res['runs_per_s_2_processes']:.0f} runs/s "
              f"({res['runs_per_s_2_processes'] / res['runs_per_s_1_thread']:.2f}x one thread); "
              f"track_many(processes=2): {res['runs_per_s_track_many_processes']:.0f} runs/s "
              f"({res['runs_per_s_track_many_processes'] / res['runs_per_s_1_thread']:.2f}x)")
    write_json(args.json, res)


if __name__ == "__main__":
    main()
