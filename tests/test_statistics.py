"""torchlie.statistics: sampling, means, keyframe interpolation, alignment, kinematics."""

from __future__ import annotations

import math
from functools import partial

import numpy as np
import pytest
import torch
from samplers import eps
from scipy.spatial.transform import Rotation, Slerp
from torch.autograd import gradcheck

import torchlie.statistics
from torchlie import se2, se3, sim3, so2, so3
from torchlie.statistics import (
    Alignment,
    align,
    se2_integrate,
    se2_mean,
    se3_integrate,
    se3_interpolate_keyframes,
    se3_mean,
    se3_randn,
    sim3_mean,
    sim3_randn,
    so2_mean,
    so3_integrate,
    so3_interpolate_keyframes,
    so3_mean,
    so3_randn,
)

F64 = torch.float64


def gen(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


_DOF = {so3: 3, se3: 6, so2: 1, se2: 3, sim3: 7}
#: Every group's mean, for the properties they share.
MEANS = pytest.mark.parametrize(
    "core, mean_fn",
    [(so3, so3_mean), (se3, se3_mean), (so2, so2_mean), (se2, se2_mean), (sim3, sim3_mean)],
    ids=["so3", "se3", "so2", "se2", "sim3"],
)


def _fn(core, verb: str):
    """The statistics function ``<group>_<verb>`` of a group's functional module."""
    return getattr(torchlie.statistics, f"{core.__name__.rsplit('.', 1)[-1]}_{verb}")


#: Every group, for the sampling, keyframe and integration properties they share.
GROUPS = pytest.mark.parametrize("core", [so3, se3, so2, se2, sim3], ids=lambda c: c.__name__[9:])
#: The groups other than SO(3), whose tests of their own run on SO(3) only.
OTHER_GROUPS = pytest.mark.parametrize("core", [se3, so2, se2, sim3], ids=lambda c: c.__name__[9:])


def cluster(core, n: int, spread: float, *batch: int, seed: int = 0, dtype=F64) -> torch.Tensor:
    """``n`` elements ``M Exp(spread * N(0, I))`` about a random ``M`` per batch element."""
    g = gen(seed)
    M = core.random(*batch, generator=g, dtype=F64)
    tau = spread * torch.randn(*batch, n, _DOF[core], generator=g, dtype=F64)
    return core.rplus(M.unsqueeze(-3), tau).to(dtype)


def scipy_matrices(R: torch.Tensor) -> Rotation:
    return Rotation.from_matrix(R.double().numpy())


# ----------------------------------------------------------------------------------------------
# randn
# ----------------------------------------------------------------------------------------------


def _check_cov(eps_samples: torch.Tensor, cov: torch.Tensor) -> None:
    """Sample mean and covariance against the requested ones, within 5 standard errors.

    For N Gaussian samples the sample covariance entry S_ij has standard deviation
    sqrt((C_ii C_jj + C_ij^2) / N) and the sample mean m_i has sqrt(C_ii / N).
    """
    n = eps_samples.shape[0]
    m = eps_samples.mean(0)
    S = torch.cov(eps_samples.T)
    d = cov.diagonal()
    se_S = ((d[:, None] * d[None, :] + cov**2) / n).sqrt()
    assert ((S - cov).abs() <= 5 * se_S).all(), (S, cov)
    assert (m.abs() <= 5 * (d / n).sqrt()).all()
    # and the test can fail: a 10 % error in a variance is far outside the band
    assert not ((1.1 * S - cov).abs() <= 5 * se_S).all()


def test_dir_lists_only_the_public_names():
    names = dir(torchlie.statistics)
    assert names == sorted(torchlie.statistics.__all__)
    assert all(hasattr(torchlie.statistics, name) for name in names)
    assert not {"Float", "Tensor", "torch", "NamedTuple", "ModuleType", "so3", "se3"} & set(names)


def test_so3_randn_covariance():
    A = torch.tensor([[0.2, 0.0, 0.0], [0.05, 0.1, 0.0], [-0.03, 0.02, 0.15]], dtype=F64)
    cov = A @ A.T
    mean = so3.random(generator=gen(0), dtype=F64)
    R = so3_randn(mean, cov=cov, sample_shape=(20000,), generator=gen(1))
    assert R.shape == (20000, 3, 3)
    assert so3.is_valid(R).all()
    _check_cov(so3.rminus(R, mean), cov)
    # scale_tril gives the same draws as the covariance's Cholesky factor
    R2 = so3_randn(
        mean, scale_tril=torch.linalg.cholesky(cov), sample_shape=(20000,), generator=gen(1)
    )
    torch.testing.assert_close(R2, R, rtol=0, atol=1e-14)


@OTHER_GROUPS
def test_randn_covariance(core):
    """log(mean^-1 X) of the samples has the requested mean (0) and covariance, and scale_tril
    gives the same draws as the covariance's Cholesky factor."""
    n = _DOF[core]
    A = torch.randn(n, n, generator=gen(2), dtype=F64) * 0.1
    cov = A @ A.T + 0.01 * torch.eye(n, dtype=F64)
    mean = core.random(generator=gen(3), dtype=F64)
    X = _fn(core, "randn")(mean, cov=cov, sample_shape=(20000,), generator=gen(4))
    assert X.shape == (20000, *mean.shape) and X.dtype == F64
    assert core.is_valid(X).all()
    _check_cov(core.rminus(X, mean), cov)
    L = torch.linalg.cholesky(cov)
    X2 = _fn(core, "randn")(mean, scale_tril=L, sample_shape=(20000,), generator=gen(4))
    torch.testing.assert_close(X2, X, rtol=0, atol=1e-13 * float(X.abs().max()))


@GROUPS
def test_randn_isotropic_and_right_perturbation(core):
    n, randn = _DOF[core], _fn(core, "randn")
    mean = core.random(generator=gen(5), dtype=F64)
    X = randn(mean, 0.2, sample_shape=(20000,), generator=gen(6))
    _check_cov(core.rminus(X, mean), 0.04 * torch.eye(n, dtype=F64))
    # the noise is on the right: the same draw with the identity as the mean, left-multiplied
    X0 = randn(core.identity(dtype=F64), 0.2, sample_shape=(20000,), generator=gen(6))
    torch.testing.assert_close(X, mean @ X0, rtol=0, atol=1e-14 * float(mean.abs().max()))


def test_randn_singular_scale_tril():
    # rotation-only noise on SE(3): translation part of the twist is exactly zero
    L = torch.diag(torch.tensor([0.0, 0.0, 0.0, 0.1, 0.2, 0.3], dtype=F64))
    mean = se3.random(generator=gen(7), dtype=F64)
    T = se3_randn(mean, scale_tril=L, sample_shape=(500,), generator=gen(8))
    xi = se3.rminus(T, mean)
    assert xi[:, :3].abs().max() < 1e-12
    assert (xi[:, 3:].std(0) > 0.05).all()


def test_randn_shapes_and_broadcast(dtype):
    mean = so3.random(4, 1, generator=gen(0), dtype=dtype)
    std = torch.tensor([0.1, 0.2, 0.3], dtype=dtype)
    R = so3_randn(mean, std, sample_shape=(2,), generator=gen(1))
    assert R.shape == (2, 4, 3, 3, 3) and R.dtype == dtype
    cov = torch.eye(6, dtype=dtype).expand(5, 6, 6) * 0.01
    T = se3_randn(se3.identity(dtype=dtype), cov=cov, generator=gen(1))
    assert T.shape == (5, 4, 4)
    # per-element std: zero std gives the mean exactly
    R = so3_randn(mean.expand(4, 2, 3, 3), torch.tensor([0.0, 0.5], dtype=dtype), generator=gen(2))
    assert torch.equal(R[:, 0], mean[:, 0])
    assert (so3.distance(R[:, 1], mean[:, 0]) > 0).all()


@OTHER_GROUPS
def test_randn_shapes_dtype_and_generator(core, dtype):
    n, randn = _DOF[core], _fn(core, "randn")
    mean = core.random(4, 1, generator=gen(0), dtype=dtype)
    std = torch.tensor([0.1, 0.2, 0.3], dtype=dtype)
    X = randn(mean, std, sample_shape=(2,), generator=gen(1))
    assert X.shape == (2, 4, 3, *mean.shape[-2:]) and X.dtype == dtype
    assert core.is_valid(X).all()
    # the same generator state gives the same draws, another seed others
    assert torch.equal(randn(mean, std, sample_shape=(2,), generator=gen(1)), X)
    assert not torch.equal(randn(mean, std, sample_shape=(2,), generator=gen(2)), X)
    cov = torch.eye(n, dtype=dtype).expand(5, n, n) * 0.01
    assert randn(core.identity(dtype=dtype), cov=cov, generator=gen(1)).shape == (5, *X.shape[-2:])
    # per-element std: zero std gives the mean exactly
    X = randn(
        mean.expand(4, 2, *mean.shape[-2:]), torch.tensor([0.0, 0.5], dtype=dtype), generator=gen(2)
    )
    assert torch.equal(X[:, 0], mean[:, 0])
    assert (core.rminus(X[:, 1], mean[:, 0]).abs().amax(-1) > 0).all()


@OTHER_GROUPS
def test_randn_gradcheck(core):
    """X = M Exp(std z) with z fixed by the generator: derivatives in the mean (tangent
    coordinates), the standard deviation and the covariance's factor."""
    n, randn = _DOF[core], _fn(core, "randn")
    M = core.random(generator=gen(12), dtype=F64)
    d = torch.zeros(n, dtype=F64, requires_grad=True)
    std = torch.tensor([0.3, 0.1], dtype=F64, requires_grad=True)
    L = (0.1 * torch.eye(n, dtype=F64) + 0.01).tril().requires_grad_()
    assert gradcheck(lambda d, s: randn(core.rplus(M, d), s, generator=gen(13)), (d, std))
    assert gradcheck(
        lambda d, L: randn(core.rplus(M, d), scale_tril=L, sample_shape=(2,), generator=gen(13)),
        (d, L),
    )


@pytest.mark.parametrize("core", [so3, se3, so2, se2, sim3], ids=lambda c: c.__name__[9:])
def test_randn_covariance_derivatives(core):
    # A covariance is read as its symmetric part: reverse and forward mode both give the
    # derivatives of that function, in every entry (not one triangle's in one of the modes).
    n, randn = _DOF[core], _fn(core, "randn")
    M = core.random(generator=gen(14), dtype=F64)
    C = 0.01 * torch.eye(n, dtype=F64) + 1e-3 * torch.arange(n * n, dtype=F64).reshape(n, n) / n**2
    assert gradcheck(
        lambda C: randn(M, cov=C, sample_shape=(2,), generator=gen(15)),
        (C.requires_grad_(),),
        check_forward_ad=True,
    )


def test_randn_non_pd_cov_is_nan_for_its_element_only():
    cov = torch.stack((0.01 * torch.eye(3, dtype=F64), -torch.eye(3, dtype=F64)))
    R = so3_randn(torch.eye(3, dtype=F64), cov=cov, generator=gen(0))
    assert torch.isfinite(R[0]).all() and torch.isnan(R[1]).all()


def test_randn_reparameterised_gradients():
    # X = M Exp(std z): d rminus(X, M) / d std = z, and the mean's gradient flows
    mean = so3.random(generator=gen(9), dtype=F64).requires_grad_()
    std = torch.tensor(0.3, dtype=F64, requires_grad=True)
    R = so3_randn(mean, std, sample_shape=(4,), generator=gen(10))
    z = so3.rminus(R, mean).detach() / 0.3
    (g,) = torch.autograd.grad(so3.rminus(R, mean.detach()).sum(), std, retain_graph=True)
    torch.testing.assert_close(g, z.sum(), rtol=0, atol=1e-13)
    (gm,) = torch.autograd.grad((R * torch.arange(9.0, dtype=F64).reshape(3, 3)).sum(), mean)
    assert torch.isfinite(gm).all() and gm.abs().sum() > 0


def test_randn_half():
    R = so3_randn(torch.eye(3, dtype=torch.float16), 0.1, sample_shape=(3,), generator=gen(0))
    assert R.dtype == torch.float16
    R32 = so3_randn(torch.eye(3), 0.1, sample_shape=(3,), generator=gen(0))
    torch.testing.assert_close(R.float(), R32, rtol=0, atol=eps(torch.float16) / 2)


def test_randn_errors():
    I3 = torch.eye(3)
    with pytest.raises(ValueError, match="exactly one of std, cov and scale_tril, got none"):
        so3_randn(I3)
    with pytest.raises(ValueError, match="got std, cov"):
        so3_randn(I3, 0.1, cov=I3)
    with pytest.raises(
        ValueError, match=r"torchlie.statistics.se3_randn: expected cov of shape \(\.\.\., 6, 6\)"
    ):
        se3_randn(torch.eye(4), cov=I3)
    with pytest.raises(ValueError, match="torchlie.statistics.so3_randn: expected mean"):
        so3_randn(torch.eye(4), 0.1)
    with pytest.raises(TypeError, match="std"):
        so3_randn(I3, torch.tensor(1))
    with pytest.raises(ValueError, match="do not broadcast"):
        so3_randn(torch.eye(3).expand(2, 3, 3), torch.ones(3))
    fn = r"torchlie\.statistics\.so3_randn"
    with pytest.raises(TypeError, match=rf"{fn}: expected generator to be a torch.Generator or "
                       "None, got int 1"):  # fmt: skip
        so3_randn(I3, 0.1, generator=1)
    with pytest.raises(TypeError, match=rf"{fn}: expected sample_shape to be a tuple of ints "
                       r"\(a torch.Size\), got int 3"):  # fmt: skip
        so3_randn(I3, 0.1, sample_shape=3)
    with pytest.raises(TypeError, match=rf"{fn}: expected sample_shape .*, got tuple \(2.0,\)"):
        so3_randn(I3, 0.1, sample_shape=(2.0,))
    with pytest.raises(ValueError, match=rf"{fn}: expected sample_shape of non-negative sizes, "
                       r"got \(2, -1\)"):  # fmt: skip
        so3_randn(I3, 0.1, sample_shape=(2, -1))
    with pytest.raises(TypeError, match=r"torchlie\.statistics\.se3_randn: expected generator"):
        se3_randn(torch.eye(4), 0.1, generator=7)
    assert so3_randn(I3, 0.1, sample_shape=[2]).shape == (2, 3, 3)
    with pytest.raises(
        ValueError, match=r"torchlie.statistics.sim3_randn: expected cov of shape \(\.\.\., 7, 7\)"
    ):
        sim3_randn(torch.eye(4), cov=torch.eye(6))


@OTHER_GROUPS
def test_randn_errors_name_the_function(core):
    randn = _fn(core, "randn")
    fn, n, k = rf"torchlie\.statistics\.{randn.__name__}", core.identity().shape[-1], _DOF[core]
    I = torch.eye(n)
    with pytest.raises(ValueError, match=rf"^{fn}: expected mean of shape \(\.\.\., {n}, {n}\)"):
        randn(torch.eye(n + 1), 0.1)
    with pytest.raises(
        ValueError, match=rf"^{fn}: expected scale_tril of shape \(\.\.\., {k}, {k}\)"
    ):
        randn(I, scale_tril=torch.eye(k + 1))
    with pytest.raises(
        ValueError, match=rf"^{fn}: expected exactly one of std, cov and scale_tril"
    ):
        randn(I, 0.1, cov=torch.eye(k))
    with pytest.raises(TypeError, match=rf"^{fn}: expected generator to be a torch.Generator"):
        randn(I, 0.1, generator=0)
    with pytest.raises(ValueError, match=rf"^{fn}: expected sample_shape of non-negative sizes"):
        randn(I, 0.1, sample_shape=(-1,))


# ----------------------------------------------------------------------------------------------
# mean
# ----------------------------------------------------------------------------------------------


def test_chordal_mean_matches_scipy(dtype):
    # scipy's Rotation.mean is the chordal L2 mean, argmin sum_i w_i |R - R_i|_F^2, computed as
    # the top eigenvector of sum_i w_i q_i q_i^T.  Since |R(q) - R(p)|_F^2 = 8 (1 - (q.p)^2)
    # the two are the same minimiser, so they agree to rounding (not just approximately).
    R = cluster(so3, 30, 0.8, 6, seed=1)
    w = torch.rand(6, 30, generator=gen(2), dtype=F64)
    M = so3_mean(R.to(dtype), w.to(dtype), method="chordal")
    for b in range(6):
        ref = scipy_matrices(R[b]).mean(weights=w[b].numpy()).as_matrix()
        torch.testing.assert_close(
            M[b].double(), torch.from_numpy(ref), rtol=0, atol=40 * eps(dtype)
        )


def test_geodesic_mean_stationarity():
    # Karcher mean: sum_i w_i Log(M^T R_i) = 0; it differs from the chordal mean by O(spread^3)
    R = cluster(so3, 40, 0.3, 5, seed=3)
    w = torch.rand(5, 40, generator=gen(4), dtype=F64)
    wn = w / w.sum(-1, keepdim=True)
    M = so3_mean(R, w)
    res = (wn[..., None] * so3.rminus(R, M.unsqueeze(-3))).sum(-2)
    assert res.norm(dim=-1).max() < 1e-14
    C = so3_mean(R, w, method="chordal")
    res_c = (wn[..., None] * so3.rminus(R, C.unsqueeze(-3))).sum(-2)
    assert res_c.norm(dim=-1).min() > 1e-6  # the chordal mean is a different point
    # scipy's (chordal) mean is close to the geodesic one at this spread, as theory says
    ref = scipy_matrices(R[0]).mean(weights=w[0].numpy()).as_matrix()
    assert so3.distance(M[0], torch.from_numpy(ref)) < 1e-2


@MEANS
def test_geodesic_mean_is_stationary(core, mean_fn):
    # sum_i w_i Log(M^-1 X_i) = 0
    X = cluster(core, 12, 0.4, 3, seed=5)
    w = torch.rand(3, 12, generator=gen(6), dtype=F64) + 0.1
    M = mean_fn(X, w, iterations=20)
    res = (w[..., None] * core.rminus(X, M.unsqueeze(-3))).sum(-2)
    assert res.norm(dim=-1).max() < 1e-14


def test_geodesic_mean_converges_from_chordal_in_few_steps():
    R = cluster(so3, 40, 0.5, seed=6)
    r = []
    for k in range(6):
        M = so3_mean(R, iterations=k)
        r.append(float(so3.rminus(R, M).mean(0).norm()))
    assert all(b < 0.1 * a for a, b in zip(r, r[1:], strict=False))
    assert torch.equal(so3_mean(R, iterations=0), so3_mean(R, method="chordal"))


@MEANS
@pytest.mark.parametrize("method", ["chordal", "geodesic"])
def test_mean_of_single_element_is_itself(core, mean_fn, method, dtype):
    X = core.random(7, 1, generator=gen(0), dtype=dtype)
    M = mean_fn(X, method=method)
    torch.testing.assert_close(M, X[:, 0], rtol=0, atol=16 * eps(dtype))
    # and of N copies
    M = mean_fn(
        X.expand(7, 5, *X.shape[-2:]),
        torch.rand(7, 5, generator=gen(1), dtype=dtype),
        method=method,
    )
    torch.testing.assert_close(M, X[:, 0], rtol=0, atol=16 * eps(dtype))


@MEANS
@pytest.mark.parametrize("method", ["chordal", "geodesic"])
def test_mean_left_invariance(core, mean_fn, method):
    X = cluster(core, 20, 0.5, 3, seed=8)
    A = core.random(3, generator=gen(9), dtype=F64)
    w = torch.rand(3, 20, generator=gen(10), dtype=F64)
    lhs = mean_fn(A.unsqueeze(-3) @ X, w, method=method)
    rhs = A @ mean_fn(X, w, method=method)
    torch.testing.assert_close(lhs, rhs, rtol=0, atol=1e-13)


@MEANS
def test_geodesic_mean_right_invariance(core, mean_fn):
    X = cluster(core, 20, 0.4, 3, seed=11)
    B = core.random(3, generator=gen(12), dtype=F64)
    lhs = mean_fn(X @ B.unsqueeze(-3))
    rhs = mean_fn(X) @ B
    torch.testing.assert_close(lhs, rhs, rtol=0, atol=1e-13)


def test_se3_chordal_mean_is_not_right_invariant():
    X = cluster(se3, 20, 0.4, seed=13)
    B = se3.from_rt(torch.eye(3, dtype=F64), torch.tensor([1.0, 2.0, 3.0], dtype=F64))
    lhs = se3_mean(X @ B, method="chordal")
    rhs = se3_mean(X, method="chordal") @ B
    assert (lhs - rhs).abs().max() > 1e-3


def test_mean_of_two_is_the_midpoint():
    R = cluster(so3, 2, 1.0, 5, seed=14)
    mid = so3.interpolate(R[:, 0], R[:, 1], 0.5)
    for method in ("chordal", "geodesic"):
        torch.testing.assert_close(so3_mean(R, method=method), mid, rtol=0, atol=1e-14)
    # weighted: the geodesic mean lies at the weighted point of the geodesic
    w = torch.tensor([3.0, 1.0], dtype=F64)
    torch.testing.assert_close(
        so3_mean(R, w), so3.interpolate(R[:, 0], R[:, 1], 0.25), rtol=0, atol=1e-14
    )


def test_se3_mean_equal_rotations_is_translation_mean():
    R = so3.random(generator=gen(15), dtype=F64).expand(6, 3, 3)
    t = torch.randn(6, 3, generator=gen(16), dtype=F64)
    w = torch.rand(6, generator=gen(17), dtype=F64)
    M = se3_mean(se3.from_rt(R, t), w)
    torch.testing.assert_close(M[:3, 3], (w[:, None] * t).sum(0) / w.sum(), rtol=0, atol=1e-14)
    torch.testing.assert_close(M[:3, :3], R[0], rtol=0, atol=1e-14)


def test_mean_weights_broadcast_and_shapes(dtype):
    R = cluster(so3, 6, 0.3, 2, 3, seed=18, dtype=dtype)
    w = torch.rand(6, generator=gen(19), dtype=dtype)  # shared by every set
    M = so3_mean(R, w)
    assert M.shape == (2, 3, 3, 3) and M.dtype == dtype
    M1 = so3_mean(R[1, 2], w)
    torch.testing.assert_close(M[1, 2], M1, rtol=0, atol=8 * eps(dtype))
    # zero weight removes an element
    w0 = torch.cat((w[:5], torch.zeros(1, dtype=dtype)))
    torch.testing.assert_close(
        so3_mean(R, w0), so3_mean(R[..., :5, :, :], w[:5]), rtol=0, atol=8 * eps(dtype)
    )


def test_mean_nan_is_confined():
    R = cluster(so3, 4, 0.3, 3, seed=20)
    R[1, 2, 0, 0] = float("nan")
    R.requires_grad_()
    for method in ("chordal", "geodesic"):
        M = so3_mean(R, method=method)
        assert torch.isnan(M[1]).all()
        assert torch.isfinite(M[0]).all() and torch.isfinite(M[2]).all()
        (g,) = torch.autograd.grad(M[0].sum() + M[2].sum(), R)
        assert torch.isfinite(g[0]).all() and torch.isfinite(g[2]).all()
        if method == "chordal":  # the double where keeps even the bad element's gradient at 0
            assert torch.equal(g[1], torch.zeros_like(g[1]))


def test_mean_half():
    R = cluster(so3, 5, 0.3, 2, seed=21)
    M = so3_mean(R.half())
    assert M.dtype == torch.float16
    torch.testing.assert_close(M.double(), so3_mean(R), rtol=0, atol=2 * eps(torch.float16))


def test_mean_gradcheck():
    R = cluster(so3, 4, 0.5, seed=22)
    w = torch.rand(4, generator=gen(23), dtype=F64).requires_grad_()
    d = torch.zeros(4, 3, dtype=F64, requires_grad=True)
    for method in ("chordal", "geodesic"):

        def f(d, w, method=method):
            return so3_mean(so3.rplus(R, d), w, method=method, iterations=3)

        assert gradcheck(f, (d, w))
    # ambient coordinates (raw matrices), as a user's gradient sees them
    Rr = R.clone().requires_grad_()
    assert gradcheck(lambda X: so3_mean(X, iterations=3), (Rr,))
    T = cluster(se3, 3, 0.4, seed=24)
    e = torch.zeros(3, 6, dtype=F64, requires_grad=True)
    for method in ("chordal", "geodesic"):
        assert gradcheck(
            lambda e, method=method: se3_mean(se3.rplus(T, e), method=method, iterations=3), (e,)
        )


def test_mean_errors():
    R = so3.identity(4)
    with pytest.raises(ValueError, match="method 'chordal' or 'geodesic', got 'karcher'"):
        so3_mean(R, method="karcher")
    with pytest.raises(ValueError, match="iterations"):
        so3_mean(R, iterations=-1)
    with pytest.raises(
        ValueError, match=r"torchlie.statistics.so3_mean: expected R of shape \(\.\.\., N, 3, 3\)"
    ):
        so3_mean(torch.eye(3))
    with pytest.raises(ValueError, match="N >= 1"):
        so3_mean(torch.zeros(0, 3, 3))
    with pytest.raises(ValueError, match=r"expected weights of shape \(\.\.\., 4\)"):
        so3_mean(R, torch.ones(3))
    with pytest.raises(TypeError, match="weights"):
        so3_mean(R, torch.ones(4, dtype=torch.int64))
    with pytest.raises(TypeError):
        so3_mean(R, torch.ones(4, dtype=F64))
    with pytest.raises(ValueError, match="torchlie.statistics.se3_mean"):
        se3_mean(R)


# ----------------------------------------------------------------------------------------------
# Keyframe interpolation
# ----------------------------------------------------------------------------------------------


def _keys(K: int, seed: int = 0):
    times = torch.sort(torch.rand(K, generator=gen(seed), dtype=F64) * 10).values
    R = so3.random(K, generator=gen(seed + 1), dtype=F64)
    return times, R


def test_keyframes_match_scipy_slerp(dtype):
    times, R = _keys(7)
    q = torch.linspace(float(times[0]), float(times[-1]), 101, dtype=F64)
    out = so3_interpolate_keyframes(times.to(dtype), R.to(dtype), q.to(dtype))
    ref = Slerp(times.numpy(), scipy_matrices(R))(q.numpy()).as_matrix()
    tol = 1e-13 if dtype == F64 else 2e-5  # float32 times: the query's u moves by ~1e-6
    torch.testing.assert_close(out.double(), torch.from_numpy(ref), rtol=0, atol=tol)


def test_keyframes_hit_keyframes_and_clamp_or_extrapolate():
    times, R = _keys(5, seed=3)
    out = so3_interpolate_keyframes(times, R, times)
    torch.testing.assert_close(out, R, rtol=0, atol=4 * eps(F64))
    assert torch.equal(out[:-1], R[:-1])  # u = 0 exactly: Exp(0) = I, the keyframe itself
    before, after = times[0] - 2.0, times[-1] + 3.0
    clamped = so3_interpolate_keyframes(times, R, torch.stack((before, after)))
    torch.testing.assert_close(clamped, R[[0, -1]], rtol=0, atol=4 * eps(F64))
    ext = so3_interpolate_keyframes(times, R, torch.stack((before, after)), extrapolate=True)
    u0 = (before - times[0]) / (times[1] - times[0])
    u1 = (after - times[-2]) / (times[-1] - times[-2])
    torch.testing.assert_close(ext[0], so3.interpolate(R[0], R[1], u0), rtol=0, atol=1e-14)
    torch.testing.assert_close(ext[1], so3.interpolate(R[-2], R[-1], u1), rtol=0, atol=1e-14)


@GROUPS
def test_keyframes_are_the_end_keyframes_exactly(core):
    """At and beyond the ends (clamped) the result is the first / last keyframe bit for bit,
    and at the last time with extrapolate=True too; the derivative there is the last
    segment's."""
    fn = _fn(core, "interpolate_keyframes")
    times = torch.tensor([0.0, 1.0, 2.5], dtype=F64)
    K = core.exp(torch.randn(3, _DOF[core], generator=gen(4), dtype=F64))
    q = torch.tensor([-1.0, 0.0, 2.5, 3.0, 1e300], dtype=F64)
    out = fn(times, K, q)
    for i, k in enumerate((0, 0, 2, 2, 2)):
        assert torch.equal(out[i], K[k]), i
    assert torch.equal(fn(times, K, 2.5, extrapolate=True), K[2])
    s = torch.tensor(2.5, dtype=F64, requires_grad=True)
    (d,) = torch.autograd.grad(fn(times, K, s, extrapolate=True).sum(), s)
    h = 1e-6  # central differences of the extrapolated curve
    fd = fn(times, K, 2.5 + h, extrapolate=True) - fn(times, K, 2.5 - h, extrapolate=True)
    assert float(fd.abs().sum()) > 0
    torch.testing.assert_close(d, fd.sum() / (2 * h), atol=1e-7, rtol=0)


@pytest.mark.parametrize("dtype, big", [(F64, 1e308), (torch.float32, 3e38)], ids=["f64", "f32"])
def test_keyframes_with_a_span_beyond_the_largest_float(dtype, big):
    K = so3.exp(torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]], dtype=dtype))
    times = torch.tensor([-big, big], dtype=dtype)
    out = so3_interpolate_keyframes(times, K, torch.tensor([0.0, big / 2, -big / 2], dtype=dtype))
    z = torch.tensor([0.5, 0.75, 0.25], dtype=dtype)
    torch.testing.assert_close(so3.log(out)[:, 2], z, atol=4 * eps(dtype), rtol=0)


