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


@pytest.mark.compile
@pytest.mark.slow
def test_compiled_forward_mode_of_jacobians_and_dynamics():
    """Inductor's code for jvp of a Jacobian whose columns are not the DoFs in order (mimic
    joints, a branch) and of the dynamics with a floating joint's bias and external wrenches:
    the tangents are eager's."""
    chain = Chain.from_urdf(sample_robot("tree"), dtype=torch.float64)
    g = torch.Generator().manual_seed(1)
    q = chain.random_configuration(3, generator=g)
    u = torch.randn(q.shape, generator=g, dtype=torch.float64)
    wrench = torch.ones(6, dtype=torch.float64)

    def f(x):
        return (
            chain.jacobian(x, "left_finger_b"),
            chain.inverse_dynamics(x, x, x, f_ext={"puck_tool": wrench, "drone_camera": wrench}),
        )

    def tangents(a, b):
        return torch.func.jvp(f, (a,), (b,))[1]

    want = tangents(q, u)
    got = torch.compile(tangents, fullgraph=True)(q, u)
    for g_, w_ in zip(got, want, strict=True):
        torch.testing.assert_close(g_, w_, rtol=1e-12, atol=1e-12 * float(w_.abs().max()))
