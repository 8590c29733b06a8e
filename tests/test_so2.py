"""SO(2): the shared planar checks (``planar_checks``) and what is SO(2)'s own."""

from __future__ import annotations

import math

import pytest
import torch
from planar_checks import *  # noqa: F403  (the shared tests, collected here for so2)

from torchlie import se2, so2


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


# ----------------------------------------------------------------------------------------------
# Derivatives of the angle at every finite magnitude of the conformal part
# ----------------------------------------------------------------------------------------------

#: magnitudes of ``z`` whose squares overflow or underflow (1e+-20 in float32, 1e+-160 in
#: float64 and beyond), with a moderate one; the gradient ~ 1 / |z| stays representable
_GRAD_MAGNITUDES = {
    torch.float32: (1.0, 1e20, 1e-20, 1e-21, 1e25, 1e-25, 1e35, 1e-35),
    torch.float64: (1.0, 1e160, 1e-160, 1e-170, 1e250, 1e-250, 1e300, 1e-300),
}
#: magnitudes whose second derivatives ~ 1 / |z|^2 are representable
_HESS_MAGNITUDES = {
    torch.float32: (1.0, 1e15, 1e-15, 1e18, 1e-18),
    torch.float64: (1.0, 1e150, 1e-150, 1e154, 1e-154),
}
_ANGLES = (0.0, 0.3, math.pi / 2, 2.0, math.pi, -1.2, -math.pi / 2)


def _complex_points(scale: float, dtype: torch.dtype) -> torch.Tensor:
    a = torch.tensor(_ANGLES, dtype=torch.float64)
    return (scale * torch.stack((a.cos(), a.sin()), dim=-1)).to(dtype)


def _central(f, z: torch.Tensor, rel: float, wrap: bool = False) -> torch.Tensor:
    """Central differences of ``f`` (float64, one output per row) at the rows of ``z``
    ``(n, 2)``, with steps ``rel * max_i |z_i|`` along each component: ``(n, 2)`` (or ``(n, 2, k)``
    for ``k`` outputs per row)."""
    z = z.double()
    h = rel * z.abs().amax(-1)  # (no squares at 1e+-300)
    cols = []
    for i in range(2):
        e = torch.zeros_like(z)
        e[:, i] = h
        d = f(z + e) - f(z - e)
        if wrap:  # the continuous angle across the half turn
            d = torch.remainder(d + math.pi, 2.0 * math.pi) - math.pi
        d = d / (2.0 * h.reshape((-1,) + (1,) * (d.dim() - 1)))
        cols.append(d)
    return torch.stack(cols, dim=1)


def _assert_rows_close(got: torch.Tensor, want: torch.Tensor, rtol: float) -> None:
    """Each row within ``rtol`` times the row's norm (components that are 0 included)."""
    scale = want.double().flatten(1).abs().amax(-1, keepdim=True)  # no squares at 1e-300
    got, want = got.double().flatten(1) / scale, want.double().flatten(1) / scale
    err = (got - want).norm(dim=-1) / want.norm(dim=-1)
    assert bool(torch.isfinite(got).all()), got
    assert float(err.max()) <= rtol, (float(err.max()), got, want)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_angle_gradient_at_every_magnitude(dtype):
    # reverse and forward mode of complex_to_angle (so2.log's Function) against central
    # differences of the float64 angle (exact in value at these magnitudes)
    rtol = 4 * torch.finfo(dtype).eps if dtype == torch.float32 else 1e-8
    for s in _GRAD_MAGNITUDES[dtype]:
        z = _complex_points(s, dtype)
        want = _central(lambda v: so2.complex_to_angle(v)[..., 0], z, 1e-6, wrap=True)
        zg = z.clone().requires_grad_()
        (grad,) = torch.autograd.grad(so2.complex_to_angle(zg).sum(), zg)
        _assert_rows_close(grad, want, rtol)
        jac = torch.func.jacfwd(so2.complex_to_angle)(z[0])  # (1, 2)
        _assert_rows_close(jac, want[:1], rtol)
        e = torch.eye(2, dtype=dtype)
        fwd = torch.stack(
            [torch.func.jvp(so2.complex_to_angle, (z,), (e[i].expand_as(z),))[1] for i in (0, 1)],
            dim=1,
        )
        _assert_rows_close(fwd[..., 0], want, rtol)
        # so2.log of the matrix [[x, -y], [y, x]]: its conformal part is 2 z, the derivative
        # along R00 (R10) half that along z0 (z1)
        R = so2.matrix(z[:, 0], z[:, 1]).requires_grad_()
        (gR,) = torch.autograd.grad(so2.log(R).sum(), R)
        _assert_rows_close(2.0 * torch.stack((gR[:, 0, 0], gR[:, 1, 0]), -1), want, rtol)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_angle_second_derivatives_at_large_and_small_magnitudes(dtype):
    # double backward (the Hessian of complex_to_angle) against central differences of the
    # float64 gradient
    rtol = 8 * torch.finfo(dtype).eps if dtype == torch.float32 else 1e-7

    def grad64(v):
        v = v.clone().requires_grad_()
        return torch.autograd.grad(so2.complex_to_angle(v).sum(), v)[0]

    for s in _HESS_MAGNITUDES[dtype]:
        z = _complex_points(s, dtype)
        want = _central(grad64, z, 1e-5)  # (n, 2 [d/dz_i], 2 [grad component])
        for i in range(z.shape[0]):
            H = torch.autograd.functional.hessian(lambda v: so2.complex_to_angle(v)[0], z[i])
            _assert_rows_close(H.reshape(1, 4), want[i].reshape(1, 4), rtol)


