"""The dynamics of MJCF chains against MuJoCo itself: inverse dynamics (``mj_inverse``), the
mass matrix (``mj_fullM``), the bias forces (``qfrc_bias``) and forward dynamics
(``mj_forward``'s ``qacc``) at random states, on hand-written files covering each joint feature
(hinge and slide joints with ``pos`` and ``ref``, several joints in one body, ball and free
joints, rotated inertia frames, fixed bodies with quaternions, joint armature set on the joints
and through defaults classes) and on packaged models, their joints' armature kept.

Coordinates are MuJoCo's: ``q`` is ``qpos`` (quaternions for ball and free joints), velocities,
accelerations and forces are over the ``nv`` velocity coordinates (angular parts of ball and
free joints in the body's frame).

The joints' armature is part of the chain's equations, as of MuJoCo's (added to the mass
matrix's diagonal).  MuJoCo adds to the rigid-body equations what a chain does not model:
damping, friction loss, springs, gravity compensation, contacts, equality constraints and
actuators (in the forces), tendons' armature.  Each model here is compiled with those zeroed or
disabled: the joints' ``damping``, ``frictionloss`` and ``stiffness``, the actuators' and
tendons' ``armature`` and the bodies' ``gravcomp`` set to 0 in its ``MjSpec``, and contacts,
constraints, equalities, limits, friction loss, actuation, springs and dampers disabled in
``option.disableflags``; so both sides compute the same equations.

Tolerances (float64): torques and bias forces within ``1e-9 (1 + |tau|)``, the mass matrix
within ``1e-10 (1 + max |M|)``, accelerations within ``1e-8 (1 + |qdd|)``: far above the
round-off of either side and far below any error of a frame, an anchor or a sign.

The packages are only folders of XML files: located with ``importlib.util.find_spec`` without
being imported; a missing one is skipped.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
import torch

from torchlie.kinematics import Chain, Inertials

mujoco = pytest.importorskip("mujoco")

# The model compiled from its MjSpec with damping, ... zeroed (see the docstring).
from torchlie.kinematics._mjcf_validate import rigid_model  # noqa: E402

TOL_TAU, TOL_M, TOL_QDD = 1e-9, 1e-10, 1e-8
F64 = torch.float64

HAND = {
    # hinge and slide joints, an anchor, ref, a rotated inertia frame, a fixed body with quat;
    # armature from the default class (j2), a named class (j1) and the joint (j3)
    "hinge_slide": """
<mujoco>
<default><joint armature="0.02"/><default class="geared"><joint armature="0.3"/></default>
</default>
<worldbody>
  <body name="a" pos="0.1 0.2 0.3" quat="0.9 0.1 0.3 0.2">
    <joint name="j1" class="geared" type="hinge" axis="0.3 0.4 0.5" pos="0.05 -0.1 0.02"
      ref="0.4"/>
    <inertial pos="0.1 0.02 -0.03" quat="0.7 0.1 -0.2 0.3" mass="1.3"
      diaginertia="0.03 0.02 0.015"/>
    <body name="b" pos="0.3 0 0" euler="0.2 0.1 -0.4">
      <joint name="j2" type="slide" axis="0 0.6 0.8" ref="0.1"/>
      <inertial pos="0 0.05 0" mass="0.7" fullinertia="0.01 0.02 0.015 0.001 -0.002 0.0015"/>
      <body name="tool" pos="0 0.1 0.05" quat="0.5 0.5 -0.5 0.5">
        <inertial pos="0.02 0 0.01" mass="0.4" diaginertia="0.002 0.003 0.004"/>
      </body>
      <body name="c" pos="0 0 0.2">
        <joint name="j3" type="hinge" axis="1 0 0" pos="0 0.03 0" armature="0.15"/>
        <inertial pos="0.03 0 0.1" mass="0.5" diaginertia="0.004 0.003 0.002"/>
      </body>
    </body>
  </body>
</worldbody></mujoco>""",
    # several joints in one body (two hinges and a slide, each with its own anchor); armature
    # on some of them
    "multi": """
<mujoco><worldbody>
  <body name="a" pos="0 0 0.5">
    <joint name="h1" type="hinge" axis="0 0 1" pos="0.1 0 0" armature="0.1"/>
    <joint name="h2" type="hinge" axis="0 1 0" pos="0 0.05 0" ref="-0.3"/>
    <joint name="s1" type="slide" axis="1 0 0" armature="0.5"/>
    <inertial pos="0.2 0.01 0" quat="0.9 0 0.3 0.1" mass="2" diaginertia="0.1 0.08 0.05"/>
    <body name="b" pos="0.4 0 0">
      <joint name="h3" type="hinge" axis="0 1 0"/>
      <joint name="h4" type="hinge" axis="1 0 0" pos="0.02 0 0.01"/>
      <inertial pos="0.15 0 0" mass="1" diaginertia="0.02 0.03 0.01"/>
    </body>
  </body>
