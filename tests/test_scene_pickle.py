"""A Scene and its SceneClearance pickle (a sweep's workers, Dask): rebuilt from what makes them, same distances.

The unpickled scene makes its coal shapes and hulls again from the same numbers (deterministic), so its
distances, rows and the tracker's record agree with the original's to rounding (1e-12: the bar of the issue's
runs without an active distance).
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from conftest import configurations
from test_tracking_scene import CLEARANCE, run, setup

import kinredund as kr
from kinredund.errors import OptionError


def cell() -> kr.Scene:
    """The Panda with a world sphere and box, a capsule carried by the hand and one ignored pair."""
    r = setup()[0]
    sc = kr.Scene(r)
    sc.add_sphere("ball", 0.05, [-0.3178, 0.2255, 0.3518])
    sc.add_box("table", [0.6, 0.6, 0.02], [0.4, 0.0, 0.05])
    sc.add_capsule("tool", 0.02, 0.1, [0.0, 0.0, 0.1], attach_to="panda_hand")
    sc.ignore("panda_link0_0", "tool")
    return sc


def test_an_unpickled_scene_clearance_gives_the_same_rows():
    c = kr.SceneClearance(cell(), clearance=CLEARANCE, self_clearance=0.01, influence=0.2)
    back = pickle.loads(pickle.dumps(c))
    assert back.pairs == c.pairs and back.scene.objects == c.scene.objects and back.scene.ignored == c.scene.ignored
    assert np.array_equal(back.clearances, c.clearances) and back.influence == c.influence
    r = c.scene.robot
    for q in configurations(r, seed=11, count=5):
        v0, G0 = c.rows_at(q)
        v1, G1 = back.rows_at(q)
        assert np.abs(v1 - v0).max() <= 1e-12 and np.abs(G1 - G0).max() <= 1e-12
        d0, d1 = c.scene.distances(q), back.scene.distances(q)
        assert d1.pairs == d0.pairs and np.abs(d1.distance - d0.distance).max() <= 1e-12
        assert np.abs(back.distance(q) - c.distance(q)).max() <= 1e-12


def test_a_run_with_an_unpickled_scene_is_the_same():
    r, path, index, q0, sc = setup()
    tr = kr.track(r, path, index, q0, scene=pickle.loads(pickle.dumps(sc)), clearance=CLEARANCE,
                  self_clearance=False)
    ref = run()
    assert tr.q.shape == ref.q.shape and np.abs(tr.q - ref.q).max() <= 1e-12
    pairs = list(zip(tr.meta["switches"], ref.meta["switches"], strict=True))
    assert pairs and all(a["name"] == b["name"] and abs(a["t"] - b["t"]) <= 1e-12 for a, b in pairs)


def test_an_unpickled_clearance_whose_scene_checks_other_pairs_is_refused():
    sc = cell()
    c = kr.SceneClearance(sc, self_clearance=None)
    state = c.__getstate__()
    state["scene"] = kr.Scene(sc.robot)  # no objects: other pairs
    back = object.__new__(kr.SceneClearance)
    with pytest.raises(OptionError, match="other pairs"):
        back.__setstate__(state)
