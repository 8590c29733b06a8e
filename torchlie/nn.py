"""Layers, losses and manifold parametrizations for networks that predict or optimise poses.

* :class:`RotationHead` / :class:`PoseHead`: an ``nn.Linear`` to an unconstrained
  representation, then the map to a rotation (:func:`representation_to_matrix`).  The output is
  a valid rotation for every finite input, zero and huge ones included, with finite gradients
  (degenerate raw vectors get a documented fixed value).
* :func:`geodesic_loss` / :func:`se3_geodesic_loss` / :func:`sim3_geodesic_loss`: rotation
  angle (or squared chordal), translation (and log-scale) losses with torch's ``reduction``
  argument.
* :class:`SO3Parametrization` / :class:`SE3Parametrization` / :class:`Sim3Parametrization`: for
  :func:`torch.nn.utils.parametrize.register_parametrization`, so that a plain parameter
  optimised by any torch optimiser (SGD, Adam, LBFGS, ...) is always read as a rotation / pose.
* :class:`PlanarPoseHead`, :func:`so2_geodesic_loss`, :func:`se2_geodesic_loss`,
  :class:`SO2Parametrization`, :class:`SE2Parametrization`: the same for the planar groups.

Representations (sizes in :data:`REPRESENTATIONS`):

================  ====  =========================================================================
``"6d"``          6     first two columns, Gram-Schmidt
                        (:func:`torchlie.conversions.rot6d_to_matrix`)
``"9d"``          9     3x3 matrix row by row, nearest rotation by SVD
                        (:func:`torchlie.conversions.rot9d_to_matrix`)
``"quaternion"``  4     ``(w, x, y, z)``, normalised (any scale), canonical hemisphere ``w >= 0``
``"rotvec"``      3     rotation vector, :func:`torchlie.so3.exp`
================  ====  =========================================================================

The 6-D and 9-D representations are continuous (every rotation has a neighbourhood of raw
vectors that map smoothly onto a neighbourhood of it) and usually train best; the quaternion
and the rotation vector cover SO(3) twice or infinitely often, so a network that must output a
*single* representative of each rotation has to jump somewhere.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from . import _checks, _coeffs, se2, se3, sim3, so2, so3
from . import conversions as _conv
from . import quaternion as _quat
from ._typing import Float
from .groups import SE2, SE3, SO3

__all__ = [
    "REPRESENTATIONS",
    "representation_to_matrix",
    "RotationHead",
    "PoseHead",
    "geodesic_loss",
    "se3_geodesic_loss",
    "SO3Parametrization",
    "SE3Parametrization",
    "PlanarPoseHead",
    "so2_geodesic_loss",
    "se2_geodesic_loss",
    "SO2Parametrization",
    "SE2Parametrization",
    "sim3_geodesic_loss",
    "Sim3Parametrization",
]


def __dir__() -> list[str]:
    # dir() lists the public API only, not the names this module imports (torch, Tensor, ...).
    return sorted(__all__)


_NAME = "torchlie.nn."

#: Size of the raw vector of each rotation representation.
REPRESENTATIONS: dict[str, int] = {"6d": 6, "9d": 9, "quaternion": 4, "rotvec": 3}

#: Relative sine below which the two 6-D columns count as parallel (module ``_safe_rot6d``), in
#: units of the compute dtype's machine epsilon.
_PARALLEL_EPS = 64.0

_REDUCTIONS = ("mean", "sum", "none")


def _check_choice(fn: str, arg: str, value: object, choices) -> None:
    if not isinstance(value, str) or value not in choices:
        allowed = ", ".join(repr(c) for c in choices)
        raise ValueError(f"{fn}: unknown {arg} {value!r}; expected one of {allowed}")


# ----------------------------------------------------------------------------------------------
# Raw representation -> rotation matrix, with deterministic fallbacks at degenerate inputs
# ----------------------------------------------------------------------------------------------


def _basis(k: Tensor, like: Tensor) -> Tensor:
    """Unit coordinate vectors ``e_k`` (``k`` integer, shape ``(...)``) as ``(..., 3)`` (a
    comparison, not ``one_hot``, which reads ``k``'s values: no ``torch.func`` transform)."""
    return (k.unsqueeze(-1) == torch.arange(3, device=k.device)).to(like.dtype)


def _scaled(v: Tensor) -> Tensor:
    """``v / max|v_i|`` (detached; a zero vector stays zero): O(1) entries at any magnitude."""
    v = v.detach()
    s = v.abs().amax(dim=-1, keepdim=True)
    return v / torch.where(s == 0, torch.ones_like(s), s)


def _safe_rot6d(x: Tensor) -> Tensor:
    """Replace the degenerate parts of a raw 6-vector (rule: :func:`representation_to_matrix`)."""
    a1, a2 = x[..., :3], x[..., 3:]
    e1 = torch.tensor([1.0, 0.0, 0.0], dtype=x.dtype, device=x.device)
    zero1 = (a1 == 0).all(dim=-1, keepdim=True)
    a1 = torch.where(zero1, e1, a1)
    u1, u2 = _scaled(a1), _scaled(a2)
    c = torch.linalg.cross(u1, u2, dim=-1)
    tau = _PARALLEL_EPS * torch.finfo(x.dtype).eps
    s2 = (c * c).sum(-1, keepdim=True)
    n2 = (u1 * u1).sum(-1, keepdim=True) * (u2 * u2).sum(-1, keepdim=True)
    parallel = s2 <= (tau * tau) * n2  # a2 = 0 included; False for NaN/Inf (they stay NaN)
    fallback = _basis(torch.argmin(u1.abs(), dim=-1), a2)
    a2 = torch.where(parallel, fallback, a2)
    return torch.cat((a1, a2), dim=-1)


def _identity_if_zero(x: Tensor) -> Tensor:
    """A raw 4-vector with ``0`` replaced by the identity quaternion (zero gradient there)."""
    zero = (x == 0).all(dim=-1, keepdim=True)
    one = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=x.dtype, device=x.device)
    return torch.where(zero, one, x)


