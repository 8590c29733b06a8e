"""Validate torchlie's kinematics of a robot against pytorch-kinematics, Pinocchio and a float64
reference.

Usage::

    python -m torchlie.kinematics.validate [ROBOT.urdf] [--samples N] [--dtype float32|float64]
                                           [--no-pk] [--no-pin]
    torchlie-validate tree            # a bundled robot: arm7 (the default), tree or panda
    torchlie-validate robot.xml       # an MJCF file: compared with MuJoCo itself
    torchlie-validate robot.sdf [--loops skip]   # an SDF file

An MJCF file (root element ``<mujoco>``) is compiled by MuJoCo and every body's pose and every
end body's Jacobian are compared with MuJoCo's ``mj_kinematics`` and ``mj_jacBody`` at the same
tolerances, and the dynamics with MuJoCo's when the model has mass (see
:mod:`torchlie.kinematics._mjcf_validate`).  An SDF file (root element
``<sdf>``) is compared link by link with an independent float64 evaluation of the SDFormat
frame rules (:mod:`torchlie.kinematics._sdf_validate`); ``--loops skip`` leaves out the joints
closing kinematic loops.  The rest of this page is about URDF.

For ``N`` random configurations within the joint limits it compares every link's pose and the
Jacobian of every end link (a link without children) computed by :class:`Chain` with

* an exact float64 reference (:mod:`torchlie.kinematics.reference`, an independent
  joint-by-joint implementation; its Jacobian comes from forward-mode autodiff), at a tolerance
  of ``1e-12`` (float64) or ``1e-5`` (float32), times ``1 + reach`` for positions and
  Jacobians (``reach``: the longest sum of joint offsets and travel from the root, in m);
* pytorch-kinematics, if installed, at ``1e-5`` (times ``1 + reach``): it parses origins and
  computes in float32.  Its known deviations from URDF are handled and reported as such, not
  as torchlie failures: it ignores ``<mimic>`` (it is given the expanded joint values), it reads
  an omitted ``<axis>`` as +Z instead of +X (it is given the axis explicitly), and it cannot
  load floating or planar joints (they become fixed joints in its copy, and the links below
  them are compared with the reference only);
* Pinocchio (``pip install 'torchlie[pinocchio]'``), if installed, in float64 at the
  reference's tolerance: every link pose, and each end link's Jacobian in all three kinds of
  :meth:`Chain.jacobian <torchlie.kinematics.Chain.jacobian>`.  Where the two libraries
  differ in convention, the comparison maps Pinocchio onto torchlie:

  - frames: torchlie's ``frame="world"`` (velocity of the link's origin and angular velocity,
    in world coordinates) is Pinocchio's ``LOCAL_WORLD_ALIGNED``, ``frame="link"`` (the same
    in the link's coordinates, the body twist) is ``LOCAL``, and ``frame="spatial"`` (the
    spatial twist: angular velocity and the velocity of the body point at the world origin)
    is ``WORLD``.  Links are Pinocchio's ``BODY`` frames of the same name.
  - motion vectors: both order a twist (linear; angular), Pinocchio's ``(v, w)``, so rows map
    one to one.
  - configuration: Pinocchio orders joints depth-first and gives some joints several
    coordinates: a continuous joint is ``(cos q, sin q)``, a planar joint ``(x, y, cos theta,
    sin theta)``, a floating joint ``(x, y, z, qx, qy, qz, qw)``.  torchlie's ``q`` (document
    order, angles and rotation vectors, see :mod:`torchlie.kinematics.chain`) is converted to
    that layout joint by joint.
  - velocities: Pinocchio's Jacobian columns are its velocity coordinates, one per
    revolute/prismatic/continuous joint, ``(R^T (dx, dy), dtheta)`` in the moving frame for a
    planar joint and the body twist ``(R^T dt, w)`` for a floating one; they are mapped to
    torchlie's DoFs by ``J_torchlie = J_pin D`` with ``D`` the derivative of Pinocchio's
    velocity with respect to ``dq`` (``R(theta)^T`` for a planar joint's translation;
    ``R^T`` and ``so3.jac_right(r)`` for a floating joint's translation and rotation vector).
  - mimic joints: its URDF reader (``mimic=False``) makes them independent joints, so it is
    given their expanded values and its columns are folded onto the joint they follow, as for
    pytorch-kinematics.  A planar joint whose axis is not +z in its frame cannot be modelled
    by Pinocchio's (xy-plane) planar joint: the links below it are not compared with it.

With Pinocchio installed and a robot with ``<inertial>`` elements, the dynamics are compared
too, in float64 (or float32) on the same configurations with random velocities and
accelerations: :meth:`Chain.inverse_dynamics <torchlie.kinematics.Chain.inverse_dynamics>`,
``mass_matrix``, ``bias_forces``, ``gravity_torques`` and ``forward_dynamics`` against its
``rnea``, ``crba``, ``nonLinearEffects`` and ``computeGeneralizedGravity``, largest error
relative to ``1 + |reference|``, at :data:`TOL_DYNAMICS`.  The forward dynamics are held to
Pinocchio's equations of motion: the residual ``|M qdd + h - tau|`` of the accelerations
computed from the torques, relative to ``|M| |qdd| + |h| + |tau|`` (:func:`backward_error`).
That is what a backward-stable solve guarantees whatever the mass matrix; the accelerations
themselves are only as accurate as its condition number allows, for any solver (Pinocchio's
``aba`` is as far from the exact ones on a robot with massive links of next to no inertia,
such as iCub).  They are left out, with a note, where the mass matrix is singular in every
state (:meth:`Chain.forward_dynamics <torchlie.kinematics.Chain.forward_dynamics>` refuses
those chains).

It prints a table (per link: largest position error in m and rotation error in rad, per end
link: largest Jacobian error per comparison) and timings of torchlie and pytorch-kinematics
(Pinocchio computes one configuration per call: it is compared, not timed), shows a progress
bar on stderr for long runs, and ends with one verdict line:

* ``PASS``: every link pose and end-link Jacobian is within tolerance;
* ``FAIL``: something is outside tolerance; a ``nan`` error (a result that is not a number
  where the reference is, or an overflow on both sides) counts as outside, never as within;
* ``NOTHING TO COMPARE``: the robot has no degree of freedom (a single link, or fixed joints
  only), so there is no configuration to vary and no Jacobian column; nothing is compared and
  nothing is timed.  This is a deliberate third status: not a failure, and not a PASS of an
  empty comparison.

Exit status: 0 for ``PASS`` and for ``NOTHING TO COMPARE`` (nothing is outside tolerance; the
verdict line tells them apart), 1 for ``FAIL`` (only then), 2 for a bad command line or an
unusable URDF (malformed, or missing).
"""

