"""torchlie.se3: values against a high-precision reference and scipy, round trips at every angle,
gradients, conversions, batching, bad input, vmap and compile."""

from __future__ import annotations

import math

import mpmath
import numpy as np
import pytest
import torch
from samplers import ANGLES, GRAD_ANGLES, PI, eps, rotvecs, unit
from scipy.spatial.transform import Rotation
from torch.autograd import gradcheck, gradgradcheck

from torchlie import _coeffs, quaternion, se3, so3

F64 = torch.float64


def twists(angles=ANGLES, n_random: int = 20, seed: int = 0, rho_norm: float | None = None):
    """Twists ``(rho, phi)`` with ``phi`` over ``samplers.rotvecs`` and random ``rho``.

    ``rho_norm`` fixes ``|rho|``; otherwise ``rho ~ N(0, I)``.  Returns ``(xi, theta)`` in f64.
    """
    w, th = rotvecs(angles, n_random=n_random, seed=seed)
    g = torch.Generator().manual_seed(seed + 1)
    rho = torch.randn(w.shape, generator=g, dtype=F64)
    if rho_norm is not None:
        rho = rho_norm * rho / rho.norm(dim=-1, keepdim=True)
    return torch.cat((rho, w), dim=-1), th


# ----------------------------------------------------------------------------------------------
# High-precision reference (mpmath, 60 digits): independent of torchlie's series
# ----------------------------------------------------------------------------------------------


def _mp_cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def _mp_jl(phi, v):
    """so3 left Jacobian applied to v (60 digits, closed form)."""
    th = mpmath.sqrt(sum(p * p for p in phi))
    if th == 0:
        return list(v)
    a = (1 - mpmath.cos(th)) / th**2
    b = (th - mpmath.sin(th)) / th**3
    pv = _mp_cross(phi, v)
    ppv = _mp_cross(phi, pv)
    return [v[i] + a * pv[i] + b * ppv[i] for i in range(3)]


def _mp_jl_matrix(phi):
    cols = [_mp_jl(phi, [mpmath.mpf(int(i == j)) for i in range(3)]) for j in range(3)]
    return mpmath.matrix([[cols[j][i] for j in range(3)] for i in range(3)])


def mp_exp(xi) -> list[list[float]]:
    """The pose of one twist (floats), computed with 60 significant digits."""
    with mpmath.workdps(60):
        v = [mpmath.mpf(float(x)) for x in xi]
        rho, phi = v[:3], v[3:]
        th = mpmath.sqrt(sum(p * p for p in phi))
        R = [[mpmath.mpf(int(i == j)) for j in range(3)] for i in range(3)]
        if th != 0:
            n = [p / th for p in phi]
            K = [[0, -n[2], n[1]], [n[2], 0, -n[0]], [-n[1], n[0], 0]]
            K2 = [[sum(K[i][k] * K[k][j] for k in range(3)) for j in range(3)] for i in range(3)]
            s, c = mpmath.sin(th), 1 - mpmath.cos(th)
            R = [[R[i][j] + s * K[i][j] + c * K2[i][j] for j in range(3)] for i in range(3)]
        t = _mp_jl(phi, rho)
        return [[float(R[i][j]) for j in range(3)] + [float(t[i])] for i in range(3)] + [
            [0.0, 0.0, 0.0, 1.0]
        ]


def mp_wrapped(xi) -> list[float]:
    """The other twist of the same pose when ``|phi|`` is (about) pi: the rotation vector
    ``phi (1 - 2 pi/|phi|)`` (axis reversed, angle ``2 pi - |phi|``) and the matching rho."""
    with mpmath.workdps(60):
        v = [mpmath.mpf(float(x)) for x in xi]
        rho, phi = v[:3], v[3:]
        th = mpmath.sqrt(sum(p * p for p in phi))
        phi2 = [p * (1 - 2 * mpmath.pi / th) for p in phi]
        t = _mp_jl(phi, rho)
        rho2 = mpmath.lu_solve(_mp_jl_matrix(phi2), mpmath.matrix(t))
        return [float(rho2[i]) for i in range(3)] + [float(p) for p in phi2]


# ----------------------------------------------------------------------------------------------
# Textbook values, pinned
# ----------------------------------------------------------------------------------------------


def test_exp_screw_motion_literal():
    # Rotation by th about z while translating along x at unit speed: the arc of a circle,
    # t = (sin th / th, (1 - cos th) / th, 0); a pitch along z adds straight to t_z.
    th = 0.9
    T = se3.exp(torch.tensor([1.0, 0.0, 0.5, 0.0, 0.0, th], dtype=F64))
    expected_t = torch.tensor([math.sin(th) / th, (1 - math.cos(th)) / th, 0.5], dtype=F64)
    torch.testing.assert_close(T[:3, 3], expected_t, rtol=0, atol=2 * eps(F64))
    torch.testing.assert_close(T[:3, :3], so3.exp(torch.tensor([0.0, 0.0, th], dtype=F64)))
    torch.testing.assert_close(T[3], torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=F64), rtol=0, atol=0)


def test_pure_translation_and_pure_rotation(dtype):
    rho = torch.tensor([1.0, -2.0, 3.0], dtype=dtype)
    T = se3.exp(torch.cat((rho, torch.zeros(3, dtype=dtype))))
    torch.testing.assert_close(T, se3.from_rt(torch.eye(3, dtype=dtype), rho), rtol=0, atol=0)
    torch.testing.assert_close(se3.log(T), torch.cat((rho, torch.zeros(3, dtype=dtype))))
    w = torch.tensor([0.3, -0.2, 0.1], dtype=dtype)
    T = se3.exp(torch.cat((torch.zeros(3, dtype=dtype), w)))
    torch.testing.assert_close(T[:3, :3], so3.exp(w), rtol=0, atol=0)
    assert bool((T[:3, 3] == 0).all())


def test_q_block_matches_barfoot_literal():
    """The top-right block of jac_left against Barfoot's eq. 7.86, written with hat matrices."""
    rho = np.array([0.3, -1.2, 0.7])
    phi = np.array([0.4, 0.9, -0.5])
    th = np.linalg.norm(phi)

    def h(v):
        return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])

    P, Rh = h(phi), h(rho)
    Q = (
        0.5 * Rh
        + (th - np.sin(th)) / th**3 * (P @ Rh + Rh @ P + P @ Rh @ P)
        + (th**2 + 2 * np.cos(th) - 2) / (2 * th**4) * (P @ P @ Rh + Rh @ P @ P - 3 * P @ Rh @ P)
        + (2 * th - 3 * np.sin(th) + th * np.cos(th))
        / (2 * th**5)
        * (P @ Rh @ P @ P + P @ P @ Rh @ P)
    )
    J = se3.jac_left(torch.tensor(np.concatenate((rho, phi))))
    torch.testing.assert_close(J[:3, 3:], torch.tensor(Q), rtol=0, atol=1e-14)
    torch.testing.assert_close(J[:3, :3], so3.jac_left(torch.tensor(phi)))
    torch.testing.assert_close(J[3:, 3:], so3.jac_left(torch.tensor(phi)))
    assert bool((J[3:, :3] == 0).all())


