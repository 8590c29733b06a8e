"""SO(3) in Rodrigues' form, from components: the coefficients, the entries of ``Exp(w)``, and
``Jl(w)``, ``Jr(w)`` and their inverses applied to vectors or formed as matrices.

Each is ``a I + b hat(w) + c w w^T`` (or applied to a vector, ``a v + b (w x v) + c (w . v) w``)
with the coefficients of :data:`torchlie._coeffs.RODRIGUES`: one formula, whose coefficients are
forward-only in the forward passes and the plain backward passes, and differentiable wherever
the result may be differentiated.  :mod:`torchlie.so3` and :mod:`torchlie.se3` build their exp,
log and Jacobians on these.
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
    w: Tensor | Sequence[Tensor], parts: str = "abcd", differentiable: bool = False
) -> tuple[tuple[Tensor, ...], tuple[Tensor, ...]]:
    """Planes ``(x, y, z)`` of ``w`` (or ``w`` given as planes) and the coefficients ``parts`` of
    :data:`torchlie._coeffs.RODRIGUES` in ``w``'s dtype: forward-only (the forward passes and the
    plain backward passes) or ``differentiable`` (:func:`torchlie._coeffs.rodrigues`)."""
    xyz = planes(w, 3)
    values = _coeffs.rodrigues(xyz, parts, differentiable)
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

#: The power of two that :func:`jl_components` takes on the products of ``w`` and ``v``: room
#: for ``|w| |v|`` up to 256 times the largest float (a reduced angle is below 11; a vector of
#: the largest floats is ``sqrt(3)`` times them), at the cost of the products within 256 times
#: the smallest normal number, whose terms lose bits to gradual underflow.
SHRINK = 2.0**-8


def jl_components(
    xyz: Sequence[Tensor],
    v: Sequence[Tensor],
    a: Tensor,
    b: Tensor,
    c: Tensor,
    out: Sequence[Tensor | None] = (None,) * 3,
    shrink: float = SHRINK,
) -> list[Tensor]:
    """Components of ``a v + b (w x v) + c (w . v) w`` (``w = xyz``, ``v`` by components;
    written to ``out``).

    ``w . v`` and ``w x v`` are formed at ``shrink`` times their size (the factor taken on each
    product before it is rounded) and the factor given back on the coefficients: a power of
    two, so the values are those of the plain products wherever these are normal, and no
    product overflows where ``|w| |v|`` exceeds the largest float but the result does not (a
    translation near it, or a huge gradient).  The coefficients given the factor back must
    stay finite: the default for those of at most a few units (Rodrigues'), a larger one for
    Sim(3)'s (of ``e^sigma``, see :data:`torchlie.sim3._SHRINK`); ``shrink=1``: the plain
    products."""
    x, y, z = xyz
    p, q, r = v
    k, up = shrink, 1.0 / shrink
    plain = shrink == 1.0
    zero = None if plain else _layout.constant(0.0, x)  # 0-dim, cached
    if plain:
        cwv = c * fma(fma(x * p, y, q), z, r)
    else:
        cwv = c * fma(fma(fma(zero, x, p, value=k), y, q, value=k), z, r, value=k)
    result = []
    for vi, wi, (w1, v2), (w2, v1), o in (
        (p, x, (y, r), (z, q), out[0]),
        (q, y, (z, p), (x, r), out[1]),
        (r, z, (x, q), (y, p), out[2]),
    ):
        if plain:
            cross = fma(w1 * v2, w2, v1, value=-1.0)
            result.append(fma(fma(a * vi, b, cross), cwv, wi, out=o))
        else:
            cross = fma(fma(zero, w1, v2, value=k), w2, v1, value=-k)
            result.append(fma(fma(a * vi, b, cross, value=up), cwv, wi, value=up, out=o))
    return result


def jl_apply(
    w: Tensor | Sequence[Tensor],
    v: Tensor | Sequence[Tensor],
    sign: float = 1.0,
    inverse: bool = False,
    stacked: bool = True,
    differentiable: bool = True,
) -> Tensor | list[Tensor]:
    """``Jl(w) v`` (``sign=1``) or ``Jr(w) v = Jl(-w) v`` (``sign=-1``), or with ``inverse`` their
    inverses (for angles of at most pi), without a matrix::

        Jl(w) v = a v + b (w x v) + c (w . v) w,    Jl(w)^-1 v = e v - (w x v)/2 + f (w . v) w

    ``w`` and ``v`` as ``(..., 3)`` tensors or their components (batches may broadcast); the
    result as a tensor or, ``stacked=False``, its components.  The coefficients are
    differentiable, or forward-only (``differentiable=False``: a plain backward pass).
    """
    if inverse:
        xyz, (a, c) = coefficients(w, "ef", differentiable)
        b = a.new_full((), -0.5)
    else:
        xyz, (a, b, c) = coefficients(w, "abc", differentiable)
    vc = planes(v, 3)
    o = _layout.outputs((xyz[0], vc[0]), 3) if stacked else (None,) * 3
    parts = jl_components(xyz, vc, a, b if sign > 0 else -b, c, o)
    return _layout.interleave(parts, o) if stacked else parts


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
    if kind in ("left", "right"):
        xyz, (a, b, c) = coefficients(w, "abc", differentiable=True)
        b = b if kind == "left" else -b
    else:
        xyz, (a, c) = coefficients(w, "ef", differentiable=True)
        b = torch.full_like(a, -0.5 if kind == "left_inv" else 0.5)
    return _abc_matrix(a, b, c, xyz)


def _abc_matrix(a: Tensor, b: Tensor, c: Tensor, xyz: Sequence[Tensor]) -> Tensor:
    """``a I + b hat(w) + c w w^T`` from the components ``xyz`` of ``w``."""
    x, y, z = xyz
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