from __future__ import annotations

import argparse
import io
import math
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable
from xml.etree import ElementTree

import torch
from torch import Tensor

from .. import _checks, so3
from . import SAMPLE_ROBOTS, sample_robot
from ._pin_reference import PIN_FRAMES, _Pin, _pin_setup
from ._pk_reference import _PK, TOL_PK, _pk_setup
from ._pk_reference import _pk_text as _pk_text  # imported from here by benchmarks/bench_ik.py
from .chain import Chain
from .dynamics import _plan as _dyn_plan
from .reference import reference_forward_kinematics, reference_jacobians
from .urdf import JointSpec, RobotSpec, URDFError, parse_urdf

__all__ = [
    "FAIL",
    "NOTHING_TO_COMPARE",
    "PASS",
    "LinkResult",
    "JacobianResult",
    "ValidationReport",
    "validate",
    "main",
]


@runtime_checkable
class TextStream(Protocol):
    """Anything with ``write(str)`` and ``flush()`` (a file, ``sys.stdout``, ``io.StringIO``)."""

    def write(self, s: str, /) -> object: ...

    def flush(self) -> object: ...


TOL_REFERENCE = {torch.float64: 1e-12, torch.float32: 1e-5}

#: Tolerances of the dynamics against Pinocchio, relative to ``1 + |reference|``.
#: ``"qdd"``: the backward error of the forward dynamics (:func:`backward_error`).
TOL_DYNAMICS = {
    torch.float64: {"tau": 1e-9, "M": 1e-10, "bias": 1e-9, "gravity": 1e-9, "qdd": 1e-12},
    torch.float32: {"tau": 1e-4, "M": 1e-4, "bias": 1e-4, "gravity": 1e-4, "qdd": 1e-5},
}
_DYN_NAMES = {
    "tau": "inverse dynamics",
    "M": "mass matrix",
    "bias": "bias forces",
    "gravity": "gravity torques",
    "qdd": "forward dynamics",  # the residual |M qdd + h - tau|
}

#: :attr:`ValidationReport.status` values.
PASS, FAIL, NOTHING_TO_COMPARE = "pass", "fail", "nothing to compare"


@dataclass
class LinkResult:
    """Largest errors of one link's pose over all configurations (``None``: not compared)."""

    link: str
    joint: str
    joint_type: str
    ref_position: float
    ref_rotation: float
    pk_position: float | None
    pk_rotation: float | None
    ok: bool
    pin_position: float | None = None
    pin_rotation: float | None = None