</worldbody></mujoco>""",
    # a free-floating base with a ball joint (anchored) and a hinge below it; armature on the
    # free joint and, from the default class, on the ball joint and the hinge (on each DoF)
    "free_ball": """
<mujoco><default><joint armature="0.07"/></default><worldbody>
  <body name="base" pos="0 0 1" quat="0.9 0.2 0.1 0.3">
    <joint type="free" name="root" armature="0.2"/>
    <inertial pos="0.01 0.02 -0.01" quat="0.8 0.1 0.2 0.1" mass="3"
      diaginertia="0.2 0.15 0.1"/>
    <body name="arm" pos="0.2 0 0" euler="0.3 0 0.2">
      <joint name="shoulder" type="ball" pos="0 0 0.05"/>
      <inertial pos="0.1 0 0.02" mass="0.8" diaginertia="0.01 0.02 0.015"/>
      <body name="hand" pos="0.25 0 0">
        <joint name="elbow" type="hinge" axis="0 1 0" pos="0.01 0 0"/>
        <inertial pos="0.05 0 0" mass="0.3" diaginertia="0.001 0.002 0.002"/>
      </body>
    </body>
  </body>
</worldbody></mujoco>""",
}

# Packaged models: (package, file).
PACKAGED = (
    ("gymnasium", "envs/mujoco/assets/reacher.xml"),
    ("gymnasium", "envs/mujoco/assets/pusher.xml"),
    ("gymnasium", "envs/mujoco/assets/hopper.xml"),
    ("gymnasium", "envs/mujoco/assets/walker2d.xml"),
    ("gymnasium", "envs/mujoco/assets/ant.xml"),
    ("gymnasium", "envs/mujoco/assets/humanoid.xml"),
    ("robosuite", "models/assets/robots/panda/robot.xml"),
)


def _package_file(pkg: str, rel: str) -> Path | None:
    try:
        spec = importlib.util.find_spec(pkg)
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.submodule_search_locations:
        return None
    p = Path(next(iter(spec.submodule_search_locations))) / rel
    return p if p.exists() else None


def random_state(m, n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``n`` random ``(qpos, qvel, qacc, tau)``: hinge/slide values in ``[-2, 2]``, unit
    quaternions, free positions in ``[-1, 1]``, velocities, accelerations and forces normal."""
    rng = np.random.default_rng(seed)
    qpos = rng.uniform(-2.0, 2.0, (n, m.nq))
    for j in range(m.njnt):
        a = int(m.jnt_qposadr[j])
        t = int(m.jnt_type[j])
        if t in (mujoco.mjtJoint.mjJNT_FREE, mujoco.mjtJoint.mjJNT_BALL):
            if t == mujoco.mjtJoint.mjJNT_FREE:
                qpos[:, a : a + 3] = rng.uniform(-1.0, 1.0, (n, 3))
                a += 3
            qu = rng.normal(size=(n, 4))
            qpos[:, a : a + 4] = qu / np.linalg.norm(qu, axis=1, keepdims=True)
    return (qpos, *rng.normal(size=(3, n, m.nv)))


def reference(m, qpos, qvel, qacc, tau):
    """MuJoCo's ``qfrc_inverse``, full ``M``, ``qfrc_bias`` and the ``qacc`` under ``tau``."""
    d = mujoco.MjData(m)
    n = qpos.shape[0]
    out_tau, out_M = np.zeros((n, m.nv)), np.zeros((n, m.nv, m.nv))
    out_h, out_qdd = np.zeros((n, m.nv)), np.zeros((n, m.nv))
    for i in range(n):
        d.qpos[:], d.qvel[:], d.qfrc_applied[:] = qpos[i], qvel[i], tau[i]
        mujoco.mj_forward(m, d)
        mujoco.mj_fullM(m, d, out_M[i])
        out_h[i], out_qdd[i] = d.qfrc_bias, d.qacc
        d.qacc[:] = qacc[i]
        mujoco.mj_inverse(m, d)
        out_tau[i] = d.qfrc_inverse
    return out_tau, out_M, out_h, out_qdd


def relerr(x: torch.Tensor, ref: np.ndarray) -> float:
    r = torch.as_tensor(ref)
    return float(((x - r).abs() / (1.0 + r.abs())).max())


