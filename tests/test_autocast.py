"""torchlie's ops are float32-exact inside ``torch.autocast``.

Autocast lowers matrix products to float16/bfloat16; every public op runs with autocast
disabled (``_checks.float32_exact``), so inside a CPU autocast region (bfloat16 and float16)
float32 inputs give the float32 results of outside it, within 4 float32 ulp relative to
``1 + |value|`` (the same kernels run, so in practice they agree exactly), and float64 stays
float64.  The sweep reuses the registry of every public op of :mod:`test_bad_input`
(``BATCHED``), its operands cast to float32; then the group classes, a chain's kinematics and
dynamics, gradients, one compiled graph, and a check that every public function is guarded.
"""

from __future__ import annotations

import pytest
import test_bad_input as tb
import torch

import torchlie
from torchlie import SE3, SO3, se3, so3
from torchlie import nn as tnn

F32 = torch.float32
EPS = torch.finfo(F32).eps
ULP = 4  # inside and outside autocast run the same float32 kernels: a few ulp at most
AMP_DTYPES = (torch.bfloat16, torch.float16)

_orig_arg = tb._arg
_calls = [0]  # operands built in the current call: the k-th one is moved by k steps (below)
_STEP = torch.tensor([0.3, -0.5, 0.7], dtype=torch.float64)


def _arg32(kind: object, b: tuple[int, ...]) -> object:
    """``test_bad_input._arg`` with float64 operands (and ``dtype=torch.float64``) as float32.

    The registry passes one element for both operands of a pair (``compose(R, R)``); here the
    k-th rotation / pose / vector operand of a call is moved by k fixed steps, so that pairs
    differ and ``between``, ``distance``, ``rminus``, ... compute something nonzero.
    """
    if kind is torch.float64:
        return F32
    x = _orig_arg(kind, b)
    if isinstance(kind, str) and kind.rstrip("0") in ("R", "T", "v3", "v6"):
        k, _calls[0] = _calls[0], _calls[0] + 1
        if kind[0] == "R":
            x = x @ so3.exp(k * _STEP)
        elif kind[0] == "T":
            x = x @ se3.exp(torch.cat((-k * _STEP, k * _STEP)))
        else:
            x = x * (1.0 + 0.4 * k)
    if isinstance(x, torch.Tensor) and x.dtype == torch.float64:
        return x.to(F32)
    return x


# The heads build a float64 linear layer of their own (autocast is meant to lower that layer;
# their representation_to_matrix is in the sweep on its own).
SWEEP = [(n, c) for n, c in tb.BATCHED if "_head" not in c.__qualname__]
SWEEP_IDS = [f"{n}-{i}" for i, (n, _) in enumerate(SWEEP)]


def _outputs(out: object) -> list[torch.Tensor]:
    if isinstance(out, torchlie.groups._Group):  # SO3, SE3, SO2, SE2, Sim3
        return [out.tensor]
    if isinstance(out, torch.Tensor):
        return [out]
    return [t for o in out for t in _outputs(o)]


def _run(call, amp_dtype=None):
    torch.manual_seed(0)
    _calls[0] = 0
    if amp_dtype is None:
        return _outputs(call((3,)))
    with torch.autocast("cpu", dtype=amp_dtype):
        return _outputs(call((3,)))


def _assert_same(got: list[torch.Tensor], want: list[torch.Tensor], name: str) -> None:
    assert len(got) == len(want), name
    for g, w in zip(got, want, strict=True):
        assert g.dtype == w.dtype and g.shape == w.shape, (name, g.dtype, w.dtype)
        if not (w.is_floating_point() or w.is_complex()):  # masks, counts
            assert torch.equal(g, w), name
            continue
        if w.is_complex():
            g, w = torch.view_as_real(g), torch.view_as_real(w)
        tol = ULP * torch.finfo(w.dtype).eps * (1.0 + w.abs())
        assert bool(((g - w).abs() <= tol).all()), (name, float((g - w).abs().max()))


