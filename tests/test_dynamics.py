"""Rigid-body dynamics (Chain.inverse_dynamics, mass_matrix, forward_dynamics, bias_forces,
gravity_torques) against Pinocchio, and their gradients, batching, compile and bad input.

Pinocchio is given torchlie's states mapped to its coordinates (see
``torchlie/kinematics/_pin_reference.py``: ``tau = D^T tau_pin`` at ``v = D qd``,
``a = D qdd + (dD/dt) qd``).  Errors are relative to ``1 + |reference|``.
"""

from __future__ import annotations

import math
import os
import re
import site
import sysconfig

import numpy as np
import pytest
import torch

from torchlie.kinematics import Chain, parse_urdf, sample_robot
from torchlie.kinematics.dynamics import Inertials
from torchlie.kinematics.validate import backward_error

F64 = torch.float64
N_STATES = 500
TOL = {"tau": 1e-9, "M": 1e-10, "bias": 1e-9, "gravity": 1e-9, "aba": 1e-8}
TOL_DERIV = 1e-7
# float32: the same comparisons, bounded loosely (the figures are printed with -s).
TOL32 = {"tau": 5e-5, "M": 2e-5, "bias": 5e-5, "gravity": 5e-5}


def _erd_dir() -> str | None:
    """example-robot-data's ``robots`` folder in the installed packages, if any."""
    roots = [sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]]
    roots += site.getsitepackages() + [site.getusersitepackages()]
    for r in roots:
        d = os.path.join(r, "cmeel.prefix", "share", "example-robot-data", "robots")
        if os.path.isdir(d):
            return d
    return None


# Fixed-base robots of example-robot-data: arms, a hand (16 DoF), a dual arm with mimic
# grippers, two humanoids (29 and 32 DoF) and a quadruped loaded without a free flyer.
ERD = {
    "ur5": "ur_description/urdf/ur5_robot.urdf",
    "xarm7": "xarm_description/urdf/xarm7.urdf",
    "z1": "z1_description/urdf/z1.urdf",
    "so101": "so_arm_description/urdf/so101.urdf",
    "allegro": "allegro_hand_description/urdf/allegro_right_hand.urdf",
    "baxter": "baxter_description/urdf/baxter.urdf",
    "g1": "g1_description/urdf/g1_29dof_rev_1_0.urdf",
    "anymal": "anymal_c_simple_description/urdf/anymal.urdf",
    "talos": "talos_data/robots/talos_reduced.urdf",  # <mimic> on fixed joints
}
ROBOTS = ["arm7", "panda", "tree", *ERD]


def _path(name: str) -> str:
    if name in ERD:
        d = _erd_dir()
        if d is None:
            pytest.skip("example-robot-data is not installed")
        return os.path.join(d, ERD[name])
    return sample_robot(name)


_CACHE: dict[str, tuple] = {}


def _reference(name: str):
    """(chain float64, q, qd, qdd, Pinocchio's results, _Pin) for N_STATES random states;
    computed once per session."""
    pin = pytest.importorskip("pinocchio")
    if name not in _CACHE:
        from torchlie.kinematics._pin_reference import _Pin

        path = _path(name)
        with open(path, "rb") as f:
            text = f.read()
        spec = parse_urdf(path)
        chain = Chain(spec, dtype=F64)
        gen = torch.Generator().manual_seed(52)
        q = chain.random_configuration(N_STATES, generator=gen)
        qd = torch.randn(N_STATES, chain.n_dof, generator=gen, dtype=F64)
        qdd = torch.randn(N_STATES, chain.n_dof, generator=gen, dtype=F64)
        P = _Pin(pin, spec, chain, text)
        _CACHE[name] = (chain, q, qd, qdd, P.dynamics(q, qd, qdd), P)
    return _CACHE[name]


def _rel(x: torch.Tensor, ref: torch.Tensor) -> float:
    return float(((x.to(F64) - ref) / (1.0 + ref.abs())).abs().max())


@pytest.mark.parametrize("name", ROBOTS)
def test_against_pinocchio(name):
    chain, q, qd, qdd, ref, P = _reference(name)
    err = {
        "tau": _rel(chain.inverse_dynamics(q, qd, qdd), ref["tau"]),
        "M": _rel(chain.mass_matrix(q), ref["M"]),
        "bias": _rel(chain.bias_forces(q, qd), ref["bias"]),
        "gravity": _rel(chain.gravity_torques(q), ref["gravity"]),
    }
    tau = ref["tau"]
    if P.model.nv == chain.n_dof:  # no mimic joint: Pinocchio's ABA applies
        err["aba"] = _rel(chain.forward_dynamics(q, qd, tau), ref["aba"])
    else:  # reduced coordinates: the accelerations that reproduce the torques
        err["aba"] = _rel(chain.forward_dynamics(q, qd, tau), qdd)
    print(f"{name} float64: " + ", ".join(f"{k} {v:.1e}" for k, v in err.items()))
    for k, v in err.items():
        assert v <= TOL[k], (name, k, v)


@pytest.mark.parametrize("name", ["arm7", "panda", "tree"])
def test_armature_against_pinocchio(name):
    # Pinocchio adds model.armature (per velocity coordinate) to crba's diagonal and rnea's
    # torques (and aba's inertia): random positive values on each joint with a coordinate of
    # its own; none on mimic joints (no coordinate of their own), on floating joints and on a
    # planar joint's x, y (Pinocchio's velocities there are not the rates of torchlie's
    # coordinates).
    chain, q, qd, qdd, _, P = _reference(name)
    q, qd, qdd = q[:50], qd[:50], qdd[:50]
    gen = torch.Generator().manual_seed(53)
    by_name = {j.name: j for j in chain.spec.joints}
    armature = torch.zeros(chain.n_v, dtype=F64)
    armature_pin = np.zeros(P.model.nv)
    for i, (kind, _, iv, d, _, _) in enumerate(P.joints, start=1):
        if by_name[P.model.names[i]].mimic is not None or kind == "free":
            continue
        k = 2 if kind == "planar" else 0  # theta
        armature[d + k] = armature_pin[iv + k] = 0.05 + float(torch.rand((), generator=gen))
    P.model.armature = armature_pin
    try:
        ref = P.dynamics(q, qd, qdd, derivatives=False)
    finally:
        P.model.armature = np.zeros(P.model.nv)
    ins = chain.inertials._replace(armature=armature)
    assert _rel(chain.mass_matrix(q), ref["M"]) > 1e-3  # the armature matters
    err = {
        "tau": _rel(chain.inverse_dynamics(q, qd, qdd, inertials=ins), ref["tau"]),
        "M": _rel(chain.mass_matrix(q, inertials=ins), ref["M"]),
        "bias": _rel(chain.bias_forces(q, qd, inertials=ins), ref["bias"]),
    }
    tau = ref["tau"]
    if P.model.nv == chain.n_dof:  # no mimic joint: Pinocchio's ABA applies
        err["aba"] = _rel(chain.forward_dynamics(q, qd, tau, inertials=ins), ref["aba"])
    else:
        err["aba"] = _rel(chain.forward_dynamics(q, qd, tau, inertials=ins), qdd)
    print(f"{name} armature: " + ", ".join(f"{k} {v:.1e}" for k, v in err.items()))
    for k, v in err.items():
        assert v <= TOL[k], (name, k, v)


