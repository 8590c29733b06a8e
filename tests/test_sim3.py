"""torchlie.sim3: values and gradients against 60-digit references from the matrix exponential
of ``hat(xi)``, Jacobians against high-precision finite differences of their definitions,
group axioms, gradcheck, bad input, vmap, compile and PyPose's ``Sim3``.

Errors are norm-wise relative per element, ``|out - ref| / |ref|``, as in ``test_precision``.
"""

from __future__ import annotations

import math

import mpmath as mp
import numpy as np
import pytest
import scipy.linalg
import torch
from agreement import assert_agree
from torch.autograd import gradcheck, gradgradcheck

from torchlie import Sim3, _coeffs, quaternion, se3, sim3, so3

F64 = torch.float64
PI = math.pi
ANGLES = [0.0, 1e-12, 1e-8, 1e-4, 1.0, 3.0, PI - 1e-8, PI]
SIGMAS = [0.0, 1e-12, 1e-6, 0.5, -3.0, 20.0]
VALUE_ULP, GRAD_ULP = 4.0, 8.0
JAC_ULP = 6.0  # 7x7 Jacobians: at most 3.9 (float64) and 1.5 (float32) measured; 3x3 products
DPS = 60  # digits of the references

# ----------------------------------------------------------------------------------------------
# High-precision references: mp.expm of hat(xi) (not the closed forms under test)
# ----------------------------------------------------------------------------------------------


def grid(dtype: torch.dtype) -> torch.Tensor:
    """Every angle with every sigma (a random axis and a random rho each), rounded to dtype."""
    g = torch.Generator().manual_seed(7)
    n = len(ANGLES) * len(SIGMAS)
    ax = torch.nn.functional.normalize(torch.randn(n, 3, generator=g, dtype=F64), dim=-1)
    rho = torch.randn(n, 3, generator=g, dtype=F64)
    th = torch.tensor([a for a in ANGLES for _ in SIGMAS], dtype=F64)
    sg = torch.tensor([s for _ in ANGLES for s in SIGMAS], dtype=F64)
    return torch.cat((rho, th[:, None] * ax, sg[:, None]), -1).to(dtype)


def _mhat(x) -> mp.matrix:
    r = [v if isinstance(v, mp.mpf) else mp.mpf(float(v)) for v in x]
    H = mp.zeros(4, 4)
    H[0, 1], H[0, 2], H[1, 2] = -r[5], r[4], -r[3]
    H[1, 0], H[2, 0], H[2, 1] = r[5], -r[4], r[3]
    for i in range(3):
        H[i, i] = r[6]
        H[i, 3] = r[i]
    return H


def _mvee(X) -> list:
    return [X[0, 3], X[1, 3], X[2, 3], (X[2, 1] - X[1, 2]) / 2, (X[0, 2] - X[2, 0]) / 2] + [
        (X[1, 0] - X[0, 1]) / 2,
        (X[0, 0] + X[1, 1] + X[2, 2]) / 3,
    ]


def _ad_np(x) -> np.ndarray:
    """ad(x) written out (float64)."""
    r, p, s = np.asarray(x[:3], float), np.asarray(x[3:6], float), float(x[6])

    def hat(v):
        return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])

    A = np.zeros((7, 7))
    A[:3, :3] = hat(p) + s * np.eye(3)
    A[:3, 3:6] = hat(r)
    A[:3, 6] = -r
    A[3:6, 3:6] = hat(p)
    return A


def _mp_jr(x) -> mp.matrix:
    """Jr(x) = int_0^1 expm(-s ad(x)) ds, the top-right block of expm([[-ad, I], [0, 0]])."""
    A = _ad_np([-float(v) for v in x])
    B = mp.zeros(14, 14)
    for i in range(7):
        for j in range(7):
            B[i, j] = mp.mpf(A[i, j])
        B[i, 7 + i] = 1
    E = mp.expm(B)
    return mp.matrix([[E[i, 7 + j] for j in range(7)] for i in range(7)])


def _projected(T: np.ndarray) -> mp.matrix:
    """``T`` with its linear block projected as log reads it: ``s = |M| / sqrt(3)``, the
    rotation ``polar(M / s)`` (Newton-Schulz)."""
    M = mp.matrix([[mp.mpf(float(T[i, j])) for j in range(3)] for i in range(3)])
    s = mp.sqrt(sum(M[i, j] ** 2 for i in range(3) for j in range(3)) / 3)
    R = M / s
    for _ in range(3):
        R = R * (3 * mp.eye(3) - R.T * R) / 2
    P = mp.eye(4)
    for i in range(3):
        for j in range(3):
            P[i, j] = s * R[i, j]
        P[i, 3] = mp.mpf(float(T[i, 3]))
    return P


def _mp_log(T: np.ndarray, start) -> list:
    """The exact log of the projected ``T`` nearest ``start``: two Newton steps
    ``x += Jr(x)^-1 vee(logm(expm(hat x)^-1 P))`` (the correction is of the order of rounding,
    so ``Jr^-1`` in float64 suffices)."""
    P = _projected(T)
    x = [mp.mpf(float(v)) for v in start]
    for _ in range(2):
        d = mp.matrix(_mvee(mp.logm(mp.inverse(mp.expm(_mhat(x))) * P)))
        A = _ad_np([-float(v) for v in x])
        Jr = scipy.linalg.expm(np.block([[A, np.eye(7)], [np.zeros((7, 14))]]))[:7, 7:]
        step = mp.matrix(np.linalg.inv(Jr).tolist()) * d
        x = [x[i] + step[i] for i in range(7)]
    return x


def _f64(rows) -> torch.Tensor:
    return torch.tensor(np.array(rows, dtype=object).astype(np.float64), dtype=F64)


_CACHE: dict[torch.dtype, dict[str, torch.Tensor]] = {}


def references(dtype: torch.dtype) -> dict[str, torch.Tensor]:
    """Inputs (rounded to ``dtype``) and references, computed once per session."""
    if dtype in _CACHE:
        return _CACHE[dtype]
    with mp.workdps(DPS):
        xi = grid(dtype)
        T_ref, G_ref, T_in, log_ref, J_ref, Jr_ref, Jri_ref = [], [], [], [], [], [], []
        for x in xi.double().numpy():
            E = mp.expm(_mhat(x))
            Jr = _mp_jr(x)
            T_ref.append(E.tolist())
            Jr_ref.append(Jr.tolist())
            Jri_ref.append((Jr**-1).tolist())
            # d Exp(x) / d x_k = Exp(x) hat(Jr(x) e_k)
            cols = [E * _mhat([Jr[i, k] for i in range(7)]) for k in range(7)]
            G_ref.append([[[cols[k][i, j] for k in range(7)] for j in range(4)] for i in range(4)])
        out = {"xi": xi, "T_ref": _f64(T_ref), "exp_grad_ref": _f64(G_ref)}
        out.update(jr_ref=_f64(Jr_ref), jr_inv_ref=_f64(Jri_ref))
        T_in = out["T_ref"].to(dtype)
        start = sim3.log(T_in.double())
        for T, s in zip(T_in.double().numpy(), start.numpy(), strict=True):
            x = _mp_log(T, s)
            log_ref.append(x)
            J_ref.append((_mp_jr(x) ** -1).tolist())
        out.update(T_in=T_in, log_ref=_f64(log_ref), log_grad_ref=_f64(J_ref))
    _CACHE[dtype] = out
    return out


def _ulp(out: torch.Tensor, ref: torch.Tensor, nd: int, dtype: torch.dtype) -> torch.Tensor:
    dims = tuple(range(-nd, 0))
    diff = (out.double() - ref).square().sum(dims).sqrt()
    scale = ref.square().sum(dims).sqrt()
    return torch.where(scale > 0, diff / torch.where(scale > 0, scale, 1.0), diff) / (
        torch.finfo(dtype).eps
    )


def _where(err: torch.Tensor, xi: torch.Tensor) -> str:
    i = int(err.argmax())
    x = xi[i].double()
    return f"{float(err[i]):.3g} ulp at theta={float(x[3:6].norm()):.17g}, sigma={float(x[6])}"


@pytest.mark.slow
def test_exp_values_and_gradients(dtype):
    r = references(dtype)
    err = _ulp(sim3.exp(r["xi"]), r["T_ref"], 2, dtype)
    assert float(err.max()) <= VALUE_ULP, _where(err, r["xi"])
    J = torch.func.vmap(torch.func.jacrev(sim3.exp))(r["xi"])
    assert bool(torch.isfinite(J).all())
    err = _ulp(J, r["exp_grad_ref"], 3, dtype)
    assert float(err.max()) <= GRAD_ULP, _where(err, r["xi"])
    # plain backward (no transform) agrees with the same reference
    x = r["xi"].clone().requires_grad_(True)
    G = torch.randn(x.shape[0], 4, 4, generator=torch.Generator().manual_seed(0), dtype=F64)
    (g,) = torch.autograd.grad(sim3.exp(x), x, G.to(dtype))
    err = _ulp(g, torch.einsum("nij,nijk->nk", G, r["exp_grad_ref"]), 1, dtype)
    assert float(err.max()) <= GRAD_ULP * 4, _where(err, r["xi"])  # a sum of 16 products


@pytest.mark.slow
def test_log_values_and_gradients(dtype):
    r = references(dtype)
    out = sim3.log(r["T_in"])
    assert bool((out[:, 3:6].norm(dim=-1) <= PI * (1 + 4 * torch.finfo(dtype).eps)).all())
    err = _ulp(out, r["log_ref"], 1, dtype)
    assert float(err.max()) <= VALUE_ULP, _where(err, r["xi"])
    # d/dd log(T Exp(d)) at d = 0 is Jr(log T)^-1 (finite at pi)
    d0 = torch.zeros(r["xi"].shape[0], 7, dtype=dtype)
    J = torch.func.vmap(torch.func.jacrev(lambda d, T: sim3.log(sim3.compose(T, sim3.exp(d)))))(
        d0, r["T_in"]
    )
    assert bool(torch.isfinite(J).all())
    err = _ulp(J, r["log_grad_ref"], 2, dtype)
    assert float(err.max()) <= GRAD_ULP, _where(err, r["xi"])


