"""Peer adapters: the same op, on the same inputs, in each peer library's own conventions.

An :class:`Adapter` maps torchlie's inputs to the peer's native representation once, outside
the timed region (``prepare``: wxyz -> xyzw quaternions, 4x4 pose -> the peer's pose object's
tensors, ...), times only the peer's call (``fn``, written as a user of that library writes it,
object construction from plain tensors included), and maps the output back for the agreement
check (``to_ours``, untimed).  ``fn`` returns a tensor or a tuple of tensors.

Representations (stated in the report, since they change the bytes an op touches):

* RoMa: quaternions xyzw; rigid motions ``roma.Rigid(R, t)``; no SE(3) exp/log.
* Kornia: conversions functions on wxyz quaternions; ``Quaternion``, ``So3``, ``Se3`` modules
  (``Se3`` = wxyz quaternion + translation).
* PyPose: ``LieTensor``; SO3 = xyzw quaternion, SE3 = 7-vector ``(t, q_xyzw)``; matrix -> SO3
  with ``pp.mat2SO3(R, check=False)``.
* pytorch-kinematics: functional transforms (wxyz quaternions, PyTorch3D-derived so3 maps) and
  ``Transform3d`` (4x4 matrices, column vectors) for rigid motions.
* scipy: ``scipy.spatial.transform.Rotation`` (numpy, float64 only); a reference row, not a
  torch peer: forward only, N <= 1000, excluded from the targets.

Left out: Theseus' torchlie (published under the import name ``torchlie``, it cannot share a
process with this project), PyTorch3D (no wheel for this torch on PyPI), lietorch (CUDA build
only), jaxlie (JAX, not torch).
"""

from __future__ import annotations

import importlib
import importlib.metadata
from collections.abc import Callable
from dataclasses import dataclass, field

import torch
from torch import Tensor

PEERS = ("roma", "kornia", "pypose", "pytorch_kinematics", "scipy")
REFERENCE_PEERS = ("scipy",)
SHORT = {"pytorch_kinematics": "pk"}


@dataclass(frozen=True)
class Adapter:
    """One peer's call for one op (see the module docstring)."""

    peer: str
    call: str
    prepare: Callable[..., tuple]
    fn: Callable[..., Tensor | tuple[Tensor, ...]]
    to_ours: Callable[..., Tensor]
    differentiable: bool = True
    max_n: int | None = None
    notes: str = field(default="")

    @property
    def reference(self) -> bool:
        return self.peer in REFERENCE_PEERS


def version(peer: str) -> str | None:
    """The installed version of a peer, or ``None`` if it cannot be imported."""
    try:
        mod = importlib.import_module(peer)
    except Exception:
        return None
    try:
        return importlib.metadata.version(peer)
    except importlib.metadata.PackageNotFoundError:
        return str(getattr(mod, "__version__", "?"))


# ----------------------------------------------------------------------------------------------
# Convention helpers (untimed)
# ----------------------------------------------------------------------------------------------


def xyzw(q: Tensor) -> Tensor:
    return torch.cat((q[..., 1:], q[..., :1]), dim=-1)


def wxyz(q: Tensor) -> Tensor:
    return torch.cat((q[..., 3:], q[..., :3]), dim=-1)


def _split(T: Tensor) -> tuple[Tensor, Tensor]:
    return T[..., :3, :3].contiguous(), T[..., :3, 3].contiguous()


def _join(R: Tensor, t: Tensor) -> Tensor:
    top = torch.cat((R, t.unsqueeze(-1)), dim=-1)
    bottom = torch.zeros_like(top[..., :1, :])
    bottom[..., 3] = 1.0
    return torch.cat((top, bottom), dim=-2)


def _first(x):
    return x[0] if isinstance(x, tuple) else x


def _ident(*xs):
    return xs


# ----------------------------------------------------------------------------------------------
# RoMa
# ----------------------------------------------------------------------------------------------


