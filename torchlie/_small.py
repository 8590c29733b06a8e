"""Small batches: an op as a handful of ATen calls, not one per arithmetic operation.

The eager kernels are written component by component (one element-wise call per multiply or
add over the planes of the batch, see :mod:`torchlie._layout`), which is what streams a large
batch through memory fastest.  Over a small batch each call costs its dispatch, 1-4 us on CPU
whatever the batch.  Below :data:`MATRIX_ROWS` elements the ops below take a *matrix form*
instead, a few calls with the component axis inside each (small matrix products, a gather),
which are not the component-wise operations:

* ``quaternion.multiply`` as the 16 products ``a_j b_k`` mapped to the four components by one
  matrix product;
* ``quaternion.to_matrix`` as the products ``q q^T`` mapped to the nine entries of ``|q|^2 R``
  and to ``|q|^2`` by one matrix product;
* float32 ``so3.exp`` as the matrix of the unit quaternion ``(cos(t/2), sin(t/2) w / t)``, in
  float64, and float32 ``se3.exp`` whole (``Jl(phi) rho`` in float64 too);
* Shepperd's method (``quaternion.from_matrix``, ``so3.log``, ``se3.log``): the
  orthogonalisation step as two products of ``3 x 3`` matrices, the four candidates and their
  pivots ``4 q_k^2`` as one product of the nine entries with a constant ``(9, 20)`` map, the
  candidate by ``argmax`` and ``gather``; float32 input evaluated in float64;
* the plain backward passes (no ``create_graph``) of ``quaternion.multiply`` (two products with
  constant maps), ``quaternion.to_matrix``, ``so3.exp``, ``so3.log``, ``se3.exp`` and
  ``se3.log`` (whole ``(rows, 3)`` vectors: ``Jl``, ``Jl^-1`` and ``Q(rho, phi)`` applied by
  their coefficients), float32 in float64; the other ops' backwards are a few whole-tensor
  calls already (``quaternion.apply`` and ``quaternion.from_matrix`` take their differentiable
  formulas on small batches);
* below :data:`POSE_ROWS` poses, ``se3.compose`` and ``se3.inverse`` (forward and backward) as
  one batched product of ``4 x 4`` matrices each, their bottom rows put to ``(0, 0, 0, 1)`` or
  zero by ``where`` (the inputs' bottom rows are still not read).

They agree with the component-wise kernels to a few ulp, not bit for bit: float32 ``so3.exp``,
``quaternion.to_matrix``, ``quaternion.from_matrix`` and ``so3.log`` are evaluated in float64
and rounded once (within 0.34, 0.32, 0.36 and 0.41 eps of the 60-digit references, against
0.92, 1.17, 1.06 and 1.29 for the component kernels), float64 ``quaternion.to_matrix`` and
``quaternion.from_matrix`` within 1.21 and 1.23 eps (1.24, 1.15).  Each element's value and
gradient is the same whatever batch below :data:`MATRIX_ROWS` it is in (tested): the batched
products of small matrices are plain loops, element by element, and every other product is one
with a constant map, each row summed alike whatever the number of rows (``addmm``, which adds
the constant inside the sum, does not, nor does ``torch.matmul`` of 2-D operands or of a batch
with a shared operand, which goes to the BLAS as one matrix product: :func:`matmul` keeps the
batched kernel for the group ops).  float64 ``so3.exp`` keeps its compensated kernel
(:mod:`torchlie._compensated`), which a plain formula in float64 cannot match.

Taken on CPU tensors, in eager mode outside ``torch.func`` transforms (``torch.compile`` fuses
the component-wise form into one loop, which is faster at every size).
"""

from __future__ import annotations

import torch
from torch import Tensor

from torchlie import _coeffs, _layout

# ----------------------------------------------------------------------------------------------
# Matrix forms
# ----------------------------------------------------------------------------------------------

#: Batches below this take the matrix forms (one thread, per call, alternated with the component
#: kernels, Intel Xeon with AVX-512, us, float32: ``quaternion.multiply`` 51 -> 14 at one
#: element, 76 -> 48 at 1000; ``quaternion.to_matrix`` 51 -> 23, 82 -> 70; ``so3.exp`` 77 -> 30,
#: 110 -> 86; ``quaternion.from_matrix`` 181 -> 33, 222 -> 180; ``so3.log`` 188 -> 46, 232 ->
#: 210; ``se3.log`` 265 -> 74, 335 -> 309; float64 alike, but for ``so3.exp``; at 2048 elements
#: the matrix forms were as fast or slower on a 2-core AMD EPYC).
MATRIX_ROWS = 1024