@pytest.mark.slow
def test_log_of_exp_over_the_grid(dtype):
    xi = grid(dtype)
    back = sim3.log(sim3.exp(xi))
    T1, T2 = sim3.exp(back.double()), sim3.exp(xi.double())
    err = _ulp(T1, T2, 2, dtype)  # at pi the axis may flip: compare the elements
    assert float(err.max()) <= 16, _where(err, xi)


def test_coefficients_at_their_limits():
    """V's coefficients at sigma = theta = 0 and at sigma = 0 (so3's Jl), both branches."""
    z = torch.zeros(3, dtype=F64)
    A, B, C = _coeffs.sim3_v(z, z)
    assert torch.equal(A, torch.ones(3, dtype=F64))
    assert torch.allclose(B, torch.full((3,), 0.5, dtype=F64), rtol=0, atol=1e-16)
    assert torch.allclose(C, torch.full((3,), 1 / 6, dtype=F64), rtol=0, atol=1e-16)
    ts = [0.3, 1.0, 3.0]
    t = torch.tensor(ts, dtype=F64)
    with mp.workdps(DPS):
        B_ref = [2 * mp.sin(mp.mpf(v) / 2) ** 2 / mp.mpf(v) ** 2 for v in ts]
        C_ref = [(mp.mpf(v) - mp.sin(mp.mpf(v))) / mp.mpf(v) ** 3 for v in ts]
        c_ref = [(1 - mp.mpf(v) / 2 / mp.tan(mp.mpf(v) / 2)) / mp.mpf(v) ** 2 for v in ts]
    A, B, C = _coeffs.sim3_v(torch.zeros(3, dtype=F64), t * t)
    assert torch.equal(A, torch.ones(3, dtype=F64))
    torch.testing.assert_close(B, _f64(B_ref), rtol=4e-16, atol=0)
    torch.testing.assert_close(C, _f64(C_ref), rtol=1.2e-15, atol=0)
    # a, b, c of V^-1 at sigma = 0 are so3's Jl^-1 coefficients
    a, b, c = _coeffs.sim3_v_inv(torch.zeros(3, dtype=F64), t * t)
    torch.testing.assert_close(b, torch.full((3,), -0.5, dtype=F64), rtol=4e-16, atol=0)
    torch.testing.assert_close(c, _f64(c_ref), rtol=2e-15, atol=0)


def _mp_abc(s, t2) -> tuple:
    """``(A, B, C)`` of V from ``E1(z)``, ``z = sigma + i theta`` (at nonzero arguments)."""
    t = mp.sqrt(t2)
    z = mp.mpc(s, t)
    E = (mp.exp(z) - 1) / z
    A = mp.expm1(s) / s
    return A, E.imag / t, (A - E.real) / t2


def test_coefficient_partials_against_mpmath():
    """``_coeffs.sim3_v_partials``: exact limits at ``sigma = theta = 0`` and relative errors
    below 1e-12 of the 60-digit derivatives of ``E1``'s coefficients (mp.diff) inside, at and
    outside the border of the joint series (the closed forms of ``C_t`` lose up to about 10
    bits just outside it, where they enter ``Jl`` multiplied by ``theta^3``)."""
    z = torch.zeros((), dtype=F64)
    got = [float(v) for v in _coeffs.sim3_v_partials(z, z)]
    assert got == pytest.approx(
        [1, 1 / 2, 1 / 6, 1 / 2, 1 / 3, 1 / 8, -1 / 24, -1 / 120], rel=1e-15
    )
    for s, th in ((0.3, 0.2), (0.49, 0.1), (0.51, 1e-4), (-0.6, 0.3), (1e-9, 1.0), (20.0, 1e-8)):
        out = _coeffs.sim3_v_partials(torch.tensor(s, dtype=F64), torch.tensor(th * th, dtype=F64))
        with mp.workdps(40):
            sm, tm = mp.mpf(s), mp.mpf(th) ** 2
            ref = [*_mp_abc(sm, tm)]
            ref += [mp.diff(lambda x, k=k, tm=tm: _mp_abc(x, tm)[k], sm) for k in range(3)]
            ref += [mp.diff(lambda x, k=k, sm=sm: _mp_abc(sm, x)[k], tm) for k in (1, 2)]
        for o, r in zip(out, ref, strict=True):
            assert float(o) == pytest.approx(float(r), rel=1e-12), (s, th)


def test_sigma_zero_is_se3(dtype):
    xi = grid(dtype)[::7]
    T = sim3.exp(torch.cat((xi[:, :6], torch.zeros_like(xi[:, 6:])), -1))
    torch.testing.assert_close(T, se3.exp(xi[:, :6]), rtol=0, atol=8 * torch.finfo(dtype).eps)


# ----------------------------------------------------------------------------------------------
# Jacobians against high-precision finite differences of their definitions
# ----------------------------------------------------------------------------------------------

