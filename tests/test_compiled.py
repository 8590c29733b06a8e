"""torchlie.compiled: the same results and gradients as the eager API, compiled fullgraph."""

from __future__ import annotations

import pytest
import torch
from samplers import ANGLES, rotvecs

from torchlie import compiled, conversions, quaternion, se3, so3

pytestmark = pytest.mark.compile


def test_compiled_mirrors_the_eager_api():
    # float64 exp: the compensated kernel in Inductor's vectorised loop keeps its error-free
    # transforms (no contraction into fused multiply-adds): eager's values within 2.5e-16
    w, _ = rotvecs(ANGLES, n_random=20, dtype=torch.float64)
    R = so3.exp(w)
    torch.testing.assert_close(compiled.so3.exp(w), R, rtol=0, atol=2.5e-16)
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


def test_inductor_options():
    vectorised = {"cpp.enable_tiling_heuristics": False}
    assert compiled.inductor_options("so3", "exp") == vectorised
    assert compiled.inductor_options("se3", "log") == vectorised
    assert compiled.inductor_options("conversions", "matrix_to_euler") == vectorised
    for module, names in compiled.KEEP_HEURISTIC.items():
        for name in names:
            assert compiled.inductor_options(module, name) == {}
    with pytest.raises(ValueError, match=r"inductor_options: expected module to be one of"):
        compiled.inductor_options("so2", "exp")
    with pytest.raises(ValueError, match=r"torchlie\.so3 has no public function '_exp'"):
        compiled.inductor_options("so3", "_exp")
