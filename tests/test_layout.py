"""The eager kernels' layout changes (products, column copies, strided stores) equal the copies."""

from __future__ import annotations

import pytest
import torch
from samplers import rotvecs

from torchlie import _autograd, _layout, conversions, quaternion, se3, so3

DTYPES = [torch.float32, torch.float64]
DEFAULT_MIN_ROWS = _layout.MIN_ROWS


def _same_bits(a, b):
    ints = {torch.float32: torch.int32, torch.float64: torch.int64}[a.dtype]
    return torch.equal(a.view(ints), b.view(ints))


@pytest.fixture(autouse=True)
def small_threshold(monkeypatch):
    """Batches of 512 elements or more take the matrix products (the tests' batches are small)."""
    monkeypatch.setattr(_layout, "MIN_ROWS", 512)


def test_default_threshold(monkeypatch):
    """Below a few thousand elements the copies are faster than the extra matrix products."""
    monkeypatch.setattr(_layout, "MIN_ROWS", DEFAULT_MIN_ROWS)
    x = torch.zeros(1)
    assert not _layout._use_product(x, 1000)
    assert _layout._use_product(x, 10_000)


def test_row_products_by_cpu(monkeypatch):
    """Products with results in rows are taken with MKL on an Intel CPU; elsewhere only float32
    ones of 16 columns; unless forced.  The vendor is read from /proc/cpuinfo where there is
    one."""
    monkeypatch.setattr(_layout, "ROW_PRODUCTS", None)
    f32, f64 = torch.float32, torch.float64
    for vendor, mkl, intel in [
        ("GenuineIntel", True, True),
        ("AuthenticAMD", True, False),
        ("GenuineIntel", False, False),
        ("", True, False),
    ]:
        monkeypatch.setattr(_layout, "_cpu_vendor", lambda _v=vendor: _v)
        monkeypatch.setattr(torch.backends.mkl, "is_available", lambda _m=mkl: _m)
        _layout.intel_mkl.cache_clear()
        for dtype, columns in ((f32, 3), (f32, 9), (f32, 16), (f64, 3), (f64, 16)):
            want = intel or (dtype == f32 and columns == 16)
            assert _layout.row_products(dtype, columns) is want, (vendor, mkl, dtype, columns)
            for forced in (True, False):
                with monkeypatch.context() as m:
                    m.setattr(_layout, "ROW_PRODUCTS", forced)
                    assert _layout.row_products(dtype, columns) is forced
    _layout.intel_mkl.cache_clear()
    monkeypatch.undo()
    try:
        with open("/proc/cpuinfo") as f:
            lines = [line for line in f if line.startswith("vendor_id")]
    except OSError:
        lines = []
    if lines:
        assert _layout._cpu_vendor() == lines[0].partition(":")[2].strip()
    assert isinstance(_layout._cpu_vendor(), str)