@dataclass
class JacobianResult:
    """Largest absolute error of one end link's Jacobian (``None``: not compared).

    ``ref_error`` and ``pk_error`` are of the world-frame Jacobian at the link's origin;
    ``pin_errors`` maps each kind (``"world"``, ``"link"``, ``"spatial"``, see
    :meth:`Chain.jacobian`) to its largest error against Pinocchio.
    """

    link: str
    ref_error: float
    pk_error: float | None
    ok: bool
    pin_errors: dict[str, float] | None = None


@dataclass
class ValidationReport:
    """Everything :func:`validate` measured.

    ``status`` is the verdict: ``"pass"``, ``"fail"`` or ``"nothing to compare"`` (a robot
    without degrees of freedom: ``links``, ``jacobians`` and ``timings`` stay empty).  ``ok``
    is ``status != "fail"``: nothing is outside tolerance.
    """

    robot: str
    source: str
    samples: int
    dtype: torch.dtype
    reach: float
    links: list[LinkResult] = field(default_factory=list)
    jacobians: list[JacobianResult] = field(default_factory=list)
    deviations: list[str] = field(default_factory=list)
    timings: dict[str, dict[str, float]] = field(default_factory=dict)
    pk_version: str | None = None
    pin_version: str | None = None
    pin_deviations: list[str] = field(default_factory=list)
    ok: bool = True
    status: str = PASS
    #: Largest relative errors of the dynamics against Pinocchio (None: not compared).
    dynamics: dict[str, float] | None = None


# ----------------------------------------------------------------------------------------------
# Helpers
# ----------------------------------------------------------------------------------------------


def _resolve(robot: str | os.PathLike[str]) -> tuple[str | bytes, bytes, str]:
    """(source for the parser, the XML bytes, label) of a path, a bundled name or XML text."""
    if isinstance(robot, str) and robot.lstrip().startswith("<"):
        return robot, robot.encode("utf-8"), "<string>"
    path = os.fspath(robot)
    if not os.path.exists(path) and path in SAMPLE_ROBOTS:
        path = sample_robot(path)
    with open(path, "rb") as f:
        data = f.read()
    return path, data, path


def _top_down(spec: RobotSpec) -> list[JointSpec]:
    """The joints, every parent's joint before its children's (breadth-first from the root)."""
    children: dict[str, list[JointSpec]] = {}
    for j in spec.joints:
        children.setdefault(j.parent, []).append(j)
    order: list[JointSpec] = []
    frontier = [spec.root]
    while frontier:
        nxt: list[str] = []
        for link in frontier:
            for j in children.get(link, ()):
                order.append(j)
                nxt.append(j.child)
        frontier = nxt
    return order


def _reach(spec: RobotSpec) -> float:
    """Longest root-to-link sum of joint offsets and joint travel, in m."""
    total = {spec.root: 0.0}
    for j in _top_down(spec):
        extra = 0.0
        if j.type == "prismatic":
            extra = max(abs(j.lower or 0.0), abs(j.upper or 0.0))
        elif j.type == "planar":
            extra = math.sqrt(2.0)
        elif j.type == "floating":
            extra = math.sqrt(3.0)
        total[j.child] = total[j.parent] + math.hypot(*j.xyz) + extra
    return max(total.values())


def _below(spec: RobotSpec, types: tuple[str, ...], names: tuple[str, ...] = ()) -> dict[str, str]:
    """Links below a joint of one of ``types`` or named in ``names``: link -> that joint."""
    out: dict[str, str] = {}
    for j in _top_down(spec):
        if j.type in types or j.name in names:
            out[j.child] = j.name
        elif j.parent in out:
            out[j.child] = out[j.parent]
    return out


def _worse(a: float, b: float) -> float:
    """The larger error; ``nan`` if either is (Python's ``max`` drops a ``nan`` first)."""
    return math.nan if math.isnan(a) or math.isnan(b) else max(a, b)


def _pose_errors(T: Tensor, T_ref: Tensor) -> tuple[float, float]:
    T, T_ref = T.to(torch.float64), T_ref.to(torch.float64)
    dp = torch.linalg.vector_norm(T[..., :3, 3] - T_ref[..., :3, 3], dim=-1)
    dr = so3.distance(T[..., :3, :3], T_ref[..., :3, :3])
    return float(dp.max()), float(dr.max())


def _best_time(fn: Callable[[], object], budget: float = 0.3, reps: int = 50) -> float:
    """Best wall time of ``fn`` in seconds (one warm-up call, then up to ``reps`` calls)."""
    fn()
    best = math.inf
    start = time.perf_counter()
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
        if time.perf_counter() - start > budget:
            break
    return best


