"""The record of a tracking run: per step what the stepper reached, diagnostics computed when read.

:class:`Recorder` keeps, per recorded point, only what the stepper already has (t, q, lambda, M, the
step's J and path sample, its evaluation where it was made at the recorded point; a run of steps' rows as
the blocks they are). At the end, :meth:`Recorder.trajectory` makes what ``track()`` itself reads or must
fix now: t, q, the pose (afresh where needed: the default mode's evaluation is at the predicted point, there
the pose at the corrected joints), the loop drift, the speeds against the limits (``meta``) and grad z at
every recorded point (:meth:`kinredund.indices.Index.gradients_many`: the index is the caller's object, the
record must not follow later changes to it). The rest is handed to the record as
:class:`~kinredund.trajectory.Deferred` values, each group computed on the first read of any of it:
:class:`PerPoint` stacks lambda, the active bounds and their multipliers and computes the task's errors
(:meth:`kinredund.tasks.Task.errors_many`) and the limit margins; :class:`Diagnostics` computes the normality
residual ||(1 - J^+ J) grad z|| (Eq. 4.5, with K afresh at the corrected joints), the solver labels of
Theorem 2 and, with ``diagnostics``, the eigenvalues of M and of its projection on the null space of J, in a
few batched numpy calls. ``track()`` then costs little more than its steps (``benchmarks/resolved_rate.py``:
``track_over_step``), and holds the GIL little after them (``track_many``'s threads).
"""

from __future__ import annotations

import math
import threading

import numpy as np

from kinredund.tasks import get_task
from kinredund.tracking.linalg import eigs_many, labels_many, normality_many, null_space_bases, null_space_eigs_many
from kinredund.tracking.record_checks import record_extremes
from kinredund.tracking.stepper import Stepper
from kinredund.trajectory import Deferred, Trajectory


