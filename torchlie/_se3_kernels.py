"""The custom autograd Functions of SE(3): compose, inverse, act, exp and log of poses.

Each forward works from components (the 12 entries of the top 3x4 block read as planes, the
result's entries written into its columns), with a closed-form backward in the same style and a
forward-mode rule; autograd's own graph of the slices and concatenations costs about twice as
many passes over memory.  compose and inverse, sums of products over the entries of the blocks,
take each block as one tensor, entries first (:func:`_top`): each term of a sum is the broadcast
of a column against a row, a few operations for all twelve entries, each entry summed in the
same order as one written out alone; so is ``between`` (``A^-1 B``, and ``A B^-1`` for the
left minus), whose backward is autograd's of its formula.  exp and log take their coefficients
from :mod:`torchlie._rodrigues` and :mod:`torchlie._se3_jacobian`.  :mod:`torchlie.se3` checks
the inputs and calls these.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch
from torch import Tensor

from . import _coeffs, _layout, _rodrigues, _rotation_matrix, _se3_jacobian
from ._autograd import CustomFunction, blocked, fma
from ._components import (
    cross_planes,
    gram_defect,
    hat,
    mtv,
    mv,
    planes,
    polar_backward_terms,
    polar_tangent,
    rt_g_vee,
)

# ----------------------------------------------------------------------------------------------
# The top block, entry by entry
# ----------------------------------------------------------------------------------------------


def _pad_row(top: Tensor) -> Tensor:
    """``(..., 3, 4) -> (..., 4, 4)`` with a zero last row."""
    return torch.nn.functional.pad(top, (0, 0, 0, 1))


def _top(T: Tensor, ndim: int = 0) -> Tensor:
    """The top 3x4 block of ``T`` entries first, ``(3, 4, *batch)``: one transposition
    (:func:`_layout.stacked`), the batch padded with leading ones to ``ndim`` dimensions (so
    that the blocks of operands whose batches broadcast broadcast alike)."""
    x = _layout.stacked(T[..., :3, :], (3, 4))
    batch = x.shape[2:]
    if ndim > len(batch):
        x = x.reshape((3, 4) + (1,) * (ndim - len(batch)) + batch)
    return x


def _rotation_and_translation(T: Tensor) -> tuple[list[Tensor], list[Tensor]]:
    """The 9 entries of the rotation block of ``T`` (row by row) and the 3 of its translation,
    as planes (one transposition of the top block; strided views while compiling)."""
    e = _layout.planes(T[..., :3, :], (3, 4))
    return [e[4 * i + j] for i in range(3) for j in range(3)], [e[4 * i + 3] for i in range(3)]


def _top_outputs(
    like: Tensor | Sequence[Tensor],
) -> tuple[tuple[Tensor | None, ...], list[list[Tensor | None]]]:
    """The 16 columns of :func:`_layout.outputs` for a 4x4 result, and the 12 of its top block
    row by row (where the entries are to be written)."""
    o = _layout.outputs(like, 16)
    return o, [list(o[4 * i : 4 * i + 4]) for i in range(3)]


def _stack_top(
    entries: Sequence[Tensor],
    corner: float = 1.0,
    out: Sequence[Tensor | None] | None = None,
) -> Tensor:
    """``[[top], [0, 0, 0, corner]]``: a 4x4 matrix from the 12 entries of its top block (row by
    row, all of one shape; written to the columns ``out`` of :func:`_top_outputs` or not), or
    from its columns in blocks entries first (``(3, k, *batch)`` tensors, ``k`` summing to 4)."""
    if len(entries) < 12:
        first = entries[0]
        rows = first.numel() // (3 * first.shape[1])
        if not (torch.compiler.is_compiling() or _layout.large(first, rows)):
            # one transposing copy: cheaper than interleaving sixteen planes on small batches
            # (compiled, the stack of planes keeps the op one loop; a concatenation would not)
            top = first if len(entries) == 1 else torch.cat(tuple(entries), dim=1)
            row = _layout.constant(((0.0, 0.0, 0.0, corner),), top, dims=top.dim())
            whole = torch.cat((top, row.expand((1, 4) + top.shape[2:])))
            return whole.movedim((0, 1), (-2, -1)).contiguous()
        by_row = zip(*(block.unbind(0) for block in entries), strict=True)
        entries = [x for row in by_row for part in row for x in part.unbind(0)]
    if isinstance(out, _layout.Columns):
        bottom = out.result[..., 12:]
        bottom[..., :3].zero_()
        bottom[..., 3].fill_(corner)
        zero, last = out[12:15], out[15]
    else:
        zero = (torch.zeros_like(entries[0]),) * 3
        last = zero[0] if corner == 0.0 else torch.full_like(zero[0], corner)
    return _layout.interleave((*entries, *zero, last), out).unflatten(-1, (4, 4))


def _stack_rows(entries: Sequence[Tensor], out: Sequence[Tensor | None] | None = None) -> Tensor:
    """:func:`_stack_top` with a zero last row (a gradient: the bottom row is not read)."""
    return _stack_top(entries, 0.0, out)


# ----------------------------------------------------------------------------------------------
# compose / inverse / act
# ----------------------------------------------------------------------------------------------


def _columns_last(x: Tensor) -> Tensor:
    """``x`` of shape ``(3, 1, *batch)`` in the last of four columns: ``(3, 4, *batch)``, zeros
    before it (the first term of a sum over the columns of a 3x4 block)."""
    return torch.nn.functional.pad(x, (0, 0) * (x.dim() - 2) + (3, 0))


def _compose_entries(A: Tensor, B: Tensor) -> Tensor:
    """``A B`` from the blocks entries first: entry ``(i, j)`` is
    ``((A_i3 [j = 3] + A_i0 B_0j) + A_i1 B_1j) + A_i2 B_2j``, each term the broadcast of a column
    of ``A`` against a row of ``B``."""
    ndim = len(_layout.broadcast(A.shape[:-2], B.shape[:-2]))
    a0, a1, a2, a3 = _top(A, ndim).unsqueeze(2).unbind(1)  # columns of A: (3, 1, *batch)
    b0, b1, b2 = _top(B, ndim).unbind(0)  # rows of B: (4, *batch)
    return _stack_top([fma(fma(fma(_columns_last(a3), a0, b0), a1, b1), a2, b2)])


def _inverse_translation(x: Tensor) -> Tensor:
    """``-R^T t`` of the block ``x = [R, t]`` entries first, ``(3, *batch)``: the sum over the
    rows of ``R``, each term a row broadcast against an entry of ``t`` (negated as it enters the
    sum: the same bits as negating the sum, one plane instead of three)."""
    r0, r1, r2 = x[:, :3].unbind(0)  # rows of R: (3, *batch)
    t0, t1, t2 = x[:, 3].unbind(0)
    return fma(fma(r0 * torch.neg(t0), r1, t1, value=-1.0), r2, t2, value=-1.0)


def _inverse_entries(T: Tensor) -> Tensor:
    """``T^-1 = [[R^T, -R^T t], [0, 1]]`` from the block entries first."""
    x = _top(T)
    return _stack_top((x[:, :3].transpose(0, 1), _inverse_translation(x).unsqueeze(1)))


def _between_entries(
    RA: Tensor, tA: Tensor, RB: Tensor, tB: Tensor, batch: Sequence[int]
) -> Tensor:
    """``A^-1 B`` from the blocks of ``A`` and ``B`` entries first (rotations ``(3, 3, *b)``,
    translations ``(3, *b)``, the ``b`` broadcasting to ``batch``): entry ``(i, j)`` is
    ``(RA_0i D_0j + RA_1i D_1j) + RA_2i D_2j`` with ``D = [RB, tB - tA]``, each term a row of
    ``RA`` broadcast against a row of ``D``.  The difference of the translations comes first,
    so that where ``A == B`` the translation is exactly 0 and the rotation block exactly
    symmetric (entries ``(i, j)`` and ``(j, i)`` the same products in the same order): its
    :func:`log` is exactly 0."""
    dt = (tB - tA).unsqueeze(1)
    D = torch.cat((RB.expand((3, 3, *batch)), dt.expand((3, 1, *batch))), dim=1)
    c0, c1, c2 = RA.unsqueeze(2).unbind(0)  # rows of RA as columns: (3, 1, *b)
    d0, d1, d2 = D.unbind(0)  # rows of D: (4, *batch)
    return _stack_top([fma(fma(c0 * d0, c1, d1), c2, d2)])


def _between_fwd(A: Tensor, B: Tensor) -> Tensor:
    batch = _layout.broadcast(A.shape[:-2], B.shape[:-2])
    a, b = _top(A, len(batch)), _top(B, len(batch))
    return _between_entries(a[:, :3], a[:, 3], b[:, :3], b[:, 3], batch)


def _right_between_fwd(A: Tensor, B: Tensor) -> Tensor:
    batch = _layout.broadcast(A.shape[:-2], B.shape[:-2])
    a, b = _top(A, len(batch)), _top(B, len(batch))
    ta, tb = _inverse_translation(a), _inverse_translation(b)
    return _between_entries(a[:, :3].transpose(0, 1), ta, b[:, :3].transpose(0, 1), tb, batch)


_between_blocked = blocked(_between_fwd, (2, 2))
_right_between_blocked = blocked(_right_between_fwd, (2, 2))


def between(A: Tensor, B: Tensor) -> Tensor:
    """``A^-1 B`` (batch shapes broadcast; the bottom rows are not read; autograd
    differentiates the formula).  Where ``A == B`` its :func:`log` is exactly 0."""
    return _between_blocked(A, B)


def right_between(A: Tensor, B: Tensor) -> Tensor:
    """``A B^-1`` as ``between(A^-1, B^-1)``, from the blocks of the inverses (not stacked):
    its translation ``R_A (R_A^T t_A - R_B^T t_B)`` is exactly 0 where ``A == B`` (that of
    ``compose(A, inverse(B))``, ``t_A - R_A R_B^T t_B``, is not), its :func:`log` exactly 0."""
    return _right_between_blocked(A, B)


def _compose_bwd(saved: tuple[Tensor, ...], G: Tensor) -> tuple[Tensor, Tensor]:
    A, B = saved
    dA, dB = _compose_grads(A, B, G)
    return dA.sum_to_size(A.shape), dB.sum_to_size(B.shape)


def _compose_bwd_entries(A: Tensor, B: Tensor, G: Tensor) -> tuple[Tensor, Tensor]:
    """The backward of ``A B`` from the blocks entries first: ``dA_ij = sum_k G_ik B_jk``
    (``j < 3``), ``dA_i3 = G_i3``, ``dB_kj = sum_i A_ik G_ij``."""
    ndim = G.dim() - 2
    g = _top(G)
    g0, g1, g2, g3 = g.unsqueeze(2).unbind(1)  # columns of G: (3, 1, *batch)
    b0, b1, b2, b3 = _top(B, ndim).unsqueeze(0).unbind(2)  # columns of B: (1, 3, *batch)
    dR = fma(fma(fma(g0 * b0, g1, b1), g2, b2), g3, b3)
    dA = _stack_rows((dR, g[:, 3:]))  # dA's last column is G's
    a0, a1, a2 = _top(A, ndim)[:, :3, None].unbind(0)  # rows of A's rotation: (3, 1, *batch)
    h0, h1, h2 = g.unbind(0)  # rows of G: (4, *batch)
    return dA, _stack_rows([fma(fma(a0 * h0, a1, h1), a2, h2)])


_compose_grads = blocked(_compose_bwd_entries, (2, 2, 2))


def _compose_jvp(saved: tuple[Tensor, ...], dA: Tensor, dB: Tensor) -> Tensor:
    A, B = saved
    top = torch.matmul(dA[..., :3, :3], B[..., :3, :])
    top = top + torch.matmul(A[..., :3, :3], dB[..., :3, :])
    top.select(-1, 3).add_(dA[..., :3, 3])
    return _pad_row(top)


_ComposeFn = CustomFunction(
    "Se3Compose",
    forward=_compose_entries,
    save=lambda inputs, out: (inputs[0], inputs[1]),
    backward=_compose_bwd,
    jvp=_compose_jvp,
    event_dims=(2, 2),
)


def compose(A: Tensor, B: Tensor) -> Tensor:
    """``A B`` (batch shapes broadcast; the bottom rows are not read)."""
    return _ComposeFn(A, B)


def _inverse_bwd(saved: tuple[Tensor, ...], G: Tensor) -> tuple[Tensor]:
    (T,) = saved
    return (_inverse_grads(T, G),)


def _inverse_bwd_entries(T: Tensor, G: Tensor) -> Tensor:
    """The backward of ``T^-1`` from the blocks entries first (``out = [R^T, -R^T t]``):
    ``dR_ij = G_ji - t_i G_j3``, ``dt_i = -sum_j R_ij G_j3`` (the sum over the columns of ``R``,
    each term a column broadcast against an entry of ``G``'s last column, negated as it enters)."""
    x, g = _top(T), _top(G)
    g3 = g[:, 3]
    dR = fma(g[:, :3].transpose(0, 1), x[:, 3].unsqueeze(1), g3.unsqueeze(0), value=-1.0)
    c0, c1, c2 = x[:, :3].unbind(1)  # columns of R: (3, *batch)
    g03, g13, g23 = g3.unbind(0)
    dt = fma(fma(c0 * torch.neg(g03), c1, g13, value=-1.0), c2, g23, value=-1.0)
    return _stack_rows((dR, dt.unsqueeze(1)))


_inverse_grads = blocked(_inverse_bwd_entries, (2, 2))


def _inverse_jvp(saved: tuple[Tensor, ...], dT: Tensor) -> Tensor:
    (T,) = saved
    dRt = dT[..., :3, :3].transpose(-1, -2)
    Rt = T[..., :3, :3].transpose(-1, -2)
    dt = torch.matmul(dRt, T[..., :3, 3:]) + torch.matmul(Rt, dT[..., :3, 3:])
    return _pad_row(torch.cat((dRt, -dt), dim=-1))


_InverseFn = CustomFunction(
    "Se3Inverse",
    forward=_inverse_entries,
    save=lambda inputs, out: (inputs[0],),
    backward=_inverse_bwd,
    jvp=_inverse_jvp,
    event_dims=(2,),
)


def inverse(T: Tensor) -> Tensor:
    """``T^-1 = [[R^T, -R^T t], [0, 1]]``."""
    return _InverseFn(T)


def _homogeneous(p: Tensor) -> Tensor:
    return torch.nn.functional.pad(p, (0, 1), value=1.0)


def _act_fwd(T: Tensor, p: Tensor) -> Tensor:
    """``R p + t``, column by column (as :func:`torchlie.so3.act`, then ``t``)."""
    return mv(T[..., :3, :], p)


def _act_grads(T: Tensor, p: Tensor, g: Tensor) -> tuple[Tensor, Tensor]:
    # out = [R, t] (p, 1): d[R, t] = g (p, 1)^T and dp = R^T g.
    dT = _pad_row(g.unsqueeze(-1) * _homogeneous(p).unsqueeze(-2))
    return dT, mtv(T[..., :3, :3], g)


_act_grads_blocked = blocked(_act_grads, (2, 1, 1))


def _act_bwd(saved: tuple[Tensor, ...], g: Tensor) -> tuple[Tensor, Tensor]:
    T, p = saved
    dT, dp = _act_grads_blocked(T, p, g)
    return dT.sum_to_size(T.shape), dp.sum_to_size(p.shape)


def _act_jvp(saved: tuple[Tensor, ...], dT: Tensor, dp: Tensor) -> Tensor:
    T, p = saved
    out = torch.matmul(dT[..., :3, :], _homogeneous(p).unsqueeze(-1))
    return (out + torch.matmul(T[..., :3, :3], dp.unsqueeze(-1))).squeeze(-1)


_ActFn = CustomFunction(
    "Se3Act",
    forward=_act_fwd,
    save=lambda inputs, out: (inputs[0], inputs[1]),
    backward=_act_bwd,
    jvp=_act_jvp,
    event_dims=(2, 1),
)


def act(T: Tensor, p: Tensor) -> Tensor:
    """``R p + t`` (batch shapes broadcast)."""
    return _ActFn(T, p)


# ----------------------------------------------------------------------------------------------
# exp / log
# ----------------------------------------------------------------------------------------------


def _exp_forward(xi: Tensor) -> Tensor:
    """``[[Exp(phi), Jl(phi) rho], [0, 1]]`` from components, one set of coefficients for both
    blocks (runs without autograd: forward-only coefficients); the rotation block is
    :func:`torchlie.so3.exp`'s, bit for bit.  The angle reduced first where it is too large for
    the formulas (:func:`_reduction`, on planes: one fused loop while compiling)."""
    x = planes(xi, 6)
    x = _reduction(_coeffs.reduction_planes(x[3:]), x, None)
    xyz, (a, b, c, d) = _rodrigues.coefficients(x[3:], "abcd")
    o, top = _top_outputs(xyz[0])
    R = _rodrigues.exp_entries(xyz, a, b, d, [e for row in top for e in row[:3]])
    t = _rodrigues.jl_components(xyz, x[:3], a, b, c, [r[3] for r in top])
    return _stack_top((*R[0:3], t[0], *R[3:6], t[1], *R[6:9], t[2]), out=o)


def _exp_grad(xi: Sequence[Tensor], T: Tensor, G: Tensor) -> list[Tensor]:
    # T = [[R, t], [0, 1]], R = Exp(phi), t = Jl(phi) rho.  With a left perturbation,
    # dt = (Q(rho, phi) - t^ Jl(phi)) dphi + Jl(phi) drho, so
    #     g_rho = Jr(phi) g_t,
    #     g_phi = Jl(phi) vee(R^T G_R - G_R^T R) + Jr(phi) (t x g_t) + Q(-rho, -phi) g_t.
    # on the planes of the guarded xi, to the guard's derivative as planes
    x = planes(xi, 6)
    xyz = x[3:]
    # coefficients that differentiate under create_graph
    (a, b, c), qc = _se3_jacobian.jl_and_q_coefficients(xyz, "abc", torch.is_grad_enabled())
    R, t = _rotation_and_translation(T)
    G_R, g_t = _rotation_and_translation(G)
    # Jr g_t, Jl vee(R^T G_R - G_R^T R) and Jr (t x g_t), Jr's b negated (Jr(phi) = Jl(-phi))
    vs = (g_t, rt_g_vee(R, G_R), cross_planes(t, g_t))
    nb = -b
    g_rho, g_phi, g_tx = (
        _rodrigues.jl_components(xyz, v, a, bi, c) for v, bi in zip(vs, (nb, b, nb), strict=True)
    )
    neg = [-v for v in x]
    q = _se3_jacobian.q_components(neg[:3], neg[3:], g_t, *qc)
    g_phi = [torch.add(p, r).add_(s) for p, r, s in zip(g_phi, g_tx, q, strict=True)]
    return [*g_rho, *g_phi]


def _exp_jvp(saved, dxi: Tensor) -> Tensor:
    # dT = [[e_phi^ R, e_phi^ t + e_rho], [0, 0]] with (e_rho, e_phi) = J_left(xi) dxi.
    xi, T = saved
    rho, phi = xi[..., :3], xi[..., 3:]
    e_phi = _rodrigues.jl_apply(phi, dxi[..., 3:])
    e_rho = _rodrigues.jl_apply(phi, dxi[..., :3]) + _se3_jacobian.q_apply(rho, phi, dxi[..., 3:])
    dR = hat(e_phi) @ T[..., :3, :3]
    dt = torch.linalg.cross(e_phi, T[..., :3, 3], dim=-1) + e_rho
    return _pad_row(torch.cat((dR, dt.unsqueeze(-1)), dim=-1))


def _reduction(
    f: tuple[Tensor, Tensor, Sequence[Tensor]],
    t: Sequence[Tensor],
    along_phi: Sequence[Tensor] | None,
) -> list[Tensor]:
    """``(P t_rho, lam t_phi + (1 - lam) u (u . along_phi))`` where the angle is reduced, ``t``
    elsewhere (6 planes), with ``lam``, ``u`` and ``P = lam I + (1 - lam) u u^T`` of a twist's
    angle (``f``: :func:`torchlie._coeffs.reduction_planes` of its ``phi``); ``along_phi``
    None: ``lam t_phi``.

    ``Jl(phi) = lam Jl(phi') + (1 - lam) u u^T`` and ``Jl(phi') u = u``, so
    ``Jl(phi) rho = Jl(phi') P rho``: the twist ``(P rho, lam phi)`` has the same ``Exp`` as
    ``xi``, and ``P`` on both halves (``along_phi = t_phi``) is its derivative.
    """
    return _coeffs.reduce_planes(f, t[:3], t[:3]) + _coeffs.reduce_planes(f, t[3:], along_phi)


def _guard(xi: Tensor) -> tuple[list[Tensor], Callable[..., Tensor]]:
    """:func:`_reduction` of ``xi`` itself, as planes (with its derivative ``P`` under
    autograd), and that derivative, ``P`` on both halves, as a function of a tangent (a tensor
    or its planes)."""
    x = xi.unbind(-1)
    f = _coeffs.reduction_planes(x[3:])
    graph = torch.is_grad_enabled() and xi.requires_grad
    along = [c - c.detach() for c in x[3:]] if graph else None  # an exact 0: derivative 1

    def derivative(t: Tensor | Sequence[Tensor]) -> Tensor:
        tt = planes(t, 6)
        return _layout.interleave(_reduction(f, tt, tt[3:]))

    return _reduction(f, x, along), derivative


_ExpMapFn = CustomFunction(
    "Se3Exp",
    forward=_exp_forward,
    save=lambda inputs, out: (inputs[0], out),
    backward=lambda saved, G: (_exp_grad(*saved, G),),
    jvp=_exp_jvp,
    event_dims=(1,),
    guard=_guard,
)


def exp(xi: Tensor) -> Tensor:
    """``Exp(xi)``."""
    return _ExpMapFn(xi)


def _log_forward(T: Tensor) -> Tensor:
    """From components, stacked once.  ``Jl(phi)^-1 t`` with the coefficients
    ``e = (theta/2) cot(theta/2)`` and ``D = (1 - e) / theta^2`` from the log's own angle and
    cotangent (:func:`torchlie._rotation_matrix.log_and_cot`)."""
    R, t = _rotation_and_translation(T)  # one transposition of the top block
    phi, theta, e = _rotation_matrix.log_and_cot(R, cot=True)
    d = torch.rsub(e, 1.0).div_(theta.mul_(theta).clamp_min_(_coeffs.H_MIN[T.dtype]))
    rho = _rodrigues.jl_components(phi, t, e, e.new_full((), -0.5), d)
    return _layout.interleave((*rho, *phi))


def _log_grad(T: Tensor, xi: Tensor, g: Tensor) -> Tensor:
    # d xi = Jr(xi)^-1 (R^T dt, vee(R^T dR)) along the tangent directions (zero along the
    # normal ones).  With h = Jr(xi)^-T g and A = so3 Jl(phi):
    #     Jr(xi)^-T = [[A^-1, 0], [-A^-1 Q A^-1, A^-1]]   (Q = Q(rho, phi) = Q(-rho, -phi)^T),
    # so G_t = R h_rho and G_R = R hat(h_phi) / 2.
    x = planes(xi, 6)
    gs = planes(g, 6)
    # coefficients that differentiate under create_graph
    graph = torch.is_grad_enabled()
    (e, f), qc = _se3_jacobian.jl_and_q_coefficients(x[3:], "ef", graph)
    minus_half = e.new_full((), -0.5)
    h_rho = _rodrigues.jl_components(x[3:], gs[:3], e, minus_half, f)
    q = _se3_jacobian.q_components(x[:3], x[3:], h_rho, *qc)
    v = [(gi - qi).mul_(0.5) for gi, qi in zip(gs[3:], q, strict=True)]
    u = _rodrigues.jl_components(x[3:], v, e, minus_half, f)  # h_phi / 2
    # G_R's rows R_i x u and G_t's entries R_i . h_rho for all rows at once, from the block
    # entries first (each term a column of R broadcast against an entry of u or h_rho)
    r0, r1, r2 = _top(T)[:, :3].unbind(1)  # columns of R: (3, *batch)
    u0, u1, u2 = u
    G_R = (
        fma(r1 * u2, r2, u1, value=-1.0),
        fma(r2 * u0, r0, u2, value=-1.0),
        fma(r0 * u1, r1, u0, value=-1.0),
    )
    G_t = fma(fma(r0 * h_rho[0], r1, h_rho[1]), r2, h_rho[2])
    G = _stack_rows([c.unsqueeze(1) for c in (*G_R, G_t)])
    if graph:  # differentiated: the gradient off SO(3) too (so3._log_grad), R -> R (I - E / 2)
        R = T[..., :3, :3]
        E = gram_defect(R)
        terms = polar_backward_terms(R, hat(torch.stack(u, dim=-1)), E)
        t = 0.5 * (R @ (E @ torch.stack(h_rho, dim=-1).unsqueeze(-1)))
        G = G - torch.nn.functional.pad(torch.cat((terms, t), dim=-1), (0, 0, 0, 1))
    return G


_log_grad_blocked = blocked(_log_grad, (2, 1, 1))


def _log_jvp(saved, dT: Tensor) -> Tensor:
    # with R^T read as polar(R)^T = (I - E / 2) R^T and the rotation's tangent as that of the
    # polar factor (so3._log_jvp), to first order off SO(3)
    T, xi = saved
    R = T[..., :3, :3]
    E = gram_defect(R)
    t = mtv(R, dT[..., :3, 3])
    t = t - 0.5 * (E @ t.unsqueeze(-1)).squeeze(-1)
    v = torch.cat((t, polar_tangent(R.transpose(-1, -2) @ dT[..., :3, :3], E)), dim=-1)
    return _se3_jacobian.jl_inv_apply(-xi, v)  # Jr(xi)^-1 v


_LogFn = CustomFunction(
    "Se3Log",
    forward=_log_forward,
    save=lambda inputs, out: (inputs[0], out),
    backward=lambda saved, g: (_log_grad_blocked(*saved, g),),
    jvp=_log_jvp,
    event_dims=(2,),
)


def log(T: Tensor) -> Tensor:
    """``Log(T)`` (the bottom row is not read)."""
    return _LogFn(T)
