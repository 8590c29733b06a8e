"""High-precision references (mpmath, 60 digits) for SO(3) values and derivatives.

Every reference is computed from the exact floating-point input the library receives (a float32
input is converted to float64 exactly first), so the comparison measures the library's own error.
The log reference is ``log(polar(R))`` of the given, rounded matrix: that is the meaning of
``torchlie.so3.log`` off the manifold (DESIGN.md section 5).
"""

from __future__ import annotations

import mpmath as mp
import numpy as np

mp.mp.dps = 60


def _hat(w):
    x, y, z = w
    return mp.matrix([[0, -z, y], [z, 0, -x], [-y, x, 0]])


def _coeffs(w):
    """A = sin t/t, B = (1-cos t)/t^2, C = (t - sin t)/t^3, D = (1 - (t/2)cot(t/2))/t^2."""
    t2 = w[0] ** 2 + w[1] ** 2 + w[2] ** 2
    if t2 == 0:
        return mp.mpf(1), mp.mpf(1) / 2, mp.mpf(1) / 6, mp.mpf(1) / 12
    t = mp.sqrt(t2)
    if t < mp.mpf("1e-6"):  # series: 60 digits would cancel away in the closed forms
        A = 1 - t2 / 6 + t2**2 / 120 - t2**3 / 5040
        B = mp.mpf(1) / 2 - t2 / 24 + t2**2 / 720 - t2**3 / 40320
        C = mp.mpf(1) / 6 - t2 / 120 + t2**2 / 5040 - t2**3 / 362880
        D = mp.mpf(1) / 12 + t2 / 720 + t2**2 / 30240 + t2**3 / 1209600
        return A, B, C, D
    A = mp.sin(t) / t
    B = 2 * mp.sin(t / 2) ** 2 / t2
    C = (t - mp.sin(t)) / (t2 * t)
    D = (1 - (t / 2) * mp.cot(t / 2)) / t2
    return A, B, C, D


def exp(w) -> mp.matrix:
    w = [mp.mpf(float(v)) for v in w]
    A, B, _, _ = _coeffs(w)
    K = _hat(w)
    return mp.eye(3) + A * K + B * K * K


def jac_right(w) -> mp.matrix:
    w = [mp.mpf(float(v)) for v in w]
    _, B, C, _ = _coeffs(w)
    K = _hat(w)
    return mp.eye(3) - B * K + C * K * K


def jac_right_inv(w) -> mp.matrix:
    w = [mp.mpf(v) if isinstance(v, mp.mpf) else mp.mpf(float(v)) for v in w]
    _, _, _, D = _coeffs(w)
    K = _hat(w)
    return mp.eye(3) + K / 2 + D * K * K


def log(R) -> list:
    """log(polar(R)) with the canonical sign rule at exactly pi."""
    M = mp.matrix([[mp.mpf(float(R[i][j])) for j in range(3)] for i in range(3)])
    # two Newton-Schulz steps: exact to far below float64 rounding for near-rotations
    for _ in range(2):
        M = M * (3 * mp.eye(3) - M.T * M) / 2
    skew = [(M[2, 1] - M[1, 2]) / 2, (M[0, 2] - M[2, 0]) / 2, (M[1, 0] - M[0, 1]) / 2]
    s = mp.sqrt(sum(v * v for v in skew))
    c = (M[0, 0] + M[1, 1] + M[2, 2] - 1) / 2
    t = mp.atan2(s, c)
    if c > 0:
        if s == 0:
            return [mp.mpf(0)] * 3
        return [t / s * v for v in skew]
    # near pi: axis from the symmetric part, sign from the skew part
    S = (M + M.T) / 2
    nn = (S - c * mp.eye(3)) / (1 - c)
    k = max(range(3), key=lambda i: nn[i, i])
    n = [nn[i, k] / mp.sqrt(nn[k, k]) for i in range(3)]
    dot = sum(n[i] * skew[i] for i in range(3))
    if dot < 0:
        n = [-v for v in n]
    return [t * v for v in n]


def to_float(m) -> np.ndarray:
    if isinstance(m, mp.matrix):
        return np.array([[float(m[i, j]) for j in range(m.cols)] for i in range(m.rows)])
    return np.array([float(v) for v in m])


def quaternion_of_rotvec(w) -> list:
    """Canonical (w > 0) unit quaternion of a high-precision rotation vector."""
    t = mp.sqrt(sum(v * v for v in w))
    if t == 0:
        return [mp.mpf(1), mp.mpf(0), mp.mpf(0), mp.mpf(0)]
    h = t / 2
    q = [mp.cos(h)] + [mp.sin(h) * v / t for v in w]
    return q


def matrix_of_quaternion(q) -> mp.matrix:
    q = [mp.mpf(float(v)) for v in q]
    n2 = sum(v * v for v in q)
    w, x, y, z = q
    s = 2 / n2
    return mp.matrix(
        [
            [1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)],
            [s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w)],
            [s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y)],
        ]
    )
