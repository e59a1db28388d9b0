"""The public stepper of Chapter 4's tracking schemes, for control loops: :class:`Tracker`.

    tracker = Tracker(robot, path, index, q0, dt)
    while running:
        tracker.step()            # from t to t + dt
        send(tracker.q, tracker.qdot)

Modes and schemes (one stepper class each, chosen here once):

- ``mode="default"``, ``scheme="augmented"`` or ``"velocity"``: predictor along the optimal path and Newton
  corrector on the first-order conditions (:class:`~kinredund.tracking.predictor_corrector.PredictorCorrector`);
- ``mode="thesis"``: explicit Euler steps with the velocity correction of Eq. (4.29), as the thesis ran
  (:class:`~kinredund.tracking.explicit.ExplicitEuler`);
- ``scheme="pseudoinverse"`` or ``"liegeois"``: the baselines (:mod:`kinredund.tracking.baselines`).

Linear solver per step (Theorem 2): where M projected on the null space of J is positive definite the
rates solve the QP min 1/2 thetadot^T M thetadot s.t. J thetadot = xdot (4.28), solved either with
proxsuite on M + rho J^T J (same minimiser on the constraint) or by a direct factorisation of its KKT
system (``qp_backend="kkt"``); elsewhere LU of R. The step records ``qp``, ``qp_aug`` or ``lu``. The
default mode solves every step with the LU factors of R, which its corrector needs anyway; its record
labels each step by where the QP form holds (the rule ``linear_solver``), and ``qp_backend="proxsuite"``
is for thesis mode only.
"""

from __future__ import annotations

import functools
import math
import weakref

import numpy as np

from kinredund.errors import OptionError, PathError, check_choice, check_flag, check_positive
from kinredund.geometry.scene import Scene
from kinredund.ik.solve import check_index_at
from kinredund.indices import Index
from kinredund.model.robot import Robot, check_robot
from kinredund.paths import Path
from kinredund.tasks import get_task
from kinredund.tracking.baselines import Liegeois, Pseudoinverse
from kinredund.tracking.compiled import attach, compiled_start
from kinredund.tracking.constraints.joint_limits import JointLimits
from kinredund.tracking.constraints.scene import SceneClearance
from kinredund.tracking.explicit import ExplicitEuler
from kinredund.tracking.limited import LimitedPredictorCorrector
from kinredund.tracking.point import Evaluator
from kinredund.tracking.predictor_corrector import PredictorCorrector
from kinredund.tracking.stepper import Stepper

SCHEMES = ("augmented", "velocity", "pseudoinverse", "liegeois")
MODES = ("default", "thesis")
QP_BACKENDS = ("proxsuite", "kkt")
LINEAR_SOLVERS = ("auto", "thesis", "lu", "qp")
#: the stepper class of each (mode, scheme)
STEPPERS = {("default", "augmented"): PredictorCorrector, ("default", "velocity"): PredictorCorrector,
            ("thesis", "augmented"): ExplicitEuler, ("thesis", "velocity"): ExplicitEuler,
            ("default", "pseudoinverse"): Pseudoinverse, ("thesis", "pseudoinverse"): Pseudoinverse,
            ("default", "liegeois"): Liegeois, ("thesis", "liegeois"): Liegeois}
#: the range of time steps [s] the tracker computes in: its step control squares dt and the rates times dt,
#: which overflow or vanish beyond these (a path at 1e-300 m/s has a period of ~1e300 s)
DT_RANGE = (1e-100, 1e100)


def check_tolerance(tol) -> float:
    """``tol`` as a float in (0, 1), else :class:`~kinredund.errors.OptionError` naming the allowed range."""
    if isinstance(tol, (str, bytes, bool)) or not isinstance(tol, (int, float, np.floating, np.integer)) \
            or not (math.isfinite(float(tol)) and 0.0 < float(tol) < 1.0):
        raise OptionError(f"tol (the corrector's tolerance on ||F||) must be a finite number in (0, 1), e.g. 1e-12; "
                          f"got {tol!r}")
    return float(tol)


def check_gain(gain) -> float:
    """The Liegeois gain k >= 0 [1/s] as a float, else :class:`~kinredund.errors.OptionError`."""
    if isinstance(gain, (str, bytes, bool)) or not isinstance(gain, (int, float, np.floating, np.integer)) \
            or not (math.isfinite(float(gain)) and float(gain) >= 0.0):
        raise OptionError(f"liegeois_gain (the gradient-projection gain k [1/s]) must be a finite number >= 0; "
                          f"got {gain!r}")
    return float(gain)


