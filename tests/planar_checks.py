"""Checks shared by SO(2) and SE(2): imported into ``test_so2.py`` and ``test_se2.py``, each of
which defines the fixture ``mod`` (the module under test).

Numerical specification: values within 4 ulp and gradients within 8 ulp (norm-wise relative
per element, absolute where the reference is 0) of 60-digit references from ``expm(hat(xi))``
(``reference_planar``), at angles 0, 1e-12, 1e-8, 1e-4, 1, 3, pi - 1e-8 and pi of both signs,
float32 and float64.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import reference_planar as ref
import torch
from torch.autograd import gradcheck, gradgradcheck

from torchlie import se2, so2

PI = math.pi
ANGLES = [0.0, 1e-12, 1e-8, 1e-4, 1.0, 3.0, PI - 1e-8, PI]
SIGNED = ANGLES + [-a for a in ANGLES[1:]]
RHOS = [(0.0, 0.0), (1e-3, 5.0), (-30.0, 0.25)]
VALUE_ULP, GRAD_ULP = 4.0, 8.0
_REFS: dict = {}


def dims(mod) -> tuple[int, int]:
    """(tangent size, matrix size)."""
    return (1, 2) if mod is so2 else (3, 3)


def name(mod) -> str:
    return "so2" if mod is so2 else "se2"


def tangents(mod) -> list[list[float]]:
    if mod is so2:
        return [[a] for a in SIGNED]
    return [[x, y, a] for a in SIGNED for x, y in RHOS]


def rel(out: np.ndarray, want: np.ndarray) -> float:
    d = float(np.sqrt(((out - want) ** 2).sum()))
    s = float(np.sqrt((want**2).sum()))
    return d / s if s > 0 else d


def references(mod, dtype):
    """Inputs rounded to ``dtype`` with their references (computed once per session)."""
    key = (name(mod), dtype)
    if key in _REFS:
        return _REFS[key]
    rng = np.random.default_rng(7)
    rows = []
    for xi in tangents(mod):
        x = torch.tensor(xi, dtype=dtype).double().numpy()
        E, D = ref.exp_and_derivatives(x, name(mod))
        G = rng.standard_normal(E.shape)
        g_exp = np.array([(G * Dk).sum() for Dk in D])
        X = torch.tensor(E, dtype=dtype).double().numpy()  # the rounded pose, the log's input
        g = rng.standard_normal(len(xi))
        log_ref, G_log = ref.log_and_gradient(X, g, name(mod))
        rows.append((xi, x, E, G, g_exp, X, g, log_ref, G_log))
    _REFS[key] = rows
    return rows


def _worst(errs):
    return max(errs, key=lambda e: e[0])


def test_ulp_error_of_values_and_gradients(mod, dtype):
    eps = torch.finfo(dtype).eps
    rows = references(mod, dtype)
    xs = torch.tensor(np.stack([r[1] for r in rows]), dtype=dtype).requires_grad_(True)
    T = mod.exp(xs)
    T.backward(torch.tensor(np.stack([r[3] for r in rows]), dtype=dtype))
    Xs = torch.tensor(np.stack([r[5] for r in rows]), dtype=dtype).requires_grad_(True)
    L = mod.log(Xs)
    L.backward(torch.tensor(np.stack([r[6] for r in rows]), dtype=dtype))
    errs = {"exp": [], "exp grad": [], "log": [], "log grad": []}
    for i, r in enumerate(rows):
        errs["exp"].append((rel(T[i].detach().double().numpy(), r[2]) / eps, r[0]))
        errs["exp grad"].append((rel(xs.grad[i].double().numpy(), r[4]) / eps, r[0]))
        errs["log"].append((rel(L[i].detach().double().numpy(), r[7]) / eps, r[0]))
        errs["log grad"].append((rel(Xs.grad[i].double().numpy(), r[8]) / eps, r[0]))
    for what, e in errs.items():
        tol = VALUE_ULP if "grad" not in what else GRAD_ULP
        worst = _worst(e)
        assert worst[0] <= tol, f"{name(mod)}.{what} {dtype}: {worst[0]:.2f} ulp at {worst[1]}"
    assert bool(torch.isfinite(xs.grad).all()) and bool(torch.isfinite(Xs.grad).all())


def test_blocked_evaluation_agrees(mod):
    """A batch large enough for the blocked evaluation gives the same values and gradients."""
    rows = references(mod, torch.float64)
    xs = torch.tensor(np.stack([r[1] for r in rows]))
    reps = 70000 // len(rows) + 1
    big = xs.repeat(reps, 1)
    torch.testing.assert_close(mod.exp(big)[: len(rows)], mod.exp(xs), rtol=0, atol=1e-15)
    X = mod.exp(xs)
    torch.testing.assert_close(
        mod.log(X.repeat(reps, 1, 1))[: len(rows)], mod.log(X), rtol=0, atol=1e-15
    )


# ----------------------------------------------------------------------------------------------
# Jacobians
# ----------------------------------------------------------------------------------------------


def _mp_jacobians(xi: list[float], group: str):
    """Jl, Jr, Ad(Exp(xi)) by 60-digit differences of their definitions (``mp.diff``)."""
    import mpmath as mp

    n, d = (1, 2) if group == "so2" else (3, 3)

    def E(v):
        if group == "so2":
            return mp.expm(mp.matrix([[0, -v[0]], [v[0], 0]]))
        return mp.expm(mp.matrix([[0, -v[2], v[0]], [v[2], 0, v[1]], [0, 0, 0]]))

    def L(M):
        t = mp.atan2(M[1, 0], M[0, 0])
        if group == "so2":
            return [t]
        return ref.se2_log_mp(M)

    X = E([mp.mpf(v) for v in xi])
    Xi = mp.inverse(X)
    Jr = ref.jac_fd(lambda v: L(Xi * E(v)), np.array(xi))
    Jl = ref.jac_fd(lambda v: L(E(v) * Xi), np.array(xi))
    Ad = ref.jac_fd(lambda v: L(X * E(v) * Xi), np.zeros(n))
    return Jl, Jr, Ad


JAC_POINTS = {
    "so2": [[0.0], [1e-8], [1.0], [-3.0]],
    "se2": [[0.0, 0.0, 0.0], [1.0, -2.0, 1e-8], [1.0, -2.0, 1.0], [-0.5, 3.0, -3.0]],
}


def test_jacobians_against_definitions(mod):
    for xi in JAC_POINTS[name(mod)]:
        Jl, Jr, Ad = _mp_jacobians(xi, name(mod))
        x = torch.tensor(xi, dtype=torch.float64)
        for got, want, what in (
            (mod.jac_left(x), Jl, "jac_left"),
            (mod.jac_right(x), Jr, "jac_right"),
            (mod.jac_left_inv(x), np.linalg.inv(Jl), "jac_left_inv"),
            (mod.jac_right_inv(x), np.linalg.inv(Jr), "jac_right_inv"),
            (mod.adjoint(mod.exp(x)), Ad, "adjoint"),
        ):
            np.testing.assert_allclose(got.numpy(), want, rtol=0, atol=1e-13, err_msg=what)


def _oplus(mod, X, d):
    return X @ mod.exp(d)


def _ominus(mod, Y, X):
    return mod.log(torch.linalg.inv(X) @ Y)


def _fd(f, x, perturb, diff, n, h=1e-6):
    cols = []
    for k in range(n):
        e = torch.zeros(n, dtype=torch.float64)
        e[k] = h
        cols.append(diff(f(perturb(x, e)), f(perturb(x, -e))) / (2 * h))
    return torch.stack(cols, dim=-1)


def test_operation_jacobians(mod):
    n, d = dims(mod)
    gen = torch.Generator().manual_seed(3)
    X, Y = (
        mod.random(generator=gen, dtype=torch.float64),
        mod.random(generator=gen, dtype=torch.float64),
    )
    p = torch.randn(2, generator=gen, dtype=torch.float64)
    tau = torch.randn(n, generator=gen, dtype=torch.float64)
    gp = lambda A, e: _oplus(mod, A, e)  # noqa: E731
    gd = lambda A, B: _ominus(mod, A, B)  # noqa: E731
    vp = lambda a, e: a + e  # noqa: E731
    vd = lambda a, b: a - b  # noqa: E731
    tol = dict(rtol=0, atol=1e-8)
    J1, J2 = mod.jac_compose(X, Y)
    torch.testing.assert_close(J1, _fd(lambda A: A @ Y, X, gp, gd, n), **tol)
    torch.testing.assert_close(J2, _fd(lambda B: X @ B, Y, gp, gd, n), **tol)
    torch.testing.assert_close(mod.jac_inverse(X), _fd(mod.inverse, X, gp, gd, n), **tol)
    JX, Jp = mod.jac_act(X, p)
    torch.testing.assert_close(JX, _fd(lambda A: mod.act(A, p), X, gp, vd, n), **tol)
    torch.testing.assert_close(Jp, _fd(lambda q: mod.act(X, q), p, vp, vd, 2), **tol)
    JX, Jt = mod.jac_rplus(X, tau)
    torch.testing.assert_close(JX, _fd(lambda A: mod.rplus(A, tau), X, gp, gd, n), **tol)
    torch.testing.assert_close(Jt, _fd(lambda v: mod.rplus(X, v), tau, vp, gd, n), **tol)
    J1, J0 = mod.jac_rminus(Y, X)
    torch.testing.assert_close(J1, _fd(lambda A: mod.rminus(A, X), Y, gp, vd, n), **tol)
    torch.testing.assert_close(J0, _fd(lambda B: mod.rminus(Y, B), X, gp, vd, n), **tol)
    J0, J1 = mod.jac_between(X, Y)
    torch.testing.assert_close(J0, _fd(lambda A: mod.between(A, Y), X, gp, gd, n), **tol)
    torch.testing.assert_close(J1, _fd(lambda B: mod.between(X, B), Y, gp, gd, n), **tol)


# ----------------------------------------------------------------------------------------------
# Group axioms and operations on batches
# ----------------------------------------------------------------------------------------------


def test_group_axioms(mod, dtype, batch, gen):
    n, d = dims(mod)
    tol = dict(rtol=0, atol=200 * torch.finfo(dtype).eps)
    X, Y, Z = (mod.random(*batch, generator=gen, dtype=dtype) for _ in range(3))
    eye = mod.identity(*batch, dtype=dtype)
    assert X.shape == (*batch, d, d) and bool(mod.is_valid(X).all())
    torch.testing.assert_close(
        mod.compose(mod.compose(X, Y), Z), mod.compose(X, mod.compose(Y, Z)), **tol
    )
    torch.testing.assert_close(mod.compose(X, eye), X, **tol)
    torch.testing.assert_close(mod.compose(X, mod.inverse(X)), eye, **tol)
    torch.testing.assert_close(mod.compose(X, Y), X @ Y, **tol)
    torch.testing.assert_close(mod.exp(mod.log(X)), X, **tol)
    tau = 0.5 * torch.randn(*batch, n, generator=gen, dtype=dtype)
    torch.testing.assert_close(mod.log(mod.exp(tau)), tau, **tol)
    torch.testing.assert_close(mod.rminus(mod.rplus(X, tau), X), tau, **tol)
    torch.testing.assert_close(mod.lminus(mod.lplus(X, tau), X), tau, **tol)
    torch.testing.assert_close(mod.rplus(X, tau), X @ mod.exp(tau), **tol)
    torch.testing.assert_close(mod.lplus(X, tau), mod.exp(tau) @ X, **tol)
    torch.testing.assert_close(mod.between(X, Y), mod.inverse(X) @ Y, **tol)
    torch.testing.assert_close(mod.interpolate(X, Y, 0.0), X, **tol)
    torch.testing.assert_close(mod.interpolate(X, Y, 1.0), Y, **tol)
    mid = mod.interpolate(X, Y, 0.5)
    torch.testing.assert_close(
        mod.compose(mod.between(X, mid), mod.between(X, mid)), mod.between(X, Y), **tol
    )
    # adjoint: X Exp(tau) X^-1 = Exp(Ad tau); Jl = Ad(Exp) Jr
    Ad = mod.adjoint(X)
    torch.testing.assert_close(
        X @ mod.exp(tau) @ mod.inverse(X), mod.exp((Ad @ tau[..., None])[..., 0]), **tol
    )
    torch.testing.assert_close(
        mod.jac_left(tau), mod.adjoint(mod.exp(tau)) @ mod.jac_right(tau), **tol
    )
    eye_n = torch.eye(n, dtype=dtype)
    torch.testing.assert_close(
        mod.jac_left_inv(tau) @ mod.jac_left(tau), eye_n.expand(*batch, n, n), **tol
    )
    torch.testing.assert_close(mod.vee(mod.hat(tau)), tau, **tol)
    ad = mod.ad(tau)
    torch.testing.assert_close(torch.linalg.matrix_exp(ad), mod.adjoint(mod.exp(tau)), **tol)
    p = torch.randn(*batch, 2, generator=gen, dtype=dtype)
    Xp = (X[..., :2, :2] @ p[..., None])[..., 0] + (X[..., :2, 2] if d == 3 else 0)
    torch.testing.assert_close(mod.act(X, p), Xp, **tol)


def test_broadcasting(mod):
    X = mod.random(3, 1, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    Y = mod.random(4, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    assert mod.compose(X, Y).shape[:-2] == (3, 4)
    assert mod.rminus(X, Y).shape[:-1] == (3, 4)
    assert mod.interpolate(X, Y, torch.tensor([0.2, 0.4, 0.6, 0.8], dtype=torch.float64)).shape[
        :-2
    ] == (3, 4)
    assert mod.act(X, torch.zeros(4, 2, dtype=torch.float64)).shape == (3, 4, 2)


def test_half_precision(mod):
    n, _ = dims(mod)
    tau = torch.full((4, n), 0.3, dtype=torch.float16)
    X = mod.exp(tau)
    assert X.dtype == torch.float16
    torch.testing.assert_close(mod.log(X).float(), tau.float(), rtol=0, atol=2e-3)


def test_nan_stays_in_its_element(mod):
    n, _ = dims(mod)
    tau = torch.full((3, n), 0.4, dtype=torch.float64, requires_grad=True)
    bad = torch.tensor([False, True, False])[:, None]
    x = torch.where(bad, float("nan"), tau)
    X = mod.exp(x)
    L = mod.log(X)
    L.sum().backward()
    assert bool(torch.isfinite(L[[0, 2]]).all()) and bool(torch.isnan(L[1]).all())
    assert bool(torch.isfinite(tau.grad[[0, 2]]).all())


# ----------------------------------------------------------------------------------------------
# Gradients: gradcheck, gradgradcheck, forward mode
# ----------------------------------------------------------------------------------------------


def _grad_points(mod):
    if mod is so2:
        return torch.tensor([[0.0], [1e-8], [1.0], [PI - 1e-6], [PI]], dtype=torch.float64)
    return torch.tensor(
        [
            [0.3, -0.2, 0.0],
            [1.0, 2.0, 1e-8],
            [-1.0, 0.5, 1.0],
            [2.0, 1.0, PI - 1e-6],
            [1.0, 1.0, PI],
        ],
        dtype=torch.float64,
    )


def test_gradcheck(mod):
    xi = _grad_points(mod).requires_grad_(True)
    assert gradcheck(mod.exp, (xi,))
    assert gradgradcheck(mod.exp, (xi,))
    X0 = mod.exp(_grad_points(mod)[:-1]).detach()  # away from the jump at pi
    d = torch.zeros(X0.shape[0], dims(mod)[0], dtype=torch.float64, requires_grad=True)
    assert gradcheck(lambda v: mod.log(X0 @ mod.exp(v)), (d,))
    assert gradgradcheck(lambda v: mod.log(X0 @ mod.exp(v)), (d,))
    M = X0.clone().requires_grad_(True)  # raw matrices: the log reads the polar factor
    assert gradcheck(mod.log, (M,))
    assert gradgradcheck(mod.log, (M,))
    Y0 = mod.exp(_grad_points(mod).flip(0)[1:]).detach().requires_grad_(True)
    t = torch.tensor([0.3, -0.5, 1.5, 0.0], dtype=torch.float64, requires_grad=True)
    assert gradcheck(lambda a, b, s: mod.interpolate(a, b, s), (M, Y0, t))
    p = torch.randn(4, 2, dtype=torch.float64, requires_grad=True)
    assert gradcheck(mod.act, (M, p))


def test_forward_mode(mod):
    xi = _grad_points(mod)
    v = torch.randn(xi.shape, dtype=torch.float64)
    _, jvp = torch.func.jvp(mod.exp, (xi,), (v,))
    _, vjp = torch.func.vjp(mod.exp, xi)
    G = torch.randn(jvp.shape, dtype=torch.float64)
    torch.testing.assert_close((G * jvp).sum(), (vjp(G)[0] * v).sum())
    X = mod.exp(xi[:-1])
    V = torch.randn(X.shape, dtype=torch.float64)
    _, jvp = torch.func.jvp(mod.log, (X,), (V,))
    _, vjp = torch.func.vjp(mod.log, X)
    g = torch.randn(jvp.shape, dtype=torch.float64)
    torch.testing.assert_close((g * jvp).sum(), (vjp(g)[0] * V).sum())


def test_half_turn_is_pi_with_the_branch_derivative(mod):
    """``log`` of a rotation by exactly pi (either zero sign) is +pi; the gradient is that of the
    angles below pi: along the tangent ``R hat(1)`` the derivative of the angle is 1."""
    _, d = dims(mod)
    for z in (0.0, -0.0):
        R = torch.tensor([[-1.0, -z], [z, -1.0]], dtype=torch.float64)
        X = R if d == 2 else se2.from_rt(R, torch.tensor([1.0, -2.0], dtype=torch.float64))
        X = X.clone().requires_grad_(True)
        out = mod.log(X)
        assert float(out[-1].detach()) == PI
        out[-1].backward()
        direction = torch.zeros(d, d, dtype=torch.float64)
        direction[:2, :2] = R @ torch.tensor([[0.0, -1.0], [1.0, 0.0]], dtype=torch.float64)
        assert float((X.grad * direction).sum()) == pytest.approx(1.0, abs=1e-15)
    x32 = mod.log(torch.eye(d, dtype=torch.float32) * torch.tensor([-1.0, -1.0, 1.0][:d]))
    assert float(x32[-1]) == float(torch.tensor(PI, dtype=torch.float32))


# ----------------------------------------------------------------------------------------------
# torch.func and torch.compile
# ----------------------------------------------------------------------------------------------


def test_vmap(mod):
    xi = _grad_points(mod)
    torch.testing.assert_close(torch.func.vmap(mod.exp)(xi), mod.exp(xi))
    X = mod.exp(xi)
    torch.testing.assert_close(torch.func.vmap(mod.log)(X), mod.log(X))
    J = torch.func.vmap(torch.func.jacrev(lambda v: mod.log(mod.exp(v))))(xi[:-1])
    eye = torch.eye(xi.shape[-1], dtype=torch.float64).expand_as(J)
    torch.testing.assert_close(J, eye, rtol=0, atol=1e-12)


@pytest.mark.compile
def test_compile_fullgraph(mod):
    xi = _grad_points(mod).requires_grad_(True)

    def f(v):
        X = mod.exp(v)
        return mod.log(mod.compose(X, mod.inverse(X) @ X)), mod.act(
            X, v[..., :2] if v.shape[-1] > 1 else v.expand(*v.shape[:-1], 2)
        )

    fc = torch.compile(f, fullgraph=True, backend="aot_eager")
    (a, b), (c, e) = fc(xi), f(xi)
    torch.testing.assert_close(a, c)
    torch.testing.assert_close(b, e)
    g1 = torch.autograd.grad((a.sum() + b.sum()), xi)[0]
    g2 = torch.autograd.grad((c.sum() + e.sum()), xi)[0]
    torch.testing.assert_close(g1, g2)


# ----------------------------------------------------------------------------------------------
# Bad input
# ----------------------------------------------------------------------------------------------


def test_bad_input(mod):
    n, d = dims(mod)
    prefix = f"torchlie.{name(mod)}."
    with pytest.raises(
        ValueError, match=prefix + r"exp: expected xi|" + prefix + "exp: expected theta"
    ):
        mod.exp(torch.zeros(n + 1))
    with pytest.raises(ValueError, match=prefix + "log"):
        mod.log(torch.zeros(d + 1, d + 1))
    with pytest.raises(TypeError, match=prefix + "exp"):
        mod.exp(torch.zeros(n, dtype=torch.int64))
    with pytest.raises(TypeError, match=prefix + "compose"):
        mod.compose(torch.eye(d), torch.eye(d, dtype=torch.float64))
    with pytest.raises(ValueError, match=prefix + "compose: batch shapes do not broadcast"):
        mod.compose(torch.eye(d).expand(2, d, d), torch.eye(d).expand(3, d, d))
    with pytest.raises(ValueError, match=prefix + "act"):
        mod.act(torch.eye(d), torch.zeros(3))
    with pytest.raises(TypeError, match=prefix + "log"):
        mod.log([[1.0, 0.0], [0.0, 1.0]])
    with pytest.raises(TypeError, match=prefix + "interpolate"):
        mod.interpolate(torch.eye(d), torch.eye(d), True)
    with pytest.raises(TypeError, match=prefix + "random"):
        mod.random(2, dtype=torch.int32)
    with pytest.raises(ValueError, match=prefix + "is_valid"):
        mod.is_valid(torch.eye(d), atol=-1.0)


# ----------------------------------------------------------------------------------------------
# The classes SO2 / SE2: every method is the functional core's value, exactly
# ----------------------------------------------------------------------------------------------


def test_class_methods_equal_core(mod, batch):
    from torchlie import SE2, SO2

    cls = SO2 if mod is so2 else SE2
    n, d = dims(mod)
    gen = torch.Generator().manual_seed(0)
    X = cls.random(*batch, generator=gen, dtype=torch.float64)
    Y = cls.random(*batch, generator=gen, dtype=torch.float64)
    a, b = X.tensor, Y.tensor
    tau = torch.randn(*batch, n, generator=gen, dtype=torch.float64)
    p = torch.randn(*batch, 2, generator=gen, dtype=torch.float64)
    pairs = [
        ((X @ Y).tensor, mod.compose(a, b)),
        (X.compose(Y).tensor, mod.compose(a, b)),
        (X @ p, mod.act(a, p)),
        (X.apply(p), mod.act(a, p)),
        (X.inverse().tensor, mod.inverse(a)),
        (X.log(), mod.log(a)),
        (cls.exp(tau).tensor, mod.exp(tau)),
        (X.adjoint(), mod.adjoint(a)),
        (X.rplus(tau).tensor, mod.rplus(a, tau)),
        (X.lplus(tau).tensor, mod.lplus(a, tau)),
        (X.rminus(Y), mod.rminus(a, b)),
        (X.lminus(Y), mod.lminus(a, b)),
        (X.between(Y).tensor, mod.between(a, b)),
        (X.interpolate(Y, 0.3).tensor, mod.interpolate(a, b, 0.3)),
        (X.is_valid(), mod.is_valid(a)),
        (cls.identity(*batch).tensor, mod.identity(*batch)),
    ]
    for got, want in pairs:
        assert torch.equal(got, want)
    assert X.matrix is a and X.shape == batch and X.rotation.shape == batch
    dist, want = X.distance(Y), mod.distance(a, b)
    for u, v in zip(
        dist if isinstance(dist, tuple) else (dist,),
        want if isinstance(want, tuple) else (want,),
        strict=True,
    ):
        assert torch.equal(u, v)
    if mod is se2:
        assert torch.equal(X.translation, a[..., :2, 2]) and torch.equal(
            X.rotation.tensor, a[..., :2, :2]
        )
        assert torch.equal(SE2.from_rt(X.rotation, X.translation).tensor, a)
        assert torch.equal(
            SE2.from_xytheta(X.xytheta()).tensor, se2.from_xytheta(se2.to_xytheta(a))
        )
    else:
        assert torch.equal(
            SO2.from_complex(X.complex()).tensor, so2.from_complex(so2.to_complex(a))
        )
    if batch:
        assert torch.equal(X[0].tensor, a[0]) and len(X) == batch[0]
    # pytree: through torch.func
    leaves, spec = torch.utils._pytree.tree_flatten(X)
    assert leaves[0] is a and type(torch.utils._pytree.tree_unflatten(leaves, spec)) is cls


@pytest.mark.compile
def test_compiled_namespace(mod):
    """``torchlie.compiled`` (Inductor, fullgraph) gives eager's values and gradients."""
    from torchlie import compiled

    cmod = getattr(compiled, name(mod))
    xi = _grad_points(mod).requires_grad_(True)
    X = cmod.exp(xi)
    torch.testing.assert_close(X, mod.exp(xi), rtol=0, atol=1e-14)
    (g,) = torch.autograd.grad((cmod.log(X) * torch.arange(1.0, 1.0 + xi.shape[-1])).sum(), xi)
    (ge,) = torch.autograd.grad(
        (mod.log(mod.exp(xi)) * torch.arange(1.0, 1.0 + xi.shape[-1])).sum(), xi
    )
    torch.testing.assert_close(g, ge, rtol=0, atol=1e-12)
    assert set(dir(cmod)) == set(mod.__all__)


def test_class_bad_input_raises(mod):
    from torchlie import SE2, SO2

    cls = SO2 if mod is so2 else SE2
    X = cls.identity(dtype=torch.float64)
    a = X.tensor
    with pytest.raises(TypeError, match=f"torchlie.{cls.__name__}.compose"):
        X.compose(a)
    with pytest.raises(
        ValueError, match=rf"torchlie.{cls.__name__}.apply \(through torchlie.{name(mod)}.act\)"
    ):
        X.apply(torch.zeros(3))


def test_huge_angles_finite(mod, dtype):
    """Values, gradients and Jacobians stay finite at angles whose square overflows."""
    n, _ = dims(mod)
    huge = 3e38 if dtype == torch.float32 else 1e300
    for theta in (1e6, 1e20, huge):
        xi = torch.tensor([1.0, -2.0, theta][-n:], dtype=dtype, requires_grad=True)
        X = mod.exp(xi)
        X.sum().backward()
        assert bool(torch.isfinite(X).all()) and bool(torch.isfinite(xi.grad).all())
        assert bool(torch.isfinite(mod.jac_left(xi.detach())).all())
        assert bool(mod.is_valid(X.detach(), atol=1e-3).all())
