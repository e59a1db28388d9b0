"""The collision-avoidance policy of Section 6.2.1 as performance indices (Eqs. 6.1-6.22, 6.29-6.44).

The policy, for an end point P on the boundary of a convex (elliptic) obstacle:

1. the obstacle is out of reach of link 1 (a condition on the set-up, checked by the planner);
2. link 2 (planar case) or the projected link k2 (spatial case) is tangent to the *largest* ellipse
   concentric with the obstacle: its semi-minor axis b(theta) is maximised (Eqs. 6.7-6.18, 6.30-6.39);
3. the last link lies along the obstacle's normal at P (Eqs. 6.19-6.20, 6.40-6.42), its joint outside.

They are combined as in Eq. (6.21) / (6.44):

    z = 1/2 [ w1 / b(theta)^2 + w2 |L(theta) - l|^2 ]

with L the unit vector of the last link (from its joint towards P) and l = -n the inward normal. The
thesis writes the second term with slopes, (m_l - m)^2 (Eq. 6.20); we use unit vectors instead
(|L - l|^2 = 2 (1 - cos delta), delta the angle between them), because the slope is infinite for a
vertical link and cannot tell the link pointing out of the obstacle from the link pointing into it.
Near alignment both are delta^2 to second order.

The semi-axis b of the concentric ellipse (semi-axes r b and b, r = a/b, Eq. 6.6) tangent to a line
with unit normal n_l through a point E follows from the ellipse's support function:

    b = |n_l . (c - E)| / sqrt(r^2 (n_l . e1)^2 + (n_l . e2)^2)                      (6.16) / (6.37)

which is the root of the vanishing discriminant of Eqs. (6.15)/(6.36) in closed form; the tests check
it against that discriminant. For the planar 3R arm, n_l = (-sin phi, cos phi), phi = theta1 + theta2,
E = l1 (cos theta1, sin theta1), so n_l . (c - E) = y0 cos phi - x0 sin phi + l1 sin theta2. For the
spatial arm the projected link k2 is the line through the base at azimuth theta1 (Eq. 6.29), E = 0.

Units: angles [rad], lengths [m]; z is dimensionless when w1 is in [m^2].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kinredund.errors import TaskError
from kinredund.indices import Index
from kinredund.kinematics.closure import cross_matrix
from kinredund.planning.obstacles import Obstacle
from kinredund.planning.selfmotion import active_joints


def check_weights(weights, what: str = "policy weights") -> tuple[float, float]:
    """(w1, w2) of Eq. (6.21)/(6.44) as floats: two finite numbers >= 0, not both 0.

    Raises:
        TaskError: anything else (``what`` names them in the message).
    """
    try:
        w1, w2 = (float(w) for w in weights)
    except (TypeError, ValueError) as err:
        raise TaskError(f"{what} must be two numbers (w1, w2) >= 0, got {weights!r}") from err
    if not (math.isfinite(w1) and math.isfinite(w2) and w1 >= 0 and w2 >= 0 and w1 + w2 > 0):
        raise TaskError(f"{what} must be finite, >= 0 and not both 0, got {weights!r}")
    return w1, w2


def _inv_b2_terms(obstacle: Obstacle, phi: float):
    """D(phi) = r^2 sin^2(phi - psi) + cos^2(phi - psi) and its first two derivatives."""
    r2 = obstacle.ratio ** 2
    s = phi - obstacle.angle
    D = r2 * math.sin(s) ** 2 + math.cos(s) ** 2
    D1 = (r2 - 1.0) * math.sin(2.0 * s)
    D2 = 2.0 * (r2 - 1.0) * math.cos(2.0 * s)
    return D, D1, D2


def _quotient(D, Dk, Dkl, d, dk, dkl):
    """f = D / d^2 with its gradient and Hessian from those of D and d (1/b^2, Eqs. 6.16-6.18)."""
    f = D / d**2
    g = Dk / d**2 - 2.0 * D * dk / d**3
    H = (Dkl / d**2 - 2.0 * (np.outer(Dk, dk) + np.outer(dk, Dk)) / d**3 - 2.0 * D * dkl / d**3
         + 6.0 * D * np.outer(dk, dk) / d**4)
    return f, g, H


@dataclass(frozen=True)
class PlanarPolicy(Index):
    """Eq. (6.21) for a planar 3R arm at one end-point target on the obstacle's boundary.

    z = 1/2 [w1 / b(theta1, theta2)^2 + w2 * 2 (1 - cos(theta1 + theta2 + theta3 - nu))], nu the
    direction of the inward normal -n at the target (the last link points from its joint to P along
    -n: its joint lies outside the obstacle).

    Args:
        obstacle: the elliptic obstacle.
        l1: the length of link 1 [m].
        normal: the outward unit normal n of the obstacle at the target, (2,) or (3,).
        weights: (w1 [m^2], w2).
        theta0: joint offsets of the HD table (theta_i = q_i + theta0_i); default zeros.
    """

    obstacle: Obstacle
    l1: float
    normal: np.ndarray
    weights: tuple = (1e-3, 1.0)
    theta0: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = np.asarray(self.normal, float)[:2]
        if not (np.all(np.isfinite(n)) and np.linalg.norm(n) > 0):
            raise TaskError(f"the target normal must be a non-zero vector, got {self.normal!r}")
        object.__setattr__(self, "normal", n / np.linalg.norm(n))
        object.__setattr__(self, "weights", check_weights(self.weights))
        object.__setattr__(self, "theta0", np.zeros(3) if self.theta0 is None else np.asarray(self.theta0, float))

    def evaluate(self, theta, t=0.0):
        th = np.asarray(theta, float) + self.theta0
        w1, w2 = self.weights
        x0, y0 = self.obstacle.center[0], self.obstacle.center[1]
        phi = th[0] + th[1]
        cp, sp = math.cos(phi), math.sin(phi)
        # d = n_l . (c - E) and its derivatives (Eqs. 6.7-6.15 in closed form)
        d = y0 * cp - x0 * sp + self.l1 * math.sin(th[1])
        dphi = -y0 * sp - x0 * cp
        dphiphi = -y0 * cp + x0 * sp
        dk = np.array([dphi, dphi + self.l1 * math.cos(th[1]), 0.0])
        dkl = np.zeros((3, 3))
        dkl[:2, :2] = dphiphi
        dkl[1, 1] -= self.l1 * math.sin(th[1])
        D, D1, D2 = _inv_b2_terms(self.obstacle, phi)
        ph = np.array([1.0, 1.0, 0.0])
        if abs(d) < 1e-300:
            d = 1e-300
        f1, g1, H1 = _quotient(D, D1 * ph, D2 * np.outer(ph, ph), d, dk, dkl)  # 1/b^2, Eq. (6.16)
        nu = math.atan2(-self.normal[1], -self.normal[0])
        e = th.sum() - nu
        f2 = 2.0 * (1.0 - math.cos(e))  # |L - l|^2, the normal-alignment term (Eq. 6.20)
        g2 = 2.0 * math.sin(e) * np.ones(3)
        H2 = 2.0 * math.cos(e) * np.ones((3, 3))
        z = 0.5 * (w1 * f1 + w2 * f2)  # Eq. (6.21)
        return z, 0.5 * (w1 * g1 + w2 * g2), 0.5 * (w1 * H1 + w2 * H2)


def link_direction_derivatives(axes: np.ndarray, L: np.ndarray, moving: int):
    """d L / d theta_j = e_j x L and d2 L / d theta_i d theta_j = e_i x (e_j x L) (i <= j).

    Args:
        axes: unit joint axes e_j in world coordinates, shape (n, 3) (rows).
        L: the link's unit vector (3,).
        moving: the joints 0..moving-1 move the link; the others leave it fixed.

    Returns:
        (dL (3, n), d2L (3, n, n)).
    """
    n = axes.shape[0]
    dL = np.zeros((3, n))
    d2L = np.zeros((3, n, n))
    E = axes[:moving]
    dL[:, :moving] = -cross_matrix(L) @ E.T  # e_j x L = -L x e_j
    # e_i x (e_j x L) = e_j (e_i . L) - L (e_i . e_j), for i <= j (e_j turns with joint i for i < j)
    C = E.T[:, None, :] * (E @ L)[None, :, None] - L[:, None, None] * (E @ E.T)[None]  # C[:, i, j]
    upper = np.triu(np.ones((moving, moving), bool))
    d2L[:, :moving, :moving] = np.where(upper, C, C.transpose(0, 2, 1))
    return dL, d2L


@dataclass(frozen=True)
class SpatialPolicy(Index):
    """Eq. (6.44) for an arm of the CYBOTECH P-15 architecture at one wrist-centre target.

    U = 1/2 [w1 / b(theta1)^2 + w2 |L(theta) - l|^2 + w_wrist sum_{i > last} (theta_i - ref_i)^2]:

    - b(theta1), Eq. (6.37): the projected link k2 (links 2-3) is the line through the base at azimuth
      theta1 (Eq. 6.29);
    - L(theta): the unit vector of the last positioning link (joint origin ``link[0]`` to ``link[1]``),
      the direction cosines of Eqs. (6.40)-(6.42) computed from the model (see
      :func:`kinredund.planning.spatial.link4_direction_thesis` for the thesis's closed form);
    - l = -n, n the obstacle's outward unit normal at the target;
    - the wrist joints after the positioning links do not move P; ``w_wrist`` keeps them at ``wrist_ref``.

    Args:
        robot: the arm (its kinematics layer gives the joint origins and axes).
        obstacle: the obstacle whose ellipse is projected.
        normal: the outward unit normal at the target (3,).
        link: the indices (i, j) in ``robot.kinematics.joint_origins`` of the last link's ends.
        weights: (w1 [m^2], w2).
        w_wrist: weight of the wrist joints' deviation.
        wrist_ref: their reference values [rad], one per wrist joint (default zeros).
    """

    robot: object
    obstacle: Obstacle
    normal: np.ndarray
    link: tuple = (4, 5)
    weights: tuple = (1e-3, 1.0)
    w_wrist: float = 1e-2
    wrist_ref: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = np.asarray(self.normal, float)
        if n.shape != (3,) or not (np.all(np.isfinite(n)) and np.linalg.norm(n) > 0):
            raise TaskError(f"the target normal must be a non-zero 3-vector, got {self.normal!r}")
        object.__setattr__(self, "normal", n / np.linalg.norm(n))
        object.__setattr__(self, "weights", check_weights(self.weights))
        nq = self.robot.nq
        i, j = self.link
        if not (0 <= i < j <= nq):
            raise TaskError(f"link must be two joint-origin indices 0 <= i < j <= {nq}, got {self.link!r}")
        wrist = np.setdiff1d(np.arange(nq), active_joints(self.robot))  # the joints that do not move P
        object.__setattr__(self, "_wrist", wrist)
        ref = np.zeros(wrist.size) if self.wrist_ref is None else np.asarray(self.wrist_ref, float)
        if ref.shape != (wrist.size,):
            raise TaskError(f"wrist_ref must have {wrist.size} values (joints {(wrist + 1).tolist()}), got {ref.shape}")
        object.__setattr__(self, "wrist_ref", ref)

    @property
    def wrist_joints(self) -> np.ndarray:
        """Indices of the joints that do not move P (the wrist), kept at ``wrist_ref``."""
        return self._wrist

    def direction(self, theta) -> np.ndarray:
        """L(theta): the unit vector of the last positioning link (Eqs. 6.40-6.42 from the model)."""
        return self._direction(self.robot.kinematics.joint_origins(np.asarray(theta, float)))

    def _direction(self, origins: np.ndarray) -> np.ndarray:
        v = origins[self.link[1]] - origins[self.link[0]]
        return v / np.linalg.norm(v)

    def evaluate(self, theta, t=0.0):
        theta = np.asarray(theta, float)
        n = theta.shape[0]
        w1, w2 = self.weights
        # 1/b^2 as a function of theta1 alone (Eqs. 6.37-6.39)
        phi = theta[0]
        x0, y0 = self.obstacle.center[0], self.obstacle.center[1]
        d = y0 * math.cos(phi) - x0 * math.sin(phi)
        if abs(d) < 1e-300:
            d = 1e-300
        dd = -y0 * math.sin(phi) - x0 * math.cos(phi)
        ddd = -d
        D, D1, D2 = _inv_b2_terms(self.obstacle, phi)
        f1, g1, H1 = _quotient(D, np.array([D1]), np.array([[D2]]), d, np.array([dd]), np.array([[ddd]]))
        g = np.zeros(n)
        H = np.zeros((n, n))
        g[0] += 0.5 * w1 * g1[0]
        H[0, 0] += 0.5 * w1 * H1[0, 0]
        # |L - l|^2 = 2 (1 - L . l), l = -n (Eq. 6.44)
        K, origins = self.robot.kinematics.jacobian_and_origins(theta)
        axes = K[:3].T
        L = self._direction(origins)
        dL, d2L = link_direction_derivatives(axes, L, self.link[0] + 1)
        lvec = -self.normal
        f2 = 2.0 * (1.0 - float(L @ lvec))
        g += 0.5 * w2 * (-2.0 * lvec @ dL)
        H += 0.5 * w2 * (-2.0 * np.einsum("a,aij->ij", lvec, d2L))
        # the wrist joints (they do not move P)
        wj = self.wrist_joints
        dev = theta[wj] - self.wrist_ref
        g[wj] += self.w_wrist * dev
        H[wj, wj] += self.w_wrist
        z = 0.5 * (w1 * f1 + w2 * f2) + 0.5 * self.w_wrist * float(dev @ dev)  # Eq. (6.44)
        return z, g, 0.5 * (H + H.T)
