"""Checking a motion: the least clearance along a sampled joint path, between the samples too.

:func:`check_motion` evaluates the scene's closest pair at every sample of the motion and then proves the
stretches between samples free, or finds their minimum, by conservative advancement: between two samples
the joints move linearly, and no point of the robot (nor of an object it carries) moves farther than

    delta = sum_i |dq_i| R_i,

R_i the reach of joint i: the longest distance from its axis to a point of a body it moves, bounded from the
model and the motion (the joint offsets along the chain, the slides of the prismatic joints in it up to the
motion's largest |q|, plus each object's bounding spheres; 1 for a prismatic joint).
Each pair's signed distance changes by at most the displacement of its two bodies (2 delta between two robot
bodies), so over a stretch the clearance is at least (d_k + d_(k+1))/2 - delta. A stretch whose bound falls
below the least clearance found so far (minus ``resolution``) is halved and its midpoint evaluated, until every
stretch is proven: the true minimum lies within ``resolution`` below the reported one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kinredund.errors import GeometryError, check_array
from kinredund.geometry.scene import Scene
from kinredund.geometry.shapes import positive

#: the default resolution [m]: the motion's least clearance is found to within this
RESOLUTION = 1e-4
#: the most midpoints evaluated per stretch between two samples before giving up on proving it
MAX_SPLITS = 4096


@dataclass(frozen=True)
class Clearance:
    """The clearance along a motion.

    Attributes:
        t: the samples' times [s], shape (N,).
        distance: the least signed distance at each sample [m], shape (N,).
        pairs: the closest pair at each sample.
        min_distance: the least clearance found [m], at samples or between them; the true minimum is at
            least ``min_distance - resolution``.
        min_pair: the pair of ``min_distance``.
        min_time: its time [s] (interpolated between samples).
        contact: True when ``min_distance <= resolution``: the motion touches or cannot be proven free.
        resolution: the resolution [m] asked for.
        evaluations: configurations evaluated (samples and midpoints).
    """

    t: np.ndarray
    distance: np.ndarray
    pairs: tuple
    min_distance: float
    min_pair: tuple[str, str] | None
    min_time: float
    contact: bool
    resolution: float
    evaluations: int


def joint_reach(scene: Scene, extent=None) -> np.ndarray:
    """R_i for each joint (module docstring): the longest distance [m] from joint i to a point it moves, 1 for a
    prismatic joint (its points move by |dq_i| exactly); ``extent`` bounds |q| over the motion, as for
    :meth:`~kinredund.geometry.scene.Scene.object_reach` (a prismatic joint's slide lengthens the chain)."""
    return scene.object_reach(extent).max(axis=0, initial=0.0)


def check_motion(scene: Scene, t, q, *, resolution: float = RESOLUTION) -> Clearance:
    """The least clearance of ``scene`` along the motion (t, q), between samples too (module docstring).

    Args:
        scene: the cell (for a final check, a scene with ``geometry="mesh"``: exact meshes).
        t: sample times [s], shape (N,), non-decreasing.
        q: joint values [rad or m], shape (N, n); joints move linearly between samples.
        resolution: how closely the least clearance is found [m].

    Raises:
        GeometryError: bad shapes or times; JointVectorError through the scene for bad joint values.
    """
    res = positive(resolution, "resolution [m]")
    q = check_array(q, (None, scene.robot.nq), "motion joint values", GeometryError)
    t = check_array(t, (len(q),), "motion times [s]", GeometryError)
    if len(q) == 0 or np.any(np.diff(t) < 0):
        raise GeometryError("a motion needs at least one sample and non-decreasing times")
    closest = [scene.closest(x) for x in q]
    d = np.array([c[1] for c in closest])
    pairs = tuple(c[0] for c in closest)
    k0 = int(np.argmin(d))
    best = [float(d[k0]), pairs[k0], float(t[k0]), len(q)]
    R = joint_reach(scene, np.abs(q).max(axis=0))  # |q_j| between two samples is at most theirs
    for k in range(len(q) - 1):
        _stretch(scene, R, res, (t[k], q[k], d[k]), (t[k + 1], q[k + 1], d[k + 1]), best)
    return Clearance(t, d, pairs, best[0], best[1], best[2], best[0] <= res, res, best[3])


def _stretch(scene: Scene, R: np.ndarray, res: float, a: tuple, b: tuple, best: list) -> None:
    """Prove the stretch a -> b (each (t, q, d)) no closer than best - res, evaluating midpoints as needed."""
    todo = [(a, b)]
    splits = 0
    while todo:
        (ta, qa, da), (tb, qb, db) = todo.pop()
        delta = float(np.abs(qb - qa) @ R)
        if 0.5 * (da + db) - delta >= best[0] - res:  # d(s) >= max(da - 2 delta s, db - 2 delta (1 - s))
            continue  # (and once delta <= res / 2 this holds, as da, db >= best)
        splits += 1
        if splits > MAX_SPLITS:
            raise GeometryError(f"could not prove the motion between t = {ta:.6g} and {tb:.6g} s within "
                                f"{MAX_SPLITS} midpoints: raise the resolution (now {res:g} m)")
        qm, tm = 0.5 * (qa + qb), 0.5 * (ta + tb)
        pair, dm = scene.closest(qm)
        best[3] += 1
        if dm < best[0]:
            best[:3] = [float(dm), pair, float(tm)]
        todo += [((ta, qa, da), (tm, qm, dm)), ((tm, qm, dm), (tb, qb, db))]
