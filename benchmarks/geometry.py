"""Collision-geometry timings: one scene query on the Panda, by collision model and with or without broadphase.

Usage::

    python benchmarks/geometry.py [--json FILE] [--repeat N]

The scene: the Panda's self pairs (its pair matrix) and five objects (a table, a ball, a post, a bar and a
tool held by the hand). Three collision models of the same robot:

- ``hulls``: the URDF's collision meshes as convex hulls (``geometry="convex"``, the default);
- ``meshes``: the same meshes exact (``geometry="mesh"``, triangle BVHs, for final checks);
- ``primitives``: example-robot-data's ``panda_collision.urdf`` (spheres and cylinders).

Each model runs on both paths of the query (``kinredund.geometry.engine``): ``compiled`` (one call of the
compiled core, ``kinredund._core``, where it is installed) and ``python`` (the same Pinocchio and coal calls
from Python; the same results, tests/test_geometry_core.py). Per model and path, the median and p95 [us] over
seeded configurations (``_bench.time_in_turn``: all calls of one model, both paths, in turn, so their ratios hold
under background load) of

- ``distances``: ``scene.distances(q)``, every checked pair exact, with witness points and normals;
- ``distances_bp``: ``scene.distances(q, influence=INFLUENCE)``, the bounding-sphere broadphase first;
- ``rows_bp``: ``scene.distance_rows(q, influence=INFLUENCE)``, distances and rows G (d_dot = G q_dot);
- ``min_distance``: ``scene.min_distance(q)`` (the pair of the least bounding-sphere gap, then every pair that
  gap bound does not rule out, in one Pinocchio call);

- ``distances_bp_free``: ``distances_bp`` on the contact-free configurations only (a tracker's steps: about
  half of the seeded configurations put the arm into itself or the table, with more near pairs and coal's
  normals to read);
- ``query_bp_free`` (``ws (bp free)``): the workspace's own query behind ``distances_bp_free``
  (``Workspace.query``: the arrays without the scene's checks of q and its record);

and the ratios without / with the broadphase, of each model to the hulls and of the Python path to the compiled
one; the same medians in this thread's CPU time (``cpu``: on a loaded machine the wall time also counts what the
scheduler gives other processes). ``coal_bp_free`` [us] is coal's share of ``distances_bp_free``: one
``pin.computeDistances`` over just the pairs the broadphase keeps (placed beforehand), the exact distances
alone. ``check_hulls`` and ``check_meshes``: ``check_motion`` (what ``kinredund check`` runs) of one seeded Panda
motion on both paths (:func:`bench_check`). The issue's target for the default (hulls) is at most 30 us per
query from Python; the script prints what it measures, and how many pairs each query computed exactly (median
over the configurations: ``exact (bp)`` for the broadphase at INFLUENCE, ``exact (min)`` for ``min_distance``, whose
compiled search computes a subset of the Python path's pairs).
"""

from __future__ import annotations

import itertools
import time

import numpy as np
import pinocchio as pin
from _bench import parser, print_table, time_in_turn, write_json

import kinredund
from kinredund.geometry.engine import compiled_core
from kinredund.geometry.motion import check_motion
from kinredund.model.erd import erd_share_dir

#: the broadphase distance [m]: pairs whose bounding spheres are farther apart are not computed
INFLUENCE = 0.05
TARGET_US = 30.0


def panda_scene(model: str, compiled: bool | None = None) -> kinredund.Scene:
    r = kinredund.load_robot("panda")
    kw = {"geometry": "mesh"} if model == "meshes" else {}
    if model == "primitives":
        kw["collision_urdf"] = erd_share_dir() / "panda_description/urdf/panda_collision.urdf"
    s = kinredund.Scene(r, compiled=compiled, **kw)
    s.add_box("table", [1.2, 0.8, 0.04], {"xyz": [0.5, 0.0, -0.03]})
    s.add_sphere("ball", 0.05, [0.45, 0.3, 0.45])
    s.add_cylinder("post", 0.04, 0.8, {"xyz": [-0.4, 0.3, 0.4]})
    s.add_capsule("bar", 0.02, 0.5, {"xyz": [0.3, -0.45, 0.6], "rpy": [1.2, 0.0, 0.0]})
    s.add_box("tool", [0.02, 0.02, 0.12], {"xyz": [0.0, 0.0, 0.12]}, attach_to="panda_hand")
    return s


