"""The eager kernels' layout changes (column copies, strided stores) hold their numbers exactly."""

from __future__ import annotations

import pytest
import torch
from agreement import assert_agree, assert_bits
from samplers import rotvecs

from torchlie import _layout, conversions, quaternion, se3, so3

DTYPES = [torch.float32, torch.float64]


@pytest.fixture(autouse=True)
def small_threshold(monkeypatch):
    """Batches of 512 elements or more take the large-batch copies (the tests' batches are
    small)."""
    monkeypatch.setattr(_layout, "MIN_ROWS", 512)


@pytest.mark.parametrize("dtype", DTYPES)
def test_planes_and_interleave_are_exact(dtype):
    g = torch.Generator().manual_seed(3)
    x = torch.randn(2, 700, 4, generator=g, dtype=dtype)
    x[0, 5] = torch.tensor([1e-40 if dtype == torch.float64 else 1e-42, 3e38, -2.5, 0.0])
    x[1, 6] = torch.tensor([float("nan"), -0.0, float("inf"), 1.0])
    parts = _layout.planes(x, 4)
    assert all(p.is_contiguous() and p.shape == (2, 700) for p in parts)
    assert_bits(torch.stack(parts, -1), x, "planes")
    out = _layout.interleave(parts)
    assert_bits(out, x, "interleave")


@pytest.mark.parametrize("dtype", DTYPES)
def test_planes_of_3_vectors_column_by_column(dtype):
    """3-vectors are split by one copy per column: bit for bit, non-finite components kept
    in their element and component."""
    g = torch.Generator().manual_seed(9)
    x = torch.randn(2, 700, 3, generator=g, dtype=dtype)
    x[0, 5] = torch.tensor([float("nan"), -0.0, float("inf")])
    x[1, 7] = torch.tensor([1e-40 if dtype == torch.float64 else 1e-42, 3e38, -2.5])
    parts = _layout.planes(x, 3)
    assert all(p.is_contiguous() and p.shape == (2, 700) for p in parts)
    assert_bits(parts, x.unbind(-1), "planes of 3-vectors")
    assert not parts[0][0, 4].isnan() and parts[1][0, 5].signbit()
    y = x.clone().requires_grad_()  # recorded by autograd: the differentiable copy
    parts = _layout.planes(y, 3)
    (grad,) = torch.autograd.grad(parts[1].sum(), y)
    assert torch.equal(grad, torch.tensor([0.0, 1.0, 0.0], dtype=dtype).expand_as(y))


@pytest.mark.parametrize("dtype", DTYPES)
def test_planes_of_a_strided_rotation_block(dtype):
    g = torch.Generator().manual_seed(4)
    T = torch.randn(3, 300, 4, 4, generator=g, dtype=dtype)
    for M in (T[..., :3, :3], T[..., 1:, 1:], T[..., :3, :3].transpose(-1, -2), T[:, ::2, :3, :3]):
        parts = _layout.planes(M, (3, 3))
        want = M.flatten(-2).unbind(-1)
        assert len(parts) == 9
        assert all(torch.equal(a, b) for a, b in zip(parts, want, strict=True))


def test_plain_copies_under_vmap():
    x = torch.randn(3, 1000, 4, dtype=torch.float64)
    got = torch.func.vmap(lambda y: _layout.interleave(_layout.planes(y, 4)))(x)
    assert torch.equal(got, x)


def _values_and_grads(cases):
    out = []
    for fn, args in cases:
        leaves = [a.clone().requires_grad_() if torch.is_tensor(a) else a for a in args]
        y = fn(*leaves)
        grads = torch.autograd.grad(
            y, [a for a in leaves if torch.is_tensor(a)], torch.ones_like(y)
        )
        out.append((fn.__name__, y.detach(), grads))
    return out


def _cases(dtype):
    """Public ops over more than ``MIN_ROWS`` elements, singular angles included."""
    w, _ = rotvecs(dtype=dtype)
    n = w.shape[0]
    g = torch.Generator().manual_seed(5)
    xi = torch.cat((torch.randn(n, 3, generator=g, dtype=dtype), w), -1)
    R, T, q = so3.exp(w), se3.exp(xi), quaternion.from_rotvec(w)
    return [
        (so3.exp, (w,)),
        (so3.log, (R,)),
        (so3.jac_left, (w,)),
        (so3.hat, (w,)),
        (quaternion.to_matrix, (q,)),
        (quaternion.from_matrix, (R,)),
        (quaternion.multiply, (q, q.flip(0))),
        (quaternion.log, (q,)),
        (se3.exp, (xi,)),
        (se3.log, (T,)),
        (conversions.matrix_to_euler, (R, "ZYX")),
        (conversions.rot6d_to_matrix, (R[..., :2, :].flatten(-2),)),
    ]


