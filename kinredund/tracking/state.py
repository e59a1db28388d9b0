"""A stepper's state as one value: what a step starts from and what a rejected step is undone to.

A :class:`~kinredund.tracking.stepper.Stepper` works on its attributes while it steps; between steps (and at
a switching time, and before each sub-step of the step control) the whole of what the next step depends on
is :class:`StepState`, a frozen record read with ``stepper.state`` and put back with ``stepper.state =
saved``. The record's fields are the stepper's attribute names, so there is one list of what the state is
(the dataclass), not one per place that saves it. Arrays in it are never changed in place by the steppers
(they assign new arrays), so a state holds references, not copies.

With constraints (:mod:`kinredund.tracking.limited`) the state also holds the active set and the
multipliers of the inequalities (:class:`ConstrainedState`). A compiled stepper keeps the same fields in
one struct.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True, slots=True)
class StepState:
    """The state of a run at one time.

    Attributes:
        t: the time [s] (t0 + k dt at the requested times).
        k: the number of requested steps taken.
        q: the joints [rad or m]; ``lam``: the multipliers of the task (Eq. 4.5).
        qdot, lamdot: their rates at t [1/s] (Eq. 4.24).
        y, yd: ``[q; lam]`` and ``[qdot; lamdot]``, the predictor's current point and slope.
        pt: the last evaluation (:class:`~kinredund.tracking.point.Point`), M: the system's matrix there.
        label: the step's linear-solver label (None until classified).
        lu, rcond: the last LU factors of R and their reciprocal condition estimate (the watch reuses them).
        prev: the predictor's history ``(y, ydot, y, ydot, ...)``, oldest first.
    """

    t: float
    k: int
    q: np.ndarray
    lam: np.ndarray
    qdot: np.ndarray | None
    lamdot: np.ndarray | None
    y: np.ndarray | None
    yd: np.ndarray | None
    pt: Any
    M: np.ndarray | None
    label: str | None
    lu: Any
    rcond: float | None
    prev: tuple = ()


@dataclass(frozen=True, slots=True)
class ConstrainedState(StepState):
    """:class:`StepState` with the active set of the inequality constraints.

    Attributes:
        fixed: (n,) bool, the joints on a bound; ``side``: (n,) +1 at a lower bound, -1 at an upper one, 0 free.
        rows: the active general inequality rows (their numbers among the stepper's rows), in the order
            their multipliers w = -nu follow lambda in ``lam``.
        mu: the multipliers of the active bounds (n,).
        switches: the switches of the active set so far (dicts: time, what, ``reach``/``release``).
    """

    fixed: np.ndarray | None = None
    side: np.ndarray | None = None
    rows: tuple = ()
    mu: np.ndarray | None = None
    switches: tuple = ()


def capture(obj, cls: type[StepState]) -> StepState:
    """The state of ``obj`` (a stepper) as a ``cls`` record: its attributes of the fields' names."""
    return cls(*[tuple(obj.prev) if name == "prev" else getattr(obj, name) for name in _names(cls)])


def apply(obj, state: StepState) -> None:
    """Put ``state`` back on ``obj`` (every field); ``prev`` is refilled in place (the predictor's list)."""
    for name in _names(type(state)):
        if name == "prev":
            obj.prev[:] = state.prev
        else:
            setattr(obj, name, getattr(state, name))


_NAMES: dict[type, tuple[str, ...]] = {}


def _names(cls: type) -> tuple[str, ...]:
    names = _NAMES.get(cls)
    if names is None:
        names = _NAMES[cls] = tuple(f.name for f in dataclasses.fields(cls))
    return names