def test_complex_to_angle_up_to_the_largest_float():
    for dtype in (torch.float32, torch.float64):
        big = torch.finfo(dtype).max
        z = torch.tensor([[big, big / 3], [-big / 2, -big], [big, -big]], dtype=dtype)
        want = torch.atan2(z[:, 1].double(), z[:, 0].double())
        torch.testing.assert_close(so2.complex_to_angle(z)[:, 0].double(), want, rtol=0, atol=1e-6)
        zg = z.clone().requires_grad_()
        (g,) = torch.autograd.grad(so2.complex_to_angle(zg).sum(), zg)
        zd = z.double() / big  # (the reference without squares at 1e308)
        ref = torch.stack((-zd[:, 1], zd[:, 0]), -1) / (zd * zd).sum(-1, keepdim=True) / big
        # the gradients ~ 1 / max are subnormal: 21 significant bits in float32, 49 in float64
        rtol = 1e-5 if dtype == torch.float32 else 1e-13
        torch.testing.assert_close(g.double(), ref, rtol=rtol, atol=0)


def test_angle_derivatives_at_the_zero_conformal_part():
    # no direction: the documented 0 in every mode, never NaN
    for dtype in (torch.float32, torch.float64):
        z = torch.zeros(2, dtype=dtype, requires_grad=True)
        (g,) = torch.autograd.grad(so2.complex_to_angle(z).sum(), z, create_graph=True)
        assert g.tolist() == [0.0, 0.0]
        (h,) = torch.autograd.grad(g.sum(), z, allow_unused=True, materialize_grads=True)
        assert bool(h.isfinite().all())  # (not differentiable there: finite is all it is)
        t = torch.func.jvp(so2.complex_to_angle, (z.detach(),), (torch.ones(2, dtype=dtype),))[1]
        assert t.tolist() == [0.0]
        R = torch.zeros(2, 2, dtype=dtype, requires_grad=True)
        (gR,) = torch.autograd.grad(so2.log(R).sum(), R)
        assert gR.abs().sum().item() == 0.0


@pytest.mark.compile
def test_compiled_angle_gradient_at_large_and_small_magnitudes():
    # torch.compile (Inductor) of the derivative's exact scaling (the exponent field read as
    # bits) gives eager's gradient (the compiled backward) and tangent
    torch._dynamo.reset()
    log = torch.compile(so2.log, fullgraph=True)
    tangent = torch.compile(lambda R, dR: torch.func.jvp(so2.log, (R,), (dR,))[1], fullgraph=True)
    for dtype, mags in ((torch.float32, (1.0, 1e20, 1e-25)), (torch.float64, (1.0, 1e160, 1e-300))):
        z = torch.cat([_complex_points(s, dtype) for s in mags])
        R = so2.matrix(z[:, 0], z[:, 1]).requires_grad_()
        dR = torch.ones_like(R)
        got = (torch.autograd.grad(log(R).sum(), R)[0], tangent(R.detach(), dR))
        want = (
            torch.autograd.grad(so2.log(R).sum(), R)[0],
            torch.func.jvp(so2.log, (R.detach(),), (dR,))[1],
        )
        for a, b in zip(got, want, strict=True):
            assert bool(a.isfinite().all())
            torch.testing.assert_close(a, b, rtol=4 * torch.finfo(dtype).eps, atol=0)


@pytest.mark.parametrize(("dtype", "s"), [(torch.float32, 3e38), (torch.float64, 1e308)])
def test_log_at_the_top_of_the_range(dtype, s):
    """so2.log, se2.log and the planar parametrizations of ``s R`` where ``R00 + R11`` overflows:
    the angle of ``R`` and its gradient, ``1 / s`` times the gradient at ``R``."""
    from torchlie import nn as tnn

    a = torch.tensor([[0.3], [2.0], [-1.2]], dtype=dtype)
    R = so2.exp(a)
    tol = {"rtol": 1e-5, "atol": 0.0}
    for fn, X in (
        (so2.log, R),
        (lambda T: se2.log(T)[..., 2:], se2.from_rt(R, torch.ones(3, 2, dtype=dtype))),
    ):
        Xs = X.clone()
        Xs[..., :2, :2] *= s
        Xs.requires_grad_()
        y = fn(Xs)
        torch.testing.assert_close(y, a, rtol=2 * torch.finfo(dtype).eps, atol=0.0)
        (g,) = torch.autograd.grad(y.sum(), Xs)
        X1 = X.clone().requires_grad_()
        (g1,) = torch.autograd.grad(fn(X1).sum(), X1)
        torch.testing.assert_close((g[..., :2, :2].double() * s), g1[..., :2, :2].double(), **tol)
    P = tnn.SO2Parametrization("matrix")
    torch.testing.assert_close(P(R * s), R, rtol=2 * torch.finfo(dtype).eps, atol=1e-7)
