"""Every finite input, from the smallest to the largest magnitude, gives a finite, right result.

Quaternions, rotation vectors and twists are swept over magnitudes from ``1e-45`` (float32) or
``1e-300`` (float64) to ``torch.finfo(dtype).max``:

* functions invariant to the scale of a quaternion give the result of a moderate scale;
* functions homogeneous in it give that result scaled;
* exponential maps give valid rotations (orthonormal, about the axis of the rotation vector);
  beyond about ``1 / eps`` the angle is known only to more than ``2 pi`` (its rounding), and
  is reduced modulo ``2 pi`` (:func:`torchlie._coeffs.reduction`);
* gradients are finite (where the true gradient is representable).

Not swept: the inverse Jacobians (meant for angles below ``2 pi``).
"""

from __future__ import annotations

import math

import pytest
import torch

from torchlie import _coeffs, conversions, nn, quaternion, se3, sim3, so3, statistics

DTYPES = [torch.float32, torch.float64]


def _magnitudes(dtype: torch.dtype) -> torch.Tensor:
    fi = torch.finfo(dtype)
    low = -45 if dtype == torch.float32 else -300
    exps = list(range(low, int(math.log10(fi.max)) + 1, 5))
    extra = [1.0, math.pi, 2.0**59, 2.0**61, 2.0**499, 2.0**501, fi.tiny, fi.max / 2, fi.max]
    values = [10.0**e for e in exps] + [x for x in extra if x <= fi.max]
    return torch.tensor(sorted(set(values)), dtype=torch.float64).to(dtype)


def _directions(n: int, dtype: torch.dtype, seed: int = 0) -> torch.Tensor:
    """``(d, n)`` directions with largest component 1 (so any scale up to ``max`` is finite)."""
    g = torch.Generator().manual_seed(seed)
    d = torch.cat((torch.randn(4, n, generator=g, dtype=torch.float64), torch.eye(n)[:2]))
    return (d / d.abs().amax(-1, keepdim=True)).to(dtype)