def test_adjoint_and_ad_literal():
    R = so3.exp(torch.tensor([0.1, -0.4, 0.8], dtype=F64))
    t = torch.tensor([1.0, 2.0, -0.5], dtype=F64)
    A = se3.adjoint(se3.from_rt(R, t))
    torch.testing.assert_close(A[:3, :3], R, rtol=0, atol=0)
    torch.testing.assert_close(A[:3, 3:], so3.hat(t) @ R, rtol=0, atol=0)
    torch.testing.assert_close(A[3:, 3:], R, rtol=0, atol=0)
    assert bool((A[3:, :3] == 0).all())
    xi = torch.tensor([1.0, 2.0, 3.0, 4.0, 5.0, 6.0], dtype=F64)
    a = se3.ad(xi)
    torch.testing.assert_close(a[:3, :3], so3.hat(xi[3:]), rtol=0, atol=0)
    torch.testing.assert_close(a[:3, 3:], so3.hat(xi[:3]), rtol=0, atol=0)
    torch.testing.assert_close(a[3:, 3:], so3.hat(xi[3:]), rtol=0, atol=0)


def test_hat_vee(batch, dtype):
    xi = torch.randn(*batch, 6, dtype=dtype)
    X = se3.hat(xi)
    assert X.shape == (*batch, 4, 4)
    assert bool((X[..., 3, :] == 0).all())
    torch.testing.assert_close(se3.vee(X), xi, rtol=0, atol=0)
    # hat(xi) [p; 1] = phi x p + rho
    p = torch.randn(*batch, 3, dtype=dtype)
    ph = torch.cat((p, torch.ones_like(p[..., :1])), dim=-1)
    lhs = (X @ ph.unsqueeze(-1)).squeeze(-1)[..., :3]
    torch.testing.assert_close(lhs, torch.linalg.cross(xi[..., 3:], p) + xi[..., :3])


# ----------------------------------------------------------------------------------------------
# Values against the high-precision reference and scipy
# ----------------------------------------------------------------------------------------------


def test_exp_matches_references(dtype):
    xi, _ = twists(n_random=20)
    xi = xi.to(dtype)
    ref = torch.tensor([mp_exp(x) for x in xi.double().tolist()], dtype=F64)
    T = se3.exp(xi).double()
    # rotation block against scipy as well (Rodrigues in float64)
    sp = torch.tensor(Rotation.from_rotvec(xi[:, 3:].double().numpy()).as_matrix())
    torch.testing.assert_close(T[:, :3, :3], sp, rtol=0, atol=8 * eps(dtype))
    torch.testing.assert_close(T[:, :3, :3], ref[:, :3, :3], rtol=0, atol=4 * eps(dtype))
    scale = xi[:, :3].double().norm(dim=-1).clamp_min(1.0)
    err_t = (T[:, :3, 3] - ref[:, :3, 3]).abs().amax(dim=-1) / scale
    assert float(err_t.max()) <= 4 * eps(dtype)
    assert bool((T[:, 3] == torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=F64)).all())


def _mp_q(xi) -> list[list[float]]:
    """Barfoot's Q(rho, phi) (eq. 7.86) with 60 significant digits."""
    with mpmath.workdps(60):
        v = [mpmath.mpf(float(x)) for x in xi]
        r, p = v[:3], v[3:]

        def h(u):
            return mpmath.matrix([[0, -u[2], u[1]], [u[2], 0, -u[0]], [-u[1], u[0], 0]])

        P, Rh = h(p), h(r)
        Q = 0.5 * Rh
        th = mpmath.sqrt(sum(x * x for x in p))
        if th != 0:
            c1 = (th - mpmath.sin(th)) / th**3
            c2 = (th**2 + 2 * mpmath.cos(th) - 2) / (2 * th**4)
            c3 = (2 * th - 3 * mpmath.sin(th) + th * mpmath.cos(th)) / (2 * th**5)
            Q += c1 * (P * Rh + Rh * P + P * Rh * P)
            Q += c2 * (P * P * Rh + Rh * P * P - 3 * P * Rh * P)
            Q += c3 * (P * Rh * P * P + P * P * Rh * P)
        return [[float(Q[i, j]) for j in range(3)] for i in range(3)]


def test_jac_left_q_block_matches_high_precision(dtype):
    # the sweep plus angles around the series/exact switch points of the coefficients
    extra = [1e-3, 0.03, 0.1, 0.3, 0.5, 0.8, 1.2, 1.5, 2.0]
    # beyond pi: around q3's series switch, the large-angle form's switch (|phi| = 8), and far
    large = [4.0, 4.5, 7.9, 8.0, 8.1, 10.0, 30.0, 1e2, 1e4, 1e8, 1e12, 1e16]
    xi, _ = twists(ANGLES + extra + large, n_random=6)
    xi = xi.to(dtype)
    J = se3.jac_left(xi).double()
    ref = torch.tensor([_mp_q(x) for x in xi.double().tolist()], dtype=F64)
    err = (J[:, :3, 3:] - ref).abs().amax(dim=(-1, -2)) / xi[:, :3].double().norm(dim=-1)
    assert float(err.max()) <= 2 * eps(dtype)


def test_log_of_reference_poses(dtype):
    # Below pi, where the twist of a pose is unique.
    xi, th = twists([a for a in ANGLES if a < PI - 1e-3], n_random=20)
    T = torch.tensor([mp_exp(x) for x in xi.tolist()], dtype=F64).to(dtype)
    out = se3.log(T).double()
    scale = xi[:, :3].norm(dim=-1).clamp_min(1.0)
    err_rho = (out[:, :3] - xi[:, :3]).abs().amax(dim=-1) / scale
    assert float(err_rho.max()) <= 4 * eps(dtype)
    torch.testing.assert_close(out[:, 3:], xi[:, 3:], rtol=0, atol=4 * eps(dtype))
    # scipy's rotation vector of the same matrices
    sp = torch.tensor(Rotation.from_matrix(T[:, :3, :3].double().numpy()).as_rotvec())
    torch.testing.assert_close(out[:, 3:], sp, rtol=0, atol=8 * eps(dtype))


