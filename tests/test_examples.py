"""The examples run with --quick, in-process, and their figures meet stated bounds."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def load(name: str):
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def has_matplotlib() -> bool:
    return importlib.util.find_spec("matplotlib") is not None


@pytest.mark.slow
def test_rotation_regression(tmp_path, capsys):
    plot = tmp_path / "error.png"
    fig = load("rotation_regression").main(["--quick", "--plot", str(plot)])
    res = fig["results"]
    assert set(res) == {"6d", "9d", "quaternion", "rotvec"}
    for rep, r in res.items():
        # an untrained network is about as wrong as a random rotation (mean 126.5 degrees)
        assert 90.0 <= r["initial_error_deg"] <= 160.0, rep
        # every representation learns: the test error drops at least 5x
        assert r["final_error_deg"] <= r["initial_error_deg"] / 5, rep
        assert r["curve"][-1][0] == fig["steps"]
    # the continuous representations are accurate and beat the discontinuous ones
    for rep in ("6d", "9d"):
        assert res[rep]["final_error_deg"] <= 3.0
        assert res[rep]["p95_error_deg"] <= 6.0
        for other in ("quaternion", "rotvec"):
            assert res[rep]["final_error_deg"] < res[other]["final_error_deg"]
    assert res["quaternion"]["final_error_deg"] <= 15.0
    assert res["rotvec"]["final_error_deg"] <= 30.0
    out = capsys.readouterr().out
    assert "representation" in out and "6d" in out and "rotvec" in out
    if has_matplotlib():
        assert fig["plot"] == str(plot) and plot.stat().st_size > 1000
    else:
        assert fig["plot"] is None and not plot.exists()


@pytest.mark.slow
def test_pose_graph(capsys):
    fig = load("pose_graph").main(["--quick"])
    assert fig["poses"] == 100 and fig["loop_closures"] > 0
    # the optimiser reaches a better optimum than the ground truth itself (the noisy
    # measurements' maximum-likelihood poses), starting from the drifted odometry
    assert fig["cost_before"] / fig["cost_after"] >= 100
    assert fig["cost_after"] <= fig["cost_ground_truth"]
    assert fig["rot_error_deg_after"] <= 1.0
    assert fig["rot_error_deg_after"] <= fig["rot_error_deg_before"] / 5
    assert fig["trans_rmse_after"] <= 0.1
    assert fig["trans_rmse_after"] <= fig["trans_rmse_before"] / 5
    assert fig["valid"]
    assert "before (odometry)" in capsys.readouterr().out


@pytest.mark.slow
def test_inverse_kinematics(capsys):
    fig = load("inverse_kinematics").main(["--quick"])
    assert fig["targets"] == 200
    assert fig["success_rate"] >= 0.9
    assert fig["median_position_error_m"] <= 1e-4
    assert fig["median_rotation_error_deg"] <= 1e-2
    # from random starts (hundreds of mm away) to sub-0.1 mm: at least 1000x
    assert fig["initial_median_position_error_m"] >= 0.1
    assert fig["initial_median_position_error_m"] / fig["median_position_error_m"] >= 1e3
    assert fig["loss_first"] / fig["loss_last"] >= 10
    assert fig["within_limits"]
    assert fig["recheck_max_position_diff_m"] <= 1e-6
    assert "success" in capsys.readouterr().out


@pytest.mark.slow
def test_kinematics_validation(capsys):
    fig = load("kinematics_validation").main(["--quick", "--brief"])
    assert fig["ok"]
    res = fig["results"]
    assert set(res) == {"arm7 float64", "arm7 float32"}
    f64, f32 = res["arm7 float64"], res["arm7 float32"]
    assert f64["links"] == 12
    # float64 agrees with the exact reference to a few ulp (positions in m, reach ~1.5 m)
    for key in ("ref_position_m", "ref_rotation_rad", "ref_jacobian"):
        assert f64[key] <= 1e-14, key
        assert f32[key] <= 2e-6, key  # float32: ~10 ulp
    # pytorch-kinematics (float32) agrees to its own precision
    for f in (f64, f32):
        assert f["pk_version"] is not None
        for key in ("pk_position_m", "pk_rotation_rad", "pk_jacobian"):
            assert f[key] <= 1e-5, key
        assert math.isfinite(f["speedup_fk"]) and f["speedup_fk"] > 0
    out = capsys.readouterr().out
    assert "summary" in out and out.rstrip().endswith("PASS")
