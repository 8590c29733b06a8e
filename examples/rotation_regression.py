"""Rotation regression: a small MLP learns the rotation of a point cloud.

A fixed template cloud ``P`` (anisotropic, so no rotation maps it onto itself) is rotated by a
Haar-random ``R`` and perturbed by Gaussian noise; the network sees the rotated points (in the
template's point order) and predicts ``R`` through :class:`torchlie.nn.RotationHead`.  The same
network is trained once per rotation representation ("6d", "9d", "quaternion", "rotvec") on the
same data stream, with the squared chordal loss, and the mean angular error on a held-out set
is reported in degrees.

Outputs, in ``--out`` (default ``examples/out/``, ignored by git): ``rotation_regression.json``
(the figures and error curves) and ``rotation_regression.png`` (test error against the training
step, one curve per representation; needs matplotlib, and says so on stderr when it is missing).

Run: ``python examples/rotation_regression.py [--quick] [--out DIR] [--no-plot]``
(``--help`` lists every option with its default).
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

from torchlie import so3
from torchlie.nn import REPRESENTATIONS, RotationHead, geodesic_loss

OUT = Path(__file__).resolve().parent / "out"


def make_template(n_points: int, generator: torch.Generator) -> torch.Tensor:
    """Template cloud ``(n_points, 3)``: Gaussian, stretched along the axes, centred."""
    P = torch.randn(n_points, 3, generator=generator) * torch.tensor([1.0, 0.6, 0.3])
    return P - P.mean(dim=0)


def make_batch(
    template: torch.Tensor, n: int, noise: float, generator: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor]:
    """``n`` inputs ``(n, 3 * n_points)`` (rotated, noisy clouds) and their rotations."""
    R = so3.random(n, generator=generator)
    X = template @ R.transpose(-1, -2)  # rows are points: (R p)^T = p^T R^T
    X = X + noise * torch.randn(X.shape, generator=generator)
    return X.flatten(1), R


class Regressor(nn.Module):
    """MLP ``3 * n_points -> hidden -> hidden -> RotationHead``."""

    def __init__(self, n_points: int, hidden: int, representation: str) -> None:
        super().__init__()
        self.body = nn.Sequential(
            nn.Linear(3 * n_points, hidden),
            nn.ReLU(),
            nn.Linear(hidden, hidden),
            nn.ReLU(),
        )
        self.head = RotationHead(hidden, representation=representation)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(self.body(x))


def mean_error_deg(model: nn.Module, X: torch.Tensor, R: torch.Tensor) -> float:
    with torch.no_grad():
        angle = geodesic_loss(model(X), R, reduction="none")
    return float(angle.mean()) * 180.0 / math.pi


def train(representation: str, cfg: argparse.Namespace) -> dict:
    """Train one model; return its error curve and final figures."""
    gen = torch.Generator().manual_seed(cfg.seed)
    template = make_template(cfg.points, gen)
    X_test, R_test = make_batch(template, cfg.test_size, cfg.noise, gen)
    torch.manual_seed(cfg.seed + 1)  # same initial body weights for every representation
    model = Regressor(cfg.points, cfg.hidden, representation)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=cfg.steps)
    data = torch.Generator().manual_seed(cfg.seed + 2)  # the same stream for every model
    curve = [(0, mean_error_deg(model, X_test, R_test))]
    for step in range(1, cfg.steps + 1):
        X, R = make_batch(template, cfg.batch, cfg.noise, data)
        loss = geodesic_loss(model(X), R, kind="chordal")
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if step % cfg.eval_every == 0 or step == cfg.steps:
            curve.append((step, mean_error_deg(model, X_test, R_test)))
    with torch.no_grad():
        angle = geodesic_loss(model(X_test), R_test, reduction="none") * 180.0 / math.pi
    return {
        "initial_error_deg": curve[0][1],
        "final_error_deg": float(angle.mean()),
        "median_error_deg": float(angle.median()),
        "p95_error_deg": float(angle.quantile(0.95)),
        "curve": curve,
    }


def save_plot(results: dict, path: Path) -> Path | None:
    """Error vs step for every representation; ``None`` (said on stderr) without matplotlib."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print(
            "rotation_regression: matplotlib is not installed, so no plot is written "
            "(pip install matplotlib)",
            file=sys.stderr,
        )
        return None
    fig, ax = plt.subplots(figsize=(6, 4))
    for rep, r in results.items():
        ax.plot([s for s, _ in r["curve"]], [e for _, e in r["curve"]], label=rep)
    ax.set_xlabel("training step")
    ax.set_ylabel("mean angular error on the test set (deg)")
    ax.set_yscale("log")
    ax.set_title("Rotation regression: representation comparison")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def parser() -> argparse.ArgumentParser:
    """The command line (options whose default depends on ``--quick`` state both defaults)."""
    p = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--quick", action="store_true", help="short run (CI): 600 steps per model")
    p.add_argument(
        "--steps",
        type=int,
        default=argparse.SUPPRESS,
        help="training steps per model (default: 4000; 600 with --quick)",
    )
    p.add_argument("--out", type=Path, default=OUT, help="folder for the JSON figures and plot")
    p.add_argument("--no-plot", action="store_true", help="write no plot (figures only)")
    p.add_argument("--seed", type=int, default=0, help="seed of the data and the initial weights")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads (small models: 1)")
    return p


def parse(argv: list[str] | None) -> argparse.Namespace:
    cfg = parser().parse_args(argv)
    if "steps" not in cfg:
        cfg.steps = 600 if cfg.quick else 4000
    cfg.points, cfg.hidden, cfg.batch, cfg.lr = 32, 128, 64, 1e-3
    cfg.noise, cfg.test_size = 0.01, 1000
    cfg.eval_every = max(cfg.steps // 20, 1)
    return cfg


def main(argv: list[str] | None = None) -> dict:
    """Train one model per representation and print the error table; returns the figures."""
    cfg = parse(argv)
    threads = torch.get_num_threads()
    torch.set_num_threads(cfg.threads)
    try:
        t0 = time.perf_counter()
        results = {rep: train(rep, cfg) for rep in REPRESENTATIONS}
        seconds = time.perf_counter() - t0
    finally:
        torch.set_num_threads(threads)
    print(f"rotation regression: {cfg.steps} steps x batch {cfg.batch}, {cfg.points} points")
    print(f"{'representation':<15}{'initial (deg)':>14}{'mean (deg)':>12}"
          f"{'median (deg)':>14}{'p95 (deg)':>11}")  # fmt: skip
    for rep, r in results.items():
        print(
            f"{rep:<15}{r['initial_error_deg']:>14.2f}{r['final_error_deg']:>12.2f}"
            f"{r['median_error_deg']:>14.2f}{r['p95_error_deg']:>11.2f}"
        )
    fig = {"steps": cfg.steps, "results": results, "seconds": seconds}
    cfg.out.mkdir(parents=True, exist_ok=True)
    figures = cfg.out / "rotation_regression.json"
    figures.write_text(json.dumps(fig, indent=1) + "\n")
    print(f"figures saved to {figures}")
    plot = None if cfg.no_plot else save_plot(results, cfg.out / "rotation_regression.png")
    if plot:
        print(f"plot saved to {plot}")
    print(f"time: {seconds:.1f} s")
    return {**fig, "figures": figures, "plot": plot}


if __name__ == "__main__":
    main()
