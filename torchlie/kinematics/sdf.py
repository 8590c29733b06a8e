"""SDFormat (SDF) robots: one model's links and joints, with the specification's frame rules.

Read: ``<model>`` (directly under ``<sdf>``, or the one model of a ``<world>``), its
``<link name>`` and ``<frame name attached_to>`` elements with their ``<pose relative_to>``,
and its ``<joint name type>`` elements with ``<parent>``, ``<child>``, ``<pose relative_to>``
and ``<axis>`` (``<xyz expressed_in>``, the older ``<use_parent_model_frame>``, ``<limit>``
``<lower>``/``<upper>``).  Joint types ``revolute``, ``continuous``, ``prismatic``,
``fixed`` and ``ball`` (its value a unit quaternion ``w, x, y, z``, the rotation of the joint
frame from its zero pose; its velocity columns the angular velocity in the joint frame).
Everything else (visuals, collisions, inertials, plugins, meshes and their ``<uri>``) is
ignored.

Frames, as SDFormat 1.7+ defines them: a link's pose is relative to the model frame unless
``relative_to`` names another frame; a joint's pose (its frame) is relative to its child link;
a ``<frame>``'s to the frame it is attached to (the model frame by default).  ``__model__``
names the model frame.  A pose is ``x y z roll pitch yaw`` with ``R = Rz(yaw) Ry(pitch)
Rx(roll)``; ``degrees="true"`` (exact at multiples of 90 degrees) and
``rotation_format="quat_xyzw"`` (``x y z qx qy qz qw``, not all zero) are read, and the
``frame`` attribute of SDFormat 1.5-1.6 poses as ``relative_to``.

What depends on ``<sdf version>`` (a file without one is read by the 1.7+ rules):

- the frame of a joint axis ``<xyz>``: up to 1.4 the model frame; in 1.5-1.6 the joint frame,
  or the model frame where ``<use_parent_model_frame>`` is true; from 1.7 the joint frame, or
  the frame ``<xyz expressed_in>`` names (``<use_parent_model_frame>`` true is then an error,
  as 1.7 removed it).  In older files an ``expressed_in`` is read too (a true
  ``<use_parent_model_frame>`` wins over it), and in a 1.4 file a false one means the joint
  frame.
- names: from 1.7 the links, joints and frames of a model share one namespace; before, a joint
  may take the name of a link or frame (a ``relative_to`` naming both means the link or frame).

Limits: ``<limit>`` ``<lower>``/``<upper>`` of a revolute or prismatic joint, one number each;
a side that is absent or beyond ``+-1e15`` (SDF's default is ``+-1e16``) is unlimited
(``-inf``/``inf``): a revolute joint without either is ``continuous``, one with a single side
keeps that side.  ``lower > upper`` is an error.

The file's encoding is the one its XML declaration names (UTF-8 by default, with or without a
byte-order mark); bytes and paths are given to the XML parser undecoded.

The chain: its root is the model frame, called ``"__model__"`` (or ``"world"`` when a joint
has ``<parent>world</parent>``: the world is then taken to be the model frame), and every pose
it returns is in the model's frame.  The model's own ``<pose>`` (where it stands in its world)
is not applied: pre-multiply the chain's poses by it for world poses.  A link that no joint
moves is attached to the root by a fixed joint.  A joint turns about its own frame's origin and
axis; the joint frame need not coincide with the child link's.

Not supported, with an error naming it: several models, nested models, ``<include>`` (also
next to a ``<model>`` in a ``<world>``), joint types other than those above, and kinematic
loops (a link that is the child of several joints), unless ``loops="skip"``: then each link
keeps the first of its parent joints (in document order) of a supported type, the others (loop
closures: gearbox, ball, ... joints) are left out, as a tree of the robot's links needs.
"""

from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import torch
from torch import Tensor

from .. import quaternion as _quaternion
from ._joints import rpy_matrix, rpy_rows_cos_sin
from .urdf import JointSpec, RobotSpec, _local, _some

