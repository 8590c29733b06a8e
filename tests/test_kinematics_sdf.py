"""SDF chains: link poses against an independent float64 evaluation of the SDFormat frame rules
(written here with numpy and scipy, joint by joint: ``X_M_child(q) = X_M_parent(q) X_PJ M(q)
X_JC``) and against pytorch-kinematics' SDF loader, on hand-written files and on the Cassie
SDFs shipped by example-robot-data; and every kind of unsupported file.

pytorch-kinematics departs from the specification in ways the tests below state: it ignores a
joint's ``<pose>`` (it turns every joint about the child link's origin), reads the axis in the
child link's frame whatever ``expressed_in`` or ``use_parent_model_frame`` say, takes
``relative_to`` and ``<frame>`` as absent, applies a link's ``roll pitch yaw`` as
``Rz(roll) Ry(pitch) Rx(yaw)``, needs an ``<inertial>`` in every link and ``<mesh><filename>``
instead of ``<uri>``, and cannot read ball joints or loops.  It is compared where none of these
applies (the specification and it then agree), within ``1e-5`` (it computes in float32).
"""

from __future__ import annotations

import math
import re
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from torchlie.kinematics import Chain
from torchlie.kinematics.sdf import SDFError, parse_sdf

CASSIE = Path(sys.prefix) / "lib"  # replaced below by the installed folder, when there is one


def cassie_files() -> list[Path]:
    import importlib.util

    spec = importlib.util.find_spec("cmeel")
    roots = [Path(p).parent for p in (spec.submodule_search_locations or [])] if spec else []
    for root in roots:
        d = root / "cmeel.prefix/share/example-robot-data/robots/cassie_description/robots"
        if d.is_dir():
            return sorted(d.glob("*.sdf"))
    return []


# ----------------------------------------------------------------------------------------------
# The independent reference
# ----------------------------------------------------------------------------------------------


def _pose(el) -> np.ndarray:
    T = np.eye(4)
    if el is None or not (el.text or "").split():
        return T
    v = [float(x) for x in el.text.split()]
    if el.get("rotation_format") == "quat_xyzw":
        T[:3, :3] = Rotation.from_quat(v[3:]).as_matrix()
    else:
        ang = np.radians(v[3:]) if el.get("degrees") == "true" else v[3:]
        T[:3, :3] = Rotation.from_euler("xyz", ang).as_matrix()  # extrinsic: Rz Ry Rx
    T[:3, 3] = v[:3]
    return T


def reference_poses(xml: str, values: dict[str, object]) -> dict[str, np.ndarray]:
    """Every link's pose in the model frame; ``values``: joint name -> angle, displacement
    or quaternion ``(w, x, y, z)`` (missing: zero / identity).  Loop joints: first supported
    parent joint of each link in document order.  The axis frame by ``<sdf version>``: 1.4
    the model frame, 1.5-1.6 the joint frame or the model frame by ``use_parent_model_frame``,
    1.7+ the joint frame or ``expressed_in``; before 1.7 a joint and a link may share a name."""
    root = ET.fromstring(xml)
    version = tuple(int(x) for x in root.get("version", "1.7").split("."))
    model = root.find("model")
    if model is None:
        model = root.find("world").find("model")
    rel, pose, joint_rel, joint_pose = {}, {}, {}, {}
    for el in model.findall("link"):
        p = el.find("pose")
        rel[el.get("name")] = (p.get("relative_to") if p is not None else None) or "__model__"
        pose[el.get("name")] = _pose(p)
    for el in model.findall("joint"):
        p = el.find("pose")
        joint_rel[el.get("name")] = (
            p.get("relative_to") if p is not None else None
        ) or el.findtext("child").strip()
        joint_pose[el.get("name")] = _pose(p)
        if el.get("name") not in rel:
            rel[el.get("name")] = joint_rel[el.get("name")]
            pose[el.get("name")] = joint_pose[el.get("name")]
    for el in model.findall("frame"):
        p = el.find("pose")
        rel[el.get("name")] = (p.get("relative_to") if p is not None else None) or (
            el.get("attached_to") or "__model__"
        )
        pose[el.get("name")] = _pose(p)

    def X0(name: str) -> np.ndarray:
        if name in ("__model__", "world"):
            return np.eye(4)
        return X0(rel[name]) @ pose[name]

    tree = {}
    for el in model.findall("joint"):
        child = el.findtext("child").strip()
        if el.get("type") in ("revolute", "continuous", "prismatic", "fixed", "ball"):
            tree.setdefault(child, el)
    out: dict[str, np.ndarray] = {}

    def X(link: str) -> np.ndarray:
        if link in ("world", "__model__"):
            return np.eye(4)
        if link in out:
            return out[link]
        el = tree.get(link)
        if el is None:
            out[link] = X0(link)
            return out[link]
        name, jtype = el.get("name"), el.get("type")
        parent = el.findtext("parent").strip()
        XP0, XJ0, XC0 = X0(parent), X0(joint_rel[name]) @ joint_pose[name], X0(link)
        M = np.eye(4)
        if jtype in ("revolute", "continuous", "prismatic"):
            axis_el = el.find("axis")
            xyz_el = axis_el.find("xyz") if axis_el is not None else None
            a = (
                np.array([float(x) for x in xyz_el.text.split()])
                if xyz_el is not None
                else [0, 0, 1]
            )
            expressed = xyz_el.get("expressed_in") if xyz_el is not None else None
            upm = axis_el.findtext("use_parent_model_frame") if axis_el is not None else None
            if upm is not None and version < (1, 7):
                model_frame = upm.strip() in ("1", "true")
            else:
                model_frame = version < (1, 5) and not expressed
            if model_frame:
                R_MF = np.eye(3)
            elif expressed:
                R_MF = X0(expressed)[:3, :3]
            else:
                R_MF = XJ0[:3, :3]
            a_J = XJ0[:3, :3].T @ R_MF @ a
            a_J = a_J / np.linalg.norm(a_J)
            v = float(values.get(name, 0.0))
            if jtype == "prismatic":
                M[:3, 3] = v * a_J
            else:
                M[:3, :3] = Rotation.from_rotvec(v * a_J).as_matrix()
        elif jtype == "ball":
            w, x, y, z = values.get(name, (1.0, 0.0, 0.0, 0.0))
            M[:3, :3] = Rotation.from_quat([x, y, z, w]).as_matrix()
        X_PJ = np.linalg.solve(XP0, XJ0)
        X_JC = np.linalg.solve(XJ0, XC0)
        out[link] = X(parent) @ X_PJ @ M @ X_JC
        return out[link]

    return {el.get("name"): X(el.get("name")) for el in model.findall("link")}


