"""High-precision references (mpmath, 60 digits) for SO(3) values and derivatives.

Every reference is computed from the exact floating-point input the library receives (a float32
input is converted to float64 exactly first), so the comparison measures the library's own error.
The log reference is ``log(polar(R))`` of the given, rounded matrix: that is the meaning of
``torchlie.so3.log`` off the manifold (DESIGN.md section 5).

Matrices are 3x3 nested lists of ``mpf``; products are written out (mpmath's matrix class costs
most of the time of a reference set otherwise); products sum as mpmath's do (``fdot``).
"""

from __future__ import annotations

import mpmath as mp
import numpy as np

mp.mp.dps = 60

_ZERO, _ONE = mp.mpf(0), mp.mpf(1)


def _mpf3(w) -> list:
    return [v if isinstance(v, mp.mpf) else mp.mpf(float(v)) for v in w]


def _hat(w) -> list:
    x, y, z = w
    return [[_ZERO, -z, y], [z, _ZERO, -x], [-y, x, _ZERO]]


def _mm(A, B) -> list:
    return [[mp.fdot([(A[i][k], B[k][j]) for k in range(3)]) for j in range(3)] for i in range(3)]


def _poly(w, a0, a1, a2) -> list:
    """a0 I + a1 K + a2 K^2 with K = hat(w), using K^2 = w w^T - |w|^2 I."""
    K = _hat(w)
    t2 = w[0] ** 2 + w[1] ** 2 + w[2] ** 2
    return [
        [(a0 - a2 * t2 if i == j else _ZERO) + a1 * K[i][j] + a2 * w[i] * w[j] for j in range(3)]
        for i in range(3)
    ]


def _coeffs(w):
    """A = sin t/t, B = (1-cos t)/t^2, C = (t - sin t)/t^3, D = (1 - (t/2)cot(t/2))/t^2."""
    t2 = w[0] ** 2 + w[1] ** 2 + w[2] ** 2
    if t2 == 0:
        return _ONE, _ONE / 2, _ONE / 6, _ONE / 12
    t = mp.sqrt(t2)
    if t < mp.mpf("1e-6"):  # series: 60 digits would cancel away in the closed forms
        A = 1 - t2 / 6 + t2**2 / 120 - t2**3 / 5040
        B = _ONE / 2 - t2 / 24 + t2**2 / 720 - t2**3 / 40320
        C = _ONE / 6 - t2 / 120 + t2**2 / 5040 - t2**3 / 362880
        D = _ONE / 12 + t2 / 720 + t2**2 / 30240 + t2**3 / 1209600
        return A, B, C, D
    A = mp.sin(t) / t
    B = 2 * mp.sin(t / 2) ** 2 / t2
    C = (t - mp.sin(t)) / (t2 * t)
    D = (1 - (t / 2) * mp.cot(t / 2)) / t2
    return A, B, C, D


def exp(w) -> list:
    w = _mpf3(w)
    A, B, _, _ = _coeffs(w)
    return _poly(w, _ONE, A, B)


def jac_right(w) -> list:
    w = _mpf3(w)
    _, B, C, _ = _coeffs(w)
    return _poly(w, _ONE, -B, C)


def jac_right_inv(w) -> list:
    w = _mpf3(w)
    _, _, _, D = _coeffs(w)
    return _poly(w, _ONE, _ONE / 2, D)


def exp_derivative(w) -> list:
    """d exp(w)_ij / d w_k = (exp(w) hat(Jr(w) e_k))_ij, as [i][j][k]."""
    R, Jr = exp(w), jac_right(w)
    cols = [_mm(R, _hat([Jr[0][k], Jr[1][k], Jr[2][k]])) for k in range(3)]
    return [[[cols[k][i][j] for k in range(3)] for j in range(3)] for i in range(3)]


def log(R) -> list:
    """log(polar(R)) with the canonical sign rule at exactly pi."""
    M = [[mp.mpf(float(R[i][j])) for j in range(3)] for i in range(3)]
    # two Newton-Schulz steps: exact to far below float64 rounding for near-rotations
    for _ in range(2):
        MtM = _mm([list(c) for c in zip(*M, strict=True)], M)
        P = _mm(M, [[(3 if i == j else 0) - MtM[i][j] for j in range(3)] for i in range(3)])
        M = [[v / 2 for v in row] for row in P]
    skew = [(M[2][1] - M[1][2]) / 2, (M[0][2] - M[2][0]) / 2, (M[1][0] - M[0][1]) / 2]
    s = mp.sqrt(sum(v * v for v in skew))
    c = (M[0][0] + M[1][1] + M[2][2] - 1) / 2
    t = mp.atan2(s, c)
    if c > 0:
        if s == 0:
            return [_ZERO] * 3
        return [t / s * v for v in skew]

    # near pi: axis from the symmetric part, sign from the skew part
    def sym(i: int, j: int):
        return ((M[i][j] + M[j][i]) / 2 - (c if i == j else 0)) / (1 - c)

    nn = [[sym(i, j) for j in range(3)] for i in range(3)]
    k = max(range(3), key=lambda i: nn[i][i])
    n = [nn[i][k] / mp.sqrt(nn[k][k]) for i in range(3)]
    dot = sum(n[i] * skew[i] for i in range(3))
    if dot < 0:
        n = [-v for v in n]
    return [t * v for v in n]


def to_float(m) -> np.ndarray:
    """Nested lists of mpf (any depth) as a float64 array."""
    return np.array(m, dtype=object).astype(np.float64)


def quaternion_of_rotvec(w) -> list:
    """Canonical (w > 0) unit quaternion of a high-precision rotation vector."""
    t = mp.sqrt(sum(v * v for v in w))
    if t == 0:
        return [_ONE, _ZERO, _ZERO, _ZERO]
    h = t / 2
    q = [mp.cos(h)] + [mp.sin(h) * v / t for v in w]
    return q


def matrix_of_quaternion(q) -> list:
    q = [mp.mpf(float(v)) for v in q]
    n2 = sum(v * v for v in q)
    w, x, y, z = q
    s = 2 / n2
    return [
        [1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)],
        [s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w)],
        [s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y)],
    ]
