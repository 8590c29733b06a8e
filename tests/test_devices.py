"""Device placement: no op makes a tensor on the CPU when its operands live elsewhere.

The ``meta`` device stands in for CUDA here (CI has no GPU): its tensors have shapes and dtypes
but no data, so a constant, buffer or index that an op builds on the CPU instead of on its
operands' device fails the op (torch refuses mixed devices) or comes back on the CPU, as it
would on a GPU.  Every public op of the registry of :mod:`test_bad_input` runs with its operands
on ``meta`` and must return tensors on ``meta`` of the CPU run's shapes and dtypes; then the
factories with ``device=``, a head, and a chain's kinematics and dynamics with their backward.
What it cannot see (values computed otherwise on another device) the second half checks where a
GPU is present: the registry, kinematics and dynamics (with a gradient) against the CPU's
values.
"""

from __future__ import annotations

import pytest
import test_bad_input as tb
import torch

import torchlie
from torchlie import nn as tnn
from torchlie.kinematics import Chain, sample_robot

META = torch.device("meta")
F64 = torch.float64

# Calls that read values by design: the registry's constructors with check=True (an explicit
# validity check) and the keyframe times' order; on meta there are none to read.  The heads
# build their layer on the CPU (a head on meta is tested below); the factories take device=
# (below).
_CHECKED = ("torchlie.SO3", "torchlie.SE3", "torchlie.Sim3")


def _kept(name: str, call) -> bool:
    if "_head" in call.__qualname__ or name.endswith((".identity", ".random")):
        return False
    checked = name in _CHECKED or name.startswith(tuple(c + ".from_" for c in _CHECKED))
    return "keyframes" not in name and not checked


SWEEP = [(n, c) for n, c in tb.BATCHED if _kept(n, c)]
SWEEP_IDS = [f"{n}-{i}" for i, (n, _) in enumerate(SWEEP)]


_cpu_arg = tb._arg


def _moved(device: torch.device | str):
    """``test_bad_input._arg`` with its tensors and group elements on ``device``."""

    def arg(kind: object, b: tuple[int, ...]) -> object:
        x = _cpu_arg(kind, b)
        if isinstance(x, torch.Tensor):
            return x.to(device)
        if isinstance(x, torchlie.groups._Group):
            return type(x)(x.tensor.to(device))
        return x

    return arg


def _same_place(got: list[torch.Tensor], want: list[torch.Tensor], name: str) -> None:
    assert len(got) == len(want), name
    for g, w in zip(got, want, strict=True):
        assert g.device == META, f"{name}: a result on {g.device}"
        assert (g.shape, g.dtype) == (w.shape, w.dtype), name


@pytest.mark.parametrize("name,call", SWEEP, ids=SWEEP_IDS)
def test_every_op_keeps_its_operands_device(name, call, monkeypatch):
    want = tb._outputs(call((3,)))
    monkeypatch.setattr(tb, "_arg", _moved(META))
    _same_place(tb._outputs(call((3,))), want, name)


def test_the_sweep_leaves_out_only_value_checks_heads_and_factories():
    left = {n for n, c in tb.BATCHED if not _kept(n, c)}
    assert all(
        n.endswith((".identity", ".random"))
        or "keyframes" in n
        or n in ("torchlie.nn.RotationHead", "torchlie.nn.PoseHead", "torchlie.SO3", "torchlie.SE3")
        or n.startswith(("torchlie.SO3.from_", "torchlie.SE3.from_", "torchlie.Sim3.from_"))
        for n in left
    ), sorted(left)


_FACTORIES = [
    (owner, f)
    for owner in ("so3", "se3", "quaternion", "so2", "se2", "sim3")
    for f in ("identity", "random")
]


@pytest.mark.parametrize("owner,f", _FACTORIES, ids=[f"{o}.{f}" for o, f in _FACTORIES])
def test_factories_make_their_tensors_on_the_device_asked_for(owner, f):
    fn = getattr(getattr(torchlie, owner), f)
    out = fn(2, 3, dtype=F64, device=META)
    assert out.device == META and out.shape[:2] == (2, 3)
    for G in (torchlie.SO3, torchlie.SE3, torchlie.SO2, torchlie.SE2, torchlie.Sim3):
        assert getattr(G, f)(2, dtype=F64, device=META).tensor.device == META


@pytest.mark.parametrize("rep", sorted(tnn.REPRESENTATIONS))
def test_heads_on_the_device_keep_it(rep):
    x = torch.empty(4, 5, dtype=F64, device=META)
    assert tnn.RotationHead(5, rep, dtype=F64, device=META)(x).device == META
    assert tnn.PoseHead(5, rep, dtype=F64, device=META)(x).device == META


def _chain(robot: str, dtype: torch.dtype) -> Chain:
    if robot.startswith("mjcf:"):  # ball and free joints (quaternion coordinates), anchors
        pytest.importorskip("mujoco")
        from test_dynamics_mjcf import HAND

        return Chain.from_mjcf(HAND[robot[5:]], dtype=dtype, device=META)
    return Chain.from_urdf(sample_robot(robot), dtype=dtype, device=META)


