"""Kinematics at the edges: empty batches, robots without DoF, bad arguments, extreme and
malformed URDF numbers, hostile names, and robots with thousands of links or joints."""

from __future__ import annotations

import io
import math
import re

import pytest
import torch

from torchlie.kinematics import Chain, URDFError, parse_urdf, sample_robot
from torchlie.kinematics import validate as V

F64 = torch.float64


def robot(body: str, links: tuple[str, ...] = ("a", "b")) -> str:
    return '<robot name="r">' + "".join(f'<link name="{n}"/>' for n in links) + body + "</robot>"


def joint(name="j", jtype="revolute", parent="a", child="b", inner="") -> str:
    limit = '<limit lower="-1" upper="1"/>' if jtype in ("revolute", "prismatic") else ""
    return (
        f'<joint name="{name}" type="{jtype}"><parent link="{parent}"/>'
        f'<child link="{child}"/>{inner}{limit}</joint>'
    )


FIXED_ONLY = robot(
    joint("m", "fixed", "a", "b", '<origin xyz="1 2 3"/>') + joint("t", "fixed", "b", "c"),
    ("a", "b", "c"),
)
SINGLE_LINK = robot("", ("a",))


def serial(n: int, *, mimic: bool = False, reverse: bool = False) -> str:
    """A chain l0 - j0 - l1 - ... - l{n}; with ``mimic`` every joint but one mimics its
    neighbour (j{k} mimics j{k-1}, or j{k+1} with ``reverse``), multiplier 1, offset 0.001."""
    links = "".join(f'<link name="l{i}"/>' for i in range(n + 1))
    joints = []
    for i in range(n):
        src = i + 1 if reverse else i - 1
        m = f'<mimic joint="j{src}" offset="0.001"/>' if mimic and 0 <= src < n else ""
        joints.append(
            f'<joint name="j{i}" type="revolute"><parent link="l{i}"/><child link="l{i + 1}"/>'
            f'<origin xyz="0.01 0.002 0" rpy="0 0.1 0.05"/><axis xyz="0 0.6 0.8"/>'
            f'<limit lower="-1" upper="1"/>{m}</joint>'
        )
    return f'<robot name="s">{links}{"".join(joints)}</robot>'


@pytest.fixture(scope="module")
def tree() -> Chain:
    return Chain.from_urdf(sample_robot("tree"), dtype=F64)


# ----------------------------------------------------------------------------------------------
# Empty batches
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("batch", [(0,), (3, 0), (0, 2)])
def test_empty_batch_gives_empty_poses_and_jacobians(tree, batch):
    # tree has every joint type, mimic joints included.
    q = torch.zeros(*batch, tree.n_dof, dtype=F64)
    poses = tree.forward_kinematics(q)
    assert list(poses) == list(tree.link_names)
    assert all(T.shape == (*batch, 4, 4) for T in poses.values())
    T = tree.forward_kinematics(q, stacked=True)
    assert T.shape == (*batch, len(tree.link_names), 4, 4)
    for link in ("drone_camera", "right_index", "left_finger_b", tree.root):
        assert tree.jacobian(q, link).shape == (*batch, 6, tree.n_dof)
    assert tree.random_configuration(*batch).shape == (*batch, tree.n_dof)


def test_empty_batch_keeps_gradients_flowing(tree):
    q = torch.zeros(0, tree.n_dof, dtype=F64, requires_grad=True)
    T = tree.forward_kinematics(q, "drone_camera")["drone_camera"]
    J = tree.jacobian(q, "right_index")
    (g,) = torch.autograd.grad(T.sum() + J.sum(), q)
    assert g.shape == (0, tree.n_dof)


def test_no_links_asked_for_gives_an_empty_result(tree):
    q = tree.random_configuration(2)
    assert tree.forward_kinematics(q, []) == {}
    assert tree.forward_kinematics(q, [], stacked=True).shape == (2, 0, 4, 4)


def test_batches_of_up_to_sixty_dimensions_and_no_more(tree):
    # The batch limit of every torchlie op (torchlie._checks.MAX_BATCH_DIMS), with the same
    # message; the chain flattens the batch, so the limit is the library's rule, not torch's.
    ok, more = (1,) * 60, (1,) * 61
    q = tree.random_configuration(*ok, generator=torch.Generator().manual_seed(0))
    assert q.shape == (*ok, tree.n_dof)
    assert tree.forward_kinematics(q, "right_index")["right_index"].shape == (*ok, 4, 4)
    J = tree.jacobian(q, "right_index", point=torch.zeros(*ok, 3, dtype=F64))
    assert J.shape == (*ok, 6, tree.n_dof)
    p = tree.forward_kinematics(q, "right_index")["right_index"][..., :3, 3]
    res = tree.inverse_kinematics(p, "right_index", max_iterations=0)
    assert res.q.shape == (*ok, tree.n_dof)
    in_q = rf"in q \(before its trailing \({tree.n_dof},\)\)"
    point = torch.zeros(*more, 3, dtype=F64)
    sizes, ik = r"\(one per batch size\)", r"in targets\['right_index'\]"
    for fn, call, where in (
        ("random_configuration", lambda: tree.random_configuration(*more), sizes),
        ("forward_kinematics", lambda: tree.forward_kinematics(q[None]), in_q),
        ("jacobian", lambda: tree.jacobian(q[None], "drone"), in_q),
        ("jacobian", lambda: tree.jacobian(q, "drone", point=point), "in point .*"),
        ("inverse_kinematics", lambda: tree.inverse_kinematics(p[None], "right_index"), ik),
    ):  # fmt: skip
        head = rf"^torchlie\.kinematics\.Chain\.{fn}: expected at most 60 batch dimensions"
        with pytest.raises(ValueError, match=rf"{head} {where}, got 61$"):
            call()


