"""Small batches: an op as fewer ATen calls than one per arithmetic operation.

The eager kernels are written component by component (one element-wise call per multiply or
add over the planes of the batch, see :mod:`torchlie._layout`), which is what streams a large
batch through memory fastest.  Over a small batch each call costs its dispatch, 2-4 us on CPU
whatever the batch.  Below :data:`SMALL_ROWS` elements the ops with a small-batch form take it
instead: the same operations on the same values, in the same order, with the component axis
inside each call (the planes stacked into one ``(k, *batch)`` tensor, gathered by index where a
formula reads several components alike), and selections by ``argmax`` and ``gather`` rather
than one-hot sums.  The results are those of the component-wise form bit for bit (the tests
compare them with ``torch.equal``).

Shepperd's method has one (``quaternion.from_matrix``, ``so3.log``, ``se3.log``: the
orthogonalisation step and the selection among four candidates, about 100 calls, become 35):
at one element 1.5-1.6x, 1.4-1.5x and 1.1-1.2x faster per call, at 1000 elements 1.2x, 1.1-1.2x
and 1.0x.  The other ops are a few tens of calls with little shared structure, which a
component axis inside each call does not shorten much.

Taken on CPU tensors, in eager mode outside ``torch.func`` transforms (``torch.compile`` fuses
the component-wise form into one loop, which is faster at every size).
"""

from __future__ import annotations

from torch import Tensor

from torchlie import _layout

#: Batches (number of elements) below this take the small-batch forms (float32 and float64, one
#: thread, per call, ``quaternion.from_matrix``: 1.5-1.6x faster at one element, 1.2x at 1000,
#: 0.9x at 2048; ``se3.log`` 0.8-0.9x there).
SMALL_ROWS = 1024


def enabled(x: Tensor, rows: int) -> bool:
    """Whether an op over ``rows`` elements like ``x`` takes its small form."""
    return rows < SMALL_ROWS and _layout.eager_cpu(x)


def interleave(planes: Tensor) -> Tensor:
    """``(k, *batch)`` planes as one ``(*batch, k)`` tensor (one copy)."""
    return planes.movedim(0, -1).contiguous()
