"""MJCF chains against MuJoCo itself: poses of every body (``mj_kinematics``: ``xpos``,
``xquat``) and Jacobians (``mj_jacBody``) at random ``qpos``, on the robot models shipped inside
installed packages and on small hand-written files covering each joint feature.

The packages (robosuite, gymnasium-robotics, metaworld, dm-control, gymnasium, mujoco) are only
folders of XML files here: they are located with ``importlib.util.find_spec`` without being
imported (their imports pull in heavy or conflicting dependencies), and a missing one is skipped.

Tolerances: float64 poses and Jacobians within ``1e-12`` (positions relative to the model's
size, at least 1 m) of MuJoCo's float64 values, float32 within ``1e-5`` of the same relative
size.  Both are far above the round-off of a chain tens of joints deep (a few ``1e-15`` in
float64) and far below any error of a convention (an axis, a sign, an anchor).
"""

from __future__ import annotations

import importlib.util
import math
import os
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from torchlie import quaternion
from torchlie.kinematics import Chain

mujoco = pytest.importorskip("mujoco")

from torchlie.kinematics.mjcf import MJCFError, parse_mjcf  # noqa: E402

# Packages shipping MJCF models, and a sample of them for the normal run.
PACKAGES = ("robosuite", "gymnasium_robotics", "metaworld", "dm_control", "gymnasium", "mujoco")
SAMPLE = (
    ("gymnasium", "envs/mujoco/assets/humanoid.xml"),  # free joint, several joints per body
    ("gymnasium", "envs/mujoco/assets/ant.xml"),  # quadruped
    ("gymnasium", "envs/mujoco/assets/walker2d.xml"),  # slide + hinge root
    ("dm_control", "suite/quadruped.xml"),
    ("dm_control", "suite/humanoid_CMU.xml"),
    ("gymnasium_robotics", "envs/assets/fetch/reach.xml"),
    ("gymnasium_robotics", "envs/assets/hand/reach.xml"),  # Shadow hand
    ("metaworld", "assets/sawyer_xyz/sawyer_reach_v3.xml"),
    ("robosuite", "models/assets/grippers/robotiq_gripper_140.xml"),
    ("robosuite", "models/assets/robots/panda/robot.xml"),
)


def package_dir(name: str) -> Path | None:
    """The folder of an installed package, found without importing it (None if absent)."""
    try:
        spec = importlib.util.find_spec(name)
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(next(iter(spec.submodule_search_locations)))


def model_files(name: str) -> list[Path]:
    """Every ``.xml`` file of a package whose root element is ``<mujoco>`` (sorted)."""
    root = package_dir(name)
    if root is None:
        return []
    out = []
    for dirpath, _, files in os.walk(root):
        for f in files:
            if f.endswith(".xml"):
                p = Path(dirpath) / f
                with open(p, errors="ignore") as fh:
                    head = fh.read(4000)
                if "<mujoco" in head:
                    out.append(p)
    return sorted(out)


