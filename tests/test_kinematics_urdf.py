"""URDF parsing: values, defaults, and every kind of malformed file."""

from __future__ import annotations

import math

import pytest
import torch

from torchlie.kinematics import Chain, URDFError, parse_urdf, sample_robot


def robot(body: str, links: tuple[str, ...] = ("a", "b")) -> str:
    decl = "".join(f'<link name="{n}"/>' for n in links)
    return f'<robot name="r">{decl}{body}</robot>'


def joint(name="j", jtype="revolute", parent="a", child="b", inner=None) -> str:
    if inner is None:
        inner = '<limit lower="-1" upper="1"/>' if jtype in ("revolute", "prismatic") else ""
    return (
        f'<joint name="{name}" type="{jtype}"><parent link="{parent}"/>'
        f'<child link="{child}"/>{inner}</joint>'
    )


# ----------------------------------------------------------------------------------------------
# Values and defaults
# ----------------------------------------------------------------------------------------------


def test_values_are_parsed_exactly_in_float64():
    spec = parse_urdf(
        robot(
            joint(
                inner='<origin xyz="0.1 -2e-3 1.0000000000000002" rpy="0.3 0 -1"/>'
                '<axis xyz="0 0 2"/><limit lower="-0.7" upper="1.3" effort="5" velocity="2"/>'
            )
        )
    )
    (j,) = spec.joints
    assert j.xyz == (0.1, -0.002, 1.0000000000000002)  # float32 would round the last one to 1
    assert j.rpy == (0.3, 0.0, -1.0)
    assert j.axis == (0.0, 0.0, 2.0) and j.axis_given
    assert (j.lower, j.upper, j.effort, j.velocity) == (-0.7, 1.3, 5.0, 2.0)
    assert spec.root == "a" and spec.source == "<string>" and spec.name == "r"


def test_defaults_follow_the_urdf_specification():
    spec = parse_urdf(
        robot(
            joint("j1", "continuous", "a", "b", "")
            + joint("j2", "prismatic", "b", "c", '<limit effort="1" velocity="1"/>')
            + joint("j3", "revolute", "c", "d", '<limit/><mimic joint="j1"/>'),
            ("a", "b", "c", "d"),
        )
    )
    j1, j2, j3 = spec.joints
    assert j1.xyz == (0.0, 0.0, 0.0) and j1.rpy == (0.0, 0.0, 0.0)
    assert j1.axis == (1.0, 0.0, 0.0) and not j1.axis_given  # omitted axis means +X
    assert (j1.lower, j1.upper) == (None, None)  # continuous: no limits
    assert (j2.lower, j2.upper) == (0.0, 0.0)  # lower/upper default to 0
    assert j3.mimic is not None and (j3.mimic.multiplier, j3.mimic.offset) == (1.0, 0.0)


def test_ignores_non_kinematic_elements_and_namespaces():
    text = (
        '<robot name="r" xmlns:xacro="http://www.ros.org/wiki/xacro">'
        '<material name="m"/><link name="a"><visual><geometry><box size="1 1 1"/></geometry>'
        '</visual></link><link name="b"/><gazebo/>'
        + joint(inner='<limit lower="0" upper="1"/><dynamics damping="1"/>')
        + "<transmission/></robot>"
    )
    spec = parse_urdf(text)
    assert spec.links == ("a", "b") and len(spec.joints) == 1


def test_reads_a_file_and_bytes(tmp_path):
    path = tmp_path / "r.urdf"
    path.write_text(robot(joint()))
    assert parse_urdf(path).source == str(path)
    assert parse_urdf(str(path)).links == ("a", "b")
    assert parse_urdf(robot(joint()).encode()).source == "<string>"
    with pytest.raises(FileNotFoundError):
        parse_urdf(tmp_path / "missing.urdf")


def test_sample_robots_parse():
    for name, n_links in (("arm7", 12), ("tree", 22), ("panda", 13)):
        spec = parse_urdf(sample_robot(name))
        assert len(spec.links) == n_links
    with pytest.raises(ValueError, match="unknown robot 'nope'"):
        sample_robot("nope")


# ----------------------------------------------------------------------------------------------
# Bad URDF: URDFError (a ValueError) naming the file, the element and the problem
# ----------------------------------------------------------------------------------------------


def bad(text: str) -> URDFError:
    with pytest.raises(URDFError) as info:
        parse_urdf(text)
    assert isinstance(info.value, ValueError)
    assert str(info.value).startswith("<string>: ")
    return info.value


def test_error_names_the_file(tmp_path):
    path = tmp_path / "broken.urdf"
    path.write_text(robot(joint(jtype="hinge")))
    with pytest.raises(URDFError) as info:
        Chain.from_urdf(path)
    assert info.value.source == str(path)
    assert str(info.value).startswith(f"{path}: <joint name='j'>: unknown joint type 'hinge'")


