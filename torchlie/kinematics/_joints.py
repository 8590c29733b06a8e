"""The chain's constants, built once from the parsed URDF in float64.

Everything :class:`~torchlie.kinematics.Chain` derives from a :class:`RobotSpec` before it sees
a ``q``: the degrees of freedom and their limits, the mimic joints resolved to the DoF they
follow, each joint's origin and per-feature matrices ``C_f``, its Jacobian columns, the
sampling ranges of :meth:`Chain.random_configuration`, and the tree of links in breadth-first
order.  Apart from :mod:`torchlie.kinematics.chain` because it runs once per chain, on the
parsed Python numbers: nothing here sees a batch.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

from .. import so3 as _so3
from .urdf import JointSpec, RobotSpec, URDFError, _describe

_QUAT = ("qw", "qx", "qy", "qz")
_SUFFIXES = {
    "planar": ("x", "y", "theta"),
    "floating": ("x", "y", "z", "rx", "ry", "rz"),
    "ball": _QUAT,
    "free": ("x", "y", "z", *_QUAT),
}
_NDOF = {
    "revolute": 1,
    "continuous": 1,
    "prismatic": 1,
    "fixed": 0,
    "planar": 3,
    "floating": 6,
    "ball": 4,
    "free": 7,
}
# Velocity coordinates where they differ from the values (a quaternion has 3).
_VEL_SUFFIXES = {"ball": ("wx", "wy", "wz"), "free": ("x", "y", "z", "wx", "wy", "wz")}
# Internal kinds (one GEMM per depth and kind).
_KIND = {
    "revolute": "rot",
    "continuous": "rot",
    "prismatic": "prism",
    "fixed": "fixed",
    "planar": "planar",
    "floating": "float",
    "ball": "ball",
    "free": "free",
}

# Sampling ranges for coordinates without limits (random_configuration).
_FREE_ANGLE = math.pi
_FREE_TRANSLATION = 1.0
_FREE_ROTVEC = math.pi / math.sqrt(3.0)


# ----------------------------------------------------------------------------------------------
# float64 constants (Python floats -> float64 tensors; no float32 on the way)
# ----------------------------------------------------------------------------------------------


def rpy_matrix(roll: float, pitch: float, yaw: float) -> Tensor:
    """``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` in float64 (URDF's fixed-axis roll, pitch, yaw).

    Example:
        >>> rpy_matrix(0.0, 0.0, math.pi / 2).round(decimals=12) + 0.0
        tensor([[ 0., -1.,  0.],
                [ 1.,  0.,  0.],
                [ 0.,  0.,  1.]], dtype=torch.float64)
    """
    return torch.tensor(rpy_rows(roll, pitch, yaw), dtype=torch.float64)


def rpy_rows(roll: float, pitch: float, yaw: float) -> list[list[float]]:
    """The rows of :func:`rpy_matrix` as Python floats (for plans built while compiling)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return rpy_rows_cos_sin(cr, sr, cp, sp, cy, sy)


def rpy_rows_cos_sin(
    cr: float, sr: float, cp: float, sp: float, cy: float, sy: float
) -> list[list[float]]:
    """The rows of :func:`rpy_matrix` from the cosines and sines of roll, pitch and yaw."""
    return [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]


def quat_rows(q: Sequence[float]) -> list[list[float]]:
    """Rows of the rotation matrix of the quaternion ``(w, x, y, z)`` (normalised), as Python
    floats."""
    n = math.sqrt(sum(x * x for x in q))
    w, x, y, z = (c / n for c in q)
    return [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]


def _quat_matrix(q: Sequence[float]) -> Tensor:
    """Rotation matrix of the quaternion ``(w, x, y, z)`` (normalised) in float64."""
    return torch.tensor(quat_rows(q), dtype=torch.float64)


def _origin(j: JointSpec) -> Tensor:
    T = torch.eye(4, dtype=torch.float64)
    T[:3, :3] = rpy_matrix(*j.rpy) if j.quat is None else _quat_matrix(j.quat)
    T[:3, 3] = torch.tensor(j.xyz, dtype=torch.float64)
    return T


def _unit_floats(v: Sequence[float]) -> tuple[float, ...]:
    """``v / |v|`` in Python floats (no tensor: a plan built while Dynamo traces reads no
    tensor's value)."""
    n = math.hypot(*v)
    return tuple(x / n for x in v)


def _unit(v: Sequence[float]) -> Tensor:
    return torch.tensor(_unit_floats(v), dtype=torch.float64)


def _block(R: Tensor | None = None, t: Tensor | None = None) -> Tensor:
    """4x4 ``[[R, t], [0, 0]]`` (zeros where not given)."""
    M = torch.zeros(4, 4, dtype=torch.float64)
    if R is not None:
        M[:3, :3] = R
    if t is not None:
        M[:3, 3] = t
    return M


def _plane_basis(n: Tensor) -> tuple[Tensor, Tensor]:
    m = min(range(3), key=lambda i: abs(float(n[i])))
    e = torch.zeros(3, dtype=torch.float64)
    e[m] = 1.0
    e1 = e - torch.dot(e, n) * n
    e1 = e1 / torch.linalg.vector_norm(e1)
    return e1, torch.linalg.cross(n, e1)


def _frame(j: JointSpec) -> tuple[Tensor, Tensor | None]:
    """``(A, P)`` with ``T_origin @ M(q - ref)`` about the anchor ``= A @ M(q) @ P`` (``P``
    None: the identity).  A rotation about the anchor ``p`` is ``Trans(p) M Trans(-p)``; the
    ``ref`` offset of a one-DoF joint is a constant motion along its axis, folded into ``A``
    (it commutes with ``M``)."""
    A = _origin(j)
    P = None
    kind = _KIND[j.type]
    if kind in ("rot", "ball") and any(j.anchor):
        p = torch.tensor(j.anchor, dtype=torch.float64)
        A = A @ (torch.eye(4, dtype=torch.float64) + _block(t=p))
        P = torch.eye(4, dtype=torch.float64) + _block(t=-p)
    if j.ref != 0.0 and kind in ("rot", "prism"):
        a = _unit(j.axis)
        if kind == "rot":
            K = _so3.hat(a)
            R = torch.eye(3, dtype=torch.float64) - math.sin(j.ref) * K
            R = R + (1.0 - math.cos(j.ref)) * (K @ K)
            H = torch.eye(4, dtype=torch.float64)
            H[:3, :3] = R
            A = A @ H
        else:
            A = A @ (torch.eye(4, dtype=torch.float64) + _block(t=-j.ref * a))
    return A, P


_UNITS = [(3, 3)] + [(r, c) for r in range(3) for c in range(3)] + [(r, 3) for r in range(3)]


def _constants(j: JointSpec) -> list[Tensor]:
    """``[C_0, C_1, ...]`` with ``T_origin @ M(q) = C_0 + sum_f feat_f(q) C_f``."""
    T, P = _frame(j)
    kind = _KIND[j.type]

    def c(M: Tensor) -> Tensor:
        return T @ M if P is None else T @ M @ P

    if kind == "fixed":
        return [T]
    if kind in ("float", "free", "ball"):
        # M = E33 + sum_rc R[r, c] E_rc + sum_r t[r] E_r3, E_rc the unit matrices (a ball
        # joint has no translation).
        out = []
        for r, col in _UNITS[:10] if kind == "ball" else _UNITS:
            E = torch.zeros(4, 4, dtype=torch.float64)
            E[r, col] = 1.0
            out.append(c(E))
        return out
    a = _unit(j.axis)
    K = _so3.hat(a)
    if kind == "rot":
        return [c(torch.eye(4, dtype=torch.float64)), c(_block(K)), c(_block(K @ K))]
    if kind == "prism":
        return [T, T @ _block(t=a)]
    e1, e2 = _plane_basis(a)  # planar
    return [T, T @ _block(K), T @ _block(K @ K), T @ _block(t=e1), T @ _block(t=e2)]


def _columns(
    j: JointSpec, rows: tuple[int, ...], mimic: tuple[int, float] | None, vel: int | None = None
) -> tuple[tuple, tuple | None]:
    """Jacobian columns of joint ``j`` (see ``_Link.cols``), from float64 values; ``vel`` is
    the joint's first velocity coordinate (``rows[0]`` when None)."""
    kind = _KIND[j.type]
    if kind == "fixed":
        return (), None
    O_R = _origin(j)[:3, :3]
    v0 = rows[0] if vel is None else vel

    def vec(v: Tensor) -> tuple[float, ...]:
        return tuple(float(x) for x in v)

    if kind == "float":
        cols = tuple(("tr", vec(O_R[:, k]), rows[k], 1.0) for k in range(3))
        return cols, (rows[3], tuple(vec(r) for r in O_R))
    # A quaternion joint's angular velocity is in the child's frame ("crot": the direction is
    # a column of the child's rotation); a free joint's translation in its parent's frame.
    unit = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    if kind == "ball":
        return tuple(("crot", unit[k], v0 + k, 1.0) for k in range(3)), None
    if kind == "free":
        cols = tuple(("tr", vec(O_R[:, k]), v0 + k, 1.0) for k in range(3))
        return cols + tuple(("crot", unit[k], v0 + 3 + k, 1.0) for k in range(3)), None
    a = _unit(j.axis)
    d, w = mimic if mimic is not None else (v0, 1.0)
    if kind == "rot":
        return (("rot", vec(O_R @ a), d, w),), None
    if kind == "prism":
        return (("tr", vec(O_R @ a), d, w),), None
    e1, e2 = _plane_basis(a)  # planar
    return (
        ("tr", vec(O_R @ e1), rows[0], 1.0),
        ("tr", vec(O_R @ e2), rows[1], 1.0),
        ("rot", vec(O_R @ a), rows[2], 1.0),
    ), None


def _resolve_mimics(spec: RobotSpec, dof_of: dict[str, int]) -> dict[str, tuple[int, float, float]]:
    """Mimic joint -> ``(DoF, mult, off)`` with value ``mult * q[DoF] + off``, chains composed.

    Each joint is resolved once (memoised), so a chain of ``n`` mimics costs ``O(n)``.
    """
    by_name = {j.name: j for j in spec.joints}
    resolved: dict[str, tuple[int, float, float]] = {}
    for j in spec.joints:
        if j.mimic is None or j.name in resolved:
            continue
        stack: list[JointSpec] = []  # mimic joints not yet resolved, j first
        on_stack: set[str] = set()
        cur = j
        while cur.mimic is not None and cur.name not in resolved:
            if cur.name in on_stack:  # parse_urdf rejects this; a hand-made RobotSpec may not
                raise ValueError(
                    f"torchlie.kinematics.Chain.__init__: mimic cycle through joint {cur.name!r}"
                )
            stack.append(cur)
            on_stack.add(cur.name)
            cur = by_name[cur.mimic.joint]
        src, mult, off = (
            resolved[cur.name] if cur.mimic is not None else (dof_of[cur.name], 1.0, 0.0)
        )
        for k in reversed(stack):  # value(k) = m * (mult * q + off) + c
            spec_k = k.mimic
            assert spec_k is not None
            mult, off = spec_k.multiplier * mult, spec_k.multiplier * off + spec_k.offset
            resolved[k.name] = (src, mult, off)
    return {j.name: resolved[j.name] for j in spec.joints if j.mimic is not None}


def _check_representable(
    spec: RobotSpec, dtype: torch.dtype, mimic_mult: list[float], mimic_off: list[float]
) -> None:
    """Raise :class:`URDFError` where a number of the URDF that the chain stores in ``dtype``
    does not fit it.

    One rule for every such number: the origins' translations, the position limits and the
    mimic joints' composed multipliers and offsets.  One beyond the dtype's range
    (``3.4e38`` for float32; in float64 only a product of mimic multipliers can get there)
    would become ``inf``: an origin would make every pose below it ``nan`` and a limit would
    silently turn into "no limit", so it is an error naming the file, the joint, the attribute
    and the value.  Rotations and axes are bounded by construction; ``effort`` and
    ``velocity`` are metadata the chain does not convert.
    """

    def first_overflow(values: list[float]) -> int | None:
        ok = torch.isfinite(torch.tensor(values, dtype=torch.float64).to(dtype))
        return None if bool(ok.all()) else int((~ok).nonzero()[0, 0])

    big = f"{dtype} (largest finite {torch.finfo(dtype).max:.6g})"
    if dtype != torch.float64:
        big += "; use dtype=torch.float64"

    def fail(j: JointSpec, sub: str, problem: str) -> URDFError:
        return URDFError(spec.source, _describe("joint", j.name, 0, sub), problem)

    k = first_overflow([x for j in spec.joints for x in j.xyz])
    if k is not None:
        j = spec.joints[k // 3]
        raise fail(j, "origin", f"attribute 'xyz' value {j.xyz[k % 3]!r} overflows {big}")
    # The limits of the DoFs (a mimic joint's own limits are not stored: it has no DoF).
    # A side may be None (SDF limits a joint on one side only).
    bounds = [
        (j, key, v)
        for j in spec.joints
        if j.mimic is None
        for key, v in (("lower", j.lower), ("upper", j.upper))
        if v is not None
    ]
    k = first_overflow([v for _, _, v in bounds])
    if k is not None:
        j, key, value = bounds[k]
        raise fail(j, "limit", f"attribute {key!r} value {value!r} overflows {big}")
    mimics = [j for j in spec.joints if j.mimic is not None]
    for what, values in (("multiplier", mimic_mult), ("offset", mimic_off)):
        k = first_overflow(values)
        if k is not None:
            raise fail(
                mimics[k],
                "mimic",
                f"the {what} composed along its chain of mimic joints, {values[k]!r}, "
                f"overflows {big}",
            )


def _uniform_within(lo: Tensor, hi: Tensor, u: Tensor) -> Tensor:
    """``lo + u (hi - lo)`` for ``u`` in ``[0, 1)``: finite and within ``[lo, hi]`` for every
    finite ``lo <= hi``.

    Written ``lo (1 - u) + hi u``, so the difference ``hi - lo`` (``inf`` for limits of opposite
    signs near the float64 range) is never formed, and clamped into ``[lo, hi]``: the rounded
    products can step an ulp outside, or to ``inf`` next to the largest double.
    """
    return torch.minimum(torch.maximum(lo * (1.0 - u) + hi * u, lo), hi)


def _sampling_ranges(
    dofs: Sequence[tuple[str, str, str]], lower: Tensor, upper: Tensor
) -> tuple[Tensor, Tensor]:
    """The limits, with the free ranges of :meth:`Chain.random_configuration` where a
    coordinate has none, chosen by what the coordinate is (``dofs``: per DoF its joint, the
    joint's type and the coordinate, as :attr:`Chain.dof_joints`); a coordinate limited on one
    side only gets a range of the same width on its limited side."""
    lo, hi = lower.clone(), upper.clone()
    for i, (_, _, coord) in enumerate(dofs):
        if math.isfinite(lo[i]) and math.isfinite(hi[i]):
            continue
        if coord in ("x", "y", "z"):  # planar, floating and free translations
            r = _FREE_TRANSLATION
        elif coord in _QUAT:  # normalised by the forward kinematics
            r = 1.0
        elif coord in ("rx", "ry", "rz"):
            r = _FREE_ROTVEC
        else:  # one-DoF joints (prismatic ones too) and a planar joint's angle
            r = _FREE_ANGLE
        if math.isfinite(lo[i]):  # limited on one side only (SDF): the free range's width
            hi[i] = lo[i] + 2.0 * r
        elif math.isfinite(hi[i]):
            lo[i] = hi[i] - 2.0 * r
        else:
            lo[i], hi[i] = -r, r
    return lo, hi


# ----------------------------------------------------------------------------------------------
# Degrees of freedom, mimic joints and the tree of links
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Link:
    name: str
    index: int  # internal (breadth-first) index
    depth: int
    parent: int  # internal index of the parent link, -1 for the root
    joint: JointSpec | None
    kind: str  # internal kind, "root" for the root
    rows: tuple[int, ...]  # rows of the value bank feeding this joint
    consts: tuple[Tensor, ...]  # float64 C_f
    # Jacobian columns of this joint: (rot|tr, direction in the parent frame, DoF, weight);
    # for a floating joint also (first rotation-vector DoF, O_R as nested tuples).
    cols: tuple[tuple[str, tuple[float, ...], int, float], ...] = ()
    float_rot: tuple[int, tuple[tuple[float, ...], ...]] | None = None
    # The point of the child frame its rotation columns turn about (None: the origin).
    anchor: tuple[float, float, float] | None = None


def _dof_layout(
    spec: RobotSpec,
) -> tuple[dict[str, int], list[str], list[tuple[str, str, str]], list[float], list[float]]:
    """Degrees of freedom in document order: joint -> its first DoF (for the joints that have
    their own: not fixed, not mimic), and per DoF its name, its role ``(joint, joint type,
    coordinate)`` (``""`` for a one-DoF joint) and its limits (``-inf``/``inf`` where there are
    none).  Raises :class:`URDFError` where two DoFs would have the same name (see
    :func:`_check_unique`)."""
    dof_of: dict[str, int] = {}
    names: list[str] = []
    roles: list[tuple[str, str, str]] = []
    lower: list[float] = []
    upper: list[float] = []
    for j in spec.joints:
        n = _NDOF[j.type]
        if n == 0 or j.mimic is not None:
            continue
        dof_of[j.name] = len(names)
        if n == 1:
            names.append(j.name)
            roles.append((j.name, j.type, ""))
            lo, hi = (j.lower, j.upper) if j.type != "continuous" else (None, None)
            lower.append(-math.inf if lo is None else lo)
            upper.append(math.inf if hi is None else hi)
        else:
            names.extend(f"{j.name}:{s}" for s in _SUFFIXES[j.type])
            roles.extend((j.name, j.type, s) for s in _SUFFIXES[j.type])
            lower.extend([-math.inf] * n)
            upper.extend([math.inf] * n)
    _check_unique(spec, names, roles, ("degree of freedom", "degrees of freedom"))
    return dof_of, names, roles, lower, upper


def _check_unique(
    spec: RobotSpec,
    names: list[str],
    roles: list[tuple[str, str, str]],
    what: tuple[str, str],
) -> None:
    """Raise :class:`URDFError` naming both joints where two coordinates have the same name:
    a joint ``J`` with several coordinates names them ``J:x``, ``J:qw``, ..., which another
    joint may be named (a revolute ``base:x`` beside a floating ``base``)."""
    first: dict[str, int] = {}
    for k, name in enumerate(names):
        if name not in first:
            first[name] = k
            continue
        (a, a_type, _), (b, b_type, _) = roles[first[name]], roles[k]
        # The element is the joint with one coordinate (its own name), or the later one.
        own, other, other_type = (b, a, a_type) if b == name else (a, b, b_type)
        theirs = ", ".join(repr(n) for n, r in zip(names, roles, strict=True) if r[0] == other)
        raise URDFError(
            spec.source,
            _describe("joint", own, 0),
            f"{name!r} would name a {what[0]} of this joint and one of the {other_type} joint "
            f"{other!r} (whose {what[1]} are {theirs}); rename one of the two joints",
        )


def _velocity_layout(spec: RobotSpec) -> tuple[dict[str, int], list[str]]:
    """Velocity coordinates (the Jacobian's columns): joint -> its first one, and their names.

    The same as the degrees of freedom of :func:`_dof_layout` except for quaternion joints
    (``ball``: 3 angular velocities, ``free``: 3 linear, then 3 angular).  Raises
    :class:`URDFError` where two have the same name."""
    vel_of: dict[str, int] = {}
    names: list[str] = []
    roles: list[tuple[str, str, str]] = []
    for j in spec.joints:
        n = _NDOF[j.type]
        if n == 0 or j.mimic is not None:
            continue
        vel_of[j.name] = len(names)
        if n == 1:
            names.append(j.name)
            roles.append((j.name, j.type, ""))
        else:
            sfx = _VEL_SUFFIXES.get(j.type, _SUFFIXES[j.type])
            names.extend(f"{j.name}:{x}" for x in sfx)
            roles.extend((j.name, j.type, x) for x in sfx)
    _check_unique(spec, names, roles, ("velocity coordinate", "velocity coordinates"))
    return vel_of, names


def _mimic_rows(
    spec: RobotSpec, dof_of: dict[str, int], n_dof: int
) -> tuple[dict[str, int], tuple[list[int], list[float], list[float]]]:
    """Mimic joint -> its row of the value bank (``n_dof + k``), and per row ``k`` the DoF it
    follows, the multiplier and the offset (chains resolved): ``q[src] * mult + off``."""
    mimic_src: list[int] = []
    mimic_mult: list[float] = []
    mimic_off: list[float] = []
    row_of: dict[str, int] = {}
    for name, (src, mult, off) in _resolve_mimics(spec, dof_of).items():
        row_of[name] = n_dof + len(mimic_src)
        mimic_src.append(src)
        mimic_mult.append(mult)
        mimic_off.append(off)
    return row_of, (mimic_src, mimic_mult, mimic_off)


def _tree_links(
    spec: RobotSpec,
    dof_of: dict[str, int],
    row_of: dict[str, int],
    mimic_of: dict[str, tuple[int, float]],
    vel_of: dict[str, int] | None = None,
) -> list[_Link]:
    """The links in breadth-first internal order (children in document order of their
    joints), the root first, each with its joint's value rows, constants and Jacobian columns
    (``mimic_of``: mimic joint -> the DoF it feeds and its multiplier)."""
    children: dict[str, list[JointSpec]] = {}
    for j in spec.joints:
        children.setdefault(j.parent, []).append(j)
    links: list[_Link] = [_Link(spec.root, 0, 0, -1, None, "root", (), ())]
    frontier = [0]
    while frontier:
        nxt = []
        for p in frontier:
            for j in children.get(links[p].name, []):
                if j.name in row_of:
                    rows: tuple[int, ...] = (row_of[j.name],)
                elif _NDOF[j.type]:
                    rows = tuple(range(dof_of[j.name], dof_of[j.name] + _NDOF[j.type]))
                else:
                    rows = ()
                link = _Link(
                    j.child,
                    len(links),
                    links[p].depth + 1,
                    p,
                    j,
                    _KIND[j.type],
                    rows,
                    tuple(_constants(j)),
                    *_columns(j, rows, mimic_of.get(j.name), (vel_of or dof_of).get(j.name)),
                    j.anchor if any(j.anchor) and _KIND[j.type] in ("rot", "ball") else None,
                )
                links.append(link)
                nxt.append(link.index)
        frontier = nxt
    return links
