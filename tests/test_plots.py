"""Figures: the drawn curves carry the trajectory's numbers, files are written atomically, and
missing data gives a clear error. Test data are synthetic trajectories built from forward kinematics.
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np
import pytest
from conftest import robot
from matplotlib.colors import to_rgb

from kinredund import ChoiceError, JointVectorError, KinredundError, PathError
from kinredund.kinematics.angles import joint_drift
from kinredund.trajectory import Trajectory
from kinredund.ui.plots import (
    LOG_FLOOR,
    errors_figure,
    joint_histories_figure,
    loop_drift_figure,
    loop_drifts,
    m_eigenvalues_figure,
    plot_errors,
    plot_joint_histories,
    plot_loop_drift,
    plot_m_eigenvalues,
    save_figure,
)

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def synthetic(period: float = 2.0, loops: int = 3, steps_per_loop: int = 100, drift: float = 0.0,
              seed: int = 0, scheme: str = "augmented", mode: str = "default") -> Trajectory:
    """A planar 3R run: sinusoidal joints of period ``period`` that creep by ``drift`` [rad] per loop.

    M's eigenvalues are made up so that the smallest, also the null-space one, changes sign: the
    steps where it is negative are labelled ``lu`` as the scheme would (Theorem 2).
    """
    r = robot("planar3r")
    rng = np.random.default_rng(seed)
    n = loops * steps_per_loop + 1
    t = np.linspace(0.0, loops * period, n)
    w = 2.0 * np.pi * t / period
    q = rng.uniform(-1.0, 1.0, 3) + 0.5 * np.sin(w[:, None] + rng.uniform(0, 2 * np.pi, 3))
    q = q + drift * (t / period)[:, None]
    p = np.array([r.fk(qi)[:3, 3] for qi in q])
    p_desired = p + 1e-6 * rng.normal(size=p.shape)
    null = 0.4 * np.sin(w) - 0.1
    m_eigs = np.column_stack([null, 1.0 + 0.2 * np.cos(w), 3.0 + 0.1 * np.sin(2 * w)])
    solver = tuple("lu" if v < 0 else "qp" for v in null)
    # the drift at the end of each loop, as kinredund.tracking.track records it
    drift_per_loop = [joint_drift(q[0], q[k * steps_per_loop], True) for k in range(1, loops + 1)]
    return Trajectory(
        robot="planar3r", task="planar", t=t, q=q, p=p, p_desired=p_desired, scheme=scheme, mode=mode,
        solver=solver, m_eigs=m_eigs, m_null_eigs=null[:, None],
        position_error=np.linalg.norm(p - p_desired, axis=1),
        trace_error=np.abs(1e-4 * np.sin(w)), vect_error=np.abs(1e-3 * np.cos(w)),
        loop_drift=np.array(drift_per_loop), loop_period=period,
    )


def read_png(path) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as img:
        return np.asarray(img.convert("RGB"))


def assert_png(path, min_bytes: int = 10_000) -> None:
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE
    assert len(data) > min_bytes
    assert [p.name for p in path.parent.iterdir() if p.name.startswith(".")] == []  # no temporary file


def test_joint_histories_draw_each_joint_in_degrees(tmp_path):
    traj = synthetic()
    fig = joint_histories_figure(traj)
    (ax,) = fig.axes
    lines = ax.get_lines()
    assert len(lines) == 3
    for j, line in enumerate(lines):
        np.testing.assert_allclose(line.get_xdata(), traj.t)
        np.testing.assert_allclose(line.get_ydata(), np.degrees(traj.q[:, j]))
    assert "deg" in ax.get_ylabel() and "[s]" in ax.get_xlabel()
    out = plot_joint_histories([traj, synthetic(seed=1)], tmp_path / "joints.png", joints=[0, 2])
    assert_png(out)
    assert read_png(out).shape[0] > read_png(plot_joint_histories(traj, tmp_path / "one.png")).shape[0]
    with pytest.raises(KinredundError, match=r"out of range.*0\.\.2"):
        joint_histories_figure(traj, joints=[3])


def test_prismatic_joints_go_on_a_millimetre_axis():
    fig = joint_histories_figure(synthetic(), revolute=[True, False, True])
    assert len(fig.axes) == 2
    assert "mm" in fig.axes[1].get_ylabel()
    np.testing.assert_allclose(fig.axes[1].get_lines()[0].get_ydata(), 1e3 * synthetic().q[:, 1])


def test_errors_on_log_scale_with_zeros_floored(tmp_path):
    traj = synthetic()
    exact = dataclasses.replace(traj, position_error=np.zeros(len(traj.t)), p_desired=traj.p.copy(), scheme="velocity")
    fig = errors_figure([traj, exact])
    top, bottom = fig.axes
    assert top.get_yscale() == "log" and bottom.get_yscale() == "log"
    first, second = top.get_lines()
    np.testing.assert_allclose(first.get_ydata(), np.maximum(traj.position_error, LOG_FLOOR))
    np.testing.assert_allclose(second.get_ydata(), LOG_FLOOR)  # exact zeros, drawn at the floor
    assert [t.get_text() for t in top.get_legend().get_texts()] == ["augmented (default)", "velocity (default)"]
    assert len(bottom.get_lines()) == 4  # trace and vect errors of both
    no_orientation = dataclasses.replace(traj, trace_error=None, vect_error=None)
    assert len(errors_figure(no_orientation).axes) == 1
    assert_png(plot_errors(traj, tmp_path / "errors.png"))
    with pytest.raises(KinredundError, match="velocity .* has no position_error"):  # every tracking run records it
        errors_figure([traj, dataclasses.replace(exact, position_error=None)])


def test_m_eigenvalues_shade_the_lu_steps(tmp_path):
    traj = synthetic()
    fig = m_eigenvalues_figure(traj)
    top, bottom = fig.axes
    for j, line in enumerate(top.get_lines()[:3]):
        np.testing.assert_allclose(line.get_ydata(), traj.m_eigs[:, j])
    lu = np.array([s == "lu" for s in traj.solver])
    runs = np.count_nonzero(np.diff(np.concatenate([[0], lu.astype(int)])) == 1)
    spans = [p for p in top.patches if p.get_facecolor()[:3] == pytest.approx(to_rgb("tab:red"))]
    assert len(spans) == runs >= 3  # the null-space eigenvalue is negative once per loop (and at t = 0)
    for span in spans:  # each shaded stretch covers negative null-space eigenvalues only
        x0, x1 = span.get_x(), span.get_x() + span.get_width()
        inside = (traj.t > x0 + 1e-9) & (traj.t < x1 - 1e-9)
        assert np.all(traj.m_null_eigs[inside, 0] < 0)

    # M indefinite but positive definite on null(J): the QP on M + rho J^T J, shaded apart from LU
    aug = dataclasses.replace(traj, solver=tuple("qp_aug" if s == "lu" else s for s in traj.solver))
    top = m_eigenvalues_figure(aug).axes[0]
    colors = [p.get_facecolor()[:3] for p in top.patches]
    assert sum(c == pytest.approx(to_rgb("gold")) for c in colors) == runs
    assert not any(c == pytest.approx(to_rgb("tab:red")) for c in colors)

    shaded = plot_m_eigenvalues(traj, tmp_path / "m.png")
    plain = plot_m_eigenvalues(dataclasses.replace(traj, solver=("qp",) * len(traj.t)), tmp_path / "m_qp.png")
    assert_png(shaded)

    def reddish(img):
        r, g, b = (img[..., k].astype(int) for k in range(3))
        return np.count_nonzero((r > 200) & (r - g > 20) & (r - b > 20) & (g > 150))

    assert reddish(read_png(shaded)) > 20 * max(reddish(read_png(plain)), 1)


def test_m_eigenvalues_need_m_eigs(tmp_path):
    traj = dataclasses.replace(synthetic(), m_eigs=None, m_null_eigs=None, scheme="pseudoinverse")
    with pytest.raises(KinredundError, match="no m_eigs.*augmented"):
        plot_m_eigenvalues(traj, tmp_path / "m.png")
    assert list(tmp_path.iterdir()) == []


def test_loop_drift_per_scheme(tmp_path):
    period, per_loop = 2.0, 1e-3
    cyclic = synthetic(period=period, loops=4, drift=0.0, scheme="augmented")
    drifting = synthetic(period=period, loops=4, drift=per_loop, scheme="pseudoinverse", mode="thesis")
    np.testing.assert_allclose(loop_drifts(drifting), per_loop * np.arange(1, 5), rtol=1e-9)
    assert np.max(loop_drifts(cyclic)) < 1e-12
    recorded = dataclasses.replace(cyclic, loop_drift=np.array([1e-14, 2e-14]))
    np.testing.assert_array_equal(loop_drifts(recorded), [1e-14, 2e-14])  # the record, not recomputed from q

    fig = loop_drift_figure([cyclic, drifting, recorded])
    (ax,) = fig.axes
    assert ax.get_yscale() == "log"
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels == ["augmented (default)", "pseudoinverse (thesis)", "augmented (default)"]
    np.testing.assert_allclose(ax.get_lines()[1].get_ydata(), per_loop * np.arange(1, 5), rtol=1e-9)
    np.testing.assert_array_equal(ax.get_lines()[2].get_xdata(), [1, 2])
    np.testing.assert_array_equal(ax.get_lines()[2].get_ydata(), [1e-14, 2e-14])
    assert_png(plot_loop_drift([cyclic, drifting], tmp_path / "drift.png"))

    open_path = dataclasses.replace(cyclic, loop_drift=None, loop_period=None)  # as track records an open path
    with pytest.raises(KinredundError, match="no loop_drift: it is not a closed path"):
        plot_loop_drift(open_path, tmp_path / "nope.png")
    with pytest.raises(KinredundError, match="no loop_drift"):
        loop_drifts(open_path)
    assert not (tmp_path / "nope.png").exists()


def test_writes_are_atomic(tmp_path, monkeypatch):
    traj = synthetic()
    target = tmp_path / "joints.png"
    target.write_bytes(b"old figure")
    fig = joint_histories_figure(traj)

    def broken(self, fh, **kwargs):
        fh.write(b"half a PNG")
        raise RuntimeError("disk full")

    monkeypatch.setattr(type(fig), "savefig", broken)
    with pytest.raises(RuntimeError, match="disk full"):
        save_figure(fig, target)
    assert target.read_bytes() == b"old figure"  # the old file is intact
    assert sorted(p.name for p in tmp_path.iterdir()) == ["joints.png"]  # and no temporary file is left
    monkeypatch.undo()
    out = save_figure(fig, target)
    assert out == target and target.read_bytes()[:8] == PNG_SIGNATURE
    umask = os.umask(0)
    os.umask(umask)
    assert oct(target.stat().st_mode & 0o777) == oct(0o666 & ~umask)  # what open() would have given


def test_formats_and_bad_input(tmp_path):
    traj = synthetic(loops=1)
    svg = plot_errors(traj, tmp_path / "e.svg")
    assert svg.read_text().lstrip().startswith("<?xml")
    assert plot_errors(traj, tmp_path / "e.pdf").read_bytes()[:5] == b"%PDF-"
    with pytest.raises(ChoiceError, match="png, pdf, svg"):
        plot_errors(traj, tmp_path / "e.jpg")
    with pytest.raises(KinredundError, match="no trajectory"):
        plot_errors([], tmp_path / "e.png")
    with pytest.raises(KinredundError, match="not a kinredund Trajectory"):
        plot_loop_drift([traj, "x"], tmp_path / "e.png")
    bad = dataclasses.replace(traj, m_eigs=traj.m_eigs[:-1])
    with pytest.raises(KinredundError, match=r"m_eigs .*must have shape \(101, n\).*got \(100, 3\)"):
        m_eigenvalues_figure(bad)
    with pytest.raises(KinredundError, match="one kinredund Trajectory, got a list"):
        m_eigenvalues_figure([traj])


def test_every_figure_checks_the_record():
    """The plots read records through Trajectory.checked: shapes, finite values, increasing times."""
    traj = synthetic(loops=1)
    t = traj.t.copy()
    t[5] = t[4]
    q = traj.q.copy()
    q[3, 1] = np.nan
    figures = (joint_histories_figure, errors_figure, m_eigenvalues_figure, loop_drift_figure)
    for figure in figures:
        with pytest.raises(PathError, match=r"increase strictly; t\[5\]"):
            figure(dataclasses.replace(traj, t=t))
        with pytest.raises(JointVectorError, match="trajectory q has non-finite"):
            figure(dataclasses.replace(traj, q=q))
        with pytest.raises(KinredundError, match="solver must be empty or 101 labels"):
            figure(dataclasses.replace(traj, solver=traj.solver[:-1]))


# -- Chapter 6 (kinredund.ui.plan_plots) ---------------------------------------------------------------
def _plan(still_joint: bool = True):
    """A made-up plan of the planar 3R: joint 3 held still (when asked), a spline 1e-3 rad off the
    tracked joints, and two links' clearance."""
    from types import SimpleNamespace

    tr = synthetic(loops=1)
    q = tr.q.copy()
    if still_joint:
        q[:, 2] = 0.25
    tr = dataclasses.replace(tr, q=q)
    clearance = SimpleNamespace(t=tr.t, clearance=np.column_stack([0.3 + 0.1 * np.sin(tr.t), 0.05 + 0 * tr.t]),
                                names=("link 1", "link 2"))
    return SimpleNamespace(trajectory=tr, q_spline=q + 1e-3, clearance=clearance, ok=True, reason="")


