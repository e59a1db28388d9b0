"""`make demo` (kinredund.demo.run_demo): every example runs and the summaries are strict JSON."""

from __future__ import annotations

import json

import pytest

from kinredund.demo import run_demo


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
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary file left