def _calls(s: kinredund.Scene, qs: list, free: list) -> dict:
    """The five queries on scene ``s``, each cycling through the configurations on its own (one shared counter
    would give each query every fifth configuration, so different configurations and numbers of near pairs)."""
    q = [itertools.cycle(qs).__next__ for _ in range(4)] + [itertools.cycle(free).__next__ for _ in range(2)]
    ws = s.workspace()
    return {
        "distances": lambda: s.distances(q[0]()),
        "distances_bp": lambda: s.distances(q[1](), influence=INFLUENCE),
        "rows_bp": lambda: s.distance_rows(q[2](), influence=INFLUENCE),
        "min_distance": lambda: s.min_distance(q[3]()),
        "distances_bp_free": lambda: s.distances(q[4](), influence=INFLUENCE),
        "query_bp_free": lambda: ws.query(q[5](), INFLUENCE),
    }


def coal_share(s: kinredund.Scene, free: list, repeat: int) -> float:
    """Median [us] of one ``pin.computeDistances`` over the pairs the broadphase keeps at each contact-free
    configuration (placed and chosen before the clock starts, the configurations in turn as in the queries'
    timing: one configuration again and again runs faster): the exact distances of ``distances_bp_free`` alone."""
    ws = s.workspace()
    cells = len(ws.geometry.geometryObjects)
    active = []
    for q in free:
        ws.place(q)
        a = np.zeros((cells, cells), dtype=bool)
        for k in ws.near_pairs(INFLUENCE).tolist():
            a[ws.first[k], ws.second[k]] = a[ws.second[k], ws.first[k]] = True
        active.append(a)
    times = []
    for _ in range(repeat):
        for q, a in zip(free, active, strict=True):
            ws.place(q)
            ws.gdata.setActiveCollisionPairs(ws.geometry, a)
            t0 = time.perf_counter()
            pin.computeDistances(ws.geometry, ws.gdata)
            times.append(time.perf_counter() - t0)
    return float(np.median(times) * 1e6)