JAC_POINTS = [
    [0.3, -1.0, 2.0, 0.1, 0.2, -0.3, 0.5],
    [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    [0.5, 0.5, -1.0, 0.0, PI - 1e-3, 0.0, -3.0],
    [-1.0, 2.0, 0.5, 1.0, 1.0, 1.0, 0.0],
    [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
]


def _fd_jacobian(f, x) -> list:
    """Central differences at 60 digits (step 1e-18: truncation O(h^2) below 1e-30)."""
    h = mp.mpf("1e-18")
    cols = []
    for k in range(7):
        e = [mp.mpf(0)] * 7
        e[k] = h
        a = f([x[i] + e[i] for i in range(7)])
        b = f([x[i] - e[i] for i in range(7)])
        cols.append([(a[i] - b[i]) / (2 * h) for i in range(7)])
    return [[cols[k][i] for k in range(7)] for i in range(7)]


@pytest.mark.parametrize("x", JAC_POINTS)
def test_jac_left_and_right_against_finite_differences(x):
    with mp.workdps(DPS):
        xm = [mp.mpf(v) for v in x]
        E = mp.expm(_mhat(xm))
        Ei = mp.inverse(E)
        # Exp(x + d) = Exp(Jl d) Exp(x) = Exp(x) Exp(Jr d)
        Jl = _fd_jacobian(lambda y: _mvee(mp.logm(mp.expm(_mhat(y)) * Ei)), xm)
        Jr = _fd_jacobian(lambda y: _mvee(mp.logm(Ei * mp.expm(_mhat(y)))), xm)
    xi = torch.tensor(x, dtype=F64)
    for out, ref in ((sim3.jac_left(xi), Jl), (sim3.jac_right(xi), Jr)):
        torch.testing.assert_close(
            out, _f64(ref), rtol=0, atol=1e-13 * (1 + float(_f64(ref).abs().max()))
        )
    eye = torch.eye(7, dtype=F64)
    torch.testing.assert_close(sim3.jac_left_inv(xi) @ sim3.jac_left(xi), eye, rtol=0, atol=1e-13)
    torch.testing.assert_close(sim3.jac_right_inv(xi) @ sim3.jac_right(xi), eye, rtol=0, atol=1e-13)
    torch.testing.assert_close(
        sim3.jac_left(xi), sim3.adjoint(sim3.exp(xi)) @ sim3.jac_right(xi), rtol=0, atol=1e-13
    )


@pytest.mark.slow
def test_jacobians_over_the_grid(dtype):
    """The closed forms of jac_left/right and their inverses at every angle and sigma of the
    grid, against the 60-digit integral ``int_0^1 expm(-s ad) ds`` (``Jl(x) = Jr(-x)``):
    within VALUE_ULP relative to the matrix norm, in the dtype of the input."""
    r = references(dtype)
    xi = r["xi"]
    for out, ref in (
        (sim3.jac_right(xi), r["jr_ref"]),
        (sim3.jac_left(-xi), r["jr_ref"]),
        (sim3.jac_right_inv(xi), r["jr_inv_ref"]),
        (sim3.jac_left_inv(-xi), r["jr_inv_ref"]),
    ):
        assert out.dtype == dtype
        err = _ulp(out, ref, 2, dtype)
        assert float(err.max()) <= JAC_ULP, _where(err, xi)


@pytest.mark.slow
def test_jacobians_around_the_joint_series(dtype):
    """Random points with ``|sigma + i theta|`` in ``[0, 1]``, across the border of the series
    of the coupling coefficients, against the 60-digit integral (within JAC_ULP)."""
    g = torch.Generator().manual_seed(11)
    n = 32
    r = torch.rand(n, generator=g, dtype=F64)
    a = torch.rand(n, generator=g, dtype=F64) * PI
    ax = torch.nn.functional.normalize(torch.randn(n, 3, generator=g, dtype=F64), dim=-1)
    rho = torch.randn(n, 3, generator=g, dtype=F64)
    xi = torch.cat((rho, (r * a.sin())[:, None] * ax, (r * a.cos())[:, None]), -1).to(dtype)
    with mp.workdps(DPS):
        jr = [_mp_jr(x) for x in xi.double().numpy()]
        ref, ref_inv = _f64([j.tolist() for j in jr]), _f64([(j**-1).tolist() for j in jr])
    for out, want in ((sim3.jac_right(xi), ref), (sim3.jac_right_inv(xi), ref_inv)):
        err = _ulp(out, want, 2, dtype)
        assert float(err.max()) <= JAC_ULP, _where(err, xi)


def test_jacobian_rotation_coupling_at_large_scale():
    """The rotation coupling of the Jacobians (rows rho, columns phi) at large ``sigma`` and
    ``|rho| = 1e3``, where it dominates the matrix: jac_left, jac_left_inv and jac_right (at
    ``-sigma``) within 8 ulp of the largest entry of 60-digit references (6 measured, in the
    inverse: three 3x3 products), and the coupling block within 8 ulp of its own largest entry
    (6 measured).  Its difference form cancelled by about ``sigma``: 250 ulp of the largest
    entry at sigma = 80."""
    g = torch.Generator().manual_seed(13)
    worst = [0.0, 0.0]
    for sg in (1.0, 3.0, 20.0, 80.0):
        for th in (1e-3, 1.0, 3.0, PI - 1e-8):
            ax = torch.nn.functional.normalize(torch.randn(3, generator=g, dtype=F64), dim=0)
            rho = torch.nn.functional.normalize(torch.randn(3, generator=g, dtype=F64), dim=0)
            xi = torch.cat((1e3 * rho, th * ax, torch.tensor([sg], dtype=F64)))
            with mp.workdps(DPS):
                jl = _mp_jr(-xi.numpy())
                ref, ref_inv = _f64(jl.tolist()), _f64((jl**-1).tolist())
            for out, want in (
                (sim3.jac_left(xi), ref),
                (sim3.jac_right(-xi), ref),
                (sim3.jac_left_inv(xi), ref_inv),
            ):
                err = (out - want).abs()
                ulp = torch.finfo(F64).eps * 2.0 ** math.floor(math.log2(float(want.abs().max())))
                q = 2.0 ** math.floor(math.log2(float(want[:3, 3:6].abs().max())))
                worst[0] = max(worst[0], float(err.max()) / ulp)
                worst[1] = max(worst[1], float(err[:3, 3:6].max()) / (torch.finfo(F64).eps * q))
    assert max(worst) <= 2 * VALUE_ULP, worst


def test_jac_left_blocks():
    """The rho block is V of exp, the phi block so3's Jl, sigma's column has 1 at the bottom."""
    xi = torch.tensor(JAC_POINTS[0], dtype=F64)
    J = sim3.jac_left(xi)
    rho_unit = torch.eye(3, dtype=F64)
    V = torch.stack([sim3.exp(torch.cat((e, xi[3:]))).mT[3, :3] for e in rho_unit], -1)
    torch.testing.assert_close(J[:3, :3], V, rtol=0, atol=1e-14)
    torch.testing.assert_close(J[3:6, 3:6], so3.jac_left(xi[3:6]), rtol=0, atol=1e-14)
    assert float(J[6, 6]) == pytest.approx(1.0, abs=1e-15)
    assert float(J[6, :6].abs().max()) < 1e-15 and float(J[3:6, 6].abs().max()) < 1e-15


def test_adjoint_and_ad(dtype):
    g = torch.Generator().manual_seed(3)
    T = sim3.random(5, generator=g, dtype=F64)
    x = torch.randn(5, 7, generator=g, dtype=F64)
    y = torch.randn(5, 7, generator=g, dtype=F64)
    # T hat(x) T^-1 = hat(Ad_T x), exactly (a linear identity)
    lhs = T @ sim3.hat(x) @ torch.linalg.inv(T)
    torch.testing.assert_close(lhs, sim3.hat((sim3.adjoint(T) @ x[..., None])[..., 0]))
    # ad(x) y is the bracket; adjoint(exp(x)) = matrix_exp(ad(x))
    X, Y = sim3.hat(x), sim3.hat(y)
    br = sim3.vee(X @ Y - Y @ X)
    torch.testing.assert_close((sim3.ad(x) @ y[..., None])[..., 0], br)
    torch.testing.assert_close(sim3.adjoint(sim3.exp(x)), torch.linalg.matrix_exp(sim3.ad(x)))
    Td = T.to(dtype)
    assert sim3.adjoint(Td).dtype == dtype


def _tangent_fd(f, X, h=1e-6):
    """d/dd Log(f(X)^-1 f(X Exp(d))) at 0, central differences in float64 (``X`` a tuple of
    arguments, the first perturbed on the right if it is an element, additively if a vector)."""
    Y = f(*X)
    cols = []
    for k in range(7 if X[0].shape[-1] == 4 else X[0].shape[-1]):
        outs = []
        for s in (h, -h):
            if X[0].shape[-1] == 4:
                d = torch.zeros(7, dtype=F64)
                d[k] = s
                a = sim3.compose(X[0], sim3.exp(d))
            else:
                a = X[0].clone()
                a[k] += s
            Z = f(a, *X[1:])
            outs.append(sim3.log(sim3.between(Y, Z)) if Z.shape[-1] == 4 else Z)
        cols.append((outs[0] - outs[1]) / (2 * h))
    return torch.stack(cols, -1)


def test_operation_jacobians_against_finite_differences():
    g = torch.Generator().manual_seed(5)
    A, B = sim3.random(2, generator=g, dtype=F64)
    xi = torch.tensor(JAC_POINTS[0], dtype=F64)
    p = torch.tensor([0.3, -0.7, 1.1], dtype=F64)
    tol = {"rtol": 0, "atol": 1e-7}
    J1, J2 = sim3.jac_compose(A, B)
    torch.testing.assert_close(J1, _tangent_fd(sim3.compose, (A, B)), **tol)
    torch.testing.assert_close(J2, _tangent_fd(lambda b, a: sim3.compose(a, b), (B, A)), **tol)
    torch.testing.assert_close(sim3.jac_inverse(A), _tangent_fd(sim3.inverse, (A,)), **tol)
    JT, Jp = sim3.jac_act(A, p)
    torch.testing.assert_close(JT, _tangent_fd(sim3.act, (A, p)), **tol)
    torch.testing.assert_close(Jp, _tangent_fd(lambda q, a: sim3.act(a, q), (p, A)), **tol)
    JT, Jx = sim3.jac_rplus(A, xi)
    torch.testing.assert_close(JT, _tangent_fd(sim3.rplus, (A, xi)), **tol)
    torch.testing.assert_close(Jx, _tangent_fd(lambda x, a: sim3.rplus(a, x), (xi, A)), **tol)
    J1, J0 = sim3.jac_rminus(A, B)
    torch.testing.assert_close(J1, _tangent_fd(sim3.rminus, (A, B)), **tol)
    torch.testing.assert_close(J0, _tangent_fd(lambda b, a: sim3.rminus(a, b), (B, A)), **tol)
    J0, J1 = sim3.jac_between(A, B)
    torch.testing.assert_close(J0, _tangent_fd(sim3.between, (A, B)), **tol)
    torch.testing.assert_close(J1, _tangent_fd(lambda b, a: sim3.between(a, b), (B, A)), **tol)


# ----------------------------------------------------------------------------------------------
# Group axioms, conversions, metrics
# ----------------------------------------------------------------------------------------------


def test_group_axioms_on_batches(dtype):
    g = torch.Generator().manual_seed(11)
    A, B, C = (sim3.random(4, 3, generator=g, dtype=dtype) for _ in range(3))
    tol = {
        "rtol": 64 * torch.finfo(dtype).eps,
        "atol": 64 * torch.finfo(dtype).eps,
    }  # chains of ops
    close = lambda x, y: torch.testing.assert_close(x, y, **tol)  # noqa: E731
    close(sim3.compose(sim3.compose(A, B), C), sim3.compose(A, sim3.compose(B, C)))
    I = sim3.identity(4, 3, dtype=dtype)
    close(sim3.compose(A, I), A)
    close(sim3.compose(I, A), A)
    close(sim3.compose(A, sim3.inverse(A)), I)
    close(sim3.compose(sim3.inverse(A), A), I)
    close(sim3.compose(A, B), A @ B)
    p = torch.randn(4, 3, 3, generator=g, dtype=dtype)
    close(sim3.act(sim3.compose(A, B), p), sim3.act(A, sim3.act(B, p)))
    close(
        sim3.act(A, p), (A @ torch.nn.functional.pad(p, (0, 1), value=1.0)[..., None])[..., :3, 0]
    )
    close(sim3.between(A, B), sim3.compose(sim3.inverse(A), B))
    x = sim3.log(sim3.between(A, B))
    close(sim3.rplus(A, x), B)
    close(sim3.rminus(B, A), x)
    close(sim3.lplus(A, sim3.lminus(B, A)), B)
    close(sim3.interpolate(A, B, 0.0), A)
    close(sim3.interpolate(A, B, 1.0), B)
    assert bool(
        sim3.is_valid(sim3.compose(A, B), atol=1e-4 if dtype == torch.float32 else None).all()
    )


def test_exp_is_matrix_exp_and_log_inverts(dtype):
    g = torch.Generator().manual_seed(2)
    xi = torch.randn(50, 7, generator=g, dtype=F64)
    xi[:, 3:6] = (
        torch.nn.functional.normalize(xi[:, 3:6], dim=-1)
        * torch.rand(50, 1, generator=g, dtype=F64)
        * 3
    )
    tol = 16 * torch.finfo(dtype).eps
    T = sim3.exp(xi.to(dtype))
    torch.testing.assert_close(
        T.double(), torch.linalg.matrix_exp(sim3.hat(xi)), rtol=tol, atol=tol
    )
    torch.testing.assert_close(sim3.log(T).double(), xi, rtol=100 * tol, atol=100 * tol)


def test_converters(dtype):
    g = torch.Generator().manual_seed(4)
    s = torch.rand(6, generator=g, dtype=dtype) + 0.5
    R = so3.random(6, generator=g, dtype=dtype)
    t = torch.randn(6, 3, generator=g, dtype=dtype)
    T = sim3.from_srt(s, R, t)
    s2, R2, t2 = sim3.to_srt(T)
    tol = {"rtol": 8 * torch.finfo(dtype).eps, "atol": 8 * torch.finfo(dtype).eps}
    torch.testing.assert_close(s2, s, **tol)
    torch.testing.assert_close(R2, R, **tol)
    assert torch.equal(t2, t)
    torch.testing.assert_close(sim3.scale(T), s, **tol)
    torch.testing.assert_close(sim3.from_se3(se3.from_rt(R, t), s), T, **tol)
    xi = sim3.log(T)
    torch.testing.assert_close(torch.exp(xi[:, 6]), s, **tol)
    assert bool(sim3.is_valid(T, atol=1e-4).all())
    # broadcasting: one scale for a batch
    assert sim3.from_srt(s[0], R, t).shape == (6, 4, 4)


def test_pos_quat_scale(dtype):
    """``(t, q, s)`` 8-vectors: the similarity of ``from_srt(s, to_matrix(q), t)`` for any
    nonzero ``q``; back to the canonical unit quaternion (``w >= 0``); a zero quaternion spoils
    only its element's linear block."""
    g = torch.Generator().manual_seed(5)
    t = torch.randn(7, 3, generator=g, dtype=dtype)
    q = torch.randn(7, 4, generator=g, dtype=dtype) * 3.0
    s = torch.rand(7, generator=g, dtype=dtype) * 4.0 + 0.1
    x = torch.cat((t, q, s[:, None]), -1)
    T = sim3.from_pos_quat_scale(x)
    eps = torch.finfo(dtype).eps
    tol = {"rtol": 8 * eps, "atol": 8 * eps}
    torch.testing.assert_close(T, sim3.from_srt(s, quaternion.to_matrix(q), t), **tol)
    y = sim3.to_pos_quat_scale(T)
    unit = quaternion.canonicalize(q / q.norm(dim=-1, keepdim=True))
    torch.testing.assert_close(y, torch.cat((t, unit, s[:, None]), -1), **tol)
    X = Sim3.from_pos_quat_scale(torch.cat((t, unit, s[:, None]), -1), check=True)
    assert torch.equal(X.pos_quat_scale(), sim3.to_pos_quat_scale(X.tensor))
    x[2, 3:7] = 0.0
    T0 = sim3.from_pos_quat_scale(x)
    assert T0[2, :3, :3].isnan().all() and torch.equal(T0[2, :3, 3], t[2])
    assert torch.equal(T0[[0, 1, 3, 4, 5, 6]], T[[0, 1, 3, 4, 5, 6]])
    with pytest.raises(ValueError, match=r"torchlie\.Sim3\.from_pos_quat_scale: .* unit quat"):
        Sim3.from_pos_quat_scale(x, check=True)
    one = torch.tensor([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0], dtype=dtype)
    with pytest.raises(ValueError, match=r"torchlie\.Sim3\.from_pos_quat_scale: .* positive"):
        Sim3.from_pos_quat_scale(one, check=True)


def test_is_valid_per_element():
    T = sim3.identity(5, dtype=F64)
    T[1, 3, 0] = 1.0  # bottom row
    T[2, :3, :3] = torch.diag(torch.tensor([1.0, 2.0, 1.0], dtype=F64))  # not a scaled rotation
    T[3, :3, :3] = -torch.eye(3, dtype=F64)  # a reflection
    T[4, 0, 3] = float("nan")
    assert sim3.is_valid(T).tolist() == [True, False, False, False, False]


def test_distance():
    R = so3.exp(torch.tensor([0.0, 0.0, 2.0], dtype=F64))
    T1 = sim3.from_srt(
        torch.tensor(3.0, dtype=F64), torch.eye(3, dtype=F64), torch.zeros(3, dtype=F64)
    )
    T2 = sim3.from_srt(torch.tensor(0.5, dtype=F64), R, torch.tensor([3.0, 4.0, 0.0], dtype=F64))
    a, t, s = sim3.distance(T1, T2)
    assert float(a) == pytest.approx(2.0, abs=1e-15)
    assert float(t) == pytest.approx(5.0, abs=1e-15)
    assert float(s) == pytest.approx(math.log(6.0), abs=1e-15)
    T = T1.clone().requires_grad_(True)
    sum(sim3.distance(T, T1)).backward()
    assert bool(torch.isfinite(T.grad).all())


def test_literal_values():
    """A pure scaling, a pure translation, and the translation of a rotation with scale."""
    T = sim3.exp(torch.tensor([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, math.log(2.0)], dtype=F64))
    torch.testing.assert_close(T, torch.diag(torch.tensor([2.0, 2.0, 2.0, 1.0], dtype=F64)))
    T = sim3.exp(torch.tensor([1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 0.0], dtype=F64))
    assert T[:3, 3].tolist() == [1.0, 2.0, 3.0]
    # rho along the axis: V rho = A rho = (e^sigma - 1)/sigma rho
    T = sim3.exp(torch.tensor([0.0, 0.0, 1.0, 0.0, 0.0, 0.7, 0.5], dtype=F64))
    assert float(T[2, 3]) == pytest.approx(math.expm1(0.5) / 0.5, rel=1e-15)


# ----------------------------------------------------------------------------------------------
# Gradients: gradcheck, finiteness, the projected gradient of log
# ----------------------------------------------------------------------------------------------

GRAD_XI = [
    [0.3, -1.0, 2.0, 0.0, 0.0, 0.0, 0.0],
    [0.3, -1.0, 2.0, 1e-8, 0.0, 0.0, 1e-9],
    [0.3, -1.0, 2.0, 0.4, 0.5, -0.2, 0.7],
    [0.3, -1.0, 2.0, 0.0, PI - 1e-3, 0.0, -1.0],
    [0.3, -1.0, 2.0, 0.3, 0.3, 0.3, 3.0],
]


@pytest.mark.parametrize("x", GRAD_XI)
def test_gradcheck_exp_log(x):
    xi = torch.tensor(x, dtype=F64, requires_grad=True)
    assert gradcheck(sim3.exp, (xi,))
    assert gradgradcheck(sim3.exp, (xi,))
    T = sim3.exp(xi.detach()).requires_grad_(True)
    assert gradcheck(sim3.log, (T,))
    assert gradgradcheck(sim3.log, (T,))
    # in tangent coordinates
    d = torch.zeros(7, dtype=F64, requires_grad=True)
    assert gradcheck(lambda d: sim3.log(sim3.compose(T.detach(), sim3.exp(d))), (d,))


@pytest.mark.parametrize("x", [*GRAD_XI, [0.3, -1.0, 2.0, 0.1, -0.2, 0.3, 0.4]])
def test_gradcheck_jacobians(x):
    """First and second derivatives of the closed forms, inside the joint series (last point)
    and on both sides of it."""
    xi = torch.tensor(x, dtype=F64, requires_grad=True)
    assert gradcheck(sim3.jac_left, (xi,))
    assert gradcheck(sim3.jac_left_inv, (xi,))
    if x[6] in (0.4, 0.7):  # second derivatives: inside the series and just outside
        assert gradgradcheck(sim3.jac_left, (xi,))


def test_gradcheck_group_ops():
    g = torch.Generator().manual_seed(9)
    A, B = sim3.random(2, 2, generator=g, dtype=F64).requires_grad_(True)
    p = torch.randn(2, 3, generator=g, dtype=F64, requires_grad=True)
    t = torch.tensor([0.3, 0.8], dtype=F64, requires_grad=True)
    for fn, args in (
        (sim3.compose, (A, B)),
        (sim3.inverse, (A,)),
        (sim3.act, (A, p)),
        (sim3.between, (A, B)),
        (sim3.interpolate, (A, B, t)),
        (sim3.rminus, (A, B)),
        (sim3.adjoint, (A,)),
        (lambda x: sim3.jac_left(x), (torch.tensor(JAC_POINTS[0], dtype=F64, requires_grad=True),)),
    ):
        assert gradcheck(fn, args), fn


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_gradients_finite_over_the_grid(dtype):
    xi = grid(dtype).requires_grad_(True)
    T = sim3.exp(xi)
    (g,) = torch.autograd.grad(T.sum() + sim3.log(T).sum(), xi)
    assert bool(torch.isfinite(g).all())
    Tl = sim3.exp(grid(dtype)).requires_grad_(True)
    (g,) = torch.autograd.grad(sim3.log(Tl).square().sum(), Tl)
    assert bool(torch.isfinite(g).all())


def test_log_gradient_is_the_projected_gradient():
    """Along M S (S symmetric, traceless) the derivative is 0; along T hat(d) it is Jr^-1 d."""
    xi = torch.tensor(JAC_POINTS[2], dtype=F64)
    T = sim3.exp(xi)
    S = torch.tensor([[1.0, 2.0, 0.0], [2.0, -3.0, 1.0], [0.0, 1.0, 2.0]], dtype=F64)
    dT = torch.zeros(4, 4, dtype=F64)
    dT[:3, :3] = T[:3, :3] @ S
    _, jvp = torch.func.jvp(sim3.log, (T,), (dT,))
    assert float(jvp.abs().max()) < 1e-12
    d = torch.tensor([0.1, -0.2, 0.3, 0.4, -0.5, 0.6, -0.7], dtype=F64)
    _, jvp = torch.func.jvp(sim3.log, (T,), (T @ sim3.hat(d),))
    torch.testing.assert_close(jvp, sim3.jac_right_inv(xi) @ d)


# ----------------------------------------------------------------------------------------------
# Batching, dtypes, bad input, transforms
# ----------------------------------------------------------------------------------------------


def test_batch_shapes_and_half(batch, dtype):
    g = torch.Generator().manual_seed(1)
    xi = torch.randn(*batch, 7, generator=g, dtype=dtype)
    T = sim3.exp(xi)
    assert T.shape == (*batch, 4, 4) and T.dtype == dtype
    assert sim3.log(T).shape == (*batch, 7)
    assert sim3.jac_left(xi).shape == (*batch, 7, 7)
    h = sim3.exp(xi.half())
    assert h.dtype == torch.float16
    torch.testing.assert_close(h.float(), sim3.exp(xi.half().float()).half().float())


def test_large_batch_in_blocks_matches_small():
    from torchlie import _autograd

    xi = grid(F64).repeat(2 * _autograd.BLOCK // 48 + 1, 1)
    big = sim3.exp(xi)
    assert_agree(sim3.exp(xi[:95]), big[:95], "the first 95 rows alone and in the blocks")


def test_nan_stays_in_its_element(dtype):
    xi = grid(dtype)[:6].clone()
    xi[2, 4] = float("nan")
    x = xi.clone().requires_grad_(True)
    T = sim3.exp(x)
    (g,) = torch.autograd.grad(T.sum(), x)
    rows = torch.arange(6) != 2
    assert bool(torch.isfinite(T[rows]).all()) and bool(torch.isfinite(g[rows]).all())
    L = sim3.log(sim3.exp(xi))
    assert bool(torch.isfinite(L[rows]).all()) and bool(torch.isnan(L[2]).any())
    for fn in (sim3.jac_left, sim3.jac_left_inv):
        J = fn(x)
        (g,) = torch.autograd.grad(J.sum(), x)
        assert bool(torch.isfinite(J[rows]).all()) and bool(torch.isfinite(g[rows]).all())
        assert bool(torch.isnan(J[2]).any())


@pytest.mark.parametrize(
    ("fn", "args", "match"),
    [
        (sim3.exp, (torch.zeros(6),), r"torchlie\.sim3\.exp: expected xi of shape \(\.\.\., 7\)"),
        (sim3.log, (torch.zeros(3, 3),), r"torchlie\.sim3\.log: expected T of shape"),
        (sim3.hat, (torch.zeros(2, 6),), r"torchlie\.sim3\.hat"),
        (sim3.act, (torch.eye(4), torch.zeros(4)), r"torchlie\.sim3\.act: expected points"),
        (sim3.compose, (torch.eye(4).expand(2, 4, 4), torch.eye(4).expand(3, 4, 4)), "broadcast"),
        (sim3.jac_left, (torch.zeros(3, 6),), r"torchlie\.sim3\.jac_left"),
    ],
)
def test_bad_shapes_raise_value_error(fn, args, match):
    with pytest.raises(ValueError, match=match):
        fn(*args)


def test_bad_types_raise_type_error():
    with pytest.raises(TypeError, match=r"torchlie\.sim3\.exp: expected xi to be a floating"):
        sim3.exp(torch.zeros(7, dtype=torch.int64))
    with pytest.raises(TypeError, match=r"torchlie\.sim3\.compose: expected inputs of one dtype"):
        sim3.compose(torch.eye(4), torch.eye(4, dtype=F64))
    with pytest.raises(TypeError, match=r"torchlie\.sim3\.log: expected T to be a torch\.Tensor"):
        sim3.log([[1.0]])
    with pytest.raises(TypeError, match=r"torchlie\.sim3\.random"):
        sim3.random(2, dtype=torch.int32)


def test_vmap_and_forward_mode():
    xi = grid(F64)[:10]
    J = torch.func.vmap(torch.func.jacfwd(sim3.exp))(xi)
    Jr = torch.func.vmap(torch.func.jacrev(sim3.exp))(xi)
    torch.testing.assert_close(J, Jr)
    T = sim3.exp(xi)
    Jl = torch.func.vmap(torch.func.jacfwd(sim3.log))(T)
    Jlr = torch.func.vmap(torch.func.jacrev(sim3.log))(T)
    torch.testing.assert_close(Jl, Jlr)
    out = torch.func.vmap(sim3.compose)(T, T)
    torch.testing.assert_close(out, T @ T)
    torch.testing.assert_close(torch.func.vmap(sim3.jac_left)(xi), sim3.jac_left(xi))


@pytest.mark.compile
def test_compile_fullgraph_matches_eager():
    xi = grid(F64)[:12]
    T = sim3.exp(xi)
    for fn, args in ((sim3.exp, (xi,)), (sim3.log, (T,)), (sim3.jac_left, (xi,))):
        c = torch.compile(fn, fullgraph=True)
        torch.testing.assert_close(c(*args), fn(*args), rtol=1e-13, atol=1e-13)


# ----------------------------------------------------------------------------------------------
# PyPose's Sim3
# ----------------------------------------------------------------------------------------------


def test_against_pypose_sim3():
    """PyPose's Sim3 stores ``(t, q_xyzw, s)`` and its sim3 tangent is ``(rho, phi, sigma)``
    in torchlie's order; its ``Exp``/``Log`` are the group exponential and logarithm."""
    pp = pytest.importorskip("pypose")
    g = torch.Generator().manual_seed(6)
    xi = torch.randn(20, 7, generator=g, dtype=F64)
    T = sim3.exp(xi)
    ours = pp.sim3(xi).Exp()
    s, R, t = sim3.to_srt(T)
    q = quaternion.to_xyzw(quaternion.from_matrix(R))
    theirs = ours.tensor()
    x = torch.cat((theirs[:, :3], quaternion.from_xyzw(theirs[:, 3:7]), theirs[:, 7:]), -1)
    torch.testing.assert_close(sim3.from_pos_quat_scale(x), T, rtol=1e-10, atol=1e-10)
    torch.testing.assert_close(theirs[:, :3], t, rtol=1e-10, atol=1e-10)
    # quaternions up to sign
    sign = torch.sign((theirs[:, 3:7] * q).sum(-1, keepdim=True))
    torch.testing.assert_close(theirs[:, 3:7] * sign, q, rtol=1e-10, atol=1e-10)
    torch.testing.assert_close(theirs[:, 7], s, rtol=1e-10, atol=1e-10)
    torch.testing.assert_close(ours.matrix(), T, rtol=1e-10, atol=1e-10)
    torch.testing.assert_close(pp.mat2Sim3(T).Log().tensor(), sim3.log(T), rtol=1e-8, atol=1e-8)
    p = torch.randn(20, 3, generator=g, dtype=F64)
    torch.testing.assert_close(ours.Act(p), sim3.act(T, p), rtol=1e-10, atol=1e-10)


# ----------------------------------------------------------------------------------------------
# The class
# ----------------------------------------------------------------------------------------------


def test_sim3_class_accessors_and_converters(batch):
    from torchlie import SE3, SO3

    g = torch.Generator().manual_seed(8)
    s = torch.rand(tuple(batch), generator=g, dtype=F64) + 0.5
    R = so3.random(*batch, generator=g, dtype=F64)
    t = torch.randn(*batch, 3, generator=g, dtype=F64)
    X = Sim3.from_srt(s, SO3(R), t)
    assert torch.equal(X.tensor, sim3.from_srt(s, R, t))
    torch.testing.assert_close(X.scale, s)
    torch.testing.assert_close(X.rotation.tensor, R)
    assert torch.equal(X.translation, t)
    assert isinstance(X.rotation, SO3) and isinstance(X.pose(), SE3)
    torch.testing.assert_close(X.pose().tensor, se3.from_rt(R, t))
    torch.testing.assert_close(Sim3.from_se3(X.pose(), s).tensor, X.tensor)
    torch.testing.assert_close(X.quaternion(), quaternion.from_matrix(R))
    for u, v in zip(X.to_srt(), sim3.to_srt(X.tensor), strict=True):
        assert torch.equal(u, v)
    p = torch.randn(*batch, 3, generator=g, dtype=F64)
    torch.testing.assert_close(X @ p, s[..., None] * (R @ p[..., None])[..., 0] + t)
    assert X.log().shape == (*batch, 7)
    with pytest.raises(ValueError, match=r"torchlie\.Sim3\.from_srt: .* positive scales"):
        Sim3.from_srt(-torch.ones(()), torch.eye(3), torch.zeros(3), check=True)
    with pytest.raises(TypeError, match=r"torchlie\.Sim3\.compose: expected another Sim3"):
        X.compose(SE3.identity())
    with pytest.raises(ValueError, match=r"torchlie\.Sim3\.exp \(through torchlie\.sim3\.exp\)"):
        Sim3.exp(torch.zeros(6))


# ----------------------------------------------------------------------------------------------
# statistics: alignment as a Sim3, the Sim(3) mean
# ----------------------------------------------------------------------------------------------


def test_align_with_scale_gives_the_similarity():
    from torchlie import statistics

    g = torch.Generator().manual_seed(12)
    T = sim3.random(3, generator=g, dtype=F64)
    P = torch.randn(3, 10, 3, generator=g, dtype=F64)
    Q = sim3.act(T[:, None], P)
    fit = statistics.align(P, Q, scale=True)
    torch.testing.assert_close(fit.matrix(), T)
    S = fit.sim3()
    assert isinstance(S, Sim3)
    torch.testing.assert_close(sim3.act(S.matrix[:, None], P), Q)
    torch.testing.assert_close(S.scale, fit.scale)  # the fields are unchanged
    rigid = statistics.align(P, Q).matrix()  # without scale: a Sim(3) element of scale 1
    torch.testing.assert_close(sim3.scale(rigid), torch.ones(3, dtype=F64))


def test_sim3_mean():
    from torchlie import statistics

    g = torch.Generator().manual_seed(13)
    M0 = sim3.random(2, generator=g, dtype=F64)
    xi = 0.3 * torch.randn(2, 6, 7, generator=g, dtype=F64)
    T = sim3.rplus(M0[:, None], xi)
    # chordal: the geometric mean of the scales (stationarity and invariance of the geodesic
    # mean: tests/test_statistics.py, every group)
    Mc = statistics.sim3_mean(T, method="chordal")
    torch.testing.assert_close(sim3.scale(Mc), sim3.scale(T).log().mean(-1).exp())
    with pytest.raises(ValueError, match=r"torchlie\.statistics\.sim3_mean"):
        statistics.sim3_mean(T[0, 0])


# ----------------------------------------------------------------------------------------------
# nn: loss and parametrization
# ----------------------------------------------------------------------------------------------


def test_sim3_geodesic_loss():
    from torchlie import nn as tnn

    R = so3.exp(torch.tensor([0.0, 0.0, 0.5], dtype=F64))
    A = sim3.from_srt(torch.tensor(2.0, dtype=F64), R, torch.tensor([3.0, 4.0, 0.0], dtype=F64))
    B = sim3.identity(dtype=F64)
    loss = tnn.sim3_geodesic_loss(A, B, 2.0, 0.5, 3.0)
    assert float(loss) == pytest.approx(2 * 0.5 + 0.5 * 5 + 3 * math.log(2.0), rel=1e-14)
    ch = tnn.sim3_geodesic_loss(A, B, kind="chordal")
    assert float(ch) == pytest.approx(8 * math.sin(0.25) ** 2 + 25 + math.log(2.0) ** 2, rel=1e-14)
    X = A.expand(3, 4, 4).clone().requires_grad_(True)
    tnn.sim3_geodesic_loss(X, X.detach()).backward()  # zero error: the zero subgradient
    assert bool(torch.isfinite(X.grad).all())
    assert tnn.sim3_geodesic_loss(X, B, reduction="none").shape == (3,)
    with pytest.raises(ValueError, match=r"torchlie\.nn\.sim3_geodesic_loss: .*scale_weight"):
        tnn.sim3_geodesic_loss(A, B, scale_weight=-1.0)


@pytest.mark.parametrize("rep", ["pos_quat_sigma", "matrix", "tangent"])
def test_sim3_parametrization(rep):
    from torch.nn.utils import parametrize

    from torchlie import nn as tnn

    g = torch.Generator().manual_seed(14)
    T = sim3.random(4, generator=g, dtype=F64)
    holder = torch.nn.Module()
    holder.T = torch.nn.Parameter(T.clone())
    parametrize.register_parametrization(holder, "T", tnn.Sim3Parametrization(rep))
    torch.testing.assert_close(holder.T, T)
    target = sim3.random(4, generator=g, dtype=F64)
    opt = torch.optim.Adam(holder.parameters(), lr=0.05)
    first = None
    for _ in range(60):
        opt.zero_grad()
        loss = tnn.sim3_geodesic_loss(holder.T, target, kind="chordal")
        first = float(loss.detach()) if first is None else first
        loss.backward()
        opt.step()
    assert bool(sim3.is_valid(holder.T).all())
    assert float(tnn.sim3_geodesic_loss(holder.T, target, kind="chordal").detach()) < 0.5 * first
    with pytest.raises(ValueError, match=r"torchlie\.nn\.Sim3Parametrization"):
        tnn.Sim3Parametrization("twist")


def _nearest_similarity_parts(X: torch.Tensor):
    """What Sim3Parametrization("matrix") reads from X: (s, R, t)."""
    A = X[..., :3, :3]
    R = so3.project(A)
    return (R * A).sum((-2, -1)) / 3, R, X[..., :3, 3]


def test_sim3_parametrization_matrix_reads_the_nearest_similarity():
    """The block A is read as s R with R = so3.project(A) and s = tr(R^T A) / 3 > 0: the
    minimiser of |s R - A|_F, whatever the matrix (reflections, rank 2, huge and tiny ones)."""
    from torchlie import nn as tnn

    p = tnn.Sim3Parametrization("matrix")
    g = torch.Generator().manual_seed(15)
    X = torch.randn(64, 4, 4, generator=g, dtype=F64)
    X[1, :3, :3] = -torch.eye(3, dtype=F64)  # a reflection: s = 1/3, R = diag(-1, -1, 1) up to axes
    X[2, :3, :3] = torch.diag(torch.tensor([1.0, 3.0, 0.0], dtype=F64))
    X[3] *= 1e300
    X[4] *= 1e-300
    T = p(X)
    assert T.shape == X.shape and bool(sim3.is_valid(T).all())
    assert torch.equal(T[:, 3], torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=F64).expand(64, 4))
    s, R, t = _nearest_similarity_parts(X)
    s_T, R_T, t_T = sim3.to_srt(T)
    assert bool((s_T > 0).all())
    torch.testing.assert_close(s_T, s, rtol=1e-14, atol=0)
    torch.testing.assert_close(R_T, R, rtol=0, atol=1e-14)
    assert torch.equal(t_T, t)
    torch.testing.assert_close(s_T[1], torch.tensor(1 / 3, dtype=F64), rtol=1e-15, atol=0)
    # a minimum: other scales and nearby rotations are farther from the block
    A = X[..., :3, :3] / X[..., :3, :3].abs().amax((-2, -1), keepdim=True)
    s, R = s / X[..., :3, :3].abs().amax((-2, -1)), R_T
    best = (s[:, None, None] * R - A).square().sum((-2, -1))
    for ds, w in ((1e-3, [0.0, 0.0, 0.0]), (-1e-3, [0.0, 0.0, 0.0]), (0.0, [1e-3, -2e-3, 1e-3])):
        other = (s + ds)[:, None, None] * so3.rplus(R, torch.tensor(w, dtype=F64))
        assert bool(((other - A).square().sum((-2, -1)) > best).all())


@pytest.mark.parametrize("dtype", [torch.float32, F64])
def test_sim3_parametrization_matrix_degenerate_blocks(dtype):
    """The zero block (and one without a normal-sized entry) reads as s = 1, R = I: never NaN,
    never a scale <= 0, and a finite (zero) gradient; the translation is read as it is."""
    from torchlie import nn as tnn

    tiny = torch.finfo(dtype).tiny
    X = torch.zeros(4, 4, 4, dtype=dtype)
    X[1, :3, :3] = tiny / 4 * torch.eye(3, dtype=dtype)  # subnormal entries
    X[2, :3, :3] = tiny * torch.eye(3, dtype=dtype)  # the smallest normal number: read as it is
    X[3, :3, :3] = torch.diag(torch.tensor([-2.0, 1.0, 3.0], dtype=dtype))  # a reflection
    X[:, :3, 3] = torch.tensor([1.0, -2.0, 3.0], dtype=dtype)
    X.requires_grad_()
    T = tnn.Sim3Parametrization("matrix")(X)
    assert bool(torch.isfinite(T).all()) and bool(sim3.is_valid(T).all())
    s, R, t = sim3.to_srt(T.detach())
    assert bool((s > 0).all())
    I4 = torch.eye(4, dtype=dtype)
    for i in (0, 1):
        assert torch.equal(T[i, :3, :3].detach(), I4[:3, :3]) and torch.equal(t[i], X[i, :3, 3])
    assert float(s[2]) == tiny and torch.equal(R[2], I4[:3, :3])
    # R = diag(-1, -1, 1) (the smallest singular value's axis flipped), s = (2 - 1 + 3) / 3
    torch.testing.assert_close(R[3], torch.diag(torch.tensor([-1.0, -1.0, 1.0], dtype=dtype)))
    torch.testing.assert_close(s[3], torch.tensor(4 / 3, dtype=dtype))
    # (the rotation's derivative at the smallest normal block, ~1 / tiny, is left out)
    W = torch.arange(16.0, dtype=dtype).reshape(4, 4)
    (grad,) = torch.autograd.grad((T[[0, 1, 3]] * W).sum(), X)
    assert bool(torch.isfinite(grad).all())
    assert not bool(grad[:2, :3, :3].any())  # the identity's, constant
    assert torch.equal(grad[:, 3], torch.zeros_like(grad[:, 3]))  # the bottom row is not read


def test_sim3_parametrization_matrix_gradcheck():
    from torchlie import nn as tnn

    p = tnn.Sim3Parametrization("matrix")
    g = torch.Generator().manual_seed(16)
    X = torch.randn(3, 4, 4, generator=g, dtype=F64)
    X[0] = sim3.random(generator=g, dtype=F64)
    X.requires_grad_()
    assert gradcheck(p, (X,))
    assert gradgradcheck(p, (X,))
    T = sim3.random(3, generator=g, dtype=F64).requires_grad_()
    assert gradcheck(p.right_inverse, (T,))


def test_sim3_parametrization_matrix_round_trip_and_state_dict():
    import io

    from torch.nn.utils import parametrize

    from torchlie import nn as tnn

    g = torch.Generator().manual_seed(17)
    T0 = sim3.random(2, 3, generator=g, dtype=F64)
    holder = torch.nn.Module()
    holder.T = torch.nn.Parameter(T0.clone())
    parametrize.register_parametrization(holder, "T", tnn.Sim3Parametrization("matrix"))
    original = holder.parametrizations.T.original
    assert original.shape == (2, 3, 4, 4)
    torch.testing.assert_close(holder.T, T0, rtol=0, atol=1e-14 * float(T0.abs().max()))
    T1 = sim3.random(2, 3, generator=g, dtype=F64)
    holder.T = T1  # right_inverse: the matrix itself, a copy
    assert torch.equal(holder.parametrizations.T.original, T1)
    assert holder.parametrizations.T.original.data_ptr() != T1.data_ptr()
    torch.testing.assert_close(holder.T, T1, rtol=0, atol=1e-14 * float(T1.abs().max()))
    with torch.no_grad():  # an arbitrary step
        holder.parametrizations.T.original.add_(torch.randn(2, 3, 4, 4, generator=g, dtype=F64))
    assert bool(sim3.is_valid(holder.T).all())
    buf = io.BytesIO()
    torch.save(holder.state_dict(), buf)
    buf.seek(0)
    other = torch.nn.Module()
    other.T = torch.nn.Parameter(sim3.identity(2, 3, dtype=F64))
    parametrize.register_parametrization(other, "T", tnn.Sim3Parametrization("matrix"))
    other.load_state_dict(torch.load(buf))
    assert torch.equal(other.T, holder.T)


@pytest.mark.compile
def test_sim3_parametrization_matrix_under_compile():
    """Forward and backward of a Sim(3)-parametrized parameter (a zero block included) under
    torch.compile(fullgraph=True) match eager."""
    from torch.nn.utils import parametrize

    from torchlie import nn as tnn

    torch._dynamo.reset()
    holder = torch.nn.Module()
    X = torch.randn(4, 4, 4, generator=torch.Generator().manual_seed(18))
    X[1, :3, :3] = 0.0
    holder.T = torch.nn.Parameter(X)
    parametrize.register_parametrization(holder, "T", tnn.Sim3Parametrization("matrix"))
    holder.parametrizations.T.original.data.copy_(X)
    p = torch.randn(4, 3, generator=torch.Generator().manual_seed(19))

    def f(p):
        return sim3.act(holder.T, p)

    ref = f(p)
    (g_ref,) = torch.autograd.grad(ref.square().sum(), holder.parametrizations.T.original)
    out = torch.compile(f, fullgraph=True)(p)
    (g,) = torch.autograd.grad(out.square().sum(), holder.parametrizations.T.original)
    torch.testing.assert_close(out, ref)
    torch.testing.assert_close(g, g_ref)
    assert bool(torch.isfinite(g).all())


# ----------------------------------------------------------------------------------------------
# Every finite scale: no square of the scale, no product of e^sigma factors, overflows
# ----------------------------------------------------------------------------------------------

#: Log scales near both ends of each dtype's range (e^sigma finite, e^(2 sigma) not, or subnormal).
EXTREME_SIGMAS = {
    torch.float32: [-87.0, -60.0, -45.0, 44.0, 50.0, 80.0, 88.0],
    torch.float64: [-708.0, -400.0, -360.0, 250.0, 354.0, 400.0, 700.0, 703.0],
}


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["f32", "f64"])
def test_every_finite_scale_is_read(dtype):
    """Everything that reads the scale of ``M = s R`` is finite and right wherever ``s`` is a
    finite positive number: log, scale, to_srt, inverse, adjoint, is_valid, distance, the class,
    the loss, the mean."""
    from torchlie import Sim3, statistics
    from torchlie import nn as tnn

    sig = torch.tensor(EXTREME_SIGMAS[dtype], dtype=F64)
    g = torch.Generator().manual_seed(21)
    n = len(sig)
    xi = torch.cat(
        (
            torch.randn(n, 3, generator=g, dtype=F64),
            torch.nn.functional.normalize(torch.randn(n, 3, generator=g, dtype=F64), dim=-1),
            sig[:, None],
        ),
        -1,
    ).to(dtype)
    T = sim3.exp(xi)
    eps = torch.finfo(dtype).eps
    L = sim3.log(T)
    assert torch.isfinite(L).all()
    torch.testing.assert_close(L[:, 6], xi[:, 6], rtol=4 * eps, atol=0)
    torch.testing.assert_close(L[:, 3:6], xi[:, 3:6], rtol=0, atol=16 * eps)
    s_ref = torch.exp(xi[:, 6].double())
    for s in (sim3.scale(T), sim3.to_srt(T)[0], Sim3(T).scale):
        torch.testing.assert_close(s.double(), s_ref, rtol=64 * eps, atol=0)
    R = so3.exp(xi[:, 3:6])
    torch.testing.assert_close(sim3.to_srt(T)[1], R, rtol=0, atol=16 * eps)
    assert sim3.is_valid(T).all()
    eye = torch.eye(4, dtype=dtype).expand(n, 4, 4)
    Ti = sim3.inverse(T)
    torch.testing.assert_close(Ti[:, :3, :3] * s_ref.to(dtype)[:, None, None], R.mT, rtol=0,
                               atol=16 * eps)  # fmt: skip
    torch.testing.assert_close(sim3.act(Ti, T[:, :3, 3]), torch.zeros(n, 3, dtype=dtype),
                               rtol=0, atol=16 * eps * T[:, :3, 3].abs().amax())  # fmt: skip
    torch.testing.assert_close(sim3.compose(T, Ti)[:, :3, :3], eye[:, :3, :3], rtol=0,
                               atol=16 * eps)  # fmt: skip
    Ad = sim3.adjoint(T)
    torch.testing.assert_close(Ad[:, 3:6, 3:6], R, rtol=0, atol=16 * eps)
    angle, _, ds = sim3.distance(T, sim3.compose(T, sim3.exp(torch.tensor(
        [0.0, 0.0, 0.0, 0.0, 0.0, 0.25, -0.5], dtype=dtype))))  # fmt: skip
    torch.testing.assert_close(angle, torch.full_like(angle, 0.25), rtol=0, atol=16 * eps)
    torch.testing.assert_close(ds, torch.full_like(ds, 0.5), rtol=0, atol=16 * eps)
    for kind in ("angle", "chordal"):
        loss = tnn.sim3_geodesic_loss(T, T, kind=kind, reduction="none")
        assert (loss.abs() <= 1e3 * eps).all(), kind
    mean = statistics.sim3_mean(T[:, None].expand(n, 3, 4, 4))
    torch.testing.assert_close(sim3.log(mean)[:, 3:], xi[:, 3:], rtol=4 * eps, atol=16 * eps)
    # the top of the range (exp's translation overflows its intermediates from sigma ~ 703)
    top = math.log(torch.finfo(dtype).max) - 0.1
    R = so3.exp(torch.tensor([0.3, -0.2, 0.4], dtype=dtype))
    T = sim3.from_srt(torch.tensor(math.exp(top), dtype=dtype), R, torch.ones(3, dtype=dtype))
    L = sim3.log(T)
    assert torch.isfinite(L).all()
    torch.testing.assert_close(L[6], torch.tensor(top, dtype=dtype), rtol=4 * eps, atol=0)
    torch.testing.assert_close(L[3:6], R.new_tensor([0.3, -0.2, 0.4]), rtol=0, atol=16 * eps)
    torch.testing.assert_close(sim3.to_srt(T)[1], R, rtol=0, atol=16 * eps)


def _mp_e1_parts(s, t2) -> tuple:
    """``(A, B, C)`` of V at ``sigma = s``, ``theta^2 = t2`` (mpf), the limits at ``theta = 0``
    from the derivatives of ``E1`` in ``z``, at 0 as well."""
    if t2 != 0:
        if s == 0:
            t = mp.sqrt(t2)
            E = (mp.expj(t) - 1) / mp.mpc(0, t)
            return mp.mpf(1), E.imag / t, (1 - E.real) / t2
        return _mp_abc(s, t2)

    def e1(x):
        return (mp.exp(x) - 1) / x if x != 0 else mp.mpf(1)

    if s == 0:
        return mp.mpf(1), mp.mpf(1) / 2, mp.mpf(1) / 6
    return e1(s), mp.diff(e1, s), mp.diff(e1, s, 2) / 2


def _v_inv_errors(dtype: torch.dtype, sigmas, angles, diff: bool) -> list[tuple]:
    """``(sigma, theta, err)``: the largest error of ``V^-1 = a I + b hat(phi) + c hat(phi)^2``'s
    coefficients weighted by ``theta^k`` (``theta`` at least 1), in units of the last place of
    the largest term ``|a|``, ``|b| theta``, ``|c| theta^2``: the error of the matrix
    (``c`` alone, nearly 0 at large negative sigma, cancels)."""
    s = torch.tensor([a for a in sigmas for _ in angles], dtype=dtype)
    th = torch.tensor([t for _ in sigmas for t in angles], dtype=dtype)
    t2 = th.double() * th.double() if dtype == F64 else (th * th).double()
    got = [x.to(dtype).double() for x in _coeffs.sim3_v_inv(s.double(), t2, dtype, diff)]
    out = []
    for i in range(len(s)):
        with mp.workdps(DPS + 20):
            sm, tm = mp.mpf(float(s[i])), mp.mpf(float(t2[i]))
            A, B, C = _mp_e1_parts(sm, tm)
            D = A - tm * C
            det = D * D + tm * B * B
            ref = (1 / A, -B / det, (B * B - C * D) / (A * det))
        w = max(float(th[i]), 1.0)
        size = max(abs(float(ref[k])) * w**k for k in range(3))
        ulp = 2.0 ** math.floor(math.log2(size)) * torch.finfo(dtype).eps
        err = max(abs(float(got[k][i]) - float(ref[k])) * w**k for k in range(3)) / ulp
        out.append((float(s[i]), float(th[i]), err))
    return out


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["f32", "f64"])
def test_v_inverse_coefficients_at_every_sigma(dtype):
    """``V^-1`` within 4 ulp of 60-digit references for sigma from -80 to 700 (``A det ~
    (e^sigma / sigma)^3`` is far beyond the range above 242) jointly with the angles, for the
    differentiable and the forward-only coefficients; float32 evaluates in float64 and rounds."""
    sigmas = [0.0, 1e-12, 1e-6, 0.5, -3.0, 20.0, 80.0, -80.0, 250.0, 400.0, 700.0]
    if dtype == torch.float32:
        sigmas = [s for s in sigmas if abs(s) < 88]
    for diff in (True, False):
        for s, th, err in _v_inv_errors(dtype, sigmas, [0.0, 1e-8, 1.0, 3.0, PI], diff):
            # just outside the joint series (sigma = 0.5, theta <= 1e-8) the closed form of c
            # cancels a few bits: 7.1 ulp of float64 measured there
            assert err <= (VALUE_ULP if abs(s) >= 1 else 2 * VALUE_ULP), (s, th, diff, err)