def _unit_quaternion(x: Tensor) -> Tensor:
    """Canonical unit quaternion of a raw 4-vector (zero -> identity)."""
    return _quat.canonicalize(_conv._unit(_identity_if_zero(x)))


def _to_matrix(x: Tensor, representation: str) -> Tensor:
    if representation == "6d":
        return _conv.rot6d_to_matrix(_safe_rot6d(x))
    if representation == "9d":
        zero = (x == 0).all(dim=-1, keepdim=True)
        eye = torch.eye(3, dtype=x.dtype, device=x.device).flatten()
        return _conv.rot9d_to_matrix(torch.where(zero, eye, x))
    if representation == "quaternion":
        return _quat.to_matrix(_unit_quaternion(x))
    return so3.exp(x)


@_checks.float32_exact
def representation_to_matrix(
    x: Float[Tensor, "*b k"], representation: str
) -> Float[Tensor, "*b 3 3"]:
    """Rotation matrix of a raw (unconstrained) representation vector; the map of the heads.

    ``k`` is ``REPRESENTATIONS[representation]``: 6, 9, 4 or 3.  Every finite input gives a
    valid rotation, with a finite gradient except at the singular 9-D inputs named below, at any
    magnitude: the 6-D, 9-D and quaternion maps are invariant to the (positive) scale of their
    input, from ``1e-30`` to ``1e30`` in float32; the rotation vector at every finite
    magnitude, as :func:`torchlie.so3.exp` (huge angles reduced modulo ``2 pi``).

    Degenerate inputs, where the map is undefined, get a fixed, documented value with a zero
    (finite) gradient:

    * ``"6d"`` ``(a1, a2)``: ``a1 = 0`` is read as ``e_x``; ``a2`` parallel to ``a1`` (relative
      sine below ``64 eps``, ``a2 = 0`` included) is read as ``e_k``, the coordinate axis
      of the smallest ``|a1_k|`` (the first on ties), which is never near ``a1``.  So ``0``
      gives the identity, and ``(a1, 0)`` the rotation whose first column is ``a1 / |a1|``.
    * ``"9d"``: the zero matrix gives the identity.  Other singular matrices (a set of measure
      zero that a linear layer does not produce in practice) give a valid rotation, but the
      gradient there may not be finite: at rank 1, or where the two smallest signed singular
      values sum to 0, the nearest rotation is not unique.
    * ``"quaternion"``: ``0`` gives the identity.  Otherwise the vector is normalised (any scale)
      and put in the canonical hemisphere ``w >= 0``; at ``w = 0`` the rule of
      :mod:`torchlie.quaternion` applies (largest-magnitude vector component positive).  The
      flip ``q -> -q`` is *not* a smooth map of the raw vector (it jumps across ``w = 0``), but
      the matrix is: ``R(q) = R(-q)``, so the matrix and its gradient do not see the flip.
    * ``"rotvec"``: :func:`torchlie.so3.exp` is defined and smooth everywhere.

    Non-finite input gives NaN for that element only.

    Example:
        >>> representation_to_matrix(torch.zeros(6), "6d")
        tensor([[1., 0., 0.],
                [0., 1., 0.],
                [0., 0., 1.]])
        >>> representation_to_matrix(torch.tensor([0.0, 0.0, 0.0, 1e6]), "quaternion")
        tensor([[-1.,  0.,  0.],
                [ 0., -1.,  0.],
                [ 0.,  0.,  1.]])
    """
    fn = _NAME + "representation_to_matrix"
    _check_choice(fn, "representation", representation, REPRESENTATIONS)
    v, dtype = _checks.tensor(x, fn, "x", (REPRESENTATIONS[representation],))
    return _checks.out(_to_matrix(v, representation), dtype)


# ----------------------------------------------------------------------------------------------
# Heads
# ----------------------------------------------------------------------------------------------


def _linear(head: nn.Module, features: Tensor, fn: str) -> Tensor:
    """A head's linear layer of ``features``, whose last dimension and dtype are checked first
    (torch's messages name neither the head nor ``in_features`` nor the layer's dtype).  Inside
    ``torch.autocast``, which casts the layer's operands, the dtypes are torch's to reconcile."""
    _checks.tensor(features, _NAME + fn, "features", (head.linear.in_features,))
    dtype = head.linear.weight.dtype
    if features.dtype != dtype and not torch.is_autocast_enabled(
        _checks._autocast_type(features.device)
    ):
        raise TypeError(
            f"{_NAME}{fn}: expected features of the head's dtype {dtype}, got {features.dtype}; "
            f"convert one of them (features.to({dtype}) or head.to({features.dtype}))"
        )
    return head.linear(features)


