"""Input checks shared by every public function.

Shape and dtype checks read only metadata, so they never synchronise a device and they trace
away under ``torch.compile``.  Value checks (orthonormality, unit norm) cost a sync and are the
explicit ``is_valid`` / ``is_unit`` functions of each module instead.

One rule for every entry point:

* tensors: float16, bfloat16 (both computed in float32), float32 or float64, else ``TypeError``;
  the tensors of one call share one dtype, else ``TypeError``; wrong trailing shape, batch
  shapes that do not broadcast, or more than :data:`MAX_BATCH_DIMS` batch dimensions:
  ``ValueError``;
* factories (``identity``, ``random``, ...): ``dtype=`` one of those four (``TypeError``), at
  most :data:`MAX_BATCH_DIMS` batch sizes (``ValueError``);
* real parameters (``t``, ``dt``, ``angle``, ``std``, query times, weights): a tensor (of the
  operands' dtype, as above) or numbers: a Python or numpy real number, a numpy array of
  reals, or a (nested) list / tuple of them, converted to the operands' dtype and device;
  ``bool`` is never a number here (``TypeError``); each of their dimensions counts as a batch
  dimension;
* tolerances and loss weights: a non-negative finite real number (``TypeError`` for another
  type, ``ValueError`` for a negative, infinite or NaN value).

Every public op is also decorated with :func:`float32_exact`, the one guard against
``torch.autocast``: an autocast region would otherwise run the matrix products inside the
formulas in float16/bfloat16 and lose float32 accuracy.
"""

from __future__ import annotations

import functools
import math
import numbers
import operator
import reprlib
from collections.abc import Mapping

import numpy as np
import torch
from torch import Tensor

_LOW_PRECISION = (torch.float16, torch.bfloat16)
#: The dtypes every op accepts (float8 and the rest are refused: no op is written for them).
_FLOATS = frozenset((torch.float16, torch.bfloat16, torch.float32, torch.float64))
_FLOAT_NAMES = "float16, bfloat16, float32 or float64"
#: The most batch dimensions (those before an argument's trailing shape, such as the ``(3, 3)``
#: of a rotation matrix) an op accepts.  torch reduces tensors of up to 64 dimensions only, and
#: the ops build intermediates of up to three dimensions after the batch (``so3.project``'s
#: product of two 3x3 factors written as an outer product and a sum); 60 keeps one in hand.
MAX_BATCH_DIMS = 60


def float32_exact(fn):
    """Decorator of every public op: run it with ``torch.autocast`` disabled.

    Autocast lowers matrix products (``@``, ``bmm``, ``einsum``, ...) to float16/bfloat16, which
    the formulas are not written for; inside an autocast region the op runs as outside it, so
    float32 inputs give float32 results of float32 accuracy (half inputs are computed in float32
    by :func:`tensor` as always).  The device type is that of the first tensor argument
    (:func:`_device_type`); outside autocast the guard costs that lookup and one call, and
    ``torch.compile`` traces the autocast state and the context manager into the graph.
    """

    def guarded(*args, **kwargs):
        device = _device_type(args, kwargs)
        if torch.is_autocast_enabled(device):
            with torch.autocast(device, enabled=False):
                return fn(*args, **kwargs)
        return fn(*args, **kwargs)

    # A code object of its own per op: torch.compile keeps its compiled graphs per code object
    # (guarded by the closure's ``fn``), so wrappers sharing one would exhaust its recompile
    # limit after a few ops compiled on their own (``torch.compile(so3.exp)``, ...).
    guarded.__code__ = guarded.__code__.replace(co_name=fn.__name__)
    guarded.float32_exact = True
    return functools.wraps(fn)(guarded)


def _device_type(args: tuple, kwargs: dict) -> str:
    """The autocast device type of the first tensor among the arguments (one level into dicts,
    lists and tuples, as IK targets); else of a ``device=`` argument; else ``"cpu"``.  Meta
    tensors (shape inference, deferred initialisation) have no autocast state of their own and
    count as ``"cpu"``."""
    for a in args:
        if isinstance(a, Tensor):
            return "cpu" if a.is_cpu else _autocast_type(a.device)  # is_cpu: cheaper than .device
    for a in (*args, *kwargs.values()):
        for v in (
            a.values() if isinstance(a, Mapping) else a if isinstance(a, (list, tuple)) else (a,)
        ):
            if isinstance(v, Tensor):
                return _autocast_type(v.device)
    device = kwargs.get("device")
    return "cpu" if device is None else _autocast_type(torch.device(device))


