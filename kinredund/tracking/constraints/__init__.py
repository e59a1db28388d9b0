"""Constraints on the joints while tracking: one base class, one file per kind (as pink's ``limits/``).

- :class:`~kinredund.tracking.constraints.base.Constraint`: inequalities c(theta) >= 0 with their
  gradients, names and margins;
- :class:`~kinredund.tracking.constraints.joint_limits.JointLimits`: the robot's position limits (simple
  bounds);
- :class:`~kinredund.tracking.constraints.clearance.SphereClearance`,
  :class:`~kinredund.tracking.constraints.clearance.PlaneClearance`: a frame's origin kept clear of a sphere
  or a plane (general rows);
- :class:`~kinredund.tracking.constraints.scene.SceneClearance`: every pair a
  :class:`~kinredund.geometry.scene.Scene` checks kept its clearance apart (general rows, one per pair);
- :class:`~kinredund.tracking.constraints.pieces.CornerClearance`: the same with the pairs of two polytopes held
  as one row per piece (vertex to polytope, edge to edge), so that faces that come parallel are held.
"""

from kinredund.tracking.constraints.base import Constraint
from kinredund.tracking.constraints.clearance import PlaneClearance, SphereClearance
from kinredund.tracking.constraints.joint_limits import JointLimits
from kinredund.tracking.constraints.pieces import CornerClearance
from kinredund.tracking.constraints.scene import SceneClearance

__all__ = ["Constraint", "CornerClearance", "JointLimits", "PlaneClearance", "SceneClearance", "SphereClearance"]