def reference(m, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """MuJoCo's ``xpos (B, nbody, 3)``, ``xquat (B, nbody, 4)``, and ``mj_jacBody``'s
    ``(B, nbody, 6, nv)`` (linear; angular) at each ``qpos`` row."""
    d = mujoco.MjData(m)
    B = qpos.shape[0]
    xpos = np.zeros((B, m.nbody, 3))
    xquat = np.zeros((B, m.nbody, 4))
    jac = np.zeros((B, m.nbody, 6, m.nv))
    for b in range(B):
        d.qpos[:] = qpos[b]
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        xpos[b], xquat[b] = d.xpos, d.xquat
        for i in range(m.nbody):
            mujoco.mj_jacBody(m, d, jac[b, i, :3], jac[b, i, 3:], i)
    return xpos, xquat, jac


def random_qpos(chain: Chain, n: int, seed: int) -> torch.Tensor:
    q = chain.random_configuration(n, generator=torch.Generator().manual_seed(seed))
    return q.to(torch.float64)


def quat_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Largest sign-insensitive difference between unit quaternions ``(..., 4)``."""
    return float(np.minimum(np.abs(a - b).max(-1), np.abs(a + b).max(-1)).max(initial=0.0))


def compare(
    m, n: int = 4, seed: int = 0, jacobians: bool = True, float32: bool = False
) -> dict[str, float]:
    """Errors of the float64 chain of ``m`` against MuJoCo at ``n`` random ``qpos``: position
    (relative to the model size, at least 1), rotation (quaternion), Jacobian (relative); and
    with ``float32`` the float32 chain's poses, scaled to the float64 tolerance."""
    chain = Chain.from_mjcf(m, dtype=torch.float64)
    assert chain.link_names[0] == "world" and len(chain.link_names) == m.nbody
    q = random_qpos(chain, n, seed)
    xpos, xquat, jac = reference(m, q.numpy())
    T = chain.forward_kinematics(q, stacked=True).numpy()
    scale = max(1.0, float(np.abs(xpos).max(initial=0.0)))
    quat = quaternion.from_matrix(torch.from_numpy(T[..., :3, :3])).numpy()
    err = {
        "pos": float(np.abs(T[..., :3, 3] - xpos).max(initial=0.0)) / scale,
        "rot": quat_distance(quat, xquat),
    }
    if jacobians:
        Js = chain.jacobian(q, list(chain.link_names))
        J = np.stack([Js[n].numpy() for n in chain.link_names], axis=1)
        err["jac"] = float(np.abs(J - jac).max(initial=0.0)) / scale
    if float32:  # errors of the float32 chain, divided by 1e-5 / 1e-12 (the tolerance ratio)
        T32 = chain.to(torch.float32).forward_kinematics(q.float(), stacked=True).double().numpy()
        R_ref = quaternion.to_matrix(torch.from_numpy(xquat)).numpy()
        e32 = max(
            float(np.abs(T32[..., :3, 3] - xpos).max(initial=0.0)) / scale,
            float(np.abs(T32[..., :3, :3] - R_ref).max(initial=0.0)),
        )
        err["float32"] = e32 * 1e-7
    return err


def compile_or_skip(path: Path):
    try:
        return mujoco.MjModel.from_xml_path(str(path))
    except ValueError:  # a fragment meant for <include>, or a file needing other assets
        return None


# ----------------------------------------------------------------------------------------------
# Installed models against MuJoCo
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("package, path", SAMPLE, ids=[Path(p).stem for _, p in SAMPLE])
def test_sample_models_match_mujoco(package, path):
    root = package_dir(package)
    if root is None or not (root / path).exists():
        pytest.skip(f"{package} is not installed")
    m = mujoco.MjModel.from_xml_path(str(root / path))
    err = compare(m, n=4, seed=1)
    assert max(err.values()) <= 1e-12, err


@pytest.mark.slow
def test_every_installed_model_matches_mujoco():
    files = [p for name in PACKAGES for p in model_files(name)]
    if not files:
        pytest.skip("no package with MJCF models is installed")
    checked, worst = 0, {"pos": 0.0, "rot": 0.0, "jac": 0.0, "float32": 0.0}
    for k, p in enumerate(files):
        m = compile_or_skip(p)
        if m is None:
            continue
        err = compare(m, n=2, seed=k, float32=True)
        assert max(err.values()) <= 1e-12, (str(p), err)
        worst = {key: max(worst[key], err[key]) for key in worst}
        checked += 1
    assert checked > 0


@pytest.mark.parametrize("package, path", SAMPLE[:2] + SAMPLE[4:5])
def test_float32_within_model_size(package, path):
    root = package_dir(package)
    if root is None or not (root / path).exists():
        pytest.skip(f"{package} is not installed")
    m = mujoco.MjModel.from_xml_path(str(root / path))
    chain = Chain.from_mjcf(m)  # float32
    q = random_qpos(chain, 8, 3)
    xpos, xquat, jac = reference(m, q.numpy())
    T = chain.forward_kinematics(q.float(), stacked=True).double().numpy()
    scale = max(1.0, float(np.abs(xpos).max()))
    assert np.abs(T[..., :3, 3] - xpos).max() <= 1e-5 * scale
    assert np.abs(T[..., :3, :3] - xmat(xquat)).max() <= 1e-5


def xmat(xquat: np.ndarray) -> np.ndarray:
    return quaternion.to_matrix(torch.from_numpy(xquat)).numpy()


# ----------------------------------------------------------------------------------------------
# Hand-written models: one feature each
# ----------------------------------------------------------------------------------------------

HINGE_SLIDE = """
<mujoco><compiler angle="radian"/><worldbody>
  <body name="base" pos="0.1 0.2 0.3" quat="0.9 0.1 -0.3 0.2">
    <joint name="h" type="hinge" pos="0.05 -0.1 0.2" axis="1 2 3" ref="0.4" range="-1 2"/>
    <joint name="s" type="slide" axis="0 1 1" ref="-0.2" range="-0.5 0.5"/>
    <joint name="h2" type="hinge" pos="0 0.3 0" axis="0 0 1"/>
    <geom size="0.1"/>
    <body name="tip" pos="0 0 0.5" euler="0.1 0.2 0.3"><joint name="h3" axis="0 1 0"/>
      <geom size="0.1"/></body>
  </body></worldbody></mujoco>
"""

BALL = """
<mujoco><worldbody>
  <body name="upper" pos="0 0 1"><joint name="shoulder" type="ball" pos="0.1 0 0.2"/>
    <geom size="0.1"/>
    <body name="lower" pos="0 0 -0.5"><joint name="elbow" axis="0 1 0" pos="0 0.1 0"/>
      <geom size="0.1"/>
      <body name="hand" pos="0.1 0 -0.4"><joint name="wrist" type="ball"/><geom size="0.1"/>
        <body><geom size="0.05"/></body></body></body>
  </body></worldbody></mujoco>
"""

FREE = """
<mujoco><worldbody>
  <body name="torso" pos="1 2 3" quat="0 0 0 1"><freejoint name="root"/><geom size="0.1"/>
    <body name="leg" pos="0.2 0 -0.3"><joint name="hip" axis="1 0 0" pos="0 0 0.1"/>
      <geom size="0.1"/></body></body>
  <body name="box" pos="0 0 1"><joint type="free"/><geom size="0.1"/></body>
  <body name="static" pos="0 1 0"><geom size="0.1"/></body>
</worldbody></mujoco>
"""

DEFAULTS = """
<mujoco>
  <compiler angle="degree" eulerseq="zyx"/>
  <default><joint axis="0 1 0" range="-45 45"/>
    <default class="finger"><joint axis="0 0 1" range="0 90"/></default></default>
  <worldbody>
    <body name="palm" euler="30 45 60" childclass="finger"><joint name="a"/><geom size="0.1"/>
      <body name="f1" pos="0 0.1 0" axisangle="1 0 0 30"><joint name="b"/><geom size="0.1"/>
      </body>
      <body name="f2" pos="0 -0.1 0" zaxis="1 1 0"><joint name="c" class="main"/>
        <geom size="0.1"/></body>
    </body>
  </worldbody>
</mujoco>
"""


# A ball then a slide in one body (MuJoCo refuses a rotation after a ball in one body).
BALL_SLIDE = """
<mujoco><worldbody>
  <body name="b" pos="0 0 1"><joint name="ball" type="ball" pos="0 0 0.1"/>
    <joint name="slide" type="slide" axis="1 1 0" ref="0.1"/><geom size="0.1"/>
    <body name="c" pos="0 0 -0.5"><joint name="ball2" type="ball" pos="0.1 0 0"/>
      <geom size="0.1"/></body></body>
</worldbody></mujoco>
"""


@pytest.mark.parametrize(
    "xml",
    [HINGE_SLIDE, BALL, BALL_SLIDE, FREE, DEFAULTS],
    ids=["hinge_slide", "ball", "ball_slide", "free", "defaults"],
)
def test_hand_written_models_match_mujoco(xml):
    m = mujoco.MjModel.from_xml_string(xml)
    err = compare(m, n=6, seed=2)
    assert max(err.values()) <= 1e-12, err


def test_q_is_qpos_and_columns_are_dofs():
    m = mujoco.MjModel.from_xml_string(FREE + "")
    chain = Chain.from_mjcf(m)
    for j in range(m.njnt):
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) or f"joint_{j}"
        first_q = [k for k, n in enumerate(chain.joint_names) if n.split(":")[0] == name][0]
        first_v = [k for k, n in enumerate(chain.velocity_names) if n.split(":")[0] == name][0]
        assert first_q == m.jnt_qposadr[j] and first_v == m.jnt_dofadr[j]
    assert (chain.n_dof, chain.n_v) == (m.nq, m.nv)
    assert chain.joint_names[:7] == tuple(
        f"root:{s}" for s in ("x", "y", "z", "qw", "qx", "qy", "qz")
    )
    assert chain.velocity_names[3:6] == ("root:wx", "root:wy", "root:wz")
    # Unnamed bodies and joints are named by MuJoCo's index.
    assert "joint_2" in chain.joint_names[8]
    # MuJoCo's qpos0 is a valid q: the model's own pose.
    T = chain.to(torch.float64).forward_kinematics(torch.from_numpy(m.qpos0.copy()), "torso")
    assert torch.allclose(T["torso"][:3, 3], torch.tensor([1.0, 2, 3], dtype=torch.float64))