# ----------------------------------------------------------------------------------------------
# Robots without degrees of freedom
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("text", [FIXED_ONLY, SINGLE_LINK], ids=["fixed_only", "single_link"])
def test_robot_without_dof_has_constant_poses_and_empty_jacobians(text):
    chain = Chain.from_urdf(text, dtype=F64)
    assert chain.n_dof == 0
    for batch in [(), (4,), (0,), (2, 3)]:
        q = chain.random_configuration(*batch)
        assert q.shape == (*batch, 0)
        for link in chain.link_names:
            assert chain.jacobian(q, link).shape == (*batch, 6, 0)
        T = chain.forward_kinematics(q, stacked=True)
        assert T.shape == (*batch, len(chain.link_names), 4, 4)
    T = chain.forward_kinematics(torch.zeros(5, 0, dtype=F64))
    expected = torch.eye(4, dtype=F64)
    if "b" in T:
        expected[:3, 3] = torch.tensor([1.0, 2.0, 3.0], dtype=F64)
        torch.testing.assert_close(T["b"], expected.expand(5, 4, 4), rtol=0, atol=0)
        torch.testing.assert_close(T["c"], expected.expand(5, 4, 4), rtol=0, atol=0)
    torch.testing.assert_close(T["a"], torch.eye(4, dtype=F64).expand(5, 4, 4), rtol=0, atol=0)


@pytest.mark.parametrize("text", [FIXED_ONLY, SINGLE_LINK], ids=["fixed_only", "single_link"])
def test_validate_robot_without_dof_has_nothing_to_compare(text):
    out = io.StringIO()
    report = V.validate(text, samples=5, out=out, err=io.StringIO())
    assert report.status == V.NOTHING_TO_COMPARE == "nothing to compare"
    assert report.ok  # not a failure ...
    assert report.links == [] and report.jacobians == [] and report.timings == {}
    printed = out.getvalue()
    assert "NOTHING TO COMPARE: the robot has no degree of freedom" in printed
    assert "PASS" not in printed and "FAIL" not in printed  # ... and not a PASS of nothing


def test_cli_robot_without_dof_says_nothing_to_compare_and_exits_0(tmp_path, capsys):
    path = tmp_path / "fixed.urdf"
    path.write_text(FIXED_ONLY)
    assert V.main([str(path), "--samples", "3", "--no-progress"]) == 0
    captured = capsys.readouterr()
    assert "NOTHING TO COMPARE" in captured.out and "PASS" not in captured.out
    assert captured.err == ""  # no traceback


def test_validate_status_is_pass_when_everything_is_within_tolerance():
    report = V.validate("arm7", samples=3, compare_pk=False, out=io.StringIO())
    assert report.status == V.PASS and report.ok


def test_validate_counts_nan_as_outside_tolerance(monkeypatch):
    fk = Chain.forward_kinematics

    def nan_tool(self, q, links=None, **kw):
        out = fk(self, q, links, **kw)
        out["tool_tcp"] = torch.full_like(out["tool_tcp"], math.nan)
        return out

    monkeypatch.setattr(Chain, "forward_kinematics", nan_tool)
    text = io.StringIO()
    report = V.validate("arm7", samples=3, compare_pk=False, out=text)
    assert report.status == V.FAIL and not report.ok
    (bad,) = [r for r in report.links if not r.ok]
    assert bad.link == "tool_tcp" and math.isnan(bad.ref_position)
    assert "FAIL: outside tolerance: tool_tcp" in text.getvalue()


# ----------------------------------------------------------------------------------------------
# Names and roles of the degrees of freedom
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("floating_first", [True, False])
def test_a_joint_named_like_another_joints_coordinate_is_an_error_naming_both(floating_first):
    floating = joint("base", "floating", "a", "b")
    revolute = joint("base:x", "revolute", "b", "c")
    body = floating + revolute if floating_first else revolute + floating
    with pytest.raises(URDFError, match=r"<string>: <joint name='base:x'>: 'base:x' would name a "
                       r"degree of freedom of this joint and one of the floating joint 'base' "
                       r"\(whose degrees of freedom are 'base:x', 'base:y', .*'base:rz'\); "
                       r"rename one of the two joints"):  # fmt: skip
        Chain.from_urdf(robot(body, ("a", "b", "c")))
    # A ball joint's velocity coordinates are named too (J:wx, J:wy, J:wz).
    sdf = (
        '<sdf version="1.7"><model name="m"><link name="a"/><link name="b"/><link name="c"/>'
        '<joint name="b0" type="ball"><parent>a</parent><child>b</child></joint>'
        '<joint name="b0:wy" type="revolute"><parent>b</parent><child>c</child>'
        "<axis><xyz>0 0 1</xyz></axis></joint></model></sdf>"
    )
    with pytest.raises(URDFError, match=r"<joint name='b0:wy'>: 'b0:wy' would name a velocity "
                       r"coordinate of this joint and one of the ball joint 'b0'"):  # fmt: skip
        Chain.from_sdf(sdf)
    # Other names with ':' are fine.
    body = joint("base", "floating", "a", "b") + joint("base:elbow", "revolute", "b", "c")
    ok = Chain.from_urdf(robot(body, ("a", "b", "c")))
    assert ok.joint_names[-1] == "base:elbow" and len(set(ok.joint_names)) == 7