class _Progress:
    def __init__(self, total: int, stream: TextStream | None) -> None:
        self.total, self.stream = total, stream

    def update(self, done: int) -> None:
        if self.stream is None:
            return
        width = 30
        k = width * done // max(self.total, 1)
        self.stream.write(f"\r[{'#' * k}{'.' * (width - k)}] {done}/{self.total} configurations")
        self.stream.flush()

    def close(self) -> None:
        if self.stream is not None:
            self.stream.write("\n")
            self.stream.flush()


def _fmt(x: float | None) -> str:
    return "n/c" if x is None else f"{x:.1e}"


# ----------------------------------------------------------------------------------------------
# The validation
# ----------------------------------------------------------------------------------------------


def validate(
    robot: str | os.PathLike[str],
    *,
    samples: int = 1000,
    dtype: torch.dtype = torch.float64,
    seed: int = 0,
    batch: int = 1000,
    compare_pk: bool = True,
    compare_pin: bool = True,
    progress: bool | None = None,
    out: TextStream | None = None,
    err: TextStream | None = None,
) -> ValidationReport:
    """Run the validation and print its report; see the module docstring.

    Args:
        robot: a URDF path, a bundled robot name (``"arm7"``, ``"tree"``, ``"panda"``) or the
            URDF text.
        samples: number of random configurations within the joint limits, at least 1.
        dtype: torchlie's dtype (pytorch-kinematics always runs in float32).
        seed: seed of the configurations.
        batch: configurations per batch (and batch size of the timings), at least 1.
        compare_pk: compare with pytorch-kinematics when it is installed.
        compare_pin: compare with Pinocchio when it is installed.
        progress: progress bar on ``err``; ``None`` shows it when there is more than one batch.
        out, err: streams for the report and the progress bar (default stdout, stderr).

    Returns:
        The :class:`ValidationReport`; ``report.status`` is ``"pass"``, ``"fail"`` (and then
        ``report.ok`` is False) or ``"nothing to compare"`` for a robot without degrees of
        freedom (see the module docstring).

    Raises:
        ValueError: ``samples`` or ``batch`` below 1 (``TypeError`` if not an integer).
        URDFError: a malformed URDF.

    Example:
        >>> import io
        >>> report = validate("arm7", samples=50, out=io.StringIO())
        >>> report.ok, len(report.links), [j.link for j in report.jacobians]
        (True, 12, ['tool_tcp', 'wrist_camera'])
    """
    samples = _checks.count(samples, "torchlie.kinematics.validate", "samples", 1)
    batch = _checks.count(batch, "torchlie.kinematics.validate", "batch", 1)
    out = sys.stdout if out is None else out
    err = sys.stderr if err is None else err
    source, text, label = _resolve(robot)
    spec = parse_urdf(source)
    chain = Chain(spec, dtype=dtype)
    reach = _reach(spec)
    scale = 1.0 + reach
    tol_ref = TOL_REFERENCE[dtype]
    report = ValidationReport(spec.name, label, samples, dtype, reach)
    if chain.n_dof == 0:
        report.status = NOTHING_TO_COMPARE
        what = "a single link" if len(spec.links) == 1 else "fixed joints only"
        out.write(
            f"torchlie.kinematics.validate: robot {report.robot!r} ({label})\n"
            f"NOTHING TO COMPARE: the robot has no degree of freedom ({what}, "
            f"{len(spec.links)} links): there is no configuration to vary and its Jacobians "
            "have no columns\n"
        )
        out.flush()
        return report

    q = chain.random_configuration(samples, generator=torch.Generator().manual_seed(seed))
    q64 = q.to(torch.float64)  # exactly the values torchlie sees

    free = _below(spec, ("floating", "planar"))
    pkc, report.pk_version, report.deviations = _pk_setup(
        spec, chain, text, compare_pk, free, tol_ref, scale
    )

    pinc, report.pin_version, report.pin_deviations = _pin_setup(spec, chain, text, compare_pin)
    pin_nc = _below(spec, (), tuple(pinc.skipped)) if pinc is not None else {}

    def pin_ok(n: str) -> bool:
        return pinc is not None and n not in pin_nc and n in pinc.frames

    parent = {j.child: j for j in spec.joints}
    stats = {
        n: [0.0, 0.0, 0.0 if pkc and n not in free else None, 0.0]
        + [0.0 if pin_ok(n) else None, 0.0]
        for n in spec.links
    }  # ref dp, ref dr, pk dp (None: n/c), pk dr, pin dp (None: n/c), pin dr
    jstats = {
        n: [0.0, 0.0 if pkc and n not in free else None]
        + [dict.fromkeys(PIN_FRAMES, 0.0) if pin_ok(n) else None]
        for n in chain.leaf_links
    }

    chunks = [(i, min(i + batch, samples)) for i in range(0, samples, batch)]
    show = (len(chunks) > 1) if progress is None else progress
    bar = _Progress(samples, err if show else None)
    bar.update(0)
    for a, b in chunks:
        qc, qc64 = q[a:b], q64[a:b]
        T = chain.forward_kinematics(qc)
        T_ref = reference_forward_kinematics(spec, qc64)
        th = pk_T = None
        if pkc is not None:
            th = pkc.values(qc64)
            pk_T = pkc.fk(th)
        for n in spec.links:
            dp, dr = _pose_errors(T[n], T_ref[n])
            s = stats[n]
            s[0], s[1] = _worse(s[0], dp), _worse(s[1], dr)
            if s[2] is not None and pk_T is not None:
                dp, dr = _pose_errors(T[n], pk_T[n])
                s[2], s[3] = _worse(s[2], dp), _worse(s[3], dr)
        J_ref = reference_jacobians(spec, qc64, list(chain.leaf_links))
        for n in chain.leaf_links:
            J = chain.jacobian(qc, n).to(torch.float64)
            js = jstats[n]
            js[0] = _worse(js[0], float((J - J_ref[n]).abs().max()))
            if js[1] is not None and pkc is not None and th is not None and n != spec.root:
                J_pk = pkc.jacobian(th, n)
                js[1] = _worse(js[1], float((J - J_pk).abs().max()))
        if pinc is not None:
            _pin_compare(pinc, chain, qc, qc64, stats, jstats)
        bar.update(b)
    bar.close()

    for n in spec.links:
        s = stats[n]
        j = parent.get(n)
        ok = s[0] <= tol_ref * scale and s[1] <= tol_ref
        if s[2] is not None:
            ok = ok and s[2] <= TOL_PK * scale and s[3] <= TOL_PK
        if s[4] is not None:
            ok = ok and s[4] <= tol_ref * scale and s[5] <= tol_ref
        report.links.append(
            LinkResult(
                n,
                j.name if j else "-",
                j.type if j else "root",
                s[0],
                s[1],
                s[2],
                None if s[2] is None else s[3],
                ok,
                s[4],
                None if s[4] is None else s[5],
            )
        )
    for n in chain.leaf_links:
        js = jstats[n]
        ok = js[0] <= tol_ref * scale and (js[1] is None or js[1] <= TOL_PK * scale)
        if js[2] is not None:
            ok = ok and all(e <= tol_ref * scale for e in js[2].values())
        report.jacobians.append(JacobianResult(n, js[0], js[1], ok, js[2]))
    report.ok = all(r.ok for r in report.links) and all(r.ok for r in report.jacobians)
    if pinc is not None and spec.inertials and not pinc.skipped:
        report.dynamics = _pin_dynamics(pinc, chain, q, seed, report.pin_deviations)
        tol = TOL_DYNAMICS[dtype]
        report.ok = report.ok and all(v <= tol[k] for k, v in report.dynamics.items())
    report.status = PASS if report.ok else FAIL

    # Timings on one batch: FK of all links (dict) and the first end link's Jacobian.
    nb = min(batch, samples)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # like-for-like and stable on a busy machine; restored below
    try:
        _time_all(report, chain, pkc, q, q64, nb, free, spec.root)
    finally:
        torch.set_num_threads(threads)

    _print_report(report, chain, tol_ref, scale, nb, out)
    return report


