"""Batched forward kinematics and Jacobians: torchlie vs pytorch-kinematics, same run.

The bundled 7-DOF arm (``arm7``, 12 links), all links, float32, one thread, batch sizes
1, 1 000 and 100 000, timed with ``torch.utils.benchmark`` (median of blocked runs).  Both
libraries' public calls are timed: torchlie's ``forward_kinematics`` (dict of ``(B, 4, 4)``,
and the stacked ``(B, 12, 4, 4)`` tensor) against pytorch-kinematics' ``forward_kinematics``
(dict of ``Transform3d``), and the end link's geometric Jacobian against pytorch-kinematics'
``SerialChain.jacobian``.  Prints a markdown table; the ratio is pk's time / torchlie's.

At B = 100 000 a stacked result is 77 MB: a fresh allocation that large is page-faulted in on
every call (glibc serves it with mmap), which costs as much as the arithmetic on a virtual
machine.  ``--thp`` sets PyTorch's ``THP_MEM_ALLOC_ENABLE=1`` (2 MB transparent huge pages for
large CPU tensors) to show the difference; it applies to both libraries.

    python benchmarks/bench_kinematics.py [--quick] [--thp] [--robot arm7]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os


def _time(fn, min_run_time: float) -> float:
    import torch.utils.benchmark as tb

    t = tb.Timer(stmt="fn()", globals={"fn": fn}, num_threads=1)
    return t.blocked_autorange(min_run_time=min_run_time).median


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="arm7", help="bundled robot name or URDF path")
    parser.add_argument("--sizes", default="1,1000,100000")
    parser.add_argument("--quick", action="store_true", help="shorter timing runs")
    parser.add_argument("--thp", action="store_true", help="THP_MEM_ALLOC_ENABLE=1 (see above)")
    args = parser.parse_args()
    if args.thp:
        os.environ["THP_MEM_ALLOC_ENABLE"] = "1"  # read by torch's CPU allocator
    import torch

    from torchlie.kinematics import Chain, sample_robot

    torch.set_num_threads(1)
    min_run = 0.2 if args.quick else 1.0

    import pytorch_kinematics as pk

    path = sample_robot(args.robot) if not args.robot.endswith(".urdf") else args.robot
    chain = Chain.from_urdf(path)
    with contextlib.redirect_stderr(io.StringIO()):
        pk_chain = pk.build_chain_from_urdf(open(path).read())
    end = chain.leaf_links[0]
    serial = pk.SerialChain(pk_chain, end)
    pk_names = pk_chain.get_joint_parameter_names()
    if list(pk_names) != list(chain.joint_names):
        raise SystemExit("this benchmark needs a robot without mimic/floating/planar joints")
    idx = [pk_names.index(n) for n in serial.get_joint_parameter_names()]

    print(
        f"robot {chain.name}: {len(chain.link_names)} links, {chain.n_dof} DoF; float32, "
        f"one thread; torch {torch.__version__}, pytorch_kinematics "
        f"{_pk_version()}; median time per call; THP_MEM_ALLOC_ENABLE="
        f"{os.environ.get('THP_MEM_ALLOC_ENABLE', 'unset')}; load average "
        f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs\n"
    )
    print("| operation | B | torchlie | pytorch_kinematics | speed-up (pk / torchlie) |")
    print("| --- | ---: | ---: | ---: | ---: |")
    gen = torch.Generator().manual_seed(0)
    for B in (int(s) for s in args.sizes.split(",")):
        q = chain.random_configuration(B, generator=gen)
        qs = q[:, idx]
        rows = [
            ("FK, all links (dict)", lambda q=q: chain.forward_kinematics(q),
             lambda q=q: pk_chain.forward_kinematics(q)),
            ("FK, all links (stacked tensor)",
             lambda q=q: chain.forward_kinematics(q, stacked=True),
             lambda q=q: pk_chain.forward_kinematics(q)),
            (f"Jacobian of {end}", lambda q=q: chain.jacobian(q, end),
             lambda qs=qs: serial.jacobian(qs)),
        ]  # fmt: skip
        for name, ours, theirs in rows:
            t_ours, t_pk = _time(ours, min_run), _time(theirs, min_run)
            print(
                f"| {name} | {B} | {_fmt(t_ours)} | {_fmt(t_pk)} | {t_pk / t_ours:.1f}x |",
                flush=True,
            )


def _pk_version() -> str:
    from importlib.metadata import version

    return version("pytorch_kinematics")


def _fmt(seconds: float) -> str:
    if seconds < 1e-3:
        return f"{seconds * 1e6:.0f} µs"
    return f"{seconds * 1e3:.2f} ms"


if __name__ == "__main__":
    main()