def test_log_and_inverse_jacobians_at_large_sigma():
    """``rho = V^-1 t`` and ``Jl^-1`` stay right where ``V``'s determinant overflows."""
    for sg in (250.0, 361.0, 400.0, 700.0):
        xi = torch.tensor([0.3, -0.2, 0.1, 1.0, 0.0, 0.0, sg], dtype=F64)
        torch.testing.assert_close(sim3.log(sim3.exp(xi)), xi, rtol=1e-14, atol=1e-14)
        Ji = sim3.jac_left_inv(xi)
        assert torch.isfinite(Ji).all() and torch.equal(Ji, sim3.jac_right_inv(-xi))
        torch.testing.assert_close(Ji @ sim3.jac_left(xi), torch.eye(7, dtype=F64), rtol=0,
                                   atol=1e-13)  # fmt: skip
        torch.testing.assert_close(sim3.rminus(sim3.exp(xi), sim3.identity(dtype=F64)), xi,
                                   rtol=1e-14, atol=1e-14)  # fmt: skip


def test_chordal_loss_of_far_apart_scales():
    """``log(s_pred / s_target)`` as a difference of logs: the ratio of two finite scales may
    overflow (1e19 / 1e-20 in float32; 8064.19 = (log 1e39)^2)."""
    from torchlie import nn as tnn

    eye = torch.eye(3)
    A = sim3.from_srt(torch.tensor(1e19), eye, torch.zeros(3))
    B = sim3.from_srt(torch.tensor(1e-20), eye, torch.zeros(3))
    X = A.clone().requires_grad_(True)
    loss = tnn.sim3_geodesic_loss(X, B, kind="chordal", rotation_weight=0.0,
                                  translation_weight=0.0)  # fmt: skip
    assert float(loss.detach()) == pytest.approx(math.log(1e39) ** 2, rel=1e-6)
    loss.backward()
    # d/dM of (log s_A - log s_B)^2 = 2 log(1e39) M / (3 s_A^2) on the diagonal
    want = 2 * math.log(1e39) / (3 * 1e19)
    torch.testing.assert_close(X.grad[:3, :3], want * eye, rtol=1e-5, atol=0)