# The numerical specification: log(exp(xi)) at every angle of the sweep, pi included.
LOG_EXP_TOL = {torch.float64: 1.5e-15, torch.float32: 1e-6}


def _log_exp_errors(xi: torch.Tensor, dtype: torch.dtype) -> torch.Tensor:
    """Max abs error of log(exp(xi)) per element, against xi or, where the axis came back
    reversed (possible only at pi), against the other twist of the same pose."""
    x = xi.to(dtype)
    out = se3.log(se3.exp(x)).double()
    x64 = x.double()  # the input as it is, exactly
    flipped = (out[:, 3:] * x64[:, 3:]).sum(-1) < 0
    theta = x64[:, 3:].norm(dim=-1)
    # a reversed axis is legitimate only at pi (in float32, pi - 1e-8 rounds above pi)
    assert bool((theta[flipped] >= PI - 16 * eps(dtype)).all())
    expected = x64.clone()
    idx = flipped.nonzero().flatten().tolist()
    if idx:
        expected[idx] = torch.tensor([mp_wrapped(x64[i].tolist()) for i in idx], dtype=F64)
    return (out - expected).abs().amax(dim=-1)


def test_log_exp_roundtrip_every_angle(dtype):
    xi, th = twists(n_random=200, rho_norm=1.0)
    err = _log_exp_errors(xi, dtype)
    for a in ANGLES:
        worst = float(err[th == a].max())
        assert worst <= LOG_EXP_TOL[dtype], f"theta={a}: {worst:.3g}"


def test_q_values_match_the_series_coefficients():
    """The forward-only float32 coefficients of Q (closed forms from Rodrigues' coefficients of
    the same angle, three-term series below ``Q_VALUES_T2``) agree with the float64 coefficient
    functions far below float32's precision, on both sides of the switch and at large angles."""
    k = _coeffs.Q_VALUES_T2
    t = torch.tensor(
        [0.0, 1e-30, 1e-12, 1e-6, 1e-4, 2.5e-3, math.nextafter(k, 0), k, math.nextafter(k, 1)]
        + [0.02, 0.1, 0.5, 1.0, 4.0, PI**2, 20.0, 100.0, 1e4, 1e10, 1e20],
        dtype=F64,
    ).sqrt()
    w = torch.stack((t, torch.zeros_like(t), torch.zeros_like(t)), -1)
    half = _coeffs.half_angle(w)
    t2 = half[0]
    got = _coeffs.q_values(t2, *_coeffs.rodrigues_values(None, "bc", half))
    want = _coeffs.q_series(t2)
    for a, b in zip(got, want, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-9, atol=0)


@pytest.mark.parametrize("dtype", [torch.float32, F64])
def test_step_is_a_float_comparison(dtype):
    tiny = torch.finfo(dtype).tiny * torch.finfo(dtype).eps  # the smallest subnormal
    x = torch.tensor([-1.0, -0.0, 0.0, tiny, 1.0, math.inf, -math.inf, math.nan], dtype=dtype)
    got = _coeffs.step(x)
    assert got.dtype == dtype
    assert got.tolist() == [0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0, 0.0]  # x > 0, NaN included
    g = torch.Generator().manual_seed(13)
    a = torch.randn(1000, generator=g, dtype=dtype)
    b = torch.where(torch.rand(1000, generator=g) < 0.3, a, a.nextafter(a + 1))  # ties, 1 ulp
    b[:200] = torch.randn(200, generator=g, dtype=dtype)
    assert torch.equal(_coeffs.step(a - b), (a > b).to(dtype))
    assert torch.equal(_coeffs.step(b - a), (b > a).to(dtype))


def test_float32_plain_backward_of_exp_and_log():
    """float32 gradients of exp and log (the plain backward, forward-only coefficients) against
    float64 ones at the same inputs: within a few float32 ulp, norm-wise, at every angle."""
    g = torch.Generator().manual_seed(12)
    axes = unit(torch.randn(50, 3, generator=g, dtype=F64))
    angles = [0.0, 1e-6, 1e-3, 0.05, 0.0999, 0.1, 0.1001, 0.3, 1.0, 2.0, 3.0, PI - 1e-3]
    phi = torch.cat([a * axes for a in angles])
    x32 = torch.cat((torch.randn(phi.shape, generator=g, dtype=F64), phi), -1).float()
    T32 = se3.exp(x32)

    def grad(fn, x, G):
        x = x.clone().requires_grad_()
        return torch.autograd.grad(fn(x), x, G)[0]

    def rel(a, b, nd):
        dims = tuple(range(-nd, 0))
        return (a.double() - b).square().sum(dims).sqrt() / b.square().sum(dims).sqrt()

    G = torch.randn(x32.shape[0], 4, 4, generator=g, dtype=F64)
    err = rel(grad(se3.exp, x32, G.float()), grad(se3.exp, x32.double(), G), 1)
    assert float(err.max()) <= 5e-7
    g6 = torch.randn(x32.shape, generator=g, dtype=F64)
    err = rel(grad(se3.log, T32, g6.float()), grad(se3.log, T32.double(), g6), 2)
    assert float(err.max()) <= 5e-7


def test_log_exp_roundtrip_large_translations(dtype):
    # The error scales with |rho|: the tolerance is relative to max(1, |rho|).
    xi, th = twists(n_random=40)
    xi[:, :3] *= 10.0
    err = _log_exp_errors(xi, dtype) / xi[:, :3].norm(dim=-1).clamp_min(1.0)
    assert float(err.max()) <= LOG_EXP_TOL[dtype]


def test_log_at_exactly_pi_axis_is_canonical():
    # pi about z with a translation: phi = (0, 0, pi) (canonical sign), rho = Jl(phi)^-1 t.
    T = se3.from_rt(
        torch.diag(torch.tensor([-1.0, -1.0, 1.0], dtype=F64)), torch.ones(3, dtype=F64)
    )
    xi = se3.log(T)
    torch.testing.assert_close(xi[3:], torch.tensor([0.0, 0.0, PI], dtype=F64), rtol=0, atol=0)
    torch.testing.assert_close(se3.exp(xi), T, rtol=0, atol=4 * eps(F64))
    # Jl(pi e_z)^-1 = I - (pi/2) hat(e_z) + hat(e_z)^2, so t = (1, 1, 1) gives (pi/2, -pi/2, 1)
    torch.testing.assert_close(
        xi[:3], torch.tensor([PI / 2, -PI / 2, 1.0], dtype=F64), rtol=0, atol=4 * eps(F64)
    )


