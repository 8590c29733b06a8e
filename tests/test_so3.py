"""torchlie.so3: literal formulas, scipy as the oracle, properties, gradients, bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from samplers import ANGLES, GRAD_ANGLES, PI, axes, eps, rotvecs, unit
from scipy.spatial.transform import Rotation, Slerp

from torchlie import _coeffs, so3

F64 = torch.float64


# ----------------------------------------------------------------------------------------------
# Textbook formulas, pinned
# ----------------------------------------------------------------------------------------------


def test_rodrigues_literal():
    n = unit([1.0, 2.0, -2.0])
    t = 0.7
    K = torch.tensor([[0, -n[2], n[1]], [n[2], 0, -n[0]], [-n[1], n[0], 0]], dtype=F64)
    expected = torch.eye(3, dtype=F64) + math.sin(t) * K + (1 - math.cos(t)) * K @ K
    torch.testing.assert_close(so3.exp(t * n), expected, rtol=0, atol=4 * eps(F64))


def test_rotate_e2_by_pi_over_3_about_x():
    R = so3.exp(torch.tensor([PI / 3, 0.0, 0.0], dtype=F64))
    p = so3.act(R, torch.tensor([0.0, 1.0, 0.0], dtype=F64))
    expected = torch.tensor([0.0, math.cos(PI / 3), math.sin(PI / 3)], dtype=F64)
    torch.testing.assert_close(p, expected, rtol=0, atol=2 * eps(F64))


@pytest.mark.parametrize(
    "R, omega",
    [
        (np.diag([1.0, -1.0, -1.0]), [PI, 0, 0]),
        (np.diag([-1.0, 1.0, -1.0]), [0, PI, 0]),
        (np.diag([-1.0, -1.0, 1.0]), [0, 0, PI]),
        # pi about (1, 1, 0)/sqrt2: R = 2 n n^T - I
        ([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]], [PI / 2**0.5, PI / 2**0.5, 0]),
        # pi about (1, -1, 0)/sqrt2: the canonical sign makes the first (tied) component positive
        ([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]], [PI / 2**0.5, -PI / 2**0.5, 0]),
        # pi about (-1, 2, 2)/3: largest-magnitude component (y, first on the tie) positive
        (
            (2 * np.outer([-1, 2, 2], [-1, 2, 2]) / 9 - np.eye(3)).tolist(),
            [-PI / 3, 2 * PI / 3, 2 * PI / 3],
        ),
    ],
)
def test_log_trace_minus_one(R, omega):
    R = torch.tensor(R, dtype=F64)
    assert float(R.diagonal().sum()) == pytest.approx(-1.0)
    torch.testing.assert_close(so3.log(R), torch.tensor(omega, dtype=F64), rtol=0, atol=1e-15)


# ----------------------------------------------------------------------------------------------
# scipy as the oracle
# ----------------------------------------------------------------------------------------------


def test_exp_log_match_scipy(dtype):
    w, _ = rotvecs(n_random=40)
    ref = torch.tensor(Rotation.from_rotvec(w.numpy()).as_matrix())
    R = so3.exp(w.to(dtype))
    torch.testing.assert_close(R.double(), ref, rtol=0, atol=8 * eps(dtype))
    # log of scipy's matrix: compare as rotations (the sign is ambiguous only at pi)
    back = so3.exp(so3.log(ref.to(dtype)).double())
    torch.testing.assert_close(back, ref, rtol=0, atol=16 * eps(dtype))


def test_log_below_pi_matches_scipy_rotvec():
    g = torch.Generator().manual_seed(3)
    R = so3.random(500, generator=g, dtype=F64)
    ref = torch.tensor(Rotation.from_matrix(R.numpy()).as_rotvec())
    torch.testing.assert_close(so3.log(R), ref, rtol=0, atol=1e-14)


# ----------------------------------------------------------------------------------------------
# Properties
# ----------------------------------------------------------------------------------------------


def test_hat_vee(batch, dtype):
    w = torch.randn(*batch, 3, dtype=dtype)
    H = so3.hat(w)
    assert H.shape == (*batch, 3, 3)
    torch.testing.assert_close(H, -H.transpose(-1, -2), rtol=0, atol=0)
    torch.testing.assert_close(so3.vee(H), w, rtol=0, atol=0)
    v = torch.randn(*batch, 3, dtype=dtype)
    torch.testing.assert_close((H @ v.unsqueeze(-1)).squeeze(-1), torch.linalg.cross(w, v))


def test_log_exp_roundtrip_below_pi(dtype):
    w, th = rotvecs([a for a in ANGLES if a < PI - 1e-3], n_random=50, dtype=dtype)
    out = so3.log(so3.exp(w))
    err = (out - w).norm(dim=-1) / w.norm(dim=-1).clamp_min(torch.finfo(dtype).tiny)
    err = torch.where(w.norm(dim=-1) == 0, (out - w).norm(dim=-1), err)
    assert float(err.max()) <= 8 * eps(dtype)


def test_exp_log_roundtrip_random(dtype):
    R = so3.random(300, generator=torch.Generator().manual_seed(0), dtype=dtype)
    torch.testing.assert_close(so3.exp(so3.log(R)), R, rtol=0, atol=16 * eps(dtype))


def test_conjugation_equals_exp_of_rotated_vector(dtype):
    g = torch.Generator().manual_seed(1)
    R = so3.random(100, generator=g, dtype=dtype)
    w, _ = rotvecs([0.0, 1e-8, 1.0, 3.0, PI - 1e-6], n_random=16, dtype=dtype)
    w = w[:100]
    lhs = R @ so3.exp(w) @ R.transpose(-1, -2)
    rhs = so3.exp(so3.act(R, w))
    torch.testing.assert_close(lhs, rhs, rtol=0, atol=16 * eps(dtype))
    torch.testing.assert_close(so3.adjoint(R), R)


def test_jacobian_identities(dtype):
    w, _ = rotvecs([0.0, 1e-12, 1e-6, 1e-2, 1.0, 3.0, PI - 1e-6, PI], n_random=20, dtype=dtype)
    eye = torch.eye(3, dtype=dtype)
    tol = 64 * eps(dtype)
    torch.testing.assert_close(so3.jac_left(w), so3.jac_right(-w), rtol=0, atol=tol)
    torch.testing.assert_close(so3.jac_left(w), so3.jac_right(w).mT, rtol=0, atol=tol)
    torch.testing.assert_close(
        so3.jac_left(w) @ so3.jac_left_inv(w), eye.expand_as(so3.hat(w)), rtol=0, atol=tol
    )
    torch.testing.assert_close(
        so3.jac_right_inv(w) @ so3.jac_right(w), eye.expand_as(so3.hat(w)), rtol=0, atol=tol
    )
    # Jl = R Jr (Ad_Exp(w) = Exp(w))
    torch.testing.assert_close(so3.jac_left(w), so3.exp(w) @ so3.jac_right(w), rtol=0, atol=tol)


@pytest.mark.parametrize("theta", [0.0, 1e-8, 1e-3, 1.0, 3.0, PI - 1e-6])
def test_jacobians_equal_jacrev_in_tangent_coordinates(theta):
    w = theta * unit([0.3, -0.5, 0.8])
    d0 = torch.zeros(3, dtype=F64)
    R = so3.exp(w)
    # Exp(w + d) = Exp(w) Exp(Jr d)  ->  d/dd Log(Exp(w)^T Exp(w + d)) = Jr
    jr = torch.func.jacrev(lambda d: so3.log(R.mT @ so3.exp(w + d)))(d0)
    torch.testing.assert_close(jr, so3.jac_right(w), rtol=0, atol=1e-12)
    jl = torch.func.jacrev(lambda d: so3.log(so3.exp(w + d) @ R.mT))(d0)
    torch.testing.assert_close(jl, so3.jac_left(w), rtol=0, atol=1e-12)
    # Log(R Exp(d)) = w + Jr^-1 d
    jri = torch.func.jacrev(lambda d: so3.log(R @ so3.exp(d)))(d0)
    torch.testing.assert_close(jri, so3.jac_right_inv(w), rtol=0, atol=1e-12)
    jli = torch.func.jacfwd(lambda d: so3.log(so3.exp(d) @ R))(d0)
    torch.testing.assert_close(jli, so3.jac_left_inv(w), rtol=0, atol=1e-12)


def test_group_axioms_and_broadcasting(dtype):
    g = torch.Generator().manual_seed(2)
    A = so3.random(2, 1, generator=g, dtype=dtype)
    B = so3.random(3, generator=g, dtype=dtype)
    C = so3.random(1, 3, generator=g, dtype=dtype)
    tol = 16 * eps(dtype)
    AB = so3.compose(A, B)
    assert AB.shape == (2, 3, 3, 3)
    torch.testing.assert_close(
        so3.compose(AB, C), so3.compose(A, so3.compose(B, C)), rtol=0, atol=tol
    )
    eye = so3.identity(2, 3, dtype=dtype)
    torch.testing.assert_close(so3.compose(AB, so3.inverse(AB)), eye, rtol=0, atol=tol)
    torch.testing.assert_close(so3.compose(so3.identity(dtype=dtype), B), B, rtol=0, atol=0)
    p = torch.randn(4, 1, 3, dtype=dtype)
    assert so3.act(B, p).shape == (4, 3, 3)
    torch.testing.assert_close(so3.act(B, p), (B @ p.unsqueeze(-1)).squeeze(-1))


def test_random_is_haar_and_valid():
    g = torch.Generator().manual_seed(5)
    R = so3.random(20000, generator=g, dtype=F64)
    assert bool(so3.is_valid(R).all())
    # Haar: E[R] = 0 and E[tr R] = 0 (trace variance 1): 5-sigma bounds
    assert float(R.mean(0).abs().max()) < 5 * (1 / 3) ** 0.5 / 20000**0.5
    # the angle has density (1 - cos t)/pi on [0, pi]: mean angle pi/2 + 2/pi
    t = so3.log(R).norm(dim=-1)
    assert abs(float(t.mean()) - (PI / 2 + 2 / PI)) < 5 * 0.65 / 20000**0.5
    same = so3.random(3, generator=torch.Generator().manual_seed(9))
    again = so3.random(3, generator=torch.Generator().manual_seed(9))
    torch.testing.assert_close(same, again, rtol=0, atol=0)


def test_is_valid_per_element():
    R = so3.random(4, generator=torch.Generator().manual_seed(0), dtype=F64)
    bad = R.clone()
    bad[1] = bad[1] * 1.001
    bad[2] = -bad[2]  # det -1
    bad[3, 0, 0] = float("nan")
    assert so3.is_valid(bad).tolist() == [True, False, False, False]
    assert bool(so3.is_valid(R[0] * (1 + 1e-7), atol=1e-6))


def test_project(dtype):
    g = torch.Generator().manual_seed(4)
    R = so3.random(50, generator=g, dtype=dtype)
    torch.testing.assert_close(so3.project(R), R, rtol=0, atol=16 * eps(dtype))
    M = R + 0.2 * torch.randn(50, 3, 3, generator=g, dtype=dtype)
    P = so3.project(M)
    assert bool(so3.is_valid(P).all())
    # nearest rotation: compare with numpy's SVD (float64)
    U, _, Vt = np.linalg.svd(M.double().numpy())
    d = np.sign(np.linalg.det(U @ Vt))
    ref = U @ (np.concatenate([np.ones((50, 2)), d[:, None]], 1)[..., None] * Vt)
    torch.testing.assert_close(P.double(), torch.tensor(ref), rtol=0, atol=64 * eps(dtype))
    # reflections are fixed to det +1
    assert bool((torch.linalg.det(so3.project(-R)) > 0).all())


def test_project_gradients():
    g = torch.Generator().manual_seed(6)
    M = so3.random(3, generator=g, dtype=F64) + 0.3 * torch.randn(3, 3, 3, generator=g, dtype=F64)
    assert torch.autograd.gradcheck(so3.project, (M.requires_grad_(),), check_forward_ad=True)
    # at a rotation (all singular values equal) the gradient is finite and tangent
    R = so3.random(3, generator=g, dtype=F64).requires_grad_()
    G = torch.randn(3, 3, 3, generator=g, dtype=F64)
    (so3.project(R) * G).sum().backward()
    assert bool(torch.isfinite(R.grad).all())
    assert torch.autograd.gradcheck(so3.project, (R.detach().requires_grad_(),))


def test_distance(dtype):
    w, th = rotvecs(ANGLES, n_random=10, dtype=dtype)
    g = torch.Generator().manual_seed(7)
    A = so3.random(w.shape[0], generator=g, dtype=dtype)
    B = A @ so3.exp(w)
    d = so3.distance(A, B)
    torch.testing.assert_close(d, th, rtol=4 * eps(dtype), atol=8 * eps(dtype))
    assert so3.distance(A[:1], B).shape == (w.shape[0],)


@pytest.mark.parametrize("theta", [0.0, PI])
def test_distance_gradient_finite_at_0_and_pi(theta):
    R1 = so3.random(generator=torch.Generator().manual_seed(8), dtype=F64).requires_grad_()
    R2 = (R1.detach() @ so3.exp(theta * unit([1.0, 2.0, 3.0]))).requires_grad_()
    so3.distance(R1, R2).backward()
    assert bool(torch.isfinite(R1.grad).all()) and bool(torch.isfinite(R2.grad).all())


def test_interpolate_matches_scipy_slerp(dtype):
    g = torch.Generator().manual_seed(9)
    R0 = so3.random(20, generator=g, dtype=F64)
    R1 = so3.random(20, generator=g, dtype=F64)
    ts = torch.tensor([0.0, 0.25, 0.5, 1.0], dtype=F64)
    out = so3.interpolate(R0.to(dtype)[:, None], R1.to(dtype)[:, None], ts.to(dtype))
    assert out.shape == (20, 4, 3, 3)
    for i in range(20):
        s = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([R0[i].numpy(), R1[i].numpy()])))
        ref = torch.tensor(s(ts.numpy()).as_matrix())
        torch.testing.assert_close(out[i].double(), ref, rtol=0, atol=64 * eps(dtype))
    torch.testing.assert_close(out[:, 0], R0.to(dtype), rtol=0, atol=16 * eps(dtype))
    torch.testing.assert_close(out[:, -1], R1.to(dtype), rtol=0, atol=16 * eps(dtype))


# ----------------------------------------------------------------------------------------------
# Gradients
# ----------------------------------------------------------------------------------------------


def _fd_eps(theta: float) -> float:
    """Finite-difference step for gradcheck: smaller than the distance to a non-smooth point."""
    return 1e-9 if theta > PI - 1e-5 else 1e-6


@pytest.mark.parametrize("theta", GRAD_ANGLES)
@pytest.mark.parametrize("axis", [[1.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.2, -0.7, 0.4]])
def test_gradcheck_exp_log_distance(theta, axis):
    w = (theta * unit(axis)).requires_grad_()
    assert torch.autograd.gradcheck(so3.exp, (w,), check_forward_ad=True)
    assert torch.autograd.gradgradcheck(so3.exp, (w,))
    R = so3.exp(w.detach()).requires_grad_()
    e = _fd_eps(theta)
    assert torch.autograd.gradcheck(so3.log, (R,), eps=e, atol=1e-6, check_forward_ad=True)
    assert torch.autograd.gradgradcheck(so3.log, (R,), eps=e, atol=1e-6)
    R0 = so3.random(generator=torch.Generator().manual_seed(0), dtype=F64)
    R1 = (R0 @ R.detach()).requires_grad_()
    # The angle is non-smooth at 0 (a cone) and at pi (a ridge): the step must stay below the
    # distance to those points, and the Hessian there scales like 1/dist, so the second-order
    # check uses a tolerance relative to that scale (1e-5 of it).
    dist = min(theta, PI - theta)
    e = 1e-10 if theta < 1e-6 else e
    assert torch.autograd.gradcheck(so3.distance, (R0.requires_grad_(), R1), eps=e, atol=1e-5)
    e2 = 1e-10 if dist < 1e-5 else 1e-6
    assert torch.autograd.gradgradcheck(so3.distance, (R0, R1), eps=e2, atol=1e-5 / dist)


@pytest.mark.parametrize("theta", GRAD_ANGLES)
def test_gradcheck_interpolate_and_jacobians(theta):
    w = (theta * unit([0.5, -0.1, 0.3])).requires_grad_()
    t = torch.tensor(0.3, dtype=F64, requires_grad=True)
    R0 = so3.random(generator=torch.Generator().manual_seed(1), dtype=F64)
    R1 = R0 @ so3.exp(w.detach())
    e = _fd_eps(theta)
    assert torch.autograd.gradcheck(
        so3.interpolate, (R0.requires_grad_(), R1.requires_grad_(), t), eps=e, atol=1e-5
    )
    for f in (so3.jac_left, so3.jac_right, so3.jac_left_inv, so3.jac_right_inv):
        assert torch.autograd.gradcheck(f, (w,))
        assert torch.autograd.gradgradcheck(f, (w,))


def test_log_gradient_is_projected_gradient():
    """The ambient gradient equals finite differences of log(polar(R + eps E))."""
    g = torch.Generator().manual_seed(11)
    for theta in [0.3, 2.0, PI - 1e-4]:
        R = so3.exp(theta * unit([0.1, 0.9, -0.4])).requires_grad_()
        u = torch.randn(3, generator=g, dtype=F64)
        (so3.log(R) @ u).backward()
        num = torch.zeros(3, 3, dtype=F64)
        h = 1e-7
        for i in range(3):
            for j in range(3):
                E = torch.zeros(3, 3, dtype=F64)
                E[i, j] = h
                plus = so3.log(so3.project(R.detach() + E)) @ u
                minus = so3.log(so3.project(R.detach() - E)) @ u
                num[i, j] = (plus - minus) / (2 * h)
        torch.testing.assert_close(R.grad, num, rtol=0, atol=1e-7)
        # zero along normal directions R S (S symmetric)
        S = torch.randn(3, 3, generator=g, dtype=F64)
        S = S + S.T
        assert abs(float((R.grad * (R.detach() @ S)).sum())) < 1e-12


@pytest.mark.parametrize("axis", [[1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.3, -0.4, 0.9]])
def test_log_gradient_finite_at_exactly_pi(axis, dtype):
    n = unit(axis)
    R = (2 * torch.outer(n, n) - torch.eye(3, dtype=F64)).to(dtype).requires_grad_()
    out = so3.log(R)
    assert torch.isfinite(out).all()
    grads = torch.autograd.grad(out.sum(), R, create_graph=True)[0]
    assert bool(torch.isfinite(grads).all())
    (gg,) = torch.autograd.grad(grads.sum(), R)
    assert bool(torch.isfinite(gg).all())


def test_gradients_finite_over_sweep(dtype):
    w, _ = rotvecs(ANGLES, n_random=30, dtype=dtype)
    w.requires_grad_()
    R = so3.exp(w)
    out = so3.log(R)
    (g1,) = torch.autograd.grad((out * torch.randn_like(out)).sum(), w, create_graph=True)
    assert bool(torch.isfinite(g1).all())
    (g2,) = torch.autograd.grad(g1.sum(), w)
    assert bool(torch.isfinite(g2).all())


# ----------------------------------------------------------------------------------------------
# dtypes, batches, bad input, NaN confinement
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("half", [torch.float16, torch.bfloat16])
def test_half_precision_computed_in_float32(half):
    w = torch.tensor([[0.1, 0.2, 0.3], [PI, 0.0, 0.0]])
    w = w.to(half)
    R = so3.exp(w)
    assert R.dtype == half
    torch.testing.assert_close(R, so3.exp(w.float()).to(half), rtol=0, atol=0)
    torch.testing.assert_close(so3.log(R), so3.log(R.float()).to(half), rtol=0, atol=0)
    assert so3.log(R).dtype == half
    assert so3.jac_left(w.to(half)).dtype == half


def test_batch_shapes(batch, dtype):
    w = torch.randn(*batch, 3, dtype=dtype)
    R = so3.exp(w)
    assert R.shape == (*batch, 3, 3)
    assert so3.log(R).shape == (*batch, 3)
    for f in (so3.jac_left, so3.jac_right, so3.jac_left_inv, so3.jac_right_inv):
        assert f(w).shape == (*batch, 3, 3)
    assert so3.distance(R, R).shape == batch
    assert so3.is_valid(R).shape == batch
    assert so3.project(R).shape == (*batch, 3, 3)
    assert so3.interpolate(R, R, 0.5).shape == (*batch, 3, 3)
    assert so3.identity(*batch, dtype=dtype).shape == (*batch, 3, 3)


@pytest.mark.parametrize(
    "fn, args",
    [
        (so3.exp, (torch.zeros(4, 2),)),
        (so3.log, (torch.zeros(3, 4),)),
        (so3.hat, (torch.zeros(2),)),
        (so3.vee, (torch.zeros(3),)),
        (so3.act, (torch.eye(3), torch.zeros(2))),
        (so3.compose, (torch.eye(3), torch.eye(4))),
        (so3.jac_left, (torch.zeros(4),)),
        (so3.project, (torch.zeros(2, 2),)),
    ],
)
def test_wrong_shape_raises_value_error_naming_function(fn, args):
    with pytest.raises(ValueError, match=rf"torchlie\.so3\.{fn.__name__}: expected .* got"):
        fn(*args)


def test_bad_dtype_and_broadcast():
    with pytest.raises(TypeError, match=r"torchlie\.so3\.exp: .*floating-point.*int64"):
        so3.exp(torch.zeros(3, dtype=torch.int64))
    with pytest.raises(TypeError, match=r"torchlie\.so3\.log: expected R to be a torch.Tensor"):
        so3.log([[1, 0, 0], [0, 1, 0], [0, 0, 1]])
    with pytest.raises(TypeError, match="one dtype"):
        so3.compose(torch.eye(3), torch.eye(3, dtype=F64))
    with pytest.raises(ValueError, match=r"so3\.compose: batch shapes do not broadcast"):
        so3.compose(torch.eye(3).expand(2, 3, 3), torch.eye(3).expand(3, 3, 3))


def test_nan_stays_in_its_element(dtype):
    w = torch.randn(4, 3, dtype=dtype)
    w[1, 0] = float("nan")
    R = so3.exp(w)
    assert bool(torch.isnan(R[1]).any())
    clean = torch.cat((R[:1], R[2:]))
    assert bool(torch.isfinite(clean).all())
    torch.testing.assert_close(clean, so3.exp(torch.cat((w[:1], w[2:]))), rtol=0, atol=0)
    out = so3.log(R)
    assert bool(torch.isnan(out[1]).all())
    torch.testing.assert_close(torch.cat((out[:1], out[2:])), so3.log(clean), rtol=0, atol=0)
    # gradients of the clean elements stay clean too
    w.requires_grad_()
    (g,) = torch.autograd.grad(so3.log(so3.exp(w)).sum(), w)
    assert bool(torch.isfinite(torch.cat((g[:1], g[2:]))).all())


def test_vmap_and_jacrev():
    w = torch.randn(6, 3, dtype=F64)
    torch.testing.assert_close(torch.func.vmap(so3.exp)(w), so3.exp(w))
    R = so3.exp(w)
    torch.testing.assert_close(torch.func.vmap(so3.log)(R), so3.log(R))
    J = torch.func.vmap(torch.func.jacrev(so3.exp))(w)
    Jf = torch.func.vmap(torch.func.jacfwd(so3.exp))(w)
    assert J.shape == (6, 3, 3, 3)
    torch.testing.assert_close(J, Jf)
    torch.testing.assert_close(
        torch.func.vmap(so3.distance)(R, R.flip(0)), so3.distance(R, R.flip(0))
    )


def test_axes_sampler_covers_hard_axes():
    a = axes(n_random=0)
    assert torch.allclose(a.norm(dim=-1), torch.ones(len(a), dtype=F64))
    assert len(a) == 6 + 8 + 4


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("parts", ["abd", "abc", "d", "ca"])
def test_rodrigues_values_computes_the_parts_asked_for(dtype, parts):
    """The forward-only coefficients asked for by letter are those of the full set, bit for bit,
    in the order asked (every angle of the sampler: 0, tiny, pi and just below)."""
    w, _ = rotvecs(n_random=20, dtype=dtype)
    full = dict(zip("abcd", _coeffs.rodrigues_values(w), strict=True))
    got = _coeffs.rodrigues_values(w, parts)
    assert len(got) == len(parts)
    for k, v in zip(parts, got, strict=True):
        assert torch.equal(v, full[k]), k
