"""The same numbers give the same bits, whatever their memory layout, batch size or broadcast.

Every public op that takes tensors is fed its inputs contiguous, transposed (the batch dimension
innermost in memory), sliced (every other row of a larger tensor) and expanded (one element
repeated with stride 0), at a small batch and at a batch large enough for the large-batch
kernels (:mod:`torchlie._layout`); its results must be bitwise those of the contiguous call, and
the rows of a large batch those of a small batch holding the same elements.  Binary ops are
also checked broadcast against the same pairs called one by one.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import pytest
import torch

from torchlie import conversions, nn, quaternion, se3, so3, statistics

SMALL = 7
LARGE = 20_000
DTYPES = [torch.float32, torch.float64]


# ----------------------------------------------------------------------------------------------
# Inputs: each kind draws (n, *event) in float64 and casts
# ----------------------------------------------------------------------------------------------


def _rotvec(n: int, g: torch.Generator) -> torch.Tensor:
    axis = torch.randn(n, 3, generator=g, dtype=torch.float64)
    axis = axis / axis.norm(dim=-1, keepdim=True)
    angle = torch.rand(n, 1, generator=g, dtype=torch.float64) * math.pi
    angle[::5] = math.pi - angle[::5] * 1e-6  # near pi
    angle[1::5] *= 1e-5  # near 0
    return axis * angle


def _rotation(n: int, g: torch.Generator) -> torch.Tensor:
    return so3.exp(_rotvec(n, g))


def _pose(n: int, g: torch.Generator) -> torch.Tensor:
    return se3.from_rt(_rotation(n, g), torch.randn(n, 3, generator=g, dtype=torch.float64))


KINDS: dict[str, Callable[[int, torch.Generator], torch.Tensor]] = {
    "rotvec": _rotvec,
    "quat": lambda n, g: torch.randn(n, 4, generator=g, dtype=torch.float64),
    "point": lambda n, g: torch.randn(n, 3, generator=g, dtype=torch.float64),
    "scalar": lambda n, g: torch.rand(n, generator=g, dtype=torch.float64) * 2.0 - 0.5,
    "twist": lambda n, g: torch.cat(
        (torch.randn(n, 3, generator=g, dtype=torch.float64), _rotvec(n, g)), -1
    ),  # fmt: skip
    "R": _rotation,
    "T": _pose,
    "M": lambda n, g: torch.randn(n, 3, 3, generator=g, dtype=torch.float64),
    "M4": lambda n, g: torch.randn(n, 4, 4, generator=g, dtype=torch.float64),
    "euler": lambda n, g: (torch.rand(n, 3, generator=g, dtype=torch.float64) - 0.5) * 6.0,
    "r6": lambda n, g: torch.randn(n, 6, generator=g, dtype=torch.float64),
    "r9": lambda n, g: torch.randn(n, 9, generator=g, dtype=torch.float64),
    "pos_quat": lambda n, g: torch.randn(n, 7, generator=g, dtype=torch.float64),
    "su2": lambda n, g: quaternion.to_su2(torch.randn(n, 4, generator=g, dtype=torch.float64)),
    "Rset": lambda n, g: so3.exp(0.5 * torch.randn(n, 3, 3, generator=g, dtype=torch.float64)),
    "Tset": lambda n, g: se3.exp(0.5 * torch.randn(n, 3, 6, generator=g, dtype=torch.float64)),
    "weights": lambda n, g: torch.rand(n, 3, generator=g, dtype=torch.float64) + 0.1,
    "cloud": lambda n, g: torch.randn(n, 5, 3, generator=g, dtype=torch.float64),
    "query": lambda n, g: torch.rand(n, generator=g, dtype=torch.float64) * 3.0,
}

_EULER = ("xyz", "ZYX", "zxz", "YXY")
_KEY_TIMES = torch.tensor([0.0, 1.0, 2.5])


def _keys(dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(99)
    w = torch.randn(3, 6, generator=g, dtype=torch.float64)
    return so3.exp(w[:, 3:]).to(dtype), se3.exp(w).to(dtype)


def _randn(core_fn):
    def run(mean, std):
        return core_fn(mean, std, generator=torch.Generator().manual_seed(3))

    return run


#: (name, function, kinds of its tensor arguments); non-tensor arguments are bound here.
OPS: list[tuple[str, Callable, tuple[str, ...]]] = [
    # so3
    ("so3.hat", so3.hat, ("rotvec",)),
    ("so3.vee", so3.vee, ("M",)),
    ("so3.exp", so3.exp, ("rotvec",)),
    ("so3.log", so3.log, ("R",)),
    ("so3.compose", so3.compose, ("R", "R")),
    ("so3.inverse", so3.inverse, ("R",)),
    ("so3.act", so3.act, ("R", "point")),
    ("so3.adjoint", so3.adjoint, ("R",)),
    ("so3.jac_left", so3.jac_left, ("rotvec",)),
    ("so3.jac_right", so3.jac_right, ("rotvec",)),
    ("so3.jac_left_inv", so3.jac_left_inv, ("rotvec",)),
    ("so3.jac_right_inv", so3.jac_right_inv, ("rotvec",)),
    ("so3.is_valid", so3.is_valid, ("M",)),
    ("so3.project", so3.project, ("M",)),
    ("so3.distance", so3.distance, ("R", "R")),
    ("so3.interpolate", so3.interpolate, ("R", "R", "scalar")),
    ("so3.ad", so3.ad, ("rotvec",)),
    ("so3.rplus", so3.rplus, ("R", "rotvec")),
    ("so3.rminus", so3.rminus, ("R", "R")),
    ("so3.lplus", so3.lplus, ("R", "rotvec")),
    ("so3.lminus", so3.lminus, ("R", "R")),
    ("so3.between", so3.between, ("R", "R")),
    ("so3.jac_compose", so3.jac_compose, ("R", "R")),
    ("so3.jac_inverse", so3.jac_inverse, ("R",)),
    ("so3.jac_act", so3.jac_act, ("R", "point")),
    ("so3.jac_rplus", so3.jac_rplus, ("R", "rotvec")),
    ("so3.jac_rminus", so3.jac_rminus, ("R", "R")),
    ("so3.jac_between", so3.jac_between, ("R", "R")),
    # se3
    ("se3.hat", se3.hat, ("twist",)),
    ("se3.vee", se3.vee, ("M4",)),
    ("se3.exp", se3.exp, ("twist",)),
    ("se3.log", se3.log, ("T",)),
    ("se3.compose", se3.compose, ("T", "T")),
    ("se3.inverse", se3.inverse, ("T",)),
    ("se3.act", se3.act, ("T", "point")),
    ("se3.adjoint", se3.adjoint, ("T",)),
    ("se3.ad", se3.ad, ("twist",)),
    ("se3.jac_left", se3.jac_left, ("twist",)),
    ("se3.jac_right", se3.jac_right, ("twist",)),
    ("se3.jac_left_inv", se3.jac_left_inv, ("twist",)),
    ("se3.jac_right_inv", se3.jac_right_inv, ("twist",)),
    ("se3.is_valid", se3.is_valid, ("M4",)),
    ("se3.from_rt", se3.from_rt, ("R", "point")),
    ("se3.to_rt", se3.to_rt, ("T",)),
    ("se3.from_pos_quat", se3.from_pos_quat, ("pos_quat",)),
    ("se3.to_pos_quat", se3.to_pos_quat, ("T",)),
    ("se3.interpolate", se3.interpolate, ("T", "T", "scalar")),
    ("se3.distance", se3.distance, ("T", "T")),
    ("se3.rplus", se3.rplus, ("T", "twist")),
    ("se3.rminus", se3.rminus, ("T", "T")),
    ("se3.lplus", se3.lplus, ("T", "twist")),
    ("se3.lminus", se3.lminus, ("T", "T")),
    ("se3.between", se3.between, ("T", "T")),
    ("se3.jac_compose", se3.jac_compose, ("T", "T")),
    ("se3.jac_inverse", se3.jac_inverse, ("T",)),
    ("se3.jac_act", se3.jac_act, ("T", "point")),
    ("se3.jac_rplus", se3.jac_rplus, ("T", "twist")),
    ("se3.jac_rminus", se3.jac_rminus, ("T", "T")),
    ("se3.jac_between", se3.jac_between, ("T", "T")),
    # quaternion
    ("quaternion.multiply", quaternion.multiply, ("quat", "quat")),
    ("quaternion.conjugate", quaternion.conjugate, ("quat",)),
    ("quaternion.inverse", quaternion.inverse, ("quat",)),
    ("quaternion.normalize", quaternion.normalize, ("quat",)),
    ("quaternion.canonicalize", quaternion.canonicalize, ("quat",)),
    ("quaternion.apply", quaternion.apply, ("quat", "point")),
    ("quaternion.exp", quaternion.exp, ("quat",)),
    ("quaternion.log", quaternion.log, ("quat",)),
    ("quaternion.slerp", quaternion.slerp, ("quat", "quat", "scalar")),
    ("quaternion.from_matrix", quaternion.from_matrix, ("R",)),
    ("quaternion.to_matrix", quaternion.to_matrix, ("quat",)),
    ("quaternion.from_rotvec", quaternion.from_rotvec, ("rotvec",)),
    ("quaternion.to_rotvec", quaternion.to_rotvec, ("quat",)),
    ("quaternion.is_unit", quaternion.is_unit, ("quat",)),
    ("quaternion.to_xyzw", quaternion.to_xyzw, ("quat",)),
    ("quaternion.from_xyzw", quaternion.from_xyzw, ("quat",)),
    ("quaternion.to_jpl", quaternion.to_jpl, ("quat",)),
    ("quaternion.from_jpl", quaternion.from_jpl, ("quat",)),
    ("quaternion.left_matrix", quaternion.left_matrix, ("quat",)),
    ("quaternion.right_matrix", quaternion.right_matrix, ("quat",)),
    ("quaternion.to_su2", quaternion.to_su2, ("quat",)),
    ("quaternion.from_su2", quaternion.from_su2, ("su2",)),
    ("quaternion.derivative.body", quaternion.derivative, ("quat", "point")),
    (
        "quaternion.derivative.world",
        lambda q, w: quaternion.derivative(q, w, frame="world"),
        ("quat", "point"),
    ),
    ("quaternion.integrate.body", quaternion.integrate, ("quat", "point", "scalar")),
    (
        "quaternion.integrate.world",
        lambda q, w, dt: quaternion.integrate(q, w, dt, frame="world"),
        ("quat", "point", "scalar"),
    ),
    # conversions
    *[
        (f"conversions.euler_to_quaternion.{s}",
         lambda a, s=s: conversions.euler_to_quaternion(a, s), ("euler",))
        for s in _EULER
    ],
    *[
        (f"conversions.quaternion_to_euler.{s}",
         lambda q, s=s: conversions.quaternion_to_euler(q, s), ("quat",))
        for s in _EULER
    ],
    *[
        (f"conversions.euler_to_matrix.{s}",
         lambda a, s=s: conversions.euler_to_matrix(a, s), ("euler",))
        for s in _EULER
    ],
    *[
        (f"conversions.matrix_to_euler.{s}",
         lambda R, s=s: conversions.matrix_to_euler(R, s), ("R",))
        for s in _EULER
    ],
    ("conversions.axis_angle_to_matrix", conversions.axis_angle_to_matrix, ("point", "scalar")),
    ("conversions.matrix_to_axis_angle", conversions.matrix_to_axis_angle, ("R",)),
    ("conversions.rot6d_to_matrix", conversions.rot6d_to_matrix, ("r6",)),
    ("conversions.matrix_to_rot6d", conversions.matrix_to_rot6d, ("R",)),
    ("conversions.rot9d_to_matrix", conversions.rot9d_to_matrix, ("r9",)),
    # statistics
    ("statistics.so3_randn", _randn(statistics.so3_randn), ("R", "scalar")),
    ("statistics.se3_randn", _randn(statistics.se3_randn), ("T", "scalar")),
    ("statistics.so3_mean.chordal", lambda R: statistics.so3_mean(R, method="chordal"),
     ("Rset",)),  # fmt: skip
    ("statistics.so3_mean.geodesic", lambda R, w: statistics.so3_mean(R, w, iterations=3),
     ("Rset", "weights")),  # fmt: skip
    ("statistics.se3_mean.chordal", lambda T: statistics.se3_mean(T, method="chordal"),
     ("Tset",)),  # fmt: skip
    ("statistics.se3_mean.geodesic", lambda T, w: statistics.se3_mean(T, w, iterations=3),
     ("Tset", "weights")),  # fmt: skip
    (
        "statistics.so3_interpolate_keyframes",
        lambda s: statistics.so3_interpolate_keyframes(
            _KEY_TIMES.to(s.dtype), _keys(s.dtype)[0], s, extrapolate=True
        ),
        ("query",),
    ),
    (
        "statistics.se3_interpolate_keyframes",
        lambda s: statistics.se3_interpolate_keyframes(
            _KEY_TIMES.to(s.dtype), _keys(s.dtype)[1], s, extrapolate=True
        ),
        ("query",),
    ),
    ("statistics.align", lambda P, Q: statistics.align(P, Q, scale=True), ("cloud", "cloud")),
    ("statistics.so3_integrate", statistics.so3_integrate, ("R", "point", "scalar")),
    (
        "statistics.se3_integrate.world",
        lambda T, xi, dt: statistics.se3_integrate(T, xi, dt, frame="world"),
        ("T", "twist", "scalar"),
    ),
    # nn
    *[
        (f"nn.representation_to_matrix.{r}",
         lambda x, r=r: nn.representation_to_matrix(x, r), (k,))
        for r, k in (("6d", "r6"), ("9d", "r9"), ("quaternion", "quat"), ("rotvec", "rotvec"))
    ],
    *[
        (f"nn.geodesic_loss.{kind}",
         lambda a, b, kind=kind: nn.geodesic_loss(a, b, kind=kind, reduction="none"), ("R", "R"))
        for kind in ("angle", "chordal")
    ],
    *[
        (f"nn.se3_geodesic_loss.{kind}",
         lambda a, b, kind=kind: nn.se3_geodesic_loss(a, b, 2.0, 0.5, kind, "none"), ("T", "T"))
        for kind in ("angle", "chordal")
    ],
]  # fmt: skip

IDS = [name for name, _, _ in OPS]


def _inputs(kinds: tuple[str, ...], n: int, dtype: torch.dtype, seed: int) -> list[torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    out = []
    for k in kinds:
        x = KINDS[k](n, g)
        out.append(x.to(dtype if not x.is_complex() else _COMPLEX[dtype]))
    return out


_COMPLEX = {torch.float32: torch.complex64, torch.float64: torch.complex128}


def _flat(result) -> list[torch.Tensor]:
    return list(result) if isinstance(result, (tuple, list)) else [result]


def _assert_same(got, want, what: str) -> None:
    got, want = _flat(got), _flat(want)
    assert len(got) == len(want), what
    for i, (a, b) in enumerate(zip(got, want, strict=True)):
        assert a.shape == b.shape and a.dtype == b.dtype, f"{what}: output {i}"
        assert torch.equal(a, b), f"{what}: output {i} differs in {int((a != b).sum())} numbers"


def _transposed(x: torch.Tensor) -> torch.Tensor:
    """``x`` stored with the batch dimension innermost (as ``(*event, n)`` in memory)."""
    return x.movedim(0, -1).contiguous().movedim(-1, 0)


def _sliced(x: torch.Tensor) -> torch.Tensor:
    """``x`` as every other row of a tensor twice as long."""
    return torch.stack((x, torch.full_like(x, 7.0)), 1).flatten(0, 1)[::2]


def _unchanged(fn: Callable, what: str) -> Callable:
    """``fn``, asserting that it leaves its inputs as they were (the kernels read views of them)."""

    def run(*xs: torch.Tensor):
        before = [x.clone() for x in xs]
        out = fn(*xs)
        _assert_same(xs, before, what + ": an input was written to")
        return out

    return run


def _check_layouts(fn: Callable, xs: list[torch.Tensor], what: str) -> None:
    fn = _unchanged(fn, what)
    want = fn(*xs)
    _assert_same(fn(*[_transposed(x) for x in xs]), want, what + " transposed")
    _assert_same(fn(*[_sliced(x) for x in xs]), want, what + " sliced")
    for i in range(len(xs)):  # one operand strided at a time (the others contiguous)
        mixed = [_transposed(x) if j == i else x for j, x in enumerate(xs)]
        _assert_same(fn(*mixed), want, f"{what} operand {i} transposed")
    n = xs[0].shape[0]
    ones = [x[:1].expand(n, *x.shape[1:]) for x in xs]  # stride 0
    _assert_same(fn(*ones), fn(*[x.contiguous() for x in ones]), what + " expanded")


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
@pytest.mark.parametrize(("name", "fn", "kinds"), OPS, ids=IDS)
def test_small_batch(name, fn, kinds, dtype):
    _check_layouts(fn, _inputs(kinds, SMALL, dtype, seed=1), f"{name} batch {SMALL}")


@pytest.mark.slow
@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
@pytest.mark.parametrize(("name", "fn", "kinds"), OPS, ids=IDS)
def test_large_batch(name, fn, kinds, dtype):
    """The large-batch kernels: every layout alike, and the first rows as a small batch's."""
    xs = _inputs(kinds, LARGE, dtype, seed=2)
    _check_layouts(fn, xs, f"{name} batch {LARGE}")
    if name.endswith("randn"):  # the draws themselves depend on the number drawn
        return
    big = _flat(fn(*xs))
    for k in (1, SMALL, 1000, LARGE - 3):
        small = _flat(fn(*[x[:k] for x in xs]))
        _assert_same(small, [b[:k] for b in big], f"{name}: the first {k} of {LARGE}")


