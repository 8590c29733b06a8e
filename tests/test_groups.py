"""torchlie.groups: the SO3 / SE3 classes are thin, exact wrappers of the functional core."""

from __future__ import annotations

import copy
import inspect
import io
import pickle
from dataclasses import dataclass

import pytest
import torch
from torch.autograd import gradcheck

import torchlie.groups
from torchlie import quaternion, se3, sim3, so3
from torchlie.groups import SE2, SE3, SO2, SO3, Sim3

F64 = torch.float64


@dataclass(frozen=True)
class G:
    """One group of the registry: class, functional core, matrix size, tangent size."""

    cls: type
    core: object
    n: int
    dof: int

    def __repr__(self) -> str:
        return self.cls.__name__


GROUPS = [G(SO3, so3, 3, 3), G(SE3, se3, 4, 6), G(Sim3, sim3, 4, 7)]


@pytest.fixture(params=GROUPS, ids=repr)
def grp(request) -> G:
    return request.param


def rand(g: G, *batch: int, seed: int = 0, dtype=F64):
    return g.cls.random(*batch, generator=torch.Generator().manual_seed(seed), dtype=dtype)


def tangent(g: G, *batch: int, seed: int = 1, dtype=F64, scale: float = 0.7) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    return scale * torch.randn(*batch, g.dof, generator=gen, dtype=dtype)


# ----------------------------------------------------------------------------------------------
# Every method is the functional core's value, exactly
# ----------------------------------------------------------------------------------------------


def test_methods_equal_core(grp, batch):
    X = rand(grp, *batch, seed=0)
    Y = rand(grp, *batch, seed=1)
    a, b = X.tensor, Y.tensor
    tau = tangent(grp, *batch)
    p = torch.randn(*batch, 3, dtype=F64, generator=torch.Generator().manual_seed(2))
    c = grp.core
    pairs = [
        ((X @ Y).tensor, c.compose(a, b)),
        (X.compose(Y).tensor, c.compose(a, b)),
        (X @ p, c.act(a, p)),
        (X.apply(p), c.act(a, p)),
        (X.inverse().tensor, c.inverse(a)),
        (X.log(), c.log(a)),
        (grp.cls.exp(tau).tensor, c.exp(tau)),
        (X.adjoint(), c.adjoint(a)),
        (X.rplus(tau).tensor, c.rplus(a, tau)),
        (X.lplus(tau).tensor, c.lplus(a, tau)),
        (X.rminus(Y), c.rminus(a, b)),
        (X.lminus(Y), c.lminus(a, b)),
        (X.between(Y).tensor, c.between(a, b)),
        (X.interpolate(Y, 0.3).tensor, c.interpolate(a, b, 0.3)),
        (X.is_valid(), c.is_valid(a)),
        (X.matrix, a),
    ]
    for got, want in pairs:
        assert torch.equal(got, want)
    dist = X.distance(Y)
    want = c.distance(a, b)
    if isinstance(want, tuple):
        assert all(torch.equal(u, v) for u, v in zip(dist, want, strict=True))
    else:
        assert torch.equal(dist, want)
    assert X.matrix is a  # no copy


def test_so3_conversions(batch):
    X = rand(GROUPS[0], *batch)
    assert torch.equal(X.quaternion(), quaternion.from_matrix(X.tensor))
    assert X.rotation is X
    q = quaternion.random(*batch, generator=torch.Generator().manual_seed(3), dtype=F64)
    assert torch.equal(SO3.from_quaternion(q).tensor, quaternion.to_matrix(q))


def test_se3_conversions(batch):
    T = rand(GROUPS[1], *batch)
    R, t = se3.to_rt(T.tensor)
    assert isinstance(T.rotation, SO3)
    assert torch.equal(T.rotation.tensor, R)
    assert torch.equal(T.translation, t)
    assert all(torch.equal(u, v) for u, v in zip(T.to_rt(), (R, t), strict=True))
    assert torch.equal(T.pos_quat(), se3.to_pos_quat(T.tensor))
    assert torch.equal(T.quaternion(), se3.to_pos_quat(T.tensor)[..., 3:])
    assert torch.equal(SE3.from_rt(R, t).tensor, se3.from_rt(R, t))
    assert torch.equal(SE3.from_rt(SO3(R), t).tensor, se3.from_rt(R, t))
    assert torch.equal(SE3.from_pos_quat(T.pos_quat()).tensor, se3.from_pos_quat(T.pos_quat()))


