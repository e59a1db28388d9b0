"""Sweeps that know the cell (kinredund.sweep.cell): the scene moved with the part, each placement's run checked
against it (self pairs too), colliding placements infeasible with the pair named, the figures in the file, bad
options refused before any work, the CLI."""

from __future__ import annotations

import functools
import pickle

import coal
import numpy as np
import pytest
from conftest import rounding

import kinredund as kr
import kinredund.sweep.evaluate as evaluate_mod
from kinredund.errors import KinredundError
from kinredund.geometry import robot_geometry, save_scene
from kinredund.sweep import (
    SweepOptions,
    evaluate_placement,
    grid,
    placement_pose,
    read_sweep_file,
    sweep,
    sweep_scene,
)
from kinredund.sweep.placement import panda_part_circle
from kinredund.ui.cli import main

#: a cube of this side [m] in the cell (the part frame) ...
PILLAR = 0.1
#: ... standing where the Panda's shoulder is when the part sits at y = +0.2 m (the base is then at part
#: y = -0.2 m; the cube's centre 0.15 m beyond it, at shoulder height): link 1 passes through it there, while at
#: y = -0.2 m the base is 0.4 m farther away
PILLAR_Y, PILLAR_HEIGHT = -0.35, 0.35
#: the clearance asked for [m] (the feasible placements keep ~0.1 m)
CLEARANCE = 0.01
#: check_motion's resolution in these runs [m]: coarse, so that a run stays cheap; the recorded clearance is a
#: distance actually evaluated at the recorded configuration, whatever the resolution
RESOLUTION = 5e-3
KW = {"steps_per_loop": 100, "starts": 2, "clearance_resolution": RESOLUTION}


@functools.cache
def cell():
    """(robot, part path, index, the part's centre, the scene with the pillar in the part frame)."""
    robot, path, index, pose = panda_part_circle()
    c = pose[:3, 3]
    scene = kr.Scene(robot)
    scene.add_box("pillar", (PILLAR,) * 3, {"xyz": [-c[0], PILLAR_Y, -c[2] + PILLAR_HEIGHT], "rpy": [0, 0, 0]})
    return robot, path, index, c, scene


def placements() -> np.ndarray:
    c = cell()[3]
    return grid(x=c[0], y=[-0.2, 0.2], z=c[2])


@functools.cache
def records():
    robot, path, index, _, scene = cell()
    return tuple(sweep(robot, path, index, placements(), workers=0, scene=scene, clearance=CLEARANCE, **KW))


def placed_by_hand(T: np.ndarray):
    """A fresh scene with the pillar put at T @ X by hand (not through the sweep's code)."""
    robot, _, _, _, scene = cell()
    X = scene.object("pillar").pose
    fresh = kr.Scene(robot, pairs=scene.pair_matrix)
    fresh.add_box("pillar", (PILLAR,) * 3, T @ X)
    return fresh


def test_placed_scene_distances_are_those_of_the_robot_placed_in_the_cell():
    """The base at T^-1 in the cell, the pillar where the cell has it: coal on the robot's own objects."""
    robot, _, _, _, scene = cell()
    spec = sweep_scene(scene, robot)
    T = placement_pose(0.35, 0.1, 0.5, 0.7)
    B = np.linalg.inv(T)  # the base in the cell
    X = scene.object("pillar").pose
    geom = {g.name: g.geometry for g in robot_geometry(robot).model.geometryObjects}
    req, res = coal.DistanceRequest(), coal.DistanceResult()
    req.gjk_tolerance = 1e-9
    rng = np.random.default_rng(3)
    for _ in range(3):
        q = rng.uniform(robot.lower, robot.upper)
        d = spec.placed(robot, T).distances(q)
        unplaced = kr.Scene(robot, pairs=scene.pair_matrix)  # robot objects in the base frame
        checked = [p for p in d.pairs if "pillar" in p]
        assert len(checked) >= 10  # every moving robot object against the pillar
        for a, b in checked:
            M = B @ unplaced.object_pose(a, q)  # the robot object in the cell
            res.clear()
            ref = coal.distance(geom[a], coal.Transform3s(M[:3, :3], M[:3, 3]), coal.Box(*(PILLAR,) * 3),
                                coal.Transform3s(X[:3, :3], X[:3, 3]), req, res)
            assert d[(a, b)] == pytest.approx(ref, abs=1e-7), (a, b)  # two GJK runs to 1e-9 on ~1 m
        self_pairs = [p for p in d.pairs if "pillar" not in p]
        np.testing.assert_allclose([d[p] for p in self_pairs], [unplaced.distances(q)[p] for p in self_pairs],
                                   atol=rounding(1.0) * 1e3)  # self distances do not depend on the placement


