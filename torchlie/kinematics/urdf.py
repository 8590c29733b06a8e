"""URDF parsing into a validated, immutable robot description.

Only the kinematic and inertial parts of URDF are read: ``<robot>``, ``<link name>`` with its
``<inertial>`` (``<origin>``, ``<mass value>``, ``<inertia ixx ixy ixz iyy iyz izz>``; both
``<mass>`` and ``<inertia>`` required, the mass not negative) and ``<joint>`` with its
``<parent>``, ``<child>``, ``<origin>``, ``<axis>``, ``<limit>`` and ``<mimic>`` elements.
Everything else (visuals, collisions, transmissions, gazebo tags, ...) is ignored.

The parser is the standard library's :mod:`xml.etree.ElementTree`: it is always present, so
kinematics adds no runtime dependency, and URDF's kinematic subset is small enough that the
checks a robot needs (one root, no cycles, known joint types, finite numbers) are clearer written
out here than inherited from a general-purpose URDF library.

Numbers must be written in the XML Schema ``double`` syntax: an optional sign, ASCII digits
with an optional fraction, an optional exponent, e.g. ``-1``, ``.5``, ``2.``, ``1e-3``,
``+4.5E+2``; ``INF``, ``+INF``, ``-INF`` and ``NaN`` are the Schema's spellings of the
non-finite values, which are then rejected as not finite.  Anything else (``1_000``, ``0x10``,
``inf``, ``nan``, ``Infinity``, non-ASCII digits, ...) is not a number, although Python's
``float`` would read it: a deliberate convention, so that a file means the same here as in
other XML tools.  Surrounding XML whitespace (space, tab, CR, LF) is ignored, and lists such as
``xyz`` are separated by it (not by other Unicode spaces).  A number is correctly rounded to
float64 and kept as a Python float; no float32 rounding happens on the way to
:class:`~torchlie.kinematics.Chain`.  Every finite double is accepted here; what a chain does
with values beyond its dtype's range is in :mod:`torchlie.kinematics.chain`.

Defaults follow the URDF specification: a missing ``<origin>`` is the identity, missing
``xyz``/``rpy`` are zeros, a missing ``<axis>`` is ``(1, 0, 0)``, ``<limit lower/upper>``
default to 0, ``<mimic multiplier>`` to 1 and ``offset`` to 0.  A ``<mimic>`` on a fixed
joint, which has no value to set, is ignored (as urdfdom does: robots such as TALOS carry
one); on a planar or floating joint it is an error.

Every problem raises :class:`URDFError` (a :class:`ValueError`) naming the file (or
``"<string>"``), the element and what is wrong.  Names and values taken from the file are
quoted with :func:`repr` in these messages, so a name containing a newline or another control
character shows as an escape and cannot forge a line of a log.  Where several names are at
fault (root links, the joints of a cycle) a message names the first five and says how many
there are, so it stays short for a file of any size.
"""

from __future__ import annotations

import math
import os
import re
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass

__all__ = [
    "JOINT_TYPES",
    "URDFError",
    "InertialSpec",
    "JointSpec",
    "MimicSpec",
    "RobotSpec",
    "parse_urdf",
]

#: Joint types of the URDF specification, all supported.
JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed", "floating", "planar")

_ONE_DOF = ("revolute", "continuous", "prismatic")

# XML Schema 1.1 ``xsd:double`` (1.0 plus "+INF"); ASCII digits only.
_DOUBLE = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|[+-]?INF|NaN")
# XML whitespace (Python's str.split/strip would also take Unicode spaces).
_XML_SPACE = " \t\r\n"
_XML_SPLIT = re.compile(r"[ \t\r\n]+")

#: How many names a message lists before it says how many more there are.
_SHOWN = 5


class URDFError(ValueError):
    """A malformed or unsupported URDF.

    Attributes:
        source: the file name, or ``"<string>"`` for XML text.
        element: the offending element, e.g. ``"<joint name='elbow'> <origin>"`` (the name as
            :func:`repr` writes it).
        problem: what is wrong with it (values from the file quoted by :func:`repr`).

    The message is ``"{source}: {element}: {problem}"``; a file name with a non-printable
    character is written as its :func:`repr` there.
    """

    def __init__(self, source: str, element: str, problem: str) -> None:
        self.source = source
        self.element = element
        self.problem = problem
        label = source if source.isprintable() else repr(source)
        super().__init__(f"{label}: {element}: {problem}")