def test_keyframes_batched_shapes():
    times, _ = _keys(4, seed=5)
    R = so3.random(4, 2, 3, generator=gen(6), dtype=F64)  # 6 trajectories sharing the times
    q = torch.rand(5, 7, generator=gen(7), dtype=F64) * 10
    out = so3_interpolate_keyframes(times, R, q)
    assert out.shape == (5, 7, 2, 3, 3, 3)
    i, j, a, b = 3, 4, 1, 2
    ref = Slerp(times.numpy(), scipy_matrices(R[:, a, b]))(
        np.clip(q[i, j].numpy(), times[0].item(), times[-1].item())
    ).as_matrix()
    torch.testing.assert_close(out[i, j, a, b], torch.from_numpy(ref), rtol=0, atol=1e-13)
    # scalar query, single keyframe
    assert so3_interpolate_keyframes(times, R, 1.5).shape == (2, 3, 3, 3)
    one = so3_interpolate_keyframes(times[:1], R[:1], q)
    assert one.shape == (5, 7, 2, 3, 3, 3) and torch.equal(one[2, 3], R[0])


def test_se3_keyframes():
    times, R = _keys(6, seed=8)
    t = torch.randn(6, 3, generator=gen(9), dtype=F64)
    T = se3.from_rt(R, t)
    q = torch.linspace(float(times[0]), float(times[-1]), 41, dtype=F64)
    out = se3_interpolate_keyframes(times, T, q)
    # rotation part: the rotations' slerp
    ref = Slerp(times.numpy(), scipy_matrices(R))(q.numpy()).as_matrix()
    torch.testing.assert_close(out[:, :3, :3], torch.from_numpy(ref), rtol=0, atol=1e-13)
    # whole pose: the SE(3) geodesic of each segment
    k = (torch.searchsorted(times, q, right=True) - 1).clamp(0, 4)
    u = (q - times[k]) / (times[k + 1] - times[k])
    torch.testing.assert_close(out, se3.interpolate(T[k], T[k + 1], u), rtol=0, atol=1e-13)
    torch.testing.assert_close(se3_interpolate_keyframes(times, T, times), T, rtol=0, atol=1e-14)


