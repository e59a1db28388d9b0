"""The hybrid closed-form inverse kinematics of the PUMA-derived 7-axis arm (Chapter 3).

:class:`ClosedFormIK` chains the pieces of Section 3.1:

1. the wrist centre is point P of the target pose (our wrist rows put P at O5);
2. theta1, both branches, Eqs. (3.3)-(3.7) (:mod:`.positioning`);
3. theta3, theta4: the constrained minimum of Eq. (3.30) (or 3.31) subject to Eq. (3.25)
   (:mod:`.redundancy`); it depends only on xi^2 + eta^2, the same for both theta1 branches;
4. theta2 from Eqs. (3.17)-(3.24);
5. the spherical wrist, both branches (:mod:`.wrist`).

:meth:`ClosedFormIK.solve_all` returns the 2 x 2 branch records; :meth:`ClosedFormIK.solve` picks
one; :meth:`ClosedFormIK.position_all` and :meth:`ClosedFormIK.position` solve the positioning problem
alone (Section 3.2). Joint values come back inside the joint limits where a 2 pi shift puts them there
(``within_limits`` says whether it did); the objective is that of the 2-D problem, whose angles are
the 2 pi representatives nearest the references.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kinredund.closed_form.positioning import ArmGeometry, plane_radius2, shoulder_branches, theta2_from
from kinredund.closed_form.redundancy import (
    OBJECTIVES,
    IsotropicConfiguration,
    RedundancySolution,
    isotropic_configuration,
)
from kinredund.closed_form.redundancy import solve_redundancy as _solve_redundancy
from kinredund.closed_form.wrist import rot_x, solve_wrist
from kinredund.errors import JointVectorError, check_array, check_choice
from kinredund.kinematics.angles import turn_into_limits, wrap_joints
from kinredund.kinematics.recursive import rotation_products
from kinredund.tasks import make_target

PICKS = ("lowest", "nearest")


@dataclass(frozen=True)
class PositioningSolution:
    """One theta1 branch of the positioning problem (axes 1-4 place the wrist centre).

    Attributes:
        q: joint values of axes 1-4 [rad], shape (4,).
        objective: z of Eq. (3.30) or (3.31) at (theta3, theta4) [rad^2].
        multiplier: lambda of Eq. (3.40).
        position_residual: max-abs error [m] of the wrist centre by forward kinematics.
        shoulder: ``front`` or ``back`` (the theta1 branch).
        axis1_singular: d = 0 and the wrist centre on axis 1 (theta1 was free: the hint was used).
        redundancy: the full record of the 2-D problem.
    """

    q: np.ndarray
    objective: float
    multiplier: float
    position_residual: float
    shoulder: str
    axis1_singular: bool
    redundancy: RedundancySolution


@dataclass(frozen=True)
class IKBranch:
    """One branch of the 7-axis solution (theta1 branch x wrist branch).

    Attributes:
        q: joint values [rad], shape (7,).
        objective: z of the 2-D problem (equal on all branches of one pose) [rad^2].
        fk_residual: max-abs entry of FK(q) - target, the 4x4 pose [m and dimensionless].
        shoulder: ``front`` or ``back``.
        wrist: ``theta6+``, ``theta6-`` or ``singular``.
        wrist_singular: |sin theta6| below the solver's tolerance (axes 5 and 7 aligned).
        sin_theta6: |sin theta6|.
        within_limits: every joint value lies inside the robot's limits.
        multiplier: lambda of Eq. (3.40).
    """

    q: np.ndarray
    objective: float
    fk_residual: float
    shoulder: str
    wrist: str
    wrist_singular: bool
    sin_theta6: float
    within_limits: bool
    multiplier: float

    @property
    def label(self) -> str:
        """``shoulder/wrist``, e.g. ``front/theta6+``."""
        return f"{self.shoulder}/{self.wrist}"


class ClosedFormIK:
    """Hybrid closed-form IK of the Chapter 3 arm: theta1, theta2 and the wrist in closed form, the
    redundancy (theta3, theta4) by a 2-D constrained minimisation.

    Args:
        robot: a :class:`~kinredund.Robot` built from an HD table with the Chapter 3 architecture
            (default ``load_robot("puma7")``; ``robot_from_hd(puma7(d))`` for a shoulder offset d).
        references: (q3*, q4*) joint values [rad]; default: the isotropic configuration of links 2-4
            (:func:`~.redundancy.isotropic_configuration`; 94.09 and 97.42 deg for Section 3.2).
        objective: ``angle`` (Eq. 3.30, default) or ``sincos`` (Eq. 3.31).
        singular_tol: |sin theta6| below which a wrist branch is flagged singular.
        samples: nodes per arc of the constraint curve in the global search of the 2-D problem.

    Raises:
        HDTableError: the robot has no HD table, or not the Chapter 3 architecture.
        ChoiceError: unknown objective.
        JointVectorError: references that are not two finite numbers.
    """

    def __init__(self, robot=None, references=None, objective: str = "angle", *,
                 singular_tol: float = 1e-8, samples: int = 96):
        if robot is None:
            from kinredund.model.loader import load_robot

            robot = load_robot("puma7")
        self.robot = robot
        self.geometry = ArmGeometry.from_hd(robot.hd)
        self.objective = check_choice("objective", objective, OBJECTIVES)
        self.singular_tol = float(singular_tol)
        self.samples = int(samples)
        theta0 = np.array(self.geometry.theta0)
        self.isotropic: IsotropicConfiguration | None = None
        if references is None:
            self.isotropic = isotropic_configuration(self.geometry)
            refs = np.array([self.isotropic.theta3, self.isotropic.theta4]) - theta0[2:4]
        else:
            refs = check_array(references, (2,), "references (q3*, q4*) [rad]", JointVectorError)
        self.references = refs
        self._theta_refs = refs + theta0[2:4]

    @property
    def theta_references(self) -> np.ndarray:
        """The references as HD angles (theta3*, theta4*) [rad] (joint values + theta0)."""
        return self._theta_refs.copy()

    # -- pieces ------------------------------------------------------------------------------------
    def _joint_values(self, theta: np.ndarray) -> tuple[np.ndarray, bool]:
        """HD angles -> joint values shifted by 2 pi into the limits where possible."""
        n = theta.shape[0]
        q = theta - np.array(self.geometry.theta0[:n])
        lo, hi = self.robot.lower[:n], self.robot.upper[:n]
        shifted, ok = turn_into_limits(q, lo, hi)
        q = np.where(ok, shifted, q)
        return q, bool(np.all((q >= lo) & (q <= hi)))

    def redundancy(self, rho2: float) -> RedundancySolution:
        """The 2-D problem for xi^2 + eta^2 = rho2 [m^2] with this solver's references and objective."""
        return _solve_redundancy(self.geometry, rho2, self._theta_refs, self.objective, self.samples)

    def position_all(self, wrist_centre, theta1_hint: float = 0.0) -> list[PositioningSolution]:
        """Both theta1 branches of the positioning problem for a wrist-centre position [m].

        Raises:
            TaskError: not 3 finite numbers.
            UnreachableError: inside the inner cylinder or out of the reach of links 2-4.
        """
        p = check_array(wrist_centre, (3,), "wrist-centre position [m]")
        geom = self.geometry
        rho2 = plane_radius2(geom, p)
        sol = self.redundancy(rho2)
        hint = float(theta1_hint) + geom.theta0[0]
        out = []
        for br in shoulder_branches(geom, p, hint):
            theta2 = theta2_from(geom, br.xi, br.eta, sol.theta3, sol.theta4)  # Eq. (3.24)
            q4, _ = self._joint_values(np.array([br.theta1, theta2, sol.theta3, sol.theta4]))
            full = np.concatenate([q4, np.zeros(self.robot.nq - 4)])
            _, reached = self.robot.kinematics.pose(full)
            out.append(PositioningSolution(
                q4, sol.objective, sol.multiplier, float(np.abs(reached - p).max()), br.label,
                br.axis1_singular, sol,
            ))
        return out

    def position(self, wrist_centre, pick: str = "lowest", q_near=None) -> PositioningSolution:
        """One positioning solution: ``lowest`` objective (ties: the front branch) or ``nearest`` q_near
        (4 or n joint values [rad]; the first 4 are compared).

        Raises:
            ChoiceError: unknown ``pick``.
            JointVectorError: ``pick="nearest"`` without a valid ``q_near``.
        """
        near = self._check_near(pick, q_near, 4)
        return self._pick(self.position_all(wrist_centre), pick, near, 4)

    def solve_all(self, pose, q_hint=None) -> list[IKBranch]:
        """Every branch (front/back x theta6+/theta6-) for a 4x4 target pose of the end-effector frame.

        Args:
            pose: 4x4 homogeneous matrix [m]; its origin is the wrist centre (point P).
            q_hint: joint values [rad] used for the free angles at singularities (theta1 with the
                wrist centre on axis 1 and d = 0; theta5 at the wrist singularity); default zeros.

        Raises:
            TaskError: not a 4x4 homogeneous matrix (last row (0, 0, 0, 1)) with a rotation block
                (:func:`kinredund.tasks.make_target`).
            UnreachableError: the wrist centre is out of reach.
        """
        target = make_target("pose", pose)
        hint = np.zeros(self.robot.nq) if q_hint is None else self.robot.check_q(q_hint, "q_hint")
        return self._solve_all(target, hint)

    def _solve_all(self, target, hint: np.ndarray) -> list[IKBranch]:
        """:meth:`solve_all` for a validated pose :class:`~kinredund.tasks.Target` and hint (n,)."""
        theta0 = np.array(self.geometry.theta0)
        rest = np.zeros(self.robot.nq - 4)
        target_w = target.Q @ rot_x(self.geometry.alpha7).T
        out = []
        for pos in self.position_all(target.p, theta1_hint=hint[0]):
            theta_arm = pos.q + theta0[:4]
            arm = rotation_products(self.robot.hd, np.concatenate([pos.q, rest]))[4]  # Q1 Q2 Q3 Q4, Eq. (2.1)
            W = arm.T @ target_w
            for w in solve_wrist(W, hint[4] + theta0[4], self.singular_tol):
                q, inside = self._joint_values(np.concatenate([theta_arm, [w.theta5, w.theta6, w.theta7]]))
                R, p = self.robot.kinematics.pose(q)
                residual = max(float(np.abs(R - target.Q).max()), float(np.abs(p - target.p).max()))
                out.append(IKBranch(q, pos.objective, residual, pos.shoulder, w.label, w.singular,
                                    w.sin_theta6, inside, pos.multiplier))
        return out

    def solve(self, pose, pick: str = "lowest", q_near=None) -> IKBranch:
        """One branch: ``lowest`` objective (ties broken in :meth:`solve_all` order: front before back,
        theta6+ before theta6-) or ``nearest`` to ``q_near`` (wrapped joint distance).

        Raises:
            ChoiceError: unknown ``pick``.
            JointVectorError: ``pick="nearest"`` without a valid ``q_near``.
        """
        target = make_target("pose", pose)
        near = self._check_near(pick, q_near, self.robot.nq)
        hint = np.zeros(self.robot.nq) if near is None else near
        return self._pick(self._solve_all(target, hint), pick, near, self.robot.nq)

    def _check_near(self, pick: str, q_near, n: int) -> np.ndarray | None:
        """Validate ``pick`` and q_near (n or robot.nq joint values [rad]; None is allowed with
        ``pick="lowest"``) once, before solving."""
        check_choice("pick", pick, PICKS)
        if q_near is None:
            if pick == "nearest":
                raise JointVectorError("pick='nearest' needs q_near, a joint vector to be near")
            return None
        near = check_array(q_near, (None,), "q_near", JointVectorError)
        if near.shape[0] not in (n, self.robot.nq):
            lengths = f"{n}" if n == self.robot.nq else f"{n} or {self.robot.nq}"
            raise JointVectorError(f"q_near must have {lengths} joint values [rad] for {self.robot.name}, "
                                   f"got {near.shape[0]}")
        return near

    @staticmethod
    def _pick(records, pick: str, near: np.ndarray | None, n: int):
        """The record of lowest objective, or nearest the validated ``near`` (wrapped joint distance)."""
        if pick == "lowest":
            best = min(r.objective for r in records)
            return next(r for r in records if r.objective <= best + 1e-12 * max(1.0, best))
        return min(records, key=lambda r: float(np.linalg.norm(wrap_joints(r.q - near[:n]))))

