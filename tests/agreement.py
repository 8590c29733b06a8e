"""Agreement of two evaluations of one result, to the rounding that torch, BLAS and the CPU
decide (their vectorised and scalar loops, small matrix products and BLAS kernels round
differently by layout, batch size and CPU): bits are never compared there."""

from __future__ import annotations

import torch

#: Largest difference allowed between two evaluations of one result element, in units of the
#: dtype's epsilon times the element's norm (over its event dimensions).
ULPS = 2.0


def flat(result) -> list[torch.Tensor]:
    """The tensors of a result (a tensor, or a tuple or list of them)."""
    return list(result) if isinstance(result, (tuple, list)) else [result]


def assert_agree(got, want, what: str, batch_dims: int = 1, ulps: float = ULPS) -> None:
    """``got`` agrees with ``want``: shapes and dtypes equal, NaN and infinities at the same
    places (infinities of the same sign), booleans and integers equal, and finite numbers within
    ``ulps`` epsilons of each element's norm (the first ``batch_dims`` dimensions index the
    elements, the others hold an element's value)."""
    got, want = flat(got), flat(want)
    assert len(got) == len(want), what
    for i, (a, b) in enumerate(zip(got, want, strict=True)):
        assert a.shape == b.shape and a.dtype == b.dtype, f"{what}: output {i}"
        if not (a.is_floating_point() or a.is_complex()):
            assert torch.equal(a, b), f"{what}: output {i} differs in {int((a != b).sum())} numbers"
            continue
        eps = torch.finfo(a.dtype).eps
        if a.is_complex():
            a, b = torch.view_as_real(a), torch.view_as_real(b)
            batch_dims = min(batch_dims, a.dim() - 1)
        same = torch.equal(a.isnan(), b.isnan()) and torch.equal(a.isinf(), b.isinf())
        assert same, f"{what}: output {i} has NaN or inf at other places"
        assert torch.equal(a[a.isinf()], b[b.isinf()]), f"{what}: output {i}: infinities differ"
        a, b = (x.double().nan_to_num(0.0, 0.0, 0.0) for x in (a, b))
        d = min(batch_dims, a.dim())
        scale = b.flatten(d).norm(dim=-1) if d < a.dim() else b.abs()
        scale = scale.reshape(scale.shape + (1,) * (a.dim() - d))
        err = (a - b).abs() / (eps * scale).clamp_min(1e-300)
        worst = float(err.max()) if err.numel() else 0.0
        assert worst <= ulps, f"{what}: output {i} differs by {worst:.3g} eps of its norm"


def assert_bits(got, want, what: str) -> None:
    """Bitwise equality (signs of zeros and NaN payloads included): for what torchlie alone
    writes, such as copies of its inputs."""
    for i, (a, b) in enumerate(zip(flat(got), flat(want), strict=True)):
        assert a.shape == b.shape and a.dtype == b.dtype, f"{what}: {i}"
        bits = [x.contiguous().view(-1).view(torch.uint8) for x in (a, b)]
        assert torch.equal(*bits), f"{what}: {i}"
