"""Property tests (hypothesis): random malformed input to the public API raises only kinredund's own errors.

Each test replaces one argument of a valid call with junk (wrong shapes and dtypes, NaN, huge values,
wrong types) and asserts that the call either succeeds or raises a :class:`kinredund.errors.KinredundError`:
never a raw numpy, Python or Pinocchio exception. Counts are only ever given invalid values (a valid
huge count is a long run, which the bounds on work refuse separately). ``derandomize=True``: the same
examples on every machine and in every order.
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import kinredund
from kinredund.errors import KinredundError
from kinredund.ik.solve import MAX_STARTS, solve_ik
from kinredund.indices import minimum_norm
from kinredund.paths import Circle, Ellipse, Helix, SampledPath, read_path_file

SETTINGS = settings(max_examples=150, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])

_scalars = st.one_of(
    st.none(), st.booleans(), st.text(alphabet="ab1./ ", max_size=4),
    st.integers(min_value=-10**30, max_value=10**30), st.integers(min_value=10**300, max_value=10**301),
    st.floats(allow_nan=True, allow_infinity=True), st.complex_numbers(allow_nan=True, allow_infinity=True),
)


@st.composite
def _arrays(draw):
    shape = tuple(draw(st.lists(st.integers(0, 4), max_size=3)))
    dtype = draw(st.sampled_from([float, int, bool, complex, object]))
    size = int(np.prod(shape)) if shape else 1
    values = draw(st.lists(st.floats(allow_nan=True, allow_infinity=True, width=64), min_size=size, max_size=size))
    arr = np.array(values, dtype=float).reshape(shape) if shape else np.float64(values[0])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # NaN to int casts
        return np.asarray(arr).astype(dtype)


JUNK = st.one_of(
    _scalars, _arrays(), st.lists(_scalars, max_size=5),
    st.lists(st.lists(st.floats(allow_nan=True), max_size=3), max_size=3),
    st.dictionaries(st.text(max_size=2), _scalars, max_size=2),
)


def _only_ours(call) -> None:
    """Run ``call``; any exception it raises must be of the kinredund family."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", np.exceptions.ComplexWarning)  # a dropped imaginary part is a silent error
        try:
            call()
        except KinredundError:
            pass


@pytest.fixture(scope="module")
def arm():
    return kinredund.load_robot("planar3r")


@SETTINGS
@given(name=JUNK, ee_frame=JUNK, task=JUNK, which=st.integers(0, 2))
def test_load_robot_with_junk(name, ee_frame, task, which):
    kw = {"name_or_path": "planar3r", "ee_frame": None, "task": None}
    key = ("name_or_path", "ee_frame", "task")[which]
    kw[key] = (name, ee_frame, task)[which]
    _only_ours(lambda: kinredund.load_robot(kw.pop("name_or_path"), **kw))


_IK_ARGS = ("target", "index", "q0", "bounds", "starts", "seed", "tol", "max_iter", "timeout")
#: counts that no function accepts (a large valid count would only be a long run)
_INVALID_COUNT = st.one_of(st.integers(max_value=0), st.floats(), st.booleans(), st.text(max_size=2), st.none())


@SETTINGS
@given(which=st.sampled_from(_IK_ARGS), junk=JUNK, count=_INVALID_COUNT)
def test_solve_ik_with_junk(arm, which, junk, count):
    kw = {"target": [3.8, 3.0], "index": minimum_norm(3), "q0": None, "bounds": False, "starts": 1, "seed": 0,
          "tol": 1e-10, "max_iter": 50, "timeout": 5.0}
    kw[which] = count if which in ("starts", "max_iter") else junk
    if which == "starts" and isinstance(count, int) and not isinstance(count, bool) and count == 0:
        kw[which] = MAX_STARTS + 1  # above the bound on work
    target, index, q0 = kw.pop("target"), kw.pop("index"), kw.pop("q0")
    _only_ours(lambda: solve_ik(arm, target, index, q0, **kw))