def check_options(scheme, mode, linear_solver, qp_backend, tol, liegeois_gain, project_start, strict) -> tuple:
    """The tracker's scalar options checked, in this order, with their defaults filled in: (linear_solver,
    qp_backend, tol, gain, project_start, strict).

    Raises:
        ChoiceError, OptionError: an unknown scheme, mode or solver, or an option out of its range.
    """
    check_choice("scheme", scheme, SCHEMES)
    check_choice("mode", mode, MODES)
    linear_solver = linear_solver or ("thesis" if mode == "thesis" else "auto")
    check_choice("linear solver", linear_solver, LINEAR_SOLVERS)
    qp_backend = qp_backend or ("proxsuite" if mode == "thesis" else "kkt")
    check_choice("QP backend", qp_backend, QP_BACKENDS)
    if mode == "default":  # it solves with R's LU factors, which its corrector needs
        check_choice("QP backend of mode='default' (proxsuite is for mode='thesis')", qp_backend, ("kkt",))
    tol, gain = check_tolerance(tol), check_gain(liegeois_gain)
    project_start, strict = check_flag(project_start, "project_start"), check_flag(strict, "strict")
    return linear_solver, qp_backend, tol, gain, project_start, strict


_check_options_cached = functools.lru_cache(maxsize=64, typed=True)(check_options)


def checked_options(*options) -> tuple:
    """:func:`check_options`, its answer kept per distinct options (by value and type: ``1`` is not ``True``) and
    shared by the runs that ask again (a failed check is not kept: it raises each time). A gain of zero is checked
    afresh (0.0 and -0.0 are one key, and the gain is returned as given)."""
    gain = options[5]
    if isinstance(gain, (int, float, np.number)) and gain != 0:
        try:
            return _check_options_cached(*options)
        except TypeError as err:  # an unhashable option (e.g. an array): checked afresh, where it raises if wrong
            if "unhashable" not in str(err):
                raise
    return check_options(*options)


def _from_stepper(name: str, doc: str) -> property:
    """A read-only property of :class:`Tracker` that reads ``name`` of its stepper (the state lives there)."""
    return property(lambda self: getattr(self.stepper, name), doc=doc)


def check_limits_option(limits, mode: str, scheme: str) -> bool:
    """Whether a run with ``limits`` (None, True, False or a JointLimits) holds joint limits in this mode and
    scheme: the one rule of the tracker, and of every options object that asks for a run (the sweep's).

    None (the default) holds them wherever the scheme can (the default mode's augmented and velocity schemes);
    False never; True or a JointLimits there only.

    Raises:
        OptionError: limits of another type, or asked of a mode or scheme that cannot hold them.
    """
    holds = mode == "default" and scheme in ("augmented", "velocity")
    if limits is None or limits is False:
        return holds and limits is None
    if limits is not True and not isinstance(limits, JointLimits):
        raise OptionError(f"limits must be None, True, False or a JointLimits, got {limits!r}")
    if not holds:
        raise OptionError(f"joint limits are held by the default mode's augmented and velocity schemes only, "
                          f"not by mode={mode!r}, scheme={scheme!r}: pass limits=False (thesis mode's explicit "
                          "steps have no corrector to hold them)")
    return True


