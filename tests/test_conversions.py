"""torchlie.conversions: scipy as the oracle for all 24 Euler sequences, gimbal lock, axis-angle,
the 6-D and 9-D representations, gradients, batch shapes, dtypes, bad input, vmap, compile."""

from __future__ import annotations

import itertools
import math
import warnings

import numpy as np
import pytest
import torch
from samplers import ANGLES, PI, eps, haar_quaternions, hard_quaternions, rotvecs
from scipy.spatial.transform import Rotation

from torchlie import conversions as C
from torchlie import quaternion, so3

F64 = torch.float64

SEQS = [
    s
    for p in itertools.product("xyz", repeat=3)
    if p[0] != p[1] and p[1] != p[2]
    for s in ("".join(p), "".join(p).upper())
]
TAIT_BRYAN = [s for s in SEQS if s[0] != s[2]]
PROPER = [s for s in SEQS if s[0] == s[2]]

#: Gimbal-lock threshold of the implementation (relative, in eps) and the resulting bound on the
#: round-trip error of a matrix entry near lock: zeroing a quaternion pair of relative size
#: <= 4 eps moves the unit quaternion by <= 8 eps and a matrix entry by <= 32 eps, plus rounding.
LOCK_EPS = 4.0
RT_LOCK_TOL = 8 * LOCK_EPS + 8


def wrap(d: torch.Tensor) -> torch.Tensor:
    """Angle difference in [-pi, pi)."""
    return torch.remainder(d + PI, 2 * PI) - PI


def is_proper(seq: str) -> bool:
    return seq[0] == seq[2]


def lock_distance(seq: str, middle: torch.Tensor) -> torch.Tensor:
    """Distance of the middle angle from gimbal lock."""
    if is_proper(seq):
        return torch.minimum(middle, PI - middle)
    return PI / 2 - middle.abs()


def to_xyzw(q: torch.Tensor) -> np.ndarray:
    return q.double()[..., [1, 2, 3, 0]].numpy()


def rotation_quaternions() -> torch.Tensor:
    """Unit quaternions (float64): Haar draws plus the hard points of the samplers."""
    return torch.cat((haar_quaternions(400, seed=3), hard_quaternions()))


def sample_angles(seq: str, n: int, seed: int) -> torch.Tensor:
    """Angles in the ranges of ``seq`` (float64), including the ends of the ranges."""
    g = torch.Generator().manual_seed(seed)
    a = (2 * torch.rand(n, 3, generator=g, dtype=F64) - 1) * PI
    if is_proper(seq):
        a[:, 1] = a[:, 1].abs()
    else:
        a[:, 1] = a[:, 1] / 2
    ends = torch.tensor(
        [[0.0, 0.1, 0.0], [PI, 0.3, -PI], [-PI, 0.5, 1.0], [1e-8, 1.0, -1e-8], [2.0, 0.7, 3.0]],
        dtype=F64,
    )
    return torch.cat((a, ends))


def scipy_quat(seq: str, angles: torch.Tensor) -> torch.Tensor:
    q = Rotation.from_euler(seq, angles.double().numpy()).as_quat()
    return torch.from_numpy(q)[..., [3, 0, 1, 2]]


def scipy_euler(seq: str, q: torch.Tensor) -> torch.Tensor:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return torch.from_numpy(Rotation.from_quat(to_xyzw(q)).as_euler(seq))


def test_there_are_24_sequences():
    assert len(SEQS) == 24 and len(set(SEQS)) == 24
    assert len(TAIT_BRYAN) == len(PROPER) == 12


# ----------------------------------------------------------------------------------------------
# Literal conventions
# ----------------------------------------------------------------------------------------------


def test_extrinsic_and_intrinsic_literal():
    a = torch.tensor([0.3, -0.7, 1.1], dtype=F64)
    Rx, Ry, Rz = (
        so3.exp(a[0] * torch.tensor([1.0, 0, 0], dtype=F64)),
        so3.exp(a[1] * torch.tensor([0, 1.0, 0], dtype=F64)),
        so3.exp(a[2] * torch.tensor([0, 0, 1.0], dtype=F64)),
    )
    tol = dict(rtol=0, atol=4 * eps(F64))
    torch.testing.assert_close(C.euler_to_matrix(a, "xyz"), Rz @ Ry @ Rx, **tol)
    torch.testing.assert_close(C.euler_to_matrix(a, "XYZ"), Rx @ Ry @ Rz, **tol)
    torch.testing.assert_close(C.euler_to_matrix(a, "XYZ"), C.euler_to_matrix(a.flip(0), "zyx"))
    Rx2 = so3.exp(a[2] * torch.tensor([1.0, 0, 0], dtype=F64))
    torch.testing.assert_close(C.euler_to_matrix(a, "xyx"), Rx2 @ Ry @ Rx, **tol)


