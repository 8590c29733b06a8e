"""Tests of torchlie.quaternion: conventions (scipy as the oracle), accuracy at the hard points
(mpmath references), gradients, batching, bad input, vmap/jacrev and torch.compile."""

from __future__ import annotations

import math
from functools import cache

import mpmath as mp
import numpy as np
import pytest
import samplers
import torch
from agreement import assert_agree
from samplers import eps
from scipy.spatial.transform import Rotation, Slerp
from torch.autograd import gradcheck, gradgradcheck

import torchlie.so3 as so3
from torchlie import quaternion as Q

F64 = torch.float64
LOW = [torch.float16, torch.bfloat16]
# Angles for gradcheck: the spec's GRAD_ANGLES plus exactly 0 (every op here is smooth there).
GC_ANGLES = [0.0] + samplers.GRAD_ANGLES


def haar(n: int, seed: int = 0, dtype=F64) -> torch.Tensor:
    return samplers.haar_quaternions(n, seed=seed, dtype=dtype)


def generic_axes(n: int = 3) -> torch.Tensor:
    """Random unit axes (no coordinate ties, so Shepperd's pivot is unique)."""
    return samplers.axes(n_random=n, seed=7)[-n:]


def rel_err(x: torch.Tensor, ref: torch.Tensor, dims: int = 1) -> torch.Tensor:
    """Normwise relative error over the last ``dims`` dimensions (0 where both are 0)."""
    d = (x.double() - ref.double()).flatten(-dims).norm(dim=-1)
    n = ref.double().flatten(-dims).norm(dim=-1)
    zero_ok = torch.where(d == 0, 0.0, math.inf)
    return torch.where(n > 0, d / torch.where(n > 0, n, 1.0), zero_ok)


def sign_err(x: torch.Tensor, ref: torch.Tensor) -> torch.Tensor:
    """Normwise error of a quaternion up to its sign."""
    x, ref = x.double(), ref.double()
    return torch.minimum((x - ref).norm(dim=-1), (x + ref).norm(dim=-1)) / ref.norm(dim=-1)


def sp(q: torch.Tensor) -> Rotation:
    return Rotation.from_quat(q.detach().double().reshape(-1, 4).numpy(), scalar_first=True)


def sp_quat(r: Rotation) -> torch.Tensor:
    return torch.from_numpy(r.as_quat(scalar_first=True))


def with_grad(x: torch.Tensor) -> torch.Tensor:
    return x.detach().clone().requires_grad_(True)


# ----------------------------------------------------------------------------------------------
# High-precision references (mpmath), from the exact floating-point inputs
# ----------------------------------------------------------------------------------------------

mp.mp.prec = 160


def _mp(x: torch.Tensor) -> list:
    return [mp.mpf(float(v)) for v in x.double().tolist()]


def _mp_rotvec_quat(w: list) -> list:
    t = mp.sqrt(sum(c * c for c in w))
    s = mp.sin(t / 2) / t if t != 0 else mp.mpf(1) / 2
    return [mp.cos(t / 2)] + [s * c for c in w]


def _mp_quat_matrix(q: list) -> list:
    n2 = sum(c * c for c in q)
    w, x, y, z = (c / mp.sqrt(n2) for c in q)
    return [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]


def _mp_exp(q: list) -> list:
    s, v = q[0], q[1:]
    n = mp.sqrt(sum(c * c for c in v))
    k = mp.sin(n) / n if n != 0 else mp.mpf(1)
    return [mp.exp(s) * mp.cos(n)] + [mp.exp(s) * k * c for c in v]


def _mp_log(q: list) -> list:
    w, v = q[0], q[1:]
    n = mp.sqrt(sum(c * c for c in v))
    ln = mp.log(mp.sqrt(w * w + n * n))
    if n == 0:
        return [ln, mp.pi if w < 0 else mp.mpf(0), mp.mpf(0), mp.mpf(0)]
    a = mp.atan2(n, w) / n
    return [ln] + [a * c for c in v]


def _to_t(rows: list) -> torch.Tensor:
    return torch.tensor([[float(c) for c in r] for r in rows], dtype=F64)


@cache
def hard_rotvec_refs(dtype: torch.dtype):
    """Rotation vectors of the spec's sweep (rounded to ``dtype``) and their exact q and R."""
    omega, _ = samplers.rotvecs(dtype=dtype)
    qs, Rs = [], []
    for w in omega:
        q = _mp_rotvec_quat(_mp(w))
        qs.append(q)
        Rs.append([c for row in _mp_quat_matrix(q) for c in row])
    return omega, _to_t(qs), _to_t(Rs).reshape(-1, 3, 3)


# ----------------------------------------------------------------------------------------------
# Conventions against scipy
# ----------------------------------------------------------------------------------------------


def test_to_matrix_matches_scipy(dtype):
    q = torch.cat((haar(300), samplers.hard_quaternions())).to(dtype)
    R = Q.to_matrix(q)
    ref = torch.from_numpy(sp(q).as_matrix())
    assert rel_err(R, ref, 2).max() <= 4 * eps(dtype)


def test_to_matrix_textbook():
    # pi/3 about x maps e2 to (0, cos, sin).
    q = Q.from_rotvec(torch.tensor([math.pi / 3, 0.0, 0.0], dtype=F64))
    e2 = torch.tensor([0.0, 1.0, 0.0], dtype=F64)
    expected = torch.tensor([0.0, 0.5, math.sqrt(3) / 2], dtype=F64)
    torch.testing.assert_close(Q.to_matrix(q) @ e2, expected, atol=4 * eps(F64), rtol=0)
    torch.testing.assert_close(Q.apply(q, e2), expected, atol=4 * eps(F64), rtol=0)


def test_to_matrix_scale_invariant(dtype):
    q = haar(100, seed=1, dtype=dtype)
    R = Q.to_matrix(q)
    for s in (1e-3, 0.5, 3.0, 1e3):
        assert rel_err(Q.to_matrix(s * q), R, 2).max() <= 8 * eps(dtype)
        assert rel_err(
            Q.apply(s * q, torch.ones(3, dtype=dtype)), R @ torch.ones(3, dtype=dtype)
        ).max() <= 8 * eps(dtype)
        assert rel_err(Q.to_rotvec(s * q), Q.to_rotvec(q)).max() <= 8 * eps(dtype)


def test_from_matrix_matches_scipy(dtype):
    R = torch.from_numpy(Rotation.random(300, rng=3).as_matrix()).to(dtype)
    q = Q.from_matrix(R)
    ref = sp_quat(Rotation.from_matrix(R.double().numpy()))
    assert sign_err(q, ref).max() <= 4 * eps(dtype)
    assert (q[..., 0] >= 0).all()


def test_from_matrix_180_degrees_matches_scipy(dtype):
    ax = samplers.axes(n_random=50)
    R = (2.0 * ax[:, :, None] * ax[:, None, :] - torch.eye(3, dtype=F64)).to(dtype)
    q = Q.from_matrix(R)
    ref = sp_quat(Rotation.from_matrix(R.double().numpy()))
    assert sign_err(q, ref).max() <= 4 * eps(dtype)
    # canonical: w >= 0 (w is O(eps) here, its sign set by the rounding of R)
    assert (q[:, 0] >= 0).all() and (q[:, 0] <= 2 * eps(dtype)).all()
    # at w == 0 exactly, the largest-magnitude vector component is positive (first on ties)
    n = torch.tensor([[0.6, -0.8, 0.0], [0.0, 0.0, -1.0], [-1.0, 1.0, 0.0]], dtype=dtype)
    n = n / n.norm(dim=-1, keepdim=True)
    q = Q.from_matrix(2.0 * n[:, :, None] * n[:, None, :] - torch.eye(3, dtype=dtype))
    assert (q[:, 0] == 0).all()
    assert (q[:, 1:] - torch.stack((-n[0], -n[1], -n[2]))).abs().max() <= 2 * eps(dtype)


