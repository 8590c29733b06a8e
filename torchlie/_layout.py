"""Layout changes of the eager kernels: ``(..., n)`` tensors to and from ``n`` contiguous planes.

The eager forward passes read the components of their inputs as contiguous planes (one tensor
per component) and write their results by interleaving planes again.  torch's copy kernel
splits a ``(N, n)`` tensor into planes with strided element loads (float32, one thread, a
65 536-row block: 10-15 ns per element for ``(N, 4)``), more than the arithmetic of the cheap
ops after it.  A matrix product with an identity matrix is the same transposition done by the
BLAS packing routines, 1.6-8x faster, and exact: each output is one input times 1 plus exact
zeros.  Differences from a copy, confined to the element concerned: a NaN or an infinity in one
component makes the element's other components NaN (``0 * inf``), and ``-0.0`` comes back as
``+0.0``.  The product is taken only where it is exact and fast: CPU tensors of float64, or of
float32 while float32 matrix products are full precision (no bfloat16 or TF32 setting), in eager
mode outside ``torch.func`` transforms, and for batches of at least :data:`MIN_ROWS` elements
(below that the extra kernel launch costs more than it saves).  Large batches of 3-vectors,
and of vectors where the product is not taken, are split by one copy per column instead
(strided loads of one column, contiguous stores: faster than both there).  Everywhere else
(CUDA, ``torch.compile``, vmap, small batches) the plain copy and unbind.

Results go the other way without a pass of their own: on large eager CPU batches a kernel's last
operations write their values straight into the columns of its result (:func:`outputs`;
``out=`` a strided view), or into ``dest``, the rows of a blocked result.  Measured on a
2-core AMD EPYC VM, one thread, a block of 65 536 rows of 9 entries, ns per entry, float32
(float64): the last operations writing strided 0.8 (1.3); writing planes 0.2 (0.4) and then
interleaving them by product 3.4 (3.6) more, by torch's transposing copy 1.5 (1.5), by
``torch.stack`` 1.9 (2.1).  Parts not written in place are copied into their columns
(:func:`interleave`; with the planes, 1.0 (1.7)).
"""

from __future__ import annotations

import functools
import os
import platform
from collections.abc import Sequence

import torch
from torch import Tensor
from torch.autograd import forward_ad as _forward_ad

from torchlie import _checks

#: Smallest batch (number of elements) that takes the matrix-product transposition (float32,
#: one thread, per call: at 1000 elements 6-15 % slower than the copies, twice as slow for the
#: entry-by-entry ops; at 8000, 0-40 % faster).
MIN_ROWS = 8192

#: ``dest`` of a kernel with two results (see :func:`interleave`): the rows of each, or None.
Dest2 = tuple[Tensor | None, Tensor | None]

_is_compiling = torch.compiler.is_compiling
_transforms_active = torch._C._are_functorch_transforms_active
_EYES: dict[tuple[torch.dtype, int], Tensor] = {}
_SELECTIONS: dict[tuple[int, tuple[int, ...], torch.dtype], Tensor] = {}


def _fp32_full_precision() -> bool:
    """Whether CPU float32 matrix products are computed in float32 (no reduced-precision mode)."""
    try:
        if torch.get_float32_matmul_precision() != "highest":
            return False
    except RuntimeError:  # a mix of the legacy and the per-backend precision settings
        return False
    mkldnn = getattr(torch.backends.mkldnn, "matmul", None)
    return getattr(mkldnn, "fp32_precision", "none") in ("none", "ieee")


def eye(dtype: torch.dtype, n: int) -> Tensor:
    """The ``n x n`` identity (CPU, built once per dtype and size)."""
    eye = _EYES.get((dtype, n))
    if eye is None:
        eye = _EYES[(dtype, n)] = torch.eye(n, dtype=dtype)
    return eye


def eager_cpu(x: Tensor) -> bool:
    """Whether ``x`` is on CPU and the op runs in eager mode outside ``torch.func`` transforms:
    where the CPU-specific eager kernels (blocks, transpositions by product, the large-batch
    kernels and the matrix forms of small batches) apply."""
    return x.device.type == "cpu" and not (_is_compiling() or _transforms_active())


