"""Batched inverse kinematics by gradient descent on the forward kinematics of the sample arm.

Targets are tool poses of the bundled 7-DOF arm (``torchlie.kinematics.sample_robot("arm7")``)
at random joint configurations within the limits, so every target is reachable.  For each
target, several random initial configurations (restarts) are optimised at once: one batch of
``targets x restarts`` joint vectors, one forward-kinematics call per step, Adam on the summed
pose error ``|p - p*|^2 + w |R - R*|_F^2`` (:func:`torchlie.nn.se3_geodesic_loss` with
``kind="chordal"``), joint values clamped to their limits after every step.  The best restart
per target is kept.  A target counts as solved when the tool is within 1 mm and 0.5 degree
of it.

Run: ``python examples/inverse_kinematics.py [--quick] [--targets N] [--restarts K]``.
"""

from __future__ import annotations

import argparse
import math
import time

import torch

from torchlie import se3
from torchlie.kinematics import Chain, sample_robot
from torchlie.nn import se3_geodesic_loss

TOOL = "tool_tcp"
POS_TOL = 1e-3  # m
ROT_TOL = math.radians(0.5)  # rad


def parse(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="fewer targets and steps (CI)")
    p.add_argument("--targets", type=int, default=None)
    p.add_argument("--restarts", type=int, default=None)
    p.add_argument("--steps", type=int, default=None)
    p.add_argument("--lr", type=float, default=0.3)
    p.add_argument("--rotation-weight", type=float, default=0.1, help="m^2 per unit chordal")
    p.add_argument("--dtype", choices=("float32", "float64"), default="float32")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    cfg = p.parse_args(argv)
    if cfg.targets is None:
        cfg.targets = 200 if cfg.quick else 1000
    if cfg.restarts is None:
        cfg.restarts = 8
    if cfg.steps is None:
        cfg.steps = 500 if cfg.quick else 1000
    return cfg


def best_restart(arm: Chain, q: torch.Tensor, target: torch.Tensor):
    """Per target, the restart closest to both tolerances: ``(q, position err, rotation err)``."""
    with torch.no_grad():
        T = arm.forward_kinematics(q, TOOL)[TOOL]
        rot, trans = se3.distance(T, target)
        best = (trans / POS_TOL + rot / ROT_TOL).argmin(dim=1)
        idx = torch.arange(q.shape[0])
    return q.detach()[idx, best], trans[idx, best], rot[idx, best]


def solve(arm: Chain, T_target: torch.Tensor, cfg: argparse.Namespace, gen: torch.Generator):
    """Adam on ``(targets, restarts, n_dof)`` joint values; returns the best restart per target
    before and after, and the mean loss per step."""
    n, k = T_target.shape[0], cfg.restarts
    q = arm.random_configuration(n, k, generator=gen).requires_grad_()
    lower, upper = arm.lower, arm.upper
    target = T_target.unsqueeze(1)  # broadcast over restarts
    initial = best_restart(arm, q, target)
    opt = torch.optim.Adam([q], lr=cfg.lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=cfg.steps, eta_min=cfg.lr * 1e-3)
    history = []
    for _ in range(cfg.steps):
        T = arm.forward_kinematics(q, TOOL)[TOOL]
        loss = se3_geodesic_loss(
            T, target, cfg.rotation_weight, 1.0, kind="chordal", reduction="none"
        )
        opt.zero_grad()
        loss.sum().backward()  # the problems are independent: each q sees only its own loss
        opt.step()
        sched.step()
        with torch.no_grad():
            q.copy_(torch.maximum(torch.minimum(q, upper), lower))
        history.append(float(loss.detach().mean()))
    return initial, best_restart(arm, q, target), history


def main(argv: list[str] | None = None) -> dict:
    """Solve the batch of IK problems; print and return the figures."""
    cfg = parse(argv)
    threads = torch.get_num_threads()
    torch.set_num_threads(cfg.threads)
    try:
        return _run(cfg)
    finally:
        torch.set_num_threads(threads)


def _run(cfg: argparse.Namespace) -> dict:
    dtype = getattr(torch, cfg.dtype)
    arm = Chain.from_urdf(sample_robot("arm7"), dtype=dtype)
    gen = torch.Generator().manual_seed(cfg.seed)
    q_true = arm.random_configuration(cfg.targets, generator=gen)
    with torch.no_grad():
        T_target = arm.forward_kinematics(q_true, TOOL)[TOOL]

    t0 = time.perf_counter()
    (_, trans0, rot0), (q, trans, rot), history = solve(arm, T_target, cfg, gen)
    seconds = time.perf_counter() - t0

    with torch.no_grad():  # independent check of the returned solutions
        rot_chk, trans_chk = se3.distance(arm.forward_kinematics(q, TOOL)[TOOL], T_target)
    within = bool(((q >= arm.lower) & (q <= arm.upper)).all())
    solved = (trans <= POS_TOL) & (rot <= ROT_TOL)
    rate = float(solved.double().mean())
    deg = 180.0 / math.pi
    figures = {
        "targets": cfg.targets,
        "restarts": cfg.restarts,
        "steps": cfg.steps,
        "success_rate": rate,
        "initial_median_position_error_m": float(trans0.median()),
        "initial_median_rotation_error_deg": float(rot0.median()) * deg,
        "median_position_error_m": float(trans.median()),
        "median_rotation_error_deg": float(rot.median()) * deg,
        "p90_position_error_m": float(trans.quantile(0.9)),
        "p90_rotation_error_deg": float(rot.quantile(0.9)) * deg,
        "loss_first": history[0],
        "loss_last": history[-1],
        "recheck_max_position_diff_m": float((trans_chk - trans).abs().max()),
        "within_limits": within,
        "seconds": seconds,
    }
    print(
        f"inverse kinematics, arm7 '{TOOL}' ({cfg.dtype}): {cfg.targets} targets x "
        f"{cfg.restarts} restarts, {cfg.steps} Adam steps on one batch of "
        f"{cfg.targets * cfg.restarts} configurations, {seconds:.1f} s"
    )
    print(f"{'best restart per target':<26}{'median mm':>12}{'median deg':>12}{'p90 mm':>12}"
          f"{'p90 deg':>12}")  # fmt: skip
    for label, t, r in (("initial (random)", trans0, rot0), ("after gradient descent", trans, rot)):
        print(
            f"{label:<26}{float(t.median()) * 1e3:>12.4g}{float(r.median()) * deg:>12.4g}"
            f"{float(t.quantile(0.9)) * 1e3:>12.4g}{float(r.quantile(0.9)) * deg:>12.4g}"
        )
    print(
        f"success (within {POS_TOL * 1e3:.0f} mm and {ROT_TOL * deg:.1f} deg): {100 * rate:.1f} %;"
        f" joint limits respected: {within}"
    )
    return figures


if __name__ == "__main__":
    main()
