"""`make demo` (kinredund.ui.demo.run_demo): every example runs and the summaries are strict JSON."""

from __future__ import annotations

import json

import pytest

from kinredund.ui.demo import run_demo


@pytest.mark.slow
def test_quick_demo_writes_every_output(tmp_path):
    assert run_demo(tmp_path, quick=True) == 0
    names = {p.name for p in tmp_path.iterdir()}
    for tag in ("4_1", "4_2", "4_3"):
        assert {f"example_{tag}.html", f"example_{tag}_joints.png", f"example_{tag}_drift.png"} <= names
    assert {"section_3_2.json", "section_6_2.json", "section_6_3.json", "section_6_3.html",
            "summary.md", "summary.json"} <= names
    summary = json.loads((tmp_path / "summary.json").read_text(), parse_constant=lambda c: pytest.fail(c))
    assert summary["failures"] == []
    assert summary["figures"]["6.2"]["ok"] is False and summary["figures"]["6.3"]["ok"] is True
    table = (tmp_path / "summary.md").read_text()
    for name in ("4.1", "4.2", "4.3"):
        # the default mode is cyclic: round-off drift after each of the quick demo's 2 loops, in the JSON ...
        figures = summary["figures"][f"{name}/default"]
        assert len(figures["loop_drift"]) == 2 and max(figures["loop_drift"]) < 1e-8, figures
        assert figures["position_error_max"] < 1e-8 and figures["lu_steps"] <= figures["steps"] == 400
        # ... and in the Markdown table's row (drift after the last loop in the 7th column)
        (row,) = [line for line in table.splitlines() if line.startswith(f"| Example {name} | default |")]
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert float(cells[6]) < 1e-8 and float(cells[2]) < 1e-8, row
        assert f"| Example {name} | thesis (1989) |" in table
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary file left


#: Everything `kinredund demo` writes (the demo's table and JSON, a figure per plot, a replay per example).
DEMO_OUTPUTS = {
    *(f"example_{tag}{suffix}" for tag in ("4_1", "4_2", "4_3")
      for suffix in (".html", "_joints.png", "_errors.png", "_drift.png", "_eigenvalues.png")),
    "section_3_2.json", "section_3_2_joints.png",
    "section_6_2.json", "section_6_2.png",
    "section_6_3.json", "section_6_3.png", "section_6_3_snapshots.png", "section_6_3.html",
    "summary.md", "summary.json",
}


@pytest.mark.slow
def test_plain_wheel_install_runs_the_whole_demo(tmp_path):
    """The wheel in a fresh virtual environment, no extras (`pip install kinredund-*.whl`): `kinredund demo`
    exits 0 and writes every figure and replay (meshcat, matplotlib and tqdm are core dependencies)."""
    import subprocess
    import sys
    import venv
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    wheels = tmp_path / "dist"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "-w", str(wheels), str(root)],
                   check=True, timeout=600)
    (wheel,) = wheels.glob("kinredund-*.whl")
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=True).create(env_dir)
    subprocess.run([str(env_dir / "bin" / "python"), "-m", "pip", "install", "--quiet", str(wheel)], check=True,
                   timeout=1800)
    out = tmp_path / "D"
    run = subprocess.run([str(env_dir / "bin" / "kinredund"), "demo", "--out", str(out)], capture_output=True,
                         text=True, timeout=3600, cwd=tmp_path)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    names = {p.name for p in out.iterdir()}
    assert DEMO_OUTPUTS <= names, sorted(DEMO_OUTPUTS - names)
    assert all((out / name).stat().st_size > 1000 for name in DEMO_OUTPUTS)
    summary = json.loads((out / "summary.json").read_text(), parse_constant=lambda c: pytest.fail(c))
    assert summary["failures"] == []
