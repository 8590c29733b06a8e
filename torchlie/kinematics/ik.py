"""Batched inverse kinematics: damped least squares (Levenberg-Marquardt) with implicit gradients.

:func:`inverse_kinematics` (also :meth:`Chain.inverse_kinematics
<torchlie.kinematics.Chain.inverse_kinematics>`) finds joint values ``q`` that put one or several
links at target poses ``(..., 4, 4)`` or positions ``(..., 3)``.

The problem, per target and start
---------------------------------
Minimise ``1/2 sum_links |W^1/2 r_link(q)|^2`` over ``q`` within the joint limits, with

* a pose target ``T*``: ``r = Log(T*^-1 T(q))`` (:func:`torchlie.se3.log`, translation first),
  whose derivative is exactly ``Jr(r)^-1 J_link(q)``: the link-frame (body) Jacobian of
  :meth:`~torchlie.kinematics.Chain.jacobian` (``T(q + dq) ~= T(q) Exp(J_link dq)``) through
  se3's right Jacobian inverse; ``r`` is ``-Log(T(q)^-1 T*)``, the right-perturbation error;
* a position target ``p*``: ``r = p(q) - p*`` in world coordinates, derivative the linear rows
  of the world Jacobian;
* ``W`` = ``position_weight`` on the three translation rows, ``rotation_weight`` on the three
  rotation rows.

Solver
------
Levenberg-Marquardt: the step solves ``(A^T A + mu I) dq = -A^T b`` (``A = W^1/2 dr/dq``,
``b = W^1/2 r``; in the dual form ``dq = -A^T (A A^T + mu I)^-1 b`` when there are fewer
residual rows than joints), ``mu = lambda * mean(diag)``; a step that lowers the cost is taken
and ``lambda`` shrinks, otherwise it is refused and ``lambda`` grows.  Each step is one batched
forward-kinematics-and-Jacobian pass for every link at once
(:meth:`Chain.poses_and_jacobians`, :meth:`Chain.jacobian`'s closed form); the residual is
:func:`torchlie.se3.log` and the small linear systems are solved by one batched
:func:`torch.linalg.solve_ex`.  The steps take ``Jr(r)^-1`` as the identity (exact at a
solution, where ``r = 0``): with both the residual and the Jacobian rotated into the world
frame (``diag(R, R)``, which leaves the step unchanged), ``A`` is then the chain's world
Jacobian as it comes, which saves most of the work per step besides forward kinematics; on
the bundled robots the starts
converge as often and as fast as with the exact derivative.  Whether a step is taken is decided
by the exact cost.

Joint limits are kept by projection with an active set: a joint resting on a limit that the
cost's gradient pushes outwards is left out of the step (its column of ``A`` is zeroed), as is
one that the previous step pushed outwards (the clamp then spoiled that step, which a
Gauss-Newton step can do while the gradient points inwards), and each trial point is clamped
into ``[lower, upper]`` before it is evaluated, so every iterate and the answer are within the
limits.  On the bundled Panda, starts converge more often this way than with clamping alone,
and as often as with the bounded reparametrisation ``q = mid + half sin(u)`` (whose derivative
vanishes at the limits) from one start, more often with restarts.  Coordinates without
limits (continuous joints, planar and floating coordinates) are unbounded; a floating joint's
rotation vector is wrapped back to an angle of at most pi after each step (same pose).  Mimic
joints follow their joint (their own ``<limit>`` is not enforced: the DoF they follow is what
is bounded).

Batching and restarts: targets of any batch shape ``(...)``; ``restarts = K`` solves ``K``
starts per target side by side in one batch of ``N = P K`` columns (the first start from
``q0`` when given, the others uniform within the limits like
:meth:`Chain.random_configuration`, from ``generator``).  Every ``restart_after + 1``
iterations (a fixed schedule) the columns take new uniform starts, except the one with the
best point of each target (it goes on: a solved target's keeps refining, an unreachable
target's keeps improving; a target's only column restarts when it is not within the
tolerances).  The new starts are dealt round-robin to the targets that no column has solved
yet, so a hard target gets the columns of the solved ones: most starts that converge do so
within a few iterations, and one stuck against the limits or in a local minimum rarely does.
Per target the result is a point within tolerance if any start reached one (the lowest cost
among those), else the lowest cost.

The iteration count is fixed (``max_iterations``) and nothing in the loop reads a tensor value
on the host, so it runs under ``torch.compile`` and on CUDA without synchronising.  With
``early_exit=True`` (eager use) the columns of solved targets leave the batch (each time they
are half of it; at least ``4 K`` columns per unsolved target stay, for the next restarts) and
the loop stops when every target is solved, which costs one synchronisation per iteration and
saves most of the work when a few targets are hard.

Gradients
---------
The iterations run without autograd.  The answer is then differentiable with respect to the
targets by the implicit-function theorem: at a solution ``A^T b = 0``, so
``dq*/dtheta = -(A^T A)^+ A^T db/dtheta`` (the minimum-norm solution when the robot is
redundant), attached as ``q* + s - s.detach()`` with ``s`` the (tiny-damped) Gauss-Newton step
of the residual computed with ``q*`` held fixed and only the targets carrying a graph.  A second
such step, from that point with the graph through the joint values too, adds the second
derivatives (the Gauss-Newton map does not move to first order at a zero residual): where the
solution is a function of the targets (isolated solutions, no redundancy), Hessians and other
second derivatives are those of the solution, not of its first-order approximation.  Reverse
mode, forward mode (:func:`torch.func.jvp`, :mod:`torch.autograd.forward_ad`;
:func:`torch.func.jacfwd` with ``randomness="same"`` where starts are drawn) and their
compositions all see them.  Joints resting on a limit get zero gradient (they stay there for
small changes).  Away from a zero residual (an unreachable target) this is the Gauss-Newton
approximation of the derivative.  A target whose step is not finite (a non-finite target, or
one so far that the step overflows: beyond about ``1e154`` m in float64) gets a zero
derivative, and its ``q`` stays as found.

Under :func:`torch.func.vmap` the solver runs as it is (without ``early_exit``, which reads
values); random starts (``restarts > 1`` or restarts during the iterations, or no ``q0``)
need ``randomness="same"`` or ``"different"``.

Example:
    >>> import torch
    >>> from torchlie.kinematics import Chain, sample_robot
    >>> arm = Chain.from_urdf(sample_robot("arm7"), dtype=torch.float64)
    >>> g = torch.Generator().manual_seed(0)
    >>> T = arm.forward_kinematics(arm.random_configuration(5, generator=g), "tool_tcp")
    >>> res = arm.inverse_kinematics(T["tool_tcp"], "tool_tcp", restarts=4, generator=g)
    >>> res.q.shape, bool(res.converged.all()), bool((res.position_error < 1e-6).all())
    (torch.Size([5, 7]), True, True)
"""