def gravity(m, dtype: torch.dtype) -> torch.Tensor:
    """The gravity in MuJoCo's forces: ``opt.gravity``, or 0 where ``<flag gravity="disable"/>``
    is set (MuJoCo keeps ``opt.gravity`` then)."""
    off = m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_GRAVITY
    return torch.as_tensor(0.0 if off else np.array(m.opt.gravity), dtype=dtype).expand(3)


def check(m, n: int, seed: int = 0) -> dict[str, float]:
    """Compare at ``n`` random states; returns the largest errors (printed with ``-s``)."""
    chain = Chain.from_mjcf(m, dtype=torch.float64)
    assert chain.n_v == m.nv and chain.n_dof == m.nq
    qpos, qvel, qacc, tau = random_state(m, n, seed)
    r_tau, r_M, r_h, r_qdd = reference(m, qpos, qvel, qacc, tau)
    q, qd, qdd, t = (torch.as_tensor(x) for x in (qpos, qvel, qacc, tau))
    g = gravity(m, torch.float64)
    M = chain.mass_matrix(q)
    err = {
        "tau": relerr(chain.inverse_dynamics(q, qd, qdd, gravity=g), r_tau),
        "h": relerr(chain.bias_forces(q, qd, gravity=g), r_h),
        "M": float((M - torch.as_tensor(r_M)).abs().max()) / (1.0 + float(np.abs(r_M).max())),
        "qdd": relerr(chain.forward_dynamics(q, qd, t, gravity=g), r_qdd),
    }
    print(f"nv {m.nv}: " + ", ".join(f"{k} {v:.1e}" for k, v in err.items()))
    assert err["tau"] < TOL_TAU and err["h"] < TOL_TAU
    assert err["M"] < TOL_M and err["qdd"] < TOL_QDD
    return err


@pytest.mark.parametrize("name", sorted(HAND))
def test_hand_written(name: str) -> None:
    check(rigid_model(HAND[name]), 20, seed=1)


@pytest.mark.parametrize("pkg,rel", PACKAGED, ids=[r.rsplit("/", 1)[-1] for _, r in PACKAGED])
def test_packaged(pkg: str, rel: str) -> None:
    path = _package_file(pkg, rel)
    if path is None:
        pytest.skip(f"{pkg} is not installed")
    check(rigid_model(path), 10, seed=2)


@pytest.mark.slow
@pytest.mark.parametrize("pkg,rel", PACKAGED, ids=[r.rsplit("/", 1)[-1] for _, r in PACKAGED])
def test_packaged_sweep(pkg: str, rel: str) -> None:
    path = _package_file(pkg, rel)
    if path is None:
        pytest.skip(f"{pkg} is not installed")
    check(rigid_model(path), 200, seed=3)


def test_float32() -> None:
    # The same chain in float32 against MuJoCo's float64 values: within 1e-4 relative to
    # 1 + |reference| (a few hundred float32 ulp through the free base and the ball joint).
    m = rigid_model(HAND["free_ball"])
    chain = Chain.from_mjcf(m, dtype=torch.float32)
    qpos, qvel, qacc, tau = random_state(m, 50, seed=4)
    r_tau, r_M, _, _ = reference(m, qpos, qvel, qacc, tau)
    q, qd, qdd = (torch.as_tensor(x, dtype=torch.float32) for x in (qpos, qvel, qacc))
    g = gravity(m, torch.float32)
    tau32 = chain.inverse_dynamics(q, qd, qdd, gravity=g)
    assert tau32.dtype == torch.float32
    err_tau = relerr(tau32.double(), r_tau)
    M32 = chain.mass_matrix(q).double()
    err_M = float((M32 - torch.as_tensor(r_M)).abs().max()) / (1.0 + float(np.abs(r_M).max()))
    print(f"float32: tau {err_tau:.1e}, M {err_M:.1e}")
    assert err_tau < 1e-4 and err_M < 1e-5


def test_gradcheck_through_ball_and_free() -> None:
    # Float64 gradcheck of the torques with respect to qpos (quaternions included: the chain
    # normalises them), qvel and qacc on the free base with an anchored ball joint.
    chain = Chain.from_mjcf(rigid_model(HAND["free_ball"]), dtype=torch.float64)
    qpos, qvel, qacc, _ = random_state(rigid_model(HAND["free_ball"]), 2, seed=5)
    args = tuple(torch.as_tensor(x).requires_grad_() for x in (qpos, qvel, qacc))
    assert torch.autograd.gradcheck(chain.inverse_dynamics, args)
    assert torch.autograd.gradcheck(lambda q: chain.mass_matrix(q), args[:1])