def _mp_e2_parts(s, t2) -> tuple:
    """``(A2, B2, C2)``: the coefficients of ``E2(z) = (e^z - 1 - z)/z^2`` as ``(A, B, C)`` are
    of ``E1`` (:func:`_mp_abc`), with the limits at ``theta = 0`` from its derivatives."""

    def e2(z):
        return (mp.exp(z) - 1 - z) / z**2

    if t2 == 0:
        return e2(s), mp.diff(e2, s), mp.diff(e2, s, 2) / 2
    t = mp.sqrt(t2)
    E = e2(mp.mpc(s, t))
    return e2(s), E.imag / t, (e2(s) - E.real) / t2


def _mp_w(s, phi, rho) -> list:
    """The sigma column of ``Jl``, ``w = -E2(sigma + hat(phi)) rho``, at 60 digits."""
    t2 = sum(x * x for x in phi)
    A2, B2, C2 = _mp_e2_parts(s, t2 if t2 > 0 else mp.mpf("1e-70"))
    pr = [phi[1] * rho[2] - phi[2] * rho[1], phi[2] * rho[0] - phi[0] * rho[2]]
    pr.append(phi[0] * rho[1] - phi[1] * rho[0])
    ppr = [phi[1] * pr[2] - phi[2] * pr[1], phi[2] * pr[0] - phi[0] * pr[2]]
    ppr.append(phi[0] * pr[1] - phi[1] * pr[0])
    return [-(A2 * rho[i] + B2 * pr[i] + C2 * ppr[i]) for i in range(3)]