def test_rotvec_matches_scipy(dtype):
    q = haar(300, seed=2, dtype=dtype)
    ref = torch.from_numpy(sp(q).as_rotvec())
    assert rel_err(Q.to_rotvec(q), ref).max() <= 4 * eps(dtype)
    w = ref.to(dtype)
    ref_q = sp_quat(Rotation.from_rotvec(w.double().numpy()))
    assert sign_err(Q.from_rotvec(w), ref_q).max() <= 4 * eps(dtype)


def test_multiply_composes_like_matrices(dtype):
    q1, q2 = haar(200, 4, dtype), haar(200, 5, dtype)
    q = Q.multiply(q1, q2)
    assert rel_err(Q.to_matrix(q), Q.to_matrix(q1) @ Q.to_matrix(q2), 2).max() <= 8 * eps(dtype)
    assert sign_err(q, sp_quat(sp(q1) * sp(q2))).max() <= 4 * eps(dtype)
    # literal: i * j = k
    i, j, k = torch.eye(4, dtype=dtype)[1:]
    assert torch.equal(Q.multiply(i, j), k)


def test_apply_matches_scipy(dtype):
    q = haar(200, 6, dtype)
    p = torch.randn(200, 3, generator=torch.Generator().manual_seed(0), dtype=F64).to(dtype)
    ref = torch.from_numpy(sp(q).apply(p.double().numpy()))
    assert rel_err(Q.apply(q, p), ref).max() <= 8 * eps(dtype)
    # q [0, p] q^-1, literally
    qp = Q.multiply(Q.multiply(q, torch.cat((torch.zeros_like(p[:, :1]), p), -1)), Q.inverse(q))
    assert rel_err(Q.apply(q, p), qp[:, 1:]).max() <= 16 * eps(dtype)
    assert (qp[:, 0].abs() <= 8 * eps(dtype) * p.norm(dim=-1)).all()


def test_inverse_conjugate_normalize(dtype):
    q = haar(100, 8, dtype) * torch.linspace(0.1, 10.0, 100, dtype=dtype)[:, None]
    one = Q.identity(100, dtype=dtype)
    assert (Q.multiply(q, Q.inverse(q)) - one).abs().max() <= 8 * eps(dtype)
    assert (Q.multiply(Q.inverse(q), q) - one).abs().max() <= 8 * eps(dtype)
    u = Q.normalize(q)
    assert ((u.norm(dim=-1) - 1).abs() <= 2 * eps(dtype)).all()
    assert rel_err(Q.inverse(u), Q.conjugate(u)).max() <= 4 * eps(dtype)
    ref = sp_quat(sp(q).inv())
    assert sign_err(Q.conjugate(u), ref).max() <= 4 * eps(dtype)
    assert torch.equal(Q.conjugate(q), q * torch.tensor([1.0, -1.0, -1.0, -1.0], dtype=dtype))


def test_canonicalize_rule():
    t = torch.tensor
    cases = [
        ([-0.5, 0.1, -0.2, 0.3], [0.5, -0.1, 0.2, -0.3]),
        ([0.5, 0.1, -0.2, 0.3], [0.5, 0.1, -0.2, 0.3]),
        ([0.0, 0.6, -0.8, 0.0], [0.0, -0.6, 0.8, 0.0]),  # largest |component| is y < 0: flip
        ([0.0, -0.8, 0.6, 0.0], [0.0, 0.8, -0.6, 0.0]),
        ([0.0, 0.0, 0.0, -1.0], [0.0, 0.0, 0.0, 1.0]),
        ([0.0, -1.0, 1.0, 0.0], [0.0, 1.0, -1.0, 0.0]),  # tie: the first one decides
        ([0.0, 1.0, -1.0, -1.0], [0.0, 1.0, -1.0, -1.0]),
        ([-0.0, 0.0, -2.0, 2.0], [0.0, 0.0, 2.0, -2.0]),  # -0.0 counts as 0
    ]
    for q, expected in cases:
        assert torch.equal(Q.canonicalize(t(q)), t(expected)), q
    # q and -q give the same canonical representative, exactly
    h = samplers.hard_quaternions()
    assert torch.equal(Q.canonicalize(h), Q.canonicalize(-h))
    assert (Q.canonicalize(h)[:, 0] >= 0).all()


# ----------------------------------------------------------------------------------------------
# Accuracy at the hard points (spec angle sweep x >= 200 axes)
# ----------------------------------------------------------------------------------------------


def test_hard_rotvecs_accuracy(dtype):
    omega, q_ref, R_ref = hard_rotvec_refs(dtype)
    tol = 4 * eps(dtype)
    # from_rotvec: exact reference of the rounded input
    assert rel_err(Q.from_rotvec(omega), q_ref).max() <= tol
    # to_matrix of the exact quaternion rounded to dtype (reference error included: the
    # rounding of q contributes at most ~2 eps)
    assert rel_err(Q.to_matrix(q_ref.to(dtype)), R_ref, 2).max() <= tol
    # from_matrix of the exact matrix rounded to dtype; up to sign (at pi the sign of w is the
    # rounding's), and always canonical
    q = Q.from_matrix(R_ref.to(dtype))
    assert sign_err(q, q_ref).max() <= tol
    assert (q[:, 0] >= 0).all()
    # to_rotvec back to the input; near pi the canonical vector may be -omega (up to O(eps))
    r = Q.to_rotvec(q_ref.to(dtype))
    w = omega.double()
    err = torch.minimum((r.double() - w).norm(dim=-1), (r.double() + w).norm(dim=-1))
    nz = w.norm(dim=-1) > 0
    assert (err[nz] / w.norm(dim=-1)[nz]).max() <= tol
    assert torch.equal(r[~nz], torch.zeros_like(r[~nz]))
    far = w.norm(dim=-1) < 3.0  # away from pi the sign is unambiguous
    assert rel_err(r[far], w[far]).max() <= tol


def test_from_rotvec_is_canonical_just_below_pi(dtype):
    # Angles just below pi (random axes at 1 to 4 floats below pi in float32, which evaluates
    # the angle in float64; 16 to 64 in float64, past its own rounding of the angle): w > 0
    # wherever the input's exact angle is below pi by more than float64 resolves.
    g = torch.Generator().manual_seed(31)
    n = torch.nn.functional.normalize(torch.randn(4000, 3, generator=g, dtype=F64), dim=-1)
    t = torch.tensor(math.pi, dtype=dtype)
    below = [t := torch.nextafter(t, torch.tensor(0.0, dtype=dtype)) for _ in range(64)]
    below = below[:4] if dtype == torch.float32 else below[15::16]
    omega = torch.cat([(n[i::4] * float(b)).to(dtype) for i, b in enumerate(below)])
    with mp.workdps(40):
        angle = [mp.sqrt(sum(mp.mpf(float(c)) ** 2 for c in row)) for row in omega.tolist()]
        inside = torch.tensor([a < mp.pi * (1 - 8 * torch.finfo(F64).eps) for a in angle])
    assert int(inside.sum()) > 1000
    q = Q.from_rotvec(omega)
    assert bool((q[inside, 0] > 0).all())


def test_hard_quaternions_antipodal(dtype):
    h = samplers.hard_quaternions(dtype)
    assert torch.equal(Q.to_matrix(h), Q.to_matrix(-h))
    assert torch.equal(Q.to_rotvec(h), Q.to_rotvec(-h))
    assert torch.equal(
        Q.apply(h, torch.ones(3, dtype=dtype)), Q.apply(-h, torch.ones(3, dtype=dtype))
    )
    # round trip through the matrix gives the canonical representative
    assert sign_err(Q.from_matrix(Q.to_matrix(h)), h).max() <= 4 * eps(dtype)
    assert (Q.from_matrix(Q.to_matrix(h))[:, 0] >= 0).all()
    assert sign_err(Q.from_rotvec(Q.to_rotvec(h)), h).max() <= 4 * eps(dtype)


