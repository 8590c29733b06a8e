"""Inverse kinematics: convergence, limits, batching, implicit gradients and bad input."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import pytest
import torch

from torchlie import se3, so3
from torchlie.kinematics import Chain, IKResult, sample_robot
from torchlie.kinematics import ik as ik_module

F64 = torch.float64

# A 6R arm (no redundancy: a pose target has isolated solutions, so the solution is a
# function of the target and its derivative is unique).
ARM6 = (
    '<robot name="arm6">'
    + "".join(f'<link name="l{i}"/>' for i in range(7))
    + "".join(
        f'<joint name="j{i}" type="revolute"><parent link="l{i}"/><child link="l{i + 1}"/>'
        f'<origin xyz="{x}" rpy="{rpy}"/><axis xyz="{axis}"/>'
        '<limit lower="-3" upper="3"/></joint>'
        for i, (x, rpy, axis) in enumerate(
            [
                ("0 0 0.3", "0 0 0", "0 0 1"),
                ("0 0.1 0.1", "0 0 0", "0 1 0"),
                ("0 0 0.45", "0 0 0", "0 1 0"),
                ("0.1 0 0.05", "0 0 0", "1 0 0"),
                ("0.35 0 0", "0 0 0", "0 1 0"),
                ("0.08 0 0", "0.3 0 0", "1 0 0"),
            ]
        )
    )
    + "</robot>"
)


ARM = Chain.from_urdf(sample_robot("arm7"), dtype=F64)
TREE = Chain.from_urdf(sample_robot("tree"), dtype=F64)


def _fk(chain: Chain, q: torch.Tensor, link: str) -> torch.Tensor:
    return chain.forward_kinematics(q, link)[link]


def _within_limits(chain: Chain, q: torch.Tensor) -> bool:
    return bool(((q >= chain.lower) & (q <= chain.upper)).all())


# ----------------------------------------------------------------------------------------------
# Convergence
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("dtype", [torch.float32, F64], ids=["f32", "f64"])
@pytest.mark.parametrize("robot, link", [("arm7", "tool_tcp"), ("panda", "panda_hand_tcp")])
def test_pose_targets_are_reached_within_limits(robot, link, dtype):
    chain = Chain.from_urdf(sample_robot(robot), dtype=dtype)
    gen = torch.Generator().manual_seed(3)
    T = _fk(chain, chain.random_configuration(24, generator=gen), link)
    res = chain.inverse_kinematics(T, link, restarts=8, generator=gen)
    assert isinstance(res, IKResult)
    assert res.q.shape == (24, chain.n_dof) and res.q.dtype == dtype
    assert res.converged.dtype == torch.bool and res.iterations.dtype == torch.int64
    assert bool(res.converged.all())
    assert _within_limits(chain, res.q)
    # The reported errors are those of the returned q, and within the tolerances.
    angle, dist = se3.distance(_fk(chain.to(F64), res.q.double(), link), T.double())
    slack = 1e-5 if dtype == torch.float32 else 1e-12
    assert float((dist - res.position_error.double()).abs().max()) < slack
    assert float((angle - res.rotation_error.double()).abs().max()) < 10 * slack
    assert float(dist.max()) <= 1e-4 + slack and float(angle.max()) <= 1e-3 + 10 * slack
    assert bool((res.iterations <= 40).all()) and bool((res.iterations > 0).all())


def test_float64_converges_to_machine_precision():
    arm = ARM
    gen = torch.Generator().manual_seed(0)
    T = _fk(arm, arm.random_configuration(16, generator=gen), "tool_tcp")
    res = arm.inverse_kinematics(T, "tool_tcp", restarts=4, generator=gen)
    assert float(res.position_error.max()) < 1e-12 and float(res.rotation_error.max()) < 1e-12


def test_rotation_weight_zero_solves_positions_of_pose_targets():
    arm = ARM
    gen = torch.Generator().manual_seed(12)
    T = _fk(arm, arm.random_configuration(6, generator=gen), "tool_tcp")
    T_turned = se3.compose(T, se3.exp(torch.tensor([0.0, 0.0, 0.0, 0.0, 0.0, 2.0], dtype=F64)))
    res = arm.inverse_kinematics(T_turned, "tool_tcp", rotation_weight=0.0, restarts=2,
                                 generator=gen)  # fmt: skip
    assert bool(res.converged.all()) and torch.equal(res.rotation_error, torch.zeros(6, dtype=F64))
    got = _fk(arm, res.q, "tool_tcp")[:, :3, 3]
    assert float((got - T[:, :3, 3]).norm(dim=-1).max()) < 1e-10


def test_position_targets():
    arm = ARM
    gen = torch.Generator().manual_seed(1)
    p = _fk(arm, arm.random_configuration(10, generator=gen), "tool_tcp")[:, :3, 3]
    res = arm.inverse_kinematics(p, "tool_tcp", restarts=2, generator=gen)
    assert bool(res.converged.all())
    assert torch.equal(res.rotation_error, torch.zeros(10, dtype=F64))
    got = _fk(arm, res.q, "tool_tcp")[:, :3, 3]
    assert float((got - p).norm(dim=-1).max()) < 1e-10


def test_several_links_of_a_tree_with_every_joint_type():
    tree = TREE
    """Both hands (mimic joints on each), the planar puck and the floating drone at once."""
    gen = torch.Generator().manual_seed(2)
    links = ["left_tcp", "right_index", "puck_tool", "drone_camera"]
    q_true = tree.random_configuration(6, generator=gen)
    T = tree.forward_kinematics(q_true, links)
    targets = {
        "left_tcp": T["left_tcp"],
        "right_index": T["right_index"][:, :3, 3],  # a position target
        "puck_tool": T["puck_tool"],
        "drone_camera": T["drone_camera"],
    }
    res = tree.inverse_kinematics(targets, restarts=4, generator=gen)
    assert bool(res.converged.all()), (res.position_error, res.rotation_error)
    assert _within_limits(tree, res.q)
    got = tree.forward_kinematics(res.q, links)
    for link in ("left_tcp", "puck_tool", "drone_camera"):
        angle, dist = se3.distance(got[link], targets[link])
        assert float(dist.max()) <= 1e-4 and float(angle.max()) <= 1e-3
    dist = (got["right_index"][:, :3, 3] - targets["right_index"]).norm(dim=-1)
    assert float(dist.max()) <= 1e-4
    # The floating joint's rotation vector stays an angle of at most pi.
    k = tree.joint_names.index("drone_free:rx")
    assert float(res.q[:, k : k + 3].norm(dim=-1).max()) <= math.pi + 1e-12


def test_batch_shapes_broadcast_and_empty():
    arm = ARM
    gen = torch.Generator().manual_seed(4)
    T = _fk(arm, arm.random_configuration(2, 3, generator=gen), "tool_tcp")
    q0 = arm.random_configuration(3, generator=gen)  # broadcast against (2, 3)
    res = arm.inverse_kinematics(T, "tool_tcp", q0=q0, restarts=2, max_iterations=40,
                                 generator=gen)  # fmt: skip
    assert res.q.shape == (2, 3, 7)
    assert res.position_error.shape == res.converged.shape == res.iterations.shape == (2, 3)
    assert bool(res.converged.all())
    one = arm.inverse_kinematics(T[1, 2], "tool_tcp", restarts=4, generator=gen)
    assert one.q.shape == (7,) and one.converged.shape == () and bool(one.converged)
    empty = arm.inverse_kinematics(T[:0], "tool_tcp", restarts=3)
    assert empty.q.shape == (0, 3, 7) and empty.converged.shape == (0, 3)


def test_initial_guess_at_the_solution_takes_no_iteration():
    arm = ARM
    gen = torch.Generator().manual_seed(5)
    q = arm.random_configuration(4, generator=gen)
    res = arm.inverse_kinematics(_fk(arm, q, "tool_tcp"), "tool_tcp", q0=q)
    assert torch.equal(res.iterations, torch.zeros(4, dtype=torch.int64))
    torch.testing.assert_close(res.q, q, atol=1e-12, rtol=0)


def test_max_iterations_zero_returns_the_clamped_start():
    arm = ARM
    q0 = arm.upper + 1.0
    res = arm.inverse_kinematics(_fk(arm, torch.zeros(7, dtype=F64), "tool_tcp"), "tool_tcp",
                                 q0=q0, max_iterations=0)  # fmt: skip
    assert torch.equal(res.q, arm.upper) and not bool(res.converged)


def test_early_exit_gives_the_same_quality():
    arm = ARM
    gen = torch.Generator().manual_seed(6)
    T = _fk(arm, arm.random_configuration(30, generator=gen), "tool_tcp")
    early = arm.inverse_kinematics(T, "tool_tcp", restarts=4, early_exit=True, generator=gen)
    assert bool(early.converged.all())
    angle, dist = se3.distance(_fk(arm, early.q, "tool_tcp"), T)
    torch.testing.assert_close(dist, early.position_error, atol=1e-12, rtol=0)
    torch.testing.assert_close(angle, early.rotation_error, atol=1e-12, rtol=0)
    assert float(dist.max()) <= 1e-4 and float(angle.max()) <= 1e-3
    # A target solved by its start is returned as is.
    q = arm.random_configuration(3, generator=gen)
    same = arm.inverse_kinematics(_fk(arm, q, "tool_tcp"), "tool_tcp", q0=q, early_exit=True)
    assert torch.equal(same.q, q) and torch.equal(
        same.iterations, torch.zeros(3, dtype=torch.int64)
    )


def test_user_bounds_are_respected():
    arm = ARM
    gen = torch.Generator().manual_seed(7)
    lower = arm.lower.clone()
    upper = arm.upper.clone()
    lower[0], upper[0] = 0.2, 0.2  # base yaw fixed
    q = arm.random_configuration(5, generator=gen)
    q[:, 0] = 0.2
    p = _fk(arm, q, "tool_tcp")[:, :3, 3]
    res = arm.inverse_kinematics(p, "tool_tcp", restarts=4, lower=lower, upper=upper,
                                 generator=gen)  # fmt: skip
    assert bool(res.converged.all())
    assert torch.equal(res.q[:, 0], torch.full((5,), 0.2, dtype=F64))


# ----------------------------------------------------------------------------------------------
# Unreachable targets
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("dtype", [torch.float32, F64], ids=["f32", "f64"])
def test_unreachable_targets_give_the_best_finite_point(dtype):
    arm = Chain.from_urdf(sample_robot("arm7"), dtype=dtype)
    far = torch.tensor([[5.0, 0.0, 1.0], [0.0, -7.0, 0.5]], dtype=dtype)
    res = arm.inverse_kinematics(far, "tool_tcp", restarts=4,
                                 generator=torch.Generator().manual_seed(0))  # fmt: skip
    assert not bool(res.converged.any())
    assert torch.equal(res.iterations, torch.full((2,), 24))  # the whole (default) budget
    one = arm.inverse_kinematics(far, "tool_tcp", generator=torch.Generator().manual_seed(0))
    assert torch.equal(one.iterations, torch.full((2,), 40))  # one start: a larger budget
    assert bool(torch.isfinite(res.q).all()) and _within_limits(arm, res.q)
    p = _fk(arm, res.q, "tool_tcp")[:, :3, 3]
    torch.testing.assert_close(res.position_error, (p - far).norm(dim=-1), atol=1e-5, rtol=0)
    # Stretched towards the target: closer than the best of many random configurations.
    samples = _fk(arm, arm.random_configuration(4000, generator=torch.Generator().manual_seed(1)),
                  "tool_tcp")[:, :3, 3]  # fmt: skip
    sampled = (samples.unsqueeze(1) - far).norm(dim=-1).amin(0)
    assert bool((res.position_error < sampled).all())
    # A pose target that is not a valid pose-in-reach at all: still finite.
    T = torch.eye(4, dtype=dtype).repeat(3, 1, 1)
    T[:, :3, 3] = torch.tensor([0.0, 0.0, 100.0], dtype=dtype)
    res = arm.inverse_kinematics(T, "tool_tcp", restarts=2)
    assert bool(torch.isfinite(res.q).all()) and not bool(res.converged.any())
    assert bool(torch.isfinite(res.position_error).all())


# ----------------------------------------------------------------------------------------------
# Targets that no DoF moves, and what a DoF is
# ----------------------------------------------------------------------------------------------

FIXED_ONLY = (
    '<robot name="r"><link name="a"/><link name="b"/><joint name="f" type="fixed">'
    '<parent link="a"/><child link="b"/><origin xyz="1 0 0"/></joint></robot>'
)


def test_a_link_no_dof_moves_keeps_the_first_start():
    """The root, a link fixed to it, or any link of a chain without DoFs: nothing is solved
    for; q is the first start as it is, converged says whether the link is at its target."""
    arm = ARM
    q0 = arm.upper + 1.0  # clamped into the limits
    for link in ("world", "base"):
        T = _fk(arm, torch.zeros(7, dtype=F64), link).expand(2, 4, 4).clone()
        T[1, :3, 3] += torch.tensor([0.0, 0.0, 0.5], dtype=F64)  # 0.5 m away: not reachable
        res = arm.inverse_kinematics(T, link, q0=q0, restarts=3)
        assert torch.equal(res.q, arm.upper.expand(2, 7))
        assert res.converged.tolist() == [True, False]
        assert res.iterations.tolist() == [0, 40]  # as for an unreachable target
        torch.testing.assert_close(res.position_error, torch.tensor([0.0, 0.5], dtype=F64))
        assert torch.equal(res.rotation_error, torch.zeros(2, dtype=F64))
    # Without q0: a uniform start within the limits.
    res = arm.inverse_kinematics(torch.zeros(3, 3, dtype=F64), "world", max_iterations=7,
                                 generator=torch.Generator().manual_seed(0))  # fmt: skip
    assert res.q.shape == (3, 7) and _within_limits(arm, res.q)
    assert bool(res.converged.all()) and torch.equal(res.iterations, torch.zeros(3).long())
    # The derivative with respect to the targets is zero (and q carries a graph).
    p = torch.tensor([[0.0, 0.0, 0.0]], dtype=F64, requires_grad=True)
    res = arm.inverse_kinematics(p, "world", q0=torch.zeros(7, dtype=F64))
    res.q.sum().backward()
    assert torch.equal(p.grad, torch.zeros(1, 3, dtype=F64))


@pytest.mark.parametrize("options", [{}, {"restarts": 4, "early_exit": True},
                                     {"max_iterations": 0}])  # fmt: skip
def test_a_chain_without_dofs_reports_whether_its_links_are_at_the_targets(options):
    fixed = Chain.from_urdf(FIXED_ONLY, dtype=F64)
    p = torch.tensor([[1.0, 0.0, 0.0], [1.0, 0.0, 0.25]], dtype=F64, requires_grad=True)
    res = fixed.inverse_kinematics(p, "b", **options)
    budget = options.get("max_iterations", 24 if options else 40)
    assert res.q.shape == (2, 0)
    assert res.converged.tolist() == [True, False]
    assert res.iterations.tolist() == [0, budget]
    torch.testing.assert_close(res.position_error, torch.tensor([0.0, 0.25], dtype=F64))
    (g,) = torch.autograd.grad(res.q.sum(), p)
    assert torch.equal(g, torch.zeros(2, 3, dtype=F64))
    T = torch.eye(4, dtype=F64)
    T[0, 3] = 1.0
    assert bool(fixed.inverse_kinematics(T, "b").converged)


def _three_hinges(first: str) -> str:
    """Three continuous joints about z, the first one named ``first``."""
    return (
        '<robot name="r"><link name="a"/><link name="b"/><link name="c"/><link name="t"/>'
        f'<joint name="{first}" type="continuous"><parent link="a"/><child link="b"/>'
        '<axis xyz="0 0 1"/></joint><joint name="j2" type="continuous"><parent link="b"/>'
        '<child link="c"/><origin xyz="1 0 0"/><axis xyz="0 0 1"/></joint>'
        '<joint name="j3" type="continuous"><parent link="c"/><child link="t"/>'
        '<origin xyz="1 0 0"/><axis xyz="0 0 1"/></joint></robot>'
    )


@pytest.mark.parametrize("name", ["wrist:rx", "x:rx", "arm:x", "j:qw"])
def test_a_joint_named_like_a_coordinate_is_solved_as_the_joint_it_is(name):
    """What a DoF is comes from its joint: a continuous joint named 'wrist:rx' is not the
    start of a floating joint's rotation vector (three hinges were wrapped as one)."""
    plain = Chain.from_urdf(_three_hinges("wrist"), dtype=F64)
    named = Chain.from_urdf(_three_hinges(name), dtype=F64)
    q = torch.tensor([[2.5, 2.0, 2.9], [-2.8, 2.2, -2.5]], dtype=F64)
    T = _fk(plain, q, "t")
    a = plain.inverse_kinematics(T, "t", q0=0.9 * q, generator=torch.Generator().manual_seed(0))
    b = named.inverse_kinematics(T, "t", q0=0.9 * q, generator=torch.Generator().manual_seed(0))
    assert bool(a.converged.all()) and bool(b.converged.all())
    assert torch.equal(a.q, b.q)
    # One such joint alone (so3.exp of one value raised).
    one = Chain.from_urdf(
        f'<robot name="r"><link name="a"/><link name="b"/><link name="t"/><joint name="{name}" '
        'type="continuous"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/></joint>'
        '<joint name="f" type="fixed"><parent link="b"/><child link="t"/><origin xyz="1 0 0"/>'
        "</joint></robot>",
        dtype=F64,
    )
    res = one.inverse_kinematics(torch.tensor([0.0, 1.0, 0.0], dtype=F64), "t")
    assert bool(res.converged) and abs(math.remainder(float(res.q) - math.pi / 2, math.tau)) < 1e-4
    assert named.dof_joints[0] == one.dof_joints[0] == (name, "continuous", "")