class RotationHead(nn.Module):
    """Features ``(..., in_features)`` -> rotations: ``nn.Linear`` then a rotation map.

    The linear layer maps to the raw representation (``REPRESENTATIONS[representation]``
    numbers), which :func:`representation_to_matrix` turns into a rotation matrix; the result is
    a valid rotation for every finite input, zero and huge features included, with finite
    gradients (degenerate raw vectors: see :func:`representation_to_matrix`).

    Args:
        in_features: size of the last input dimension.
        representation: ``"6d"`` (default), ``"9d"``, ``"quaternion"`` or ``"rotvec"``.
        output: ``"matrix"`` (a ``(..., 3, 3)`` tensor, default) or ``"SO3"`` (an
            :class:`torchlie.SO3`).
        bias, device, dtype: passed to ``nn.Linear``.

    Example:
        >>> head = RotationHead(16, representation="6d")
        >>> R = head(torch.randn(8, 16))
        >>> R.shape, bool(so3.is_valid(R).all())
        (torch.Size([8, 3, 3]), True)
    """

    def __init__(
        self,
        in_features: int,
        representation: str = "6d",
        output: str = "matrix",
        *,
        bias: bool = True,
        device: torch.device | str | None = None,
        dtype: torch.dtype | None = None,
    ) -> None:
        super().__init__()
        fn = _NAME + "RotationHead"
        _checks.factory(fn, (), dtype)
        _check_choice(fn, "representation", representation, REPRESENTATIONS)
        _check_choice(fn, "output", output, ("matrix", "SO3"))
        self.representation = representation
        self.output = output
        self.linear = nn.Linear(
            in_features, REPRESENTATIONS[representation], bias=bias, device=device, dtype=dtype
        )

    def extra_repr(self) -> str:
        return f"representation={self.representation!r}, output={self.output!r}"

    def raw(self, features: Float[Tensor, "*b f"]) -> Float[Tensor, "*b k"]:
        """The unconstrained representation vector ``(..., k)`` (the linear layer's output).

        Example:
            >>> RotationHead(16, representation="9d").raw(torch.zeros(2, 16)).shape
            torch.Size([2, 9])
        """
        return _linear(self, features, "RotationHead.raw")

    def forward(self, features: Float[Tensor, "*b f"]) -> Float[Tensor, "*b 3 3"] | SO3:
        """Rotation matrices ``(..., 3, 3)`` (or an :class:`torchlie.SO3`)."""
        R = representation_to_matrix(_linear(self, features, "RotationHead"), self.representation)
        return SO3._wrap(R) if self.output == "SO3" else R

    def quaternion(self, features: Float[Tensor, "*b f"]) -> Float[Tensor, "*b 4"]:
        """Canonical unit quaternions ``(..., 4)`` (``w >= 0``) of the predicted rotations.

        For ``representation="quaternion"`` this is the normalised raw output put in the
        canonical hemisphere (not a smooth function of it at ``w = 0``, see
        :func:`representation_to_matrix`); otherwise :func:`torchlie.quaternion.from_matrix`
        of the matrix.

        Example:
            >>> head = RotationHead(2, representation="quaternion")
            >>> _ = torch.nn.init.zeros_(head.linear.weight)
            >>> _ = head.linear.bias.data.copy_(torch.tensor([-2.0, 0.0, 0.0, 2.0]))
            >>> head.quaternion(torch.zeros(2)).detach()  # (-2, 0, 0, 2) flipped to w >= 0
            tensor([ 0.7071, -0.0000, -0.0000, -0.7071])
        """
        x = _linear(self, features, "RotationHead.quaternion")
        if self.representation == "quaternion":
            fn = _NAME + "RotationHead.quaternion"
            v, dtype = _checks.tensor(x, fn, "x", (4,))
            return _checks.out(_unit_quaternion(v), dtype)
        return _quat.from_matrix(representation_to_matrix(x, self.representation))


class PoseHead(nn.Module):
    """Features ``(..., in_features)`` -> poses ``(..., 4, 4)`` ``[[R, t], [0, 1]]``.

    One ``nn.Linear`` to ``k + 3`` numbers: the first ``k`` are the rotation's raw
    representation (as :class:`RotationHead`), the last 3 the translation ``t`` as it is.

    Args:
        in_features: size of the last input dimension.
        representation: ``"6d"`` (default), ``"9d"``, ``"quaternion"`` or ``"rotvec"``.
        output: ``"matrix"`` (default) or ``"SE3"`` (an :class:`torchlie.SE3`).
        bias, device, dtype: passed to ``nn.Linear``.

    Example:
        >>> head = PoseHead(16, representation="9d")
        >>> T = head(torch.zeros(2, 16))
        >>> T.shape, bool(se3.is_valid(T).all())
        (torch.Size([2, 4, 4]), True)
    """

    def __init__(
        self,
        in_features: int,
        representation: str = "6d",
        output: str = "matrix",
        *,
        bias: bool = True,
        device: torch.device | str | None = None,
        dtype: torch.dtype | None = None,
    ) -> None:
        super().__init__()
        fn = _NAME + "PoseHead"
        _checks.factory(fn, (), dtype)
        _check_choice(fn, "representation", representation, REPRESENTATIONS)
        _check_choice(fn, "output", output, ("matrix", "SE3"))
        self.representation = representation
        self.output = output
        k = REPRESENTATIONS[representation]
        self.linear = nn.Linear(in_features, k + 3, bias=bias, device=device, dtype=dtype)

    def extra_repr(self) -> str:
        return f"representation={self.representation!r}, output={self.output!r}"

    def forward(self, features: Float[Tensor, "*b f"]) -> Float[Tensor, "*b 4 4"] | SE3:
        """Poses ``(..., 4, 4)`` (or an :class:`torchlie.SE3`)."""
        y = _linear(self, features, "PoseHead")
        R = representation_to_matrix(y[..., :-3], self.representation)
        T = se3.from_rt(R, y[..., -3:])
        return SE3._wrap(T) if self.output == "SE3" else T


# ----------------------------------------------------------------------------------------------
# Losses
# ----------------------------------------------------------------------------------------------


def _sum_squares(d: Tensor, k: int) -> Tensor:
    """``sum d^2`` over the last ``k`` dimensions, entry by entry in a fixed order (the same
    bits whatever the layout of ``d``; torch's reductions sum in an order that depends on it)."""
    return _coeffs.sum_squares(d.flatten(-k) if k > 1 else d)


def _reduce(loss: Tensor, reduction: str) -> Tensor:
    if reduction == "mean":
        return loss.mean()
    if reduction == "sum":
        return loss.sum()
    return loss


