"""The examples: documented command lines, outputs in ``--out``, and with ``--quick`` (run
in-process) figures that meet stated bounds."""

from __future__ import annotations

import importlib.util
import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"

# Every option of each example (besides -h); each must be listed by --help with a default.
OPTIONS = {
    "distributed_training": (
        "--quick --steps --world-size --backend --out --no-plot --seed --threads".split()
    ),
    "kinematics_validation": (
        "--quick --robots --samples --dtypes --brief --out --threads".split()
    ),
    "rotation_regression": "--quick --steps --out --no-plot --seed --threads".split(),
    "inverse_kinematics": (
        "--quick --targets --restarts --max-iterations --dtype --seed --threads --out --no-plot"
    ).split(),
    "payload_identification": (
        "--quick --states --payload --noise --iterations --out --no-plot --seed --threads".split()
    ),
    "scaled_alignment": (
        "--quick --poses --noise --iterations --seed --out --no-plot --threads".split()
    ),
    "pose_graph": (
        "--quick --poses --laps --optimizer --representation --iterations --seed --out "
        "--no-plot --threads"
    ).split(),
    "planar_pose_graph": (
        "--quick --poses --laps --representation --iterations --seed --out --no-plot --threads"
    ).split(),
}


def load(name: str):
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def has_matplotlib() -> bool:
    return importlib.util.find_spec("matplotlib") is not None


def help_entries(text: str) -> dict[str, str]:
    """Option -> its help text (default included), from argparse's ``--help`` output."""
    entries: dict[str, str] = {}
    option = None
    for line in text.split("options:", 1)[1].splitlines():
        if line.startswith("  -"):
            option = line.split()[0].rstrip(",")
            invocation_and_help = re.split(r"\s{2,}", line.strip(), maxsplit=1)
            entries[option] = invocation_and_help[1] if len(invocation_and_help) > 1 else ""
        elif option and line.startswith("   "):
            entries[option] += " " + line.strip()
    return entries


@pytest.mark.parametrize("name", sorted(OPTIONS))
def test_docstring_says_what_and_how_to_run(name):
    doc = load(name).__doc__
    assert len(doc.splitlines()[0]) > 20  # one line saying what it shows
    assert f"Run: ``python examples/{name}.py" in doc
    assert "--out" in doc and "examples/out/" in doc


@pytest.mark.parametrize("name", sorted(OPTIONS))
def test_help_lists_every_option_with_help_and_default(name, capsys):
    with pytest.raises(SystemExit) as exit_:
        load(name).main(["--help"])
    assert exit_.value.code == 0
    entries = help_entries(capsys.readouterr().out)
    assert sorted(entries) == sorted(["-h", *OPTIONS[name]])
    for option in OPTIONS[name]:
        text = entries[option]
        assert "(default: " in text, option
        # a description besides the default
        assert len(re.findall(r"[A-Za-z]{2,}", text.split("(default: ")[0])) >= 2, option
    assert "examples/out" in entries["--out"]


def test_out_folder_is_ignored_by_git():
    gitignore = (EXAMPLES.parent / ".gitignore").read_text().splitlines()
    assert "examples/out/" in gitignore


