"""SE(3): homogeneous poses ``(..., 4, 4)`` and twists ``(..., 6)``.

Conventions (see :mod:`torchlie`): a pose is ``T = [[R, t], [0, 1]]`` and acts on points as
``p -> R p + t``; a twist is ``xi = (rho, phi)``, translation part first, rotation vector last;
perturbations are on the right, ``T (+) d = T Exp(d)``.  Everything is built from
:mod:`torchlie.so3`: ``Exp(rho, phi) = [[Exp(phi), V(phi) rho], [0, 1]]`` with
``V = so3.jac_left``, so :func:`log` returns a rotation angle in ``[0, pi]`` with so3's rule at pi.

Jacobians (``Jl(xi)`` = :func:`jac_left`, ``Jr(xi) = Jl(-xi)`` = :func:`jac_right`)::

    Exp(xi + d) ~= Exp(xi) Exp(Jr(xi) d) ~= Exp(Jl(xi) d) Exp(xi)
    Jl(rho, phi) = [[A, Q], [0, A]],   A = so3.jac_left(phi)
    Jl(rho, phi)^-1 = [[A^-1, -A^-1 Q A^-1], [0, A^-1]]
    Q = rho^/2 + c1 (phi^ rho^ + rho^ phi^ + phi^ rho^ phi^)
               + c2 (phi^ phi^ rho^ + rho^ phi^ phi^ - 3 phi^ rho^ phi^)
               + c3 (phi^ rho^ phi^ phi^ + phi^ phi^ rho^ phi^)
    c1 = (t - sin t)/t^3,  c2 = (t^2/2 + cos t - 1)/t^4,  c3 = (2t - 3 sin t + t cos t)/(2 t^5)

(``x^`` is :func:`torchlie.so3.hat` and ``t = |phi|``; ``Q`` is Barfoot's, "State Estimation for
Robotics", eq. 7.86).  The adjoint acting on twists ``(rho, phi)`` is
``Ad_T = [[R, t^ R], [0, R]]`` and the small adjoint ``ad(rho, phi) = [[phi^, rho^], [0, phi^]]``.

Jacobians of operations follow Sola et al., "A micro Lie theory for state estimation in
robotics" (and manif): for ``Y = f(X)`` the Jacobian ``J_Y_X`` maps a right perturbation of the
input to a right perturbation of the output, ``f(X Exp(d)) ~= f(X) Exp(J_Y_X d)``; a vector
argument or result (a point, a twist) is perturbed by plain addition.
"""

from __future__ import annotations

import torch
from torch import Tensor

from . import (
    _checks,
    _coeffs,
    _components,
    _layout,
    _rotation_matrix,
    _se3_jacobian,
    _se3_kernels,
    so3,
)
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
    "from_rt",
    "to_rt",
    "from_pos_quat",
    "to_pos_quat",
    "interpolate",
    "distance",
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

_NAME = "torchlie.se3."

# ----------------------------------------------------------------------------------------------
# Component helpers (private)
# ----------------------------------------------------------------------------------------------


def _rot(T: Tensor) -> Tensor:
    return T[..., :3, :3]


def _trans(T: Tensor) -> Tensor:
    return T[..., :3, 3]


def _broadcast_rt(R: Tensor, t: Tensor) -> tuple[Tensor, Tensor]:
    batch = _layout.broadcast(R.shape[:-2], t.shape[:-1])
    return R.expand(*batch, 3, 3), t.expand(*batch, 3)


def _hat(xi: Tensor) -> Tensor:
    rho, phi = xi[..., :3], xi[..., 3:]
    top = torch.cat((_components.hat(phi), rho.unsqueeze(-1)), dim=-1)
    return torch.cat((top, torch.zeros_like(top[..., :1, :])), dim=-2)


def _adjoint(T: Tensor) -> Tensor:
    R, t = _rot(T), _trans(T)
    return _components.blocks(R, _components.hat(t) @ R, torch.zeros_like(R), R)


def _ad(xi: Tensor) -> Tensor:
    P = _components.hat(xi[..., 3:])
    return _components.blocks(P, _components.hat(xi[..., :3]), torch.zeros_like(P), P)


_between = _se3_kernels.between