def test_accessors_are_read_only_properties(batch):
    # The class rule: nouns for stored data are properties; verbs and conversions are methods.
    T = rand(GROUPS[1], *batch)
    X = SO3(T.tensor[..., :3, :3])
    props = {SE3: ("matrix", "rotation", "translation"), SO3: ("matrix", "rotation")}
    for cls, names in props.items():
        for name in names:
            assert isinstance(inspect.getattr_static(cls, name), property), (cls, name)
    for obj, name in [(T, "matrix"), (T, "rotation"), (T, "translation"), (X, "rotation")]:
        with pytest.raises(AttributeError):
            setattr(obj, name, getattr(obj, name))
    for cls, name in [
        (SE3, "log"),
        (SE3, "inverse"),
        (SE3, "apply"),
        (SE3, "quaternion"),
        (SE3, "pos_quat"),
        (SE3, "to_rt"),
        (SO3, "quaternion"),
        (SO3, "log"),
    ]:
        assert inspect.isfunction(inspect.getattr_static(cls, name)), (cls, name)

    assert T.matrix is T.tensor and X.matrix is X.tensor
    assert X.rotation is X
    assert type(T.rotation) is SO3 and T.rotation.shape == T.shape
    assert torch.equal(T.rotation.tensor, T.tensor[..., :3, :3])
    assert torch.equal(T.translation, T.tensor[..., :3, 3])
    # rotation and translation are copies: writing into them leaves the element as it was.
    t, R = T.translation.clone(), T.rotation.tensor.clone()
    T.translation.add_(1.0)
    T.rotation.tensor.add_(1.0)
    assert torch.equal(T.translation, t) and torch.equal(T.rotation.tensor, R)

    # The reported case: the identity residual is plain tensor arithmetic on the property.
    residual = (T @ T.inverse()).matrix - torch.eye(4, dtype=F64)
    assert residual.shape == (*batch, 4, 4)
    torch.testing.assert_close(residual, torch.zeros_like(residual), rtol=0, atol=1e-12)
    T32 = SE3.from_rt(so3.exp(torch.tensor([0.3, -0.2, 0.1])), torch.tensor([1.0, 2.0, 3.0]))
    residual = (T32 @ T32.inverse()).matrix - torch.eye(4)
    assert residual.dtype == torch.float32
    assert float(residual.abs().max()) <= 8 * torch.finfo(torch.float32).eps


def test_dir_lists_only_the_public_names():
    assert dir(torchlie.groups) == sorted(torchlie.groups.__all__)
    assert dir(torchlie.groups) == ["SE2", "SE3", "SO2", "SO3", "Sim3"]


def test_identity_random(grp, dtype):
    eye = grp.cls.identity(2, 3, dtype=dtype)
    assert eye.shape == (2, 3) and eye.dtype == dtype
    assert torch.equal(eye.tensor, grp.core.identity(2, 3, dtype=dtype))
    g1, g2 = torch.Generator().manual_seed(5), torch.Generator().manual_seed(5)
    X = grp.cls.random(4, generator=g1, dtype=dtype)
    assert torch.equal(X.tensor, grp.core.random(4, generator=g2, dtype=dtype))


def test_pi_rotation_through_classes():
    # Composition landing exactly at pi: the class returns the core's canonical log.
    R = SO3.exp(torch.tensor([0.0, 0.0, torch.pi / 2], dtype=F64))
    torch.testing.assert_close((R @ R).log(), torch.tensor([0.0, 0.0, torch.pi], dtype=F64))


def test_broadcasting_compose_and_act(grp):
    X = rand(grp, 4, 1)
    Y = rand(grp, 3, seed=2)
    assert (X @ Y).shape == (4, 3)
    assert (X @ torch.zeros(5, 3, dtype=F64)).shape == (4, 5, 3)


# ----------------------------------------------------------------------------------------------
# Container behaviour
# ----------------------------------------------------------------------------------------------


