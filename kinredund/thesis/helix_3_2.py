"""Section 3.2: the wrist centre of the PUMA-derived arm traces a helix (thesis Figs. 3.5-3.6).

Parameters (``docs/thesis_readings.md``, Chapter 3): links b1 = 2 m, a2 = 2 m, a3 = sqrt(2) m,
a4 = 1 m, no shoulder offset; the wrist centre follows

    x = 1.5 cos(beta),   y = 1.5 sin(beta),   z = (3 / pi) beta + 2,   0 <= beta <= pi/2   [m];

theta1 and theta2 in closed form (front branch: theta1 = beta), theta3 and theta4 minimise Eq. (3.30)
subject to Eq. (3.25) with the isotropic references (computed: 94.09, 97.42 deg; printed 94.08, 97.41).
Fig. 3.6 plots the four joint histories against a time axis from 0 to 2 s; the thesis states no
speed, so ``t = 4 beta / pi`` [s] is our reading of that axis.

``reproduce`` returns (and optionally writes) the histories; ``kinredund reproduce 3.2`` calls it.
"""

from __future__ import annotations

import math

import numpy as np

from kinredund.closed_form import ClosedFormIK, conditioning, polynomial_route, solve_redundancy
from kinredund.closed_form.positioning import plane_radius2
from kinredund.errors import PathError, check_count
from kinredund.io import write_json
from kinredund.paths import Helix

#: the Section 3.2 helix x = 1.5 cos(beta), y = 1.5 sin(beta), z = (3/pi) beta + 2 (paths.Helix's defaults)
HELIX = Helix(radius=1.5, pitch=3.0 / math.pi, z0=2.0, rate=1.0)
BETA_END = 0.5 * math.pi
TIME_END = 2.0  # Fig. 3.6's time axis [s] (our reading)


def helix(beta) -> np.ndarray:
    """Wrist-centre positions [m] on the Section 3.2 helix, shape (len(beta), 3)."""
    return np.array([HELIX.sample(b).p for b in np.asarray(beta, dtype=float)])  # rate 1: t = beta


def _polynomial_route(ik: ClosedFormIK, solutions, points) -> dict:
    """Conditioning of the thesis's degree-24 route (Eq. 3.81) vs its degree-12 factor, per sample.

    The route minimises the sin/cos objective Eq. (3.31), so its roots are compared with that
    minimum (found directly); ``theta4_gap_deg`` is how far it lies from the Eq. (3.30) minimum.
    """
    geom, refs = ik.geometry, ik.theta_references
    keys = ("coefficient_spread_24", "coefficient_spread_12", "root_condition_24", "root_condition_12",
            "root_error_24", "root_error_12", "perturbed_error_24", "perturbed_error_12", "spurious_cluster_24")
    out: dict = {k: [] for k in keys}
    out["theta4_gap_deg"] = []
    for sol, p in zip(solutions, points, strict=True):
        rho2 = plane_radius2(geom, p)  # xi^2 + eta^2, Eqs. (3.14)-(3.15)
        sincos = solve_redundancy(geom, rho2, refs, "sincos")
        c = conditioning(polynomial_route(geom, rho2, refs), sincos.theta4, trials=5)
        for k in keys:
            out[k].append(getattr(c, k))
        out["theta4_gap_deg"].append(math.degrees(abs(sincos.theta4 - sol.theta4)))
    out["eps"] = c.eps
    out["t4_power_24"] = c.t4_power_24
    return out


def reproduce(samples: int = 91, json_path=None) -> dict:
    """Solve the positioning problem along the helix (front branch: theta1 = beta) and return the
    joint histories.

    Args:
        samples: number of equally spaced beta values in [0, pi/2] (an integer >= 2).
        json_path: where to write the result as JSON (atomically; non-finite numbers as null), or None.

    Returns:
        A dict with ``beta`` [rad], ``t`` [s], ``wrist_centre`` [m], ``q`` (theta1..theta4 [rad] per
        sample), ``q_deg``, ``objective`` (z of Eq. 3.30 [rad^2]), ``multiplier`` (Eq. 3.40),
        ``position_residual`` [m], ``constraint_residual`` [m^2], ``normality_residual``, the
        references, the maxima of the residuals, and ``polynomial_route``: per sample, the
        conditioning of the degree-24 polynomial of Eq. (3.81) and of its degree-12 factor
        (:class:`~kinredund.closed_form.Conditioning`).

    Raises:
        PathError: samples not an integer >= 2.
    """
    samples = check_count(samples, 2, "samples (points along the helix)", PathError)
    ik = ClosedFormIK()
    beta = np.linspace(0.0, BETA_END, samples)
    points = helix(beta)
    rows = [next(s for s in ik.position_all(p) if s.shoulder == "front") for p in points]
    q = np.array([s.q for s in rows])
    data = {
        "example": "3.2",
        "robot": "puma7",
        "objective_kind": "angle, Eq. (3.30)",
        "branch": "front",
        "references_deg": np.degrees(ik.references).tolist(),
        "references_thesis_deg": [94.08, 97.41],
        "beta": beta.tolist(),
        "t": (beta * TIME_END / BETA_END).tolist(),
        "wrist_centre": points.tolist(),
        "q": q.tolist(),
        "q_deg": np.degrees(q).tolist(),
        "objective": [s.objective for s in rows],
        "multiplier": [s.multiplier for s in rows],
        "position_residual": [s.position_residual for s in rows],
        "constraint_residual": [s.redundancy.constraint_residual for s in rows],
        "normality_residual": [s.redundancy.normality_residual for s in rows],
    }
    data["polynomial_route"] = _polynomial_route(ik, [s.redundancy for s in rows], points)
    data["theta3_ref_deg"], data["theta4_ref_deg"] = data["references_deg"]
    data["max_position_residual"] = max(data["position_residual"])
    data["max_normality_residual"] = max(data["normality_residual"])
    data["max_joint_step_deg"] = float(np.degrees(np.abs(np.diff(q, axis=0))).max())
    if json_path is not None:
        write_json(json_path, data, indent=1)
    return data