def test_outputs_and_gradients_finite_at_hard_points(dtype):
    h = samplers.hard_quaternions(dtype)
    omega, _ = samplers.rotvecs(n_random=8, dtype=dtype)
    p = torch.ones(3, dtype=dtype)
    fns = {
        "to_matrix": lambda q: Q.to_matrix(q),
        "to_rotvec": lambda q: Q.to_rotvec(q),
        "apply": lambda q: Q.apply(q, p),
        "log": lambda q: Q.log(q),
        "exp": lambda q: Q.exp(q),
        "exp_log": lambda q: Q.exp(Q.log(q)),
        "slerp_same": lambda q: Q.slerp(q, q, 0.3),
        "slerp_anti": lambda q: Q.slerp(q, -q, 0.3),
        "slerp_id": lambda q: Q.slerp(Q.identity(dtype=dtype), q, 0.7),
        "from_matrix": lambda q: Q.from_matrix(Q.to_matrix(q)),
        "inverse": lambda q: Q.inverse(q),
        "integrate": lambda q: Q.integrate(Q.identity(dtype=dtype), q[..., 1:], 2.0),
    }
    for name, f in fns.items():
        x = with_grad(h)
        y = f(x)
        assert torch.isfinite(y).all(), name
        (g,) = torch.autograd.grad(y.sum(), x)
        assert torch.isfinite(g).all(), name
    x = with_grad(omega)
    y = Q.from_rotvec(x)
    (g,) = torch.autograd.grad(y.sum(), x)
    assert torch.isfinite(y).all() and torch.isfinite(g).all()


def test_gradients_finite_when_w_is_tiny_against_v(dtype):
    # w = 1e-20 next to |v| = 1: n^2/w^3 overflows float32 if a series test divides by w^2
    q = with_grad(torch.tensor([[1e-20, 1.0, 0.0, 0.0], [-1e-20, 0.0, 0.6, 0.8]], dtype=dtype))
    for f in (Q.to_rotvec, Q.log, lambda x: Q.slerp(Q.identity(dtype=dtype), x, 0.5)):
        (g,) = torch.autograd.grad(f(q).sum(), q)
        assert torch.isfinite(g).all()
    # d to_rotvec / dw at w = 0+ for q = (w, 1, 0, 0): -2 (derivative of 2 atan2(1, w) at 0)
    (g,) = torch.autograd.grad(Q.to_rotvec(q)[0, 0], q)
    assert abs(g[0, 0].item() + 2.0) <= 4 * eps(dtype)


# ----------------------------------------------------------------------------------------------
# exp / log of general quaternions
# ----------------------------------------------------------------------------------------------


def general_quaternions(dtype) -> torch.Tensor:
    """Scaled hard quaternions (w of both signs, w = 0, tiny and large vector parts)."""
    h = samplers.hard_quaternions()[::7]
    scales = torch.tensor([1e-3, 0.7, 1.0, 20.0], dtype=F64)
    return (scales[:, None, None] * h[None]).reshape(-1, 4).to(dtype)


def test_log_accuracy(dtype):
    q = general_quaternions(dtype)
    ref = _to_t([_mp_log(_mp(x)) for x in q])
    out = Q.log(q)
    # componentwise: the scalar ln|q| and the vector part each to a few ulp
    assert (
        (out[:, 0].double() - ref[:, 0]).abs() <= 4 * eps(dtype) * ref[:, 0].abs().clamp_min(1.0)
    ).all()
    assert rel_err(out[:, 1:], ref[:, 1:]).max() <= 4 * eps(dtype)
    zero_v = ref[:, 1:].norm(dim=-1) == 0
    assert torch.equal(out[zero_v, 1:], ref[zero_v, 1:].to(dtype))


def test_log_branch_cut_and_zero(dtype):
    q = torch.tensor(
        [[-2.0, 0.0, 0.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]], dtype=dtype
    )
    out = Q.log(q)
    torch.testing.assert_close(
        out[0],
        torch.tensor([math.log(2.0), math.pi, 0.0, 0.0], dtype=dtype),
        rtol=0,
        atol=eps(dtype),
    )
    assert torch.equal(out[1], torch.tensor([0.0, math.pi, 0.0, 0.0], dtype=dtype))
    assert torch.isnan(out[2]).all()
    assert rel_err(Q.exp(out[:2]), q[:2]).max() <= 2 * eps(dtype)  # sin(fl(pi)) ~ eps
    x = with_grad(q[:2])
    (g,) = torch.autograd.grad(Q.log(x).sum(), x)
    assert torch.isfinite(g).all()


def _mp_log_jacobian(q: list, rel: float) -> list:
    """Central differences of :func:`_mp_log`, each step ``rel`` times the smallest non-zero
    |component| ``m`` (far below the distance to the branch cut), with digits enough for the
    changes of ``ln|q|`` (of order ``m h``) and of the angle."""
    m = min(abs(c) for c in q if c != 0)
    with mp.workdps(100 + 3 * int(-mp.log10(m * rel))):
        h = mp.mpf(rel) * m
        J = [[mp.mpf(0)] * 4 for _ in range(4)]
        for j in range(4):
            hi = [c + (h if i == j else 0) for i, c in enumerate(q)]
            lo = [c - (h if i == j else 0) for i, c in enumerate(q)]
            for i, (a, b) in enumerate(zip(_mp_log(hi), _mp_log(lo), strict=True)):
                J[i][j] = (a - b) / (2 * h)
        return J


@pytest.mark.parametrize("w", [-1.0, -2.0, 0.5])
@pytest.mark.parametrize("s", [1e-3, 1e-12, 1e-20, 1e-30])
def test_log_jacobian_next_to_the_reals(dtype, w, s):
    """Every entry of the Jacobian, reverse and forward mode, next to the real axis: beside the
    branch cut (w < 0) the derivative across v is about pi/|v| and the one along v is w/|q|^2
    (about -1): both to a few ulp entry by entry, for v along an axis (in float64 also 1e-100
    and 1e-200, whose squares are far below the normal range)."""
    sizes = [s] if dtype == torch.float32 else [s, s * 1e-70, s * 1e-170]
    for m in sizes:
        q = torch.tensor([w, 0.0, m, 0.0], dtype=dtype)
        ref = _to_t(_mp_log_jacobian(_mp(q), 1e-30))
        for J in (torch.func.jacrev(Q.log)(q), torch.func.jacfwd(Q.log)(q)):
            err = (J.double() - ref).abs()
            assert (err <= 4 * eps(dtype) * ref.abs()).all(), (m, J, ref)


def test_exp_accuracy(dtype):
    a, _ = samplers.rotvecs(n_random=20)
    a = torch.cat(
        (
            0.5 * a,
            torch.tensor(
                [[2.0, 0.0, 0.0], [0.0, math.pi, 0.0], [3.0, -4.0, 0.0], [0.0, 6.0, 8.0]], dtype=F64
            ),
        )
    )
    s = torch.tensor([0.0, -0.7, 1.3], dtype=F64)
    p = torch.cat((s.repeat_interleave(a.shape[0])[:, None], a.repeat(3, 1)), dim=-1).to(dtype)
    ref = _to_t([_mp_exp(_mp(x)) for x in p])
    assert rel_err(Q.exp(p), ref).max() <= 4 * eps(dtype)
    # exp of a pure quaternion is from_rotvec of twice its vector part, bitwise
    pure = p[: a.shape[0]]
    assert torch.equal(Q.exp(pure), Q.from_rotvec(2.0 * pure[:, 1:]))


