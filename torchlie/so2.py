"""SO(2): planar rotation matrices ``(..., 2, 2)`` and angles ``(..., 1)``.

Conventions (see :mod:`torchlie`): matrices act on column vectors, ``p_world = R @ p_body``;
the tangent is the angle ``theta`` (counter-clockwise positive) as a ``(..., 1)`` tensor,
``hat(theta) = [[0, -theta], [theta, 0]]``; perturbations are on the right,
``R (+) d = R Exp(d)``.  :func:`log` returns the angle in ``(-pi, pi]``: exactly ``pi`` (the
float nearest it) at a half turn.

The group is commutative, so the adjoint is 1, the small adjoint 0 and every Jacobian of
``exp``/``log`` is 1 (``1 x 1`` matrices, to keep the shapes of :mod:`torchlie.so3`).  The
unit complex number of ``R`` is ``(cos theta, sin theta)``, its first column
(:func:`to_complex`, :func:`from_complex`).

Matrices off SO(2): :func:`log` reads ``R`` as its nearest rotation (the polar factor, which
for a 2x2 matrix is exactly the rotation by ``atan2(R10 - R01, R00 + R11)``), so its value and
gradient are those of ``log o polar`` for every matrix whose conformal part is non-zero.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import Tensor

from . import _checks, _coeffs, _components, _layout
from ._autograd import CustomFunction, blocked
from ._typing import Bool, Float

__all__ = [
    "hat",
    "vee",
    "exp",
    "log",
    "compose",
    "inverse",
    "act",
    "adjoint",
    "ad",
    "jac_left",
    "jac_right",
    "jac_left_inv",
    "jac_right_inv",
    "identity",
    "random",
    "is_valid",
    "to_complex",
    "from_complex",
    "angle_to_complex",
    "complex_to_angle",
    "distance",
    "interpolate",
    "rplus",
    "rminus",
    "lplus",
    "lminus",
    "between",
    "jac_compose",
    "jac_inverse",
    "jac_act",
    "jac_rplus",
    "jac_rminus",
    "jac_between",
]

_NAME = "torchlie.so2."


# ----------------------------------------------------------------------------------------------
# Formulas on components (shared with torchlie.se2)
# ----------------------------------------------------------------------------------------------


def matrix(c: Tensor, s: Tensor) -> Tensor:
    """``[[c, -s], [s, c]]`` of planes ``c``, ``s``."""
    return torch.stack((c, -s, s, c), dim=-1).unflatten(-1, (2, 2))


def columns(like: Tensor, n: int) -> tuple[Tensor | None, ...]:
    """Where a forward writes the ``n`` entries of its result (:func:`torchlie._layout.outputs`)."""
    return _layout.outputs(like, n)


def assemble(parts: Sequence[Tensor | float], out: Sequence[Tensor | None]) -> Tensor:
    """The ``(..., len(parts))`` result of planes and constants, written into ``out`` (from
    :func:`columns`) where those are columns: constants filled in place, planes copied unless
    they were written there."""
    if isinstance(out, _layout.Columns):
        for part, column in zip(parts, out, strict=True):
            if isinstance(part, float):
                column.fill_(part)
            elif part is not column:
                column.copy_(part)
        return out.result
    like = next(p for p in parts if isinstance(p, Tensor))
    return torch.stack(
        [p if isinstance(p, Tensor) else torch.full_like(like, p) for p in parts], -1
    )


def angle(x: Tensor, y: Tensor) -> Tensor:
    """``atan2(y, x)`` in ``(-pi, pi]`` (forward only): a zero ``y`` is read as ``+0``, so an
    exact half turn given with a negative zero gives ``pi``, not ``-pi``.

    torch's ``atan2`` itself: the angle is all of ``log``'s arithmetic, and the
    batch-independent one (:func:`torchlie._coeffs.angle`) would cost several times as much;
    an element alone and in a batch may differ by an ulp."""
    return torch.atan2(torch.where(y == 0, 0.0, y), x)


def conformal(R: Tensor) -> tuple[Tensor, Tensor]:
    """``((R00 + R11) / 2, (R10 - R01) / 2)``: the cosine and sine of the polar factor's angle
    times its scale, halved term by term (the plain sums overflow from half the largest
    float); the derivatives of the angle with respect to ``R`` are half those with respect to
    these."""
    return (
        torch.add(R[..., 0, 0] * 0.5, R[..., 1, 1], alpha=0.5),
        torch.sub(R[..., 1, 0] * 0.5, R[..., 0, 1], alpha=0.5),
    )


def _exp(theta: Tensor) -> Tensor:
    t = theta[..., 0]
    o = columns(t, 4)
    c, s = torch.cos(t), torch.sin(t)  # contiguous: strided stores take a slower loop here
    return assemble((c, torch.neg(s, out=o[1]), s, c), o).unflatten(-1, (2, 2))


def _exp_backward(saved: tuple[Tensor, ...], g: Tensor) -> tuple[Tensor]:
    # dR/dtheta = R hat(1) = [[-s, -c], [c, -s]]
    R = saved[0]
    c, s = R[..., 0, 0], R[..., 1, 0]
    return ((c * (g[..., 1, 0] - g[..., 0, 1]) - s * (g[..., 0, 0] + g[..., 1, 1])).unsqueeze(-1),)


def _exp_jvp(saved: tuple[Tensor, ...], d: Tensor) -> Tensor:
    R = saved[0]
    return matrix(-R[..., 1, 0], R[..., 0, 0]) * d.unsqueeze(-1)


# one pass over blocks of the batch (the one driver), the backward's planes kept in cache
_exp_backward_blocked = blocked(lambda *t: _exp_backward(t[:-1], t[-1]), (2, 2))

_ExpFn = CustomFunction(
    "So2Exp",
    forward=_exp,
    save=lambda inputs, out: (out,),
    backward=lambda saved, g: _exp_backward_blocked(*saved, g),
    jvp=_exp_jvp,
    event_dims=(1,),
)


def _log(R: Tensor) -> Tensor:
    return angle(*conformal(R)).unsqueeze(-1)


def angle_scaled(x: Tensor, y: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """``(x / k, y / k, r2, 1 / k)``: the conformal part scaled by the power of two ``k``
    (detached) that brings ``max(|x|, |y|)`` into ``[1, 2)``
    (:func:`torchlie._coeffs.power_of_two`), and its squared norm ``r2`` (1 where it is 0), for
    the derivative ``(x dy - y dx) / (x^2 + y^2)`` of the angle without the squares of ``x``
    and ``y`` at their own magnitude.

    The scaling is exact, so wherever the squares neither overflow nor underflow the
    derivatives have the bits of the formula on ``x`` and ``y`` themselves; at the zero
    conformal part ``k = 1`` and the derivative is 0.  The derivative, homogeneous of degree
    -1, is the one of the scaled part divided by ``k``; with ``k`` held constant, its own
    derivatives are the true ones too (double backward), and their powers of ``r2`` cannot
    overflow either."""
    m = _coeffs.largest((x, y))
    zero = 1.0 - torch.sign(m)  # 1 where m = 0, else 0 (cheaper than a comparison)
    inv = torch.reciprocal(_coeffs.power_of_two(m + zero))  # exact: k is a normal power of two
    xs, ys = x * inv, y * inv
    return xs, ys, xs * xs + ys * ys + zero, inv


def angle_gradient(x: Tensor, y: Tensor, g: Tensor) -> tuple[Tensor, Tensor]:
    """Gradient ``(-y, x) g / (x^2 + y^2)`` of ``g atan2(y, x)`` at every finite magnitude (0
    at ``x = y = 0``, where there is no direction)."""
    xs, ys, r2, inv = angle_scaled(x, y)
    c = g / r2 * inv
    return -(ys * c), xs * c


def angle_tangent(x: Tensor, y: Tensor, dx: Tensor, dy: Tensor) -> Tensor:
    """Tangent ``(x dy - y dx) / (x^2 + y^2)`` of ``atan2(y, x)`` (as :func:`angle_gradient`)."""
    xs, ys, r2, inv = angle_scaled(x, y)
    return (xs * dy - ys * dx) / r2 * inv


def _log_backward(saved: tuple[Tensor, ...], g: Tensor) -> tuple[Tensor]:
    # d atan2(y, x) = (x dy - y dx) / (x^2 + y^2); 0 where x = y = 0 (no direction)
    gx, gy = angle_gradient(*conformal(saved[0]), 0.5 * g[..., 0])
    o = columns(gx, 4)
    return (assemble((gx, torch.neg(gy, out=o[1]), gy, gx), o).unflatten(-1, (2, 2)),)


def _log_jvp(saved: tuple[Tensor, ...], dR: Tensor) -> Tensor:
    return angle_tangent(*conformal(saved[0]), *conformal(dR)).unsqueeze(-1)


# one pass over blocks of the batch (the one driver), the backward's planes kept in cache
_log_backward_blocked = blocked(lambda *t: _log_backward(t[:-1], t[-1]), (2, 1))

_LogFn = CustomFunction(
    "So2Log",
    forward=_log,
    save=lambda inputs, out: (inputs[0],),
    backward=lambda saved, g: _log_backward_blocked(*saved, g),
    jvp=_log_jvp,
    event_dims=(2,),
)


def log_angle(R: Tensor) -> Tensor:
    """:func:`log` without checks (for :mod:`torchlie.se2`)."""
    return _LogFn(R)


def exp_angle(theta: Tensor) -> Tensor:
    """:func:`exp` without checks (for :mod:`torchlie.se2`)."""
    return _ExpFn(theta)


def _ones(batch: torch.Size, like: Tensor, value: float = 1.0) -> Tensor:
    return torch.full((*batch, 1, 1), value, dtype=like.dtype, device=like.device)


# ----------------------------------------------------------------------------------------------
# hat / vee, exp / log
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def hat(theta: Float[Tensor, "*b 1"]) -> Float[Tensor, "*b 2 2"]:
    """``[[0, -theta], [theta, 0]]``.

    Example:
        >>> hat(torch.tensor([2.0]))
        tensor([[ 0., -2.],
                [ 2.,  0.]])
    """
    x, dtype = _checks.tensor(theta, _NAME + "hat", "theta", (1,))
    t = x[..., 0]
    return _checks.out(matrix(torch.zeros_like(t), t), dtype)


@_checks.float32_exact
def vee(Theta: Float[Tensor, "*b 2 2"]) -> Float[Tensor, "*b 1"]:
    """Inverse of :func:`hat`, applied to the skew-symmetric part: ``(M10 - M01)/2``.

    Example:
        >>> vee(hat(torch.tensor([2.0])))
        tensor([2.])
    """
    x, dtype = _checks.tensor(Theta, _NAME + "vee", "Theta", (2, 2))
    return _checks.out(_components.half_difference(x[..., 1, 0], x[..., 0, 1])[..., None], dtype)


@_checks.float32_exact
def exp(theta: Float[Tensor, "*b 1"]) -> Float[Tensor, "*b 2 2"]:
    """Rotation matrix ``[[cos t, -sin t], [sin t, cos t]]`` of the angle ``theta``.

    Exact to the rounding of ``sin`` and ``cos`` at every angle; the backward pass is the
    closed form ``dL/dtheta = <G, R hat(1)>``; double backward and forward mode are supported.

    Example:
        >>> exp(torch.tensor([torch.pi / 2])).round(decimals=6) + 0.0
        tensor([[ 0., -1.],
                [ 1.,  0.]])
    """
    x, dtype = _checks.tensor(theta, _NAME + "exp", "theta", (1,))
    return _checks.out(_ExpFn(x), dtype)


@_checks.float32_exact
def log(R: Float[Tensor, "*b 2 2"]) -> Float[Tensor, "*b 1"]:
    """Angle of ``R`` in ``(-pi, pi]``: ``atan2(R10 - R01, R00 + R11)``.

    At a half turn the result is exactly ``pi`` (never ``-pi``).  That is the angle of the
    polar factor of ``R`` (its nearest rotation), so value and gradient are those of
    ``log o polar``; the gradient is the exact derivative ``d theta`` along every tangent
    direction ``R hat(d)`` and 0 across.  The log jumps by ``2 pi`` at the half turn; there
    (and only there) the gradient returned is the derivative of the branch that holds ``pi``
    (the limit from the angles below it), which is also the derivative ``1`` of the continuous
    angle in tangent coordinates.  Right at every finite magnitude of the conformal part
    (its squares are never formed at their own magnitude); at the zero matrix it is 0.

    Example:
        >>> log(-torch.eye(2))
        tensor([3.1416])
    """
    x, dtype = _checks.tensor(R, _NAME + "log", "R", (2, 2))
    return _checks.out(_LogFn(x), dtype)


# ----------------------------------------------------------------------------------------------
# Group operations
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def compose(R1: Float[Tensor, "*b1 2 2"], R2: Float[Tensor, "*b2 2 2"]) -> Float[Tensor, "*b 2 2"]:
    """``R1 @ R2`` (batch shapes broadcast).

    Example:
        >>> R = exp(torch.tensor([0.5]))
        >>> torch.allclose(compose(R, R), exp(torch.tensor([1.0])))
        True
    """
    a, b, dtype, _ = _checks.pair(_NAME + "compose", R1, R2, "R1", "R2", (2, 2), (2, 2))
    return _checks.out(a @ b, dtype)


@_checks.float32_exact
def inverse(R: Float[Tensor, "*b 2 2"]) -> Float[Tensor, "*b 2 2"]:
    """``R^T``.

    Example:
        >>> R = exp(torch.tensor([0.3]))
        >>> torch.allclose(inverse(R) @ R, torch.eye(2))
        True
    """
    x, dtype = _checks.tensor(R, _NAME + "inverse", "R", (2, 2))
    return _checks.out(x.transpose(-1, -2).clone(), dtype)


@_checks.float32_exact
def act(R: Float[Tensor, "*b1 2 2"], points: Float[Tensor, "*b2 2"]) -> Float[Tensor, "*b 2"]:
    """Rotate points: ``R @ p`` (batch shapes broadcast).

    Example:
        >>> act(exp(torch.tensor([torch.pi / 2])), torch.tensor([1.0, 0.0])).round(decimals=6) + 0
        tensor([0., 1.])
    """
    a, p, dtype, _ = _checks.pair(_NAME + "act", R, points, "R", "points", (2, 2), (2,))
    return _checks.out((a @ p.unsqueeze(-1)).squeeze(-1), dtype)


@_checks.float32_exact
def adjoint(R: Float[Tensor, "*b 2 2"]) -> Float[Tensor, "*b 1 1"]:
    """Adjoint matrix of SO(2): ``[[1]]`` (the group is commutative).

    Example:
        >>> adjoint(identity())
        tensor([[1.]])
    """
    x, dtype = _checks.tensor(R, _NAME + "adjoint", "R", (2, 2))
    return _checks.out(_ones(x.shape[:-2], x), dtype)


@_checks.float32_exact
def ad(theta: Float[Tensor, "*b 1"]) -> Float[Tensor, "*b 1 1"]:
    """Small adjoint of so(2): ``[[0]]`` (the Lie bracket vanishes).

    Example:
        >>> ad(torch.tensor([0.3]))
        tensor([[0.]])
    """
    x, dtype = _checks.tensor(theta, _NAME + "ad", "theta", (1,))
    return _checks.out(_ones(x.shape[:-1], x, 0.0), dtype)


def _jac(fn: str, theta: Tensor) -> Tensor:
    x, dtype = _checks.tensor(theta, _NAME + fn, "theta", (1,))
    return _checks.out(_ones(x.shape[:-1], x), dtype)


@_checks.float32_exact
def jac_left(theta: Float[Tensor, "*b 1"]) -> Float[Tensor, "*b 1 1"]:
    """Left Jacobian ``[[1]]``: ``Exp(t + d) = Exp(d) Exp(t)``.

    Example:
        >>> jac_left(torch.tensor([0.3]))
        tensor([[1.]])
    """
    return _jac("jac_left", theta)


@_checks.float32_exact
def jac_right(theta: Float[Tensor, "*b 1"]) -> Float[Tensor, "*b 1 1"]:
    """Right Jacobian ``[[1]]``: ``Exp(t + d) = Exp(t) Exp(d)``.

    Example:
        >>> jac_right(torch.tensor([0.3]))
        tensor([[1.]])
    """
    return _jac("jac_right", theta)


@_checks.float32_exact
def jac_left_inv(theta: Float[Tensor, "*b 1"]) -> Float[Tensor, "*b 1 1"]:
    """Inverse left Jacobian ``[[1]]``.

    Example:
        >>> jac_left_inv(torch.tensor([0.3]))
        tensor([[1.]])
    """
    return _jac("jac_left_inv", theta)


@_checks.float32_exact
def jac_right_inv(theta: Float[Tensor, "*b 1"]) -> Float[Tensor, "*b 1 1"]:
    """Inverse right Jacobian ``[[1]]``.

    Example:
        >>> jac_right_inv(torch.tensor([0.3]))
        tensor([[1.]])
    """
    return _jac("jac_right_inv", theta)


# ----------------------------------------------------------------------------------------------
# Construction, validation, conversions
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def identity(
    *batch: int, dtype: torch.dtype | None = None, device: torch.device | str | None = None
) -> Float[Tensor, "*batch 2 2"]:
    """Identity rotations of shape ``(*batch, 2, 2)``.

    Example:
        >>> identity(3).shape
        torch.Size([3, 2, 2])
    """
    _, dtype = _checks.factory(_NAME + "identity", batch, dtype)
    return torch.eye(2, dtype=dtype, device=device).expand(*batch, 2, 2).clone()


@_checks.float32_exact
def random(
    *batch: int,
    generator: torch.Generator | None = None,
    dtype: torch.dtype | None = None,
    device: torch.device | str | None = None,
) -> Float[Tensor, "*batch 2 2"]:
    """Uniform random rotations (angles uniform in ``[-pi, pi)``).

    Example:
        >>> R = random(4, generator=torch.Generator().manual_seed(0))
        >>> bool(is_valid(R).all())
        True
    """
    compute, dtype = _checks.factory(_NAME + "random", batch, dtype)
    u = torch.rand(*batch, 1, generator=generator, dtype=compute, device=device)
    return _checks.out(_exp((2.0 * u - 1.0) * math.pi), dtype)


@_checks.float32_exact
def is_valid(R: Float[Tensor, "*b 2 2"], atol: float | None = None) -> Bool[Tensor, "*b"]:
    """Per element: finite, ``R^T R = I`` and ``det R = 1`` within ``atol``.

    ``atol`` (a non-negative finite real number) defaults to ``100 * eps`` of the input dtype
    (``4 * eps`` for float16/bfloat16).  This reads the values (a device sync where you branch
    on it).

    Example:
        >>> is_valid(torch.stack((torch.eye(2), 2 * torch.eye(2))))
        tensor([ True, False])
    """
    x, _ = _checks.tensor(R, _NAME + "is_valid", "R", (2, 2))
    tol = _checks.tolerance(atol, _NAME + "is_valid", "atol", R.dtype)
    eye = torch.eye(2, dtype=x.dtype, device=x.device)
    orth = (x.transpose(-1, -2) @ x - eye).abs().amax(dim=(-1, -2)) <= tol
    det = (x[..., 0, 0] * x[..., 1, 1] - x[..., 0, 1] * x[..., 1, 0] - 1.0).abs() <= tol
    return orth & det & torch.isfinite(x).all(dim=-1).all(dim=-1)


@_checks.float32_exact
def to_complex(R: Float[Tensor, "*b 2 2"]) -> Float[Tensor, "*b 2"]:
    """Unit complex number ``(cos theta, sin theta)`` of ``R`` as a real ``(..., 2)`` tensor
    (the first column of ``R``, a copy).

    Example:
        >>> to_complex(exp(torch.tensor([torch.pi / 2]))).round(decimals=6) + 0.0
        tensor([0., 1.])
    """
    x, dtype = _checks.tensor(R, _NAME + "to_complex", "R", (2, 2))
    return _checks.out(x[..., :, 0].clone(), dtype)


@_checks.float32_exact
def from_complex(z: Float[Tensor, "*b 2"]) -> Float[Tensor, "*b 2 2"]:
    """Rotation of the complex number ``z = (re, im)``, a real ``(..., 2)`` tensor.

    ``z`` need not be unit: the rotation of ``z / |z|`` is returned (scale-invariant, with its
    gradient); ``z = 0`` gives NaN for that element only.

    Example:
        >>> from_complex(torch.tensor([0.0, 2.0]))
        tensor([[ 0., -1.],
                [ 1.,  0.]])
    """
    x, dtype = _checks.tensor(z, _NAME + "from_complex", "z", (2,))
    x = _coeffs.rescaled(x)[0]  # no overflow or underflow of the squares
    u = x / _coeffs.norm(x, keepdim=True)
    return _checks.out(matrix(u[..., 0], u[..., 1]), dtype)


@_checks.float32_exact
def angle_to_complex(theta: Float[Tensor, "*b 1"]) -> Float[Tensor, "*b 2"]:
    """Unit complex number ``(cos theta, sin theta)`` of the angle ``theta``.

    Example:
        >>> angle_to_complex(torch.tensor([torch.pi / 2])).round(decimals=6) + 0.0
        tensor([0., 1.])
    """
    x, dtype = _checks.tensor(theta, _NAME + "angle_to_complex", "theta", (1,))
    return _checks.out(torch.cat((torch.cos(x), torch.sin(x)), dim=-1), dtype)


@_checks.float32_exact
def complex_to_angle(z: Float[Tensor, "*b 2"]) -> Float[Tensor, "*b 1"]:
    """Angle ``atan2(im, re)`` of the complex number ``z = (re, im)`` in ``(-pi, pi]`` (any
    non-zero scale; the same value and gradient as :func:`log` of its rotation).

    Example:
        >>> complex_to_angle(torch.tensor([-2.0, 0.0]))
        tensor([3.1416])
    """
    x, dtype = _checks.tensor(z, _NAME + "complex_to_angle", "z", (2,))
    # [[re, -im], [im, re]]: its conformal part is z itself, exactly (the halves of each pair)
    re, im = x[..., 0], x[..., 1]
    return _checks.out(_LogFn(torch.stack((re, -im, im, re), -1).unflatten(-1, (2, 2))), dtype)


# ----------------------------------------------------------------------------------------------
# Metrics, interpolation, plus / minus
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def distance(R1: Float[Tensor, "*b1 2 2"], R2: Float[Tensor, "*b2 2 2"]) -> Float[Tensor, "*b"]:
    """Geodesic distance: ``|log(R1^T R2)|`` in ``[0, pi]``.

    Not differentiable at 0 (a cone) and at pi (a ridge); the gradient there is the zero
    subgradient, finite.

    Example:
        >>> distance(identity(), exp(torch.tensor([-0.3])))
        tensor(0.3000)
    """
    a, b, dtype, _ = _checks.pair(_NAME + "distance", R1, R2, "R1", "R2", (2, 2), (2, 2))
    M = a.transpose(-1, -2) @ b
    x, y = conformal(M)
    return _checks.out(_coeffs.atan2(y.abs(), x), dtype)


@_checks.float32_exact
def interpolate(
    R0: Float[Tensor, "*b1 2 2"], R1: Float[Tensor, "*b2 2 2"], t: Float[Tensor, "*b3"] | float
) -> Float[Tensor, "*b 2 2"]:
    """Geodesic interpolation ``R0 Exp(t Log(R0^T R1))`` (``t`` broadcasts with the batch).

    ``t`` is a tensor of the dtype of ``R0`` or numbers; at a relative half turn the path turns
    counter-clockwise (the log is ``+pi``).

    Example:
        >>> R1 = exp(torch.tensor([1.0]))
        >>> torch.allclose(interpolate(identity(), R1, 0.5), exp(torch.tensor([0.5])))
        True
    """
    fn = _NAME + "interpolate"
    a, b, dtype, _ = _checks.pair(fn, R0, R1, "R0", "R1", (2, 2), (2, 2))
    t = _checks.real(t, fn, "t", a, ("R0", R0))
    _checks.batch_broadcast(fn, (a.shape[:-2], "R0"), (b.shape[:-2], "R1"), (t.shape, "t"))
    w = _LogFn(a.transpose(-1, -2) @ b)
    return _checks.out(a @ _ExpFn(t.unsqueeze(-1) * w), dtype)


@_checks.float32_exact
def rplus(R: Float[Tensor, "*b1 2 2"], tau: Float[Tensor, "*b2 1"]) -> Float[Tensor, "*b 2 2"]:
    """Right plus ``R Exp(tau)``.

    Example:
        >>> log(rplus(identity(), torch.tensor([0.3])))
        tensor([0.3000])
    """
    x, v, dtype, _ = _checks.pair(_NAME + "rplus", R, tau, "R", "tau", (2, 2), (1,))
    return _checks.out(x @ _ExpFn(v), dtype)


@_checks.float32_exact
def rminus(R1: Float[Tensor, "*b1 2 2"], R0: Float[Tensor, "*b2 2 2"]) -> Float[Tensor, "*b 1"]:
    """Right minus ``Log(R0^T R1)`` in ``(-pi, pi]``; ``rplus(R0, rminus(R1, R0)) == R1``.

    Example:
        >>> rminus(exp(torch.tensor([0.5])), exp(torch.tensor([0.2])))
        tensor([0.3000])
    """
    a, b, dtype, _ = _checks.pair(_NAME + "rminus", R1, R0, "R1", "R0", (2, 2), (2, 2))
    return _checks.out(_LogFn(b.transpose(-1, -2) @ a), dtype)


@_checks.float32_exact
def lplus(R: Float[Tensor, "*b1 2 2"], tau: Float[Tensor, "*b2 1"]) -> Float[Tensor, "*b 2 2"]:
    """Left plus ``Exp(tau) R`` (equal to :func:`rplus`: the group is commutative).

    Example:
        >>> log(lplus(identity(), torch.tensor([0.3])))
        tensor([0.3000])
    """
    x, v, dtype, _ = _checks.pair(_NAME + "lplus", R, tau, "R", "tau", (2, 2), (1,))
    return _checks.out(_ExpFn(v) @ x, dtype)


@_checks.float32_exact
def lminus(R1: Float[Tensor, "*b1 2 2"], R0: Float[Tensor, "*b2 2 2"]) -> Float[Tensor, "*b 1"]:
    """Left minus ``Log(R1 R0^T)``; ``lplus(R0, lminus(R1, R0)) == R1``.

    Example:
        >>> lminus(exp(torch.tensor([0.5])), exp(torch.tensor([0.2])))
        tensor([0.3000])
    """
    a, b, dtype, _ = _checks.pair(_NAME + "lminus", R1, R0, "R1", "R0", (2, 2), (2, 2))
    return _checks.out(_LogFn(a @ b.transpose(-1, -2)), dtype)


@_checks.float32_exact
def between(R0: Float[Tensor, "*b1 2 2"], R1: Float[Tensor, "*b2 2 2"]) -> Float[Tensor, "*b 2 2"]:
    """Relative rotation ``R0^T R1``.

    Example:
        >>> log(between(exp(torch.tensor([0.2])), exp(torch.tensor([0.5]))))
        tensor([0.3000])
    """
    a, b, dtype, _ = _checks.pair(_NAME + "between", R0, R1, "R0", "R1", (2, 2), (2, 2))
    return _checks.out(a.transpose(-1, -2) @ b, dtype)


# ----------------------------------------------------------------------------------------------
# Jacobians of the operations (right perturbations, as torchlie.so3)
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def jac_compose(
    R1: Float[Tensor, "*b1 2 2"], R2: Float[Tensor, "*b2 2 2"]
) -> tuple[Float[Tensor, "*b 1 1"], Float[Tensor, "*b 1 1"]]:
    """Jacobians of ``R1 R2``: ``(J_R1, J_R2) = ([[1]], [[1]])``.

    Example:
        >>> jac_compose(identity(), identity())
        (tensor([[1.]]), tensor([[1.]]))
    """
    a, _, dtype, batch = _checks.pair(_NAME + "jac_compose", R1, R2, "R1", "R2", (2, 2), (2, 2))
    return _checks.out(_ones(batch, a), dtype), _checks.out(_ones(batch, a), dtype)


@_checks.float32_exact
def jac_inverse(R: Float[Tensor, "*b 2 2"]) -> Float[Tensor, "*b 1 1"]:
    """Jacobian of ``R^T``: ``[[-1]]``.

    Example:
        >>> jac_inverse(identity())
        tensor([[-1.]])
    """
    x, dtype = _checks.tensor(R, _NAME + "jac_inverse", "R", (2, 2))
    return _checks.out(_ones(x.shape[:-2], x, -1.0), dtype)


@_checks.float32_exact
def jac_act(
    R: Float[Tensor, "*b1 2 2"], points: Float[Tensor, "*b2 2"]
) -> tuple[Float[Tensor, "*b 2 1"], Float[Tensor, "*b 2 2"]]:
    """Jacobians of ``R p``: ``(J_Rp_R, J_Rp_p) = (R hat(1) p, R)`` (``hat(1) p = (-py, px)``).

    Example:
        >>> JR, Jp = jac_act(identity(), torch.tensor([1.0, 2.0]))
        >>> JR
        tensor([[-2.],
                [ 1.]])
    """
    x, p, dtype, batch = _checks.pair(_NAME + "jac_act", R, points, "R", "points", (2, 2), (2,))
    x = x.expand(*batch, 2, 2)
    q = torch.stack((-p[..., 1], p[..., 0]), dim=-1).expand(*batch, 2)
    return _checks.out(x @ q.unsqueeze(-1), dtype), _checks.out(x.clone(), dtype)


@_checks.float32_exact
def jac_rplus(
    R: Float[Tensor, "*b1 2 2"], tau: Float[Tensor, "*b2 1"]
) -> tuple[Float[Tensor, "*b 1 1"], Float[Tensor, "*b 1 1"]]:
    """Jacobians of ``R Exp(tau)``: ``([[1]], [[1]])``.

    Example:
        >>> jac_rplus(identity(), torch.tensor([0.3]))
        (tensor([[1.]]), tensor([[1.]]))
    """
    x, _, dtype, batch = _checks.pair(_NAME + "jac_rplus", R, tau, "R", "tau", (2, 2), (1,))
    return _checks.out(_ones(batch, x), dtype), _checks.out(_ones(batch, x), dtype)


@_checks.float32_exact
def jac_rminus(
    R1: Float[Tensor, "*b1 2 2"], R0: Float[Tensor, "*b2 2 2"]
) -> tuple[Float[Tensor, "*b 1 1"], Float[Tensor, "*b 1 1"]]:
    """Jacobians of ``Log(R0^T R1)``: ``([[1]], [[-1]])``.

    Example:
        >>> jac_rminus(identity(), identity())
        (tensor([[1.]]), tensor([[-1.]]))
    """
    a, _, dtype, batch = _checks.pair(_NAME + "jac_rminus", R1, R0, "R1", "R0", (2, 2), (2, 2))
    return _checks.out(_ones(batch, a), dtype), _checks.out(_ones(batch, a, -1.0), dtype)


@_checks.float32_exact
def jac_between(
    R0: Float[Tensor, "*b1 2 2"], R1: Float[Tensor, "*b2 2 2"]
) -> tuple[Float[Tensor, "*b 1 1"], Float[Tensor, "*b 1 1"]]:
    """Jacobians of ``R0^T R1``: ``([[-1]], [[1]])``.

    Example:
        >>> jac_between(identity(), identity())
        (tensor([[-1.]]), tensor([[1.]]))
    """
    a, _, dtype, batch = _checks.pair(_NAME + "jac_between", R0, R1, "R0", "R1", (2, 2), (2, 2))
    return _checks.out(_ones(batch, a, -1.0), dtype), _checks.out(_ones(batch, a), dtype)
