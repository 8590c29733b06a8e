"""torchlie.nn: rotation/pose heads, geodesic losses and manifold parametrizations."""

from __future__ import annotations

import io
import math

import pytest
import torch
from samplers import rotvecs
from torch.autograd import gradcheck, gradgradcheck
from torch.nn.utils import parametrize

import torchlie.nn
from torchlie import conversions, quaternion, se3, so3
from torchlie.groups import SE3, SO3
from torchlie.nn import (
    REPRESENTATIONS,
    PoseHead,
    RotationHead,
    SE3Parametrization,
    SO3Parametrization,
    geodesic_loss,
    representation_to_matrix,
    se3_geodesic_loss,
)

F64 = torch.float64
REPS = list(REPRESENTATIONS)
SCALES = [0.0, 1e-30, 1.0, 1e6, 1e30]


def orth_error(R: torch.Tensor) -> torch.Tensor:
    """max |R^T R - I| per element."""
    eye = torch.eye(3, dtype=R.dtype)
    return (R.transpose(-1, -2) @ R - eye).abs().amax(dim=(-1, -2))


def assert_rotations(R: torch.Tensor, tol_eps: float = 16.0) -> None:
    """Orthonormal and det +1 within ``tol_eps`` machine epsilons of R's dtype."""
    tol = tol_eps * torch.finfo(R.dtype).eps
    R = R.detach()
    assert torch.isfinite(R).all()
    assert float(orth_error(R).max()) <= tol
    assert float((torch.linalg.det(R) - 1.0).abs().max()) <= tol


def max_scale(rep: str, dtype: torch.dtype) -> float:
    """Largest raw magnitude each map is specified for (rotvec: so3.exp's range)."""
    if rep == "rotvec":
        return 1e18 if dtype == torch.float32 else 1e100
    return math.inf


# ----------------------------------------------------------------------------------------------
# representation_to_matrix and the heads: validity, fallbacks, gradients
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("rep", REPS)
@pytest.mark.parametrize("scale", SCALES)
def test_map_valid_and_finite_grad(rep, scale, dtype, gen):
    if scale > max_scale(rep, dtype):
        scale = max_scale(rep, dtype)
    k = REPRESENTATIONS[rep]
    x = (torch.randn(200, k, generator=gen, dtype=dtype) * scale).requires_grad_()
    R = representation_to_matrix(x, rep)
    assert R.shape == (200, 3, 3) and R.dtype == dtype
    assert_rotations(R)
    (g,) = torch.autograd.grad((R * torch.randn(R.shape, dtype=dtype, generator=gen)).sum(), x)
    assert torch.isfinite(g).all()


@pytest.mark.parametrize("rep", REPS)
@pytest.mark.parametrize("scale", [0.0, 1.0, 1e6])
def test_heads_valid_and_finite_grad(rep, scale, dtype, gen):
    torch.manual_seed(0)
    head = RotationHead(8, representation=rep, dtype=dtype)
    pose = PoseHead(8, representation=rep, dtype=dtype)
    f = (torch.randn(4, 5, 8, generator=gen, dtype=dtype) * scale).requires_grad_()
    R = head(f)
    T = pose(f)
    assert R.shape == (4, 5, 3, 3) and T.shape == (4, 5, 4, 4)
    assert_rotations(R)
    assert bool(se3.is_valid(T).all())
    loss = (R * R.detach().flip(0)).sum() + (T * T.detach().flip(1)).sum()
    grads = torch.autograd.grad(loss, [f, *head.parameters(), *pose.parameters()])
    assert all(torch.isfinite(g).all() for g in grads)


@pytest.mark.parametrize("rep", REPS)
def test_heads_zero_raw_output_is_identity(rep, dtype):
    """A zeroed linear layer (raw vector 0) gives the identity with zero, finite gradients
    for every representation (the documented fallback; exp(0) = I for rotvec)."""
    head = RotationHead(5, representation=rep, dtype=dtype)
    torch.nn.init.zeros_(head.linear.weight)
    torch.nn.init.zeros_(head.linear.bias)
    R = head(torch.randn(3, 5, dtype=dtype))
    assert torch.equal(R, torch.eye(3, dtype=dtype).expand(3, 3, 3))
    R.sum().backward()
    assert torch.isfinite(head.linear.weight.grad).all()
    assert torch.isfinite(head.linear.bias.grad).all()