def _roma() -> dict[str, Adapter]:
    import roma

    def quat_in(q, *rest):
        return (xyzw(q), *rest)

    def rigid_in(T, *rest):
        return (*_split(T), *rest)

    return {
        "so3.exp": Adapter(
            "roma", "roma.rotvec_to_rotmat(w)", _ident, roma.rotvec_to_rotmat, _first
        ),
        "so3.log": Adapter(
            "roma", "roma.rotmat_to_rotvec(R)", _ident, roma.rotmat_to_rotvec, _first
        ),
        "quat.to_matrix": Adapter(
            "roma", "roma.unitquat_to_rotmat(q_xyzw)", quat_in, roma.unitquat_to_rotmat, _first
        ),
        "quat.from_matrix": Adapter(
            "roma", "roma.rotmat_to_unitquat(R)", _ident, roma.rotmat_to_unitquat, wxyz
        ),
        "quat.multiply": Adapter(
            "roma",
            "roma.quat_product(q1_xyzw, q2_xyzw)",
            lambda a, b: (xyzw(a), xyzw(b)),
            roma.quat_product,
            wxyz,
        ),
        "quat.apply": Adapter(
            "roma",
            "roma.quat_action(q_xyzw, p, is_normalized=True)",
            quat_in,
            lambda q, p: roma.quat_action(q, p, is_normalized=True),
            _first,
        ),
        "so3.act": Adapter(
            "roma",
            "roma.Rotation(R).apply(p)",
            _ident,
            lambda R, p: roma.Rotation(R).apply(p),
            _first,
        ),
        "se3.compose": Adapter(
            "roma",
            "roma.Rigid(R1, t1).compose(roma.Rigid(R2, t2))",
            lambda T1, T2: (*_split(T1), *_split(T2)),
            lambda R1, t1, R2, t2: roma.Rigid(R1, t1).compose(roma.Rigid(R2, t2)).as_tuple(),
            lambda out: _join(*out),
        ),
        "se3.inverse": Adapter(
            "roma",
            "roma.Rigid(R, t).inverse()",
            rigid_in,
            lambda R, t: roma.Rigid(R, t).inverse().as_tuple(),
            lambda out: _join(*out),
        ),
        "se3.act": Adapter(
            "roma",
            "roma.Rigid(R, t).apply(p)",
            rigid_in,
            lambda R, t, p: roma.Rigid(R, t).apply(p),
            _first,
        ),
    }


# ----------------------------------------------------------------------------------------------
# Kornia
# ----------------------------------------------------------------------------------------------


def _kornia() -> dict[str, Adapter]:
    import kornia.geometry.conversions as kc
    from kornia.geometry.liegroup import Se3, So3
    from kornia.geometry.quaternion import Quaternion

    def se3_in(T, *rest):
        s = Se3.from_matrix(T.detach())
        return (s.so3.q.data.detach().contiguous(), s.t.detach().contiguous(), *rest)

    def se3_out(out):
        q, t = out
        return Se3(So3(Quaternion(q.detach())), t.detach()).matrix()

    def se3_tensors(s):
        return s.so3.q.data, s.t

    return {
        "so3.exp": Adapter(
            "kornia", "kc.axis_angle_to_rotation_matrix(w)", _ident,
            kc.axis_angle_to_rotation_matrix, _first,
        ),
        "so3.log": Adapter(
            "kornia", "kc.rotation_matrix_to_axis_angle(R)", _ident,
            kc.rotation_matrix_to_axis_angle, _first,
        ),
        "quat.to_matrix": Adapter(
            "kornia", "kc.quaternion_to_rotation_matrix(q)", _ident,
            kc.quaternion_to_rotation_matrix, _first,
        ),
        "quat.from_matrix": Adapter(
            "kornia", "kc.rotation_matrix_to_quaternion(R)", _ident,
            kc.rotation_matrix_to_quaternion, _first,
        ),
        "quat.multiply": Adapter(
            "kornia", "(Quaternion(q1) * Quaternion(q2)).data", _ident,
            lambda a, b: (Quaternion(a) * Quaternion(b)).data, _first,
        ),
        "quat.apply": Adapter(
            "kornia", "So3(Quaternion(q)) * p", _ident,
            lambda q, p: So3(Quaternion(q)) * p, _first,
        ),
        "se3.exp": Adapter(
            "kornia", "Se3.exp(xi)", _ident, lambda xi: se3_tensors(Se3.exp(xi)), se3_out,
        ),
        "se3.log": Adapter(
            "kornia", "Se3(Quaternion(q), t).log()", se3_in,
            lambda q, t: Se3(Quaternion(q), t).log(), _first,
        ),
        "se3.compose": Adapter(
            "kornia", "Se3(q1, t1) * Se3(q2, t2)",
            lambda T1, T2: (*se3_in(T1), *se3_in(T2)),
            lambda q1, t1, q2, t2: se3_tensors(Se3(Quaternion(q1), t1) * Se3(Quaternion(q2), t2)),
            se3_out,
        ),
        "se3.inverse": Adapter(
            "kornia", "Se3(Quaternion(q), t).inverse()", se3_in,
            lambda q, t: se3_tensors(Se3(Quaternion(q), t).inverse()), se3_out,
        ),
        "se3.act": Adapter(
            "kornia", "Se3(Quaternion(q), t) * p", se3_in,
            lambda q, t, p: Se3(Quaternion(q), t) * p, _first,
        ),
        **_kornia_planar(),
    }  # fmt: skip