@dataclass(frozen=True)
class MimicSpec:
    """``<mimic joint multiplier offset>``: value = ``multiplier * q[joint] + offset``."""

    joint: str
    multiplier: float = 1.0
    offset: float = 0.0


@dataclass(frozen=True)
class JointSpec:
    """One ``<joint>`` element, with the URDF defaults filled in.

    ``axis`` is the axis exactly as written (not normalised; ``(1, 0, 0)`` when the element is
    omitted, and then ``axis_given`` is False).  ``lower``/``upper`` are the position limits
    (``None`` where the joint type has none); ``effort``/``velocity`` are kept as metadata.
    The MJCF loader also makes ``ball`` (value: a quaternion ``w, x, y, z``) and ``free``
    (position, then a quaternion) joints.
    """

    name: str
    type: str
    parent: str
    child: str
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    axis: tuple[float, float, float] = (1.0, 0.0, 0.0)
    axis_given: bool = False
    lower: float | None = None
    upper: float | None = None
    effort: float | None = None
    velocity: float | None = None
    mimic: MimicSpec | None = None
    # Set by the MJCF loader only (URDF has no such attributes): the origin's rotation as a
    # unit quaternion ``(w, x, y, z)`` (replaces ``rpy`` when given), the point of the joint
    # frame a rotation turns about, and the joint value at which the joint is at its origin
    # (MuJoCo's ``ref``): ``M(q - ref)``.
    quat: tuple[float, float, float, float] | None = None
    anchor: tuple[float, float, float] = (0.0, 0.0, 0.0)
    ref: float = 0.0
    # The joint's armature (MuJoCo's ``armature``: rotor inertia reflected to the joint, kg m^2
    # or kg), added to the mass matrix's diagonal entry of each of its velocity coordinates;
    # URDF and SDF have none: 0.
    armature: float = 0.0


@dataclass(frozen=True)
class InertialSpec:
    """A link's ``<inertial>``: ``mass`` (kg), the centre of mass and the frame of ``inertia``
    (``xyz``, ``rpy`` of its ``<origin>``, in the link's frame) and the rotational inertia
    about the centre of mass in that frame, ``(ixx, ixy, ixz, iyy, iyz, izz)`` (kg m^2)."""

    mass: float
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    inertia: tuple[float, float, float, float, float, float] = (0.0,) * 6


@dataclass(frozen=True)
class RobotSpec:
    """A parsed, validated robot: a tree of links joined by joints.

    ``links`` and ``joints`` are in document order; ``root`` is the one link that is no joint's
    child; ``source`` is the file name or ``"<string>"``; ``inertials`` holds each link's
    :class:`InertialSpec` (``None`` for a link without ``<inertial>``) in ``links`` order, or
    is empty (no link has one).
    """

    name: str
    links: tuple[str, ...]
    joints: tuple[JointSpec, ...]
    root: str
    source: str
    inertials: tuple[InertialSpec | None, ...] = ()

    def joint(self, name: str) -> JointSpec:
        """The joint called ``name`` (``KeyError`` if there is none)."""
        for j in self.joints:
            if j.name == name:
                return j
        raise KeyError(name)

    def parent_joint(self, link: str) -> JointSpec | None:
        """The joint whose child is ``link`` (``None`` for the root)."""
        for j in self.joints:
            if j.child == link:
                return j
        return None


def _describe(tag: str, name: str | None, index: int, sub: str | None = None) -> str:
    head = f"<{tag} name={name!r}>" if name else f"<{tag}> #{index + 1}"
    return f"{head} <{sub}>" if sub else head


def _some(names: Sequence[str], sep: str = ", ", quote: bool = True) -> str:
    """The first :data:`_SHOWN` of ``names`` (quoted by :func:`repr`, unless ``quote`` is
    False) joined by ``sep``, then how many more there are: ``'a', 'b', ... and 7995 more``."""
    text = sep.join(repr(n) if quote else n for n in names[:_SHOWN])
    more = len(names) - _SHOWN
    return f"{text} and {more} more" if more > 0 else text


def _local(tag: object) -> str:
    """Tag without an XML namespace."""
    tag = str(tag)
    return tag.rsplit("}", 1)[-1]