def test_velocity_shapes() -> None:
    # q is qpos (nq values), the velocities are nv: a qd of nq values is refused, naming both.
    chain = Chain.from_mjcf(HAND["free_ball"], dtype=torch.float64)
    assert (chain.n_dof, chain.n_v) == (12, 10)
    q = torch.zeros(12, dtype=torch.float64)
    q[3] = q[7] = 1.0
    v = torch.zeros(10, dtype=torch.float64)
    assert chain.inverse_dynamics(q, v, v).shape == (10,)
    assert chain.mass_matrix(q).shape == (10, 10)
    with pytest.raises(ValueError, match="inverse_dynamics.*qd"):
        chain.inverse_dynamics(q, q, v)
    with pytest.raises(ValueError, match="forward_dynamics.*tau"):
        chain.forward_dynamics(q, v, q)


@pytest.mark.compile
def test_compile_fullgraph() -> None:
    chain = Chain.from_mjcf(HAND["free_ball"], dtype=torch.float64)
    qpos, qvel, qacc, _ = (
        torch.as_tensor(x) for x in random_state(rigid_model(HAND["free_ball"]), 3, seed=6)
    )
    f = torch.compile(chain.inverse_dynamics, fullgraph=True)
    torch.testing.assert_close(f(qpos, qvel, qacc), chain.inverse_dynamics(qpos, qvel, qacc))
    f = torch.compile(chain.mass_matrix, fullgraph=True)
    torch.testing.assert_close(f(qpos), chain.mass_matrix(qpos))


def test_validate_reports_the_dynamics(tmp_path, capsys) -> None:
    # python -m torchlie.kinematics.validate on an MJCF file compares the dynamics with MuJoCo
    # (on the model recompiled without damping, ..., its joints' armature kept): four lines,
    # all within tolerance, in float64 and float32.
    from torchlie.kinematics.validate import main

    path = tmp_path / "robot.xml"
    path.write_text(
        HAND["free_ball"].replace('pos="0 0 0.05"/>', 'pos="0 0 0.05" armature="0.1"/>')
    )
    assert main([str(path), "--samples", "20", "--dtype", "float64"]) == 0
    text = capsys.readouterr().out
    assert "dynamics against MuJoCo" in text and "PASS" in text
    for name in ("inverse dynamics", "mass matrix", "bias forces", "forward dynamics"):
        line = next(ln for ln in text.splitlines() if ln.strip().startswith(name))
        assert line.endswith("ok")
    assert main([str(path), "--samples", "10", "--dtype", "float32"]) == 0


def test_gravity_disabled_by_flag(tmp_path, capsys) -> None:
    # <flag gravity="disable"/> keeps opt.gravity but leaves gravity out of MuJoCo's forces:
    # the comparison and python -m torchlie.kinematics.validate take gravity 0 there (they
    # reported a mismatch of about 10 N m)
    from torchlie.kinematics.validate import main

    xml = HAND["free_ball"].replace(
        "<mujoco>", '<mujoco><option><flag gravity="disable"/></option>', 1
    )
    assert xml != HAND["free_ball"]
    m = rigid_model(xml)
    assert m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_GRAVITY and m.opt.gravity[2] != 0
    err = check(m, 10)
    assert err["tau"] <= TOL_TAU and err["qdd"] <= TOL_QDD
    path = tmp_path / "robot.xml"
    path.write_text(xml)
    assert main([str(path), "--samples", "10", "--dtype", "float64"]) == 0
    assert "PASS" in capsys.readouterr().out


def test_sites_change_nothing() -> None:
    # Sites are links fixed to their bodies without inertials: the same bodies, inertials and
    # torques with or without them (fixed origins given by quaternions).
    site = '<site name="s" pos="0.1 0 0" quat="0.6 0.8 0 0"/>'
    m = rigid_model(
        HAND["hinge_slide"].replace("</body>\n</worldbody>", site + "</body></worldbody>")
    )
    a = Chain.from_mjcf(m, dtype=torch.float64)
    b = Chain.from_mjcf(m, sites=True, dtype=torch.float64)
    assert "s" in b.link_names and a.body_names == b.body_names
    qpos, qvel, qacc, _ = (torch.as_tensor(x) for x in random_state(m, 5, seed=7))
    torch.testing.assert_close(
        b.inverse_dynamics(qpos, qvel, qacc), a.inverse_dynamics(qpos, qvel, qacc)
    )