def test_missing_parent_link():
    e = bad(robot(joint(parent="ghost")))
    assert e.element == "<joint name='j'> <parent>"
    assert e.problem == "link 'ghost' is not declared by any <link> element"


def test_missing_child_link():
    e = bad(robot(joint(child="ghost")))
    assert e.element == "<joint name='j'> <child>"
    assert "link 'ghost' is not declared" in e.problem


def test_missing_parent_element():
    e = bad(robot('<joint name="j" type="fixed"><child link="b"/></joint>'))
    assert e.element == "<joint name='j'>" and e.problem == "missing required element <parent>"


def test_cycle():
    # 'a' is the root; b -> c -> d -> b hangs in a loop of its own.
    text = robot(
        joint("bc", "fixed", "b", "c")
        + joint("cd", "fixed", "c", "d")
        + joint("db", "fixed", "d", "b"),
        ("a", "b", "c", "d"),
    )
    e = bad(text)
    assert e.element == "<joint name='db'>"
    assert e.problem == "cycle through 3 joints 'bc' -> 'cd' -> 'db' (links 'b', 'c', 'd')"
    # A cycle through every link leaves no root at all.
    e = bad(robot(joint("ab", "fixed", "a", "b") + joint("ba", "fixed", "b", "a")))
    assert e.problem == "cycle through 2 joints 'ab' -> 'ba' (links 'a', 'b')"


def test_self_loop():
    e = bad(robot(joint("aa", "fixed", "a", "a")))
    assert e.element == "<joint name='aa'>" and e.problem == "cycle: link 'a' is its own parent"


def test_link_with_two_parents():
    e = bad(robot(joint("j1", "fixed", "a", "c") + joint("j2", "fixed", "b", "c"), ("a", "b", "c")))
    assert e.element == "<joint name='j2'>"
    assert e.problem == "link 'c' is already the child of joint 'j1' (not a tree)"


def test_two_roots():
    e = bad(robot(joint("j", "fixed", "a", "b"), ("a", "b", "c")))
    assert e.element == "<robot>"
    assert e.problem == "2 root links ('a', 'c'); exactly one link may be without a parent joint"


def test_unknown_joint_type():
    e = bad(robot(joint(jtype="spherical")))
    assert e.element == "<joint name='j'>"
    assert e.problem.startswith("unknown joint type 'spherical' (expected one of revolute,")


@pytest.mark.parametrize(
    ("inner", "element", "problem"),
    [
        ('<origin xyz="0 0 abc"/>', "<origin>", "attribute 'xyz' is not a number: 'abc'"),
        ('<origin rpy="0 0"/>', "<origin>", "attribute 'rpy' must be three numbers, got '0 0'"),
        ('<origin xyz="0 NaN 0"/>', "<origin>", "attribute 'xyz' is not finite: 'NaN'"),
        ('<axis xyz="1,0,0"/>', "<axis>", "attribute 'xyz' must be three numbers, got '1,0,0'"),
        ('<axis xyz="0 0 0"/>', "<axis>", "the axis is the zero vector"),
        ('<limit lower="-1" upper="x1"/>', "<limit>", "attribute 'upper' is not a number: 'x1'"),
        ('<limit lower="1" upper="-1"/>', "<limit>", "lower limit 1.0 is above upper limit -1.0"),
    ],
)
def test_malformed_numbers(inner, element, problem):
    if "<limit" not in inner:
        inner += '<limit lower="-1" upper="1"/>'
    e = bad(robot(joint(inner=inner)))
    assert e.element == f"<joint name='j'> {element}"
    assert e.problem == problem


def test_malformed_mimic_number():
    text = robot(
        joint("j1", "revolute", "a", "b")
        + joint("j2", "revolute", "b", "c", '<limit/><mimic joint="j1" multiplier="two"/>'),
        ("a", "b", "c"),
    )
    e = bad(text)
    assert e.element == "<joint name='j2'> <mimic>"
    assert e.problem == "attribute 'multiplier' is not a number: 'two'"


@pytest.mark.parametrize(
    ("text", "element", "problem"),
    [
        (robot('<joint name="j"><parent link="a"/><child link="b"/></joint>'), "<joint name='j'>",
         "missing required attribute 'type'"),
        (robot('<joint type="fixed"><parent link="a"/><child link="b"/></joint>'), "<joint> #1",
         "missing required attribute 'name'"),
        (robot('<joint name="j" type="fixed"><parent/><child link="b"/></joint>'),
         "<joint name='j'> <parent>", "missing required attribute 'link'"),
        ('<robot name="r"><link/></robot>', "<link> #1", "missing required attribute 'name'"),
        ('<robot><link name="a"/></robot>', "<robot>", "missing required attribute 'name'"),
        (robot(joint(inner='<axis/><limit lower="0" upper="1"/>')), "<joint name='j'> <axis>",
         "missing required attribute 'xyz'"),
        (robot(joint(inner="")), "<joint name='j'>", "a revolute joint requires a <limit> element"),
        (robot(joint(inner='<limit lower="0" upper="1"/><mimic/>')), "<joint name='j'> <mimic>",
         "missing required attribute 'joint'"),
        (robot(joint(name="")), "<joint> #1", "attribute 'name' is empty"),
    ],
)  # fmt: skip
def test_missing_required_attributes(text, element, problem):
    e = bad(text)
    assert (e.element, e.problem) == (element, problem)