def values_of(chain: Chain, q: torch.Tensor) -> dict[str, object]:
    """Chain's ``q`` as joint name -> value (quaternions for ball joints)."""
    out: dict[str, object] = {}
    names = chain.joint_names
    for k, n in enumerate(names):
        base, _, sfx = n.rpartition(":")
        if sfx == "qw":
            out[base] = tuple(float(x) for x in q[k : k + 4])
        elif sfx not in ("qx", "qy", "qz"):
            out[n] = float(q[k])
    return out


def compare(xml: str, *, loops: str = "error", n: int = 5, seed: int = 0) -> float:
    chain = Chain.from_sdf(xml, loops=loops, dtype=torch.float64)
    q = chain.random_configuration(n, generator=torch.Generator().manual_seed(seed))
    T = chain.forward_kinematics(q)
    worst = 0.0
    for b in range(n):
        ref = reference_poses(xml, values_of(chain, q[b]))
        for link, X in ref.items():
            worst = max(worst, float(np.abs(T[link][b].numpy() - X).max()))
    return worst


# ----------------------------------------------------------------------------------------------
# Hand-written files
# ----------------------------------------------------------------------------------------------

FRAMES = """<sdf version="1.8"><model name="frames">
  <pose>5 5 5 0 0 1</pose>
  <frame name="mount" attached_to="base"><pose>0.1 0 0.2 0 0.3 0</pose></frame>
  <link name="base"><pose>0 0 0.5 0.1 0.2 0.3</pose></link>
  <link name="upper"><pose relative_to="mount">0 0.1 0.3 0.4 0 -0.2</pose></link>
  <link name="lower"><pose relative_to="upper">0.4 0 0 0 0 0.5</pose></link>
  <link name="slider"><pose relative_to="lower" degrees="true">0 0 -0.2 10 20 30</pose></link>
  <link name="tool">
    <pose relative_to="slider" rotation_format="quat_xyzw">0 0 0.1 0 0 0.6 0.8</pose></link>
  <joint name="shoulder" type="revolute"><parent>base</parent><child>upper</child>
    <pose>0.05 -0.02 0.1 0.3 0.2 0.1</pose>
    <axis><xyz expressed_in="__model__">0 1 1</xyz>
      <limit><lower>-2</lower><upper>2</upper></limit></axis>
  </joint>
  <joint name="elbow" type="continuous"><parent>upper</parent><child>lower</child>
    <pose relative_to="upper">0.4 0 0 0 0 0</pose><axis><xyz expressed_in="mount">1 0 0</xyz></axis>
  </joint>
  <joint name="slide" type="prismatic"><parent>lower</parent><child>slider</child>
    <axis><xyz>0 0 1</xyz><limit><lower>-0.1</lower><upper>0.3</upper></limit></axis></joint>
  <joint name="wrist" type="ball"><parent>slider</parent><child>tool</child>
    <pose>0.02 0 0.05 0.5 0 0</pose></joint>
</model></sdf>"""

