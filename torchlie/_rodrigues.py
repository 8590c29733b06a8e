"""SO(3) in Rodrigues' form, from components: the coefficients, the entries of ``Exp(w)``, and
``Jl(w)``, ``Jr(w)`` and their inverses applied to vectors or formed as matrices.

Each is ``a I + b hat(w) + c w w^T`` (or applied to a vector, ``a v + b (w x v) + c (w . v) w``)
with coefficients of :mod:`torchlie._coeffs`; the ``*_values`` forms take forward-only
coefficients (backward passes without ``create_graph``), the others differentiable ones.
:mod:`torchlie.so3` and :mod:`torchlie.se3` build their exp, log and Jacobians on these.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from . import _coeffs, _layout
from ._autograd import fma
from ._components import planes

# ----------------------------------------------------------------------------------------------
# Coefficients and the entries of Exp
# ----------------------------------------------------------------------------------------------


def coefficients(
    w: Tensor | Sequence[Tensor], parts: str = "abcd"
) -> tuple[tuple[Tensor, ...], tuple[Tensor, ...]]:
    """Planes ``(x, y, z)`` of ``w`` (or ``w`` given as planes) and the coefficients ``parts`` of
    :func:`_coeffs.rodrigues_values` in ``w``'s dtype (forward-only)."""
    xyz = planes(w, 3)
    values = _coeffs.rodrigues_values(xyz, parts)
    return xyz, tuple(v.to(xyz[0].dtype) for v in values)


def exp_entries(
    xyz: Sequence[Tensor],
    a: Tensor,
    b: Tensor,
    d: Tensor,
    out: Sequence[Tensor | None] = (None,) * 9,
) -> list[Tensor]:
    """The 9 entries (row by row) of ``d I + a hat(w) + b w w^T`` from components (written to
    ``out``)."""
    x, y, z = xyz
    bx, by, bz = b * x, b * y, b * z
    ax, ay, az = a * x, a * y, a * z
    bxy, bxz, byz = bx * y, bx * z, by * z
    o, add, sub = out, torch.add, torch.sub
    return [
        fma(d, bx, x, out=o[0]), sub(bxy, az, out=o[1]), add(bxz, ay, out=o[2]),
        add(bxy, az, out=o[3]), fma(d, by, y, out=o[4]), sub(byz, ax, out=o[5]),
        sub(bxz, ay, out=o[6]), add(byz, ax, out=o[7]), fma(d, bz, z, out=o[8]),
    ]  # fmt: skip


# ----------------------------------------------------------------------------------------------
# Jl(w) and Jl(w)^-1 applied to vectors
# ----------------------------------------------------------------------------------------------


def jl_components(
    xyz: Sequence[Tensor],
    v: Sequence[Tensor],
    a: Tensor,
    b: Tensor,
    c: Tensor,
    out: Sequence[Tensor | None] = (None,) * 3,
) -> list[Tensor]:
    """Components of ``a v + b (w x v) + c (w . v) w`` (``w = xyz``, ``v`` by components;
    written to ``out``)."""
    x, y, z = xyz
    p, q, r = v
    cwv = c * fma(fma(x * p, y, q), z, r)
    result = []
    for vi, wi, (w1, v2), (w2, v1), o in (
        (p, x, (y, r), (z, q), out[0]),
        (q, y, (z, p), (x, r), out[1]),
        (r, z, (x, q), (y, p), out[2]),
    ):
        cross = fma(w1 * v2, w2, v1, value=-1.0)
        result.append(fma(fma(a * vi, b, cross), cwv, wi, out=o))
    return result


def jl_apply_values(w: Tensor, v: tuple[Tensor, ...], sign: float = 1.0) -> Tensor:
    """``Jl(w) v`` (``sign=1``) or ``Jr(w) v`` (``sign=-1``) from components; forward-only.

    ``Jl(w) v = a v + b (w x v) + c (w . v) w`` with :func:`torchlie._coeffs.rodrigues_values`
    (not differentiable: backward passes without ``create_graph`` only).
    """
    xyz, (a, b, c) = coefficients(w, "abc")
    o = _layout.outputs(xyz[0], 3)
    return _layout.interleave(jl_components(xyz, v, a, b if sign > 0 else -b, c, o), o)