def test_mimic_pointing_at_nothing():
    e = bad(robot(joint(inner='<limit lower="0" upper="1"/><mimic joint="ghost"/>')))
    assert e.element == "<joint name='j'> <mimic>"
    assert e.problem == "mimicked joint 'ghost' does not exist"


def test_mimic_of_a_fixed_joint_and_mimic_on_fixed_and_floating_joints():
    text = robot(
        joint("f", "fixed", "a", "b") + joint("m", "prismatic", "b", "c",
                                               '<limit/><mimic joint="f"/>'),
        ("a", "b", "c"),
    )  # fmt: skip
    assert bad(text).problem == "mimicked joint 'f' is fixed, not a one-DoF joint"
    # a fixed joint has no value to set: its <mimic> is ignored (urdfdom's reading), even one
    # naming no joint
    for target in ("j", "ghost"):
        text = robot(
            joint("j", "revolute", "a", "b", "<limit/>")
            + joint("f", "fixed", "b", "c", f'<origin xyz="0 0 1"/><mimic joint="{target}"/>'),
            ("a", "b", "c"),
        )
        chain = Chain.from_urdf(text, dtype=torch.float64)
        assert chain.joint_names == ("j",)
        T = chain.forward_kinematics(torch.tensor([0.0], dtype=torch.float64), "c")["c"]
        assert torch.equal(T[:3, 3], torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))
    text = robot(
        joint("j", "revolute", "a", "b", "<limit/>")
        + joint("f", "floating", "b", "c", '<mimic joint="j"/>'),
        ("a", "b", "c"),
    )
    assert bad(text).problem == "a floating joint cannot mimic another joint"


def test_mimic_cycle():
    text = robot(
        joint("j1", "revolute", "a", "b", '<limit/><mimic joint="j2"/>')
        + joint("j2", "revolute", "b", "c", '<limit/><mimic joint="j1"/>'),
        ("a", "b", "c"),
    )
    assert bad(text).problem == "mimic cycle of 2 joints: 'j1' -> 'j2' -> 'j1'"
    text = robot(joint("j1", "revolute", inner='<limit/><mimic joint="j1"/>'))
    assert bad(text).problem == "mimic cycle of 1 joint: 'j1' -> 'j1'"


def test_duplicates():
    assert bad(robot("", ("a", "a"))).problem == "duplicate link name"
    e = bad(robot(joint("j", "fixed", "a", "b") + joint("j", "fixed", "b", "c"), ("a", "b", "c")))
    assert e.problem == "duplicate joint name"


def test_not_xml_not_robot_no_links():
    e = bad("<robot name='r'><link name='a'></robot>")
    assert e.element.startswith("line 1, column") and "not well-formed XML" in e.problem
    assert bad('<model name="r"/>').problem == "the root element must be <robot>"
    assert bad('<robot name="r"/>').problem == "no <link> elements"


def test_two_origin_elements():
    e = bad(robot(joint(inner='<origin/><origin/><limit lower="0" upper="1"/>')))
    assert e.problem == "more than one <origin> element"


def test_parsed_rpy_and_origin_reach_the_chain_in_float64():
    # 0.1 is not a float32; a float32 parse would be off by ~1.5e-9.
    chain = Chain.from_urdf(
        robot(joint(jtype="fixed", inner='<origin xyz="0.1 0 0" rpy="0.1 0 0"/>')),
        dtype=torch.float64,
    )
    T = chain.forward_kinematics(torch.zeros(0, dtype=torch.float64))["b"]
    assert T[0, 3].item() == 0.1
    assert T[1, 1].item() == math.cos(0.1) and T[2, 1].item() == math.sin(0.1)


def test_text_with_a_byte_order_mark(tmp_path):
    """URDF text (str or bytes) and files that start with a UTF-8 byte-order mark (it was taken
    for a path)."""
    text = (
        '<robot name="r"><link name="a"/><link name="b"/><joint name="j" type="continuous">'
        '<parent link="a"/><child link="b"/></joint></robot>'
    )
    path = tmp_path / "bom.urdf"
    path.write_bytes(("\ufeff" + text).encode("utf-8"))
    for source in ("\ufeff" + text, ("\ufeff" + text).encode("utf-8"), path):
        assert parse_urdf(source).joints[0].name == "j"