OLD_STYLE = """<sdf version="1.6"><world name="w"><model name="old">
  <link name="a"><pose>0 0 1 0 0 0.7</pose></link>
  <link name="b"><pose>0.3 0 1 0.2 0.5 0</pose></link>
  <link name="c"><pose>0.6 0.1 1 0 0 0</pose></link>
  <joint name="fix" type="fixed"><parent>world</parent><child>a</child></joint>
  <joint name="j1" type="revolute"><parent>a</parent><child>b</child><pose>0 0 0.1 0 0 0</pose>
    <axis><xyz>0 0 1</xyz><use_parent_model_frame>1</use_parent_model_frame>
    <limit><lower>-1</lower><upper>1</upper></limit></axis></joint>
  <joint name="j2" type="revolute"><parent>b</parent><child>c</child>
    <axis><xyz>1 0 0</xyz></axis></joint>
</model></world></sdf>"""


@pytest.mark.parametrize("xml", [FRAMES, OLD_STYLE], ids=["frames", "old_style"])
def test_hand_written_against_reference(xml):
    assert compare(xml, n=6) <= 1e-12


def test_roots_names_and_limits():
    chain = Chain.from_sdf(FRAMES)
    assert chain.root == "__model__" and chain.link_names[0] == "__model__"
    assert chain.joint_names == ("shoulder", "elbow", "slide", *(f"wrist:q{c}" for c in "wxyz"))
    assert chain.velocity_names[-3:] == ("wrist:wx", "wrist:wy", "wrist:wz")
    assert (
        chain.lower[0] == -2 and math.isinf(chain.lower[1]) and chain.upper[2] == pytest.approx(0.3)
    )
    old = Chain.from_sdf(OLD_STYLE)
    assert old.root == "world" and old.joint_names == ("j1", "j2")
    assert parse_sdf(OLD_STYLE).joint("j2").type == "continuous"  # no <limit>: SDF's none


def test_sdf_inertials_are_not_read_and_forward_dynamics_says_so():
    chain = Chain.from_sdf(FRAMES, dtype=torch.float64)
    ins = chain.inertials
    assert not ins.mass.any() and not ins.inertia.any()
    q = chain.random_configuration(2, generator=torch.Generator().manual_seed(0))
    v = torch.zeros(2, chain.n_v, dtype=torch.float64)
    with pytest.raises(ValueError, match="a chain from SDF, whose inertials are not read"):
        chain.forward_dynamics(q, v, v)


def test_sdf_jacobian_matches_autograd():
    chain = Chain.from_sdf(FRAMES, dtype=torch.float64)
    q = chain.random_configuration(generator=torch.Generator().manual_seed(3))[:3]
    q = torch.cat((q, torch.tensor([1.0, 0, 0, 0], dtype=torch.float64)))
    J = chain.jacobian(q, "lower")

    def pos(x):
        return chain.forward_kinematics(torch.cat((x, q[3:])), "lower")["lower"][:3, 3]

    Jp = torch.autograd.functional.jacobian(pos, q[:3])
    assert torch.allclose(J[:3, :3], Jp, atol=1e-12)


def test_file_path_and_world(tmp_path):
    path = tmp_path / "robot.sdf"
    path.write_text(OLD_STYLE)
    assert Chain.from_sdf(path).joint_names == Chain.from_sdf(str(path)).joint_names


# ----------------------------------------------------------------------------------------------
# Cassie (example-robot-data) and pytorch-kinematics
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("path", cassie_files(), ids=lambda p: p.stem)
def test_cassie_against_reference(path):
    xml = path.read_text()
    with pytest.raises(SDFError, match="kinematic loop"):
        Chain.from_sdf(path)
    assert compare(xml, loops="skip", n=4, seed=1) <= 1e-12


