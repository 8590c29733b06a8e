"""A deliberately plain float64 reference for forward kinematics and Jacobians.

Written independently of :mod:`torchlie.kinematics.chain` (it shares only the parsed
:class:`~torchlie.kinematics.RobotSpec`): one joint at a time, parent before child, each pose
``T_parent @ T_origin @ M(q)`` built from explicit textbook formulas (``Rz Ry Rx`` for rpy,
Rodrigues for an axis and angle) and plain 4x4 products, always in float64.  The Jacobian is
obtained by forward-mode automatic differentiation of that same FK, one DoF at a time, and
converted to the geometric form ``(dp/dq; vee(dR/dq R^T))``, so it shares no formula with the
closed-form :meth:`Chain.jacobian <torchlie.kinematics.Chain.jacobian>`.

This is a testing oracle, not a fast path: it loops over joints in Python.
"""

from __future__ import annotations

import functools
import math

import torch
from torch import Tensor

from .urdf import JointSpec, RobotSpec

__all__ = ["reference_dof_names", "reference_forward_kinematics", "reference_jacobians"]

_COORDS = {"planar": ("x", "y", "theta"), "floating": ("x", "y", "z", "rx", "ry", "rz")}


def _own_joints(spec: RobotSpec) -> list[tuple[JointSpec, int]]:
    """The joints with DoFs of their own (not fixed, not mimic), in document order, each with
    its first DoF."""
    out = []
    k = 0
    for j in spec.joints:
        if j.type == "fixed" or j.mimic is not None:
            continue
        out.append((j, k))
        k += len(_COORDS.get(j.type, ("",)))
    return out


def reference_dof_names(spec: RobotSpec) -> list[str]:
    """DoF names in document order (fixed and mimic joints excluded).

    Example:
        >>> from torchlie.kinematics import parse_urdf, sample_robot
        >>> reference_dof_names(parse_urdf(sample_robot("arm7")))[:2]
        ['base_yaw', 'shoulder_pitch']
    """
    names = []
    for j, _ in _own_joints(spec):
        if j.type in _COORDS:
            names += [f"{j.name}:{c}" for c in _COORDS[j.type]]
        else:
            names.append(j.name)
    return names


def _rot_x(a: float) -> list[list[float]]:
    c, s = math.cos(a), math.sin(a)
    return [[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]


def _rot_y(a: float) -> list[list[float]]:
    c, s = math.cos(a), math.sin(a)
    return [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]


def _rot_z(a: float) -> list[list[float]]:
    c, s = math.cos(a), math.sin(a)
    return [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]


@functools.lru_cache(maxsize=1024)
def _origin(j: JointSpec) -> Tensor:
    r, p, y = j.rpy
    R = (
        torch.tensor(_rot_z(y), dtype=torch.float64)
        @ torch.tensor(_rot_y(p), dtype=torch.float64)
        @ torch.tensor(_rot_x(r), dtype=torch.float64)
    )
    T = torch.eye(4, dtype=torch.float64)
    T[:3, :3] = R
    T[:3, 3] = torch.tensor(j.xyz, dtype=torch.float64)
    return T


def _rodrigues(axis: Tensor, angle: Tensor) -> Tensor:
    """``(B, 3, 3)`` rotations about unit ``axis`` (shape ``(3,)`` or ``(B, 3)``) by ``angle``."""
    axis = axis.expand(angle.shape[0], 3)
    x, y, z = axis.unbind(-1)
    zero = torch.zeros_like(x)
    K = torch.stack((zero, -z, y, z, zero, -x, -y, x, zero), -1).view(-1, 3, 3)
    c, s = torch.cos(angle)[:, None, None], torch.sin(angle)[:, None, None]
    eye = torch.eye(3, dtype=torch.float64)
    return eye + s * K + (1.0 - c) * (K @ K)


def _motion(j: JointSpec, vals: Tensor) -> Tensor:
    """``(B, 4, 4)`` joint motion ``M(q)`` for the joint's values ``vals`` ``(B, k)``."""
    B = vals.shape[0]
    M = torch.eye(4, dtype=torch.float64).repeat(B, 1, 1)
    if j.type == "fixed":  # its axis is not read (and may be zero)
        return M
    if j.type != "floating":
        norm = math.hypot(*j.axis)  # no overflow for huge components (ax @ ax would be inf)
        ax = torch.tensor([x / norm for x in j.axis], dtype=torch.float64)
    if j.type in ("revolute", "continuous"):
        M[:, :3, :3] = _rodrigues(ax, vals[:, 0])
    elif j.type == "prismatic":
        M[:, :3, 3] = vals[:, :1] * ax
    elif j.type == "planar":
        # e1: the coordinate axis least aligned with the normal, projected on the plane.
        k = min(range(3), key=lambda i: abs(float(ax[i])))
        e = torch.zeros(3, dtype=torch.float64)
        e[k] = 1.0
        e1 = e - (e @ ax) * ax
        e1 = e1 / math.sqrt(float(e1 @ e1))
        e2 = torch.linalg.cross(ax, e1)
        M[:, :3, :3] = _rodrigues(ax, vals[:, 2])
        M[:, :3, 3] = vals[:, :1] * e1 + vals[:, 1:2] * e2
    elif j.type == "floating":
        w = vals[:, 3:]
        angle = torch.linalg.vector_norm(w, dim=-1)
        safe = torch.where(angle > 0, angle, torch.ones_like(angle))
        axis = torch.where(
            angle[:, None] > 0,
            w / safe[:, None],
            torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64),
        )
        M[:, :3, :3] = _rodrigues(axis, angle)
        M[:, :3, 3] = vals[:, :3]
    return M