def test_indexing(grp):
    X = rand(grp, 5, 4)
    a = X.tensor
    assert X.shape == (5, 4) and X.ndim == 2 and len(X) == 5
    cases = [
        (X[0], a[0]),
        (X[1:3], a[1:3]),
        (X[..., 2], a[:, 2]),
        (X[-1, 1:], a[-1, 1:]),
        (X[None], a[None]),
        (X[torch.tensor([0, 2])], a[torch.tensor([0, 2])]),
        (X[torch.arange(20).reshape(5, 4) % 3 == 0], a[torch.arange(20).reshape(5, 4) % 3 == 0]),
    ]
    for got, want in cases:
        assert type(got) is grp.cls
        assert torch.equal(got.tensor, want)
        assert got.tensor.shape[-2:] == (grp.n, grp.n)
    assert X[0, 1].shape == ()
    assert [x.shape for x in X[0]] == [()] * 4
    assert all(torch.equal(x.tensor, a[i]) for i, x in enumerate(X))


def test_indexing_errors(grp):
    X = rand(grp, 5)
    with pytest.raises(IndexError):
        X[0, 0]  # only one batch dimension: the matrix dimensions are not indexable
    with pytest.raises(IndexError):
        X[5]
    with pytest.raises(TypeError, match="unbatched"):
        len(X[0])


def test_to_detach_requires_grad(grp, device):
    X = rand(grp, 3, dtype=torch.float32)
    Y = X.to(device=device, dtype=F64)
    assert type(Y) is grp.cls and Y.dtype == F64 and Y.device.type == device
    torch.testing.assert_close(Y.tensor.cpu(), X.tensor.double(), rtol=0, atol=0)
    Z = Y.clone().requires_grad_()
    assert Z.requires_grad and not Y.requires_grad
    D = (Z @ Z).detach()
    assert not D.requires_grad and D.tensor.grad_fn is None


def test_immutable_and_pickle(grp):
    X = rand(grp, 2)
    with pytest.raises(AttributeError, match="immutable"):
        X.tensor = X.tensor
    with pytest.raises(AttributeError, match="immutable"):
        del X.tensor
    with pytest.raises(AttributeError):
        X.extra = 1
    for Y in (pickle.loads(pickle.dumps(X)), copy.deepcopy(X), copy.copy(X)):
        assert type(Y) is grp.cls and torch.equal(Y.tensor, X.tensor)


def test_torch_save_and_load_with_the_default_weights_only(grp):
    # a checkpoint holding elements loads with torch.load's default (weights_only=True)
    X = rand(grp, 2)
    buf = io.BytesIO()
    torch.save({"pose": X, "list": [X[0]]}, buf)
    buf.seek(0)
    got = torch.load(buf)
    assert type(got["pose"]) is grp.cls and torch.equal(got["pose"].tensor, X.tensor)
    assert type(got["list"][0]) is grp.cls and torch.equal(got["list"][0].tensor, X.tensor[0])


def test_repr():
    assert repr(SO3.identity()) == (
        "SO3(tensor([[1., 0., 0.],\n            [0., 1., 0.],\n            [0., 0., 1.]]))"
    )
    r = repr(SE3.identity(2, dtype=F64))
    assert r.startswith("SE3(tensor([[[1., 0., 0., 0.],") and r.endswith("dtype=torch.float64))")
    assert " \n" not in r  # no trailing blanks on the separator line


def test_half_precision(grp):
    tau = tangent(grp, 4, dtype=torch.float16, scale=0.5)
    X = grp.cls.exp(tau)
    assert X.dtype == torch.float16
    ref = grp.core.exp(tau.double())
    h = torch.finfo(torch.float16).eps  # computed in float32, rounded once to half
    torch.testing.assert_close(X.tensor.double(), ref, rtol=h / 2, atol=h / 2)
    assert X.log().dtype == torch.float16
    assert (X @ X).dtype == torch.float16


# ----------------------------------------------------------------------------------------------
# Bad input
# ----------------------------------------------------------------------------------------------


def test_constructor_bad_shape_and_dtype(grp):
    name = grp.cls.__name__
    with pytest.raises(ValueError, match=rf"torchlie\.{name}: expected tensor of shape"):
        grp.cls(torch.zeros(2, grp.n + 1, grp.n))
    with pytest.raises(TypeError, match=rf"torchlie\.{name}"):
        grp.cls(torch.eye(grp.n, dtype=torch.int64))
    with pytest.raises(TypeError, match=rf"torchlie\.{name}"):
        grp.cls([[1.0, 0.0, 0.0]] * 3)