# ----------------------------------------------------------------------------------------------
# The derivative used by the solver, and the implicit gradients
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "robot, links", [("arm7", ["tool_tcp"]), ("tree", ["left_tcp", "drone_camera", "puck_tool"])]
)
def test_residual_jacobian_is_the_exact_derivative(robot, links):
    """``A = W^1/2 Jr(r)^-1 J_link`` against autodiff of the log residual ``Log(T*^-1 T(q))``."""
    chain = Chain.from_urdf(sample_robot(robot), dtype=F64)
    gen = torch.Generator().manual_seed(8)
    N = 5
    q = chain.random_configuration(N, generator=gen)
    T_star = chain.forward_kinematics(chain.random_configuration(N, generator=gen), links)
    tasks = [
        ik_module._Task(name, True,
                        se3.inverse(T_star[name]).reshape(N, 16).mT.reshape(4, 4, N))
        for name in links
    ]  # fmt: skip
    w = torch.tensor([1.0, 1.0, 1.0, 0.5, 0.5, 0.5] * len(links), dtype=F64)
    b, A = ik_module._residuals(chain, q.mT.contiguous(), tasks, w, None)

    def residual(x: torch.Tensor) -> torch.Tensor:
        T = chain.forward_kinematics(x, links)
        return torch.cat([se3.log(se3.compose(se3.inverse(T_star[n][k]), T[n])) for n in links]) * w

    for k in range(N):
        expected = torch.func.jacrev(residual)(q[k])
        torch.testing.assert_close(b[:, k], residual(q[k]), atol=1e-12, rtol=0)
        torch.testing.assert_close(A[:, :, k], expected, atol=1e-10, rtol=0)


