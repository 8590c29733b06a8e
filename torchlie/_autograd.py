"""Custom autograd Functions, built from plain functions.

Each differentiable op that needs its own derivative (the log maps, whose naive derivative is
infinite at theta = pi, and a few ops whose closed-form backward is much cheaper than autograd's)
is declared with :func:`custom_function` from four pure functions:

* ``forward(*inputs) -> output``       values only (runs without autograd);
* ``save(inputs, output) -> tuple``     the tensors the derivatives need;
* ``backward(saved, grad) -> grads``    written in differentiable torch ops, so double
  backward works;
* ``jvp(saved, *tangents) -> tangent``  forward mode (``torch.func.jvp`` / ``jacfwd``).

The vmap rule is generated (``generate_vmap_rule = True``): every piece is batch-agnostic.

``torch.compile`` (Dynamo) does not trace Functions that define ``jvp``, so each op is built
twice, with and without ``jvp``, and :meth:`CustomFunction.__call__` picks the one without
while compiling.  That choice reads a flag of the tracer, never a tensor value.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch
from torch import Tensor
from torch.autograd import Function


class CustomFunction:
    """A callable pair of ``torch.autograd.Function`` s (eager with jvp; compiled without)."""

    def __init__(
        self,
        name: str,
        forward: Callable[..., Tensor],
        save: Callable[[Sequence[Tensor], Tensor], tuple[Tensor, ...]],
        backward: Callable[..., tuple[Tensor | None, ...]],
        jvp: Callable[..., Tensor],
    ) -> None:
        def _forward(*inputs: Tensor) -> Tensor:
            return forward(*inputs)

        def _setup_context(ctx, inputs, output) -> None:
            saved = save(inputs, output)
            ctx.save_for_backward(*saved)
            ctx.save_for_forward(*saved)

        def _backward(ctx, grad: Tensor):
            return backward(ctx.saved_tensors, grad)

        def _jvp(ctx, *tangents: Tensor) -> Tensor:
            return jvp(ctx.saved_tensors, *tangents)

        body = {
            "generate_vmap_rule": True,
            "forward": staticmethod(_forward),
            "setup_context": staticmethod(_setup_context),
            "backward": staticmethod(_backward),
            "__module__": __name__,
        }
        self.name = name
        self.compiled = type(name + "Function", (Function,), dict(body))
        self.eager = type(name + "FunctionJvp", (self.compiled,), {"jvp": staticmethod(_jvp)})

    def __call__(self, *inputs: Tensor) -> Tensor:
        if torch.compiler.is_compiling():
            return self.compiled.apply(*inputs)
        return self.eager.apply(*inputs)


def custom_function(
    name: str,
    *,
    forward: Callable[..., Tensor],
    save: Callable[[Sequence[Tensor], Tensor], tuple[Tensor, ...]],
    backward: Callable[..., tuple[Tensor | None, ...]],
    jvp: Callable[..., Tensor],
) -> CustomFunction:
    """Build a :class:`CustomFunction` (see the module docstring for the four pieces)."""
    return CustomFunction(name, forward, save, backward, jvp)
