"""The one home of every small-angle and near-singular series in torchlie.

Every coefficient is a function of ``t2 = theta**2`` (never of ``theta``), so that it is smooth
at 0 to every order.  Each is evaluated with the *double where* pattern: the exact formula is fed
a safe argument wherever the series branch is taken, so the branch not taken produces no
Inf/NaN in the forward pass **or** in any backward pass.  Thresholds come from the dtype's
machine epsilon: the series is used where its first omitted term is below epsilon (relative), and
the exact formula is written so that it does not cancel catastrophically above the threshold.

Notation (theta = rotation angle):

=================  ==============================================  =========================
name               value                                            series at 0
=================  ==============================================  =========================
``sinc``           sin(t) / t                                       1 - t2/6 + ...
``cosc``           (1 - cos t) / t2                                 1/2 - t2/24 + ...
``sinc3``          (t - sin t) / t**3                               1/6 - t2/120 + ...
``cosc4``          (t2/2 + cos t - 1) / t2**2                       1/24 - t2/720 + ...
``q3``             (2t - 3 sin t + t cos t) / (2 t**5)              1/120 - 2 t2/7! + ...
``jinv``           (1 - (t/2) cot(t/2)) / t2                        1/12 + t2/720 + ...
``atan_ratio``     atan2(n, w) / n  (for n >= 0)                    (1/w)(1 - (n/w)**2/3 + ...)
=================  ==============================================  =========================

Forward-only evaluations (``*_values``) serve the forward passes of the custom autograd Functions
and their plain backward passes, which run without autograd: there no branch needs to be safe to
differentiate, so a clamp of the half angle replaces the series and its ``where`` (``sin(h)/h`` is
exact to rounding for every ``h > 0``, and equals 1 for the clamped value).  They must not be
differentiated: under ``create_graph`` the same formulas take the series (:func:`rodrigues`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import torch
from torch import Tensor

from . import _layout
from ._autograd import Guard, fma, needs_graph, transforms_active
from ._components import planes

# --------------------------------------------------------------------------------------------
# Series coefficients (exact rationals, converted to float once).
# --------------------------------------------------------------------------------------------


def _alt_factorial_series(offset: int, n: int) -> list[float]:
    """Coefficients of sum_k (-1)^k t2^k / (2k + offset)!."""
    return [(-1) ** k / math.factorial(2 * k + offset) for k in range(n)]


_N_MAX = 12
_SINC = _alt_factorial_series(1, _N_MAX)
_COSC = _alt_factorial_series(2, _N_MAX)
_SINC3 = _alt_factorial_series(3, _N_MAX)
_COSC4 = _alt_factorial_series(4, _N_MAX)
#: (2t - 3 sin t + t cos t)/(2 t^5) = sum_k (-1)^k (k + 1) t2^k / (2k + 5)!
_Q3 = [(-1) ** k * (k + 1) / math.factorial(2 * k + 5) for k in range(_N_MAX)]
_ATAN = [(-1) ** k / (2 * k + 1) for k in range(_N_MAX)]
#: (1/n) d/dn [atan2(n, w)/n] w^3 = sum_k (-1)^(k+1) (2k + 2)/(2k + 3) (n/w)^(2k)
_ATAN_SLOPE = [(-1) ** (k + 1) * (2 * k + 2) / (2 * k + 3) for k in range(_N_MAX)]

# Number of series terms per function: (float32, float64).  Enough that the series reaches
# t2 where the exact formula is accurate again, in its value and in its derivatives (autograd
# differentiates it term by term): sin(t)/t's derivatives cancel as eps / t2 and eps / t2^2
# though its value does not (a switch at t2 = 1e-4 would leave the Jacobians' derivatives
# hundreds of ulp off), and sinc3, cosc4, q3 cancel in their values too.  Only the
# differentiable evaluations (double where) use these; the forward-only ones clamp instead.
_TERMS = {
    "sinc": (6, 10),
    "cosc": (6, 10),
    "atan": (4, 5),
    # evaluated where the atan series is (its threshold is larger than atan's)
    "atan_slope": (5, 6),
    "sinc3": (5, 9),
    "cosc4": (6, 11),
    "q3": (6, 11),
}
_SERIES = {
    "sinc": _SINC,
    "cosc": _COSC,
    "atan": _ATAN,
    "atan_slope": _ATAN_SLOPE,
    "sinc3": _SINC3,
    "cosc4": _COSC4,
    "q3": _Q3,
}


def _make_plan(name: str, dtype: torch.dtype) -> tuple[tuple[float, ...], float]:
    """Series coefficients used and the t2 threshold below which the series and its first
    derivative are exact to eps: the first omitted term ``c_n t2^n`` below ``eps |c_0|`` and its
    derivative ``n c_n t2^(n - 1)`` below ``eps |c_1|``."""
    n = _TERMS[name][1 if dtype == torch.float64 else 0]
    c = _SERIES[name]
    eps = torch.finfo(dtype).eps
    value = (eps * abs(c[0]) / abs(c[n])) ** (1.0 / n)
    slope = (eps * abs(c[1]) / (n * abs(c[n]))) ** (1.0 / (n - 1))
    return tuple(c[:n]), min(value, slope)


# Precomputed once: plain dict look-ups trace cleanly under torch.compile.
_PLANS = {
    (name, dtype): _make_plan(name, dtype)
    for name in _TERMS
    for dtype in (torch.float16, torch.bfloat16, torch.float32, torch.float64)
}


def _plan(name: str, dtype: torch.dtype) -> tuple[tuple[float, ...], float]:
    return _PLANS[(name, dtype)]


def threshold(name: str, dtype: torch.dtype) -> float:
    """The t2 (= theta**2) threshold of a coefficient for ``dtype`` (for tests and docs)."""
    return _plan(name, dtype)[1]


def _horner(t2: Tensor, coeffs: tuple[float, ...]) -> Tensor:
    acc = torch.full_like(t2, coeffs[-1])
    for c in coeffs[-2::-1]:
        acc = acc * t2 + c
    return acc


def _series_where(name: str, t2: Tensor, exact) -> Tensor:
    coeffs, thr2 = _plan(name, t2.dtype)
    small = t2 < thr2
    safe = torch.where(small, torch.ones_like(t2), t2)
    # each branch sees only its own arguments (a large t2's powers overflow in the series)
    tiny = torch.where(small, t2, torch.zeros_like(t2))
    return torch.where(small, _horner(tiny, coeffs), exact(safe))


# --------------------------------------------------------------------------------------------
# Coefficient functions of t2 = theta**2
# --------------------------------------------------------------------------------------------


def sinc(t2: Tensor) -> Tensor:
    """sin(theta)/theta."""

    def exact(s: Tensor) -> Tensor:
        t = s.sqrt()
        return torch.sin(t) / t

    return _series_where("sinc", t2, exact)


def cosc(t2: Tensor) -> Tensor:
    """(1 - cos(theta))/theta**2, computed as 2 sin(theta/2)**2 / theta**2 (no cancellation)."""

    def exact(s: Tensor) -> Tensor:
        h = 0.5 * s.sqrt()
        r = torch.sin(h) / h
        return 0.5 * r * r

    return _series_where("cosc", t2, exact)


def sinc3(t2: Tensor) -> Tensor:
    """(theta - sin(theta))/theta**3."""

    def exact(s: Tensor) -> Tensor:
        t = s.sqrt()
        return (t - torch.sin(t)) / (s * t)

    return _series_where("sinc3", t2, exact)


def cosc4(t2: Tensor) -> Tensor:
    """(theta**2/2 + cos(theta) - 1)/theta**4  ( = (1/2 - cosc)/theta**2 )."""

    def exact(s: Tensor) -> Tensor:
        h = 0.5 * s.sqrt()
        r = torch.sin(h) / h
        return (0.5 - 0.5 * r * r) / s

    return _series_where("cosc4", t2, exact)


def q3(t2: Tensor, c1: Tensor | None = None) -> Tensor:
    """(2 theta - 3 sin(theta) + theta cos(theta))/(2 theta**5), the third coefficient of the
    SE(3) Jacobian's ``Q`` block, as ``(3 sinc3 - cosc)/(2 theta**2)``: above the series the
    difference loses at most a factor 2 (``3 sinc3 >= 2 cosc`` there), at every angle.
    ``c1``: ``sinc3(t2)`` if the caller has it (the branch not taken reads it, finite)."""

    def exact(s: Tensor) -> Tensor:
        return (3.0 * (sinc3(s) if c1 is None else c1) - cosc(s)) / (2.0 * s)

    return _series_where("q3", t2, exact)


def jinv(t2: Tensor) -> Tensor:
    """(1 - (theta/2) cot(theta/2))/theta**2, the hat(w)^2 coefficient of the inverse Jacobians.

    Composed as (sinc3 - 2 cosc4) / (2 cosc), whose pieces are each accurate, so no extra
    cancellation enters.  Finite on [0, 2*pi); in particular jinv(pi**2) = 1/pi**2.
    """
    return (sinc3(t2) - 2.0 * cosc4(t2)) / (2.0 * cosc(t2))


def angle(y: Tensor, x: Tensor) -> Tensor:
    """The value of ``torch.atan2(y, x)`` (no derivative), the same for an element whatever
    the batch around it: ``atan(y / x)``, plus ``pi`` with the sign of ``y`` where ``x`` is
    negative (``-0`` included).

    torch's ``atan2`` rounds some elements differently in its vectorised and scalar loops (by
    an ulp, between a batch and the element alone), which the Jacobians and interpolations
    built on the log maps amplify past two ulps of their results; division and ``atan`` round
    alike in both loops.  Within about one ulp of the true angle
    (``y / x`` rounds relatively, and ``atan`` is well conditioned; ``x = 0`` gives
    ``+-pi/2`` through ``atan(+-inf)``); signed zeros as ``torch.atan2``, exactly ``pi`` for
    ``(+0, x < 0)``.  ``(0, 0)`` and two infinities give NaN: callers guard them."""
    t = torch.atan(y / x)
    pi = _layout.constant((math.pi,), t)[0]  # 0-dim: the result keeps the operands' shape
    return torch.where(torch.signbit(x), t + torch.copysign(pi, y), t)


def atan2(y: Tensor, x: Tensor) -> Tensor:
    """``atan2(y, x)`` with the value of :func:`angle` (the same whatever the batch) and the
    derivatives of ``torch.atan2`` (the true ones, ``x / r^2`` and ``-y / r^2``, at every
    point, on the axes and the diagonals included, and of every order), except at ``(0, 0)``,
    where the value is ``atan2(y, 1)`` (a signed zero) and the gradient 0 (double where).

    The derivatives ride on the value as ``angle - (t.detach() - t)`` with ``t`` torch's
    ``atan2`` (``+0`` in value, so signed zeros are kept); that term is taken only where
    autograd, a transform or the compiler may differentiate.
    """
    origin = (x == 0) & (y == 0)
    x = torch.where(origin, torch.ones_like(x), x)
    if torch.compiler.is_compiling() or transforms_active() or needs_graph((y, x)):
        t = torch.atan2(y, x)
        return angle(y.detach(), x.detach()) - (t.detach() - t)
    return angle(y, x)


def atan_small(n: Tensor, w: Tensor) -> Tensor:
    """Where :func:`atan_ratio` takes its series: ``w > 0`` and ``n / w`` small (found without
    dividing by ``w``)."""
    return (w > 0) & (n * n < _plan("atan", n.dtype)[1] * (w * w))


def atan_ratio(n: Tensor, w: Tensor) -> Tensor:
    """atan2(n, w)/n for n >= 0: the angle of a quaternion over the norm of its vector part.

    Smooth at n = 0 when w > 0 (value 1/w).  At n = 0 with w <= 0 the value is infinite; the
    result there is replaced by 0 (the caller decides what the singular point means).  The
    series branch is selected without dividing by w, and only its own elements see ``n/w``, so
    no branch overflows in the backward pass (e.g. at w ~ 1e-17, n ~ 1: a rotation by pi).
    """
    small = atan_small(n, w)
    series = atan_ratio_series(n, w, small)
    ok = n > 0
    n_e = torch.where(small | ~ok, torch.ones_like(n), n)
    w_e = torch.where(small, torch.ones_like(w), w)
    exact = torch.where(ok, atan2(n_e, w_e) / n_e, torch.zeros_like(n))
    return torch.where(small, series, exact)


def atan_ratio_series(n: Tensor, w: Tensor, small: Tensor, name: str = "atan") -> Tensor:
    """Where ``small`` (of :func:`atan_small`): ``a = atan2(n, w)/n`` (``name`` ``"atan"``) or
    its slope ``c = (1/n) da/dn = (w/(n^2 + w^2) - a)/n^2`` (``"atan_slope"``; the exact form
    cancels there), as series in ``(n/w)^2``; elsewhere finite filler.  Smooth in ``n`` and
    ``w`` to every order."""
    w_s = torch.where(small, w, torch.ones_like(w))
    r2 = torch.where(small, n * n, torch.zeros_like(n)) / (w_s * w_s)
    out = _horner(r2, _plan(name, n.dtype)[0]) / w_s
    return out if name == "atan" else out / (w_s * w_s)


def cos_sqrt(t2: Tensor) -> Tensor:
    """cos(sqrt(t2)) to a few ulp at every t2 >= 0, with finite derivatives of all orders at 0.

    ``1 - t2 cosc(t2)`` below t2 = 1 (the subtraction loses at most one bit there, and the
    derivative at 0 is the series'), ``cos(sqrt(t2))`` above (accurate near pi/2, where the
    first form cancels); double where.
    """
    small = t2 < 1.0
    safe = torch.where(small, torch.ones_like(t2), t2)
    return torch.where(small, 1.0 - t2 * cosc(t2), torch.cos(safe.sqrt()))


def sqrt0(x: Tensor) -> Tensor:
    """sqrt(x) for x >= 0 with a zero (finite) gradient at 0; NaN stays NaN."""
    pos = x > 0
    return torch.where(pos, torch.where(pos, x, torch.ones_like(x)).sqrt(), x)


def norm(v: Tensor, keepdim: bool = False) -> Tensor:
    """Euclidean norm over the last dimension, at every finite magnitude, whose gradient at
    v = 0 is 0 (a subgradient) instead of NaN; NaN stays.

    From the squares of ``v / k`` (``k`` of :func:`rescaled`, detached: 1 where the squares of
    ``v`` neither overflow nor underflow, so the same bits there; 1 for the zero vector)."""
    k = _scale(v)
    k = torch.where(k == 0.0, 1.0, k)
    out = sqrt0(sum_squares(v / k, True)) * k
    return out if keepdim else out.squeeze(-1)


def sum_squares(v: Tensor, keepdim: bool = False) -> Tensor:
    """``sum_i v_i^2`` over the last dimension, component by component from the first (the
    same bits whatever the layout of ``v``; torch's reductions sum in an order that depends
    on it)."""
    acc = dot(v, v)
    return acc.unsqueeze(-1) if keepdim else acc


# --------------------------------------------------------------------------------------------
# Extreme magnitudes
# --------------------------------------------------------------------------------------------

#: Largest component magnitude, per dtype, of the rotation vectors the formulas above take as
#: they are (beyond it, :func:`reduction`).
_HUGE = {torch.float32: 2.0**60, torch.float64: 2.0**200}
#: Range of the largest component magnitude that :func:`rescaled` leaves as it is: the squared
#: norm and its powers up to ``+-3/2`` (in derivatives) are normal and finite.
_PLAIN = {torch.float32: (2.0**-30, 2.0**30), torch.float64: (2.0**-300, 2.0**300)}


#: the integer type of each float type's bits, and the mask of its exponent field
_EXPONENT_BITS = {
    torch.float32: (torch.int32, 0x7F800000),
    torch.float64: (torch.int64, 0x7FF0000000000000),
}


def power_of_two(m: Tensor) -> Tensor:
    """The power of two ``k <= m`` with ``m / k`` in ``[1, 2)`` for positive ``m`` (float32 or
    float64), ``k`` the smallest normal number where ``m`` is below it (0 included); infinite
    where ``m`` is not finite.  Read from the exponent field of ``m`` (no rounding, a few cheap
    element-wise operations): dividing by ``k`` is exact."""
    bits, mask = _EXPONENT_BITS[m.dtype]
    x = torch.clamp_min(m, torch.finfo(m.dtype).tiny).view(bits)
    if torch.compiler.is_compiling():
        return (x & mask).view(m.dtype)
    # in place on the clamp's own result, the mask a cached tensor (a Python int operand costs
    # torch more than the operation on a block of a batch)
    return x.bitwise_and_(_layout.constant(mask, x)).view(m.dtype)


def largest(v: Tensor | Sequence[Tensor]) -> Tensor:
    """``max_i |v_i|`` over the last dimension (kept, size 1) or over planes, detached.

    While compiling, element-wise, component by component (no reduction kernel of its own)."""
    if isinstance(v, Tensor):
        if not torch.compiler.is_compiling():
            return v.detach().abs().amax(-1, keepdim=True)
        return largest(v.unbind(-1)).unsqueeze(-1)
    m = v[0].detach().abs()
    for x in v[1:]:
        m = torch.maximum(m, x.detach().abs())
    return m


def rescaled(v: Tensor) -> tuple[Tensor, Tensor]:
    """``(v / k, k)`` with ``k = 1`` where the largest ``|v_i|`` lies within :data:`_PLAIN`
    (so ``v / k`` is ``v`` itself, bit for bit) and elsewhere ``k = max |v_i| / b``, ``b`` the
    nearer bound of that range (the largest ``|v_i / k|`` is then ``b``), over the last
    dimension (``k`` has it kept, size 1, and is detached).

    For the functions that are invariant to the scale of a quaternion, and for norms: the
    squares of ``v / k`` neither overflow nor underflow, so every finite non-zero ``v`` has a
    finite, accurate result.  A zero ``v`` gives ``k = 0`` and ``v / k`` NaN (no direction).
    While compiling, computed on the planes and stacked (one fused loop; the same values).
    """
    if not torch.compiler.is_compiling():
        k = _scale(v)
        return v / k, k
    x = v.unbind(-1)
    k = _scale(x)
    return torch.stack([c / k for c in x], dim=-1), k.unsqueeze(-1)


def rescaled_planes(v: Tensor, n: int) -> Sequence[Tensor]:
    """The planes of ``v / k`` of :func:`rescaled` (``n`` components, no autograd).

    In eager mode from the stack of ``v``'s planes (:func:`torchlie._layout.stacked`), whole:
    ``k`` from one maximum over its rows and one division of the stack (the values of the
    planes, bit for bit, in a few operations); while compiling element-wise on the planes (one
    fused loop)."""
    if torch.compiler.is_compiling():
        x = v.unbind(-1)
        k = _scale(x)
        return [c / k for c in x]
    S = _layout.stacked(v, n)
    return (S / _scale_of(S.abs().amax(0))).unbind(0)


def binary_planes(v: Tensor, n: int) -> Sequence[Tensor]:
    """The planes of ``v r`` (``n`` components, no autograd), ``r = 1 / (8 k)`` with ``k`` the
    power of two of the largest ``|v_i|`` (:func:`power_of_two`): the largest ``|v_i r|`` lies
    in ``[1/8, 1/4)`` (NaN for a zero ``v``, as :func:`rescaled`).

    For functions invariant to the scale of a quaternion whose arithmetic is exact under
    powers of two: the same bits as from ``v`` itself wherever no product underflows, and
    products with another operand (a point) that cannot overflow for the scale of ``v``.  In
    eager mode from the stack of ``v``'s planes, as :func:`rescaled_planes`; while compiling
    element-wise on the planes."""
    if torch.compiler.is_compiling():
        x = v.unbind(-1)
        r = _binary_factor(largest(x))
        return [c * r for c in x]
    S = _layout.stacked(v, n)
    return (S * _binary_factor(S.abs().amax(0))).unbind(0)


def _binary_factor(m: Tensor) -> Tensor:
    """``r = 1 / (8 k)`` of :func:`binary_planes` from the largest ``|v_i|``: a power of two
    (subnormal for the top binades of ``m``), so ``v r`` is exact, a subnormal ``v`` too."""
    k = power_of_two(m)
    return _layout.constant(0.125, k) / k


def _binary_guard(v: Tensor) -> tuple[Tensor, Callable[[Tensor], Tensor]]:
    if not torch.compiler.is_compiling():
        r = _binary_factor(largest(v))
        return v * r, lambda t: t * r
    x = v.unbind(-1)
    r = _binary_factor(largest(x))
    return (
        torch.stack([c * r for c in x], dim=-1),
        lambda t: torch.stack([c * r for c in t.unbind(-1)], dim=-1),
    )


#: :func:`binary_planes` as the guard of a custom Function (the derivative of ``v r`` is
#: ``r``).
BINARY: Guard = _binary_guard


def _scale(v: Tensor | Sequence[Tensor]) -> Tensor:
    """``k`` of :func:`rescaled` (of planes: a plane)."""
    return _scale_of(largest(v))


def _scale_of(m: Tensor) -> Tensor:
    """``k`` of :func:`rescaled` from the largest ``|v_i|``: ``m / clamp(m)``, exactly 1 within
    the range (two cheap element-wise operations, no select)."""
    return m / m.clamp(*_PLAIN[m.dtype])


def _rescale_guard(v: Tensor) -> tuple[Tensor, Callable[[Tensor], Tensor]]:
    scaled, k = rescaled(v)
    if not torch.compiler.is_compiling():
        return scaled, lambda t: t / k
    return scaled, lambda t: torch.stack([x / k[..., 0] for x in t.unbind(-1)], dim=-1)


#: :func:`rescaled` as the guard of a custom Function (the derivative of ``v / k`` is ``1 / k``).
RESCALE: Guard = _rescale_guard


def reduction(w: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """``(w', lam, u)``: rotation vectors ``w`` ``(..., 3)`` with the same axis and an angle
    below ``2 pi sqrt(3)`` where the largest ``|w_i|`` exceeds ``_HUGE`` (``2**60`` in float32,
    ``2**200`` in float64, where the formulas' fifth powers of the angle still fit), with
    ``lam = |w'| / |w|`` and the unit axis ``u = w / |w|`` there (``lam`` of shape
    ``(..., 1)``); elsewhere ``w`` itself, bit for bit, ``lam = 1`` and ``u = w``.

    Beyond those magnitudes the angle ``t = |w|`` is known only to far more than ``2 pi`` (its
    rounding), so its residue modulo ``2 pi`` is not determined by ``w``: the one taken is
    ``r = |w'|``, with ``w' = lam w`` and ``lam = fmod(m, 2 pi) / m`` (``m`` the largest
    ``|w_i|``; ``fmod`` is exact).  Every function of the rotation vector then sees ``t`` with
    ``sin t = sin r`` and ``cos t = cos r``: ``Exp(w) = Exp(w')``, a valid rotation about ``u``,
    and the left Jacobian follows from the reduced one, ``Jl(w) = lam Jl(w') + (1 - lam) u u^T``.
    Derivatives: ``d w' / d w`` is ``I`` along ``u`` (``d|w| / d w = u``, as for the true angle)
    and ``lam`` across, so gradients are those of the functions at ``t`` and finite (``u`` and
    ``lam`` are held constant: their own derivatives are of order ``1 / |w|``, below the rounding
    of the rest).
    """
    x = w.unbind(-1)
    lam, big, u = f = reduction_planes(x)
    u = torch.where(big.unsqueeze(-1), torch.stack(u, -1), w)
    return torch.stack(reduced_planes(x, f), dim=-1), lam.unsqueeze(-1), u


def _lam(w: Sequence[Tensor]) -> tuple[Tensor, Tensor, Tensor]:
    """``(lam, big, m)`` of :func:`reduction`, detached, of the planes ``w`` (``big`` where the
    angle is reduced, ``m`` the largest ``|w_i|``)."""
    return _lam_of(largest(w))


def _lam_of(m: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """:func:`_lam` from the largest ``|w_i|``."""
    big = m > _HUGE[m.dtype]
    return torch.where(big, torch.fmod(m, 2.0 * math.pi).div_(m), 1.0), big, m


def reduced_planes(
    w: Sequence[Tensor], factors: tuple[Tensor, Tensor, Sequence[Tensor]] | None = None
) -> list[Tensor]:
    """:func:`reduced` of the planes ``w`` (element-wise only, for the fused loops of
    ``torch.compile``); ``factors`` of :func:`reduction_planes` if the caller has them."""
    if torch.is_grad_enabled() and any(x.requires_grad for x in w):
        f = reduction_planes(w) if factors is None else factors
        return reduce_planes(f, w, [x - x.detach() for x in w])
    lam = (_lam(w) if factors is None else factors)[0]
    return [x * lam for x in w]  # x itself where lam = 1


def reduction_planes(w: Sequence[Tensor]) -> tuple[Tensor, Tensor, list[Tensor]]:
    """``(lam, big, u)`` of :func:`reduction`, detached, of the planes ``w`` (``big`` where the
    angle is reduced; element-wise only, for the fused loops of ``torch.compile``)."""
    lam, big, m = _lam(w)
    d = torch.where(big, m, 1.0)
    v = [x.detach() / d for x in w]
    r = torch.where(big, dot(v, v), 1.0).rsqrt()
    return lam, big, [x * r for x in v]


def reduced_planes_of(w: Tensor) -> Sequence[Tensor]:
    """The planes of :func:`reduced` of ``w`` ``(..., 3)`` (no autograd): in eager mode from the
    stack of its planes, whole (as :func:`rescaled_planes`); while compiling element-wise on
    the planes."""
    if torch.compiler.is_compiling():
        return reduced_planes(w.unbind(-1))
    S = _layout.stacked(w, 3)
    return (S * _lam_of(S.abs().amax(0))[0]).unbind(0)


def reduce_planes(
    factors: tuple[Tensor, Tensor, Sequence[Tensor]],
    t: Sequence[Tensor],
    along: Sequence[Tensor] | None = None,
) -> list[Tensor]:
    """``lam t + (1 - lam) u (u . along)`` where the angle is reduced, ``t`` elsewhere, on planes
    (``factors`` of :func:`reduction_planes`); ``along`` None: ``lam t``.

    ``along = t``: the derivative ``P = lam I + (1 - lam) u u^T`` of the reduction applied to
    ``t``; ``along = t - t.detach()`` (an exact 0): the reduced ``lam t``, with derivative ``P``
    under autograd.
    """
    lam, big, u = factors
    if along is None:
        return [x * lam for x in t]  # x itself where lam = 1
    s = (1.0 - lam) * dot(u, along)
    return [torch.where(big, fma(x * lam, s, ui), x) for x, ui in zip(t, u, strict=True)]


def reduced(w: Tensor) -> Tensor:
    """The rotation vectors ``w`` with the angle reduced where it is beyond the range of the
    formulas (:func:`reduction`), ``w`` itself elsewhere; under autograd with the derivative
    ``P`` of :func:`reduce_planes` (computed on planes, stacked: one loop while compiling)."""
    return torch.stack(reduced_planes(w.unbind(-1)), dim=-1)


def _reduce_guard(w: Tensor) -> tuple[list[Tensor], Callable[..., Tensor]]:
    x = w.unbind(-1)
    f = reduction_planes(x)

    def derivative(t: Tensor | Sequence[Tensor]) -> Tensor:
        tt = planes(t, 3)
        return _layout.interleave(reduce_planes(f, tt, tt))

    return reduced_planes(x, f), derivative


#: :func:`reduced` as the guard of a custom Function (on planes: one loop compiled).
REDUCE: Guard = _reduce_guard


def dot(a: Tensor | Sequence[Tensor], b: Tensor | Sequence[Tensor], value: float = 1.0) -> Tensor:
    """``value * sum_i a_i b_i`` over the last dimension (or planes), component by component
    from the first; ``value`` (a power of two, to keep the products of huge vectors finite) is
    taken on each product before it is rounded, at no extra operation."""
    x = a.unbind(-1) if isinstance(a, Tensor) else a
    y = b.unbind(-1) if isinstance(b, Tensor) else b
    if value == 1.0:
        acc = x[0] * y[0]
    else:
        acc = fma(_layout.constant(0.0, x[0]), x[0], y[0], value=value)
    for xi, yi in zip(x[1:], y[1:], strict=True):
        acc = fma(acc, xi, yi, value=value)
    return acc


#: Clamp of the half angle in the forward-only evaluations: sin(h)/h rounds to 1 below it.
H_MIN = {torch.float32: 1e-30, torch.float64: 1e-150}


def half_angle(w: Tensor | Sequence[Tensor]) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """``(t2, sin(h)/h, sin h, cos h)`` with ``t2 = theta2(w)`` and ``h = sqrt(t2) / 2`` clamped
    at :data:`H_MIN`: the one ``sqrt``, ``sin``, ``cos`` and division per element that the
    forward-only evaluations below start from (``half=`` of each, to take several from one)."""
    t2 = theta2(w)
    h = t2.sqrt().mul_(0.5).clamp_min_(H_MIN[t2.dtype])
    sh = torch.sin(h)
    return t2, sh / h, sh, torch.cos(h)


def rodrigues_values(
    w: Tensor | Sequence[Tensor] | None,
    parts: str = "abcd",
    half: tuple[Tensor, Tensor, Tensor, Tensor] | None = None,
) -> tuple[Tensor, ...]:
    """The coefficients of Rodrigues' forms of ``t = |w|``, by letter (:data:`RODRIGUES`), in
    the order of ``parts`` (the others are not computed); forward-only (module docstring).

    With ``h = t/2`` and ``s = sin(h)/h``: ``a = s cos h``, ``b = s^2 / 2``,
    ``d = (cos h - sin h)(cos h + sin h)`` and ``e = cos(h) / s``, free of cancellation at every
    angle; one ``sqrt``, ``sin`` and ``cos`` per element.  ``c = (1 - a)/t^2`` and
    ``f = (1 - e)/t^2`` have no series: their absolute error is about ``eps / t^2``, so the term
    they enter, ``c w w^T``, is accurate to about ``eps`` at every angle (and 0 at t = 0); use
    them only in that product.  Computed in the precision of :func:`theta2` (float64 for
    float32 input) and returned in it.  ``w`` as a ``(..., 3)`` tensor or its three components
    (as :func:`theta2`), or ``half``: its :func:`half_angle`.
    """
    t2, s, sh, ch = half_angle(w) if half is None else half
    values: dict[str, Tensor] = {}
    if "a" in parts or "c" in parts:
        values["a"] = s * ch
    if "c" in parts:
        values["c"] = (1.0 - values["a"]).div_(t2.clamp_min(H_MIN[t2.dtype]))
    if "d" in parts:
        values["d"] = (ch - sh).mul_(ch + sh)
    if "b" in parts:
        values["b"] = (s * s).mul_(0.5)
    if "e" in parts or "f" in parts:
        values["e"] = ch / s
    if "f" in parts:
        values["f"] = (1.0 - values["e"]).div_(t2.clamp_min(H_MIN[t2.dtype]))
    return tuple(values[k] for k in parts)


#: The coefficients of Rodrigues' forms by letter: ``Exp(w) = d I + a hat(w) + b w w^T``,
#: ``Jl(w) = a I + b hat(w) + c w w^T`` and ``Jl(w)^-1 = e I - hat(w)/2 + f w w^T``, functions
#: of ``t2``, differentiable to every order (double where).
RODRIGUES: dict[str, Callable[[Tensor], Tensor]] = {
    "a": sinc,
    "b": cosc,
    "c": sinc3,
    "d": cos_sqrt,
    "e": lambda t2: 1.0 - t2 * jinv(t2),
    "f": jinv,
}


def rodrigues(
    w: Sequence[Tensor], parts: str, differentiable: bool, half: tuple[Tensor, ...] | None = None
) -> tuple[Tensor, ...]:
    """The coefficients ``parts`` of :data:`RODRIGUES` of the planes ``w``, in :func:`theta2`'s
    precision: differentiable (the series above), or forward-only (:func:`rodrigues_values`,
    cheaper, for the plain backward passes; from ``half`` if given).  The one choice between
    the two evaluations of a coefficient."""
    if differentiable:
        t2 = theta2(w)
        return tuple(RODRIGUES[k](t2) for k in parts)
    return rodrigues_values(w, parts, half)


def step(x: Tensor) -> Tensor:
    """``1.0`` where ``x > 0``, else ``0.0`` (NaN included, as ``x > 0``; torch's ``sign`` is
    0 there), in ``x``'s dtype, without boolean tensors (on CPU a comparison, its conversion
    and a ``where`` each cost several float kernels).  For selections of the forward-only
    evaluations, as ``f a + (1 - f) b`` (exact for finite ``a`` and ``b``); ``step(a - b)`` is
    ``a > b`` exactly, since ``a - b > 0`` iff ``a > b`` with gradual underflow."""
    return torch.sign(x).clamp_min_(0.0)


def q_series(t2: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """``(k1, k2, k3, k4) = (c1, c1 - 3 c2, c2, c3)`` of ``t2``, each to a few ulp of ``t2``'s
    dtype, with ``c1 = sinc3``, ``c2 = cosc4``, ``c3 = q3``: the coefficients of the top-right
    block ``Q`` of the SE(3) Jacobian (``torchlie._se3_jacobian.q_components``)."""
    c1, c2 = sinc3(t2), cosc4(t2)
    return c1, c1 - 3.0 * c2, c2, q3(t2, c1)


#: ``t2`` below which :func:`q_values` takes its series.
Q_VALUES_T2 = 1e-2
#: Three terms of each series of :func:`q_values`: ``sinc3``, ``cosc4`` and ``q3``; the first
#: omitted term is below 2e-11 of the value for ``t2 < Q_VALUES_T2``.
_Q_SERIES = (tuple(_SINC3[:3]), tuple(_COSC4[:3]), tuple(_Q3[:3]))


def q_values(t2: Tensor, b: Tensor, c: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """:func:`q_series` of ``t2`` in float64, to well within float32's precision: the
    coefficients of ``Q`` in the plain backward passes of float32 input.

    Forward-only (module docstring).  From ``b = (1 - cos t)/t^2`` and ``c = (t - sin t)/t^3`` of
    the same angle (:func:`rodrigues_values`, whose ``sin`` and ``cos`` they share; no
    trigonometric function of its own): ``c1 = c``, ``c2 = (1/2 - b)/t2`` and
    ``c3 = (3 c - b)/(2 t2)``, whose cancellations leave relative errors of about ``12 eps/t2``
    and ``30 eps/t2`` (float64 ``eps``: below 1e-12 for ``t2 >= Q_VALUES_T2``; none at large
    angles), and three terms of each series below that, selected with :func:`step` (the closed
    forms divide by ``t2`` clamped at the switch, one reciprocal for both, so the branch not
    taken is finite).
    """
    small = step(Q_VALUES_T2 - t2)
    ts, tl = t2.clamp_min(Q_VALUES_T2), t2.clamp_max(Q_VALUES_T2)
    r = ts.reciprocal_()
    c2 = torch.rsub(b, 0.5).mul_(r)
    c3 = (3.0 * c - b).mul_(r).mul_(0.5)
    large = 1.0 - small
    c1, c2, c3 = (
        fma(exact * large, (tl * k2).add_(k1).mul_(tl).add_(k0), small)
        for (k0, k1, k2), exact in zip(_Q_SERIES, (c, c2, c3), strict=True)
    )
    return c1, c1 - 3.0 * c2, c2, c3


def q_plain(
    dtype: torch.dtype, t2: Tensor, b: Tensor | None, c: Tensor | None
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Forward-only ``(k1, k2, k3, k4)`` of ``t2`` for input of ``dtype`` (the plain backward
    passes): :func:`q_values` from Rodrigues' ``b`` and ``c`` for float32 (a few operations
    and no trigonometric function, to well within float32's precision), :func:`q_series`
    otherwise (``b`` and ``c`` not read); in ``t2``'s dtype."""
    return q_values(t2, b, c) if dtype == torch.float32 else q_series(t2)


#: ``t2`` above which the Jacobians take ``Q`` in its form of large angles (:func:`q_far`).
Q_FAR_T2 = 64.0


def q_far(t: Tensor, s: Tensor, c: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """``(k1, k2, k3, k4)`` of ``Q`` in terms of the unit axis ``u = phi / t`` instead of
    ``phi``: ``(c1 t, (c1 - 3 c2) t^2, c2 t^2, c3 t^3)``, bounded at every angle::

        (t - s)/t^2,  3 (1 - c)/t^2 - s/t - 1/2,  1/2 - (1 - c)/t^2,  (2 + c)/(2 t) - 3 s/(2 t^2)

    with ``s = sin t`` and ``c = cos t`` (of the reduced angle beyond the range of the formulas,
    :func:`reduction`).  Free of cancellation for ``t^2 > Q_FAR_T2``, and of powers of ``t``
    (which overflow, in float32 from about ``t = 1e9`` in the derivatives).
    """
    it = t.reciprocal()
    v = (1.0 - c) * it * it
    k4 = (0.5 * (2.0 + c) - 1.5 * s * it) * it
    return (1.0 - s * it) * it, 3.0 * v - s * it - 0.5, 0.5 - v, k4


def wide(x: Tensor) -> Tensor:
    """``x`` in the dtype the coefficients are evaluated in: float64 for float32 (see
    :func:`theta2`), unchanged otherwise."""
    return x.double() if x.dtype == torch.float32 else x


def theta2(w: Tensor | Sequence[Tensor], keepdim: bool = False) -> Tensor:
    """|w|^2 over the last dimension, in the dtype the coefficients are evaluated in.

    For float32 input the angle and the series coefficients are evaluated in float64 (a few
    per-element operations): the rounding of theta^2 otherwise dominates the error of every
    result, which then reaches 3 ulp; with it, results are within about 1 ulp.  Callers cast
    the coefficients back with ``.to(w.dtype)``.  ``w`` as a ``(..., 3)`` tensor or as its three
    components (tensors of one shape).
    """
    # Component-wise: a reduction over a trailing dimension of 3 costs several times more.
    x, y, z = (wide(c) for c in (w.unbind(-1) if isinstance(w, Tensor) else w))
    t2 = fma(fma(x * x, y, y), z, z)
    return t2.unsqueeze(-1) if keepdim else t2


def planar(t: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """``(a, b, c1, c2) = (sin t / t, (1 - cos t)/t, (t - sin t)/t^2, (1 - cos t)/t^2)`` of the
    SE(2) angle ``t`` (signed), the entries of the SE(2) Jacobians; differentiable to every
    order (double where).

    Below ``|t| = 1`` from the series of :func:`sinc`, :func:`cosc` and :func:`sinc3` (functions
    of ``t^2``); above, from ``sin`` and ``cos`` of ``t`` and powers of ``1 / t`` only
    (``a = sin t / t``, ``b = 2 sin^2(t/2) / t``, ``c1 = (1 - a)/t``, ``c2 = b / t``), free of
    cancellation there and of ``t^2``, which overflows at large angles.

    For float32 ``t`` evaluated in float64 and returned in float32, as :func:`theta2`: the
    float32 series are sized for values, and their derivatives miss up to ``t2/10`` relative
    (a few 1e-4 at the switches) where the float64 ones are exact to float32's precision.
    """
    dtype, t = t.dtype, wide(t)
    small = t.abs() < 1.0
    tn = torch.where(small, t, torch.zeros_like(t))
    t2 = tn * tn
    cn = cosc(t2)
    tf = torch.where(small, torch.ones_like(t), t)
    a = torch.sin(tf) / tf
    sh = torch.sin(0.5 * tf)
    b = 2.0 * sh * sh / tf
    coefficients = (
        torch.where(small, sinc(t2), a),
        torch.where(small, tn * cn, b),
        torch.where(small, tn * sinc3(t2), (1.0 - a) / tf),
        torch.where(small, cn, b / tf),
    )
    return tuple(c.to(dtype) for c in coefficients)


#: ``|t|`` below which :func:`planar_values` takes ``c1`` from its series.
PLANAR_SWITCH = 2.0
#: Terms of that series: the first omitted one is below ``eps`` of ``c1`` for ``|t| < 2``.
_PLANAR_TERMS = {torch.float32: 7, torch.float64: 12}


def planar_values(t: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor, Tensor]:
    """Forward-only :func:`planar` for the plain backward passes (see the module docstring),
    and ``(r, cos(t/2))`` with ``r = sin(t/2) / (t/2)``.

    From the half angle ``h = t/2`` (one ``sin``, one ``cos``, one division): ``a = r cos h``,
    ``b = r sin h``, ``c2 = r^2 / 2``, free of cancellation; ``c1 = t sinc3(t^2)`` from the
    series of ``sinc3`` below ``|t| = 2`` and ``(1 - a)/t`` above, selected with :func:`step`
    (each evaluated on an argument clamped to its side, so the branch not taken is finite).
    """
    h = 0.5 * t
    sh, ch = torch.sin(h), torch.cos(h)
    zero = h == 0
    r = torch.where(zero, 1.0, sh / torch.where(zero, 1.0, h))
    a, b = r * ch, r * sh
    c2 = 0.5 * r * r
    ts = t.clamp(-PLANAR_SWITCH, PLANAR_SWITCH)
    coeffs = tuple(_SINC3[: _PLANAR_TERMS.get(t.dtype, 7)])
    near = ts * _horner(ts * ts, coeffs)
    far_t = torch.where(t.abs() < PLANAR_SWITCH, PLANAR_SWITCH, t)
    far = (1.0 - torch.sin(far_t) / far_t) / far_t
    small = step(PLANAR_SWITCH - t.abs())
    c1 = fma(far * (1.0 - small), near, small)
    return a, b, c1, c2, r, ch


# --------------------------------------------------------------------------------------------
# Sim(3): coefficients of functions of sigma (log scale) and t2 = theta**2 jointly
# --------------------------------------------------------------------------------------------

_SINHC = [1.0 / math.factorial(2 * k + 1) for k in range(_N_MAX)]
_TERMS["sinhc"] = (6, 9)
_SERIES["sinhc"] = _SINHC
for _dt in (torch.float16, torch.bfloat16, torch.float32, torch.float64):
    _PLANS[("sinhc", _dt)] = _make_plan("sinhc", _dt)


def sinhc(u: Tensor) -> Tensor:
    """sinh(x)/x of ``u = x**2`` (even in ``x``, so a function of ``u``; smooth at 0).

    Above the series, ``sinh(x) = m (m + 2) / (2 (m + 1))`` with ``m = expm1(x)``, ``x >= 0``
    (no cancellation, the ratio taken first so that nothing overflows before ``sinh``
    does): torch's ``sinh`` rounds differently in its vectorised and scalar loops, ``expm1``
    alike in both (see :func:`angle`)."""

    def exact(s: Tensor) -> Tensor:
        x = s.sqrt()
        m = torch.expm1(x)
        k = torch.where(torch.isinf(m), 1.0, (m + 2.0) / (m + 1.0))
        return 0.5 * m * k / x

    return _series_where("sinhc", u, exact)


def expc(sigma: Tensor) -> Tensor:
    """(exp(sigma) - 1)/sigma as ``exp(sigma/2) sinhc(sigma**2/4)``: no cancellation and no
    division by ``sigma``, smooth at 0 (value 1) with accurate derivatives of every order;
    below ``sigma = -1`` as ``expm1(sigma)/sigma`` (double where), whose derivatives do not
    cancel there (those of the product lose ``log2 |sigma|`` bits: 195 ulp at -709)."""
    neg = sigma < -1.0
    sn = torch.where(neg, sigma, -1.0)
    sp = torch.where(neg, 0.0, sigma)
    return torch.where(neg, torch.expm1(sn) / sn, torch.exp(0.5 * sp) * sinhc(0.25 * sp * sp))


#: E1(z) = (exp(z) - 1)/z = sum_n z^n/(n+1)!.
_E1 = [1.0 / math.factorial(n + 1) for n in range(22)]
#: Per input dtype: ``sigma**2 + t2`` below which the Sim(3) coefficients take their joint
#: series, and its number of terms (the first omitted one below the rounding of the result).
#: float64 takes the series up to ``|z| = 1/2``, where the closed forms and their derivatives
#: lose at most a few bits; float32 (coefficients evaluated in float64) up to ``|z| = 0.1``,
#: where the closed forms' cancellation, ``eps64 / |z|^3`` in the derivatives, is far below
#: float32's rounding.
#: Forward-only evaluations (values, no derivatives; ``differentiable=False``) need the series
#: only where the closed forms divide 0 by 0: their cancellation costs ``eps / |z|^2`` of ``C``
#: (``eps / |z|`` of ``B``), which enters the result multiplied by ``theta^2`` (``theta``), at
#: most ``eps`` of it.
SIM3_SERIES = {
    (torch.float64, True): (0.25, 16),
    (torch.float32, True): (1e-2, 8),
    (torch.float64, False): (1e-6, 6),
    (torch.float32, False): (1e-6, 6),
}


#: ``sigma`` above which :func:`sim3_v_inv` takes ``V``'s coefficients with ``e^sigma``
#: factored out: far below any overflow, above the log scales of moderate size, and where
#: ``A e^-sigma = (1 - e^-sigma)/sigma`` is ``1/sigma`` to float64's rounding.
SIM3_BIG = 64.0


def _half_exp(big: Tensor, sigma: Tensor, sign: float = 1.0) -> Tensor:
    """``e^(sign sigma / 2)`` where ``big``, 1 elsewhere: the factor applied twice that takes
    Sim(3) coefficients with ``e^sigma`` factored out back to their values (``e^sigma`` itself
    would overflow, or underflow, where the result does not)."""
    return torch.exp(torch.where(big, (0.5 * sign) * sigma, 0.0))


def _sim3_v_scaled(
    sigma: Tensor, t2: Tensor, dtype: torch.dtype, differentiable: bool, scaled: bool = True
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor | None]:
    """``(A, A', B', C', big)`` with ``V = A I + f (B' hat(phi) + C' hat(phi)^2)``,
    ``A = f A'`` and ``f = e^sigma`` where ``big`` (``sigma > SIM3_BIG``), ``f = 1`` elsewhere;
    ``scaled=False``: ``f = 1`` everywhere (``big`` None)."""
    r2max, terms = SIM3_SERIES[(dtype, differentiable)]
    small = sigma * sigma + t2 < r2max
    # series branch: its own arguments only (zeros where it is not taken)
    ss = torch.where(small, sigma, 0.0)
    ts = torch.where(small, t2, 0.0)
    p = torch.full_like(t2, _E1[terms - 1])
    q = torch.zeros_like(t2)
    r = torch.zeros_like(t2)
    for c in _E1[terms - 2 :: -1]:
        p, q, r = fma(ss * p, ts, q, value=-1.0) + c, fma(p, ss, q), fma(q, ss, r)
    # closed forms: safe arguments where the series is taken
    sl = torch.where(small, 1.0, sigma)
    tl = torch.where(small, 1.0, t2)
    big = sigma > SIM3_BIG if scaled else None
    e = torch.exp(sl if big is None else torch.where(big, 0.0, sl))  # 1 where factored out
    if differentiable:
        A = expc(sigma)  # accurate at every sigma (its own series)
        sc, cc = sinc(tl), cosc(tl)
    else:  # forward-only: one sin and cos of the half angle (as rodrigues_values), expm1
        h = tl.sqrt().mul_(0.5).clamp_min_(H_MIN[tl.dtype])
        sh, ch = torch.sin(h), torch.cos(h)
        sh_h = sh / h
        sc, cc = sh_h * ch, 0.5 * sh_h * sh_h
        nz = sigma != 0
        A = torch.where(nz, torch.expm1(sigma) / torch.where(nz, sigma, 1.0), 1.0)
    Ah = A
    if big is not None:
        # A e^-sigma = (1 - e^-sigma)/sigma: 1/sigma to float64's rounding above SIM3_BIG
        Ah = torch.where(big, 1.0 / torch.where(big, sl, 1.0), A)
    # divided (not times a reciprocal): a reciprocal's partial, B (sigma^2 + t2), overflows
    # in the backward pass above sigma about 703 where B is finite
    den = sl * sl + tl
    B = fma(fma(sl * e * sc, e * tl, cc), sl, Ah, value=-1.0) / den
    C = fma(fma(Ah, sl * e, cc), e, sc, value=-1.0) / den
    return A, Ah, torch.where(small, q, B), torch.where(small, r, C), big


def sim3_v(
    sigma: Tensor, t2: Tensor, dtype: torch.dtype = torch.float64, differentiable: bool = True
) -> tuple[Tensor, Tensor, Tensor]:
    """``(A, B, C)`` with ``V = A I + B hat(phi) + C hat(phi)^2 = int_0^1 exp(s (hat(phi) +
    sigma I)) ds``, the matrix that maps ``rho`` to the translation of the Sim(3) exponential::

        A = (e^sigma - 1)/sigma
        B = Im(E1(z))/theta = (sigma e^sigma sinc + e^sigma t2 cosc - (e^sigma - 1))/(sigma^2 + t2)
        C = (A - Re(E1(z)))/t2 = (A + sigma e^sigma cosc - e^sigma sinc)/(sigma^2 + t2)

    with ``z = sigma + i theta``, ``E1(z) = (e^z - 1)/z``, ``sinc`` and ``cosc`` of ``t2``.
    ``B`` and ``C`` cancel as ``sigma`` and ``theta`` go to 0 together: there
    (:data:`SIM3_SERIES` of the input ``dtype``; the smaller region of forward-only values
    with ``differentiable=False``) they are the series of ``E1`` in ``z``,
    evaluated by Horner's rule on ``p + i theta q = E1(z)`` and ``r = (E1(sigma) - p)/t2``
    (real polynomials in ``sigma`` and ``t2``: ``B = q``, ``C = r``, ``A = p + t2 r``); double
    where, so neither branch produces Inf/NaN in forward or backward.  Above
    :data:`SIM3_BIG` ``B`` and ``C`` come from the coefficients with ``e^sigma`` factored out
    (``sigma e^sigma`` overflows from ``sigma`` about 703 in float64, where they are finite),
    times two factors ``e^(sigma/2)``.
    """
    A, _, B, C, big = _sim3_v_scaled(sigma, t2, dtype, differentiable)
    h = _half_exp(big, sigma)  # type: ignore[arg-type]
    return A, B * h * h, C * h * h


def sim3_reduced(w: Sequence[Tensor]) -> tuple[list[Tensor], Tensor, Tensor]:
    """``(w', lam, big)``: the planes of :func:`reduced` of the rotation vectors ``w`` (with its
    derivative under autograd) and the ``lam`` and ``big`` of :func:`reduction`, without the
    unit axis (Sim(3)'s exponential builds its limit term from ``w'``)."""
    if torch.is_grad_enabled() and any(x.requires_grad for x in w):
        f = reduction_planes(w)
        return reduce_planes(f, w, [x - x.detach() for x in w]), f[0], f[1]
    lam, big, _ = _lam(w)
    return [x * lam for x in w], lam, big


def sim3_v_inv(
    sigma: Tensor, t2: Tensor, dtype: torch.dtype = torch.float64, differentiable: bool = True
) -> tuple[Tensor, Tensor, Tensor]:
    """``(a, b, c)`` with ``V^-1 = a I + b hat(phi) + c hat(phi)^2`` (``V`` of :func:`sim3_v`)::

        a = 1/A,  b = -B/det,  c = (B^2 - C D)/(A det),  D = A - t2 C,  det = D^2 + t2 B^2

    (``D + i theta B = E1(z)``, so ``det = |E1(z)|^2 > 0`` for ``theta < 2 pi``); no
    cancellation beyond a factor 3 in ``B^2 - C D`` near 0.  Above :data:`SIM3_BIG` from the
    coefficients with ``e^sigma`` factored out (``det`` and ``A det`` would overflow long before
    ``b`` and ``c ~ e^-sigma`` underflow), multiplied by ``e^-sigma`` as two factors
    ``e^-sigma/2`` (the one factor is subnormal near the top of the float64 range)."""
    A, Ah, B, C, big = _sim3_v_scaled(sigma, t2, dtype, differentiable)
    D = Ah - t2 * C
    det = D * D + t2 * B * B
    h = _half_exp(big, sigma, -1.0)  # type: ignore[arg-type]
    # a = 1/A as e^-sigma / Ah too: the reciprocal's derivative, -A'/A^2, squares A
    return h / Ah * h, -B * h / det * h, (B * B - C * D) * h / (Ah * det) * h


#: E1'(sigma) = sum_n (n + 1) sigma^n/(n + 2)!: the series below |sigma| = 1/2.
_DE1 = [(n + 1) / math.factorial(n + 2) for n in range(20)]


def expc_prime(sigma: Tensor) -> Tensor:
    """d/dsigma of (exp(sigma) - 1)/sigma, ``(e^sigma (sigma - 1) + 1)/sigma^2``: its series
    below ``|sigma| = 1/2`` (double where), where the closed form cancels; above
    :data:`SIM3_BIG` ``e^sigma`` as two factors ``e^(sigma/2)`` around ``(sigma - 1)/sigma^2``
    (``e^sigma (sigma - 1)`` overflows from about 703 in float64, where the value is finite)."""
    small = sigma.abs() < 0.5
    ss = torch.where(small, sigma, 0.0)
    s = torch.full_like(sigma, _DE1[-1])
    for c in _DE1[-2::-1]:
        s = fma(torch.full_like(sigma, c), s, ss)
    sl = torch.where(small, 1.0, sigma)
    big = sigma > SIM3_BIG
    h = _half_exp(big, sigma)
    e = torch.exp(torch.where(big, 0.0, sl))
    sl2 = sl * sl
    closed = torch.where(big, h * ((sl - 1.0) / sl2) * h + 1.0 / sl2, (e * (sl - 1.0) + 1.0) / sl2)
    return torch.where(small, s, closed)


def sim3_v_partials(
    sigma: Tensor, t2: Tensor, dtype: torch.dtype = torch.float64
) -> tuple[Tensor, ...]:
    """``(A, B, C, A_s, B_s, C_s, B_t, C_t)``: the coefficients of :func:`sim3_v` and their
    partial derivatives in ``sigma`` (``_s``) and ``t2`` (``_t``; ``A`` does not depend on
    ``t2``), for the coupling blocks of the Sim(3) Jacobian.  With ``N_B = sigma e sinc +
    e t2 cosc - (e - 1)``, ``N_C = A + sigma e cosc - e sinc`` (so ``B = N_B / (sigma^2 + t2)``,
    ``C = N_C / (sigma^2 + t2)``, ``e = e^sigma``) and ``sinc' = (sinc3 - cosc)/2``,
    ``cosc' = cosc4 - sinc3/2`` (derivatives in ``t2``)::

        B_s = (e (sigma sinc + t2 (cosc - sinc3)) - 2 sigma B)/(sigma^2 + t2)
        C_s = (A_s + e ((1 + sigma) cosc - sinc) - 2 sigma C)/(sigma^2 + t2)
        B_t = (sigma e sinc' + e (cosc + t2 cosc') - B)/(sigma^2 + t2)
        C_t = (e (sigma cosc' - sinc') - C)/(sigma^2 + t2)

    and ``A_s`` of :func:`expc_prime`.  Near ``sigma = theta = 0`` (:data:`SIM3_SERIES`) the
    derivatives of the joint series of :func:`sim3_v`, carried along its Horner recurrence;
    double where, so neither branch produces Inf/NaN in forward or backward."""
    r2max, terms = SIM3_SERIES[(dtype, True)]
    small = sigma * sigma + t2 < r2max
    ss = torch.where(small, sigma, 0.0)
    ts = torch.where(small, t2, 0.0)
    p = torch.full_like(t2, _E1[terms - 1])
    q, r = torch.zeros_like(t2), torch.zeros_like(t2)
    ps, qs, rs, pt, qt, rt = (torch.zeros_like(t2) for _ in range(6))
    for c in _E1[terms - 2 :: -1]:
        ps, qs, rs, pt, qt, rt = (
            p + ss * ps - ts * qs,
            ps + q + ss * qs,
            qs + r + ss * rs,
            ss * pt - q - ts * qt,
            pt + ss * qt,
            qt + ss * rt,
        )
        p, q, r = fma(ss * p, ts, q, value=-1.0) + c, fma(p, ss, q), fma(q, ss, r)
    sl = torch.where(small, 1.0, sigma)
    tl = torch.where(small, 1.0, t2)
    A, As = expc(sigma), expc_prime(sigma)
    # Above SIM3_BIG the closed forms with f = e^sigma factored out (sigma e^sigma overflows
    # from about 703 in float64, where the coefficients are finite), times f as two factors
    # e^(sigma/2); below it f = 1 and the same values as without it.
    big = sigma > SIM3_BIG
    sb = torch.where(big, sl, 1.0)
    e = torch.exp(torch.where(big, 0.0, sl))  # e^sigma / f
    em1 = torch.where(big, -torch.expm1(-sb), torch.expm1(torch.where(big, 0.0, sl)))
    Af = torch.where(big, em1 / sb, A)  # A / f
    Asf = torch.where(big, (sb - 1.0 + torch.exp(-sb)) / (sb * sb), As)  # A_s / f
    sc, cc, s3, c4 = sinc(tl), cosc(tl), sinc3(tl), cosc4(tl)
    dsc, dcc = 0.5 * (s3 - cc), c4 - 0.5 * s3
    den = sl * sl + tl  # divided, as in _sim3_v_scaled
    B = (sl * e * sc + e * tl * cc - em1) / den
    C = (Af + e * (sl * cc - sc)) / den
    Bs = (e * (sl * sc + tl * (cc - s3)) - 2.0 * sl * B) / den
    Cs = (Asf + e * ((1.0 + sl) * cc - sc) - 2.0 * sl * C) / den
    Bt = (e * (sl * dsc + cc + tl * dcc) - B) / den
    Ct = (e * (sl * dcc - dsc) - C) / den
    h = _half_exp(big, sigma)
    w = torch.where
    return (
        A,
        w(small, q, B * h * h),
        w(small, r, C * h * h),
        As,
        w(small, qs, Bs * h * h),
        w(small, rs, Cs * h * h),
        w(small, qt, Bt * h * h),
        w(small, rt, Ct * h * h),
    )


#: ``sigma`` from which :func:`sim3_coupling` solves for the couplings of the Sim(3) Jacobian:
#: below it their difference forms lose at most a few bits, above it they cancel by about
#: ``sigma`` (their terms are of order ``A |rho|``, the couplings of order ``A |rho| / sigma``).
SIM3_Q_SIGMA = 1.0


def sim3_coupling(sigma: Tensor, t2: Tensor) -> tuple[tuple[Tensor, ...], Tensor, Tensor, Tensor]:
    """``(p, k, r, use)``: the couplings of the translation to ``phi`` (``Q``) and to
    ``sigma`` (``w``) in the Sim(3) left Jacobian as solutions of linear equations in
    ``sigma + P`` (``P = hat(phi)``), taken where ``use`` (``sigma >=`` :data:`SIM3_Q_SIGMA`).

    ``w = -E2(sigma + P) rho = -(sigma + P)^-1 y`` with ``y = V rho - rho``, and ``(sigma +
    P)^-1 = ((sigma^2 + t2) I - sigma P + P^2) / (sigma a)``, ``a = sigma^2 + t2``, so ``w =
    -r (y - phi x y / sigma + phi (phi . y) / sigma^2)`` with ``r = sigma / a`` (each term at
    most ``|y|``: ``sigma y`` overflows near the top of the range of ``e^sigma``).

    ``Q = int_0^1 int_0^t e^(u (sigma + P)) hat(rho) e^((t - u) P) du dt`` solves
    ``sigma Q + ad(Q) = Y``, ``Y = V hat(rho) - hat(rho) Jl(phi)``, ``ad(X) = P X - X P``, so
    ``Q = sum_j p_j (k ad)^j (Y)``: ``ad`` has eigenvalues ``0, +-i theta, +-2 i theta``, so
    ``(sigma + ad)^-1`` is the polynomial ``p(ad)`` that inverts ``sigma + x`` modulo ``x (x^2 +
    t2) (x^2 + 4 t2)``::

        p_0 = 1/sigma,  p_1 = -(sigma^2 + 5 t2)/(a b),  p_2 = -p_1/sigma,
        p_3 = -1/(a b),  p_4 = 1/(sigma a b),  b = sigma^2 + 4 t2

    given as ``p_j m^j`` with ``k = 1/m``, ``m = sqrt(b)``: each ``(k ad)^j (Y)`` is at most
    ``|Y|`` and each ``p_j m^j`` at most ``5/sigma``, so no term cancels more than a few bits
    (``sigma + P`` and ``sigma + ad`` have condition ``sqrt(a) / sigma`` and ``sqrt(b) /
    sigma``) and none overflows where the couplings do not.  ``sigma = SIM3_Q_SIGMA`` where
    not ``use`` (finite, not taken)."""
    use = sigma >= SIM3_Q_SIGMA
    s = torch.where(use, sigma, SIM3_Q_SIGMA)
    s2 = s * s
    a, b = s2 + t2, s2 + 4.0 * t2
    m = b.sqrt()
    f = 1.0 + t2 / b  # (sigma^2 + 5 t2)/b
    ba = b / a
    return (1.0 / s, -f * m / a, f * ba / s, -m / a, ba / s), 1.0 / m, s / a, use
