"""torchlie.compiled: the same results and gradients as the eager API, compiled fullgraph."""

from __future__ import annotations

import pytest
import torch

from torchlie import compiled, conversions, quaternion, se3, so3

pytestmark = pytest.mark.compile


def test_compiled_mirrors_the_eager_api():
    w = torch.randn(7, 3, dtype=torch.float64)
    w[0] = 0.0
    R = so3.exp(w)
    torch.testing.assert_close(compiled.so3.exp(w), R, rtol=0, atol=1e-15)
    q = torch.randn(7, 4, dtype=torch.float64)
    torch.testing.assert_close(
        compiled.quaternion.to_matrix(q), quaternion.to_matrix(q), rtol=0, atol=1e-15
    )
    a = torch.randn(7, 3, dtype=torch.float64)
    torch.testing.assert_close(
        compiled.conversions.euler_to_matrix(a, "ZYX"),
        conversions.euler_to_matrix(a, "ZYX"),
        rtol=0,
        atol=1e-15,
    )
    xi = torch.randn(7, 6, dtype=torch.float64)
    torch.testing.assert_close(compiled.se3.exp(xi), se3.exp(xi), rtol=0, atol=1e-15)
    # compiled once, then kept on the namespace
    assert compiled.so3.exp is compiled.so3.exp
    assert compiled.so3.exp.__name__ == "exp" and compiled.so3.exp.__doc__ == so3.exp.__doc__


def test_compiled_gradients_and_errors():
    w = torch.randn(5, 3, dtype=torch.float64, requires_grad=True)
    (g_eager,) = torch.autograd.grad(so3.log(so3.exp(w) @ so3.exp(w)).sum(), w)
    (g_comp,) = torch.autograd.grad(
        compiled.so3.log(compiled.so3.exp(w) @ compiled.so3.exp(w)).sum(), w
    )
    torch.testing.assert_close(g_comp, g_eager, rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError, match=r"torchlie\.so3\.exp: expected omega of shape"):
        compiled.so3.exp(torch.zeros(2, 4))
    with pytest.raises(AttributeError, match="has no function '_exp'"):
        compiled.so3._exp  # noqa: B018
    assert compiled.so3.random is so3.random
    assert set(dir(compiled.so3)) == set(so3.__all__)
