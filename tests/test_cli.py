"""The command line: each command runs, writes what it says, and fails clearly with the right exit code."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import TRACK_HOLD
from conftest import robot as cached_robot
from test_viz import scene_commands
from test_viz import track as animation_track

from kinredund.ui.cli import EXIT_FAILED, EXIT_USAGE, main


def test_robots_lists_every_name(capsys):
    assert main(["robots"]) == 0
    out = capsys.readouterr().out
    for name in ("planar3r", "planar3r_ch6", "puma7", "cybotech_p15", "panda", "xarm7"):
        assert name in out


@pytest.mark.parametrize("example", ["4.1", "4.2"])
def test_reproduce_chapter4_writes_json_and_plot(tmp_path, example):
    js, png = tmp_path / "r.json", tmp_path / "r.png"
    assert main(["reproduce", example, "--loops", "2", "--json", str(js), "--plot", str(png)]) == 0
    data = json.loads(js.read_text())
    for key in ("t", "q", "q0", "solver", "m_min_eig", "position_error_max", "trace_error_max", "vect_error_max",
                "loop_drift"):
        assert key in data
    assert len(data["q"]) == len(data["t"]) == 401 and len(data["loop_drift"]) == 2
    assert max(data["loop_drift"]) < 1e-8 and data["position_error_max"] < 1e-8
    assert png.stat().st_size > 10_000 and png.read_bytes()[:4] == b"\x89PNG"


def test_reproduce_4_3_thesis_mode(tmp_path):
    js = tmp_path / "r.json"
    assert main(["reproduce", "4.3", "--mode", "thesis", "--json", str(js)]) == 0
    data = json.loads(js.read_text())
    assert data["mode"] == "thesis" and data["position_error_max"] < 2e-3 and data["vect_error_max"] < 1e-2


def test_reproduce_3_2(tmp_path):
    js = tmp_path / "h.json"
    assert main(["reproduce", "3.2", "--json", str(js)]) == 0
    data = json.loads(js.read_text())
    assert len(data["beta"]) == len(data["q"]) > 10


def test_bad_arguments_exit_2_with_a_message(capsys, tmp_path):
    with pytest.raises(SystemExit) as err:
        main(["reproduce", "4.9"])
    assert err.value.code == EXIT_USAGE
    assert "invalid choice" in capsys.readouterr().err
    capsys.readouterr()
    # counts are checked by argparse with the library's own bounds, before any work
    for argv, message in ((["reproduce", "4.1", "--loops", "0"], "--loops: must be an integer >= 1, got 0"),
                          (["track", "planar3r", "--steps", "-3"], "--steps: must be an integer >= 1, got -3"),
                          (["ik", "planar3r", "--target", "1,2", "--starts", "0"], "--starts: must be an integer >= 1"),
                          (["plan", "6.2", "--samples", "3"], "--samples: must be an integer >= 4, got 3")):
        with pytest.raises(SystemExit) as err:
            main(argv)
        assert err.value.code == EXIT_USAGE
        assert message in capsys.readouterr().err
    with pytest.raises(SystemExit) as err:
        main(["ik", "planar3r", "--target", "1,nan"])
    assert err.value.code == EXIT_USAGE
    assert main(["ik", "kuka", "--target", "1,2"]) == EXIT_USAGE
    assert "unknown robot 'kuka'" in capsys.readouterr().err
    assert main(["ik", "planar3r", "--target", "1,2,3"]) == EXIT_USAGE
    assert "shape (2,)" in capsys.readouterr().err
    missing = tmp_path / "nothing.json"
    assert main(["play", str(missing), "--html", str(tmp_path / "x.html")]) == EXIT_USAGE
    assert "cannot read" in capsys.readouterr().err
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    assert main(["play", str(bad), "--html", str(tmp_path / "x.html")]) == EXIT_USAGE
    assert "not valid JSON" in capsys.readouterr().err
    assert not (tmp_path / "x.html").exists()


def test_ik_command(capsys, tmp_path):
    js = tmp_path / "ik.json"
    assert main(["ik", "planar3r", "--target", "3.8,3", "--index", "min-norm", "--starts", "8", "--json", str(js)]) == 0
    out = json.loads(js.read_text(), parse_constant=lambda c: pytest.fail(f"non-strict JSON: {c}"))
    # converged: the solver's residuals passed its own test (what they mean is checked in test_ik.py)
    assert out["converged"] and 0.0 <= out["normality_residual"] < float("inf")
    assert out["robot"] == "planar3r" and out["starts"] == 8 and len(out["q"]) == 3  # the IKResult's fields
    assert main(["ik", "planar3r", "--target", "9,0"]) == EXIT_FAILED  # out of reach: not converged
    assert '"converged": false' in capsys.readouterr().out


def test_track_and_play(tmp_path):
    js, html = tmp_path / "t.json", tmp_path / "t.html"
    assert main(["track", "planar3r", "--radius", "0.5", "--speed", "0.5", "--loops", "2", "--json", str(js)]) == 0
    data = json.loads(js.read_text())
    assert max(data["loop_drift"]) < 1e-8
    assert main(["play", str(js), "--html", str(html)]) == 0
    # the replay's tracer keyframes follow the tracked p at the trajectory's own clock
    (anim,) = [c for c in scene_commands(html.read_text()) if c["type"] == "set_animation"]
    fps = anim["animations"][0]["clip"]["fps"]
    keys, tracer = animation_track(anim, "/meshcat/path/tracer", "position")
    t, p = np.array(data["t"]), np.array(data["p"])
    assert len(keys) > 300 and keys[-1] / fps == pytest.approx(t[-1] - t[0])  # two loops of 2 pi 0.5 / 0.5 s
    expected = np.column_stack([np.interp(t[0] + keys / fps, t, p[:, i]) for i in range(3)])
    np.testing.assert_allclose(tracer, expected, atol=1e-9)
    # and they lie on the tracked circle (radius 0.5 m about the start point - 0.5 m in x, plane z = 0)
    center = p[0] - [0.5, 0.0, 0.0]
    np.testing.assert_allclose(np.linalg.norm(tracer - center, axis=1), 0.5, atol=1e-4)
    np.testing.assert_allclose(tracer[:, 2], 0.0, atol=1e-12)


def test_track_pose_task_holds_the_start_orientation(tmp_path):
    """For a pose task the circle keeps the start pose's orientation: vect and trace errors stay ~0."""
    from kinredund import load_robot
    from kinredund.trajectory import Trajectory

    js = tmp_path / "pose.json"
    assert main(["track", "puma7", "--radius", "0.1", "--steps", "60", "--json", str(js)]) == 0
    tr = Trajectory.load_json(js)
    robot = load_robot("puma7")
    Q_start = robot.fk(tr.q[0])[:3, :3]
    assert max(np.abs(robot.fk(q)[:3, :3] - Q_start).max() for q in tr.q) < 1e-9
    assert tr.position_error.max() < TRACK_HOLD and tr.loop_drift.max() < 1e-8