class Tracker:
    """Tracks ``path`` from ``q0`` step by step: :meth:`step` advances by ``dt``.

    Args:
        robot: the arm (its ``task`` sets m).
        path: the path; pose tasks need a path with orientation.
        index: the performance index z (required for ``augmented``/``velocity``/``liegeois``).
        q0: the starting configuration (on the path; for the optimal schemes, at the constrained
            minimum - see :func:`kinredund.ik.solve_ik`; the default mode corrects it onto the optimum, with one
            Newton update at least, so the record's first point may differ from q0 by the IK's tolerance).
        dt: the time step [s].
        scheme, mode: see the module docstring.
        linear_solver: the rule of :func:`~kinredund.tracking.linalg.classify`: ``auto`` (default mode's
            default), ``thesis`` (thesis mode's default), ``lu`` or ``qp``.
        qp_backend: ``proxsuite`` or ``kkt`` (default: proxsuite in thesis mode, kkt in default mode, which
            solves with R's LU factors and does not take ``proxsuite``).
        tol: the corrector's tolerance on ||F||, in (0, 1) (default mode).
        liegeois_gain: the gradient-projection gain k >= 0 of the Liegeois baseline [1/s].
        t0: the starting time [s].
        limits: hold the robot's joint position limits: ``True``, or a
            :class:`~kinredund.tracking.constraints.JointLimits` (e.g. with a margin); ``False`` for the
            unconstrained scheme of Chapter 4 (the thesis's). The default (``None``) holds them wherever
            the scheme can: the default mode's augmented and velocity schemes
            (:mod:`kinredund.tracking.limited`); thesis mode and the baselines run without them, and
            refuse ``limits=True`` (explicit steps have no corrector to hold the bounds).
        project_start: put a ``q0`` outside the limits on them instead of raising.
        constraints: general inequality constraints held like the limits (e.g.
            :class:`~kinredund.tracking.constraints.SphereClearance`; :mod:`kinredund.tracking.rows`): the run
            stops with ``cause="collision"`` where one cannot be held. ``qp_solver``: the rate QP's solver at a
            weakly active row (``proxqp``, or ``daqp`` where installed).
        scene, clearance, self_clearance: a :class:`~kinredund.geometry.scene.Scene` whose pairs are held apart
            (a :class:`~kinredund.tracking.constraints.SceneClearance` added to ``constraints``): ``clearance``
            [m] from its obstacles (default 0.02) and ``self_clearance`` [m] between the robot's own objects
            (default 0.01, MoveIt Servo's; ``False`` leaves them unchecked). A ``q0`` under a clearance is
            refused (``cause="collision"``, naming the pair and by how much).
        strict: the default mode's step control, jump check and fold and singularity watch
            (:mod:`kinredund.tracking.step_control`; on by default): a step the corrector fails is retried in
            sub-steps, and the run stops before a fold or a singularity with a
            :class:`~kinredund.errors.TrackingError`; ``strict=False`` is the plain predictor-corrector step.
        backend: ``compiled`` (the default mode's ordinary step in the compiled core, the other steps in
            Python: :mod:`kinredund.tracking.compiled`; with constraints or a scene, the steps with no row
            active, each checked by the Python stepper's own search for a row switch), ``python`` (every step
            in Python) or ``auto`` (compiled where the core loads and supports the problem). Default:
            ``$KINREDUND_BACKEND``, else ``auto``.
            Both give the same results (to ~1e-12); the attribute ``backend`` says which one runs.

    Attributes (read them after each step): ``q`` [rad or m], ``t`` [s], ``lam`` (the multipliers),
    ``qdot`` [rad/s] (the rates at t), ``lamdot``, ``solver`` (the step's linear-solver label),
    ``stepper`` (the scheme's own object) and ``backend`` (``compiled`` or ``python``).

    Raises:
        ChoiceError, OptionError: an unknown scheme, mode or solver, or an option out of its range (also:
            limits asked of thesis mode or a baseline; ``backend="compiled"`` where it cannot run, saying why; limits,
            a scene or a constraint made for another robot).
        TrackingError: with constraints, ``q0`` violates one (``cause="collision"``, naming it and by how much).
        TaskError: an index that cannot be evaluated on the robot's joints (the wrong length, a custom
            index whose callables fail or return the wrong shapes: :func:`kinredund.ik.solve.check_index_at`).
        TrackingError: with limits, ``q0`` is outside them (``cause="limits_infeasible"``, naming the joints
            and by how much), or no constrained optimum is found at the start.
        PathError: the start is off the path, or the path is unsuitable (says why).
        TrackingError: the start is a kinematic singularity (``kinematic_singularity``, a SingularityError too).
        TrackingError: the start cannot be corrected onto a constrained minimum (``non_optimal_start``), or
            dt is longer than the path's period (``step_too_long``); from :meth:`step`, the run cannot go on
            (the cause, the last good point; the stepper stays at the last requested time).
    """

    def __init__(self, robot: Robot, path: Path, index: Index | None, q0, dt: float, *, scheme: str = "augmented",
                 mode: str = "default", linear_solver: str | None = None, qp_backend: str | None = None,
                 tol: float = 1e-12, liegeois_gain: float = 1.0, t0: float = 0.0,
                 limits: bool | JointLimits | None = None, project_start: bool = False, strict: bool = True,
                 constraints=None, qp_solver: str = "proxqp", scene=None, clearance: float | None = None,
                 self_clearance: float | bool | None = None, backend: str | None = None):
        linear_solver, qp_backend, tol, gain, project_start, strict = checked_options(
            scheme, mode, linear_solver, qp_backend, tol, liegeois_gain, project_start, strict)
        check_robot(robot)
        check_path(path)
        if get_task(robot.task).has_orientation and not path.has_orientation:
            raise PathError(f"a {robot.task} task needs a path with orientation (e.g. Circle(..., frenet=True))")
        if index is None and scheme in ("augmented", "velocity", "liegeois"):
            raise PathError(f"the {scheme} scheme needs a performance index")
        if index is not None and not isinstance(index, Index):
            raise OptionError(f"index must be a kinredund.indices.Index (or None for the pseudoinverse scheme), "
                              f"got {type(index).__name__}")
        if not (type(dt) is float and 0.0 < dt < math.inf):  # (a positive finite float is check_positive's own)
            dt = check_positive(dt, "the time step [s]", PathError)
        if not DT_RANGE[0] <= dt <= DT_RANGE[1]:
            raise OptionError(f"the time step {dt:.3g} s is outside the range the tracker computes in, "
                              f"{DT_RANGE[0]:g} to {DT_RANGE[1]:g} s")
        if not math.isfinite(float(t0)):
            raise OptionError(f"t0 (the starting time [s]) must be finite, got {t0!r}")
        self.robot, self.path, self.index, self.scheme, self.mode, self.dt = robot, path, index, scheme, mode, dt
        q = robot.check_q(q0, "starting configuration").copy()
        ev = Evaluator(robot, path, index, "velocity" if scheme == "velocity" else "augmented")
        # a wrong length or a malformed custom index: said here, in its words; its terms serve the first evaluation
        ev.keep_index_at(q, check_index_at(robot, index, q))
        limits = self._limits(robot, limits, mode, scheme)
        kwargs = {"t0": t0, "tol": tol, "linear_solver": linear_solver, "qp_backend": qp_backend}
        given = constraint_list(constraints)
        check_constraints_robot(robot, limits, given)  # (scene_constraints checks scene='s robot itself)
        self.limits, constraints = limits, given + scene_constraints(robot, scene, clearance, self_clearance)
        if constraints and not (mode == "default" and scheme in ("augmented", "velocity")):
            raise OptionError(f"constraints are held by the default mode's augmented and velocity schemes only, "
                              f"not by mode={mode!r}, scheme={scheme!r}")
        limited = limits is not None or bool(constraints)
        cls = LimitedPredictorCorrector if limited else STEPPERS[mode, scheme]
        # the start in the core where the steps are compiled (general rows: the Python stepper's extended system)
        start = None if constraints else compiled_start(backend, cls, ev, mode, scheme)
        if start is not None:
            kwargs["start"] = start
        if limited:
            if project_start and limits is not None:
                q = limits.project(q)
            self.stepper: Stepper = LimitedPredictorCorrector(ev, q, dt, limits=limits, constraints=constraints,
                                                              qp_solver=qp_solver, strict=strict, **kwargs)
            self.step = self.stepper.step
            self.backend = attach(self, backend, start)
            return
        if scheme in ("pseudoinverse", "liegeois"):
            kwargs["project"] = mode == "default"
        if scheme == "liegeois":
            kwargs["gain"] = gain
        if mode == "default" and scheme in ("augmented", "velocity"):
            kwargs["strict"] = strict
        self.stepper: Stepper = cls(ev, q, dt, **kwargs)
        self.step = self.stepper.step
        self.backend = attach(self, backend, start)

    @staticmethod
    def _limits(robot: Robot, limits, mode: str, scheme: str) -> JointLimits | None:
        if not check_limits_option(limits, mode, scheme):
            return None
        return robot_limits(robot) if limits is None or limits is True else limits

    def step(self) -> None:  # replaced by the stepper's own bound method in __init__ (no extra call)
        """One time step: from (q, lambda) at t to t + dt."""
        self.stepper.step()

    q = _from_stepper("q", "The joint values at :attr:`t` [rad or m].")
    t = _from_stepper("t", "The current time [s].")
    lam = _from_stepper("task_lam", "The multipliers lambda at :attr:`t` (Eq. 4.5; lambda* in the velocity form).")
    qdot = _from_stepper("qdot", "The joint rates [rad/s] at :attr:`t` (the default mode's: at the step's predicted "
                                 "point).")
    lamdot = _from_stepper("lamdot", "The multipliers' rates at :attr:`t`.")
    solver = _from_stepper("solver", "The step's linear-solver label (``qp``, ``qp_aug``, ``lu``; ``lstsq`` for the "
                                     "baselines).")


