"""Samplers that hit the hard cases: exactly 0, tiny angles, exactly pi, just below pi.

Use these in every property test so that each group and conversion is exercised at the same
singular points.
"""

from __future__ import annotations

import math

import torch

PI = math.pi


def eps(dtype: torch.dtype) -> float:
    """Machine epsilon of ``dtype`` (tolerances are stated in multiples of it)."""
    return torch.finfo(dtype).eps


def unit(v) -> torch.Tensor:
    """``v`` as a float64 unit vector."""
    v = torch.as_tensor(v, dtype=torch.float64)
    return v / v.norm()


#: The angle sweep of the numerical specification.
ANGLES = [
    0.0, 1e-12, 1e-8, 1e-6, 1e-4, 1e-2, 1.0, 3.0,
    PI - 1e-2, PI - 1e-4, PI - 1e-6, PI - 1e-8, PI,
]  # fmt: skip

#: Angles at which gradcheck / gradgradcheck run.
GRAD_ANGLES = [1e-8, 1.0, PI - 1e-6]

#: Angles at which the tangent-coordinate gradient is checked (DESIGN.md section 5).
TANGENT_ANGLES = [0.0, 1e-12, 1e-8, 1e-4, 1.0, PI - 1e-3, PI - 1e-6, PI - 1e-9, PI]


def axes(n_random: int = 200, seed: int = 0, dtype=torch.float64) -> torch.Tensor:
    """Unit axes: coordinate axes (both signs), diagonals, near-diagonals and random ones."""
    fixed = []
    for i in range(3):
        for s in (1.0, -1.0):
            e = [0.0, 0.0, 0.0]
            e[i] = s
            fixed.append(e)
    for sx in (1.0, -1.0):
        for sy in (1.0, -1.0):
            for sz in (1.0, -1.0):
                fixed.append([sx, sy, sz])
    near = [[1.0, 1.0, 1.0 + 1e-7], [1.0, 1.0 - 1e-9, 1.0], [1.0, 1e-9, 0.0], [1e-12, 0.0, 1.0]]
    fixed += near
    g = torch.Generator().manual_seed(seed)
    rnd = torch.randn(n_random, 3, generator=g, dtype=torch.float64)
    a = torch.cat((torch.tensor(fixed, dtype=torch.float64), rnd))
    return (a / a.norm(dim=-1, keepdim=True)).to(dtype)


def rotvecs(angles=ANGLES, n_random: int = 200, seed: int = 0, dtype=torch.float64):
    """All combinations angle x axis, shape ``(len(angles) * n_axes, 3)``, plus the angles."""
    ax = axes(n_random, seed, torch.float64)
    th = torch.tensor(angles, dtype=torch.float64)
    w = (th[:, None, None] * ax[None]).reshape(-1, 3)
    return w.to(dtype), th.repeat_interleave(ax.shape[0]).to(dtype)


def haar_quaternions(n: int, seed: int = 0, dtype=torch.float64) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    q = torch.randn(n, 4, generator=g, dtype=torch.float64)
    return (q / q.norm(dim=-1, keepdim=True)).to(dtype)


def hard_quaternions(dtype=torch.float64) -> torch.Tensor:
    """Unit quaternions at the hard points: identity, +-pi about axes (w = 0), tiny angles,
    antipodal pairs (q and -q), and w slightly negative."""
    w, _ = rotvecs(ANGLES, n_random=8)
    h = 0.5 * w.norm(dim=-1, keepdim=True)
    n = torch.nn.functional.normalize(w, dim=-1)
    q = torch.cat((torch.cos(h), torch.sin(h) * n), dim=-1)
    q = torch.cat((q, -q))
    return q.to(dtype)