class _Reader:
    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, element: str, problem: str) -> URDFError:
        return URDFError(self.source, element, problem)

    def attr(self, el: ET.Element, key: str, where: str) -> str:
        value = el.get(key)
        if value is None:
            raise self.fail(where, f"missing required attribute '{key}'")
        value = value.strip(_XML_SPACE)
        if not value:
            raise self.fail(where, f"attribute '{key}' is empty")
        return value

    def number(self, text: str, key: str, where: str) -> float:
        """``text`` (XML whitespace already stripped) as an XML Schema double, finite."""
        if _DOUBLE.fullmatch(text) is None:
            raise self.fail(where, f"attribute '{key}' is not a number: {text!r}")
        value = float(text)  # every string _DOUBLE matches is one float() reads the same way
        if not math.isfinite(value):
            raise self.fail(where, f"attribute '{key}' is not finite: {text!r}")
        return value

    def opt_number(self, el: ET.Element, key: str, where: str) -> float | None:
        text = el.get(key)
        return None if text is None else self.number(text.strip(_XML_SPACE), key, where)

    def vec3(self, el: ET.Element, key: str, where: str) -> tuple[float, float, float] | None:
        text = el.get(key)
        if text is None:
            return None
        stripped = text.strip(_XML_SPACE)
        parts = _XML_SPLIT.split(stripped) if stripped else []
        if len(parts) != 3:
            raise self.fail(where, f"attribute '{key}' must be three numbers, got {text!r}")
        x, y, z = (self.number(p, key, where) for p in parts)
        return (x, y, z)

    def children(self, el: ET.Element, tag: str) -> list[ET.Element]:
        return [c for c in el if _local(c.tag) == tag]

    def single(self, subs: dict[str, list[ET.Element]], tag: str, where: str) -> ET.Element | None:
        """The one ``<tag>`` among ``subs`` (an element's children by tag), if any."""
        found = subs.get(tag, ())
        if len(found) > 1:
            raise self.fail(where, f"more than one <{tag}> element")
        return found[0] if found else None


def _read_joint(r: _Reader, el: ET.Element, index: int) -> JointSpec:
    name_attr = el.get("name")
    where = _describe("joint", name_attr, index)
    name = r.attr(el, "name", where)
    jtype = r.attr(el, "type", where)
    subs: dict[str, list[ET.Element]] = {}  # children by tag, read once
    for c in el:
        subs.setdefault(_local(c.tag), []).append(c)
    if jtype not in JOINT_TYPES:
        raise r.fail(
            where, f"unknown joint type {jtype!r} (expected one of {', '.join(JOINT_TYPES)})"
        )

    links = {}
    for tag in ("parent", "child"):
        sub = r.single(subs, tag, where)
        if sub is None:
            raise r.fail(where, f"missing required element <{tag}>")
        links[tag] = r.attr(sub, "link", _describe("joint", name, index, tag))

    xyz = rpy = None
    origin = r.single(subs, "origin", where)
    if origin is not None:
        w = _describe("joint", name, index, "origin")
        xyz = r.vec3(origin, "xyz", w)
        rpy = r.vec3(origin, "rpy", w)

    axis = None
    axis_el = r.single(subs, "axis", where)
    if axis_el is not None:
        w = _describe("joint", name, index, "axis")
        axis = r.vec3(axis_el, "xyz", w)
        if axis is None:
            raise r.fail(w, "missing required attribute 'xyz'")
        if jtype != "fixed" and math.hypot(*axis) == 0.0:
            raise r.fail(w, "the axis is the zero vector")

    lower = upper = effort = velocity = None
    limit = r.single(subs, "limit", where)
    if limit is not None:
        w = _describe("joint", name, index, "limit")
        effort = r.opt_number(limit, "effort", w)
        velocity = r.opt_number(limit, "velocity", w)
        if jtype in ("revolute", "prismatic"):
            lower = r.opt_number(limit, "lower", w)
            upper = r.opt_number(limit, "upper", w)
            lower = 0.0 if lower is None else lower
            upper = 0.0 if upper is None else upper
            if lower > upper:
                raise r.fail(w, f"lower limit {lower} is above upper limit {upper}")
    elif jtype in ("revolute", "prismatic"):
        raise r.fail(where, f"a {jtype} joint requires a <limit> element")

    mimic = None
    mimic_el = r.single(subs, "mimic", where)
    if mimic_el is not None and jtype != "fixed":  # a fixed joint has no value to set
        w = _describe("joint", name, index, "mimic")
        if jtype not in _ONE_DOF:
            raise r.fail(w, f"a {jtype} joint cannot mimic another joint")
        target = r.attr(mimic_el, "joint", w)
        mult = r.opt_number(mimic_el, "multiplier", w)
        off = r.opt_number(mimic_el, "offset", w)
        mimic = MimicSpec(target, 1.0 if mult is None else mult, 0.0 if off is None else off)

    return JointSpec(
        name=name,
        type=jtype,
        parent=links["parent"],
        child=links["child"],
        xyz=xyz or (0.0, 0.0, 0.0),
        rpy=rpy or (0.0, 0.0, 0.0),
        axis=axis or (1.0, 0.0, 0.0),
        axis_given=axis is not None,
        lower=lower,
        upper=upper,
        effort=effort,
        velocity=velocity,
        mimic=mimic,
    )


