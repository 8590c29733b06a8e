"""Chain: forward kinematics and Jacobians against hand-computed poses, autodiff and a reference."""

from __future__ import annotations

import math

import pytest
import torch
from agreement import assert_agree
from samplers import eps
from scipy.spatial.transform import Rotation

from torchlie import se3, so3
from torchlie.kinematics import Chain, sample_robot
from torchlie.kinematics.reference import (
    reference_dof_names,
    reference_forward_kinematics,
    reference_jacobians,
)

F64 = torch.float64


def robot(body: str, links: tuple[str, ...]) -> str:
    return '<robot name="r">' + "".join(f'<link name="{n}"/>' for n in links) + body + "</robot>"


def joint(name, jtype, parent, child, origin="", axis="", extra="") -> str:
    limit = '<limit lower="-3.2" upper="3.2"/>' if jtype in ("revolute", "prismatic") else ""
    return (
        f'<joint name="{name}" type="{jtype}"><parent link="{parent}"/><child link="{child}"/>'
        f"{origin}{axis}{limit}{extra}</joint>"
    )


def rz(a: float) -> torch.Tensor:
    c, s = math.cos(a), math.sin(a)
    return torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], dtype=F64)


def pose(R: torch.Tensor, p) -> torch.Tensor:
    T = torch.eye(4, dtype=F64)
    T[:3, :3] = R
    T[:3, 3] = torch.as_tensor(p, dtype=F64)
    return T


# A planar 2R arm on a column, a prismatic slider and a fixed tool frame turned by 90 degrees.
RRP = robot(
    joint("j1", "revolute", "base", "l1", '<origin xyz="0 0 0.5"/>', '<axis xyz="0 0 1"/>')
    + joint("j2", "revolute", "l1", "l2", '<origin xyz="1 0 0"/>', '<axis xyz="0 0 1"/>')
    + joint("j3", "prismatic", "l2", "slider", '<origin xyz="0.5 0 0"/>', '<axis xyz="1 0 0"/>')
    + joint("tool", "fixed", "slider", "tip",
            '<origin xyz="0 0 0.1" rpy="0 0 1.5707963267948966"/>'),
    ("base", "l1", "l2", "slider", "tip"),
)  # fmt: skip


def rrp_by_hand(q1: float, q2: float, d: float) -> dict[str, torch.Tensor]:
    c1, s1 = math.cos(q1), math.sin(q1)
    c12, s12 = math.cos(q1 + q2), math.sin(q1 + q2)
    p2 = (c1, s1, 0.5)
    ps = (c1 + (0.5 + d) * c12, s1 + (0.5 + d) * s12, 0.5)
    return {
        "base": torch.eye(4, dtype=F64),
        "l1": pose(rz(q1), (0.0, 0.0, 0.5)),
        "l2": pose(rz(q1 + q2), p2),
        "slider": pose(rz(q1 + q2), ps),
        "tip": pose(rz(q1 + q2 + math.pi / 2), (ps[0], ps[1], 0.6)),
    }


CONFIGS = [(0.0, 0.0, 0.0), (math.pi / 2, -math.pi / 2, 0.1), (0.3, 1.2, 0.25), (-3.0, 3.1, -0.4)]


@pytest.fixture(scope="module")
def arm() -> Chain:
    return Chain.from_urdf(sample_robot("arm7"), dtype=F64)


@pytest.fixture(scope="module")
def tree() -> Chain:
    return Chain.from_urdf(sample_robot("tree"), dtype=F64)


# ----------------------------------------------------------------------------------------------
# Hand-computed poses
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("config", CONFIGS)
def test_hand_computed_poses(config, dtype):
    chain = Chain.from_urdf(RRP, dtype=dtype)
    T = chain.forward_kinematics(torch.tensor(config, dtype=dtype))
    expected = rrp_by_hand(*(float(torch.tensor(c, dtype=dtype)) for c in config))
    assert list(T) == ["base", "l1", "l2", "slider", "tip"]
    for name, E in expected.items():
        assert T[name].dtype == dtype
        torch.testing.assert_close(T[name].to(F64), E, atol=8 * eps(dtype), rtol=0)


