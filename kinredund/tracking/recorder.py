"""The record of a tracking run: per step what the stepper reached, diagnostics computed when read.

:class:`Recorder` keeps, per recorded point, only what the stepper already has (t, q, lambda, M, the
step's J and path sample, its evaluation where it was made at the recorded point). At the end,
:meth:`Recorder.trajectory` evaluates the pose afresh where needed (the default mode's evaluation is at
the predicted point: there the pose at the corrected joints), computes the task's errors
(:meth:`kinredund.tasks.Task.errors_many`) and grad z at every recorded point
(:meth:`kinredund.indices.Index.gradients_many`: the index is the caller's object, the record must not
follow later changes to it). The diagnostics - the normality residual ||(1 - J^+ J) grad z|| (Eq. 4.5,
with K afresh at the corrected joints), the solver labels of
Theorem 2 and, with ``diagnostics``, the eigenvalues of M and of its projection on the null space of J -
are handed to the record as :class:`~kinredund.trajectory.Deferred` values: :class:`Diagnostics`
computes them all in a few batched numpy calls on the first read of any of them. ``track()`` then costs
little more than its steps (``benchmarks/resolved_rate.py``: ``track_over_step``).
"""

from __future__ import annotations

import threading

import numpy as np

from kinredund.kinematics.angles import joint_drift
from kinredund.tasks import get_task
from kinredund.tracking.linalg import eigs_many, labels_many, normality_many, null_space_bases, null_space_eigs_many
from kinredund.tracking.stepper import Stepper
from kinredund.trajectory import Deferred, Trajectory


