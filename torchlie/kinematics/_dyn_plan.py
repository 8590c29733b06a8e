"""The dynamics' plan of a chain, built once from the parsed URDF: its bodies (links moved by
a joint with degrees of freedom, with the inertials of the links fixed to them merged in), the
joints' armature per velocity coordinate, its joint columns and the constant 0/1 matrices that
turn the Newton-Euler recursions into sums over the tree (see
:mod:`torchlie.kinematics.dynamics`).

Apart from :mod:`torchlie.kinematics.dynamics` because it runs once per chain, on the parsed
Python numbers (nothing here sees a batch), like :mod:`torchlie.kinematics._joints` for the
kinematics.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from .. import _layout
from ._joints import _Link, _unit_floats, quat_rows, rpy_rows
from .urdf import RobotSpec

_EPS64 = 2.0**-52  # float64's machine epsilon: the plan is built in float64

#: Gravity in the root frame when none is given, m/s^2.
DEFAULT_GRAVITY = (0.0, 0.0, -9.81)


# ----------------------------------------------------------------------------------------------
# The plan: bodies, joint columns and the ancestor matrices, built once per chain
# ----------------------------------------------------------------------------------------------


@dataclass
class _DynPlan:
    bodies: tuple[int, ...]  # internal link index of each body
    body_of: dict[int, int]  # link -> its body (-1: fixed to the root)
    targets: tuple[int, ...]  # links whose poses a pass needs: bodies, then column parents
    n_rot: int  # columns: n_rot constant rotations, then 3 per floating joint, then translations
    col_anchor: Tensor | None  # (n_rot, 3, 1) rotation columns' pivots in their bodies' frames
    col_v: Tensor  # (n_const, 1, 3) directions of the constant columns in their parent frames
    col_parent_pos: tuple[int, ...]  # position in targets of each constant column's frame link
    frames_are_bodies: bool  # col_parent_pos == (0, 1, ..., n_const - 1): the bodies' own frames
    rot_bodies_run: bool  # col_body[:n_rot] == (0, 1, ..., n_rot - 1)
    sub_cols: Tensor  # (K, n_bodies): row col_body[k] of sub (the composite of column k's body)
    col_body: Tensor  # (K,) body moved by each column
    col_frame: Tensor  # (K,) body whose velocity carries the column (n_bodies: the world)
    frames_are_own: bool  # col_frame == (0, 1, ..., K - 1) == the bodies: Af = A
    col_dof: Tensor  # (K,) the DoF of each column
    col_w: Tensor  # (K, 1) its weight (mimic multipliers)
    floats: list[tuple[int, int, int, Tensor]]  # parent pos in targets, body, rotvec DoF, O_R
    A: Tensor  # (n_bodies, K): 1 where the column's body is an ancestor-or-self of the body
    At: Tensor  # A transposed, contiguous
    Af: Tensor  # (K, K): 1 where column l's body is an ancestor-or-self of column k's frame
    # the first rotation column of each floating joint, as gathers of _layout.add_rows (K rows)
    float_gathers: tuple[Tensor, ...]
    sub: Tensor  # (n_bodies, n_bodies): 1 where the second is in the first's subtree
    m_gather: Tensor  # (K * K,) where each entry of the mass matrix is read (see _crba)
    m_zero: bool  # some entries are 0 (columns on different branches): read from row K * K
    W: Tensor  # (n_dof, K) folding of columns onto DoFs
    W_is_identity: bool  # column k is DoF k with weight 1 (no mimic joint, DoF order)
    # merged (mass, com, inertia), then the armature per velocity coordinate, float64 CPU
    inertials64: tuple[Tensor, Tensor, Tensor, Tensor]
    inertials: tuple[Tensor, Tensor, Tensor, Tensor]  # the same in the chain's dtype and device
    has_armature: bool  # some armature is not 0 (else the dynamics leave it out)
    gravity: Tensor  # (3, 1) DEFAULT_GRAVITY in the chain's dtype and device
    massless: list[str]  # DoFs that move neither mass nor inertia (a translation: no mass)


# The merge of the inertials is written on Python floats: the plan is then the same whether
# it is built eagerly or while torch.compile traces a first call.
_M3 = list[list[float]]


def _mul3(A: _M3, B: _M3) -> _M3:
    return [[sum(A[i][k] * B[k][j] for k in range(3)) for j in range(3)] for i in range(3)]


def _mv3(A: _M3, v: list[float]) -> list[float]:
    return [sum(A[i][k] * v[k] for k in range(3)) for i in range(3)]


def _compose(T1: tuple[_M3, list[float]], T2: tuple[_M3, list[float]]):
    """``T1 T2`` for poses ``(R, t)``."""
    R1, t1 = T1
    R2, t2 = T2
    return _mul3(R1, R2), [a + b for a, b in zip(_mv3(R1, t2), t1, strict=True)]


def _merge(parts: list[tuple[float, list[float], _M3]]) -> tuple[float, list[float], _M3]:
    """One rigid body from several ``(mass, centre of mass, inertia about it)`` in one frame
    (parallel-axis theorem)."""
    m = sum(p[0] for p in parts)
    c = [sum(p[0] * p[1][i] for p in parts) / m for i in range(3)] if m > 0 else [0.0] * 3
    inertia = [[0.0] * 3 for _ in range(3)]
    for mi, ci, Ii in parts:
        d = [ci[k] - c[k] for k in range(3)]
        d2 = sum(x * x for x in d)
        for i in range(3):
            for j in range(3):
                inertia[i][j] += Ii[i][j] + mi * ((d2 if i == j else 0.0) - d[i] * d[j])
    return m, c, inertia


def _build(spec: RobotSpec, links: list[_Link], joint_names: tuple[str, ...]) -> _DynPlan:
    """The plan; ``joint_names`` names the velocity coordinates (the columns' DoFs)."""
    n_dof = len(joint_names)
    moving = [lk.index for lk in links[1:] if lk.cols or lk.float_rot is not None]
    body_ix = {i: b for b, i in enumerate(moving)}
    nb = len(moving)
    # Each link's body and its pose in the body's frame (fixed joints only in between).
    eye3 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    body_of: dict[int, int] = {0: -1}
    pose_in_body: dict[int, tuple[_M3, list[float]]] = {0: (eye3, [0.0] * 3)}
    for lk in links[1:]:
        if lk.index in body_ix:
            body_of[lk.index] = body_ix[lk.index]
            pose_in_body[lk.index] = (eye3, [0.0] * 3)
        else:
            # A fixed joint's origin as the kinematics read it (``_joints._origin``: a
            # quaternion where there is one, else rpy; anchors and ref concern moving joints).
            j = lk.joint
            assert j is not None
            body_of[lk.index] = body_of[lk.parent]
            origin = (rpy_rows(*j.rpy) if j.quat is None else quat_rows(j.quat), list(j.xyz))
            pose_in_body[lk.index] = _compose(pose_in_body[lk.parent], origin)
    # Merged inertials in the body frames.
    spec_in = dict(zip(spec.links, spec.inertials, strict=True)) if spec.inertials else {}
    per_body: list[list[tuple[float, list[float], _M3]]] = [[] for _ in range(nb)]
    for lk in links:
        b = body_of[lk.index]
        ins = spec_in.get(lk.name)
        if b < 0 or ins is None:
            continue
        R, c = _compose(pose_in_body[lk.index], (rpy_rows(*ins.rpy), list(ins.xyz)))
        ixx, ixy, ixz, iyy, iyz, izz = ins.inertia
        I_f = [[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]]
        Rt = [list(r) for r in zip(*R, strict=True)]
        per_body[b].append((ins.mass, c, _mul3(_mul3(R, I_f), Rt)))
    merged = [_merge(p) for p in per_body]
    mass = torch.tensor([m for m, _, _ in merged], dtype=torch.float64)
    com = torch.tensor([c for _, c, _ in merged], dtype=torch.float64).reshape(nb, 3)
    inertia = torch.tensor([i for _, _, i in merged], dtype=torch.float64).reshape(nb, 3, 3)

    parent_body = [body_of[links[i].parent] for i in moving]
    anc_sets: list[set[int]] = []
    for b in range(nb):
        s = {b}
        p = parent_body[b]
        while p >= 0:
            s.add(p)
            p = parent_body[p]
        anc_sets.append(s)

    # Columns: constant rotations, floating rotations, translations.  A column's direction is
    # fixed in a link's frame: the link's own for rotations about its joint's axis ("rot":
    # the rotation about the axis leaves it fixed), for prismatic joints and for ball and free
    # joints' angular velocities ("crot"); its parent's for the translations of planar,
    # floating and free joints (the link turns under them).  Own frames need no parent pose,
    # and where they are the bodies in order, no gather at all.  Rotations turn about the
    # link's anchor.
    rot: list[tuple[int, tuple[float, ...], int, int, float]] = []  # frame, v, body, d, w
    tr: list[tuple[int, tuple[float, ...], int, int, float]] = []
    anchors: list[tuple[float, float, float]] = []  # per rotation column, in its body's frame
    floats_raw: list[tuple[int, int, int, Tensor]] = []
    for i in moving:
        lk = links[i]
        b = body_ix[i]
        own = lk.kind in ("rot", "prism")
        for kind, v, d, w in lk.cols:
            if kind == "tr":
                if own:  # the axis in the child's frame
                    assert lk.joint is not None
                    tr.append((lk.index, _unit_floats(lk.joint.axis), b, d, w))
                else:
                    tr.append((lk.parent, v, b, d, w))
                continue
            if kind == "rot":  # revolute, continuous, planar: the axis in the child's frame
                assert lk.joint is not None
                rot.append((lk.index, _unit_floats(lk.joint.axis), b, d, w))
            else:
                rot.append((lk.index, v, b, d, w))
            anchors.append(lk.anchor or (0.0, 0.0, 0.0))
        if lk.float_rot is not None:
            d0, O_R = lk.float_rot
            floats_raw.append((lk.parent, b, d0, torch.tensor(O_R, dtype=torch.float64)))
    const = rot + tr
    parents = sorted({p for p, *_ in const} | {p for p, *_ in floats_raw})
    targets = tuple(moving) + tuple(p for p in parents if p not in body_ix)
    pos = {t: k for k, t in enumerate(targets)}
    col_parent_pos = tuple(pos[p] for p, *_ in const)
    col_body = [b for _, _, b, _, _ in rot]
    col_body += [b for _, b, _, _ in floats_raw for _ in range(3)]
    col_body += [b for _, _, b, _, _ in tr]
    col_frame = [b for _, _, b, _, _ in rot] + [b for _, b, _, _ in floats_raw for _ in range(3)]
    col_frame += [body_of[p] if body_of[p] >= 0 else nb for p, *_ in tr]
    col_dof = [d for *_, d, _ in rot] + [d0 + k for _, _, d0, _ in floats_raw for k in range(3)]
    col_dof += [d for *_, d, _ in tr]
    col_w = [w for *_, w in rot] + [1.0] * (3 * len(floats_raw)) + [w for *_, w in tr]
    K = len(col_body)
    A = torch.zeros(nb, K, dtype=torch.float64)
    for b in range(nb):
        for k in range(K):
            if col_body[k] in anc_sets[b]:
                A[b, k] = 1.0
    sub = torch.tensor(
        [[1.0 if b in anc_sets[c] else 0.0 for c in range(nb)] for b in range(nb)],
        dtype=torch.float64,
    ).reshape(nb, nb)

    def anc(k: int, j: int) -> bool:  # column k's body is an ancestor-or-self of column j's
        return col_body[k] in anc_sets[col_body[j]]

    m_gather = [
        k * K + j if anc(k, j) else (j * K + k if anc(j, k) else K * K)
        for k in range(K)
        for j in range(K)
    ]
    W = torch.zeros(n_dof, K, dtype=torch.float64)
    for k in range(K):
        W[col_dof[k], k] += col_w[k]
    Af = torch.tensor(
        [
            [float(col_frame[k] < nb and col_body[j] in anc_sets[col_frame[k]]) for j in range(K)]
            for k in range(K)
        ],
        dtype=torch.float64,
    ).reshape(K, K)

    # The armature per velocity coordinate: each joint's on its own coordinates (a mimic
    # joint has none of its own; its columns drive the coordinate of the joint it follows).
    armature = [0.0] * n_dof
    for lk in links[1:]:
        if lk.joint is None or lk.joint.mimic is not None:
            continue
        dofs = {d for _, _, d, _ in lk.cols}
        if lk.float_rot is not None:
            dofs |= {lk.float_rot[0] + k for k in range(3)}
        for d in dofs:
            armature[d] = float(lk.joint.armature)

    # DoFs that move nothing resisting their motion (M has a zero row there): a subtree with
    # neither mass nor inertia, a translation (prismatic, floating, free) moving no mass, or a
    # rotation of an end body about an axis holding its mass (below), and no armature; a DoF
    # is named when every column it drives is such a column.
    subtrees = [[c for c in range(nb) if b in anc_sets[c]] for b in range(nb)]
    empty = [
        all(merged[c][0] == 0.0 and not any(any(r) for r in merged[c][2]) for c in sub_b)
        for sub_b in subtrees
    ]
    no_mass = [all(merged[c][0] == 0.0 for c in sub_b) for sub_b in subtrees]
    n_turn = len(rot) + 3 * len(floats_raw)  # the columns after these translate
    # A body at the end of the tree turned about an axis through its anchor that holds all its
    # mass, with no inertia about it (a point mass on a hinge's axis): its diagonal entry of M,
    # v.I v + m |v x r|^2, is 0 in every state (up to the rounding of a rotated inertia), or
    # negative where the file's inertia is not physical.
    flat = [False] * K
    for k, (_, v, b, _, _) in enumerate(rot):
        if len(subtrees[b]) == 1:
            m_b, c_b, I_b = merged[b]
            r = [c_b[i] - anchors[k][i] for i in range(3)]
            vr = [v[1] * r[2] - v[2] * r[1], v[2] * r[0] - v[0] * r[2], v[0] * r[1] - v[1] * r[0]]
            m_kk = sum(x * y for x, y in zip(v, _mv3(I_b, list(v)), strict=True))
            m_kk += m_b * sum(x * x for x in vr)
            scale = I_b[0][0] + I_b[1][1] + I_b[2][2] + m_b * sum(x * x for x in r)
            flat[k] = m_kk <= 4 * _EPS64 * scale
    inert = [
        empty[col_body[k]] or flat[k] or (k >= n_turn and no_mass[col_body[k]]) for k in range(K)
    ]
    massless = sorted(
        {
            joint_names[d]
            for d in {col_dof[k] for k in range(K)}
            if armature[d] == 0.0 and all(inert[k] for k in range(K) if col_dof[k] == d)
        },
        key=joint_names.index,
    )
    return _DynPlan(
        bodies=tuple(moving),
        body_of=body_of,
        targets=targets,
        n_rot=len(rot),
        col_anchor=(
            torch.tensor(anchors, dtype=torch.float64).reshape(-1, 3, 1)
            if any(any(a) for a in anchors)
            else None
        ),
        col_v=torch.tensor([list(v) for _, v, *_ in const], dtype=torch.float64).reshape(-1, 1, 3),
        col_parent_pos=col_parent_pos,
        frames_are_bodies=len(const) <= nb and col_parent_pos == tuple(range(len(const))),
        rot_bodies_run=col_body[: len(rot)] == list(range(len(rot))),
        sub_cols=sub[torch.tensor(col_body, dtype=torch.long)].reshape(K, nb),
        col_body=torch.tensor(col_body, dtype=torch.long),
        col_frame=torch.tensor(col_frame, dtype=torch.long),
        frames_are_own=K == nb and col_frame == list(range(K)),
        col_dof=torch.tensor(col_dof, dtype=torch.long),
        col_w=torch.tensor(col_w, dtype=torch.float64).reshape(K, 1),
        floats=[(pos[p], b, d0, O_R) for p, b, d0, O_R in floats_raw],
        A=A,
        At=A.T.contiguous(),
        Af=Af,
        float_gathers=_layout.row_gathers(
            [len(rot) + 3 * k for k in range(len(floats_raw))], K, torch.device("cpu")
        ),
        sub=sub,
        m_gather=torch.tensor(m_gather, dtype=torch.long),
        m_zero=K * K in m_gather,
        W=W,
        W_is_identity=col_dof == list(range(n_dof)) and all(w == 1.0 for w in col_w),
        inertials64=(mass, com, inertia, torch.tensor(armature, dtype=torch.float64)),
        inertials=(mass, com, inertia, torch.tensor(armature, dtype=torch.float64)),
        has_armature=any(a != 0.0 for a in armature),
        gravity=torch.tensor(DEFAULT_GRAVITY, dtype=torch.float64).unsqueeze(-1),
        massless=massless,
    )


def _convert(plan: _DynPlan, dtype: torch.dtype, device: torch.device) -> _DynPlan:
    """The plan's float tensors in ``dtype`` on ``device`` (index tensors moved only)."""

    def f(x: Tensor) -> Tensor:
        return x.to(dtype=dtype, device=device)

    def i(x: Tensor) -> Tensor:
        return x.to(device=device)

    return _DynPlan(
        bodies=plan.bodies,
        body_of=plan.body_of,
        targets=plan.targets,
        n_rot=plan.n_rot,
        col_anchor=None if plan.col_anchor is None else f(plan.col_anchor),
        col_v=f(plan.col_v),
        col_parent_pos=plan.col_parent_pos,
        frames_are_bodies=plan.frames_are_bodies,
        rot_bodies_run=plan.rot_bodies_run,
        sub_cols=f(plan.sub_cols),
        col_body=i(plan.col_body),
        col_frame=i(plan.col_frame),
        frames_are_own=plan.frames_are_own,
        col_dof=i(plan.col_dof),
        col_w=f(plan.col_w),
        floats=[(p, b, d0, f(O)) for p, b, d0, O in plan.floats],
        A=f(plan.A),
        At=f(plan.At),
        Af=f(plan.Af),
        float_gathers=tuple(i(g) for g in plan.float_gathers),
        sub=f(plan.sub),
        m_gather=i(plan.m_gather),
        m_zero=plan.m_zero,
        W=f(plan.W),
        W_is_identity=plan.W_is_identity,
        inertials64=plan.inertials64,
        inertials=(
            f(plan.inertials[0]),
            f(plan.inertials[1]),
            f(plan.inertials[2]),
            f(plan.inertials[3]),
        ),
        has_armature=plan.has_armature,
        gravity=f(plan.gravity),
        massless=plan.massless,
    )
