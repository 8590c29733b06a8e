"""Batched inverse kinematics on the Franka Emika Panda with ``Chain.inverse_kinematics``.

Targets are poses of the Panda's ``panda_hand_tcp`` at random joint configurations within the
limits (so every target is reachable).  One call solves all of them at once: several random
starts per target side by side in one batch, Levenberg-Marquardt steps on the log error
``Log(T*^-1 T(q))`` with its exact derivative, the joint limits kept by projection (see
:mod:`torchlie.kinematics.ik`).  A target is solved when the hand is within 0.1 mm and 1 mrad
of it (the solver's default tolerances), checked here again by forward kinematics.

The solver is deterministic for a given generator seed, and ``max_iterations=k`` stops it after
``k`` iterations of the same run, so the convergence curve is drawn by solving with
``k = 0, 2, 4, ...``: the share of targets solved and the median errors after ``k``
iterations, saved as ``examples/out/convergence.png`` (``--out DIR`` for another folder; with
matplotlib, and without it or with ``--no-plot`` the figures are printed only).

Run: ``python examples/inverse_kinematics.py [--quick] [--targets N] [--restarts K] [--out DIR]
[--no-plot]``.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import torch

from torchlie import se3
from torchlie.kinematics import Chain, sample_robot

LINK = "panda_hand_tcp"
OUT = Path(__file__).resolve().parent / "out"


def parse(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--quick", action="store_true", help="200 targets, a coarser curve (CI)")
    p.add_argument("--targets", type=int, default=1000, help="number of target poses")
    p.add_argument("--restarts", type=int, default=8, help="random starts per target")
    p.add_argument("--max-iterations", type=int, default=40, help="iteration budget")
    p.add_argument(
        "--dtype", choices=("float32", "float64"), default="float32", help="dtype of the solve"
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the targets and the starts")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    p.add_argument("--out", type=Path, default=OUT, help="folder of the convergence plot")
    p.add_argument("--no-plot", action="store_true", help="write no plot (figures only)")
    cfg = p.parse_args(argv)
    if cfg.quick:
        cfg.targets = 200
    return cfg


def solve(arm: Chain, T: torch.Tensor, cfg: argparse.Namespace, iterations: int):
    """One solver run; the same starts for every ``iterations`` (same generator seed)."""
    gen = torch.Generator().manual_seed(cfg.seed + 1)
    return arm.inverse_kinematics(
        T, LINK, restarts=cfg.restarts, max_iterations=iterations, generator=gen
    )


def loss(arm64: Chain, q: torch.Tensor, T: torch.Tensor) -> float:
    """The solver's objective at ``q``, ``1/2 |Log(T*^-1 T(q))|^2``, averaged over targets."""
    T_q = arm64.forward_kinematics(q.double(), LINK)[LINK]
    r = se3.log(se3.compose(se3.inverse(T.double()), T_q))
    return float(0.5 * (r * r).sum(-1).mean())


def main(argv: list[str] | None = None) -> dict:
    """Solve the batch, draw the convergence curve; print and return the figures."""
    cfg = parse(argv)
    threads = torch.get_num_threads()
    torch.set_num_threads(cfg.threads)
    try:
        return _run(cfg)
    finally:
        torch.set_num_threads(threads)


