"""Benchmark torchlie against its peers, side by side, in one process on the same inputs.

Usage (from the repository root)::

    python benchmarks/run.py                      # full run: N in {1, 1e3, 1e6}, float32/64
    python benchmarks/run.py --quick              # smoke test: tiny sizes, short timings
    python benchmarks/run.py --ops so3.exp,so3.log --sizes 1000000 --dtypes float32

What is measured, for every op, mode (``fwd``; ``fwd+bwd`` = forward then
``torch.autograd.grad`` of all inputs against a fixed random output gradient), dtype and N:

* ``floor``: ``clone()`` of one contiguous buffer shaped like each input of the op and one
  holding its output's numbers (``N * (in + out)`` numbers in all; the same again for
  ``fwd+bwd``, whose backward reads the output gradient and writes the input gradients).  A
  clone reads and writes each of those bytes once: the time of touching the op's data, with
  no arithmetic and one dispatch per tensor.
* ``torchlie``: the eager function; ``compiled``: the function of ``torchlie.compiled``, i.e.
  ``torch.compile(fn, fullgraph=True, options=torchlie.compiled.inductor_options(...))`` (mode
  default; the options vectorise Inductor's CPU loops), with the first call's time
  (compilation included) recorded per N; the compile cache
  is reset per (op, dtype, mode), so N = 1 compiles a static graph and the next N recompiles
  with a dynamic batch size that the larger N reuse.
* every installed peer through the adapters of ``benchmarks/peers.py``; each adapter's output is
  first checked against torchlie's on the same inputs (float64, N = 16), and a peer that
  disagrees is reported and not timed.

Timings: ``torch.utils.benchmark.Timer.blocked_autorange`` (median of blocks) with
``--threads`` threads (one by default), on the calling thread's CPU time by default (``--clock``):
on a machine whose cores are shared, wall-clock medians measure the other processes.  All the
implementations of one cell (op, dtype, mode, N: floor, torchlie, compiled, peers) are timed in
turn, ``--rounds`` times over (3 by default), and each reports the least of its rounds' medians
(all kept in the JSON): on a shared machine a slow phase otherwise lands on whichever
implementation is being timed and skews its ratios.

Environment: run as a script, this file re-executes itself once with

* ``OMP_WAIT_POLICY=PASSIVE`` (OpenMP threads sleep instead of spinning: oversubscribed runs
  otherwise stall for milliseconds);
* with ``--malloc reuse`` only: ``MALLOC_MMAP_THRESHOLD_=4294967296
  MALLOC_TRIM_THRESHOLD_=68719476736``, so that glibc keeps freed memory for reuse (as
  PyTorch's CUDA caching allocator does) and N = 1e6 timings are of arithmetic and memory
  traffic alone.  The default (``--malloc default``) is the environment a user's process has:
  with glibc's own thresholds a result of 32 MB or more is a fresh ``mmap`` whose pages are
  faulted in on first touch, for the ops and the copy floor alike (``clone()`` allocates its
  result as the ops do).  Every table says which setting it was measured under.

Output (``--out``, default ``benchmarks/results``): ``results.md`` (also printed), ``results.json``
(every measurement and the machine; rewritten after every op, so an interrupted run keeps what
it measured), and ``results.png`` when matplotlib is importable.
"""

from __future__ import annotations

import os
import sys

ENV = {"OMP_WAIT_POLICY": "PASSIVE"}
MALLOC_ENV = {"MALLOC_MMAP_THRESHOLD_": "4294967296", "MALLOC_TRIM_THRESHOLD_": "68719476736"}
_REEXEC_FLAG = "TORCHLIE_BENCH_REEXEC"


def _wanted_env(argv: list[str]) -> dict[str, str]:
    reuse = "--malloc=reuse" in argv or any(
        a == "--malloc" and b == "reuse" for a, b in zip(argv, argv[1:], strict=False)
    )
    return {**ENV, **(MALLOC_ENV if reuse else {})}


if __name__ == "__main__" and "torch" not in sys.modules:
    _missing = {k: v for k, v in _wanted_env(sys.argv[1:]).items() if os.environ.get(k) != v}
    if _missing and os.environ.get(_REEXEC_FLAG) != "1":
        os.environ.update(_missing)
        os.environ[_REEXEC_FLAG] = "1"
        sys.stdout.flush()
        os.execv(sys.executable, [sys.executable, os.path.abspath(__file__), *sys.argv[1:]])

_OMP_BEFORE = os.environ.get("OMP_WAIT_POLICY")
if "torch" not in sys.modules:
    os.environ["OMP_WAIT_POLICY"] = "PASSIVE"  # must precede the first import of torch
