"""Robot kinematics on torchlie: URDF, MJCF and SDF chains, batched forward kinematics and
Jacobians.

>>> import torch
>>> from torchlie.kinematics import Chain, sample_robot
>>> arm = Chain.from_urdf(sample_robot("arm7"))
>>> q = arm.random_configuration(1000)                    # (1000, 7), within the joint limits
>>> poses = arm.forward_kinematics(q)                     # dict: link -> (1000, 4, 4)
>>> poses["tool_tcp"].shape
torch.Size([1000, 4, 4])
>>> arm.jacobian(q, "tool_tcp").shape                     # rows (linear; angular)
torch.Size([1000, 6, 7])
>>> res = arm.inverse_kinematics(poses["tool_tcp"][:8], "tool_tcp", restarts=4)
>>> res.q.shape, res.converged.shape                      # batched, differentiable IK
(torch.Size([8, 7]), torch.Size([8]))

Conventions (joint coordinates, ``q`` layout, Jacobian kinds) are in
:mod:`torchlie.kinematics.chain`, the inverse kinematics solver in
:mod:`torchlie.kinematics.ik`, rigid-body dynamics (``Chain.inverse_dynamics``,
``mass_matrix``, ``forward_dynamics``, ...) in :mod:`torchlie.kinematics.dynamics`.
``python -m torchlie.kinematics.validate ROBOT.urdf`` checks every link pose and the end links'
Jacobians against pytorch-kinematics, Pinocchio (where installed) and an exact float64
reference, and the dynamics against Pinocchio.
"""

from __future__ import annotations

from pathlib import Path

from .chain import Chain
from .dynamics import Inertials
from .ik import IKResult
from .mjcf import MJCFError, parse_mjcf
from .sdf import SDFError, parse_sdf
from .urdf import JOINT_TYPES, JointSpec, MimicSpec, RobotSpec, URDFError, parse_urdf

__all__ = [
    "Chain",
    "IKResult",
    "Inertials",
    "JOINT_TYPES",
    "JointSpec",
    "MimicSpec",
    "RobotSpec",
    "URDFError",
    "parse_urdf",
    "MJCFError",
    "parse_mjcf",
    "SDFError",
    "parse_sdf",
    "sample_robot",
    "SAMPLE_ROBOTS",
]

_ROBOTS = Path(__file__).resolve().parent / "robots"

#: Bundled robots: name -> file under ``torchlie/kinematics/robots``.
SAMPLE_ROBOTS = {
    "arm7": "arm7.urdf",
    "tree": "tree.urdf",
    "panda": "panda/panda.urdf",
}


def sample_robot(name: str) -> str:
    """Path of a bundled URDF: ``"arm7"`` (7-DOF arm), ``"tree"`` (branching robot with every
    joint type) or ``"panda"`` (Franka Emika Panda, Apache-2.0, see ``robots/panda/``).

    Example:
        >>> Path(sample_robot("arm7")).name
        'arm7.urdf'
    """
    if name not in SAMPLE_ROBOTS:
        raise ValueError(
            f"torchlie.kinematics.sample_robot: unknown robot {name!r} "
            f"(bundled: {', '.join(SAMPLE_ROBOTS)})"
        )
    return str(_ROBOTS / SAMPLE_ROBOTS[name])
