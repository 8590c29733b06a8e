"""The small-batch forms equal the component-wise kernels bit for bit, and are taken only where
they are meant to be (small CPU batches, eager, outside ``torch.func`` transforms)."""

from __future__ import annotations

import pytest
import torch
from samplers import rotvecs

from torchlie import _layout, _small, quaternion, se3, so3

DTYPES = [torch.float32, torch.float64]


def _ops(dtype):
    """Ops with a small-batch form, on inputs at 0, tiny angles, pi and just below pi."""
    w, _ = rotvecs(dtype=dtype)
    g = torch.Generator().manual_seed(7)
    xi = torch.cat((torch.randn(w.shape[0], 3, generator=g, dtype=dtype), w), -1)
    R = so3.exp(w)
    # a perturbed copy: the orthogonalisation step and the pivot see non-rotations too
    Rp = R + 1e-3 * torch.randn(R.shape, generator=g, dtype=dtype)
    return [
        (quaternion.from_matrix, R),
        (quaternion.from_matrix, Rp),
        (so3.log, R),
        (so3.log, Rp),
        (se3.log, se3.exp(xi)),
    ]


def _values_and_grads(fn, x):
    leaf = x.clone().requires_grad_()
    y = fn(leaf)
    g = torch.randn(y.shape, generator=torch.Generator().manual_seed(8), dtype=y.dtype)
    return y.detach(), torch.autograd.grad(y, leaf, g)[0]


@pytest.mark.parametrize("dtype", DTYPES)
def test_small_forms_equal_the_component_kernels(dtype, monkeypatch):
    """Every element of the samplers, shuffled, in batches of 1 to 1000 rows (one of two batch
    dims); values and gradients."""
    calls = []
    form = quaternion._small_candidate
    monkeypatch.setattr(quaternion, "_small_candidate", lambda R: calls.append(1) or form(R))
    for fn, x in _ops(dtype):
        x = x[torch.randperm(x.shape[0], generator=torch.Generator().manual_seed(10))]
        pieces = [x[:1], x[1:3], x[3:20], x[20:32].unflatten(0, (3, 4)), *x[32:].split(1000)]
        calls.clear()
        small = [_values_and_grads(fn, p) for p in pieces]
        assert len(calls) == len(pieces)
        monkeypatch.setattr(_small, "SMALL_ROWS", 0)
        plain = [_values_and_grads(fn, p) for p in pieces]
        assert len(calls) == len(pieces)
        monkeypatch.setattr(_small, "SMALL_ROWS", 1024)
        for (y1, g1), (y2, g2), p in zip(small, plain, pieces, strict=True):
            assert torch.equal(y1, y2), (fn.__name__, p.shape)
            assert torch.equal(g1, g2), (fn.__name__, p.shape)


@pytest.mark.parametrize("fn", [quaternion.from_matrix, so3.log])
def test_small_forms_of_one_element_and_of_none(fn):
    R = so3.exp(torch.tensor([0.3, -2.0, 1.0], dtype=torch.float64))
    one = fn(R)
    assert torch.equal(one, fn(R.unsqueeze(0))[0])
    empty = fn(R.expand(0, 3, 3))
    assert empty.shape == (0,) + one.shape


def test_at_pi_the_canonical_representative():
    """``w = 0``: the largest vector component positive (quaternion module docstring)."""
    for dtype in DTYPES:
        R = torch.diag(torch.tensor([-1.0, 1.0, -1.0], dtype=dtype))  # pi about y
        assert torch.equal(quaternion.from_matrix(R), torch.tensor([0, 0, 1.0, 0], dtype=dtype))
        assert torch.equal(so3.log(R), torch.tensor([0, torch.pi, 0], dtype=dtype))


def test_nan_stays_in_its_element():
    R = so3.exp(torch.randn(6, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(9)))
    R[2, 1, 0] = float("nan")
    for fn in (quaternion.from_matrix, so3.log):
        out = fn(R)
        assert out[2].isnan().all()
        assert torch.equal(out[[0, 1, 3, 4, 5]], fn(R[[0, 1, 3, 4, 5]]))


def test_taken_only_where_meant(monkeypatch):
    x = torch.zeros(3)
    assert _small.enabled(x, 1) and _small.enabled(x, _small.SMALL_ROWS - 1)
    assert not _small.enabled(x, _small.SMALL_ROWS)
    assert not _small.enabled(torch.zeros(3, device="meta"), 1)
    seen = []
    torch.func.vmap(lambda y: seen.append(_small.enabled(y, 1)) or y)(torch.zeros(2, 3))
    assert seen == [False]
    monkeypatch.setattr(_layout, "_is_compiling", lambda: True)
    assert not _small.enabled(x, 1)