def test_intrinsic_is_reversed_extrinsic():
    a = sample_angles("xyz", 50, seed=1)
    for seq in SEQS:
        rev = seq[::-1].swapcase()
        torch.testing.assert_close(
            C.euler_to_matrix(a, seq), C.euler_to_matrix(a.flip(-1), rev), rtol=0, atol=1e-15
        )


# ----------------------------------------------------------------------------------------------
# scipy as the oracle, all 24 sequences
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seq", SEQS)
def test_euler_to_matrix_and_quaternion_match_scipy(seq, dtype):
    a = sample_angles(seq, 300, seed=7).to(dtype)
    ref_q = scipy_quat(seq, a)
    ref_R = torch.from_numpy(Rotation.from_euler(seq, a.double().numpy()).as_matrix())
    R = C.euler_to_matrix(a, seq)
    assert R.dtype == dtype
    torch.testing.assert_close(R.double(), ref_R, rtol=0, atol=8 * eps(dtype))
    q = C.euler_to_quaternion(a, seq).double()
    err = torch.minimum((q - ref_q).abs().amax(-1), (q + ref_q).abs().amax(-1))
    assert err.max() <= 4 * eps(dtype)


@pytest.mark.parametrize("seq", SEQS)
def test_to_euler_matches_scipy(seq, dtype):
    q = rotation_quaternions().to(dtype)
    R = quaternion.to_matrix(q)
    for got, ref in (
        (C.quaternion_to_euler(q, seq), scipy_euler(seq, q)),
        (C.matrix_to_euler(R, seq), scipy_euler(seq, quaternion.from_matrix(R.double()))),
    ):
        assert got.dtype == dtype and torch.isfinite(got).all()
        got = got.double()
        # The middle angle is well conditioned everywhere.
        assert (got[:, 1] - ref[:, 1]).abs().max() <= 8 * eps(dtype)
        # The outer angles are conditioned like 1 / sin(distance to gimbal lock).
        dist = lock_distance(seq, ref[:, 1])
        keep = dist > 1e-3
        assert keep.sum() > 300
        err = wrap(got - ref)[:, [0, 2]].abs().amax(-1)
        assert (err[keep] * torch.sin(dist[keep])).max() <= 16 * eps(dtype)


@pytest.mark.parametrize("seq", SEQS)
def test_to_euler_ranges_and_round_trip(seq, dtype):
    q = rotation_quaternions().to(dtype)
    R = quaternion.to_matrix(q)
    for a in (C.quaternion_to_euler(q, seq), C.matrix_to_euler(R, seq)):
        assert a[:, [0, 2]].min() >= -PI and a[:, [0, 2]].max() < PI
        if is_proper(seq):
            assert a[:, 1].min() >= 0 and a[:, 1].max() <= PI
        else:
            assert a[:, 1].abs().max() <= PI / 2
        err = (C.euler_to_matrix(a, seq) - R).abs().amax()
        assert err <= RT_LOCK_TOL * eps(dtype)


@pytest.mark.parametrize("seq", ["xyz", "ZXZ", "yxz", "XYX"])
def test_euler_round_trip_from_angles(seq, dtype):
    """Away from lock, angles -> matrix -> angles returns the angles (in range, as given)."""
    a = sample_angles(seq, 300, seed=11)
    a = a[lock_distance(seq, a[:, 1]) > 0.05]
    a = a[(a[:, [0, 2]].abs() < PI - 1e-3).all(-1)].to(dtype)
    for back in (
        C.matrix_to_euler(C.euler_to_matrix(a, seq), seq),
        C.quaternion_to_euler(C.euler_to_quaternion(a, seq), seq),
    ):
        sin_d = torch.sin(lock_distance(seq, a[:, 1].double()))
        err = (back - a).double().abs().amax(-1)
        assert (err * sin_d).max() <= 16 * eps(dtype)


# ----------------------------------------------------------------------------------------------
# Gimbal lock
# ----------------------------------------------------------------------------------------------


def lock_values(seq: str) -> list[float]:
    return [0.0, PI] if is_proper(seq) else [PI / 2, -PI / 2]


def lock_angles(seq: str, offset_eps: float, dtype, n: int = 200, seed: int = 5):
    """Random outer angles, middle angle at (or ``offset_eps`` eps inside) each lock value."""
    g = torch.Generator().manual_seed(seed)
    rows = []
    for lock in lock_values(seq):
        a = (2 * torch.rand(n, 3, generator=g, dtype=F64) - 1) * PI
        inward = 1.0 if lock in (0.0, -PI / 2) else -1.0
        a[:, 1] = lock + inward * offset_eps * eps(dtype)
        rows.append(a)
    return torch.cat(rows).to(dtype)