def _read_inertial(r: _Reader, link: ET.Element, lname: str, index: int) -> InertialSpec | None:
    where = _describe("link", lname, index, "inertial")
    subs: dict[str, list[ET.Element]] = {}
    for c in link:
        subs.setdefault(_local(c.tag), []).append(c)
    el = r.single(subs, "inertial", _describe("link", lname, index))
    if el is None:
        return None
    inner: dict[str, list[ET.Element]] = {}
    for c in el:
        inner.setdefault(_local(c.tag), []).append(c)
    xyz = rpy = None
    origin = r.single(inner, "origin", where)
    if origin is not None:
        xyz = r.vec3(origin, "xyz", f"{where} <origin>")
        rpy = r.vec3(origin, "rpy", f"{where} <origin>")
    mass_el = r.single(inner, "mass", where)
    if mass_el is None:
        raise r.fail(where, "missing required element <mass>")
    w = f"{where} <mass>"
    mass = r.number(r.attr(mass_el, "value", w), "value", w)
    if mass < 0.0:
        raise r.fail(w, f"the mass is negative: {mass!r}")
    inertia_el = r.single(inner, "inertia", where)
    if inertia_el is None:
        raise r.fail(where, "missing required element <inertia>")
    w = f"{where} <inertia>"
    keys = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
    ixx, ixy, ixz, iyy, iyz, izz = (r.number(r.attr(inertia_el, k, w), k, w) for k in keys)
    return InertialSpec(
        mass, xyz or (0.0, 0.0, 0.0), rpy or (0.0, 0.0, 0.0), (ixx, ixy, ixz, iyy, iyz, izz)
    )


def _check_tree(r: _Reader, links: list[str], joints: list[JointSpec]) -> str:
    """Check the links and joints form one tree; return its root link."""
    link_set = set(links)
    parent_of: dict[str, JointSpec] = {}
    for j in joints:
        where = _describe("joint", j.name, 0)
        for role, link in (("parent", j.parent), ("child", j.child)):
            if link not in link_set:
                raise r.fail(
                    f"{where} <{role}>", f"link {link!r} is not declared by any <link> element"
                )
        if j.parent == j.child:
            raise r.fail(where, f"cycle: link {j.child!r} is its own parent")
        if j.child in parent_of:
            other = parent_of[j.child].name
            raise r.fail(
                where, f"link {j.child!r} is already the child of joint {other!r} (not a tree)"
            )
        parent_of[j.child] = j

    roots = [link for link in links if link not in parent_of]
    if len(roots) > 1:
        raise r.fail(
            "<robot>",
            f"{len(roots)} root links ({_some(roots)}); exactly one link may be without a "
            "parent joint",
        )

    # With every other link having exactly one parent, a link that is not reachable from the
    # root lies on (or below) a cycle: walk up its parents until a link repeats.
    reachable = set(roots)
    children: dict[str, list[str]] = {}
    for j in joints:
        children.setdefault(j.parent, []).append(j.child)
    stack = list(roots)
    while stack:
        for c in children.get(stack.pop(), []):
            if c not in reachable:
                reachable.add(c)
                stack.append(c)
    for link in links:
        if link in reachable:
            continue
        seen: dict[str, int] = {}  # link -> position on the walk up
        cur = link
        while cur not in seen:
            seen[cur] = len(seen)
            cur = parent_of[cur].parent
        cycle = list(seen)[seen[cur] :]
        down = list(reversed(cycle))  # joints in parent -> child order
        names = _some([parent_of[x].name for x in down], " -> ")
        loop = _some([parent_of[x].parent for x in down])
        raise r.fail(
            _describe("joint", parent_of[cur].name, 0),
            f"cycle through {len(down)} joints {names} (links {loop})",
        )
    return roots[0]


