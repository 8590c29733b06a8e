"""The benchmark suite compares like with like, and its one command runs.

* every op's reference (``benchmarks/ops.py``) agrees with torchlie on the benchmark inputs;
* every installed peer's adapter (``benchmarks/peers.py``) returns the same values as torchlie on
  the same elements (float64 and float32), and its backward reaches every input;
* ``benchmarks/run.py --quick`` runs on a tiny configuration in a subprocess and writes its
  markdown and JSON; the target bookkeeping is checked on synthetic timings.

Agreement tolerance: ``sqrt(eps)`` of the dtype (the check is about conventions: a wrong
quaternion order, transpose or sign is an O(1) difference; precision is tested elsewhere).
"""

from __future__ import annotations

import importlib.util
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks import ops as bops  # noqa: E402
from benchmarks import peers as bpeers  # noqa: E402
from benchmarks import run as brun  # noqa: E402

N_CHECK = 16
DTYPES = [torch.float64, torch.float32]


def _tol(dtype: torch.dtype) -> float:
    return math.sqrt(torch.finfo(dtype).eps)


def _cases() -> list[tuple[str, str]]:
    return [(name, a.peer) for name in bops.OPS for a in bpeers.adapters(name)]


def _adapter(op: str, peer: str) -> bpeers.Adapter:
    (a,) = bpeers.adapters(op, (peer,))
    return a


@pytest.mark.parametrize("name", list(bops.OPS))
@pytest.mark.parametrize("dtype", DTYPES, ids=["f64", "f32"])
def test_torchlie_matches_reference(name: str, dtype: torch.dtype) -> None:
    op = bops.OPS[name]
    fn = op.torchlie()
    assert fn is not None, f"torchlie.{op.target} is missing"
    xs = op.inputs(N_CHECK, dtype, torch.Generator().manual_seed(7))
    ref = op.reference(*(x.to(torch.float64) for x in xs))
    got = fn(*xs)
    assert got.dtype == dtype
    assert float(bops.close(got, ref, op.compare)) <= _tol(dtype)


@pytest.mark.parametrize(("name", "peer"), _cases())
@pytest.mark.parametrize("dtype", DTYPES, ids=["f64", "f32"])
def test_peer_agrees_with_torchlie(name: str, peer: str, dtype: torch.dtype) -> None:
    op = bops.OPS[name]
    a = _adapter(name, peer)
    xs = op.inputs(N_CHECK, dtype, torch.Generator().manual_seed(11))
    expected = op.torchlie()(*xs)
    got = a.to_ours(a.fn(*a.prepare(*xs)))
    if not a.reference:
        assert got.dtype == dtype, "the peer must compute in the benchmarked dtype"
    assert float(bops.close(got, expected, op.compare)) <= _tol(dtype)


@pytest.mark.parametrize(("name", "peer"), [c for c in _cases() if _adapter(*c).differentiable])
def test_peer_backward_reaches_every_input(name: str, peer: str) -> None:
    op = bops.OPS[name]
    a = _adapter(name, peer)
    xs = op.inputs(N_CHECK, torch.float64, torch.Generator().manual_seed(3))
    leaves = brun._leaves(a.prepare(*xs), grad=True)
    grads = brun.make_step(a.fn, leaves, "fwd+bwd")()
    assert len(grads) == len(leaves)
    for g, x in zip(grads, leaves, strict=True):
        assert g is not None and g.shape == x.shape
        assert torch.isfinite(g).all() and g.abs().sum() > 0


def test_floor_sizes_follow_the_op() -> None:
    # so3.exp: 3 numbers in, 9 out per element.
    op = bops.OPS["so3.exp"]
    assert (op.in_numbers(), op.out_numbers) == (3, 9)
    assert bops.OPS["se3.compose"].in_numbers() == 32
    xs = op.inputs(8, torch.float32)
    assert brun.floor_shapes(op, xs, grad=False) == [(8, 3), (8, 9)]
    assert brun.floor_shapes(op, xs, grad=True) == [(8, 3), (8, 9)] * 2
    outs = brun.floor_step([(8, 3), (8, 9)], torch.float32)()
    assert [o.shape for o in outs] == [(8, 3), (8, 9)]