@pytest.mark.parametrize("robot", ["arm7", "tree", "panda", "mjcf:free_ball", "mjcf:multi"])
@pytest.mark.parametrize("dtype", [torch.float32, F64], ids=["f32", "f64"])
def test_kinematics_and_dynamics_keep_the_chains_device(robot, dtype):
    chain = _chain(robot, dtype)
    last = chain.link_names[-1]
    q = torch.empty(4, chain.n_dof, dtype=dtype, device=META, requires_grad=True)
    v = torch.empty(4, chain.n_v, dtype=dtype, device=META, requires_grad=True)
    wrench = {last: torch.empty(4, 6, dtype=dtype, device=META)}
    gravity = torch.empty(3, dtype=dtype, device=META)
    outs = [
        *chain.forward_kinematics(q).values(),
        chain.jacobian(q, last),
        chain.inverse_dynamics(q, v, v),
        chain.inverse_dynamics(q, v, v, f_ext=wrench, gravity=gravity),
        chain.mass_matrix(q),
        chain.forward_dynamics(q, v, v, f_ext=wrench),
        chain.bias_forces(q, v),
        chain.gravity_torques(q),
        *chain.inertials,
    ]
    if not robot.startswith("mjcf:"):  # hinge and slide joints only
        targets = torch.empty(4, 4, 4, dtype=dtype, device=META)
        outs += list(chain.inverse_kinematics(targets, last, max_iterations=2, restarts=1))
    assert all(o.device == META for o in outs)
    grads = torch.autograd.grad(chain.inverse_dynamics(q, v, v).sum(), (q, v))
    assert [(g.device, g.shape) for g in grads] == [(META, q.shape), (META, v.shape)]


# ----------------------------------------------------------------------------------------------
# On a GPU (where one is present): the same values as on the CPU
# ----------------------------------------------------------------------------------------------

GPUS = [d for d in ("cuda",) if getattr(torch, d).is_available()]
_RANDOM = ("random", "randn")
GPU_SWEEP = [(n, c) for n, c in SWEEP if not any(k in n for k in _RANDOM)]


def _close(got: list[torch.Tensor], want: list[torch.Tensor], name: str, rtol: float) -> None:
    assert len(got) == len(want), name
    for g, w in zip(got, want, strict=True):
        assert g.device.type != "cpu" and (g.shape, g.dtype) == (w.shape, w.dtype), name
        g = g.cpu()
        if w.dtype == torch.bool:
            assert torch.equal(g, w), name
            continue
        err = ((g - w).abs() / (1.0 + w.abs())).nan_to_num(0.0).max() if w.numel() else 0.0
        assert float(err) <= rtol and torch.equal(g.isnan(), w.isnan()), (name, float(err))


@pytest.mark.skipif(not GPUS, reason="no GPU")
@pytest.mark.parametrize("gpu", GPUS)
@pytest.mark.parametrize("name,call", GPU_SWEEP, ids=[n for n, _ in GPU_SWEEP])
def test_every_op_gives_the_cpus_values_on_a_gpu(name, call, gpu, monkeypatch):
    want = tb._outputs(call((3,)))
    monkeypatch.setattr(tb, "_arg", _moved(gpu))
    _close(tb._outputs(call((3,))), want, name, 1e-12)


@pytest.mark.skipif(not GPUS, reason="no GPU")
@pytest.mark.parametrize("gpu", GPUS)
@pytest.mark.parametrize("robot", ["arm7", "tree", "panda"])
@pytest.mark.parametrize("dtype", [torch.float32, F64], ids=["f32", "f64"])
def test_kinematics_and_dynamics_give_the_cpus_values_on_a_gpu(robot, dtype, gpu):
    rtol = 1e-10 if dtype == F64 else 1e-3  # forward dynamics: M's condition in float32
    path = sample_robot(robot)
    gen = torch.Generator().manual_seed(0)
    n = Chain.from_urdf(path).n_dof
    q, qd, qdd = (torch.randn(64, 3, n, generator=gen, dtype=dtype) for _ in "abc")
    out = {}
    for device in ("cpu", gpu):
        chain = Chain.from_urdf(path, dtype=dtype, device=device)
        x, xd, xdd = (t.to(device) for t in (q, qd, qdd))
        x.requires_grad_(True)
        tau = chain.inverse_dynamics(x, xd, xdd)
        (dtau,) = torch.autograd.grad(tau.square().sum(), x)
        out[device] = [
            *chain.forward_kinematics(x.detach()).values(),
            chain.jacobian(x.detach(), chain.link_names[-1]),
            tau.detach(),
            dtau,
            chain.mass_matrix(x.detach()),
            chain.forward_dynamics(x.detach(), xd, xdd),
        ]
    _close(out[gpu], out["cpu"], robot, rtol)
