"""The placement sweep: one cyclic task at many part poses, serially or on a Dask cluster.

:func:`sweep` answers the cell designer's question of where to put the part: it tracks the same path
(given in the part frame) at every placement and returns one
:class:`~kinredund.sweep.record.PlacementRecord` per placement, in placement order;
:func:`~kinredund.sweep.record.best` ranks them.

Execution (``dask.distributed``): by default an in-process ``LocalCluster`` of one single-threaded
worker process per core (nothing to start beforehand); ``scheduler="tcp://host:port"`` or ``client=``
runs on an existing cluster; ``workers=0`` runs serially in this process. Whatever runs it, each
placement goes through the same function (:func:`run_batch`) with the same inputs, so the records are
the same: everything discrete (feasible, cause, steps) exactly, the figures to round-off. Not bit for
bit: the bounded IK's box-constrained QP steps (proxsuite, dense) were measured to return results that
differ in the last bits for identical inputs from one call to the next (~1e-18 to 1e-16 on the step),
and the start configuration, hence the run, inherits it (~1e-15 relative on the figures); the tracker
itself repeats bit for bit.

What travels to the workers, once: a :class:`SweepJob` holding the :class:`~kinredund.model.robot.Robot`
itself (pickled with its ``pin.Model``, which Pinocchio serialises through Boost; the per-thread
workspace, a ``pin.Data``, is left out and made again where it is used), the path, the index and the
options. It is scattered to every worker (``broadcast=True``): each worker process deserialises it once
and its tasks share that robot. The pickled model rather than the robot's name or URDF text because it
serves every robot alike (the shipped ones, example-robot-data arms with joints locked or dropped, URDF
files the workers do not have, robots built from an HD table in memory) and is the very model the client
holds, frames, limits and home included, so nothing is re-parsed or re-resolved differently on a worker;
the price is that workers must run the same Pinocchio version (Boost archives are tied to it), which
identical results need anyway. No ``GeometryData`` (which does not pickle) is involved, and nothing is
attached to the ``pin.Model`` (a model with an extra attribute does not pickle). Tasks then carry only
their placements (a batch of 4x4 poses) and bring back small records.

Batching: placements go in batches of ``batch_size``, by default guided (:func:`batches`): large
batches first, so the scheduler's ~1 ms per task stays small next to ~50 ms per placement, and single
placements last, so the workers finish together.

Output: with ``out=``, the sweep file (:mod:`kinredund.sweep.store`) is rewritten as batches complete
(at most once a second, and on the way out, also when interrupted); ``resume=True`` keeps the
records already in it and runs only the others, giving the same final file.
"""

from __future__ import annotations

import hashlib
import math
import pickle
import time
from dataclasses import dataclass, fields
from pathlib import Path as FilePath

import numpy as np

from kinredund.errors import KinredundError, check_count, check_size
from kinredund.indices import Index
from kinredund.model.robot import Robot
from kinredund.paths import Path
from kinredund.sweep.cell import sweep_scene
from kinredund.sweep.cluster import check_scheduler, dask_client
from kinredund.sweep.evaluate import SweepOptions, check_clearance, evaluate_placement
from kinredund.sweep.placement import check_placements, pose_coordinates
from kinredund.sweep.record import PlacementRecord
from kinredund.sweep.store import resumable_records, write_sweep_file

#: default batches (guided): each takes 1 / (this many x worker threads) of the placements still to batch ...
GUIDED_SHARE = 4
#: ... and at most this many placements
MAX_BATCH = 32
#: how long a sweep waits for the first worker of a cluster that has none [s]
WORKER_WAIT = 60.0
#: the partial output file is rewritten at most this often [s]
WRITE_INTERVAL = 1.0


@dataclass(frozen=True)
class SweepJob:
    """Everything a worker needs for any placement of one sweep (scattered once per sweep).

    Attributes:
        robot: the arm (pickled with its ``pin.Model``; each process makes its own workspace).
        path: the path in the part frame; index: the index z (or None); options: the run options.
        token: a SHA-256 of all of it (pickled): the job's identity, also in the output file's header.
    """

    robot: Robot
    path: Path
    index: Index | None
    options: SweepOptions
    token: str = ""


def make_job(robot: Robot, path: Path, index: Index | None, options: SweepOptions) -> SweepJob:
    """The :class:`SweepJob` of a sweep, with its token."""
    if not isinstance(robot, Robot):
        raise KinredundError(f"robot must be a kinredund Robot (see kinredund.load_robot), got {type(robot).__name__}")
    if not isinstance(path, Path):
        raise KinredundError(f"path must be a kinredund.paths.Path (in the part frame), got {type(path).__name__}")
    if index is not None and not isinstance(index, Index):
        raise KinredundError(f"index must be a kinredund.indices.Index or None, got {type(index).__name__}")
    job = SweepJob(robot, path, index, options)
    try:
        blob = pickle.dumps(job, protocol=4)
    except (pickle.PicklingError, TypeError, AttributeError) as err:
        raise KinredundError(f"the sweep's robot, path or index cannot be pickled for the workers: {err} "
                             "(a path from a lambda or a local function: use a module-level function)") from err
    return SweepJob(robot, path, index, options, hashlib.sha256(blob).hexdigest())