def test_plan_figure_draws_moving_joints_with_dashed_splines_and_names_the_still_ones():
    from kinredund.ui.plan_plots import plan_figure

    result = _plan()
    fig = plan_figure("6.2", result, {}, robot_name="planar3r")
    joints, clear = fig.axes[:2]
    solid = [ln for ln in joints.get_lines() if ln.get_linestyle() == "-" and len(ln.get_xdata())]
    dashed = [ln for ln in joints.get_lines() if ln.get_linestyle() == "--" and len(ln.get_xdata())]
    assert len(solid) == len(dashed) == 2  # theta1, theta2; theta3 is still and not drawn
    np.testing.assert_allclose(dashed[0].get_ydata(), np.degrees(result.q_spline[:, 0]))
    labels = [t.get_text() for t in joints.get_legend().get_texts()]
    assert any("spline" in s for s in labels) and any("not drawn" in s and "theta_{3}" in s for s in labels)
    assert joints.get_legend().get_bbox_to_anchor().x0 > joints.get_window_extent().x1 - 1  # off the data
    assert joints.get_ylabel() == "joint angle [deg]" and clear.get_ylabel() == "clearance to the obstacle [m]"
    assert clear.get_xlabel() == "time [s]"


def test_snapshots_name_their_views_and_label_the_axes(tmp_path):
    from kinredund.planning.obstacles import EllipseObstacle
    from kinredund.ui.plan_plots import snapshot_figure

    obstacle = EllipseObstacle(center=(3.0, 3.0), a=0.8, b=0.4, angle=0.3)
    fig = snapshot_figure(_plan(still_joint=False), robot("planar3r"), obstacle, count=4)
    (view,) = [ax for ax in fig.axes if ax.get_title()]
    assert view.get_title() == "top view (x-y plane)"
    assert (view.get_xlabel(), view.get_ylabel()) == ("x [m]", "y [m]")
    arms = [ln for ln in view.get_lines() if ln.get_marker() == "o"]
    assert len(arms) == 4  # the arm at four times
    r = robot("planar3r")
    tr = _plan(still_joint=False).trajectory
    np.testing.assert_allclose(arms[0].get_xdata(), r.kinematics.joint_origins(tr.q[0])[:, 0])
    out = snapshot_figure(_plan(still_joint=False), r, obstacle, tmp_path / "s.png")
    assert_png(out)