@OTHER_GROUPS
def test_keyframes_hit_the_keyframes_and_agree_with_interpolate(core):
    """At the times, the keyframes; between, the group's geodesic interpolate of the two
    neighbours; before and after, the end keyframes or (extrapolate) the end segments'
    geodesics; several trajectories sharing the times."""
    fn = _fn(core, "interpolate_keyframes")
    times, _ = _keys(6, seed=8)
    K = core.random(6, 2, generator=gen(9), dtype=F64)  # two trajectories
    tol = 1e-13 * float(K.abs().max())
    torch.testing.assert_close(fn(times, K, times), K, rtol=0, atol=tol)
    q = torch.linspace(float(times[0]) - 1.0, float(times[-1]) + 1.0, 41, dtype=F64)
    out = fn(times, K, q)
    assert out.shape == (41, 2, *K.shape[-2:]) and out.dtype == F64
    k = (torch.searchsorted(times, q, right=True) - 1).clamp(0, 4)
    u = (q - times[k]) / (times[k + 1] - times[k])
    ref = core.interpolate(K[k], K[k + 1], u.clamp(0, 1)[:, None])
    torch.testing.assert_close(out, ref, rtol=0, atol=tol)
    assert torch.equal(out[0], K[0]) and torch.equal(out[-1], K[-1])
    ext = fn(times, K, q, extrapolate=True)
    torch.testing.assert_close(ext, core.interpolate(K[k], K[k + 1], u[:, None]), rtol=0, atol=tol)
    # a scalar query, one keyframe
    assert fn(times, K, 1.5).shape == K.shape[1:]
    one = fn(times[:1], K[:1], q)
    assert one.shape == out.shape and torch.equal(one[3], K[0])


