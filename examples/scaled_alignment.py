"""Scaled trajectory alignment: a monocular-style trajectory mapped onto the truth by Sim(3).

A camera trajectory is estimated up to an unknown similarity: the estimate lives in its own
frame, at its own scale (as a monocular SLAM system's does), with noise on every position and
orientation.  The example recovers the similarity two ways and compares them:

* closed form: Umeyama's alignment of the positions, :func:`torchlie.statistics.align` with
  ``scale=True``, read as a :class:`torchlie.Sim3` (``.sim3()``);
* optimisation: a :class:`torchlie.nn.Sim3Parametrization` (a Sim(3) tangent read through
  :func:`torchlie.sim3.exp`) fitted with L-BFGS to the same positions *and* the orientations,
  through :func:`torchlie.sim3.log` of the residual similarities.

It reports the absolute trajectory error (RMSE of the positions, in the ground truth's metres)
and the mean rotation error before and after each, and the recovered scale.

Outputs, in ``--out`` (default ``examples/out/``, ignored by git): ``scaled_alignment.json``
(the figures) and ``scaled_alignment.png`` (top view of the trajectories; needs matplotlib,
and says so on stderr when it is missing).

Run: ``python examples/scaled_alignment.py [--quick] [--out DIR] [--no-plot]``
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
from torch.nn.utils import parametrize

from torchlie import Sim3, se3, sim3, so3, statistics
from torchlie.nn import Sim3Parametrization

OUT = Path(__file__).resolve().parent / "out"


def ground_truth(n: int, dtype: torch.dtype) -> torch.Tensor:
    """``(n, 4, 4)`` camera poses on a rising figure-of-eight, looking along the path."""
    s = torch.linspace(0.0, 2.0 * math.pi, n, dtype=dtype)
    p = torch.stack((4.0 * torch.sin(s), 2.0 * torch.sin(2.0 * s), 0.3 * s), -1)
    heading = torch.atan2(8.0 * torch.cos(2.0 * s), 4.0 * torch.cos(s))  # of dp/ds in x, y
    w = torch.stack((torch.zeros_like(s), torch.zeros_like(s), heading), -1)
    return se3.from_rt(so3.exp(w), p)


def estimate(
    T_true: torch.Tensor, S: torch.Tensor, noise: float, gen: torch.Generator
) -> torch.Tensor:
    """The trajectory as an estimator in another frame reports it: positions ``S^-1 p`` and
    orientations ``R_S^T R``, each with Gaussian noise (``noise`` in the estimate's units and
    radians), as ``(n, 4, 4)`` poses."""
    n = T_true.shape[0]
    Si = sim3.inverse(S)
    p = sim3.act(Si, T_true[:, :3, 3]) + noise * torch.randn(n, 3, generator=gen, dtype=S.dtype)
    _, R_S, _ = sim3.to_srt(S)
    R = R_S.transpose(-1, -2) @ T_true[:, :3, :3]
    R = R @ so3.exp(noise * torch.randn(n, 3, generator=gen, dtype=S.dtype))
    return se3.from_rt(R, p)


def errors(S: torch.Tensor, T_est: torch.Tensor, T_true: torch.Tensor) -> tuple[float, float]:
    """ATE (RMSE of the positions, metres) and mean rotation error (degrees) of the estimate
    mapped by the similarity ``S``."""
    p = sim3.act(S, T_est[:, :3, 3])
    ate = float((p - T_true[:, :3, 3]).square().sum(-1).mean().sqrt())
    _, R_S, _ = sim3.to_srt(S)
    rot = so3.distance(R_S @ T_est[:, :3, :3], T_true[:, :3, :3])
    return ate, float(rot.mean()) * 180.0 / math.pi


def fit(T_est: torch.Tensor, T_true: torch.Tensor, start: torch.Tensor, iterations: int) -> dict:
    """Sim(3) fitted with L-BFGS: positions and orientations (as the rotation vectors of the
    residual rotations), from the similarity ``start``."""
    holder = torch.nn.Module()
    holder.S = torch.nn.Parameter(start.clone())
    parametrize.register_parametrization(holder, "S", Sim3Parametrization("tangent"))
    opt = torch.optim.LBFGS(holder.parameters(), max_iter=iterations, line_search_fn="strong_wolfe")
    est = sim3.from_se3(T_est, torch.ones((), dtype=T_est.dtype))
    truth = sim3.from_se3(T_true, torch.ones((), dtype=T_true.dtype))

    def cost() -> torch.Tensor:
        opt.zero_grad()
        mapped = sim3.compose(holder.S, est)
        p = mapped[:, :3, 3] - T_true[:, :3, 3]
        # the rotation part of Log(truth^-1 mapped), its scale part left free
        r = sim3.log(sim3.between(truth, mapped))[:, 3:6]
        c = p.square().sum() + r.square().sum()
        c.backward()
        return c

    opt.step(cost)
    return {"S": holder.S.detach().clone(), "cost": float(cost().detach())}


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--quick", action="store_true", help="a short trajectory (CI): 60 poses")
    p.add_argument("--poses", type=int, default=400, help="poses on the trajectory")
    p.add_argument("--noise", type=float, default=0.02, help="noise of the estimate, per axis")
    p.add_argument("--iterations", type=int, default=50, help="L-BFGS iterations")
    p.add_argument("--seed", type=int, default=0, help="seed of the similarity and the noise")
    p.add_argument("--out", type=Path, default=OUT, help="folder for the JSON figures and plot")
    p.add_argument("--no-plot", action="store_true", help="write no plot (figures only)")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    return p


def save_plot(trajectories: dict[str, torch.Tensor], path: Path) -> Path | None:
    """Top view (x, y) of each ``(N, 3)`` position track; ``None`` (said on stderr) without
    matplotlib."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print(
            "scaled_alignment: matplotlib is not installed, so no plot is written "
            "(pip install matplotlib)",
            file=sys.stderr,
        )
        return None
    fig, ax = plt.subplots(figsize=(5, 5))
    for label, p in trajectories.items():
        dashed = label == "ground truth"
        ax.plot(p[:, 0], p[:, 1], "k--" if dashed else "-", label=label, linewidth=1.0)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title("Scaled alignment: positions seen from above")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> dict:
    """Build the trajectories, align them both ways; print and return the figures."""
    cfg = parser().parse_args(argv)
    if cfg.quick:
        cfg.poses = 60
    threads = torch.get_num_threads()
    torch.set_num_threads(cfg.threads)
    try:
        return _run(cfg)
    finally:
        torch.set_num_threads(threads)


