"""Joint speed, acceleration and jerk limits for retiming, and the tool-speed limit along the path.

Velocity limits come from the URDF where the robot has them (Pinocchio's ``model.velocityLimit``,
the ``<limit velocity=...>`` attribute). URDFs carry no acceleration limits (the format has no field
for them) and rarely a jerk limit, so those are always given by the caller: there is no default, a
guessed acceleration limit would be a wrong answer reported as success.

Units: [rad/s, rad/s^2, rad/s^3] for revolute joints, [m/s, m/s^2, m/s^3] for prismatic ones; the tool
speed is the speed of point P along the path [m/s].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kinredund.errors import KinredundError, check_positive
from kinredund.model.robot import NO_LIMIT


class RetimeError(KinredundError, ValueError):
    """Bad input to retiming or export: a limit, a record that is not a joint path, an output that exists."""


def _positive_vector(value, n: int, what: str) -> np.ndarray:
    """``value`` (a number or n numbers) as n finite numbers > 0, or RetimeError naming what is wrong."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as err:
        raise RetimeError(f"{what} must be a number or {n} numbers > 0, got {value!r}") from err
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    if arr.shape != (n,):
        raise RetimeError(f"{what} must be one number or {n} numbers (one per joint), got shape {arr.shape}")
    bad = [k for k, v in enumerate(arr) if not (math.isfinite(v) and v > 0)]
    if bad:
        raise RetimeError(f"{what} must be finite and > 0 for every joint; joint(s) {bad} have "
                          f"{[float(arr[k]) for k in bad]}")
    return arr


@dataclass(frozen=True)
class Limits:
    """The limits a retimed motion must hold at every sample.

    Attributes:
        velocity: joint speed limits |qdot_i| <= velocity_i, shape (n,) [rad/s or m/s].
        acceleration: |qddot_i| <= acceleration_i, shape (n,) [rad/s^2 or m/s^2].
        jerk: |qdddot_i| <= jerk_i, shape (n,) [rad/s^3 or m/s^3], or None (no jerk limit: the
            time-optimal TOPP-RA law, whose acceleration jumps between samples).
        tool_speed: the speed of point P along the path [m/s], or None.
    """

    velocity: np.ndarray
    acceleration: np.ndarray
    jerk: np.ndarray | None = None
    tool_speed: float | None = None

    @classmethod
    def make(cls, n: int, velocity, acceleration, jerk=None, tool_speed=None) -> Limits:
        """Validated limits for n joints; scalars apply to every joint.

        Raises:
            RetimeError: a limit that is missing, zero, negative, NaN, infinite or of the wrong length.
        """
        if velocity is None or acceleration is None:
            raise RetimeError("retiming needs velocity and acceleration limits (URDFs have no acceleration limits: "
                              "give them)")
        v = _positive_vector(velocity, n, "joint velocity limit [rad/s or m/s]")
        a = _positive_vector(acceleration, n, "joint acceleration limit [rad/s^2 or m/s^2]")
        j = None if jerk is None else _positive_vector(jerk, n, "joint jerk limit [rad/s^3 or m/s^3]")
        ts = None if tool_speed is None else check_positive(tool_speed, "tool-speed limit [m/s]", RetimeError)
        for arr in (v, a, j):
            if arr is not None:
                arr.flags.writeable = False
        return cls(v, a, j, ts)

    def to_dict(self) -> dict:
        """JSON-ready figures (for a record's ``meta``)."""
        return {"velocity": self.velocity.tolist(), "acceleration": self.acceleration.tolist(),
                "jerk": None if self.jerk is None else self.jerk.tolist(), "tool_speed": self.tool_speed}


def urdf_velocity_limits(robot) -> np.ndarray | None:
    """The robot's URDF velocity limits [rad/s or m/s], shape (n,), or None where the URDF has none.

    Pinocchio reads ``<limit velocity=...>`` into ``model.velocityLimit``; a joint without it gets 0 or
    an effectively infinite value (>= :data:`~kinredund.model.robot.NO_LIMIT`), which is no limit at all.
    """
    v = np.array(robot.model.velocityLimit, dtype=float)
    if v.shape != (robot.nq,) or not np.all(np.isfinite(v)) or np.any(v <= 0) or np.any(v >= NO_LIMIT):
        return None
    return v


def limits_for(robot, acceleration, velocity=None, jerk=None, tool_speed=None) -> Limits:
    """:class:`Limits` for ``robot``: ``velocity`` defaults to its URDF velocity limits.

    Args:
        robot: a :class:`~kinredund.model.robot.Robot`.
        acceleration: [rad/s^2 or m/s^2], a number or one per joint (required: URDFs have none).
        velocity: [rad/s or m/s], a number or one per joint; default the URDF's.
        jerk: [rad/s^3 or m/s^3], optional.
        tool_speed: [m/s], optional.

    Raises:
        RetimeError: a bad limit, or no velocity limit given for a robot whose URDF has none.
    """
    if velocity is None:
        velocity = urdf_velocity_limits(robot)
        if velocity is None:
            raise RetimeError(f"robot {robot.name!r} has no URDF velocity limits for every joint: give the velocity "
                              "limits (--vmax)")
    return Limits.make(robot.nq, velocity, acceleration, jerk, tool_speed)