def test_keyframes_gradcheck():
    times, R = _keys(4, seed=10)
    q = torch.tensor([times[0] + 0.1, (times[1] + times[2]) / 2, times[3] - 0.2], dtype=F64)
    d = torch.zeros(4, 3, dtype=F64, requires_grad=True)
    qq = q.clone().requires_grad_()
    assert gradcheck(lambda d, qq: so3_interpolate_keyframes(times, so3.rplus(R, d), qq), (d, qq))
    # at the exact keyframe time the derivative in the keyframes is the identity (u = 0)
    T = se3.random(3, generator=gen(11), dtype=F64)
    e = torch.zeros(3, 6, dtype=F64, requires_grad=True)
    tt = torch.tensor([0.0, 1.0, 2.0], dtype=F64)
    assert gradcheck(
        lambda e: se3_interpolate_keyframes(
            tt, se3.rplus(T, e), torch.tensor([0.4, 1.7], dtype=F64)
        ),
        (e,),
    )


@OTHER_GROUPS
def test_keyframes_gradcheck_every_group(core):
    fn = _fn(core, "interpolate_keyframes")
    times = torch.tensor([0.0, 1.0, 2.5], dtype=F64)
    K = core.random(3, generator=gen(14), dtype=F64)
    d = torch.zeros(3, _DOF[core], dtype=F64, requires_grad=True)
    q = torch.tensor([0.3, 1.7, 2.4, 3.0], dtype=F64, requires_grad=True)
    assert gradcheck(lambda d, q: fn(times, core.rplus(K, d), q, extrapolate=True), (d, q))


