"""Hybrid closed-form inverse kinematics of the PUMA-derived 7-axis arm (thesis Chapter 3).

- :mod:`.positioning`: theta1 (Eqs. 3.3-3.7, both branches, the inner cylinder of Fig. 3.4) and theta2
  (Eqs. 3.17-3.24); :class:`UnreachableError`.
- :mod:`.redundancy`: theta3, theta4 minimising Eq. (3.30) or (3.31) subject to Eq. (3.25); the
  isotropic references of Section 3.2.
- :mod:`.polynomial`: the polynomial route, Eqs. (3.50)-(3.81), and its conditioning.
- :mod:`.wrist`: the spherical wrist, both branches, its singularity.
- :mod:`.solver`: :class:`ClosedFormIK`, the whole chain.
"""

from kinredund.closed_form.polynomial import Conditioning, PolynomialRoute, conditioning, polynomial_route
from kinredund.closed_form.positioning import ArmGeometry, UnreachableError
from kinredund.closed_form.redundancy import (
    IsotropicConfiguration,
    RedundancySolution,
    isotropic_configuration,
    solve_redundancy,
)
from kinredund.closed_form.solver import ClosedFormIK, IKBranch, PositioningSolution
from kinredund.closed_form.wrist import WristSolution, solve_wrist

__all__ = [
    "ArmGeometry",
    "ClosedFormIK",
    "Conditioning",
    "IKBranch",
    "IsotropicConfiguration",
    "PolynomialRoute",
    "PositioningSolution",
    "RedundancySolution",
    "UnreachableError",
    "WristSolution",
    "conditioning",
    "isotropic_configuration",
    "polynomial_route",
    "solve_redundancy",
    "solve_wrist",
]
