"""The same numbers give the same results, whatever their memory layout, batch size, broadcast
or thread count.

Every public op that takes tensors is fed its inputs contiguous, transposed (the batch dimension
innermost in memory), sliced (every other row of a larger tensor) and expanded (one element
repeated with stride 0), at a small batch and at a batch large enough for the large-batch
kernels; its results must agree with those of the contiguous call, and the rows of a large batch
with a small batch holding the same elements and with scattered elements evaluated alone.
Binary ops are also checked broadcast against the same pairs called one by one.

Agreement, not bits: torch's vectorised and scalar loops, its small matrix products and BLAS
round differently by layout and by CPU, so results are held to ``agreement.ULPS`` units of the
dtype's epsilon relative to each result element's norm; NaN and infinities must come at the
same places, and inputs are never written to (bitwise).  A non-finite component stays in its
element at every batch size.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import pytest
import torch
from agreement import ULPS, assert_agree, assert_bits, flat

from torchlie import conversions, nn, quaternion, se2, se3, sim3, so2, so3, statistics

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
    "pos_quat_scale": lambda n, g: torch.cat(
        (
            torch.randn(n, 7, generator=g, dtype=torch.float64),
            torch.rand(n, 1, generator=g, dtype=torch.float64) * 3.0 + 0.1,
        ),
        -1,
    ),
    "su2": lambda n, g: quaternion.to_su2(torch.randn(n, 4, generator=g, dtype=torch.float64)),
    "Rset": lambda n, g: so3.exp(0.5 * torch.randn(n, 3, 3, generator=g, dtype=torch.float64)),
    "Tset": lambda n, g: se3.exp(0.5 * torch.randn(n, 3, 6, generator=g, dtype=torch.float64)),
    "weights": lambda n, g: torch.rand(n, 3, generator=g, dtype=torch.float64) + 0.1,
    "cloud": lambda n, g: torch.randn(n, 5, 3, generator=g, dtype=torch.float64),
    "query": lambda n, g: torch.rand(n, generator=g, dtype=torch.float64) * 3.0,
}


def _angle(n: int, g: torch.Generator) -> torch.Tensor:
    """Angles ``(n, 1)`` in ``[-pi, pi]``, some a hair from the half turn and some near 0."""
    t = (torch.rand(n, 1, generator=g, dtype=torch.float64) * 2.0 - 1.0) * math.pi
    t[::5] = math.copysign(math.pi, 1.0) - t[::5].abs() * 1e-6
    t[1::5] *= 1e-5
    return t


def _twist2(n: int, g: torch.Generator) -> torch.Tensor:
    return torch.cat((torch.randn(n, 2, generator=g, dtype=torch.float64), _angle(n, g)), -1)


def _sim3_tangent(n: int, g: torch.Generator) -> torch.Tensor:
    sigma = torch.randn(n, 1, generator=g, dtype=torch.float64)
    sigma[2::5] *= 1e-7  # scale near 1 (the series in sigma)
    rho = torch.randn(n, 3, generator=g, dtype=torch.float64)
    return torch.cat((rho, _rotvec(n, g), sigma), -1)


KINDS.update(
    {
        "angle": _angle,
        "R2": lambda n, g: so2.exp(_angle(n, g)),
        "twist2": _twist2,
        "T2": lambda n, g: se2.exp(_twist2(n, g)),
        "point2": lambda n, g: torch.randn(n, 2, generator=g, dtype=torch.float64),
        "M2": lambda n, g: torch.randn(n, 2, 2, generator=g, dtype=torch.float64),
        "tangent7": _sim3_tangent,
        "S": lambda n, g: sim3.exp(_sim3_tangent(n, g)),
        "positive": lambda n, g: torch.rand(n, generator=g, dtype=torch.float64) * 3.0 + 0.1,
        "R2set": lambda n, g: so2.exp(torch.randn(n, 3, 1, generator=g, dtype=torch.float64)),
        "T2set": lambda n, g: se2.exp(0.5 * torch.randn(n, 3, 3, generator=g, dtype=torch.float64)),
        "Sset": lambda n, g: sim3.exp(0.5 * torch.randn(n, 3, 7, generator=g, dtype=torch.float64)),
    }
)

_EULER = ("xyz", "ZYX", "zxz", "YXY")
_KEY_TIMES = torch.tensor([0.0, 1.0, 2.5])


def _keys(dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(99)
    w = torch.randn(3, 6, generator=g, dtype=torch.float64)
    return so3.exp(w[:, 3:]).to(dtype), se3.exp(w).to(dtype)


def _more_keys(dtype: torch.dtype) -> dict[str, torch.Tensor]:
    """Keyframes of SO(2), SE(2) and Sim(3) at :data:`_KEY_TIMES`."""
    g = torch.Generator().manual_seed(98)
    return {
        "so2": so2.exp(torch.randn(3, 1, generator=g, dtype=torch.float64)).to(dtype),
        "se2": se2.exp(torch.randn(3, 3, generator=g, dtype=torch.float64)).to(dtype),
        "sim3": sim3.exp(0.5 * torch.randn(3, 7, generator=g, dtype=torch.float64)).to(dtype),
    }


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

# SO(2), SE(2), Sim(3): the same verbs (the module, its element, tangent, point and matrix kinds).
_PLANAR_SIM3 = (
    (so2, "R2", "angle", "point2", "M2"),
    (se2, "T2", "twist2", "point2", "M"),
    (sim3, "S", "tangent7", "point", "M4"),
)
for _m, _E, _tan, _pt, _M in _PLANAR_SIM3:
    _n = _m.__name__.rpartition(".")[2]
    _jacs = ("jac_left", "jac_right", "jac_left_inv", "jac_right_inv")
    OPS += [(f"{_n}.{f}", getattr(_m, f), (_tan,)) for f in ("hat", "exp", "ad", *_jacs)]
    OPS += [(f"{_n}.{f}", getattr(_m, f), (_E,)) for f in
            ("log", "inverse", "adjoint", "jac_inverse")]  # fmt: skip
    OPS += [(f"{_n}.{f}", getattr(_m, f), (_M,)) for f in ("vee", "is_valid")]
    OPS += [(f"{_n}.{f}", getattr(_m, f), (_E, _E)) for f in
            ("compose", "distance", "rminus", "lminus", "between", "jac_compose", "jac_rminus",
             "jac_between")]  # fmt: skip
    OPS += [(f"{_n}.{f}", getattr(_m, f), (_E, _tan)) for f in ("rplus", "lplus", "jac_rplus")]
    OPS += [(f"{_n}.{f}", getattr(_m, f), (_E, _pt)) for f in ("act", "jac_act")]
    OPS += [(f"{_n}.interpolate", _m.interpolate, (_E, _E, "scalar"))]
OPS += [
    ("so2.to_complex", so2.to_complex, ("R2",)),
    ("so2.from_complex", so2.from_complex, ("point2",)),
    ("so2.angle_to_complex", so2.angle_to_complex, ("angle",)),
    ("so2.complex_to_angle", so2.complex_to_angle, ("point2",)),
    ("se2.from_rt", se2.from_rt, ("R2", "point2")),
    ("se2.to_rt", se2.to_rt, ("T2",)),
    ("se2.from_xytheta", se2.from_xytheta, ("twist2",)),
    ("se2.to_xytheta", se2.to_xytheta, ("T2",)),
    ("sim3.from_srt", sim3.from_srt, ("positive", "R", "point")),
    ("sim3.to_srt", sim3.to_srt, ("S",)),
    ("sim3.from_se3", sim3.from_se3, ("T", "positive")),
    ("sim3.scale", sim3.scale, ("S",)),
    ("sim3.from_pos_quat_scale", sim3.from_pos_quat_scale, ("pos_quat_scale",)),
    ("sim3.to_pos_quat_scale", sim3.to_pos_quat_scale, ("S",)),
    ("statistics.so2_mean.chordal", lambda R: statistics.so2_mean(R, method="chordal"),
     ("R2set",)),
    ("statistics.so2_mean.geodesic", lambda R, w: statistics.so2_mean(R, w, iterations=3),
     ("R2set", "weights")),
    ("statistics.se2_mean.chordal", lambda T: statistics.se2_mean(T, method="chordal"),
     ("T2set",)),
    ("statistics.se2_mean.geodesic", lambda T, w: statistics.se2_mean(T, w, iterations=3),
     ("T2set", "weights")),
    ("statistics.sim3_mean.chordal", lambda T: statistics.sim3_mean(T, method="chordal"),
     ("Sset",)),
    ("statistics.sim3_mean.geodesic", lambda T, w: statistics.sim3_mean(T, w, iterations=3),
     ("Sset", "weights")),
    *[
        (f"statistics.{g}_randn", _randn(getattr(statistics, f"{g}_randn")), (X, "scalar"))
        for g, X in (("so2", "R2"), ("se2", "T2"), ("sim3", "S"))
    ],
    *[
        (f"statistics.{g}_interpolate_keyframes",
         lambda s, g=g: getattr(statistics, f"{g}_interpolate_keyframes")(
             _KEY_TIMES.to(s.dtype), _more_keys(s.dtype)[g], s, extrapolate=True),
         ("query",))
        for g in ("so2", "se2", "sim3")
    ],
    ("statistics.so2_integrate", statistics.so2_integrate, ("R2", "angle", "scalar")),
    ("statistics.se2_integrate.world",
     lambda T, xi, dt: statistics.se2_integrate(T, xi, dt, frame="world"),
     ("T2", "twist2", "scalar")),
    ("statistics.sim3_integrate", statistics.sim3_integrate, ("S", "tangent7", "scalar")),
    *[
        (f"nn.so2_geodesic_loss.{kind}",
         lambda a, b, kind=kind: nn.so2_geodesic_loss(a, b, kind=kind, reduction="none"),
         ("R2", "R2"))
        for kind in ("angle", "chordal")
    ],
    *[
        (f"nn.se2_geodesic_loss.{kind}",
         lambda a, b, kind=kind: nn.se2_geodesic_loss(a, b, 2.0, 0.5, kind, "none"), ("T2", "T2"))
        for kind in ("angle", "chordal")
    ],
    *[
        (f"nn.sim3_geodesic_loss.{kind}",
         lambda a, b, kind=kind: nn.sim3_geodesic_loss(a, b, 2.0, 0.5, 1.5, kind, "none"),
         ("S", "S"))
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
        assert_bits(xs, before, what + ": an input was written to")
        return out

    return run


def _check_layouts(fn: Callable, xs: list[torch.Tensor], what: str) -> None:
    fn = _unchanged(fn, what)
    want = fn(*xs)
    assert_agree(fn(*[_transposed(x) for x in xs]), want, what + " transposed")
    assert_agree(fn(*[_sliced(x) for x in xs]), want, what + " sliced")
    for i in range(len(xs)):  # one operand strided at a time (the others contiguous)
        mixed = [_transposed(x) if j == i else x for j, x in enumerate(xs)]
        assert_agree(fn(*mixed), want, f"{what} operand {i} transposed")
    n = xs[0].shape[0]
    ones = [x[:1].expand(n, *x.shape[1:]) for x in xs]  # stride 0
    assert_agree(fn(*ones), fn(*[x.contiguous() for x in ones]), what + " expanded")


@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
@pytest.mark.parametrize(("name", "fn", "kinds"), OPS, ids=IDS)
def test_small_batch(name, fn, kinds, dtype):
    _check_layouts(fn, _inputs(kinds, SMALL, dtype, seed=1), f"{name} batch {SMALL}")


@pytest.mark.parametrize(("name", "fn", "kinds"), OPS, ids=IDS)
def test_results_do_not_share_memory_with_inputs(name, fn, kinds):
    # a result that is a view of an input (so3.inverse as a transpose) lets an in-place update
    # of the result write into the caller's tensor
    xs = _inputs(kinds, SMALL, torch.float64, seed=3)
    held = {x.untyped_storage().data_ptr() for x in xs}
    for i, out in enumerate(flat(fn(*xs))):
        if isinstance(out, torch.Tensor) and out.numel():
            assert out.untyped_storage().data_ptr() not in held, f"{name}: output {i}"


#: Rows of the large batch also evaluated alone.
_ALONE = range(1, LARGE, 211)
#: The ops held to more than ``ULPS`` between an element alone and in a batch: the planar log
#: takes torch's ``atan2`` (its angle alone agrees within an ulp; the batch-independent angle
#: of ``_coeffs.angle`` would take most of ``so2.log``'s time), and these amplify the angle's
#: ulp: the interpolations multiply it by ``t`` (an ulp of ``pi`` is two of the result), the
#: Jacobians of ``rminus`` take it through their coefficients of the angle.
_ALONE_ULPS = {"so2.interpolate": 3.0, "se2.interpolate": 3.0, "se2.jac_rminus": 3.0}


@pytest.mark.slow
@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
@pytest.mark.parametrize(("name", "fn", "kinds"), OPS, ids=IDS)
def test_large_batch(name, fn, kinds, dtype):
    """The large-batch kernels: every layout alike, and the first rows as a small batch's."""
    xs = _inputs(kinds, LARGE, dtype, seed=2)
    _check_layouts(fn, xs, f"{name} batch {LARGE}")
    if name.endswith("randn"):  # the draws themselves depend on the number drawn
        return
    big = flat(fn(*xs))
    for k in (1, SMALL, 1000, LARGE - 3):
        small = flat(fn(*[x[:k] for x in xs]))
        assert_agree(small, [b[:k] for b in big], f"{name}: the first {k} of {LARGE}")
    # elements alone (torch's scalar loops) against their rows of the batch (its vectorised
    # loops), every residue of the samplers' patterns (near 0, near pi, small sigma) among them
    ulps = _ALONE_ULPS.get(name, ULPS)
    for r in _ALONE:
        one = flat(fn(*[x[r : r + 1] for x in xs]))
        assert_agree(one, [b[r : r + 1] for b in big], f"{name}: element {r} alone", ulps=ulps)
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        assert_agree(fn(*xs), big, f"{name}: two threads")
    finally:
        torch.set_num_threads(threads)


