"""Batched inverse kinematics: torchlie's solver against pytorch-kinematics', same targets.

For each bundled robot (``arm7``'s ``tool_tcp``, the Panda's ``panda_hand_tcp`` and the
``tree``'s ``left_tcp``), the targets are the poses of the end link at random configurations
within the joint limits (so every target is reachable).  Both solvers get the same targets, the
same number of random starts per target (``--restarts``), tolerances 1e-4 m and 1e-3 rad, float32
and one thread (``torch.set_num_threads(1)``):

* torchlie: :meth:`Chain.inverse_kinematics <torchlie.kinematics.Chain.inverse_kinematics>`
  with its defaults (a fixed budget of iterations, no synchronisation), and with
  ``early_exit=True`` (the starts of solved targets leave the batch);
* pytorch-kinematics: ``pytorch_kinematics.PseudoInverseIK`` with its defaults (50 iterations,
  ``early_stopping_any_converged=False``) and with ``early_stopping_any_converged=True`` (it
  stops when every target has a converged start), the starts uniform within the same limits.

A target is solved when the returned joint values (within the limits) put the link within
1e-4 m and 1e-3 rad of it, checked for both libraries by the same float64 forward kinematics
(not by the solvers' own reports).  Time: one ``solve`` call on all targets, the median of
``--repeats`` calls after a warm-up call on a few targets, as the CPU time of the process
(one thread, so on a shared machine it is far less disturbed by other processes than the wall
clock, also printed); throughput and speed-ups are from the CPU time.  The tree's pk chain is the
serial chain to ``left_tcp`` (its floating and planar joints, which pk cannot load, are off
that path); it has 5 joints, so pk's ``J J^T`` is singular and its default regularisation of
1e-9 fails in float32, and continuous joints, whose infinite limits make pk's final limit
enforcement return nan: there pk gets ``regularlization=1e-6``, ``enforce_joint_limits=False``
and ``clamp_to_limits=True``.  Prints a markdown table; speed-up = pk's time / torchlie's, per
pk configuration.

    python benchmarks/bench_ik.py [--targets 1000] [--restarts 8] [--quick]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import statistics
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from torchlie import se3  # noqa: E402
from torchlie.kinematics import Chain, sample_robot  # noqa: E402
from torchlie.kinematics.validate import _pk_text  # noqa: E402

ROBOTS = {"arm7": "tool_tcp", "panda": "panda_hand_tcp", "tree": "left_tcp"}
POS_TOL, ROT_TOL = 1e-4, 1e-3


def solved(chain64: Chain, link: str, q: torch.Tensor, T: torch.Tensor) -> torch.Tensor:
    """Within the limits and the tolerances, by float64 forward kinematics."""
    q = q.to(torch.float64)
    inside = ((q >= chain64.lower - 1e-6) & (q <= chain64.upper + 1e-6)).all(-1)
    angle, dist = se3.distance(chain64.forward_kinematics(q, link)[link], T.to(torch.float64))
    return inside & (dist <= POS_TOL) & (angle <= ROT_TOL)


def timed(fn, repeats: int):
    """``((median CPU seconds, median wall seconds), last result)`` of ``fn()``."""
    cpu, wall, out = [], [], None
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - t0)
    return (statistics.median(cpu), statistics.median(wall)), out


def torchlie_rows(chain, chain64, link, T, args):
    rows = []
    for label, kw in (("torchlie (fixed budget, no sync)", {}),
                      ("torchlie early_exit=True", {"early_exit": True})):  # fmt: skip

        def run(T=T, kw=kw):
            gen = torch.Generator().manual_seed(1)
            return chain.inverse_kinematics(T, link, restarts=args.restarts, generator=gen, **kw)

        chain.inverse_kinematics(T[:8], link, restarts=args.restarts)  # warm-up
        t, res = timed(run, args.repeats)
        ok = solved(chain64, link, res.q, T)
        its = res.iterations[res.converged].double()
        it = f"{its.median():.0f} / {its.max():.0f}" if its.numel() else "-"
        rows.append((label, float(ok.double().mean()), it, t))
    return rows


def pk_rows(chain, chain64, link, T, args):
    import pytorch_kinematics as pk

    text = Path(sample_robot(args.robot_name)).read_bytes()
    with contextlib.redirect_stderr(io.StringIO()):
        pk_chain = pk.build_chain_from_urdf(_pk_text(text))
    serial = pk.SerialChain(pk_chain, link)
    names = serial.get_joint_parameter_names()
    idx = [chain.joint_names.index(n) for n in names]
    lo, hi = chain.sampling_bounds()  # the limits, and torchlie's ranges where there are none
    limits = torch.stack((lo[idx], hi[idx]), 1).float()
    # The tree's arm: 5 joints, so J J^T is singular and pk's default regularisation (1e-9)
    # fails in float32 ("input matrix is singular"); and continuous joints, whose infinite
    # limits turn pk's final limit enforcement into nan.  There pk gets a regularisation of
    # 1e-6 and clamps to the limits at each step instead.
    reg = {}
    if len(idx) < 6 or not bool(torch.isfinite(chain.lower[idx]).all()):
        reg = {"regularlization": 1e-6, "enforce_joint_limits": False, "clamp_to_limits": True}
    rows = []
    for label, kw in (("pytorch_kinematics PseudoInverseIK (defaults)", {}),
                      ("pytorch_kinematics, early_stopping_any_converged=True",
                       {"early_stopping_any_converged": True})):  # fmt: skip

        def run(kw=kw):
            torch.manual_seed(1)
            ik = pk.PseudoInverseIK(
                serial, num_retries=args.restarts, joint_limits=limits, pos_tolerance=POS_TOL,
                rot_tolerance=ROT_TOL, **reg, **kw,
            )  # fmt: skip
            return ik.solve(pk.Transform3d(matrix=T)), ik

        torch.manual_seed(0)
        pk.PseudoInverseIK(serial, num_retries=args.restarts, joint_limits=limits, **reg).solve(
            pk.Transform3d(matrix=T[:8])
        )  # warm-up
        t, (sol, _) = timed(run, args.repeats)
        # Its answer per target: a converged start if any, else the smallest error.
        err = sol.err_pos / POS_TOL + sol.err_rot / ROT_TOL
        key = torch.where(sol.converged, err * 0, err + 1)
        best = key.argmin(1)
        q_pk = sol.solutions[torch.arange(T.shape[0]), best]  # (M, n_serial)
        # Joints off the serial chain do not move the link: zero, clamped into their limits.
        q = torch.zeros(T.shape[0], chain.n_dof, dtype=torch.float64)
        q = torch.maximum(torch.minimum(q, chain64.upper), chain64.lower)
        q[:, idx] = q_pk.double()
        ok = solved(chain64, link, q, T)
        rows.append((label, float(ok.double().mean()), f"{sol.iterations} (all targets)", t))
    return rows


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--robots", default="arm7,panda,tree", help="bundled robots")
    parser.add_argument("--targets", type=int, default=1000, help="targets per robot")
    parser.add_argument("--restarts", type=int, default=8, help="random starts per target")
    parser.add_argument("--repeats", type=int, default=3, help="timed calls (median)")
    parser.add_argument("--no-pk", action="store_true", help="torchlie only")
    parser.add_argument("--quick", action="store_true", help="100 targets, one timed call")
    args = parser.parse_args(argv)
    if args.quick:
        args.targets, args.repeats = 100, 1
    torch.set_num_threads(1)
    have_pk = not args.no_pk
    if have_pk:
        try:
            import pytorch_kinematics  # noqa: F401
        except ImportError:
            have_pk = False
            print("pytorch_kinematics is not installed: torchlie only")
    print(
        f"inverse kinematics, {args.targets} targets x {args.restarts} starts, float32, one "
        f"thread, torch {torch.__version__}; solved = within {POS_TOL:g} m and {ROT_TOL:g} rad "
        "(float64 FK of the answer)\n"
    )
    print(
        "| robot | solver | solved | iterations (median / max) | CPU time | wall | targets/s "
        "| speed-up |"
    )
    print("| --- | --- | ---: | --- | ---: | ---: | ---: | --- |")
    results = []
    for name in args.robots.split(","):
        link = ROBOTS[name]
        args.robot_name = name
        chain = Chain.from_urdf(sample_robot(name))
        chain64 = chain.to(torch.float64)
        gen = torch.Generator().manual_seed(0)
        T = chain.forward_kinematics(chain.random_configuration(args.targets, generator=gen), link)[
            link
        ]
        rows = torchlie_rows(chain, chain64, link, T, args)
        pk = pk_rows(chain, chain64, link, T, args) if have_pk else []
        for label, rate, it, (t, wall) in rows + pk:
            up = ""
            if label.startswith("torchlie") and pk:
                up = ", ".join(f"{p[3][0] / t:.1f}x" for p in pk)
            print(
                f"| {name} `{link}` | {label} | {100 * rate:.1f}% | {it} | {t * 1e3:.0f} ms | "
                f"{wall * 1e3:.0f} ms | {args.targets / t:.0f} | {up} |",
                flush=True,
            )
            results.append(
                {"robot": name, "solver": label, "solved": rate, "cpu_s": t, "wall_s": wall}
            )
    if have_pk:
        print(
            "\nspeed-up: pk's CPU time / torchlie's, against pk's defaults, then against its "
            f"early stop; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs"
        )
    return results


if __name__ == "__main__":
    main()