# -- what the figures say (issue 29): legends off the data, one unit per quantity, honest ranges and labels ---
@pytest.fixture(scope="module")
def example_4_2():
    from kinredund.thesis.chapter4 import load_example, run_example

    return run_example(load_example("4.2"), loops=1)


def _retimed_synthetic() -> Trajectory:
    """A retimed-looking record: ``synthetic``'s joints with their exact rates and the limits in its meta."""
    traj = synthetic(loops=1)
    w = 2.0 * np.pi / 2.0
    qdot = np.gradient(traj.q, traj.t, axis=0)
    qddot = np.gradient(qdot, traj.t, axis=0)
    limits = {"velocity": [1.2 * float(np.abs(qdot).max())] * 3, "acceleration": [1.2 * w * w] * 3}
    return dataclasses.replace(traj, qdot=qdot, qddot=qddot, meta={"retime": {"limits": limits}})


def _points_under_legends(fig) -> list[str]:
    """The curves with a vertex under a legend of their axes (in display coordinates, after drawing)."""
    fig.canvas.draw()
    hits = []
    for ax in fig.axes:
        legend = ax.get_legend()
        if legend is None:
            continue
        box = legend.get_window_extent()
        # the twin axes of a joint-history panel share its area: their curves count too
        for other in [a for a in fig.axes if a.bbox.bounds == ax.bbox.bounds]:
            for line in other.get_lines():
                xy = line.get_transform().transform(np.asarray(line.get_xydata(), float))
                inside = (xy[:, 0] > box.x0) & (xy[:, 0] < box.x1) & (xy[:, 1] > box.y0) & (xy[:, 1] < box.y1)
                if inside.any():
                    hits.append(f"{ax.get_ylabel()}: {line.get_label()} ({int(inside.sum())} points)")
    return hits


