"""The thesis's robots as HD tables (Tables 3.1 and 4.1, Examples 4.1-4.2, Section 6.2).

Each table is the single source of its shipped URDF in ``robots/``: ``kinredund generate-robots``
writes the files from these tables and a test checks that the shipped files equal what it writes.
Angles [rad], lengths [m].
"""

from __future__ import annotations

import numpy as np

from kinredund.kinematics.hd import HDTable

PI = np.pi
#: task kind of each shipped robot (planar position, spatial position, or full pose)
SHIPPED_TASKS = {
    "planar3r": "planar",
    "planar3r_ch6": "planar",
    "puma7": "pose",
    "cybotech_p15": "pose",
}


def planar3r() -> HDTable:
    """Planar 3R of Examples 4.1-4.2: three parallel axes, links of 2 m (Eqs. 4.43-4.44).

    The thesis sets no joint limits; +-2 pi keeps Example 4.2's theta3 ~ pi well inside them.
    """
    return HDTable(
        alpha=np.zeros(3), a=[2.0, 2.0, 2.0], b=np.zeros(3),
        lower=[-2 * PI] * 3, upper=[2 * PI] * 3, name="planar3r",
    )


def planar3r_ch6() -> HDTable:
    """Planar 3R of Chapter 6 (Section 6.2): links 0.5, 0.6 and 0.3 m (the middle value is read from
    a blurred figure, see ``docs/thesis_readings.md``)."""
    return HDTable(
        alpha=np.zeros(3), a=[0.5, 0.6, 0.3], b=np.zeros(3),
        lower=[-2 * PI] * 3, upper=[2 * PI] * 3, name="planar3r_ch6",
    )


PUMA7_NOTES = """\
PUMA-derived 7-axis arm (Table 3.1 with the Section 3.2 dimensions) and a spherical wrist.
Rows (alpha [deg], a [m], b [m]):
  1: ( 90, 0,       2)    axis 1 vertical; b1 = 2 m is the vertical column
  2: (  0, 2,       d)    axes 2-4 parallel and horizontal; d = shoulder offset (0 in Section 3.2)
  3: (  0, sqrt(2), 0)
  4: ( 90, 1,       0)    a4 = 1 m ends at the wrist centre O5; alpha4 turns axis 5 normal to axis 4
  5: (-90, 0,       0)    spherical wrist: axes 5, 6, 7 meet at O5 (a5 = a6 = b6 = 0)
  6: ( 90, 0,       0)
  7: (  0, 0,       0)    point P is the wrist centre; the end-effector frame is frame 8
The wrist rows are our choice (the OCR lost the wrist): a standard roll-pitch-roll wrist, singular
where theta6 = 0 or pi (axes 5 and 7 aligned).
"""


def puma7(shoulder_offset: float = 0.0) -> HDTable:
    """The PUMA-derived 7-axis arm of Chapter 3 (Table 3.1, Section 3.2 dimensions) with a spherical
    wrist; the rows are documented in :data:`PUMA7_NOTES`."""
    deg = PI / 180
    return HDTable(
        alpha=np.array([90, 0, 0, 90, -90, 90, 0]) * deg,
        a=[0.0, 2.0, np.sqrt(2.0), 1.0, 0.0, 0.0, 0.0],
        b=[2.0, shoulder_offset, 0.0, 0.0, 0.0, 0.0, 0.0],
        lower=[-PI] * 7, upper=[PI] * 7, name="puma7", notes=PUMA7_NOTES,
    )


def cybotech_p15() -> HDTable:
    """The CYBOTECH P-15 of Table 4.1 as printed; P at the wrist centre (O6 = O7 = O8).

    Limits of axes 1-4 as read in NOTES.md (Eq. 4.49); the wrist axes get +-2 pi (they may turn
    a full turn per loop in Example 4.3).
    """
    deg = PI / 180
    return HDTable(
        alpha=np.array([90, 180, -90, 90, 90, 90, -90]) * deg,
        a=[0.0, 0.16, 0.2, 0.0, 0.0, 0.0, 0.0],
        b=[0.16, 0.0, 0.0, 0.0, 0.14, 0.0, 0.0],
        lower=[-PI / 2, -PI / 4, -PI / 4, -PI / 3, -2 * PI, -2 * PI, -2 * PI],
        upper=[PI / 2, PI / 4, 3 * PI / 4, PI / 3, 2 * PI, 2 * PI, 2 * PI],
        name="cybotech_p15",
    )


#: a default, well-conditioned configuration of each shipped robot (mid-limits can be singular:
#: the planar arms would be stretched out)
SHIPPED_HOMES = {
    "planar3r": (0.3, 1.0, 1.0),
    "planar3r_ch6": (0.3, 1.0, 1.0),
    "puma7": (0.0, 0.8, -1.2, 0.9, 0.3, 1.2, 0.2),
    "cybotech_p15": (0.0, 0.3, 0.9, 0.3, 0.5, 1.0, 0.3),
}

SHIPPED_TABLES = {
    "planar3r": planar3r,
    "planar3r_ch6": planar3r_ch6,
    "puma7": puma7,
    "cybotech_p15": cybotech_p15,
}


def cybotech_p15_scaled(scale: float, *, last_link: float | None = None, lower=None, upper=None) -> HDTable:
    """Table 4.1 (the CYBOTECH P-15 architecture) with every length times ``scale``: Section 6.3's arm
    (:func:`kinredund.planning.spatial.scaled_p15` says why scale 8), with axes 1-4 given [-pi, pi] and
    the wrist +-2 pi unless ``lower``/``upper`` are given; ``last_link`` replaces b5 [m]."""
    t = cybotech_p15()
    b = scale * np.asarray(t.b, float)
    if last_link is not None:
        b[4] = float(last_link)
    lo = [-PI] * 4 + [-2 * PI] * 3 if lower is None else lower
    hi = [PI] * 4 + [2 * PI] * 3 if upper is None else upper
    tag = "" if last_link is None else f"_b5_{last_link:g}"
    return HDTable(alpha=t.alpha, a=scale * t.a, b=b, lower=lo, upper=hi, name=f"cybotech_p15_x{scale:g}{tag}",
                   notes=f"Table 4.1 (CYBOTECH P-15) with every length times {scale:g} (Section 6.3)")


#: the scale of Table 4.1's lengths adopted for Section 6.3 (:func:`kinredund.planning.spatial.scaled_p15`)
P15_SCALE = 8.0

#: robots built from an HD table alone (no URDF file), by name: (table, default task, note)
TABLE_ROBOTS = {
    "cybotech_p15_x8": (lambda: cybotech_p15_scaled(P15_SCALE), "position",
                        "thesis robot: Section 6.3's P-15, every length x8 (HD table)"),
}
