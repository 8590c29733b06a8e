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
forward-kinematics-and-Jacobian pass for every link at once (:meth:`Chain.jacobian`'s closed
form); the small linear systems are solved by a Cholesky factorisation vectorised over the
batch.

Joint limits are kept by projection with an active set: a joint resting on a limit that the
cost's gradient pushes outwards is left out of the step (its column of ``A`` is zeroed), and
each trial point is clamped into ``[lower, upper]`` before it is evaluated, so every iterate
and the answer are within the limits.  Measured on the bundled Panda (targets from random
in-limit configurations, one start each, 100 iterations), the share of starts that converge
is 50% for this projection, 38% for clamping alone and 50% for the bounded reparametrisation
``q = mid + half sin(u)`` (whose derivative vanishes at the limits); with 8 starts and
restarts, projection with the active set converged most often, so it is what this module
does.  Coordinates without limits (continuous joints, planar and floating coordinates) are
unbounded; a floating joint's rotation vector is wrapped back to an angle of at most pi after
each step (same pose).  Mimic joints follow their joint (their own ``<limit>`` is not
enforced: the DoF they follow is what is bounded).

Batching and restarts: targets of any batch shape ``(...)``; ``restarts = K`` solves ``K``
starts per target side by side in one batch (the first from ``q0`` when given, the others
uniform within the limits like :meth:`Chain.random_configuration`, from ``generator``).  A
start still outside the tolerances after ``restart_after`` iterations is replaced by a fresh
uniform one (most starts that converge do so within a dozen iterations; one stuck against the
limits or in a local minimum rarely does), and the best point of every start is remembered.
Per target the result is a point within tolerance if any start reached one (the lowest cost
among those), else the lowest cost.

The iteration count is fixed (``max_iterations``) and nothing in the loop reads a tensor value
on the host, so it runs under ``torch.compile`` and on CUDA without synchronising.  With
``early_exit=True`` (eager use) solved targets leave the batch (it shrinks each time half of it
is solved) and the loop stops when none is left, which costs one synchronisation per
iteration and saves most of the work when a few targets are hard.

Gradients
---------
The iterations run without autograd.  The answer is then differentiable with respect to the
targets by the implicit-function theorem: at a solution ``A^T b = 0``, so
``dq*/dtheta = -(A^T A)^+ A^T db/dtheta`` (the minimum-norm solution when the robot is
redundant), attached as ``q* + s - s.detach()`` with ``s`` the (tiny-damped) Gauss-Newton step
of the residual computed with ``q*`` held fixed and only the targets carrying a graph.  Joints
resting on a limit get zero gradient (they stay there for small changes).  Away from a zero
residual (an unreachable target) this is the Gauss-Newton approximation of the derivative.

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
import operator
import reprlib
from collections.abc import Mapping
from typing import TYPE_CHECKING, NamedTuple

import torch
from torch import Tensor

from .. import _checks, _coeffs
from .. import se3 as _se3
from .. import so3 as _so3

if TYPE_CHECKING:
    from .chain import Chain

__all__ = ["IKResult", "inverse_kinematics"]

_FN = "torchlie.kinematics.Chain.inverse_kinematics"

