"""SE(2): the shared planar checks (``planar_checks``) and what is SE(2)'s own."""

from __future__ import annotations

import math

import pytest
import torch
from planar_checks import *  # noqa: F403  (the shared tests, collected here for se2)

from torchlie import se2, so2


@pytest.fixture
def mod():
    return se2


def test_conversions():
    pose = torch.tensor([[1.0, -2.0, 0.5], [0.0, 3.0, -math.pi / 2]], dtype=torch.float64)
    T = se2.from_xytheta(pose)
    torch.testing.assert_close(se2.to_xytheta(T), pose)
    R, t = se2.to_rt(T)
    torch.testing.assert_close(R, so2.exp(pose[:, 2:]))
    torch.testing.assert_close(t, pose[:, :2])
    torch.testing.assert_close(se2.from_rt(R, t), T)
    # the twist is not (x, y, theta): exp couples the translation with the rotation
    xi = torch.tensor([1.0, 0.0, math.pi / 2], dtype=torch.float64)
    torch.testing.assert_close(
        se2.exp(xi)[:2, 2], torch.tensor([2 / math.pi, 2 / math.pi], dtype=torch.float64)
    )


def test_distance():
    T1 = se2.from_xytheta(torch.tensor([1.0, 1.0, 0.2], dtype=torch.float64))
    T2 = se2.from_xytheta(torch.tensor([4.0, 5.0, -0.3], dtype=torch.float64))
    angle, trans = se2.distance(T1, T2)
    assert float(angle) == pytest.approx(0.5, abs=1e-15) and float(trans) == pytest.approx(
        5.0, abs=1e-15
    )


def test_against_se3_embedding():
    """SE(2) is the subgroup of SE(3) of rotations about z and translations in the xy plane."""
    from torchlie import se3

    gen = torch.Generator().manual_seed(5)
    xi = torch.randn(50, 3, generator=gen, dtype=torch.float64) * 2
    z = torch.zeros(50, 1, dtype=torch.float64)
    xi3 = torch.cat((xi[:, :2], z, z, z, xi[:, 2:]), dim=-1)
    T3 = se3.exp(xi3)
    T2 = se2.exp(xi)
    torch.testing.assert_close(T3[:, :2, :2], T2[:, :2, :2])
    torch.testing.assert_close(T3[:, :2, 3], T2[:, :2, 2])
    J3 = se3.jac_right(xi3)[:, [0, 1, 5]][:, :, [0, 1, 5]]
    torch.testing.assert_close(J3, se2.jac_right(xi))
    J3 = se3.jac_left_inv(xi3)[:, [0, 1, 5]][:, :, [0, 1, 5]]
    torch.testing.assert_close(J3, se2.jac_left_inv(xi))


def test_se2_chordal_mean_averages_the_translations():
    # stationarity and invariance of the means: tests/test_statistics.py, every group
    from torchlie import statistics

    F = torch.float64
    g = torch.Generator().manual_seed(6)
    M0 = se2.random(3, generator=g, dtype=F)
    T = se2.rplus(M0[:, None], 0.4 * torch.randn(3, 6, 3, generator=g, dtype=F))
    w = torch.rand(3, 6, generator=g, dtype=F) + 0.1
    Mc = statistics.se2_mean(T, w, method="chordal")
    tw = (w[..., None] * T[..., :2, 2]).sum(-2) / w.sum(-1, keepdim=True)
    torch.testing.assert_close(Mc[..., :2, 2], tw)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_log_derivatives_at_every_magnitude_of_the_rotation_block(dtype):
    # se2.log and to_xytheta of poses whose rotation block is s R (its polar factor R): the
    # Jacobian in the block's entries, row by row in reverse mode and column by column in
    # forward mode, against central differences of the float64 function (its norm the scale)
    mags = (1e20, 1e-20, 1e-25, 1e35) if dtype == torch.float32 else (1e160, 1e-160, 1e300)
    rtol = 4 * torch.finfo(dtype).eps if dtype == torch.float32 else 1e-8
    a = torch.tensor([0.0, 0.3, math.pi / 2, 2.0, -1.2], dtype=torch.float64)
    entries = ((0, 0), (0, 1), (1, 0), (1, 1))
    E = torch.zeros(4, 3, 3, dtype=dtype)
    for n, (i, j) in enumerate(entries):
        E[n, i, j] = 1.0
    for fn in (se2.log, se2.to_xytheta):
        for s in (1.0, *mags):
            T = se2.from_xytheta(torch.stack((torch.ones_like(a), -2.0 * a, a), -1))
            T[..., :2, :2] *= s
            T = T.to(dtype)
            T64 = T.double()
            want = torch.stack(  # (batch, output, entry)
                [
                    (fn(T64 + 1e-6 * s * E[n].double()) - fn(T64 - 1e-6 * s * E[n].double()))
                    / (2e-6 * s)
                    for n in range(4)
                ],
                -1,
            )
            Tg = T.clone().requires_grad_()
            out = fn(Tg)
            rev = torch.stack(
                [
                    torch.autograd.grad(out[..., k].sum(), Tg, retain_graph=True)[0]
                    for k in range(3)
                ],
                -3,
            )
            fwd = torch.stack(
                [torch.func.jvp(fn, (T,), (E[n].expand_as(T),))[1] for n in range(4)], -1
            )
            for g in (rev[..., :2, :2].flatten(-2), fwd):
                g = g.double() * s  # (the derivatives are ~ 1 / s)
                ref = want * s
                assert bool(g.isfinite().all()), (fn, s, g)
                err = float(
                    ((g - ref).flatten(-2).norm(dim=-1) / ref.flatten(-2).norm(dim=-1)).max()
                )
                assert err <= rtol, (fn, s, err)
            # the translation block's gradient and the bottom row (0) are unchanged by the scale
            assert rev[..., 2, :].abs().max().item() == 0.0


@pytest.mark.parametrize("name", ["jac_left", "jac_right", "jac_left_inv", "jac_right_inv"])
@pytest.mark.parametrize("transform", [torch.func.jacfwd, torch.func.jacrev])
def test_float32_derivatives_of_the_jacobians_at_every_angle(name, transform):
    # The Jacobians' own derivatives (second derivatives of exp and log) in float32 agree with
    # float64's to float32's precision, small angles and the coefficients' switches included.
    fn = getattr(se2, name)
    t = torch.logspace(-4.0, 0.7, 64, dtype=torch.float64)
    t = torch.cat((t, -t))
    x = torch.stack((torch.full_like(t, 0.3), torch.full_like(t, -0.7), t), dim=-1)
    J32 = torch.func.vmap(transform(fn))(x.float()).double()
    J64 = torch.func.vmap(transform(fn))(x)
    err = (J32 - J64).abs().flatten(1).amax(1) / J64.abs().flatten(1).amax(1)
    assert err.max() <= 16 * torch.finfo(torch.float32).eps
