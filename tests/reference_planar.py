"""High-precision references (mpmath, 60 digits) for SO(2) and SE(2).

Every reference comes from the matrix exponential of ``hat(xi)`` (``mp.expm``) and its Frechet
derivative (the top-right block of ``expm([[A, E], [0, A]])``), never from the closed forms
under test.  The log reference is the tangent whose ``expm`` is the polar-projected input (the
meaning of the log maps off the manifold); the reference gradient of a log is the one matrix
``G`` with ``<G, dT/dxi_k> = g_k`` along the tangent directions, 0 along the normal directions
``R S`` (``S`` symmetric) and 0 on the bottom row (DESIGN.md section 5).
"""

from __future__ import annotations

import mpmath as mp
import numpy as np

mp.mp.dps = 60


def _mpf(x) -> mp.mpf:
    return mp.mpf(float(x))


def hat2(theta) -> mp.matrix:
    t = _mpf(theta)
    return mp.matrix([[0, -t], [t, 0]])


def hat3(xi) -> mp.matrix:
    x, y, t = (_mpf(v) for v in xi)
    return mp.matrix([[0, -t, x], [t, 0, y], [0, 0, 0]])


def _frechet(A: mp.matrix, E: mp.matrix) -> mp.matrix:
    n = A.rows
    B = mp.zeros(2 * n, 2 * n)
    for i in range(n):
        for j in range(n):
            B[i, j] = A[i, j]
            B[n + i, n + j] = A[i, j]
            B[i, n + j] = E[i, j]
    M = mp.expm(B)
    return mp.matrix([[M[i, n + j] for j in range(n)] for i in range(n)])


def to_np(M: mp.matrix) -> np.ndarray:
    return np.array([[float(M[i, j]) for j in range(M.cols)] for i in range(M.rows)])


def _basis(n: int, hat):
    return [hat([1.0 if k == i else 0.0 for k in range(n)]) for i in range(n)]


def exp_and_derivatives(xi, group: str) -> tuple[np.ndarray, list[np.ndarray]]:
    """``expm(hat(xi))`` and its derivatives ``d/dxi_k`` (float64 arrays)."""
    if group == "so2":
        A = hat2(xi[0])
        E = [mp.matrix([[0, -1], [1, 0]])]
    else:
        A = hat3(xi)
        E = _basis(3, hat3)
    return to_np(mp.expm(A)), [to_np(_frechet(A, e)) for e in E]


def _polar2(R) -> mp.matrix:
    x = _mpf(R[0][0]) + _mpf(R[1][1])
    y = _mpf(R[1][0]) - _mpf(R[0][1])
    r = mp.sqrt(x * x + y * y)
    return mp.matrix([[x / r, -y / r], [y / r, x / r]])


def _log_tangent(M: mp.matrix, group: str) -> list:
    """The angle of the rotation block (``atan2`` in ``(-pi, pi]``: the argument of the complex
    number ``M[0, 0] + i M[1, 0]``) and, for SE(2), the ``rho`` with ``expm(hat(rho, t))`` of
    translation ``M[:2, 2]``: the translation of ``expm(hat(rho, t))`` is linear in ``rho``,
    its matrix read off ``expm`` at the two unit ``rho``."""
    t = mp.atan2(M[1, 0], M[0, 0])
    if group == "so2":
        return [t]
    cols = [mp.expm(_hat_mp([1, 0, t])), mp.expm(_hat_mp([0, 1, t]))]
    V = mp.matrix([[cols[j][i, 2] for j in range(2)] for i in range(2)])
    rho = mp.lu_solve(V, mp.matrix([M[0, 2], M[1, 2]]))
    return [rho[0], rho[1], t]


def log_and_gradient(X: np.ndarray, g: np.ndarray, group: str) -> tuple[np.ndarray, np.ndarray]:
    """``Log(polar X)`` (:func:`_log_tangent`) and the reference gradient ``G`` of
    ``<g, log>`` at ``X``."""
    P = _polar2(X[:2, :2])
    if group == "so2":
        M = P
    else:
        M = mp.matrix([[P[0, 0], P[0, 1], _mpf(X[0, 2])], [P[1, 0], P[1, 1], _mpf(X[1, 2])]])
        M = mp.matrix([[M[i, j] for j in range(3)] for i in range(2)] + [[0, 0, 1]])
    xi = _log_tangent(M, group)
    n = 1 if group == "so2" else 3
    d = 2 if group == "so2" else 3
    A = hat2(xi[0]) if group == "so2" else _hat_mp(xi)
    E = [mp.matrix([[0, -1], [1, 0]])] if group == "so2" else _basis(3, hat3)
    D = [_frechet(A, e) for e in E]
    R = mp.expm(A)
    rows, rhs = [], []
    for k in range(n):
        rows.append([D[k][i, j] for i in range(d) for j in range(d)])
        rhs.append(_mpf(g[k]))
    for S in ([[1, 0], [0, 0]], [[0, 0], [0, 1]], [[0, 1], [1, 0]]):
        RS = [[sum(R[i, k] * S[k][j] for k in range(2)) for j in range(2)] for i in range(2)]
        rows.append([RS[i][j] if i < 2 and j < 2 else 0 for i in range(d) for j in range(d)])
        rhs.append(0)
    if group == "se2":
        for j in range(3):
            rows.append([1 if (i == 2 and jj == j) else 0 for i in range(3) for jj in range(3)])
            rhs.append(0)
    G = mp.lu_solve(mp.matrix(rows), mp.matrix(rhs))
    return np.array([float(v) for v in xi]), np.array([float(G[i]) for i in range(d * d)]).reshape(
        d, d
    )


def _hat_mp(xi) -> mp.matrix:
    x, y, t = xi
    return mp.matrix([[0, -t, x], [t, 0, y], [0, 0, 0]])


def jac_fd(fn, xi: np.ndarray) -> np.ndarray:
    """Jacobian (columns: d/dxi_k) of a vector function of mp vectors, by mp.diff."""
    xs = [mp.mpf(float(v)) for v in xi]
    cols = []
    for k in range(len(xs)):

        def f(h, k=k):
            ys = list(xs)
            ys[k] = ys[k] + h
            return fn(ys)

        n = len(f(mp.mpf(0)))
        cols.append([float(mp.diff(lambda h, i=i: f(h)[i], 0)) for i in range(n)])
    return np.array(cols).T


def se2_log_mp(M: mp.matrix) -> list:
    return _log_tangent(M, "se2")


def se2_exp_mp(xi) -> mp.matrix:
    return mp.expm(_hat_mp(xi))
