"""Forward kinematics and Jacobians under torch.compile(fullgraph=True)."""

from __future__ import annotations

import pytest
import torch

from torchlie.kinematics import Chain, sample_robot

TOL = 64 * torch.finfo(torch.float32).eps


@pytest.mark.compile
def test_compile_fullgraph_every_joint_type():
    # aot_eager: dynamo must trace everything in one graph (fullgraph) through AOT autograd,
    # without paying inductor's code generation for this many small groups.
    chain = Chain.from_urdf(sample_robot("tree"))
    links = ["left_finger_b", "right_index", "puck_tool", "drone_camera"]

    def f(q):
        return chain.forward_kinematics(q, links, stacked=True), chain.jacobian(q, "drone_camera")

    q = chain.random_configuration(16, generator=torch.Generator().manual_seed(0))
    T, J = torch.compile(f, fullgraph=True, backend="aot_eager")(q)
    assert not chain._plans and not chain._jac_plans  # tracing caches nothing
    T_eager, J_eager = f(q)
    torch.testing.assert_close(T, T_eager, atol=TOL, rtol=0)
    torch.testing.assert_close(J, J_eager, atol=TOL, rtol=0)


@pytest.mark.compile
@pytest.mark.slow
def test_compile_inductor_arm():
    arm = Chain.from_urdf(sample_robot("arm7"))
    q = arm.random_configuration(32, generator=torch.Generator().manual_seed(0))
    f = torch.compile(lambda x: arm.forward_kinematics(x, stacked=True), fullgraph=True)
    torch.testing.assert_close(f(q), arm.forward_kinematics(q, stacked=True), atol=TOL, rtol=0)