def for_pk(xml: str, chain: Chain) -> str:
    """A copy pytorch-kinematics can read: no visuals or collisions, an inertial in every
    link, only the chain's tree joints, ball joints made fixed."""
    root = ET.fromstring(xml)
    model = root.find("model") if root.find("model") is not None else root.find("world/model")
    keep = {j.name for j in chain.spec.joints}
    for link in model.findall("link"):
        for tag in ("visual", "collision", "sensor"):
            for el in link.findall(tag):
                link.remove(el)
        if link.find("inertial") is None:
            inertial = ET.SubElement(link, "inertial")
            ET.SubElement(inertial, "mass").text = "1"
            inertia = ET.SubElement(inertial, "inertia")
            for k in ("ixx", "iyy", "izz"):
                ET.SubElement(inertia, k).text = "1"
            for k in ("ixy", "ixz", "iyz"):
                ET.SubElement(inertia, k).text = "0"
    for el in model.findall("joint"):
        if el.get("name") not in keep:
            model.remove(el)
        elif el.get("type") == "ball":
            el.set("type", "fixed")
    for el in model.findall("plugin"):
        model.remove(el)
    return re.sub(r"<\?xml[^>]*\?>", "", ET.tostring(root, encoding="unicode"))


def test_pytorch_kinematics_agrees_where_it_follows_the_specification():
    pk = pytest.importorskip("pytorch_kinematics")
    # Joint frames at the child links, axes in the child frames, no rotated link poses: the
    # cases pytorch-kinematics reads as the specification says.
    xml = """<sdf version="1.7"><model name="m">
      <link name="a"/><link name="b"><pose>0 0 0.5 0 0 0</pose></link>
      <link name="c"><pose>0.3 0 0.5 0 0 0</pose></link>
      <link name="d"><pose>0.3 0.2 0.5 0 0 0</pose></link>
      <joint name="j1" type="revolute"><parent>a</parent><child>b</child>
        <axis><xyz>0 0 1</xyz><limit><lower>-2</lower><upper>2</upper></limit></axis></joint>
      <joint name="j2" type="revolute"><parent>b</parent><child>c</child>
        <axis><xyz>0 1 0</xyz><limit><lower>-2</lower><upper>2</upper></limit></axis></joint>
      <joint name="j3" type="prismatic"><parent>c</parent><child>d</child>
        <axis><xyz>1 0 0</xyz><limit><lower>-0.2</lower><upper>0.2</upper></limit></axis></joint>
    </model></sdf>"""
    chain = Chain.from_sdf(xml, dtype=torch.float64)
    pkc = pk.build_chain_from_sdf(for_pk(xml, chain)).to(dtype=torch.float64)
    assert tuple(pkc.get_joint_parameter_names()) == chain.joint_names
    q = chain.random_configuration(16, generator=torch.Generator().manual_seed(0))
    T, T_pk = chain.forward_kinematics(q), pkc.forward_kinematics(q)
    for link in ("b", "c", "d"):
        assert torch.allclose(T[link], T_pk[link].get_matrix(), atol=1e-5)


def test_pytorch_kinematics_departs_on_joint_poses():
    """A joint frame away from the child's origin: pytorch-kinematics turns about the child's
    origin, the specification (and the reference) about the joint's."""
    pk = pytest.importorskip("pytorch_kinematics")
    xml = """<sdf version="1.7"><model name="m">
      <link name="a"/><link name="b"><pose>0 0 0.5 0 0 0</pose></link>
      <joint name="j" type="revolute"><parent>a</parent><child>b</child>
        <pose>0.2 0 0 0 0 0</pose>
        <axis><xyz>0 0 1</xyz><limit><lower>-2</lower><upper>2</upper></limit></axis></joint>
    </model></sdf>"""
    chain = Chain.from_sdf(xml, dtype=torch.float64)
    pkc = pk.build_chain_from_sdf(for_pk(xml, chain)).to(dtype=torch.float64)
    q = torch.tensor([[1.0]], dtype=torch.float64)
    ours = chain.forward_kinematics(q, "b")["b"][0]
    ref = reference_poses(xml, {"j": 1.0})["b"]
    assert np.abs(ours.numpy() - ref).max() <= 1e-12
    theirs = pkc.forward_kinematics(q)["b"].get_matrix()[0]
    assert (theirs[:3, 3] - ours[:3, 3]).abs().max() > 0.1  # it turned about the child origin


