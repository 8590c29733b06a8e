"""torchlie.compiled: the same results and gradients as the eager API, compiled fullgraph."""

from __future__ import annotations

import math

import pytest
import torch
from samplers import ANGLES, rotvecs

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


def test_compiled_has_a_namespace_per_function_module():
    # the functional API mirrored name for name: every function module, each with its names
    import torchlie

    modules = {"so2", "se2", "so3", "se3", "sim3", "quaternion", "conversions"}
    assert modules <= set(compiled.__all__)
    for m in modules:
        eager = getattr(torchlie, m)
        assert set(dir(getattr(compiled, m))) == set(eager.__all__), m
        for name in eager.__all__:
            assert compiled.inductor_options(m, name) == compiled.inductor_options("so3", "exp")


def test_compiled_sim3_exp_log_values_and_gradients():
    from torchlie import sim3

    g = torch.Generator().manual_seed(46)
    xi = (0.5 * torch.randn(5, 7, generator=g, dtype=torch.float64)).requires_grad_()
    w = torch.arange(1.0, 8.0, dtype=torch.float64)
    torch._dynamo.reset()
    T = compiled.sim3.exp(xi)
    eps = torch.finfo(torch.float64).eps
    torch.testing.assert_close(T, sim3.exp(xi), rtol=0, atol=8 * eps)
    torch.testing.assert_close(compiled.sim3.log(T), sim3.log(T), rtol=0, atol=16 * eps)
    (got,) = torch.autograd.grad((compiled.sim3.log(compiled.sim3.exp(xi)) * w).sum(), xi)
    (want,) = torch.autograd.grad((sim3.log(sim3.exp(xi)) * w).sum(), xi)
    torch.testing.assert_close(got, want, rtol=0, atol=1e-12)
    assert compiled.sim3.random is sim3.random


def test_inductor_options_errors():
    with pytest.raises(ValueError, match=r"inductor_options: expected module to be one of"):
        compiled.inductor_options("so4", "exp")
    with pytest.raises(ValueError, match=r"torchlie\.so3 has no public function '_exp'"):
        compiled.inductor_options("so3", "_exp")


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
    "module, name, make",
    [
        ("se3", "compose", lambda g: (se3.random(37, generator=g), se3.random(37, generator=g))),
        ("se3", "inverse", lambda g: (se3.random(37, generator=g),)),
        ("quaternion", "apply", lambda g: (torch.randn(37, 4, generator=g), torch.randn(37, 3))),
        ("so3", "log", lambda g: (so3.random(37, generator=g),)),
        ("se3", "log", lambda g: (se3.random(37, generator=g),)),
        ("so3", "exp", lambda g: (torch.randn(1000, 3, generator=g),)),
        ("se3", "exp", lambda g: (torch.randn(1000, 6, generator=g),)),
        ("so3", "act", lambda g: (so3.random(1000, generator=g), torch.randn(1000, 3))),
        ("se3", "act", lambda g: (se3.random(1000, generator=g), torch.randn(1000, 3))),
    ],
)
def test_compiled_forward_and_backward_agree_with_eager(module, name, make):
    """With the options of :func:`torchlie.compiled.inductor_options` (how many loops Inductor
    makes of them is reported by ``benchmarks/loops.py``, not asserted)."""
    args = [x.requires_grad_() for x in make(torch.Generator().manual_seed(42))]
    fn = getattr({"so3": so3, "se3": se3, "quaternion": quaternion}[module], name)
    torch._dynamo.reset()
    cfn = torch.compile(fn, fullgraph=True, options=compiled.inductor_options(module, name))
    out = cfn(*args)
    G = torch.randn_like(out)
    got = torch.autograd.grad(out, args, G)
    want_out = fn(*args)
    want = torch.autograd.grad(want_out, args, G)
    torch.testing.assert_close(out, want_out, rtol=1e-5, atol=1e-5)
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


def test_new_float_values_and_many_variants():
    """A new float (``t``) does not count as a variant to compile, and past torch's limit of
    recompilations a function runs eagerly with a warning instead of raising (the limit
    lowered to 2 here, for speed)."""
    import warnings

    from torchlie import so2

    torch._dynamo.reset()
    ns = compiled._CompiledNamespace(so2)  # fresh wrappers
    R0, R1 = so2.identity(), so2.exp(torch.tensor([1.0]))
    with torch._dynamo.config.patch(recompile_limit=2), warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        for t in (0.1, 0.2, 0.3, 0.4):
            torch.testing.assert_close(ns.interpolate(R0, R1, t), so2.interpolate(R0, R1, t))
        assert not any("runs eagerly" in str(x.message) for x in w)
        for rank in (1, 2, 3, 4):
            theta = torch.ones((2,) * (rank - 1) + (1,))
            torch.testing.assert_close(ns.exp(theta), so2.exp(theta))
        assert any("runs eagerly" in str(x.message) for x in w)