def _kornia_planar() -> dict[str, Adapter]:
    """Kornia's So2 (a unit complex number) and Se2 (an So2 and a translation)."""
    from kornia.geometry.liegroup import Se2, So2

    # the complex numbers travel as real (..., 2) views (view_as_complex is free), so that
    # the backward pass reaches a real leaf
    def so2_in(R, *rest):
        return (torch.view_as_real(So2.from_matrix(R.detach()).z.detach()).contiguous(), *rest)

    def se2_in(T, *rest):
        s = Se2.from_matrix(T.detach())
        z = torch.view_as_real(s.so2.z.detach()).contiguous()
        return (z, s.t.detach().contiguous(), *rest)

    cplx = torch.view_as_complex

    def se2_out(out):
        z, t = out
        return Se2(So2(z.detach()), t.detach()).matrix()

    return {
        "so2.exp": Adapter(
            "kornia", "So2.exp(theta).z", lambda t: (t[..., 0],), lambda t: So2.exp(t).z,
            lambda z: So2(z.detach()).matrix(),
        ),
        "so2.log": Adapter(
            "kornia", "So2(z).log()", so2_in, lambda z: So2(cplx(z)).log(), lambda t: t[..., None],
        ),
        "se2.exp": Adapter(
            "kornia", "Se2.exp(xi)", _ident, lambda xi: (lambda s: (s.so2.z, s.t))(Se2.exp(xi)),
            se2_out,
        ),
        "se2.log": Adapter(
            "kornia", "Se2(So2(z), t).log()", se2_in, lambda z, t: Se2(So2(cplx(z)), t).log(),
            _first,
        ),
    }  # fmt: skip


# ----------------------------------------------------------------------------------------------
# PyPose
# ----------------------------------------------------------------------------------------------


