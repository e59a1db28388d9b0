"""What a finished tracking run says about itself (issue 26): a result that ran to its end is not yet a
success. :func:`kinredund.tracking.track` calls these on every record:

- :func:`say_open_loop`: a closed path whose joints do not return within
  :data:`~kinredund.trajectory.LOOP_CLOSURE_TOL` at the end of a loop, with its cause;
- :func:`say_rate_burst`: a step whose joints move far more than the run's typical step and that does not
  shrink in proportion when the time step is halved: rates that grow without bound under refinement (a
  square-root point where a joint bound releases and the bounded optimum is not strongly stable, or a
  near-singularity), never passed as an ordinary step.

The record's loop drifts and fastest rates, which these and the speed checks read, are :func:`record_extremes`'s
(:meth:`kinredund.tracking.recorder.Recorder.trajectory` calls it once per record).

Each puts its message in the record's ``meta`` and warns (:class:`~kinredund.trajectory.RecordWarning`).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable

import numpy as np

from kinredund.errors import KinredundError, OptionError
from kinredund.kinematics.angles import loop_drifts
from kinredund.tracking.compiled import load_core
from kinredund.trajectory import LOOP_CLOSURE_TOL, RecordWarning, Trajectory

#: a step whose largest joint change is more than this many times the run's median step is a burst
#: candidate, checked by running again with half the time step (smooth motions vary far less than this
#: within a run of tens of steps per loop; the issue's bursts were 60x the median)
BURST_RATIO = 10.0
#: steps within this factor of the largest count as the largest, and the first of them is named: the same step of two
#: loops differs by rounding only (~1e-15), which named one loop's on one backend and the other's on the other
BURST_TIE = 1e-9
#: halving the time step shrinks a smooth motion's largest step 2x, a square-root point's (q ~ sqrt(t - t*))
#: sqrt(2) = 1.41x; a candidate whose largest step shrinks by less than this is a rate burst
REFINED_SHRINK = 1.7
#: ... and one whose largest step shrinks by less than this is a jump (a step independent of the time step)
JUMP_SHRINK = 1.2
#: fewest steps for a median to mean something
MIN_STEPS = 8


def open_loop_cause(scheme: str, mode: str) -> str:
    """Why a closed path's joints did not close, by the scheme that ran (the default mode's optimal schemes
    hold every point on a branch of constrained minima of z to ~1e-12, so there the branch is at fault)."""
    if scheme in ("pseudoinverse", "liegeois"):
        return (f"the {scheme} baseline is not cyclic (it does not follow a constrained minimum of z): use "
                "scheme='augmented', which is")
    if mode == "thesis":
        return ("the explicit steps of thesis mode (Eq. 4.29) drift off the optimum: use mode='default', which "
                "corrects every step onto it")
    return ("the branch of minima followed is not periodic: its continuation around the loop ends at another "
            "local minimum of z; use kinredund.plan(robot, path, index), which chooses a closed walk")


def say_open_loop(traj: Trajectory, scheme: str, mode: str) -> None:
    """A closed path whose joints do not return: the cause in ``meta["loop_not_closed"]`` and a
    :class:`~kinredund.trajectory.RecordWarning` (never a plain success)."""
    if traj.loop_closed is not False:
        return
    why = (f"the joints do not return at the end of a loop of the closed path: drift {max(traj.loop_drift):.3g} rad "
           f"(at most {LOOP_CLOSURE_TOL:g} for a closed joint path): {open_loop_cause(scheme, mode)}")
    traj.meta["loop_not_closed"] = why
    warnings.warn(why, RecordWarning, stacklevel=3)


def largest_steps(q: np.ndarray) -> np.ndarray:
    """The largest joint change of each step of a record, max_j |q[k+1, j] - q[k, j]| [rad or m] (by joint rows: a
    maximum over a record's few joints, row by row, costs more than over its steps)."""
    qT = np.ascontiguousarray(q.T)
    d = qT[:, 1:] - qT[:, :-1]
    return np.abs(d, out=d).max(axis=0)


def burst_candidate(q: np.ndarray) -> int | None:
    """The step (its index k: from row k to k + 1) whose largest joint change is more than
    :data:`BURST_RATIO` times the run's median one, the largest such (the first within :data:`BURST_TIE` of it); None
    where there is none. By the compiled core where it is installed (``_core.burst_candidate``: the same arithmetic),
    else by numpy."""
    if len(q) < MIN_STEPS + 1:
        return None
    core = load_core()
    if core is not None and hasattr(core, "burst_candidate"):  # the same step in one call (src/core/record_checks.cpp)
        k = core.burst_candidate(np.ascontiguousarray(q, float), BURST_RATIO, BURST_TIE)
        return None if k < 0 else k
    d = largest_steps(q)
    largest = d.max()
    if np.isnan(largest):
        return None
    k = int(np.flatnonzero(d >= largest * (1.0 - BURST_TIE))[0])
    return k if largest > BURST_RATIO * median(d) else None


def median(d: np.ndarray) -> float:
    """``np.median`` of a 1-D array (the middle value, or the mean of the middle two: the same float) by one
    partition, without np.median's general machinery, which costs more than the partition on a run's steps. (With a
    NaN among them it may differ from np.median's NaN, but burst_candidate's largest step is then a NaN, no burst.)"""
    h = len(d) // 2
    if len(d) % 2:
        return float(np.partition(d, h)[h])
    part = np.partition(d, (h - 1, h))
    return float((part[h - 1] + part[h]) / 2.0)


def say_rate_burst(traj: Trajectory, refined: Callable[[], Trajectory]) -> None:
    """A burst candidate (:func:`burst_candidate`) checked by ``refined()``, the same run with half the time
    step: where its largest step shrinks by less than :data:`REFINED_SHRINK`, ``meta["rate_burst"]`` names
    it (time, joint, step, how it refines) and a :class:`~kinredund.trajectory.RecordWarning` says so."""
    k = burst_candidate(traj.q)
    if k is None:
        return
    d = largest_steps(traj.q)
    j = int(np.argmax(np.abs(traj.q[k + 1] - traj.q[k])))
    where = (f"joint {j} moves {d[k]:.3g} in the step from t = {traj.t[k]:.6g} s to {traj.t[k + 1]:.6g} s, "
             f"{d[k] / float(np.median(d)):.3g} times the run's median step")
    try:
        fine = refined()
    except OptionError as err:  # twice the steps is more than a run may have: said, not checked
        why = f"{where}; not checked with half the time step ({err}): possibly a rate burst"
    except KinredundError as err:  # its message without a diverged iterate's q
        stop = str(err).rsplit("; q = ", 1)[0]
        why = f"{where}; the run with half the time step stopped ({stop}): the motion is not resolved there"
    else:
        shrink = d[k] / float(largest_steps(fine.q).max())
        if shrink >= REFINED_SHRINK:
            return  # resolved: a fast but ordinary stretch (the speeds against the limits say the rest)
        kind = ("a jump: the joints move as far however short the step (the path jumps, or the joints jump "
                "to another branch)") if shrink < JUMP_SHRINK else (
            "a rate burst, joint rates that grow without bound under refinement (a square-root point where a "
            "joint bound releases and the bounded optimum is not strongly stable, or a near-singularity)")
        why = (f"{where}, and only {shrink:.3g} times less with half the time step (2 for a smooth motion, 1.41 at "
               f"a square-root point, 1 at a jump): {kind}; no time law keeps this motion within speed limits")
    traj.meta["rate_burst"] = why
    warnings.warn(why, RecordWarning, stacklevel=3)


def record_extremes(q: np.ndarray, qdot: np.ndarray | None, revolute: np.ndarray, steps_per_loop: int | None,
                    loops: int | None) -> tuple[np.ndarray | None, list[float] | None]:
    """(the loop drifts (loops,) [rad or m]: :func:`~kinredund.kinematics.angles.loop_drifts`, None for an open run
    (``loops`` None); each joint's largest |qdot| [rad/s] over the run's points, as floats, None without ``qdot``), in
    one call of the compiled core where it is installed (``_core.record_extremes``, ``src/core/record_checks.cpp``: the
    same numbers), else by numpy. ``q``, ``qdot``: float (N, n) arrays, C-contiguous."""
    core = load_core()
    if core is not None and hasattr(core, "record_extremes"):
        n = q.shape[1]
        drift, fastest = np.empty(0 if loops is None else loops), np.empty(n)
        core.record_extremes(q, _NO_RATES[n] if qdot is None else qdot, _revolute(revolute),
                             0 if loops is None else steps_per_loop, drift, fastest)
        return None if loops is None else drift, None if qdot is None else fastest.tolist()
    drift = None if loops is None else loop_drifts(q, steps_per_loop, loops, revolute)
    fastest = None if qdot is None else np.abs(qdot.T, order="C").max(axis=1).tolist()  # (a joint's speeds in a row)
    return drift, fastest


class _NoRates(dict):
    """(0, n) arrays by n, made once each (read-only: shared)."""

    def __missing__(self, n: int) -> np.ndarray:
        out = self[n] = np.zeros((0, n))
        out.flags.writeable = False
        return out


_NO_RATES = _NoRates()


def _revolute(revolute) -> np.ndarray:
    """The robot's revolute mask as the core takes it (a C-contiguous bool array; the robot's own where it is one)."""
    if type(revolute) is np.ndarray and revolute.dtype == bool and revolute.flags.c_contiguous:
        return revolute
    return np.ascontiguousarray(revolute, dtype=bool)