def bench_model(model: str, repeat: int) -> dict:
    paths = {"compiled": True, "python": False} if compiled_core() is not None else {"python": False}
    scenes = {p: panda_scene(model, c) for p, c in paths.items()}
    s = scenes["python"]
    r = s.robot
    rng = np.random.default_rng(0)
    qs = [r.home] + [r.random_configuration(rng, 0.1) for _ in range(19)]
    free = [x for x in qs if s.min_distance(x) > 0]
    n_free, free = len(free), free or qs  # (exact meshes: coal reports touching parts of the hand as 0)
    calls = {f"{name}/{p}": f for p, sc in scenes.items() for name, f in _calls(sc, qs, free).items()}
    wall = time_in_turn(calls, repeat=repeat, warmup=5)
    cpu = time_in_turn(calls, repeat=repeat, warmup=5, clock=time.thread_time)
    exact = [len(s.distances(x, influence=INFLUENCE)) for x in qs]
    exact_min = {p: [] for p in paths}
    for x, (p, sc) in itertools.product(qs, scenes.items()):  # min_distance leaves the pairs it computed active
        sc.min_distance(x)
        exact_min[p].append(sum(sc.workspace().gdata.activeCollisionPairs))
    out = {"pairs": len(s.pairs), "self_pairs": len(s.pair_matrix.enabled), "free_configurations": n_free,
           "exact_pairs_bp_median": float(np.median(exact)),
           "exact_pairs_min_median": {p: float(np.median(e)) for p, e in exact_min.items()},
           "exact_pairs_bp_free_median": float(np.median([len(s.distances(x, influence=INFLUENCE)) for x in free])),
           "coal_bp_free_us": coal_share(s, free, max(1, repeat // 4))}
    for p in paths:
        times = {k.split("/")[0]: v for k, v in wall.items() if k.endswith("/" + p)}
        out[p] = {**times, "cpu": {k.split("/")[0]: v for k, v in cpu.items() if k.endswith("/" + p)},
                  "ratio_bp": times["distances"]["median_us"] / times["distances_bp"]["median_us"]}
    if "compiled" in paths:
        out["python_over_compiled"] = {k: out["python"][k]["median_us"] / out["compiled"][k]["median_us"]
                                       for k in QUERIES}
    return out


QUERIES = ("distances", "distances_bp", "distances_bp_free", "rows_bp", "min_distance", "query_bp_free")


def bench_check(model: str, samples: int, repeat: int) -> dict:
    """``check_motion`` (``kinredund check``) of a seeded back-and-forth joint motion about the Panda's home
    (``samples`` samples over 2 s) on both paths: the least clearance, configurations evaluated (samples and
    midpoints) and the median CPU time [ms] of ``repeat`` runs."""
    r = kinredund.load_robot("panda")
    direction = np.random.default_rng(1).uniform(-1.0, 1.0, r.nq)
    t = np.linspace(0.0, 2.0, samples)
    q = r.home + 0.5 * np.sin(np.pi * t)[:, None] * direction
    out = {"samples": samples}
    for path, compiled in (("compiled", True), ("python", False)):
        if compiled and compiled_core() is None:
            continue
        s = panda_scene(model, compiled)
        times = []
        for _ in range(repeat):
            t0 = time.thread_time()
            c = check_motion(s, t, q)
            times.append(time.thread_time() - t0)
        out[path] = {"ms": float(np.median(times) * 1e3), "min_distance": c.min_distance,
                     "min_pair": list(c.min_pair) if c.min_pair else None, "evaluations": c.evaluations}
    if "compiled" in out:
        out["python_over_compiled"] = out["python"]["ms"] / out["compiled"]["ms"]
    return out


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=400, help="timed calls per query (meshes: a tenth)")
    args = p.parse_args()
    repeat = 3 if args.smoke else args.repeat
    out = {"influence_m": INFLUENCE, "target_us": TARGET_US, "compiled_core": compiled_core() is not None}
    for model in ("hulls", "primitives", "meshes"):
        out[model] = bench_model(model, repeat if model != "meshes" else max(3 if args.smoke else 20, repeat // 10))
    paths = [x for x in ("compiled", "python") if x in out["hulls"]]
    rows = []
    for model, path in itertools.product(("hulls", "primitives", "meshes"), paths):
        m, t = out[model], out[model][path]
        rows.append([model, path, m["pairs"], m["exact_pairs_bp_median"], m["exact_pairs_min_median"][path]]
                    + [t[k]["median_us"] for k in QUERIES]
                    + [t["ratio_bp"], t["distances"]["median_us"] / out["hulls"][path]["distances"]["median_us"]])
    print(f"Panda, self pairs + 5 objects; broadphase influence {INFLUENCE} m; median us per call")
    print_table(rows, ["model", "path", "pairs", "exact (bp)", "exact (min)", "distances", "dist. (bp)",
                       "free (bp)", "rows (bp)", "min_distance", "ws (bp free)", "no bp / bp", "vs hulls"])
    if "compiled" in paths:
        print("python / compiled (median ratios):")
        print_table([[model] + [out[model]["python_over_compiled"][k] for k in QUERIES]
                     for model in ("hulls", "primitives", "meshes")], ["model", *QUERIES])
    else:
        print("the compiled core is not installed: the Python path only")
    h = out["hulls"][paths[0]]
    queries = ("distances_bp", "distances_bp_free", "rows_bp", "min_distance")
    cpu = ", ".join(f"{k} {h['cpu'][k]['median_us']:.0f}" for k in queries)
    verdict = ", ".join(f"{k} {h[k]['median_us']:.0f} us ({'meets' if h[k]['median_us'] <= TARGET_US else 'misses'})"
                        for k in queries)
    print(f"target for the default (hulls, {paths[0]}): <= {TARGET_US:g} us per query: {verdict}")
    print(f"hulls, {paths[0]}, this thread's CPU time only (median us; what the scheduler does not add): {cpu}")
    for model in ("hulls", "meshes"):
        out[f"check_{model}"] = c = bench_check(model, 11 if args.smoke else 101, 1 if args.smoke else 3)
        line = ", ".join(f"{p} {c[p]['ms']:.1f} ms ({c[p]['evaluations']} configurations, least clearance "
                         f"{c[p]['min_distance']:.6f} m)" for p in paths)
        ratio = f"; python / compiled {c['python_over_compiled']:.2f}" if "compiled" in c else ""
        print(f"check_motion, {model}, {c['samples']} samples (CPU time): {line}{ratio}")
    coal, free = out["hulls"]["coal_bp_free_us"], h["distances_bp_free"]["median_us"]
    print(f"hulls: coal's exact distances alone (one pin.computeDistances over the broadphase's pairs, contact-free): "
          f"{coal:.1f} us of {free:.1f} us ({coal / free:.0%})")
    write_json(args.json, out)


if __name__ == "__main__":
    main()