def run_batch(job: SweepJob, batch: list[tuple[int, np.ndarray]]) -> list[PlacementRecord]:
    """The records of a batch of (placement number, 4x4 pose): the work of one task.

    A placement that raises anything is an ``internal`` record (a bug to report, not a lost sweep).
    """
    robot = job.robot  # deserialised once per worker process (scattered data), shared by its tasks
    out = []
    for k, T in batch:
        try:
            out.append(evaluate_placement(robot, job.path, job.index, T, k, job.options))
        except Exception as err:  # noqa: BLE001 - one placement's failure is its record
            x, y, z, yaw = pose_coordinates(np.asarray(T, float))
            out.append(PlacementRecord(int(k), tuple(float(v) for v in np.ravel(T)), x, y, z, yaw, False,
                                       cause="internal", message=f"{type(err).__name__}: {err}"))
    return out


def _lost(batch, err: BaseException) -> list[PlacementRecord]:
    """Records of a batch whose task failed on the cluster (a lost worker, a deserialisation error)."""
    out = []
    for k, T in batch:
        x, y, z, yaw = pose_coordinates(np.asarray(T, float))
        out.append(PlacementRecord(int(k), tuple(float(v) for v in np.ravel(T)), x, y, z, yaw, False,
                                   cause="worker", message=f"{type(err).__name__}: {err}"))
    return out


def header(job: SweepJob, count: int) -> dict:
    """The output file's header: what was swept (the token identifies it exactly)."""
    robot = job.robot
    return {"robot": robot.name, "task": robot.task, "nq": robot.nq, "path": type(job.path).__name__,
            "index": None if job.index is None else type(job.index).__name__, "options": options_dict(job.options),
            "placements": count, "token": job.token}


def options_dict(options: SweepOptions) -> dict:
    """The options for the file's header (JSON): the scene as its objects
    (:meth:`kinredund.sweep.cell.SweepScene.describe`)."""
    out = {f.name: getattr(options, f.name) for f in fields(options)}
    out["scene"] = None if options.scene is None else options.scene.describe()
    return out


def batches(todo: list[int], size: int | None, threads: int) -> list[list[int]]:
    """``todo`` cut into batches: of ``size`` each, or by default guided (Polychronopoulos and Kuck 1987).

    Guided: each batch takes 1 / (GUIDED_SHARE x threads) of the placements not yet batched, 1 to
    MAX_BATCH of them: the first batches are large (little scheduling per placement), the last ones
    single placements, so the workers finish together. The scheduler hands batches out in order as
    workers free up.
    """
    out, i = [], 0
    while i < len(todo):
        step = size or max(1, min(MAX_BATCH, math.ceil((len(todo) - i) / (GUIDED_SHARE * max(threads, 1)))))
        out.append(todo[i:i + step])
        i += step
    return out


