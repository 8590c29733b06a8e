"""SE(3): homogeneous poses ``(..., 4, 4)`` and twists ``(..., 6)``.

Conventions (see :mod:`torchlie`): a pose is ``T = [[R, t], [0, 1]]`` and acts on points as
``p -> R p + t``; a twist is ``xi = (rho, phi)``, translation part first, rotation vector last;
perturbations are on the right, ``T (+) d = T Exp(d)``.  Everything is built from
:mod:`torchlie.so3`: ``Exp(rho, phi) = [[Exp(phi), V(phi) rho], [0, 1]]`` with
``V = so3.jac_left``, so :func:`log` returns a rotation angle in ``[0, pi]`` with so3's rule at pi.

Jacobians (``Jl(xi)`` = :func:`jac_left`, ``Jr(xi) = Jl(-xi)`` = :func:`jac_right`)::

    Exp(xi + d) ~= Exp(xi) Exp(Jr(xi) d) ~= Exp(Jl(xi) d) Exp(xi)
    Jl(rho, phi) = [[A, Q], [0, A]],   A = so3.jac_left(phi)
    Jl(rho, phi)^-1 = [[A^-1, -A^-1 Q A^-1], [0, A^-1]]
    Q = rho^/2 + c1 (phi^ rho^ + rho^ phi^ + phi^ rho^ phi^)
               + c2 (phi^ phi^ rho^ + rho^ phi^ phi^ - 3 phi^ rho^ phi^)
               + c3 (phi^ rho^ phi^ phi^ + phi^ phi^ rho^ phi^)
    c1 = (t - sin t)/t^3,  c2 = (t^2/2 + cos t - 1)/t^4,  c3 = (2t - 3 sin t + t cos t)/(2 t^5)

(``x^`` is :func:`torchlie.so3.hat` and ``t = |phi|``; ``Q`` is Barfoot's, "State Estimation for
Robotics", eq. 7.86).  The adjoint acting on twists ``(rho, phi)`` is
``Ad_T = [[R, t^ R], [0, R]]`` and the small adjoint ``ad(rho, phi) = [[phi^, rho^], [0, phi^]]``.

Jacobians of operations follow Sola et al., "A micro Lie theory for state estimation in
robotics" (and manif): for ``Y = f(X)`` the Jacobian ``J_Y_X`` maps a right perturbation of the
input to a right perturbation of the output, ``f(X Exp(d)) ~= f(X) Exp(J_Y_X d)``; a vector
argument or result (a point, a twist) is perturbed by plain addition.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from . import _checks, _coeffs, _components, _layout, _rodrigues, _rotation_matrix, so3
from ._autograd import blocked, custom_function, fma
from ._typing import Bool, Float

__all__ = [
    "hat",
    "vee",
    "exp",
    "log",
    "compose",
    "inverse",
    "act",
    "adjoint",
    "ad",
    "jac_left",
    "jac_right",
    "jac_left_inv",
    "jac_right_inv",
    "identity",
    "random",
    "is_valid",
    "from_rt",
    "to_rt",
    "from_pos_quat",
    "to_pos_quat",
    "interpolate",
    "distance",
    "rplus",
    "rminus",
    "lplus",
    "lminus",
    "between",
    "jac_compose",
    "jac_inverse",
    "jac_act",
    "jac_rplus",
    "jac_rminus",
    "jac_between",
]

_NAME = "torchlie.se3."


# ----------------------------------------------------------------------------------------------
# Component helpers (private)
# ----------------------------------------------------------------------------------------------


def _rot(T: Tensor) -> Tensor:
    return T[..., :3, :3]


def _trans(T: Tensor) -> Tensor:
    return T[..., :3, 3]


_mv = _components.mv


def _assemble(R: Tensor, t: Tensor) -> Tensor:
    """``[[R, t], [0, 1]]`` (``R`` and ``t`` share their batch shape)."""
    top = torch.cat((R, t.unsqueeze(-1)), dim=-1)
    bottom = torch.cat((torch.zeros_like(t), torch.ones_like(t[..., :1])), dim=-1)
    return torch.cat((top, bottom.unsqueeze(-2)), dim=-2)


def _broadcast_rt(R: Tensor, t: Tensor) -> tuple[Tensor, Tensor]:
    batch = _layout.broadcast(R.shape[:-2], t.shape[:-1])
    return R.expand(*batch, 3, 3), t.expand(*batch, 3)


def _blocks(A: Tensor, B: Tensor, C: Tensor, D: Tensor) -> Tensor:
    """The 6x6 matrix ``[[A, B], [C, D]]`` from four 3x3 blocks of one batch shape."""
    return torch.cat((torch.cat((A, B), dim=-1), torch.cat((C, D), dim=-1)), dim=-2)


def _hat(xi: Tensor) -> Tensor:
    rho, phi = xi[..., :3], xi[..., 3:]
    top = torch.cat((_components.hat(phi), rho.unsqueeze(-1)), dim=-1)
    return torch.cat((top, torch.zeros_like(top[..., :1, :])), dim=-2)


def _q_coeffs(phi: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """``(k1, k2, k3, k4)`` of :func:`_q_components` for ``phi`` itself
    (:func:`torchlie._coeffs.q_series`), in ``phi``'s dtype."""
    return _in_dtype(_coeffs.q_series(_coeffs.theta2(phi)), phi.dtype)


def _in_dtype(ks: tuple[Tensor, ...], dtype: torch.dtype) -> tuple[Tensor, ...]:
    return tuple(k.to(dtype) for k in ks)


