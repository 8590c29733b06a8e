"""Unit quaternions: Hamilton convention, scalar first ``(w, x, y, z)``, shape ``(..., 4)``.

``q`` and ``-q`` are the same rotation.  The *canonical* representative has ``w > 0``; when
``w == 0`` (a rotation by exactly pi) it is the one whose largest-magnitude vector component is
positive (the first such component on ties).  :func:`canonicalize`, :func:`from_matrix` and
:func:`from_rotvec` at pi all follow that rule, so ``torchlie.so3.log`` at pi is deterministic.

A quaternion acts on a point ``p`` as ``q * [0, p] * conj(q)``; :func:`to_matrix` gives the
matrix ``R`` with ``R @ p`` equal to that rotation (column vectors).  Products compose like
matrices: ``to_matrix(multiply(q1, q2)) == to_matrix(q1) @ to_matrix(q2)``.

A zero quaternion has no rotation: functions that normalise return NaN for that batch element
(never a silent identity).
"""

from __future__ import annotations

import torch
from torch import Tensor

from . import _checks, _coeffs
from ._typing import Float

__all__ = [
    "multiply",
    "conjugate",
    "normalize",
    "canonicalize",
    "from_matrix",
    "to_matrix",
    "from_rotvec",
    "to_rotvec",
]


def multiply(q1: Float[Tensor, "*b1 4"], q2: Float[Tensor, "*b2 4"]) -> Float[Tensor, "*b 4"]:
    """Hamilton product ``q1 * q2`` (batch shapes broadcast).

    Example:
        >>> q = torch.tensor([0.0, 1.0, 0.0, 0.0])  # pi about x
        >>> multiply(q, q)
        tensor([-1.,  0.,  0.,  0.])
    """
    fn = "torchlie.quaternion.multiply"
    a, dtype = _checks.tensor(q1, fn, "q1", (4,))
    b, _ = _checks.tensor(q2, fn, "q2", (4,))
    _checks.same_dtype(fn, q1=q1, q2=q2)
    _checks.batch_broadcast(fn, (a.shape[:-1], "q1"), (b.shape[:-1], "q2"))
    return _checks.out(_multiply(a, b), dtype)


def _multiply(a: Tensor, b: Tensor) -> Tensor:
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        (
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ),
        dim=-1,
    )


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


def normalize(q: Float[Tensor, "*b 4"]) -> Float[Tensor, "*b 4"]:
    """``q / |q|``.  A zero quaternion gives NaN for that element.

    Example:
        >>> normalize(torch.tensor([2.0, 0.0, 0.0, 0.0]))
        tensor([1., 0., 0., 0.])
    """
    x, dtype = _checks.tensor(q, "torchlie.quaternion.normalize", "q", (4,))
    return _checks.out(_normalize(x), dtype)


def _normalize(q: Tensor) -> Tensor:
    n2 = (q * q).sum(-1, keepdim=True)
    # |q| = 0 -> 0/0 = NaN for that element only (documented), never identity.
    return q * torch.rsqrt(n2)