_LIMITS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # robot -> ((lower, upper), its JointLimits)


def check_path(path) -> Path:
    """``path`` if it is a :class:`~kinredund.paths.Path`, else OptionError."""
    if not isinstance(path, Path):
        raise OptionError(f"path must be a kinredund.paths.Path, got {type(path).__name__}")
    return path


def constraint_list(constraints) -> list:
    """``constraints`` (None, or an iterable of them) as a new list, else OptionError (a single constraint or a number
    is not a list of them; each item is checked where the rows are set up)."""
    if constraints is None:
        return []
    try:
        return list(constraints)
    except TypeError as err:  # (a number, a single constraint, a 0-d array)
        raise OptionError(f"constraints must be a list of Constraints (e.g. [kr.SphereClearance(...)]), got "
                          f"{type(constraints).__name__}") from err


def robot_limits(robot: Robot) -> JointLimits:
    """``JointLimits(robot)``, made once per robot (its ``lower`` and ``upper``, read-only arrays) and shared by its
    runs (:func:`~kinredund.tracking.many.track_many`'s make one per problem otherwise): a JointLimits is not
    changed after it is made."""
    key = (robot.lower, robot.upper)
    kept = _LIMITS.get(robot)
    if kept is None or kept[0][0] is not key[0] or kept[0][1] is not key[1]:
        kept = _LIMITS[robot] = (key, JointLimits(robot))
    return kept[1]