def test_hand_computed_jacobian():
    chain = Chain.from_urdf(RRP, dtype=F64)
    q1, q2, d = 0.3, 1.2, 0.25
    J = chain.jacobian(torch.tensor([q1, q2, d], dtype=F64), "tip")
    p = rrp_by_hand(q1, q2, d)["tip"][:3, 3]
    c1, s1 = math.cos(q1), math.sin(q1)
    c12, s12 = math.cos(q1 + q2), math.sin(q1 + q2)
    expected = torch.tensor(
        [
            # j1 about z through (0, 0, 0.5); j2 about z through (c1, s1, 0.5); j3 along x of l2
            [-p[1], -(p[1] - s1), c12],
            [p[0], p[0] - c1, s12],
            [0.0, 0.0, 0.0],
            [0.0, 0.0, 0.0],
            [0.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
        ],
        dtype=F64,
    )
    torch.testing.assert_close(J, expected, atol=4 * eps(F64), rtol=0)


def test_rpy_is_fixed_axis_roll_pitch_yaw():
    rpy = (0.3, -1.1, 2.4)
    origin = f'<origin rpy="{rpy[0]} {rpy[1]} {rpy[2]}"/>'
    chain = Chain.from_urdf(robot(joint("f", "fixed", "a", "b", origin), ("a", "b")), dtype=F64)
    R = chain.forward_kinematics(torch.zeros(0, dtype=F64))["b"][:3, :3]
    expected = torch.from_numpy(Rotation.from_euler("xyz", rpy).as_matrix())  # extrinsic x, y, z
    torch.testing.assert_close(R, expected, atol=4 * eps(F64), rtol=0)


def test_omitted_axis_is_x_and_axes_are_normalised():
    text = robot(
        joint("rx", "revolute", "a", "b")
        + joint("rz2", "revolute", "b", "c", axis='<axis xyz="0 0 2"/>')
        + joint("p34", "prismatic", "c", "d", axis='<axis xyz="0 3 4"/>'),
        ("a", "b", "c", "d"),
    )
    chain = Chain.from_urdf(text, dtype=F64)
    q = torch.tensor([0.7, -0.4, 0.5], dtype=F64)
    T = chain.forward_kinematics(q)
    c, s = math.cos(0.7), math.sin(0.7)
    Rx = torch.tensor([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]], dtype=F64)
    torch.testing.assert_close(T["b"][:3, :3], Rx, atol=4 * eps(F64), rtol=0)
    torch.testing.assert_close(T["c"][:3, :3], Rx @ rz(-0.4), atol=4 * eps(F64), rtol=0)
    offset = Rx @ rz(-0.4) @ torch.tensor([0.0, 0.6, 0.8], dtype=F64) * 0.5  # unit axis * q
    torch.testing.assert_close(T["d"][:3, 3], offset, atol=4 * eps(F64), rtol=0)


def test_planar_joint_coordinates():
    text = robot(
        joint("pz", "planar", "a", "b", axis='<axis xyz="0 0 1"/>')
        + joint("py", "planar", "a", "c", axis='<axis xyz="0 1 0"/>'),
        ("a", "b", "c"),
    )
    chain = Chain.from_urdf(text, dtype=F64)
    assert chain.joint_names == ("pz:x", "pz:y", "pz:theta", "py:x", "py:y", "py:theta")
    q = torch.tensor([0.3, -0.2, 0.9, 0.3, -0.2, 0.9], dtype=F64)
    T = chain.forward_kinematics(q)
    # axis z: the plane is xy, e1 = x, e2 = y; rotation about z.
    torch.testing.assert_close(T["b"], pose(rz(0.9), (0.3, -0.2, 0.0)), atol=4e-16, rtol=0)
    # axis y: e1 = x (least aligned with y), e2 = y x x = -z; rotation about y.
    Ry = torch.from_numpy(Rotation.from_rotvec([0.0, 0.9, 0.0]).as_matrix())
    torch.testing.assert_close(T["c"], pose(Ry, (0.3, 0.0, 0.2)), atol=4e-16, rtol=0)


