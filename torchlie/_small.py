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

Three ops have a *matrix form* instead, a handful of calls that are not the component-wise
operations: ``quaternion.multiply`` as ``L(a) b`` (the left-multiplication matrix of ``a``
gathered from its components, one small matrix product), ``quaternion.to_matrix`` as the
products ``q q^T`` mapped to the nine entries of ``|q|^2 R`` and to ``|q|^2`` by one matrix
product, and float32 ``so3.exp`` (with it the rotation block of float32 ``se3.exp``) as the
matrix of the unit quaternion ``(cos(t/2), sin(t/2) w / t)``, in float64.  They agree with the
component-wise kernels to a few ulp, not bit for bit: float32 ``so3.exp`` and
``quaternion.to_matrix`` are evaluated in float64 and rounded once (within 0.34 and 0.32 eps of
the 60-digit references, against 0.92 and 1.17 for the component kernels), float64
``quaternion.to_matrix`` within 1.21 eps (1.24).  Each element's result is the same whatever
batch it is in (the products of small matrices are plain loops, element by element).  float64
``so3.exp`` keeps its compensated kernel (:mod:`torchlie._compensated`), which a plain formula
in float64 cannot match.  The backwards are the ops' own closed forms at every size.

Taken on CPU tensors, in eager mode outside ``torch.func`` transforms (``torch.compile`` fuses
the component-wise form into one loop, which is faster at every size).
"""

from __future__ import annotations

import torch
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


# ----------------------------------------------------------------------------------------------
# Matrix forms
# ----------------------------------------------------------------------------------------------

#: Batches below this take the matrix forms (float32, one thread, per call, alternated with
#: the component kernels, us: ``so3.exp`` 209 -> 103 at one element, 308 -> 287 at 1000, 327
#: -> 333 at 2048; ``quaternion.to_matrix`` 130 -> 72, 186 -> 165, 216 -> 250;
#: ``quaternion.multiply`` 137 -> 44, 175 -> 129, 240 -> 232; float64 alike).
MATRIX_ROWS = 1024

_F64 = torch.float64
#: Clamp of the half angle: ``sin(h) / h`` is 1 in float64 below it.
_H_MIN = 1e-150


def matrix_form(x: Tensor, rows: int) -> bool:
    """Whether an op over ``rows`` elements like ``x`` takes its matrix form."""
    return rows < MATRIX_ROWS and _layout.eager_cpu(x)


def _hamilton_left() -> tuple[Tensor, Tensor]:
    """Index and sign of ``L(a)``, the ``4 x 4`` matrix with ``L(a) b = a b`` (Hamilton
    product): ``L(a)[i, j] = sign[i, j] a[index[i, j]]``."""
    index = torch.tensor([[0, 1, 2, 3], [1, 0, 3, 2], [2, 3, 0, 1], [3, 2, 1, 0]])
    sign = torch.tensor([[1, -1, -1, -1], [1, 1, -1, 1], [1, 1, 1, -1], [1, -1, 1, 1]])
    return index, sign


_L_INDEX, _L_SIGN = _hamilton_left()
_L_FLAT = _L_INDEX.flatten()


def _quadratic_forms(scale_vector: float) -> Tensor:
    """``(16, 10)``: the products ``q_a q_b`` (row ``4 a + b``) to the nine entries of ``|q|^2 R``
    (row by row) and ``|q|^2``, for ``q = (w, x, y, z)`` whose vector part is ``scale_vector``
    times the quaternion's (a power of two: the coefficients stay exact)."""
    forms = torch.zeros(4, 4, 10, dtype=_F64)
    w, x, y, z = range(4)
    # R = (w^2 - |v|^2) I + 2 v v^T + 2 w hat(v), entry by entry
    entries = {
        (0, 0): [(w, w, 1), (x, x, 1), (y, y, -1), (z, z, -1)],
        (1, 1): [(w, w, 1), (x, x, -1), (y, y, 1), (z, z, -1)],
        (2, 2): [(w, w, 1), (x, x, -1), (y, y, -1), (z, z, 1)],
        (0, 1): [(x, y, 2), (w, z, -2)], (1, 0): [(x, y, 2), (w, z, 2)],
        (0, 2): [(x, z, 2), (w, y, 2)], (2, 0): [(x, z, 2), (w, y, -2)],
        (1, 2): [(y, z, 2), (w, x, -2)], (2, 1): [(y, z, 2), (w, x, 2)],
    }  # fmt: skip
    for (i, j), terms in entries.items():
        for a, b, c in terms:
            forms[a, b, 3 * i + j] = c
    for a in range(4):
        forms[a, a, 9] = 1
    # q_a q_b with k vector components carries scale_vector^k
    for a in range(4):
        for b in range(4):
            forms[a, b] /= scale_vector ** ((a > 0) + (b > 0))
    return forms.reshape(16, 10)