# ----------------------------------------------------------------------------------------------
# hat / vee, exp / log
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def hat(xi: Float[Tensor, "*b 6"]) -> Float[Tensor, "*b 4 4"]:
    """The 4x4 matrix ``[[phi^, rho], [0, 0]]`` of the twist ``xi = (rho, phi)``.

    Example:
        >>> hat(torch.tensor([1.0, 2.0, 3.0, 4.0, 5.0, 6.0]))
        tensor([[ 0., -6.,  5.,  1.],
                [ 6.,  0., -4.,  2.],
                [-5.,  4.,  0.,  3.],
                [ 0.,  0.,  0.,  0.]])
    """
    x, dtype = _checks.tensor(xi, _NAME + "hat", "xi", (6,))
    return _checks.out(_hat(x), dtype)


@_checks.float32_exact
def vee(Xi: Float[Tensor, "*b 4 4"]) -> Float[Tensor, "*b 6"]:
    """Inverse of :func:`hat`: ``(Xi[:3, 3], so3.vee(Xi[:3, :3]))`` (skew part of the block).

    The bottom row is ignored.

    Example:
        >>> vee(hat(torch.tensor([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])))
        tensor([1., 2., 3., 4., 5., 6.])
    """
    x, dtype = _checks.tensor(Xi, _NAME + "vee", "Xi", (4, 4))
    return _checks.out(torch.cat((_trans(x), _components.vee(_rot(x))), dim=-1), dtype)


@_checks.float32_exact
def exp(xi: Float[Tensor, "*b 6"]) -> Float[Tensor, "*b 4 4"]:
    """Pose of the twist ``xi = (rho, phi)``: ``[[so3.exp(phi), so3.jac_left(phi) rho], [0, 1]]``.

    Exact to a few ulp as :func:`torchlie.so3.exp` (one set of half-angle coefficients for both
    blocks, no cancellation at 0 or near pi).  The backward pass is closed-form,
    ``g_rho = Jr(phi) g_t`` and
    ``g_phi = Jl(phi) vee(R^T G_R - G_R^T R) + Jr(phi)(t x g_t) + Q(-rho, -phi) g_t``, with
    series-safe coefficients, so every derivative is finite, at 0 and pi included; double
    backward and forward mode are supported.

    Example:
        >>> T = exp(torch.tensor([1.0, 0.0, 0.0, 0.0, 0.0, torch.pi / 2]))
        >>> T[:3, 3]  # quarter turn about z while moving along x: (2/pi, 2/pi, 0)
        tensor([0.6366, 0.6366, 0.0000])
    """
    x, dtype = _checks.tensor(xi, _NAME + "exp", "xi", (6,))
    return _checks.out(_se3_kernels.exp(x), dtype)


@_checks.float32_exact
def log(T: Float[Tensor, "*b 4 4"]) -> Float[Tensor, "*b 6"]:
    """Twist ``(rho, phi)`` of ``T``: ``phi = so3.log(R)``, ``rho = so3.jac_left(phi)^-1 t``.

    The rotation angle ``|phi|`` is in ``[0, pi]``; at exactly pi the axis sign follows
    :func:`torchlie.so3.log`'s canonical rule (and ``rho`` is the one that matches that axis).
    The bottom row of ``T`` is not read.

    Gradient meaning: the backward pass is the gradient of ``log`` composed with the projection
    of the rotation block onto SO(3) (as :func:`torchlie.so3.log`): along the tangent directions
    ``T hat(d)`` it is the exact derivative ``Jr(xi)^-1 d``; the translation block's gradient is
    exact (``d rho / d t = so3.jac_left(phi)^-1``); directions that leave SO(3) in the rotation
    block (``R S``, ``S`` symmetric) and the bottom row get zero gradient.  It is finite at
    ``theta = pi``.  The forward pass agrees with it to first order (as so3's), so plain
    ``gradcheck`` on a raw pose matrix passes.  Double backward and forward
    mode are supported.

    The rotation block must be a rotation up to first-order deviations; other matrices give an
    unspecified result (see "Matrices off SO(3)" in :mod:`torchlie.so3`).

    Example:
        >>> T = exp(torch.tensor([1.0, 2.0, 3.0, 0.1, 0.2, 0.3]))
        >>> log(T)
        tensor([1.0000, 2.0000, 3.0000, 0.1000, 0.2000, 0.3000])
    """
    x, dtype = _checks.tensor(T, _NAME + "log", "T", (4, 4))
    return _checks.out(_se3_kernels.log(x), dtype)