from __future__ import annotations

import math
import reprlib
from collections.abc import Mapping, Sequence
from typing import NamedTuple, Protocol, runtime_checkable

import torch
import torch.autograd.forward_ad as _fwad
from torch import Tensor

from .. import _checks, _coeffs, _layout
from .. import se3 as _se3
from .. import so3 as _so3
from ._joints import _uniform_within

__all__ = ["IKResult", "SolverChain", "inverse_kinematics"]

_FN = "torchlie.kinematics.Chain.inverse_kinematics"

# Levenberg-Marquardt schedule: lambda (relative to the mean diagonal of the normal matrix).
_LAMBDA0 = 1e-2
_LAMBDA_DOWN = 0.25
_LAMBDA_UP = 4.0
_LAMBDA_MIN = 1e-9
_LAMBDA_MAX = 1e9
# With early exit, columns kept per unsolved target, in units of `restarts` (the surplus ones
# take unsolved targets at the next restart).
_SPARE = 4
# Default iteration budget with fewer / at least _MANY_STARTS starts per target: with several
# starts, those of solved targets restart for the unsolved ones, so fewer iterations reach the
# same success (bundled robots and the Panda: 8 starts, 24 iterations solve every target; one
# start needs 40 to solve as many as before the restarts were shared).
_MANY_STARTS = 4
_BUDGET = (40, 24)


class IKResult(NamedTuple):
    """Result of :func:`inverse_kinematics`; ``(...)`` is the targets' batch shape.

    Attributes:
        q: ``(..., n_dof)`` joint values, within the limits; differentiable with respect to the
            targets (implicit function theorem, see the module docstring).
        position_error: ``(...)`` largest distance, in m, between a link's position and its
            target over the links asked for (detached).
        rotation_error: ``(...)`` largest rotation angle, in rad, between a link's orientation
            and its target pose's (``0`` for position-only targets; detached).
        converged: ``(...)`` bool, both errors within their tolerances.
        iterations: ``(...)`` int64, the iterations before a start came within the
            tolerances (``max_iterations`` when none did).
    """

    q: Tensor
    position_error: Tensor
    rotation_error: Tensor
    converged: Tensor
    iterations: Tensor


@runtime_checkable
class SolverChain(Protocol):
    """What the solver uses of a robot: :class:`~torchlie.kinematics.Chain` provides it, and
    the solver touches nothing else of it.

    Attributes:
        dtype, device: of the chain's constants (the targets, ``q0`` and bounds must match).
        n_dof, n_v: joint values and velocity coordinates (the solver steps the values, so it
            needs ``n_v == n_dof``: no quaternion joints).
        joint_names: the DoFs' names (for messages).
        dof_joints: per DoF ``(joint, joint type, coordinate)`` (:attr:`Chain.dof_joints
            <torchlie.kinematics.Chain.dof_joints>`): a floating joint's rotation vector is the
            DoFs of coordinates ``rx, ry, rz`` of a ``"floating"`` joint.
        link_names: the links targets may name.
        lower, upper: ``(n_dof,)`` limits (``-inf``/``inf`` where there are none).
    """

    dtype: torch.dtype
    device: torch.device
    n_dof: int
    n_v: int
    joint_names: tuple[str, ...]
    dof_joints: tuple[tuple[str, str, str], ...]
    link_names: tuple[str, ...]
    lower: Tensor
    upper: Tensor

    def poses_and_jacobians(
        self, q_t: Tensor, links: Sequence[str], dofs: Sequence[int] | None = None
    ) -> tuple[list[Tensor], list[Tensor]]:
        """Per link, the transposed pose ``(4, 4, B)`` and the world Jacobian ``(k, 6, B)``
        (only the columns of ``dofs``) at ``q_t (n_dof, B)``, from one pass
        (:meth:`Chain.poses_and_jacobians <torchlie.kinematics.Chain.poses_and_jacobians>`)."""
        ...

    def moving_dofs(self, links: Sequence[str]) -> tuple[int, ...]:
        """The sorted DoFs that move at least one of ``links``."""
        ...

    def sampling_bounds(
        self, lower: Tensor | None = None, upper: Tensor | None = None
    ) -> tuple[Tensor, Tensor]:
        """float64 CPU ``(lo, hi)`` of uniform starts, within the limits or the given bounds
        (:meth:`Chain.sampling_bounds <torchlie.kinematics.Chain.sampling_bounds>`)."""
        ...


class _Dofs(NamedTuple):
    """The DoFs solved for (those that move a target link), when not all of them."""

    ids: tuple[int, ...]  # sorted
    index: Tensor  # the same, a long tensor on the chain's device
    gathers: tuple[Tensor, ...]  # their rows among all DoFs (torchlie._layout.add_rows)


class _Task(NamedTuple):
    link: str
    pose: bool  # pose target (else a position)
    target: Tensor  # batch innermost: (4, 4, N) T*^-1, or (3, N) p*
    # a pose target's own translation p* (3, N), for the position error |p - p*| (the
    # translation of T*^-1 T has that norm only where T*'s rotation block is a rotation)
    position: Tensor | None = None


# ----------------------------------------------------------------------------------------------
# Argument checks (metadata only, except explicit limits: see _limits)
# ----------------------------------------------------------------------------------------------


