"""Error-free transforms, and the float64 kernel of :func:`torchlie.so3.exp` built on them.

In float64 the plain Rodrigues formula is a few ulp off near pi: there ``sin(theta)`` and
``cos(theta/2)`` have slope 1, so the rounding of ``theta^2`` and of its square root (up to
~2 ulp of theta) passes unchanged into the entries, and the diagonal ``1 - B (y^2 + z^2)`` rounds
a sum near 2.  :func:`exp` removes both:

* ``theta^2`` is summed exactly (Veltkamp/Dekker squares, TwoSum) and ``theta = t + t_lo`` is
  carried as an unevaluated sum; sin/cos of the half angle ``h`` take the first-order correction
  ``sin(h + d) = sin h + d cos h``;
* ``g = sin(h)/theta`` carries the residual of its division (TwoProduct); ``B/2 = g^2``,
  ``A/2 = g cos h`` and ``cos^2 h`` are each rounded once;
* diagonal ``cos^2 h + (B/2)(w_i^2 - w_j^2 - w_k^2)`` (two terms bounded by 1); off-diagonal
  ``B w_i w_j -+ A w_k`` with ``A w_k`` exact, so each entry is rounded about once relative to
  its own size (``so3.log`` reads small angles from them).

Measured over the test sweep (13 angles x 218 axes, 60-digit references): 2.4e-16 norm-wise
relative error against 6.8e-16 for the plain formula.  The price is the number of kernels:
about 140 element-wise operations with fused products (244 with split ones) against 47 for the
plain formula, which decides the time at small batches.  No series: at ``w = 0`` the result
is exactly the identity.

Values only: these run in the forward pass of the custom autograd Function (and never under
autograd).  In-place operations act on fresh temporaries, on the operand that depends on every
input (valid under ``torch.func.vmap``).  The exact error of a product comes from a fused
multiply-add where one is known to round once: ``torch.addcmul`` on the CPU in eager mode, if a
probe at import finds it fused (:data:`FUSED_CPU`; contiguous and strided operands).  Elsewhere
(compiled code, other devices) products are split (Veltkamp, ``2**27 + 1``), which assumes no
floating-point contraction: true for the eager kernels and Inductor's C++ backend (compiled with
``-ffp-contract=off``).  Both give the exact error, so the results are the same bits; where a
backend contracts (Triton fuses multiply-adds), the transforms lose their low parts and the
result falls back to about the plain formula's accuracy.  Range: ``|w|`` up to ~1e150 (the
squares overflow above, as in the plain formula).
"""

from __future__ import annotations

import torch
from torch import Tensor

from . import _layout
from . import quaternion as _quat

_SPLITTER = 134217729.0  # 2**27 + 1
_T_COMPENSATED = 1e4


def _probe_fused_cpu() -> bool:
    """Whether ``torch.addcmul`` on float64 CPU tensors rounds ``c + a b`` once."""
    a = torch.full((67,), 1.0 + 2.0**-30, dtype=torch.float64)
    b = torch.full((67,), 1.0 - 2.0**-30, dtype=torch.float64)
    p = a * b  # 1 - 2^-60 rounds to 1
    want = torch.full((67,), -(2.0**-60), dtype=torch.float64)
    views = (slice(None), slice(None, None, 2), slice(0, 1))
    vec_ok = all(torch.equal(torch.addcmul(-p[v], a[v], b[v]), want[v]) for v in views)
    at = a.reshape(1, 67).expand(3, 67).t()  # non-contiguous 2-D operand
    sq = torch.addcmul(-(at * at), at, at)  # (1 + 2^-30)^2 - fl(.) = 2^-60
    return vec_ok and torch.equal(sq, torch.full((67, 3), 2.0**-60, dtype=torch.float64))


#: ``torch.addcmul`` is a fused multiply-add on this CPU (probed at import).
FUSED_CPU = _probe_fused_cpu()


def _fused(x: Tensor) -> bool:
    """Take exact product errors from ``torch.addcmul`` for ``x``'s device (eager CPU only)."""
    return FUSED_CPU and x.device.type == "cpu" and not torch.compiler.is_compiling()


