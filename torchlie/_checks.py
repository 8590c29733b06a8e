"""Input checks shared by every public function.

Shape and dtype checks read only metadata, so they never synchronise a device and they trace
away under ``torch.compile``.  Value checks (orthonormality, unit norm) cost a sync and are the
explicit ``is_valid`` / ``is_unit`` functions of each module instead.
"""

from __future__ import annotations

import torch
from torch import Tensor

_LOW_PRECISION = (torch.float16, torch.bfloat16)


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
    if not dtype.is_floating_point:
        raise TypeError(
            f"{fn}: expected {arg} to be a floating-point tensor (float16, bfloat16, float32 or "
            f"float64), got dtype {dtype}"
        )
    shape = tuple(x.shape)  # a tuple slices several times faster than a torch.Size
    k = len(shape) - len(trailing)
    if k < 0 or shape[k:] != trailing:
        raise ValueError(f"{fn}: expected {arg} of shape {_shape_str(trailing)}, got {shape}")
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


def batch_broadcast(fn: str, *shapes: tuple[torch.Size, str]) -> torch.Size:
    """Broadcast the leading (batch) shapes, raising a ``ValueError`` that names the function.

    Eager calls broadcast in plain Python over the sizes (``torch.broadcast_shapes`` costs ~10 us
    a call, more than a small op's arithmetic); while compiling, sizes may be symbolic and
    ``torch.broadcast_shapes`` decides (it is traced once, so it costs nothing per call).
    """
    if torch.compiler.is_compiling():
        try:
            return torch.broadcast_shapes(*(s for s, _ in shapes))
        except RuntimeError:
            raise _broadcast_error(fn, shapes) from None
    first = shapes[0][0] if shapes else ()
    for shape, _ in shapes:
        if shape != first:
            break
    else:
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
    result.reverse()
    return torch.Size(result)


def _broadcast_error(fn: str, shapes: tuple[tuple[torch.Size, str], ...]) -> ValueError:
    desc = ", ".join(f"{name} batch {tuple(s)}" for s, name in shapes)
    return ValueError(f"{fn}: batch shapes do not broadcast: {desc}")


def out(x: Tensor, dtype: torch.dtype) -> Tensor:
    """Cast a result computed in float32 back to a half-precision input dtype."""
    return x if x.dtype == dtype else x.to(dtype)


def default_atol(dtype: torch.dtype) -> float:
    """Default tolerance of the value checks (``is_valid``, ``is_unit``) for an input dtype."""
    return (4 if dtype in _LOW_PRECISION else 100) * torch.finfo(dtype).eps