def test_floating_joint_is_translation_then_rotation_vector():
    text = robot(
        joint("free", "floating", "a", "b", '<origin xyz="1 2 3" rpy="0 0 0.5"/>'), ("a", "b")
    )
    chain = Chain.from_urdf(text, dtype=F64)
    assert chain.n_dof == 6 and chain.joint_names[3:] == ("free:rx", "free:ry", "free:rz")
    t, r = [0.1, -0.2, 0.3], [0.4, -1.0, 2.5]
    T = chain.forward_kinematics(torch.tensor(t + r, dtype=F64))["b"]
    M = pose(torch.from_numpy(Rotation.from_rotvec(r).as_matrix()), t)
    torch.testing.assert_close(T, pose(rz(0.5), (1.0, 2.0, 3.0)) @ M, atol=8 * eps(F64), rtol=0)
    # Rotation vector exactly zero: finite value and gradient.
    q = torch.zeros(6, dtype=F64, requires_grad=True)
    T0 = chain.forward_kinematics(q)["b"]
    (g,) = torch.autograd.grad(T0.sum(), q)
    assert torch.isfinite(g).all()


def test_mimic_value_is_multiplier_times_parent_plus_offset():
    text = robot(
        joint("j", "revolute", "a", "b", axis='<axis xyz="0 0 1"/>')
        + joint("m1", "revolute", "a", "c", axis='<axis xyz="0 0 1"/>',
                extra='<mimic joint="j" multiplier="-0.5" offset="0.1"/>')
        + joint("m2", "prismatic", "a", "d", axis='<axis xyz="1 0 0"/>',
                extra='<mimic joint="m1" multiplier="2" offset="0.3"/>'),
        ("a", "b", "c", "d"),
    )  # fmt: skip
    chain = Chain.from_urdf(text, dtype=F64)
    assert chain.joint_names == ("j",)
    q = 0.8
    T = chain.forward_kinematics(torch.tensor([q], dtype=F64))
    m1 = -0.5 * q + 0.1
    torch.testing.assert_close(T["c"], pose(rz(m1), (0, 0, 0)), atol=4e-16, rtol=0)
    torch.testing.assert_close(T["d"][:3, 3], torch.tensor([2 * m1 + 0.3, 0, 0], dtype=F64))
    J = chain.jacobian(torch.tensor([q], dtype=F64), "d")
    torch.testing.assert_close(J[:, 0], torch.tensor([-1.0, 0, 0, 0, 0, 0], dtype=F64))


# ----------------------------------------------------------------------------------------------
# Every sample robot against the float64 reference
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["arm7", "tree", "panda"])
def test_against_float64_reference(name, dtype, gen):
    chain = Chain.from_urdf(sample_robot(name), dtype=dtype)
    assert list(chain.joint_names) == reference_dof_names(chain.spec)
    q = chain.random_configuration(64, generator=gen)
    T = chain.forward_kinematics(q)
    T_ref = reference_forward_kinematics(chain.spec, q.to(F64))
    tol = 32 * eps(dtype) * 5.0  # 5 m bounds 1 + reach of these robots
    for link in chain.link_names:
        torch.testing.assert_close(T[link].to(F64), T_ref[link], atol=tol, rtol=0)
    J_ref = reference_jacobians(chain.spec, q.to(F64), list(chain.leaf_links))
    for link in chain.leaf_links:
        torch.testing.assert_close(chain.jacobian(q, link).to(F64), J_ref[link], atol=tol, rtol=0)


