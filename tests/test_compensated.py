"""The compensated float64 kernel of so3.exp and its error-free transforms."""

from __future__ import annotations

from fractions import Fraction

import pytest
import torch
from samplers import ANGLES, rotvecs

from torchlie import _compensated as C
from torchlie import so3

F64 = torch.float64


def _exact(t: torch.Tensor) -> list[Fraction]:
    return [Fraction(v) for v in t.tolist()]


def _hard_doubles(n: int, seed: int) -> torch.Tensor:
    """Random doubles over many binades and both signs (full 53-bit significands)."""
    g = torch.Generator().manual_seed(seed)
    mant = torch.rand(n, generator=g, dtype=F64) + 1.0
    expo = torch.randint(-60, 60, (n,), generator=g).to(F64)
    sign = torch.where(torch.rand(n, generator=g) < 0.5, -1.0, 1.0).to(F64)
    return sign * mant * torch.exp2(expo)


def _fused_or_fallback(fused: bool, x: torch.Tensor) -> bool:
    """For the fused cases: on a CPU whose addcmul is not fused, the kernel must not use it."""
    if fused and not C.FUSED_CPU:
        assert not C._fused(x)
        return False
    return True


@pytest.mark.parametrize("fused", [False, True], ids=["split", "fused"])
def test_error_free_transforms_are_exact(fused):
    a, b = _hard_doubles(2000, 1), _hard_doubles(2000, 2)
    if not _fused_or_fallback(fused, a):
        return
    hi, lo = C._split(a)
    assert all(h + l == x for h, l, x in zip(_exact(hi), _exact(lo), _exact(a), strict=True))
    p, e = C._two_prod(a, b, fused=fused)
    want = [x * y for x, y in zip(_exact(a), _exact(b), strict=True)]
    assert [x + y for x, y in zip(_exact(p), _exact(e), strict=True)] == want
    # strided operands (a transposed view)
    at, bt = a.reshape(40, 50).t(), b.reshape(40, 50).t()
    p, e = C._two_prod(at, bt, fused=fused)
    want = [x * y for x, y in zip(_exact(at.flatten()), _exact(bt.flatten()), strict=True)]
    assert [x + y for x, y in zip(_exact(p.flatten()), _exact(e.flatten()), strict=True)] == want
    p, e = C._two_sqr(a, fused=fused)
    assert [x + y for x, y in zip(_exact(p), _exact(e), strict=True)] == [x * x for x in _exact(a)]
    s, e = C._two_sum(a, b)
    want = [x + y for x, y in zip(_exact(a), _exact(b), strict=True)]
    assert [x + y for x, y in zip(_exact(s), _exact(e), strict=True)] == want


def test_theta2_is_exact_to_double_double():
    w = torch.stack([_hard_doubles(500, k) for k in (3, 4, 5)], -1) * 1e-3
    _, _, _, S, S_lo = C._theta2(*w.unbind(-1))
    for row, s, s_lo in zip(w.tolist(), S.tolist(), S_lo.tolist(), strict=True):
        exact = sum(Fraction(v) ** 2 for v in row)
        assert abs(Fraction(s) + Fraction(s_lo) - exact) <= exact * Fraction(2) ** -100


def test_exp_identity_exact_at_zero_and_matches_plain_formula():
    assert torch.equal(C.exp(torch.zeros(4, 3, dtype=F64)), torch.eye(3, dtype=F64).expand(4, 3, 3))
    w, _ = rotvecs(ANGLES, n_random=20, dtype=F64)
    plain = so3._exp(w.float()).double()  # float32 path: independent formula
    torch.testing.assert_close(C.exp(w), plain, rtol=0, atol=4e-7)


def test_fused_and_split_kernels_give_the_same_bits():
    w, _ = rotvecs(ANGLES, n_random=50, dtype=F64)
    w = torch.cat((w, w[:200] * 1e3, w[:200] * 1e-9, w[:100] * 1e20))
    assert C._fused(w) == C.FUSED_CPU  # eager CPU takes the fused products where they are exact
    if not _fused_or_fallback(True, w):
        return
    assert torch.equal(C.exp(w, fused=True), C.exp(w, fused=False))
    assert torch.equal(so3.exp(w), C.exp(w, fused=False))


def test_exp_nan_stays_in_its_element_and_batches():
    w = torch.tensor([[0.1, 0.2, 0.3], [float("nan"), 0.0, 0.0], [3.0, -1.0, 0.5]], dtype=F64)
    out = C.exp(w)
    assert bool(out[1].isnan().all())
    torch.testing.assert_close(out[[0, 2]], C.exp(w[[0, 2]]), rtol=0, atol=0)
    batched = C.exp(w[[0, 2]].reshape(2, 1, 3).expand(2, 5, 3))
    assert batched.shape == (2, 5, 3, 3)
    assert torch.equal(batched[:, 3], C.exp(w[[0, 2]]))


def test_exp_under_vmap_equals_batched():
    w, _ = rotvecs(ANGLES, n_random=5, dtype=F64)
    assert torch.equal(torch.func.vmap(C.exp)(w), C.exp(w))


@pytest.mark.compile
def test_exp_compiled_keeps_the_error_free_transforms():
    """Inductor's C++ code must not contract the split products into fused multiply-adds.

    Here the scalar loop that ``torch.compile`` builds by default; ``tests/test_compiled.py``
    checks the vectorised loop that :mod:`torchlie.compiled` builds the same way."""
    w, _ = rotvecs(ANGLES, n_random=20, dtype=F64)
    compiled = torch.compile(C.exp, fullgraph=True)(w)
    torch.testing.assert_close(compiled, C.exp(w), rtol=0, atol=2.5e-16)
    a, b = _hard_doubles(500, 6), _hard_doubles(500, 7)
    p, e = torch.compile(C._two_prod, fullgraph=True)(a, b)
    want = [x * y for x, y in zip(_exact(a), _exact(b), strict=True)]
    assert [x + y for x, y in zip(_exact(p), _exact(e), strict=True)] == want


@pytest.mark.parametrize("scale", [1e3, 1e5, 1e10, 1e30, 1e100])
def test_exp_stays_orthogonal_at_large_angles(scale):
    w = torch.tensor([[0.3, -0.5, 0.8], [1.0, 0.0, 0.0]], dtype=F64) * scale
    R = C.exp(w)
    err = (R @ R.transpose(-1, -2) - torch.eye(3, dtype=F64)).abs().max()
    assert float(err) <= 8 * torch.finfo(F64).eps
