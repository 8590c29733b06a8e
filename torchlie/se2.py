"""SE(2): planar poses ``(..., 3, 3)`` and twists ``(..., 3)``.

Conventions (see :mod:`torchlie`): a pose is ``T = [[R, t], [0, 1]]`` (``R`` in SO(2)) and acts
on points as ``p -> R p + t``; a twist is ``xi = (rho_x, rho_y, theta)``, translation part
first, ``hat(xi) = [[0, -theta, rho_x], [theta, 0, rho_y], [0, 0, 0]]``; perturbations are on
the right, ``T (+) d = T Exp(d)``.  :func:`log` returns ``theta`` in ``(-pi, pi]`` (as
:func:`torchlie.so2.log`).

Formulas (``a = sin t / t``, ``b = (1 - cos t)/t``, ``c1 = (t - sin t)/t^2``,
``c2 = (1 - cos t)/t^2``, ``e = (t/2) cot(t/2)``, all from :mod:`torchlie._coeffs`)::

    Exp(rho, t) = [[R(t), V rho], [0, 1]],   V = [[a, -b], [b, a]],   V^-1 = [[e, t/2], [-t/2, e]]
    Jl(rho, t) = [[a, -b, c1 rho_x + c2 rho_y],
                  [b,  a, c1 rho_y - c2 rho_x],
                  [0,  0, 1]]
    Jr(xi) = Jl(-xi),   Jl^-1 = [[V^-1, -V^-1 q], [0, 1]]  (q the last column of Jl, top)
    Ad_T = [[R, (t_y, -t_x)^T], [0, 1]],   ad(xi) = [[0, -t, rho_y], [t, 0, -rho_x], [0, 0, 0]]

Jacobians of operations follow Sola et al. (and manif), as in :mod:`torchlie.se3`: ``J_Y_X``
maps a right perturbation of the input to one of the output; points are perturbed additively.
"""

from __future__ import annotations

import torch
from torch import Tensor

from . import _checks, _coeffs, _components, _layout, so2
from ._autograd import CustomFunction, blocked, fma
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
    "from_xytheta",
    "to_xytheta",
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

_NAME = "torchlie.se2."


# ----------------------------------------------------------------------------------------------
# Formulas on components
# ----------------------------------------------------------------------------------------------


def _pose(c: Tensor, s: Tensor, tx: Tensor, ty: Tensor) -> Tensor:
    """``[[c, -s, tx], [s, c, ty], [0, 0, 1]]`` of planes."""
    z = torch.zeros_like(c)
    return torch.stack((c, -s, tx, s, c, ty, z, z, z + 1.0), dim=-1).unflatten(-1, (3, 3))