def large(x: Tensor, rows: int) -> bool:
    """Whether an op over ``rows`` elements like ``x`` takes the kernels meant for large eager
    CPU batches: at least :data:`MIN_ROWS` elements, :func:`eager_cpu`."""
    return rows >= MIN_ROWS and eager_cpu(x)


def broadcast(*shapes: torch.Size) -> torch.Size:
    """The broadcast of batch shapes already checked to broadcast, by
    :func:`torchlie._checks.batch_broadcast` (plain Python eager: ``torch.broadcast_shapes``
    costs 10-50 us a call, more than a small op's arithmetic)."""
    return _checks.batch_broadcast("torchlie", *((s, f"operand {i}") for i, s in enumerate(shapes)))


def _use_product(x: Tensor, rows: int) -> bool:
    if not large(x, rows):
        return False
    if x.dtype == torch.float64:
        return True
    return x.dtype == torch.float32 and _fp32_full_precision()


#: Whether the kernels of large batches take matrix products with results in rows (see
#: :func:`row_products`): ``None`` decides by the CPU and dtype, ``True`` or ``False`` forces (as
#: does the environment variable ``TORCHLIE_ROW_PRODUCTS=1`` or ``0`` when the package is
#: imported).
ROW_PRODUCTS: bool | None = {"1": True, "0": False}.get(
    os.environ.get("TORCHLIE_ROW_PRODUCTS", "").strip()
)


def row_products(dtype: torch.dtype, columns: int) -> bool:
    """Whether a kernel of large batches may end in a matrix product whose result is a block of
    the batch's rows, ``columns`` entries each (a constant map applied to every row): with MKL
    on an Intel CPU always; elsewhere only float32 products of 16 columns.

    The other direction, planes from rows (``(k, n) @ (n, rows)``, see :func:`stacked`), is fast
    on every CPU measured.  Products with results in rows are not: on an AMD EPYC (Zen 5), a block
    in cache, ns per row, float32 ``(rows, 9) @ (9, 3)`` 11.9 where ``(3, 9) @ (9, rows)`` takes
    4.7, ``(rows, 3) @ (3, 9)`` 8.9; float64 ``(rows, 12) @ (12, 16)`` 22-28 where copying the
    twelve planes into the rows takes 7.2 (float32 5.5 against 5.0).  MKL there also sums a row
    of such a product differently by its place in the batch (its index modulo 4 in float32, 2
    in float64: an ulp here and there), where on an Intel Xeon each row is summed alike.

    Where this is false, the kernels written entry by entry over planes or rows are taken
    instead of the products forms of ``so3.act`` (forward and backward), the backward of
    ``se3.act``, ``quaternion.to_matrix`` (forward and backward) and ``quaternion.apply`` (3 and
    9 columns), and copies instead of the exact products with 0/1 maps that write the results
    of ``se3.compose``, ``se3.inverse`` and their backward passes (16 columns).  On that AMD
    EPYC, one thread, N = 10^6, ns per element, float32 (float64): ``so3.act`` forward 20.5 ->
    9.0 (23.2 -> 12.9), forward+backward 54.4 -> 25.3 (61.8 -> 37.6); ``quaternion.to_matrix``
    forward 23.2 -> 11.2 (28.6 -> 21.8), forward+backward 43.3 -> 33.4 (65.9 -> 72.0);
    ``quaternion.apply`` forward 13.3 -> 9.7 (23.6 -> 17.4), forward+backward 33.2 -> 28.6
    (57.6 -> 48.7); ``se3.act`` forward+backward 38.9 -> 33.6 (68.2 -> 56.0); float64
    ``se3.inverse`` forward 57.0 -> 45.4, ``se3.compose`` forward 85.4 -> 65.3 (float32, with
    copies: 26.9 -> 31.9 and 29.2 -> 31.7, so the products stay there).
    """
    if ROW_PRODUCTS is not None:
        return ROW_PRODUCTS
    return intel_mkl() or (dtype == torch.float32 and columns >= 16)


