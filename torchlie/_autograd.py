"""The one evaluation driver and the custom autograd Functions built on it.

Every op that has its own derivative (the log maps, whose naive derivative is infinite at
theta = pi, and the ops whose closed-form backward is much cheaper than autograd's graph of
their formula) is a :class:`CustomFunction` of four pure functions:

* ``forward(*inputs) -> output``       the op's formula, in differentiable torch ops;
* ``save(inputs, output) -> tuple``     the tensors the derivatives need;
* ``backward(saved, grad) -> grads``    the derivative's formula, one for every mode: its
  coefficients are forward-only in a plain backward pass and differentiable under
  ``create_graph`` (so double backward differentiates the same formula);
* ``jvp(saved, *tangents) -> tangent``  forward mode (``torch.func.jvp`` / ``jacfwd``).

An op whose formula has a limited range (squares that overflow, angles beyond ``1 / eps``) takes a
:data:`Guard` of its first input: the map into that range which leaves the op's value unchanged
(a rescaling, an angle reduction).  The op's ``forward`` takes the input as it came and applies
the guard itself (on components where its formula reads components); the Function saves the
input as it came, and its ``backward`` and ``jvp`` see the guarded input, their derivatives
carried back through the guard.  A compiled op then saves no guarded copy.

The same formulas run in every mode: eager CPU and CUDA, ``torch.compile``, ``torch.func``
transforms.  The only thing that differs is how the formula is evaluated.  On large eager CPU
batches :func:`evaluate` runs it block by block over the flattened batch, each block's result
written into its rows of one preallocated result: the many element-wise operations of a
formula then keep their operands in the cache instead of streaming them through main memory.
Everywhere else (CUDA, compile, transforms, a graph being recorded) the formula runs once on
the whole batch.

Under ``torch.compile``, Dynamo traces a Function with its own backward only outside the
``torch.func`` transforms (inside them it inlines the forward and drops the backward) and
refuses a custom ``jvp``.  There, an op is traced as ``f(x0) + jvp(x0; x - x0)`` with ``x0`` the
input detached: the value of ``f``, and as first derivatives, in forward and reverse mode, the
op's own ``jvp`` formula (which is the transpose of its backward).  Second derivatives of these
ops through ``torch.func`` under ``torch.compile`` are not those of the op (the coefficients
are constants there); eager ``torch.func`` and eager double backward give them.

Forward mode nested in forward mode (``jacfwd(jacfwd(f))``): torch differentiates an
``autograd.Function``'s ``jvp`` there as if its saved tensors were constants, so the second
derivative would miss every term of the op.  There an op is traced instead as
``f(x0) + jvp(m; x - x0)`` at the midpoint ``m = (x0 + x) / 2``, whose saved output is
``f(x0) + jvp(x0; m - x0)``: the value of ``f``, its first derivatives, and as second
derivatives those of the ``jvp`` formula.  Third and higher derivatives taken with two forward
levels among them would not be the op's: they raise.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, MutableMapping, Sequence
from typing import TypeVar

import torch
from torch import Tensor
from torch.autograd import Function
from torch.autograd import forward_ad as _forward_ad

from . import _checks

_Out = TypeVar("_Out", Tensor, tuple[Tensor, ...])
_is_compiling = torch.compiler.is_compiling
_addcmul = torch.addcmul

#: Rows per block and thread for 4-byte elements (in proportion for other element sizes): the
#: planes of a block stay in a core's cache from one element-wise operation to the next.
BLOCK = 32768


#: torch's query of active ``torch.func`` transforms: private, and read only here (None where
#: torch has none).
_TRANSFORMS_QUERY = getattr(torch._C, "_are_functorch_transforms_active", None)


def _interpreters_query() -> Callable[[], Sequence[object]] | None:
    """torch's private list of the active ``torch.func`` transforms (see
    :func:`_derivative_levels`), or None where torch has none."""
    try:
        from torch._functorch import pyfunctorch
    except ImportError:
        return None
    return getattr(pyfunctorch, "retrieve_all_functorch_interpreters", None)


_INTERPRETERS_QUERY = _interpreters_query()


def transforms_active() -> bool:
    """Whether a ``torch.func`` transform (vmap, grad, jvp, ...) is active.

    torch has no public query for this; where its private one is missing the answer is
    ``True``, which is always correct (calls then take the Function that transforms take, and
    no blocks).
    """
    return True if _TRANSFORMS_QUERY is None else bool(_TRANSFORMS_QUERY())


_K = TypeVar("_K")
_V = TypeVar("_V")


def cached(cache: MutableMapping[_K, _V], key: _K, build: Callable[[], _V]) -> _V:
    """``cache[key]``, built on first use, for constants that later calls share (plans,
    index and coefficient tensors).

    Stored only when what ``build`` makes is a plain tensor every later call can use: not while
    dynamo traces (traced values), not under a ``torch.func`` transform (its tensors are wrapped
    for that transform's level and fail outside it); under inference mode it is built as normal
    tensors (an inference tensor cannot be saved for a later backward pass).
    """
    if key in cache:
        return cache[key]
    if _is_compiling() or transforms_active():
        return build()
    if torch.is_inference_mode_enabled():
        with torch.inference_mode(False):
            value = build()
    else:
        value = build()
    cache[key] = value
    return value


def forward_ad_active() -> bool:
    """Whether a forward-mode AD level is entered (any input might then carry a tangent).

    Read from ``torch.autograd.forward_ad``, which keeps the level it last entered; where that
    attribute is missing the answer is ``True`` (always correct: the call then goes through
    the Function, which handles tangents).
    """
    return getattr(_forward_ad, "_current_level", 0) >= 0


def fma(x: Tensor, t1: Tensor, t2: Tensor, value: float = 1.0, out: Tensor | None = None) -> Tensor:
    """``x + value * t1 * t2``: ``torch.addcmul`` in eager mode, spelled out while compiling.

    torch's forward-mode rule of ``addcmul`` crashes under ``torch.compile`` when some operands
    carry a tangent and others do not, as the terms of a linearised op do (see the module
    docstring); Inductor generates the same fused code from either spelling.
    """
    if _is_compiling():
        if value == -1.0:  # no product of -1 and one operand alone, which AOTAutograd could
            return x - t1 * t2  # compute in the forward (a loop of its own) and save
        return x + t1 * t2 if value == 1.0 else x + value * t1 * t2
    if out is None:  # keyword arguments cost torch's argument parser more than the product
        return _addcmul(x, t1, t2) if value == 1.0 else _addcmul(x, t1, t2, value=value)
    return _addcmul(x, t1, t2, value=value, out=out)


def _records(inputs: Sequence[Tensor]) -> bool:
    """Whether autograd records a graph of an operation on ``inputs``."""
    if torch.is_grad_enabled():
        for x in inputs:  # (a generator costs a small op more than its test)
            if x.requires_grad:
                return True
    return False


def needs_graph(inputs: Sequence[Tensor]) -> bool:
    """Whether autograd may record operations on ``inputs``: a graph being recorded, or a
    forward-mode level entered (an input may carry a tangent)."""
    return forward_ad_active() or _records(inputs)


def evaluate(
    fn: Callable[..., _Out],
    inputs: Sequence[Tensor],
    event_dims: Sequence[int],
    width: int = 1,
) -> _Out:
    """``fn(*inputs)``, over blocks of the flattened batch where that pays.

    ``event_dims[i]`` trailing dimensions of input ``i`` are not batch.  Blocks are taken for
    eager CPU tensors of one common batch shape of at least two blocks, outside transforms and
    without a graph being recorded; ``fn`` returns a tensor or a tuple of tensors (or None) with
    the batch shape first, and a block's result is the same whatever block it is in (row by row).
    ``width``: how many planes per row the formula's temporaries hold, relative to an
    element-wise op's one (a formula over the joint columns of a robot: their number); blocks
    hold proportionally fewer rows, so that their temporaries take the same memory.
    """
    first = inputs[0]
    if (
        torch.compiler.is_compiling()
        or first.numel() < BLOCK
        or not first.is_cpu
        or transforms_active()
        or _records(inputs)
    ):
        return fn(*inputs)
    batch = first.shape[: first.dim() - event_dims[0]]
    rows = max(1, BLOCK * 4 // first.element_size() * torch.get_num_threads() // width)
    n = batch.numel()
    if n < 2 * rows or any(
        x.shape[: x.dim() - k] != batch for x, k in zip(inputs, event_dims, strict=True)
    ):
        return fn(*inputs)
    flat = [
        x.reshape((n,) + x.shape[x.dim() - k :]) for x, k in zip(inputs, event_dims, strict=True)
    ]
    results: tuple[Tensor | None, ...] = ()
    plan = _Plan()
    outer, _PLANS.current = getattr(_PLANS, "current", None), plan
    try:
        for start in range(0, n, rows):
            out = fn(*(x[start : start + rows] for x in flat))
            outs = out if isinstance(out, tuple) else (out,)
            if not results:
                results = tuple(
                    None if o is None else o.new_empty((n,) + o.shape[1:]) for o in outs
                )
            plan.next_block(outs, results, start, start + rows)
    finally:
        _PLANS.current = outer
    joined = tuple(None if r is None else r.reshape(batch + r.shape[1:]) for r in results)
    return joined if isinstance(out, tuple) else joined[0]  # type: ignore[return-value]


class _Plan:
    """Where the kernels of one :func:`evaluate` allocate their results (:func:`result_buffer`):
    from the second block on, a request that made a result in the first block (the block's
    ``i``-th request) gets the block's rows of that whole result, so the kernel's last
    operations store there and no copy follows; any other request takes a new tensor, and a
    result that is not where its rows are is copied there."""

    def __init__(self) -> None:
        self.requests: list[Tensor] = []  # this block's, in order
        self.targets: dict[int, Tensor] = {}  # request index: the rows of its whole result
        self.owners: dict[int, int] | None = None  # request index: result index

    def take(self, shape: tuple[int, ...], like: Tensor) -> Tensor:
        rows = self.targets.get(len(self.requests))
        if rows is not None and shape and rows.dtype == like.dtype and rows.device == like.device:
            rows = rows[: shape[0]]
            out = rows.view(shape) if rows.numel() == math.prod(shape) else None
        else:
            out = None
        if out is None:
            out = torch.empty(shape, dtype=like.dtype, device=like.device)
        self.requests.append(out)
        return out

    def next_block(
        self, outs: Sequence[Tensor | None], results: Sequence[Tensor | None], start: int, stop: int
    ) -> None:
        """Copy the block's results ``outs`` to rows ``start:stop`` of ``results`` where they
        are not there already, and aim the next block's requests at the rows after them."""
        if self.owners is None:  # the first block: which request made which result
            self.owners = {
                i: j
                for j, o in enumerate(outs)
                for i, b in enumerate(self.requests)
                if o is not None and _same_memory(o, b)
            }
        stores = {r.untyped_storage().data_ptr() for r in results if r is not None}
        moves = [
            # a result made in another result's rows (the block took another path than the
            # first) is taken out of them before any rows are written
            (r[start:stop], o.clone() if o.untyped_storage().data_ptr() in stores else o)
            for r, o in zip(results, outs, strict=True)
            if r is not None and not _same_memory(o, r[start:stop])
        ]
        for rows, o in moves:
            rows.copy_(o)
        self.requests = []
        self.targets = {i: results[j][stop:] for i, j in self.owners.items()}  # type: ignore[index]


def _same_memory(a: Tensor | None, b: Tensor) -> bool:
    """Whether ``a`` is ``b``'s memory, element for element (contiguous both, same start and
    size)."""
    return (
        a is not None
        and a.data_ptr() == b.data_ptr()
        and a.numel() == b.numel()
        and a.is_contiguous()
        and b.is_contiguous()
    )


_PLANS = threading.local()


def result_buffer(shape: tuple[int, ...], like: Tensor) -> Tensor:
    """``torch.empty(shape)`` of ``like``'s dtype and device, for a kernel's result: where
    :func:`evaluate` runs the kernel block by block, the block's rows of the whole result
    (:class:`_Plan`)."""
    plan = getattr(_PLANS, "current", None)
    if plan is None:
        return torch.empty(shape, dtype=like.dtype, device=like.device)
    return plan.take(shape, like)


#: A map of an op's first input into its formula's range that leaves the op unchanged:
#: ``guard(x)`` is the guarded input (``x`` itself, bit for bit, inside the range), as a tensor
#: or as its planes (the components along the last dimension), and the map's derivative at
#: ``x``, a function of a tangent given either way; it is symmetric, so it also transposes a
#: gradient.  The guarded input has that derivative under autograd.  Planes go to the op's
#: backward as they are (no stack of them to read back: a buffer and a loop of its own in
#: Inductor's code), stacked to its ``jvp``.
Guard = Callable[[Tensor], tuple[Tensor | Sequence[Tensor], Callable[..., Tensor]]]


def _guarded(
    guard: Guard,
    backward: Callable[..., tuple[Tensor | None, ...]],
    jvp: Callable[..., Tensor],
    event_dims: int,
) -> tuple[Callable[..., tuple[Tensor | None, ...]], Callable[..., Tensor]]:
    """``backward`` and ``jvp`` of the guarded input, as functions of the input as it came
    (``save`` keeps it first among the saved tensors, of ``event_dims`` trailing dimensions).

    The plain backward (no ``create_graph``) runs guard, formula and the guard's derivative
    block by block (:func:`evaluate`), the saved tensors and the gradient taken with the batch
    shape of the input."""

    def inner(saved: Sequence[Tensor]) -> tuple[tuple, Callable[..., Tensor]]:
        x, derivative = guard(saved[0])
        return (x, *saved[1:]), derivative

    def through(saved: Sequence[Tensor], grad: Tensor) -> tuple[Tensor | None, ...]:
        guarded, derivative = inner(saved)
        first, *rest = backward(guarded, grad)
        return (None if first is None else derivative(first), *rest)

    def guarded_backward(saved: Sequence[Tensor], grad: Tensor) -> tuple[Tensor | None, ...]:
        if torch.is_grad_enabled():  # create_graph
            return through(saved, grad)
        batch = saved[0].dim() - event_dims
        tensors = (*saved, grad)
        return evaluate(
            lambda *t: through(t[:-1], t[-1]), tensors, [t.dim() - batch for t in tensors]
        )

    def guarded_jvp(saved: Sequence[Tensor], dx: Tensor | None, *rest: Tensor | None) -> Tensor:
        (x, *others), derivative = inner(saved)
        x = x if isinstance(x, Tensor) else torch.stack(tuple(x), dim=-1)
        return jvp((x, *others), None if dx is None else derivative(dx), *rest)

    return guarded_backward, guarded_jvp


def _derivative_levels() -> tuple[int, int]:
    """``(forward, all)``: how many of the active ``torch.func`` transforms differentiate in
    forward mode, and how many differentiate at all (forward or reverse).

    torch has no public query; its private list of transforms is read here only.  Where it is
    missing the answer is ``(0, 0)``: calls then take the Function as outside nested forward
    mode (whose second derivatives torch computes wrong, see the module docstring)."""
    if _INTERPRETERS_QUERY is None:
        return 0, 0
    keys = [str(i.key()) for i in _INTERPRETERS_QUERY()]
    forward = sum(k.endswith("Jvp") for k in keys)
    return forward, forward + sum(k.endswith("Grad") for k in keys)


def _positional(forward: Callable[..., Tensor], n: int) -> Callable[..., Tensor]:
    """``forward`` as a function of exactly ``n`` positional tensors (Dynamo tells a
    ``setup_context``-style forward from one taking ``ctx`` by its signature)."""
    if n == 1:
        return lambda a: forward(a)
    if n == 2:
        return lambda a, b: forward(a, b)
    if n == 3:
        return lambda a, b, c: forward(a, b, c)
    raise ValueError(f"CustomFunction: forward takes 1 to 3 tensors, got {n}")


class CustomFunction:
    """An op with its own derivatives, from the four pieces of the module docstring: callable
    with tensors only.

    ``event_dims``: the number of trailing (non-batch) dimensions of each input, e.g. ``(1,)``
    for a rotation vector, ``(2, 1)`` for a matrix and a point (for :func:`evaluate`).
    ``guard``: of the first input, which ``save`` then keeps first (see the module docstring).

    Two ``torch.autograd.Function`` s are built from the same four pieces: one in the
    ``setup_context`` style (vmap rule generated), which ``torch.func`` transforms and
    ``torch.compile`` need, and one whose ``forward`` takes ``ctx``, which plain eager autograd
    calls without binding its arguments anew on every call.  Without anything to differentiate
    the formula runs on its own, through :func:`evaluate`.
    """

    def __init__(
        self,
        name: str,
        *,
        forward: Callable[..., Tensor],
        save: Callable[[Sequence[Tensor], Tensor], tuple[Tensor, ...]],
        backward: Callable[..., tuple[Tensor | None, ...]],
        jvp: Callable[..., Tensor],
        event_dims: tuple[int, ...],
        guard: Guard | None = None,
    ) -> None:
        if guard is not None:
            backward, jvp = _guarded(guard, backward, jvp, event_dims[0])
        self.name = name
        self.formula = forward
        self.event_dims = event_dims
        n = len(event_dims)

        def run_forward(*inputs: Tensor) -> Tensor:
            return evaluate(forward, inputs, event_dims)

        def setup_context(ctx, inputs, output) -> None:
            saved = save(inputs, output)
            ctx.save_for_backward(*saved)
            ctx.save_for_forward(*saved)

        # A backward called inside an autocast region runs as the forward did (without autocast).
        @_checks.float32_exact
        def _backward(ctx, grad: Tensor):
            return backward(ctx.saved_tensors, grad)

        @_checks.float32_exact
        def _jvp(ctx, *tangents: Tensor) -> Tensor:
            return jvp(ctx.saved_tensors, *tangents)

        def eager_forward(ctx, *inputs: Tensor) -> Tensor:
            output = run_forward(*inputs)
            setup_context(ctx, inputs, output)
            return output

        body = {"backward": staticmethod(_backward), "__module__": __name__}
        self.compiled = type(
            name + "Function",
            (Function,),
            {
                **body,
                "generate_vmap_rule": True,
                "forward": staticmethod(_positional(run_forward, n)),
                "setup_context": staticmethod(setup_context),
            },
        )
        self.transform = type(name + "FunctionJvp", (self.compiled,), {"jvp": staticmethod(_jvp)})
        self.eager = type(
            name + "EagerFunction",
            (Function,),
            {**body, "forward": staticmethod(eager_forward), "jvp": staticmethod(_jvp)},
        )
        self.forward = run_forward

        def linearized(*inputs: Tensor) -> Tensor:
            # f(x0) + J(x0) (x - x0) at x = x0: the value of f, and as derivative the op's own
            # jvp (whose reverse is its backward), whatever transform differentiates it.
            bare = tuple(x.detach() for x in inputs)
            y = forward(*bare)
            return y + jvp(save(bare, y), *(x - b for x, b in zip(inputs, bare, strict=True)))

        self.linearized = linearized

        def second_order(*inputs: Tensor) -> Tensor:
            # f(x0) + jvp(m; x - x0) at m = (x0 + x) / 2, saving f(x0) + jvp(x0; m - x0) as
            # the output at m (module docstring): along h = x - x0 this is
            # f(x0) + J h + (dJ[h] h) / 2 + O(h^3), the op's Taylor polynomial of order two.
            bare = tuple(x.detach() for x in inputs)
            y = forward(*bare)
            steps = tuple(x - b for x, b in zip(inputs, bare, strict=True))
            mids = tuple(b + 0.5 * h for b, h in zip(bare, steps, strict=True))
            y_mid = y + jvp(save(bare, y), *(0.5 * h for h in steps))
            return y + jvp(save(mids, y_mid), *steps)

        self.second_order = second_order

    def __call__(self, *inputs: Tensor) -> Tensor:
        if torch.compiler.is_compiling():
            # Dynamo inlines a Function's forward under torch.func transforms (dropping its
            # backward) and refuses a custom jvp: there the op's value and its own first
            # derivatives are traced as plain ops instead (see ``linearized``).
            if transforms_active() or forward_ad_active():
                return self.linearized(*inputs)
            return self.compiled.apply(*_distinct(inputs))
        if transforms_active():
            forward_levels, levels = _derivative_levels()
            if forward_levels > 1:
                if levels > 2:
                    raise NotImplementedError(
                        f"torchlie ({self.name}): derivatives of order three or more taken "
                        "with forward mode nested in forward mode (jacfwd of jacfwd) are not "
                        "supported (torch differentiates a custom jvp as a constant there); "
                        "take the outer derivatives in reverse mode (jacrev)"
                    )
                return self.second_order(*inputs)
            return self.transform.apply(*inputs)
        if needs_graph(inputs):
            return self.eager.apply(*inputs)
        return self.forward(*inputs)


def _distinct(inputs: Sequence[Tensor]) -> list[Tensor]:
    """``inputs`` with each repeat of a tensor replaced by a view of it (the same values and
    gradient): Dynamo refuses to trace a Function given one tensor twice (``compose(T, T)``)."""
    out: list[Tensor] = []
    for x in inputs:
        out.append(x.view_as(x) if any(x is y for y in out) else x)
    return out


def blocked(fn: Callable[..., _Out], event_dims: tuple[int, ...]) -> Callable[..., _Out]:
    """``fn`` evaluated by :func:`evaluate` (``event_dims`` as there)."""

    def run(*inputs: Tensor) -> _Out:
        return evaluate(fn, inputs, event_dims)

    return run