@pytest.mark.parametrize("name", ["arm7", "panda"])
def test_fast_motion_against_pinocchio(name):
    # Velocities and accelerations of 1e3 (rad/s, rad/s^2): the velocity-product terms,
    # a million times the gravity terms, within the same relative bounds.
    chain, q, qd, qdd, _, P = _reference(name)
    q, qd, qdd = q[:20], 1e3 * qd[:20], 1e3 * qdd[:20]
    ref = P.dynamics(q, qd, qdd, derivatives=False)
    assert _rel(chain.inverse_dynamics(q, qd, qdd), ref["tau"]) <= TOL["tau"]
    assert _rel(chain.bias_forces(q, qd), ref["bias"]) <= TOL["bias"]
    assert _rel(chain.forward_dynamics(q, qd, ref["tau"]), qdd) <= TOL["aba"]


@pytest.mark.parametrize("name", [r for r in ROBOTS if r != "tree"])
def test_rnea_derivatives_against_pinocchio(name):
    chain, q, qd, qdd, ref, _ = _reference(name)
    q, qd = q.clone().requires_grad_(), qd.clone().requires_grad_()
    tau = chain.inverse_dynamics(q, qd, qdd)
    n = chain.n_dof
    dq, dqd = torch.empty(N_STATES, n, n, dtype=F64), torch.empty(N_STATES, n, n, dtype=F64)
    for i in range(n):
        gq, gqd = torch.autograd.grad(tau[:, i].sum(), (q, qd), retain_graph=i < n - 1)
        dq[:, i], dqd[:, i] = gq, gqd
    e_q, e_qd = _rel(dq, ref["dtau_dq"]), _rel(dqd, ref["dtau_dqd"])
    print(f"{name} dtau/dq {e_q:.1e}, dtau/dqd {e_qd:.1e}")
    assert e_q <= TOL_DERIV and e_qd <= TOL_DERIV


@pytest.mark.parametrize("name", ["arm7", "panda", "tree", "ur5", "g1"])
def test_float32_against_pinocchio(name):
    chain, q, qd, qdd, ref, _ = _reference(name)
    c32 = chain.to(dtype=torch.float32)
    q32, qd32, qdd32 = (x.float() for x in (q, qd, qdd))
    err = {
        "tau": _rel(c32.inverse_dynamics(q32, qd32, qdd32), ref["tau"]),
        "M": _rel(c32.mass_matrix(q32), ref["M"]),
        "bias": _rel(c32.bias_forces(q32, qd32), ref["bias"]),
        "gravity": _rel(c32.gravity_torques(q32), ref["gravity"]),
    }
    print(f"{name} float32: " + ", ".join(f"{k} {v:.1e}" for k, v in err.items()))
    for k, v in err.items():
        assert v <= TOL32[k], (name, k, v)


def test_external_wrenches_against_pinocchio():
    # Pinocchio's fext: per joint, the wrench in the joint's (= its child link's) local frame.
    pin = pytest.importorskip("pinocchio")
    import numpy as np

    path = sample_robot("arm7")
    chain = Chain.from_urdf(path, dtype=F64)
    model = pin.buildModelFromUrdf(path)
    data = model.createData()
    q, qd, qdd = _state(chain, 50, seed=18)
    gen = torch.Generator().manual_seed(19)
    links = {"link3": "upper_arm_roll", "link7": "flange_roll"}
    w = {k: torch.randn(50, 6, generator=gen, dtype=F64) for k in links}
    tau = chain.inverse_dynamics(q, qd, qdd, f_ext=w)
    T = chain.forward_kinematics(q, list(links))
    err = 0.0
    for b in range(50):
        fext = [pin.Force.Zero() for _ in range(model.njoints)]
        for link, joint in links.items():
            Rt = T[link][b, :3, :3].T
            local = torch.cat((Rt @ w[link][b, :3], Rt @ w[link][b, 3:])).numpy()
            fext[model.getJointId(joint)] = pin.Force(np.ascontiguousarray(local))
        ref = pin.rnea(model, data, q[b].numpy(), qd[b].numpy(), qdd[b].numpy(), fext)
        err = max(err, _rel(tau[b], torch.from_numpy(ref.copy())))
    assert err <= TOL["tau"], err


def test_against_mujoco():
    # MuJoCo reads the URDF itself (fixed links fused, no armature or damping in this file):
    # mj_inverse, mj_fullM and mj_forward's accelerations under the same torques.
    mujoco = pytest.importorskip("mujoco")
    import numpy as np

    path = sample_robot("arm7")
    model = mujoco.MjModel.from_xml_path(path)
    data = mujoco.MjData(model)
    chain = Chain.from_urdf(path, dtype=F64)
    assert [model.joint(i).name for i in range(model.njnt)] == list(chain.joint_names)
    q, qd, qdd = _state(chain, 100, seed=17)
    tau, M = chain.inverse_dynamics(q, qd, qdd), chain.mass_matrix(q)
    acc = chain.forward_dynamics(q, qd, tau)
    err = {"tau": 0.0, "M": 0.0, "qdd": 0.0}
    Mf = np.zeros((model.nv, model.nv))
    for b in range(100):
        data.qpos[:], data.qvel[:], data.qacc[:] = q[b].numpy(), qd[b].numpy(), qdd[b].numpy()
        mujoco.mj_inverse(model, data)
        mujoco.mj_fullM(model, data, Mf)
        ref_tau = torch.from_numpy(data.qfrc_inverse.copy())
        err["tau"] = max(err["tau"], _rel(tau[b], ref_tau))
        err["M"] = max(err["M"], _rel(M[b], torch.from_numpy(Mf.copy())))
        data.qfrc_applied[:] = tau[b].numpy()
        mujoco.mj_forward(model, data)
        err["qdd"] = max(err["qdd"], _rel(acc[b], torch.from_numpy(data.qacc.copy())))
    print("arm7 against MuJoCo: " + ", ".join(f"{k} {v:.1e}" for k, v in err.items()))
    assert err["tau"] <= TOL["tau"] and err["M"] <= TOL["M"] and err["qdd"] <= TOL["aba"]


