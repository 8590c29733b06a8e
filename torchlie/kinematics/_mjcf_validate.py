"""``python -m torchlie.kinematics.validate ROBOT.xml`` for an MJCF file: every body's pose and
every end body's Jacobian of :meth:`Chain.from_mjcf` against MuJoCo's own ``mj_kinematics``
(``xpos``, ``xmat``) and ``mj_jacBody`` at random ``qpos``.

Apart from :mod:`torchlie.kinematics.validate` because MuJoCo is the one oracle here (and the
only reader of the file): the URDF comparisons there (pytorch-kinematics, Pinocchio, the
float64 reference) read URDF.  Tolerances are the same: ``1e-12`` (float64) or ``1e-5``
(float32), times ``1 + size`` for positions and Jacobians, ``size`` the largest distance of a
body from the world origin over the samples (m).

When the model has mass, the dynamics are compared too (inverse dynamics, mass matrix, bias
forces against ``mj_inverse``, ``mj_fullM`` and ``qfrc_bias``; the forward dynamics by the
backward error of MuJoCo's equations of motion, ``|M qdd + bias - tau|`` relative to
``|M| |qdd| + |bias| + |tau|``, as against Pinocchio), on the model compiled again from its
``MjSpec`` with what MuJoCo adds to the rigid bodies and their joints' armature zeroed or
disabled (damping, friction loss, springs, gravity compensation, tendons' and actuators'
armature, contacts, constraints, limits, actuators), with the tolerances of the URDF dynamics
against Pinocchio (:data:`torchlie.kinematics.validate.TOL_DYNAMICS`).  The joints' armature
is kept: the chain adds it as MuJoCo does.  A source given as a compiled ``MjModel`` has no
spec to recompile: its dynamics are not compared.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
import torch

from .chain import Chain
from .dynamics import _plan as _dyn_plan
from .mjcf import _compile, _mujoco


def mujoco_reference(m: Any, qpos: np.ndarray, bodies: list[int]) -> tuple[np.ndarray, ...]:
    """MuJoCo's ``xpos (B, nbody, 3)``, ``xmat (B, nbody, 3, 3)`` and the ``mj_jacBody``
    Jacobians ``(B, len(bodies), 6, nv)`` (linear; angular) at each row of ``qpos``."""
    mujoco = _mujoco()
    d = mujoco.MjData(m)
    B = qpos.shape[0]
    xpos = np.zeros((B, m.nbody, 3))
    xmat = np.zeros((B, m.nbody, 3, 3))
    jac = np.zeros((B, len(bodies), 6, m.nv))
    for b in range(B):
        d.qpos[:] = qpos[b]
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        xpos[b], xmat[b] = d.xpos, d.xmat.reshape(-1, 3, 3)
        for k, i in enumerate(bodies):
            mujoco.mj_jacBody(m, d, jac[b, k, :3], jac[b, k, 3:], i)
    return xpos, xmat, jac


def rigid_model(source: Any) -> Any:
    """``source`` (a path or MJCF text) compiled with everything beyond rigid-body dynamics and
    the joints' armature zeroed in its ``MjSpec`` or disabled in its options."""
    mujoco = _mujoco()
    if isinstance(source, str) and source.lstrip().startswith("<"):
        spec = mujoco.MjSpec.from_string(source)
    else:
        spec = mujoco.MjSpec.from_file(str(source))
    for j in spec.joints:
        j.damping = np.zeros_like(np.asarray(j.damping))
        j.frictionloss = 0.0
        j.stiffness = np.zeros_like(np.asarray(j.stiffness))
    for a in spec.actuators:
        a.armature = 0.0
    for t in spec.tendons:
        t.armature = 0.0
    for b in spec.bodies:
        b.gravcomp = 0.0
    d = mujoco.mjtDisableBit
    spec.option.disableflags |= int(
        d.mjDSBL_CONTACT
        | d.mjDSBL_CONSTRAINT
        | d.mjDSBL_EQUALITY
        | d.mjDSBL_LIMIT
        | d.mjDSBL_FRICTIONLOSS
        | d.mjDSBL_ACTUATION
        | d.mjDSBL_SPRING
        | d.mjDSBL_DAMPER
    )
    return spec.compile()


def _dynamics(source: Any, dtype: torch.dtype, q: torch.Tensor, seed: int) -> dict[str, float]:
    """Largest errors of the dynamics against MuJoCo's, relative to ``1 + |reference|`` (the
    mass matrix: to ``1 + max |M|``)."""
    mujoco = _mujoco()
    m = rigid_model(source)
    chain = Chain.from_mjcf(m, dtype=dtype)
    B = q.shape[0]
    gen = torch.Generator().manual_seed(seed + 1)
    qd, qdd, tau = torch.randn(3, B, m.nv, generator=gen, dtype=torch.float64)
    q64 = q.to(torch.float64)
    d = mujoco.MjData(m)
    ref = {k: np.zeros((B, m.nv)) for k in ("tau", "bias")}
    ref_M = np.zeros((B, m.nv, m.nv))
    for b in range(B):
        d.qpos[:], d.qvel[:] = q64[b].numpy(), qd[b].numpy()
        mujoco.mj_forward(m, d)
        mujoco.mj_fullM(m, d, ref_M[b])
        ref["bias"][b] = d.qfrc_bias
        d.qacc[:] = qdd[b].numpy()
        mujoco.mj_inverse(m, d)
        ref["tau"][b] = d.qfrc_inverse

    def rel(x: torch.Tensor, r: np.ndarray) -> float:
        return float(np.max(np.abs(x.double().numpy() - r) / (1.0 + np.abs(r)), initial=0.0))

    # MuJoCo keeps opt.gravity when <flag gravity="disable"/> is set, and leaves it out
    off = m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_GRAVITY
    g = torch.as_tensor(0.0 if off else np.array(m.opt.gravity), dtype=dtype).expand(3)
    q_, qd_, qdd_, tau_ = (x.to(dtype) for x in (q64, qd, qdd, tau))
    M = chain.mass_matrix(q_).double().numpy()
    out = {
        "tau": rel(chain.inverse_dynamics(q_, qd_, qdd_, gravity=g), ref["tau"]),
        "M": float(np.abs(M - ref_M).max(initial=0.0)) / (1.0 + float(np.abs(ref_M).max())),
        "bias": rel(chain.bias_forces(q_, qd_, gravity=g), ref["bias"]),
    }
    if not _dyn_plan(chain).massless:  # else forward_dynamics refuses the chain
        # the residual of MuJoCo's equations of motion, as against Pinocchio (validate's
        # docstring): qacc is only as accurate as the condition number of M allows
        from .validate import backward_error

        a = chain.forward_dynamics(q_, qd_, tau_, gravity=g)
        out["qdd"] = backward_error(torch.from_numpy(ref_M), a, torch.from_numpy(ref["bias"]), tau_)
    return out


