"""Diagnosing a tracking failure: the cause, the watched quantities and a partial record (issue 15).

- :func:`loadable_name`: what :func:`kinredund.load_robot` reloads the robot of a record from;
- :func:`point_record`: a one-point :class:`~kinredund.trajectory.Trajectory` (a failure before the first
  step still carries a record that plays);
- :func:`task_residual_min`: the smallest task residual reachable at a time (Levenberg-Marquardt on
  |r|^2 from a configuration): nonzero where the path has left the workspace;
- :func:`start_failure`, :func:`step_too_long`: the :class:`~kinredund.errors.TrackingError` of a start
  that cannot be corrected onto a constrained minimum, and of a step longer than the path's period;
- :func:`branch_end`: where a branch followed ends inside the step control's floor, and what ended it;
  :func:`constraints_dependent`: whether a rank loss is the constraints' (LICQ) rather than the arm's.
"""

from __future__ import annotations

import math

import numpy as np

from kinredund.errors import PathError, SingularityError, TrackingError
from kinredund.kinematics import closure
from kinredund.model.robot import Robot
from kinredund.tasks import get_task
from kinredund.tracking.ahead import EMPTY, core_orientation
from kinredund.tracking.point import Evaluator
from kinredund.tracking.watch import SIGMA_FLOOR, exact, reduce
from kinredund.trajectory import Trajectory

#: a path point whose smallest reachable task residual exceeds this (times max(1, |p_d|) [m]) is out of
#: reach: the stepper's own on-path bar (1e-6 of the path's scale)
REACH_TOL = 1e-6

#: where the corrector fails below the floor unannounced, the branch is followed toward the failed time by this many
#: bisections, down to BRANCH_RESOLUTION dt, and a quantity that has fallen below BRANCH_FALL of its value at the
#: nearest good point by the branch's end names the stop (:func:`branch_end`)
BRANCH_BISECTIONS, BRANCH_RESOLUTION, BRANCH_FALL = 40, 1e-9, 0.1
#: ... and a point within BRANCH_JUMP dt past the end that the watch's floors reject (no minimum there) names it too
BRANCH_JUMP = 1e-6
#: a sub-step of the branch's end search that moves the joints by more than this times its length times the larger
#: of the rates at its ends has jumped onto another branch (a move along one branch is at most the largest rate
#: on it times the length)
BRANCH_SPEED = 2.0


def loadable_name(robot: Robot) -> str:
    """What :func:`kinredund.load_robot` reloads the robot from: its ``source`` (name or URDF file, with the
    options it was loaded with) if load_robot made it, else its name if known, else its URDF file."""
    from kinredund.model.loader import known_robots

    if robot.source is not None:
        return robot.source
    if robot.name in known_robots() or robot.urdf_path is None:
        return robot.name
    return str(robot.urdf_path)


def point_record(ev: Evaluator, q: np.ndarray, t: float, *, scheme: str, mode: str,
                 meta: dict | None = None) -> Trajectory:
    """The one-point :class:`~kinredund.trajectory.Trajectory` at (q, t) (it plays: one frame)."""
    pt = ev.point(np.asarray(q, float), t, need_dJ=False)
    task = get_task(ev.task)
    Q_d = pt.sample.Q[None] if task.has_orientation else None
    errors = task.errors_many(pt.Q[None], pt.p[None], Q_d, pt.sample.p[None])
    zeros = np.zeros(1)
    return Trajectory(robot=loadable_name(ev.robot), task=task.name, t=np.array([float(t)]), q=np.array([q], float),
                      p=pt.p[None].copy(), p_desired=pt.sample.p[None].copy(), scheme=scheme, mode=mode,
                      solver=(), position_error=errors["position_error"], trace_error=errors.get("trace_error", zeros),
                      vect_error=errors.get("vect_error", zeros), axis_error=errors.get("axis_error"),
                      loop_period=ev.path.period, meta=dict(meta or {}, partial=True))


