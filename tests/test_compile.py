"""Every public so3 and quaternion-core op under torch.compile(fullgraph=True).

fullgraph=True fails on any graph break, so these tests also prove that no op synchronises the
device or branches in Python on tensor values.  One compiled function per module keeps the
compile cost to one graph each.  These two graphs go through Inductor, the backend users get
(so do tests/test_compiled.py, test_nn.py, test_se3.py and
test_kinematics_compile.py); the fullgraph tests of the other modules use ``aot_eager``:
Dynamo and AOTAutograd trace the same graph, forward and backward, without Inductor's C++ code
generation, which costs 10-40 s per graph on a cold cache.
"""

from __future__ import annotations

import pytest
import torch
from samplers import PI

from torchlie import _autograd, quaternion, se3, so3

pytestmark = pytest.mark.compile


def _so3_all(w: torch.Tensor, p: torch.Tensor, M: torch.Tensor) -> tuple[torch.Tensor, ...]:
    R = so3.exp(w)
    S = so3.compose(R, R.flip(0))
    return (
        so3.hat(w),
        so3.vee(so3.hat(w)),
        R,
        so3.log(R),
        S,
        so3.inverse(R),
        so3.act(R, p),
        so3.adjoint(R),
        so3.jac_left(w),
        so3.jac_right(w),
        so3.jac_left_inv(w),
        so3.jac_right_inv(w),
        so3.identity(2, dtype=w.dtype),
        so3.is_valid(R),
        so3.project(M),
        so3.distance(R, S),
        so3.interpolate(R, S, 0.25),
    )


def _quaternion_core(q: torch.Tensor, w: torch.Tensor) -> tuple[torch.Tensor, ...]:
    R = quaternion.to_matrix(q)
    return (
        quaternion.multiply(q, q.flip(0)),
        quaternion.conjugate(q),
        quaternion.normalize(q),
        quaternion.canonicalize(-q),
        R,
        quaternion.from_matrix(R),
        quaternion.from_rotvec(w),
        quaternion.to_rotvec(q),
    )


def _inputs(dtype):
    g = torch.Generator().manual_seed(0)
    w = torch.randn(6, 3, generator=g, dtype=dtype)
    w[0] = 0.0
    w[1] = torch.tensor([PI, 0.0, 0.0], dtype=dtype)
    w[2] = torch.tensor([1e-9, 0.0, 0.0], dtype=dtype)
    p = torch.randn(6, 3, generator=g, dtype=dtype)
    M = torch.randn(6, 3, 3, generator=g, dtype=dtype)
    q = torch.randn(6, 4, generator=g, dtype=dtype)
    return w, p, M, q


@pytest.mark.parametrize("dtype", [torch.float32])
def test_so3_ops_compile_fullgraph(dtype):
    w, p, M, _ = _inputs(dtype)
    eager = _so3_all(w, p, M)
    compiled = torch.compile(_so3_all, fullgraph=True)(w, p, M)
    assert len(eager) == len(compiled)
    for a, b in zip(eager, compiled, strict=True):
        if a.dtype == torch.bool:
            assert torch.equal(a, b)
        else:
            torch.testing.assert_close(b, a, rtol=1e-5, atol=1e-5)


def test_quaternion_core_compile_fullgraph():
    w, _, _, q = _inputs(torch.float32)
    eager = _quaternion_core(q, w)
    compiled = torch.compile(_quaternion_core, fullgraph=True)(q, w)
    for a, b in zip(eager, compiled, strict=True):
        torch.testing.assert_close(b, a, rtol=1e-5, atol=1e-5)


def test_large_batches_compile_fullgraph_whatever_the_threads():
    """Batches large enough for the eager blocks compile in one graph, forward and backward,
    where the eager blocks are sized by the thread count: ``torch.get_num_threads()`` would
    break the graph, and is not called while compiling (``aot_eager``, see above)."""
    g = torch.Generator().manual_seed(1)
    n = _autograd.BLOCK // 2  # 3 n numbers per batch of vectors: above the eager threshold
    w, xi = torch.randn(n, 3, generator=g), torch.randn(n, 6, generator=g)

    def ops(w, xi):
        R, T = so3.exp(w), se3.exp(xi)
        return so3.log(R), quaternion.from_matrix(R), quaternion.to_matrix(xi[..., :4]), se3.log(T)

    results = []
    for fn in (ops, torch.compile(ops, fullgraph=True, backend="aot_eager")):
        leaves = [w.clone().requires_grad_(), xi.clone().requires_grad_()]
        ys = fn(*leaves)
        results.append((ys, torch.autograd.grad(sum(y.sum() for y in ys), leaves)))
    for want, got in zip(*results, strict=True):
        for a, b in zip(want, got, strict=True):
            torch.testing.assert_close(b, a, rtol=1e-5, atol=1e-4)