def test_dof_joints_say_what_each_dof_is(tree):
    roles = dict(zip(tree.joint_names, tree.dof_joints, strict=True))
    assert roles["puck_slide:theta"] == ("puck_slide", "planar", "theta")
    assert roles["drone_free:rx"] == ("drone_free", "floating", "rx")
    assert all(r == (n, t, "") for n, r in roles.items() for t in [r[1]] if ":" not in n)


def test_sampling_ranges_come_from_the_joint_types_not_the_names():
    """Unlimited coordinates: [-pi, pi] for one-DoF joints (continuous, and prismatic: in m),
    [-1, 1] per quaternion component, whatever the joints are named."""
    text = robot(
        joint("wheel:x", "continuous", "a", "b") + joint("arm:rz", "continuous", "b", "c")
        + joint("c:qw", "continuous", "c", "d"),
        ("a", "b", "c", "d"),
    )  # fmt: skip
    lo, hi = Chain.from_urdf(text).sampling_bounds()
    assert torch.equal(hi, torch.full((3,), math.pi, dtype=F64)) and torch.equal(lo, -hi)
    sdf = (
        '<sdf version="1.7"><model name="m"><link name="a"/><link name="b"/><link name="c"/>'
        '<link name="d"/><joint name="ball" type="ball"><parent>a</parent><child>b</child>'
        '</joint><joint name="h:y" type="revolute"><parent>b</parent><child>c</child>'
        '<axis><xyz>0 0 1</xyz></axis></joint><joint name="s" type="prismatic"><parent>c'
        "</parent><child>d</child><axis><xyz>1 0 0</xyz></axis></joint></model></sdf>"
    )
    chain = Chain.from_sdf(sdf, dtype=F64)
    lo, hi = chain.sampling_bounds()
    pi = math.pi
    assert hi.tolist() == [1.0, 1.0, 1.0, 1.0, pi, pi] and torch.equal(lo, -hi)
    q = chain.random_configuration(1000, generator=torch.Generator().manual_seed(0))
    assert float(q[:, 5].abs().max()) > 3.0  # the slide over [-pi, pi] m
    # moving_dofs indexes the velocity coordinates (the Jacobian's columns).
    assert chain.moving_dofs("d") == (0, 1, 2, 3, 4)
    assert chain.velocity_names[4] == "s" and chain.joint_names[4] == "h:y"


# ----------------------------------------------------------------------------------------------
# Subsets of Jacobian columns, and points
# ----------------------------------------------------------------------------------------------


def test_poses_and_jacobians_gives_the_columns_of_any_dofs(tree):
    arm = Chain.from_urdf(sample_robot("arm7"), dtype=F64)
    q = arm.random_configuration(3, generator=torch.Generator().manual_seed(0))
    J = arm.jacobian(q, "tool_tcp")
    for dofs in [(1, 3), (6,), (0, 1, 2, 3, 4, 5, 6), ()]:
        (_,), (Jd,) = arm.poses_and_jacobians(q.mT, ["tool_tcp"], dofs=dofs)
        assert torch.equal(Jd.permute(2, 1, 0), J[..., list(dofs)])
    (_,), (Jd,) = arm.poses_and_jacobians(q.mT, ["link2"], dofs=[1, 4])  # 4 does not move it
    assert torch.equal(Jd.permute(2, 1, 0), arm.jacobian(q, "link2")[..., [1, 4]])
    assert bool((Jd[1] == 0).all())
    # A tree with mimic joints (columns summed into the DoF they follow).
    q = tree.random_configuration(2, generator=torch.Generator().manual_seed(1))
    links = list(tree.leaf_links)
    Js = tree.jacobian(q, links)
    for dofs in [(0, 2, 5), tuple(range(1, tree.n_dof, 2)), tree.moving_dofs(links)[1:]]:
        _, Jd = tree.poses_and_jacobians(q.mT, links, dofs=dofs)
        for name, Jk in zip(links, Jd, strict=True):
            assert torch.equal(Jk.permute(2, 1, 0), Js[name][..., list(dofs)]), (name, dofs)
    fn = r"torchlie\.kinematics\.Chain\.poses_and_jacobians"
    for bad in [(9,), (-1,), (3, 1), (2, 2)]:
        with pytest.raises(ValueError, match=rf"{fn}: expected dofs to be strictly increasing "
                           rf"indices in \[0, 7\) .*got {re.escape(repr(bad))}"):  # fmt: skip
            arm.poses_and_jacobians(q[:, :7].mT, ["tool_tcp"], dofs=bad)
    for bad in [3, "01", (1.0,), (True,)]:
        with pytest.raises(TypeError, match=rf"{fn}: expected dofs to be None or a sequence of "
                           "integer DoF indices"):  # fmt: skip
            arm.poses_and_jacobians(q[:, :7].mT, ["tool_tcp"], dofs=bad)