# Levenberg-Marquardt schedule: lambda (relative to the mean diagonal of the normal matrix).
_LAMBDA0 = 1e-2
_LAMBDA_DOWN = 0.25
_LAMBDA_UP = 4.0
_LAMBDA_MIN = 1e-9
_LAMBDA_MAX = 1e9


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
        iterations: ``(...)`` int64, the iterations spent on the kept start (and on the starts
            it replaced, see ``restart_after``) before it came within the tolerances
            (``max_iterations``, or fewer with ``early_exit``, when it did not).
    """

    q: Tensor
    position_error: Tensor
    rotation_error: Tensor
    converged: Tensor
    iterations: Tensor


class _Dofs(NamedTuple):
    """The DoFs solved for (those that move a target link), when not all of them."""

    ids: tuple[int, ...]  # sorted
    index: Tensor  # the same, a long tensor on the chain's device


class _Task(NamedTuple):
    name: str
    link: int  # internal index of the link
    pose: bool  # pose target (else a position)
    target: Tensor  # batch innermost: (4, 4, N) T*^-1, or (3, N) p*


# ----------------------------------------------------------------------------------------------
# Argument checks (metadata only, except explicit limits: see _limits)
# ----------------------------------------------------------------------------------------------


def _count(value: object, name: str, least: int) -> int:
    try:
        if isinstance(value, bool):
            raise TypeError
        n = operator.index(value)  # type: ignore[arg-type]
    except TypeError:
        raise TypeError(
            f"{_FN}: expected {name} to be an integer >= {least}, got {type(value).__name__} "
            f"{reprlib.repr(value)}"
        ) from None
    if n < least:
        raise ValueError(f"{_FN}: expected {name} >= {least}, got {name}={n}")
    return n


def _number(value: object, name: str, positive: bool) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TypeError(
            f"{_FN}: expected {name} to be a number, got {type(value).__name__} "
            f"{reprlib.repr(value)}"
        )
    x = float(value)
    if not math.isfinite(x) or x < 0 or (positive and x == 0):
        need = "> 0" if positive else ">= 0"
        raise ValueError(f"{_FN}: expected {name} to be finite and {need}, got {name}={x!r}")
    return x


def _tensor(chain: Chain, x: object, name: str) -> Tensor:
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


def _targets(chain: Chain, targets: object, link: object) -> list[tuple[str, int, bool, Tensor]]:
    """``[(link name, link index, is pose, tensor)]`` from ``targets`` and ``link``."""
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
        (index,) = chain._targets(name, "inverse_kinematics")
        what = f"targets[{name!r}]" if isinstance(targets, Mapping) else "targets"
        t = _tensor(chain, t, what)
        shape = tuple(t.shape)
        if shape[-2:] == (4, 4):
            out.append((name, index, True, t))
        elif shape[-1:] == (3,):
            out.append((name, index, False, t))
        else:
            raise ValueError(
                f"{_FN}: expected {what} to be poses of shape (..., 4, 4) or positions of "
                f"shape (..., 3), got shape {shape}"
            )
    return out


def _limits(chain: Chain, lower: object, upper: object) -> tuple[Tensor, Tensor]:
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
            raise ValueError(
                f"{_FN}: expected lower <= upper for every DoF, got lower={float(lo[k])!r} > "
                f"upper={float(hi[k])!r} for {chain.joint_names[k]!r} (DoF {k})"
            )
    return lo, hi


# ----------------------------------------------------------------------------------------------
# Numerical core.  Everything is batch innermost: a problem's vector of length k is (k, N), a
# matrix (k, l, N), so the many tiny per-problem operations are a few long vector operations.
# ----------------------------------------------------------------------------------------------


def _hat_entries(w: tuple[Tensor, ...]) -> list[list[Tensor | None]]:
    x, y, z = w
    return [[None, -z, y], [z, None, -x], [-y, x, None]]


def _matmul3(X: Tensor, Y: Tensor) -> Tensor:
    """``X @ Y`` for ``(3, 3, N)`` stacks of matrices."""
    return (X.unsqueeze(2) * Y.unsqueeze(0)).sum(1)


def _jr_inv_rt(r: Tensor, Rt: Tensor) -> tuple[Tensor, Tensor]:
    """``(B R^T, C R^T)``, ``(3, 3, N)`` each, with ``Jr(r)^-1 = [[B, C], [0, B]]`` for the
    twists ``r (6, N)`` and the rotations ``R^T (3, 3, N)``.

    ``Jr(r)^-1 = Jl(-r)^-1`` (:mod:`torchlie.se3`): ``B = I + phi^/2 + d phi^ phi^`` (so3's
    ``Jl(-phi)^-1``, ``d = (1 - (t/2) cot(t/2)) / t^2``) and ``C = -B Q(-rho, -phi) B``.
    """
    rho = tuple(-x for x in r[:3].unbind(0))
    phi = r[3:].unbind(0)
    t2 = _coeffs.theta2(phi)
    d = _coeffs.jinv(t2).to(r.dtype)
    ks = (c.to(r.dtype) for c in _coeffs.q_series(t2))
    H = _hat_entries(phi)
    one = torch.ones_like(phi[0])
    # phi^ phi^ = phi phi^T - |phi|^2 I
    B = torch.stack(
        [
            torch.stack(
                [
                    d * (phi[i] * phi[j] - (t2.to(r.dtype) if i == j else 0.0))
                    + (one if i == j else 0.5 * H[i][j])  # type: ignore[operator]
                    for j in range(3)
                ]
            )
            for i in range(3)
        ]
    )
    neg_phi = tuple(-x for x in phi)
    eye = torch.eye(3, dtype=r.dtype, device=r.device).unsqueeze(-1)  # e_j along dim 0
    Qcols = _se3._q_components(rho, neg_phi, eye.unbind(1), *ks)  # Q e_j: (3, N) each
    Q = torch.stack(Qcols)  # (row i, column j, N)
    C = -_matmul3(_matmul3(B, Q), B)
    return _matmul3(B, Rt), _matmul3(C, Rt)


def _norm3(v: Tensor) -> Tensor:
    """Norm of ``(3, N)`` columns (three fused products: a reduction over a leading dimension
    of 3 costs more)."""
    x, y, z = v.unbind(0)
    return torch.addcmul(torch.addcmul(x * x, y, y), z, z).sqrt()


def _combine(G: Tensor, rows: tuple[Tensor, ...], G2: Tensor | None = None,
             rows2: tuple[Tensor, ...] = ()) -> Tensor:  # fmt: skip
    """``sum_j G[j] rows[j] (+ sum_j G2[j] rows2[j])``: a row of a ``(3, 3, N)`` matrix times
    the rows ``(n, N)`` of a Jacobian, per problem."""
    out = G[0] * rows[0]
    for j in (1, 2):
        out = torch.addcmul(out, G[j], rows[j])
    if G2 is not None:
        for j in range(3):
            out = torch.addcmul(out, G2[j], rows2[j])
    return out


def _residuals(
    chain: Chain, q: Tensor, tasks: list[_Task], weights: Tensor, dofs: _Dofs | None
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Weighted residuals ``b (m, N)``, their Jacobian ``A (m, k, N)`` with respect to the DoFs
    ``dofs`` (``k`` of them; all if None) and the position and rotation errors ``(N,)`` (worst
    over the tasks) at ``q (n_dof, N)``."""
    links = tuple(t.link for t in tasks)
    poses, jacs = chain._poses_and_jacobians(q.mT, links, None if dofs is None else dofs.ids)
    rs, As, perr, rerr = [], [], [], []
    for task, P, J in zip(tasks, poses, jacs, strict=True):
        # P (4, 4, N) with P[c, r] = T[r, c]; J (n, 6, N) in world coordinates.
        if task.pose:
            Ti = task.target  # (4, 4, N): T*^-1
            RtT = P[:3, :3]  # R^T
            ER = (Ti[:3, None, :3] * RtT[None]).sum(2)  # (T*^-1 T) rotation, [r, c]
            Et = (Ti[:3, :3] * P[3, :3].unsqueeze(0)).sum(1) + Ti[:3, 3]
            E = torch.cat((torch.cat((ER, Et.unsqueeze(1)), 1), Ti[3:]), 0)  # (4, 4, N)
            r = _se3.log(E.permute(2, 0, 1)).mT  # (6, N)
            # The derivative of the log: Jr(r)^-1 times the link-frame Jacobian R^T J.
            G1, G2 = _jr_inv_rt(r, RtT)
            Jc = J.unbind(1)  # six (n, N): linear then angular rows
            top = [_combine(G1[i], Jc[:3], G2[i], Jc[3:]) for i in range(3)]
            bottom = [_combine(G1[i], Jc[3:]) for i in range(3)]
            As.append(torch.stack(top + bottom))
            rs.append(r)
            perr.append(_norm3(Et))
            rerr.append(_norm3(r[3:]))
        else:
            r = P[3, :3] - task.target
            rs.append(r)
            As.append(J[:, :3].transpose(0, 1))
            perr.append(_norm3(r))
    b = (torch.cat(rs) if len(rs) > 1 else rs[0]) * weights.unsqueeze(-1)
    A = (torch.cat(As) if len(As) > 1 else As[0]) * weights.view(-1, 1, 1)
    p_err = torch.stack(perr).amax(0) if len(perr) > 1 else perr[0]
    if not rerr:
        return b, A, p_err, torch.zeros_like(p_err)
    r_err = torch.stack(rerr).amax(0) if len(rerr) > 1 else rerr[0]
    return b, A, p_err, r_err


