"""The functional API compiled with ``torch.compile(fullgraph=True)``, as an explicit namespace.

Eager PyTorch makes one pass over memory per elementwise operation; compiling fuses a whole op
(Rodrigues' formula, Shepperd's method, the series branches) into one kernel.  The compiled
functions mirror the eager ones name for name, with the same conventions, errors and gradients::

    from torchlie.compiled import so3
    R = so3.exp(omega)      # first call compiles (seconds); later calls run the fused kernel

Each function is compiled on its first call and kept; a call with a new batch shape or dtype may
compile once more (torch's automatic dynamic shapes take over after the second shape).  Nothing
global changes: ``torchlie.so3`` stays eager.  Constructors that take a ``torch.Generator`` or
only shapes (``identity``, ``random``) are passed through uncompiled.
"""

from __future__ import annotations

import functools
import types
from collections.abc import Callable

import torch

from . import conversions as _conversions
from . import quaternion as _quaternion
from . import se3 as _se3
from . import so3 as _so3

__all__ = ["so3", "se3", "quaternion", "conversions"]

_EAGER_ONLY = frozenset({"identity", "random"})


def _compile(fn: Callable) -> Callable:
    compiled = torch.compile(fn, fullgraph=True)

    @functools.wraps(fn)
    def call(*args, **kwargs):
        try:
            return compiled(*args, **kwargs)
        except torch._dynamo.exc.TorchDynamoException:
            # Bad input raises inside the traced code, where Dynamo re-wraps it: the eager
            # function raises the library's own error for it.  If the eager call succeeds, the
            # compile failure is genuine and is raised as it is.
            fn(*args, **kwargs)
            raise

    return call


class _CompiledNamespace(types.ModuleType):
    """A module-like object whose public functions are compiled versions of ``module``'s."""

    def __init__(self, module: types.ModuleType) -> None:
        super().__init__(f"torchlie.compiled.{module.__name__.rsplit('.', 1)[-1]}")
        self.__doc__ = f"Compiled mirror of :mod:`{module.__name__}`."
        self._eager = module
        self.__all__ = list(module.__all__)

    def __getattr__(self, name: str) -> Callable:
        if name.startswith("_") or name not in self._eager.__all__:
            raise AttributeError(f"{self.__name__} has no function {name!r}")
        fn = getattr(self._eager, name)
        if name not in _EAGER_ONLY:
            fn = _compile(fn)
        setattr(self, name, fn)  # compiled once, kept on the namespace
        return fn

    def __dir__(self) -> list[str]:
        return list(self.__all__)


so3 = _CompiledNamespace(_so3)
se3 = _CompiledNamespace(_se3)
quaternion = _CompiledNamespace(_quaternion)
conversions = _CompiledNamespace(_conversions)