@pytest.mark.parametrize("dtype", DTYPES)
def test_large_batch_kernels_agree_with_the_small_ones(dtype, monkeypatch):
    """Values and gradients of the ops agree with those of the small-batch layout."""
    fast = _values_and_grads(_cases(dtype))
    monkeypatch.setattr(_layout, "MIN_ROWS", 10**12)
    slow = _values_and_grads(_cases(dtype))
    for (name, y1, g1), (_, y2, g2) in zip(fast, slow, strict=True):
        assert_agree([y1, *g1], [y2, *g2], name)


def test_interleave_is_differentiable_where_autograd_records():
    x = torch.randn(700, 3, dtype=torch.float64, requires_grad=True)
    parts = [2.0 * c for c in x.unbind(-1)]
    y = _layout.interleave(parts)
    assert torch.equal(y, 2.0 * x)
    (grad,) = torch.autograd.grad(y, x, torch.arange(2100.0, dtype=x.dtype).view(700, 3))
    assert torch.equal(grad, 2.0 * torch.arange(2100.0, dtype=x.dtype).view(700, 3))


def test_no_output_planes_where_autograd_records():
    x = torch.randn(700)
    assert _layout.outputs(x, 3) != (None,) * 3
    y = x.clone().requires_grad_()
    assert _layout.outputs(y, 3) == (None,) * 3
    with torch.no_grad():
        assert _layout.outputs(y, 3) != (None,) * 3
    with torch.autograd.forward_ad.dual_level():
        assert _layout.outputs(x, 3) == (None,) * 3
    assert _layout.outputs(x[:10], 3) == (None,) * 3  # small batch: the copies


@pytest.mark.parametrize("dtype", DTYPES)
def test_broadcast_batches_of_large_inputs(dtype):
    """Operands whose batches broadcast (one of them large): values and gradients equal those
    of the same op on operands expanded to the full batch first."""
    g = torch.Generator().manual_seed(10)
    a = quaternion.random(700, 1, generator=g, dtype=dtype)
    b = quaternion.random(1, 3, generator=g, dtype=dtype)
    strided = torch.randn(4, 700, 1, generator=g, dtype=dtype).permute(1, 2, 0)
    A = se3.random(700, 1, generator=g, dtype=dtype)
    B = se3.random(1, 3, generator=g, dtype=dtype)
    p_small = torch.randn(1, 3, 3, generator=g, dtype=dtype)
    p_large = torch.randn(700, 1, 3, generator=g, dtype=dtype)
    cases = [
        (quaternion.multiply, (a, b)),
        (quaternion.multiply, (b, a)),
        (quaternion.multiply, (strided, b)),
        (quaternion.apply, (a, p_small)),
        (quaternion.apply, (b, p_large)),
        (se3.compose, (A, B)),
        (se3.compose, (B, A)),
        (se3.act, (A, p_small)),
        (so3.act, (A[..., :3, :3], p_small)),
    ]
    eps = torch.finfo(dtype).eps
    for fn, args in cases:
        leaves = [x.clone().requires_grad_() for x in args]
        y = fn(*leaves)
        c = torch.randn(y.shape, generator=g, dtype=dtype)
        grads = torch.autograd.grad(y, leaves, c)
        batch = y.shape[:2]
        full = [x.expand(batch + x.shape[2:]) for x in leaves]
        want = fn(*[x.contiguous() for x in full])
        want_grads = torch.autograd.grad(fn(*full), leaves, c)
        with torch.no_grad():
            torch.testing.assert_close(fn(*args), want, rtol=4 * eps, atol=8 * eps)
        torch.testing.assert_close(y.detach(), want, rtol=4 * eps, atol=8 * eps)
        for got, ref in zip(grads, want_grads, strict=True):
            # sums over the broadcast dimension: a few eps per summand
            torch.testing.assert_close(got, ref, rtol=4 * eps, atol=16 * eps * 700)


def test_broadcast_of_batch_shapes():
    S = torch.Size
    assert _layout.broadcast(S((5, 2)), S((5, 2))) == S((5, 2))
    assert type(_layout.broadcast((3,), (3,))) is S
    assert _layout.broadcast(S(()), S(())) == S(())
    for shapes in [((5, 1), (1, 3)), ((2,), (4, 1)), ((), (7,)), ((1,), (6, 1), (6, 2))]:
        assert _layout.broadcast(*map(S, shapes)) == torch.broadcast_shapes(*shapes)
    with pytest.raises(ValueError, match="do not broadcast"):
        _layout.broadcast(S((2,)), S((3,)))