_F64 = torch.float64
#: Clamp of the half angle: ``sin(h) / h`` is 1 in float64 below it.
_H_MIN = 1e-150


#: Poses below this many take the 4 x 4 product forms of ``se3.compose`` and ``se3.inverse``
#: (:func:`pose_compose`, :func:`pose_inverse`): per call, one thread, float32, on a 2-core AMD
#: EPYC, in alternation with the products of the blocks, us, ``se3.compose`` forward at 1, 16
#: and 64 poses 18.2 -> 9.8, 19.3 -> 11.6, 22.4 -> 16.4, ``se3.inverse`` 17.7 -> 12.2, 17.7 ->
#: 14.7, 20.7 -> 20.0 (at 256, 31 -> 55 and 25 -> 38: the batched product of 4 x 4 matrices
#: is a plain loop per element).
POSE_ROWS = 32


def pose_form(x: Tensor, rows: int) -> bool:
    """Whether a pose op over ``rows`` elements like ``x`` takes its ``4 x 4`` product form."""
    return rows < POSE_ROWS and _layout.eager_cpu(x)


def matrix_form(x: Tensor, rows: int) -> bool:
    """Whether an op over ``rows`` elements like ``x`` takes its matrix form."""
    return rows < MATRIX_ROWS and _layout.eager_cpu(x)


def matmul(A: Tensor, B: Tensor) -> Tensor:
    """``A @ B`` (batch shapes broadcast); on small eager CPU batches as one batched product of
    operands expanded to the broadcast batch, whatever their shapes: torch's batched product of
    small matrices is a plain loop per element, so that each element's result is the same in
    any batch (``torch.matmul`` hands a product of 2-D operands, or of a batch with one shared
    matrix, to the BLAS as one matrix product, which may sum in another order)."""
    if A.dim() == 3 and B.dim() == 3 and A.shape[0] == B.shape[0]:
        return torch.bmm(A, B)
    batch = _layout.broadcast(A.shape[:-2], B.shape[:-2])
    if not matrix_form(A, batch.numel()):
        return torch.matmul(A, B)
    a, b = A.expand(batch + A.shape[-2:]), B.expand(batch + B.shape[-2:])
    if len(batch) == 1:  # a batch dimension of stride 0 is one bmm takes as it is
        return torch.bmm(a, b)
    a, b = a.reshape((-1,) + A.shape[-2:]), b.reshape((-1,) + B.shape[-2:])
    return torch.bmm(a, b).view(batch + (A.shape[-2], B.shape[-1]))


def _hamilton_forms() -> Tensor:
    """``(16, 4)``: the products ``a_j b_k`` (row ``4 j + k``) to the components of the Hamilton
    product ``a b``."""
    forms = torch.zeros(4, 4, 4, dtype=_F64)
    w, x, y, z = range(4)
    terms = (
        ((w, w, 1), (x, x, -1), (y, y, -1), (z, z, -1)),  # w
        ((w, x, 1), (x, w, 1), (y, z, 1), (z, y, -1)),  # x
        ((w, y, 1), (x, z, -1), (y, w, 1), (z, x, 1)),  # y
        ((w, z, 1), (x, y, 1), (y, x, -1), (z, w, 1)),  # z
    )
    for i, products in enumerate(terms):
        for j, k, c in products:
            forms[j, k, i] = c
    return forms.reshape(16, 4)


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


def _pair_forms(forms: Tensor) -> Tensor:
    """``(10, k)``: a ``(16, k)`` map of the products ``q_a q_b`` (row ``4 a + b``) folded onto
    the ten with ``a <= b``, pairs in row-major order (``(0, 0), (0, 1), ..., (3, 3)``)."""
    full = forms.view(4, 4, -1)
    pairs = [(a, b) for a in range(4) for b in range(a, 4)]
    return torch.stack([full[a, a] if a == b else full[a, b] + full[b, a] for a, b in pairs])