@pytest.mark.parametrize("robot, links", [("panda", ["panda_hand_tcp"]),
                                           ("tree", ["left_tcp", "drone_camera"])])  # fmt: skip
def test_solver_residual_is_the_world_frame_residual(robot, links):
    """The iterations' residual is ``diag(R, R)`` times the log residual (same norm, so the
    same cost), and their Jacobian, the chain's world Jacobian, is its exact derivative at a
    solution (``Jr(0) = I``)."""
    chain = Chain.from_urdf(sample_robot(robot), dtype=F64)
    gen = torch.Generator().manual_seed(9)
    N = 4
    q = chain.random_configuration(N, generator=gen)
    T = chain.forward_kinematics(q, links)
    w = torch.tensor([1.0, 1.0, 1.0, 0.5, 0.5, 0.5] * len(links), dtype=F64)
    # diag(R, R) per link, per sample: (N, 6 L, 6 L)
    Rot = torch.stack(
        [torch.block_diag(*[T[n][k, :3, :3] for n in links for _ in range(2)]) for k in range(N)]
    )
    for at_solution in (False, True):
        qs = q if at_solution else chain.random_configuration(N, generator=gen)
        T_star = chain.forward_kinematics(qs, links)
        tasks = [
            ik_module._Task(name, True,
                            se3.inverse(T_star[name]).reshape(N, 16).mT.reshape(4, 4, N),
                            T_star[name][:, :3, 3].mT.contiguous())
            for name in links
        ]  # fmt: skip
        b, A = ik_module._residuals(chain, q.mT.contiguous(), tasks, w, None)
        bw, Aw, perr_w, rerr_w = ik_module._linearise(chain, q.mT.contiguous(), tasks, w, None)
        torch.testing.assert_close(bw.mT, (Rot @ b.mT.unsqueeze(-1)).squeeze(-1), atol=1e-12,
                                   rtol=0)  # fmt: skip
        # the errors: the largest distance and the largest angle over the links
        dist = torch.stack([(T[n][:, :3, 3] - T_star[n][:, :3, 3]).norm(dim=-1) for n in links])
        angle = (b / w.unsqueeze(-1)).view(len(links), 2, 3, N)[:, 1].norm(dim=1)
        torch.testing.assert_close(perr_w, dist.amax(0), atol=1e-12, rtol=0)
        torch.testing.assert_close(rerr_w, angle.amax(0), atol=1e-12, rtol=0)
        if at_solution:  # A (m, n, N); Aw (n, m, N)
            torch.testing.assert_close(Aw.permute(2, 1, 0), Rot @ A.permute(2, 0, 1), atol=1e-12,
                                       rtol=0)  # fmt: skip