# ----------------------------------------------------------------------------------------------
# Without Pinocchio: identities, gradients, batching, compile, bad input
# ----------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def arm():
    return Chain.from_urdf(sample_robot("arm7"), dtype=F64)


@pytest.fixture(scope="module")
def tree():
    return Chain.from_urdf(sample_robot("tree"), dtype=F64)


def _state(chain, *batch, seed=0):
    gen = torch.Generator().manual_seed(seed)
    q = chain.random_configuration(*batch, generator=gen)
    qd = torch.randn(*batch, chain.n_dof, generator=gen, dtype=chain.dtype)
    qdd = torch.randn(*batch, chain.n_dof, generator=gen, dtype=chain.dtype)
    return q, qd, qdd


@pytest.mark.parametrize("robot", ["arm7", "tree"])
def test_equations_of_motion_are_consistent(robot):
    chain = Chain.from_urdf(sample_robot(robot), dtype=F64)
    q, qd, qdd = _state(chain, 20)
    tau = chain.inverse_dynamics(q, qd, qdd)
    M, h = chain.mass_matrix(q), chain.bias_forces(q, qd)
    torch.testing.assert_close(tau, (M @ qdd.unsqueeze(-1)).squeeze(-1) + h, rtol=0, atol=1e-11)
    torch.testing.assert_close(M, M.mT, rtol=0, atol=1e-14)
    assert bool((torch.linalg.eigvalsh(M) > 0).all())
    torch.testing.assert_close(chain.forward_dynamics(q, qd, tau), qdd, rtol=0, atol=1e-9)
    torch.testing.assert_close(
        chain.gravity_torques(q), chain.bias_forces(q, torch.zeros_like(qd)), rtol=0, atol=0
    )
    # Without gravity the bias is quadratic in the velocity.
    g0 = torch.zeros(3, dtype=F64)
    h1, h2 = chain.bias_forces(q, qd, gravity=g0), chain.bias_forces(q, 2 * qd, gravity=g0)
    torch.testing.assert_close(h2, 4 * h1, rtol=0, atol=1e-11)


@pytest.mark.parametrize("dtype", [F64, torch.float32])
@pytest.mark.parametrize("x", [1e3, 1e6, 1e30])
def test_results_do_not_depend_on_where_the_robot_stands(dtype, x):
    # A floating base far from the world origin (the tree's drone) and an arm mounted far from
    # it: the equations of motion are those at the origin, to the same precision (computed
    # about each subtree's own first link, not about the world origin, where the moments of a
    # body x away are ~m x^2 and cancel).
    with open(sample_robot("arm7")) as f:
        text = f.read()
    mount = '<origin xyz="0.05 -0.02 0" rpy="0 0 0.35"/>'
    assert mount in text
    arms = [
        Chain.from_urdf(
            text.replace(mount, f'<origin xyz="{dx} -0.02 {dz}" rpy="0 0 0.35"/>'), dtype=dtype
        )
        for dx, dz in ((0.05, 0), (x, -x / 3))
    ]
    tree = Chain.from_urdf(sample_robot("tree"), dtype=dtype)
    i = tree.joint_names.index("drone_free:x")
    for near, far_q in (
        (arms[0], lambda q: (arms[1], q)),
        (
            tree,
            lambda q: (
                tree,
                q + x * torch.nn.functional.one_hot(torch.tensor(i), tree.n_dof).to(dtype),
            ),
        ),
    ):
        q, qd, qdd = _state(near, 4, seed=21)
        far, qx = far_q(q)
        tau = near.inverse_dynamics(q, qd, qdd)
        assert torch.equal(far.mass_matrix(qx), near.mass_matrix(q))
        assert torch.equal(far.inverse_dynamics(qx, qd, qdd), tau)
        assert torch.equal(far.forward_dynamics(qx, qd, tau), near.forward_dynamics(q, qd, tau))
        wrench = torch.tensor([1.0, -2.0, 0.5, 0.3, 0.1, -0.2], dtype=dtype)
        link = near.body_names[-1]
        torch.testing.assert_close(
            far.inverse_dynamics(qx, qd, qdd, f_ext={link: wrench}),
            near.inverse_dynamics(q, qd, qdd, f_ext={link: wrench}),
            rtol=0,
            atol=1e-12 if dtype == F64 else 1e-4,
        )


def test_mass_matrix_is_kinetic_energy(tree):
    # 1/2 qd^T M qd equals the bodies' kinetic energy from their Jacobians (at the centre of
    # mass): independent of the composite-inertia algorithm.
    q, qd, _ = _state(tree, 6, seed=3)
    M = tree.mass_matrix(q)
    ins = tree.inertials
    T = tree.forward_kinematics(q, list(tree.body_names), stacked=True)
    ke = torch.zeros(6, dtype=F64)
    for b, name in enumerate(tree.body_names):
        J = tree.jacobian(q, name, point=ins.com[b])
        v = (J @ qd.unsqueeze(-1)).squeeze(-1)
        R = T[:, b, :3, :3]
        Iw = R @ ins.inertia[b] @ R.mT
        w = v[:, 3:]
        ke += 0.5 * ins.mass[b] * (v[:, :3] ** 2).sum(-1)
        ke += 0.5 * (w.unsqueeze(-2) @ Iw @ w.unsqueeze(-1)).view(-1)
    torch.testing.assert_close(
        0.5 * (qd.unsqueeze(-2) @ M @ qd.unsqueeze(-1)).view(-1), ke, rtol=1e-12, atol=0
    )


