"""The matrix forms of small batches agree with the component-wise kernels to a few ulp and are
taken only where they are meant to be (small CPU batches, eager, outside ``torch.func``
transforms)."""

from __future__ import annotations

import pytest
import torch
from samplers import rotvecs

from torchlie import _layout, _small, quaternion, se3, so3

DTYPES = [torch.float32, torch.float64]


def _values_and_grads(fn, *xs, upstream=None):
    """``fn(*xs)`` and its gradients for the upstream gradient ``upstream`` (reshaped to the
    result; a seeded normal draw without it)."""
    leaves = [x.clone().requires_grad_() for x in xs]
    y = fn(*leaves)
    if upstream is None:
        g = torch.randn(y.shape, generator=torch.Generator().manual_seed(8), dtype=y.dtype)
    else:
        g = upstream.reshape(y.shape)
    return y.detach(), torch.autograd.grad(y, leaves, g)


def _pieces(x):
    """``x`` in batches of 1 to 1000 rows (one of two batch dims), each below the bounds."""
    return [x[:1], x[1:3], x[3:20], x[20:32].unflatten(0, (3, 4)), *x[32:].split(1000)]


SHEPPERD_OPS = [quaternion.from_matrix, so3.log, lambda R: se3.log(se3.from_rt(R, R[..., 0]))]


@pytest.mark.parametrize("fn", SHEPPERD_OPS)
def test_shepperd_forms_of_one_element_and_of_none(fn):
    """An element's result is the same alone, in a batch of one and in a batch of three."""
    R = so3.exp(torch.tensor([[0.3, -2.0, 1.0], [0.0, 0.0, 0.0], [3.0, 0.1, 0.0]]))
    whole = fn(R)
    for i, one in enumerate(R.unbind(0)):
        assert torch.equal(fn(one), whole[i])
        assert torch.equal(fn(one.unsqueeze(0)), whole[i : i + 1])
    assert fn(R[:0]).shape == (0,) + whole.shape[1:]


def test_at_pi_the_canonical_representative():
    """``w = 0``: the largest vector component positive (quaternion module docstring), whatever
    the signs of the zero entries of the matrix."""
    g = torch.Generator().manual_seed(15)
    for dtype in DTYPES:
        for axis in range(3):
            R = -torch.eye(3, dtype=dtype)
            R[axis, axis] = 1.0  # pi about the axis
            zeros = ~torch.eye(3, dtype=torch.bool)
            for _ in range(8):
                signs = torch.randint(0, 2, (3, 3), generator=g).to(dtype) * -2 + 1
                Rs = torch.where(zeros, torch.zeros_like(R).mul_(signs), R)
                q = torch.zeros(4, dtype=dtype)
                q[1 + axis] = 1.0
                assert torch.equal(quaternion.from_matrix(Rs), q)
                assert not quaternion.from_matrix(Rs)[0].signbit()
                assert torch.equal(so3.log(Rs), torch.pi * q[1:])
                xi = se3.log(se3.from_rt(Rs, torch.zeros(3, dtype=dtype)))
                assert torch.equal(xi[3:], torch.pi * q[1:])


def test_nan_stays_in_its_element():
    R = so3.exp(torch.randn(6, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(9)))
    R[2, 1, 0] = float("nan")
    for fn in SHEPPERD_OPS:
        out = fn(R)
        assert out[2].isnan().all()
        assert torch.equal(out[[0, 1, 3, 4, 5]], fn(R[[0, 1, 3, 4, 5]]))


# ----------------------------------------------------------------------------------------------
# Matrix forms
# ----------------------------------------------------------------------------------------------

MATRIX_FORMS = (
    "multiply",
    "to_matrix",
    "exp_float32",
    "se3_exp_float32",
    "from_matrix",
    "log",
    "se3_log",
)
BACKWARD_FORMS = (
    "multiply_backward",
    "exp_backward",
    "log_backward",
    "to_matrix_backward",
    "se3_exp_backward",
    "se3_log_backward",
)


def _counted(monkeypatch):
    """Calls of each matrix form, by name."""
    calls = {name: 0 for name in MATRIX_FORMS + BACKWARD_FORMS}

    def wrap(name):
        form = getattr(_small, name)

        def counted(*args):
            calls[name] += 1
            return form(*args)

        return counted

    for name in calls:
        monkeypatch.setattr(_small, name, wrap(name))
    return calls