def _track_with(arm, which: str, junk) -> None:
    from kinredund import track

    path = Circle([3.0, 3.0], 0.8, 0.8)
    kw = {"robot": arm, "path": path, "index": minimum_norm(3), "q0": solve_ik(arm, path(0.0).p[:2], minimum_norm(3)).q,
          "scheme": "augmented", "mode": "default", "steps_per_loop": 8, "loops": 1, "tol": 1e-12,
          "liegeois_gain": 1.0}
    kw[which] = junk
    _only_ours(lambda: track(kw.pop("robot"), kw.pop("path"), kw.pop("index"), kw.pop("q0"), **kw))


@SETTINGS
@given(which=st.sampled_from(("q0", "scheme", "mode")), junk=JUNK)
def test_track_with_junk(arm, which, junk):
    _track_with(arm, which, junk)


@SETTINGS
@given(which=st.sampled_from(("robot", "path", "constraints")), junk=JUNK)
def test_track_robot_path_and_constraints_with_junk(arm, which, junk):
    # None, a number or a name as the robot or the path raised AttributeError; a number as constraints TypeError
    _track_with(arm, which, junk)


@pytest.mark.parametrize(("which", "junk", "words"), [
    ("robot", None, "robot must be a kinredund Robot .*got NoneType"),
    ("robot", "planar3r", "robot must be a kinredund Robot .*got str"),
    ("path", None, "path must be a kinredund.paths.Path, got NoneType"),
    ("constraints", 3, r"constraints must be a list of Constraints .*got int"),
])
def test_tracker_track_solve_ik_and_plan_name_a_robot_path_or_constraints_of_the_wrong_type(arm, which, junk, words):
    from kinredund import Tracker, plan, track

    path = Circle([3.0, 3.0], 0.8, 0.8)
    q0 = solve_ik(arm, path(0.0).p[:2], minimum_norm(3)).q
    args = {"robot": arm, "path": path, "constraints": None}
    args[which] = junk
    robot, path, constraints = args["robot"], args["path"], args["constraints"]
    with pytest.raises(kinredund.OptionError, match=words):
        track(robot, path, minimum_norm(3), q0, loops=1, steps_per_loop=8, constraints=constraints)
    with pytest.raises(kinredund.OptionError, match=words):
        Tracker(robot, path, minimum_norm(3), q0, 0.1, constraints=constraints)
    if which == "robot":
        with pytest.raises(kinredund.OptionError, match=words):
            solve_ik(robot, path(0.0).p[:2], minimum_norm(3))
        with pytest.raises(kinredund.OptionError, match=words):
            plan(robot, path, minimum_norm(3))


@SETTINGS
@given(which=st.sampled_from(("steps_per_loop", "loops", "tol", "liegeois_gain")), junk=JUNK,
       count=st.one_of(st.integers(max_value=0), st.floats(-5.0, 5.0), st.just(float("nan")), st.booleans(),
                       st.text(max_size=2), st.none()))
def test_track_options_with_junk(arm, which, junk, count):
    # invalid or small counts only: a valid large one is a long run (bounded by the tracker separately)
    _track_with(arm, which, count if which in ("steps_per_loop", "loops") else junk)


@SETTINGS
@given(junk=JUNK)
def test_track_index_with_junk(arm, junk):
    _track_with(arm, "index", junk)


@SETTINGS
@given(kind=st.sampled_from(("circle", "ellipse", "helix")), which=st.integers(0, 8), junk=JUNK)
def test_paths_with_junk(kind, which, junk):
    make, valid = {"circle": (Circle, [[0.0, 0.0, 0.0], 1.0, 1.0, 0.0, (0.0, 0.0, 1.0), None, False, None, 0.0]),
                   "ellipse": (Ellipse, [[0.0, 0.0], 1.0, 0.5, 0.0, 1.0, 0.0]),
                   "helix": (Helix, [1.5, 1.0, 2.0, 1.0])}[kind]
    args = list(valid)
    args[which % len(args)] = junk  # every field in turn, in the order of the dataclass

    def build_and_sample():
        make(*args)(0.25)

    _only_ours(build_and_sample)


