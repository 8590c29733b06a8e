"""The numerical specification: values and derivatives against 60-digit references.

Angles 0, 1e-12, 1e-8, 1e-6, 1e-4, 1e-2, 1, 3, pi-1e-2, pi-1e-4, pi-1e-6, pi-1e-8, pi over 218 axes
(coordinate axes, diagonals, near-diagonals, 200 random), float32 and float64.  Errors are
norm-wise relative per element, ``|out - ref| / |ref|`` (absolute where ``ref = 0``).

Targets: values within 4 ulp (``4 eps``) and gradients within 8 ulp (``8 eps``) of the
references, in every angle region and both dtypes.  The values and the plain backward passes
are checked over the whole sample set, in batches of 100 rows, and over the sample set
repeated to a batch large enough to be evaluated in blocks (``torchlie._autograd.evaluate``)
with its results written in columns (``torchlie._layout``).
"""

from __future__ import annotations

import numpy as np
import pytest
import reference as ref
import torch
from samplers import ANGLES, PI, rotvecs

from torchlie import _autograd, _layout, compiled, quaternion, so3

pytestmark = pytest.mark.slow

VALUE_TOL = {dt: 4 * torch.finfo(dt).eps for dt in (torch.float32, torch.float64)}
GRAD_TOL = {dt: 8 * torch.finfo(dt).eps for dt in (torch.float32, torch.float64)}
_CACHE: dict[torch.dtype, dict[str, torch.Tensor]] = {}


def _references(dtype: torch.dtype) -> dict[str, torch.Tensor]:
    """Inputs (rounded to ``dtype``) and their references, computed once per session."""
    if dtype in _CACHE:
        return _CACHE[dtype]
    w, theta = rotvecs(ANGLES, n_random=200, dtype=dtype)
    w64 = w.double().numpy()
    R_ref = [ref.exp(v) for v in w64]
    R_in = torch.tensor(np.stack([ref.to_float(R) for R in R_ref])).to(dtype)
    logs = [ref.log(R) for R in R_in.double().numpy()]
    quats = [ref.quaternion_of_rotvec(v) for v in logs]
    q_in = torch.tensor(np.stack([ref.to_float(q) for q in quats])).to(dtype)
    out = {
        "w": w,
        "theta": theta,
        "R_ref": torch.tensor(np.stack([ref.to_float(R) for R in R_ref])),
        "R_in": R_in,
        "log_ref": torch.tensor(np.stack([ref.to_float(v) for v in logs])),
        "quat_ref": torch.tensor(np.stack([ref.to_float(q) for q in quats])),
        "q_in": q_in,
        "q_matrix_ref": torch.tensor(
            np.stack([ref.to_float(ref.matrix_of_quaternion(q)) for q in q_in.double().numpy()])
        ),
        # d/dw exp(w) [i, j, k] = (R hat(Jr(w) e_k))_ij
        "exp_grad_ref": torch.tensor(np.stack([ref.to_float(ref.exp_derivative(v)) for v in w64])),
        "jr_inv_ref": torch.tensor(np.stack([ref.to_float(ref.jac_right_inv(v)) for v in logs])),
    }
    _CACHE[dtype] = out
    return out


def _rel(out: torch.Tensor, expected: torch.Tensor, nd: int) -> torch.Tensor:
    dims = tuple(range(-nd, 0))
    diff = (out.double() - expected).square().sum(dims).sqrt()
    scale = expected.square().sum(dims).sqrt()
    return torch.where(scale > 0, diff / torch.where(scale > 0, scale, 1.0), diff)


def _report(err: torch.Tensor, theta: torch.Tensor) -> str:
    i = int(err.argmax())
    return f"max rel err {float(err[i]):.3g} at theta={float(theta[i]):.17g}"


def _sign_free_near_pi(out, expected, theta, nd):
    """At (float) pi the axis sign is decided by rounding noise: accept either sign there."""
    err = _rel(out, expected, nd)
    flipped = _rel(-out, expected, nd)
    at_pi = (theta.double() > PI - 1e-12).reshape(err.shape)
    return torch.where(at_pi, torch.minimum(err, flipped), err)


#: ``rows`` of a run over the sample set repeated to a large batch (the kernels of large eager
#: CPU batches, see torchlie._layout), the first copy kept.
LARGE = -1