def task_residual_min(ev: Evaluator, q: np.ndarray, t: float, max_iter: int = 200) -> tuple[float, np.ndarray]:
    """(min |r|, the configuration reaching it) at time t from q: Levenberg-Marquardt on 1/2 |r|^2 (task only).

    The damping mu grows by 4 on a rejected step and shrinks by 3 on an accepted one; the iteration
    ends where the gradient J^T r or the step is negligible. Where the path point is reachable the
    residual falls to rounding level (quadratic convergence near a regular solution); where it is not, it
    stays at the distance the arm cannot close (the workspace boundary's Gauss-Newton minimum).

    Where the compiled core is installed and runs the problem (the augmented form, nq = nv), the same iteration
    runs there (``StepCore.residual_min``, the GIL released; the same operations on r and J to rounding, whichever
    backend tracked), else in Python with the evaluator's points.
    """
    q = np.array(q, float)
    core = _residual_core(ev)
    if core is not None:
        s = ev.sample(t)
        res, q_min = core.residual_min(q, s.p, s.v, *core_orientation(s), max_iter)
        return float(res), q_min
    pt = ev.point(q, t, need_dJ=False)
    f = float(pt.r @ pt.r)
    mu = 1e-3
    n = len(q)
    for _ in range(max_iter):
        J, r = pt.J, pt.r
        g = J.T @ r
        if not math.isfinite(f) or float(g @ g) <= 1e-30 or f <= 1e-30:
            break
        dq = np.linalg.solve(J.T @ J + mu * np.eye(n), -g)
        trial = ev.point(q + dq, t, need_dJ=False)
        f_new = float(trial.r @ trial.r)
        if f_new < f:
            q, pt, f, mu = q + dq, trial, f_new, max(mu / 3.0, 1e-12)
            if float(dq @ dq) <= 1e-28:
                break
        else:
            mu *= 4.0
            if mu > 1e12:
                break
    return math.sqrt(f), q


def _residual_core(ev: Evaluator):
    """A ``StepCore`` of ``ev``'s robot and task for :func:`task_residual_min` (its index terms unused), or None where
    the compiled core is not installed or cannot run it (another formulation than augmented, nq != nv)."""
    from kinredund.tracking.compiled import load_core
    from kinredund.tracking.compiled_start import TASK_CODES, core_hermite
    from kinredund.tracking.predictor_corrector import predictor_weights

    core = load_core()
    model = ev.robot.model
    if core is None or ev.formulation != "augmented" or model.nq != model.nv or ev.task not in TASK_CODES:
        return None
    n = model.nv
    hermite = core_hermite(predictor_weights(1.0))
    return core.StepCore(model, int(ev.robot.ee_frame_id), TASK_CODES[ev.task], False, np.ones(n), np.zeros(n), False,
                         1e-12, 1.0, hermite, EMPTY, EMPTY)


def out_of_reach(ev: Evaluator, q: np.ndarray, times, restarts: int = 12, seed: int = 0) -> tuple[bool, float, float]:
    """(out of reach at any of ``times``, a smallest residual [m], a time [s]): where some time is out of reach, the
    farthest such residual and its time; where every time is within reach, the largest residual and the first time
    (the residuals are then rounding, whose largest says nothing of the path).

    From q first, then (where that leaves a residual) from ``restarts`` seeded perturbations of q (0.3 and
    1 rad, clipped into the robot's limits): Levenberg-Marquardt from the last good point alone can end
    on a singular configuration (J^T r = 0 with r != 0) although the point is reachable past the
    singularity. The task-only residual uses the displacement form, whose J is the Jacobian of r.
    """
    if ev.formulation != "augmented":
        ev = Evaluator(ev.robot, ev.path, ev.index, "augmented")
    rng = np.random.default_rng(seed)
    lo, hi = np.maximum(ev.robot.lower, -1e3), np.minimum(ev.robot.upper, 1e3)
    worst, worst_far, at = 0.0, 0.0, float(times[0])  # worst_far: the largest residual out of reach (0: none)
    for tp in times:
        scale = max(1.0, float(np.abs(ev.sample(tp).p).max()))
        res, _ = task_residual_min(ev, q, tp)
        for k in range(restarts):
            if res <= REACH_TOL * scale:
                break
            start = np.clip(q + (0.3 if k % 2 == 0 else 1.0) * rng.standard_normal(len(q)), lo, hi)
            res = min(res, task_residual_min(ev, start, tp)[0])
        if not res <= worst:
            worst = res
        if not res <= REACH_TOL * scale and not res <= worst_far:  # out of reach there, the farthest so far
            worst_far, at = res, float(tp)
    if worst_far > 0.0:  # out of reach: the farthest such residual and its time
        return True, worst_far, at
    return False, worst, at


