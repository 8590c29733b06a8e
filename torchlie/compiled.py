"""The functional API compiled with ``torch.compile(fullgraph=True)``, as an explicit namespace.

Eager PyTorch makes one pass over memory per elementwise operation; compiling fuses a whole op
(Rodrigues' formula, Shepperd's method, the series branches) into one kernel.  The compiled
functions mirror the eager ones name for name, with the same conventions, errors and gradients
(reverse mode; forward mode and double backward are torch.compile's: ``torch.func.jvp`` and
``jacfwd`` raise, and a dual tensor of ``torch.autograd.forward_ad`` comes back without a
tangent, so take those derivatives with the eager functions)::

    from torchlie.compiled import so3
    R = so3.exp(omega)      # first call compiles (seconds); later calls run the fused kernel

Each function is compiled on its first call and kept.  A variant of the call compiles once more:
a new dtype, rank, string argument (an Euler sequence, a frame), or inputs that now record a
gradient (or no longer do).  Within a variant a new batch shape compiles once more, after which
torch's automatic dynamic shapes cover every batch size.  Python floats (``t``, angles) are
passed as 0-dim tensors of the operands' dtype, so new values do not compile again.  Past
torch's limit of compiled graphs of one function (8) that function runs eagerly, with a
warning: two dtypes, two ranks, with and without gradients already make 8 graphs, so a
program that calls one function in that many ways should compile its own code instead
(``torch.compile`` of the caller, with :func:`inductor_options`).  Nothing global changes:
``torchlie.so3`` stays eager.  Constructors that take a ``torch.Generator`` or only shapes
(``identity``, ``random``) are passed through uncompiled.

Vectorised CPU loops.  Inductor's C++ code generator leaves a fused loop scalar when strided
loads and stores are many against its arithmetic (its ``cpp.enable_tiling_heuristics``); the ops
here read and write the components of ``(..., 3)``, ``(..., 4)`` and ``(..., 3, 3)`` tensors with
small strides, so nearly every kernel would be judged so and call the scalar ``sin``, ``cos``,
``atan2`` and ``sqrt`` once per element.  The functions here are compiled with that heuristic off
(:func:`inductor_options`), which vectorises the loop (the strided components are gathered) and
runs the transcendental functions on vectors.  Every function is compiled with the same
options.  ``torch.compile`` of one's own code that calls torchlie can pass them too:
``torch.compile(fn, options={"cpp.enable_tiling_heuristics": False})``.  GPU code generation
does not read them.

One loop per op.  Inductor fuses two element-wise computations into one loop only when they read
a common buffer, and the constant entries of a result (the ``(0, 0, 0, 1)`` row of a pose) read
none; every function here is compiled with :data:`FUSION` as well, which lets such computations
share the op's loop.  The compiled functions run the same formulas as the eager ones; their
values agree with eager's within a few ulp, not bit for bit (eager CPU multiply-adds round once,
Inductor's CPU loops round the product and the sum separately).  The first call of each
function compiles it: seconds for most ops, a minute or more on a CPU for the largest graphs
(Sim(3)'s exponential and Jacobians, with their backward).
"""

from __future__ import annotations

import functools
import types
import warnings
from collections.abc import Callable

import torch

from . import conversions as _conversions
from . import quaternion as _quaternion
from . import se2 as _se2
from . import se3 as _se3
from . import sim3 as _sim3
from . import so2 as _so2
from . import so3 as _so3

__all__ = [
    "so3",
    "se3",
    "quaternion",
    "conversions",
    "so2",
    "se2",
    "sim3",
    "inductor_options",
    "FUSION",
]

_EAGER_ONLY = frozenset({"identity", "random"})

#: Inductor options of every function here: computations that share no buffer (constant entries
#: of a result among them) are fused into one loop too, the C++ backend's limit of 16 such
#: computations per loop is raised to 64, and the limit of 64 nodes per fused loop to 256 (the
#: backward of ``se3.exp`` has more: its components, each a node, would take loops of their
#: own).  An intermediate of more than 25 operations that is used twice is kept in a variable of
#: the loop instead of being re-expanded into each use (``realize_opcount_threshold``, 50 by
#: default on CPU): the same code, generated faster.
FUSION: dict[str, bool | int] = {
    "aggressive_fusion": True,
    "score_fusion_memory_threshold": 0,
    "cpp.max_horizontal_fusion_size": 64,
    "max_fusion_size": 256,
    "realize_opcount_threshold": 25,
}

