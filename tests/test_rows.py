"""The large-batch kernels of the group operations (torchlie._rows)."""

from __future__ import annotations

import pytest
import torch

from torchlie import _autograd, _layout, _rows, se3, so3

DTYPES = [torch.float32, torch.float64]


@pytest.fixture(autouse=True)
def small_threshold(monkeypatch):
    """Batches of 512 elements or more are large (the tests' batches are small)."""
    monkeypatch.setattr(_layout, "MIN_ROWS", 512)


def _bits(x):
    ints = {torch.float32: torch.int32, torch.float64: torch.int64}[x.dtype]
    return x.view(ints)


def _poses(n, dtype, seed=0):
    g = torch.Generator().manual_seed(seed)
    xi = torch.randn(n, 6, generator=g, dtype=dtype)
    return se3.exp(xi), se3.exp(xi.flip(0) * 2), torch.randn(n, 3, generator=g, dtype=dtype)


def _cases(A, B, p):
    return [
        (se3.compose, (A, B)),
        (se3.inverse, (A,)),
        (se3.act, (A, p)),
        (so3.act, (A[..., :3, :3].contiguous(), p)),
    ]


def _run(fn, args, upstream=None):
    leaves = [a.clone().requires_grad_() for a in args]
    y = fn(*leaves)
    g = torch.ones_like(y) if upstream is None else upstream
    return y.detach(), torch.autograd.grad(y, leaves, g)


@pytest.mark.parametrize("dtype", DTYPES)
def test_taken_forward_and_backward(dtype, rows_calls):
    A, B, p = _poses(700, dtype)
    for fn, args in _cases(A, B, p):
        _run(fn, args)
    assert rows_calls == [
        "compose",
        "compose_grads",
        "inverse",
        "inverse_grads",
        "act",
        "pose_act_grads",  # se3.act's backward
        "act",
        "act_grads",
    ]
    rows_calls.clear()
    A, B, p = _poses(500, dtype)  # below MIN_ROWS
    for fn, args in _cases(A, B, p):
        _run(fn, args)
    assert rows_calls == []


@pytest.mark.parametrize("dtype", DTYPES)
def test_blocks_equal_one_pass_bit_for_bit(dtype, monkeypatch):
    """The kernels go over blocks of ROWS rows (act: ACT_BLOCKS times as many; a short last
    one here): the same bits as one pass, forward and backward, for a batch of two
    dimensions."""
    A, B, p = _poses(1400, dtype, seed=1)
    A, B, p = A.view(2, 700, 4, 4), B.view(2, 700, 4, 4), p.view(2, 700, 3)
    gen = torch.Generator().manual_seed(2)
    g, h = (torch.randn(2, 700, *s, generator=gen, dtype=dtype) for s in ((4, 4), (3,)))
    ops = [(se3.compose, (A, B), g), (se3.inverse, (A,), g), (se3.act, (A, p), h)]
    ops.append((so3.act, (A[..., :3, :3].contiguous(), p), h))
    monkeypatch.setattr(_rows, "ROWS", 10**9)
    whole = [_run(fn, args, up) for fn, args, up in ops]
    monkeypatch.setattr(_rows, "ROWS", 100)  # float32 100 rows a block, float64 50
    blocked = [_run(fn, args, up) for fn, args, up in ops]
    for (y1, g1), (y2, g2) in zip(blocked, whole, strict=True):
        assert torch.equal(_bits(y1), _bits(y2))
        assert all(torch.equal(_bits(a), _bits(b)) for a, b in zip(g1, g2, strict=True))


@pytest.mark.parametrize("dtype", DTYPES)
def test_blocks_per_thread_equal_one_thread(dtype, monkeypatch):
    """With two intra-op threads the blocks hold twice the rows (one block's worth per thread):
    the same bits as with one, forward and backward."""
    A, B, p = _poses(1400, dtype, seed=11)
    monkeypatch.setattr(_rows, "ROWS", 100)
    monkeypatch.setattr(_autograd, "PASSIVE", False)
    threads = torch.get_num_threads()
    seen = []
    kernel = _rows._compose_planes_kernel

    def spy(A, B, out):
        seen.append(out.shape[0])
        kernel(A, B, out)

    monkeypatch.setattr(_rows, "_compose_planes_kernel", spy)
    try:
        results = []
        for k in (1, 2):
            torch.set_num_threads(k)
            results.append([_run(fn, args) for fn, args in _cases(A, B, p)])
    finally:
        torch.set_num_threads(threads)
    rows = _rows.PLANE_BLOCKS * 100 * 4 // A.element_size()
    assert seen[0] == rows and rows * 2 in seen
    for (y1, g1), (y2, g2) in zip(*results, strict=True):
        assert torch.equal(_bits(y1), _bits(y2))
        assert all(torch.equal(_bits(a), _bits(b)) for a, b in zip(g1, g2, strict=True))


