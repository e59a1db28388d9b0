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

from kinredund.errors import MAX_STARTS, OptionError, check_choice, check_count, check_size
from kinredund.planning.keepout import Keepout
from kinredund.planning.spline import SPLINE_KINDS
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


#: the options that size a plan's work: (name, least value, their kind of :data:`~kinredund.errors.SIZES`)
SIZED = (("samples", 4, "plan_samples"), ("refine_samples", 0, "plan_samples"), ("max_candidates", 1, "candidates"),
         ("budget", 0, "refinements"), ("rounds", 0, "rounds"), ("max_iter", 1, "iterations"))


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
        spline: the knots' cubic spline, ``periodic`` (default) or ``natural`` (the thesis's, :mod:`.spline`).

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
    spline: str = "periodic"

    def __post_init__(self) -> None:
        counts = {"starts": 1, "seed": 0, "loops": 1, "steps_per_loop": 4, "cycles": 1}
        for name, minimum in counts.items():
            object.__setattr__(self, name, check_count(getattr(self, name), minimum, name, OptionError))
        for name, minimum, size in SIZED:  # bounded (errors.SIZES), before any work
            object.__setattr__(self, name, check_size(getattr(self, name), name, size, minimum=minimum))
        check_size(self.samples * self.cycles, f"samples x cycles ({self.samples} x {self.cycles})", "plan_samples")
        # else solve_ik refuses 4 x starts deep in the run, after the solves before
        check_size(self.starts, "starts", "starts", per=(4, "four times as many seed one pose-only solve"))
        if not isinstance(self.follow, (bool, np.bool_)):
            raise OptionError(f"follow must be True or False, got {self.follow!r}")
        object.__setattr__(self, "follow", bool(self.follow))
        check_choice("spline", self.spline, SPLINE_KINDS)
        object.__setattr__(self, "max_jump", _length(self.max_jump, "max_jump [rad or m]", positive=True))
        object.__setattr__(self, "margin", _length(self.margin, "margin [rad or m]", positive=False))
        object.__setattr__(self, "clearance_resolution", _length(self.clearance_resolution,
                                                                 "clearance_resolution [m]", positive=True))
        self.keepout_for(getattr(self.scene, "robot", None))  # the scene's own checks (the robot's in check_for)
        total = -(-self.loops // self.cycles) * self.cycles * self.steps_per_loop  # what the tracker records
        check_size(total, f"loops x steps_per_loop ({self.loops} x {self.steps_per_loop}, whole cycles of "
                          f"{self.cycles}: the record holds every step)", "samples")

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


def _sample_times(samples) -> tuple[float, ...]:
    """Sample times [s]: at least 4 finite numbers from 0, strictly increasing (the period is checked by the planner).

    Raises:
        OptionError: anything else.
    """
    try:
        t = np.asarray(samples, float)
    except (TypeError, ValueError) as err:
        raise OptionError(f"samples must be a count or sample times [s], got {samples!r}") from err
    if t.ndim != 1 or t.size < 4 or not np.all(np.isfinite(t)) or t[0] != 0.0 or np.any(np.diff(t) <= 0):
        raise OptionError(f"sample times must be at least 4 finite numbers from 0, increasing strictly, "
                          f"got {samples!r}")
    return tuple(float(v) for v in t)


@dataclass(frozen=True)
class ObstacleOptions(PlanOptions):
    """The options of the Chapter 6 obstacle planner (:func:`kinredund.planning.planner.plan`): the pipeline's
    options with the thesis's defaults (9 samples, one loop, the spline reference all along) and the policy's.

    Attributes:
        samples: a count of equally spaced samples, or the sample times [s] themselves (then ``sample_times``).
        sample_times: the sample times [s] (from 0, increasing, below the period), or None.
        weights: (w1 [m^2], w2) of Eq. (6.21)/(6.44), or one pair per sample, shape (N, 2).
        policy: ``policy(robot, obstacle, normal, (w1, w2)) -> Index``; None: the thesis's policy.
        seeds: {sample index: configuration or list of configurations} added to the seeds there.
        substeps: clearance checks per tracking step (at most ``MAX_STEPS`` clearance checks in all).
        link_radius: capsule radius of the links [m].
        tool_tip: the last link's tip excluded from its clearance [m]; None: 1/6 of its length.
        check_doubling: repeat the clearance check at twice the resolution.
        check_reach: screen the samples with the wrist reach of the default policy (Eq. 6.44).
        refine: bisect the transitions between samples (``max_jump``, at most ``budget`` points each).
        refine_samples: the most samples inserted where no closed walk exists (0 by default: the thesis's
            sampling as given; each inserted sample costs its candidates and the transitions of two intervals).

    Raises:
        OptionError: as :class:`PlanOptions`, bad weights or sample times, a scene (the obstacle planner checks its
            obstacle; a scene is ``kr.plan``'s).
    """

    samples: int = 9
    starts: int = 12
    loops: int = 1
    steps_per_loop: int = 400
    max_jump: float = 0.3
    margin: float = 0.0
    max_candidates: int = 4
    budget: int = 32
    refine_samples: int = 0
    follow: bool = False
    sample_times: tuple | None = None
    weights: object = (1e-3, 1.0)
    policy: object = None
    seeds: object = None
    substeps: int = 8
    link_radius: float = 0.0
    tool_tip: float | None = None
    check_doubling: bool = True
    check_reach: bool = True
    refine: bool = True

    def __post_init__(self) -> None:
        if isinstance(self.samples, bool) or not isinstance(self.samples, (int, np.integer)):
            object.__setattr__(self, "sample_times", _sample_times(self.samples))
            object.__setattr__(self, "samples", len(self.sample_times))
        super().__post_init__()
        if self.scene is not None:
            raise OptionError("the obstacle planner checks its obstacle: give a scene to kinredund.plan instead")
        object.__setattr__(self, "substeps", check_count(self.substeps, 1, "substeps", OptionError))
        check_size(self.substeps * self.loops * self.steps_per_loop, "substeps x loops x steps_per_loop "
                   f"({self.substeps} x {self.loops} x {self.steps_per_loop}: the clearance checks)", "samples")
        object.__setattr__(self, "link_radius", _length(self.link_radius, "link_radius [m]", positive=False))
        if self.tool_tip is not None:
            object.__setattr__(self, "tool_tip", _length(self.tool_tip, "tool_tip [m]", positive=False))
        for flag in ("check_doubling", "check_reach", "refine"):
            if not isinstance(getattr(self, flag), (bool, np.bool_)):
                raise OptionError(f"{flag} must be True or False, got {getattr(self, flag)!r}")
        if self.policy is not None and not callable(self.policy):
            raise OptionError(f"policy must be a callable policy(robot, obstacle, normal, weights) -> Index, "
                              f"got {type(self.policy).__name__}")
        if self.seeds is not None and not isinstance(self.seeds, dict):
            raise OptionError("seeds must be a dict {sample index: configuration(s)}, "
                              f"got {type(self.seeds).__name__}")
        self.weights_per_sample()  # checked here, once

    def check_for(self, robot) -> None:
        """:meth:`PlanOptions.check_for` and the seeds: each at a sample of the plan, a configuration of the robot.

        Raises:
            OptionError: a seed at no sample; JointVectorError: a seed that is not a configuration of the robot.
        """
        super().check_for(robot)
        for k, given in (self.seeds or {}).items():
            if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k < self.samples:
                raise OptionError(f"seeds must be keyed by a sample index in 0..{self.samples - 1}, got {k!r}")
            for q in ([given] if np.ndim(given) == 1 else list(given)):
                robot.check_q(q, f"seed of sample {k + 1}")

    def weights_per_sample(self) -> np.ndarray:
        """The (w1, w2) of each sample, shape (N, 2), each pair checked as the policy checks it.

        Raises:
            OptionError: not (w1, w2) or one pair per sample, or a pair the policy refuses.
        """
        n = self.samples
        try:
            w = np.asarray(self.weights, float)
        except (TypeError, ValueError) as err:
            raise OptionError(f"weights must be (w1, w2) or one pair per sample ({n}, 2), "
                              f"got {self.weights!r}") from err
        w = np.tile(w, (n, 1)) if w.shape == (2,) else w
        if w.shape != (n, 2):
            raise OptionError(f"weights must be (w1, w2) or one pair per sample ({n}, 2), got shape {w.shape}")
        for k, (w1, w2) in enumerate(w):
            if not (math.isfinite(w1) and math.isfinite(w2) and w1 >= 0 and w2 >= 0 and w1 + w2 > 0):
                raise OptionError(f"the weights of sample S{k + 1} must be finite, >= 0 and not both 0, got {(w1, w2)}")
        return w

    def times(self, period: float) -> np.ndarray:
        """The sample times [s] over one period.

        Raises:
            OptionError: given sample times that reach the period.
        """
        if self.sample_times is None:
            return np.arange(self.samples) * period / self.samples
        if self.sample_times[-1] >= period:
            raise OptionError(f"sample times must stay below the period {period:.6g} s, got {self.sample_times[-1]}")
        return np.array(self.sample_times)


@dataclass(frozen=True)
class RoadmapOptions(ObstacleOptions):
    """The options of the roadmap plan of Section 6.3 (:func:`kinredund.planning.roadmap.plan_roadmap`).

    Attributes:
        slices: the roadmap's time slices over the loop.
        grid: the azimuths of the self-motion per slice.
        (the others as :class:`ObstacleOptions`, with 720 tracking steps and 4 clearance checks per step)
    """

    max_jump: float = 0.25
    steps_per_loop: int = 720
    substeps: int = 4
    slices: int = 90
    grid: int = 360

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("slices", "grid"):
            object.__setattr__(self, name, check_size(getattr(self, name), name, "roadmap", minimum=4))
        check_size(self.slices * self.grid, f"slices x grid ({self.slices} x {self.grid})", "roadmap")
