""":func:`~kinredund.tracking.many.track_many`'s runs in worker processes (``processes=``), which share no GIL.

A run with clearance rows spends most of its CPU on the Python bookkeeping of the switches of its active set
(:mod:`kinredund.tracking.switches`: finding, making and checking them; their times are located in the core) and the
steps around them, with the GIL held, so threads gain little on it (``python benchmarks/many.py --sphere --runs 16
--loops 2 --repeat 5 --processes``, README: 1.04 to 1.24 times one thread's runs per second on two threads, 1.23 to
1.35 times with ``processes=2``, up to 2.2 times on two bare worker processes that send no record back); processes
do. The
workers are forked (:func:`start_method`: they inherit the problems and options; ``spawn`` where the platform has no
fork, which pickles them to each worker as it starts); each takes the next problem not yet taken (one at a time, so a
long run does not hold up the others) and sends its record back pickled (the record's lazily computed fields are
computed in the worker for it). The runs are the same computation as in the caller, so the records equal the runs
one by one, bit for bit.

A forked worker holds only the calling thread: a lock that another of the caller's threads held at the fork stays
held in it (a thread of the caller's own inside kinredund, such as a second ``track_many``, can hold one), so call it
with ``processes=`` from a program whose other threads are idle, or use ``threads=``. ``progress=`` is called in the
workers, not in the caller. On Ctrl-C the problems already queued to the workers still run before the
KeyboardInterrupt reaches the caller (6.7 s after it, for runs of about 4 s on two workers).
"""

from __future__ import annotations

import multiprocessing
import pickle
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool

from kinredund.errors import OptionError, SolverError, TrackingError

_WORK: dict = {}  # in a worker: the problems and the options (given once, by _load)


def _load(jobs: list, options: dict) -> None:
    _WORK["jobs"], _WORK["options"] = jobs, options


def _track_one(k: int) -> tuple[bool, object]:
    """(True, the record or the TrackingError) of problem ``k``, or (False, the error) where track() raised another
    (a bad problem, or a user path's or index's own exception: the caller raises the first such in the problems'
    order once all have run, as the threads' route does)."""
    from kinredund.tracking.run import track

    try:
        return True, track(*_WORK["jobs"][k], **_WORK["options"])
    except TrackingError as err:
        return True, err
    except Exception as err:  # (of any family: an error raised by the map itself would skip an earlier problem's)
        return False, err


def start_method() -> str:
    """``fork`` where the platform has it (the workers inherit the problems: nothing to pickle on the way there, and
    no re-import of the caller's script, which ``spawn`` needs guarded by ``if __name__ == "__main__"``), else
    ``spawn``."""
    return "fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn"


def in_processes(jobs: list, options: dict, workers: int) -> list:
    """``[track(*job, **options) or its TrackingError for job in jobs]`` in ``workers`` worker processes (module
    docstring). OptionError where ``spawn`` must send problems or options that cannot be pickled (a path of a
    lambda, say); SolverError where a worker process dies (killed, out of memory)."""
    method = start_method()
    if method == "spawn":
        try:
            pickle.dumps((jobs, options))
        except (pickle.PicklingError, TypeError, AttributeError) as err:
            raise OptionError(f"processes= sends the problems and options to worker processes, which needs them "
                              f"picklable here ({type(err).__name__}: {err}); a FunctionPath of a lambda or of a local "
                              "function is not: define it at a module's top level, or use threads=") from err
    context = multiprocessing.get_context(method)
    try:
        with ProcessPoolExecutor(workers, mp_context=context, initializer=_load, initargs=(jobs, options)) as pool:
            outcomes = list(pool.map(_track_one, range(len(jobs))))
    except BrokenProcessPool as err:
        raise SolverError(f"a worker process of track_many(processes={workers}) ended abruptly ({err}): killed, or "
                          "out of memory? The runs in threads (threads=) or one by one give the records") from err
    for ok, value in outcomes:
        if not ok:
            raise value
    return [value for _, value in outcomes]
