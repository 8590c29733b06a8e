"""The benchmarked operations: inputs in torchlie's conventions, torchlie's function, a reference.

Every op is described once by an :class:`Op`:

* ``inputs(n, dtype, gen)`` draws ``n`` elements in torchlie's conventions (wxyz quaternions,
  column-vector matrices, twists ``(rho, phi)``, 4x4 poses).  The values are drawn in float64
  and cast, so float32 and float64 runs see the same elements.  Angles are uniform in
  ``(0, pi)``: generic elements, no special points.
* ``torchlie()`` resolves torchlie's function lazily (``None`` when the module or function does
  not exist yet, e.g. while ``torchlie.se3`` is being written).
* ``reference(*inputs)`` is an independent float64 value (``torch.linalg.matrix_exp`` of the Lie
  algebra element, plain matmuls, or ``scipy.spatial.transform``) used by the tests to check
  torchlie and every peer adapter on the same inputs.
* ``out_numbers``: numbers per element of the output; with the inputs' numbers per element it
  sizes the copy floor (see ``run.py``).
* ``compare``: ``"value"`` (elementwise) or ``"quat"`` (equal up to the sign of the quaternion).
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor

# ----------------------------------------------------------------------------------------------
# Input samplers (torchlie conventions)
# ----------------------------------------------------------------------------------------------


def _unit(v: Tensor) -> Tensor:
    return v / v.norm(dim=-1, keepdim=True)


def rotvecs(n: int, gen: torch.Generator) -> Tensor:
    """``(n, 3)`` float64 rotation vectors, uniform axis, angle uniform in ``(0, pi)``."""
    axis = _unit(torch.randn(n, 3, generator=gen, dtype=torch.float64))
    angle = torch.rand(n, 1, generator=gen, dtype=torch.float64) * math.pi
    return axis * angle


def quaternions(n: int, gen: torch.Generator) -> Tensor:
    """``(n, 4)`` float64 Haar-uniform unit quaternions ``(w, x, y, z)`` (either sign)."""
    return _unit(torch.randn(n, 4, generator=gen, dtype=torch.float64))


def quat_to_matrix(q: Tensor) -> Tensor:
    """Rotation matrix of a unit wxyz quaternion (plain formula, for building inputs)."""
    w, x, y, z = q.unbind(-1)
    rows = (
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    )  # fmt: skip
    return torch.stack(rows, dim=-1).unflatten(-1, (3, 3))


def rotmats(n: int, gen: torch.Generator) -> Tensor:
    """``(n, 3, 3)`` float64 Haar-uniform rotation matrices."""
    return quat_to_matrix(quaternions(n, gen))


def points(n: int, gen: torch.Generator) -> Tensor:
    """``(n, 3)`` float64 standard-normal points."""
    return torch.randn(n, 3, generator=gen, dtype=torch.float64)


def twists(n: int, gen: torch.Generator) -> Tensor:
    """``(n, 6)`` float64 twists ``(rho, phi)``; ``rho`` standard normal, ``phi`` as rotvecs."""
    return torch.cat((points(n, gen), rotvecs(n, gen)), dim=-1)


def poses(n: int, gen: torch.Generator) -> Tensor:
    """``(n, 4, 4)`` float64 homogeneous poses ``[[R, t], [0, 1]]``."""
    R = rotmats(n, gen)
    t = points(n, gen)
    top = torch.cat((R, t.unsqueeze(-1)), dim=-1)
    bottom = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=torch.float64).expand(n, 1, 4)
    return torch.cat((top, bottom), dim=-2)


def angles(n: int, gen: torch.Generator) -> Tensor:
    """``(n, 1)`` float64 planar angles, uniform in ``(-pi, pi)``."""
    return (2.0 * torch.rand(n, 1, generator=gen, dtype=torch.float64) - 1.0) * math.pi


def rot2(theta: Tensor) -> Tensor:
    """``(..., 2, 2)`` rotation matrices of angles ``(..., 1)``."""
    c, s = theta.cos(), theta.sin()
    return torch.cat((c, -s, s, c), dim=-1).unflatten(-1, (2, 2))


def planar_twists(n: int, gen: torch.Generator) -> Tensor:
    """``(n, 3)`` float64 twists ``(rho_x, rho_y, theta)``; ``rho`` standard normal."""
    return torch.cat((torch.randn(n, 2, generator=gen, dtype=torch.float64), angles(n, gen)), -1)


def planar_poses(n: int, gen: torch.Generator) -> Tensor:
    """``(n, 3, 3)`` float64 planar poses ``[[R, t], [0, 1]]``."""
    top = torch.cat(
        (rot2(angles(n, gen)), torch.randn(n, 2, 1, generator=gen, dtype=torch.float64)), -1
    )
    bottom = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand(n, 1, 3)
    return torch.cat((top, bottom), dim=-2)


def sim3_tangents(n: int, gen: torch.Generator) -> Tensor:
    """``(n, 7)`` float64 ``(rho, phi, sigma)``: a twist and a standard-normal log scale."""
    return torch.cat((twists(n, gen), torch.randn(n, 1, generator=gen, dtype=torch.float64)), -1)


def similarities(n: int, gen: torch.Generator) -> Tensor:
    """``(n, 4, 4)`` float64 ``[[s R, t], [0, 1]]`` (``s = exp(N(0, 1))``)."""
    T = poses(n, gen)
    s = torch.exp(torch.randn(n, 1, 1, generator=gen, dtype=torch.float64))
    scale = torch.cat((s.expand(n, 3, 3), torch.ones(n, 3, 1, dtype=T.dtype)), -1)
    return torch.cat((T[:, :3] * scale, T[:, 3:]), 1)


# ----------------------------------------------------------------------------------------------
# References (float64, independent of torchlie and of the peers)
# ----------------------------------------------------------------------------------------------


def hat(w: Tensor) -> Tensor:
    x, y, z = w.unbind(-1)
    o = torch.zeros_like(x)
    return torch.stack((o, -z, y, z, o, -x, -y, x, o), dim=-1).unflatten(-1, (3, 3))


def se3_hat(xi: Tensor) -> Tensor:
    """4x4 Lie-algebra matrix ``[[hat(phi), rho], [0, 0]]`` of a twist ``(rho, phi)``."""
    rho, phi = xi[..., :3], xi[..., 3:]
    top = torch.cat((hat(phi), rho.unsqueeze(-1)), dim=-1)
    return torch.cat((top, torch.zeros_like(top[..., :1, :])), dim=-2)


def _scipy_rotation():
    from scipy.spatial.transform import Rotation

    return Rotation


def _xyzw(q: Tensor) -> Tensor:
    return torch.cat((q[..., 1:], q[..., :1]), dim=-1)


def _wxyz(q: Tensor) -> Tensor:
    return torch.cat((q[..., 3:], q[..., :3]), dim=-1)


def _ref_so3_log(R: Tensor) -> Tensor:
    return torch.from_numpy(_scipy_rotation().from_matrix(R.numpy()).as_rotvec())


def _ref_from_matrix(R: Tensor) -> Tensor:
    return _wxyz(torch.from_numpy(_scipy_rotation().from_matrix(R.numpy()).as_quat()))


def _ref_multiply(q1: Tensor, q2: Tensor) -> Tensor:
    Rot = _scipy_rotation()
    r = Rot.from_quat(_xyzw(q1).numpy()) * Rot.from_quat(_xyzw(q2).numpy())
    return _wxyz(torch.from_numpy(r.as_quat()))


def _ref_quat_apply(q: Tensor, p: Tensor) -> Tensor:
    return torch.from_numpy(_scipy_rotation().from_quat(_xyzw(q).numpy()).apply(p.numpy()))


def _ref_se3_log(T: Tensor) -> Tensor:
    # phi from scipy; rho = V(phi)^-1 t, with V's columns read off exp of the twists (e_i, phi).
    phi = _ref_so3_log(T[..., :3, :3])
    eye = torch.eye(3, dtype=T.dtype)
    cols = [
        torch.linalg.matrix_exp(se3_hat(torch.cat((eye[i].expand_as(phi), phi), dim=-1)))[
            ..., :3, 3
        ]
        for i in range(3)
    ]
    V = torch.stack(cols, dim=-1)
    rho = torch.linalg.solve(V, T[..., :3, 3:])[..., 0]
    return torch.cat((rho, phi), dim=-1)


def so2_hat(t: Tensor) -> Tensor:
    o = torch.zeros_like(t)
    return torch.cat((o, -t, t, o), dim=-1).unflatten(-1, (2, 2))


def se2_hat(xi: Tensor) -> Tensor:
    """3x3 Lie-algebra matrix ``[[hat(theta), rho], [0, 0]]`` of a twist ``(rho, theta)``."""
    top = torch.cat((so2_hat(xi[..., 2:]), xi[..., :2, None]), dim=-1)
    return torch.cat((top, torch.zeros_like(top[..., :1, :])), dim=-2)


def _ref_so2_log(R: Tensor) -> Tensor:
    return torch.atan2(R[..., 1, 0], R[..., 0, 0])[..., None]


def _ref_se2_log(T: Tensor) -> Tensor:
    # theta from atan2; rho = V(theta)^-1 t, V's columns read off exp of the twists (e_i, theta).
    theta = _ref_so2_log(T[..., :2, :2])
    eye = torch.eye(2, dtype=T.dtype)
    cols = [
        torch.linalg.matrix_exp(
            se2_hat(torch.cat((eye[i].expand(*theta.shape[:-1], 2), theta), -1))
        )[..., :2, 2]
        for i in range(2)
    ]
    rho = torch.linalg.solve(torch.stack(cols, dim=-1), T[..., :2, 2:])[..., 0]
    return torch.cat((rho, theta), dim=-1)


def sim3_hat(xi: Tensor) -> Tensor:
    """4x4 Lie-algebra matrix ``[[hat(phi) + sigma I, rho], [0, 0]]``."""
    eye = torch.diag(torch.tensor([1.0, 1.0, 1.0, 0.0], dtype=xi.dtype))
    return se3_hat(xi[..., :6]) + xi[..., 6, None, None] * eye


def _ref_sim3_log(T: Tensor) -> Tensor:
    # s from the determinant, phi from scipy, rho = V^-1 t with V's columns read off exp of
    # (e_i, phi, sigma).
    s = torch.linalg.det(T[..., :3, :3]).pow(1.0 / 3.0)
    phi = _ref_so3_log(T[..., :3, :3] / s[..., None, None])
    sigma = torch.log(s).unsqueeze(-1)
    eye = torch.eye(3, dtype=T.dtype)
    cols = [
        torch.linalg.matrix_exp(sim3_hat(torch.cat((eye[i].expand_as(phi), phi, sigma), -1)))[
            ..., :3, 3
        ]
        for i in range(3)
    ]
    rho = torch.linalg.solve(torch.stack(cols, dim=-1), T[..., :3, 3:])[..., 0]
    return torch.cat((rho, phi, sigma), dim=-1)


# ----------------------------------------------------------------------------------------------
# The ops
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Op:
    name: str
    label: str
    target: str
    make: Callable[[int, torch.Generator], tuple[Tensor, ...]]
    reference: Callable[..., Tensor]
    out_numbers: int
    compare: str = "value"

    def inputs(
        self, n: int, dtype: torch.dtype, gen: torch.Generator | None = None
    ) -> tuple[Tensor, ...]:
        """``n`` elements in torchlie's conventions, contiguous, in ``dtype``."""
        gen = gen if gen is not None else torch.Generator().manual_seed(0)
        return tuple(x.to(dtype).contiguous() for x in self.make(n, gen))

    def in_numbers(self) -> int:
        """Numbers per element of all inputs together."""
        return sum(x[0].numel() for x in self.make(1, torch.Generator().manual_seed(0)))

    def torchlie(self) -> Callable[..., Tensor] | None:
        """torchlie's function, or ``None`` when it does not exist (yet)."""
        module, _, fn = self.target.rpartition(".")
        try:
            mod = importlib.import_module("torchlie." + module)
        except ImportError:
            return None
        return getattr(mod, fn, None)