def test_jacobian_matches_jacrev_of_forward_kinematics(tree, gen):
    q = tree.random_configuration(3, generator=gen)
    for link in tree.link_names:
        for b in range(3):

            def fk(x: torch.Tensor, link=link) -> torch.Tensor:
                return tree.forward_kinematics(x, link, stacked=True)[0]

            T = fk(q[b])
            dT = torch.func.jacrev(fk)(q[b])  # (4, 4, n_dof)
            W = torch.einsum("ijn,kj->ikn", dT[:3, :3], T[:3, :3])  # dR R^T
            ang = 0.5 * torch.stack((W[2, 1] - W[1, 2], W[0, 2] - W[2, 0], W[1, 0] - W[0, 1]))
            expected = torch.cat((dT[:3, 3], ang))
            torch.testing.assert_close(tree.jacobian(q[b], link), expected, atol=1e-14, rtol=0)


def test_jacobian_columns_of_other_branches_are_zero(tree):
    q = tree.random_configuration(2)
    J = tree.jacobian(q, "right_index")
    moving = {"rail", "torso_yaw", "right_shoulder", "right_elbow", "right_thumb"}
    for i, name in enumerate(tree.joint_names):
        if name in moving:
            assert J[..., i].abs().amax() > 0
        else:
            assert torch.equal(J[..., i], torch.zeros_like(J[..., i]))
    assert torch.equal(tree.jacobian(q, "world"), torch.zeros(2, 6, tree.n_dof, dtype=F64))


# ----------------------------------------------------------------------------------------------
# Jacobian kinds: frames and points, against jacrev of FK in tangent coordinates
# ----------------------------------------------------------------------------------------------

KINDS_LINKS = ["left_tcp", "right_index", "puck_tool", "drone_camera", "camera_optical"]


def _tangent_jacobian(chain: Chain, q: torch.Tensor, link: str, frame: str, point=None):
    """Jacobian ``(6, n)`` of the tangent coordinates of FK at ``q``: ``Log(T0^-1 T(x))`` (link),
    ``Log(T(x) T0^-1)`` (spatial), or the world point and ``vee(dR R0^T)`` (world)."""
    T0 = chain.forward_kinematics(q, link)[link]

    def tangent(x: torch.Tensor) -> torch.Tensor:
        T = chain.forward_kinematics(x, link)[link]
        if frame == "link":
            xi = se3.log(se3.compose(se3.inverse(T0), T))
            if point is None:
                return xi
            # The point's velocity in link coordinates: R0^T d(T point).
            moved = se3.act(se3.inverse(T0), se3.act(T, point))
            return torch.cat((moved, xi[3:]))
        if frame == "spatial":
            return se3.log(se3.compose(T, se3.inverse(T0)))
        p = se3.act(T, torch.zeros(3, dtype=F64) if point is None else point)
        return torch.cat((p, so3.log(T[:3, :3] @ T0[:3, :3].mT)))

    return torch.func.jacrev(tangent)(q)


@pytest.mark.parametrize(
    "frame, with_point",
    [("world", False), ("world", True), ("link", False), ("link", True), ("spatial", False)],
)
def test_jacobian_kinds_match_jacrev_in_tangent_coordinates(tree, gen, frame, with_point):
    q = tree.random_configuration(2, generator=gen)
    point = torch.tensor([0.05, -0.12, 0.3], dtype=F64) if with_point else None
    Js = tree.jacobian(q, KINDS_LINKS, frame=frame, point=point)
    assert list(Js) == KINDS_LINKS
    for link in KINDS_LINKS:
        assert Js[link].shape == (2, 6, tree.n_dof)
        for b in range(2):
            expected = _tangent_jacobian(tree, q[b], link, frame, point)
            torch.testing.assert_close(Js[link][b], expected, atol=1e-12, rtol=0)
            one = tree.jacobian(q[b], link, frame=frame, point=point)
            torch.testing.assert_close(one, Js[link][b], atol=1e-15, rtol=0)


