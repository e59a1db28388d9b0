"""Which closed paths a closed joint path inside the limits can follow: the orientation loop's class.

A joint motion that stays inside the limits and comes back to its start is a closed curve in a box of
R^n, which is contractible; its image under the forward kinematics is then a contractible loop in
SO(3). The orientation of a closed pose path is a loop in SO(3), whose fundamental group is Z_2: a loop
that turns the tool once about a fixed axis (the Frenet frame of a circle, Eq. 4.47, does: it turns
about the plane normal by 2 pi per loop) is *not* contractible, so **no within-limits joint path closes
after one loop of such a path**, on any arm. Traversed twice the loop is contractible, and a joint path
that closes after two loops may exist. (Joints with a range over one turn do not escape this: closing
means coming back to the same joint values, not to the same angles modulo 2 pi.)

:func:`orientation_loop_flips` decides the class numerically: a unit quaternion carried continuously
along the path (each sample's sign chosen nearest the previous one) comes back to itself after a
contractible loop and to its negative after a non-contractible one. :class:`RepeatedPath` is the path
run ``cycles`` times as one closed path, for planning a joint motion that repeats every ``cycles`` loops.

Units: times [s].
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from kinredund.errors import PathError, check_count
from kinredund.paths import Path, PathSample

#: orientation samples per loop for :func:`orientation_loop_flips`: consecutive quaternions must be far
#: closer than antipodal (a tool turning by less than pi between samples is enough)
LOOP_SAMPLES = 720


def orientation_loop_flips(path: Path, samples: int = LOOP_SAMPLES) -> bool | None:
    """True when the closed path's orientation loop is not contractible in SO(3) (module docstring),
    False when it is, None for a path without orientation.

    Raises:
        PathError: an open path.
    """
    if path.period is None:
        raise PathError("the orientation loop needs a closed path (one with a period)")
    if not path.has_orientation:
        return None
    ts = np.linspace(0.0, float(path.period), int(samples) + 1)
    quats = Rotation.from_matrix(np.array([path(float(t)).Q for t in ts])).as_quat()
    for k in range(1, len(quats)):  # carry the sign continuously along the loop
        if quats[k] @ quats[k - 1] < 0:
            quats[k] = -quats[k]
    return bool(quats[-1] @ quats[0] < 0)


class RepeatedPath(Path):
    """``base`` run ``cycles`` times: the same samples, the period ``cycles`` times the base's."""

    def __init__(self, base: Path, cycles: int):
        if base.period is None:
            raise PathError("only a closed path (one with a period) can be repeated")
        self.base = base
        self.cycles = check_count(cycles, 1, "cycles", PathError)
        self.period = float(base.period) * self.cycles
        self.has_orientation = base.has_orientation

    def sample(self, t: float) -> PathSample:
        return self.base.sample(t)


__all__ = ["LOOP_SAMPLES", "RepeatedPath", "orientation_loop_flips"]