@GROUPS
def test_keyframes_derivative_in_time_at_a_keyframe_time(core):
    """At a keyframe time the derivative in the query time is the starting segment's (the
    right-sided one), whatever torch does at the bounds of ``clamp`` (its derivative there is
    0 since torch 2.15: it was 0 here at every keyframe time); at the first time too."""
    fn = _fn(core, "interpolate_keyframes")
    times = torch.tensor([0.0, 1.0, 3.0], dtype=F64)
    K = core.random(3, generator=gen(16), dtype=F64)
    G = torch.randn(K.shape[1:], generator=gen(17), dtype=F64)
    h = 1e-6
    for t in (0.0, 1.0):
        s = torch.tensor(t, dtype=F64, requires_grad=True)
        (g,) = torch.autograd.grad((fn(times, K, s) * G).sum(), s)
        right = ((fn(times, K, t + h) - fn(times, K, t)) * G).sum() / h
        torch.testing.assert_close(g, right, rtol=1e-5, atol=1e-8)
        assert float(g.abs()) > 1e-3


@GROUPS
def test_keyframes_vmap_over_queries(core):
    fn = _fn(core, "interpolate_keyframes")
    times, _ = _keys(5, seed=12)
    K = core.random(5, generator=gen(15), dtype=F64)
    q = torch.rand(8, generator=gen(13), dtype=F64) * 10
    out = torch.func.vmap(lambda s: fn(times, K, s))(q)
    tol = 4 * eps(F64) * float(K.abs().max())  # the batched products may round otherwise
    torch.testing.assert_close(out, fn(times, K, q), rtol=0, atol=tol)


def test_keyframes_errors():
    times, R = _keys(3)
    with pytest.raises(TypeError, match=r"expected extrapolate to be True or False, got str"):
        so3_interpolate_keyframes(times, R, 1.0, extrapolate="no")
    with pytest.raises(
        ValueError, match=r"expected keyframes of shape \(K, \.\.\., 3, 3\) with K = 3"
    ):
        so3_interpolate_keyframes(times, R[:2], 1.0)
    with pytest.raises(ValueError, match=r"expected times of shape \(K,\)"):
        so3_interpolate_keyframes(times[None], R, 1.0)
    with pytest.raises(TypeError, match="times"):
        so3_interpolate_keyframes(torch.arange(3), R, 1.0)
    with pytest.raises(TypeError, match="query_times"):
        so3_interpolate_keyframes(times, R, torch.tensor([1]))
    with pytest.raises(ValueError, match="torchlie.statistics.se3_interpolate_keyframes"):
        se3_interpolate_keyframes(times, R, 1.0)


@OTHER_GROUPS
def test_keyframes_errors_name_the_function(core):
    fn = _fn(core, "interpolate_keyframes")
    name, n = rf"torchlie\.statistics\.{fn.__name__}", core.identity().shape[-1]
    times, K = torch.tensor([0.0, 1.0, 2.0]), core.random(3)
    with pytest.raises(
        ValueError,
        match=rf"^{name}: expected keyframes of shape \(K, \.\.\., {n}, {n}\) with K = 3",
    ):
        fn(times, K[:2], 1.0)
    with pytest.raises(
        ValueError, match=rf"^{name}: expected keyframes of shape \(\.\.\., {n}, {n}\)"
    ):
        fn(times, torch.eye(n + 1).expand(3, n + 1, n + 1), 1.0)
    with pytest.raises(TypeError, match=rf"^{name}: expected extrapolate to be True or False"):
        fn(times, K, 1.0, extrapolate=1)


# ----------------------------------------------------------------------------------------------
# Alignment
# ----------------------------------------------------------------------------------------------


def test_align_matches_scipy_align_vectors(dtype):
    g = gen(30)
    b = torch.randn(10, 3, generator=g, dtype=F64)
    R_true = so3.random(generator=g, dtype=F64)
    a = b @ R_true.T + 0.1 * torch.randn(10, 3, generator=g, dtype=F64)
    w = torch.rand(10, generator=g, dtype=F64)
    ref, _ = Rotation.align_vectors(a.numpy(), b.numpy(), weights=w.numpy())
    fit = align(b.to(dtype), a.to(dtype), w.to(dtype), translation=False)
    torch.testing.assert_close(
        fit.rotation.double(), torch.from_numpy(ref.as_matrix()), rtol=0, atol=64 * eps(dtype)
    )
    assert torch.equal(fit.translation, torch.zeros(3, dtype=dtype))
    assert torch.equal(fit.scale, torch.ones((), dtype=dtype))


def test_align_recovers_similarity(batch, dtype):
    g = gen(31)
    P = torch.randn(*batch, 12, 3, generator=g, dtype=F64)
    R = so3.random(*batch, generator=g, dtype=F64)
    t = torch.randn(*batch, 3, generator=g, dtype=F64)
    s = torch.rand(batch, generator=g, dtype=F64) + 0.5
    Q = s[..., None, None] * P @ R.mT + t[..., None, :]
    fit = align(P.to(dtype), Q.to(dtype), scale=True)
    assert isinstance(fit, Alignment)
    tol = 200 * eps(dtype)
    torch.testing.assert_close(fit.rotation.double(), R, rtol=0, atol=tol)
    torch.testing.assert_close(fit.translation.double(), t, rtol=0, atol=tol * 10)
    torch.testing.assert_close(fit.scale.double(), s, rtol=0, atol=tol)
    rigid = align(P.to(dtype), (P @ R.mT + t[..., None, :]).to(dtype))
    torch.testing.assert_close(rigid.rotation.double(), R, rtol=0, atol=tol)
    torch.testing.assert_close(rigid.translation.double(), t, rtol=0, atol=tol * 10)


def _cost(P, Q, w, R, t, s):
    r = s[..., None, None] * P @ R.mT + t[..., None, :] - Q
    return (w * (r * r).sum(-1)).sum(-1)


@pytest.mark.parametrize("scale", [False, True])
def test_align_is_optimal_with_noise(scale):
    # the gradient of the cost in (rotation tangent, translation, log scale) vanishes
    g = gen(32)
    P = torch.randn(4, 9, 3, generator=g, dtype=F64)
    Q = 1.3 * P @ so3.random(4, generator=g, dtype=F64).mT + 0.3 * torch.randn(
        4, 9, 3, generator=g, dtype=F64
    )
    w = torch.rand(4, 9, generator=g, dtype=F64)
    fit = align(P, Q, w, scale=scale)
    d = torch.zeros(4, 3, dtype=F64, requires_grad=True)
    dt = torch.zeros(4, 3, dtype=F64, requires_grad=True)
    ds = torch.zeros(4, dtype=F64, requires_grad=True)
    cost = _cost(
        P, Q, w, so3.rplus(fit.rotation, d), fit.translation + dt, fit.scale * torch.exp(ds)
    )
    grads = torch.autograd.grad(cost.sum(), (d, dt, ds))
    assert grads[0].abs().max() < 1e-12 and grads[1].abs().max() < 1e-12
    if scale:
        assert grads[2].abs().max() < 1e-12
    else:
        assert grads[2].abs().min() > 1e-6  # s = 1 is not the optimal scale here


