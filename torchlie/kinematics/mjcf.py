"""MJCF (MuJoCo's XML) robots, read through MuJoCo's own compiler.

MJCF is a large language: defaults classes, ``childclass``, ``<compiler angle eulerseq>``,
``<include>``, frames and five ways to write an orientation.  Rather than a second reading of
it, the file is compiled by MuJoCo (the optional ``mujoco`` package: ``pip install
torchlie[mjcf]``) and the kinematic tree is taken from the compiled model's arrays
(``body_parentid``, ``body_pos``, ``body_quat``, ``jnt_type``, ``jnt_pos``, ``jnt_axis``,
``qpos0``, ``jnt_range``, ...), so every file means here what it means in MuJoCo.

The result is the same :class:`~torchlie.kinematics.RobotSpec` the URDF parser makes:

* one link per body, named as the body; an unnamed body ``i`` (MuJoCo's body index) is called
  ``"body_{i}"`` (with ``_`` appended while that name is taken).  The world body is the root
  (MuJoCo names it ``"world"``).  A mocap body stays at its model pose.
* Joints ``hinge`` (made a ``revolute`` joint, ``continuous`` when it is not limited),
  ``slide`` (``prismatic``), ``ball`` and ``free``; a body without joints is attached by a
  ``fixed`` joint.  Unnamed joints are called ``"joint_{j}"`` (MuJoCo's joint index).
  A body with several joints applies them in order, each in the frame the previous ones
  moved, as MuJoCo does; the frames between them are links of the chain that are not in
  :attr:`~torchlie.kinematics.Chain.link_names` (named ``"{body}:{joint}"``).
* ``q`` is MuJoCo's ``qpos``: one value per hinge or slide joint, a unit quaternion
  ``(w, x, y, z)`` per ball joint, the position then the quaternion per free joint, in
  MuJoCo's joint order; quaternions are normalised by the forward kinematics (a zero one gives
  NaN poses for that batch element, where MuJoCo would use the identity).  A hinge or slide
  joint with ``ref`` is at its origin for ``q = ref``; ``jnt_pos`` is the point a hinge or
  ball turns about.  A free joint sets the body's world pose (it ignores the body's ``pos``
  and ``quat``, which only give its ``qpos0``).
* Each body's inertial (for the dynamics) is MuJoCo's compiled ``body_mass``, ``body_ipos``
  and ``body_inertia`` along ``body_iquat``, in the body's frame; the frames between several
  joints of one body have none.  Each joint's ``armature`` (defaults classes applied; 0 when
  not set) is MuJoCo's compiled ``dof_armature`` at its first DoF, which MuJoCo gives each
  of a ball or free joint's DoFs alike; the dynamics add it to the mass matrix's diagonal.
* Position limits are the ``range`` of the limited hinge and slide joints (MuJoCo's compiled
  ``jnt_range``, in radians whatever ``<compiler angle>`` says); a ball joint's range (a cone)
  is not kept.

Errors: a file MuJoCo refuses raises :class:`MJCFError` with MuJoCo's message and the file
name; a missing ``mujoco`` package raises :class:`ImportError` naming the extra.
"""

from __future__ import annotations

import os
from typing import Any

from ._joints import quat_rows
from .urdf import InertialSpec, JointSpec, RobotSpec

__all__ = ["MJCFError", "parse_mjcf"]

# mjtJoint: free, ball, slide, hinge.
_FREE, _BALL, _SLIDE, _HINGE = 0, 1, 2, 3


class MJCFError(ValueError):
    """An MJCF file (or text) that MuJoCo's compiler refuses; the message is
    ``"{source}: {MuJoCo's message}"``.

    Attributes:
        source: the file name, or ``"<string>"`` for XML text.
        problem: MuJoCo's message.
    """

    def __init__(self, source: str, problem: str) -> None:
        self.source = source
        self.problem = problem
        label = source if source.isprintable() else repr(source)
        super().__init__(f"{label}: {problem}")


def _mujoco() -> Any:
    try:
        import mujoco
    except ImportError as e:
        raise ImportError(
            "torchlie.kinematics: reading MJCF needs the 'mujoco' package, which is not "
            "installed: pip install 'torchlie[mjcf]'"
        ) from e
    return mujoco