def _autocast_type(device: torch.device) -> str:
    return "cpu" if device.type == "meta" else device.type


def batch_dims(fn: str, k: int, what: str) -> None:
    """Raise a ``ValueError`` naming ``fn`` if ``k`` batch dimensions (``what``: where they
    are, e.g. ``"in t"``) are more than :data:`MAX_BATCH_DIMS`."""
    if k > MAX_BATCH_DIMS:
        raise _too_many(fn, k, what)


def _too_many(fn: str, k: int, what: str) -> ValueError:
    return ValueError(f"{fn}: expected at most {MAX_BATCH_DIMS} batch dimensions {what}, got {k}")


def _shape_str(trailing: tuple[int, ...]) -> str:
    return "(..., " + ", ".join(str(d) for d in trailing) + ")"


def tensor(x: object, fn: str, arg: str, trailing: tuple[int, ...]) -> tuple[Tensor, torch.dtype]:
    """Check ``x`` is a floating tensor ending in ``trailing``; return it in a compute dtype.

    Returns ``(x_compute, out_dtype)``: float16/bfloat16 inputs are computed in float32 and the
    caller casts the result back to ``out_dtype``.
    """
    if not isinstance(x, Tensor):
        raise TypeError(f"{fn}: expected {arg} to be a torch.Tensor, got {type(x).__name__}")
    dtype = x.dtype
    if dtype not in _FLOATS:
        raise TypeError(
            f"{fn}: expected {arg} to be a floating-point tensor ({_FLOAT_NAMES}), got dtype "
            f"{dtype}"
        )
    shape = tuple(x.shape)  # a tuple slices several times faster than a torch.Size
    k = len(shape) - len(trailing)
    if k < 0 or shape[k:] != trailing:
        raise ValueError(f"{fn}: expected {arg} of shape {_shape_str(trailing)}, got {shape}")
    if k > MAX_BATCH_DIMS:
        raise _too_many(fn, k, f"in {arg} (before its trailing {trailing})")
    if dtype in _LOW_PRECISION:
        return x.float(), dtype
    return x, dtype


def same_dtype(fn: str, **tensors: Tensor) -> None:
    """Raise a ``TypeError`` unless all tensors share one dtype."""
    dtype = None
    for t in tensors.values():
        if dtype is None:
            dtype = t.dtype
        elif t.dtype != dtype:
            desc = ", ".join(f"{k} is {v.dtype}" for k, v in tensors.items())
            raise TypeError(f"{fn}: expected inputs of one dtype, got {desc}")


def factory(fn: str, batch: tuple[object, ...], dtype: object) -> tuple[torch.dtype, torch.dtype]:
    """Check a factory's batch sizes and ``dtype=``; return ``(compute dtype, output dtype)``.

    ``dtype=None`` means torch's default dtype.  Half precision is drawn and computed in float32
    and cast back by the caller (``out``).
    """
    batch_dims(fn, len(batch), "(one per batch size)")
    for b in batch:
        if type(b) is int and b >= 0:  # the common case, before the slower ABC checks
            continue
        if isinstance(b, bool) or not isinstance(b, (numbers.Integral, torch.SymInt)):
            raise TypeError(
                f"{fn}: expected the batch sizes to be ints, got {type(b).__name__} ({b!r})"
            )
        if isinstance(b, numbers.Integral) and b < 0:
            raise ValueError(f"{fn}: expected batch sizes >= 0, got {tuple(batch)}")
    if dtype is None:
        dtype = torch.get_default_dtype()
    if not isinstance(dtype, torch.dtype) or dtype not in _FLOATS:
        raise TypeError(
            f"{fn}: expected dtype to be one of torch.float16, torch.bfloat16, torch.float32 or "
            f"torch.float64, got {dtype!r}"
        )
    return (torch.float32 if dtype in _LOW_PRECISION else dtype), dtype


def _real_leaves(x: object) -> bool:
    """Whether a (nested) list / tuple holds real numbers only (``bool`` is not one here)."""
    if isinstance(x, (list, tuple)):
        return all(_real_leaves(v) for v in x)
    return isinstance(x, numbers.Real) and not isinstance(x, bool)