def test_pytorch_kinematics_swaps_roll_and_yaw():
    pk = pytest.importorskip("pytorch_kinematics")
    xml = """<sdf version="1.7"><model name="m">
      <link name="a"/><link name="b"><pose>0 0 0 0.1 0.2 0.3</pose></link>
      <joint name="j" type="fixed"><parent>a</parent><child>b</child>
        <axis><xyz>0 0 1</xyz></axis></joint>
    </model></sdf>"""
    chain = Chain.from_sdf(xml, dtype=torch.float64)
    pkc = pk.build_chain_from_sdf(for_pk(xml, chain)).to(dtype=torch.float64)
    ours = chain.forward_kinematics(torch.zeros(0, dtype=torch.float64), "b")["b"][:3, :3]
    theirs = pkc.forward_kinematics(torch.zeros(0, dtype=torch.float64))["b"].get_matrix()[0]
    spec = Rotation.from_euler("xyz", [0.1, 0.2, 0.3]).as_matrix()  # Rz(yaw) Ry(pitch) Rx(roll)
    swapped = Rotation.from_euler("xyz", [0.3, 0.2, 0.1]).as_matrix()
    assert np.abs(ours.numpy() - spec).max() <= 1e-15
    assert np.abs(theirs[:3, :3].numpy() - swapped).max() <= 1e-6


@pytest.mark.parametrize("path", cassie_files()[:1], ids=lambda p: p.stem)
def test_cassie_pytorch_kinematics_at_zero(path):
    """On Cassie pytorch-kinematics reads axes in the child frames (the file says the model
    frame) and ignores joint poses, so it is compared at the zero configuration only, where
    neither matters (its copy without ball joints and loops): every link's position, and the
    rotation of the links whose ``roll == yaw`` (it swaps the two)."""
    pk = pytest.importorskip("pytorch_kinematics")
    xml = path.read_text()
    chain = Chain.from_sdf(xml, loops="skip", dtype=torch.float64)
    pkc = pk.build_chain_from_sdf(for_pk(xml, chain)).to(dtype=torch.float64)
    T = chain.forward_kinematics(_identity_q(chain))
    T_pk = pkc.forward_kinematics(
        torch.zeros(len(pkc.get_joint_parameter_names()), dtype=torch.float64)
    )
    model = ET.fromstring(xml).find("model")
    swapped = 0
    for el in model.findall("link"):
        link = el.get("name")
        M = T_pk[link].get_matrix()[0]
        assert torch.allclose(T[link][:3, 3], M[:3, 3], atol=1e-5), link
        rpy = [float(x) for x in (el.findtext("pose") or "0 0 0 0 0 0").split()][3:]
        if abs(rpy[0] - rpy[2]) < 1e-12:
            assert torch.allclose(T[link][:3, :3], M[:3, :3], atol=1e-5), link
        else:
            swapped += 1
            assert not torch.allclose(T[link][:3, :3], M[:3, :3], atol=1e-5), link
    assert swapped < len(chain.link_names) - 1


def _identity_q(chain: Chain) -> torch.Tensor:
    q = torch.zeros(chain.n_dof, dtype=chain.dtype)
    for k, n in enumerate(chain.joint_names):
        if n.endswith(":qw"):
            q[k] = 1.0
    return q


# ----------------------------------------------------------------------------------------------
# Unsupported and malformed files
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "xml, match",
    [
        ('<sdf><model name="a"><link name="x"/></model><model name="b"/></sdf>', "several models"),
        ('<sdf><world name="w"><include><uri>model://m</uri></include></world></sdf>', "include"),
        ('<sdf><model name="a"><model name="n"/></model></sdf>', "nested models"),
        ('<sdf><model name="a"><include><uri>model://m</uri></include></model></sdf>', "include"),
        (
            '<sdf><model name="a"><link name="x"/><link name="y"/><joint name="j" type="screw">'
            "<parent>x</parent><child>y</child></joint></model></sdf>",
            "'screw' is not supported",
        ),
        (
            '<sdf><model name="a"><link name="x"/><joint name="j" type="fixed">'
            "<parent>x</parent><child>z</child></joint></model></sdf>",
            "'z' is not a link",
        ),
        (
            '<sdf><model name="a"><link name="x"><pose relative_to="nope"/></link></model></sdf>',
            "unknown frame 'nope'",
        ),
        ('<sdf><model name="a"><link name="x"><pose>1 2</pose></link></model></sdf>', "6 numbers"),
        ("<robot/>", "must be <sdf>"),
        ("<sdf><model", "not well-formed"),
    ],
)
def test_unsupported_files_raise(xml, match):
    with pytest.raises(SDFError, match=match):
        Chain.from_sdf(xml)


# ----------------------------------------------------------------------------------------------
# python -m torchlie.kinematics.validate on SDF
# ----------------------------------------------------------------------------------------------


