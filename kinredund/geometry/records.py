"""The records a scene's queries return: distances with witness points, and distance rows for constraints."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kinredund.errors import ChoiceError


@dataclass(frozen=True)
class Distances:
    """Signed distances of a scene's checked pairs at one configuration.

    Attributes:
        q: the configuration [rad or m], shape (n,).
        pairs: the pairs computed exactly, (first object, second object), in the scene's pair order.
        distance: their signed distances [m], shape (k,): > 0 apart, < 0 penetrating (convex shapes; an exact
            mesh reports 0 or a small negative value inside).
        point_a, point_b: the witness points on the first and second object, world frame [m], shape (k, 3).
        normal: unit normals from the first object to the second, world frame, shape (k, 3); moving b along
            the normal increases the distance.
        influence: the broadphase distance [m], or None when every checked pair was computed.
        checked: how many pairs the scene checks; ``checked - len(pairs)`` were farther than ``influence``
            (their bounding spheres were), so their distance exceeds it.
    """

    q: np.ndarray
    pairs: tuple[tuple[str, str], ...]
    distance: np.ndarray
    point_a: np.ndarray
    point_b: np.ndarray
    normal: np.ndarray
    influence: float | None
    checked: int

    def __len__(self) -> int:
        return len(self.pairs)

    def index(self, a: str, b: str) -> int:
        """The row of pair (a, b) (either order), or ChoiceError listing the computed pairs."""
        for k, p in enumerate(self.pairs):
            if p == (a, b) or p == (b, a):
                return k
        raise ChoiceError("pair (not checked, or beyond the influence distance)", (a, b),
                          [f"({x}, {y})" for x, y in self.pairs])

    def __getitem__(self, pair: tuple[str, str]) -> float:
        """The signed distance [m] of pair (a, b), either order."""
        return float(self.distance[self.index(*pair)])

    def as_dict(self) -> dict[tuple[str, str], float]:
        """(a, b) -> signed distance [m]."""
        return {p: float(d) for p, d in zip(self.pairs, self.distance, strict=True)}

    @property
    def min_distance(self) -> float:
        """The smallest signed distance [m] (inf when no pair was computed)."""
        return float(self.distance.min()) if len(self.pairs) else float("inf")

    @property
    def closest(self) -> tuple[str, str] | None:
        """The pair of :attr:`min_distance` (None when no pair was computed)."""
        return self.pairs[int(np.argmin(self.distance))] if len(self.pairs) else None


@dataclass(frozen=True)
class DistanceRows:
    """Distances and their first-order change with q: d_dot = G q_dot, for inequality constraints.

    ``d, G = scene.distance_rows(q)`` unpacks the two arrays.

    Attributes:
        pairs: the pairs within the influence distance (all checked pairs without one).
        d: their signed distances [m], shape (k,).
        G: rows n^T (J_b(p_b) - J_a(p_a)) [m/rad], shape (k, n) (``kinredund.geometry.engine``).
        influence: the broadphase distance [m] or None.
        index: the pairs' positions in ``scene.pairs`` (k,) (stable while the scene is unchanged).
        normal, point_a, point_b: the unit normals (first to second object) and witness points [m], world
            frame, shape (k, 3) each: what ``scene.distance_curvature`` takes.
    """

    pairs: tuple[tuple[str, str], ...]
    d: np.ndarray
    G: np.ndarray
    influence: float | None
    index: np.ndarray | None = None
    normal: np.ndarray | None = None
    point_a: np.ndarray | None = None
    point_b: np.ndarray | None = None

    def __iter__(self):
        return iter((self.d, self.G))