def _sweep(
    n: int, dtype: torch.dtype, seed: int = 0, top: float = 1.0
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(s, x)``: every magnitude up to ``top * max`` times every direction, flattened;
    ``x = s * u``."""
    s = _magnitudes(dtype)
    s = s[s <= top * torch.finfo(dtype).max]
    u = _directions(n, dtype, seed)
    s, u = torch.broadcast_tensors(s[:, None, None], u[None])
    return s[..., 0].reshape(-1), (s * u).reshape(-1, n)


def _unit_of(x: torch.Tensor) -> torch.Tensor:
    """``x / |x|`` computed in float64 from a prescaled copy (the test's own reference)."""
    y = x.double() / x.double().abs().amax(-1, keepdim=True)
    return y / y.norm(dim=-1, keepdim=True)


def _norm_of(x: torch.Tensor) -> torch.Tensor:
    """``|x|`` ``(..., 1)`` in float64 from a prescaled copy."""
    m = x.double().abs().amax(-1, keepdim=True)
    return m * (x.double() / m).norm(dim=-1, keepdim=True)


def _tol(dtype: torch.dtype) -> float:
    return 16 * torch.finfo(dtype).eps


# ----------------------------------------------------------------------------------------------
# Quaternion functions invariant to the scale of q
# ----------------------------------------------------------------------------------------------

_P = torch.tensor([0.3, -1.2, 2.0])
INVARIANT = {
    "to_matrix": quaternion.to_matrix,
    "to_rotvec": quaternion.to_rotvec,
    "normalize": quaternion.normalize,
    "apply": lambda q: quaternion.apply(q, _P.to(q.dtype)),
    "slerp": lambda q: quaternion.slerp(q, q.flip(-1) * torch.tensor([1.0, -1.0, 1.0, 1.0]).to(
        q.dtype), 0.3),
    "log_vector": lambda q: quaternion.log(q)[..., 1:],
    "quaternion_to_euler": lambda q: conversions.quaternion_to_euler(q, "ZYX"),
    "from_pos_quat": lambda q: se3.from_pos_quat(torch.cat((torch.ones_like(q[..., :3]), q), -1)),
    "representation_quaternion": lambda q: nn.representation_to_matrix(q, "quaternion"),
}  # fmt: skip


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
@pytest.mark.parametrize("name", list(INVARIANT))
def test_scale_invariant_quaternion_functions(name, dtype):
    fn = INVARIANT[name]
    s, q = _sweep(4, dtype)
    want = fn(_unit_of(q).to(dtype))
    got = fn(q)
    assert torch.isfinite(got).all(), (name, s[~torch.isfinite(got).flatten(1).all(-1)])
    torch.testing.assert_close(got, want, rtol=0, atol=_tol(dtype) * 4)


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
@pytest.mark.parametrize("name", ["to_matrix", "to_rotvec", "normalize", "apply", "log_vector"])
def test_scale_invariant_gradients(name, dtype):
    """``d f(s q) / dq = (d f / dq)(q) / s``: finite wherever ``1 / s`` is."""
    fn = INVARIANT[name]
    s, q = _sweep(4, dtype)
    keep = s > 64.0 / torch.finfo(dtype).max
    s, q = s[keep], q[keep].clone().requires_grad_()
    out = fn(q)
    c = torch.randn(out.shape, generator=torch.Generator().manual_seed(1), dtype=dtype)
    (grad,) = torch.autograd.grad(out, q, c)
    assert torch.isfinite(grad).all(), s[~torch.isfinite(grad).all(-1)]
    u = _unit_of(q.detach()).to(dtype).requires_grad_()
    (ref,) = torch.autograd.grad(fn(u), u, c)
    m = q.detach().double().abs().amax(-1, keepdim=True)
    scaled = grad.double() * m * (q.detach().double() / m).norm(dim=-1, keepdim=True)
    torch.testing.assert_close(scaled, ref.double(), rtol=0, atol=_tol(dtype) * 8)


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
def test_inverse_and_log_norm(dtype):
    s, q = _sweep(4, dtype, top=0.25)  # |q| up to twice the largest component
    u = _unit_of(q)
    n = _norm_of(q)
    ok = s > 4.0 / torch.finfo(dtype).max  # 1/|q| representable
    inv = quaternion.inverse(q[ok])
    assert torch.isfinite(inv).all()
    want = u[ok] * torch.tensor([1.0, -1.0, -1.0, -1.0], dtype=torch.float64)
    torch.testing.assert_close(inv.double() * n[ok], want, rtol=0, atol=_tol(dtype) * 4)
    log_norm = quaternion.log(q)[..., 0]
    assert torch.isfinite(log_norm).all()
    ref = q.double().abs().amax(-1).log() + (q.double() / q.double().abs().amax(-1, keepdim=True)
                                             ).norm(dim=-1).log()  # fmt: skip
    torch.testing.assert_close(log_norm.double(), ref, rtol=_tol(dtype), atol=_tol(dtype))


HOMOGENEOUS = {
    "multiply_left": lambda q: quaternion.multiply(q, _Q.to(q.dtype)),
    "multiply_right": lambda q: quaternion.multiply(_Q.to(q.dtype), q),
    "conjugate": quaternion.conjugate,
    "canonicalize": quaternion.canonicalize,
    "to_xyzw": quaternion.to_xyzw,
    "to_jpl": quaternion.to_jpl,
    "left_matrix": quaternion.left_matrix,
    "right_matrix": quaternion.right_matrix,
    "derivative": lambda q: quaternion.derivative(q, _P.to(q.dtype)),
    "integrate": lambda q: quaternion.integrate(q, _P.to(q.dtype), 0.7),
}
_Q = torch.tensor([0.5, -0.5, 0.5, 0.5])


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
@pytest.mark.parametrize("name", list(HOMOGENEOUS))
def test_homogeneous_quaternion_functions(name, dtype):
    """``f(s q) = s f(q)`` for unit ``q``: finite up to the largest ``s``."""
    fn = HOMOGENEOUS[name]
    s, q = _sweep(4, dtype, top=0.25)  # results up to |q|, twice the largest component
    u = _unit_of(q)
    got = fn(q)
    assert torch.isfinite(got).all()
    n = _norm_of(q).view((-1,) + (1,) * (got.dim() - 1))
    tiny = torch.finfo(dtype).tiny  # results below it are subnormal: absolute error up to it
    err = (got.double() / n - fn(u)).abs()
    assert (err <= _tol(dtype) + tiny / n).all(), err.max()


# ----------------------------------------------------------------------------------------------
# Rotation vectors and twists
# ----------------------------------------------------------------------------------------------


def _assert_rotation(R: torch.Tensor, axis: torch.Tensor, dtype: torch.dtype) -> None:
    """Orthonormal with determinant 1, and ``R axis = axis``."""
    assert torch.isfinite(R).all()
    R = R.double()
    eye = torch.eye(3, dtype=torch.float64)
    tol = _tol(dtype)
    assert (R.mT @ R - eye).abs().amax() <= tol
    assert (torch.linalg.det(R) - 1.0).abs().amax() <= tol
    assert (R @ axis.unsqueeze(-1) - axis.unsqueeze(-1)).abs().amax() <= tol


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
def test_rotation_vector_exp_maps(dtype):
    s, w = _sweep(3, dtype)
    axis = _unit_of(w)
    for R in (
        so3.exp(w),
        quaternion.to_matrix(quaternion.from_rotvec(w)),
        quaternion.to_matrix(quaternion.exp(torch.cat((torch.zeros_like(w[:, :1]), w), -1))),
        conversions.axis_angle_to_matrix(w, 1.0),
        conversions.axis_angle_to_matrix(axis.to(dtype), s),
        nn.representation_to_matrix(w, "rotvec"),
        so3.rplus(so3.identity(dtype=dtype), w),
        so3.lplus(so3.identity(dtype=dtype), w),
        se3.exp(torch.cat((torch.ones_like(w), w), -1))[..., :3, :3],
        se3.rplus(se3.identity(dtype=dtype), torch.cat((torch.ones_like(w), w), -1))[..., :3, :3],
        se3.lplus(se3.identity(dtype=dtype), torch.cat((torch.ones_like(w), w), -1))[..., :3, :3],
        statistics.so3_integrate(so3.identity(dtype=dtype), w, 1.0),
        so3.jac_rplus(so3.identity(dtype=dtype), w)[0].mT,
    ):
        _assert_rotation(R, axis, dtype)
    for q in (quaternion.from_rotvec(w), quaternion.integrate(quaternion.identity(dtype=dtype),
                                                              w, 1.0)):  # fmt: skip
        assert torch.isfinite(q).all()
        assert ((q.double().norm(dim=-1) - 1.0).abs() <= _tol(dtype)).all()


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
def test_moderate_angles_keep_their_bits(dtype):
    """Below the reduction's threshold the exp maps are those of the formulas, unreduced."""
    w = _directions(3, dtype) * _coeffs._HUGE[dtype]
    assert torch.equal(_coeffs.reduced(w), w)
    assert (_coeffs.reduced(w * 2.0).norm(dim=-1) < 2 * math.pi * math.sqrt(3.0)).all()


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
def test_se3_exp_translation(dtype):
    """``t = Jl(phi) rho``: along the axis ``(u . rho) u`` plus ``O(|rho| / |phi|)`` across."""
    s, phi = _sweep(3, dtype)
    g = torch.Generator().manual_seed(2)
    rho = torch.randn(phi.shape, generator=g, dtype=dtype)
    T = se3.exp(torch.cat((rho, phi), -1))
    assert torch.isfinite(T).all()
    u = _unit_of(phi)
    t = T[..., :3, 3].double()
    along = (t * u).sum(-1)
    torch.testing.assert_close(along, (rho.double() * u).sum(-1), rtol=0, atol=_tol(dtype) * 8)
    across = (t - along[:, None] * u).norm(dim=-1)
    assert (across <= 2.0 * rho.double().norm(dim=-1) / s.double().clamp_max(2.0) + 1e-6).all()


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
def test_left_and_right_jacobians(dtype):
    """Finite at every magnitude; ``Jl(w) u = u`` and ``Jl(w) -> u u^T`` as ``|w| -> inf``."""
    s, w = _sweep(3, dtype)
    u = _unit_of(w)
    for J in (so3.jac_left(w), so3.jac_right(w), so3.jac_rplus(so3.identity(dtype=dtype), w)[1]):
        assert torch.isfinite(J).all()
        Ju = (J.double() @ u.unsqueeze(-1)).squeeze(-1)
        torch.testing.assert_close(Ju, u, rtol=0, atol=_tol(dtype) * 4)
        big = s.double() > 1e8
        far = J.double()[big] - u[big].unsqueeze(-1) * u[big].unsqueeze(-2)
        assert far.abs().amax() <= 1e-7


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
def test_se3_jacobians(dtype):
    """Finite at every magnitude of ``phi``: the diagonal blocks are so3's ``Jl(phi)``, ``Jr`` is
    ``Jl(-xi)``, and ``Q`` tends to ``rho^/2 - K rho^ K/2 + (K^2 rho^ + rho^ K^2)/2`` (``K = u^``)
    with an error of order ``|rho| / |phi|``."""
    s, phi = _sweep(3, dtype)
    g = torch.Generator().manual_seed(4)
    rho = torch.randn(phi.shape, generator=g, dtype=dtype)
    xi = torch.cat((rho, phi), -1)
    J = se3.jac_left(xi)
    assert torch.isfinite(J).all()
    assert torch.equal(J[..., :3, :3], so3.jac_left(phi))
    assert torch.equal(J[..., 3:, 3:], so3.jac_left(phi))
    assert torch.equal(se3.jac_right(xi), se3.jac_left(-xi))
    K, P = so3.hat(_unit_of(phi)), so3.hat(rho.double())
    limit = 0.5 * (P - K @ P @ K + K @ K @ P + P @ K @ K)
    err = (J[..., :3, 3:].double() - limit).abs().amax((-1, -2))
    size = rho.double().abs().amax(-1)
    big = s.double() > 1e3
    assert (err[big] <= size[big] * (10.0 / s.double()[big] + _tol(dtype))).all()


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
def test_se3_jacobian_q_is_linear_in_rho(dtype):
    """``Q(rho, phi)`` is linear in ``rho``: finite and scaled for every magnitude of ``rho``."""
    s, rho = _sweep(3, dtype, top=2.0**-6)
    phi = torch.tensor([0.3, -2.0, 1.1], dtype=dtype).expand_as(rho)
    Q = se3.jac_left(torch.cat((rho, phi), -1))[..., :3, 3:]
    assert torch.isfinite(Q).all()
    unit = se3.jac_left(torch.cat((_unit_of(rho).to(dtype), phi), -1))[..., :3, 3:]
    want = unit.double() * _norm_of(rho).unsqueeze(-1)
    scale = want.abs().amax((-1, -2), keepdim=True)
    keep = s > 1e3 * torch.finfo(dtype).tiny  # Q's entries of subnormal rho lose digits
    torch.testing.assert_close(
        (Q.double() / scale)[keep], (want / scale)[keep], rtol=0, atol=_tol(dtype) * 4
    )


def _sim3_tangents(dtype: torch.dtype, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``(s, xi)``: the sweep of rotation vectors with random ``rho`` and log scales alternating
    between 0 (where Sim(3) is SE(3)), 0.7 and -1.3."""
    s, phi = _sweep(3, dtype)
    g = torch.Generator().manual_seed(seed)
    rho = torch.randn(phi.shape, generator=g, dtype=dtype)
    sigma = torch.tensor([0.0, 0.7, -1.3], dtype=dtype).repeat(len(s) // 3 + 1)[: len(s)]
    return s, torch.cat((rho, phi, sigma[:, None]), -1)


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
def test_sim3_exp_at_every_angle(dtype):
    """``M / s`` is the rotation of ``phi`` and ``t = V rho`` tends to ``A (u . rho) u`` (``A =
    (e^sigma - 1)/sigma``) with an error of order ``A |rho| / |phi|``; at ``sigma = 0`` the
    translation is se3's."""
    s, xi = _sim3_tangents(dtype, 7)
    T = sim3.exp(xi)
    assert torch.isfinite(T).all()
    u = _unit_of(xi[:, 3:6])
    sig = xi[:, 6].double()
    _assert_rotation(T[:, :3, :3] / torch.exp(xi[:, 6])[:, None, None], u, dtype)
    A = torch.where(sig == 0, 1.0, torch.expm1(sig) / torch.where(sig == 0, 1.0, sig))
    t, rho = T[:, :3, 3].double(), xi[:, :3].double()
    along = (t * u).sum(-1)
    torch.testing.assert_close(along, A * (rho * u).sum(-1), rtol=0, atol=_tol(dtype) * 8)
    across = (t - along[:, None] * u).norm(dim=-1)
    assert (across <= 2.0 * A * rho.norm(dim=-1) / s.double().clamp_max(2.0) + 1e-6).all()
    zero = sig == 0
    T3 = se3.exp(xi[zero, :6])
    torch.testing.assert_close(T[zero, :3, 3], T3[:, :3, 3], rtol=0, atol=_tol(dtype) * 4)


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
def test_sim3_jacobians_at_every_angle(dtype):
    """Finite at every magnitude of ``phi``; the rotation block is so3's ``Jl(phi)``, ``Jr`` is
    ``Jl(-xi)``, at ``sigma = 0`` the (rho, phi) block is se3's, and as ``|phi| -> inf`` the
    blocks tend to ``V -> A u u^T``, ``Q -> 0``, ``W -> (A_s - A) (u . rho) u``."""
    s, xi = _sim3_tangents(dtype, 8)
    J = sim3.jac_left(xi)
    assert torch.isfinite(J).all()
    assert torch.equal(sim3.jac_right(xi), sim3.jac_left(-xi))
    tol = _tol(dtype)
    torch.testing.assert_close(J[:, 3:6, 3:6], so3.jac_left(xi[:, 3:6]), rtol=0, atol=tol)
    zero = xi[:, 6] == 0
    torch.testing.assert_close(J[zero, :6, :6], se3.jac_left(xi[zero, :6]), rtol=0, atol=tol * 4)
    u, sig, rho = _unit_of(xi[:, 3:6]), xi[:, 6].double(), xi[:, :3].double()
    nz = torch.where(sig == 0, 1.0, sig)
    A = torch.where(sig == 0, 1.0, torch.expm1(sig) / nz)
    As = torch.where(sig == 0, 0.5, (torch.exp(sig) * (sig - 1.0) + 1.0) / (nz * nz))
    uu = u.unsqueeze(-1) * u.unsqueeze(-2)
    big = s.double() > 1e8
    Jd = J.double()[big]
    size = 1.0 + rho[big].norm(dim=-1)
    near = 1e-7 + tol
    assert ((Jd[:, :3, :3] - A[big, None, None] * uu[big]).abs().amax((-1, -2)) <= near).all()
    assert (Jd[:, :3, 3:6].abs().amax((-1, -2)) <= near * size).all()
    W = ((As - A) * (rho * u).sum(-1))[:, None] * u
    assert ((Jd[:, :3, 6] - W[big]).abs().amax(-1) <= near * size).all()


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
def test_gradients_are_finite(dtype):
    s, w = _sweep(3, dtype)
    g = torch.Generator().manual_seed(3)
    xi = torch.cat((torch.randn(w.shape, generator=g, dtype=dtype), w), -1)
    q = torch.cat((torch.zeros_like(w[:, :1]), w), -1)
    cases = [
        (so3.exp, w),
        (so3.jac_left, w),
        (so3.jac_right, w),
        (quaternion.from_rotvec, w),
        (quaternion.exp, q),
        (se3.exp, xi),
        (se3.jac_left, xi),
        (se3.jac_right, xi),
        (sim3.exp, torch.cat((xi, torch.full_like(xi[:, :1], 0.7)), -1)),
        (sim3.jac_left, torch.cat((xi, torch.full_like(xi[:, :1], -1.3)), -1)),
        (sim3.jac_right, torch.cat((xi, torch.full_like(xi[:, :1], 0.7)), -1)),
        # d (v / |v|) / dv ~ 1 / |v|: representable from |v| ~ 1 / max
        (lambda v: conversions.axis_angle_to_matrix(v, 1.0), w[s > 64 / torch.finfo(dtype).max]),
    ]
    for fn, x in cases:
        leaf = x.clone().requires_grad_()
        out = fn(leaf)
        c = torch.randn(out.shape, generator=g, dtype=dtype)
        (grad,) = torch.autograd.grad(out, leaf, c)
        assert torch.isfinite(grad).all(), fn


# ----------------------------------------------------------------------------------------------
# torchlie.compiled: the same range (the rescaling and the angle reduction run inside the ops)
# ----------------------------------------------------------------------------------------------


@pytest.mark.compile
@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
def test_compiled_ops_take_every_magnitude(dtype):
    from torchlie import compiled

    cq = compiled.quaternion
    s, q = _sweep(4, dtype)
    unit = _unit_of(q).to(dtype)
    p = _P.to(dtype)
    for fn, eager in (
        (cq.to_matrix, quaternion.to_matrix),  # custom Functions
        (lambda x: cq.apply(x, p), lambda x: quaternion.apply(x, p)),
        (cq.normalize, quaternion.normalize),  # plain formulas
        (cq.to_rotvec, quaternion.to_rotvec),
    ):
        got = fn(q)
        assert torch.isfinite(got).all(), s[~torch.isfinite(got).flatten(1).all(-1)]
        torch.testing.assert_close(got, eager(unit), rtol=0, atol=_tol(dtype) * 4)
    s, w = _sweep(3, dtype)
    axis = _unit_of(w)
    g = torch.Generator().manual_seed(4)
    rho = torch.randn(w.shape, generator=g, dtype=dtype)
    T = compiled.se3.exp(torch.cat((rho, w), -1))
    for R in (
        compiled.so3.exp(w),
        cq.to_matrix(cq.from_rotvec(w)),
        T[..., :3, :3],
    ):
        _assert_rotation(R, axis, dtype)
    along = (T[..., :3, 3].double() * axis).sum(-1)
    torch.testing.assert_close(along, (rho.double() * axis).sum(-1), rtol=0, atol=_tol(dtype) * 8)


@pytest.mark.compile
@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
def test_compiled_gradients_are_finite_and_eager(dtype):
    """Through the custom Functions' backward, whose guard is carried back by hand: finite at
    every magnitude, and eager's: the quaternion ops' below ``1 / eps``, the exp maps' for
    angles up to 10.  Eager's multiply-adds and Inductor's code may round the angle ``t = |w|``
    differently, by an ulp of ``t``, which moves ``sin t`` and ``cos t`` by about ``t eps``:
    beyond a few radians the two are different but equally valid evaluations, and only their
    finiteness is compared."""
    from torchlie import compiled

    s, w = _sweep(3, dtype)
    xi = torch.cat(
        (torch.randn(w.shape, generator=torch.Generator().manual_seed(5), dtype=dtype), w), -1
    )
    q = torch.cat((torch.ones_like(w[:, :1]), w), -1)
    p = _P.to(dtype)
    angles, scale_free = s <= 10.0, s < 1.0 / torch.finfo(dtype).eps
    for fn, eager, x, exact in (
        (compiled.so3.exp, so3.exp, w, angles),
        (compiled.se3.exp, se3.exp, xi, angles),
        (compiled.quaternion.to_matrix, quaternion.to_matrix, q, scale_free),
        (
            lambda v: compiled.quaternion.apply(v, p),
            lambda v: quaternion.apply(v, p),
            q,
            scale_free,
        ),
    ):
        leaf = x.clone().requires_grad_()
        out = fn(leaf)
        c = torch.randn(out.shape, generator=torch.Generator().manual_seed(6), dtype=dtype)
        (grad,) = torch.autograd.grad(out, leaf, c)
        assert torch.isfinite(grad).all(), s[~torch.isfinite(grad).all(-1)]
        (want,) = torch.autograd.grad(eager(leaf), leaf, c)
        scale = want[exact].abs().amax(-1, keepdim=True).clamp_min(1.0)
        assert ((grad[exact] - want[exact]).abs() <= 64 * torch.finfo(dtype).eps * scale).all()


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_norms_and_small_vector_parts_at_every_magnitude(dtype):
    """Lengths whose squares overflow or underflow: translation distances, rotation angles
    read from a matrix's skew part, the axis of ``matrix_to_axis_angle`` and the vector part
    of a quaternion next to the negative real axis (it lay on the cut: axis x, or a wrong
    angle)."""
    eps = torch.finfo(dtype).eps
    big = 1e300 if dtype == torch.float64 else 1e36
    small = (1e-160, 1e-200, 1e-300) if dtype == torch.float64 else (1e-20, 1e-25, 1e-30)
    for s in (big, 3e19 if dtype == torch.float32 else 3e160, *small):
        t = torch.tensor([3.0, 4.0, 0.0], dtype=dtype) * s
        T = se3.from_rt(torch.eye(3, dtype=dtype), t)
        d = se3.distance(se3.identity(dtype=dtype), T)[1]
        assert abs(float(d) / (5 * s) - 1) <= 2 * eps, (s, float(d))
    u = torch.tensor([0.36, -0.48, 0.8], dtype=torch.float64)  # a unit axis
    for a in small:
        R = so3.exp((u * a).to(dtype))
        assert abs(float(so3.distance(torch.eye(3, dtype=dtype), R)) / a - 1) <= 4 * eps
        axis, angle = conversions.matrix_to_axis_angle(R)
        torch.testing.assert_close(axis.double(), u, rtol=0, atol=4 * eps)
        assert abs(float(angle) / a - 1) <= 4 * eps
        q = torch.cat((torch.tensor([-1.0], dtype=torch.float64), u * a)).to(dtype)
        want = (math.pi - a) * u  # the angle times the unit axis of the vector part
        torch.testing.assert_close(quaternion.log(q)[1:].double(), want, rtol=0, atol=4 * eps)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_vee_of_hat_up_to_the_largest_float(dtype):
    """``vee(hat(x)) = x`` exactly up to the largest float (the skew part's ``(a - b) / 2``
    overflowed from half of it)."""
    from torchlie import se2, so2

    top = torch.finfo(dtype).max
    x = torch.tensor([top, -top / 2, top / 3], dtype=dtype)
    for core, v in ((so3, x), (se3, torch.cat((x, x))), (so2, x[:1]), (se2, x)):
        assert torch.equal(core.vee(core.hat(v)), v), core.__name__


# ----------------------------------------------------------------------------------------------
# Intermediate products near the largest float: the result is finite and right
# ----------------------------------------------------------------------------------------------


def _close(got: torch.Tensor, want: torch.Tensor, dtype: torch.dtype, scale: float) -> None:
    """``got`` (finite) within ``_tol(dtype) * 4`` of ``want`` relative to ``scale``."""
    assert torch.isfinite(got).all(), got
    err = ((got.double() - want.double()) / scale).abs().max()
    assert err <= _tol(dtype) * 4, float(err)


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
def test_se3_exp_and_log_of_translations_near_the_largest_float(dtype):
    """``t = Jl(phi) rho``, ``rho = Jl(phi)^-1 t``: linear in ``rho`` (``t``), and ``t = rho``
    for ``rho`` along ``phi``; the products of ``phi`` and ``rho`` (``phi . rho``,
    ``phi x rho``) overflowed from a few times the largest float over ``|phi|`` (inf and NaN)."""
    m = torch.finfo(dtype).max / 2
    T = se3.exp(torch.tensor([m, 0.0, 0.0, m, 0.0, 0.0], dtype=dtype))
    _close(T[:3, 3], torch.tensor([m, 0.0, 0.0], dtype=torch.float64), dtype, m)
    xi = torch.ones(6, dtype=dtype) * (m / 2)
    _close(se3.exp(xi)[:3, 3], xi[:3], dtype, m)
    R = torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=dtype))
    got = se3.log(se3.from_rt(R, torch.tensor([m, 0.0, 0.0], dtype=dtype)))
    want = torch.tensor([m, 0.0, 0.0, math.pi, 0.0, 0.0], dtype=torch.float64)
    _close(got, want, dtype, m)
    _close(got[3:], want[3:], dtype, 1.0)
    # generic directions: the results of rho (t) of size s are s times those of size 1
    g = torch.Generator().manual_seed(11)
    phi = torch.randn(8, 3, generator=g, dtype=torch.float64) * 1.5
    u = torch.randn(8, 3, generator=g, dtype=torch.float64)
    u = (u / u.abs().amax(-1, keepdim=True)).to(dtype)
    phi = phi.to(dtype)
    s = m / 2
    unit = se3.exp(torch.cat((u, phi), -1))[:, :3, 3]
    _close(se3.exp(torch.cat((u * s, phi), -1))[:, :3, 3], unit.double() * s, dtype, s)
    Rs = so3.exp(phi)
    unit = se3.log(se3.from_rt(Rs, u))
    got = se3.log(se3.from_rt(Rs, u * s))
    _close(got[:, :3], unit[:, :3].double() * s, dtype, s)
    assert torch.equal(got[:, 3:], unit[:, 3:])


def _linear_grads(fn, x_unit: torch.Tensor, x_big: torch.Tensor, G: torch.Tensor):
    """Gradients of ``<fn(x), G>`` at ``x_unit`` and ``x_big``, in float64."""
    out = []
    for x in (x_unit, x_big):
        leaf = x.clone().requires_grad_()
        (grad,) = torch.autograd.grad(fn(leaf), leaf, G)
        assert torch.isfinite(grad).all(), grad
        out.append(grad.double())
    return out


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
def test_se3_exp_and_log_gradients_near_the_largest_float(dtype):
    """The translation of ``exp`` is linear in ``rho``, the ``rho`` of ``log`` in ``t``: their
    gradients in ``phi`` (``R``) from an upstream gradient on them scale with ``rho`` (``t``),
    those in ``rho`` (``t``) do not, at every size up to half the largest float."""
    m = torch.finfo(dtype).max / 2
    g = torch.Generator().manual_seed(12)
    phi = torch.cat(
        (torch.tensor([[m, 0.0, 0.0], [m / 2, m / 2, m / 2]], dtype=torch.float64),
         torch.randn(6, 3, generator=g, dtype=torch.float64) * 1.5)
    ).to(dtype)  # fmt: skip
    u = torch.cat(
        (torch.tensor([[1.0, 0.0, 0.0], [1.0, 1.0, 1.0]], dtype=torch.float64),
         torch.rand(6, 3, generator=g, dtype=torch.float64) * 2.0 - 1.0)
    ).to(dtype)  # fmt: skip
    s = m / 2
    # exp: an upstream gradient on the translation only (small: the gradient in phi is s times
    # that of rho = u)
    G = torch.zeros(8, 4, 4, dtype=dtype)
    G[:, :3, 3] = torch.randn(8, 3, generator=g, dtype=dtype) * 2.0**-6
    one, big = _linear_grads(se3.exp, torch.cat((u, phi), -1), torch.cat((u * s, phi), -1), G)
    _close(big[:, :3], one[:, :3], dtype, 1.0)
    _close(big[:, 3:] / s, one[:, 3:], dtype, float(one[:, 3:].abs().max()))
    # log: an upstream gradient on rho only
    Rs = so3.exp(torch.randn(8, 3, generator=g, dtype=dtype))
    Rs[0] = torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=dtype))  # angle pi
    gl = torch.zeros(8, 6, dtype=dtype)
    gl[:, :3] = torch.randn(8, 3, generator=g, dtype=dtype) * 2.0**-6
    one, big = _linear_grads(se3.log, se3.from_rt(Rs, u), se3.from_rt(Rs, u * s), gl)
    _close(big[:, :3, 3], one[:, :3, 3], dtype, float(one[:, :3, 3].abs().max()))
    _close(big[:, :3, :3] / s, one[:, :3, :3], dtype, float(one[:, :3, :3].abs().max()))