class Recorder:
    """Collects one row per recorded point of a :class:`~kinredund.tracking.stepper.Stepper`'s run."""

    def __init__(self, stepper: Stepper, diagnostics: bool = True):
        self.stepper, self.diagnostics = stepper, diagnostics
        self.t, self.solver, self.points = [], [], []
        self.q, self.lam, self.M = Column(), Column(), Column()
        self.J_step = Column()  # the step's J at the points whose solver label is pending (None), in order
        self.pending = 0  # how many those are
        self.M_missing = False  # a point without M (the baselines): no eigenvalues
        self.limited = getattr(stepper, "limits", None) is not None
        self.active, self.mu, self.qdot = Column(), Column(), Column()
        self._free = np.zeros(stepper.n, dtype=int) if self.limited else None  # the active bounds with none held
        self.rows = [] if getattr(stepper, "general", None) else None  # general rows: (min c, active, nu)

    def add(self) -> None:
        """Record the stepper's current point (M and J may come from the step's predicted point).

        The steppers assign new arrays at every step and never change q, lambda, M, the rates or the
        bound multipliers in place, so the record keeps references (the active set, changed in place at
        a switch, is copied only while a bound is active).
        """
        s = self.stepper
        pt = s.pt.base  # the task's evaluation (without the active constraint rows)
        pending = s.label_pending
        self.t.append(s.t)
        self.q.append(s.q)
        self.lam.append(s.task_lam)  # in the closure 7-vector's coordinates at the end (lam_full, batched)
        self.solver.append(None if pending else s.solver)
        self.M.append(s.M)
        self.M_missing = self.M_missing or s.M is None
        if pending:
            self.J_step.append(pt.J)
            self.pending += 1
        # the step's own evaluation where it was made at the recorded point, else the path sample (with the pose
        # at the recorded joints where the step has it: a compiled step's RecordedPose)
        self.points.append(pt if pt.q is s.q and pt.t == s.t else getattr(pt, "recorded", pt.sample))
        if self.limited:
            self.active.append(s.active_bounds() if s.any_active else self._free)
            self.mu.append(s.mu)
            self.qdot.append(s.qdot)
        if self.rows is not None:
            self.rows.append(s.row_record())

    def add_rows(self, t: list[float], q, lam, M, J, pose, desired, qdot, held: tuple | None = None,
                 smallest: list[float] | None = None, nu=None) -> None:
        """Record several steps at once (:mod:`kinredund.tracking.runs`): per step its time [s], joints,
        multipliers, M, the step's J (rows of arrays) and rates, ``pose`` (Q (k, 3, 3), p (k, 3)) at the corrected
        joints and ``desired``, the path's (p_d (k, 3), Q_d (k, 3, 3) or None). Without ``held``
        no joint is on a bound (the solver labels pending, the stepper's own multipliers of the bounds, zero, as
        :meth:`add` records); else (the steps' solver labels, the active bounds (n,), the bound multipliers
        (k, n)), the same active set throughout. With general rows: ``smallest``, the rows' smallest value per step
        [m] (the compiled check's, as :meth:`add` records it from ``row_record``), and ``nu`` (k, rows) the
        multipliers of the stepper's active rows, the same rows throughout (None: none active). ``lam`` and ``J``:
        the task's (without the rows')."""
        k = len(t)
        self.t += t
        self.q.extend(q)
        self.lam.extend(lam)
        self.M.extend(M)
        self.points.append(PoseRows(*pose, *desired))
        if held is None:
            self.solver += [None] * k
            self.J_step.extend(J)
            self.pending += k
        else:
            self.solver += held[0]
        if self.limited:
            # (the same row k times: rows by reference, stacked when read)
            self.active.extend([self._free if held is None else held[1]] * k)
            self.mu.extend([self.stepper.mu] * k if held is None else held[2])
            self.qdot.extend(qdot)
        if self.rows is not None:  # (row_record's: with no row active, no multipliers)
            active = self.stepper.rows
            self.rows += [(v, active, np.zeros(0) if nu is None else nu[j]) for j, v in enumerate(smallest)]

    def __len__(self) -> int:
        return len(self.t)

    def _limits_meta(self, meta: dict, fastest: list[float]) -> None:
        """The limits' record in ``meta``: switches, speeds against the limits (``fastest``: each joint's largest
        |qdot| [rad/s], :func:`~kinredund.tracking.record_checks.record_extremes`; the active sets, bound
        multipliers, margins and switch times are :class:`PerPoint`'s). The velocity limits are ``meta``'s where the
        run put them there (``track()``: read once per run), else the robot's."""
        s = self.stepper
        vmax = meta.get("velocity_limit")
        if vmax is None:
            vmax = np.asarray(s.ev.robot.model.velocityLimit, dtype=float).tolist()
        ratio = [f / v if v > 0 else math.inf for f, v in zip(fastest, vmax, strict=True)]  # (a few joints: floats)
        meta.update(switches=list(s.switches), joint_speed_max=fastest, velocity_limit=vmax,
                    speed_over_velocity_limit_max=max(ratio) if all(map(math.isfinite, ratio)) else None,
                    limit_margin=s.limits.margin)

    def _poses(self) -> tuple[list, dict]:
        """(the recorded poses, {k: J} where the step's own evaluation was made at recorded point k): a run's rows
        (:class:`PoseRows`) as they are, a point recorded one by one as (Q, p, the path sample), (Q, p) None where
        the step has no pose at the recorded joints (:func:`stack_poses` evaluates it there on first read)."""
        poses, own = [], {}
        k = 0
        for item in self.points:
            if isinstance(item, PoseRows):  # the rows of a run (add_rows)
                poses.append(item)
                k += len(item.p)
                continue
            if hasattr(item, "terms"):
                own[k] = item.J
                poses.append((item.Q, item.p, item.sample))
            elif hasattr(item, "pose"):
                poses.append((*item.pose, item.sample))
            else:
                poses.append((None, None, item))
            k += 1
        return poses, own

    def trajectory(self, *, robot_name: str, scheme: str, mode: str, loops: int | None, steps_per_loop: int | None,
                   period: float | None, meta: dict) -> Trajectory:
        """The :class:`~kinredund.trajectory.Trajectory` of the run (``loops``: the loop drift per loop)."""
        s = self.stepper
        task = get_task(s.ev.task)
        q = self.q.array()
        index = s.ev.index  # grad z now, unless the index cannot change: it is the caller's object, the record must
        fixed = index is None or index.fixed  # not follow later changes to it (Index.fixed)
        grad = None if fixed else index.gradients_many(q, np.array(self.t))
        poses, own = self._poses()
        lim = self.limited  # (the record's q is the caller's to change before the rest is read: q's rows again)
        per = PerPoint(task, list(self.t), poses, self.q.snapshot(), s.ev.robot, self.lam.snapshot(), s.pt.basis,
                       (s.limits, self.active.snapshot(), self.mu.snapshot(), [w["t"] for w in s.switches]) if lim
                       else None)
        diag = Diagnostics(self, grad, index if fixed else None, own, per)
        eigs = diag.eigenvalues
        solver = diag if self.pending else tuple(self.solver)
        drift, fastest = record_extremes(q, self.qdot.array() if lim else None, s.ev.robot.revolute, steps_per_loop,
                                         loops)
        if lim:
            self._limits_meta(meta, fastest)
        if self.rows is not None:  # the general constraints' record (issue 27): per point, and the switches
            meta.update(switches=list(s.switches), constraints={
                "names": s.row_names(range(len(s.row_pairs))), "min_value": [r[0] for r in self.rows],
                "active": [list(r[1]) for r in self.rows], "multipliers": [r[2].tolist() for r in self.rows]})
        # the deferred groups stand for their fields (Deferred.value_for)
        return Trajectory.assemble(
            **dict.fromkeys(PER_POINT + (LIMITS_FIELDS if lim else ()), per), robot=robot_name, task=task.name, q=q,
            scheme=scheme, mode=mode, solver=solver, m_eigs=diag if eigs else None, m_null_eigs=diag if eigs else None,
            normality_residual=diag, loop_drift=drift, loop_period=period, meta=meta)