def _q_values(
    dtype: torch.dtype, half: tuple[Tensor, ...], bc: tuple[Tensor, Tensor] | None = None
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """:func:`_q_coeffs` of ``phi`` for input of ``dtype``, forward-only (the plain backward
    passes), from its :func:`_coeffs.half_angle`: for float32, :func:`_coeffs.q_values` from
    Rodrigues' ``b`` and ``c`` (``bc``, or evaluated from ``half``; no trigonometric function
    of its own), :func:`_coeffs.q_series` otherwise; in ``dtype``."""
    if bc is None and dtype == torch.float32:
        bc = _coeffs.rodrigues_values(None, "bc", half)
    return _in_dtype(_coeffs.q_plain(dtype, half[0], *(bc or (None, None))), dtype)


def _q_components(
    rho: Sequence[Tensor],
    x: Sequence[Tensor],
    v: Sequence[Tensor],
    k1: Tensor,
    k2: Tensor,
    k3: Tensor,
    k4: Tensor,
) -> list[Tensor]:
    """Components of ``Q(rho, phi) v`` (the top-right block of the left Jacobian), from
    components, with cross products only::

        Q v = rho^ v / 2 + k1 (x^ rho^ + rho^ x^) v + k2 x^ rho^ x^ v
              + k3 (x^ x^ rho^ + rho^ x^ x^) v + k4 (x^ rho^ x^ x^ + x^ x^ rho^ x^) v

    with ``x = phi`` and the coefficients of :func:`_q_coeffs`, or ``x`` the unit axis and
    those of :func:`torchlie._coeffs.q_far`.  With ``a = x^ v``, ``b = x^ a`` and
    ``r(y) = rho^ y``, the terms group as ``r(v)/2 + k1 r(a) + k3 r(b) + x^ (k1 r(v) + k2 r(a)
    + k4 r(b) + x^ (k3 r(v) + k4 r(a)))``.
    """
    a = _components.cross_planes(x, v)
    b = _components.cross_planes(x, a)
    rv, ra, rb = (
        _components.cross_planes(rho, v),
        _components.cross_planes(rho, a),
        _components.cross_planes(rho, b),
    )
    inner = _components.cross_planes(x, [fma(k3 * p, k4, q) for p, q in zip(rv, ra, strict=True)])
    mid = [
        fma(fma(fma(i, k1, p), k2, q), k4, r) for p, q, r, i in zip(rv, ra, rb, inner, strict=True)
    ]
    outer = _components.cross_planes(x, mid)
    return [
        fma(fma(o.add(p, alpha=0.5), k1, q), k3, r)
        for p, q, r, o in zip(rv, ra, rb, outer, strict=True)
    ]


def _q_apply(
    rho: Tensor, phi: Tensor, v: Tensor, form: tuple[Tensor, tuple[Tensor, ...]] | None = None
) -> Tensor:
    """``Q(rho, phi) v`` (batch shapes broadcast): :func:`_q_components` on planar copies, with
    ``phi`` and its :func:`_q_coeffs`, or ``form = (x, (k1, k2, k3, k4))``."""
    P = _components.planes
    x, ks = (phi, _q_coeffs(phi)) if form is None else form
    return _layout.interleave(_q_components(P(rho, 3), P(x, 3), P(v, 3), *ks))


def _q_matrix(rho: Tensor, phi: Tensor) -> Tensor:
    """``Q(rho, phi)`` as a matrix at every angle (:func:`_q_form`): :func:`_q_apply` on the
    three unit vectors."""
    eye = torch.eye(3, dtype=rho.dtype, device=rho.device).expand(*rho.shape[:-1], 3, 3)
    cols = _q_apply(rho.unsqueeze(-2), phi, eye, _q_form(phi.unsqueeze(-2)))  # row j = Q e_j
    return cols.transpose(-1, -2)


def _q_form(phi: Tensor) -> tuple[Tensor, tuple[Tensor, Tensor, Tensor, Tensor]]:
    """``(x, (k1, k2, k3, k4))`` of :func:`_q_components` for ``Q(., phi)`` at every magnitude
    of ``phi``: ``phi`` and :func:`_q_coeffs` up to ``|phi|^2 = Q_FAR_T2``, the unit axis and
    :func:`torchlie._coeffs.q_far` above it (no powers of the angle, which overflow in the
    derivatives), with the angle reduced modulo ``2 pi`` for ``sin`` and ``cos`` beyond the
    range of the formulas (:func:`torchlie._coeffs.reduction`, as so3's Jacobians).  Double
    where: each form sees only its own elements.  Derivatives are those of ``Q`` at the angle
    (``d t / d phi = u``, as the reduced angle's).
    """
    r, lam, u = _coeffs.reduction(phi)
    t2 = _coeffs.theta2(r)  # the reduced angle's (|phi|^2 where not reduced)
    reduced = lam[..., 0] < 1.0
    far = (t2 > _coeffs.Q_FAR_T2) | reduced
    ang = torch.where(far, t2, 1.0).sqrt()
    t = torch.where(reduced, _coeffs.dot(u.to(t2.dtype), phi.to(t2.dtype)), ang)
    axis = torch.where(reduced.unsqueeze(-1), u, phi / t.to(phi.dtype).unsqueeze(-1))
    far_ks = _coeffs.q_far(t, torch.sin(ang), torch.cos(ang))
    near_ks = _coeffs.q_series(torch.where(far, 0.0, t2))
    ks = tuple(torch.where(far, a, b) for a, b in zip(far_ks, near_ks, strict=True))
    return torch.where(far.unsqueeze(-1), axis, phi), _in_dtype(ks, phi.dtype)


def _jac_left(xi: Tensor) -> Tensor:
    rho, phi = xi[..., :3], xi[..., 3:]
    A = _rodrigues.jac_matrix(phi, "left")
    return _blocks(A, _q_matrix(rho, phi), torch.zeros_like(A), A)


def _jac_left_inv(xi: Tensor) -> Tensor:
    rho, phi = xi[..., :3], xi[..., 3:]
    Ai = _rodrigues.jac_matrix(phi, "left_inv")
    B = -(Ai @ _q_matrix(rho, phi) @ Ai)
    return _blocks(Ai, B, torch.zeros_like(Ai), Ai)


def _jl_inv_apply(xi: Tensor, v: Tensor) -> Tensor:
    """``Jl(xi)^-1 v`` without a matrix."""
    rho, phi = xi[..., :3], xi[..., 3:]
    u_phi = _rodrigues.jl_inv_apply(phi, v[..., 3:])
    u_rho = _rodrigues.jl_inv_apply(phi, v[..., :3] - _q_apply(rho, phi, u_phi))
    return torch.cat((u_rho, u_phi), dim=-1)


def _adjoint(T: Tensor) -> Tensor:
    R, t = _rot(T), _trans(T)
    return _blocks(R, _components.hat(t) @ R, torch.zeros_like(R), R)


def _ad(xi: Tensor) -> Tensor:
    P = _components.hat(xi[..., 3:])
    return _blocks(P, _components.hat(xi[..., :3]), torch.zeros_like(P), P)


def _between(A: Tensor, B: Tensor) -> Tensor:
    """``A^-1 B`` from components."""
    Rt = _rot(A).transpose(-1, -2)
    R = Rt @ _rot(B)
    t = _mv(Rt, _trans(B) - _trans(A))
    return _assemble(R, t.expand(*R.shape[:-2], 3))


# ----------------------------------------------------------------------------------------------
# compose / inverse / act kernels (private)
#
# Each op is one forward entry by entry over the 12 entries of the top block, and a closed-form
# backward in the same style (autograd's own graph of the slices and concatenations costs
# about twice as many passes over memory).
# ----------------------------------------------------------------------------------------------


def _pad_row(top: Tensor) -> Tensor:
    """``(..., 3, 4) -> (..., 4, 4)`` with a zero last row."""
    return torch.nn.functional.pad(top, (0, 0, 0, 1))


def _with_last_row(top: Tensor) -> Tensor:
    """``(..., 3, 4) -> (..., 4, 4)`` with the last row ``(0, 0, 0, 1)``."""
    out = _pad_row(top)
    out.select(-2, 3).select(-1, 3).fill_(1.0)
    return out


def _top_entries(T: Tensor) -> list[list[Tensor]]:
    """The entries of the top 3x4 block of ``T``, row by row (contiguous planes; strided views
    while compiling)."""
    e = _layout.planes(T[..., :3, :], (3, 4))
    return [list(e[4 * i : 4 * i + 4]) for i in range(3)]


def _rotation_and_translation(T: Tensor) -> tuple[list[Tensor], list[Tensor]]:
    """:func:`_top_entries` as the 9 entries of the rotation (row by row) and the 3 of the
    translation."""
    e = _top_entries(T)
    return [x for row in e for x in row[:3]], [row[3] for row in e]


def _top_outputs(
    like: Tensor | Sequence[Tensor],
) -> tuple[tuple[Tensor | None, ...], list[list[Tensor | None]]]:
    """The 16 columns of :func:`_layout.outputs` for a 4x4 result, and the 12 of its top block
    row by row (where the entries are to be written)."""
    o = _layout.outputs(like, 16)
    return o, [list(o[4 * i : 4 * i + 4]) for i in range(3)]


def _stack_top(
    rows: Sequence[Sequence[Tensor]],
    corner: float = 1.0,
    out: Sequence[Tensor | None] | None = None,
) -> Tensor:
    """``[[rows], [0, 0, 0, corner]]``: a 4x4 matrix from the 12 entries of its top block (row by
    row, all of one shape; written to the columns ``out`` of :func:`_top_outputs` or not)."""
    if isinstance(out, _layout.Columns):
        bottom = out.result[..., 12:]
        bottom[..., :3].zero_()
        bottom[..., 3].fill_(corner)
        zero, last = out[12:15], out[15]
    else:
        zero = (torch.zeros_like(rows[0][0]),) * 3
        last = zero[0] if corner == 0.0 else torch.full_like(zero[0], corner)
    entries = (*rows[0], *rows[1], *rows[2], *zero, last)
    return _layout.interleave(entries, out).unflatten(-1, (4, 4))


def _stack_rows(
    rows: Sequence[Sequence[Tensor]], out: Sequence[Tensor | None] | None = None
) -> Tensor:
    """:func:`_stack_top` with a zero last row (a gradient: the bottom row is not read)."""
    return _stack_top(rows, 0.0, out)


def _compose_entries(A: Tensor, B: Tensor) -> Tensor:
    """``A B`` entry by entry."""
    a, b = _top_entries(A), _top_entries(B)
    o, top = _top_outputs((a[0][0], b[0][0]))  # batches may broadcast
    rows = []
    for ai, oi in zip(a, top, strict=True):
        row = [
            fma(fma(ai[0] * b[0][j], ai[1], b[1][j]), ai[2], b[2][j], out=oi[j]) for j in range(3)
        ]
        t = fma(fma(ai[0] * b[0][3], ai[1], b[1][3]), ai[2], b[2][3])
        rows.append([*row, torch.add(t, ai[3], out=oi[3])])
    return _stack_top(rows, out=o)


def _inverse_entries(T: Tensor) -> Tensor:
    """``T^-1 = [[R^T, -R^T t], [0, 1]]`` entry by entry."""
    r = _top_entries(T)
    o, top = _top_outputs(r[0][0])
    rows = []
    for i in range(3):
        col = [r[0][i], r[1][i], r[2][i]]
        t = fma(fma(col[0] * r[0][3], col[1], r[1][3]), col[2], r[2][3])
        rows.append([*col, torch.neg(t, out=top[i][3])])
    return _stack_top(rows, out=o)


def _compose_bwd(saved: tuple[Tensor, ...], G: Tensor) -> tuple[Tensor, Tensor]:
    A, B = saved
    dA, dB = _compose_grads(A, B, G)
    return dA.sum_to_size(A.shape), dB.sum_to_size(B.shape)


def _compose_bwd_entries(A: Tensor, B: Tensor, G: Tensor) -> tuple[Tensor, Tensor]:
    """The backward of ``A B`` entry by entry: ``dA_ij = sum_k G_ik B_jk`` (``j < 3``),
    ``dA_i3 = G_i3``, ``dB_kj = sum_i A_ik G_ij``."""
    a, b, g = _top_entries(A), _top_entries(B), _top_entries(G)
    oa, top_a = _top_outputs(g[0][0])
    ob, top_b = _top_outputs(g[0][0])
    da = [
        [
            fma(
                fma(fma(gi[0] * b[j][0], gi[1], b[j][1]), gi[2], b[j][2]),
                gi[3],
                b[j][3],
                out=oi[j],
            )
            for j in range(3)
        ]
        + [gi[3]]
        for gi, oi in zip(g, top_a, strict=True)
    ]
    db = [
        [
            fma(fma(a[0][k] * g[0][j], a[1][k], g[1][j]), a[2][k], g[2][j], out=ok[j])
            for j in range(4)
        ]
        for k, ok in zip(range(3), top_b, strict=True)
    ]
    return _stack_rows(da, oa), _stack_rows(db, ob)


_compose_grads = blocked(_compose_bwd_entries, (2, 2, 2))


def _compose_jvp(saved: tuple[Tensor, ...], dA: Tensor, dB: Tensor) -> Tensor:
    A, B = saved
    top = torch.matmul(dA[..., :3, :3], B[..., :3, :])
    top = top + torch.matmul(A[..., :3, :3], dB[..., :3, :])
    top.select(-1, 3).add_(dA[..., :3, 3])
    return _pad_row(top)


_ComposeFn = custom_function(
    "Se3Compose",
    forward=_compose_entries,
    save=lambda inputs, out: (inputs[0], inputs[1]),
    backward=_compose_bwd,
    jvp=_compose_jvp,
    event_dims=(2, 2),
)


def _inverse_bwd(saved: tuple[Tensor, ...], G: Tensor) -> tuple[Tensor]:
    (T,) = saved
    return (_inverse_grads(T, G),)


def _inverse_bwd_entries(T: Tensor, G: Tensor) -> Tensor:
    """The backward of ``T^-1`` entry by entry (``out = [R^T, -R^T t]``):
    ``dR_ij = G_ji - t_i G_j3``, ``dt_i = -sum_j R_ij G_j3``."""
    r, g = _top_entries(T), _top_entries(G)
    o, top = _top_outputs(g[0][0])
    rows = []
    for i, oi in zip(range(3), top, strict=True):
        dR = [fma(g[j][i], r[i][3], g[j][3], value=-1.0, out=oi[j]) for j in range(3)]
        dt = fma(fma(r[i][0] * g[0][3], r[i][1], g[1][3]), r[i][2], g[2][3])
        rows.append([*dR, torch.neg(dt, out=oi[3])])
    return _stack_rows(rows, o)


_inverse_grads = blocked(_inverse_bwd_entries, (2, 2))


def _inverse_jvp(saved: tuple[Tensor, ...], dT: Tensor) -> Tensor:
    (T,) = saved
    dRt = dT[..., :3, :3].transpose(-1, -2)
    Rt = T[..., :3, :3].transpose(-1, -2)
    dt = torch.matmul(dRt, T[..., :3, 3:]) + torch.matmul(Rt, dT[..., :3, 3:])
    return _pad_row(torch.cat((dRt, -dt), dim=-1))


_InverseFn = custom_function(
    "Se3Inverse",
    forward=_inverse_entries,
    save=lambda inputs, out: (inputs[0],),
    backward=_inverse_bwd,
    jvp=_inverse_jvp,
    event_dims=(2,),
)


def _homogeneous(p: Tensor) -> Tensor:
    return torch.nn.functional.pad(p, (0, 1), value=1.0)


def _act_fwd(T: Tensor, p: Tensor) -> Tensor:
    """``R p + t``, column by column (as :func:`torchlie.so3.act`)."""
    return torch.add(_mv(T[..., :3, :3], p), T[..., :3, 3])


def _act_grads(T: Tensor, p: Tensor, g: Tensor) -> tuple[Tensor, Tensor]:
    # out = [R, t] (p, 1): d[R, t] = g (p, 1)^T and dp = R^T g.
    dT = _pad_row(g.unsqueeze(-1) * _homogeneous(p).unsqueeze(-2))
    return dT, _mv(T[..., :3, :3].transpose(-1, -2), g)


_act_grads_blocked = blocked(_act_grads, (2, 1, 1))


def _act_bwd(saved: tuple[Tensor, ...], g: Tensor) -> tuple[Tensor, Tensor]:
    T, p = saved
    dT, dp = _act_grads_blocked(T, p, g)
    return dT.sum_to_size(T.shape), dp.sum_to_size(p.shape)


def _act_jvp(saved: tuple[Tensor, ...], dT: Tensor, dp: Tensor) -> Tensor:
    T, p = saved
    out = torch.matmul(dT[..., :3, :], _homogeneous(p).unsqueeze(-1))
    return (out + torch.matmul(T[..., :3, :3], dp.unsqueeze(-1))).squeeze(-1)


def _compose(A: Tensor, B: Tensor) -> Tensor:
    return _ComposeFn(A, B)


def _inverse(T: Tensor) -> Tensor:
    return _InverseFn(T)


_ActFn = custom_function(
    "Se3Act",
    forward=_act_fwd,
    save=lambda inputs, out: (inputs[0], inputs[1]),
    backward=_act_bwd,
    jvp=_act_jvp,
    event_dims=(2, 1),
)


# ----------------------------------------------------------------------------------------------
# exp / log
# ----------------------------------------------------------------------------------------------


def _exp_forward(xi: Tensor) -> Tensor:
    """``[[Exp(phi), Jl(phi) rho], [0, 1]]`` from components, one set of coefficients for both
    blocks (runs without autograd: forward-only coefficients); the rotation block is
    :func:`torchlie.so3.exp`'s, bit for bit."""
    xyz, (a, b, c, d) = _rodrigues.coefficients(xi[..., 3:], "abcd")
    o, top = _top_outputs(xyz[0])
    R = _rodrigues.exp_entries(xyz, a, b, d, [e for row in top for e in row[:3]])
    t = _rodrigues.jl_components(
        xyz, _components.planes(xi[..., :3], 3), a, b, c, [r[3] for r in top]
    )
    return _stack_top([(*R[0:3], t[0]), (*R[3:6], t[1]), (*R[6:9], t[2])], out=o)


def _exp_backward(saved, G: Tensor):
    # T = [[R, t], [0, 1]], R = Exp(phi), t = Jl(phi) rho.  With a left perturbation,
    # dt = (Q(rho, phi) - t^ Jl(phi)) dphi + Jl(phi) drho, so
    #     g_rho = Jr(phi) g_t,
    #     g_phi = Jl(phi) vee(R^T G_R - G_R^T R) + Jr(phi) (t x g_t) + Q(-rho, -phi) g_t.
    xi, T = saved
    if not torch.is_grad_enabled():
        return (_exp_grad_values(xi, T, G),)
    rho, phi = xi[..., :3], xi[..., 3:]  # create_graph: differentiable ops
    R, t = _rot(T), _trans(T)
    g_R, g_t = _rot(G), _trans(G)
    g_rho = _rodrigues.jl_apply(phi, g_t, sign=-1.0)
    g_phi = _rodrigues.jl_apply(phi, 2.0 * _components.vee(R.transpose(-1, -2) @ g_R))
    g_phi = g_phi + _rodrigues.jl_apply(phi, torch.linalg.cross(t, g_t, dim=-1), sign=-1.0)
    return (torch.cat((g_rho, g_phi + _q_apply(-rho, -phi, g_t)), dim=-1),)


def _exp_backward_values(xi: Tensor, T: Tensor, G: Tensor) -> Tensor:
    """:func:`_exp_backward` from components, forward-only coefficients (plain backward)."""
    x = _components.planes(xi, 6)
    xyz = x[3:]
    half = _coeffs.half_angle(xyz)
    a, b, c = _coeffs.rodrigues_values(None, "abc", half)
    qc = _q_values(xi.dtype, half, (b, c))
    a, b, c = (v.to(xi.dtype) for v in (a, b, c))
    R, t = _rotation_and_translation(T)
    G_R, g_t = _rotation_and_translation(G)
    o = _layout.outputs(x[0], 6)
    g_rho = _rodrigues.jl_components(xyz, g_t, a, -b, c, o[:3])
    u = _components.rt_g_vee(R, G_R)
    g_phi = _rodrigues.jl_components(xyz, u, a, b, c)
    g_tx = _rodrigues.jl_components(xyz, _components.cross_planes(t, g_t), a, -b, c)
    neg = [-v for v in x]
    q = _q_components(neg[:3], neg[3:], g_t, *qc)
    g_phi = [
        torch.add(p, r, out=oi).add_(s) for p, r, s, oi in zip(g_phi, g_tx, q, o[3:], strict=True)
    ]
    return _layout.interleave((*g_rho, *g_phi), o)


_exp_grad_values = blocked(_exp_backward_values, (1, 2, 2))


def _exp_jvp(saved, dxi: Tensor) -> Tensor:
    # dT = [[e_phi^ R, e_phi^ t + e_rho], [0, 0]] with (e_rho, e_phi) = J_left(xi) dxi.
    xi, T = saved
    rho, phi = xi[..., :3], xi[..., 3:]
    e_phi = _rodrigues.jl_apply(phi, dxi[..., 3:])
    e_rho = _rodrigues.jl_apply(phi, dxi[..., :3]) + _q_apply(rho, phi, dxi[..., 3:])
    dR = _components.hat(e_phi) @ _rot(T)
    dt = torch.linalg.cross(e_phi, _trans(T), dim=-1) + e_rho
    return _pad_row(torch.cat((dR, dt.unsqueeze(-1)), dim=-1))


_ExpMapFn = custom_function(
    "Se3Exp",
    forward=_exp_forward,
    save=lambda inputs, out: (inputs[0], out),
    backward=_exp_backward,
    jvp=_exp_jvp,
    event_dims=(1,),
)


def _exp(xi: Tensor) -> Tensor:
    return _ExpMapFn(_reduced(xi))


def _reduced(xi: Tensor) -> Tensor:
    """A twist with the same ``Exp`` as ``xi`` (and the same derivatives), the angle reduced
    modulo ``2 pi`` where it is too large for the formulas, ``xi`` itself elsewhere.

    With ``phi'``, ``lam`` and ``u`` of :func:`torchlie._coeffs.reduction`,
    ``Jl(phi) = lam Jl(phi') + (1 - lam) u u^T`` and ``Jl(phi') u = u``, so
    ``Jl(phi) rho = Jl(phi') rho'`` with ``rho' = lam rho + (1 - lam) (u . rho) u``.
    ``xi`` itself while compiling (:func:`torchlie._coeffs.reduction`).
    """
    if torch.compiler.is_compiling():
        return xi
    phi, lam, u = _coeffs.reduction(xi[..., 3:])
    lam, u = lam[..., 0], u.unbind(-1)
    rho = xi[..., :3].unbind(-1)
    along = fma(fma(u[0] * rho[0], u[1], rho[1]), u[2], rho[2])
    big = lam < 1.0
    rho = [
        torch.where(big, torch.lerp(along * ui, ri, lam), ri) for ui, ri in zip(u, rho, strict=True)
    ]
    return torch.stack((*rho, *phi.unbind(-1)), dim=-1)


def _log_forward(T: Tensor) -> Tensor:
    """From components, stacked once.  ``Jl(phi)^-1 t`` with the coefficients
    ``e = (theta/2) cot(theta/2)`` and ``D = (1 - e) / theta^2`` from the log's own angle and
    cotangent (:func:`torchlie._rotation_matrix.log_and_cot`)."""
    R, t = _rotation_and_translation(T)  # one transposition of the top block
    phi, theta, e = _rotation_matrix.log_and_cot(R, cot=True)
    d = torch.rsub(e, 1.0).div_(theta.mul_(theta).clamp_min_(_coeffs.H_MIN[T.dtype]))
    rho = _rodrigues.jl_components(phi, t, e, e.new_full((), -0.5), d)
    return _layout.interleave((*rho, *phi))


def _log_backward(saved, g: Tensor):
    # d xi = Jr(xi)^-1 (R^T dt, vee(R^T dR)) along the tangent directions (zero along the
    # normal ones).  With h = Jr(xi)^-T g and A = so3 Jl(phi):
    #     Jr(xi)^-T = [[A^-1, 0], [-A^-1 Q A^-1, A^-1]]   (Q = Q(rho, phi) = Q(-rho, -phi)^T),
    # so G_t = R h_rho and G_R = R hat(h_phi) / 2.
    T, xi = saved
    if not torch.is_grad_enabled():
        return (_log_grad_values(T, xi, g),)
    R = _rot(T)  # create_graph: differentiable ops
    rho, phi = xi[..., :3], xi[..., 3:]
    h_rho = _rodrigues.jl_inv_apply(phi, g[..., :3])
    h_phi = _rodrigues.jl_inv_apply(phi, g[..., 3:] - _q_apply(rho, phi, h_rho))
    G_R = 0.5 * (R @ _components.hat(h_phi))
    top = torch.cat((G_R, _mv(R, h_rho).unsqueeze(-1)), dim=-1)
    return (torch.cat((top, torch.zeros_like(top[..., :1, :])), dim=-2),)


def _log_backward_values(T: Tensor, xi: Tensor, g: Tensor) -> Tensor:
    """:func:`_log_backward` from components, forward-only coefficients (plain backward)."""
    x = _components.planes(xi, 6)
    gs = _components.planes(g, 6)
    half = _coeffs.half_angle(x[3:])  # one sin and cos for the coefficients of Jl^-1 and Q
    qc = _q_values(xi.dtype, half)
    e, d = (v.to(xi.dtype) for v in _coeffs.jl_inv_values(None, half))
    minus_half = e.new_full((), -0.5)
    h_rho = _rodrigues.jl_components(x[3:], gs[:3], e, minus_half, d)
    q = _q_components(x[:3], x[3:], h_rho, *qc)
    v = [(gi - qi).mul_(0.5) for gi, qi in zip(gs[3:], q, strict=True)]
    u = _rodrigues.jl_components(x[3:], v, e, minus_half, d)  # h_phi / 2
    r = _components.planes(_rot(T), 9)
    o, top = _top_outputs(r[0])
    G_R = [
        _components.cross_planes(r[3 * i : 3 * i + 3], u, top[i][:3]) for i in range(3)
    ]  # rows of R hat(u)
    G_t = [
        fma(fma(r[i] * h_rho[0], r[i + 1], h_rho[1]), r[i + 2], h_rho[2], out=oi[3])
        for i, oi in zip((0, 3, 6), top, strict=True)
    ]
    return _stack_rows([(*G_R[i], G_t[i]) for i in range(3)], o)


_log_grad_values = blocked(_log_backward_values, (2, 1, 1))


def _log_jvp(saved, dT: Tensor) -> Tensor:
    T, xi = saved
    Rt = _rot(T).transpose(-1, -2)
    v = torch.cat((_mv(Rt, _trans(dT)), _components.vee(Rt @ _rot(dT))), dim=-1)
    return _jl_inv_apply(-xi, v)  # Jr(xi)^-1 v


_LogFn = custom_function(
    "Se3Log",
    forward=_log_forward,
    save=lambda inputs, out: (inputs[0], out),
    backward=_log_backward,
    jvp=_log_jvp,
    event_dims=(2,),
)


def hat(xi: Float[Tensor, "*b 6"]) -> Float[Tensor, "*b 4 4"]:
    """The 4x4 matrix ``[[phi^, rho], [0, 0]]`` of the twist ``xi = (rho, phi)``.

    Example:
        >>> hat(torch.tensor([1.0, 2.0, 3.0, 4.0, 5.0, 6.0]))
        tensor([[ 0., -6.,  5.,  1.],
                [ 6.,  0., -4.,  2.],
                [-5.,  4.,  0.,  3.],
                [ 0.,  0.,  0.,  0.]])
    """
    x, dtype = _checks.tensor(xi, _NAME + "hat", "xi", (6,))
    return _checks.out(_hat(x), dtype)


def vee(Xi: Float[Tensor, "*b 4 4"]) -> Float[Tensor, "*b 6"]:
    """Inverse of :func:`hat`: ``(Xi[:3, 3], so3.vee(Xi[:3, :3]))`` (skew part of the block).

    The bottom row is ignored.

    Example:
        >>> vee(hat(torch.tensor([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])))
        tensor([1., 2., 3., 4., 5., 6.])
    """
    x, dtype = _checks.tensor(Xi, _NAME + "vee", "Xi", (4, 4))
    return _checks.out(torch.cat((_trans(x), _components.vee(_rot(x))), dim=-1), dtype)


def exp(xi: Float[Tensor, "*b 6"]) -> Float[Tensor, "*b 4 4"]:
    """Pose of the twist ``xi = (rho, phi)``: ``[[so3.exp(phi), so3.jac_left(phi) rho], [0, 1]]``.

    Exact to a few ulp at every angle (one set of half-angle coefficients for both blocks, no
    cancellation at 0 or near pi).  The backward pass is closed-form, ``g_rho = Jr(phi) g_t``
    and ``g_phi = Jl(phi) vee(R^T G_R - G_R^T R) + Jr(phi)(t x g_t) + Q(-rho, -phi) g_t``, with
    series-safe coefficients, so every derivative is finite, at 0 and pi included; double
    backward and forward mode are supported.

    Example:
        >>> T = exp(torch.tensor([1.0, 0.0, 0.0, 0.0, 0.0, torch.pi / 2]))
        >>> T[:3, 3]  # quarter turn about z while moving along x: (2/pi, 2/pi, 0)
        tensor([0.6366, 0.6366, 0.0000])
    """
    x, dtype = _checks.tensor(xi, _NAME + "exp", "xi", (6,))
    return _checks.out(_exp(x), dtype)


def log(T: Float[Tensor, "*b 4 4"]) -> Float[Tensor, "*b 6"]:
    """Twist ``(rho, phi)`` of ``T``: ``phi = so3.log(R)``, ``rho = so3.jac_left(phi)^-1 t``.

    The rotation angle ``|phi|`` is in ``[0, pi]``; at exactly pi the axis sign follows
    :func:`torchlie.so3.log`'s canonical rule (and ``rho`` is the one that matches that axis).
    The bottom row of ``T`` is not read.

    Gradient meaning: the backward pass is the gradient of ``log`` composed with the projection
    of the rotation block onto SO(3) (as :func:`torchlie.so3.log`): along the tangent directions
    ``T hat(d)`` it is the exact derivative ``Jr(xi)^-1 d``; the translation block's gradient is
    exact (``d rho / d t = so3.jac_left(phi)^-1``); directions that leave SO(3) in the rotation
    block (``R S``, ``S`` symmetric) and the bottom row get zero gradient.  It is finite at
    ``theta = pi``.  The forward pass agrees with it to first order (so3's orthogonalisation
    step), so plain ``gradcheck`` on a raw pose matrix passes.  Double backward and forward
    mode are supported.

    The rotation block must be a rotation up to first-order deviations; other matrices give an
    unspecified result (see "Matrices off SO(3)" in :mod:`torchlie.so3`).

    Example:
        >>> T = exp(torch.tensor([1.0, 2.0, 3.0, 0.1, 0.2, 0.3]))
        >>> log(T)
        tensor([1.0000, 2.0000, 3.0000, 0.1000, 0.2000, 0.3000])
    """
    x, dtype = _checks.tensor(T, _NAME + "log", "T", (4, 4))
    return _checks.out(_LogFn(x), dtype)


# ----------------------------------------------------------------------------------------------
# Group operations
# ----------------------------------------------------------------------------------------------


def _pair(fn: str, a: object, b: object, na: str, nb: str, ta=(4, 4), tb=(4, 4)):
    x, dtype = _checks.tensor(a, _NAME + fn, na, ta)
    y, _ = _checks.tensor(b, _NAME + fn, nb, tb)
    _checks.same_dtype(_NAME + fn, **{na: a, nb: b})
    batch = _checks.batch_broadcast(
        _NAME + fn, (x.shape[: x.dim() - len(ta)], na), (y.shape[: y.dim() - len(tb)], nb)
    )
    return x, y, dtype, batch


def compose(T1: Float[Tensor, "*b1 4 4"], T2: Float[Tensor, "*b2 4 4"]) -> Float[Tensor, "*b 4 4"]:
    """``T1 @ T2`` from blocks (``R1 R2``, ``R1 t2 + t1``); batch shapes broadcast.

    The bottom rows of the inputs are not read; the result's is exactly ``(0, 0, 0, 1)``.

    Example:
        >>> T = exp(torch.tensor([1.0, 0.0, 0.0, 0.0, 0.0, 0.5]))
        >>> torch.allclose(compose(T, T), exp(torch.tensor([2.0, 0.0, 0.0, 0.0, 0.0, 1.0])))
        True
    """
    a, b, dtype, _ = _pair("compose", T1, T2, "T1", "T2")
    return _checks.out(_ComposeFn(a, b), dtype)


def inverse(T: Float[Tensor, "*b 4 4"]) -> Float[Tensor, "*b 4 4"]:
    """``T^-1 = [[R^T, -R^T t], [0, 1]]``.

    Example:
        >>> T = exp(torch.tensor([1.0, 2.0, 3.0, 0.1, 0.2, 0.3]))
        >>> torch.allclose(compose(inverse(T), T), torch.eye(4), atol=1e-6)
        True
    """
    x, dtype = _checks.tensor(T, _NAME + "inverse", "T", (4, 4))
    return _checks.out(_InverseFn(x), dtype)


def act(T: Float[Tensor, "*b1 4 4"], points: Float[Tensor, "*b2 3"]) -> Float[Tensor, "*b 3"]:
    """Transform points: ``R p + t`` (batch shapes broadcast).

    Example:
        >>> T = from_rt(so3.exp(torch.tensor([0.0, 0.0, torch.pi])), torch.tensor([1.0, 2.0, 3.0]))
        >>> act(T, torch.tensor([1.0, 0.0, 0.0])).round(decimals=6)
        tensor([0., 2., 3.])
    """
    x, p, dtype, _ = _pair("act", T, points, "T", "points", tb=(3,))
    return _checks.out(_ActFn(x, p), dtype)


def adjoint(T: Float[Tensor, "*b 4 4"]) -> Float[Tensor, "*b 6 6"]:
    """Adjoint matrix ``Ad_T = [[R, t^ R], [0, R]]`` on twists ``(rho, phi)``.

    ``T Exp(xi) T^-1 = Exp(Ad_T xi)``.

    Example:
        >>> T = from_rt(torch.eye(3), torch.tensor([1.0, 0.0, 0.0]))
        >>> adjoint(T)[1:3, 4:]
        tensor([[ 0., -1.],
                [ 1.,  0.]])
    """
    x, dtype = _checks.tensor(T, _NAME + "adjoint", "T", (4, 4))
    return _checks.out(_adjoint(x), dtype)


def ad(xi: Float[Tensor, "*b 6"]) -> Float[Tensor, "*b 6 6"]:
    """Small adjoint ``ad(rho, phi) = [[phi^, rho^], [0, phi^]]``.

    ``ad(x) y`` is the Lie bracket ``vee(hat(x) hat(y) - hat(y) hat(x))`` and
    ``adjoint(exp(x)) = matrix_exp(ad(x))``.

    Example:
        >>> ad(torch.tensor([1.0, 2.0, 3.0, 4.0, 5.0, 6.0]))
        tensor([[ 0., -6.,  5.,  0., -3.,  2.],
                [ 6.,  0., -4.,  3.,  0., -1.],
                [-5.,  4.,  0., -2.,  1.,  0.],
                [ 0.,  0.,  0.,  0., -6.,  5.],
                [ 0.,  0.,  0.,  6.,  0., -4.],
                [ 0.,  0.,  0., -5.,  4.,  0.]])
    """
    x, dtype = _checks.tensor(xi, _NAME + "ad", "xi", (6,))
    return _checks.out(_ad(x), dtype)


def _jac(fn: str, xi: Tensor, inv: bool, sign: float) -> Tensor:
    x, dtype = _checks.tensor(xi, _NAME + fn, "xi", (6,))
    x = x if sign > 0 else -x
    return _checks.out(_jac_left_inv(x) if inv else _jac_left(x), dtype)


def jac_left(xi: Float[Tensor, "*b 6"]) -> Float[Tensor, "*b 6 6"]:
    """Left Jacobian ``Jl(xi) = [[A, Q], [0, A]]`` (``A = so3.jac_left(phi)``, ``Q`` Barfoot's).

    ``Exp(xi + d) ~= Exp(Jl(xi) d) Exp(xi)``; the translation of ``Exp(xi)`` is ``A rho``.

    Example:
        >>> torch.equal(jac_left(torch.zeros(6)), torch.eye(6))
        True
    """
    return _jac("jac_left", xi, False, 1.0)


def jac_right(xi: Float[Tensor, "*b 6"]) -> Float[Tensor, "*b 6 6"]:
    """Right Jacobian ``Jr(xi) = Jl(-xi)``; ``Exp(xi + d) ~= Exp(xi) Exp(Jr(xi) d)``.

    It is also the Jacobian ``J_Exp(xi)_xi`` of :func:`exp` (right perturbation of the result).

    Example:
        >>> xi = torch.tensor([1.0, 2.0, 3.0, 0.1, 0.2, 0.3])
        >>> torch.allclose(jac_left(xi), adjoint(exp(xi)) @ jac_right(xi), atol=1e-6)
        True
    """
    return _jac("jac_right", xi, False, -1.0)


def jac_left_inv(xi: Float[Tensor, "*b 6"]) -> Float[Tensor, "*b 6 6"]:
    """``Jl(xi)^-1 = [[A^-1, -A^-1 Q A^-1], [0, A^-1]]``, closed form, finite for ``|phi| < 2 pi``.

    Example:
        >>> xi = torch.tensor([1.0, 2.0, 3.0, 0.1, 0.2, 0.3])
        >>> torch.allclose(jac_left_inv(xi) @ jac_left(xi), torch.eye(6), atol=1e-6)
        True
    """
    return _jac("jac_left_inv", xi, True, 1.0)


def jac_right_inv(xi: Float[Tensor, "*b 6"]) -> Float[Tensor, "*b 6 6"]:
    """``Jr(xi)^-1 = Jl(-xi)^-1``; ``jac_right_inv(log(T))`` is the Jacobian ``J_Log(T)_T``.

    Example:
        >>> xi = torch.tensor([1.0, 2.0, 3.0, 0.1, 0.2, 0.3])
        >>> torch.allclose(jac_right_inv(xi) @ jac_right(xi), torch.eye(6), atol=1e-6)
        True
    """
    return _jac("jac_right_inv", xi, True, -1.0)


# ----------------------------------------------------------------------------------------------
# Construction, validation, conversions
# ----------------------------------------------------------------------------------------------


def identity(
    *batch: int, dtype: torch.dtype | None = None, device: torch.device | str | None = None
) -> Float[Tensor, "*batch 4 4"]:
    """Identity poses of shape ``(*batch, 4, 4)``.

    Example:
        >>> identity(2).shape
        torch.Size([2, 4, 4])
    """
    _, dtype = _checks.factory(_NAME + "identity", batch, dtype)
    return torch.eye(4, dtype=dtype, device=device).expand(*batch, 4, 4).clone()


def random(
    *batch: int,
    generator: torch.Generator | None = None,
    dtype: torch.dtype | None = None,
    device: torch.device | str | None = None,
) -> Float[Tensor, "*batch 4 4"]:
    """Random poses: Haar-uniform rotations (:func:`torchlie.so3.random`), translations ``N(0, I)``.

    float16/bfloat16 are drawn and computed in float32, then cast.

    Example:
        >>> T = random(4, generator=torch.Generator().manual_seed(0))
        >>> bool(is_valid(T).all())
        True
    """
    compute, dtype = _checks.factory(_NAME + "random", batch, dtype)
    R = so3.random(*batch, generator=generator, dtype=compute, device=device)
    t = torch.randn(*batch, 3, generator=generator, dtype=compute, device=device)
    return _checks.out(_assemble(R, t), dtype)


def is_valid(T: Float[Tensor, "*b 4 4"], atol: float | None = None) -> Bool[Tensor, "*b"]:
    """Per element: finite, rotation block valid (:func:`torchlie.so3.is_valid`) and bottom row
    ``(0, 0, 0, 1)``, each within ``atol`` (a non-negative finite real number; default
    ``100 * eps`` of the input dtype, ``4 * eps`` for half).

    Example:
        >>> bad = identity()
        >>> bad[3, 0] = 1.0
        >>> is_valid(torch.stack((identity(), bad)))
        tensor([ True, False])
    """
    x, _ = _checks.tensor(T, _NAME + "is_valid", "T", (4, 4))
    tol = _checks.tolerance(atol, _NAME + "is_valid", "atol", T.dtype)
    last = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=x.dtype, device=x.device)
    bottom = (x[..., 3, :] - last).abs().amax(dim=-1) <= tol
    return so3.is_valid(_rot(x), atol=tol) & bottom & torch.isfinite(_trans(x)).all(dim=-1)


