"""End-effector paths as functions of time: pose and twist (Chapter 4 examples, Section 3.2, Chapter 6).

A path returns, at time t, a :class:`PathSample`: the position p_d [m] of point P, its velocity
v_d [m/s], and for pose tasks the rotation Q_d and angular velocity omega_d [rad/s] (world axes).
Closed paths have a ``period`` [s].

- :class:`Circle`: a circle in a plane through its centre with unit normal n, constant speed,
  counter-clockwise about n (Examples 4.1-4.2 in the xy-plane; Example 4.3 about +x with the Frenet
  frame Q_d = [e_n, e_t, e_n x e_t], Eqs. 4.47-4.48).
- :class:`Ellipse`: an ellipse in the xy-plane (Chapter 6), constant angular rate of its parameter.
- :class:`Helix`: the helix of Section 3.2.
- :class:`FunctionPath`: a user path from a callable t -> (p, v) or (Q, p, omega, v).
- :class:`AxisPath`: a point and a tool axis alone (the tool-axis task).
- :class:`SampledPath`, :func:`read_path_file`: splines through samples, from data or a JSON file.
"""

from kinredund.paths.analytic import Circle, Ellipse, Helix
from kinredund.paths.base import Path, PathSample
from kinredund.paths.sampled import ROTATION_TOL, SampledPath, read_path_file
from kinredund.paths.user import AxisPath, FunctionPath

__all__ = ["ROTATION_TOL", "AxisPath", "Circle", "Ellipse", "FunctionPath", "Helix", "Path", "PathSample",
           "SampledPath", "read_path_file"]
