"""Statistics, interpolation, alignment and kinematics on SO(3), SE(3), Sim(3), SO(2) and SE(2).

Functions are named ``so3_*`` / ``se3_*`` / ``sim3_*`` / ``so2_*`` / ``se2_*`` by group and take
plain tensors in the conventions of :mod:`torchlie`: rotations ``(..., 3, 3)``, poses
``(..., 4, 4)``, rotation vectors ``(..., 3)``, twists ``(rho, phi)`` ``(..., 6)``, the planar and
similarity groups as in :mod:`torchlie.so2`, :mod:`torchlie.se2` and :mod:`torchlie.sim3`, right
perturbations ``X Exp(eps)``.

* :func:`so3_randn`, :func:`se3_randn`, :func:`sim3_randn`, :func:`so2_randn`,
  :func:`se2_randn`: Gaussian noise in the tangent space about a mean, ``X = M Exp(eps)``,
  ``eps ~ N(0, Sigma)``.
* :func:`so3_mean`, :func:`se3_mean`, :func:`sim3_mean`, :func:`so2_mean`, :func:`se2_mean`:
  weighted means of a set
  ``(..., N, n, n)`` (the last batch dimension is the set), ``"chordal"`` (closed form) or
  ``"geodesic"`` (Karcher iteration with a fixed iteration count, so nothing synchronises a
  device and the result is differentiable).
* :func:`so3_interpolate_keyframes`, :func:`se3_interpolate_keyframes`,
  :func:`sim3_interpolate_keyframes`, :func:`so2_interpolate_keyframes`,
  :func:`se2_interpolate_keyframes`: piecewise-geodesic trajectories through timed keyframes,
  evaluated at any query times.
* :func:`align`: weighted Kabsch / Umeyama alignment of point sets (rotation, translation and
  optionally scale).
* :func:`so3_integrate`, :func:`se3_integrate`, :func:`sim3_integrate`, :func:`so2_integrate`,
  :func:`se2_integrate`: exact integration of a constant velocity (angular velocity, twist) in
  the body or world frame.  (The relative transform ``T1^-1 T2`` is
  :func:`torchlie.se3.between` / :func:`torchlie.so3.between`.)

Nothing here branches in Python on tensor values, so every function works under
``torch.compile(fullgraph=True)`` and ``torch.func.vmap`` (except that the ``*_randn`` functions
draw random numbers, which ``vmap`` supports only with ``randomness="different"`` or
``"same"``, and ``torch.compile`` only without a ``generator=``).  float16/bfloat16 inputs
are computed in float32 and returned in the input dtype.
"""

from __future__ import annotations

import math
import reprlib
from collections.abc import Callable
from types import ModuleType
from typing import NamedTuple

import torch
from torch import Tensor

from . import _checks, _coeffs, _components, se2, se3, sim3, so2, so3
from ._typing import Float

__all__ = [
    "so3_randn",
    "se3_randn",
    "sim3_randn",
    "so2_randn",
    "se2_randn",
    "so3_mean",
    "se3_mean",
    "sim3_mean",
    "so2_mean",
    "se2_mean",
    "so3_interpolate_keyframes",
    "se3_interpolate_keyframes",
    "sim3_interpolate_keyframes",
    "so2_interpolate_keyframes",
    "se2_interpolate_keyframes",
    "Alignment",
    "align",
    "so3_integrate",
    "se3_integrate",
    "sim3_integrate",
    "so2_integrate",
    "se2_integrate",
]


def __dir__() -> list[str]:
    # dir() lists the public API only, not the names this module imports (torch, Tensor, ...).
    return sorted(__all__)


_NAME = "torchlie.statistics."
_METHODS = ("chordal", "geodesic")


class _Group(NamedTuple):
    name: str
    core: ModuleType
    n: int  # matrix size
    dof: int  # tangent dimension
    affine: bool  # [[L, t], [0, 1]] with a translation t


_SO3 = _Group("so3", so3, 3, 3, False)
_SE3 = _Group("se3", se3, 4, 6, True)
_SIM3 = _Group("sim3", sim3, 4, 7, True)
_SO2 = _Group("so2", so2, 2, 1, False)
_SE2 = _Group("se2", se2, 3, 3, True)


# ----------------------------------------------------------------------------------------------
# Sampling
# ----------------------------------------------------------------------------------------------


def _randn(
    g: _Group,
    mean: Tensor,
    std: Tensor | float | None,
    cov: Tensor | None,
    scale_tril: Tensor | None,
    sample_shape: tuple[int, ...] | torch.Size,
    generator: torch.Generator | None,
) -> Tensor:
    fn = _NAME + g.name + "_randn"
    m, dtype = _checks.tensor(mean, fn, "mean", (g.n, g.n))
    sizes = sample_shape if isinstance(sample_shape, (tuple, list)) else None
    if sizes is None or not all(isinstance(k, int) and not isinstance(k, bool) for k in sizes):
        raise TypeError(
            f"{fn}: expected sample_shape to be a tuple of ints (a torch.Size), got "
            f"{type(sample_shape).__name__} {reprlib.repr(sample_shape)}"
        )
    if any(k < 0 for k in sizes):
        raise ValueError(
            f"{fn}: expected sample_shape of non-negative sizes, got {tuple(sample_shape)}"
        )
    _checks.generator(generator, fn)
    given = [
        k for k, v in (("std", std), ("cov", cov), ("scale_tril", scale_tril)) if v is not None
    ]
    if len(given) != 1:
        raise ValueError(
            f"{fn}: expected exactly one of std, cov and scale_tril, got "
            f"{', '.join(given) if given else 'none'}"
        )
    shapes = [(m.shape[:-2], "mean")]
    if std is not None:
        s = _checks.real(std, fn, "std", m, ("mean", mean))
        shapes.append((s.shape, "std"))
    else:
        name = "cov" if cov is not None else "scale_tril"
        L, _ = _checks.tensor(cov if cov is not None else scale_tril, fn, name, (g.dof, g.dof))
        _checks.same_dtype(fn, mean=mean, **{name: cov if cov is not None else scale_tril})
        if cov is not None:
            L, info = torch.linalg.cholesky_ex(_components.symmetric_part(L))
            # A covariance that is not positive definite gives NaN for its element only.
            L = torch.where((info == 0)[..., None, None], L, torch.full_like(L, float("nan")))
        else:
            L = L.tril()
        shapes.append((L.shape[:-2], name))
    batch = _checks.batch_broadcast(fn, *shapes)
    _checks.batch_dims(fn, len(sample_shape) + len(batch), "in sample_shape and the batch")
    z = torch.randn(
        (*sample_shape, *batch, g.dof), generator=generator, dtype=m.dtype, device=m.device
    )
    if std is not None:
        eps = s.unsqueeze(-1) * z
    else:
        eps = (L @ z.unsqueeze(-1)).squeeze(-1)
    return _checks.out(g.core.rplus(m, eps), dtype)


