"""Rotation matrices and unit quaternions, each from the other, and the rotation vector and
angle of a matrix: the kernels that :mod:`torchlie.quaternion`, :mod:`torchlie.so3` and
:mod:`torchlie.se3` share.

:func:`from_quaternion` and :func:`to_quaternion` (Shepperd's method, refined by one power
step) are custom Functions with closed-form backward and forward-mode rules; :func:`log` and
:func:`log_and_cot` read the rotation vector straight from the unnormalised candidate (the
forward of ``so3.log`` and ``se3.log``).  They are apart from
:mod:`torchlie.quaternion` so that so3 and se3 build on them without the rest of that module.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from . import _coeffs, _layout
from ._autograd import CustomFunction, blocked, fma
from ._components import (
    cross_planes,
    gram_defect,
    hat,
    norm2,
    planes,
    polar_backward_terms,
    polar_tangent,
    r_hat,
    rt_g_vee,
    vee,
)
from ._hamilton import conj_product_vec, multiply

# ----------------------------------------------------------------------------------------------
# Quaternion to matrix
# ----------------------------------------------------------------------------------------------


def _to_matrix_forward(q: Tensor | Sequence[Tensor]) -> Tensor:
    """:func:`torchlie.quaternion.to_matrix` entry by entry."""
    w, x, y, z = planes(q, 4)
    ww, yy = w * w, y * y
    # Diagonal as (w^2 + x^2 - y^2 - z^2) / |q|^2: two terms bounded by |q|^2, where
    # 1 - (yy + zz) s rounds a sum near 2 close to pi (3.1e-16 instead of 5.0e-16 in float64).
    # The last two share their halves: (ww - xx) +- (yy - zz).  Squares and products enter
    # by multiply-adds (one rounding each, where the CPU fuses them).
    a, b = fma(ww, x, x), fma(yy, z, z)
    hs = torch.reciprocal(a + b)  # 1 / |q|^2
    s = hs + hs
    u, v = fma(ww, x, x, value=-1.0), fma(yy, z, z, value=-1.0)
    xs, ys, zs = x * s, y * s, z * s
    xy, xz, yz = x * ys, x * zs, y * zs
    o = _layout.outputs(w, 9)
    mul = torch.mul
    entries = (
        mul(a - b, hs, out=o[0]), fma(xy, w, zs, value=-1.0, out=o[1]), fma(xz, w, ys, out=o[2]),
        fma(xy, w, zs, out=o[3]), mul(u + v, hs, out=o[4]), fma(yz, w, xs, value=-1.0, out=o[5]),
        fma(xz, w, ys, value=-1.0, out=o[6]), fma(yz, w, xs, out=o[7]), mul(u - v, hs, out=o[8]),
    )  # fmt: skip
    return _layout.interleave(entries, o).unflatten(-1, (3, 3))


def _to_matrix_grad(q: Tensor, R: Tensor, G: Tensor) -> Tensor:
    # With u = q/|q|, a change dq turns R into R Exp(d), d = 2 vec(conj(q) dq) / |q|^2, so
    # <G, R hat(d)> = a . d with a = vee(R^T G - G^T R), and dL/dq = 2 (q (0, a)) / |q|^2
    # (orthogonal to q: to_matrix does not see the scale of q).
    w, x, y, z = planes(q, 4)
    a1, a2, a3 = rt_g_vee(R, G)
    k = 2.0 / norm2(w, x, y, z)
    o = _layout.outputs((w, a1), 4)
    gw = torch.mul(fma(fma(x * a1, y, a2), z, a3), k, out=o[0]).neg_()
    c = cross_planes((x, y, z), (a1, a2, a3))
    gv = [
        torch.mul(fma(ci, w, ai), k, out=oi)
        for ai, ci, oi in zip((a1, a2, a3), c, o[1:], strict=True)
    ]
    return _layout.interleave((gw, *gv), o)


_to_matrix_grad_blocked = blocked(_to_matrix_grad, (1, 2, 2))


def _to_matrix_jvp(saved: tuple[Tensor, ...], dq: Tensor) -> Tensor:
    # dR = R hat(d), d = 2 vec(conj(q) dq) / |q|^2 (row i of R hat(d) is R_i x d).
    q, R = saved
    d = conj_product_vec(q, dq) * (2.0 / (q * q).sum(-1, keepdim=True))
    return torch.linalg.cross(R, d.unsqueeze(-2).expand_as(R), dim=-1)


_ToMatrixFn = CustomFunction(
    "QuaternionToMatrix",
    forward=lambda q: _to_matrix_forward(_coeffs.rescaled_planes(q, 4)),
    save=lambda inputs, out: (inputs[0], out),
    backward=lambda saved, G: (_to_matrix_grad_blocked(*saved, G),),
    jvp=_to_matrix_jvp,
    event_dims=(1,),
    guard=_coeffs.RESCALE,
)


def from_quaternion(q: Tensor) -> Tensor:
    """Rotation matrix of ``q / |q|`` (``torchlie.quaternion.to_matrix`` without input checks)."""
    return _ToMatrixFn(q)


# ----------------------------------------------------------------------------------------------
# Matrix to quaternion
# ----------------------------------------------------------------------------------------------


def _from_matrix_parts(
    R: Tensor | Sequence[Tensor],
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """``(cw, cx, cy, cz, s)``: ``c`` is proportional to the quaternion of the rotation
    nearest ``R`` (to first order in the distance of ``R`` from SO(3)), with ``|c| >= 8`` for a
    rotation; ``c / |c|`` with the sign of ``s`` (``copysign``) is the canonical unit
    quaternion."""
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = planes(R, 9)
    # The symmetric K = [[d0, s21, s02, s10], [s21, d1, a01, a02], [s02, a01, d2, a12],
    # [s10, a02, a12, d3]] is 4 q q^T for a rotation; for any R its top eigenvector is the
    # quaternion of the nearest rotation (of largest tr(Q^T R)).  Its diagonal 4 q_i^2, as
    # (1 +- m22) +- (m00 +- m11):
    p22, n22, p01, n01 = 1.0 + m22, 1.0 - m22, m00 + m11, m00 - m11
    d0, d1, d2, d3 = p22 + p01, n22 + n01, n22 - n01, p22 - p01
    s21, s02, s10 = m21 - m12, m02 - m20, m10 - m01  # 4 w (x, y, z)
    a01, a02, a12 = m01 + m10, m02 + m20, m12 + m21  # 4 (xy, xz, yz)
    # Pivot: the largest d_i (the first on ties).  Column i of K is 4 q_i q: proportional to q
    # with a positive i-th entry, selected entry by entry by steps g_i in {0, 1} (float steps,
    # not comparisons: see _coeffs.step), as lerp(a, b, g): exactly a at g = 0 and b at g = 1.
    g1 = _coeffs.step(d1 - d0)  # d1 > d0
    dmax = torch.maximum(d0, d1)
    g2 = _coeffs.step(d2 - dmax)
    g3 = _coeffs.step(d3 - torch.maximum(dmax, d2))
    lerp = torch.lerp

    def pick(c0: Tensor, c1: Tensor, c2: Tensor, c3: Tensor) -> Tensor:
        return lerp(lerp(lerp(c0, c1, g1), c2, g2), c3, g3)

    K = ((d0, s21, s02, s10), (s21, d1, a01, a02), (s02, a01, d2, a12), (s10, a02, a12, d3))
    c = [pick(*row) for row in K]
    # One power step, K c = K^2 e_p: near SO(3) the other eigenvalues of K are of the order of
    # the distance, so K c is the top eigenvector up to its square.  Its pivot entry |c|^2 is
    # positive, as c's was.  The term of the largest q_j^2 is the largest: that of the w
    # column, added last, wherever |w| is the largest entry (the angles up to pi / 2 at least).
    cw, cx, cy, cz = (
        fma(fma(fma(k1 * c[1], k2, c[2]), k3, c[3]), k0, c[0]) for k0, k1, k2, k3 in K
    )
    # Canonical sign: the pivot entry is positive, so flipping on w < 0 gives the canonical
    # representative (at w = 0 the pivot is the largest-magnitude vector component).
    # cw + 0.0 turns -0.0 into +0.0: no flip at w = 0.
    return cw, cx, cy, cz, cw + 0.0


def _from_matrix_forward(R: Tensor) -> Tensor:
    cw, cx, cy, cz, s = _from_matrix_parts(R)
    # |c| = 16 q_p >= 8 for a rotation: the division is safe, and a NaN element stays in its row.
    scale = torch.copysign(torch.rsqrt(norm2(cw, cx, cy, cz)), s)
    o = _layout.outputs(cw, 4)
    parts = [torch.mul(c, scale, out=oi) for c, oi in zip((cw, cx, cy, cz), o, strict=True)]
    return _layout.interleave(parts, o)


def _from_matrix_backward(saved: tuple[Tensor, ...], g: Tensor) -> tuple[Tensor]:
    # Along a tangent direction R hat(d) the canonical quaternion moves by dq = q (0, d) / 2;
    # along the normal directions R S (S symmetric) it does not move (the power step).  So
    # dL/dd = u = vec(conj(q) g) / 2 and G = R hat(u) / 2, the gradient that autograd gives
    # through Shepperd's formula and the power step at a rotation.
    R, q = saved
    w, x, y, z = planes(q, 4)
    gw, gx, gy, gz = planes(g, 4)
    c = cross_planes((x, y, z), (gx, gy, gz))
    u = [
        fma(w * gi, gw, vi, value=-1.0).sub_(ci).mul_(0.25)
        for gi, vi, ci in zip((gx, gy, gz), (x, y, z), c, strict=True)
    ]
    G = r_hat(R, u)
    if torch.is_grad_enabled():  # differentiated: the gradient off SO(3) too (so3._log_grad)
        G = G - polar_backward_terms(R, hat(torch.stack(u, dim=-1)), gram_defect(R))
    return (G,)


def _from_matrix_jvp(saved: tuple[Tensor, ...], dR: Tensor) -> Tensor:
    # dq = q (0, d) / 2 with d = vee of the skew part of R^T dR (its symmetric part: no effect).
    R, q = saved
    d = polar_tangent(R.transpose(-1, -2) @ dR, gram_defect(R))
    return multiply(q, torch.nn.functional.pad(0.5 * d, (1, 0)))


_FromMatrixFn = CustomFunction(
    "QuaternionFromMatrix",
    forward=_from_matrix_forward,
    save=lambda inputs, out: (inputs[0], out),
    backward=_from_matrix_backward,
    jvp=_from_matrix_jvp,
    event_dims=(2,),
)


def to_quaternion(R: Tensor) -> Tensor:
    """Canonical unit quaternion of ``R`` (``torchlie.quaternion.from_matrix`` without input
    checks)."""
    return _FromMatrixFn(R)


# ----------------------------------------------------------------------------------------------
# Rotation vector of a matrix
# ----------------------------------------------------------------------------------------------


def log(R: Tensor) -> Tensor:
    """Rotation vector of ``R`` (forward of :func:`torchlie.so3.log`; runs without autograd).

    ``2 atan2(|c_v|, |c_w|) c_v / |c_v|`` with the sign of the canonical quaternion, straight
    from the unnormalised candidate ``c`` (atan2 is scale-invariant).  At ``c_v = 0``
    (the identity) the quotient's denominator is clamped, which gives exactly 0.
    """
    return _layout.interleave(log_and_cot(R)[0])


def log_and_cot(
    R: Tensor | Sequence[Tensor], cot: bool = False
) -> tuple[tuple[Tensor, Tensor, Tensor], Tensor | None, Tensor | None]:
    """The three components of :func:`log` (not stacked; ``R`` as a tensor or its 9 planes, row
    by row), and with ``cot`` the angle ``theta`` and ``(theta/2) cot(theta/2)`` (the
    coefficients of ``Jl^-1``).  The rotation vector is ``2 atan2(|c_v|, |c_w|) c_v / |c_v|``
    with the sign of ``s`` (:func:`_from_matrix_parts`), ``|c_v|`` clamped at
    ``_coeffs.H_MIN`` before the angle and the quotient (which tends to ``2 / |c_w|``; ``phi``
    is exactly 0 at ``c_v = 0``) and ``cot(theta/2) = |c_w| / |c_v|``."""
    cw, cx, cy, cz, s = _from_matrix_parts(R)
    nv = fma(fma(cx * cx, cy, cy), cz, cz).sqrt_()
    nv = nv.clamp_min_(_coeffs.H_MIN[nv.dtype])
    a = cw.abs()
    theta = torch.atan(nv / a).mul_(2.0)  # atan2(nv, a) for nv > 0, a >= 0 (_coeffs.angle)
    f = torch.copysign(torch.div(theta, nv), s)
    phi = (f * cx, f * cy, f * cz)
    if not cot:
        return phi, None, None
    return phi, theta, a.div_(nv).mul_(theta).mul_(0.5)


def angle(M: Tensor) -> Tensor:
    """Rotation angle of ``M`` as ``atan2(|skew|, (tr - 1)/2)``: accurate at 0 and at pi."""
    s = _coeffs.norm(vee(M))
    c = 0.5 * (M[..., 0, 0] + M[..., 1, 1] + M[..., 2, 2] - 1.0)
    return _coeffs.atan2(s, c)