def test_a_sweep_scene_pickles_and_rebuilds_to_the_same_distances():
    robot, _, _, _, scene = cell()
    spec = sweep_scene(scene, robot)
    copy = pickle.loads(pickle.dumps(spec))
    assert copy.key == spec.key
    T, q = placements()[1], robot.home
    a = spec.placed(robot, T).distances(q)
    b = copy.build(robot)
    b.move("pillar", T @ scene.object("pillar").pose)
    assert a.pairs == b.distances(q).pairs
    np.testing.assert_allclose(a.distance, b.distances(q).distance, rtol=0, atol=1e-12)


def test_colliding_placements_are_infeasible_with_the_pair_and_the_distance_recomputed():
    robot = cell()[0]
    clear, hit = records()
    assert clear.feasible and clear.cause is None and clear.clearance >= CLEARANCE
    assert not hit.feasible and hit.cause == "collision" and "pillar" in hit.clearance_pair
    assert "pillar" in hit.message and "panda_link" in hit.message and hit.clearance < 0  # link 1 runs through it
    for r, T in zip((clear, hit), placements(), strict=True):
        d = placed_by_hand(T).distances(np.array(r.clearance_q))
        assert d.min_distance == pytest.approx(r.clearance, abs=1e-9)  # GJK to 1e-9 m
        assert d.closest == r.clearance_pair
        assert 0.0 <= r.clearance_time <= 10.0
    assert hit.t_fail == hit.clearance_time  # the same number, copied
    assert hit.q_last is None or len(hit.q_last) == robot.nq
    # the same run, asked for more clearance than the free placement keeps, is infeasible by that margin
    robot, path, index, _, scene = cell()
    options = SweepOptions(steps_per_loop=100, starts=2, scene=sweep_scene(scene, robot),
                           clearance=clear.clearance + 0.02, clearance_resolution=RESOLUTION)
    tight = evaluate_placement(robot, path, index, placements()[0], 0, options)
    assert not tight.feasible and tight.cause == "collision" and "come within" in tight.message
    assert tight.clearance == pytest.approx(clear.clearance, abs=1e-9)


def test_the_map_ranks_and_labels_the_clearance(tmp_path):
    from kinredund.sweep import best
    from kinredund.ui.plots_sweep import plot_sweep_map, sweep_map_figure, sweep_maps

    clear, hit = records()
    assert best(records(), "clearance") == [clear]  # the colliding placement is not ranked
    maps = sweep_maps(records(), "clearance")
    np.testing.assert_array_equal(maps["feasible"][:, 0], [1.0, 0.0])  # y = -0.2 clear, y = +0.2 hit
    assert maps["quality"][0, 0] == clear.clearance and np.isnan(maps["quality"][1, 0])  # copied values
    fig = sweep_map_figure(records(), "clearance")
    labels = [ax.get_ylabel() for ax in fig.axes] + [t.get_text() for ax in fig.axes if ax.get_legend()
                                                     for t in ax.get_legend().get_texts()]
    assert "least clearance to the cell and itself [m]" in labels
    assert any(f"clearance {clear.clearance:.3g} m" in text for text in labels)
    assert plot_sweep_map(records(), tmp_path / "map.png", "clearance").stat().st_size > 10_000


def test_without_a_scene_the_records_have_no_clearance():
    robot, path, index, _, _ = cell()
    r = evaluate_placement(robot, path, index, placements()[0], 0, SweepOptions(steps_per_loop=100, starts=2))
    assert r.clearance is None and r.clearance_pair is None and r.feasible


def test_the_sweep_file_keeps_the_clearance_and_resumes(tmp_path):
    robot, path, index, _, scene = cell()
    out = tmp_path / "cell.jsonl"

    def interrupt(done, total):
        if done == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):  # stopped after the first placement: its record is in the file
        sweep(robot, path, index, placements(), workers=0, scene=scene, clearance=CLEARANCE, out=out,
              batch_size=1, progress=interrupt, **KW)
    head, back = read_sweep_file(out)
    assert len(back) == 1 and back[0].clearance_pair == records()[0].clearance_pair
    assert back[0].clearance == pytest.approx(records()[0].clearance, abs=1e-9)
    assert head["options"]["clearance"] == CLEARANCE and head["options"]["scene"]["objects"][0]["name"] == "pillar"
    calls = []

    def count(*args):
        calls.append(args[4])
        return evaluate_placement(*args)

    mp = pytest.MonkeyPatch()
    mp.setattr("kinredund.sweep.run.evaluate_placement", count)
    try:
        resumed = sweep(robot, path, index, placements(), workers=0, scene=scene, clearance=CLEARANCE, out=out,
                        resume=True, **KW)
    finally:
        mp.undo()
    assert calls == [1] and resumed[0] == back[0]  # the first record read back, field for field
    final = read_sweep_file(out)[1]
    assert final == resumed and final[1].cause == "collision" and isinstance(final[1].clearance_pair, tuple)
    with pytest.raises(KinredundError, match="another sweep"):  # another clearance is another sweep
        sweep(robot, path, index, placements(), workers=0, scene=scene, clearance=0.02, out=out, resume=True, **KW)