__all__ = ["SDFError", "parse_sdf", "SDF_JOINT_TYPES"]

#: SDF joint types the chain builds.
SDF_JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed", "ball")

# SDF's default limits (+-1e16) mean "none".
_NO_LIMIT = 1e15
# The version whose rules apply when <sdf> gives none.
_NEWEST = (1, 7)


class SDFError(ValueError):
    """A malformed or unsupported SDF file; the message is ``"{source}: {element}: {problem}"``.

    Attributes:
        source: the file name, or ``"<string>"`` for XML text.
        element: the offending element, e.g. ``"<joint name='knee'>"``.
        problem: what is wrong with it.
    """

    def __init__(self, source: str, element: str, problem: str) -> None:
        self.source, self.element, self.problem = source, element, problem
        label = source if source.isprintable() else repr(source)
        super().__init__(f"{label}: {element}: {problem}")


@dataclass(frozen=True)
class _Frame:
    relative_to: str
    pose: Tensor  # 4x4 float64


class _Reader:
    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, element: str, problem: str) -> SDFError:
        return SDFError(self.source, element, problem)

    def numbers(self, text: str | None, where: str, what: str) -> list[float]:
        try:
            values = [float(x) for x in (text or "").split()]
        except ValueError:
            raise self.fail(where, f"<{what}> is not a list of numbers: {text!r}") from None
        if not all(math.isfinite(v) for v in values):
            raise self.fail(where, f"<{what}> is not finite: {text!r}")
        return values

    def pose(self, el: ET.Element | None, where: str) -> Tensor:
        """4x4 float64 of a ``<pose>`` element (identity when absent or empty)."""
        T = torch.eye(4, dtype=torch.float64)
        if el is None:
            return T
        v = self.numbers(el.text, where, "pose")
        fmt = el.get("rotation_format", "euler_rpy")
        if not v:
            return T
        if fmt == "quat_xyzw":
            if len(v) != 7:
                raise self.fail(
                    where, f"<pose rotation_format='quat_xyzw'> needs 7 numbers, got {len(v)}"
                )
            qx, qy, qz, qw = v[3:]
            if qx == qy == qz == qw == 0.0:
                raise self.fail(where, "the quaternion (qx qy qz qw) is zero: not a rotation")
            R = _quaternion.to_matrix(torch.tensor([qw, qx, qy, qz], dtype=torch.float64))
        elif fmt == "euler_rpy":
            if len(v) != 6:
                raise self.fail(
                    where, f"<pose> needs 6 numbers (x y z roll pitch yaw), got {len(v)}"
                )
            if el.get("degrees", "false").strip().lower() in ("true", "1"):
                cos_sin = [x for a in v[3:] for x in _cos_sin_degrees(a)]
                R = torch.tensor(rpy_rows_cos_sin(*cos_sin), dtype=torch.float64)
            else:
                R = rpy_matrix(*v[3:])
        else:
            raise self.fail(where, f"unknown <pose rotation_format={fmt!r}>")
        T[:3, :3] = R
        T[:3, 3] = torch.tensor(v[:3], dtype=torch.float64)
        return T

    def text(self, el: ET.Element, tag: str, where: str) -> str:
        sub = el.find(tag)
        if sub is None or not (sub.text or "").strip():
            raise self.fail(where, f"missing <{tag}>")
        return (sub.text or "").strip()


# Cosine and sine at the multiples of 90 degrees, exactly.
_RIGHT_ANGLES = {
    0.0: (1.0, 0.0),
    90.0: (0.0, 1.0),
    -90.0: (0.0, -1.0),
    180.0: (-1.0, 0.0),
    -180.0: (-1.0, 0.0),
}


def _cos_sin_degrees(a: float) -> tuple[float, float]:
    """``cos`` and ``sin`` of ``a`` degrees, exact at multiples of 90 (the angle reduced to
    ``[-180, 180]`` first: exact in floating point)."""
    a = math.remainder(a, 360.0)
    if a in _RIGHT_ANGLES:
        return _RIGHT_ANGLES[a]
    return math.cos(math.radians(a)), math.sin(math.radians(a))