if __name__ == "__main__" and "--compile-cache" not in sys.argv:
    # A fresh compile cache: the first-call times are those of a cold compilation.
    import atexit
    import shutil
    import tempfile

    _CACHE = tempfile.mkdtemp(prefix="torchlie-bench-inductor-")
    os.environ["TORCHINDUCTOR_CACHE_DIR"] = _CACHE
    atexit.register(shutil.rmtree, _CACHE, ignore_errors=True)

import argparse  # noqa: E402
import datetime  # noqa: E402
import gc  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import subprocess  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

_TORCH_PREIMPORTED = "torch" in sys.modules and _OMP_BEFORE != "PASSIVE"

import torch  # noqa: E402
import torch.utils.benchmark as tbench  # noqa: E402

from benchmarks import ops as _ops  # noqa: E402
from benchmarks import peers as _peers  # noqa: E402
from torchlie.compiled import inductor_options  # noqa: E402

DTYPES = {"float32": torch.float32, "float64": torch.float64}
MODES = ("fwd", "fwd+bwd")
CHECK_N = 16
# float64 agreement of every adapter with torchlie: half the digits (a convention slip is O(1))
CHECK_ATOL = math.sqrt(torch.finfo(torch.float64).eps)
LEFT_OUT = {
    "theseus torchlie": "published under the import name `torchlie`: cannot share a process "
    "with this package",
    "pytorch3d": "no wheel on PyPI for this torch (`pip download --no-deps pytorch3d` finds none)",
    "lietorch": "needs a CUDA build",
    "jaxlie": "JAX, not torch",
}


# ----------------------------------------------------------------------------------------------
# Arguments
# ----------------------------------------------------------------------------------------------


def _csv(s: str) -> list[str]:
    return [x.strip() for x in s.split(",") if x.strip()]


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    p.add_argument("--sizes", type=str, default=None, help="batch sizes N, e.g. 1,1000,1000000")
    p.add_argument("--dtypes", type=str, default=None, help="float32,float64")
    p.add_argument("--ops", type=str, default=None, help="ops, e.g. so3.exp,se3.log (default all)")
    p.add_argument("--modes", type=str, default=None, help="fwd,fwd+bwd")
    p.add_argument("--peers", type=str, default=None, help="peers to include (default all)")
    p.add_argument("--quick", action="store_true", help="tiny sizes, short timings (smoke test)")
    p.add_argument(
        "--compile",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="also time torch.compile(fullgraph=True) (default: on, off with --quick)",
    )
    p.add_argument(
        "--min-time", type=float, default=None, help="seconds per measurement (per round)"
    )
    p.add_argument(
        "--rounds",
        type=int,
        default=None,
        help="times every implementation of a cell is measured, in turn (default 3, 1 with "
        "--quick); the least of the rounds' medians is reported",
    )
    p.add_argument(
        "--compile-cache",
        action="store_true",
        help="use torch's on-disk compile caches (default: a fresh cache, i.e. cold compiles)",
    )
    p.add_argument(
        "--clock",
        choices=("cpu", "wall"),
        default=None,
        help="cpu: the thread's CPU time (default with one thread: immune to other processes "
        "sharing the cores); wall: perf_counter (default with several threads)",
    )
    p.add_argument(
        "--malloc",
        choices=("default", "reuse"),
        default="default",
        help="default: glibc's own thresholds, as in a user's process; reuse: glibc keeps "
        "freed memory (set by the re-exec, see the module docstring)",
    )
    p.add_argument("--out", type=str, default=str(ROOT / "benchmarks" / "results"))
    p.add_argument("--no-plot", action="store_true", help="skip the PNG")
    p.add_argument(
        "--kinematics",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="also run benchmarks/bench_kinematics.py (forward kinematics) and "
        "benchmarks/bench_ik.py (inverse kinematics), both against pytorch-kinematics, and "
        "append their tables (default: on, off with --quick)",
    )
    args = p.parse_args(argv)
    if args.sizes is None:
        args.sizes = "1,64" if args.quick else "1,1000,1000000"
    if args.dtypes is None:
        args.dtypes = "float32" if args.quick else "float32,float64"
    if args.compile is None:
        args.compile = not args.quick
    if args.rounds is None:
        args.rounds = 1 if args.quick else 3
    if args.rounds < 1:
        p.error("--rounds must be at least 1")
    if args.kinematics is None:
        args.kinematics = not args.quick
    if args.clock is None:
        args.clock = "cpu" if args.threads == 1 else "wall"
    if args.clock == "cpu" and args.threads != 1:
        p.error("--clock cpu measures the calling thread only: use it with --threads 1")
    args.sizes = [int(float(s)) for s in _csv(args.sizes)]
    args.dtypes = _csv(args.dtypes)
    args.ops = _csv(args.ops) if args.ops else list(_ops.OPS)
    args.modes = _csv(args.modes) if args.modes else list(MODES)
    args.peers = tuple(_csv(args.peers)) if args.peers else _peers.PEERS
    for d in args.dtypes:
        if d not in DTYPES:
            p.error(f"unknown dtype {d!r} (choose from {', '.join(DTYPES)})")
    for o in args.ops:
        if o not in _ops.OPS:
            p.error(f"unknown op {o!r} (choose from {', '.join(_ops.OPS)})")
    for m in args.modes:
        if m not in MODES:
            p.error(f"unknown mode {m!r} (choose from {', '.join(MODES)})")
    for peer in args.peers:
        if peer not in _peers.PEERS:
            p.error(f"unknown peer {peer!r} (choose from {', '.join(_peers.PEERS)})")
    return args