def test_jacobian_point_must_broadcast_with_q():
    arm = Chain.from_urdf(sample_robot("arm7"))
    fn = r"torchlie\.kinematics\.Chain\.jacobian"
    for frame in ("world", "link"):
        with pytest.raises(ValueError, match=rf"{fn}: batch shapes do not broadcast: q batch "
                           r"\(4,\), point batch \(5,\)"):  # fmt: skip
            arm.jacobian(torch.zeros(4, 7), "tool_tcp", point=torch.zeros(5, 3), frame=frame)
    with pytest.raises(ValueError, match=rf"{fn}: .* point\['link2'\] batch \(5,\)"):
        arm.jacobian(torch.zeros(4, 7), ["tool_tcp", "link2"], point={"link2": torch.zeros(5, 3)})
    J = arm.jacobian(torch.zeros(4, 7), "tool_tcp", point=torch.zeros(2, 1, 3))
    assert J.shape == (2, 4, 6, 7)


# ----------------------------------------------------------------------------------------------
# Bad arguments
# ----------------------------------------------------------------------------------------------


def test_random_configuration_rejects_negative_or_non_integer_sizes(tree):
    fn = "torchlie.kinematics.Chain.random_configuration"
    with pytest.raises(ValueError, match=rf"{fn}: expected batch sizes >= 0, got batch=\(-1,\)"):
        tree.random_configuration(-1)
    with pytest.raises(ValueError, match=rf"{fn}: .* got batch=\(2, -3\)"):
        tree.random_configuration(2, -3)
    for size in (2.0, "2", None, True):
        with pytest.raises(TypeError, match=f"{fn}: expected batch sizes to be integers"):
            tree.random_configuration(size)
    assert tree.random_configuration(torch.tensor(2)).shape == (2, tree.n_dof)
    for gen in (0, "seed", torch.tensor(3)):
        with pytest.raises(TypeError, match=f"{fn}: expected generator to be a torch.Generator"):
            tree.random_configuration(2, generator=gen)


@pytest.mark.parametrize("arg", ["samples", "batch"])
@pytest.mark.parametrize("value", [0, -1])
def test_validate_rejects_fewer_than_one_sample_or_batch(arg, value):
    with pytest.raises(ValueError, match=rf"validate: expected {arg} >= 1, got {arg}={value}"):
        V.validate("arm7", out=io.StringIO(), **{arg: value})
    with pytest.raises(TypeError, match=rf"validate: expected {arg} to be an integer"):
        V.validate("arm7", out=io.StringIO(), **{arg: 2.5})


def test_links_of_the_wrong_type_are_a_clear_type_error(tree):
    q = tree.random_configuration(2)
    fk = "torchlie.kinematics.Chain.forward_kinematics"
    with pytest.raises(TypeError, match=rf"{fk}: expected links to be a link name, .* got int 3"):
        tree.forward_kinematics(q, links=3)
    with pytest.raises(TypeError, match=rf"{fk}: .* got a list whose item 1 is int 7"):
        tree.forward_kinematics(q, ["world", 7])
    with pytest.raises(TypeError, match=rf"{fk}: .* got set"):
        tree.forward_kinematics(q, {"world"})  # no order: a dict or stack would be arbitrary
    with pytest.raises(ValueError, match=rf"{fk}: unknown link 'nope' \(the links are 'world',"):
        tree.forward_kinematics(q, ("world", "nope"))
    jac = "torchlie.kinematics.Chain.jacobian"
    for link, got in ((None, "NoneType"), (3, "int"), (b"drone", "bytes")):
        with pytest.raises(TypeError, match=rf"{jac}: expected link to be a link name \(str\) "
                           rf"or a sequence of link names, got {got}"):  # fmt: skip
            tree.jacobian(q, link)
    with pytest.raises(ValueError, match=rf"{jac}: unknown link 'nope' \(the links are"):
        tree.jacobian(q, ["drone", "nope"])


# ----------------------------------------------------------------------------------------------
# Extreme numbers
# ----------------------------------------------------------------------------------------------


def test_huge_finite_origin_is_computed_in_float64_and_rejected_in_float32():
    text = robot(joint(inner='<origin xyz="1e308 0 0"/>') + joint("k", "revolute", "b", "c"),
                 ("a", "b", "c"))  # fmt: skip
    assert parse_urdf(text).joints[0].xyz == (1e308, 0.0, 0.0)
    chain = Chain.from_urdf(text, dtype=F64)
    q = torch.tensor([[0.3, -0.2]], dtype=F64)
    T = chain.forward_kinematics(q)
    assert T["c"][0, 0, 3].item() == 1e308  # no overflow here: computed exactly
    assert bool(torch.isfinite(T["c"]).all())
    J = chain.jacobian(q, "c")
    assert bool(torch.isfinite(J).all()) and J[0, 3:, 1].tolist() == pytest.approx(
        T["b"][0, :3, 0].tolist()
    )
    with pytest.raises(URDFError) as info:
        Chain.from_urdf(text)  # float32: the constant itself would be inf
    e = info.value
    assert e.source == "<string>" and e.element == "<joint name='j'> <origin>"
    assert e.problem.startswith("attribute 'xyz' value 1e+308 overflows torch.float32")
    assert V.main([text, "--samples", "2", "--dtype", "float32", "--no-pk"]) == 2


def test_overflowing_sum_of_origins_is_inf_not_an_error():
    text = robot(
        joint("j", "fixed", "a", "b", '<origin xyz="1e308 0 0"/>')
        + joint("k", "fixed", "b", "c", '<origin xyz="1e308 0 0"/>'),
        ("a", "b", "c"),
    )
    T = Chain.from_urdf(text, dtype=F64).forward_kinematics(torch.zeros(0, dtype=F64))
    assert T["c"][0, 3].item() == math.inf  # IEEE overflow, as documented