@_checks.float32_exact
def so3_randn(
    mean: Float[Tensor, "*b1 3 3"],
    std: Float[Tensor, "*b2"] | float | None = None,
    *,
    cov: Float[Tensor, "*b2 3 3"] | None = None,
    scale_tril: Float[Tensor, "*b2 3 3"] | None = None,
    sample_shape: tuple[int, ...] | torch.Size = (),
    generator: torch.Generator | None = None,
) -> Float[Tensor, "*sample_batch 3 3"]:
    """Gaussian rotations about ``mean``: ``R = mean Exp(eps)``, ``eps ~ N(0, Sigma)``.

    ``eps`` is a rotation vector in the body frame of ``mean`` (right perturbation), so
    ``so3.rminus(R, mean)`` recovers it exactly while ``|eps| < pi``.  Give exactly one of
    ``std`` (isotropic, ``Sigma = std^2 I``, in radians; a float or a tensor broadcasting with
    the batch), ``cov`` (full ``3x3`` covariance, positive definite, read as its symmetric part
    ``(C + C^T)/2`` in value and derivatives; one that is not gives NaN for its element) or
    ``scale_tril`` (a lower-triangular factor ``L``, ``Sigma = L L^T``; use it for singular
    covariances).  The result has shape ``(*sample_shape, *batch, 3, 3)`` with
    ``batch`` the broadcast of the batch shapes of ``mean`` and ``std`` / ``cov``.

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> R = so3_randn(torch.eye(3), 0.1, sample_shape=(1000,), generator=g)
        >>> R.shape
        torch.Size([1000, 3, 3])
        >>> round(so3.log(R).square().mean().sqrt().item(), 2)  # per-axis std
        0.1
    """
    return _randn(_SO3, mean, std, cov, scale_tril, sample_shape, generator)


@_checks.float32_exact
def se3_randn(
    mean: Float[Tensor, "*b1 4 4"],
    std: Float[Tensor, "*b2"] | float | None = None,
    *,
    cov: Float[Tensor, "*b2 6 6"] | None = None,
    scale_tril: Float[Tensor, "*b2 6 6"] | None = None,
    sample_shape: tuple[int, ...] | torch.Size = (),
    generator: torch.Generator | None = None,
) -> Float[Tensor, "*sample_batch 4 4"]:
    """Gaussian poses about ``mean``: ``T = mean Exp(eps)``, ``eps ~ N(0, Sigma)``.

    ``eps`` is a twist ``(rho, phi)`` (translation part first) in the body frame of ``mean``, so
    ``Sigma`` is ``6x6`` in that order; ``se3.rminus(T, mean)`` recovers ``eps`` exactly while
    ``|phi| < pi``.  Give exactly one of ``std`` (isotropic; it mixes metres and radians, so it
    is mostly useful for tests), ``cov`` (positive definite; its symmetric part, as
    :func:`so3_randn`) or ``scale_tril`` (``Sigma = L L^T``, for singular covariances such as
    rotation-only noise).  Shape
    ``(*sample_shape, *batch, 4, 4)``.

    Example:
        >>> cov = torch.diag(torch.tensor([1.0, 1.0, 1.0, 0.01, 0.01, 0.01]))
        >>> g = torch.Generator().manual_seed(0)
        >>> T = se3_randn(torch.eye(4), cov=cov, sample_shape=(5, 2), generator=g)
        >>> T.shape
        torch.Size([5, 2, 4, 4])
    """
    return _randn(_SE3, mean, std, cov, scale_tril, sample_shape, generator)


@_checks.float32_exact
def sim3_randn(
    mean: Float[Tensor, "*b1 4 4"],
    std: Float[Tensor, "*b2"] | float | None = None,
    *,
    cov: Float[Tensor, "*b2 7 7"] | None = None,
    scale_tril: Float[Tensor, "*b2 7 7"] | None = None,
    sample_shape: tuple[int, ...] | torch.Size = (),
    generator: torch.Generator | None = None,
) -> Float[Tensor, "*sample_batch 4 4"]:
    """Gaussian similarities about ``mean``: ``T = mean Exp(eps)``, ``eps ~ N(0, Sigma)``.

    ``eps`` is a tangent ``(rho, phi, sigma)`` (translation part, rotation vector, log scale) in
    the body frame of ``mean``, so ``Sigma`` is ``7x7`` in that order; ``sim3.rminus(T, mean)``
    recovers ``eps`` exactly while ``|phi| < pi``.  The scale is the mean's times
    ``exp(sigma)``: log-normal, always positive.  Give exactly one of ``std``, ``cov`` or
    ``scale_tril`` (as :func:`se3_randn`).  Shape ``(*sample_shape, *batch, 4, 4)``.

    Example:
        >>> cov = torch.diag(torch.tensor([1.0, 1.0, 1.0, 0.01, 0.01, 0.01, 0.04]))
        >>> g = torch.Generator().manual_seed(0)
        >>> T = sim3_randn(torch.eye(4), cov=cov, sample_shape=(1000,), generator=g)
        >>> T.shape
        torch.Size([1000, 4, 4])
        >>> round(torch.log(sim3.scale(T)).std().item(), 1)  # the log scale's std
        0.2
    """
    return _randn(_SIM3, mean, std, cov, scale_tril, sample_shape, generator)


@_checks.float32_exact
def so2_randn(
    mean: Float[Tensor, "*b1 2 2"],
    std: Float[Tensor, "*b2"] | float | None = None,
    *,
    cov: Float[Tensor, "*b2 1 1"] | None = None,
    scale_tril: Float[Tensor, "*b2 1 1"] | None = None,
    sample_shape: tuple[int, ...] | torch.Size = (),
    generator: torch.Generator | None = None,
) -> Float[Tensor, "*sample_batch 2 2"]:
    """Gaussian planar rotations about ``mean``: ``R = mean Exp(eps)``, ``eps ~ N(0, Sigma)``.

    ``eps`` is an angle ``(..., 1)`` in radians (right and left perturbations agree on SO(2)),
    so ``so2.rminus(R, mean)`` recovers it exactly while ``|eps| < pi`` (beyond, it wraps: the
    angles follow the wrapped normal distribution).  Give exactly one of ``std``, ``cov`` or
    ``scale_tril`` (``1x1``; as :func:`so3_randn`).  Shape ``(*sample_shape, *batch, 2, 2)``.

    Example:
        >>> g = torch.Generator().manual_seed(0)
        >>> R = so2_randn(torch.eye(2), 0.1, sample_shape=(1000,), generator=g)
        >>> R.shape
        torch.Size([1000, 2, 2])
        >>> round(so2.log(R).square().mean().sqrt().item(), 2)  # the angle's std
        0.1
    """
    return _randn(_SO2, mean, std, cov, scale_tril, sample_shape, generator)


