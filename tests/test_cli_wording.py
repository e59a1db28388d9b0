"""What the command line says: one unit for every angle, a unit on every printed figure, plain words.

Each test runs the installed ``kinredund`` script as a user would (a subprocess) and reads what it prints.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

EXE = Path(sys.executable).with_name("kinredund")


def kinredund(*argv: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([str(EXE), *argv], capture_output=True, text=True, timeout=600, cwd=cwd)


def test_robots_table_columns_line_up():
    """Every row's columns start where the header's do (a long name pushed one row out of line)."""
    run = kinredund("robots")
    assert run.returncode == 0, run.stderr
    header, *rows = run.stdout.splitlines()
    starts = [header.index(word) for word in ("task", "redundancy", "default frame", "source")]
    names = {line.split()[0] for line in rows}
    assert {"cybotech_p15_x8", "panda", "planar3r"} <= names
    for line in rows:
        for col in starts:
            assert line[col - 2:col] == "  " and line[col] != " ", (col, line)


def test_sweep_yaw_is_in_radians_and_every_figure_has_its_unit(tmp_path):
    """--grid takes yaw in radians like every other angle; the best placements print yaw [rad] and the
    margin with its unit; placements without a start configuration are counted as such."""
    out = tmp_path / "s.json"
    run = kinredund("sweep", "panda", "--grid", "0.4:2.0:2,0:0:1,0:0.5:2", "--workers", "0", "--starts", "2",
                    "--steps", "40", "--quiet", "--json", str(out))
    assert run.returncode == 0, run.stderr
    first = run.stdout.splitlines()[0]
    assert first.endswith("4 placements at z = 0.590 m, 2 feasible, 2 without a start"), first
    best = [line for line in run.stdout.splitlines() if line.startswith("  #")]
    assert best and all(re.search(r"yaw [+-]\d\.\d{3} rad  margin \S+ rad$", line) for line in best), best
    assert {line.split("yaw ")[1].split()[0] for line in best} == {"+0.000", "+0.500"}
    records = [json.loads(line) for line in out.read_text().splitlines()[1:]] if out.suffix == ".jsonl" \
        else json.loads(out.read_text())["records"]
    assert sorted({round(r["yaw"], 12) for r in records}) == [0.0, 0.5]  # radians, as given


def test_axis_error_prints_its_unit():
    run = kinredund("track", "ur5", "--steps", "40", "--quiet")
    assert run.returncode == 0, run.stderr
    (row,) = [line for line in run.stdout.splitlines() if "axis_error_max" in line]
    assert row.endswith(" rad"), row


def test_a_task_without_redundancy_says_the_index_has_no_effect():
    run = kinredund("track", "ur5", "--task", "pose", "--steps", "40", "--quiet")
    assert run.returncode == 0, run.stderr
    assert "not redundant" in run.stderr and "--index home has no effect" in run.stderr, run.stderr
    redundant = kinredund("track", "planar3r", "--radius", "0.5", "--speed", "0.5", "--steps", "40", "--quiet")
    assert redundant.returncode == 0 and "no effect" not in redundant.stderr


def test_errors_speak_the_command_line_and_print_plain_numbers():
    run = kinredund("ik", "so100", "--task", "pose", "--target", "0.1,0.1,0.1", "--rpy", "0,0,0")
    assert run.returncode == 2
    assert "--task position" in run.stderr and "with_task" not in run.stderr, run.stderr
    run = kinredund("track", "planar3r", "--center", "1,2,3,4", "--quiet")
    assert run.returncode == 2
    assert "got [1.0, 2.0, 3.0, 4.0]" in run.stderr and "array(" not in run.stderr, run.stderr


def test_plan_plot_help_announces_the_snapshot_file():
    for command in ("plan", "reproduce"):
        run = kinredund(command, "--help")
        text = " ".join(run.stdout.split())
        assert "NAME_snapshots.EXT" in text, command


@pytest.mark.parametrize(("value", "shown"), [
    ([0] * 90, "90 values, all 0"),
    (list(np.linspace(0.0, 1.0, 90)), "90 values from 0 to 1 m"),
    ([1, 2, 3], "[1, 2, 3] m"),
])
def test_long_lists_are_summed_up_not_cut(value, shown):
    """`candidates [0, 0, ..., 0] (90 values)` said nothing a reader could use."""
    from kinredund.ui.summary import format_value as _format

    key = "candidates" if shown.startswith("90 values, all") else "clearance_min"
    assert _format(key, value) == shown