@_checks.float32_exact
def geodesic_loss(
    R_pred: Float[Tensor, "*b1 3 3"],
    R_target: Float[Tensor, "*b2 3 3"],
    kind: str = "angle",
    reduction: str = "mean",
) -> Float[Tensor, "*b"]:
    """Rotation error between predicted and target rotations (batch shapes broadcast).

    ``kind="angle"``: the geodesic distance, the angle of ``R_pred^T R_target`` in radians,
    ``[0, pi]`` (:func:`torchlie.so3.distance`).  It is not differentiable at 0 (a cone) or at
    pi (a ridge); the gradient there is the zero subgradient, so it is always finite.
    ``kind="chordal"``: the squared chordal distance ``|R_pred - R_target|_F^2``, equal to
    ``8 sin^2(angle / 2)`` for rotations; smooth everywhere, its derivative along rotations
    vanishes at 0 and at pi (the gradient on the raw matrix is ``2 (R_pred - R_target)``).

    Args:
        R_pred, R_target: rotation matrices ``(..., 3, 3)``.
        kind: ``"angle"`` (default) or ``"chordal"``.
        reduction: ``"mean"`` (default), ``"sum"`` or ``"none"``, as in torch's losses.

    Returns:
        A scalar, or the per-element losses ``(...)`` for ``reduction="none"``.

    Example:
        >>> R = so3.exp(torch.tensor([[0.0, 0.0, 0.5], [0.0, 0.0, 1.0]]))
        >>> geodesic_loss(R, torch.eye(3), reduction="none")
        tensor([0.5000, 1.0000])
        >>> geodesic_loss(R, torch.eye(3))
        tensor(0.7500)
    """
    fn = _NAME + "geodesic_loss"
    _check_choice(fn, "kind", kind, ("angle", "chordal"))
    _check_choice(fn, "reduction", reduction, _REDUCTIONS)
    a, b, dtype, _ = _checks.pair(fn, R_pred, R_target, "R_pred", "R_target", (3, 3), (3, 3))
    if kind == "angle":
        loss = so3.distance(a, b)
    else:
        d = a - b
        loss = _sum_squares(d, 2)
    return _checks.out(_reduce(loss, reduction), dtype)


@_checks.float32_exact
def se3_geodesic_loss(
    T_pred: Float[Tensor, "*b1 4 4"],
    T_target: Float[Tensor, "*b2 4 4"],
    rotation_weight: float = 1.0,
    translation_weight: float = 1.0,
    kind: str = "angle",
    reduction: str = "mean",
) -> Float[Tensor, "*b"]:
    """Weighted pose error ``rotation_weight * rot + translation_weight * trans``.

    ``kind="angle"``: ``rot`` is the rotation angle of ``R_pred^T R_target`` (radians) and
    ``trans`` the distance ``|t_pred - t_target|`` (:func:`torchlie.se3.distance`); both have the
    zero subgradient where they are not differentiable (zero error, angle pi), so the gradient
    is always finite.  ``kind="chordal"``: ``rot = |R_pred - R_target|_F^2`` and
    ``trans = |t_pred - t_target|^2``, smooth everywhere.  The weights convert the two units
    (radians and your length unit) into one loss; the bottom rows are not read.

    Args:
        T_pred, T_target: poses ``(..., 4, 4)`` (batch shapes broadcast).
        rotation_weight, translation_weight: non-negative finite real numbers (per-element
            weights: combine the ``reduction="none"`` losses yourself).
        kind: ``"angle"`` (default) or ``"chordal"``.
        reduction: ``"mean"`` (default), ``"sum"`` or ``"none"``.

    Example:
        >>> T = se3.from_rt(so3.exp(torch.tensor([0.0, 0.3, 0.0])), torch.tensor([3.0, 4.0, 0.0]))
        >>> se3_geodesic_loss(T, se3.identity(), rotation_weight=10.0)
        tensor(8.)
    """
    fn = _NAME + "se3_geodesic_loss"
    _check_choice(fn, "kind", kind, ("angle", "chordal"))
    _check_choice(fn, "reduction", reduction, _REDUCTIONS)
    rotation_weight = _checks.nonnegative(rotation_weight, fn, "rotation_weight")
    translation_weight = _checks.nonnegative(translation_weight, fn, "translation_weight")
    a, b, dtype, _ = _checks.pair(fn, T_pred, T_target, "T_pred", "T_target", (4, 4), (4, 4))
    if kind == "angle":
        rot, trans = se3.distance(a, b)
    else:
        dR = a[..., :3, :3] - b[..., :3, :3]
        dt = a[..., :3, 3] - b[..., :3, 3]
        rot, trans = _sum_squares(dR, 2), _sum_squares(dt, 1)
    loss = rotation_weight * rot + translation_weight * trans
    return _checks.out(_reduce(loss, reduction), dtype)


# ----------------------------------------------------------------------------------------------
# Parametrizations
# ----------------------------------------------------------------------------------------------


_SO3_PARAMS = {"quaternion": (4,), "matrix": (3, 3), "rotvec": (3,)}
_SE3_PARAMS = {"pos_quat": (7,), "matrix": (4, 4), "twist": (6,)}


