"""Joint-level inverse kinematics: poses, and constrained minima of a performance index (Chapter 4.2,
Appendix D).

:func:`solve_ik` solves g(theta) = x (Eq. 4.1) for a pose or point target, or, given an index z, the
constrained problem of Eq. (4.3),

    min z(theta)   subject to   g(theta) = x,

by the orthogonal-decomposition algorithm of Appendix D (:mod:`kinredund.ik.newton`). This is how the
thesis finds the starting configuration of a resolved-rate run (Section 4.2, Examples 4.1-4.3). The
result reports both optimality conditions:

- first order, the normality condition (4.5)/(D.9)/(D.30): the gradient of z projected on the null
  space of the constraint Jacobian vanishes, ``normality_residual`` = ||L^T grad z||;
- second order, Eq. (D.33): L^T (Hess z + Lambda) L is positive definite, Lambda = d(K^T lambda*)/dtheta
  with lambda* the least-squares multipliers of K^T lambda* = -grad z (Eqs. 4.33, 4.37; on the null
  space of K this equals the Hessian of lambda^T g of the closure equations, Eq. 4.26).

Joint limits: ``bounds=True`` keeps every iterate within them (with an index, box-constrained QP
steps, :mod:`kinredund.ik.qp`; pose-only, joints held at a limit and the rest clipped into them,
:mod:`kinredund.ik.newton`); a seed outside them is projected into them and the result's ``notes`` say so
(the seed is never used as it is). ``starts > 1`` runs seeded multi-start and returns the converged
result of lowest z.

Units: theta [rad or m], residuals in the units of the task (m, and dimensionless closure entries),
z [rad^2] for the joint-deviation indices, times [s].
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from time import perf_counter

import numpy as np

from kinredund.errors import SIZES, TaskError, check_count, check_flag, check_positive, check_size
from kinredund.ik.common import Setup, StartOutcome
from kinredund.ik.compiled import pick
from kinredund.ik.newton import run_start
from kinredund.ik.optimality import (  # noqa: F401  (check_optimality, check_index_at: importable here too)
    Optimality,
    check_index_at,
    check_optimality,
    ik_target,
    optimality_at,
    second_order,
)
from kinredund.ik.qp import BoxStep
from kinredund.indices import Index
from kinredund.kinematics.angles import turn_into_limits
from kinredund.model.robot import check_robot
from kinredund.tasks import task_residual

#: residuals are never asked to be smaller than this many units of round-off times the target scale
ROUNDING = 64.0 * float(np.finfo(float).eps)


@dataclass(frozen=True)
class IKResult:
    """The outcome of :func:`solve_ik`.

    Attributes:
        q: the joint vector found (the closest one when not converged) [rad or m].
        converged: residual < tol (for pose tasks the 6-D error [log(Q Q_d^T); p - p_d] too: the
            closure 7-vector alone is insensitive to some rotation errors near half-turn targets)
            and, with an index, normality residual < tol.
        iterations: iterations of the returned start.
        residual: ||g(q) - x||, the closure 7-vector of Eq. (2.13) for pose tasks.
        normality_residual: ||L^T grad z||, Eqs. (D.9)/(D.30) (with bounds: the KKT residual including
            the multipliers of the limits that hold); 0.0 without an index. For a converged result this
            and the second-order fields come from the last iteration (L the null space of its G, which
            equals K[rows] up to O(||e||), :meth:`kinredund.tasks.Task.ik_residual`); :func:`check_optimality`
            evaluates them on K itself.
        objective: z(q); 0.0 without an index.
        reduced_hessian_pd: Eq. (D.33): L^T (Hess z + Lambda) L positive definite (False without an
            index: there is nothing to check).
        reduced_hessian_min_eig: its smallest eigenvalue (inf when the null space is empty, nan
            without an index).
        reason: "" when converged, else why not (``"timeout"``, a stall, ``max_iter``).
        starts: how many starts were run.
        time_s: wall time of the whole call [s].
        notes: remarks that are not failures (e.g. a seed projected into the joint limits).
    """

    q: np.ndarray
    converged: bool
    iterations: int
    residual: float
    normality_residual: float
    objective: float
    reduced_hessian_pd: bool
    reduced_hessian_min_eig: float
    reason: str
    starts: int = 1
    time_s: float = 0.0
    notes: str = ""

    @property
    def cause(self) -> str:
        """``reason`` with its numbers (the residual, time or count it stopped at) replaced by ``#``: the kind of stop,
        comparable between two runs that stop alike at points a rounding apart ("" when converged)."""
        return _NUMBER.sub("#", self.reason)


#: a number in a stop's reason (IKResult.cause)
_NUMBER = re.compile(r"-?\d[\d.]*(e[-+]?\d+)?")

#: the most starts one call runs (each is a whole local solve: a typo such as 1e8 would run for days);
#: use ``timeout`` to bound a search by time instead (kinredund.errors.SIZES holds every such limit)
MAX_STARTS = SIZES["starts"][0]


def _check_options(robot, starts, tol, max_iter, timeout, seed, bounds) -> None:
    check_robot(robot)
    check_flag(bounds, "bounds", TaskError)
    check_size(starts, "starts", "starts", TaskError)  # a long search is bounded by timeout= instead
    check_count(seed, 0, "seed (of numpy.random.default_rng)", TaskError)
    check_count(max_iter, 1, "max_iter", TaskError)
    check_positive(tol, "tol", TaskError)
    if timeout is not None and (isinstance(timeout, bool) or not (isinstance(timeout, (int, float)) and timeout > 0)):
        raise TaskError(f"timeout must be None or a number of seconds > 0, got {timeout!r}")
    if robot.nq < robot.task_dim:
        raise TaskError(
            f"{robot.name} has {robot.nq} joints, fewer than the {robot.task_dim} of its {robot.task!r} task: "
            "use robot.with_task('position') or robot.with_task('planar')"
        )


#: converged starts whose z differ by less than this times 1 + |z| count as equal minima (the first is returned): two
#: starts that reach the same minimum stop at points ~tol apart, whose z differ by ~|lambda| tol, so the choice
#: between them would otherwise be the rounding's (and differ between the backends)
Z_TIE = 1e-9

#: multi-start samples of a pose-only solve (index=None) leave out this fraction of each joint range at
#: either end: local solves from the middle of the ranges succeeded more often in a one-off measurement
#: on the Panda with bounds (hardest targets; no benchmark reproduces it)
POSE_SAMPLE_MARGIN = 0.2
#: multi-start samples are drawn this many at a time
SAMPLE_BATCH = 16


def _wrap_into_limits(robot, q: np.ndarray, index: Index | None) -> tuple[np.ndarray, list[int]]:
    """Turn revolute joints outside their limits by multiples of 2 pi into them (the pose does not
    change), one joint at a time and only where z and grad z stay the same. Returns (q, joints turned)."""
    outside = np.flatnonzero(robot.revolute & ((q < robot.lower) | (q > robot.upper)))
    if outside.size == 0:
        return q, []
    z0, g0 = (0.0, None) if index is None else index.evaluate(q)[:2]
    into, inside = turn_into_limits(q, robot.lower, robot.upper)  # the smallest turns in
    turned, done = q.copy(), []
    for i in outside:
        if not inside[i]:
            continue
        trial = turned.copy()
        trial[i] = into[i]
        if index is not None:
            z1, g1 = index.evaluate(trial)[:2]
            if abs(z1 - z0) > 1e-14 * (1.0 + abs(z0)) or not np.allclose(g1, g0, rtol=0.0, atol=1e-14):
                continue
        turned, done = trial, [*done, int(i)]
    return turned, done


def solve_ik(
    robot,
    target,
    index: Index | None = None,
    q0=None,
    *,
    bounds: bool = False,
    starts: int = 1,
    seed: int = 0,
    tol: float = 1e-10,
    max_iter: int = 200,
    timeout: float | None = None,
    backend: str | None = None,
) -> IKResult:
    """Solve g(theta) = x, or min z(theta) s.t. g(theta) = x (Eq. 4.3), by the method of Appendix D.

    Args:
        robot: a :class:`kinredund.Robot`; its task kind sets what ``target`` is.
        target: (x, y) for planar, p (3,) for position, a 4x4 pose (or (Q, p)) for pose tasks [m], or
            a :class:`kinredund.tasks.Target`.
        index: the performance index z (:mod:`kinredund.indices`); None solves the pose only.
        q0: the first seed (n,); default ``robot.home``.
        bounds: keep the joints within the robot's limits. A seed outside them is projected into them
            (recorded in ``notes``).
        starts: number of starts: q0, then ``starts - 1`` samples of ``np.random.default_rng(seed)``
            uniform in the limits (unbounded joints: [-pi, pi] or [-1, 1] m; pose-only solves leave
            out :data:`POSE_SAMPLE_MARGIN` of each range at either end). With an index the converged
            result of lowest z is returned (the first of those within :data:`Z_TIE` of it; the global
            constrained minimum when enough starts are run); without one, the first converged. While
            other starts remain (or with a timeout), a pose-only start whose squared error has not
            halved in 3 iterations (20 at most, 60 for a start already close and still gaining) is
            abandoned for the next one, after one try at turning a joint stuck at a limit through a
            full turn (:mod:`kinredund.ik.newton`).
        seed: seed of the multi-start samples, an integer >= 0.
        tol: convergence tolerance on the residual and, with an index, on the normality residual. It
            is raised to the round-off floor (64 eps times the target scale, and 1e-13 (1 + |grad z|)
            for the normality residual) when smaller.
        max_iter: iterations per start (a start also stops when its residual has not halved in
            20 iterations with an index, or, pose-only, its squared error has not decreased in 10).
        timeout: wall-time budget of the whole call [s]; when it runs out, the best converged result so
            far is returned, else ``converged=False`` with reason ``"timeout"``.
        backend: where the constrained iteration (with an index) runs: ``"auto"`` (the compiled core where it
            loads and supports the problem), ``"compiled"`` (an OptionError where it cannot) or ``"python"``;
            None reads the environment variable ``KINREDUND_BACKEND`` (default ``"auto"``). The same results
            either way (:mod:`kinredund.ik.compiled`); pose-only solves are Python's.

    Returns:
        An :class:`IKResult`. An unreachable target gives ``converged=False``, the configuration with
        the smallest residual found and a reason. A start that was on the target and left it (an index
        unbounded below along the self-motion, e.g. a negative-definite one) returns its lowest-z point
        on the target, never one worse than its seed; an index that turns non-finite stops the start at
        the last point where it was finite; a start on the target at a singular configuration is
        converged when the gradient vanishes on the SVD null space there. Every reason says which.

    Raises:
        OptionError: ``backend="compiled"`` where the compiled core cannot run the problem; ``robot`` not a Robot.
        ChoiceError: an unknown ``backend``.
        TaskError: wrong-size or non-finite target, a target for another task kind, bad options (``starts``
            outside 1..:data:`MAX_STARTS`, a negative ``seed``, ``bounds`` not a bool), an index of the wrong size.
        JointVectorError: q0 of the wrong size or non-finite.
    """
    t0 = perf_counter()
    _check_options(robot, starts, tol, max_iter, timeout, seed, bounds)
    tgt = ik_target(robot, target)
    q0 = robot.home.copy() if q0 is None else robot.check_q(q0, "q0").copy()
    check_index_at(robot, index, q0)
    notes = ""
    if bounds and not np.all((q0 >= robot.lower) & (q0 <= robot.upper)):
        bad = np.flatnonzero((q0 < robot.lower) | (q0 > robot.upper)).tolist()
        q0 = np.clip(q0, robot.lower, robot.upper)
        notes = f"q0 was outside the joint limits at joints {bad}: projected into them"
    if index is not None and robot.nq == robot.task_dim:  # n = m: no self-motion for z to act on (Eq. 4.3)
        index, notes = None, "; ".join(filter(None, [notes, (
            f"n = m = {robot.nq}: the task leaves no redundancy, so the index is irrelevant; the solution "
            "nearest the seed (of the first converged start) is returned")]))
    res = task_residual(tgt)
    setup = Setup(
        kin=robot.kinematics, res=res, index=index, lower=np.asarray(robot.lower), upper=np.asarray(robot.upper),
        bounds=bool(bounds), rtol=max(float(tol), ROUNDING * (1.0 + res.scale())), tol=float(tol),
        max_iter=int(max_iter), deadline=None if timeout is None else t0 + float(timeout),
        box=BoxStep(robot.nq, res.m) if bounds and index is not None else None,  # pose-only: no QP
        revolute=robot.revolute, compiled=pick(robot, res, index, backend),
    )
    rng = box = None
    outcomes: list[tuple[StartOutcome, float]] = []
    for k in range(int(starts)):
        if k == 0:
            qs = q0
        else:
            if (k - 1) % SAMPLE_BATCH == 0:  # the same draws as one at a time, fewer calls
                if rng is None:
                    rng = np.random.default_rng(seed)
                    box = robot.sample_box(POSE_SAMPLE_MARGIN if index is None else 0.0)
                batch = rng.uniform(*box, size=(min(SAMPLE_BATCH, int(starts) - k), robot.nq))
            qs = batch[(k - 1) % SAMPLE_BATCH]
        setup.quick_exit = k < starts - 1 or timeout is not None
        out = run_start(setup, qs)
        z = index.value(out.q) if (index is not None and out.converged) else 0.0
        outcomes.append((out, z))
        if out.reason == "timeout" or (index is None and out.converged):
            break
    converged = [(o, z) for o, z in outcomes if o.converged]
    if converged:
        z_min = min(z for _, z in converged)  # the first of equal minima (to Z_TIE: the same minimum found again)
        best = next(o for o, z in converged if z <= z_min + Z_TIE * (1.0 + abs(z_min)))
    else:
        best = min(outcomes, key=lambda oz: oz[0].residual)[0]
        if outcomes[-1][0].reason == "timeout":
            best = StartOutcome(best.q, False, best.iterations, "timeout", best.residual)
    if not best.converged:  # a start stuck near a spurious zero of e (the tool axis reversed) says so
        why = res.spurious(*robot.kinematics.pose(best.q))
        if why and why not in best.reason:
            best = StartOutcome(best.q, False, best.iterations, f"{best.reason}; {why}", best.residual)
    q, wrapped = _wrap_into_limits(robot, best.q, index)
    if wrapped:
        notes = "; ".join(filter(None, [notes, f"joints {wrapped} turned by multiples of 2 pi into their limits"]))
        best = StartOutcome(q, best.converged, best.iterations, best.reason, res.residual(*robot.kinematics.pose(q)))
    if index is None:  # nothing else to check: skip the second kinematics pass
        return IKResult(
            q=best.q, converged=best.converged, iterations=best.iterations, residual=best.residual,
            normality_residual=0.0, objective=0.0, reduced_hessian_pd=False, reduced_hessian_min_eig=float("nan"),
            reason=best.reason, starts=len(outcomes), time_s=perf_counter() - t0, notes=notes,
        )
    if best.terms is None:  # not converged, or turned into the limits: evaluate the report at q
        opt = optimality_at(robot, res, best.q, index, bounds)
    else:  # the converged iteration's terms: no second kinematics pass
        opt = second_order(best.residual, best.terms, res.rows)
    converged, reason = best.converged, best.reason
    if not (np.isfinite(opt.normality_residual) and np.isfinite(opt.objective)):  # never a silent NaN
        converged = False
        reason = "; ".join(filter(None, [reason, "the index is not finite at the point returned"]))
    return IKResult(
        q=best.q, converged=converged, iterations=best.iterations, residual=opt.residual,
        normality_residual=opt.normality_residual, objective=opt.objective,
        reduced_hessian_pd=opt.reduced_hessian_pd, reduced_hessian_min_eig=opt.reduced_hessian_min_eig,
        reason=reason, starts=len(outcomes), time_s=perf_counter() - t0, notes=notes,
    )