def _tensor(chain: SolverChain, x: object, name: str) -> Tensor:
    """``x``, checked to be a tensor of the chain's dtype on its device."""
    if not isinstance(x, Tensor):
        raise TypeError(f"{_FN}: expected {name} to be a torch.Tensor, got {type(x).__name__}")
    if x.dtype != chain.dtype:
        raise TypeError(
            f"{_FN}: {name} has dtype {x.dtype} but the chain's constants are {chain.dtype}; "
            "convert one of them (chain.to(dtype=...))"
        )
    if x.device != chain.device:
        raise ValueError(
            f"{_FN}: {name} is on {x.device} but the chain is on {chain.device}; use "
            "chain.to(device=...)"
        )
    return x


def _targets(chain: SolverChain, targets: object, link: object) -> list[tuple[str, bool, Tensor]]:
    """``[(link name, is pose, tensor)]`` from ``targets`` and ``link``."""
    if isinstance(targets, Mapping):
        if link is not None:
            raise TypeError(
                f"{_FN}: targets is a dict link -> targets, so link must be None, got "
                f"{reprlib.repr(link)}"
            )
        items = list(targets.items())
        if not items:
            raise ValueError(f"{_FN}: targets is an empty dict; give at least one link")
    else:
        if not isinstance(link, str):
            raise TypeError(
                f"{_FN}: expected link to be a link name (str) when targets is a tensor (or "
                f"targets to be a dict link -> targets), got {type(link).__name__} "
                f"{reprlib.repr(link)}"
            )
        items = [(link, targets)]
    out = []
    for name, t in items:
        if not isinstance(name, str):
            raise TypeError(
                f"{_FN}: expected the keys of targets to be link names (str), got "
                f"{type(name).__name__} {reprlib.repr(name)}"
            )
        if name not in chain.link_names:
            raise ValueError(
                f"{_FN}: unknown link {name!r} (the links are {reprlib.repr(chain.link_names)})"
            )
        what = f"targets[{name!r}]" if isinstance(targets, Mapping) else "targets"
        t = _tensor(chain, t, what)
        shape = tuple(t.shape)
        if shape[-2:] == (4, 4):
            out.append((name, True, t))
        elif shape[-1:] == (3,):
            out.append((name, False, t))
        else:
            raise ValueError(
                f"{_FN}: expected {what} to be poses of shape (..., 4, 4) or positions of "
                f"shape (..., 3), got shape {shape}"
            )
    return out


def _limits(chain: SolverChain, lower: object, upper: object) -> tuple[Tensor, Tensor]:
    """The bounds ``(n_dof,)``: the chain's, or the ones given (broadcast to ``(n_dof,)``).

    Bounds given explicitly are checked for ``lower <= upper`` (one synchronisation, skipped
    while compiling); the chain's were checked when the URDF was parsed.
    """
    lo, hi = chain.lower, chain.upper
    given = []
    for name, v, default in (("lower", lower, lo), ("upper", upper, hi)):
        if v is None:
            given.append(default)
            continue
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            v = torch.full((chain.n_dof,), float(v), dtype=chain.dtype, device=chain.device)
        elif not isinstance(v, Tensor):
            raise TypeError(
                f"{_FN}: expected {name} to be a number or a torch.Tensor of shape () or "
                f"({chain.n_dof},), got {type(v).__name__} {reprlib.repr(v)}"
            )
        v = _tensor(chain, v, name)
        if v.dim() > 1 or (v.dim() == 1 and v.shape[0] not in (1, chain.n_dof)):
            raise ValueError(
                f"{_FN}: expected {name} to be a number or a tensor of shape () or "
                f"({chain.n_dof},) (one bound per DoF), got shape {tuple(v.shape)}"
            )
        given.append(v.expand(chain.n_dof))
    lo, hi = given
    if (lower is not None or upper is not None) and not torch.compiler.is_compiling():
        bad = (lo > hi) | torch.isnan(lo) | torch.isnan(hi)
        if bool(bad.any()):
            k = int(bad.nonzero()[0, 0])
            for name, v in (("lower", lo), ("upper", hi)):
                if math.isnan(float(v[k])):
                    raise ValueError(
                        f"{_FN}: expected {name} to be a bound or -inf/inf for every DoF (not "
                        f"NaN), got {name}=nan for {chain.joint_names[k]!r} (DoF {k})"
                    )
            raise ValueError(
                f"{_FN}: expected lower <= upper for every DoF, got lower={float(lo[k])!r} > "
                f"upper={float(hi[k])!r} for {chain.joint_names[k]!r} (DoF {k})"
            )
    return lo, hi


# ----------------------------------------------------------------------------------------------
# Numerical core.  Everything is batch innermost: a problem's vector of length k is (k, N), a
# matrix (k, l, N), so the many tiny per-problem operations are a few long vector operations.
# ----------------------------------------------------------------------------------------------


def _norm3(v: Tensor) -> Tensor:
    """Norm of ``(3, N)`` columns, by :func:`torch.hypot` (no overflow of the squares of
    far targets' errors; a reduction over a leading dimension of 3 costs more)."""
    x, y, z = v.unbind(0)
    return torch.hypot(torch.hypot(x, y), z)


def _errors(perr: list[Tensor], rerr: list[Tensor]) -> tuple[Tensor, Tensor]:
    """The worst position and rotation errors over the tasks (rotation 0 without poses)."""
    p = torch.stack(perr).amax(0) if len(perr) > 1 else perr[0]
    if not rerr:
        return p, torch.zeros_like(p)
    return p, torch.stack(rerr).amax(0) if len(rerr) > 1 else rerr[0]


def _columns(task: _Task, cols: Tensor) -> _Task:
    """``task`` at the columns ``cols`` of its targets (batch innermost)."""
    p = task.position
    return task._replace(
        target=task.target.index_select(-1, cols),
        position=None if p is None else p.index_select(-1, cols),
    )


def _log_error(P: Tensor, Ti: Tensor) -> Tensor:
    """``r = Log(T*^-1 T)`` ``(6, N)`` (:func:`torchlie.se3.log`) from the transposed pose
    ``P (4, 4, N)`` of ``T`` and ``Ti (4, 4, N)`` = ``T*^-1``.

    ``T*^-1 T`` is formed batch last, four fused multiply-adds over the batch (faster than a
    batched product of 4x4 matrices).
    """
    E = Ti[:, None, 0] * P[None, :, 0]  # [r, c, N]
    for k in (1, 2, 3):
        E = torch.addcmul(E, Ti[:, None, k], P[None, :, k])
    return _se3.log(E.permute(2, 0, 1)).mT