def test_exp_log_round_trips(dtype):
    q = general_quaternions(dtype)
    q = q[(q[:, 1:].norm(dim=-1) > 0) | (q[:, 0] > 0)]  # off the branch cut
    assert rel_err(Q.exp(Q.log(q)), q).max() <= 8 * eps(dtype)
    p = Q.log(q)
    p = p[p[:, 1:].norm(dim=-1) < 3.0]  # log o exp is the identity for |p_v| < pi
    r = Q.log(Q.exp(p))
    # The scalar part ln|q| is conditioned absolutely (exp rounds |q| to a few eps relative,
    # whatever the size of p), the vector part relatively: the error model of test_log_accuracy.
    s_err = (r[:, 0].double() - p[:, 0].double()).abs() / p[:, 0].double().abs().clamp_min(1.0)
    assert s_err.max() <= 4 * eps(dtype)
    assert rel_err(r[:, 1:], p[:, 1:]).max() <= 16 * eps(dtype)
    # for unit q with w >= 0, 2 log(q) is the rotation vector
    u = Q.canonicalize(haar(100, 9, dtype))
    assert rel_err(2.0 * Q.log(u)[:, 1:], Q.to_rotvec(u)).max() <= 4 * eps(dtype)
    assert (Q.log(u)[:, 0].abs() <= 2 * eps(dtype)).all()


# ----------------------------------------------------------------------------------------------
# slerp
# ----------------------------------------------------------------------------------------------


def test_slerp_endpoints_and_shortest_path(dtype):
    q0, q1 = haar(100, 10, dtype), haar(100, 11, dtype)
    near = torch.where((q0 * q1).sum(-1, keepdim=True) < 0, -q1, q1)
    assert (Q.slerp(q0, q1, 0.0) - q0).abs().max() <= 2 * eps(dtype)
    assert (Q.slerp(q0, q1, 1.0) - near).abs().max() <= 8 * eps(dtype)
    for t in (0.0, 0.3, 1.0, 1.7):
        assert torch.equal(Q.slerp(q0, q1, t), Q.slerp(q0, -q1, t))
    # scale of the inputs does not matter
    assert (Q.slerp(3.0 * q0, 0.2 * q1, 0.4) - Q.slerp(q0, q1, 0.4)).abs().max() <= 8 * eps(dtype)


def test_slerp_matches_scipy_and_textbook():
    q0, q1 = haar(100, 12), haar(100, 13)
    for t in (0.25, 0.5, 0.9):
        ref = [
            Slerp([0.0, 1.0], sp(torch.stack((a, b))))([t]).as_quat(scalar_first=True)[0]
            for a, b in zip(q0, q1, strict=True)
        ]
        assert sign_err(Q.slerp(q0, q1, t), torch.tensor(np.array(ref))).max() <= 16 * eps(F64)
    # sin((1 - t) a)/sin(a) q0 + sin(t a)/sin(a) q1' at well-separated pairs
    q1n = torch.where((q0 * q1).sum(-1, keepdim=True) < 0, -q1, q1)
    a = torch.acos((q0 * q1n).sum(-1, keepdim=True))
    keep = (a > 0.1).squeeze(-1)
    t = 0.3
    ref = (torch.sin((1 - t) * a) * q0 + torch.sin(t * a) * q1n) / torch.sin(a)
    assert (Q.slerp(q0, q1, t)[keep] - ref[keep]).abs().max() <= 1e-13


def test_slerp_nearly_equal(dtype):
    q0 = haar(3, 14, dtype).repeat(5, 1)
    n = generic_axes(15)
    delta = torch.tensor([0.0, 1e-12, 1e-8, 1e-6, 1e-3], dtype=F64).repeat_interleave(3)[:, None]
    q1 = Q.multiply(q0.double(), Q.from_rotvec(delta * n)).to(dtype)
    for t in (0.0, 0.5, 1.0, 2.0):
        out = Q.slerp(q0, q1, t)
        ref = Q.multiply(q0.double(), Q.from_rotvec(t * delta * n))
        assert torch.isfinite(out).all()
        assert (out.double() - ref).abs().max() <= 8 * eps(dtype)
    x0, x1, tt = with_grad(q0), with_grad(q0), with_grad(torch.full((15,), 0.4, dtype=dtype))
    g = torch.autograd.grad(Q.slerp(x0, x1, tt).sum(), (x0, x1, tt))
    assert all(torch.isfinite(gi).all() for gi in g)


def test_slerp_constant_speed_and_t_broadcast(dtype):
    q0, q1 = haar(4, 15, dtype), haar(4, 16, dtype)
    t = torch.linspace(0, 1, 7, dtype=dtype)[:, None]  # (7, 1) against batch (4,)
    out = Q.slerp(q0, q1, t)
    assert out.shape == (7, 4, 4)
    ang = 2 * torch.atan2(
        Q.multiply(Q.conjugate(q0), out)[..., 1:].norm(dim=-1),
        Q.multiply(Q.conjugate(q0), out)[..., 0].abs(),
    )
    torch.testing.assert_close(ang, t * ang[-1:], atol=16 * eps(dtype), rtol=0)
    assert Q.slerp(q0[0], q1[0], torch.tensor([0.1, 0.2], dtype=dtype)).shape == (2, 4)


# ----------------------------------------------------------------------------------------------
# Gradients: gradcheck + gradgradcheck in float64
# ----------------------------------------------------------------------------------------------


def _rot_q(theta: float, scale: float = 1.0) -> torch.Tensor:
    return scale * Q.from_rotvec(theta * generic_axes(3))


@pytest.mark.parametrize("theta", GC_ANGLES)
def test_gradcheck_to_matrix(theta):
    q = with_grad(_rot_q(theta, 1.3))
    assert gradcheck(Q.to_matrix, (q,))
    assert gradgradcheck(Q.to_matrix, (q,))


@pytest.mark.parametrize("theta", GC_ANGLES)
def test_gradcheck_from_matrix(theta):
    R = with_grad(Q.to_matrix(_rot_q(theta)))
    # At pi - 1e-6, w = 5e-7: a finite-difference step of 1e-6 could cross w = 0, where the
    # canonical sign flips (a jump), so the step is 1e-9 there.  Generic axes keep Shepperd's
    # pivot unique (at a tie two formulas, equal only to first order, would be mixed).
    step = 1e-9 if math.pi - theta < 1e-5 else 1e-6
    assert gradcheck(Q.from_matrix, (R,), eps=step)
    assert gradgradcheck(Q.from_matrix, (R,), eps=step)


@pytest.mark.parametrize("theta", GC_ANGLES)
def test_gradcheck_exp_log(theta):
    q = with_grad(_rot_q(theta, 1.7))
    assert gradcheck(Q.log, (q,))
    assert gradgradcheck(Q.log, (q,))
    p = with_grad(
        torch.cat((torch.full((3, 1), 0.3, dtype=F64), 0.5 * theta * generic_axes(3)), -1)
    )
    assert gradcheck(Q.exp, (p,))
    assert gradgradcheck(Q.exp, (p,))


@pytest.mark.parametrize("theta", GC_ANGLES)
def test_gradcheck_apply(theta):
    q = with_grad(_rot_q(theta, 0.8))
    p = with_grad(torch.tensor([[1.0, -2.0, 0.5], [0.3, 0.1, 2.0], [0.0, 0.0, 1.0]], dtype=F64))
    assert gradcheck(Q.apply, (q, p))
    assert gradgradcheck(Q.apply, (q, p))