def from_rt(R: Float[Tensor, "*b1 3 3"], t: Float[Tensor, "*b2 3"]) -> Float[Tensor, "*b 4 4"]:
    """Pose ``[[R, t], [0, 1]]`` from a rotation matrix and a translation (batches broadcast).

    Example:
        >>> from_rt(torch.eye(3), torch.tensor([1.0, 2.0, 3.0]))
        tensor([[1., 0., 0., 1.],
                [0., 1., 0., 2.],
                [0., 0., 1., 3.],
                [0., 0., 0., 1.]])
    """
    r, v, dtype, _ = _pair("from_rt", R, t, "R", "t", ta=(3, 3), tb=(3,))
    return _checks.out(_assemble(*_broadcast_rt(r, v)), dtype)


def to_rt(T: Float[Tensor, "*b 4 4"]) -> tuple[Float[Tensor, "*b 3 3"], Float[Tensor, "*b 3"]]:
    """Rotation block and translation ``(R, t)`` of ``T`` (copies, not views).

    Example:
        >>> R, t = to_rt(from_rt(torch.eye(3), torch.tensor([1.0, 2.0, 3.0])))
        >>> t
        tensor([1., 2., 3.])
    """
    _checks.tensor(T, _NAME + "to_rt", "T", (4, 4))
    return T[..., :3, :3].clone(), T[..., :3, 3].clone()


