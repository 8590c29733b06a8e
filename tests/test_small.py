"""The small-batch forms equal the component-wise kernels bit for bit, the matrix forms agree
with them to a few ulp, and both are taken only where they are meant to be (small CPU batches,
eager, outside ``torch.func`` transforms)."""

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


def _values_and_grads(fn, *xs):
    leaves = [x.clone().requires_grad_() for x in xs]
    y = fn(*leaves)
    g = torch.randn(y.shape, generator=torch.Generator().manual_seed(8), dtype=y.dtype)
    return y.detach(), torch.autograd.grad(y, leaves, g)


def _pieces(x):
    """``x`` in batches of 1 to 1000 rows (one of two batch dims), each below the bounds."""
    return [x[:1], x[1:3], x[3:20], x[20:32].unflatten(0, (3, 4)), *x[32:].split(1000)]


@pytest.mark.parametrize("dtype", DTYPES)
def test_small_forms_equal_the_component_kernels(dtype, monkeypatch):
    """Every element of the samplers, shuffled, in batches of 1 to 1000 rows (one of two batch
    dims); values and gradients."""
    calls = []
    form = quaternion._small_candidate
    monkeypatch.setattr(quaternion, "_small_candidate", lambda R: calls.append(1) or form(R))
    for fn, x in _ops(dtype):
        x = x[torch.randperm(x.shape[0], generator=torch.Generator().manual_seed(10))]
        pieces = _pieces(x)
        calls.clear()
        small = [_values_and_grads(fn, p) for p in pieces]
        assert len(calls) == len(pieces)
        monkeypatch.setattr(_small, "SMALL_ROWS", 0)
        plain = [_values_and_grads(fn, p) for p in pieces]
        assert len(calls) == len(pieces)
        monkeypatch.setattr(_small, "SMALL_ROWS", 1024)
        for (y1, g1), (y2, g2), p in zip(small, plain, pieces, strict=True):
            assert torch.equal(y1, y2), (fn.__name__, p.shape)
            assert torch.equal(g1[0], g2[0]), (fn.__name__, p.shape)


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


# ----------------------------------------------------------------------------------------------
# Matrix forms
# ----------------------------------------------------------------------------------------------

MATRIX_FORMS = ("multiply", "to_matrix", "exp_float32")


def _counted(monkeypatch):
    """Calls of each matrix form, by name."""
    calls = {name: 0 for name in MATRIX_FORMS}

    def wrap(name):
        form = getattr(_small, name)

        def counted(*args):
            calls[name] += 1
            return form(*args)

        return counted

    for name in MATRIX_FORMS:
        monkeypatch.setattr(_small, name, wrap(name))
    return calls


def _sampled(dtype):
    """Rotation vectors at 0, tiny angles, pi, just below pi and beyond; quaternions of them,
    scaled (to_matrix does not see the scale) and shuffled against each other."""
    w, _ = rotvecs(dtype=dtype)
    w = torch.cat((w, 7.0 * w[-300:]))
    g = torch.Generator().manual_seed(11)
    q = quaternion.from_rotvec(w) * torch.exp(torch.randn(w.shape[0], 1, generator=g, dtype=dtype))
    p = q[torch.randperm(q.shape[0], generator=g)]
    return w, q, p


def _norm_error(a, b, nd):
    """Norm-wise difference per element, relative to ``b``'s norm."""
    dims = tuple(range(-nd, 0))
    return (a.double() - b.double()).square().sum(dims).sqrt() / b.double().square().sum(
        dims
    ).sqrt()


def _matrix_form_ops(dtype):
    """(name of the form, op, inputs, trailing dims of the result)"""
    w, q, p = _sampled(dtype)
    ops = [
        ("multiply", quaternion.multiply, (q, p), 1),
        ("multiply", quaternion.multiply, (q, p[5]), 1),  # batch shapes broadcast
        ("to_matrix", quaternion.to_matrix, (q,), 2),
    ]
    if dtype == torch.float32:
        ops += [
            ("exp_float32", so3.exp, (w,), 2),
            ("exp_float32", lambda v: se3.exp(torch.cat((v, v), -1)), (w,), 2),
        ]
    return ops