def test_track_path_from_file(tmp_path):
    ts = np.linspace(0.0, 4.0, 41)
    p = np.column_stack([3.0 + 0.5 * np.cos(2 * np.pi * ts / 4), 3.0 + 0.5 * np.sin(2 * np.pi * ts / 4)])
    f = tmp_path / "path.json"
    f.write_text(json.dumps({"t": ts.tolist(), "p": p.tolist()}))
    js = tmp_path / "t.json"
    assert main(["track", "planar3r", "--path", "file", "--path-file", str(f), "--index", "min-norm",
                 "--json", str(js)]) == 0
    assert json.loads(js.read_text())["position_error_max"] < 1e-8
    f.write_text(json.dumps({"t": [0, 1], "p": [[0, 0], [1, 1]]}))
    assert main(["track", "planar3r", "--path", "file", "--path-file", str(f)]) == EXIT_USAGE


def test_track_open_path_from_file(tmp_path, capsys):
    """An open path ("closed": false) is tracked once over its duration, with --steps steps in all."""
    from kinredund.paths import read_path_file

    ts = 5.0 + np.linspace(0.0, 2.0, 21)  # times need not start at 0: they count from the first sample
    angle = 0.25 * np.pi * (ts - 5.0)  # a quarter of the circle of test_track_path_from_file
    p = np.column_stack([3.0 + 0.5 * np.cos(angle), 3.0 + 0.5 * np.sin(angle)])
    f = tmp_path / "open.json"
    f.write_text(json.dumps({"t": ts.tolist(), "p": p.tolist(), "closed": False}))
    path, duration = read_path_file(f)
    assert path.period is None and duration == pytest.approx(2.0)
    js = tmp_path / "t.json"
    assert main(["track", "planar3r", "--path", "file", "--path-file", str(f), "--index", "min-norm",
                 "--steps", "50", "--json", str(js)]) == 0
    data = json.loads(js.read_text())
    assert data["steps"] == 50 and len(data["t"]) == 51 and data["t"][-1] == pytest.approx(2.0)
    assert data["loop_drift"] is None and data["loop_period"] is None
    assert data["position_error_max"] < 1e-8
    np.testing.assert_allclose(np.array(data["p"])[[0, -1], :2], p[[0, -1]], atol=1e-8)  # from end to end
    f.write_text(json.dumps({"t": ts.tolist(), "p": p.tolist(), "closed": "no"}))
    assert main(["track", "planar3r", "--path", "file", "--path-file", str(f)]) == EXIT_USAGE
    assert "'closed' in" in capsys.readouterr().err


