"""Conversions between rotation representations.

Rotation matrices ``(..., 3, 3)`` act on column vectors and quaternions are Hamilton
``(w, x, y, z)`` (see :mod:`torchlie`).  Matrix <-> rotation vector is :func:`torchlie.so3.exp` /
:func:`torchlie.so3.log`; quaternion <-> rotation vector and quaternion <-> matrix live in
:mod:`torchlie.quaternion`.  This module adds Euler angles, axis-angle pairs and the continuous
6-D and 9-D representations used by networks.

Euler angles
------------
A sequence is three letters, scipy's naming: lower case ``"xyz"`` is *extrinsic* (rotations
about the static axes), upper case ``"XYZ"`` is *intrinsic* (about the rotating axes).  All 24
are accepted: the 12 Tait-Bryan sequences (three different axes, ``"xyz"``, ``"ZYX"``, ...) and
the 12 proper Euler sequences (first axis repeated, ``"zxz"``, ``"YZY"``, ...).  Angles are
``(..., 3)`` in radians, in the order of the sequence::

    extrinsic "abc", angles (t1, t2, t3):  R = R_c(t3) @ R_b(t2) @ R_a(t1)
    intrinsic "ABC", angles (t1, t2, t3):  R = R_a(t1) @ R_b(t2) @ R_c(t3)

so intrinsic ``"XYZ"`` with ``(t1, t2, t3)`` is extrinsic ``"zyx"`` with ``(t3, t2, t1)``.

Ranges returned (those of scipy): ``t1, t3`` in ``[-pi, pi)``; ``t2`` in ``[-pi/2, pi/2]`` for
Tait-Bryan sequences and in ``[0, pi]`` for proper Euler sequences.

**Gimbal lock.**  When ``t2`` is at the end of its range (``+-pi/2`` for Tait-Bryan, ``0`` or
``pi`` for proper Euler) only ``t1 + t3`` or ``t1 - t3`` is determined.  The rule (scipy's) is
then: *the third angle is 0 and the first carries the whole rotation about that axis*.  The
test is relative to the dtype: the lock branch is taken where the two components of the
quaternion that carry the undetermined angle are below ``4 eps`` of the two that carry the
determined one (``t2`` within about ``8 eps`` of the lock value), so that setting the third
angle to 0 moves the rotation by at most about ``16 eps`` (radians); every returned triple
converts back to the input rotation to that accuracy, at, near and away from gimbal lock.  No
NaN and no warning is produced, and the gradient stays finite there (zero for the angle set
to 0, that of the sum or difference for the other).  scipy's own test is an absolute ``1e-7``
on ``t2``, so within ``1e-7`` of gimbal lock (but farther than ``8 eps``) scipy sets the third
angle to 0 while this module returns the exact split.

The angles are computed from the quaternion with one branch-free formula for all sequences
(after the general method of Bernardes and Viollet, 2022): the quaternion is mapped to four
numbers ``(a, b, c, d)`` with ``a + ib = cos(t2'/2) e^{i(t1+t3)/2}`` and
``c + id = sin(t2'/2) e^{i(t3-t1)/2}`` (angles in extrinsic order, so reversed for intrinsic
sequences; for Tait-Bryan sequences after a fixed quarter turn that makes
``t2' = t2 + pi/2``), and each angle is one ``atan2`` of products of them.

**Derivatives.**  Away from gimbal lock the angles are smooth functions of the rotation, and
their derivatives (reverse, forward, second order) are the true ones, at angles of exactly 0
and +-pi/2 included.  Where ``t1`` or ``t3`` wraps from ``pi`` to ``-pi`` the value jumps by
``2 pi`` but the derivative is the same on both sides.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from . import _checks, _coeffs, _layout, _rotation_matrix
from . import quaternion as _quat
from . import so3 as _so3
from ._typing import Float

__all__ = [
    "euler_to_quaternion",
    "quaternion_to_euler",
    "euler_to_matrix",
    "matrix_to_euler",
    "axis_angle_to_matrix",
    "matrix_to_axis_angle",
    "rot6d_to_matrix",
    "matrix_to_rot6d",
    "rot9d_to_matrix",
]

_NAME = "torchlie.conversions."

#: Gimbal-lock threshold, in units of the compute dtype's machine epsilon (module docstring).
_LOCK_EPS = 4.0


# ----------------------------------------------------------------------------------------------
# Euler sequences
# ----------------------------------------------------------------------------------------------


def _euler_plan(fn: str, seq: object) -> tuple[int, int, int, bool]:
    """Validate ``seq``; return the extrinsic axes ``(i, j, k)`` (0, 1, 2 = x, y, z) and whether
    the angles are given in reverse (intrinsic) order."""
    if not isinstance(seq, str):
        raise TypeError(f"{fn}: expected seq to be a str such as 'xyz', got {type(seq).__name__}")
    if len(seq) != 3:
        raise ValueError(f"{fn}: invalid Euler sequence {seq!r}: expected exactly 3 axes")
    if not (set(seq) <= set("xyz") or set(seq) <= set("XYZ")):
        raise ValueError(
            f"{fn}: invalid Euler sequence {seq!r}: expected axes from 'xyz' (extrinsic) or "
            "from 'XYZ' (intrinsic), all of one case"
        )
    if seq[0] == seq[1] or seq[1] == seq[2]:
        raise ValueError(
            f"{fn}: invalid Euler sequence {seq!r}: consecutive axes must be different"
        )
    intrinsic = seq.isupper()
    axes = ["xyz".index(ch) for ch in seq.lower()]
    if intrinsic:
        axes.reverse()
    return axes[0], axes[1], axes[2], intrinsic


def _levi(a: int, b: int) -> float:
    """``e_a e_b = _levi(a, b) e_c`` for the quaternion units of two different axes."""
    return 1.0 if (b - a) % 3 == 1 else -1.0


def _euler_to_quaternion(angles: Tensor, plan: tuple[int, int, int, bool]) -> Tensor:
    i, j, k, intrinsic = plan
    h = 0.5 * angles
    c1, c2, c3 = torch.cos(h).unbind(-1)
    s1, s2, s3 = torch.sin(h).unbind(-1)
    if intrinsic:  # extrinsic order: the last angle is applied first
        c1, c3, s1, s3 = c3, c1, s3, s1
    m = 3 - i - j
    # p = q_j(t2) q_i(t1) = c2 c1 + c2 s1 e_i + s2 c1 e_j + s2 s1 e_j e_i
    pw = c2 * c1
    pv: list[Tensor] = [pw] * 3
    pv[i] = c2 * s1
    pv[j] = s2 * c1
    pv[m] = _levi(j, i) * (s2 * s1)
    # q = q_k(t3) p = c3 p + s3 e_k p, with e_k p = -p_k + p_w e_k + e_k x p_v
    u, v = (k + 1) % 3, (k + 2) % 3
    qv: list[Tensor] = [pw] * 3
    qv[k] = c3 * pv[k] + s3 * pw
    qv[u] = c3 * pv[u] - s3 * pv[v]
    qv[v] = c3 * pv[v] + s3 * pv[u]
    qw = c3 * pw - s3 * pv[k]
    return _layout.interleave((qw, qv[0], qv[1], qv[2]))


def _quaternion_to_euler(q: Tensor, plan: tuple[int, int, int, bool]) -> Tensor:
    i, j, k, intrinsic = plan
    q = _quat._normalize(q)  # scale invariance; a zero quaternion gives NaN here
    w, x, y, z = q.unbind(-1)
    qv = (x, y, z)
    proper = i == k
    m = 3 - i - j
    e = _levi(i, j)  # e_i e_j = e * e_m
    if proper:
        a, b, c, d = w, qv[i], qv[j], e * qv[m]
    else:
        # q' = (1 + e_j) q: a quarter turn about j makes the sequence (i, j, i), t2' = t2 + pi/2.
        a, b, c, d = w - qv[j], qv[i] + e * qv[m], qv[j] + w, e * qv[m] - qv[i]
    nab2 = a * a + b * b  # cos^2(t2'/2) (times |q'|^2)
    ncd2 = c * c + d * d  # sin^2(t2'/2)
    tau2 = (_LOCK_EPS * torch.finfo(q.dtype).eps) ** 2
    lock_sum = ncd2 <= tau2 * nab2  # t2' = 0: only t1 + t3 is determined
    lock_diff = nab2 <= tau2 * ncd2  # t2' = pi: only t1 - t3 is determined
    one, zero = torch.ones_like(a), torch.zeros_like(a)
    # Double where: the pair that vanishes is replaced by (1, 0) before any atan2 sees it.
    sa, sb = torch.where(lock_diff, one, a), torch.where(lock_diff, zero, b)
    sc, sd = torch.where(lock_sum, one, c), torch.where(lock_sum, zero, d)
    # With A = a + ib = |A| e^{i(t1+t3)/2} and C = c + id = |C| e^{i(t3-t1)/2}:
    # No (0, 0) reaches atan2 (a zero quaternion is NaN by now), so its derivatives are the
    # true ones everywhere, at exact zeros and ties included.
    atan2 = _coeffs.atan2
    first = atan2(sb * sc - sa * sd, sa * sc + sb * sd)  # arg(A conj(C)) = t1
    third = atan2(sb * sc + sa * sd, sa * sc - sb * sd)  # arg(A C) = t3
    sum_ = atan2(2.0 * sa * sb, sa * sa - sb * sb)  # arg(A^2) = t1 + t3
    diff = atan2(2.0 * sc * sd, sc * sc - sd * sd)  # arg(C^2) = t3 - t1
    locked = lock_sum | lock_diff
    if intrinsic:  # the angle set to 0 is t1 (the last of the intrinsic triple)
        first = torch.where(locked, zero, first)
        third = torch.where(lock_sum, sum_, torch.where(lock_diff, diff, third))
    else:
        first = torch.where(lock_sum, sum_, torch.where(lock_diff, -diff, first))
        third = torch.where(locked, zero, third)
    nab, ncd = _coeffs.sqrt0(nab2), _coeffs.sqrt0(ncd2)
    if proper:
        middle = 2.0 * atan2(ncd, nab)
    else:
        middle = atan2(ncd2 - nab2, 2.0 * nab * ncd)  # t2' - pi/2, without rounding pi/2
        third = e * third
    if intrinsic:
        first, third = third, first
    # atan2 gives (-pi, pi]; fold pi (which also arises from -0 vs +0) to -pi: range [-pi, pi).
    first = torch.where(first >= math.pi, first - 2.0 * math.pi, first)
    third = torch.where(third >= math.pi, third - 2.0 * math.pi, third)
    return _layout.interleave((first, middle, third))


@_checks.float32_exact
def euler_to_quaternion(angles: Float[Tensor, "*b 3"], seq: str) -> Float[Tensor, "*b 4"]:
    """Quaternion ``(w, x, y, z)`` of Euler angles (conventions: module docstring).

    The product of the three elementary quaternions, e.g. ``q_z(t3) q_y(t2) q_x(t1)`` for
    ``"xyz"``.  It is smooth in the angles and is *not* canonicalised (``w`` may be negative);
    use :func:`torchlie.quaternion.canonicalize` for ``w >= 0``.

    Args:
        angles: ``(..., 3)`` radians, in the order of ``seq``.
        seq: one of the 24 sequences, ``"xyz"`` extrinsic, ``"XYZ"`` intrinsic.

    Example:
        >>> euler_to_quaternion(torch.tensor([0.0, 0.0, torch.pi / 2]), "xyz").round(decimals=4)
        tensor([0.7071, 0.0000, 0.0000, 0.7071])
    """
    fn = _NAME + "euler_to_quaternion"
    plan = _euler_plan(fn, seq)
    x, dtype = _checks.tensor(angles, fn, "angles", (3,))
    return _checks.out(_euler_to_quaternion(x, plan), dtype)


@_checks.float32_exact
def quaternion_to_euler(q: Float[Tensor, "*b 4"], seq: str) -> Float[Tensor, "*b 3"]:
    """Euler angles of the rotation of ``q / |q|`` (conventions and gimbal lock: module docstring).

    ``q`` and ``-q`` give the same angles.  A zero quaternion gives NaN for that element.

    Args:
        q: ``(..., 4)`` quaternion ``(w, x, y, z)``, any non-zero scale.
        seq: one of the 24 sequences, ``"xyz"`` extrinsic, ``"XYZ"`` intrinsic.

    Returns:
        ``(..., 3)`` radians in the order of ``seq``: first and third in ``[-pi, pi)``, second in
        ``[-pi/2, pi/2]`` (Tait-Bryan) or ``[0, pi]`` (proper Euler).

    Example:
        >>> q = euler_to_quaternion(torch.tensor([0.1, 0.2, 0.3]), "ZYX")
        >>> quaternion_to_euler(q, "ZYX")
        tensor([0.1000, 0.2000, 0.3000])
    """
    fn = _NAME + "quaternion_to_euler"
    plan = _euler_plan(fn, seq)
    x, dtype = _checks.tensor(q, fn, "q", (4,))
    return _checks.out(_quaternion_to_euler(x, plan), dtype)


@_checks.float32_exact
def euler_to_matrix(angles: Float[Tensor, "*b 3"], seq: str) -> Float[Tensor, "*b 3 3"]:
    """Rotation matrix of Euler angles (conventions: module docstring).

    ``"xyz"``: ``R = R_z(t3) @ R_y(t2) @ R_x(t1)``; ``"XYZ"``: ``R = R_x(t1) @ R_y(t2) @ R_z(t3)``.

    Args:
        angles: ``(..., 3)`` radians, in the order of ``seq``.
        seq: one of the 24 sequences, ``"xyz"`` extrinsic, ``"XYZ"`` intrinsic.

    Example:
        >>> euler_to_matrix(torch.tensor([0.0, 0.0, torch.pi / 2]), "xyz").round(decimals=6)
        tensor([[ 0., -1.,  0.],
                [ 1.,  0.,  0.],
                [ 0.,  0.,  1.]])
    """
    fn = _NAME + "euler_to_matrix"
    plan = _euler_plan(fn, seq)
    x, dtype = _checks.tensor(angles, fn, "angles", (3,))
    return _checks.out(_rotation_matrix.from_quaternion(_euler_to_quaternion(x, plan)), dtype)


@_checks.float32_exact
def matrix_to_euler(R: Float[Tensor, "*b 3 3"], seq: str) -> Float[Tensor, "*b 3"]:
    """Euler angles of a rotation matrix (conventions and gimbal lock: module docstring).

    Goes through :func:`torchlie.quaternion.from_matrix`: the result and its gradient are those
    of the nearest rotation to first order.

    Args:
        R: ``(..., 3, 3)`` rotation matrix.
        seq: one of the 24 sequences, ``"xyz"`` extrinsic, ``"XYZ"`` intrinsic.

    Returns:
        ``(..., 3)`` radians in the order of ``seq`` (ranges as :func:`quaternion_to_euler`).

    Example:
        >>> R = euler_to_matrix(torch.tensor([0.3, 1.2, -2.0]), "zxz")
        >>> matrix_to_euler(R, "zxz")
        tensor([ 0.3000,  1.2000, -2.0000])
    """
    fn = _NAME + "matrix_to_euler"
    plan = _euler_plan(fn, seq)
    x, dtype = _checks.tensor(R, fn, "R", (3, 3))
    return _checks.out(_quaternion_to_euler(_rotation_matrix.to_quaternion(x), plan), dtype)


# ----------------------------------------------------------------------------------------------
# Axis-angle
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def axis_angle_to_matrix(
    axis: Float[Tensor, "*b1 3"], angle: Float[Tensor, "*b2"] | float
) -> Float[Tensor, "*b 3 3"]:
    """Rotation by ``angle`` (radians, right-handed) about ``axis``; batch shapes broadcast.

    ``axis`` need not be unit: it is normalised first, so only its direction matters.  A zero
    axis has no direction and gives NaN for that element.  Any real ``angle`` is accepted
    (negative angles and angles beyond ``pi`` wrap around as rotations do): a tensor of the
    dtype of ``axis`` or numbers (a float, numpy scalar or array, or a list), converted to it;
    not a bool.  Equal to ``torchlie.so3.exp(angle * axis / |axis|)``.

    Example:
        >>> R = axis_angle_to_matrix(torch.tensor([0.0, 0.0, 2.0]), torch.tensor(torch.pi / 3))
        >>> R @ torch.tensor([1.0, 0.0, 0.0])
        tensor([0.5000, 0.8660, 0.0000])
    """
    fn = _NAME + "axis_angle_to_matrix"
    n, dtype = _checks.tensor(axis, fn, "axis", (3,))
    t = _checks.real(angle, fn, "angle", n, ("axis", axis))
    _checks.batch_broadcast(fn, (n.shape[:-1], "axis"), (t.shape, "angle"))
    unit = _unit(n)  # zero axis -> NaN (documented)
    return _checks.out(_so3._ExpMapFn(t.unsqueeze(-1) * unit), dtype)


@_checks.float32_exact
def matrix_to_axis_angle(
    R: Float[Tensor, "*b 3 3"],
) -> tuple[Float[Tensor, "*b 3"], Float[Tensor, "*b"]]:
    """Unit axis and angle of a rotation matrix, ``angle`` in ``[0, pi]``.

    Through :func:`torchlie.so3.log` (same values and gradient meaning).  At angle 0 the axis is
    undetermined and ``(1, 0, 0)`` is returned, with zero (finite) gradient; at exactly ``pi``
    the axis sign follows the canonical rule of :mod:`torchlie.quaternion` (largest-magnitude
    component positive).

    Returns:
        ``(axis, angle)``: ``(..., 3)`` unit vectors and ``(...)`` angles.

    Example:
        >>> axis, angle = matrix_to_axis_angle(torch.diag(torch.tensor([-1.0, 1.0, -1.0])))
        >>> axis, angle
        (tensor([0., 1., 0.]), tensor(3.1416))
    """
    x, dtype = _checks.tensor(R, _NAME + "matrix_to_axis_angle", "R", (3, 3))
    w = _so3._LogFn(x)
    n = _coeffs.norm(w, keepdim=True)  # at every magnitude (the squares of tiny angles vanish)
    zero = n == 0
    # Double where: the zero-angle branch never sees 1/|w|; a NaN element stays NaN.
    axis = torch.where(zero, w.new_tensor([1.0, 0.0, 0.0]), w / torch.where(zero, 1.0, n))
    # |w| may round one ulp above pi.  Not clamp: its derivative at the bound is torch's
    # choice (0 since torch 2.15), and |w| is exactly pi at every half turn about an axis.
    angle = torch.where(n[..., 0] > math.pi, math.pi, n[..., 0])
    return _checks.out(axis, dtype), _checks.out(angle, dtype)


# ----------------------------------------------------------------------------------------------
# Continuous representations for networks
# ----------------------------------------------------------------------------------------------


def _unit(v: Tensor) -> Tensor:
    """``v / |v|``, robust to over/underflow of ``|v|^2``; ``v = 0`` gives NaN."""
    # Scale by the (detached) largest magnitude first: v / |v| is scale invariant, so the
    # detached scale changes neither the value nor the gradient, and |v|^2 cannot overflow.
    s = v.detach().abs().amax(dim=-1, keepdim=True)
    u = v / s
    return u * torch.rsqrt((u * u).sum(-1, keepdim=True))


@_checks.float32_exact
def rot6d_to_matrix(x: Float[Tensor, "*b 6"]) -> Float[Tensor, "*b 3 3"]:
    """Rotation matrix from the continuous 6-D representation (Gram-Schmidt).

    Layout: ``x = (a1, a2)``, ``a1 = x[..., 0:3]`` and ``a2 = x[..., 3:6]`` are the *first two
    columns* of the (unnormalised) matrix.  ``b1 = a1 / |a1|``,
    ``b2 = normalise(a2 - (b1 . a2) b1)``, ``b3 = b1 x b2``, and ``R = [b1 | b2 | b3]``.  The
    orthogonalisation of ``b2`` is done twice ("twice is enough"), so that ``R`` is orthonormal
    to rounding even when ``a2`` is nearly parallel to ``a1``.  The result is invariant to the
    positive scale of ``a1`` and of ``a2``, and is accurate and has finite gradients at any
    magnitude (``1e-20`` or ``1e20``).

    Degenerate input: ``a1 = 0``, or ``a2`` exactly parallel to ``a1`` (zero Gram-Schmidt
    residual, ``a2 = 0`` included) gives NaN for that element only; nearly parallel inputs give
    a rotation whose second column is ill-conditioned.

    Example:
        >>> rot6d_to_matrix(torch.tensor([2.0, 0.0, 0.0, 1.0, 3.0, 0.0]))
        tensor([[1., 0., 0.],
                [0., 1., 0.],
                [0., 0., 1.]])
    """
    v, dtype = _checks.tensor(x, _NAME + "rot6d_to_matrix", "x", (6,))
    return _checks.out(_rot6d_to_matrix(v), dtype)


def _rot6d_to_matrix(x: Tensor) -> Tensor:
    a1, a2 = x[..., :3], x[..., 3:]
    b1 = _unit(a1)
    r = a2 - (b1 * a2).sum(-1, keepdim=True) * b1
    # a2 parallel to a1 (residual at rounding level) has no second direction: NaN, documented
    # (max-abs comparison: no squares, so no overflow or underflow at extreme scales)
    tol = 64 * torch.finfo(x.dtype).eps
    parallel = r.abs().amax(-1, keepdim=True) <= tol * a2.abs().amax(-1, keepdim=True)
    r = _unit(torch.where(parallel, torch.full_like(r, float("nan")), r))
    b2 = _unit(r - (b1 * r).sum(-1, keepdim=True) * b1)
    b3 = torch.linalg.cross(b1, b2, dim=-1)
    b1 = b1 + 0.0 * b2  # a degenerate a2 makes the whole matrix NaN, not only two columns
    return _layout.interleave((b1, b2, b3))


@_checks.float32_exact
def matrix_to_rot6d(R: Float[Tensor, "*b 3 3"]) -> Float[Tensor, "*b 6"]:
    """The 6-D representation of ``R``: its first two columns, ``(R[:, 0], R[:, 1])``.

    ``rot6d_to_matrix(matrix_to_rot6d(R)) == R`` for a rotation ``R`` (to rounding).

    Example:
        >>> matrix_to_rot6d(torch.eye(3))
        tensor([1., 0., 0., 0., 1., 0.])
    """
    x, dtype = _checks.tensor(R, _NAME + "matrix_to_rot6d", "R", (3, 3))
    return _checks.out(torch.cat((x[..., :, 0], x[..., :, 1]), dim=-1), dtype)


@_checks.float32_exact
def rot9d_to_matrix(x: Float[Tensor, "*b 9"]) -> Float[Tensor, "*b 3 3"]:
    """Rotation matrix from the 9-D representation: SVD special orthogonalisation.

    Layout: ``x`` is a ``3 x 3`` matrix ``M`` flattened row by row (``M = x.unflatten(-1,
    (3, 3))``, so ``matrix.flatten(-2)`` is the inverse for a rotation).  Returns the rotation
    nearest to ``M`` in the Frobenius norm, ``U diag(1, 1, det(U V^T)) V^T``
    (:func:`torchlie.so3.project`), whose backward pass is finite wherever the two smallest
    signed singular values of ``M`` do not sum to zero (rotations included, where the SVD's own
    backward divides by zero).  A non-finite element gives NaN for that element only.

    Example:
        >>> rot9d_to_matrix(torch.tensor([2.0, 0.0, 0.0, 0.0, 3.0, 0.0, 0.0, 0.0, 0.5]))
        tensor([[1., 0., 0.],
                [0., 1., 0.],
                [0., 0., 1.]])
    """
    v, dtype = _checks.tensor(x, _NAME + "rot9d_to_matrix", "x", (9,))
    M = v.unflatten(-1, (3, 3))
    return _checks.out(_so3._ProjectFn(M), dtype)
