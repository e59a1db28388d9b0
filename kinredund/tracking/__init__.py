"""Tracking (Chapter 4): the resolved-rate schemes that follow the constrained optimum along a path.

- :class:`Tracker` (:mod:`.tracker`): the public stepper for control loops (``step()``, ``q``, ``t``);
- :func:`track` (:mod:`.run`): a whole run, recorded as a :class:`~kinredund.trajectory.Trajectory`;
  :func:`track_many` (:mod:`.many`): many runs in one call, in threads;
- :mod:`.compiled`: the default mode's ordinary step in the compiled core (``Tracker(..., backend=)``);
- the schemes, one class each: :mod:`.predictor_corrector` (default mode), :mod:`.explicit` (thesis
  mode, Eq. 4.29), :mod:`.baselines` (pseudoinverse, Liegeois); their shared state in :mod:`.stepper`
  and their evaluation at a point in :mod:`.point`;
- :mod:`.linalg`: R of Eq. (4.24), its LU and QP solutions, multipliers, the predictor's weights;
- :mod:`.recorder`: the per-step record and its diagnostics;
- the strict tracker of the default mode: :mod:`.step_control` (sub-steps, the jump check), :mod:`.watch`
  (the fold and singularity watch), :mod:`.failure` (the cause of a stop and its partial record);
- :mod:`.constraints`: constraints on the joints (joint limits, clearances), held by :mod:`.limited` (the
  default mode with hard joint limits: active sets, exact switching times) and :mod:`.rows` (general
  inequality rows); the stepper's state as one value in :mod:`.state`.
"""

from kinredund.tracking.constraints import (
    Constraint,
    CornerClearance,
    JointLimits,
    PlaneClearance,
    SceneClearance,
    SphereClearance,
)
from kinredund.tracking.many import track_many
from kinredund.tracking.run import MAX_STEPS, track
from kinredund.tracking.tracker import LINEAR_SOLVERS, MODES, QP_BACKENDS, SCHEMES, Tracker

__all__ = ["LINEAR_SOLVERS", "MAX_STEPS", "MODES", "QP_BACKENDS", "SCHEMES", "Constraint", "CornerClearance",
           "JointLimits", "PlaneClearance", "SceneClearance", "SphereClearance", "Tracker", "track", "track_many"]