def test_exp_log_roundtrip_random(dtype):
    T = se3.random(300, generator=torch.Generator().manual_seed(0), dtype=dtype)
    scale = T[:, :3, 3].norm(dim=-1).clamp_min(1.0)[:, None, None]
    err = (se3.exp(se3.log(T)) - T).abs() / scale
    assert float(err.max()) <= 16 * eps(dtype)


# ----------------------------------------------------------------------------------------------
# Group operations, metrics, interpolation
# ----------------------------------------------------------------------------------------------


def test_compose_inverse_act_against_matrices(dtype):
    g = torch.Generator().manual_seed(1)
    A = se3.random(2, 1, generator=g, dtype=dtype)
    B = se3.random(3, generator=g, dtype=dtype)
    tol = 16 * eps(dtype)
    AB = se3.compose(A, B)
    assert AB.shape == (2, 3, 4, 4)
    torch.testing.assert_close(AB, A @ B, rtol=0, atol=tol)
    assert bool((AB[..., 3, :] == torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=dtype)).all())
    torch.testing.assert_close(se3.inverse(B), torch.linalg.inv(B), rtol=0, atol=tol)
    p = torch.randn(4, 1, 3, dtype=dtype)
    out = se3.act(B, p)
    assert out.shape == (4, 3, 3)
    ph = torch.cat((p, torch.ones_like(p[..., :1])), dim=-1)
    torch.testing.assert_close(out, (B @ ph.unsqueeze(-1)).squeeze(-1)[..., :3], rtol=0, atol=tol)


def test_rotation_and_translation_parts_compose_like_so3():
    g = torch.Generator().manual_seed(2)
    A, B = se3.random(2, 10, generator=g, dtype=F64)
    AB = se3.compose(A, B)
    torch.testing.assert_close(AB[:, :3, :3], so3.compose(A[:, :3, :3], B[:, :3, :3]))
    torch.testing.assert_close(AB[:, :3, 3], so3.act(A[:, :3, :3], B[:, :3, 3]) + A[:, :3, 3])


def test_distance(dtype):
    xi, th = twists(n_random=10)
    xi = xi.to(dtype)
    g = torch.Generator().manual_seed(3)
    A = se3.random(xi.shape[0], generator=g, dtype=dtype)
    B = se3.compose(A, se3.exp(xi))
    angle, trans = se3.distance(A, B)
    torch.testing.assert_close(angle, th.to(dtype), rtol=4 * eps(dtype), atol=8 * eps(dtype))
    # translation of A^-1 B = Exp(xi): |Jl(phi) rho|
    expected = se3.exp(xi)[:, :3, 3].norm(dim=-1)
    torch.testing.assert_close(trans, expected, rtol=16 * eps(dtype), atol=16 * eps(dtype))
    a1, t1 = se3.distance(A[:1], B)
    assert a1.shape == t1.shape == (xi.shape[0],)


@pytest.mark.parametrize("theta", [0.0, PI])
def test_distance_gradient_finite_at_0_and_pi(theta):
    T1 = se3.random(generator=torch.Generator().manual_seed(4), dtype=F64).requires_grad_()
    xi = torch.cat((torch.zeros(3, dtype=F64), theta * unit([1.0, 2.0, 3.0])))
    T2 = se3.compose(T1.detach(), se3.exp(xi)).requires_grad_()
    angle, trans = se3.distance(T1, T2)
    (angle + trans).backward()
    assert bool(torch.isfinite(T1.grad).all()) and bool(torch.isfinite(T2.grad).all())


def test_interpolate(dtype):
    g = torch.Generator().manual_seed(5)
    T0 = se3.random(20, 1, generator=g, dtype=dtype)
    T1 = se3.random(20, 1, generator=g, dtype=dtype)
    ts = torch.tensor([0.0, 0.25, 0.5, 1.0], dtype=dtype)
    out = se3.interpolate(T0, T1, ts)
    assert out.shape == (20, 4, 4, 4)
    tol = 32 * eps(dtype)
    torch.testing.assert_close(out[:, 0], T0[:, 0], rtol=0, atol=tol)
    torch.testing.assert_close(out[:, 3], T1[:, 0], rtol=0, atol=tol)
    # the rotation follows the SO(3) geodesic (slerp), as a screw motion does
    Rs = so3.interpolate(T0[..., :3, :3], T1[..., :3, :3], ts)
    torch.testing.assert_close(out[..., :3, :3], Rs, rtol=0, atol=tol)
    # constant velocity: two half steps make the whole relative motion
    half = se3.between(T0[:, 0], out[:, 2])
    torch.testing.assert_close(
        se3.compose(half, half), se3.between(T0[:, 0], T1[:, 0]), rtol=0, atol=tol
    )


# ----------------------------------------------------------------------------------------------
# Gradients
# ----------------------------------------------------------------------------------------------


def _fd_eps(theta: float) -> float:
    """gradcheck's finite-difference step.  Within 1e-6 of pi a step of 1e-6 can carry the
    rotation past pi, where the log jumps to the reversed axis, so the step must be smaller than
    the distance to pi."""
    return 1e-9 if theta > PI - 1e-5 else 1e-6


def _pose(theta: float, axis=(0.2, -0.7, 0.4), rho=(0.3, -1.0, 0.5)) -> torch.Tensor:
    return torch.cat((torch.tensor(rho, dtype=F64), theta * unit(axis)))


@pytest.mark.parametrize("theta", GRAD_ANGLES)
@pytest.mark.parametrize("axis", [[1.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.2, -0.7, 0.4]])
def test_gradcheck_exp_log(theta, axis):
    xi = _pose(theta, axis).requires_grad_()
    assert gradcheck(se3.exp, (xi,), check_forward_ad=True)
    assert gradgradcheck(se3.exp, (xi,))
    # log on the raw 4x4 matrix (all 16 entries perturbed, off SO(3) as well)
    T = se3.exp(xi.detach()).requires_grad_()
    e = _fd_eps(theta)
    assert gradcheck(se3.log, (T,), eps=e, atol=1e-6, check_forward_ad=True)
    assert gradgradcheck(se3.log, (T,), eps=e, atol=1e-6)


@pytest.mark.parametrize("theta", [0.0, 1e-12, 1e-8, 1e-4, 1.0, PI - 1e-3, PI - 1e-6, PI - 1e-9])
def test_gradcheck_log_in_tangent_coordinates(theta):
    xi = _pose(theta, (0.5, -0.1, 0.3))
    T = se3.exp(xi)

    def f(d):
        return se3.log(se3.rplus(T, d))

    d0 = torch.zeros(6, dtype=F64, requires_grad=True)
    e = 1e-10 if theta > PI - 1e-5 else 1e-6  # stay on this side of pi
    assert gradcheck(f, (d0,), eps=e, atol=1e-5)
    assert gradgradcheck(f, (d0,), eps=e, atol=1e-5)
    J = torch.func.jacrev(f)(d0.detach())
    torch.testing.assert_close(J, se3.jac_right_inv(xi), rtol=0, atol=1e-12)