def _split(a: Tensor) -> tuple[Tensor, Tensor]:
    """``a = hi + lo`` exactly, each with at most 26 significant bits."""
    c = a * _SPLITTER
    hi = c.sub_(c - a)
    return hi, a - hi


def _two_prod(a: Tensor, b: Tensor, sa=None, sb=None, fused: bool = False):
    """``a * b = p + e`` exactly; ``sa``/``sb`` are splits already computed (split path)."""
    p = a * b
    if fused:
        return p, torch.addcmul(p.neg(), a, b)
    ah, al = _split(a) if sa is None else sa
    bh, bl = _split(b) if sb is None else sb
    e = (ah * bh).sub_(p).add_(ah * bl).add_(al * bh).add_(al * bl)
    return p, e


def _two_sqr(a: Tensor, sa=None, fused: bool = False) -> tuple[Tensor, Tensor]:
    """``a * a = p + e`` exactly."""
    p = a * a
    if fused:
        return p, torch.addcmul(p.neg(), a, a)
    ah, al = _split(a) if sa is None else sa
    e = (ah * ah).sub_(p).add_((ah * al).mul_(2.0)).add_(al * al)
    return p, e


def _two_sum(a: Tensor, b: Tensor) -> tuple[Tensor, Tensor]:
    """``a + b = s + e`` exactly (any magnitudes)."""
    s = a + b
    bb = s - a
    e = (s - bb).neg_().add_(a).add_(bb.neg_().add_(b))
    return s, e


def _sqr_round(a: Tensor, a_lo: Tensor, sa=None, fused: bool = False) -> Tensor:
    """``(a + a_lo)^2`` rounded once (first order in ``a_lo``)."""
    p, e = _two_sqr(a, sa, fused)
    return p.add_(e.add_((2.0 * a).mul_(a_lo)))


def _mul_lo(a: Tensor, a_lo: Tensor, v: Tensor, sa=None, fused: bool = False):
    """``(a + a_lo) v = p + lo``: ``p = fl(a v)``, ``lo`` its exact error plus ``a_lo v``."""
    p, e = _two_prod(a, v, sa, None, fused)
    return p, e.add_(a_lo * v)


def _theta2(x: Tensor, y: Tensor, z: Tensor, fused: bool = False):
    """Rounded squares and ``theta^2 = S + S_lo`` (exact to ~eps^2)."""
    xx, exx = _two_sqr(x, None, fused)
    yy, eyy = _two_sqr(y, None, fused)
    zz, ezz = _two_sqr(z, None, fused)
    s1, e1 = _two_sum(xx, yy)
    S, e2 = _two_sum(s1, zz)
    S_lo = e1.add_(e2).add_(exx.add_(eyy).add_(ezz))
    return xx, yy, zz, S, S_lo


def _half(S: Tensor, S_lo: Tensor, fused: bool = False):
    """``(Ss, g, g_lo, ch, ch_lo)`` for ``theta^2 = S + S_lo``.

    ``Ss`` = ``S`` (1 at ``theta = 0``), ``g + g_lo = sin(theta/2)/theta`` (1/2 at 0),
    ``ch + ch_lo = cos(theta/2)`` (first order in the low part of theta).
    """
    pos = (S > 0).to(S.dtype)  # NaN -> 0; Ss stays NaN
    Ss = (1.0 - pos).add_(S)
    t = Ss.sqrt()
    st = None if fused else _split(t)
    P, E = _two_sqr(t, st, fused)
    tlo = (Ss - P).sub_(E).add_(S_lo).div_(2.0 * t)
    del P, E
    # The first-order corrections below need |tlo| << 1.  Beyond theta ~ 1e4 the angle modulo
    # 2 pi is known to less than an ulp of theta anyway: drop the low part there (plain form).
    tlo.mul_((t < _T_COMPENSATED).to(t.dtype))
    h = (0.5 * t).mul_(pos)  # 0 at theta = 0: sin h = 0, cos h = 1
    hlo = 0.5 * tlo
    sh, ch = torch.sin(h), torch.cos(h)
    del h
    sh_lo = ch * hlo
    ch_lo = (sh * hlo).neg_()
    del hlo
    g = sh / t
    p, e = _two_prod(g, t, None, st, fused)
    g_lo = (sh - p).sub_(e).add_(sh_lo.sub_(g * tlo)).div_(t)
    g.add_(pos.neg_().add_(1.0).mul_(0.5))
    return Ss, g, g_lo, ch, ch_lo