def test_ball_jacobian_is_the_derivative_of_the_pose():
    """A ball joint's columns: the body's angular velocity for ``q_ball * Exp(w t)``, in the
    frame right after the ball (MuJoCo's convention; where no rotating joint follows the ball
    in its body they equal ``mj_jacBody``'s, checked below)."""
    m = mujoco.MjModel.from_xml_string(BALL)
    chain = Chain.from_mjcf(m, dtype=torch.float64)
    q = random_qpos(chain, 1, 5)[0]
    q[:4] = q[:4] / q[:4].norm()
    J = chain.jacobian(q, "hand")
    T0 = chain.forward_kinematics(q, "hand")["hand"]
    h = 1e-7
    for k in range(3):
        dq = torch.zeros(4, dtype=torch.float64)  # Exp(h e_k)
        dq[0], dq[k + 1] = math.cos(h / 2), math.sin(h / 2)
        qp = q.clone()
        qp[:4] = quaternion.multiply(q[:4], dq)
        qm = q.clone()
        qm[:4] = quaternion.multiply(q[:4], quaternion.conjugate(dq))
        Tp = chain.forward_kinematics(qp, "hand")["hand"]
        Tm = chain.forward_kinematics(qm, "hand")["hand"]
        v = (Tp[:3, 3] - Tm[:3, 3]) / (2 * h)
        dR = (Tp[:3, :3] - Tm[:3, :3]) / (2 * h) @ T0[:3, :3].T
        omega = torch.stack((dR[2, 1], dR[0, 2], dR[1, 0]))
        assert torch.allclose(J[:3, k], v, atol=1e-7) and torch.allclose(J[3:, k], omega, atol=1e-7)
    # The model's joints each alone in their body: the columns are MuJoCo's.
    _, _, jac = reference(m, q.unsqueeze(0).numpy())
    Js = chain.jacobian(q.unsqueeze(0), list(chain.link_names))
    for i, name in enumerate(chain.link_names):
        assert np.abs(Js[name][0].numpy() - jac[0, i]).max() <= 1e-12


