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