# ----------------------------------------------------------------------------------------------
# Broadcast batches against the same pairs one by one
# ----------------------------------------------------------------------------------------------

#: The ops of two or more operands, each a batch of elements (not sets, not random draws).
BINARY = [
    (name, fn, kinds)
    for name, fn, kinds in OPS
    if len(kinds) >= 2 and not name.endswith(("randn", "mean.geodesic", "align"))
]


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
@pytest.mark.parametrize(("name", "fn", "kinds"), BINARY, ids=[n for n, _, _ in BINARY])
def test_broadcast_equals_one_by_one(name, fn, kinds, dtype):
    """Operands of batch ``(4, 1)`` and ``(1, 5)``: element ``(i, j)`` of the result is the
    op of the pair ``(i, 0)``, ``(0, j)`` alone."""
    a, b, *rest = _inputs(kinds, 20, dtype, seed=4)
    a = a[:4].unsqueeze(1)
    b = b[:5].unsqueeze(0)
    rest = [x[:1] for x in rest]  # one value for the other arguments, broadcast
    full = _flat(fn(a, b, *rest))
    for i in range(4):
        for j in range(5):
            one = _flat(fn(a[i, 0], b[0, j], *[x[0] for x in rest]))
            _assert_same(one, [f[i, j] for f in full], f"{name} pair ({i}, {j})")