def _spd_solve(S: Tensor, y: Tensor) -> Tensor:
    """``S^-1 y`` for symmetric positive definite ``S (k, k, N)`` and ``y (k, N)``.

    A Cholesky factorisation by columns, each a few vector operations over the batch (``k`` is
    small: a few rows per link): for thousands of tiny systems this is several times faster on
    a CPU than a LAPACK call per matrix, and it has no error check that would read a device
    value.  A pivot that rounding makes non-positive is clamped to the smallest normal number,
    so the result stays finite.
    """
    k = S.shape[0]
    tiny = torch.finfo(S.dtype).tiny
    L = torch.zeros_like(S)
    inv = torch.zeros_like(y)
    for j in range(k):
        col = S[j:, j] if j == 0 else S[j:, j] - (L[j:, :j] * L[j, :j]).sum(1)
        inv[j] = col[0].clamp_min(tiny).rsqrt()
        L[j:, j] = col * inv[j]
    z = torch.zeros_like(y)
    for i in range(k):
        acc = y[i] if i == 0 else y[i] - (L[i, :i] * z[:i]).sum(0)
        z[i] = acc * inv[i]
    x = torch.zeros_like(y)
    for i in reversed(range(k)):
        acc = z[i] if i == k - 1 else z[i] - (L[i + 1 :, i] * x[i + 1 :]).sum(0)
        x[i] = acc * inv[i]
    return x


