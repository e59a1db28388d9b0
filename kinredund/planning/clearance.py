"""Clearance verification of a planned motion, independent of the policy indices (Chapter 6).

Every link is a segment between consecutive joint origins (``robot.kinematics.joint_origins``), or a
capsule of a stated radius around it; segments of zero length (e.g. the P-15's offsets a4 = b4 = 0
and its wrist, whose axes meet at P) are dropped once per robot. The last link ends at the end point
P, which lies on the obstacle's boundary by design (the tool touches the surface), so its distance is
always zero: its clearance is measured on the link without a tool tip of stated length at P, and the
whole last link is separately checked for *penetration*: a point of it deeper than the end point
itself by more than ``PENETRATION_TOL`` (between tracked steps the interpolated end point may dip
below the boundary by the interpolation error, which is reported separately).

The motion is checked at a finer resolution than the tracking steps: the joints are interpolated
linearly between recorded steps (``substeps`` points per step). Two statements bound what lies
between the checked configurations:

- a rigorous bound for the interpolated motion: between two checked configurations, no point of link
  k moves by more than ``sum_i |dtheta_i| R_ik`` (R_ik the distance along the chain from joint i to the
  far end of link k, an upper bound of that point's distance from axis i), so the true minimum is at
  least the sampled minimum minus half of that (``lower_bound``);
- an empirical check: :func:`verify_motion` with ``check_doubling=True`` repeats the check at twice the
  resolution and records how much the minimum moved (``doubling_change``).

Units: lengths [m], times [s].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kinredund.errors import OptionError, TaskError
from kinredund.planning.obstacles import Obstacle, segment_minimum

#: a point of the last link deeper than the end point by more than this is a penetration [m]
PENETRATION_TOL = 1e-9
#: segments shorter than this are not links [m]
ZERO_LENGTH = 1e-12


@dataclass(frozen=True)
class LinkModel:
    """Which joint-origin pairs are links, their lengths, and the chain reach used by the bounds.

    Attributes:
        pairs: (k, 2) indices into ``joint_origins`` of each link's two ends.
        lengths: link lengths [m], shape (k,).
        names: ``link 1`` ... ``link k`` (segments of zero length over the whole joint box skipped).
        reach: reach[i, k] = an upper bound, over the joint limits, of the chain length from joint origin i to
            the far end of link k [m] (0 when the link comes before joint i), shape (n, k).
        revolute: which joints are revolute (a prismatic joint moves points by |dq| instead).
        moved: moved[i, k]: joint i moves link k (a revolute joint the links after its origin, a prismatic one
            its own origin's link too), shape (n, k).
    """

    pairs: np.ndarray
    lengths: np.ndarray
    names: tuple[str, ...]
    reach: np.ndarray
    revolute: np.ndarray
    moved: np.ndarray


def longest_segments(robot) -> tuple[np.ndarray, np.ndarray]:
    """(lengths at home, upper bounds over the joint limits) of the segments between consecutive joint origins [m].

    A revolute joint turns the segments after its origin rigidly; a prismatic joint p moves the origins from
    its own on by q_p along its axis, so a segment it stretches is at most its home length plus p's travel
    from home (triangle inequality). Which segments a prismatic joint stretches is found at home by moving it.
    """
    home = np.asarray(robot.home, float)
    pts = robot.kinematics.joint_origins(home)
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    longest = seg.copy()
    for p in np.flatnonzero(~np.asarray(robot.revolute, bool)):
        travel = float(max(robot.upper[p] - home[p], home[p] - robot.lower[p], 0.0))
        step = np.zeros_like(home)
        step[p] = 1e-3 * max(1.0, travel)
        moved = np.linalg.norm(np.diff(robot.kinematics.joint_origins(home + step), axis=0), axis=1)
        longest = longest + travel * (np.abs(moved - seg) > 1e-9 * step[p])  # Eq.: |c + dq u| <= |c| + |dq|
    return seg, longest


def link_model(robot) -> LinkModel:
    """The links of ``robot`` (segments between consecutive joint origins; those of zero length over the whole
    joint box dropped), with the reach bounds over the joint limits (a prismatic joint stretches its links)."""
    seg, longest = longest_segments(robot)
    keep = np.flatnonzero(longest > ZERO_LENGTH)
    pairs = np.stack([keep, keep + 1], axis=1)
    n, revolute = robot.nq, np.asarray(robot.revolute, bool)
    cum = np.concatenate([[0.0], np.cumsum(longest)])  # longest chain from origin 0 to origin m
    reach, moved = np.zeros((n, keep.size)), np.zeros((n, keep.size), bool)
    for k, (_, j) in enumerate(pairs):
        for i in range(n):
            moved[i, k] = i < j or (i == j and not revolute[i])  # a prismatic joint moves its own origin
            reach[i, k] = cum[j] - cum[i] if i < j else 0.0
    return LinkModel(pairs, seg[keep], tuple(f"link {k + 1}" for k in range(keep.size)), reach, revolute, moved)


def link_segments(robot, q_all, model: LinkModel | None = None) -> np.ndarray:
    """Link end points for many configurations: shape (N, k, 2, 3) [m]."""
    model = model or link_model(robot)
    q_all = np.atleast_2d(np.asarray(q_all, float))
    pts = np.array([robot.kinematics.joint_origins(q) for q in q_all])
    return np.stack([pts[:, model.pairs[:, 0]], pts[:, model.pairs[:, 1]]], axis=2)


def link_clearance(obstacle: Obstacle, segments: np.ndarray, *, radius: float = 0.0, tool_tip: float = 0.0,
                   distance=None):
    """Per-link clearance [m], the last link's penetration and the end point's depth, for segments (N, k, 2, 3).

    Args:
        obstacle: the obstacle.
        segments: from :func:`link_segments`.
        radius: capsule radius of every link [m].
        tool_tip: length [m] at the end point excluded from the last link's clearance (the tool that
            touches the surface); the whole last link is still checked for penetration.
        distance: ``distance(points) -> [m]`` used instead of ``obstacle.signed_distance``: a convex,
            1-Lipschitz lower bound of it (e.g.
            :meth:`~kinredund.planning.obstacles.EllipticCylinder.surface_bound`) screens cheaply, and
            every value returned is then a lower bound of the exact one.

    Returns:
        (clearance (N, k), penetration (N,), end-point depth (N,)). The penetration is how much deeper
        than the end point itself any point of the last link lies (>= 0): the end point of an
        interpolated motion may dip below the boundary by the interpolation error (reported as the
        end-point depth, >= 0), which is not a penetration of the link.
    """
    p0 = segments[:, :, 0].copy()
    p1 = segments[:, :, 1].copy()
    last = p1[:, -1] - p0[:, -1]
    length = np.linalg.norm(last, axis=1)
    if np.any(tool_tip >= length):
        raise TaskError(f"the tool tip ({tool_tip} m) must be shorter than the last link ({length.min():.4g} m)")
    p1[:, -1] = p1[:, -1] - (tool_tip / length)[:, None] * last
    sd = obstacle.signed_distance if distance is None else distance
    clear = segment_minimum(sd, p0, p1, radius)
    whole = segment_minimum(sd, segments[:, -1, 0], segments[:, -1, 1])
    tip_depth = np.maximum(0.0, -sd(segments[:, -1, 1]))
    return clear, np.maximum(0.0, np.maximum(0.0, -whole) - tip_depth), tip_depth


def interpolate_joints(t: np.ndarray, q: np.ndarray, substeps: int) -> tuple[np.ndarray, np.ndarray]:
    """Linear interpolation of recorded joints at ``substeps`` >= 1 points per step (ends included)."""
    lam = np.arange(substeps) / substeps
    tt = (t[:-1, None] + lam[None, :] * np.diff(t)[:, None]).ravel()
    qq = (q[:-1, None, :] + lam[None, :, None] * np.diff(q, axis=0)[:, None, :]).reshape(-1, q.shape[1])
    return np.append(tt, t[-1]), np.vstack([qq, q[-1]])


def motion_bound(model: LinkModel, q_dense: np.ndarray) -> np.ndarray:
    """Largest displacement of any point of each link between consecutive checked configurations.

    For each pair of consecutive configurations, sum_i |dq_i| R_ik (Section docstring); returns the
    maximum over the pairs, per link [m], shape (k,).
    """
    dq = np.abs(np.diff(q_dense, axis=0))  # (N-1, n)
    lever = np.where(model.revolute[:, None], model.reach, model.moved.astype(float))
    return (dq @ lever).max(axis=0) if len(dq) else np.zeros(model.pairs.shape[0])


@dataclass(frozen=True)
class ClearanceReport:
    """What :func:`verify_motion` found.

    Attributes:
        names: the link names.
        t: the checked times [s], shape (N,).
        clearance: per-link clearance [m] at those times, shape (N, k) (the last link without its tool
            tip; capsules when ``radius`` > 0).
        penetration: how much deeper than the end point any point of the last link lies [m], shape (N,)
            (the end point itself touches the surface).
        minimum: per-link minimum clearance [m], shape (k,).
        argmin_t: per-link time of the minimum [s].
        lower_bound: per-link certified lower bound for the interpolated motion [m]:
            minimum - motion_bound / 2.
        motion_bound: per-link largest displacement between checked configurations [m].
        doubling_change: per-link |minimum at twice the resolution - minimum| [m], or None.
        endpoint_depth_max: the allowance of the penetration test [m]: how far the end point of the
            interpolated motion dips below the boundary (or, with ``path``, strays from the path) between
            tracked steps - the interpolation error, ~0 at the steps themselves.
        substeps, radius, tool_tip: the settings.
    """

    names: tuple[str, ...]
    t: np.ndarray
    clearance: np.ndarray
    penetration: np.ndarray
    minimum: np.ndarray
    argmin_t: np.ndarray
    lower_bound: np.ndarray
    motion_bound: np.ndarray
    doubling_change: np.ndarray | None
    endpoint_depth_max: float
    substeps: int
    radius: float
    tool_tip: float

    @property
    def collision_free(self) -> bool:
        """No penetration of the last link and every certified lower bound > 0."""
        return bool(self.penetration.max() <= PENETRATION_TOL and np.all(self.lower_bound > 0))

    def intervals(self, threshold: float = 0.0) -> list[tuple[str, float, float, float]]:
        """(link, t_start, t_end, depth) of each run where a link's clearance is <= threshold [m]."""
        out = []
        series = [(self.names[k], self.clearance[:, k]) for k in range(len(self.names))]
        series.append((f"{self.names[-1]} (whole, penetration)", -self.penetration + PENETRATION_TOL))
        for name, c in series:
            bad = c <= threshold
            if not bad.any():
                continue
            idx = np.flatnonzero(bad)
            splits = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
            for run in splits:
                out.append((name, float(self.t[run[0]]), float(self.t[run[-1]]), float(-c[run].min())))
        return out