@functools.cache
def intel_mkl() -> bool:
    """Whether torch's CPU matrix products are MKL's and the CPU is an Intel one."""
    return torch.backends.mkl.is_available() and "GenuineIntel" in _cpu_vendor()


def _cpu_vendor() -> str:
    """The CPU's vendor string: ``vendor_id`` of ``/proc/cpuinfo`` (Linux), else what
    :func:`platform.processor` says (Windows names the vendor there); ``""`` if neither does."""
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("vendor_id"):
                    return line.partition(":")[2].strip()
    except OSError:
        pass
    return platform.processor()


def by_product(x: Tensor, event_dims: int) -> bool:
    """Whether :func:`planes` and :func:`interleave` transpose ``x`` (``event_dims`` trailing
    dimensions of it are not batch) by matrix product: where a kernel written entry by entry
    beats one that calls a batched matmul."""
    return _use_product(x, x.shape[: x.dim() - event_dims].numel())


def planes(M: Tensor, n: int | tuple[int, int]) -> tuple[Tensor, ...]:
    """The trailing entries of ``M`` as contiguous planes of its batch shape.

    ``n`` is the size of the last dimension, or ``(rows, cols)`` for a matrix read row by row
    (which may be a strided block, such as the rotation block of a pose).  One transposition;
    while compiling, strided views instead (the fused loop reads each entry where it is, and a
    copy would be one more buffer for AOTAutograd to save for the backward).
    """
    matrix = isinstance(n, tuple)
    if _is_compiling():
        if matrix:
            return tuple(M[..., i, j] for i in range(n[0]) for j in range(n[1]))
        return M.unbind(-1)
    return stacked(M, n).unbind(0)


def stacked(M: Tensor, n: int | tuple[int, int]) -> Tensor:
    """:func:`planes` as one contiguous ``(count, *batch)`` tensor (eager mode; the same
    transposition)."""
    matrix = isinstance(n, tuple)
    batch = M.shape[: M.dim() - (2 if matrix else 1)]
    rows = batch.numel()
    count = n[0] * n[1] if matrix else n
    if _use_product(M, rows) and (matrix or n > 3):
        flat = M.reshape((rows,) + M.shape[len(batch) :])
        if matrix:
            flat, columns = _rows_of_matrices(flat)
            select = selection(M.dtype, flat.shape[1], tuple(columns))
        else:
            select = eye(M.dtype, n)
        return torch.mm(select, flat.T).reshape((count,) + batch)
    if matrix:  # one copy even when M is a strided block
        return M.movedim((-2, -1), (0, 1)).contiguous().flatten(0, 1)
    if large(M, rows) and not needs_graph((M,)):
        # column by column: faster than the transposing copy below, and than the product for
        # 3-vectors (float32 and float64, a block of 65 536 rows, ns per entry: 0.7-1.3
        # against 2.3-4.0 and 1.6-3.0)
        out = M.new_empty((n,) + batch)
        for plane, column in zip(out.unbind(0), M.unbind(-1), strict=True):
            plane.copy_(column)
        return out
    return M.movedim(-1, 0).contiguous()


def matrix_planes(M: Tensor) -> Tensor:
    """The entries of a ``(B, r, c)`` batch of matrices (or a strided block of one), row by
    row, as ``(r c, B)`` planes by one product with a selection, whatever ``B``: for kernels
    that have checked :func:`by_product` for their whole batch."""
    flat, columns = _rows_of_matrices(M)
    return torch.mm(selection(M.dtype, flat.shape[1], tuple(columns)), flat.T)


def selection(dtype: torch.dtype, k: int, columns: tuple[int, ...]) -> Tensor:
    """The rows ``columns`` of the ``k x k`` identity: picks those columns of a matrix."""
    key = (k, columns, dtype)
    out = _SELECTIONS.get(key)
    if out is None:
        out = _SELECTIONS[key] = eye(dtype, k)[list(columns)]
    return out