def test_jacobian_sigma_column_at_large_sigma():
    """The sigma column of jac_left, ``w = d(V rho)/dsigma - V rho``, within 4 ulp of its largest
    component and its derivative in sigma within 8 ulp, against 60-digit references, from
    sigma = 1 (where its difference form starts to cancel: 7.3 ulp at sigma = 3.5 and angle 3,
    its derivative 10.2 at sigma = 2) to 250 (47 ulp at sigma = 40, 205 at 250)."""
    rho, ax = [0.3, -0.7, 0.5], [0.6, 0.0, 0.8]
    worst = [0.0, 0.0]
    for sg in (1.0, 2.0, 3.5, 4.5, 10.0, 20.0, 40.0, 80.0, 250.0):
        for th in (1e-4, 1.0, 3.0, PI):
            s = torch.tensor(sg, dtype=F64, requires_grad=True)
            xi = torch.cat((torch.tensor(rho + [th * a for a in ax], dtype=F64), s[None]))
            w = sim3.jac_left(xi)[:3, 6]
            dw = [float(torch.autograd.grad(w[i], s, retain_graph=True)[0]) for i in range(3)]
            with mp.workdps(DPS):
                phi, r = [mp.mpf(th) * a for a in ax], [mp.mpf(x) for x in rho]
                ref = _mp_w(mp.mpf(sg), phi, r)
                dref = [
                    mp.diff(lambda x, i=i, p=phi, r=r: _mp_w(x, p, r)[i], mp.mpf(sg))
                    for i in range(3)
                ]
            for k, (got, want) in enumerate(((w.tolist(), ref), (dw, dref))):
                top = max(abs(float(v)) for v in want)
                ulp = 2.0 ** math.floor(math.log2(top)) * torch.finfo(F64).eps
                err = max(abs(got[i] - float(want[i])) for i in range(3)) / ulp
                worst[k] = max(worst[k], err)
    assert worst[0] <= VALUE_ULP and worst[1] <= GRAD_ULP, worst