def validate_mjcf(
    source: Any, *, samples: int, dtype: torch.dtype, seed: int, out: Any
) -> tuple[bool, int]:
    """Compare and print the report; returns ``(ok, n_v)``."""
    m, label = _compile(source)
    chain = Chain.from_mjcf(m, dtype=dtype)
    tol = 1e-12 if dtype == torch.float64 else 1e-5
    w = out.write
    w(f"torchlie.kinematics.validate: MJCF {label}\n")
    w(
        f"{m.nbody} bodies, {m.njnt} joints, nq = {m.nq}, nv = {m.nv}; {samples} random qpos "
        f"(limits where the joints have them); torchlie in {str(dtype)[6:]}; compared with "
        f"MuJoCo {_mujoco().__version__} (mj_kinematics, mj_jacBody)\n"
    )
    if chain.n_dof == 0:
        w("NOTHING TO COMPARE: the model has no joint\n")
        return True, 0
    q = chain.random_configuration(samples, generator=torch.Generator().manual_seed(seed))
    q64 = q.to(torch.float64)
    names = list(chain.link_names)
    leaves = [names.index(n) for n in chain.leaf_links]
    xpos, xmat, jac = mujoco_reference(m, q64.numpy(), leaves)
    T = chain.forward_kinematics(q, stacked=True).to(torch.float64).numpy()
    scale = 1.0 + float(np.abs(xpos).max())
    dp = np.abs(T[..., :3, 3] - xpos).max(axis=(0, 2))
    dr = np.abs(T[..., :3, :3] - xmat).max(axis=(0, 2, 3))
    Js = chain.jacobian(q, list(chain.leaf_links)) if leaves else {}
    dj = [
        float(np.abs(Js[names[i]].double().numpy() - jac[:, k]).max()) for k, i in enumerate(leaves)
    ]
    width = max(12, *(len(n) for n in names)) + 2
    w(f"tolerance {tol:g} rad, {tol * scale:.1e} m (1 + size = {scale:.2f} m)\n\n")
    w(f"{'body':<{width}}{'|dp| m':>12}{'|dR|':>12}  status\n")
    ok = True
    for i, n in enumerate(names):
        good = bool(dp[i] <= tol * scale and dr[i] <= tol)  # a nan is outside
        ok = ok and good
        w(f"{n:<{width}}{dp[i]:>12.1e}{dr[i]:>12.1e}  {'ok' if good else 'MISMATCH'}\n")
    w(f"\n{'Jacobian of end body':<{width}}{'max|dJ|':>12}\n")
    for k, i in enumerate(leaves):
        good = dj[k] <= tol * scale
        ok = ok and good
        w(f"{names[i]:<{width}}{dj[k]:>12.1e}  {'ok' if good else 'MISMATCH'}\n")
    mujoco = _mujoco()
    if isinstance(source, mujoco.MjModel):
        w("\ndynamics: not compared (a compiled MjModel has no spec to zero the damping in)\n")
    elif float(np.sum(m.body_mass)) > 0.0:
        from .validate import _DYN_NAMES, TOL_DYNAMICS

        dtol = TOL_DYNAMICS[dtype]
        dyn = _dynamics(source, dtype, q[: min(samples, 200)], seed)
        w(
            f"\ndynamics against MuJoCo (mj_inverse, mj_fullM, qfrc_bias; "
            f"{min(samples, 200)} states, random velocities, accelerations and forces; joint "
            "armature kept; damping, springs, contacts, constraints and actuators zeroed or "
            "disabled; largest error relative to 1 + |reference|; forward dynamics: the "
            "residual |M qdd + bias - tau| relative to |M| |qdd| + |bias| + |tau|):\n"
        )
        if "qdd" not in dyn:
            w("  forward dynamics not compared: the mass matrix is singular\n")
        for k, v in dyn.items():
            good = v <= dtol[k]
            ok = ok and good
            w(
                f"  {_DYN_NAMES[k]:<20}{v:>10.1e}   (tolerance {dtol[k]:g})  "
                f"{'ok' if good else 'MISMATCH'}\n"
            )
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        qt = q[: min(samples, 1000)]
        chain.forward_kinematics(qt)
        best = math.inf
        for _ in range(20):
            t0 = time.perf_counter()
            chain.forward_kinematics(qt)
            best = min(best, time.perf_counter() - t0)
    finally:
        torch.set_num_threads(threads)
    w(f"\ntiming: FK of all bodies, batch of {qt.shape[0]}, one thread: {best * 1e3:.3f} ms\n")
    w("\nPASS: every comparison within tolerance\n" if ok else "\nFAIL\n")
    return ok, chain.n_v
