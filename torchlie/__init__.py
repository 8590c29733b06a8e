"""torchlie: batched, differentiable SO(3), SE(3), SO(2), SE(2), Sim(3) and quaternion math for
PyTorch.

Conventions (one for every function in the package)
----------------------------------------------------

=================  ===========================================================================
quaternion         Hamilton, scalar first ``(w, x, y, z)``, shape ``(..., 4)``; canonical
                   representative ``w > 0`` (at ``w = 0``: largest-magnitude vector component
                   positive).  ``quaternion.to_xyzw`` / ``from_xyzw`` / ``to_jpl`` / ``from_jpl``
                   convert at the boundary.
rotation matrix    ``(..., 3, 3)``, acts on column vectors: ``p_world = R @ p_body``.
pose               homogeneous ``(..., 4, 4)`` ``[[R, t], [0, 1]]``; also ``(R, t)`` pairs and
                   7-vectors ``(t, q)`` (translation, then wxyz quaternion).
so(3) tangent      rotation vector ``(..., 3)`` = angle * unit axis.
se(3) tangent      twist ``(..., 6)`` = ``(rho, phi)``: translation part first, rotation last.
planar groups      SO(2): matrices ``(..., 2, 2)``, tangent the angle ``(..., 1)``; SE(2): poses
                   ``(..., 3, 3)``, twist ``(..., 3)`` = ``(rho_x, rho_y, theta)``.
similarity         ``(..., 4, 4)`` ``[[s R, t], [0, 1]]`` with ``s = exp(sigma)``; sim(3) tangent
                   ``(..., 7)`` = ``(rho, phi, sigma)`` (:mod:`torchlie.sim3`).
perturbation       right: ``X (+) tau = X Exp(tau)``, ``Y (-) X = Log(X^-1 Y)``; the left
                   versions are named explicitly (``lplus``, ``lminus``).
Euler angles       scipy's naming: ``"xyz"`` lower case = extrinsic (static axes), ``"XYZ"``
                   upper case = intrinsic; all 24 sequences.
log range          rotation angle in ``[0, pi]``; at exactly pi the axis sign follows the
                   canonical quaternion rule above.  Planar angles in ``(-pi, pi]``.
batch              up to 60 leading dimensions (torch's reductions take at most 64 in all),
                   broadcast like torch; no op flattens or loops in Python.
dtypes             float32 and float64; float16/bfloat16 are computed in float32 and returned
                   in the input dtype.  ``torch.autocast`` does not reach inside an op: there
                   too float32 is computed and returned in float32, float64 in float64.
                   Integer tensors raise ``TypeError``; a wrong trailing shape raises
                   ``ValueError`` naming the function and both shapes.
gradients          finite at every angle, 0 and pi included.  The log maps' backward is the
                   gradient of ``log o polar`` (see :func:`torchlie.so3.log`).
=================  ===========================================================================

The core is pure functions on plain tensors (``torchlie.so3.exp(omega)``); nothing branches in
Python on tensor values, so every op works under ``torch.compile(fullgraph=True)``,
``torch.func.vmap`` / ``jacrev`` / ``jacfwd`` and on CUDA.
"""

from . import conversions, kinematics, nn, quaternion, se2, se3, sim3, so2, so3, statistics
from .groups import SE2, SE3, SO2, SO3, Sim3

__all__ = [
    "SE2",
    "SE3",
    "SO2",
    "SO3",
    "Sim3",
    "conversions",
    "kinematics",
    "nn",
    "quaternion",
    "se2",
    "se3",
    "so2",
    "sim3",
    "so3",
    "statistics",
]
__version__ = "0.1.0"
