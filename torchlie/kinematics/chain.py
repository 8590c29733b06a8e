"""Kinematic trees: batched forward kinematics and geometric Jacobians.

Conventions
-----------
* World frame = the root link's frame.  A pose is a homogeneous ``(..., 4, 4)`` matrix
  ``[[R, t], [0, 1]]`` mapping link coordinates to world coordinates, ``p_world = T @ p_link``.
* A joint's child frame is ``T_child = T_parent @ T_origin @ M(q)``, ``T_origin`` from
  ``<origin xyz rpy>`` with ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (fixed axes), computed in float64
  from the parsed numbers.
* Joint coordinates, in the joint frame with the unit axis ``a`` (``<axis>`` normalised;
  ``(1, 0, 0)`` when omitted, as the URDF specification says):

  ==========  ====  ============================================================================
  revolute    1     ``M = Rot(a, q)``; ``continuous`` is the same without limits
  prismatic   1     ``M = Trans(q a)``
  fixed       0     ``M = I``
  planar      3     ``(x, y, theta)``: ``M = Trans(x e1 + y e2) Rot(n, theta)``, ``n`` the axis
                    (the plane's normal), ``e1`` the unit projection onto the plane of the
                    coordinate axis least aligned with ``n`` (first of x, y, z on ties),
                    ``e2 = n x e1``; for ``n = z`` this is ``e1 = x``, ``e2 = y``
  floating    6     ``(x, y, z, rx, ry, rz)``: ``M = [[Exp(r), t], [0, 1]]``, ``t`` the
                    translation in the joint frame and ``r`` a rotation vector
                    (:func:`torchlie.so3.exp`)
  ==========  ====  ============================================================================

* MJCF (:meth:`Chain.from_mjcf`) and SDF (:meth:`Chain.from_sdf`) chains also have ``ball``
  joints (``q``: a quaternion ``w, x, y, z``) and MJCF ``free`` joints (position, then a
  quaternion), joints that turn about a point of their frame (MJCF ``pos``) and MJCF ``ref``
  offsets: see :mod:`torchlie.kinematics.mjcf` and :mod:`torchlie.kinematics.sdf`.  A
  quaternion has three velocity coordinates, so their Jacobians have ``n_v`` columns
  (:attr:`Chain.velocity_names`), ``n_v = n_dof`` otherwise.
* ``<mimic joint=J multiplier=m offset=c>``: the joint's value is ``m * q[J] + c``; it has no
  DoF of its own (chains of mimics compose).
* ``q`` has shape ``(..., n_dof)`` in :attr:`Chain.joint_names` order: one entry per degree of
  freedom, joints in document order, fixed and mimic joints excluded; a planar or floating
  joint ``J`` contributes ``J:x, J:y, J:theta`` or ``J:x, J:y, J:z, J:rx, J:ry, J:rz``.
  These names are unique: a joint named like another joint's coordinate (``base:x`` beside a
  floating ``base``) raises :class:`~torchlie.kinematics.URDFError` naming both joints when
  the chain is built.  What each DoF is comes from its joint (:attr:`Chain.dof_joints`),
  never from its name.
* :meth:`Chain.jacobian` is the geometric Jacobian ``(..., 6, n_dof)``, rows (linear; angular),
  columns in ``q``'s order; by default in world coordinates at the link's origin: column ``i``
  holds ``(dp/dq_i, w_i)`` where ``dR/dq_i = hat(w_i) R``, the same meaning as
  pytorch-kinematics' ``jacobian``.  ``frame="link"`` gives it in the link's coordinates (the
  body twist, ``T(q + dq) ~= T(q) Exp(J dq)``), ``frame="spatial"`` the spatial twist
  (``T(q + dq) ~= Exp(J dq) T(q)``), and ``point=`` the linear velocity of a point fixed in
  the link instead of its origin.

Deliberate conventions at the edges:

* Every batch shape of up to 60 dimensions is accepted, empty ones included: ``q`` of shape
  ``(0, n_dof)`` gives poses ``(0, 4, 4)`` and Jacobians ``(0, 6, n_dof)``, like every
  torchlie op (more batch dimensions raise ``ValueError``, as there).
* A robot without degrees of freedom (one link, or fixed joints only) takes ``q`` of shape
  ``(..., 0)``; its poses are constants and its Jacobians have no columns, ``(..., 6, 0)``.
* Numbers: one rule for every number of the URDF the chain stores in its dtype (``<origin>``
  translations, ``<limit lower upper>`` and the composed ``<mimic>`` multipliers and
  offsets): one that does not fit the dtype (beyond ``3.4e38`` in a float32 chain, or mimic
  multipliers whose product overflows) raises :class:`~torchlie.kinematics.URDFError` naming
  the file, the joint, the attribute and the value when the chain is built (by
  :meth:`Chain.from_urdf`, the constructor or :meth:`Chain.to`); it never silently becomes
  ``inf`` (for a limit, that would read as "no limit").  With constants that fit, poses
  follow plain IEEE arithmetic: a pose whose translation overflows (two origins of ``1e308``
  in float64) is ``inf`` there, and the links below it get ``nan`` entries (the 4x4 products
  multiply that ``inf`` by the bottom row's zeros).  No check on values is made at run time
  (it would cost a device sync).

Implementation: the joints of each tree depth are computed together, per joint kind, with one
matrix product per depth.  A child pose is linear in a few features of its joint value
(``T_parent @ T_origin @ M(q) = sum_f feat_f(q) T_parent @ C_f`` with constant ``C_f``, e.g.
``1, sin q, 1 - cos q`` for a revolute joint), so a depth costs one GEMM of the parents'
poses against the stacked ``C_f`` plus a few fused multiply-adds.  Poses are kept internally
as ``(4, 4, batch)`` (batch innermost) so those element-wise ops run over long contiguous
rows; the public results are ordinary contiguous ``(..., 4, 4)`` tensors.  A Jacobian is one
column per moving joint on the link's path (a world direction, and for a rotation its moment
about the link), each added into its DoF's column by gathers (mimic joints share a
DoF), so time and memory are linear in the number of joints.  Everything is plain
differentiable torch, so first and second derivatives with respect to ``q`` are exact.  The
constants are built from the parsed URDF in ``_joints.py``, the forward pass is planned and run
in ``_fk_plan.py`` and the Jacobian columns are computed in ``_jacobian.py``; :class:`Chain`
holds the constants and caches the plans.
"""

from __future__ import annotations

import math
import operator
import os
import reprlib
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor

from .. import _checks, _layout
from .._autograd import cached
from .._typing import Float
from . import dynamics as _dyn
from ._fk_plan import _build_plan, _Plan, _pose, _run
from ._jacobian import _dof_index, _frame_jacobian, _jacobian_plan, _JacPlan, _link_columns
from ._joints import (
    _check_representable,
    _dof_layout,
    _mimic_rows,
    _sampling_ranges,
    _tree_links,
    _uniform_within,
    _velocity_layout,
    rpy_matrix,
)
from .dynamics import Inertials
from .urdf import RobotSpec, _some, parse_urdf

if TYPE_CHECKING:  # the solver is imported when it is called: it depends on Chain, not back
    from .ik import IKResult

__all__ = ["Chain", "rpy_matrix"]

_NAME = "torchlie.kinematics.Chain."

# Batch size up to which results are transposed back in one stacked copy (see
# forward_kinematics).
_SMALL_BATCH = 2048


class Chain:
    """A robot's kinematic tree, ready for batched forward kinematics and Jacobians.

    Build it with :meth:`from_urdf`; see the module docstring for every convention (joint
    coordinates, ``q`` layout, Jacobian meaning).  A chain holds constants in one dtype and on
    one device (float32 on the CPU by default); :meth:`to` returns a converted copy, rebuilt
    from the float64 values parsed from the file.  Every tensor argument of its methods (``q``,
    velocities, torques, points, gravity, wrenches, inertials) has the chain's dtype, or, on a
    float32 chain, float16/bfloat16 (computed in float32); results have ``q``'s dtype.

    Solvers use a chain through its attributes and three methods, the interface
    :class:`~torchlie.kinematics.ik.SolverChain` states: :meth:`poses_and_jacobians` (poses
    and world Jacobians of several links from one pass, batch last), :meth:`moving_dofs` and
    :meth:`sampling_bounds`.

    Attributes:
        spec: the parsed :class:`~torchlie.kinematics.RobotSpec`.
        name: the robot's name.
        root: the root link (its frame is the world frame).
        link_names: every link, in document order.
        joint_names: the ``n_dof`` degrees of freedom, in the order of ``q``'s last dimension.
        dof_joints: per degree of freedom, ``(joint, type, coordinate)``: the joint it belongs
            to, that joint's type (``"revolute"``, ``"floating"``, ...) and which of its
            coordinates it is (``""`` for a one-DoF joint, else ``"x"``, ``"theta"``,
            ``"rx"``, ``"qw"``, ...).  What a DoF is comes from here, not from its name (a
            joint may be named like a coordinate, ``"base:x"``).
        velocity_names: the ``n_v`` velocity coordinates, the Jacobian's columns (the same as
            ``joint_names`` unless the chain has MJCF ball or free joints).
        leaf_links: links without children (end effectors, tool frames), in document order.
        lower, upper: ``(n_dof,)`` position limits (``-inf``/``inf`` where there are none).
        dtype, device: of the constants, and hence of ``q`` and the results.

    Example:
        >>> from torchlie.kinematics import Chain, sample_robot
        >>> arm = Chain.from_urdf(sample_robot("arm7"))
        >>> arm.n_dof, arm.root
        (7, 'world')
        >>> arm.forward_kinematics(torch.zeros(5, 7))["tool_tcp"].shape
        torch.Size([5, 4, 4])
    """

    def __init__(
        self,
        spec: RobotSpec,
        *,
        dtype: torch.dtype = torch.float32,
        device: torch.device | str | None = None,
    ) -> None:
        if dtype not in (torch.float32, torch.float64):
            raise TypeError(f"{_NAME}__init__: dtype must be float32 or float64, got {dtype}")
        self.spec = spec
        self.name = spec.name
        self.root = spec.root
        self.dtype = dtype
        self.device = torch.device("cpu") if device is None else torch.device(device)
        self.link_names: tuple[str, ...] = spec.links

        # Degrees of freedom, in document order.
        dof_of, names, roles, lower, upper = _dof_layout(spec)
        self.joint_names: tuple[str, ...] = tuple(names)
        self.dof_joints: tuple[tuple[str, str, str], ...] = tuple(roles)
        self.n_dof = len(names)
        self._limits64 = (
            torch.tensor(lower, dtype=torch.float64),
            torch.tensor(upper, dtype=torch.float64),
        )
        self.lower = self._limits64[0].to(dtype=dtype, device=self.device)
        self._sample64 = _sampling_ranges(roles, *self._limits64)
        self.upper = self._limits64[1].to(dtype=dtype, device=self.device)
        # Velocity coordinates (the Jacobian's columns): the DoFs, except that a quaternion
        # (MJCF ball and free joints) has three.
        vel_of, vel_names = _velocity_layout(spec)
        self.velocity_names: tuple[str, ...] = tuple(vel_names)
        self.n_v = len(vel_names)

        # Mimic joints: value row = n_dof + k, q[src] * mult + off (chains resolved).
        row_of, self._mimic = _mimic_rows(spec, dof_of, self.n_dof)
        mimic_src, mimic_mult, mimic_off = self._mimic
        _check_representable(spec, dtype, mimic_mult, mimic_off)
        # Per DoF column of the Jacobian: which joints (and with which multiplier) move it.
        self._mimic_of = {
            j.name: (
                mimic_src[row_of[j.name] - self.n_dof],
                mimic_mult[row_of[j.name] - self.n_dof],
            )
            for j in spec.joints
            if j.mimic is not None
        }

        # Breadth-first internal order; children in document order of their joints.
        self._links = _tree_links(spec, dof_of, row_of, self._mimic_of, vel_of)
        self._index = {link.name: link.index for link in self._links}
        has_child = {link.parent for link in self._links}
        self.leaf_links: tuple[str, ...] = tuple(
            name for name in spec.links if self._index[name] not in has_child
        )
        self._plans: dict[tuple[tuple[int, ...], bool], _Plan] = {}
        self._jac_plans: dict[int, _JacPlan] = {}
        # (link, DoFs) -> which of the link's Jacobian columns feed those DoFs and where they go
        # among them (see _dof_index).
        self._dof_maps: dict[
            tuple[int, tuple[int, ...]], tuple[Tensor | None, tuple[Tensor, ...] | None]
        ]
        self._dof_maps = {}
        self._mimic_t: dict[torch.dtype, tuple[Tensor, Tensor, Tensor]] = {}

    # ------------------------------------------------------------------------------------------
    # Construction and conversion
    # ------------------------------------------------------------------------------------------

    @classmethod
    def from_urdf(
        cls,
        source: str | os.PathLike[str] | bytes,
        *,
        dtype: torch.dtype = torch.float32,
        device: torch.device | str | None = None,
    ) -> Chain:
        """Parse a URDF file (or URDF text) and build its chain.

        Args:
            source: a path to a ``.urdf`` file, or the XML text (a string starting with ``<``).
            dtype: float32 (default) or float64.
            device: where the constants live (default CPU).

        Raises:
            URDFError: a malformed URDF (see :func:`~torchlie.kinematics.parse_urdf`).

        Example:
            >>> chain = Chain.from_urdf('''<robot name="r"><link name="a"/><link name="b"/>
            ...   <joint name="j" type="prismatic"><parent link="a"/><child link="b"/>
            ...     <axis xyz="0 0 2"/><limit lower="0" upper="0.5"/></joint></robot>''')
            >>> chain.joint_names, chain.upper
            (('j',), tensor([0.5000]))
        """
        return cls(parse_urdf(source), dtype=dtype, device=device)

    @classmethod
    def from_mjcf(
        cls,
        source: str | os.PathLike[str] | bytes | Any,
        *,
        sites: bool = False,
        site_prefix: str = "",
        dtype: torch.dtype = torch.float32,
        device: torch.device | str | None = None,
    ) -> Chain:
        """Compile an MJCF file (or MJCF text, or take a ``mujoco.MjModel``) with MuJoCo and
        build its chain (needs the ``mujoco`` package: ``torchlie[mjcf]``).

        One link per body; ``q`` is MuJoCo's ``qpos`` (so ``chain.forward_kinematics(
        data.qpos)`` needs no conversion) and the Jacobian's columns are MuJoCo's ``nv``
        velocity coordinates (:attr:`velocity_names`).  The naming of unnamed bodies and
        joints and the joint conventions are in :mod:`torchlie.kinematics.mjcf`.

        Args:
            source: a path to an ``.xml`` file, MJCF text (a string starting with ``<``) or a
                ``mujoco.MjModel``.
            sites: also make each site a link (fixed to its body, after the bodies).
            site_prefix: put before each site's name to name its link (for models whose
                sites share names with bodies, which is otherwise an error).
            dtype: float32 (default) or float64.
            device: where the constants live (default CPU).

        Raises:
            MJCFError: MuJoCo refused the file (MuJoCo's message, with the file name).
            ImportError: ``mujoco`` is not installed.

        Example:
            >>> chain = Chain.from_mjcf('''<mujoco><worldbody><body name="ball" pos="0 0 1">
            ...   <joint type="ball"/><geom size="0.1"/><body name="tip" pos="0 0 -1"/></body>
            ...   </worldbody></mujoco>''', dtype=torch.float64)
            >>> chain.joint_names
            ('joint_0:qw', 'joint_0:qx', 'joint_0:qy', 'joint_0:qz')
            >>> chain.velocity_names
            ('joint_0:wx', 'joint_0:wy', 'joint_0:wz')
            >>> q = torch.tensor([0.0, 1.0, 0.0, 0.0], dtype=torch.float64)  # pi about x
            >>> chain.forward_kinematics(q, "tip")["tip"][:3, 3]
            tensor([0., 0., 2.], dtype=torch.float64)
        """
        from .mjcf import parse_mjcf

        return cls(
            parse_mjcf(source, sites=sites, site_prefix=site_prefix), dtype=dtype, device=device
        )

    @classmethod
    def from_sdf(
        cls,
        source: str | os.PathLike[str] | bytes,
        *,
        loops: str = "error",
        dtype: torch.dtype = torch.float32,
        device: torch.device | str | None = None,
    ) -> Chain:
        """Parse an SDF file (or SDF text: one model, or a world holding one) and build its
        chain; poses are in the model's frame (see :mod:`torchlie.kinematics.sdf`).

        Args:
            source: a path to an ``.sdf`` file, or the XML text (a string starting with ``<``).
            loops: ``"error"`` or ``"skip"`` (leave out the joints closing kinematic loops).
            dtype: float32 (default) or float64.
            device: where the constants live (default CPU).

        Raises:
            SDFError: a malformed or unsupported SDF.

        Example:
            >>> chain = Chain.from_sdf('''<sdf version="1.7"><model name="m">
            ...   <link name="a"/><link name="b"><pose>0 0 1 0 0 0</pose></link>
            ...   <joint name="j" type="prismatic"><parent>a</parent><child>b</child>
            ...     <axis><xyz>1 0 0</xyz></axis></joint></model></sdf>''')
            >>> chain.forward_kinematics(torch.tensor([0.5]), "b")["b"][:3, 3]
            tensor([0.5000, 0.0000, 1.0000])
        """
        from .sdf import parse_sdf

        return cls(parse_sdf(source, loops=loops), dtype=dtype, device=device)

    def to(
        self, dtype: torch.dtype | None = None, device: torch.device | str | None = None
    ) -> Chain:
        """A copy of the chain with constants in ``dtype`` on ``device`` (``self`` if unchanged).

        Constants are rebuilt from the float64 values parsed from the URDF, so
        ``chain.to(torch.float32).to(torch.float64)`` loses nothing.

        Example:
            >>> from torchlie.kinematics import sample_robot
            >>> chain = Chain.from_urdf(sample_robot("arm7")).to(dtype=torch.float64)
            >>> chain.dtype
            torch.float64
        """
        dtype = self.dtype if dtype is None else dtype
        device = self.device if device is None else torch.device(device)
        if dtype == self.dtype and device == self.device:
            return self
        return Chain(self.spec, dtype=dtype, device=device)

    def __repr__(self) -> str:
        return (
            f"Chain({self.name!r}, links={len(self.link_names)}, n_dof={self.n_dof}, "
            f"dtype={self.dtype}, device={self.device})"
        )

    # ------------------------------------------------------------------------------------------
    # Sampling
    # ------------------------------------------------------------------------------------------

    def sampling_bounds(
        self, lower: Tensor | None = None, upper: Tensor | None = None
    ) -> tuple[Tensor, Tensor]:
        """The float64 CPU box ``(lo, hi)`` that uniform joint values are drawn from
        (:meth:`random_configuration`, the starts of :meth:`inverse_kinematics`).

        Where a bound is finite it is the bound: the chain's limit, or ``lower``/``upper`` when
        given (float64 CPU ``(n_dof,)``, replacing the chain's).  Where it is infinite it is the
        chain's own range (its limit, or where it has none the free range stated in
        :meth:`random_configuration`), moved to the finite side of the other bound when that
        one is finite (so that ``lo <= hi``).  Reads no device value.

        Example:
            >>> from torchlie.kinematics import sample_robot
            >>> tree = Chain.from_urdf(sample_robot("tree"))
            >>> lo, hi = tree.sampling_bounds()
            >>> k = tree.joint_names.index("drone_free:x")
            >>> float(tree.lower[k]), float(lo[k]), float(hi[k])
            (-inf, -1.0, 1.0)
        """
        for name, v in (("lower", lower), ("upper", upper)):
            if v is not None and not (
                isinstance(v, Tensor)
                and v.shape == (self.n_dof,)
                and v.dtype == torch.float64
                and v.device.type == "cpu"
            ):
                raise TypeError(
                    f"{_NAME}sampling_bounds: expected {name} to be None or a float64 CPU tensor "
                    f"of shape ({self.n_dof},), got {reprlib.repr(v)}"
                )
        lo64 = self._limits64[0] if lower is None else lower
        hi64 = self._limits64[1] if upper is None else upper
        free_lo, free_hi = self._sample64
        lo = torch.where(torch.isfinite(lo64), lo64, torch.minimum(free_lo, hi64))
        hi = torch.where(torch.isfinite(hi64), hi64, torch.maximum(free_hi, lo64))
        return lo, hi

    def random_configuration(
        self, *batch: int, generator: torch.Generator | None = None
    ) -> Float[Tensor, "*batch n_dof"]:
        """Uniform joint values within the limits, shape ``(*batch, n_dof)``.

        Coordinates without limits are drawn from ``[-pi, pi]`` (continuous joints, planar
        rotation, and prismatic joints without limits, SDF prismatic joints or MJCF slides: in
        m), ``[-1, 1]`` m (planar, floating and free translations),
        ``[-pi/sqrt(3), pi/sqrt(3)]`` per rotation-vector component (floating rotations) and
        ``[-1, 1]`` per quaternion component (ball and free joints; the forward kinematics
        normalises them, and the rotations are not uniformly distributed); a coordinate limited
        on one side only (SDF) from a range of the same width on that side, e.g.
        ``[lower, lower + 2 pi]``.  What a coordinate is comes from its joint
        (:attr:`dof_joints`).
        Drawn on the CPU in float64 (with ``generator`` if given), then converted; the values are
        finite for every pair of limits, those near the float64 range included.  Each batch
        size is a non-negative integer (0 gives an empty batch), at most 60 of them (the batch
        limit of every torchlie op), ``generator`` a ``torch.Generator`` or None; anything else
        raises ``TypeError``/``ValueError``.

        Example:
            >>> from torchlie.kinematics import sample_robot
            >>> arm = Chain.from_urdf(sample_robot("arm7"))
            >>> q = arm.random_configuration(100, generator=torch.Generator().manual_seed(0))
            >>> bool(((q >= arm.lower) & (q <= arm.upper)).all())
            True
        """
        fn = _NAME + "random_configuration"
        sizes: list[int] = []
        for b in batch:
            try:
                if isinstance(b, bool):
                    raise TypeError
                size = operator.index(b)  # ints, numpy integers, integer 0-d tensors
            except TypeError:
                raise TypeError(
                    f"{fn}: expected batch sizes to be integers, got {type(b).__name__} "
                    f"{reprlib.repr(b)} in batch={reprlib.repr(batch)}"
                ) from None
            if size < 0:
                raise ValueError(f"{fn}: expected batch sizes >= 0, got batch={batch!r}")
            sizes.append(size)
        _checks.batch_dims(fn, len(sizes), "(one per batch size)")
        _checks.generator(generator, fn)
        lo, hi = self.sampling_bounds()
        u = torch.rand(*sizes, self.n_dof, generator=generator, dtype=torch.float64)
        return _uniform_within(lo, hi, u).to(dtype=self.dtype, device=self.device)

    # ------------------------------------------------------------------------------------------
    # Forward kinematics: plans (which links, grouped by depth and joint kind) and their run
    # ------------------------------------------------------------------------------------------

    def _plan(self, targets: tuple[int, ...], relative: bool = False) -> _Plan:
        """The plan of ``targets`` (see :func:`_build_plan`; ``relative``: each subtree of the
        root about its own origin)."""
        return cached(
            self._plans,
            (targets, relative),
            lambda: _build_plan(self._links, targets, self.dtype, self.device, relative),
        )

    def _values(self, q2: Tensor) -> Tensor:
        """Value bank ``(n_dof + n_mimic, B)``: ``q`` transposed, then the mimic joints."""
        qT = q2.mT.contiguous()
        src, mult, off = self._mimic
        if not src:
            return qT
        s, m, o = cached(
            self._mimic_t,
            q2.dtype,
            lambda: (
                torch.tensor(src, dtype=torch.long, device=self.device),
                torch.tensor(mult, dtype=q2.dtype, device=self.device).unsqueeze(-1),
                torch.tensor(off, dtype=q2.dtype, device=self.device).unsqueeze(-1),
            ),
        )
        return torch.cat((qT, torch.addcmul(o, qT.index_select(0, s), m)), dim=0)

    def _run(self, plan: _Plan, q2: Tensor) -> list[list[Tensor]]:
        """Poses of the plan's links: per level, per group, ``(n, 4, 4, B)`` = ``T[b]^T``."""
        return _run(plan, self._values(q2))

    def _pose(self, plan: _Plan, out: list[list[Tensor]], i: int, B: int, like: Tensor) -> Tensor:
        """Internal ``(4, 4, B)`` transposed pose of link ``i``."""
        return _pose(plan, out, i, B, like)

    def _check_like(self, x: Tensor, fn: str, name: str, given: torch.dtype) -> None:
        """Raise unless ``x`` (computed from an argument ``name`` of dtype ``given`` of the
        method ``fn``, named in full) has the chain's dtype and device."""
        if x.dtype != self.dtype:
            raise TypeError(
                f"{fn}: {name} has dtype {given} but the chain's constants are {self.dtype}; "
                "convert one of them (chain.to(dtype=...))"
            )
        if x.device != self.device:
            raise ValueError(
                f"{fn}: {name} is on {x.device} but the chain is on {self.device}; use "
                "chain.to(device=...)"
            )

    def _prepare(self, q: Tensor, fn: str) -> tuple[Tensor, torch.dtype, tuple[int, ...]]:
        x, out_dtype = _checks.tensor(q, _NAME + fn, "q", (self.n_dof,))
        self._check_like(x, _NAME + fn, "q", q.dtype)
        batch = tuple(x.shape[:-1])
        return x.reshape(math.prod(batch), self.n_dof), out_dtype, batch

    def _targets(self, links: str | Sequence[str] | None, fn: str) -> tuple[int, ...]:
        """Indices of ``links``: a name, a sequence of names (not a set: order matters), None."""
        if links is None:
            names: Sequence[str] = self.link_names
        elif isinstance(links, str):
            names = (links,)
        elif isinstance(links, Sequence) and not isinstance(links, (bytes, bytearray)):
            names = tuple(links)
            for k, n in enumerate(names):
                if not isinstance(n, str):
                    raise TypeError(
                        f"{_NAME}{fn}: expected links to be a link name, a sequence of link "
                        f"names or None, got a {type(links).__name__} whose item {k} is "
                        f"{type(n).__name__} {reprlib.repr(n)}"
                    )
        else:
            raise TypeError(
                f"{_NAME}{fn}: expected links to be a link name, a sequence of link names or "
                f"None, got {type(links).__name__} {reprlib.repr(links)}"
            )
        for n in names:
            if n not in self._index:
                raise ValueError(
                    f"{_NAME}{fn}: unknown link {n!r} (the links are {_some(self.link_names)})"
                )
        return tuple(self._index[n] for n in names)

    @_checks.float32_exact
    def forward_kinematics(
        self,
        q: Float[Tensor, "*b n_dof"],
        links: str | Sequence[str] | None = None,
        *,
        stacked: bool = False,
    ) -> dict[str, Float[Tensor, "*b 4 4"]] | Float[Tensor, "*b n 4 4"]:
        """World poses of links for joint values ``q``.

        Args:
            q: ``(..., n_dof)`` joint values in :attr:`joint_names` order, in the chain's dtype
                (float16/bfloat16 are accepted by a float32 chain, computed in float32 and
                returned in their dtype) and on its device.  Any batch shape.
            links: one link name, a sequence of names, or ``None`` for every link.  Only the
                links asked for and their ancestors are computed.
            stacked: return one tensor ``(..., n_links, 4, 4)`` (links in :attr:`link_names`
                order, or in the order given) instead of a dict.

        Returns:
            A dict link name -> ``(..., 4, 4)`` pose (in the order asked for), or the stacked
            tensor.  All results are contiguous.

        Example:
            >>> from torchlie.kinematics import sample_robot
            >>> arm = Chain.from_urdf(sample_robot("arm7"), dtype=torch.float64)
            >>> q = torch.zeros(7, dtype=torch.float64)
            >>> T = arm.forward_kinematics(q, ["tool_tcp", "link1"], stacked=True)
            >>> T.shape
            torch.Size([2, 4, 4])
            >>> T[0, :3, 3]
            tensor([ 0.0500, -0.0200,  1.4810], dtype=torch.float64)
        """
        q2, out_dtype, batch = self._prepare(q, "forward_kinematics")
        targets = self._targets(links, "forward_kinematics")
        if not targets:  # links=[]: nothing asked for
            if stacked:
                return _checks.out(q2.new_zeros(*batch, 0, 4, 4), out_dtype)
            return {}
        plan = self._plan(targets)
        B = q2.shape[0]
        out = self._run(plan, q2)
        poses = [self._pose(plan, out, i, B, q2) for i in targets]  # (c, r, B) each
        n = len(targets)
        # Back to (..., 4, 4): for small batches one stacked copy (fewest ops); for large ones
        # per-link copies, which torch runs faster than one interleaved copy.
        if B > _SMALL_BATCH:
            Ts = tuple(p.permute(2, 1, 0).contiguous() for p in poses)
        if stacked:
            if B <= _SMALL_BATCH:
                T = torch.stack(poses).permute(3, 0, 2, 1).contiguous()
            else:
                T = torch.stack(Ts, dim=1)
            return _checks.out(T.reshape(*batch, n, 4, 4), out_dtype)
        if B <= _SMALL_BATCH:
            Ts = torch.stack(poses).permute(0, 3, 2, 1).contiguous().unbind(0)
        return {
            self._links[i].name: _checks.out(T.view(*batch, 4, 4), out_dtype)
            for i, T in zip(targets, Ts, strict=True)
        }

    # ------------------------------------------------------------------------------------------
    # Jacobians
    # ------------------------------------------------------------------------------------------

    def _jac_plan(self, target: int) -> _JacPlan:
        return cached(
            self._jac_plans,
            target,
            lambda: _jacobian_plan(self._links, target, self.n_v, self.dtype, self.device),
        )

    def _jacobian_columns(
        self,
        jp: _JacPlan,
        pose: Callable[[int], Tensor],
        q2: Tensor,
        target: int,
        dofs: tuple[int, ...] | None = None,
    ) -> Tensor:
        """World Jacobian at the origin of ``target`` as ``(n_dof, 6, B)`` (batch innermost; see
        :meth:`jacobian`), or only the columns of ``dofs`` (sorted DoFs, ``(len(dofs), 6, B)``);
        ``pose(i)`` gives link ``i``'s internal ``(4, 4, B)`` pose."""
        B = q2.shape[0]
        n_out = self.n_v if dofs is None else len(dofs)
        C = _link_columns(jp, pose, q2, target)
        if C is None:
            return q2.new_zeros(n_out, 6, B)
        if dofs is None:
            index = None if jp.in_dof_order else jp.dof_gathers
        else:
            keep, index = cached(
                self._dof_maps, (target, dofs), lambda: _dof_index(jp, dofs, C.device)
            )
            if keep is not None:  # columns of DoFs not asked for
                C = C.index_select(0, keep)
        if index is None:  # the link's columns are those DoFs, in order
            return C
        # Each column into its DoF's column (summed where mimic joints share one).
        return _layout.add_rows(C, index)

    def moving_dofs(self, links: str | Sequence[str]) -> tuple[int, ...]:
        """The DoFs that move at least one of ``links``, sorted: the others have zero Jacobian
        columns for them.  They are indices into :attr:`velocity_names` (the Jacobian's
        columns), which are those into :attr:`joint_names` unless the chain has ball or free
        joints (a quaternion has four values but three velocity coordinates).

        Example:
            >>> from torchlie.kinematics import sample_robot
            >>> arm = Chain.from_urdf(sample_robot("arm7"))
            >>> arm.moving_dofs("link3")
            (0, 1, 2)
        """
        targets = self._targets(links, "moving_dofs")
        return tuple(sorted({d for t in targets for d in self._jac_plan(t).dofs}))

    @_checks.float32_exact
    def poses_and_jacobians(
        self,
        q_t: Float[Tensor, "n_dof B"],
        links: str | Sequence[str],
        dofs: Sequence[int] | None = None,
    ) -> tuple[list[Float[Tensor, "4 4 B"]], list[Float[Tensor, "k 6 B"]]]:
        """Poses and world Jacobians of ``links`` from one forward-kinematics pass, batch last:
        the form an iterative solver works in (:mod:`torchlie.kinematics.ik`).

        Args:
            q_t: ``(n_dof, B)`` joint values, the batch last (``q.mT`` for ``q (B, n_dof)``),
                in the chain's dtype and on its device.
            links: a link name or a sequence of names.
            dofs: strictly increasing indices into :attr:`velocity_names` (the Jacobian's
                columns; see :meth:`moving_dofs`), any of them: only their Jacobian columns are
                returned (zero for a DoF that does not move the link); ``None`` for all
                ``n_v`` columns.

        Returns:
            Per link, its pose transposed, ``(4, 4, B)`` with entry ``[c, r, b]`` the pose
            ``T[b][r, c]``, and its Jacobian (as :meth:`jacobian` with ``frame="world"``)
            ``(k, 6, B)``: column, row, batch.

        Example:
            >>> from torchlie.kinematics import sample_robot
            >>> arm = Chain.from_urdf(sample_robot("arm7"))
            >>> q = torch.zeros(4, 7)
            >>> (P,), (J,) = arm.poses_and_jacobians(q.mT, ["tool_tcp"])
            >>> torch.equal(P.permute(2, 1, 0), arm.forward_kinematics(q, "tool_tcp")["tool_tcp"])
            True
            >>> torch.equal(J.permute(2, 1, 0), arm.jacobian(q, "tool_tcp"))
            True
        """
        fn = "poses_and_jacobians"
        if not isinstance(q_t, Tensor):
            raise TypeError(f"{_NAME}{fn}: expected q_t to be a torch.Tensor, got {type(q_t)}")
        if q_t.dim() != 2 or q_t.shape[0] != self.n_dof:
            raise ValueError(
                f"{_NAME}{fn}: expected q_t of shape ({self.n_dof}, B) (batch last), got shape "
                f"{tuple(q_t.shape)}"
            )
        self._check_like(q_t, _NAME + fn, "q_t", q_t.dtype)
        targets = self._targets(links, fn)
        return self._poses_and_jacobians(q_t.mT, targets, self._dof_subset(dofs, fn))

    def _dof_subset(self, dofs: Sequence[int] | None, fn: str) -> tuple[int, ...] | None:
        """``dofs`` of :meth:`poses_and_jacobians` checked, as a tuple (None stays None)."""
        if dofs is None:
            return None

        def index(d: object) -> int:
            if isinstance(d, bool):
                raise TypeError
            return operator.index(d)  # ints, numpy integers, integer 0-d tensors

        try:
            if isinstance(dofs, (str, bytes, bytearray)) or not isinstance(dofs, Sequence):
                raise TypeError
            out = tuple(index(d) for d in dofs)
        except TypeError:
            raise TypeError(
                f"{_NAME}{fn}: expected dofs to be None or a sequence of integer DoF indices, "
                f"got {type(dofs).__name__} {reprlib.repr(dofs)}"
            ) from None
        increasing = all(a < b for a, b in zip(out, out[1:], strict=False))
        if not increasing or any(not 0 <= d < self.n_v for d in out):
            raise ValueError(
                f"{_NAME}{fn}: expected dofs to be strictly increasing indices in "
                f"[0, {self.n_v}) (into velocity_names; see moving_dofs), got "
                f"{reprlib.repr(dofs)}"
            )
        return out

    def _poses_and_jacobians(
        self, q2: Tensor, targets: tuple[int, ...], dofs: tuple[int, ...] | None = None
    ) -> tuple[list[Tensor], list[Tensor]]:
        """Poses and world Jacobians at the origins of ``targets`` for ``q2`` of shape
        ``(B, n_dof)``, from one forward-kinematics pass over the links they need, batch
        innermost: poses ``(4, 4, B)`` transposed (entry ``[c, r, b]`` is ``T[b][r, c]``),
        Jacobians ``(n_dof, 6, B)``, or only the columns of the sorted DoFs ``dofs`` (used by
        :meth:`jacobian` and the inverse kinematics)."""
        B = q2.shape[0]
        plan = self._plan(targets)
        out = self._run(plan, q2)

        def pose(i: int) -> Tensor:
            return self._pose(plan, out, i, B, q2)

        Js = [self._jacobian_columns(self._jac_plan(t), pose, q2, t, dofs) for t in targets]
        return [pose(t) for t in targets], Js

    @_checks.float32_exact
    def jacobian(
        self,
        q: Float[Tensor, "*b n_dof"],
        link: str | Sequence[str],
        *,
        frame: str = "world",
        point: Tensor | Mapping[str, Tensor] | None = None,
    ) -> Float[Tensor, "*b 6 n_v"] | dict[str, Float[Tensor, "*b 6 n_v"]]:
        """Geometric Jacobian of a link, ``(..., 6, n_v)``, in closed form.

        ``n_v`` is the number of velocity coordinates (:attr:`velocity_names`): ``n_dof``,
        except for the quaternions of MJCF ``ball`` and ``free`` joints, which have three
        (MuJoCo's ``nv`` columns, in its order; ``q`` itself is its ``qpos``).  Their columns
        follow MuJoCo: a ball joint's three columns are angular velocities about the axes of
        the body's own frame (the frame right after the ball joint: the quaternion moved to
        ``q_ball * Exp(w dt)``), turning about the joint's anchor; a free joint's first three
        are the linear velocity of the body's origin along the world axes, the last three the
        angular velocity about the body's own axes.

        Column ``i`` is the velocity of the link for a unit rate of velocity coordinate ``i``
        (columns in :attr:`velocity_names` order: the DoFs, in :attr:`joint_names` order, for
        a URDF chain), rows (linear; angular), in one of three conventions:

        * ``frame="world"`` (the default): the linear velocity of the link's origin (or of
          ``point``) and the angular velocity, both in world coordinates.  For a revolute joint
          with world axis ``z`` through ``p_i`` the column is ``(z x (p - p_i); z)``, for a
          prismatic one ``(z; 0)``.  Same meaning as pytorch-kinematics' ``jacobian`` and
          Pinocchio's ``LOCAL_WORLD_ALIGNED``.
        * ``frame="link"``: the same velocities in the link's own coordinates, ``R^T`` times
          both rows.  At the origin this is the body twist of
          :mod:`torchlie.se3`'s right perturbation, ``T(q + dq) ~= T(q) Exp(J dq)``
          (Pinocchio's ``LOCAL``).
        * ``frame="spatial"``: the spatial twist, ``T(q + dq) ~= Exp(J dq) T(q)``: the angular
          velocity and the velocity of the body point passing through the world origin,
          ``v - w x p``, in world coordinates (Pinocchio's ``WORLD``).  It is the same for every
          point of the link, so ``point`` must be None.

        A mimic joint adds its multiplier times its own column to the column of the joint it
        follows.  A planar joint's columns are two translations and a rotation; a floating
        joint's are three translations along the joint frame's axes and the angular velocities
        ``R_joint Jl(r) e_k`` of its rotation vector (:func:`torchlie.so3.jac_left`).  Columns
        of joints that do not move the link are zero.  A robot without degrees of freedom, or
        the root link, gives an all-zero or empty ``(..., 6, n_dof)``; an empty batch gives an
        empty result.

        Args:
            q: ``(..., n_dof)`` joint values, as for :meth:`forward_kinematics`.
            link: a link name, or a sequence of names (then a dict is returned; one
                forward-kinematics pass serves them all).
            frame: ``"world"``, ``"link"`` or ``"spatial"`` (see above).
            point: ``None`` (the link's origin), a point ``(3,)`` or ``(..., 3)`` in the link's
                frame (its batch shape broadcasts with ``q``'s), or for several links a dict
                link -> point (links not in it use their origin).

        Returns:
            ``(..., 6, n_dof)``, or a dict link -> ``(..., 6, n_dof)`` in the order given.

        Example:
            >>> from torchlie.kinematics import sample_robot
            >>> arm = Chain.from_urdf(sample_robot("arm7"))
            >>> J = arm.jacobian(torch.zeros(2, 7), "tool_tcp")
            >>> J.shape, J[0, 3:, 0]
            (torch.Size([2, 6, 7]), tensor([0., 0., 1.]))
            >>> Js = arm.jacobian(torch.zeros(7), ["tool_tcp", "link3"], frame="link")
            >>> list(Js), Js["link3"].shape
            (['tool_tcp', 'link3'], torch.Size([6, 7]))
        """
        fn = "jacobian"
        q2, out_dtype, batch = self._prepare(q, fn)
        if isinstance(link, str):
            names: tuple[str, ...] = (link,)
        elif isinstance(link, Sequence) and not isinstance(link, (bytes, bytearray)):
            names = tuple(link)
        else:
            raise TypeError(
                f"{_NAME}{fn}: expected link to be a link name (str) or a sequence of link "
                f"names, got {type(link).__name__} {reprlib.repr(link)}"
            )
        targets = self._targets(names, fn)
        if frame not in ("world", "link", "spatial"):
            raise ValueError(
                f"{_NAME}{fn}: expected frame to be 'world', 'link' or 'spatial', got "
                f"{reprlib.repr(frame)}"
            )
        points = self._jacobian_points(point, names, frame, batch)
        poses, jacs = self._poses_and_jacobians(q2, targets) if targets else ([], [])
        out: dict[str, Tensor] = {}
        for name, P, Jd in zip(names, poses, jacs, strict=True):
            J = Jd.permute(2, 1, 0)  # (B, 6, n)
            if frame != "world" or points.get(name) is not None:
                J = _frame_jacobian(J, P, frame, points.get(name), batch)
            else:
                J = J.reshape(*batch, 6, self.n_v)
            out[name] = _checks.out(J.contiguous(), out_dtype)
        if isinstance(link, str):
            return out[link]
        return out

    def _jacobian_points(
        self,
        point: Tensor | Mapping[str, Tensor] | None,
        names: tuple[str, ...],
        frame: str,
        batch: tuple[int, ...],
    ) -> dict[str, Tensor]:
        """``point`` of :meth:`jacobian` checked (its batch shape broadcasts with ``q``'s,
        ``batch``), as a dict link -> ``(..., 3)`` point."""
        fn = _NAME + "jacobian"
        if point is None:
            return {}
        if frame == "spatial":
            raise ValueError(
                f"{fn}: point is not used with frame='spatial' (the spatial twist is the same "
                "for every point of the link); pass point=None"
            )
        if isinstance(point, Mapping):
            for k in point:
                if k not in names:
                    raise ValueError(
                        f"{fn}: point has an entry for {reprlib.repr(k)}, which is not among "
                        f"the links asked for ({_some(names)})"
                    )
            items = {k: (v, f"point[{k!r}]") for k, v in point.items()}
        else:
            items = {n: (point, "point") for n in names}
        out = {}
        for k, (v, what) in items.items():
            x, _ = _checks.tensor(v, fn, what, (3,))
            self._check_like(x, fn, what, v.dtype)
            _checks.batch_broadcast(fn, (torch.Size(batch), "q"), (x.shape[:-1], what))
            out[k] = x
        return out

    @_checks.float32_exact
    def inverse_kinematics(
        self,
        targets: Tensor | Mapping[str, Tensor],
        link: str | None = None,
        **options: Any,
    ) -> IKResult:
        """Joint values putting ``link`` at ``targets``: batched Levenberg-Marquardt within the
        joint limits, differentiable with respect to the targets.

        Same as :func:`torchlie.kinematics.ik.inverse_kinematics(self, targets, link, ...)
        <torchlie.kinematics.ik.inverse_kinematics>`, which documents the options (``q0``,
        ``restarts``, weights, tolerances, ``max_iterations``, ``early_exit``, bounds,
        ``generator``) and the method.  ``targets``: poses ``(..., 4, 4)`` or positions
        ``(..., 3)``, or a dict link -> targets (then ``link`` is None).

        Returns:
            :class:`~torchlie.kinematics.IKResult` ``(q, position_error, rotation_error,
            converged, iterations)``, ``q`` of shape ``(..., n_dof)``, the others ``(...)``.

        Example:
            >>> from torchlie.kinematics import sample_robot
            >>> arm = Chain.from_urdf(sample_robot("arm7"))
            >>> q = arm.random_configuration(3, generator=torch.Generator().manual_seed(1))
            >>> p = arm.forward_kinematics(q, "tool_tcp")["tool_tcp"][:, :3, 3]
            >>> res = arm.inverse_kinematics(p, "tool_tcp", restarts=2)  # positions only
            >>> res.q.shape, res.converged.tolist()
            (torch.Size([3, 7]), [True, True, True])
        """
        from .ik import inverse_kinematics

        return inverse_kinematics(self, targets, link, **options)

    # ------------------------------------------------------------------------------------------
    # Dynamics (conventions and method in torchlie.kinematics.dynamics)
    # ------------------------------------------------------------------------------------------

    @property
    def body_names(self) -> tuple[str, ...]:
        """The bodies of the dynamics: the links moved by a joint with degrees of freedom, in
        the order of :attr:`inertials` (links on fixed joints are merged into them).  In MJCF
        chains the frames between several joints of one body (``"{body}:{joint}"``, not in
        :attr:`link_names`) are bodies too, with zero inertials; wrenches (``f_ext``) name the
        MJCF body itself.

        Example:
            >>> from torchlie.kinematics import sample_robot
            >>> Chain.from_urdf(sample_robot("arm7")).body_names[-1]
            'link7'
        """
        return _dyn._body_names(self)

    @property
    def inertials(self) -> Inertials:
        """The bodies' inertial parameters from the URDF's ``<inertial>`` elements (MJCF:
        MuJoCo's compiled ``body_mass``, ``body_ipos``, ``body_iquat``, ``body_inertia``; SDF:
        not read, zero), merged
        through fixed joints, and the joints' armature per velocity coordinate (MJCF: MuJoCo's
        compiled ``dof_armature``; URDF and SDF have none: 0), as fresh tensors in the chain's
        dtype and device: :class:`~torchlie.kinematics.dynamics.Inertials` ``(mass, com,
        inertia, armature)``.  Change them, or make them require gradients, and pass them back
        as ``inertials=`` to the dynamics methods.

        Example:
            >>> from torchlie.kinematics import sample_robot
            >>> arm = Chain.from_urdf(sample_robot("arm7"), dtype=torch.float64)
            >>> round(float(arm.inertials.mass[-1]), 3)  # link7 with its flange
            0.6
        """
        return _dyn._inertials(self)

    @_checks.float32_exact
    def inverse_dynamics(
        self,
        q: Float[Tensor, "*b n_dof"],
        qd: Float[Tensor, "*b n_v"],
        qdd: Float[Tensor, "*b n_v"],
        *,
        gravity: Tensor | None = None,
        f_ext: Mapping[str, Tensor] | None = None,
        inertials: Inertials | None = None,
    ) -> Float[Tensor, "*b n_v"]:
        """Joint torques (forces for prismatic joints) producing the motion ``(q, qd, qdd)``:
        recursive Newton-Euler, ``tau = M(q) qdd + h(q, qd) - sum J^T f_ext``.

        Args:
            q, qd, qdd: ``(..., n_dof)`` positions, ``(..., n_v)`` velocities and
                accelerations (:attr:`velocity_names`: ``n_v = n_dof`` but for the quaternion
                joints of MJCF chains; ``qd``, ``qdd`` broadcast to ``q``'s batch shape).
            gravity: ``(3,)`` or ``(..., 3)`` acceleration of free fall in the root frame
                (default ``(0, 0, -9.81)``).
            f_ext: dict link name -> ``(..., 6)`` wrench (force; torque) on the link, world
                coordinates, torque about the link's origin.
            inertials: other inertial parameters (default :attr:`inertials`).

        Example:
            >>> from torchlie.kinematics import sample_robot
            >>> arm = Chain.from_urdf(sample_robot("arm7"))
            >>> q = torch.zeros(4, 7)
            >>> arm.inverse_dynamics(q, q, q).shape  # holding still against gravity
            torch.Size([4, 7])
        """
        return _dyn._inverse_dynamics(
            self, q, qd, qdd, gravity=gravity, f_ext=f_ext, inertials=inertials
        )

    @_checks.float32_exact
    def mass_matrix(
        self, q: Float[Tensor, "*b n_dof"], *, inertials: Inertials | None = None
    ) -> Float[Tensor, "*b n_v n_v"]:
        """Joint-space mass matrix ``M(q)`` ``(..., n_v, n_v)`` (composite rigid bodies).

        Example:
            >>> from torchlie.kinematics import sample_robot
            >>> arm = Chain.from_urdf(sample_robot("arm7"))
            >>> M = arm.mass_matrix(torch.zeros(7))
            >>> M.shape, bool(torch.allclose(M, M.mT))
            (torch.Size([7, 7]), True)
        """
        return _dyn._mass_matrix(self, q, inertials=inertials)

    @_checks.float32_exact
    def forward_dynamics(
        self,
        q: Float[Tensor, "*b n_dof"],
        qd: Float[Tensor, "*b n_v"],
        tau: Float[Tensor, "*b n_v"],
        *,
        gravity: Tensor | None = None,
        f_ext: Mapping[str, Tensor] | None = None,
        inertials: Inertials | None = None,
    ) -> Float[Tensor, "*b n_v"]:
        """Joint accelerations under the joint forces ``tau``: ``M(q)^-1 (tau - h(q, qd) +
        sum J^T f_ext)`` by a batched Cholesky solve.  Arguments as for
        :meth:`inverse_dynamics`.

        The chain's own inertials are checked once: a DoF without armature that moves neither
        mass nor inertia (a translation: no mass) makes ``M`` singular at every state and
        raises.  Where ``M(q)`` is not positive definite otherwise (inertials given with
        ``inertials=``, or ones that leave a joint no inertia about its axis in some
        configuration: a point mass on the axis, a thin rod along it), the accelerations of
        that state are NaN.

        Raises:
            ValueError: a DoF moves nothing that resists its motion (``M`` singular).

        Example:
            >>> from torchlie.kinematics import sample_robot
            >>> arm = Chain.from_urdf(sample_robot("arm7"), dtype=torch.float64)
            >>> q = arm.random_configuration(3)
            >>> qd, qdd = torch.randn(2, 3, 7, dtype=torch.float64)
            >>> tau = arm.inverse_dynamics(q, qd, qdd)
            >>> bool(torch.allclose(arm.forward_dynamics(q, qd, tau), qdd))
            True
        """
        return _dyn._forward_dynamics(
            self, q, qd, tau, gravity=gravity, f_ext=f_ext, inertials=inertials
        )

    @_checks.float32_exact
    def bias_forces(
        self,
        q: Float[Tensor, "*b n_dof"],
        qd: Float[Tensor, "*b n_v"],
        *,
        gravity: Tensor | None = None,
        inertials: Inertials | None = None,
    ) -> Float[Tensor, "*b n_v"]:
        """Coriolis, centrifugal and gravity forces ``h(q, qd)`` (inverse dynamics at
        ``qdd = 0``; Pinocchio's ``nonLinearEffects``).

        Example:
            >>> from torchlie.kinematics import sample_robot
            >>> arm = Chain.from_urdf(sample_robot("arm7"))
            >>> arm.bias_forces(torch.zeros(7), torch.ones(7)).shape
            torch.Size([7])
        """
        return _dyn._inverse_dynamics(
            self, q, qd, None, gravity=gravity, inertials=inertials, _fn="bias_forces"
        )

    @_checks.float32_exact
    def gravity_torques(
        self,
        q: Float[Tensor, "*b n_dof"],
        *,
        gravity: Tensor | None = None,
        inertials: Inertials | None = None,
    ) -> Float[Tensor, "*b n_v"]:
        """Joint forces holding the robot still against gravity, ``g(q)`` (Pinocchio's
        ``computeGeneralizedGravity``).

        Example:
            >>> from torchlie.kinematics import sample_robot
            >>> arm = Chain.from_urdf(sample_robot("arm7"))
            >>> float(arm.gravity_torques(torch.zeros(7))[0])  # the base yaw axis is vertical
            0.0
        """
        return _dyn._inverse_dynamics(
            self, q, None, None, gravity=gravity, inertials=inertials, _fn="gravity_torques"
        )