def min_time(args: argparse.Namespace, n: int) -> float:
    if args.min_time is not None:
        return args.min_time
    if args.quick:
        return 0.01
    return 0.25 if n >= 100_000 else 0.1


# ----------------------------------------------------------------------------------------------
# Machine description
# ----------------------------------------------------------------------------------------------


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _mem_gib() -> float | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal"):
                return round(int(line.split()[1]) / 2**20, 1)
    except OSError:
        pass
    return None


def _git() -> str | None:
    try:
        rev = subprocess.run(
            ["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
            capture_output=True, text=True, timeout=10, check=True,
        ).stdout.strip()  # fmt: skip
        dirty = subprocess.run(
            ["git", "-C", str(ROOT), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True, text=True, timeout=10, check=True,
        ).stdout.strip()  # fmt: skip
        return rev + ("+dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return None


def machine(args: argparse.Namespace) -> dict:
    import torchlie

    load = os.getloadavg() if hasattr(os, "getloadavg") else None
    return {
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "cpu": _cpu_model(),
        "cores": os.cpu_count(),
        "memory_gib": _mem_gib(),
        "os": platform.platform(),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "cuda": torch.cuda.is_available(),
        "threads": args.threads,
        "omp_wait_policy": os.environ.get("OMP_WAIT_POLICY"),
        "malloc": {k: os.environ.get(k) for k in MALLOC_ENV},
        "malloc_setting": malloc_setting(),
        "compile_cache": "on-disk caches" if args.compile_cache else "fresh (cold compiles)",
        "clock": {"cpu": "thread CPU time (time.thread_time)", "wall": "wall clock (perf_counter)"}[
            args.clock
        ],
        "torchlie": getattr(torchlie, "__version__", "?"),
        "git": _git(),
        "peers": _peers.available(),
        "left_out": LEFT_OUT,
        "loadavg_start": load,
        "command": "python benchmarks/run.py " + " ".join(sys.argv[1:]),
    }


# ----------------------------------------------------------------------------------------------
# Measurement
# ----------------------------------------------------------------------------------------------


CLOCKS = {"cpu": time.thread_time, "wall": time.perf_counter}


def warm_up(fn, seconds: float, max_calls: int = 12) -> int:
    """Call ``fn`` until ``seconds`` have passed or ``max_calls`` calls were made (at least one).

    The first few calls that touch a fresh large output (new inputs, a just-compiled kernel) run
    at page-fault speed on some machines (several times slower for 5-10 calls); timing starts
    after them.
    """
    calls, t0 = 0, time.perf_counter()
    while calls < max_calls and (calls == 0 or time.perf_counter() - t0 < seconds):
        fn()
        calls += 1
    return calls


def timeit(fn, seconds: float, threads: int, clock: str = "wall", warm_calls: int = 12) -> dict:
    warm_up(fn, seconds, warm_calls)
    t = tbench.Timer(stmt="fn()", globals={"fn": fn}, num_threads=threads, timer=CLOCKS[clock])
    m = t.blocked_autorange(min_run_time=seconds)
    return {"median_s": m.median, "iqr_s": m.iqr, "runs": len(m.times)}


def _leaves(args: tuple, grad: bool) -> tuple:
    out = []
    for a in args:
        if isinstance(a, torch.Tensor) and a.is_floating_point():
            a = a.detach().contiguous()
            if grad:
                a.requires_grad_(True)
        out.append(a)
    return tuple(out)


def make_step(fn, args: tuple, mode: str):
    """The timed closure: ``fn(*args)``, or forward then ``autograd.grad`` of every input."""
    if mode == "fwd":
        return lambda: fn(*args)
    leaves = [a for a in args if isinstance(a, torch.Tensor) and a.requires_grad]
    gen = torch.Generator().manual_seed(1)
    outs = _peers.outputs(fn(*args))
    grads = [torch.randn(o.shape, dtype=o.dtype, generator=gen) for o in outs]

    def step():
        o = _peers.outputs(fn(*args))
        return torch.autograd.grad(o, leaves, grads, allow_unused=True)

    return step


def floor_step(shapes: list[tuple[int, ...]], dtype: torch.dtype):
    """``clone()`` of one buffer per shape (the op's inputs and outputs): no arithmetic."""
    bufs = [torch.randn(s, dtype=dtype) for s in shapes]
    return lambda: [b.clone() for b in bufs]


def floor_shapes(op: _ops.Op, xs: tuple, grad: bool) -> list[tuple[int, ...]]:
    """The op's input shapes and its output's ``(N, out_numbers)``; twice for ``fwd+bwd``."""
    shapes = [tuple(x.shape) for x in xs] + [(xs[0].shape[0], op.out_numbers)]
    return shapes * (2 if grad else 1)


def check_adapters(op: _ops.Op, adapters: list, log) -> tuple[list, list[dict]]:
    """Keep the adapters whose float64 output agrees with torchlie's (or the reference's)."""
    xs = op.inputs(CHECK_N, torch.float64, torch.Generator().manual_seed(123))
    fn = op.torchlie()
    expected = fn(*xs) if fn is not None else op.reference(*xs)
    kept, failures = [], []
    for a in adapters:
        try:
            got = a.to_ours(a.fn(*a.prepare(*xs)))
            err = float(_ops.close(got, expected, op.compare))
        except Exception as e:  # a peer that cannot run this op is reported, not fatal
            err, msg = math.inf, f"{type(e).__name__}: {e}"
        else:
            msg = f"max |difference| {err:.2e}"
        if err <= CHECK_ATOL:
            kept.append(a)
        else:
            failures.append({"op": op.name, "peer": a.peer, "call": a.call, "error": msg})
            log(f"  ! {a.peer} {a.call}: disagrees with torchlie ({msg}); not timed")
    return kept, failures


class _Cell:
    """Measurements of one (op, dtype, mode, N): appends records to a shared list."""

    def __init__(self, records: list[dict], args: argparse.Namespace, **base) -> None:
        self.records, self.args, self.base = records, args, base
        self.seconds = min_time(args, base["n"])

    def add(self, impl: str, call: str, res: dict, **extra) -> dict:
        rec = {**self.base, "impl": impl, "call": call, **res, **extra}
        if "median_s" in rec:
            rec["ns_per_el"] = rec["median_s"] / self.base["n"] * 1e9
            rec["us_per_call"] = rec["median_s"] * 1e6
        self.records.append(rec)
        return rec

    def time_all(self, entries: list[tuple[str, str, object, dict]]) -> None:
        """Time every ``(impl, call, step, extra)`` in turn, ``--rounds`` times over.

        Each round times each implementation once (``timeit``: warm-up, then the median of
        ``blocked_autorange``); the recorded median is the least of the rounds' medians, and
        every round's median is kept (``round_medians_s``).  A slow phase of the machine then
        has to cover the same implementation in every round to bias its figure, instead of
        whichever implementation it happened to fall on.  An exception is recorded as that
        implementation's error (and it is not timed again).
        """
        rounds: list[list[dict]] = [[] for _ in entries]
        errors: dict[int, str] = {}
        for k in range(self.args.rounds):
            # The first round warms each step up fully (fresh outputs fault their pages in);
            # later ones find the memory mapped and need a couple of calls.
            warm_calls = 12 if k == 0 else 2
            for i, (_impl, _call, step, _extra) in enumerate(entries):
                if i in errors:
                    continue
                try:
                    res = timeit(step, self.seconds, self.args.threads, self.args.clock, warm_calls)
                    rounds[i].append(res)
                except Exception as e:
                    errors[i] = f"{type(e).__name__}: {e}"[:300]
        for i, (impl, call, _step, extra) in enumerate(entries):
            if i in errors:
                self.add(impl, call, {}, error=errors[i])
                continue
            best = min(rounds[i], key=lambda r: r["median_s"])
            res = {
                **best,
                "runs": sum(r["runs"] for r in rounds[i]),
                "round_medians_s": [r["median_s"] for r in rounds[i]],
            }
            self.add(impl, call, res, **extra)


def run(args: argparse.Namespace, log=print, checkpoint=None) -> dict:
    """Measure everything ``args`` asks for; ``checkpoint(result)`` is called after every op."""
    torch.set_num_threads(args.threads)
    meta = machine(args)
    records: list[dict] = []
    failures: list[dict] = []
    calls: dict[str, dict[str, str]] = {}
    result = {
        "meta": meta,
        "records": records,
        "check_failures": failures,
        "calls": calls,
        "args": dict(vars(args)),
    }
    t_start = time.perf_counter()
    torch._dynamo.config.recompile_limit = max(torch._dynamo.config.recompile_limit, 16)

    for name in args.ops:
        op = _ops.OPS[name]
        tl = op.torchlie()
        adapters, bad = check_adapters(op, _peers.adapters(name, args.peers), log)
        failures += bad
        calls[name] = {a.peer: a.call for a in adapters}
        if tl is None:
            log(f"  ! torchlie.{op.target} does not exist: peers only")
        for dname in args.dtypes:
            dtype = DTYPES[dname]
            for mode in args.modes:
                grad = mode == "fwd+bwd"
                compiled, compile_error = None, None
                if tl is not None and args.compile:
                    torch._dynamo.reset()
                    module, _, fn_name = op.target.rpartition(".")
                    options = inductor_options(module, fn_name)
                    compiled = torch.compile(tl, fullgraph=True, options=options)
                for n in args.sizes:
                    cell = _Cell(records, args, op=name, dtype=dname, mode=mode, n=n)
                    xs = op.inputs(n, dtype, torch.Generator().manual_seed(n))
                    shapes = floor_shapes(op, xs, grad)
                    numbers = sum(math.prod(s) for s in shapes)
                    call = f"clone of {numbers} numbers in {len(shapes)} tensors"
                    entries = [("floor", call, floor_step(shapes, dtype), {})]
                    if tl is not None:
                        lx = _leaves(xs, grad)
                        tl_step = make_step(tl, lx, mode)
                        entries.append(("torchlie", "torchlie." + op.target, tl_step, {}))
                        if compiled is not None and compile_error is None:
                            call = f"torchlie.compiled.{op.target}"
                            try:
                                t0 = time.perf_counter()
                                step = make_step(compiled, lx, mode)
                                step()
                                first = time.perf_counter() - t0
                            except Exception as e:
                                compile_error = f"{type(e).__name__}: {str(e)[:300]}"
                                cell.add("compiled", call, {}, error=compile_error)
                                log(f"  ! compile failed for {name}: {compile_error}")
                            else:
                                entries.append(("compiled", call, step, {"first_call_s": first}))
                        del lx
                    for a in adapters:
                        if (a.max_n is not None and n > a.max_n) or (grad and not a.differentiable):
                            continue
                        try:
                            step = make_step(a.fn, _leaves(a.prepare(*xs), grad), mode)
                        except Exception as e:
                            cell.add(a.peer, a.call, {}, error=f"{type(e).__name__}: {e}"[:300])
                            log(f"  ! {a.peer} failed on {name} {dname} {mode} N={n}: {e}"[:300])
                            continue
                        entries.append((a.peer, a.call, step, {}))
                    cell.time_all(entries)
                    entries = tl_step = step = None
                    del xs
                    gc.collect()
                    elapsed = time.perf_counter() - t_start
                    log(f"[{elapsed:6.0f} s] " + _progress_line(records, cell.base))
        meta["loadavg_end"] = os.getloadavg() if hasattr(os, "getloadavg") else None
        meta["wall_s"] = round(time.perf_counter() - t_start, 1)
        if checkpoint is not None:
            checkpoint(result)
    return result


def _progress_line(records: list[dict], base: dict) -> str:
    rows = [r for r in records if all(r[k] == v for k, v in base.items())]
    parts = []
    for r in rows:
        if "median_s" in r:
            v = r["us_per_call"] if base["n"] == 1 else r["ns_per_el"]
            parts.append(f"{_peers.SHORT.get(r['impl'], r['impl'])} {_fmt(v)}")
        else:
            parts.append(f"{r['impl']} error")
    unit = "us/call" if base["n"] == 1 else "ns/el"
    head = f"{base['op']:<17} {base['dtype']} {base['mode']:<7} N={base['n']:<8} [{unit}]"
    return head + "  " + ", ".join(parts)


# ----------------------------------------------------------------------------------------------
# Report
# ----------------------------------------------------------------------------------------------


def _fmt(v: float | None) -> str:
    if v is None or not math.isfinite(v):
        return "-"
    if v >= 100:
        return f"{v:.0f}"
    if v >= 10:
        return f"{v:.1f}"
    return f"{v:.2f}"


def _ratio(v: float | None) -> str:
    if v is None or not math.isfinite(v):
        return "-"
    return f"{v:.2f}x" if v < 10 else f"{v:.1f}x"


def _n_label(n: int) -> str:
    if n >= 1000 and math.log10(n).is_integer():
        return f"1e{int(math.log10(n))}"
    return str(n)


class Table:
    """Index of the records: ``value(op, dtype, mode, n, impl)`` in seconds per call."""

    def __init__(self, result: dict):
        self.idx = {}
        for r in result["records"]:
            key = (r["op"], r["dtype"], r["mode"], r["n"], r["impl"])
            self.idx[key] = r

    def get(self, *key) -> float | None:
        r = self.idx.get(key)
        return r.get("median_s") if r else None

    def rec(self, *key) -> dict | None:
        return self.idx.get(key)


def _torch_peers(result: dict) -> list[str]:
    seen = []
    for r in result["records"]:
        if r["impl"] in _peers.PEERS and r["impl"] not in seen:
            seen.append(r["impl"])
    return [p for p in _peers.PEERS if p in seen]


def fastest_peer(tab: Table, peers: list[str], *key) -> tuple[str | None, float | None]:
    best, best_t = None, None
    for p in peers:
        if p in _peers.REFERENCE_PEERS:
            continue
        t = tab.get(*key, p)
        if t is not None and (best_t is None or t < best_t):
            best, best_t = p, t
    return best, best_t


def malloc_setting() -> str:
    """``reuse`` where this process has :data:`MALLOC_ENV`, else ``default``."""
    return "reuse" if all(os.environ.get(k) == v for k, v in MALLOC_ENV.items()) else "default"


def _malloc_label(meta: dict) -> str:
    if meta.get("malloc_setting", "reuse") == "reuse":
        return "reuse (" + " ".join(f"{k}={v}" for k, v in MALLOC_ENV.items()) + ", not a default)"
    return "default (glibc's own thresholds, as in a user's process)"


def markdown(result: dict) -> str:
    meta, args = result["meta"], result["args"]
    tab = Table(result)
    peers = _torch_peers(result)
    ops = [o for o in args["ops"]]
    sizes, dtypes, modes = args["sizes"], args["dtypes"], args["modes"]
    out = ["# torchlie benchmarks", ""]
    peer_v = ", ".join(f"{p} {v}" for p, v in meta["peers"].items())
    out += [
        f"- date: {meta['date']}; command: `{meta['command'].strip()}`",
        f"- machine: {meta['cpu']}, {meta['cores']} cores, {meta['memory_gib']} GiB; {meta['os']}",
        f"- python {meta['python']}, torch {meta['torch']} (CPU capability "
        f"{meta['cpu_capability']}), torchlie {meta['torchlie']} ({meta['git']})",
        f"- threads: {meta['threads']}, OMP_WAIT_POLICY={meta['omp_wait_policy']}, clock: "
        f"{meta['clock']}; compile first-call times: wall clock, compile cache "
        f"{meta['compile_cache']}; allocator: {_malloc_label(meta)}; load average "
        f"at start {meta['loadavg_start']}, at end {meta['loadavg_end']}",
        f"- peers: {peer_v}",
        "- left out: " + "; ".join(f"{k} ({v})" for k, v in meta["left_out"].items()),
        "",
        "Cells: median time per element in **ns** (N = 1: per call in **us**), the least of "
        f"{result['args'].get('rounds', 1)} rounds that time the cell's implementations in "
        "turn; in parentheses the "
        "peer's time over torchlie's (> 1: torchlie is faster). `floor` = `clone()` of one "
        "buffer per input and output of the op, N x (input + output numbers) in all (twice "
        "that for fwd+bwd): every byte of the op read and written once, no arithmetic. "
        "`compiled` = `torchlie.compiled.<op>` (`torch.compile(fn, fullgraph=True)` with "
        "Inductor's CPU loops vectorised, see `torchlie.compiled.inductor_options`). fwd+bwd "
        "= forward, then `torch.autograd.grad` of all inputs. Peers get the same elements in "
        "their own conventions (converted before timing; object construction from tensors is "
        "timed).",
        "",
    ]
    if result["check_failures"]:
        out += ["Adapters that disagreed with torchlie (not timed):", ""]
        out += [
            f"- {f['op']} {f['peer']} `{f['call']}`: {f['error']}" for f in result["check_failures"]
        ]
        out += [""]

    short = [
        _peers.SHORT.get(p, p) + (" (ref)" if p in _peers.REFERENCE_PEERS else "") for p in peers
    ]
    for dname in dtypes:
        for mode in modes:
            out += [f"## {dname}, {mode}, allocator {meta.get('malloc_setting', 'reuse')}", ""]
            head = ["op", "N", "floor", "torchlie", "compiled", *short, "best peer/torchlie",
                    "torchlie/floor"]  # fmt: skip
            out += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
            for name in ops:
                for n in sizes:
                    key = (name, dname, mode, n)
                    scale = 1e6 if n == 1 else 1e9 / n
                    tl = tab.get(*key, "torchlie")
                    cells = [name, _n_label(n) + (" (us)" if n == 1 else "")]
                    for impl in ("floor", "torchlie", "compiled"):
                        t = tab.get(*key, impl)
                        cells.append(_fmt(t * scale) if t is not None else "-")
                    for p in peers:
                        t = tab.get(*key, p)
                        if t is None:
                            cells.append("-")
                        elif tl is None:
                            cells.append(_fmt(t * scale))
                        else:
                            cells.append(f"{_fmt(t * scale)} ({_ratio(t / tl)})")
                    bp, bt = fastest_peer(tab, peers, *key)
                    cells.append(
                        f"{_ratio(bt / tl)} {_peers.SHORT.get(bp, bp)}" if bt and tl else "-"
                    )
                    fl = tab.get(*key, "floor")
                    cells.append(_ratio(tl / fl) if tl and fl else "-")
                    out.append("| " + " | ".join(cells) + " |")
            out += [""]

    out += targets(result, tab, peers)
    out += compile_table(result, tab)
    for key, title in (
        ("kinematics", "Forward kinematics (`benchmarks/bench_kinematics.py`, wall clock)"),
        ("inverse_kinematics", "Inverse kinematics (`benchmarks/bench_ik.py`, CPU time)"),
    ):
        kin = result.get(key)
        if kin:
            out += [f"## {title}", ""]
            out += [kin["output"] if kin["rc"] == 0 else f"failed ({kin['rc']}):\n\n```\n"
                    + kin["output"] + "\n```", ""]  # fmt: skip
    out += ["## Calls timed", ""]
    for name in ops:
        calls = result["calls"].get(name, {})
        if calls:
            out.append(
                f"- {name}: "
                + "; ".join(f"{_peers.SHORT.get(p, p)} `{c}`" for p, c in calls.items())
            )
    out += [""]
    return "\n".join(out)


def targets(result: dict, tab: Table, peers: list[str]) -> list[str]:
    """The speed targets of the issue, per op: met or not, with the ratios."""
    args = result["args"]
    big = max(args["sizes"])
    small = min(args["sizes"])
    rows = []
    cols = []
    for dname, need in (("float32", 2.0), ("float64", 1.0)):
        for mode in args["modes"]:
            if dname in args["dtypes"]:
                cols.append((f"{dname} {mode} N={_n_label(big)}: peer/tl >= {need:g}",
                             "peer", dname, mode, big, need))  # fmt: skip
    for dname in args["dtypes"] if small != big else ():
        for mode in args["modes"]:
            cols.append(
                (f"{dname} {mode} N={small}: peer/tl >= 2", "peer", dname, mode, small, 2.0)
            )
    for dname in args["dtypes"]:
        for mode in args["modes"]:
            cols.append((f"compiled {dname} {mode} N={_n_label(big)}: compiled/floor <= 3",
                         "floor", dname, mode, big, 3.0))  # fmt: skip
    met = [0] * len(cols)
    total = [0] * len(cols)
    for name in args["ops"]:
        cells = [name]
        for i, (_, kind, dname, mode, n, need) in enumerate(cols):
            key = (name, dname, mode, n)
            if kind == "peer":
                tl = tab.get(*key, "torchlie")
                bp, bt = fastest_peer(tab, peers, *key)
                if tl is None or bt is None:
                    cells.append("-")
                    continue
                v = bt / tl
                ok = v >= need
            else:
                c, f = tab.get(*key, "compiled"), tab.get(*key, "floor")
                if c is None or f is None:
                    cells.append("-")
                    continue
                v = c / f
                ok = v <= need
            total[i] += 1
            met[i] += ok
            cells.append(f"{_ratio(v)} {'yes' if ok else 'NO'}")
        rows.append("| " + " | ".join(cells) + " |")
    head = ["op"] + [c[0] for c in cols]
    out = ["## Targets", "", "peer/tl = fastest torch peer's time over torchlie's (eager); "
           "compiled/floor = compiled torchlie over the copy floor.", ""]  # fmt: skip
    out += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    out += rows
    out.append("| met | " + " | ".join(f"{m}/{t}" for m, t in zip(met, total, strict=True)) + " |")
    out.append("")
    return out


def compile_table(result: dict, tab: Table) -> list[str]:
    recs = [r for r in result["records"] if r["impl"] == "compiled" and "first_call_s" in r]
    if not recs:
        return []
    args = result["args"]
    out = ["## Compiled: first-call time (s, compilation included) per N", ""]
    head = ["op", "dtype", "mode"] + [f"N={_n_label(n)}" for n in args["sizes"]]
    out += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name in args["ops"]:
        for dname in args["dtypes"]:
            for mode in args["modes"]:
                cells = [name, dname, mode]
                any_ = False
                for n in args["sizes"]:
                    r = tab.rec(name, dname, mode, n, "compiled")
                    if r and "first_call_s" in r:
                        any_ = True
                        cells.append(f"{r['first_call_s']:.2f}")
                    else:
                        cells.append(r.get("error", "-")[:40] if r else "-")
                if any_:
                    out.append("| " + " | ".join(cells) + " |")
    out.append("")
    return out


KINEMATICS = ROOT / "benchmarks" / "bench_kinematics.py"
INVERSE_KINEMATICS = ROOT / "benchmarks" / "bench_ik.py"


def kinematics(args: argparse.Namespace, log=print, script: Path = KINEMATICS) -> dict:
    """Run a kinematics benchmark (forward: ``bench_kinematics.py``; inverse:
    ``bench_ik.py``) in a subprocess (same environment); its output."""
    if not script.exists():
        return {"rc": None, "output": f"{script.name} not found"}
    cmd = [sys.executable, str(script)] + (["--quick"] if args.quick else [])
    path = [str(ROOT)] + ([os.environ["PYTHONPATH"]] if os.environ.get("PYTHONPATH") else [])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(path)}
    log("running " + " ".join(cmd[1:]))
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env=env)
    out = proc.stdout.strip()
    if proc.returncode != 0:
        out += "\n\n" + proc.stderr.strip()[-2000:]
    return {
        "rc": proc.returncode,
        "output": out,
        "command": f"python benchmarks/{script.name}",
    }


def plot(result: dict, path: Path) -> bool:
    """Bar chart of ns/element at the largest N, per op, float32 (or the first dtype)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return False
    args = result["args"]
    tab = Table(result)
    big = max(args["sizes"])
    dname = "float32" if "float32" in args["dtypes"] else args["dtypes"][0]
    impls = ["floor", "torchlie", "compiled"] + [
        p for p in _torch_peers(result) if p not in _peers.REFERENCE_PEERS
    ]
    fig, axes = plt.subplots(len(args["modes"]), 1, figsize=(13, 4.2 * len(args["modes"])),
                             squeeze=False)  # fmt: skip
    width = 0.8 / len(impls)
    for ax, mode in zip(axes[:, 0], args["modes"], strict=True):
        for j, impl in enumerate(impls):
            xs, ys = [], []
            for i, name in enumerate(args["ops"]):
                t = tab.get(name, dname, mode, big, impl)
                if t is not None:
                    xs.append(i + (j - (len(impls) - 1) / 2) * width)
                    ys.append(t / big * 1e9)
            ax.bar(xs, ys, width=width, label=_peers.SHORT.get(impl, impl))
        ax.set_yscale("log")
        ax.set_xticks(range(len(args["ops"])))
        ax.set_xticklabels(args["ops"], rotation=20, ha="right")
        ax.set_ylabel("ns / element (log)")
        ax.set_title(f"{mode}, {dname}, N = {big:,}, {result['meta']['threads']} thread(s)")
        ax.grid(axis="y", which="both", alpha=0.3)
    axes[0, 0].legend(ncol=len(impls), fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if _TORCH_PREIMPORTED:
        warnings.warn(
            "torch was imported before benchmarks.run set OMP_WAIT_POLICY=PASSIVE; run "
            "`OMP_WAIT_POLICY=PASSIVE python benchmarks/run.py` or call it as a script",
            stacklevel=2,
        )
    if args.malloc == "reuse" and any(os.environ.get(k) != v for k, v in MALLOC_ENV.items()):
        warnings.warn(
            "--malloc reuse needs " + " ".join(f"{k}={v}" for k, v in MALLOC_ENV.items())
            + " in the environment at start-up (run benchmarks/run.py as a script); measuring "
            "with the environment as it is",
            stacklevel=2,
        )  # fmt: skip
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    def checkpoint(result: dict) -> None:
        (out / "results.json").write_text(json.dumps(result, indent=1, default=str))

    result = run(args, log=lambda s: print(s, flush=True), checkpoint=checkpoint)
    if args.kinematics:
        for key, script in (("kinematics", KINEMATICS), ("inverse_kinematics", INVERSE_KINEMATICS)):
            result[key] = kinematics(args, log=lambda s: print(s, flush=True), script=script)
    md = markdown(result)
    (out / "results.md").write_text(md)
    (out / "results.json").write_text(json.dumps(result, indent=1, default=str))
    made = not args.no_plot and plot(result, out / "results.png")
    print()
    print(md)
    print(f"wrote {out / 'results.md'}, {out / 'results.json'}"
          + (f", {out / 'results.png'}" if made else " (no plot)")
          + f" in {result['meta']['wall_s']} s")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