def test_limits_and_names():
    chain = Chain.from_mjcf(DEFAULTS, dtype=torch.float64)
    assert chain.link_names == ("world", "palm", "f1", "f2")
    assert chain.joint_names == ("a", "b", "c")
    deg = math.pi / 180
    assert torch.allclose(chain.lower, torch.tensor([0.0, 0.0, -45 * deg], dtype=torch.float64))
    assert torch.allclose(
        chain.upper, torch.tensor([90 * deg, 90 * deg, 45 * deg], dtype=torch.float64)
    )
    # Several joints in one body: one link per body; the frames between them are not listed.
    hs = Chain.from_mjcf(HINGE_SLIDE)
    assert hs.link_names == ("world", "base", "tip") and hs.n_dof == 4
    assert hs.leaf_links == ("tip",)
    spec = parse_mjcf(HINGE_SLIDE)
    assert [j.type for j in spec.joints] == ["revolute", "prismatic", "continuous", "continuous"]


def test_include_and_file_paths(tmp_path):
    (tmp_path / "arm.xml").write_text(
        '<mujoco><body name="link" pos="0 0 1"><joint name="j" axis="1 0 0"/>'
        '<geom size="0.1"/></body></mujoco>'
    )
    main = tmp_path / "robot.xml"
    main.write_text(
        '<mujoco model="incl"><worldbody><include file="arm.xml"/></worldbody></mujoco>'
    )
    for src in (main, str(main)):
        chain = Chain.from_mjcf(src, dtype=torch.float64)
        assert chain.link_names == ("world", "link") and chain.joint_names == ("j",)
    err = compare(mujoco.MjModel.from_xml_path(str(main)))
    assert max(err.values()) <= 1e-12


