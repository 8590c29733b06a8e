"""The Jacobians of SE(3) in closed form: the block ``Q(rho, phi)`` (Barfoot's, eq. 7.86) applied
to vectors or formed as a matrix, at every magnitude of ``phi``, and ``Jl(xi)``, ``Jl(xi)^-1``
built on it and on :mod:`torchlie._rodrigues` (see the formulas in :mod:`torchlie.se3`).

Apart from :mod:`torchlie.se3` so that the exp and log kernels (:mod:`torchlie._se3_kernels`)
take ``Q`` from below that module, as the public Jacobians and the inverse kinematics do.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from . import _coeffs, _layout, _rodrigues
from ._autograd import fma
from ._components import blocks, cross_planes, planes


def _q_coeffs(phi: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """``(k1, k2, k3, k4)`` of :func:`q_components` for ``phi`` itself
    (:func:`torchlie._coeffs.q_series`), in ``phi``'s dtype."""
    return _in_dtype(_coeffs.q_series(_coeffs.theta2(phi)), phi.dtype)


def _in_dtype(ks: tuple[Tensor, ...], dtype: torch.dtype) -> tuple[Tensor, ...]:
    return tuple(k.to(dtype) for k in ks)


def jl_and_q_coefficients(
    phi: Sequence[Tensor], parts: str, differentiable: bool
) -> tuple[tuple[Tensor, ...], tuple[Tensor, ...]]:
    """The coefficients ``parts`` of :data:`torchlie._coeffs.RODRIGUES` and ``(k1, k2, k3, k4)``
    of :func:`q_components` of the angle of the planes ``phi``, in their dtype: differentiable
    (:func:`torchlie._coeffs.rodrigues`, :func:`torchlie._coeffs.q_series`), or forward-only for
    the plain backward passes, all from one ``sin`` and ``cos`` (for float32, ``Q``'s from
    Rodrigues' ``b`` and ``c``: :func:`torchlie._coeffs.q_values`)."""
    dtype = phi[0].dtype
    half = None if differentiable else _coeffs.half_angle(phi)
    extra = "bc" if dtype == torch.float32 and not differentiable else ""
    values = _coeffs.rodrigues(phi, parts + extra, differentiable, half)
    if differentiable:
        ks = _coeffs.q_series(_coeffs.theta2(phi))
    else:
        ks = _coeffs.q_plain(dtype, half[0], *(values[len(parts) :] or (None, None)))
    return _in_dtype(values[: len(parts)], dtype), _in_dtype(ks, dtype)


def q_components(
    rho: Sequence[Tensor],
    x: Sequence[Tensor],
    v: Sequence[Tensor],
    k1: Tensor,
    k2: Tensor,
    k3: Tensor,
    k4: Tensor,
) -> list[Tensor]:
    """Components of ``Q(rho, phi) v`` (the top-right block of the left Jacobian), from
    components, with cross products only::

        Q v = rho^ v / 2 + k1 (x^ rho^ + rho^ x^) v + k2 x^ rho^ x^ v
              + k3 (x^ x^ rho^ + rho^ x^ x^) v + k4 (x^ rho^ x^ x^ + x^ x^ rho^ x^) v

    with ``x = phi`` and the coefficients of :func:`_q_coeffs`, or ``x`` the unit axis and
    those of :func:`torchlie._coeffs.q_far`.  With ``a = x^ v``, ``b = x^ a`` and
    ``r(y) = rho^ y``, the terms group as ``r(v)/2 + k1 r(a) + k3 r(b) + x^ (k1 r(v) + k2 r(a)
    + k4 r(b) + x^ (k3 r(v) + k4 r(a)))``.
    """
    a = cross_planes(x, v)
    b = cross_planes(x, a)
    rv, ra, rb = cross_planes(rho, v), cross_planes(rho, a), cross_planes(rho, b)
    inner = cross_planes(x, [fma(k3 * p, k4, q) for p, q in zip(rv, ra, strict=True)])
    mid = [
        fma(fma(fma(i, k1, p), k2, q), k4, r) for p, q, r, i in zip(rv, ra, rb, inner, strict=True)
    ]
    outer = cross_planes(x, mid)
    return [
        fma(fma(o.add(p, alpha=0.5), k1, q), k3, r)
        for p, q, r, o in zip(rv, ra, rb, outer, strict=True)
    ]


