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
    if not x.is_floating_point():
        raise TypeError(
            f"{fn}: expected {arg} to be a floating-point tensor (float16, bfloat16, float32 or "
            f"float64), got dtype {x.dtype}"
        )
    n = len(trailing)
    if x.dim() < n or tuple(x.shape[x.dim() - n :]) != trailing:
        raise ValueError(
            f"{fn}: expected {arg} of shape {_shape_str(trailing)}, got {tuple(x.shape)}"
        )
    if x.dtype in _LOW_PRECISION:
        return x.float(), x.dtype
    return x, x.dtype


def same_dtype(fn: str, **tensors: Tensor) -> None:
    """Raise a ``TypeError`` unless all tensors share one dtype."""
    dtypes = {name: t.dtype for name, t in tensors.items()}
    if len(set(dtypes.values())) > 1:
        desc = ", ".join(f"{k} is {v}" for k, v in dtypes.items())
        raise TypeError(f"{fn}: expected inputs of one dtype, got {desc}")


def batch_broadcast(fn: str, *shapes: tuple[torch.Size, str]) -> torch.Size:
    """Broadcast the leading (batch) shapes, raising a ``ValueError`` that names the function."""
    try:
        return torch.broadcast_shapes(*(s for s, _ in shapes))
    except RuntimeError:
        desc = ", ".join(f"{name} batch {tuple(s)}" for s, name in shapes)
        raise ValueError(f"{fn}: batch shapes do not broadcast: {desc}") from None


def out(x: Tensor, dtype: torch.dtype) -> Tensor:
    """Cast a result computed in float32 back to a half-precision input dtype."""
    return x if x.dtype == dtype else x.to(dtype)


def default_atol(dtype: torch.dtype) -> float:
    """Default tolerance of the value checks (``is_valid``, ``is_unit``) for an input dtype."""
    return (4 if dtype in _LOW_PRECISION else 100) * torch.finfo(dtype).eps