# ----------------------------------------------------------------------------------------------
# Group operations
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def compose(T1: Float[Tensor, "*b1 4 4"], T2: Float[Tensor, "*b2 4 4"]) -> Float[Tensor, "*b 4 4"]:
    """``T1 @ T2`` from blocks (``R1 R2``, ``R1 t2 + t1``); batch shapes broadcast.

    The bottom rows of the inputs are not read; the result's is exactly ``(0, 0, 0, 1)``.

    Example:
        >>> T = exp(torch.tensor([1.0, 0.0, 0.0, 0.0, 0.0, 0.5]))
        >>> torch.allclose(compose(T, T), exp(torch.tensor([2.0, 0.0, 0.0, 0.0, 0.0, 1.0])))
        True
    """
    a, b, dtype, _ = _checks.pair(_NAME + "compose", T1, T2, "T1", "T2", (4, 4), (4, 4))
    return _checks.out(_se3_kernels.compose(a, b), dtype)


@_checks.float32_exact
def inverse(T: Float[Tensor, "*b 4 4"]) -> Float[Tensor, "*b 4 4"]:
    """``T^-1 = [[R^T, -R^T t], [0, 1]]``.

    Example:
        >>> T = exp(torch.tensor([1.0, 2.0, 3.0, 0.1, 0.2, 0.3]))
        >>> torch.allclose(compose(inverse(T), T), torch.eye(4), atol=1e-6)
        True
    """
    x, dtype = _checks.tensor(T, _NAME + "inverse", "T", (4, 4))
    return _checks.out(_se3_kernels.inverse(x), dtype)


@_checks.float32_exact
def act(T: Float[Tensor, "*b1 4 4"], points: Float[Tensor, "*b2 3"]) -> Float[Tensor, "*b 3"]:
    """Transform points: ``R p + t`` (batch shapes broadcast).

    Example:
        >>> T = from_rt(so3.exp(torch.tensor([0.0, 0.0, torch.pi])), torch.tensor([1.0, 2.0, 3.0]))
        >>> act(T, torch.tensor([1.0, 0.0, 0.0])).round(decimals=6)
        tensor([0., 2., 3.])
    """
    x, p, dtype, _ = _checks.pair(_NAME + "act", T, points, "T", "points", (4, 4), (3,))
    return _checks.out(_se3_kernels.act(x, p), dtype)


@_checks.float32_exact
def adjoint(T: Float[Tensor, "*b 4 4"]) -> Float[Tensor, "*b 6 6"]:
    """Adjoint matrix ``Ad_T = [[R, t^ R], [0, R]]`` on twists ``(rho, phi)``.

    ``T Exp(xi) T^-1 = Exp(Ad_T xi)``.

    Example:
        >>> T = from_rt(torch.eye(3), torch.tensor([1.0, 0.0, 0.0]))
        >>> adjoint(T)[1:3, 4:]
        tensor([[ 0., -1.],
                [ 1.,  0.]])
    """
    x, dtype = _checks.tensor(T, _NAME + "adjoint", "T", (4, 4))
    return _checks.out(_adjoint(x), dtype)


@_checks.float32_exact
def ad(xi: Float[Tensor, "*b 6"]) -> Float[Tensor, "*b 6 6"]:
    """Small adjoint ``ad(rho, phi) = [[phi^, rho^], [0, phi^]]``.

    ``ad(x) y`` is the Lie bracket ``vee(hat(x) hat(y) - hat(y) hat(x))`` and
    ``adjoint(exp(x)) = matrix_exp(ad(x))``.

    Example:
        >>> ad(torch.tensor([1.0, 2.0, 3.0, 4.0, 5.0, 6.0]))
        tensor([[ 0., -6.,  5.,  0., -3.,  2.],
                [ 6.,  0., -4.,  3.,  0., -1.],
                [-5.,  4.,  0., -2.,  1.,  0.],
                [ 0.,  0.,  0.,  0., -6.,  5.],
                [ 0.,  0.,  0.,  6.,  0., -4.],
                [ 0.,  0.,  0., -5.,  4.,  0.]])
    """
    x, dtype = _checks.tensor(xi, _NAME + "ad", "xi", (6,))
    return _checks.out(_ad(x), dtype)


def _jac(fn: str, xi: Tensor, inv: bool, sign: float) -> Tensor:
    x, dtype = _checks.tensor(xi, _NAME + fn, "xi", (6,))
    x = x if sign > 0 else -x
    return _checks.out(_se3_jacobian.jac_left_inv(x) if inv else _se3_jacobian.jac_left(x), dtype)


