"""Paths: the twist each path returns is the time derivative of its pose; closed paths close."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

import kinredund
from kinredund.kinematics.closure import rotation_from_invariants
from kinredund.kinematics.finite_diff import central_difference
from kinredund.paths import Circle, Ellipse, FunctionPath, Helix, SampledPath


def _tilted_q0():
    return rotation_from_invariants(np.array([0.3, -0.5, 0.8]), 1.1)


def _user(t):
    Q = rotation_from_invariants(np.array([0.0, 0.0, 1.0]), 0.4 * t)
    return Q, np.array([0.1 * t, np.sin(t), 0.5]), np.array([0.0, 0.0, 0.4]), np.array([0.1, np.cos(t), 0.0])


def _sampled(oriented: bool = False):
    ts = np.linspace(0.0, 2.0, 41)
    p = np.column_stack([np.cos(np.pi * ts), np.sin(np.pi * ts), 0.2 * np.sin(np.pi * ts)])
    if not oriented:
        return SampledPath(ts, p, closed=True)
    Q = np.array([rotation_from_invariants(np.array([0.2, 0.3, 1.0]), np.pi * t) for t in ts])
    return SampledPath(ts, p, Q, closed=False)


PATHS = {
    "circle_plane": lambda: Circle((0.5, -0.2), 0.3, 0.7, start_angle=0.4),
    "circle_frenet_tilted": lambda: Circle((0.1, 0.2, 0.3), 0.4, 1.3, normal=(0.3, 0.2, 1.0), frenet=True),
    "circle_frenet_x": lambda: Circle((1.0, 0.0, 0.5), 0.25, 0.5, normal=(1.0, 0.0, 0.0), frenet=True),
    "circle_roll": lambda: Circle((0.4, 0.1, 0.6), 0.1, 0.2, orientation=_tilted_q0(), roll_amplitude=0.3),
    "ellipse": lambda: Ellipse((0.2, 0.1), 0.3, 0.15, angle=0.5, rate=1.2, start=0.3),
    "helix": lambda: Helix(),
    "function": lambda: FunctionPath(_user, has_orientation=True),
    "sampled": _sampled,
    "sampled_oriented": lambda: _sampled(oriented=True),
}


@pytest.mark.parametrize("name", sorted(PATHS))
def test_twist_is_the_derivative_of_the_pose(name):
    path = PATHS[name]()
    bounded = isinstance(path, SampledPath) and path.period is None  # no samples before t = 0
    for t in ((0.01,) if bounded else (0.0,)) + (0.37, 1.9):
        s = path(t)
        v_fd = central_difference(lambda x: path(x[0]).p, np.array([t]))[:, 0]
        tol = 1e-4 if name.startswith("sampled") else 1e-8  # the spline's own derivative vs differences of it
        assert np.abs(s.v - v_fd).max() < tol
        if s.Q is None:
            continue
        assert np.abs(s.Q @ s.Q.T - np.eye(3)).max() < 1e-12 and np.linalg.det(s.Q) > 0
        dQ = central_difference(lambda x: path(x[0]).Q.ravel(), np.array([t]))[:, 0].reshape(3, 3)
        W = dQ @ s.Q.T  # [omega]x (world axes)
        assert np.abs(W + W.T).max() < 1e-8
        assert np.abs(np.array([W[2, 1], W[0, 2], W[1, 0]]) - s.omega).max() < 1e-8


@pytest.mark.parametrize("name", ["circle_plane", "circle_frenet_tilted", "circle_roll", "ellipse", "sampled"])
def test_closed_paths_close(name):
    path = PATHS[name]()
    a, b = path(0.2), path(0.2 + path.period)
    assert np.abs(a.p - b.p).max() < 1e-12 and np.abs(a.v - b.v).max() < 1e-10
    if a.Q is not None:
        assert np.abs(a.Q - b.Q).max() < 1e-12


def test_rolling_orientation_turns_about_the_tool_axis():
    """Q_d = Q_0 Rz(a sin(2 pi t / T)): the tool's z axis stays Q_0's, the other two turn by the roll angle."""
    path = PATHS["circle_roll"]()
    Q0 = _tilted_q0()
    for t in (0.0, 0.4, 1.1, 2.5):
        ang = 0.3 * np.sin(2 * np.pi * t / path.period)
        Rz = rotation_from_invariants(np.array([0.0, 0.0, 1.0]), ang)
        assert np.abs(path(t).Q - Q0 @ Rz).max() < 1e-14


def test_frenet_frame_of_example_4_3():
    """Eq. (4.47): Q_d = [e_n, e_t, e_n x e_t] with e_n the outward radial unit vector, e_t the tangent."""
    c = np.array([0.1, 0.2, 0.3])
    path = Circle(c, 0.4, 1.3, normal=(0.3, 0.2, 1.0), frenet=True)
    n = np.array([0.3, 0.2, 1.0]) / np.linalg.norm([0.3, 0.2, 1.0])
    for t in (0.0, 0.8, 1.5):
        s = path(t)
        assert np.abs(s.Q[:, 0] - (s.p - c) / 0.4).max() < 1e-12
        assert np.abs(s.Q[:, 1] - s.v / 1.3).max() < 1e-12
        assert np.abs(s.Q[:, 2] - n).max() < 1e-12
        assert np.abs(s.omega - (1.3 / 0.4) * n).max() < 1e-12  # Eq. (4.48)


@pytest.mark.parametrize("make", [
    lambda: Circle((0.0, 0.0), -1.0, 1.0),
    lambda: Circle((0.0, 0.0), 1.0, 0.0),
    lambda: Circle((np.nan, 0.0), 1.0, 1.0),
    lambda: Circle((0.0, 0.0, 0.0), 1.0, 1.0, orientation=np.ones((3, 3))),
    lambda: Circle((0.0, 0.0, 0.0), 1.0, 1.0, orientation=np.full((3, 3), np.nan)),
    lambda: Circle((0.0, 0.0, 0.0), 1.0, 1.0, orientation=np.diag([1.0, 1.0, -1.0])),  # a reflection
    lambda: Circle((0.0, 0.0, 0.0), 1.0, 1.0, orientation=np.eye(3), roll_amplitude=np.nan),
    lambda: Ellipse((0.0, 0.0), 0.0, 1.0),
    lambda: SampledPath([0.0, 1.0, 2.0], [[0, 0], [1, 0], [0, 0]]),
    lambda: SampledPath([0.0, 1.0, 2.0, 3.0], [[0, 0], [1, 0], [1, 1], [0.5, 0]], closed=True),
    lambda: SampledPath([0.0, 1.0, 2.0, 3.0], [[0, 0], [1, 0], [1, 1], [0, 0]],
                        [rotation_from_invariants(np.array([0.0, 0.0, 1.0]), a) for a in (0.0, 1.0, 2.0, 3.0)]),
    lambda: Circle("ab", 1.0, 1.0),
    lambda: Circle((0.0, 0.0, 0.0), 1.0, 1.0, normal=(0.0, 0.0, 0.0)),
    lambda: Circle((0.0, 0.0, 0.0), 1.0, 1.0, normal=(0.0, 0.0, 1.0), axis_x=(0.0, 0.0, 2.0)),
    lambda: Ellipse((1.0, 2.0, 3.0, 4.0), 1.0, 1.0),
    lambda: Helix(radius=-1.0),
    lambda: Helix(rate=0.0),
])
def test_bad_paths_raise_path_error(make):
    with pytest.raises(kinredund.PathError):
        make()


@pytest.mark.parametrize(("make", "period"), [(lambda: Circle((0.0, 0.0, 0.0), 1e-300, 1e300), "0.0"),
                                              (lambda: Circle((0.0, 0.0, 0.0), 1e300, 1e-300), "inf"),
                                              (lambda: Ellipse((0.0, 0.0), 1.0, 1.0, rate=1e-310), "inf")])
def test_a_period_that_over_or_underflows_is_refused(make, period):
    """Fields each finite and > 0 whose period is not (a circle of 1e-300 m at 1e300 m/s had period 0): a PathError
    naming the period and what gives it, not a path that divides by it."""
    with pytest.raises(kinredund.PathError, match=rf"gives the period {period} s; it must be a finite number > 0"):
        make()
    assert Circle((0.0, 0.0, 0.0), 1e-3, 1e3).period == pytest.approx(2 * np.pi * 1e-6, rel=1e-15)


def test_user_path_of_the_wrong_shape_says_when():
    path = FunctionPath(lambda t: (np.zeros(4), np.zeros(4)))
    with pytest.raises(kinredund.PathError, match=r"at t = 0\.25 s"):
        path(0.25)


@pytest.mark.parametrize(("kwargs", "words"), [
    ({"period": 0.0}, r"period \[s\] must be a finite number > 0, got 0.0"),
    ({"period": -1.0}, r"period \[s\] must be a finite number > 0, got -1.0"),
    ({"period": float("nan")}, r"period \[s\] must be a finite number > 0, got nan"),
    ({"period": "1"}, r"period \[s\] must be a finite number > 0, got '1'"),
    ({"has_orientation": "no"}, "has_orientation must be True or False, got 'no'"),
    ({"fn": 3}, "fn must be a function of t"),
])
def test_a_user_path_with_a_bad_period_flag_or_function_is_refused_when_made(kwargs, words):
    """FunctionPath took any period (0, -1, NaN, a string: track then divided it into a negative or NaN time step, or
    raised TypeError), any has_orientation (the string 'no' is true) and fn=3 (TypeError at the first sample)."""
    args = {"fn": lambda t: (np.zeros(3), np.zeros(3)), **kwargs}
    with pytest.raises(kinredund.PathError, match=words):
        FunctionPath(**args)
    assert FunctionPath(args["fn"] if "fn" not in kwargs else np.cos, period=2).period == 2.0


@pytest.mark.parametrize(("Q", "words"), [(3.0 * np.eye(3), r"\|Q Q\^T - 1\| = 8, det = 27"),
                                          (np.diag([1.0, 1.0, -1.0]), r"\|Q Q\^T - 1\| = 0, det = -1"),
                                          (np.full((3, 3), np.nan), None)])
def test_a_user_paths_orientation_must_be_a_rotation(Q, words):
    """A user pose path returning 3 I (or a reflection) as Q was sampled as it was, and the tracker then called the
    start 'turned by 180 deg' from the path: the sample names the matrix that is not a rotation (the sampled path's
    test, rotation_gaps, to ROTATION_TOL), and when."""
    path = FunctionPath(lambda t: (Q, np.zeros(3), np.zeros(3), np.zeros(3)), has_orientation=True)
    said = r"non-finite Q at t = 0.5 s" if words is None else r"Q at t = 0.5 s is not a rotation matrix .*" + words
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # (no numpy warning on the NaN)
        with pytest.raises(kinredund.PathError, match=said):
            path(0.5)
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    assert np.array_equal(FunctionPath(lambda t: (turn, np.zeros(3), np.zeros(3), np.zeros(3)),
                                       has_orientation=True)(0.5).Q, turn)


def test_huge_but_finite_path_values_are_named_not_called_non_finite():
    """A path whose values are finite but so large that their squares overflow is refused by name (the
    finiteness check squares them), with the sizes, and without a floating-point warning."""
    import warnings

    path = Circle((0.0, 0.0, 0.0), 1e200, 1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(kinredund.PathError, match=r"too large for any robot at t = 0.25 s \(\|p\| = 1e\+200"):
            path(0.25)
    with pytest.raises(kinredund.PathError, match="non-finite p at t = 0.25 s"):
        FunctionPath(lambda t: (np.array([np.inf, 0.0, 0.0]), np.zeros(3)))(0.25)


def _part(inner: str):
    from kinredund.sweep.placement import PartPath, placement_pose

    T = placement_pose(0.3, -0.2, 0.1, 0.8)
    T[:3, :3] = T[:3, :3] @ rotation_from_invariants(np.array([1.0, 0.2, 0.0]), 0.6)
    return PartPath(PATHS[inner](), T)


MANY = {"ellipse": PATHS["ellipse"], "helix": PATHS["helix"], "part_circle_roll": lambda: _part("circle_roll"),
        "part_circle_frenet": lambda: _part("circle_frenet_tilted"), "part_ellipse": lambda: _part("ellipse"),
        "part_function": lambda: _part("function")}


@pytest.mark.parametrize("name", sorted(MANY))
def test_sample_many_is_sample_at_each_time(name):
    """The vectorised samples (Ellipse, Helix, PartPath) are the scalar ones: the same operations on arrays,
    equal to 1e-15 of each field's size at random times (both sides round each product once)."""
    path = MANY[name]()
    times = np.random.default_rng(7).uniform(-3.0, 12.0, 50).tolist()
    many = path.sample_many(times)
    assert many.listed is None  # computed as arrays (the default samples one by one and lists them)
    for field in ("p", "v", "Q", "omega"):
        want = [getattr(path.sample(t), field) for t in times]
        got = getattr(many, field)
        assert (got is None) == (want[0] is None), field
        if got is None:
            continue
        want = np.array(want)
        assert got.shape == want.shape, field
        scale = max(1.0, float(np.abs(want).max()))
        assert np.abs(got - want).max() <= 1e-15 * scale, field
        assert np.all([np.array_equal(getattr(many.sample(k), field), got[k]) for k in range(len(times))])


