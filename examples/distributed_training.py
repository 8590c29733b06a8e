"""Distributed training: a pose regression network on several processes with torch's DDP.

A fixed template cloud ``P`` (anisotropic, so no rotation maps it onto itself) is moved by a
random pose ``T = (R, t)`` (``R`` Haar-uniform, ``t`` Gaussian) and perturbed by Gaussian noise;
an MLP sees the moved points (in the template's point order) and predicts ``T`` through
:class:`torchlie.nn.PoseHead`, trained on the squared chordal loss of
:func:`torchlie.nn.se3_geodesic_loss`.  The model is wrapped in
``torch.nn.parallel.DistributedDataParallel``: every process (rank) runs a replica on its own
shard of each global batch (``torch.utils.data.DistributedSampler``), DDP averages the
gradients over the ranks, and the replicas stay identical.  torchlie needs nothing of its own
for this: its ops are element-wise over the batch, keep no state and make no collective calls.

Backend ``gloo`` on CPU and ``nccl`` on CUDA (one GPU per rank).  Started as a plain script the
example spawns its ranks itself (``torch.multiprocessing``) and meets them on ``127.0.0.1`` at a
free port; under ``torchrun`` it takes the ranks and the meeting point torchrun gives.  The
global batch is the same whatever the number of ranks, so the runs are comparable.  Printed:
the test set's mean geodesic (rotation angle) error in degrees and the translation error,
before and after, and whether the replicas' parameters are identical at the end.

Outputs, in ``--out`` (default ``examples/out/``, ignored by git): ``distributed_training.json``
(the figures and curves) and ``distributed_training.png`` (the training loss and the test
error against the step; needs matplotlib, and says so on stderr when it is missing).

Run: ``python examples/distributed_training.py [--quick] [--world-size N] [--out DIR]``
or ``torchrun --standalone --nproc-per-node 2 examples/distributed_training.py [--quick]``
(``--help`` lists every option with its default).
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import socket
import sys
import time
from pathlib import Path

import torch
import torch.distributed as dist
from torch import nn
from torch.nn.parallel import DistributedDataParallel
from torch.utils.data import DataLoader, DistributedSampler, TensorDataset

from torchlie import se3, so3
from torchlie.nn import PoseHead, geodesic_loss, se3_geodesic_loss

OUT = Path(__file__).resolve().parent / "out"
NAME = "distributed_training"


# ----------------------------------------------------------------------------------------------
# Data and model
# ----------------------------------------------------------------------------------------------


def make_template(n_points: int, generator: torch.Generator) -> torch.Tensor:
    """Template cloud ``(n_points, 3)``: Gaussian, stretched along the axes, centred."""
    P = torch.randn(n_points, 3, generator=generator) * torch.tensor([1.0, 0.6, 0.3])
    return P - P.mean(dim=0)


def make_data(
    template: torch.Tensor, n: int, noise: float, generator: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor]:
    """``n`` inputs ``(n, 3 * n_points)`` (moved, noisy clouds) and their poses ``(n, 4, 4)``."""
    T = se3.from_rt(so3.random(n, generator=generator), torch.randn(n, 3, generator=generator))
    X = se3.act(T.unsqueeze(-3), template)  # (n, n_points, 3): R p + t
    X = X + noise * torch.randn(X.shape, generator=generator)
    return X.flatten(1), T


class PoseRegressor(nn.Module):
    """MLP ``3 * n_points -> hidden -> hidden -> PoseHead`` (6-D rotation representation)."""

    def __init__(self, n_points: int, hidden: int) -> None:
        super().__init__()
        self.body = nn.Sequential(
            nn.Linear(3 * n_points, hidden),
            nn.ReLU(),
            nn.Linear(hidden, hidden),
            nn.ReLU(),
        )
        self.head = PoseHead(hidden, representation="6d")

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(self.body(x))


def errors(model: nn.Module, X: torch.Tensor, T: torch.Tensor) -> tuple[float, float]:
    """Mean geodesic rotation error (degrees) and mean translation error on ``(X, T)``."""
    with torch.no_grad():
        T_pred = model(X)
        angle = geodesic_loss(T_pred[..., :3, :3], T[..., :3, :3])
        dist_t = (T_pred[..., :3, 3] - T[..., :3, 3]).norm(dim=-1).mean()
    return math.degrees(float(angle)), float(dist_t)


# ----------------------------------------------------------------------------------------------
# One rank
# ----------------------------------------------------------------------------------------------


def train(rank: int, world: int, local_rank: int, cfg: argparse.Namespace) -> dict | None:
    """Train on this rank inside an initialised process group; rank 0 returns the figures."""
    device = torch.device("cuda", local_rank) if cfg.backend == "nccl" else torch.device("cpu")
    if device.type == "cuda":
        torch.cuda.set_device(device)
    gen = torch.Generator().manual_seed(cfg.seed)
    template = make_template(cfg.points, gen)
    X_train, T_train = make_data(template, cfg.train_size, cfg.noise, gen)
    X_test, T_test = make_data(template, cfg.test_size, cfg.noise, gen)
    X_test, T_test = X_test.to(device), T_test.to(device)

    # --8<-- [start:ddp]
    torch.manual_seed(cfg.seed + 1)  # the same initial weights on every rank (DDP also
    model = PoseRegressor(cfg.points, cfg.hidden).to(device)  # broadcasts rank 0's at start)
    ddp = DistributedDataParallel(model, device_ids=[local_rank] if device.type == "cuda" else None)
    opt = torch.optim.Adam(ddp.parameters(), lr=cfg.lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=cfg.steps)

    # Each rank reads its shard (batch / world samples) of every global batch.
    train_set = TensorDataset(X_train, T_train)
    sampler = DistributedSampler(train_set, num_replicas=world, rank=rank, seed=cfg.seed + 2)
    loader = DataLoader(train_set, batch_size=cfg.batch // world, sampler=sampler)

    curve_loss, curve_error = [], [(0, *errors(model, X_test, T_test))]
    step, epoch = 0, 0
    while step < cfg.steps:
        sampler.set_epoch(epoch)  # a new shuffle each epoch, the same on every rank
        epoch += 1
        for X, T in loader:
            X, T = X.to(device), T.to(device)
            loss = se3_geodesic_loss(ddp(X), T, kind="chordal")
            opt.zero_grad()
            loss.backward()  # DDP's hooks average the gradients over the ranks here
            opt.step()
            sched.step()
            step += 1
            mean_loss = loss.detach().clone()
            dist.all_reduce(mean_loss)  # the loss of the global batch, for the curve
            curve_loss.append((step, float(mean_loss) / world))
            if rank == 0 and (step % cfg.eval_every == 0 or step == cfg.steps):
                curve_error.append((step, *errors(model, X_test, T_test)))
            if step == cfg.steps:
                break
    # --8<-- [end:ddp]

    # The replicas are identical: gather every rank's parameters and compare them.
    flat = torch.cat([p.detach().flatten() for p in model.parameters()])
    gathered = [torch.empty_like(flat) for _ in range(world)]
    dist.all_gather(gathered, flat)
    if rank != 0:
        return None
    identical = all(torch.equal(g, gathered[0]) for g in gathered)
    return {
        "world_size": world,
        "backend": cfg.backend,
        "device": str(device),
        "steps": cfg.steps,
        "global_batch": cfg.batch,
        "initial_rotation_error_deg": curve_error[0][1],
        "initial_translation_error": curve_error[0][2],
        "final_rotation_error_deg": curve_error[-1][1],
        "final_translation_error": curve_error[-1][2],
        "replicas_identical": identical,
        "loss_curve": curve_loss,
        "error_curve": curve_error,
    }


def loopback_interface() -> str:
    """Name of the loopback network interface (read on Linux, the usual name elsewhere)."""
    net = Path("/sys/class/net")
    if net.is_dir():
        for iface in sorted(net.iterdir()):
            try:
                if int((iface / "flags").read_text(), 16) & 0x8:  # IFF_LOOPBACK
                    return iface.name
            except (OSError, ValueError):
                continue
    return "lo0" if sys.platform == "darwin" else "lo"


def free_port() -> int:
    """A TCP port free on 127.0.0.1 (the system's choice for port 0)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def spawned(rank: int, world: int, cfg: argparse.Namespace, port: int, figures: Path) -> None:
    """Entry point of a spawned rank: meet on 127.0.0.1, train, rank 0 writes the figures."""
    torch.set_num_threads(cfg.threads)
    # gloo and nccl exchange their data over the loopback interface only
    os.environ.setdefault("GLOO_SOCKET_IFNAME", loopback_interface())
    os.environ.setdefault("NCCL_SOCKET_IFNAME", loopback_interface())
    dist.init_process_group(
        cfg.backend,
        init_method=f"tcp://127.0.0.1:{port}",
        rank=rank,
        world_size=world,
        timeout=datetime.timedelta(seconds=cfg.timeout),
    )
    try:
        fig = train(rank, world, rank, cfg)
        if fig is not None:
            figures.write_text(json.dumps(fig, indent=1) + "\n")
        dist.barrier()  # no rank tears its connections down while another still uses them
    finally:
        dist.destroy_process_group()
    leave()


def leave() -> None:
    """End a spawned rank whose work is done and saved, without the interpreter's teardown:
    there torch's gloo threads can still abort the process (``std::terminate`` in a static
    destructor), which would fail a finished run."""
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)