# ----------------------------------------------------------------------------------------------
# Gradients
# ----------------------------------------------------------------------------------------------

GRADS = [
    (name, fn, kinds)
    for name, fn, kinds in OPS
    if name
    in {
        "so3.exp", "so3.log", "so3.act", "so3.jac_left", "se3.exp", "se3.log", "se3.compose",
        "se3.inverse", "se3.act", "quaternion.multiply", "quaternion.apply",
        "quaternion.to_matrix", "quaternion.from_matrix", "quaternion.slerp",
        "conversions.quaternion_to_euler.xyz", "nn.geodesic_loss.chordal",
    }
]  # fmt: skip


def _grads(fn, xs: list[torch.Tensor], cot: list[torch.Tensor] | None = None):
    """The gradients of ``fn`` at ``xs`` for the cotangents ``cot`` (drawn if not given)."""
    leaves = [x.detach().requires_grad_() for x in xs]
    before = [x.clone() for x in xs]
    out = _flat(fn(*leaves))
    if cot is None:
        g = torch.Generator().manual_seed(6)
        cot = [torch.randn(o.shape, generator=g, dtype=o.dtype) for o in out]
    grads = list(torch.autograd.grad(out, leaves, cot))
    _assert_same(leaves, before, "an input was written to")
    return grads, cot