def _solve6(xi: torch.Tensor, chain: Chain, T0: torch.Tensor, q0: torch.Tensor) -> torch.Tensor:
    return chain.inverse_kinematics(se3.compose(T0, se3.exp(xi)), "l6", q0=q0,
                                    max_iterations=30, restart_after=0).q  # fmt: skip


def test_gradient_of_the_solution_matches_finite_differences():
    """gradcheck (central differences of re-solved problems) on a non-redundant 6R arm."""
    chain = Chain.from_urdf(ARM6, dtype=F64)
    q_true = torch.tensor([0.3, -0.4, 0.9, 0.5, 0.7, -0.2], dtype=F64)
    T0 = _fk(chain, q_true, "l6")
    xi = torch.tensor([0.01, -0.02, 0.015, 0.02, -0.01, 0.03], dtype=F64, requires_grad=True)
    q0 = q_true + 0.05
    assert bool(chain.inverse_kinematics(se3.compose(T0, se3.exp(xi.detach())), "l6",
                                         q0=q0).converged)  # fmt: skip
    assert torch.autograd.gradcheck(lambda x: _solve6(x, chain, T0, q0), (xi,), atol=1e-6)


def test_gradient_of_a_position_solution_matches_finite_differences():
    chain = Chain.from_urdf(ARM6, dtype=F64)
    q = torch.tensor([0.3, -0.4, 0.9, 0.0, 0.0, 0.0], dtype=F64)
    p = _fk(chain, q, "l4")[:3, 3].clone().requires_grad_()  # three joints move l4's origin

    def solve(x: torch.Tensor) -> torch.Tensor:
        return chain.inverse_kinematics(x, "l4", q0=q + 0.05, restart_after=0).q

    assert torch.autograd.gradcheck(solve, (p,), atol=1e-6)
    (J,) = torch.autograd.functional.jacobian(solve, (p,))
    assert torch.equal(J[3:], torch.zeros(3, 3, dtype=F64))  # joints that do not move l4