def watched_at(stepper, q: np.ndarray | None = None, t: float | None = None) -> dict:
    """The watched quantities at (q, t) (default: the stepper's current point), computed exactly.

    ``sigma_min_J`` and ``sigma_max_J`` (the scale of the watch's kinematic floor), ``reduced_hessian_min``
    (on the null space of J and of the fixed joints, when the stepper has a ``fixed`` mask),
    ``task_residual`` [m] and ``normality_residual`` (|(1 - J^+ J) grad z| over the free joints: a joint
    held on a bound takes its multiplier's share of grad z).
    """
    q = stepper.q if q is None else q
    t = stepper.t if t is None else t
    pt = stepper.evaluate(q, t)
    out = {"task_residual": float(np.abs(pt.r).max())}
    if stepper.ev.index is None:
        return out
    M = pt.system(stepper.lam)[0]
    fixed = getattr(stepper, "fixed", None)
    J_free, M_free = reduce(pt.J, M, fixed)
    sigma, eig, _ = exact(J_free, M_free)
    # the normality residual on the free joints: a joint held on a bound carries its multiplier in grad z
    free = slice(None) if fixed is None else ~np.asarray(fixed, bool)
    grad = pt.grad[free]
    Z = np.linalg.qr(J_free.T, mode="complete")[0][:, J_free.shape[0]:]
    out.update(sigma_min_J=sigma, sigma_max_J=float(np.linalg.norm(J_free, 2)), reduced_hessian_min=eig,
               normality_residual=float(np.linalg.norm(Z.T @ grad)))
    return out


def start_failure(stepper, q0: np.ndarray, err: Exception) -> TrackingError:
    """The error of a start the default mode's corrector cannot put on a constrained minimum.

    ``non_optimal_start`` where q0 is on the path (the stepper checked it) but not at the constrained
    optimum (its normality residual above 1e-8 of max(1, |grad z|)); at an optimal start whose R is
    singular, ``kinematic_singularity`` where sigma_min(J) is at the watch's kinematic floor
    (:data:`~kinredund.tracking.watch.SIGMA_FLOOR` of max(1, sigma_max(J))), else ``fold``.
    """
    ev = stepper.ev
    stepper.q, stepper.t = q0, stepper.t0
    watched = watched_at(stepper, q0, stepper.t0)
    if getattr(err, "sigma_min", None) is not None:
        watched["sigma_min_R"] = float(err.sigma_min)
    grad = ev.gradient(q0, stepper.t0)
    optimal = watched.get("normality_residual", 0.0) <= 1e-8 * max(1.0, float(np.linalg.norm(grad)))
    cause = "non_optimal_start"
    if optimal:
        floor = SIGMA_FLOOR * max(1.0, watched.get("sigma_max_J", 1.0))  # the watch's own (Watch.floors)
        cause = "kinematic_singularity" if watched.get("sigma_min_J", math.inf) <= floor else "fold"
    partial = point_record(ev, q0, stepper.t0, scheme=ev.formulation, mode="default")
    return TrackingError(f"the start at t = {stepper.t0:.6g} s cannot be corrected onto a constrained minimum of z "
                         f"({cause}; normality residual {watched.get('normality_residual', float('nan')):.3g}): {err}",
                         cause=cause, t=stepper.t0, q=q0, watched=watched, partial=partial)