def canonicalize(q: Float[Tensor, "*b 4"]) -> Float[Tensor, "*b 4"]:
    """The representative of ``{q, -q}`` with ``w > 0`` (rule at ``w == 0``: module docstring).

    Does not normalise.

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
    return _checks.out(_to_matrix(x), dtype)


def _to_matrix(q: Tensor) -> Tensor:
    w, x, y, z = q.unbind(-1)
    s = 2.0 / (w * w + x * x + y * y + z * z)
    xs, ys, zs = x * s, y * s, z * s
    wx, wy, wz = w * xs, w * ys, w * zs
    xx, xy, xz = x * xs, x * ys, x * zs
    yy, yz, zz = y * ys, y * zs, z * zs
    return torch.stack(
        (
            1.0 - (yy + zz), xy - wz, xz + wy,
            xy + wz, 1.0 - (xx + zz), yz - wx,
            xz - wy, yz + wx, 1.0 - (xx + yy),
        ),
        dim=-1,
    ).unflatten(-1, (3, 3))  # fmt: skip


def from_matrix(R: Float[Tensor, "*b 3 3"]) -> Float[Tensor, "*b 4"]:
    """Canonical unit quaternion of a rotation matrix (robust at every angle, pi included).

    Shepperd's method: of the four equivalent formulas the one dividing by the largest of
    ``|w|, |x|, |y|, |z|`` is selected per element with ``torch.where`` (no boolean-mask
    writes, no host sync).  The input first takes one orthogonalisation step
    ``R (3I - R^T R) / 2``, exact on SO(3), so that the result and its gradient are those of the
    nearest rotation to first order: ``from_matrix(R + eps E)`` equals
    ``from_matrix(polar(R + eps E))`` up to ``O(eps^2)``, whichever formula is selected.

    Example:
        >>> from_matrix(torch.diag(torch.tensor([1.0, -1.0, -1.0])))  # pi about x
        tensor([0., 1., 0., 0.])
    """
    x, dtype = _checks.tensor(R, "torchlie.quaternion.from_matrix", "R", (3, 3))
    return _checks.out(_from_matrix(x), dtype)


def _orthogonalize_step(R: Tensor) -> Tensor:
    """One Newton step of the polar decomposition, ``R - R (R^T R - I) / 2``."""
    E = R.transpose(-1, -2) @ R
    E = E - torch.eye(3, dtype=R.dtype, device=R.device)
    return R - 0.5 * (R @ E)


def _from_matrix(R: Tensor) -> Tensor:
    m = _orthogonalize_step(R)
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = m.flatten(-2).unbind(-1)
    # 4 q_i^2 for i = w, x, y, z
    d = torch.stack(
        (
            1.0 + m00 + m11 + m22,
            1.0 + m00 - m11 - m22,
            1.0 - m00 + m11 - m22,
            1.0 - m00 - m11 + m22,
        ),
        dim=-1,
    )
    s21, s02, s10 = m21 - m12, m02 - m20, m10 - m01  # 4 w (x, y, z)
    a01, a02, a12 = m01 + m10, m02 + m20, m12 + m21  # 4 (xy, xz, yz)
    d0, d1, d2, d3 = d.unbind(-1)
    # Row i holds 4 q_i q: proportional to q with a positive i-th entry.
    cand = torch.stack(
        (
            torch.stack((d0, s21, s02, s10), -1),
            torch.stack((s21, d1, a01, a02), -1),
            torch.stack((s02, a01, d2, a12), -1),
            torch.stack((s10, a02, a12, d3), -1),
        ),
        dim=-2,
    )
    pivot = torch.argmax(d, dim=-1, keepdim=True)
    c = torch.gather(cand, -2, pivot.unsqueeze(-1).expand(*pivot.shape[:-1], 1, 4))[..., 0, :]
    # c = 4 q_p q with q_p > 0, so |c| = 4 q_p >= 2 for a rotation: the division is safe, and
    # a NaN element stays in its own row.
    q = c * torch.rsqrt((c * c).sum(-1, keepdim=True))
    return _canonicalize(q)


# ----------------------------------------------------------------------------------------------
# Rotation vectors
# ----------------------------------------------------------------------------------------------


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
    t2 = (omega * omega).sum(-1, keepdim=True)
    h2 = 0.25 * t2  # (t/2)^2
    # cos(t/2) = 1 - 2 sin^2(t/4) = 1 - h2 * cosc(h2)... computed as 1 - 2 (h/2)^2 sinc(h/2)^2
    half = 0.5 * _coeffs.sinc(h2) * omega  # sin(t/2)/t * omega
    w = 1.0 - h2 * _coeffs.cosc(h2)  # cos(t/2), accurate at small t
    return torch.cat((w, half), dim=-1)


def to_rotvec(q: Float[Tensor, "*b 4"]) -> Float[Tensor, "*b 3"]:
    """Rotation vector (angle in ``[0, pi]``) of ``q / |q|``; ``q`` and ``-q`` give the same.

    Computed as ``2 atan2(|v|, |w|) v/|v|`` with ``v`` signed like the canonical
    representative; smooth at the identity.  Zero quaternion: NaN.

    Example:
        >>> to_rotvec(torch.tensor([0.0, 0.0, 1.0, 0.0]))
        tensor([0.0000, 3.1416, 0.0000])
    """
    x, dtype = _checks.tensor(q, "torchlie.quaternion.to_rotvec", "q", (4,))
    return _checks.out(_to_rotvec(x), dtype)


def _to_rotvec(q: Tensor) -> Tensor:
    q = _canonicalize(q)
    w = q[..., :1]
    v = q[..., 1:]
    n = _coeffs.norm(v, keepdim=True)
    # Zero quaternion: w = 0 and n = 0 -> make it NaN, not zero.
    bad = (w == 0) & (n == 0)
    ratio = _coeffs.atan_ratio(n, w)
    ratio = torch.where(bad, torch.full_like(ratio, float("nan")), ratio)
    return 2.0 * ratio * v