def test_validate_of_a_huge_origin_robot_ends_with_a_verdict():
    text = robot(joint(inner='<origin xyz="1e308 0 0"/>') + joint("k", "revolute", "b", "c"),
                 ("a", "b", "c"))  # fmt: skip
    out = io.StringIO()
    report = V.validate(text, samples=3, batch=2, compare_pk=False, out=out)
    assert report.status == V.PASS  # float64 computes it; no float32 copy to time
    assert list(report.timings) == ["torchlie float64"] and "PASS" in out.getvalue()


def test_mimic_multipliers_whose_product_overflows_are_rejected():
    text = robot(
        joint("j1", "revolute", "a", "b")
        + joint("j2", "revolute", "b", "c", '<mimic joint="j1" multiplier="1e200"/>')
        + joint("j3", "revolute", "c", "d", '<mimic joint="j2" multiplier="1e200"/>'),
        ("a", "b", "c", "d"),
    )
    with pytest.raises(URDFError) as info:
        Chain.from_urdf(text, dtype=F64)
    assert info.value.element == "<joint name='j3'> <mimic>"
    assert "the multiplier composed along its chain of mimic joints, inf" in info.value.problem


MAX64 = torch.finfo(F64).max
MAX32 = float(torch.finfo(torch.float32).max)


def limited(lower: float, upper: float, jtype: str = "prismatic") -> str:
    """A one-joint robot with limits written as the doubles ``lower`` and ``upper``."""
    return robot(
        joint("j", jtype).replace('lower="-1" upper="1"', f'lower="{lower!r}" upper="{upper!r}"')
    )


@pytest.mark.parametrize(
    ("lower", "upper"),
    [(-MAX64, MAX64), (-1e300, 1e308), (1e308, MAX64), (-MAX64, -1e308), (MAX64, MAX64),
     (-MAX64, -MAX64), (0.5, 0.5)],
)  # fmt: skip
def test_random_configuration_is_finite_and_uniform_for_every_finite_pair_of_limits(lower, upper):
    # hi - lo overflows for the first pair; the draw never forms it.
    chain = Chain.from_urdf(limited(lower, upper), dtype=F64)
    q = chain.random_configuration(20_000, generator=torch.Generator().manual_seed(0))[:, 0]
    assert bool(torch.isfinite(q).all())
    assert bool(((q >= lower) & (q <= upper)).all())
    if lower == upper:
        assert bool((q == lower).all())
    else:  # where in [lower, upper], as a fraction: uniform, mean 1/2 and spread 1/sqrt(12)
        f = (q / 2 - lower / 2) / (upper / 2 - lower / 2)
        assert abs(f.mean().item() - 0.5) < 0.01 and abs(f.std().item() - 12**-0.5) < 0.01


def test_ik_starts_are_finite_within_bounds_near_the_float64_range():
    chain = Chain.from_urdf(limited(-1.0, 1.0), dtype=F64)
    res = chain.inverse_kinematics(
        torch.zeros(50, 3, dtype=F64), "b", restarts=4, max_iterations=0, lower=-MAX64,
        upper=MAX64, generator=torch.Generator().manual_seed(0),
    )  # fmt: skip
    # Uniform in [-MAX64, MAX64] (not all at one bound, as inf * u clamped would be).
    assert bool(torch.isfinite(res.q).all()) and res.q.unique().numel() == 50
    assert 0.2 < (res.q > 0).double().mean().item() < 0.8 and res.q.abs().max().item() > 1e307


@pytest.mark.parametrize("dtype", [torch.float32, F64], ids=str)
def test_limits_at_the_edge_of_the_dtype_are_kept_and_sampled_finite(dtype):
    top = MAX32 if dtype == torch.float32 else MAX64
    chain = Chain.from_urdf(limited(-top, top), dtype=dtype)
    assert chain.lower.tolist() == [-top] and chain.upper.tolist() == [top]
    q = chain.random_configuration(1000, generator=torch.Generator().manual_seed(1))
    assert bool(torch.isfinite(q).all()) and bool(((q >= -top) & (q <= top)).all())
    # 3.4028235e38 is above float32's largest value but rounds to it, so it fits float32.
    chain = Chain.from_urdf(limited(0.0, 3.4028235e38))
    assert chain.upper.tolist() == [MAX32]
    q = chain.random_configuration(1000, generator=torch.Generator().manual_seed(2))
    assert bool(torch.isfinite(q).all()) and bool((q <= MAX32).all())


ONE_RULE = [  # (robot, element, attribute, written value): every number the chain stores
    (robot(joint(inner='<origin xyz="0 1e39 0"/>')), "origin", "xyz", "1e+39"),
    (limited(-1e39, 1.0, "revolute"), "limit", "lower", "-1e+39"),
    (limited(0.0, 3.5e38), "limit", "upper", "3.5e+38"),
]


@pytest.mark.parametrize(
    ("text", "sub", "key", "value"), ONE_RULE, ids=["origin", "lower", "upper"]
)
def test_numbers_beyond_float32_are_rejected_alike_naming_file_element_and_value(
    tmp_path, text, sub, key, value
):
    # Origins and limits follow one rule: computed in float64, an error in float32 (a limit
    # would otherwise become inf, read as "no limit"), from a file, a string or Chain.to.
    path = tmp_path / "big.urdf"
    path.write_text(text)
    problem = (
        f"attribute '{key}' value {value} overflows torch.float32 (largest finite 3.40282e+38); "
        "use dtype=torch.float64"
    )
    for source, label in ((path, str(path)), (text, "<string>")):
        with pytest.raises(URDFError) as info:
            Chain.from_urdf(source)
        e = info.value
        assert (e.source, e.element, e.problem) == (label, f"<joint name='j'> <{sub}>", problem)
        assert str(e) == f"{label}: <joint name='j'> <{sub}>: {problem}"
    chain = Chain.from_urdf(path, dtype=F64)
    q = chain.random_configuration(100, generator=torch.Generator().manual_seed(0))
    assert bool(torch.isfinite(chain.forward_kinematics(q)["b"]).all())
    with pytest.raises(URDFError) as info:
        chain.to(torch.float32)
    assert info.value.problem == problem


