"""The Hamilton product of quaternions ``(w, x, y, z)``, from components, as a custom Function
with a closed-form backward and forward-mode rule.

Apart from :mod:`torchlie.quaternion` because the rotation-matrix kernels
(:mod:`torchlie._rotation_matrix`) take it in their derivatives and sit below that module.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from . import _layout
from ._autograd import CustomFunction, blocked, fma
from ._components import planes

#: The Hamilton product: component ``i`` of ``a b`` is the sum of ``sign a_j b_k`` over row ``i``.
_HAMILTON = (
    ((0, 0, 1), (1, 1, -1), (2, 2, -1), (3, 3, -1)),
    ((0, 1, 1), (1, 0, 1), (2, 3, 1), (3, 2, -1)),
    ((0, 2, 1), (1, 3, -1), (2, 0, 1), (3, 1, 1)),
    ((0, 3, 1), (1, 2, 1), (2, 1, -1), (3, 0, 1)),
)


def _signed_terms(conj_a: bool, conj_b: bool) -> tuple[tuple[tuple[int, int, float], ...], ...]:
    """:data:`_HAMILTON` for ``conj(a)`` and/or ``conj(b)``, a positive term first in each row."""
    rows = []
    for row in _HAMILTON:
        terms = [
            (j, k, float(s * (-1 if conj_a and j else 1) * (-1 if conj_b and k else 1)))
            for j, k, s in row
        ]
        terms.sort(key=lambda term: -term[2])  # there always is a positive one
        rows.append(tuple(terms))
    return tuple(rows)


_SIGNED_TERMS = {(ca, cb): _signed_terms(ca, cb) for ca in (False, True) for cb in (False, True)}


def _hamilton(
    a: Sequence[Tensor],
    b: Sequence[Tensor],
    conj_a: bool = False,
    conj_b: bool = False,
    out: Sequence[Tensor | None] = (None,) * 4,
) -> list[Tensor]:
    """Components of ``a b`` (``conj(a)``, ``conj(b)`` if asked) from the components of each:
    one product and three multiply-adds per component (the last written to ``out``)."""
    result = []
    for ((j, k, _), *rest), o in zip(_SIGNED_TERMS[(conj_a, conj_b)], out, strict=True):
        acc = a[j] * b[k]
        (j1, k1, s1), (j2, k2, s2), (j3, k3, s3) = rest
        acc = fma(fma(acc, a[j1], b[k1], value=s1), a[j2], b[k2], value=s2)
        result.append(fma(acc, a[j3], b[k3], value=s3, out=o))
    return result


def _product(a: Sequence[Tensor], b: Sequence[Tensor], **conj: bool) -> Tensor:
    """:func:`_hamilton`, interleaved."""
    o = _layout.outputs((a[0], b[0]), 4)  # batches may broadcast
    return _layout.interleave(_hamilton(a, b, out=o, **conj), o)


def _multiply_values(a: Tensor, b: Tensor) -> Tensor:
    """``a b`` component by component."""
    return _product(planes(a, 4), planes(b, 4))


def _multiply_grads(a: Tensor, b: Tensor, g: Tensor) -> tuple[Tensor, Tensor]:
    """``(g conj(b), conj(a) g)``: the backward of ``a b``."""
    ap, bp, gp = planes(a, 4), planes(b, 4), planes(g, 4)
    return _product(gp, bp, conj_b=True), _product(ap, gp, conj_a=True)


_multiply_grads_blocked = blocked(_multiply_grads, (1, 1, 1))


def _multiply_backward(saved: tuple[Tensor, ...], g: Tensor) -> tuple[Tensor, Tensor]:
    # d(a b) = da b + a db: dL/da = g conj(b), dL/db = conj(a) g (two products instead of
    # autograd's graph of 16 multiply-adds, each with two products in its backward).
    a, b = saved
    da, db = _multiply_grads_blocked(a, b, g)
    return da.sum_to_size(a.shape), db.sum_to_size(b.shape)


_MultiplyFn = CustomFunction(
    "QuaternionMultiply",
    forward=_multiply_values,
    save=lambda inputs, out: (inputs[0], inputs[1]),
    backward=_multiply_backward,
    jvp=lambda saved, da, db: _multiply_values(da, saved[1]) + _multiply_values(saved[0], db),
    event_dims=(1, 1),
)


def multiply(a: Tensor, b: Tensor) -> Tensor:
    """``a b`` (batch shapes broadcast; no input checks)."""
    return _MultiplyFn(a, b)


def conj_product_vec(q: Tensor, p: Tensor) -> Tensor:
    """Vector part of ``conj(q) p``: ``w p_v - p_w v - v x p_v`` (differentiable)."""
    w, v = q[..., :1], q[..., 1:]
    u = fma(w * p[..., 1:], p[..., :1], v, value=-1.0)
    return u - torch.linalg.cross(v, p[..., 1:], dim=-1)