EXACT_SCALES = [2.0**-100, 2.0**-20, 2.0**20, 2.0**100]
SCALE_CASES = [(rep, c) for rep in ("6d", "9d", "quaternion") for c in EXACT_SCALES] + [
    (rep, c) for rep in ("6d", "quaternion") for c in (1e-30, 3.0, 1e30)
]


@pytest.mark.parametrize(("rep", "c"), SCALE_CASES)
def test_scale_invariance(rep, c, dtype, gen):
    """Positive scale does not change the rotation.  Powers of two scale exactly, so the result
    is the same to rounding; other factors round the input (relative eps/2), which the 9-D map
    amplifies by the conditioning of the SVD, so 9-D is checked at powers of two only."""
    x = torch.randn(100, REPRESENTATIONS[rep], generator=gen, dtype=dtype)
    R1 = representation_to_matrix(x, rep)
    R2 = representation_to_matrix(x * c, rep)
    torch.testing.assert_close(R2, R1, atol=32 * torch.finfo(dtype).eps, rtol=0)


@pytest.mark.parametrize("rep", REPS)
def test_map_equals_the_conversions(rep, gen):
    """Away from degenerate inputs the map is exactly the library's conversion."""
    x = torch.randn(50, REPRESENTATIONS[rep], generator=gen, dtype=F64)
    expected = {
        "6d": conversions.rot6d_to_matrix,
        "9d": conversions.rot9d_to_matrix,
        "quaternion": quaternion.to_matrix,
        "rotvec": so3.exp,
    }[rep](x)
    torch.testing.assert_close(representation_to_matrix(x, rep), expected, atol=1e-14, rtol=0)


def test_rot6d_fallbacks(dtype):
    e = torch.eye(3, dtype=dtype)
    a1 = torch.tensor([2.0, -1.0, 0.5], dtype=dtype)
    b1 = a1 / a1.norm()
    cases = torch.stack(
        (
            torch.zeros(6, dtype=dtype),  # -> identity
            torch.cat((a1, torch.zeros(3, dtype=dtype))),  # a2 = 0
            torch.cat((a1, -3.0 * a1)),  # exactly parallel (anti-parallel)
            torch.cat((a1, a1 * (1 + 1e-3 * torch.finfo(dtype).eps))),  # parallel to rounding
            torch.cat((torch.zeros(3, dtype=dtype), e[0] * 5.0)),  # a1 = 0, a2 along e_x
            torch.cat((torch.zeros(3, dtype=dtype), e[1] * 5.0)),  # a1 = 0, a2 fine
        )
    ).requires_grad_()
    R = representation_to_matrix(cases, "6d")
    assert_rotations(R)
    assert torch.equal(R[0], e)
    # a1 kept as the first column; a2 replaced by e_k, k = argmin |a1| = z here
    ek = e[2]
    b2 = ek - (b1 @ ek) * b1
    b2 = b2 / b2.norm()
    for i in (1, 2, 3):
        torch.testing.assert_close(R[i, :, 0], b1, atol=4 * torch.finfo(dtype).eps, rtol=0)
        torch.testing.assert_close(R[i, :, 1], b2, atol=4 * torch.finfo(dtype).eps, rtol=0)
    assert torch.equal(R[4], e)  # a1 -> e_x, a2 parallel to it -> e_y
    assert torch.equal(R[5], e)  # a1 -> e_x, a2 = 5 e_y
    (g,) = torch.autograd.grad(R.sum(), cases)
    assert torch.isfinite(g).all()
    assert torch.equal(g[:4, 3:], torch.zeros(4, 3, dtype=dtype))  # replaced a2: zero gradient
    assert torch.equal(g[4:, :3], torch.zeros(2, 3, dtype=dtype))  # replaced a1: zero gradient