def test_apply_derivatives_in_forward_and_reverse_mode():
    """apply's own backward and jvp: forward mode against central differences (a tangent on
    either input or both), jacfwd against jacrev, and the plain backward (no graph) against the
    differentiable one, batches broadcast."""
    g = torch.Generator().manual_seed(31)
    q = 1.3 * Q.random(5, generator=g, dtype=F64)
    p = torch.randn(5, 3, generator=g, dtype=F64)
    vmap, jacrev, jacfwd = torch.func.vmap, torch.func.jacrev, torch.func.jacfwd
    for i in (0, 1):
        Jr = vmap(jacrev(Q.apply, argnums=i))(q, p)
        Jf = vmap(jacfwd(Q.apply, argnums=i))(q, p)
        torch.testing.assert_close(Jr, Jf, rtol=0, atol=1e-14)
    tq, tp = (
        torch.randn(q.shape, generator=g, dtype=F64),
        torch.randn(p.shape, generator=g, dtype=F64),
    )
    h = 1e-6
    for dq, dp, qx, px in (
        (tq, None, q, p),
        (None, tp, q, p),
        (tq, tp, q, p),
        (tq[:1], tp, q[:1], p),  # batches broadcast
    ):
        with torch.autograd.forward_ad.dual_level():
            qd = qx if dq is None else torch.autograd.forward_ad.make_dual(qx, dq)
            pd = px if dp is None else torch.autograd.forward_ad.make_dual(px, dp)
            _, dy = torch.autograd.forward_ad.unpack_dual(Q.apply(qd, pd))
        sq = torch.zeros_like(qx) if dq is None else h * dq
        sp = torch.zeros_like(px) if dp is None else h * dp
        fd = (Q.apply(qx + sq, px + sp) - Q.apply(qx - sq, px - sp)) / (2 * h)
        torch.testing.assert_close(dy, fd, rtol=1e-7, atol=1e-8)
    for qs, ps in ((q, p), (q[:1], p), (q[0], p), (q, p[0]), (q[:, None], p)):
        ql, pl = qs.clone().requires_grad_(), ps.clone().requires_grad_()
        y = Q.apply(ql, pl)
        c = torch.randn(y.shape, generator=g, dtype=F64)
        plain = torch.autograd.grad(y, (ql, pl), c)
        graph = torch.autograd.grad(Q.apply(ql, pl), (ql, pl), c, create_graph=True)
        assert plain[0].shape == qs.shape and plain[1].shape == ps.shape
        for a, b in zip(plain, graph, strict=True):
            torch.testing.assert_close(a, b, rtol=1e-13, atol=1e-13)
        # dL/dq is orthogonal to q: apply does not see the scale of q
        assert float((plain[0] * qs).sum(-1).abs().max()) < 1e-12


@pytest.mark.parametrize("theta", GC_ANGLES)
def test_gradcheck_slerp(theta):
    q0 = haar(3, 17)
    q1 = with_grad(Q.multiply(q0, _rot_q(theta)))
    q0 = with_grad(q0)
    t = with_grad(torch.tensor([0.3, 0.7, 1.4], dtype=F64))
    # At pi - 1e-6 the relative rotation has w = dot(q0, q1) = 5e-7: a step of 1e-6 could cross
    # dot = 0, where the shortest path switches to -q1 (a jump), so the step is 1e-9 there.
    step = 1e-9 if math.pi - theta < 1e-5 else 1e-6
    assert gradcheck(Q.slerp, (q0, q1, t), eps=step)
    assert gradgradcheck(Q.slerp, (q0, q1, t), eps=step)


def test_gradcheck_rotvec_and_kinematics():
    w = with_grad(torch.tensor([[1e-8, 0.0, 0.0], [0.3, -0.2, 0.5], [0.0, 3.0, 0.1]], dtype=F64))
    assert gradcheck(Q.from_rotvec, (w,))
    assert gradgradcheck(Q.from_rotvec, (w,))
    q = with_grad(_rot_q(1.0))
    assert gradcheck(Q.to_rotvec, (q,))
    dt = with_grad(torch.tensor([0.1, 1e-9, 2.0], dtype=F64))
    assert gradcheck(Q.integrate, (q, w, dt, "body"))
    assert gradcheck(Q.integrate, (q, w, dt, "world"))
    assert gradgradcheck(Q.integrate, (q, w, dt, "world"))
    assert gradcheck(Q.derivative, (q, w, "body"))
    assert gradcheck(Q.derivative, (q, w, "world"))


def test_log_gradient_is_scale_invariant():
    q = with_grad(_rot_q(1.0))
    (g,) = torch.autograd.grad(Q.log(q)[:, 1:].sum(), q)
    # the vector part does not change along q: its gradient is orthogonal to q
    assert ((g * q).sum(-1).abs() <= 8 * eps(F64)).all()


# ----------------------------------------------------------------------------------------------
# Kinematics: derivative and integrate
# ----------------------------------------------------------------------------------------------


def _rk4(q, omega, T, frame, n=400):
    h = T / n
    f = lambda x: Q.derivative(x, omega, frame)  # noqa: E731
    for _ in range(n):
        k1 = f(q)
        k2 = f(q + 0.5 * h * k1)
        k3 = f(q + 0.5 * h * k2)
        k4 = f(q + h * k3)
        q = q + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return q


@pytest.mark.parametrize("frame", ["body", "world"])
def test_integrate_matches_rk4(frame):
    q = haar(4, 18) * torch.tensor([[1.0], [2.0], [0.5], [1.0]], dtype=F64)
    omega = torch.tensor(
        [[0.3, -1.0, 2.0], [0.0, 0.0, 0.0], [1e-9, 0.0, 0.0], [0.0, 4.0, 0.0]], dtype=F64
    )
    T = 0.5
    ref = _rk4(q, omega, T, frame)
    # RK4 global error ~ (|omega| T)^5 / (120 n^4) ~ 1e-11 here (|omega| T <= 2, n = 400)
    assert (Q.integrate(q, omega, T, frame) - ref).abs().max() <= 1e-10


def test_integrate_closed_form_and_frames(dtype):
    q = haar(6, 19, dtype)
    w = torch.randn(6, 3, generator=torch.Generator().manual_seed(1), dtype=F64).to(dtype)
    dt = torch.linspace(-1.0, 2.0, 6, dtype=dtype)
    e = Q.from_rotvec(dt[:, None] * w)
    assert torch.equal(Q.integrate(q, w, dt, "body"), Q.multiply(q, e))
    assert torch.equal(Q.integrate(q, w, dt, "world"), Q.multiply(e, q))
    # a constant body rate w is the constant world rate R(q0) w
    wb = Q.integrate(q, w, dt, "body")
    ww = Q.integrate(q, Q.apply(q, w), dt, "world")
    assert (wb - ww).abs().max() <= 16 * eps(dtype) * (
        1 + (dt[:, None] * w).norm(dim=-1, keepdim=True)
    ).max()
    # the norm is preserved (not imposed): 2q stays 2q in norm
    assert ((Q.integrate(2 * q, w, dt).norm(dim=-1) - 2).abs() <= 16 * eps(dtype)).all()
    # dt broadcasting
    assert Q.integrate(q, w, torch.ones(3, 1, dtype=dtype)).shape == (3, 6, 4)
    assert Q.integrate(q[0], w, 0.1).shape == (6, 4)
    # integrate over 0 is the identity map, exactly
    assert torch.equal(Q.integrate(q, w, 0.0), q)


@pytest.mark.parametrize("frame", ["body", "world"])
def test_derivative_matches_integrate(frame):
    q = haar(5, 20) * 1.5
    w = torch.randn(5, 3, generator=torch.Generator().manual_seed(2), dtype=F64)
    h = 1e-5
    fd = (Q.integrate(q, w, h, frame) - Q.integrate(q, w, -h, frame)) / (2 * h)
    d = Q.derivative(q, w, frame)
    assert (fd - d).abs().max() <= 1e-9
    # exactly through autograd at dt = 0
    dt = with_grad(torch.zeros(5, dtype=F64))
    qs = Q.integrate(q, w, dt, frame)
    jac = torch.stack(
        [torch.autograd.grad(qs[:, i].sum(), dt, retain_graph=True)[0] for i in range(4)], -1
    )
    assert (jac - d).abs().max() <= 4 * eps(F64)
    # literal: body frame q_dot = 1/2 q * [0, w]
    ref = 0.5 * Q.multiply(q, torch.cat((torch.zeros(5, 1, dtype=F64), w), -1))
    if frame == "body":
        assert torch.equal(d, ref)


def test_kinematics_bad_frame():
    q, w = Q.identity(), torch.zeros(3)
    for f in (lambda: Q.derivative(q, w, "inertial"), lambda: Q.integrate(q, w, 0.1, "Body")):
        with pytest.raises(ValueError, match="frame"):
            f()


