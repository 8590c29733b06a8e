"""The README's speed table from two runs of ``benchmarks/run.py``: one under glibc's default
allocator (``fwd`` and ``fwd+bwd``) and one with ``--malloc reuse`` (``fwd``), both at
N = 10^6, one thread, without compile::

    python benchmarks/run.py --sizes 1000000 --no-compile --no-kinematics --out out/default
    python benchmarks/run.py --sizes 1000000 --no-compile --no-kinematics --modes fwd \\
        --malloc reuse --out out/reuse
    python benchmarks/readme_table.py out/default/results.json out/reuse/results.json

Cells: torchlie's ns per element, in parentheses the fastest peer's time over torchlie's (above
1: torchlie faster) and that peer; the copy floor of the default run, then of the reuse run.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks import peers as _peers  # noqa: E402
from benchmarks.run import Table, _fmt, _torch_peers, fastest_peer  # noqa: E402


def _ns(seconds: float | None, n: int) -> str:
    return "–" if seconds is None else _fmt(seconds * 1e9 / n)


def _cell(tab: Table, peers: list[str], op: str, dtype: str, mode: str, n: int, named: bool) -> str:
    tl = tab.get(op, dtype, mode, n, "torchlie")
    if tl is None:
        return "–"
    best, t = fastest_peer(tab, peers, op, dtype, mode, n)
    if t is None:
        return _ns(tl, n)
    name = f" {_peers.SHORT.get(best, best)}" if named else ""
    return f"{_ns(tl, n)} ({t / tl:.2f}{name})"


def table(default: dict, reuse: dict | None, n: int = 1_000_000) -> str:
    """The markdown table at batch size ``n`` (one row per op of the default run, in its
    order)."""
    tab, peers = Table(default), _torch_peers(default)
    rtab = Table(reuse) if reuse else None
    rpeers = _torch_peers(reuse) if reuse else []
    ops = list(dict.fromkeys(r["op"] for r in default["records"]))
    head = ["op"]
    for dt in ("float32", "float64"):
        head += [f"{dt} fwd", "fwd+bwd", "copy floor", "fwd, reuse"]
    lines = ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    for op in ops:
        cells = [op]
        for dt in ("float32", "float64"):
            floor = tab.get(op, dt, "fwd", n, "floor")
            rfloor = rtab.get(op, dt, "fwd", n, "floor") if rtab else None
            cells += [
                _cell(tab, peers, op, dt, "fwd", n, True),
                _cell(tab, peers, op, dt, "fwd+bwd", n, True),
                f"{_ns(floor, n)} / {_ns(rfloor, n)}",
                _cell(rtab, rpeers, op, dt, "fwd", n, False) if rtab else "–",
            ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("default", type=Path, help="results.json of the default-allocator run")
    p.add_argument("reuse", type=Path, nargs="?", help="results.json of the --malloc reuse run")
    args = p.parse_args(argv)
    default = json.loads(args.default.read_text())
    reuse = json.loads(args.reuse.read_text()) if args.reuse else None
    print(table(default, reuse))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