def test_rot6d_nearly_parallel_above_threshold_is_kept(gen):
    """Above the parallel threshold the input is not replaced: the conversion's own value."""
    a1 = torch.randn(3, generator=gen, dtype=F64)
    perp = torch.linalg.cross(a1, torch.randn(3, generator=gen, dtype=F64), dim=-1)
    x = torch.cat((a1, a1 + 1e-9 * perp / perp.norm() * a1.norm()))
    R = representation_to_matrix(x, "6d")
    assert_rotations(R)
    torch.testing.assert_close(R, conversions.rot6d_to_matrix(x), atol=0, rtol=0)


def test_nan_stays_in_its_element(gen):
    for rep in REPS:
        x = torch.randn(4, REPRESENTATIONS[rep], generator=gen, dtype=F64)
        x[1, 0] = float("nan")
        x[2] = 0.0
        R = representation_to_matrix(x, rep)
        assert torch.isnan(R[1]).all()
        assert torch.isfinite(R[[0, 2, 3]]).all()
        torch.testing.assert_close(R[[0, 3]], representation_to_matrix(x[[0, 3]], rep))


@pytest.mark.parametrize("rep", REPS)
def test_half_precision(rep, gen):
    x = torch.randn(20, REPRESENTATIONS[rep], generator=gen).to(torch.bfloat16)
    R = representation_to_matrix(x, rep)
    assert R.dtype == torch.bfloat16
    assert float(orth_error(R.float()).max()) <= 4 * torch.finfo(torch.bfloat16).eps


def test_quaternion_hemisphere_and_sign_invariance(gen):
    head = RotationHead(6, representation="quaternion", dtype=F64)
    f = torch.randn(500, 6, generator=gen, dtype=F64)
    q = head.quaternion(f)
    assert (q[:, 0] >= 0).all()
    torch.testing.assert_close(q.norm(dim=-1), torch.ones(500, dtype=F64))
    torch.testing.assert_close(quaternion.to_matrix(q), head(f), atol=1e-15, rtol=0)
    # w = 0: the largest-magnitude vector component is made positive
    raw = torch.tensor([[0.0, 0.2, -0.9, 0.1], [0.0, -0.5, 0.3, 0.1]], dtype=F64)
    head.linear.weight.data.zero_()
    head.linear.bias.data.copy_(raw[0])
    torch.testing.assert_close(head.quaternion(torch.zeros(6, dtype=F64)), -raw[0] / raw[0].norm())
    # q and -q: same matrix and same gradient (the flip is invisible to the matrix)
    x = torch.randn(30, 4, generator=gen, dtype=F64)
    x[:, 0] = torch.where(x[:, 0].abs() < 0.1, 0.5, x[:, 0])
    G = torch.randn(30, 3, 3, generator=gen, dtype=F64)
    xp, xm = x.clone().requires_grad_(), (-x).requires_grad_()
    Rp, Rm = representation_to_matrix(xp, "quaternion"), representation_to_matrix(xm, "quaternion")
    torch.testing.assert_close(Rp, Rm, atol=1e-15, rtol=0)
    (gp,) = torch.autograd.grad((Rp * G).sum(), xp)
    (gm,) = torch.autograd.grad((Rm * G).sum(), xm)
    torch.testing.assert_close(gm, -gp)  # d/dx f(-x) = -f'(-x) = -f'(x) for even f


def test_head_quaternion_other_representations(gen):
    head = RotationHead(6, representation="6d", dtype=F64)
    f = torch.randn(10, 6, generator=gen, dtype=F64)
    torch.testing.assert_close(head.quaternion(f), quaternion.from_matrix(head(f)))


@pytest.mark.parametrize("rep", REPS)
def test_gradcheck_heads(rep, gen):
    torch.manual_seed(1)
    head = RotationHead(5, representation=rep, dtype=F64)
    pose = PoseHead(5, representation=rep, dtype=F64)
    f = torch.randn(3, 5, generator=gen, dtype=F64, requires_grad=True)
    assert gradcheck(head, (f,))
    assert gradcheck(pose, (f,))
    assert gradgradcheck(head, (f,))
    x = torch.randn(3, REPRESENTATIONS[rep], generator=gen, dtype=F64, requires_grad=True)
    assert gradcheck(lambda v: representation_to_matrix(v, rep), (x,))


