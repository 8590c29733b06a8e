"""Planar pose-graph optimisation (2-D SLAM back end): SE(2) poses from noisy relative measurements.

A robot drives ``--laps`` times round a square with rounded corners, so it revisits places.
Every consecutive pair of poses gets an odometry measurement and pairs close in space but far
apart in time get loop closures; each measurement is the true relative pose ``T_i^-1 T_j``
perturbed by ``Exp(noise)`` (a planar twist).  The poses start from the chained noisy odometry
(which drifts), the first is held fixed (the gauge), and the others are one batched parameter
kept on SE(2) by :class:`torchlie.nn.SE2Parametrization`.  The cost is the sum of squared
whitened residuals ``se2.rminus(T_i^-1 T_j, Z_ij)``, minimised with ``torch.optim.LBFGS``.
Printed: cost, mean heading error and position RMSE against the ground truth, before and after.
With the ``"matrix"`` form (default) LBFGS reaches the optimum in the fewest cost evaluations;
``"pos_complex"`` and ``"twist"`` reach the same optimum, in a few times more.

Outputs, in ``--out`` (default ``examples/out/``, ignored by git): ``planar_pose_graph.json``
(the figures) and ``planar_pose_graph.png`` (the ground truth, the odometry and the optimised
trajectory; needs matplotlib, and says so on stderr when it is missing).

Run: ``python examples/planar_pose_graph.py [--quick] [--out DIR]`` (``--help`` lists every
option with its default).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import torch
from torch import nn
from torch.nn.utils import parametrize

from torchlie import se2
from torchlie.nn import SE2Parametrization

OUT = Path(__file__).resolve().parent / "out"


def ground_truth(n: int, laps: int, dtype: torch.dtype) -> torch.Tensor:
    """``(n, 3, 3)`` poses round a rounded square (half-width 4, corner radius 1.5), heading
    along the path, ``laps`` times."""
    s = torch.linspace(0.0, 2.0 * math.pi * laps, n + 1, dtype=dtype)[:-1]
    c, d = torch.cos(s), torch.sin(s)
    p = 4.0  # superellipse |x|^p + |y|^p = r^p: a square with rounded corners
    x = 4.0 * c.sign() * c.abs() ** (2 / p)
    y = 4.0 * d.sign() * d.abs() ** (2 / p)
    xy = torch.stack((x, y), dim=-1)
    step = torch.roll(xy, -1, dims=0) - torch.roll(xy, 1, dims=0)
    heading = torch.atan2(step[:, 1], step[:, 0])
    return se2.from_xytheta(torch.cat((xy, heading[:, None]), dim=-1))


def make_edges(T: torch.Tensor, max_loops: int, radius: float, gen: torch.Generator):
    """Odometry ``(i, i+1)`` and up to ``max_loops`` loop closures (within ``radius`` in space,
    at least a quarter of the trajectory apart in time); returns ``(edges, n_odometry)``."""
    n = T.shape[0]
    odo = torch.stack((torch.arange(n - 1), torch.arange(1, n)), dim=-1)
    pos = T[:, :2, 2]
    dist = torch.cdist(pos, pos)
    i, j = torch.triu_indices(n, n, offset=n // 4)
    near = dist[i, j] < radius
    loops = torch.stack((i[near], j[near]), dim=-1)
    if loops.shape[0] > max_loops:
        loops = loops[torch.randperm(loops.shape[0], generator=gen)[:max_loops]]
    return torch.cat((odo, loops)), odo.shape[0]


def measure(T: torch.Tensor, edges: torch.Tensor, sigma: torch.Tensor, gen: torch.Generator):
    """Noisy relative poses ``Z_ij = T_i^-1 T_j Exp(noise)``, noise ~ N(0, diag(sigma^2))."""
    rel = se2.between(T[edges[:, 0]], T[edges[:, 1]])
    noise = sigma * torch.randn(edges.shape[0], 3, generator=gen, dtype=T.dtype)
    return se2.rplus(rel, noise)


class PoseGraph(nn.Module):
    """The first pose is fixed (a buffer); the others are one parameter on SE(2)."""

    def __init__(self, T_init: torch.Tensor, representation: str) -> None:
        super().__init__()
        self.register_buffer("anchor", T_init[:1].clone())
        self.free = nn.Parameter(T_init[1:].clone())
        parametrize.register_parametrization(self, "free", SE2Parametrization(representation))

    def poses(self) -> torch.Tensor:
        return torch.cat((self.anchor, self.free), dim=0)


def cost(T: torch.Tensor, edges: torch.Tensor, Z: torch.Tensor, sigma: torch.Tensor):
    """Sum of squared whitened residuals ``Log(Z^-1 T_i^-1 T_j) / sigma``."""
    r = se2.rminus(se2.between(T[edges[:, 0]], T[edges[:, 1]]), Z) / sigma
    return (r * r).sum()


def trajectory_error(T: torch.Tensor, T_true: torch.Tensor) -> tuple[float, float]:
    """Mean heading error (degrees) and position RMSE against the ground truth."""
    angle, dist = se2.distance(T, T_true)
    return float(angle.mean()) * 180.0 / math.pi, float((dist * dist).mean().sqrt())


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--quick", action="store_true", help="small graph (CI): 120 poses")
    p.add_argument(
        "--poses",
        type=int,
        default=argparse.SUPPRESS,
        help="poses in the trajectory (default: 600; 120 with --quick)",
    )
    p.add_argument("--laps", type=int, default=3, help="laps round the square (loop closures)")
    p.add_argument(
        "--representation",
        choices=("pos_complex", "matrix", "twist"),
        default="matrix",
        help="stored parameter of SE2Parametrization",
    )
    p.add_argument(
        "--iterations",
        type=int,
        default=argparse.SUPPRESS,
        help="LBFGS iterations (default: 1000; 200 with --quick)",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the measurement noise")
    p.add_argument("--out", type=Path, default=OUT, help="folder for the JSON figures and plot")
    p.add_argument("--no-plot", action="store_true", help="write no plot (figures only)")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    return p


def parse(argv: list[str] | None) -> argparse.Namespace:
    cfg = parser().parse_args(argv)
    if "poses" not in cfg:
        cfg.poses = 120 if cfg.quick else 600
    if "iterations" not in cfg:
        cfg.iterations = 200 if cfg.quick else 1000
    return cfg


def optimise(model: PoseGraph, cfg, edges, Z, sigma) -> int:
    """Minimise the cost with LBFGS; return the number of cost evaluations."""
    evals = 0
    opt = torch.optim.LBFGS(
        model.parameters(),
        lr=1.0,
        max_iter=cfg.iterations,
        history_size=50,
        tolerance_grad=1e-12,
        tolerance_change=1e-15,
        line_search_fn="strong_wolfe",
    )

    def closure() -> torch.Tensor:
        nonlocal evals
        evals += 1
        opt.zero_grad()
        c = cost(model.poses(), edges, Z, sigma)
        c.backward()
        return c

    opt.step(closure)
    return evals


def save_plot(trajectories: dict[str, torch.Tensor], path: Path) -> Path | None:
    """The (x, y) path of each ``(N, 3, 3)`` trajectory; ``None`` (said on stderr) without
    matplotlib."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print(
            "planar_pose_graph: matplotlib is not installed, so no plot is written "
            "(pip install matplotlib)",
            file=sys.stderr,
        )
        return None
    fig, ax = plt.subplots(figsize=(5, 5))
    for label, T in trajectories.items():
        style = "k--" if label == "ground truth" else "-"
        ax.plot(T[:, 0, 2], T[:, 1, 2], style, label=label, linewidth=1.0)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title("Planar pose graph")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> dict:
    """Build, perturb and optimise the pose graph; print and return the figures."""
    cfg = parse(argv)
    threads = torch.get_num_threads()
    torch.set_num_threads(cfg.threads)
    try:
        return _run(cfg)
    finally:
        torch.set_num_threads(threads)