def test_validate_command_takes_sdf(tmp_path, capsys):
    from torchlie.kinematics._sdf_validate import joint_values, sdf_reference_poses
    from torchlie.kinematics.validate import main

    path = tmp_path / "robot.sdf"
    path.write_text(FRAMES)
    assert main([str(path), "--samples", "10"]) == 0
    text = capsys.readouterr().out
    assert "PASS" in text and "tool" in text
    assert main([str(path), "--samples", "4", "--dtype", "float32"]) == 0
    # the format is the root element's, after a header of any length
    headed = tmp_path / "headed.sdf"
    headed.write_text('<?xml version="1.0"?>\n<!-- ' + "licence " * 1000 + "-->\n" + FRAMES)
    assert main([str(headed), "--samples", "4"]) == 0
    assert "PASS" in capsys.readouterr().out
    # The validation's reference agrees with this file's (scipy) one.
    chain = Chain.from_sdf(FRAMES, dtype=torch.float64)
    q = chain.random_configuration(generator=torch.Generator().manual_seed(6)).numpy()
    ours = sdf_reference_poses(FRAMES, joint_values(chain.dof_joints, q))
    theirs = reference_poses(FRAMES, values_of(chain, torch.from_numpy(q)))
    assert max(float(np.abs(ours[n] - theirs[n]).max()) for n in theirs) <= 1e-13
    loop = tmp_path / "loop.sdf"
    loop.write_text(
        '<sdf version="1.7"><model name="m"><link name="a"/><link name="b"/><link name="c"/>'
        '<joint name="j1" type="revolute"><parent>a</parent><child>b</child></joint>'
        '<joint name="j2" type="revolute"><parent>a</parent><child>c</child></joint>'
        '<joint name="j3" type="ball"><parent>b</parent><child>c</child></joint>'
        "</model></sdf>"
    )
    assert main([str(loop)]) == 2
    err = capsys.readouterr().err
    assert str(loop) in err and "kinematic loop" in err
    assert main([str(loop), "--loops", "skip", "--samples", "3"]) == 0


def test_validate_reads_the_joints_values_by_their_types_not_their_names(tmp_path, capsys):
    """A revolute joint named 'w:qw' is one value, not a ball joint's quaternion."""
    from torchlie.kinematics.validate import main

    path = tmp_path / "named.sdf"
    path.write_text(
        '<sdf version="1.7"><model name="m"><link name="a"/><link name="b"/><link name="c"/>'
        '<link name="d"/><joint name="w:qw" type="revolute"><parent>a</parent><child>b</child>'
        '<axis><xyz>0 0 1</xyz></axis></joint><joint name="k" type="ball"><parent>b</parent>'
        '<child>c</child></joint><link name="e"><pose>1 0 0 0 0 0</pose></link>'
        '<joint name="m:x" type="prismatic"><parent>c</parent><child>d</child>'
        '<axis><xyz>1 0 0</xyz></axis></joint><joint name="f" type="fixed"><parent>d'
        "</parent><child>e</child></joint></model></sdf>"
    )
    assert main([str(path), "--samples", "10"]) == 0
    assert "PASS" in capsys.readouterr().out


def test_old_frame_attribute_is_relative_to():
    old = FRAMES.replace('relative_to="upper">0.4', 'frame="upper">0.4')
    assert old != FRAMES
    a = Chain.from_sdf(FRAMES, dtype=torch.float64)
    b = Chain.from_sdf(old, dtype=torch.float64)
    q = a.random_configuration(3, generator=torch.Generator().manual_seed(2))
    torch.testing.assert_close(
        a.forward_kinematics(q, stacked=True), b.forward_kinematics(q, stacked=True)
    )


# ----------------------------------------------------------------------------------------------
# SDFormat versions, limits, encodings
# ----------------------------------------------------------------------------------------------


def _rotated_child(version: str, axis: str = "<xyz>1 0 0</xyz>") -> str:
    """A prismatic joint whose child link (and so joint frame) is turned 90 degrees about z."""
    head = f'<sdf version="{version}">' if version else "<sdf>"
    return (
        f'{head}<model name="m"><link name="a"/>'
        '<link name="b"><pose>0 0 0 0 0 1.5707963267948966</pose></link>'
        '<joint name="j" type="prismatic"><parent>a</parent><child>b</child>'
        f"<axis>{axis}<limit><lower>-1</lower><upper>1</upper></limit></axis></joint>"
        "</model></sdf>"
    )


UPM = "<xyz>1 0 0</xyz><use_parent_model_frame>{}</use_parent_model_frame>"