#: Rows of the batch spoiled by :func:`_spoiled`, per operand: (row, component, value).
_SPOILS = ((3, 0, math.inf), (5, -1, math.nan), (11, 1, -math.inf))


def _spoiled(xs: list[torch.Tensor]) -> tuple[list[torch.Tensor], list[int]]:
    """``xs`` with one component of a few rows made non-finite (other rows for each operand),
    and the rows spoiled."""
    out, rows = [], []
    for k, x in enumerate(xs):
        x = x.clone()
        for row, comp, value in _SPOILS:
            r = row + 13 * k
            flat_x = x.view(x.shape[0], -1)
            flat_x[r, comp % flat_x.shape[1]] = value
            rows.append(r)
        out.append(x)
    return out, rows


@pytest.mark.slow
@pytest.mark.parametrize("dtype", DTYPES, ids=["f32", "f64"])
@pytest.mark.parametrize(("name", "fn", "kinds"), OPS, ids=IDS)
def test_non_finite_components_stay_in_their_element(name, fn, kinds, dtype):
    """An infinity or a NaN in one element of a large batch: that element's result is what the
    element gives alone (the same NaN and infinities), and every other element's is what it gives
    without the spoiled ones in the batch."""
    if name.endswith("randn"):
        return
    xs = _inputs(kinds, LARGE, dtype, seed=3)
    spoiled, rows = _spoiled(xs)
    got = flat(fn(*spoiled))
    for r in rows:
        alone = flat(fn(*[x[r : r + 1] for x in spoiled]))
        assert_agree([g[r : r + 1] for g in got], alone, f"{name}: spoiled element {r}")
    keep = torch.ones(LARGE, dtype=torch.bool)
    keep[rows] = False
    clean = flat(fn(*xs))
    assert_agree([g[keep] for g in got], [c[keep] for c in clean], f"{name}: the other elements")


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
    full = flat(fn(a, b, *rest))
    for i in range(4):
        for j in range(5):
            one = flat(fn(a[i, 0], b[0, j], *[x[0] for x in rest]))
            assert_agree(one, [f[i, j] for f in full], f"{name} pair ({i}, {j})", batch_dims=0)


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
    out = flat(fn(*leaves))
    if cot is None:
        g = torch.Generator().manual_seed(6)
        cot = [torch.randn(o.shape, generator=g, dtype=o.dtype) for o in out]
    grads = list(torch.autograd.grad(out, leaves, cot))
    assert_bits(leaves, before, "an input was written to")
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
            assert_agree(got, want, f"{name} grad {n} {layout.__name__}")
        if n == LARGE:
            small, _ = _grads(fn, [x[:SMALL] for x in xs], [c[:SMALL] for c in cot])
            assert_agree(small, [w[:SMALL] for w in want], f"{name} grad first {SMALL}")