_MODULES = {
    "so3": _so3,
    "se3": _se3,
    "quaternion": _quaternion,
    "conversions": _conversions,
    "so2": _so2,
    "se2": _se2,
    "sim3": _sim3,
}


def inductor_options(module: str, name: str) -> dict[str, bool | int]:
    """The Inductor options :mod:`torchlie.compiled` compiles ``torchlie.<module>.<name>`` with.

    :data:`FUSION` and ``{"cpp.enable_tiling_heuristics": False}`` (vectorised CPU loops, see the
    module docstring), the same for every function.

    Example:
        >>> inductor_options("so3", "exp")["cpp.enable_tiling_heuristics"]
        False
    """
    fn = "torchlie.compiled.inductor_options"
    if module not in _MODULES:
        raise ValueError(f"{fn}: expected module to be one of {sorted(_MODULES)}, got {module!r}")
    if name not in _MODULES[module].__all__:
        raise ValueError(f"{fn}: torchlie.{module} has no public function {name!r}")
    return {**FUSION, "cpp.enable_tiling_heuristics": False}


def _numbers_as_tensors(args: tuple, kwargs: dict) -> tuple[tuple, dict]:
    """Python floats (``t``, angles) as 0-dim tensors of the first tensor argument's dtype and
    device: Dynamo compiles a new graph for each new float value, not for a tensor's."""
    like = next((a for a in (*args, *kwargs.values()) if isinstance(a, torch.Tensor)), None)
    if like is None or not like.is_floating_point():
        return args, kwargs

    def conv(a):
        if isinstance(a, float):
            return torch.tensor(a, dtype=like.dtype, device=like.device)
        return a

    return tuple(conv(a) for a in args), {k: conv(v) for k, v in kwargs.items()}


def _compile(fn: Callable, options: dict[str, bool | int]) -> Callable:
    compiled = torch.compile(fn, fullgraph=True, options=options)
    eager = False  # set once torch's limit of compiled variants is reached

    @functools.wraps(fn)
    def call(*args, **kwargs):
        nonlocal eager
        if eager:
            return fn(*args, **kwargs)
        args, kwargs = _numbers_as_tensors(args, kwargs)
        try:
            return compiled(*args, **kwargs)
        except torch._dynamo.exc.FailOnRecompileLimitHit:
            # Each dtype, rank, string argument (an Euler sequence, a frame) and gradient
            # recording is a variant of its own; past torch's limit of them the function runs
            # eagerly (same results).
            warnings.warn(
                f"torchlie.compiled: {fn.__qualname__} reached torch.compile's limit of "
                "recompilations (one per dtype, rank, string argument and whether the inputs "
                "record a gradient, and one more per new batch shape); it runs eagerly from now "
                "on",
                stacklevel=2,
            )
            eager = True
            return fn(*args, **kwargs)
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
        short = module.__name__.rsplit(".", 1)[-1]
        super().__init__(f"torchlie.compiled.{short}")
        self._short = short
        self.__doc__ = f"Compiled mirror of :mod:`{module.__name__}`."
        self._eager = module
        self.__all__ = list(module.__all__)

    def __getattr__(self, name: str) -> Callable:
        if name.startswith("_") or name not in self._eager.__all__:
            raise AttributeError(f"{self.__name__} has no function {name!r}")
        fn = getattr(self._eager, name)
        if name not in _EAGER_ONLY:
            fn = _compile(fn, inductor_options(self._short, name))
        setattr(self, name, fn)  # compiled once, kept on the namespace
        return fn

    def __dir__(self) -> list[str]:
        return list(self.__all__)


so3 = _CompiledNamespace(_so3)
se3 = _CompiledNamespace(_se3)
quaternion = _CompiledNamespace(_quaternion)
conversions = _CompiledNamespace(_conversions)
so2 = _CompiledNamespace(_so2)
se2 = _CompiledNamespace(_se2)
sim3 = _CompiledNamespace(_sim3)
