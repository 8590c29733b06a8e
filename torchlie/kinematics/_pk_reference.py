"""pytorch-kinematics as a reference for :mod:`torchlie.kinematics.validate`: its chain of the
robot, fed torchlie's configurations, and the report's lines on where it departs from URDF.

Apart from the validation because it is one reference library's adapter: it knows
pytorch-kinematics' API and its deviations from URDF (see :mod:`torchlie.kinematics.validate`),
and nothing of the comparison or the report.  pytorch-kinematics is optional: it is imported
when a validation asks for it.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Iterable

import torch
from torch import Tensor

from ._joints import _resolve_mimics
from .chain import Chain
from .urdf import RobotSpec, _some

#: Tolerance against pytorch-kinematics (times ``1 + reach`` for positions and Jacobians): it
#: parses origins and computes in float32.
TOL_PK = 1e-5


def _import_pk():
    try:
        import pytorch_kinematics as pk
    except ImportError:
        return None
    return pk


def _pk_version() -> str:
    try:
        from importlib.metadata import version

        return version("pytorch_kinematics")
    except Exception:  # pragma: no cover - metadata missing
        return "?"


def _pk_text(text: bytes) -> str:
    """URDF text for pytorch-kinematics: explicit axes, floating/planar joints made fixed."""
    root = ET.fromstring(text)
    for el in root:
        if str(el.tag).rsplit("}", 1)[-1] != "joint":
            continue
        jtype = el.get("type")
        if jtype in ("floating", "planar"):
            el.set("type", "fixed")
        elif jtype in ("revolute", "continuous", "prismatic"):
            if not any(str(c.tag).rsplit("}", 1)[-1] == "axis" for c in el):
                ET.SubElement(el, "axis", {"xyz": "1 0 0"})
    return ET.tostring(root, encoding="unicode")


class _PK:
    """pytorch-kinematics' chain of the robot, fed expanded joint values."""

    def __init__(self, pk, spec: RobotSpec, chain: Chain, text: bytes) -> None:
        import contextlib
        import io
        import warnings

        # Its URDF reader prints a line to stderr for every element it does not know.
        with warnings.catch_warnings(), contextlib.redirect_stderr(io.StringIO()):
            warnings.simplefilter("ignore")
            self.chain = pk.build_chain_from_urdf(_pk_text(text))
        self.pk = pk
        self.names = list(self.chain.get_joint_parameter_names())
        # q_pk = q @ E^T + b (mimic joints are independent joints for pk).
        n = chain.n_dof
        self.E = torch.zeros(len(self.names), n, dtype=torch.float64)
        self.b = torch.zeros(len(self.names), dtype=torch.float64)
        dof = {name: i for i, name in enumerate(chain.joint_names)}
        mimic = _resolve_mimics(spec, dof)  # name -> (DoF, mult, off), chains composed
        for k, name in enumerate(self.names):
            d, mult, off = mimic[name] if name in mimic else (dof[name], 1.0, 0.0)
            self.E[k, d] = mult
            self.b[k] = off
        self._serial: dict[str, tuple[object, Tensor]] = {}

    def values(self, q64: Tensor) -> Tensor:
        return (q64 @ self.E.T + self.b).to(torch.float32)

    def fk(self, th: Tensor) -> dict[str, Tensor]:
        return {k: v.get_matrix() for k, v in self.chain.forward_kinematics(th).items()}

    def serial(self, link: str):
        if link not in self._serial:
            s = self.pk.SerialChain(self.chain, link)
            names = s.get_joint_parameter_names()
            idx = torch.tensor([self.names.index(n) for n in names], dtype=torch.long)
            self._serial[link] = (s, idx)
        return self._serial[link]

    def jacobian(self, th: Tensor, link: str) -> Tensor:
        """``(B, 6, n_dof)`` in torchlie's DoFs (mimic columns folded in with ``E``)."""
        s, idx = self.serial(link)
        Js = s.jacobian(th[:, idx]).to(torch.float64)  # (B, 6, n_serial)
        full = Js.new_zeros(th.shape[0], 6, len(self.names))
        full[:, :, idx] = Js
        return full @ self.E


def _pk_setup(
    spec: RobotSpec,
    chain: Chain,
    text: bytes,
    compare_pk: bool,
    free: Iterable[str],
    tol_ref: float,
    scale: float,
) -> tuple[_PK | None, str | None, list[str]]:
    """pytorch-kinematics' chain of the robot (None: not compared), its version (None: not
    installed or not asked for) and the report's lines on its deviations from URDF; ``free``:
    the links below floating and planar joints, ``tol_ref`` and ``scale`` the reference's
    tolerance and ``1 + reach``."""
    pk = _import_pk() if compare_pk else None
    pkc: _PK | None = None
    version: str | None = None
    deviations: list[str] = []
    if pk is not None:
        version = _pk_version()
        try:
            pkc = _PK(pk, spec, chain, text)
        except Exception as e:  # pk cannot load it: not torchlie's failure
            deviations.append(
                f"pytorch_kinematics could not load this URDF ({type(e).__name__}: {e}); "
                "compared with the float64 reference only"
            )
    elif compare_pk:
        deviations.append(
            "pytorch_kinematics is not installed (pip install 'torchlie[validate]'): compared "
            "with the float64 reference only"
        )
    if pkc is not None:
        mimics = [j for j in spec.joints if j.mimic is not None]
        if mimics:
            desc = _some(
                [
                    f"{j.name} = {j.mimic.multiplier:g} * {j.mimic.joint} + {j.mimic.offset:g}"
                    for j in mimics
                    if j.mimic is not None
                ],
                quote=False,
            )
            deviations.append(
                f"pk ignores <mimic> (it makes them independent joints): it was given the "
                f"expanded values {desc}, and its Jacobian columns were folded accordingly"
            )
        no_axis = [
            j.name
            for j in spec.joints
            if not j.axis_given and j.type in ("revolute", "continuous", "prismatic")
        ]
        if no_axis:
            deviations.append(
                "pk reads an omitted <axis> as +Z (URDF: +X): its copy has axis '1 0 0' written "
                f"out for {_some(no_axis, quote=False)}"
            )
        free_joints = [j.name for j in spec.joints if j.type in ("floating", "planar")]
        if free_joints:
            deviations.append(
                "pk cannot load floating or planar joints: they are fixed joints in its copy "
                f"({_some(free_joints, quote=False)}); the links below them "
                f"({_some(list(free), quote=False)}) are "
                "compared with the float64 reference only"
            )
        deviations.append(
            "pk parses origins and computes in float32: compared at "
            f"{TOL_PK:g} (x {scale:.2f} for positions and Jacobians), the float64 reference "
            f"at {tol_ref:g}"
        )
    return pkc, version, deviations