def test_gradcheck_compose_act():
    # polynomial in the entries: one generic point is enough
    g = torch.Generator().manual_seed(6)
    T0, T1 = (T.requires_grad_() for T in se3.random(2, generator=g, dtype=F64).unbind())
    p = torch.randn(2, 3, generator=g, dtype=F64, requires_grad=True)
    assert gradcheck(se3.compose, (T0, T1), check_forward_ad=True)
    assert gradgradcheck(se3.compose, (T0, T1))
    assert gradcheck(se3.act, (T1, p), check_forward_ad=True)
    assert gradgradcheck(se3.act, (T1, p))


@pytest.mark.parametrize("theta", GRAD_ANGLES)
def test_gradcheck_interpolate(theta):
    # theta is the angle of T0^-1 T1, the point where interpolate's log is evaluated
    g = torch.Generator().manual_seed(6)
    T0 = se3.random(generator=g, dtype=F64)
    T1 = se3.compose(T0, se3.exp(_pose(theta))).requires_grad_()
    T0.requires_grad_()
    t = torch.tensor(0.3, dtype=F64, requires_grad=True)
    e = _fd_eps(theta)
    assert gradcheck(se3.interpolate, (T0, T1, t), eps=e, atol=1e-5)
    assert gradgradcheck(se3.interpolate, (T0, T1, t), eps=e, atol=1e-5)


def test_gradcheck_jacobians():
    xi = _pose(1.0).requires_grad_()
    for f in (se3.jac_left, se3.jac_right, se3.jac_left_inv, se3.jac_right_inv):
        assert gradcheck(f, (xi,))
    # jac_right(xi) = jac_left(-xi), jac_right_inv likewise: the second order once each
    for f in (se3.jac_left, se3.jac_left_inv):
        assert gradgradcheck(f, (xi,))


def test_log_gradient_is_projected_gradient():
    """Ambient gradient = finite differences of log([[polar(R + eps E), t + eps e], [0, 1]])."""
    g = torch.Generator().manual_seed(7)
    h = 1e-7
    for theta in [0.3, 2.0, PI - 1e-4]:
        T = se3.exp(_pose(theta, (0.1, 0.9, -0.4))).requires_grad_()
        u = torch.randn(6, generator=g, dtype=F64)
        (se3.log(T) @ u).backward()
        num = torch.zeros(4, 4, dtype=F64)
        for i in range(4):
            for j in range(4):
                E = torch.zeros(4, 4, dtype=F64)
                E[i, j] = h
                vals = []
                for s in (1.0, -1.0):
                    M = T.detach() + s * E
                    P = se3.from_rt(so3.project(M[:3, :3]), M[:3, 3])
                    vals.append(se3.log(P) @ u)
                num[i, j] = (vals[0] - vals[1]) / (2 * h)
        torch.testing.assert_close(T.grad, num, rtol=0, atol=1e-7)
        assert bool((T.grad[3] == 0).all())  # bottom row: not read
        S = torch.randn(3, 3, generator=g, dtype=F64)
        S = S + S.T
        assert abs(float((T.grad[:3, :3] * (T.detach()[:3, :3] @ S)).sum())) < 1e-12


@pytest.mark.parametrize("axis", [[1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.3, -0.4, 0.9]])
def test_log_gradient_finite_at_exactly_pi(axis, dtype):
    n = unit(axis)
    R = 2 * torch.outer(n, n) - torch.eye(3, dtype=F64)
    T = se3.from_rt(R, torch.tensor([0.5, -1.0, 2.0], dtype=F64)).to(dtype).requires_grad_()
    out = se3.log(T)
    assert bool(torch.isfinite(out).all())
    (g1,) = torch.autograd.grad(
        (out * torch.arange(1.0, 7.0, dtype=dtype)).sum(), T, create_graph=True
    )
    assert bool(torch.isfinite(g1).all())
    (g2,) = torch.autograd.grad(g1.sum(), T)
    assert bool(torch.isfinite(g2).all())
    # forward mode too
    _, tangent = torch.func.jvp(se3.log, (T.detach(),), (torch.ones_like(T),))
    assert bool(torch.isfinite(tangent).all())


def test_gradients_finite_over_sweep(dtype):
    xi, _ = twists(n_random=30)
    xi = xi.to(dtype).requires_grad_()
    out = se3.log(se3.exp(xi))
    (g1,) = torch.autograd.grad((out * torch.randn_like(out)).sum(), xi, create_graph=True)
    assert bool(torch.isfinite(g1).all())
    (g2,) = torch.autograd.grad(g1.sum(), xi)
    assert bool(torch.isfinite(g2).all())


def test_gradient_of_log_exp_is_identity_below_pi(dtype):
    # d log(exp(xi)) / d xi = I wherever the twist is unique (angle < pi)
    xi, _ = twists([a for a in ANGLES if a < PI - 1e-3], n_random=5)
    xi = xi.to(dtype)
    J = torch.func.vmap(torch.func.jacrev(lambda x: se3.log(se3.exp(x))))(xi)
    eye = torch.eye(6, dtype=dtype).expand_as(J)
    scale = xi[:, :3].norm(dim=-1).clamp_min(1.0)[:, None, None]
    assert float(((J - eye).abs() / scale).max()) <= 16 * eps(dtype)


# ----------------------------------------------------------------------------------------------
# Construction, validation, conversions
# ----------------------------------------------------------------------------------------------


def test_random_and_identity():
    g = torch.Generator().manual_seed(8)
    T = se3.random(20000, generator=g, dtype=F64)
    assert bool(se3.is_valid(T).all())
    t = T[:, :3, 3]
    n = 20000**0.5
    assert float(t.mean(0).abs().max()) < 5 / n  # N(0, I): 5-sigma bounds
    assert float((t.std(0) - 1).abs().max()) < 5 * 0.71 / n
    assert float(T[:, :3, :3].mean(0).abs().max()) < 5 * (1 / 3) ** 0.5 / n  # Haar
    a = se3.random(3, generator=torch.Generator().manual_seed(9))
    b = se3.random(3, generator=torch.Generator().manual_seed(9))
    torch.testing.assert_close(a, b, rtol=0, atol=0)
    assert se3.identity(2, 3, dtype=F64).shape == (2, 3, 4, 4)
    torch.testing.assert_close(se3.identity(dtype=F64), torch.eye(4, dtype=F64), rtol=0, atol=0)