@pytest.mark.parametrize("dtype", DTYPES)
def test_matrix_forms_agree_with_the_component_kernels(dtype, monkeypatch):
    """Norm-wise within 3 eps of the component kernels (each is within about 1.5 eps of the
    exact value, test_precision.py), 2 eps for float32 ``so3.exp`` (rounded once from float64),
    every sampler angle, batches of 1 to 1000 rows; gradients (the same closed-form backwards,
    fed the forms' results where they read the output) within 8 eps of their largest entry."""
    e = torch.finfo(dtype).eps
    for name, fn, args, nd in _matrix_form_ops(dtype):
        calls = _counted(monkeypatch)
        count = len(_pieces(args[0]))
        pieces = list(zip(*(_pieces(a) if a.dim() > 1 else [a] * count for a in args), strict=True))
        formed = [_values_and_grads(fn, *piece) for piece in pieces]
        assert calls[name] == len(pieces), name
        monkeypatch.setattr(_small, "MATRIX_ROWS", 0)
        plain = [_values_and_grads(fn, *piece) for piece in pieces]
        assert calls[name] == len(pieces), name
        monkeypatch.setattr(_small, "MATRIX_ROWS", 1024)
        for (y1, g1), (y2, g2) in zip(formed, plain, strict=True):
            assert y1.shape == y2.shape
            err = _norm_error(y1, y2, nd)
            assert float(err.max()) <= (2 if name == "exp_float32" else 3) * e, name
            for a, b in zip(g1, g2, strict=True):
                assert float((a - b).abs().max()) <= 8 * e * max(1.0, float(b.abs().max())), name


def test_matrix_forms_taken_only_where_meant(monkeypatch):
    """Eager CPU batches below MATRIX_ROWS; not at MATRIX_ROWS, under vmap, while compiling, nor
    for float64 ``so3.exp`` (its compensated kernel)."""
    x = torch.zeros(3)
    assert _small.matrix_form(x, _small.MATRIX_ROWS - 1)
    assert not _small.matrix_form(x, _small.MATRIX_ROWS)
    calls = _counted(monkeypatch)
    g = torch.Generator().manual_seed(12)
    for rows, taken in ((_small.MATRIX_ROWS - 1, 1), (_small.MATRIX_ROWS, 0)):
        q = torch.randn(rows, 4, generator=g)
        quaternion.multiply(q, q)
        quaternion.to_matrix(q)
        so3.exp(q[:, :3])
        so3.exp(q[:, :3].double())
        assert calls == {"multiply": taken, "to_matrix": taken, "exp_float32": taken}
        calls.update(dict.fromkeys(calls, 0))
    q = torch.randn(5, 4, generator=g)
    torch.func.vmap(quaternion.multiply)(q, q)
    torch.func.vmap(quaternion.to_matrix)(q)
    torch.func.vmap(so3.exp)(q[:, :3])
    assert calls == {"multiply": 0, "to_matrix": 0, "exp_float32": 0}
    monkeypatch.setattr(_layout, "_is_compiling", lambda: True)
    assert not _small.matrix_form(x, 1)


def test_matrix_forms_at_the_edges():
    """One element, none, a NaN kept in its element, a zero quaternion (NaN: no rotation),
    angles up to float32's largest (a rotation still)."""
    g = torch.Generator().manual_seed(13)
    q = torch.randn(6, 4, generator=g)
    w = torch.randn(6, 3, generator=g)
    assert torch.equal(quaternion.multiply(q[2], q[3]), quaternion.multiply(q, q[[3]])[2])
    assert torch.equal(quaternion.to_matrix(q[2]), quaternion.to_matrix(q)[2])
    assert torch.equal(so3.exp(w[2]), so3.exp(w)[2])
    assert quaternion.to_matrix(q[:0]).shape == (0, 3, 3) and so3.exp(w[:0]).shape == (0, 3, 3)
    q[2, 1] = float("nan")
    w[2, 1] = float("nan")
    q[4] = 0.0
    for out in (quaternion.multiply(q, q), quaternion.to_matrix(q), so3.exp(w)):
        assert out[2].isnan().all()
        assert out[[0, 1, 3, 5]].isfinite().all()
    assert quaternion.to_matrix(q)[4].isnan().all()
    assert torch.equal(quaternion.multiply(q, q)[4], torch.zeros(4))
    big = torch.tensor([[0.3, 0.5, -0.2]]) * torch.tensor([[1e10], [1e30], [3e38]])
    R = so3.exp(big)
    assert float((R @ R.mT - torch.eye(3)).abs().max()) <= 4 * torch.finfo(torch.float32).eps
    torch.testing.assert_close(R, so3.exp(big.double()).float(), atol=2e-7, rtol=0)