@pytest.mark.parametrize("amp_dtype", AMP_DTYPES, ids=["bf16", "f16"])
@pytest.mark.parametrize("name,call", SWEEP, ids=SWEEP_IDS)
def test_every_op_is_float32_exact_under_autocast(name, call, amp_dtype, monkeypatch):
    monkeypatch.setattr(tb, "_arg", _arg32)
    want = _run(call)
    got = _run(call, amp_dtype)
    _assert_same(got, want, name)


#: The modules of functions on tensors (the planar and similarity groups join when they exist).
_MODULES = ("so3", "se3", "quaternion", "conversions", "statistics", "nn", "so2", "se2", "sim3")


def test_every_public_function_is_guarded():
    """Each public function (and Chain's computing methods) goes through ``float32_exact``."""
    from torchlie.kinematics import Chain, ik

    funcs = {
        f"{m}.{n}": getattr(getattr(torchlie, m), n)
        for m in _MODULES
        if hasattr(torchlie, m)
        for n in getattr(torchlie, m).__all__
    }
    funcs = {k: f for k, f in funcs.items() if callable(f) and not isinstance(f, type)}
    computing = ("forward_kinematics", "jacobian", "poses_and_jacobians", "inverse_kinematics",
                 "inverse_dynamics", "mass_matrix", "forward_dynamics", "bias_forces",
                 "gravity_torques")  # fmt: skip
    funcs |= {f"Chain.{n}": getattr(Chain, n) for n in computing}
    funcs["ik.inverse_kinematics"] = ik.inverse_kinematics
    assert len(funcs) > 100
    bare = sorted(k for k, f in funcs.items() if not getattr(f, "float32_exact", False))
    assert bare == []


# ----------------------------------------------------------------------------------------------
# Group classes, kinematics, gradients and torch.compile under autocast
# ----------------------------------------------------------------------------------------------


def _pair(G):
    torch.manual_seed(3)
    return G.random(4), G.random(4)


@pytest.mark.parametrize("amp_dtype", AMP_DTYPES, ids=["bf16", "f16"])
@pytest.mark.parametrize("G", [SO3, SE3], ids=["SO3", "SE3"])
def test_group_class_methods_are_float32_exact_under_autocast(G, amp_dtype):
    X, Y = _pair(G)
    p = torch.randn(4, 3)
    calls = {
        "@": lambda: (X @ Y).tensor,
        "apply": lambda: X.apply(p),
        "@p": lambda: X @ p,
        "log": lambda: X.log(),
        "inverse": lambda: X.inverse().tensor,
        "rminus": lambda: X.rminus(Y),
        "between": lambda: X.between(Y).tensor,
    }
    for name, f in calls.items():
        want = f()
        with torch.autocast("cpu", dtype=amp_dtype):
            got = f()
        _assert_same([got], [want], f"{G.__name__} {name}")


def test_ops_on_each_device_are_float32_exact_under_its_autocast(device):
    # The guard disables autocast for the device type of the op's tensors (CUDA where present).
    torch.manual_seed(5)
    R, T = so3.random(8).to(device), se3.random(8).to(device)
    w, xi = torch.randn(8, 3, device=device), torch.randn(8, 6, device=device)
    calls = {
        "so3.compose": lambda: so3.compose(R, R.flip(0)),
        "so3.rminus": lambda: so3.rminus(R, R.flip(0)),
        "so3.rplus": lambda: so3.rplus(R, w),
        "se3.between": lambda: se3.between(T, T.flip(0)),
        "se3.adjoint": lambda: se3.adjoint(T),
        "se3.jac_left_inv": lambda: se3.jac_left_inv(xi),
    }
    amp_dtype = torch.bfloat16 if device == "cpu" else torch.float16
    for name, f in calls.items():
        want = f()
        with torch.autocast(device, dtype=amp_dtype):
            got = f()
        _assert_same([got], [want], f"{name} on {device}")


def _arm():
    from pathlib import Path

    from torchlie.kinematics import Chain

    urdf = Path(__file__).parent.parent / "torchlie" / "kinematics" / "robots" / "arm7.urdf"
    return Chain.from_urdf(str(urdf), dtype=F32)