def _unique(name: str, taken: set[str]) -> str:
    while name in taken:
        name += "_"
    taken.add(name)
    return name


def _compile(source: Any) -> tuple[Any, str]:
    """The compiled ``MjModel`` of ``source`` (a path, XML text or an ``MjModel``) and the
    label its errors name."""
    mujoco = _mujoco()
    if isinstance(source, mujoco.MjModel):
        return source, "<MjModel>"
    if isinstance(source, bytes):
        source = source.decode("utf-8-sig")  # a UTF-8 byte-order mark dropped
    if isinstance(source, str) and source.lstrip("\ufeff \t\r\n").startswith("<"):
        label = "<string>"
        load = mujoco.MjModel.from_xml_string
        source = source.lstrip("\ufeff")
    elif isinstance(source, (str, os.PathLike)):
        label = os.fspath(source)
        load = mujoco.MjModel.from_xml_path
        source = label
    else:
        raise TypeError(
            "torchlie.kinematics.parse_mjcf: expected a path, MJCF text or a mujoco.MjModel, "
            f"got {type(source).__name__}"
        )
    try:
        return load(source), label
    except ValueError as e:  # MuJoCo's compiler and parser errors
        raise MJCFError(label, str(e).strip()) from None


def parse_mjcf(
    source: str | os.PathLike[str] | bytes | Any, *, sites: bool = False, site_prefix: str = ""
) -> RobotSpec:
    """Compile an MJCF file (or MJCF text, or take a compiled ``mujoco.MjModel``) with MuJoCo
    and describe its kinematic tree as a :class:`~torchlie.kinematics.RobotSpec`.

    See the module docstring for the naming and the joints; the numbers are MuJoCo's compiled
    float64 values.

    Args:
        source: a path to an ``.xml`` file, MJCF text (a string starting with ``<``) or a
            ``mujoco.MjModel``.
        sites: also make each ``<site>`` a link (after the bodies, fixed to its body; an
            unnamed site ``s`` is ``"site_{s}"``).
        site_prefix: put before every site's name to make its link's name, for models whose
            sites share names with bodies (MuJoCo keeps the two apart; a chain's links cannot:
            a site link named as a body is an error that names this argument).

    Raises:
        MJCFError: MuJoCo's compiler refused the file (its message, with the file name).
        ImportError: the ``mujoco`` package is not installed (``torchlie[mjcf]``).

    Example:
        >>> spec = parse_mjcf('''<mujoco><worldbody><body name="arm" pos="0 0 1">
        ...   <joint name="shoulder" axis="0 1 0"/><geom size="0.1"/></body>
        ...   </worldbody></mujoco>''')
        >>> spec.root, spec.links, [(j.name, j.type, j.xyz) for j in spec.joints]
        ('world', ('world', 'arm'), [('shoulder', 'continuous', (0.0, 0.0, 1.0))])
    """
    if not isinstance(site_prefix, str):
        raise TypeError(
            f"torchlie.kinematics.parse_mjcf: expected site_prefix to be a str, got "
            f"{type(site_prefix).__name__}"
        )
    m, label = _compile(source)
    mujoco = _mujoco()

    def name(kind: Any, i: int) -> str:
        return mujoco.mj_id2name(m, kind, i) or ""

    taken: set[str] = set()
    bodies = [name(mujoco.mjtObj.mjOBJ_BODY, i) for i in range(m.nbody)]
    for n in bodies:
        taken.add(n)
    bodies = [n if n else _unique(f"body_{i}", taken) for i, n in enumerate(bodies)]
    jtaken = {name(mujoco.mjtObj.mjOBJ_JOINT, j) for j in range(m.njnt)} - {""}
    jnames = [
        name(mujoco.mjtObj.mjOBJ_JOINT, j) or _unique(f"joint_{j}", jtaken) for j in range(m.njnt)
    ]

    def vec(a: Any) -> tuple[float, ...]:
        return tuple(float(x) for x in a)

    joints: list[JointSpec] = []
    for i in range(1, m.nbody):
        parent = bodies[int(m.body_parentid[i])]
        xyz, quat = vec(m.body_pos[i]), vec(m.body_quat[i])
        first, count = int(m.body_jntadr[i]), int(m.body_jntnum[i])
        if count == 0:
            fixed = _unique(f"{bodies[i]}:fixed", jtaken)
            joints.append(JointSpec(fixed, "fixed", parent, bodies[i], xyz=xyz, quat=quat))
            continue
        for k, j in enumerate(range(first, first + count)):
            jt = int(m.jnt_type[j])
            last = k == count - 1
            child = bodies[i] if last else _unique(f"{bodies[i]}:{jnames[j]}", taken)
            origin: dict[str, Any] = {"xyz": xyz, "quat": quat} if k == 0 else {}
            # the same value on each of the joint's DoFs (one attribute per joint)
            armature = float(m.dof_armature[int(m.jnt_dofadr[j])])
            if jt == _FREE:  # the body's world pose (free joints are on top-level bodies)
                joints.append(JointSpec(jnames[j], "free", parent, child, armature=armature))
            elif jt == _BALL:
                anchor = vec(m.jnt_pos[j])
                joints.append(
                    JointSpec(
                        jnames[j], "ball", parent, child, anchor=anchor, armature=armature, **origin
                    )
                )
            else:
                limited = bool(m.jnt_limited[j])
                lo, hi = (
                    (float(m.jnt_range[j][0]), float(m.jnt_range[j][1]))
                    if limited
                    else (None, None)
                )
                jtype = ("revolute" if limited else "continuous") if jt == _HINGE else "prismatic"
                joints.append(
                    JointSpec(
                        jnames[j],
                        jtype,
                        parent,
                        child,
                        axis=vec(m.jnt_axis[j]),
                        axis_given=True,
                        lower=lo,
                        upper=hi,
                        anchor=vec(m.jnt_pos[j]) if jt == _HINGE else (0.0, 0.0, 0.0),
                        ref=float(m.qpos0[int(m.jnt_qposadr[j])]),
                        armature=armature,
                        **origin,
                    )
                )
            parent = child
    links = list(bodies)
    inertials: list[InertialSpec | None] = [None] + [_inertial(m, i) for i in range(1, m.nbody)]
    if sites:
        staken = {name(mujoco.mjtObj.mjOBJ_SITE, s) for s in range(m.nsite)} - {""}
        for s in range(m.nsite):
            site = site_prefix + (name(mujoco.mjtObj.mjOBJ_SITE, s) or _unique(f"site_{s}", staken))
            if site in taken:
                raise MJCFError(
                    label,
                    f"site link {site!r} has the name of a body: its frame would be ambiguous "
                    f"(pass site_prefix, e.g. site_prefix='site:', to name the sites apart)",
                )
            taken.add(site)
            links.append(site)
            inertials.append(None)
            body = bodies[int(m.site_bodyid[s])]
            xyz, quat = vec(m.site_pos[s]), vec(m.site_quat[s])
            fixed = _unique(f"{site}:fixed", jtaken)  # as bodies' fixed joints
            joints.append(JointSpec(fixed, "fixed", body, site, xyz=xyz, quat=quat))
    # The model's name: the first entry of MuJoCo's name buffer.
    model_name = bytes(m.names).split(b"\0", 1)[0].decode("utf-8", "replace")
    return RobotSpec(
        model_name or "mjcf", tuple(links), tuple(joints), bodies[0], label, tuple(inertials)
    )


def _inertial(m: Any, i: int) -> InertialSpec:
    """Body ``i``'s compiled inertial (``body_mass``, ``body_ipos``, and the principal moments
    ``body_inertia`` along the axes of ``body_iquat``) as an :class:`InertialSpec` in the body's
    frame: the inertia tensor ``R diag(I) R^T`` about the centre of mass, ``rpy`` zero."""
    R = quat_rows([float(c) for c in m.body_iquat[i]])  # MuJoCo's body_iquat is a unit quaternion
    d = [float(v) for v in m.body_inertia[i]]
    I = [[sum(R[r][k] * d[k] * R[c][k] for k in range(3)) for c in range(3)] for r in range(3)]
    return InertialSpec(
        float(m.body_mass[i]),
        (float(m.body_ipos[i][0]), float(m.body_ipos[i][1]), float(m.body_ipos[i][2])),
        (0.0, 0.0, 0.0),
        (I[0][0], I[0][1], I[0][2], I[1][1], I[1][2], I[2][2]),
    )