@pytest.mark.parametrize("dtype", DTYPES)
def test_bottom_rows_not_read_and_exact(dtype):
    """Whatever the inputs' bottom rows, and the upstream gradient's, hold: the result's bottom
    row is exactly (0, 0, 0, 1) and the gradients' are zero."""
    A, B, p = _poses(700, dtype, seed=3)
    bad_A, bad_B = A.clone(), B.clone()
    bad_A[..., 3, :] = torch.nan
    bad_B[..., 3, :] = torch.tensor([1.0, -2.0, 3.0, 7.0], dtype=dtype)
    g = torch.randn(700, 4, 4, generator=torch.Generator().manual_seed(4), dtype=dtype)
    bad_g = g.clone()
    bad_g[..., 3, :] = torch.nan
    last = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=dtype)
    for fn, good, bad in (
        (se3.compose, (A, B), (bad_A, bad_B)),
        (se3.inverse, (A,), (bad_A,)),
    ):
        y1, g1 = _run(fn, good, g)
        y2, g2 = _run(fn, bad, bad_g)
        assert torch.equal(y1, y2) and bool((y2[..., 3, :] == last).all())
        for a, b in zip(g1, g2, strict=True):
            assert torch.equal(a, b) and bool((b[..., 3, :] == 0).all())
    y1, g1 = _run(se3.act, (A, p))
    y2, g2 = _run(se3.act, (bad_A, p))
    assert torch.equal(y1, y2) and torch.equal(g1[1], g2[1])
    assert torch.equal(g1[0], g2[0]) and bool((g2[0][..., 3, :] == 0).all())


@pytest.mark.parametrize("dtype", DTYPES)
def test_nan_stays_in_its_element(dtype):
    A, B, p = _poses(700, dtype, seed=5)
    clean = [_run(fn, args) for fn, args in _cases(A, B, p)]
    A2, p2 = A.clone(), p.clone()
    A2[10, 0, 1] = torch.nan  # a rotation entry
    A2[20, 2, 3] = torch.nan  # a translation entry
    p2[30, 1] = torch.nan
    dirty = [_run(fn, args) for fn, args in _cases(A2, B, p2)]
    keep = torch.ones(700, dtype=torch.bool)
    keep[[10, 20, 30]] = False
    for (y1, g1), (y2, g2) in zip(clean, dirty, strict=True):
        assert torch.equal(y1[keep], y2[keep])
        assert all(torch.equal(a[keep], b[keep]) for a, b in zip(g1, g2, strict=True))


@pytest.mark.parametrize("dtype", DTYPES)
def test_strided_inputs(dtype, rows_calls):
    """Slices and column-major poses give what their contiguous copies give."""
    A, B, p = _poses(1400, dtype, seed=6)
    column_major = A[:700].transpose(-1, -2).contiguous().transpose(-1, -2)
    for strided in (A[::2], column_major):
        want = [_run(fn, args) for fn, args in _cases(strided.contiguous(), B[:700], p[::2])]
        got = [_run(fn, args) for fn, args in _cases(strided, B[:700], p[::2])]
        for (y1, g1), (y2, g2) in zip(got, want, strict=True):
            assert torch.equal(y1, y2)
            assert all(torch.equal(a, b) for a, b in zip(g1, g2, strict=True))
    assert "compose" in rows_calls and "inverse" in rows_calls


