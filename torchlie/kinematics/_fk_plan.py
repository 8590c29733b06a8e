"""Forward kinematics as a plan: which links to compute for a set of targets, grouped by tree
depth and joint kind, and the batched computation of a plan.

A plan is built once per set of target links (and cached by the chain); running it costs, per
depth, one GEMM of the parents' poses against the stacked constants ``C_f`` and a few fused
multiply-adds with the joint features (see the Implementation paragraph of
:mod:`torchlie.kinematics.chain`).  Apart from :mod:`torchlie.kinematics.chain` because it is
the engine behind :meth:`Chain.forward_kinematics` and the Jacobians, not part of the API.
Poses are internal ``(4, 4, B)`` tensors, batch innermost, holding ``T[b]^T``.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

from .. import quaternion as _quaternion
from .. import so3 as _so3
from .._autograd import transforms_active
from ._joints import _Link

# Internal kinds in the order their groups are computed at each depth (one GEMM per kind).
_KIND_ORDER = ("fixed", "rot", "prism", "planar", "float", "ball", "free")


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
    quat_idx: Tensor | None = None  # value rows of the quaternions (ball, free), 4 per joint


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


def _needed(links: Sequence[_Link], targets: Iterable[int]) -> list[int]:
    """The links ``targets`` and their ancestors, sorted."""
    need: set[int] = set()
    for t in targets:
        while t >= 0 and t not in need:
            need.add(t)
            t = links[t].parent
    return sorted(need)


def _build_plan(
    links: Sequence[_Link],
    targets: tuple[int, ...],
    dt: torch.dtype,
    dev: torch.device,
    relative: bool = False,
) -> _Plan:
    """The plan computing the links ``targets`` and their ancestors, constants in ``dt`` on
    ``dev``.

    ``relative``: every child of the root is placed with its translation from the root dropped
    (its rotation kept), so that each subtree hanging from the root is computed about its own
    first link's origin, however far from the root that stands (a floating base, a mount), and
    its relative geometry keeps full precision; the poses are those of the chain moved, subtree
    by subtree, by one translation."""
    need = _needed(links, targets)
    by_depth: dict[int, list[_Link]] = {}
    for i in need:
        if i:
            by_depth.setdefault(links[i].depth, []).append(links[i])

    # Value rows that need sin / 1 - cos, and floating joints' first rows.
    rot_rows: list[int] = []
    float_rows: list[int] = []
    quat_rows: list[int] = []
    for i in need:
        link = links[i]
        if link.kind == "rot":
            rot_rows.append(link.rows[0])
        elif link.kind == "planar":
            rot_rows.append(link.rows[2])
        elif link.kind == "float":
            float_rows.append(link.rows[0])
        elif link.kind in ("ball", "free"):
            quat_rows.append(link.rows[-4])
    rot_rows = sorted(set(rot_rows))
    rot_pos = {r: k for k, r in enumerate(rot_rows)}
    float_pos = {r: k for k, r in enumerate(float_rows)}
    quat_pos = {r: k for k, r in enumerate(quat_rows)}

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
                if relative:  # C_f^T[3, :3] is C_f's translation
                    cts[:, :, 3, :3] = 0.0
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
            if kind in ("ball", "free"):  # the rotation matrix's entries, then the position
                for k in range(9):
                    rows = [quat_pos[link.rows[-4]] * 9 + k for link in members]
                    feats.append(("Q", _rows_index(rows, dev)))
            if kind == "free":
                for k in range(3):
                    feats.append(("v", _rows_index([link.rows[k] for link in members], dev)))
            groups.append(_Group([m.index for m in members], kind, parent_src, ct, feats))
        levels.append(groups)
    rot_sel = None if not rot_rows else _rows_index(rot_rows, dev)
    float_idx = None
    if float_rows:
        float_idx = torch.tensor([r + k for r in float_rows for k in range(6)], device=dev)
    quat_idx = None
    if quat_rows:
        quat_idx = torch.tensor([r + k for r in quat_rows for k in range(4)], device=dev)
    return _Plan(levels, where, rot_sel, float_idx, quat_idx)


def _run(plan: _Plan, v: Tensor) -> list[list[Tensor]]:
    """Poses of the plan's links: per level, per group, ``(n, 4, 4, B)`` = ``T[b]^T``, from the
    value bank ``v`` ``(n_dof + n_mimic, B)`` (the joint values, row per value)."""
    B = v.shape[1]
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
    if plan.quat_idx is not None:
        nq = plan.quat_idx.shape[0] // 4
        x = v.index_select(0, plan.quat_idx).view(nq, 4, B).transpose(1, 2)
        R = _quaternion.to_matrix(x)  # (n, B, 3, 3), of the normalised quaternion
        banks["Q"] = R.permute(0, 2, 3, 1).reshape(nq * 9, 1, 1, B)

    # Eager, outside the torch.func transforms (which have no batching rule for in-place
    # multiply-adds), each pose accumulates its feature terms in place (autograd records that).
    inplace = not torch.compiler.is_compiling() and not transforms_active()
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
                if f and inplace:  # T is this loop's own result: accumulate into it
                    T = T.addcmul_(_take(banks[b], sel), Y[f + 1])
                else:
                    T = torch.addcmul(T, _take(banks[b], sel), Y[f + 1])
            res.append(T)
        out.append(res)
    return out


def _pose(plan: _Plan, out: list[list[Tensor]], i: int, B: int, like: Tensor) -> Tensor:
    """Internal ``(4, 4, B)`` transposed pose of link ``i``."""
    if i == 0:
        return torch.eye(4, dtype=like.dtype, device=like.device).unsqueeze(-1).expand(4, 4, B)
    level, g, pos = plan.where[i]
    return out[level - 1][g][pos]