@_checks.float32_exact
def se2_randn(
    mean: Float[Tensor, "*b1 3 3"],
    std: Float[Tensor, "*b2"] | float | None = None,
    *,
    cov: Float[Tensor, "*b2 3 3"] | None = None,
    scale_tril: Float[Tensor, "*b2 3 3"] | None = None,
    sample_shape: tuple[int, ...] | torch.Size = (),
    generator: torch.Generator | None = None,
) -> Float[Tensor, "*sample_batch 3 3"]:
    """Gaussian planar poses about ``mean``: ``T = mean Exp(eps)``, ``eps ~ N(0, Sigma)``.

    ``eps`` is a twist ``(rho_x, rho_y, theta)`` (translation part first) in the body frame of
    ``mean``, so ``Sigma`` is ``3x3`` in that order; ``se2.rminus(T, mean)`` recovers ``eps``
    exactly while ``|theta| < pi``.  Give exactly one of ``std``, ``cov`` or ``scale_tril`` (as
    :func:`se3_randn`).  Shape ``(*sample_shape, *batch, 3, 3)``.

    Example:
        >>> cov = torch.diag(torch.tensor([0.25, 0.25, 0.01]))
        >>> g = torch.Generator().manual_seed(0)
        >>> T = se2_randn(torch.eye(3), cov=cov, sample_shape=(5, 2), generator=g)
        >>> T.shape
        torch.Size([5, 2, 3, 3])
    """
    return _randn(_SE2, mean, std, cov, scale_tril, sample_shape, generator)


# ----------------------------------------------------------------------------------------------
# Means
# ----------------------------------------------------------------------------------------------


def _weights(fn: str, x: Tensor, weights: object, n: int, ref: tuple[str, Tensor]) -> Tensor:
    """Normalised weights ``(..., n)`` (a tensor of ``ref``'s dtype, or numbers), divided by a
    power of two of the largest first (exactly), so that their sum does not overflow."""
    w = _checks.real(weights, fn, "weights", x, ref)
    if w.dim() == 0 or w.shape[-1] != n:
        raise ValueError(
            f"{fn}: expected weights of shape (..., {n}) (one per element of the set), got "
            f"{tuple(w.shape)}"
        )
    w = w / _coeffs.power_of_two(w.detach().abs().amax(-1, keepdim=True))
    return w / _sum(w, -1).unsqueeze(-1)


def _set(fn: str, g: _Group, X: Tensor, weights: object, arg: str):
    x, dtype = _checks.tensor(X, fn, arg, (g.n, g.n))
    if x.dim() < 3 or x.shape[-3] == 0:
        raise ValueError(
            f"{fn}: expected {arg} of shape (..., N, {g.n}, {g.n}) with N >= 1 (the set is the "
            f"last batch dimension), got {tuple(X.shape)}"
        )
    if weights is None:
        w = torch.full(x.shape[:-2], 1.0 / x.shape[-3], dtype=x.dtype, device=x.device)
    else:
        w = _weights(fn, x, weights, x.shape[-3], (arg, X))
        _checks.batch_broadcast(fn, (x.shape[:-3], arg), (w.shape[:-1], "weights"))
    return x, w, dtype


def _check_method(fn: str, method: str, iterations: int) -> None:
    if method not in _METHODS:
        raise ValueError(f"{fn}: expected method 'chordal' or 'geodesic', got {method!r}")
    _checks.count(iterations, fn, "iterations", 0)


def _wsum(w: Tensor, x: Tensor, k: int) -> Tensor:
    """``sum_i w_i x_i`` over the set dimension (``x`` has ``k`` trailing data dimensions)."""
    return _sum(w[(...,) + (None,) * k] * x, -1 - k)


def _binade(x: Tensor, used: Tensor | None = None) -> Tensor:
    """The power of two ``k`` with ``max |x_ij| / k`` in ``[1, 2)`` over the last two dimensions
    (kept, size 1), detached (:func:`torchlie._coeffs.power_of_two`); over the rows ``used``
    (``(..., n, 1)`` bool) when given."""
    m = x.detach().abs()
    if used is not None:
        m = torch.where(used, m, 0.0)
    return _coeffs.power_of_two(m.amax((-2, -1), keepdim=True))


def _sum(x: Tensor, dims: int | tuple[int, ...]) -> Tensor:
    """``x.sum(dims)`` in an order fixed by the numbers summed alone: the summed dimensions
    are moved last and made contiguous first (torch sums in an order that depends on the
    layout of the operand, so the same numbers laid out otherwise would round otherwise)."""
    dims = (dims,) if isinstance(dims, int) else dims
    n = len(dims)
    y = x.movedim(dims, tuple(range(-n, 0))).contiguous()
    return (y.flatten(-n) if n > 1 else y).sum(-1)


def _chordal_so3(x: Tensor, w: Tensor) -> Tensor:
    return so3.project(_wsum(w, x, 2))


def _chordal_so2(x: Tensor, w: Tensor) -> Tensor:
    # sum_i w_i R_i is a multiple of a rotation (the sum of the unit complex numbers): its
    # direction is the nearest rotation
    return so2.from_complex(_wsum(w, x[..., :, 0], 1))


def _chordal_se3(x: Tensor, w: Tensor) -> Tensor:
    return se3.from_rt(_chordal_so3(x[..., :3, :3], w), _wsum(w, x[..., :3, 3], 1))


def _chordal_sim3(x: Tensor, w: Tensor) -> Tensor:
    s, R, t = sim3.to_srt(x)  # the weighted geometric mean of the scales
    return sim3.from_srt(torch.exp(_wsum(w, torch.log(s), 0)), _chordal_so3(R, w), _wsum(w, t, 1))


def _chordal_se2(x: Tensor, w: Tensor) -> Tensor:
    return se2.from_rt(_chordal_so2(x[..., :2, :2], w), _wsum(w, x[..., :2, 2], 1))


def _mean(
    name: str,
    g: _Group,
    X: Tensor,
    weights: object,
    arg: str,
    chordal: Callable[[Tensor, Tensor], Tensor],
    method: str,
    iterations: int,
) -> Tensor:
    """The chordal mean of a set, then (``method="geodesic"``) the Karcher steps from it."""
    fn = _NAME + name
    _check_method(fn, method, iterations)
    x, w, dtype = _set(fn, g, X, weights, arg)
    M = chordal(x, w)
    if method == "geodesic":
        M = _karcher(g, M, x, w, iterations)
    return _checks.out(M, dtype)


def _with_translation(X: Tensor, t: Tensor) -> Tensor:
    """``X`` (``(..., n, n)``, ``[[L, t], [0, 1]]``) with the translation ``t`` ``(..., n - 1)``."""
    d = X.shape[-1] - 1
    t = t.expand(*X.shape[:-2], d)
    return torch.cat((X[..., :d], torch.cat((t, X[..., d:, d]), -1).unsqueeze(-1)), -1)