def test_a_mimic_joints_own_limits_are_not_stored_so_not_checked():
    mimic = joint("j2", "revolute", "b", "c", '<mimic joint="j1"/>')
    text = robot(
        joint("j1", "revolute", "a", "b") + mimic.replace('"1"', '"1e39"'), ("a", "b", "c")
    )
    chain = Chain.from_urdf(text)  # float32: j2 has no DoF, its limits are not in chain.upper
    assert chain.joint_names == ("j1",) and chain.upper.tolist() == [1.0]


# ----------------------------------------------------------------------------------------------
# Number syntax: XML Schema double, nothing else
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "value"),
    [("1", 1.0), ("-1", -1.0), ("+1", 1.0), ("1.", 1.0), (".5", 0.5), ("-.5e-3", -0.0005),
     ("1E+2", 100.0), ("007", 7.0), ("0.1", 0.1), (" \t2.5\n", 2.5)],
)  # fmt: skip
def test_numbers_in_xml_schema_double_syntax_are_read(text, value):
    spec = parse_urdf(robot(joint("j", "revolute").replace('upper="1"', f'upper="{text}"')))
    assert spec.joints[0].upper == value


@pytest.mark.parametrize(
    "text",
    ["1_000", "0x10", "inf", "-inf", "nan", "Infinity", "infinity", "1e", "e1", ".", "+", "-",
     "1.0f", "1,5", "--1", "1e1.5", "\u0661\u0662", "\uff11", "\u00a01", "1\u2003"],
)  # fmt: skip
def test_anything_else_is_not_a_number(text):
    with pytest.raises(URDFError) as info:
        parse_urdf(robot(joint(inner=f'<origin xyz="0 {text} 0"/>')))
    e = info.value
    assert e.element == "<joint name='j'> <origin>"
    assert e.problem == f"attribute 'xyz' is not a number: {text!r}"


@pytest.mark.parametrize("text", ["INF", "+INF", "-INF", "NaN", "1e309"])
def test_schema_spellings_of_non_finite_values_are_not_finite(text):
    with pytest.raises(URDFError) as info:
        parse_urdf(robot(joint().replace('lower="-1"', f'lower="{text}"')))
    assert info.value.problem == f"attribute 'lower' is not finite: {text!r}"


def test_lists_are_separated_by_xml_whitespace_only():
    spec = parse_urdf(robot(joint(inner='<origin xyz="1\t2\n 3"/>')))
    assert spec.joints[0].xyz == (1.0, 2.0, 3.0)
    with pytest.raises(URDFError, match="attribute 'xyz' must be three numbers"):
        parse_urdf(robot(joint(inner='<origin xyz="1\u20032 3"/>')))  # em space: not XML's


# ----------------------------------------------------------------------------------------------
# Names in messages are quoted
# ----------------------------------------------------------------------------------------------


def test_names_in_error_messages_cannot_forge_log_lines(tmp_path):
    forged = "j&#10;ERROR: forged"
    text = robot(f'<joint name="{forged}" type="hinge"/>')
    with pytest.raises(URDFError) as info:
        parse_urdf(text)
    assert "\n" not in str(info.value)
    assert info.value.element == "<joint name='j\\nERROR: forged'>"
    # A link name in a problem, a mimic cycle and a file name are quoted too.
    with pytest.raises(URDFError) as info:
        parse_urdf(robot(joint(parent="x&#13;y")))
    assert "\r" not in str(info.value) and "link 'x\\ry'" in info.value.problem
    cycle = robot(
        joint("p&#10;q", "revolute", "a", "b", '<mimic joint="r"/>')
        + joint("r", "revolute", "b", "c", '<mimic joint="p&#10;q"/>'),
        ("a", "b", "c"),
    )
    with pytest.raises(URDFError) as info:
        parse_urdf(cycle)
    assert "\n" not in str(info.value) and "'p\\nq' -> 'r' -> 'p\\nq'" in info.value.problem
    path = tmp_path / "a\nb.urdf"
    path.write_text(robot(joint(jtype="hinge")))
    with pytest.raises(URDFError) as info:
        parse_urdf(path)
    assert "\n" not in str(info.value) and str(info.value).startswith(repr(str(path)))
    # An unknown link asked of a chain.
    chain = Chain.from_urdf(robot(joint()))
    with pytest.raises(ValueError) as info2:
        chain.forward_kinematics(torch.zeros(1), "b\nFAKE")
    assert "\n" not in str(info2.value)


# ----------------------------------------------------------------------------------------------
# Thousands of links and joints
# ----------------------------------------------------------------------------------------------


def _big_error(tmp_path, text: str) -> URDFError:
    """The URDFError of ``text`` read from a file: it names the file and stays short."""
    path = tmp_path / "big.urdf"
    path.write_text(text)
    with pytest.raises(URDFError) as info:
        parse_urdf(path)
    e = info.value
    assert e.source == str(path) and str(e) == f"{path}: {e.element}: {e.problem}"
    assert len(e.problem) < 160
    return e