def test_row_products_from_the_environment():
    """TORCHLIE_ROW_PRODUCTS=1 or 0 forces the choice at import; anything else leaves it to
    the CPU."""
    import os
    import subprocess
    import sys

    code = "from torchlie import _layout; print(_layout.ROW_PRODUCTS)"
    for value, want in (("1", "True"), ("0", "False"), ("", "None"), ("yes", "None")):
        env = dict(os.environ, TORCHLIE_ROW_PRODUCTS=value)
        out = subprocess.run(
            [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
        )
        assert out.stdout.strip() == want, value


@pytest.mark.parametrize("dtype", DTYPES)
def test_planes_and_interleave_are_exact(dtype):
    g = torch.Generator().manual_seed(3)
    x = torch.randn(2, 700, 4, generator=g, dtype=dtype)
    x[0, 5] = torch.tensor([1e-40 if dtype == torch.float64 else 1e-42, 3e38, -2.5, 0.0])
    parts = _layout.planes(x, 4)
    assert all(p.is_contiguous() and p.shape == (2, 700) for p in parts)
    assert torch.equal(torch.stack(parts, -1), x)
    out = _layout.interleave(parts)
    assert out.shape == x.shape and torch.equal(out, x)


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
    assert all(_same_bits(p, c) for p, c in zip(parts, x.unbind(-1), strict=True))
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


def test_product_path_only_where_it_is_exact(monkeypatch):
    x = torch.randn(1000, 4)
    assert _layout._use_product(x, 1000)
    assert not _layout._use_product(x, 10)  # small batch
    assert not _layout._use_product(x.half(), 1000)
    assert _layout._use_product(x.double(), 1000)
    monkeypatch.setattr(torch, "get_float32_matmul_precision", lambda: "medium")
    assert not _layout._use_product(x, 1000)  # reduced-precision float32 products
    assert _layout._use_product(x.double(), 1000)
    assert torch.equal(torch.stack(_layout.planes(x, 4), -1), x)


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
def test_ops_equal_with_copies_only(dtype, monkeypatch):
    """Values and gradients of the ops are bitwise those of the copying layout (the component
    forms of ``quaternion.multiply`` and ``quaternion.to_matrix``: large batches take complex
    arithmetic and matrix products, tested in test_quaternion.py)."""
    monkeypatch.setattr(quaternion, "_large_pair", lambda a, b: False)
    monkeypatch.setattr(quaternion, "_large_matrix", lambda q: False)
    fast = _values_and_grads(_cases(dtype))
    monkeypatch.setattr(_layout, "MIN_ROWS", 10**12)
    slow = _values_and_grads(_cases(dtype))
    for (name, y1, g1), (_, y2, g2) in zip(fast, slow, strict=True):
        assert torch.equal(y1, y2), name
        for a, b in zip(g1, g2, strict=True):
            assert torch.equal(a, b), name


@pytest.mark.parametrize("dtype", DTYPES)
def test_large_batch_kernels_of_the_group_ops_equal_the_matmuls(dtype, rows_calls, monkeypatch):
    """The ops that switch to other kernels on large CPU batches (torchlie._rows for the group
    ops, entry by entry for quaternion.apply) agree with their batched-matmul (and
    cross-product) forms."""
    g = torch.Generator().manual_seed(6)
    xi = torch.randn(3, 400, 6, generator=g, dtype=dtype)
    T, p = se3.exp(xi), torch.randn(3, 400, 3, generator=g, dtype=dtype)
    q = quaternion.from_matrix(T[..., :3, :3])
    cases = [
        (se3.compose, (T, T.flip(1))),
        (se3.compose, (T, T[0, 0])),
        (se3.inverse, (T,)),
        (se3.act, (T, p)),
        (se3.act, (T[0, 0], p)),
        (so3.act, (T[..., :3, :3], p)),
        (so3.act, (T[..., :3, :3], p[0, 0])),
        (quaternion.apply, (q, p)),
        (quaternion.apply, (q[0, 0], p)),
    ]
    large = _values_and_grads(cases)
    # every group op's forward and backward
    assert sorted(set(rows_calls)) == sorted(rows_calls.names)
    assert rows_calls.count("act") == 4 and rows_calls.count("compose") == 2
    monkeypatch.setattr(_layout, "MIN_ROWS", 10**12)
    rows_calls.clear()
    matmuls = _values_and_grads(cases)
    assert not rows_calls
    eps = torch.finfo(dtype).eps
    for (name, y1, g1), (_, y2, g2) in zip(large, matmuls, strict=True):
        # rounding differs: a few eps of the largest input scale (|p| up to ~4 here)
        scale = 4 * eps * y2.abs().max()
        torch.testing.assert_close(y1, y2, rtol=0, atol=scale, msg=name)
        for a, b in zip(g1, g2, strict=True):
            # a broadcast input's gradient is a sum over the batch: a few eps per summand
            summed = T.shape[:-2].numel() // a.shape[:-2].numel()
            torch.testing.assert_close(a, b, rtol=4 * eps, atol=4 * eps * summed, msg=name)


@pytest.mark.parametrize("dtype", DTYPES)
def test_interleave_reads_its_output_columns_and_writes_dest(dtype):
    g = torch.Generator().manual_seed(7)
    x = torch.randn(700, 4, generator=g, dtype=dtype)
    x[5] = torch.tensor(
        [-0.0, float("inf"), float("nan"), 1e-40 if dtype == torch.float64 else 1e-42]
    )
    cols = [c.contiguous() for c in x.unbind(-1)]
    o = _layout.outputs(cols[0], 4)
    assert isinstance(o, _layout.Columns) and o.result.shape == (700, 4)
    assert all(
        c.shape == (700,) and c.data_ptr() == o.result[0, i].data_ptr() for i, c in enumerate(o)
    )
    parts = [torch.mul(c, 1.0, out=p) for c, p in zip(cols[:3], o, strict=False)]
    parts.append(cols[3])  # not written to its column: copied there
    got = _layout.interleave(parts, o)
    assert got is o.result and _same_bits(got, x)  # -0.0, inf and NaN kept as they are
    # columns of dest: the kernel's last operations write the rows of the blocked result
    dest = torch.full((1000, 4), float("nan"), dtype=dtype)
    o = _layout.outputs(cols[0], 4, dest=dest[100:800])
    assert o[0].data_ptr() == dest[100].data_ptr()
    parts = [torch.mul(c, 1.0, out=p) for c, p in zip(cols, o, strict=True)]
    got = _layout.interleave(parts, o, dest[100:800])
    assert got.data_ptr() == dest[100].data_ptr()
    assert _same_bits(dest[100:800], x) and dest[:100].isnan().all() and dest[800:].isnan().all()
    # columns of a new result, then copied to dest
    o = _layout.outputs(cols[0], 4)
    parts = [torch.mul(c, 1.0, out=p) for c, p in zip(cols, o, strict=True)]
    dest = torch.zeros(700, 4, dtype=dtype)
    assert _layout.interleave(parts, o, dest).data_ptr() == dest.data_ptr()
    assert _same_bits(dest, x)
    # no columns: the parts copied into the columns of the result, or of dest
    assert _same_bits(_layout.interleave(cols), x)
    assert _same_bits(_layout.interleave(cols[:2], dest=dest[:700, :2].contiguous()), x[:, :2])


def test_interleave_is_differentiable_where_autograd_records():
    x = torch.randn(700, 3, dtype=torch.float64, requires_grad=True)
    parts = [2.0 * c for c in x.unbind(-1)]
    y = _layout.interleave(parts)
    assert torch.equal(y, 2.0 * x)
    (grad,) = torch.autograd.grad(y, x, torch.arange(2100.0, dtype=x.dtype).view(700, 3))
    assert torch.equal(grad, 2.0 * torch.arange(2100.0, dtype=x.dtype).view(700, 3))


def test_no_output_planes_where_autograd_records():
    x = torch.randn(700)
    assert _layout.outputs(x, 3, x) != (None,) * 3
    y = x.clone().requires_grad_()
    assert _layout.outputs(x, 3, y) == (None,) * 3
    with torch.no_grad():
        assert _layout.outputs(x, 3, y) != (None,) * 3
    with torch.autograd.forward_ad.dual_level():
        assert _layout.outputs(x, 3, x) == (None,) * 3
    assert _layout.outputs(x[:10], 3) == (None,) * 3  # small batch: the copies


@pytest.mark.parametrize("dtype", DTYPES)
def test_blocks_written_in_place_equal_one_pass(dtype, monkeypatch):
    """Large batches, evaluated block by block with each block's result written in its rows
    of the output (forward, and the plain backward), equal one pass over the whole batch."""
    monkeypatch.setattr(_layout, "MIN_ROWS", 64)
    cases = _cases(dtype)
    w = cases[0][1][0]
    T = se3.exp(torch.cat((w.flip(0), w), -1))
    p = torch.randn(w.shape, generator=torch.Generator().manual_seed(8), dtype=dtype)
    q = quaternion.from_rotvec(w)
    cases += [
        (se3.compose, (T, T.flip(0))),
        (se3.inverse, (T,)),
        (se3.act, (T, p)),
        (so3.act, (T[..., :3, :3], p)),
        (quaternion.apply, (q, p)),
    ]

    def second_order(fn, args):  # the backward recorded for a second one: blocks joined
        leaves = [a.clone().requires_grad_() for a in args]
        y = fn(*leaves)
        grads = torch.autograd.grad(y, leaves, torch.ones_like(y), create_graph=True)
        return torch.autograd.grad(sum(g.square().sum() for g in grads), leaves)

    def run():
        with torch.no_grad():
            plain = [fn(*args) for fn, args in cases]
        again = [g for fn, args in cases[-5:] for g in second_order(fn, args)]
        return plain + again, _values_and_grads(cases)

    whole = run()
    monkeypatch.setattr(_autograd, "BLOCK", 256)  # float32 256 rows, float64 128
    blocked = run()
    eps = torch.finfo(dtype).eps
    for a, b in zip(blocked[0], whole[0], strict=True):
        # the same per-element formulas; only a SIMD tail may round differently
        torch.testing.assert_close(a, b, rtol=4 * eps, atol=4 * eps)
    for (name, y1, g1), (_, y2, g2) in zip(blocked[1], whole[1], strict=True):
        torch.testing.assert_close(y1, y2, rtol=4 * eps, atol=4 * eps, msg=name)
        for a, b in zip(g1, g2, strict=True):
            torch.testing.assert_close(a, b, rtol=4 * eps, atol=4 * eps, msg=name)


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
