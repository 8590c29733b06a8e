"""Shape annotations.

Public functions are annotated with jaxtyping-style shape strings, e.g.
``Float[Tensor, "*batch 3"]``.  jaxtyping is only a test dependency: when it is missing the
names below are plain aliases of :class:`torch.Tensor`, so annotations cost nothing at run time.
The test suite checks the annotations with ``jaxtyping.jaxtyped`` + ``beartype``.
"""

from __future__ import annotations

from torch import Tensor

try:  # pragma: no cover - exercised by whichever environment runs
    from jaxtyping import Bool, Float, Int, Shaped
except ImportError:  # pragma: no cover

    class _Alias:
        def __class_getitem__(cls, item: object) -> type[Tensor]:
            return Tensor

    class Float(_Alias):  # type: ignore[no-redef]
        pass

    class Bool(_Alias):  # type: ignore[no-redef]
        pass

    class Int(_Alias):  # type: ignore[no-redef]
        pass

    class Shaped(_Alias):  # type: ignore[no-redef]
        pass


__all__ = ["Bool", "Float", "Int", "Shaped", "Tensor"]