@_checks.float32_exact
def jac_left(xi: Float[Tensor, "*b 6"]) -> Float[Tensor, "*b 6 6"]:
    """Left Jacobian ``Jl(xi) = [[A, Q], [0, A]]`` (``A = so3.jac_left(phi)``, ``Q`` Barfoot's).

    ``Exp(xi + d) ~= Exp(Jl(xi) d) Exp(xi)``; the translation of ``Exp(xi)`` is ``A rho``.

    Example:
        >>> torch.equal(jac_left(torch.zeros(6)), torch.eye(6))
        True
    """
    return _jac("jac_left", xi, False, 1.0)


@_checks.float32_exact
def jac_right(xi: Float[Tensor, "*b 6"]) -> Float[Tensor, "*b 6 6"]:
    """Right Jacobian ``Jr(xi) = Jl(-xi)``; ``Exp(xi + d) ~= Exp(xi) Exp(Jr(xi) d)``.

    It is also the Jacobian ``J_Exp(xi)_xi`` of :func:`exp` (right perturbation of the result).

    Example:
        >>> xi = torch.tensor([1.0, 2.0, 3.0, 0.1, 0.2, 0.3])
        >>> torch.allclose(jac_left(xi), adjoint(exp(xi)) @ jac_right(xi), atol=1e-6)
        True
    """
    return _jac("jac_right", xi, False, -1.0)


@_checks.float32_exact
def jac_left_inv(xi: Float[Tensor, "*b 6"]) -> Float[Tensor, "*b 6 6"]:
    """``Jl(xi)^-1 = [[A^-1, -A^-1 Q A^-1], [0, A^-1]]``, closed form, finite for ``|phi| < 2 pi``.

    Example:
        >>> xi = torch.tensor([1.0, 2.0, 3.0, 0.1, 0.2, 0.3])
        >>> torch.allclose(jac_left_inv(xi) @ jac_left(xi), torch.eye(6), atol=1e-6)
        True
    """
    return _jac("jac_left_inv", xi, True, 1.0)


@_checks.float32_exact
def jac_right_inv(xi: Float[Tensor, "*b 6"]) -> Float[Tensor, "*b 6 6"]:
    """``Jr(xi)^-1 = Jl(-xi)^-1``; ``jac_right_inv(log(T))`` is the Jacobian ``J_Log(T)_T``.

    Example:
        >>> xi = torch.tensor([1.0, 2.0, 3.0, 0.1, 0.2, 0.3])
        >>> torch.allclose(jac_right_inv(xi) @ jac_right(xi), torch.eye(6), atol=1e-6)
        True
    """
    return _jac("jac_right_inv", xi, True, -1.0)


# ----------------------------------------------------------------------------------------------
# Construction, validation, conversions
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def identity(
    *batch: int, dtype: torch.dtype | None = None, device: torch.device | str | None = None
) -> Float[Tensor, "*batch 4 4"]:
    """Identity poses of shape ``(*batch, 4, 4)``.

    Example:
        >>> identity(2).shape
        torch.Size([2, 4, 4])
    """
    _, dtype = _checks.factory(_NAME + "identity", batch, dtype)
    return torch.eye(4, dtype=dtype, device=device).expand(*batch, 4, 4).clone()


@_checks.float32_exact
def random(
    *batch: int,
    generator: torch.Generator | None = None,
    dtype: torch.dtype | None = None,
    device: torch.device | str | None = None,
) -> Float[Tensor, "*batch 4 4"]:
    """Random poses: Haar-uniform rotations (:func:`torchlie.so3.random`), translations ``N(0, I)``.

    float16/bfloat16 are drawn and computed in float32, then cast.

    Example:
        >>> T = random(4, generator=torch.Generator().manual_seed(0))
        >>> bool(is_valid(T).all())
        True
    """
    compute, dtype = _checks.factory(_NAME + "random", batch, dtype)
    R = so3.random(*batch, generator=generator, dtype=compute, device=device)
    t = torch.randn(*batch, 3, generator=generator, dtype=compute, device=device)
    return _checks.out(_components.homogeneous(R, t), dtype)


@_checks.float32_exact
def is_valid(T: Float[Tensor, "*b 4 4"], atol: float | None = None) -> Bool[Tensor, "*b"]:
    """Per element: finite, rotation block valid (:func:`torchlie.so3.is_valid`) and bottom row
    ``(0, 0, 0, 1)``, each within ``atol`` (a non-negative finite real number; default
    ``100 * eps`` of the input dtype, ``4 * eps`` for half).

    Example:
        >>> bad = identity()
        >>> bad[3, 0] = 1.0
        >>> is_valid(torch.stack((identity(), bad)))
        tensor([ True, False])
    """
    x, _ = _checks.tensor(T, _NAME + "is_valid", "T", (4, 4))
    tol = _checks.tolerance(atol, _NAME + "is_valid", "atol", T.dtype)
    last = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=x.dtype, device=x.device)
    bottom = (x[..., 3, :] - last).abs().amax(dim=-1) <= tol
    return so3.is_valid(_rot(x), atol=tol) & bottom & torch.isfinite(_trans(x)).all(dim=-1)


