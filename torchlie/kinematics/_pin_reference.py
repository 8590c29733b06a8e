"""Pinocchio as a reference for :mod:`torchlie.kinematics.validate`: its model of the robot,
fed torchlie's configurations with its conventions mapped onto torchlie's, and the report's
lines on what it cannot compare.

Apart from the validation because it is one reference library's adapter: it knows Pinocchio's
API and conventions (frames, configuration and velocity layouts, mimic joints; see
:mod:`torchlie.kinematics.validate`), and nothing of the comparison or the report.  Pinocchio
is optional: it is imported when a validation asks for it.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from .. import so3
from ._joints import _resolve_mimics
from .chain import Chain
from .urdf import RobotSpec, _some

#: Pinocchio's reference frames for torchlie's Jacobian kinds (``Chain.jacobian(frame=...)``).
PIN_FRAMES = {"world": "LOCAL_WORLD_ALIGNED", "link": "LOCAL", "spatial": "WORLD"}


def _import_pin():
    try:
        import pinocchio as pin
    except ImportError:
        return None
    return pin


class _Pin:
    """Pinocchio's model of the robot (float64, one configuration at a time), fed torchlie's
    configurations: ``q`` converted to its layout and its Jacobian columns to torchlie's DoFs
    (see :mod:`torchlie.kinematics.validate`)."""

    def __init__(self, pin, spec: RobotSpec, chain: Chain, text: bytes) -> None:
        self.pin = pin
        self.model = pin.buildModelFromXML(text.decode("utf-8"))
        self.data = self.model.createData()
        self.n = chain.n_dof
        dof = {name: i for i, name in enumerate(chain.joint_names)}
        mimic = _resolve_mimics(spec, dof)
        by_name = {j.name: j for j in spec.joints}
        # Per Pinocchio joint: (kind, idx_q, idx_v, first DoF, multiplier, offset).
        self.joints: list[tuple[str, int, int, int, float, float]] = []
        self.skipped: list[str] = []  # joints Pinocchio does not model as URDF says
        for i in range(1, self.model.njoints):
            name = self.model.names[i]
            jm = self.model.joints[i]
            j = by_name[name]
            if j.type == "floating":
                entry = ("free", dof[f"{name}:x"], 1.0, 0.0)
            elif j.type == "planar":
                entry = ("planar", dof[f"{name}:x"], 1.0, 0.0)
                if tuple(_unit_axis(j.axis)) != (0.0, 0.0, 1.0):
                    self.skipped.append(name)  # Pinocchio's planar joint is in its xy plane
            else:
                d, mult, off = mimic[name] if name in mimic else (dof[name], 1.0, 0.0)
                entry = ("circle" if j.type == "continuous" else "scalar", d, mult, off)
            kind, d, mult, off = entry
            self.joints.append((kind, jm.idx_q, jm.idx_v, d, mult, off))
        self.frames = {
            link: self.model.getFrameId(link, pin.FrameType.BODY)
            for link in spec.links
            if self.model.existFrame(link, pin.FrameType.BODY)
        }

    def _q_and_map(self, q: Tensor):
        """Pinocchio's ``q`` for torchlie's ``q (n_dof,)`` and ``D (nv, n_dof)`` with
        ``v_pin = D dq``."""
        import numpy as np

        qp = np.zeros(self.model.nq)
        D = np.zeros((self.model.nv, self.n))
        x = q.tolist()
        for kind, iq, iv, d, mult, off in self.joints:
            if kind in ("scalar", "circle"):
                v = mult * x[d] + off
                if kind == "scalar":
                    qp[iq] = v
                else:  # a unit complex number (cos, sin)
                    qp[iq : iq + 2] = (math.cos(v), math.sin(v))
                D[iv, d] += mult
            elif kind == "planar":  # (x, y, cos, sin); velocity in the moving frame
                c, s = math.cos(x[d + 2]), math.sin(x[d + 2])
                qp[iq : iq + 4] = (x[d], x[d + 1], c, s)
                D[iv : iv + 2, d : d + 2] = ((c, s), (-s, c))
                D[iv + 2, d + 2] = 1.0
            else:  # free flyer: (t, quaternion xyzw); velocity (R^T dt, Jr(r) dr)
                r = q[d + 3 : d + 6]
                R = so3.exp(r)
                qp[iq : iq + 3] = x[d : d + 3]
                qp[iq + 3 : iq + 7] = self.pin.Quaternion(R.numpy()).coeffs()
                D[iv : iv + 3, d : d + 3] = R.T.numpy()
                D[iv + 3 : iv + 6, d + 3 : d + 6] = so3.jac_right(r).numpy()
        return qp, D

    def evaluate(
        self, q64: Tensor, links: list[str], leaves: list[str]
    ) -> tuple[dict[str, Tensor], dict[tuple[str, str], Tensor]]:
        """Poses ``(B, 4, 4)`` of ``links`` and Jacobians ``(B, 6, n_dof)`` of ``leaves`` per
        kind, in torchlie's conventions."""
        import numpy as np

        pin, model, data = self.pin, self.model, self.data
        poses = {k: np.zeros((q64.shape[0], 4, 4)) for k in links if k in self.frames}
        jacs = {
            (k, kind): np.zeros((q64.shape[0], 6, self.n))
            for k in leaves
            if k in self.frames
            for kind in PIN_FRAMES
        }
        for b in range(q64.shape[0]):
            qp, D = self._q_and_map(q64[b])
            pin.framesForwardKinematics(model, data, qp)
            pin.computeJointJacobians(model, data, qp)
            for k, P in poses.items():
                P[b] = data.oMf[self.frames[k]].homogeneous
            for (k, kind), J in jacs.items():
                ref = getattr(pin.ReferenceFrame, PIN_FRAMES[kind])
                J[b] = pin.getFrameJacobian(model, data, self.frames[k], ref) @ D
        return (
            {k: torch.from_numpy(v) for k, v in poses.items()},
            {k: torch.from_numpy(v) for k, v in jacs.items()},
        )

    def has_moving_map(self) -> bool:
        """Whether ``D`` depends on ``q`` (a planar or floating joint): then Pinocchio's
        acceleration is ``D qdd + (dD/dt) qd``."""
        return any(kind in ("planar", "free") for kind, *_ in self.joints)

    def _d_dot_qd(self, q: Tensor, qd: Tensor):
        """``(dD/dt) qd`` by a 4th-order central difference of ``D`` along ``qd`` (``D`` is
        smooth; a step of at most 1e-3 in ``q``, whose error is far below float64's round-off
        of the dynamics, whatever the size of ``qd``)."""
        import numpy as np

        if not self.has_moving_map():
            return np.zeros(self.model.nv)
        h = 1e-3 / max(1.0, float(qd.abs().max()))
        Ds = [self._q_and_map(q + k * h * qd)[1] for k in (-2, -1, 1, 2)]
        dD = (Ds[0] - 8.0 * Ds[1] + 8.0 * Ds[2] - Ds[3]) / (12.0 * h)
        return dD @ qd.numpy()

    def dynamics(
        self,
        q64: Tensor,
        qd64: Tensor,
        qdd64: Tensor,
        gravity=None,
        derivatives: bool = True,
        aba: bool = True,
    ) -> dict[str, Tensor]:
        """Pinocchio's inverse dynamics, mass matrix, bias and gravity forces in torchlie's
        coordinates (``tau = D^T tau_pin`` at ``v = D qd``, ``a = D qdd + (dD/dt) qd``), the
        accelerations for ``tau = inverse dynamics`` by its ABA (with ``aba``, where ``D`` is
        square) and the RNEA derivatives (with ``derivatives``, where ``D`` is constant), per
        configuration."""
        import numpy as np

        pin, model, data = self.pin, self.model, self.data
        if gravity is not None:
            model.gravity.linear = np.asarray(gravity, dtype=float)
        B, n = q64.shape[0], self.n
        out = {k: np.zeros((B, n)) for k in ("tau", "bias", "gravity", "aba")}
        out["M"] = np.zeros((B, n, n))
        out["dtau_dq"] = np.zeros((B, n, n))
        out["dtau_dqd"] = np.zeros((B, n, n))
        square = model.nv == n
        for b in range(B):
            qp, D = self._q_and_map(q64[b])
            v = D @ qd64[b].numpy()
            c = self._d_dot_qd(q64[b], qd64[b])
            a = D @ qdd64[b].numpy() + c
            tau_p = pin.rnea(model, data, qp, v, a).copy()
            out["tau"][b] = D.T @ tau_p
            Mp = pin.crba(model, data, qp).copy()
            Mp = np.triu(Mp) + np.triu(Mp, 1).T
            out["M"][b] = D.T @ Mp @ D
            out["bias"][b] = D.T @ (pin.nonLinearEffects(model, data, qp, v) + Mp @ c)
            out["gravity"][b] = D.T @ pin.computeGeneralizedGravity(model, data, qp)
            if aba and square:
                ap = pin.aba(model, data, qp, v, tau_p)
                out["aba"][b] = np.linalg.solve(D, ap - c)
            if derivatives and not self.has_moving_map():
                dq, dv, _ = pin.computeRNEADerivatives(model, data, qp, v, a)
                out["dtau_dq"][b] = D.T @ dq @ D
                out["dtau_dqd"][b] = D.T @ dv @ D
        if gravity is not None:
            model.gravity.linear = np.array([0.0, 0.0, -9.81])
        return {k: torch.from_numpy(v) for k, v in out.items()}


