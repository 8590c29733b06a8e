"""Derivatives of every public differentiable function at exact special inputs (float64).

The inputs are the points where formulas built from ``abs``, ``minimum``, ``maximum``,
``copysign`` or ``where(x == 0, ...)`` go wrong (their derivative is 0 at 0 and at ties):
axis-aligned rotations by multiples of 90 degrees, quaternions with exact zeros and
equal-magnitude components, Euler angles of exactly 0, +-pi/2 and pi, twists with zero parts,
identity poses, interpolation parameters 0 and 1.

At each point, along random directions ``u`` (two per point and argument) and a random
cotangent ``v``:

(a) the reverse-mode ``<v, J u>`` (from ``J^T v``),
(b) the forward-mode ``J u`` (``torch.autograd.forward_ad``),
(c) the Hessian-vector product of ``<v, f>`` (double backward),

are compared with central differences, Richardson-extrapolated (steps ``h`` and ``2h``), of the
function (a, b) and of its gradient (c).  A point is checked only where the function (for c,
its gradient too) is smooth along ``u``: one-sided differences from the two sides, each from
the two step sizes, agree.  Elsewhere (a cone at the identity of a distance, a sign flip at
pi, gimbal lock) the function is not differentiable and its docstring says what comes back.

Rotation and pose arguments move in tangent coordinates, ``R expm(hat(d))`` and
``T expm(hat(xi))`` (DESIGN.md section 5: the log maps' gradient is that of ``log o polar``,
exact along these directions); every other argument moves in its ambient coordinates.

The functions are taken from the modules' ``__all__`` and the public attributes of
:class:`torchlie.SO3` and :class:`torchlie.SE3`; :data:`EXCLUDED` names the others and why,
and ``test_every_public_function_is_checked`` fails for a new public name in neither.

``PYTHONPATH=. python tests/test_exact_derivatives.py`` prints the counts per function.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Any, NamedTuple

import pytest
import torch
import torch.autograd.forward_ad as fwAD
from torch import Tensor

import torchlie
from torchlie import (
    SE2,
    SE3,
    SO2,
    SO3,
    Sim3,
    conversions,
    quaternion,
    se2,
    se3,
    sim3,
    so2,
    so3,
    statistics,
)
from torchlie import nn as tnn

DT = torch.float64
H = 1e-3  # finite-difference step (Richardson from h and 2h: error O(h^4))
TOL = 1e-6  # derivative agreement, relative to 1 + |difference| + |value| (per point)
SMOOTH_TOL = 1e-6  # the two one-sided second-order differences agree: smooth along u
DIRECTIONS = 2
STENCIL = (0.0, 1.0, -1.0, 2.0, -2.0)
S2 = math.sqrt(0.5)
PI = math.pi

# ----------------------------------------------------------------------------------------------
# How an argument moves
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Kind:
    """``dim`` real coordinates; ``move(x0, d)`` is the point at coordinates ``d`` (0 at x0)."""

    dim: int
    move: Callable[[Tensor, Tensor], Tensor]


def _hat3(w: Tensor) -> Tensor:
    x, y, z = w.unbind(-1)
    o = torch.zeros_like(x)
    return torch.stack((o, -z, y, z, o, -x, -y, x, o), -1).unflatten(-1, (3, 3))


def _hat6(xi: Tensor) -> Tensor:
    top = torch.cat((_hat3(xi[..., 3:]), xi[..., :3, None]), -1)
    return torch.nn.functional.pad(top, (0, 0, 0, 1))


def ambient(*shape: int) -> Kind:
    return Kind(math.prod(shape), lambda x, d: x + d.reshape(x.shape))


def _rot_set(n: int) -> Kind:
    """``n`` rotations ``(..., n, 3, 3)``, each moved in its tangent coordinates."""
    return Kind(3 * n, lambda R, d: R @ torch.linalg.matrix_exp(_hat3(d.reshape(*R.shape[:-2], 3))))


def _pose_set(n: int) -> Kind:
    return Kind(6 * n, lambda T, d: T @ torch.linalg.matrix_exp(_hat6(d.reshape(*T.shape[:-2], 6))))


ROT = _rot_set(1)
POSE = _pose_set(1)
COMPLEX2 = Kind(8, lambda U, d: U + torch.view_as_complex(d.reshape(*U.shape, 2)))
FIXED = None  # an argument that is not differentiated (times of keyframes)

# ----------------------------------------------------------------------------------------------
# Exact points
# ----------------------------------------------------------------------------------------------


def _t(rows) -> Tensor:
    return torch.tensor(rows, dtype=DT)


def _octahedral() -> Tensor:
    """The 24 rotations that map axes to axes (signed permutation matrices, det +1), identity
    first: every rotation by 0, 90, 180 or 270 degrees about a coordinate axis and their
    products."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            M = torch.zeros(3, 3, dtype=DT)
            for r, c in enumerate(perm):
                M[r, c] = signs[r]
            if torch.linalg.det(M) > 0:
                out.append(M)
    return torch.stack(out)


def _binary_octahedral() -> Tensor:
    """The 48 unit quaternions of those rotations (both signs), identity first: exact zeros,
    ``(s, s, 0, 0)`` ties with ``s = sqrt(1/2)``, ``(+-1, +-1, +-1, +-1)/2``, negative ``w``."""
    out = []
    for i in range(4):
        for s in (1.0, -1.0):
            q = [0.0] * 4
            q[i] = s
            out.append(q)
    out.extend([0.5 * a for a in signs] for signs in itertools.product((1.0, -1.0), repeat=4))
    for i, j in itertools.combinations(range(4), 2):
        for a, b in itertools.product((S2, -S2), repeat=2):
            q = [0.0] * 4
            q[i], q[j] = a, b
            out.append(q)
    return _t(out)


