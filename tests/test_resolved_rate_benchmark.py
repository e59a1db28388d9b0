"""The resolved-rate benchmark (benchmarks/resolved_rate.py, issue 4) runs and reports what it says."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parent.parent / "benchmarks"


def _load():
    sys.path.insert(0, str(BENCH))  # the script imports its sibling _bench
    spec = importlib.util.spec_from_file_location("kinredund_bench_resolved_rate", BENCH / "resolved_rate.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


bench = _load()


def test_panda_figures_and_plot(tmp_path):
    res = bench.bench("panda", steps=20)
    keys = {"eval_us", "step_default_us", "step_default_velocity_us", "step_thesis_us", "pinv_us"}
    assert keys <= set(res) and all(res[k] > 0 for k in keys)
    if importlib.util.find_spec("pink") is not None:
        assert res["pink_step_us"] > 0 and res["pink_limits_step_us"] > 0
        assert abs(res["default_over_pink"] - res["step_default_us"] / res["pink_step_us"]) < 1e-12
    out = tmp_path / "times.png"
    bench.write_plot({"panda": res}, out)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not list(tmp_path.glob(".*"))  # no temporary file left behind


def test_evaluation_solves_the_velocity_form_system():
    """_eval_once gives the rates of Eq. (4.36) at the start: M* thetadot + K^T lambda*dot = 0, K thetadot = twist."""
    import numpy as np

    from kinredund.closure import contract
    from kinredund.resolved_rate import multipliers

    robot, path, index, q0 = bench._setup("panda")
    s = path(0.0)
    twist = np.concatenate([s.omega, s.v])
    x = bench._eval_once(robot, index, q0, twist)
    _, _, K, dK = robot.kinematics.jacobian_derivative(q0)
    _, grad, hess = index.evaluate(q0)
    M = hess + contract(multipliers(K, grad)[0], dK)  # Eq. (4.37) through the tensor route
    assert np.abs(M @ x[:7] + K.T @ x[7:]).max() < 1e-10
    assert np.abs(K @ x[:7] - twist).max() < 1e-10