def _run(cfg: argparse.Namespace) -> dict:
    dtype = torch.float64
    gen = torch.Generator().manual_seed(cfg.seed)
    T_true = ground_truth(cfg.poses, cfg.laps, dtype)
    edges, n_odo = make_edges(T_true, max_loops=2 * cfg.poses, radius=1.0, gen=gen)
    # noise: 2 cm per axis in translation, 0.5 degree in heading
    sigma = torch.tensor([0.02, 0.02, math.radians(0.5)], dtype=dtype)
    Z = measure(T_true, edges, sigma, gen)

    T_init = [T_true[0]]  # chain the odometry from the (known) first pose
    for k in range(n_odo):
        T_init.append(se2.compose(T_init[-1], Z[k]))
    T_init = torch.stack(T_init)

    model = PoseGraph(T_init, cfg.representation)
    with torch.no_grad():
        cost0 = float(cost(model.poses(), edges, Z, sigma))
        cost_true = float(cost(T_true, edges, Z, sigma))
    rot0, trans0 = trajectory_error(T_init, T_true)

    t0 = time.perf_counter()
    evals = optimise(model, cfg, edges, Z, sigma)
    seconds = time.perf_counter() - t0

    with torch.no_grad():
        T = model.poses()
        cost1 = float(cost(T, edges, Z, sigma))
        valid = bool(se2.is_valid(T).all())
    rot1, trans1 = trajectory_error(T, T_true)

    n_edges = edges.shape[0]
    print(
        f"planar pose graph: {cfg.poses} poses, {n_edges} measurements ({n_odo} odometry, "
        f"{n_edges - n_odo} loop closures), LBFGS on SE2Parametrization"
        f"({cfg.representation!r}), {evals} cost evaluations, {seconds:.1f} s"
    )
    print(f"{'':<22}{'cost':>14}{'heading (deg)':>15}{'pos RMSE':>12}")
    print(f"{'before (odometry)':<22}{cost0:>14.1f}{rot0:>15.3f}{trans0:>12.4f}")
    print(f"{'after':<22}{cost1:>14.1f}{rot1:>15.3f}{trans1:>12.4f}")
    print(f"{'ground truth':<22}{cost_true:>14.1f}")

    cfg.out.mkdir(parents=True, exist_ok=True)
    plot = None
    if not cfg.no_plot:
        trajectories = {"ground truth": T_true, "odometry": T_init, "optimised": T}
        plot = save_plot(trajectories, cfg.out / "planar_pose_graph.png")
    figures = {
        "poses": cfg.poses,
        "measurements": n_edges,
        "loop_closures": n_edges - n_odo,
        "representation": cfg.representation,
        "evaluations": evals,
        "seconds": seconds,
        "cost_before": cost0,
        "cost_after": cost1,
        "cost_ground_truth": cost_true,
        "heading_error_deg_before": rot0,
        "heading_error_deg_after": rot1,
        "position_rmse_before": trans0,
        "position_rmse_after": trans1,
        "valid": valid,
    }
    (cfg.out / "planar_pose_graph.json").write_text(json.dumps(figures, indent=2))
    return {**figures, "plot": plot}


if __name__ == "__main__":
    main()
