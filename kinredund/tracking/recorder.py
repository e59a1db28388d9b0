"""The record of a tracking run: per step what the stepper reached, diagnostics computed once per run.

:class:`Recorder` keeps, per recorded point, only what the stepper already has (t, q, lambda, M, the
step's J and path sample, its evaluation where it was made at the recorded point). At the end,
:meth:`Recorder.trajectory` evaluates afresh where needed (the default mode's evaluation is at the
predicted point: there the pose and K, and grad z, at the corrected joints) and computes the
diagnostics in a few batched numpy calls per run: the task's errors (:meth:`kinredund.tasks.Task.errors_many`), the
normality residual ||(1 - J^+ J) grad z|| (Eq. 4.5), the solver labels of Theorem 2 and, with
``diagnostics``, the eigenvalues of M and of its projection on the null space of J. Recording then costs
little next to the step itself (``benchmarks/resolved_rate.py``: ``track_over_step``).
"""

from __future__ import annotations

import numpy as np

from kinredund.kinematics.angles import joint_drift
from kinredund.tasks import get_task
from kinredund.tracking.linalg import eigs_many, labels_many, normality_many, null_space_bases, null_space_eigs_many
from kinredund.tracking.stepper import Stepper
from kinredund.trajectory import Trajectory


class Recorder:
    """Collects one row per recorded point of a :class:`~kinredund.tracking.stepper.Stepper`'s run."""

    def __init__(self, stepper: Stepper, diagnostics: bool = True):
        self.stepper, self.diagnostics = stepper, diagnostics
        self.t, self.q, self.lam, self.solver, self.M, self.J_step, self.points = [], [], [], [], [], [], []
        self.limited = getattr(stepper, "limits", None) is not None
        self.active, self.mu, self.qdot = [], [], []

    def add(self) -> None:
        """Record the stepper's current point (M and J may come from the step's predicted point).

        The steppers assign new arrays at every step and never change q, lambda, M, the rates or the
        bound multipliers in place, so the record keeps references (the active set, changed in place at
        a switch, is copied only while a bound is active).
        """
        s = self.stepper
        pt = s.pt
        pending = s.label_pending
        self.t.append(s.t)
        self.q.append(s.q)
        self.lam.append(s.lam)  # in the closure 7-vector's coordinates at the end (lam_full, batched)
        self.solver.append(None if pending else s.solver)
        self.M.append(s.M)
        self.J_step.append(pt.J if pending else None)
        self.points.append(pt if pt.q is s.q and pt.t == s.t else pt.sample)
        if self.limited:
            self.active.append(s.active_bounds() if s.any_active else None)
            self.mu.append(s.mu)
            self.qdot.append(s.qdot)

    def _lam_full(self) -> np.ndarray:
        """lambda per point in the closure 7-vector's coordinates (augmented pose task: U lambda), else lambda."""
        lam = np.array(self.lam)
        basis = self.stepper.pt.basis
        return lam if basis is None else lam @ basis.T

    def __len__(self) -> int:
        return len(self.t)

    def _limits_record(self, q: np.ndarray, meta: dict) -> dict:
        """The limits' record: active sets, bound multipliers, margins, switches, speeds against the limits."""
        s = self.stepper
        lim = s.limits
        speeds = np.abs(np.array(self.qdot))
        vmax = np.asarray(s.ev.robot.model.velocityLimit, dtype=float)
        fastest = speeds.max(axis=0)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(vmax > 0, fastest / vmax, np.inf)
        meta.update(switches=list(s.switches), joint_speed_max=fastest.tolist(), velocity_limit=vmax.tolist(),
                    speed_over_velocity_limit_max=float(np.max(ratio)) if np.all(np.isfinite(ratio)) else None,
                    limit_margin=lim.margin)
        free = np.zeros(len(q[0]), dtype=int)
        return {"active_bounds": np.array([free if a is None else a for a in self.active]),
                "bound_multipliers": np.array(self.mu), "limit_margins": np.minimum(lim.margins(q), 1e10),
                "switch_times": np.array([w["t"] for w in s.switches], dtype=float)}

    def _evaluate(self):
        """Per point (Q, p, J or the rows of K with J's row space, grad z, sample): the step's own
        evaluation where it was made at the recorded point, else afresh at the recorded joints."""
        ev = self.stepper.ev
        kin, task = ev.robot.kinematics, get_task(ev.task)
        Qs, ps, Js, grads, samples = [], [], [], [], []
        for t, q, item in zip(self.t, self.q, self.points, strict=True):
            if hasattr(item, "terms"):
                Q, p, J, grad, sample = item.Q, item.p, item.J, item.grad, item.sample
            else:
                Q, p, K = kin.jacobian(q)
                # rows with J's row space on the path: the null space of J, and with it the normality
                # residual of Eq. (4.5), follows from K alone (Task.span_rows)
                J, grad, sample = task.span_rows(Q, K, item), ev.gradient(q, t), item
            Qs.append(Q)
            ps.append(p)
            Js.append(J)
            grads.append(grad)
            samples.append(sample)
        return np.array(Qs), np.array(ps), np.array(Js), np.array(grads), samples

    def trajectory(self, *, robot_name: str, scheme: str, mode: str, loops: int | None, steps_per_loop: int | None,
                   period: float | None, meta: dict) -> Trajectory:
        """The :class:`~kinredund.trajectory.Trajectory` of the run (``loops``: the loop drift per loop)."""
        s = self.stepper
        task = get_task(s.ev.task)
        Q, p, J, grad, samples = self._evaluate()
        Z = null_space_bases(J)
        p_d = np.array([x.p for x in samples])
        Q_d = np.array([x.Q for x in samples]) if task.has_orientation else None
        errors = task.errors_many(Q, p, Q_d, p_d)
        zeros = np.zeros(len(p))  # the trace and vect errors of tasks that do not hold them, as always recorded
        m_eigs = m_null = None
        if self.diagnostics and all(M is not None for M in self.M):
            M = np.array(self.M)
            m_eigs, m_null = eigs_many(M), null_space_eigs_many(M, J, Z)
        solver = list(self.solver)
        pending = [k for k, v in enumerate(solver) if v is None]
        if pending:
            # the labels' (M, J) are the step's (at its predicted point, within the corrector's step of
            # the recorded one): the eigenvalues decide where they are clearly signed, classify elsewhere
            eig = None if m_eigs is None else m_eigs[pending]
            eig_null = None if m_null is None else m_null[pending]
            labels = labels_many([self.M[k] for k in pending], [self.J_step[k] for k in pending],
                                 s.linear_solver, s.symmetric, eig, eig_null)
            for k, label in zip(pending, labels, strict=True):
                solver[k] = label
        q = np.array(self.q)
        drift = None
        if loops is not None:
            drift = np.array([joint_drift(q[0], q[(i + 1) * steps_per_loop], s.ev.robot.revolute)
                              for i in range(loops)])
        extra = self._limits_record(q, meta) if self.limited else {}
        return Trajectory(
            **extra, robot=robot_name, task=task.name, t=np.array(self.t), q=q, p=p, p_desired=p_d, scheme=scheme,
            mode=mode,
            solver=tuple(solver), lam=self._lam_full(), m_eigs=m_eigs, m_null_eigs=m_null,
            position_error=errors["position_error"], trace_error=errors.get("trace_error", zeros),
            vect_error=errors.get("vect_error", zeros), axis_error=errors.get("axis_error"),
            normality_residual=normality_many(Z, grad), loop_drift=drift, loop_period=period, meta=meta)