def from_pos_quat(x: Float[Tensor, "*b 7"]) -> Float[Tensor, "*b 4 4"]:
    """Pose from a 7-vector ``(tx, ty, tz, qw, qx, qy, qz)``: translation, then a wxyz quaternion.

    The quaternion need not be unit (the rotation of ``q / |q|`` is used, as
    :func:`torchlie.quaternion.to_matrix`); a zero quaternion gives NaN for that element.

    Example:
        >>> from_pos_quat(torch.tensor([1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0]))
        tensor([[-1.,  0.,  0.,  1.],
                [ 0., -1.,  0.,  2.],
                [ 0.,  0.,  1.,  3.],
                [ 0.,  0.,  0.,  1.]])
    """
    v, dtype = _checks.tensor(x, _NAME + "from_pos_quat", "x", (7,))
    return _checks.out(_assemble(_rotation_matrix.from_quaternion(v[..., 3:]), v[..., :3]), dtype)


def to_pos_quat(T: Float[Tensor, "*b 4 4"]) -> Float[Tensor, "*b 7"]:
    """7-vector ``(t, q)`` of a pose: translation, then the canonical wxyz unit quaternion.

    The quaternion is :func:`torchlie.quaternion.from_matrix` of the rotation block (``w >= 0``).

    Example:
        >>> to_pos_quat(from_pos_quat(torch.tensor([1.0, 2.0, 3.0, 0.0, 1.0, 0.0, 0.0])))
        tensor([1., 2., 3., 0., 1., 0., 0.])
    """
    x, dtype = _checks.tensor(T, _NAME + "to_pos_quat", "T", (4, 4))
    q = _rotation_matrix.to_quaternion(_rot(x))
    return _checks.out(torch.cat((_trans(x), q), dim=-1), dtype)