class Recorder:
    """Collects one row per recorded point of a :class:`~kinredund.tracking.stepper.Stepper`'s run."""

    def __init__(self, stepper: Stepper, diagnostics: bool = True):
        self.stepper, self.diagnostics = stepper, diagnostics
        self.t, self.solver, self.M, self.J_step, self.points = [], [], [], [], []
        self.q, self.lam = Column(), Column()
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
        self.J_step.append(pt.J if pending else None)
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
                 smallest: list[float] | None = None) -> None:
        """Record several steps at once (:mod:`kinredund.tracking.runs`): per step its time [s], joints,
        multipliers, M, the step's J (rows of arrays) and rates, ``pose`` (Q (k, 3, 3), p (k, 3)) at the corrected
        joints and ``desired``, the path's (p_d (k, 3), Q_d (k, 3, 3) or None). Without ``held``
        no joint is on a bound (the solver labels pending, the stepper's own multipliers of the bounds, zero, as
        :meth:`add` records); else (the steps' solver labels, the active bounds (n,), the bound multipliers
        (k, n)), the same active set throughout. With general rows, none active throughout: ``smallest``, the rows'
        smallest value per step [m] (the compiled check's, as :meth:`add` records it from ``row_record``)."""
        k = len(t)
        self.t += t
        self.q.extend(q)
        self.lam.extend(lam)
        self.M += list(M)
        self.points.append(PoseRows(*pose, *desired))
        if held is None:
            self.solver += [None] * k
            self.J_step += list(J)
        else:
            self.solver += held[0]
            self.J_step += [None] * k
        if self.limited:
            self.active.extend(np.repeat((self._free if held is None else held[1])[None], k, axis=0))
            self.mu.extend(np.repeat(self.stepper.mu[None], k, axis=0) if held is None else held[2])
            self.qdot.extend(qdot)
        if self.rows is not None:  # (row_record's with no row active: no multipliers)
            active, none = self.stepper.rows, np.zeros(0)
            self.rows += [(v, active, none) for v in smallest]

    def _lam_full(self) -> np.ndarray:
        """lambda per point in the closure 7-vector's coordinates (augmented pose task: U lambda), else lambda."""
        lam = self.lam.array()
        basis = self.stepper.pt.basis
        return lam if basis is None else lam @ basis.T

    def __len__(self) -> int:
        return len(self.t)

    def _limits_record(self, q: np.ndarray, meta: dict) -> dict:
        """The limits' record: active sets, bound multipliers, margins, switches, speeds against the limits."""
        s = self.stepper
        lim = s.limits
        speeds = np.abs(self.qdot.array())
        vmax = np.asarray(s.ev.robot.model.velocityLimit, dtype=float)
        fastest = speeds.max(axis=0)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(vmax > 0, fastest / vmax, np.inf)
        meta.update(switches=list(s.switches), joint_speed_max=fastest.tolist(), velocity_limit=vmax.tolist(),
                    speed_over_velocity_limit_max=float(np.max(ratio)) if np.all(np.isfinite(ratio)) else None,
                    limit_margin=lim.margin)
        return {"active_bounds": self.active.array(),
                "bound_multipliers": self.mu.array(), "limit_margins": np.minimum(lim.margins(q), 1e10),
                "switch_times": np.array([w["t"] for w in s.switches], dtype=float)}

    def _evaluate(self, q: np.ndarray, oriented: bool):
        """(Q (k, 3, 3), p (k, 3), {k: J} where the step's own evaluation was made at recorded point k, p_d (k, 3),
        Q_d (k, 3, 3), None where the task has no orientation (``oriented``)): the pose afresh at the other
        recorded joints (K there is left to :class:`Diagnostics`). A run's rows (:class:`PoseRows`) are stacked as
        the blocks they are, the points recorded one by one in between a block each."""
        kin = self.stepper.ev.robot.kinematics
        blocks, single, own = [], [], {}

        def close() -> None:  # the points recorded one by one since the last block, as one block
            if single:
                Q, p, p_d, Q_d = zip(*single, strict=True)
                blocks.append((np.array(Q), np.array(p), np.array(p_d), np.array(Q_d) if oriented else None))
                single.clear()

        k = 0
        for item in self.points:
            if isinstance(item, PoseRows):  # the rows of a run (add_rows)
                close()
                blocks.append((item.Q, item.p, item.p_d, item.Q_d))
                k += len(item.p)
                continue
            if hasattr(item, "terms"):
                (Q, p), own[k], sample = (item.Q, item.p), item.J, item.sample
            elif hasattr(item, "pose"):
                (Q, p), sample = item.pose, item.sample
            else:
                (Q, p), sample = kin.pose(q[k]), item
            single.append((Q, p, sample.p, sample.Q))
            k += 1
        close()
        Q, p, p_d = (np.concatenate([b[j] for b in blocks]) for j in range(3))
        return Q, p, own, p_d, np.concatenate([b[3] for b in blocks]) if oriented else None

    def trajectory(self, *, robot_name: str, scheme: str, mode: str, loops: int | None, steps_per_loop: int | None,
                   period: float | None, meta: dict) -> Trajectory:
        """The :class:`~kinredund.trajectory.Trajectory` of the run (``loops``: the loop drift per loop)."""
        s = self.stepper
        task = get_task(s.ev.task)
        t, q = np.array(self.t), self.q.array()
        Q, p, own, p_d, Q_d = self._evaluate(q, task.has_orientation)
        errors = task.errors_many(Q, p, Q_d, p_d)
        zeros = np.zeros(len(p))  # the trace and vect errors of tasks that do not hold them, as always recorded
        index = s.ev.index  # grad z now: the index is the caller's object, the record must not follow it
        grad = np.zeros_like(q) if index is None else index.gradients_many(q, t)
        diag = Diagnostics(self, t, q, grad, own, Q_d)
        eigs = diag.eigenvalues
        solver = Deferred(diag.solver) if diag.pending else tuple(self.solver)
        drift = None
        if loops is not None:
            drift = np.array([joint_drift(q[0], q[(i + 1) * steps_per_loop], s.ev.robot.revolute)
                              for i in range(loops)])
        extra = self._limits_record(q, meta) if self.limited else {}
        if self.rows is not None:  # the general constraints' record (issue 27): per point, and the switches
            meta.update(switches=list(s.switches), constraints={
                "names": s.row_names(range(len(s.row_pairs))), "min_value": [r[0] for r in self.rows],
                "active": [list(r[1]) for r in self.rows], "multipliers": [r[2].tolist() for r in self.rows]})
        return Trajectory(
            **extra, robot=robot_name, task=task.name, t=t, q=q, p=p, p_desired=p_d, scheme=scheme,
            mode=mode,
            solver=solver, lam=self._lam_full(), m_eigs=Deferred(diag.m_eigs) if eigs else None,
            m_null_eigs=Deferred(diag.m_null_eigs) if eigs else None,
            position_error=errors["position_error"], trace_error=errors.get("trace_error", zeros),
            vect_error=errors.get("vect_error", zeros), axis_error=errors.get("axis_error"),
            normality_residual=Deferred(diag.normality_residual), loop_drift=drift, loop_period=period, meta=meta)