def test_align_reflection_fix():
    # Q is a mirror image of P: the best proper rotation (det +1), never the reflection
    g = gen(33)
    P = torch.randn(8, 3, generator=g, dtype=F64)
    Q = P * torch.tensor([1.0, 1.0, -1.0], dtype=F64)
    fit = align(P, Q)
    assert so3.is_valid(fit.rotation)
    assert torch.linalg.det(fit.rotation) > 0
    # and it beats every rotation of a dense random sample
    Rs = so3.random(5000, generator=g, dtype=F64)
    Pc, Qc = P - P.mean(0), Q - Q.mean(0)
    best = _cost(
        Pc,
        Qc,
        torch.ones(8, dtype=F64),
        fit.rotation,
        torch.zeros(3, dtype=F64),
        torch.ones((), dtype=F64),
    )
    others = _cost(
        Pc,
        Qc,
        torch.ones(8, dtype=F64),
        Rs,
        torch.zeros(5000, 3, dtype=F64),
        torch.ones(5000, dtype=F64),
    )
    assert best <= others.min()


def test_align_gradcheck():
    g = gen(34)
    P = torch.randn(6, 3, generator=g, dtype=F64, requires_grad=True)
    Q = (
        P.detach() @ so3.exp(torch.tensor([0.3, -0.2, 1.0], dtype=F64)).T
        + 0.2 * torch.randn(6, 3, generator=g, dtype=F64)
    ).requires_grad_()
    w = (torch.rand(6, generator=g, dtype=F64) + 0.5).requires_grad_()
    assert gradcheck(lambda P, Q, w: tuple(align(P, Q, w, scale=True)), (P, Q, w))
    assert gradcheck(lambda P, Q: align(P, Q, translation=False).rotation, (P, Q))


def test_align_broadcast_weights_and_half():
    g = gen(35)
    P = torch.randn(2, 1, 7, 3, generator=g, dtype=F64)
    Q = torch.randn(3, 7, 3, generator=g, dtype=F64)
    w = torch.rand(7, generator=g, dtype=F64)
    fit = align(P, Q, w, scale=True)
    assert (
        fit.rotation.shape == (2, 3, 3, 3)
        and fit.translation.shape == (2, 3, 3)
        and fit.scale.shape == (2, 3)
    )
    one = align(P[1, 0], Q[2], w, scale=True)
    torch.testing.assert_close(fit.rotation[1, 2], one.rotation, rtol=0, atol=1e-14)
    # half: a well-conditioned fit (Q a rotated copy of P) loses only the inputs' rounding
    R = so3.random(generator=g, dtype=F64)
    Q = P @ R.T + 0.01 * torch.randn(2, 1, 7, 3, generator=g, dtype=F64)
    h = align(P.half(), Q.half(), w.half())
    assert h.rotation.dtype == torch.float16
    ref = align(P, Q, w).rotation
    torch.testing.assert_close(h.rotation.double(), ref, rtol=0, atol=4 * eps(torch.float16))


#: magnitudes of the points whose products overflow or underflow (H, the spread), per dtype
_ALIGN_MAGNITUDES = {
    torch.float32: (1e21, 1e-25, 1e30, 1e-30, 1e36, 1e-36),
    torch.float64: (1e170, 1e-170, 1e250, 1e-250, 1e300, 1e-300),
}


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_align_at_every_magnitude(dtype):
    # equivariance: scaling both sets by c leaves R and s and scales t; scaling P by c and Q
    # by d divides s by c / d.  Checked against the fit at magnitude 1 and against the truth.
    g = gen(36)
    P = torch.randn(6, 3, generator=g, dtype=F64)
    R = so3.exp(torch.tensor([0.3, -0.5, 1.1], dtype=F64))
    t = torch.tensor([0.5, -1.0, 2.0], dtype=F64)
    Q = 2.0 * P @ R.T + t + 0.01 * torch.randn(6, 3, generator=g, dtype=F64)  # (noisy)
    tol = 16 * eps(dtype)
    for kw in ({"scale": True}, {"scale": False}, {"scale": True, "translation": False}):
        ref = align(P.to(dtype), Q.to(dtype), **kw)
        for c in _ALIGN_MAGNITUDES[dtype]:
            fit = align((c * P).to(dtype), (c * Q).to(dtype), **kw)
            for x in fit:
                assert bool(x.isfinite().all()), (kw, c, fit)
            torch.testing.assert_close(fit.rotation, ref.rotation, rtol=0, atol=tol)
            torch.testing.assert_close(fit.scale, ref.scale, rtol=tol, atol=0)
            torch.testing.assert_close(
                fit.translation.double() / c, ref.translation.double(), rtol=0, atol=tol * 8
            )
            assert so3.is_valid(fit.rotation)
            if kw.get("translation", True):  # the truth, within the noise
                assert float((fit.rotation.double() - R).abs().max()) < 0.02
    # P and Q at different magnitudes (the scale 1e30 or 1e200): its own factor each
    c, d = (1e-15, 1e15) if dtype == torch.float32 else (1e-100, 1e100)
    fit = align((c * P).to(dtype), (d * Q).to(dtype), scale=True)
    ref = align(P.to(dtype), Q.to(dtype), scale=True)
    torch.testing.assert_close(fit.rotation, ref.rotation, rtol=0, atol=tol)
    torch.testing.assert_close(fit.scale.double() * c / d, ref.scale.double(), rtol=tol, atol=0)
    torch.testing.assert_close(
        fit.translation.double() / d, ref.translation.double(), rtol=0, atol=tol * 8
    )


@pytest.mark.parametrize("scale", [False, True])
@pytest.mark.parametrize("far, small", [(1e4, 1.0), (1e12, 1.0), (1e308, 1e-3)])
def test_align_a_far_point_of_zero_weight_changes_nothing(far, small, scale):
    """A point of zero weight changes nothing, wherever it is and whatever its index (centring
    through the first point and scaling by the largest coordinate lost the others' digits)."""
    P = torch.randn(6, 3, generator=gen(0), dtype=F64) * small
    R = so3.exp(torch.tensor([0.3, -0.2, 0.5], dtype=F64))
    Q = P @ R.mT + torch.tensor([1.0, -2.0, 0.5], dtype=F64) * small
    P[0] = far
    w = torch.tensor([0.0, 1.0, 1.0, 1.0, 1.0, 1.0], dtype=F64)
    ref = align(P[1:], Q[1:], scale=scale)
    for k in (0, 3):  # the point first, then in the middle
        fit = align(P.roll(k, 0), Q.roll(k, 0), w.roll(k), scale=scale)
        torch.testing.assert_close(fit.rotation, ref.rotation, atol=4e-15, rtol=0)
        torch.testing.assert_close(fit.translation, ref.translation, atol=8e-15 * small, rtol=0)
        torch.testing.assert_close(fit.scale, ref.scale, atol=4e-15, rtol=0)


@pytest.mark.parametrize("dtype, big", [(F64, 1e308), (torch.float32, 2e38)], ids=["f64", "f32"])
def test_weights_whose_sum_overflows(dtype, big):
    """Weights are scale-invariant up to the largest finite ones (w / sum(w) gave w / inf)."""
    R = so3.exp(torch.randn(3, 3, generator=gen(1), dtype=F64) * 0.5).to(dtype)
    T = se3.exp(torch.randn(3, 6, generator=gen(2), dtype=F64)).to(dtype)
    w = torch.full((3,), big, dtype=dtype)
    tol = 8 * eps(dtype)
    torch.testing.assert_close(so3_mean(R, w), so3_mean(R), atol=tol, rtol=0)
    torch.testing.assert_close(se3_mean(T, w), se3_mean(T), atol=4 * tol, rtol=0)
    P = torch.randn(5, 3, generator=gen(3), dtype=F64).to(dtype)
    Q = P @ R[0].mT + 1.0
    fit, ref = align(P, Q, torch.full((5,), big, dtype=dtype)), align(P, Q)
    torch.testing.assert_close(fit.rotation, ref.rotation, atol=tol, rtol=0)
    torch.testing.assert_close(fit.translation, ref.translation, atol=4 * tol, rtol=0)


def test_align_magnitudes_per_element_and_gradients():
    # a batch of sets at 1e-170, 1 and 1e170: each its own fit (the same as alone, within the
    # rounding of the batched products), and the gradients scale as 1 / c (homogeneity)
    g = gen(37)
    P = torch.randn(6, 3, generator=g, dtype=F64)
    Q = 1.5 * P @ so3.exp(torch.tensor([0.2, 0.9, -0.4], dtype=F64)).T
    Q = Q + 0.05 * torch.randn(6, 3, generator=g, dtype=F64)
    cs = torch.tensor([1e-170, 1.0, 1e170], dtype=F64)[:, None, None]
    Pc, Qc = (cs * P).requires_grad_(), (cs * Q).requires_grad_()
    fit = align(Pc, Qc, scale=True)
    alone = align(P, Q, scale=True)
    for i in range(3):
        torch.testing.assert_close(fit.rotation[i], alone.rotation, rtol=0, atol=1e-15)
        torch.testing.assert_close(fit.scale[i], alone.scale, rtol=1e-15, atol=0)
    P1, Q1 = P.clone().requires_grad_(), Q.clone().requires_grad_()
    f1 = align(P1, Q1, scale=True)
    want = torch.autograd.grad(f1.scale + f1.rotation[0, 1], (P1, Q1))
    got = torch.autograd.grad((fit.scale + fit.rotation[:, 0, 1]).sum(), (Pc, Qc))
    for a, b in zip(got, want, strict=True):
        torch.testing.assert_close(a * cs, b.expand_as(a), rtol=1e-12, atol=1e-12)


