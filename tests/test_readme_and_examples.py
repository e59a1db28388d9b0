"""The README's Python snippets and the scripts in examples/ are complete programs: each runs as it is,
in a fresh interpreter, and prints the figures it promises."""

from __future__ import annotations

import math
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SNIPPETS = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), flags=re.S)
EXAMPLES = sorted((ROOT / "examples").glob("*.py"))


def _run(code: str, cwd: Path) -> str:
    done = subprocess.run([sys.executable, "-c", code], cwd=cwd, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout


def _numbers(text: str) -> list[float]:
    return [float(x) for x in re.findall(r"-?\d+(?:\.\d+)?(?:e[-+]?\d+)?", text)]


def test_the_readme_has_its_snippets():
    assert len(SNIPPETS) >= 3


@pytest.mark.parametrize("k", range(len(SNIPPETS)))
def test_readme_snippet_runs_verbatim(k, tmp_path):
    out = _run(SNIPPETS[k], tmp_path)
    figures = _numbers(out)
    assert figures, f"snippet {k} printed no figures: {out!r}"
    # every snippet prints a drift [rad] and an error [m or rad]: both at machine-precision level
    assert max(abs(v) for v in figures if abs(v) < 1.0) < 1e-9, out
    # a print whose comment says what it prints ('# ~1e-15 rad, ~4e-13 m') says it to within a factor of 10
    # (round-off figures move by a few units with the BLAS kernel; the tool-axis snippet claimed ~1e-15 rad
    # where it printed 1.3e-14)
    claims = [_numbers(c) for line in SNIPPETS[k].splitlines() if line.startswith("print(") and "# ~" in line
              for c in re.findall(r"~(\S+)", line.split("#", 1)[1])]
    if claims:
        claimed = [c[0] for c in claims]
        assert len(claimed) == len(figures), (claimed, out)
        for said, got in zip(claimed, figures, strict=True):
            if got == 0.0:  # a round-off figure may come out exactly 0 on another kernel: a claim at round-off holds
                assert abs(said) < 1e-12, f"the comment says ~{said:g}, it printed 0"
                continue
            assert abs(math.log10(abs(got) / abs(said))) <= 1.0, f"the comment says ~{said:g}, it printed {got:g}"


@pytest.mark.parametrize("script", EXAMPLES, ids=[p.stem for p in EXAMPLES])
def test_example_script_runs(script, tmp_path):
    out = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "ok" in out.stdout.splitlines()[-1], out.stdout[-2000:]