def test_warm_up_stops_at_calls_or_time() -> None:
    calls = []
    assert brun.warm_up(lambda: calls.append(1), seconds=60.0, max_calls=5) == 5
    assert len(calls) == 5
    # One call at least, even with no time to spend; time ends it before the call cap.
    assert brun.warm_up(lambda: None, seconds=0.0, max_calls=5) == 1
    n = brun.warm_up(lambda: time.sleep(0.02), seconds=0.05, max_calls=100)
    assert 2 <= n <= 4


def test_cells_are_timed_in_rounds() -> None:
    args = brun.parse_args(["--quick", "--rounds", "3", "--min-time", "0.001"])
    records: list[dict] = []
    cell = brun._Cell(records, args, op="so3.exp", dtype="float32", mode="fwd", n=1)
    calls = {"ok": 0, "bad": 0}

    def ok() -> None:
        calls["ok"] += 1

    def bad() -> None:
        calls["bad"] += 1
        raise RuntimeError("no such op")

    cell.time_all([("torchlie", "fn", ok, {}), ("roma", "peer", bad, {"x": 1})])
    good, err = records
    assert good["impl"] == "torchlie" and len(good["round_medians_s"]) == 3
    assert good["median_s"] == min(good["round_medians_s"]) > 0
    assert good["runs"] >= 3 and calls["ok"] > 3
    # An implementation that fails is recorded with its error and not called again.
    assert err["impl"] == "roma" and err["error"] == "RuntimeError: no such op"
    assert "median_s" not in err and calls["bad"] == 1
    assert brun.parse_args(["--quick"]).rounds == 1 and brun.parse_args([]).rounds == 3


def _synthetic(tl: float, peer: float, compiled: float, floor: float) -> dict:
    records = []
    for n in (1, 1000):
        for impl, t in (("floor", floor), ("torchlie", tl), ("compiled", compiled), ("roma", peer)):
            records.append({"op": "so3.exp", "dtype": "float32", "mode": "fwd", "n": n,
                            "impl": impl, "median_s": t * n})  # fmt: skip
    args = {"ops": ["so3.exp"], "sizes": [1, 1000], "dtypes": ["float32"], "modes": ["fwd"]}
    return {"records": records, "args": args}


def test_targets_bookkeeping() -> None:
    met = _synthetic(tl=1.0, peer=2.5, compiled=2.0, floor=1.0)
    rows = brun.targets(met, brun.Table(met), ["roma"])
    assert rows[-2] == "| met | 1/1 | 1/1 | 1/1 |"
    assert "| so3.exp | 2.50x yes | 2.50x yes | 2.00x yes |" in rows
    missed = _synthetic(tl=1.0, peer=1.5, compiled=3.5, floor=1.0)
    rows = brun.targets(missed, brun.Table(missed), ["roma"])
    assert "| so3.exp | 1.50x NO | 1.50x NO | 3.50x NO |" in rows
    assert rows[-2] == "| met | 0/1 | 0/1 | 0/1 |"


def test_readme_table() -> None:
    from benchmarks import readme_table

    def records(tl: float, peer: float) -> list[dict]:
        return [
            {"op": "so3.exp", "dtype": dt, "mode": mode, "n": 10, "impl": impl, "median_s": t}
            for dt in ("float32", "float64")
            for mode in ("fwd", "fwd+bwd")
            for impl, t in (("floor", 1e-8), ("torchlie", tl), ("roma", peer))
        ]

    default = {"records": records(1e-7, 2e-7)}
    reuse = {"records": records(2e-7, 3e-7)}
    row = "| so3.exp | 10.0 (2.00 roma) | 10.0 (2.00 roma) | 1.00 / 1.00 | 20.0 (1.50) |"
    assert readme_table.table(default, reuse, n=10).splitlines()[2].startswith(row)