@SETTINGS
@given(which=st.sampled_from(("t", "p", "Q", "closed")), junk=JUNK)
def test_sampled_paths_and_path_files_with_junk(tmp_path, which, junk):
    t = np.linspace(0.0, 1.0, 6)
    p = np.column_stack([np.cos(2 * np.pi * t), np.sin(2 * np.pi * t)])
    kw = {"t": t, "p": p, "Q": None, "closed": True}
    kw[which] = junk
    _only_ours(lambda: SampledPath(**kw)(0.3))
    data = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in kw.items() if v is not None}
    try:
        text = json.dumps(data, default=str)
    except (TypeError, ValueError):
        return
    f = tmp_path / "path.json"
    f.write_text(text)
    _only_ours(lambda: read_path_file(f)[0](0.3))


@pytest.mark.parametrize(("which", "junk", "words"), [
    ("progress", 3, r"progress must be a function progress\(done, total, \.\.\.\) or None, got int"),
    ("progress", "print", "progress must be a function .*got str"),
    ("meta", 3, "meta must be a dict of extra entries .*got int"),
    ("meta", [("a", 1)], "meta must be a dict .*got list"),
])
def test_track_and_the_planners_refuse_a_progress_or_meta_of_the_wrong_type_before_any_work(arm, which, junk, words):
    """track(progress=3) called 3 after the first step (Python's TypeError, the run's work lost), and meta=3 failed in
    the record's dict(meta); so did plan() and the obstacle planners. Each refuses them up front, naming them."""
    from kinredund import plan, track
    from kinredund.planning.obstacles import EllipticCylinder
    from kinredund.planning.planner import plan as plan_obstacle
    from kinredund.planning.roadmap import plan_roadmap

    path = Circle([3.0, 3.0], 0.8, 0.8)
    q0 = solve_ik(arm, path(0.0).p[:2], minimum_norm(3)).q
    hooks = {which: junk}
    with pytest.raises(kinredund.OptionError, match=words):
        track(arm, path, minimum_norm(3), q0, loops=1, steps_per_loop=8, **hooks)
    with pytest.raises(kinredund.OptionError, match=words):
        plan(arm, path, minimum_norm(3), **hooks)
    obstacle = EllipticCylinder([3.0, 3.0, 0.0], 0.3, 0.2, 0.0, 0.5)
    for planner in (plan_obstacle, plan_roadmap):
        with pytest.raises(kinredund.OptionError, match=words):
            planner(arm, path, obstacle, **hooks)


def test_the_roadmap_planner_names_an_obstacle_or_robot_of_the_wrong_type():
    """plan_roadmap(robot, path, None) failed reading None.to_dict() (AttributeError) after its options' checks; it
    now checks its arguments as the obstacle planner does (one function, check_obstacle_args)."""
    from kinredund.planning.roadmap import plan_roadmap

    robot, path = kinredund.load_robot("panda"), Circle([0.4, 0.0, 0.4], 0.1, 0.1)
    with pytest.raises(kinredund.TaskError, match="obstacle must be a kinredund.planning Obstacle, got NoneType"):
        plan_roadmap(robot, path, None)
    with pytest.raises(kinredund.OptionError, match="robot must be a kinredund Robot .*got NoneType"):
        plan_roadmap(None, path, None)


@pytest.mark.parametrize(("junk", "words"), [(None, r"not a file path \(NoneType\)"), ("", "the path is empty"),
                                             (3, r"not a file path \(int\)")])
def test_write_csv_names_a_path_that_is_not_one(tmp_path, junk, words):
    """write_csv(traj, None) raised Python's TypeError from Path(None), and '' was called the folder '.': the path is
    the outputs' check's (file_path) before any work, and nothing is written."""
    from kinredund.errors import OutputPathError
    from kinredund.export import JointSamples, write_csv

    samples = JointSamples(("a", "b"), np.array([0.0, 0.1]), np.zeros((2, 2)))
    with pytest.raises(OutputPathError, match=words):
        write_csv(samples, junk)
    assert list(tmp_path.iterdir()) == []