def _sim3_unit_and_scale(dtype: torch.dtype, seed: int):
    """``(xi, s)``: 8 tangents with ``|rho_i| <= 1``, moderate ``phi`` and ``sigma``, and per row
    a power of two ``s`` that takes the larger of ``rho`` and the translation ``V rho`` to
    between a quarter and half the largest float."""
    g = torch.Generator().manual_seed(seed)
    u = torch.rand(8, 3, generator=g, dtype=torch.float64) * 2.0 - 1.0
    phi = torch.randn(8, 3, generator=g, dtype=torch.float64) * 1.5
    sigma = torch.randn(8, 1, generator=g, dtype=torch.float64) * 0.7
    xi = torch.cat((u, phi, sigma), -1).to(dtype)
    size = torch.maximum(xi[:, :3].abs().amax(-1), sim3.exp(xi)[:, :3, 3].abs().amax(-1))
    top = torch.finfo(dtype).max
    s = 2.0 ** torch.floor(torch.log2(top / 2 / size.double()))
    return xi, s.to(dtype)


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
def test_sim3_inverse_whose_translation_overflows(dtype):
    # A tiny scale and a huge translation: -R^T t / s exceeds the largest float, so each
    # component is an infinity of the true sign (or 0 where R^T t is 0), never NaN.
    g = torch.Generator().manual_seed(23)
    R = so3.random(16, generator=g, dtype=torch.float64)
    R[:4] = torch.eye(3, dtype=torch.float64)  # exact zeros in R^T t
    fi = torch.finfo(dtype)
    t = ((torch.rand(16, 3, generator=g, dtype=torch.float64) * 2 - 1) * fi.max / 4).to(dtype)
    t[:4, 1:] = 0
    T = sim3.from_srt(torch.full((16,), 2.0**-10, dtype=dtype), R.to(dtype), t)
    got = sim3.inverse(T)[:, :3, 3]
    want = -(R.mT @ t.double().unsqueeze(-1)).squeeze(-1)  # the sign of the true result
    assert not bool(got.isnan().any())
    torch.testing.assert_close(got.sign(), want.sign().to(dtype), rtol=0, atol=0)
    assert bool(got[want != 0].isinf().all())


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
def test_sim3_exp_and_log_of_translations_near_the_largest_float(dtype):
    """``t = V rho``, ``rho = V^-1 t``: linear in ``rho`` (``t``); the products of ``phi`` and
    ``rho`` (``t``) overflowed from the largest float over ``|phi|`` (inf and NaN)."""
    top = torch.finfo(dtype).max
    c = top / torch.finfo(torch.float64).max
    # the translation of exp: [-inf, -inf, nan]; of log of an element: [-inf, -inf, -inf]
    x = torch.tensor(
        [-1.6183184662942647e306, -4.617988753513921e307, 3.552338921332569e307,
         -4.821637872663512, -5.353708275269559, -1.5779314739067056, -0.21511260619543326],
        dtype=torch.float64,
    )  # fmt: skip
    x[:3] *= c
    want = torch.tensor(
        [-1.7212230124086865e307, -1.8324301655013976e307, 1.3038415572072897e306],
        dtype=torch.float64,
    )
    _close(sim3.exp(x.to(dtype))[:3, 3], want * c, dtype, top)
    x = torch.tensor(
        [-1.0987132010365576e308, -8.491380176665809e307, 1.1712778751316592e306,
         0.554131335828653, 1.1266801580295962, 0.34069310921475, 0.7754704401183692],
        dtype=torch.float64,
    )  # fmt: skip
    x[:3] *= c
    _close(sim3.log(sim3.exp(x.to(dtype)))[:3], x[:3], dtype, top)
    # generic directions: the results of rho (t) of size s are s times those of size 1
    xi, s = _sim3_unit_and_scale(dtype, 21)
    S = s.double()[:, None]
    big = torch.cat((xi[:, :3] * s[:, None], xi[:, 3:]), -1)
    unit = sim3.exp(xi)
    _close(sim3.exp(big)[:, :3, 3] / S, unit[:, :3, 3], dtype, 1.0)
    Tb = unit.clone()
    Tb[:, :3, 3] *= s[:, None]
    got = sim3.log(Tb)
    _close(got[:, :3] / S, sim3.log(unit)[:, :3], dtype, 1.0)
    assert torch.equal(got[:, 3:], sim3.log(unit)[:, 3:])


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
def test_sim3_log_gradients_near_the_largest_float(dtype):
    """The ``rho`` of ``log`` is linear in ``t``: its gradients in ``M`` from an upstream
    gradient on ``rho`` scale with ``t``, those in ``t`` do not, up to half the largest float
    (``u . (phi x t)`` and the like overflowed: inf and NaN)."""
    xi, s = _sim3_unit_and_scale(dtype, 22)
    g = torch.Generator().manual_seed(23)
    gl = torch.zeros(8, 7, dtype=dtype)
    gl[:, :3] = torch.randn(8, 3, generator=g, dtype=dtype) * 2.0**-6
    unit = sim3.exp(xi)
    Tb = unit.clone()
    Tb[:, :3, 3] *= s[:, None]
    one, big = _linear_grads(sim3.log, unit, Tb, gl)
    _close(big[:, :3, 3], one[:, :3, 3], dtype, float(one[:, :3, 3].abs().max()))
    scale = float(one[:, :3, :3].abs().max())
    _close(big[:, :3, :3] / s.double()[:, None, None], one[:, :3, :3], dtype, scale)


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
def test_sim3_exp_and_log_of_random_huge_translations(dtype):
    """Translations of any size up to the largest float with random rotations and scales: exp's
    translation and log's ``rho`` of the elements are finite and within ``1e-6`` of the
    reference, computed in float64 from ``rho`` (``t``) scaled down by a power of two.  Results
    within 8 times of the largest float are left out (there a sum of terms each below it may
    overflow)."""
    top = torch.finfo(dtype).max
    k = 2.0**-900 if dtype == torch.float64 else 2.0**-100
    g = torch.Generator().manual_seed(24)
    n = 300
    r = torch.rand(n, 1, generator=g, dtype=torch.float64)
    rho = (torch.rand(n, 3, generator=g, dtype=torch.float64) - 0.5) * top * r
    phi = torch.randn(n, 3, generator=g, dtype=torch.float64) * 3.0
    phi = phi * torch.rand(n, 1, generator=g, dtype=torch.float64)
    sigma = torch.randn(n, 1, generator=g, dtype=torch.float64) * 1.5
    x = torch.cat((rho, phi, sigma), -1).to(dtype)
    xs = x.double().clone()
    xs[:, :3] *= k
    want = sim3.exp(xs)[:, :3, 3] / k
    keep = want.abs().amax(-1) <= top / 8
    assert keep.sum() > n // 3
    T = sim3.exp(x[keep])
    got = T[:, :3, 3].double()
    assert torch.isfinite(got).all()
    err = (got - want[keep]).norm(dim=-1) / want[keep].norm(dim=-1)
    assert err.max() <= 1e-6, float(err.max())
    # log of these elements
    Ts = T.double().clone()
    Ts[:, :3, 3] *= k
    want = sim3.log(Ts)[:, :3] / k
    keep = want.abs().amax(-1) <= top / 8
    got = sim3.log(T[keep])[:, :3].double()
    assert torch.isfinite(got).all()
    err = (got - want[keep]).norm(dim=-1) / want[keep].norm(dim=-1)
    assert err.max() <= 1e-6, float(err.max())


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
def test_exp_gradients_of_huge_upstream_gradients(dtype):
    """The gradients are linear in the upstream gradient: a power of two ``c`` with ``c |w|``
    times the upstream gradient beyond the largest float (``w . v`` and ``w x v`` of the
    backward overflowed, NaN) gives ``c`` times the gradient (se3's at moderate angles: its
    ``Q`` block takes ``phi`` itself, whose products with the gradient overflow at 1e10)."""
    g = torch.Generator().manual_seed(13)
    w = torch.tensor([[1e10, 2e9, -3e9], [30.0, -10.0, 20.0], [1.0, -2.0, 0.5]], dtype=dtype)
    xi = torch.cat((torch.randn(3, 3, generator=g, dtype=dtype), w), -1)
    c = 2.0 ** (math.floor(math.log2(torch.finfo(dtype).max)) - 30)  # 1.6e29 f32, 8e298 f64
    for fn, x, shape in ((so3.exp, w, (3, 3, 3)), (se3.exp, xi[1:], (2, 4, 4))):
        G = torch.rand(shape, generator=g, dtype=dtype) * 2.0 - 1.0
        leaf = x.clone().requires_grad_()
        (want,) = torch.autograd.grad(fn(leaf), leaf, G)
        (got,) = torch.autograd.grad(fn(leaf), leaf, G * c)
        _close(got.double() / c, want.double(), dtype, float(want.abs().max()))


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
def test_project_gradients_of_huge_matrices(dtype):
    """``project(s M) = project(M)``: the gradient (reverse and forward) of ``s M`` is that of
    ``M`` over ``s``, up to half the largest float (the trace of the polar factor overflowed:
    NaN)."""
    g = torch.Generator().manual_seed(14)
    M = torch.cat((torch.eye(3, dtype=dtype)[None], torch.randn(4, 3, 3, generator=g, dtype=dtype)))
    M = M / M.abs().amax((-1, -2), keepdim=True)
    s = torch.finfo(dtype).max / 2
    G = torch.arange(9.0, dtype=dtype).view(3, 3) * 2.0**20
    one, big = _linear_grads(so3.project, M, M * s, G.expand(5, 3, 3))
    _close(big * s, one, dtype, float(one.abs().max()))
    one, big = _linear_grads(
        conversions.rot9d_to_matrix, M.flatten(-2), (M * s).flatten(-2), G.expand(5, 3, 3)
    )
    _close(big * s, one, dtype, float(one.abs().max()))
    import torch.autograd.forward_ad as fwad

    with fwad.dual_level():
        outs = [
            fwad.unpack_dual(so3.project(fwad.make_dual(x, G.expand(5, 3, 3)))).tangent
            for x in (M, M * s)
        ]
    _close(outs[1].double() * s, outs[0].double(), dtype, float(outs[0].abs().max()))


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
def test_quaternion_apply_near_the_largest_float(dtype):
    """``apply(q, p)`` is ``to_matrix(q) p`` for points up to the largest float and any scale of
    ``q`` (``v x (v x p)`` overflowed with ``|q|^2 |p|``), its gradient in ``q`` linear in
    ``p``."""
    top = torch.finfo(dtype).max
    q = torch.tensor([1.541, -0.2934, -2.1788, 0.5684], dtype=dtype)
    p = torch.tensor([-6.97e307, -8.99e307, 2.59e307], dtype=torch.float64)
    p = (p * (top / 1.7976931348623157e308)).to(dtype)
    _close(quaternion.apply(q, p), so3.act(quaternion.to_matrix(q), p), dtype, top)
    g = torch.Generator().manual_seed(15)
    qs = torch.randn(6, 4, generator=g, dtype=dtype)
    ps = torch.rand(6, 3, generator=g, dtype=dtype) * 2.0 - 1.0
    want = quaternion.apply(qs, ps).double()
    for k in (2.0**-20, 1.0, 2.0**20):
        _close(quaternion.apply(qs * k, ps * (top / 2)), want * (top / 2), dtype, top / 2)
    G = torch.randn(6, 3, generator=g, dtype=dtype) * 2.0**-6
    one, big = _linear_grads(lambda x: quaternion.apply(x, ps), qs, qs, G)
    _, big = _linear_grads(lambda x: quaternion.apply(x, ps * (top / 2)), qs, qs, G)
    _close(big / (top / 2), one, dtype, float(one.abs().max()))
