"""torchlie.compiled: the same results and gradients as the eager API, compiled fullgraph."""

from __future__ import annotations

import math
import re

import pytest
import torch
from samplers import ANGLES, rotvecs
from torch._inductor.utils import run_and_get_code

from torchlie import compiled, conversions, quaternion, se3, so3

pytestmark = pytest.mark.compile


def test_compiled_mirrors_the_eager_api():
    # the same formula, multiply-adds rounded once in eager and twice in Inductor's loops
    # (see test_compiled_values_within_8_ulp_of_eager): within 4 ulp of the largest entry
    w, _ = rotvecs(ANGLES, n_random=20, dtype=torch.float64)
    R = so3.exp(w)
    eps = torch.finfo(torch.float64).eps
    torch.testing.assert_close(compiled.so3.exp(w), R, rtol=0, atol=4 * eps)
    q = torch.randn(7, 4, dtype=torch.float64)
    torch.testing.assert_close(
        compiled.quaternion.to_matrix(q), quaternion.to_matrix(q), rtol=0, atol=1e-15
    )
    a = torch.randn(7, 3, dtype=torch.float64)
    torch.testing.assert_close(
        compiled.conversions.euler_to_matrix(a, "ZYX"),
        conversions.euler_to_matrix(a, "ZYX"),
        rtol=0,
        atol=1e-15,
    )
    xi = torch.randn(7, 6)
    torch.testing.assert_close(compiled.se3.exp(xi), se3.exp(xi), rtol=0, atol=1e-6)
    # compiled once, then kept on the namespace
    assert compiled.so3.exp is compiled.so3.exp
    assert compiled.so3.exp.__name__ == "exp" and compiled.so3.exp.__doc__ == so3.exp.__doc__


def _agreement_cases(dtype):
    w, angle = rotvecs(ANGLES, n_random=20, dtype=torch.float64)
    g = torch.Generator().manual_seed(0)
    q, p, rho = (torch.randn(len(w), k, generator=g, dtype=torch.float64) for k in (4, 3, 3))
    w, q, p, xi = (x.to(dtype) for x in (w, q, p, torch.cat((rho, w), -1)))
    # within rounding of pi the log's axis sign is decided by rounding: both signs are right
    unique = angle < math.pi - 1e-3
    return [
        ("so3", "exp", (w,)),
        ("so3", "log", (so3.exp(w[unique]),)),
        ("quaternion", "multiply", (q, q.flip(0))),
        ("quaternion", "apply", (q, p)),
        ("se3", "exp", (xi,)),
        ("se3", "log", (se3.exp(xi[unique]),)),
        ("so3", "act", (so3.exp(w), p)),
        ("se3", "act", (se3.exp(xi), p)),
    ]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=str)
def test_compiled_values_within_8_ulp_of_eager(dtype):
    # Not bit for bit: eager CPU multiply-adds (torch.addcmul) round once, Inductor's CPU loops
    # round the product and the sum separately (its C++ backend has no fused multiply-add), and
    # the two evaluate sin, cos and atan with different vector routines.  The same formula
    # otherwise: each entry within 8 ulp of max(1, |entry|) of eager's.
    eps = torch.finfo(dtype).eps
    for module, name, args in _agreement_cases(dtype):
        eager = getattr(globals()[module], name)(*args)
        torch._dynamo.reset()
        got = getattr(getattr(compiled, module), name)(*args)
        err = ((got - eager).abs() / eager.abs().clamp_min(1.0)).max().item()
        assert err <= 8 * eps, (module, name, err / eps)


def test_compiled_gradients_and_errors():
    w = torch.randn(5, 3, requires_grad=True)
    (g_eager,) = torch.autograd.grad(so3.log(so3.exp(w) @ so3.exp(w)).sum(), w)
    (g_comp,) = torch.autograd.grad(
        compiled.so3.log(compiled.so3.exp(w) @ compiled.so3.exp(w)).sum(), w
    )
    torch.testing.assert_close(g_comp, g_eager, rtol=1e-5, atol=1e-5)
    with pytest.raises(ValueError, match=r"torchlie\.so3\.exp: expected omega of shape"):
        compiled.so3.exp(torch.zeros(2, 4))
    with pytest.raises(AttributeError, match="has no function '_exp'"):
        compiled.so3._exp  # noqa: B018
    assert compiled.so3.random is so3.random
    assert set(dir(compiled.so3)) == set(so3.__all__)