def test_eighty_thousand_root_links_are_counted_and_five_named(tmp_path):
    e = _big_error(tmp_path, robot("", tuple(f"l{i}" for i in range(80_000))))
    assert e.element == "<robot>"
    assert e.problem == (
        "80000 root links ('l0', 'l1', 'l2', 'l3', 'l4' and 79995 more); exactly one link may "
        "be without a parent joint"
    )


def test_a_five_thousand_joint_cycle_is_counted_and_five_named(tmp_path):
    n = 5_000  # l0 -> l1 -> ... -> l4999 -> l0 by joints j0 ... j4999, below no root
    body = "".join(joint(f"j{i}", "fixed", f"l{i}", f"l{(i + 1) % n}") for i in range(n))
    e = _big_error(tmp_path, robot(body, ("root", *(f"l{i}" for i in range(n)))))
    assert e.element == "<joint name='j4999'>"
    assert e.problem == (
        "cycle through 5000 joints 'j0' -> 'j1' -> 'j2' -> 'j3' -> 'j4' and 4995 more (links "
        "'l0', 'l1', 'l2', 'l3', 'l4' and 4995 more)"
    )


def test_a_five_thousand_joint_mimic_cycle_is_counted_and_five_named(tmp_path):
    n = 5_000  # j{i} mimics j{i+1}, and j4999 mimics j0
    text = serial(n, mimic=True, reverse=True).replace(
        '<limit lower="-1" upper="1"/></joint></robot>',
        '<limit lower="-1" upper="1"/><mimic joint="j0"/></joint></robot>',
    )
    e = _big_error(tmp_path, text)
    assert e.element == "<joint name='j0'> <mimic>"
    assert e.problem == (
        "mimic cycle of 5000 joints: 'j0' -> 'j1' -> 'j2' -> 'j3' -> 'j4' and 4996 more"
    )


def test_chain_errors_list_five_of_two_thousand_links():
    n = 2_000
    chain = Chain.from_urdf(serial(n))
    q = torch.zeros(chain.n_dof)
    with pytest.raises(ValueError) as info:
        chain.forward_kinematics(q, "nope")
    assert str(info.value) == (
        "torchlie.kinematics.Chain.forward_kinematics: unknown link 'nope' (the links are 'l0', "
        "'l1', 'l2', 'l3', 'l4' and 1996 more)"
    )
    links = [f"l{i}" for i in range(1, n + 1)]
    with pytest.raises(ValueError) as info:
        chain.jacobian(q, links, point={"l0": torch.zeros(3)})
    assert str(info.value) == (
        "torchlie.kinematics.Chain.jacobian: point has an entry for 'l0', which is not among the "
        "links asked for ('l1', 'l2', 'l3', 'l4', 'l5' and 1995 more)"
    )


def test_validate_notes_list_five_joints_and_count_the_rest():
    pytest.importorskip("pytorch_kinematics")
    n = 12  # every joint without <axis>, every other one a mimic joint
    body = "".join(
        joint(f"j{i}", "revolute", f"l{i}", f"l{i + 1}", f'<mimic joint="j{i - 1}"/>' * (i % 2))
        for i in range(n)
    )
    text = robot(body, tuple(f"l{i}" for i in range(n + 1)))
    text = text.replace('upper="1"/>', 'upper="1" effort="1" velocity="1"/>')  # pk needs them
    report = V.validate(text, samples=2, batch=2, compare_pin=False, out=io.StringIO())
    dev = "\n".join(report.deviations)
    assert "written out for j0, j1, j2, j3, j4 and 7 more" in dev
    assert "expanded values j1 = 1 * j0 + 0, j3 = 1 * j2 + 0, j5 = 1 * j4 + 0, " in dev
    assert "j9 = 1 * j8 + 0 and 1 more," in dev


def test_parses_twenty_thousand_links():
    n = 20_000
    links = "".join(f'<link name="l{i}"/>' for i in range(n))
    joints = "".join(
        f'<joint name="j{i}" type="fixed"><parent link="l{i // 2}"/><child link="l{i}"/></joint>'
        for i in range(1, n)
    )
    spec = parse_urdf(f'<robot name="big">{links}{joints}</robot>')
    assert spec.links == tuple(f"l{i}" for i in range(n)) and spec.root == "l0"
    assert len(spec.joints) == n - 1 and spec.joints[-1].parent == f"l{(n - 1) // 2}"
    dup = f'<robot name="big">{links}<link name="l{n // 2}"/>{joints}</robot>'
    with pytest.raises(URDFError) as info:
        parse_urdf(dup)
    assert (info.value.element, info.value.problem) == (
        f"<link name='l{n // 2}'>",
        "duplicate link name",
    )