def _step(A: Tensor, b: Tensor, lam: Tensor) -> Tensor:
    """``dq = (A^T A + mu I)^-1 A^T b`` ``(n, N)`` (the descent step is ``-dq``), ``mu = lam
    mean(diag)`` plus a floor of a few ulp; through the ``m x m`` dual system
    ``dq = A^T (A A^T + mu I)^-1 b`` when ``m <= n``."""
    m, n = A.shape[:2]
    dual = m <= n
    M = A if dual else A.transpose(0, 1)  # (k, l, N): S = M M^T
    k = M.shape[0]
    S = torch.stack([(M[i : i + 1] * M).sum(1) for i in range(k)])  # (k, k, N)
    diag = torch.diagonal(S, dim1=0, dim2=1).mT  # (k, N)
    eps = torch.finfo(A.dtype).eps
    mu = lam * diag.mean(0) + eps * (1.0 + diag.amax(0))
    S = S + mu * torch.eye(k, dtype=A.dtype, device=A.device).unsqueeze(-1)
    if dual:
        return (A * _spd_solve(S, b).unsqueeze(1)).sum(0)
    return _spd_solve(S, (A * b.unsqueeze(1)).sum(0))


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
    chain: Chain,
    bounds: tuple[Tensor, Tensor] | None,
    shape: tuple[int, ...],
    generator: torch.Generator | None,
) -> Tensor:
    """Uniform draws ``(*shape, n_dof)`` within the chain's limits, or within ``bounds`` (given
    bounds, already on the host), with the free ranges of :meth:`Chain.random_configuration`
    where a bound is infinite; drawn on the CPU in float64 (no device value is read)."""
    slo, shi = chain._sampling_bounds()
    lo64, hi64 = chain._limits64 if bounds is None else bounds
    slo = torch.where(torch.isfinite(lo64), lo64, torch.minimum(slo, hi64))
    shi = torch.where(torch.isfinite(hi64), hi64, torch.maximum(shi, lo64))
    u = torch.rand(*shape, chain.n_dof, generator=generator, dtype=torch.float64)
    return (slo + (shi - slo) * u).to(dtype=chain.dtype, device=chain.device)