def test_gradient_of_a_redundant_solution_moves_the_link_with_the_target():
    arm = ARM
    """7 joints, 3 constraints: the derivative is the minimum-norm one, and the link follows
    the target exactly to first order (d FK(q*(p)) / dp = I)."""
    q = arm.random_configuration(2, generator=torch.Generator().manual_seed(9))
    p = _fk(arm, q, "tool_tcp")[:, :3, 3]

    def reached(x: torch.Tensor) -> torch.Tensor:
        sol = arm.inverse_kinematics(x, "tool_tcp", q0=q + 0.02)
        return _fk(arm, sol.q, "tool_tcp")[:, :3, 3]

    J = torch.autograd.functional.jacobian(reached, p)  # (2, 3, 2, 3)
    for k in range(2):
        torch.testing.assert_close(J[k, :, k], torch.eye(3, dtype=F64), atol=1e-9, rtol=0)
        torch.testing.assert_close(J[k, :, 1 - k], torch.zeros(3, 3, dtype=F64), atol=0, rtol=0)
    # Minimum norm: the derivative of q has no component in the Jacobian's null space.
    sol = arm.inverse_kinematics(p, "tool_tcp", q0=q + 0.02)
    Jq = torch.autograd.functional.jacobian(
        lambda x: arm.inverse_kinematics(x, "tool_tcp", q0=q + 0.02).q, p
    )[0, :, 0]  # (7, 3)
    Jp = arm.jacobian(sol.q[0], "tool_tcp")[:3]  # (3, 7)
    torch.testing.assert_close(Jq, torch.linalg.pinv(Jp), atol=1e-8, rtol=0)


def test_gradient_is_zero_for_joints_on_a_limit():
    arm = ARM
    q = arm.random_configuration(1, generator=torch.Generator().manual_seed(10))[0]
    q[3] = arm.lower[3]
    T = _fk(arm, q, "tool_tcp").requires_grad_()
    upper = arm.upper.clone()
    upper[3] = arm.lower[3]  # the joint held on its limit, whatever the rounding of the steps
    res = arm.inverse_kinematics(T, "tool_tcp", q0=q, upper=upper)
    assert float(res.q[3].detach()) == float(arm.lower[3])
    (g,) = torch.autograd.grad(res.q[3], T, retain_graph=True)
    assert torch.equal(g, torch.zeros_like(g))
    (g,) = torch.autograd.grad(res.q[1], T)
    assert float(g.abs().max()) > 0


def test_no_graph_without_targets_that_require_grad():
    arm = ARM
    T = _fk(arm, torch.zeros(7, dtype=F64), "tool_tcp")
    assert not arm.inverse_kinematics(T, "tool_tcp").q.requires_grad


def test_forward_mode_derivative_is_the_reverse_mode_one():
    """jvp, forward_ad and jacfwd give the implicit derivative (their tensors do not require
    grad: the derivative is attached all the same)."""
    arm = ARM
    q = arm.random_configuration(1, generator=torch.Generator().manual_seed(3))
    p = _fk(arm, q, "tool_tcp")[0, :3, 3]

    def solve(x: torch.Tensor) -> torch.Tensor:
        return arm.inverse_kinematics(x, "tool_tcp", q0=q[0], max_iterations=50,
                                      position_tolerance=1e-12).q  # fmt: skip

    J = torch.autograd.functional.jacobian(solve, p)  # (7, 3)
    assert float(J.abs().max()) > 0.1
    e = torch.tensor([1.0, 0.0, 0.0], dtype=F64)
    torch.testing.assert_close(torch.func.jvp(solve, (p,), (e,))[1], J[:, 0], atol=1e-12, rtol=0)
    with torch.autograd.forward_ad.dual_level():
        out = solve(torch.autograd.forward_ad.make_dual(p, e))
        tangent = torch.autograd.forward_ad.unpack_dual(out).tangent
    torch.testing.assert_close(tangent, J[:, 0], atol=1e-12, rtol=0)
    with torch.no_grad():  # forward mode does not need grad mode
        torch.testing.assert_close(torch.func.jvp(solve, (p,), (e,))[1], J[:, 0], atol=1e-12,
                                   rtol=0)  # fmt: skip
    # The random starts need a randomness mode under jacfwd's vmap.
    torch.testing.assert_close(torch.func.jacfwd(solve, randomness="same")(p), J, atol=1e-12,
                               rtol=0)  # fmt: skip


def test_second_derivative_of_the_solution_matches_finite_differences():
    """The Hessian of a non-redundant solution is that of the solution (central differences
    of its first derivative), not only its first derivative's."""
    chain = Chain.from_urdf(ARM6, dtype=F64)
    q_true = torch.tensor([0.3, -0.4, 0.9, 0.5, 0.7, -0.2], dtype=F64)
    T0 = _fk(chain, q_true, "l6")
    xi = torch.tensor([0.01, -0.02, 0.015, 0.02, -0.01, 0.03], dtype=F64)

    def solve(x: torch.Tensor) -> torch.Tensor:
        tight = {"position_tolerance": 1e-13, "rotation_tolerance": 1e-13}
        return chain.inverse_kinematics(se3.compose(T0, se3.exp(x)), "l6", q0=q_true + 0.05,
                                        max_iterations=30, restart_after=0, **tight).q  # fmt: skip

    def grad(x: torch.Tensor) -> torch.Tensor:
        return torch.autograd.functional.jacobian(solve, x, create_graph=True)  # (6, 6)

    H = torch.autograd.functional.jacobian(grad, xi)  # (6, 6, 6)
    h = 1e-5
    fd = torch.stack([(grad(xi + h * e) - grad(xi - h * e)).detach() / (2 * h)
                      for e in torch.eye(6, dtype=F64)], -1)  # fmt: skip
    assert float(fd.abs().max()) > 0.1
    torch.testing.assert_close(H, fd, atol=1e-7, rtol=0)