def test_is_valid_per_element():
    T = se3.random(7, generator=torch.Generator().manual_seed(10), dtype=F64)
    bad = T.clone()
    bad[1, 3, 0] = 1e-3  # bottom row
    bad[2, 3, 3] = 1.5  # bottom-right entry
    bad[3, :3, :3] *= 1.001  # not orthonormal
    bad[4, :3, :3] *= -1.0  # det -1
    bad[5, 1, 3] = float("nan")  # translation
    bad[6, 0, 3] = float("inf")
    assert se3.is_valid(bad).tolist() == [True] + [False] * 6
    assert se3.is_valid(T).shape == (7,)
    near = T[0].clone()
    near[3, 0] = 1e-7
    assert not bool(se3.is_valid(near))
    assert bool(se3.is_valid(near, atol=1e-6))


def test_from_rt_to_rt(batch, dtype):
    R = so3.random(*batch, generator=torch.Generator().manual_seed(11), dtype=dtype)
    t = torch.randn(*batch, 3, dtype=dtype)
    T = se3.from_rt(R, t)
    assert T.shape == (*batch, 4, 4)
    R2, t2 = se3.to_rt(T)
    torch.testing.assert_close(R2, R, rtol=0, atol=0)
    torch.testing.assert_close(t2, t, rtol=0, atol=0)
    R2.zero_()  # copies: T is untouched
    assert bool(se3.is_valid(T).all())
    # broadcasting: one rotation, many translations
    many = se3.from_rt(so3.identity(dtype=dtype), torch.randn(5, 3, dtype=dtype))
    assert many.shape == (5, 4, 4)


def test_pos_quat_against_scipy(dtype):
    g = torch.Generator().manual_seed(12)
    q = torch.randn(50, 4, generator=g, dtype=F64)
    t = torch.randn(50, 3, generator=g, dtype=F64)
    x = torch.cat((t, q), dim=-1).to(dtype)  # non-unit quaternions: the scale is ignored
    T = se3.from_pos_quat(x)
    ref = torch.tensor(Rotation.from_quat(q[:, [1, 2, 3, 0]].numpy()).as_matrix())
    torch.testing.assert_close(T[:, :3, :3].double(), ref, rtol=0, atol=8 * eps(dtype))
    torch.testing.assert_close(T[:, :3, 3], x[:, :3], rtol=0, atol=0)
    back = se3.to_pos_quat(T)
    qn = quaternion.canonicalize(q / q.norm(dim=-1, keepdim=True)).to(dtype)
    assert bool((back[:, 3] >= 0).all())
    torch.testing.assert_close(back[:, 3:], qn, rtol=0, atol=8 * eps(dtype))
    torch.testing.assert_close(back[:, :3], x[:, :3], rtol=0, atol=0)
    torch.testing.assert_close(se3.from_pos_quat(back), T, rtol=0, atol=8 * eps(dtype))


def test_from_pos_quat_zero_quaternion_gives_a_nan_rotation_block_only(dtype):
    # As documented: no rotation, so that element's rotation block is NaN; its translation
    # column is as given and its bottom row (0, 0, 0, 1); the other element is untouched.
    x = torch.tensor(
        [[1.0, 2.0, 3.0, 1.0, 0.0, 0.0, 0.0], [4.0, -5.0, 6.0, 0.0, 0.0, 0.0, 0.0]],
        dtype=dtype,
        requires_grad=True,
    )
    T = se3.from_pos_quat(x)
    torch.testing.assert_close(
        T[0], se3.from_rt(torch.eye(3, dtype=dtype), x[0, :3]), rtol=0, atol=0
    )
    assert bool(torch.isnan(T[1, :3, :3]).all())
    assert T[1, :3, 3].tolist() == [4.0, -5.0, 6.0]
    assert T[1, 3].tolist() == [0.0, 0.0, 0.0, 1.0]
    # The gradient follows the blocks: finite for both translations and the unit quaternion,
    # NaN for the zero quaternion only.
    (g,) = torch.autograd.grad(T.sum(), x)
    assert bool(torch.isfinite(g[0]).all()) and bool(torch.isfinite(g[1, :3]).all())
    assert g[1, :3].tolist() == [1.0, 1.0, 1.0]
    assert bool(torch.isnan(g[1, 3:]).all())


# ----------------------------------------------------------------------------------------------
# dtypes, batches, bad input, NaN confinement
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("half", [torch.float16, torch.bfloat16])
def test_half_precision_computed_in_float32(half):
    xi = torch.tensor([[0.1, 0.2, 0.3, 0.4, -0.5, 0.6], [1.0, 0.0, -1.0, PI, 0.0, 0.0]]).to(half)
    T = se3.exp(xi)
    assert T.dtype == half
    torch.testing.assert_close(T, se3.exp(xi.float()).to(half), rtol=0, atol=0)
    assert se3.log(T).dtype == half
    torch.testing.assert_close(se3.log(T), se3.log(T.float()).to(half), rtol=0, atol=0)
    torch.testing.assert_close(
        se3.compose(T, T), se3.compose(T.float(), T.float()).to(half), rtol=0, atol=0
    )
    for f in (se3.jac_left, se3.jac_right_inv, se3.ad):
        assert f(xi).dtype == half
    assert se3.adjoint(T).dtype == half
    assert se3.interpolate(T, T, 0.5).dtype == half


def test_batch_shapes(batch, dtype):
    xi = torch.randn(*batch, 6, dtype=dtype)
    T = se3.exp(xi)
    p = torch.randn(*batch, 3, dtype=dtype)
    assert T.shape == (*batch, 4, 4)
    assert se3.log(T).shape == (*batch, 6)
    for f in (se3.jac_left, se3.jac_right, se3.jac_left_inv, se3.jac_right_inv, se3.ad):
        assert f(xi).shape == (*batch, 6, 6)
    assert se3.adjoint(T).shape == (*batch, 6, 6)
    assert se3.compose(T, T).shape == se3.inverse(T).shape == (*batch, 4, 4)
    assert se3.act(T, p).shape == (*batch, 3)
    assert se3.is_valid(T).shape == batch
    assert all(d.shape == batch for d in se3.distance(T, T))
    assert se3.interpolate(T, T, 0.5).shape == (*batch, 4, 4)
    assert se3.to_pos_quat(T).shape == (*batch, 7)
    assert se3.from_pos_quat(se3.to_pos_quat(T)).shape == (*batch, 4, 4)


