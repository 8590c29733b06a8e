"""The validation command: sample robots, a real robot, failure detection, and pk's deviations."""

from __future__ import annotations

import contextlib
import importlib.util
import io
import os
import subprocess
import sys

import pytest
import torch

import torchlie.kinematics.validate as V
from torchlie.kinematics import sample_robot
from torchlie.kinematics._pin_reference import _Pin
from torchlie.kinematics._pk_reference import _PK, _pk_text

needs_pk = pytest.mark.skipif(
    importlib.util.find_spec("pytorch_kinematics") is None,
    reason="pytorch_kinematics is not installed (pip install 'torchlie[validate]')",
)


def run(robot, **kw) -> tuple[V.ValidationReport, str]:
    out = io.StringIO()
    kw.setdefault("samples", 200)
    report = V.validate(robot, out=out, err=io.StringIO(), **kw)
    return report, out.getvalue()


@needs_pk
def test_arm7_fully_comparable():
    report, text = run("arm7")
    assert report.ok and report.pk_version
    assert len(report.links) == 12
    assert [j.link for j in report.jacobians] == ["tool_tcp", "wrist_camera"]
    for r in report.links + report.jacobians:
        assert r.ok
    for r in report.links:
        assert r.pk_position is not None and r.pk_position <= V.TOL_PK * (1 + report.reach)
        assert r.ref_position <= 1e-12 * (1 + report.reach) and r.ref_rotation <= 1e-12
    for r in report.jacobians:
        assert r.pk_error is not None and r.ref_error <= 1e-12 * (1 + report.reach)
    # Only the float32 note: no mimic, no omitted axis, no floating/planar joint.
    assert len(report.deviations) == 1 and "float32" in report.deviations[0]
    assert "PASS: all 12 link poses and 2 end-link Jacobians" in text
    assert "n/c" not in text
    timed = {"torchlie float64", "torchlie float32", "pytorch_kinematics float32"}
    assert timed <= set(report.timings)


@needs_pk
def test_tree_reports_pk_deviations_and_not_comparable_links():
    report, text = run("tree", dtype=torch.float32)
    assert report.ok
    free = {"puck", "puck_arm", "puck_tool", "drone", "drone_camera"}
    for r in report.links:
        assert (r.pk_position is None) == (r.link in free), r.link
        assert r.ref_position <= 1e-5 * (1 + report.reach)
    for r in report.jacobians:
        assert (r.pk_error is None) == (r.link in free), r.link
    dev = "\n".join(report.deviations)
    assert "pk ignores <mimic>" in dev and "right_index = -0.5 * right_thumb + 0.1" in dev
    assert "omitted <axis> as +Z" in dev and "head_roll" in dev
    assert "cannot load floating or planar joints" in dev and "puck_slide, drone_free" in dev
    assert "n/c: not comparable with pytorch_kinematics" in text
    row = next(line for line in text.splitlines() if line.startswith("drone "))
    assert row.split()[5:7] == ["n/c", "n/c"] and row.split()[-1] == "ok"


@needs_pk
def test_real_robot_panda():
    # The Franka Emika Panda URDF shipped with the package (Apache-2.0, robots/panda/LICENSE).
    report, _ = run("panda")
    assert report.ok and len(report.links) == 13
    assert all(r.pk_position is not None for r in report.links)
    assert any("panda_finger_joint2 = 1 * panda_finger_joint1 + 0" in d for d in report.deviations)
    assert os.path.exists(os.path.join(os.path.dirname(sample_robot("panda")), "LICENSE"))


def test_detects_a_mismatch(monkeypatch):
    real = V.reference_forward_kinematics

    def off_by_a_nanometre(spec, q):
        T = real(spec, q)
        T["link5"] = T["link5"].clone()
        T["link5"][:, 0, 3] += 1e-9
        return T

    monkeypatch.setattr(V, "reference_forward_kinematics", off_by_a_nanometre)
    report, text = run("arm7", samples=20)
    assert not report.ok
    bad = [r.link for r in report.links if not r.ok]
    assert bad == ["link5"]
    assert "MISMATCH" in text and "FAIL: outside tolerance: link5" in text
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert V.main(["arm7", "--samples", "20", "--no-progress"]) == 1


@needs_pk
def test_detects_a_jacobian_mismatch_against_pk(monkeypatch):
    real = _PK.jacobian

    def scaled(self, th, link):
        return real(self, th, link) * 1.001

    monkeypatch.setattr(_PK, "jacobian", scaled)
    report, _ = run("arm7", samples=20)
    assert not report.ok and not any(j.ok for j in report.jacobians)
    assert all(r.ok for r in report.links)