def exp(w: Tensor, fused: bool | None = None, dest: Tensor | None = None) -> Tensor:
    """Rotation matrix of the rotation vector ``w``: ``(..., 3)`` -> ``(..., 3, 3)``, float64.

    The entries of :func:`exp_entries`, stacked (into ``dest`` if given).
    """
    return _layout.interleave(exp_entries(w, fused), dest=dest).unflatten(-1, (3, 3))


def exp_entries(w: Tensor, fused: bool | None = None) -> list[Tensor]:
    """The 9 entries (row by row) of the rotation matrix of ``w`` (float64, compensated).

    ``R_ii = cos^2(h) + (B/2)(w_i^2 - w_j^2 - w_k^2)``, ``R_ij = B w_i w_j -+ A w_k`` with
    ``h = theta/2``, ``A = sin(theta)/theta = 2 g cos h``, ``B = (1 - cos theta)/theta^2 = 2 g^2``,
    ``g = sin(h)/theta``.  ``A`` is a double-double and ``A w_k`` exact (TwoProduct), so each
    off-diagonal entry is rounded about once relative to its own size: ``so3.log`` of the result
    reads ``theta`` from them, and at small angles its relative error is theirs.

    ``fused``: exact product errors from ``torch.addcmul`` (default: :func:`_fused`) or from
    Veltkamp splits; the result is the same either way.
    """
    if fused is None:
        fused = _fused(w)
    x, y, z = _quat._planes(w, 3)
    xx, yy, zz, S, S_lo = _theta2(x, y, z, fused)
    _, g, g_lo, ch, ch_lo = _half(S, S_lo, fused)
    del S, S_lo
    sg, sc = (None, None) if fused else (_split(g), _split(ch))
    bh = _sqr_round(g, g_lo, sg, fused)  # B/2
    p, e = _two_prod(g, ch, sg, sc, fused)  # A/2 = g cos h = p + e + ...
    a_lo = e.add_((g_lo * ch).add_(g * ch_lo)).mul_(2.0)
    a = p.mul_(2.0)
    c2 = _sqr_round(ch, ch_lo, sc, fused)  # cos^2 h
    del g, g_lo, ch, ch_lo, sg, sc, e
    b = 2.0 * bh
    bx = b * x
    by = b.mul_(y)
    bxy = bx * y
    bxz = bx.mul_(z)
    byz = by.mul_(z)
    sa = None if fused else _split(a)
    ax, ax_lo = _mul_lo(a, a_lo, x, sa, fused)
    ay, ay_lo = _mul_lo(a, a_lo, y, sa, fused)
    az, az_lo = _mul_lo(a, a_lo, z, sa, fused)
    del a, a_lo, sa
    r01 = (bxy - az).sub_(az_lo)
    r10 = bxy.add_(az).add_(az_lo)
    r02 = (bxz + ay).add_(ay_lo)
    r20 = bxz.sub_(ay).sub_(ay_lo)
    r12 = (byz - ax).sub_(ax_lo)
    r21 = byz.add_(ax).add_(ax_lo)
    del ax, ay, az, ax_lo, ay_lo, az_lo
    d0 = (xx - yy).sub_(zz).mul_(bh).add_(c2)
    d1 = (yy - xx).sub_(zz).mul_(bh).add_(c2)
    d2 = zz.sub_(xx).sub_(yy).mul_(bh).add_(c2)
    return [d0, r01, r02, r10, d1, r12, r20, r21, d2]
