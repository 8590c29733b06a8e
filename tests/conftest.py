"""Shared fixtures: dtype, device, generator, batch shapes."""

from __future__ import annotations

import pytest
import torch

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


@pytest.fixture(autouse=True)
def _seeded_global_generator():
    """Each test starts from one state of torch's global generator: a test that draws from it
    gets the same inputs whichever tests ran before it in its worker (pytest-xdist groups the
    files into workers by the machine's core count)."""
    torch.manual_seed(0)


@pytest.fixture
def gen() -> torch.Generator:
    return torch.Generator().manual_seed(1234)