def test_targets_that_require_grad_leave_the_solution_as_it_is():
    """A non-finite or far target (finite, beyond where squares overflow) that requires grad
    gives the solution found without grad (finite), and the other targets' gradients are
    finite."""
    arm = ARM
    q = arm.random_configuration(4, generator=torch.Generator().manual_seed(0))
    T = _fk(arm, q, "tool_tcp")
    T[1, 0, 3] = math.nan
    T[2, :3, 3] = torch.tensor([1e155, 0.0, 0.0], dtype=F64)
    T[3, :3, 3] = torch.tensor([0.0, -1e300, 0.0], dtype=F64)
    plain = arm.inverse_kinematics(T, "tool_tcp", restarts=2,
                                   generator=torch.Generator().manual_seed(1))  # fmt: skip
    Tg = T.clone().requires_grad_()
    res = arm.inverse_kinematics(Tg, "tool_tcp", restarts=2,
                                 generator=torch.Generator().manual_seed(1))  # fmt: skip
    assert bool(plain.q.isfinite().all())
    assert torch.equal(res.q.detach(), plain.q)
    (g,) = torch.autograd.grad(res.q[0].sum(), Tg)
    assert bool(g[0].isfinite().all()) and float(g[0].abs().max()) > 0
    assert torch.equal(g[1:], torch.zeros_like(g[1:]))


def test_position_error_is_the_distance_for_any_rotation_block():
    """The reported position error is the distance ``|p - p*|`` to the target's translation
    even where the target's rotation block is not a rotation (values are not checked): a zero
    block (a pose built from ``torch.zeros``), whose log residual is 0 at every ``q``, is not
    reported converged, and a scaled one does not scale the error."""
    arm = ARM
    T = torch.zeros(2, 4, 4, dtype=F64)
    T[:, 3, 3] = 1.0
    T[:, :3, 3] = torch.tensor([0.3, 0.2, 0.8], dtype=F64)
    T[1, :3, :3] = 2.0 * so3.exp(torch.tensor([0.3, -0.5, 0.2], dtype=F64))
    res = arm.inverse_kinematics(T, "tool_tcp", generator=torch.Generator().manual_seed(0))
    p = arm.forward_kinematics(res.q, "tool_tcp")["tool_tcp"][:, :3, 3]
    torch.testing.assert_close(res.position_error, (p - T[:, :3, 3]).norm(dim=-1))
    assert not bool(res.converged[0])
    assert float(res.position_error[0]) > 0.1


def test_far_targets_report_their_distance_and_are_stepped():
    """A finite target far beyond where the squared error overflows: its (finite) error, and
    the solver steps (it took no step: every cost was inf)."""
    arm = ARM
    for far in (1e160, 1e300):
        T = torch.eye(4, dtype=F64).repeat(2, 1, 1)
        T[:, :3, 3] = torch.tensor([[far, 0.0, 0.0], [0.0, 0.0, -far]], dtype=F64)
        start = arm.inverse_kinematics(T, "tool_tcp", max_iterations=0,
                                       generator=torch.Generator().manual_seed(0))  # fmt: skip
        res = arm.inverse_kinematics(T, "tool_tcp", generator=torch.Generator().manual_seed(0))
        torch.testing.assert_close(res.position_error, torch.full((2,), far, dtype=F64))
        assert bool((res.q != start.q).any(-1).all())


@pytest.mark.parametrize("dtype", [torch.float32, F64], ids=["f32", "f64"])
def test_restarts_return_the_best_of_their_starts_for_far_targets(dtype):
    """Independent starts (no restart): the point kept is the best single start's, also where
    the cost is large (a ranking key squeezing the costs into [0, 1) tied them)."""
    arm = Chain.from_urdf(sample_robot("arm7"), dtype=dtype)
    p = torch.tensor([[1e3, 0.0, 0.5]], dtype=dtype)
    if dtype == F64:
        p = p * 1e6
    starts = arm.random_configuration(1, 8, generator=torch.Generator().manual_seed(1))[0]
    res = arm.inverse_kinematics(p, "tool_tcp", restarts=8, restart_after=0, max_iterations=40,
                                 generator=torch.Generator().manual_seed(1))  # fmt: skip
    single = [arm.inverse_kinematics(p, "tool_tcp", q0=s, restart_after=0, max_iterations=40)
              for s in starts]  # fmt: skip
    best = min(range(8), key=lambda k: float(single[k].position_error))
    assert float(single[best].position_error) < float(single[0].position_error)
    # the same start alone and among 8 (kernels round by batch width: not bitwise)
    tol = 1e-6 if dtype == F64 else 1e-3
    torch.testing.assert_close(res.q, single[best].q, rtol=0, atol=tol)
    err = float(res.position_error)
    assert abs(err - float(single[best].position_error)) <= tol * err


def test_vmap():
    """Under torch.func.vmap (random starts need randomness="same" or "different")."""
    arm = ARM
    q = arm.random_configuration(3, generator=torch.Generator().manual_seed(0))
    T = _fk(arm, q, "tool_tcp")
    q0 = (q + 0.05).clamp(arm.lower, arm.upper)
    ref = arm.inverse_kinematics(T, "tool_tcp", q0=q0, restart_after=0)

    def solve(t: torch.Tensor, s: torch.Tensor, **options) -> torch.Tensor:
        return arm.inverse_kinematics(t, "tool_tcp", q0=s, **options).q

    out = torch.func.vmap(lambda t, s: solve(t, s, restart_after=0))(T, q0)
    torch.testing.assert_close(out, ref.q, atol=1e-9, rtol=0)
    out = torch.func.vmap(lambda t, s: solve(t, s, restarts=2), randomness="same")(T, q0)
    torch.testing.assert_close(_fk(arm, out, "tool_tcp"), T, atol=1e-4, rtol=0)