# ----------------------------------------------------------------------------------------------
# Metrics and interpolation
# ----------------------------------------------------------------------------------------------


def interpolate(
    T0: Float[Tensor, "*b1 4 4"], T1: Float[Tensor, "*b2 4 4"], t: Float[Tensor, "*b3"] | float
) -> Float[Tensor, "*b 4 4"]:
    """Geodesic interpolation ``T0 Exp(t Log(T0^-1 T1))`` (``t`` broadcasts with the batch).

    ``t = 0`` gives ``T0`` and ``t = 1`` gives ``T1``; the path is a screw motion (rotation and
    translation coupled), not separate slerp + lerp.  Other ``t`` extrapolate.  ``t`` is a
    tensor of the dtype of ``T0`` or numbers (a float, numpy scalar or array, or a list),
    converted to it; not a bool.

    Example:
        >>> T1 = exp(torch.tensor([2.0, 0.0, 0.0, 0.0, 0.0, 1.0]))
        >>> mid = exp(torch.tensor([1.0, 0.0, 0.0, 0.0, 0.0, 0.5]))
        >>> torch.allclose(interpolate(identity(), T1, 0.5), mid, atol=1e-6)
        True
    """
    fn = _NAME + "interpolate"
    a, b, dtype, _ = _pair("interpolate", T0, T1, "T0", "T1")
    t = _checks.real(t, fn, "t", a, ("T0", T0))
    _checks.batch_broadcast(fn, (a.shape[:-2], "T0"), (b.shape[:-2], "T1"), (t.shape, "t"))
    xi = _LogFn(_between(a, b))
    return _checks.out(_compose(a, _exp(t.unsqueeze(-1) * xi)), dtype)


