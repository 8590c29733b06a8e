"""``python -m torchlie.kinematics.validate robot.sdf``, and the independent float64 evaluation
of an SDF model's link poses it compares with.

Written apart from :mod:`torchlie.kinematics.sdf` and the chain on purpose: numpy only, the
SDFormat rules applied literally, joint by joint, ``X_M_child(q) = X_M_parent(q) X_PJ M(q)
X_JC`` with ``X_PJ`` and ``X_JC`` from the zero-configuration frames and ``M(q)`` the joint's
motion in its own frame (about the axis expressed in the joint frame), where the chain writes
each joint about the child link's frame.  Used by ``python -m torchlie.kinematics.validate
robot.sdf`` and by the tests.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from typing import Any

import numpy as np
import torch

from .chain import Chain

_TREE_TYPES = ("revolute", "continuous", "prismatic", "fixed", "ball")


def _rot_rpy(r: float, p: float, y: float) -> np.ndarray:
    def rx(a: float) -> np.ndarray:
        return np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])

    def ry(a: float) -> np.ndarray:
        return np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])

    def rz(a: float) -> np.ndarray:
        return np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])

    return rz(y) @ ry(p) @ rx(r)


def _rot_quat(w: float, x: float, y: float, z: float) -> np.ndarray:
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _rot_axis(a: np.ndarray, angle: float) -> np.ndarray:
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * (K @ K)


def _pose(el: ET.Element | None) -> np.ndarray:
    T = np.eye(4)
    if el is None or not (el.text or "").split():
        return T
    v = [float(x) for x in (el.text or "").split()]
    if el.get("rotation_format") == "quat_xyzw":
        T[:3, :3] = _rot_quat(v[6], v[3], v[4], v[5])
    else:
        ang = v[3:]
        if (el.get("degrees") or "").strip().lower() in ("true", "1"):
            ang = [math.radians(a) for a in ang]
        T[:3, :3] = _rot_rpy(*ang)
    T[:3, 3] = v[:3]
    return T


def _strip(root: ET.Element) -> ET.Element:
    for el in root.iter():
        el.tag = str(el.tag).rsplit("}", 1)[-1]
    return root


def sdf_reference_poses(xml: str | bytes, values: dict[str, object]) -> dict[str, np.ndarray]:
    """Every link's pose ``(4, 4)`` in the model frame for the joint values ``values``: joint
    name -> angle, displacement or quaternion ``(w, x, y, z)`` (missing: zero / identity).
    Each link's tree joint is its first parent joint of a supported type (document order).

    The joint axis frame by ``<sdf version>`` (absent: 1.7): up to 1.4 the model frame; 1.5
    and 1.6 the joint frame, the model frame where ``<use_parent_model_frame>`` is true; from
    1.7 the joint frame or the one ``expressed_in`` names.  Before 1.7 a joint may share its
    name with a link (a ``relative_to`` then names the link)."""
    root = _strip(ET.fromstring(xml))
    major, minor = (int(x) for x in root.get("version", "1.7").split("."))
    version = (major, minor)
    model = root.find("model")
    if model is None:
        model = root.find("world/model")
    assert model is not None
    rel: dict[str, str] = {}
    pose: dict[str, np.ndarray] = {}
    joint_rel: dict[str, str] = {}
    joint_pose: dict[str, np.ndarray] = {}

    def read(el: ET.Element, default: str, rel: dict, pose: dict) -> None:  # noqa: ANN001
        p = el.find("pose")
        given = ""
        if p is not None:
            given = (p.get("relative_to") or p.get("frame") or "").strip()
        rel[el.get("name", "")] = given or default
        pose[el.get("name", "")] = _pose(p)

    for el in model.findall("link"):
        read(el, "__model__", rel, pose)
    for el in model.findall("frame"):
        read(el, (el.get("attached_to") or "").strip() or "__model__", rel, pose)
    for el in model.findall("joint"):
        read(el, (el.findtext("child") or "").strip(), joint_rel, joint_pose)
    for name in joint_rel:
        if name not in rel:
            rel[name], pose[name] = joint_rel[name], joint_pose[name]

    def X0(name: str) -> np.ndarray:
        return np.eye(4) if name in ("__model__", "world") else X0(rel[name]) @ pose[name]

    def XJ(name: str) -> np.ndarray:
        """The joint frame (its name may also be a link's before 1.7)."""
        return X0(joint_rel[name]) @ joint_pose[name]

    tree: dict[str, ET.Element] = {}
    for el in model.findall("joint"):
        if (el.get("type") or "").strip() in _TREE_TYPES:
            tree.setdefault((el.findtext("child") or "").strip(), el)
    out: dict[str, np.ndarray] = {}

    def X(link: str) -> np.ndarray:
        if link in ("world", "__model__"):
            return np.eye(4)
        if link not in out:
            el = tree.get(link)
            out[link] = (
                X0(link) if el is None else X(_parent(el)) @ _motion(el, values, X0, XJ, version)
            )
        return out[link]

    return {el.get("name", ""): X(el.get("name", "")) for el in model.findall("link")}


def _parent(el: ET.Element) -> str:
    return (el.findtext("parent") or "").strip()


def _motion(el: ET.Element, values: dict[str, object], X0, XJ, version) -> np.ndarray:  # noqa: ANN001
    """``X_PJ M(q) X_JC`` of joint ``el``."""
    name, jtype = el.get("name", ""), (el.get("type") or "").strip()
    child = (el.findtext("child") or "").strip()
    XP0, XJ0, XC0 = X0(_parent(el)), XJ(name), X0(child)
    M = np.eye(4)
    if jtype in ("revolute", "continuous", "prismatic"):
        axis_el = el.find("axis")
        xyz_el = axis_el.find("xyz") if axis_el is not None else None
        a = np.array([0.0, 0.0, 1.0])
        if xyz_el is not None:
            a = np.array([float(x) for x in (xyz_el.text or "").split()])
        upm = axis_el.findtext("use_parent_model_frame") if axis_el is not None else None
        expressed = (xyz_el.get("expressed_in") or "").strip() if xyz_el is not None else ""
        if version >= (1, 7) or upm is None:  # 1.4 and older: the model frame by default
            in_model = version < (1, 5) and not expressed
        else:
            in_model = upm.strip().lower() in ("1", "true")
        if in_model:
            R_JF = XJ0[:3, :3].T
        elif expressed:
            R_JF = XJ0[:3, :3].T @ X0(expressed)[:3, :3]
        else:  # the joint frame
            R_JF = np.eye(3)
        a_J = R_JF @ a
        a_J = a_J / np.linalg.norm(a_J)
        v = float(values.get(name, 0.0))  # type: ignore[arg-type]
        if jtype == "prismatic":
            M[:3, 3] = v * a_J
        else:
            M[:3, :3] = _rot_axis(a_J, v)
    elif jtype == "ball":
        M[:3, :3] = _rot_quat(*values.get(name, (1.0, 0.0, 0.0, 0.0)))  # type: ignore[misc]
    return np.linalg.solve(XP0, XJ0) @ M @ np.linalg.solve(XJ0, XC0)


def joint_values(dof_joints: tuple[tuple[str, str, str], ...], q: np.ndarray) -> dict[str, object]:
    """A chain's ``q`` (one configuration) as joint name -> value, quaternions for ball
    joints, by the chain's :attr:`~torchlie.kinematics.Chain.dof_joints` (what each DoF is,
    whatever the joints are named)."""
    out: dict[str, object] = {}
    for k, (joint, _, coord) in enumerate(dof_joints):
        if coord == "qw":
            out[joint] = tuple(float(x) for x in q[k : k + 4])
        elif coord == "":
            out[joint] = float(q[k])
    return out


def validate_sdf(
    source: str, *, samples: int, dtype: torch.dtype, seed: int, loops: str, out: Any
) -> bool:
    """``python -m torchlie.kinematics.validate robot.sdf``: every link's pose of
    :meth:`Chain.from_sdf` against :func:`sdf_reference_poses` at random configurations,
    within ``1e-12`` (float64) or ``1e-5`` (float32), times ``1 + size`` for positions
    (``size``: the largest distance of a link from the model origin, m); prints the report and
    returns whether everything is within tolerance."""
    xml: str | bytes
    if source.lstrip("\ufeff \t\r\n").startswith("<"):
        xml, label = source, "<string>"
    else:
        with open(source, "rb") as f:  # the XML declaration names the encoding
            xml, label = f.read(), source
    chain = Chain.from_sdf(source, loops=loops, dtype=dtype)  # errors name the file
    tol = 1e-12 if dtype == torch.float64 else 1e-5
    w = out.write
    w(f"torchlie.kinematics.validate: SDF {label}\n")
    w(
        f"{len(chain.link_names)} links, {chain.n_dof} joint values; {samples} random "
        f"configurations; torchlie in {str(dtype)[6:]}; compared with an independent float64 "
        "evaluation of the SDFormat frame rules (torchlie.kinematics._sdf_validate)\n"
    )
    q = chain.random_configuration(samples, generator=torch.Generator().manual_seed(seed))
    T = chain.forward_kinematics(q, stacked=True).to(torch.float64).numpy()
    q64 = q.to(torch.float64).numpy()
    links = list(chain.link_names)
    refs = [
        sdf_reference_poses(xml, joint_values(chain.dof_joints, q64[b])) for b in range(samples)
    ]
    scale = 1.0 + max(float(np.abs(r[n][:3, 3]).max()) for r in refs for n in r)
    w(f"tolerance {tol:g} rad, {tol * scale:.1e} m (1 + size = {scale:.2f} m)\n\n")
    width = max(12, *(len(n) for n in links)) + 2
    w(f"{'link':<{width}}{'|dp| m':>12}{'|dR|':>12}  status\n")
    ok = True
    for i, n in enumerate(links):
        if n not in refs[0]:  # the root (model frame)
            continue
        ref = np.stack([r[n] for r in refs])
        dp = float(np.abs(T[:, i, :3, 3] - ref[:, :3, 3]).max())
        dr = float(np.abs(T[:, i, :3, :3] - ref[:, :3, :3]).max())
        good = dp <= tol * scale and dr <= tol  # a nan is outside
        ok = ok and good
        w(f"{n:<{width}}{dp:>12.1e}{dr:>12.1e}  {'ok' if good else 'MISMATCH'}\n")
    w("\nPASS: every link pose within tolerance\n" if ok else "\nFAIL\n")
    return ok