def test_head_outputs_and_translation(gen):
    f = torch.randn(7, 4, generator=gen)
    head = RotationHead(4, output="SO3")
    R = head(f)
    assert isinstance(R, SO3) and R.shape == (7,)
    torch.testing.assert_close(R.tensor, representation_to_matrix(head.raw(f), "6d"))
    pose = PoseHead(4, representation="rotvec", output="SE3")
    T = pose(f)
    assert isinstance(T, SE3) and T.shape == (7,)
    y = pose.linear(f)
    torch.testing.assert_close(T.translation, y[:, 3:])
    torch.testing.assert_close(T.rotation.tensor, so3.exp(y[:, :3]))
    assert "representation='rotvec'" in repr(pose)


def test_dir_lists_only_the_public_names():
    names = dir(torchlie.nn)
    assert names == sorted(torchlie.nn.__all__)
    assert all(hasattr(torchlie.nn, name) for name in names)
    assert not {"Float", "Tensor", "torch", "nn", "so3", "se3", "SO3", "SE3"} & set(names)


def test_bad_arguments():
    with pytest.raises(ValueError, match=r"torchlie\.nn\.RotationHead: unknown representation"):
        RotationHead(3, representation="euler")
    with pytest.raises(ValueError, match=r"torchlie\.nn\.RotationHead: unknown output"):
        RotationHead(3, output="quaternion")
    with pytest.raises(ValueError, match=r"torchlie\.nn\.PoseHead: unknown output 'SO3'"):
        PoseHead(3, output="SO3")
    with pytest.raises(ValueError, match=r"unknown representation '5d'"):
        representation_to_matrix(torch.zeros(5), "5d")
    with pytest.raises(ValueError, match=r"torchlie\.nn\.representation_to_matrix: expected x "):
        representation_to_matrix(torch.zeros(2, 5), "6d")
    with pytest.raises(TypeError, match=r"floating-point"):
        representation_to_matrix(torch.zeros(6, dtype=torch.int64), "6d")
    with pytest.raises(ValueError, match=r"unknown representation 'rotvec'"):
        SE3Parametrization("rotvec")
    with pytest.raises(ValueError, match=r"unknown representation 'twist'"):
        SO3Parametrization("twist")
    R = torch.eye(3)
    with pytest.raises(ValueError, match=r"torchlie\.nn\.geodesic_loss: unknown kind"):
        geodesic_loss(R, R, kind="frobenius")
    with pytest.raises(ValueError, match=r"torchlie\.nn\.geodesic_loss: unknown reduction"):
        geodesic_loss(R, R, reduction="max")
    with pytest.raises(ValueError, match=r"torchlie\.nn\.geodesic_loss: expected R_target"):
        geodesic_loss(R, torch.eye(4))
    with pytest.raises(ValueError, match=r"batch shapes do not broadcast"):
        geodesic_loss(R.expand(2, 3, 3), R.expand(3, 3, 3))
    with pytest.raises(TypeError, match=r"one dtype"):
        geodesic_loss(R, R.double())
    T = torch.eye(4)
    with pytest.raises(ValueError, match=r"torchlie\.nn\.se3_geodesic_loss: unknown reduction"):
        se3_geodesic_loss(T, T, reduction="avg")
    with pytest.raises(ValueError, match=r"torchlie\.nn\.se3_geodesic_loss: expected T_pred"):
        se3_geodesic_loss(R, T)


# ----------------------------------------------------------------------------------------------
# Losses
# ----------------------------------------------------------------------------------------------


def test_geodesic_loss_agrees_with_distance(dtype):
    w, theta = rotvecs(n_random=20, dtype=dtype)
    R = so3.exp(w)
    B = so3.random(w.shape[0], generator=torch.Generator().manual_seed(3), dtype=dtype)
    # pairs (B, B R): relative rotation R, angles from 0 to pi exactly
    angle = geodesic_loss(B, B @ R, reduction="none")
    torch.testing.assert_close(angle, so3.distance(B, B @ R), atol=0, rtol=0)
    torch.testing.assert_close(angle, theta, atol=64 * torch.finfo(dtype).eps ** 0.5, rtol=0)
    chord = geodesic_loss(B, B @ R, kind="chordal", reduction="none")
    expected = 8.0 * torch.sin(theta / 2) ** 2
    torch.testing.assert_close(chord, expected, atol=64 * torch.finfo(dtype).eps, rtol=0)