def _strip_namespaces(root: ET.Element) -> None:
    for el in root.iter():
        el.tag = _local(el.tag)


def _version(r: _Reader, root: ET.Element) -> tuple[int, int]:
    """``<sdf version>`` as ``(major, minor)``; absent: the newest rules (1.7+)."""
    given = root.get("version")
    if given is None:
        return _NEWEST
    try:
        major, minor = (int(x) for x in given.strip().split("."))
    except ValueError:
        raise r.fail(
            f"<sdf version={given!r}>", "expected a version MAJOR.MINOR, e.g. '1.7'"
        ) from None
    return major, minor


def _the_model(r: _Reader, root: ET.Element) -> ET.Element:
    if root.tag != "sdf":
        raise r.fail(f"<{root.tag}>", "the root element must be <sdf>")
    models = root.findall("model")
    for world in root.findall("world"):
        if world.find("include") is not None:  # with or without local models: not read
            raise r.fail(
                f"<world name={world.get('name')!r}> <include>",
                "models included by URI are not supported: put the <model> in the file",
            )
        models += world.findall("model")
    if root.find("include") is not None:
        raise r.fail("<sdf> <include>", "models included by URI are not supported")
    if not models:
        raise r.fail("<sdf>", "no <model> (directly or in a <world>)")
    if len(models) > 1:
        names = [m.get("name") or "?" for m in models]
        raise r.fail("<sdf>", f"several models ({_some(names)}); one model is supported")
    model = models[0]
    where = f"<model name={model.get('name')!r}>"
    if model.find("model") is not None:
        raise r.fail(where + " <model>", "nested models are not supported")
    if model.find("include") is not None:
        raise r.fail(where + " <include>", "included models are not supported")
    return model