def _symmetrized(forms: Tensor) -> Tensor:
    """``(16, k)``: ``M + M^T`` of each column ``M`` (a ``4 x 4`` matrix, row ``4 a + b``) of a
    ``(16, k)`` map of the products ``q_a q_b``: the gradient of ``q^T M q`` is ``(M + M^T) q``."""
    full = forms.view(4, 4, -1)
    return (full + full.transpose(0, 1)).reshape(16, -1)


_CONSTANTS: dict[tuple[str, torch.dtype], Tensor] = {}
_SOURCES = {
    "multiply": _hamilton_forms,
    "to_matrix": lambda: _quadratic_forms(1.0),
    "to_matrix_pairs": lambda: _pair_forms(_quadratic_forms(1.0)[:, :9]),
    "to_matrix_gradient": lambda: _symmetrized(_quadratic_forms(1.0)[:, :9]),
    "exp": lambda: _quadratic_forms(2.0)[:, :9],
    "bottom": lambda: torch.tensor([[0.0, 0.0, 0.0, 1.0]]),
    "zero_row": lambda: torch.zeros(1, 4),
    # 4 x 4 masks (as booleans) and the matrix with a 1 in its corner (3, 3) only
    "top_rows": lambda: torch.arange(4).unsqueeze(-1).expand(4, 4) < 3,
    "rotation_block": lambda: (torch.arange(4) < 3).unsqueeze(-1) & (torch.arange(4) < 3),
    "translation_column": lambda: (torch.arange(4) < 3).unsqueeze(-1) & (torch.arange(4) == 3),
    "corner": lambda: torch.diag(torch.tensor([0.0, 0.0, 0.0, 1.0])),
    "zero": lambda: torch.zeros(()),
}


def constant(name: str, dtype: torch.dtype) -> Tensor:
    """The constant map ``name`` (a key of ``_SOURCES``) in ``dtype``, built once."""
    out = _CONSTANTS.get((name, dtype))
    if out is None:
        out = _CONSTANTS[(name, dtype)] = _SOURCES[name]().to(dtype).contiguous()
    return out


def pose_compose(A: Tensor, B: Tensor) -> Tensor:
    """``A B`` of poses (batch shapes broadcast) as one batched product of ``4 x 4`` matrices
    whose bottom rows are put to ``(0, 0, 0, 1)`` (by ``where``: the inputs' bottom rows are not
    read, the result's is ``(0, 0, 0, 1)``)."""
    top, corner = constant("top_rows", torch.bool), constant("corner", A.dtype)
    return matmul(torch.where(top, A, corner), torch.where(top, B, corner))


def pose_compose_grads(A: Tensor, B: Tensor, G: Tensor) -> tuple[Tensor, Tensor]:
    """The gradients of :func:`pose_compose` for ``G`` (over the broadcast batch): ``G_top B'^T``
    and ``R_A'^T G_top`` with ``G_top`` the top rows of ``G``, ``B'`` as in the forward and
    ``R_A'`` the rotation block of ``A`` alone (bottom rows zero)."""
    zero, top_rows = constant("zero", G.dtype), constant("top_rows", torch.bool)
    top = torch.where(top_rows, G, zero)
    b = torch.where(top_rows, B, constant("corner", B.dtype))
    a = torch.where(constant("rotation_block", torch.bool), A, zero)
    return matmul(top, b.mT), matmul(a.mT, top)


def pose_inverse(T: Tensor) -> Tensor:
    """``[[R^T, -R^T t], [0, 1]]`` of poses as ``P - P Q`` (one ``baddbmm``) with
    ``P = [[R^T, 0], [0, 1]]`` and ``Q`` the translation column alone."""
    x = T if T.dim() == 3 else T.reshape(-1, 4, 4)
    P = torch.where(constant("rotation_block", torch.bool), x, constant("corner", x.dtype)).mT
    Q = torch.where(constant("translation_column", torch.bool), x, constant("zero", x.dtype))
    return _result(torch.baddbmm(P, P, Q, alpha=-1.0), T, 2)