def reference_forward_kinematics(spec: RobotSpec, q: Tensor) -> dict[str, Tensor]:
    """World poses ``(B, 4, 4)`` of every link, in float64, for ``q`` of shape ``(B, n_dof)``.

    ``q`` follows :func:`reference_dof_names` (the same layout as ``Chain.joint_names``);
    which DoFs a joint takes follows from the joints' types and document order, not from the
    names (a joint may be named ``arm:shoulder``).

    Example:
        >>> from torchlie.kinematics import parse_urdf, sample_robot
        >>> spec = parse_urdf(sample_robot("arm7"))
        >>> T = reference_forward_kinematics(spec, torch.zeros(1, 7, dtype=torch.float64))
        >>> T["tool_tcp"][0, :3, 3]
        tensor([ 0.0500, -0.0200,  1.4810], dtype=torch.float64)
    """
    q = q.to(torch.float64)
    B = q.shape[0]
    by_joint = {j.name: j for j in spec.joints}
    start = {j.name: k for j, k in _own_joints(spec)}

    def own(j: JointSpec) -> Tensor:
        if j.type == "fixed":
            return q[:, :0]
        k = {"planar": 3, "floating": 6}.get(j.type, 1)
        return q[:, start[j.name] : start[j.name] + k]

    # Mimic values, each computed once: walk a chain of mimics up to its first known value,
    # then back down (no recursion, so chains of any length).
    memo: dict[str, Tensor] = {}

    def values(j: JointSpec) -> Tensor:
        chain: list[JointSpec] = []
        cur = j
        while cur.mimic is not None and cur.name not in memo:
            chain.append(cur)
            cur = by_joint[cur.mimic.joint]
        v = memo[cur.name] if cur.mimic is not None else own(cur)
        for m in reversed(chain):
            assert m.mimic is not None
            v = memo[m.name] = v * m.mimic.multiplier + m.mimic.offset
        return v

    children: dict[str, list[JointSpec]] = {}
    for j in spec.joints:
        children.setdefault(j.parent, []).append(j)
    poses = {spec.root: torch.eye(4, dtype=torch.float64).repeat(B, 1, 1)}
    stack = [spec.root]  # parents before children
    while stack:
        for j in children.get(stack.pop(), ()):
            poses[j.child] = poses[j.parent] @ _origin(j) @ _motion(j, values(j))
            stack.append(j.child)
    return {link: poses[link] for link in spec.links}


def reference_jacobians(spec: RobotSpec, q: Tensor, links: list[str]) -> dict[str, Tensor]:
    """Geometric Jacobians ``(B, 6, n_dof)`` of ``links`` (rows linear; angular), float64.

    Forward-mode derivative of :func:`reference_forward_kinematics` along every DoF at once
    (the DoF directions are stacked into the batch), as ``(dp/dq_i; vee(dR/dq_i R^T))``.

    Example:
        >>> from torchlie.kinematics import parse_urdf, sample_robot
        >>> spec = parse_urdf(sample_robot("arm7"))
        >>> J = reference_jacobians(spec, torch.zeros(1, 7, dtype=torch.float64), ["tool_tcp"])
        >>> J["tool_tcp"][0, :, 0]
        tensor([0., 0., 0., 0., 0., 1.], dtype=torch.float64)
    """
    q = q.to(torch.float64)
    B, n = q.shape
    if n == 0:
        return {link: q.new_zeros(B, 6, 0) for link in links}
    eye = torch.eye(n, dtype=torch.float64)
    Q = q.repeat(n, 1)  # (n * B, n): block i is q
    E = eye.repeat_interleave(B, dim=0)  # block i is e_i

    def fk(x: Tensor) -> tuple[Tensor, ...]:
        poses = reference_forward_kinematics(spec, x)
        return tuple(poses[link] for link in links)

    Ts, dTs = torch.func.jvp(fk, (Q,), (E,))
    out = {}
    for link, T, dT in zip(links, Ts, dTs, strict=True):
        T, dT = T.view(n, B, 4, 4), dT.view(n, B, 4, 4)
        W = dT[..., :3, :3] @ T[..., :3, :3].transpose(-1, -2)
        w = 0.5 * torch.stack(
            (W[..., 2, 1] - W[..., 1, 2], W[..., 0, 2] - W[..., 2, 0], W[..., 1, 0] - W[..., 0, 1]),
            -1,
        )
        out[link] = torch.cat((dT[..., :3, 3], w), -1).permute(1, 2, 0)  # (B, 6, n)
    return out
