"""SO(3): rotation matrices ``(..., 3, 3)`` and rotation vectors ``(..., 3)``.

Conventions (see :mod:`torchlie`): matrices act on column vectors, ``p_world = R @ p_body``;
the tangent vector is the rotation vector ``omega = theta * axis``; perturbations are on the
right, ``R (+) d = R Exp(d)``.  :func:`log` returns ``theta`` in ``[0, pi]``; at exactly pi the
sign of the axis follows :mod:`torchlie.quaternion`'s canonical rule (largest-magnitude axis
component positive).

Jacobians (``Jr(w)`` = ``jac_right``, ``Jl(w)`` = ``jac_left``)::

    Exp(w + d) ~= Exp(w) Exp(Jr(w) d) ~= Exp(Jl(w) d) Exp(w)
    Jl(w) = I + B hat(w) + C hat(w)^2,   Jr(w) = Jl(-w) = Jl(w)^T
    B = (1 - cos t)/t^2,  C = (t - sin t)/t^3
    Jl^-1(w) = I - hat(w)/2 + D hat(w)^2,  D = (1 - (t/2) cot(t/2))/t^2

Matrices off SO(3): an argument documented as a rotation is taken to be one up to rounding; its
values are not checked (that would synchronise a device: :func:`is_valid` checks explicitly).
The log maps (:func:`log` and what is built on it: :func:`rminus`, :func:`lminus`,
:func:`interpolate`, :func:`torchlie.se3.log`, :func:`torchlie.quaternion.from_matrix`, the
matrix-to-X conversions) correct deviations of first order: they read ``R`` as its nearest
rotation ``project(R)`` up to ``O(|R^T R - I|^2)``, so rounding drift costs nothing.  A matrix
farther from SO(3) (a scaled rotation ``s R`` with ``s`` not near 1, a reflection, an arbitrary
matrix) gives an unspecified result, not an error: ``log(2 * I)`` is not ``0``.  Pass such
matrices through :func:`project` first.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from . import _checks, _coeffs, _components, _layout, _rodrigues, _rotation_matrix
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
    "jac_left",
    "jac_right",
    "jac_left_inv",
    "jac_right_inv",
    "identity",
    "random",
    "is_valid",
    "project",
    "distance",
    "interpolate",
    # Lie-group operations and their Jacobians
    "ad",
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

_NAME = "torchlie.so3."


# ----------------------------------------------------------------------------------------------
# exp / log with closed-form derivatives
# ----------------------------------------------------------------------------------------------


def _exp(w: Sequence[Tensor]) -> Tensor:
    """Forward of :func:`exp` from the planes of the (reduced) rotation vectors (runs without
    autograd: forward-only coefficients)."""
    o = _layout.outputs(w[0], 9)
    return _layout.interleave(_exp_entries(w, o), o).unflatten(-1, (3, 3))


def _exp_entries(w: Sequence[Tensor], out: Sequence[Tensor | None] = (None,) * 9) -> list[Tensor]:
    """The entries of :func:`_exp` (row by row, written to ``out``): for callers that build
    a larger matrix from them where nothing is differentiated."""
    xyz, (a, b, d) = _rodrigues.coefficients(w, "abd")
    return _rodrigues.exp_entries(xyz, a, b, d, out)


def _exp_grad(w: Sequence[Tensor], R: Tensor, g: Tensor) -> list[Tensor]:
    # dL/dw = Jl(w) vee(R^T G - G^T R) (full vee, i.e. twice the skew part's), on the planes of
    # the guarded w, to the guard's derivative as planes; coefficients that differentiate
    # under create_graph
    v = _components.rt_g_vee(R, g)
    return _rodrigues.jl_apply(w, v, stacked=False, differentiable=torch.is_grad_enabled())


def _exp_jvp(saved, dw: Tensor) -> Tensor:
    w, R = saved
    return R @ _components.hat(_rodrigues.jl_apply(w, dw, sign=-1.0))


_ExpMapFn = CustomFunction(
    "So3Exp",
    forward=lambda w: _exp(_coeffs.reduced_planes_of(w)),
    save=lambda inputs, out: (inputs[0], out),
    backward=lambda saved, g: (_exp_grad(*saved, g),),
    jvp=_exp_jvp,
    event_dims=(1,),
    guard=_coeffs.REDUCE,  # the angle reduced modulo 2 pi where it is too large for the formulas
)


def _log(R: Tensor) -> Tensor:
    """Forward of :func:`log` (runs without autograd)."""
    return _rotation_matrix.log(R)


def _log_grad(R: Tensor, w: Tensor, g: Tensor) -> Tensor:
    # Gradient of log o polar: G = R hat(Jl^-1(w) g) / 2 (tangent part only); where the
    # backward is differentiated, with the terms that make it that gradient off SO(3) as well.
    graph = torch.is_grad_enabled()
    u = _rodrigues.jl_apply(w, 0.5 * g, inverse=True, stacked=False, differentiable=graph)
    G = _components.r_hat(R, u)
    if graph:
        H = _components.hat(torch.stack(tuple(u), dim=-1))
        G = G - _components.polar_backward_terms(R, H, _components.gram_defect(R))
    return G


_log_grad_blocked = blocked(_log_grad, (2, 1, 1))


def _log_jvp(saved, dR: Tensor) -> Tensor:
    R, w = saved
    d = _components.polar_tangent(R.transpose(-1, -2) @ dR, _components.gram_defect(R))
    return _rodrigues.jl_apply(w, d, sign=-1.0, inverse=True)


_LogFn = CustomFunction(
    "So3Log",
    forward=_log,
    save=lambda inputs, out: (inputs[0], out),
    backward=lambda saved, g: (_log_grad_blocked(*saved, g),),
    jvp=_log_jvp,
    event_dims=(2,),
)


@_checks.float32_exact
def hat(omega: Float[Tensor, "*b 3"]) -> Float[Tensor, "*b 3 3"]:
    """Skew-symmetric matrix with ``hat(w) @ v == cross(w, v)``.

    Example:
        >>> hat(torch.tensor([1.0, 2.0, 3.0]))
        tensor([[ 0., -3.,  2.],
                [ 3.,  0., -1.],
                [-2.,  1.,  0.]])
    """
    x, dtype = _checks.tensor(omega, _NAME + "hat", "omega", (3,))
    return _checks.out(_components.hat(x), dtype)


@_checks.float32_exact
def vee(Omega: Float[Tensor, "*b 3 3"]) -> Float[Tensor, "*b 3"]:
    """Inverse of :func:`hat`, applied to the skew-symmetric part ``(M - M^T)/2``.

    Example:
        >>> vee(hat(torch.tensor([1.0, 2.0, 3.0])))
        tensor([1., 2., 3.])
    """
    x, dtype = _checks.tensor(Omega, _NAME + "vee", "Omega", (3, 3))
    return _checks.out(_components.vee(x), dtype)


@_checks.float32_exact
def exp(omega: Float[Tensor, "*b 3"]) -> Float[Tensor, "*b 3 3"]:
    """Rotation matrix of the rotation vector ``omega`` (Rodrigues' formula).

    ``R = cos(t) I + sin(t)/t hat(w) + (1 - cos t)/t^2 w w^T`` with ``t = |w|``, exact to a few ulp
    for angles up to a few radians (half-angle forms, no cancellation; float32 input takes its
    coefficients in float64, and is exact at every angle).  Beyond that, in float64, the error is
    that of ``t`` rounded to float64, about ``t / 3`` ulp (333 at 1000 rad).  The backward pass is
    the closed form ``dL/dw = Jl(w) vee(R^T G - G^T R)``; double backward and forward mode are
    supported.

    Example:
        >>> exp(torch.tensor([0.0, 0.0, torch.pi / 2])).round(decimals=6) + 0.0
        tensor([[ 0., -1.,  0.],
                [ 1.,  0.,  0.],
                [ 0.,  0.,  1.]])
    """
    x, dtype = _checks.tensor(omega, _NAME + "exp", "omega", (3,))
    return _checks.out(_ExpMapFn(x), dtype)


@_checks.float32_exact
def log(R: Float[Tensor, "*b 3 3"]) -> Float[Tensor, "*b 3"]:
    """Rotation vector of ``R``: angle in ``[0, pi]`` times the unit axis.

    Values: through :func:`torchlie.quaternion.from_matrix` (Shepperd's method, robust at pi)
    and ``2 atan2(|v|, w)``, accurate to a few ulp at every angle.  At exactly pi the axis sign
    follows the canonical rule (largest-magnitude component positive).

    Gradient meaning: the backward pass returns the gradient of ``log o polar`` (``polar`` is
    the nearest-rotation projection), ``G = R hat(Jl(w)^-1 g) / 2``: the exact derivative along
    every tangent direction ``R hat(d)`` (``Jr(w)^-1 d``) and zero along the normal directions
    ``R S`` (``S`` symmetric).  It is finite at ``theta = pi``, where the naive formula's
    derivative is infinite, and it equals any other correct derivative whenever ``R`` is built
    by a valid rotation construction.  The forward pass reads ``R`` as its nearest rotation to
    first order (see :func:`torchlie.quaternion.from_matrix`), so it agrees with that gradient
    and plain ``gradcheck`` on a raw rotation matrix passes.

    ``R`` must be a rotation up to first-order deviations; other matrices (``2 * I``, a scaled
    or reflected rotation) give an unspecified result: see "Matrices off SO(3)" in
    :mod:`torchlie.so3`.

    Example:
        >>> log(torch.diag(torch.tensor([1.0, -1.0, -1.0])))
        tensor([3.1416, 0.0000, 0.0000])
    """
    x, dtype = _checks.tensor(R, _NAME + "log", "R", (3, 3))
    return _checks.out(_LogFn(x), dtype)


# ----------------------------------------------------------------------------------------------
# Group operations
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def compose(R1: Float[Tensor, "*b1 3 3"], R2: Float[Tensor, "*b2 3 3"]) -> Float[Tensor, "*b 3 3"]:
    """``R1 @ R2`` (batch shapes broadcast).

    Example:
        >>> Rz = exp(torch.tensor([0.0, 0.0, 0.5]))
        >>> torch.allclose(compose(Rz, Rz), exp(torch.tensor([0.0, 0.0, 1.0])))
        True
    """
    a, b, dtype, _ = _checks.pair(_NAME + "compose", R1, R2, "R1", "R2", (3, 3), (3, 3))
    return _checks.out(a @ b, dtype)


@_checks.float32_exact
def inverse(R: Float[Tensor, "*b 3 3"]) -> Float[Tensor, "*b 3 3"]:
    """``R^T`` (the inverse of a rotation), a new tensor (not a view of ``R``).

    Example:
        >>> R = exp(torch.tensor([0.1, 0.2, 0.3]))
        >>> torch.allclose(inverse(R) @ R, torch.eye(3), atol=1e-6)
        True
    """
    x, dtype = _checks.tensor(R, _NAME + "inverse", "R", (3, 3))
    return _checks.out(x.transpose(-1, -2).clone(memory_format=torch.contiguous_format), dtype)


@_checks.float32_exact
def act(R: Float[Tensor, "*b1 3 3"], points: Float[Tensor, "*b2 3"]) -> Float[Tensor, "*b 3"]:
    """Rotate points: ``R @ p`` (batch shapes broadcast).

    Example:
        >>> act(exp(torch.tensor([0.0, 0.0, torch.pi / 2])), torch.tensor([1.0, 0.0, 0.0]))
        tensor([-4.3711e-08,  1.0000e+00,  0.0000e+00])
    """
    a, p, dtype, _ = _checks.pair(_NAME + "act", R, points, "R", "points", (3, 3), (3,))
    return _checks.out(_ActFn(a, p), dtype)


def _act_grads(R: Tensor, p: Tensor, g: Tensor) -> tuple[Tensor, Tensor]:
    """``dR = g p^T``, ``dp = R^T g``."""
    return g.unsqueeze(-1) * p.unsqueeze(-2), _components.mtv(R, g)


_act_grads_blocked = blocked(_act_grads, (2, 1, 1))


def _act_backward(saved: tuple[Tensor, ...], g: Tensor) -> tuple[Tensor, Tensor]:
    R, p = saved
    dR, dp = _act_grads_blocked(R, p, g)  # recorded as it is under create_graph
    return dR.sum_to_size(R.shape), dp.sum_to_size(p.shape)


_ActFn = CustomFunction(
    "So3Act",
    forward=_components.mv,
    save=lambda inputs, out: (inputs[0], inputs[1]),
    backward=_act_backward,
    jvp=lambda saved, dR, dp: _components.mv(dR, saved[1]) + _components.mv(saved[0], dp),
    event_dims=(2, 1),
)


@_checks.float32_exact
def adjoint(R: Float[Tensor, "*b 3 3"]) -> Float[Tensor, "*b 3 3"]:
    """Adjoint matrix of SO(3), ``Ad_R = R`` (so ``R Exp(w) R^T = Exp(R w)``).

    Example:
        >>> torch.equal(adjoint(torch.eye(3)), torch.eye(3))
        True
    """
    x, dtype = _checks.tensor(R, _NAME + "adjoint", "R", (3, 3))
    return _checks.out(x.clone(), dtype)


def _jac(fn: str, omega: Tensor, kind: str) -> Tensor:
    w, dtype = _checks.tensor(omega, _NAME + fn, "omega", (3,))
    return _checks.out(_rodrigues.jac_matrix(w, kind), dtype)


@_checks.float32_exact
def jac_left(omega: Float[Tensor, "*b 3"]) -> Float[Tensor, "*b 3 3"]:
    """Left Jacobian ``Jl(w) = I + (1-cos t)/t^2 hat(w) + (t - sin t)/t^3 hat(w)^2``.

    ``Exp(w + d) ~= Exp(Jl(w) d) Exp(w)``.

    Example:
        >>> torch.equal(jac_left(torch.zeros(3)), torch.eye(3))
        True
    """
    return _jac("jac_left", omega, "left")


@_checks.float32_exact
def jac_right(omega: Float[Tensor, "*b 3"]) -> Float[Tensor, "*b 3 3"]:
    """Right Jacobian ``Jr(w) = Jl(-w) = Jl(w)^T``; ``Exp(w + d) ~= Exp(w) Exp(Jr(w) d)``.

    Example:
        >>> w = torch.tensor([0.3, -0.2, 0.5])
        >>> torch.allclose(jac_right(w), jac_left(w).mT)
        True
    """
    return _jac("jac_right", omega, "right")


@_checks.float32_exact
def jac_left_inv(omega: Float[Tensor, "*b 3"]) -> Float[Tensor, "*b 3 3"]:
    """``Jl(w)^-1 = I - hat(w)/2 + (1 - (t/2)cot(t/2))/t^2 hat(w)^2``, finite for ``t < 2 pi``.

    Example:
        >>> w = torch.tensor([0.3, -0.2, 0.5])
        >>> torch.allclose(jac_left_inv(w) @ jac_left(w), torch.eye(3), atol=1e-6)
        True
    """
    return _jac("jac_left_inv", omega, "left_inv")


@_checks.float32_exact
def jac_right_inv(omega: Float[Tensor, "*b 3"]) -> Float[Tensor, "*b 3 3"]:
    """``Jr(w)^-1 = Jl(-w)^-1``: the derivative of :func:`log` in right-perturbation coordinates.

    Example:
        >>> w = torch.tensor([0.3, -0.2, 0.5])
        >>> torch.allclose(jac_right_inv(w) @ jac_right(w), torch.eye(3), atol=1e-6)
        True
    """
    return _jac("jac_right_inv", omega, "right_inv")


# ----------------------------------------------------------------------------------------------
# Construction, validation, projection
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def identity(
    *batch: int, dtype: torch.dtype | None = None, device: torch.device | str | None = None
) -> Float[Tensor, "*batch 3 3"]:
    """Identity rotations of shape ``(*batch, 3, 3)``.

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
    """Haar-uniform random rotations (normalised Gaussian quaternions).

    float16/bfloat16 are drawn and computed in float32, then cast (as
    :func:`torchlie.quaternion.random`).

    Example:
        >>> R = random(4, generator=torch.Generator().manual_seed(0))
        >>> bool(is_valid(R).all())
        True
    """
    compute, dtype = _checks.factory(_NAME + "random", batch, dtype)
    q = torch.randn(*batch, 4, generator=generator, dtype=compute, device=device)
    return _checks.out(_rotation_matrix.from_quaternion(q), dtype)


@_checks.float32_exact
def is_valid(R: Float[Tensor, "*b 3 3"], atol: float | None = None) -> Bool[Tensor, "*b"]:
    """Per element: finite, ``R^T R = I`` and ``det R = 1`` within ``atol``.

    ``atol`` (a non-negative finite real number) defaults to ``100 * eps`` of the input dtype
    (about 1.2e-5 for float32; ``4 * eps`` for float16/bfloat16).  This reads the
    values, so use it outside hot loops on a GPU (the result is a tensor; nothing syncs until
    you branch on it).

    Example:
        >>> is_valid(torch.stack((torch.eye(3), 2 * torch.eye(3))))
        tensor([ True, False])
    """
    x, _ = _checks.tensor(R, _NAME + "is_valid", "R", (3, 3))
    tol = _checks.tolerance(atol, _NAME + "is_valid", "atol", R.dtype)
    eye = torch.eye(3, dtype=x.dtype, device=x.device)
    orth = (x.transpose(-1, -2) @ x - eye).abs().amax(dim=(-1, -2)) <= tol
    det = (torch.linalg.det(x) - 1.0).abs() <= tol
    return orth & det & torch.isfinite(x).all(dim=-1).all(dim=-1)


def _project_forward(M: Tensor) -> Tensor:
    # The SVD raises for the whole batch if any element is not finite: such elements are
    # decomposed as the identity and come back as NaN, each alone.
    finite = torch.isfinite(M).all(dim=-1).all(dim=-1)[..., None, None]
    eye = torch.eye(3, dtype=M.dtype, device=M.device)
    U, S, Vh = torch.linalg.svd(torch.where(finite, M, eye))
    d = torch.sign(torch.linalg.det(U) * torch.linalg.det(Vh))
    d = torch.where(d == 0, torch.ones_like(d), d)
    Vh = torch.cat((Vh[..., :2, :], Vh[..., 2:, :] * d[..., None, None]), dim=-2)
    # U @ Vh as products and a sum over k: the same bits for an element whatever the batch
    # around it (a batched 3 x 3 matmul need not round like the unbatched one).
    R = (U.unsqueeze(-1) * Vh.unsqueeze(-3)).sum(-2)
    return torch.where(finite, R, torch.full_like(M, float("nan")))


def _polar_system(M: Tensor, R: Tensor):
    """``(finite, R, B, k)``: ``B = tr(P) I - P`` for the symmetric factor ``P = R^T M / k``
    (non-finite elements as the identity), ``k`` the power of two of the largest ``|M_ij|``
    (:func:`torchlie._coeffs.power_of_two`, detached): the sums of ``P`` then stay far from
    overflow (``tr(P)`` overflowed from a third of the largest float), and ``B^-1 / k`` is the
    system's inverse, the same bits as unscaled where no entry is subnormal.  For symmetric
    ``P``, ``P hat(x) + hat(x) P = hat(B x)``."""
    finite = torch.isfinite(R).all(dim=-1).all(dim=-1)[..., None, None]
    eye = torch.eye(3, dtype=M.dtype, device=M.device)
    R = torch.where(finite, R, eye)
    M = torch.where(finite, M, eye)
    k = _coeffs.power_of_two(M.detach().abs().amax((-1, -2), keepdim=True))
    P = R.transpose(-1, -2) @ (M / k)
    P = 0.5 * (P + P.transpose(-1, -2))
    B = P.diagonal(0, -2, -1).sum(-1)[..., None, None] * eye - P
    return finite, R, B, k


def _solve3(B: Tensor, w: Tensor) -> Tensor:
    """``B^-1 w`` (``inv_ex`` without its check: a singular ``B`` gives Inf/NaN for that
    element, never an error or a device sync).  The inverse, not ``solve_ex``: torch's
    forward-over-forward derivative of ``solve`` is wrong, that of ``inv`` right."""
    return (torch.linalg.inv_ex(B, check_errors=False)[0] @ w.unsqueeze(-1)).squeeze(-1)


def _r_hat(R: Tensor, z: Tensor) -> Tensor:
    """``R hat(z)``: row ``i`` is ``R_i x z``."""
    return torch.linalg.cross(R, z.unsqueeze(-2).expand_as(R), dim=-1)


def _project_backward(saved, g: Tensor):
    # Polar decomposition M = R P (P symmetric): dR = R hat(x) with P hat(x) + hat(x) P =
    # hat(B x) = R^T dM - dM^T R, B = tr(P) I - P.  Its eigenvalues are the sums s_i + s_j of
    # two signed singular values: B is invertible wherever the projection is differentiable,
    # rotations included, and no eigenbasis is formed (an eigenbasis has no derivative at
    # repeated singular values, so the second derivatives at rotations would be wrong).
    finite, R, B, k = _polar_system(*saved)
    grad = _r_hat(R, _solve3(B, _components.skew_vee(R.transpose(-1, -2) @ g)) / k[..., 0])
    # a non-finite element (NaN output) passes no gradient: the others stay clean
    return (torch.where(finite, grad, torch.zeros_like(grad)),)


def _project_jvp(saved, dM: Tensor) -> Tensor:
    finite, R, B, k = _polar_system(*saved)
    out = _r_hat(R, _solve3(B, _components.skew_vee(R.transpose(-1, -2) @ dM)) / k[..., 0])
    return torch.where(finite, out, torch.full_like(out, float("nan")))


_ProjectFn = CustomFunction(
    "So3Project",
    forward=_project_forward,
    save=lambda inputs, out: (inputs[0], out),
    backward=_project_backward,
    jvp=_project_jvp,
    event_dims=(2,),
)


@_checks.float32_exact
def project(M: Float[Tensor, "*b 3 3"]) -> Float[Tensor, "*b 3 3"]:
    """Nearest rotation to ``M`` in the Frobenius norm (SVD with the determinant fixed).

    ``U diag(1, 1, det(U V^T)) V^T``.  Differentiable: the backward pass solves the polar
    decomposition's Sylvester equation, which is well defined whenever the two smallest signed
    singular values do not sum to zero, including at rotations, where the SVD's own backward
    divides by zero.

    Example:
        >>> R = project(torch.eye(3) + 0.01)
        >>> bool(is_valid(R))
        True
    """
    x, dtype = _checks.tensor(M, _NAME + "project", "M", (3, 3))
    return _checks.out(_ProjectFn(x), dtype)


# ----------------------------------------------------------------------------------------------
# Metrics and interpolation
# ----------------------------------------------------------------------------------------------


@_checks.float32_exact
def distance(R1: Float[Tensor, "*b1 3 3"], R2: Float[Tensor, "*b2 3 3"]) -> Float[Tensor, "*b"]:
    """Geodesic distance: the angle of ``R1^T R2`` in ``[0, pi]``.

    Computed as ``atan2(|vee(M)|, (tr M - 1)/2)``, accurate at every angle.  The angle is not
    differentiable at 0 and at pi (it is a cone and a ridge there); the gradient returned at those
    points is the zero subgradient, always finite.  Between them its derivatives are the true
    ones, at right angles too.

    Example:
        >>> distance(torch.eye(3), exp(torch.tensor([0.0, 0.3, 0.0])))
        tensor(0.3000)
    """
    a, b, dtype, _ = _checks.pair(_NAME + "distance", R1, R2, "R1", "R2", (3, 3), (3, 3))
    return _checks.out(_rotation_matrix.angle(a.transpose(-1, -2) @ b), dtype)


@_checks.float32_exact
def interpolate(
    R0: Float[Tensor, "*b1 3 3"], R1: Float[Tensor, "*b2 3 3"], t: Float[Tensor, "*b3"] | float
) -> Float[Tensor, "*b 3 3"]:
    """Geodesic interpolation ``R0 Exp(t Log(R0^T R1))`` (``t`` broadcasts with the batch).

    ``t = 0`` gives ``R0``, ``t = 1`` gives ``R1``; other ``t`` extrapolate along the geodesic.
    When ``R0^T R1`` is a rotation by exactly pi the path follows the canonical axis.  ``t`` is a
    tensor of the dtype of ``R0`` or numbers (a float, numpy scalar or array, or a list),
    converted to it; not a bool.

    Example:
        >>> Rz = exp(torch.tensor([0.0, 0.0, 1.0]))
        >>> torch.allclose(interpolate(torch.eye(3), Rz, 0.5), exp(torch.tensor([0.0, 0.0, 0.5])))
        True
    """
    fn = _NAME + "interpolate"
    a, dtype = _checks.tensor(R0, fn, "R0", (3, 3))
    b, _ = _checks.tensor(R1, fn, "R1", (3, 3))
    _checks.same_dtype(fn, R0=R0, R1=R1)
    t = _checks.real(t, fn, "t", a, ("R0", R0))
    _checks.batch_broadcast(fn, (a.shape[:-2], "R0"), (b.shape[:-2], "R1"), (t.shape, "t"))
    w = _LogFn(a.transpose(-1, -2) @ b)
    return _checks.out(a @ _ExpMapFn(t.unsqueeze(-1) * w), dtype)


# ----------------------------------------------------------------------------------------------
# Lie-group operations and their Jacobians
# ----------------------------------------------------------------------------------------------
#
# Jacobians of operations follow Sola et al., "A micro Lie theory for state estimation in
# robotics" (and manif): for Y = f(X), J_Y_X maps a right perturbation of the input to a right
# perturbation of the output, f(X Exp(d)) ~= f(X) Exp(J_Y_X d); vector arguments and results
# (points, rotation vectors) are perturbed by plain addition.  Functions returning two Jacobians
# return them in the order of the arguments.  The Jacobians of exp and log are
# jac_right(omega) and jac_right_inv(log(R)).


def _eye3(batch: torch.Size, like: Tensor) -> Tensor:
    return torch.eye(3, dtype=like.dtype, device=like.device).expand(*batch, 3, 3).clone()


@_checks.float32_exact
def ad(omega: Float[Tensor, "*b 3"]) -> Float[Tensor, "*b 3 3"]:
    """Small adjoint of so(3): ``ad(w) = hat(w)``, so ``ad(x) y = x cross y`` (the Lie bracket).

    ``adjoint(exp(w)) = matrix_exp(ad(w))``.

    Example:
        >>> ad(torch.tensor([0.0, 0.0, 1.0])) @ torch.tensor([1.0, 0.0, 0.0])
        tensor([0., 1., 0.])
    """
    x, dtype = _checks.tensor(omega, _NAME + "ad", "omega", (3,))
    return _checks.out(_components.hat(x), dtype)


@_checks.float32_exact
def rplus(R: Float[Tensor, "*b1 3 3"], tau: Float[Tensor, "*b2 3"]) -> Float[Tensor, "*b 3 3"]:
    """Right plus ``R (+) tau = R Exp(tau)`` (``tau`` in the body frame; batches broadcast).

    Example:
        >>> R = rplus(identity(), torch.tensor([0.0, 0.0, 0.3]))
        >>> log(R)
        tensor([0.0000, 0.0000, 0.3000])
    """
    x, v, dtype, _ = _checks.pair(_NAME + "rplus", R, tau, "R", "tau", (3, 3), (3,))
    return _checks.out(x @ _ExpMapFn(v), dtype)


@_checks.float32_exact
def rminus(R1: Float[Tensor, "*b1 3 3"], R0: Float[Tensor, "*b2 3 3"]) -> Float[Tensor, "*b 3"]:
    """Right minus ``R1 (-) R0 = Log(R0^T R1)``, so that ``rplus(R0, rminus(R1, R0)) == R1``.

    The gradient meaning of :func:`log` applies.

    Example:
        >>> R0 = exp(torch.tensor([0.1, 0.2, 0.3]))
        >>> tau = torch.tensor([0.3, -0.2, 0.5])
        >>> torch.allclose(rminus(rplus(R0, tau), R0), tau, atol=1e-6)
        True
    """
    a, b, dtype, _ = _checks.pair(_NAME + "rminus", R1, R0, "R1", "R0", (3, 3), (3, 3))
    return _checks.out(_LogFn(b.transpose(-1, -2) @ a), dtype)


@_checks.float32_exact
def lplus(R: Float[Tensor, "*b1 3 3"], tau: Float[Tensor, "*b2 3"]) -> Float[Tensor, "*b 3 3"]:
    """Left plus ``Exp(tau) R`` (``tau`` in the world frame; batches broadcast).

    Example:
        >>> R = exp(torch.tensor([0.1, 0.2, 0.3]))
        >>> torch.allclose(lplus(R, torch.zeros(3)), R)
        True
    """
    x, v, dtype, _ = _checks.pair(_NAME + "lplus", R, tau, "R", "tau", (3, 3), (3,))
    return _checks.out(_ExpMapFn(v) @ x, dtype)


@_checks.float32_exact
def lminus(R1: Float[Tensor, "*b1 3 3"], R0: Float[Tensor, "*b2 3 3"]) -> Float[Tensor, "*b 3"]:
    """Left minus ``Log(R1 R0^T)``, so that ``lplus(R0, lminus(R1, R0)) == R1``.

    Example:
        >>> R0 = exp(torch.tensor([0.1, 0.2, 0.3]))
        >>> tau = torch.tensor([0.3, -0.2, 0.5])
        >>> torch.allclose(lminus(lplus(R0, tau), R0), tau, atol=1e-6)
        True
    """
    a, b, dtype, _ = _checks.pair(_NAME + "lminus", R1, R0, "R1", "R0", (3, 3), (3, 3))
    return _checks.out(_LogFn(a @ b.transpose(-1, -2)), dtype)


@_checks.float32_exact
def between(R0: Float[Tensor, "*b1 3 3"], R1: Float[Tensor, "*b2 3 3"]) -> Float[Tensor, "*b 3 3"]:
    """Relative rotation ``R0^T R1`` (``R1`` expressed in the frame of ``R0``).

    Example:
        >>> R0 = exp(torch.tensor([0.0, 0.0, 0.2]))
        >>> R1 = exp(torch.tensor([0.0, 0.0, 0.5]))
        >>> log(between(R0, R1))
        tensor([0.0000, 0.0000, 0.3000])
    """
    a, b, dtype, _ = _checks.pair(_NAME + "between", R0, R1, "R0", "R1", (3, 3), (3, 3))
    return _checks.out(a.transpose(-1, -2) @ b, dtype)


@_checks.float32_exact
def jac_compose(
    R1: Float[Tensor, "*b1 3 3"], R2: Float[Tensor, "*b2 3 3"]
) -> tuple[Float[Tensor, "*b 3 3"], Float[Tensor, "*b 3 3"]]:
    """Jacobians of ``R1 R2``: ``(J_R1R2_R1, J_R1R2_R2) = (R2^T, I)``.

    ``(R1 Exp(d1)) (R2 Exp(d2)) ~= R1 R2 Exp(R2^T d1 + d2)`` (``R2^T = Ad(R2)^-1``).

    Example:
        >>> R2 = exp(torch.tensor([0.1, 0.2, 0.3]))
        >>> J1, J2 = jac_compose(identity(), R2)
        >>> torch.equal(J1, R2.mT) and torch.equal(J2, torch.eye(3))
        True
    """
    a, b, dtype, batch = _checks.pair(_NAME + "jac_compose", R1, R2, "R1", "R2", (3, 3), (3, 3))
    J1 = b.transpose(-1, -2).expand(*batch, 3, 3).clone()
    return _checks.out(J1, dtype), _checks.out(_eye3(batch, a), dtype)


@_checks.float32_exact
def jac_inverse(R: Float[Tensor, "*b 3 3"]) -> Float[Tensor, "*b 3 3"]:
    """Jacobian ``J_Rinv_R = -Ad(R) = -R``: ``(R Exp(d))^T = R^T Exp(-R d)``.

    Example:
        >>> torch.equal(jac_inverse(identity()), -torch.eye(3))
        True
    """
    x, dtype = _checks.tensor(R, _NAME + "jac_inverse", "R", (3, 3))
    return _checks.out(-x, dtype)


@_checks.float32_exact
def jac_act(
    R: Float[Tensor, "*b1 3 3"], points: Float[Tensor, "*b2 3"]
) -> tuple[Float[Tensor, "*b 3 3"], Float[Tensor, "*b 3 3"]]:
    """Jacobians of ``R p``: ``(J_Rp_R, J_Rp_p) = (-R hat(p), R)``.

    ``R Exp(d) (p + dp) ~= R p - R hat(p) d + R dp`` (the point is perturbed additively).

    Example:
        >>> p = torch.tensor([1.0, 2.0, 3.0])
        >>> JR, Jp = jac_act(identity(), p)
        >>> torch.equal(JR, -hat(p)) and torch.equal(Jp, torch.eye(3))
        True
    """
    x, p, dtype, batch = _checks.pair(_NAME + "jac_act", R, points, "R", "points", (3, 3), (3,))
    x = x.expand(*batch, 3, 3)
    return _checks.out(-(x @ _components.hat(p)), dtype), _checks.out(x.clone(), dtype)


@_checks.float32_exact
def jac_rplus(
    R: Float[Tensor, "*b1 3 3"], tau: Float[Tensor, "*b2 3"]
) -> tuple[Float[Tensor, "*b 3 3"], Float[Tensor, "*b 3 3"]]:
    """Jacobians of ``R Exp(tau)``: ``(J_R, J_tau) = (Exp(tau)^T, Jr(tau))``.

    Example:
        >>> JR, Jtau = jac_rplus(identity(), torch.zeros(3))
        >>> torch.equal(JR, torch.eye(3)) and torch.equal(Jtau, torch.eye(3))
        True
    """
    x, v, dtype, batch = _checks.pair(_NAME + "jac_rplus", R, tau, "R", "tau", (3, 3), (3,))
    v = v.expand(*batch, 3)
    JR = _ExpMapFn(v).transpose(-1, -2)
    return _checks.out(JR, dtype), _checks.out(_rodrigues.jac_matrix(v, "right"), dtype)


@_checks.float32_exact
def jac_rminus(
    R1: Float[Tensor, "*b1 3 3"], R0: Float[Tensor, "*b2 3 3"]
) -> tuple[Float[Tensor, "*b 3 3"], Float[Tensor, "*b 3 3"]]:
    """Jacobians of ``tau = Log(R0^T R1)``: ``(J_tau_R1, J_tau_R0) = (Jr(tau)^-1, -Jl(tau)^-1)``.

    Example:
        >>> J1, J0 = jac_rminus(identity(), identity())
        >>> torch.equal(J1, torch.eye(3)) and torch.equal(J0, -torch.eye(3))
        True
    """
    a, b, dtype, _ = _checks.pair(_NAME + "jac_rminus", R1, R0, "R1", "R0", (3, 3), (3, 3))
    tau = _LogFn(b.transpose(-1, -2) @ a)
    J1, J0 = _rodrigues.jac_matrix(tau, "right_inv"), -_rodrigues.jac_matrix(tau, "left_inv")
    return _checks.out(J1, dtype), _checks.out(J0, dtype)


@_checks.float32_exact
def jac_between(
    R0: Float[Tensor, "*b1 3 3"], R1: Float[Tensor, "*b2 3 3"]
) -> tuple[Float[Tensor, "*b 3 3"], Float[Tensor, "*b 3 3"]]:
    """Jacobians of ``R0^T R1``: ``(J_R0, J_R1) = (-Ad(R1^T R0), I) = (-R1^T R0, I)``.

    Example:
        >>> J0, J1 = jac_between(identity(), identity())
        >>> torch.equal(J0, -torch.eye(3)) and torch.equal(J1, torch.eye(3))
        True
    """
    a, b, dtype, batch = _checks.pair(_NAME + "jac_between", R0, R1, "R0", "R1", (3, 3), (3, 3))
    J0 = -(b.transpose(-1, -2) @ a)
    return _checks.out(J0, dtype), _checks.out(_eye3(batch, a), dtype)
