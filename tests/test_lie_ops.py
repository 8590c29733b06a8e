"""Lie-group properties written once for every group (one registry), and the closed-form
Jacobians of the group operations checked against ``torch.func.jacrev`` in tangent coordinates.

Jacobian convention (Sola et al., "A micro Lie theory"): for ``Y = f(X)``,
``J_Y_X = d Log(f(X)^-1 f(X Exp(d))) / d d`` at ``d = 0``; vector arguments and results (points,
tangent vectors) are perturbed by plain addition.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import ModuleType

import pytest
import torch
from samplers import ANGLES, PI, eps, rotvecs

from torchlie import se2, se3, sim3, so2, so3

F64 = torch.float64


@dataclass(frozen=True)
class Group:
    """A matrix Lie group of torchlie with the samplers its property tests use."""

    name: str
    mod: ModuleType
    dof: int  # tangent dimension
    size: int  # matrix size
    pdim: int = 3  # dimension of the points it acts on

    def tangent(self, angles=ANGLES, n_random: int = 8, seed: int = 0, dtype=F64):
        """Tangent vectors whose rotation part runs over ``angles`` x ``samplers.axes`` (planar:
        ``angles`` with the signs +, -, + and ``n_random`` random ones); the translation part of a
        twist is ``N(0, I)``."""
        if self.pdim == 2:
            g = torch.Generator().manual_seed(seed)
            a = torch.tensor(angles, dtype=F64)[:, None]
            signs = torch.randint(0, 2, (len(angles), n_random), generator=g) * 2.0 - 1.0
            fixed = torch.tensor([[1.0, -1.0, 1.0]], dtype=F64).expand(len(angles), 3)
            t = (a * torch.cat((fixed, signs), -1)).reshape(-1, 1)
            if self.dof == 1:
                return t.to(dtype)
            rho = torch.randn(t.shape[0], 2, generator=g, dtype=F64)
            return torch.cat((rho, t), dim=-1).to(dtype)
        w, _ = rotvecs(angles, n_random=n_random, seed=seed)
        if self.dof == 3:
            return w.to(dtype)
        g = torch.Generator().manual_seed(seed + 100)
        rho = torch.randn(w.shape, generator=g, dtype=F64)
        return torch.cat((rho, w), dim=-1).to(dtype)

    def random(self, *batch: int, seed: int = 0, dtype=F64) -> torch.Tensor:
        return self.mod.random(*batch, generator=torch.Generator().manual_seed(seed), dtype=dtype)

    def hat(self, x: torch.Tensor) -> torch.Tensor:
        return self.mod.hat(x)

    def scale(self, *xs: torch.Tensor) -> float:
        """1 + the largest magnitude in the inputs: translations set the size of errors."""
        return 1.0 + max(float(x.abs().amax()) for x in xs)


GROUPS = [
    Group("so3", so3, 3, 3),
    Group("se3", se3, 6, 4),
    Group("so2", so2, 1, 2, pdim=2),
    Group("se2", se2, 3, 3, pdim=2),
]


@pytest.fixture(params=GROUPS, ids=lambda g: g.name)
def group(request) -> Group:
    return request.param


def close(a: torch.Tensor, b: torch.Tensor, atol: float) -> None:
    torch.testing.assert_close(a, b, rtol=0, atol=atol)


def matvec(M: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    return (M @ v.unsqueeze(-1)).squeeze(-1)


# ----------------------------------------------------------------------------------------------
# Group axioms and adjoints
# ----------------------------------------------------------------------------------------------


def test_group_axioms(group, dtype):
    G = group.mod
    A = group.random(2, 1, seed=1, dtype=dtype)
    B = group.random(3, seed=2, dtype=dtype)
    C = group.random(1, 3, seed=3, dtype=dtype)
    tol = 8 * eps(dtype) * group.scale(A, B, C)
    AB = G.compose(A, B)
    assert AB.shape == (2, 3, group.size, group.size)
    close(G.compose(AB, C), G.compose(A, G.compose(B, C)), tol)
    eye = G.identity(dtype=dtype)
    close(G.compose(eye, B), B, 0.0)
    close(G.compose(B, eye), B, 0.0)
    close(G.compose(AB, G.inverse(AB)), G.identity(2, 3, dtype=dtype), tol)
    close(G.compose(G.inverse(AB), AB), G.identity(2, 3, dtype=dtype), tol)
    close(G.inverse(G.inverse(B)), B, tol)
    assert bool(G.is_valid(AB).all())
    close(G.between(A, B), G.compose(G.inverse(A), B), tol)
    close(G.log(eye), torch.zeros(group.dof, dtype=dtype), 0.0)
    close(G.exp(torch.zeros(group.dof, dtype=dtype)), eye, 0.0)


def test_conjugation_is_exp_of_adjoint(group, dtype):
    G = group.mod
    tau = group.tangent(dtype=dtype)
    X = group.random(tau.shape[0], seed=4, dtype=dtype)
    lhs = G.compose(G.compose(X, G.exp(tau)), G.inverse(X))
    rhs = G.exp(matvec(G.adjoint(X), tau))
    close(lhs, rhs, 8 * eps(dtype) * group.scale(X, tau))


def test_adjoint_is_a_representation(group, dtype):
    G = group.mod
    A = group.random(20, seed=5, dtype=dtype)
    B = group.random(20, seed=6, dtype=dtype)
    tol = 8 * eps(dtype) * group.scale(A, B)
    close(G.adjoint(G.compose(A, B)), G.adjoint(A) @ G.adjoint(B), tol)
    eye = torch.eye(group.dof, dtype=dtype).expand(20, -1, -1)
    close(G.adjoint(G.inverse(A)) @ G.adjoint(A), eye, tol)


def test_small_adjoint(group, dtype):
    G = group.mod
    x = group.tangent([0.0, 1e-8, 1.0, 3.0, PI - 1e-6, PI], seed=1, dtype=dtype)
    y = group.tangent([0.5, 2.0, 1e-4, PI, 1.0, 0.0], seed=2, dtype=dtype)
    tol = 8 * eps(dtype) * group.scale(x, y)
    adxy = matvec(G.ad(x), y)
    close(adxy, -matvec(G.ad(y), x), tol)
    # ad(x) y is the Lie bracket [hat(x), hat(y)]
    hx, hy = group.hat(x), group.hat(y)
    close(group.hat(adxy), hx @ hy - hy @ hx, tol)
    # Ad(Exp(x)) = exp(ad(x)) (in float64: matrix_exp's own error is not the subject here)
    lhs = torch.linalg.matrix_exp(G.ad(x.double()))
    close(G.adjoint(G.exp(x)).double(), lhs, 16 * eps(dtype) * group.scale(x))


# ----------------------------------------------------------------------------------------------
# Exp/Log Jacobian identities
# ----------------------------------------------------------------------------------------------


def test_jacobian_identities(group, dtype):
    G = group.mod
    tau = group.tangent(dtype=dtype)
    s = group.scale(tau)
    tol = 4 * eps(dtype) * s
    eye = torch.eye(group.dof, dtype=dtype).expand(tau.shape[0], -1, -1)
    Jl, Jr = G.jac_left(tau), G.jac_right(tau)
    Jli, Jri = G.jac_left_inv(tau), G.jac_right_inv(tau)
    close(Jl, G.jac_right(-tau), 2 * eps(dtype) * s)
    close(Jli, G.jac_right_inv(-tau), 2 * eps(dtype) * s)
    close(Jl, G.adjoint(G.exp(tau)) @ Jr, tol)
    close(Jl @ Jli, eye, tol)
    close(Jli @ Jl, eye, tol)
    close(Jr @ Jri, eye, tol)
    close(Jri @ Jr, eye, tol)


# ----------------------------------------------------------------------------------------------
# Plus, minus, between
# ----------------------------------------------------------------------------------------------


def test_plus_minus_between_consistency(group, dtype):
    G = group.mod
    X = group.random(40, seed=7, dtype=dtype)
    Y = group.random(40, seed=8, dtype=dtype)
    tol = 8 * eps(dtype) * group.scale(X, Y)
    tau = G.rminus(Y, X)
    close(tau, G.log(G.between(X, Y)), 0.0)
    close(G.rplus(X, tau), Y, tol)
    close(G.rplus(X, tau), G.compose(X, G.exp(tau)), 0.0)
    sigma = G.lminus(Y, X)
    close(G.lplus(X, sigma), Y, tol)
    close(G.lplus(X, sigma), G.compose(G.exp(sigma), X), 0.0)
    # Y X^-1 = X (X^-1 Y) X^-1, so the left difference is the right one carried by Ad_X
    close(sigma, matvec(G.adjoint(X), tau), tol)
    # below pi, minus undoes plus
    small = group.tangent([a for a in ANGLES if a < PI - 1e-3], n_random=2, seed=3, dtype=dtype)
    Z = group.random(small.shape[0], seed=9, dtype=dtype)
    close(G.rminus(G.rplus(Z, small), Z), small, tol)
    close(G.lminus(G.lplus(Z, small), Z), small, tol)


#: Every group, Sim(3) included, with whether ``between(X, X)`` is exactly the identity (Sim(3):
#: its log reads the scale from the norm of the linear block, so only the identity has log 0).
EQUAL_ELEMENTS = [
    pytest.param(g, exact, id=g.name)
    for g, exact in [(g, False) for g in GROUPS] + [(Group("sim3", sim3, 7, 4), True)]
]


@pytest.mark.parametrize("group, exact_between", EQUAL_ELEMENTS)
@pytest.mark.parametrize("batch", [(), (5,), (2, 3), (70000,)], ids=str)
def test_minus_of_equal_elements_is_exactly_zero(group, exact_between, batch, dtype):
    # (70000,): large enough for the kernels of large batches, evaluated block by block
    G = group.mod
    X = group.random(*batch, seed=3, dtype=dtype)
    zero = torch.zeros(*batch, group.dof, dtype=dtype)
    assert torch.equal(G.rminus(X, X), zero)
    assert torch.equal(G.lminus(X, X), zero)
    dist = G.distance(X, X)  # a tensor, or a tuple of them
    for d in dist if isinstance(dist, tuple) else (dist,):
        assert torch.equal(d, torch.zeros(batch, dtype=dtype))
    if exact_between:
        assert torch.equal(G.between(X, X), G.identity(*batch, dtype=dtype))
    # and the derivatives there stay right: d rminus(X Exp(d), X) = d lminus(Exp(d) X, X) = d
    Y = group.random(seed=4, dtype=F64)
    d0 = torch.zeros(group.dof, dtype=F64)
    eye = torch.eye(group.dof, dtype=F64)
    for J in (
        torch.autograd.functional.jacobian(lambda d: G.rminus(G.rplus(Y, d), Y), d0),
        torch.autograd.functional.jacobian(lambda d: G.lminus(G.lplus(Y, d), Y), d0),
    ):
        close(J, eye, 16 * eps(F64))


def test_ops_broadcast_and_keep_half_precision(group):
    G = group.mod
    X = group.random(2, 1, seed=10, dtype=torch.float32)
    Y = group.random(3, seed=11, dtype=torch.float32)
    tau = group.tangent([0.3], n_random=0, seed=4, dtype=torch.float32)[:3]  # (3, dof)
    p = torch.randn(5, 1, 1, group.pdim)
    n, d, k = group.size, group.dof, group.pdim
    assert G.rplus(X, tau).shape == G.lplus(X, tau).shape == (2, 3, n, n)
    assert G.rminus(X, Y).shape == G.lminus(X, Y).shape == (2, 3, d)
    assert G.between(X, Y).shape == (2, 3, n, n)
    assert G.ad(tau).shape == (3, d, d)
    for J in (
        *G.jac_compose(X, Y),
        *G.jac_rplus(X, tau),
        *G.jac_rminus(X, Y),
        *G.jac_between(X, Y),
    ):
        assert J.shape == (2, 3, d, d)
    assert G.jac_inverse(X).shape == (2, 1, d, d)
    JX, Jp = G.jac_act(X, p)
    assert JX.shape == (5, 2, 1, k, d) and Jp.shape == (5, 2, 1, k, k)
    for half in (torch.float16, torch.bfloat16):
        Xh, Yh, th = X.to(half), Y.to(half), tau.to(half)
        close(G.rminus(Xh, Yh), G.rminus(Xh.float(), Yh.float()).to(half), 0.0)
        close(G.rplus(Xh, th), G.rplus(Xh.float(), th.float()).to(half), 0.0)
        J1, J2 = G.jac_rminus(Xh, Yh)
        assert J1.dtype == J2.dtype == half


def test_ops_bad_input(group):
    G = group.mod
    n, d = group.size, group.dof
    name = rf"torchlie\.{group.name}\."
    X = torch.eye(n)
    with pytest.raises(ValueError, match=name + r"rplus: expected (tau|xi) of shape"):
        G.rplus(X, torch.zeros(d + 1))
    for fn in (G.rminus, G.lminus, G.between, G.jac_compose, G.jac_rminus, G.jac_between):
        with pytest.raises(ValueError, match=name + fn.__name__ + ": expected"):
            fn(X, torch.eye(n + 1))
        with pytest.raises(TypeError, match="one dtype"):
            fn(X, X.double())
        with pytest.raises(ValueError, match="batch shapes do not broadcast"):
            fn(X.expand(2, n, n), X.expand(3, n, n))
    with pytest.raises(ValueError, match=name + "jac_act: expected points"):
        G.jac_act(X, torch.zeros(4))
    with pytest.raises(ValueError, match=name + "ad: expected"):
        G.ad(torch.zeros(d + 1))
    with pytest.raises(TypeError, match=name + "jac_inverse: .*floating-point"):
        G.jac_inverse(torch.eye(n, dtype=torch.int32))


def test_nan_stays_in_its_element(group, dtype):
    G = group.mod
    X = group.random(4, seed=12, dtype=dtype)
    Y = group.random(4, seed=13, dtype=dtype)
    X[1, 0, 0] = float("nan")
    keep = [0, 2, 3]
    close(G.rminus(Y, X)[keep], G.rminus(Y[keep], X[keep]), 0.0)
    for a, b in zip(G.jac_rminus(Y, X), G.jac_rminus(Y[keep], X[keep]), strict=True):
        close(a[keep], b, 0.0)
        assert bool(torch.isnan(a[1]).any()) or group.name == "so2"  # so2's are constants


# ----------------------------------------------------------------------------------------------
# Closed-form Jacobians of the operations against jacrev in tangent coordinates
# ----------------------------------------------------------------------------------------------

WHERE = {"zero": 0.0, "tiny": 1e-8, "generic": 1.3, "near_pi": PI - 1e-6}
OPS = ["compose", "inverse", "act", "exp", "log", "jac_left", "rplus", "rminus", "between"]


def _point(group: Group, theta: float):
    """X generic, tau of angle theta, Y = X Exp(tau) (so Log(X^-1 Y) = tau), a point p."""
    tau = group.tangent([theta], n_random=1, seed=6)[-1]  # the one random axis
    X = group.random(seed=14)
    Y = group.mod.rplus(X, tau)
    p = torch.tensor([0.4, -1.1, 0.7], dtype=F64)[: group.pdim]
    return X, Y, tau, p


def _rjac(group: Group, f, x0: torch.Tensor, kind: str) -> torch.Tensor:
    """Jacobian of ``f`` in tangent coordinates at ``x0``: ``d -> f(x0 (+) d) (-) f(x0)``, where
    (+)/(-) are the group's right plus/minus for a group element and +/- for a vector."""
    G = group.mod
    d0 = torch.zeros(group.dof if kind == "group" else x0.shape[-1], dtype=F64)
    y0 = f(x0)

    def g(d):
        x = G.rplus(x0, d) if kind == "group" else x0 + d
        y = f(x)
        return G.rminus(y, y0) if y.shape[-2:] == (group.size, group.size) else y - y0

    return torch.func.jacrev(g)(d0)