@pytest.mark.parametrize("kind", ["angle", "chordal"])
def test_reductions_and_broadcast(kind, gen):
    A = so3.random(2, 3, generator=gen, dtype=F64)
    B = so3.random(3, generator=gen, dtype=F64)
    none = geodesic_loss(A, B, kind=kind, reduction="none")
    assert none.shape == (2, 3)
    torch.testing.assert_close(geodesic_loss(A, B, kind=kind), none.mean())
    torch.testing.assert_close(geodesic_loss(A, B, kind=kind, reduction="sum"), none.sum())
    T1 = se3.random(2, 3, generator=gen, dtype=F64)
    T2 = se3.random(3, generator=gen, dtype=F64)
    none = se3_geodesic_loss(T1, T2, 2.0, 0.5, kind=kind, reduction="none")
    assert none.shape == (2, 3)
    torch.testing.assert_close(se3_geodesic_loss(T1, T2, 2.0, 0.5, kind=kind), none.mean())
    s = se3_geodesic_loss(T1, T2, 2.0, 0.5, kind=kind, reduction="sum")
    torch.testing.assert_close(s, none.sum())


def test_se3_loss_values(gen):
    T1 = se3.random(10, generator=gen, dtype=F64)
    T2 = se3.random(10, generator=gen, dtype=F64)
    angle = so3.distance(T1[:, :3, :3], T2[:, :3, :3])
    dist = (T1[:, :3, 3] - T2[:, :3, 3]).norm(dim=-1)
    loss = se3_geodesic_loss(T1, T2, 3.0, 0.25, reduction="none")
    torch.testing.assert_close(loss, 3.0 * angle + 0.25 * dist)
    chord = se3_geodesic_loss(T1, T2, 3.0, 0.25, kind="chordal", reduction="none")
    expected = 3.0 * 8.0 * torch.sin(angle / 2) ** 2 + 0.25 * dist**2
    torch.testing.assert_close(chord, expected)


def test_loss_gradients_at_zero_and_pi(dtype):
    """Angle loss: the zero subgradient at zero error and at exactly pi; chordal: smooth, its
    gradient's tangent part vanishes there.  (Exactly pi needs an exactly orthogonal matrix:
    a permutation, and a flip about y.)"""
    perm = torch.tensor([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]], dtype=dtype)
    flip = torch.diag(torch.tensor([-1.0, 1.0, -1.0], dtype=dtype))
    generic = so3.exp(torch.tensor([0.3, -0.2, 0.5], dtype=dtype))
    Rt = torch.stack((generic, perm))
    for kind in ("angle", "chordal"):
        for Rp in (Rt.clone(), Rt @ flip):  # zero error; error exactly pi
            Rp.requires_grad_()
            loss = geodesic_loss(Rp, Rt, kind=kind, reduction="sum")
            (g,) = torch.autograd.grad(loss, Rp)
            assert torch.isfinite(g).all()
            tangent = so3.vee(Rp.detach().transpose(-1, -2) @ g)  # what moves the rotation
            assert float(tangent.abs().max()) <= 16 * torch.finfo(dtype).eps
    # near pi (rounding away from it) the gradient is finite, of norm at most 1
    Rp = (Rt @ so3.exp(torch.tensor([0.0, math.pi, 0.0], dtype=dtype))).requires_grad_()
    (g,) = torch.autograd.grad(geodesic_loss(Rp, Rt, reduction="sum"), Rp)
    tangent = 2 * so3.vee(Rp.detach().transpose(-1, -2) @ g)
    assert float(tangent.norm(dim=-1).max()) <= 1 + 16 * torch.finfo(dtype).eps
    Tp = se3.from_rt(Rt, torch.zeros(2, 3, dtype=dtype)).requires_grad_()
    Tt = Tp.detach().clone()
    (g,) = torch.autograd.grad(se3_geodesic_loss(Tp, Tt), Tp)
    assert torch.equal(g, torch.zeros_like(g))


