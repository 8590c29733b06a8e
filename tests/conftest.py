"""Shared fixtures: dtype, device, generator, batch shapes, component kernels."""

from __future__ import annotations

import pytest
import torch

from torchlie import _rows, _small

torch.set_num_threads(1)

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
BATCH_SHAPES = [(), (1,), (5,), (2, 3)]


@pytest.fixture(params=[torch.float32, torch.float64], ids=["f32", "f64"])
def dtype(request) -> torch.dtype:
    return request.param


@pytest.fixture(params=DEVICES)
def device(request) -> str:
    return request.param


@pytest.fixture(params=BATCH_SHAPES, ids=lambda s: "b" + "x".join(map(str, s)) if s else "b()")
def batch(request) -> tuple[int, ...]:
    return request.param


@pytest.fixture
def gen() -> torch.Generator:
    return torch.Generator().manual_seed(1234)


@pytest.fixture
def component_kernels(monkeypatch) -> None:
    """Eager small batches on the component kernels, as under ``torch.func.vmap``, which never
    takes the matrix forms of :mod:`torchlie._small` (they agree with those kernels to a few
    ulp, test_small.py): for the tests that compare vmap with eager mode bit for bit."""
    monkeypatch.setattr(_small, "MATRIX_ROWS", 0)


class KernelCalls(list):
    """Names of kernels called, in order; :attr:`names`: every kernel watched."""

    names: tuple[str, ...] = (
        "act",
        "act_grads",
        "pose_act_grads",
        "compose",
        "compose_grads",
        "inverse",
        "inverse_grads",
    )


@pytest.fixture
def rows_calls(monkeypatch) -> KernelCalls:
    """The names of the large-batch kernels of :mod:`torchlie._rows` called, in order."""
    out = KernelCalls()
    for name in out.names:
        kernel = getattr(_rows, name)

        def spy(*args, _name=name, _kernel=kernel):
            out.append(_name)
            return _kernel(*args)

        monkeypatch.setattr(_rows, name, spy)
    return out