@pytest.mark.parametrize("seq", SEQS)
def test_gimbal_lock_exact(seq, dtype):
    a = lock_angles(seq, 0.0, dtype)
    q = C.euler_to_quaternion(a, seq)
    R = C.euler_to_matrix(a, seq)
    ref = scipy_euler(seq, q.double())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        outs = (C.quaternion_to_euler(q, seq), C.matrix_to_euler(R, seq))
    for out in outs:
        assert torch.isfinite(out).all()
        # The documented rule: third angle exactly 0, the first carries the rotation (= scipy).
        assert (out[:, 2] == 0).all()
        assert wrap(out.double() - ref).abs().max() <= 16 * eps(dtype)
        err = (C.euler_to_matrix(out, seq) - R).abs().amax()
        assert err <= RT_LOCK_TOL * eps(dtype)


@pytest.mark.parametrize("offset", [0.5, 2.0, 6.0, 8.0, 12.0, 64.0, 1e4])
@pytest.mark.parametrize("seq", ["xyz", "ZYX", "zxz", "YXY", "yzx", "XZX"])
def test_gimbal_lock_near(seq, offset, dtype):
    """Within a few eps of lock, on both sides of the threshold: the angles round-trip."""
    a = lock_angles(seq, offset, dtype)
    R = C.euler_to_matrix(a, seq)
    for out in (
        C.quaternion_to_euler(C.euler_to_quaternion(a, seq), seq),
        C.matrix_to_euler(R, seq),
    ):
        assert torch.isfinite(out).all()
        err = (C.euler_to_matrix(out, seq) - R).abs().amax()
        assert err <= RT_LOCK_TOL * eps(dtype)


@pytest.mark.parametrize("seq", ["xyz", "XYZ", "zxz", "ZXZ"])
def test_gimbal_lock_gradient_finite(seq, dtype):
    a = lock_angles(seq, 0.0, dtype, n=20)
    R = C.euler_to_matrix(a, seq).requires_grad_(True)
    C.matrix_to_euler(R, seq).sum().backward()
    assert torch.isfinite(R.grad).all()
    q = C.euler_to_quaternion(a, seq).requires_grad_(True)
    out = C.quaternion_to_euler(q, seq)
    # the angle that the rule sets to 0 has zero gradient
    (g,) = torch.autograd.grad(out[:, 2].sum(), q, retain_graph=True, materialize_grads=True)
    assert (g == 0).all()
    out.sum().backward()
    assert torch.isfinite(q.grad).all()


def test_zero_quaternion_is_nan_only_there():
    q = torch.tensor([[0.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.3, -0.2, 0.5, 0.1]])
    out = C.quaternion_to_euler(q, "xyz")
    assert torch.isnan(out[0]).all()
    assert torch.isfinite(out[1:]).all()
    torch.testing.assert_close(out[1:], C.quaternion_to_euler(q[1:], "xyz"), rtol=0, atol=0)


def test_quaternion_to_euler_scale_and_sign_invariant():
    q = rotation_quaternions()
    for seq in ("xyz", "ZXZ"):
        a = C.quaternion_to_euler(q, seq)
        for k in (-1.0, -4.0, 2.0**-40, -(2.0**40)):  # exact scalings: exactly the same angles
            torch.testing.assert_close(C.quaternion_to_euler(k * q, seq), a, rtol=0, atol=0)
        for k in (-3.0, 1e-10, 1e10):  # inexact scalings: the same up to the conditioning
            R = C.euler_to_matrix(C.quaternion_to_euler(k * q, seq), seq)
            assert (R - quaternion.to_matrix(q)).abs().max() <= RT_LOCK_TOL * eps(F64)


# ----------------------------------------------------------------------------------------------
# Gradients (float64)
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seq", ["xyz", "ZYX", "zxz", "YZY"])
def test_gradcheck_euler_to_matrix_and_quaternion(seq):
    a = sample_angles(seq, 4, seed=2)[:4]
    a = torch.cat((a, lock_angles(seq, 0.0, F64, n=1)))  # smooth at gimbal lock as well
    a.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: C.euler_to_matrix(x, seq), (a,))
    assert torch.autograd.gradgradcheck(lambda x: C.euler_to_matrix(x, seq), (a,))
    assert torch.autograd.gradcheck(lambda x: C.euler_to_quaternion(x, seq), (a,))