def _sampled(dtype):
    """Rotation vectors at 0, tiny angles, pi, just below pi and beyond; quaternions of them,
    scaled (to_matrix does not see the scale) and shuffled against each other."""
    w, _ = rotvecs(dtype=dtype)
    w = torch.cat((w, 7.0 * w[-300:]))
    g = torch.Generator().manual_seed(11)
    q = quaternion.from_rotvec(w) * torch.exp(torch.randn(w.shape[0], 1, generator=g, dtype=dtype))
    p = q[torch.randperm(q.shape[0], generator=g)]
    return w, q, p


def _norm_error(a, b, nd):
    """Norm-wise difference per element, relative to ``b``'s norm (absolute where it is 0)."""
    dims = tuple(range(-nd, 0))
    diff = (a.double() - b.double()).square().sum(dims).sqrt()
    return diff / b.double().square().sum(dims).sqrt().clamp_min(1.0 if nd else 0.0).where(
        b.double().square().sum(dims) > 0, 1.0
    )


def _matrix_form_ops(dtype):
    """(the forms taken, forward first, each as often as it is taken; op, inputs, trailing dims
    of the result)"""
    w, q, p = _sampled(dtype)
    g = torch.Generator().manual_seed(14)
    R = so3.exp(w)
    # a perturbed copy: the orthogonalisation step and the pivot see non-rotations too
    Rp = R + 1e-3 * torch.randn(R.shape, generator=g, dtype=dtype)
    xi = torch.cat((torch.randn(w.shape, generator=g, dtype=dtype), w), -1)
    ops = [
        (("multiply", "multiply_backward"), quaternion.multiply, (q, p), 1),
        # batch shapes broadcast
        (("multiply", "multiply_backward"), quaternion.multiply, (q, p[5]), 1),
        (("to_matrix", "to_matrix_backward"), quaternion.to_matrix, (q,), 2),
        ((), quaternion.apply, (q, w), 1),  # its backward: fewer calls, no form of its own
        (("from_matrix",), quaternion.from_matrix, (R,), 1),
        (("from_matrix",), quaternion.from_matrix, (Rp,), 1),
        (("log", "log_backward"), so3.log, (R,), 1),
        (("log", "log_backward"), so3.log, (Rp,), 1),
        (("se3_log", "se3_log_backward"), se3.log, (se3.exp(xi),), 1),
    ]
    if dtype == torch.float32:
        ops += [
            (("exp_float32", "exp_backward"), so3.exp, (w,), 2),
            (("se3_exp_float32", "se3_exp_backward"), se3.exp, (xi,), 2),
        ]
    else:  # the compensated kernel forward, the matrix form backward
        ops.append((("exp_backward",), so3.exp, (w,), 2))
        ops.append((("se3_exp_backward",), se3.exp, (xi,), 2))
    return ops


SHEPPERD = ("from_matrix", "log", "se3_log")


def _other_sign(name, y, x):
    """Shepperd's forms: the result for the other sign of the rotation's quaternion, and where
    that sign is decided by rounding (``w`` within 16 eps of 0, at pi)."""
    eps = torch.finfo(y.dtype).eps
    if name == "from_matrix":
        return -y, y[..., 0].abs() < 16 * eps
    phi = y[..., 3:] if name == "se3_log" else y
    near = torch.linalg.vector_norm(phi, dim=-1) > torch.pi - 32 * eps
    if name == "log":
        return -y, near
    # rho = Jl(phi)^-1 t: of the two terms odd in phi only -hat(phi) t / 2
    rho = y[..., :3] + torch.linalg.cross(phi, x[..., :3, 3])
    return torch.cat((rho, -phi), -1), near