def test_constructor_check(grp):
    good = rand(grp, 3).tensor
    assert torch.equal(grp.cls(good, check=True).tensor, good)
    bad = good.clone()
    bad[1, 0, 0] += 1e-3
    grp.cls(bad)  # no value check by default (it would sync a GPU)
    with pytest.raises(ValueError, match=r"1 of 3 element\(s\) are not"):
        grp.cls(bad, check=True)
    grp.cls(bad, check=True, atol=1e-2)
    nan = good.clone()
    nan[2, 0, 1] = float("nan")
    with pytest.raises(ValueError):
        grp.cls(nan, check=True)


def test_from_quaternion_and_pos_quat_check():
    q = torch.tensor([[1.0, 0.0, 0.0, 0.0], [2.0, 0.0, 0.0, 0.0]], dtype=F64)
    assert torch.equal(SO3.from_quaternion(q).tensor, so3.identity(2, dtype=F64))  # scale-free
    with pytest.raises(ValueError, match="torchlie.SO3.from_quaternion: 1 of 2"):
        SO3.from_quaternion(q, check=True)
    pq = torch.cat((torch.ones(2, 3, dtype=F64), q), dim=-1)
    with pytest.raises(ValueError, match="torchlie.SE3.from_pos_quat: 1 of 2"):
        SE3.from_pos_quat(pq, check=True)
    SE3.from_pos_quat(pq[:1], check=True)


def _eyes(n: int, off: float) -> torch.Tensor:
    """Two identity matrices, the second with its (0, 0) entry off by ``off``."""
    M = torch.eye(n, dtype=F64).repeat(2, 1, 1)
    M[1, 0, 0] += off
    return M


def _q(off: float) -> torch.Tensor:
    return torch.tensor([[0.0, 0.0, 0.0, 1.0], [1.0 + off, 0.0, 0.0, 0.0]], dtype=F64)


#: Every constructor from a representation with a value constraint: (name, the call of its
#: arguments with the second element off by ``off``, what the check calls a valid value, the
#: call with a wrong trailing shape).  Each takes ``check=`` and ``atol=`` with one meaning.
VALUE_CONSTRUCTORS = [
    (
        "SO3.from_quaternion",
        lambda off, **kw: SO3.from_quaternion(_q(off), **kw),
        "unit quaternions",
        lambda **kw: SO3.from_quaternion(torch.ones(2, 3), **kw),
    ),
    (
        "SE3.from_pos_quat",
        lambda off, **kw: SE3.from_pos_quat(
            torch.cat((torch.ones(2, 3, dtype=F64), _q(off)), -1), **kw
        ),
        "unit quaternions",
        lambda **kw: SE3.from_pos_quat(torch.ones(2, 6), **kw),
    ),
    (
        "SE3.from_rt",
        lambda off, **kw: SE3.from_rt(_eyes(3, off), torch.ones(3, dtype=F64), **kw),
        "rotations",
        lambda **kw: SE3.from_rt(torch.eye(2), torch.ones(3), **kw),
    ),
    (
        "SO2.from_complex",
        lambda off, **kw: SO2.from_complex(_eyes(2, off)[:, 0], **kw),
        "unit complex numbers",
        lambda **kw: SO2.from_complex(torch.ones(2, 3), **kw),
    ),
    (
        "SE2.from_rt",
        lambda off, **kw: SE2.from_rt(_eyes(2, off), torch.ones(2, dtype=F64), **kw),
        "rotations",
        lambda **kw: SE2.from_rt(torch.eye(3), torch.ones(2), **kw),
    ),
    (
        "Sim3.from_srt",
        lambda off, **kw: Sim3.from_srt(
            torch.tensor(2.0, dtype=F64), _eyes(3, off), torch.ones(3, dtype=F64), **kw
        ),
        "rotations",
        lambda **kw: Sim3.from_srt(torch.tensor(2.0), torch.eye(3), torch.ones(4), **kw),
    ),
    (
        "Sim3.from_se3",
        lambda off, **kw: Sim3.from_se3(_eyes(4, off), torch.tensor(2.0, dtype=F64), **kw),
        "rigid poses",
        lambda **kw: Sim3.from_se3(torch.eye(3), torch.tensor(2.0), **kw),
    ),
]