@pytest.mark.parametrize("seq", ["xyz", "ZYX", "zxz", "YZY"])
def test_gradcheck_to_euler_away_from_lock(seq):
    q = haar_quaternions(6, seed=4)
    a = C.quaternion_to_euler(q, seq)
    assert (lock_distance(seq, a[:, 1]) > 0.1).all()
    R = quaternion.to_matrix(q).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: C.matrix_to_euler(x, seq), (R,))
    q.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: C.quaternion_to_euler(x, seq), (q,))
    # tangent coordinates: d -> matrix_to_euler(R Exp(d))
    d = torch.zeros(6, 3, dtype=F64, requires_grad=True)
    R0 = R.detach()
    assert torch.autograd.gradcheck(lambda x: C.matrix_to_euler(R0 @ so3.exp(x), seq), (d,))


@pytest.mark.parametrize("seq", ["xzy", "YXZ", "yxy", "ZXZ"])
def test_euler_jacobians_are_inverse(seq):
    """d(angles)/d(tangent) of matrix_to_euler inverts d(tangent)/d(angles) of euler_to_matrix."""
    a0 = torch.tensor([0.4, 0.8 if is_proper(seq) else -0.6, -2.5], dtype=F64)
    R0 = C.euler_to_matrix(a0, seq)
    A = torch.func.jacrev(lambda a: so3.log(R0.mT @ C.euler_to_matrix(a, seq)))(a0)
    B = torch.func.jacrev(lambda d: C.matrix_to_euler(R0 @ so3.exp(d), seq))(
        torch.zeros(3, dtype=F64)
    )
    torch.testing.assert_close(B @ A, torch.eye(3, dtype=F64), rtol=0, atol=1e-13)


# ----------------------------------------------------------------------------------------------
# Axis-angle
# ----------------------------------------------------------------------------------------------


def test_axis_angle_to_matrix_matches_scipy(dtype):
    w, th = rotvecs(n_random=20)
    axis = torch.nn.functional.normalize(torch.where(th[:, None] > 0, w, 1.0), dim=-1)
    ref = torch.from_numpy(Rotation.from_rotvec((th[:, None] * axis).numpy()).as_matrix())
    scale = torch.linspace(0.01, 100.0, len(th), dtype=F64)[:, None]  # axis need not be unit
    R = C.axis_angle_to_matrix((scale * axis).to(dtype), th.to(dtype))
    assert R.dtype == dtype
    torch.testing.assert_close(R.double(), ref, rtol=0, atol=8 * eps(dtype))


def test_axis_angle_literal_and_any_angle():
    axis = torch.tensor([0.0, 0.0, 5.0], dtype=F64)
    R = C.axis_angle_to_matrix(axis, PI / 3)
    c, s = math.cos(PI / 3), math.sin(PI / 3)
    expected = torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], dtype=F64)
    torch.testing.assert_close(R, expected, rtol=0, atol=2 * eps(F64))
    # negative angles and angles beyond pi are rotations too
    torch.testing.assert_close(C.axis_angle_to_matrix(axis, -PI / 3), expected.mT)
    torch.testing.assert_close(C.axis_angle_to_matrix(axis, 2 * PI + PI / 3), expected)


def test_matrix_to_axis_angle_round_trip(dtype):
    w, th = rotvecs(n_random=30, dtype=dtype)
    R = so3.exp(w)
    axis, angle = C.matrix_to_axis_angle(R)
    assert axis.dtype == angle.dtype == dtype
    assert axis.shape == w.shape and angle.shape == th.shape
    assert angle.min() >= 0 and angle.max() <= PI
    torch.testing.assert_close(axis.norm(dim=-1), torch.ones_like(th), rtol=0, atol=4 * eps(dtype))
    torch.testing.assert_close(angle, so3.log(R).norm(dim=-1), rtol=eps(dtype), atol=0)
    back = C.axis_angle_to_matrix(axis, angle)
    assert (back - R).abs().max() <= 8 * eps(dtype)


