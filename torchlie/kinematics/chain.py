"""Kinematic trees: batched forward kinematics and geometric Jacobians.

Conventions
-----------
* World frame = the root link's frame.  A pose is a homogeneous ``(..., 4, 4)`` matrix
  ``[[R, t], [0, 1]]`` mapping link coordinates to world coordinates, ``p_world = T @ p_link``.
* A joint's child frame is ``T_child = T_parent @ T_origin @ M(q)``, ``T_origin`` from
  ``<origin xyz rpy>`` with ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (fixed axes), computed in float64
  from the parsed numbers.
* Joint coordinates, in the joint frame with the unit axis ``a`` (``<axis>`` normalised;
  ``(1, 0, 0)`` when omitted, as the URDF specification says):

  ==========  ====  ============================================================================
  revolute    1     ``M = Rot(a, q)``; ``continuous`` is the same without limits
  prismatic   1     ``M = Trans(q a)``
  fixed       0     ``M = I``
  planar      3     ``(x, y, theta)``: ``M = Trans(x e1 + y e2) Rot(n, theta)``, ``n`` the axis
                    (the plane's normal), ``e1`` the unit projection onto the plane of the
                    coordinate axis least aligned with ``n`` (first of x, y, z on ties),
                    ``e2 = n x e1``; for ``n = z`` this is ``e1 = x``, ``e2 = y``
  floating    6     ``(x, y, z, rx, ry, rz)``: ``M = [[Exp(r), t], [0, 1]]``, ``t`` the
                    translation in the joint frame and ``r`` a rotation vector
                    (:func:`torchlie.so3.exp`)
  ==========  ====  ============================================================================

* ``<mimic joint=J multiplier=m offset=c>``: the joint's value is ``m * q[J] + c``; it has no
  DoF of its own (chains of mimics compose).
* ``q`` has shape ``(..., n_dof)`` in :attr:`Chain.joint_names` order: one entry per degree of
  freedom, joints in document order, fixed and mimic joints excluded; a planar or floating
  joint ``J`` contributes ``J:x, J:y, J:theta`` or ``J:x, J:y, J:z, J:rx, J:ry, J:rz``.
* :meth:`Chain.jacobian` is the geometric Jacobian ``(..., 6, n_dof)``, rows (linear; angular),
  columns in ``q``'s order; by default in world coordinates at the link's origin: column ``i``
  holds ``(dp/dq_i, w_i)`` where ``dR/dq_i = hat(w_i) R``, the same meaning as
  pytorch-kinematics' ``jacobian``.  ``frame="link"`` gives it in the link's coordinates (the
  body twist, ``T(q + dq) ~= T(q) Exp(J dq)``), ``frame="spatial"`` the spatial twist
  (``T(q + dq) ~= Exp(J dq) T(q)``), and ``point=`` the linear velocity of a point fixed in
  the link instead of its origin.

Deliberate conventions at the edges:

* Every batch shape is accepted, empty ones included: ``q`` of shape ``(0, n_dof)`` gives
  poses ``(0, 4, 4)`` and Jacobians ``(0, 6, n_dof)``, like every torchlie op.
* A robot without degrees of freedom (one link, or fixed joints only) takes ``q`` of shape
  ``(..., 0)``; its poses are constants and its Jacobians have no columns, ``(..., 6, 0)``.
* Numbers: a constant of the chain that does not fit its dtype (an ``<origin>`` translation
  beyond ``3.4e38`` in a float32 chain, or mimic multipliers whose product overflows) raises
  :class:`~torchlie.kinematics.URDFError` naming the joint and the value when the chain is
  built.  With constants that fit, poses follow plain IEEE arithmetic: a pose whose
  translation overflows (two origins of ``1e308`` in float64) is ``inf`` there, and the links
  below it get ``nan`` entries (the 4x4 products multiply that ``inf`` by the bottom row's
  zeros).  No check on values is made at run time (it would cost a device sync).

Implementation: the joints of each tree depth are computed together, per joint kind, with one
matrix product per depth.  A child pose is linear in a few features of its joint value
(``T_parent @ T_origin @ M(q) = sum_f feat_f(q) T_parent @ C_f`` with constant ``C_f``, e.g.
``1, sin q, 1 - cos q`` for a revolute joint), so a depth costs one GEMM of the parents'
poses against the stacked ``C_f`` plus a few fused multiply-adds.  Poses are kept internally
as ``(4, 4, batch)`` (batch innermost) so those element-wise ops run over long contiguous
rows; the public results are ordinary contiguous ``(..., 4, 4)`` tensors.  A Jacobian is one
column per moving joint on the link's path (a world direction, and for a rotation its moment
about the link), each added into its DoF's column by one ``index_add`` (mimic joints share a
DoF), so time and memory are linear in the number of joints.  Everything is plain
differentiable torch, so first and second derivatives with respect to ``q`` are exact.
"""

from __future__ import annotations

import math
import operator
import os
import reprlib
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from .. import _checks
from .. import so3 as _so3
from .._typing import Float
from .ik import IKResult
from .ik import inverse_kinematics as _inverse_kinematics
from .urdf import JointSpec, RobotSpec, URDFError, _describe, parse_urdf

__all__ = ["Chain", "rpy_matrix"]

_NAME = "torchlie.kinematics.Chain."

_SUFFIXES = {"planar": ("x", "y", "theta"), "floating": ("x", "y", "z", "rx", "ry", "rz")}
_NDOF = {"revolute": 1, "continuous": 1, "prismatic": 1, "fixed": 0, "planar": 3, "floating": 6}
# Internal kinds (one GEMM per depth and kind).
_KIND = {
    "revolute": "rot",
    "continuous": "rot",
    "prismatic": "prism",
    "fixed": "fixed",
    "planar": "planar",
    "floating": "float",
}
_KIND_ORDER = ("fixed", "rot", "prism", "planar", "float")

# Sampling ranges for coordinates without limits (random_configuration).
_FREE_ANGLE = math.pi
_FREE_TRANSLATION = 1.0
_FREE_ROTVEC = math.pi / math.sqrt(3.0)

# Batch size up to which results are transposed back in one stacked copy (see
# forward_kinematics).
_SMALL_BATCH = 2048


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
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return torch.tensor(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ],
        dtype=torch.float64,
    )


def _origin(j: JointSpec) -> Tensor:
    T = torch.eye(4, dtype=torch.float64)
    T[:3, :3] = rpy_matrix(*j.rpy)
    T[:3, 3] = torch.tensor(j.xyz, dtype=torch.float64)
    return T