def test_bad_options_are_refused_before_any_work(monkeypatch):
    robot, path, index, _, scene = cell()
    monkeypatch.setattr(evaluate_mod, "evaluate_placement", lambda *a: pytest.fail("ran a placement"))
    monkeypatch.setattr("kinredund.sweep.run.evaluate_placement", lambda *a: pytest.fail("ran a placement"))
    P = placements()[:1]
    for bad in (-0.01, float("nan"), float("inf"), "1cm", True):
        with pytest.raises(KinredundError, match="clearance must be a finite distance >= 0"):
            sweep(robot, path, index, P, workers=0, scene=scene, clearance=bad)
    with pytest.raises(KinredundError, match="needs a scene"):
        sweep(robot, path, index, P, workers=0, clearance=0.01)
    with pytest.raises(KinredundError, match="must be a kinredund Scene"):
        sweep(robot, path, index, P, workers=0, scene="cell.json")
    other = kr.Scene(kr.load_robot("planar3r"))
    with pytest.raises(KinredundError, match="made for robot 'planar3r'"):
        sweep(robot, path, index, P, workers=0, scene=other)
    with pytest.raises(KinredundError, match="clearance_resolution"):
        sweep(robot, path, index, P, workers=0, scene=scene, clearance_resolution=0.0)


def test_cli_sweep_with_a_scene(tmp_path, capsys):
    robot, _, _, c, scene = cell()
    file, pairs = save_scene(scene, tmp_path / "cell.json"), scene.pair_matrix.save(tmp_path / "pairs.json")
    out = tmp_path / "s.jsonl"
    grid_arg = f"{c[0]}:{c[0]}:1,-0.2:0.2:2"
    code = main(["sweep", "panda", "--grid", grid_arg, "--z", str(c[2]), "--steps", "100", "--starts", "2",
                 "--workers", "0", "--scene", str(file), "--clearance", str(CLEARANCE), "--criterion", "clearance",
                 "--resolution", str(RESOLUTION), "--pairs", str(pairs),
                 "--json", str(out), "--quiet"])
    text = capsys.readouterr().out
    assert code == 0 and "1 feasible, 1 in collision" in text and "clearance" in text and " m (" in text
    _, back = read_sweep_file(out)
    assert [r.cause for r in back] == [None, "collision"]
    with pytest.raises(SystemExit):
        main(["sweep", "--help"])
    assert "--clearance C" in capsys.readouterr().out
    assert main(["sweep", "panda", "--grid", grid_arg, "--clearance", "0.01", "--workers", "0"]) == 2
    assert "need --scene" in capsys.readouterr().err
    assert main(["sweep", "panda", "--grid", grid_arg, "--scene", str(file), "--clearance", "-0.01", "--workers", "0",
                 "--quiet"]) == 2
    assert "clearance must be a finite distance >= 0 [m]" in capsys.readouterr().err


@pytest.mark.slow
def test_one_local_dask_worker_gives_the_serial_records():
    from test_sweep import assert_same_records

    robot, path, index, _, scene = cell()
    on_dask = sweep(robot, path, index, placements(), workers=1, scene=scene, clearance=CLEARANCE, **KW)
    assert_same_records(records(), on_dask)
    for a, b in zip(records(), on_dask, strict=True):
        assert a.clearance_pair == b.clearance_pair
        assert b.clearance == pytest.approx(a.clearance, abs=1e-9)


def test_a_scene_that_does_not_rebuild_the_same_is_refused():
    """A scene of an HD-table arm made with thicker capsules than the default would be checked on the workers
    with the default ones: refused once, before any placement."""
    planar = kr.load_robot("planar3r")
    scene = kr.Scene(planar, capsule_radius=0.2)
    scene.add_sphere("ball", 0.05, [0.0, 0.0, 1.0])
    with pytest.raises(KinredundError, match="does not rebuild"):
        sweep_scene(scene, planar)
    default = kr.Scene(planar)
    default.add_sphere("ball", 0.05, [0.0, 0.0, 1.0])
    assert sweep_scene(default, planar).objects[0][0] == "ball"


def test_records_read_back_with_and_without_the_clearance_fields():
    from kinredund.sweep import PlacementRecord

    hit = records()[1]
    data = hit.to_json_dict()
    assert PlacementRecord.from_json_dict(data) == hit  # every field, the pair back as a tuple
    old = {k: v for k, v in data.items() if not k.startswith("clearance")}  # a schema-version-1 record
    assert PlacementRecord.from_json_dict(old).clearance is None
    for bad in (["panda_link1_0"], ["a", 3], "a,b"):
        with pytest.raises(KinredundError, match="clearance_pair must be two object names"):
            PlacementRecord.from_json_dict({**data, "clearance_pair": bad})
    with pytest.raises(KinredundError, match="clearance must be a finite number"):
        PlacementRecord.from_json_dict({**data, "clearance": float("nan")})
