"""The compiled backend of the IK's constrained iteration (issue 28): :func:`kinredund.ik.newton._iterate` in C++.

``kinredund._core.IKCore`` (``src/core/ik.cpp``) runs the iterations of one start of the constrained minimum
(:func:`kinredund.ik.newton._constrained_minimum`) operation by operation: one Pinocchio evaluation per iteration
(shared with the compiled step), e and G of the task kinds' IK residuals (point, planar, pose, axis), the QR split
of G^T (Eq. D.25), x0 (Eq. D.24), the least-squares multipliers (Eqs. 4.11-4.12) or the first-order conditions with
bounds (Eq. D.30), the Lagrangian Hessian M (Eqs. 4.20-4.26), the reduced Newton step of Eq. (D.26) with its
eigenvalue fix, the merit search with its second-order correction, the damped least-squares restoration step (with
bounds, its box least squares where :mod:`kinredund.ik.qp`'s active-set guesses solve it), the box QP of a Newton step
that leaves the joint limits (where :mod:`kinredund.ik.qp`'s guesses solve its equality form, or the core certifies
that form infeasible and the guesses solve the box least squares that Python then takes) and the stall and
convergence tests, for the index :class:`~kinredund.indices.JointDeviation` (``minimum_norm``, ``mid_range``).

A start that converges there comes back with the terms of its last iteration (the optimality report's, as the Python
iteration gives them). Anything else is handed to the Python iteration from the state at the start of the iteration
that needs it (:data:`STATUS`): a box QP of the Newton step that needs proxsuite (the guesses neither solve it nor
certify its equality form infeasible), a restoration step whose box least squares needs proxsuite, every stop that
is not convergence (the reason is the Python iteration's to word), a rotation near a half turn (the log's
symmetric-part branch), a spurious zero of e.
The Python iteration redoes that iteration and hands the next one back to the core, so the results are the Python
iteration's to rounding.

Backends as the tracker's (:mod:`kinredund.tracking.compiled`): ``solve_ik(..., backend=)`` or the environment
variable ``KINREDUND_BACKEND`` where the caller gives none; ``auto`` (the default) runs the core where it loads
and supports the problem, ``python`` the reference, the caller's ``compiled`` raises an
:class:`~kinredund.errors.OptionError` where the core cannot run it (the environment's ``compiled`` where it cannot
load: :func:`~kinredund.errors.check_backend`). A core that cannot be loaded warns once. Pose-only solves
(``index=None``, :mod:`kinredund.ik.pose_only`) are Python's under every backend.
"""

from __future__ import annotations

import math
import threading
import warnings

import numpy as np

from kinredund.errors import OptionError, check_backend
from kinredund.ik.common import (
    ACTIVE_TOL,
    ARMIJO,
    DAMPING,
    LM_WEIGHT,
    MAX_STEP,
    MIN_ALPHA,
    RANK_TOL,
    STALL_ITERS,
    OptimalityTerms,
    Setup,
    StartOutcome,
)
from kinredund.ik.qp import GUESS_ROUNDS
from kinredund.indices import JointDeviation
from kinredund.kinematics.state import HessianContraction
from kinredund.tasks.axis import AxisResidual
from kinredund.tasks.pose import PoseResidual
from kinredund.tasks.position import PointResidual

#: the constants of :mod:`kinredund.ik.common` as the core takes them (src/core/ik.cpp Constants)
CONSTANTS = np.array([ARMIJO, MAX_STEP, MIN_ALPHA, RANK_TOL, DAMPING, LM_WEIGHT, ACTIVE_TOL, STALL_ITERS, GUESS_ROUNDS],
                     float)
#: why the core handed an iteration back to Python (its status codes)
STATUS = {1: "log_near_pi", 2: "not_finite", 3: "spurious", 4: "max_iter", 5: "timeout", 6: "stalled",
          7: "singular", 8: "restore_box", 9: "restore_failed", 10: "box_qp", 11: "merit_failed"}
_EMPTY = np.zeros(0)
#: iterations handed back by reason, and runs of the core ending converged (for benchmarks and tests; per process)
COUNTS: dict[str, int] = {}
_COUNTS_LOCK = threading.Lock()  # solves run in threads (track_many, a sweep's workers)


def _count(key: str) -> None:
    with _COUNTS_LOCK:
        COUNTS[key] = COUNTS.get(key, 0) + 1


class IKBackendWarning(UserWarning):
    """The compiled core cannot be loaded: the IK's constrained iteration runs in Python (same results, slower)."""


def _task_code(res) -> int | None:
    if type(res) is PointResidual:
        return {2: 0, 3: 1}.get(res.m) if list(res.rows) == list(range(3, 3 + res.m)) else None
    return {PoseResidual: 2, AxisResidual: 3}.get(type(res))