def _rows_of_matrices(flat: Tensor) -> tuple[Tensor, list[int]]:
    """``(B, r, c)`` as a ``(B, k)`` view holding its entries, and their columns in it, row by row.

    A contiguous matrix is its ``r c`` entries; a block with row stride ``s`` and unit column
    stride is the span of ``(r - 1) s + c`` entries from its first (the ones between the rows
    are skipped by the selection).  Anything else is copied to contiguous first.
    """
    r, c = flat.shape[1:]
    if flat.stride(-1) != 1 or flat.stride(-2) < c:
        flat = flat.contiguous()
    s = flat.stride(-2)
    view = flat.as_strided((flat.shape[0], (r - 1) * s + c), (flat.stride(0), 1))
    return view, [i * s + j for i in range(r) for j in range(c)]


class Columns(tuple):
    """The columns of one ``(*batch, n)`` result (:attr:`result`), one tensor each, where a
    kernel writes its last operations (see :func:`outputs`)."""

    result: Tensor


def outputs(
    like: Tensor | Sequence[Tensor], n: int, *inputs: Tensor, dest: Tensor | None = None
) -> tuple[Tensor | None, ...]:
    """Where a kernel writes the ``n`` parts it will :func:`interleave` (``out=`` of its last
    operations): the columns of its ``(*batch, n)`` result (``batch``: the shape of ``like``, or
    the broadcast of the shapes of several planes, one per operand), or of ``dest`` (the rows of a
    blocked result, see :func:`interleave`), as :class:`Columns`, on large eager CPU batches
    (:func:`large`); the last operations then store their values strided, where they belong,
    and no pass over the result interleaves them afterwards.  ``n`` Nones (new tensors)
    elsewhere, and where autograd records the kernel (grad mode on and one of ``inputs``
    requiring grad: ``out=`` is not differentiable)."""
    likes = (like,) if isinstance(like, Tensor) else tuple(like)
    first = likes[0]
    if not eager_cpu(first):
        return (None,) * n
    batch = broadcast(*(x.shape for x in likes))
    if batch.numel() < MIN_ROWS or needs_graph(inputs):
        return (None,) * n
    shape = batch + (n,)
    if dest is None:
        whole = torch.empty(shape, dtype=first.dtype, device=first.device)
    else:
        whole = dest.view(shape)
    columns = Columns(whole.unbind(-1))
    columns.result = whole
    return columns


def needs_graph(inputs: Sequence[Tensor]) -> bool:
    """Whether autograd may record operations on ``inputs``: grad mode on and one of them
    requires grad, or a forward-mode level entered (an input may carry a tangent)."""
    if _forward_ad._current_level >= 0:
        return True
    return torch.is_grad_enabled() and any(x.requires_grad for x in inputs)


def interleave(
    parts: Sequence[Tensor],
    out: Sequence[Tensor | None] | None = None,
    dest: Tensor | None = None,
) -> Tensor:
    """``torch.stack(parts, dim=-1)`` (the parts have one shape).

    ``out``: the :class:`Columns` from :func:`outputs` the parts were written to (a part that
    is not its column is copied there).  ``dest``: a contiguous tensor of the result's size to
    write it in (the rows of a larger result, see :func:`torchlie._autograd._blocked`; not
    differentiable).  On large eager CPU batches each part is copied into its column of the
    result (strided stores, one pass), which is faster than ``torch.stack``.
    """
    first = parts[0]
    shape = first.shape + (len(parts),)
    target = None if dest is None else dest.view(shape)
    if isinstance(out, Columns):
        for part, column in zip(parts, out, strict=True):
            if part is not column:
                column.copy_(part)
        if target is None or same_memory(out.result, target):
            return out.result
        return target.copy_(out.result)
    if not large(first, first.numel()) or needs_graph(parts):
        return torch.stack(tuple(parts), dim=-1, out=target)
    if target is None:
        target = torch.empty(shape, dtype=first.dtype, device=first.device)
    for part, column in zip(parts, target.unbind(-1), strict=True):
        column.copy_(part)
    return target


def same_memory(a: Tensor, b: Tensor) -> bool:
    """Whether ``a`` and ``b`` are the same elements of the same memory (a result written in
    place, nothing to copy)."""
    return a.data_ptr() == b.data_ptr() and a.stride() == b.stride() and a.shape == b.shape