def parse_sdf(source: str | os.PathLike[str] | bytes, *, loops: str = "error") -> RobotSpec:
    """Parse an SDF file (or SDF text) into a :class:`~torchlie.kinematics.RobotSpec`.

    See the module docstring for the frame rules, the root and what is supported.  Each joint
    becomes a :class:`~torchlie.kinematics.JointSpec` whose origin is the child link's pose in
    the parent link's frame at ``q = 0``, whose axis and ``anchor`` (the joint frame's origin)
    are in the child link's frame: the motion ``X_parent_joint M(q) X_joint_child`` written
    about the child's frame.

    Args:
        source: a path to an ``.sdf`` file, or the XML text (a string or bytes starting with
            ``<``, after a byte-order mark and whitespace).
        loops: ``"error"`` (default): a link that is the child of several joints is an error;
            ``"skip"``: keep the first supported joint of each link, leave the others out.

    Raises:
        SDFError: a malformed or unsupported file (names the file, the element, the problem).

    Example:
        >>> spec = parse_sdf('''<sdf version="1.7"><model name="m">
        ...   <link name="base"/><link name="arm"><pose>0 0 1 0 0 0</pose></link>
        ...   <joint name="j" type="revolute"><parent>base</parent><child>arm</child>
        ...     <axis><xyz>0 1 0</xyz><limit><lower>-1</lower><upper>1</upper></limit></axis>
        ...   </joint></model></sdf>''')
        >>> spec.root, spec.links, [(j.name, j.parent, j.child) for j in spec.joints]
        ('__model__', ('__model__', 'base', 'arm'), [('base:fixed', '__model__', 'base'), \
('j', 'base', 'arm')])
    """
    if loops not in ("error", "skip"):
        raise ValueError(
            f"torchlie.kinematics.parse_sdf: loops must be 'error' or 'skip', got {loops!r}"
        )
    data: str | bytes
    if isinstance(source, bytes) and source.lstrip(b"\xef\xbb\xbf \t\r\n").startswith(b"<"):
        label, data = "<string>", source  # the XML declaration names the encoding
    elif isinstance(source, str) and source.lstrip("\ufeff \t\r\n").startswith("<"):
        label, data = "<string>", source
    else:
        label = os.fsdecode(source)
        with open(label, "rb") as f:
            data = f.read()
    r = _Reader(label)
    try:
        root = ET.fromstring(data)
    except ET.ParseError as e:
        raise r.fail("<sdf>", f"not well-formed XML: {e}") from None
    except LookupError as e:  # an encoding Python does not know
        raise r.fail("<?xml encoding?>", f"cannot decode the file: {e}") from None
    _strip_namespaces(root)
    version = _version(r, root)
    model = _the_model(r, root)

    # Frames: name -> pose relative to another frame.  Joint frames also by joint name:
    # before SDFormat 1.7 a joint may share its name with a link (names were unique per type).
    frames: dict[str, _Frame] = {}
    joint_frames: dict[str, _Frame] = {}
    links: list[str] = []
    own_names: set[str] = set()  # of the links and <frame>s
    shared_names = version >= (1, 7)

    def add(name: str | None, el: ET.Element, tag: str, default_rel: str) -> str:
        where = f"<{tag} name={name!r}>"
        if not name:
            raise r.fail(f"<{tag}>", "missing attribute 'name'")
        if shared_names:
            taken: dict[str, _Frame] | set[str] = frames
        else:
            taken = joint_frames if tag == "joint" else own_names
        if name in taken or name in ("__model__", "world"):
            raise r.fail(where, f"the name {name!r} is already taken")
        pose_el = el.find("pose")
        rel = default_rel
        if pose_el is not None:  # SDFormat 1.5-1.6 spelled relative_to "frame"
            given = (pose_el.get("relative_to") or pose_el.get("frame") or "").strip()
            rel = given or rel
        frame = _Frame(rel, r.pose(pose_el, where + " <pose>"))
        if tag == "joint":  # before 1.7, a link or <frame> of the same name keeps the name
            joint_frames[name] = frame
            frames.setdefault(name, frame)
        else:
            own_names.add(name)
            frames[name] = frame
        return name

    for el in model.findall("link"):
        links.append(add(el.get("name"), el, "link", "__model__"))
    joints_el = model.findall("joint")
    for el in joints_el:
        where = f"<joint name={el.get('name')!r}>"
        add(el.get("name"), el, "joint", r.text(el, "child", where))
    for el in model.findall("frame"):
        attached = (el.get("attached_to") or "").strip() or "__model__"
        add(el.get("name"), el, "frame", attached)

    resolved: dict[str, Tensor] = {
        "__model__": torch.eye(4, dtype=torch.float64),
        "world": torch.eye(4, dtype=torch.float64),
    }

    def in_model(name: str, where: str) -> Tensor:
        """``X_model_name`` (the zero configuration), following ``relative_to``."""
        chain: list[str] = []
        cur = name
        while cur not in resolved:
            if cur not in frames:
                raise r.fail(where, f"unknown frame {cur!r}")
            if cur in chain:
                raise r.fail(where, f"the poses' relative_to form a cycle: {_some(chain)}")
            chain.append(cur)
            cur = frames[cur].relative_to
        for f in reversed(chain):
            resolved[f] = resolved[frames[f].relative_to] @ frames[f].pose
        return resolved[name]

    # The tree: each link's first parent joint of a supported type.
    parents: dict[str, list[ET.Element]] = {}
    for el in joints_el:
        name = el.get("name", "")
        where = f"<joint name={name!r}>"
        parent, child = r.text(el, "parent", where), r.text(el, "child", where)
        if parent == child:
            raise r.fail(where, f"link {child!r} is both its <parent> and its <child>")
        if child not in links:
            raise r.fail(where + " <child>", f"{child!r} is not a link of the model")
        if parent not in links and parent != "world":
            raise r.fail(where + " <parent>", f"{parent!r} is not a link of the model")
        parents.setdefault(child, []).append(el)
    tree: dict[str, ET.Element] = {}
    for child, els in parents.items():
        where = f"<joint name={els[0].get('name')!r}>"
        if len(els) > 1 and loops == "error":
            names = [e.get("name", "") for e in els]
            raise r.fail(
                where,
                f"link {child!r} is the child of several joints ({_some(names)}: a kinematic "
                "loop); parse_sdf(..., loops='skip') keeps the first of a supported type",
            )
        ok = [e for e in els if (e.get("type") or "").strip() in SDF_JOINT_TYPES]
        if not ok:
            raise r.fail(
                where,
                f"joint type {(els[0].get('type') or '').strip()!r} is not supported "
                f"(supported: {', '.join(SDF_JOINT_TYPES)})",
            )
        tree[child] = ok[0]
    uses_world = any(r.text(el, "parent", "") == "world" for el in tree.values())
    root = "world" if uses_world else "__model__"

    joints: list[JointSpec] = []
    for link in links:
        if link not in tree:
            X = in_model(link, f"<link name={link!r}>")
            joints.append(_fixed(f"{link}:fixed", root, link, X))
    for el in joints_el:
        child = _child_of(el, r)
        if tree.get(child) is not el:
            continue
        jf = joint_frames[el.get("name", "")]
        X_MJ = in_model(jf.relative_to, f"<joint name={el.get('name')!r}> <pose>") @ jf.pose
        joints.extend(_joint(r, el, in_model, root, X_MJ, version))
    _check_acyclic(r, root, links, joints)
    return RobotSpec(model.get("name") or "sdf", (root, *links), tuple(joints), root, label)