@pytest.mark.parametrize("dtype", DTYPES)
def test_matrix_forms_agree_with_the_component_kernels(dtype, monkeypatch):
    """Norm-wise within 3 eps of the component kernels (each is within about 1.5 eps of the
    exact value, test_precision.py), 2 eps for float32 ``so3.exp`` and ``se3.exp`` (rounded
    once from float64), every sampler angle, batches of 1 to 1000 rows; gradients (the
    closed-form backwards, of which some have matrix forms too, fed the forms' results where
    they read the output) within 8 eps of their largest entry, times ``theta^2 / pi^2`` beyond
    pi for ``se3.exp`` (whose backward sums terms of size ``theta^2 |rho| |g|``: at ``7 pi``
    both kernels are up to 14 eps off the derivative of a 60-digit ``expm``).
    At pi Shepperd's forms may give the other sign of the quaternion (the rotation is the same),
    where its ``w`` is rounding noise: that one is compared there (and not the gradients)."""
    e = torch.finfo(dtype).eps
    for forms, fn, args, nd in _matrix_form_ops(dtype):
        name = forms[0] if forms else fn.__name__
        calls = _counted(monkeypatch)
        count = len(_pieces(args[0]))
        pieces = list(zip(*(_pieces(a) if a.dim() > 1 else [a] * count for a in args), strict=True))
        formed = [_values_and_grads(fn, *piece) for piece in pieces]
        assert all(calls[f] == forms.count(f) * len(pieces) for f in forms), forms
        monkeypatch.setattr(_small, "MATRIX_ROWS", 0)
        plain = [_values_and_grads(fn, *piece) for piece in pieces]
        assert all(calls[f] == forms.count(f) * len(pieces) for f in forms), forms
        monkeypatch.setattr(_small, "MATRIX_ROWS", 1024)
        for (y1, g1), (y2, g2), piece in zip(formed, plain, pieces, strict=True):
            assert y1.shape == y2.shape
            err = _norm_error(y1, y2, nd)
            if name in SHEPPERD:
                other, near = _other_sign(name, y2, piece[0])
                err_other = _norm_error(y1, other, nd)
                flipped = near & (err_other < err)
                err = torch.where(flipped, err_other, err)
                g1, g2 = ([g[~flipped] for g in grads] for grads in (g1, g2))
            assert float(err.max()) <= (2 if "exp" in name else 3) * e, name
            scale = 1.0
            if name.startswith("se3_exp"):  # terms of size theta^2 |rho| |g| beyond pi
                theta2 = piece[0][..., 3:].double().square().sum(-1)
                scale = (theta2 / torch.pi**2).clamp_min(1.0).unsqueeze(-1)
            for a, b in zip(g1, g2, strict=True):
                tol = 8 * e * max(1.0, float(b.abs().max())) * scale
                assert bool(((a - b).abs() <= tol).all()), name


def test_matrix_forms_taken_only_where_meant(monkeypatch):
    """Eager CPU batches below MATRIX_ROWS; not at MATRIX_ROWS, under vmap, while compiling, nor
    for float64 ``so3.exp`` (its compensated kernel)."""
    x = torch.zeros(3)
    assert _small.matrix_form(x, _small.MATRIX_ROWS - 1)
    assert not _small.matrix_form(x, _small.MATRIX_ROWS)
    calls = _counted(monkeypatch)
    g = torch.Generator().manual_seed(12)

    def run(q, w, R, T):
        quaternion.multiply(q, q)
        quaternion.to_matrix(q)
        so3.exp(w)
        so3.exp(w.double())
        se3.exp(torch.cat((w, w), -1))
        se3.exp(torch.cat((w, w), -1).double())
        quaternion.from_matrix(R)
        so3.log(R)
        return se3.log(T)

    def inputs(rows):
        q = torch.randn(rows, 4, generator=g)
        out = q, q[:, :3], so3.exp(q[:, 1:]), se3.exp(torch.cat((q, q[:, 2:]), -1))
        calls.update(dict.fromkeys(calls, 0))
        return out

    for rows, taken in ((_small.MATRIX_ROWS - 1, 1), (_small.MATRIX_ROWS, 0)):
        run(*inputs(rows))
        assert calls == dict.fromkeys(MATRIX_FORMS, taken) | dict.fromkeys(BACKWARD_FORMS, 0)
    torch.func.vmap(run)(*inputs(5))
    assert not any(calls.values())
    monkeypatch.setattr(_layout, "_is_compiling", lambda: True)
    assert not _small.matrix_form(x, 1)