def distance(
    T1: Float[Tensor, "*b1 4 4"], T2: Float[Tensor, "*b2 4 4"]
) -> tuple[Float[Tensor, "*b"], Float[Tensor, "*b"]]:
    """Rotation angle and translation length of the relative pose ``T1^-1 T2``.

    Returns a pair ``(angle, translation)``: the rotation angle of ``R1^T R2`` in ``[0, pi]`` (as
    :func:`torchlie.so3.distance`) and ``|R1^T (t2 - t1)| = |t2 - t1|``.  Both are measured in
    their own units, so no weighting is imposed; both have the zero subgradient where they are
    not differentiable (angle 0 or pi, equal translations), so gradients are always finite.

    Example:
        >>> T2 = from_rt(so3.exp(torch.tensor([0.0, 0.3, 0.0])), torch.tensor([3.0, 4.0, 0.0]))
        >>> distance(identity(), T2)
        (tensor(0.3000), tensor(5.))
    """
    a, b, dtype, _ = _pair("distance", T1, T2, "T1", "T2")
    angle = _rotation_matrix.angle(_rot(a).transpose(-1, -2) @ _rot(b))
    trans = _coeffs.norm(_trans(b) - _trans(a))
    trans = trans.expand(angle.shape)
    return _checks.out(angle, dtype), _checks.out(trans, dtype)