@pytest.mark.parametrize("dtype", DTYPES)
def test_upstream_gradients_with_any_strides(dtype, rows_calls, monkeypatch):
    """An upstream gradient whose batch dimensions are stored transposed (dense, not
    contiguous) gives the gradients of its contiguous copy, in blocks and at once."""
    A, B, p = _poses(800, dtype, seed=9)
    A, B, p = A.view(20, 40, 4, 4), B.view(20, 40, 4, 4), p.view(20, 40, 3)
    gen = torch.Generator().manual_seed(10)
    for rows in (10**9, 100):
        monkeypatch.setattr(_rows, "ROWS", rows)
        for fn, args in _cases(A, B, p):
            y = fn(*args)
            g = torch.randn(y.shape, generator=gen, dtype=dtype)
            transposed = g.transpose(0, 1).contiguous().transpose(0, 1)
            assert not transposed.is_contiguous()
            _, want = _run(fn, args, g)
            _, got = _run(fn, args, transposed)
            assert all(torch.equal(a, b) for a, b in zip(got, want, strict=True))
    assert sorted(set(rows_calls)) == sorted(rows_calls.names)


@pytest.mark.parametrize("dtype", DTYPES)
def test_not_taken_where_autograd_records(dtype, rows_calls, monkeypatch):
    """Double backward and forward mode take the differentiable batched matmuls (out= is not
    differentiable): their results equal those of small batches of the same elements."""
    A, B, p = _poses(700, dtype, seed=7)
    for fn, args in _cases(A, B, p):
        leaves = [a.clone().requires_grad_() for a in args]
        y = fn(*leaves)
        grads = torch.autograd.grad(y, leaves, torch.ones_like(y), create_graph=True)
        assert all(g.requires_grad for g in grads)
        rows_calls.clear()  # the forward above took them
        second = torch.autograd.grad(sum(g.square().sum() for g in grads), leaves)
        assert rows_calls == []
        with monkeypatch.context() as m:
            m.setattr(_layout, "MIN_ROWS", 10**12)
            leaves_s = [a.clone().requires_grad_() for a in args]
            y_s = fn(*leaves_s)
            grads_s = torch.autograd.grad(y_s, leaves_s, torch.ones_like(y_s), create_graph=True)
            second_s = torch.autograd.grad(sum(g.square().sum() for g in grads_s), leaves_s)
        eps = torch.finfo(dtype).eps
        for a, b in zip(second, second_s, strict=True):
            torch.testing.assert_close(a, b, rtol=8 * eps, atol=8 * eps * 4)
        with torch.autograd.forward_ad.dual_level():
            duals = [torch.autograd.forward_ad.make_dual(a, torch.ones_like(a)) for a in args]
            out = torch.autograd.forward_ad.unpack_dual(fn(*duals))
        assert rows_calls == []
        torch.testing.assert_close(out.primal, fn(*args), rtol=0, atol=8 * eps * 4)


def test_inverse_only_at_full_float32_matmul_precision(rows_calls, monkeypatch):
    A, _, _ = _poses(700, torch.float32, seed=8)
    want = se3.inverse(A)
    assert rows_calls == ["inverse"]
    monkeypatch.setattr(torch, "get_float32_matmul_precision", lambda: "medium")
    rows_calls.clear()
    got = se3.inverse(A)
    assert rows_calls == []
    torch.testing.assert_close(got, want, rtol=0, atol=4 * torch.finfo(torch.float32).eps * 8)
    assert se3.compose(A, A).shape == A.shape and rows_calls == ["compose"]  # no product there