def test_without_pk():
    report, text = run("tree", samples=50, compare_pk=False)
    assert report.ok and report.pk_version is None
    assert all(r.pk_position is None for r in report.links)
    assert "pytorch_kinematics: not compared" in text


def test_progress_bar_and_xml_text():
    err = io.StringIO()
    text = open(sample_robot("arm7")).read()
    report = V.validate(text, samples=30, batch=10, out=io.StringIO(), err=err)
    assert report.ok and report.source == "<string>"
    assert "[##############################] 30/30 configurations" in err.getvalue()
    assert err.getvalue().count("\r") == 4  # 0, 10, 20, 30
    quiet = io.StringIO()
    V.validate("arm7", samples=30, batch=10, progress=False, out=io.StringIO(), err=quiet)
    assert quiet.getvalue() == ""


def test_cli_exit_codes(tmp_path, capsys):
    assert V.main(["arm7", "--samples", "10", "--dtype", "float32", "--no-progress"]) == 0
    assert "torchlie in float32" in capsys.readouterr().out
    bad = tmp_path / "bad.urdf"
    bad.write_text('<robot name="r"><link name="a"/><joint name="j" type="hinge"/></robot>')
    assert V.main([str(bad)]) == 2
    assert "unknown joint type 'hinge'" in capsys.readouterr().err
    assert V.main([str(tmp_path / "missing.urdf")]) == 2
    with pytest.raises(SystemExit):
        V.main(["arm7", "--samples", "0"])