def _pin_compare(
    pinc: _Pin, chain: Chain, qc: Tensor, qc64: Tensor, stats: dict, jstats: dict
) -> None:
    """Fold the errors against Pinocchio of one batch into ``stats`` and ``jstats``."""
    links = [n for n, s in stats.items() if s[4] is not None]
    leaves = [n for n, js in jstats.items() if js[2] is not None]
    P, J = pinc.evaluate(qc64, links, leaves)
    T = chain.forward_kinematics(qc, links) if links else {}
    for n in links:
        dp, dr = _pose_errors(T[n], P[n])
        s = stats[n]
        s[4], s[5] = _worse(s[4], dp), _worse(s[5], dr)
    for kind in PIN_FRAMES:
        Jt = chain.jacobian(qc, leaves, frame=kind) if leaves else {}
        for n in leaves:
            err = float((Jt[n].to(torch.float64) - J[(n, kind)]).abs().max())
            jstats[n][2][kind] = _worse(jstats[n][2][kind], err)


def _pin_dynamics(
    pinc: _Pin, chain: Chain, q: Tensor, seed: int, notes: list[str]
) -> dict[str, float]:
    """Largest errors of the dynamics against Pinocchio, relative to ``1 + |reference|``; the
    forward dynamics left out (and why, in ``notes``) where the mass matrix is singular in
    every state (``forward_dynamics`` refuses those chains)."""
    gen = torch.Generator().manual_seed(seed + 1)
    q64 = q.to(torch.float64)
    qd64 = torch.randn(q.shape, generator=gen, dtype=torch.float64)
    qdd64 = torch.randn(q.shape, generator=gen, dtype=torch.float64)
    ref = pinc.dynamics(q64, qd64, qdd64, derivatives=False, aba=False)
    qd, qdd = qd64.to(chain.dtype), qdd64.to(chain.dtype)
    tau_ref = ref["tau"].to(chain.dtype)

    def rel(x: Tensor, r: Tensor) -> float:
        e = float(((x.to(torch.float64) - r) / (1.0 + r.abs())).abs().max())
        return math.nan if math.isnan(e) or math.isinf(e) else e

    out = {
        "tau": rel(chain.inverse_dynamics(q, qd, qdd), ref["tau"]),
        "M": rel(chain.mass_matrix(q), ref["M"]),
        "bias": rel(chain.bias_forces(q, qd), ref["bias"]),
        "gravity": rel(chain.gravity_torques(q), ref["gravity"]),
    }
    singular = _dyn_plan(chain).massless
    if singular:
        names = ", ".join(repr(n) for n in singular)
        notes.append(f"forward dynamics not compared: the mass matrix is singular ({names})")
    else:
        # the residual of Pinocchio's equations of motion: a backward-stable solve leaves it at
        # the rounding of M, h and tau, where the accelerations themselves are only as accurate
        # as the condition number of M allows (Pinocchio's aba's too)
        a = chain.forward_dynamics(q, qd, tau_ref)
        out["qdd"] = backward_error(ref["M"], a, ref["bias"], tau_ref)
    return out