def _run(tmp_path: Path, *extra: str) -> dict:
    cmd = [sys.executable, str(ROOT / "benchmarks" / "run.py"), "--quick", "--out", str(tmp_path),
           "--no-plot", *extra]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert (tmp_path / "results.md").read_text() in proc.stdout
    return json.loads((tmp_path / "results.json").read_text())


def test_reuse_allocator_is_set_and_labelled_when_asked(tmp_path: Path) -> None:
    result = _run(tmp_path, "--ops", "so3.exp", "--sizes", "8", "--no-compile", "--malloc", "reuse")
    assert result["meta"]["malloc"] == brun.MALLOC_ENV
    assert result["meta"]["malloc_setting"] == "reuse"
    assert "allocator reuse" in (tmp_path / "results.md").read_text()


def test_quick_run(tmp_path: Path) -> None:
    ops = ["so3.exp", "se3.act"]
    result = _run(tmp_path, "--ops", ",".join(ops), "--sizes", "1,8", "--no-compile")
    assert result["meta"]["omp_wait_policy"] == "PASSIVE"
    # the default is the environment a user's process has; the reuse setting only on request
    assert result["meta"]["malloc_setting"] == "default"
    assert "allocator default" in (tmp_path / "results.md").read_text()
    assert result["meta"]["threads"] == 1
    assert result["check_failures"] == []
    timed = {
        (r["op"], r["impl"], r["mode"], r["n"])
        for r in result["records"]
        if r.get("median_s", 0) > 0
    }
    for name in ops:
        impls = ["floor", "torchlie"] + [a.peer for a in bpeers.adapters(name)]
        for impl in impls:
            for mode in ("fwd", "fwd+bwd"):
                if impl == "scipy" and mode == "fwd+bwd":
                    continue
                for n in (1, 8):
                    assert (name, impl, mode, n) in timed
    floors = {(r["op"], r["mode"], r["n"]): r["call"] for r in result["records"]
              if r["impl"] == "floor"}  # fmt: skip
    assert floors[("so3.exp", "fwd", 8)] == "clone of 96 numbers in 2 tensors"
    assert floors[("so3.exp", "fwd+bwd", 8)] == "clone of 192 numbers in 4 tensors"
    md = (tmp_path / "results.md").read_text()
    assert "## float32, fwd+bwd" in md and "## Targets" in md


@pytest.mark.compile
@pytest.mark.slow
def test_quick_run_compiled(tmp_path: Path) -> None:
    result = _run(tmp_path, "--ops", "so3.exp", "--sizes", "8", "--modes", "fwd", "--peers",
                  "roma", "--compile")  # fmt: skip
    (rec,) = [r for r in result["records"] if r["impl"] == "compiled"]
    assert "error" not in rec
    assert rec["first_call_s"] > rec["median_s"] > 0


def test_inverse_kinematics_table() -> None:
    """``run.py``'s kinematics section also runs ``bench_ik.py`` (here ``--quick``: 100 targets
    per robot, one timed call): a row per solver and robot, torchlie's with pk's speed-ups."""
    args = brun.parse_args(["--quick"])
    kin = brun.kinematics(args, log=lambda s: None, script=brun.INVERSE_KINEMATICS)
    assert kin["rc"] == 0, kin["output"]
    assert kin["command"] == "python benchmarks/bench_ik.py"
    rows = [line.split(" | ") for line in kin["output"].splitlines() if line.startswith("| ")]
    have_pk = importlib.util.find_spec("pytorch_kinematics") is not None
    for robot in ("arm7", "panda", "tree"):
        ours = [r for r in rows if r[0].startswith(f"| {robot} ") and "torchlie" in r[1]]
        assert len(ours) == 2  # the fixed budget and early_exit
        for r in ours:
            assert float(r[2].rstrip("%")) >= 95.0  # solved
            assert r[-1].rstrip(" |").endswith("x") == have_pk  # speed-ups against pk