def _check_mimics(r: _Reader, joints: list[JointSpec]) -> None:
    """Each mimic names an existing one-DoF joint, and following mimics never loops.

    Linear in the number of joints: a chain of mimics is walked once; every joint on a walk
    that ends (at a joint with its own DoF, or at a missing joint reported when that joint is
    checked) is remembered as ending, and later walks stop there.
    """
    by_name = {j.name: j for j in joints}
    ends: set[str] = set()  # joints whose mimic chain is known to end
    for j in joints:
        if j.mimic is None:
            continue
        where = _describe("joint", j.name, 0, "mimic")
        target = by_name.get(j.mimic.joint)
        if target is None:
            raise r.fail(where, f"mimicked joint {j.mimic.joint!r} does not exist")
        if target.type not in _ONE_DOF:
            raise r.fail(
                where, f"mimicked joint {target.name!r} is {target.type}, not a one-DoF joint"
            )
        # Follow the chain of mimics to make sure it ends at a joint with its own DoF.
        walk: dict[str, int] = {}  # joint -> position on this walk
        cur: JointSpec | None = j
        while cur is not None and cur.mimic is not None and cur.name not in ends:
            if cur.name in walk:
                n = len(walk) - walk[cur.name]  # the walk may lead into the cycle
                path = _some([*walk, cur.name], " -> ")
                raise r.fail(where, f"mimic cycle of {n} joint{'s' * (n > 1)}: {path}")
            walk[cur.name] = len(walk)
            cur = by_name.get(cur.mimic.joint)
        ends.update(walk)


def _parse_root(r: _Reader, root: ET.Element) -> RobotSpec:
    if _local(root.tag) != "robot":
        raise r.fail(f"<{_local(root.tag)}>", "the root element must be <robot>")
    name = r.attr(root, "name", "<robot>")

    links: dict[str, InertialSpec | None] = {}  # ordered: document order, constant-time lookups
    for i, el in enumerate(r.children(root, "link")):
        lname = r.attr(el, "name", _describe("link", None, i))
        if lname in links:
            raise r.fail(_describe("link", lname, i), "duplicate link name")
        links[lname] = _read_inertial(r, el, lname, i)
    if not links:
        raise r.fail("<robot>", "no <link> elements")

    joints: list[JointSpec] = []
    names: set[str] = set()
    for i, el in enumerate(r.children(root, "joint")):
        j = _read_joint(r, el, i)
        if j.name in names:
            raise r.fail(_describe("joint", j.name, i), "duplicate joint name")
        names.add(j.name)
        joints.append(j)

    root_link = _check_tree(r, list(links), joints)
    _check_mimics(r, joints)
    inertials = tuple(links.values()) if any(v is not None for v in links.values()) else ()
    return RobotSpec(name, tuple(links), tuple(joints), root_link, r.source, inertials)


def _looks_like_xml(text: str) -> bool:
    return text.lstrip("\ufeff \t\r\n").startswith("<")  # a byte-order mark may lead


def parse_urdf(source: str | os.PathLike[str] | bytes) -> RobotSpec:
    """Parse a URDF file or URDF text into a validated :class:`RobotSpec`.

    Args:
        source: a path to a ``.urdf`` file, or the XML text itself (a string starting with
            ``<``, or bytes).

    Raises:
        URDFError: malformed XML, a missing required element or attribute, a malformed
            number, an unknown joint type, a link that is not declared, two roots, a cycle,
            or a mimic joint pointing at nothing.  The message names the file (or
            ``"<string>"``), the element and the problem.
        FileNotFoundError: ``source`` is a path that does not exist.

    Example:
        >>> spec = parse_urdf('''<robot name="r"><link name="a"/><link name="b"/>
        ...   <joint name="j" type="continuous"><parent link="a"/><child link="b"/></joint>
        ... </robot>''')
        >>> spec.root, spec.joints[0].axis, spec.joints[0].axis_given
        ('a', (1.0, 0.0, 0.0), False)
    """
    if isinstance(source, bytes):
        label, data = "<string>", source
    elif isinstance(source, str) and _looks_like_xml(source):
        label, data = "<string>", source.encode("utf-8")
    else:
        label = os.fspath(source)
        with open(label, "rb") as f:
            data = f.read()
    r = _Reader(label)
    try:
        root = ET.fromstring(data)
    except ET.ParseError as e:
        line, col = e.position
        raise r.fail(f"line {line}, column {col + 1}", f"not well-formed XML ({e})") from None
    return _parse_root(r, root)