def test_external_wrenches_are_jacobian_transposed(arm):
    q, qd, qdd = _state(arm, 5, seed=1)
    gen = torch.Generator().manual_seed(2)
    f_tcp = torch.randn(5, 6, generator=gen, dtype=F64)
    f_l3 = torch.randn(6, generator=gen, dtype=F64)
    f_ext = {"tool_tcp": f_tcp, "link3": f_l3, "base": torch.ones(6, dtype=F64)}  # base: fixed
    tau = arm.inverse_dynamics(q, qd, qdd, f_ext=f_ext)
    J = arm.jacobian(q, ["tool_tcp", "link3"])
    expected = arm.inverse_dynamics(q, qd, qdd)
    expected = expected - (J["tool_tcp"].mT @ f_tcp.unsqueeze(-1)).squeeze(-1)
    expected = expected - (J["link3"].mT @ f_l3).squeeze(-1)
    torch.testing.assert_close(tau, expected, rtol=0, atol=1e-11)
    qdd2 = arm.forward_dynamics(q, qd, tau, f_ext=f_ext)
    torch.testing.assert_close(qdd2, qdd, rtol=0, atol=1e-9)


def test_gravity_argument(arm):
    q, _, _ = _state(arm, 4, seed=4)
    g = arm.gravity_torques(q)
    torch.testing.assert_close(
        arm.gravity_torques(q, gravity=torch.tensor([0.0, 0.0, -9.81], dtype=F64)), g
    )
    torch.testing.assert_close(
        arm.gravity_torques(q, gravity=torch.tensor([0.0, 0.0, -19.62], dtype=F64)), 2 * g
    )
    # Per-state gravity broadcasts with the batch.
    gb = torch.tensor([[0.0, 0.0, -9.81], [0.0, 0.0, 0.0]], dtype=F64).repeat(2, 1)
    out = arm.gravity_torques(q, gravity=gb)
    torch.testing.assert_close(out[0::2], g[0::2])
    assert float(out[1::2].abs().max()) == 0.0


@pytest.mark.parametrize("batch", [(), (1,), (5,), (2, 3)])
def test_batch_shapes(arm, batch):
    q, qd, qdd = _state(arm, *batch, seed=5)
    flat = (q.reshape(-1, 7), qd.reshape(-1, 7), qdd.reshape(-1, 7))
    tau = arm.inverse_dynamics(q, qd, qdd)
    assert tau.shape == (*batch, 7)
    torch.testing.assert_close(tau.reshape(-1, 7), arm.inverse_dynamics(*flat), rtol=0, atol=0)
    M = arm.mass_matrix(q)
    assert M.shape == (*batch, 7, 7)
    assert arm.forward_dynamics(q, qd, tau).shape == (*batch, 7)
    # qd, qdd broadcast to q's batch shape.
    assert arm.inverse_dynamics(q, qd[..., :].reshape(-1, 7)[0], qdd).shape == (*batch, 7)


def test_empty_batch(arm):
    q = torch.zeros(0, 7, dtype=F64)
    assert arm.inverse_dynamics(q, q, q).shape == (0, 7)
    assert arm.mass_matrix(q).shape == (0, 7, 7)
    assert arm.forward_dynamics(q, q, q).shape == (0, 7)