@pytest.mark.parametrize("reverse", [False, True], ids=["forward", "reverse"])
def test_long_chain_of_mimic_joints_composes(reverse):
    n = 2_000
    chain = Chain.from_urdf(serial(n, mimic=True, reverse=reverse), dtype=F64)
    assert chain.joint_names == (f"j{n - 1}" if reverse else "j0",)
    # Joint j{k}'s value is q + 0.001 * (its distance along the mimics from the joint with
    # the DoF), each with multiplier 1: the end's angular Jacobian column is the sum of the
    # joints' world axes (all n mimic columns folded into the one DoF) ...
    q = torch.tensor([[0.2]], dtype=F64)
    J = chain.jacobian(q, f"l{n}")
    T = chain.forward_kinematics(q, [f"l{k}" for k in range(1, n + 1)], stacked=True)[0]
    axes = T[:, :3, :3] @ torch.tensor([0.0, 0.6, 0.8], dtype=F64)  # joint k's, child l{k+1}
    torch.testing.assert_close(J[0, 3:, 0], axes.sum(0), atol=1e-9, rtol=0)
    # ... and joint j{k} turns its child by its own value relative to its parent.
    one = Chain.from_urdf(serial(1), dtype=F64)
    for k in (1, n // 2, n - 1):
        value = 0.2 + 0.001 * (n - 1 - k if reverse else k)
        expected = one.forward_kinematics(torch.tensor([value], dtype=F64), "l1")["l1"]
        torch.testing.assert_close(torch.linalg.solve(T[k - 1], T[k]), expected, atol=1e-9, rtol=0)


def _geometric_jacobian(chain: Chain, q: torch.Tensor, n: int) -> torch.Tensor:
    """Column by column from the poses: (a_k x (p_end - p_k); a_k) for revolute joint k."""
    T = chain.forward_kinematics(q, [f"l{k}" for k in range(1, n + 1)], stacked=True)
    a = T[..., :3, :3] @ torch.tensor([0.0, 0.6, 0.8], dtype=q.dtype)  # (B, n, 3)
    p = T[..., :3, 3]
    lin = torch.linalg.cross(a, p[..., -1:, :] - p, dim=-1)
    return torch.cat((lin, a), dim=-1).transpose(-1, -2)  # (B, 6, n)


def test_jacobian_of_a_three_thousand_joint_chain():
    n = 3_000
    chain = Chain.from_urdf(serial(n), dtype=F64)
    q = chain.random_configuration(2, generator=torch.Generator().manual_seed(0))
    J = chain.jacobian(q, f"l{n}")
    assert J.shape == (2, 6, n)
    torch.testing.assert_close(J, _geometric_jacobian(chain, q, n), atol=1e-10, rtol=0)
    # A link halfway: the columns of the joints below it are zero.
    Jm = chain.jacobian(q, f"l{n // 2}")
    assert bool((Jm[..., n // 2 :] == 0).all())
    torch.testing.assert_close(
        Jm[..., : n // 2], _geometric_jacobian(chain, q, n // 2), atol=1e-10, rtol=0
    )


def test_jacobian_of_a_chain_with_mimics_matches_jacrev():
    for chain in (
        Chain.from_urdf(serial(40, mimic=True), dtype=F64),
        Chain.from_urdf(serial(40), dtype=F64),
    ):
        q = chain.random_configuration(3, generator=torch.Generator().manual_seed(1))

        def position(x, chain=chain):
            return chain.forward_kinematics(x, "l40")["l40"][..., :3, 3]

        Jp = torch.vmap(torch.func.jacrev(position))(q)  # (B, 3, n_dof)
        assert Jp.shape == (3, 3, chain.n_dof)
        torch.testing.assert_close(chain.jacobian(q, "l40")[:, :3], Jp, atol=1e-12, rtol=0)


def test_mimic_jacobian_under_vmap(tree):
    q = tree.random_configuration(3, 2, generator=torch.Generator().manual_seed(2))
    for link in ("right_index", "left_finger_b"):
        J = torch.func.vmap(lambda x, link=link: tree.jacobian(x, link))(q)
        torch.testing.assert_close(J, tree.jacobian(q, link), atol=1e-15, rtol=0)


@pytest.mark.parametrize("robot_name", ["arm7", "tree"])  # tree: mimic joints, floating base
@pytest.mark.parametrize("first", ["hessian", "inference_mode"])
def test_first_call_under_a_transform_or_inference_mode_leaves_the_chain_usable(robot_name, first):
    """A fresh chain whose first call runs under ``torch.func.hessian`` or
    ``torch.inference_mode`` keeps no constants of that mode: afterwards ``jacrev``, ``jacfwd``
    and a backward pass work and agree with a chain whose first call was eager."""
    from torch.func import hessian, jacfwd, jacrev

    ref = Chain.from_urdf(sample_robot(robot_name), dtype=F64)
    chain = Chain.from_urdf(sample_robot(robot_name), dtype=F64)
    q = ref.random_configuration(1, generator=torch.Generator().manual_seed(3))[0]
    qd = torch.linspace(-1.0, 1.0, q.shape[-1], dtype=F64)
    last = chain.link_names[-1]

    def fk(c, x):
        return c.forward_kinematics(x, links=[last])[last]

    def calls(c, x):
        return (fk(c, x).sum(), c.mass_matrix(x).sum(), c.inverse_dynamics(x, qd, qd).sum())

    if first == "hessian":
        for k in range(3):
            hessian(lambda x, k=k: calls(chain, x)[k])(q)
    else:
        with torch.inference_mode():
            calls(chain, q)
    for k in range(3):
        for jac in (jacrev, jacfwd):
            torch.testing.assert_close(
                jac(lambda x, k=k: calls(chain, x)[k])(q), jac(lambda x, k=k: calls(ref, x)[k])(q)
            )
        x = q.clone().requires_grad_()
        calls(chain, x)[k].backward()
        torch.testing.assert_close(x.grad, torch.func.grad(lambda x, k=k: calls(ref, x)[k])(q))