def _residuals(
    chain: SolverChain, q: Tensor, tasks: list[_Task], weights: Tensor, dofs: _Dofs | None
) -> tuple[Tensor, Tensor]:
    """Weighted residuals ``b (m, N)`` and their exact Jacobian ``A (m, k, N)`` with respect to
    the DoFs ``dofs`` (``k`` of them; all if None) at ``q (n_dof, N)``: the link-frame
    residuals of the module docstring (used for the implicit gradients)."""
    links = tuple(t.link for t in tasks)
    poses, jacs = chain.poses_and_jacobians(q, links, None if dofs is None else dofs.ids)
    rs, As = [], []
    for task, P, J in zip(tasks, poses, jacs, strict=True):
        # P (4, 4, N) with P[c, r] = T[r, c]; J (k, 6, N) in world coordinates.
        if task.pose:
            r = _log_error(P, task.target)
            # The derivative of the log: Jr(r)^-1 times the link-frame Jacobian diag(R, R)^T J.
            Rt = P[:3, :3].permute(2, 0, 1)  # R^T
            Jw = J.permute(2, 1, 0)  # (N, 6, k)
            J_link = torch.cat((Rt @ Jw[:, :3], Rt @ Jw[:, 3:]), 1)
            As.append((_se3.jac_right_inv(r.mT) @ J_link).permute(1, 2, 0))
            rs.append(r)
        else:
            rs.append(P[3, :3] - task.target)
            As.append(J[:, :3].transpose(0, 1))
    b = (torch.cat(rs) if len(rs) > 1 else rs[0]) * weights.unsqueeze(-1)
    A = (torch.cat(As) if len(As) > 1 else As[0]) * weights.view(-1, 1, 1)
    return b, A