@pytest.mark.parametrize("robot", ["arm7", "tree"])
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_large_batch_over_blocks_agrees(robot, dtype):
    """A batch large enough for the shared driver to run the dynamics over blocks of it
    gives, row by row, what the rows give alone and what the unblocked call (a graph being
    recorded) gives."""
    from torchlie._autograd import BLOCK

    chain = Chain.from_urdf(sample_robot(robot), dtype=dtype)
    n = chain.n_dof
    B = 2 * BLOCK * torch.get_num_threads() // n + 5  # two blocks and a part even in float32
    q, qd, qdd = _state(chain, B, seed=11)
    tol = {"rtol": 1e-12, "atol": 1e-12} if dtype == F64 else {"rtol": 2e-5, "atol": 2e-5}
    tau = chain.inverse_dynamics(q, qd, qdd)
    M = chain.mass_matrix(q)
    qdd2 = chain.forward_dynamics(q, qd, tau)
    rows = torch.tensor([0, 1, B // 2, B - 6, B - 1])  # in the first, a middle and the last block
    torch.testing.assert_close(
        tau[rows], chain.inverse_dynamics(q[rows], qd[rows], qdd[rows]), **tol
    )
    torch.testing.assert_close(M[rows], chain.mass_matrix(q[rows]), **tol)
    # Accelerations: through a Cholesky solve, which amplifies the rounding of M and h by M's
    # condition number (5e6 for tree), so the rows' own and the batch's differ by as much; both
    # solve the rows' equations of motion to the backward error of a backward-stable solve.
    ref = chain.forward_dynamics(q[rows], qd[rows], tau[rows])
    eom = (chain.mass_matrix(q[rows]), chain.bias_forces(q[rows], qd[rows]), tau[rows])
    bound = 1e-12 if dtype == F64 else 1e-5
    for x in (qdd2[rows], ref):
        assert backward_error(eom[0], x, *eom[1:]) <= bound
    qg = q.clone().requires_grad_()
    tau_g = chain.inverse_dynamics(qg, qd, qdd)
    torch.testing.assert_close(tau_g.detach(), tau, **tol)
    (grad,) = torch.autograd.grad(tau_g[:, 0].sum(), qg)
    assert bool(grad.isfinite().all())


def test_inertials_replace_and_differentiate(arm):
    q, qd, qdd = _state(arm, 8, seed=6)
    ins = arm.inertials
    assert ins.mass.shape == (7,) and ins.com.shape == (7, 3) and ins.inertia.shape == (7, 3, 3)
    ins.mass.add_(1.0)  # a fresh copy: the chain is unchanged
    assert float(arm.inertials.mass[0]) == pytest.approx(3.2)
    # tau is affine in each mass (centre of mass and inertia fixed): the gradient is the
    # difference quotient, exactly.
    base = arm.inertials
    m = base.mass.clone().requires_grad_()
    tau = arm.inverse_dynamics(q, qd, qdd, inertials=Inertials(m, base.com, base.inertia))
    (g,) = torch.autograd.grad(tau[:, 2].sum(), m)
    tau = tau.detach()
    for b in range(7):
        m2 = base.mass.clone()
        m2[b] += 1.0
        t2 = arm.inverse_dynamics(q, qd, qdd, inertials=Inertials(m2, base.com, base.inertia))
        assert float((t2[:, 2] - tau[:, 2]).sum()) == pytest.approx(float(g[b]), abs=1e-10)
    # Scaling every mass and inertia scales every torque.
    scaled = Inertials(2 * base.mass, base.com, 2 * base.inertia)
    torch.testing.assert_close(
        arm.inverse_dynamics(q, qd, qdd, inertials=scaled), 2 * tau, rtol=1e-13, atol=0
    )
    # Per-state inertials broadcast with the batch.
    mb = base.mass.expand(8, 7).clone()
    mb[3, 6] += 0.5
    tb = arm.inverse_dynamics(q, qd, qdd, inertials=Inertials(mb, base.com, base.inertia))
    m6 = base.mass.clone()
    m6[6] += 0.5
    t6 = arm.inverse_dynamics(q[3], qd[3], qdd[3], inertials=Inertials(m6, base.com, base.inertia))
    torch.testing.assert_close(tb[3], t6, rtol=0, atol=1e-12)
    torch.testing.assert_close(tb[:3], tau[:3], rtol=0, atol=1e-12)


def test_armature_replace_and_differentiate(arm):
    # URDF has no armature: 0 on every velocity coordinate, and the results are those of the
    # rigid bodies, bitwise, whether the armature is the chain's own, left out or given as 0.
    q, qd, qdd = _state(arm, 6, seed=17)
    ins = arm.inertials
    assert ins.armature.shape == (7,) and not bool(ins.armature.any())
    for given in (None, ins, Inertials(*ins[:3])):
        assert torch.equal(arm.mass_matrix(q, inertials=given), arm.mass_matrix(q))
        tau = arm.inverse_dynamics(q, qd, qdd, inertials=given)
        assert torch.equal(tau, arm.inverse_dynamics(q, qd, qdd))
        assert torch.equal(
            arm.forward_dynamics(q, qd, tau, inertials=given), arm.forward_dynamics(q, qd, tau)
        )
    # Set: M + diag(armature), tau + armature * qdd, and forward dynamics inverts that.
    a = torch.linspace(0.1, 0.7, 7, dtype=F64)
    given = ins._replace(armature=a)
    M = arm.mass_matrix(q, inertials=given)
    torch.testing.assert_close(M, arm.mass_matrix(q) + torch.diag(a), rtol=0, atol=1e-15)
    tau = arm.inverse_dynamics(q, qd, qdd, inertials=given)
    torch.testing.assert_close(
        tau, arm.inverse_dynamics(q, qd, qdd) + a * qdd, rtol=1e-14, atol=1e-14
    )
    assert torch.equal(arm.bias_forces(q, qd, inertials=given), arm.bias_forces(q, qd))
    assert torch.equal(arm.gravity_torques(q, inertials=given), arm.gravity_torques(q))
    torch.testing.assert_close(
        arm.forward_dynamics(q, qd, tau, inertials=given), qdd, rtol=0, atol=1e-12
    )
    # Gradients with respect to the armature (float64 gradcheck, per-state values).
    q, qd, qdd = q[:2], qd[:2], qdd[:2]
    tau = arm.inverse_dynamics(q, qd, qdd)
    ab = 0.1 + torch.rand(2, 7, generator=torch.Generator().manual_seed(18), dtype=F64)
    for fn, args in (
        (arm.inverse_dynamics, (q, qd, qdd)),
        (arm.mass_matrix, (q,)),
        (arm.forward_dynamics, (q, qd, tau)),
    ):
        for x in (a, ab):

            def f(x, fn=fn, args=args):
                return fn(*args, inertials=ins._replace(armature=x))

            assert torch.autograd.gradcheck(f, (x.clone().requires_grad_(),))
    # Bad shapes, named.
    with pytest.raises(ValueError, match=r"mass_matrix: expected inertials.armature of shape"):
        arm.mass_matrix(q, inertials=ins._replace(armature=a[:6]))
    with pytest.raises(ValueError, match=r"inertials.armature has batch shape \(3,\), which"):
        arm.mass_matrix(q, inertials=ins._replace(armature=a.expand(3, 7)))


def test_armature_set_on_a_urdf_spec():
    # The armature is a joint attribute of the spec (JointSpec.armature; URDF has no element
    # for it): set there, it is the chain's own, and a translation moving no mass but with
    # armature is not singular.
    import dataclasses

    no_mass = (
        '<inertial><mass value="0"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" '
        'izz="0.1"/></inertial>'
    )
    spec = parse_urdf(_two_joints(no_mass, "prismatic"))
    spec = dataclasses.replace(
        spec,
        joints=tuple(
            dataclasses.replace(j, armature=0.5) if j.name == "j2" else j for j in spec.joints
        ),
    )
    chain = Chain(spec, dtype=F64)
    assert chain.inertials.armature.tolist() == [0.0, 0.5]
    q = torch.tensor([[0.3, 0.2]], dtype=F64)
    one = torch.ones(1, 2, dtype=F64)
    assert float(chain.mass_matrix(q)[0, 1, 1]) == 0.5
    acc = chain.forward_dynamics(q, one, one)
    torch.testing.assert_close(chain.inverse_dynamics(q, one, acc), one, rtol=0, atol=1e-12)


def test_inertials_merge_through_fixed_joints():
    # link7 (0.4 kg) carries the flange (0.2 kg): one body of 0.6 kg, centre of mass between.
    arm = Chain.from_urdf(sample_robot("arm7"), dtype=F64)
    spec = arm.spec
    ins = dict(zip(spec.links, spec.inertials, strict=True))
    m7, mf = ins["link7"].mass, ins["flange"].mass
    b = arm.body_names.index("link7")
    assert float(arm.inertials.mass[b]) == pytest.approx(m7 + mf, rel=1e-15)
    c7 = torch.tensor(ins["link7"].xyz, dtype=F64)
    cf = torch.tensor(ins["flange"].xyz, dtype=F64) + torch.tensor([0, 0, 0.035], dtype=F64)
    torch.testing.assert_close(arm.inertials.com[b], (m7 * c7 + mf * cf) / (m7 + mf))


def test_gradcheck_small_chain():
    chain = Chain.from_urdf(sample_robot("arm7"), dtype=F64)
    q, qd, qdd = _state(chain, 2, seed=7)
    ins = chain.inertials
    com = ins.com.clone().requires_grad_()

    def f(q, qd, qdd, mass, com):
        return chain.inverse_dynamics(q, qd, qdd, inertials=Inertials(mass, com, ins.inertia))

    args = (q, qd, qdd, ins.mass, com)
    args = tuple(a.detach().clone().requires_grad_() for a in args)
    assert torch.autograd.gradcheck(f, args)
    qg = q.clone().requires_grad_()
    assert torch.autograd.gradcheck(chain.mass_matrix, (qg,))
    tau = chain.inverse_dynamics(q, qd, qdd)
    fd_args = (qg, qd.clone().requires_grad_(), tau.clone().requires_grad_())
    assert torch.autograd.gradcheck(chain.forward_dynamics, fd_args)


@pytest.mark.parametrize("fn", ["inverse_dynamics", "mass_matrix", "forward_dynamics"])
def test_inertia_derivatives_in_every_entry(tree, fn):
    # The derivative in each of the 9 entries of each body's inertia, one at a time (the
    # symmetric pairs split apart: the inertia is read as its symmetric part), against a
    # fourth-order difference with a step relative to the body's inertia; every perturbed copy is
    # one batch of per-state inertials.
    q, qd, qdd = _state(tree, 2, seed=10)
    ins = tree.inertials
    nb = ins.inertia.shape[0]

    def f(inertia):
        i2 = Inertials(ins.mass, ins.com, inertia)
        batch = torch.broadcast_shapes(inertia.shape[:-3], q.shape[:-1])
        x = [v.expand(*batch, -1) for v in (q, qd, qdd)]
        if fn == "mass_matrix":
            return tree.mass_matrix(x[0], inertials=i2)
        return getattr(tree, fn)(*x, inertials=i2)

    I = ins.inertia.clone().requires_grad_()
    out = f(I)
    w = torch.randn(out.shape, generator=torch.Generator().manual_seed(11), dtype=F64)
    (grad,) = torch.autograd.grad((out * w).sum(), I)
    step = 1e-2 * ins.inertia.diagonal(dim1=-2, dim2=-1).mean(-1)  # (nb,)
    E = torch.eye(nb * 9, dtype=F64).view(nb * 9, nb, 3, 3) * step.view(1, nb, 1, 1)
    stencil = ((-2, 1 / 12), (-1, -8 / 12), (1, 8 / 12), (2, -1 / 12))
    fd = sum(c * (f((ins.inertia + k * E).unsqueeze(1)) * w).flatten(1).sum(1) for k, c in stencil)
    fd = fd.view(nb, 3, 3) / step.view(nb, 1, 1)
    torch.testing.assert_close(grad, fd, rtol=1e-5, atol=1e-8 * float(fd.abs().max()))


def test_finite_true_gradients_at_exact_inputs(tree):
    # q = 0 puts the floating joint's rotation vector at exactly 0 (its series branch) and
    # every revolute joint at an axis-aligned pose: autograd equals central differences.
    q = torch.zeros(tree.n_dof, dtype=F64)
    _, qd, qdd = _state(tree, seed=8)

    def f(x):
        return tree.inverse_dynamics(x, qd, qdd)

    J = torch.autograd.functional.jacobian(f, q)
    assert bool(torch.isfinite(J).all())
    h = 1e-6
    fd = torch.stack(
        [(f(q + h * e) - f(q - h * e)) / (2 * h) for e in torch.eye(tree.n_dof, dtype=F64)], -1
    )
    torch.testing.assert_close(J, fd, rtol=0, atol=1e-6 * (1 + float(fd.abs().max())))
    Jqd = torch.autograd.functional.jacobian(lambda v: tree.inverse_dynamics(q, v, qdd), qd)
    assert bool(torch.isfinite(Jqd).all())


def test_finite_gradients_float32():
    chain = Chain.from_urdf(sample_robot("tree"))
    q, qd, qdd = _state(chain, 64, seed=9)
    q[0] = 0.0
    q, qd = q.requires_grad_(), qd.requires_grad_()
    out = chain.inverse_dynamics(q, qd, qdd).sum() + chain.forward_dynamics(q, qd, qdd).sum()
    gq, gqd = torch.autograd.grad(out, (q, qd))
    assert bool(torch.isfinite(gq).all() and torch.isfinite(gqd).all())


def test_half_precision_input():
    chain = Chain.from_urdf(sample_robot("arm7"))
    q, qd, qdd = _state(chain, 3, seed=10)
    tau = chain.inverse_dynamics(q.half(), qd.half(), qdd.half())
    assert tau.dtype == torch.float16
    ref = chain.inverse_dynamics(q.half().float(), qd.half().float(), qdd.half().float())
    torch.testing.assert_close(tau.float(), ref, rtol=1e-3, atol=1e-2)


def test_nan_stays_in_its_batch_element(arm):
    q, qd, qdd = _state(arm, 4, seed=11)
    q[1, 2] = math.nan
    tau = arm.inverse_dynamics(q, qd, qdd)
    M = arm.mass_matrix(q)
    acc = arm.forward_dynamics(q, qd, tau)
    good = [0, 2, 3]
    assert bool(torch.isnan(tau[1]).any()) and bool(torch.isfinite(tau[good]).all())
    assert bool(torch.isfinite(M[good]).all()) and bool(torch.isfinite(acc[good]).all())
    torch.testing.assert_close(acc[good], qdd[good], rtol=0, atol=1e-9)


@pytest.mark.compile
def test_compile_fullgraph_and_vmap():
    # float64, so that the comparison with eager mode is tight.
    chain = Chain.from_urdf(sample_robot("arm7"), dtype=F64)
    q, qd, qdd = _state(chain, 8, seed=12)
    f_ext = {"tool_tcp": torch.ones(6, dtype=F64)}

    def f(q, qd, qdd):  # one forward-kinematics pass and the Newton-Euler sums
        return chain.inverse_dynamics(q, qd, qdd, f_ext=f_ext)

    tau = torch.compile(f, fullgraph=True, backend="aot_eager")(q, qd, qdd)
    assert "_dyn_plan" not in chain.__dict__  # tracing caches nothing
    torch.testing.assert_close(tau, f(q, qd, qdd), rtol=0, atol=1e-10)
    tau_v = torch.func.vmap(chain.inverse_dynamics)(q, qd, qdd)
    torch.testing.assert_close(tau_v, chain.inverse_dynamics(q, qd, qdd), rtol=0, atol=1e-12)
    M_v = torch.func.vmap(chain.mass_matrix)(q)
    torch.testing.assert_close(M_v, chain.mass_matrix(q), rtol=0, atol=1e-12)


@pytest.mark.compile
@pytest.mark.slow
def test_compile_forward_dynamics():
    # The whole pipeline (kinematics, Newton-Euler, composite inertias, Cholesky) in one graph.
    chain = Chain.from_urdf(sample_robot("arm7"), dtype=F64)
    q, qd, qdd = _state(chain, 8, seed=13)
    tau = chain.inverse_dynamics(q, qd, qdd)
    f = torch.compile(chain.forward_dynamics, fullgraph=True, backend="aot_eager")
    torch.testing.assert_close(f(q, qd, tau), qdd, rtol=0, atol=1e-9)


@pytest.mark.compile
@pytest.mark.slow
def test_compile_inductor_arm():
    arm = Chain.from_urdf(sample_robot("arm7"), dtype=F64)
    q, qd, qdd = _state(arm, 16, seed=16)
    f = torch.compile(arm.inverse_dynamics, fullgraph=True)
    torch.testing.assert_close(f(q, qd, qdd), arm.inverse_dynamics(q, qd, qdd), rtol=0, atol=1e-10)


# ----------------------------------------------------------------------------------------------
# Chains without inertials, and bad input
# ----------------------------------------------------------------------------------------------


def _strip_inertials(text: str, links: tuple[str, ...] | None = None) -> str:
    if links is None:
        return re.sub(r"<inertial>.*?</inertial>", "", text, flags=re.S)
    for name in links:
        text = re.sub(
            rf'(<link name="{name}">)\s*<inertial>.*?</inertial>', r"\1", text, flags=re.S
        )
    return text


def test_chain_without_inertials():
    with open(sample_robot("arm7")) as f:
        text = _strip_inertials(f.read())
    chain = Chain.from_urdf(text, dtype=F64)
    assert float(chain.inertials.mass.abs().sum()) == 0.0
    q, qd, qdd = _state(chain, 3, seed=13)
    # Documented: no mass, no forces (zeros, never NaN).
    assert float(chain.inverse_dynamics(q, qd, qdd).abs().max()) == 0.0
    assert float(chain.mass_matrix(q).abs().max()) == 0.0
    with pytest.raises(ValueError, match=r"forward_dynamics: .*singular.*'base_yaw'"):
        chain.forward_dynamics(q, qd, qdd)
    # With inertials given, it works.
    full = Chain.from_urdf(sample_robot("arm7"), dtype=F64)
    tau = full.inverse_dynamics(q, qd, qdd)
    acc = chain.forward_dynamics(q, qd, tau, inertials=full.inertials)
    torch.testing.assert_close(acc, qdd, rtol=0, atol=1e-9)


def test_massless_moving_subtree_is_named():
    with open(sample_robot("tree")) as f:
        text = _strip_inertials(f.read(), ("left_finger_a", "left_finger_b"))
    chain = Chain.from_urdf(text, dtype=F64)
    q, qd, qdd = _state(chain, 2, seed=14)
    assert bool(torch.isfinite(chain.inverse_dynamics(q, qd, qdd)).all())
    with pytest.raises(ValueError, match="left_finger_a"):
        chain.forward_dynamics(q, qd, qdd)


def _two_joints(child_inertial: str, kind: str) -> str:
    inertia = '<inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/>'
    limit = '<limit lower="-1" upper="1" effort="1" velocity="1"/>'
    return (
        f'<robot name="r"><link name="world"/><link name="a"><inertial><mass value="1"/>{inertia}'
        f'</inertial></link><link name="b">{child_inertial}</link>'
        '<joint name="j1" type="revolute"><parent link="world"/><child link="a"/>'
        f'<axis xyz="0 0 1"/>{limit}</joint><joint name="j2" type="{kind}"><parent link="a"/>'
        f'<child link="b"/><origin xyz="0.5 0 0"/><axis xyz="1 0 0"/>{limit}</joint></robot>'
    )


def test_singular_mass_matrix():
    q = torch.tensor([[0.3, 0.2]], dtype=F64)
    one = torch.ones(1, 2, dtype=F64)
    # A translation that moves inertia but no mass: singular at every state, named.
    no_mass = '<inertial><mass value="0"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" '
    chain = Chain.from_urdf(_two_joints(no_mass + 'izz="0.1"/></inertial>', "prismatic"), dtype=F64)
    with pytest.raises(ValueError, match=r"forward_dynamics: the mass matrix is singular.*'j2'"):
        chain.forward_dynamics(q, one, one)
    # The same joint turning instead moves inertia: not singular.
    chain = Chain.from_urdf(_two_joints(no_mass + 'izz="0.1"/></inertial>', "revolute"), dtype=F64)
    assert bool(torch.isfinite(chain.forward_dynamics(q, one, one)).all())
    # A point mass on the axis of the joint turning the last link: M(q) is singular at every
    # state (its computed diagonal entry may round to a tiny positive number, and the
    # accelerations to 1e17): named, as a subtree without mass.  On the axis away from the
    # anchor, at the anchor, on a slanted axis; with a thin rod's inertia along the axis.
    rod = 'ixx="0" ixy="0" ixz="0" iyy="0.2" iyz="0" izz="0.2"'
    for origin, axis, inertia in (
        ("0.3 0 0", "1 0 0", 'ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"'),
        ("0 0 0", "0 1 0", 'ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"'),
        ("0.3 0.6 -0.9", "1 2 -3", 'ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"'),
        ("0.3 0 0", "1 0 0", rod),
    ):
        point = f'<inertial><origin xyz="{origin}"/><mass value="1"/><inertia {inertia}/>'
        text = _two_joints(point + "</inertial>", "revolute").replace(
            '<axis xyz="1 0 0"/>', f'<axis xyz="{axis}"/>'
        )
        chain = Chain.from_urdf(text, dtype=F64)
        with pytest.raises(ValueError, match=r"the mass matrix is singular.*'j2'.*on its joint's"):
            chain.forward_dynamics(q, one, one)
        # inverse dynamics and the mass matrix stay defined
        assert bool(torch.isfinite(chain.inverse_dynamics(q, one, one)).all())
        # off the axis, or with inertia about it: not singular
        for off in (
            text.replace(f'xyz="{origin}"/><mass', 'xyz="0 0 0.1"/><mass'),
            text.replace(inertia, 'ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"'),
        ):
            acc = Chain.from_urdf(off, dtype=F64).forward_dynamics(q, one, one)
            assert bool(torch.isfinite(acc).all()) and float(acc.abs().max()) < 1e3
    # A negative moment about the axis (a file's non-physical <inertia>): named as such too.
    bad = 'ixx="-0.1" ixy="0" ixz="0" iyy="0.2" iyz="0" izz="0.2"'
    point = f'<inertial><origin xyz="0.3 0 0"/><mass value="1"/><inertia {bad}/></inertial>'
    chain = Chain.from_urdf(_two_joints(point, "revolute"), dtype=F64)
    with pytest.raises(ValueError, match=r"singular.*'j2'.*or a negative one.*non-physical"):
        chain.forward_dynamics(q, one, one)
    # Inertials given per state: only the singular state is NaN.
    full = Chain.from_urdf(_two_joints(no_mass + 'izz="0.1"/></inertial>', "revolute"), dtype=F64)
    ins = full.inertials
    mass = ins.mass.expand(3, 2).clone()
    inertia = ins.inertia.expand(3, 2, 3, 3).clone()
    inertia[1, 1] = 0.0  # the second state's link b: no mass, no inertia
    acc = full.forward_dynamics(
        q.expand(3, 2),
        one.expand(3, 2),
        one.expand(3, 2),
        inertials=Inertials(mass, ins.com.expand(3, 2, 3), inertia),
    )
    assert bool(torch.isnan(acc[1]).all()) and bool(torch.isfinite(acc[[0, 2]]).all())
    torch.testing.assert_close(acc[0], full.forward_dynamics(q, one, one)[0], rtol=1e-14, atol=0)


def test_robot_without_degrees_of_freedom():
    chain = Chain.from_urdf(
        '<robot name="r"><link name="a"/><link name="b"><inertial><mass value="1"/>'
        '<inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>'
        '<joint name="j" type="fixed"><parent link="a"/><child link="b"/></joint></robot>'
    )
    q = torch.zeros(3, 0)
    assert chain.body_names == () and chain.inertials.mass.shape == (0,)
    assert chain.inverse_dynamics(q, q, q).shape == (3, 0)
    assert chain.mass_matrix(q).shape == (3, 0, 0)
    assert chain.forward_dynamics(q, q, q).shape == (3, 0)
    assert chain.gravity_torques(q, gravity=torch.ones(3)).shape == (3, 0)


def test_bad_inertial_elements():
    from torchlie.kinematics import URDFError

    base = '<robot name="r"><link name="a">{}</link></robot>'
    with pytest.raises(URDFError, match=r"<link name='a'> <inertial>: missing required element"):
        parse_urdf(base.format('<inertial><mass value="1"/></inertial>'))
    with pytest.raises(URDFError, match="the mass is negative"):
        parse_urdf(
            base.format(
                '<inertial><mass value="-1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" '
                'izz="1"/></inertial>'
            )
        )
    with pytest.raises(URDFError, match="'ixy' is not a number"):
        parse_urdf(
            base.format(
                '<inertial><mass value="1"/><inertia ixx="1" ixy="x" ixz="0" iyy="1" iyz="0" '
                'izz="1"/></inertial>'
            )
        )


def test_bad_arguments(arm):
    q, qd, qdd = _state(arm, 2, seed=15)
    fn = "torchlie.kinematics.Chain.inverse_dynamics"
    with pytest.raises(ValueError, match=rf"{fn}: expected qd of shape \(\.\.\., 7\)"):
        arm.inverse_dynamics(q, qd[:, :6], qdd)
    with pytest.raises(ValueError, match=rf"{fn}: qdd of shape \(3, 7\) does not broadcast"):
        arm.inverse_dynamics(q, qd, torch.zeros(3, 7, dtype=F64))
    with pytest.raises(TypeError, match=rf"{fn}: qd has dtype torch.float32"):
        arm.inverse_dynamics(q, qd.float(), qdd)
    with pytest.raises(ValueError, match=rf"{fn}: f_ext names unknown link 'nope'"):
        arm.inverse_dynamics(q, qd, qdd, f_ext={"nope": torch.zeros(6, dtype=F64)})
    with pytest.raises(ValueError, match=r"expected f_ext\['link3'\] of shape \(\.\.\., 6\)"):
        arm.inverse_dynamics(q, qd, qdd, f_ext={"link3": torch.zeros(3, dtype=F64)})
    with pytest.raises(ValueError, match=r"expected gravity of shape \(\.\.\., 3\)"):
        arm.inverse_dynamics(q, qd, qdd, gravity=torch.zeros(2, dtype=F64))
    for bad in ("down", [True, False, True], np.array([True, False, True])):
        with pytest.raises(TypeError, match=rf"{fn}: expected gravity to be a \(3,\) or"):
            arm.inverse_dynamics(q, qd, qdd, gravity=bad)
    # a wrench on a link fixed to the world acts on the world, and is checked all the same
    for link in ("world", "base"):
        with pytest.raises(ValueError, match=rf"f_ext\['{link}'\] of shape \(5, 6\) does not"):
            arm.inverse_dynamics(q, qd, qdd, f_ext={link: torch.zeros(5, 6, dtype=F64)})
    ins = arm.inertials
    with pytest.raises(ValueError, match=r"mass_matrix: expected inertials.mass of shape"):
        arm.mass_matrix(q, inertials=Inertials(ins.mass[:3], ins.com, ins.inertia))
    with pytest.raises(TypeError, match="expected inertials to be an Inertials"):
        arm.mass_matrix(q, inertials={"mass": ins.mass})
    with pytest.raises(ValueError, match=r"inertials.mass has batch shape \(3,\), which does"):
        arm.mass_matrix(q, inertials=Inertials(ins.mass.expand(3, 7), ins.com, ins.inertia))


# ----------------------------------------------------------------------------------------------
# The validation command reports the dynamics
# ----------------------------------------------------------------------------------------------


def _validate(robot, **kw):
    import io

    import torchlie.kinematics.validate as V

    out = io.StringIO()
    kw.setdefault("samples", 40)
    report = V.validate(robot, out=out, err=io.StringIO(), compare_pk=False, **kw)
    return report, out.getvalue()


def test_validate_reports_dynamics():
    pytest.importorskip("pinocchio")
    report, text = _validate("panda")
    assert report.ok and report.dynamics is not None
    assert set(report.dynamics) == {"tau", "M", "bias", "gravity", "qdd"}
    assert all(v <= 1e-9 for v in report.dynamics.values())
    assert "dynamics against Pinocchio (40 states" in text and "MISMATCH" not in text
    # Without Pinocchio, or without inertials, nothing is said about the dynamics.
    report, text = _validate("panda", compare_pin=False)
    assert report.dynamics is None and "dynamics" not in text
    with open(sample_robot("arm7")) as f:
        report, text = _validate(_strip_inertials(f.read()))
    assert report.ok and report.dynamics is None and "dynamics" not in text


def test_validate_detects_a_dynamics_mismatch(monkeypatch):
    pytest.importorskip("pinocchio")
    good = Chain.mass_matrix
    monkeypatch.setattr(Chain, "mass_matrix", lambda self, q, **kw: good(self, q, **kw) * 1.001)
    report, text = _validate("arm7")
    assert not report.ok and report.status == "fail"
    assert "FAIL: outside tolerance: mass matrix\n" in text
