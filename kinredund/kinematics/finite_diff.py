"""Central finite differences: the one helper that checks every analytic derivative.

Used by the tests (Jacobians, derivative tensors, index gradients and Hessians) and by
``kinredund.indices.check_index`` to check a user's index.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def central_difference(f: Callable[[np.ndarray], np.ndarray], x: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """d f / d x by central differences; the derivative index is the last axis of the result.

    For f: R^n -> R^(shape) the result has shape (shape..., n).
    """
    x = np.asarray(x, dtype=float)
    cols = []
    for k in range(x.shape[0]):
        step = np.zeros_like(x)
        step[k] = eps
        cols.append((np.asarray(f(x + step)) - np.asarray(f(x - step))) / (2.0 * eps))
    return np.stack(cols, axis=-1)
