"""Rigid-body dynamics of a :class:`~torchlie.kinematics.Chain`: inverse dynamics (recursive
Newton-Euler), the joint-space mass matrix (composite rigid bodies), forward dynamics, bias
forces and gravity torques, batched and differentiable, also with respect to the inertials.

Conventions (see also ``docs/dynamics.md``):

* Coordinates: ``q``, ``qd = dq/dt``, ``qdd`` and ``tau`` are ``(..., n_dof)`` in
  :attr:`Chain.joint_names` order, exactly the coordinates of the kinematics (for a floating
  joint: its translation and the time derivatives of its rotation vector; for a planar joint
  ``(x, y, theta)``).  The equations of motion are ``M(q) qdd + h(q, qd) = tau + sum_links
  J_link(q)^T f_link``, ``tau`` the generalised forces (torques of revolute joints, forces of
  prismatic ones) that do virtual work ``tau . dq``.  A mimic joint has no coordinate: its
  motion is ``m qd[J]`` and its torque is added, times ``m``, to the torque of the joint it
  follows (the reduced equations of the mimic constraint).
* MJCF chains use MuJoCo's coordinates: ``q`` is ``qpos`` (a unit quaternion per ball joint,
  position and quaternion per free joint), while ``qd``, ``qdd`` and ``tau`` are over the
  ``n_v`` velocity coordinates (:attr:`Chain.velocity_names`, MuJoCo's ``nv``: a ball joint's
  angular velocity in its body's frame, a free joint's linear velocity of the body's origin in
  the world frame then its angular velocity in the body's frame), as
  :meth:`Chain.jacobian`'s columns; ``M`` is ``(..., n_v, n_v)``.  The results are MuJoCo's
  ``qfrc_inverse``, ``mj_fullM`` and ``qacc`` with the joints' armature, without what else
  MuJoCo adds to the rigid bodies (damping, friction loss, springs, contacts, constraints,
  actuators, tendons).
* Bodies: every link moved by a joint with degrees of freedom (a mimic joint included) is a
  body; links attached through fixed joints merge their inertials into their nearest moving
  ancestor (links fixed to the root do not move and are ignored).  :attr:`Chain.inertials`
  holds, per body (:attr:`Chain.body_names`), its mass, centre of mass and rotational inertia
  about the centre of mass, both in the body's (link) frame, and per velocity coordinate the
  joint's armature (rotor inertia reflected to the joint: MuJoCo's ``armature``, 0 for URDF and
  SDF), added to ``M``'s diagonal (so ``armature * qdd`` to ``tau``; the bias forces do not
  change).  A mimic joint has no coordinate, hence no armature of its own.
* Gravity ``(3,)`` or ``(..., 3)`` is the acceleration of free fall in the root (world) frame,
  default ``(0, 0, -9.81)``.  External wrenches ``f_ext`` map a link name to a ``(..., 6)``
  wrench ``(force; torque)`` acting on that link, in world coordinates, the torque taken about
  the link's origin (the dual of :meth:`Chain.jacobian`'s default ``frame="world"``: the
  wrench contributes ``J^T f`` to the equations).

Method: spatial vectors are 6-vectors (linear; angular) in world coordinates (Plücker
coordinates) about one point per subtree hanging from the root: the origin of that subtree's
first link, so that the moments stay of the size of the robot however far from the world origin
it stands (a floating base, a mount): the results do not depend on where a subtree stands, and
neither does their precision. In that frame every recursion of the Newton-Euler algorithm is a
sum along the tree: body velocities and accelerations are sums of their joints' motions over the
ancestors, and joint forces sums of body forces over the subtree, so each is one product with a
constant 0/1 ancestor matrix, batch innermost, instead of a loop over links. The mass matrix
follows from composite inertias (mass, first and second moment about that point, summed over
subtrees by one product with the subtree matrix) and the joint axes; forward dynamics solves
``M qdd = tau - h`` by a batched Cholesky factorisation (the articulated-body algorithm would be a
Python loop over the tree's depth; for the tens of degrees of freedom of a robot the Cholesky
solve is as exact and costs fewer torch calls). Large eager CPU batches run block by block
through the shared driver (:func:`torchlie._autograd.evaluate`, blocks of fewer rows the more
joint columns), so that the temporaries of a call stay bounded.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import NamedTuple

import torch
from torch import Tensor

from .. import _checks, _coeffs, _components, _layout
from .. import so3 as _so3
from .._autograd import cached, evaluate, fma, needs_graph, transforms_active
from .._typing import Float
from ._dyn_plan import DEFAULT_GRAVITY, _build, _convert, _DynPlan
from .urdf import _some

__all__ = ["Inertials", "DEFAULT_GRAVITY"]

_NAME = "torchlie.kinematics.Chain."


class Inertials(NamedTuple):
    """Inertial parameters of a chain's bodies (:attr:`Chain.body_names` order) and joints.

    Attributes:
        mass: ``(..., n_bodies)`` kg.
        com: ``(..., n_bodies, 3)`` centre of mass in the body's frame, m.
        inertia: ``(..., n_bodies, 3, 3)`` rotational inertia about the centre of mass, axes of
            the body's frame, kg m^2; read as its symmetric part ``(I + I^T) / 2``, so that
            every function sees the same matrix and the derivative in one off-diagonal entry
            is half that in the symmetric pair.
        armature: ``(..., n_v)`` per velocity coordinate (:attr:`Chain.velocity_names`), the
            inertia added to the mass matrix's diagonal (rotor inertia reflected to the joint:
            kg m^2 for a rotation, kg for a translation; MuJoCo's joint ``armature``,
            Pinocchio's ``model.armature``).  ``None`` (the default, so ``Inertials(mass, com,
            inertia)``): the chain's own, :attr:`Chain.inertials`'s.

    Leading batch dimensions are allowed (they broadcast to ``q``'s batch shape); the tensors
    may require gradients (system identification).

    Example:
        >>> from torchlie.kinematics import Chain, sample_robot
        >>> arm = Chain.from_urdf(sample_robot("arm7"))
        >>> arm.inertials.mass.shape, arm.body_names[:2], arm.inertials.armature.shape
        (torch.Size([7]), ('link1', 'link2'), torch.Size([7]))
    """

    mass: Tensor
    com: Tensor
    inertia: Tensor
    armature: Tensor | None = None


def _plan(chain) -> _DynPlan:
    return cached(
        chain.__dict__,
        "_dyn_plan",
        lambda: _convert(
            _build(chain.spec, chain._links, chain.velocity_names), chain.dtype, chain.device
        ),
    )


def _body_names(chain) -> tuple[str, ...]:
    """The chain's bodies (links moved by a joint with degrees of freedom), internal order."""
    return tuple(chain._links[i].name for i in _plan(chain).bodies)


def _inertials(chain) -> Inertials:
    """The chain's merged inertials and its armature in its dtype and on its device (fresh
    tensors)."""
    dt, dev = chain.dtype, chain.device
    return Inertials(*(x.to(device=dev, dtype=dt, copy=True) for x in _plan(chain).inertials64))


# ----------------------------------------------------------------------------------------------
# The computation, batch innermost: spatial 6-vectors are (n, 6, B), 3-vectors (n, 3, B)
# ----------------------------------------------------------------------------------------------


def _cross_parts(a: Tensor, b: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """The components of the cross product of vectors along dim -2."""
    return _components.cross_planes(a.unbind(-2), b.unbind(-2))


def _cross_sum(x: Tensor | None, *terms: tuple[Tensor, Tensor]) -> tuple[Tensor, Tensor, Tensor]:
    """The components of ``x + sum a x b`` over ``terms`` (vectors along dim -2; ``x`` None:
    0), each summed by multiply-adds before anything is stacked."""
    if x is None:
        out = list(_cross_parts(*terms[0]))
        terms = terms[1:]
    else:
        out = list(x.unbind(-2))
    for a, b in terms:
        a0, a1, a2 = a.unbind(-2)
        b0, b1, b2 = b.unbind(-2)
        for i, (p, q, r, t) in enumerate(((a1, b2, a2, b1), (a2, b0, a0, b2), (a0, b1, a1, b0))):
            out[i] = fma(fma(out[i], p, q), r, t, -1.0)
    return out[0], out[1], out[2]


def _stack6(lin: tuple[Tensor, ...], ang: tuple[Tensor, ...]) -> Tensor:
    """Spatial vectors ``(..., 2, 3, B)`` from the components of their two parts."""
    v = torch.stack((*lin, *ang), dim=-2)
    return v.view(*v.shape[:-2], 2, 3, v.shape[-1])


def _columns_times(cols: Tensor, x: Tensor) -> Tensor:
    """``sum_k cols[..., k, :, :] * x[..., k, :]``: a 3x3 matrix given by its columns
    ``(..., k, 3, B)`` times ``x (..., 3, B)``, as three multiply-adds."""
    c0, c1, c2 = cols.unbind(-3)
    x0, x1, x2 = x.unsqueeze(-2).unbind(-3)
    return fma(fma(c0 * x0, c1, x1), c2, x2)


def _rot(RT: Tensor, x: Tensor) -> Tensor:
    """``R x`` for internal transposed rotations ``RT (..., c, r, B)`` and ``x (..., 3, B)``."""
    return _columns_times(RT, x)


def _rot_t(RT: Tensor, x: Tensor) -> Tensor:
    """``R^T x``."""
    return _columns_times(RT.transpose(-3, -2), x)


def _mat(M: Tensor, x: Tensor) -> Tensor:
    """``M x`` for ``M (..., 3, 3, B|1)`` (rows, columns) and ``x (..., 3, B)``."""
    return _columns_times(M.transpose(-3, -2), x)


@dataclass
class _Geometry:
    S: Tensor  # (K, 2, 3, B) joint columns (linear; angular), world Plücker coordinates
    p: Tensor  # (nb, 3, B) body origins
    RT: Tensor  # (nb, 3, 3, B) body rotations, transposed: RT[c, r] = R[r, c]
    origins: list[Tensor]  # (3, B) origins of the extra links asked for
    floats: list[tuple[Tensor, Tensor, Tensor]]  # per floating joint: R_parent O_R, r, p

    @property
    def Sl(self) -> Tensor:
        return self.S[:, 0]

    @property
    def Sa(self) -> Tensor:
        return self.S[:, 1]


def _cat(parts: list[Tensor]) -> Tensor:
    """``torch.cat(parts)`` without the copy of a single part."""
    return parts[0] if len(parts) == 1 else torch.cat(parts)


def _geometry(chain, plan: _DynPlan, q2: Tensor, extra: tuple[int, ...]) -> _Geometry:
    """Poses and joint columns for ``q2 (B, n_dof)``; ``extra``: more links whose origins are
    wanted."""
    B = q2.shape[0]
    targets = plan.targets + extra
    fk = chain._plan(targets, relative=True)
    out = chain._run(fk, q2)
    poses = [chain._pose(fk, out, i, B, q2) for i in targets]  # (c, r, B) each
    nb = len(plan.bodies)
    RT = torch.stack([P[:3, :3] for P in poses[:nb]])  # (nb, c, r, B)
    p = torch.stack([P[3, :3] for P in poses[:nb]])  # (nb, 3, B)
    parts_u: list[Tensor] = []
    parts_p: list[Tensor] = []
    n_const = plan.col_v.shape[0]
    U = None
    if n_const:
        if plan.frames_are_bodies:  # each column's direction is fixed in its own body
            Rf = RT[:n_const]
        else:
            Rf = torch.stack([poses[k][:3, :3] for k in plan.col_parent_pos])
        U = torch.matmul(plan.col_v, Rf.reshape(n_const, 3, 3 * B)).view(n_const, 3, B)
        parts_u.append(U[: plan.n_rot])
        if plan.rot_bodies_run:
            piv = p[: plan.n_rot]
        else:
            piv = p.index_select(0, plan.col_body[: plan.n_rot])
        if plan.col_anchor is not None:  # the joint turns about a point of its body
            piv = piv + _rot(RT.index_select(0, plan.col_body[: plan.n_rot]), plan.col_anchor)
        parts_p.append(piv)
    floats = []
    for ppos, b, d0, O_R in plan.floats:
        Rp = poses[ppos][:3, :3]  # (c, r, B)
        RO = torch.einsum("crb,ck->rkb", Rp, O_R)  # R_parent O_R, (3, 3, B)
        r = q2[:, d0 : d0 + 3]
        Jl = _so3.jac_left(r).permute(1, 2, 0)  # (3, 3, B)
        parts_u.append(torch.einsum("rkb,kjb->jrb", RO, Jl))  # column j: RO Jl e_j
        parts_p.append(p[b].unsqueeze(0).expand(3, 3, B))
        floats.append((RO, r, p[b]))
    origins = [P[3, :3] for P in poses[len(plan.targets) :]]
    parts_s = []
    if parts_u:  # rotation columns: (p x u; u), stacked at once
        Ur = _cat(parts_u)
        S6 = torch.stack((*_cross_parts(_cat(parts_p), Ur), *Ur.unbind(1)), dim=1)
        parts_s.append(S6.view(Ur.shape[0], 2, 3, B))
    if U is not None and U.shape[0] > plan.n_rot:  # translation columns: (u; 0)
        Ut = U[plan.n_rot :]
        parts_s.append(torch.stack((Ut, torch.zeros_like(Ut)), dim=1))
    S = _cat(parts_s) if parts_s else q2.new_zeros(0, 2, 3, B)
    return _Geometry(S, p, RT, origins, floats)


def _batch_last(x: Tensor, batch: tuple[int, ...], trailing: int) -> Tensor:
    """``x (*b, *t)`` (``b`` broadcasting to ``batch``, ``trailing`` dims ``t``) as
    ``(*t, B)`` or ``(*t, 1)`` when ``x`` has no batch dimensions."""
    if x.dim() == trailing:
        return x.unsqueeze(-1)
    t = tuple(x.shape[x.dim() - trailing :])
    x = x.broadcast_to(batch + t).reshape((math.prod(batch),) + t)
    return x.permute(*range(1, trailing + 1), 0)


def _body_inertia(geo: _Geometry, ins: Inertials, batch: tuple[int, ...]):
    """Per body: mass ``(nb, 1, B|1)``, world centre of mass ``(nb, 3, B)`` and the rotational
    inertia about it in the body frame ``(nb, 3, 3, B|1)``."""
    m = _batch_last(ins.mass, batch, 1).unsqueeze(1)
    c = _batch_last(ins.com, batch, 2)
    Ic = _batch_last(ins.inertia, batch, 3)
    nb = c.shape[0]
    return m, geo.p + _const_times(c.unsqueeze(1), geo.RT).view(nb, 3, geo.RT.shape[-1]), Ic


def _forces(
    m: Tensor,
    cw: Tensor,
    Ic: Tensor,
    RT: Tensor,
    al: Tensor,
    aa: Tensor | None,
    vl: Tensor | None,
    va: Tensor | None,
) -> Tensor:
    """Per body the force ``I a + v x* I v`` about its subtree's reference point
    ``(nb, 2, 3, B)`` for accelerations ``(al; aa)`` and velocities ``(vl; va)``
    ``(nb, 3, B)`` (None: 0), in the form ``fl = m (al + aa x c + va x vc)``,
    ``fa = c x fl + Iw aa + va x Iw va`` (``vc`` the centre of mass's velocity,
    ``Iw = R Ic R^T``; the bias terms ``v x* (m vc; c x m vc + Iw va)`` folded in by the Jacobi
    identity)."""

    def Iw(x: Tensor) -> Tensor:
        return _rot(RT, _const_mat(Ic, _rot_t(RT, x)))

    terms = [] if aa is None else [(aa, cw)]
    if va is not None and vl is not None:
        terms.append((va, torch.stack(_cross_sum(vl, (va, cw)), dim=-2)))
    fl = m * (torch.stack(_cross_sum(al, *terms), dim=-2) if terms else al)
    terms = [(cw, fl)] if va is None else [(cw, fl), (va, Iw(va))]
    fa = _cross_sum(None if aa is None else Iw(aa), *terms)
    return _stack6(fl.unbind(-2), fa)


def _const_mat(M: Tensor, x: Tensor) -> Tensor:
    """``M x`` for ``M (n, 3, 3, B|1)`` and ``x (..., n, 3, B)``: one batched matrix product
    where ``M`` has no batch."""
    if M.shape[-1] == 1:
        return torch.matmul(M.squeeze(-1), x)
    return _mat(M, x)


def _gather_cols(x: Tensor, plan: _DynPlan) -> Tensor:
    """Per column, ``x[:, col_dof] * col_w``, as ``(K, 1, B)`` from ``x (B, n_dof)``."""
    return (x.mT.index_select(0, plan.col_dof) * plan.col_w).unsqueeze(1)


def _float_bias(geo: _Geometry, qd2: Tensor, plan: _DynPlan) -> Tensor | None:
    """The acceleration terms ``(p x u; u)``, ``u = R_parent O_R (dJl/dt) rd``, of the floating
    joints' rotation columns (their axes turn with the rotation vector), ``(n_float, 2, 3,
    B)``."""
    if not plan.floats:
        return None
    lin, ang = [], []
    for (RO, r, p), (_, _, d0, _) in zip(geo.floats, plan.floats, strict=True):
        rd = qd2[:, d0 : d0 + 3]
        t2 = (r * r).sum(-1, keepdim=True)
        rdot = (r * rd).sum(-1, keepdim=True)
        b = _coeffs.sinc3(t2)
        a_dot = (2.0 * _coeffs.cosc4(t2) - b) * rdot  # d/dt of cosc(|r|^2)
        b_dot = -2.0 * _coeffs.q3(t2) * rdot  # d/dt of sinc3(|r|^2)
        rxrd = torch.linalg.cross(r, rd, dim=-1)
        u = (
            a_dot * rxrd
            + b_dot * torch.linalg.cross(r, rxrd, dim=-1)
            + b * torch.linalg.cross(rd, rxrd, dim=-1)
        )
        uw = (RO * u.mT.unsqueeze(0)).sum(1)  # (3, B)
        lin.append(_components.cross(p, uw, dim=-2))
        ang.append(uw)
    return torch.stack((torch.stack(lin), torch.stack(ang)), dim=1)


def _mm(M: Tensor, x: Tensor) -> Tensor:
    """``M (r, n)`` times ``x (n, 3, B)`` over the first dimension: ``(r, 3, B)``."""
    return torch.mm(M, x.reshape(x.shape[0], math.prod(x.shape[1:]))).view(M.shape[0], *x.shape[1:])


def _body_motion(
    plan: _DynPlan, geo: _Geometry, qd2: Tensor | None, qdd2: Tensor | None, g: Tensor
) -> tuple[Tensor, Tensor | None, Tensor | None, Tensor | None]:
    """Body accelerations (gravity as an acceleration ``-g`` of the base) and velocities,
    ``(al, aa, vl, va)`` ``(nb, 3, B)`` (None: 0); the column terms die here."""
    S = geo.S
    B = S.shape[-1]
    nb = len(plan.bodies)
    acc = vl = va = None
    if qd2 is not None:
        V = S * _gather_cols(qd2, plan).unsqueeze(1)  # (K, 2, 3, B)
        Vl, Va = V.unbind(1)
        v = _mm(plan.A, V)
        vl, va = v.unbind(1)
        # Each column's axis moves with its frame body: its rate of change is that body's
        # velocity cross the column (where every column's frame is its own body, in order,
        # those are the body velocities).
        fl_, fa_ = (v if plan.frames_are_own else _mm(plan.Af, V)).unbind(1)
        acc = _stack6(_cross_sum(None, (fa_, Vl), (fl_, Va)), _cross_parts(fa_, Va))
        fb = _float_bias(geo, qd2, plan)
        if fb is not None:
            acc = acc + _layout.add_rows(fb, plan.float_gathers)
    if qdd2 is not None:
        qddc = _gather_cols(qdd2, plan).unsqueeze(1)
        acc = S * qddc if acc is None else fma(acc, S, qddc)
    if acc is None:
        return (-g).expand(nb, 3, B), None, vl, va
    a = _mm(plan.A, acc)
    return a[:, 0] - g, a[:, 1], vl, va


def _rnea(
    plan: _DynPlan,
    geo: _Geometry,
    ins: Inertials,
    batch: tuple[int, ...],
    qd2: Tensor | None,
    qdd2: Tensor | None,
    g: Tensor,
    fext: Tensor | None,
) -> Tensor:
    """Generalised forces ``(n_dof, B)``; ``qd2``/``qdd2`` ``(B, n_dof)`` or None for zero,
    ``g (3, B|1)`` gravity, ``fext`` world-origin wrenches per body ``(nb, 2, 3, B)``; the
    armature's ``armature * qdd`` added.  Spatial vectors are ``(..., 2, 3, B)`` (linear;
    angular)."""
    S = geo.S
    B = S.shape[-1]
    nb = len(plan.bodies)
    m, cw, Ic = _body_inertia(geo, ins, batch)
    f = _forces(m, cw, Ic, geo.RT, *_body_motion(plan, geo, qd2, qdd2, g)).expand(nb, 2, 3, B)
    if fext is not None:
        f = f - fext
    tau_c = (S * _mm(plan.At, f)).sum((1, 2))  # (K, B)
    tau = tau_c if plan.W_is_identity else torch.mm(plan.W, tau_c)
    arm = _armature(ins, batch)
    return tau if arm is None or qdd2 is None else fma(tau, arm, qdd2.mT)


def _armature(ins: Inertials, batch: tuple[int, ...]) -> Tensor | None:
    """The armature ``(n_v, B|1)``; None: nothing to add (the chain's own, all 0)."""
    return None if ins.armature is None else _batch_last(ins.armature, batch, 1)


def _acc(x: Tensor, t1: Tensor, t2: Tensor) -> Tensor:
    """``x + t1 * t2``, accumulated in place into ``x`` (a fresh result of the caller's
    formula, which no other operation saved) in eager mode: autograd records the in-place
    operation, and large batches need no new buffer per term.  Out of place under the
    ``torch.func`` transforms (which have no batching rule for it) and while compiling."""
    if torch.compiler.is_compiling() or transforms_active():
        return fma(x, t1, t2)
    return x.addcmul_(t1, t2)


def _const_times(M: Tensor, X: Tensor) -> Tensor:
    """``M X`` for ``M (n, r, c, B|1)`` and ``X (n, c, ..., B)`` (contraction over dim 1):
    one batched matrix product where ``M`` has no batch, else multiply-adds."""
    n, r = M.shape[:2]
    if M.shape[-1] == 1:
        rest = math.prod(X.shape[2:])
        return torch.bmm(M.squeeze(-1), X.reshape(n, X.shape[1], rest)).view(n, r, *X.shape[2:])
    tail = (1,) * (X.dim() - 3)
    cols = M.unbind(2)  # (n, r, B) each
    rows = X.unbind(1)  # (n, ..., B) each
    b = M.shape[-1]
    out = cols[0].reshape(n, r, *tail, b) * rows[0].unsqueeze(1)
    for m, x in zip(cols[1:], rows[1:], strict=True):
        out = fma(out, m.reshape(n, r, *tail, b), x.unsqueeze(1))
    return out


def _composite(plan: _DynPlan, geo: _Geometry, m: Tensor, cw: Tensor, Ic: Tensor):
    """Composite inertias per column (of the column's body subtree) about their reference point:
    mass ``(K, 1, B|1)``, first moment ``h = m c`` ``(K, 3, B)`` and second moment
    ``J = sum m r r^T`` ``(K, 3, 3, B)`` (the rotational inertia is ``tr(J) 1 - J``).

    Per body ``J = R Jc R^T + m c c^T`` with ``Jc = tr(Ic) / 2 1 - Ic`` about the centre of
    mass; the sums over subtrees are one product with the subtree matrix (its rows taken per
    column)."""
    nb, K, B = cw.shape[0], geo.S.shape[0], cw.shape[-1]
    eye = torch.eye(3, dtype=cw.dtype, device=cw.device).unsqueeze(-1)
    tr = (Ic[:, 0, 0] + Ic[:, 1, 1] + Ic[:, 2, 2]).view(nb, 1, 1, Ic.shape[-1])
    Jc = fma(-Ic, tr, eye, 0.5)  # (nb, 3, 3, B|1)
    h = m * cw
    J = _second_moment(Jc, geo.RT, h, cw)
    mc = _mm(plan.sub_cols, m)
    hc = _mm(plan.sub_cols, h)
    return mc, hc, _mm(plan.sub_cols, J.view(nb, 9, B)).view(K, 3, 3, B)


def _second_moment(Jc: Tensor, RT: Tensor, h: Tensor, cw: Tensor) -> Tensor:
    """``R Jc R^T + h c^T`` ``(nb, 3, 3, B)`` (its temporaries die here)."""
    Y = _const_times(Jc, RT)  # Jc R^T: (nb, a, r, B)
    Rt, Yt = RT.unbind(1), Y.unbind(1)
    J = h.unsqueeze(2) * cw.unsqueeze(1)
    for i in range(3):
        J = _acc(J, Rt[i].unsqueeze(2), Yt[i].unsqueeze(1))
    return J


def _column_forces(plan: _DynPlan, geo: _Geometry, ins: Inertials, batch: tuple[int, ...]):
    """``F_k = Ic S_k`` ``(K, 2, 3, B)``, the composite inertia of column ``k``'s subtree
    applied to the column (the composite inertias die here)."""
    Sl, Sa = geo.Sl, geo.Sa
    mc, hc, Jk = _composite(plan, geo, *_body_inertia(geo, ins, batch))
    trJ = (Jk[:, 0, 0] + Jk[:, 1, 1] + Jk[:, 2, 2]).unsqueeze(1)  # (K, 1, B)
    return _stack6(_cross_sum(mc * Sl, (Sa, hc)), _cross_sum(trJ * Sa - _mat(Jk, Sa), (hc, Sl)))


def _columns_and_forces(
    plan: _DynPlan, geo: _Geometry, ins: Inertials, batch: tuple[int, ...]
) -> tuple[Tensor, Tensor, Tensor | None]:
    """``(S, F, armature)`` for :func:`_crba` (the rest of the geometry dies here)."""
    return geo.S, _column_forces(plan, geo, ins, batch), _armature(ins, batch)


def _crba(plan: _DynPlan, S: Tensor, F: Tensor, armature: Tensor | None) -> Tensor:
    """Mass matrix ``(B, n_dof, n_dof)`` from the joint columns ``S`` and their forces ``F``
    (:func:`_column_forces`), the ``armature`` ``(n_dof, B|1)`` (None: 0) added to its
    diagonal."""
    K, _, _, B = S.shape
    # Q[k, l] = S_k . Ic_l S_l, summed component by component over (K, K, B).
    S6, F6 = S.view(K, 6, B), F.view(K, 6, B)
    Q = S6[:, None, 0] * F6[None, :, 0]
    for i in range(1, 6):
        Q = _acc(Q, S6[:, None, i], F6[None, :, i])
    Qz = Q.view(K * K, B)
    if plan.m_zero:  # entries between branches read a row of zeros
        Qz = torch.cat((Qz, Qz.new_zeros(1, B)))
    # M[k, l] = Q[k, l] where column k's body is an ancestor of column l's, Q[l, k] where it is
    # the other way round, 0 between branches: one gather of whole rows (batch last), then one
    # transposing copy into the (B, K, K) layout (a gather reading B apart is several times
    # slower on large batches).
    Mc = Qz.index_select(0, plan.m_gather).mT.contiguous().view(B, K, K)
    M = Mc if plan.W_is_identity else plan.W @ Mc @ plan.W.T
    return M if armature is None else M + torch.diag_embed(armature.mT)


# ----------------------------------------------------------------------------------------------
# Argument handling of the Chain methods
# ----------------------------------------------------------------------------------------------


def _check_inertials(
    chain, inertials: Inertials | None, fn: str, batch: tuple[int, ...]
) -> Inertials:
    """The inertials to use, checked; an ``armature`` None (not given) is the chain's own, and
    stays None where that is all 0 (nothing to add)."""
    plan = _plan(chain)
    own = plan.inertials[3] if plan.has_armature else None
    if inertials is None:
        return Inertials(*plan.inertials[:3], own)
    if not isinstance(inertials, tuple) or len(inertials) not in (3, 4):
        raise TypeError(
            f"{_NAME}{fn}: expected inertials to be an Inertials (mass, com, inertia, "
            f"armature), got {type(inertials).__name__}"
        )
    nb = len(plan.bodies)
    given = (*inertials, None)[:4]
    out = []
    for name, x, trailing in zip(
        ("mass", "com", "inertia", "armature"),
        given,
        ((nb,), (nb, 3), (nb, 3, 3), (chain.n_v,)),
        strict=True,
    ):
        if name == "armature" and x is None:
            out.append(own)
            continue
        t, _ = _checks.tensor(x, _NAME + fn, f"inertials.{name}", trailing)
        chain._check_like(t, _NAME + fn, f"inertials.{name}", x.dtype)
        if name == "inertia":  # the recursions read both triangles, the factorization one
            t = _components.symmetric_part(t)
        lead = tuple(t.shape[: t.dim() - len(trailing)])
        try:
            ok = torch.broadcast_shapes(lead, batch) == batch
        except RuntimeError:
            ok = False
        if not ok:
            raise ValueError(
                f"{_NAME}{fn}: inertials.{name} has batch shape {lead}, which does not "
                f"broadcast to q's batch shape {batch}"
            )
        out.append(t)
    return Inertials(*out)


def _check_vec(chain, x: Tensor, fn: str, name: str, batch: tuple[int, ...]) -> Tensor:
    """``x (..., n_v)`` (velocities, accelerations, forces) as ``(B, n_v)``."""
    t, _ = _checks.tensor(x, _NAME + fn, name, (chain.n_v,))
    chain._check_like(t, _NAME + fn, name, x.dtype)
    try:
        t = t.broadcast_to(batch + (chain.n_v,))
    except RuntimeError:
        raise ValueError(
            f"{_NAME}{fn}: {name} of shape {tuple(x.shape)} does not broadcast to q's batch "
            f"shape {batch}"
        ) from None
    return t.reshape(math.prod(batch), chain.n_v)


def _gravity(chain, gravity, fn: str, batch: tuple[int, ...], like: Tensor) -> Tensor:
    if gravity is None:
        return _plan(chain).gravity
    if not isinstance(gravity, Tensor):
        try:  # numbers (never bool), in the chain's dtype
            gravity = _checks.real(gravity, _NAME + fn, "gravity", like, ("q", like))
        except TypeError:
            raise TypeError(
                f"{_NAME}{fn}: expected gravity to be a (3,) or (..., 3) tensor or a sequence "
                f"of 3 numbers, got {type(gravity).__name__} {gravity!r:.60}"
            ) from None
    g, _ = _checks.tensor(gravity, _NAME + fn, "gravity", (3,))
    chain._check_like(g, _NAME + fn, "gravity", gravity.dtype)
    try:
        return _batch_last(g, batch, 1)
    except RuntimeError:
        raise ValueError(
            f"{_NAME}{fn}: gravity of shape {tuple(gravity.shape)} does not broadcast to q's "
            f"batch shape {batch}"
        ) from None


def _fext_links(chain, f_ext: Mapping[str, Tensor] | None, fn: str) -> tuple[int, ...]:
    if f_ext is None:
        return ()
    if not isinstance(f_ext, Mapping):
        raise TypeError(
            f"{_NAME}{fn}: expected f_ext to be a dict link name -> (..., 6) wrench, got "
            f"{type(f_ext).__name__}"
        )
    for k in f_ext:
        if k not in chain._index:
            raise ValueError(
                f"{_NAME}{fn}: f_ext names unknown link {k!r} (the links are "
                f"{_some(chain.link_names)})"
            )
    return tuple(chain._index[k] for k in f_ext)


def _fext(
    chain,
    plan: _DynPlan,
    geo: _Geometry,
    f_ext: Mapping[str, Tensor],
    fn: str,
    batch: tuple[int, ...],
) -> Tensor | None:
    """The wrenches of ``f_ext`` summed per body, about their reference point, ``(nb, 2, 3, B)``
    (forces; torques)."""
    nb = len(plan.bodies)
    B = geo.S.shape[-1]
    parts: list[Tensor] = []
    idx: list[int] = []
    for k, (name, w) in enumerate(f_ext.items()):
        t, _ = _checks.tensor(w, _NAME + fn, f"f_ext[{name!r}]", (6,))
        chain._check_like(t, _NAME + fn, f"f_ext[{name!r}]", w.dtype)
        try:
            wb = _batch_last(t, batch, 1).expand(6, B)
        except RuntimeError:
            raise ValueError(
                f"{_NAME}{fn}: f_ext[{name!r}] of shape {tuple(w.shape)} does not broadcast "
                f"to q's batch shape {batch}"
            ) from None
        b = plan.body_of[chain._index[name]]
        if b < 0:
            continue  # a link fixed to the world: the wrench acts on the world
        p = geo.origins[k]  # the link's origin, (3, B)
        f, n = wb[:3], wb[3:]
        parts.append(torch.cat((f, n + torch.linalg.cross(p, f, dim=0)), dim=0))
        idx.append(b)
    if not parts:
        return None
    out = _layout.add_rows(torch.stack(parts), _layout.row_gathers(idx, nb, parts[0].device))
    return out.view(nb, 2, 3, B)


def _prepare(chain, q: Tensor, fn: str):
    q2, out_dtype, batch = chain._prepare(q, fn)
    return q2, out_dtype, batch, _plan(chain)


def _over_blocks(
    fn, plan: _DynPlan, inputs: list[Tensor | None], others: tuple[Tensor | None, ...], whole: bool
):
    """``fn(*inputs)`` for batch-first ``inputs`` (None: absent), through the shared driver
    :func:`~torchlie._autograd.evaluate` over blocks of the batch (their width: the number of
    joint columns) when nothing else (``others``: gravity, inertials) has a batch or may
    record a graph and ``whole`` (external wrenches) does not ask for the whole batch;
    ``others``' armature may be None."""
    given = [x for x in inputs if x is not None]

    def call(*xs: Tensor):
        it = iter(xs)
        return fn(*(None if x is None else next(it) for x in inputs))

    g, *ins = others
    batched = g.shape[-1] != 1 or any(
        t is not None and t.dim() > d for t, d in zip(ins, (1, 2, 3, 1), strict=True)
    )
    if whole or batched or needs_graph([t for t in others if t is not None]):
        return call(*given)
    return evaluate(call, given, [1] * len(given), width=plan.col_dof.shape[0])


def _inverse_dynamics(
    chain,
    q: Float[Tensor, "*b n_dof"],
    qd: Float[Tensor, "*b n_dof"],
    qdd: Float[Tensor, "*b n_dof"],
    *,
    gravity: Tensor | None = None,
    f_ext: Mapping[str, Tensor] | None = None,
    inertials: Inertials | None = None,
    _fn: str = "inverse_dynamics",
) -> Float[Tensor, "*b n_dof"]:
    """Joint forces for the motion ``(q, qd, qdd)``: see :meth:`Chain.inverse_dynamics`."""
    q2, out_dtype, batch, plan = _prepare(chain, q, _fn)
    qd2 = None if qd is None else _check_vec(chain, qd, _fn, "qd", batch)
    qdd2 = None if qdd is None else _check_vec(chain, qdd, _fn, "qdd", batch)
    ins = _check_inertials(chain, inertials, _fn, batch)
    g = _gravity(chain, gravity, _fn, batch, q2)
    extra = _fext_links(chain, f_ext, _fn)
    if not plan.bodies:  # no degree of freedom
        return _checks.out(q2.new_zeros(*batch, 0), out_dtype)

    def run(q2: Tensor, qd2: Tensor | None, qdd2: Tensor | None) -> Tensor:
        geo = _geometry(chain, plan, q2, extra)
        fx = None if f_ext is None else _fext(chain, plan, geo, f_ext, _fn, batch)
        return _rnea(plan, geo, ins, batch, qd2, qdd2, g, fx).mT

    tau = _over_blocks(run, plan, [q2, qd2, qdd2], (g, *ins), f_ext is not None)
    return _checks.out(tau.reshape(*batch, chain.n_v), out_dtype)


def _mass_matrix(
    chain, q: Float[Tensor, "*b n_dof"], *, inertials: Inertials | None = None
) -> Float[Tensor, "*b n_dof n_dof"]:
    """Joint-space mass matrix: see :meth:`Chain.mass_matrix`."""
    fn = "mass_matrix"
    q2, out_dtype, batch, plan = _prepare(chain, q, fn)
    ins = _check_inertials(chain, inertials, fn, batch)
    if not plan.bodies:  # no degree of freedom
        return _checks.out(q2.new_zeros(*batch, chain.n_v, chain.n_v), out_dtype)

    def run(q2: Tensor) -> Tensor:
        return _crba(plan, *_columns_and_forces(plan, _geometry(chain, plan, q2, ()), ins, batch))

    M = _over_blocks(run, plan, [q2], (plan.gravity, *ins), False)
    return _checks.out(M.reshape(*batch, chain.n_v, chain.n_v), out_dtype)


def _forward_dynamics(
    chain,
    q: Float[Tensor, "*b n_dof"],
    qd: Float[Tensor, "*b n_dof"],
    tau: Float[Tensor, "*b n_dof"],
    *,
    gravity: Tensor | None = None,
    f_ext: Mapping[str, Tensor] | None = None,
    inertials: Inertials | None = None,
) -> Float[Tensor, "*b n_dof"]:
    """Joint accelerations: see :meth:`Chain.forward_dynamics`."""
    fn = "forward_dynamics"
    q2, out_dtype, batch, plan = _prepare(chain, q, fn)
    if inertials is None and plan.massless:
        raise ValueError(
            f"{_NAME}{fn}: the mass matrix is singular: nothing resisting their motion moves "
            f"with {_some(plan.massless)} (neither mass nor inertia nor armature; no mass for a "
            "translation; an end link's mass on its joint's axis, with no inertia about it, "
            "or a negative one: links without <inertial>, a chain from SDF, whose inertials "
            "are not read, or a non-physical <inertia>?); give those links inertials or pass "
            "inertials="
        )
    qd2 = _check_vec(chain, qd, fn, "qd", batch)
    tau2 = _check_vec(chain, tau, fn, "tau", batch)
    ins = _check_inertials(chain, inertials, fn, batch)
    g = _gravity(chain, gravity, fn, batch, q2)
    extra = _fext_links(chain, f_ext, fn)
    if not plan.bodies:  # no degree of freedom
        return _checks.out(q2.new_zeros(*batch, 0), out_dtype)

    def run(q2: Tensor, qd2: Tensor, tau2: Tensor) -> Tensor:
        geo = _geometry(chain, plan, q2, extra)
        fx = None if f_ext is None else _fext(chain, plan, geo, f_ext, fn, batch)
        h = _rnea(plan, geo, ins, batch, qd2, None, g, fx)  # (n, B)
        M = _crba(plan, *_columns_and_forces(plan, geo, ins, batch))  # (B, n, n)
        L, info = torch.linalg.cholesky_ex(M)
        qdd = torch.cholesky_solve((tau2 - h.mT).unsqueeze(-1), L).squeeze(-1)  # (B, n)
        # a state whose M is not positive definite: NaN, not what the failed factor gives
        return torch.where((info > 0).unsqueeze(-1), torch.nan, qdd)

    qdd = _over_blocks(run, plan, [q2, qd2, tau2], (g, *ins), f_ext is not None)
    return _checks.out(qdd.reshape(*batch, chain.n_v), out_dtype)