ROTS = _octahedral()
QUATS = torch.cat(
    (
        _binary_octahedral(),
        _t(
            [
                [1.0, 1.0, 0.0, 0.0],
                [-1.0, 1.0, 0.0, 0.0],
                [1.0, 1.0, 1.0, 1.0],
                [2.0, 0.0, 0.0, 0.0],
                [0.0, 0.0, -3.0, 0.0],
                [0.6, 0.8, 0.0, 0.0],
                [-0.6, 0.0, 0.0, 0.8],
                [0.0, 0.0, 0.6, -0.8],
                [0.8, 0.0, -0.6, 0.0],
            ]
        ),
    )
)
ROTVECS = _t(
    [
        [0.0, 0.0, 0.0],
        [PI / 2, 0.0, 0.0],
        [0.0, PI, 0.0],
        [0.0, 0.0, -PI / 2],
        [-PI, 0.0, 0.0],
        [0.0, 3 * PI / 2, 0.0],
        [0.5, 0.0, 0.0],
        [0.0, 0.0, -2.0],
        [1.0, 1.0, 0.0],
        [0.0, 1.0, -1.0],
        [1.0, 1.0, 1.0],
        [PI / 2, PI / 2, 0.0],
    ]
)
TWISTS = torch.stack(
    [
        torch.cat((rho, phi))
        for rho in _t([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, -2.0, 1.0]])
        for phi in _t(
            [
                [0.0, 0.0, 0.0],
                [PI / 2, 0.0, 0.0],
                [0.0, PI, 0.0],
                [0.0, 0.0, -PI / 2],
                [1.0, 1.0, 0.0],
                [0.0, 0.0, 0.5],
            ]
        )
    ]
)
TRANSLATIONS = _t([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, -2.0, 1.0]])


def _pose(R: Tensor, t: Tensor) -> Tensor:
    return torch.nn.functional.pad(torch.cat((R, t[..., None]), -1), (0, 0, 0, 1)) + _t(
        [[0.0] * 4] * 3 + [[0.0, 0.0, 0.0, 1.0]]
    )