def _run(cfg: argparse.Namespace) -> dict:
    start = time.perf_counter()
    dtype = torch.float64
    gen = torch.Generator().manual_seed(cfg.seed)
    T_true = ground_truth(cfg.poses, dtype)
    # the unknown similarity from the estimate's frame to the world: scale 1/3 to 3
    xi = torch.randn(7, generator=gen, dtype=dtype) * torch.tensor([2.0] * 3 + [1.0] * 3 + [0.5])
    S_true = sim3.exp(xi)
    T_est = estimate(T_true, S_true, cfg.noise, gen)

    identity = sim3.identity(dtype=dtype)
    ate0, rot0 = errors(identity, T_est, T_true)
    umeyama = statistics.align(T_est[:, :3, 3], T_true[:, :3, 3], scale=True).sim3()
    assert isinstance(umeyama, Sim3)
    ate1, rot1 = errors(umeyama.matrix, T_est, T_true)
    refined = fit(T_est, T_true, umeyama.matrix, cfg.iterations)
    ate2, rot2 = errors(refined["S"], T_est, T_true)

    figures = {
        "poses": cfg.poses,
        "noise": cfg.noise,
        "scale_true": float(sim3.scale(S_true)),
        "scale_umeyama": float(umeyama.scale),
        "scale_refined": float(sim3.scale(refined["S"])),
        "ate_before": ate0,
        "ate_umeyama": ate1,
        "ate_refined": ate2,
        "rot_error_deg_before": rot0,
        "rot_error_deg_umeyama": rot1,
        "rot_error_deg_refined": rot2,
        "similarity_error": float(sim3.log(sim3.between(S_true, refined["S"])).norm()),
        "valid": bool(sim3.is_valid(refined["S"])),
    }
    print(f"scale: true {figures['scale_true']:.4f}, Umeyama {figures['scale_umeyama']:.4f}, "
          f"refined {figures['scale_refined']:.4f}")  # fmt: skip
    print(f"{'':22s}{'ATE (m)':>10s}{'rotation (deg)':>16s}")
    for label, a, r in (
        ("before (raw estimate)", ate0, rot0),
        ("Umeyama (positions)", ate1, rot1),
        ("refined (+ rotations)", ate2, rot2),
    ):
        print(f"{label:22s}{a:10.4f}{r:16.3f}")
    cfg.out.mkdir(parents=True, exist_ok=True)
    plot = None
    if not cfg.no_plot:
        tracks = {
            "ground truth": T_true[:, :3, 3],
            "raw estimate": T_est[:, :3, 3],
            "aligned (Sim(3))": sim3.act(refined["S"], T_est[:, :3, 3]),
        }
        plot = save_plot(tracks, cfg.out / "scaled_alignment.png")
    figures["seconds"] = time.perf_counter() - start
    (cfg.out / "scaled_alignment.json").write_text(json.dumps(figures, indent=2) + "\n")
    figures["plot"] = plot
    return figures


if __name__ == "__main__":
    main()