def test_matrix_to_axis_angle_at_zero_and_pi():
    axis, angle = C.matrix_to_axis_angle(torch.eye(3, dtype=F64).expand(2, 3, 3))
    assert torch.equal(axis, torch.tensor([[1.0, 0.0, 0.0]] * 2, dtype=F64))
    assert torch.equal(angle, torch.zeros(2, dtype=F64))
    R = torch.eye(3, dtype=F64).requires_grad_(True)
    axis, angle = C.matrix_to_axis_angle(R)
    (axis.sum() + angle).backward()
    assert torch.isfinite(R.grad).all()
    # pi about -y: canonical axis +y (largest-magnitude component positive)
    axis, angle = C.matrix_to_axis_angle(torch.diag(torch.tensor([-1.0, 1.0, -1.0], dtype=F64)))
    assert torch.equal(axis, torch.tensor([0.0, 1.0, 0.0], dtype=F64))
    assert angle == PI


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("axis", [0, 1, 2])
def test_matrix_to_axis_angle_derivative_at_a_half_turn(dtype, axis):
    # The rotation by the float64 pi (below the true pi, where the angle is differentiable)
    # about a coordinate axis: |log R| is exactly the float pi, and d angle / d s along
    # R Exp(s e) is 1 there, in reverse and forward mode, as just below it.
    e = torch.zeros(3, dtype=dtype)
    e[axis] = 1.0
    for theta in (PI, PI - 1e-3):
        R = so3.exp(theta * e.double()).to(dtype)

        def angle(s, R=R):
            return C.matrix_to_axis_angle(R @ so3.exp(s * e))[1]

        s = torch.zeros((), dtype=dtype)
        for d in (torch.func.grad(angle)(s), torch.func.jacfwd(angle)(s)):
            assert (d - 1.0).abs() <= 8 * eps(dtype)


