"""Many tracking runs in one call (issue 28): :func:`track_many`, one :func:`~kinredund.tracking.run.track` per
problem, in threads (or in worker processes: :mod:`kinredund.tracking.many_processes`).

Each run is independent and deterministic (its own stepper, its own compiled core and, per thread, its own
kinematics workspace: ``Robot.kinematics``), so the results equal the runs made one by one. On the compiled
backend ``track()`` advances in runs of ordinary steps, each one C++ call with the GIL released
(:mod:`kinredund.tracking.runs`; the watch's measurements and verdicts inside them), and so is each run's start (the
correction onto the optimum, the rates and the watch's first measurement:
:class:`~kinredund.tracking.compiled_start.CompiledStart`), so threads overlap those. The rest of each run's set-up (the
:class:`~kinredund.tracking.tracker.Tracker`'s checks and the start's first evaluation, in Python), the path samples,
the steps handed back to the Python stepper and the record's end hold the GIL, which bounds the speed-up on two
threads (``python benchmarks/many.py``: runs per second on 1 and 2 threads, and the share in the core's GIL-free
calls). Every other release of the GIL in a run is a point where another thread takes it and this one then waits for
it: the threads take the problems one after another themselves (the calling thread one of them), with no future per
problem for a waiting caller to wake up at.
"""

from __future__ import annotations

import itertools
import os
import threading

from kinredund.errors import OptionError, TrackingError, check_count
from kinredund.tracking.compiled import load_core
from kinredund.tracking.many_processes import in_processes
from kinredund.tracking.run import track


def track_many(problems, *, threads: int | None = None, processes: int | None = None, **options) -> list:
    """Track each problem with the same :func:`~kinredund.tracking.run.track` options, in ``threads`` threads or
    ``processes`` worker processes.

    Args:
        problems: (robot, path, index, q0) per run (robots, paths and indices may be shared between them).
        threads: worker threads (an integer >= 1; default: the machine's CPU count), at most one per problem: a
            thread more would find no problem to take.
        processes: worker processes instead of threads (an integer >= 1, at most one per problem; not with
            ``threads``): for runs whose Python part holds the GIL most of the time, as clearance rows' switches do
            (:mod:`~kinredund.tracking.many_processes`: forked workers; the records must pickle, and the problems and
            options too where the platform has no fork).
        **options: :func:`~kinredund.tracking.run.track`'s keyword arguments, the same for every run.

    Returns:
        Per problem, in order: its :class:`~kinredund.trajectory.Trajectory`, or the
        :class:`~kinredund.errors.TrackingError` where its run stopped (with its ``partial`` record).

    Raises:
        OptionError: problems that are not a list of (robot, path, index, q0) tuples, a bad ``threads`` or
            ``processes``, both given, problems or options that do not pickle (``processes`` without fork); any error
            of bad input that :func:`~kinredund.tracking.run.track` raises for a run.
    """
    try:
        if isinstance(problems, str | bytes):
            raise TypeError("a string is not a list of problems")
        jobs = list(problems)
    except TypeError as err:  # (None, a number, a 0-d array)
        raise OptionError(f"problems must be a list of (robot, path, index, q0) tuples, got {type(problems).__name__}"
                          ) from err
    for k, job in enumerate(jobs):
        if not isinstance(job, tuple | list) or len(job) != 4:
            raise OptionError(f"problem {k} must be a (robot, path, index, q0) tuple, got {type(job).__name__}")
    if processes is not None and threads is not None:
        raise OptionError(f"give threads= or processes=, not both (got threads={threads!r}, processes={processes!r})")
    if processes is not None:
        workers = min(check_count(processes, 1, "processes", OptionError), len(jobs))
        if workers > 1:
            return in_processes(jobs, options, workers)
    else:
        workers = (os.cpu_count() or 1) if threads is None else check_count(threads, 1, "threads", OptionError)
        workers = min(workers, len(jobs))  # (threads=10**6 for two problems started a million threads, that waited)
    load_core()  # once, before the threads (it warns once where the core cannot be loaded)

    def one(job):
        try:
            return track(*job, **options)
        except TrackingError as err:
            return err

    if workers <= 1 or len(jobs) <= 1:
        return [one(job) for job in jobs]
    return _in_threads(one, jobs, workers)


def _in_threads(one, jobs: list, workers: int) -> list:
    """``[one(job) for job in jobs]`` computed by ``workers`` threads, the calling thread one of them: each takes the
    next job not yet taken until none is left. Where ``one`` raises, the first such job's error (in the jobs' order)
    is raised once all have run, as ``ThreadPoolExecutor.map`` raises it. A KeyboardInterrupt (or SystemExit) stops
    the taking of jobs: the runs under way end, and it is raised. (No future per job: the caller, waiting on each
    job's future in turn, took the GIL from the workers at every job's end.)"""
    results, failed, taken, stop = [None] * len(jobs), {}, itertools.count(), []

    def work() -> None:
        for k in iter(taken.__next__, None):  # (itertools.count's next is atomic: each job is taken once)
            if k >= len(jobs) or stop:
                return
            try:
                results[k] = one(jobs[k])
            except Exception as err:  # re-raised in the caller below, as map re-raises it
                failed[k] = err
            except BaseException as err:  # Ctrl-C (delivered to the calling thread): no more jobs are taken
                stop.append(err)
                return

    helpers = [threading.Thread(target=work, daemon=True) for _ in range(workers - 1)]
    for thread in helpers:
        thread.start()
    work()
    for thread in helpers:
        thread.join()
    if stop:
        raise stop[0]
    if failed:
        raise failed[min(failed)]
    return results