# ----------------------------------------------------------------------------------------------
# Construction and validation
# ----------------------------------------------------------------------------------------------


def test_identity():
    assert torch.equal(Q.identity(), torch.tensor([1.0, 0.0, 0.0, 0.0]))
    e = Q.identity(2, 3, dtype=F64)
    assert e.shape == (2, 3, 4) and e.dtype == F64
    e[0, 0, 0] = 5.0  # a fresh tensor, not an expanded view
    assert e[1, 1, 0] == 1.0
    q = haar(5)
    assert torch.equal(Q.multiply(q, Q.identity(dtype=F64)), q)


def test_random_haar(dtype):
    g = torch.Generator().manual_seed(5)
    q = Q.random(20000, generator=g, dtype=dtype)
    assert q.shape == (20000, 4) and q.dtype == dtype
    assert Q.is_unit(q).all()
    # same generator state: same rotation as so3.random
    R = so3.random(7, generator=torch.Generator().manual_seed(9), dtype=dtype)
    q7 = Q.random(7, generator=torch.Generator().manual_seed(9), dtype=dtype)
    assert (Q.to_matrix(q7) - R).abs().max() <= 4 * eps(dtype)
    # uniform on S^3: E[q_i^2] = 1/4 (sd of the mean 0.25/sqrt(n)), and the rotation angle has
    # the Haar CDF (t - sin t)/pi (sd of the empirical CDF <= 0.5/sqrt(n)); bounds are 5 sd
    n = q.shape[0]
    assert ((q.double() ** 2).mean(0) - 0.25).abs().max() <= 5 * 0.25 / math.sqrt(n)
    theta = Q.to_rotvec(q).double().norm(dim=-1)
    for x in (0.5, 1.5, 2.5):
        assert abs(
            (theta <= x).double().mean() - (x - math.sin(x)) / math.pi
        ) <= 5 * 0.5 / math.sqrt(n)
    assert (q[:, 0] < 0).any()  # not canonicalised
    assert Q.random(2, 3).shape == (2, 3, 4)
    for low in LOW:
        assert Q.random(3, dtype=low).dtype == low


def test_is_unit(dtype):
    q = torch.tensor(
        [
            [1.0, 0.0, 0.0, 0.0],
            [0.5, 0.5, 0.5, 0.5],
            [1.0, 1.0, 0.0, 0.0],
            [math.nan, 0, 0, 0],
            [math.inf, 0, 0, 0],
            [0, 0, 0, 0],
        ],
        dtype=dtype,
    )
    assert Q.is_unit(q).tolist() == [True, True, False, False, False, False]
    tol = 100 * eps(dtype)
    near = torch.tensor([[1.0 + 0.5 * tol, 0, 0, 0], [1.0 + 2 * tol, 0, 0, 0]], dtype=dtype)
    assert Q.is_unit(near).tolist() == [True, False]
    assert Q.is_unit(near, atol=4 * tol).tolist() == [True, True]
    assert Q.is_unit(torch.zeros(2, 3, 4)).shape == (2, 3)
    for low in LOW:
        assert Q.is_unit(haar(50, 21).to(low)).all()


# ----------------------------------------------------------------------------------------------
# Other layouts: xyzw, JPL, left/right matrices, SU(2)
# ----------------------------------------------------------------------------------------------


def test_xyzw_matches_scipy_order(dtype):
    q = haar(50, 22, dtype)
    xyzw = Q.to_xyzw(q)
    assert np.allclose(
        Rotation.from_quat(xyzw.double().numpy()).as_matrix(),
        Q.to_matrix(q).double().numpy(),
        rtol=0,
        atol=8 * eps(dtype),
    )
    assert torch.equal(xyzw, q[:, [1, 2, 3, 0]])
    assert torch.equal(Q.from_xyzw(xyzw), q)


def _jpl_matrix(qj: torch.Tensor) -> torch.Tensor:
    """C(q) = (2 q4^2 - 1) I - 2 q4 [q]x + 2 q q^T (Trawny & Roumeliotis 2005, eq. 78)."""
    v, q4 = qj[..., :3], qj[..., 3:]
    eye = torch.eye(3, dtype=qj.dtype)
    return (
        (2 * q4[..., None] ** 2 - 1) * eye
        - 2 * q4[..., None] * so3.hat(v)
        + 2 * v[..., :, None] * v[..., None, :]
    )


