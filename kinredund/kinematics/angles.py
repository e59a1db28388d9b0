"""Joint-angle utilities: wrapping revolute joints, drift modulo 2 pi, turning angles into limits."""

from __future__ import annotations

import numpy as np


def wrap_joints(d, revolute=True) -> np.ndarray:
    """Joint values or differences with the revolute entries brought into [-pi, pi) [rad]."""
    d = np.asarray(d, float)
    return np.where(revolute, (d + np.pi) % (2 * np.pi) - np.pi, d)


def joint_drift(q_start: np.ndarray, q_end: np.ndarray, revolute: np.ndarray) -> float:
    """max |q_end - q_start| with revolute joints compared modulo 2 pi [rad]."""
    return float(np.max(np.abs(wrap_joints(np.asarray(q_end, float) - np.asarray(q_start, float), revolute))))


def loop_drifts(q: np.ndarray, steps_per_loop: int, loops: int, revolute: np.ndarray) -> np.ndarray:
    """:func:`joint_drift` from q[0] to the end of each loop, q[(i + 1) steps_per_loop] for i < ``loops``, in one
    pass: (loops,) [rad or m]. ``q``: float (N, n), N > loops steps_per_loop."""
    ends = q[steps_per_loop:loops * steps_per_loop + 1:steps_per_loop]
    return np.abs(wrap_joints(ends - q[0], revolute)).max(axis=1)


def turn_into_limits(q: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(q + 2 pi k, ok): each angle turned by the multiple of 2 pi that brings it to the lowest value
    >= its lower limit [rad], and whether that value is also <= the upper limit (where it is not, no
    turn puts the angle inside the limits). The pose does not change for revolute joints."""
    turned = q + 2.0 * np.pi * np.ceil((lower - q) / (2.0 * np.pi))
    return turned, turned <= upper
