"""Layout changes of the eager kernels: ``(..., n)`` tensors to and from ``n`` contiguous planes.

The eager forward passes read the components of their inputs as contiguous planes (one tensor
per component) and write their results by interleaving planes again.  torch's copy kernel does
both with strided element loads and stores (float32, one thread, a 65 536-row block: 10-15 ns
per element to split a ``(N, 4)`` tensor, 35 ns to stack 9 planes along a new last dimension),
more than the arithmetic of the cheap ops between them.  A matrix product with an identity
matrix is the same transposition done by the BLAS packing routines, 4-8x faster, and exact: each
output is one input times 1 plus exact zeros.

Differences from a copy, confined to the element concerned: a NaN or an infinity in one
component makes the element's other components NaN (``0 * inf``), and ``-0.0`` comes back as
``+0.0``.  The product is taken only where it is exact and fast: CPU tensors of float64, or of
float32 while float32 matrix products are full precision (no bfloat16 or TF32 setting), in eager
mode outside ``torch.func`` transforms, and for batches of at least :data:`MIN_ROWS` elements
(below that the extra kernel launch costs more than it saves).  Everywhere else (CUDA,
``torch.compile``, vmap, small batches) the plain copy, stack and unbind.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

#: Smallest batch (number of elements) that takes the matrix-product transposition.
MIN_ROWS = 512

_is_compiling = torch.compiler.is_compiling
_transforms_active = torch._C._are_functorch_transforms_active
_EYES: dict[tuple[torch.dtype, int], Tensor] = {}


def _fp32_full_precision() -> bool:
    """Whether CPU float32 matrix products are computed in float32 (no reduced-precision mode)."""
    try:
        if torch.get_float32_matmul_precision() != "highest":
            return False
    except RuntimeError:  # a mix of the legacy and the per-backend precision settings
        return False
    mkldnn = getattr(torch.backends.mkldnn, "matmul", None)
    return getattr(mkldnn, "fp32_precision", "none") in ("none", "ieee")


def _eye(dtype: torch.dtype, n: int) -> Tensor:
    eye = _EYES.get((dtype, n))
    if eye is None:
        eye = _EYES[(dtype, n)] = torch.eye(n, dtype=dtype)
    return eye


def _use_product(x: Tensor, rows: int) -> bool:
    if rows < MIN_ROWS or x.device.type != "cpu" or _is_compiling() or _transforms_active():
        return False
    if x.dtype == torch.float64:
        return True
    return x.dtype == torch.float32 and _fp32_full_precision()


def planes(M: Tensor, n: int) -> tuple[Tensor, ...]:
    """The ``n`` trailing entries of ``M`` as contiguous planes of its batch shape.

    ``n`` is the size of the last dimension, or 9 for a 3x3 matrix read row by row (which may be
    a strided block, such as the rotation block of a pose).  One transposition; while compiling,
    strided views instead (the fused loop reads each entry where it is, and a copy would be one
    more buffer for AOTAutograd to save for the backward).
    """
    if _is_compiling():
        if n == 9:
            return tuple(M[..., i, j] for i in range(3) for j in range(3))
        return M.unbind(-1)
    batch = M.shape[: M.dim() - (2 if n == 9 else 1)]
    rows = batch.numel()
    if _use_product(M, rows):
        flat = M.reshape((rows,) + M.shape[len(batch) :])
        if n == 9:
            flat = _rows_of_matrices(flat)
            select = _eye(M.dtype, flat.shape[1])[_matrix_columns(flat.shape[1])]
        else:
            select = _eye(M.dtype, n)
        return torch.mm(select, flat.T).reshape((n,) + batch).unbind(0)
    if n == 9:  # one copy even when M is a strided block
        return M.movedim((-2, -1), (0, 1)).contiguous().flatten(0, 1).unbind(0)
    return M.movedim(-1, 0).contiguous().unbind(0)


def _rows_of_matrices(flat: Tensor) -> Tensor:
    """``(B, 3, 3)`` as a ``(B, k)`` view whose columns hold its 9 entries (and some between).

    A contiguous matrix is its 9 entries; a block with row stride ``s`` and unit column stride
    is the span of ``2 s + 3`` entries from its first (the ones between the rows are skipped by
    the selection).  Anything else is copied to contiguous first.
    """
    if flat.stride(-1) != 1 or flat.stride(-2) < 3:
        flat = flat.contiguous()
    s = flat.stride(-2)
    return flat.as_strided((flat.shape[0], 2 * s + 3), (flat.stride(0), 1))


def _matrix_columns(k: int) -> list[int]:
    s = (k - 3) // 2
    return [i * s + j for i in range(3) for j in range(3)]


def interleave(parts: Sequence[Tensor]) -> Tensor:
    """``torch.stack(parts, dim=-1)`` (the parts have one shape)."""
    first = parts[0]
    rows = first.numel()
    if not _use_product(first, rows):
        return torch.stack(tuple(parts), dim=-1)
    n = len(parts)
    stacked = torch.stack(tuple(parts)).reshape(n, rows)
    return torch.mm(stacked.T, _eye(first.dtype, n)).reshape(first.shape + (n,))