# ----------------------------------------------------------------------------------------------
# Command line and report
# ----------------------------------------------------------------------------------------------


def save_plot(fig: dict, path: Path) -> Path | None:
    """Training loss and test error against the step; ``None`` (said on stderr) without
    matplotlib."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print(
            f"{NAME}: matplotlib is not installed, so no plot is written (pip install matplotlib)",
            file=sys.stderr,
        )
        return None
    figure, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    left.plot([s for s, _ in fig["loss_curve"]], [v for _, v in fig["loss_curve"]], lw=0.8)
    left.set_xlabel("training step")
    left.set_ylabel("squared chordal loss (global batch)")
    left.set_yscale("log")
    steps = [s for s, _, _ in fig["error_curve"]]
    right.plot(steps, [r for _, r, _ in fig["error_curve"]], label="rotation (deg)")
    right.plot(steps, [t for _, _, t in fig["error_curve"]], label="translation")
    right.set_xlabel("training step")
    right.set_ylabel("mean error on the test set")
    right.set_yscale("log")
    right.legend()
    figure.suptitle(
        f"Pose regression with DDP: {fig['world_size']} ranks, {fig['backend']}, "
        f"global batch {fig['global_batch']}"
    )
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)
    return path


def parser() -> argparse.ArgumentParser:
    """The command line (options whose default depends on ``--quick`` or on the machine state
    both defaults)."""
    p = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--quick", action="store_true", help="short run (CI): 300 steps")
    p.add_argument(
        "--steps",
        type=int,
        default=argparse.SUPPRESS,
        help="optimiser steps (default: 3000; 300 with --quick)",
    )
    p.add_argument(
        "--world-size",
        type=int,
        default=argparse.SUPPRESS,
        help="processes to spawn, ignored under torchrun "
        "(default: the number of GPUs with CUDA, else 2)",
    )
    p.add_argument(
        "--backend",
        choices=("auto", "gloo", "nccl"),
        default="auto",
        help="torch.distributed backend; auto is nccl with CUDA, else gloo",
    )
    p.add_argument("--out", type=Path, default=OUT, help="folder for the JSON figures and plot")
    p.add_argument("--no-plot", action="store_true", help="write no plot (figures only)")
    p.add_argument("--seed", type=int, default=0, help="seed of the data and the initial weights")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads per rank")
    return p


def parse(argv: list[str] | None) -> argparse.Namespace:
    cfg = parser().parse_args(argv)
    if "steps" not in cfg:
        cfg.steps = 300 if cfg.quick else 3000
    cuda = torch.cuda.is_available()
    if cfg.backend == "auto":
        cfg.backend = "nccl" if cuda else "gloo"
    if cfg.backend == "nccl" and not cuda:
        raise SystemExit(f"{NAME}: the nccl backend needs CUDA; use --backend gloo on CPU")
    if "world_size" not in cfg:
        cfg.world_size = torch.cuda.device_count() if cfg.backend == "nccl" else 2
    if cfg.steps < 1 or cfg.world_size < 1:
        raise SystemExit(f"{NAME}: --steps and --world-size must be at least 1")
    gpus = torch.cuda.device_count()
    if cfg.backend == "nccl" and not under_torchrun() and cfg.world_size > gpus:
        raise SystemExit(
            f"{NAME}: nccl takes one GPU per rank: --world-size {cfg.world_size} with {gpus} GPUs"
        )
    cfg.points, cfg.hidden, cfg.batch, cfg.lr = 32, 128, 64, 2e-3
    cfg.noise, cfg.train_size, cfg.test_size = 0.01, 8192, 1000
    cfg.eval_every = max(cfg.steps // 20, 1)
    cfg.timeout = 300  # seconds a rank waits for the others in a collective before it fails
    return cfg


def under_torchrun() -> bool:
    return all(k in os.environ for k in ("RANK", "WORLD_SIZE", "LOCAL_RANK", "MASTER_ADDR"))


def report(fig: dict, seconds: float, cfg: argparse.Namespace) -> dict:
    """Print the figures, write them and the plot to ``--out``; return them with the paths."""
    fig = {**fig, "seconds": seconds}
    print(
        f"{NAME}: {fig['world_size']} ranks ({fig['backend']}, {fig['device']}), "
        f"{fig['steps']} steps x global batch {fig['global_batch']}"
    )
    print(f"{'':<22}{'rotation (deg)':>16}{'translation':>13}")
    print(
        f"{'before training':<22}{fig['initial_rotation_error_deg']:>16.2f}"
        f"{fig['initial_translation_error']:>13.4f}"
    )
    print(
        f"{'after training':<22}{fig['final_rotation_error_deg']:>16.2f}"
        f"{fig['final_translation_error']:>13.4f}"
    )
    print(f"final geodesic error: {fig['final_rotation_error_deg']:.2f} deg (test-set mean)")
    print(f"replicas identical: {fig['replicas_identical']}")
    cfg.out.mkdir(parents=True, exist_ok=True)
    figures = cfg.out / f"{NAME}.json"
    figures.write_text(json.dumps(fig, indent=1) + "\n")
    print(f"figures saved to {figures}")
    plot = None if cfg.no_plot else save_plot(fig, cfg.out / f"{NAME}.png")
    if plot:
        print(f"plot saved to {plot}")
    print(f"time: {seconds:.1f} s")
    return {**fig, "figures": figures, "plot": plot}


def main(argv: list[str] | None = None) -> dict | None:
    """Train with DDP (spawned ranks, or this rank under torchrun); rank 0 reports and returns
    the figures, other ranks return ``None``."""
    cfg = parse(argv)
    if under_torchrun():
        cfg.world_size = int(os.environ["WORLD_SIZE"])
    if cfg.batch % cfg.world_size:
        raise SystemExit(f"{NAME}: the global batch {cfg.batch} must divide by the world size")
    t0 = time.perf_counter()
    if under_torchrun():
        rank, world = int(os.environ["RANK"]), cfg.world_size
        local_rank = int(os.environ["LOCAL_RANK"])
        torch.set_num_threads(cfg.threads)
        dist.init_process_group(cfg.backend, timeout=datetime.timedelta(seconds=cfg.timeout))
        try:
            fig = train(rank, world, local_rank, cfg)
            dist.barrier()  # no rank tears its connections down while another still uses them
        finally:
            dist.destroy_process_group()
        if fig is None:
            return None
    else:
        cfg.out.mkdir(parents=True, exist_ok=True)
        figures = cfg.out / f"{NAME}.json"
        figures.unlink(missing_ok=True)
        torch.multiprocessing.spawn(
            spawned, args=(cfg.world_size, cfg, free_port(), figures), nprocs=cfg.world_size
        )
        fig = json.loads(figures.read_text())
    return report(fig, time.perf_counter() - t0, cfg)


if __name__ == "__main__":
    main()