def test_angle_loss_gradient_near_zero_is_unit(gen):
    """Just away from zero error the angle's gradient along the geodesic has norm 1."""
    Rt = so3.random(5, generator=gen, dtype=F64)
    axis = torch.nn.functional.normalize(torch.randn(5, 3, generator=gen, dtype=F64), dim=-1)
    for eps in (1e-6, 1e-3, 1.0, math.pi - 1e-3):
        d = (eps * axis).requires_grad_()
        loss = geodesic_loss(Rt @ so3.exp(d), Rt, reduction="sum")
        (g,) = torch.autograd.grad(loss, d)
        torch.testing.assert_close(g, axis, atol=1e-6, rtol=0)


def test_gradcheck_losses(gen):
    A = so3.random(4, generator=gen, dtype=F64).requires_grad_()
    B = so3.random(4, generator=gen, dtype=F64).requires_grad_()
    for kind in ("angle", "chordal"):
        assert gradcheck(lambda a, b, k=kind: geodesic_loss(a, b, kind=k, reduction="none"), (A, B))
    assert gradgradcheck(lambda a, b: geodesic_loss(a, b, kind="chordal"), (A, B))
    T1 = se3.random(4, generator=gen, dtype=F64).requires_grad_()
    T2 = se3.random(4, generator=gen, dtype=F64).requires_grad_()
    for kind in ("angle", "chordal"):
        assert gradcheck(lambda a, b, k=kind: se3_geodesic_loss(a, b, 2.0, 0.5, kind=k), (T1, T2))
    # through tangent coordinates at the hard points: 1e-8 and pi - 1e-6 from the target
    for theta in (1e-8, math.pi - 1e-6):
        Rt = so3.random(3, generator=gen, dtype=F64)
        axis = torch.nn.functional.normalize(torch.randn(3, 3, generator=gen, dtype=F64), dim=-1)
        base = Rt @ so3.exp(theta * axis)
        d = torch.zeros(3, 3, dtype=F64, requires_grad=True)
        assert gradcheck(
            lambda v, b=base, t=Rt: geodesic_loss(b @ so3.exp(v), t, kind="chordal"), (d,)
        )


# ----------------------------------------------------------------------------------------------
# Parametrizations
# ----------------------------------------------------------------------------------------------

SO3_REPS = ["quaternion", "matrix", "rotvec"]
SE3_REPS = ["pos_quat", "matrix", "twist"]


def holder(value: torch.Tensor, param) -> torch.nn.Module:
    m = torch.nn.Module()
    m.X = torch.nn.Parameter(value.clone())
    parametrize.register_parametrization(m, "X", param)
    return m


@pytest.mark.parametrize("rep", SO3_REPS)
def test_so3_parametrization_1000_adam_steps(rep):
    """After 1000 Adam steps (float32) the weight is a rotation to 1e-5 and has converged."""
    gen = torch.Generator().manual_seed(0)
    R0 = so3.random(8, generator=gen)
    m = holder(R0, SO3Parametrization(rep))
    torch.testing.assert_close(m.X, R0, atol=1e-6, rtol=0)
    target = so3.random(8, generator=gen)
    opt = torch.optim.Adam(m.parameters(), lr=1e-2)
    start = float(geodesic_loss(m.X, target).detach())
    for _ in range(1000):
        opt.zero_grad()
        loss = geodesic_loss(m.X, target, kind="chordal")
        loss.backward()
        opt.step()
    R = m.X.detach()
    assert R.dtype == torch.float32
    assert float(orth_error(R).max()) <= 1e-5
    assert float((torch.linalg.det(R) - 1).abs().max()) <= 1e-5
    assert start > 1.0
    assert float(geodesic_loss(R, target)) <= 2e-2  # converged: mean error < 1.2 degrees


@pytest.mark.parametrize("rep", SO3_REPS)
@pytest.mark.parametrize("opt_name", ["sgd", "lbfgs"])
def test_so3_parametrization_sgd_lbfgs(rep, opt_name):
    gen = torch.Generator().manual_seed(1)
    m = holder(so3.random(4, generator=gen, dtype=F64), SO3Parametrization(rep))
    target = so3.random(4, generator=gen, dtype=F64)

    def closure():
        opt.zero_grad()
        loss = geodesic_loss(m.X, target, kind="chordal", reduction="sum")
        loss.backward()
        return loss

    if opt_name == "sgd":
        opt = torch.optim.SGD(m.parameters(), lr=0.05, momentum=0.9)
        for _ in range(300):
            opt.step(closure)
    else:
        opt = torch.optim.LBFGS(m.parameters(), max_iter=200, line_search_fn="strong_wolfe")
        opt.step(closure)
    assert_rotations(m.X.detach())
    assert float(geodesic_loss(m.X.detach(), target).max()) <= 1e-5