def real(x: object, fn: str, arg: str, like: Tensor, ref: tuple[str, Tensor]) -> Tensor:
    """A real parameter (``t``, ``dt``, ``angle``, ...) in the compute dtype and device of ``like``.

    ``ref`` is ``(name, tensor)`` of the operand whose dtype a tensor ``x`` must share.  Numbers
    (Python, numpy, 0-d or n-d numpy arrays, nested lists) are converted; ``bool`` is refused.
    """
    if isinstance(x, Tensor):
        if x.dtype not in _FLOATS:
            raise TypeError(
                f"{fn}: expected {arg} to be a real number or a floating-point tensor, got "
                f"dtype {x.dtype}"
            )
        same_dtype(fn, **{ref[0]: ref[1], arg: x})
        batch_dims(fn, x.dim(), f"in {arg}")
        return x if x.dtype == like.dtype else x.to(like.dtype)
    # float and int first (the ABC check is slower); numpy's bool_ is not a numbers.Real
    if type(x) in (float, int) or (isinstance(x, numbers.Real) and not isinstance(x, bool)):
        return torch.tensor(float(x), dtype=like.dtype, device=like.device)
    if isinstance(x, np.ndarray) and x.dtype.kind in "fiu":
        batch_dims(fn, x.ndim, f"in {arg}")
        return torch.as_tensor(x).to(dtype=like.dtype, device=like.device)
    if isinstance(x, (list, tuple)) and _real_leaves(x):
        try:
            t = torch.tensor(x, dtype=like.dtype, device=like.device)
        except (ValueError, TypeError, RuntimeError):
            raise ValueError(
                f"{fn}: expected {arg} to be a rectangular (nested) list of numbers, got a "
                "ragged one"
            ) from None
        batch_dims(fn, t.dim(), f"in {arg}")
        return t
    what = f"numpy array of dtype {x.dtype}" if isinstance(x, np.ndarray) else type(x).__name__
    raise TypeError(
        f"{fn}: expected {arg} to be a real number, a list or numpy array of them, or a "
        f"floating-point tensor, got {what}"
    )


def flag(x: object, fn: str, arg: str) -> bool:
    """A yes/no argument: ``bool`` (or numpy's); anything else is a ``TypeError`` (a string
    such as ``"no"``, a number or a tensor would be read by its truth value)."""
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    raise TypeError(
        f"{fn}: expected {arg} to be True or False, got {type(x).__name__} {reprlib.repr(x)}"
    )


def generator(x: object, fn: str) -> None:
    """A ``generator=`` argument: a ``torch.Generator`` or None; anything else (a seed, say)
    is a ``TypeError``."""
    if x is not None and not isinstance(x, torch.Generator):
        raise TypeError(
            f"{fn}: expected generator to be a torch.Generator or None, got "
            f"{type(x).__name__} {reprlib.repr(x)}"
        )


def count(x: object, fn: str, arg: str, least: int) -> int:
    """An integer argument of at least ``least`` (``bool`` is not one; numpy and 0-d integer
    tensors are): ``TypeError`` for another type, ``ValueError`` below ``least``."""
    try:
        if isinstance(x, bool):
            raise TypeError
        n = operator.index(x)  # type: ignore[arg-type]
    except TypeError:
        raise TypeError(
            f"{fn}: expected {arg} to be an integer >= {least}, got {type(x).__name__} "
            f"{reprlib.repr(x)}"
        ) from None
    if n < least:
        raise ValueError(f"{fn}: expected {arg} >= {least}, got {arg}={n}")
    return n


def nonnegative(x: object, fn: str, arg: str, positive: bool = False) -> float:
    """A non-negative (``positive``: positive) finite real number, such as a tolerance or a
    weight, as a ``float``.

    Python and numpy numbers; ``bool`` and tensors are refused (a tensor's value cannot be
    checked without a device sync).
    """
    what = "positive" if positive else "non-negative"
    if isinstance(x, bool) or not isinstance(x, numbers.Real):
        raise TypeError(
            f"{fn}: expected {arg} to be a {what} finite real number, got {type(x).__name__}"
        )
    v = float(x)
    if not (math.isfinite(v) and (v > 0.0 if positive else v >= 0.0)):
        raise ValueError(f"{fn}: expected {arg} to be a {what} finite real number, got {v}")
    return v


