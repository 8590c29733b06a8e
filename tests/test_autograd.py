"""The call paths of the custom autograd Functions, and the shared input checks.

``CustomFunction.__call__`` skips ``Function.apply`` where it can (plain forward when nothing is
differentiated, the Function's C entry point in reverse and forward mode AD).  These tests pin
that every path gives the same values and derivatives as the public ``Function.apply``, and that
forward-mode AD, ``torch.func`` transforms, double backward and ``torch.compile`` still work.
"""

from __future__ import annotations

import math
import re

import pytest
import torch
from torch.autograd import forward_ad as fwAD

from torchlie import (
    _autograd,
    _checks,
    _hamilton,
    _rotation_matrix,
    _se3_kernels,
    conversions,
    quaternion,
    se3,
    sim3,
    so3,
)

F64 = torch.float64


def _rotvecs(gen: torch.Generator, n: int = 5) -> torch.Tensor:
    w = torch.randn(n, 3, generator=gen, dtype=F64)
    return w * (2.5 / w.norm(dim=-1, keepdim=True)) * torch.rand(n, 1, generator=gen, dtype=F64)


def _twists(gen: torch.Generator, n: int = 5) -> torch.Tensor:
    return torch.cat((torch.randn(n, 3, generator=gen, dtype=F64), _rotvecs(gen, n)), dim=-1)


# Each case: the public op and a float64 input at a generic point (rotations away from 0 and pi,
# a well-conditioned matrix for project).
CASES = {
    "so3.exp": (so3.exp, lambda g: _rotvecs(g)),
    "so3.log": (so3.log, lambda g: so3.exp(_rotvecs(g))),
    "so3.project": (
        so3.project,
        lambda g: so3.exp(_rotvecs(g)) + 0.2 * torch.randn(5, 3, 3, generator=g, dtype=F64),
    ),
    "se3.log": (se3.log, lambda g: se3.exp(_twists(g))),
    "quaternion.from_matrix": (quaternion.from_matrix, lambda g: so3.exp(_rotvecs(g))),
    "quaternion.to_matrix": (
        quaternion.to_matrix,
        lambda g: 1.3 * quaternion.from_rotvec(_rotvecs(g)),
    ),
}


@pytest.fixture(params=list(CASES))
def case(request, gen):
    fn, make = CASES[request.param]
    return fn, make(gen)


def _custom_functions() -> list[_autograd.CustomFunction]:
    found = []
    for module in (so3, quaternion, _hamilton, _rotation_matrix, _se3_kernels):
        found += [v for v in vars(module).values() if isinstance(v, _autograd.CustomFunction)]
    return found


def _public_call(self, *inputs):
    """``CustomFunction.__call__`` through the ``setup_context`` Function that ``torch.func``
    transforms take, always."""
    if torch.compiler.is_compiling():
        return self.compiled.apply(*inputs)
    return self.transform.apply(*inputs)


@pytest.fixture
def public_path(monkeypatch):
    """Route every custom Function through its ``setup_context`` Function."""

    def use():
        monkeypatch.setattr(_autograd.CustomFunction, "__call__", _public_call)

    return use


def _value_and_grad(fn, x: torch.Tensor, seed: int = 0):
    x = x.detach().requires_grad_()
    y = fn(x)
    g = torch.randn(y.shape, generator=torch.Generator().manual_seed(seed), dtype=y.dtype)
    g = g.to(y.device)
    (dx,) = torch.autograd.grad(y, x, g)
    return y.detach(), dx


# ----------------------------------------------------------------------------------------------
# The eager Function and the plain forward against the setup_context Function
# ----------------------------------------------------------------------------------------------


def test_fast_paths_match_function_apply(case, public_path, device):
    fn, x = case
    x = x.to(device)
    y_fast = fn(x)
    y_fast_grad, dx_fast = _value_and_grad(fn, x)
    public_path()
    y_ref = fn(x)
    y_ref_grad, dx_ref = _value_and_grad(fn, x)
    # Same kernels in the same order: bit-for-bit equal.
    assert torch.equal(y_fast, y_ref)
    assert torch.equal(y_fast_grad, y_ref)
    assert torch.equal(dx_fast, dx_ref)


