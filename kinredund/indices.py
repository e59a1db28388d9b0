"""Performance indices z = 1/2 f^T W f of Eq. (4.2), with gradients and Hessians.

An index maps the joint vector theta (and, for time-varying indices, the time t) to

    z = 1/2 f(theta)^T W f(theta),     grad z = F^T W f,     Hess z = F^T W F + sum_j (W f)_j Hess f_j

with F = df/dtheta. The family here covers the thesis's indices:

- :class:`JointDeviation`: f = theta - theta_ref, Eqs. (4.45), (4.46) and (3.30) (optionally on a
  subset of joints, with weights).
- :func:`mid_range`: f = theta_i - mid_i over chosen joints, Eq. (4.49).
- :class:`TimeVaryingReference`: f = theta - theta*(t), Eq. (6.25), with theta*(t) and its rate given.
- :class:`CustomIndex`: user-defined z, grad z, Hess z; :func:`check_index` compares them with finite
  differences.

Units: theta [rad or m], z [rad^2].
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from kinredund.errors import KinredundError, TaskError, check_array
from kinredund.kinematics.finite_diff import central_difference


class Index:
    """Base class: z(theta, t), its gradient and Hessian. Subclasses implement :meth:`evaluate`."""

    #: True when the index depends on time (then :meth:`time_derivative_of_gradient` is used)
    time_varying: bool = False
    #: True when nothing about the index can change after it is made (frozen, with read-only arrays of its own):
    #: a tracking record may then compute grad z from it when first read rather than at the run's end (a subclass
    #: of such an index that adds state it can change sets it back to False)
    fixed = False

    def evaluate(self, theta: np.ndarray, t: float = 0.0) -> tuple[float, np.ndarray, np.ndarray]:
        """(z, grad z, Hess z) at theta and time t."""
        raise NotImplementedError

    def value(self, theta: np.ndarray, t: float = 0.0) -> float:
        """z alone."""
        return self.evaluate(theta, t)[0]

    def gradient(self, theta: np.ndarray, t: float = 0.0) -> np.ndarray:
        """grad z alone."""
        return self.evaluate(theta, t)[1]

    def hessian(self, theta: np.ndarray, t: float = 0.0) -> np.ndarray:
        """Hess z alone."""
        return self.evaluate(theta, t)[2]

    def gradients_many(self, thetas: np.ndarray, times: np.ndarray) -> np.ndarray:
        """grad z at each row of ``thetas`` (N, n) and time of ``times`` (N,): (N, n), :meth:`evaluate`'s
        gradient row by row (subclasses vectorise it where they can)."""
        return np.array([self.evaluate(q, float(t))[1] for q, t in zip(thetas, times, strict=True)])

    def time_derivative_of_gradient(self, theta: np.ndarray, t: float = 0.0) -> np.ndarray:
        """d(grad z)/dt at fixed theta (zero for time-invariant indices); Eq. (6.27)."""
        return np.zeros_like(theta)


@dataclass(frozen=True)
class JointDeviation(Index):
    """z = 1/2 sum_i w_i (theta_i - ref_i)^2 over the selected joints (Eqs. 4.45, 4.46, 3.30).

    Args:
        reference: theta_ref, shape (n,) [rad or m].
        weights: w_i >= 0, shape (n,); a zero weight leaves that joint out. Default: all ones.
    """

    reference: np.ndarray
    weights: np.ndarray | None = None
    fixed = True  # (frozen; its reference and weights are read-only copies: Index.fixed)

    def __post_init__(self) -> None:
        # copies, read-only: the index (and every record made with it) must not change when the caller
        # reuses its array (e.g. q0 as the reference, then warm-starting from it in place)
        ref = np.array(check_array(self.reference, (None,), "index reference"))
        w = np.ones_like(ref) if self.weights is None else np.array(check_array(self.weights, ref.shape,
                                                                                "index weights"))
        if np.any(w < 0):
            raise TaskError(f"index weights must be {ref.shape[0]} finite values >= 0, got {self.weights!r}")
        ref.flags.writeable = w.flags.writeable = False
        object.__setattr__(self, "reference", ref)
        object.__setattr__(self, "weights", w)
        object.__setattr__(self, "_hess", np.diag(w))

    def evaluate(self, theta, t=0.0):
        f = theta - self.reference
        wf = self.weights * f
        return 0.5 * float(f @ wf), wf, self._hess  # Eq. (4.45)

    def gradients_many(self, thetas, times):
        return self.weights * (thetas - self.reference)  # Eq. (4.45)'s gradient, row by row


def minimum_norm(n: int) -> JointDeviation:
    """z = 1/2 sum theta_i^2, Eq. (4.45) of Example 4.1."""
    return JointDeviation(np.zeros(n))


def mid_range(lower, upper, joints=None) -> JointDeviation:
    """z = 1/2 sum_{i in joints} (theta_i - mid_i)^2 with mid = (lower + upper)/2, Eq. (4.49)."""
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    n = lower.shape[0]
    w = np.zeros(n)
    w[list(range(n)) if joints is None else list(joints)] = 1.0
    mid = np.where(np.isfinite(lower + upper), 0.5 * (lower + upper), 0.0)
    return JointDeviation(mid, w)


@dataclass(frozen=True)
class TimeVaryingReference(Index):
    """h = 1/2 sum_i w_i (theta_i - theta*_i(t))^2, Eqs. (6.23)-(6.25).

    Args:
        reference: t -> theta*(t), shape (n,).
        rate: t -> dtheta*/dt, shape (n,) (the spline's rate, used as feed-forward, Eq. 6.27).
        weights: w_i >= 0; default ones.
    """

    reference: Callable[[float], np.ndarray]
    rate: Callable[[float], np.ndarray]
    weights: np.ndarray | None = None
    time_varying: bool = True

    def evaluate(self, theta, t=0.0):
        w = np.ones_like(theta) if self.weights is None else np.asarray(self.weights, float)
        f = theta - np.asarray(self.reference(t), float)
        return 0.5 * float(f @ (w * f)), w * f, np.diag(w)  # Eq. (6.25)

    def time_derivative_of_gradient(self, theta, t=0.0):
        w = np.ones_like(theta) if self.weights is None else np.asarray(self.weights, float)
        return -w * np.asarray(self.rate(t), float)


@dataclass(frozen=True)
class CustomIndex(Index):
    """A user-defined index from callables z(theta), grad z(theta) and Hess z(theta)."""

    z: Callable[[np.ndarray], float]
    grad: Callable[[np.ndarray], np.ndarray]
    hess: Callable[[np.ndarray], np.ndarray]

    def evaluate(self, theta, t=0.0):
        return float(self.z(theta)), np.asarray(self.grad(theta), float), np.asarray(self.hess(theta), float)


class IndexCheckError(KinredundError, ValueError):
    """A user index whose gradient or Hessian disagrees with finite differences."""


def check_index(index: Index, theta, eps: float = 1e-6, tol: float = 1e-6) -> tuple[float, float]:
    """Compare an index's gradient and Hessian with central differences at theta.

    Returns:
        (gradient error, Hessian error), max-abs, relative to max(1, |value|).

    Raises:
        IndexCheckError: an error exceeds ``tol``; the message names which one and where.
    """
    theta = np.asarray(theta, dtype=float)
    _, g, H = index.evaluate(theta)
    g_fd = central_difference(lambda x: np.array(index.value(x)), theta, eps)
    H_fd = central_difference(index.gradient, theta, eps)
    eg = float(np.abs(g - g_fd).max() / max(1.0, np.abs(g_fd).max()))
    eh = float(np.abs(H - H_fd).max() / max(1.0, np.abs(H_fd).max()))
    if eg > tol:
        k = int(np.argmax(np.abs(g - g_fd)))
        raise IndexCheckError(f"gradient disagrees with finite differences by {eg:.3g} (entry {k})")
    if eh > tol:
        i, j = np.unravel_index(int(np.argmax(np.abs(H - H_fd))), H.shape)
        raise IndexCheckError(f"Hessian disagrees with finite differences by {eh:.3g} (entry {i}, {j})")
    return eg, eh