def backward_error(M: Tensor, qdd: Tensor, h: Tensor, tau: Tensor) -> float:
    """Largest normwise backward error of accelerations ``qdd`` ``(B, n)`` in the equations of
    motion ``M qdd + h = tau`` of a reference (``M`` ``(B, n, n)``): ``|M qdd + h - tau|``
    over ``|M| |qdd| + |h| + |tau|`` (infinity norms), in float64.  A backward-stable solve
    leaves it at a small multiple of the rounding unit whatever the condition number of ``M``,
    which bounds the accelerations' own error."""
    M, qdd, h, tau = (x.to(torch.float64) for x in (M, qdd, h, tau))
    r = (M @ qdd.unsqueeze(-1)).squeeze(-1) + h - tau
    scale = M.abs().sum(-1).amax(-1) * qdd.abs().amax(-1) + h.abs().amax(-1) + tau.abs().amax(-1)
    e = r.abs().amax(-1) / scale
    return float(e.max()) if e.numel() else 0.0


def _time_all(
    report: ValidationReport,
    chain: Chain,
    pkc: _PK | None,
    q: Tensor,
    q64: Tensor,
    nb: int,
    free: dict[str, str],
    root: str,
) -> None:
    dtype = chain.dtype
    if nb > 0:
        leaf = chain.leaf_links[0]
        runs: list[tuple[str, Chain | None]] = [(f"torchlie {str(dtype)[6:]}", chain)]
        if dtype != torch.float32:
            try:
                runs.append(("torchlie float32", chain.to(dtype=torch.float32)))
            except URDFError:  # a constant beyond float32's range: no float32 chain to time
                pass
        for name, c in runs:
            assert c is not None
            qt = q[:nb].to(c.dtype)
            report.timings[name] = {
                "fk": _best_time(lambda c=c, qt=qt: c.forward_kinematics(qt)),
                "jacobian": _best_time(lambda c=c, qt=qt: c.jacobian(qt, leaf)),
            }
        if pkc is not None:
            th = pkc.values(q64[:nb])
            t_fk = _best_time(lambda: pkc.chain.forward_kinematics(th))
            t_j = math.nan
            if leaf not in free and leaf != root:
                s_chain, idx = pkc.serial(leaf)
                ths = th[:, idx]
                t_j = _best_time(lambda: s_chain.jacobian(ths))
            report.timings["pytorch_kinematics float32"] = {"fk": t_fk, "jacobian": t_j}