def _karcher(g: _Group, M: Tensor, x: Tensor, w: Tensor, iterations: int) -> Tensor:
    # M <- M Exp(sum_i w_i Log(M^-1 X_i)): the Gauss-Newton step of sum_i w_i |Log(M^-1 X_i)|^2.
    d = g.n - 1 if g.affine else 0  # the translation's dimension
    x0 = x
    if d:
        # The rotation (and scale) part of Log(M^-1 X_i) does not depend on the translations:
        # the steps run on the set with its translations zeroed (the mean's stays 0), and the
        # translation then solves its own, linear, equation.  (The plain step multiplies the
        # translation's error by I - A, A below: it diverges for Sim(3) sets whose log-scales
        # are a few units apart.)
        zero = x.new_zeros(d)
        x0, M = _with_translation(x, zero), _with_translation(M, zero)
    for _ in range(iterations):
        M = g.core.rplus(M, _wsum(w, g.core.rminus(x0, M.unsqueeze(-3)), 1))
    if not d:
        return M
    # M = [[L, L y], [0, 1]]: the translation part of Log(M^-1 X_i) is V_i^-1 (L^-1 t_i - y)
    # (V_i: the translation's coefficients of the i-th relative rotation and scale), so
    # sum_i w_i of it is a - A y, with a its value at y = 0 and A e_k = -(its value on the
    # translation-free set at y = e_k, i.e. with L's k-th column as M's translation).
    L = M[..., :d, :d]

    def rho(X: Tensor, t: Tensor) -> Tensor:
        return _wsum(w, g.core.rminus(X, _with_translation(M, t).unsqueeze(-3))[..., :d], 1)

    a = rho(x, zero)
    A = -torch.stack([rho(x0, L[..., k]) for k in range(d)], -1)
    y = torch.linalg.solve_ex(A, a.unsqueeze(-1), check_errors=False)[0]
    return _with_translation(M, _sum(L * y.mT, -1))


@_checks.float32_exact
def so3_mean(
    R: Float[Tensor, "*b1 N 3 3"],
    weights: Float[Tensor, "*b2 N"] | None = None,
    *,
    method: str = "geodesic",
    iterations: int = 10,
) -> Float[Tensor, "*b 3 3"]:
    """Weighted mean of a set of rotations (the set is the last batch dimension).

    ``method="chordal"``: the rotation nearest to ``sum_i w_i R_i`` (:func:`torchlie.so3.project`),
    which minimises ``sum_i w_i |R - R_i|_F^2``.  This is the same minimiser as the quaternion
    eigenvector mean of ``scipy.spatial.transform.Rotation.mean`` (since
    ``|R(q) - R(p)|_F^2 = 8 (1 - (q . p)^2)``).

    ``method="geodesic"`` (default): the Karcher mean, the stationary point of
    ``sum_i w_i |Log(M^T R_i)|^2``, by ``iterations`` Gauss-Newton steps
    ``M <- M Exp(sum_i w_i Log(M^T R_i))`` started from the chordal mean.  The count is fixed (no
    convergence test, so no host sync).  Each step shrinks the residual
    ``|sum_i w_i Log(M^T R_i)|`` by a factor of roughly ``theta^2 / 20``, ``theta`` the rms angle
    of the set about its mean: the default 10 steps reach float64 rounding for sets with
    ``theta`` up to about 0.9 rad (0.5 rad per axis) and about 1e-9 rad at ``theta = 1.7``;
    raise ``iterations`` for wider sets.  Gradients flow through the unrolled steps.

    Both are equivariant: ``mean(A R_i B) = A mean(R_i) B``.  Weights ``(..., N)`` (non-negative,
    positive sum, of any finite magnitude; normalised here; not checked, which would read their
    values: a sum of 0 gives NaN) broadcast with the set; default uniform.  The other means take
    weights alike.

    Where the chordal mean is not unique, because ``sum_i w_i R_i`` has rank at most 1 (e.g. two
    rotations ``pi`` apart with equal weights, ``{I, Rz(pi)}``, where every rotation about ``z``
    minimises), ``method="chordal"`` returns one of the minimisers (finite, and the same
    whatever the batch around it; not NaN, unlike :func:`so2_mean`), and the geodesic steps
    start from it and reach one of the Karcher means (``Rz(pi/2)`` for ``{I, Rz(pi)}``).  The
    derivatives there are finite but belong to no particular mean.

    Example:
        >>> R = so3.exp(torch.tensor([[0.0, 0.0, 0.2], [0.0, 0.0, 0.6]]))
        >>> so3.log(so3_mean(R))
        tensor([0.0000, 0.0000, 0.4000])
        >>> so3.log(so3_mean(R, torch.tensor([3.0, 1.0])))
        tensor([0.0000, 0.0000, 0.3000])
    """
    return _mean("so3_mean", _SO3, R, weights, "R", _chordal_so3, method, iterations)


@_checks.float32_exact
def se3_mean(
    T: Float[Tensor, "*b1 N 4 4"],
    weights: Float[Tensor, "*b2 N"] | None = None,
    *,
    method: str = "geodesic",
    iterations: int = 10,
) -> Float[Tensor, "*b 4 4"]:
    """Weighted mean of a set of poses (the set is the last batch dimension).

    ``method="chordal"``: rotation as :func:`so3_mean`'s chordal mean, translation the weighted
    mean of the translations.  Equivariant under left multiplication ``A T_i`` (and under right
    multiplication by a pure rotation), not under right multiplication in general.

    ``method="geodesic"`` (default): the exponential barycenter, the pose ``M`` with
    ``sum_i w_i Log(M^-1 T_i) = 0`` (twists in SE(3)'s own exponential coordinates).  The
    rotation part of that equation does not involve the translations: ``M``'s rotation is the
    rotations' Karcher mean, by ``iterations`` fixed steps from the chordal mean (as
    :func:`so3_mean`); the translation part is linear in ``M``'s translation, which then solves
    it (one 3x3 solve).  It is equivariant under left and right multiplication, and it
    coincides with the chordal translation when all rotations are equal.

    Example:
        >>> T = se3.from_rt(torch.eye(3), torch.tensor([[0.0, 0.0, 0.0], [2.0, 4.0, 6.0]]))
        >>> se3.to_rt(se3_mean(T))[1]
        tensor([1., 2., 3.])
    """
    return _mean("se3_mean", _SE3, T, weights, "T", _chordal_se3, method, iterations)


@_checks.float32_exact
def sim3_mean(
    T: Float[Tensor, "*b1 N 4 4"],
    weights: Float[Tensor, "*b2 N"] | None = None,
    *,
    method: str = "geodesic",
    iterations: int = 10,
) -> Float[Tensor, "*b 4 4"]:
    """Weighted mean of a set of similarities (the set is the last batch dimension).

    ``method="chordal"``: rotation as :func:`so3_mean`'s chordal mean, scale the weighted
    geometric mean of the scales, translation the weighted mean of the translations.
    ``method="geodesic"`` (default): the exponential barycenter, ``sum_i w_i Log(M^-1 T_i) = 0``
    in Sim(3)'s exponential coordinates, computed as :func:`se3_mean`'s (its scale is the
    weighted geometric mean of the scales, its rotation the rotations' Karcher mean, its
    translation the solution of the linear translation part, at any spread of the scales);
    equivariant under left and right multiplication.

    Example:
        >>> T = sim3.from_srt(torch.tensor([1.0, 4.0]), torch.eye(3), torch.zeros(2, 3))
        >>> sim3.scale(sim3_mean(T))
        tensor(2.)
    """
    return _mean("sim3_mean", _SIM3, T, weights, "T", _chordal_sim3, method, iterations)


