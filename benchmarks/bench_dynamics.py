"""Batched rigid-body dynamics: torchlie vs Pinocchio, same run, one thread.

The bundled 7-DOF arm (``arm7``), float64 (Pinocchio's dtype) and torchlie in float32 too,
batch sizes 1 to 4 096.  Three calls: inverse dynamics (``Chain.inverse_dynamics`` vs
``pin.rnea``), the mass matrix (``Chain.mass_matrix`` vs ``pin.crba``) and forward dynamics
(``Chain.forward_dynamics``, a Cholesky solve of the mass matrix, vs ``pin.aba``).  Pinocchio
computes one state per call, so it is timed two ways: a Python loop over the batch (what a
PyTorch user pays: one call per state, NumPy arrays prepared beforehand) and its per-call time
times the batch size (the C++ speed without the loop; a lower bound).  torchlie's time is one
batched call, timed with ``torch.utils.benchmark`` (median of blocked runs).  The table gives
microseconds per batch and, per call, the smallest batch from which torchlie's batched call is
at least as fast as the loop (``cross-over``) and as the per-call bound.  The last line splits
torchlie's forward dynamics into its parts (mass matrix, bias forces, Cholesky solve), to show
what an articulated-body recursion could save.

    python benchmarks/bench_dynamics.py [--quick] [--robot arm7] [--sizes 1,16,...]
"""

from __future__ import annotations

import argparse
import time


def _time(fn, min_run_time: float) -> float:
    """Fastest block of ``torch.utils.benchmark``'s blocked runs, seconds per call (the least
    disturbed by other processes on a shared machine)."""
    import torch.utils.benchmark as tb

    t = tb.Timer(stmt="fn()", globals={"fn": fn}, num_threads=1)
    return min(t.blocked_autorange(min_run_time=min_run_time).times)


def _per_call(fn, reps: int) -> float:
    """Best of five runs of ``reps`` calls, seconds per call."""
    best = float("inf")
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(reps):
            fn()
        best = min(best, (time.perf_counter() - t0) / reps)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="arm7", help="bundled robot name or URDF path")
    parser.add_argument("--sizes", default="1,16,64,256,1024,4096")
    parser.add_argument("--quick", action="store_true", help="shorter timing runs")
    parser.add_argument("--rounds", type=int, default=3, help="interleaved timing rounds")
    args = parser.parse_args()
    import pinocchio as pin
    import torch

    from torchlie.kinematics import Chain, sample_robot

    torch.set_num_threads(1)
    min_run = 0.1 if args.quick else 0.5
    path = sample_robot(args.robot) if not args.robot.endswith(".urdf") else args.robot
    chain = Chain.from_urdf(path, dtype=torch.float64)
    c32 = chain.to(dtype=torch.float32)
    model = pin.buildModelFromUrdf(path)
    data = model.createData()
    if model.nq != chain.n_dof or model.nv != chain.n_dof:
        raise SystemExit("this benchmark needs revolute/prismatic joints only")
    sizes = [int(s) for s in args.sizes.split(",")]
    gen = torch.Generator().manual_seed(0)
    Bmax = max(sizes)
    q = chain.random_configuration(Bmax, generator=gen)
    qd = torch.randn(Bmax, chain.n_dof, generator=gen, dtype=torch.float64)
    qdd = torch.randn(Bmax, chain.n_dof, generator=gen, dtype=torch.float64)
    tau = chain.inverse_dynamics(q, qd, qdd)
    qn, qdn, qddn, taun = (x.numpy().copy() for x in (q, qd, qdd, tau))

    calls = {
        "inverse dynamics": (
            lambda c, b, x: c.inverse_dynamics(*x[:3]),
            lambda i: pin.rnea(model, data, qn[i], qdn[i], qddn[i]),
        ),
        "mass matrix": (
            lambda c, b, x: c.mass_matrix(x[0]),
            lambda i: pin.crba(model, data, qn[i]),
        ),
        "forward dynamics": (
            lambda c, b, x: c.forward_dynamics(x[0], x[1], x[3]),
            lambda i: pin.aba(model, data, qn[i], qdn[i], taun[i]),
        ),
    }
    reps = 500 if args.quick else 5000
    print(
        f"{args.robot}, {chain.n_dof} DoF, one thread; microseconds per batch "
        f"(Pinocchio {pin.__version__}, torch {torch.__version__})\n"
    )
    head = "| call | B | torchlie f64 | torchlie f32 | pin loop | pin per call x B | loop / f64 |"
    print(head)
    print("|" + "---|" * (head.count("|") - 1))
    summary = []
    for name, (tl, pn) in calls.items():
        per_call = _per_call(lambda pn=pn: pn(0), reps)
        cross_loop = cross_call = None
        for B in sizes:
            x64 = (q[:B], qd[:B], qdd[:B], tau[:B])
            x32 = tuple(v.float() for v in x64)

            def loop(B=B, pn=pn):
                for i in range(B):
                    pn(i)

            t64 = t32 = tl_loop = float("inf")
            for _ in range(1 if args.quick else args.rounds):
                t64 = min(t64, _time(lambda x64=x64, tl=tl, B=B: tl(chain, B, x64), min_run))
                t32 = min(t32, _time(lambda x32=x32, tl=tl, B=B: tl(c32, B, x32), min_run))
                tl_loop = min(tl_loop, _time(loop, min_run))
            bound = per_call * B
            if cross_loop is None and t64 <= tl_loop:
                cross_loop = B
            if cross_call is None and t64 <= bound:
                cross_call = B
            print(
                f"| {name} | {B} | {t64 * 1e6:.0f} | {t32 * 1e6:.0f} | {tl_loop * 1e6:.0f} | "
                f"{bound * 1e6:.0f} | {tl_loop / t64:.1f}x |"
            )
        summary.append((name, cross_loop, cross_call))
    print()
    for name, cl, cc in summary:
        fmt = lambda b: f"B = {b}" if b is not None else f"not within B <= {Bmax}"  # noqa: E731
        print(
            f"- {name}: as fast as Pinocchio's Python loop from {fmt(cl)}; as fast as its "
            f"per-call time x B from {fmt(cc)}"
        )

    # Forward dynamics, split (float64, the largest batch).
    B = Bmax
    x = (q[:B], qd[:B], tau[:B])
    t_fd = _time(lambda: chain.forward_dynamics(*x), min_run)
    t_m = _time(lambda: chain.mass_matrix(x[0]), min_run)
    t_h = _time(lambda: chain.bias_forces(x[0], x[1]), min_run)
    M = chain.mass_matrix(x[0])
    rhs = (x[2] - chain.bias_forces(x[0], x[1])).unsqueeze(-1)

    def chol():
        L, _ = torch.linalg.cholesky_ex(M)
        return torch.cholesky_solve(rhs, L)

    t_c = _time(chol, min_run)
    print(
        f"- forward dynamics at B = {B}, float64: {t_fd * 1e6:.0f} us = mass matrix "
        f"{t_m * 1e6:.0f} + bias forces {t_h * 1e6:.0f} + Cholesky solve {t_c * 1e6:.0f} "
        "(separate calls; the fused call shares one forward-kinematics pass)"
    )


if __name__ == "__main__":
    main()