def sweep(robot: Robot, path: Path, index: Index | None, placements, *, steps_per_loop: int = 200,
          loops: int = 1, duration: float | None = None, steps: int | None = None, scheme: str = "augmented",
          mode: str = "default", limits: bool = True, speed_limit: bool = False, starts: int = 8, seed: int = 0,
          scene=None, clearance: float = 0.0, clearance_resolution: float = 1e-3, client=None,
          workers: int | None = None, scheduler: str | None = None, batch_size: int | None = None,
          out: str | FilePath | None = None, resume: bool = False, progress=None) -> list[PlacementRecord]:
    """Track ``path`` (in the part frame) with the part at each of ``placements``; one record each.

    Args:
        robot: the arm; its task kind sets what is tracked.
        path: a :class:`kinredund.paths.Path` in part coordinates (wrapped by
            :class:`~kinredund.sweep.placement.PartPath` at each placement).
        index: the performance index z (None for the pseudoinverse scheme).
        placements: part poses in the base frame, (N, 4, 4) [m]: :func:`~kinredund.sweep.placement.grid`
            or any list of rigid transforms.
        steps_per_loop, loops, duration, steps, scheme, mode, limits, speed_limit, starts, seed: the run
            at each placement (:class:`~kinredund.sweep.evaluate.SweepOptions`).
        scene: a :class:`kinredund.geometry.Scene` of this robot, its world objects given in the part frame
            (:mod:`kinredund.sweep.cell`: at each placement they move with the part, as the path does), or
            None. Each placement's run is checked against it, self pairs included (records' ``clearance``).
        clearance: with ``scene``, a run closer than this to an object or to itself is infeasible [m]
            (cause ``collision``; 0: only contact is).
        clearance_resolution: how closely each run's least clearance is found [m] (``SweepOptions``).
        client: a ``distributed.Client`` to run on (left open).
        workers: worker processes of the default local cluster (default: this machine's cores);
            0 runs serially in this process. The workers are spawned processes that import the main
            module: a script calls :func:`sweep` under ``if __name__ == "__main__":``.
        scheduler: the address of an existing Dask scheduler (``tcp://host:port``; :func:`check_scheduler`).
        batch_size: placements per task (default: see the module docstring).
        out: the sweep file, written as batches complete (``.jsonl``: JSON lines; else one JSON object).
        resume: keep the records already in ``out`` (it must come from the same sweep) and run the rest.
        progress: called as ``progress(done, total)`` after each batch.

    Returns:
        The records in placement order.

    Raises:
        PlacementError: a placement that is not a rigid transform.
        OptionError: bad options, refused before any placement runs (limits asked of a mode or scheme that cannot
            hold them: pass ``limits=False`` with ``mode="thesis"`` or a baseline scheme).
        KinredundError: an unreachable scheduler, ``out`` from another sweep on resume.
    """
    T = check_placements(placements)
    check_clearance(clearance, scene is not None)  # before the scene is rebuilt
    options = SweepOptions(steps_per_loop, loops, duration, steps, scheme, mode, limits, bool(speed_limit),
                           starts, seed, sweep_scene(scene, robot), clearance,
                           clearance_resolution)
    if sum(x is not None for x in (client, scheduler, workers)) > 1:
        raise KinredundError("give at most one of client=, scheduler= and workers= (workers sizes a local cluster)")
    if workers is not None:
        check_size(workers, "workers", "workers", KinredundError, minimum=0)
    if batch_size is not None:
        check_count(batch_size, 1, "batch_size", KinredundError)
    if scheduler is not None:
        check_scheduler(scheduler)
    if resume and out is None:
        raise KinredundError("resume=True needs out= (the partial sweep file to resume from)")
    job = make_job(robot, path, index, options)
    head = header(job, len(T))
    done: dict[int, PlacementRecord] = {}
    if resume and FilePath(out).exists():
        done = resumable_records(out, head, T)
    todo = [k for k in range(len(T)) if k not in done]
    last_write = [time.monotonic()]
    unwritten = [False]  # records computed since the file was last written

    def write(force: bool = False) -> None:
        # only new records are written: a sweep that stops before computing any (an unreachable
        # scheduler, a bad option) leaves an existing file as it was, never replaced by a bare header
        if out is not None and unwritten[0] and (force or time.monotonic() - last_write[0] >= WRITE_INTERVAL):
            write_sweep_file(out, head, [done[k] for k in sorted(done)])
            last_write[0], unwritten[0] = time.monotonic(), False

    def finish(records: list[PlacementRecord]) -> None:
        for r in records:
            done[r.placement] = r
        unwritten[0] = unwritten[0] or bool(records)
        write()
        if progress is not None:
            progress(len(done), len(T))

    if progress is not None:
        progress(len(done), len(T))
    try:
        if todo and workers == 0 and client is None and scheduler is None:
            for batch in batches(todo, batch_size, 1):
                finish(run_batch(job, [(k, T[k]) for k in batch]))
        elif todo:
            _run_on_dask(job, T, todo, batch_size, finish, client, scheduler, workers)
    finally:
        write(force=True)
    return [done[k] for k in range(len(T))]


def _run_on_dask(job, T, todo, batch_size, finish, client, scheduler, workers) -> None:
    from distributed import as_completed

    with dask_client(client, scheduler, workers) as c:
        if not c.nthreads():  # a cluster whose workers are still joining: wait for one
            try:
                c.wait_for_workers(1, timeout=WORKER_WAIT)
            except TimeoutError as err:
                raise KinredundError(f"the Dask cluster has no workers (none joined in {WORKER_WAIT:.0f} s)") from err
        threads = sum(c.nthreads().values())
        job_f = c.scatter(job, broadcast=True, hash=False)
        items_of = {}
        futures = []
        for batch in batches(todo, batch_size, threads):
            items = [(k, T[k]) for k in batch]
            fut = c.submit(run_batch, job_f, items, pure=False)
            items_of[fut.key] = items
            futures.append(fut)
        try:
            # the results gathered by as_completed's own thread: fut.result() is a sync() call, and a Ctrl-C in its
            # first instants hit distributed's cancel callback before its future existed (a NameError traceback)
            for fut, got in as_completed(futures, with_results=True, raise_errors=False):
                if fut.status == "error":  # a lost task: its placements say so ((type, error, traceback))
                    records = _lost(items_of[fut.key], got[1])
                elif isinstance(got, BaseException):  # cancelled
                    records = _lost(items_of[fut.key], got)
                else:
                    records = got
                finish(records)
        finally:
            c.cancel(futures)