class SO3Parametrization(nn.Module):
    """Keep a parameter on SO(3): for :func:`torch.nn.utils.parametrize.register_parametrization`.

    The registered tensor (``module.weight``) is always read as valid rotations ``(..., 3, 3)``,
    whatever any optimiser (SGD, Adam, LBFGS, ...) does to the stored parameter
    (``module.parametrizations.weight.original``): the rotation is computed from it on every
    read, so nothing needs re-projecting after a step.  Assigning ``module.weight = R`` stores
    ``right_inverse(R)``.  ``state_dict`` holds the stored parameter.

    ``representation`` chooses the stored parameter:

    * ``"quaternion"`` (default): ``(..., 4)``, read as :func:`torchlie.quaternion.to_matrix`
      (the rotation of ``q / |q|``): smooth everywhere except at ``q = 0``, no chart
      singularity, no SVD; the cheapest and most robust choice.  The gradient is orthogonal
      to ``q``, so plain gradient steps only make ``|q|`` grow (slowly, second order in the
      step); adaptive optimisers, whose steps are not along the gradient, move ``|q|`` a
      little either way.  ``right_inverse`` is :func:`torchlie.quaternion.from_matrix`.  A
      stored ``q = 0`` (where no rotation is defined) reads as the identity with a zero
      gradient, never NaN; it therefore stays there, so initialise the parameter by assigning
      rotations (``right_inverse``), not zeros.
    * ``"matrix"``: an unconstrained ``(..., 3, 3)`` matrix read as its nearest rotation,
      :func:`torchlie.so3.project`; ``right_inverse`` stores the assigned matrix as it is (the
      stored value *is* the rotation until the first step).  Costs an SVD per read and an
      eigen-decomposition per backward, and optimisers move the stored matrix off SO(3) along
      directions that do not change the rotation, so its singular values drift freely (towards
      0 they make the projection ill-conditioned).
    * ``"rotvec"``: a rotation vector ``(..., 3)`` read as :func:`torchlie.so3.exp`;
      ``right_inverse`` is :func:`torchlie.so3.log`.  Three numbers per rotation, and weight
      decay pulls towards the identity; but the chart degenerates as the angle approaches
      ``2 pi`` (the gradient across the axis vanishes), and nothing keeps a long optimisation
      from drifting there.

    Keep the stored parameter out of weight decay for ``"quaternion"`` and ``"matrix"``: decay
    shrinks it towards 0, where the rotation is undefined.  All three work with
    ``torch.compile(fullgraph=True)``.

    Example:
        >>> from torch.nn.utils import parametrize
        >>> holder = torch.nn.Module()
        >>> holder.R = torch.nn.Parameter(so3.identity(5))
        >>> _ = parametrize.register_parametrization(holder, "R", SO3Parametrization())
        >>> holder.parametrizations.R.original.shape
        torch.Size([5, 4])
        >>> with torch.no_grad():
        ...     _ = holder.parametrizations.R.original.add_(torch.randn(5, 4))
        >>> bool(so3.is_valid(holder.R).all())
        True
    """

    def __init__(self, representation: str = "quaternion") -> None:
        super().__init__()
        fn = _NAME + "SO3Parametrization"
        _check_choice(fn, "representation", representation, _SO3_PARAMS)
        self.representation = representation

    def extra_repr(self) -> str:
        return f"representation={self.representation!r}"

    def forward(self, X: Tensor) -> Float[Tensor, "*b 3 3"]:
        """The rotations ``(..., 3, 3)`` of the stored parameter ``X``."""
        fn = _NAME + "SO3Parametrization"
        _checks.tensor(X, fn, "X", _SO3_PARAMS[self.representation])
        if self.representation == "quaternion":
            return _quat.to_matrix(_identity_if_zero(X))
        if self.representation == "matrix":
            return so3.project(X)
        return so3.exp(X)

    def right_inverse(self, R: Float[Tensor, "*b 3 3"]) -> Tensor:
        """The stored parameter that reads as the rotations ``R``."""
        _checks.tensor(R, _NAME + "SO3Parametrization.right_inverse", "R", (3, 3))
        if self.representation == "quaternion":
            return _quat.from_matrix(R)
        if self.representation == "matrix":
            return R.clone()  # never alias the caller's tensor
        return so3.log(R)


class SE3Parametrization(nn.Module):
    """Keep a parameter on SE(3): for :func:`torch.nn.utils.parametrize.register_parametrization`.

    The registered tensor is always read as valid poses ``(..., 4, 4)`` (as
    :class:`SO3Parametrization`).  ``representation`` chooses the stored parameter:

    * ``"pos_quat"`` (default): ``(..., 7)`` ``(t, q)``, read as
      :func:`torchlie.se3.from_pos_quat` (translation as it is, rotation of ``q / |q|``;
      ``q = 0`` reads as the identity rotation, as for :class:`SO3Parametrization`);
      ``right_inverse`` is :func:`torchlie.se3.to_pos_quat`.  Rotation and translation are
      decoupled, which usually conditions pose optimisation well.
    * ``"matrix"``: an unconstrained ``(..., 4, 4)`` matrix; the rotation block is read through
      :func:`torchlie.so3.project`, the translation column as it is, and the bottom row as
      ``(0, 0, 0, 1)`` (the stored bottom row is not read and gets no gradient);
      ``right_inverse`` stores the assigned pose as it is.
    * ``"twist"``: a twist ``(..., 6)`` ``(rho, phi)`` read as :func:`torchlie.se3.exp`;
      ``right_inverse`` is :func:`torchlie.se3.log`.  Rotation and translation are coupled
      (``t = so3.jac_left(phi) rho``): a step in ``phi`` also moves the translation, which
      slows first-order optimisers (SGD, Adam) compared with the other two forms.

    Example:
        >>> from torch.nn.utils import parametrize
        >>> holder = torch.nn.Module()
        >>> holder.pose = torch.nn.Parameter(se3.identity(5))
        >>> _ = parametrize.register_parametrization(holder, "pose", SE3Parametrization())
        >>> with torch.no_grad():
        ...     _ = holder.parametrizations.pose.original.add_(torch.randn(5, 7))
        >>> bool(se3.is_valid(holder.pose).all())
        True
    """

    def __init__(self, representation: str = "pos_quat") -> None:
        super().__init__()
        fn = _NAME + "SE3Parametrization"
        _check_choice(fn, "representation", representation, _SE3_PARAMS)
        self.representation = representation

    def extra_repr(self) -> str:
        return f"representation={self.representation!r}"

    def forward(self, X: Tensor) -> Float[Tensor, "*b 4 4"]:
        """The poses ``(..., 4, 4)`` of the stored parameter ``X``."""
        _checks.tensor(X, _NAME + "SE3Parametrization", "X", _SE3_PARAMS[self.representation])
        if self.representation == "pos_quat":
            return se3.from_pos_quat(torch.cat((X[..., :3], _identity_if_zero(X[..., 3:])), -1))
        if self.representation == "matrix":
            return se3.from_rt(so3.project(X[..., :3, :3]), X[..., :3, 3])
        return se3.exp(X)

    def right_inverse(self, T: Float[Tensor, "*b 4 4"]) -> Tensor:
        """The stored parameter that reads as the poses ``T``."""
        _checks.tensor(T, _NAME + "SE3Parametrization.right_inverse", "T", (4, 4))
        if self.representation == "pos_quat":
            return se3.to_pos_quat(T)
        if self.representation == "matrix":
            return T.clone()  # never alias the caller's tensor
        return se3.log(T)


# ----------------------------------------------------------------------------------------------
# The planar groups
# ----------------------------------------------------------------------------------------------