def unsupported(robot, res, index) -> str:
    """Why the core cannot run this constrained problem ("" where it can)."""
    if type(index) is not JointDeviation:
        return f"it knows the index JointDeviation (minimum_norm, mid_range), not {type(index).__name__}"
    model = robot.model
    if model.nq != model.nv:
        return f"the robot's configuration has nq = {model.nq} != nv = {model.nv} entries"
    if _task_code(res) is None:
        return f"unknown task residual {type(res).__name__}"
    return ""


def core_module():
    """The compiled module with its IKCore, or None where it cannot be loaded (or is an older build)."""
    return _load()[0]


def _load():
    from kinredund.tracking.compiled import core_error, load_core  # one loader (a lazy import: tracking uses ik)

    core = load_core()
    if core is None:
        return None, core_error()
    if not hasattr(core, "IKCore"):
        return None, "kinredund._core has no IKCore (an older build: reinstall kinredund)"
    return core, ""


def pick(robot, res, index, backend: str | None) -> bool:
    """Whether the constrained iteration of this solve runs in the core (see the module docstring).

    Raises:
        OptionError: ``backend="compiled"`` where the core cannot run the problem or cannot be loaded.
        ChoiceError: an unknown backend.
    """
    backend, forced = check_backend(backend)
    if backend == "python" or index is None:  # pose-only solves are Python's under every backend
        return False
    why = unsupported(robot, res, index)
    if why:
        if forced:
            raise OptionError(f"backend='compiled' cannot run this IK: {why}; use backend='python' or 'auto'")
        return False
    core, why = _load()
    if core is None:
        if backend == "compiled":
            raise OptionError(f"backend='compiled': the compiled core cannot be loaded ({why}); reinstall "
                              "kinredund with pin[build] and nanobind beside pin, or use backend='python'")
        _warn_once(why)
        return False
    return True


_WARNED: list = []


def _warn_once(why: str) -> None:
    if not _WARNED:
        _WARNED.append(True)
        warnings.warn(f"kinredund's compiled core cannot be loaded ({why}): the IK's constrained iteration runs in "
                      "Python (same results, slower)", IKBackendWarning, stacklevel=4)


def _core_of(kin):
    """This thread's IKCore for ``kin`` (a :class:`~kinredund.kinematics.state.Kinematics`: one per thread)."""
    core = getattr(kin, "_ik_core", None)
    if core is None:
        core = _load()[0].IKCore(kin.model, int(kin.frame_id), CONSTANTS)
        kin._ik_core = core
    return core


def run_compiled(s: Setup, q: np.ndarray, on_target: list, state: tuple | None = None) -> StartOutcome | tuple:
    """The iterations of one start in the core from q (a fresh start) or from ``state`` (where the Python iteration
    hands back, :func:`kinredund.ik.newton._iterate`'s): the converged :class:`StartOutcome`, or the state
    ``(it, q, rho, r_ref, since, q_prev, r_prev)`` at the start of the iteration handed back to Python
    (``on_target`` updated as :func:`kinredund.ik.newton._iterate` updates it)."""
    res, index = s.res, s.index
    t = res.target
    Qd = np.eye(3) if t.Q is None else t.Q
    it0, q, rho, r_ref, since, q_prev, r_prev = state or (0, q, 0.0, math.inf, 0, q, math.inf)
    on_q, on_z, on_r = on_target or (_EMPTY, 0.0, 0.0)
    out = _core_of(s.kin).run(q, _task_code(res), Qd, t.p, index.weights, index.reference, s.lower, s.upper,
                              s.bounds, s.rtol, s.tol, s.max_iter, math.inf if s.deadline is None else s.deadline,
                              it0, rho, r_ref, since, q_prev, r_prev, on_q, on_z, on_r)
    status, it = out[0], out[1]
    on_q, on_z, on_r = out[-3:]
    if on_q is not None:
        on_target[:] = [on_q, float(on_z), float(on_r)]
    if status:
        why = STATUS[status]
        _count(why)
        return out[1:8]
    _count("converged")
    _, _, qc, r, normality, z, lam_k, L, active, extra, hbuf = out[:11]
    n = qc.shape[0]
    active = np.zeros(n, dtype=bool) if active is None else active.astype(bool)
    dk = HessianContraction(hbuf.reshape(6, n, n))  # the buffer of Pinocchio's tensor, as eigenpy gives it
    terms = OptimalityTerms(float(normality), float(z), index.evaluate(qc)[2], dk, lam_k, L, active, extra)
    return StartOutcome(qc, True, it, "", float(r), terms)