def test_matrix_forms_at_the_edges():
    """One element, none, a NaN kept in its element, a zero quaternion (NaN: no rotation),
    angles up to float32's largest (a rotation still)."""
    g = torch.Generator().manual_seed(13)
    q = torch.randn(6, 4, generator=g)
    w = torch.randn(6, 3, generator=g)
    assert torch.equal(quaternion.multiply(q[2], q[3]), quaternion.multiply(q, q[[3]])[2])
    assert torch.equal(quaternion.to_matrix(q[2]), quaternion.to_matrix(q)[2])
    xi = torch.cat((torch.randn(6, 3, generator=g), w), -1)
    assert torch.equal(so3.exp(w[2]), so3.exp(w)[2])
    assert torch.equal(se3.exp(xi[2]), se3.exp(xi)[2])
    assert torch.equal(se3.exp(torch.zeros(6)), torch.eye(4))
    assert quaternion.to_matrix(q[:0]).shape == (0, 3, 3) and so3.exp(w[:0]).shape == (0, 3, 3)
    assert se3.exp(xi[:0]).shape == (0, 4, 4)
    q[2, 1] = float("nan")
    w[2, 1] = float("nan")
    xi[2, 4] = float("nan")
    q[4] = 0.0
    for out in (quaternion.multiply(q, q), quaternion.to_matrix(q), so3.exp(w), se3.exp(xi)[:, :3]):
        assert out[2].isnan().all()
        assert out[[0, 1, 3, 5]].isfinite().all()
    assert quaternion.to_matrix(q)[4].isnan().all()
    assert torch.equal(quaternion.multiply(q, q)[4], torch.zeros(4))
    big = torch.tensor([[0.3, 0.5, -0.2]]) * torch.tensor([[1e10], [1e30], [3e38]])
    R = so3.exp(big)
    assert float((R @ R.mT - torch.eye(3)).abs().max()) <= 4 * torch.finfo(torch.float32).eps
    torch.testing.assert_close(R, so3.exp(big.double()).float(), atol=2e-7, rtol=0)


def test_backward_forms_taken_only_where_meant(monkeypatch):
    """Plain backward passes of batches below MATRIX_ROWS; not at MATRIX_ROWS, nor with
    ``create_graph`` (the differentiable backward, for higher derivatives)."""
    calls = _counted(monkeypatch)
    g = torch.Generator().manual_seed(16)
    for rows, taken, create_graph in ((5, 1, False), (_small.MATRIX_ROWS, 0, False), (5, 0, True)):
        w = torch.randn(rows, 3, generator=g, dtype=torch.float64)
        R = so3.exp(w)
        xi = torch.cat((w, w), -1)
        T = se3.exp(xi)
        calls.update(dict.fromkeys(calls, 0))
        for fn, x in (
            (so3.exp, w),
            (so3.log, R),
            (quaternion.to_matrix, quaternion.from_matrix(R)),
            (se3.exp, xi),
            (se3.log, T),
            (lambda x: quaternion.multiply(x, x.flip(-1)), quaternion.from_matrix(R)),
        ):
            leaf = x.clone().requires_grad_()
            torch.autograd.grad(fn(leaf).sum(), leaf, create_graph=create_graph)
        assert {k: calls[k] for k in BACKWARD_FORMS} == dict.fromkeys(BACKWARD_FORMS, taken)


def _group_ops(dtype):
    """(name, op, inputs) of the ops with a small-batch path: matrix forms or batched products."""
    g = torch.Generator().manual_seed(17)
    w = torch.randn(7, 3, generator=g, dtype=dtype)
    xi = torch.randn(7, 6, generator=g, dtype=dtype)
    p = torch.randn(7, 3, generator=g, dtype=dtype)
    q, R, T, T2 = quaternion.from_rotvec(w), so3.exp(w), se3.exp(xi), se3.exp(xi.flip(0))
    return [
        ("so3.exp", so3.exp, (w,)),
        ("so3.log", so3.log, (R,)),
        ("so3.act", so3.act, (R, p)),
        ("quaternion.multiply", quaternion.multiply, (q, q.flip(0))),
        ("quaternion.apply", quaternion.apply, (q, p)),
        ("quaternion.to_matrix", quaternion.to_matrix, (q,)),
        ("quaternion.from_matrix", quaternion.from_matrix, (R,)),
        ("se3.exp", se3.exp, (xi,)),
        ("se3.log", se3.log, (T,)),
        ("se3.compose", se3.compose, (T, T2)),
        ("se3.inverse", se3.inverse, (T,)),
        ("se3.act", se3.act, (T, p)),
    ]