# Per velocity coordinate, as the files set it (see HAND): a free joint's and a ball joint's
# armature on each of their DoFs.
ARMATURE = {
    "hinge_slide": [0.3, 0.02, 0.15],
    "multi": [0.1, 0.0, 0.5, 0.0, 0.0],
    "free_ball": [0.2] * 6 + [0.07] * 4,
    # <freejoint> takes no defaults (MuJoCo's rule): 0 on the free joint
    "freejoint": [0.0] * 6 + [0.07] * 4,
}


@pytest.mark.parametrize("name", sorted(ARMATURE))
def test_armature_is_read(name: str) -> None:
    # Each joint's armature (its own, its class's or the default class's) on each of its
    # velocity coordinates, exactly MuJoCo's compiled dof_armature.
    text = HAND.get(name) or HAND["free_ball"].replace(
        '<joint type="free" name="root" armature="0.2"/>', '<freejoint name="root"/>'
    )
    m = rigid_model(text)
    chain = Chain.from_mjcf(text, dtype=torch.float64)
    armature = chain.inertials.armature
    assert armature.shape == (chain.n_v,) and armature.dtype == torch.float64
    assert armature.tolist() == ARMATURE[name] == m.dof_armature.tolist()


def test_armature_replace_and_batch() -> None:
    # The armature is an inertial parameter like the others: replaced through inertials=,
    # per state, in the mass matrix's diagonal and in the torques (armature * qdd); the bias
    # forces do not depend on it, and forward dynamics inverts the same mass matrix.
    m = rigid_model(HAND["free_ball"])
    chain = Chain.from_mjcf(m, dtype=torch.float64)
    qpos, qvel, qacc, _ = (torch.as_tensor(x) for x in random_state(m, 4, seed=8))
    ins = chain.inertials
    own = chain.mass_matrix(qpos)
    # Inertials(mass, com, inertia): the chain's own armature
    assert torch.equal(chain.mass_matrix(qpos, inertials=Inertials(*ins[:3])), own)
    rigid = ins._replace(armature=torch.zeros(chain.n_v, dtype=torch.float64))
    M0 = chain.mass_matrix(qpos, inertials=rigid)
    torch.testing.assert_close(own, M0 + torch.diag(ins.armature), rtol=0, atol=1e-15)
    a = 0.1 + torch.rand(4, chain.n_v, generator=torch.Generator().manual_seed(9), dtype=F64)
    given = ins._replace(armature=a)
    torch.testing.assert_close(
        chain.mass_matrix(qpos, inertials=given), M0 + torch.diag_embed(a), rtol=0, atol=1e-15
    )
    tau0 = chain.inverse_dynamics(qpos, qvel, qacc, inertials=rigid)
    tau = chain.inverse_dynamics(qpos, qvel, qacc, inertials=given)
    torch.testing.assert_close(tau, tau0 + a * qacc, rtol=1e-14, atol=1e-14)
    torch.testing.assert_close(
        tau[2],
        chain.inverse_dynamics(qpos[2], qvel[2], qacc[2], inertials=ins._replace(armature=a[2])),
    )
    assert torch.equal(
        chain.bias_forces(qpos, qvel, inertials=given),
        chain.bias_forces(qpos, qvel, inertials=rigid),
    )
    assert torch.equal(chain.gravity_torques(qpos, inertials=given), chain.gravity_torques(qpos))
    acc = chain.forward_dynamics(qpos, qvel, tau, inertials=given)
    torch.testing.assert_close(acc, qacc, rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match=r"mass_matrix: expected inertials.armature of shape"):
        chain.mass_matrix(qpos, inertials=ins._replace(armature=torch.zeros(12, dtype=F64)))


def test_armature_under_vmap() -> None:
    # torch.func.vmap over states gives the batched results, armature included.
    m = rigid_model(HAND["free_ball"])
    chain = Chain.from_mjcf(m, dtype=torch.float64)
    qpos, qvel, qacc, tau = (torch.as_tensor(x) for x in random_state(m, 5, seed=10))
    vmap = torch.func.vmap
    tol = {"rtol": 1e-12, "atol": 1e-12}
    torch.testing.assert_close(
        vmap(chain.inverse_dynamics)(qpos, qvel, qacc),
        chain.inverse_dynamics(qpos, qvel, qacc),
        **tol,
    )
    torch.testing.assert_close(vmap(chain.mass_matrix)(qpos), chain.mass_matrix(qpos), **tol)
    torch.testing.assert_close(
        vmap(chain.forward_dynamics)(qpos, qvel, tau),
        chain.forward_dynamics(qpos, qvel, tau),
        **tol,
    )