def test_v_coefficients_up_to_the_top_of_the_range():
    """``V``'s ``B`` and ``C`` within 4 ulp of 60-digit references for sigma up to 709.7 in
    float64 (``sigma e^sigma`` overflows from about 703, where they are finite), and the
    exponential's translation with them: ``log(exp(xi)) = xi``."""
    for diff in (True, False):
        for sg in (80.0, 250.0, 500.0, 700.0, 703.5, 706.0, 709.7):
            for th in (1e-8, 1.0, 3.0, PI):
                got = _coeffs.sim3_v(
                    torch.tensor(sg, dtype=F64), torch.tensor(th * th, dtype=F64),
                    F64, diff,
                )  # fmt: skip
                with mp.workdps(60):
                    ref = _mp_abc(mp.mpf(sg), mp.mpf(th) ** 2)
                for g, r in zip(got, ref, strict=True):
                    err = abs(mp.mpf(float(g)) - r) / abs(r) / mp.mpf(torch.finfo(F64).eps)
                    assert err <= VALUE_ULP, (sg, th, diff, float(err))
        xi = torch.tensor([0.3, -0.2, 0.1, 1.0, 0.5, -0.3, 709.7], dtype=F64)
        T = sim3.exp(xi)
        assert torch.isfinite(T).all()
        torch.testing.assert_close(sim3.log(T), xi, rtol=1e-14, atol=1e-14)