def test_align_sets_at_the_origin_keep_finite_gradients():
    # a set all at the origin has the smallest scaling factor: the ratio of the factors
    # overflows, and must stay out of the result and its gradient (the documented s = 1 / 0)
    for dtype in (torch.float32, torch.float64):
        big = 0.25 * torch.finfo(dtype).max ** 0.5
        for zero_p in (True, False):
            X = torch.randn(5, 3, generator=gen(38), dtype=dtype) * big
            P = torch.zeros_like(X) if zero_p else X
            Q = X if zero_p else torch.zeros_like(X)
            P, Q = P.clone().requires_grad_(), Q.clone().requires_grad_()
            fit = align(P, Q, scale=True)
            assert float(fit.scale.detach()) == (1.0 if zero_p else 0.0)
            assert torch.equal(fit.rotation, torch.eye(3, dtype=dtype))
            out = fit.scale + fit.rotation.sum() + fit.translation.sum() / big
            for g in torch.autograd.grad(out, (P, Q)):
                assert bool(g.isfinite().all())


def test_align_errors():
    P = torch.randn(5, 3)
    for kw in ({"scale": "yes"}, {"translation": 0}, {"scale": torch.tensor(True)}):
        with pytest.raises(
            TypeError, match=rf"statistics.align: expected {next(iter(kw))} to be True or False"
        ):
            align(P, P, **kw)
    with pytest.raises(
        ValueError,
        match=r"statistics.align: expected P and Q of shape \(\.\.\., N, 3\) with the same N",
    ):
        align(P, P[:4])
    with pytest.raises(ValueError, match=r"expected Q of shape \(\.\.\., 3\)"):
        align(P, torch.randn(5, 2))
    with pytest.raises(ValueError, match=r"expected weights of shape \(\.\.\., 5\)"):
        align(P, P, torch.ones(4))
    with pytest.raises(TypeError):
        align(P, P.double())
    with pytest.raises(TypeError):
        align(P.long(), P.long())


# ----------------------------------------------------------------------------------------------
# Kinematics
# ----------------------------------------------------------------------------------------------


@GROUPS
def test_integrate_against_matrix_exp(core, dtype):
    g = gen(40)
    X = core.random(4, generator=g, dtype=F64)
    v = torch.randn(4, _DOF[core], generator=g, dtype=F64)
    dt = torch.rand(4, generator=g, dtype=F64)
    E = torch.linalg.matrix_exp(core.hat(v) * dt[:, None, None])
    tol = 16 * eps(dtype) * float(X.abs().max())
    integrate = _fn(core, "integrate")
    out = integrate(X.to(dtype), v.to(dtype), dt.to(dtype))
    assert out.dtype == dtype
    torch.testing.assert_close(out.double(), X @ E, rtol=0, atol=tol)
    out = integrate(X.to(dtype), v.to(dtype), dt.to(dtype), frame="world")
    torch.testing.assert_close(out.double(), E @ X, rtol=0, atol=tol)


@GROUPS
def test_integrate_is_rplus_or_lplus_of_the_step(core):
    g = gen(42)
    X = core.random(3, generator=g, dtype=F64)
    v = torch.randn(3, _DOF[core], generator=g, dtype=F64)
    dt = torch.tensor([0.0, 0.5, -1.5], dtype=F64)
    integrate, tol = _fn(core, "integrate"), 4 * eps(F64) * float(X.abs().max())
    step = dt[:, None] * v
    torch.testing.assert_close(integrate(X, v, dt), core.rplus(X, step), rtol=0, atol=tol)
    torch.testing.assert_close(integrate(X, v, dt, "world"), core.lplus(X, step), rtol=0, atol=tol)
    assert torch.equal(integrate(X, v, dt)[0], X[0])  # dt = 0: Exp(0) = I


@GROUPS
def test_integrate_body_world_agree_and_compose(core):
    g = gen(41)
    X = core.random(3, generator=g, dtype=F64)
    v = torch.randn(3, _DOF[core], generator=g, dtype=F64)
    v_world = (core.adjoint(X) @ v[..., None])[..., 0]
    integrate, tol = _fn(core, "integrate"), 1e-13 * float(X.abs().max())
    torch.testing.assert_close(
        integrate(X, v, 0.7), integrate(X, v_world, 0.7, "world"), rtol=0, atol=tol
    )
    two = integrate(integrate(X, v, 0.3), v, 0.4)
    torch.testing.assert_close(two, integrate(X, v, 0.7), rtol=0, atol=tol)


def test_integrate_a_constant_body_twist_traces_a_circle():
    # forward speed v and yaw rate r: a circle of radius v/r, half of it after pi/r
    circle = se3_integrate(
        se3.identity(dtype=F64), torch.tensor([2.0, 0, 0, 0, 0, 0.5], dtype=F64), math.pi / 0.5
    )
    torch.testing.assert_close(
        circle[:3, 3], torch.tensor([0.0, 8.0, 0.0], dtype=F64), rtol=0, atol=1e-14
    )
    planar = se2_integrate(
        se2.identity(dtype=F64), torch.tensor([2.0, 0, 0.5], dtype=F64), math.pi / 0.5
    )
    torch.testing.assert_close(
        se2.to_xytheta(planar), torch.tensor([0.0, 8.0, math.pi], dtype=F64), rtol=0, atol=1e-14
    )


@OTHER_GROUPS
def test_integrate_gradcheck(core):
    """Derivatives in the element (tangent coordinates), the velocity and the time step."""
    integrate = _fn(core, "integrate")
    X = core.random(2, generator=gen(43), dtype=F64)
    d = torch.zeros(2, _DOF[core], dtype=F64, requires_grad=True)
    v = torch.randn(2, _DOF[core], generator=gen(44), dtype=F64).requires_grad_()
    dt = torch.tensor([0.3, -0.8], dtype=F64, requires_grad=True)
    for frame in ("body", "world"):
        f = partial(lambda d, v, dt, frame: integrate(core.rplus(X, d), v, dt, frame), frame=frame)
        assert gradcheck(f, (d, v, dt))


@OTHER_GROUPS
def test_integrate_errors_name_the_function(core):
    integrate = _fn(core, "integrate")
    name, n, k = (
        rf"torchlie\.statistics\.{integrate.__name__}",
        core.identity().shape[-1],
        _DOF[core],
    )
    X, v = ("R", "omega") if core is so2 else ("T", "xi")
    with pytest.raises(
        ValueError, match=rf"^{name}: expected frame 'body' or 'world', got 'space'"
    ):
        integrate(torch.eye(n), torch.zeros(k), 1.0, frame="space")
    with pytest.raises(ValueError, match=rf"^{name}: expected {v} of shape \(\.\.\., {k}\)"):
        integrate(torch.eye(n), torch.zeros(k + 1), 1.0)
    with pytest.raises(ValueError, match=rf"^{name}: expected {X} of shape \(\.\.\., {n}, {n}\)"):
        integrate(torch.eye(n + 1), torch.zeros(k), 1.0)
    with pytest.raises(TypeError, match=rf"^{name}: expected inputs of one dtype"):
        integrate(torch.eye(n), torch.zeros(k, dtype=F64), 1.0)
    with pytest.raises(ValueError, match=rf"^{name}: .*do not broadcast"):
        integrate(torch.eye(n).expand(2, n, n), torch.zeros(3, k), 1.0)
    assert integrate(torch.eye(n), torch.randn(4, 1, k), torch.rand(5)).shape == (4, 5, n, n)