POSES = torch.stack([_pose(R, t) for t in TRANSLATIONS for R in ROTS])
POINTS = _t([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 1.0], [1.0, -2.0, 3.0]])
EULERS = _t(list(itertools.product((0.0, PI / 2, -PI / 2, 0.3, PI), repeat=3)))
INTERP = _t([0.0, 0.5, 1.0, -0.5, 2.0])  # interpolation parameters
DTS = _t([0.0, 0.25, 1.0])
MATRICES = torch.cat(  # general 3 x 3 matrices: rotations, and some that are not
    (
        ROTS,
        _t(
            [
                [[2.0, 0.0, 0.0], [0.0, 3.0, 0.0], [0.0, 0.0, 1.0]],
                [[1.0, 1.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
                [[0.0, -2.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.5]],
                [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, -1.0]],
            ]
        ),
    )
)
ROT6DS = torch.cat(
    (
        torch.cat((ROTS[:, :, 0], ROTS[:, :, 1]), -1),
        _t(
            [
                [1.0, 0.0, 0.0, 1.0, 1.0, 0.0],
                [2.0, 0.0, 0.0, 0.0, 0.0, 3.0],
                [1.0, 1.0, 0.0, -1.0, 1.0, 0.0],
                [0.0, 0.0, 1.0, 1.0, 1.0, 1.0],
            ]
        ),
    )
)
AXES = _t([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [1.0, 1.0, 0.0], [1.0, 1.0, 1.0], [0.0, -3.0, 4.0]])
ANGLES = _t([0.0, PI / 2, PI, -PI / 2, 3 * PI / 2])


def _sets(items: Tensor, n: int, count: int) -> Tensor:
    """``count`` ordered ``n``-tuples of ``items`` (deterministic), as ``(count, n, ...)``."""
    idx = list(itertools.product(range(len(items)), repeat=n))
    step = max(1, len(idx) // count)
    return torch.stack([items[list(i)] for i in idx[::step][:count]])


ROT_SETS = _sets(ROTS[:8], 3, 24)
POSE_SETS = _sets(torch.cat((POSES[:6], POSES[24:26], POSES[48:50])), 3, 24)
WEIGHTS3 = _t([[1.0, 1.0, 1.0], [1.0, 2.0, 1.0], [0.5, 0.0, 0.5]])
POINT_SETS = _t(
    [
        [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 3.0], [1.0, 1.0, 1.0]],
    ]
)
WEIGHTS4 = _t([[1.0, 1.0, 1.0, 1.0], [1.0, 2.0, 1.0, 0.5]])
SEQUENCES = [
    c(s)
    for s in ["".join(p) for p in itertools.permutations("xyz")]
    + [a + b + a for a, b in itertools.permutations("xyz", 2)]
    for c in (str.lower, str.upper)
]

# ----------------------------------------------------------------------------------------------
# Cases
# ----------------------------------------------------------------------------------------------


@dataclass
class Case:
    name: str  # "module.function" or "module.function[variant]"
    fn: Callable[..., Any]
    kinds: tuple[Kind | None, ...]
    points: tuple[Tensor, ...]  # per argument, the same leading size P
    chunk: int = 0  # evaluate so many points at a time (0: all at once)


_LIMIT = 600  # points per case at most (products of the sets are thinned past it)


def _grid(*sets: Tensor) -> tuple[Tensor, ...]:
    """Product of the point sets; past :data:`_LIMIT` a deterministic subset that keeps every
    combination whose first argument is its set's first point (identity, 0)."""
    idx = list(itertools.product(*(range(len(s)) for s in sets)))
    if len(idx) > _LIMIT:
        keep = [i for i in idx if i[0] == 0]
        rest = [i for i in idx if i[0] != 0]
        g = torch.Generator().manual_seed(len(idx))
        pick = torch.randperm(len(rest), generator=g)[: max(0, _LIMIT - len(keep))]
        idx = keep + [rest[k] for k in sorted(pick.tolist())]
    cols = list(zip(*idx, strict=True))
    return tuple(s[list(c)] for s, c in zip(sets, cols, strict=True))


CASES: list[Case] = []


def case(name: str, fn: Callable[..., Any], *args: tuple[Kind | None, Tensor], **kw) -> None:
    kinds = tuple(k for k, _ in args)
    CASES.append(Case(name, fn, kinds, _grid(*(p for _, p in args)), **kw))


SKEWS = _hat3(ROTVECS)
SKEW4S = _hat6(TWISTS)
POS_QUATS = torch.cat(
    (TRANSLATIONS.repeat_interleave(len(QUATS), 0), QUATS.repeat(len(TRANSLATIONS), 1)), -1
)
# (kind, points) of the common arguments
R_, P_, Q_ = (ROT, ROTS), (POSE, POSES), (ambient(4), QUATS)
O_, T_, PT_ = (ambient(3), ROTVECS), (ambient(6), TWISTS), (ambient(3), POINTS)
S_, DT_ = (ambient(), INTERP), (ambient(), DTS)


def _group_cases(mod, A, tangent, pt) -> None:
    """The verbs so3 and se3 share (``A``: element, ``tangent``: rotation vector or twist)."""
    m = mod.__name__.split(".")[-1]
    for name in ("hat", "exp", "ad", "jac_left", "jac_right", "jac_left_inv", "jac_right_inv"):
        case(f"{m}.{name}", getattr(mod, name), tangent)
    for name in ("log", "inverse", "adjoint", "jac_inverse"):
        case(f"{m}.{name}", getattr(mod, name), A)
    for name in (
        *("compose", "distance", "rminus", "lminus", "between"),
        *("jac_compose", "jac_rminus", "jac_between"),
    ):
        case(f"{m}.{name}", getattr(mod, name), A, A)
    for name in ("rplus", "lplus", "jac_rplus"):
        case(f"{m}.{name}", getattr(mod, name), A, tangent)
    for name in ("act", "jac_act"):
        case(f"{m}.{name}", getattr(mod, name), A, pt)
    case(f"{m}.interpolate", mod.interpolate, A, A, S_)


_group_cases(so3, R_, O_, PT_)
case("so3.vee", so3.vee, (ambient(3, 3), torch.cat((SKEWS, ROTS))))
case("so3.project", so3.project, (ambient(3, 3), MATRICES))
_group_cases(se3, P_, T_, PT_)
case("se3.vee", se3.vee, (ambient(4, 4), torch.cat((SKEW4S, POSES[:24]))))
case("se3.from_rt", se3.from_rt, R_, (ambient(3), TRANSLATIONS))
case("se3.to_rt", se3.to_rt, P_)
case("se3.from_pos_quat", se3.from_pos_quat, (ambient(7), POS_QUATS))
case("se3.to_pos_quat", se3.to_pos_quat, P_)


# The planar groups: rotations by multiples of 90 degrees (exact zeros and ties) and a half turn.
def _hat2(t: Tensor) -> Tensor:
    o = torch.zeros_like(t[..., 0])
    return torch.stack((o, -t[..., 0], t[..., 0], o), -1).unflatten(-1, (2, 2))


def _hat_se2(xi: Tensor) -> Tensor:
    top = torch.cat((_hat2(xi[..., 2:]), xi[..., :2, None]), -1)
    return torch.nn.functional.pad(top, (0, 0, 0, 1))


ROT2 = Kind(1, lambda R, d: R @ torch.linalg.matrix_exp(_hat2(d.reshape(*R.shape[:-2], 1))))
POSE2 = Kind(3, lambda T, d: T @ torch.linalg.matrix_exp(_hat_se2(d.reshape(*T.shape[:-2], 3))))
ANGLES2 = _t([[0.0], [PI / 2], [PI], [-PI / 2], [3 * PI / 2], [0.5], [-2.0]])
ROTS2 = so2.exp(ANGLES2[:5]).round()  # exact entries 0 and +-1
TWISTS2 = torch.stack(
    [torch.cat((rho, a)) for rho in _t([[0.0, 0.0], [1.0, 0.0], [0.0, -2.0]]) for a in ANGLES2]
)
POSES2 = torch.stack(
    [se2.from_rt(R, t) for t in _t([[0.0, 0.0], [1.0, 0.0], [0.0, -2.0]]) for R in ROTS2]
)
POINTS2 = _t([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, -2.0]])
PT2_ = (ambient(2), POINTS2)
_group_cases(so2, (ROT2, ROTS2), (ambient(1), ANGLES2), PT2_)
case("so2.vee", so2.vee, (ambient(2, 2), torch.cat((_hat2(ANGLES2), ROTS2))))
case("so2.to_complex", so2.to_complex, (ROT2, ROTS2))
case("so2.angle_to_complex", so2.angle_to_complex, (ambient(1), ANGLES2))
case(
    "so2.complex_to_angle",
    so2.complex_to_angle,
    (ambient(2), _t([[1.0, 0.0], [0.0, 2.0], [1.0, 1.0], [-3.0, 0.0], [0.0, -1.0]])),
)
case(
    "so2.from_complex",
    so2.from_complex,
    (ambient(2), _t([[1.0, 0.0], [0.0, 2.0], [1.0, 1.0], [-3.0, 0.0]])),
)
_group_cases(se2, (POSE2, POSES2), (ambient(3), TWISTS2), PT2_)
_ROT2_SET = Kind(3, lambda R, d: R @ torch.linalg.matrix_exp(_hat2(d.reshape(*R.shape[:-2], 1))))
_POSE2_SET = Kind(
    9, lambda T, d: T @ torch.linalg.matrix_exp(_hat_se2(d.reshape(*T.shape[:-2], 3)))
)
for _method in ("geodesic", "chordal"):
    case(
        f"statistics.so2_mean[{_method}]",
        partial(statistics.so2_mean, method=_method),
        (_ROT2_SET, _sets(ROTS2, 3, 24)),
        (ambient(3), WEIGHTS3),
    )
    case(
        f"statistics.se2_mean[{_method}]",
        partial(statistics.se2_mean, method=_method),
        (_POSE2_SET, _sets(POSES2[::2], 3, 24)),
        (ambient(3), WEIGHTS3),
    )
case("se2.vee", se2.vee, (ambient(3, 3), torch.cat((_hat_se2(TWISTS2), POSES2))))
case("se2.from_rt", se2.from_rt, (ROT2, ROTS2), (ambient(2), POINTS2))
case("se2.to_rt", se2.to_rt, (POSE2, POSES2))
case("se2.from_xytheta", se2.from_xytheta, (ambient(3), TWISTS2))
case("se2.to_xytheta", se2.to_xytheta, (POSE2, POSES2))


def _hat7(xi: Tensor) -> Tensor:
    return _hat6(xi[..., :6]) + xi[..., 6, None, None] * torch.diag(_t([1.0, 1.0, 1.0, 0.0]))


