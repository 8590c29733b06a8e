"""Layout changes of the eager kernels: ``(..., n)`` tensors to and from ``n`` planes.

The kernels read the components of their inputs as planes (one tensor per component) and write
their results by interleaving planes again, one mechanism for every op.  The planes are views of
the input where that is cheapest, copies where the kernels' arithmetic then runs faster; the
kernels never write into them.

Planes from rows (:func:`planes`): vectors of small CPU batches are read where they are
(strided views: any copy costs more than the strided reads it saves there); vectors of large
batches are split by one copy per column, faster than torch's transposing copy; matrices by the
plain transposing copy; while compiling, strided views.  Every way holds the input's numbers
exactly, so a non-finite component stays in its element.

Rows from planes (:func:`outputs`, :func:`interleave`): on large eager CPU batches a kernel's
last operations write their values straight into the columns of its result (``out=`` a strided
view), so no pass over the result interleaves them afterwards; inside the evaluation driver's
blocks that result is the block's rows of the whole result
(:func:`torchlie._autograd.result_buffer`).

Results.  The same numbers give the same results whatever their layout, batch size or
broadcast, within the rounding that torch's kernels do differently in their vectorised and
scalar loops and BLAS by CPU: the planes hold the input's numbers exactly, sums over a few
components are written out one by one, and sums over a set are taken over contiguous copies.
``tests/test_layout_agreement.py`` holds every op to it.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from torchlie import _autograd, _checks

#: Smallest batch (number of elements) that takes the copies column by column and the writes
#: into columns (below it the extra kernel launches cost more than they save).
MIN_ROWS = 8192

_is_compiling = torch.compiler.is_compiling
_CONSTANTS: dict[tuple[object, torch.dtype, torch.device, int], Tensor] = {}


def constant(values: tuple[object, ...] | float | int, like: Tensor, dims: int = 0) -> Tensor:
    """``values`` (a number, or nested tuples of numbers) as a tensor of ``like``'s device and
    dtype, with trailing dimensions of size one up to ``dims`` dimensions (to broadcast against
    a batch): built once per device, dtype and shape in eager mode, in the traced graph while
    compiling."""

    def build() -> Tensor:
        out = torch.tensor(values, dtype=like.dtype, device=like.device)
        return out.reshape(out.shape + (1,) * (dims - out.dim()))

    if _is_compiling():
        return build()
    return _autograd.cached(_CONSTANTS, (values, like.dtype, like.device, dims), build)


def eager_cpu(x: Tensor) -> bool:
    """Whether ``x`` is on CPU and the op runs in eager mode outside ``torch.func`` transforms:
    where the CPU-specific eager kernels (blocks, copies column by column, the large-batch
    kernels and the matrix forms of small batches) apply."""
    return x.is_cpu and not (_is_compiling() or _autograd.transforms_active())


def large(x: Tensor, rows: int) -> bool:
    """Whether an op over ``rows`` elements like ``x`` takes the kernels meant for large eager
    CPU batches: at least :data:`MIN_ROWS` elements, :func:`eager_cpu`."""
    return rows >= MIN_ROWS and eager_cpu(x)


def broadcast(*shapes: torch.Size) -> torch.Size:
    """The broadcast of batch shapes already checked to broadcast, by
    :func:`torchlie._checks.batch_broadcast` (plain Python: ``torch.broadcast_shapes`` costs
    more than a small op's arithmetic)."""
    return _checks.batch_broadcast("torchlie", *((s, f"operand {i}") for i, s in enumerate(shapes)))


def _in_place(M: Tensor, rows: int) -> bool:
    """Whether the planes of a vector ``M`` over ``rows`` elements are read where they are
    (strided views): small CPU batches, where any copy costs more than the reads it saves."""
    return rows < MIN_ROWS and M.is_cpu


def planes(M: Tensor, n: int | tuple[int, int]) -> tuple[Tensor, ...]:
    """The trailing entries of ``M`` as planes of its batch shape (module docstring).

    ``n`` is the size of the last dimension, or ``(rows, cols)`` for a matrix read row by row
    (which may be a strided block, such as the rotation block of a pose).  One transposition
    (views of small batches of vectors); while compiling, strided views instead (the fused
    loop reads each entry where it is, and a copy would be one more buffer for AOTAutograd to
    save for the backward).
    """
    if isinstance(n, tuple):
        if _is_compiling():
            return tuple(M[..., i, j] for i in range(n[0]) for j in range(n[1]))
    elif _is_compiling() or _in_place(M, M.numel() // n):
        return M.unbind(-1)  # the views of :func:`stacked`, taken in one call
    S = stacked(M, n)
    return (S.flatten(0, 1) if isinstance(n, tuple) else S).unbind(0)


def stacked(M: Tensor, n: int | tuple[int, int]) -> Tensor:
    """:func:`planes` as one tensor (the same transposition), ``(n, *batch)`` or for a matrix
    ``(rows, cols, *batch)``: contiguous, or a view of ``M`` for small CPU batches of vectors
    and while compiling."""
    matrix = isinstance(n, tuple)
    if _is_compiling():
        return M.movedim((-2, -1), (0, 1)) if matrix else M.movedim(-1, 0)
    batch = M.shape[: M.dim() - (2 if matrix else 1)]
    rows = batch.numel()
    if not matrix and _in_place(M, rows):
        return M.movedim(-1, 0)
    if matrix:  # one copy even when M is a strided block
        return M.movedim((-2, -1), (0, 1)).contiguous()
    if large(M, rows) and not _autograd.needs_graph((M,)):
        # column by column: faster than the transposing copy below
        out = M.new_empty((n,) + batch)
        for plane, column in zip(out.unbind(0), M.unbind(-1), strict=True):
            plane.copy_(column)
        return out
    return M.movedim(-1, 0).contiguous()


class Columns(tuple):
    """The columns of one ``(*batch, n)`` result (:attr:`result`), one tensor each, where a
    kernel writes its last operations (see :func:`outputs`)."""

    result: Tensor


def outputs(like: Tensor | Sequence[Tensor], n: int) -> tuple[Tensor | None, ...]:
    """Where a kernel writes the ``n`` parts it will :func:`interleave` (``out=`` of its last
    operations): the columns of its ``(*batch, n)`` result (``batch``: the shape of ``like``, or
    the broadcast of the shapes of several planes, one per operand), as :class:`Columns`, on
    large eager CPU batches (:func:`large`); the last operations then store their values
    strided, where they belong, and no pass over the result interleaves them afterwards.  ``n``
    Nones (new tensors) elsewhere, and where autograd records the kernel (``out=`` is not
    differentiable)."""
    if _is_compiling():
        return (None,) * n
    likes = (like,) if isinstance(like, Tensor) else like
    size = 1  # the product bounds the size of the broadcast
    for x in likes:
        size *= x.numel()
    first = likes[0]
    if size < MIN_ROWS or not eager_cpu(first):
        return (None,) * n
    batch = broadcast(*(x.shape for x in likes))
    if batch.numel() < MIN_ROWS or _autograd.needs_graph(likes):
        return (None,) * n
    whole = _autograd.result_buffer(batch + (n,), first)
    columns = Columns(whole.unbind(-1))
    columns.result = whole
    return columns


def interleave(parts: Sequence[Tensor], out: Sequence[Tensor | None] | None = None) -> Tensor:
    """``torch.stack(parts, dim=-1)`` (the parts have one shape).

    ``out``: the :class:`Columns` from :func:`outputs` the parts were written to (a part that
    is not its column is copied there).  On large eager CPU batches each part is copied into
    its column of the result (strided stores, one pass), which is faster than ``torch.stack``.
    """
    first = parts[0]
    if isinstance(out, Columns):
        for part, column in zip(parts, out, strict=True):
            if part is not column:
                column.copy_(part)
        return out.result
    if not large(first, first.numel()) or _autograd.needs_graph(parts):
        return torch.stack(tuple(parts), dim=-1)
    target = _autograd.result_buffer(first.shape + (len(parts),), first)
    for part, column in zip(parts, target.unbind(-1), strict=True):
        column.copy_(part)
    return target


def row_gathers(index: Sequence[int], n: int, device: torch.device) -> tuple[Tensor, ...]:
    """The gathers of :func:`add_rows` for ``index`` (row ``k`` of the source goes to row
    ``index[k]`` of ``n``): the ``j``-th is, for each result row, its ``j``-th source row, or
    ``len(index)`` (the zero row appended) where it has fewer (at least one gather)."""
    groups: list[list[int]] = [[] for _ in range(n)]
    for k, i in enumerate(index):
        groups[i].append(k)
    depth = max([1, *(len(g) for g in groups)])  # one at least: no source row, zeros
    pad = len(index)
    return tuple(
        torch.tensor([g[j] if j < len(g) else pad for g in groups], dtype=torch.long, device=device)
        for j in range(depth)
    )


def add_rows(x: Tensor, gathers: Sequence[Tensor]) -> Tensor:
    """``x.new_zeros(n, ...).index_add(0, index, x)`` with the gathers of :func:`row_gathers`:
    rows of ``x`` summed into the rows of the result, in the order of ``x``'s rows (the same
    values), by ``index_select`` of ``x`` with a zero row appended.  torch's ``index_add`` and
    ``index_copy`` are not used: Inductor (torch 2.13) compiles their forward-mode derivative
    wrong (every tangent entry the sum of all the tangents added)."""
    xp = torch.cat((x, x.new_zeros(1, *x.shape[1:])))
    out = xp.index_select(0, gathers[0])
    for g in gathers[1:]:
        out = out + xp.index_select(0, g)
    return out
