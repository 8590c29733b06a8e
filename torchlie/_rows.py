"""The group operations on large batches: ``so3.act`` and ``se3.compose``, ``inverse``, ``act``.

``se3.compose`` (forward and backward) and the backward of ``se3.inverse`` split operands of
one batch shape into planes where matrix products are exact (see :func:`compose`); ``so3.act``
(forward and backward) and the backward of ``se3.act`` take products forms there, sums of
products by constant maps (see :func:`act`), on CPUs where such products are fast
(:func:`torchlie._layout.row_products`); everything else is written as follows.

Each row (or column) of a result is a sum of three products of an entry of one operand with a
row of the other, computed as one multiply and two multiply-adds over strided views of the
operands, where their entries lie, and written by the last of them straight into its place in
the result (``out=`` a strided view).  The operands are not split into planes first (one
transposition each way, as the exp and log kernels do, see :mod:`torchlie._layout`), and no
batched matrix product is called: torch's batched product of ``3 x 3`` matrices is a loop of
small products per element, slower than these few passes.  ``se3.inverse`` writes the rotation
block ``R^T`` and the zeros of the last row by one product of the top ``3 x 4`` block with a
constant ``(12, 16)`` map, then fills in the last entry (exact, but ``-0.0`` becomes ``+0.0``
and an infinite entry makes the rest of its pose NaN, as for the transpositions by product).
All of them, forward and backward, go over blocks of :data:`ROWS` rows (``act``:
:data:`ACT_BLOCKS` times as many, the kernels over planes :data:`PLANE_BLOCKS` times), so that
the operands' cache lines are read from the cache by the passes after the first.

Measured on a 2-core Intel Xeon VM (AVX-512), one thread, N = 10^6, ns per element, float32
(float64), against the kernels these replace (a batched matmul for ``act``, the 4x4 matrices split
into 16 planes by product and written entry by entry for ``compose`` and ``inverse``): forward
``so3.act`` 16.8 -> 10.3 (22.7 -> 17.3), ``se3.act`` 29.1 -> 14.0 (38.6 -> 29.1),
``se3.inverse`` 58.7 -> 30.7 (121 -> 59), ``se3.compose`` 82 -> 64 (178 -> 114); backward
``se3.act`` 70 -> 58, ``se3.inverse`` 76 -> 59, ``se3.compose`` 159 -> 134, ``so3.act`` 36 -> 38.
The outer product ``g p^T`` of the backward of ``act`` written column by column (three products
of a vector by a broadcast entry) instead of as one broadcast product of ``(3, 1)`` by ``(1, 3)``
per element, and in blocks with the rest of that backward; the rotation block's gradient in
``se3.inverse``'s backward column by column likewise, instead of one broadcast ``G_R^T - t g^T``
(forward+backward, in alternation, later, in a slower phase of the VM): ``so3.act`` 62 -> 49
(93 -> 80), ``se3.act`` 104 -> 71 (167 -> 122), ``se3.inverse`` 108 -> 94 (161 -> 164).
``act`` over blocks of 8192 rows (float64 4096) rather than the whole batch, forward (forward+
backward), same phase: ``so3.act`` 19.5 -> 14.3 (50 -> 42), ``se3.act`` 27.0 -> 19.9 (71 -> 63);
float64 31.0 -> 21.9 (84 -> 69), 42.0 -> 29.7 (129 -> 112); blocks of 4096, 16 384 and 32 768
rows took 16.5, 15.5 and 16.0 for ``so3.act`` (float64, 8192 to 32 768 rows: 22.9-24.0).  In an
earlier, faster phase of the VM (``so3.act`` 9 over the whole batch) blocks were no faster.
Blocks of 1024 rows cost more in calls than they save (``se3.compose`` 102), of 16 384 or more
the operands no longer stay in the 2 MB L2 (83-99).  Each entry is summed in the same order as
the entry-by-entry kernels under ``torch.compile`` (bit for bit on this CPU), not as a matmul.

Taken on eager CPU batches of at least :data:`torchlie._layout.MIN_ROWS` elements where autograd
records nothing (``out=`` is not differentiable: the double backward and forward mode take the
batched matmuls).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch
from torch import Tensor

from . import _layout
from ._autograd import block_rows

#: Rows per block of :func:`compose` and :func:`inverse` (forward and backward) for 4-byte
#: elements; half as many for float64: 256 kB of poses per operand.
ROWS = 4096

_LAST_ROWS: dict[torch.dtype, Tensor] = {}
_MAPS: dict[tuple[str, torch.dtype], Tensor] = {}


def taken(inputs: Sequence[Tensor], rows: int) -> bool:
    """Whether an op over ``rows`` elements of ``inputs`` takes the kernels of this module."""
    return _layout.large(inputs[0], rows) and not _layout.needs_graph(inputs)


def inverse_taken(T: Tensor) -> bool:
    """:func:`taken` for :func:`inverse`, whose product with a constant map is exact only at full
    float32 matmul precision (as :func:`torchlie._layout.by_product`)."""
    return _layout.by_product(T, 2) and not _layout.needs_graph((T,))


def _batch(*operands: tuple[Tensor, int]) -> torch.Size:
    return _layout.broadcast(*(x.shape[: x.dim() - k] for x, k in operands))


def _in_blocks(
    kernel: Callable[..., None],
    inputs: Sequence[tuple[Tensor, int]],
    outs: Sequence[tuple[Tensor, int]],
    blocks: int = 1,
) -> None:
    """``kernel(*inputs, *outs)`` block by block when every input has the batch shape of the
    results, else at once.  Each operand comes with its number of trailing (non-batch)
    dimensions; the results are written in place (contiguous, or views whose batch dimensions
    flatten, such as a block of a contiguous pose).  Blocks of ``blocks * ROWS`` rows (4-byte
    elements, one thread; see :func:`torchlie._autograd.block_rows`)."""
    first, k0 = outs[0]
    batch = first.shape[: first.dim() - k0]
    if any(x.shape[: x.dim() - k] != batch for x, k in inputs):
        kernel(*(x for x, _ in inputs), *(o for o, _ in outs))
        return
    n = batch.numel()
    flat_in = [x.reshape((n,) + x.shape[x.dim() - k :]) for x, k in inputs]
    flat_out = [o.view((n,) + o.shape[o.dim() - k :]) for o, k in outs]
    step = block_rows(blocks * ROWS, first)
    for start in range(0, n, step):
        block = slice(start, start + step)
        kernel(*(x[block] for x in flat_in), *(o[block] for o in flat_out))


def _last_row(dtype: torch.dtype) -> Tensor:
    """The last row ``(0, 0, 0, 1)`` of a pose (built once per dtype)."""
    row = _LAST_ROWS.get(dtype)
    if row is None:
        row = _LAST_ROWS[dtype] = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=dtype)
    return row


def _rotate(R: Tensor, p: Tensor, out: Tensor, t: Tensor | None = None) -> Tensor:
    """``R p (+ t)`` into ``out``: ``R`` is ``(..., 3, 3)`` (a view of a pose's block or not)."""
    if t is None:
        torch.mul(R[..., :, 0], p[..., :1], out=out)
    else:
        torch.addcmul(t, R[..., :, 0], p[..., :1], out=out)
    return out.addcmul_(R[..., :, 1], p[..., 1:2]).addcmul_(R[..., :, 2], p[..., 2:])


#: ``act`` and its backward go over blocks of ``ACT_BLOCKS * ROWS`` rows: their operands take
#: fewer bytes per row than a pose product's.
ACT_BLOCKS = 2

#: Off Intel CPUs the kernels of ``act`` and the forward of ``se3.inverse`` go over blocks this
#: many times as large (see :func:`_blocks`).
OTHER_CPU_BLOCKS = 4


def _blocks(blocks: int) -> int:
    """``blocks`` of :data:`ROWS` rows, as measured on an Intel Xeon, or :data:`OTHER_CPU_BLOCKS`
    times as many on other CPUs (:func:`torchlie._layout.intel_mkl`), where larger blocks measured
    faster: on an AMD EPYC (Zen 5), one thread, N = 10^6, ns per element, in alternation, float32
    (float64), ``ACT_BLOCKS`` 2 -> 8: ``so3.act`` forward 8.1 -> 7.0 (12.0 -> 9.3),
    forward+backward 23.2 -> 19.4 (35.0 -> 27.1), ``se3.act`` forward 10.6 -> 8.5 (16.0 -> 12.5),
    forward+backward 31.1 -> 25.8 (57.8 -> 47.3); blocks of 32 ``ROWS`` about the same as 8, the
    whole batch slower; ``se3.inverse`` forward over 4 ``ROWS`` rather than 1: 21.8 -> 16.3 (32.8
    -> 24.9).  On the Intel Xeon, ``act`` over 16 384 and 32 768 rows took 8-12 % longer than over
    8192."""
    return blocks if _layout.intel_mkl() else OTHER_CPU_BLOCKS * blocks


#: The kernels over planes (:func:`compose`, :func:`compose_grads`, :func:`inverse_grads`) go over
#: blocks of ``PLANE_BLOCKS * ROWS`` rows: fewer calls, and their planes stay in cache (one
#: thread, N = 10^6, ns per element, in alternation, 1 -> 4 (8): forward ``se3.compose`` 54.1 ->
#: 52.4, forward+backward 143 -> 130 (132), ``se3.inverse`` forward+backward 84.9 -> 79.5
#: (82.6); float64 107.6 -> 102.0, 285 -> 260 (262), 164 -> 156 (157)).
PLANE_BLOCKS = 4


def _pose_act_kernel(R: Tensor, p: Tensor, t: Tensor, out: Tensor) -> None:
    _rotate(R, p, out, t)


def products_taken(R: Tensor, *vectors: Tensor) -> bool:
    """Whether :func:`act` and :func:`act_grads` (or :func:`pose_act_grads`, ``R`` a pose) take
    their products forms: the vectors of ``R``'s batch shape, the matrix's entries contiguous
    (a rotation block of a pose is not: the form would read the translation), its matrix
    products exact (as :func:`torchlie._layout.by_product`), fast and summed alike on this CPU
    (:func:`torchlie._layout.row_products`)."""
    n = R.shape[-1]
    return (
        _layout.by_product(R, 2)
        and R.stride()[-2:] == (n, 1)
        and all(v.shape[:-1] == R.shape[:-2] for v in vectors)
        and _layout.row_products(R.dtype, 3)
    )


def _spread(v: Tensor, name: str) -> Tensor:
    return torch.mm(v, _map(name, v.dtype))


def _act_products_kernel(R: Tensor, p: Tensor, out: Tensor) -> None:
    m = R.shape[0]
    products = _spread(p, "by_column3").mul_(R.reshape(m, 9))  # R_ij p_j
    torch.mm(products, _map("row_sums3", R.dtype), out=out)


def act(R: Tensor, p: Tensor, t: Tensor | None = None) -> Tensor:
    """``R p`` (``so3.act``), or ``R p + t`` with ``R`` and ``t`` the blocks of a pose
    (``se3.act``); batch shapes broadcast.

    ``so3.act`` of one batch shape (see :func:`products_taken`) takes the products form: ``p``
    spread over the entries of ``R`` by a product with a constant map, one multiplication by
    the flattened ``R``, and the rows summed by a product with another (the same sums, in the
    same order, each product rounded on its own rather than fused with the sum; ``-0.0`` may
    become ``+0.0``, and an infinite entry makes its element's other results NaN).  One thread,
    N = 10^6, ns per element, in alternation with the kernel over rows, float32 (float64): 13.2
    -> 8.1 (20.3 -> 17.0).  For ``se3.act`` the form spreads over twelve entries, and measured
    no faster: 17.4 -> 18.8 (28.0 -> 28.3); its rows' kernel stays.  These figures are an Intel
    Xeon's; where MKL's products with constant maps are slow (an AMD EPYC) the kernels over rows
    are taken, see :func:`torchlie._layout.row_products`."""
    out = p.new_empty(_batch((R, 2), (p, 1)) + (3,))
    if t is not None:
        _in_blocks(_pose_act_kernel, ((R, 2), (p, 1), (t, 1)), ((out, 1),), _blocks(ACT_BLOCKS))
    elif products_taken(R, p):
        _in_blocks(_act_products_kernel, ((R, 2), (p, 1)), ((out, 1),), _blocks(ACT_BLOCKS))
    else:
        _in_blocks(_rotate, ((R, 2), (p, 1)), ((out, 1),), _blocks(ACT_BLOCKS))
    return out


def _act_grads_kernel(R: Tensor, p: Tensor, g: Tensor, dR: Tensor, dp: Tensor) -> None:
    # g p^T column by column (column j is g p_j): one broadcast product of (3, 1) by (1, 3)
    # per element costs three times as much (float32, 25 against 7 ns per element)
    for j in range(3):
        torch.mul(g, p[..., j : j + 1], out=dR[..., :, j])
    _rotate(R.transpose(-1, -2), g, dp)


def _act_grads_products_kernel(R: Tensor, p: Tensor, g: Tensor, dR: Tensor, dp: Tensor) -> None:
    m = R.shape[0]
    by_row = _spread(g, "by_row3")  # g_i at every (i, j)
    torch.mul(by_row, _spread(p, "by_column3"), out=dR.view(m, 9))  # g_i p_j
    by_row.mul_(R.reshape(m, 9))  # R_ij g_i, summed over i
    torch.mm(by_row, _map("column_sums3", R.dtype), out=dp)


def act_grads(R: Tensor, p: Tensor, g: Tensor, dR: Tensor) -> Tensor:
    """The backward of :func:`act`: ``g p^T`` written to ``dR`` (a contiguous ``(..., 3, 3)``
    tensor of the broadcast batch), and ``R^T g`` returned (``g`` has the broadcast batch).

    In the products form where :func:`act` takes it (one thread, N = 10^6, ns per element, in
    alternation with the kernel over rows, float32 (float64): 24.2 -> 17.6 (42.2 -> 33.4))."""
    dp = g.new_empty(g.shape)  # contiguous, whatever g's strides: its blocks are views
    operands, outs = ((R, 2), (p, 1), (g, 1)), ((dR, 2), (dp, 1))
    if products_taken(R, p, g):
        _in_blocks(_act_grads_products_kernel, operands, outs, _blocks(ACT_BLOCKS))
    else:
        _in_blocks(_act_grads_kernel, operands, outs, _blocks(ACT_BLOCKS))
    return dp


def _pose_act_grads_kernel(T: Tensor, p: Tensor, g: Tensor, dT: Tensor, dp: Tensor) -> None:
    _act_grads_kernel(T[..., :3, :3], p, g, dT[..., :3, :3], dp)
    dT[..., :3, 3].copy_(g)
    dT[..., 3, :].zero_()


def _pose_act_grads_products_kernel(
    T: Tensor, p: Tensor, g: Tensor, dT: Tensor, dp: Tensor
) -> None:
    m = T.shape[0]
    by_column = _spread(p, "by_column4")  # (p, 1) in every top row, the bottom row zero
    by_column[:, 3:12:4] = 1.0
    by_row = _spread(g, "by_row4")  # g_i in row i, the bottom row zero
    torch.mul(by_row, by_column, out=dT.view(m, 16))
    top = by_row[:, :12].mul_(T.reshape(m, 16)[:, :12])  # R_ij g_i (and t_i g_i, not summed)
    torch.mm(top, _map("column_sums4", T.dtype), out=dp)


def pose_act_grads(T: Tensor, p: Tensor, g: Tensor) -> tuple[Tensor, Tensor]:
    """The backward of ``se3.act``: ``[[g p^T, g], [0, 0]]`` and ``R^T g``.

    In the products form where :func:`products_taken` (``T``'s bottom row is not read; one
    thread, N = 10^6, ns per element, in alternation with the kernel over rows, float32
    (float64): 40.1 -> 36.5 (79.7 -> 61.0)), over blocks of :data:`ACT_BLOCKS` times
    :data:`ROWS` rows as the other ``act`` kernels: against blocks of ``ROWS`` rows, with one
    thread 37.4 -> 38.3 (62.1 -> 65.3), with two (blocks per thread) 24.4 -> 20.0 (41.2 ->
    41.6)."""
    dT, dp = g.new_empty(g.shape[:-1] + (4, 4)), g.new_empty(g.shape)
    operands, outs = ((T, 2), (p, 1), (g, 1)), ((dT, 2), (dp, 1))
    if products_taken(T, p, g):
        _in_blocks(_pose_act_grads_products_kernel, operands, outs, _blocks(ACT_BLOCKS))
    else:
        _in_blocks(_pose_act_grads_kernel, operands, outs, _blocks(ACT_BLOCKS))
    return dT, dp


def _compose_kernel(A: Tensor, B: Tensor, out: Tensor) -> None:
    for i in range(3):  # row i of the top block: sum_k A_ik B_k, plus A_i3 in the last column
        row = out[..., i, :]
        torch.mul(A[..., i, :1], B[..., 0, :], out=row)
        row.addcmul_(A[..., i, 1:2], B[..., 1, :]).addcmul_(A[..., i, 2:3], B[..., 2, :])
    out[..., :3, 3].add_(A[..., :3, 3])
    out[..., 3, :].copy_(_last_row(out.dtype))


def _top_planes(T: Tensor) -> Tensor:
    """The top ``3 x 4`` blocks of a ``(m, 4, 4)`` block of poses (or of their gradients) as
    ``(3, 4, m)`` planes (one transposition by product, see :mod:`torchlie._layout`)."""
    return _layout.matrix_planes(T[:, :3, :]).view(3, 4, T.shape[0])


def _pairs(name: str) -> tuple[tuple[int, int], list[tuple[int, int]]]:
    """The shape of the constant map ``name`` and its entries equal to one (see :func:`_map`)."""
    r, r4 = range(3), range(4)
    maps = {
        "top": ((12, 16), [(4 * i + j, 4 * i + j) for i in r for j in r4]),
        "transpose": ((12, 16), [(4 * i + j, 4 * j + i) for i in r for j in r]),
        "inverse_grads": (
            (12, 16),
            [(3 * j + i, 4 * i + j) for i in r for j in r] + [(9 + i, 4 * i + 3) for i in r],
        ),
        "by_column3": ((3, 9), [(j, 3 * i + j) for i in r for j in r]),
        "by_column4": ((3, 16), [(j, 4 * i + j) for i in r for j in r]),
        "by_row3": ((3, 9), [(i, 3 * i + j) for i in r for j in r]),
        "by_row4": ((3, 16), [(i, 4 * i + j) for i in r for j in r4]),
        "row_sums3": ((9, 3), [(3 * i + j, i) for i in r for j in r]),
        "column_sums3": ((9, 3), [(3 * i + j, j) for i in r for j in r]),
        "column_sums4": ((12, 3), [(4 * i + j, j) for i in r for j in r]),
    }
    return maps[name]


def _map(name: str, dtype: torch.dtype) -> Tensor:
    """The constant map ``name``, zeros and ones (built once per dtype).

    ``(12, 16)`` maps from twelve planes (or entries) to the flattened ``4 x 4`` matrix:
    ``"top"``, the twelve entries of a top block, row by row, to their places; ``"transpose"``,
    those of ``[R, t]`` to ``[R^T, 0]``; ``"inverse_grads"``, the planes of ``dR^T`` (``3 j + i``)
    and ``dt`` (``9 + i``) to ``[dR, dt]``.  The products forms of ``act`` (see
    :func:`act`) spread a vector over the entries of a flattened ``3 x 3`` matrix (suffix
    ``3``) or of the top rows of a ``4 x 4`` one (``4``), ``"by_column"`` (its entry ``j`` to
    the entries ``(i, j)``, ``j < 3``) or ``"by_row"`` (its entry ``i`` to the entries ``(i,
    j)``), and sum such entries by ``"row_sums3"`` (over ``j``) or ``"column_sums3"`` and
    ``"column_sums4"`` (over ``i``, the entries ``j < 3``).
    """
    out = _MAPS.get((name, dtype))
    if out is None:
        shape, pairs = _pairs(name)
        forms = torch.zeros(shape, dtype=dtype)
        for row, col in pairs:
            forms[row, col] = 1.0
        out = _MAPS[(name, dtype)] = forms
    return out


def _write(planes: Tensor, out: Tensor, name: str, last: bool) -> None:
    """Twelve planes (``(12, m)``, or shaped ``(3, 4, m)``) into the ``(m, 4, 4)`` rows ``out``
    by one product with the constant map ``name`` (see :func:`_map`), the last rows
    ``(0, 0, 0, 1)`` (``last``) or zero (exact, with the caveats of the transpositions by
    product, see :mod:`torchlie._layout`); by copies where such products are slow (see
    :func:`torchlie._layout.row_products`)."""
    m = out.shape[0]
    planes = planes.reshape(12, m)
    if not _layout.row_products(out.dtype, 16):
        _copy_planes(planes, out, name)
        if last:
            out[:, 3, :].copy_(_last_row(out.dtype))
        else:
            out[:, 3, :].zero_()
        return
    flat = torch.mm(planes.T, _map(name, out.dtype), out=out.view(m, 16))
    if last:  # filled after the product: addmm's bias costs more (see _inverse_kernel)
        flat[:, 15].fill_(1.0)


def _copy_planes(planes: Tensor, out: Tensor, name: str) -> None:
    """The top ``3 x 4`` blocks of ``out`` from twelve ``(12, m)`` planes, placed as the map
    ``name`` of :func:`_write` places them, by strided copies."""
    m = out.shape[0]
    if name == "top":  # plane 4 i + j to (i, j)
        out[:, :3, :].copy_(planes.T.view(m, 3, 4))
    elif name == "inverse_grads":  # plane 3 j + i to (i, j), plane 9 + i to (i, 3)
        out[:, :3, :3].copy_(planes[:9].view(3, 3, m).permute(2, 1, 0))
        out[:, :3, 3].copy_(planes[9:].T)
    else:
        raise ValueError(f"torchlie._rows._copy_planes: no copy form for the map {name!r}")


def _compose_planes_kernel(A: Tensor, B: Tensor, out: Tensor) -> None:
    a, b = _top_planes(A), _top_planes(B)
    top = a[:, :1] * b[:1]  # (3, 4, m): row i is sum_k A_ik B_k, as in _compose_kernel
    top.addcmul_(a[:, 1:2], b[1:2]).addcmul_(a[:, 2:3], b[2:3])
    top[:, 3] += a[:, 3]
    _write(top, out, "top", last=True)


def planes_taken(*operands: Tensor) -> bool:
    """Whether :func:`compose` and :func:`compose_grads` split their operands into planes: all
    of one batch shape, and their matrix products exact (as :func:`torchlie._layout.by_product`)."""
    first = operands[0]
    return _layout.by_product(first, 2) and all(x.shape == first.shape for x in operands)


def compose(A: Tensor, B: Tensor) -> Tensor:
    """``A B`` of two poses (batch shapes broadcast; the bottom rows are not read).

    Operands of one batch shape, where matrix products are exact, are split into planes: the
    top blocks as ``(3, 4)`` planes each, the rows of the product as three broadcast operations
    over them (each twelve planes wide), written back by one product with a constant map; the
    backward alike (one thread, N = 10^6, in alternation with the kernels over rows, ns per
    element, forward (forward+backward): float32 74 -> 58 (221 -> 150), float64 127 -> 117 (355
    -> 306); the same bits on finite entries)."""
    out = A.new_empty(_batch((A, 2), (B, 2)) + (4, 4))
    if planes_taken(A, B):
        _in_blocks(_compose_planes_kernel, ((A, 2), (B, 2)), ((out, 2),), PLANE_BLOCKS)
    else:
        _in_blocks(_compose_kernel, ((A, 2), (B, 2)), ((out, 2),))
    return out


def _compose_grads_kernel(A: Tensor, B: Tensor, G: Tensor, dA: Tensor, dB: Tensor) -> None:
    # dA_ij = sum_k G_ik B_jk (j < 3), dA_i3 = G_i3; dB_kj = sum_i A_ik G_ij; bottom rows zero
    for i in range(3):
        row = dA[..., i, :3]
        torch.mul(G[..., i, :1], B[..., :3, 0], out=row)
        for k in range(1, 4):
            row.addcmul_(G[..., i, k : k + 1], B[..., :3, k])
    dA[..., :3, 3].copy_(G[..., :3, 3])
    for k in range(3):
        row, a = dB[..., k, :], A[..., :3, k : k + 1]
        torch.mul(a[..., 0, :], G[..., 0, :], out=row)
        row.addcmul_(a[..., 1, :], G[..., 1, :]).addcmul_(a[..., 2, :], G[..., 2, :])
    dA[..., 3, :].zero_()
    dB[..., 3, :].zero_()


def _compose_grads_planes_kernel(A: Tensor, B: Tensor, G: Tensor, dA: Tensor, dB: Tensor) -> None:
    a, b, g = _top_planes(A), _top_planes(B), _top_planes(G)
    da = torch.empty_like(g)  # (3, 4, m), summed in the order of _compose_grads_kernel
    rot = torch.mul(g[:, :1], b[None, :, 0], out=da[:, :3])  # (i, j): G_ik B_jk over k
    for k in range(1, 4):
        rot.addcmul_(g[:, k : k + 1], b[None, :, k])
    da[:, 3] = g[:, 3]
    db = a[0, :3, None] * g[:1]  # (k, j): A_ik G_ij over i
    db.addcmul_(a[1, :3, None], g[1:2]).addcmul_(a[2, :3, None], g[2:3])
    _write(da, dA, "top", last=False)
    _write(db, dB, "top", last=False)


def compose_grads(A: Tensor, B: Tensor, G: Tensor) -> tuple[Tensor, Tensor]:
    """The backward of :func:`compose` over the broadcast batch (``G``'s); in planes where
    :func:`compose` takes them."""
    dA, dB = G.new_empty(G.shape), G.new_empty(G.shape)
    operands, outs = ((A, 2), (B, 2), (G, 2)), ((dA, 2), (dB, 2))
    if planes_taken(A, B, G):
        _in_blocks(_compose_grads_planes_kernel, operands, outs, PLANE_BLOCKS)
    else:
        _in_blocks(_compose_grads_kernel, operands, outs)
    return dA, dB


def _inverse_kernel(T: Tensor, out: Tensor) -> None:
    n = T.shape[0]
    if _layout.row_products(T.dtype, 16):
        forms = _map("transpose", T.dtype)  # [R^T, 0] from [R, t], rows read where they lie
        flat = torch.mm(T.reshape(n, 16)[:, :12], forms, out=out.view(n, 16))
        # the last entry filled after the product, not as the bias of torch.addmm: the same
        # bits, float32 N = 10^6 37.3 -> 33.2 ns per element (float64 67.4 -> 59.0),
        # se3.compose's _write 53.8 -> 48.9 (105.1 -> 98.1)
        flat[:, 15].fill_(1.0)
    else:  # the same values by copies (exact, -0.0 and infinities kept)
        out[:, :3, :3].copy_(T[:, :3, :3].mT)
        out[:, 3, :].copy_(_last_row(out.dtype))
    t = out[:, :3, 3]  # -R^T t = -sum_j R_j t_j (rows R_j of R)
    torch.mul(T[:, 0, :3], T[:, 0, 3:], out=t)
    t.addcmul_(T[:, 1, :3], T[:, 1, 3:]).addcmul_(T[:, 2, :3], T[:, 2, 3:]).neg_()


def inverse(T: Tensor) -> Tensor:
    """``[[R^T, -R^T t], [0, 1]]`` (the bottom row is not read); see :func:`inverse_taken`."""
    out = T.new_empty(T.shape)
    flat = T.reshape((-1, 4, 4))
    _in_blocks(_inverse_kernel, ((flat, 2),), ((out.view(flat.shape), 2),), _blocks(1))
    return out


def _inverse_grads_kernel(T: Tensor, G: Tensor, dT: Tensor) -> None:
    # dR_ij = G_ji - t_i G_j3, dt_i = -sum_j R_ij G_j3; bottom row zero
    g = G[..., :3, 3]
    for j in range(3):  # column j of dR: row j of G_R minus t G_j3
        torch.addcmul(G[..., j, :3], T[..., :3, 3], G[..., j, 3:], value=-1.0, out=dT[..., :3, j])
    _rotate(T[..., :3, :3], g, dT[..., :3, 3]).neg_()
    dT[..., 3, :].zero_()


def _inverse_grads_planes_kernel(T: Tensor, G: Tensor, dT: Tensor) -> None:
    a, g = _top_planes(T), _top_planes(G)
    m = T.shape[0]
    planes = T.new_empty(12, m)  # dR^T (planes 3 j + i), then dt, as _inverse_grads_kernel
    torch.addcmul(g[:, :3], a[None, :, 3], g[:, 3:], value=-1.0, out=planes[:9].view(3, 3, m))
    dt = torch.mul(a[:, 0], g[0, 3:], out=planes[9:])
    dt.addcmul_(a[:, 1], g[1, 3:]).addcmul_(a[:, 2], g[2, 3:]).neg_()
    _write(planes, dT, "inverse_grads", last=False)


def inverse_grads(T: Tensor, G: Tensor) -> Tensor:
    """The backward of :func:`inverse`; in planes where :func:`compose` takes them (one thread,
    N = 10^6, ns per element, in alternation with the kernel over rows: float32 57.5 -> 47.8,
    float64 97 -> 96; the same bits on finite entries).  The forward stays over rows: planes
    made it no faster (float32 37.7 -> 39.4, float64 70.7 -> 75.3)."""
    dT = G.new_empty(G.shape)
    if planes_taken(T, G):
        _in_blocks(_inverse_grads_planes_kernel, ((T, 2), (G, 2)), ((dT, 2),), PLANE_BLOCKS)
    else:
        _in_blocks(_inverse_grads_kernel, ((T, 2), (G, 2)), ((dT, 2),))
    return dT