def test_console_script_is_installed():
    from pathlib import Path

    script = Path(sys.executable).parent / "kinredund"  # installed by pip next to the interpreter
    assert script.exists()
    out = subprocess.run([str(script), "robots"], capture_output=True, text=True)
    assert out.returncode == 0 and "panda" in out.stdout
    out = subprocess.run([str(script), "reproduce", "9.9"], capture_output=True, text=True)
    assert out.returncode == 2 and "invalid choice" in out.stderr


def test_failed_run_leaves_no_output_file(tmp_path, capsys):
    js = tmp_path / "t.json"
    # a 3 m circle around the home point: the path leaves the 6 m workspace
    # a tracking stop is a result that failed (exit 1), not bad input (exit 2)
    assert main(["track", "planar3r", "--radius", "3", "--speed", "1", "--index", "min-norm", "--json", str(js)]) \
        == EXIT_FAILED
    err = capsys.readouterr().err
    assert "kinredund: tracking stopped:" in err and "t = " in err
    assert not js.exists() and not list(tmp_path.iterdir())


# -- help, version, messages ---------------------------------------------------------------------------
def _subparsers(parser):
    import argparse

    (action,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return action.choices


def test_every_option_has_help_with_its_default():
    """Walk every subcommand's options: each has a help text; one with a default says it (or %(default)s);
    every subcommand has a description and an example in its epilog."""
    import argparse

    from kinredund.ui.cli import build_parser

    parser = build_parser()
    missing, no_default = [], []
    for name, sub in _subparsers(parser).items():
        assert sub.description and "`" not in sub.description.replace("`kinredund", ""), name
        assert sub.epilog and f"kinredund {name}" in sub.epilog or name == "play" and "kinredund play" in sub.epilog
        for action in sub._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            label = f"{name} {'/'.join(action.option_strings) or action.dest}"
            if not action.help or not action.help.strip():
                missing.append(label)
            elif action.option_strings and not action.required and "default" not in action.help:
                no_default.append(label)
    assert not missing, f"options without help text: {missing}"
    assert not no_default, f"options whose help does not give the default: {no_default}"
    assert "``" not in parser.description and "`" not in parser.description  # plain words, no RST
    assert "examples:" in parser.epilog


def _help_examples() -> dict[str, list[list[str]]]:
    """The examples of every ``--help`` (``kinredund --help`` as ""), by subcommand: each command's words after
    ``kinredund``, the parts of a ``&&`` chain as two commands, a trailing comment (after 3 spaces) left out."""
    import re
    import shlex

    from kinredund.ui.cli import build_parser

    parser = build_parser()
    examples = {}
    for name, p in [("", parser), *_subparsers(parser).items()]:
        lines = [line.strip() for line in p.epilog.split("examples:\n", 1)[1].splitlines()]
        commands = [re.split(r"\s{3,}", line)[0] for line in lines if line.startswith("kinredund ")]
        examples[name] = [shlex.split(part)[1:] for c in commands for part in c.split("&&")]
        assert examples[name] and all(words for words in examples[name]), (name, lines)
    return examples


def test_every_help_example_parses_as_its_subcommand():
    from kinredund.ui.cli import build_parser

    parser = build_parser()
    for name, commands in _help_examples().items():
        for words in commands:
            args = parser.parse_args(words)  # SystemExit(2) on an example the parser refuses
            assert args.command == words[0], words
        assert not name or name in [words[0] for words in commands], name  # one example of its own at least


#: examples run in test_every_help_example_runs, by --help: quick, or marked slow (a whole planner or sweep run)
_SLOW_HELP = {"", "demo", "plan", "sweep", "reproduce"}


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n in _SLOW_HELP else n
                                  for n in ["", "demo", "reproduce", "track", "ik", "plan", "play", "generate-robots",
                                            "robots", "retime", "export", "sweep", "check"]])