def test_ik_on_hinge_and_slide_chains():
    chain = Chain.from_mjcf(HINGE_SLIDE, dtype=torch.float64)
    q = random_qpos(chain, 4, 7)
    target = chain.forward_kinematics(q, "tip")["tip"]
    res = chain.inverse_kinematics(target[:, :3, 3], "tip", restarts=4,
                                   generator=torch.Generator().manual_seed(0))  # fmt: skip
    assert bool(res.converged.all())
    reached = chain.forward_kinematics(res.q, "tip")["tip"][:, :3, 3]
    assert torch.allclose(reached, target[:, :3, 3], atol=1e-5)
    ball = Chain.from_mjcf(BALL)
    with pytest.raises(ValueError, match="ball or free joints.*'shoulder'"):
        ball.inverse_kinematics(torch.zeros(3), "hand")


# ----------------------------------------------------------------------------------------------
# Bad input
# ----------------------------------------------------------------------------------------------


def test_refused_file_names_file_and_mujoco_message(tmp_path):
    bad = tmp_path / "bad.xml"
    bad.write_text('<mujoco><worldbody><body><joint type="hinge" axis="0 0 0"/>'
                   '<geom size="1"/></body></worldbody></mujoco>')  # fmt: skip
    with pytest.raises(MJCFError) as e:
        Chain.from_mjcf(bad)
    assert str(bad) in str(e.value) and "axis" in str(e.value).lower()
    assert e.value.source == str(bad)
    with pytest.raises(MJCFError, match="<string>: .*"):
        Chain.from_mjcf("<mujoco><worldbody><body><freejoint/><body><freejoint/></body>"
                        "</body></worldbody></mujoco>")  # fmt: skip
    with pytest.raises(MJCFError, match="missing.xml"):
        Chain.from_mjcf(tmp_path / "missing.xml")
    with pytest.raises(TypeError, match="parse_mjcf"):
        parse_mjcf(3.0)


def test_missing_mujoco_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "mujoco", None)
    with pytest.raises(ImportError, match=r"torchlie\[mjcf\]"):
        Chain.from_mjcf(BALL)


# ----------------------------------------------------------------------------------------------
# python -m torchlie.kinematics.validate on MJCF
# ----------------------------------------------------------------------------------------------


def test_validate_command_takes_mjcf(tmp_path, capsys):
    from torchlie.kinematics.validate import main

    path = tmp_path / "robot.xml"
    path.write_text(FREE)
    assert main([str(path), "--samples", "20"]) == 0
    text = capsys.readouterr().out
    assert "MuJoCo" in text and "PASS" in text and "leg" in text
    assert main([str(path), "--samples", "5", "--dtype", "float32"]) == 0
    # the format is the root element's, whatever comes before it
    noted = tmp_path / "noted.xml"
    noted.write_text('<!-- converted from <robot name="arm"> -->\n' + FREE)
    assert main([str(noted), "--samples", "5"]) == 0
    assert "MuJoCo" in capsys.readouterr().out
    bad = tmp_path / "bad.xml"
    bad.write_text('<mujoco><worldbody><body><joint axis="0 0 0"/><geom size="1"/></body>'
                   "</worldbody></mujoco>")  # fmt: skip
    assert main([str(bad)]) == 2
    assert str(bad) in capsys.readouterr().err