def _child_of(el: ET.Element, r: _Reader) -> str:
    return r.text(el, "child", f"<joint name={el.get('name')!r}>")


def _quat(R: Tensor) -> tuple[float, float, float, float]:
    q = _quaternion.from_matrix(R)
    return tuple(float(x) for x in q)  # type: ignore[return-value]


def _fixed(name: str, parent: str, child: str, X: Tensor) -> JointSpec:
    t = tuple(float(x) for x in X[:3, 3])
    return JointSpec(name, "fixed", parent, child, xyz=t, quat=_quat(X[:3, :3]))  # type: ignore[arg-type]


def _joint(  # noqa: ANN001
    r: _Reader, el: ET.Element, in_model, root: str, X_MJ: Tensor, version: tuple[int, int]
) -> list[JointSpec]:
    name = el.get("name", "")
    where = f"<joint name={name!r}>"
    jtype = (el.get("type") or "").strip()
    parent, child = r.text(el, "parent", where), r.text(el, "child", where)
    X_MP = (
        in_model(parent, where + " <parent>")
        if parent != "world"
        else torch.eye(4, dtype=torch.float64)
    )
    X_MC = in_model(child, where + " <child>")
    X_PC = torch.linalg.solve(X_MP, X_MC)
    R_MC = X_MC[:3, :3]
    t = tuple(float(x) for x in X_PC[:3, 3])
    parent = root if parent == "world" else parent
    if jtype == "ball":  # the joint frame turns: a frame between parent and child
        X_PJ = torch.linalg.solve(X_MP, X_MJ)
        X_JC = torch.linalg.solve(X_MJ, X_MC)
        mid = f"{child}:{name}"
        t_PJ = tuple(float(x) for x in X_PJ[:3, 3])
        return [
            JointSpec(name, "ball", parent, mid, xyz=t_PJ, quat=_quat(X_PJ[:3, :3])),  # type: ignore[arg-type]
            _fixed(f"{name}:frame", mid, child, X_JC),
        ]
    if jtype == "fixed":
        return [JointSpec(name, "fixed", parent, child, xyz=t, quat=_quat(X_PC[:3, :3]))]  # type: ignore[arg-type]
    axis_el = el.find("axis")
    a = [0.0, 0.0, 1.0]
    expressed_in = ""
    parent_model_frame: bool | None = None  # <use_parent_model_frame> (before 1.7)
    lower = upper = None
    if axis_el is not None:
        xyz_el = axis_el.find("xyz")
        if xyz_el is not None:
            a = r.numbers(xyz_el.text, where + " <axis> <xyz>", "xyz")
            if len(a) != 3 or math.hypot(*a) == 0.0:
                raise r.fail(
                    where + " <axis> <xyz>", f"expected a non-zero 3-vector, got {xyz_el.text!r}"
                )
            expressed_in = (xyz_el.get("expressed_in") or "").strip()
        upm = axis_el.find("use_parent_model_frame")
        if upm is not None:
            on = (upm.text or "").strip().lower() in ("1", "true")
            if version >= (1, 7) and on:
                raise r.fail(
                    where + " <axis> <use_parent_model_frame>",
                    "is SDFormat 1.4-1.6 (removed in 1.7): write "
                    "<xyz expressed_in='__model__'>, or declare the file's <sdf version>",
                )
            parent_model_frame = on if version < (1, 7) else None
        lim = axis_el.find("limit")
        if lim is not None and jtype != "continuous":
            lower, upper = _limits(r, lim, where + " <axis> <limit>")
    if parent_model_frame or (parent_model_frame is None and version < (1, 5) and not expressed_in):
        R_MF = torch.eye(3, dtype=torch.float64)  # the model frame (SDFormat 1.4's default)
    elif expressed_in:
        R_MF = in_model(expressed_in, where + " <axis> <xyz expressed_in>")[:3, :3]
    else:  # the joint frame
        R_MF = X_MJ[:3, :3]
    axis = R_MC.mT @ (R_MF @ torch.tensor(a, dtype=torch.float64))
    anchor = R_MC.mT @ (X_MJ[:3, 3] - X_MC[:3, 3])
    if jtype == "revolute" and lower is None and upper is None:  # SDF's default: no limit
        jtype = "continuous"
    return [
        JointSpec(
            name,
            jtype,
            parent,
            child,
            xyz=t,  # type: ignore[arg-type]
            quat=_quat(X_PC[:3, :3]),
            axis=tuple(float(x) for x in axis),  # type: ignore[arg-type]
            axis_given=True,
            lower=lower,
            upper=upper,
            anchor=tuple(float(x) for x in anchor) if jtype != "prismatic" else (0.0, 0.0, 0.0),  # type: ignore[arg-type]
        )
    ]