def _print_report(
    report: ValidationReport, chain: Chain, tol_ref: float, scale: float, nb: int, out: TextStream
) -> None:
    w = out.write
    n_joints = len(chain.spec.joints)
    w(f"torchlie.kinematics.validate: robot {report.robot!r} ({report.source})\n")
    w(
        f"{len(chain.link_names)} links, {n_joints} joints, {chain.n_dof} DoF; "
        f"{report.samples} random configurations within the joint limits; torchlie in "
        f"{str(report.dtype)[6:]}\n"
    )
    pk_desc = (
        f"pytorch_kinematics {report.pk_version} (float32)"
        if report.pk_version
        else "pytorch_kinematics: not compared"
    )
    pin = report.pin_version is not None
    pin_desc = f"; Pinocchio {report.pin_version} (float64)" if pin else ""
    w(f"compared with: exact float64 reference; {pk_desc}{pin_desc}\n")
    pin_tol = "; Pinocchio at the reference's" if pin else ""
    w(
        f"tolerances: reference {tol_ref:g} rad, {tol_ref * scale:.1e} m; pytorch_kinematics "
        f"{TOL_PK:g} rad, {TOL_PK * scale:.1e} m{pin_tol} (1 + reach = {scale:.2f} m)\n\n"
    )
    name_w = max(12, *(len(r.link) for r in report.links)) + 2
    joint_w = max(10, *(len(r.joint) for r in report.links)) + 2
    pin_head = f"{'pin |dp| m':>12}{'pin |dR| rad':>14}" if pin else ""
    head = (
        f"{'link':<{name_w}}{'joint':<{joint_w}}{'type':<12}"
        f"{'ref |dp| m':>12}{'ref |dR| rad':>14}{'pk |dp| m':>12}{'pk |dR| rad':>14}"
        f"{pin_head}  status\n"
    )
    w(head)
    w("-" * (len(head) - 1) + "\n")
    for r in report.links:
        pin_cols = f"{_fmt(r.pin_position):>12}{_fmt(r.pin_rotation):>14}" if pin else ""
        w(
            f"{r.link:<{name_w}}{r.joint:<{joint_w}}{r.joint_type:<12}"
            f"{_fmt(r.ref_position):>12}{_fmt(r.ref_rotation):>14}"
            f"{_fmt(r.pk_position):>12}{_fmt(r.pk_rotation):>14}{pin_cols}  "
            f"{'ok' if r.ok else 'MISMATCH'}\n"
        )
    pin_head = "".join(f"{'pin ' + k:>14}" for k in PIN_FRAMES) if pin else ""
    w(
        f"\n{'Jacobian of end link':<{name_w + joint_w + 12}}{'ref max|dJ|':>12}"
        f"{'pk max|dJ|':>14}{pin_head}\n"
    )
    for r in report.jacobians:
        pin_cols = ""
        if pin:
            errs = r.pin_errors or {}
            pin_cols = "".join(f"{_fmt(errs.get(k)):>14}" for k in PIN_FRAMES)
        pad = "" if pin else f"{'':>26}"
        w(
            f"{r.link:<{name_w + joint_w + 12}}{_fmt(r.ref_error):>12}{_fmt(r.pk_error):>14}"
            f"{pin_cols}{pad}  {'ok' if r.ok else 'MISMATCH'}\n"
        )
    if any(r.pk_position is None for r in report.links) and report.pk_version:
        w("n/c: not comparable with pytorch_kinematics (see below)\n")
    if pin:
        w(
            "pin world / link / spatial: Chain.jacobian(frame=...) against Pinocchio's "
            "LOCAL_WORLD_ALIGNED / LOCAL / WORLD\n"
        )
    if report.deviations:
        w("\npytorch_kinematics deviations from URDF, handled (not torchlie failures):\n")
        for d in report.deviations:
            w(f"  - {d}\n")
    if report.pin_deviations:
        w("\nPinocchio:\n")
        for d in report.pin_deviations:
            w(f"  - {d}\n")
    if report.timings:
        w(f"\ntimings, batch of {nb}, one thread (best of repeated calls, ms per call):\n")
        w(f"  {'':<28}{'FK, all links':>16}{'Jacobian ' + chain.leaf_links[0]:>28}\n")
        for name, t in report.timings.items():
            jac = "n/c" if math.isnan(t["jacobian"]) else f"{t['jacobian'] * 1e3:.3f}"
            w(f"  {name:<28}{t['fk'] * 1e3:>16.3f}{jac:>28}\n")
        pk_t = report.timings.get("pytorch_kinematics float32")
        tl_t = report.timings.get("torchlie float32")
        if pk_t and tl_t:
            w(f"  torchlie float32 speed-up: FK {pk_t['fk'] / tl_t['fk']:.1f}x")
            if not math.isnan(pk_t["jacobian"]):
                w(f", Jacobian {pk_t['jacobian'] / tl_t['jacobian']:.1f}x")
            w("\n")
    if report.dynamics is not None:
        tol = TOL_DYNAMICS[report.dtype]
        w(
            f"\ndynamics against Pinocchio ({report.samples} states, random velocities and "
            "accelerations; largest error relative to 1 + |reference|):\n"
        )
        for k, v in report.dynamics.items():
            flag = "ok" if v <= tol[k] else "MISMATCH"
            w(f"  {_DYN_NAMES[k]:<20}{_fmt(v):>10}   (tolerance {tol[k]:g})  {flag}\n")
        if "qdd" in report.dynamics:
            w(
                "  (forward dynamics: the residual |M qdd + h - tau| of Pinocchio's M and h, "
                "relative to |M| |qdd| + |h| + |tau|)\n"
            )
    worst_ref = max([r.ref_position for r in report.links] + [0.0])
    if report.ok:
        w(
            f"\nPASS: all {len(report.links)} link poses and {len(report.jacobians)} end-link "
            f"Jacobians within tolerance (largest position error vs reference {worst_ref:.1e} m)\n"
        )
    else:
        bad = [r.link for r in report.links if not r.ok]
        bad += [f"Jacobian of {r.link}" for r in report.jacobians if not r.ok]
        if report.dynamics is not None:
            tol = TOL_DYNAMICS[report.dtype]
            bad += [_DYN_NAMES[k] for k, v in report.dynamics.items() if not v <= tol[k]]
        w(f"\nFAIL: outside tolerance: {', '.join(bad)}\n")


