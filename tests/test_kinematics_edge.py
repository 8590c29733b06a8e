"""Kinematics at the edges: empty batches, robots without DoF, bad arguments, extreme and
malformed URDF numbers, hostile names, and robots with thousands of links or joints."""

from __future__ import annotations

import pytest
import torch
from torchlie.kinematics import Chain, URDFError, parse_urdf, sample_robot

F64 = torch.float64


def robot(body: str, links: tuple[str, ...] = ("a", "b")) -> str:
    return (
        '<robot name="r">'
        + "".join(f'<link name="{n}"/>' for n in links)
        + body
        + "</robot>"
    )


def joint(name="j", jtype="revolute", parent="a", child="b", inner="") -> str:
    limit = (
        '<limit lower="-1" upper="1"/>' if jtype in ("revolute", "prismatic") else ""
    )
    return (
        f'<joint name="{name}" type="{jtype}"><parent link="{parent}"/>'
        f'<child link="{child}"/>{inner}{limit}</joint>'
    )


FIXED_ONLY = robot(
    joint("m", "fixed", "a", "b", '<origin xyz="1 2 3"/>')
    + joint("t", "fixed", "b", "c"),
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


# ----------------------------------------------------------------------------------------------
# Robots without degrees of freedom
# ----------------------------------------------------------------------------------------------


# ----------------------------------------------------------------------------------------------
# Bad arguments
# ----------------------------------------------------------------------------------------------


# ----------------------------------------------------------------------------------------------
# Extreme numbers
# ----------------------------------------------------------------------------------------------


# ----------------------------------------------------------------------------------------------
# Number syntax: XML Schema double, nothing else
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "value"),
    [("1", 1.0), ("-1", -1.0), ("+1", 1.0), ("1.", 1.0), (".5", 0.5), ("-.5e-3", -0.0005),
     ("1E+2", 100.0), ("007", 7.0), ("0.1", 0.1), (" \t2.5\n", 2.5)],
)  # fmt: skip
def test_numbers_in_xml_schema_double_syntax_are_read(text, value):
    spec = parse_urdf(
        robot(joint("j", "revolute").replace('upper="1"', f'upper="{text}"'))
    )
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
        parse_urdf(
            robot(joint(inner='<origin xyz="1\u20032 3"/>'))
        )  # em space: not XML's


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
    assert (
        "\n" not in str(info.value)
        and "'p\\nq' -> 'r' -> 'p\\nq'" in info.value.problem
    )
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


def _geometric_jacobian(chain: Chain, q: torch.Tensor, n: int) -> torch.Tensor:
    """Column by column from the poses: (a_k x (p_end - p_k); a_k) for revolute joint k."""
    T = chain.forward_kinematics(q, [f"l{k}" for k in range(1, n + 1)], stacked=True)
    a = T[..., :3, :3] @ torch.tensor([0.0, 0.6, 0.8], dtype=q.dtype)  # (B, n, 3)
    p = T[..., :3, 3]
    lin = torch.linalg.cross(a, p[..., -1:, :] - p, dim=-1)
    return torch.cat((lin, a), dim=-1).transpose(-1, -2)  # (B, 6, n)