def _unit_complex(x: Tensor) -> Tensor:
    """The rotation of a raw ``(re, im)`` 2-vector; ``0`` reads as the identity (zero gradient)."""
    zero = (x == 0).all(dim=-1, keepdim=True)
    one = torch.tensor([1.0, 0.0], dtype=x.dtype, device=x.device)
    return so2.from_complex(torch.where(zero, one, x))


class PlanarPoseHead(nn.Module):
    """Features ``(..., in_features)`` -> planar poses ``(..., 3, 3)`` ``[[R, t], [0, 1]]``.

    One ``nn.Linear`` to 4 numbers: a complex number ``(re, im)`` read as the rotation of
    ``z / |z|`` (continuous; ``z = 0`` reads as the identity, with a zero gradient) and the
    translation ``t`` as it is.

    Args:
        in_features: size of the last input dimension.
        output: ``"matrix"`` (default) or ``"SE2"`` (an :class:`torchlie.SE2`).
        bias, device, dtype: passed to ``nn.Linear``.

    Example:
        >>> head = PlanarPoseHead(8)
        >>> T = head(torch.zeros(2, 8))
        >>> T.shape, bool(se2.is_valid(T).all())
        (torch.Size([2, 3, 3]), True)
    """

    def __init__(
        self,
        in_features: int,
        output: str = "matrix",
        *,
        bias: bool = True,
        device: torch.device | str | None = None,
        dtype: torch.dtype | None = None,
    ) -> None:
        super().__init__()
        fn = _NAME + "PlanarPoseHead"
        _checks.factory(fn, (), dtype)
        _check_choice(fn, "output", output, ("matrix", "SE2"))
        self.output = output
        self.linear = nn.Linear(in_features, 4, bias=bias, device=device, dtype=dtype)

    def extra_repr(self) -> str:
        return f"output={self.output!r}"

    def forward(self, features: Float[Tensor, "*b f"]) -> Float[Tensor, "*b 3 3"] | SE2:
        """Poses ``(..., 3, 3)`` (or an :class:`torchlie.SE2`)."""
        y = _linear(self, features, "PlanarPoseHead")
        T = se2.from_rt(_unit_complex(y[..., :2]), y[..., 2:])
        return SE2._wrap(T) if self.output == "SE2" else T


@_checks.float32_exact
def so2_geodesic_loss(
    R_pred: Float[Tensor, "*b1 2 2"],
    R_target: Float[Tensor, "*b2 2 2"],
    kind: str = "angle",
    reduction: str = "mean",
) -> Float[Tensor, "*b"]:
    """Planar rotation error (as :func:`geodesic_loss`): the angle of ``R_pred^T R_target`` in
    ``[0, pi]`` (:func:`torchlie.so2.distance`, zero subgradient at 0 and pi) or the squared
    chordal distance ``|R_pred - R_target|_F^2 = 8 sin^2(angle / 2)``.

    Example:
        >>> R = so2.exp(torch.tensor([[0.5], [-1.0]]))
        >>> so2_geodesic_loss(R, torch.eye(2), reduction="none")
        tensor([0.5000, 1.0000])
    """
    fn = _NAME + "so2_geodesic_loss"
    _check_choice(fn, "kind", kind, ("angle", "chordal"))
    _check_choice(fn, "reduction", reduction, _REDUCTIONS)
    a, b, dtype, _ = _checks.pair(fn, R_pred, R_target, "R_pred", "R_target", (2, 2), (2, 2))
    loss = so2.distance(a, b) if kind == "angle" else _sum_squares(a - b, 2)
    return _checks.out(_reduce(loss, reduction), dtype)


@_checks.float32_exact
def se2_geodesic_loss(
    T_pred: Float[Tensor, "*b1 3 3"],
    T_target: Float[Tensor, "*b2 3 3"],
    rotation_weight: float = 1.0,
    translation_weight: float = 1.0,
    kind: str = "angle",
    reduction: str = "mean",
) -> Float[Tensor, "*b"]:
    """Weighted planar pose error ``rotation_weight * rot + translation_weight * trans`` (as
    :func:`se3_geodesic_loss`: angle and distance, or squared chordal and squared distance).

    Example:
        >>> T = se2.from_xytheta(torch.tensor([3.0, 4.0, 0.3]))
        >>> se2_geodesic_loss(T, se2.identity(), rotation_weight=10.0)
        tensor(8.)
    """
    fn = _NAME + "se2_geodesic_loss"
    _check_choice(fn, "kind", kind, ("angle", "chordal"))
    _check_choice(fn, "reduction", reduction, _REDUCTIONS)
    rotation_weight = _checks.nonnegative(rotation_weight, fn, "rotation_weight")
    translation_weight = _checks.nonnegative(translation_weight, fn, "translation_weight")
    a, b, dtype, _ = _checks.pair(fn, T_pred, T_target, "T_pred", "T_target", (3, 3), (3, 3))
    if kind == "angle":
        rot, trans = se2.distance(a, b)
    else:
        rot = _sum_squares(a[..., :2, :2] - b[..., :2, :2], 2)
        trans = _sum_squares(a[..., :2, 2] - b[..., :2, 2], 1)
    loss = rotation_weight * rot + translation_weight * trans
    return _checks.out(_reduce(loss, reduction), dtype)


_SO2_PARAMS = {"complex": (2,), "matrix": (2, 2), "angle": (1,)}
_SE2_PARAMS = {"pos_complex": (4,), "matrix": (3, 3), "twist": (3,)}


def _polar2(M: Tensor) -> Tensor:
    """Nearest rotation of 2x2 matrices: the rotation of ``(M00 + M11, M10 - M01)``."""
    return _unit_complex(torch.stack(so2.conformal(M), dim=-1))