def q_apply(rho: Tensor, x: Tensor, v: Tensor, ks: tuple[Tensor, ...] | None = None) -> Tensor:
    """``Q(rho, phi) v`` (batch shapes broadcast): :func:`q_components` on planar copies, with
    ``x = phi`` and its :func:`_q_coeffs` (``ks=None``), or ``x, ks`` of :func:`_q_form`."""
    ks = _q_coeffs(x) if ks is None else ks
    return _layout.interleave(q_components(planes(rho, 3), planes(x, 3), planes(v, 3), *ks))


def _q_matrix(rho: Tensor, phi: Tensor) -> Tensor:
    """``Q(rho, phi)`` as a matrix at every angle (:func:`_q_form`): :func:`q_apply` on the
    three unit vectors."""
    eye = torch.eye(3, dtype=rho.dtype, device=rho.device).expand(*rho.shape[:-1], 3, 3)
    x, ks = _q_form(phi.unsqueeze(-2))
    cols = q_apply(rho.unsqueeze(-2), x, eye, ks)  # row j = Q e_j
    return cols.transpose(-1, -2)


def _q_form(phi: Tensor) -> tuple[Tensor, tuple[Tensor, Tensor, Tensor, Tensor]]:
    """``(x, (k1, k2, k3, k4))`` of :func:`q_components` for ``Q(., phi)`` at every magnitude
    of ``phi``: ``phi`` and :func:`_q_coeffs` up to ``|phi|^2 = Q_FAR_T2``, the unit axis and
    :func:`torchlie._coeffs.q_far` above it (no powers of the angle, which overflow in the
    derivatives), with the angle reduced modulo ``2 pi`` for ``sin`` and ``cos`` beyond the
    range of the formulas (:func:`torchlie._coeffs.reduction`, as so3's Jacobians).  Double
    where: each form sees only its own elements.  Derivatives are those of ``Q`` at the angle
    (``d t / d phi = u``, as the reduced angle's).
    """
    r, lam, u = _coeffs.reduction(phi)
    t2 = _coeffs.theta2(r)  # the reduced angle's (|phi|^2 where not reduced)
    reduced = lam[..., 0] < 1.0
    far = (t2 > _coeffs.Q_FAR_T2) | reduced
    ang = torch.where(far, t2, 1.0).sqrt()
    t = torch.where(reduced, _coeffs.dot(u.to(t2.dtype), phi.to(t2.dtype)), ang)
    axis = torch.where(reduced.unsqueeze(-1), u, phi / t.to(phi.dtype).unsqueeze(-1))
    far_ks = _coeffs.q_far(t, torch.sin(ang), torch.cos(ang))
    near_ks = _coeffs.q_series(torch.where(far, 0.0, t2))
    ks = tuple(torch.where(far, a, b) for a, b in zip(far_ks, near_ks, strict=True))
    return torch.where(far.unsqueeze(-1), axis, phi), _in_dtype(ks, phi.dtype)


def jac_left(xi: Tensor) -> Tensor:
    """``Jl(xi) = [[A, Q], [0, A]]`` as a 6x6 matrix (no input checks)."""
    rho, phi = xi[..., :3], xi[..., 3:]
    A = _rodrigues.jac_matrix(phi, "left")
    return blocks(A, _q_matrix(rho, phi), torch.zeros_like(A), A)


def jac_left_inv(xi: Tensor) -> Tensor:
    """``Jl(xi)^-1 = [[A^-1, -A^-1 Q A^-1], [0, A^-1]]`` as a 6x6 matrix (no input checks)."""
    rho, phi = xi[..., :3], xi[..., 3:]
    Ai = _rodrigues.jac_matrix(phi, "left_inv")
    B = -(Ai @ _q_matrix(rho, phi) @ Ai)
    return blocks(Ai, B, torch.zeros_like(Ai), Ai)


def jl_inv_apply(xi: Tensor, v: Tensor) -> Tensor:
    """``Jl(xi)^-1 v`` without a matrix."""
    rho, phi = xi[..., :3], xi[..., 3:]
    u_phi = _rodrigues.jl_apply(phi, v[..., 3:], inverse=True)
    u_rho = _rodrigues.jl_apply(phi, v[..., :3] - q_apply(rho, phi, u_phi), inverse=True)
    return torch.cat((u_rho, u_phi), dim=-1)
