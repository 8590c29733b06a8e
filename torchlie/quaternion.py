"""Unit quaternions: Hamilton convention, scalar first ``(w, x, y, z)``, shape ``(..., 4)``.

``q`` and ``-q`` are the same rotation.  The *canonical* representative has ``w > 0``; when
``w == 0`` (a rotation by exactly pi) it is the one whose largest-magnitude vector component is
positive (the first such component on ties).  :func:`canonicalize`, :func:`from_matrix` and
:func:`to_rotvec` (at pi) all follow that rule, so ``torchlie.so3.log`` at pi is deterministic.
Their results jump to their negatives across ``w = 0``, where they are not differentiable: the
derivative returned there is the one-sided derivative of the representative returned.
Everywhere else derivatives (reverse, forward, second order) are the true ones, at exact zeros
and equal components included.

A quaternion acts on a point ``p`` as ``q * [0, p] * conj(q)``; :func:`to_matrix` gives the
matrix ``R`` with ``R @ p`` equal to that rotation (column vectors).  Products compose like
matrices: ``to_matrix(multiply(q1, q2)) == to_matrix(q1) @ to_matrix(q2)``.

Functions that read a rotation from ``q`` (:func:`to_matrix`, :func:`apply`, :func:`to_rotvec`,
:func:`slerp`) are invariant to its scale.  A zero quaternion has no rotation: those functions,
:func:`normalize`, :func:`inverse` and :func:`log` return NaN for that batch element (never a
silent identity).  Other layouts and conventions convert at the boundary: :func:`to_xyzw`,
:func:`to_jpl` (scalar last, flipped product) and :func:`to_su2` (2x2 complex matrices).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from . import _checks, _coeffs, _components, _hamilton, _layout, _rotation_matrix
from ._autograd import CustomFunction, blocked, fma
from ._typing import Bool, Float, Shaped

__all__ = [
    "multiply",
    "conjugate",
    "inverse",
    "normalize",
    "canonicalize",
    "apply",
    "exp",
    "log",
    "slerp",
    "from_matrix",
    "to_matrix",
    "from_rotvec",
    "to_rotvec",
    "identity",
    "random",
    "is_unit",
    "to_xyzw",
    "from_xyzw",
    "to_jpl",
    "from_jpl",
    "left_matrix",
    "right_matrix",
    "to_su2",
    "from_su2",
    "derivative",
    "integrate",
]


@_checks.float32_exact
def multiply(q1: Float[Tensor, "*b1 4"], q2: Float[Tensor, "*b2 4"]) -> Float[Tensor, "*b 4"]:
    """Hamilton product ``q1 * q2`` (batch shapes broadcast).

    Example:
        >>> q = torch.tensor([0.0, 1.0, 0.0, 0.0])  # pi about x
        >>> multiply(q, q)
        tensor([-1.,  0.,  0.,  0.])
    """
    a, b, dtype, _ = _checks.pair("torchlie.quaternion.multiply", q1, q2, "q1", "q2", (4,), (4,))
    return _checks.out(_hamilton.multiply(a, b), dtype)


@_checks.float32_exact
def conjugate(q: Float[Tensor, "*b 4"]) -> Float[Tensor, "*b 4"]:
    """``(w, -x, -y, -z)``; the inverse rotation of a unit quaternion.

    Example:
        >>> conjugate(torch.tensor([1.0, 2.0, 3.0, 4.0]))
        tensor([ 1., -2., -3., -4.])
    """
    x, dtype = _checks.tensor(q, "torchlie.quaternion.conjugate", "q", (4,))
    return _checks.out(_conjugate(x), dtype)


def _conjugate(q: Tensor) -> Tensor:
    return q * q.new_tensor([1.0, -1.0, -1.0, -1.0])


@_checks.float32_exact
def normalize(q: Float[Tensor, "*b 4"]) -> Float[Tensor, "*b 4"]:
    """``q / |q|``.  A zero quaternion gives NaN for that element.

    Example:
        >>> normalize(torch.tensor([2.0, 0.0, 0.0, 0.0]))
        tensor([1., 0., 0., 0.])
    """
    x, dtype = _checks.tensor(q, "torchlie.quaternion.normalize", "q", (4,))
    return _checks.out(_normalize(x), dtype)


def _normalize(q: Tensor) -> Tensor:
    # |q| = 0 -> 0/0 = NaN for that element only (documented), never identity.
    q = _coeffs.rescaled(q)[0]
    return q * torch.rsqrt(_components.norm2(*q.unbind(-1)).unsqueeze(-1))


@_checks.float32_exact
def canonicalize(q: Float[Tensor, "*b 4"]) -> Float[Tensor, "*b 4"]:
    """The representative of ``{q, -q}`` with ``w > 0`` (rule at ``w == 0``: module docstring).

    Does not normalise.  Its derivative is ``+-`` the identity, that of the sign chosen (at
    ``w == 0`` too, where the result jumps).

    Example:
        >>> canonicalize(torch.tensor([-1.0, 0.0, 0.0, 0.0]))
        tensor([1., -0., -0., -0.])
    """
    x, dtype = _checks.tensor(q, "torchlie.quaternion.canonicalize", "q", (4,))
    return _checks.out(_canonicalize(x), dtype)


def _canonical_sign(q: Tensor) -> Tensor:
    """+1 or -1 per element (shape ``(..., 1)``): the sign that makes ``q`` canonical."""
    w = q[..., 0]
    v = q[..., 1:]
    pivot = torch.argmax(v.abs(), dim=-1, keepdim=True)
    v_pivot = torch.gather(v, -1, pivot)[..., 0]
    key = torch.where(w != 0, w, v_pivot)
    return torch.where(key < 0, -torch.ones_like(w), torch.ones_like(w)).unsqueeze(-1)


def _canonicalize(q: Tensor) -> Tensor:
    return q * _canonical_sign(q)


# ----------------------------------------------------------------------------------------------
# Matrices
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def to_matrix(q: Float[Tensor, "*b 4"]) -> Float[Tensor, "*b 3 3"]:
    """Rotation matrix of ``q / |q|`` (invariant to the scale of ``q``).

    A zero quaternion gives NaN for that element.

    Example:
        >>> to_matrix(torch.tensor([0.0, 0.0, 0.0, 2.0]))  # pi about z
        tensor([[-1.,  0.,  0.],
                [ 0., -1.,  0.],
                [ 0.,  0.,  1.]])
    """
    x, dtype = _checks.tensor(q, "torchlie.quaternion.to_matrix", "q", (4,))
    return _checks.out(_rotation_matrix.from_quaternion(x), dtype)


@_checks.float32_exact
def from_matrix(R: Float[Tensor, "*b 3 3"]) -> Float[Tensor, "*b 4"]:
    """Canonical unit quaternion of a rotation matrix (robust at every angle, pi included).

    Shepperd's method: of the four equivalent formulas the one dividing by the largest of
    ``|w|, |x|, |y|, |z|`` is selected per element (no boolean-mask writes, no host sync).  The
    four are the columns of a symmetric 4x4 matrix ``K`` of ``R``'s entries, ``4 q q^T`` on
    SO(3), whose top eigenvector is the quaternion of the rotation nearest ``R``; the selected
    column takes one power step (``K c``), so that the result and its gradient are those of the
    nearest rotation to first order: ``from_matrix(R + eps E)`` equals
    ``from_matrix(polar(R + eps E))`` up to ``O(eps^2)``, whichever formula is selected.  A
    matrix farther from SO(3) (``3 * R``, a reflection, an arbitrary matrix) gives an
    unspecified quaternion, not an error: project it first with :func:`torchlie.so3.project`
    (see "Matrices off SO(3)" in :mod:`torchlie.so3`).

    Example:
        >>> from_matrix(torch.diag(torch.tensor([1.0, -1.0, -1.0])))  # pi about x
        tensor([0., 1., 0., 0.])
    """
    x, dtype = _checks.tensor(R, "torchlie.quaternion.from_matrix", "R", (3, 3))
    return _checks.out(_rotation_matrix.to_quaternion(x), dtype)


# ----------------------------------------------------------------------------------------------
# Rotation vectors
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def from_rotvec(omega: Float[Tensor, "*b 3"]) -> Float[Tensor, "*b 4"]:
    """Unit quaternion ``(cos(t/2), sin(t/2) n)`` of the rotation vector ``omega = t n``.

    Exact and smooth at ``t = 0``; for ``t`` in ``[0, pi)`` the result is canonical.

    Example:
        >>> from_rotvec(torch.tensor([torch.pi, 0.0, 0.0]))
        tensor([-4.3711e-08,  1.0000e+00,  0.0000e+00,  0.0000e+00])
    """
    x, dtype = _checks.tensor(omega, "torchlie.quaternion.from_rotvec", "omega", (3,))
    return _checks.out(_from_rotvec(x), dtype)


def _from_rotvec(omega: Tensor) -> Tensor:
    return _exp_pure(0.5 * omega)


def _exp_pure(a: Tensor) -> Tensor:
    """``exp([0, a]) = [cos|a|, sin|a| a/|a|]`` for ``a`` of shape ``(..., 3)``; smooth at 0.

    ``|a|`` is reduced modulo ``2 pi`` first where it is too large for the formulas
    (:func:`torchlie._coeffs.reduced`; the same value and derivatives).  ``|a|^2`` and the
    coefficients as :func:`torchlie._coeffs.theta2` evaluates them (float64 for float32: a
    float32 ``|a|^2`` rounds angles just below ``pi`` onto it, and ``cos`` to the wrong sign)."""
    x, y, z = _coeffs.reduced_planes(a.unbind(-1))
    t2 = _coeffs.theta2((x, y, z))
    s = _coeffs.sinc(t2).to(x.dtype)
    return torch.stack((_coeffs.cos_sqrt(t2).to(x.dtype), s * x, s * y, s * z), dim=-1)


@_checks.float32_exact
def to_rotvec(q: Float[Tensor, "*b 4"]) -> Float[Tensor, "*b 3"]:
    """Rotation vector (angle in ``[0, pi]``) of ``q / |q|``; ``q`` and ``-q`` give the same.

    Computed as ``2 atan2(|v|, |w|) v/|v|`` with ``v`` signed like the canonical
    representative; smooth at the identity.  At ``w = 0`` (angle pi) the result jumps to its
    negative; the derivative there is that of the canonical side (``w -> 0+``).  Zero
    quaternion: NaN.

    Example:
        >>> to_rotvec(torch.tensor([0.0, 0.0, 1.0, 0.0]))
        tensor([0.0000, 3.1416, 0.0000])
    """
    x, dtype = _checks.tensor(q, "torchlie.quaternion.to_rotvec", "q", (4,))
    return _checks.out(_to_rotvec(x), dtype)


def _to_rotvec(q: Tensor) -> Tensor:
    return _rotvec_of_canonical(_canonicalize(_coeffs.rescaled(q)[0]))


def _rotvec_of_canonical(q: Tensor) -> Tensor:
    """:func:`to_rotvec` of a quaternion already in canonical sign (as from_matrix returns it)."""
    w = q[..., :1]
    v = q[..., 1:]
    n = _coeffs.norm(v, keepdim=True)
    # Zero quaternion: w = 0 and n = 0 -> make it NaN, not zero.
    bad = (w == 0) & (n == 0)
    ratio = _coeffs.atan_ratio(n, w)
    ratio = torch.where(bad, torch.full_like(ratio, float("nan")), ratio)
    return 2.0 * ratio * v


# ----------------------------------------------------------------------------------------------
# Shared private helpers
# ----------------------------------------------------------------------------------------------


def _pure(v: Tensor) -> Tensor:
    """The pure quaternion ``[0, v]``."""
    return torch.cat((torch.zeros_like(v[..., :1]), v), dim=-1)


_FRAMES = ("body", "world")


def _check_frame(fn: str, frame: str) -> None:
    if frame not in _FRAMES:
        raise ValueError(f"{fn}: expected frame 'body' or 'world', got {frame!r}")


# ----------------------------------------------------------------------------------------------
# Group operations
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def inverse(q: Float[Tensor, "*b 4"]) -> Float[Tensor, "*b 4"]:
    """Multiplicative inverse ``conj(q) / |q|^2`` (equal to :func:`conjugate` for unit ``q``).

    ``multiply(q, inverse(q))`` is the identity for every non-zero ``q``; a zero quaternion
    gives NaN for that element.

    Example:
        >>> inverse(torch.tensor([0.0, 0.0, 2.0, 0.0]))
        tensor([ 0.0000, -0.0000, -0.5000, -0.0000])
    """
    x, dtype = _checks.tensor(q, "torchlie.quaternion.inverse", "q", (4,))
    return _checks.out(_inverse(x), dtype)


def _inverse(q: Tensor) -> Tensor:
    u, k = _coeffs.rescaled(q)  # q = k u: q^-1 = conj(u) / |u|^2 / k
    return _conjugate(u) / _components.norm2(*u.unbind(-1)).unsqueeze(-1) / k


@_checks.float32_exact
def apply(q: Float[Tensor, "*b1 4"], points: Float[Tensor, "*b2 3"]) -> Float[Tensor, "*b 3"]:
    """Rotate points by ``q``: ``to_matrix(q) @ p`` without forming the matrix (batches broadcast).

    Cross-product form of ``q [0, p] q^-1``: with ``q = [w, v]`` and ``s = 2 / |q|^2``,
    ``t = s (v x p)`` and ``p' = p + w t + v x t``.  The factor ``s`` makes the result
    invariant to the scale of ``q`` (like :func:`to_matrix`), so ``q`` need not be exactly
    unit; a zero quaternion gives NaN for that element.

    Example:
        >>> q = torch.tensor([0.0, 0.0, 0.0, 1.0])  # pi about z
        >>> apply(q, torch.tensor([1.0, 2.0, 3.0]))
        tensor([-1., -2.,  3.])
    """
    a, p, dtype, _ = _checks.pair("torchlie.quaternion.apply", q, points, "q", "points", (4,), (3,))
    return _checks.out(_ApplyFn(a, p), dtype)


def _apply_values(q: Tensor | Sequence[Tensor], p: Tensor) -> Tensor:
    """:func:`apply` from components: ``p + s (w (v x p) + v x (v x p))``, ``s = 2 / |q|^2``.

    ``q`` as the callers pass it, scaled by a power of two to a largest component in
    ``[1/8, 1/4)`` (:func:`torchlie._coeffs.binary_planes`): the same values as from ``q``
    itself, and every product and sum below the largest float where ``p``'s components are
    (``v x (v x p)`` of an unscaled ``q`` overflowed with ``|q|^2 |p|``)."""
    w, *v = _components.planes(q, 4)
    pc = _components.planes(p, 3)
    s = 2.0 / _components.norm2(w, *v)
    c = _components.cross_planes(v, pc)
    vc = _components.cross_planes(v, c)
    o = _layout.outputs((w, pc[0]), 3)  # batches may broadcast
    parts = [
        fma(pi, s, fma(vci, w, ci), out=oi) for pi, ci, vci, oi in zip(pc, c, vc, o, strict=True)
    ]
    return _layout.interleave(parts, o)


def _apply_grads(q: Tensor, p: Tensor, g: Tensor) -> tuple[Tensor, Tensor]:
    # y = R p with R the rotation of q / |q|: dL/dp = R^T g (the rotation by conj(q)).  A
    # change dq turns R into R Exp(d), d = 2 vec(conj(q) dq) / |q|^2, so dy = R (d x p) and
    # <g, dy> = <p x R^T g, d>: dL/dq = 2 q (0, p x R^T g) / |q|^2 (orthogonal to q).
    w, *v = _components.planes(q, 4)
    pc, gc = _components.planes(p, 3), _components.planes(g, 3)
    s = 2.0 / _components.norm2(w, *v)
    likes = (w, pc[0], gc[0])  # the batch shape of the result: q's and p's broadcast
    oq = _layout.outputs(likes, 4)
    op = _layout.outputs(likes, 3)
    # R^T g = g + s (v x (v x g) - w (v x g))
    c = _components.cross_planes(v, gc)
    dp = [
        fma(gi, s, fma(vci, w, ci, value=-1.0), out=oi)
        for gi, ci, vci, oi in zip(gc, c, _components.cross_planes(v, c), op, strict=True)
    ]
    # q (0, a) = (-v . a, w a + v x a), times s, with a = p x R^T g
    a = _components.cross_planes(pc, dp)
    va = fma(fma(v[0] * a[0], v[1], a[1]), v[2], a[2])
    dq = [torch.mul(va, s, out=oq[0]).neg_()]
    dq += [
        torch.mul(fma(ci, w, ai), s, out=oi)
        for ai, ci, oi in zip(a, _components.cross_planes(v, a), oq[1:], strict=True)
    ]
    return _layout.interleave(dq, oq), _layout.interleave(dp, op)


_apply_grads_blocked = blocked(_apply_grads, (1, 1, 1))


def _apply_backward(saved: tuple[Tensor, ...], g: Tensor) -> tuple[Tensor, Tensor]:
    q, p = saved
    dq, dp = _apply_grads_blocked(q, p, g)
    return dq.sum_to_size(q.shape), dp.sum_to_size(p.shape)


def _apply_jvp(saved: tuple[Tensor, ...], dq: Tensor | None, dp: Tensor | None) -> Tensor:
    # dy = R (d x p + dp), d = 2 vec(conj(q) dq) / |q|^2 (see _apply_backward).
    q, p = saved
    u = torch.zeros_like(p) if dp is None else dp
    if dq is not None:
        d = _hamilton.multiply(_conjugate(q), dq)[..., 1:] * (2.0 / (q * q).sum(-1, keepdim=True))
        d, pb = torch.broadcast_tensors(d, p)
        u = u + torch.linalg.cross(d, pb, dim=-1)
    return _apply_values(q, u)


_ApplyFn = CustomFunction(
    "QuaternionApply",
    forward=lambda q, p: _apply_values(_coeffs.binary_planes(q, 4), p),
    save=lambda inputs, out: (inputs[0], inputs[1]),
    backward=_apply_backward,
    jvp=_apply_jvp,
    event_dims=(1, 1),
    guard=_coeffs.BINARY,
)


@_checks.float32_exact
def exp(q: Float[Tensor, "*b 4"]) -> Float[Tensor, "*b 4"]:
    """Exponential of a general quaternion: ``exp([s, v]) = e^s [cos|v|, sin|v| v/|v|]``.

    Exact and smooth at ``v = 0`` (series in ``|v|^2``); gradients are finite everywhere.  For a
    rotation vector ``omega``, ``exp([0, omega/2])`` is :func:`from_rotvec` ``(omega)``.

    Example:
        >>> exp(torch.tensor([1.0, 0.0, 0.0, 0.0]))
        tensor([2.7183, 0.0000, 0.0000, 0.0000])
        >>> exp(torch.tensor([0.0, 0.0, torch.pi / 4, 0.0]))  # pi/2 about y
        tensor([0.7071, 0.0000, 0.7071, 0.0000])
    """
    x, dtype = _checks.tensor(q, "torchlie.quaternion.exp", "q", (4,))
    return _checks.out(_exp(x), dtype)


def _exp(q: Tensor) -> Tensor:
    return torch.exp(q[..., :1]) * _exp_pure(q[..., 1:])


@_checks.float32_exact
def log(q: Float[Tensor, "*b 4"]) -> Float[Tensor, "*b 4"]:
    """Principal logarithm of a general quaternion: ``[ln|q|, atan2(|v|, w) v/|v|]``.

    The vector part has norm in ``[0, pi]`` (for a unit ``q`` it is half the rotation vector
    of ``q``, not of ``canonicalize(q)``, so its norm exceeds ``pi/2`` when ``w < 0``);
    ``exp(log(q)) == q`` for every non-zero ``q``.  Smooth at ``v = 0`` for ``w > 0`` (value
    ``[ln w, v/w]`` to first order).  On the branch cut ``v = 0, w < 0`` (the negative reals,
    where every ``pi u``, ``u`` a unit vector, is a logarithm) the value is
    ``[ln|w|, pi, 0, 0]``, i.e. ``u`` is the x axis, as the canonical rule's first-on-ties
    choice would give; there the vector part is not differentiable and gets a zero gradient
    (the scalar part keeps its true one).  Zero quaternion: NaN.

    Gradient meaning: the vector part is invariant to the scale of ``q``, so its ordinary
    gradient is already the projected one.  Its derivatives (a closed form, reverse and forward
    mode and of every order) are the true ones wherever ``log`` is differentiable (everywhere
    except the branch cut), ``w = 0``, ``|w| = |v_i|`` and ``v`` next to the negative reals
    included (the derivative along ``v`` there, ``w/|q|^2``, is kept beside the one across it,
    about ``pi/|v|``).

    Example:
        >>> log(torch.tensor([0.0, 0.0, 0.0, 2.0]))
        tensor([0.6931, 0.0000, 0.0000, 1.5708])
        >>> log(torch.tensor([-1.0, 0.0, 0.0, 0.0]))
        tensor([0.0000, 3.1416, 0.0000, 0.0000])
    """
    x, dtype = _checks.tensor(q, "torchlie.quaternion.log", "q", (4,))
    return _checks.out(_LogFn(x), dtype)


def _log_parts(q: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """``(k, w, v, |v|)`` of ``q / k`` (``k`` of :func:`torchlie._coeffs.rescaled`: ``ln|q| =
    ln|q / k| + ln k``, the rest is invariant to the scale); ``|v|`` from ``v`` scaled by its
    own largest component, accurate also where ``|v|``'s squares underflow beside ``w``'s."""
    q, k = _coeffs.rescaled(q)
    v = q[..., 1:]
    return k, q[..., :1], v, _coeffs.norm(v, keepdim=True)


def _log_values(q: Tensor) -> Tensor:
    k, w, v, n = _log_parts(q)
    # atan_ratio is smooth at n = 0 for w > 0 and returns 0 where n = 0 and w <= 0 (fixed below)
    vec = _coeffs.atan_ratio(n, w) * v
    # w <= 0 and |v| below about 1e-154 |w| (float64; 1e-19 in float32): the angle times the
    # unit vector (pi / |v| overflows for the smallest)
    tiny = (w <= 0) & (n > 0) & (n * n < 4.0 * torch.finfo(n.dtype).tiny)
    ne = torch.where(tiny, n, 1.0)
    vec = torch.where(tiny, _coeffs.atan2(ne, w) * (v / ne), vec)
    cut = torch.cat((torch.full_like(w, torch.pi), torch.zeros_like(v[..., 1:])), dim=-1)
    vec = torch.where((n == 0) & (w < 0), cut, vec)
    out = torch.cat((0.5 * torch.log(fma(w * w, n, n)) + k.log(), vec), dim=-1)
    return torch.where((n == 0) & (w == 0), torch.full_like(out, float("nan")), out)


def _log_derivative(q: Tensor, d: Tensor, transpose: bool) -> Tensor:
    """``J d`` (``J^T d`` if ``transpose``), ``J`` the Jacobian of :func:`log` at ``q``.

    With ``r^2 = w^2 + n^2``, ``n = |v|``, ``u = v/n``, ``phi = atan2(n, w)``:
    ``d ln|q| = (w dw + v.dv) / r^2`` and ``d vec = -v dw / r^2 + S dv``, ``S`` symmetric:
    ``(w / r^2) u u^T`` along ``v`` plus ``(phi / n)(I - u u^T)`` across it.  The two parts
    are applied apart: next to the negative reals ``phi / n ~ pi / n`` is huge and the radial
    ``w / r^2 ~ -1`` would be lost in their difference.  Where ``n << w`` (the series of
    :func:`torchlie._coeffs.atan_ratio`) ``S = a I + c v v^T`` with ``a = phi / n`` and
    ``c = (w / r^2 - a) / n^2`` as series, smooth at ``v = 0``.  On the branch cut the vector
    part's derivative is 0 (the docstring's choice)."""
    k, w, v, n = _log_parts(q)
    d0, dv = d[..., :1], d[..., 1:]
    r2 = fma(w * w, n, n)
    small = _coeffs.atan_small(n, w)
    a = _coeffs.atan_ratio_series(n, w, small)
    c = _coeffs.atan_ratio_series(n, w, small, "atan_slope")
    vdv = _coeffs.dot(v, dv).unsqueeze(-1)
    near = fma(a * dv, c * v, vdv)
    far = ~small & (n > 0)
    ne = torch.where(far, n, 1.0)
    u = v / ne
    p = _coeffs.dot(u, dv).unsqueeze(-1)
    # (I - u u^T) dv as u x (dv x u): its transpose (reverse mode through this formula, as
    # under compile) has no radial part to cancel either
    across = torch.linalg.cross(u, torch.linalg.cross(dv, u, dim=-1), dim=-1) / ne
    s_dv = torch.where(
        small, near, torch.where(far, fma(_coeffs.atan2(ne, w) * across, u, p * w / r2), 0.0)
    )
    # the off-diagonal blocks (v^T / r^2 and -v / r^2) swap with the transpose
    sign = -1.0 if transpose else 1.0
    out0 = (w * d0 + sign * vdv) / r2
    outv = fma(s_dv, v, -sign * d0 / r2)
    return torch.cat((out0, outv), dim=-1) / k  # the derivative at q / k, divided by k


_LogFn = CustomFunction(
    "QuaternionLog",
    forward=_log_values,
    save=lambda inputs, out: (inputs[0],),
    backward=lambda saved, g: (_log_derivative(saved[0], g, True),),
    jvp=lambda saved, dq: _log_derivative(saved[0], dq, False),
    event_dims=(1,),
)


@_checks.float32_exact
def slerp(
    q0: Float[Tensor, "*b1 4"], q1: Float[Tensor, "*b2 4"], t: Float[Tensor, "*b3"] | float
) -> Float[Tensor, "*b 4"]:
    """Spherical linear interpolation along the shortest path (``t`` broadcasts with the batch).

    Inputs are normalised first; the result is the unit quaternion
    ``q0 exp(t log(q0^-1 q1'))``, with ``q1' = -q1`` when ``dot(q0, q1) < 0`` so that the path
    is the shorter of the two arcs (at ``dot == 0`` the two are equally long and ``q1`` is kept:
    the result jumps there, and its derivative is that of the side ``dot > 0``).
    ``t = 0`` gives ``q0``, ``t = 1`` gives ``q1'``; other ``t`` extrapolate.  Written with the
    half-angle vector ``atan2(|r_v|, r_w) r_v/|r_v|`` of ``r = q0^-1 q1'`` and the series of
    :mod:`torchlie._coeffs`, so it is exact and has finite gradients for nearly equal or equal
    inputs (no ``0/0`` as in ``sin((1-t) a)/sin(a)``).  Zero quaternion: NaN.  ``t`` is a
    tensor of the dtype of ``q0`` or numbers (a float, numpy scalar or array, or a list),
    converted to it; not a bool.

    Example:
        >>> q0 = torch.tensor([1.0, 0.0, 0.0, 0.0])
        >>> q1 = torch.tensor([0.0, 0.0, 0.0, 1.0])  # pi about z
        >>> slerp(q0, q1, 0.5)  # pi/2 about z
        tensor([0.7071, 0.0000, 0.0000, 0.7071])
    """
    fn = "torchlie.quaternion.slerp"
    a, dtype = _checks.tensor(q0, fn, "q0", (4,))
    b, _ = _checks.tensor(q1, fn, "q1", (4,))
    _checks.same_dtype(fn, q0=q0, q1=q1)
    tt = _checks.real(t, fn, "t", a, ("q0", q0))
    _checks.batch_broadcast(fn, (a.shape[:-1], "q0"), (b.shape[:-1], "q1"), (tt.shape, "t"))
    return _checks.out(_slerp(a, b, tt), dtype)


def _slerp(q0: Tensor, q1: Tensor, t: Tensor) -> Tensor:
    q0 = _normalize(q0)
    r = _hamilton.multiply(_conjugate(q0), _normalize(q1))
    rw = r[..., :1]
    r = torch.where(rw < 0, -r, r)
    rw = r[..., :1]
    rv = r[..., 1:]
    half = _coeffs.atan_ratio(_coeffs.norm(rv, keepdim=True), rw) * rv
    return _hamilton.multiply(q0, _exp_pure(t.unsqueeze(-1) * half))


# ----------------------------------------------------------------------------------------------
# Construction and validation
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def identity(
    *batch: int, dtype: torch.dtype | None = None, device: torch.device | str | None = None
) -> Float[Tensor, "*batch 4"]:
    """Identity quaternions ``(1, 0, 0, 0)`` of shape ``(*batch, 4)``.

    Example:
        >>> identity(2)
        tensor([[1., 0., 0., 0.],
                [1., 0., 0., 0.]])
    """
    _, dtype = _checks.factory("torchlie.quaternion.identity", batch, dtype)
    e = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=dtype, device=device)
    return e.expand(*batch, 4).clone()


@_checks.float32_exact
def random(
    *batch: int,
    generator: torch.Generator | None = None,
    dtype: torch.dtype | None = None,
    device: torch.device | str | None = None,
) -> Float[Tensor, "*batch 4"]:
    """Uniform random unit quaternions on the 3-sphere (Haar measure), shape ``(*batch, 4)``.

    Normalised Gaussian 4-vectors: uniform on the unit quaternions, hence Haar-uniform
    rotations.  Not canonicalised (both signs are equally likely).  With the same generator
    state and dtype, ``to_matrix(random(...))`` is the rotation ``torchlie.so3.random(...)``
    returns, up to rounding (the two round in another order).
    float16/bfloat16 are drawn and normalised in float32, then cast.

    Example:
        >>> q = random(3, generator=torch.Generator().manual_seed(0))
        >>> is_unit(q)
        tensor([True, True, True])
    """
    compute, dtype = _checks.factory("torchlie.quaternion.random", batch, dtype)
    x = torch.randn(*batch, 4, generator=generator, dtype=compute, device=device)
    return _checks.out(_normalize(x), dtype)


@_checks.float32_exact
def is_unit(q: Float[Tensor, "*b 4"], atol: float | None = None) -> Bool[Tensor, "*b"]:
    """Per element: finite and ``| |q| - 1 | <= atol``.

    ``atol`` (a non-negative finite real number) defaults to ``100 * eps`` of float32/float64
    (about 1.2e-5 for float32), and to ``4 * eps`` of float16/bfloat16 for those inputs
    (rounding a unit quaternion to them stays within that).  Reads the values, so keep it out
    of hot loops on a GPU.

    Example:
        >>> is_unit(torch.tensor([[1.0, 0.0, 0.0, 0.0], [1.0, 1.0, 0.0, 0.0]]))
        tensor([ True, False])
    """
    x, dtype = _checks.tensor(q, "torchlie.quaternion.is_unit", "q", (4,))
    atol = _checks.tolerance(atol, "torchlie.quaternion.is_unit", "atol", dtype)
    return _checks.unit_norm(x, atol)


# ----------------------------------------------------------------------------------------------
# Other layouts and conventions
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def to_xyzw(q: Float[Tensor, "*b 4"]) -> Float[Tensor, "*b 4"]:
    """Reorder to scalar last, ``(x, y, z, w)`` (scipy's default, ROS, Eigen's storage).

    Same Hamilton quaternion, same rotation; only the storage order changes.

    Example:
        >>> to_xyzw(torch.tensor([1.0, 2.0, 3.0, 4.0]))
        tensor([2., 3., 4., 1.])
    """
    x, dtype = _checks.tensor(q, "torchlie.quaternion.to_xyzw", "q", (4,))
    return _checks.out(torch.cat((x[..., 1:], x[..., :1]), dim=-1), dtype)


@_checks.float32_exact
def from_xyzw(q: Float[Tensor, "*b 4"]) -> Float[Tensor, "*b 4"]:
    """Reorder a scalar-last ``(x, y, z, w)`` Hamilton quaternion to ``(w, x, y, z)``.

    Example:
        >>> from_xyzw(torch.tensor([2.0, 3.0, 4.0, 1.0]))
        tensor([1., 2., 3., 4.])
    """
    x, dtype = _checks.tensor(q, "torchlie.quaternion.from_xyzw", "q", (4,))
    return _checks.out(torch.cat((x[..., 3:], x[..., :3]), dim=-1), dtype)


@_checks.float32_exact
def to_jpl(q: Float[Tensor, "*b 4"]) -> Float[Tensor, "*b 4"]:
    """The JPL quaternion with the same rotation matrix: ``(-x, -y, -z, w)``.

    The JPL convention (Breckenridge 1979; Trawny & Roumeliotis 2005) stores the scalar last,
    ``q_jpl = (q1, q2, q3, q4)``, multiplies with ``ij = -k`` (the flipped product
    ``p (x) q = [p4 q_v + q4 p_v - p_v x q_v, p4 q4 - p_v . q_v]``) and maps a unit quaternion
    to ``C(q_jpl) = (2 q4^2 - 1) I - 2 q4 [q_v]x + 2 q_v q_v^T``.  This conversion preserves
    that matrix: ``C(to_jpl(q)) == to_matrix(q)``, and products map to products:
    ``to_jpl(multiply(q1, q2)) == to_jpl(q1) (x) to_jpl(q2)``.  JPL's ``C`` is read
    passively (it maps coordinates from the global frame into the local one); if your JPL
    quaternion ``^L_G q`` stands for the inverse of the rotation that ``q`` stands for (for
    example ``^B_W q`` of a filter, against ``q_WB`` with ``p_W = to_matrix(q_WB) p_B``), the
    components are simply reordered: use :func:`to_xyzw` instead.

    Example:
        >>> to_jpl(torch.tensor([1.0, 2.0, 3.0, 4.0]))
        tensor([-2., -3., -4.,  1.])
    """
    x, dtype = _checks.tensor(q, "torchlie.quaternion.to_jpl", "q", (4,))
    return _checks.out(torch.cat((-x[..., 1:], x[..., :1]), dim=-1), dtype)


@_checks.float32_exact
def from_jpl(q: Float[Tensor, "*b 4"]) -> Float[Tensor, "*b 4"]:
    """Inverse of :func:`to_jpl`: the Hamilton ``(w, x, y, z)`` with ``to_matrix == C(q_jpl)``.

    ``(q1, q2, q3, q4) -> (q4, -q1, -q2, -q3)``; see :func:`to_jpl` for the JPL convention.

    Example:
        >>> from_jpl(torch.tensor([-2.0, -3.0, -4.0, 1.0]))
        tensor([1., 2., 3., 4.])
    """
    x, dtype = _checks.tensor(q, "torchlie.quaternion.from_jpl", "q", (4,))
    return _checks.out(torch.cat((x[..., 3:], -x[..., :3]), dim=-1), dtype)


@_checks.float32_exact
def left_matrix(q: Float[Tensor, "*b 4"]) -> Float[Tensor, "*b 4 4"]:
    """``[q]_L``, the 4x4 matrix with ``multiply(q, p) == left_matrix(q) @ p``.

    Example:
        >>> left_matrix(torch.tensor([1.0, 2.0, 3.0, 4.0]))
        tensor([[ 1., -2., -3., -4.],
                [ 2.,  1., -4.,  3.],
                [ 3.,  4.,  1., -2.],
                [ 4., -3.,  2.,  1.]])
    """
    x, dtype = _checks.tensor(q, "torchlie.quaternion.left_matrix", "q", (4,))
    w, a, b, c = x.unbind(-1)
    m = _layout.interleave(
        (
            w, -a, -b, -c,
            a, w, -c, b,
            b, c, w, -a,
            c, -b, a, w,
        ),
    ).unflatten(-1, (4, 4))  # fmt: skip
    return _checks.out(m, dtype)


@_checks.float32_exact
def right_matrix(p: Float[Tensor, "*b 4"]) -> Float[Tensor, "*b 4 4"]:
    """``[p]_R``, the 4x4 matrix with ``multiply(q, p) == right_matrix(p) @ q``.

    Example:
        >>> right_matrix(torch.tensor([1.0, 2.0, 3.0, 4.0]))
        tensor([[ 1., -2., -3., -4.],
                [ 2.,  1.,  4., -3.],
                [ 3., -4.,  1.,  2.],
                [ 4.,  3., -2.,  1.]])
    """
    x, dtype = _checks.tensor(p, "torchlie.quaternion.right_matrix", "p", (4,))
    w, a, b, c = x.unbind(-1)
    m = _layout.interleave(
        (
            w, -a, -b, -c,
            a, w, c, -b,
            b, -c, w, a,
            c, b, -a, w,
        ),
    ).unflatten(-1, (4, 4))  # fmt: skip
    return _checks.out(m, dtype)


_REAL = {torch.complex64: torch.float32, torch.complex128: torch.float64}


@_checks.float32_exact
def to_su2(q: Float[Tensor, "*b 4"]) -> Shaped[Tensor, "*b 2 2"]:
    """The SU(2) matrix ``U = w I - i (x sx + y sy + z sz)`` (``s*`` the Pauli matrices).

    Explicitly ``U = [[w - iz, -y - ix], [y - ix, w + iz]]``.  This is the isomorphism of unit
    quaternions with SU(2) (``i, j, k -> -i sx, -i sy, -i sz``): it maps products to matrix
    products, ``to_su2(multiply(q1, q2)) == to_su2(q1) @ to_su2(q2)``, conjugation to the
    conjugate transpose and ``|q|^2`` to ``det U``.  For a rotation by ``t`` about the unit
    axis ``n`` it is the spin-1/2 operator ``exp(-i t/2 n.s)``, and
    ``U (p.s) U^H == (to_matrix(q) @ p).s``.  float32 gives complex64, float64 complex128
    (float16/bfloat16 give complex64).

    Example:
        >>> to_su2(torch.tensor([0.0, 0.0, 0.0, 1.0]))
        tensor([[0.-1.j, -0.-0.j],
                [0.-0.j, 0.+1.j]])
    """
    x, _ = _checks.tensor(q, "torchlie.quaternion.to_su2", "q", (4,))
    w, a, b, c = x.unbind(-1)
    re = _layout.interleave((w, -b, b, w))
    im = _layout.interleave((-c, -a, -a, c))
    return torch.complex(re, im).unflatten(-1, (2, 2))


@_checks.float32_exact
def from_su2(U: Shaped[Tensor, "*b 2 2"]) -> Float[Tensor, "*b 4"]:
    """Inverse of :func:`to_su2`: ``(w, x, y, z)`` of a 2x2 complex matrix.

    Reads ``U = [[a, -conj(b)], [b, conj(a)]]`` with ``a = w - iz``, ``b = y - ix``, averaging
    the two copies of ``a`` and of ``b``: exact when ``U = to_su2(q)``, and otherwise the ``q``
    whose ``to_su2(q)`` is nearest to ``U`` in the Frobenius norm.  complex64 gives float32,
    complex128 float64 (complex32 is computed in complex64 and gives float16).

    Raises:
        TypeError: ``U`` is not a complex tensor.
        ValueError: ``U`` is not of shape ``(..., 2, 2)``.

    Example:
        >>> U = torch.tensor([[0.5 - 0.5j, 0.5 - 0.5j], [-0.5 - 0.5j, 0.5 + 0.5j]])
        >>> from_su2(U)
        tensor([ 0.5000,  0.5000, -0.5000,  0.5000])
    """
    fn = "torchlie.quaternion.from_su2"
    if not isinstance(U, Tensor):
        raise TypeError(f"{fn}: expected U to be a torch.Tensor, got {type(U).__name__}")
    if not U.is_complex():
        raise TypeError(
            f"{fn}: expected U to be a complex tensor (complex64 or complex128), "
            f"got dtype {U.dtype}"
        )
    if U.dim() < 2 or tuple(U.shape[-2:]) != (2, 2):
        raise ValueError(f"{fn}: expected U of shape (..., 2, 2), got {tuple(U.shape)}")
    out_dtype = torch.float16 if U.dtype == torch.complex32 else _REAL[U.dtype]
    if U.dtype == torch.complex32:
        U = U.to(torch.complex64)
    a = 0.5 * (U[..., 0, 0] + U[..., 1, 1].conj())
    b = 0.5 * (U[..., 1, 0] - U[..., 0, 1].conj())
    q = _layout.interleave((a.real, -b.imag, b.real, -a.imag))
    return _checks.out(q, out_dtype)


# ----------------------------------------------------------------------------------------------
# Kinematics
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def derivative(
    q: Float[Tensor, "*b1 4"], omega: Float[Tensor, "*b2 3"], frame: str = "body"
) -> Float[Tensor, "*b 4"]:
    """Time derivative of ``q`` under the angular velocity ``omega`` (batches broadcast).

    ``frame="body"``: ``omega`` is expressed in the body (rotated) frame and
    ``q_dot = 1/2 q * [0, omega]``; ``frame="world"``: ``omega`` is in the world (fixed) frame
    and ``q_dot = 1/2 [0, omega] * q``.  Here ``p_world = to_matrix(q) @ p_body``, so the two
    agree when ``omega_world = to_matrix(q) @ omega_body``.

    Raises:
        ValueError: ``frame`` is neither ``"body"`` nor ``"world"``.

    Example:
        >>> derivative(torch.tensor([1.0, 0.0, 0.0, 0.0]), torch.tensor([0.0, 0.0, 2.0]))
        tensor([0., 0., 0., 1.])
    """
    fn = "torchlie.quaternion.derivative"
    _check_frame(fn, frame)
    a, dtype = _checks.tensor(q, fn, "q", (4,))
    w, _ = _checks.tensor(omega, fn, "omega", (3,))
    _checks.same_dtype(fn, q=q, omega=omega)
    _checks.batch_broadcast(fn, (a.shape[:-1], "q"), (w.shape[:-1], "omega"))
    p = _pure(0.5 * w)
    out = _hamilton.multiply(a, p) if frame == "body" else _hamilton.multiply(p, a)
    return _checks.out(out, dtype)


@_checks.float32_exact
def integrate(
    q: Float[Tensor, "*b1 4"],
    omega: Float[Tensor, "*b2 3"],
    dt: Float[Tensor, "*b3"] | float,
    frame: str = "body",
) -> Float[Tensor, "*b 4"]:
    """Exact integration of a constant angular velocity over ``dt`` (batches broadcast).

    Solves the linear ODE of :func:`derivative` in closed form:
    ``q(dt) = q * exp([0, omega dt/2])`` in the body frame and ``exp([0, omega dt/2]) * q`` in
    the world frame (``exp([0, omega dt/2])`` is ``from_rotvec(omega * dt)``).  Exact for any
    ``q`` (the norm is preserved, not imposed) and for any ``|omega dt|``, small ones included.
    ``dt`` is a tensor of the dtype of ``q`` or numbers, converted to it (as ``t`` in
    :func:`slerp`).

    Raises:
        ValueError: ``frame`` is neither ``"body"`` nor ``"world"``.

    Example:
        >>> q = torch.tensor([1.0, 0.0, 0.0, 0.0])
        >>> integrate(q, torch.tensor([0.0, 0.0, torch.pi]), 0.5)  # pi/2 about z
        tensor([0.7071, 0.0000, 0.0000, 0.7071])
    """
    fn = "torchlie.quaternion.integrate"
    _check_frame(fn, frame)
    a, dtype = _checks.tensor(q, fn, "q", (4,))
    w, _ = _checks.tensor(omega, fn, "omega", (3,))
    _checks.same_dtype(fn, q=q, omega=omega)
    h = _checks.real(dt, fn, "dt", a, ("q", q))
    _checks.batch_broadcast(fn, (a.shape[:-1], "q"), (w.shape[:-1], "omega"), (h.shape, "dt"))
    e = _exp_pure((0.5 * h).unsqueeze(-1) * w)
    out = _hamilton.multiply(a, e) if frame == "body" else _hamilton.multiply(e, a)
    return _checks.out(out, dtype)