@_checks.float32_exact
def from_rt(R: Float[Tensor, "*b1 3 3"], t: Float[Tensor, "*b2 3"]) -> Float[Tensor, "*b 4 4"]:
    """Pose ``[[R, t], [0, 1]]`` from a rotation matrix and a translation (batches broadcast).

    Example:
        >>> from_rt(torch.eye(3), torch.tensor([1.0, 2.0, 3.0]))
        tensor([[1., 0., 0., 1.],
                [0., 1., 0., 2.],
                [0., 0., 1., 3.],
                [0., 0., 0., 1.]])
    """
    r, v, dtype, _ = _checks.pair(_NAME + "from_rt", R, t, "R", "t", (3, 3), (3,))
    return _checks.out(_components.homogeneous(*_broadcast_rt(r, v)), dtype)


@_checks.float32_exact
def to_rt(T: Float[Tensor, "*b 4 4"]) -> tuple[Float[Tensor, "*b 3 3"], Float[Tensor, "*b 3"]]:
    """Rotation block and translation ``(R, t)`` of ``T`` (copies, not views).

    Example:
        >>> R, t = to_rt(from_rt(torch.eye(3), torch.tensor([1.0, 2.0, 3.0])))
        >>> t
        tensor([1., 2., 3.])
    """
    _checks.tensor(T, _NAME + "to_rt", "T", (4, 4))
    return T[..., :3, :3].clone(), T[..., :3, 3].clone()


@_checks.float32_exact
def from_pos_quat(x: Float[Tensor, "*b 7"]) -> Float[Tensor, "*b 4 4"]:
    """Pose from a 7-vector ``(tx, ty, tz, qw, qx, qy, qz)``: translation, then a wxyz quaternion.

    The quaternion need not be unit (the rotation of ``q / |q|`` is used, as
    :func:`torchlie.quaternion.to_matrix`).  A zero quaternion has no rotation: that
    element's rotation block is NaN (as :func:`torchlie.quaternion.to_matrix` of it), while its
    translation column is as given and its bottom row ``(0, 0, 0, 1)``: each block depends
    only on its own part of ``x``, and so does the gradient (finite for the translation, NaN
    for the zero quaternion).  The other elements of the batch are unaffected.

    Example:
        >>> from_pos_quat(torch.tensor([1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0]))
        tensor([[-1.,  0.,  0.,  1.],
                [ 0., -1.,  0.,  2.],
                [ 0.,  0.,  1.,  3.],
                [ 0.,  0.,  0.,  1.]])
    """
    v, dtype = _checks.tensor(x, _NAME + "from_pos_quat", "x", (7,))
    return _checks.out(
        _components.homogeneous(_rotation_matrix.from_quaternion(v[..., 3:]), v[..., :3]), dtype
    )


@_checks.float32_exact
def to_pos_quat(T: Float[Tensor, "*b 4 4"]) -> Float[Tensor, "*b 7"]:
    """7-vector ``(t, q)`` of a pose: translation, then the canonical wxyz unit quaternion.

    The quaternion is :func:`torchlie.quaternion.from_matrix` of the rotation block (``w >= 0``).

    Example:
        >>> to_pos_quat(from_pos_quat(torch.tensor([1.0, 2.0, 3.0, 0.0, 1.0, 0.0, 0.0])))
        tensor([1., 2., 3., 0., 1., 0., 0.])
    """
    x, dtype = _checks.tensor(T, _NAME + "to_pos_quat", "T", (4, 4))
    q = _rotation_matrix.to_quaternion(_rot(x))
    return _checks.out(torch.cat((_trans(x), q), dim=-1), dtype)