@pytest.mark.parametrize("dtype", DTYPES)
def test_planes_equal_rows(dtype, monkeypatch):
    """se3.compose and its backward, and the backward of se3.inverse, split operands of one
    batch shape into planes where matrix products are exact: the bits of the kernels over rows
    on finite poses; a broadcast batch, and reduced-precision float32 products, take the
    kernels over rows."""
    A, B, _ = _poses(1400, dtype, seed=12)
    A, B = A.view(2, 700, 4, 4), B.view(2, 700, 4, 4)
    G = torch.randn(2, 700, 4, 4, generator=torch.Generator().manual_seed(13), dtype=dtype)
    monkeypatch.setattr(_rows, "ROWS", 100)
    seen = []
    planes = ("_compose_planes_kernel", "_compose_grads_planes_kernel")
    planes += ("_inverse_grads_planes_kernel",)
    for name in planes + ("_compose_kernel", "_inverse_grads_kernel"):
        kernel = getattr(_rows, name)
        spy = lambda *args, _n=name, _k=kernel: seen.append(_n) or _k(*args)  # noqa: E731
        monkeypatch.setattr(_rows, name, spy)
    cases = [(se3.compose, (A, B)), (se3.inverse, (A,))]
    fast = [_run(fn, args, G) for fn, args in cases]
    assert set(seen) == set(planes)
    with monkeypatch.context() as m:
        m.setattr(_rows, "planes_taken", lambda *operands: False)
        rows = [_run(fn, args, G) for fn, args in cases]
    for (y1, g1), (y2, g2) in zip(fast, rows, strict=True):
        assert torch.equal(_bits(y1), _bits(y2))
        assert all(torch.equal(_bits(a), _bits(b)) for a, b in zip(g1, g2, strict=True))
    seen.clear()
    y3, _ = _run(se3.compose, (A, B[0]), G)  # B broadcast over the first dimension
    assert "_compose_kernel" in seen and "_compose_planes_kernel" not in seen
    assert torch.equal(y3[0], fast[0][0][0])
    if dtype == torch.float32:
        seen.clear()
        monkeypatch.setattr(torch, "get_float32_matmul_precision", lambda: "medium")
        for fn, args in cases:
            _run(fn, args, G)
        assert seen == ["_compose_kernel"] * 14 + ["_inverse_grads_kernel"] * 14


def test_blocks_by_cpu(monkeypatch):
    """act and se3.inverse go over blocks as measured on an Intel Xeon there, four times as
    large elsewhere; the bits do not depend on the blocks."""
    monkeypatch.setattr(_layout, "ROW_PRODUCTS", False)  # the same kernels in both runs
    monkeypatch.setattr(_layout, "intel_mkl", lambda: True)
    assert _rows._blocks(_rows.ACT_BLOCKS) == _rows.ACT_BLOCKS and _rows._blocks(1) == 1
    A, B, p = _poses(1400, torch.float64, seed=31)
    monkeypatch.setattr(_rows, "ROWS", 50)
    on_intel = [_run(fn, args) for fn, args in _cases(A, B, p)]
    monkeypatch.setattr(_layout, "intel_mkl", lambda: False)
    assert _rows._blocks(_rows.ACT_BLOCKS) == _rows.OTHER_CPU_BLOCKS * _rows.ACT_BLOCKS
    elsewhere = [_run(fn, args) for fn, args in _cases(A, B, p)]
    for (y1, g1), (y2, g2) in zip(on_intel, elsewhere, strict=True):
        assert torch.equal(_bits(y1), _bits(y2))
        assert all(torch.equal(_bits(a), _bits(b)) for a, b in zip(g1, g2, strict=True))


@pytest.mark.parametrize("dtype", DTYPES)
def test_results_by_copies_equal_the_products(dtype, monkeypatch):
    """Where products with results in rows are slow (torchlie._layout.row_products), se3.compose,
    se3.inverse and their backward passes write their results by copies: the bits of the exact
    products on finite poses, over planes and over rows alike, and a -0.0 stays -0.0."""
    A, B, _ = _poses(1400, dtype, seed=21)
    A, B = A.view(2, 700, 4, 4), B.view(2, 700, 4, 4)
    G = torch.randn(2, 700, 4, 4, generator=torch.Generator().manual_seed(22), dtype=dtype)
    monkeypatch.setattr(_rows, "ROWS", 100)
    copies = []
    kernel = _rows._copy_planes
    spy = lambda *args: copies.append(args[2]) or kernel(*args)  # noqa: E731
    monkeypatch.setattr(_rows, "_copy_planes", spy)
    cases = [(se3.compose, (A, B)), (se3.inverse, (A,))]
    for planes in (True, False):
        if not planes:
            monkeypatch.setattr(_rows, "planes_taken", lambda *operands: False)
        monkeypatch.setattr(_layout, "ROW_PRODUCTS", True)
        products = [_run(fn, args, G) for fn, args in cases]
        assert copies == []
        monkeypatch.setattr(_layout, "ROW_PRODUCTS", False)
        copied = [_run(fn, args, G) for fn, args in cases]
        assert set(copies) == ({"top", "inverse_grads"} if planes else set())
        copies.clear()
        for (y1, g1), (y2, g2) in zip(products, copied, strict=True):
            assert torch.equal(_bits(y1), _bits(y2))
            assert all(torch.equal(_bits(a), _bits(b)) for a, b in zip(g1, g2, strict=True))
    signed = A.clone()
    signed[0, 3, 0, 1] = -0.0  # the products make it +0.0
    inverse = se3.inverse(signed)
    assert torch.equal(_bits(inverse[0, 3, 1, 0]), _bits(torch.tensor(-0.0, dtype=dtype)))
    with pytest.raises(ValueError, match="no copy form for the map 'transpose'"):
        _rows._copy_planes(torch.zeros(12, 5, dtype=dtype), torch.zeros(5, 4, 4), "transpose")