def test_legends_sit_off_the_data(example_4_2):
    """Example 4.2's eigenvalue legend covered mu_3's curve, the retime plot's the joint angles."""
    from kinredund.ui.plots_retime import retimed_figure

    figures = {"eigenvalues": m_eigenvalues_figure(example_4_2), "errors": errors_figure(example_4_2),
               "joints": joint_histories_figure(example_4_2), "drift": loop_drift_figure(example_4_2),
               "retimed": retimed_figure(_retimed_synthetic())}
    for name, fig in figures.items():
        assert any(ax.get_legend() is not None for ax in fig.axes), name
        assert _points_under_legends(fig) == [], name


def test_a_positive_eigenvalue_panel_is_not_stretched_from_zero(example_4_2):
    """Example 4.2's eigenvalues on null(J) lie between 0.94 and 1.06: the panel spanned 0 to 1.1 (a zero line
    drawn far from the data). A panel whose data change sign keeps its zero line."""
    top, bottom = m_eigenvalues_figure(example_4_2).axes[:2]
    data = example_4_2.m_null_eigs
    low, high = bottom.get_ylim()
    span = float(data.max() - data.min())
    assert low > 0.5 and high - low < 1.5 * span, (low, high, span)
    assert "all > 0" in bottom.get_ylabel()
    zero_lines = [line for line in top.get_lines() if np.all(np.asarray(line.get_ydata(), float) == 0.0)]
    assert example_4_2.m_eigs.min() < 0 < example_4_2.m_eigs.max() and len(zero_lines) == 1


def test_retime_plot_has_one_angle_unit():
    """q was drawn in degrees next to qdot in rad/s and qddot in rad/s^2 (limits given in rad/s)."""
    from kinredund.ui.plots_retime import retimed_figure

    traj = _retimed_synthetic()
    axes = retimed_figure(traj).axes
    units = [ax.get_ylabel().rsplit("[", 1)[1].rstrip("]") for ax in axes]
    assert units == ["rad", "rad/s", "rad/s$^2$"]
    np.testing.assert_array_equal(axes[0].get_lines()[0].get_ydata(), traj.q[:, 0])  # drawn as recorded


def test_drift_plot_says_what_it_plots():
    """loop_drift is |q(k T) - q(0)|, the drift from the start after each loop: the plot said 'per loop'."""
    traj = synthetic(loops=4, drift=1e-3)
    (ax,) = loop_drift_figure(traj).axes
    words = f"{ax.get_title()} {ax.get_ylabel()} {ax.get_xlabel()}"
    assert "per loop" not in words and "from the start" in ax.get_ylabel()
    np.testing.assert_allclose(ax.get_lines()[0].get_ydata(), 1e-3 * np.arange(1, 5), rtol=1e-9)  # cumulative