def test_sites_as_links():
    xml = HINGE_SLIDE.replace(
        '<geom size="0.1"/></body>',
        '<geom size="0.1"/><site name="tcp" pos="0.1 0 0.2" euler="0.3 0 0"/><site/></body>',
    )
    m = mujoco.MjModel.from_xml_string(xml)
    chain = Chain.from_mjcf(m, sites=True, dtype=torch.float64)
    assert chain.link_names == ("world", "base", "tip", "tcp", "site_1")
    assert Chain.from_mjcf(m).link_names == ("world", "base", "tip")
    q = random_qpos(chain, 3, 8)
    T = chain.forward_kinematics(q, ["tcp", "site_1"], stacked=True).numpy()
    d = mujoco.MjData(m)
    for b in range(3):
        d.qpos[:] = q[b].numpy()
        mujoco.mj_kinematics(m, d)
        assert np.abs(T[b, :, :3, 3] - d.site_xpos).max() <= 1e-12
        assert np.abs(T[b, :, :3, :3] - d.site_xmat.reshape(-1, 3, 3)).max() <= 1e-12
    clash = HINGE_SLIDE.replace(
        '<geom size="0.1"/></body>', '<geom size="0.1"/><site name="tip"/></body>'
    )
    with pytest.raises(MJCFError, match="site link 'tip' has the name of a body.*site_prefix"):
        Chain.from_mjcf(clash, sites=True)
    # a prefix names the sites apart: the site's frame, not the body's
    m = mujoco.MjModel.from_xml_string(clash)
    named = Chain.from_mjcf(m, sites=True, site_prefix="site:", dtype=torch.float64)
    assert named.link_names == ("world", "base", "tip", "site:tip")
    q = random_qpos(named, 4, 9)
    T = named.forward_kinematics(q, ["tip", "site:tip"], stacked=True).numpy()
    d = mujoco.MjData(m)
    for b in range(4):
        d.qpos[:] = q[b].numpy()
        mujoco.mj_kinematics(m, d)
        assert np.abs(T[b, 1, :3, 3] - d.site_xpos[0]).max() <= 1e-12
        assert np.abs(T[b, 0, :3, 3] - d.xpos[2]).max() <= 1e-12
    unnamed = Chain.from_mjcf(xml, sites=True, site_prefix="s/")
    assert unnamed.link_names[-2:] == ("s/tcp", "s/site_1")
    with pytest.raises(TypeError, match="parse_mjcf: expected site_prefix to be a str"):
        Chain.from_mjcf(xml, sites=True, site_prefix=1)


@pytest.mark.compile
def test_compile_fullgraph_ball_free_anchors():
    # aot_eager: one graph through AOT autograd (as tests/test_kinematics_compile.py).
    chain = Chain.from_mjcf(FREE.replace('type="free"', 'type="ball" pos="0.1 0 0"'))
    links = ["leg", "box"]

    def f(q):
        return chain.forward_kinematics(q, links, stacked=True), chain.jacobian(q, "leg")

    q = chain.random_configuration(16, generator=torch.Generator().manual_seed(0))
    T, J = torch.compile(f, fullgraph=True, backend="aot_eager")(q)
    T_eager, J_eager = f(q)
    tol = 64 * torch.finfo(torch.float32).eps
    torch.testing.assert_close(T, T_eager, atol=tol, rtol=0)
    torch.testing.assert_close(J, J_eager, atol=tol, rtol=0)


def test_gradients_through_quaternion_joints():
    """First derivatives with respect to ``q`` through ball and free joints (normalised
    quaternions) and anchors: ``gradcheck`` in float64."""
    chain = Chain.from_mjcf(BALL_SLIDE, dtype=torch.float64)
    q = random_qpos(chain, 2, 9).requires_grad_()
    assert torch.autograd.gradcheck(
        lambda x: chain.forward_kinematics(x, "c")["c"], (q,), eps=1e-6, atol=1e-8
    )


def test_text_with_a_byte_order_mark():
    """MJCF text (str or bytes) that starts with a UTF-8 byte-order mark (it was taken for a
    path)."""
    text = (
        '<mujoco model="m"><worldbody><body name="a"><joint name="h" type="hinge"/>'
        '<geom size="0.1"/></body></worldbody></mujoco>'
    )
    for source in ("\ufeff" + text, ("\ufeff" + text).encode("utf-8")):
        assert parse_mjcf(source).joints[0].name == "h"


def test_site_joint_names_are_unique():
    # a site's fixed joint takes a free name, as a body's does (it was "s:fixed" twice here)
    spec = parse_mjcf(
        '<mujoco><worldbody><body name="a"><joint name="s:fixed" axis="0 1 0"/>'
        '<geom size=".1"/><site name="s"/></body></worldbody></mujoco>',
        sites=True,
    )
    names = [j.name for j in spec.joints]
    assert len(names) == len(set(names)) and "s:fixed_" in names


def test_zero_quaternion_spoils_only_its_state():
    # torchlie's rule for a zero quaternion (NaN for that element; MuJoCo reads the identity)
    chain = Chain.from_mjcf(FREE, dtype=torch.float64)
    q = chain.random_configuration(3, generator=torch.Generator().manual_seed(0))
    q[1, 3:7] = 0.0  # the free joint's quaternion
    T = chain.forward_kinematics(q, ["torso", "leg", "box"], stacked=True)
    assert bool(T[1, :2].isnan().all())  # the joint's body and its child
    assert bool(T[1, 2].isfinite().all() and T[[0, 2]].isfinite().all())