@pytest.mark.parametrize(
    "name, argv, figures, plot",
    [
        (
            "rotation_regression",
            ["--steps", "2"],
            "rotation_regression.json",
            "rotation_regression.png",
        ),
        (
            "pose_graph",
            ["--poses", "24", "--laps", "2", "--iterations", "3"],
            "pose_graph.json",
            "pose_graph.png",
        ),
        (
            "payload_identification",
            ["--states", "20", "--iterations", "1"],
            "payload_identification.json",
            "payload_identification.png",
        ),
    ],
)
def test_missing_matplotlib_is_said_once_on_stderr(
    name, argv, figures, plot, tmp_path, capsys, monkeypatch
):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib -> ImportError
    monkeypatch.setitem(sys.modules, "matplotlib.pyplot", None)
    fig = load(name).main([*argv, "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert err.count("matplotlib is not installed") == 1, err
    assert f"{name}: " in err and "pip install matplotlib" in err
    assert fig["plot"] is None
    assert sorted(p.name for p in tmp_path.iterdir()) == [figures]
    assert json.loads((tmp_path / figures).read_text())["seconds"] == fig["seconds"]


def test_missing_pytorch_kinematics_is_said_once_on_stderr(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "pytorch_kinematics", None)  # import -> ImportError
    argv = ["--robots", "arm7", "--samples", "5", "--dtypes", "float64", "--brief"]
    fig = load("kinematics_validation").main([*argv, "--out", str(tmp_path)])
    out, err = capsys.readouterr()
    assert err.count("pytorch-kinematics is not installed") == 1, err
    assert fig["ok"] and fig["results"]["arm7 float64"]["pk_version"] is None
    assert out.rstrip().endswith("PASS")
    assert "not installed" in (tmp_path / "kinematics_validation.txt").read_text()


@pytest.mark.slow
def test_rotation_regression(tmp_path, capsys):
    plot = tmp_path / "rotation_regression.png"
    fig = load("rotation_regression").main(["--quick", "--out", str(tmp_path)])
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
    saved = json.loads((tmp_path / "rotation_regression.json").read_text())
    assert saved["steps"] == fig["steps"]
    assert saved["results"]["6d"]["final_error_deg"] == res["6d"]["final_error_deg"]
    assert saved["results"]["rotvec"]["curve"][-1] == list(res["rotvec"]["curve"][-1])
    if has_matplotlib():
        assert fig["plot"] == plot and plot.stat().st_size > 1000
    else:
        assert fig["plot"] is None and not plot.exists()


def test_payload_identification(tmp_path, capsys):
    plot = tmp_path / "payload_identification.png"
    fig = load("payload_identification").main(["--quick", "--out", str(tmp_path)])
    assert fig["states"] == 200 and fig["true_mass_kg"] == 1.5
    # From no payload to the payload within the noise: mass to 0.5 %, position to 2 mm, the
    # torque residual down to the measurement noise (0.05 N m).
    h = fig["history"]
    assert h[0]["mass_kg"] == 0.0 and h[0]["rms_torque_residual_Nm"] >= 1.0
    assert fig["mass_error_rel"] <= 5e-3
    assert fig["com_error_m"] <= 2e-3
    assert fig["rms_torque_residual_Nm"] <= 1.1 * fig["noise_Nm"]
    assert "payload identification" in capsys.readouterr().out
    saved = json.loads((tmp_path / "payload_identification.json").read_text())
    assert saved["mass_kg"] == fig["mass_kg"] and saved["history"] == h
    if has_matplotlib():
        assert fig["plot"] == str(plot) and plot.stat().st_size > 1000
    else:
        assert fig["plot"] is None and not plot.exists()


@pytest.mark.slow
def test_distributed_training(tmp_path):
    # a subprocess, as users start it: the spawned ranks import the script as their main module
    script = EXAMPLES / "distributed_training.py"
    path = [str(EXAMPLES.parent), os.environ.get("PYTHONPATH", "")]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in path if p)}
    run = subprocess.run(
        [sys.executable, str(script), "--quick", "--backend", "gloo", "--world-size", "2"]
        + ["--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,  # a hang fails the test
        env=env,
    )
    assert run.returncode == 0, run.stderr
    fig = json.loads((tmp_path / "distributed_training.json").read_text())
    assert fig["world_size"] == 2 and fig["backend"] == "gloo" and fig["steps"] == 300
    assert fig["replicas_identical"]
    # an untrained network is about as wrong as a random rotation (mean 126.5 degrees)
    assert 90.0 <= fig["initial_rotation_error_deg"] <= 160.0
    # 300 steps: a few degrees (4.6 at seed 0), the translation error down 10x
    assert fig["final_rotation_error_deg"] <= 8.0
    assert fig["final_translation_error"] <= fig["initial_translation_error"] / 10
    assert len(fig["loss_curve"]) == 300
    assert fig["loss_curve"][-1][1] <= fig["loss_curve"][0][1] / 100
    assert f"final geodesic error: {fig['final_rotation_error_deg']:.2f} deg" in run.stdout
    plot = tmp_path / "distributed_training.png"
    if has_matplotlib():
        assert plot.stat().st_size > 1000
    else:
        assert not plot.exists() and "matplotlib is not installed" in run.stderr


@pytest.mark.slow
def test_pose_graph(tmp_path, capsys):
    fig = load("pose_graph").main(["--quick", "--out", str(tmp_path)])
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
    saved = json.loads((tmp_path / "pose_graph.json").read_text())
    assert saved["cost_after"] == fig["cost_after"] and saved["poses"] == 100
    plot = tmp_path / "pose_graph.png"
    if has_matplotlib():
        assert fig["plot"] == plot and plot.stat().st_size > 1000
    else:
        assert fig["plot"] is None and not plot.exists()


@pytest.mark.slow
def test_planar_pose_graph(tmp_path, capsys):
    fig = load("planar_pose_graph").main(["--quick", "--out", str(tmp_path)])
    assert fig["poses"] == 120 and fig["loop_closures"] > 0
    # the maximum-likelihood poses fit the noisy measurements better than the ground truth
    assert fig["cost_before"] / fig["cost_after"] >= 50
    assert fig["cost_after"] <= fig["cost_ground_truth"]
    assert fig["position_rmse_after"] <= fig["position_rmse_before"] / 4
    assert fig["heading_error_deg_after"] <= fig["heading_error_deg_before"]
    assert fig["valid"]
    assert "before (odometry)" in capsys.readouterr().out
    saved = json.loads((tmp_path / "planar_pose_graph.json").read_text())
    assert saved["cost_after"] == fig["cost_after"]
    plot = tmp_path / "planar_pose_graph.png"
    if has_matplotlib():
        assert fig["plot"] == plot and plot.stat().st_size > 1000
    else:
        assert fig["plot"] is None and not plot.exists()


@pytest.mark.slow
def test_inverse_kinematics(tmp_path, capsys):
    fig = load("inverse_kinematics").main(["--quick", "--out", str(tmp_path)])
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
    plot = tmp_path / "convergence.png"
    if has_matplotlib():
        assert fig["plot"] is not None and plot.stat().st_size > 1000
    else:
        assert fig["plot"] is None and not plot.exists()


def test_inverse_kinematics_default_out_and_no_plot(tmp_path, monkeypatch):
    # the default folder is the examples' own, wherever the script is run from
    monkeypatch.chdir(tmp_path)
    module = load("inverse_kinematics")
    assert module.main.__globals__["OUT"] == EXAMPLES / "out"
    fig = module.main(["--targets", "4", "--restarts", "1", "--max-iterations", "2", "--no-plot"])
    assert fig["plot"] is None and not any(tmp_path.iterdir())


@pytest.mark.slow
def test_kinematics_validation(tmp_path, capsys):
    fig = load("kinematics_validation").main(["--quick", "--brief", "--out", str(tmp_path)])
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
    # --brief prints only the summary; the full reports are in the --out folder
    reports = (tmp_path / "kinematics_validation.txt").read_text()
    assert "Jacobian of end link" not in out
    assert reports.count("Jacobian of end link") == 2 and reports.count("PASS: all 12") == 2
    assert json.loads((tmp_path / "kinematics_validation.json").read_text()) == {
        "ok": True,
        "samples": 200,
        "results": res,
    }


@pytest.mark.slow
def test_scaled_alignment(tmp_path, capsys):
    fig = load("scaled_alignment").main(["--quick", "--out", str(tmp_path)])
    assert fig["poses"] == 60 and fig["valid"]
    # the similarity is recovered: scale within 1 %, errors down to the noise level
    assert abs(fig["scale_refined"] / fig["scale_true"] - 1.0) < 0.01
    assert fig["ate_before"] > 1.0 and fig["ate_umeyama"] < 3 * fig["noise"] * fig["scale_true"]
    assert fig["ate_refined"] <= fig["ate_umeyama"] * 1.05
    assert fig["rot_error_deg_refined"] <= fig["rot_error_deg_umeyama"] + 1e-9
    assert fig["rot_error_deg_refined"] < 3.0 < fig["rot_error_deg_before"]
    assert "Umeyama (positions)" in capsys.readouterr().out
    saved = json.loads((tmp_path / "scaled_alignment.json").read_text())
    assert saved["ate_refined"] == fig["ate_refined"]
    plot = tmp_path / "scaled_alignment.png"
    if has_matplotlib():
        assert fig["plot"] == plot and plot.stat().st_size > 1000
    else:
        assert fig["plot"] is None and not plot.exists()