def test_jacobian_default_is_the_world_frame_at_the_origin(tree, gen):
    q = tree.random_configuration(3, generator=gen)
    for link in KINDS_LINKS:
        J = tree.jacobian(q, link)
        assert torch.equal(tree.jacobian(q, link, frame="world"), J)
        zero = torch.zeros(3, dtype=F64)
        torch.testing.assert_close(tree.jacobian(q, link, point=zero), J, atol=1e-15, rtol=0)


def test_jacobian_points_broadcast_and_per_link(tree, gen):
    q = tree.random_configuration(3, generator=gen)
    pts = torch.tensor([[0.1, 0.0, 0.0], [0.0, 0.2, 0.0]], dtype=F64).view(2, 1, 3)
    J = tree.jacobian(q, "left_tcp", frame="link", point=pts)
    assert J.shape == (2, 3, 6, tree.n_dof)
    for i in range(2):
        for b in range(3):
            expected = tree.jacobian(q[b], "left_tcp", frame="link", point=pts[i, 0])
            torch.testing.assert_close(J[i, b], expected, atol=1e-15, rtol=0)
    Js = tree.jacobian(q, ["left_tcp", "drone_camera"], point={"left_tcp": pts[0, 0]})
    torch.testing.assert_close(
        Js["left_tcp"], tree.jacobian(q, "left_tcp", point=pts[0, 0]), atol=0, rtol=0
    )
    torch.testing.assert_close(Js["drone_camera"], tree.jacobian(q, "drone_camera"), atol=0, rtol=0)
    assert tree.jacobian(q, []) == {}


def test_jacobian_kind_errors(tree):
    q = tree.random_configuration(2)
    jac = r"torchlie\.kinematics\.Chain\.jacobian"
    with pytest.raises(ValueError, match=rf"{jac}: expected frame to be 'world', 'link' or "
                       r"'spatial', got 'body'"):  # fmt: skip
        tree.jacobian(q, "left_tcp", frame="body")
    with pytest.raises(ValueError, match=rf"{jac}: point is not used with frame='spatial'"):
        tree.jacobian(q, "left_tcp", frame="spatial", point=torch.zeros(3, dtype=F64))
    with pytest.raises(ValueError, match=rf"{jac}: expected point of shape \(\.\.\., 3\)"):
        tree.jacobian(q, "left_tcp", point=torch.zeros(4, dtype=F64))
    with pytest.raises(ValueError, match=rf"{jac}: point has an entry for 'drone'"):
        tree.jacobian(q, ["left_tcp"], point={"drone": torch.zeros(3, dtype=F64)})
    with pytest.raises(TypeError, match=rf"{jac}: point has dtype torch.float32 but the chain's"):
        tree.jacobian(q, "left_tcp", point=torch.zeros(3))


# ----------------------------------------------------------------------------------------------
# Gradients
# ----------------------------------------------------------------------------------------------


def test_gradcheck_and_gradgradcheck_arm(arm, gen):
    q = arm.random_configuration(2, generator=gen).requires_grad_()

    def f(x):
        return arm.forward_kinematics(x, ["link4", "tool_tcp"], stacked=True)

    assert torch.autograd.gradcheck(f, (q,))
    assert torch.autograd.gradgradcheck(f, (q,))
    assert torch.autograd.gradcheck(lambda x: arm.jacobian(x, "tool_tcp"), (q,))


def test_gradgradcheck_every_joint_type(tree, gen):
    q = tree.random_configuration(1, generator=gen).requires_grad_()
    links = ["right_index", "left_finger_b", "puck_tool", "drone_camera", "camera_optical"]

    def f(x):
        return tree.forward_kinematics(x, links, stacked=True)

    assert torch.autograd.gradcheck(f, (q,), fast_mode=True)
    assert torch.autograd.gradgradcheck(f, (q,), fast_mode=True)