def test_inductor_options():
    vectorised = {**compiled.FUSION, "cpp.enable_tiling_heuristics": False}
    assert compiled.FUSION["aggressive_fusion"] is True
    assert compiled.FUSION["score_fusion_memory_threshold"] == 0
    assert compiled.FUSION["realize_opcount_threshold"] == 25
    assert compiled.inductor_options("so3", "exp") == vectorised
    assert compiled.inductor_options("se3", "log") == vectorised
    assert compiled.inductor_options("conversions", "matrix_to_euler") == vectorised
    assert compiled.inductor_options("se3", "compose") == vectorised
    with pytest.raises(ValueError, match=r"inductor_options: expected module to be one of"):
        compiled.inductor_options("so2", "exp")
    with pytest.raises(ValueError, match=r"torchlie\.so3 has no public function '_exp'"):
        compiled.inductor_options("so3", "_exp")


def _batch_loops(fn, *args, options):
    """The outputs of ``fn`` compiled with ``options`` and the number of loops over the batch in
    the C++ code Inductor generated for it (each a pass over the result's memory)."""
    torch._dynamo.reset()
    out, code = run_and_get_code(torch.compile(fn, fullgraph=True, options=options), *args)
    return out, sum(_loops(c) for c in code), code


def _loops(code: str) -> int:
    """Loops over the batch (the outermost index ``x0``) in one generated C++ module."""
    return len(re.findall(r"for\s*\(\s*int64_t x0\s*=", code))


def _batch_steps(code: str) -> list[int]:
    """How many elements each loop over the batch advances by (the vector width where the loop
    is vectorised along the batch, 1 where it is not)."""
    loop = r"for\s*\(\s*int64_t x0\s*=[^;]*;[^;]*;\s*x0\s*\+=\s*static_cast<int64_t>\((\d+)L\)"
    return [int(step) for step in re.findall(loop, code)]


@pytest.mark.parametrize("module", ["so3", "se3"])
def test_compiled_actions_are_vectorised_along_the_batch(module):
    # Written entry by entry while compiling: a broadcast over (..., 3) vectors would be
    # vectorised along the 3 (masked loads, several times slower than eager).
    torch._dynamo.reset()
    _, probe = run_and_get_code(torch.compile(lambda x: 2.0 * x), torch.randn(1000))
    if max(_batch_steps("".join(probe)), default=1) == 1:
        pytest.skip("Inductor does not vectorise on this CPU")
    mod = {"so3": so3, "se3": se3}[module]
    g = torch.Generator().manual_seed(43)
    X, p = mod.random(1000, generator=g), torch.randn(1000, 3, generator=g)
    out, loops, code = _batch_loops(mod.act, X, p, options=compiled.inductor_options(module, "act"))
    assert loops == 1
    assert min(_batch_steps("".join(code))) > 1
    torch.testing.assert_close(out, mod.act(X, p), rtol=0, atol=1e-5)


@pytest.mark.parametrize(
    "name, make",
    [
        ("exp", lambda g: (torch.randn(37, 6, generator=g),)),
        ("compose", lambda g: (se3.random(37, generator=g), se3.random(37, generator=g))),
        ("inverse", lambda g: (se3.random(37, generator=g),)),
    ],
)
def test_compiled_pose_ops_are_one_loop(name, make):
    # The (0, 0, 0, 1) row shares the loop that computes the rest (FUSION), compose and inverse
    # are written element-wise there (no batched matmul, no concatenation or in-place update
    # of an intermediate): one pass over the result.
    args = make(torch.Generator().manual_seed(40))
    fn = getattr(se3, name)
    out, loops, code = _batch_loops(fn, *args, options=compiled.inductor_options("se3", name))
    assert loops == 1, f"{loops} loops"
    assert not any("extern_kernels." in c for c in code)  # no library call (bmm)
    torch.testing.assert_close(out, fn(*args), rtol=0, atol=2e-6)
    # without FUSION, the constant entries take loops of their own
    _, default_loops, _ = _batch_loops(fn, *args, options={})
    assert default_loops > 1