# ----------------------------------------------------------------------------------------------
# Metrics and interpolation
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def interpolate(
    T0: Float[Tensor, "*b1 4 4"], T1: Float[Tensor, "*b2 4 4"], t: Float[Tensor, "*b3"] | float
) -> Float[Tensor, "*b 4 4"]:
    """Geodesic interpolation ``T0 Exp(t Log(T0^-1 T1))`` (``t`` broadcasts with the batch).

    ``t = 0`` gives ``T0`` and ``t = 1`` gives ``T1``; the path is a screw motion (rotation and
    translation coupled), not separate slerp + lerp.  Other ``t`` extrapolate.  ``t`` is a
    tensor of the dtype of ``T0`` or numbers (a float, numpy scalar or array, or a list),
    converted to it; not a bool.

    Example:
        >>> T1 = exp(torch.tensor([2.0, 0.0, 0.0, 0.0, 0.0, 1.0]))
        >>> mid = exp(torch.tensor([1.0, 0.0, 0.0, 0.0, 0.0, 0.5]))
        >>> torch.allclose(interpolate(identity(), T1, 0.5), mid, atol=1e-6)
        True
    """
    fn = _NAME + "interpolate"
    a, b, dtype, _ = _checks.pair(_NAME + "interpolate", T0, T1, "T0", "T1", (4, 4), (4, 4))
    t = _checks.real(t, fn, "t", a, ("T0", T0))
    _checks.batch_broadcast(fn, (a.shape[:-2], "T0"), (b.shape[:-2], "T1"), (t.shape, "t"))
    xi = _se3_kernels.log(_between(a, b))
    return _checks.out(_se3_kernels.compose(a, _se3_kernels.exp(t.unsqueeze(-1) * xi)), dtype)


@_checks.float32_exact
def distance(
    T1: Float[Tensor, "*b1 4 4"], T2: Float[Tensor, "*b2 4 4"]
) -> tuple[Float[Tensor, "*b"], Float[Tensor, "*b"]]:
    """Rotation angle and translation length of the relative pose ``T1^-1 T2``.

    Returns a pair ``(angle, translation)``: the rotation angle of ``R1^T R2`` in ``[0, pi]`` (as
    :func:`torchlie.so3.distance`) and ``|R1^T (t2 - t1)| = |t2 - t1|``.  Both are measured in
    their own units, so no weighting is imposed; both have the zero subgradient where they are
    not differentiable (angle 0 or pi, equal translations), so gradients are always finite.

    Example:
        >>> T2 = from_rt(so3.exp(torch.tensor([0.0, 0.3, 0.0])), torch.tensor([3.0, 4.0, 0.0]))
        >>> distance(identity(), T2)
        (tensor(0.3000), tensor(5.))
    """
    a, b, dtype, _ = _checks.pair(_NAME + "distance", T1, T2, "T1", "T2", (4, 4), (4, 4))
    angle = _rotation_matrix.angle(_rot(a).transpose(-1, -2) @ _rot(b))
    trans = _coeffs.norm(_trans(b) - _trans(a))
    trans = trans.expand(angle.shape)
    return _checks.out(angle, dtype), _checks.out(trans, dtype)


# ----------------------------------------------------------------------------------------------
# Lie-group operations and their Jacobians
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def rplus(T: Float[Tensor, "*b1 4 4"], xi: Float[Tensor, "*b2 6"]) -> Float[Tensor, "*b 4 4"]:
    """Right plus ``T (+) xi = T Exp(xi)`` (batch shapes broadcast).

    Example:
        >>> xi = torch.tensor([1.0, 0.0, 0.0, 0.0, 0.0, 0.0])
        >>> rplus(identity(), xi)[:3, 3]
        tensor([1., 0., 0.])
    """
    x, v, dtype, _ = _checks.pair(_NAME + "rplus", T, xi, "T", "xi", (4, 4), (6,))
    return _checks.out(_se3_kernels.compose(x, _se3_kernels.exp(v)), dtype)


@_checks.float32_exact
def rminus(T1: Float[Tensor, "*b1 4 4"], T0: Float[Tensor, "*b2 4 4"]) -> Float[Tensor, "*b 6"]:
    """Right minus ``T1 (-) T0 = Log(T0^-1 T1)``, so that ``rplus(T0, rminus(T1, T0)) == T1``;
    exactly 0 where ``T1 == T0``.

    Example:
        >>> xi = torch.tensor([1.0, 2.0, 3.0, 0.1, 0.2, 0.3])
        >>> T0 = exp(torch.tensor([0.5, 0.0, 0.0, 0.0, 1.0, 0.0]))
        >>> torch.allclose(rminus(rplus(T0, xi), T0), xi, atol=1e-5)
        True
    """
    a, b, dtype, _ = _checks.pair(_NAME + "rminus", T1, T0, "T1", "T0", (4, 4), (4, 4))
    return _checks.out(_se3_kernels.log(_between(b, a)), dtype)