def _unit_axis(axis) -> list[float]:
    n = math.hypot(*axis)
    return [x / n + 0.0 for x in axis]


def _pin_version() -> str:
    try:
        from importlib.metadata import version

        return version("pin")
    except Exception:  # pragma: no cover - metadata missing
        return "?"


def _pin_setup(
    spec: RobotSpec, chain: Chain, text: bytes, compare_pin: bool
) -> tuple[_Pin | None, str | None, list[str]]:
    """Pinocchio's model of the robot (None: not compared), its version (None: not compared)
    and the report's lines on how it is compared, or why not."""
    pin = _import_pin() if compare_pin else None
    if pin is None:
        why = "Pinocchio is not installed (pip install 'torchlie[pinocchio]'): not compared"
        return None, None, [why] if compare_pin else []
    try:
        pinc = _Pin(pin, spec, chain, text)
    except Exception as e:  # Pinocchio cannot load it: not torchlie's failure
        why = f"Pinocchio could not load this URDF ({type(e).__name__}: {e}); not compared"
        return None, None, [why]
    deviations: list[str] = []
    if any(j.mimic is not None for j in spec.joints):
        deviations.append(
            "Pinocchio's URDF reader (mimic=False) makes mimic joints independent: it was given "
            "the expanded values, and its Jacobian columns were folded accordingly"
        )
    if pinc.skipped:
        deviations.append(
            "Pinocchio's planar joint moves in its xy plane only: "
            f"{_some(pinc.skipped, quote=False)} "
            "(another axis) and the links below are not compared with it"
        )
    deviations.append(
        "Pinocchio computes in float64 from its own parse of the file; q and Jacobian columns "
        "are mapped to torchlie's layout (see the module docstring)"
    )
    return pinc, _pin_version(), deviations