@pytest.mark.parametrize("rep", SE3_REPS)
def test_se3_parametrization_adam_and_lbfgs(rep):
    """Adam (float32) keeps the poses valid; LBFGS (float64) reaches the target poses."""
    gen = torch.Generator().manual_seed(2)
    m = holder(se3.random(6, generator=gen), SE3Parametrization(rep))
    target = se3.random(6, generator=gen)
    opt = torch.optim.Adam(m.parameters(), lr=2e-2)
    for _ in range(300):
        opt.zero_grad()
        se3_geodesic_loss(m.X, target, kind="chordal").backward()
        opt.step()
    T = m.X.detach()
    assert float(orth_error(T[:, :3, :3]).max()) <= 1e-5
    assert torch.equal(T[:, 3], torch.tensor([0.0, 0.0, 0.0, 1.0]).expand(6, 4))

    m = holder(se3.random(6, generator=gen, dtype=F64), SE3Parametrization(rep))
    target = se3.random(6, generator=gen, dtype=F64)
    opt = torch.optim.LBFGS(m.parameters(), max_iter=300, line_search_fn="strong_wolfe")

    def closure():
        opt.zero_grad()
        loss = se3_geodesic_loss(m.X, target, kind="chordal", reduction="sum")
        loss.backward()
        return loss

    opt.step(closure)
    T = m.X.detach()
    assert float(orth_error(T[:, :3, :3]).max()) <= 16 * torch.finfo(F64).eps
    rot, trans = se3.distance(T, target)
    assert float(rot.max()) <= 1e-4 and float(trans.max()) <= 1e-4


@pytest.mark.parametrize("rep", SO3_REPS)
def test_so3_parametrization_roundtrip_and_state_dict(rep):
    gen = torch.Generator().manual_seed(3)
    R0 = so3.random(2, 3, generator=gen, dtype=F64)
    m = holder(R0, SO3Parametrization(rep))
    torch.testing.assert_close(m.X, R0, atol=1e-14, rtol=0)  # registration keeps the value
    R1 = so3.random(2, 3, generator=gen, dtype=F64)
    m.X = R1  # assignment goes through right_inverse
    torch.testing.assert_close(m.X, R1, atol=1e-14, rtol=0)
    assert m.parametrizations.X.original.data_ptr() != R1.data_ptr()  # no aliasing
    shape = {"quaternion": (2, 3, 4), "matrix": (2, 3, 3, 3), "rotvec": (2, 3, 3)}[rep]
    assert m.parametrizations.X.original.shape == shape
    with torch.no_grad():
        m.parametrizations.X.original.add_(0.1)
    buf = io.BytesIO()
    torch.save(m.state_dict(), buf)
    buf.seek(0)
    m2 = holder(so3.identity(2, 3, dtype=F64), SO3Parametrization(rep))
    m2.load_state_dict(torch.load(buf))
    assert list(m2.state_dict()) == ["parametrizations.X.original"]
    assert torch.equal(m2.X, m.X)
    assert_rotations(m2.X.detach())


@pytest.mark.parametrize("rep", SE3_REPS)
def test_se3_parametrization_roundtrip_and_state_dict(rep):
    gen = torch.Generator().manual_seed(4)
    T0 = se3.random(5, generator=gen, dtype=F64)
    m = holder(T0, SE3Parametrization(rep))
    torch.testing.assert_close(m.X, T0, atol=1e-14, rtol=0)
    T1 = se3.random(5, generator=gen, dtype=F64)
    m.X = T1
    torch.testing.assert_close(m.X, T1, atol=1e-14, rtol=0)
    assert m.parametrizations.X.original.data_ptr() != T1.data_ptr()
    with torch.no_grad():
        m.parametrizations.X.original.mul_(1.5)
    assert bool(se3.is_valid(m.X).all())
    buf = io.BytesIO()
    torch.save(m.state_dict(), buf)
    buf.seek(0)
    m2 = holder(se3.identity(5, dtype=F64), SE3Parametrization(rep))
    m2.load_state_dict(torch.load(buf))
    assert torch.equal(m2.X, m.X)


