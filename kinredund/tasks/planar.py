"""The planar task: (x, y) of point P in the plane of a planar arm (m = 2; Chapter 4, Examples 4.1-4.2).

The position task restricted to the rows pdot_x, pdot_y of K; a target (x, y) is placed at the plane
height z.

Spurious zeros: none. The residual (x - x_d, y - y_d) vanishes exactly where the point's x and y are on
the target: z is no part of the task (a planar arm keeps it constant; on a spatial arm it is free, as
the task says).
"""

from __future__ import annotations

import numpy as np

from kinredund.tasks.position import PositionTask


class PlanarTask(PositionTask):
    """(x, y) of point P [m]."""

    name = "planar"
    dim = 2
    planar = True
    point_rows = np.array([3, 4])

    def _point(self, x: np.ndarray, z: float) -> np.ndarray:
        return np.array([x[0], x[1], z])