def _coefficients(t: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """``(a, b, c1, c2)`` of the module docstring: differentiable to every order where autograd
    records (double backward), forward-only in a plain backward pass (the same values)."""
    if torch.is_grad_enabled():
        return _coeffs.planar(t)
    return _coeffs.planar_values(t)[:4]


def _vinv(t: Tensor) -> tuple[Tensor, Tensor]:
    """``(e, de/dt)``: ``e = (t/2) cot(t/2) = cos(t/2) / sinc(t/2)`` and
    ``e' = -t sinc3(t^2) / sinc(t/2)^2 = -c1 / sinc(t/2)^2``, differentiable to every order
    where autograd records (float32 in float64, as :func:`torchlie._coeffs.planar`),
    forward-only otherwise."""
    if torch.is_grad_enabled():
        w = _coeffs.wide(t)
        h2 = 0.25 * w * w
        r = _coeffs.sinc(h2)
        e, de = _coeffs.cos_sqrt(h2) / r, -w * _coeffs.sinc3(w * w) / (r * r)
        return e.to(t.dtype), de.to(t.dtype)
    _, _, c1, _, r, ch = _coeffs.planar_values(t)
    return ch / r, -c1 / (r * r)


def _jl(x: Tensor, y: Tensor, t: Tensor) -> tuple[Tensor, ...]:
    """Entries ``(a, b, q1, q2)`` of ``Jl(x, y, t) = [[a, -b, q1], [b, a, q2], [0, 0, 1]]``."""
    a, b, c1, c2 = _coefficients(t)
    return a, b, c1 * x + c2 * y, c1 * y - c2 * x


def _exp(xi: Tensor) -> Tensor:
    # half-angle forms (as so3.exp): h = t/2, r = sin(h)/h, R = [[c, -s], [s, c]] with
    # c = (cos h - sin h)(cos h + sin h), s = 2 sin h cos h; a = r cos h, b = r sin h
    x, y, t = _layout.planes(xi, 3)
    o = so2.columns(t, 9)
    h = 0.5 * t
    sh, ch = torch.sin(h), torch.cos(h)
    zero = h == 0
    r = torch.where(zero, 1.0, sh / torch.where(zero, 1.0, h))
    a, b = r * ch, r * sh
    c = torch.mul(ch - sh, ch + sh, out=o[0])
    s = torch.mul(2.0 * sh, ch, out=o[3])
    tx = torch.sub(a * x, b * y, out=o[2])
    ty = torch.add(b * x, a * y, out=o[5])
    parts = (c, torch.neg(s, out=o[1]), tx, s, c, ty, 0.0, 0.0, 1.0)
    return so2.assemble(parts, o).unflatten(-1, (3, 3))


def _exp_backward(saved: tuple[Tensor, ...], g: Tensor) -> tuple[Tensor]:
    # dL/dxi = Jr(xi)^T gamma, gamma = (R^T g_t, <G_R, R hat(1)>)
    xi, T = saved
    c, s = T[..., 0, 0], T[..., 1, 0]
    gx, gy = g[..., 0, 2], g[..., 1, 2]
    u, v = c * gx + s * gy, c * gy - s * gx
    w = c * (g[..., 1, 0] - g[..., 0, 1]) - s * (g[..., 0, 0] + g[..., 1, 1])
    a, b, q1, q2 = _jl(*(-xi).unbind(-1))  # Jr(xi) = Jl(-xi)
    return (torch.stack((a * u + b * v, a * v - b * u, q1 * u + q2 * v + w), dim=-1),)


def _exp_jvp(saved: tuple[Tensor, ...], d: Tensor) -> Tensor:
    # dT = T hat(Jr(xi) d)
    xi, T = saved
    c, s = T[..., 0, 0], T[..., 1, 0]
    a, b, q1, q2 = _jl(*(-xi).unbind(-1))
    dx, dy, dt = d.unbind(-1)
    u, v = a * dx - b * dy + q1 * dt, b * dx + a * dy + q2 * dt
    z = torch.zeros_like(c)
    rows = (-s * dt, -c * dt, c * u - s * v, c * dt, -s * dt, s * u + c * v, z, z, z)
    return torch.stack(rows, dim=-1).unflatten(-1, (3, 3))


# one pass over blocks of the batch (the one driver), the backward's planes kept in cache
_exp_backward_blocked = blocked(lambda *t: _exp_backward(t[:-1], t[-1]), (1, 2, 2))

_ExpFn = CustomFunction(
    "Se2Exp",
    forward=_exp,
    save=lambda inputs, out: (inputs[0], out),
    backward=lambda saved, g: _exp_backward_blocked(*saved, g),
    jvp=_exp_jvp,
    event_dims=(1,),
)


def _log(T: Tensor) -> Tensor:
    x, y = so2.conformal(T[..., :2, :2])
    tx, ty = T[..., 0, 2], T[..., 1, 2]
    o = so2.columns(x, 3)
    t = so2.angle(x, y)
    h = 0.5 * t
    zero = h == 0
    e = torch.cos(h) * torch.where(zero, 1.0, h / torch.where(zero, 1.0, torch.sin(h)))
    rx = torch.add(e * tx, h * ty, out=o[0])
    ry = torch.sub(e * ty, h * tx, out=o[1])
    return so2.assemble((rx, ry, t), o)


def _log_parts(T: Tensor, xi: Tensor):
    t = xi[..., 2]
    tx, ty = T[..., 0, 2], T[..., 1, 2]
    e, de = _vinv(t)
    return t, tx, ty, e, de


def _log_backward(saved: tuple[Tensor, ...], g: Tensor) -> tuple[Tensor]:
    T, xi = saved
    t, tx, ty, e, de = _log_parts(T, xi)
    h = 0.5 * t
    gx, gy, gt = g.unbind(-1)
    gt = gt + gx * (de * tx + 0.5 * ty) + gy * (de * ty - 0.5 * tx)
    # rotation block: so2.log's backward with the angle's gradient gt; bottom row 0
    u, v = so2.angle_gradient(*so2.conformal(T[..., :2, :2]), 0.5 * gt)
    o = so2.columns(u, 9)
    parts = (u, -v, e * gx - h * gy, v, u, h * gx + e * gy, 0.0, 0.0, 0.0)
    return (so2.assemble(parts, o).unflatten(-1, (3, 3)),)


def _log_jvp(saved: tuple[Tensor, ...], dT: Tensor) -> Tensor:
    T, xi = saved
    t, tx, ty, e, de = _log_parts(T, xi)
    h = 0.5 * t
    dt = so2._log_jvp((T[..., :2, :2],), dT[..., :2, :2])[..., 0]
    dx, dy = dT[..., 0, 2], dT[..., 1, 2]
    rx = e * dx + h * dy + (de * tx + 0.5 * ty) * dt
    ry = e * dy - h * dx + (de * ty - 0.5 * tx) * dt
    return torch.stack((rx, ry, dt), dim=-1)


# one pass over blocks of the batch (the one driver), the backward's planes kept in cache
_log_backward_blocked = blocked(lambda *t: _log_backward(t[:-1], t[-1]), (2, 1, 1))

_LogFn = CustomFunction(
    "Se2Log",
    forward=_log,
    save=lambda inputs, out: (inputs[0], out),
    backward=lambda saved, g: _log_backward_blocked(*saved, g),
    jvp=_log_jvp,
    event_dims=(2,),
)


def _compose(A: Tensor, B: Tensor) -> Tensor:
    RA = A[..., :2, :2]
    R = RA @ B[..., :2, :2]
    t = (RA @ B[..., :2, 2:])[..., 0] + A[..., :2, 2]
    return _components.homogeneous(R, t.expand(*R.shape[:-2], 2))


def _inverse(T: Tensor) -> Tensor:
    Rt = T[..., :2, :2].transpose(-1, -2)
    return _components.homogeneous(Rt, -(Rt @ T[..., :2, 2:])[..., 0])


def _blocks(T: Tensor, inverse: bool) -> tuple[tuple[Tensor, ...], tuple[Tensor, Tensor]]:
    """The planes of the blocks of ``T`` (rotation row by row, translation), or of ``T^-1``'s
    (``R^T`` and ``-R^T t``)."""
    e = T.flatten(-2).unbind(-1)  # (one node for autograd, where 6 selections are 6)
    r, (x, y) = (e[0], e[1], e[3], e[4]), (e[2], e[5])
    if not inverse:
        return r, (x, y)
    r = (r[0], r[2], r[1], r[3])
    return r, (fma(-r[0] * x, r[1], y, value=-1.0), fma(-r[2] * x, r[3], y, value=-1.0))


def _between_planes(A: tuple, B: tuple) -> Tensor:
    """``A^-1 B`` from the planes of the blocks of ``A`` and ``B`` (:func:`_blocks`): entry
    ``(i, j)`` is ``RA_0i D_0j + RA_1i D_1j`` with ``D = [RB, tB - tA]``.  The difference of
    the translations comes first, so that where ``A == B`` the translation is exactly 0 and
    the rotation block exactly symmetric (entries ``(0, 1)`` and ``(1, 0)`` the same products
    in the same order): its :func:`log` is exactly 0."""
    (ra, ta), (rb, tb) = A, B
    d = (rb[0], rb[1], tb[0] - ta[0], rb[2], rb[3], tb[1] - ta[1])  # rows of D
    out = [fma(ra[i] * d[j], ra[2 + i], d[3 + j]) for i in range(2) for j in range(3)]
    return so2.assemble((*out, 0.0, 0.0, 1.0), so2.columns(out[0], 9)).unflatten(-1, (3, 3))


#: ``A^-1 B`` and ``A B^-1``; where ``A == B`` exactly symmetric with a zero translation (a log of
#: exactly 0)
_between, _right_between = _components.between_kernels(_blocks, _between_planes)


def _adjoint(T: Tensor) -> Tensor:
    R, tx, ty = T[..., :2, :2], T[..., 0, 2], T[..., 1, 2]
    return _components.homogeneous(R, torch.stack((ty, -tx), dim=-1))


def _jac_left(xi: Tensor) -> Tensor:
    a, b, q1, q2 = _jl(*xi.unbind(-1))
    return _pose(a, b, q1, q2)


def _jac_left_inv(xi: Tensor) -> Tensor:
    a, b, q1, q2 = _jl(*xi.unbind(-1))
    h = 0.5 * xi[..., 2]
    e = _vinv(xi[..., 2])[0]
    return _pose(e, -h, -(e * q1 + h * q2), h * q1 - e * q2)


# ----------------------------------------------------------------------------------------------
# hat / vee, exp / log
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def hat(xi: Float[Tensor, "*b 3"]) -> Float[Tensor, "*b 3 3"]:
    """``[[0, -theta, rho_x], [theta, 0, rho_y], [0, 0, 0]]`` of ``xi = (rho_x, rho_y, theta)``.

    Example:
        >>> hat(torch.tensor([1.0, 2.0, 3.0]))
        tensor([[ 0., -3.,  1.],
                [ 3.,  0.,  2.],
                [ 0.,  0.,  0.]])
    """
    x, dtype = _checks.tensor(xi, _NAME + "hat", "xi", (3,))
    rx, ry, t = x.unbind(-1)
    z = torch.zeros_like(t)
    out = torch.stack((z, -t, rx, t, z, ry, z, z, z), dim=-1).unflatten(-1, (3, 3))
    return _checks.out(out, dtype)


@_checks.float32_exact
def vee(Xi: Float[Tensor, "*b 3 3"]) -> Float[Tensor, "*b 3"]:
    """Inverse of :func:`hat`: ``(Xi[0, 2], Xi[1, 2], (Xi[1, 0] - Xi[0, 1])/2)``.

    Example:
        >>> vee(hat(torch.tensor([1.0, 2.0, 3.0])))
        tensor([1., 2., 3.])
    """
    x, dtype = _checks.tensor(Xi, _NAME + "vee", "Xi", (3, 3))
    t = _components.half_difference(x[..., 1, 0], x[..., 0, 1])
    return _checks.out(torch.stack((x[..., 0, 2], x[..., 1, 2], t), dim=-1), dtype)


@_checks.float32_exact
def exp(xi: Float[Tensor, "*b 3"]) -> Float[Tensor, "*b 3 3"]:
    """Pose of the twist ``xi = (rho, theta)``: ``[[R(theta), V(theta) rho], [0, 1]]``.

    ``V = [[a, -b], [b, a]]`` with ``a = sin t / t`` and ``b = (1 - cos t)/t`` (as
    ``2 sin(t/2)^2 / t``: no cancellation), exact to a few ulp at every angle.  The backward pass
    is the closed form ``dL/dxi = Jr(xi)^T (R^T g_t, <G_R, R hat(1)>)`` with series-safe
    coefficients; double backward and forward mode are supported.

    Example:
        >>> T = exp(torch.tensor([1.0, 0.0, torch.pi / 2]))
        >>> T[:2, 2]  # quarter turn while moving along x: (2/pi, 2/pi)
        tensor([0.6366, 0.6366])
    """
    x, dtype = _checks.tensor(xi, _NAME + "exp", "xi", (3,))
    return _checks.out(_ExpFn(x), dtype)


@_checks.float32_exact
def log(T: Float[Tensor, "*b 3 3"]) -> Float[Tensor, "*b 3"]:
    """Twist ``(rho, theta)`` of ``T``: ``theta = so2.log(R)`` in ``(-pi, pi]``,
    ``rho = V(theta)^-1 t = [[e, theta/2], [-theta/2, e]] t`` with ``e = (theta/2) cot(theta/2)``.

    Gradient meaning: that of ``log`` composed with the projection of the rotation block onto
    SO(2) (as :func:`torchlie.so2.log`, exact for 2x2 blocks); the translation block's gradient
    is exact and the bottom row gets zero.  At a half turn the gradient is the derivative of
    the branch that holds ``theta = pi`` (see :func:`torchlie.so2.log`).  Double backward and
    forward mode are supported.

    Example:
        >>> log(exp(torch.tensor([1.0, 2.0, 0.5])))
        tensor([1.0000, 2.0000, 0.5000])
    """
    x, dtype = _checks.tensor(T, _NAME + "log", "T", (3, 3))
    return _checks.out(_LogFn(x), dtype)


# ----------------------------------------------------------------------------------------------
# Group operations
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def compose(T1: Float[Tensor, "*b1 3 3"], T2: Float[Tensor, "*b2 3 3"]) -> Float[Tensor, "*b 3 3"]:
    """``T1 @ T2`` from blocks (``R1 R2``, ``R1 t2 + t1``); the bottom row is exactly
    ``(0, 0, 1)``; batch shapes broadcast.

    Example:
        >>> T = exp(torch.tensor([1.0, 0.0, 0.5]))
        >>> torch.allclose(compose(T, T), exp(torch.tensor([2.0, 0.0, 1.0])))
        True
    """
    a, b, dtype, _ = _checks.pair(_NAME + "compose", T1, T2, "T1", "T2", (3, 3), (3, 3))
    return _checks.out(_compose(a, b), dtype)


@_checks.float32_exact
def inverse(T: Float[Tensor, "*b 3 3"]) -> Float[Tensor, "*b 3 3"]:
    """``T^-1 = [[R^T, -R^T t], [0, 1]]``.

    Example:
        >>> T = exp(torch.tensor([1.0, 2.0, 0.3]))
        >>> torch.allclose(compose(inverse(T), T), torch.eye(3), atol=1e-6)
        True
    """
    x, dtype = _checks.tensor(T, _NAME + "inverse", "T", (3, 3))
    return _checks.out(_inverse(x), dtype)


@_checks.float32_exact
def act(T: Float[Tensor, "*b1 3 3"], points: Float[Tensor, "*b2 2"]) -> Float[Tensor, "*b 2"]:
    """Transform points: ``R p + t`` (batch shapes broadcast).

    Example:
        >>> T = from_xytheta(torch.tensor([1.0, 2.0, torch.pi]))
        >>> act(T, torch.tensor([1.0, 0.0])).round(decimals=6) + 0.0
        tensor([0., 2.])
    """
    x, p, dtype, _ = _checks.pair(_NAME + "act", T, points, "T", "points", (3, 3), (2,))
    out = (x[..., :2, :2] @ p.unsqueeze(-1))[..., 0] + x[..., :2, 2]
    return _checks.out(out, dtype)


@_checks.float32_exact
def adjoint(T: Float[Tensor, "*b 3 3"]) -> Float[Tensor, "*b 3 3"]:
    """Adjoint matrix ``Ad_T = [[R, (t_y, -t_x)^T], [0, 1]]`` on twists ``(rho, theta)``.

    ``T Exp(xi) T^-1 = Exp(Ad_T xi)``.

    Example:
        >>> adjoint(from_xytheta(torch.tensor([1.0, 2.0, 0.0]))) + 0.0
        tensor([[ 1.,  0.,  2.],
                [ 0.,  1., -1.],
                [ 0.,  0.,  1.]])
    """
    x, dtype = _checks.tensor(T, _NAME + "adjoint", "T", (3, 3))
    return _checks.out(_adjoint(x), dtype)


@_checks.float32_exact
def ad(xi: Float[Tensor, "*b 3"]) -> Float[Tensor, "*b 3 3"]:
    """Small adjoint ``ad(rho, theta) = [[0, -theta, rho_y], [theta, 0, -rho_x], [0, 0, 0]]``.

    ``ad(x) y`` is the Lie bracket ``vee(hat(x) hat(y) - hat(y) hat(x))`` and
    ``adjoint(exp(x)) = matrix_exp(ad(x))``.

    Example:
        >>> ad(torch.tensor([1.0, 2.0, 3.0]))
        tensor([[ 0., -3.,  2.],
                [ 3.,  0., -1.],
                [ 0.,  0.,  0.]])
    """
    x, dtype = _checks.tensor(xi, _NAME + "ad", "xi", (3,))
    rx, ry, t = x.unbind(-1)
    z = torch.zeros_like(t)
    out = torch.stack((z, -t, ry, t, z, -rx, z, z, z), dim=-1).unflatten(-1, (3, 3))
    return _checks.out(out, dtype)


@_checks.float32_exact
def jac_left(xi: Float[Tensor, "*b 3"]) -> Float[Tensor, "*b 3 3"]:
    """Left Jacobian ``Jl(xi)`` (module docstring): ``Exp(xi + d) ~= Exp(Jl(xi) d) Exp(xi)``.

    Example:
        >>> torch.equal(jac_left(torch.zeros(3)), torch.eye(3))
        True
    """
    x, dtype = _checks.tensor(xi, _NAME + "jac_left", "xi", (3,))
    return _checks.out(_jac_left(x), dtype)


@_checks.float32_exact
def jac_right(xi: Float[Tensor, "*b 3"]) -> Float[Tensor, "*b 3 3"]:
    """Right Jacobian ``Jr(xi) = Jl(-xi)``: ``Exp(xi + d) ~= Exp(xi) Exp(Jr(xi) d)``.

    Example:
        >>> xi = torch.tensor([1.0, 2.0, 0.3])
        >>> torch.allclose(jac_left(xi), adjoint(exp(xi)) @ jac_right(xi), atol=1e-6)
        True
    """
    x, dtype = _checks.tensor(xi, _NAME + "jac_right", "xi", (3,))
    return _checks.out(_jac_left(-x), dtype)


@_checks.float32_exact
def jac_left_inv(xi: Float[Tensor, "*b 3"]) -> Float[Tensor, "*b 3 3"]:
    """``Jl(xi)^-1 = [[V^-1, -V^-1 q], [0, 1]]``, closed form, finite for ``|theta| < 2 pi``.

    Example:
        >>> xi = torch.tensor([1.0, 2.0, 0.3])
        >>> torch.allclose(jac_left_inv(xi) @ jac_left(xi), torch.eye(3), atol=1e-6)
        True
    """
    x, dtype = _checks.tensor(xi, _NAME + "jac_left_inv", "xi", (3,))
    return _checks.out(_jac_left_inv(x), dtype)


@_checks.float32_exact
def jac_right_inv(xi: Float[Tensor, "*b 3"]) -> Float[Tensor, "*b 3 3"]:
    """``Jr(xi)^-1 = Jl(-xi)^-1``; ``jac_right_inv(log(T))`` is the Jacobian of :func:`log`.

    Example:
        >>> xi = torch.tensor([1.0, 2.0, 0.3])
        >>> torch.allclose(jac_right_inv(xi) @ jac_right(xi), torch.eye(3), atol=1e-6)
        True
    """
    x, dtype = _checks.tensor(xi, _NAME + "jac_right_inv", "xi", (3,))
    return _checks.out(_jac_left_inv(-x), dtype)


# ----------------------------------------------------------------------------------------------
# Construction, validation, conversions
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def identity(
    *batch: int, dtype: torch.dtype | None = None, device: torch.device | str | None = None
) -> Float[Tensor, "*batch 3 3"]:
    """Identity poses of shape ``(*batch, 3, 3)``.

    Example:
        >>> identity(2).shape
        torch.Size([2, 3, 3])
    """
    _, dtype = _checks.factory(_NAME + "identity", batch, dtype)
    return torch.eye(3, dtype=dtype, device=device).expand(*batch, 3, 3).clone()


@_checks.float32_exact
def random(
    *batch: int,
    generator: torch.Generator | None = None,
    dtype: torch.dtype | None = None,
    device: torch.device | str | None = None,
) -> Float[Tensor, "*batch 3 3"]:
    """Random poses: uniform rotations (:func:`torchlie.so2.random`), translations ``N(0, I)``.

    Example:
        >>> T = random(4, generator=torch.Generator().manual_seed(0))
        >>> bool(is_valid(T).all())
        True
    """
    compute, dtype = _checks.factory(_NAME + "random", batch, dtype)
    R = so2.random(*batch, generator=generator, dtype=compute, device=device)
    t = torch.randn(*batch, 2, generator=generator, dtype=compute, device=device)
    return _checks.out(_components.homogeneous(R, t), dtype)


@_checks.float32_exact
def is_valid(T: Float[Tensor, "*b 3 3"], atol: float | None = None) -> Bool[Tensor, "*b"]:
    """Per element: finite, rotation block valid (:func:`torchlie.so2.is_valid`) and bottom row
    ``(0, 0, 1)``, within ``atol`` (default ``100 * eps`` of the dtype, ``4 * eps`` for half).

    Example:
        >>> is_valid(torch.stack((identity(), 2 * identity())))
        tensor([ True, False])
    """
    x, _ = _checks.tensor(T, _NAME + "is_valid", "T", (3, 3))
    tol = _checks.tolerance(atol, _NAME + "is_valid", "atol", T.dtype)
    last = torch.tensor([0.0, 0.0, 1.0], dtype=x.dtype, device=x.device)
    bottom = (x[..., 2, :] - last).abs().amax(dim=-1) <= tol
    trans = torch.isfinite(x[..., :2, 2]).all(dim=-1)
    return so2.is_valid(x[..., :2, :2], atol=tol) & bottom & trans


@_checks.float32_exact
def from_rt(R: Float[Tensor, "*b1 2 2"], t: Float[Tensor, "*b2 2"]) -> Float[Tensor, "*b 3 3"]:
    """Pose ``[[R, t], [0, 1]]`` from a rotation matrix and a translation (batches broadcast).

    Example:
        >>> from_rt(torch.eye(2), torch.tensor([1.0, 2.0]))
        tensor([[1., 0., 1.],
                [0., 1., 2.],
                [0., 0., 1.]])
    """
    r, v, dtype, batch = _checks.pair(_NAME + "from_rt", R, t, "R", "t", (2, 2), (2,))
    return _checks.out(_components.homogeneous(r.expand(*batch, 2, 2), v.expand(*batch, 2)), dtype)


@_checks.float32_exact
def to_rt(T: Float[Tensor, "*b 3 3"]) -> tuple[Float[Tensor, "*b 2 2"], Float[Tensor, "*b 2"]]:
    """Rotation block and translation ``(R, t)`` of ``T`` (copies).

    Example:
        >>> to_rt(from_rt(torch.eye(2), torch.tensor([1.0, 2.0])))[1]
        tensor([1., 2.])
    """
    _checks.tensor(T, _NAME + "to_rt", "T", (3, 3))
    return T[..., :2, :2].clone(), T[..., :2, 2].clone()


@_checks.float32_exact
def from_xytheta(pose: Float[Tensor, "*b 3"]) -> Float[Tensor, "*b 3 3"]:
    """Pose of the planar coordinates ``(x, y, theta)``: translation ``(x, y)``, rotation by
    ``theta`` (not the twist: ``exp`` couples translation and rotation).

    Example:
        >>> from_xytheta(torch.tensor([1.0, 2.0, 0.0])) + 0.0
        tensor([[1., 0., 1.],
                [0., 1., 2.],
                [0., 0., 1.]])
    """
    x, dtype = _checks.tensor(pose, _NAME + "from_xytheta", "pose", (3,))
    px, py, t = x.unbind(-1)
    return _checks.out(_pose(torch.cos(t), torch.sin(t), px, py), dtype)


@_checks.float32_exact
def to_xytheta(T: Float[Tensor, "*b 3 3"]) -> Float[Tensor, "*b 3"]:
    """``(x, y, theta)`` of ``T``: its translation and the angle of :func:`torchlie.so2.log`.

    Example:
        >>> to_xytheta(from_xytheta(torch.tensor([1.0, 2.0, 0.5])))
        tensor([1.0000, 2.0000, 0.5000])
    """
    x, dtype = _checks.tensor(T, _NAME + "to_xytheta", "T", (3, 3))
    t = so2.log_angle(x[..., :2, :2])
    return _checks.out(torch.cat((x[..., :2, 2], t), dim=-1), dtype)


# ----------------------------------------------------------------------------------------------
# Metrics, interpolation, plus / minus
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def interpolate(
    T0: Float[Tensor, "*b1 3 3"], T1: Float[Tensor, "*b2 3 3"], t: Float[Tensor, "*b3"] | float
) -> Float[Tensor, "*b 3 3"]:
    """Geodesic interpolation ``T0 Exp(t Log(T0^-1 T1))`` (a screw motion; ``t`` broadcasts).

    Example:
        >>> T1 = exp(torch.tensor([2.0, 0.0, 1.0]))
        >>> mid = exp(torch.tensor([1.0, 0.0, 0.5]))
        >>> torch.allclose(interpolate(identity(), T1, 0.5), mid, atol=1e-6)
        True
    """
    fn = _NAME + "interpolate"
    a, b, dtype, _ = _checks.pair(fn, T0, T1, "T0", "T1", (3, 3), (3, 3))
    t = _checks.real(t, fn, "t", a, ("T0", T0))
    _checks.batch_broadcast(fn, (a.shape[:-2], "T0"), (b.shape[:-2], "T1"), (t.shape, "t"))
    xi = _LogFn(_between(a, b))
    return _checks.out(_compose(a, _ExpFn(t.unsqueeze(-1) * xi)), dtype)


@_checks.float32_exact
def distance(
    T1: Float[Tensor, "*b1 3 3"], T2: Float[Tensor, "*b2 3 3"]
) -> tuple[Float[Tensor, "*b"], Float[Tensor, "*b"]]:
    """Rotation angle in ``[0, pi]`` and translation length of the relative pose ``T1^-1 T2``
    (as :func:`torchlie.se3.distance`; zero subgradients where not differentiable).

    Example:
        >>> distance(identity(), from_xytheta(torch.tensor([3.0, 4.0, 0.3])))
        (tensor(0.3000), tensor(5.))
    """
    a, b, dtype, _ = _checks.pair(_NAME + "distance", T1, T2, "T1", "T2", (3, 3), (3, 3))
    x, y = so2.conformal(a[..., :2, :2].transpose(-1, -2) @ b[..., :2, :2])
    angle = _coeffs.atan2(y.abs(), x)
    trans = _coeffs.norm(b[..., :2, 2] - a[..., :2, 2]).expand(angle.shape)
    return _checks.out(angle, dtype), _checks.out(trans, dtype)


@_checks.float32_exact
def rplus(T: Float[Tensor, "*b1 3 3"], xi: Float[Tensor, "*b2 3"]) -> Float[Tensor, "*b 3 3"]:
    """Right plus ``T Exp(xi)`` (batch shapes broadcast).

    Example:
        >>> rplus(identity(), torch.tensor([1.0, 0.0, 0.0]))[:2, 2]
        tensor([1., 0.])
    """
    x, v, dtype, _ = _checks.pair(_NAME + "rplus", T, xi, "T", "xi", (3, 3), (3,))
    return _checks.out(_compose(x, _ExpFn(v)), dtype)


@_checks.float32_exact
def rminus(T1: Float[Tensor, "*b1 3 3"], T0: Float[Tensor, "*b2 3 3"]) -> Float[Tensor, "*b 3"]:
    """Right minus ``Log(T0^-1 T1)``; ``rplus(T0, rminus(T1, T0)) == T1``; exactly 0 where
    ``T1 == T0``.

    Example:
        >>> T0, xi = exp(torch.tensor([0.5, 0.0, 1.0])), torch.tensor([1.0, 2.0, 0.3])
        >>> torch.allclose(rminus(rplus(T0, xi), T0), xi, atol=1e-5)
        True
    """
    a, b, dtype, _ = _checks.pair(_NAME + "rminus", T1, T0, "T1", "T0", (3, 3), (3, 3))
    return _checks.out(_LogFn(_between(b, a)), dtype)


@_checks.float32_exact
def lplus(T: Float[Tensor, "*b1 3 3"], xi: Float[Tensor, "*b2 3"]) -> Float[Tensor, "*b 3 3"]:
    """Left plus ``Exp(xi) T`` (the perturbation in the world frame).

    Example:
        >>> T = from_xytheta(torch.tensor([1.0, 0.0, 0.0]))
        >>> lplus(T, torch.tensor([0.0, 0.0, torch.pi / 2]))[:2, 2].round(decimals=6) + 0.0
        tensor([0., 1.])
    """
    x, v, dtype, _ = _checks.pair(_NAME + "lplus", T, xi, "T", "xi", (3, 3), (3,))
    return _checks.out(_compose(_ExpFn(v), x), dtype)


@_checks.float32_exact
def lminus(T1: Float[Tensor, "*b1 3 3"], T0: Float[Tensor, "*b2 3 3"]) -> Float[Tensor, "*b 3"]:
    """Left minus ``Log(T1 T0^-1)``; ``lplus(T0, lminus(T1, T0)) == T1``; exactly 0 where
    ``T1 == T0`` (the translation of ``T1 T0^-1`` is taken as ``R1 (R1^T t1 - R0^T t0)``).

    Example:
        >>> T0, xi = exp(torch.tensor([0.5, 0.0, 1.0])), torch.tensor([1.0, 2.0, 0.3])
        >>> torch.allclose(lminus(lplus(T0, xi), T0), xi, atol=1e-5)
        True
    """
    a, b, dtype, _ = _checks.pair(_NAME + "lminus", T1, T0, "T1", "T0", (3, 3), (3, 3))
    return _checks.out(_LogFn(_right_between(a, b)), dtype)


@_checks.float32_exact
def between(T0: Float[Tensor, "*b1 3 3"], T1: Float[Tensor, "*b2 3 3"]) -> Float[Tensor, "*b 3 3"]:
    """Relative pose ``T0^-1 T1`` (``T1`` in the frame of ``T0``).

    Example:
        >>> T0 = from_xytheta(torch.tensor([1.0, 0.0, 0.0]))
        >>> between(T0, from_xytheta(torch.tensor([1.0, 2.0, 0.0])))[:2, 2]
        tensor([0., 2.])
    """
    a, b, dtype, _ = _checks.pair(_NAME + "between", T0, T1, "T0", "T1", (3, 3), (3, 3))
    return _checks.out(_between(a, b), dtype)


# ----------------------------------------------------------------------------------------------
# Jacobians of the operations (right perturbations)
# ----------------------------------------------------------------------------------------------


def _eye3(batch: torch.Size, like: Tensor) -> Tensor:
    return torch.eye(3, dtype=like.dtype, device=like.device).expand(*batch, 3, 3).clone()


@_checks.float32_exact
def jac_compose(
    T1: Float[Tensor, "*b1 3 3"], T2: Float[Tensor, "*b2 3 3"]
) -> tuple[Float[Tensor, "*b 3 3"], Float[Tensor, "*b 3 3"]]:
    """Jacobians of ``T1 T2``: ``(Ad(T2)^-1, I)``.

    Example:
        >>> T2 = exp(torch.tensor([1.0, 2.0, 0.3]))
        >>> J1, J2 = jac_compose(identity(), T2)
        >>> torch.allclose(J1, adjoint(inverse(T2))) and torch.equal(J2, torch.eye(3))
        True
    """
    a, b, dtype, batch = _checks.pair(_NAME + "jac_compose", T1, T2, "T1", "T2", (3, 3), (3, 3))
    J1 = _adjoint(_inverse(b)).expand(*batch, 3, 3).clone()
    return _checks.out(J1, dtype), _checks.out(_eye3(batch, a), dtype)


@_checks.float32_exact
def jac_inverse(T: Float[Tensor, "*b 3 3"]) -> Float[Tensor, "*b 3 3"]:
    """Jacobian of ``T^-1``: ``-Ad(T)``.

    Example:
        >>> torch.equal(jac_inverse(identity()), -torch.eye(3))
        True
    """
    x, dtype = _checks.tensor(T, _NAME + "jac_inverse", "T", (3, 3))
    return _checks.out(-_adjoint(x), dtype)


@_checks.float32_exact
def jac_act(
    T: Float[Tensor, "*b1 3 3"], points: Float[Tensor, "*b2 2"]
) -> tuple[Float[Tensor, "*b 2 3"], Float[Tensor, "*b 2 2"]]:
    """Jacobians of ``T p``: ``(J_Tp_T, J_Tp_p) = ([R, R hat(1) p], R)``, ``hat(1) p = (-py, px)``.

    Example:
        >>> JT, Jp = jac_act(identity(), torch.tensor([1.0, 2.0]))
        >>> JT
        tensor([[ 1.,  0., -2.],
                [ 0.,  1.,  1.]])
    """
    x, p, dtype, batch = _checks.pair(_NAME + "jac_act", T, points, "T", "points", (3, 3), (2,))
    R = x[..., :2, :2].expand(*batch, 2, 2)
    q = torch.stack((-p[..., 1], p[..., 0]), dim=-1).expand(*batch, 2)
    JT = torch.cat((R, R @ q.unsqueeze(-1)), dim=-1)
    return _checks.out(JT, dtype), _checks.out(R.clone(), dtype)


@_checks.float32_exact
def jac_rplus(
    T: Float[Tensor, "*b1 3 3"], xi: Float[Tensor, "*b2 3"]
) -> tuple[Float[Tensor, "*b 3 3"], Float[Tensor, "*b 3 3"]]:
    """Jacobians of ``T Exp(xi)``: ``(Ad(Exp(xi))^-1, Jr(xi))``.

    Example:
        >>> JT, Jxi = jac_rplus(identity(), torch.zeros(3))
        >>> torch.equal(JT, torch.eye(3)) and torch.equal(Jxi, torch.eye(3))
        True
    """
    _, v, dtype, batch = _checks.pair(_NAME + "jac_rplus", T, xi, "T", "xi", (3, 3), (3,))
    v = v.expand(*batch, 3)
    return _checks.out(_adjoint(_ExpFn(-v)), dtype), _checks.out(_jac_left(-v), dtype)


@_checks.float32_exact
def jac_rminus(
    T1: Float[Tensor, "*b1 3 3"], T0: Float[Tensor, "*b2 3 3"]
) -> tuple[Float[Tensor, "*b 3 3"], Float[Tensor, "*b 3 3"]]:
    """Jacobians of ``xi = Log(T0^-1 T1)``: ``(Jr(xi)^-1, -Jl(xi)^-1)``.

    Example:
        >>> J1, J0 = jac_rminus(identity(), identity())
        >>> torch.equal(J1, torch.eye(3)) and torch.equal(J0, -torch.eye(3))
        True
    """
    a, b, dtype, _ = _checks.pair(_NAME + "jac_rminus", T1, T0, "T1", "T0", (3, 3), (3, 3))
    xi = _LogFn(_between(b, a))
    return _checks.out(_jac_left_inv(-xi), dtype), _checks.out(-_jac_left_inv(xi), dtype)


@_checks.float32_exact
def jac_between(
    T0: Float[Tensor, "*b1 3 3"], T1: Float[Tensor, "*b2 3 3"]
) -> tuple[Float[Tensor, "*b 3 3"], Float[Tensor, "*b 3 3"]]:
    """Jacobians of ``T0^-1 T1``: ``(-Ad(T1^-1 T0), I)``.

    Example:
        >>> J0, J1 = jac_between(identity(), identity())
        >>> torch.equal(J0, -torch.eye(3)) and torch.equal(J1, torch.eye(3))
        True
    """
    a, b, dtype, batch = _checks.pair(_NAME + "jac_between", T0, T1, "T0", "T1", (3, 3), (3, 3))
    return _checks.out(-_adjoint(_between(b, a)), dtype), _checks.out(_eye3(batch, a), dtype)