def scene_constraints(robot: Robot, scene, clearance, self_clearance) -> list:
    """[SceneClearance] for ``track(..., scene=)`` (defaults 2 cm and 1 cm), [] without a scene.

    Raises:
        OptionError: a clearance without a scene, or a scene of another robot.
    """
    if scene is None:
        if clearance is not None or self_clearance is not None:
            raise OptionError("clearance and self_clearance need scene= (a kinredund Scene of this robot)")
        return []
    if not isinstance(scene, Scene):
        raise OptionError(f"scene must be a kinredund Scene, got {type(scene).__name__}")
    check_robot_of(robot, "the scene", scene.robot.name, scene.robot.joint_names, scene.robot.model, "the Scene")
    if self_clearance is True:
        raise OptionError("self_clearance takes a distance [m] (default 0.01) or False, not True")
    own = None if self_clearance is False else (0.01 if self_clearance is None else self_clearance)
    return [SceneClearance(scene, 0.02 if clearance is None else clearance, own)]


def check_robot_of(robot: Robot, what: str, name: str, joint_names, model=None, kind: str = "it") -> None:
    """Refuse (OptionError) ``what`` (a scene, a constraint, the limits), made for the robot ``name`` with
    ``joint_names`` and ``model`` (None: not compared), where the tracked robot's joints are other ones: its rows
    would be another arm's kinematics at the tracked joint values (a wrong record with no error where the joint counts
    agree, a Pinocchio error where they do not)."""
    if list(joint_names) != list(robot.joint_names):
        raise OptionError(f"{what} is of a robot with joints {list(joint_names)}, not the tracked "
                          f"{list(robot.joint_names)}: make {kind} of the tracked robot")
    if model is not None and not same_chain(model, robot.model):
        raise OptionError(f"{what} is of a robot {name!r} whose joints have the tracked robot's names but other "
                          f"placements or kinds than {robot.name!r}'s: make {kind} of the tracked robot")


def check_constraints_robot(robot: Robot, limits, constraints: list) -> None:
    """:func:`check_robot_of` for the limits and each constraint that says whose joints it is of (``joint_names``:
    JointLimits, the frame clearances; a user's own Constraint need not say)."""
    for c in ([limits] if limits is not None else []) + constraints:
        joint_names = getattr(c, "joint_names", None)
        if joint_names is not None:
            what = "limits=" if c is limits else f"the constraint {c.names()[0]!r}"
            check_robot_of(robot, what, getattr(c, "robot_name", "?"), joint_names, getattr(c, "model", None))


def same_chain(a, b) -> bool:
    """Do two Pinocchio models have one kinematic chain: parents, joint kinds and joint placements (to 1e-12)?"""
    if a is b:  # (the common case: the scene made of the tracked robot)
        return True
    if a.njoints != b.njoints or list(a.parents) != list(b.parents):
        return False
    kinds = all(x.shortname() == y.shortname() for x, y in zip(a.joints, b.joints, strict=True))
    return kinds and all(np.allclose(x.homogeneous, y.homogeneous, rtol=0.0, atol=1e-12)
                         for x, y in zip(a.jointPlacements, b.jointPlacements, strict=True))