class Column:
    """One recorded vector field (q, lambda, the rates, the bound multipliers): rows added one by one
    (:meth:`append`, the stepper's arrays, kept by reference) or as a run's block (:meth:`extend`: a 2-D array of
    rows), stacked into one array when read (:meth:`array`: a new array, the rows' values)."""

    __slots__ = ("_blocks", "_rows", "_count")

    def __init__(self):
        self._blocks: list = []  # 2-D arrays and lists of rows, in order
        self._rows: list = []  # the rows appended since the last block
        self._count = 0

    def append(self, row) -> None:
        self._rows.append(row)
        self._count += 1

    def extend(self, block: np.ndarray) -> None:
        self._flush()
        self._blocks.append(block)
        self._count += len(block)

    def _flush(self) -> None:
        if self._rows:
            self._blocks.append(self._rows)
            self._rows = []

    def __len__(self) -> int:
        return self._count

    def array(self) -> np.ndarray:
        """The rows stacked (k, width)."""
        self._flush()
        blocks = self._blocks
        if len(blocks) == 1:
            return np.array(blocks[0])
        return np.concatenate([b if isinstance(b, np.ndarray) else np.array(b) for b in blocks])  # (one copy each)

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        out = self.array()
        return out if dtype is None else out.astype(dtype)


class PoseRows:
    """The points of a run of steps (:meth:`Recorder.add_rows`), stacked: the pose (Q, p) at the corrected joints and
    the path's p_d and Q_d (None without orientation), one row per step."""

    __slots__ = ("Q", "p", "p_d", "Q_d")

    def __init__(self, Q, p, p_d, Q_d):
        self.Q, self.p, self.p_d, self.Q_d = Q, p, p_d, Q_d


class Diagnostics:
    """A run's diagnostics, computed together on the first call of any of them, then kept.

    The normality residual ||Z^T grad z|| (Eq. 4.5, Z a null-space basis of J; J's rows afresh at each
    corrected point the step did not evaluate, grad z as the recorder computed it), with ``diagnostics``
    the eigenvalues of M and of Z^T M Z (Theorem 2), and the solver labels the steps left pending
    (:func:`labels_many`, which the eigenvalues make cheap). Until then it holds the run's arrays
    (about 1 KiB per point on a 7-axis arm; M and the step's J per point, stacked when first read) and the
    robot for its kinematics; it drops them once computed. Safe to read from several threads (one computes,
    the others wait).
    """

    def __init__(self, rec: Recorder, t: np.ndarray, q: np.ndarray, grad: np.ndarray, own: dict,
                 Q_d: np.ndarray | None):
        s = rec.stepper
        self.pending = [k for k, v in enumerate(rec.solver) if v is None]
        self.eigenvalues = rec.diagnostics and all(M is not None for M in rec.M)
        # copies (the record's t and q are the caller's to change); M and J per step are stacked when first read
        # (the steppers never change them in place)
        self._inputs = (t.copy(), q.copy(), grad, own, Q_d, s.ev.robot, s.ev.task, list(rec.M), list(rec.J_step),
                        list(rec.solver), s.linear_solver, s.symmetric)
        self._out = None
        self._lock = threading.Lock()

    def _compute(self) -> dict:
        with self._lock:
            if self._out is None:
                self._out = self._run(*self._inputs)
                self._inputs = None
            return self._out

    def _run(self, t, q, grad, own, Q_d, robot, task_name, Ms, Js_step, solver, rule, symmetric) -> dict:
        kin, task = robot.kinematics, get_task(task_name)
        M = np.array(Ms) if self.eigenvalues else None
        M_pending = None if M is not None or not self.pending else np.array([Ms[k] for k in self.pending])
        J_pending = np.array([Js_step[k] for k in self.pending]) if self.pending else None
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
        if self.pending:
            # the labels' (M, J) are the step's (at its predicted point, within the corrector's step of
            # the recorded one): the eigenvalues decide where they are clearly signed, classify elsewhere
            k = self.pending
            eig = None if out["m_eigs"] is None else out["m_eigs"][k]
            eig_null = None if out["m_null_eigs"] is None else out["m_null_eigs"][k]
            Ms = M[k] if M is not None else M_pending
            for i, label in zip(k, labels_many(list(Ms), list(J_pending), rule, symmetric, eig, eig_null),
                                strict=True):
                labels[i] = label
        out["solver"] = tuple(labels)
        return out

    def normality_residual(self) -> np.ndarray:
        return self._compute()["normality_residual"]

    def m_eigs(self) -> np.ndarray | None:
        return self._compute()["m_eigs"]

    def m_null_eigs(self) -> np.ndarray | None:
        return self._compute()["m_null_eigs"]

    def solver(self) -> tuple[str, ...]:
        return self._compute()["solver"]