def pose_inverse_grads(T: Tensor, G: Tensor) -> Tensor:
    """The gradient of :func:`pose_inverse` for ``G``: ``[[G_R^T - t g^T, -R g], [0, 0]]``
    (``g`` the translation column of ``G``) as ``G_R'^T - M N`` by one ``baddbmm``, with
    ``M = [[R, t], [0, 0]]`` and ``N = [[0, g], [g^T, 0]]``."""
    x, y = (T, G) if T.dim() == 3 else (T.reshape(-1, 4, 4), G.reshape(-1, 4, 4))
    zero = constant("zero", y.dtype)
    C = torch.where(constant("rotation_block", torch.bool), y, zero).mT
    M = torch.where(constant("top_rows", torch.bool), x, zero)
    g = torch.where(constant("translation_column", torch.bool), y, zero)
    return _result(torch.baddbmm(C, M, g + g.mT, alpha=-1.0), T, 2)


def _outer(v: Tensor, u: Tensor | None = None) -> Tensor:
    """``v u^T`` of each pair of 4-vectors (``v v^T`` without ``u``; batch shapes broadcast),
    flattened to 16 entries."""
    return (v.unsqueeze(-1) * (v if u is None else u).unsqueeze(-2)).flatten(-2)


def multiply(a: Tensor, b: Tensor) -> Tensor:
    """Hamilton product ``a b``: the products ``a_j b_k`` mapped to its components by one matrix
    product (batch shapes broadcast)."""
    return torch.matmul(_outer(a, b), constant("multiply", a.dtype))


def _compute(x: Tensor) -> Tensor:
    """``x`` in the dtype the forms compute in: float64 for float32 (rounded once at the end)."""
    return x.double() if x.dtype == torch.float32 else x


def to_matrix(q: Tensor) -> Tensor:
    """Rotation matrix of ``q / |q|``: ``q q^T`` mapped to the entries of ``|q|^2 R`` and to
    ``|q|^2`` by one product, then one division (float32 input evaluated in float64)."""
    v = _compute(q)
    forms = torch.matmul(_outer(v), constant("to_matrix", v.dtype))
    R = forms[..., :9] / forms[..., 9:]
    return (R.float() if q.dtype == torch.float32 else R).unflatten(-1, (3, 3))