# ----------------------------------------------------------------------------------------------
# Lie-group operations and their Jacobians
# ----------------------------------------------------------------------------------------------


def rplus(T: Float[Tensor, "*b1 4 4"], xi: Float[Tensor, "*b2 6"]) -> Float[Tensor, "*b 4 4"]:
    """Right plus ``T (+) xi = T Exp(xi)`` (batch shapes broadcast).

    Example:
        >>> xi = torch.tensor([1.0, 0.0, 0.0, 0.0, 0.0, 0.0])
        >>> rplus(identity(), xi)[:3, 3]
        tensor([1., 0., 0.])
    """
    x, v, dtype, _ = _pair("rplus", T, xi, "T", "xi", tb=(6,))
    return _checks.out(_compose(x, _exp(v)), dtype)


def rminus(T1: Float[Tensor, "*b1 4 4"], T0: Float[Tensor, "*b2 4 4"]) -> Float[Tensor, "*b 6"]:
    """Right minus ``T1 (-) T0 = Log(T0^-1 T1)``, so that ``rplus(T0, rminus(T1, T0)) == T1``.

    Example:
        >>> xi = torch.tensor([1.0, 2.0, 3.0, 0.1, 0.2, 0.3])
        >>> T0 = exp(torch.tensor([0.5, 0.0, 0.0, 0.0, 1.0, 0.0]))
        >>> torch.allclose(rminus(rplus(T0, xi), T0), xi, atol=1e-5)
        True
    """
    a, b, dtype, _ = _pair("rminus", T1, T0, "T1", "T0")
    return _checks.out(_LogFn(_between(b, a)), dtype)