def _pypose() -> dict[str, Adapter]:
    import pypose as pp

    def se3_in(T, *rest):
        return (pp.mat2SE3(T.detach(), check=False).tensor().contiguous(), *rest)

    def se3_out(x):
        return pp.SE3(x.detach()).matrix()

    def sim3_in(T, *rest):
        # PyPose stores (t, q_xyzw, s); the scale as |M| / sqrt(3), q from M / s
        M = T[..., :3, :3]
        s = M.square().sum((-1, -2)).div(3.0).sqrt()
        R = M / s[..., None, None]
        q = pp.mat2SO3(R, check=False).tensor()
        return (torch.cat((T[..., :3, 3], q, s[..., None]), -1).contiguous(), *rest)

    def plain(x):
        return x.tensor() if isinstance(x, pp.LieTensor) else x

    return {
        "so3.exp": Adapter(
            "pypose", "pp.so3(w).matrix()", _ident, lambda w: pp.so3(w).matrix(), _first,
        ),
        "so3.log": Adapter(
            "pypose", "pp.mat2SO3(R, check=False).Log()", _ident,
            lambda R: pp.mat2SO3(R, check=False).Log(), plain,
        ),
        "quat.to_matrix": Adapter(
            "pypose", "pp.SO3(q_xyzw).matrix()", lambda q: (xyzw(q),),
            lambda q: pp.SO3(q).matrix(), _first,
        ),
        "quat.from_matrix": Adapter(
            "pypose", "pp.mat2SO3(R, check=False)", _ident,
            lambda R: pp.mat2SO3(R, check=False), lambda q: wxyz(plain(q)),
        ),
        "quat.multiply": Adapter(
            "pypose", "pp.SO3(q1_xyzw) @ pp.SO3(q2_xyzw)",
            lambda a, b: (xyzw(a), xyzw(b)),
            lambda a, b: pp.SO3(a) @ pp.SO3(b), lambda q: wxyz(plain(q)),
        ),
        "quat.apply": Adapter(
            "pypose", "pp.SO3(q_xyzw).Act(p)", lambda q, p: (xyzw(q), p),
            lambda q, p: pp.SO3(q).Act(p), _first,
        ),
        "so3.act": Adapter("pypose", "pp.bmv(R, p)", _ident, pp.bmv, _first),
        "se3.exp": Adapter(
            "pypose", "pp.se3(xi).Exp()", _ident, lambda xi: pp.se3(xi).Exp(), se3_out,
        ),
        "se3.log": Adapter(
            "pypose", "pp.SE3(x).Log()", se3_in, lambda x: pp.SE3(x).Log(), plain,
        ),
        "se3.compose": Adapter(
            "pypose", "pp.SE3(x1) @ pp.SE3(x2)",
            lambda T1, T2: (*se3_in(T1), *se3_in(T2)),
            lambda a, b: pp.SE3(a) @ pp.SE3(b), se3_out,
        ),
        "se3.inverse": Adapter(
            "pypose", "pp.SE3(x).Inv()", se3_in, lambda x: pp.SE3(x).Inv(), se3_out,
        ),
        "sim3.exp": Adapter(
            "pypose", "pp.sim3(xi).Exp()", _ident, lambda xi: pp.sim3(xi).Exp(),
            lambda x: pp.Sim3(x.detach()).matrix(),
        ),
        "sim3.log": Adapter(
            "pypose", "pp.Sim3(x).Log()", sim3_in, lambda x: pp.Sim3(x).Log(), plain,
            notes="x = (t, q_xyzw, s), converted outside the timing (pp.mat2Sim3 allocates "
            "an N x N tensor)",
        ),
        "se3.act": Adapter(
            "pypose", "pp.SE3(x).Act(p)", se3_in, lambda x, p: pp.SE3(x).Act(p), _first,
        ),
    }  # fmt: skip


# ----------------------------------------------------------------------------------------------
# pytorch-kinematics
# ----------------------------------------------------------------------------------------------


def _pk() -> dict[str, Adapter]:
    import pytorch_kinematics.transforms as pt

    return {
        "so3.exp": Adapter(
            "pytorch_kinematics", "pt.so3_exp_map(w)", _ident, pt.so3_exp_map, _first,
        ),
        "so3.log": Adapter(
            "pytorch_kinematics", "pt.so3_log_map(R)", _ident, pt.so3_log_map, _first,
        ),
        "quat.to_matrix": Adapter(
            "pytorch_kinematics", "pt.quaternion_to_matrix(q)", _ident,
            pt.quaternion_to_matrix, _first,
        ),
        "quat.from_matrix": Adapter(
            "pytorch_kinematics", "pt.matrix_to_quaternion(R)", _ident,
            pt.matrix_to_quaternion, _first,
        ),
        "quat.multiply": Adapter(
            "pytorch_kinematics", "pt.quaternion_raw_multiply(q1, q2)", _ident,
            pt.quaternion_raw_multiply, _first,
        ),
        "quat.apply": Adapter(
            "pytorch_kinematics", "pt.quaternion_apply(q, p)", _ident,
            pt.quaternion_apply, _first,
        ),
        "se3.compose": Adapter(
            "pytorch_kinematics", "Transform3d(matrix=T1).compose(Transform3d(matrix=T2))",
            _ident,
            lambda A, B: pt.Transform3d(matrix=A).compose(pt.Transform3d(matrix=B)).get_matrix(),
            _first,
        ),
        "se3.inverse": Adapter(
            "pytorch_kinematics", "Transform3d(matrix=T).inverse()", _ident,
            lambda T: pt.Transform3d(matrix=T).inverse().get_matrix(), _first,
        ),
        "se3.act": Adapter(
            "pytorch_kinematics", "Transform3d(matrix=T).transform_points(p[:, None])",
            lambda T, p: (T, p.unsqueeze(-2)),
            lambda T, p: pt.Transform3d(matrix=T).transform_points(p),
            lambda out: out.squeeze(-2),
        ),
    }  # fmt: skip