@_checks.float32_exact
def lplus(T: Float[Tensor, "*b1 4 4"], xi: Float[Tensor, "*b2 6"]) -> Float[Tensor, "*b 4 4"]:
    """Left plus ``Exp(xi) T`` (the perturbation is expressed in the world frame).

    Example:
        >>> T = from_rt(torch.eye(3), torch.tensor([1.0, 0.0, 0.0]))
        >>> xi = torch.tensor([0.0, 0.0, 0.0, 0.0, 0.0, torch.pi / 2])
        >>> torch.allclose(lplus(T, xi)[:3, 3], torch.tensor([0.0, 1.0, 0.0]), atol=1e-6)
        True
    """
    x, v, dtype, _ = _checks.pair(_NAME + "lplus", T, xi, "T", "xi", (4, 4), (6,))
    return _checks.out(_se3_kernels.compose(_se3_kernels.exp(v), x), dtype)


@_checks.float32_exact
def lminus(T1: Float[Tensor, "*b1 4 4"], T0: Float[Tensor, "*b2 4 4"]) -> Float[Tensor, "*b 6"]:
    """Left minus ``Log(T1 T0^-1)``, so that ``lplus(T0, lminus(T1, T0)) == T1``; exactly 0
    where ``T1 == T0`` (the translation of ``T1 T0^-1`` is taken as ``R1 (R1^T t1 - R0^T t0)``).

    Example:
        >>> xi = torch.tensor([1.0, 2.0, 3.0, 0.1, 0.2, 0.3])
        >>> T0 = exp(torch.tensor([0.5, 0.0, 0.0, 0.0, 1.0, 0.0]))
        >>> torch.allclose(lminus(lplus(T0, xi), T0), xi, atol=1e-5)
        True
    """
    a, b, dtype, _ = _checks.pair(_NAME + "lminus", T1, T0, "T1", "T0", (4, 4), (4, 4))
    return _checks.out(_se3_kernels.log(_se3_kernels.right_between(a, b)), dtype)


@_checks.float32_exact
def between(T0: Float[Tensor, "*b1 4 4"], T1: Float[Tensor, "*b2 4 4"]) -> Float[Tensor, "*b 4 4"]:
    """Relative pose ``T0^-1 T1`` (``T1`` expressed in the frame of ``T0``).

    Example:
        >>> T0 = from_rt(torch.eye(3), torch.tensor([1.0, 0.0, 0.0]))
        >>> T1 = from_rt(torch.eye(3), torch.tensor([1.0, 2.0, 0.0]))
        >>> between(T0, T1)[:3, 3]
        tensor([0., 2., 0.])
    """
    a, b, dtype, _ = _checks.pair(_NAME + "between", T0, T1, "T0", "T1", (4, 4), (4, 4))
    return _checks.out(_between(a, b), dtype)


def _eye6(batch: torch.Size, like: Tensor) -> Tensor:
    return torch.eye(6, dtype=like.dtype, device=like.device).expand(*batch, 6, 6).clone()


@_checks.float32_exact
def jac_compose(
    T1: Float[Tensor, "*b1 4 4"], T2: Float[Tensor, "*b2 4 4"]
) -> tuple[Float[Tensor, "*b 6 6"], Float[Tensor, "*b 6 6"]]:
    """Jacobians of ``T1 T2``: ``(J_T1T2_T1, J_T1T2_T2) = (Ad(T2)^-1, I)``.

    Right perturbations throughout: ``(T1 Exp(d1)) (T2 Exp(d2)) ~= T1 T2 Exp(J1 d1 + J2 d2)``.

    Example:
        >>> T2 = exp(torch.tensor([1.0, 2.0, 3.0, 0.1, 0.2, 0.3]))
        >>> J1, J2 = jac_compose(identity(), T2)
        >>> torch.allclose(J1, adjoint(inverse(T2))) and torch.equal(J2, torch.eye(6))
        True
    """
    a, b, dtype, batch = _checks.pair(_NAME + "jac_compose", T1, T2, "T1", "T2", (4, 4), (4, 4))
    J1 = _adjoint(_se3_kernels.inverse(b)).expand(*batch, 6, 6).clone()
    return _checks.out(J1, dtype), _checks.out(_eye6(batch, a), dtype)