def test_second_derivative_matches_finite_differences_of_jacobian(arm):
    # d/dq of (dp/dq) from double backward equals the finite difference of the closed-form
    # Jacobian's linear rows.
    q = torch.tensor([0.3, -0.5, 1.0, 1.2, -0.7, 0.4, 0.2], dtype=F64, requires_grad=True)
    p = arm.forward_kinematics(q, "tool_tcp")["tool_tcp"][:3, 3]
    (g,) = torch.autograd.grad(p[0], q, create_graph=True)
    (h,) = torch.autograd.grad(g[3], q)
    e = torch.zeros(7, dtype=F64)
    e[5] = 1e-6
    fd = (
        arm.jacobian(q.detach() + e, "tool_tcp") - arm.jacobian(q.detach() - e, "tool_tcp")
    ) / 2e-6
    assert abs(h[5].item() - fd[0, 3].item()) < 1e-8


# ----------------------------------------------------------------------------------------------
# Shapes, dtypes, devices, outputs
# ----------------------------------------------------------------------------------------------


def test_batch_shapes(batch, dtype, gen):
    chain = Chain.from_urdf(sample_robot("tree"), dtype=dtype)
    q = chain.random_configuration(*batch, generator=gen)
    T = chain.forward_kinematics(q)
    S = chain.forward_kinematics(q, stacked=True)
    J = chain.jacobian(q, "drone_camera")
    assert S.shape == (*batch, len(chain.link_names), 4, 4) and S.is_contiguous()
    assert J.shape == (*batch, 6, chain.n_dof) and J.dtype == dtype
    flat = chain.forward_kinematics(q.reshape(-1, chain.n_dof), stacked=True)
    tol = 8 * eps(dtype)
    torch.testing.assert_close(S.reshape(flat.shape), flat, atol=tol, rtol=0)
    for i, link in enumerate(chain.link_names):
        assert T[link].shape == (*batch, 4, 4) and T[link].is_contiguous()
        assert torch.equal(T[link], S[..., i, :, :])


def test_small_and_large_batches_agree(arm):
    # Results are transposed back differently above 2048 configurations.
    q = arm.random_configuration(3000)
    big = arm.forward_kinematics(q, stacked=True)
    small = arm.forward_kinematics(q[:100], stacked=True)
    torch.testing.assert_close(big[:100], small, atol=4 * eps(F64), rtol=0)
    d_big, d_small = arm.forward_kinematics(q), arm.forward_kinematics(q[:100])
    for link in arm.link_names:
        assert torch.equal(d_big[link], big[:, arm.link_names.index(link)])
        assert d_big[link].is_contiguous()
        torch.testing.assert_close(d_big[link][:100], d_small[link], atol=4 * eps(F64), rtol=0)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_large_batches_equal_small_ones_and_are_contiguous(dtype):
    """Above 2048 configurations the poses go back to (..., 4, 4) by per-link copies: the
    small-batch path's poses (to the rounding that the matrix products' kernels decide by batch
    size), every output contiguous."""
    arm = Chain.from_urdf(sample_robot("arm7"), dtype=dtype)
    q = arm.random_configuration(3000, generator=torch.Generator().manual_seed(3))
    S, d = arm.forward_kinematics(q, stacked=True), arm.forward_kinematics(q)
    assert S.is_contiguous()
    for i, link in enumerate(arm.link_names):
        assert torch.equal(S[:, i], d[link]) and d[link].is_contiguous()
        small = torch.cat([arm.forward_kinematics(part)[link] for part in q.split(999)])
        assert_agree(d[link], small, f"{link}: 3000 poses and the same in parts of 999")