def test_zero_axis_is_nan_only_there():
    axis = torch.tensor([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    R = C.axis_angle_to_matrix(axis, torch.tensor([0.5, 0.5]))
    assert torch.isnan(R[0]).all() and torch.isfinite(R[1]).all()


def test_gradcheck_axis_angle():
    g = torch.Generator().manual_seed(0)
    axis = torch.randn(5, 3, generator=g, dtype=F64, requires_grad=True)
    angle = torch.tensor([1e-8, 0.5, 2.0, PI - 1e-6, -1.0], dtype=F64, requires_grad=True)
    assert torch.autograd.gradcheck(C.axis_angle_to_matrix, (axis, angle))
    assert torch.autograd.gradgradcheck(C.axis_angle_to_matrix, (axis, angle))
    R = so3.exp(torch.randn(4, 3, generator=g, dtype=F64)).requires_grad_(True)
    assert torch.autograd.gradcheck(C.matrix_to_axis_angle, (R,))


# ----------------------------------------------------------------------------------------------
# 6-D and 9-D representations
# ----------------------------------------------------------------------------------------------


def assert_rotation(R: torch.Tensor, tol: float):
    eye = torch.eye(3, dtype=R.dtype)
    assert (R.mT @ R - eye).abs().max() <= tol
    assert (torch.linalg.det(R) - 1).abs().max() <= tol


def test_rot6d_round_trip_and_layout(dtype):
    R = quaternion.to_matrix(rotation_quaternions().to(dtype))
    x = C.matrix_to_rot6d(R)
    assert x.shape == (*R.shape[:-2], 6)
    assert torch.equal(x[..., :3], R[..., :, 0]) and torch.equal(x[..., 3:], R[..., :, 1])
    assert (C.rot6d_to_matrix(x) - R).abs().max() <= 4 * eps(dtype)


def test_rot6d_gram_schmidt(dtype):
    g = torch.Generator().manual_seed(1)
    x = torch.randn(500, 6, generator=g, dtype=F64)
    R = C.rot6d_to_matrix(x.to(dtype))
    assert_rotation(R, 8 * eps(dtype))
    a1, a2 = x[:, :3], x[:, 3:]
    b1 = a1 / a1.norm(dim=-1, keepdim=True)
    r = a2 - (b1 * a2).sum(-1, keepdim=True) * b1
    b2 = r / r.norm(dim=-1, keepdim=True)
    ref = torch.stack((b1, b2, torch.linalg.cross(b1, b2)), dim=-1)
    # the Gram-Schmidt residual's conditioning is |a2| / |r|
    cond = (a2.norm(dim=-1) / r.norm(dim=-1))[:, None, None]
    assert ((R.double() - ref).abs() / cond).max() <= 8 * eps(dtype)
    # invariant to a positive scale of each column
    s = torch.tensor([1e-20, 3.0, 1e20], dtype=dtype)
    for s1, s2 in itertools.product(s, s):
        xs = torch.cat((s1 * x[:, :3].to(dtype), s2 * x[:, 3:].to(dtype)), dim=-1)
        assert ((C.rot6d_to_matrix(xs).double() - ref).abs() / cond).max() <= 8 * eps(dtype)


def test_rot6d_nearly_parallel_is_still_a_rotation(dtype):
    a1 = torch.tensor([1.0, 2.0, 3.0], dtype=dtype)
    a2 = 2.0 * a1 + torch.tensor([0.0, 1.0, -1.0], dtype=dtype) * 1e3 * eps(dtype)
    R = C.rot6d_to_matrix(torch.cat((a1, a2)))
    assert_rotation(R, 8 * eps(dtype))
    torch.testing.assert_close(R[:, 0], a1 / a1.norm(), rtol=0, atol=2 * eps(dtype))


def test_rot6d_degenerate_is_nan_only_there():
    x = torch.tensor(
        [
            [0.0, 0.0, 0.0, 0.0, 1.0, 0.0],  # a1 = 0
            [1.0, 0.0, 0.0, 2.0, 0.0, 0.0],  # a2 parallel to a1
            [1.0, 0.0, 0.0, 0.0, 0.0, 0.0],  # a2 = 0
            [1.0, 2.0, 0.0, -1.0, 0.5, 3.0],
        ],
        requires_grad=True,
    )
    R = C.rot6d_to_matrix(x)
    assert torch.isnan(R[:3]).all(dim=(-1, -2)).all()
    assert torch.isfinite(R[3]).all()
    R.nansum().backward()
    assert torch.isfinite(x.grad[3]).all()


@pytest.mark.parametrize("scale", [1e-6, 1.0, 1e6])
def test_gradcheck_rot6d(scale):
    g = torch.Generator().manual_seed(2)
    x = (scale * torch.randn(5, 6, generator=g, dtype=F64)).requires_grad_(True)
    assert torch.autograd.gradcheck(C.rot6d_to_matrix, (x,), eps=1e-6 * scale)
    if scale == 1.0:
        assert torch.autograd.gradgradcheck(C.rot6d_to_matrix, (x,))


def test_rot6d_gradient_finite_at_huge_and_tiny_scale(dtype):
    g = torch.Generator().manual_seed(3)
    x = torch.randn(8, 6, generator=g, dtype=dtype)
    grads = []
    for scale in (1e-6, 1.0, 1e6):
        xs = (scale * x).requires_grad_(True)
        (C.rot6d_to_matrix(xs) * torch.arange(9, dtype=dtype).reshape(3, 3)).sum().backward()
        assert torch.isfinite(xs.grad).all()
        grads.append(xs.grad * scale)
    # the gradient scales exactly like 1 / scale
    for gr in grads[::2]:
        torch.testing.assert_close(gr, grads[1], rtol=64 * eps(dtype), atol=64 * eps(dtype))


def numpy_project(M: np.ndarray) -> np.ndarray:
    U, _, Vt = np.linalg.svd(M)
    d = np.sign(np.linalg.det(U @ Vt))
    return U @ np.diag([1.0, 1.0, d]) @ Vt


def test_rot9d(dtype):
    g = torch.Generator().manual_seed(4)
    x = torch.randn(200, 9, generator=g, dtype=F64)
    R = C.rot9d_to_matrix(x.to(dtype))
    assert R.shape == (200, 3, 3) and R.dtype == dtype
    ref = torch.from_numpy(np.stack([numpy_project(m) for m in x.reshape(-1, 3, 3).numpy()]))
    # conditioning: 1 / (sum of the two smallest signed singular values)
    s = torch.linalg.svdvals(x.reshape(-1, 3, 3))
    sign = torch.sign(torch.linalg.det(x.reshape(-1, 3, 3)))
    gap = (s[:, 1] + sign * s[:, 2]) / s[:, 0]
    assert (((R.double() - ref).abs().amax((-1, -2))) * gap).max() <= 32 * eps(dtype)
    assert_rotation(R, 16 * eps(dtype))
    torch.testing.assert_close(R, so3.project(x.reshape(-1, 3, 3).to(dtype)), rtol=0, atol=0)
    # a rotation maps to itself (row-major layout)
    Rs = quaternion.to_matrix(rotation_quaternions().to(dtype))
    assert (C.rot9d_to_matrix(Rs.flatten(-2)) - Rs).abs().max() <= 16 * eps(dtype)


def test_gradcheck_rot9d():
    g = torch.Generator().manual_seed(5)
    x = torch.randn(4, 9, generator=g, dtype=F64)
    R = quaternion.to_matrix(haar_quaternions(2, seed=6)).flatten(-2)  # at rotations too
    x = torch.cat((x, R)).requires_grad_(True)
    assert torch.autograd.gradcheck(C.rot9d_to_matrix, (x,))


# ----------------------------------------------------------------------------------------------
# Batch shapes, dtypes, bad input, NaN isolation
# ----------------------------------------------------------------------------------------------

# (function, makes its input from a batch of rotations (R, q), trailing output shape)
UNARY = {
    "euler_to_matrix": (lambda a: C.euler_to_matrix(a, "ZYX"), lambda R, q, e: e, (3, 3)),
    "euler_to_quaternion": (lambda a: C.euler_to_quaternion(a, "yzy"), lambda R, q, e: e, (4,)),
    "matrix_to_euler": (lambda R: C.matrix_to_euler(R, "xzx"), lambda R, q, e: R, (3,)),
    "quaternion_to_euler": (lambda q: C.quaternion_to_euler(q, "YXZ"), lambda R, q, e: q, (3,)),
    "rot6d_to_matrix": (C.rot6d_to_matrix, lambda R, q, e: C.matrix_to_rot6d(R), (3, 3)),
    "matrix_to_rot6d": (C.matrix_to_rot6d, lambda R, q, e: R, (6,)),
    "rot9d_to_matrix": (C.rot9d_to_matrix, lambda R, q, e: R.flatten(-2) + 0.1, (3, 3)),
    "axis_angle_to_matrix": (
        lambda x: C.axis_angle_to_matrix(x[..., :3], x[..., 3]),
        lambda R, q, e: q,
        (3, 3),
    ),
    "matrix_to_axis_angle": (
        lambda R: torch.cat(
            (C.matrix_to_axis_angle(R)[0], C.matrix_to_axis_angle(R)[1][..., None]), dim=-1
        ),
        lambda R, q, e: R,
        (4,),
    ),
}


def batch_inputs(batch, dtype):
    n = math.prod(batch)
    q = haar_quaternions(max(n, 1), seed=8)[:n].reshape(*batch, 4)
    R = quaternion.to_matrix(q)
    e = C.quaternion_to_euler(q, "xyz")
    return R.to(dtype), q.to(dtype), e.to(dtype)


@pytest.mark.parametrize("name", list(UNARY))
def test_batch_shapes(name, batch, dtype):
    fn, make, trailing = UNARY[name]
    x = make(*batch_inputs(batch, dtype))
    out = fn(x)
    assert out.shape == (*batch, *trailing) and out.dtype == dtype
    # each element equals the unbatched call
    flat = x.reshape(-1, *x.shape[len(batch) :])
    for i in range(flat.shape[0]):
        torch.testing.assert_close(out.reshape(-1, *trailing)[i], fn(flat[i]), rtol=0, atol=0)


def test_axis_angle_broadcasts():
    axis = torch.randn(5, 1, 3, dtype=F64)
    angle = torch.rand(1, 4, dtype=F64)
    R = C.axis_angle_to_matrix(axis, angle)
    assert R.shape == (5, 4, 3, 3)
    torch.testing.assert_close(R[2, 3], C.axis_angle_to_matrix(axis[2, 0], angle[0, 3]))
    assert C.axis_angle_to_matrix(torch.tensor([0.0, 0.0, 1.0]), 0.5).shape == (3, 3)
    with pytest.raises(ValueError, match=r"torchlie\.conversions\.axis_angle_to_matrix"):
        C.axis_angle_to_matrix(torch.randn(5, 3), torch.rand(4))


@pytest.mark.parametrize("half", [torch.float16, torch.bfloat16])
@pytest.mark.parametrize("name", list(UNARY))
def test_half_in_half_out(name, half):
    fn, make, _ = UNARY[name]
    x = make(*batch_inputs((5,), torch.float32))
    out = fn(x.to(half))
    assert out.dtype == half
    ref = fn(x.to(half).float())
    torch.testing.assert_close(out, ref.to(half), rtol=0, atol=0)


def test_half_axis_angle_tuple():
    axis, angle = C.matrix_to_axis_angle(torch.eye(3, dtype=torch.bfloat16))
    assert axis.dtype == angle.dtype == torch.bfloat16


@pytest.mark.parametrize(
    "call, shape",
    [
        (lambda x: C.euler_to_matrix(x, "xyz"), (4, 2)),
        (lambda x: C.euler_to_quaternion(x, "xyz"), (4,)),
        (lambda x: C.matrix_to_euler(x, "xyz"), (3, 4)),
        (lambda x: C.quaternion_to_euler(x, "xyz"), (3,)),
        (C.rot6d_to_matrix, (2, 9)),
        (C.matrix_to_rot6d, (6,)),
        (C.rot9d_to_matrix, (3, 3)),
        (C.matrix_to_axis_angle, (3,)),
        (lambda x: C.axis_angle_to_matrix(x, 1.0), (4,)),
    ],
)
def test_bad_shape_and_dtype(call, shape):
    with pytest.raises(ValueError, match=r"torchlie\.conversions\.\w+: expected .* got"):
        call(torch.zeros(shape))
    good = {4: 4, 2: 3, 9: 6, 6: 9}
    with pytest.raises(TypeError, match=r"torchlie\.conversions\.\w+"):
        call(torch.zeros(*shape[:-1], good.get(shape[-1], 3), dtype=torch.int64))


@pytest.mark.parametrize("seq", ["xy", "xyzx", "", "xYz", "Xyz", "xxy", "xyy", "XXZ", "abc", "xwz"])
@pytest.mark.parametrize(
    "fn, shape",
    [
        (C.euler_to_matrix, (3,)),
        (C.euler_to_quaternion, (3,)),
        (C.matrix_to_euler, (3, 3)),
        (C.quaternion_to_euler, (4,)),
    ],
)
def test_bad_sequence(fn, shape, seq):
    with pytest.raises(ValueError, match=rf"torchlie\.conversions\.{fn.__name__}: .*'{seq}'"):
        fn(torch.zeros(shape), seq)


def test_sequence_must_be_str():
    with pytest.raises(TypeError, match=r"torchlie\.conversions\.euler_to_matrix"):
        C.euler_to_matrix(torch.zeros(3), ["x", "y", "z"])


def test_axis_angle_bad_angle():
    with pytest.raises(TypeError, match="angle"):
        C.axis_angle_to_matrix(torch.zeros(3), torch.tensor(1))
    with pytest.raises(TypeError, match="dtype"):
        C.axis_angle_to_matrix(torch.zeros(3), torch.tensor(1.0, dtype=F64))


@pytest.mark.parametrize("name", list(UNARY))
def test_nan_stays_in_its_element(name):
    fn, make, _ = UNARY[name]
    x = make(*batch_inputs((4,), F64)).clone()
    ref = fn(x[1:])
    x[0] = float("nan")
    out = fn(x)
    assert torch.isnan(out[0]).all()
    torch.testing.assert_close(out[1:], ref, rtol=0, atol=0)


# ----------------------------------------------------------------------------------------------
# vmap, compile, device
# ----------------------------------------------------------------------------------------------


def test_vmap():
    q = haar_quaternions(6, seed=9)
    R = quaternion.to_matrix(q)
    vm = torch.func.vmap(lambda x: C.matrix_to_euler(x, "ZXY"))
    torch.testing.assert_close(vm(R), C.matrix_to_euler(R, "ZXY"))
    a = C.matrix_to_euler(R, "ZXY")
    ve = torch.func.vmap(lambda x: C.euler_to_matrix(x, "ZXY"))
    torch.testing.assert_close(ve(a), R)
    x = C.matrix_to_rot6d(R)
    torch.testing.assert_close(torch.func.vmap(C.rot6d_to_matrix)(x), C.rot6d_to_matrix(x))
    J = torch.func.vmap(torch.func.jacrev(C.rot6d_to_matrix))(x)
    Jf = torch.func.vmap(torch.func.jacfwd(C.rot6d_to_matrix))(x)
    torch.testing.assert_close(J, Jf)


@pytest.mark.compile
def test_compile_fullgraph():
    def pipeline(a: torch.Tensor, x6: torch.Tensor):
        R = C.euler_to_matrix(a, "XYZ") @ C.rot6d_to_matrix(x6)
        axis, angle = C.matrix_to_axis_angle(R)
        return C.matrix_to_euler(R, "zxz"), C.matrix_to_rot6d(R), axis, angle

    g = torch.Generator().manual_seed(10)
    a = torch.randn(7, 3, generator=g)
    x6 = torch.randn(7, 6, generator=g)
    compiled = torch.compile(pipeline, fullgraph=True, backend="aot_eager")  # see test_compile.py
    for got, ref in zip(compiled(a, x6), pipeline(a, x6), strict=True):
        torch.testing.assert_close(got, ref, rtol=0, atol=64 * eps(torch.float32))


def test_device(device):
    a = sample_angles("xyz", 20, seed=12).to(device)
    R = C.euler_to_matrix(a, "yxz")
    assert R.device.type == torch.device(device).type
    back = C.euler_to_matrix(C.matrix_to_euler(R, "yxz"), "yxz")
    assert (back - R).abs().max() <= RT_LOCK_TOL * eps(F64)
    assert (C.rot6d_to_matrix(C.matrix_to_rot6d(R)) - R).abs().max() <= 4 * eps(F64)


def test_sampler_angles_round_trip_all_sequences(dtype):
    """Rotations at the sampler's hard angles (0, tiny, pi, just below pi) over every sequence."""
    w, _ = rotvecs(ANGLES, n_random=10, dtype=dtype)
    R = so3.exp(w)
    for seq in SEQS:
        a = C.matrix_to_euler(R, seq)
        assert torch.isfinite(a).all()
        assert (C.euler_to_matrix(a, seq) - R).abs().max() <= RT_LOCK_TOL * eps(dtype)