def test_broadcasting():
    g = torch.Generator().manual_seed(13)
    A = se3.random(2, 1, generator=g, dtype=F64)
    B = se3.random(3, generator=g, dtype=F64)
    assert se3.compose(A, B).shape == (2, 3, 4, 4)
    assert se3.act(A, torch.zeros(5, 1, 1, 3, dtype=F64)).shape == (5, 2, 1, 3)
    assert se3.interpolate(A, B, torch.rand(4, 1, 1, dtype=F64)).shape == (4, 2, 3, 4, 4)
    angle, trans = se3.distance(A, B)
    assert angle.shape == trans.shape == (2, 3)
    torch.testing.assert_close(se3.compose(A, B)[1, 2], se3.compose(A[1, 0], B[2]))


@pytest.mark.parametrize(
    "fn, args",
    [
        (se3.exp, (torch.zeros(4, 3),)),
        (se3.log, (torch.zeros(3, 3),)),
        (se3.hat, (torch.zeros(3),)),
        (se3.vee, (torch.zeros(3, 3),)),
        (se3.compose, (torch.eye(4), torch.eye(3))),
        (se3.inverse, (torch.eye(3),)),
        (se3.act, (torch.eye(4), torch.zeros(4))),
        (se3.adjoint, (torch.zeros(6, 6),)),
        (se3.jac_left, (torch.zeros(3),)),
        (se3.jac_right_inv, (torch.zeros(7),)),
        (se3.from_rt, (torch.eye(3), torch.zeros(4))),
        (se3.from_pos_quat, (torch.zeros(6),)),
        (se3.to_pos_quat, (torch.eye(3),)),
        (se3.interpolate, (torch.eye(4), torch.eye(3), 0.5)),
        (se3.distance, (torch.eye(4), torch.eye(3))),
        (se3.is_valid, (torch.eye(3),)),
    ],
)
def test_wrong_shape_raises_value_error_naming_function(fn, args):
    with pytest.raises(ValueError, match=rf"torchlie\.se3\.{fn.__name__}: expected .* got"):
        fn(*args)


def test_bad_dtype_and_broadcast():
    with pytest.raises(TypeError, match=r"torchlie\.se3\.exp: .*floating-point.*int64"):
        se3.exp(torch.zeros(6, dtype=torch.int64))
    with pytest.raises(TypeError, match=r"torchlie\.se3\.log: expected T to be a torch.Tensor"):
        se3.log(np.eye(4))
    with pytest.raises(TypeError, match="one dtype"):
        se3.compose(torch.eye(4), torch.eye(4, dtype=F64))
    with pytest.raises(TypeError, match="one dtype"):
        se3.act(torch.eye(4), torch.zeros(3, dtype=F64))
    with pytest.raises(ValueError, match=r"se3\.compose: batch shapes do not broadcast"):
        se3.compose(torch.eye(4).expand(2, 4, 4), torch.eye(4).expand(3, 4, 4))
    with pytest.raises(TypeError, match=r"se3\.interpolate: expected t"):
        se3.interpolate(torch.eye(4), torch.eye(4), torch.tensor(1))


def test_nan_stays_in_its_element(dtype):
    xi = torch.randn(4, 6, dtype=dtype)
    xi[1, 4] = float("nan")
    T = se3.exp(xi)
    assert bool(torch.isnan(T[1, :3]).any())
    keep = [0, 2, 3]
    torch.testing.assert_close(T[keep], se3.exp(xi[keep]), rtol=0, atol=0)
    out = se3.log(T)
    assert bool(torch.isnan(out[1]).all())
    torch.testing.assert_close(out[keep], se3.log(T[keep]), rtol=0, atol=0)
    B = se3.random(4, generator=torch.Generator().manual_seed(14), dtype=dtype)
    torch.testing.assert_close(se3.compose(T, B)[keep], se3.compose(T[keep], B[keep]))
    torch.testing.assert_close(
        se3.interpolate(T, B, 0.3)[keep], se3.interpolate(T[keep], B[keep], 0.3)
    )
    xi.requires_grad_()
    (g,) = torch.autograd.grad(se3.log(se3.exp(xi)).sum(), xi)
    assert bool(torch.isfinite(g[keep]).all())


def test_on_device(device):
    xi, _ = twists([a for a in ANGLES if a < PI - 1e-3], n_random=4)
    x = xi.to(device=device, dtype=torch.float32).requires_grad_()
    T = se3.exp(x)
    assert T.device.type == device
    scale = xi[:, :3].norm(dim=-1).clamp_min(1.0)[:, None, None]
    assert float(((T.detach().cpu().double() - se3.exp(xi)).abs() / scale).max()) <= 8e-7
    out = se3.log(se3.compose(T, se3.inverse(T.detach())) @ T)
    assert float(((out.detach().cpu().double() - xi).abs() / scale[..., 0]).max()) <= 1e-6
    (g,) = torch.autograd.grad(out.sum(), x)
    assert g.device.type == device and bool(torch.isfinite(g).all())
    p = torch.randn(len(xi), 3, device=device)
    ref = se3.act(T.detach().cpu(), p.cpu())
    torch.testing.assert_close(se3.act(T.detach(), p).cpu(), ref)


def test_vmap_and_forward_mode():
    g = torch.Generator().manual_seed(15)
    xi = torch.randn(6, 6, generator=g, dtype=F64)
    T = se3.exp(xi)
    B = se3.random(6, generator=g, dtype=F64)
    p = torch.randn(6, 3, generator=g, dtype=F64)
    vmap = torch.func.vmap
    torch.testing.assert_close(vmap(se3.exp)(xi), T)
    torch.testing.assert_close(vmap(se3.log)(T), se3.log(T))
    torch.testing.assert_close(vmap(se3.compose)(T, B), se3.compose(T, B))
    torch.testing.assert_close(vmap(se3.act)(T, p), se3.act(T, p))
    torch.testing.assert_close(vmap(se3.jac_left)(xi), se3.jac_left(xi))
    torch.testing.assert_close(
        vmap(se3.interpolate, in_dims=(0, 0, None))(T, B, 0.25), se3.interpolate(T, B, 0.25)
    )
    Jr = vmap(torch.func.jacrev(se3.log))(T)
    Jf = vmap(torch.func.jacfwd(se3.log))(T)
    assert Jr.shape == (6, 6, 4, 4)
    torch.testing.assert_close(Jr, Jf)