def _run(cfg: argparse.Namespace) -> dict:
    dtype = getattr(torch, cfg.dtype)
    arm = Chain.from_urdf(sample_robot("panda"), dtype=dtype)
    q_true = arm.random_configuration(
        cfg.targets, generator=torch.Generator().manual_seed(cfg.seed)
    )
    T = arm.forward_kinematics(q_true, LINK)[LINK]

    t0 = time.perf_counter()
    res = solve(arm, T, cfg, cfg.max_iterations)
    seconds = time.perf_counter() - t0

    # Independent check of the answers: float64 forward kinematics.
    arm64 = arm.to(torch.float64)
    angle, dist = se3.distance(arm64.forward_kinematics(res.q.double(), LINK)[LINK], T.double())
    within = bool(((res.q >= arm.lower) & (res.q <= arm.upper)).all())
    solved = (dist <= 1e-4) & (angle <= 1e-3)

    # The convergence curve: the same run stopped after k iterations.
    step = 4 if cfg.quick else 2
    ks = list(range(0, cfg.max_iterations + 1, step))
    if ks[-1] != cfg.max_iterations:
        ks.append(cfg.max_iterations)
    curve, losses = [], []
    for k in ks:
        r = res if k == cfg.max_iterations else solve(arm, T, cfg, k)
        curve.append(
            (k, float(r.converged.double().mean()), float(r.position_error.median()),
             float(r.rotation_error.median()))
        )  # fmt: skip
        losses.append(loss(arm64, r.q, T))

    figures = {
        "targets": cfg.targets,
        "restarts": cfg.restarts,
        "max_iterations": cfg.max_iterations,
        "success_rate": float(solved.double().mean()),
        "reported_success_rate": float(res.converged.double().mean()),
        "median_iterations": float(res.iterations.double().median()),
        "max_position_error_m": float(dist.max()),
        "max_rotation_error_rad": float(angle.max()),
        "median_position_error_m": float(dist.median()),
        "median_rotation_error_deg": math.degrees(float(angle.median())),
        "initial_median_position_error_m": curve[0][2],
        "loss_first": losses[0],
        "loss_last": losses[-1],
        "recheck_max_position_diff_m": float((dist - res.position_error.double()).abs().max()),
        "within_limits": within,
        "seconds": seconds,
        "curve": curve,
        "plot": None,
    }
    print(
        f"inverse kinematics, Panda '{LINK}' ({cfg.dtype}): {cfg.targets} targets x "
        f"{cfg.restarts} starts, {cfg.max_iterations} iterations, one call: {seconds:.2f} s"
    )
    print(
        f"success (solved within 0.1 mm and 1 mrad, rechecked): "
        f"{100 * figures['success_rate']:.1f} %; "
        f"median iterations of the solved: {figures['median_iterations']:.0f}; joint limits "
        f"respected: {within}"
    )
    print(f"{'iteration':>10}{'solved %':>10}{'median mm':>12}{'median mrad':>13}")
    for k, rate, p, r in curve:
        print(f"{k:>10}{100 * rate:>10.1f}{p * 1e3:>12.4g}{r * 1e3:>13.4g}")
    figures["plot"] = None if cfg.no_plot else plot(curve, cfg.out, cfg)
    return figures


def plot(curve: list[tuple[int, float, float, float]], out: Path, cfg) -> str | None:
    """Save the convergence curve as ``out/convergence.png``; None without matplotlib."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib is not installed: no plot (pip install matplotlib)")
        return None
    ks = [c[0] for c in curve]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    ax1.plot(ks, [100 * c[1] for c in curve], marker="o")
    ax1.set(xlabel="iteration", ylabel="targets solved (%)", ylim=(0, 101))
    ax1.grid(alpha=0.3)
    floor = 1e-12
    ax2.semilogy(ks, [max(c[2], floor) for c in curve], marker="o", label="position (m)")
    ax2.semilogy(ks, [max(c[3], floor) for c in curve], marker="s", label="rotation (rad)")
    ax2.axhline(1e-4, color="C0", ls=":", lw=1)
    ax2.axhline(1e-3, color="C1", ls=":", lw=1)
    ax2.set(xlabel="iteration", ylabel="median error of the kept start")
    ax2.legend()
    ax2.grid(alpha=0.3)
    fig.suptitle(f"Panda IK: {cfg.targets} targets x {cfg.restarts} starts ({cfg.dtype})")
    fig.tight_layout()
    out.mkdir(parents=True, exist_ok=True)
    path = out / "convergence.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    print(f"saved {path}")
    return str(path)


if __name__ == "__main__":
    main()