@pytest.mark.parametrize(
    "name, make, what, bad_shape", VALUE_CONSTRUCTORS, ids=[c[0] for c in VALUE_CONSTRUCTORS]
)
def test_value_constructors_check_and_atol(name, make, what, bad_shape):
    cls_name, method = name.split(".")
    params = inspect.signature(getattr(getattr(torchlie.groups, cls_name), method)).parameters
    for opt, default in (("check", False), ("atol", None)):
        assert params[opt].kind is inspect.Parameter.KEYWORD_ONLY and params[opt].default is default
    good = make(0.0).tensor
    assert torch.equal(make(0.0, check=True).tensor, good)
    make(1e-3)  # no value check by default (it would sync a GPU)
    with pytest.raises(
        ValueError, match=rf"^torchlie\.{name}: 1 of 2 element\(s\) are not {what}$"
    ):
        make(1e-3, check=True)
    make(1e-3, check=True, atol=1e-2)
    with pytest.raises(ValueError, match=r"1 of 2 element\(s\)"):
        make(float("nan"), check=True, atol=1e-2)
    with pytest.raises(ValueError, match=rf"^torchlie\.{name}: expected atol"):
        make(0.0, atol=-1.0)  # checked even without check=True


@pytest.mark.parametrize(
    "name, make, what, bad_shape", VALUE_CONSTRUCTORS, ids=[c[0] for c in VALUE_CONSTRUCTORS]
)
def test_value_constructors_wrong_shape_error_same_with_and_without_check(
    name, make, what, bad_shape
):
    # the core's error, named through it: SE3.from_pos_quat said "expected pq" with check=True
    # and "(through torchlie.se3.from_pos_quat): expected x" without
    errors = []
    for check in (False, True):
        with pytest.raises(ValueError, match=rf"^torchlie\.{name} \(through torchlie\.") as e:
            bad_shape(check=check)
        errors.append(str(e.value))
    assert errors[0] == errors[1]


def test_sim3_constructors_check_positive_scales():
    # from_se3 with a negative or zero scale made diag(-2, -2, -2, 1) silently, check= or not
    T, R, t = torch.eye(4, dtype=F64), torch.eye(3, dtype=F64), torch.zeros(3, dtype=F64)
    for s in (torch.tensor([2.0, -2.0], dtype=F64), torch.tensor([2.0, 0.0], dtype=F64)):
        assert Sim3.from_se3(T, s).tensor.shape == (2, 4, 4)  # no value check by default
        msg = r": 1 of 2 element\(s\) are not positive scales$"
        with pytest.raises(ValueError, match=r"^torchlie\.Sim3\.from_se3" + msg):
            Sim3.from_se3(SE3(T), s, check=True)
        with pytest.raises(ValueError, match=r"^torchlie\.Sim3\.from_srt" + msg):
            Sim3.from_srt(s, R, t, check=True)


def test_from_rt_check():
    R = 1.01 * torch.eye(3, dtype=F64)
    SE3.from_rt(R, torch.zeros(3, dtype=F64))
    with pytest.raises(ValueError, match="torchlie.SE3.from_rt"):
        SE3.from_rt(R, torch.zeros(3, dtype=F64), check=True)


def test_operator_type_errors():
    R, T = SO3.identity(), SE3.identity()
    with pytest.raises(TypeError):
        R @ T
    with pytest.raises(TypeError):
        T @ R
    with pytest.raises(TypeError):
        R @ 2.0
    with pytest.raises(TypeError):
        torch.eye(3) @ R
    with pytest.raises(TypeError, match="torchlie.SO3.compose: expected another SO3, got SE3"):
        R.compose(T)
    with pytest.raises(TypeError, match="torchlie.SE3.rminus"):
        T.rminus(R)
    with pytest.raises(
        ValueError,
        match=r"torchlie\.SO3\.__matmul__ \(through torchlie\.so3\.act\): expected points",
    ):
        R @ torch.zeros(4)


# ----------------------------------------------------------------------------------------------
# Gradients, torch.func, torch.compile
# ----------------------------------------------------------------------------------------------