# ----------------------------------------------------------------------------------------------
# Compilation
# ----------------------------------------------------------------------------------------------


@pytest.mark.compile
@pytest.mark.slow
@pytest.mark.parametrize(
    "offset, options",
    [(0.01, {"restart_after": 0, "max_iterations": 2}),
     # the restarts: the best point per target, the round-robin of new starts
     (0.3, {"restarts": 2, "restart_after": 1, "max_iterations": 4})],
    ids=["no-restart", "restarts"],
)  # fmt: skip
def test_compiles_with_fullgraph(offset, options):
    chain = Chain.from_urdf(sample_robot("arm7"))
    gen = torch.Generator().manual_seed(11)
    q = chain.random_configuration(8, generator=gen)
    T = _fk(chain, q, "tool_tcp")
    q0 = (q + offset).clamp(chain.lower, chain.upper)

    def solve(T: torch.Tensor, q0: torch.Tensor) -> torch.Tensor:
        r = chain.inverse_kinematics(T, "tool_tcp", q0=q0, **options)
        return r.q, r.converged, r.iterations

    torch.manual_seed(0)  # the same random starts in both
    q_c, conv_c, it_c = torch.compile(solve, fullgraph=True, backend="aot_eager")(T, q0)
    torch.manual_seed(0)
    q_e, conv_e, it_e = solve(T, q0)
    torch.testing.assert_close(q_c, q_e, atol=1e-4, rtol=0)
    assert torch.equal(conv_c, conv_e) and torch.equal(it_c, it_e)
    assert bool(conv_e.all()) if offset < 0.1 else bool(conv_e.any())


# ----------------------------------------------------------------------------------------------
# Bad input
# ----------------------------------------------------------------------------------------------


def test_bad_input_names_the_argument():
    arm = ARM
    fn = r"Chain\.inverse_kinematics"
    T = torch.eye(4, dtype=F64)
    shapes = r"\(\.\.\., 4, 4\) or positions of shape \(\.\.\., 3\), got shape \(2, 4\)"
    with pytest.raises(ValueError, match=rf"{fn}: expected targets to be poses of shape {shapes}"):
        arm.inverse_kinematics(torch.zeros(2, 4, dtype=F64), "tool_tcp")
    with pytest.raises(ValueError, match=rf"{fn}: expected targets\['tool_tcp'\] to be poses"):
        arm.inverse_kinematics({"tool_tcp": torch.zeros(3, 3, 4, dtype=F64)})
    with pytest.raises(ValueError, match=rf"{fn}: unknown link 'hand'"):
        arm.inverse_kinematics(T, "hand")
    with pytest.raises(TypeError, match=rf"{fn}: expected early_exit to be True or False"):
        arm.inverse_kinematics(T, "tool_tcp", early_exit="no")
    with pytest.raises(TypeError, match=rf"{fn}: expected link to be a link name"):
        arm.inverse_kinematics(T)
    with pytest.raises(TypeError, match=rf"{fn}: targets is a dict .* link must be None"):
        arm.inverse_kinematics({"tool_tcp": T}, "tool_tcp")
    with pytest.raises(ValueError, match=rf"{fn}: expected restarts >= 1, got restarts=0"):
        arm.inverse_kinematics(T, "tool_tcp", restarts=0)
    with pytest.raises(TypeError, match=rf"{fn}: expected restarts to be an integer"):
        arm.inverse_kinematics(T, "tool_tcp", restarts=2.5)
    lower = arm.lower.clone()
    lower[2] = 4.0
    with pytest.raises(ValueError, match=rf"{fn}: expected lower <= upper for every DoF, got "
                       r"lower=4.0 > upper=3.05 for 'upper_arm_roll'"):  # fmt: skip
        arm.inverse_kinematics(T, "tool_tcp", lower=lower)
    with pytest.raises(ValueError, match=rf"{fn}: expected lower .* shape \(\) or \(7,\)"):
        arm.inverse_kinematics(T, "tool_tcp", lower=torch.zeros(3, dtype=F64))
    nan = r"every DoF \(not NaN\), got lower=nan for 'base_yaw' \(DoF 0\)"
    with pytest.raises(
        ValueError, match=rf"{fn}: expected lower to be a bound or -inf/inf for {nan}"
    ):
        arm.inverse_kinematics(T, "tool_tcp", lower=math.nan)
    with pytest.raises(ValueError, match=rf"{fn}: .* got upper=nan for 'upper_arm_roll'"):
        upper = arm.upper.clone()
        upper[2] = math.nan
        arm.inverse_kinematics(T, "tool_tcp", upper=upper)
    with pytest.raises(TypeError, match=rf"{fn}: expected lower to be a number or a torch.Tensor "
                       r"of shape \(\) or \(7,\), got bool True"):  # fmt: skip
        arm.inverse_kinematics(T, "tool_tcp", lower=True)
    with pytest.raises(TypeError, match=rf"{fn}: expected generator to be a torch.Generator or "
                       r"None, got int 3"):  # fmt: skip
        arm.inverse_kinematics(T, "tool_tcp", generator=3)
    with pytest.raises(TypeError, match=rf"{fn}: targets has dtype torch.float32"):
        arm.inverse_kinematics(T.float(), "tool_tcp")
    with pytest.raises(ValueError, match=rf"{fn}: expected q0 of shape \(\.\.\., 7\)"):
        arm.inverse_kinematics(T, "tool_tcp", q0=torch.zeros(6, dtype=F64))
    with pytest.raises(ValueError, match=rf"{fn}: .*broadcast"):
        arm.inverse_kinematics(T.expand(3, 4, 4), "tool_tcp", q0=torch.zeros(2, 7, dtype=F64))
    with pytest.raises(
        ValueError, match=rf"{fn}: expected position_weight to be a positive finite"
    ):
        arm.inverse_kinematics(T, "tool_tcp", position_weight=0.0)
    with pytest.raises(ValueError, match=rf"{fn}: expected rotation_weight to be a non-negative"):
        arm.inverse_kinematics(T, "tool_tcp", rotation_weight=-1.0)
    with pytest.raises(ValueError, match=rf"{fn}: expected max_iterations >= 0"):
        arm.inverse_kinematics(T, "tool_tcp", max_iterations=-1)
    with pytest.raises(ValueError, match=rf"{fn}: targets is an empty dict"):
        arm.inverse_kinematics({})