def _watched_start(ev: Evaluator, q: np.ndarray, t: float) -> dict:
    """The watched quantities at a start (lambda by least squares, Eqs. 4.11-4.12)."""
    from kinredund.tracking.linalg import multipliers

    pt = ev.point(q, t)
    out = {"task_residual": float(np.abs(pt.r).max())}
    lam = multipliers(pt.J, pt.grad)[0]
    sigma, eig, _ = exact(pt.J, pt.system(lam)[0])
    return out | {"sigma_min_J": sigma, "reduced_hessian_min": eig}


def singular_start(ev: Evaluator, q0: np.ndarray, t0: float, why: str, *, mode: str) -> TrackingError:
    """The error of a start where J has lost rank (``kinematic_singularity``: the arm stretched or folded)."""
    pt = ev.point(q0, t0, need_dJ=False)
    sJ = np.linalg.svd(pt.J, compute_uv=False)
    watched = {"task_residual": float(np.abs(pt.r).max()), "sigma_min_J": float(sJ[-1]), "sigma_max_J": float(sJ[0])}
    return TrackingError(f"the start is a kinematic singularity: J has lost rank there ({why}): start "
                         "from another configuration on the path, or move the path away from where the arm is "
                         "stretched or folded",
                         cause="kinematic_singularity", t=t0, q=q0, watched=watched,
                         partial=point_record(ev, q0, t0, scheme=ev.formulation, mode=mode))


def step_too_long(ev: Evaluator, q0: np.ndarray, t0: float, dt: float, *, mode: str) -> TrackingError:
    """The error of a time step longer than the closed path's period (the path would be aliased)."""
    return TrackingError(f"the time step {dt:.6g} s is longer than the path's period {ev.path.period:.6g} s: "
                         "take at least one step per loop", cause="step_too_long", t=t0, q=q0,
                         watched=_watched_start(ev, q0, t0) | {"dt": float(dt), "period": float(ev.path.period)},
                         partial=point_record(ev, q0, t0, scheme=ev.formulation, mode=mode))


def path_jumps(ev: Evaluator, t_a: float, t_b: float, factor: float = 4.0) -> bool:
    """Does the path's position move from t_a to t_b by more than ``factor`` times its speed allows?"""
    a, b = ev.path(t_a), ev.path(t_b)
    speed = max(float(np.linalg.norm(a.v)), float(np.linalg.norm(b.v)))
    return float(np.linalg.norm(b.p - a.p)) > factor * (t_b - t_a) * speed + 1e-12 * max(1.0, float(np.abs(a.p).max()))


#: a path whose velocity differs from the central difference of its position (step 1e-3 of the failed
#: step, truncation ~1e-7 relative) by more than this fraction of its speed contradicts itself
CONTRADICTION = 1e-3


def path_contradiction(ev: Evaluator, t_a: float, t_b: float) -> str:
    """Why the path's velocity contradicts its motion in the middle of (t_a, t_b) ("" where it does not):
    v against the central difference of p, and where the path has a rotation, omega against
    log(Q(t + h) Q(t - h)^T) / 2h (h = 1e-3 (t_b - t_a): both agree to ~1e-7 on a smooth path)."""
    if not t_b > t_a:
        return ""
    t, h = 0.5 * (t_a + t_b), 5e-4 * (t_b - t_a)
    a, b, c = ev.path(t - h), ev.path(t + h), ev.path(t)
    parts = [("velocity v", (b.p - a.p) / (2.0 * h), c.v)]
    if c.Q is not None:
        parts.append(("angular velocity omega", np.asarray(closure.rotation_log(b.Q @ a.Q.T)[0]) / (2.0 * h), c.omega))
    for name, rate, given in parts:
        gap = float(np.linalg.norm(rate - given))
        if gap > CONTRADICTION * max(float(np.linalg.norm(rate)), float(np.linalg.norm(given))) and gap > 1e-9:
            return (f"the path's {name} at t = {t:.6g} s, {np.round(given, 6).tolist()}, is not the rate of its "
                    f"motion there, {np.round(rate, 6).tolist()}: a self-contradictory path (its function must "
                    "return the derivative of what it returns as the pose)")
    return ""