@pytest.mark.compile
@pytest.mark.slow
def test_compile_fullgraph_matches_eager():
    def f(xi, T, p):
        X = se3.compose(T, se3.exp(xi))
        return se3.log(X), se3.act(se3.inverse(X), p), se3.adjoint(X)

    def h(T0, T1, t):
        return se3.log(se3.interpolate(T0, T1, t))

    # float32 (one graph is enough for the compile check)
    g = torch.Generator().manual_seed(16)
    F32 = torch.float32
    xi = torch.randn(5, 6, generator=g, dtype=F32)
    T = se3.random(5, generator=g, dtype=F32)
    p = torch.randn(5, 3, generator=g, dtype=F32)
    t = torch.rand(5, generator=g, dtype=F32)
    compiled = torch.compile(f, fullgraph=True)  # inductor: the path users get
    for got, want in zip(compiled(xi, T, p), f(xi, T, p), strict=True):
        torch.testing.assert_close(got, want)
    # Gradients through the compiled graph (the log's custom Function without jvp, forward and
    # backward traced by AOTAutograd).  aot_eager checks exactly that tracing without paying
    # inductor's code generation a second time.
    ch = torch.compile(h, fullgraph=True, backend="aot_eager")
    Tg = T.clone().requires_grad_()
    (gc,) = torch.autograd.grad((ch(Tg, T.flip(0), t) * p.repeat(1, 2)).sum(), Tg)
    (ge,) = torch.autograd.grad((h(Tg, T.flip(0), t) * p.repeat(1, 2)).sum(), Tg)
    torch.testing.assert_close(gc, ge)


# ----------------------------------------------------------------------------------------------
# compose / inverse / act: custom backward and forward mode, bottom rows never read
# ----------------------------------------------------------------------------------------------


def _raw_4x4(*batch, seed):
    """Arbitrary 4x4 matrices (not poses): the three ops are polynomial in the entries read."""
    g = torch.Generator().manual_seed(seed)
    return torch.randn(*batch, 4, 4, generator=g, dtype=F64, requires_grad=True)


@pytest.mark.parametrize(
    "fn, make",
    [
        (se3.compose, lambda: (_raw_4x4(2, 1, seed=20), _raw_4x4(3, seed=21))),
        (se3.compose, lambda: (_raw_4x4(seed=22), _raw_4x4(2, seed=23))),
        (se3.inverse, lambda: (_raw_4x4(2, 3, seed=24),)),
        (se3.act, lambda: (_raw_4x4(2, 1, seed=25), torch.randn(3, 3, dtype=F64).requires_grad_())),
        (se3.act, lambda: (_raw_4x4(3, seed=26), torch.randn(3, dtype=F64).requires_grad_())),
    ],
)
def test_group_ops_gradcheck_with_broadcasting(fn, make):
    args = make()
    assert gradcheck(fn, args, check_forward_ad=True)
    assert gradgradcheck(fn, args, check_fwd_over_rev=True)
    # the bottom rows are not read, so their gradient is exactly zero
    out = fn(*args)
    grads = torch.autograd.grad(out, args, torch.randn_like(out))
    for x, gx in zip(args, grads, strict=True):
        assert gx.shape == x.shape
        if x.shape[-2:] == (4, 4):
            assert bool((gx[..., 3, :] == 0).all())


@pytest.mark.parametrize("grad", [False, True])
def test_group_ops_ignore_bottom_rows(grad):
    g = torch.Generator().manual_seed(27)
    A, B = se3.random(2, 5, generator=g, dtype=F64)
    p = torch.randn(5, 3, generator=g, dtype=F64)
    bad_A, bad_B = A.clone(), B.clone()
    bad_A[..., 3, :] = torch.nan
    bad_B[..., 3, :] = torch.tensor([1.0, -2.0, 3.0, 7.0], dtype=F64)
    if grad:
        bad_A.requires_grad_()
        bad_B.requires_grad_()
    cases = [
        (se3.compose(bad_A, bad_B), se3.compose(A, B)),
        (se3.inverse(bad_A), se3.inverse(A)),
        (se3.act(bad_A, p), se3.act(A, p)),
    ]
    for got, want in cases:
        torch.testing.assert_close(got, want, rtol=0, atol=0)
    if grad:
        total = sum((got * torch.randn_like(got)).sum() for got, _ in cases)
        gA, gB = torch.autograd.grad(total, (bad_A, bad_B))
        assert bool(torch.isfinite(gA).all()) and bool(torch.isfinite(gB).all())
        assert bool((gA[..., 3, :] == 0).all()) and bool((gB[..., 3, :] == 0).all())


def test_group_ops_reverse_mode_matches_forward_mode_under_vmap():
    g = torch.Generator().manual_seed(28)
    A, B = se3.random(2, 4, generator=g, dtype=F64)
    p = torch.randn(4, 3, generator=g, dtype=F64)
    vmap, jacrev, jacfwd = torch.func.vmap, torch.func.jacrev, torch.func.jacfwd
    for fn, args in ((se3.compose, (A, B)), (se3.inverse, (A,)), (se3.act, (A, p))):
        for i in range(len(args)):
            Jr = vmap(jacrev(fn, argnums=i))(*args)
            Jf = vmap(jacfwd(fn, argnums=i))(*args)
            torch.testing.assert_close(Jr, Jf, rtol=0, atol=1e-14)
    # vmap of a call that records a graph (the custom Functions' generated vmap rule)
    Ag = A.clone().requires_grad_()
    for fn, rest in ((se3.compose, (B,)), (se3.inverse, ()), (se3.act, (p,))):
        w = torch.randn_like(fn(A, *rest))
        (got,) = torch.autograd.grad((vmap(fn)(Ag, *rest) * w).sum(), Ag)
        (want,) = torch.autograd.grad((fn(Ag, *rest) * w).sum(), Ag)
        torch.testing.assert_close(got, want, rtol=0, atol=1e-14)


@pytest.mark.parametrize("half", [torch.float16, torch.bfloat16])
def test_inverse_act_half_precision_computed_in_float32(half):
    T = se3.random(3, generator=torch.Generator().manual_seed(29)).to(half)
    p = torch.randn(3, 3).to(half)
    for got, want in (
        (se3.inverse(T), se3.inverse(T.float())),
        (se3.act(T, p), se3.act(T.float(), p.float())),
    ):
        assert got.dtype == half
        torch.testing.assert_close(got, want.to(half), rtol=0, atol=0)


@pytest.mark.compile
def test_group_ops_backward_compiles_fullgraph():
    def f(A, B, p):
        return (se3.act(se3.inverse(se3.compose(A, B)), p) ** 2).sum()

    g = torch.Generator().manual_seed(30)
    A, B = se3.random(2, 3, generator=g, dtype=F64)
    p = torch.randn(3, 3, generator=g, dtype=F64, requires_grad=True)
    A.requires_grad_()
    compiled = torch.compile(f, fullgraph=True, backend="aot_eager")
    got = torch.autograd.grad(compiled(A, B, p), (A, p))
    want = torch.autograd.grad(f(A, B, p), (A, p))
    for a, b in zip(got, want, strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-13)
