"""Bad input: one rule for every entry point (see :mod:`torchlie._checks`).

Wrong dtypes and mixed dtypes raise ``TypeError``, wrong shapes ``ValueError``; real parameters
take tensors or numbers (never ``bool``); tolerances and loss weights are non-negative finite
real numbers; degenerate inputs with a documented meaning give finite values; errors name what
the user called.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
import torch
from torch.nn.utils import parametrize

import torchlie
from torchlie import SE2, SE3, SO2, SO3, Sim3, _checks, conversions, se2, se3, sim3, so2, so3
from torchlie import nn as tnn
from torchlie import quaternion as quat
from torchlie import statistics as st

F32, F64 = torch.float32, torch.float64
BAD_DTYPES = [torch.int64, torch.bool, torch.float8_e4m3fn, torch.float8_e5m2, torch.complex64]
FLOATS = [torch.float16, torch.bfloat16, torch.float32, torch.float64]


def _rz(angle: float, dtype=F64) -> torch.Tensor:
    return so3.exp(torch.tensor([0.0, 0.0, angle], dtype=dtype))


# ----------------------------------------------------------------------------------------------
# dtypes
# ----------------------------------------------------------------------------------------------

FACTORIES = [
    ("torchlie.so3.identity", so3.identity),
    ("torchlie.so3.random", so3.random),
    ("torchlie.se3.identity", se3.identity),
    ("torchlie.se3.random", se3.random),
    ("torchlie.quaternion.identity", quat.identity),
    ("torchlie.quaternion.random", quat.random),
    ("torchlie.SO3.identity", SO3.identity),
    ("torchlie.SO3.random", SO3.random),
    ("torchlie.SE3.identity", SE3.identity),
    ("torchlie.SE3.random", SE3.random),
]


@pytest.mark.parametrize("bad", BAD_DTYPES, ids=str)
@pytest.mark.parametrize("name,factory", FACTORIES, ids=[n for n, _ in FACTORIES])
def test_factories_refuse_dtypes_other_than_the_four_floats(name, factory, bad):
    msg = rf"{re.escape(name)}\b.*expected dtype to be one of torch\.float16.*got {bad}"
    with pytest.raises(TypeError, match=msg):
        factory(2, dtype=bad)


@pytest.mark.parametrize("name,factory", FACTORIES, ids=[n for n, _ in FACTORIES])
def test_factories_refuse_a_dtype_that_is_not_a_torch_dtype(name, factory):
    with pytest.raises(TypeError, match=rf"{re.escape(name)}\b.*got 'float32'"):
        factory(dtype="float32")


@pytest.mark.parametrize("dtype", FLOATS, ids=str)
@pytest.mark.parametrize("name,factory", FACTORIES, ids=[n for n, _ in FACTORIES])
def test_factories_return_the_requested_float_dtype(name, factory, dtype):
    out = factory(2, dtype=dtype)
    assert (out.tensor if isinstance(out, (SO3, SE3)) else out).dtype == dtype


@pytest.mark.parametrize("module", [so3, se3, quat], ids=lambda m: m.__name__)
@pytest.mark.parametrize("half", [torch.float16, torch.bfloat16], ids=str)
def test_random_in_half_precision_is_drawn_in_float32_and_cast(module, half):
    got = module.random(5, generator=torch.Generator().manual_seed(3), dtype=half)
    ref = module.random(5, generator=torch.Generator().manual_seed(3), dtype=F32)
    assert torch.equal(got, ref.to(half))


@pytest.mark.parametrize(
    "batch,exc", [((2.5,), TypeError), ((True,), TypeError), ((-1,), ValueError)]
)
def test_factories_refuse_bad_batch_sizes(batch, exc):
    with pytest.raises(exc, match=r"torchlie\.so3\.identity: expected (the )?batch sizes"):
        so3.identity(*batch)
    assert so3.identity(np.int64(2)).shape == (2, 3, 3)


ENTRY_POINTS = [
    ("torchlie.so3.exp", lambda d: so3.exp(torch.zeros(3, dtype=d))),
    ("torchlie.so3.log", lambda d: so3.log(torch.eye(3, dtype=d))),
    ("torchlie.se3.log", lambda d: se3.log(torch.eye(4, dtype=d))),
    ("torchlie.quaternion.from_matrix", lambda d: quat.from_matrix(torch.eye(3, dtype=d))),
    (
        "torchlie.conversions.matrix_to_euler",
        lambda d: conversions.matrix_to_euler(torch.eye(3, dtype=d), "xyz"),
    ),
    ("torchlie.statistics.so3_mean", lambda d: st.so3_mean(torch.eye(3, dtype=d).expand(2, 3, 3))),
    (
        "torchlie.nn.representation_to_matrix",
        lambda d: tnn.representation_to_matrix(torch.ones(6, dtype=d), "6d"),
    ),
    ("torchlie.SO3", lambda d: SO3(torch.eye(3, dtype=d))),
]


@pytest.mark.parametrize("bad", [torch.float8_e4m3fn, torch.float8_e5m2, torch.int32], ids=str)
@pytest.mark.parametrize("name,call", ENTRY_POINTS, ids=[n for n, _ in ENTRY_POINTS])
def test_tensors_of_other_dtypes_raise_type_error_naming_the_function(name, call, bad):
    msg = rf"^{re.escape(name)}: expected \w+ to be a floating-point tensor .*got dtype {bad}"
    with pytest.raises(TypeError, match=msg):
        call(bad)


def test_so3_identity_of_an_integer_dtype_is_refused_not_returned():
    with pytest.raises(TypeError, match=r"torchlie\.so3\.identity: .*got torch\.int64"):
        so3.identity(dtype=torch.int64)


def test_group_to_a_non_float_dtype_is_refused():
    with pytest.raises(TypeError, match=r"torchlie\.SO3\.to: .*got torch\.int64"):
        SO3.identity().to(torch.int64)
    assert SO3.identity().to(F64).dtype == F64


# ----------------------------------------------------------------------------------------------
# Mixed dtypes: TypeError everywhere
# ----------------------------------------------------------------------------------------------

_R32, _R64 = _rz(0.3, F32), _rz(0.3)
_T32 = se3.from_rt(_R32, torch.ones(3))
_t64 = torch.tensor(0.5, dtype=F64)

MIXED = [
    ("torchlie.so3.compose", lambda: so3.compose(_R32, _R64)),
    ("torchlie.so3.interpolate", lambda: so3.interpolate(_R32, _R32, _t64)),
    ("torchlie.se3.interpolate", lambda: se3.interpolate(_T32, _T32, _t64)),
    ("torchlie.quaternion.slerp", lambda: quat.slerp(quat.identity(), quat.identity(), _t64)),
    ("torchlie.quaternion.integrate", lambda: quat.integrate(quat.identity(), torch.ones(3), _t64)),
    (
        "torchlie.conversions.axis_angle_to_matrix",
        lambda: conversions.axis_angle_to_matrix(torch.ones(3), _t64),
    ),
    ("torchlie.statistics.so3_integrate", lambda: st.so3_integrate(_R64, torch.ones(3), 0.1)),
    (
        "torchlie.statistics.so3_integrate",
        lambda: st.so3_integrate(_R32, torch.ones(3, dtype=F64), 0.1),
    ),
    ("torchlie.statistics.so3_integrate", lambda: st.so3_integrate(_R32, torch.ones(3), _t64)),
    (
        "torchlie.statistics.se3_integrate",
        lambda: st.se3_integrate(_T32.double(), torch.ones(6), 0.1),
    ),
    ("torchlie.statistics.so3_randn", lambda: st.so3_randn(_R32, _t64)),
    (
        "torchlie.statistics.se2_randn",
        lambda: st.se2_randn(torch.eye(3), cov=torch.eye(3, dtype=F64)),
    ),
    (
        "torchlie.statistics.sim3_integrate",
        lambda: st.sim3_integrate(torch.eye(4), torch.ones(7, dtype=F64), 0.1),
    ),
    (
        "torchlie.statistics.so2_integrate",
        lambda: st.so2_integrate(torch.eye(2), torch.ones(1), _t64),
    ),
    (
        "torchlie.statistics.so3_mean",
        lambda: st.so3_mean(_R32.expand(2, 3, 3), torch.ones(2, dtype=F64)),
    ),
    (
        "torchlie.statistics.align",
        lambda: st.align(torch.ones(3, 3), torch.ones(3, 3), torch.ones(3, dtype=F64)),
    ),
    (
        "torchlie.statistics.so3_interpolate_keyframes",
        lambda: st.so3_interpolate_keyframes(
            torch.tensor([0.0, 1.0], dtype=F64), _R32.expand(2, 3, 3), 0.5
        ),
    ),
    (
        "torchlie.statistics.so3_interpolate_keyframes",
        lambda: st.so3_interpolate_keyframes(torch.tensor([0.0, 1.0]), _R32.expand(2, 3, 3), _t64),
    ),
    (
        "torchlie.statistics.so2_interpolate_keyframes",
        lambda: st.so2_interpolate_keyframes(
            torch.tensor([0.0, 1.0], dtype=F64), torch.eye(2).expand(2, 2, 2), 0.5
        ),
    ),
    ("torchlie.SO3.interpolate", lambda: SO3(_R32).interpolate(SO3(_R32), _t64)),
]


@pytest.mark.parametrize("name,call", MIXED, ids=[f"{n}-{i}" for i, (n, _) in enumerate(MIXED)])
def test_mixed_dtypes_raise_type_error_naming_the_function(name, call):
    with pytest.raises(
        TypeError, match=rf"^{re.escape(name)}\b.*expected inputs of one dtype, got"
    ):
        call()


def test_half_parameters_of_half_operands_are_accepted():
    R = _rz(0.8, torch.float16)
    out = so3.interpolate(
        torch.eye(3, dtype=torch.float16), R, torch.tensor(0.5, dtype=torch.float16)
    )
    assert out.dtype == torch.float16
    torch.testing.assert_close(out, _rz(0.4, torch.float16), rtol=0, atol=2e-3)


# ----------------------------------------------------------------------------------------------
# Real parameters: numbers and tensors, never bool
# ----------------------------------------------------------------------------------------------

_RZ1 = _rz(1.0)
_Q1 = quat.from_matrix(_RZ1)
_T1 = se3.from_rt(_RZ1, torch.tensor([1.0, 2.0, 3.0], dtype=F64))
_KEYS = torch.stack((torch.eye(3, dtype=F64), _RZ1))
_TIMES = torch.tensor([0.0, 2.0], dtype=F64)

# (name, f(x)) with the real parameter x
REAL_PARAMS = [
    ("torchlie.so3.interpolate", lambda x: so3.interpolate(torch.eye(3, dtype=F64), _RZ1, x)),
    ("torchlie.se3.interpolate", lambda x: se3.interpolate(torch.eye(4, dtype=F64), _T1, x)),
    ("torchlie.quaternion.slerp", lambda x: quat.slerp(quat.identity(dtype=F64), _Q1, x)),
    ("torchlie.quaternion.integrate", lambda x: quat.integrate(_Q1, torch.ones(3, dtype=F64), x)),
    (
        "torchlie.conversions.axis_angle_to_matrix",
        lambda x: conversions.axis_angle_to_matrix(torch.ones(3, dtype=F64), x),
    ),
    (
        "torchlie.statistics.so3_integrate",
        lambda x: st.so3_integrate(_RZ1, torch.ones(3, dtype=F64), x),
    ),
    (
        "torchlie.statistics.se3_integrate",
        lambda x: st.se3_integrate(_T1, torch.ones(6, dtype=F64), x),
    ),
    (
        "torchlie.statistics.so3_interpolate_keyframes",
        lambda x: st.so3_interpolate_keyframes(_TIMES, _KEYS, x),
    ),
    (
        "torchlie.statistics.so3_randn",
        lambda x: st.so3_randn(_RZ1, x, generator=torch.Generator().manual_seed(0)),
    ),
    (
        "torchlie.statistics.sim3_randn",
        lambda x: st.sim3_randn(
            torch.eye(4, dtype=F64), x, generator=torch.Generator().manual_seed(0)
        ),
    ),
    (
        "torchlie.statistics.se2_integrate",
        lambda x: st.se2_integrate(torch.eye(3, dtype=F64), torch.ones(3, dtype=F64), x),
    ),
    (
        "torchlie.statistics.so2_interpolate_keyframes",
        lambda x: st.so2_interpolate_keyframes(
            _TIMES, so2.exp(torch.tensor([[0.0], [1.0]], dtype=F64)), x
        ),
    ),
    (
        "torchlie.SO3.interpolate",
        lambda x: SO3(torch.eye(3, dtype=F64)).interpolate(SO3(_RZ1), x).tensor,
    ),
]
_IDS = [n.rsplit(".", 2)[-2] + "." + n.rsplit(".", 1)[-1] for n, _ in REAL_PARAMS]


@pytest.mark.parametrize(
    "bad", [True, False, np.bool_(True), torch.tensor(True), [True, False], np.array([True])]
)
@pytest.mark.parametrize("name,f", REAL_PARAMS, ids=_IDS)
def test_bool_is_refused_where_a_real_parameter_is_expected(name, f, bad):
    with pytest.raises(TypeError, match=rf"^{re.escape(name)}\b.*expected \w+ to be a real number"):
        f(bad)


@pytest.mark.parametrize(
    "bad",
    ["0.5", {"t": 0.5}, object(), 0.5j, np.array(["a"])],
    ids=["str", "dict", "object", "complex", "str-array"],
)
@pytest.mark.parametrize("name,f", REAL_PARAMS, ids=_IDS)
def test_non_numbers_are_refused_naming_what_came(name, f, bad):
    came = "numpy array of dtype <U1" if isinstance(bad, np.ndarray) else type(bad).__name__
    with pytest.raises(TypeError, match=rf"^{re.escape(name)}\b.*got {re.escape(came)}$"):
        f(bad)


@pytest.mark.parametrize(
    "number",
    [0.25, 1, np.float64(0.25), np.float32(0.25), np.int64(1), np.array(0.25), np.float16(0.25)],
    ids=repr,
)
@pytest.mark.parametrize("name,f", REAL_PARAMS, ids=_IDS)
def test_python_and_numpy_numbers_work_like_python_floats(name, f, number):
    torch.testing.assert_close(f(number), f(float(number)), rtol=0, atol=0)


@pytest.mark.parametrize("name,f", REAL_PARAMS, ids=_IDS)
def test_lists_and_numpy_arrays_work_like_tensors_of_the_operand_dtype(name, f):
    values = [0.1, 0.25, 3.0]
    ref = f(torch.tensor(values, dtype=F64))
    torch.testing.assert_close(f(values), ref, rtol=0, atol=0)
    torch.testing.assert_close(f(tuple(values)), ref, rtol=0, atol=0)
    torch.testing.assert_close(f(np.array(values)), ref, rtol=0, atol=0)
    with pytest.raises(ValueError, match=rf"^{re.escape(name)}\b.*ragged"):
        f([[0.1], [0.2, 0.3]])


def test_list_is_converted_from_python_floats_not_through_float32():
    # 0.1 rounded to float32 and back differs from 0.1 in float64 by ~1.5e-9
    w = so3.log(so3.interpolate(torch.eye(3, dtype=F64), _RZ1, [0.1]))
    assert float(w[0, 2]) == float(so3.log(so3.interpolate(torch.eye(3, dtype=F64), _RZ1, 0.1))[2])


@pytest.mark.parametrize("mean", [st.so3_mean, st.se3_mean])
def test_mean_iterations_are_ints_not_bools(mean):
    X = (so3 if mean is st.so3_mean else se3).identity(2)
    name = re.escape(f"torchlie.statistics.{mean.__name__}")
    for bad in (True, 2.0, "3"):
        with pytest.raises(TypeError, match=rf"^{name}: expected iterations to be an integer >= 0"):
            mean(X, iterations=bad)
    with pytest.raises(ValueError, match=rf"^{name}: expected iterations >= 0, got iterations=-1"):
        mean(X, iterations=-1)
    assert torch.equal(mean(X, iterations=np.int64(2)), mean(X, iterations=2))


def test_weights_accept_lists():
    R = so3.exp(torch.tensor([[0.0, 0.0, 0.2], [0.0, 0.0, 0.6]], dtype=F64))
    torch.testing.assert_close(
        st.so3_mean(R, [3.0, 1.0]), st.so3_mean(R, torch.tensor([3.0, 1.0], dtype=F64))
    )
    with pytest.raises(TypeError, match=r"torchlie\.statistics\.so3_mean: expected weights"):
        st.so3_mean(R, [True, False])


# ----------------------------------------------------------------------------------------------
# Tolerances and loss weights
# ----------------------------------------------------------------------------------------------

_I3, _I4 = torch.eye(3), torch.eye(4)
TOLERANCES = [
    ("torchlie.so3.is_valid", lambda a: so3.is_valid(_I3, atol=a)),
    ("torchlie.se3.is_valid", lambda a: se3.is_valid(_I4, atol=a)),
    ("torchlie.quaternion.is_unit", lambda a: quat.is_unit(quat.identity(), atol=a)),
    ("torchlie.SO3", lambda a: SO3(_I3, atol=a)),
    ("torchlie.SE3", lambda a: SE3(_I4, check=True, atol=a)),
    ("torchlie.SO3.is_valid", lambda a: SO3(_I3).is_valid(atol=a)),
    ("torchlie.SO3.from_quaternion", lambda a: SO3.from_quaternion(quat.identity(), atol=a)),
    ("torchlie.SE3.from_rt", lambda a: SE3.from_rt(_I3, torch.zeros(3), check=True, atol=a)),
    (
        "torchlie.SE3.from_pos_quat",
        lambda a: SE3.from_pos_quat(torch.tensor([0.0] * 3 + [1.0, 0, 0, 0]), atol=a),
    ),
]


@pytest.mark.parametrize("bad", ["x", True, torch.tensor(1e-3), [1e-3], None.__class__], ids=repr)
@pytest.mark.parametrize("name,f", TOLERANCES, ids=[n for n, _ in TOLERANCES])
def test_tolerance_of_another_type_raises_type_error(name, f, bad):
    msg = rf"^{re.escape(name)}\b.*expected atol to be a non-negative finite real number, got"
    with pytest.raises(TypeError, match=msg):
        f(bad)


@pytest.mark.parametrize("bad", [-1e-3, float("nan"), float("inf"), np.float64(-1.0)], ids=repr)
@pytest.mark.parametrize("name,f", TOLERANCES, ids=[n for n, _ in TOLERANCES])
def test_negative_or_non_finite_tolerance_raises_value_error(name, f, bad):
    msg = rf"^{re.escape(name)}\b.*expected atol to be a non-negative finite real number, got"
    with pytest.raises(ValueError, match=msg):
        f(bad)


@pytest.mark.parametrize("good", [0, 0.0, 1e-3, np.float32(1e-3), None], ids=repr)
@pytest.mark.parametrize("name,f", TOLERANCES, ids=[n for n, _ in TOLERANCES])
def test_non_negative_real_tolerances_are_accepted(name, f, good):
    f(good)


def test_tolerance_is_applied():
    R = torch.eye(3) + 1e-3
    assert not bool(so3.is_valid(R, atol=np.float64(1e-4)))
    assert bool(so3.is_valid(R, atol=1e-2))


@pytest.mark.parametrize("arg", ["rotation_weight", "translation_weight"])
@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -1.0], ids=repr)
def test_geodesic_loss_weights_must_be_finite_and_non_negative(arg, bad):
    T = se3.identity()
    with pytest.raises(
        ValueError, match=rf"torchlie\.nn\.se3_geodesic_loss: expected {arg} .*got {bad}"
    ):
        tnn.se3_geodesic_loss(T, T, **{arg: bad})


@pytest.mark.parametrize("bad", ["1", True, torch.tensor(1.0)], ids=repr)
def test_geodesic_loss_weights_of_another_type_raise_type_error(bad):
    T = se3.identity()
    with pytest.raises(
        TypeError, match=r"torchlie\.nn\.se3_geodesic_loss: expected rotation_weight"
    ):
        tnn.se3_geodesic_loss(T, T, rotation_weight=bad)


def test_geodesic_loss_numpy_weight_acts_as_float():
    T1 = se3.from_rt(_rz(0.3, F32), torch.tensor([3.0, 4.0, 0.0]))
    T0 = se3.identity()
    got = tnn.se3_geodesic_loss(T1, T0, rotation_weight=np.float32(10.0), translation_weight=0)
    torch.testing.assert_close(got, torch.tensor(3.0))


# ----------------------------------------------------------------------------------------------
# Degenerate inputs with a documented, finite meaning
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("translation", [True, False])
def test_align_with_coincident_source_points_has_scale_one_and_finite_gradients(translation):
    P = torch.zeros(5, 3, dtype=F64) + (
        torch.tensor([1.0, -2.0, 0.5], dtype=F64) if translation else 0.0
    )
    P.requires_grad_()
    Q = torch.randn(5, 3, dtype=F64, generator=torch.Generator().manual_seed(0)).requires_grad_()
    fit = st.align(P, Q, scale=True, translation=translation)
    assert float(fit.scale.detach()) == 1.0
    torch.testing.assert_close(fit.rotation, torch.eye(3, dtype=F64), rtol=0, atol=1e-15)
    loss = fit.scale + fit.rotation.sum() + fit.translation.sum()
    grads = torch.autograd.grad(loss, (P, Q))
    assert all(bool(torch.isfinite(g).all()) for g in grads)
    if translation:  # t = q_bar - p_bar, exactly
        torch.testing.assert_close(fit.translation, Q.mean(0) - P.mean(0))


def test_align_with_coincident_target_points_has_scale_zero():
    P = torch.randn(5, 3, dtype=F64, generator=torch.Generator().manual_seed(1))
    Q = torch.ones(5, 3, dtype=F64)
    fit = st.align(P, Q, scale=True)
    assert float(fit.scale) == 0.0
    torch.testing.assert_close(fit.translation, torch.ones(3, dtype=F64))


def test_align_degenerate_element_leaves_the_rest_of_the_batch_alone():
    g = torch.Generator().manual_seed(2)
    P = torch.randn(3, 6, 3, dtype=F64, generator=g)
    R = so3.random(3, generator=g, dtype=F64)
    Q = 2.0 * P @ R.mT + 1.0
    P[1] = 0.5
    fit = st.align(P, Q, scale=True)
    torch.testing.assert_close(fit.scale, torch.tensor([2.0, 1.0, 2.0], dtype=F64))
    torch.testing.assert_close(fit.rotation[[0, 2]], R[[0, 2]])


@pytest.mark.parametrize("dtype", [F32, F64], ids=str)
def test_so3_parametrization_reads_a_zero_quaternion_as_the_identity(dtype):
    holder = torch.nn.Module()
    holder.R = torch.nn.Parameter(so3.identity(3, dtype=dtype))
    parametrize.register_parametrization(holder, "R", tnn.SO3Parametrization())
    q = _rz(0.4, dtype)
    with torch.no_grad():
        holder.parametrizations.R.original.copy_(
            torch.stack(
                (torch.zeros(4, dtype=dtype), quat.from_matrix(q), 2 * quat.identity(dtype=dtype))
            )
        )
    R = holder.R
    torch.testing.assert_close(R[0], torch.eye(3, dtype=dtype), rtol=0, atol=0)
    torch.testing.assert_close(R[1], q)
    (R * torch.arange(27, dtype=dtype).view(3, 3, 3)).sum().backward()
    grad = holder.parametrizations.R.original.grad
    assert bool(torch.isfinite(grad).all())
    assert torch.equal(grad[0], torch.zeros(4, dtype=dtype))
    assert bool((grad[1] != 0).any())


def test_se3_parametrization_reads_a_zero_quaternion_as_the_identity_rotation():
    X = torch.tensor([[1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 0.0]], requires_grad=True)
    T = tnn.SE3Parametrization()(X)
    torch.testing.assert_close(
        T[0], se3.from_rt(torch.eye(3), torch.tensor([1.0, 2.0, 3.0])), rtol=0, atol=0
    )
    T.sum().backward()
    assert bool(torch.isfinite(X.grad).all())
    torch.testing.assert_close(X.grad[0, 3:], torch.zeros(4), rtol=0, atol=0)


# ----------------------------------------------------------------------------------------------
# Matrices off SO(3): the documented first-order promise of the log maps
# ----------------------------------------------------------------------------------------------

LOG_MAPS = [
    ("so3.log", lambda M: so3.log(M)),
    ("quaternion.from_matrix", lambda M: quat.canonicalize(quat.from_matrix(M))),
    ("so3.rminus", lambda M: so3.rminus(M, _rz(0.7))),
    ("so3.lminus", lambda M: so3.lminus(M, _rz(0.7))),
    ("so3.interpolate", lambda M: so3.interpolate(torch.eye(3, dtype=F64), M, 0.3)),
    ("se3.log", lambda M: se3.log(se3.from_rt(M, torch.tensor([1.0, -2.0, 0.5], dtype=F64)))),
    ("conversions.matrix_to_euler", lambda M: conversions.matrix_to_euler(M, "ZYX")),
]


@pytest.mark.parametrize("name,f", LOG_MAPS, ids=[n for n, _ in LOG_MAPS])
def test_log_maps_read_a_nearly_rotation_as_its_nearest_rotation_to_first_order(name, f):
    g = torch.Generator().manual_seed(4)
    # the largest quaternion entry is w, x, z and y in turn (each of Shepperd's four formulas)
    w = torch.tensor([[0.3, -1.1, 0.4], [2.0, 0.5, -0.9], [0.0, 0.1, 3.0], [0.2, 2.9, -0.3]])
    R = so3.exp(w.to(F64))
    E = torch.randn(4, 3, 3, dtype=F64, generator=g)
    E = E / torch.linalg.matrix_norm(E, keepdim=True)
    for eps in (1e-4, 1e-6):
        M = R + eps * E
        err = (f(M) - f(so3.project(M))).abs().amax()
        assert float(err) <= 4 * eps**2 + 1e-14, (eps, float(err))


def test_log_of_a_rotation_scaled_by_one_plus_rounding_is_unchanged():
    R = _rz(0.3)
    for s in (1 + 2**-40, 1 - 2**-40):
        torch.testing.assert_close(so3.log(s * R), so3.log(R), rtol=0, atol=1e-15)
        torch.testing.assert_close(quat.from_matrix(s * R), quat.from_matrix(R), rtol=0, atol=1e-15)


@pytest.mark.parametrize("fn", [so3.log, quat.from_matrix, se3.log])
def test_log_maps_document_what_they_promise_off_so3(fn):
    doc = " ".join(fn.__doc__.split())
    assert "unspecified" in doc and "project" in doc


# ----------------------------------------------------------------------------------------------
# Group classes: errors name the method the user called
# ----------------------------------------------------------------------------------------------

_X, _Y = SO3.identity(), SE3.identity()
GROUP_ERRORS = [
    ("SO3.__matmul__", "so3.act", ValueError, lambda: _X @ torch.zeros(4)),
    ("SO3.__matmul__", "so3.act", TypeError, lambda: _X @ torch.zeros(3, dtype=F64)),
    ("SO3.__matmul__", "so3.compose", TypeError, lambda: _X @ SO3.identity(dtype=F64)),
    ("SE3.__matmul__", "se3.act", ValueError, lambda: _Y @ torch.zeros(2, 2)),
    ("SO3.apply", "so3.act", ValueError, lambda: _X.apply(torch.zeros(4))),
    ("SE3.apply", "se3.act", TypeError, lambda: _Y.apply(torch.zeros(3, dtype=torch.int64))),
    ("SO3.compose", "so3.compose", ValueError, lambda: SO3.identity(2).compose(SO3.identity(3))),
    ("SO3.rplus", "so3.rplus", ValueError, lambda: _X.rplus(torch.zeros(6))),
    ("SE3.lplus", "se3.lplus", ValueError, lambda: _Y.lplus(torch.zeros(3))),
    ("SE3.interpolate", "se3.interpolate", TypeError, lambda: _Y.interpolate(_Y, True)),
    ("SO3.exp", "so3.exp", ValueError, lambda: SO3.exp(torch.zeros(6))),
    ("SE3.exp", "se3.exp", TypeError, lambda: SE3.exp([0.0] * 6)),
    ("SO3.identity", "so3.identity", TypeError, lambda: SO3.identity(dtype=torch.int64)),
    ("SE3.random", "se3.random", TypeError, lambda: SE3.random(dtype=torch.float8_e4m3fn)),
    ("SO3.is_valid", "so3.is_valid", TypeError, lambda: _X.is_valid(atol="x")),
    (
        "SO3.from_quaternion",
        "quaternion.to_matrix",
        ValueError,
        lambda: SO3.from_quaternion(torch.zeros(3)),
    ),
    ("SE3.from_rt", "se3.from_rt", ValueError, lambda: SE3.from_rt(torch.eye(3), torch.zeros(4))),
    (
        "SE3.from_pos_quat",
        "se3.from_pos_quat",
        ValueError,
        lambda: SE3.from_pos_quat(torch.zeros(6)),
    ),
]


@pytest.mark.parametrize(
    "method,core,exc,call", GROUP_ERRORS, ids=[f"{m}-{i}" for i, (m, *_) in enumerate(GROUP_ERRORS)]
)
def test_group_errors_name_the_method_called(method, core, exc, call):
    msg = (
        rf"^torchlie\.{re.escape(method)} \(through torchlie\.{re.escape(core)}\): (expected|batch)"
    )
    with pytest.raises(exc, match=msg):
        call()


def test_group_method_errors_keep_their_own_name():
    with pytest.raises(TypeError, match=r"^torchlie\.SO3\.compose: expected another SO3, got SE3"):
        _X.compose(_Y)
    with pytest.raises(
        TypeError,
        match=r"^torchlie\.SO3\.__matmul__: expected another SO3 or a tensor of points, got SE3",
    ):
        _X @ _Y
    with pytest.raises(ValueError, match=r"^torchlie\.SO3: expected tensor of shape"):
        SO3(torch.eye(4))


@pytest.mark.parametrize("cls", [tnn.RotationHead, tnn.PoseHead, tnn.PlanarPoseHead])
def test_heads_name_their_input_width(cls):
    head = cls(4)
    name = cls.__name__
    with pytest.raises(
        ValueError,
        match=rf"^torchlie\.nn\.{name}: expected features of shape \(\.\.\., 4\), got \(2, 3\)",
    ):
        head(torch.zeros(2, 3))
    with pytest.raises(TypeError, match=rf"^torchlie\.nn\.{name}: expected features to be a torch"):
        head([0.0] * 4)


@pytest.mark.parametrize(
    "cls, method",
    [
        (tnn.RotationHead, "forward"),
        (tnn.RotationHead, "raw"),
        (tnn.RotationHead, "quaternion"),
        (tnn.PoseHead, "forward"),
        (tnn.PlanarPoseHead, "forward"),
    ],
)
def test_heads_name_a_dtype_other_than_their_layers(cls, method):
    # was torch's "mat1 and mat2 must have the same dtype, but got Double and Float"
    name = cls.__name__ + ("" if method == "forward" else f".{method}")
    for layer, given in ((torch.float32, F64), (F64, torch.float32)):
        head = cls(4, dtype=layer)
        with pytest.raises(
            TypeError,
            match=rf"^torchlie\.nn\.{name}: expected features of the head's dtype "
            + re.escape(f"{layer}, got {given}; convert one of them"),
        ):
            getattr(head, method)(torch.zeros(2, 4, dtype=given))
    # torch.autocast casts the layer's operands: bfloat16 features with a float32 layer there
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = getattr(cls(4), method)(torch.zeros(2, 4, dtype=torch.bfloat16))
    assert torch.isfinite(out.tensor if hasattr(out, "tensor") else out).all()


# ----------------------------------------------------------------------------------------------
# Batch dimensions: at most _checks.MAX_BATCH_DIMS, one check shared by every entry point
# ----------------------------------------------------------------------------------------------

LIMIT = _checks.MAX_BATCH_DIMS
_R1 = _rz(0.3)
_T1 = se3.exp(torch.tensor([0.1, 0.2, 0.3, 0.3, -0.2, 0.1], dtype=F64))
_Q1 = quat.normalize(torch.tensor([0.9, 0.1, -0.2, 0.3], dtype=F64))
_P1 = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 3.0]], dtype=F64)
_ELEMENTS = {  # kind -> (an element, its trailing dimensions)
    "R": (_R1, 2),
    "T": (_T1, 2),
    "q": (_Q1, 1),
    "v3": (torch.tensor([0.1, -0.2, 0.3], dtype=F64), 1),
    "v4": (_Q1, 1),
    "v5": (torch.linspace(-1.0, 1.0, 5, dtype=F64), 1),
    "v6": (torch.tensor([0.1, -0.2, 0.3, 0.2, 0.1, -0.3], dtype=F64), 1),
    "v7": (torch.cat((torch.tensor([1.0, 2.0, 3.0], dtype=F64), _Q1)), 1),
    "v9": (_R1.reshape(9), 1),
    "s": (torch.tensor(0.3, dtype=F64), 0),  # a real parameter: t, dt, angle, std, query time
    "R2": (so2.exp(torch.tensor([0.3], dtype=F64)), 2),
    "T2": (se2.exp(torch.tensor([0.1, 0.2, 0.3], dtype=F64)), 2),
    "v1": (torch.tensor([0.3], dtype=F64), 1),
    "v2": (torch.tensor([0.1, -0.2], dtype=F64), 1),
    "S": (sim3.exp(torch.tensor([0.1, -0.2, 0.3, 0.2, 0.1, -0.3, 0.4], dtype=F64)), 2),
    "v8": (torch.cat((torch.tensor([1.0, 2.0, 3.0], dtype=F64), _Q1, torch.ones(1, dtype=F64))), 1),
}
# Sets (means, align: the set last) and keyframes (first): that dimension is a batch dimension.
_SETS = {
    "Rset": (_R1, lambda b: (*b[1:], 2)),
    "Tset": (_T1, lambda b: (*b[1:], 2)),
    "Sset": (sim3.exp(torch.full((7,), 0.2, dtype=F64)), lambda b: (*b[1:], 2)),
    "R2set": (so2.exp(torch.tensor([0.3], dtype=F64)), lambda b: (*b[1:], 2)),
    "T2set": (se2.exp(torch.tensor([0.1, 0.2, 0.3], dtype=F64)), lambda b: (*b[1:], 2)),
    "wset": (torch.tensor(1.0, dtype=F64), lambda b: (*b[1:], 2)),
    "Pset": (_P1, lambda b: b[1:]),
    "Qset": (2 * _P1 + 1, lambda b: b[1:]),
    "Rkeys": (_R1, lambda b: (2, *b[1:])),
    "Tkeys": (_T1, lambda b: (2, *b[1:])),
    "R2keys": (so2.exp(torch.tensor([0.3], dtype=F64)), lambda b: (2, *b[1:])),
    "T2keys": (se2.exp(torch.tensor([0.1, 0.2, 0.3], dtype=F64)), lambda b: (2, *b[1:])),
    "Skeys": (sim3.exp(torch.full((7,), 0.2, dtype=F64)), lambda b: (2, *b[1:])),
}


def _arg(kind: object, b: tuple[int, ...]) -> object:
    """The operand ``kind`` with the batch ``b``: ``"R"`` a rotation, ``"R0"`` one alone,
    ``"SO3:R0"`` it as an SO3, ...; any other value is passed as it is."""
    if not isinstance(kind, str):
        return kind
    if kind[:4] in ("SO3:", "SE3:"):
        return (SO3 if kind[:3] == "SO3" else SE3)(_arg(kind[4:], b))
    if kind[-1:] == "0" and kind[:-1] in _ELEMENTS.keys() | _SETS.keys():
        kind, b = kind[:-1], ()
    if kind in _ELEMENTS:
        x, n = _ELEMENTS[kind]
        return x.expand(*b, *x.shape[x.dim() - n :]).clone()
    if kind in _SETS:
        x, lead = _SETS[kind]
        return x.expand(*lead(b), *x.shape).clone()
    return kind


_OWNERS = {"so3": so3, "se3": se3, "quaternion": quat, "conversions": conversions,
           "statistics": st, "nn": tnn, "SO3": SO3, "SE3": SE3, "": torchlie,
           "so2": so2, "se2": se2, "SO2": SO2, "SE2": SE2, "sim3": sim3, "Sim3": Sim3}  # fmt: skip


def _on(path: str, *args: object, **kwargs: object) -> tuple[str, object]:
    """``(torchlie.<path>, a call of it with every operand batched by b)``; ``"*b"`` is the
    batch sizes of a factory."""
    owner, _, attr = path.rpartition(".")
    f = getattr(_OWNERS[owner], attr)

    def call(b: tuple[int, ...]) -> object:
        pos = [x for a in args for x in (b if a == "*b" else (_arg(a, b),))]
        return f(*pos, **{k: _arg(v, b) for k, v in kwargs.items()})

    return f"torchlie.{path}", call


def _head(cls: type, rep: str) -> tuple[str, object]:
    # A head checks its features, then applies its linear layer.
    return f"torchlie.nn.{cls.__name__}", lambda b: cls(5, rep, dtype=F64)(_arg("v5", b))


def _param(cls: type, rep: str, kind: str) -> tuple[str, object]:
    return f"torchlie.nn.{cls.__name__}", lambda b: cls(rep)(_arg(kind, b))


# Every public function of so3, se3, quaternion, conversions, statistics and nn, and the SO3 /
# SE3 constructors and methods that take tensors; each tensor argument batched.
BATCHED: list[tuple[str, object]] = []
for _m, _E, _tan in (("so3", "R", "v3"), ("se3", "T", "v6")):
    _G, _g0 = _m.upper(), f"{_m.upper()}:{_E}0"
    _jacs = ("jac_left", "jac_right", "jac_left_inv", "jac_right_inv")
    BATCHED += [_on(f"{_m}.{f}", _tan) for f in ("hat", "exp", "ad", *_jacs)]
    BATCHED += [_on(f"{_m}.{f}", _E) for f in ("vee", "log", "inverse", "adjoint", "is_valid")]
    _pairs = ("compose", "distance", "rminus", "lminus", "between")
    BATCHED += [_on(f"{_m}.{f}", _E, _E) for f in (*_pairs, "jac_compose", "jac_rminus")]
    BATCHED += [_on(f"{_m}.jac_between", _E, _E), _on(f"{_m}.jac_inverse", _E)]
    BATCHED += [_on(f"{_m}.{f}", _E, _tan) for f in ("rplus", "lplus", "jac_rplus")]
    BATCHED += [_on(f"{_m}.{f}", _E, "v3") for f in ("act", "jac_act")]
    BATCHED += [_on(f"{p}.{f}", "*b", dtype=F64) for p in (_m, _G) for f in ("identity", "random")]
    BATCHED += [
        _on(f"{_m}.interpolate", _E, _E, 0.3),
        _on(f"{_m}.interpolate", f"{_E}0", f"{_E}0", "s"),
        _on(_G, _E, check=True),
        _on(f"{_G}.exp", _tan),
        _on(f"{_G}.apply", _g0, "v3"),
        _on(f"{_G}.rplus", _g0, _tan),
        _on(f"{_G}.lplus", _g0, _tan),
        _on(f"{_G}.interpolate", _g0, _g0, "s"),
    ]
BATCHED += [
    _on("so3.project", "R"),
    _on("se3.from_rt", "R", "v3"),
    _on("se3.to_rt", "T"),
    _on("se3.from_pos_quat", "v7"),
    _on("se3.to_pos_quat", "T"),
    _on("SO3.from_quaternion", "q", check=True),
    _on("SE3.from_rt", "R", "v3", check=True),
    _on("SE3.from_pos_quat", "v7", check=True),
    *(_on(f"quaternion.{f}", "q") for f in ("conjugate", "inverse", "normalize", "canonicalize",
                                            "exp", "log", "to_matrix", "to_rotvec", "is_unit",
                                            "to_xyzw", "from_xyzw", "to_jpl", "from_jpl",
                                            "left_matrix", "right_matrix", "to_su2")),
    *(_on(f"quaternion.{f}", "*b", dtype=F64) for f in ("identity", "random")),
    _on("quaternion.multiply", "q", "q"),
    _on("quaternion.apply", "q", "v3"),
    _on("quaternion.slerp", "q", "q", 0.3),
    _on("quaternion.slerp", "q0", "q0", "s"),
    _on("quaternion.from_matrix", "R"),
    _on("quaternion.from_rotvec", "v3"),
    _on("quaternion.derivative", "q", "v3"),
    _on("quaternion.integrate", "q", "v3", 0.1),
    _on("quaternion.integrate", "q0", "v30", "s"),
    _on("conversions.euler_to_quaternion", "v3", "xyz"),
    _on("conversions.quaternion_to_euler", "q", "XYZ"),
    _on("conversions.euler_to_matrix", "v3", "zyx"),
    _on("conversions.matrix_to_euler", "R", "xyz"),
    _on("conversions.axis_angle_to_matrix", "v3", 0.3),
    _on("conversions.axis_angle_to_matrix", "v30", "s"),
    _on("conversions.matrix_to_axis_angle", "R"),
    _on("conversions.rot6d_to_matrix", "v6"),
    _on("conversions.matrix_to_rot6d", "R"),
    _on("conversions.rot9d_to_matrix", "v9"),
    _on("statistics.so3_randn", "R", 0.1),
    _on("statistics.so3_randn", "R0", "s"),
    _on("statistics.se3_randn", "T", scale_tril=0.1 * torch.eye(6, dtype=F64)),
    _on("statistics.so3_mean", "Rset"),
    _on("statistics.se3_mean", "Tset", "wset"),
    _on("statistics.so3_interpolate_keyframes", torch.tensor([0.0, 1.0], dtype=F64), "Rkeys", 0.5),
    _on("statistics.se3_interpolate_keyframes", torch.tensor([0.0, 1.0], dtype=F64), "Tkeys0", "s"),
    _on("statistics.align", "Pset", "Qset", scale=True),
    _on("statistics.so3_integrate", "R", "v3", 0.1),
    _on("statistics.se3_integrate", "T", "v6", 0.1),
    _on("nn.geodesic_loss", "R", "R", reduction="none"),
    _on("nn.se3_geodesic_loss", "T", "T"),
    *(_on("nn.representation_to_matrix", f"v{k}", rep) for rep, k in tnn.REPRESENTATIONS.items()),
    *(_head(cls, rep) for cls in (tnn.RotationHead, tnn.PoseHead) for rep in tnn.REPRESENTATIONS),
    *(_param(tnn.SO3Parametrization, rep, k) for rep, k in (("quaternion", "q"), ("matrix", "R"),
                                                            ("rotvec", "v3"))),
    *(_param(tnn.SE3Parametrization, rep, k) for rep, k in (("pos_quat", "v7"), ("matrix", "T"),
                                                            ("twist", "v6"))),
]  # fmt: skip
# The planar groups: the same verbs.
for _m, _E, _tan in (("so2", "R2", "v1"), ("se2", "T2", "v3"), ("sim3", "S", "v7")):
    _G = "Sim3" if _m == "sim3" else _m.upper()
    _jacs = ("jac_left", "jac_right", "jac_left_inv", "jac_right_inv")
    BATCHED += [_on(f"{_m}.{f}", _tan) for f in ("hat", "exp", "ad", *_jacs)]
    BATCHED += [_on(f"{_m}.{f}", _E) for f in ("vee", "log", "inverse", "adjoint", "is_valid")]
    _pairs = ("compose", "distance", "rminus", "lminus", "between")
    BATCHED += [_on(f"{_m}.{f}", _E, _E) for f in (*_pairs, "jac_compose", "jac_rminus")]
    BATCHED += [_on(f"{_m}.jac_between", _E, _E), _on(f"{_m}.jac_inverse", _E)]
    BATCHED += [_on(f"{_m}.{f}", _E, _tan) for f in ("rplus", "lplus", "jac_rplus")]
    _pt = "v3" if _m == "sim3" else "v2"
    BATCHED += [_on(f"{_m}.{f}", _E, _pt) for f in ("act", "jac_act")]
    BATCHED += [_on(f"{p}.{f}", "*b", dtype=F64) for p in (_m, _G) for f in ("identity", "random")]
    BATCHED += [_on(f"{_m}.interpolate", _E, _E, 0.3), _on(f"{_G}.exp", _tan)]
BATCHED += [
    _on("so2.to_complex", "R2"),
    _on("so2.from_complex", "v2"),
    _on("so2.angle_to_complex", "v1"),
    _on("so2.complex_to_angle", "v2"),
    _on("se2.from_rt", "R2", "v2"),
    _on("se2.to_rt", "T2"),
    _on("se2.from_xytheta", "v3"),
    _on("se2.to_xytheta", "T2"),
    _on("nn.so2_geodesic_loss", "R2", "R2", reduction="none"),
    _on("nn.se2_geodesic_loss", "T2", "T2"),
    *(_param(tnn.SO2Parametrization, rep, k) for rep, k in (("complex", "v2"), ("matrix", "R2"),
                                                            ("angle", "v1"))),
    *(_param(tnn.SE2Parametrization, rep, k) for rep, k in (("pos_complex", "v4"),
                                                            ("matrix", "T2"), ("twist", "v3"))),
    _on("sim3.from_srt", "s", "R", "v3"),
    _on("sim3.to_srt", "S"),
    _on("sim3.from_se3", "T", "s"),
    _on("sim3.scale", "S"),
    _on("sim3.from_pos_quat_scale", "v8"),
    _on("sim3.to_pos_quat_scale", "S"),
    _on("Sim3.from_pos_quat_scale", "v8", check=True),
    _on("statistics.sim3_mean", "Sset", "wset"),
    _on("statistics.so2_mean", "R2set", "wset"),
    _on("statistics.se2_mean", "T2set", "wset"),
    _on("statistics.sim3_randn", "S", 0.1),
    _on("statistics.so2_randn", "R20", "s"),
    _on("statistics.se2_randn", "T2", scale_tril=0.1 * torch.eye(3, dtype=F64)),
    *(_on(f"statistics.{g}_interpolate_keyframes", torch.tensor([0.0, 1.0], dtype=F64), k, q)
      for g, k, q in (("sim3", "Skeys", 0.5), ("so2", "R2keys0", "s"), ("se2", "T2keys", 0.5))),
    _on("statistics.sim3_integrate", "S", "v7", 0.1),
    _on("statistics.so2_integrate", "R2", "v1", 0.1),
    _on("statistics.se2_integrate", "T2", "v3", "s"),
    _on("nn.sim3_geodesic_loss", "S", "S"),
    *(_param(tnn.Sim3Parametrization, rep, k) for rep, k in (("pos_quat_sigma", "v8"),
                                                             ("matrix", "S"), ("tangent", "v7"))),
]  # fmt: skip
_BATCHED_IDS = [f"{n}-{i}" for i, (n, _) in enumerate(BATCHED)]


def _outputs(out: object) -> list[torch.Tensor]:
    if isinstance(out, (SO3, SE3, SO2, SE2, Sim3)):
        return [out.tensor]
    if isinstance(out, torch.Tensor):
        return [out]
    return [t for o in out for t in _outputs(o)]  # type: ignore[attr-defined]


@pytest.mark.parametrize("name,call", BATCHED, ids=_BATCHED_IDS)
def test_every_op_computes_with_the_most_batch_dimensions(name, call):
    outs = _outputs(call((1,) * LIMIT))
    for out in outs:
        assert bool(out.all()) if out.dtype == torch.bool else bool(torch.isfinite(out).all())
    if not any(k in name for k in ("mean", "align", "loss", "keyframes")):  # they reduce
        assert outs[0].shape[:LIMIT] == (1,) * LIMIT


@pytest.mark.parametrize("name,call", BATCHED, ids=_BATCHED_IDS)
def test_one_batch_dimension_more_raises_value_error_naming_function_limit_and_count(name, call):
    with pytest.raises(ValueError) as info:
        call((1,) * (LIMIT + 1))
    msg = str(info.value)
    assert msg.startswith((f"{name}: ", f"{name} (through torchlie.")), msg
    where = r"in \w+ \(before its trailing \([\d, ]+\)\)|in \w+|\(one per batch size\)"
    assert re.search(
        rf": expected at most {LIMIT} batch dimensions ({where}), got {LIMIT + 1}$", msg
    )


def test_the_batch_limit_covers_every_public_function():
    tested = {name for name, _ in BATCHED}
    # Not calls: a table and a result type.  quaternion.from_su2 takes complex (..., 2, 2)
    # tensors through a check of its own and computes elementwise at any batch; the heads are
    # covered through the representation_to_matrix they call.
    exempt = {"nn.REPRESENTATIONS", "statistics.Alignment", "quaternion.from_su2",
              "nn.RotationHead", "nn.PoseHead", "nn.PlanarPoseHead"}  # fmt: skip
    missing = [
        f"{owner}.{f}"
        for owner in (
            "so3",
            "se3",
            "quaternion",
            "conversions",
            "statistics",
            "nn",
            "so2",
            "se2",
            "sim3",
        )
        for f in _OWNERS[owner].__all__
        if f"torchlie.{owner}.{f}" not in tested and f"{owner}.{f}" not in exempt
    ]
    assert missing == []


def test_the_message_names_the_argument_and_its_trailing_shape():
    # The two functions issue 49 found failing inside torch with 62 leading dimensions.
    with pytest.raises(ValueError) as info:
        so3.project(torch.eye(3).expand(*(1,) * 62, 3, 3))
    assert str(info.value) == (
        "torchlie.so3.project: expected at most 60 batch dimensions in M (before its trailing "
        "(3, 3)), got 62"
    )
    with pytest.raises(ValueError) as info:
        conversions.rot9d_to_matrix(torch.ones(*(1,) * 62, 9))
    assert str(info.value) == (
        "torchlie.conversions.rot9d_to_matrix: expected at most 60 batch dimensions in x "
        "(before its trailing (9,)), got 62"
    )


def _nested(n: int) -> object:
    return 0.5 if n == 0 else [_nested(n - 1)]


@pytest.mark.parametrize(
    "make",
    [lambda n: torch.full((1,) * n, 0.5, dtype=F64), lambda n: np.full((1,) * n, 0.5), _nested],
    ids=["tensor", "numpy", "list"],
)
def test_real_parameters_count_every_dimension_as_a_batch_dimension(make):
    assert so3.interpolate(_R1, _R1, make(LIMIT)).shape == (*(1,) * LIMIT, 3, 3)
    msg = rf"^torchlie\.so3\.interpolate: expected at most {LIMIT} batch dimensions in t, got 61$"
    with pytest.raises(ValueError, match=msg):
        so3.interpolate(_R1, _R1, make(LIMIT + 1))


def test_batch_dimensions_added_by_sample_shape_and_query_times():
    """Dimensions that each input stays within but that add up beyond the limit: the error
    names the statistics function, not the op it calls."""
    half = LIMIT // 2
    R = torch.eye(3, dtype=F64).expand(*(1,) * half, 3, 3)
    assert st.so3_randn(R, 0.1, sample_shape=(1,) * (LIMIT - half)).dim() == LIMIT + 2
    with pytest.raises(ValueError, match=r"^torchlie\.statistics\.so3_randn: expected at most"):
        st.so3_randn(R, 0.1, sample_shape=(1,) * (LIMIT - half + 1))
    keys = torch.eye(3, dtype=F64).expand(2, *(1,) * half, 3, 3)
    times = torch.tensor([0.0, 1.0], dtype=F64)
    query = torch.zeros((1,) * (LIMIT - half), dtype=F64)
    assert st.so3_interpolate_keyframes(times, keys, query).dim() == LIMIT + 2
    with pytest.raises(ValueError, match=r"^torchlie\.statistics\.so3_interpolate_keyframes: "):
        st.so3_interpolate_keyframes(times, keys, query[None])