def _graph_nodes(node, depth: int = 4) -> list:
    """``node`` and the autograd nodes up to ``depth`` steps behind it."""
    out = [node]
    if depth > 0:
        for nxt, _ in node.next_functions:
            if nxt is not None:
                out += _graph_nodes(nxt, depth - 1)
    return out


def test_reverse_mode_records_the_custom_backward(case):
    fn, x = case
    y = fn(x.detach().requires_grad_())
    assert y.requires_grad
    names = [type(n).__name__ for n in _graph_nodes(y.grad_fn)]
    assert any("Function" in n and n.endswith("Backward") for n in names), names


def test_no_grad_call_has_no_grad_fn(case, device):
    fn, x = case
    x = x.to(device)
    xg = x.detach().requires_grad_()
    y = fn(x)
    assert y.grad_fn is None and not y.requires_grad
    with torch.no_grad():
        y = fn(xg)
    assert y.grad_fn is None and not y.requires_grad
    with torch.inference_mode():
        y = fn(xg)
    assert y.grad_fn is None and not y.requires_grad
    torch.testing.assert_close(y, fn(x), rtol=0, atol=0)


# ----------------------------------------------------------------------------------------------
# Forward mode, torch.func, double backward
# ----------------------------------------------------------------------------------------------


def _jacobian(fn, x: torch.Tensor) -> torch.Tensor:
    """Reverse-mode Jacobian (autograd, the C entry point), shape ``y.shape + x.shape``."""
    return torch.autograd.functional.jacobian(fn, x)


