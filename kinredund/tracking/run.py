"""A whole tracking run: :func:`track` steps a :class:`~kinredund.tracking.tracker.Tracker` and records it.

Closed paths (with a ``period``) run ``loops`` loops of ``steps_per_loop`` steps and record the joint
drift at the end of each loop; open paths need ``duration`` [s] and ``steps``. Every argument is
checked before any work, and the run's length is bounded (:data:`MAX_STEPS`): a typo cannot make it
endless.
"""

from __future__ import annotations

from kinredund.errors import (
    MAX_SAMPLES,
    OptionError,
    PathError,
    TrackingError,
    check_count,
    check_hooks,
    check_positive,
    check_size,
)
from kinredund.indices import Index
from kinredund.model.robot import Robot
from kinredund.paths import Path
from kinredund.tracking.failure import loadable_name
from kinredund.tracking.record_checks import say_open_loop, say_rate_burst
from kinredund.tracking.recorder import Recorder
from kinredund.tracking.runs import stepping
from kinredund.tracking.tracker import DT_RANGE, Tracker, check_path
from kinredund.trajectory import Trajectory

#: the most steps one run records (the record holds every step; kinredund.errors.SIZES holds every such limit)
MAX_STEPS = MAX_SAMPLES


def _span(path: Path, steps_per_loop, loops, duration, steps) -> tuple[float, int, int | None]:
    """(dt [s], total steps, loops or None for an open run), the arguments checked."""
    dt, total, loops = _steps(path, steps_per_loop, loops, duration, steps)
    if not DT_RANGE[0] <= dt <= DT_RANGE[1]:
        what = f"the path's period {path.period:.3g} s" if loops is not None else f"the duration {duration:.3g} s"
        raise OptionError(f"the time step {dt:.3g} s ({what} over {total} steps) is outside the range the tracker "
                          f"computes in, {DT_RANGE[0]:g} to {DT_RANGE[1]:g} s: is the path's speed or duration a "
                          "typo?")
    return dt, total, loops


def _steps(path: Path, steps_per_loop, loops, duration, steps) -> tuple[float, int, int | None]:
    if path.period is not None and duration is None:
        spl = check_count(steps_per_loop, 1, "steps_per_loop", OptionError)
        loops = check_count(loops, 1, "loops", OptionError)
        check_size(spl * loops, f"loops x steps_per_loop ({loops} x {spl})", "samples")  # the record holds every step
        return path.period / spl, spl * loops, loops
    if duration is None or steps is None:
        raise PathError("an open path needs duration > 0 [s] and steps >= 1")
    duration = check_positive(duration, "duration [s] of an open path", PathError)
    steps = check_size(steps, "steps", "samples")
    return duration / steps, steps, None