_CONSTANTS: dict[tuple[str, torch.dtype], Tensor] = {}
_SOURCES = {
    "L_sign": lambda: _L_SIGN,
    "to_matrix": lambda: _quadratic_forms(1.0),
    "exp": lambda: _quadratic_forms(2.0)[:, :9],
}


def _constant(name: str, dtype: torch.dtype) -> Tensor:
    out = _CONSTANTS.get((name, dtype))
    if out is None:
        out = _CONSTANTS[(name, dtype)] = _SOURCES[name]().to(dtype).contiguous()
    return out


def _outer(v: Tensor) -> Tensor:
    """``v v^T`` of each 4-vector, flattened to 16 entries."""
    return (v.unsqueeze(-1) * v.unsqueeze(-2)).flatten(-2)


#: Batches from this size gather ``L(a)`` by ``index_select`` (1000 elements, float32: 16 us
#: against 53 for advanced indexing; one element: 7 against 4).
_SELECT_ROWS = 64


def multiply(a: Tensor, b: Tensor) -> Tensor:
    """Hamilton product ``a b`` as ``L(a) b`` (batch shapes broadcast)."""
    if a.shape[:-1].numel() < _SELECT_ROWS:
        gathered = a[..., _L_INDEX]
    else:
        gathered = a.index_select(-1, _L_FLAT).view(a.shape[:-1] + (4, 4))
    left = gathered * _constant("L_sign", a.dtype)
    return torch.matmul(left, b.unsqueeze(-1)).squeeze(-1)


def to_matrix(q: Tensor) -> Tensor:
    """Rotation matrix of ``q / |q|``: ``q q^T`` mapped to the entries of ``|q|^2 R`` and to
    ``|q|^2`` by one product, then one division (float32 input evaluated in float64)."""
    v = q.to(_F64) if q.dtype == torch.float32 else q
    forms = torch.matmul(_outer(v), _constant("to_matrix", v.dtype))
    return (forms[..., :9] / forms[..., 9:]).to(q.dtype).view(q.shape[:-1] + (3, 3))


def exp_float32(w: Tensor) -> Tensor:
    """``Exp(w)`` of float32 rotation vectors, evaluated in float64 and rounded once: the matrix
    of the unit quaternion ``(cos h, sin(h) w / t)``, ``t = |w|``, ``h = t / 2`` (sine and cosine
    of the same ``h``, so that the quaternion stays a unit one at every angle)."""
    t = torch.linalg.vector_norm(w, dim=-1, keepdim=True, dtype=_F64)
    h = t.mul_(0.5).clamp_min_(_H_MIN)
    s = torch.sin(h).div_(h)  # sin(h) / h = 2 sin(h) / t: the vector part is twice q's
    q = torch.cat((torch.cos(h), s * w), -1)  # float64 (s) times float32 (w): float64
    return torch.matmul(_outer(q), _constant("exp", _F64)).to(w.dtype).view(w.shape[:-1] + (3, 3))