def inverse_kinematics(
    chain: Chain,
    targets: Tensor | Mapping[str, Tensor],
    link: str | None = None,
    *,
    q0: Tensor | None = None,
    restarts: int = 1,
    position_weight: float = 1.0,
    rotation_weight: float = 1.0,
    max_iterations: int = 40,
    restart_after: int | None = 12,
    position_tolerance: float = 1e-4,
    rotation_tolerance: float = 1e-3,
    early_exit: bool = False,
    lower: Tensor | float | None = None,
    upper: Tensor | float | None = None,
    generator: torch.Generator | None = None,
) -> IKResult:
    """Joint values that put ``link`` at ``targets`` (see the module docstring for the method).

    Args:
        chain: the robot.
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
            Jacobian pass), at least 0.
        restart_after: a start that is not within tolerance after this many iterations is
            replaced by a fresh uniform one (``None``: never), so a budget of
            ``max_iterations`` tries up to ``restarts * (1 + max_iterations // restart_after)``
            starts per target at the cost of ``restarts``; the best point of every start is
            kept.  Only the DoFs that move a target link are solved for: the others keep their
            start value.
        position_tolerance, rotation_tolerance: thresholds of ``converged`` (m, rad).
        early_exit: stop once every target has a start within tolerance (one device
            synchronisation per iteration; not for ``torch.compile(fullgraph=True)``).
        lower, upper: bounds replacing the chain's limits, ``(n_dof,)`` or a number (``inf``
            for none); checked ``lower <= upper``.
        generator: random generator of the starts.

    Returns:
        :class:`IKResult` ``(q, position_error, rotation_error, converged, iterations)``; an
        unreachable target gives ``converged = False`` and the best ``q`` found (finite).

    Raises:
        TypeError, ValueError: a target of the wrong shape, dtype or device, an unknown link,
            ``restarts < 1``, ``lower > upper``, and other bad arguments, with the argument's
            name.
    """
    items = _targets(chain, targets, link)
    restarts = _count(restarts, "restarts", 1)
    max_iterations = _count(max_iterations, "max_iterations", 0)
    if restart_after is not None:
        restart_after = _count(restart_after, "restart_after", 1)
    wp = _number(position_weight, "position_weight", True)
    wr = _number(rotation_weight, "rotation_weight", False)
    if wr == 0:  # orientations ignored: pose targets are position targets
        items = [(nm, i, False, t[..., :3, 3]) if pose else (nm, i, pose, t)
                 for nm, i, pose, t in items]  # fmt: skip
    tol_p = _number(position_tolerance, "position_tolerance", False)
    tol_r = _number(rotation_tolerance, "rotation_tolerance", False)
    lo, hi = _limits(chain, lower, upper)
    dtype, device, n = chain.dtype, chain.device, chain.n_dof
    shapes = [(t.shape[:-2] if pose else t.shape[:-1], f"targets[{name!r}]")
              for name, _, pose, t in items]  # fmt: skip
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

    # Tasks: targets broadcast to (P,) then repeated over the K starts, batch innermost.
    tasks, grad_tasks, weights = [], [], []
    for name, index, pose, t in items:
        tail = (4, 4) if pose else (3,)
        size = math.prod(tail)
        tb = t.expand(*batch, *tail).reshape(P, *tail)
        ref = _se3.inverse(tb) if pose else tb
        grad_tasks.append(_Task(name, index, pose, ref.reshape(P, size).mT.reshape(*tail, P)))
        rep = ref.detach().repeat_interleave(K, dim=0).reshape(N, size)
        tasks.append(_Task(name, index, pose, rep.mT.contiguous().view(*tail, N)))
        weights += [wp] * 3 + ([wr] * 3 if pose else [])
    w_sqrt = torch.tensor(weights, dtype=dtype, device=device).sqrt()
    # Only the DoFs that move a target link are solved for (the others keep their start).
    moving = chain._moving_dofs(tuple(index for _, index, _, _ in items))
    dofs = None if moving == tuple(range(n)) else _Dofs(moving, torch.tensor(moving, device=device))

    with torch.no_grad():
        q_best, out = _solve(
            chain, seeds, tasks, w_sqrt, dofs, lo1, hi1, (P, K), max_iterations,
            restart_after, (tol_p, tol_r), early_exit,
        )  # fmt: skip

    q_out = q_best
    if torch.is_grad_enabled() and any(t.requires_grad for *_, t in items):
        q_out = q_best + _implicit_step(chain, q_best, grad_tasks, w_sqrt, dofs, lo1, hi1)
    return IKResult(q_out.mT.reshape(*batch, n), *(x.reshape(batch) for x in out))


