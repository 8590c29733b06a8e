"""SO(2): the shared planar checks (``planar_checks``) and what is SO(2)'s own."""

from __future__ import annotations

import math

import pytest
import torch
from planar_checks import *  # noqa: F403  (the shared tests, collected here for so2)

from torchlie import so2


@pytest.fixture
def mod():
    return so2


def test_complex_conversions():
    theta = torch.tensor([[0.0], [0.5], [-2.0], [math.pi]], dtype=torch.float64)
    R = so2.exp(theta)
    z = so2.to_complex(R)
    torch.testing.assert_close(z, torch.cat((theta.cos(), theta.sin()), dim=-1))
    torch.testing.assert_close(so2.from_complex(3.0 * z), R)
    assert bool(torch.isnan(so2.from_complex(torch.zeros(2))).all())
    torch.testing.assert_close(so2.angle_to_complex(theta), z)
    torch.testing.assert_close(so2.complex_to_angle(2.0 * z), so2.log(R))
    assert float(so2.complex_to_angle(torch.tensor([-1.0, -0.0], dtype=torch.float64))) == math.pi


def test_log_range():
    theta = torch.linspace(-3 * math.pi, 3 * math.pi, 1001, dtype=torch.float64)[:, None]
    out = so2.log(so2.exp(theta))
    assert bool((out > -math.pi).all()) and bool((out <= math.pi).all())
    torch.testing.assert_close(so2.exp(out), so2.exp(theta))


def test_distance_and_trivial_jacobians():
    a = so2.exp(torch.tensor([0.2], dtype=torch.float64))
    b = so2.exp(torch.tensor([-3.0], dtype=torch.float64))
    assert float(so2.distance(a, b)) == pytest.approx(2 * math.pi - 3.2, abs=1e-14)
    assert float(so2.distance(a, a)) == 0.0
    assert so2.adjoint(a).tolist() == [[1.0]] and so2.ad(torch.ones(1)).tolist() == [[0.0]]


def test_so2_mean():
    from scipy.stats import circmean

    from torchlie import statistics

    F = torch.float64
    g = torch.Generator().manual_seed(5)
    theta = torch.rand(4, 7, 1, generator=g, dtype=F) * 2.0 - 1.0 + 3.0  # around the half turn
    R = so2.exp(theta)
    w = torch.rand(4, 7, generator=g, dtype=F) + 0.1
    # chordal: the circular mean (scipy's, unweighted)
    mc = so2.log(statistics.so2_mean(R, method="chordal"))[..., 0]
    ref = torch.tensor(circmean(theta[..., 0].numpy(), high=math.pi, low=-math.pi, axis=-1))
    torch.testing.assert_close(
        torch.remainder(mc - ref + math.pi, 2 * math.pi) - math.pi,
        torch.zeros(4, dtype=F),
        atol=1e-12,
        rtol=0,
    )
    # geodesic about the half turn, where the angles wrap: stationary (the other properties
    # of the means: tests/test_statistics.py, every group)
    M = statistics.so2_mean(R, w)
    r = (w[..., None] * so2.rminus(R, M[:, None])).sum(-2)
    assert float(r.abs().max()) < 1e-13
    # no direction: two opposite rotations of equal weight give NaN for that set only
    Rn = torch.stack((torch.stack((torch.eye(2, dtype=F), -torch.eye(2, dtype=F))), R[0, :2]))
    out = statistics.so2_mean(Rn, method="chordal")
    assert out[0].isnan().all() and out[1].isfinite().all()