def explicit_failure(stepper, err: Exception) -> TrackingError:
    """The error of a failed explicit step (thesis mode, the baselines), the stepper at the step's start.

    ``kinematic_singularity`` where J lost rank (or its smallest singular value is below 1e-2 of its
    largest at the last good point: an explicit step past a stretched arm leaves the path instead),
    ``fold`` where R turned singular with J of full rank (an algorithmic singularity), ``out_of_reach``
    where the step left the path and the path point cannot be reached, else ``step_control_exhausted``
    (the explicit schemes have no sub-steps: a finer step may help).
    """
    text = str(err)
    t_next = stepper.t0 + (stepper.k + 1) * stepper.dt
    watched = watched_at(stepper)
    watched["t_failed"] = float(t_next)
    if getattr(err, "sigma_min", None) is not None:
        watched["sigma_min_R"] = float(err.sigma_min)
    pt = stepper.ev.point(stepper.q, stepper.t, need_dJ=False)
    sJ = np.linalg.svd(pt.J, compute_uv=False)
    if "kinematic" in text or sJ[-1] < 1e-2 * sJ[0]:  # J rank-deficient, or nearly so at the last good point
        cause = "kinematic_singularity"
    elif "algorithmic" in text:
        cause = "fold"
    else:
        far, res, _ = out_of_reach(stepper.ev, stepper.q, [t_next])
        watched["reach_residual"] = res
        cause = "out_of_reach" if far else "step_control_exhausted"
    return TrackingError(f"tracking stopped after t = {stepper.t:.6g} s ({cause}): {text}", cause=cause,
                         t=stepper.t, q=stepper.q.copy(), watched=watched)


def on_branch(before, after) -> bool:
    """Did the move from the state ``before`` to ``after`` (a piece of a branch, h = their times' difference) stay on
    one branch? It moves the joints at most :data:`BRANCH_SPEED` h times the larger of the rates at its ends (a move
    along a branch is at most its largest rate times h; one onto another branch moves as far however short h is).
    Not the step control's trapezoidal check, which the rates' own jump where a curvature jumps fails at any h."""
    dq, qd0, qd1 = after.q - before.q, before.qdot, after.qdot
    return float(dq @ dq) <= (BRANCH_SPEED * (after.t - before.t)) ** 2 * max(float(qd0 @ qd0), float(qd1 @ qd1))