def _unit(v: Sequence[float]) -> Tensor:
    n = math.hypot(*v)
    return torch.tensor([x / n for x in v], dtype=torch.float64)


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


def _constants(j: JointSpec) -> list[Tensor]:
    """``[C_0, C_1, ...]`` with ``T_origin @ M(q) = C_0 + sum_f feat_f(q) C_f``."""
    T = _origin(j)
    kind = _KIND[j.type]
    if kind == "fixed":
        return [T]
    if kind == "float":
        # M = E33 + sum_rc R[r, c] E_rc + sum_r t[r] E_r3, E_rc the unit matrices.
        out = []
        units = [(3, 3)] + [(r, c) for r in range(3) for c in range(3)] + [(r, 3) for r in range(3)]
        for r, c in units:
            E = torch.zeros(4, 4, dtype=torch.float64)
            E[r, c] = 1.0
            out.append(T @ E)
        return out
    a = _unit(j.axis)
    K = _so3.hat(a)
    if kind == "rot":
        return [T, T @ _block(K), T @ _block(K @ K)]
    if kind == "prism":
        return [T, T @ _block(t=a)]
    e1, e2 = _plane_basis(a)  # planar
    return [T, T @ _block(K), T @ _block(K @ K), T @ _block(t=e1), T @ _block(t=e2)]