def _check(robot, obstacle, t, q, model, substeps, radius, tool_tip, path):
    tt, qq = interpolate_joints(t, q, substeps)
    seg = link_segments(robot, qq, model)
    clear, pen, tip = link_clearance(obstacle, seg, radius=radius, tool_tip=tool_tip)
    if path is not None:
        # the end point of an interpolated configuration is off the path by the chord error; the link may be
        # that much deeper than a configuration on the path would put it (signed distance is 1-Lipschitz)
        dev = np.linalg.norm(seg[:, -1, 1] - np.array([path(tv).p for tv in tt]), axis=1)
        pen = np.maximum(0.0, pen + tip - dev)
        tip = dev
    return tt, qq, clear, pen, tip


def verify_motion(robot, obstacle: Obstacle, t, q, *, substeps: int = 8, radius: float = 0.0,
                  tool_tip: float = 0.0, check_doubling: bool = True, path=None) -> ClearanceReport:
    """Check every link against the obstacle along a recorded motion, finer than its steps.

    Args:
        robot: the robot.
        obstacle: the obstacle.
        t: times [s], shape (N,).
        q: joints, shape (N, n).
        substeps: checked configurations per recorded step (linear interpolation in joint space).
        radius: capsule radius of the links [m].
        tool_tip: the last link's tip length excluded from its clearance [m].
        check_doubling: also check at 2 * substeps and record how much each minimum moved.
        path: the desired path; when given, the last link's penetration is measured beyond the end
            point's distance from the path point at the same time (at the recorded steps ~1e-12 m,
            between them the interpolation's chord error) instead of beyond the end point's depth.

    Returns:
        A :class:`ClearanceReport`.
    """
    t = np.asarray(t, float)
    q = np.asarray(q, float)
    if q.ndim != 2 or q.shape[0] != t.shape[0] or q.shape[1] != robot.nq:
        raise TaskError(f"q must have shape ({t.shape[0]}, {robot.nq}), got {q.shape}")
    if substeps < 1:
        raise TaskError(f"substeps must be >= 1, got {substeps}")
    model = link_model(robot)
    # with the doubling check, one pass at 2 * substeps: its even points are the base grid exactly
    # ((2j) / (2 substeps) rounds to the same double as j / substeps)
    stride = 2 if check_doubling else 1
    tt, qq, clear, pen, tip = _check(robot, obstacle, t, q, model, stride * substeps, radius, tool_tip, path)
    minimum2 = clear.min(axis=0)
    tt, qq, clear, pen, tip = tt[::stride], qq[::stride], clear[::stride], pen[::stride], tip[::stride]
    k = clear.argmin(axis=0)
    minimum = clear.min(axis=0)
    bound = motion_bound(model, qq)
    change = np.abs(minimum2 - minimum) if check_doubling else None
    return ClearanceReport(model.names, tt, clear, pen, minimum, tt[k], minimum - 0.5 * bound, bound, change,
                           float(tip.max()), int(substeps), float(radius), float(tool_tip))


def tool_tip_length(model: LinkModel, tool_tip) -> float:
    """The last link's tip left out of its clearance [m]: default 1/6 of its length, else checked in
    [0, length).

    Raises:
        OptionError: a tip that is not a length in [0, length).
    """
    length = float(model.lengths[-1])
    if tool_tip is None:
        return length / 6.0
    try:
        tip = float(tool_tip)
    except (TypeError, ValueError) as err:
        raise OptionError(f"tool_tip must be a length [m], got {tool_tip!r}") from err
    if not (0.0 <= tip < length):
        raise OptionError(f"tool_tip must be in [0, {length:.4g}) m (the last link), got {tool_tip!r}")
    return tip


def winding(path, obstacle: Obstacle, period: float, count: int = 720) -> float:
    """How many times the path goes around the obstacle's centre in the xy-plane over one period."""
    ts = np.linspace(0.0, period, count + 1)
    xy = np.array([path(t).p[:2] for t in ts]) - obstacle.center[:2]
    ang = np.unwrap(np.arctan2(xy[:, 1], xy[:, 0]))
    return float((ang[-1] - ang[0]) / (2 * np.pi))