def _jpl_multiply(p: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
    """JPL product: [p4 q + q4 p - p x q, p4 q4 - p . q] (i j = -k)."""
    pv, p4, qv, q4 = p[..., :3], p[..., 3:], q[..., :3], q[..., 3:]
    v = p4 * qv + q4 * pv - torch.linalg.cross(pv, qv)
    return torch.cat((v, p4 * q4 - (pv * qv).sum(-1, keepdim=True)), -1)


def test_jpl_preserves_rotation_matrix_and_products(dtype):
    q1, q2 = haar(50, 23, dtype), haar(50, 24, dtype)
    j1, j2 = Q.to_jpl(q1), Q.to_jpl(q2)
    assert (_jpl_matrix(j1) - Q.to_matrix(q1)).abs().max() <= 8 * eps(dtype)
    assert (Q.to_jpl(Q.multiply(q1, q2)) - _jpl_multiply(j1, j2)).abs().max() <= 8 * eps(dtype)
    assert (
        _jpl_matrix(_jpl_multiply(j1, j2)) - _jpl_matrix(j1) @ _jpl_matrix(j2)
    ).abs().max() <= 16 * eps(dtype)
    assert torch.equal(Q.from_jpl(j1), q1)
    # literal: pi/2 about z.  Hamilton (c, 0, 0, s) is JPL (0, 0, -s, c); JPL's own matrix of
    # (0, 0, s, c) is the transpose (it maps world coordinates into the rotated frame).
    c = math.sqrt(0.5)
    qz = torch.tensor([c, 0.0, 0.0, c], dtype=dtype)
    assert torch.equal(Q.to_jpl(qz), torch.tensor([-0.0, -0.0, -c, c], dtype=dtype))
    Rz = torch.tensor([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], dtype=dtype)
    assert (_jpl_matrix(Q.to_xyzw(qz)) - Rz.T).abs().max() <= 4 * eps(dtype)


def test_left_right_matrices(dtype):
    q, p = haar(30, 25, dtype) * 1.5, haar(30, 26, dtype)
    qp = Q.multiply(q, p)
    assert (Q.left_matrix(q) @ p[..., None] - qp[..., None]).abs().max() <= 4 * eps(dtype)
    assert (Q.right_matrix(p) @ q[..., None] - qp[..., None]).abs().max() <= 4 * eps(dtype)
    assert torch.equal(Q.left_matrix(Q.conjugate(q)), Q.left_matrix(q).mT)
    # left and right multiplications commute: [q]_L [p]_R = [p]_R [q]_L
    assert (
        Q.left_matrix(q) @ Q.right_matrix(p) - Q.right_matrix(p) @ Q.left_matrix(q)
    ).abs().max() <= 8 * eps(dtype)
    # |q| times an orthogonal matrix
    eye = torch.eye(4, dtype=dtype)
    assert (Q.left_matrix(p).mT @ Q.left_matrix(p) - eye).abs().max() <= 8 * eps(dtype)


PAULI = torch.tensor(
    [[[0, 1], [1, 0]], [[0, -1j], [1j, 0]], [[1, 0], [0, -1]]], dtype=torch.complex128
)


def test_su2_homomorphism_and_meaning(dtype):
    cdtype = {torch.float32: torch.complex64, torch.float64: torch.complex128}[dtype]
    q1, q2 = haar(50, 27, dtype), haar(50, 28, dtype)
    U1, U2 = Q.to_su2(q1), Q.to_su2(q2)
    assert U1.dtype == cdtype and U1.shape == (50, 2, 2)
    assert (Q.to_su2(Q.multiply(q1, q2)) - U1 @ U2).abs().max() <= 8 * eps(dtype)
    eye = torch.eye(2, dtype=cdtype)
    assert (U1 @ U1.mH - eye).abs().max() <= 8 * eps(dtype)
    assert (torch.linalg.det(U1) - 1).abs().max() <= 8 * eps(dtype)
    assert (Q.to_su2(Q.conjugate(q1)) - U1.mH).abs().max() == 0
    # literal images of 1, i, j, k: I, -i sx, -i sy, -i sz
    basis = torch.eye(4, dtype=F64)
    expected = torch.cat((torch.eye(2, dtype=torch.complex128)[None], -1j * PAULI))
    assert torch.equal(Q.to_su2(basis), expected)
    # U (p.s) U^H == (R p).s, and U = exp(-i t/2 n.s)
    p = torch.randn(50, 3, generator=torch.Generator().manual_seed(3), dtype=F64)
    Ud = U1.to(torch.complex128)
    ps = torch.einsum("bi,ijk->bjk", p.to(torch.complex128), PAULI)
    Rp = torch.einsum("bi,ijk->bjk", Q.apply(q1.double(), p).to(torch.complex128), PAULI)
    assert (Ud @ ps @ Ud.mH - Rp).abs().max() <= 16 * eps(dtype) * p.norm(dim=-1).max()
    w = Q.to_rotvec(q1.double())
    gen = torch.einsum("bi,ijk->bjk", (-0.5j * w).to(torch.complex128), PAULI)
    assert (
        torch.linalg.matrix_exp(gen) - Q.to_su2(Q.canonicalize(q1)).to(torch.complex128)
    ).abs().max() <= 16 * eps(dtype)
    # inverse
    back = Q.from_su2(U1)
    assert back.dtype == dtype and torch.equal(back, q1)


def test_from_su2_errors_and_dtypes():
    with pytest.raises(TypeError, match="torchlie.quaternion.from_su2"):
        Q.from_su2(torch.eye(2))
    with pytest.raises(TypeError, match="torchlie.quaternion.from_su2"):
        Q.from_su2(torch.eye(2, dtype=torch.int64))
    with pytest.raises(TypeError, match="torchlie.quaternion.from_su2"):
        Q.from_su2([[1, 0], [0, 1]])
    with pytest.raises(ValueError, match=r"torchlie.quaternion.from_su2.*\(3, 3\)"):
        Q.from_su2(torch.eye(3, dtype=torch.complex64))
    with pytest.raises(ValueError, match=r"\(2,\)"):
        Q.from_su2(torch.ones(2, dtype=torch.complex64))
    assert Q.from_su2(torch.eye(2, dtype=torch.complex128)).dtype == F64
    assert Q.to_su2(torch.tensor([1.0, 0, 0, 0], dtype=torch.float16)).dtype == torch.complex64
    # projection: the nearest to_su2 image of a perturbed matrix
    U = Q.to_su2(haar(10, 29))
    E = torch.randn(10, 2, 2, dtype=torch.complex128, generator=torch.Generator().manual_seed(0))
    q = Q.from_su2(U + 1e-3 * E)
    d = with_grad(q)
    loss = (Q.to_su2(d) - (U + 1e-3 * E)).abs().pow(2).sum()
    (g,) = torch.autograd.grad(loss, d)
    assert g.abs().max() <= 1e-12  # stationary: least squares optimum


# ----------------------------------------------------------------------------------------------
# Batching, dtypes, bad input
# ----------------------------------------------------------------------------------------------

# name -> (function of one input, input trailing shape, output trailing shape)
UNARY = {
    "conjugate": (Q.conjugate, (4,), (4,)),
    "inverse": (Q.inverse, (4,), (4,)),
    "normalize": (Q.normalize, (4,), (4,)),
    "canonicalize": (Q.canonicalize, (4,), (4,)),
    "exp": (Q.exp, (4,), (4,)),
    "log": (Q.log, (4,), (4,)),
    "to_matrix": (Q.to_matrix, (4,), (3, 3)),
    "to_rotvec": (Q.to_rotvec, (4,), (3,)),
    "from_rotvec": (Q.from_rotvec, (3,), (4,)),
    "from_matrix": (lambda R: Q.from_matrix(R), (3, 3), (4,)),
    "to_xyzw": (Q.to_xyzw, (4,), (4,)),
    "from_xyzw": (Q.from_xyzw, (4,), (4,)),
    "to_jpl": (Q.to_jpl, (4,), (4,)),
    "from_jpl": (Q.from_jpl, (4,), (4,)),
    "left_matrix": (Q.left_matrix, (4,), (4, 4)),
    "right_matrix": (Q.right_matrix, (4,), (4, 4)),
    "is_unit": (Q.is_unit, (4,), ()),
    "to_su2": (Q.to_su2, (4,), (2, 2)),
}

# name -> (function, trailing shapes of the tensor inputs, output trailing shape)
BINARY = {
    "multiply": (Q.multiply, [(4,), (4,)], (4,)),
    "apply": (Q.apply, [(4,), (3,)], (3,)),
    "slerp": (lambda a, b: Q.slerp(a, b, 0.3), [(4,), (4,)], (4,)),
    "derivative": (Q.derivative, [(4,), (3,)], (4,)),
    "integrate": (lambda a, b: Q.integrate(a, b, 0.3), [(4,), (3,)], (4,)),
}


def _inputs(trailing, batch, dtype=F64, seed=0):
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(*batch, *trailing, generator=g, dtype=F64)
    if trailing == (3, 3):
        x = Q.to_matrix(torch.randn(*batch, 4, generator=g, dtype=F64))
    return x.to(dtype)


@pytest.mark.parametrize("name", list(UNARY))
def test_unary_batch_shapes(name, batch, dtype):
    f, tin, tout = UNARY[name]
    x = _inputs(tin, batch, dtype)
    y = f(x)
    assert y.shape == (*batch, *tout)
    if batch:  # batched result agrees with the element-wise results
        flat = x.reshape(-1, *tin)
        each = torch.stack([f(e) for e in flat]).reshape(y.shape)
        assert_agree(y, each, name, batch_dims=len(batch))


@pytest.mark.parametrize("name", list(BINARY))
def test_binary_broadcasting(name, dtype):
    f, (ta, tb), tout = BINARY[name]
    a, b = _inputs(ta, (2, 1), dtype, 1), _inputs(tb, (3,), dtype, 2)
    y = f(a, b)
    assert y.shape == (2, 3, *tout)
    each = torch.stack([torch.stack([f(a[i, 0], b[j]) for j in range(3)]) for i in range(2)])
    assert (y - each).abs().max() <= 2 * eps(dtype)
    assert f(a[0, 0], b[0]).shape == tout
    with pytest.raises(ValueError, match=f"torchlie.quaternion.{name}: batch shapes"):
        f(_inputs(ta, (2,), dtype), _inputs(tb, (3,), dtype))


@pytest.mark.parametrize("low", LOW, ids=["f16", "bf16"])
@pytest.mark.parametrize("name", list(UNARY) + list(BINARY))
def test_half_precision(name, low):
    if name in UNARY:
        f, tins, _ = UNARY[name][0], [UNARY[name][1]], None
    else:
        f, tins, _ = BINARY[name]
    xs = [_inputs(t, (5,), F64, i).to(low) for i, t in enumerate(tins)]
    y = f(*xs)
    ref = f(*(x.float() for x in xs))  # half is computed in float32 and cast back
    if name == "is_unit":
        assert torch.equal(y, ref)
    elif name == "to_su2":
        assert y.dtype == torch.complex64 and torch.equal(y, ref)
    else:
        assert y.dtype == low
        assert torch.equal(y, ref.to(low))


@pytest.mark.parametrize("name", list(UNARY) + list(BINARY))
def test_bad_input(name):
    if name in UNARY:
        f, tins = UNARY[name][0], [UNARY[name][1]]
    else:
        f, tins, _ = BINARY[name]
    good = [_inputs(t, (2,)) for t in tins]
    for k, t in enumerate(tins):
        wrong = list(good)
        bad_shape = (2, 5) if len(t) == 1 else (2, 3, 2)
        wrong[k] = torch.zeros(bad_shape, dtype=F64)
        with pytest.raises(
            ValueError, match=rf"torchlie\.quaternion\.\w+: expected .*{re_shape(bad_shape)}"
        ):
            f(*wrong)
        wrong[k] = good[k].to(torch.int64)
        with pytest.raises(TypeError, match=r"torchlie\.quaternion\.\w+"):
            f(*wrong)
    if len(tins) == 2:
        with pytest.raises(TypeError, match="one dtype"):
            f(good[0], good[1].float())


def re_shape(shape) -> str:
    return r"\(" + r", ".join(str(s) for s in shape) + r"\)"


def test_bad_t_and_dt():
    q = haar(2)
    with pytest.raises(TypeError, match="torchlie.quaternion.slerp"):
        Q.slerp(q, q, torch.tensor([1, 2]))
    with pytest.raises(TypeError, match="torchlie.quaternion.integrate"):
        Q.integrate(q, torch.zeros(2, 3, dtype=F64), "0.1")
    with pytest.raises(ValueError, match="torchlie.quaternion.slerp: batch shapes"):
        Q.slerp(q, q, torch.zeros(3, dtype=F64))
    with pytest.raises(
        ValueError,
        match=r"torchlie.quaternion.from_matrix: expected R of shape "
        r"\(\.\.\., 3, 3\), got \(3, 4\)",
    ):
        Q.from_matrix(torch.zeros(3, 4))


# ----------------------------------------------------------------------------------------------
# NaN isolation and the zero quaternion
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(UNARY) + list(BINARY))
def test_nan_stays_in_its_element(name):
    if name in UNARY:
        f, tins = UNARY[name][0], [UNARY[name][1]]
    else:
        f, tins, _ = BINARY[name]
    xs = [_inputs(t, (3,), F64, i) for i, t in enumerate(tins)]
    clean = f(*xs)
    for k in range(len(xs)):
        poisoned = [x.clone() for x in xs]
        poisoned[k][1] = math.nan
        y = f(*poisoned)
        assert torch.equal(y[0], clean[0]) and torch.equal(y[2], clean[2])
        if name == "is_unit":
            assert not y[1]
        else:
            assert torch.isnan(y[1]).all()