@pytest.mark.parametrize("dtype", DTYPES)
def test_an_element_alone_and_in_a_batch(dtype):
    """Each element's value and gradients are the same, bit for bit, alone (no batch dim), in a
    batch of one, in the whole batch and in a batch of two dims, and with the other operand
    shared (broadcast): small batches never hand their products to a kernel that sums in
    another order."""
    for name, fn, args in _group_ops(dtype):
        y0 = fn(*args)
        gy = torch.randn(y0.shape, generator=torch.Generator().manual_seed(18), dtype=dtype)
        y, grads = _values_and_grads(fn, *args, upstream=gy)
        y2, grads2 = _values_and_grads(fn, *(a.unflatten(0, (7, 1)) for a in args), upstream=gy)
        assert torch.equal(y2.flatten(0, 1), y), name
        assert all(torch.equal(a.flatten(0, 1), b) for a, b in zip(grads2, grads, strict=True))
        for i in range(7):
            for part in ([a[i] for a in args], [a[i : i + 1] for a in args]):
                one, one_grads = _values_and_grads(fn, *part, upstream=gy[i])
                assert torch.equal(one.reshape(y[i].shape), y[i]), (name, i)
                for a, b in zip(one_grads, grads, strict=True):
                    assert torch.equal(a.reshape(b[i].shape), b[i]), (name, i)
            if len(args) == 2:  # the second operand shared by the batch
                shared, (d_first, _) = _values_and_grads(fn, args[0], args[1][i], upstream=gy)
                alone, (d_alone, _) = _values_and_grads(fn, args[0][3], args[1][i], upstream=gy[3])
                assert torch.equal(shared[3], alone) and torch.equal(d_first[3], d_alone), name


POSE_FORMS = ("pose_compose", "pose_compose_grads", "pose_inverse", "pose_inverse_grads")


@pytest.mark.parametrize("dtype", DTYPES)
def test_pose_forms_agree_with_the_block_products(dtype, monkeypatch):
    """``se3.compose`` and ``se3.inverse`` (forward and backward) below POSE_ROWS poses take
    their ``4 x 4`` product forms, and agree with the products of the blocks they replace to an
    ulp of the largest entry (the same sums, with zero terms added); NaN bottom rows are not read
    and a NaN entry spoils only its own pose's result."""
    calls = {name: 0 for name in POSE_FORMS}
    for name in POSE_FORMS:
        form = getattr(_small, name)

        def counted(*args, name=name, form=form):
            calls[name] += 1
            return form(*args)

        monkeypatch.setattr(_small, name, counted)
    g = torch.Generator().manual_seed(31)
    e = torch.finfo(dtype).eps
    for rows in (1, 2, 7, _small.POSE_ROWS - 1):
        A, B = se3.random(2, rows, generator=g, dtype=dtype)
        A = A.clone()
        A[..., 3, :] = torch.nan  # not read
        A[0, 0, 0] = torch.nan  # one pose spoiled
        G = torch.randn(rows, 4, 4, generator=g, dtype=dtype)
        results = []
        for pose_rows in (_small.POSE_ROWS, 0):
            monkeypatch.setattr(_small, "POSE_ROWS", pose_rows)
            calls.update(dict.fromkeys(calls, 0))
            a, b = A.clone().requires_grad_(), B.clone().requires_grad_()
            out, inv = se3.compose(a, b), se3.inverse(a)
            grads = torch.autograd.grad(out, (a, b), G) + torch.autograd.grad(inv, a, G)
            results.append((out.detach(), inv.detach(), *grads))
            assert calls == dict.fromkeys(POSE_FORMS, int(pose_rows > 0))
        for formed, plain in zip(*results, strict=True):
            assert not bool(formed[1:].isnan().any())
            assert bool((formed[1:, 3, :3] == 0).all())
            torch.testing.assert_close(formed[1:], plain[1:], rtol=0, atol=4 * e)
            # the NaN pose: NaN wherever the blocks' products read its NaN entry (the forms may
            # spread it over more of that pose's entries: its products with zeros)
            assert bool((formed[0].isnan() | ~plain[0].isnan()).all())
    monkeypatch.setattr(_small, "POSE_ROWS", 32)
    assert _small.pose_form(torch.zeros(3), 31) and not _small.pose_form(torch.zeros(3), 32)
    assert not _small.pose_form(torch.zeros(3, device="meta"), 1)