def test_module_entry_point():
    proc = subprocess.run(
        [sys.executable, "-m", "torchlie.kinematics.validate", "arm7", "--samples", "5"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    assert "PASS" in proc.stdout


# ----------------------------------------------------------------------------------------------
# The pytorch-kinematics behaviour the validation works around, measured
# ----------------------------------------------------------------------------------------------

TWO = """<robot name="r"><link name="a"/><link name="b"/><link name="c"/>
<joint name="j1" type="revolute"><parent link="a"/><child link="b"/>
  <origin xyz="0.1 0 0"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
<joint name="j2" type="revolute"><parent link="b"/><child link="c"/><axis xyz="0 0 1"/>
  <limit lower="-1" upper="1" effort="1" velocity="1"/>
  <mimic joint="j1" multiplier="2" offset="0.5"/></joint>
</robot>"""


def _pk_chain(text):
    import pytorch_kinematics as pk

    with contextlib.redirect_stderr(io.StringIO()):
        return pk.build_chain_from_urdf(text)


@needs_pk
def test_pk_deviations_are_real():
    c = _pk_chain(TWO)
    # <mimic> ignored: the mimic joint is an independent DoF.
    assert c.get_joint_parameter_names() == ["j1", "j2"]
    # Omitted <axis> read as +Z (URDF says +X).
    assert c.axes[0].tolist() == [0.0, 0.0, 1.0]
    # Origins rounded to float32 even in a float64 chain.
    c64 = _pk_chain(TWO).to(dtype=torch.float64)
    assert c64._static_offsets[1, 0, 3].item() != 0.1
    # Floating and planar joints cannot be loaded.
    for jtype in ("floating", "planar"):
        with pytest.raises(KeyError):
            _pk_chain(TWO.replace('name="j1" type="revolute"', f'name="j1" type="{jtype}"'))


@needs_pk
def test_pk_text_makes_pk_agree():
    fixed = _pk_text(TWO.encode())
    c = _pk_chain(fixed)
    assert c.axes[0].tolist() == [1.0, 0.0, 0.0]
    tree = _pk_text(open(sample_robot("tree"), "rb").read())
    assert 'type="floating"' not in tree and 'type="planar"' not in tree


@needs_pk
def test_pk_load_failure_is_reported_not_failed():
    # pk's URDF reader insists on <limit effort velocity>; the URDF specification does too, but
    # torchlie only needs the position limits.
    text = TWO.replace(' effort="1" velocity="1"', "")
    report, out = run(text, samples=20)
    assert report.ok and all(r.pk_position is None for r in report.links)
    assert any("could not load this URDF" in d for d in report.deviations)


@needs_pk
def test_pk_second_derivative_vanishes_ours_does_not():
    # pk's default (analytical) backward is not itself differentiable: with create_graph=True
    # the first derivative carries no graph, so every second derivative comes out as zero.
    c64 = _pk_chain(TWO).to(dtype=torch.float64)
    q = torch.tensor([[0.3, 0.2]], dtype=torch.float64, requires_grad=True)
    (g,) = torch.autograd.grad(c64.forward_kinematics_tensor(q)[2, 0, 0, 3], q, create_graph=True)
    assert not g.requires_grad
    chain = V.Chain.from_urdf(TWO, dtype=torch.float64)

    def first(v: float, create_graph: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
        x = torch.tensor([v], dtype=torch.float64, requires_grad=True)
        y = chain.forward_kinematics(x, "c")["c"][1, 0]  # R_c = Rx(q) Rz(2q + 0.5)
        return torch.autograd.grad(y, x, create_graph=create_graph)[0], x

    g, x = first(0.3, create_graph=True)
    (h,) = torch.autograd.grad(g.sum(), x)
    fd = (first(0.3 + 1e-6)[0] - first(0.3 - 1e-6)[0]) / 2e-6
    assert abs(h.item()) > 0.1 and abs(h.item() - fd.item()) < 1e-8


# ----------------------------------------------------------------------------------------------
# Pinocchio
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("robot", ["arm7", "tree", "panda"])
def test_pinocchio_agrees_on_every_pose_and_jacobian_kind(robot):
    pytest.importorskip("pinocchio")
    report, text = run(robot, samples=60, compare_pk=False)
    assert report.ok and report.pin_version
    tol = 1e-12 * (1 + report.reach)
    for r in report.links:  # every link, planar, floating and mimic joints included
        assert r.pin_position is not None and r.pin_position <= tol, r.link
        assert r.pin_rotation is not None and r.pin_rotation <= 1e-12, r.link
    for r in report.jacobians:
        assert r.pin_errors is not None and set(r.pin_errors) == {"world", "link", "spatial"}
        assert max(r.pin_errors.values()) <= tol, (r.link, r.pin_errors)
    assert f"Pinocchio {report.pin_version} (float64)" in text
    assert "pin world" in text and "pin spatial" in text and "LOCAL_WORLD_ALIGNED" in text
    if robot != "arm7":
        assert any("mimic" in d for d in report.pin_deviations)


@pytest.mark.parametrize("kind", ["world", "link", "spatial"])
def test_detects_a_jacobian_kind_mismatch_against_pinocchio(monkeypatch, kind):
    pytest.importorskip("pinocchio")
    real = _Pin.evaluate

    def off(self, q64, links, leaves):
        poses, jacs = real(self, q64, links, leaves)
        return poses, {k: v * 1.001 if k[1] == kind else v for k, v in jacs.items()}

    monkeypatch.setattr(_Pin, "evaluate", off)
    report, text = run("arm7", samples=20, compare_pk=False)
    assert not report.ok and not any(j.ok for j in report.jacobians)
    assert all(r.ok for r in report.links)
    for j in report.jacobians:
        assert j.pin_errors is not None
        assert j.pin_errors[kind] > 1e-6
        assert all(e <= 1e-12 * (1 + report.reach) for k, e in j.pin_errors.items() if k != kind)


def test_without_pinocchio_columns():
    report, text = run("arm7", samples=20, compare_pk=False, compare_pin=False)
    assert report.ok and report.pin_version is None and report.pin_deviations == []
    assert all(r.pin_position is None for r in report.links)
    assert all(j.pin_errors is None for j in report.jacobians)
    assert "pin |dp|" not in text and "Pinocchio" not in text
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert V.main(["arm7", "--samples", "10", "--no-progress", "--no-pk", "--no-pin"]) == 0
    assert "pin |dp|" not in out.getvalue()


def test_joint_names_with_colons():
    """The float64 reference takes each joint's DoFs from the joints' types and order, not
    from their names ('arm:shoulder' was read as a coordinate of a joint 'arm')."""
    from torchlie.kinematics import Chain
    from torchlie.kinematics.reference import reference_forward_kinematics

    text = (
        '<robot name="r"><link name="a"/><link name="b"/><link name="c"/><link name="d"/>'
        '<joint name="arm" type="planar"><parent link="a"/><child link="b"/>'
        '<axis xyz="0 0 1"/></joint>'
        '<joint name="arm:shoulder" type="revolute"><parent link="b"/><child link="c"/>'
        '<axis xyz="0 0 1"/><limit lower="-1" upper="1"/></joint>'
        '<joint name="arm:elbow" type="revolute"><parent link="c"/><child link="d"/>'
        '<origin xyz="1 0 0"/><axis xyz="0 1 0"/><limit lower="-1" upper="1"/></joint></robot>'
    )
    chain = Chain.from_urdf(text, dtype=torch.float64)
    q = chain.random_configuration(5, generator=torch.Generator().manual_seed(0))
    ref = reference_forward_kinematics(chain.spec, q)
    T = chain.forward_kinematics(q)
    for link in chain.link_names:
        torch.testing.assert_close(T[link], ref[link], atol=1e-14, rtol=0)
    report, out = run(text, samples=20)
    assert report.ok and "PASS" in out


@needs_pk
def test_fixed_zero_axis_fixed_leaf_and_singular_mass_matrix():
    """Robots that validate crashed on: a fixed joint with ``<axis xyz="0 0 0"/>`` (SO-101),
    an end link fixed to the root (no joint of pytorch-kinematics' serial chain to it), and a
    chain whose mass matrix is singular in every state (a finger without mass: romeo's hands),
    where the forward dynamics are left out with a note instead."""
    pytest.importorskip("pinocchio")
    inertia = '<inertial><mass value="1"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" '
    inertia += 'izz="0.1"/></inertial>'
    text = (
        f'<robot name="r"><link name="a"/><link name="b">{inertia}</link><link name="c"/>'
        '<link name="tool"/><link name="mount"/>'
        '<joint name="j" type="revolute"><parent link="a"/><child link="b"/>'
        '<axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>'
        '<joint name="finger" type="revolute"><parent link="b"/><child link="c"/>'
        '<origin xyz="1 0 0"/><axis xyz="0 1 0"/>'
        '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint>'
        '<joint name="t" type="fixed"><parent link="c"/><child link="tool"/>'
        '<origin xyz="0 0 0.2"/><axis xyz="0 0 0"/></joint>'
        '<joint name="m" type="fixed"><parent link="a"/><child link="mount"/>'
        '<origin xyz="0 1 0"/></joint></robot>'
    )
    report, out = run(text, samples=20)
    assert report.ok and "PASS" in out
    assert {r.link for r in report.jacobians} == {"tool", "mount"}
    assert report.dynamics is not None and "qdd" not in report.dynamics
    assert "forward dynamics not compared: the mass matrix is singular ('finger')" in out
    # with the finger's mass, the forward dynamics are compared
    report, out = run(
        text.replace('<link name="c"/>', f'<link name="c">{inertia}</link>'), samples=20
    )
    assert report.ok and report.dynamics is not None and "qdd" in report.dynamics


def test_forward_dynamics_by_the_residual_of_the_equations_of_motion(monkeypatch):
    """The forward dynamics pass on a chain so ill-conditioned that two exact solvers'
    accelerations differ (a heavy link of next to no inertia beside a light one, as iCub's),
    and fail when the accelerations are off by a small fraction."""
    pytest.importorskip("pinocchio")
    from torchlie.kinematics import Chain

    def inertial(m: float, i: float) -> str:
        return (
            f'<inertial><mass value="{m}"/><origin xyz="0.3 0 0"/><inertia ixx="{i}" ixy="0" '
            f'ixz="0" iyy="{i}" iyz="0" izz="{i}"/></inertial>'
        )

    limit = '<limit lower="-1" upper="1" effort="1" velocity="1"/>'
    text = (
        f'<robot name="r"><link name="a"/><link name="b">{inertial(1e3, 1e-12)}</link>'
        f'<link name="c">{inertial(1e-3, 1e-12)}</link>'
        f'<joint name="j1" type="revolute"><parent link="a"/><child link="b"/>'
        f'<axis xyz="0 0 1"/>{limit}</joint>'
        f'<joint name="j2" type="revolute"><parent link="b"/><child link="c"/>'
        f'<origin xyz="0.6 0 0"/><axis xyz="1 0 0"/>{limit}</joint></robot>'
    )
    chain = Chain.from_urdf(text, dtype=torch.float64)
    q = chain.random_configuration(20, generator=torch.Generator().manual_seed(3))
    assert float(torch.linalg.cond(chain.mass_matrix(q)).max()) > 1e11
    report, out = run(text, samples=20)
    assert report.ok and report.dynamics["qdd"] <= 1e-12
    assert "the residual |M qdd + h - tau| of Pinocchio" in out
    real = Chain.forward_dynamics

    def off(self, *args, **kw):
        return real(self, *args, **kw) * (1 + 1e-7)

    monkeypatch.setattr(Chain, "forward_dynamics", off)
    report, out = run(text, samples=20)
    assert not report.ok and "FAIL: outside tolerance: forward dynamics" in out
