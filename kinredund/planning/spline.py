"""Step 2 of the off-line procedure (Section 6.2.2.2): joint estimates between the sample points.

The joint values at the sample points are interpolated by a cubic spline in time; its values are the
estimates theta*(t) and its derivative the feed-forward rate of Eq. (6.27).

Boundary conditions: the thesis uses a *natural* spline (zero second derivative at both ends). The path
is a closed loop, so we default to a *periodic* spline instead: it is C2 across the start/end of the
loop, so the estimate and its rate join up from one loop to the next, whereas a natural spline has a
kink in the rate there (its end slopes differ). ``bc="natural"`` gives the thesis's choice.

Revolute joints may gain whole turns over a loop (the sample values are unwrapped one after the
other); the spline then interpolates q - turns t / T, which is periodic, and adds the ramp back.

Units: times [s], joints [rad or m].
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicSpline

from kinredund.errors import check_choice
from kinredund.kinematics.angles import wrap_joints

SPLINE_KINDS = ("periodic", "natural")


def unwrap_samples(q: np.ndarray, revolute: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Make consecutive samples continuous (revolute joints shifted by whole turns) and find the turns.

    Returns:
        (q unwrapped (N, n), turns (n,)): turns = the closing value minus q[0], a multiple of 2 pi for
        revolute joints and 0 for prismatic ones.
    """
    q = np.asarray(q, float)
    out = q.copy()
    for k in range(1, len(q)):
        out[k] = out[k - 1] + wrap_joints(q[k] - out[k - 1], revolute)
    close = out[-1] + wrap_joints(q[0] - out[-1], revolute)
    return out, close - out[0]


class JointSpline:
    """theta*(t) through the samples of one loop (period T), periodic or natural (module docstring).

    Args:
        t: sample times in [0, T), strictly increasing, t[0] = 0 [s].
        q: unwrapped sample joints (N, n).
        period: T [s].
        turns: joint change over one loop (N,) [rad or m].
        bc: ``periodic`` or ``natural``.
    """

    def __init__(self, t, q, period: float, turns, bc: str = "periodic"):
        check_choice("spline boundary condition", bc, SPLINE_KINDS)
        t = np.asarray(t, float)
        q = np.asarray(q, float)
        self.period = float(period)
        self.turns = np.asarray(turns, float)
        tt = np.append(t, self.period)
        if bc == "periodic":
            y = q - np.outer(t / self.period, self.turns)
            y = np.vstack([y, y[0]])
            self._spline = CubicSpline(tt, y, bc_type="periodic")
            self._ramp = self.turns / self.period
        else:
            y = np.vstack([q, q[0] + self.turns])
            self._spline = CubicSpline(tt, y, bc_type="natural")
            self._ramp = np.zeros_like(self.turns)
        self._d = self._spline.derivative()

    def __call__(self, t: float) -> np.ndarray:
        """theta*(t) [rad or m]."""
        return self._spline(t) + self._ramp * t

    def rate(self, t: float) -> np.ndarray:
        """d theta*/dt, the feed-forward of Eq. (6.27) [rad/s or m/s]."""
        return self._d(t) + self._ramp

    def values(self, ts) -> np.ndarray:
        """theta* at many times, shape (len(ts), n)."""
        ts = np.asarray(ts, float)
        return self._spline(ts) + np.outer(ts, self._ramp)