@_checks.float32_exact
def so2_mean(
    R: Float[Tensor, "*b1 N 2 2"],
    weights: Float[Tensor, "*b2 N"] | None = None,
    *,
    method: str = "geodesic",
    iterations: int = 10,
) -> Float[Tensor, "*b 2 2"]:
    """Weighted mean of a set of planar rotations (the set is the last batch dimension).

    ``method="chordal"``: the rotation nearest to ``sum_i w_i R_i``, the direction of the
    weighted sum of the unit complex numbers (the circular mean); NaN where that sum is 0 (no
    direction, e.g. two opposite rotations of equal weight; close to it the direction is
    ill-conditioned).  ``method="geodesic"`` (default):
    the Karcher mean, ``sum_i w_i Log(M^T R_i) = 0``, by ``iterations`` fixed steps from the
    chordal mean (as :func:`so3_mean`; on SO(2) the angles add, so one step from a start within
    the set's half circle already reaches it).  Both are equivariant: ``mean(A R_i) = A mean(R_i)``.

    Example:
        >>> R = so2.exp(torch.tensor([[0.2], [0.6]]))
        >>> so2.log(so2_mean(R))
        tensor([0.4000])
    """
    return _mean("so2_mean", _SO2, R, weights, "R", _chordal_so2, method, iterations)


@_checks.float32_exact
def se2_mean(
    T: Float[Tensor, "*b1 N 3 3"],
    weights: Float[Tensor, "*b2 N"] | None = None,
    *,
    method: str = "geodesic",
    iterations: int = 10,
) -> Float[Tensor, "*b 3 3"]:
    """Weighted mean of a set of planar poses (the set is the last batch dimension).

    ``method="chordal"``: rotation as :func:`so2_mean`'s chordal mean, translation the weighted
    mean of the translations.  ``method="geodesic"`` (default): the exponential barycenter,
    ``sum_i w_i Log(M^-1 T_i) = 0`` in SE(2)'s exponential coordinates, computed as
    :func:`se3_mean`'s (the rotation as :func:`so2_mean`'s geodesic mean); equivariant under
    left and right multiplication.

    Example:
        >>> T = se2.from_xytheta(torch.tensor([[0.0, 0.0, 0.0], [2.0, 4.0, 0.0]]))
        >>> se2.to_xytheta(se2_mean(T))
        tensor([1., 2., 0.])
    """
    return _mean("se2_mean", _SE2, T, weights, "T", _chordal_se2, method, iterations)


# ----------------------------------------------------------------------------------------------
# Keyframe interpolation
# ----------------------------------------------------------------------------------------------


def _keyframes(
    g: _Group, times: Tensor, keyframes: Tensor, query: Tensor | float, extrapolate: bool
) -> Tensor:
    fn = _NAME + g.name + "_interpolate_keyframes"
    extrapolate = _checks.flag(extrapolate, fn, "extrapolate")
    kf, dtype = _checks.tensor(keyframes, fn, "keyframes", (g.n, g.n))
    ts = _checks.real(times, fn, "times", kf, ("keyframes", keyframes))
    if ts.dim() != 1 or ts.shape[0] == 0:
        raise ValueError(f"{fn}: expected times of shape (K,) with K >= 1, got {tuple(ts.shape)}")
    K = ts.shape[0]
    if kf.dim() < 3 or kf.shape[0] != K:
        raise ValueError(
            f"{fn}: expected keyframes of shape (K, ..., {g.n}, {g.n}) with K = {K} (one per "
            f"time), got {tuple(keyframes.shape)}"
        )
    q = _checks.real(query, fn, "query_times", kf, ("keyframes", keyframes))
    batch = kf.shape[1:-2]
    _checks.batch_dims(fn, q.dim() + len(batch), "in query_times and the keyframes' batch")
    lead = (None,) * len(batch)
    if K == 1:
        return _checks.out(kf[0].expand(*q.shape, *batch, g.n, g.n).clone(), dtype)
    idx = torch.searchsorted(ts, q.contiguous(), right=True) - 1
    idx = idx.clamp(0, K - 2)
    t0, t1 = ts[idx], ts[idx + 1]
    dt = t1 - t0
    ok = dt > 0
    # A span beyond the largest float (dt = inf): u from the halves of the times.
    wide = torch.isinf(dt)
    num = torch.where(wide, q / 2 - t0 / 2, q - t0)
    den = torch.where(ok, torch.where(wide, t1 / 2 - t0 / 2, dt), torch.ones_like(dt))
    u = torch.where(ok, num / den, torch.zeros_like(q))
    if not extrapolate:
        # not clamp: its derivative at the bounds is torch's choice (1 up to torch 2.14, 0
        # since), and u = 0 at every keyframe time; there the derivative is the segment's
        # that starts at that time
        u = torch.where(u < 0.0, 0.0, torch.where(u > 1.0, 1.0, u))
    u = u[(...,) + lead]
    k1 = kf[idx + 1]
    out = g.core.interpolate(kf[idx], k1, u)
    # At u = 1 (at and after the last time when clamped) the keyframe itself, exactly (the
    # interpolation's value there may differ by an ulp), with the interpolation's derivatives.
    end = (u == 1)[(...,) + (None, None)]
    out = torch.where(end, k1.detach() + (out - out.detach()), out)
    return _checks.out(out, dtype)


@_checks.float32_exact
def so3_interpolate_keyframes(
    times: Float[Tensor, " K"],
    keyframes: Float[Tensor, "K *b 3 3"],
    query_times: Float[Tensor, "*q"] | float,
    *,
    extrapolate: bool = False,
) -> Float[Tensor, "*query_batch 3 3"]:
    """Rotation trajectory through keyframes ``(times[k], keyframes[k])``, at ``query_times``.

    Piecewise geodesic: between ``times[k] <= s < times[k+1]`` (found with
    :func:`torch.searchsorted`) the result is :func:`torchlie.so3.interpolate` of the two
    neighbours at ``u = (s - times[k]) / (times[k+1] - times[k])``, the shortest rotation
    between them (as ``scipy.spatial.transform.Slerp``).  ``times`` must be sorted increasing
    (not checked; a repeated time is a jump).  Outside ``[times[0], times[-1]]`` the result is
    clamped to the first / last keyframe, or with ``extrapolate=True`` continues along the first
    / last segment's geodesic.  ``keyframes`` may carry extra batch dimensions ``(K, *b, 3, 3)``
    (several trajectories sharing the times); the result has shape ``(*q, *b, 3, 3)``.
    Differentiable in the keyframes and in the query times; at a keyframe time (where the
    velocity may jump) the derivative in the query time is that of the segment starting there
    (at the last keyframe, clamped, that of the segment ending there).

    Example:
        >>> times = torch.tensor([0.0, 1.0, 3.0])
        >>> keys = so3.exp(torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 2.0]]))
        >>> so3.log(so3_interpolate_keyframes(times, keys, torch.tensor([0.5, 2.0, 4.0])))
        tensor([[0.0000, 0.0000, 0.5000],
                [0.0000, 0.0000, 1.5000],
                [0.0000, 0.0000, 2.0000]])
    """
    return _keyframes(_SO3, times, keyframes, query_times, extrapolate)