@pytest.mark.slow
@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
@pytest.mark.parametrize(("name", "fn", "kinds"), GRADS, ids=[n for n, _, _ in GRADS])
def test_gradients(name, fn, kinds, dtype):
    """Backward passes (closed-form and autograd's) alike for every layout and batch size."""
    for n in (SMALL, LARGE):
        xs = _inputs(kinds, n, dtype, seed=5)
        want, cot = _grads(fn, xs)
        for layout in (_transposed, _sliced):
            got, _ = _grads(fn, [layout(x) for x in xs], cot)
            _assert_same(got, want, f"{name} grad {n} {layout.__name__}")
        if n == LARGE:
            small, _ = _grads(fn, [x[:SMALL] for x in xs], [c[:SMALL] for c in cot])
            _assert_same(small, [w[:SMALL] for w in want], f"{name} grad first {SMALL}")


# ----------------------------------------------------------------------------------------------
# The premise: torch's element-wise kernels round alike in all their loops
# ----------------------------------------------------------------------------------------------

ELEMENTWISE = {
    "mul": lambda a, b, c: a * b,
    "add": lambda a, b, c: torch.add(a, b, alpha=-0.5),
    "sub": lambda a, b, c: a - b,
    "div": lambda a, b, c: a / b,
    "addcmul": lambda a, b, c: torch.addcmul(a, b, c),
    "addcmul-": lambda a, b, c: torch.addcmul(a, b, c, value=-1.0),
    "addcmul.5": lambda a, b, c: torch.addcmul(a, b, c, value=0.5),
    "lerp": lambda a, b, c: torch.lerp(a, b, c),
    "rsub": lambda a, b, c: torch.rsub(a, 0.5),
    "reciprocal": lambda a, b, c: torch.reciprocal(a),
    "sqrt": lambda a, b, c: torch.sqrt(a.abs()),
    "rsqrt": lambda a, b, c: torch.rsqrt(a.abs()),
    "sin": lambda a, b, c: torch.sin(a),
    "cos": lambda a, b, c: torch.cos(a),
    "atan": lambda a, b, c: torch.atan(a),
    "exp": lambda a, b, c: torch.exp(a),
    "log": lambda a, b, c: torch.log(a.abs()),
    "fmod": lambda a, b, c: torch.fmod(a, 3.0),
    "minimum": lambda a, b, c: torch.minimum(a, b),
    "maximum": lambda a, b, c: torch.maximum(a, b),
    "copysign": lambda a, b, c: torch.copysign(a, b),
    "where": lambda a, b, c: torch.where(a > 0, b, c),
    "sign": lambda a, b, c: torch.sign(a),
    "clamp": lambda a, b, c: a.clamp(-0.5, 0.5),
    "double": lambda a, b, c: a.double() if a.dtype == torch.float32 else a.float(),
}


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
@pytest.mark.parametrize("name", list(ELEMENTWISE))
def test_elementwise_kernels_round_alike_in_every_loop(name, dtype):
    """The formulas are written in these operations only (``torch.atan2``, whose vectorised
    and scalar loops round differently, is replaced by :func:`torchlie._coeffs.atan2`, and
    reductions by sums component by component): each rounds alike in torch's vectorised loop,
    in its scalar loop (the tail of an array), on strided operands and into strided outputs,
    so a formula's bits depend neither on the batch size nor on the layout."""
    fn = ELEMENTWISE[name]
    g = torch.Generator().manual_seed(7)
    n = 4099
    args = [
        torch.randn(n, generator=g, dtype=torch.float64)
        .mul(torch.exp2(torch.randint(-20, 20, (n,), generator=g).double()))
        .to(dtype)
        for _ in range(3)
    ]
    want = fn(*args)
    for k in (1, 3, 17, 40):  # scalar tails
        assert torch.equal(fn(*[a[:k] for a in args]), want[:k])
    strided = [torch.stack((a, a), 1)[:, 0] for a in args]
    assert torch.equal(fn(*strided), want)
    out = torch.empty(n, 3, dtype=want.dtype)
    out[:, 1] = fn(*args)  # the copy into a column
    assert torch.equal(out[:, 1], want)
    if name.startswith(("mul", "addcmul", "div", "sin", "atan", "sqrt")):
        into = torch.empty(n, 3, dtype=want.dtype)
        op = {"mul": torch.mul, "div": torch.div, "sin": torch.sin, "atan": torch.atan}
        if name in op:
            op[name](*args[: 1 if name in ("sin", "atan") else 2], out=into[:, 1])
            assert torch.equal(into[:, 1], want)
        elif name.startswith("addcmul"):
            value = {"addcmul": 1.0, "addcmul-": -1.0, "addcmul.5": 0.5}[name]
            torch.addcmul(*args, value=value, out=into[:, 1])
            assert torch.equal(into[:, 1], want)