def test_zero_quaternion_gives_nan_in_its_element_only():
    q = haar(3, 30)
    q0 = q.clone()
    q0[1] = 0.0
    p = torch.ones(3, 3, dtype=F64)
    fns = {
        "normalize": Q.normalize,
        "inverse": Q.inverse,
        "to_matrix": Q.to_matrix,
        "to_rotvec": Q.to_rotvec,
        "log": Q.log,
        "apply": lambda x: Q.apply(x, p),
        "slerp_q0": lambda x: Q.slerp(x, q, 0.4),
        "slerp_q1": lambda x: Q.slerp(q, x, 0.4),
    }
    for name, f in fns.items():
        ref, y = f(q), f(q0)
        assert torch.isnan(y[1]).all(), name
        assert torch.equal(y[[0, 2]], ref[[0, 2]]), name
    assert not Q.is_unit(q0)[1]


# ----------------------------------------------------------------------------------------------
# torch.func, devices, torch.compile
# ----------------------------------------------------------------------------------------------


def test_vmap():
    q0, q1 = haar(6, 31), haar(6, 32)
    p = torch.randn(6, 3, dtype=F64, generator=torch.Generator().manual_seed(4))
    t = torch.linspace(0, 1, 6, dtype=F64)
    vm = torch.func.vmap
    assert torch.equal(vm(Q.apply)(q0, p), Q.apply(q0, p))
    assert (vm(Q.slerp)(q0, q1, t) - Q.slerp(q0, q1, t)).abs().max() <= 2 * eps(F64)
    assert (
        vm(Q.slerp, in_dims=(0, 0, None))(q0, q1, 0.3) - Q.slerp(q0, q1, 0.3)
    ).abs().max() <= 2 * eps(F64)
    assert torch.equal(vm(Q.log)(q0), Q.log(q0))
    assert torch.equal(vm(Q.from_matrix)(Q.to_matrix(q0)), Q.from_matrix(Q.to_matrix(q0)))
    assert torch.equal(
        vm(lambda a, b: Q.integrate(a, b, 0.2, "world"))(q0, p), Q.integrate(q0, p, 0.2, "world")
    )
    assert torch.equal(vm(Q.to_su2)(q0), Q.to_su2(q0))


def test_jacrev():
    q = _rot_q(1.0)[0]
    jf = torch.func.jacrev
    for f in (
        Q.log,
        Q.exp,
        Q.to_matrix,
        Q.to_rotvec,
        lambda x: Q.slerp(Q.identity(dtype=F64), x, 0.3),
    ):
        J = jf(f)(q)
        ref = torch.autograd.functional.jacobian(f, q)
        assert (J - ref).abs().max() <= 4 * eps(F64)
    # jacobian of to_rotvec at the identity: 2 [0 | I] (first order of 2 v / w)
    J = jf(Q.to_rotvec)(Q.identity(dtype=F64))
    assert torch.equal(
        J, torch.cat((torch.zeros(3, 1, dtype=F64), 2 * torch.eye(3, dtype=F64)), -1)
    )
    # forward mode agrees with reverse mode
    Jf = torch.func.jacfwd(Q.log)(q)
    assert (Jf - jf(Q.log)(q)).abs().max() <= 4 * eps(F64)


def test_device(device):
    q0, q1 = haar(5, 33), haar(5, 34)
    p = torch.ones(5, 3, dtype=F64)
    cpu = [
        Q.slerp(q0, q1, 0.3),
        Q.apply(q0, p),
        Q.log(q0),
        Q.from_matrix(Q.to_matrix(q0)),
        Q.integrate(q0, p, 0.1),
    ]
    d = [x.to(device) for x in (q0, q1, p)]
    dev = [
        Q.slerp(d[0], d[1], 0.3),
        Q.apply(d[0], d[2]),
        Q.log(d[0]),
        Q.from_matrix(Q.to_matrix(d[0])),
        Q.integrate(d[0], d[2], 0.1),
    ]
    for a, b in zip(cpu, dev, strict=True):
        assert b.device.type == torch.device(device).type
        assert (a - b.cpu()).abs().max() <= 8 * eps(F64)
    assert Q.identity(2, device=device).device.type == torch.device(device).type
    assert Q.random(2, device=device).device.type == torch.device(device).type


@pytest.mark.compile
def test_compile_fullgraph():
    def f(q0, q1, p, w, t):
        s = Q.slerp(q0, q1, t)
        r = Q.apply(s, p)
        e = Q.exp(Q.log(q0))
        i = Q.integrate(Q.inverse(q0), w, t, "world")
        d = Q.derivative(q1, w)
        m = Q.left_matrix(q1) @ Q.to_jpl(q0)[..., None]
        return r, e + i + d + m[..., 0], Q.is_unit(s)

    q0, q1 = haar(8, 35), haar(8, 36)
    q1[0] = q0[0]  # nearly equal / equal inputs go through the same graph
    p = torch.randn(8, 3, dtype=F64, generator=torch.Generator().manual_seed(6))
    w = torch.randn(8, 3, dtype=F64, generator=torch.Generator().manual_seed(7))
    t = torch.linspace(0, 1, 8, dtype=F64)
    cf = torch.compile(f, fullgraph=True, backend="aot_eager")  # see tests/test_compile.py
    for a, b in zip(cf(q0, q1, p, w, t), f(q0, q1, p, w, t), strict=True):
        if a.dtype == torch.bool:
            assert torch.equal(a, b)
        else:
            assert (a - b).abs().max() <= 8 * eps(F64)