def test_integrate_broadcast_and_errors():
    out = so3_integrate(torch.eye(3), torch.randn(4, 1, 3), torch.rand(5))
    assert out.shape == (4, 5, 3, 3)
    with pytest.raises(ValueError, match="frame 'body' or 'world', got 'space'"):
        se3_integrate(torch.eye(4), torch.zeros(6), 1.0, frame="space")
    with pytest.raises(
        ValueError,
        match=r"torchlie.statistics.se3_integrate: expected xi of shape \(\.\.\., 6\)",
    ):
        se3_integrate(torch.eye(4), torch.zeros(3), 1.0)
    with pytest.raises(TypeError, match="dt"):
        so3_integrate(torch.eye(3), torch.zeros(3), "1")


# ----------------------------------------------------------------------------------------------
# torch.compile
# ----------------------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.compile
def test_compile_fullgraph():
    torch._dynamo.reset()

    def f(R, w, times, q, P, Q):
        M = so3_mean(R, w, iterations=1)
        traj = so3_interpolate_keyframes(times, R, q)
        fit = align(P, Q, w, scale=True)
        return M, traj, fit.rotation, fit.scale

    F32 = torch.float32
    R = cluster(so3, 6, 0.5, seed=50, dtype=F32)
    w = torch.rand(6, generator=gen(51), dtype=F32)
    times = torch.arange(6, dtype=F32)
    q = torch.rand(4, generator=gen(52), dtype=F32) * 5
    P = torch.randn(6, 3, generator=gen(53), dtype=F32)
    Q = torch.randn(6, 3, generator=gen(54), dtype=F32)
    got = torch.compile(f, fullgraph=True, backend="aot_eager")(R, w, times, q, P, Q)
    want = f(R, w, times, q, P, Q)
    for a, b in zip(got, want, strict=True):
        assert a.dtype == F32
        torch.testing.assert_close(a, b)


@pytest.mark.slow
@pytest.mark.compile
@OTHER_GROUPS
def test_compile_fullgraph_every_group(core):
    """Keyframes, integration and sampling of each group in one fullgraph-compiled function."""
    torch._dynamo.reset()
    keyframes, integrate, randn = (
        _fn(core, v) for v in ("interpolate_keyframes", "integrate", "randn")
    )

    def f(times, K, q, v, dt, L):
        traj = keyframes(times, K, q, extrapolate=True)
        return traj, integrate(traj, v, dt, "world"), randn(K, scale_tril=L, generator=None)

    F32 = torch.float32
    K = core.random(5, generator=gen(55), dtype=F32)
    times = torch.arange(5, dtype=F32)
    q = torch.tensor([-0.5, 0.0, 1.25, 3.5, 4.0, 4.5], dtype=F32)
    v = torch.randn(_DOF[core], generator=gen(56), dtype=F32)
    dt = torch.rand(6, generator=gen(57), dtype=F32)
    L = torch.zeros(_DOF[core], _DOF[core], dtype=F32)  # zero noise: the draw is the mean
    got = torch.compile(f, fullgraph=True, backend="aot_eager")(times, K, q, v, dt, L)
    want = f(times, K, q, v, dt, L)
    for a, b in zip(got, want, strict=True):
        assert a.dtype == F32
        torch.testing.assert_close(a, b, rtol=0, atol=64 * eps(F32) * float(b.abs().max()))


def test_align_nan_is_confined():
    P = torch.randn(3, 6, 3, generator=gen(60), dtype=F64)
    Q = torch.randn(3, 6, 3, generator=gen(61), dtype=F64)
    Q[1, 4, 2] = float("nan")
    Q.requires_grad_()
    fit = align(P, Q, scale=True)
    for x in fit:
        assert torch.isnan(x[1]).all()
        assert torch.isfinite(x[0]).all() and torch.isfinite(x[2]).all()
    (g,) = torch.autograd.grad(fit.rotation[0].sum() + fit.scale[2], Q)
    assert torch.isfinite(g[0]).all() and torch.isfinite(g[2]).all()
    torch.testing.assert_close(fit.rotation[2], align(P[2], Q[2]).rotation, rtol=0, atol=0)


@pytest.mark.parametrize("where", ["P", "weights"])
@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_align_nan_or_inf_in_p_or_the_weights_gives_a_nan_scale(where, bad):
    # every part of that element's fit is NaN, its scale too (not the scale of coinciding points)
    P = torch.randn(3, 6, 3, generator=gen(62), dtype=F64)
    Q = 2.0 * P + 1.0
    w = torch.ones(3, 6, dtype=F64)
    (P if where == "P" else w)[1, 4, ...] = bad
    fit = align(P, Q, w, scale=True)
    for x in fit:
        assert torch.isnan(x[1]).all()
        assert torch.isfinite(x[0]).all() and torch.isfinite(x[2]).all()


def test_vmap_mean_and_align():
    R = cluster(so3, 5, 0.4, 4, seed=70)
    w = torch.rand(4, 5, generator=gen(71), dtype=F64)
    out = torch.func.vmap(lambda r, v: so3_mean(r, v))(R, w)
    torch.testing.assert_close(out, so3_mean(R, w), rtol=0, atol=1e-14)
    T = cluster(se3, 5, 0.4, 4, seed=72)
    out = torch.func.vmap(se3_mean)(T)
    torch.testing.assert_close(out, se3_mean(T), rtol=0, atol=1e-14)
    P = torch.randn(4, 7, 3, generator=gen(73), dtype=F64)
    Q = torch.randn(4, 7, 3, generator=gen(74), dtype=F64)
    fit = torch.func.vmap(lambda p, q: tuple(align(p, q, scale=True)))(P, Q)
    for a, b in zip(fit, align(P, Q, scale=True), strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-14)


def test_device(device):
    R = cluster(so3, 5, 0.4, 3, seed=80)
    P = torch.randn(3, 7, 3, generator=gen(81), dtype=F64)
    times = torch.arange(5, dtype=F64)
    q = torch.tensor([0.5, 2.25, 6.0], dtype=F64)
    cpu = (
        so3_mean(R),
        align(P, P.flip(-2), scale=True).rotation,
        so3_interpolate_keyframes(times, R[0], q),
    )
    dev = (
        so3_mean(R.to(device)),
        align(P.to(device), P.flip(-2).to(device), scale=True).rotation,
        so3_interpolate_keyframes(times.to(device), R[0].to(device), q.to(device)),
    )
    for a, b in zip(dev, cpu, strict=True):
        assert a.device.type == device
        torch.testing.assert_close(a.cpu(), b, rtol=0, atol=1e-12)
    g = torch.Generator(device=device).manual_seed(0)
    X = se3_randn(se3.identity(dtype=F64, device=device), 0.1, sample_shape=(4,), generator=g)
    assert X.device.type == device and se3.is_valid(X).all()


@pytest.mark.parametrize("spread", [0.5, 3.0, 5.0, 40.0])
def test_sim3_geodesic_mean_at_any_spread_of_scales(spread):
    """The Sim(3) barycenter of two similarities is their midpoint, and of a set it is
    stationary, however far apart the scales are (the plain fixed-point step diverges once the
    log-scales differ by a few units)."""
    R = so3.exp(torch.tensor([[0.1, -0.2, 0.3], [0.4, 0.5, -0.6]], dtype=F64))
    s = torch.tensor([spread, -spread], dtype=F64).exp()
    T = sim3.from_srt(s, R, torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 2.0]], dtype=F64))
    M = sim3_mean(T)
    mid = sim3.interpolate(T[0], T[1], 0.5)
    torch.testing.assert_close(M, mid, rtol=1e-13, atol=1e-13)
    xi = torch.randn(9, 7, generator=gen(30), dtype=F64)
    X = sim3.rplus(T[0], xi * torch.tensor([2.0] * 3 + [0.3] * 3 + [spread], dtype=F64))
    w = torch.rand(9, generator=gen(31), dtype=F64) + 0.1
    M = sim3_mean(X, w, iterations=20)
    d = sim3.rminus(X, M)
    res = (w[..., None] * d).sum(-2)  # relative to the terms summed
    assert float(res.norm()) < 1e-14 * float((w[..., None] * d).norm(dim=-1).sum())


@pytest.mark.parametrize(
    ("core", "mean_fn", "rot_mean"),
    [(se3, se3_mean, so3_mean), (se2, se2_mean, so2_mean), (sim3, sim3_mean, so3_mean)],
)
def test_geodesic_mean_rotation_is_the_rotations_karcher_mean(core, mean_fn, rot_mean):
    """The rotation part of the barycenter equation does not involve the translations."""
    X = cluster(core, 15, 0.8, 3, seed=32)
    M = mean_fn(X)
    d = X.shape[-1] - 1
    if core is sim3:
        X, M = sim3.to_srt(X)[1], sim3.to_srt(M)[1]
    torch.testing.assert_close(M[..., :d, :d], rot_mean(X[..., :d, :d]), rtol=0, atol=1e-14)