def jl_inv_apply_values(
    w: Tensor | Sequence[Tensor], v: Tensor | Sequence[Tensor]
) -> tuple[Tensor, Tensor, Tensor]:
    """Components of ``Jl(w)^-1 v = e v - (w x v)/2 + D (w . v) w`` for ``w`` of angle at most
    pi (a log's); forward-only.  ``w`` and ``v`` as ``(..., 3)`` tensors or as their three
    components."""
    wc = planes(w, 3)
    e, d = (t.to(wc[0].dtype) for t in _coeffs.jl_inv_values(wc))
    out = jl_components(wc, planes(v, 3), e, e.new_full((), -0.5), d)
    return out[0], out[1], out[2]


def jl_apply(w: Tensor, v: Tensor, sign: float = 1.0) -> Tensor:
    """``Jl(w) v`` (``sign=1``) or ``Jr(w) v = Jl(-w) v`` (``sign=-1``), without a matrix."""
    t2 = _coeffs.theta2(w, keepdim=True)
    b, c = _coeffs.cosc(t2).to(w.dtype), _coeffs.sinc3(t2).to(w.dtype)
    wxv = torch.linalg.cross(w, v, dim=-1)
    wxwxv = torch.linalg.cross(w, wxv, dim=-1)
    return v + sign * b * wxv + c * wxwxv


def jl_inv_apply(w: Tensor, v: Tensor, sign: float = 1.0) -> Tensor:
    """``Jl(w)^-1 v`` (``sign=1``) or ``Jr(w)^-1 v`` (``sign=-1``), without a matrix."""
    t2 = _coeffs.theta2(w, keepdim=True)
    d = _coeffs.jinv(t2).to(w.dtype)
    wxv = torch.linalg.cross(w, v, dim=-1)
    wxwxv = torch.linalg.cross(w, wxv, dim=-1)
    return v - sign * 0.5 * wxv + d * wxwxv


# ----------------------------------------------------------------------------------------------
# As matrices
# ----------------------------------------------------------------------------------------------


def jac_matrix(w: Tensor, kind: str) -> Tensor:
    """``Jl``, ``Jr``, ``Jl^-1`` or ``Jr^-1`` of ``w`` (``kind`` = ``"left"``, ``"right"``,
    ``"left_inv"``, ``"right_inv"``) as a matrix, from components (no input checks).

    ``Jl`` and ``Jr`` of angles beyond the range of the formulas from those of the reduced
    angle, ``Jl(w) = lam Jl(w') + (1 - lam) u u^T`` (:func:`torchlie._coeffs.reduction`);
    the inverses are meant for angles below ``2 pi``.
    """
    if kind in ("left", "right"):
        r, lam, u = _coeffs.reduction(w)
        J = _jac_formula(r, kind)
        lam = lam.unsqueeze(-1)
        huge = lam * J + (1.0 - lam) * (u.unsqueeze(-1) * u.unsqueeze(-2))
        return torch.where(lam < 1.0, huge, J)
    return _jac_formula(w, kind)


def _jac_formula(w: Tensor, kind: str) -> Tensor:
    """:func:`jac_matrix` by the formula of each kind."""
    # I + b hat + c hat^2 = (1 - c t2) I + b hat + c w w^T
    t2 = _coeffs.theta2(w)
    if kind in ("left", "right"):
        b = _coeffs.cosc(t2) * (1.0 if kind == "left" else -1.0)
        c = _coeffs.sinc3(t2)
    else:
        b = torch.full_like(t2, -0.5 if kind == "left_inv" else 0.5)
        c = _coeffs.jinv(t2)
    a = (1.0 - c * t2).to(w.dtype)
    return _abc_matrix(a, b.to(w.dtype), c.to(w.dtype), w)


def _abc_matrix(a: Tensor, b: Tensor, c: Tensor, w: Tensor) -> Tensor:
    """``a I + b hat(w) + c w w^T`` from components (``a, b, c`` of shape ``w.shape[:-1]``)."""
    x, y, z = w.unbind(-1)
    cx, cy, cz = c * x, c * y, c * z
    bx, by, bz = b * x, b * y, b * z
    cxy, cxz, cyz = cx * y, cx * z, cy * z
    return _layout.interleave(
        (
            a + cx * x, cxy - bz, cxz + by,
            cxy + bz, a + cy * y, cyz - bx,
            cxz - by, cyz + bx, a + cz * z,
        ),
    ).unflatten(-1, (3, 3))  # fmt: skip