@_checks.float32_exact
def jac_inverse(T: Float[Tensor, "*b 4 4"]) -> Float[Tensor, "*b 6 6"]:
    """Jacobian ``J_Tinv_T = -Ad(T)``: ``(T Exp(d))^-1 = T^-1 Exp(-Ad(T) d)``.

    Example:
        >>> torch.equal(jac_inverse(identity()), -torch.eye(6))
        True
    """
    x, dtype = _checks.tensor(T, _NAME + "jac_inverse", "T", (4, 4))
    return _checks.out(-_adjoint(x), dtype)


@_checks.float32_exact
def jac_act(
    T: Float[Tensor, "*b1 4 4"], points: Float[Tensor, "*b2 3"]
) -> tuple[Float[Tensor, "*b 3 6"], Float[Tensor, "*b 3 3"]]:
    """Jacobians of ``T p``: ``(J_Tp_T, J_Tp_p) = ([R, -R p^], R)``.

    ``T Exp(d) (p + dp) ~= T p + J_Tp_T d + J_Tp_p dp`` (the point is perturbed additively).

    Example:
        >>> p = torch.tensor([1.0, 2.0, 3.0])
        >>> JT, Jp = jac_act(identity(), p)
        >>> torch.equal(JT, torch.cat((torch.eye(3), -so3.hat(p)), dim=-1))
        True
    """
    x, p, dtype, batch = _checks.pair(_NAME + "jac_act", T, points, "T", "points", (4, 4), (3,))
    R = _rot(x).expand(*batch, 3, 3)
    JT = torch.cat((R, -(R @ _components.hat(p))), dim=-1)
    return _checks.out(JT, dtype), _checks.out(R.clone(), dtype)


@_checks.float32_exact
def jac_rplus(
    T: Float[Tensor, "*b1 4 4"], xi: Float[Tensor, "*b2 6"]
) -> tuple[Float[Tensor, "*b 6 6"], Float[Tensor, "*b 6 6"]]:
    """Jacobians of ``T Exp(xi)``: ``(J_T, J_xi) = (Ad(Exp(xi))^-1, Jr(xi))``.

    Example:
        >>> JT, Jxi = jac_rplus(identity(), torch.zeros(6))
        >>> torch.equal(JT, torch.eye(6)) and torch.equal(Jxi, torch.eye(6))
        True
    """
    x, v, dtype, batch = _checks.pair(_NAME + "jac_rplus", T, xi, "T", "xi", (4, 4), (6,))
    v = v.expand(*batch, 6)
    JT = _adjoint(_se3_kernels.exp(-v))
    return _checks.out(JT, dtype), _checks.out(_se3_jacobian.jac_left(-v), dtype)


@_checks.float32_exact
def jac_rminus(
    T1: Float[Tensor, "*b1 4 4"], T0: Float[Tensor, "*b2 4 4"]
) -> tuple[Float[Tensor, "*b 6 6"], Float[Tensor, "*b 6 6"]]:
    """Jacobians of ``xi = Log(T0^-1 T1)``: ``(J_xi_T1, J_xi_T0) = (Jr(xi)^-1, -Jl(xi)^-1)``.

    Example:
        >>> J1, J0 = jac_rminus(identity(), identity())
        >>> torch.equal(J1, torch.eye(6)) and torch.equal(J0, -torch.eye(6))
        True
    """
    a, b, dtype, _ = _checks.pair(_NAME + "jac_rminus", T1, T0, "T1", "T0", (4, 4), (4, 4))
    xi = _se3_kernels.log(_between(b, a))
    J1, J0 = _se3_jacobian.jac_left_inv(-xi), -_se3_jacobian.jac_left_inv(xi)
    return _checks.out(J1, dtype), _checks.out(J0, dtype)


@_checks.float32_exact
def jac_between(
    T0: Float[Tensor, "*b1 4 4"], T1: Float[Tensor, "*b2 4 4"]
) -> tuple[Float[Tensor, "*b 6 6"], Float[Tensor, "*b 6 6"]]:
    """Jacobians of ``T0^-1 T1``: ``(J_T0, J_T1) = (-Ad(T1^-1 T0), I)``.

    Example:
        >>> J0, J1 = jac_between(identity(), identity())
        >>> torch.equal(J0, -torch.eye(6)) and torch.equal(J1, torch.eye(6))
        True
    """
    a, b, dtype, batch = _checks.pair(_NAME + "jac_between", T0, T1, "T0", "T1", (4, 4), (4, 4))
    J0 = -_adjoint(_between(b, a))
    return _checks.out(J0, dtype), _checks.out(_eye6(batch, a), dtype)