def track(robot: Robot, path: Path, index: Index | None, q0, *, scheme: str = "augmented", mode: str = "default",
          steps_per_loop: int = 200, loops: int = 1, duration: float | None = None, steps: int | None = None,
          linear_solver: str | None = None, qp_backend: str | None = None, tol: float = 1e-12,
          diagnostics: bool = True, liegeois_gain: float = 1.0, limits=None, project_start: bool = False,
          strict: bool = True, constraints=None, qp_solver: str = "proxqp", scene=None, clearance=None,
          self_clearance=None, progress=None, meta: dict | None = None, backend: str | None = None) -> Trajectory:
    """Track ``path`` from ``q0`` and return the :class:`~kinredund.trajectory.Trajectory`.

    Args:
        robot, path, index, q0, scheme, mode, linear_solver, qp_backend, tol, liegeois_gain, limits,
            project_start, strict, constraints, qp_solver, scene, clearance, self_clearance, backend: as for
            :class:`~kinredund.tracking.tracker.Tracker` (by default the default mode's optimal schemes
            keep the joints within the robot's limits; ``limits=False`` is
            the thesis's unconstrained scheme; ``strict`` the step control and the fold and singularity
            watch).
        steps_per_loop, loops: a closed path's steps per loop and loops (integers >= 1, at most
            :data:`MAX_STEPS` steps in all).
        duration, steps: an open path's duration [s] and steps.
        diagnostics: record the eigenvalues of M and of its projection (``m_eigs``, ``m_null_eigs``).
        progress: ``progress(done, total)`` after each step.
        meta: free-form entries for the record's ``meta``.

    Warns:
        RecordWarning: a closed path whose joints do not return within
            :data:`~kinredund.trajectory.LOOP_CLOSURE_TOL` at the end of a loop (the record's ``loop_closed``
            is False and ``meta["loop_not_closed"]`` names the cause).

    Raises:
        OptionError, ChoiceError: an argument out of its range (checked before any work), a ``progress`` that is
            not callable, a ``meta`` that is not a dict.
        PathError: the path is malformed, non-finite, or leaves the workspace (says when and where).
        SingularityError: R or J becomes singular (time, configuration, smallest singular value).
        TrackingError: the run stopped (a subclass of both errors above): ``cause``, ``t`` and ``q`` of the
            last good point (on the path, inside the limits), ``watched``, and ``partial``, the record up to
            the last requested time before it.
    """
    check_hooks(progress, meta)
    options = {"scheme": scheme, "mode": mode, "linear_solver": linear_solver, "qp_backend": qp_backend, "tol": tol,
               "liegeois_gain": liegeois_gain, "limits": limits, "project_start": project_start, "strict": strict,
               "constraints": constraints, "qp_solver": qp_solver,
               "scene": scene, "clearance": clearance, "self_clearance": self_clearance, "backend": backend}
    span = {"steps_per_loop": steps_per_loop, "loops": loops, "duration": duration, "steps": steps}
    traj = _run(robot, path, index, q0, span, options, diagnostics, progress, meta)
    say_open_loop(traj, scheme, mode)

    def refined() -> Trajectory:  # the same run with half the time step, for the rate-burst check
        finer = dict(span, steps_per_loop=2 * steps_per_loop, steps=None if steps is None else 2 * steps)
        return _run(robot, path, index, q0, finer, options, False, None, None)

    say_rate_burst(traj, refined)
    return traj


def _run(robot: Robot, path: Path, index: Index | None, q0, span: dict, options: dict, diagnostics: bool, progress,
         meta: dict | None) -> Trajectory:
    """The run of :func:`track` (its arguments grouped) and its record, without the record's checks."""
    scheme, mode = options["scheme"], options["mode"]
    dt, total, loops_run = _span(check_path(path), **span)  # (the robot: the Tracker's own check, next)
    tracker = Tracker(robot, path, index, q0, dt, **options)
    rec = Recorder(tracker.stepper, diagnostics)
    rec.add()
    advance = stepping(tracker, rec)  # runs of compiled steps in one call where it can (tracking/runs.py)
    info = {"robot_name": loadable_name(robot), "scheme": scheme, "mode": mode, "period": path.period,
            "meta": dict(meta or {}, dt=dt, steps=total, backend=tracker.backend,
                         velocity_limit=robot.model.velocityLimit.tolist())}  # Trajectory.speed_over_limits
    try:
        try:
            done = 0
            while done < total:
                before, done = done, done + advance(total - done)
                if progress is not None:
                    for k in range(before, done):
                        progress(k + 1, total)
        except TrackingError as err:
            if err.partial is None:  # the record up to the last requested time (a Trajectory that plays)
                info["meta"].update(steps=len(rec) - 1, partial=True)
                err.partial = rec.trajectory(loops=None, steps_per_loop=None, **info)
            raise
        return rec.trajectory(loops=loops_run, steps_per_loop=None if loops_run is None else total // loops_run,
                              **info)
    finally:
        _unlink(tracker)


def _unlink(tracker: Tracker) -> None:
    """The run's stepper lets go of its step control and of its compiled corrector once the run is recorded (each
    refers back to the stepper: left as they are, each run's objects - its stepper, evaluations, rows - wait for the
    cyclic garbage collector, whose collections every few tens of runs cost ~25 us per run, GIL held; unlinked, they
    go when the run ends, in its thread). Nothing reads the stepper after the run: the record holds what it needs of
    it."""
    stepper = tracker.stepper
    if getattr(stepper, "control", None) is not None:  # (the default mode's strict steppers have one)
        stepper.control = None
    if getattr(stepper, "corrector", None) is not None:  # (kinredund.tracking.compiled_correct.CoreCorrector)
        stepper.corrector = None