def _root_tag(robot: str) -> str | None:
    """The root element of ``robot`` (a path or XML text) when it is ``mujoco`` (MJCF) or
    ``sdf``, else None (URDF, a bundled name, or not readable: the URDF path reports it).  Read
    as XML up to the root's start tag, so that comments and headers of any length before it,
    and names in them, do not count."""
    source = io.BytesIO(robot.encode()) if robot.lstrip().startswith("<") else robot
    try:
        for _, element in ElementTree.iterparse(source, events=("start",)):
            return element.tag if element.tag in ("mujoco", "sdf") else None
    except (ElementTree.ParseError, OSError, UnicodeDecodeError):
        pass
    return None


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point (``torchlie-validate``); returns the exit status.

    0: ``PASS`` or ``NOTHING TO COMPARE`` (nothing outside tolerance), 1: ``FAIL`` (something
    outside tolerance), 2: a bad command line or an unusable URDF (see the module docstring).
    """
    parser = argparse.ArgumentParser(
        prog="torchlie-validate",
        description="Compare torchlie's forward kinematics and Jacobians of a URDF robot with "
        "pytorch-kinematics, Pinocchio and an exact float64 reference, and its dynamics with "
        "Pinocchio.",
    )
    parser.add_argument(
        "robot",
        nargs="?",
        default="arm7",
        help=f"URDF, MJCF or SDF file, or a bundled robot: {', '.join(SAMPLE_ROBOTS)} "
        "(default arm7)",
    )
    parser.add_argument("--samples", type=int, default=1000, help="random configurations")
    parser.add_argument("--dtype", choices=("float32", "float64"), default="float64")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--batch", type=int, default=1000, help="configurations per batch")
    parser.add_argument("--no-pk", action="store_true", help="skip pytorch-kinematics")
    parser.add_argument("--no-pin", action="store_true", help="skip Pinocchio")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument(
        "--loops",
        choices=("error", "skip"),
        default="error",
        help="SDF: a kinematic loop is an error, or its closing joints are left out",
    )
    args = parser.parse_args(argv)
    if args.samples < 1 or args.batch < 1:
        parser.error("--samples and --batch must be positive")
    if _root_tag(args.robot) == "sdf":
        from ._sdf_validate import validate_sdf
        from .sdf import SDFError

        try:
            ok = validate_sdf(
                args.robot,
                samples=args.samples,
                dtype=getattr(torch, args.dtype),
                seed=args.seed,
                loops=args.loops,
                out=sys.stdout,
            )
        except (SDFError, OSError) as e:
            print(f"torchlie-validate: error: {e}", file=sys.stderr)
            return 2
        return 0 if ok else 1
    if _root_tag(args.robot) == "mujoco":
        from ._mjcf_validate import validate_mjcf
        from .mjcf import MJCFError

        try:
            ok, _ = validate_mjcf(
                args.robot,
                samples=args.samples,
                dtype=getattr(torch, args.dtype),
                seed=args.seed,
                out=sys.stdout,
            )
        except (MJCFError, ImportError, OSError) as e:
            print(f"torchlie-validate: error: {e}", file=sys.stderr)
            return 2
        return 0 if ok else 1
    try:
        report = validate(
            args.robot,
            samples=args.samples,
            dtype=getattr(torch, args.dtype),
            seed=args.seed,
            batch=args.batch,
            compare_pk=not args.no_pk,
            compare_pin=not args.no_pin,
            progress=False if args.no_progress else None,
        )
    except (URDFError, OSError) as e:
        print(f"torchlie-validate: error: {e}", file=sys.stderr)
        return 2
    return 0 if report.ok else 1


if __name__ == "__main__":
    sys.exit(main())