class SO2Parametrization(nn.Module):
    """Keep a parameter on SO(2) (as :class:`SO3Parametrization`).

    * ``"complex"`` (default): ``(..., 2)`` ``(re, im)``, read as the rotation of ``z / |z|``
      (``z = 0`` reads as the identity); ``right_inverse`` is :func:`torchlie.so2.to_complex`.
    * ``"matrix"``: an unconstrained ``(..., 2, 2)`` matrix read as its nearest rotation;
      ``right_inverse`` stores the assigned matrix.
    * ``"angle"``: the angle ``(..., 1)`` read as :func:`torchlie.so2.exp`; ``right_inverse`` is
      :func:`torchlie.so2.log`.  A chart without singularity (SO(2) is commutative).

    Example:
        >>> from torch.nn.utils import parametrize
        >>> holder = torch.nn.Module()
        >>> holder.R = torch.nn.Parameter(so2.identity(3))
        >>> _ = parametrize.register_parametrization(holder, "R", SO2Parametrization())
        >>> with torch.no_grad():
        ...     _ = holder.parametrizations.R.original.add_(torch.randn(3, 2))
        >>> bool(so2.is_valid(holder.R).all())
        True
    """

    def __init__(self, representation: str = "complex") -> None:
        super().__init__()
        _check_choice(_NAME + "SO2Parametrization", "representation", representation, _SO2_PARAMS)
        self.representation = representation

    def extra_repr(self) -> str:
        return f"representation={self.representation!r}"

    def forward(self, X: Tensor) -> Float[Tensor, "*b 2 2"]:
        """The rotations ``(..., 2, 2)`` of the stored parameter ``X``."""
        _checks.tensor(X, _NAME + "SO2Parametrization", "X", _SO2_PARAMS[self.representation])
        if self.representation == "complex":
            return _unit_complex(X)
        if self.representation == "matrix":
            return _polar2(X)
        return so2.exp(X)

    def right_inverse(self, R: Float[Tensor, "*b 2 2"]) -> Tensor:
        """The stored parameter that reads as the rotations ``R``."""
        _checks.tensor(R, _NAME + "SO2Parametrization.right_inverse", "R", (2, 2))
        if self.representation == "complex":
            return so2.to_complex(R)
        if self.representation == "matrix":
            return R.clone()
        return so2.log(R)


class SE2Parametrization(nn.Module):
    """Keep a parameter on SE(2) (as :class:`SE3Parametrization`).

    * ``"pos_complex"`` (default): ``(..., 4)`` ``(t_x, t_y, re, im)``: translation as it is,
      rotation as :class:`SO2Parametrization`'s ``"complex"``.
    * ``"matrix"``: an unconstrained ``(..., 3, 3)`` matrix: rotation block read as its nearest
      rotation, translation column as it is, bottom row not read.
    * ``"twist"``: ``(..., 3)`` read as :func:`torchlie.se2.exp`; ``right_inverse`` is
      :func:`torchlie.se2.log`.

    Example:
        >>> from torch.nn.utils import parametrize
        >>> holder = torch.nn.Module()
        >>> holder.pose = torch.nn.Parameter(se2.identity(3))
        >>> _ = parametrize.register_parametrization(holder, "pose", SE2Parametrization())
        >>> with torch.no_grad():
        ...     _ = holder.parametrizations.pose.original.add_(torch.randn(3, 4))
        >>> bool(se2.is_valid(holder.pose).all())
        True
    """

    def __init__(self, representation: str = "pos_complex") -> None:
        super().__init__()
        _check_choice(_NAME + "SE2Parametrization", "representation", representation, _SE2_PARAMS)
        self.representation = representation

    def extra_repr(self) -> str:
        return f"representation={self.representation!r}"

    def forward(self, X: Tensor) -> Float[Tensor, "*b 3 3"]:
        """The poses ``(..., 3, 3)`` of the stored parameter ``X``."""
        _checks.tensor(X, _NAME + "SE2Parametrization", "X", _SE2_PARAMS[self.representation])
        if self.representation == "pos_complex":
            return se2.from_rt(_unit_complex(X[..., 2:]), X[..., :2])
        if self.representation == "matrix":
            return se2.from_rt(_polar2(X[..., :2, :2]), X[..., :2, 2])
        return se2.exp(X)

    def right_inverse(self, T: Float[Tensor, "*b 3 3"]) -> Tensor:
        """The stored parameter that reads as the poses ``T``."""
        _checks.tensor(T, _NAME + "SE2Parametrization.right_inverse", "T", (3, 3))
        if self.representation == "pos_complex":
            return torch.cat((T[..., :2, 2], T[..., :2, 0]), dim=-1)
        if self.representation == "matrix":
            return T.clone()
        return se2.log(T)


@_checks.float32_exact
def sim3_geodesic_loss(
    T_pred: Float[Tensor, "*b1 4 4"],
    T_target: Float[Tensor, "*b2 4 4"],
    rotation_weight: float = 1.0,
    translation_weight: float = 1.0,
    scale_weight: float = 1.0,
    kind: str = "angle",
    reduction: str = "mean",
) -> Float[Tensor, "*b"]:
    """Weighted similarity error ``rotation_weight * rot + translation_weight * trans +
    scale_weight * scale``.

    ``kind="angle"``: the three parts of :func:`torchlie.sim3.distance`: the rotation angle of
    ``R_pred^T R_target``, ``|t_pred - t_target|`` and ``|log(s_pred / s_target)|`` (each with
    the zero subgradient where it is not differentiable, so gradients are always finite).
    ``kind="chordal"``: ``|R_pred - R_target|_F^2``, ``|t_pred - t_target|^2`` and
    ``log(s_pred / s_target)^2``, smooth everywhere.  Arguments as :func:`se3_geodesic_loss`.

    Example:
        >>> T = sim3.from_srt(torch.tensor(2.0), torch.eye(3), torch.tensor([3.0, 4.0, 0.0]))
        >>> sim3_geodesic_loss(T, sim3.identity(), scale_weight=0.0)
        tensor(5.)
    """
    fn = _NAME + "sim3_geodesic_loss"
    _check_choice(fn, "kind", kind, ("angle", "chordal"))
    _check_choice(fn, "reduction", reduction, _REDUCTIONS)
    w_rot = _checks.nonnegative(rotation_weight, fn, "rotation_weight")
    w_trans = _checks.nonnegative(translation_weight, fn, "translation_weight")
    w_scale = _checks.nonnegative(scale_weight, fn, "scale_weight")
    a, b, dtype, _ = _checks.pair(fn, T_pred, T_target, "T_pred", "T_target", (4, 4), (4, 4))
    if kind == "angle":
        rot, trans, scale = sim3.distance(a, b)
    else:
        sa, Ra, ta = sim3.to_srt(a)
        sb, Rb, tb = sim3.to_srt(b)
        rot, trans = _sum_squares(Ra - Rb, 2), _sum_squares(ta - tb, 1)
        scale = (torch.log(sa) - torch.log(sb)).square()  # sa / sb may overflow
    loss = w_rot * rot + w_trans * trans + w_scale * scale
    return _checks.out(_reduce(loss, reduction), dtype)