def test_parametrization_matrix_mode_is_projection(gen):
    M = torch.randn(4, 3, 3, generator=gen, dtype=F64)
    torch.testing.assert_close(SO3Parametrization("matrix")(M), so3.project(M))
    M4 = torch.randn(4, 4, 4, generator=gen, dtype=F64)
    T = SE3Parametrization("matrix")(M4)
    torch.testing.assert_close(T[:, :3, :3], so3.project(M4[:, :3, :3]))
    torch.testing.assert_close(T[:, :3, 3], M4[:, :3, 3])
    with pytest.raises(ValueError, match=r"SO3Parametrization: expected X of shape \(\.\.\., 4\)"):
        SO3Parametrization()(torch.zeros(3, 3))


@pytest.mark.parametrize("rep", REPS)
def test_map_under_vmap(rep, gen):
    x = torch.randn(6, REPRESENTATIONS[rep], generator=gen, dtype=F64)
    x[2] = 0.0  # the fallback branch inside vmap too
    y = torch.func.vmap(lambda v: representation_to_matrix(v, rep))(x)
    torch.testing.assert_close(y, representation_to_matrix(x, rep), atol=0, rtol=0)
    # per-sample derivatives (vmap of jacrev / jacfwd), the fallback branch included
    for jac in (torch.func.jacrev, torch.func.jacfwd):
        J = torch.func.vmap(jac(lambda v: representation_to_matrix(v, rep)))(x)
        J1 = torch.stack([jac(lambda v: representation_to_matrix(v, rep))(v) for v in x])
        torch.testing.assert_close(J, J1, atol=1e-15, rtol=1e-12)


def test_head_per_sample_gradients():
    from torch.func import functional_call, grad

    head = RotationHead(8)
    params = {k: v.detach() for k, v in head.named_parameters()}

    def loss(p, f):
        return functional_call(head, p, (f,)).sum()

    f = torch.randn(4, 8)
    g = torch.func.vmap(grad(loss), in_dims=(None, 0))(params, f)
    one = [grad(loss)(params, fi) for fi in f]
    for k in params:
        torch.testing.assert_close(g[k], torch.stack([o[k] for o in one]))


class _Net(torch.nn.Module):
    """A parametrized rotation weight followed by a 6-D rotation head."""

    def __init__(self) -> None:
        super().__init__()
        self.lin = torch.nn.Linear(3, 3, bias=False)
        parametrize.register_parametrization(self.lin, "weight", SO3Parametrization())
        self.head = RotationHead(3, representation="6d")

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(self.lin(x))


@pytest.mark.compile
def test_parametrized_module_under_compile():
    """One forward/backward under torch.compile(fullgraph=True) of a module with an
    SO(3)-parametrized weight and a 6-D head (fallback branch included): parametrize does not
    break the graph in torch 2.13, and values and gradients match eager."""
    torch._dynamo.reset()
    torch.manual_seed(0)
    net = _Net()
    x = torch.randn(5, 3, generator=torch.Generator().manual_seed(0))
    x[0] = 0.0  # zero features -> raw 6-vector = bias: the head's fallback is not needed...
    with torch.no_grad():
        net.head.linear.bias[:] = 0.0  # ...unless the bias is zero too: identity fallback
    params = [net.lin.parametrizations.weight.original, *net.head.parameters()]
    y_ref = net(x)
    g_ref = torch.autograd.grad((y_ref * y_ref.flip(0)).sum(), params)
    y = torch.compile(net, fullgraph=True)(x)
    g = torch.autograd.grad((y * y.flip(0)).sum(), params)
    assert torch.equal(y_ref[0], torch.eye(3))
    torch.testing.assert_close(y, y_ref)
    for a, b in zip(g, g_ref, strict=True):
        torch.testing.assert_close(a, b)