@pytest.mark.parametrize("where", list(WHERE))
@pytest.mark.parametrize("op", OPS)
def test_op_jacobians_match_jacrev(group, op, where):
    G = group.mod
    X, Y, tau, p = _point(group, WHERE[where])
    grp, vec = "group", "vector"
    if op == "compose":
        got = G.jac_compose(X, Y)
        want = (
            _rjac(group, lambda a: G.compose(a, Y), X, grp),
            _rjac(group, lambda b: G.compose(X, b), Y, grp),
        )
    elif op == "inverse":
        got = (G.jac_inverse(X),)
        want = (_rjac(group, G.inverse, X, grp),)
    elif op == "act":
        got = G.jac_act(X, p)
        want = (
            _rjac(group, lambda a: G.act(a, p), X, grp),
            _rjac(group, lambda q: G.act(X, q), p, vec),
        )
    elif op == "exp":
        got = (G.jac_right(tau),)
        want = (_rjac(group, G.exp, tau, vec),)
    elif op == "log":
        E = G.exp(tau)
        got = (G.jac_right_inv(G.log(E)),)
        want = (_rjac(group, G.log, E, grp),)
    elif op == "jac_left":
        # Exp(tau + d) = Exp(Jl d) Exp(tau): the left-perturbation counterpart of exp's
        E = G.exp(tau)
        d0 = torch.zeros(group.dof, dtype=F64)
        got = (G.jac_left(tau),)
        want = (torch.func.jacrev(lambda d: G.lminus(G.exp(tau + d), E))(d0),)
    elif op == "rplus":
        got = G.jac_rplus(X, tau)
        want = (
            _rjac(group, lambda a: G.rplus(a, tau), X, grp),
            _rjac(group, lambda v: G.rplus(X, v), tau, vec),
        )
    elif op == "rminus":
        got = G.jac_rminus(Y, X)
        want = (
            _rjac(group, lambda a: G.rminus(a, X), Y, grp),
            _rjac(group, lambda b: G.rminus(Y, b), X, grp),
        )
    else:  # between
        got = G.jac_between(X, Y)
        want = (
            _rjac(group, lambda a: G.between(a, Y), X, grp),
            _rjac(group, lambda b: G.between(X, b), Y, grp),
        )
    assert len(got) == len(want)
    for J, ref in zip(got, want, strict=True):
        assert J.shape == ref.shape
        close(J, ref, 16 * eps(F64) * group.scale(X, Y, tau))


def test_jacobians_under_vmap(group):
    G = group.mod
    X = group.random(5, seed=15)
    Y = group.random(5, seed=16)
    p = torch.randn(5, group.pdim, dtype=F64)
    vmap = torch.func.vmap
    for fn, args in ((G.jac_rminus, (Y, X)), (G.jac_between, (X, Y)), (G.jac_act, (X, p))):
        for a, b in zip(vmap(fn)(*args), fn(*args), strict=True):
            close(a, b, 0.0)