def tolerance(x: object, fn: str, arg: str, dtype: torch.dtype) -> float:
    """``atol``-like argument: ``None`` gives :func:`default_atol` of ``dtype``."""
    return default_atol(dtype) if x is None else nonnegative(x, fn, arg)


def batch_broadcast(fn: str, *shapes: tuple[torch.Size, str]) -> torch.Size:
    """Broadcast the leading (batch) shapes, raising a ``ValueError`` that names the function
    (shapes that do not broadcast, or a result of more than :data:`MAX_BATCH_DIMS` dimensions).

    Eager calls broadcast in plain Python over the sizes (``torch.broadcast_shapes`` costs more
    than a small op's arithmetic); while compiling, sizes may be symbolic and
    ``torch.broadcast_shapes`` decides (it is traced once, so it costs nothing per call).
    """
    if torch.compiler.is_compiling():
        try:
            out = torch.broadcast_shapes(*(s for s, _ in shapes))
        except RuntimeError:
            raise _broadcast_error(fn, shapes) from None
        if len(out) > MAX_BATCH_DIMS:
            raise _broadcast_dims(fn, shapes)
        return out
    first = shapes[0][0] if shapes else ()
    for shape, _ in shapes:
        if shape != first:
            break
    else:
        if len(first) > MAX_BATCH_DIMS:
            raise _broadcast_dims(fn, shapes)
        return first if type(first) is torch.Size else torch.Size(first)
    result: list[int] = []  # the broadcast shape, last dimension first
    for shape, _ in shapes:
        for i, d in enumerate(reversed(shape)):
            if i == len(result):
                result.append(d)
            elif d != result[i]:
                if result[i] == 1:
                    result[i] = d
                elif d != 1:
                    raise _broadcast_error(fn, shapes)
    if len(result) > MAX_BATCH_DIMS:
        raise _broadcast_dims(fn, shapes)
    result.reverse()
    return torch.Size(result)


def pair(
    fn: str,
    a: object,
    b: object,
    na: str,
    nb: str,
    ta: tuple[int, ...],
    tb: tuple[int, ...],
) -> tuple[Tensor, Tensor, torch.dtype, torch.Size]:
    """Check the two tensor operands ``a`` (named ``na``, ending in ``ta``) and ``b`` of ``fn``:
    each as :func:`tensor`, one dtype, batch shapes that broadcast.  Returns both in the
    compute dtype, the output dtype and the broadcast batch shape."""
    x, dtype = tensor(a, fn, na, ta)
    y, other = tensor(b, fn, nb, tb)
    if other != dtype:
        same_dtype(fn, **{na: a, nb: b})
    sx, sy = x.shape, y.shape
    batch = batch_broadcast(fn, (sx[: len(sx) - len(ta)], na), (sy[: len(sy) - len(tb)], nb))
    return x, y, dtype, batch


def _broadcast_dims(fn: str, shapes: tuple[tuple[torch.Size, str], ...]) -> ValueError:
    """The error of a broadcast batch of more than :data:`MAX_BATCH_DIMS` dimensions, naming the
    longest operand (one whose batch was not checked before, such as the IK solver's targets)."""
    shape, name = max(shapes, key=lambda s: len(s[0]))
    return _too_many(fn, len(shape), f"in {name}")


def _broadcast_error(fn: str, shapes: tuple[tuple[torch.Size, str], ...]) -> ValueError:
    desc = ", ".join(f"{name} batch {tuple(s)}" for s, name in shapes)
    return ValueError(f"{fn}: batch shapes do not broadcast: {desc}")


def out(x: Tensor, dtype: torch.dtype) -> Tensor:
    """Cast a result computed in float32 back to a half-precision input dtype."""
    return x if x.dtype == dtype else x.to(dtype)


def default_atol(dtype: torch.dtype) -> float:
    """Default tolerance of the value checks (``is_valid``, ``is_unit``) for an input dtype."""
    return (4 if dtype in _LOW_PRECISION else 100) * torch.finfo(dtype).eps


def unit_norm(x: Tensor, tol: float) -> Tensor:
    """Per element of ``x`` ``(..., k)``: finite and ``| |x| - 1 | <= tol`` (the ``is_unit`` value
    check of quaternions and of the complex numbers of ``SO2.from_complex``)."""
    n = torch.linalg.vector_norm(x, dim=-1)
    return ((n - 1.0).abs() <= tol) & torch.isfinite(x).all(dim=-1)
