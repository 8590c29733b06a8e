"""Sim(3): similarity transforms ``(..., 4, 4)`` and their tangents ``(..., 7)``.

Conventions (see :mod:`torchlie`): a similarity is ``T = [[s R, t], [0, 1]]`` with scale
``s = exp(sigma) > 0``, and acts on points as ``p -> s R p + t``; a tangent is
``xi = (rho, phi, sigma)``: translation part first, rotation vector, then log scale, with
``hat(xi) = [[hat(phi) + sigma I, rho], [0, 0]]``; perturbations are on the right,
``T (+) d = T Exp(d)``.  Built on :mod:`torchlie.so3` and the coefficient source
:mod:`torchlie._coeffs`::

    Exp(rho, phi, sigma) = [[e^sigma so3.exp(phi), V rho], [0, 1]]
    V = int_0^1 e^(s sigma) so3.exp(s phi) ds = A I + B hat(phi) + C hat(phi)^2
    A = (e^sigma - 1)/sigma,  B + ...: see torchlie._coeffs.sim3_v

so at ``sigma = 0`` the rotation and translation are those of :mod:`torchlie.se3`
(``V = so3.jac_left(phi)``).  :func:`log` returns a rotation angle in ``[0, pi]`` with so3's
rule at pi.  The adjoint on tangents is ``Ad_T = [[s R, hat(t) R, -t], [0, R, 0], [0, 0, 1]]``
and the small adjoint ``ad(xi) = [[hat(phi) + sigma I, hat(rho), -rho], [0, hat(phi), 0],
[0, 0, 0]]``; ``jac_left(xi) = int_0^1 exp(s ad(xi)) ds``, in closed form by blocks.
Jacobians of operations follow Sola et al. (as :mod:`torchlie.se3`):
``f(X Exp(d)) ~= f(X) Exp(J_Y_X d)``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import torch
from torch import Tensor

from . import (
    _checks,
    _coeffs,
    _components,
    _layout,
    _rodrigues,
    _rotation_matrix,
    _se3_kernels,
    so3,
)
from ._autograd import CustomFunction, blocked, fma, needs_graph, transforms_active
from ._typing import Bool, Float

__all__ = [
    "hat",
    "vee",
    "exp",
    "log",
    "compose",
    "inverse",
    "act",
    "adjoint",
    "ad",
    "jac_left",
    "jac_right",
    "jac_left_inv",
    "jac_right_inv",
    "identity",
    "random",
    "is_valid",
    "from_srt",
    "to_srt",
    "from_se3",
    "from_pos_quat_scale",
    "to_pos_quat_scale",
    "scale",
    "interpolate",
    "distance",
    "rplus",
    "rminus",
    "lplus",
    "lminus",
    "between",
    "jac_compose",
    "jac_inverse",
    "jac_act",
    "jac_rplus",
    "jac_rminus",
    "jac_between",
]

_NAME = "torchlie.sim3."

# ----------------------------------------------------------------------------------------------
# Component helpers (private)
# ----------------------------------------------------------------------------------------------


def _lin(T: Tensor) -> Tensor:
    """The linear block ``s R``."""
    return T[..., :3, :3]


def _trans(T: Tensor) -> Tensor:
    return T[..., :3, 3]


def _scaled_entries(M: Tensor | Sequence[Tensor]) -> tuple[list[Tensor], Tensor, Tensor]:
    """``(entries of M / k, k, out)``: ``k`` a power of two near the largest ``|M_ij|`` (an
    exact division; detached) where that lies outside the range whose squares are normal and
    finite (``out``; that of :func:`torchlie._coeffs.rescaled`), 1 elsewhere.  ``M`` as a
    tensor or its nine planes, row by row (taken by one transposing copy of the strided block:
    element-wise operations on the block itself are several times slower)."""
    e = _components.planes(M, 9)
    m = _coeffs.largest(e)  # a max is exact: the same in any order
    lo, hi = _coeffs._PLAIN[m.dtype]
    out = ((m < lo) & (m > 0.0)) | ((m > hi) & (m < float("inf")))
    k = torch.where(out, _coeffs.power_of_two(m), 1.0)
    return [x / k for x in e], k, out


def _scale(M: Tensor | Sequence[Tensor]) -> tuple[Tensor, Tensor]:
    """``(s, 1/s)`` of the linear block ``M = s R``, ``s = |M|_F / sqrt(3)``, from the squares of
    ``M / k`` (:func:`_scaled_entries`): every finite scale, without the round trip through
    :func:`_log_scale2` (``exp`` of a rounded log costs ``log2 |log s|`` bits)."""
    e, k, _ = _scaled_entries(M)
    r = torch.sqrt(_coeffs.dot(e, e) / 3.0)
    return r * k, 1.0 / r / k


def _log_scale2(M: Tensor | Sequence[Tensor]) -> Tensor:
    """``2 sigma = log(|M|_F^2 / 3)`` of the linear block ``M = s R``: near ``s = 1`` as
    ``log1p`` of ``(sum (M_ii - 1)(M_ii + 1) + sum_(i != j) M_ij^2) / 3`` (exact at the
    identity, where ``|M|^2 - 3`` cancels), elsewhere as ``log`` of the sum of squares (double
    where: no branch sees an argument out of its range).  Entry by entry (planes).

    Where the largest ``|M_ij|`` lies outside the range whose squares are normal and finite,
    the squares are those of ``M / k`` (:func:`_scaled_entries`) and ``2 log(k)`` is added
    back: every finite scale has its log.  Elsewhere ``k = 1``, the same values as without it."""
    e, k, out = _scaled_entries(M)
    d, off = (e[0], e[4], e[8]), (e[1], e[2], e[3], e[5], e[6], e[7])
    o2 = _coeffs.dot(off, off)
    sq = o2 + _coeffs.dot(d, d)
    x = (_coeffs.dot([v - 1.0 for v in d], [v + 1.0 for v in d]) + o2) / 3.0
    near = (x.abs() < 0.5) & ~out
    return torch.where(
        near,
        torch.log1p(torch.where(near, x, 0.0)),
        torch.log(torch.where(near, 1.0, sq / 3.0)) + 2.0 * torch.log(k),
    )


#: The power of two that ``V rho`` and ``V^-1 t`` take on the products of ``phi`` and the vector
#: (:func:`torchlie._rodrigues.jl_components`): room for ``|phi| |rho|`` up to 64 times the
#: largest float (a reduced angle is below 11), while the coefficients that give it back stay
#: finite wherever ``e^sigma`` is (``|B|, |C| <= e^sigma / sigma`` for large ``sigma``; the
#: coefficients of ``V^-1`` are of order ``|sigma|`` at most).
_SHRINK = 2.0**-6


def _poly_planes(
    a: Tensor, b: Tensor, c: Tensor, phi: Tensor | Sequence[Tensor], v: Tensor
) -> list[Tensor]:
    """The planes of ``(a I + b hat(phi) + c hat(phi)^2) v``, as
    ``(a - c t2) v + b (phi x v) + c (phi . v) phi`` (coefficients of shape ``(...)``;
    ``phi`` as a tensor or its planes)."""
    x = phi.unbind(-1) if isinstance(phi, Tensor) else phi
    t2 = _coeffs.dot(x, x)
    return _rodrigues.jl_components(x, v.unbind(-1), a - c * t2, b, c, shrink=_SHRINK)


def _poly(a: Tensor, b: Tensor, c: Tensor, phi: Tensor, v: Tensor) -> Tensor:
    """``(a I + b hat(phi) + c hat(phi)^2) v`` (coefficients of shape ``(...)``)."""
    return _layout.interleave(_poly_planes(a, b, c, phi, v))


def _coefficients(
    fn, sigma: Tensor, phi: Tensor | Sequence[Tensor], differentiable: bool = True
) -> tuple[Tensor, Tensor, Tensor]:
    out = fn(_coeffs.wide(sigma), _coeffs.theta2(phi), sigma.dtype, differentiable)
    return tuple(x.to(sigma.dtype) for x in out)  # type: ignore[return-value]


def _huge(phi: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """``(phi', lam, big, u)``: the rotation vectors reduced where their angle is beyond the
    range of the formulas (:func:`torchlie._coeffs.reduction`; ``phi`` itself elsewhere, with
    derivative ``lam I + (1 - lam) u u^T`` there), and the unit axis ``u`` where ``big``, 0
    elsewhere (so that the limit terms built from it are finite everywhere).

    ``V = A I + B hat(phi) + C hat(phi)^2`` tends to ``A u u^T`` as the angle grows (``B theta``
    and ``A - C theta^2`` are the parts of ``E1(sigma + i theta)``, of order ``A / theta``), so
    where the angle is known only to more than ``2 pi``, ``V(phi) = lam V(phi') + (1 - lam) A u
    u^T`` to rounding, as so3's ``Jl`` (``V`` at ``sigma = 0``)."""
    x = phi.unbind(-1)
    f = _coeffs.reduction_planes(x)
    lam, big, u = f
    red = torch.stack(_coeffs.reduced_planes(x, f), dim=-1)
    return red, lam, big, torch.stack([torch.where(big, c, 0.0) for c in u], dim=-1)


def _exp(xi: Tensor) -> Tensor:
    rho, phi, sigma = xi[..., :3], xi[..., 3:6], xi[..., 6]
    # forward-only coefficients where nothing can differentiate them
    diff = torch.compiler.is_compiling() or transforms_active() or needs_graph((xi,))
    # angles beyond the formulas' range reduced, V(phi) = lam V(phi') + (1 - lam) A u u^T
    # there (see _huge), with u u^T = phi' phi'^T / |phi'|^2
    red, lam, big = _coeffs.sim3_reduced(phi.unbind(-1))
    A, B, C = _coefficients(_coeffs.sim3_v, sigma, red, diff)
    t2 = _coeffs.dot(red, red)
    v = rho.unbind(-1)
    t = _rodrigues.jl_components(red, v, A - C * t2, B, C, shrink=_SHRINK)  # as _poly_planes
    # (phi' . rho at _SHRINK times its size, given back in the sum: finite for every rho)
    k = (1.0 - lam) * A * _coeffs.dot(red, v, _SHRINK) / torch.where(big, t2, 1.0)
    k = torch.where(big, k, 0.0)
    up = 1.0 / _SHRINK
    s = torch.exp(sigma)
    o, top = _se3_kernels._top_outputs(s)  # the columns of the result, where they are written
    t = [
        torch.where(big, fma(c * lam, k, r, value=up), c, out=top[i][3])
        for i, (c, r) in enumerate(zip(t, red, strict=True))
    ]
    # so3.exp's entries: through its Function where they are differentiated, as planes elsewhere
    # (from red, which is its forward's reduced_planes_of(phi) where nothing is differentiated)
    R = so3._ExpMapFn(phi).flatten(-2).unbind(-1) if diff else so3._exp_entries(red)
    rows = [
        [torch.mul(s, R[3 * i + j], out=top[i][j]) for j in range(3)] + [t[i]] for i in range(3)
    ]
    return _se3_kernels._stack_top([e for row in rows for e in row], out=o)


_exp_blocked = blocked(_exp, (1,))


def _inverse(T: Tensor) -> Tensor:
    """``[[M^-1, -M^-1 t], [0, 1]]`` with ``M^-1 = (M^T / s) / s`` (``s^2`` may not be
    representable where ``s`` is).  The translation's products are those of
    ``compose(T^-1, T)``, whose translation is then exactly 0; where they overflow (a sum of
    infinities) it is ``-(R^T t) / s`` instead, rotated before it is scaled."""
    r = _scale(_lin(T))[1][..., None, None]
    Rt = _lin(T).transpose(-1, -2) * r
    Mi = Rt * r
    t = -_components.mv(Mi, _trans(T))
    t = torch.where(t.isfinite(), t, -_components.mv(Rt, _trans(T)) * r[..., 0])
    return _components.homogeneous(Mi, t)


def _compose(A: Tensor, B: Tensor) -> Tensor:
    M = _lin(A) @ _lin(B)
    t = _components.mv(_lin(A), _trans(B)) + _trans(A)
    batch = M.shape[:-2]
    return _components.homogeneous(M, t.expand(*batch, 3))


def _blocks(T: Tensor, inverse: bool) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """``(s, 1/s, R, t)`` of ``T = [[s R, t], [0, 1]]`` (:func:`_scale`), or of ``T^-1``:
    ``(1/s, s, R^T, -R^T t / s)``."""
    s, r = _scale(_lin(T))
    R = _lin(T) * r[..., None, None]
    if not inverse:
        return s, r, R, _trans(T)
    Rt = R.transpose(-1, -2)
    return r, s, Rt, -_components.mv(Rt, _trans(T)) * r[..., None]


def _between_blocks(A: tuple[Tensor, ...], B: tuple[Tensor, ...]) -> Tensor:
    """``A^-1 B`` from the blocks of ``A`` and ``B`` (:func:`_blocks`): the relative scale and
    rotation apart, ``(s_B / s_A) (I + R_A^T (R_B - R_A))`` and ``R_A^T (t_B - t_A) / s_A``.
    Where ``A == B`` the ratio is exactly 1 and the differences exactly 0: the result is
    exactly the identity (``M_A^-1 M_B`` is neither exactly symmetric nor of norm ``sqrt(3)``,
    and :func:`log` reads the scale from that norm)."""
    sA, rA, RA, tA = A
    sB, _, RB, tB = B
    eye = _layout.constant(((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)), RA)
    R = RA.transpose(-1, -2) @ (RB - RA) + eye
    M = R * (sB / sA)[..., None, None]
    t = _components.mtv(RA, tB - tA) * rA[..., None]
    return _components.homogeneous(M, t.expand(*M.shape[:-2], 3))


#: ``A^-1 B`` and ``A B^-1``, exactly the identity where ``A == B``
_between, _right_between = _components.between_kernels(_blocks, _between_blocks)


def _hat(xi: Tensor) -> Tensor:
    rho, phi, sigma = xi[..., :3], xi[..., 3:6], xi[..., 6:]
    eye = torch.eye(3, dtype=xi.dtype, device=xi.device)
    top = torch.cat((_components.hat(phi) + sigma[..., None] * eye, rho.unsqueeze(-1)), dim=-1)
    return torch.cat((top, torch.zeros_like(top[..., :1, :])), dim=-2)


def _rows(*blocks: tuple[Tensor, ...]) -> Tensor:
    return torch.cat([torch.cat(row, dim=-1) for row in blocks], dim=-2)


def _adjoint(T: Tensor) -> Tensor:
    M, t = _lin(T), _trans(T)
    R = M * _scale(M)[1][..., None, None]
    z31, z13 = torch.zeros_like(t).unsqueeze(-1), torch.zeros_like(t).unsqueeze(-2)
    one = torch.ones_like(t[..., :1]).unsqueeze(-1)
    return _rows(
        (M, _components.hat(t) @ R, -t.unsqueeze(-1)),
        (torch.zeros_like(R), R, z31),
        (z13, z13, one),
    )


def _ad(xi: Tensor) -> Tensor:
    rho, phi, sigma = xi[..., :3], xi[..., 3:6], xi[..., 6:]
    P = _components.hat(phi)
    eye = torch.eye(3, dtype=xi.dtype, device=xi.device)
    z31, z13 = torch.zeros_like(rho).unsqueeze(-1), torch.zeros_like(rho).unsqueeze(-2)
    z11 = torch.zeros_like(sigma).unsqueeze(-1)
    return _rows(
        (P + sigma[..., None] * eye, _components.hat(rho), -rho.unsqueeze(-1)),
        (torch.zeros_like(P), P, z31),
        (z13, z13, z11),
    )


def _mat(a: Tensor, b: Tensor, c: Tensor, P: Tensor) -> Tensor:
    """``a I + b P + c P^2`` (coefficients of shape ``(...)``, ``P = hat(phi)``)."""
    eye = torch.eye(3, dtype=P.dtype, device=P.device)
    P2 = _components.mm(P, P)
    return a[..., None, None] * eye + b[..., None, None] * P + c[..., None, None] * P2


def _couplings(
    rho: Tensor, phi: Tensor, sigma: Tensor, t2: Tensor, blocks: tuple[Tensor, ...]
) -> tuple[Tensor, Tensor]:
    """The couplings ``Q`` and ``w`` of :func:`_jl` from ``blocks = (P, R, V, Jp, t, Q, w)``
    (``hat(phi)``, ``hat(rho)``, ``V``, so3's ``Jl``, the translation ``V rho``, and the
    couplings' difference forms): those where ``sigma < SIM3_Q_SIGMA``, the solves of
    :func:`torchlie._coeffs.sim3_coupling` from there on (the differences cancel by about
    ``sigma``)."""
    P, R, V, Jp, t, Q, w = blocks
    p, k, r, use = _coeffs.sim3_coupling(sigma, t2)
    k = k[..., None, None]
    Z = _components.mm(V, R) - _components.mm(R, Jp)
    S = p[0][..., None, None] * Z
    for c in p[1:]:
        Z = (_components.mm(P, Z) - _components.mm(Z, P)) * k
        S = S + c[..., None, None] * Z
    y = t - rho
    inv_s = p[0][..., None]
    along = _coeffs.dot(phi.unbind(-1), y.unbind(-1))[..., None] * inv_s
    ws = (inv_s * torch.linalg.cross(phi, y) - y - inv_s * along * phi) * r[..., None]
    return torch.where(use[..., None, None], S, Q), torch.where(use[..., None], ws, w)


class _VRho(NamedTuple):
    """What the derivatives of ``V rho = A rho + B phi x rho + C phi x (phi x rho)`` in
    ``(phi, sigma)`` are made of (planes): ``rho``, ``phi``, ``phi x rho``, ``phi x (phi x
    rho)`` and the coefficients and partials of :func:`torchlie._coeffs.sim3_v_partials`
    (``(A, B, C, A_s, B_s, C_s, B_t, C_t)``)."""

    rho: Sequence[Tensor]
    phi: Sequence[Tensor]
    pr: Sequence[Tensor]
    ppr: Sequence[Tensor]
    parts: Sequence[Tensor]


def _vrho(rho: Sequence[Tensor], phi: Sequence[Tensor], parts: Sequence[Tensor]) -> _VRho:
    pr = _components.cross_planes(phi, rho)
    return _VRho(rho, phi, pr, _components.cross_planes(phi, pr), parts)


def _vrho_jvp(d: _VRho, v: Sequence[Tensor], s: Tensor | None) -> list[Tensor]:
    """``d(V rho)/dphi v + d(V rho)/dsigma s`` (planes; ``s`` None: the first term)::

    d/dphi v = B (v x rho) - C ((phi x rho) x v + phi x (rho x v))
               + 2 (phi . v) (B_t (phi x rho) + C_t (phi x (phi x rho)))
    d/dsigma = A_s rho + B_s (phi x rho) + C_s (phi x (phi x rho))"""
    _, B, C, As, Bs, Cs, Bt, Ct = d.parts
    vr = _components.cross_planes(v, d.rho)
    prv = _components.cross_planes(d.pr, v)
    pvr = _components.cross_planes(d.phi, vr)  # phi x (v x rho) = -phi x (rho x v)
    k = 2.0 * _coeffs.dot(d.phi, v)
    out = [
        fma(fma(B * a, C, pvr_i, value=1.0), C, prv_i, value=-1.0) + k * (Bt * pr_i + Ct * ppr_i)
        for a, prv_i, pvr_i, pr_i, ppr_i in zip(vr, prv, pvr, d.pr, d.ppr, strict=True)
    ]
    if s is None:
        return out
    return [
        o + s * fma(fma(As * r, Bs, pr_i), Cs, ppr_i)
        for o, r, pr_i, ppr_i in zip(out, d.rho, d.pr, d.ppr, strict=True)
    ]


def _vrho_vjp(d: _VRho, u: Sequence[Tensor]) -> tuple[Tensor, list[Tensor]]:
    """The transpose of :func:`_vrho_jvp`: ``(d(V rho)/dsigma . u, d(V rho)/dphi^T u)``::

    d/dphi^T u = B (rho x u) - C (u x (phi x rho) + (u x phi) x rho)
                 + 2 (B_t u . (phi x rho) + C_t u . (phi x (phi x rho))) phi"""
    _, B, C, As, Bs, Cs, Bt, Ct = d.parts
    upr, uppr = _coeffs.dot(u, d.pr), _coeffs.dot(u, d.ppr)
    ru = _components.cross_planes(d.rho, u)
    upr_x = _components.cross_planes(u, d.pr)
    upr_r = _components.cross_planes(_components.cross_planes(u, d.phi), d.rho)
    k = 2.0 * fma(Bt * upr, Ct, uppr)
    j_phi = [
        fma(B * a, C, b + c, value=-1.0) + k * p
        for a, b, c, p in zip(ru, upr_x, upr_r, d.phi, strict=True)
    ]
    j_sigma = fma(fma(As * _coeffs.dot(u, d.rho), Bs, upr), Cs, uppr)
    return j_sigma, j_phi


def _vrho_at(rho: Tensor, phi: Tensor, sigma: Tensor) -> _VRho:
    """:class:`_VRho` at ``_SHRINK rho`` (the derivatives are linear in ``rho``: the caller
    gives the factor back; their factors such as ``u . (phi x rho)`` may exceed the largest
    float where the derivative does not), in float64 for float32 input."""
    phi, sigma = _coeffs.wide(phi), _coeffs.wide(sigma)
    parts = _coeffs.sim3_v_partials(sigma, _coeffs.theta2(phi), rho.dtype)
    return _vrho((_coeffs.wide(rho) * _SHRINK).unbind(-1), phi.unbind(-1), parts)


def _jl(xi: Tensor, inverse: bool = False) -> Tensor:
    """``Jl(xi) = int_0^1 exp(s ad(xi)) ds`` (or its inverse) in closed form, by blocks::

        Jl = [[V, Q, W], [0, so3 Jl(phi), 0], [0, 0, 1]]
        Q = d(V rho)/dphi + hat(t) so3 Jl(phi),  W = d(V rho)/dsigma - t,  t = V rho

    (``Exp(xi + d) = Exp(Jl d) Exp(xi)`` read on the translation), with ``V = A I + B P +
    C P^2``, ``P = hat(phi)``, so ``d(V rho)/dphi = -B hat(rho) - C (hat(phi x rho) +
    P hat(rho)) + 2 (B_t (phi x rho) + C_t (phi x (phi x rho))) phi^T`` and ``d(V rho)/dsigma -
    t = (A_s - A) rho + (B_s - B) (phi x rho) + (C_s - C) (phi x (phi x rho))``: coefficients
    of :func:`torchlie._coeffs.sim3_v_partials` (all in float64 for float32 input).  From
    ``sigma = 1`` on, where these differences cancel by about ``sigma``, ``Q`` and ``W`` are
    the solutions of ``sigma Q + P Q - Q P = V hat(rho) - hat(rho) so3 Jl(phi)`` and ``(sigma
    I + P) W = rho - V rho`` instead (:func:`_couplings`).  The inverse is block triangular:
    ``[[V^-1, -V^-1 Q Jl(phi)^-1, -V^-1 W], [0, Jl(phi)^-1, 0], [0, 0, 1]]``.
    """
    dtype = xi.dtype  # evaluated in float64 for float32: the products of up to three
    xi = _coeffs.wide(xi)  # components of phi overflow float32 below the angle reduction's range
    rho, phi, sigma = xi[..., :3], xi[..., 3:6], xi[..., 6]
    if not inverse:  # the inverse is meant for angles below 2 pi
        phi, lam, big, u = _huge(phi)
    t2 = _coeffs.theta2(phi)
    parts = _coeffs.sim3_v_partials(sigma, t2, xi.dtype)
    A, B, C, As, Bs, Cs = parts[:6]  # B_t, C_t enter through _vrho_jvp
    Aw, Bw, Cw = As - A, Bs - B, Cs - C  # -E2(z)'s: they cancel by about sigma, see below
    d = _vrho(rho.unbind(-1), phi.unbind(-1), parts)
    e = torch.eye(3, dtype=xi.dtype, device=xi.device).unbind(-1)  # d(V rho)/dphi by columns
    dphi = torch.stack(
        [torch.stack(_vrho_jvp(d, [x.expand_as(sigma) for x in c], None), -1) for c in e], -1
    )
    P, R = _components.hat(phi), _components.hat(rho)
    pr, ppr = torch.stack(d.pr, -1), torch.stack(d.ppr, -1)
    t = _poly(A, B, C, phi, rho)
    W = Aw[..., None] * rho + Bw[..., None] * pr + Cw[..., None] * ppr
    z31, z13 = torch.zeros_like(rho).unsqueeze(-1), torch.zeros_like(rho).unsqueeze(-2)
    one = torch.ones_like(sigma)[..., None, None]
    V = _mat(A, B, C, P)
    Jp = _rodrigues.jac_matrix(phi, "left")
    Q = dphi + _components.mm(_components.hat(t), Jp)
    Q, W = _couplings(rho, phi, sigma, t2, (P, R, V, Jp, t, Q, W))
    if not inverse:
        J = _rows(
            (V, Q, W.unsqueeze(-1)),
            (torch.zeros_like(P), Jp, z31),
            (z13, z13, one),
        )
        # beyond the formulas' angles: lam Jl(xi') + (1 - lam) times the limit of Jl, whose
        # blocks are V -> A u u^T, so3's Jl -> u u^T, W -> (A_s - A) u (u . rho), Q -> 0
        uu = u.unsqueeze(-1) * u.unsqueeze(-2)
        ur = (Aw * _coeffs.dot(u.unbind(-1), rho.unbind(-1)))[..., None] * u
        L = _rows(
            (A[..., None, None] * uu, torch.zeros_like(P), ur.unsqueeze(-1)),
            (torch.zeros_like(P), uu, z31),
            (z13, z13, one),
        )
        lam = lam[..., None, None]
        return torch.where(big[..., None, None], lam * J + (1.0 - lam) * L, J).to(dtype)
    Jpi = _rodrigues.jac_matrix(phi, "left_inv")
    a, b, c = _coefficients(_coeffs.sim3_v_inv, sigma, phi)
    Vi = _mat(a, b, c, P)
    Qi = -_components.mm(Vi, _components.mm(Q, Jpi))
    return _rows(
        (Vi, Qi, -_components.mv(Vi, W).unsqueeze(-1)),
        (torch.zeros_like(P), Jpi, z31),
        (z13, z13, one),
    ).to(dtype)


# ----------------------------------------------------------------------------------------------
# log: a custom Function (gradient of log o projection, as se3.log)
# ----------------------------------------------------------------------------------------------


def _log_forward(T: Tensor) -> Tensor:
    e, t = _components.planes(_lin(T), 9), _trans(T)
    sigma = 0.5 * _log_scale2(e)
    r = torch.exp(-sigma)
    phi = _rotation_matrix.log_and_cot([x * r for x in e])[0]
    a, b, c = _coefficients(_coeffs.sim3_v_inv, sigma, phi, False)
    return _layout.interleave((*_poly_planes(a, b, c, phi, t), *phi, sigma))


# The right Jacobian, by block rows: Exp(xi) Exp(eps) with eps = Jr(xi) dxi moves t by
# M eps_rho and M by M (hat(eps_phi) + eps_sigma I), while Exp(xi + dxi) moves t by
# V drho + d(V rho)/d(phi, sigma) (dphi, dsigma), so
#     Jr(xi) = [[M^-1 V, M^-1 d(V rho)/dphi, M^-1 d(V rho)/dsigma], [0, so3 Jr(phi), 0], [0, 0, 1]]
# and Jr^-1 and Jr^-T need V^-1 (closed form), so3's Jl^-1 and one product with the derivative
# of V rho (_vrho_vjp and _vrho_jvp, from the coefficients' partials the Jacobians use;
# differentiable, so double backward differentiates the same formula).


def _log_backward(saved: tuple[Tensor, ...], g: Tensor) -> tuple[Tensor]:
    # h = Jr(xi)^-T g: u = V^-T g_rho (= M^-T h_rho), h_phi = so3 Jl(phi)^-1 (g_phi - J_phi^T u),
    # h_sigma = g_sigma - J_sigma^T u with J = d(V rho)/d(phi, sigma); the tangent part of the
    # ambient gradient is G_t = u, G_M = M^-T (hat(h_phi)/2 + h_sigma I/3), M^-T = M / s^2.
    T, xi = saved
    rho, phi, sigma = xi[..., :3], xi[..., 3:6], xi[..., 6]
    a, b, c = _coefficients(_coeffs.sim3_v_inv, sigma, phi)
    u = _poly(a, -b, c, phi, g[..., :3])
    # J (linear in rho) at _SHRINK rho, given back in the differences: J^T u is finite wherever
    # the gradient is, though its factors (u . (phi x rho), ...) may exceed the largest float
    j_sigma, j_phi = _vrho_vjp(_vrho_at(rho, phi, sigma), _coeffs.wide(u).unbind(-1))
    j_sigma, j_phi = j_sigma.to(u.dtype), torch.stack(j_phi, -1).to(u.dtype)
    diff = torch.is_grad_enabled()
    up = 1.0 / _SHRINK
    h_phi = _rodrigues.jl_apply(
        phi, torch.sub(g[..., 3:6], j_phi, alpha=up), inverse=True, differentiable=diff
    )
    h_sigma = torch.sub(g[..., 6], j_sigma, alpha=up)
    r = torch.exp(-sigma)[..., None, None]
    Mt = _lin(T) * r * r
    eye = torch.eye(3, dtype=T.dtype, device=T.device)
    H = 0.5 * _components.hat(h_phi)
    G_M = Mt @ (H + (h_sigma / 3.0)[..., None, None] * eye)
    if diff:  # differentiated: the gradient off the group too (so3._log_grad), N = M / s
        N = _lin(T) * r
        G_M = G_M - _components.polar_backward_terms(N, H, _components.gram_defect(N)) * r
    top = torch.cat((G_M, u.unsqueeze(-1)), dim=-1)
    return (torch.nn.functional.pad(top, (0, 0, 0, 1)),)


def _log_jvp(saved: tuple[Tensor, ...], dT: Tensor) -> Tensor:
    # Jr dxi = d with d = (M^-1 dt, vee(skew(X)), tr(X)/3), X = M^-1 dM:
    # dsigma = d_sigma, dphi = so3 Jr(phi)^-1 d_phi, drho = V^-1 (dt - J (dphi, dsigma)).
    T, xi = saved
    rho, phi, sigma = xi[..., :3], xi[..., 3:6], xi[..., 6]
    r = torch.exp(-sigma)[..., None, None]
    Mi = _lin(T).transpose(-1, -2) * r * r
    X = Mi @ _lin(dT)
    d_sigma = X.diagonal(dim1=-2, dim2=-1).sum(-1) / 3.0
    # the rotation's tangent as that of the polar factor of M / s (so3._log_jvp)
    E = _components.gram_defect(_lin(T) * r)
    d_phi = _rodrigues.jl_apply(phi, _components.polar_tangent(X, E), sign=-1.0, inverse=True)
    # J (dphi, dsigma) at _SHRINK rho as in _log_backward
    v, s = _coeffs.wide(d_phi).unbind(-1), _coeffs.wide(d_sigma)
    jv = torch.stack(_vrho_jvp(_vrho_at(rho, phi, sigma), v, s), -1).to(rho.dtype)
    a, b, c = _coefficients(_coeffs.sim3_v_inv, sigma, phi)
    d_rho = _poly(a, b, c, phi, torch.sub(_trans(dT), jv, alpha=1.0 / _SHRINK))
    return torch.cat((d_rho, d_phi, d_sigma.unsqueeze(-1)), dim=-1)


# one pass over blocks of the batch (the one driver), the backward's planes kept in cache
_log_backward_blocked = blocked(lambda *t: _log_backward(t[:-1], t[-1]), (2, 1, 1))

_LogFn = CustomFunction(
    "Sim3Log",
    forward=_log_forward,
    save=lambda inputs, out: (inputs[0], out),
    backward=lambda saved, g: _log_backward_blocked(*saved, g),
    jvp=_log_jvp,
    event_dims=(2,),
)


# ----------------------------------------------------------------------------------------------
# hat / vee, exp / log
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def hat(xi: Float[Tensor, "*b 7"]) -> Float[Tensor, "*b 4 4"]:
    """The 4x4 matrix ``[[hat(phi) + sigma I, rho], [0, 0]]`` of ``xi = (rho, phi, sigma)``.

    Example:
        >>> hat(torch.tensor([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 0.5]))
        tensor([[ 0.5000, -6.0000,  5.0000,  1.0000],
                [ 6.0000,  0.5000, -4.0000,  2.0000],
                [-5.0000,  4.0000,  0.5000,  3.0000],
                [ 0.0000,  0.0000,  0.0000,  0.0000]])
    """
    x, dtype = _checks.tensor(xi, _NAME + "hat", "xi", (7,))
    return _checks.out(_hat(x), dtype)


@_checks.float32_exact
def vee(Xi: Float[Tensor, "*b 4 4"]) -> Float[Tensor, "*b 7"]:
    """Inverse of :func:`hat`: ``(Xi[:3, 3], so3.vee(Xi[:3, :3]), trace(Xi[:3, :3]) / 3)``.

    The bottom row is ignored.

    Example:
        >>> vee(hat(torch.tensor([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 0.5])))
        tensor([1.0000, 2.0000, 3.0000, 4.0000, 5.0000, 6.0000, 0.5000])
    """
    x, dtype = _checks.tensor(Xi, _NAME + "vee", "Xi", (4, 4))
    B = _lin(x)
    tr = B.diagonal(dim1=-2, dim2=-1).sum(-1, keepdim=True) / 3.0
    return _checks.out(torch.cat((_trans(x), _components.vee(B), tr), dim=-1), dtype)


@_checks.float32_exact
def exp(xi: Float[Tensor, "*b 7"]) -> Float[Tensor, "*b 4 4"]:
    """Similarity of ``xi = (rho, phi, sigma)``: ``[[e^sigma so3.exp(phi), V rho], [0, 1]]``.

    ``V = A I + B hat(phi) + C hat(phi)^2`` with the coefficients of
    :func:`torchlie._coeffs.sim3_v`: closed forms away from 0 and a series in
    ``sigma + i theta`` near it, where they cancel (double where: every derivative is finite,
    at 0 and pi included; autograd differentiates the formula, any order, forward mode too).

    Example:
        >>> T = exp(torch.tensor([1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]))
        >>> T[:3, 3]
        tensor([1., 0., 0.])
    """
    x, dtype = _checks.tensor(xi, _NAME + "exp", "xi", (7,))
    return _checks.out(_exp_blocked(x), dtype)


@_checks.float32_exact
def log(T: Float[Tensor, "*b 4 4"]) -> Float[Tensor, "*b 7"]:
    """Tangent ``(rho, phi, sigma)`` of ``T``: ``sigma = log(|M|_F / sqrt(3))`` of the linear
    block ``M = s R``, ``phi = so3.log(M / s)`` and ``rho = V^-1 t``.

    The rotation angle ``|phi|`` is in ``[0, pi]``; at exactly pi the axis sign follows
    :func:`torchlie.so3.log`'s rule.  The bottom row of ``T`` is not read.

    Gradient meaning (as :func:`torchlie.se3.log`): the backward pass is the gradient of ``log``
    composed with the projection of ``M`` onto the scaled rotations: along the tangent
    directions ``T hat(d)`` it is the exact derivative ``Jr(xi)^-1 d``; the directions ``M S``
    (``S`` symmetric and traceless) and the bottom row get zero.  The forward pass agrees with
    it to first order, so plain ``gradcheck`` on a raw matrix passes; finite at ``theta = pi``.
    Double backward and forward mode are supported.

    Example:
        >>> xi = torch.tensor([1.0, 2.0, 3.0, 0.1, 0.2, 0.3, 0.5])
        >>> torch.allclose(log(exp(xi)), xi, atol=1e-6)
        True
    """
    x, dtype = _checks.tensor(T, _NAME + "log", "T", (4, 4))
    return _checks.out(_LogFn(x), dtype)


# ----------------------------------------------------------------------------------------------
# Group operations
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def compose(T1: Float[Tensor, "*b1 4 4"], T2: Float[Tensor, "*b2 4 4"]) -> Float[Tensor, "*b 4 4"]:
    """``T1 @ T2`` from blocks (``M1 M2``, ``M1 t2 + t1``); batch shapes broadcast.

    Example:
        >>> T = exp(torch.tensor([1.0, 0.0, 0.0, 0.0, 0.0, 0.5, 0.2]))
        >>> U = exp(torch.tensor([2.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.4]))
        >>> torch.allclose(compose(T, T), U)
        True
    """
    a, b, dtype, _ = _checks.pair(_NAME + "compose", T1, T2, "T1", "T2", (4, 4), (4, 4))
    return _checks.out(_compose(a, b), dtype)


@_checks.float32_exact
def inverse(T: Float[Tensor, "*b 4 4"]) -> Float[Tensor, "*b 4 4"]:
    """``T^-1 = [[R^T / s, -R^T t / s], [0, 1]]``.

    Example:
        >>> T = exp(torch.tensor([1.0, 2.0, 3.0, 0.1, 0.2, 0.3, 0.5]))
        >>> torch.allclose(compose(inverse(T), T), torch.eye(4), atol=1e-6)
        True
    """
    x, dtype = _checks.tensor(T, _NAME + "inverse", "T", (4, 4))
    return _checks.out(_inverse(x), dtype)


@_checks.float32_exact
def act(T: Float[Tensor, "*b1 4 4"], points: Float[Tensor, "*b2 3"]) -> Float[Tensor, "*b 3"]:
    """Transform points: ``s R p + t`` (batch shapes broadcast).

    Example:
        >>> T = from_srt(torch.tensor(2.0), torch.eye(3), torch.tensor([1.0, 0.0, 0.0]))
        >>> act(T, torch.tensor([1.0, 1.0, 1.0]))
        tensor([3., 2., 2.])
    """
    x, p, dtype, _ = _checks.pair(_NAME + "act", T, points, "T", "points", (4, 4), (3,))
    return _checks.out(_components.mv(_lin(x), p) + _trans(x), dtype)


@_checks.float32_exact
def adjoint(T: Float[Tensor, "*b 4 4"]) -> Float[Tensor, "*b 7 7"]:
    """Adjoint ``Ad_T = [[s R, hat(t) R, -t], [0, R, 0], [0, 0, 1]]``: ``T Exp(xi) T^-1 =
    Exp(Ad_T xi)``.

    Example:
        >>> T = from_srt(torch.tensor(2.0), torch.eye(3), torch.zeros(3))
        >>> adjoint(T).diagonal()
        tensor([2., 2., 2., 1., 1., 1., 1.])
    """
    x, dtype = _checks.tensor(T, _NAME + "adjoint", "T", (4, 4))
    return _checks.out(_adjoint(x), dtype)


@_checks.float32_exact
def ad(xi: Float[Tensor, "*b 7"]) -> Float[Tensor, "*b 7 7"]:
    """Small adjoint ``[[hat(phi) + sigma I, hat(rho), -rho], [0, hat(phi), 0], [0, 0, 0]]``.

    ``ad(x) y = vee(hat(x) hat(y) - hat(y) hat(x))`` and ``adjoint(exp(x)) = matrix_exp(ad(x))``.

    Example:
        >>> ad(torch.tensor([1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]))[:3, 6]
        tensor([-1., -0., -0.])
    """
    x, dtype = _checks.tensor(xi, _NAME + "ad", "xi", (7,))
    return _checks.out(_ad(x), dtype)


def _jac(fn: str, xi: Tensor, inv: bool, sign: float) -> Tensor:
    x, dtype = _checks.tensor(xi, _NAME + fn, "xi", (7,))
    return _checks.out(_jl(x if sign > 0 else -x, inv), dtype)


@_checks.float32_exact
def jac_left(xi: Float[Tensor, "*b 7"]) -> Float[Tensor, "*b 7 7"]:
    """Left Jacobian ``Jl(xi) = int_0^1 exp(s ad(xi)) ds``: ``Exp(xi + d) ~= Exp(Jl(xi) d)
    Exp(xi)``.

    In closed form by blocks: ``V`` (of :func:`exp`) on ``rho``, ``so3.jac_left(phi)`` on
    ``phi``, 1 on ``sigma``, and the couplings of the translation to ``phi`` and ``sigma``
    from the partial derivatives of ``V``'s coefficients (see the Lie page of the docs).

    Example:
        >>> torch.allclose(jac_left(torch.zeros(7)), torch.eye(7))
        True
    """
    return _jac("jac_left", xi, False, 1.0)


@_checks.float32_exact
def jac_right(xi: Float[Tensor, "*b 7"]) -> Float[Tensor, "*b 7 7"]:
    """Right Jacobian ``Jr(xi) = Jl(-xi)``: ``Exp(xi + d) ~= Exp(xi) Exp(Jr(xi) d)``.

    Example:
        >>> xi = torch.tensor([1.0, 2.0, 3.0, 0.1, 0.2, 0.3, 0.5])
        >>> torch.allclose(jac_left(xi), adjoint(exp(xi)) @ jac_right(xi), atol=1e-5)
        True
    """
    return _jac("jac_right", xi, False, -1.0)


@_checks.float32_exact
def jac_left_inv(xi: Float[Tensor, "*b 7"]) -> Float[Tensor, "*b 7 7"]:
    """``Jl(xi)^-1``, finite for rotation angles below ``2 pi``: the closed-form block
    inverse (``V^-1`` and ``so3.jac_left_inv`` on the diagonal).

    Example:
        >>> xi = torch.tensor([1.0, 2.0, 3.0, 0.1, 0.2, 0.3, 0.5])
        >>> torch.allclose(jac_left_inv(xi) @ jac_left(xi), torch.eye(7), atol=1e-5)
        True
    """
    return _jac("jac_left_inv", xi, True, 1.0)


@_checks.float32_exact
def jac_right_inv(xi: Float[Tensor, "*b 7"]) -> Float[Tensor, "*b 7 7"]:
    """``Jr(xi)^-1 = Jl(-xi)^-1``; ``jac_right_inv(log(T))`` is the Jacobian ``J_Log(T)_T``.

    Example:
        >>> xi = torch.tensor([1.0, 2.0, 3.0, 0.1, 0.2, 0.3, 0.5])
        >>> torch.allclose(jac_right_inv(xi) @ jac_right(xi), torch.eye(7), atol=1e-5)
        True
    """
    return _jac("jac_right_inv", xi, True, -1.0)


# ----------------------------------------------------------------------------------------------
# Construction, validation, conversions
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def identity(
    *batch: int, dtype: torch.dtype | None = None, device: torch.device | str | None = None
) -> Float[Tensor, "*batch 4 4"]:
    """Identity similarities of shape ``(*batch, 4, 4)``.

    Example:
        >>> identity(2).shape
        torch.Size([2, 4, 4])
    """
    _, dtype = _checks.factory(_NAME + "identity", batch, dtype)
    return torch.eye(4, dtype=dtype, device=device).expand(*batch, 4, 4).clone()


@_checks.float32_exact
def random(
    *batch: int,
    generator: torch.Generator | None = None,
    dtype: torch.dtype | None = None,
    device: torch.device | str | None = None,
) -> Float[Tensor, "*batch 4 4"]:
    """Random similarities: Haar-uniform rotations, translations ``N(0, I)``, log scales
    ``N(0, 1)``.

    Example:
        >>> T = random(4, generator=torch.Generator().manual_seed(0))
        >>> bool(is_valid(T).all())
        True
    """
    compute, dtype = _checks.factory(_NAME + "random", batch, dtype)
    R = so3.random(*batch, generator=generator, dtype=compute, device=device)
    t = torch.randn(*batch, 3, generator=generator, dtype=compute, device=device)
    sigma = torch.randn((*batch, 1), generator=generator, dtype=compute, device=device)[..., 0]
    return _checks.out(_components.homogeneous(torch.exp(sigma)[..., None, None] * R, t), dtype)


@_checks.float32_exact
def is_valid(T: Float[Tensor, "*b 4 4"], atol: float | None = None) -> Bool[Tensor, "*b"]:
    """Per element: finite, ``M / s`` a rotation (:func:`torchlie.so3.is_valid`, ``s`` the
    scale of :func:`scale`), ``s > 0`` and bottom row ``(0, 0, 0, 1)``, each within ``atol``
    (default ``100 * eps`` of the dtype, ``4 * eps`` for half).

    Example:
        >>> is_valid(torch.stack((identity(), -identity())))
        tensor([ True, False])
    """
    x, _ = _checks.tensor(T, _NAME + "is_valid", "T", (4, 4))
    tol = _checks.tolerance(atol, _NAME + "is_valid", "atol", T.dtype)
    s = _scale(_lin(x))[0]
    pos = s > 0
    R = _lin(x) / torch.where(pos, s, 1.0)[..., None, None]
    last = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=x.dtype, device=x.device)
    bottom = (x[..., 3, :] - last).abs().amax(dim=-1) <= tol
    finite = torch.isfinite(x).flatten(-2).all(dim=-1)
    return so3.is_valid(R, atol=tol) & pos & bottom & finite


@_checks.float32_exact
def from_srt(
    s: Float[Tensor, "*b1"], R: Float[Tensor, "*b2 3 3"], t: Float[Tensor, "*b3 3"]
) -> Float[Tensor, "*b 4 4"]:
    """Similarity ``[[s R, t], [0, 1]]`` from a scale, a rotation matrix and a translation
    (batch shapes broadcast).

    Example:
        >>> from_srt(torch.tensor(2.0), torch.eye(3), torch.tensor([1.0, 2.0, 3.0]))[:3]
        tensor([[2., 0., 0., 1.],
                [0., 2., 0., 2.],
                [0., 0., 2., 3.]])
    """
    fn = _NAME + "from_srt"
    r, v, dtype, _ = _checks.pair(fn, R, t, "R", "t", (3, 3), (3,))
    k, _ = _checks.tensor(s, fn, "s", ())
    _checks.same_dtype(fn, s=s, R=R)
    batch = _checks.batch_broadcast(fn, (k.shape, "s"), (r.shape[:-2], "R"), (v.shape[:-1], "t"))
    M = (k[..., None, None] * r).expand(*batch, 3, 3)
    return _checks.out(_components.homogeneous(M, v.expand(*batch, 3)), dtype)


@_checks.float32_exact
def to_srt(
    T: Float[Tensor, "*b 4 4"],
) -> tuple[Float[Tensor, "*b"], Float[Tensor, "*b 3 3"], Float[Tensor, "*b 3"]]:
    """Scale, rotation and translation ``(s, R, t)`` of ``T`` (``s = |M|_F / sqrt(3)``,
    ``R = M / s``).

    Example:
        >>> s, R, t = to_srt(from_srt(torch.tensor(2.0), torch.eye(3), torch.ones(3)))
        >>> s
        tensor(2.)
    """
    x, dtype = _checks.tensor(T, _NAME + "to_srt", "T", (4, 4))
    s, R = _scale_rotation(x)
    return _checks.out(s, dtype), _checks.out(R, dtype), _checks.out(_trans(x).clone(), dtype)


def _scale_rotation(T: Tensor) -> tuple[Tensor, Tensor]:
    """``(s, R)`` of ``T = [[s R, t], [0, 1]]`` (:func:`to_srt`)."""
    s = _scale(_lin(T))[0]
    return s, _lin(T) / s[..., None, None]


@_checks.float32_exact
def from_se3(T: Float[Tensor, "*b1 4 4"], s: Float[Tensor, "*b2"]) -> Float[Tensor, "*b 4 4"]:
    """Similarity ``[[s R, t], [0, 1]]`` from an SE(3) pose ``[[R, t], [0, 1]]`` and a scale.

    Example:
        >>> from_se3(torch.eye(4), torch.tensor(3.0)).diagonal()
        tensor([3., 3., 3., 1.])
    """
    fn = _NAME + "from_se3"
    x, dtype = _checks.tensor(T, fn, "T", (4, 4))
    k, _ = _checks.tensor(s, fn, "s", ())
    _checks.same_dtype(fn, T=T, s=s)
    batch = _checks.batch_broadcast(fn, (x.shape[:-2], "T"), (k.shape, "s"))
    M = (k[..., None, None] * _lin(x)).expand(*batch, 3, 3)
    return _checks.out(_components.homogeneous(M, _trans(x).expand(*batch, 3)), dtype)


@_checks.float32_exact
def from_pos_quat_scale(x: Float[Tensor, "*b 8"]) -> Float[Tensor, "*b 4 4"]:
    """Similarity from an 8-vector ``(tx, ty, tz, qw, qx, qy, qz, s)``: translation, a wxyz
    quaternion and the scale (:func:`torchlie.se3.from_pos_quat` with the scale appended;
    PyPose's ``Sim3`` holds the same numbers with the quaternion in xyzw order).

    ``[[s R, t], [0, 1]]`` with ``R`` the rotation of ``q / |q|`` (as
    :func:`torchlie.quaternion.to_matrix`; a zero quaternion gives a NaN linear block for that
    element, its translation as given).  The scale is taken as it is (see
    :meth:`torchlie.Sim3.from_pos_quat_scale` for a check that it is positive).

    Example:
        >>> from_pos_quat_scale(torch.tensor([1.0, 2.0, 3.0, 1.0, 0.0, 0.0, 0.0, 2.0]))[:3]
        tensor([[2., 0., 0., 1.],
                [0., 2., 0., 2.],
                [0., 0., 2., 3.]])
    """
    v, dtype = _checks.tensor(x, _NAME + "from_pos_quat_scale", "x", (8,))
    M = v[..., 7, None, None] * _rotation_matrix.from_quaternion(v[..., 3:7])
    return _checks.out(_components.homogeneous(M, v[..., :3]), dtype)


@_checks.float32_exact
def to_pos_quat_scale(T: Float[Tensor, "*b 4 4"]) -> Float[Tensor, "*b 8"]:
    """8-vector ``(t, q, s)`` of a similarity: translation, the canonical wxyz unit quaternion
    of its rotation (:func:`torchlie.quaternion.from_matrix`, ``w >= 0``) and its scale
    (:func:`scale`).

    Example:
        >>> x = torch.tensor([1.0, 2.0, 3.0, 0.0, 1.0, 0.0, 0.0, 0.5])
        >>> to_pos_quat_scale(from_pos_quat_scale(x))
        tensor([1.0000, 2.0000, 3.0000, 0.0000, 1.0000, 0.0000, 0.0000, 0.5000])
    """
    x, dtype = _checks.tensor(T, _NAME + "to_pos_quat_scale", "T", (4, 4))
    s, R = _scale_rotation(x)
    q = _rotation_matrix.to_quaternion(R)
    return _checks.out(torch.cat((_trans(x), q, s[..., None]), dim=-1), dtype)


@_checks.float32_exact
def scale(T: Float[Tensor, "*b 4 4"]) -> Float[Tensor, "*b"]:
    """The scale ``s = |M|_F / sqrt(3)`` of the linear block ``M = s R``.

    Example:
        >>> scale(exp(torch.tensor([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])))
        tensor(2.7183)
    """
    x, dtype = _checks.tensor(T, _NAME + "scale", "T", (4, 4))
    return _checks.out(_scale(_lin(x))[0], dtype)


# ----------------------------------------------------------------------------------------------
# Metrics and interpolation
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def interpolate(
    T0: Float[Tensor, "*b1 4 4"], T1: Float[Tensor, "*b2 4 4"], t: Float[Tensor, "*b3"] | float
) -> Float[Tensor, "*b 4 4"]:
    """Geodesic interpolation ``T0 Exp(t Log(T0^-1 T1))`` (``t`` broadcasts with the batch).

    ``t = 0`` gives ``T0`` and ``t = 1`` gives ``T1``; the log scale moves linearly in ``t``.
    ``t`` is a tensor of the dtype of ``T0`` or numbers.

    Example:
        >>> T1 = exp(torch.tensor([2.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.8]))
        >>> mid = exp(torch.tensor([1.0, 0.0, 0.0, 0.0, 0.0, 0.5, 0.4]))
        >>> torch.allclose(interpolate(identity(), T1, 0.5), mid, atol=1e-6)
        True
    """
    fn = _NAME + "interpolate"
    a, b, dtype, _ = _checks.pair(fn, T0, T1, "T0", "T1", (4, 4), (4, 4))
    t = _checks.real(t, fn, "t", a, ("T0", T0))
    _checks.batch_broadcast(fn, (a.shape[:-2], "T0"), (b.shape[:-2], "T1"), (t.shape, "t"))
    xi = _LogFn(_between(a, b))
    return _checks.out(_compose(a, _exp(t.unsqueeze(-1) * xi)), dtype)


@_checks.float32_exact
def distance(
    T1: Float[Tensor, "*b1 4 4"], T2: Float[Tensor, "*b2 4 4"]
) -> tuple[Float[Tensor, "*b"], Float[Tensor, "*b"], Float[Tensor, "*b"]]:
    """``(angle, translation, log_scale)``: the rotation angle of ``R1^T R2`` in ``[0, pi]``,
    ``|t2 - t1|`` and ``|log(s2 / s1)|``, each in its own units (no weighting imposed; the zero
    subgradient where one is not differentiable, so gradients are always finite).

    Example:
        >>> T2 = from_srt(torch.tensor(2.0), so3.exp(torch.tensor([0.0, 0.3, 0.0])), torch.ones(3))
        >>> [round(float(d), 4) for d in distance(identity(), T2)]
        [0.3, 1.7321, 0.6931]
    """
    a, b, dtype, batch = _checks.pair(_NAME + "distance", T1, T2, "T1", "T2", (4, 4), (4, 4))
    la, lb = _log_scale2(_lin(a)), _log_scale2(_lin(b))
    Ra = _lin(a) * torch.exp(-0.5 * la)[..., None, None]
    Rb = _lin(b) * torch.exp(-0.5 * lb)[..., None, None]
    angle = _rotation_matrix.angle(Ra.transpose(-1, -2) @ Rb)
    trans = _coeffs.norm(_trans(b) - _trans(a)).expand(batch)
    ds = 0.5 * (lb - la)
    ds = _coeffs.norm(ds.unsqueeze(-1)).expand(batch)
    angle = angle.expand(batch)
    return _checks.out(angle, dtype), _checks.out(trans, dtype), _checks.out(ds, dtype)


# ----------------------------------------------------------------------------------------------
# Lie-group operations and their Jacobians
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def rplus(T: Float[Tensor, "*b1 4 4"], xi: Float[Tensor, "*b2 7"]) -> Float[Tensor, "*b 4 4"]:
    """Right plus ``T (+) xi = T Exp(xi)`` (batch shapes broadcast).

    Example:
        >>> rplus(identity(), torch.tensor([1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]))[:3, 3]
        tensor([1., 0., 0.])
    """
    x, v, dtype, _ = _checks.pair(_NAME + "rplus", T, xi, "T", "xi", (4, 4), (7,))
    return _checks.out(_compose(x, _exp(v)), dtype)


@_checks.float32_exact
def rminus(T1: Float[Tensor, "*b1 4 4"], T0: Float[Tensor, "*b2 4 4"]) -> Float[Tensor, "*b 7"]:
    """Right minus ``T1 (-) T0 = Log(T0^-1 T1)``, so that ``rplus(T0, rminus(T1, T0)) == T1``;
    exactly 0 where ``T1 == T0`` (see :func:`between`).

    Example:
        >>> xi = torch.tensor([1.0, 2.0, 3.0, 0.1, 0.2, 0.3, 0.5])
        >>> T0 = exp(torch.tensor([0.5, 0.0, 0.0, 0.0, 1.0, 0.0, -0.2]))
        >>> torch.allclose(rminus(rplus(T0, xi), T0), xi, atol=1e-5)
        True
    """
    a, b, dtype, _ = _checks.pair(_NAME + "rminus", T1, T0, "T1", "T0", (4, 4), (4, 4))
    return _checks.out(_LogFn(_between(b, a)), dtype)


@_checks.float32_exact
def lplus(T: Float[Tensor, "*b1 4 4"], xi: Float[Tensor, "*b2 7"]) -> Float[Tensor, "*b 4 4"]:
    """Left plus ``Exp(xi) T`` (the perturbation is expressed in the world frame).

    Example:
        >>> T = from_srt(torch.tensor(1.0), torch.eye(3), torch.tensor([1.0, 0.0, 0.0]))
        >>> lplus(T, torch.tensor([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]))[:3, 3]
        tensor([2.7183, 0.0000, 0.0000])
    """
    x, v, dtype, _ = _checks.pair(_NAME + "lplus", T, xi, "T", "xi", (4, 4), (7,))
    return _checks.out(_compose(_exp(v), x), dtype)


@_checks.float32_exact
def lminus(T1: Float[Tensor, "*b1 4 4"], T0: Float[Tensor, "*b2 4 4"]) -> Float[Tensor, "*b 7"]:
    """Left minus ``Log(T1 T0^-1)``, so that ``lplus(T0, lminus(T1, T0)) == T1``; exactly 0
    where ``T1 == T0`` (``T1 T0^-1`` is taken as ``between(T1^-1, T0^-1)``).

    Example:
        >>> xi = torch.tensor([1.0, 2.0, 3.0, 0.1, 0.2, 0.3, 0.5])
        >>> T0 = exp(torch.tensor([0.5, 0.0, 0.0, 0.0, 1.0, 0.0, -0.2]))
        >>> torch.allclose(lminus(lplus(T0, xi), T0), xi, atol=1e-5)
        True
    """
    a, b, dtype, _ = _checks.pair(_NAME + "lminus", T1, T0, "T1", "T0", (4, 4), (4, 4))
    return _checks.out(_LogFn(_right_between(a, b)), dtype)


@_checks.float32_exact
def between(T0: Float[Tensor, "*b1 4 4"], T1: Float[Tensor, "*b2 4 4"]) -> Float[Tensor, "*b 4 4"]:
    """Relative similarity ``T0^-1 T1``, with the relative scale and rotation apart:
    ``[[(s1 / s0) (I + R0^T (R1 - R0)), R0^T (t1 - t0) / s0], [0, 1]]``, exactly the identity
    where ``T0 == T1`` (so that its :func:`log`, which reads the scale from the norm of the
    linear block, is exactly 0 there).

    Example:
        >>> T0 = from_srt(torch.tensor(2.0), torch.eye(3), torch.tensor([1.0, 0.0, 0.0]))
        >>> T1 = from_srt(torch.tensor(2.0), torch.eye(3), torch.tensor([1.0, 2.0, 0.0]))
        >>> between(T0, T1)[:3, 3]
        tensor([0., 1., 0.])
    """
    a, b, dtype, _ = _checks.pair(_NAME + "between", T0, T1, "T0", "T1", (4, 4), (4, 4))
    return _checks.out(_between(a, b), dtype)


def _eye7(batch: torch.Size, like: Tensor) -> Tensor:
    return torch.eye(7, dtype=like.dtype, device=like.device).expand(*batch, 7, 7).clone()


@_checks.float32_exact
def jac_compose(
    T1: Float[Tensor, "*b1 4 4"], T2: Float[Tensor, "*b2 4 4"]
) -> tuple[Float[Tensor, "*b 7 7"], Float[Tensor, "*b 7 7"]]:
    """Jacobians of ``T1 T2``: ``(J_T1T2_T1, J_T1T2_T2) = (Ad(T2)^-1, I)``.

    Example:
        >>> T2 = exp(torch.tensor([1.0, 2.0, 3.0, 0.1, 0.2, 0.3, 0.5]))
        >>> J1, J2 = jac_compose(identity(), T2)
        >>> torch.allclose(J1, adjoint(inverse(T2)), atol=1e-6)
        True
    """
    a, b, dtype, batch = _checks.pair(_NAME + "jac_compose", T1, T2, "T1", "T2", (4, 4), (4, 4))
    J1 = _adjoint(_inverse(b)).expand(*batch, 7, 7).clone()
    return _checks.out(J1, dtype), _checks.out(_eye7(batch, a), dtype)


@_checks.float32_exact
def jac_inverse(T: Float[Tensor, "*b 4 4"]) -> Float[Tensor, "*b 7 7"]:
    """Jacobian ``J_Tinv_T = -Ad(T)``: ``(T Exp(d))^-1 = T^-1 Exp(-Ad(T) d)``.

    Example:
        >>> torch.equal(jac_inverse(identity()), -torch.eye(7))
        True
    """
    x, dtype = _checks.tensor(T, _NAME + "jac_inverse", "T", (4, 4))
    return _checks.out(-_adjoint(x), dtype)


@_checks.float32_exact
def jac_act(
    T: Float[Tensor, "*b1 4 4"], points: Float[Tensor, "*b2 3"]
) -> tuple[Float[Tensor, "*b 3 7"], Float[Tensor, "*b 3 3"]]:
    """Jacobians of ``T p``: ``(J_Tp_T, J_Tp_p) = ([M, -M hat(p), M p], M)`` with ``M = s R``.

    Example:
        >>> JT, Jp = jac_act(identity(), torch.tensor([1.0, 2.0, 3.0]))
        >>> JT[:, 6]
        tensor([1., 2., 3.])
    """
    x, p, dtype, batch = _checks.pair(_NAME + "jac_act", T, points, "T", "points", (4, 4), (3,))
    M = _lin(x).expand(*batch, 3, 3)
    JT = torch.cat((M, -(M @ _components.hat(p)), _components.mv(M, p).unsqueeze(-1)), dim=-1)
    return _checks.out(JT, dtype), _checks.out(M.clone(), dtype)


@_checks.float32_exact
def jac_rplus(
    T: Float[Tensor, "*b1 4 4"], xi: Float[Tensor, "*b2 7"]
) -> tuple[Float[Tensor, "*b 7 7"], Float[Tensor, "*b 7 7"]]:
    """Jacobians of ``T Exp(xi)``: ``(J_T, J_xi) = (Ad(Exp(xi))^-1, Jr(xi))``.

    Example:
        >>> JT, Jxi = jac_rplus(identity(), torch.zeros(7))
        >>> torch.allclose(JT, torch.eye(7)) and torch.allclose(Jxi, torch.eye(7))
        True
    """
    x, v, dtype, batch = _checks.pair(_NAME + "jac_rplus", T, xi, "T", "xi", (4, 4), (7,))
    v = v.expand(*batch, 7)
    return _checks.out(_adjoint(_exp(-v)), dtype), _checks.out(_jl(-v), dtype)


@_checks.float32_exact
def jac_rminus(
    T1: Float[Tensor, "*b1 4 4"], T0: Float[Tensor, "*b2 4 4"]
) -> tuple[Float[Tensor, "*b 7 7"], Float[Tensor, "*b 7 7"]]:
    """Jacobians of ``xi = Log(T0^-1 T1)``: ``(J_xi_T1, J_xi_T0) = (Jr(xi)^-1, -Jl(xi)^-1)``.

    Example:
        >>> J1, J0 = jac_rminus(identity(), identity())
        >>> torch.allclose(J1, torch.eye(7)) and torch.allclose(J0, -torch.eye(7))
        True
    """
    a, b, dtype, _ = _checks.pair(_NAME + "jac_rminus", T1, T0, "T1", "T0", (4, 4), (4, 4))
    xi = _LogFn(_between(b, a))
    J1 = _jl(-xi, True)
    J0 = -_jl(xi, True)
    return _checks.out(J1, dtype), _checks.out(J0, dtype)


@_checks.float32_exact
def jac_between(
    T0: Float[Tensor, "*b1 4 4"], T1: Float[Tensor, "*b2 4 4"]
) -> tuple[Float[Tensor, "*b 7 7"], Float[Tensor, "*b 7 7"]]:
    """Jacobians of ``T0^-1 T1``: ``(J_T0, J_T1) = (-Ad(T1^-1 T0), I)``.

    Example:
        >>> J0, J1 = jac_between(identity(), identity())
        >>> torch.equal(J0, -torch.eye(7)) and torch.equal(J1, torch.eye(7))
        True
    """
    a, b, dtype, batch = _checks.pair(_NAME + "jac_between", T0, T1, "T0", "T1", (4, 4), (4, 4))
    J0 = -_adjoint(_between(b, a)).expand(*batch, 7, 7)
    return _checks.out(J0, dtype), _checks.out(_eye7(batch, a), dtype)