def test_gradients_flow(grp):
    tau = tangent(grp, 3).requires_grad_()
    Y = rand(grp, 3)
    p = torch.randn(3, 3, dtype=F64)
    loss = ((grp.cls.exp(tau) @ Y).inverse().apply(p) ** 2).sum()
    (g_cls,) = torch.autograd.grad(loss, tau)
    c = grp.core
    loss_f = (c.act(c.inverse(c.compose(c.exp(tau), Y.tensor)), p) ** 2).sum()
    (g_fun,) = torch.autograd.grad(loss_f, tau)
    assert torch.equal(g_cls, g_fun)
    assert torch.isfinite(g_cls).all() and g_cls.abs().sum() > 0


def test_gradcheck_through_classes(grp):
    Y = rand(grp, 2)

    def f(tau, v):
        X = grp.cls.exp(tau).rplus(v)
        return (X.between(Y) @ Y).log()

    tau = tangent(grp, 2).requires_grad_()
    v = tangent(grp, 2, seed=4, scale=0.3).requires_grad_()
    assert gradcheck(f, (tau, v))


def test_vmap_builds_classes_inside(grp):
    Y = rand(grp)

    def f(tau, pt):
        X = grp.cls.exp(tau) @ Y
        return X.inverse().apply(pt) + X[None][0].log()[:3]

    tau = tangent(grp, 6)
    pts = torch.randn(6, 3, dtype=F64)
    out = torch.func.vmap(f, in_dims=(0, 0))(tau, pts)
    ref = torch.stack([f(tau[i], pts[i]) for i in range(6)])
    torch.testing.assert_close(out, ref, rtol=0, atol=1e-13)
    assert out.shape == (6, 3)


def test_pytree_through_torch_func(grp):
    X = rand(grp, 5)

    # vmap over a function taking and returning group elements
    def f(A):
        return A.inverse() @ A.rplus(torch.ones(grp.dof, dtype=F64) * 0.1)

    out = torch.func.vmap(f)(X)
    assert type(out) is grp.cls and out.shape == (5,)
    torch.testing.assert_close(out.tensor, f(X).tensor, rtol=0, atol=1e-14)

    # grad with respect to a group element: the ambient gradient, wrapped in the same class
    def loss(A):
        return (A.log() ** 2).sum()

    g = torch.func.grad(loss)(X)
    assert type(g) is grp.cls
    a = X.tensor.clone().requires_grad_()
    (ref,) = torch.autograd.grad((grp.core.log(a) ** 2).sum(), a)
    torch.testing.assert_close(g.tensor, ref, rtol=0, atol=1e-14)

    leaves, spec = torch.utils._pytree.tree_flatten({"x": X, "n": 3})
    assert len(leaves) == 2 and any(leaf is X.tensor for leaf in leaves)
    back = torch.utils._pytree.tree_unflatten(leaves, spec)
    assert type(back["x"]) is grp.cls and back["x"].tensor is X.tensor


@pytest.mark.slow
@pytest.mark.compile
def test_compile_fullgraph():
    # torch 2.13's Dynamo cannot trace the ``@`` operator on user-defined classes, so
    # compiled code uses the named methods; the classes cross the boundary as pytrees.
    torch._dynamo.reset()

    def f(R: SO3, w: torch.Tensor, T: SE3, p: torch.Tensor):
        X = R.compose(SO3.exp(w)).inverse()
        Y = T.compose(SE3.from_rt(X, p)).rplus(torch.cat((p, w), -1))
        return X, Y.apply(p) + X.log() + Y.translation + Y.rotation.matrix[..., 0], Y[0]

    F32 = torch.float32
    R = rand(GROUPS[0], 4, dtype=F32)
    T = rand(GROUPS[1], 4, dtype=F32)
    w = torch.randn(4, 3, dtype=F32)
    p = torch.randn(4, 3, dtype=F32)
    cf = torch.compile(f, fullgraph=True, backend="aot_eager")  # see tests/test_compile.py
    got, want = cf(R, w, T, p), f(R, w, T, p)
    assert type(got[0]) is SO3 and type(got[2]) is SE3
    assert got[1].dtype == F32
    torch.testing.assert_close(got[0].tensor, want[0].tensor)
    torch.testing.assert_close(got[1], want[1])
    torch.testing.assert_close(got[2].tensor, want[2].tensor)