@pytest.mark.parametrize("sg", [-700.0, 380.0, 650.0, 703.5, 706.0, 709.0])
def test_derivatives_up_to_the_top_of_the_range(sg):
    """Reverse and forward derivatives of ``exp``, the Jacobians and ``log`` at sigma up to
    709 in float64 agree with central differences (partials that overflowed from about 703
    gave NaN, a reciprocal's derivative that underflowed from about 372 gave a wrong one)."""
    xi = torch.tensor([1.0, 2.0, 3.0, 0.6, 0.0, 0.8, sg], dtype=F64)
    fns = (sim3.exp, sim3.jac_left, sim3.jac_right, sim3.jac_left_inv, sim3.jac_right_inv)
    for fn in fns:
        scale = 1.0 / float(fn(xi).abs().max())

        def f(x, fn=fn, scale=scale):
            return fn(x) * scale

        J = torch.autograd.functional.jacobian(f, xi)  # reverse mode
        Jf = torch.func.jacfwd(f)(xi)
        h = 1e-6
        steps = torch.eye(7, dtype=F64) * h
        fd = torch.stack([(f(xi + e) - f(xi - e)) / (2 * h) for e in steps], -1)
        for jac in (J, Jf):
            assert bool(jac.isfinite().all()), fn.__name__
            assert float((jac - fd).abs().max()) <= 1e-6 * float(fd.abs().max()), fn.__name__
    T = sim3.exp(xi)
    Jl = torch.autograd.functional.jacobian(sim3.log, T)  # entries down to about 1 / s
    Jlf = torch.func.jacfwd(sim3.log)(T)
    assert bool(Jl.isfinite().all()) and bool(Jlf.isfinite().all())
    torch.testing.assert_close(Jlf, Jl, rtol=1e-10, atol=1e-10 * float(Jl.abs().max()))


@pytest.mark.parametrize(
    ("dtype", "s"),
    [(F64, 1e100), (F64, 1e-100), (F64, 1e300), (F64, 3e-308), (F64, 2.0**200), (F64, 7.0)]
    + [(torch.float32, 1e20), (torch.float32, 1e-20)],
)
def test_scale_is_read_exactly_at_every_magnitude(dtype, s):
    """``scale``, ``to_srt``, ``is_valid`` and ``inverse`` of ``s R`` for scales given exactly
    (not as ``exp(sigma)``): the scale within 2 ulp (not through its log, which cost ``log2 |log
    s|`` bits: 78 ulp at 1e100), ``T^-1 T`` the identity within 4 ulp."""
    R = so3.exp(torch.tensor([[0.0, 0.0, math.pi / 2], [0.3, -0.2, 0.9]], dtype=F64)).to(dtype)
    T = sim3.from_srt(torch.tensor(s, dtype=dtype), R, torch.ones(3, dtype=dtype))
    eps = torch.finfo(dtype).eps
    got = sim3.scale(T).double()
    assert float(((got - s) / s).abs().max()) <= 2 * eps
    torch.testing.assert_close(sim3.to_srt(T)[0], sim3.scale(T), rtol=0, atol=0)
    assert bool(sim3.is_valid(T).all())
    I = sim3.compose(sim3.inverse(T), T)
    assert float((I - torch.eye(4, dtype=dtype)).abs().max()) <= 4 * eps


def test_scale_coefficient_and_its_derivatives_at_every_sigma():
    """``A = (e^sigma - 1)/sigma`` and its first and second autograd derivatives within 4, 4
    and 16 ulp of 50-digit references from -709 to 700 (below -1 the product form's
    derivatives lost ``log2 |sigma|`` bits: 195 ulp at -709)."""
    pts = (-709.0, -100.0, -64.0, -16.0, -3.0, -1.5, -1.0, -0.3, 0.0, 1e-12, 0.5, 3.0, 64.0, 700.0)
    worst = [0.0, 0.0, 0.0]
    for sg in pts:
        s = torch.tensor(sg, dtype=F64, requires_grad=True)
        v = _coeffs.expc(s)
        (d1,) = torch.autograd.grad(v, s, create_graph=True)
        (d2,) = torch.autograd.grad(d1, s)
        with mp.workdps(50):
            x = mp.mpf(sg)

            def f(y):
                return mp.expm1(y) / y if y != 0 else mp.mpf(1)

            refs = (f(x), mp.diff(f, x), mp.diff(f, x, 2))
            for i, (got, ref) in enumerate(zip((v, d1, d2), refs, strict=True)):
                ulp = abs(ref) * mp.mpf(2) ** -52
                worst[i] = max(worst[i], float(abs(mp.mpf(float(got.detach())) - ref) / ulp))
    assert worst[0] <= 4 and worst[1] <= 4 and worst[2] <= 16, worst