_SIM3_PARAMS = {"pos_quat_sigma": (8,), "matrix": (4, 4), "tangent": (7,)}


def _nearest_similarity(A: Tensor) -> tuple[Tensor, Tensor]:
    """Scale ``(...)`` and rotation ``(..., 3, 3)`` of the multiple ``s R`` of a rotation nearest
    to the 3x3 blocks ``A`` in the Frobenius norm (rule: :class:`Sim3Parametrization`)."""
    m = A.detach().abs().amax((-2, -1), keepdim=True)
    # No normal-sized entry (the zero block included): the identity, with a zero gradient (the
    # rotation's true derivative, of the order of 1 / |A|, is not finite there).
    small = m < torch.finfo(A.dtype).tiny
    B = torch.where(small, torch.eye(3, dtype=A.dtype, device=A.device), A)
    R = so3.project(B)
    # s = tr(R^T B) / 3 >= (largest |B_ij|) / 3 > 0, summed on B / k (exact, k the power of two
    # of its largest entry) so that the sum cannot overflow before the division.
    k = _coeffs.power_of_two(torch.where(small, torch.ones_like(m), m))
    s = k[..., 0, 0] * ((R * (B / k)).sum((-2, -1)) / 3)
    return s, R


class Sim3Parametrization(nn.Module):
    """Keep a parameter on Sim(3): for :func:`torch.nn.utils.parametrize.register_parametrization`.

    The registered tensor is always read as valid similarities ``(..., 4, 4)`` (as
    :class:`SE3Parametrization`).  ``representation`` chooses the stored parameter:

    * ``"pos_quat_sigma"`` (default): ``(..., 8)`` ``(t, q, sigma)``, read as
      :func:`torchlie.sim3.from_srt` of ``exp(sigma)``, the rotation of ``q / |q|`` (``q = 0``
      reads as the identity rotation) and ``t``: translation, rotation and log scale
      decoupled, and the scale positive whatever the optimiser does (while ``exp(sigma)`` is
      representable: an optimisation that diverges to ``sigma`` below about -104 in float32
      or -745 in float64 reads a scale of 0).
    * ``"matrix"``: an unconstrained ``(..., 4, 4)`` matrix; its top-left 3x3 block ``A`` is
      read as the nearest similarity ``s R`` in the Frobenius norm: ``R`` its nearest rotation
      (:func:`torchlie.so3.project`) and ``s = tr(R^T A) / 3``, which is at least a third of
      ``A``'s largest entry, so positive for every nonzero block; the translation column as it
      is; the bottom row is not read (and gets no gradient).  A block with no entry of
      magnitude at least the smallest normal number (the zero block above all) reads as
      ``s = 1``, ``R = I`` with a zero gradient, never NaN.  ``right_inverse`` stores the
      assigned similarity as it is.  Costs and drift as :class:`SO3Parametrization`'s
      ``"matrix"``; keep it out of weight decay.
    * ``"tangent"``: ``(..., 7)`` ``(rho, phi, sigma)`` read as :func:`torchlie.sim3.exp`;
      ``right_inverse`` is :func:`torchlie.sim3.log` (the parts coupled, as SE(3)'s twist).

    Example:
        >>> from torch.nn.utils import parametrize
        >>> holder = torch.nn.Module()
        >>> holder.T = torch.nn.Parameter(sim3.identity(5))
        >>> _ = parametrize.register_parametrization(holder, "T", Sim3Parametrization())
        >>> with torch.no_grad():
        ...     _ = holder.parametrizations.T.original.add_(torch.randn(5, 8))
        >>> bool(sim3.is_valid(holder.T).all())
        True
    """

    def __init__(self, representation: str = "pos_quat_sigma") -> None:
        super().__init__()
        fn = _NAME + "Sim3Parametrization"
        _check_choice(fn, "representation", representation, _SIM3_PARAMS)
        self.representation = representation

    def extra_repr(self) -> str:
        return f"representation={self.representation!r}"

    def forward(self, X: Tensor) -> Float[Tensor, "*b 4 4"]:
        """The similarities ``(..., 4, 4)`` of the stored parameter ``X``."""
        x, dtype = _checks.tensor(
            X, _NAME + "Sim3Parametrization", "X", _SIM3_PARAMS[self.representation]
        )
        if self.representation == "tangent":
            return sim3.exp(X)
        if self.representation == "matrix":
            s, R = _nearest_similarity(x[..., :3, :3])
            return _checks.out(sim3.from_srt(s, R, x[..., :3, 3]), dtype)
        R = _quat.to_matrix(_identity_if_zero(X[..., 3:7]))
        return sim3.from_srt(torch.exp(X[..., 7]), R, X[..., :3])

    def right_inverse(self, T: Float[Tensor, "*b 4 4"]) -> Tensor:
        """The stored parameter that reads as the similarities ``T``."""
        _checks.tensor(T, _NAME + "Sim3Parametrization.right_inverse", "T", (4, 4))
        if self.representation == "tangent":
            return sim3.log(T)
        if self.representation == "matrix":
            return T.clone()  # never alias the caller's tensor
        s, R, t = sim3.to_srt(T)
        return torch.cat((t, _quat.from_matrix(R), torch.log(s).unsqueeze(-1)), -1)
