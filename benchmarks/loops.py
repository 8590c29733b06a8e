"""How many loops over the batch Inductor generates for each op of ``torchlie.compiled``.

Each op is compiled with its options (``torchlie.compiled.inductor_options``), run forward and
backward on a batch, and the C++ that Inductor wrote is searched for loops over the batch index
and for library calls (``extern_kernels``, e.g. a batched matrix product).  One loop per pass is
the aim of the compiled path: each further loop is one more pass over memory.  The code depends
on the CPU (vector width) and the torch version, so this is a report, never a test.

    python benchmarks/loops.py [--dtype float64]
"""

from __future__ import annotations

import argparse
import re

import torch
from torch._inductor.utils import run_and_get_code

from torchlie import compiled, quaternion, se3, so3

_MODULES = {"so3": so3, "se3": se3, "quaternion": quaternion}


def _inputs(n: int, dtype: torch.dtype) -> dict[tuple[str, str], tuple[torch.Tensor, ...]]:
    g = torch.Generator().manual_seed(0)

    def rand(*shape: int) -> torch.Tensor:
        return torch.randn(*shape, generator=g, dtype=dtype)

    R, T = so3.random(n, generator=g, dtype=dtype), se3.random(n, generator=g, dtype=dtype)
    return {
        ("so3", "exp"): (rand(n, 3),),
        ("so3", "log"): (R,),
        ("so3", "act"): (R, rand(n, 3)),
        ("se3", "exp"): (rand(n, 6),),
        ("se3", "log"): (T,),
        ("se3", "compose"): (T, T.flip(0)),
        ("se3", "inverse"): (T,),
        ("se3", "act"): (T, rand(n, 3)),
        ("quaternion", "multiply"): (rand(n, 4), rand(n, 4)),
        ("quaternion", "apply"): (rand(n, 4), rand(n, 3)),
        ("quaternion", "to_matrix"): (rand(n, 4),),
        ("quaternion", "from_matrix"): (R,),
    }


def _loops(code: str) -> int:
    """Loops over the batch (the outermost index ``x0``) in one generated C++ module."""
    return len(re.findall(r"for\s*\(\s*int64_t x0\s*=", code))


def report(n: int = 1000, dtype: torch.dtype = torch.float32) -> list[tuple[str, int, int, int]]:
    """``(op, forward loops, backward loops, library calls)`` for every op timed above."""
    rows = []
    for (module, name), args in _inputs(n, dtype).items():
        fn = getattr(_MODULES[module], name)
        leaves = [x.clone().requires_grad_() for x in args]
        torch._dynamo.reset()
        cfn = torch.compile(fn, fullgraph=True, options=compiled.inductor_options(module, name))
        G = torch.ones_like(fn(*args))

        def step(cfn=cfn, leaves=leaves, G=G):
            return torch.autograd.grad(cfn(*leaves), leaves, G)

        _, code = run_and_get_code(step)
        fwd, bwd = (code + ["", ""])[:2]
        calls = sum(c.count("extern_kernels.") for c in code)
        rows.append((f"{module}.{name}", _loops(fwd), _loops(bwd), calls))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dtype", default="float32", choices=["float32", "float64"])
    parser.add_argument("--n", type=int, default=1000, help="batch size")
    args = parser.parse_args()
    print(f"torch {torch.__version__}, {args.dtype}, batch {args.n}")
    print("| op | forward loops | backward loops | library calls |")
    print("| --- | --- | --- | --- |")
    for op, fwd, bwd, calls in report(args.n, getattr(torch, args.dtype)):
        print(f"| {op} | {fwd} | {bwd} | {calls} |")


if __name__ == "__main__":
    main()