def branch_end(ctl, t_fail: float, near: dict, why: str) -> tuple[str, str, dict]:
    """(cause, reason, watched) of a corrector that fails below the floor of the step control ``ctl``
    (:class:`~kinredund.tracking.step_control.StepControl`) with neither quantity predicted to cross.

    The watch extrapolates smooth quantities; where one jumps within a sub-step (a distance row's curvature
    where its witness point passes from a face to an edge, Lagrangian -nu Hess c) and then runs to zero, the
    branch ends inside the floor's sub-step unannounced, and the corrector's iterates beyond it diverge (their
    own words, a singular R far off the path, say nothing of the path). So the branch is followed from the
    nearest good point (the current one) toward ``t_fail`` by :data:`BRANCH_BISECTIONS` bisections (Euler
    sub-steps from the farthest point reached; one that moves the joints more than :data:`BRANCH_SPEED` times its
    length times the larger of the rates at its ends has jumped onto another branch; not the trapezoidal check,
    which the rates' own jump where the curvature jumps fails at any length; one the watch's floors reject is no
    minimum, or J is singular there) and measured exactly at its end: a
    quantity fallen below :data:`BRANCH_FALL` of its value at the nearest good point names the stop (``fold``
    or ``kinematic_singularity``), and so does one below its floor at a corrected point within
    :data:`BRANCH_JUMP` dt past the end (it jumped there), else it is ``step_control_exhausted``. ``watched``:
    the end's time and joints (``branch_end_t``, ``branch_end_q``: a good point, corrected, nearer the failure
    than the sub-steps'). The stepper is left at that end."""
    s = ctl.s
    t_near, lo, hi, end, beyond = s.t, ctl.snapshot(), t_fail, near, None
    for _ in range(BRANCH_BISECTIONS):
        if hi - lo[0].t <= BRANCH_RESOLUTION * s.dt:
            break
        mid = 0.5 * (lo[0].t + hi)
        s.prev.clear()
        try:
            s.euler_to(mid)
            ok = on_branch(lo[0], s)
            w = watched_at(s) if ok else {}
            crossed = ok and ctl.watch.crossed(w.get("sigma_min_J", math.inf),
                                                w.get("reduced_hessian_min", math.inf))
            if crossed:  # no minimum, or J singular (past a fold the corrector may converge onto a saddle)
                beyond, ok = (mid, crossed, w), False
        except (PathError, SingularityError, TrackingError):
            ok = False
        if ok:
            lo, end = ctl.snapshot(), w
        else:
            hi = mid
        ctl.restore(lo)
    words = f"the corrector finds no optimum on the branch followed beyond t = {hi:.9g} s"
    branch = {"branch_end_t": float(s.t), "branch_end_q": s.q.tolist()}
    for cause, key, what in (("fold", "reduced_hessian_min", "the reduced-Hessian eigenvalue"),
                             ("kinematic_singularity", "sigma_min_J", "sigma_min(J)")):
        was, now = near.get(key, math.nan), end.get(key, math.nan)
        if now < BRANCH_FALL * was:
            return cause, (f"{words}: {what} falls from {was:.3g} at t = {t_near:.6g} s to {now:.3g} at t = "
                           f"{s.t:.9g} s, within a sub-step (a jump the watch cannot extrapolate)"), branch
    if beyond is not None and beyond[0] - s.t <= BRANCH_JUMP * s.dt:  # it jumps at the end: below a floor there
        t_b, kind, w = beyond
        key, what = ("sigma_min_J", "sigma_min(J)") if kind == "kinematic" else \
            ("reduced_hessian_min", "the reduced-Hessian eigenvalue")
        cause = "kinematic_singularity" if kind == "kinematic" else "fold"
        return cause, (f"{words}: {what} jumps from {end.get(key, math.nan):.3g} to {w.get(key, math.nan):.3g} "
                       f"within {t_b - s.t:.2g} s of t = {s.t:.9g} s (the minimum followed ends there: a "
                       f"distance's curvature, or its gradient, jumps)"), branch
    return "step_control_exhausted", f"{words} (at its iterates: {why})", branch


def constraints_dependent(s, q, t) -> float | None:
    """With joints on bounds or rows active: J's smallest singular value at (q, t) where J itself is regular while
    the watched Jacobian (J's free columns, the active rows' gradients below J) is (nearly) not (the constraints,
    not the arm, are singular), else None. "Regular": sigma_min(J) above 1e-3 of sigma_max(J) at (q, t), the nearest
    good point of a stop (at most a sub-step floor, dt/64, before the crossing; an arm singularity that close has
    sigma_min(J) of that order itself, far below 1e-3 at ordinary speeds)."""
    fixed = getattr(s, "fixed", None)
    if (fixed is None or not fixed.any()) and not getattr(s, "rows", None):
        return None
    sJ = np.linalg.svd(s.ev.point(q, t, need_dJ=False).J, compute_uv=False)
    return float(sJ[-1]) if sJ[-1] > 1e-3 * sJ[0] else None