def test_link_subsets(tree):
    q = tree.random_configuration(4)
    full = tree.forward_kinematics(q)
    sub = tree.forward_kinematics(q, ["right_tcp", "carriage", "drone"])
    assert list(sub) == ["right_tcp", "carriage", "drone"]
    for k, v in sub.items():
        assert torch.equal(v, full[k])
    S = tree.forward_kinematics(q, ["drone", "world"], stacked=True)
    assert S.shape == (4, 2, 4, 4)
    assert torch.equal(S[:, 0], full["drone"])
    assert torch.equal(S[:, 1], torch.eye(4, dtype=F64).expand(4, 4, 4))
    assert list(tree.forward_kinematics(q, "head")) == ["head"]
    with pytest.raises(ValueError, match=r"Chain\.forward_kinematics: unknown link 'hand'"):
        tree.forward_kinematics(q, ["head", "hand"])
    with pytest.raises(ValueError, match=r"Chain\.jacobian: unknown link 'hand'"):
        tree.jacobian(q, "hand")


def test_names_limits_and_sampling(tree, gen):
    assert tree.link_names[0] == "world" and tree.root == "world"
    assert tree.joint_names[:4] == ("rail", "torso_yaw", "neck_pan", "head_roll")
    assert "left_finger_b" not in tree.joint_names  # mimic joints have no DoF
    assert tree.n_dof == 21 and len(tree.lower) == 21
    i = tree.joint_names.index("torso_yaw")
    assert tree.lower[i] == -math.inf and tree.upper[i] == math.inf
    q = tree.random_configuration(500, 2, generator=gen)
    assert q.shape == (500, 2, 21) and q.dtype == F64
    assert bool(((q >= tree.lower) & (q <= tree.upper)).all())
    assert q[..., i].abs().max() <= math.pi
    rot = [tree.joint_names.index(f"drone_free:r{c}") for c in "xyz"]
    assert torch.linalg.vector_norm(q[..., rot], dim=-1).max() <= math.pi + 1e-12
    assert "left_tcp" in tree.leaf_links and "torso" not in tree.leaf_links


def test_to_rebuilds_constants_from_float64():
    c32 = Chain.from_urdf(sample_robot("tree"))
    assert c32.dtype == torch.float32 and c32.to() is c32
    c64 = c32.to(dtype=F64)
    ref = Chain.from_urdf(sample_robot("tree"), dtype=F64)
    q = ref.random_configuration(5)
    assert torch.equal(
        c64.forward_kinematics(q, stacked=True), ref.forward_kinematics(q, stacked=True)
    )
    assert c64.to(torch.float32).forward_kinematics(q.float(), stacked=True).dtype == torch.float32
    with pytest.raises(TypeError, match="dtype must be float32 or float64"):
        c32.to(dtype=torch.float16)


def test_device(device):
    chain = Chain.from_urdf(sample_robot("tree"), dtype=F64)
    q = chain.random_configuration(6)
    on = chain.to(device=device)
    assert on.lower.device.type == torch.device(device).type
    out = on.forward_kinematics(q.to(device), stacked=True)
    assert out.device.type == torch.device(device).type
    torch.testing.assert_close(
        out.cpu(), chain.forward_kinematics(q, stacked=True), atol=1e-12, rtol=0
    )
    J = on.jacobian(q.to(device), "drone_camera").cpu()
    torch.testing.assert_close(J, chain.jacobian(q, "drone_camera"), atol=1e-12, rtol=0)


def test_half_precision_is_computed_in_float32():
    chain = Chain.from_urdf(sample_robot("arm7"))
    q = chain.random_configuration(8).half()
    T = chain.forward_kinematics(q, stacked=True)
    assert T.dtype == torch.float16
    expected = chain.forward_kinematics(q.float(), stacked=True).half()
    assert torch.equal(T, expected)
    assert chain.jacobian(q.bfloat16(), "tool_tcp").dtype == torch.bfloat16
    # the other arguments follow the same rule: the chain's dtype, or half on a float32 chain
    p = torch.tensor([0.1, -0.2, 0.3])
    J = chain.jacobian(q.float(), "tool_tcp", point=p.half())
    assert torch.equal(J, chain.jacobian(q.float(), "tool_tcp", point=p.half().float()))
    with pytest.raises(TypeError, match=r"point has dtype torch.float64 but the chain's"):
        chain.jacobian(q.float(), "tool_tcp", point=p.double())


