"""torchlie.nn for the planar groups: PlanarPoseHead, so2/se2 geodesic losses, parametrizations."""

from __future__ import annotations

import math

import pytest
import torch
from torch.nn.utils import parametrize

from torchlie import SE2, nn, se2, so2

F64 = torch.float64


@pytest.mark.parametrize("scale", [0.0, 1e-30, 1.0, 1e30])
def test_head_valid_and_finite_grad(scale, dtype, gen):
    head = nn.PlanarPoseHead(5, dtype=dtype)
    x = (scale * torch.randn(7, 5, generator=gen, dtype=dtype)).requires_grad_(True)
    T = head(x)
    assert T.shape == (7, 3, 3) and bool(se2.is_valid(T).all())
    T.sum().backward()
    assert bool(torch.isfinite(x.grad).all())
    assert isinstance(nn.PlanarPoseHead(5, output="SE2", dtype=dtype)(x), SE2)


def test_head_zero_output_is_identity():
    head = nn.PlanarPoseHead(3, dtype=F64)
    torch.nn.init.zeros_(head.linear.weight)
    torch.nn.init.zeros_(head.linear.bias)
    assert torch.equal(head(torch.ones(2, 3, dtype=F64)), se2.identity(2, dtype=F64))


def test_losses(dtype):
    theta = torch.tensor([[0.0], [0.5], [-2.0], [math.pi]], dtype=dtype)
    R = so2.exp(theta)
    eye = so2.identity(dtype=dtype)
    tol = dict(rtol=0, atol=10 * torch.finfo(dtype).eps)
    torch.testing.assert_close(
        nn.so2_geodesic_loss(R, eye, reduction="none"), theta[:, 0].abs(), **tol
    )
    chordal = 8 * torch.sin(theta[:, 0] / 2) ** 2
    torch.testing.assert_close(
        nn.so2_geodesic_loss(R, eye, kind="chordal", reduction="none"), chordal, **tol
    )
    T = se2.from_rt(R, torch.tensor([3.0, 4.0], dtype=dtype))
    loss = nn.se2_geodesic_loss(T, se2.identity(dtype=dtype), rotation_weight=2.0, reduction="none")
    torch.testing.assert_close(loss, 2 * theta[:, 0].abs() + 5.0, **tol)
    loss = nn.se2_geodesic_loss(T, se2.identity(dtype=dtype), kind="chordal", reduction="sum")
    torch.testing.assert_close(loss, (chordal + 25.0).sum(), **tol)
    # gradients finite at 0 and pi (zero subgradients there)
    Rg = R.clone().requires_grad_(True)
    nn.so2_geodesic_loss(Rg, eye).backward()
    assert bool(torch.isfinite(Rg.grad).all())


@pytest.mark.parametrize(
    "cls, rep",
    [(nn.SO2Parametrization, r) for r in ("complex", "matrix", "angle")]
    + [(nn.SE2Parametrization, r) for r in ("pos_complex", "matrix", "twist")],
)
def test_parametrization_adam_reaches_target(cls, rep):
    mod = so2 if cls is nn.SO2Parametrization else se2
    gen = torch.Generator().manual_seed(0)
    target = mod.random(6, generator=gen, dtype=F64)
    holder = torch.nn.Module()
    holder.X = torch.nn.Parameter(mod.identity(6, dtype=F64))
    parametrize.register_parametrization(holder, "X", cls(rep))
    torch.testing.assert_close(holder.X, mod.identity(6, dtype=F64))
    opt = torch.optim.Adam(holder.parameters(), lr=0.05)
    for _ in range(300):
        opt.zero_grad()
        loss = ((holder.X - target) ** 2).sum()
        loss.backward()
        opt.step()
    assert bool(mod.is_valid(holder.X).all())
    torch.testing.assert_close(holder.X, target, rtol=0, atol=1e-3)
    holder.X = target  # right_inverse
    torch.testing.assert_close(holder.X, target)


def test_bad_arguments():
    with pytest.raises(ValueError, match="torchlie.nn.PlanarPoseHead: .*output"):
        nn.PlanarPoseHead(3, output="SE3")
    with pytest.raises(ValueError, match="torchlie.nn.so2_geodesic_loss: .*kind"):
        nn.so2_geodesic_loss(torch.eye(2), torch.eye(2), kind="geodesic")
    with pytest.raises(ValueError, match="torchlie.nn.se2_geodesic_loss"):
        nn.se2_geodesic_loss(torch.eye(3), torch.eye(4))
    with pytest.raises(ValueError, match="torchlie.nn.SO2Parametrization"):
        nn.SO2Parametrization("quaternion")
    with pytest.raises(ValueError, match="torchlie.nn.SE2Parametrization"):
        nn.SE2Parametrization("twist")(torch.zeros(4))