def lplus(T: Float[Tensor, "*b1 4 4"], xi: Float[Tensor, "*b2 6"]) -> Float[Tensor, "*b 4 4"]:
    """Left plus ``Exp(xi) T`` (the perturbation is expressed in the world frame).

    Example:
        >>> T = from_rt(torch.eye(3), torch.tensor([1.0, 0.0, 0.0]))
        >>> xi = torch.tensor([0.0, 0.0, 0.0, 0.0, 0.0, torch.pi / 2])
        >>> torch.allclose(lplus(T, xi)[:3, 3], torch.tensor([0.0, 1.0, 0.0]), atol=1e-6)
        True
    """
    x, v, dtype, _ = _pair("lplus", T, xi, "T", "xi", tb=(6,))
    return _checks.out(_compose(_exp(v), x), dtype)


def lminus(T1: Float[Tensor, "*b1 4 4"], T0: Float[Tensor, "*b2 4 4"]) -> Float[Tensor, "*b 6"]:
    """Left minus ``Log(T1 T0^-1)``, so that ``lplus(T0, lminus(T1, T0)) == T1``.

    Example:
        >>> xi = torch.tensor([1.0, 2.0, 3.0, 0.1, 0.2, 0.3])
        >>> T0 = exp(torch.tensor([0.5, 0.0, 0.0, 0.0, 1.0, 0.0]))
        >>> torch.allclose(lminus(lplus(T0, xi), T0), xi, atol=1e-5)
        True
    """
    a, b, dtype, _ = _pair("lminus", T1, T0, "T1", "T0")
    return _checks.out(_LogFn(_compose(a, _inverse(b))), dtype)


def between(T0: Float[Tensor, "*b1 4 4"], T1: Float[Tensor, "*b2 4 4"]) -> Float[Tensor, "*b 4 4"]:
    """Relative pose ``T0^-1 T1`` (``T1`` expressed in the frame of ``T0``).

    Example:
        >>> T0 = from_rt(torch.eye(3), torch.tensor([1.0, 0.0, 0.0]))
        >>> T1 = from_rt(torch.eye(3), torch.tensor([1.0, 2.0, 0.0]))
        >>> between(T0, T1)[:3, 3]
        tensor([0., 2., 0.])
    """
    a, b, dtype, _ = _pair("between", T0, T1, "T0", "T1")
    return _checks.out(_between(a, b), dtype)


def _eye6(batch: torch.Size, like: Tensor) -> Tensor:
    return torch.eye(6, dtype=like.dtype, device=like.device).expand(*batch, 6, 6).clone()


def jac_compose(
    T1: Float[Tensor, "*b1 4 4"], T2: Float[Tensor, "*b2 4 4"]
) -> tuple[Float[Tensor, "*b 6 6"], Float[Tensor, "*b 6 6"]]:
    """Jacobians of ``T1 T2``: ``(J_T1T2_T1, J_T1T2_T2) = (Ad(T2)^-1, I)``.

    Right perturbations throughout: ``(T1 Exp(d1)) (T2 Exp(d2)) ~= T1 T2 Exp(J1 d1 + J2 d2)``.

    Example:
        >>> T2 = exp(torch.tensor([1.0, 2.0, 3.0, 0.1, 0.2, 0.3]))
        >>> J1, J2 = jac_compose(identity(), T2)
        >>> torch.allclose(J1, adjoint(inverse(T2))) and torch.equal(J2, torch.eye(6))
        True
    """
    a, b, dtype, batch = _pair("jac_compose", T1, T2, "T1", "T2")
    J1 = _adjoint(_inverse(b)).expand(*batch, 6, 6).clone()
    return _checks.out(J1, dtype), _checks.out(_eye6(batch, a), dtype)


def jac_inverse(T: Float[Tensor, "*b 4 4"]) -> Float[Tensor, "*b 6 6"]:
    """Jacobian ``J_Tinv_T = -Ad(T)``: ``(T Exp(d))^-1 = T^-1 Exp(-Ad(T) d)``.

    Example:
        >>> torch.equal(jac_inverse(identity()), -torch.eye(6))
        True
    """
    x, dtype = _checks.tensor(T, _NAME + "jac_inverse", "T", (4, 4))
    return _checks.out(-_adjoint(x), dtype)


def jac_act(
    T: Float[Tensor, "*b1 4 4"], points: Float[Tensor, "*b2 3"]
) -> tuple[Float[Tensor, "*b 3 6"], Float[Tensor, "*b 3 3"]]:
    """Jacobians of ``T p``: ``(J_Tp_T, J_Tp_p) = ([R, -R p^], R)``.

    ``T Exp(d) (p + dp) ~= T p + J_Tp_T d + J_Tp_p dp`` (the point is perturbed additively).

    Example:
        >>> p = torch.tensor([1.0, 2.0, 3.0])
        >>> JT, Jp = jac_act(identity(), p)
        >>> torch.equal(JT, torch.cat((torch.eye(3), -so3.hat(p)), dim=-1))
        True
    """
    x, p, dtype, batch = _pair("jac_act", T, points, "T", "points", tb=(3,))
    R = _rot(x).expand(*batch, 3, 3)
    JT = torch.cat((R, -(R @ _components.hat(p))), dim=-1)
    return _checks.out(JT, dtype), _checks.out(R.clone(), dtype)


def jac_rplus(
    T: Float[Tensor, "*b1 4 4"], xi: Float[Tensor, "*b2 6"]
) -> tuple[Float[Tensor, "*b 6 6"], Float[Tensor, "*b 6 6"]]:
    """Jacobians of ``T Exp(xi)``: ``(J_T, J_xi) = (Ad(Exp(xi))^-1, Jr(xi))``.

    Example:
        >>> JT, Jxi = jac_rplus(identity(), torch.zeros(6))
        >>> torch.equal(JT, torch.eye(6)) and torch.equal(Jxi, torch.eye(6))
        True
    """
    x, v, dtype, batch = _pair("jac_rplus", T, xi, "T", "xi", tb=(6,))
    v = v.expand(*batch, 6)
    JT = _adjoint(_exp(-v))
    return _checks.out(JT, dtype), _checks.out(_jac_left(-v), dtype)


def jac_rminus(
    T1: Float[Tensor, "*b1 4 4"], T0: Float[Tensor, "*b2 4 4"]
) -> tuple[Float[Tensor, "*b 6 6"], Float[Tensor, "*b 6 6"]]:
    """Jacobians of ``xi = Log(T0^-1 T1)``: ``(J_xi_T1, J_xi_T0) = (Jr(xi)^-1, -Jl(xi)^-1)``.

    Example:
        >>> J1, J0 = jac_rminus(identity(), identity())
        >>> torch.equal(J1, torch.eye(6)) and torch.equal(J0, -torch.eye(6))
        True
    """
    a, b, dtype, _ = _pair("jac_rminus", T1, T0, "T1", "T0")
    xi = _LogFn(_between(b, a))
    return _checks.out(_jac_left_inv(-xi), dtype), _checks.out(-_jac_left_inv(xi), dtype)


def jac_between(
    T0: Float[Tensor, "*b1 4 4"], T1: Float[Tensor, "*b2 4 4"]
) -> tuple[Float[Tensor, "*b 6 6"], Float[Tensor, "*b 6 6"]]:
    """Jacobians of ``T0^-1 T1``: ``(J_T0, J_T1) = (-Ad(T1^-1 T0), I)``.

    Example:
        >>> J0, J1 = jac_between(identity(), identity())
        >>> torch.equal(J0, -torch.eye(6)) and torch.equal(J1, torch.eye(6))
        True
    """
    a, b, dtype, batch = _pair("jac_between", T0, T1, "T0", "T1")
    J0 = -_adjoint(_between(b, a))
    return _checks.out(J0, dtype), _checks.out(_eye6(batch, a), dtype)
