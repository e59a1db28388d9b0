"""The self-collision pair matrix: which pairs of the robot's own objects are checked.

All pairs, minus (the first reason that applies is recorded):

- ``same_body``: both objects ride on one rigid body (one joint of the reduced model): their distance never changes;
- ``adjacent``: the same link, or a link and its parent (links without geometry skipped, as MoveIt does);
- ``srdf``: disabled by the robot's SRDF (example-robot-data ships one for several arms);
- ``home``: in contact at the robot's home configuration (MoveIt's "default" pairs);
- ``always``: in contact in at least ``always_fraction`` of the seeded samples of the joint box;
- ``never``: never closer than ``never_closer`` [m] in those samples.

The last three are what MoveIt's setup assistant does by sampling. ``never`` is a statistical judgement: a
pair that comes closer only in configurations the samples miss is not checked; lower ``never_closer`` or raise
``samples`` to keep more pairs. The samples use the convex hulls whatever ``geometry`` the scene uses (a hull is
never farther than its mesh, so "never closer" on hulls holds for the meshes); the object names are the same.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from kinredund.errors import GeometryError, check_count
from kinredund.geometry.collision_model import RobotGeometry
from kinredund.geometry.engine import Workspace
from kinredund.geometry.shapes import as_kind, bounding_spheres, positive
from kinredund.io import read_json_object, write_json
from kinredund.model.robot import Robot

#: the reasons a pair is not checked, in the order they are tried
REASONS = ("same_body", "adjacent", "srdf", "home", "always", "never")
SAMPLES, NEVER_CLOSER, ALWAYS_FRACTION = 300, 0.02, 0.95
FORMAT = "kinredund-pair-matrix"


@dataclass(frozen=True)
class PairMatrix:
    """Which self pairs are checked, and why the others are not.

    Attributes:
        robot: the robot's name.
        objects: the robot's collision objects, in order.
        enabled: the checked pairs (a, b), a before b in ``objects``.
        disabled: (a, b) -> the reason (one of :data:`REASONS`) for every pair not checked.
        samples, seed, never_closer, always_fraction: the sampling that decided ``home``/``always``/``never``
            (never_closer [m]).
    """

    robot: str
    objects: tuple[str, ...]
    enabled: tuple[tuple[str, str], ...]
    disabled: dict = field(repr=False)
    samples: int = SAMPLES
    seed: int = 0
    never_closer: float = NEVER_CLOSER
    always_fraction: float = ALWAYS_FRACTION

    def counts(self) -> dict[str, int]:
        """Pairs per reason, and ``checked``."""
        out = {r: 0 for r in REASONS}
        for reason in self.disabled.values():
            out[reason] += 1
        return {"checked": len(self.enabled), **out}

    def summary(self) -> str:
        """One line: how many pairs are checked and why the others are not."""
        c = self.counts()
        why = ", ".join(f"{v} {k}" for k, v in c.items() if k != "checked" and v)
        return f"{self.robot}: {c['checked']} of {c['checked'] + len(self.disabled)} self pairs checked ({why} not)"

    def to_dict(self) -> dict:
        """The JSON form (docs/schema.md)."""
        return {"format": FORMAT, "version": 1, "robot": self.robot, "objects": list(self.objects),
                "enabled": [list(p) for p in self.enabled],
                "disabled": [[a, b, r] for (a, b), r in self.disabled.items()],
                "samples": self.samples, "seed": self.seed, "never_closer": self.never_closer,
                "always_fraction": self.always_fraction}

    def save(self, path) -> Path:
        """Write the matrix as JSON (atomically)."""
        return write_json(path, self.to_dict(), indent=1)

    @classmethod
    def from_dict(cls, data: dict, where: str = "pair matrix") -> PairMatrix:
        """The matrix from :meth:`to_dict`'s form; GeometryError naming what is wrong."""
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise GeometryError(f"{where} is not a pair matrix: its 'format' must be {FORMAT!r}")
        try:
            objects = tuple(str(o) for o in data["objects"])
            enabled = tuple((str(a), str(b)) for a, b in data["enabled"])
            disabled = {(str(a), str(b)): str(r) for a, b, r in data["disabled"]}
            extra = {k: data[k] for k in ("samples", "seed", "never_closer", "always_fraction") if k in data}
            matrix = cls(str(data["robot"]), objects, enabled, disabled, **extra)
        except (KeyError, TypeError, ValueError) as err:
            raise GeometryError(f"{where}: malformed pair matrix ({type(err).__name__}: {err})") from err
        bad = [r for r in disabled.values() if r not in REASONS]
        named = {o for p in (*enabled, *disabled) for o in p}
        if bad or not named <= set(objects):
            raise GeometryError(f"{where}: unknown reasons {bad} (allowed: {', '.join(REASONS)}) or object names "
                                f"{sorted(named - set(objects))} not in its objects")
        return matrix

    @classmethod
    def load(cls, path) -> PairMatrix:
        """Read a matrix written by :meth:`save`."""
        return cls.from_dict(read_json_object(path), str(path))