def test_atan2_of_torch_rounds_otherwise_in_its_loops():
    """Why :func:`torchlie._coeffs.atan2` exists (if torch's loops come to agree, it may go)."""
    g = torch.Generator().manual_seed(8)
    y, x = torch.randn(2, 4099, generator=g)
    want = torch.atan2(y, x)
    strided = torch.atan2(torch.stack((y, y), 1)[:, 0], torch.stack((x, x), 1)[:, 0])
    assert not torch.equal(strided, want)


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
def test_atan2_matches_torch(dtype):
    from torchlie import _coeffs

    g = torch.Generator().manual_seed(9)
    y, x = torch.randn(2, 100_000, generator=g, dtype=torch.float64)
    y[:8] = torch.tensor([0.0, -0.0, 0.0, -0.0, 1.0, -1.0, 0.0, -2.0])
    x[:8] = torch.tensor([0.0, 0.0, -0.0, -0.0, 0.0, -0.0, -3.0, 0.0])
    y, x = y.to(dtype), x.to(dtype)
    got, want = _coeffs.atan2(y, x), torch.atan2(y, x)
    assert torch.equal(got[:8].signbit(), want[:8].signbit())
    torch.testing.assert_close(got, want, rtol=2 * torch.finfo(dtype).eps, atol=0)
    pos = y.abs() + torch.finfo(dtype).tiny
    torch.testing.assert_close(
        _coeffs.atan2_nonneg(pos, x.abs()),
        torch.atan2(pos, x.abs()),
        rtol=2 * torch.finfo(dtype).eps,
        atol=0,
    )