def _solve(
    chain: Chain,
    seeds: Tensor,
    tasks: list[_Task],
    w_sqrt: Tensor,
    dofs: _Dofs | None,
    lo: Tensor,
    hi: Tensor,
    PK: tuple[int, int],
    max_iterations: int,
    restart_after: int | None,
    tols: tuple[float, float],
    early_exit: bool,
) -> tuple[Tensor, list[Tensor]]:
    """The Levenberg-Marquardt loop (call without autograd) on the ``K`` starts of ``P``
    targets (column ``p * K + k``); ``seeds (S, n, P K)`` are the starts and their
    replacements.  Returns ``q (n, P)`` of the kept start per target and its position error,
    rotation error, convergence flag and iteration count ``(P,)``.

    With ``early_exit``, targets are dropped from the batch once solved (the batch shrinks
    when half of it is done), and the loop ends when none is left.
    """
    P, K = PK
    tol_p, tol_r = tols
    n_seeds, n, N = seeds.shape
    dtype, device = seeds.dtype, seeds.device
    rot_dofs = [i for i, name in enumerate(chain.joint_names) if name.endswith(":rx")]
    q = seeds[0]
    b, A, perr, rerr = _residuals(chain, q, tasks, w_sqrt, dofs)
    cost = 0.5 * (b * b).sum(0)
    sel = None if dofs is None else dofs.index
    lo_a, hi_a = (lo, hi) if sel is None else (lo.index_select(0, sel), hi.index_select(0, sel))
    conv = (perr <= tol_p) & (rerr <= tol_r)
    zeros = torch.zeros(N, dtype=torch.int64, device=device)
    # Every per-start tensor, last dimension the start (so that early exit can select).
    st: dict[str, Tensor] = {
        "q": q, "b": b, "A": A, "perr": perr, "rerr": rerr, "cost": cost, "conv": conv,
        "lam": torch.full((N,), _LAMBDA0, dtype=dtype, device=device),
        "iters": zeros, "age": zeros, "seed": zeros,
        "fresh": torch.zeros(N, dtype=torch.bool, device=device),  # take the next seed now
        "best_q": q, "best_key": _key(conv, cost), "best_perr": perr, "best_rerr": rerr,
        "best_conv": conv, "seeds": seeds,
    }  # fmt: skip
    targets = [t.target for t in tasks]
    ids = torch.arange(P, device=device)  # targets still in the batch
    q_out = q.new_zeros(n, P)
    outs = [perr.new_zeros(P), perr.new_zeros(P), conv.new_zeros(P), zeros.new_zeros(P)]

    def finish(which: Tensor | None) -> None:
        """Write the kept start of the targets ``which`` (positions in the batch; all if None)."""
        p_now = st["q"].shape[-1] // K
        pick = st["best_key"].view(p_now, K).argmin(1)
        rows = torch.arange(p_now, device=device) if which is None else which
        cols = rows * K + pick.index_select(0, rows)
        where = ids.index_select(0, rows)
        q_out.index_copy_(1, where, st["best_q"].index_select(1, cols))
        for o, key in zip(outs, ("best_perr", "best_rerr", "best_conv", "iters"), strict=True):
            o.index_copy_(0, where, st[key].index_select(0, cols))

    for _ in range(max_iterations):
        if early_exit:
            solved = st["conv"].view(st["conv"].shape[0] // K, K).any(1)
            left = int((~solved).sum())  # the synchronisation early exit pays for
            if left == 0:
                break
            if left <= solved.shape[0] // 2:  # drop the solved targets
                done, keep = solved.nonzero().squeeze(1), (~solved).nonzero().squeeze(1)
                finish(done)
                cols = (keep.unsqueeze(1) * K + torch.arange(K, device=device)).reshape(-1)
                st = {k: v.index_select(-1, cols) for k, v in st.items()}
                targets = [t.index_select(-1, cols) for t in targets]
                tasks = [t._replace(target=x) for t, x in zip(tasks, targets, strict=True)]
                ids = ids.index_select(0, keep)
        q, A, b, lam, fresh = st["q"], st["A"], st["b"], st["lam"], st["fresh"]
        st["iters"] = st["iters"] + (~st["conv"]).to(torch.int64)
        # Projection with an active set: a joint on a limit that the gradient pushes outwards
        # is left out of the step; the trial point is clamped into the limits.
        g = (A * b.unsqueeze(1)).sum(0)
        q_a = q if sel is None else q.index_select(0, sel)
        blocked = ((q_a <= lo_a) & (g > 0)) | ((q_a >= hi_a) & (g < 0))
        dq = _step(A * (~blocked).to(dtype), b, lam)
        q_new = q - dq if sel is None else q.index_add(0, sel, dq, alpha=-1.0)
        q_new = _clamp(_wrap_rotvecs(q_new, rot_dofs), lo, hi)
        if restart_after:
            fresh_q = st["seeds"].gather(0, st["seed"].view(1, 1, -1).expand(1, n, -1))
            q_new = torch.where(fresh, fresh_q.squeeze(0), q_new)
        b_new, A_new, perr_new, rerr_new = _residuals(chain, q_new, tasks, w_sqrt, dofs)
        cost_new = 0.5 * (b_new * b_new).sum(0)
        ok = (cost_new < st["cost"]) | fresh  # False for nan: a failed step is refused
        for key, new in (("q", q_new), ("b", b_new), ("A", A_new), ("perr", perr_new),
                         ("rerr", rerr_new), ("cost", cost_new)):  # fmt: skip
            st[key] = torch.where(ok, new, st[key])
        lam = torch.where(ok, lam * _LAMBDA_DOWN, lam * _LAMBDA_UP)
        st["lam"] = torch.where(fresh, _LAMBDA0, lam.clamp(_LAMBDA_MIN, _LAMBDA_MAX))
        conv = (st["perr"] <= tol_p) & (st["rerr"] <= tol_r)
        st["conv"] = conv
        key = _key(conv, st["cost"])
        better = key < st["best_key"]
        for name, new in (("q", st["q"]), ("key", key), ("perr", st["perr"]),
                          ("rerr", st["rerr"]), ("conv", conv)):  # fmt: skip
            st["best_" + name] = torch.where(better, new, st["best_" + name])
        if restart_after:
            age = torch.where(fresh, 0, st["age"] + 1)
            fresh = (~conv) & (age >= restart_after) & (st["seed"] + 1 < n_seeds)
            st["age"], st["fresh"] = age, fresh
            st["seed"] = st["seed"] + fresh.to(torch.int64)
    finish(None)
    return q_out, outs


def _key(conv: Tensor, cost: Tensor) -> Tensor:
    """Ranks points: any converged one before any other, then by cost (in ``[0, 1)``)."""
    return (~conv).to(cost.dtype) * 2.0 + cost / (1.0 + cost)


def _implicit_step(
    chain: Chain,
    q: Tensor,
    tasks: list[_Task],
    w_sqrt: Tensor,
    dofs: _Dofs | None,
    lo: Tensor,
    hi: Tensor,
) -> Tensor:
    """``s - s.detach()`` with ``s = -(A^T A)^+ A^T b``: zero, with the implicit-function
    gradient of the solution with respect to the targets (only ``b`` carries a graph)."""
    with torch.no_grad():
        fixed = [t._replace(target=t.target.detach()) for t in tasks]
        _, A, _, _ = _residuals(chain, q, fixed, w_sqrt, dofs)
        free = (q > lo) & (q < hi)  # a joint on a limit stays there
        A = A * (free if dofs is None else free.index_select(0, dofs.index)).to(A.dtype)
    b = _residual_values(chain, q, tasks, w_sqrt)
    s = -_step(A, b, torch.zeros_like(q[0]))
    if dofs is not None:  # zero for the DoFs that do not move a target link
        s = q.new_zeros(q.shape).index_add(0, dofs.index, s)
    return s - s.detach()


def _residual_values(chain: Chain, q: Tensor, tasks: list[_Task], w_sqrt: Tensor) -> Tensor:
    """Weighted residuals ``(m, N)`` with the graph of the targets (``q`` held fixed)."""
    with torch.no_grad():
        poses, _ = chain._poses_and_jacobians(q.mT, tuple(t.link for t in tasks))
    rs = []
    for task, Pt in zip(tasks, poses, strict=True):
        T = Pt.permute(2, 1, 0)  # (N, 4, 4)
        if task.pose:
            Ti = task.target.permute(2, 0, 1)
            rs.append(_se3.log(_se3.compose(Ti, T)).mT)
        else:
            rs.append(T[:, :3, 3].mT - task.target)
    return (torch.cat(rs) if len(rs) > 1 else rs[0]) * w_sqrt.unsqueeze(-1)
