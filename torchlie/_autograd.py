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

Per-call cost.  ``Function.apply`` binds its arguments with ``inspect.signature`` on every call
(tens of microseconds, more than a small op's whole arithmetic), so :meth:`CustomFunction.__call__`
takes one of three paths, each decided from flags and ``requires_grad`` only:

* inside a ``torch.func`` transform (vmap, grad, jvp, jacrev, ...): the public
  ``Function.apply``, which hands the call to functorch;
* nothing to differentiate (grad mode off or no input requiring grad, and no forward-mode AD
  level entered, so no input can carry a tangent): the plain ``forward``, no Function at all;
* otherwise (reverse or forward mode AD): the Function's C entry point
  (``torch._C._FunctionBase.apply``), which is what ``Function.apply`` ends in outside the
  transforms; the argument binding it skips is the identity for ``forward(*inputs)`` (no
  defaults, no keywords).
"""

from __future__ import annotations

import inspect
import os
from collections.abc import Callable, Sequence
from typing import TypeVar

import torch
from torch import Tensor
from torch.autograd import Function
from torch.autograd import forward_ad as _forward_ad

from torchlie import _layout

# What ``Function.apply`` calls once it has bound the arguments and found no functorch
# transform: the C implementation, bound to a Function class with ``__get__``.
_C_APPLY = torch._C._FunctionBase.__dict__["apply"]
_transforms_active = torch._C._are_functorch_transforms_active
_grad_enabled = torch.is_grad_enabled
_is_compiling = torch.compiler.is_compiling
_threads = torch.get_num_threads
_unwrap_if_dead = torch._C._functorch.unwrap_if_dead
# ``torch.autograd.forward_ad._current_level``: the dual level last entered (-1: none).  Every
# dual level, ``torch.func.jvp``'s included, is entered through that module, which keeps it.


_Out = TypeVar("_Out", Tensor, tuple[Tensor, ...])

#: Rows per block of the blocked passes (see :func:`_blocked`) for 4-byte elements (float32);
#: in proportion for other sizes (float64: half as many), so that each plane is 128 kB; times
#: the number of intra-op threads (:func:`block_rows`).
BLOCK = 32768

#: Whether OpenMP's idle threads sleep rather than spin (``OMP_WAIT_POLICY=PASSIVE``, read once,
#: as the OpenMP runtime reads it when it starts); see :func:`block_rows`.
PASSIVE = os.environ.get("OMP_WAIT_POLICY", "").strip().upper() == "PASSIVE"


def block_rows(rows: int, x: Tensor) -> int:
    """``rows`` (a block for 4-byte elements, one thread) scaled to the element size of ``x``
    and to ``torch.get_num_threads()``.

    torch splits an element-wise kernel between its threads only above 32 768 elements, in
    equal contiguous parts, the same for every kernel of a block: a block of ``rows`` per thread
    keeps each thread's part in its own core's cache from one kernel to the next, where blocks
    of a fixed size would run every kernel on one thread.  Measured with 2 threads on the 2-core
    Intel Xeon VM, N = 10^6, float32 forward, ns per element, fixed blocks -> blocks per thread
    (the whole batch at once): so3.exp 37.7 -> 22.0 (27.0), so3.log 49.0 -> 31.3 (43.9),
    quaternion.to_matrix 28.6 -> 16.1 (18.7), se3.exp 90.9 -> 49.2 (62.5), so3.act 15.0 -> 8.2
    (5.2), se3.compose 67.7 -> 65.1 (56.4); se3.act forward+backward 64.9 -> 36.0 (49.7).

    Not under ``OMP_WAIT_POLICY=PASSIVE`` (:data:`PASSIVE`): there idle threads sleep, and each
    kernel split between threads pays for waking them (so3.log with 2 threads: 272 ns per
    element with blocks per thread, 61 with blocks of one thread's size), so the blocks keep one
    thread's size and the kernels run on one thread.
    """
    return rows * 4 // x.element_size() * (1 if PASSIVE else _threads())


def _blocked(
    forward: Callable[..., _Out], event_dims: tuple[int, ...], other_cpu: int = 1
) -> Callable[..., _Out]:
    """``forward`` evaluated block by block over the flattened batch when the batch is large.

    ``forward`` returns a tensor or a tuple of tensors, each with the batch shape first.

    The forward passes are many small element-wise operations; over a batch of 10^6 each one
    streams its operands through main memory, over a block of :data:`BLOCK` rows they stay in
    the cache (measured, float32 N = 10^6: so3.exp 61 -> 50 ns per element, so3.log 77 -> 58,
    se3.log 171 -> 110; float64 blocks of 32 768 rows rather than 65 536: so3.log 195 -> 182,
    se3.log 250 -> 220, from_matrix 170 -> 146).  Planes of 128 kB rather than 256 kB (on a
    2-core Intel Xeon VM with 2 MB of L2 per core, where the temporaries of a 256 kB block
    spill to L3; float32, N = 10^6, ns per element, 65 536 -> 32 768 rows, in alternation):
    forward so3.exp 35.5 -> 29.8, quaternion.to_matrix 27.0 -> 21.6, se3.exp 79.8 -> 75.6,
    so3.log 44.8 -> 42.9, quaternion.apply 16.0 -> 16.8; float64 (32 768 -> 16 384 rows) so3.exp
    97 -> 88, quaternion.to_matrix 53 -> 44, se3.exp 204 -> 190; forward+backward up to 6 %
    faster (quaternion.apply the same, quaternion.multiply float32 38.5 -> 40.1; on the AMD
    EPYC VM of the earlier measurements, 512 kB of L2: to_matrix 25 either way, so3.exp 40 ->
    42).  Only in eager mode outside ``torch.func`` transforms, only when every input has the
    same batch shape (``event_dims[i]`` trailing dimensions of input ``i`` are not batch), on
    CPU (a GPU's caches are not what this is for, and each block is one more launch of every
    kernel); the result is the same tensor.

    A ``forward`` with a keyword parameter ``dest`` is given, for each block after the first,
    the rows of the result (a tensor, or a tuple of tensors for a tuple of results) that block
    is for, and may write its result there (``out=`` of its last operation): no concatenation
    of the blocks afterwards, which is a pass over the whole result in main memory.  A block
    result that is not ``dest`` itself (or a view of it) is copied there.

    ``other_cpu``: blocks that many times as large where the CPU is not an Intel one with MKL
    (:func:`torchlie._layout.intel_mkl`), for kernels of many calls per block whose cost per
    call outweighs the cache there (``quaternion.apply``, 27 calls per block: on a 2-core AMD
    EPYC, Zen 5, one thread, N = 10^6, ns per element, three rounds in alternation, blocks of
    32 768 -> 65 536 rows, float32 forward 9.9-10.3 -> 8.6-8.9, float64 17.9-21.9 -> 15.7-16.4,
    forward+backward 31.1-45.8 -> 29.1-44.3 (float64 51.8-71.9 -> 48.5-53.5); the other kernels
    measured within 5 % either way, ``se3.log`` 8 % slower, so they keep theirs).
    """
    takes_dest = "dest" in inspect.signature(forward).parameters

    def run(*inputs: Tensor) -> _Out:
        first = inputs[0]
        # below two blocks in every dtype (elements up to 16 B); not while compiling, before the
        # thread count is read (torch.get_num_threads() would break the graph)
        if first.numel() < BLOCK // 2 or not _layout.eager_cpu(first):
            return forward(*inputs)
        batch = first.shape[: first.dim() - event_dims[0]]
        n = batch.numel()
        rows = block_rows(BLOCK, first)  # the same bytes per plane and thread in every dtype
        if other_cpu != 1 and not _layout.intel_mkl():
            rows *= other_cpu
        if n < 2 * rows:
            return forward(*inputs)
        flat = []
        for x, k in zip(inputs, event_dims, strict=True):
            if x.shape[: x.dim() - k] != batch:
                return forward(*inputs)
            flat.append(x.reshape((n,) + x.shape[x.dim() - k :]).split(rows))
        blocks = list(zip(*flat, strict=True))
        if takes_dest and not _layout.needs_graph(inputs):
            return _written(forward, blocks, n, batch)
        outs = [forward(*block) for block in blocks]
        if isinstance(outs[0], tuple):  # several results, each concatenated
            return tuple(_joined(parts, batch) for parts in zip(*outs, strict=True))
        return _joined(outs, batch)

    return run


def _joined(blocks: Sequence[Tensor], batch: torch.Size) -> Tensor:
    out = torch.cat(blocks)
    return out.reshape(batch + out.shape[1:])


def _written(forward: Callable[..., _Out], blocks: list, n: int, batch: torch.Size) -> _Out:
    """The blocked ``forward`` with ``dest``: each block's result written in its rows."""
    first = forward(*blocks[0])
    single = not isinstance(first, tuple)
    outs = (first,) if single else first
    results = tuple(out.new_empty((n,) + out.shape[1:]) for out in outs)
    start = 0
    for i, block in enumerate(blocks):
        stop = start + block[0].shape[0]
        dest = tuple(r[start:stop] for r in results)
        if i:
            outs = forward(*block, dest=dest[0] if single else dest)
            outs = (outs,) if single else outs
        for out, d in zip(outs, dest, strict=True):
            if not _layout.same_memory(out, d):
                d.copy_(out)
        start = stop
    joined = tuple(r.reshape(batch + r.shape[1:]) for r in results)
    return joined[0] if single else joined


def _positional(forward: Callable[..., Tensor], n: int) -> Callable[..., Tensor]:
    """``forward`` as a function of exactly its ``n`` positional tensor inputs.

    A fixed arity (not ``*inputs``): Dynamo tells a ``setup_context``-style forward from one
    that takes ``ctx`` by its signature, and with ``*inputs`` it passes ``ctx`` to a forward of
    two or more inputs.  No defaults, no keywords: the argument binding of ``Function.apply`` is
    the identity, which is what lets ``__call__`` go to the C entry point directly.
    """
    if n == 1:

        def f1(a: Tensor) -> Tensor:
            return forward(a)

        return f1
    if n == 2:

        def f2(a: Tensor, b: Tensor) -> Tensor:
            return forward(a, b)

        return f2
    if n == 3:

        def f3(a: Tensor, b: Tensor, c: Tensor) -> Tensor:
            return forward(a, b, c)

        return f3
    raise ValueError(f"custom_function: forward takes 1 to 3 tensors, got {n} parameters")


class CustomFunction:
    """A callable pair of ``torch.autograd.Function`` s (eager with jvp; compiled without).

    Called with tensors only (``requires_grad`` is read from every input); the path it takes is
    described in the module docstring.
    """

    def __init__(
        self,
        name: str,
        forward: Callable[..., Tensor],
        save: Callable[[Sequence[Tensor], Tensor], tuple[Tensor, ...]],
        backward: Callable[..., tuple[Tensor | None, ...]],
        jvp: Callable[..., Tensor],
        event_dims: tuple[int, ...],
        blocked: bool = True,
    ) -> None:
        positional = (inspect.Parameter.POSITIONAL_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)
        n = sum(p.kind in positional for p in inspect.signature(forward).parameters.values())
        if len(event_dims) != n:
            raise ValueError(f"custom_function {name}: one event_dims entry per input, {n} inputs")
        if blocked:
            forward = _blocked(forward, event_dims)
        _forward = _positional(forward, n)

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
        self.forward = forward
        self.compiled = type(name + "Function", (Function,), dict(body))
        self.eager = type(name + "FunctionJvp", (self.compiled,), {"jvp": staticmethod(_jvp)})
        self._apply_c = _C_APPLY.__get__(self.eager, self.eager)

    def __call__(self, *inputs: Tensor) -> Tensor:
        if _is_compiling():
            return self.compiled.apply(*inputs)
        if _transforms_active():
            return self.eager.apply(*inputs)
        if _forward_ad._current_level < 0:  # no input can carry a forward-mode tangent
            if not _grad_enabled():
                return self.forward(*inputs)
            for x in inputs:
                if x.requires_grad:
                    break
            else:
                return self.forward(*inputs)
        return self._apply_c(*[_unwrap_if_dead(x) for x in inputs])


def custom_function(
    name: str,
    *,
    forward: Callable[..., Tensor],
    save: Callable[[Sequence[Tensor], Tensor], tuple[Tensor, ...]],
    backward: Callable[..., tuple[Tensor | None, ...]],
    jvp: Callable[..., Tensor],
    event_dims: tuple[int, ...],
    blocked: bool = True,
) -> CustomFunction:
    """Build a :class:`CustomFunction` (see the module docstring for the four pieces).

    ``event_dims``: the number of trailing (non-batch) dimensions of each input, e.g. ``(1,)``
    for a rotation vector, ``(2, 1)`` for a matrix and a point (for the blocked forward);
    ``blocked=False`` for a forward of one batched matmul, which blocks only slow down.
    """
    return CustomFunction(name, forward, save, backward, jvp, event_dims, blocked)