@pytest.mark.parametrize("amp_dtype", AMP_DTYPES, ids=["bf16", "f16"])
def test_kinematics_and_dynamics_are_float32_exact_under_autocast(amp_dtype):
    chain = _arm()
    torch.manual_seed(0)
    q = chain.random_configuration(4)
    qd, qdd = torch.randn_like(q), torch.randn_like(q)
    link = chain.link_names[-1]
    target = chain.forward_kinematics(q, link)[link]
    calls = {
        "forward_kinematics": lambda: chain.forward_kinematics(q, stacked=True),
        "jacobian": lambda: chain.jacobian(q, link),
        "poses_and_jacobians": lambda: chain.poses_and_jacobians(q.mT.contiguous(), link),
        "inverse_dynamics": lambda: chain.inverse_dynamics(q, qd, qdd),
        "mass_matrix": lambda: chain.mass_matrix(q),
        "forward_dynamics": lambda: chain.forward_dynamics(q, qd, qdd),
        "bias_forces": lambda: chain.bias_forces(q, qd),
        "gravity_torques": lambda: chain.gravity_torques(q),
        "inverse_kinematics": lambda: tuple(
            chain.inverse_kinematics(target, link, max_iterations=10)
        ),
    }
    for name, f in calls.items():
        torch.manual_seed(1)
        want = _outputs(f())
        torch.manual_seed(1)
        with torch.autocast("cpu", dtype=amp_dtype):
            got = _outputs(f())
        _assert_same(got, want, name)


def _loss(R, T, w):
    """A scalar through custom Functions (log, exp) and matrix products of so3, se3 and nn."""
    R1 = so3.rplus(R, w)
    loss = so3.rminus(R1, R).square().sum() + tnn.geodesic_loss(R1, R.flip(0))
    angle, length = se3.distance(se3.rplus(T, torch.cat((w, w), -1)), T.flip(0))
    return loss + angle.sum() + length.sum()


def _grads(R, T, w0, amp: bool, backward_inside: bool) -> list[torch.Tensor]:
    w = w0.clone().requires_grad_()
    with torch.autocast("cpu", dtype=torch.bfloat16, enabled=amp):
        loss = _loss(R, T, w)
        if backward_inside:
            loss.backward()
    if not backward_inside:
        loss.backward()
    return [loss.detach(), w.grad]


def test_gradients_are_float32_exact_under_autocast():
    # torch's recommended pattern: forward and loss inside autocast, backward outside.
    torch.manual_seed(2)
    R, T, w0 = so3.random(5), se3.random(5), 0.3 * torch.randn(5, 3)
    _assert_same(_grads(R, T, w0, True, False), _grads(R, T, w0, False, False), "gradient")


def test_backward_inside_autocast_is_finite_and_close():
    # A backward called inside the region: torch lowers the backward formulas of its own
    # products (matmul's) as it would in any model; torchlie's custom backwards run in float32.
    torch.manual_seed(2)
    R, T, w0 = so3.random(5), se3.random(5), 0.3 * torch.randn(5, 3)
    (loss, g), (loss0, g0) = _grads(R, T, w0, True, True), _grads(R, T, w0, False, False)
    assert loss.dtype == g.dtype == F32 and bool(torch.isfinite(g).all())
    _assert_same([loss], [loss0], "loss")
    assert float((g - g0).abs().max()) <= 2e-2 * float(g0.abs().max())  # bfloat16: 8 bits


@pytest.mark.compile
def test_compiled_fullgraph_is_float32_exact_under_autocast():
    torch.manual_seed(4)
    R, T, w = so3.random(6), se3.random(6), torch.randn(6, 3)

    def f(R, T, w):
        return so3.rminus(so3.rplus(R, w), R), se3.between(T, T.flip(0)), so3.distance(R, R.flip(0))

    want = list(f(R, T, w))
    compiled = torch.compile(f, fullgraph=True)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        got = list(compiled(R, T, w))
    _assert_same(got, want, "compiled")
    assert all(g.dtype == F32 for g in got)