def _tiled(x: torch.Tensor) -> torch.Tensor:
    """``x`` repeated along its first dimension to a batch of several blocks."""
    copies = -(-max(_layout.MIN_ROWS, 3 * _autograd.BLOCK) // x.shape[0])
    return x.repeat((copies,) + (1,) * (x.dim() - 1))


def _in_rows(fn, x: torch.Tensor, rows: int | None) -> torch.Tensor:
    """``fn(x)`` over the whole sample set, in batches of ``rows``, or over a large batch
    (``rows = LARGE``)."""
    if rows is None:
        return fn(x)
    if rows == LARGE:
        return fn(_tiled(x))[: x.shape[0]]
    return torch.cat([fn(part) for part in x.split(rows)])


BATCHES = pytest.mark.parametrize("rows", [None, 100, LARGE], ids=["whole", "rows100", "large"])


@BATCHES
def test_exp_values(dtype, rows):
    r = _references(dtype)
    err = _rel(_in_rows(so3.exp, r["w"], rows), r["R_ref"], 2)
    assert float(err.max()) <= VALUE_TOL[dtype], _report(err, r["theta"])


@BATCHES
def test_log_values(dtype, rows):
    r = _references(dtype)
    err = _sign_free_near_pi(_in_rows(so3.log, r["R_in"], rows), r["log_ref"], r["theta"], 1)
    assert float(err.max()) <= VALUE_TOL[dtype], _report(err, r["theta"])


@BATCHES
def test_log_of_exp(dtype, rows):
    r = _references(dtype)
    w = r["w"]
    out = _in_rows(lambda v: so3.log(so3.exp(v)), w, rows)
    err = _sign_free_near_pi(out, w.double(), r["theta"], 1)
    assert float(err.max()) <= VALUE_TOL[dtype], _report(err, r["theta"])


@pytest.mark.compile
def test_compiled_log_values(dtype):
    """``torchlie.compiled.so3.log`` within the same tolerance, and the rotation vectors of
    ``log(exp(w))`` as well."""
    r = _references(dtype)
    log = compiled.so3.log
    err = _sign_free_near_pi(log(r["R_in"]), r["log_ref"], r["theta"], 1)
    assert float(err.max()) <= VALUE_TOL[dtype], _report(err, r["theta"])
    err = _sign_free_near_pi(log(so3.exp(r["w"])), r["w"].double(), r["theta"], 1)
    assert float(err.max()) <= VALUE_TOL[dtype], _report(err, r["theta"])


@BATCHES
def test_quaternion_from_matrix(dtype, rows):
    r = _references(dtype)
    out = _in_rows(quaternion.from_matrix, r["R_in"], rows)
    err = _sign_free_near_pi(out, r["quat_ref"], r["theta"], 1)
    assert float(err.max()) <= VALUE_TOL[dtype], _report(err, r["theta"])


@BATCHES
def test_quaternion_to_matrix(dtype, rows):
    r = _references(dtype)
    err = _rel(_in_rows(quaternion.to_matrix, r["q_in"], rows), r["q_matrix_ref"], 2)
    assert float(err.max()) <= VALUE_TOL[dtype], _report(err, r["theta"])


def test_exp_gradient(dtype):
    r = _references(dtype)
    J = torch.func.vmap(torch.func.jacrev(so3.exp))(r["w"])
    assert bool(torch.isfinite(J).all())
    err = _rel(J, r["exp_grad_ref"], 3)
    assert float(err.max()) <= GRAD_TOL[dtype], _report(err, r["theta"])


def test_log_gradient_in_tangent_coordinates(dtype):
    """d/dd log(R Exp(d)) at d = 0 is Jr(log R)^-1, finite up to and including pi."""
    r = _references(dtype)
    R = r["R_in"]
    d0 = torch.zeros(R.shape[0], 3, dtype=dtype)
    J = torch.func.vmap(torch.func.jacrev(lambda d, X: so3.log(X @ so3.exp(d))))(d0, R)
    assert bool(torch.isfinite(J).all())
    err = _rel(J, r["jr_inv_ref"], 2)
    # at pi the reference was taken for one sign of the axis; Jr^-1(-w) = Jl^-1(w) = Jr^-1(w)^T
    flipped = _rel(J.transpose(-1, -2), r["jr_inv_ref"], 2)
    at_pi = r["theta"].double() > PI - 1e-12
    err = torch.where(at_pi, torch.minimum(err, flipped), err)
    assert float(err.max()) <= GRAD_TOL[dtype], _report(err, r["theta"])


def test_log_of_exp_gradient(dtype):
    r = _references(dtype)
    J = torch.func.vmap(torch.func.jacrev(lambda w: so3.log(so3.exp(w))))(r["w"])
    assert bool(torch.isfinite(J).all())
    eye = torch.eye(3, dtype=torch.float64).expand(J.shape)
    err = _rel(J, eye, 2)
    # at exactly (float) pi the log may return -w: log o exp jumps there, and only finiteness
    # is required
    below = r["theta"].double() < PI - 1e-12
    err = torch.where(below, err, torch.zeros_like(err))
    assert float(err.max()) <= GRAD_TOL[dtype], _report(err, r["theta"])


# Plain backward passes (no create_graph) take the forward-only derivative evaluation of the
# custom Functions; the tests above (jacrev) take the differentiable one.  Both meet the targets.


def _rows_of_plain_backward(out: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """d out / d x per element, one ``torch.autograd.grad`` per output entry (no create_graph)."""
    flat = out.flatten(1)
    rows = []
    for i in range(flat.shape[1]):
        g = torch.zeros_like(flat)
        g[:, i] = 1.0
        rows.append(torch.autograd.grad(flat, x, g, retain_graph=True)[0])
    return torch.stack(rows, 1).unflatten(1, out.shape[1:])


def _plain_jacobian(fn, x: torch.Tensor, *rest: torch.Tensor, rows: int | None) -> torch.Tensor:
    """:func:`_rows_of_plain_backward` of ``fn(x, *rest)`` with respect to ``x``, over the whole
    sample set, in batches of ``rows`` or over a large batch (``rows = LARGE``)."""
    whole = [(x, *rest)]
    if rows == LARGE:
        whole = [tuple(_tiled(t) for t in whole[0])]
    parts = whole if rows in (None, LARGE) else zip(*(t.split(rows) for t in whole[0]), strict=True)
    out = []
    for first, *others in parts:
        leaf = first.clone().requires_grad_()
        out.append(_rows_of_plain_backward(fn(leaf, *others), leaf))
    return torch.cat(out)[: x.shape[0]]


@BATCHES
def test_exp_gradient_plain_backward(dtype, rows):
    r = _references(dtype)
    J = _plain_jacobian(so3.exp, r["w"], rows=rows)
    assert bool(torch.isfinite(J).all())
    err = _rel(J, r["exp_grad_ref"], 3)
    assert float(err.max()) <= GRAD_TOL[dtype], _report(err, r["theta"])


@BATCHES
def test_log_gradient_plain_backward(dtype, rows):
    r = _references(dtype)
    R = r["R_in"]
    d0 = torch.zeros(R.shape[0], 3, dtype=dtype)
    J = _plain_jacobian(lambda d, X: so3.log(X @ so3.exp(d)), d0, R, rows=rows)
    assert bool(torch.isfinite(J).all())
    err = _rel(J, r["jr_inv_ref"], 2)
    flipped = _rel(J.transpose(-1, -2), r["jr_inv_ref"], 2)
    at_pi = r["theta"].double() > PI - 1e-12
    err = torch.where(at_pi, torch.minimum(err, flipped), err)
    assert float(err.max()) <= GRAD_TOL[dtype], _report(err, r["theta"])


@BATCHES
def test_log_of_exp_gradient_plain_backward(dtype, rows):
    r = _references(dtype)
    J = _plain_jacobian(lambda w: so3.log(so3.exp(w)), r["w"], rows=rows)
    assert bool(torch.isfinite(J).all())
    err = _rel(J, torch.eye(3, dtype=torch.float64).expand(J.shape), 2)
    below = r["theta"].double() < PI - 1e-12
    err = torch.where(below, err, torch.zeros_like(err))
    assert float(err.max()) <= GRAD_TOL[dtype], _report(err, r["theta"])


def _jacobian_derivative_reference(fn, w: np.ndarray) -> np.ndarray:
    """``d fn(w)_ij / d w_k`` as ``[i, j, k]``: central differences of the 60-digit reference
    (step 1e-20: truncation and rounding both far below float64's)."""
    h = ref.mp.mpf("1e-20")
    cols = []
    for k in range(3):
        lo, hi = list(ref._mpf3(w)), list(ref._mpf3(w))
        lo[k], hi[k] = lo[k] - h, hi[k] + h
        A, B = fn(hi), fn(lo)
        cols.append([[(A[i][j] - B[i][j]) / (2 * h) for j in range(3)] for i in range(3)])
    return np.array([[[float(c[i][j]) for c in cols] for j in range(3)] for i in range(3)])


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("name", ["jac_right", "jac_right_inv"])
def test_derivatives_of_the_jacobians(name, dtype):
    # The Jacobians' own derivatives (second derivatives of exp and log, as a Gauss-Newton or
    # second-order method takes them) within 8 ulp at every angle region, the series' switches
    # included, in forward and reverse mode.
    w, theta = rotvecs(ANGLES[:8] + [2.0, 2.5], n_random=2, dtype=dtype)
    reference = getattr(ref, name)
    expected = torch.tensor(
        np.stack([_jacobian_derivative_reference(reference, v) for v in w.double().numpy()])
    )
    fn = getattr(so3, name)
    for transform in (torch.func.jacfwd, torch.func.jacrev):
        got = torch.func.vmap(transform(fn))(w)
        err = _rel(got, expected, 3)
        assert float(err.max()) <= GRAD_TOL[dtype], (transform, _report(err, theta))