# ----------------------------------------------------------------------------------------------
# scipy (reference row: numpy, forward only, N <= 1000)
# ----------------------------------------------------------------------------------------------


def _scipy() -> dict[str, Adapter]:
    from scipy.spatial.transform import Rotation

    def np_in(*xs):
        return tuple(x.detach().to(torch.float64).numpy() for x in xs)

    def np_xyzw_in(q, *rest):
        return np_in(xyzw(q), *rest)

    def to_t(x):
        return torch.from_numpy(x)

    def ref(call, prepare, fn, to_ours):
        return Adapter("scipy", call, prepare, fn, to_ours, differentiable=False, max_n=1000)

    return {
        "so3.exp": ref(
            "Rotation.from_rotvec(w).as_matrix()", np_in,
            lambda w: Rotation.from_rotvec(w).as_matrix(), to_t,
        ),
        "so3.log": ref(
            "Rotation.from_matrix(R).as_rotvec()", np_in,
            lambda R: Rotation.from_matrix(R).as_rotvec(), to_t,
        ),
        "quat.to_matrix": ref(
            "Rotation.from_quat(q_xyzw).as_matrix()", np_xyzw_in,
            lambda q: Rotation.from_quat(q).as_matrix(), to_t,
        ),
        "quat.from_matrix": ref(
            "Rotation.from_matrix(R).as_quat()", np_in,
            lambda R: Rotation.from_matrix(R).as_quat(), lambda q: wxyz(to_t(q)),
        ),
        "quat.multiply": ref(
            "(Rotation.from_quat(q1) * Rotation.from_quat(q2)).as_quat()",
            lambda a, b: np_in(xyzw(a), xyzw(b)),
            lambda a, b: (Rotation.from_quat(a) * Rotation.from_quat(b)).as_quat(),
            lambda q: wxyz(to_t(q)),
        ),
        "quat.apply": ref(
            "Rotation.from_quat(q_xyzw).apply(p)", np_xyzw_in,
            lambda q, p: Rotation.from_quat(q).apply(p), to_t,
        ),
    }  # fmt: skip


_FACTORIES: dict[str, Callable[[], dict[str, Adapter]]] = {
    "roma": _roma,
    "kornia": _kornia,
    "pypose": _pypose,
    "pytorch_kinematics": _pk,
    "scipy": _scipy,
}


def available() -> dict[str, str]:
    """Importable peers and their versions."""
    out = {}
    for peer in PEERS:
        v = version(peer)
        if v is not None:
            out[peer] = v
    return out


def adapters(op: str, peers: tuple[str, ...] | None = None) -> list[Adapter]:
    """The adapters of every importable peer (or of ``peers``) that implements ``op``."""
    result = []
    for peer in peers if peers is not None else PEERS:
        if version(peer) is None:
            continue
        table = _FACTORIES[peer]()
        if op in table:
            result.append(table[op])
    return result


def outputs(out) -> tuple[Tensor, ...]:
    """The output tensors of a timed call, as a tuple."""
    return out if isinstance(out, tuple) else (out,)
