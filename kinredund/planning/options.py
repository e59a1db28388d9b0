"""The options of the cyclic planner, validated once (:class:`PlanOptions`), as the sweep's ``SweepOptions``.

Every count and length of :func:`kinredund.planning.cyclic.plan` is checked here before any work: a bad
value raises :class:`~kinredund.errors.OptionError` naming the option and its allowed range, never a
silent cap or a run that cannot end. The checks that need the robot (the margin against its narrowest
joint range) are :meth:`PlanOptions.check_for`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from kinredund.errors import MAX_STARTS, OptionError, check_count
from kinredund.planning.keepout import Keepout
from kinredund.tracking import MAX_STEPS
from kinredund.tracking.tracker import scene_constraints


def _length(value, what: str, *, positive: bool) -> float:
    """A finite real number (> 0 with ``positive``, else >= 0) as a float, else OptionError."""
    bound = "> 0" if positive else ">= 0"
    if isinstance(value, (bool, str, bytes)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise OptionError(f"{what} must be a finite number {bound}, got {value!r}")
    v = float(value)
    if not (math.isfinite(v) and (v > 0 if positive else v >= 0)):
        raise OptionError(f"{what} must be a finite number {bound}, got {value!r}")
    return v


#: the most random starts per sample: a sample none of them reached is seeded by one pose-only solve with four
#: times as many, and :func:`kinredund.ik.solve_ik` takes at most :data:`~kinredund.errors.MAX_STARTS`
MAX_PLAN_STARTS = MAX_STARTS // 4


@dataclass(frozen=True)
class PlanOptions:
    """How :func:`kinredund.planning.cyclic.plan` samples, walks, tracks and re-plans.

    Attributes:
        samples: N, equally spaced sample times k T / N per loop (at least 4, for the cubic spline).
        starts: random starts inside the limits per sample (four times as many at the first sample, and
            in the pose-only solve that seeds a sample none of them reached): at most :data:`MAX_PLAN_STARTS`.
        seed: the seed of ``np.random.default_rng`` for those starts (>= 0).
        loops: loops tracked (the verification checks closure after every loop).
        steps_per_loop: tracking steps per loop (at least 4).
        max_jump: the largest joint change between consecutive knots [rad or m].
        margin: the limits are shrunk by this for the samples and refinements [rad or m], at most a
            quarter of the robot's narrowest joint range (:meth:`check_for`).
        max_candidates: the candidates kept per sample (lowest z first), at least 1.
        budget: the most points inserted into one refined interval (0: no refinement).
        refine_samples: the most sample times added where no closed walk exists at the current sampling
            (in the middle of each interval the walk cannot cross), before the plan says why (0: none).
        rounds: re-plans with an inserted knot where the motion leaves the limits (0: none).
        max_iter: iterations of each joint-level solve.
        cycles: the joint motion repeats every ``cycles`` loops of the path.
        follow: follow z's own bounded optimum wherever it is strongly stable, the spline reference only
            across folds and singular stretches (:mod:`kinredund.planning.follow`); False: the reference
            all along (the thesis's Eqs. 6.23-6.28), with the measured intervals off z's optimum reported.
        scene: a :class:`~kinredund.geometry.scene.Scene` of the planned robot whose pairs the plan keeps apart
            (:mod:`kinredund.planning.keepout`), or None.
        clearance: with a scene, the least distance [m] from its obstacles (default 0.02, the tracker's).
        self_clearance: with a scene, the least distance [m] between the robot's own objects (default 0.01),
            or False to leave them unchecked.
        clearance_resolution: with a scene, the motion between recorded points (joints linear) must keep at
            least clearance - this [m], proven by :func:`~kinredund.geometry.motion.check_motion` (a motion
            held on a clearance sags by about (step length)^2 / (8 radius) between points).

    Raises:
        OptionError: a value outside its range, or loops x steps_per_loop over the tracker's
            :data:`~kinredund.tracking.MAX_STEPS`; a clearance without a scene, a clearance < 0, not a Scene.
    """

    samples: int = 24
    starts: int = 8
    seed: int = 0
    loops: int = 2
    steps_per_loop: int = 200
    max_jump: float = 0.25
    margin: float = 1e-3
    max_candidates: int = 8
    budget: int = 16
    refine_samples: int = 24
    rounds: int = 4
    max_iter: int = 200
    cycles: int = 1
    follow: bool = True
    scene: object = None
    clearance: float | None = None
    self_clearance: float | bool | None = None
    clearance_resolution: float = 1e-3

    def __post_init__(self) -> None:
        counts = {"samples": 4, "starts": 1, "seed": 0, "loops": 1, "steps_per_loop": 4, "max_candidates": 1,
                  "budget": 0, "refine_samples": 0, "rounds": 0, "max_iter": 1, "cycles": 1}
        for name, minimum in counts.items():
            object.__setattr__(self, name, check_count(getattr(self, name), minimum, name, OptionError))
        if self.starts > MAX_PLAN_STARTS:  # else solve_ik refuses 4 x starts deep in the run, after the solves before
            raise OptionError(f"starts must be at most {MAX_PLAN_STARTS} (four times as many seed one pose-only "
                              f"solve, which takes at most {MAX_STARTS}), got {self.starts}")
        if not isinstance(self.follow, (bool, np.bool_)):
            raise OptionError(f"follow must be True or False, got {self.follow!r}")
        object.__setattr__(self, "follow", bool(self.follow))
        object.__setattr__(self, "max_jump", _length(self.max_jump, "max_jump [rad or m]", positive=True))
        object.__setattr__(self, "margin", _length(self.margin, "margin [rad or m]", positive=False))
        object.__setattr__(self, "clearance_resolution", _length(self.clearance_resolution,
                                                                 "clearance_resolution [m]", positive=True))
        self.keepout_for(getattr(self.scene, "robot", None))  # the scene's own checks (the robot's in check_for)
        total = -(-self.loops // self.cycles) * self.cycles * self.steps_per_loop  # what the tracker records
        if total > MAX_STEPS:
            raise OptionError(f"loops x steps_per_loop must be at most {MAX_STEPS} (the record holds every step), "
                              f"got {self.loops} x {self.steps_per_loop}")

    @classmethod
    def of(cls, options: PlanOptions | None = None, **overrides) -> PlanOptions:
        """``options`` (default the defaults) with ``overrides`` replaced, validated.

        Raises:
            OptionError: an unknown option name (lists the known ones) or a value outside its range.
        """
        known = [f.name for f in fields(cls)]
        unknown = sorted(set(overrides) - set(known))
        if unknown:
            raise OptionError(f"unknown plan option(s) {unknown}; the options are {known}")
        base = cls() if options is None else options
        if not isinstance(base, cls):
            raise OptionError(f"options must be a PlanOptions, got {type(base).__name__}")
        return cls(**{**{k: getattr(base, k) for k in known}, **overrides}) if overrides else base

    def check_for(self, robot) -> None:
        """The checks that need the robot: the margin at most a quarter of its narrowest joint range.

        Raises:
            OptionError: a margin that would close a joint's range (it was silently capped before).
        """
        span = float(np.min(robot.upper - robot.lower))
        if self.margin > 0.25 * span:
            raise OptionError(f"margin must be at most a quarter of {robot.name}'s narrowest joint range "
                              f"({0.25 * span:.6g} rad or m), got {self.margin!r}")

    def scene_kw(self) -> dict:
        """``track()``'s scene=, clearance=, self_clearance= of these options ({} without a scene)."""
        return {} if self.scene is None else {"scene": self.scene, "clearance": self.clearance,
                                              "self_clearance": self.self_clearance}

    def keepout_for(self, robot):
        """The scene's clearances as the tracker holds them (:class:`~kinredund.planning.keepout.Keepout`), or
        None without a scene.

        Raises:
            OptionError: a clearance without a scene, not a Scene, a scene of another robot, a clearance < 0.
        """
        held = scene_constraints(robot, self.scene, self.clearance, self.self_clearance)
        return Keepout(held[0], self.clearance_resolution) if held else None
