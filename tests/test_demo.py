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