#: numpy releases the GIL for a copy of more than 500 entries (``NPY_BEGIN_THREADS_THRESHOLDED``): a record's columns
#: are copied in pieces of at most this many, so that stacking them does not hand the GIL to another of track_many's
#: threads, which this one would then wait for (each such hand-over costs it the other's Python stretch)
COPY_ELEMENTS = 500


class Column:
    """One recorded vector field (q, lambda, the rates, the bound multipliers): rows added one by one
    (:meth:`append`, the stepper's arrays, kept by reference) or as a run's block (:meth:`extend`: a 2-D array of
    rows, or a list of rows), stacked into one array when read (:meth:`array`: a new array, the rows' values)."""

    __slots__ = ("_blocks", "_rows", "_count")

    def __init__(self):
        self._blocks: list = []  # 2-D arrays and lists of rows, in order
        self._rows: list = []  # the rows appended since the last block
        self._count = 0

    def append(self, row) -> None:
        self._rows.append(row)
        self._count += 1

    def extend(self, block: np.ndarray | list) -> None:
        self._flush()
        self._blocks.append(block)
        self._count += len(block)

    def _flush(self) -> None:
        if self._rows:
            self._blocks.append(self._rows)
            self._rows = []

    def __len__(self) -> int:
        return self._count

    def snapshot(self) -> Column:
        """The rows so far, as a Column of their own (rows added to this one later are not in it)."""
        self._flush()
        out = Column()
        out._blocks, out._count = list(self._blocks), self._count
        return out

    def rows(self) -> list:
        """The rows, one by one (a block's as views)."""
        self._flush()
        return [row for b in self._blocks for row in b]

    def array(self) -> np.ndarray:
        """The rows stacked (k, width): ``np.concatenate``'s array, copied in pieces of at most :data:`COPY_ELEMENTS`
        entries."""
        self._flush()
        blocks = self._blocks
        if not blocks or (len(blocks) == 1 and type(blocks[0]) is list):
            return np.concatenate(blocks) if not blocks else np.array(blocks[0])
        parts = [np.asarray(b) for b in blocks]  # (a list of rows taken as np.array takes it)
        out = np.empty((self._count, *parts[0].shape[1:]), np.result_type(*parts))
        rows = max(1, COPY_ELEMENTS // max(1, out[0].size))
        k = 0
        for part in parts:
            for a in range(0, len(part), rows):
                piece = part[a:a + rows]
                out[k:k + len(piece)] = piece
                k += len(piece)
        return out

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        out = self.array()
        return out if dtype is None else out.astype(dtype)


class PoseRows:
    """The points of a run of steps (:meth:`Recorder.add_rows`), stacked: the pose (Q, p) at the corrected joints and
    the path's p_d and Q_d (None without orientation), one row per step."""

    __slots__ = ("Q", "p", "p_d", "Q_d")

    def __init__(self, Q, p, p_d, Q_d):
        self.Q, self.p, self.p_d, self.Q_d = Q, p, p_d, Q_d


class Once(Deferred):
    """Values computed together on the first read of any of them, then kept: a
    :class:`~kinredund.trajectory.Deferred` that stands for each of its fields of a record (:meth:`value_for`).
    Until then it holds its inputs, and drops them once computed. Safe to read from several threads (one
    computes, the others wait)."""

    def __init__(self, *inputs):
        self._inputs = inputs
        self._out = None
        self._lock = threading.Lock()

    def _compute(self) -> dict:
        with self._lock:
            if self._out is None:
                self._out = self._run(*self._inputs)
                self._inputs = None
            return self._out

    def _run(self, *inputs) -> dict:
        raise NotImplementedError

    def value_for(self, name: str):
        return self._compute()[name]


def stack_poses(poses: list, q: np.ndarray, robot, oriented: bool) -> dict:
    """The poses of :meth:`Recorder._poses` stacked: Q (k, 3, 3), p (k, 3) at the recorded joints ``q`` (evaluated
    there where the step had none), the path's p_desired (k, 3) and Q_d (k, 3, 3), None where the task has no
    orientation (``oriented``)."""
    Qs, ps, p_ds, Q_ds = [], [], [], []
    k = 0
    for item in poses:
        if isinstance(item, PoseRows):
            Qs.append(item.Q)
            ps.append(item.p)
            p_ds.append(item.p_d)
            Q_ds.append(item.Q_d)
            k += len(item.p)
            continue
        Q, p, sample = item
        if Q is None:
            Q, p = robot.kinematics.pose(q[k])
        Qs.append(np.asarray(Q)[None])
        ps.append(np.asarray(p)[None])
        p_ds.append(np.asarray(sample.p)[None])
        Q_ds.append(np.asarray(sample.Q)[None] if oriented else None)
        k += 1
    return {"Q": np.concatenate(Qs), "p": np.concatenate(ps), "p_desired": np.concatenate(p_ds),
            "Q_d": np.concatenate(Q_ds) if oriented else None}


#: the fields of a record :class:`PerPoint` stands for, and those of a run with limits
PER_POINT = ("t", "p", "p_desired", "lam", "position_error", "trace_error", "vect_error", "axis_error")
LIMITS_FIELDS = ("active_bounds", "bound_multipliers", "limit_margins", "switch_times")


class PerPoint(Once):
    """A run's per-point fields that ``track()`` itself does not read (:data:`PER_POINT`, with limits
    :data:`LIMITS_FIELDS`), stacked and computed on the first read of any: the times; the poses reached and asked
    for (:func:`stack_poses`: p, p_desired, and Q, Q_d for the task's errors and :class:`Diagnostics`); the
    multipliers lambda (in the closure 7-vector's coordinates for the augmented pose task: U lambda); the task's
    errors (:meth:`kinredund.tasks.Task.errors_many`; zeros for the trace and vect errors of a task that does not
    hold them, None for its axis error); with limits, the active bounds, their multipliers, the margins to the
    limits (:meth:`~kinredund.tracking.constraints.joint_limits.JointLimits.margins`, 1e10 where a joint has none;
    a JointLimits is not changed after it is made) and the switch times.

    Args: the task; the times [s] (a list of its own); the poses (:meth:`Recorder._poses`: the steppers never
    change a recorded point's arrays in place); q's :class:`Column`; the robot; lambda's
    :class:`Column` and the basis U (None: lambda as it is); with limits, (the run's JointLimits, the active
    bounds' and multipliers' Columns, the switch times [s]), else None.
    """

    def values(self) -> dict:
        """All of them (computed on the first call)."""
        return self._compute()

    def _run(self, task, t, poses, q, robot, lam, basis, limits) -> dict:
        q = q.array()
        out = stack_poses(poses, q, robot, task.has_orientation)
        out["q_run"] = q  # (:class:`Diagnostics`')
        out["t"], p = np.array(t), out["p"]
        out.update(task.errors_many(out["Q"], p, out["Q_d"], out["p_desired"]))
        zeros = np.zeros(len(p))  # the trace and vect errors of tasks that do not hold them, as always recorded
        out.setdefault("trace_error", zeros)
        out.setdefault("vect_error", zeros)
        out.setdefault("axis_error", None)
        lam = lam.array()
        out["lam"] = lam if basis is None else lam @ basis.T
        if limits is not None:
            bounds, active, mu, switches = limits
            out.update(active_bounds=active.array(), bound_multipliers=mu.array(),
                       limit_margins=np.minimum(bounds.margins(q), 1e10), switch_times=np.array(switches, dtype=float))
        return out


class Diagnostics(Once):
    """A run's diagnostics, computed together on the first read of any of them, then kept.

    The normality residual ||Z^T grad z|| (Eq. 4.5, Z a null-space basis of J; J's rows afresh at each
    corrected point the step did not evaluate, grad z as the recorder computed it), with ``diagnostics``
    the eigenvalues of M and of Z^T M Z (Theorem 2), and the solver labels the steps left pending
    (:func:`labels_many`, which the eigenvalues make cheap). Until then it holds the run's arrays
    (about 1 KiB per point on a 7-axis arm; M and the step's J per point, stacked when first read) and the
    robot for its kinematics (:class:`Once`).
    """

    def __init__(self, rec: Recorder, grad: np.ndarray | None, index, own: dict, per: PerPoint):
        s = rec.stepper
        self.eigenvalues = rec.diagnostics and not rec.M_missing
        # grad z, or None: then from the index, one that cannot change (Index.fixed), or zero without one; M and J:
        # the recorder's rows so far (the steppers never change them in place), stacked when first read; t, q and
        # Q_d: the per-point fields' (their own: the record's are the caller's to change)
        super().__init__(grad, index, own, per, s.ev.robot, s.ev.task, rec.M.snapshot(), rec.J_step.snapshot(),
                         list(rec.solver), s.linear_solver, s.symmetric)

    def _run(self, grad, index, own, per, robot, task_name, Ms, J_pending, solver, rule, symmetric) -> dict:
        kin, task = robot.kinematics, get_task(task_name)
        t, q, Q_d = (per.values()[name] for name in ("t", "q_run", "Q_d"))
        if grad is None:
            grad = np.zeros_like(q) if index is None else index.gradients_many(q, t)
        pending = [k for k, v in enumerate(solver) if v is None]
        M = Ms.array() if self.eigenvalues else None
        M_pending = None if M is not None or not pending else [Ms.rows()[k] for k in pending]
        Js = []
        for k in range(len(t)):
            if k in own:
                Js.append(own[k])
                continue
            Q, _, K = kin.jacobian(q[k])
            # rows with J's row space on the path: the null space of J, and with it the normality residual
            # of Eq. (4.5), follows from K alone (Task.span_rows)
            Js.append(task.span_rows(Q, K, None if Q_d is None else Q_d[k]))
        J = np.array(Js)
        Z = null_space_bases(J)
        out = {"normality_residual": normality_many(Z, grad), "m_eigs": None, "m_null_eigs": None}
        if M is not None:
            out["m_eigs"], out["m_null_eigs"] = eigs_many(M), null_space_eigs_many(M, J, Z)
        labels = list(solver)
        if pending:
            # the labels' (M, J) are the step's (at its predicted point, within the corrector's step of
            # the recorded one): the eigenvalues decide where they are clearly signed, classify elsewhere
            k = pending
            eig = None if out["m_eigs"] is None else out["m_eigs"][k]
            eig_null = None if out["m_null_eigs"] is None else out["m_null_eigs"][k]
            Ms = list(M[k]) if M is not None else M_pending
            for i, label in zip(k, labels_many(Ms, list(J_pending.array()), rule, symmetric, eig, eig_null),
                                strict=True):
                labels[i] = label
        out["solver"] = tuple(labels)
        return out