@pytest.mark.parametrize(
    "version, axis, along_model_x",
    [
        ("1.4", "<xyz>1 0 0</xyz>", True),  # 1.4: the axis is in the model frame
        ("1.4", UPM.format("false"), False),
        ("1.5", "<xyz>1 0 0</xyz>", False),  # 1.5-1.6: the joint frame ...
        ("1.6", "<xyz>1 0 0</xyz>", False),
        ("1.6", UPM.format("true"), True),  # ... unless use_parent_model_frame
        ("1.7", "<xyz>1 0 0</xyz>", False),  # 1.7+: the joint frame ...
        ("1.9", '<xyz expressed_in="__model__">1 0 0</xyz>', True),  # ... unless expressed_in
        ("1.7", UPM.format("false"), False),
        ("", "<xyz>1 0 0</xyz>", False),  # no version: the 1.7+ rules
    ],
)
def test_axis_frame_follows_the_sdf_version(version, axis, along_model_x):
    from torchlie.kinematics._sdf_validate import sdf_reference_poses

    xml = _rotated_child(version, axis)
    chain = Chain.from_sdf(xml, dtype=torch.float64)
    p = chain.forward_kinematics(torch.tensor([0.5], dtype=torch.float64), "b")["b"][:3, 3]
    want = [0.5, 0.0, 0.0] if along_model_x else [0.0, 0.5, 0.0]
    np.testing.assert_allclose(p.numpy(), want, atol=1e-15)
    for ref in (reference_poses, sdf_reference_poses):  # both references apply the same rule
        np.testing.assert_allclose(ref(xml, {"j": 0.5})["b"][:3, 3], want, atol=1e-15)


def test_old_sdf_versions_against_reference(tmp_path, capsys):
    from torchlie.kinematics.validate import main

    old = OLD_STYLE.replace("<use_parent_model_frame>1</use_parent_model_frame>", "")
    for version in ("1.4", "1.5", "1.6"):
        xml = old.replace('version="1.6"', f'version="{version}"')
        assert compare(xml, n=4) <= 1e-12
        path = tmp_path / f"m{version}.sdf"
        path.write_text(xml)
        assert main([str(path), "--samples", "4"]) == 0
    assert "PASS" in capsys.readouterr().out


def test_use_parent_model_frame_is_refused_from_sdf_1_7():
    with pytest.raises(SDFError, match=r"<joint name='j'> <axis> <use_parent_model_frame>.*1\.7"):
        Chain.from_sdf(_rotated_child("1.7", UPM.format("true")))
    with pytest.raises(SDFError, match=r"<sdf version='one'>"):
        Chain.from_sdf(_rotated_child("one"))


def test_link_and_joint_may_share_a_name_before_sdf_1_7():
    xml = (
        '<sdf version="1.6"><model name="m"><link name="a"/>'
        '<link name="b"><pose>1 0 0 0 0 0.5</pose></link>'
        '<joint name="b" type="revolute"><parent>a</parent><child>b</child>'
        "<pose>0 0.2 0 0 0 0</pose><axis><xyz>0 1 0</xyz>"
        "<limit><lower>-1</lower><upper>1</upper></limit></axis></joint></model></sdf>"
    )
    chain = Chain.from_sdf(xml, dtype=torch.float64)
    assert chain.joint_names == ("b",) and chain.link_names[-1] == "b"
    assert compare(xml, n=4) <= 1e-12
    with pytest.raises(SDFError, match="<joint name='b'>: the name 'b' is already taken"):
        Chain.from_sdf(xml.replace('version="1.6"', 'version="1.7"'))
    with pytest.raises(SDFError, match="<link name='a'>: the name 'a' is already taken"):
        Chain.from_sdf(xml.replace('<link name="b">', '<link name="a">'))  # same type


def test_world_include_next_to_a_model_raises():
    xml = (
        '<sdf version="1.7"><world name="w"><include><uri>model://robot</uri></include>'
        '<model name="ground"><static>true</static><link name="g"/></model></world></sdf>'
    )
    with pytest.raises(SDFError, match=r"<world name='w'> <include>: models included by URI"):
        parse_sdf(xml)


def _one_joint(jtype: str, limit: str) -> str:
    return (
        '<sdf version="1.7"><model name="m"><link name="a"/><link name="b"/>'
        f'<joint name="j" type="{jtype}"><parent>a</parent><child>b</child>'
        f"<axis><xyz>0 0 1</xyz><limit>{limit}</limit></axis></joint></model></sdf>"
    )


