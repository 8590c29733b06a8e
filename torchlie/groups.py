"""Thin, immutable group-element classes: :class:`SO3`, :class:`SE3`, :class:`SO2`, :class:`SE2`
and :class:`Sim3`.

Each object wraps exactly one tensor, ``.tensor``: rotation matrices ``(..., 3, 3)`` for
:class:`SO3` and ``(..., 2, 2)`` for :class:`SO2`, homogeneous matrices ``(..., 4, 4)`` for
:class:`SE3` and :class:`Sim3` and ``(..., 3, 3)`` for :class:`SE2`.  Every method is one call into
the functional core (:mod:`torchlie.so3`, :mod:`torchlie.se3`, :mod:`torchlie.so2`,
:mod:`torchlie.se2`, :mod:`torchlie.sim3`, :mod:`torchlie.quaternion`), so
values, gradients, batching and the conventions of :mod:`torchlie` are exactly those of the
functions.  The classes are not tensor subclasses and not modules: they hold no state besides the
tensor, cannot be mutated, and cost one Python object per call.

* ``X @ Y`` composes two elements of the same group (batch shapes broadcast);
  ``X @ p`` with a plain tensor ``p`` of points (``(..., 3)``, ``(..., 2)`` for the planar
  groups) acts on them (``X.apply(p)``).
  Inside ``torch.compile(fullgraph=True)`` use the named methods ``X.compose(Y)`` and
  ``X.apply(p)``: torch 2.13's Dynamo does not trace ``@`` on user-defined classes (2.15's does).
* ``X.shape`` is the *batch* shape; ``len(X)``, ``X[i]``, ``X[1:3]``, ``X[..., 0]`` index the
  batch dimensions only and return the same class.
* Property or method, by one rule: a *property* is a noun for data the element stores, read
  without arguments or arithmetic (``.tensor``, ``.matrix``, ``.rotation``, ``.translation``
  and the metadata ``.shape``, ``.ndim``, ``.dtype``, ``.device``, ``.requires_grad``); a
  *method* takes arguments, is a verb, or computes new numbers: group operations and maps
  (``.inverse()``, ``.log()``, ``.adjoint()``, ``.apply(p)``) and changes of representation
  (``.quaternion()``, ``.pos_quat()``, ``.to_rt()``).  So ``(T @ T.inverse()).matrix`` is a
  tensor, as ``.tensor`` is.
* ``X == Y`` is Python's identity, as for any object (not an element-wise comparison): compare
  values with ``torch.equal(X.tensor, Y.tensor)`` or ``X.distance(Y)``.
* The classes are registered as pytree nodes (one leaf, the tensor), so they can be passed into
  and returned from ``torch.func`` transforms and ``torch.compile`` d functions.  A transform
  that maps leaves maps the tensor: ``torch.func.grad`` with respect to an ``SO3`` returns an
  ``SO3`` wrapping the *ambient* gradient ``dL/dR``, which is not a rotation.

Shape and dtype checks in the constructors are free (metadata only), and their errors are the
same with and without ``check=``.  ``check=True`` also checks the values (``is_valid``, unit
norms, positive scales), which synchronises a GPU; it raises ``ValueError``.  Errors name what
was called: a bad argument of ``X @ p`` raises ``torchlie.SO3.__matmul__ (through
torchlie.so3.act): ...``, naming the method first and then the function that checked it (whose
argument names the message uses).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator
from types import ModuleType
from typing import Any, ClassVar, TypeVar

import torch
import torch.utils._pytree as _pytree
from torch import Tensor

from . import _checks
from . import quaternion as _quat
from . import se2 as _se2
from . import se3 as _se3
from . import sim3 as _sim3
from . import so2 as _so2
from . import so3 as _so3
from ._typing import Bool, Float

__all__ = ["SO3", "SE3", "SO2", "SE2", "Sim3"]


def __dir__() -> list[str]:
    # dir() lists the public API only, not the names this module imports (torch, Tensor, ...).
    return sorted(__all__)


_G = TypeVar("_G", bound="_Group")
_F = TypeVar("_F", bound=Callable[..., Any])
_CORES = (
    "torchlie.so3.",
    "torchlie.se3.",
    "torchlie.quaternion.",
    "torchlie.so2.",
    "torchlie.se2.",
    "torchlie.sim3.",
)


def _as_method(op: str) -> Callable[[_F], _F]:
    """Report the functional core's ``TypeError`` / ``ValueError`` under the method ``op``.

    The core names itself (``torchlie.so3.act: ...``); the error is raised again as
    ``torchlie.SO3.apply (through torchlie.so3.act): ...``.  Free when nothing is raised.
    """

    def decorate(method: _F) -> _F:
        @functools.wraps(method)
        def named(obj: Any, *args: Any, **kwargs: Any) -> Any:
            try:
                return method(obj, *args, **kwargs)
            except (TypeError, ValueError) as err:
                raise _renamed(err, obj, op) from None

        return named  # type: ignore[return-value]

    return decorate


def _renamed(err: Exception, obj: Any, op: str) -> Exception:
    head, sep, rest = str(err).partition(": ")
    if not (sep and head.startswith(_CORES)):
        return err
    cls = obj if isinstance(obj, type) else type(obj)
    return type(err)(f"torchlie.{cls.__name__}.{op} (through {head}): {rest}")


class _Group:
    """Behaviour shared by the five classes (not public)."""

    __slots__ = ("tensor",)

    tensor: Tensor
    _core: ClassVar[ModuleType]
    _n: ClassVar[int]  # matrix size: 2, 3 or 4
    _dof: ClassVar[int]  # tangent dimension: 1, 3, 6 or 7

    # -- construction ----------------------------------------------------------------------

    def __init__(self, tensor: Tensor, *, check: bool = False, atol: float | None = None) -> None:
        name = "torchlie." + type(self).__name__
        _checks.tensor(tensor, name, "tensor", (self._n, self._n))
        tol = _checks.tolerance(atol, name, "atol", tensor.dtype)
        if check:
            _check_valid(name, self._core.is_valid(tensor, atol=tol), "a valid group element")
        object.__setattr__(self, "tensor", tensor)

    @classmethod
    def _wrap(cls: type[_G], tensor: Any) -> _G:
        """Wrap without checks (results of the core, and pytree leaves of any type)."""
        obj = object.__new__(cls)
        object.__setattr__(obj, "tensor", tensor)
        return obj

    def __setattr__(self, name: str, value: object) -> None:
        raise AttributeError(f"{type(self).__name__} is immutable")

    def __delattr__(self, name: str) -> None:
        raise AttributeError(f"{type(self).__name__} is immutable")

    def __reduce__(self):
        return (_rebuild, (type(self), self.tensor))

    @classmethod
    @_as_method("exp")
    def exp(cls: type[_G], tangent: Tensor) -> _G:
        """``Exp`` of a tangent vector of the group's convention (:mod:`torchlie`): rotation
        vector ``(..., 3)`` (SO3), twist ``(..., 6)`` (SE3), angle ``(..., 1)`` (SO2), twist
        ``(rho_x, rho_y, theta)`` (SE2), ``(rho, phi, sigma)`` ``(..., 7)`` (Sim3).

        Example:
            >>> SO3.exp(torch.zeros(5, 3)).shape
            torch.Size([5])
        """
        return cls._wrap(cls._core.exp(tangent))

    @classmethod
    @_as_method("identity")
    def identity(
        cls: type[_G],
        *batch: int,
        dtype: torch.dtype | None = None,
        device: torch.device | str | None = None,
    ) -> _G:
        """Identity elements of batch shape ``batch``.

        Example:
            >>> SE3.identity(2, dtype=torch.float64).log()
            tensor([[0., 0., 0., 0., 0., 0.],
                    [0., 0., 0., 0., 0., 0.]], dtype=torch.float64)
        """
        return cls._wrap(cls._core.identity(*batch, dtype=dtype, device=device))

    @classmethod
    @_as_method("random")
    def random(
        cls: type[_G],
        *batch: int,
        generator: torch.Generator | None = None,
        dtype: torch.dtype | None = None,
        device: torch.device | str | None = None,
    ) -> _G:
        """Random elements of batch shape ``batch`` (the core's ``random``).

        Example:
            >>> SO3.random(3, generator=torch.Generator().manual_seed(0)).is_valid()
            tensor([True, True, True])
        """
        return cls._wrap(cls._core.random(*batch, generator=generator, dtype=dtype, device=device))

    # -- group operations ------------------------------------------------------------------

    @_as_method("__matmul__")
    def __matmul__(self, other: object) -> Any:
        if type(other) is type(self):
            return type(self)._wrap(self._core.compose(self.tensor, other.tensor))
        if isinstance(other, Tensor):
            return self._core.act(self.tensor, other)
        if isinstance(other, _Group):
            name = type(self).__name__
            raise TypeError(
                f"torchlie.{name}.__matmul__: expected another {name} or a tensor of points, "
                f"got {type(other).__name__}"
            )
        return NotImplemented

    @_as_method("compose")
    def compose(self: _G, other: _G) -> _G:
        """``self @ other`` (batch shapes broadcast); use it in ``torch.compile`` d code.

        torch 2.13's Dynamo cannot trace the ``@`` operator on user-defined classes (2.15's can):
        it graph breaks, and ``fullgraph=True`` raises.  The named methods trace in both.

        Example:
            >>> X = SO3.exp(torch.tensor([0.0, 0.0, 0.25]))
            >>> X.compose(X).log()
            tensor([0.0000, 0.0000, 0.5000])
        """
        _same_group("compose", self, other)
        return type(self)._wrap(self._core.compose(self.tensor, other.tensor))

    @_as_method("apply")
    def apply(self, points: Float[Tensor, "*b1 3"]) -> Float[Tensor, "*b 3"]:
        """Act on points ``(..., 3)`` (``self @ points``; batch shapes broadcast; the planar
        groups take points ``(..., 2)``).

        Example:
            >>> SE3.from_rt(torch.eye(3), torch.ones(3)).apply(torch.zeros(2, 3))
            tensor([[1., 1., 1.],
                    [1., 1., 1.]])
        """
        return self._core.act(self.tensor, points)

    @_as_method("inverse")
    def inverse(self: _G) -> _G:
        """The inverse element.

        Example:
            >>> SE3.from_rt(torch.eye(3), torch.ones(3)).inverse().translation
            tensor([-1., -1., -1.])
        """
        return type(self)._wrap(self._core.inverse(self.tensor))

    @_as_method("log")
    def log(self) -> Tensor:
        """``Log``: the tangent vector of :meth:`exp`'s convention (rotation vector ``(..., 3)``,
        twist ``(..., 6)``, angle ``(..., 1)``, planar twist ``(..., 3)``, ``(..., 7)``).

        Example:
            >>> SO3.exp(torch.tensor([0.1, 0.2, 0.3])).log()
            tensor([0.1000, 0.2000, 0.3000])
        """
        return self._core.log(self.tensor)

    @_as_method("adjoint")
    def adjoint(self) -> Tensor:
        """Adjoint matrix ``(..., dof, dof)``: ``X Exp(tau) X^-1 = Exp(Ad_X tau)``.

        Example:
            >>> SE3.identity().adjoint().shape
            torch.Size([6, 6])
        """
        return self._core.adjoint(self.tensor)

    @_as_method("rplus")
    def rplus(self: _G, tau: Tensor) -> _G:
        """``self (+) tau = self Exp(tau)`` (``tau`` in the body frame).

        Example:
            >>> SO3.identity().rplus(torch.tensor([0.0, 0.5, 0.0])).log()
            tensor([0.0000, 0.5000, 0.0000])
        """
        return type(self)._wrap(self._core.rplus(self.tensor, tau))

    @_as_method("lplus")
    def lplus(self: _G, tau: Tensor) -> _G:
        """``Exp(tau) self`` (``tau`` in the world frame).

        Example:
            >>> T = SE3.from_rt(torch.eye(3), torch.tensor([1.0, 0.0, 0.0]))
            >>> T.lplus(torch.tensor([0.0, 2.0, 0.0, 0.0, 0.0, 0.0])).translation
            tensor([1., 2., 0.])
        """
        return type(self)._wrap(self._core.lplus(self.tensor, tau))

    @_as_method("rminus")
    def rminus(self: _G, other: _G) -> Tensor:
        """``self (-) other = Log(other^-1 self)``, so ``other.rplus(self.rminus(other)) == self``.

        Example:
            >>> a, b = SO3.exp(torch.tensor([0.0, 0.0, 0.5])), SO3.identity()
            >>> a.rminus(b)
            tensor([0.0000, 0.0000, 0.5000])
        """
        _same_group("rminus", self, other)
        return self._core.rminus(self.tensor, other.tensor)

    @_as_method("lminus")
    def lminus(self: _G, other: _G) -> Tensor:
        """``Log(self other^-1)``, the left-perturbation difference.

        Example:
            >>> a, b = SO3.exp(torch.tensor([0.0, 0.0, 0.5])), SO3.identity()
            >>> a.lminus(b)
            tensor([0.0000, 0.0000, 0.5000])
        """
        _same_group("lminus", self, other)
        return self._core.lminus(self.tensor, other.tensor)

    @_as_method("between")
    def between(self: _G, other: _G) -> _G:
        """``self^-1 other``: ``other`` expressed in the frame of ``self``.

        Example:
            >>> a = SE3.from_rt(torch.eye(3), torch.tensor([1.0, 0.0, 0.0]))
            >>> b = SE3.from_rt(torch.eye(3), torch.tensor([1.0, 2.0, 0.0]))
            >>> a.between(b).translation
            tensor([0., 2., 0.])
        """
        _same_group("between", self, other)
        return type(self)._wrap(self._core.between(self.tensor, other.tensor))

    @_as_method("interpolate")
    def interpolate(self: _G, other: _G, t: Tensor | float) -> _G:
        """Geodesic interpolation ``self Exp(t Log(self^-1 other))`` (``t`` broadcasts).

        Example:
            >>> a, b = SO3.identity(), SO3.exp(torch.tensor([0.0, 0.0, 1.0]))
            >>> a.interpolate(b, torch.tensor([0.25, 0.5])).log()
            tensor([[0.0000, 0.0000, 0.2500],
                    [0.0000, 0.0000, 0.5000]])
        """
        _same_group("interpolate", self, other)
        return type(self)._wrap(self._core.interpolate(self.tensor, other.tensor, t))

    @_as_method("distance")
    def distance(self: _G, other: _G) -> Any:
        """The core's ``distance``: the angle (SO3, SO2), ``(angle, translation norm)`` (SE3,
        SE2), ``(angle, translation norm, |log scale|)`` (Sim3) (see each module's
        ``distance``).

        Example:
            >>> SO3.identity().distance(SO3.exp(torch.tensor([0.0, 0.3, 0.4])))
            tensor(0.5000)
        """
        _same_group("distance", self, other)
        return self._core.distance(self.tensor, other.tensor)

    @_as_method("is_valid")
    def is_valid(self, atol: float | None = None) -> Bool[Tensor, "*b"]:
        """Per-element value check (reads the values; see the core's ``is_valid``).

        Example:
            >>> SO3(torch.stack((torch.eye(3), 2 * torch.eye(3)))).is_valid()
            tensor([ True, False])
        """
        return self._core.is_valid(self.tensor, atol=atol)

    # -- views and conversions -------------------------------------------------------------

    @property
    def matrix(self) -> Tensor:
        """The wrapped matrix ``(..., n, n)``: the same tensor as ``.tensor``, not a copy.

        Example:
            >>> SO3.identity().matrix
            tensor([[1., 0., 0.],
                    [0., 1., 0.],
                    [0., 0., 1.]])
        """
        return self.tensor

    @property
    def shape(self) -> torch.Size:
        """The batch shape (the matrix dimensions excluded)."""
        return self.tensor.shape[:-2]

    @property
    def ndim(self) -> int:
        """The number of batch dimensions."""
        return self.tensor.dim() - 2

    @property
    def dtype(self) -> torch.dtype:
        return self.tensor.dtype

    @property
    def device(self) -> torch.device:
        return self.tensor.device

    @property
    def requires_grad(self) -> bool:
        return self.tensor.requires_grad

    def __len__(self) -> int:
        if self.tensor.dim() == 2:
            raise TypeError(f"len() of an unbatched {type(self).__name__}")
        return self.tensor.shape[0]

    def __getitem__(self: _G, key: Any) -> _G:
        if not isinstance(key, tuple):
            key = (key,)
        # The two explicit full slices pin the matrix dimensions: the key indexes batch
        # dimensions only, and indexing past them raises IndexError.
        return type(self)._wrap(self.tensor[key + (slice(None), slice(None))])

    def __iter__(self: _G) -> Iterator[_G]:
        for i in range(len(self)):
            yield self[i]

    def to(self: _G, *args: Any, **kwargs: Any) -> _G:
        """``Tensor.to`` on the wrapped tensor (dtype and/or device).

        Example:
            >>> SO3.identity().to(torch.float64).dtype
            torch.float64
        """
        tensor = self.tensor.to(*args, **kwargs)
        _checks.factory(f"torchlie.{type(self).__name__}.to", (), tensor.dtype)
        return type(self)._wrap(tensor)

    def detach(self: _G) -> _G:
        """The same element, cut from the autograd graph (``Tensor.detach``).

        Example:
            >>> SO3.exp(torch.ones(3, requires_grad=True)).detach().requires_grad
            False
        """
        return type(self)._wrap(self.tensor.detach())

    def clone(self: _G) -> _G:
        """A copy of the wrapped tensor, in a new object (``Tensor.clone``).

        Example:
            >>> X = SO3.identity()
            >>> X.clone().tensor is X.tensor
            False
        """
        return type(self)._wrap(self.tensor.clone())

    def requires_grad_(self: _G, requires_grad: bool = True) -> _G:
        """Set ``requires_grad`` on the wrapped tensor (a leaf) and return ``self``.

        Example:
            >>> SO3.identity(dtype=torch.float64).requires_grad_().requires_grad
            True
        """
        self.tensor.requires_grad_(requires_grad)
        return self

    def __repr__(self) -> str:
        name = type(self).__name__
        pad = " " * (len(name) + 1)
        lines = repr(self.tensor).split("\n")
        body = "\n".join([lines[0]] + [pad + s if s else s for s in lines[1:]])
        return f"{name}({body})"


def _same_group(op: str, a: _Group, b: object) -> None:
    if type(b) is not type(a):
        raise TypeError(
            f"torchlie.{type(a).__name__}.{op}: expected another {type(a).__name__}, "
            f"got {type(b).__name__}"
        )


def _check_atol(name: str, atol: object) -> None:
    if atol is not None:  # checked even without check=True: a bad value is a bug either way
        _checks.nonnegative(atol, name, "atol")


def _check_valid(name: str, ok: Tensor, what: str) -> None:
    # Reads the values (a device sync): only with check=True.
    bad = int((~ok).sum())
    if bad:
        raise ValueError(f"{name}: {bad} of {ok.numel()} element(s) are not {what}")


class SO3(_Group):
    """Rotations, wrapping rotation matrices ``(..., 3, 3)`` (``p_world = R @ p_body``).

    Properties are nouns for stored data, read without arguments or arithmetic: ``.tensor`` and
    ``.matrix`` (the same rotation matrices), ``.rotation`` (``self``, as for :class:`SE3`),
    ``.shape`` (batch shape), ``.dtype``, ...  Everything that takes arguments, is a verb or
    computes new numbers is a method: ``.log()``, ``.inverse()``, ``.apply(p)``, and the
    conversion ``.quaternion()``.

    Args:
        tensor: rotation matrices ``(..., 3, 3)``, floating point.
        check: also check the values with :func:`torchlie.so3.is_valid` (``ValueError``).
        atol: tolerance of that check (default: the core's).

    Example:
        >>> R = SO3.exp(torch.tensor([0.0, 0.0, torch.pi / 2]))
        >>> p = torch.tensor([1.0, 0.0, 0.0])
        >>> torch.allclose(R @ p, torch.tensor([0.0, 1.0, 0.0]), atol=1e-6)
        True
        >>> (R @ R).distance(SO3.identity())
        tensor(3.1416)
        >>> SO3.identity(2, 5)[1, 1:3].shape
        torch.Size([2])
    """

    __slots__ = ()
    _core = _so3
    _n = 3
    _dof = 3

    @classmethod
    @_as_method("from_quaternion")
    def from_quaternion(
        cls, q: Float[Tensor, "*b 4"], *, check: bool = False, atol: float | None = None
    ) -> SO3:
        """From wxyz quaternions ``(..., 4)`` (scale-invariant: ``q / |q|`` is used).

        With ``check=True``, raises ``ValueError`` unless every ``|q|`` is 1 within ``atol``
        (:func:`torchlie.quaternion.is_unit`) and finite.

        Example:
            >>> SO3.from_quaternion(torch.tensor([0.0, 0.0, 0.0, 1.0])).log()
            tensor([0.0000, 0.0000, 3.1416])
        """
        _check_atol("torchlie.SO3.from_quaternion", atol)
        R = cls._wrap(_quat.to_matrix(q))
        if check:
            _check_valid(
                "torchlie.SO3.from_quaternion", _quat.is_unit(q, atol=atol), "unit quaternions"
            )
        return R

    @_as_method("quaternion")
    def quaternion(self) -> Float[Tensor, "*b 4"]:
        """Canonical wxyz unit quaternions ``(..., 4)`` (``w >= 0``); a conversion, so a method.

        Example:
            >>> SO3.exp(torch.tensor([0.0, 0.0, torch.pi / 2])).quaternion()
            tensor([0.7071, 0.0000, 0.0000, 0.7071])
        """
        return _quat.from_matrix(self.tensor)

    @property
    def rotation(self) -> SO3:
        """``self``, so that code reading ``X.rotation`` of an :class:`SE3` accepts an SO3 too.

        Example:
            >>> R = SO3.identity()
            >>> R.rotation is R
            True
        """
        return self


class SE3(_Group):
    """Rigid motions, wrapping homogeneous poses ``(..., 4, 4)`` ``[[R, t], [0, 1]]``.

    Tangent vectors are twists ``(rho, phi)`` ``(..., 6)``, translation part first.

    Properties are nouns for stored data, read without arguments or arithmetic: ``.tensor`` and
    ``.matrix`` (the same poses), ``.rotation`` (the rotation block as an :class:`SO3`),
    ``.translation`` ``(..., 3)``, ``.shape`` (batch shape), ``.dtype``, ...  Everything that
    takes arguments, is a verb or computes new numbers is a method: ``.log()``,
    ``.inverse()``, ``.apply(p)``, and the conversions ``.quaternion()``, ``.pos_quat()``,
    ``.to_rt()``.

    Args:
        tensor: poses ``(..., 4, 4)``, floating point.
        check: also check the values with :func:`torchlie.se3.is_valid` (``ValueError``).
        atol: tolerance of that check (default: the core's).

    Example:
        >>> T = SE3.from_rt(torch.eye(3), torch.tensor([1.0, 2.0, 3.0]))
        >>> T @ torch.zeros(3)
        tensor([1., 2., 3.])
        >>> (T @ T).translation
        tensor([2., 4., 6.])
        >>> T.inverse().log()
        tensor([-1., -2., -3.,  0.,  0.,  0.])
    """

    __slots__ = ()
    _core = _se3
    _n = 4
    _dof = 6

    @classmethod
    @_as_method("from_rt")
    def from_rt(
        cls,
        R: Float[Tensor, "*b1 3 3"] | SO3,
        t: Float[Tensor, "*b2 3"],
        *,
        check: bool = False,
        atol: float | None = None,
    ) -> SE3:
        """From rotations (matrices ``(..., 3, 3)`` or an :class:`SO3`) and translations.

        With ``check=True``, raises ``ValueError`` unless every ``R`` is a valid rotation.
        """
        if isinstance(R, SO3):
            R = R.tensor
        _check_atol("torchlie.SE3.from_rt", atol)
        T = cls._wrap(_se3.from_rt(R, t))
        if check:
            _check_valid("torchlie.SE3.from_rt", _so3.is_valid(R, atol=atol), "rotations")
        return T

    @classmethod
    @_as_method("from_pos_quat")
    def from_pos_quat(
        cls, pq: Float[Tensor, "*b 7"], *, check: bool = False, atol: float | None = None
    ) -> SE3:
        """From 7-vectors ``(tx, ty, tz, qw, qx, qy, qz)``.

        With ``check=True``, raises ``ValueError`` unless every quaternion has unit norm
        within ``atol`` (:func:`torchlie.quaternion.is_unit`).
        """
        _check_atol("torchlie.SE3.from_pos_quat", atol)
        T = cls._wrap(_se3.from_pos_quat(pq))
        if check:
            _check_valid(
                "torchlie.SE3.from_pos_quat",
                _quat.is_unit(pq[..., 3:], atol=atol),
                "unit quaternions",
            )
        return T

    @_as_method("to_rt")
    def to_rt(self) -> tuple[Float[Tensor, "*b 3 3"], Float[Tensor, "*b 3"]]:
        """``(R, t)``: rotation matrices ``(..., 3, 3)`` and translations ``(..., 3)``."""
        return _se3.to_rt(self.tensor)

    @_as_method("pos_quat")
    def pos_quat(self) -> Float[Tensor, "*b 7"]:
        """7-vectors ``(t, q)``: translation, then the canonical wxyz quaternion."""
        return _se3.to_pos_quat(self.tensor)

    @property
    def rotation(self) -> SO3:
        """The rotation block as an :class:`SO3` (a copy, from :func:`torchlie.se3.to_rt`).

        Example:
            >>> SE3.identity().rotation
            SO3(tensor([[1., 0., 0.],
                        [0., 1., 0.],
                        [0., 0., 1.]]))
        """
        return SO3._wrap(_se3.to_rt(self.tensor)[0])

    @property
    def translation(self) -> Float[Tensor, "*b 3"]:
        """The translation column ``(..., 3)`` (a copy, from :func:`torchlie.se3.to_rt`).

        Example:
            >>> SE3.from_rt(torch.eye(3), torch.tensor([1.0, 2.0, 3.0])).translation
            tensor([1., 2., 3.])
        """
        return _se3.to_rt(self.tensor)[1]

    @_as_method("quaternion")
    def quaternion(self) -> Float[Tensor, "*b 4"]:
        """Canonical wxyz quaternion of the rotation part ``(..., 4)``."""
        return _se3.to_pos_quat(self.tensor)[..., 3:]


# -- the planar groups -------------------------------------------------------------------------


class _Planar(_Group):
    """Behaviour shared by :class:`SO2` and :class:`SE2` (not public): points are ``(..., 2)``."""

    __slots__ = ()

    @_as_method("apply")
    def apply(self, points: Float[Tensor, "*b1 2"]) -> Float[Tensor, "*b 2"]:
        """Act on points ``(..., 2)`` (``self @ points``; batch shapes broadcast).

        Example:
            >>> SE2.from_xytheta(torch.tensor([1.0, 1.0, 0.0])).apply(torch.zeros(2, 2))
            tensor([[1., 1.],
                    [1., 1.]])
        """
        return self._core.act(self.tensor, points)


class SO2(_Planar):
    """Planar rotations, wrapping rotation matrices ``(..., 2, 2)``; tangents are angles
    ``(..., 1)``.  The accessors and methods of :class:`SO3`; ``.apply`` takes points
    ``(..., 2)``.  Conversions: ``.complex()`` and :meth:`from_complex`.

    Example:
        >>> R = SO2.exp(torch.tensor([torch.pi / 2]))
        >>> (R @ torch.tensor([1.0, 0.0])).round(decimals=6) + 0.0
        tensor([0., 1.])
        >>> (R @ R @ R).log()
        tensor([-1.5708])
    """

    __slots__ = ()
    _core = _so2
    _n = 2
    _dof = 1

    @classmethod
    @_as_method("from_complex")
    def from_complex(
        cls, z: Float[Tensor, "*b 2"], *, check: bool = False, atol: float | None = None
    ) -> SO2:
        """From complex numbers ``(re, im)`` ``(..., 2)`` (scale-invariant, as
        :func:`torchlie.so2.from_complex`).

        With ``check=True``, raises ``ValueError`` unless every ``|z|`` is 1 within ``atol``
        (default as :func:`torchlie.quaternion.is_unit`) and finite.

        Example:
            >>> SO2.from_complex(torch.tensor([0.0, 2.0])).log()
            tensor([1.5708])
        """
        _check_atol("torchlie.SO2.from_complex", atol)
        R = cls._wrap(_so2.from_complex(z))
        if check:
            x, _ = _checks.tensor(z, "torchlie.SO2.from_complex", "z", (2,))  # half: in float32
            tol = _checks.tolerance(atol, "torchlie.SO2.from_complex", "atol", z.dtype)
            _check_valid(
                "torchlie.SO2.from_complex", _checks.unit_norm(x, tol), "unit complex numbers"
            )
        return R

    @_as_method("complex")
    def complex(self) -> Float[Tensor, "*b 2"]:
        """Unit complex numbers ``(cos theta, sin theta)`` ``(..., 2)``.

        Example:
            >>> SO2.identity().complex()
            tensor([1., 0.])
        """
        return _so2.to_complex(self.tensor)

    @property
    def rotation(self) -> SO2:
        """``self`` (as :attr:`SO3.rotation`)."""
        return self


class SE2(_Planar):
    """Planar rigid motions, wrapping poses ``(..., 3, 3)`` ``[[R, t], [0, 1]]``; tangents are
    twists ``(rho_x, rho_y, theta)``.  The accessors and methods of :class:`SE3`: ``.rotation``
    (an :class:`SO2`), ``.translation`` ``(..., 2)``, ``.to_rt()``, and ``.xytheta()``.

    Example:
        >>> T = SE2.from_xytheta(torch.tensor([1.0, 2.0, 0.0]))
        >>> T @ torch.zeros(2)
        tensor([1., 2.])
        >>> (T @ T).translation
        tensor([2., 4.])
    """

    __slots__ = ()
    _core = _se2
    _n = 3
    _dof = 3

    @classmethod
    @_as_method("from_rt")
    def from_rt(
        cls,
        R: Float[Tensor, "*b1 2 2"] | SO2,
        t: Float[Tensor, "*b2 2"],
        *,
        check: bool = False,
        atol: float | None = None,
    ) -> SE2:
        """From rotations (matrices ``(..., 2, 2)`` or an :class:`SO2`) and translations.

        With ``check=True``, raises ``ValueError`` unless every ``R`` is a valid rotation.

        Example:
            >>> SE2.from_rt(SO2.identity(), torch.tensor([1.0, 2.0])).translation
            tensor([1., 2.])
        """
        if isinstance(R, SO2):
            R = R.tensor
        _check_atol("torchlie.SE2.from_rt", atol)
        T = cls._wrap(_se2.from_rt(R, t))
        if check:
            _check_valid("torchlie.SE2.from_rt", _so2.is_valid(R, atol=atol), "rotations")
        return T

    @classmethod
    @_as_method("from_xytheta")
    def from_xytheta(cls, pose: Float[Tensor, "*b 3"]) -> SE2:
        """From planar coordinates ``(x, y, theta)`` (:func:`torchlie.se2.from_xytheta`).

        Example:
            >>> SE2.from_xytheta(torch.tensor([1.0, 2.0, 0.5])).xytheta()
            tensor([1.0000, 2.0000, 0.5000])
        """
        return cls._wrap(_se2.from_xytheta(pose))

    @_as_method("to_rt")
    def to_rt(self) -> tuple[Float[Tensor, "*b 2 2"], Float[Tensor, "*b 2"]]:
        """``(R, t)``: rotation matrices ``(..., 2, 2)`` and translations ``(..., 2)``.

        Example:
            >>> SE2.identity().to_rt()[1]
            tensor([0., 0.])
        """
        return _se2.to_rt(self.tensor)

    @_as_method("xytheta")
    def xytheta(self) -> Float[Tensor, "*b 3"]:
        """Planar coordinates ``(x, y, theta)`` (:func:`torchlie.se2.to_xytheta`).

        Example:
            >>> SE2.identity().xytheta()
            tensor([0., 0., 0.])
        """
        return _se2.to_xytheta(self.tensor)

    @property
    def rotation(self) -> SO2:
        """The rotation block as an :class:`SO2` (a copy).

        Example:
            >>> SE2.identity().rotation
            SO2(tensor([[1., 0.],
                        [0., 1.]]))
        """
        return SO2._wrap(_se2.to_rt(self.tensor)[0])

    @property
    def translation(self) -> Float[Tensor, "*b 2"]:
        """The translation column ``(..., 2)`` (a copy).

        Example:
            >>> SE2.from_xytheta(torch.tensor([1.0, 2.0, 0.0])).translation
            tensor([1., 2.])
        """
        return _se2.to_rt(self.tensor)[1]


class Sim3(_Group):
    """Similarities, wrapping ``(..., 4, 4)`` matrices ``[[s R, t], [0, 1]]`` (``s > 0``).

    Tangent vectors are ``(rho, phi, sigma)`` ``(..., 7)`` (:mod:`torchlie.sim3`).  Properties
    as for :class:`SE3` plus ``.scale`` ``(...)``; ``.rotation`` is the rotation ``R`` (an
    :class:`SO3`) and ``.pose()`` the rigid part ``[[R, t], [0, 1]]`` (an :class:`SE3`).

    Args:
        tensor: similarities ``(..., 4, 4)``, floating point.
        check: also check the values with :func:`torchlie.sim3.is_valid` (``ValueError``).
        atol: tolerance of that check (default: the core's).

    Example:
        >>> S = Sim3.from_srt(torch.tensor(2.0), torch.eye(3), torch.tensor([1.0, 0.0, 0.0]))
        >>> S @ torch.ones(3)
        tensor([3., 2., 2.])
        >>> (S @ S).scale
        tensor(4.)
    """

    __slots__ = ()
    _core = _sim3
    _n = 4
    _dof = 7

    @classmethod
    @_as_method("from_srt")
    def from_srt(
        cls,
        s: Float[Tensor, "*b1"],
        R: Float[Tensor, "*b2 3 3"] | SO3,
        t: Float[Tensor, "*b3 3"],
        *,
        check: bool = False,
        atol: float | None = None,
    ) -> Sim3:
        """From scales, rotations (matrices or an :class:`SO3`) and translations.

        With ``check=True``, raises ``ValueError`` unless every ``R`` is a valid rotation and
        every ``s`` positive.

        Example:
            >>> Sim3.from_srt(torch.tensor(3.0), SO3.identity(), torch.zeros(3)).scale
            tensor(3.)
        """
        if isinstance(R, SO3):
            R = R.tensor
        _check_atol("torchlie.Sim3.from_srt", atol)
        S = cls._wrap(_sim3.from_srt(s, R, t))
        if check:
            _check_valid("torchlie.Sim3.from_srt", _so3.is_valid(R, atol=atol), "rotations")
            _check_valid("torchlie.Sim3.from_srt", s > 0, "positive scales")
        return S

    @classmethod
    @_as_method("from_se3")
    def from_se3(
        cls,
        T: Float[Tensor, "*b1 4 4"] | SE3,
        s: Float[Tensor, "*b2"],
        *,
        check: bool = False,
        atol: float | None = None,
    ) -> Sim3:
        """From a rigid pose (a matrix or an :class:`SE3`) and a scale: ``[[s R, t], [0, 1]]``.

        With ``check=True``, raises ``ValueError`` unless every ``T`` is a valid rigid pose
        (:func:`torchlie.se3.is_valid`) and every ``s`` positive.

        Example:
            >>> Sim3.from_se3(SE3.identity(), torch.tensor(2.0)).scale
            tensor(2.)
        """
        if isinstance(T, SE3):
            T = T.tensor
        _check_atol("torchlie.Sim3.from_se3", atol)
        S = cls._wrap(_sim3.from_se3(T, s))
        if check:
            _check_valid("torchlie.Sim3.from_se3", _se3.is_valid(T, atol=atol), "rigid poses")
            _check_valid("torchlie.Sim3.from_se3", s > 0, "positive scales")
        return S

    @classmethod
    @_as_method("from_pos_quat_scale")
    def from_pos_quat_scale(
        cls, x: Float[Tensor, "*b 8"], *, check: bool = False, atol: float | None = None
    ) -> Sim3:
        """From 8-vectors ``(tx, ty, tz, qw, qx, qy, qz, s)``
        (:func:`torchlie.sim3.from_pos_quat_scale`).

        With ``check=True``, raises ``ValueError`` unless every quaternion has unit norm
        within ``atol`` (:func:`torchlie.quaternion.is_unit`) and every ``s`` is positive.

        Example:
            >>> x = torch.tensor([1.0, 2.0, 3.0, 1.0, 0.0, 0.0, 0.0, 2.0])
            >>> Sim3.from_pos_quat_scale(x).scale
            tensor(2.)
        """
        _check_atol("torchlie.Sim3.from_pos_quat_scale", atol)
        S = cls._wrap(_sim3.from_pos_quat_scale(x))
        if check:
            name = "torchlie.Sim3.from_pos_quat_scale"
            _check_valid(name, _quat.is_unit(x[..., 3:7], atol=atol), "unit quaternions")
            _check_valid(name, x[..., 7] > 0, "positive scales")
        return S

    @_as_method("pos_quat_scale")
    def pos_quat_scale(self) -> Float[Tensor, "*b 8"]:
        """8-vectors ``(t, q, s)``: translation, the canonical wxyz quaternion, the scale
        (:func:`torchlie.sim3.to_pos_quat_scale`).

        Example:
            >>> Sim3.identity().pos_quat_scale()
            tensor([0., 0., 0., 1., 0., 0., 0., 1.])
        """
        return _sim3.to_pos_quat_scale(self.tensor)

    @_as_method("to_srt")
    def to_srt(
        self,
    ) -> tuple[Float[Tensor, "*b"], Float[Tensor, "*b 3 3"], Float[Tensor, "*b 3"]]:
        """``(s, R, t)``: scales ``(...)``, rotation matrices and translations.

        Example:
            >>> s, R, t = Sim3.from_srt(torch.tensor(2.0), torch.eye(3), torch.ones(3)).to_srt()
            >>> s, t
            (tensor(2.), tensor([1., 1., 1.]))
        """
        return _sim3.to_srt(self.tensor)

    @_as_method("pose")
    def pose(self) -> SE3:
        """The rigid part ``[[R, t], [0, 1]]`` as an :class:`SE3` (the scale dropped).

        Example:
            >>> S = Sim3.from_srt(torch.tensor(2.0), torch.eye(3), torch.tensor([1.0, 2.0, 3.0]))
            >>> S.pose().translation
            tensor([1., 2., 3.])
        """
        _, R, t = _sim3.to_srt(self.tensor)
        return SE3._wrap(_se3.from_rt(R, t))

    @property
    def scale(self) -> Float[Tensor, "*b"]:
        """The scale ``s`` ``(...)`` (:func:`torchlie.sim3.scale`).

        Example:
            >>> Sim3.exp(torch.tensor([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])).scale
            tensor(2.7183)
        """
        return _sim3.scale(self.tensor)

    @property
    def rotation(self) -> SO3:
        """The rotation ``R = M / s`` as an :class:`SO3`.

        Example:
            >>> Sim3.from_srt(torch.tensor(5.0), torch.eye(3), torch.zeros(3)).rotation.log()
            tensor([0., 0., 0.])
        """
        return SO3._wrap(_sim3.to_srt(self.tensor)[1])

    @property
    def translation(self) -> Float[Tensor, "*b 3"]:
        """The translation column ``(..., 3)`` (a copy).

        Example:
            >>> Sim3.from_srt(torch.tensor(2.0), torch.eye(3), torch.ones(3)).translation
            tensor([1., 1., 1.])
        """
        return self.tensor[..., :3, 3].clone()

    @_as_method("quaternion")
    def quaternion(self) -> Float[Tensor, "*b 4"]:
        """Canonical wxyz quaternion of the rotation ``(..., 4)``.

        Example:
            >>> Sim3.from_srt(torch.tensor(2.0), torch.eye(3), torch.zeros(3)).quaternion()
            tensor([1., 0., 0., 0.])
        """
        return _quat.from_matrix(_sim3.to_srt(self.tensor)[1])


# -- pytrees and serialization ----------------------------------------------------------------


def _rebuild(cls: type[_G], tensor: Any) -> _G:
    """An element from its tensor, without checks (what pickling an element stores)."""
    return cls._wrap(tensor)


def _flatten(x: _Group) -> tuple[list[Any], None]:
    return [x.tensor], None


def _flatten_with_keys(x: _Group) -> tuple[list[tuple[Any, Any]], None]:
    return [(_pytree.GetAttrKey("tensor"), x.tensor)], None


_CLASSES = (SO3, SE3, SO2, SE2, Sim3)
for _cls in _CLASSES:
    _pytree.register_pytree_node(
        _cls,
        _flatten,
        lambda leaves, _ctx, _c=_cls: _c._wrap(next(iter(leaves))),
        serialized_type_name=f"torchlie.groups.{_cls.__name__}",
        flatten_with_keys_fn=_flatten_with_keys,
    )
del _cls
# ``torch.load``'s default (``weights_only=True``) unpickles only what is allowed: an element
# is its class and a tensor, nothing executable
torch.serialization.add_safe_globals([_rebuild, *_CLASSES])