def test_the_core_s_cosines_and_sines_are_math_s(monkeypatch):
    """A circle's samples taken together come from the compiled core (``_core.circle_samples``, whose cosines and
    sines ``_core.cos_sin`` gives the other paths): the C functions that ``math.cos`` and ``math.sin`` call, so the
    same floats to the bit (the signs of zeros too) at angles over 600 decades, near multiples of pi / 2 and at the
    extremes; where an angle is not finite they write nothing and say so, and ``math`` takes them (it raises on
    +-inf, as :meth:`Circle.sample` does). Without the core every circle's samples are the same numbers (numpy's
    route)."""
    from kinredund.paths import analytic

    core = analytic._CORE
    if core is None:
        pytest.skip("the compiled core is not built")
    rng = np.random.default_rng(3)
    a = np.concatenate([rng.uniform(-10.0, 10.0, 2000), rng.uniform(-1e6, 1e6, 2000),
                        10.0 ** rng.uniform(-300.0, 300.0, 2000) * rng.choice([-1.0, 1.0], 2000),
                        np.pi / 2 * np.arange(-50, 51), [0.0, -0.0, 5e-324, -1.7e308]])
    c, s = np.empty(len(a)), np.empty(len(a))
    assert core.cos_sin(a, c, s)
    assert c.tobytes() == np.array([math.cos(x) for x in a]).tobytes()
    assert s.tobytes() == np.array([math.sin(x) for x in a]).tobytes()
    for bad in (np.inf, -np.inf, np.nan):
        c[:2] = s[:2] = 7.0
        assert not core.cos_sin(np.array([0.5, bad]), c[:2], s[:2])
        assert (c[:2] == 7.0).all() and (s[:2] == 7.0).all()
    cn, sn = analytic._cos_sin(np.array([0.5, np.nan]))
    assert cn[0] == math.cos(0.5) and sn[0] == math.sin(0.5) and np.isnan(cn[1]) and np.isnan(sn[1])
    with pytest.raises(ValueError, match="math domain error"):
        analytic._cos_sin(np.array([0.5, np.inf]))
    with pytest.raises(ValueError, match=r"c and s must have 3 entries"):
        core.cos_sin(np.zeros(3), np.empty(2), np.empty(3))
    circles = [PATHS[name]() for name in ("circle_plane", "circle_frenet_tilted", "circle_frenet_x", "circle_roll")]
    circles.append(Circle((0.4, 0.1, 0.6), 0.1, 0.2, orientation=_tilted_q0()))
    times = rng.uniform(-3.0, 12.0, 50).tolist()
    with_core = [path.sample_many(times) for path in circles]
    for path in circles:
        with pytest.raises(ValueError, match="math domain error"):  # as path.sample(inf) raises
            path.sample_many([0.0, math.inf])
    with pytest.raises(ValueError, match=r"P must have shape \(2, 3\)"):
        path = circles[0]
        core.circle_samples(np.zeros(2), 0.0, 1.0, path._plane_rows, path._center, 1.0, 1.0, 0, np.zeros((0, 0)),
                            0.0, np.empty((3, 3)), np.empty((2, 3)), np.empty((0, 9)), np.empty((0, 3)))
    monkeypatch.setattr(analytic, "_CORE", None)
    for path, got in zip(circles, with_core, strict=True):
        want = path.sample_many(times)
        for field in ("p", "v", "Q", "omega"):
            a, b = getattr(got, field), getattr(want, field)
            assert (a is None) == (b is None) and (a is None or a.tobytes() == b.tobytes()), (path, field)