def _jvp_from_jacobian(J: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    return (J.reshape(-1, t.numel()) @ t.reshape(-1)).reshape(J.shape[: J.dim() - t.dim()])


@pytest.mark.parametrize("grad_mode", [True, False], ids=["grad", "no_grad"])
def test_dual_tensor_gets_its_jvp(case, gen, grad_mode):
    fn, x = case
    t = torch.randn(x.shape, generator=gen, dtype=F64)
    expected = _jvp_from_jacobian(_jacobian(fn, x), t)
    with torch.set_grad_enabled(grad_mode), fwAD.dual_level():
        y, dy = fwAD.unpack_dual(fn(fwAD.make_dual(x, t)))
    assert dy is not None
    torch.testing.assert_close(y, fn(x), rtol=0, atol=0)
    torch.testing.assert_close(dy, expected, rtol=1e-10, atol=1e-12)
    # Central difference along t (float64, h = 1e-6: truncation ~1e-12, rounding ~1e-10).
    h = 1e-6
    fd = (fn(x + h * t) - fn(x - h * t)) / (2 * h)
    torch.testing.assert_close(dy, fd, rtol=1e-7, atol=1e-8)


def test_torch_func_jvp_jacfwd_jacrev(case, gen):
    fn, x = case
    J = _jacobian(fn, x)
    t = torch.randn(x.shape, generator=gen, dtype=F64)
    y, dy = torch.func.jvp(fn, (x,), (t,))
    torch.testing.assert_close(y, fn(x), rtol=0, atol=0)
    torch.testing.assert_close(dy, _jvp_from_jacobian(J, t), rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(torch.func.jacfwd(fn)(x), J, rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(torch.func.jacrev(fn)(x), J, rtol=1e-10, atol=1e-12)


def test_second_derivatives_in_every_mode(case, gen):
    # jacfwd of jacfwd included, where torch differentiates a custom jvp as a constant
    fn, x = case
    x = x[:2]
    c = torch.randn(fn(x).shape, generator=gen, dtype=F64)

    def loss(z):
        return (fn(z) * c).sum()

    H = torch.func.jacrev(torch.func.jacrev(loss))(x)
    for outer, inner in ((torch.func.jacfwd, torch.func.jacfwd), (torch.func.jacfwd,
                         torch.func.jacrev), (torch.func.jacrev, torch.func.jacfwd)):  # fmt: skip
        torch.testing.assert_close(outer(inner(loss))(x), H, rtol=1e-9, atol=1e-10)
    with pytest.raises(NotImplementedError, match=r"order three or more .*\(jacfwd of jacfwd\)"):
        torch.func.jacrev(torch.func.jacfwd(torch.func.jacfwd(loss)))(x)


def test_without_the_private_query_of_transforms_first_derivatives_hold(case, monkeypatch):
    # where torch lacks its list of transforms, nested forward mode takes the Function as
    # elsewhere: first derivatives as always
    fn, x = case
    J = _jacobian(fn, x)
    monkeypatch.setattr(_autograd, "_INTERPRETERS_QUERY", None)
    assert _autograd._derivative_levels() == (0, 0)
    torch.testing.assert_close(torch.func.jacfwd(fn)(x), J, rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(torch.func.jacrev(fn)(x), J, rtol=1e-10, atol=1e-12)


def test_torch_func_vmap_and_grad(case, gen):
    fn, x = case
    torch.testing.assert_close(torch.func.vmap(fn)(x), fn(x), rtol=1e-14, atol=1e-14)
    c = torch.randn(fn(x).shape, generator=gen, dtype=F64)
    dx_func = torch.func.grad(lambda z: (fn(z) * c).sum())(x)
    xg = x.detach().requires_grad_()
    (dx_ref,) = torch.autograd.grad(fn(xg), xg, c)
    torch.testing.assert_close(dx_func, dx_ref, rtol=1e-12, atol=1e-14)
    # Per-element Jacobians: vmap of jacrev against the batched reverse-mode Jacobian.
    J = _jacobian(fn, x)  # (n, *out, n, *in): block diagonal over the batch
    Jb = torch.func.vmap(torch.func.jacrev(fn))(x)
    diag = torch.stack([J[i].select(J.dim() - x.dim() - 1, i) for i in range(x.shape[0])])
    torch.testing.assert_close(Jb, diag, rtol=1e-10, atol=1e-12)


def test_gradcheck_forward_and_double_backward(case):
    fn, x = case
    x = x[:2].detach().requires_grad_()
    assert torch.autograd.gradcheck(fn, (x,), check_forward_ad=True)
    assert torch.autograd.gradgradcheck(fn, (x,))


@pytest.mark.compile
def test_compiled_fullgraph_with_backward():
    """One compile: so3.exp / so3.log (custom Functions), a broadcasting compose and distance,
    backward, at generic rotation vectors and at 0, 1e-9 and pi.

    Traced by Dynamo and AOTAutograd (``aot_eager``: graph breaks, syncs, the custom Functions'
    backward); Inductor's code generation is tested in test_compile.py and test_compiled.py."""
    F32 = torch.float32
    g = torch.Generator().manual_seed(3)
    R0 = so3.exp(_rotvecs(g, 2).to(F32)).reshape(2, 1, 3, 3)
    w0 = _rotvecs(g, 6).to(F32)
    w0[0] = 0.0
    w0[1] = torch.tensor([math.pi, 0.0, 0.0], dtype=F32)
    w0[2] = torch.tensor([1e-9, 0.0, 0.0], dtype=F32)

    def f(R, w):
        S = so3.compose(R, so3.exp(w))  # batch (2, 1) with (6,) -> (2, 6)
        return so3.log(S), so3.distance(S, R)

    w1, w2 = w0.clone().requires_grad_(), w0.clone().requires_grad_()
    y1 = f(R0, w1)
    y2 = torch.compile(f, fullgraph=True, backend="aot_eager")(R0, w2)  # see test_compile.py
    assert y2[0].shape == (2, 6, 3) and y2[1].shape == (2, 6)
    c = [torch.randn(y.shape, generator=g, dtype=F32) for y in y1]
    for a, b in zip(y2, y1, strict=True):
        torch.testing.assert_close(a, b)
    (d1,) = torch.autograd.grad(y1, w1, c)
    (d2,) = torch.autograd.grad(y2, w2, c)
    assert bool(torch.isfinite(d2).all())
    torch.testing.assert_close(d2, d1)


# ----------------------------------------------------------------------------------------------
# _checks
# ----------------------------------------------------------------------------------------------

BROADCAST_CASES = [
    [(), ()],
    [(1,), (1,)],
    [(5,), (5,)],
    [(5,), (1,)],
    [(1,), (5,)],
    [(), (2, 3)],
    [(2, 1), (3,)],
    [(4, 1, 2), (3, 1)],
    [(0,), (1,)],
    [(1, 0), (3, 1)],
    [(2, 1, 1), (1, 3, 1), (4,)],
    [(7,)],
]


@pytest.mark.parametrize("shapes", BROADCAST_CASES, ids=str)
def test_batch_broadcast_matches_torch(shapes):
    named = [(torch.Size(s), f"x{i}") for i, s in enumerate(shapes)]
    out = _checks.batch_broadcast("f", *named)
    assert type(out) is torch.Size
    assert out == torch.broadcast_shapes(*shapes)


@pytest.mark.parametrize(
    "shapes", [[(2,), (3,)], [(0,), (2,)], [(2, 3), (4, 3)], [(1, 2), (3,), (2, 1)]], ids=str
)
def test_batch_broadcast_error_names_function_and_shapes(shapes):
    named = [(torch.Size(s), f"x{i}") for i, s in enumerate(shapes)]
    desc = ", ".join(f"x{i} batch {tuple(s)}" for i, s in enumerate(shapes))
    with pytest.raises(
        ValueError, match="^" + re.escape(f"mod.fn: batch shapes do not broadcast: {desc}") + "$"
    ):
        _checks.batch_broadcast("mod.fn", *named)
    with pytest.raises(RuntimeError):
        torch.broadcast_shapes(*shapes)


def test_batch_broadcast_error_from_an_op():
    R1, R2 = so3.identity(2), so3.identity(4)
    msg = "so3.compose: batch shapes do not broadcast: R1 batch (2,), R2 batch (4,)"
    with pytest.raises(ValueError, match=re.escape(msg)):
        so3.compose(R1, R2)


def test_tensor_check_errors_and_compute_dtype():
    with pytest.raises(
        TypeError, match=re.escape("m.f: expected x to be a torch.Tensor, got list")
    ):
        _checks.tensor([0.0, 0.0, 0.0], "m.f", "x", (3,))
    with pytest.raises(
        TypeError,
        match=re.escape(
            "m.f: expected x to be a floating-point tensor (float16, bfloat16, float32 or "
            "float64), got dtype torch.int64"
        ),
    ):
        _checks.tensor(torch.zeros(3, dtype=torch.int64), "m.f", "x", (3,))
    for shape in [(4, 2), (3, 4), (2, 4, 3), (), (3,), (9,)]:
        x = torch.zeros(shape)
        with pytest.raises(
            ValueError, match=re.escape(f"m.f: expected R of shape (..., 3, 3), got {shape}")
        ):
            _checks.tensor(x, "m.f", "R", (3, 3))
    for shape in [(3, 3), (2, 5, 3, 3)]:
        x = torch.zeros(shape, dtype=F64)
        y, dtype = _checks.tensor(x, "m.f", "R", (3, 3))
        assert y is x and dtype == F64
    for half in (torch.float16, torch.bfloat16):
        y, dtype = _checks.tensor(torch.zeros(2, 3, dtype=half), "m.f", "w", (3,))
        assert y.dtype == torch.float32 and dtype == half
        assert _checks.out(y, dtype).dtype == half
    y, dtype = _checks.tensor(torch.zeros(2), "m.f", "t", ())
    assert y.shape == (2,) and dtype == torch.float32


def test_same_dtype():
    a, b = torch.zeros(3), torch.zeros(3, dtype=F64)
    _checks.same_dtype("m.f", a=a, c=a.clone())
    with pytest.raises(
        TypeError,
        match=re.escape(
            "m.f: expected inputs of one dtype, got a is torch.float32, b is torch.float64"
        ),
    ):
        _checks.same_dtype("m.f", a=a, b=b)


# ----------------------------------------------------------------------------------------------
# Blocked forward passes over large batches
# ----------------------------------------------------------------------------------------------


@pytest.fixture
def small_blocks(monkeypatch):
    """Blocks of 16 rows: every batch of 32 or more elements is evaluated block by block."""
    monkeypatch.setattr(_autograd, "BLOCK", 16)


def _blocked_cases(dtype):
    g = torch.Generator().manual_seed(40)
    w = torch.randn(5, 23, 3, generator=g, dtype=dtype) * 2
    xi = torch.randn(5, 23, 6, generator=g, dtype=dtype)
    R, T = so3.exp(w), se3.exp(xi)
    p = torch.randn(5, 23, 3, generator=g, dtype=dtype)
    return [
        (so3.exp, (w,)),
        (so3.log, (R,)),
        (so3.project, (R + 0.01,)),
        (se3.exp, (xi,)),
        (se3.log, (T,)),
        (se3.compose, (T, T.flip(0))),
        (se3.inverse, (T,)),
        (se3.act, (T, p)),
        (se3.act, (T[:, :1], p)),  # broadcast: not blocked
        (quaternion.to_matrix, (quaternion.from_rotvec(w),)),
        (quaternion.from_matrix, (R,)),
    ]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_blocked_forward_equals_unblocked(dtype, monkeypatch):
    want = [fn(*args) for fn, args in _blocked_cases(dtype)]
    monkeypatch.setattr(_autograd, "BLOCK", 16)
    got = [fn(*args) for fn, args in _blocked_cases(dtype)]
    eps = torch.finfo(dtype).eps
    for a, b in zip(got, want, strict=True):
        assert a.shape == b.shape
        # the same per-element formulas; only a SIMD tail may round differently
        torch.testing.assert_close(a, b, rtol=4 * eps, atol=4 * eps)


@pytest.mark.parametrize("threads", [1, 2])
def test_blocked_equals_the_whole_batch(threads):
    """The driver's result is the function's on the whole batch, for one result or a tuple, in
    every dtype and thread count; each row is evaluated once; small batches, broadcast batches
    and other devices are evaluated whole."""
    calls = []

    def fwd(a, b):
        calls.append(a.shape[0])
        return a * 2.0 + b.unsqueeze(-1), a.sum(-1)

    run = _autograd.blocked(fwd, (1, 0))
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(threads)
        for dtype in (torch.float32, torch.float64):
            n = 4 * _autograd.BLOCK * threads + 5
            a, b = torch.randn(n, 3, dtype=dtype), torch.randn(n, dtype=dtype)
            for args in ((a, b), (a[:100], b[:100]), (a, b[:1]), (a.to("meta"), b.to("meta"))):
                calls.clear()
                got, want = run(*args), fwd(*args)
                if args[0].device.type != "meta":
                    assert all(torch.equal(x, y) for x, y in zip(got, want, strict=True))
                assert sum(calls[:-1]) == args[0].shape[0]  # the last call: fwd above
    finally:
        torch.set_num_threads(before)


@pytest.mark.parametrize("swap", ["last", "all but the first"])
def test_blocked_results_in_buffers_of_the_driver(small_blocks, swap):
    """Results allocated by ``result_buffer`` land in their rows even where a block allocates
    them in another order than the first block (another path of the kernel), and a temporary
    allocated there does not spoil them."""

    sizes = []

    def fwd(a):
        rows = a.shape[0]
        sizes.append(rows)
        x = _autograd.result_buffer((rows, 3), a)
        y = _autograd.result_buffer((rows, 3), a)
        t = _autograd.result_buffer((rows, 3), a)  # a temporary
        other = rows != sizes[0] if swap == "last" else bool(a[0, 0] != first[0, 0])
        if other:
            x, y = y, x
        torch.mul(a, 2.0, out=t)
        torch.add(t, 1.0, out=x)
        torch.sub(a, t, out=y)
        return x, y, t.sum(-1)

    a = torch.randn(16 * 5 + 7, 3, dtype=torch.float64)
    first = a[:1]
    got = _autograd.blocked(fwd, (1,))(a)
    want = (2.0 * a + 1.0, a - 2.0 * a, (2.0 * a).sum(-1))
    for x, y in zip(got, want, strict=True):
        assert torch.equal(x, y)


def test_blocked_plain_backward_equals_unblocked(monkeypatch):
    g = torch.Generator().manual_seed(41)
    q = (1.3 * torch.randn(5, 23, 4, generator=g, dtype=F64)).requires_grad_()
    G = torch.randn(5, 23, 3, 3, generator=g, dtype=F64)
    (want,) = torch.autograd.grad(quaternion.to_matrix(q), q, G)
    monkeypatch.setattr(_autograd, "BLOCK", 16)
    (got,) = torch.autograd.grad(quaternion.to_matrix(q), q, G)
    eps = torch.finfo(F64).eps
    torch.testing.assert_close(got, want, rtol=4 * eps, atol=4 * eps)


def test_blocked_forward_with_grad_and_under_vmap(small_blocks):
    w = (0.5 * torch.randn(4, 20, 3, dtype=torch.float64)).requires_grad_()  # |w| < pi
    (g,) = torch.autograd.grad(so3.log(so3.exp(w)).sum(), w)
    torch.testing.assert_close(g, torch.ones_like(w), rtol=0, atol=1e-12)
    torch.testing.assert_close(torch.func.vmap(so3.exp)(w.detach()), so3.exp(w.detach()))


def test_without_the_private_queries_every_mode_still_works(case, monkeypatch):
    """Where torch lacks the private query of active transforms and the forward-mode level,
    :mod:`torchlie._autograd` assumes both active: every call then goes through the
    ``setup_context`` Function, with the same values, gradients and tangents."""
    fn, x = case
    y, dx = _value_and_grad(fn, x)
    with fwAD.dual_level():
        tangent = fwAD.unpack_dual(fn(fwAD.make_dual(x, torch.ones_like(x)))).tangent
    monkeypatch.setattr(_autograd, "_TRANSFORMS_QUERY", None)
    monkeypatch.setattr(_autograd, "_forward_ad", object())  # no level to read
    assert _autograd.transforms_active() and _autograd.forward_ad_active()
    assert torch.equal(fn(x), y)
    y2, dx2 = _value_and_grad(fn, x)
    assert torch.equal(y2, y) and torch.equal(dx2, dx)
    torch.testing.assert_close(torch.func.jvp(fn, (x,), (torch.ones_like(x),))[1], tangent)


def test_first_call_under_a_transform_or_inference_mode_leaves_the_ops_usable():
    """Ops that build shared constants on first use (the angle's pi, the matrix kernels' rows)
    keep none of the mode of that first call: in a fresh process, a first call under
    ``torch.func.hessian`` or ``torch.inference_mode`` leaves ``jacrev``, ``jacfwd`` and backward
    working."""
    import subprocess
    import sys
    import textwrap

    script = textwrap.dedent(
        """
        import sys
        import torch
        from torch.func import hessian, jacfwd, jacrev
        from torchlie import conversions, se3, so3

        fns = [
            lambda v: conversions.quaternion_to_euler(v, "xyz").sum(),
            lambda v: so3.distance(so3.exp(v[:3]), so3.exp(v[1:])).sum(),
            lambda v: se3.exp(torch.cat([v, v[:2]])).sum(),
        ]
        q = torch.tensor([0.5, 0.5, 0.5, 0.5], dtype=torch.float64)
        for f in fns:
            if sys.argv[1] == "hessian":
                hessian(f)(q)
            else:
                with torch.inference_mode():
                    f(q)
        for f in fns:
            jacrev(f)(q), jacfwd(f)(q)
            x = q.clone().requires_grad_()
            f(x).backward()
            assert bool(x.grad.isfinite().all())
        """
    )
    for first in ("hessian", "inference_mode"):
        run = subprocess.run(
            [sys.executable, "-c", script, first], capture_output=True, text=True, timeout=300
        )
        assert run.returncode == 0, (first, run.stderr[-2000:])


# ----------------------------------------------------------------------------------------------
# Second derivatives in the raw matrix entries
# ----------------------------------------------------------------------------------------------


def _polar(M: torch.Tensor) -> torch.Tensor:
    """The nearest rotation, differentiably (Newton's iteration ``X <- (X + X^-T) / 2``)."""
    X = M
    for _ in range(8):
        X = 0.5 * (X + torch.linalg.inv(X).mT)
    return X


def _project_pose(T: torch.Tensor, scaled: bool) -> torch.Tensor:
    """``[[s polar(M), t], [0, 1]]`` of a pose's top block, ``s = |M|_F / sqrt(3)`` (Sim(3)) or
    1: the element whose log the backward of ``se3.log`` / ``sim3.log`` differentiates."""
    M = T[:3, :3]
    s = M.square().sum().div(3.0).sqrt() if scaled else 1.0
    top = torch.cat((s * _polar(M), T[:3, 3:]), dim=-1)
    return torch.cat((top, T[3:]), dim=-2)


_RAW_MATRIX_CASES = {
    "so3.log": (so3.log, _polar, 3),
    "quaternion.from_matrix": (quaternion.from_matrix, _polar, 3),
    "matrix_to_euler": (lambda R: conversions.matrix_to_euler(R, "zyx"), _polar, 3),
    "se3.log": (se3.log, lambda T: _project_pose(T, False), 4),
    "sim3.log": (sim3.log, lambda T: _project_pose(T, True), 4),
}


@pytest.mark.parametrize("name", list(_RAW_MATRIX_CASES))
def test_second_derivatives_in_raw_matrix_entries(name):
    # The backward is the gradient of f o polar near SO(3) (docs/gradients.md), so its
    # derivative in all 9 (or 12) entries, normal directions R S included, is the Hessian of
    # f o polar: symmetric, whichever mode takes it, at exact rotations too.
    fn, project, n = _RAW_MATRIX_CASES[name]
    rotations = [
        torch.eye(3, dtype=F64),
        torch.tensor([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]], dtype=F64),  # 90 degrees about x
        so3.exp(torch.tensor([0.3, -1.2, 2.0], dtype=F64)),
    ]
    gen = torch.Generator().manual_seed(3)
    for R in rotations:
        X = R
        if n == 4:
            scale = 2.0 if name == "sim3.log" else 1.0
            t = torch.tensor([[0.0], [-2.0], [1.0]], dtype=F64)
            X = torch.cat((torch.cat((scale * R, t), -1), torch.eye(4, dtype=F64)[3:]), -2)
        v = torch.randn(fn(X).shape, dtype=F64, generator=gen)

        def loss(M, f=fn, v=v):
            return (f(M) * v).sum()

        ref = torch.func.hessian(lambda M, f=loss, p=project: f(p(M)))(X)
        for mode in (torch.func.jacrev, torch.func.jacfwd):
            H = mode(torch.func.jacrev(loss))(X)
            torch.testing.assert_close(H, ref, rtol=1e-9, atol=1e-9, msg=f"{name} {mode}")
        H = torch.func.jacfwd(torch.func.jacfwd(loss))(X)
        torch.testing.assert_close(H, ref, rtol=1e-9, atol=1e-9, msg=f"{name} jacfwd twice")