def _columns(
    j: JointSpec, rows: tuple[int, ...], mimic: tuple[int, float] | None
) -> tuple[tuple, tuple | None]:
    """Jacobian columns of joint ``j`` (see ``_Link.cols``), from float64 values."""
    kind = _KIND[j.type]
    if kind == "fixed":
        return (), None
    O_R = _origin(j)[:3, :3]

    def vec(v: Tensor) -> tuple[float, ...]:
        return tuple(float(x) for x in v)

    if kind == "float":
        cols = tuple(("tr", vec(O_R[:, k]), rows[k], 1.0) for k in range(3))
        return cols, (rows[3], tuple(vec(r) for r in O_R))
    a = _unit(j.axis)
    d, w = mimic if mimic is not None else (rows[0], 1.0)
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
                raise ValueError(f"{_NAME}__init__: mimic cycle through joint {cur.name!r}")
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
    """Raise :class:`URDFError` where a constant of the chain overflows ``dtype``.

    The origins' translations and the mimic joints' composed multipliers and offsets become
    constants of the chain; one beyond the dtype's range (``3.4e38`` for float32; in float64
    only a product of mimic multipliers can get there) would be ``inf`` and make every pose
    below it ``nan``, so it is an error naming the joint and the value.  Rotations and axes are
    bounded by construction; a limit beyond the range is ``inf`` (no limit).
    """

    def first_overflow(values: list[float]) -> int | None:
        ok = torch.isfinite(torch.tensor(values, dtype=torch.float64).to(dtype))
        return None if bool(ok.all()) else int((~ok).nonzero()[0, 0])

    big = f"{dtype} (largest finite {torch.finfo(dtype).max:.6g})"
    k = first_overflow([x for j in spec.joints for x in j.xyz])
    if k is not None:
        j = spec.joints[k // 3]
        raise URDFError(
            spec.source,
            _describe("joint", j.name, 0, "origin"),
            f"attribute 'xyz' value {j.xyz[k % 3]!r} overflows {big}; use dtype=torch.float64",
        )
    mimics = [j for j in spec.joints if j.mimic is not None]
    for what, values in (("multiplier", mimic_mult), ("offset", mimic_off)):
        k = first_overflow(values)
        if k is not None:
            raise URDFError(
                spec.source,
                _describe("joint", mimics[k].name, 0, "mimic"),
                f"the {what} composed along its chain of mimic joints, {values[k]!r}, "
                f"overflows {big}",
            )


def _sampling_ranges(names: Sequence[str], lower: Tensor, upper: Tensor) -> tuple[Tensor, Tensor]:
    """The limits, with the free ranges of :meth:`Chain.random_configuration` where a
    coordinate has none (by the suffix of its DoF name)."""
    lo, hi = lower.clone(), upper.clone()
    for i, name in enumerate(names):
        if math.isfinite(lo[i]) and math.isfinite(hi[i]):
            continue
        suffix = name.rsplit(":", 1)[-1] if ":" in name else ""
        if suffix in ("x", "y", "z"):
            r = _FREE_TRANSLATION
        elif suffix in ("rx", "ry", "rz"):
            r = _FREE_ROTVEC
        else:
            r = _FREE_ANGLE
        lo[i], hi[i] = -r, r
    return lo, hi


# ----------------------------------------------------------------------------------------------
# Static description of the tree (dtype-free)
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


@dataclass
class _Group:
    links: list[int]
    kind: str
    parent_src: tuple | None  # how to gather the parents' poses, None when the parent is root
    ct: Tensor | tuple[Tensor, ...]  # (n, 4K, 4) stacked C_f^T; root children: K (n, 4, 4, 1)
    feats: list[tuple[str, object]]  # per feature f >= 1: (bank, rows) with rows int/slice/idx


@dataclass
class _Plan:
    levels: list[list[_Group]]
    where: dict[int, tuple[int, int, int]]  # link -> (level, group, position)
    rot_sel: object  # None, slice or index tensor into the value bank
    float_idx: Tensor | None  # value rows of the floating joints, 6 per joint


@dataclass
class _JacPlan:
    parents: list[int]  # parent link of each constant-direction column
    vs: Tensor | None  # (n, 1, 3) those directions in the parent frames
    n_rot_const: int  # the first n_rot_const of them are rotational
    rot_children: list[int]  # the child link (rotation centre) of each
    floats: list[tuple[int, int, int, Tensor]]  # floating joints: parent, child, rotvec dof, O_R
    # Column k of the link's motion adds col_weight[k] times itself to the Jacobian column of
    # DoF dof_index[k] (several columns feed one DoF through mimic joints); col_weight is None
    # when every weight is 1.  Two vectors of the columns' length, so memory is linear in the
    # number of joints.
    dof_index: Tensor  # (n_cols,) long
    col_weight: Tensor | None  # (n_cols,)
    in_dof_order: bool  # column k is DoF k's, for every DoF (a serial arm): no scatter needed
    dofs: tuple[int, ...]  # the DoFs that move the link (those of dof_index, sorted)
    col_dofs: tuple[int, ...]  # dof_index as Python ints


def _frame_jacobian(
    J: Tensor, P: Tensor, frame: str, point: Tensor | None, batch: tuple[int, ...]
) -> Tensor:
    """The world Jacobian at the origin ``J (B, 6, n)`` of a link with internal pose
    ``P (4, 4, B)``, in ``frame`` and at ``point`` (see :meth:`Chain.jacobian`), ``(..., 6, n)``
    with ``...`` the broadcast of ``batch`` and ``point``'s batch shape."""
    n = J.shape[-1]
    J = J.reshape(*batch, 6, n)
    T = P.permute(2, 1, 0).reshape(*batch, 4, 4)
    R, p = T[..., :3, :3], T[..., :3, 3]
    lin, ang = J[..., :3, :], J[..., 3:, :]
    if frame == "spatial":  # v - w x p = v + p x w
        lin = lin + torch.linalg.cross(p.unsqueeze(-1).expand_as(ang), ang, dim=-2)
    elif frame == "world":
        if point is not None:  # v + w x (R point)
            offset = (R @ point.unsqueeze(-1)).squeeze(-1)
            lin, ang = torch.broadcast_tensors(lin, ang, offset.unsqueeze(-1))[:2]
            lin = lin + torch.linalg.cross(ang, offset.unsqueeze(-1).expand_as(ang), dim=-2)
    else:  # link: R^T v (+ w_b x point), R^T w
        lin, ang = R.mT @ lin, R.mT @ ang
        if point is not None:
            lin, ang, pt = torch.broadcast_tensors(lin, ang, point.unsqueeze(-1))
            lin = lin + torch.linalg.cross(ang, pt, dim=-2)
    return torch.cat((lin, ang), dim=-2)


def _rows_index(rows: Sequence[int], device: torch.device) -> object:
    """A cheap selector for ``rows``: a slice (a run of rows) or an index tensor."""
    if len(rows) == 1:
        return slice(rows[0], rows[0] + 1)
    if list(rows) == list(range(rows[0], rows[0] + len(rows))):
        return slice(rows[0], rows[0] + len(rows))
    return torch.tensor(list(rows), dtype=torch.long, device=device)


def _take(bank: Tensor, sel: object) -> Tensor:
    if isinstance(sel, slice):
        return bank[sel]
    return bank.index_select(0, sel)  # type: ignore[arg-type]


class Chain:
    """A robot's kinematic tree, ready for batched forward kinematics and Jacobians.

    Build it with :meth:`from_urdf`; see the module docstring for every convention (joint
    coordinates, ``q`` layout, Jacobian meaning).  A chain holds constants in one dtype and on
    one device (float32 on the CPU by default); :meth:`to` returns a converted copy, rebuilt
    from the float64 values parsed from the file.

    Attributes:
        spec: the parsed :class:`~torchlie.kinematics.RobotSpec`.
        name: the robot's name.
        root: the root link (its frame is the world frame).
        link_names: every link, in document order.
        joint_names: the ``n_dof`` degrees of freedom, in the order of ``q``'s last dimension.
        leaf_links: links without children (end effectors, tool frames), in document order.
        lower, upper: ``(n_dof,)`` position limits (``-inf``/``inf`` where there are none).
        dtype, device: of the constants, and hence of ``q`` and the results.

    Example:
        >>> from torchlie.kinematics import Chain, sample_robot
        >>> arm = Chain.from_urdf(sample_robot("arm7"))
        >>> arm.n_dof, arm.root
        (7, 'world')
        >>> arm.forward_kinematics(torch.zeros(5, 7))["tool_tcp"].shape
        torch.Size([5, 4, 4])
    """

    def __init__(
        self,
        spec: RobotSpec,
        *,
        dtype: torch.dtype = torch.float32,
        device: torch.device | str | None = None,
    ) -> None:
        if dtype not in (torch.float32, torch.float64):
            raise TypeError(f"{_NAME}__init__: dtype must be float32 or float64, got {dtype}")
        self.spec = spec
        self.name = spec.name
        self.root = spec.root
        self.dtype = dtype
        self.device = torch.device("cpu") if device is None else torch.device(device)
        self.link_names: tuple[str, ...] = spec.links

        # Degrees of freedom, in document order.
        dof_of: dict[str, int] = {}
        names: list[str] = []
        lower: list[float] = []
        upper: list[float] = []
        for j in spec.joints:
            n = _NDOF[j.type]
            if n == 0 or j.mimic is not None:
                continue
            dof_of[j.name] = len(names)
            if n == 1:
                names.append(j.name)
                lo, hi = (j.lower, j.upper) if j.type != "continuous" else (None, None)
                lower.append(-math.inf if lo is None else lo)
                upper.append(math.inf if hi is None else hi)
            else:
                names.extend(f"{j.name}:{s}" for s in _SUFFIXES[j.type])
                lower.extend([-math.inf] * n)
                upper.extend([math.inf] * n)
        self.joint_names: tuple[str, ...] = tuple(names)
        self.n_dof = len(names)
        self._limits64 = (
            torch.tensor(lower, dtype=torch.float64),
            torch.tensor(upper, dtype=torch.float64),
        )
        self.lower = self._limits64[0].to(dtype=dtype, device=self.device)
        self._sample64 = _sampling_ranges(names, *self._limits64)
        self.upper = self._limits64[1].to(dtype=dtype, device=self.device)

        # Mimic joints: value row = n_dof + k, q[src] * mult + off (chains resolved).
        mimic_src: list[int] = []
        mimic_mult: list[float] = []
        mimic_off: list[float] = []
        row_of: dict[str, int] = {}
        for name, (src, mult, off) in _resolve_mimics(spec, dof_of).items():
            row_of[name] = self.n_dof + len(mimic_src)
            mimic_src.append(src)
            mimic_mult.append(mult)
            mimic_off.append(off)
        self._mimic = (mimic_src, mimic_mult, mimic_off)
        _check_representable(spec, dtype, mimic_mult, mimic_off)
        # Per DoF column of the Jacobian: which joints (and with which multiplier) move it.
        self._mimic_of = {
            j.name: (
                mimic_src[row_of[j.name] - self.n_dof],
                mimic_mult[row_of[j.name] - self.n_dof],
            )
            for j in spec.joints
            if j.mimic is not None
        }

        # Breadth-first internal order; children in document order of their joints.
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
                        *_columns(j, rows, self._mimic_of.get(j.name)),
                    )
                    links.append(link)
                    nxt.append(link.index)
            frontier = nxt
        self._links = links
        self._index = {link.name: link.index for link in links}
        has_child = {link.parent for link in links}
        self.leaf_links: tuple[str, ...] = tuple(
            name for name in spec.links if self._index[name] not in has_child
        )
        self._plans: dict[tuple[int, ...], _Plan] = {}
        self._jac_plans: dict[int, _JacPlan] = {}
        # (link, DoFs) -> where the link's Jacobian columns go among those DoFs (None: in order).
        self._dof_maps: dict[tuple[int, tuple[int, ...]], Tensor | None] = {}
        self._mimic_t: tuple[Tensor, Tensor, Tensor] | None = None

    # ------------------------------------------------------------------------------------------
    # Construction and conversion
    # ------------------------------------------------------------------------------------------

    @classmethod
    def from_urdf(
        cls,
        source: str | os.PathLike[str] | bytes,
        *,
        dtype: torch.dtype = torch.float32,
        device: torch.device | str | None = None,
    ) -> Chain:
        """Parse a URDF file (or URDF text) and build its chain.

        Args:
            source: a path to a ``.urdf`` file, or the XML text (a string starting with ``<``).
            dtype: float32 (default) or float64.
            device: where the constants live (default CPU).

        Raises:
            URDFError: a malformed URDF (see :func:`~torchlie.kinematics.parse_urdf`).

        Example:
            >>> chain = Chain.from_urdf('''<robot name="r"><link name="a"/><link name="b"/>
            ...   <joint name="j" type="prismatic"><parent link="a"/><child link="b"/>
            ...     <axis xyz="0 0 2"/><limit lower="0" upper="0.5"/></joint></robot>''')
            >>> chain.joint_names, chain.upper
            (('j',), tensor([0.5000]))
        """
        return cls(parse_urdf(source), dtype=dtype, device=device)

    def to(
        self, dtype: torch.dtype | None = None, device: torch.device | str | None = None
    ) -> Chain:
        """A copy of the chain with constants in ``dtype`` on ``device`` (``self`` if unchanged).

        Constants are rebuilt from the float64 values parsed from the URDF, so
        ``chain.to(torch.float32).to(torch.float64)`` loses nothing.

        Example:
            >>> from torchlie.kinematics import sample_robot
            >>> chain = Chain.from_urdf(sample_robot("arm7")).to(dtype=torch.float64)
            >>> chain.dtype
            torch.float64
        """
        dtype = self.dtype if dtype is None else dtype
        device = self.device if device is None else torch.device(device)
        if dtype == self.dtype and device == self.device:
            return self
        return Chain(self.spec, dtype=dtype, device=device)

    def __repr__(self) -> str:
        return (
            f"Chain({self.name!r}, links={len(self.link_names)}, n_dof={self.n_dof}, "
            f"dtype={self.dtype}, device={self.device})"
        )

    # ------------------------------------------------------------------------------------------
    # Sampling
    # ------------------------------------------------------------------------------------------

    def _sampling_bounds(self) -> tuple[Tensor, Tensor]:
        """float64 CPU ``(lower, upper)`` of :meth:`random_configuration`: the limits, and the
        free ranges it states where a coordinate has none (copies)."""
        return self._sample64[0].clone(), self._sample64[1].clone()

    def random_configuration(
        self, *batch: int, generator: torch.Generator | None = None
    ) -> Float[Tensor, "*batch n_dof"]:
        """Uniform joint values within the limits, shape ``(*batch, n_dof)``.

        Coordinates without limits are drawn from ``[-pi, pi]`` (continuous joints, planar
        rotation), ``[-1, 1]`` m (planar and floating translations) and
        ``[-pi/sqrt(3), pi/sqrt(3)]`` per rotation-vector component (floating rotations).
        Drawn on the CPU in float64 (with ``generator`` if given), then converted.  Each batch
        size is a non-negative integer (0 gives an empty batch); anything else raises
        ``TypeError``/``ValueError``.

        Example:
            >>> from torchlie.kinematics import sample_robot
            >>> arm = Chain.from_urdf(sample_robot("arm7"))
            >>> q = arm.random_configuration(100, generator=torch.Generator().manual_seed(0))
            >>> bool(((q >= arm.lower) & (q <= arm.upper)).all())
            True
        """
        fn = _NAME + "random_configuration"
        sizes: list[int] = []
        for b in batch:
            try:
                if isinstance(b, bool):
                    raise TypeError
                size = operator.index(b)  # ints, numpy integers, integer 0-d tensors
            except TypeError:
                raise TypeError(
                    f"{fn}: expected batch sizes to be integers, got {type(b).__name__} "
                    f"{reprlib.repr(b)} in batch={reprlib.repr(batch)}"
                ) from None
            if size < 0:
                raise ValueError(f"{fn}: expected batch sizes >= 0, got batch={batch!r}")
            sizes.append(size)
        lo, hi = self._sampling_bounds()
        u = torch.rand(*sizes, self.n_dof, generator=generator, dtype=torch.float64)
        return (lo + (hi - lo) * u).to(dtype=self.dtype, device=self.device)

    # ------------------------------------------------------------------------------------------
    # Plans: which links to compute, grouped by depth and joint kind
    # ------------------------------------------------------------------------------------------

    def _needed(self, targets: Iterable[int]) -> list[int]:
        need: set[int] = set()
        for t in targets:
            while t >= 0 and t not in need:
                need.add(t)
                t = self._links[t].parent
        return sorted(need)

    def _plan(self, targets: tuple[int, ...]) -> _Plan:
        plan = self._plans.get(targets)
        if plan is not None:
            return plan
        dev, dt = self.device, self.dtype
        need = self._needed(targets)
        by_depth: dict[int, list[_Link]] = {}
        for i in need:
            if i:
                by_depth.setdefault(self._links[i].depth, []).append(self._links[i])

        # Value rows that need sin / 1 - cos, and floating joints' first rows.
        rot_rows: list[int] = []
        float_rows: list[int] = []
        for i in need:
            link = self._links[i]
            if link.kind == "rot":
                rot_rows.append(link.rows[0])
            elif link.kind == "planar":
                rot_rows.append(link.rows[2])
            elif link.kind == "float":
                float_rows.append(link.rows[0])
        rot_rows = sorted(set(rot_rows))
        rot_pos = {r: k for k, r in enumerate(rot_rows)}
        float_pos = {r: k for k, r in enumerate(float_rows)}

        where: dict[int, tuple[int, int, int]] = {0: (0, 0, 0)}
        levels: list[list[_Group]] = []
        for depth in sorted(by_depth):
            groups: list[_Group] = []
            for kind in _KIND_ORDER:
                members = [link for link in by_depth[depth] if link.kind == kind]
                if not members:
                    continue
                g_index = len(groups)
                for pos, link in enumerate(members):
                    where[link.index] = (depth, g_index, pos)
                # Parent gather.
                if depth == 1:
                    parent_src = None
                else:
                    srcs = [where[link.parent] for link in members]
                    gset = {s[1] for s in srcs}
                    positions = [s[2] for s in srcs]
                    if len(gset) == 1:
                        gi = gset.pop()
                        whole = positions == list(range(len(levels[-1][gi].links)))
                        sel = None if whole else _rows_index(positions, dev)
                        parent_src = ("group", gi, sel)
                    else:
                        prev = levels[-1]
                        offsets = [0]
                        for g in prev:
                            offsets.append(offsets[-1] + len(g.links))
                        flat = [offsets[s[1]] + s[2] for s in srcs]
                        whole = flat == list(range(offsets[-1]))
                        parent_src = ("level", None, None if whole else _rows_index(flat, dev))
                # Constants: (n, K, 4, 4) of C_f^T.
                cts = torch.stack([torch.stack([c.T for c in link.consts]) for link in members])
                n, K = cts.shape[:2]
                ct: Tensor | tuple[Tensor, ...]
                if depth == 1:  # K constants (n, 4, 4, 1)
                    ct = cts.unsqueeze(-1).to(dtype=dt, device=dev).unbind(1)
                else:
                    ct = cts.reshape(n, K * 4, 4).to(dtype=dt, device=dev).contiguous()
                # Features f >= 1.
                feats: list[tuple[str, object]] = []
                if kind in ("rot", "planar"):
                    r_idx = 0 if kind == "rot" else 2
                    rows = [rot_pos[link.rows[r_idx]] for link in members]
                    feats += [("s", _rows_index(rows, dev)), ("c", _rows_index(rows, dev))]
                if kind == "prism":
                    feats.append(("v", _rows_index([link.rows[0] for link in members], dev)))
                if kind == "planar":
                    for k in range(2):
                        feats.append(("v", _rows_index([link.rows[k] for link in members], dev)))
                if kind == "float":
                    for k in range(12):
                        rows = [float_pos[link.rows[0]] * 12 + k for link in members]
                        feats.append(("F", _rows_index(rows, dev)))
                groups.append(_Group([m.index for m in members], kind, parent_src, ct, feats))
            levels.append(groups)
        rot_sel = None if not rot_rows else _rows_index(rot_rows, dev)
        float_idx = None
        if float_rows:
            float_idx = torch.tensor([r + k for r in float_rows for k in range(6)], device=dev)
        plan = _Plan(levels, where, rot_sel, float_idx)
        if not torch.compiler.is_compiling():  # a plan traced by dynamo is not reusable
            self._plans[targets] = plan
        return plan

    # ------------------------------------------------------------------------------------------
    # The computation
    # ------------------------------------------------------------------------------------------

    def _values(self, q2: Tensor) -> Tensor:
        """Value bank ``(n_dof + n_mimic, B)``: ``q`` transposed, then the mimic joints."""
        qT = q2.mT.contiguous()
        src, mult, off = self._mimic
        if not src:
            return qT
        if self._mimic_t is None or self._mimic_t[1].dtype != q2.dtype:
            self._mimic_t = (
                torch.tensor(src, dtype=torch.long, device=self.device),
                torch.tensor(mult, dtype=q2.dtype, device=self.device).unsqueeze(-1),
                torch.tensor(off, dtype=q2.dtype, device=self.device).unsqueeze(-1),
            )
        s, m, o = self._mimic_t
        return torch.cat((qT, torch.addcmul(o, qT.index_select(0, s), m)), dim=0)

    def _run(self, plan: _Plan, q2: Tensor) -> list[list[Tensor]]:
        """Poses of the plan's links: per level, per group, ``(n, 4, 4, B)`` = ``T[b]^T``."""
        B = q2.shape[0]
        v = self._values(q2)
        # Feature banks, shaped (rows, 1, 1, B) to broadcast over a group's (n, 4, 4, B).
        # Every size is spelled out: with an empty batch (B = 0) a -1 would be ambiguous.
        banks: dict[str, Tensor] = {"v": v.view(v.shape[0], 1, 1, B)}
        if plan.rot_sel is not None:
            x = _take(v, plan.rot_sel)
            banks["s"] = torch.sin(x).view(x.shape[0], 1, 1, B)
            banks["c"] = (1.0 - torch.cos(x)).view(x.shape[0], 1, 1, B)
        if plan.float_idx is not None:
            nf = plan.float_idx.shape[0] // 6
            vals = v.index_select(0, plan.float_idx).view(nf, 6, B)
            R = _so3.exp(vals[:, 3:].transpose(1, 2))  # (n, B, 3, 3)
            F = torch.cat((R.permute(0, 2, 3, 1).reshape(nf, 9, B), vals[:, :3]), dim=1)
            banks["F"] = F.view(nf * 12, 1, 1, B)

        out: list[list[Tensor]] = []
        for groups in plan.levels:
            res: list[Tensor] = []
            for g in groups:
                if g.parent_src is None:
                    # Children of the root: the parent pose is the identity.
                    Y = g.ct  # K x (n, 4, 4, 1)
                else:
                    how, gi, sel = g.parent_src
                    prev = out[-1][gi] if how == "group" else torch.cat(out[-1], dim=0)
                    P = prev if sel is None else _take(prev, sel)
                    n, K4 = g.ct.shape[:2]
                    prod = torch.bmm(g.ct, P.reshape(n, 4, 4 * B))
                    Y = prod.view(n, K4 // 4, 4, 4, B).unbind(1)
                if not g.feats:
                    res.append(Y[0].expand(-1, 4, 4, B) if g.parent_src is None else Y[0])
                    continue
                T = Y[0]
                for f, (b, sel) in enumerate(g.feats):
                    T = torch.addcmul(T, _take(banks[b], sel), Y[f + 1])
                res.append(T)
            out.append(res)
        return out

    def _pose(self, plan: _Plan, out: list[list[Tensor]], i: int, B: int, like: Tensor) -> Tensor:
        """Internal ``(4, 4, B)`` transposed pose of link ``i``."""
        if i == 0:
            return torch.eye(4, dtype=like.dtype, device=like.device).unsqueeze(-1).expand(4, 4, B)
        level, g, pos = plan.where[i]
        return out[level - 1][g][pos]

    def _prepare(self, q: Tensor, fn: str) -> tuple[Tensor, torch.dtype, tuple[int, ...]]:
        x, out_dtype = _checks.tensor(q, _NAME + fn, "q", (self.n_dof,))
        if x.dtype != self.dtype:
            raise TypeError(
                f"{_NAME}{fn}: q has dtype {q.dtype} but the chain's constants are "
                f"{self.dtype}; convert one of them (chain.to(dtype=...))"
            )
        if x.device != self.device:
            raise ValueError(
                f"{_NAME}{fn}: q is on {x.device} but the chain is on {self.device}; "
                "use chain.to(device=...)"
            )
        batch = tuple(x.shape[:-1])
        return x.reshape(math.prod(batch), self.n_dof), out_dtype, batch

    def _targets(self, links: str | Sequence[str] | None, fn: str) -> tuple[int, ...]:
        """Indices of ``links``: a name, a sequence of names (not a set: order matters), None."""
        if links is None:
            names: Sequence[str] = self.link_names
        elif isinstance(links, str):
            names = (links,)
        elif isinstance(links, Sequence) and not isinstance(links, (bytes, bytearray)):
            names = tuple(links)
            for k, n in enumerate(names):
                if not isinstance(n, str):
                    raise TypeError(
                        f"{_NAME}{fn}: expected links to be a link name, a sequence of link "
                        f"names or None, got a {type(links).__name__} whose item {k} is "
                        f"{type(n).__name__} {reprlib.repr(n)}"
                    )
        else:
            raise TypeError(
                f"{_NAME}{fn}: expected links to be a link name, a sequence of link names or "
                f"None, got {type(links).__name__} {reprlib.repr(links)}"
            )
        for n in names:
            if n not in self._index:
                raise ValueError(f"{_NAME}{fn}: unknown link {n!r} ({self._some_links()})")
        return tuple(self._index[n] for n in names)

    def _some_links(self, shown: int = 12) -> str:
        names = ", ".join(repr(n) for n in self.link_names[:shown])
        more = len(self.link_names) - shown
        return f"the links are {names}" + (f" and {more} more" if more > 0 else "")

    def forward_kinematics(
        self,
        q: Float[Tensor, "*b n_dof"],
        links: str | Sequence[str] | None = None,
        *,
        stacked: bool = False,
    ) -> dict[str, Float[Tensor, "*b 4 4"]] | Float[Tensor, "*b n 4 4"]:
        """World poses of links for joint values ``q``.

        Args:
            q: ``(..., n_dof)`` joint values in :attr:`joint_names` order, in the chain's dtype
                (float16/bfloat16 are accepted by a float32 chain, computed in float32 and
                returned in their dtype) and on its device.  Any batch shape.
            links: one link name, a sequence of names, or ``None`` for every link.  Only the
                links asked for and their ancestors are computed.
            stacked: return one tensor ``(..., n_links, 4, 4)`` (links in :attr:`link_names`
                order, or in the order given) instead of a dict.

        Returns:
            A dict link name -> ``(..., 4, 4)`` pose (in the order asked for), or the stacked
            tensor.  All results are contiguous.

        Example:
            >>> from torchlie.kinematics import sample_robot
            >>> arm = Chain.from_urdf(sample_robot("arm7"), dtype=torch.float64)
            >>> q = torch.zeros(7, dtype=torch.float64)
            >>> T = arm.forward_kinematics(q, ["tool_tcp", "link1"], stacked=True)
            >>> T.shape
            torch.Size([2, 4, 4])
            >>> T[0, :3, 3]
            tensor([ 0.0500, -0.0200,  1.4810], dtype=torch.float64)
        """
        q2, out_dtype, batch = self._prepare(q, "forward_kinematics")
        targets = self._targets(links, "forward_kinematics")
        if not targets:  # links=[]: nothing asked for
            if stacked:
                return _checks.out(q2.new_zeros(*batch, 0, 4, 4), out_dtype)
            return {}
        plan = self._plan(targets)
        B = q2.shape[0]
        out = self._run(plan, q2)
        poses = [self._pose(plan, out, i, B, q2) for i in targets]  # (c, r, B) each
        n = len(targets)
        # Back to (..., 4, 4): for small batches one stacked copy (fewest ops); for large ones
        # per-link copies, which torch runs faster than one interleaved copy.
        if B > _SMALL_BATCH:
            Ts = tuple(p.permute(2, 1, 0).contiguous() for p in poses)
        if stacked:
            if B <= _SMALL_BATCH:
                T = torch.stack(poses).permute(3, 0, 2, 1).contiguous()
            else:
                T = torch.stack(Ts, dim=1)
            return _checks.out(T.reshape(*batch, n, 4, 4), out_dtype)
        if B <= _SMALL_BATCH:
            Ts = torch.stack(poses).permute(0, 3, 2, 1).contiguous().unbind(0)
        return {
            self._links[i].name: _checks.out(T.view(*batch, 4, 4), out_dtype)
            for i, T in zip(targets, Ts, strict=True)
        }

    def _jac_plan(self, target: int) -> _JacPlan:
        cached = self._jac_plans.get(target)
        if cached is not None:
            return cached
        dev, dt = self.device, self.dtype
        path: list[_Link] = []
        i = target
        while i > 0:
            path.append(self._links[i])
            i = self._links[i].parent

        # Columns: a world direction u = R_parent @ v, v constant in the parent frame (or, for a
        # floating joint's rotation, O_R Jl(r) e_k), rotational about the child's origin or
        # translational, feeding DoF d with weight w.
        rot: list[tuple[int, tuple[float, ...], int, int, float]] = []  # parent, v, child, d, w
        tr: list[tuple[int, tuple[float, ...], int, float]] = []  # parent, v, d, w
        floats: list[tuple[int, int, int, Tensor]] = []  # parent, child, rotvec DoF, O_R
        for link in reversed(path):
            for kind, v, d, w in link.cols:
                if kind == "rot":
                    rot.append((link.parent, v, link.index, d, w))
                else:
                    tr.append((link.parent, v, d, w))
            if link.float_rot is not None:
                d0, O_R = link.float_rot
                floats.append(
                    (link.parent, link.index, d0, torch.tensor(O_R, dtype=dt, device=dev))
                )

        # Columns in the order they are stacked: constant rotations, floating rotations,
        # translations.
        dofs = [d for *_, d, _ in rot]
        dofs += [d0 + k for _, _, d0, _ in floats for k in range(3)]
        dofs += [d for *_, d, _ in tr]
        col_w = [w for *_, w in rot] + [1.0] * (3 * len(floats)) + [w for *_, w in tr]
        vs = [list(v) for _, v, *_ in rot] + [list(v) for _, v, *_ in tr]
        plan = _JacPlan(
            parents=[p for p, *_ in rot] + [p for p, *_ in tr],
            vs=torch.tensor(vs, dtype=dt, device=dev).view(len(vs), 1, 3) if vs else None,
            n_rot_const=len(rot),
            rot_children=[c for _, _, c, _, _ in rot],
            floats=floats,
            dof_index=torch.tensor(dofs, dtype=torch.long, device=dev),
            in_dof_order=dofs == list(range(self.n_dof)),
            dofs=tuple(sorted(set(dofs))),
            col_dofs=tuple(dofs),
            col_weight=(
                None
                if all(w == 1.0 for w in col_w)
                else torch.tensor(col_w, dtype=dt, device=dev).view(len(col_w), 1, 1)
            ),
        )
        if not torch.compiler.is_compiling():
            self._jac_plans[target] = plan
        return plan

    def _jacobian_columns(
        self,
        jp: _JacPlan,
        pose: Callable[[int], Tensor],
        q2: Tensor,
        target: int,
        dofs: tuple[int, ...] | None = None,
    ) -> Tensor:
        """World Jacobian at the origin of ``target`` as ``(n_dof, 6, B)`` (batch innermost; see
        :meth:`jacobian`), or only the columns of ``dofs`` (sorted DoFs, ``(len(dofs), 6, B)``);
        ``pose(i)`` gives link ``i``'s internal ``(4, 4, B)`` pose."""
        B = q2.shape[0]
        us: list[Tensor] = []
        if jp.vs is not None:
            Rs = torch.stack([pose(p)[:3, :3] for p in jp.parents])  # (n, c, r, B)
            n = Rs.shape[0]
            U = torch.matmul(jp.vs, Rs.reshape(n, 3, 3 * B)).view(n, 3, B)
            us.append(U[: jp.n_rot_const])
        origins = [pose(c)[3, :3] for c in jp.rot_children]
        for parent, child, d0, O_R in jp.floats:
            V = torch.matmul(O_R, _so3.jac_left(q2[:, d0 : d0 + 3]))  # (B, c, k)
            Rp = pose(parent)[:3, :3]  # (c, r, B)
            us.append((Rp.unsqueeze(0) * V.permute(2, 1, 0).unsqueeze(2)).sum(1))
            origins += [pose(child)[3, :3]] * 3
        cols: list[Tensor] = []
        if origins:
            Ur = torch.cat(us) if len(us) > 1 else us[0]
            p = pose(target)[3, :3]
            lin = torch.linalg.cross(Ur, p - torch.stack(origins), dim=1)
            cols.append(torch.cat((lin, Ur), dim=1))
        if jp.vs is not None and jp.n_rot_const < jp.vs.shape[0]:
            Ut = U[jp.n_rot_const :]
            cols.append(torch.cat((Ut, torch.zeros_like(Ut)), dim=1))
        n_out = self.n_dof if dofs is None else len(dofs)
        if not cols:
            return q2.new_zeros(n_out, 6, B)
        C = torch.cat(cols) if len(cols) > 1 else cols[0]  # (n_cols, 6, B)
        if jp.col_weight is not None:
            C = C * jp.col_weight
        if dofs is None:
            if jp.in_dof_order:
                return C
            index = jp.dof_index
        else:
            key = (target, dofs)
            if key in self._dof_maps:
                index = self._dof_maps[key]
            else:
                pos = {d: i for i, d in enumerate(dofs)}
                where = [pos[d] for d in jp.col_dofs]
                index = None
                if where != list(range(n_out)):
                    index = torch.tensor(where, dtype=torch.long, device=C.device)
                if not torch.compiler.is_compiling():
                    self._dof_maps[key] = index
            if index is None:  # the link's columns are those DoFs, in order
                return C
        # Each column into its DoF's column (summed where mimic joints share one).
        return C.new_zeros(n_out, 6, B).index_add(0, index, C)

    def _moving_dofs(self, targets: tuple[int, ...]) -> tuple[int, ...]:
        """The DoFs that move at least one of the links ``targets`` (sorted): the others have
        zero Jacobian columns."""
        return tuple(sorted({d for t in targets for d in self._jac_plan(t).dofs}))

    def _poses_and_jacobians(
        self, q2: Tensor, targets: tuple[int, ...], dofs: tuple[int, ...] | None = None
    ) -> tuple[list[Tensor], list[Tensor]]:
        """Poses and world Jacobians at the origins of ``targets`` for ``q2`` of shape
        ``(B, n_dof)``, from one forward-kinematics pass over the links they need, batch
        innermost: poses ``(4, 4, B)`` transposed (entry ``[c, r, b]`` is ``T[b][r, c]``),
        Jacobians ``(n_dof, 6, B)``, or only the columns of the sorted DoFs ``dofs`` (used by
        :meth:`jacobian` and the inverse kinematics)."""
        B = q2.shape[0]
        plan = self._plan(targets)
        out = self._run(plan, q2)

        def pose(i: int) -> Tensor:
            return self._pose(plan, out, i, B, q2)

        Js = [self._jacobian_columns(self._jac_plan(t), pose, q2, t, dofs) for t in targets]
        return [pose(t) for t in targets], Js

    def jacobian(
        self,
        q: Float[Tensor, "*b n_dof"],
        link: str | Sequence[str],
        *,
        frame: str = "world",
        point: Tensor | Mapping[str, Tensor] | None = None,
    ) -> Float[Tensor, "*b 6 n_dof"] | dict[str, Float[Tensor, "*b 6 n_dof"]]:
        """Geometric Jacobian of a link, ``(..., 6, n_dof)``, in closed form.

        Column ``i`` is the velocity of the link for a unit rate of DoF ``i`` (columns in
        :attr:`joint_names` order), rows (linear; angular), in one of three conventions:

        * ``frame="world"`` (the default): the linear velocity of the link's origin (or of
          ``point``) and the angular velocity, both in world coordinates.  For a revolute joint
          with world axis ``z`` through ``p_i`` the column is ``(z x (p - p_i); z)``, for a
          prismatic one ``(z; 0)``.  Same meaning as pytorch-kinematics' ``jacobian`` and
          Pinocchio's ``LOCAL_WORLD_ALIGNED``.
        * ``frame="link"``: the same velocities in the link's own coordinates, ``R^T`` times
          both rows.  At the origin this is the body twist of
          :mod:`torchlie.se3`'s right perturbation, ``T(q + dq) ~= T(q) Exp(J dq)``
          (Pinocchio's ``LOCAL``).
        * ``frame="spatial"``: the spatial twist, ``T(q + dq) ~= Exp(J dq) T(q)``: the angular
          velocity and the velocity of the body point passing through the world origin,
          ``v - w x p``, in world coordinates (Pinocchio's ``WORLD``).  It is the same for every
          point of the link, so ``point`` must be None.

        A mimic joint adds its multiplier times its own column to the column of the joint it
        follows.  A planar joint's columns are two translations and a rotation; a floating
        joint's are three translations along the joint frame's axes and the angular velocities
        ``R_joint Jl(r) e_k`` of its rotation vector (:func:`torchlie.so3.jac_left`).  Columns
        of joints that do not move the link are zero.  A robot without degrees of freedom, or
        the root link, gives an all-zero or empty ``(..., 6, n_dof)``; an empty batch gives an
        empty result.

        Args:
            q: ``(..., n_dof)`` joint values, as for :meth:`forward_kinematics`.
            link: a link name, or a sequence of names (then a dict is returned; one
                forward-kinematics pass serves them all).
            frame: ``"world"``, ``"link"`` or ``"spatial"`` (see above).
            point: ``None`` (the link's origin), a point ``(3,)`` or ``(..., 3)`` in the link's
                frame (its batch shape broadcasts with ``q``'s), or for several links a dict
                link -> point (links not in it use their origin).

        Returns:
            ``(..., 6, n_dof)``, or a dict link -> ``(..., 6, n_dof)`` in the order given.

        Example:
            >>> from torchlie.kinematics import sample_robot
            >>> arm = Chain.from_urdf(sample_robot("arm7"))
            >>> J = arm.jacobian(torch.zeros(2, 7), "tool_tcp")
            >>> J.shape, J[0, 3:, 0]
            (torch.Size([2, 6, 7]), tensor([0., 0., 1.]))
            >>> Js = arm.jacobian(torch.zeros(7), ["tool_tcp", "link3"], frame="link")
            >>> list(Js), Js["link3"].shape
            (['tool_tcp', 'link3'], torch.Size([6, 7]))
        """
        fn = "jacobian"
        q2, out_dtype, batch = self._prepare(q, fn)
        if isinstance(link, str):
            names: tuple[str, ...] = (link,)
        elif isinstance(link, Sequence) and not isinstance(link, (bytes, bytearray)):
            names = tuple(link)
        else:
            raise TypeError(
                f"{_NAME}{fn}: expected link to be a link name (str) or a sequence of link "
                f"names, got {type(link).__name__} {reprlib.repr(link)}"
            )
        targets = self._targets(names, fn)
        if frame not in ("world", "link", "spatial"):
            raise ValueError(
                f"{_NAME}{fn}: expected frame to be 'world', 'link' or 'spatial', got "
                f"{reprlib.repr(frame)}"
            )
        points = self._jacobian_points(point, names, frame, q2.dtype)
        poses, jacs = self._poses_and_jacobians(q2, targets) if targets else ([], [])
        out: dict[str, Tensor] = {}
        for name, P, Jd in zip(names, poses, jacs, strict=True):
            J = Jd.permute(2, 1, 0)  # (B, 6, n)
            if frame != "world" or points.get(name) is not None:
                J = _frame_jacobian(J, P, frame, points.get(name), batch)
            else:
                J = J.reshape(*batch, 6, self.n_dof)
            out[name] = _checks.out(J.contiguous(), out_dtype)
        if isinstance(link, str):
            return out[link]
        return out

    def _jacobian_points(
        self,
        point: Tensor | Mapping[str, Tensor] | None,
        names: tuple[str, ...],
        frame: str,
        dtype: torch.dtype,
    ) -> dict[str, Tensor]:
        """``point`` of :meth:`jacobian` checked, as a dict link -> ``(..., 3)`` point."""
        fn = _NAME + "jacobian"
        if point is None:
            return {}
        if frame == "spatial":
            raise ValueError(
                f"{fn}: point is not used with frame='spatial' (the spatial twist is the same "
                "for every point of the link); pass point=None"
            )
        if isinstance(point, Mapping):
            for k in point:
                if k not in names:
                    raise ValueError(
                        f"{fn}: point has an entry for {reprlib.repr(k)}, which is not among "
                        f"the links asked for ({', '.join(map(repr, names))})"
                    )
            items = {k: (v, f"point[{k!r}]") for k, v in point.items()}
        else:
            items = {n: (point, "point") for n in names}
        out = {}
        for k, (v, what) in items.items():
            x, _ = _checks.tensor(v, fn, what, (3,))
            if x.dtype != dtype or x.device != self.device:
                raise TypeError(
                    f"{fn}: {what} has dtype {x.dtype} on {x.device}, expected {dtype} on "
                    f"{self.device} (like q)"
                )
            out[k] = x
        return out

    def inverse_kinematics(
        self,
        targets: Tensor | Mapping[str, Tensor],
        link: str | None = None,
        **options: Any,
    ) -> IKResult:
        """Joint values putting ``link`` at ``targets``: batched Levenberg-Marquardt within the
        joint limits, differentiable with respect to the targets.

        Same as :func:`torchlie.kinematics.ik.inverse_kinematics(self, targets, link, ...)
        <torchlie.kinematics.ik.inverse_kinematics>`, which documents the options (``q0``,
        ``restarts``, weights, tolerances, ``max_iterations``, ``early_exit``, bounds,
        ``generator``) and the method.  ``targets``: poses ``(..., 4, 4)`` or positions
        ``(..., 3)``, or a dict link -> targets (then ``link`` is None).

        Returns:
            :class:`~torchlie.kinematics.IKResult` ``(q, position_error, rotation_error,
            converged, iterations)``, ``q`` of shape ``(..., n_dof)``, the others ``(...)``.

        Example:
            >>> from torchlie.kinematics import sample_robot
            >>> arm = Chain.from_urdf(sample_robot("arm7"))
            >>> q = arm.random_configuration(3, generator=torch.Generator().manual_seed(1))
            >>> p = arm.forward_kinematics(q, "tool_tcp")["tool_tcp"][:, :3, 3]
            >>> res = arm.inverse_kinematics(p, "tool_tcp", restarts=2)  # positions only
            >>> res.q.shape, res.converged.tolist()
            (torch.Size([3, 7]), [True, True, True])
        """
        return _inverse_kinematics(self, targets, link, **options)
