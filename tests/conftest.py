"""Shared fixtures: robots are loaded once per session (loading the Panda's URDF takes ~50 ms)."""

from __future__ import annotations

import functools
import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

import kinredund

SHIPPED = ["planar3r", "planar3r_ch6", "puma7", "cybotech_p15"]
ALL_ROBOTS = SHIPPED + ["panda", "xarm7"]


@functools.cache
def robot(name: str, task: str | None = None) -> kinredund.Robot:
    """A cached robot (tests must not rely on its workspace state between calls)."""
    return kinredund.load_robot(name, task=task)


def configurations(r: kinredund.Robot, seed: int, count: int = 3, margin: float = 0.1) -> list[np.ndarray]:
    """Seeded random configurations inside the limits (away from the bounds), for derivative checks."""
    rng = np.random.default_rng(seed)
    lo = np.maximum(r.lower, -np.pi)
    hi = np.minimum(r.upper, np.pi)
    span = hi - lo
    return [rng.uniform(lo + margin * span, hi - margin * span) for _ in range(count)]


BENCHMARKS = Path(__file__).resolve().parent.parent / "benchmarks"


@functools.cache
def load_benchmark(name: str):
    """The module of ``benchmarks/NAME.py`` (the scripts import their sibling ``_bench``)."""
    if str(BENCHMARKS) not in sys.path:
        sys.path.insert(0, str(BENCHMARKS))
    spec = importlib.util.spec_from_file_location(f"kinredund_bench_{name}", BENCHMARKS / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(params=ALL_ROBOTS)
def any_robot(request) -> kinredund.Robot:
    return robot(request.param)