@_checks.float32_exact
def se3_interpolate_keyframes(
    times: Float[Tensor, " K"],
    keyframes: Float[Tensor, "K *b 4 4"],
    query_times: Float[Tensor, "*q"] | float,
    *,
    extrapolate: bool = False,
) -> Float[Tensor, "*query_batch 4 4"]:
    """Pose trajectory through timed keyframes (as :func:`so3_interpolate_keyframes`).

    Each segment is :func:`torchlie.se3.interpolate`, the SE(3) geodesic (a screw motion: the
    rotation part is the rotations' slerp, the translation follows the screw, not a straight
    line).  Same sorting, clamping / ``extrapolate`` rules and shapes as the SO(3) version.

    Example:
        >>> times = torch.tensor([0.0, 2.0])
        >>> keys = se3.from_rt(torch.eye(3), torch.tensor([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]]))
        >>> se3.to_rt(se3_interpolate_keyframes(times, keys, torch.tensor([1.0, 3.0])))[1]
        tensor([[1., 0., 0.],
                [2., 0., 0.]])
    """
    return _keyframes(_SE3, times, keyframes, query_times, extrapolate)


@_checks.float32_exact
def sim3_interpolate_keyframes(
    times: Float[Tensor, " K"],
    keyframes: Float[Tensor, "K *b 4 4"],
    query_times: Float[Tensor, "*q"] | float,
    *,
    extrapolate: bool = False,
) -> Float[Tensor, "*query_batch 4 4"]:
    """Similarity trajectory through timed keyframes (as :func:`so3_interpolate_keyframes`).

    Each segment is :func:`torchlie.sim3.interpolate`, the Sim(3) geodesic: the rotation part is
    the rotations' slerp, the log scale moves linearly in time (the scale geometrically) and the
    translation follows the group's exponential.  Same sorting, clamping / ``extrapolate`` rules
    and shapes as the SO(3) version.

    Example:
        >>> times = torch.tensor([0.0, 2.0])
        >>> keys = sim3.from_srt(torch.tensor([1.0, 4.0]), torch.eye(3), torch.zeros(2, 3))
        >>> sim3.scale(sim3_interpolate_keyframes(times, keys, torch.tensor([1.0, 3.0])))
        tensor([2., 4.])
    """
    return _keyframes(_SIM3, times, keyframes, query_times, extrapolate)


@_checks.float32_exact
def so2_interpolate_keyframes(
    times: Float[Tensor, " K"],
    keyframes: Float[Tensor, "K *b 2 2"],
    query_times: Float[Tensor, "*q"] | float,
    *,
    extrapolate: bool = False,
) -> Float[Tensor, "*query_batch 2 2"]:
    """Planar rotation trajectory through timed keyframes (as :func:`so3_interpolate_keyframes`).

    Each segment is :func:`torchlie.so2.interpolate`: the angle moves linearly along the shorter
    arc between the two neighbours (counter-clockwise at an exact half turn).  Same sorting,
    clamping / ``extrapolate`` rules and shapes as the SO(3) version.

    Example:
        >>> times = torch.tensor([0.0, 1.0, 3.0])
        >>> keys = so2.exp(torch.tensor([[0.0], [1.0], [2.0]]))
        >>> so2.log(so2_interpolate_keyframes(times, keys, torch.tensor([0.5, 2.0, 4.0])))
        tensor([[0.5000],
                [1.5000],
                [2.0000]])
    """
    return _keyframes(_SO2, times, keyframes, query_times, extrapolate)


@_checks.float32_exact
def se2_interpolate_keyframes(
    times: Float[Tensor, " K"],
    keyframes: Float[Tensor, "K *b 3 3"],
    query_times: Float[Tensor, "*q"] | float,
    *,
    extrapolate: bool = False,
) -> Float[Tensor, "*query_batch 3 3"]:
    """Planar pose trajectory through timed keyframes (as :func:`so3_interpolate_keyframes`).

    Each segment is :func:`torchlie.se2.interpolate`, the SE(2) geodesic: the heading moves
    linearly and the translation along a circular arc (a straight line where the heading does
    not change).  Same sorting, clamping / ``extrapolate`` rules and shapes as the SO(3)
    version.

    Example:
        >>> times = torch.tensor([0.0, 2.0])
        >>> keys = se2.from_xytheta(torch.tensor([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]]))
        >>> se2.to_xytheta(se2_interpolate_keyframes(times, keys, torch.tensor([1.0, 3.0])))
        tensor([[1., 0., 0.],
                [2., 0., 0.]])
    """
    return _keyframes(_SE2, times, keyframes, query_times, extrapolate)


# ----------------------------------------------------------------------------------------------
# Point-set alignment
# ----------------------------------------------------------------------------------------------


class Alignment(NamedTuple):
    """Result of :func:`align`: ``q ~= scale * rotation @ p + translation``.

    The fields are as they always were; :meth:`matrix` and :meth:`sim3` give the same
    transform as one Sim(3) element (a rigid one, scale 1, without ``scale=True``).
    """

    rotation: Float[Tensor, "*b 3 3"]
    translation: Float[Tensor, "*b 3"]
    scale: Float[Tensor, "*b"]

    def matrix(self) -> Float[Tensor, "*b 4 4"]:
        """``[[scale rotation, translation], [0, 1]]`` (:func:`torchlie.sim3.from_srt`).

        Example:
            >>> P = torch.eye(3)
            >>> align(P, 2.0 * P, scale=True, translation=False).matrix().diagonal()
            tensor([2., 2., 2., 1.])
        """
        return sim3.from_srt(self.scale, self.rotation, self.translation)

    def sim3(self):
        """The transform as a :class:`torchlie.Sim3` (apply it with ``@``).

        Example:
            >>> P = torch.eye(3)
            >>> fit = align(P, 2.0 * P + 1.0, scale=True)
            >>> torch.allclose(fit.sim3() @ P, 2.0 * P + 1.0, atol=1e-6)
            True
        """
        from .groups import Sim3

        return Sim3._wrap(self.matrix())