SIM = Kind(7, lambda T, d: T @ torch.linalg.matrix_exp(_hat7(d.reshape(*T.shape[:-2], 7))))
SIMS = torch.cat([POSES[::4] @ torch.diag(_t([s, s, s, 1.0])) for s in (1.0, 2.0)])
SIM_TANGENTS = torch.cat(
    [torch.cat((TWISTS, torch.full_like(TWISTS[:, :1], s)), -1) for s in (0.0, 0.5)]
)
SCALES = _t([1.0, 2.0, 0.5])
SIM_ = (SIM, SIMS)
_group_cases(sim3, SIM_, (ambient(7), SIM_TANGENTS), PT_)
# fewer points for the Jacobians built on a matrix exponential of size 14, and for distance
# a second argument whose scale, translation and rotation differ from the first's (each of its
# three parts has a cone where they are equal)
_REDONE = ("sim3.jac_rminus", "sim3.jac_rplus", "sim3.distance")
CASES[:] = [c for c in CASES if c.name not in _REDONE]
case("sim3.jac_rminus", sim3.jac_rminus, (SIM, SIMS[::3]), (SIM, SIMS[1::3]))
case("sim3.jac_rplus", sim3.jac_rplus, (SIM, SIMS[::3]), (ambient(7), SIM_TANGENTS[::2]))
_SHIFT = se3.exp(_t([0.5, 0.25, 0.0, 0.3, 0.2, 0.1])) @ torch.diag(_t([3.0, 3.0, 3.0, 1.0]))
case("sim3.distance", sim3.distance, SIM_, (SIM, SIMS[::2] @ _SHIFT))
case("sim3.vee", sim3.vee, (ambient(4, 4), torch.cat((_hat7(SIM_TANGENTS), SIMS[:12]))))
case("sim3.from_srt", sim3.from_srt, (ambient(), SCALES), R_, (ambient(3), TRANSLATIONS))
case("sim3.to_srt", sim3.to_srt, SIM_)
case("sim3.from_se3", sim3.from_se3, P_, (ambient(), SCALES))
case("sim3.scale", sim3.scale, SIM_)
_PQS = torch.cat((POS_QUATS, SCALES.repeat(len(POS_QUATS) // 3 + 1)[: len(POS_QUATS), None]), -1)
case("sim3.from_pos_quat_scale", sim3.from_pos_quat_scale, (ambient(8), _PQS))
case("sim3.to_pos_quat_scale", sim3.to_pos_quat_scale, SIM_)
for _kind in ("angle", "chordal"):
    case(
        f"nn.sim3_geodesic_loss[{_kind}]",
        partial(tnn.sim3_geodesic_loss, translation_weight=0.5, kind=_kind, reduction="none"),
        SIM_,
        (SIM, SIMS[::2] @ se3.exp(_t([0.5, 0.25, 0.0, 0.3, 0.2, 0.1]))),
    )
_Q8 = torch.cat((POS_QUATS[::5], torch.zeros(len(POS_QUATS[::5]), 1, dtype=DT)), -1)
case("nn.Sim3Parametrization[pos_quat_sigma]", tnn.Sim3Parametrization(), (ambient(8), _Q8))
# similarities, and blocks that are not: a reflection's multiple, rank 2, a shear
_M4 = torch.cat(
    (
        SIMS,
        torch.diag(_t([-2.0, 1.0, 3.0, 1.0]))[None],
        torch.diag(_t([1.0, 3.0, 0.0, 0.0]))[None],
        _t([[[1.0, 1.0, 0.0, 0.5], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, -1.0], [0, 0, 0, 1]]]),
    )
)
case("nn.Sim3Parametrization[matrix]", tnn.Sim3Parametrization("matrix"), (ambient(4, 4), _M4))
case(
    "nn.Sim3Parametrization[tangent]",
    tnn.Sim3Parametrization("tangent"),
    (ambient(7), SIM_TANGENTS),
)
for _rep in ("pos_quat_sigma", "matrix", "tangent"):
    case(
        f"nn.Sim3Parametrization[{_rep}].right_inverse",
        tnn.Sim3Parametrization(_rep).right_inverse,
        SIM_,
    )
_SIM_SET = Kind(21, SIM.move)
for _method in ("geodesic", "chordal"):
    case(
        f"statistics.sim3_mean[{_method}]",
        partial(statistics.sim3_mean, method=_method),
        (_SIM_SET, _sets(torch.cat((SIMS[:4], SIMS[18:22])), 3, 24)),
        (ambient(3), WEIGHTS3),
    )

for _name in (
    *("conjugate", "inverse", "normalize", "canonicalize", "exp", "log", "to_matrix"),
    *("to_rotvec", "to_xyzw", "from_xyzw", "to_jpl", "from_jpl", "to_su2"),
    *("left_matrix", "right_matrix"),
):
    case(f"quaternion.{_name}", getattr(quaternion, _name), Q_)
PURE = torch.cat((0 * ROTVECS[:, :1], ROTVECS), -1)
case("quaternion.exp[pure]", quaternion.exp, (ambient(4), PURE))
case("quaternion.multiply", quaternion.multiply, Q_, Q_)
case("quaternion.apply", quaternion.apply, Q_, PT_)
case("quaternion.slerp", quaternion.slerp, Q_, Q_, S_)
case("quaternion.from_matrix", quaternion.from_matrix, R_)
case("quaternion.from_rotvec", quaternion.from_rotvec, O_)
case("quaternion.from_su2", quaternion.from_su2, (COMPLEX2, quaternion.to_su2(QUATS)))
for _frame in ("body", "world"):
    case(
        f"quaternion.derivative[{_frame}]",
        partial(quaternion.derivative, frame=_frame),
        Q_,
        O_,
    )
    case(
        f"quaternion.integrate[{_frame}]",
        partial(quaternion.integrate, frame=_frame),
        Q_,
        O_,
        DT_,
    )

E_ = (ambient(3), EULERS)
for _seq in SEQUENCES:
    for _name, _arg in (
        ("euler_to_quaternion", E_),
        ("euler_to_matrix", E_),
        ("quaternion_to_euler", Q_),
        ("matrix_to_euler", R_),
    ):
        case(f"conversions.{_name}[{_seq}]", partial(getattr(conversions, _name), seq=_seq), _arg)
    # Round trips (not public names): the identity map wherever it is smooth.
    for _to in ("matrix", "quaternion"):
        _there = partial(getattr(conversions, f"euler_to_{_to}"), seq=_seq)
        _back = partial(getattr(conversions, f"{_to}_to_euler"), seq=_seq)
        case(
            f"round_trip.{_to}_to_euler(euler_to_{_to})[{_seq}]",
            lambda a, t=_there, b=_back: b(t(a)),
            E_,
        )
case(
    "conversions.axis_angle_to_matrix",
    conversions.axis_angle_to_matrix,
    (ambient(3), AXES),
    (ambient(), ANGLES),
)
case("conversions.matrix_to_axis_angle", conversions.matrix_to_axis_angle, R_)
case("conversions.rot6d_to_matrix", conversions.rot6d_to_matrix, (ambient(6), ROT6DS))
case("conversions.matrix_to_rot6d", conversions.matrix_to_rot6d, R_)
case("conversions.rot9d_to_matrix", conversions.rot9d_to_matrix, (ambient(9), MATRICES.flatten(-2)))


def _unique_mean_case(name: str, fn: Callable[..., Any], sets: tuple[Kind, Tensor]) -> None:
    """A mean's case without the sets whose mean is not unique: ``sum_i w_i R_i`` of rank 1 or
    less (two rotations pi apart with equal weights), where every rotation about an axis is a
    mean, the result is one of them and its derivatives belong to no particular one (the means'
    docstring).  The differences along a direction can still look smooth there, taking one
    branch on both sides, while the rounding at the point itself chooses another."""
    points = _grid(sets[1], WEIGHTS3)
    R = points[0][..., :3, :3]
    w = points[1] / points[1].sum(-1, keepdim=True)
    second = torch.linalg.svdvals((w[..., None, None] * R).sum(-3))[..., 1]
    keep = second > 1e-6
    kinds = (sets[0], ambient(3))
    CASES.append(Case(name, fn, kinds, tuple(p[keep] for p in points)))


for _method in ("geodesic", "chordal"):
    _unique_mean_case(
        f"statistics.so3_mean[{_method}]",
        partial(statistics.so3_mean, method=_method),
        (_rot_set(3), ROT_SETS),
    )
    _unique_mean_case(
        f"statistics.se3_mean[{_method}]",
        partial(statistics.se3_mean, method=_method),
        (_pose_set(3), POSE_SETS),
    )


def _keyframes(fn):
    """``fn(times, keyframes (K, *b), query (*q))`` has shape ``(*q, *b)``: with ``b = q = (B,)``
    its diagonal is the batch of independent points."""

    def call(times, keys, query):
        out = fn(times[0], keys.movedim(0, 1), query)
        return out.diagonal(0, 0, 1).movedim(-1, 0)

    return call


_TIMES = _t([[0.0, 1.0, 3.0]])
_QUERY = _t([0.0, 0.5, 1.0, 2.0, 3.0, -1.0, 4.0])
for _g, _kind, _sets_of in (
    ("so3", _rot_set(3), ROT_SETS),
    ("se3", _pose_set(3), POSE_SETS),
    ("so2", _ROT2_SET, _sets(ROTS2, 3, 24)),
    ("se2", _POSE2_SET, _sets(POSES2[::2], 3, 24)),
    ("sim3", _SIM_SET, _sets(torch.cat((SIMS[:4], SIMS[18:22])), 3, 24)),
):
    _name = f"{_g}_interpolate_keyframes"
    _args = ((FIXED, _TIMES), (_kind, _sets_of[:8]), (ambient(), _QUERY))
    case(f"statistics.{_name}", _keyframes(getattr(statistics, _name)), *_args, chunk=1)
for _scale, _translation in itertools.product((False, True), repeat=2):
    _v = f"scale={_scale},translation={_translation}"
    case(
        f"statistics.align[{_v}]",
        partial(statistics.align, scale=_scale, translation=_translation),
        (ambient(4, 3), POINT_SETS.repeat(len(ROTS) * 2, 1, 1)),
        (
            ambient(4, 3),
            torch.stack(
                [2.0 * P @ R.mT + t for R in ROTS for t in TRANSLATIONS[:2] for P in POINT_SETS]
            ),
        ),
        (ambient(4), WEIGHTS4),
    )
for _frame in ("body", "world"):
    for _g, _args in (
        ("so3", (R_, O_, DT_)),
        ("se3", (P_, T_, DT_)),
        ("so2", ((ROT2, ROTS2), (ambient(1), ANGLES2), DT_)),
        ("se2", ((POSE2, POSES2), (ambient(3), TWISTS2), DT_)),
        ("sim3", (SIM_, (ambient(7), SIM_TANGENTS), DT_)),
    ):
        _fn = partial(getattr(statistics, f"{_g}_integrate"), frame=_frame)
        case(f"statistics.{_g}_integrate[{_frame}]", _fn, *_args)

_REPS = {
    "6d": torch.cat((ROT6DS, torch.zeros(1, 6, dtype=DT))),
    "9d": torch.cat((MATRICES.flatten(-2), torch.zeros(1, 9, dtype=DT))),
    "quaternion": torch.cat((QUATS, torch.zeros(1, 4, dtype=DT))),
    "rotvec": ROTVECS,
}
for _rep, _pts in _REPS.items():
    case(
        f"nn.representation_to_matrix[{_rep}]",
        partial(tnn.representation_to_matrix, representation=_rep),
        (ambient(_pts.shape[-1]), _pts),
    )
for _kind in ("angle", "chordal"):
    case(
        f"nn.geodesic_loss[{_kind}]",
        partial(tnn.geodesic_loss, kind=_kind, reduction="none"),
        R_,
        R_,
    )
    case(
        f"nn.se3_geodesic_loss[{_kind}]",
        partial(
            tnn.se3_geodesic_loss,
            rotation_weight=2.0,
            translation_weight=0.5,
            kind=_kind,
            reduction="none",
        ),
        P_,
        P_,
    )
_PARAMS = {
    "SO3Parametrization": {
        "quaternion": (ambient(4), _REPS["quaternion"]),
        "matrix": (ambient(3, 3), MATRICES),
        "rotvec": O_,
    },
    "SE3Parametrization": {
        "pos_quat": (ambient(7), torch.cat((POS_QUATS, torch.zeros(1, 7, dtype=DT)))),
        "matrix": (ambient(4, 4), POSES),
        "twist": T_,
    },
}
for _cls, _reps in _PARAMS.items():
    for _rep, _arg in _reps.items():
        _module = getattr(tnn, _cls)(_rep)
        case(f"nn.{_cls}[{_rep}]", _module, _arg)
        case(
            f"nn.{_cls}[{_rep}].right_inverse",
            _module.right_inverse,
            R_ if _cls.startswith("SO3") else P_,
        )

for _kind in ("angle", "chordal"):
    case(
        f"nn.so2_geodesic_loss[{_kind}]",
        partial(tnn.so2_geodesic_loss, kind=_kind, reduction="none"),
        (ROT2, ROTS2),
        (ROT2, ROTS2),
    )
    case(
        f"nn.se2_geodesic_loss[{_kind}]",
        partial(tnn.se2_geodesic_loss, rotation_weight=2.0, kind=_kind, reduction="none"),
        (POSE2, POSES2),
        (POSE2, POSES2),
    )
_COMPLEX = _t([[1.0, 0.0], [0.0, 2.0], [1.0, 1.0], [-3.0, 0.0], [0.0, 0.0]])
_PARAMS2 = {
    "SO2Parametrization": {
        "complex": (ambient(2), _COMPLEX),
        "matrix": (ambient(2, 2), torch.cat((ROTS2, 2 * ROTS2 + _t([[0.0, 1.0], [0.0, 0.0]])))),
        "angle": (ambient(1), ANGLES2),
    },
    "SE2Parametrization": {
        "pos_complex": (ambient(4), torch.cat((POINTS2[[0, 1, 2, 3, 3]], _COMPLEX), -1)),
        "matrix": (ambient(3, 3), POSES2),
        "twist": (ambient(3), TWISTS2),
    },
}
for _cls, _reps in _PARAMS2.items():
    for _rep, _arg in _reps.items():
        _module = getattr(tnn, _cls)(_rep)
        case(f"nn.{_cls}[{_rep}]", _module, _arg)
        case(
            f"nn.{_cls}[{_rep}].right_inverse",
            _module.right_inverse,
            (ROT2, ROTS2) if _cls.startswith("SO2") else (POSE2, POSES2),
        )

# The classes: every public method and property that computes from tensors.


def _call(attr: Any) -> Any:
    """A method's result, or a property's value."""
    return attr() if callable(attr) else attr


_CLASSES = (
    (SO3, R_, O_, PT_),
    (SE3, P_, T_, PT_),
    (SO2, (ROT2, ROTS2), (ambient(1), ANGLES2), PT2_),
    (SE2, (POSE2, POSES2), (ambient(3), TWISTS2), PT2_),
    (Sim3, SIM_, (ambient(7), SIM_TANGENTS), PT_),
)
for _G, _A, _tan, _pt in _CLASSES:
    _n = _G.__name__
    case(f"{_n}.exp", lambda w, G=_G: G.exp(w), _tan)
    case(f"{_n}.compose", lambda a, b, G=_G: G(a).compose(G(b)), _A, _A)
    case(f"{_n}.matmul", lambda a, b, G=_G: G(a) @ G(b), _A, _A)
    case(f"{_n}.apply", lambda a, p, G=_G: G(a).apply(p), _A, _pt)
    for _m in ("inverse", "log", "adjoint", "matrix", "rotation"):
        case(f"{_n}.{_m}", lambda a, G=_G, m=_m: _call(getattr(G(a), m)), _A)
    for _m in ("rplus", "lplus"):
        case(f"{_n}.{_m}", lambda a, w, G=_G, m=_m: getattr(G(a), m)(w), _A, _tan)
    for _m in ("rminus", "lminus", "between", "distance"):
        case(f"{_n}.{_m}", lambda a, b, G=_G, m=_m: getattr(G(a), m)(G(b)), _A, _A)
    case(f"{_n}.interpolate", lambda a, b, t, G=_G: G(a).interpolate(G(b), t), _A, _A, S_)
    if hasattr(_G, "quaternion"):
        case(f"{_n}.quaternion", lambda a, G=_G: G(a).quaternion(), _A)
case("SO3.from_quaternion", SO3.from_quaternion, Q_)
case("SO2.complex", lambda R: SO2(R).complex(), (ROT2, ROTS2))
case("SO2.from_complex", SO2.from_complex, (ambient(2), _t([[1.0, 0.0], [0.0, 2.0], [1.0, 1.0]])))
case("SE2.from_rt", SE2.from_rt, (ROT2, ROTS2), (ambient(2), POINTS2))
case("SE2.from_xytheta", SE2.from_xytheta, (ambient(3), TWISTS2))
case("SE2.to_rt", lambda T: SE2(T).to_rt(), (POSE2, POSES2))
case("SE2.translation", lambda T: SE2(T).translation, (POSE2, POSES2))
case("SE2.xytheta", lambda T: SE2(T).xytheta(), (POSE2, POSES2))
case("Sim3.from_srt", Sim3.from_srt, (ambient(), SCALES), R_, (ambient(3), TRANSLATIONS))
case("Sim3.from_se3", Sim3.from_se3, P_, (ambient(), SCALES))
case("Sim3.to_srt", lambda T: Sim3(T).to_srt(), SIM_)
case("Sim3.from_pos_quat_scale", Sim3.from_pos_quat_scale, (ambient(8), _PQS))
case("Sim3.pos_quat_scale", lambda T: Sim3(T).pos_quat_scale(), SIM_)
case("Sim3.pose", lambda T: Sim3(T).pose(), SIM_)
case("Sim3.scale", lambda T: Sim3(T).scale, SIM_)
case("Sim3.translation", lambda T: Sim3(T).translation, SIM_)
# as sim3.distance: a second argument whose three parts all differ from the first's
CASES[:] = [c for c in CASES if c.name != "Sim3.distance"]
case("Sim3.distance", lambda a, b: Sim3(a).distance(Sim3(b)), SIM_, (SIM, SIMS[::2] @ _SHIFT))
case("SE3.from_rt", SE3.from_rt, R_, (ambient(3), TRANSLATIONS))
case("SE3.from_pos_quat", SE3.from_pos_quat, (ambient(7), POS_QUATS))
case("SE3.to_rt", lambda T: SE3(T).to_rt(), P_)
case("SE3.pos_quat", lambda T: SE3(T).pos_quat(), P_)
case("SE3.translation", lambda T: SE3(T).translation, P_)


#: Public names that are not checked here, and why.
EXCLUDED = {
    # not differentiable: boolean results, factories, random draws
    "so3.identity": "factory",
    "so3.random": "random draw",
    "so3.is_valid": "boolean result",
    "se3.identity": "factory",
    "se3.random": "random draw",
    "se3.is_valid": "boolean result",
    **{
        f"{g}.{m}": r
        for g in ("so2", "se2")
        for m, r in (
            ("identity", "factory"),
            ("random", "random draw"),
            ("is_valid", "boolean result"),
        )
    },
    "sim3.identity": "factory",
    "sim3.random": "random draw",
    "sim3.is_valid": "boolean result",
    "quaternion.identity": "factory",
    "quaternion.random": "random draw",
    "quaternion.is_unit": "boolean result",
    "statistics.so3_randn": "random draw (its differentiable part is so3.exp and compose)",
    "statistics.se3_randn": "random draw (its differentiable part is se3.exp and compose)",
    **{
        f"statistics.{g}_randn": f"random draw (its differentiable part is {g}.rplus)"
        for g in ("sim3", "so2", "se2")
    },
    "statistics.Alignment": "the result type of align",
    "nn.REPRESENTATIONS": "a table of sizes",
    "nn.RotationHead": "nn.Linear then nn.representation_to_matrix (checked)",
    "nn.PoseHead": "nn.Linear then nn.representation_to_matrix and se3.from_rt (checked)",
    "nn.PlanarPoseHead": "nn.Linear then so2.from_complex and se2.from_rt (checked)",
    # class plumbing: factories, predicates, metadata, copies
    **{
        f"{g}.{m}": "class plumbing"
        for g in ("SO3", "SE3", "SO2", "SE2", "Sim3")
        for m in (
            "identity",
            "random",
            "is_valid",
            "shape",
            "ndim",
            "dtype",
            "device",
            "requires_grad",
            "requires_grad_",
            "to",
            "detach",
            "clone",
            "tensor",
        )
    },
}

# ----------------------------------------------------------------------------------------------
# The check
# ----------------------------------------------------------------------------------------------


def _leaves(out: Any) -> list[Tensor]:
    if isinstance(out, Tensor):
        return [out]
    if isinstance(out, SO3 | SE3 | SO2 | SE2 | Sim3):
        return [out.tensor]
    if isinstance(out, tuple | list):
        return [t for o in out for t in _leaves(o)]
    raise TypeError(f"unexpected result {type(out).__name__}")


def _flat(leaves: list[Tensor], n: int) -> Tensor:
    parts = [torch.view_as_real(t) if t.is_complex() else t for t in leaves]
    return torch.cat([t.reshape(n, -1) for t in parts], 1)


def _differences(G: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """From values at the stencil ``(5, n, m)``: the Richardson central difference ``(n, m)``,
    whether the point is smooth along the direction ``(n,)``, and the scale of both."""
    d1 = (G[1] - G[2]) / (2 * H)
    d2 = (G[3] - G[4]) / (4 * H)
    central = (4 * d1 - d2) / 3
    ahead = (-3 * G[0] + 4 * G[1] - G[3]) / (2 * H)  # one-sided, second order (h and 2h)
    behind = (3 * G[0] - 4 * G[2] + G[4]) / (2 * H)
    scale = 1 + central.abs().amax(-1) + G[0].abs().amax(-1)
    smooth = (ahead - behind).abs().amax(-1) <= SMOOTH_TOL * scale  # NaN: False
    smooth &= torch.isfinite(G).flatten(2).all(-1).all(0)
    return central, smooth, scale


class Result(NamedTuple):
    """Per point (size P): checked to first / second order, and which comparisons failed."""

    first: Tensor
    second: Tensor
    reverse: Tensor
    forward: Tensor
    hessian: Tensor


def _check_argument(c: Case, points: tuple[Tensor, ...], a: int, gen: torch.Generator) -> Result:
    kind = c.kinds[a]
    assert kind is not None
    P = points[0].shape[0]
    n, S = P * DIRECTIONS, len(STENCIL)
    base = [x.repeat_interleave(DIRECTIONS, 0) for x in points]
    u = torch.randn(n, kind.dim, generator=gen, dtype=DT)

    def call(args: list[Tensor], d: Tensor) -> list[Tensor]:
        args = list(args)
        args[a] = kind.move(args[a], d)
        return _leaves(c.fn(*args))

    # Values and gradients on the stencil x0 + s h u.
    based = [x.repeat(S, *[1] * (x.dim() - 1)) for x in base]
    step = (torch.tensor(STENCIL, dtype=DT)[:, None, None] * H * u).reshape(S * n, -1)
    d = torch.zeros(S * n, kind.dim, dtype=DT, requires_grad=True)
    out = _flat(call(based, step + d), S * n)
    m = out.shape[1]
    v = torch.randn(n, m, generator=gen, dtype=DT)
    grads = _grad((out * v.repeat(S, 1)).sum(), d)
    values, grads = out.detach().reshape(S, n, m), grads.reshape(S, n, kind.dim)
    central, smooth1, scale1 = _differences(values)
    central_g, smooth2, scale2 = _differences(grads)
    smooth2 &= smooth1

    # (a) reverse mode and (c) Hessian-vector product at x0.
    d0 = torch.zeros(n, kind.dim, dtype=DT, requires_grad=True)
    g0 = _grad((_flat(call(base, d0), n) * v).sum(), d0, create_graph=True)
    hv = _grad((g0 * u).sum(), d0)
    rev = (g0.detach() * u).sum(-1)
    bad_rev = ~((rev - (central * v).sum(-1)).abs() <= TOL * scale1 * v.abs().sum(-1))
    bad_hv = ~((hv - central_g).abs().amax(-1) <= TOL * scale2)

    # (b) forward mode at x0.
    with fwAD.dual_level():
        leaves = call(base, fwAD.make_dual(torch.zeros(n, kind.dim, dtype=DT), u))
        tangents = []
        for t in leaves:
            tan = fwAD.unpack_dual(t).tangent
            tangents.append(torch.zeros_like(t) if tan is None else tan)
    jv = _flat(tangents, n)
    bad_fwd = ~((jv - central).abs().amax(-1) <= TOL * scale1)

    def per_point(x: Tensor) -> Tensor:
        return x.reshape(P, DIRECTIONS).any(-1)

    return Result(
        per_point(smooth1),
        per_point(smooth2),
        per_point(smooth1 & bad_rev),
        per_point(smooth1 & bad_fwd),
        per_point(smooth2 & bad_hv),
    )


def _grad(y: Tensor, x: Tensor, create_graph: bool = False) -> Tensor:
    """``dy/dx`` (zeros where ``y`` does not depend on ``x``)."""
    if not y.requires_grad:
        return torch.zeros_like(x)
    (g,) = torch.autograd.grad(y, x, create_graph=create_graph, allow_unused=True)
    return torch.zeros_like(x) if g is None else g


def run_case(c: Case) -> Result:
    """All differentiable arguments of ``c`` at all its points; per point, checked if smooth
    along some direction of some argument, failed if any comparison there failed."""
    gen = torch.Generator().manual_seed(sum(map(ord, c.name)))
    P = c.points[0].shape[0]
    size = c.chunk or P
    chunks = []
    for lo in range(0, P, size):
        pts = tuple(p[lo : lo + size] for p in c.points)
        rs = [_check_argument(c, pts, a, gen) for a, k in enumerate(c.kinds) if k is not None]
        chunks.append(Result(*(torch.stack(f).any(0) for f in zip(*rs, strict=True))))
    return Result(*(torch.cat(f) for f in zip(*chunks, strict=True)))


# ----------------------------------------------------------------------------------------------
# Tests
# ----------------------------------------------------------------------------------------------

#: At least this fraction of a case's points is smooth, so checked, to first and to second
#: order (the rest: cones, sign flips and gimbal lock), so that no case passes vacuously.
MIN_CHECKED = 0.3


@pytest.mark.parametrize("c", CASES, ids=[c.name for c in CASES])
def test_derivatives_at_exact_points(c: Case):
    r = run_case(c)
    P = len(r.first)
    wrong = r.reverse | r.forward | r.hessian
    msg = []
    for i in wrong.nonzero().flatten()[:5].tolist():
        which = [f for f in ("reverse", "forward", "hessian") if getattr(r, f)[i]]
        args = ", ".join(str(p[i].tolist()) for p in c.points)
        msg.append(f"  point {i} ({args}): {', '.join(which)}")
    assert not wrong.any(), f"{c.name}: {int(wrong.sum())} of {P} points wrong\n" + "\n".join(msg)
    for order, smooth in (("first", r.first), ("second", r.second)):
        n = int(smooth.sum())
        assert n >= MIN_CHECKED * P, f"{c.name}: only {n} of {P} points checked to {order} order"


def _public_names() -> set[str]:
    names = set()
    for mod in (so3, se3, so2, se2, sim3, quaternion, conversions, statistics, tnn):
        names |= {f"{mod.__name__.split('.')[-1]}.{n}" for n in mod.__all__}
    for G in (SO3, SE3, SO2, SE2, Sim3):
        names |= {f"{G.__name__}.{n}" for n in dir(G) if not n.startswith("_")}
    return names


def test_every_public_function_is_checked():
    """A public name is either a case here or excluded with a reason."""
    assert {n for n in torchlie.__all__ if n[0].islower()} <= {
        "so3",
        "se3",
        "so2",
        "se2",
        "sim3",
        "quaternion",
        "conversions",
        "statistics",
        "nn",
        "kinematics",  # robot models; its derivatives are tested with kinematics
    }
    covered = {c.name.split("[")[0] for c in CASES}
    missing = _public_names() - covered - set(EXCLUDED)
    assert not missing, f"public names neither checked nor excluded: {sorted(missing)}"
    assert not (covered & set(EXCLUDED))


def _issue_examples():
    """The wrong derivatives of the issue, each at its exact point."""
    s = S2
    Rz90 = _t([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    return [
        ("so3.distance", lambda R: so3.distance(R, torch.eye(3, dtype=DT)), Rz90),
        ("quaternion.log w=0", quaternion.log, _t([0.0, 1.0, 0.0, 0.0])),
        ("quaternion.log tie", quaternion.log, _t([s, s, 0.0, 0.0])),
        ("quaternion.to_rotvec tie", quaternion.to_rotvec, _t([1.0, 1.0, 0.0, 0.0])),
        (
            "quaternion.slerp",
            lambda q0: quaternion.slerp(q0, _t([s, s, 0.0, 0.0]), 0.5),
            _t([1.0, 0.0, 0.0, 0.0]),
        ),
        ("quaternion_to_euler", lambda q: conversions.quaternion_to_euler(q, "xyz"), QUATS[0]),
        ("matrix_to_euler", lambda R: conversions.matrix_to_euler(R, "zyx"), ROTS[0]),
    ]


@pytest.mark.parametrize("name, fn, x", _issue_examples(), ids=[e[0] for e in _issue_examples()])
def test_issue_examples_gradcheck(name, fn, x):
    """gradcheck and gradgradcheck (reverse and forward mode) at the issue's exact points; the
    matrix functions through tangent coordinates."""
    if x.shape == (3, 3):
        R = x

        def f(d):
            return fn(R @ torch.linalg.matrix_exp(_hat3(d)))

        x = torch.zeros(3, dtype=DT)
    else:
        f = fn
    x = x.clone().requires_grad_()
    assert torch.autograd.gradcheck(f, (x,), check_forward_ad=True)
    assert torch.autograd.gradgradcheck(f, (x,))


def test_issue_values():
    """The true derivatives the issue names."""
    Rz90 = _t([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]).requires_grad_()
    (g,) = torch.autograd.grad(so3.distance(Rz90, torch.eye(3, dtype=DT)), Rz90)
    torch.testing.assert_close(g.diagonal(), _t([-0.5, -0.5, -0.5]))
    q = _t([0.0, 1.0, 0.0, 0.0]).requires_grad_()
    (g,) = torch.autograd.grad(quaternion.log(q)[1], q)
    torch.testing.assert_close(g[0], _t(-1.0))
    q = _t([1.0, 0.0, 0.0, 0.0]).requires_grad_()
    H_ = torch.autograd.functional.hessian(
        lambda q: conversions.quaternion_to_euler(q, "xyz")[0], q
    )
    assert torch.isfinite(H_).all()
    a = torch.zeros(3, dtype=DT)
    J = torch.autograd.functional.jacobian(
        lambda a: conversions.matrix_to_euler(conversions.euler_to_matrix(a, "xyz"), "xyz"), a
    )
    torch.testing.assert_close(J, torch.eye(3, dtype=DT))


def _summary() -> None:
    """Per case: points, checked to first / second order, wrong in reverse, forward, second
    order and in any of them; then the totals."""
    head = ("points", "first", "second", "reverse", "forward", "hessian", "wrong")
    print(f"{'case':60s}" + "".join(f"{h:>8s}" for h in head))
    totals = [0] * len(head)
    for c in CASES:
        r = run_case(c)
        row = [len(r.first), *(int(x.sum()) for x in r), int((r[2] | r[3] | r[4]).sum())]
        totals = [t + x for t, x in zip(totals, row, strict=True)]
        print(f"{c.name:60s}" + "".join(f"{x:8d}" for x in row))
    print(f"{'total':60s}" + "".join(f"{x:8d}" for x in totals))


if __name__ == "__main__":
    torch.set_num_threads(1)
    _summary()