def test_every_help_example_runs(name, tmp_path, monkeypatch, capsys):
    """The examples of one ``--help``, run in order as printed in a new folder (the files they read, run.json,
    timed.json and a scene cell.json, put there first; an absolute output path moved into the folder): each exits
    0. A ``--live`` replay serves until Ctrl-C: it is only parsed. Reproducer: ``kinredund track xarm7 --task
    position --scheme pseudoinverse`` exited 1 (the baseline does not close the loop)."""
    monkeypatch.chdir(tmp_path)
    assert main(["track", "planar3r", "--steps", "40", "--json", "run.json", "--quiet"]) == 0
    assert main(["retime", "run.json", "--amax", "5", "--json", "timed.json"]) == 0
    (tmp_path / "cell.json").write_text(json.dumps({"format": "kinredund-scene", "version": 1, "objects": [
        {"name": "wall", "shape": "box", "size": [0.2, 4.0, 1.0], "pose": {"xyz": [1.5, 0.0, 0.0]}}]}))
    commands = _help_examples()[name]
    assert commands, name
    for words in commands:
        if "--live" in words:
            continue
        words = [str(tmp_path / Path(w).name) if w.startswith("/") else w for w in words]
        code = main(words)
        assert code == 0, (words, capsys.readouterr().err[-2000:])


def test_help_renders_units_and_defaults(capsys):
    with pytest.raises(SystemExit) as err:
        main(["track", "--help"])
    assert err.value.code == 0
    out = capsys.readouterr().out
    assert "[m/s] (default: 0.1)" in out and "[m] (default: 0.1)" in out and "examples:" in out


def test_version(capsys):
    import kinredund

    with pytest.raises(SystemExit) as err:
        main(["--version"])
    assert err.value.code == 0
    assert capsys.readouterr().out.strip() == f"kinredund {kinredund.__version__}"


