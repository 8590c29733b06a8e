"""Small vector and matrix algebra written component by component, shared by the kernels of
:mod:`torchlie.quaternion`, :mod:`torchlie.so3` and :mod:`torchlie.se3`.

The kernels read their inputs as planes (one tensor per component, :func:`planes`) and spell
out cross products, matrix-vector products and the like from those planes, in multiply-adds:
an element's result rounds alike whatever the batch around it (see :mod:`torchlie._layout`).
These helpers are the pieces every module needs; they live here, below all of them, so that no
module reaches into another's privates for them.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import torch
from torch import Tensor

from . import _layout
from ._autograd import blocked, fma


def planes(M: Tensor | Sequence[Tensor], n: int) -> tuple[Tensor, ...]:
    """The ``n`` trailing entries of ``M`` as planes (see :func:`_layout.planes`);
    ``n = 9``: a 3x3 matrix read row by row.  ``M`` given as its planes already: those (the
    callers that read several blocks of one matrix transpose it once)."""
    if not isinstance(M, Tensor):
        return tuple(M)
    return _layout.planes(M, (3, 3) if n == 9 else n)


def norm2(w: Tensor, x: Tensor, y: Tensor, z: Tensor) -> Tensor:
    """``w^2 + x^2 + y^2 + z^2`` from components (multiply-adds, left to right)."""
    return fma(fma(fma(w * w, x, x), y, y), z, z)


def cross_planes(
    a: Sequence[Tensor], b: Sequence[Tensor], out: Sequence[Tensor | None] = (None,) * 3
) -> tuple[Tensor, Tensor, Tensor]:
    """``a x b`` from components (planes, written to ``out``)."""
    ax, ay, az = a
    bx, by, bz = b
    return (
        fma(ay * bz, az, by, value=-1.0, out=out[0]),
        fma(az * bx, ax, bz, value=-1.0, out=out[1]),
        fma(ax * by, ay, bx, value=-1.0, out=out[2]),
    )


def cross(a: Tensor, b: Tensor, dim: int = -1) -> Tensor:
    """``a x b`` along ``dim`` (of size 3; the other dimensions broadcast) from components: for
    large batches laid out batch last (the three components planes), several times faster than
    ``torch.linalg.cross``, whose CPU kernel loops element by element; where the components
    are the last dimension, or the batch is small, ``torch.linalg.cross`` is the faster."""
    return torch.stack(cross_planes(a.unbind(dim), b.unbind(dim)), dim)


def mv(M: Tensor, v: Tensor) -> Tensor:
    """``M @ v`` for a batch of matrices and vectors (batch shapes broadcast), column by
    column: each element's result is summed alike whatever the batch around it.  A 3x4 block
    ``M = [A, t]`` gives ``A v + t`` (the sum, then ``t``)."""
    m0, m1, m2, *t = M.unbind(-1)
    return _combine((m0, m1, m2), v, t[0] if t else None)


def mm(A: Tensor, B: Tensor) -> Tensor:
    """``A @ B`` for batches of 3x3 matrices (batch shapes broadcast) from components: the
    columns of ``A`` against the rows of ``B``, by multiply-adds, so each element's product
    rounds alike whatever the batch (torch's batched matrix products take other kernels by
    batch size)."""
    a = A.unsqueeze(-1).unbind(-2)  # column k of A, (..., 3, 1)
    b = B.unsqueeze(-2).unbind(-3)  # row k of B, (..., 1, 3)
    return fma(fma(a[0] * b[0], a[1], b[1]), a[2], b[2])


def mtv(M: Tensor, v: Tensor) -> Tensor:
    """``M^T @ v`` (batch shapes broadcast) row by row: the same sums as :func:`mv` of the
    transpose, without transposing."""
    return _combine(M.unbind(-2), v)


def _combine(c: Sequence[Tensor], v: Tensor, t: Tensor | None = None) -> Tensor:
    """``((c0 v0 + c1 v1) + c2 v2) (+ t)`` for vectors ``c_k`` and ``t`` ``(..., 3)``: whole
    vectors in eager mode; while compiling entry by entry, stacked, the same sums (Inductor's
    loop over a broadcast of ``(..., 3)`` vectors runs along the 3; over planes, along the
    batch)."""
    if not torch.compiler.is_compiling():
        v0, v1, v2 = v.unsqueeze(-1).unbind(-2)
        out = fma(fma(c[0] * v0, c[1], v1), c[2], v2)
        return out if t is None else torch.add(out, t)
    v0, v1, v2 = v.unbind(-1)
    c0, c1, c2 = (x.unbind(-1) for x in c)
    out = [fma(fma(c0[i] * v0, c1[i], v1), c2[i], v2) for i in range(3)]
    if t is not None:
        out = [o + ti for o, ti in zip(out, t.unbind(-1), strict=True)]
    return torch.stack(out, -1)


def hat(w: Tensor) -> Tensor:
    """The skew-symmetric matrix of ``w`` (``hat(w) @ v == cross(w, v)``)."""
    x, y, z = w.unbind(-1)
    o = torch.zeros_like(x)
    return _layout.interleave((o, -z, y, z, o, -x, -y, x, o)).unflatten(-1, (3, 3))


def half_difference(a: Tensor, b: Tensor) -> Tensor:
    """``(a - b) / 2`` as ``a / 2 - b / 2`` (the same value; ``a - b`` overflows from half the
    largest float)."""
    return torch.sub(a * 0.5, b, alpha=0.5)


def symmetric_part(M: Tensor) -> Tensor:
    """``(M + M^T) / 2`` as ``M / 2 + M^T / 2``: exactly symmetric, a symmetric ``M`` unchanged,
    no overflow.  For matrices read by a factorization that reads one triangle (Cholesky) while
    other code reads both: with it every reader sees one matrix, and forward and reverse mode
    agree (torch's backward of the factorization returns the symmetric gradient)."""
    return 0.5 * M + 0.5 * M.mT


def vee(M: Tensor) -> Tensor:
    """vee of the skew-symmetric part, ``((M - M^T)/2)^v``, at every finite magnitude."""
    d = half_difference
    return _layout.interleave(
        (
            d(M[..., 2, 1], M[..., 1, 2]),
            d(M[..., 0, 2], M[..., 2, 0]),
            d(M[..., 1, 0], M[..., 0, 1]),
        )
    )


def skew_vee(M: Tensor) -> Tensor:
    """``vee(M - M^T)`` (twice the vee of the skew part of ``M``), differentiable."""
    return _layout.interleave(
        (M[..., 2, 1] - M[..., 1, 2], M[..., 0, 2] - M[..., 2, 0], M[..., 1, 0] - M[..., 0, 1]),
    )


def rt_g_vee(
    R: Tensor | Sequence[Tensor], G: Tensor | Sequence[Tensor]
) -> tuple[Tensor, Tensor, Tensor]:
    """Components of ``vee(R^T G - G^T R)`` (the full vee: twice that of the skew part; each
    matrix as a tensor or its 9 planes).

    ``= sum_k cross(G_k, R_k)`` over the rows, from components (no batched 3x3 product).
    """
    r = planes(R, 9)
    g = planes(G, 9)
    out = []
    for i, j in ((1, 2), (2, 0), (0, 1)):
        acc = g[i] * r[j]
        for k in (3, 6):
            acc = fma(acc, g[k + i], r[k + j])
        for k in (0, 3, 6):
            acc = fma(acc, g[k + j], r[k + i], value=-1.0)
        out.append(acc)
    return out[0], out[1], out[2]


def gram_defect(N: Tensor) -> Tensor:
    """``E = N^T N - I`` of a ``3x3`` block ``N``: ``N = R (I + E / 2)`` to first order, with
    ``R`` the nearest rotation (zero on SO(3) up to rounding)."""
    return N.mT @ N - torch.eye(3, dtype=N.dtype, device=N.device)


def polar_backward_terms(N: Tensor, H: Tensor, E: Tensor) -> Tensor:
    """``N (3/4 E H + 1/4 H E)``: subtracted from a backward ``N H`` (``H`` skew, ``E`` from
    :func:`gram_defect`), it makes ``N H`` the gradient of ``f o polar`` to first order off
    SO(3) too, not only on it.  From ``d polar(R P) = R W`` with ``W P + P W`` the skew part of
    ``2 R^T dM``: ``W = skew(A) - (skew(A) S + S skew(A)) / 2`` to first order in
    ``P = I + S``.  Zero on SO(3) up to rounding: only the derivative of a backward (second
    derivatives in the normal directions ``R S``) needs it."""
    return N @ (0.75 * (E @ H) + 0.25 * (H @ E))


def polar_tangent(A: Tensor, E: Tensor) -> Tensor:
    """``vee(W)`` of ``d polar(N) = polar(N) W``, from ``A = N^T dN`` and ``E`` of
    :func:`gram_defect`, to first order in ``E`` (:func:`polar_backward_terms`): the forward-mode
    twin, ``vee`` of ``skew(A) - skew(E A) / 2 - (skew(A) E + E skew(A)) / 4`` (:func:`vee`
    takes the skew parts)."""
    K = 0.5 * (A - A.mT)
    return vee(A - 0.5 * (E @ A) - 0.25 * (K @ E + E @ K))


def r_hat(R: Tensor, u: Sequence[Tensor]) -> Tensor:
    """``R hat(u)`` from components: row ``i`` is ``cross(R_i, u)``, for all rows at once (the
    columns of ``R`` entries first, ``(3, *batch)``, each term a column against an entry of
    ``u``)."""
    c = _layout.stacked(R, (3, 3)).unbind(1)
    g = [x.unbind(0) for x in cross_planes(c, u)]  # column j of the result, row by row
    return _layout.interleave([g[j][i] for i in range(3) for j in range(3)]).unflatten(-1, (3, 3))


def blocks(A: Tensor, B: Tensor, C: Tensor, D: Tensor) -> Tensor:
    """The 6x6 matrix ``[[A, B], [C, D]]`` from four 3x3 blocks of one batch shape."""
    return torch.cat((torch.cat((A, B), dim=-1), torch.cat((C, D), dim=-1)), dim=-2)


def homogeneous(M: Tensor, t: Tensor) -> Tensor:
    """``[[M, t], [0, 1]]`` of ``n x n`` blocks ``M`` and ``n``-vectors ``t`` of one batch
    shape (SE(2), SE(3), Sim(3) elements)."""
    top = torch.cat((M, t.unsqueeze(-1)), dim=-1)
    bottom = torch.cat((torch.zeros_like(t), torch.ones_like(t[..., :1])), dim=-1)
    return torch.cat((top, bottom.unsqueeze(-2)), dim=-2)


def between_kernels(
    blocks: Callable[[Tensor, bool], Any], combine: Callable[[Any, Any], Tensor]
) -> tuple[Callable[[Tensor, Tensor], Tensor], Callable[[Tensor, Tensor], Tensor]]:
    """``A^-1 B`` and ``A B^-1`` of matrix groups, evaluated in blocks (batch shapes broadcast;
    autograd differentiates the formula), from a group's ``blocks(T, inverse)`` (the blocks of
    ``T`` or of ``T^-1``) and ``combine(a, b)`` (``a^-1 b`` from the blocks of ``a`` and
    ``b``).  ``A B^-1`` is ``between(A^-1, B^-1)``: where ``A == B`` it cancels exactly as
    ``A^-1 B`` does (``compose(A, inverse(B))``'s translation ``t_A - R_A R_B^T t_B`` does
    not)."""

    def between(A: Tensor, B: Tensor) -> Tensor:
        return combine(blocks(A, False), blocks(B, False))

    def right_between(A: Tensor, B: Tensor) -> Tensor:
        return combine(blocks(A, True), blocks(B, True))

    return blocked(between, (2, 2)), blocked(right_between, (2, 2))