def srdf_disabled(path: Path) -> set[frozenset]:
    """The link pairs an SRDF's ``<disable_collisions link1= link2=>`` elements name."""
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as err:
        raise GeometryError(f"cannot read SRDF {str(path)!r}: {err}") from err
    return {frozenset((e.get("link1"), e.get("link2"))) for e in root.iter("disable_collisions")}


def _structural(geom: RobotGeometry) -> tuple[list, dict]:
    """(candidate pairs (i, j), disabled (a, b) -> reason) from the bodies, the link tree and the SRDF."""
    objs = geom.model.geometryObjects
    srdf = srdf_disabled(geom.srdf) if geom.srdf is not None else set()
    todo, disabled = [], {}
    for i in range(len(objs)):
        for j in range(i + 1, len(objs)):
            la, lb = geom.links[i], geom.links[j]
            key = (geom.names[i], geom.names[j])
            if objs[i].parentJoint == objs[j].parentJoint:
                disabled[key] = "same_body"
            elif la == lb or geom.parent_link.get(la) == lb or geom.parent_link.get(lb) == la:
                disabled[key] = "adjacent"
            elif frozenset((la, lb)) in srdf:
                disabled[key] = "srdf"
            else:
                todo.append((i, j))
    return todo, disabled


def self_pairs(robot: Robot, geom: RobotGeometry, *, samples: int = SAMPLES, seed: int = 0,
               never_closer: float = NEVER_CLOSER, always_fraction: float = ALWAYS_FRACTION) -> PairMatrix:
    """The pair matrix of the robot's own objects (module docstring).

    Args:
        robot: the robot (its joint box is sampled, its home tested).
        geom: its collision model (:func:`~kinredund.geometry.collision_model.robot_geometry`); meshes are
            sampled as convex hulls.
        samples: seeded uniform samples of the joint box (``robot.sample_box``).
        seed: the sampling's seed (``np.random.default_rng(seed)``).
        never_closer: a pair never closer than this [m] in every sample is not checked.
        always_fraction: a pair in contact in at least this fraction of the samples is not checked.
    """
    samples = check_count(samples, 1, "samples", GeometryError)
    never_closer = positive(never_closer, "never_closer [m]")
    if not 0.0 < always_fraction <= 1.0:
        raise GeometryError(f"always_fraction must be in (0, 1], got {always_fraction!r}")
    todo, disabled = _structural(geom)
    gm = pin.GeometryModel()
    for g in geom.model.geometryObjects:  # hulls for the sampling (the names and order are the same)
        shape = as_kind(g.geometry, "convex")
        gm.addGeometryObject(pin.GeometryObject(g.name, g.parentJoint, g.parentFrame, g.placement, shape))
    for i, j in todo:
        gm.addCollisionPair(pin.CollisionPair(i, j))
    spheres = [bounding_spheres(g.geometry, g.placement) for g in gm.geometryObjects]
    first = np.array([i for i, _ in todo], dtype=int)
    second = np.array([j for _, j in todo], dtype=int)
    ws = Workspace(robot.model, gm, np.array([g.parentJoint for g in gm.geometryObjects]),
                   np.array([c for c, _ in spheres]), np.array([r for _, r in spheres]), first, second)
    rng = np.random.default_rng(seed)
    qs = [robot.home] + [robot.random_configuration(rng) for _ in range(samples)]
    closest = np.full(len(todo), np.inf)
    contacts = np.zeros(len(todo), dtype=int)
    at_home = np.zeros(len(todo), dtype=bool)
    for s, q in enumerate(qs):
        near, dist = ws.query(q, never_closer)[:2] if len(todo) else ((), ())  # the broadphase, then coal
        for k, d in zip(near, dist, strict=True):
            closest[k] = min(closest[k], d)
            if d <= 0.0:
                if s == 0:
                    at_home[k] = True
                else:
                    contacts[k] += 1
    enabled = []
    for k, (i, j) in enumerate(todo):
        key = (geom.names[i], geom.names[j])
        if at_home[k]:
            disabled[key] = "home"
        elif contacts[k] >= always_fraction * samples:
            disabled[key] = "always"
        elif closest[k] > never_closer:
            disabled[key] = "never"
        else:
            enabled.append(key)
    return PairMatrix(robot.name, geom.names, tuple(enabled), disabled, samples, seed, never_closer, always_fraction)
