"""Joint-level inverse kinematics (Chapter 4.2, Appendix D): min z s.t. g(theta) = x, with bounds."""

from kinredund.ik.optimality import check_optimality
from kinredund.ik.solve import IKResult, solve_ik

__all__ = ["IKResult", "check_optimality", "solve_ik"]