def _limits(r: _Reader, lim: ET.Element, where: str) -> tuple[float | None, float | None]:
    """``<lower>``, ``<upper>`` of a ``<limit>``; ``None`` where absent or SDF's default
    (``+-1e16``, beyond ``+-1e15``: no limit on that side)."""
    out: list[float | None] = []
    for tag in ("lower", "upper"):
        v = r.numbers(lim.findtext(tag), where, tag)
        if len(v) > 1:
            raise r.fail(where, f"<{tag}> must be one number, got {lim.findtext(tag)!r}")
        out.append(v[0] if v and abs(v[0]) < _NO_LIMIT else None)
    lower, upper = out
    if lower is not None and upper is not None and lower > upper:
        raise r.fail(where, f"<lower> {lower!r} is above <upper> {upper!r}")
    return lower, upper


def _check_acyclic(r: _Reader, root: str, links: list[str], joints: list[JointSpec]) -> None:
    """Every link reachable from the root (a joint cycle would leave links unreached)."""
    children: dict[str, list[str]] = {}
    for j in joints:
        children.setdefault(j.parent, []).append(j.child)
    seen = {root}
    frontier = [root]
    while frontier:
        frontier = [c for p in frontier for c in children.get(p, []) if c not in seen]
        seen.update(frontier)
    lost = [n for n in links if n not in seen]
    if lost:
        raise r.fail("<model>", f"the joints form a cycle through the links {_some(lost)}")