def _linearise(
    chain: SolverChain,
    q: Tensor,
    tasks: list[_Task],
    weights: Tensor | None,
    dofs: _Dofs | None,
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """What one solver iteration needs at ``q (n_dof, N)``: the residuals rotated into the world
    frame ``b (m, N)`` (weighted; the same norm as :func:`_residuals`'), their Jacobian
    ``A (k, m, N)`` (DoF first) with ``Jr(r)^-1`` taken as the identity, which is the world
    Jacobian of the chain as it is, and the position and rotation errors ``(N,)``.

    With ``Rot = diag(R, R)`` (``R`` the link's rotation) the link-frame linearisation
    ``r + Jr(r)^-1 Rot^T J dq`` has the norm of ``Rot r + Rot Jr(r)^-1 Rot^T J dq``, and
    ``Jr(r)^-1 = I + O(|r|)``: at a solution the two agree, and away from one the cost that
    decides whether a step is taken is still the exact one.
    """
    links = tuple(t.link for t in tasks)
    poses, jacs = chain.poses_and_jacobians(q, links, None if dofs is None else dofs.ids)
    rs, As, perr, rerr = [], [], [], []
    for task, P, J in zip(tasks, poses, jacs, strict=True):
        if task.pose:
            r = _log_error(P, task.target)  # (rho, phi) in the link frame
            perr.append(_norm3(P[3, :3] - task.position))
            rerr.append(_norm3(r[3:]))
            r = (P[:3, :3] * r.view(2, 3, 1, -1)).sum(1).view(6, -1)  # R rho, R phi
        else:
            r = P[3, :3] - task.target
            J = J[:, :3]
            perr.append(_norm3(r))
        rs.append(r)
        As.append(J)
    b = torch.cat(rs) if len(rs) > 1 else rs[0]
    A = torch.cat(As, 1) if len(As) > 1 else As[0]
    if weights is not None:
        b, A = b * weights.unsqueeze(-1), A * weights.unsqueeze(-1)
    return b, A, *_errors(perr, rerr)


def _spd_solve(S: Tensor, y: Tensor) -> Tensor:
    """``S^-1 y`` ``(k, N)`` for symmetric positive definite ``S (k, k, N)`` and ``y (k, N)``,
    batch last, by :func:`torch.linalg.solve_ex` (no error check, which would read a device
    value: a system that rounding makes singular gives non-finite values, and the step that
    uses them is refused by the cost test)."""
    x, _ = torch.linalg.solve_ex(S.permute(2, 0, 1), y.mT)
    return x.mT


def _gram(X: Tensor) -> Tensor:
    """``S[i, j] = sum_l X[l, i] X[l, j]``, ``(c, c, N)``, for ``X (l, c, N)``."""
    S = X[0].unsqueeze(1) * X[0].unsqueeze(0)
    for row in X[1:]:
        S = torch.addcmul(S, row.unsqueeze(1), row.unsqueeze(0))
    return S


def _step(A: Tensor, b: Tensor, lam: Tensor, g: Tensor | None = None) -> Tensor:
    """``dq = (A^T A + mu I)^-1 A^T b`` ``(k, N)`` (the descent step is ``-dq``) for
    ``A (k, m, N)`` (DoF first) and ``b (m, N)``, ``mu = lam mean(diag)`` plus a floor of a few
    ulp; through the ``m x m`` dual system ``dq = A^T (A A^T + mu I)^-1 b`` when ``m <= k``.
    ``g``: ``A^T b`` when the caller has it."""
    k, m = A.shape[:2]
    if k == 0:  # no DoF to step (A^T b, empty: a target link no DoF moves)
        return (A * b.unsqueeze(0)).sum(1)
    dual = m <= k
    S = _gram(A if dual else A.transpose(0, 1))
    diag = torch.diagonal(S)  # (N, k or m), a view: mu is added in place (in the solver loop)
    eps = torch.finfo(A.dtype).eps
    mu = lam * diag.mean(-1) + eps * (1.0 + diag.amax(-1))
    if torch.is_grad_enabled():  # (the implicit steps: S has a graph)
        S = S + torch.diag_embed(mu.unsqueeze(-1).expand_as(diag)).permute(1, 2, 0)
    else:
        diag.add_(mu.unsqueeze(-1))
    if dual:
        return (A * _spd_solve(S, b).unsqueeze(0)).sum(1)
    return _spd_solve(S, (A * b.unsqueeze(0)).sum(1) if g is None else g)


def _wrap_rotvecs(q: Tensor, rot: list[int]) -> Tensor:
    """Rotation vectors of floating joints (DoFs ``rot[k]:rot[k]+3`` of ``q (n, N)``) back to
    angles of at most pi (the same rotations)."""
    if not rot:
        return q
    parts = []
    start = 0
    for d in rot:
        parts.append(q[start:d])
        parts.append(_so3.log(_so3.exp(q[d : d + 3].mT)).mT)
        start = d + 3
    parts.append(q[start:])
    return torch.cat(parts)


def _clamp(q: Tensor, lo: Tensor, hi: Tensor) -> Tensor:
    return torch.minimum(torch.maximum(q, lo), hi)


def _starts(
    chain: SolverChain,
    bounds: tuple[Tensor, Tensor] | None,
    shape: tuple[int, ...],
    generator: torch.Generator | None,
) -> Tensor:
    """Uniform draws ``(*shape, n_dof)`` within the chain's limits, or within ``bounds`` (given
    bounds, already on the host), with the free ranges of :meth:`Chain.random_configuration`
    where a bound is infinite (:meth:`SolverChain.sampling_bounds`); drawn on the CPU in
    float64 (no device value is read)."""
    slo, shi = chain.sampling_bounds() if bounds is None else chain.sampling_bounds(*bounds)
    u = torch.rand(*shape, chain.n_dof, generator=generator, dtype=torch.float64)
    return _uniform_within(slo, shi, u).to(dtype=chain.dtype, device=chain.device)


@_checks.float32_exact
def inverse_kinematics(
    chain: SolverChain,
    targets: Tensor | Mapping[str, Tensor],
    link: str | None = None,
    *,
    q0: Tensor | None = None,
    restarts: int = 1,
    position_weight: float = 1.0,
    rotation_weight: float = 1.0,
    max_iterations: int | None = None,
    restart_after: int | None = None,
    position_tolerance: float = 1e-4,
    rotation_tolerance: float = 1e-3,
    early_exit: bool = False,
    lower: Tensor | float | None = None,
    upper: Tensor | float | None = None,
    generator: torch.Generator | None = None,
) -> IKResult:
    """Joint values that put ``link`` at ``targets`` (see the module docstring for the method).

    Args:
        chain: the robot: a :class:`~torchlie.kinematics.Chain`, or anything with the
            :class:`SolverChain` interface.
        targets: poses ``(..., 4, 4)`` or positions ``(..., 3)`` of ``link`` in the world (root)
            frame; or a dict link name -> such targets for several links at once (a tree's
            end links), their batch shapes broadcast together.  In the chain's dtype and on its
            device.
        link: the link, when ``targets`` is a tensor (``None`` with a dict).
        q0: initial guess ``(..., n_dof)`` (broadcast with the targets' batch), clamped into
            the limits: the first start of every target.
        restarts: starts solved side by side per target, at least 1; those not from ``q0`` are
            uniform within the limits (drawn on the CPU with ``generator``).
        position_weight, rotation_weight: weights (> 0 and >= 0) of the translation and
            rotation rows of the residual (m against rad); ``rotation_weight=0`` makes pose
            targets position targets (their orientation is neither solved for nor checked).
        max_iterations: Levenberg-Marquardt iterations (each one forward-kinematics and
            Jacobian pass), at least 0; by default 24 with 4 or more starts per target and 40
            with fewer (with several starts the columns of solved targets restart for the
            unsolved ones, so fewer iterations reach the same success).
        restart_after: every ``restart_after + 1`` iterations, starting after
            ``restart_after``, the columns take fresh uniform starts for the targets not solved
            yet, all but the best one of each target (``0``: never; by default a third of
            ``max_iterations``; see the module docstring), so a budget of ``max_iterations``
            tries up to
            ``restarts * (1 + max_iterations // restart_after)`` starts per target on average
            at the cost of ``restarts``, most of them for the hard targets; the best point of
            every target is kept.  Only the DoFs that move a target link are solved for: the
            others keep their start value.
        position_tolerance, rotation_tolerance: thresholds of ``converged`` (m, rad).
        early_exit: stop once every target has a start within tolerance (one device
            synchronisation per iteration; not for ``torch.compile(fullgraph=True)`` nor
            :func:`torch.func.vmap`).
        lower, upper: bounds replacing the chain's limits, ``(n_dof,)`` or a number (``inf``
            for none); checked ``lower <= upper``.
        generator: random generator of the starts.

    Returns:
        :class:`IKResult` ``(q, position_error, rotation_error, converged, iterations)``; an
        unreachable target gives ``converged = False`` and the best ``q`` found (finite).
        When no DoF moves the target links (the root, links fixed to it, a chain without
        DoFs) nothing is solved for: ``q`` is the first start as it is (``q0`` clamped into
        the limits, else a uniform draw), ``converged`` says whether the links already are at
        their targets (``iterations`` 0 then, else ``max_iterations``, as for an unreachable
        target) and the derivative with respect to the targets is zero.

    Raises:
        TypeError, ValueError: a target of the wrong shape, dtype or device, an unknown link,
            ``restarts < 1``, ``lower > upper``, and other bad arguments, with the argument's
            name.
    """
    if chain.n_v != chain.n_dof:  # the steps below add velocities to the values
        quats = sorted({j for j, jtype, _ in chain.dof_joints if jtype in ("ball", "free")})
        raise ValueError(
            f"{_FN}: the chain has ball or free joints ({', '.join(map(repr, quats[:5]))}), "
            "whose quaternion values the solver does not step; it solves for hinge, slide "
            "(revolute, prismatic) and URDF joints"
        )
    items = _targets(chain, targets, link)
    _checks.generator(generator, _FN)
    restarts = _checks.count(restarts, _FN, "restarts", 1)
    if max_iterations is None:
        max_iterations = _BUDGET[restarts >= _MANY_STARTS]
    max_iterations = _checks.count(max_iterations, _FN, "max_iterations", 0)
    early_exit = _checks.flag(early_exit, _FN, "early_exit")
    if restart_after is None:
        restart_after = max(1, max_iterations // 3)
    restart_after = _checks.count(restart_after, _FN, "restart_after", 0) or None  # None: never
    wp = _checks.nonnegative(position_weight, _FN, "position_weight", positive=True)
    wr = _checks.nonnegative(rotation_weight, _FN, "rotation_weight")
    if wr == 0:  # orientations ignored: pose targets are position targets
        items = [(nm, False, t[..., :3, 3]) if pose else (nm, pose, t)
                 for nm, pose, t in items]  # fmt: skip
    tol_p = _checks.nonnegative(position_tolerance, _FN, "position_tolerance")
    tol_r = _checks.nonnegative(rotation_tolerance, _FN, "rotation_tolerance")
    lo, hi = _limits(chain, lower, upper)
    dtype, device, n = chain.dtype, chain.device, chain.n_dof
    shapes = [(t.shape[:-2] if pose else t.shape[:-1], f"targets[{name!r}]")
              for name, pose, t in items]  # fmt: skip
    if q0 is not None:
        q0 = _tensor(chain, q0, "q0")
        _checks.tensor(q0, _FN, "q0", (n,))
        shapes.append((q0.shape[:-1], "q0"))
    batch = _checks.batch_broadcast(_FN, *shapes)
    P, K = math.prod(batch), restarts
    N = P * K  # problem p, start k at column p * K + k
    lo1, hi1 = lo.unsqueeze(-1), hi.unsqueeze(-1)

    # Seeds (S, n, N): seed 0 of every start, then the replacements.
    host = None
    if lower is not None or upper is not None:  # read on the host once (checked above)
        host = (lo.detach().cpu().double(), hi.detach().cpu().double())
    n_seeds = 1 + (max_iterations // restart_after if restart_after else 0)
    if q0 is None:
        draws = _starts(chain, host, (n_seeds, P, K), generator)  # (S, P, K, n)
    else:
        draws = q0.detach().expand(*batch, n).reshape(1, P, 1, n)
        if K > 1 or n_seeds > 1:  # (no random draw otherwise: nothing to trace but q0)
            more = _starts(chain, host, (n_seeds, P, K), generator)
            draws = torch.cat((torch.cat((draws, more[:1, :, 1:]), 2), more[1:]), 0)
    seeds = _clamp(draws.reshape(n_seeds, N, n).mT.contiguous(), lo1, hi1)

    # Tasks: targets broadcast to (P,), batch innermost.
    tasks, raw, weights = [], [], []
    for name, pose, t in items:
        tail = (4, 4) if pose else (3,)
        tb = t.expand(*batch, *tail).reshape(P, *tail)
        raw.append(_Task(name, pose, tb))
        p = tb.detach()[:, :3, 3].mT.contiguous() if pose else None
        tasks.append(_Task(name, pose, _batch_last(tb.detach(), pose).contiguous(), p))
        weights += [wp] * 3 + ([wr] * 3 if pose else [])
    w_sqrt = torch.tensor(weights, dtype=dtype, device=device).sqrt()
    w_loop = None if all(w == 1.0 for w in weights) else w_sqrt
    # Only the DoFs that move a target link are solved for (the others keep their start).
    moving = chain.moving_dofs([name for name, _, _ in items])
    dofs = None
    if moving != tuple(range(n)) or not moving:
        dofs = _Dofs(
            moving,
            torch.tensor(moving, dtype=torch.long, device=device),
            _layout.row_gathers(moving, n, device),
        )

    with torch.no_grad():
        if moving:
            q_best, out = _solve(
                chain, seeds, tasks, w_loop, dofs, lo1, hi1, (P, K), max_iterations,
                restart_after, (tol_p, tol_r), early_exit,
            )  # fmt: skip
        else:  # nothing to solve for: the first start, as it is
            q_best = seeds[0].view(n, P, K)[:, :, 0]
            _, _, perr, rerr = _linearise(chain, q_best, tasks, w_loop, dofs)
            conv = (perr <= tol_p) & (rerr <= tol_r)
            out = [perr, rerr, conv, torch.where(conv, 0, max_iterations)]

    q_out = q_best
    if any(_differentiated(t) for *_, t in items):
        q_out = _implicit_steps(chain, q_best, raw, w_sqrt, dofs, lo1, hi1)
    return IKResult(q_out.mT.reshape(*batch, n), *(x.reshape(batch) for x in out))


def _batch_last(t: Tensor, pose: bool) -> Tensor:
    """A task's target ``(..., P)`` from targets ``(P, 4, 4)`` (as ``T*^-1``) or ``(P, 3)``."""
    ref = _se3.inverse(t) if pose else t
    return ref.reshape(t.shape[0], math.prod(t.shape[1:])).mT.reshape(*t.shape[1:], t.shape[0])


def _differentiated(t: Tensor) -> bool:
    """Whether ``t`` carries a derivative: a reverse-mode graph (grad mode on), a forward-mode
    tangent (:mod:`torch.autograd.forward_ad`, :func:`torch.func.jvp`, whose tensors do not
    require grad)."""
    if torch.is_grad_enabled() and t.requires_grad:
        return True
    return not torch.compiler.is_compiling() and _fwad.unpack_dual(t).tangent is not None


def _solve(
    chain: SolverChain,
    seeds: Tensor,
    tasks: list[_Task],
    weights: Tensor | None,
    dofs: _Dofs | None,
    lo: Tensor,
    hi: Tensor,
    PK: tuple[int, int],
    max_iterations: int,
    restart_after: int | None,
    tols: tuple[float, float],
    early_exit: bool,
) -> tuple[Tensor, list[Tensor]]:
    """The Levenberg-Marquardt loop (call without autograd) on ``N = P K`` starts for ``P``
    targets (``tasks``' targets ``(..., P)``): column ``c`` solves for target ``c // K`` until
    it is restarted; ``seeds (S, n, N)`` are the starts and their replacements.  Returns
    ``q (n, P)`` of the kept point per target and its position error, rotation error,
    convergence flag and the iterations before the target was solved ``(P,)``.

    Restarts follow a fixed schedule: every ``restart_after + 1`` iterations the best point of
    every target is gathered from its columns (a column's own points only improve: a step is
    taken when it lowers the cost and does not leave the tolerances), and every column but the
    one holding it takes its next seed, dealt round-robin to the targets that no column has
    solved yet; a target's only column goes on if it is within tolerance.  With
    ``early_exit``, the columns of solved targets are dropped once they are half of the batch
    (keeping ``_SPARE K`` columns per unsolved target), and the loop ends when every target is
    solved.
    """
    P, K = PK
    tol_p, tol_r = tols
    n_seeds, n, N = seeds.shape
    dtype, device = seeds.dtype, seeds.device
    rot_dofs = [
        i for i, (_, jtype, c) in enumerate(chain.dof_joints) if (jtype, c) == ("floating", "rx")
    ]
    sel = None if dofs is None else dofs.index
    lo_a, hi_a = (lo, hi) if sel is None else (lo.index_select(0, sel), hi.index_select(0, sel))
    per_target = tasks  # targets (..., P)
    tgt = torch.arange(N, device=device) // K  # the target of every column
    tasks = [_columns(t, tgt) for t in per_target]
    q = seeds[0]
    b, A, perr, rerr = _linearise(chain, q, tasks, weights, dofs)
    conv = (perr <= tol_p) & (rerr <= tol_r)
    # Per column, last dimension the column (so that early exit can select).
    st: dict[str, Tensor] = {
        "q": q, "b": b, "A": A, "perr": perr, "rerr": rerr, "cost": _size(b), "conv": conv,
        "lam": torch.full((N,), _LAMBDA0, dtype=dtype, device=device),
        "solved_at": torch.zeros(N, dtype=torch.int64, device=device),  # iterations until conv
        "tgt": tgt, "seeds": seeds,
        # Joints on a limit that the last step pushed outwards (and the clamp stopped).
        "pushed": torch.zeros(lo_a.shape[0], N, dtype=torch.bool, device=device),
    }  # fmt: skip
    # Per target: the best point so far.
    inf = torch.full((P,), math.inf, dtype=dtype, device=device)
    best = {
        "q": q.view(n, P, K)[:, :, 0], "cost": inf, "perr": inf, "rerr": inf,
        "conv": torch.zeros(P, dtype=torch.bool, device=device),
        "found": torch.zeros(P, dtype=torch.bool, device=device),  # a point with a cost
        "solved_at": torch.full((P,), max_iterations, dtype=torch.int64, device=device),
    }  # fmt: skip

    def gather_best() -> Tensor:
        """The best point of every target over its columns (ties: the first column); returns
        which columns hold them.  Ranked as the result is: a point within tolerance before
        any other, then by cost (a NaN cost never), compared as they are (no key mixing the
        two, which would tie large costs)."""
        conv, cost, tgt = st["conv"], st["cost"], st["tgt"]
        M = cost.shape[0]
        cols = torch.arange(M, device=device)
        solved = torch.zeros_like(best["conv"]).scatter_reduce(0, tgt, conv, "amax")
        ranked = (conv | ~solved.index_select(0, tgt)) & ~cost.isnan()
        cost = torch.where(ranked, cost, math.inf)
        cmin = inf.scatter_reduce(0, tgt, cost, "amin")
        win = torch.where(ranked & (cost == cmin.index_select(0, tgt)), cols, M)
        c = torch.full((P,), M, device=device).scatter_reduce(0, tgt, win, "amin")
        leads = torch.zeros(M + 1, dtype=torch.bool, device=device).index_fill(0, c, True)
        found = c < M
        c = c.clamp(max=M - 1)
        was = best["conv"]
        better = found & (
            ~best["found"] | (solved & ~was) | ((solved == was) & (cmin < best["cost"]))
        )
        best["found"] = best["found"] | found
        best["q"] = torch.where(better, st["q"].index_select(1, c), best["q"])
        best["cost"] = torch.where(better, cmin, best["cost"])
        for name in ("perr", "rerr", "conv"):
            best[name] = torch.where(better, st[name].index_select(0, c), best[name])
        first = best["solved_at"].scatter_reduce(0, tgt, st["solved_at"], "amin")
        best["solved_at"] = torch.where(best["conv"], first, best["solved_at"])
        return leads[:M]

    seed = 0
    for it in range(max_iterations):
        if early_exit:
            solved = best["conv"].scatter_reduce(0, st["tgt"], st["conv"], "amax")
            done = solved.index_select(0, st["tgt"])
            left, n_done = torch.stack(((~solved).sum(), done.sum())).tolist()  # one sync
            if left == 0:
                break
            spare = _SPARE * K * left if restart_after is not None else 0
            size = max(done.shape[0] - n_done, min(done.shape[0], spare))
            if 2 * size <= done.shape[0]:  # drop the columns of solved targets
                gather_best()
                extra = size - (done.shape[0] - n_done)
                keep = ~done | (torch.cumsum(done.to(torch.int64), 0) <= extra)
                cols = keep.nonzero().squeeze(1)
                st = {k: v.index_select(-1, cols) for k, v in st.items()}
                tasks = [_columns(t, cols) for t in tasks]
        q, A, b, lam, conv = st["q"], st["A"], st["b"], st["lam"], st["conv"]
        # Projection with an active set: a joint on a limit that the gradient, or the last
        # step, pushes outwards is left out of the step; the trial point is clamped into the
        # limits.
        g = (A * b).sum(1)
        q_a = q if sel is None else q.index_select(0, sel)
        at_lo, at_hi = q_a <= lo_a, q_a >= hi_a
        blocked = (at_lo & (g > 0)) | (at_hi & (g < 0)) | (st["pushed"] & (at_lo | at_hi))
        free = (~blocked).to(dtype)
        dq = _step(A * free.unsqueeze(1), b, lam, g * free)
        st["pushed"] = (at_lo & (dq > 0)) | (at_hi & (dq < 0))
        q_new = q - dq if sel is None else q.index_add(0, sel, dq, alpha=-1.0)
        q_new = _clamp(_wrap_rotvecs(q_new, rot_dofs), lo, hi)
        # Every restart_after + 1 iterations (after the first restart_after), the columns take
        # the next seed and an unsolved target (evaluated here), but for the best of each.
        restart = (
            restart_after is not None
            and it >= restart_after
            and (it - restart_after) % (restart_after + 1) == 0
            and seed + 1 < n_seeds
        )
        if restart:
            leads = gather_best()
            seed += 1
            # The leading column of a target goes on (a solved target's keeps refining, an
            # unreachable target's keeps improving), unless it is the target's only column and
            # not within tolerance; the others restart.
            shared = (
                torch.zeros(P, dtype=torch.int64, device=device)
                .index_add(0, st["tgt"], torch.ones_like(st["tgt"]))
                .index_select(0, st["tgt"])
                > 1
            )
            fresh = ~leads | (~conv & ~shared)
            unsolved = ~best["conv"]
            order = torch.argsort(best["conv"].to(torch.uint8), stable=True)  # unsolved first
            rank = torch.cumsum(fresh.to(torch.int64), 0) - 1
            new_tgt = order.index_select(0, rank % unsolved.sum().clamp(min=1))
            st["tgt"] = torch.where(fresh, new_tgt, st["tgt"])
            tasks = [_columns(t, st["tgt"]) for t in per_target]
            q_new = torch.where(fresh, st["seeds"][seed], q_new)
            st["pushed"] = st["pushed"] & ~fresh
        b_new, A_new, perr_new, rerr_new = _linearise(chain, q_new, tasks, weights, dofs)
        cost_new = _size(b_new)
        conv_new = (perr_new <= tol_p) & (rerr_new <= tol_r)
        ok = (cost_new < st["cost"]) & (conv_new | ~conv)  # False for nan: a failed step
        if restart:
            ok = ok | fresh
        for key, new in (("q", q_new), ("b", b_new), ("A", A_new), ("perr", perr_new),
                         ("rerr", rerr_new), ("cost", cost_new), ("conv", conv_new)):  # fmt: skip
            st[key] = torch.where(ok, new, st[key])
        counted = conv & ~fresh if restart else conv  # solved before this iteration
        st["solved_at"] = torch.where(counted, st["solved_at"], it + 1)
        lam = (lam * torch.where(ok, _LAMBDA_DOWN, _LAMBDA_UP)).clamp(_LAMBDA_MIN, _LAMBDA_MAX)
        st["lam"] = torch.where(fresh, _LAMBDA0, lam) if restart else lam
    gather_best()
    return best["q"], [best["perr"], best["rerr"], best["conv"], best["solved_at"]]


def _size(b: Tensor) -> Tensor:
    """The cost's measure ``|b|`` ``(N,)`` of residuals ``b (m, N)`` (the steps minimise
    ``|b|^2 / 2``, which ranks alike), from ``b`` scaled by a power of two of its largest
    component: finite for every finite ``b`` (``|b|^2`` overflows beyond about ``1e154`` in
    float64, ``1e19`` in float32)."""
    k = _coeffs.power_of_two(b.abs().amax(0))
    k = torch.where(k.isfinite(), k, 1.0)  # (a non-finite residual: a non-finite size)
    c = b / k
    return (c * c).sum(0).sqrt() * k


def _implicit_steps(
    chain: SolverChain,
    q: Tensor,
    targets: list[_Task],
    w_sqrt: Tensor,
    dofs: _Dofs | None,
    lo: Tensor,
    hi: Tensor,
) -> Tensor:
    """``q`` (the solver's answer ``(n_dof, P)``, as it is) with the derivatives of the solution
    with respect to ``targets`` (tasks with their targets as given, ``(P, 4, 4)`` or
    ``(P, 3)``), to first and second order: two Gauss-Newton steps ``G(q, theta) = q -
    (A^T A)^+ A^T b`` attached as ``q + s - s.detach()``.  The first, at ``q`` held fixed (only
    ``b`` carries a graph, through the targets), gives ``dq*/dtheta``; the second, from it with
    the graph through ``q`` too (forward kinematics, ``A`` and ``b``), adds the second
    derivatives: ``dG/dq = 0`` at a zero residual, so ``d^2 G(q1(theta), theta)`` is that of
    the solution once ``q1`` has the right first derivative.  A column whose step is not finite
    (a non-finite or far target) keeps ``q`` (zero derivative)."""
    free = (q > lo) & (q < hi)  # a joint on a limit stays there (its column of A is zeroed)
    free = (free if dofs is None else free.index_select(0, dofs.index)).to(q.dtype)
    zero = q.new_zeros(q.shape[1])
    with torch.no_grad():  # both steps' values (q1 = q): finite, or the column is left out
        fixed = [t._replace(target=_batch_last(t.target, t.pose)) for t in targets]
        b, A = _residuals(chain, q, fixed, w_sqrt, dofs)
        ok = _step((A * free).transpose(0, 1), b, zero).isfinite().all(0)
    # A column left out takes its target without a graph (where's derivative is a selection:
    # neither q nor the targets' derivatives see its non-finite values).
    tasks = []
    for t in targets:
        sel = ok.view(-1, *(1,) * (t.target.dim() - 1))
        tasks.append(t._replace(target=_batch_last(torch.where(sel, t.target, t.target.detach()),
                                                   t.pose)))  # fmt: skip
    b, A = _residuals(chain, q, tasks, w_sqrt, dofs)
    q1 = q + _attached(q, -_step((A.detach() * free).transpose(0, 1), b, zero), ok, dofs)
    b, A = _residuals(chain, q1, tasks, w_sqrt, dofs)
    return q1 + _attached(q, -_step((A * free).transpose(0, 1), b, zero), ok, dofs)


def _attached(q: Tensor, s: Tensor, ok: Tensor, dofs: _Dofs | None) -> Tensor:
    """``s - s.detach()`` ``(n_dof, N)`` for a step ``s`` of the DoFs ``dofs``: zero, with the
    derivatives of ``s``; zero in the columns not ``ok`` (``(N,)``)."""
    s = torch.where(ok, s, 0.0)
    if dofs is not None:  # zero for the DoFs that do not move a target link
        s = _layout.add_rows(s, dofs.gathers)
    return s - s.detach()