def test_compiled_compose_inverse_entries_ignore_bottom_rows_and_broadcast():
    g = torch.Generator().manual_seed(41)
    A = se3.random(2, 1, generator=g, dtype=torch.float64)
    B = se3.random(3, generator=g, dtype=torch.float64)
    bad_A, bad_B = A.clone(), B.clone()
    bad_A[..., 3, :] = torch.nan
    bad_B[..., 3, :] = torch.tensor([1.0, -2.0, 3.0, 7.0], dtype=torch.float64)
    got = compiled.se3.compose(bad_A, bad_B)
    assert got.shape == (2, 3, 4, 4)
    torch.testing.assert_close(got, se3.compose(A, B), rtol=0, atol=1e-15)
    assert bool((got[..., 3, :] == torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=got.dtype)).all())
    torch.testing.assert_close(compiled.se3.inverse(bad_A), se3.inverse(A), rtol=0, atol=1e-15)
    # gradients through the compiled forward (element-wise) and the custom backward
    Ag = bad_A.clone().requires_grad_()
    W = torch.randn(2, 3, 4, 4, generator=g, dtype=torch.float64)
    (gc,) = torch.autograd.grad((compiled.se3.compose(Ag, bad_B) * W).sum(), Ag)
    (ge,) = torch.autograd.grad((se3.compose(Ag, bad_B) * W).sum(), Ag)
    torch.testing.assert_close(gc, ge, rtol=0, atol=1e-14)


@pytest.mark.parametrize(
    "module, name, make, most_backward_loops",
    [
        ("se3", "compose", lambda g: (se3.random(37, generator=g), se3.random(37, generator=g)), 1),
        ("se3", "inverse", lambda g: (se3.random(37, generator=g),), 1),
        # the guard of q's scale (any finite |q|): the backward reads q rescaled, written once
        # and read by the gradient's formula (2 loops with torch 2.13's Inductor, 3 with 2.14's)
        ("quaternion", "apply", lambda g: (torch.randn(37, 4, generator=g), torch.randn(37, 3)), 3),
        ("so3", "log", lambda g: (so3.random(37, generator=g),), 1),
        ("se3", "log", lambda g: (se3.random(37, generator=g),), 1),
        # the guarded twist and the gradient before the guard's derivative as planes (no stack
        # read back), the three Rodrigues applications one by one (no stack of them)
        ("so3", "exp", lambda g: (torch.randn(1000, 3, generator=g),), 1),
        ("se3", "exp", lambda g: (torch.randn(1000, 6, generator=g),), 1),
    ],
)
def test_compiled_forward_and_backward_loops(module, name, make, most_backward_loops):
    # Entry by entry while compiling (no batched matmul, no linalg.cross gathers, no transposed
    # copies of the components for AOTAutograd to save, no stacked intermediate read again by
    # components): one loop for the forward; the gradients are eager's.
    args = [x.requires_grad_() for x in make(torch.Generator().manual_seed(42))]
    fn = getattr({"so3": so3, "se3": se3, "quaternion": quaternion}[module], name)
    torch._dynamo.reset()
    cfn = torch.compile(fn, fullgraph=True, options=compiled.inductor_options(module, name))
    G = torch.randn_like(fn(*args))
    got, code = run_and_get_code(lambda: torch.autograd.grad(cfn(*args), args, G))
    assert len(code) == 2  # forward, backward
    assert _loops(code[0]) == 1
    assert 1 <= _loops(code[1]) <= most_backward_loops
    assert not any("extern_kernels." in c for c in code)
    want = torch.autograd.grad(fn(*args), args, G)
    for a, b in zip(got, want, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize(
    "module, name, make",
    [
        ("se3", "compose", lambda g: se3.random(6, generator=g, dtype=torch.float64)),
        ("se3", "between", lambda g: se3.random(6, generator=g, dtype=torch.float64)),
        ("so3", "compose", lambda g: so3.random(6, generator=g, dtype=torch.float64)),
        ("quaternion", "multiply", lambda g: torch.randn(6, 4, generator=g, dtype=torch.float64)),
    ],
)
def test_compiled_op_given_one_tensor_twice(module, name, make):
    # compose(T, T): one tensor as both operands of an op with its own backward (which Dynamo
    # does not trace as it is); the value and gradient are eager's
    X = make(torch.Generator().manual_seed(44)).requires_grad_()
    eager = getattr({"so3": so3, "se3": se3, "quaternion": quaternion}[module], name)
    fn = getattr(getattr(compiled, module), name)
    got = fn(X, X)
    want = eager(X, X)
    torch.testing.assert_close(got, want)
    W = torch.randn(want.shape, generator=torch.Generator().manual_seed(45), dtype=want.dtype)
    (g_got,) = torch.autograd.grad((got * W).sum(), X)
    (g_want,) = torch.autograd.grad((want * W).sum(), X)
    torch.testing.assert_close(g_got, g_want)
