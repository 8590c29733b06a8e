"""Payload identification: the mass and centre of mass of an unknown payload from joint torques.

The Franka Emika Panda holds a payload (a point mass of ``--payload`` kg, 5 cm off its flange
axis, 12 cm beyond the hand) that its model does not know.  Joint torques are "measured" at
random states (positions within the limits, velocities and accelerations drawn at random) by
:meth:`Chain.inverse_dynamics <torchlie.kinematics.Chain.inverse_dynamics>` with the payload,
plus Gaussian noise of ``--noise`` N m.  The payload's mass ``m`` and position ``c`` (in the
frame of ``panda_link7``, the body the hand is fixed to) are then identified by Gauss-Newton on the
torque residuals: the model's inertials are the arm's own with the payload merged
into ``panda_link7`` (parallel-axis theorem, written in torch), passed to ``inverse_dynamics``
as ``inertials=``, so autograd gives the gradient with respect to ``m`` and ``c`` through the
whole recursive Newton-Euler pass in one batched call.

Outputs, in ``--out`` (default ``examples/out/``, ignored by git):
``payload_identification.json`` (the figures and the history of the estimates) and
``payload_identification.png`` (mass estimate and torque residual against the iteration; needs
matplotlib, and says so on stderr when it is missing).

Run: ``python examples/payload_identification.py [--quick] [--out DIR] [--no-plot]``
(``--help`` lists every option with its default).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

from torchlie.kinematics import Chain, sample_robot
from torchlie.kinematics.dynamics import Inertials

OUT = Path(__file__).resolve().parent / "out"
BODY = "panda_link7"
#: The payload's true position in the frame of panda_link7 (m): 5 cm off the flange axis, 12 cm
#: beyond the hand's tool centre point (0.107 + 0.1034 m along z).
TRUE_OFFSET = (0.05, 0.0, 0.107 + 0.1034 + 0.12)


def with_payload(base: Inertials, b: int, m: torch.Tensor, c: torch.Tensor) -> Inertials:
    """``base`` with a point mass ``m`` at ``c`` (body ``b``'s frame) merged into body ``b``
    (the joints' armature, left out, stays the chain's own)."""
    mb, cb, Ib = base.mass[b], base.com[b], base.inertia[b]
    total = mb + m
    com = (mb * cb + m * c) / total
    eye = torch.eye(3, dtype=c.dtype)

    def shift(mass: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        return mass * ((d * d).sum() * eye - torch.outer(d, d))

    inertia = Ib + shift(mb, cb - com) + shift(m, c - com)
    onehot = torch.zeros_like(base.mass)
    onehot[b] = 1.0
    return Inertials(
        base.mass + onehot * m,
        torch.cat((base.com[:b], com.unsqueeze(0), base.com[b + 1 :])),
        torch.cat((base.inertia[:b], inertia.unsqueeze(0), base.inertia[b + 1 :])),
    )


def parser() -> argparse.ArgumentParser:
    """The command line (options whose default depends on ``--quick`` state both defaults)."""
    p = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--quick", action="store_true", help="short run (CI): 200 states")
    p.add_argument(
        "--states",
        type=int,
        default=argparse.SUPPRESS,
        help="measured states (default: 2000; 200 with --quick)",
    )
    p.add_argument("--payload", type=float, default=1.5, help="the payload's true mass in kg")
    p.add_argument("--noise", type=float, default=0.05, help="torque noise std in N m")
    p.add_argument("--iterations", type=int, default=6, help="Gauss-Newton iterations")
    p.add_argument("--out", type=Path, default=OUT, help="folder for the JSON figures and plot")
    p.add_argument("--no-plot", action="store_true", help="write no plot (figures only)")
    p.add_argument("--seed", type=int, default=0, help="seed of the states and the noise")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    return p


def parse(argv: list[str] | None) -> argparse.Namespace:
    cfg = parser().parse_args(argv)
    if "states" not in cfg:
        cfg.states = 200 if cfg.quick else 2000
    return cfg


def identify(cfg: argparse.Namespace) -> dict:
    dt = torch.float64
    arm = Chain.from_urdf(sample_robot("panda"), dtype=dt)
    b = arm.body_names.index(BODY)
    base = arm.inertials
    gen = torch.Generator().manual_seed(cfg.seed)
    q = arm.random_configuration(cfg.states, generator=gen)
    qd = torch.randn(cfg.states, arm.n_dof, generator=gen, dtype=dt)
    qdd = 2.0 * torch.randn(cfg.states, arm.n_dof, generator=gen, dtype=dt)
    m_true = torch.tensor(cfg.payload, dtype=dt)
    c_true = torch.tensor(TRUE_OFFSET, dtype=dt)
    truth = with_payload(base, b, m_true, c_true)
    tau = arm.inverse_dynamics(q, qd, qdd, inertials=truth)
    tau = tau + cfg.noise * torch.randn(tau.shape, generator=gen, dtype=dt)

    # Unknowns x = (m, c): the mass and the position; the initial guess is no payload, at the
    # flange.  Gauss-Newton on the torque residuals r(x), with the Jacobian dr/dx by
    # forward-mode autodiff (four directions) through the batched inverse dynamics.
    x = torch.tensor([0.0, 0.0, 0.0, 0.107], dtype=dt)

    def residuals(x: torch.Tensor) -> torch.Tensor:
        pred = arm.inverse_dynamics(q, qd, qdd, inertials=with_payload(base, b, x[0], x[1:]))
        return (pred - tau).reshape(-1)

    history = []
    t0 = time.perf_counter()
    for it in range(cfg.iterations + 1):
        r = residuals(x)
        history.append(
            {
                "iteration": it,
                "mass_kg": float(x[0]),
                "com_error_m": float(torch.linalg.vector_norm(x[1:] - c_true)),
                "rms_torque_residual_Nm": float(r.square().mean().sqrt()),
            }
        )
        if it == cfg.iterations:
            break
        J = torch.func.jacfwd(residuals)(x)  # (N n_dof, 4)
        step = torch.linalg.lstsq(J, r.unsqueeze(-1)).solution.squeeze(-1)
        x = x - step
    seconds = time.perf_counter() - t0
    m, c = x[0], x[1:]
    return {
        "states": cfg.states,
        "noise_Nm": cfg.noise,
        "true_mass_kg": cfg.payload,
        "mass_kg": float(m),
        "mass_error_rel": abs(float(m) - cfg.payload) / cfg.payload,
        "true_offset_m": list(TRUE_OFFSET),
        "offset_m": [float(v) for v in c],
        "com_error_m": float(torch.linalg.vector_norm(c - c_true)),
        "rms_torque_residual_Nm": history[-1]["rms_torque_residual_Nm"],
        "iterations": cfg.iterations,
        "seconds": seconds,
        "history": history,
        "plot": None,
    }


def save_plot(fig: dict, path: Path) -> Path | None:
    """Mass estimate and residual against the iteration; ``None`` (said on stderr) without
    matplotlib."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print(
            "payload_identification: matplotlib is not installed, so no plot is written "
            "(pip install matplotlib)",
            file=sys.stderr,
        )
        return None
    h = fig["history"]
    its = [e["iteration"] for e in h]
    f, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    ax1.plot(its, [e["mass_kg"] for e in h], marker="o", label="estimate")
    ax1.axhline(fig["true_mass_kg"], color="k", ls=":", label="true mass")
    ax1.set(xlabel="Gauss-Newton iteration", ylabel="payload mass (kg)")
    ax1.legend()
    ax1.grid(alpha=0.3)
    rms = [e["rms_torque_residual_Nm"] for e in h]
    ax2.semilogy(its, rms, marker="o", label="RMS torque residual (N m)")
    ax2.semilogy(its, [max(e["com_error_m"], 1e-6) for e in h], marker="s", label="|c - c*| (m)")
    ax2.axhline(fig["noise_Nm"], color="C0", ls=":", lw=1, label="noise std (N m)")
    ax2.set(xlabel="Gauss-Newton iteration")
    ax2.legend()
    ax2.grid(alpha=0.3)
    f.suptitle(f"Panda payload identification from {fig['states']} torque measurements")
    f.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    f.savefig(path, dpi=120)
    plt.close(f)
    return path


def main(argv: list[str] | None = None) -> dict:
    """Identify the payload; print, save and return the figures."""
    cfg = parse(argv)
    threads = torch.get_num_threads()
    torch.set_num_threads(cfg.threads)
    try:
        fig = identify(cfg)
    finally:
        torch.set_num_threads(threads)
    print(
        f"payload identification, Panda, {fig['states']} states, noise {fig['noise_Nm']} N m: "
        f"mass {fig['mass_kg']:.4f} kg (true {fig['true_mass_kg']} kg, "
        f"{100 * fig['mass_error_rel']:.3f} % off), centre of mass off by "
        f"{1e3 * fig['com_error_m']:.2f} mm, RMS residual {fig['rms_torque_residual_Nm']:.4f} "
        f"N m, {fig['iterations']} Gauss-Newton iterations in {fig['seconds']:.2f} s"
    )
    cfg.out.mkdir(parents=True, exist_ok=True)
    if not cfg.no_plot:
        path = save_plot(fig, cfg.out / "payload_identification.png")
        fig["plot"] = None if path is None else str(path)
    (cfg.out / "payload_identification.json").write_text(json.dumps(fig, indent=1) + "\n")
    return fig


if __name__ == "__main__":
    main()