@pytest.mark.parametrize("dtype", DTYPES)
def test_act_products_forms(dtype, monkeypatch):
    """so3.act (forward and backward) and se3.act's backward, on operands of one batch shape
    with contiguous matrices, take the products forms where products with constant maps are fast
    (torchlie._layout.row_products): the sums of the kernels over rows, each product rounded on its
    own (within an ulp or two of the largest product); a broadcast batch, a rotation block of a
    pose, reduced-precision float32 products and other CPUs take the kernels over rows."""
    A, _, p = _poses(1400, dtype, seed=14)
    A, p = A.view(2, 700, 4, 4), p.view(2, 700, 3) * 5.0
    R = A[..., :3, :3].contiguous()
    h = torch.randn(2, 700, 3, generator=torch.Generator().manual_seed(15), dtype=dtype)
    monkeypatch.setattr(_rows, "ROWS", 100)
    monkeypatch.setattr(_layout, "ROW_PRODUCTS", True)  # whatever this CPU takes
    products = ["_act_products_kernel", "_act_grads_products_kernel"]
    products.append("_pose_act_grads_products_kernel")
    rows = ["_rotate", "_act_grads_kernel", "_pose_act_grads_kernel"]
    seen = []
    for name in products + rows:
        kernel = getattr(_rows, name)
        spy = lambda *args, _n=name, _k=kernel: seen.append(_n) or _k(*args)  # noqa: E731
        monkeypatch.setattr(_rows, name, spy)
    cases = [(so3.act, (R, p)), (se3.act, (A, p))]
    fast = [_run(fn, args, h) for fn, args in cases]
    assert set(products) <= set(seen) and "_act_grads_kernel" not in seen
    assert "_pose_act_grads_kernel" not in seen
    with monkeypatch.context() as m:
        m.setattr(_rows, "products_taken", lambda *operands: False)
        slow = [_run(fn, args, h) for fn, args in cases]
    with monkeypatch.context() as m:
        m.setattr(_layout, "ROW_PRODUCTS", False)
        seen.clear()
        elsewhere = [_run(fn, args, h) for fn, args in cases]
        assert not set(products) & set(seen) and set(rows) <= set(seen)
    for (y1, g1), (y2, g2) in zip(elsewhere, slow, strict=True):
        assert torch.equal(y1, y2)
        assert all(torch.equal(a, b) for a, b in zip(g1, g2, strict=True))
    eps = torch.finfo(dtype).eps
    # |R_ij p_j| <= |p| (~ 10 here), |g_i p_j| and |R_ij g_i| <= |g| |p|
    for (y1, g1), (y2, g2) in zip(fast, slow, strict=True):
        torch.testing.assert_close(y1, y2, rtol=0, atol=2 * eps * 16)
        for a, b in zip(g1, g2, strict=True):
            torch.testing.assert_close(a, b, rtol=0, atol=2 * eps * 16 * 4)
    assert torch.equal(fast[1][1][0], slow[1][1][0])  # g (p, 1)^T: the same products
    assert torch.equal(fast[0][1][0], slow[0][1][0])
    seen.clear()
    for fn, args in [(so3.act, (R, p[0])), (so3.act, (R[0], p))]:
        _run(fn, args, h)
    pose = A.clone().requires_grad_()  # its rotation block: strided, not to be copied by _run
    torch.autograd.grad(so3.act(pose[..., :3, :3], p), pose, h)
    assert seen and not set(products) & set(seen)
    if dtype == torch.float32:
        seen.clear()
        monkeypatch.setattr(torch, "get_float32_matmul_precision", lambda: "medium")
        for fn, args in cases:
            _run(fn, args, h)
        assert not set(products) & set(seen) and "_pose_act_grads_kernel" in seen
