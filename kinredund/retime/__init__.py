"""Retiming: joint speed, acceleration and jerk limits by a new time law along the same optimal joint path.

- :mod:`~kinredund.retime.limits`: :class:`Limits` (velocity from the URDF, acceleration given), errors;
- :mod:`~kinredund.retime.joint_path`: the record's joint path theta*(s) as a quintic spline;
- :mod:`~kinredund.retime.time_law`: TOPP-RA (periodic for closed paths) and the jerk-limited law;
- :mod:`~kinredund.retime.retime`: :func:`retime`, the retimed record and its interpolation;
- :mod:`~kinredund.retime.resample`: :func:`resample`, the motion at uniform times, each sample solved exactly.
"""

from kinredund.retime.limits import Limits, RetimeError, limits_for, urdf_velocity_limits
from kinredund.retime.resample import resample
from kinredund.retime.retime import RetimeResult, retime

__all__ = ["Limits", "RetimeError", "RetimeResult", "limits_for", "resample", "retime", "urdf_velocity_limits"]