def test_so3_wrap_keeps_the_rotation():
    q = torch.tensor([[0.1], [4.0], [0.0], [0.0]], dtype=F64).repeat(1, 3)  # (4, N) rows
    q[1:4, 1] = torch.tensor([4.0, 0.0, 0.0], dtype=F64)
    w = ik_module._wrap_rotvecs(q, [1])
    torch.testing.assert_close(so3.exp(w[1:4].mT), so3.exp(q[1:4].mT), atol=1e-12, rtol=0)
    assert float(w[1:4].norm(dim=0).max()) <= math.pi + 1e-12
    assert torch.equal(w[0], q[0])


# ----------------------------------------------------------------------------------------------
# The example
# ----------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_inverse_kinematics_example_quick_run(tmp_path, capsys):
    path = Path(__file__).resolve().parents[1] / "examples" / "inverse_kinematics.py"
    spec = importlib.util.spec_from_file_location("example_inverse_kinematics", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    fig = module.main(["--quick", "--out", str(tmp_path)])
    assert fig["targets"] == 200 and fig["restarts"] == 8
    assert fig["success_rate"] >= 0.99 and fig["within_limits"]
    assert fig["reported_success_rate"] == fig["success_rate"]
    assert fig["max_position_error_m"] <= 1e-4 and fig["max_rotation_error_rad"] <= 1e-3
    ks = [c[0] for c in fig["curve"]]
    assert ks[0] == 0 and ks[-1] == 40
    rates = [c[1] for c in fig["curve"]]
    assert rates[0] < 0.05 and rates[-1] == fig["reported_success_rate"]
    assert fig["loss_last"] < 1e-6 * fig["loss_first"]
    out = capsys.readouterr().out
    assert "success (solved within 0.1 mm and 1 mrad" in out
    if importlib.util.find_spec("matplotlib") is not None:
        assert fig["plot"] == str(tmp_path / "convergence.png")
        assert (tmp_path / "convergence.png").stat().st_size > 1000
    else:
        assert fig["plot"] is None and "matplotlib is not installed" in out


# ----------------------------------------------------------------------------------------------
# The interface the solver uses of a chain
# ----------------------------------------------------------------------------------------------


def test_solver_uses_only_the_stated_interface():
    """ik.py reads no private member of a chain, only the attributes and methods SolverChain
    states, and chain.py does not import the solver at module level (no import circle)."""
    import ast

    tree = ast.parse(Path(ik_module.__file__).read_text())
    private = [
        f"{node.value.id}.{node.attr} (line {node.lineno})"
        for node in ast.walk(tree)
        if isinstance(node, ast.Attribute)
        and isinstance(node.value, ast.Name)
        and node.value.id == "chain"
        and node.attr.startswith("_")
    ]
    assert private == []
    used = {
        node.attr
        for node in ast.walk(tree)
        if isinstance(node, ast.Attribute)
        and isinstance(node.value, ast.Name)
        and node.value.id == "chain"
    }
    stated = set(ik_module.SolverChain.__annotations__) | {
        "poses_and_jacobians", "moving_dofs", "sampling_bounds"
    }  # fmt: skip
    assert used <= stated, used - stated
    # chain.py imports the solver only inside Chain.inverse_kinematics (and for type checking).
    chain_src = ast.parse((Path(ik_module.__file__).parent / "chain.py").read_text())
    top = [node.module for node in chain_src.body if isinstance(node, ast.ImportFrom)]
    assert "ik" not in top and "torchlie.kinematics.ik" not in top


def test_interface_methods():
    tree = TREE
    q = tree.random_configuration(3, generator=torch.Generator().manual_seed(2))
    links = ["left_tcp", "puck_tool"]
    dofs = tree.moving_dofs(links)
    assert dofs == tuple(sorted(dofs)) and dofs == tree.moving_dofs(links[::-1])
    J_all = tree.jacobian(q, links)
    off = [i for i in range(tree.n_dof) if i not in set(dofs)]
    for name, P, J in zip(links, *tree.poses_and_jacobians(q.mT, links, dofs), strict=True):
        torch.testing.assert_close(P.permute(2, 1, 0), _fk(tree, q, name), atol=0, rtol=0)
        torch.testing.assert_close(J.permute(2, 1, 0), J_all[name][..., list(dofs)], atol=0,
                                   rtol=0)  # fmt: skip
        assert bool((J_all[name][..., off] == 0).all())
    with pytest.raises(ValueError, match=r"Chain\.poses_and_jacobians: expected q_t of shape"):
        tree.poses_and_jacobians(q, links)
    with pytest.raises(ValueError, match=r"Chain\.moving_dofs: unknown link 'nope'"):
        tree.moving_dofs(["nope"])
    with pytest.raises(TypeError, match=r"Chain\.sampling_bounds: expected lower to be None or a "
                       r"float64 CPU tensor of shape \(21,\)"):  # fmt: skip
        tree.sampling_bounds(torch.zeros(tree.n_dof), None)
    # Sampling bounds: finite bounds as given; free ranges on the side of a finite bound.
    n = tree.n_dof
    lower = torch.full((n,), 0.5, dtype=F64)
    upper = torch.full((n,), math.inf, dtype=F64)
    lo, hi = tree.sampling_bounds(lower, upper)
    assert lo.dtype == F64 and lo.device.type == "cpu"
    assert torch.equal(lo, lower) and bool((hi >= lo).all()) and bool(torch.isfinite(hi).all())
    lo, hi = tree.sampling_bounds()
    finite = torch.isfinite(tree.lower)
    assert torch.equal(lo[finite], tree.lower[finite])
    assert torch.equal(hi[finite], tree.upper[finite])
    assert bool(torch.isfinite(lo).all()) and bool((lo < hi).all())