@pytest.mark.parametrize("jtype", ["revolute", "prismatic"])
def test_one_sided_limit_is_kept(jtype):
    chain = Chain.from_sdf(_one_joint(jtype, "<lower>-0.5</lower>"), dtype=torch.float64)
    assert parse_sdf(_one_joint(jtype, "<lower>-0.5</lower>")).joint("j").type == jtype
    assert float(chain.lower[0]) == -0.5 and chain.upper[0] == math.inf
    q = chain.random_configuration(200, generator=torch.Generator().manual_seed(0))
    assert bool((q >= -0.5).all()) and bool((q <= -0.5 + 2 * math.pi).all())
    chain = Chain.from_sdf(_one_joint(jtype, "<upper>0.5</upper><lower>-1e16</lower>"))
    assert chain.lower[0] == -math.inf and float(chain.upper[0]) == 0.5
    q = chain.random_configuration(200, generator=torch.Generator().manual_seed(0))
    assert bool((q <= 0.5).all()) and bool((q >= 0.5 - 2 * math.pi).all())
    assert parse_sdf(_one_joint(jtype, "")).joint("j").type == (
        "continuous" if jtype == "revolute" else "prismatic"
    )


@pytest.mark.parametrize(
    "limit, match",
    [
        ("<lower>1</lower><upper>-1</upper>", r"<lower> 1\.0 is above <upper> -1\.0"),
        ("<lower>1 2</lower><upper>3</upper>", "<lower> must be one number, got '1 2'"),
        ("<lower>0</lower><upper>1 2</upper>", "<upper> must be one number"),
    ],
)
def test_bad_limits_raise_naming_the_joint(limit, match):
    with pytest.raises(SDFError, match=r"<joint name='j'> <axis> <limit>: " + match):
        parse_sdf(_one_joint("prismatic", limit))


@pytest.mark.parametrize(
    ("inner", "match"),
    [
        (
            '<parent>a</parent><child>b</child><pose rotation_format="quat_xyzw">'
            "0 0 0 0 0 0 0</pose>",
            r"<joint name='j'> <pose>: the quaternion .* is zero",
        ),
        ("<parent>a</parent><child>a</child>", r"<joint name='j'>: link 'a' is both its <parent>"),
    ],
    ids=["zero_quaternion", "own_parent"],
)
def test_bad_joint_raises_naming_it(inner, match):
    xml = (
        '<sdf version="1.7"><model name="m"><link name="a"/><link name="b"/>'
        f'<joint name="j" type="revolute">{inner}</joint></model></sdf>'
    )
    with pytest.raises(SDFError, match=match):
        parse_sdf(xml)


def test_byte_order_mark_and_declared_encodings(tmp_path):
    xml = '<sdf version="1.7"><model name="m\xe9"><link name="a"/></model></sdf>'
    assert parse_sdf(("\ufeff" + xml).encode("utf-8")).name == "m\xe9"
    assert parse_sdf("\ufeff" + xml).name == "m\xe9"  # open(f).read() of such a file
    latin = '<?xml version="1.0" encoding="ISO-8859-1"?>\n' + xml
    path = tmp_path / "latin.sdf"
    path.write_bytes(latin.encode("latin-1"))
    assert parse_sdf(path).name == parse_sdf(latin.encode("latin-1")).name == "m\xe9"
    from torchlie.kinematics.validate import main

    assert main([str(path), "--samples", "2"]) == 0  # its reference reads the file alike
    bom = tmp_path / "bom.sdf"
    bom.write_bytes(("\ufeff" + xml).encode("utf-8"))
    assert parse_sdf(bom).name == "m\xe9"
    with pytest.raises(SDFError, match="unknown encoding: nope"):
        parse_sdf(latin.replace("ISO-8859-1", "nope").encode("latin-1"))
    path.write_bytes(xml.encode("latin-1"))  # undeclared, not UTF-8
    with pytest.raises(SDFError, match=f"{re.escape(str(path))}: <sdf>: not well-formed"):
        parse_sdf(path)


def test_degrees_are_exact_at_multiples_of_90():
    xml = (
        '<sdf version="1.7"><model name="m">'
        '<link name="a"><pose degrees="true">0 0 0 90 -180 450</pose></link>'
        '<link name="b"><pose degrees="true">0 0 0 30 0 0</pose></link></model></sdf>'
    )
    chain = Chain.from_sdf(xml, dtype=torch.float64)
    T = chain.forward_kinematics(torch.zeros(0, dtype=torch.float64))
    R = T["a"][:3, :3]
    assert set(R.flatten().tolist()) <= {0.0, 1.0, -1.0}
    torch.testing.assert_close(
        R, torch.tensor(Rotation.from_euler("xyz", [90, -180, 450], degrees=True).as_matrix())
    )
    torch.testing.assert_close(
        T["b"][:3, :3],
        torch.tensor(Rotation.from_euler("x", 30, degrees=True).as_matrix()),
        rtol=0,
        atol=2e-16,
    )
