"""Geometric Jacobians of the chain's links: per link, a plan of its columns (one per moving
joint on its path, each feeding one DoF), their batched computation from the link poses, and
the change of frame and reference point of :meth:`Chain.jacobian`.

Apart from :mod:`torchlie.kinematics.chain` because it is the Jacobian's own machinery: it
takes the links built by :mod:`~torchlie.kinematics._joints` and the poses computed by
:mod:`~torchlie.kinematics._fk_plan` (as a function of the link), and returns plain tensors;
the chain caches the plans.  Poses are internal ``(4, 4, B)`` tensors, batch innermost,
holding ``T[b]^T``; world Jacobians at a link's origin are ``(n_cols, 6, B)``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

from .. import _components, _layout
from .. import so3 as _so3
from ._joints import _Link


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
    dof_gathers: tuple[Tensor, ...]  # dof_index for _layout.add_rows (n_dof rows)
    dofs: tuple[int, ...]  # the DoFs that move the link (those of dof_index, sorted)
    col_dofs: tuple[int, ...]  # dof_index as Python ints
    # (n_rot_const, 3, 1, 1): the centre of each rotation in its child's frame (MJCF joint
    # anchors), None when every centre is the child's origin
    rot_anchor: Tensor | None = None


def _jacobian_plan(
    links: Sequence[_Link], target: int, n_dof: int, dt: torch.dtype, dev: torch.device
) -> _JacPlan:
    """The columns of the Jacobian of link ``target`` (of a chain with ``n_dof`` DoFs),
    constants in ``dt`` on ``dev``."""
    path: list[_Link] = []
    i = target
    while i > 0:
        path.append(links[i])
        i = links[i].parent

    # Columns: a world direction u = R_parent @ v, v constant in the parent frame (or, for a
    # floating joint's rotation, O_R Jl(r) e_k), rotational about the child's origin or
    # translational, feeding DoF d with weight w.
    rot: list[tuple[int, tuple[float, ...], int, int, float]] = []  # parent, v, child, d, w
    tr: list[tuple[int, tuple[float, ...], int, float]] = []  # parent, v, d, w
    floats: list[tuple[int, int, int, Tensor]] = []  # parent, child, rotvec DoF, O_R
    anchors: list[tuple[float, float, float]] = []
    for link in reversed(path):
        for kind, v, d, w in link.cols:
            if kind in ("rot", "crot"):  # crot: a direction fixed in the child's frame
                frame = link.parent if kind == "rot" else link.index
                rot.append((frame, v, link.index, d, w))
                anchors.append(link.anchor or (0.0, 0.0, 0.0))
            else:
                tr.append((link.parent, v, d, w))
        if link.float_rot is not None:
            d0, O_R = link.float_rot
            floats.append((link.parent, link.index, d0, torch.tensor(O_R, dtype=dt, device=dev)))

    # Columns in the order they are stacked: constant rotations, floating rotations,
    # translations.
    dofs = [d for *_, d, _ in rot]
    dofs += [d0 + k for _, _, d0, _ in floats for k in range(3)]
    dofs += [d for *_, d, _ in tr]
    col_w = [w for *_, w in rot] + [1.0] * (3 * len(floats)) + [w for *_, w in tr]
    vs = [list(v) for _, v, *_ in rot] + [list(v) for _, v, *_ in tr]
    return _JacPlan(
        parents=[p for p, *_ in rot] + [p for p, *_ in tr],
        vs=torch.tensor(vs, dtype=dt, device=dev).view(len(vs), 1, 3) if vs else None,
        n_rot_const=len(rot),
        rot_children=[c for _, _, c, _, _ in rot],
        floats=floats,
        dof_index=torch.tensor(dofs, dtype=torch.long, device=dev),
        in_dof_order=dofs == list(range(n_dof)),
        dof_gathers=_layout.row_gathers(dofs, n_dof, dev),
        dofs=tuple(sorted(set(dofs))),
        col_dofs=tuple(dofs),
        col_weight=(
            None
            if all(w == 1.0 for w in col_w)
            else torch.tensor(col_w, dtype=dt, device=dev).view(len(col_w), 1, 1)
        ),
        rot_anchor=(
            torch.tensor(anchors, dtype=dt, device=dev).view(len(anchors), 3, 1, 1)
            if any(any(a) for a in anchors)
            else None
        ),
    )


def _link_columns(
    jp: _JacPlan, pose: Callable[[int], Tensor], q2: Tensor, target: int
) -> Tensor | None:
    """The columns of the world Jacobian at the origin of ``target`` (plan ``jp``), weighted,
    ``(n_cols, 6, B)`` in the plan's order, or None when no joint moves the link; ``pose(i)``
    gives link ``i``'s internal ``(4, 4, B)`` pose and ``q2`` is ``(B, n_dof)``."""
    B = q2.shape[0]
    us: list[Tensor] = []
    if jp.vs is not None:
        Rs = torch.stack([pose(p)[:3, :3] for p in jp.parents])  # (n, c, r, B)
        n = Rs.shape[0]
        U = torch.matmul(jp.vs, Rs.reshape(n, 3, 3 * B)).view(n, 3, B)
        us.append(U[: jp.n_rot_const])
    origins = [pose(c)[3, :3] for c in jp.rot_children]
    if jp.rot_anchor is not None:  # the anchor p of the child c: t_c + R_c p
        Rc = torch.stack([pose(c)[:3, :3] for c in jp.rot_children])  # (n, c, r, B)
        origins = list((torch.stack(origins) + (jp.rot_anchor * Rc).sum(1)).unbind(0))
    for parent, child, d0, O_R in jp.floats:
        V = torch.matmul(O_R, _so3.jac_left(q2[:, d0 : d0 + 3]))  # (B, c, k)
        Rp = pose(parent)[:3, :3]  # (c, r, B)
        us.append((Rp.unsqueeze(0) * V.permute(2, 1, 0).unsqueeze(2)).sum(1))
        origins += [pose(child)[3, :3]] * 3
    cols: list[Tensor] = []
    if origins:
        Ur = torch.cat(us) if len(us) > 1 else us[0]
        p = pose(target)[3, :3]
        lin = _components.cross(Ur, p - torch.stack(origins), dim=1)
        cols.append(torch.cat((lin, Ur), dim=1))
    if jp.vs is not None and jp.n_rot_const < jp.vs.shape[0]:
        Ut = U[jp.n_rot_const :]
        cols.append(torch.cat((Ut, torch.zeros_like(Ut)), dim=1))
    if not cols:
        return None
    C = torch.cat(cols) if len(cols) > 1 else cols[0]  # (n_cols, 6, B)
    if jp.col_weight is not None:
        C = C * jp.col_weight
    return C


def _dof_index(
    jp: _JacPlan, dofs: tuple[int, ...], device: torch.device
) -> tuple[Tensor | None, tuple[Tensor, ...] | None]:
    """``(keep, where)`` for the Jacobian columns of the sorted DoFs ``dofs``: ``keep``, the
    columns of ``jp`` that feed one of them (None: all do), and ``where``, the place of each
    kept column among ``dofs`` as gathers of :func:`torchlie._layout.add_rows` (None: the kept
    columns are those DoFs, in order)."""
    pos = {d: i for i, d in enumerate(dofs)}
    kept = [k for k, d in enumerate(jp.col_dofs) if d in pos]
    where = [pos[jp.col_dofs[k]] for k in kept]
    keep = None
    if len(kept) < len(jp.col_dofs):
        keep = torch.tensor(kept, dtype=torch.long, device=device)
    if where == list(range(len(dofs))):
        return keep, None
    return keep, _layout.row_gathers(where, len(dofs), device)


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
