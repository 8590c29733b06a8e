"""torch.func transforms under torch.compile give each op's own derivatives, as in eager mode.

Every op with its own derivative formulas (a custom autograd Function) is differentiated by
``grad``, ``jacrev``, ``jacfwd`` and ``jvp`` inside ``torch.compile(fullgraph=True)`` and the
results compared with the same transforms in eager mode, in both dtypes, on batches that hold
the singular points (theta = 0, a tiny angle, theta near pi, repeated singular values).  Dynamo
and AOTAutograd decide how a Function is traced, so the graphs go through ``aot_eager``
(Inductor only generates code for the graph they produce; one Inductor case checks that too).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import pytest
import torch

from torchlie import quaternion, se3, so3

pytestmark = pytest.mark.compile


def _rotvecs(dtype: torch.dtype) -> torch.Tensor:
    # a generic angle, a tiny one, just below pi, exactly 0
    return torch.tensor(
        [[0.3, -0.2, 0.5], [1e-9, 0.0, 0.0], [0.0, math.pi - 1e-6, 0.0], [0.0, 0.0, 0.0]],
        dtype=dtype,
    )


def _cases(dtype: torch.dtype) -> dict[str, tuple[Callable[..., torch.Tensor], tuple]]:
    g = torch.Generator().manual_seed(0)
    w = _rotvecs(dtype)
    R = so3.exp(w)
    q = quaternion.from_rotvec(w)
    xi = torch.cat((torch.randn(4, 3, generator=g, dtype=dtype), w), dim=-1)
    T = se3.exp(xi)
    p = torch.randn(4, 3, generator=g, dtype=dtype)
    # identity (three equal singular values) and a generic matrix
    M = torch.stack((torch.eye(3, dtype=dtype),) * 2 + (R[0] + 0.1, R[2]))
    # general quaternions: beside the branch cut, w = 0, a tie, and a scaled one
    qg = torch.tensor(
        [
            [-1.0, 0.0, 1e-20, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.5, 0.5, 0.0, 0.0],
            [0.6, -0.4, 1.0, 1.8],
        ],
        dtype=dtype,
    )
    return {
        "so3.exp": (so3.exp, (w,)),
        "so3.log": (so3.log, (R,)),
        "so3.act": (so3.act, (R, p)),
        "so3.project": (so3.project, (M,)),
        "quaternion.multiply": (quaternion.multiply, (q, q.flip(0))),
        "quaternion.to_matrix": (quaternion.to_matrix, (q,)),
        "quaternion.from_matrix": (quaternion.from_matrix, (R,)),
        "quaternion.apply": (quaternion.apply, (q, p)),
        "quaternion.log": (quaternion.log, (qg,)),
        "se3.exp": (se3.exp, (xi,)),
        "se3.log": (se3.log, (T,)),
        "se3.compose": (se3.compose, (T, T.flip(0))),
        "se3.inverse": (se3.inverse, (T,)),
        "se3.act": (se3.act, (T, p)),
    }


def _transforms(f: Callable[..., torch.Tensor], n: int) -> Callable[..., tuple]:
    """``grad``, ``jacrev``, ``jacfwd`` and ``jvp`` of ``f`` (``n`` tensor arguments) in one
    function of ``n`` tensors (one graph to compile; fixed arity: Dynamo traces these best)."""
    if n == 1:

        def loss1(a: torch.Tensor) -> torch.Tensor:
            return (f(a) ** 2).sum()

        def all1(a: torch.Tensor) -> tuple:
            return (
                torch.func.grad(loss1)(a),
                torch.func.jacrev(f)(a),
                torch.func.jacfwd(f)(a),
                torch.func.jvp(f, (a,), (torch.ones_like(a),))[1],
            )

        return all1

    def loss2(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        return (f(a, b) ** 2).sum()

    def all2(a: torch.Tensor, b: torch.Tensor) -> tuple:
        return (
            torch.func.grad(loss2, argnums=(0, 1))(a, b),
            torch.func.jacrev(f, argnums=(0, 1))(a, b),
            torch.func.jacfwd(f, argnums=(0, 1))(a, b),
            torch.func.jvp(f, (a, b), (torch.ones_like(a), torch.ones_like(b)))[1],
        )

    return all2


OPS = list(_cases(torch.float64))
TRANSFORMS = ("grad", "jacrev", "jacfwd", "jvp")


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("op", OPS)
def test_func_transforms_under_compile_match_eager(op, dtype):
    f, args = _cases(dtype)[op]
    transforms = _transforms(f, len(args))
    expected = transforms(*args)
    got = torch.compile(transforms, backend="aot_eager", fullgraph=True)(*args)
    torch._dynamo.reset()
    eps = torch.finfo(dtype).eps
    for name, e_tree, c_tree in zip(TRANSFORMS, expected, got, strict=True):
        e_leaves = torch.utils._pytree.tree_leaves(e_tree)
        c_leaves = torch.utils._pytree.tree_leaves(c_tree)
        assert len(c_leaves) == len(e_leaves)
        for e, c in zip(e_leaves, c_leaves, strict=True):
            assert torch.isfinite(c).all(), f"{op} {name}: non-finite under compile"
            scale = e.abs().amax().clamp_min(1.0)
            assert (c - e).abs().amax() <= 8 * eps * scale, f"{op} {name}"


def test_grad_under_inductor_matches_eager():
    w = _rotvecs(torch.float64)
    R = so3.exp(w)

    def grad_of_log(R: torch.Tensor) -> torch.Tensor:
        return torch.func.grad(lambda M: (so3.log(M) ** 2).sum())(R)

    expected = grad_of_log(R)
    got = torch.compile(grad_of_log, fullgraph=True)(R)
    torch.testing.assert_close(got, expected, rtol=1e-12, atol=1e-12)


def test_forward_mode_of_project_under_compile_is_finite_at_repeated_singular_values():
    M = torch.eye(3, dtype=torch.float64).expand(5, 3, 3).clone()
    dM = torch.randn(5, 3, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(1))

    def tangent(M: torch.Tensor, dM: torch.Tensor) -> torch.Tensor:
        return torch.func.jvp(so3.project, (M,), (dM,))[1]

    expected = tangent(M, dM)
    got = torch.compile(tangent, backend="aot_eager", fullgraph=True)(M, dM)
    assert torch.isfinite(expected).all()
    torch.testing.assert_close(got, expected, rtol=0, atol=1e-15)
    # at R = I the tangent is the skew part of dM
    torch.testing.assert_close(got, 0.5 * (dM - dM.transpose(-1, -2)), rtol=0, atol=1e-15)