OPS: dict[str, Op] = {
    op.name: op
    for op in (
        Op(
            "so3.exp",
            "SO(3) exp: rotvec -> matrix",
            "so3.exp",
            lambda n, g: (rotvecs(n, g),),
            lambda w: torch.linalg.matrix_exp(hat(w)),
            9,
        ),
        Op(
            "so3.log",
            "SO(3) log: matrix -> rotvec",
            "so3.log",
            lambda n, g: (rotmats(n, g),),
            _ref_so3_log,
            3,
        ),
        Op(
            "quat.to_matrix",
            "quaternion -> matrix",
            "quaternion.to_matrix",
            lambda n, g: (quaternions(n, g),),
            quat_to_matrix,
            9,
        ),
        Op(
            "quat.from_matrix",
            "matrix -> quaternion",
            "quaternion.from_matrix",
            lambda n, g: (rotmats(n, g),),
            _ref_from_matrix,
            4,
            compare="quat",
        ),
        Op(
            "quat.multiply",
            "quaternion multiply",
            "quaternion.multiply",
            lambda n, g: (quaternions(n, g), quaternions(n, g)),
            _ref_multiply,
            4,
            compare="quat",
        ),
        Op(
            "quat.apply",
            "quaternion apply (rotate points)",
            "quaternion.apply",
            lambda n, g: (quaternions(n, g), points(n, g)),
            _ref_quat_apply,
            3,
        ),
        Op(
            "so3.act",
            "matrix apply (rotate points)",
            "so3.act",
            lambda n, g: (rotmats(n, g), points(n, g)),
            lambda R, p: (R @ p.unsqueeze(-1)).squeeze(-1),
            3,
        ),
        Op(
            "se3.exp",
            "SE(3) exp: twist -> pose",
            "se3.exp",
            lambda n, g: (twists(n, g),),
            lambda xi: torch.linalg.matrix_exp(se3_hat(xi)),
            16,
        ),
        Op(
            "se3.log",
            "SE(3) log: pose -> twist",
            "se3.log",
            lambda n, g: (poses(n, g),),
            _ref_se3_log,
            6,
        ),
        Op(
            "se3.compose",
            "SE(3) compose",
            "se3.compose",
            lambda n, g: (poses(n, g), poses(n, g)),
            lambda T1, T2: T1 @ T2,
            16,
        ),
        Op(
            "se3.inverse",
            "SE(3) inverse",
            "se3.inverse",
            lambda n, g: (poses(n, g),),
            torch.linalg.inv,
            16,
        ),
        Op(
            "se3.act",
            "SE(3) act (transform points)",
            "se3.act",
            lambda n, g: (poses(n, g), points(n, g)),
            lambda T, p: (T[..., :3, :3] @ p.unsqueeze(-1)).squeeze(-1) + T[..., :3, 3],
            3,
        ),
        Op(
            "so2.exp",
            "SO(2) exp: angle -> matrix",
            "so2.exp",
            lambda n, g: (angles(n, g),),
            lambda t: torch.linalg.matrix_exp(so2_hat(t)),
            4,
        ),
        Op(
            "so2.log",
            "SO(2) log: matrix -> angle",
            "so2.log",
            lambda n, g: (rot2(angles(n, g)),),
            _ref_so2_log,
            1,
        ),
        Op(
            "se2.exp",
            "SE(2) exp: twist -> pose",
            "se2.exp",
            lambda n, g: (planar_twists(n, g),),
            lambda xi: torch.linalg.matrix_exp(se2_hat(xi)),
            9,
        ),
        Op(
            "se2.log",
            "SE(2) log: pose -> twist",
            "se2.log",
            lambda n, g: (planar_poses(n, g),),
            _ref_se2_log,
            3,
        ),
        Op(
            "sim3.exp",
            "Sim(3) exp: tangent -> similarity",
            "sim3.exp",
            lambda n, g: (sim3_tangents(n, g),),
            lambda xi: torch.linalg.matrix_exp(sim3_hat(xi)),
            16,
        ),
        Op(
            "sim3.log",
            "Sim(3) log: similarity -> tangent",
            "sim3.log",
            lambda n, g: (similarities(n, g),),
            _ref_sim3_log,
            7,
        ),
    )
}


def close(a: Tensor, b: Tensor, compare: str) -> Tensor:
    """Largest elementwise difference of two outputs (up to sign per quaternion for ``quat``)."""
    a = a.detach().to(torch.float64)
    b = b.detach().to(torch.float64)
    if a.shape != b.shape:
        raise ValueError(f"output shapes differ: {tuple(a.shape)} vs {tuple(b.shape)}")
    d = (a - b).abs()
    if compare == "quat":
        d = torch.minimum(d.amax(-1), (a + b).abs().amax(-1))
    return d.max()