@_checks.float32_exact
def align(
    P: Float[Tensor, "*b1 N 3"],
    Q: Float[Tensor, "*b2 N 3"],
    weights: Float[Tensor, "*b3 N"] | None = None,
    *,
    scale: bool = False,
    translation: bool = True,
) -> Alignment:
    """Similarity or rigid transform best mapping points ``P`` onto ``Q`` (Kabsch / Umeyama).

    Minimises ``sum_i w_i |s R p_i + t - q_i|^2`` over rotations ``R`` (never reflections),
    translations ``t`` and, with ``scale=True``, scales ``s > 0`` (else ``s = 1``).  With
    ``translation=False``, ``t = 0`` and the points are not centred: the rotation then solves
    Wahba's problem, as ``scipy.spatial.transform.Rotation.align_vectors(Q, P, w)``.

    Closed form: with weighted centroids ``p_bar``, ``q_bar`` and
    ``H = sum_i w_i (q_i - q_bar)(p_i - p_bar)^T``, ``R = so3.project(H)`` (the SVD solution
    with the determinant fixed), ``s = tr(R^T H) / sum_i w_i |p_i - p_bar|^2`` and
    ``t = q_bar - s R p_bar``.  Batch shapes of ``P``, ``Q`` and ``weights`` broadcast; weights
    are non-negative with a positive sum (not checked, which would read their values: others
    give the minimiser of the weighted sum as written, a sum of 0 gives NaN).  Differentiable
    (through :func:`torchlie.so3.project`) wherever the rotation is unique, i.e. the centred
    points are not all collinear; with fewer than three points or collinear points the rotation
    is one of many minimisers and its gradient is not finite.  When ``H = 0``, because the
    points of ``P`` all coincide or those of ``Q`` do (all lie at the origin, with
    ``translation=False``), every rotation fits equally: the identity is returned, with zero
    gradient.  With ``scale=True``, when those of ``P`` coincide every scale fits equally too:
    ``s = 1``, with zero gradient (never NaN); when only those of ``Q`` do, ``s = 0``.
    ``weights`` is a tensor of the dtype of ``P`` or numbers (a list, a numpy array), converted
    to it.  Points of any finite magnitude: each set is scaled by a power of two (from its
    largest coordinate over the points of nonzero weight) before the products are formed, and
    the factors are undone exactly; points of zero weight change nothing, wherever they are.

    Returns:
        :class:`Alignment` ``(rotation (..., 3, 3), translation (..., 3), scale (...))``; its
        ``.sim3()`` is the same transform as a :class:`torchlie.Sim3` and ``.matrix()`` its
        ``(..., 4, 4)`` matrix ``[[s R, t], [0, 1]]``.

    Example:
        >>> P = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
        >>> R = so3.exp(torch.tensor([0.0, 0.0, torch.pi / 2]))
        >>> Q = 2.0 * P @ R.mT + torch.tensor([1.0, 2.0, 3.0])
        >>> fit = align(P, Q, scale=True)
        >>> torch.allclose(fit.rotation, R, atol=1e-6), round(fit.scale.item(), 5)
        (True, 2.0)
        >>> torch.allclose(fit.translation, torch.tensor([1.0, 2.0, 3.0]), atol=1e-5)
        True
    """
    fn = _NAME + "align"
    p, dtype = _checks.tensor(P, fn, "P", (3,))
    q, _ = _checks.tensor(Q, fn, "Q", (3,))
    _checks.same_dtype(fn, P=P, Q=Q)
    scale = _checks.flag(scale, fn, "scale")
    translation = _checks.flag(translation, fn, "translation")
    if p.dim() < 2 or q.dim() < 2 or p.shape[-2] != q.shape[-2] or p.shape[-2] == 0:
        raise ValueError(
            f"{fn}: expected P and Q of shape (..., N, 3) with the same N >= 1, got "
            f"{tuple(P.shape)} and {tuple(Q.shape)}"
        )
    n = p.shape[-2]
    w = None if weights is None else _weights(fn, p, weights, n, ("P", P))
    shapes = [(p.shape[:-2], "P"), (q.shape[:-2], "Q")]
    if w is not None:
        shapes.append((w.shape[:-1], "weights"))
    batch = _checks.batch_broadcast(fn, *shapes)
    if w is None:
        w = torch.full((*batch, n), 1.0 / n, dtype=p.dtype, device=p.device)
    # The fit is equivariant under scaling either set (R unchanged, s and t scaled): each set is
    # divided by a power of two from its largest coordinate, exactly, so that the products in H
    # and the spread neither overflow nor underflow at any finite magnitude; the factors are
    # undone at the end (exactly too).  They are constants: the result's dependence on them is
    # exactly cancelled, so its derivatives are those of the unscaled formula.
    # Points of zero weight do not count (they do not change the fit; far ones would take the
    # others' digits), and are clamped where that scale puts them beyond where products stay
    # finite.
    used = (w != 0).unsqueeze(-1)
    a, b = _binade(p, used), _binade(q, used)
    big = 2.0 ** (math.frexp(torch.finfo(p.dtype).max)[1] // 2 - 4)
    p, q = (p / a).clamp(-big, big), (q / b).clamp(-big, big)
    a, b = a[..., 0, 0], b[..., 0, 0]
    if translation:
        # Centred through the point of largest weight (the first of them; picked exactly, the
        # other terms zero): points that all coincide centre to exactly 0, and a far point of
        # zero weight does not take the others' digits in p - p0.
        top = w.detach().argmax(-1, keepdim=True)
        pick = (torch.arange(n, device=w.device) == top).to(w.dtype)
        p0, q0 = _wsum(pick, p, 1).unsqueeze(-2), _wsum(pick, q, 1).unsqueeze(-2)
        dp, dq = _wsum(w, p - p0, 1), _wsum(w, q - q0, 1)
        p_bar, q_bar = p0.squeeze(-2) + dp, q0.squeeze(-2) + dq
        p = (p - p0) - dp.unsqueeze(-2)
        q = (q - q0) - dq.unsqueeze(-2)
    # H = (w q)^T p and R p_bar as products and sums (not matmul): an element's result has the
    # same bits whatever the batch around it.
    H = _sum((q * w.unsqueeze(-1)).unsqueeze(-1) * p.unsqueeze(-2), -3)
    # H = 0 (the weighted points of P, or those of Q, all at one place): every rotation fits
    # equally; the identity is returned with zero gradient (project's backward would be 0/0).
    flat = (H == 0).all(dim=-1).all(dim=-1)[..., None, None]
    R = so3.project(torch.where(flat, torch.eye(3, dtype=H.dtype, device=H.device), H))
    if scale:
        # All points of P at one place (zero spread): every scale fits equally, and s = 1 is
        # returned, with zero gradient (the double where keeps 0/0 out of the backward too).
        # A NaN spread (NaN or inf in P or the weights) gives a NaN scale, not that 1.
        spread = _sum(w * _sum(p * p, -1), -1)
        some = spread != 0
        s = _sum(R * H, (-1, -2)) / torch.where(some, spread, torch.ones_like(spread))
        s = torch.where(some, s, torch.ones_like(s))  # (of the scaled sets)
        if translation:  # t = b (q_bar - s R p_bar) of the scaled sets
            t = (q_bar - s.unsqueeze(-1) * _sum(R * p_bar.unsqueeze(-2), -1)) * b.unsqueeze(-1)
        s = torch.where(some, s * (b / a), s)
    else:
        s = torch.ones(batch, dtype=p.dtype, device=p.device)
        if translation:
            t = q_bar * b.unsqueeze(-1) - _sum(R * p_bar.unsqueeze(-2), -1) * a.unsqueeze(-1)
    if not translation:
        t = torch.zeros((*batch, 3), dtype=p.dtype, device=p.device)
    return Alignment(_checks.out(R, dtype), _checks.out(t, dtype), _checks.out(s, dtype))


# ----------------------------------------------------------------------------------------------
# Kinematics
# ----------------------------------------------------------------------------------------------


def _integrate(g: _Group, X: Tensor, v: Tensor, dt: Tensor | float, frame: str) -> Tensor:
    fn = _NAME + g.name + "_integrate"
    if frame not in ("body", "world"):
        raise ValueError(f"{fn}: expected frame 'body' or 'world', got {frame!r}")
    # the public argument names: a rotation and its angular velocity, or an element and its twist
    nx, nv = ("T", "xi") if g.affine else ("R", "omega")
    x, dtype = _checks.tensor(X, fn, nx, (g.n, g.n))
    vel, _ = _checks.tensor(v, fn, nv, (g.dof,))
    _checks.same_dtype(fn, **{nx: X, nv: v})
    h = _checks.real(dt, fn, "dt", x, (nx, X))
    _checks.batch_broadcast(fn, (x.shape[:-2], nx), (vel.shape[:-1], nv), (h.shape, "dt"))
    step = h.unsqueeze(-1) * vel
    out = g.core.rplus(x, step) if frame == "body" else g.core.lplus(x, step)
    return _checks.out(out, dtype)


@_checks.float32_exact
def so3_integrate(
    R: Float[Tensor, "*b1 3 3"],
    omega: Float[Tensor, "*b2 3"],
    dt: Float[Tensor, "*b3"] | float,
    frame: str = "body",
) -> Float[Tensor, "*b 3 3"]:
    """Rotation after rotating at a constant angular velocity ``omega`` for ``dt`` (exact).

    ``frame="body"``: ``omega`` in the body frame, ``R Exp(omega dt)``; ``frame="world"``:
    ``omega`` in the world frame, ``Exp(omega dt) R``.  They agree when
    ``omega_world = R omega_body``.  Batch shapes of ``R``, ``omega`` and ``dt`` broadcast.

    Example:
        >>> R = so3_integrate(torch.eye(3), torch.tensor([0.0, 0.0, 2.0]), 0.25)
        >>> so3.log(R)
        tensor([0.0000, 0.0000, 0.5000])
    """
    return _integrate(_SO3, R, omega, dt, frame)


@_checks.float32_exact
def se3_integrate(
    T: Float[Tensor, "*b1 4 4"],
    xi: Float[Tensor, "*b2 6"],
    dt: Float[Tensor, "*b3"] | float,
    frame: str = "body",
) -> Float[Tensor, "*b 4 4"]:
    """Pose after moving with a constant twist ``xi = (v, omega)`` for ``dt`` (exact).

    ``frame="body"``: ``xi`` is the body twist (linear and angular velocity in the body frame),
    ``T Exp(xi dt)``; ``frame="world"``: ``xi`` is the spatial twist, ``Exp(xi dt) T``.  They
    agree when ``xi_world = Ad_T xi_body``.  A constant body twist traces a screw (a helix),
    not a straight line.  Batch shapes of ``T``, ``xi`` and ``dt`` broadcast.

    Example:
        >>> xi = torch.tensor([1.0, 0.0, 0.0, 0.0, 0.0, torch.pi])  # drive forward, turn left
        >>> T = se3_integrate(torch.eye(4), xi, 1.0)  # half a circle of radius 1/pi
        >>> torch.allclose(se3.to_rt(T)[1], torch.tensor([0.0, 2 / torch.pi, 0.0]), atol=1e-6)
        True
    """
    return _integrate(_SE3, T, xi, dt, frame)


@_checks.float32_exact
def sim3_integrate(
    T: Float[Tensor, "*b1 4 4"],
    xi: Float[Tensor, "*b2 7"],
    dt: Float[Tensor, "*b3"] | float,
    frame: str = "body",
) -> Float[Tensor, "*b 4 4"]:
    """Similarity after moving with a constant velocity ``xi = (v, omega, sigma_dot)`` for
    ``dt`` (exact).

    ``frame="body"``: ``xi`` in the body frame, ``T Exp(xi dt)``; ``frame="world"``: ``xi`` in
    the world frame, ``Exp(xi dt) T``.  They agree when ``xi_world = Ad_T xi_body``
    (:func:`torchlie.sim3.adjoint`).  ``sigma_dot`` is the rate of the log scale: the scale is
    multiplied by ``exp(sigma_dot dt)``.  Batch shapes of ``T``, ``xi`` and ``dt`` broadcast.

    Example:
        >>> xi = torch.tensor([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.5])  # the log scale's rate
        >>> sim3.scale(sim3_integrate(torch.eye(4), xi, 2.0))
        tensor(2.7183)
    """
    return _integrate(_SIM3, T, xi, dt, frame)


@_checks.float32_exact
def so2_integrate(
    R: Float[Tensor, "*b1 2 2"],
    omega: Float[Tensor, "*b2 1"],
    dt: Float[Tensor, "*b3"] | float,
    frame: str = "body",
) -> Float[Tensor, "*b 2 2"]:
    """Planar rotation after turning at a constant rate ``omega`` ``(..., 1)`` for ``dt`` (exact).

    ``R Exp(omega dt)``; the group is commutative, so ``frame="body"`` and ``frame="world"``
    (``Exp(omega dt) R``) agree (both are accepted, as for the other groups).  Batch shapes of
    ``R``, ``omega`` and ``dt`` broadcast.

    Example:
        >>> so2.log(so2_integrate(torch.eye(2), torch.tensor([2.0]), 0.25))
        tensor([0.5000])
    """
    return _integrate(_SO2, R, omega, dt, frame)


@_checks.float32_exact
def se2_integrate(
    T: Float[Tensor, "*b1 3 3"],
    xi: Float[Tensor, "*b2 3"],
    dt: Float[Tensor, "*b3"] | float,
    frame: str = "body",
) -> Float[Tensor, "*b 3 3"]:
    """Planar pose after moving with a constant twist ``xi = (v_x, v_y, omega)`` for ``dt``
    (exact).

    ``frame="body"``: ``xi`` is the body twist, ``T Exp(xi dt)`` (a unicycle's forward speed and
    yaw rate trace a circular arc); ``frame="world"``: ``xi`` is the spatial twist,
    ``Exp(xi dt) T``.  They agree when ``xi_world = Ad_T xi_body`` (:func:`torchlie.se2.adjoint`).
    Batch shapes of ``T``, ``xi`` and ``dt`` broadcast.

    Example:
        >>> xi = torch.tensor([1.0, 0.0, torch.pi])  # drive forward, turn left
        >>> T = se2_integrate(torch.eye(3), xi, 1.0)  # half a circle of radius 1/pi
        >>> torch.allclose(se2.to_xytheta(T)[:2], torch.tensor([0.0, 2 / torch.pi]), atol=1e-6)
        True
    """
    return _integrate(_SE2, T, xi, dt, frame)