def _half_angle(w: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """``(h, sin(h) / h, cos h)`` in float64, ``h = |w| / 2`` clamped at :data:`_H_MIN` (where
    ``sin(h) / h`` is 1)."""
    h = torch.linalg.vector_norm(w, dim=-1, keepdim=True, dtype=_F64).mul_(0.5)
    h.clamp_min_(_H_MIN)
    return h, torch.sin(h).div_(h), torch.cos(h)


def _exp_float64(w: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """``Exp(w)`` in float64 as ``(..., 9)`` entries, row by row: the matrix of the unit
    quaternion ``(cos h, sin(h) w / t)``, ``t = |w|``, ``h = t / 2`` (sine and cosine of the same
    ``h``, so that the quaternion stays a unit one at every angle); with ``h`` (clamped at
    :data:`_H_MIN`), ``sin(h) / h`` and ``cos h``."""
    h, s, c = _half_angle(w)  # s = sin(h) / h = 2 sin(h) / t: the vector part is twice q's
    q = torch.cat((c, s * w), -1)  # float64 (s) times float32 (w): float64
    return torch.matmul(_outer(q), constant("exp", _F64)), h, s, c


def exp_float32(w: Tensor) -> Tensor:
    """``Exp(w)`` of float32 rotation vectors, evaluated in float64 and rounded once."""
    R, _, _, _ = _exp_float64(w)
    return R.float().unflatten(-1, (3, 3))


def se3_exp_float32(xi: Tensor) -> Tensor:
    """``[[Exp(phi), Jl(phi) rho], [0, 1]]`` of float32 twists ``(rho, phi)``, evaluated in
    float64 and rounded once; the rotation block is :func:`exp_float32`'s, bit for bit.
    ``Jl(phi) rho = a rho + b phi x rho + c (phi . rho) phi`` with ``a = sin(t) / t``,
    ``b = (1 - cos t) / t^2`` (from ``h``: ``s cos h`` and ``s^2 / 2``, ``s = sin(h) / h``) and
    ``c = (1 - a) / t^2``, whose absolute error of about ``eps / t^2`` is that of
    :func:`torchlie._coeffs.rodrigues_values` (``c`` enters only ``c (phi . rho) phi``)."""
    rho, phi = xi[..., :3].double(), xi[..., 3:]
    R, *half = _exp_float64(phi)
    t = _jl(phi.double(), rho, *_jl_coefficients(*half))
    batch = xi.shape[:-1]
    top = torch.cat((R.view(batch + (3, 3)), t.unsqueeze(-1)), -1)
    bottom = constant("bottom", _F64).expand(batch + (1, 4))
    return torch.cat((top, bottom), -2).to(xi.dtype)


def _shepperd_map() -> Tensor:
    """``(10, 20)``: ``(1, m_00, m_01, ..., m_22)`` to Shepperd's values of a rotation matrix,
    the four candidates ``4 q_k q`` (columns ``4 k + i``: component ``i`` of candidate ``k``) and
    ``d_k = 4 q_k^2`` (columns 16-19), for ``q = (w, x, y, z)``."""
    d = {  # 4 q_k^2 = 1 +- m00 +- m11 +- m22
        0: ((0, 0, 1), (1, 1, 1), (2, 2, 1)),
        1: ((0, 0, 1), (1, 1, -1), (2, 2, -1)),
        2: ((0, 0, -1), (1, 1, 1), (2, 2, -1)),
        3: ((0, 0, -1), (1, 1, -1), (2, 2, 1)),
    }
    s = {1: (2, 1), 2: (0, 2), 3: (1, 0)}  # 4 w v_i = m_jk - m_kj
    # 4 v_i v_j = m_ij + m_ji (i, j vector components 1-3)
    forms = torch.zeros(10, 20, dtype=_F64)
    for k in range(4):
        columns = (5 * k, 16 + k)  # the pivot entry of candidate k, and d_k equal to it
        for column in columns:
            forms[0, column] = 1.0
            for i, j, c in d[k]:
                forms[1 + 3 * i + j, column] = c
        for i in range(4):
            if i == k:
                continue
            column = 4 * k + i
            lo, hi = min(i, k), max(i, k)
            if lo == 0:  # w v_hi
                a, b = s[hi]
                forms[1 + 3 * a + b, column] = 1.0
                forms[1 + 3 * b + a, column] = -1.0
            else:  # v_lo v_hi
                forms[1 + 3 * (lo - 1) + hi - 1, column] = 1.0
                forms[1 + 3 * (hi - 1) + lo - 1, column] = 1.0
    return forms


_SOURCES["shepperd_bias"] = lambda: _shepperd_map()[0]
_SOURCES["shepperd"] = lambda: _shepperd_map()[1:]


def shepperd(M: Tensor) -> Tensor:
    """``(rows, 4)``: Shepperd's candidate of the largest ``d_k`` (the first on ties), ``c``
    proportional to the quaternion of each ``(rows, 3, 3)`` matrix, after the orthogonalisation
    step ``R - R (R^T R - I) / 2`` (one product ``R^T R``, one ``R E``); float64 input (see
    :func:`_compute`).  Its ``w`` is never ``-0``: the constant added last is ``+0`` there."""
    E = torch.bmm(M.mT, M)
    P = torch.baddbmm(M, M, E, beta=1.5, alpha=-0.5)
    bias, forms = constant("shepperd_bias", M.dtype), constant("shepperd", M.dtype)
    # the product, then the constant (addmm fuses them into a sum whose rounding depends on
    # the number of rows)
    values = torch.mm(P.view(-1, 9), forms).add_(bias).view(-1, 5, 4)
    pivot = values[:, 4:].argmax(-1, keepdim=True)
    return values.gather(1, pivot.expand(-1, 1, 4)).view(-1, 4)


def _rows(x: Tensor, event: tuple[int, ...]) -> Tensor:
    """``x`` as ``(rows, *event)``, in the dtype the forms compute in (:func:`_compute`)."""
    return _compute(x if x.dim() == len(event) + 1 else x.reshape((-1,) + event))


def _result(y: Tensor, x: Tensor, dims: int) -> Tensor:
    """The ``(rows, ...)`` result ``y`` in the dtype of ``x`` and with its batch shape (``dims``
    trailing dimensions of ``x`` are not batch)."""
    y = y.float() if x.dtype == torch.float32 else y.to(x.dtype)
    return y if x.dim() == dims + 1 else y.view(x.shape[: x.dim() - dims] + y.shape[1:])


def _signed(c: Tensor, x: Tensor) -> Tensor:
    """``x`` with the sign of the :func:`shepperd` candidate ``c``'s ``w`` (never ``-0``: no
    flip at ``w = 0``), the canonical sign (the pivot entry of ``c`` is positive)."""
    return torch.copysign(x, c[:, :1])


def from_matrix(R: Tensor) -> Tensor:
    """Canonical unit quaternion of each matrix: Shepperd's candidate, normalised and signed."""
    c = shepperd(_rows(R, (3, 3)))
    return _result(c / _signed(c, torch.linalg.vector_norm(c, dim=-1, keepdim=True)), R, 2)


def _log_of_candidate(c: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """``(phi, theta, |c_w| / |c_v|)``: the rotation vector of Shepperd's candidate ``c``,
    ``2 atan2(|c_v|, |c_w|) c_v / |c_v|`` signed like the canonical quaternion, its angle, and
    the ratio that gives ``(theta/2) cot(theta/2)``.  ``|c_v|`` is clamped at :data:`_H_MIN`
    before both the angle and the division: the quotient tends to ``2 / |c_w|`` there, and
    ``phi`` is exactly 0 at ``c_v = 0``."""
    v = c[:, 1:]
    nv = torch.linalg.vector_norm(v, dim=-1, keepdim=True).clamp_min_(_H_MIN)
    a = c[:, :1].abs()
    theta = torch.atan2(nv, a).mul_(2.0)
    return v * _signed(c, theta / nv), theta, a.div_(nv)


def log(R: Tensor) -> Tensor:
    """Rotation vector of each matrix (:func:`torchlie.so3.log`)."""
    phi, _, _ = _log_of_candidate(shepperd(_rows(R, (3, 3))))
    return _result(phi, R, 2)


def se3_log(T: Tensor) -> Tensor:
    """``(rho, phi)`` of each pose (:func:`torchlie.se3.log`): ``phi`` as :func:`log`,
    ``rho = Jl(phi)^-1 t = e t - phi x t / 2 + D (phi . t) phi`` with
    ``e = (theta/2) cot(theta/2)`` (from the candidate: ``|c_w| / |c_v|`` times half the angle)
    and ``D = (1 - e) / theta^2``, whose absolute error of about ``eps / theta^2`` is that of
    :func:`torchlie._coeffs.jl_inv_values` (``D`` enters only ``D (phi . t) phi``)."""
    M = _rows(T, (4, 4))
    t = M[:, :3, 3]
    phi, theta, ratio = _log_of_candidate(shepperd(M[:, :3, :3]))
    e = ratio.mul_(theta).mul_(0.5)
    d = torch.rsub(e, 1.0).div_(theta.square_().clamp_min_(_H_MIN))
    rho = _jl(phi, t, e, -0.5, d)
    return _result(torch.cat((rho, phi), -1), T, 2)


def _jl(w: Tensor, v: Tensor, a: Tensor, b: Tensor | float | None, c: Tensor) -> Tensor:
    """``a v + b w x v + c (w . v) w`` of ``(rows, 3)`` vectors: ``Jl(w) v``, ``Jr(w) v`` and
    their inverses by their coefficients (``b = None``: no cross product term)."""
    out = a * v
    if b is not None:
        cross = torch.linalg.cross(w, v)
        out = out.add_(cross, alpha=b) if isinstance(b, float) else out.addcmul_(b, cross)
    return out.addcmul_(c * (w * v).sum(-1, keepdim=True), w)


# ----------------------------------------------------------------------------------------------
# Backward passes (closed forms, no autograd graph)
# ----------------------------------------------------------------------------------------------


def _vee_map() -> Tensor:
    """``(9, 3)``: the entries of ``M`` (row by row) to ``vee(M - M^T)``."""
    forms = torch.zeros(3, 3, 3, dtype=_F64)
    for k, (i, j) in enumerate(((2, 1), (0, 2), (1, 0))):
        forms[i, j, k], forms[j, i, k] = 1.0, -1.0
    return forms.reshape(9, 3)


def _conjugated_forms(side: int) -> Tensor:
    """``(16, 4)``: :func:`_hamilton_forms` with the vector part of the left (``side = 0``) or
    the right (``side = 1``) factor negated: the products ``a_j b_k`` to ``conj(a) b`` or
    ``a conj(b)``."""
    forms = _hamilton_forms().view(4, 4, 4).clone()
    if side == 0:
        forms[1:] *= -1.0
    else:
        forms[:, 1:] *= -1.0
    return forms.reshape(16, 4)


_SOURCES["vee"] = _vee_map
_SOURCES["conj_left"] = lambda: _conjugated_forms(0)
_SOURCES["conj_right"] = lambda: _conjugated_forms(1)
_SOURCES["pure"] = lambda: _hamilton_forms().view(4, 4, 4)[:, 1:].reshape(12, 4)


def _vee_rt_g(R: Tensor, G: Tensor) -> Tensor:
    """``(rows, 3)``: ``vee(R^T G - G^T R)`` of ``(rows, 3, 3)`` matrices."""
    return torch.mm(torch.bmm(R.mT, G).view(-1, 9), constant("vee", R.dtype))


def _r_hat(R: Tensor, u: Tensor) -> Tensor:
    """``R hat(u)`` (row ``i``: ``R_i x u``) of ``(rows, 3, 3)`` matrices and ``(rows, 3)``."""
    return torch.linalg.cross(R, u.unsqueeze(1).expand_as(R))


def exp_backward(w: Tensor, R: Tensor, G: Tensor) -> Tensor:
    """Gradient of :func:`torchlie.so3.exp`: ``Jl(w) vee(R^T G - G^T R)`` (float32 in float64)."""
    M, g = _rows(R, (3, 3)), _rows(G, (3, 3))
    v = _rows(w, (3,))
    return _result(_jl(v, _vee_rt_g(M, g), *_jl_coefficients(*_half_angle(v))), w, 1)


def log_backward(R: Tensor, w: Tensor, g: Tensor) -> Tensor:
    """Gradient of :func:`torchlie.so3.log`: ``R hat(Jl(w)^-1 g) / 2``, ``Jl(w)^-1 = e I -
    hat(w) / 2 + D w w^T`` with ``e = h cot h`` and ``D = (1 - e) / t^2`` (float32 in float64)."""
    v = _rows(w, (3,))
    e, d = _jl_inv_coefficients(*_half_angle(v))
    u = _jl(v, _rows(g, (3,)).mul(0.5), e, -0.5, d)
    return _result(_r_hat(_rows(R, (3, 3)), u), R, 2)


def to_matrix_backward(q: Tensor, R: Tensor, G: Tensor) -> Tensor:
    """Gradient of :func:`torchlie.quaternion.to_matrix`: ``2 q (0, a) / |q|^2`` with
    ``a = vee(R^T G - G^T R)`` (float32 in float64)."""
    v = _rows(q, (4,))
    a = _vee_rt_g(_rows(R, (3, 3)), _rows(G, (3, 3)))
    out = torch.mm(_outer(v, a), constant("pure", v.dtype)).mul_(2.0)
    return _result(out.div_((v * v).sum(-1, keepdim=True)), q, 1)


def _jl_coefficients(h: Tensor, s: Tensor, cos_h: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """``(a, b, c)`` of ``Jl(phi) = a I + b hat(phi) + c phi phi^T`` from :func:`_half_angle`:
    ``sin(t) / t = s cos h``, ``(1 - cos t) / t^2 = s^2 / 2`` and ``(1 - a) / t^2`` (see
    :func:`se3_exp_float32`)."""
    a = s * cos_h
    return a, s.square().mul_(0.5), torch.rsub(a, 1.0).div_(h.square().mul_(4.0))


def _jl_inv_coefficients(h: Tensor, s: Tensor, cos_h: Tensor) -> tuple[Tensor, Tensor]:
    """``(e, D)`` of ``Jl(phi)^-1 = e I - hat(phi) / 2 + D phi phi^T`` from :func:`_half_angle`,
    in float64: ``h cot h`` and ``(1 - e) / t^2`` (see :func:`se3_log`)."""
    e = cos_h / s
    return e, torch.rsub(e, 1.0).div_(h.square().mul_(4.0))


def _q(rho: Tensor, phi: Tensor, v: Tensor, dtype: torch.dtype, b: Tensor, c: Tensor) -> Tensor:
    """``Q(rho, phi) v``, the top-right block of the SE(3) left Jacobian, of ``(rows, 3)``
    vectors (``dtype``: the input's, which picks the coefficients' evaluation, see
    :func:`torchlie._coeffs.q_plain`, from Rodrigues' ``b`` and ``c`` of ``phi`` for float32).
    With ``a = phi x v``, ``b = phi x a`` and ``r(x) = rho x x``: ``r(v)/2 + c1 r(a) + c2 r(b) +
    phi x (c1 r(v) + (c1 - 3 c2) r(a) + c3 r(b) + phi x (c2 r(v) + c3 r(a)))``."""
    t2 = (phi * phi).sum(-1, keepdim=True)
    c1, c2, c3 = _coeffs.q_plain(dtype, t2, b, c)
    cross = torch.linalg.cross
    a = cross(phi, v)
    rv, ra, rb = cross(rho, v), cross(rho, a), cross(rho, cross(phi, a))
    mid = cross(phi, torch.addcmul(c2 * rv, c3, ra)).addcmul_(c1, rv)
    mid.addcmul_(c1 - 3.0 * c2, ra).addcmul_(c3, rb)
    return cross(phi, mid).add_(rv, alpha=0.5).addcmul_(c1, ra).addcmul_(c2, rb)


def se3_exp_backward(xi: Tensor, T: Tensor, G: Tensor) -> Tensor:
    """Gradient of :func:`torchlie.se3.exp`: ``g_rho = Jr(phi) g_t`` and ``g_phi = Jl(phi) u +
    Jr(phi) (t x g_t) + Q(-rho, -phi) g_t`` with ``u = vee(R^T G_R - G_R^T R)`` (float32 in
    float64)."""
    x, M, g = (_rows(y, e) for y, e in ((xi, (6,)), (T, (4, 4)), (G, (4, 4))))
    rho, phi = x[:, :3], x[:, 3:]
    g_t = g[:, :3, 3]
    a, b, c = _jl_coefficients(*_half_angle(phi))
    g_rho = _jl(phi, g_t, a, -b, c)
    # Jl(phi) u + Jr(phi) w = a (u + w) + b phi x (u - w) + c (phi . (u + w)) phi
    u = _vee_rt_g(M[:, :3, :3], g[:, :3, :3])
    w = torch.linalg.cross(M[:, :3, 3], g_t)
    g_phi = _jl(phi, u + w, a, None, c).addcmul_(b, torch.linalg.cross(phi, u - w))
    g_phi += _q(-rho, -phi, g_t, xi.dtype, b, c)
    return _result(torch.cat((g_rho, g_phi), -1), xi, 1)


def se3_log_backward(T: Tensor, xi: Tensor, g: Tensor) -> Tensor:
    """Gradient of :func:`torchlie.se3.log`: ``G_t = R h_rho`` and ``G_R = R hat(u)`` with
    ``h_rho = Jl(phi)^-1 g_rho`` and ``u = Jl(phi)^-1 (g_phi - Q(rho, phi) h_rho) / 2``, the
    bottom row 0 (float32 in float64)."""
    M, x, gg = (_rows(y, e) for y, e in ((T, (4, 4)), (xi, (6,)), (g, (6,))))
    rho, phi = x[:, :3], x[:, 3:]
    half = _half_angle(phi)  # one sin and cos for the coefficients of Jl^-1 and Q
    e, d = _jl_inv_coefficients(*half)
    h_rho = _jl(phi, gg[:, :3], e, -0.5, d)
    _, b, c = _jl_coefficients(*half)
    q = _q(rho, phi, h_rho, xi.dtype, b, c)
    v = (gg[:, 3:] - q).mul_(0.5)
    R = M[:, :3, :3]
    top = torch.cat((_r_hat(R, _jl(phi, v, e, -0.5, d)), torch.bmm(R, h_rho.unsqueeze(-1))), -1)
    zeros = constant("zero_row", M.dtype).expand(M.shape[0], 1, 4)
    return _result(torch.cat((top, zeros), -2), T, 2)


def multiply_backward(a: Tensor, b: Tensor, g: Tensor) -> tuple[Tensor, Tensor]:
    """Gradients of :func:`multiply` at the broadcast batch shape: ``g conj(b)`` and
    ``conj(a) g``, one product with a constant map each."""
    return (
        torch.matmul(_outer(g, b), constant("conj_right", g.dtype)),
        torch.matmul(_outer(a, g), constant("conj_left", g.dtype)),
    )