def test_robots_lists_what_the_loader_knows(capsys):
    from kinredund.model.loader import known_robots

    assert main(["robots"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in lines[1:]] == known_robots()


def test_ik_pose_without_rpy_hints_at_task_position(capsys):
    assert main(["ik", "panda", "--target", "0.4,0.2,0.5"]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert "--rpy" in err and "--task position" in err
    assert main(["ik", "panda", "--target", "0.4,0.2,0.5", "--task", "position"]) == 0


def test_play_needs_an_action_and_says_so(tmp_path, capsys):
    js = tmp_path / "t.json"
    assert main(["track", "planar3r", "--radius", "0.5", "--speed", "0.5", "--json", str(js), "--quiet"]) == 0
    capsys.readouterr()
    assert main(["play", str(js)]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert "--html" in err and "--live" in err and str(js) in err
    bad = tmp_path / "other.json"
    bad.write_text('{"hello": 1}')
    assert main(["play", str(bad), "--html", str(tmp_path / "x.html")]) == EXIT_USAGE
    assert "not a kinredund record" in capsys.readouterr().err


def test_play_live_reads_its_scene_before_serving(tmp_path):
    """``play --live --scene`` with a missing scene file: the error naming the file, before any server starts
    (the scene was ignored with --live: the replay was served without it, until Ctrl-C)."""
    js, missing = tmp_path / "t.json", tmp_path / "no_cell.json"
    assert main(["track", "planar3r", "--steps", "20", "--json", str(js), "--quiet"]) == 0
    exe = Path(sys.executable).with_name("kinredund")
    proc = subprocess.Popen([str(exe), "play", str(js), "--live", "--scene", str(missing)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        out, err = proc.communicate(timeout=120)  # a hang guard: the old code served until Ctrl-C
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)  # the group this test started (the server with it), by its PID
            proc.wait()
    assert proc.returncode == EXIT_USAGE, err
    assert str(missing) in err and "No such file" in err
    assert "open http" not in out


def test_an_orientation_or_plane_the_task_cannot_hold_is_refused(capsys):
    """ik --rpy for a task without orientation, and track --normal tilting a circle out of a planar task's plane:
    refused naming what the task holds (both exited 0: the rotation was ignored, and the vertical circle was
    tracked as its shadow on the plane, a line back and forth)."""
    assert main(["ik", "planar3r", "--target", "1,1", "--rpy", "1,2,3"]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert "--rpy" in err and "'planar'" in err and "no orientation" in err, err
    assert main(["track", "planar3r", "--normal", "1,0,0", "--quiet"]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert "--normal" in err and "0,0,1" in err and "'planar'" in err, err
    assert main(["track", "planar3r", "--normal", "0,0,-2", "--steps", "20", "--quiet"]) == 0  # the plane itself


def test_path_options_that_the_path_does_not_take_are_refused(tmp_path, capsys):
    """--path-file without --path file, --center or --normal with --path file, and --normal with an ellipse (which
    lies in a horizontal plane) are refused naming the option, not ignored (each exited 0 tracking another path
    than the one described)."""
    path_file = tmp_path / "p.json"
    path_file.write_text(json.dumps({"t": [0.0, 1.0, 2.0], "p": [[1.0, 1.0, 0.0], [1.1, 1.0, 0.0], [1.0, 1.0, 0.0]]}))
    for argv, words in ((["--path-file", str(path_file)], "--path-file is read with --path file"),
                        (["--path", "file", "--path-file", str(path_file), "--center", "1,1"], "--center"),
                        (["--path", "file", "--path-file", str(path_file), "--normal", "0,0,1"], "--normal"),
                        (["--path", "ellipse", "--normal", "0,1,0"], "--normal")):
        assert main(["track", "planar3r", "--steps", "20", "--quiet", *argv]) == EXIT_USAGE, argv
        err = capsys.readouterr().err
        assert words in err, (argv, err)


def test_a_path_file_fixes_the_radius_and_speed_so_they_are_refused_with_it(tmp_path, capsys):
    """--radius and --speed with --path file were ignored (their defaults 0.1 were not None: nothing said so);
    given with a file they are refused naming them, and the circle still takes its defaults without them."""
    path_file = tmp_path / "p.json"
    path_file.write_text(json.dumps({"t": [0.0, 1.0, 2.0, 3.0], "p": [[3.0, 3.0], [3.1, 3.0], [3.1, 3.1], [3.0, 3.0]]}))
    for extra, words in ((["--radius", "0.1"], "--radius"), (["--speed", "0.3"], "--speed"),
                         (["--radius", "0.2", "--speed", "0.3"], "--radius and --speed")):
        argv = ["track", "planar3r", "--path", "file", "--path-file", str(path_file), "--quiet", *extra]
        assert main(argv) == EXIT_USAGE, extra
        err = capsys.readouterr().err
        assert f"{words} do(es) not apply to --path file" in err and "the file's samples fix" in err, err
    js = tmp_path / "c.json"
    assert main(["track", "planar3r", "--steps", "20", "--quiet", "--json", str(js)]) == 0
    p = np.array(json.loads(js.read_text())["p_desired"])[:, :2]
    centre = p[0] - [0.1, 0.0]  # the default: --radius 0.1 along -x from the start point
    np.testing.assert_allclose(np.linalg.norm(p - centre, axis=1), 0.1, atol=1e-12)
    from types import SimpleNamespace

    from kinredund.ui.cli_track import say_speed

    fast = SimpleNamespace(speed_over_limits=(2.0, 0, 0.5))  # a joint at twice its limit: the hint for a file path
    say_speed(fast, cached_robot("planar3r"), SimpleNamespace(path="file", speed=None, json=None))
    err = capsys.readouterr().err
    assert "a path file whose times are 2 times as long" in err and "--speed" not in err, err


@pytest.mark.parametrize(("argv", "task"), [(["track", "planar3r"], "planar"),
                                            (["track", "panda", "--task", "position"], "position"),
                                            (["sweep", "planar3r", "--grid", "0:0:1,0:0:1"], "planar")])
def test_a_path_file_with_rotations_is_refused_for_a_task_without_orientation(tmp_path, capsys, argv, task):
    """A file's 'Q' was dropped silently where the task follows the position only: refused, naming both."""
    ts = np.linspace(0.0, 4.0, 41)
    xy = np.column_stack([3.0 + 0.5 * np.cos(np.pi * ts / 2), 3.0 + 0.5 * np.sin(np.pi * ts / 2)])
    Q = [[[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]] for a in np.pi * ts / 2]
    f = tmp_path / "turning.json"
    f.write_text(json.dumps({"t": ts.tolist(), "p": xy.tolist(), "Q": Q}))
    assert main([*argv, "--path", "file", "--path-file", str(f), "--quiet"]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert "holds rotations ('Q')" in err and f"{task!r} task follows the position only" in err, err
    assert "leave 'Q' out" in err and "--task pose" in err, err


def test_a_path_file_moving_in_z_is_refused_for_a_planar_task(tmp_path, capsys):
    """The planar task follows x and y: a file whose z moves was tracked as its shadow on the plane, silently."""
    ts = np.linspace(0.0, 4.0, 41)
    xy = np.column_stack([3.0 + 0.5 * np.cos(np.pi * ts / 2), 3.0 + 0.5 * np.sin(np.pi * ts / 2)])
    f = tmp_path / "helix.json"
    f.write_text(json.dumps({"t": ts.tolist(), "p": np.column_stack([xy, 0.05 * np.sin(np.pi * ts / 2)]).tolist()}))
    assert main(["track", "planar3r", "--path", "file", "--path-file", str(f), "--quiet"]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert "moves in z (from -0.05 to 0.05 m)" in err and "'planar' task follows x and y only" in err, err
    assert "Allowed: one z for every sample" in err and "--task position" in err
    f.write_text(json.dumps({"t": ts.tolist(), "p": np.column_stack([xy, np.full(len(ts), 0.2)]).tolist()}))
    assert main(["track", "planar3r", "--path", "file", "--path-file", str(f), "--index", "min-norm", "--quiet",
                 "--steps", "40"]) == 0  # one plane z: the file's plane, nothing dropped but the constant


def test_reproduce_refuses_tracking_options_where_they_do_not_apply(capsys):
    """--loops, --steps, --mode and --scheme apply to 4.1-4.3: given to 3.2 or 6.x (which fix their own) they are
    refused naming them, before any work (they were ignored: exit 0 with the reproduction's own settings)."""
    for argv in (["3.2", "--scheme", "pseudoinverse"], ["6.3", "--loops", "3", "--mode", "thesis"]):
        assert main(["reproduce", *argv, "--quiet"]) == EXIT_USAGE, argv
        err = capsys.readouterr().err
        assert all(option in err for option in argv if option.startswith("--")) and "4.1-4.3" in err, err


def test_a_plot_path_without_a_suffix_is_named_as_such(capsys):
    """--plot joints (no suffix) said "unknown --plot format (file suffix) ''": it says the file has no suffix and
    which to give."""
    assert main(["track", "planar3r", "--plot", "joints", "--quiet"]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert "--plot 'joints' has no suffix" in err and ".png, .pdf or .svg" in err, err


def test_play_replays_the_helix_of_3_2(tmp_path, capsys):
    js, html = tmp_path / "h.json", tmp_path / "h.html"
    assert main(["reproduce", "3.2", "--json", str(js), "--quiet"]) == 0
    assert main(["play", str(js), "--html", str(html)]) == 0
    assert f"wrote {html}" in capsys.readouterr().out
    page = html.read_text()
    assert "puma7: Section 3.2" in page
    desired = next(c for c in scene_commands(page) if c.get("path") == "/meshcat/path/desired")
    line = np.frombuffer(desired["object"]["geometries"][0]["data"]["attributes"]["position"]["array"].data,
                         dtype=np.float32).reshape(-1, 3)
    np.testing.assert_allclose(line, json.loads(js.read_text())["wrist_centre"], atol=1e-5)  # the helix itself


def test_plan_6_2_failure_prints_no_empty_rows_and_play_explains(tmp_path, capsys):
    js, png = tmp_path / "p.json", tmp_path / "p.png"
    assert main(["reproduce", "6.2", "--json", str(js), "--plot", str(png), "--quiet"]) == EXIT_FAILED
    out = capsys.readouterr().out
    assert f"wrote {js}" in out and f"wrote {png}" in out
    assert not (tmp_path / "p_snapshots.png").exists()  # no motion, no snapshots
    rows = out.splitlines()[1:-2]
    assert rows and not [r for r in rows if r.split()[-1] in ("None", "nan", "{}", "[]")], rows
    assert main(["play", str(js), "--html", str(tmp_path / "p.html")]) == EXIT_USAGE
    assert "no motion to replay" in capsys.readouterr().err


def test_summary_numbers_have_one_format(capsys):
    from kinredund.ui.summary import print_summary as _print_summary

    _print_summary({"loop_drift": [1.234567e-15, 2.5e-15], "x": None, "y": float("nan"), "z": {}, "w": [],
                    "timings_s": {"roadmap_s": 12.345, "total_s": 20.0}, "position_error_max": 1.23456e-12})
    _print_summary({"loop_drift": 0.0})
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in lines] == ["loop_drift", "timings_s", "position_error_max", "loop_drift"]
    assert lines[0].split(None, 1)[1] == "2.5e-15 rad after loop 2 (largest 2.5e-15 rad)"
    assert lines[3].split(None, 1)[1] == "0 rad after loop 1"
    assert "roadmap 12.3 s, total 20 s" in lines[1] and lines[2].endswith("1.23e-12 m")


def test_baseline_normality_residual_is_against_the_index(capsys):
    """`track --scheme pseudoinverse` measures the normality residual (Eq. 4.5) against --index: the
    pseudoinverse leaves the optimum of the home index, so its residual is far from round-off. Its joints do
    not close over the loop either: exit 1, the cause named."""
    assert main(["track", "planar3r", "--radius", "0.5", "--speed", "0.5", "--scheme", "pseudoinverse",
                 "--quiet"]) == EXIT_FAILED
    out, err = capsys.readouterr()
    assert "the pseudoinverse baseline is not cyclic" in err
    (row,) = [line for line in out.splitlines() if "normality_residual_max" in line]
    assert float(row.split()[1]) > 1e-4, row


def test_track_announces_every_file(tmp_path, capsys):
    files = {flag: tmp_path / f"t.{ext}" for flag, ext in (("--json", "json"), ("--plot", "png"), ("--html", "html"))}
    argv = ["track", "planar3r", "--radius", "0.5", "--speed", "0.5", "--quiet"]
    assert main(argv + [x for flag, f in files.items() for x in (flag, str(f))]) == 0
    out = capsys.readouterr().out
    assert all(f"wrote {f}" in out for f in files.values())
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(f.name for f in files.values())


def _progress_lines(proc, until: str, timeout: float) -> list[str]:
    """stderr lines of ``proc`` until one contains ``until`` (or the stream ends), each waited for with a
    select timeout (a hang fails the test; no assertion on speed)."""
    import select

    lines = []
    while True:
        ready, _, _ = select.select([proc.stderr], [], [], timeout)
        assert ready, f"no progress line within {timeout} s; so far: {lines}"
        line = proc.stderr.readline()
        if not line:
            return lines
        lines.append(line.rstrip("\n"))
        if until in line:
            return lines


@pytest.mark.slow
def test_plan_6_3_reports_progress_from_start_to_end(tmp_path):
    """`kinredund plan 6.3` writes a progress line before any work (off a terminal: one line per stage and
    every few seconds) and follows the roadmap, the tracking and the clearance check to the end."""
    from pathlib import Path

    exe = Path(sys.executable).with_name("kinredund")
    proc = subprocess.Popen([str(exe), "plan", "6.3", "--json", str(tmp_path / "p.json")], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    try:
        first = _progress_lines(proc, "starting", timeout=60)
        assert first[-1].startswith("plan 6.3: starting 0/1")
        rest = _progress_lines(proc, "plan 6.3: done", timeout=60)
        out, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0
    stages = [line.split(": ", 1)[1].rsplit(" ", 3)[0] for line in rest if " 0/" in line or "/" in line]
    for stage in ("roadmap", "tracking", "clearance"):
        assert any(s.startswith(stage) for s in stages), rest
    assert rest[-1].startswith("plan 6.3: done")
    assert f"wrote {tmp_path / 'p.json'}" in out
    # the plan replays: the scaled P-15 of Section 6.3 with its obstacle, the end point on the planned path
    html = tmp_path / "p.html"
    run = subprocess.run([str(exe), "play", str(tmp_path / "p.json"), "--html", str(html)], capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    page = html.read_text()
    assert "cybotech_p15_x8: Section 6.3, collision-free plan" in page and "obstacle" in page
    cmds = scene_commands(page)
    assert any(c.get("path") == "/meshcat/obstacle" for c in cmds if c["type"] == "set_object")
    (anim,) = [c for c in cmds if c["type"] == "set_animation"]
    keys, tracer = animation_track(anim, "/meshcat/path/tracer", "position")
    from kinredund.planning.spatial import section_path

    path = section_path()
    fps = anim["animations"][0]["clip"]["fps"]
    t0 = json.loads((tmp_path / "p.json").read_text())["t"][0]
    on_path = np.array([path(t0 + k / fps).p for k in keys])
    # the replayed end point (FK of the plan's joints, interpolated linearly between its 720 steps) is on the
    # Section 6.3 path at the same time: the chord of one step (~1 cm) leaves a sagitta well below 1e-4 m
    assert np.abs(tracer - on_path).max() < 1e-4


def test_quiet_prints_no_progress(tmp_path):
    from pathlib import Path

    exe = Path(sys.executable).with_name("kinredund")
    run = subprocess.run([str(exe), "reproduce", "4.1", "--quiet"], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0 and run.stderr == ""
    run = subprocess.run([str(exe), "reproduce", "4.1"], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0 and run.stderr.startswith("reproduce 4.1: starting")
    assert "reproduce 4.1: tracking" in run.stderr and run.stderr.rstrip().splitlines()[-1].startswith(
        "reproduce 4.1: done")


def test_progress_lines_off_a_terminal_and_a_bar_on_one():
    import io

    from kinredund.ui.progress import Progress

    log = io.StringIO()
    bar = Progress("plan 6.3", stream=log, interval=1e9)  # no timed lines: the first call and each stage's end
    for stage, total in (("roadmap", 50), ("tracking", 720), ("clearance", 1)):
        for k in range(total + 1):
            bar(k, total, stage)
    bar.close()
    lines = log.getvalue().splitlines()
    assert [line.split(": ")[1].split(" ")[0] for line in lines[:-1]] == ["roadmap", "roadmap", "tracking",
                                                                        "clearance"]
    assert lines[0].startswith("plan 6.3: roadmap 0/50 (0%)") and lines[-1].startswith("plan 6.3: done")
    # a stage's line says where it got to, not where it began
    assert lines[1].startswith("plan 6.3: roadmap 50/50 (100%)") and lines[2].startswith("plan 6.3: tracking 720/720")
    quiet = io.StringIO()
    bar = Progress("x", stream=quiet, quiet=True)
    bar(1, 2, "a")
    bar.close()
    assert quiet.getvalue() == ""
    term = io.StringIO()
    bar = Progress("track panda", stream=term)
    bar.terminal = True  # as on a terminal: tqdm draws on the stream
    bar(0, 1, "the optimal start (IK)")
    bar(100, 200, "tracking")
    bar.close()
    drawn = term.getvalue()
    assert "track panda: the optimal start (IK)" in drawn and "track panda: tracking" in drawn and "100/200" in drawn


def test_every_output_option_is_checked_and_typed_as_an_output_file():
    """Every option that names a file the command writes (``--json``, ``--plot``, ``--html``, ``--csv``,
    ``--partial``) is in :data:`kinredund.ui.cli.OUTPUT_OPTIONS` (checked before any work) and parsed by
    :func:`kinredund.ui.options.output_file` (``out.json/`` names a folder and is refused, not turned into
    ``out.json``), on every subcommand."""
    from kinredund.ui.cli import OUTPUT_OPTIONS, build_parser
    from kinredund.ui.options import output_file

    files = {name for name, kind in OUTPUT_OPTIONS.items() if kind == "file"}
    untyped, unchecked = [], []
    for name, sub in _subparsers(build_parser()).items():
        for action in sub._actions:
            if action.dest in files and action.type is not output_file:
                untyped.append(f"{name} {'/'.join(action.option_strings)}")
            if action.type is output_file and action.dest not in OUTPUT_OPTIONS:
                unchecked.append(f"{name} {'/'.join(action.option_strings)}")
    assert not untyped, f"output options not typed with options.output_file: {untyped}"
    assert not unchecked, f"output options missing from OUTPUT_OPTIONS: {unchecked}"
    with pytest.raises(SystemExit) as exc:
        main(["check", "run.json", "--scene", "cell.json", "--json", "out.json/"])
    assert exc.value.code == EXIT_USAGE