def test_bad_input(arm):
    fn = "torchlie.kinematics.Chain.forward_kinematics"
    with pytest.raises(ValueError, match=rf"{fn}: expected q of shape \(\.\.\., 7\), got \(3, 6\)"):
        arm.forward_kinematics(torch.zeros(3, 6, dtype=F64))
    with pytest.raises(TypeError, match=f"{fn}: expected q to be a floating-point tensor"):
        arm.forward_kinematics(torch.zeros(3, 7, dtype=torch.int64))
    with pytest.raises(TypeError, match=f"{fn}: q has dtype torch.float32 but the chain's"):
        arm.forward_kinematics(torch.zeros(3, 7))
    with pytest.raises(TypeError, match="expected q to be a torch.Tensor"):
        arm.jacobian([0.0] * 7, "tool_tcp")


def test_nan_stays_in_its_batch_element(tree, gen):
    q = tree.random_configuration(4, generator=gen)
    bad = q.clone()
    bad[2, 5] = math.nan
    T, T_ok = tree.forward_kinematics(bad, stacked=True), tree.forward_kinematics(q, stacked=True)
    keep = [0, 1, 3]
    assert torch.equal(T[keep], T_ok[keep])
    assert torch.isnan(T[2, tree.link_names.index("left_tcp")]).any()
    J, J_ok = tree.jacobian(bad, "left_tcp"), tree.jacobian(q, "left_tcp")
    assert torch.equal(J[keep], J_ok[keep]) and torch.isnan(J[2]).any()


def test_vmap(tree):
    q = tree.random_configuration(3, 2)
    out = torch.func.vmap(lambda x: tree.forward_kinematics(x, stacked=True))(q)
    torch.testing.assert_close(out, tree.forward_kinematics(q, stacked=True), atol=1e-15, rtol=0)
    J = torch.func.vmap(lambda x: tree.jacobian(x, "drone_camera"))(q)
    torch.testing.assert_close(J, tree.jacobian(q, "drone_camera"), atol=1e-15, rtol=0)


# ----------------------------------------------------------------------------------------------
# pytorch-kinematics, directly
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["arm7", "panda"])
def test_fk_and_jacobian_match_pytorch_kinematics(name, gen):
    pk = pytest.importorskip("pytorch_kinematics", reason="pytorch_kinematics not installed")
    text = open(sample_robot(name)).read()
    pk_chain = pk.build_chain_from_urdf(text)
    chain = Chain.from_urdf(sample_robot(name))
    q = chain.random_configuration(100, generator=gen)
    # pk treats the Panda's mimic finger as an independent joint: feed it the mimicked value.
    pk_names = pk_chain.get_joint_parameter_names()
    mimic = {"panda_finger_joint2": "panda_finger_joint1"}
    th = torch.stack([q[:, chain.joint_names.index(mimic.get(n, n))] for n in pk_names], 1)
    ours = chain.forward_kinematics(q)
    theirs = pk_chain.forward_kinematics(th)
    for link in chain.link_names:
        torch.testing.assert_close(ours[link], theirs[link].get_matrix(), atol=5e-6, rtol=0)
    end = chain.leaf_links[0]
    serial = pk.SerialChain(pk_chain, end)
    idx = [pk_names.index(n) for n in serial.get_joint_parameter_names()]
    J_pk = serial.jacobian(th[:, idx])
    J = chain.jacobian(q, end)[:, :, [chain.joint_names.index(pk_names[i]) for i in idx]]
    torch.testing.assert_close(J, J_pk, atol=5e-6, rtol=0)
