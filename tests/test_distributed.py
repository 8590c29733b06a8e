"""torchlie's layers and custom autograd Functions under torch's distributed data parallelism.

Two processes, backend gloo, CPU, a few SGD steps of a small rotation regressor whose graph
runs through torchlie's own Functions (``so3.exp`` in the rotation-vector head, ``so3.log`` in
``so3.rminus``, ``so3.act``), wrapped in DistributedDataParallel (eager, and compiled with
``torch.compile``) and in FSDP2's ``fully_shard``.  The ranks meet on 127.0.0.1 at a free port;
every process start is bounded by a timeout (and every collective by the process group's), so
a hang fails the test instead of hanging CI.  One spawn serves several checks: each rank saves
its parameters after every step and the names of the autograd nodes of its loss, and this
process compares them with a single-process run on the concatenated global batch.
"""

from __future__ import annotations

import datetime
import faulthandler
import os
import socket
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import pytest
import torch
import torch.distributed as dist
from torch import nn
from torch.distributed.fsdp import fully_shard
from torch.nn.parallel import DistributedDataParallel

from torchlie import se3, so3
from torchlie.nn import (
    REPRESENTATIONS,
    PoseHead,
    RotationHead,
    geodesic_loss,
    representation_to_matrix,
    se3_geodesic_loss,
)

WORLD = 2
BATCH = 8  # per rank; the global batch is WORLD * BATCH
STEPS = 4
FEATURES = 12
SEED = 0
LR = 0.2
#: Seconds for the ranks to start (spawn, import torch), train and exit; the compiled run also
#: compiles.  Generous: CI runs several test files at once on few cores.
TIMEOUT = 180
TIMEOUT_COMPILE = 300
#: Seconds a rank waits in a collective for the other before it fails.
COLLECTIVE_TIMEOUT = 60

#: Parameters after each step agree with the single-process run within this (absolute; the
#: parameters are O(1)).  Both runs compute the same gradient in float32; only the order of
#: the sums differs: DDP sums each rank's half of the batch on its own and then the two halves
#: (the all-reduce), the single process sums the whole batch in one pass.  Each step's update
#: then differs by about one ulp of the parameters (float32 eps 1.2e-7), and later steps carry
#: it on through the gradient's dependence on the parameters, which at this step size hardly
#: amplifies it: the runs differ by at most 1.2e-7 after STEPS steps, eager or compiled, and
#: 1e-6 (8 ulp of an O(1) parameter) leaves room for other CPUs' and torch versions' kernels.
ATOL = 1e-6


class Regressor(nn.Module):
    """Features -> rotation matrices through a rotation-vector head (``so3.exp``)."""

    def __init__(self) -> None:
        super().__init__()
        self.body = nn.Sequential(nn.Linear(FEATURES, 16), nn.Tanh())
        self.head = RotationHead(16, representation="rotvec")

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(self.body(x))


def make_model() -> Regressor:
    torch.manual_seed(SEED)
    return Regressor()


def global_batch(step: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Inputs ``(WORLD * BATCH, FEATURES)``, target rotations and points of step ``step``."""
    gen = torch.Generator().manual_seed(1000 + step)
    x = torch.randn(WORLD * BATCH, FEATURES, generator=gen)
    R = so3.random(WORLD * BATCH, generator=gen)
    p = torch.randn(WORLD * BATCH, 5, 3, generator=gen)
    return x, R, p


def loss_fn(R_pred: torch.Tensor, R: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    """Squared log error (``so3.rminus``) plus the error of the moved points (``so3.act``)."""
    log_error = so3.rminus(R_pred, R).square().sum(-1).mean()
    moved = so3.act(R_pred.unsqueeze(-3), p) - so3.act(R.unsqueeze(-3), p)
    return log_error + moved.square().sum(-1).mean()


def flat_params(model: nn.Module) -> torch.Tensor:
    return torch.cat([q.detach().flatten() for q in model.parameters()])


def node_names(t: torch.Tensor) -> set[str]:
    """Names of the autograd nodes ``t`` depends on."""
    names, stack, seen = set(), [t.grad_fn], set()
    while stack:
        node = stack.pop()
        if node is None or node in seen:
            continue
        seen.add(node)
        names.add(type(node).__name__)
        stack.extend(n for n, _ in node.next_functions)
    return names


def train(model: nn.Module, shard, record, params=None) -> list[torch.Tensor]:
    """``STEPS`` SGD steps on ``shard(step)``; ``params()`` (default: the model's parameters
    flattened) before and after every step."""
    params = params or (lambda: flat_params(model))
    opt = torch.optim.SGD(model.parameters(), lr=LR)
    snapshots = [params()]
    for step in range(STEPS):
        x, R, p = shard(step)
        loss = loss_fn(model(x), R, p)
        record(loss)
        opt.zero_grad()
        loss.backward()
        opt.step()
        snapshots.append(params())
    return snapshots


def loopback_interface() -> str:
    """Name of the loopback network interface (read on Linux, the usual name elsewhere)."""
    net = Path("/sys/class/net")
    if net.is_dir():
        for iface in sorted(net.iterdir()):
            try:
                if int((iface / "flags").read_text(), 16) & 0x8:  # IFF_LOOPBACK
                    return iface.name
            except (OSError, ValueError):
                continue
    return "lo0" if sys.platform == "darwin" else "lo"


def wrap(model: nn.Module, mode: str) -> tuple[nn.Module, Callable[[], torch.Tensor]]:
    """The model wrapped for ``mode`` and a function reading its full parameters."""
    if mode == "fsdp":
        # FSDP2 shards each parameter over the ranks; ``full_tensor`` gathers it back.
        fully_shard(model.body)
        fully_shard(model)

        def gathered() -> torch.Tensor:
            return torch.cat([q.full_tensor().detach().flatten() for q in model.parameters()])

        return model, gathered
    ddp = DistributedDataParallel(model, find_unused_parameters=False)
    if mode == "ddp-compiled":
        # Dynamo captures the DDP-wrapped model (split at DDP's gradient buckets) and
        # AOTAutograd traces torchlie's Functions with their backward, as for Inductor;
        # "aot_eager" runs the captured graphs without building C++ kernels in every rank
        # (Inductor's code for torchlie's ops is tested in test_compile.py).
        ddp = torch.compile(ddp, backend="aot_eager")
    return ddp, lambda: flat_params(model)


def _rank(rank: int, port: int, out: str, modes: tuple[str, ...], timeout: float) -> None:
    """One rank: train a fresh model under each of ``modes`` and save what it saw."""
    # a rank still running near the parent's deadline (which counts this process's start,
    # torch's import included) prints where it is, to the test's captured output, and exits
    faulthandler.dump_traceback_later(0.8 * timeout, exit=True)
    torch.set_num_threads(1)
    os.environ.setdefault("GLOO_SOCKET_IFNAME", loopback_interface())
    # FSDP2 warns that the root's output is a view (the head's 3x3 reshape of 9 numbers): it
    # matters only to in-place changes of the output, which nothing here makes.
    warnings.filterwarnings("ignore", message="FSDP2-wrapped module", category=UserWarning)
    dist.init_process_group(
        "gloo",
        init_method=f"tcp://127.0.0.1:{port}",
        rank=rank,
        world_size=WORLD,
        timeout=datetime.timedelta(seconds=COLLECTIVE_TIMEOUT),
    )
    try:
        rows = slice(rank * BATCH, (rank + 1) * BATCH)
        saved = {}
        for mode in modes:
            net, params = wrap(make_model(), mode)
            names: set[str] = set()
            steps = train(
                net,
                lambda step: tuple(t[rows] for t in global_batch(step)),
                lambda loss, names=names: names.update(node_names(loss)),
                params,
            )
            saved[mode] = {"params": torch.stack(steps), "nodes": sorted(names)}
        torch.save(saved, f"{out}/{rank}.pt")
        # no rank tears its connections down while another still uses them (gloo may abort
        # or hang then)
        dist.barrier()
    finally:
        dist.destroy_process_group()
    # done and saved: leave without the interpreter's teardown, where gloo's threads can still
    # abort the process (std::terminate in a static destructor)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run_ranks(tmp_path: Path, modes: tuple[str, ...], timeout: float) -> list[dict]:
    """Spawn the ranks, wait at most ``timeout`` seconds (then kill them and fail); return
    what each saved."""
    ctx = torch.multiprocessing.start_processes(
        _rank,
        args=(free_port(), str(tmp_path), modes, timeout),
        nprocs=WORLD,
        join=False,
        start_method="spawn",
    )
    deadline = time.monotonic() + timeout
    try:
        while not ctx.join(timeout=max(deadline - time.monotonic(), 0.0)):
            if time.monotonic() >= deadline:
                pytest.fail(f"the {WORLD} ranks did not finish within {timeout} s")
    finally:
        for proc in ctx.processes:
            if proc.is_alive():
                proc.kill()
            proc.join()
    return [torch.load(tmp_path / f"{r}.pt") for r in range(WORLD)]


def reference() -> torch.Tensor:
    """Parameters of one process trained on the whole global batch, ``(STEPS + 1, n)``."""
    return torch.stack(train(make_model(), global_batch, lambda loss: None))


def check_steps(ranks: list[dict]) -> None:
    """Every rank's parameters after every step: identical, and the one-process run's."""
    ref = reference()
    for r, saved in enumerate(ranks):
        params = saved["params"]
        assert params.shape == ref.shape
        # every rank holds the same parameters after every step: the all-reduce (DDP) or
        # reduce-scatter (FSDP) gives every rank the same averaged gradient (with two ranks
        # a + b = b + a exactly), and the same SGD step on the same numbers gives the same
        # numbers
        assert torch.equal(params, ranks[0]["params"]), f"rank {r} differs from rank 0"
        for step in range(STEPS + 1):
            err = float((params[step] - ref[step]).abs().max())
            assert err <= ATOL, f"rank {r}, step {step}: {err:.2e} from the one-process run"
    # the parameters moved (the comparison is not between two untrained models)
    assert float((ref[-1] - ref[0]).abs().max()) > 1e-2


def test_ddp_and_fsdp_match_one_process_through_custom_functions(tmp_path):
    ranks = run_ranks(tmp_path, ("ddp", "fsdp"), timeout=TIMEOUT)
    for mode in ("ddp", "fsdp"):
        check_steps([saved[mode] for saved in ranks])
        # the losses ran through torchlie's own Functions, whose gradients reached DDP's hooks
        # (DDP's find_unused_parameters=False raises if a parameter's gradient goes missing)
        for saved in ranks:
            nodes = saved[mode]["nodes"]
            for fn in ("So3Exp", "So3Log", "So3Act"):
                assert f"{fn}EagerFunctionBackward" in nodes, (mode, fn, nodes)


@pytest.mark.compile
def test_ddp_of_compiled_model_matches_one_process(tmp_path):
    ranks = run_ranks(tmp_path, ("ddp-compiled",), timeout=TIMEOUT_COMPILE)
    check_steps([saved["ddp-compiled"] for saved in ranks])
    # the model was compiled (its backward is one compiled node, so3.exp's included); the loss
    # outside it runs torchlie's eager Functions
    for saved in ranks:
        nodes = saved["ddp-compiled"]["nodes"]
        assert "CompiledFunctionBackward" in nodes, nodes
        assert "So3ExpEagerFunctionBackward" not in nodes, nodes
        assert "So3LogEagerFunctionBackward" in nodes, nodes


# ----------------------------------------------------------------------------------------------
# Mixed precision, as docs/distributed.md describes it (CPU autocast, bfloat16)
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("rep", sorted(REPRESENTATIONS))
def test_heads_under_autocast_compute_the_map_in_float32(rep):
    # autocast runs the head's nn.Linear in bfloat16; torchlie computes the rotation of that
    # bfloat16 vector in float32 and returns it rounded to bfloat16, the input's dtype
    torch.manual_seed(0)
    rot, pose = RotationHead(16, representation=rep), PoseHead(16, representation=rep)
    features = torch.randn(64, 16)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        R, T = rot(features), pose(features)
        raw_R, raw_T = rot.raw(features), pose.linear(features)
    assert R.dtype == T.dtype == raw_R.dtype == torch.bfloat16
    assert torch.equal(R, representation_to_matrix(raw_R.float(), rep).bfloat16())
    R_T = representation_to_matrix(raw_T[..., :-3].float(), rep)
    assert torch.equal(T, se3.from_rt(R_T, raw_T[..., -3:].float()).bfloat16())


def test_head_and_loss_outside_autocast_are_float32():
    # the pattern of docs/distributed.md: the network's body under autocast, the head and the
    # loss outside it on float32 features: the loss and its gradient are those of float32
    torch.manual_seed(0)
    body, head = nn.Linear(8, 16), PoseHead(16)
    x, T = torch.randn(32, 8), se3.random(32, generator=torch.Generator().manual_seed(1))

    def head_and_loss(features: torch.Tensor) -> torch.Tensor:
        T_pred = head(features)
        rotation = geodesic_loss(T_pred[..., :3, :3], T[..., :3, :3])  # so3.distance
        return rotation + se3_geodesic_loss(T_pred, T, kind="chordal")

    with torch.autocast("cpu", dtype=torch.bfloat16):
        features = body(x)
        assert features.dtype == torch.bfloat16
        with torch.autocast("cpu", enabled=False):
            loss = head_and_loss(features.float())
    (grad,) = torch.autograd.grad(loss, head.linear.weight, retain_graph=True)
    loss_ref = head_and_loss(features.detach().float())
    (grad_ref,) = torch.autograd.grad(loss_ref, head.linear.weight)
    assert loss.dtype == grad.dtype == torch.float32
    assert torch.equal(loss, loss_ref) and torch.equal(grad, grad_ref)
    assert body.weight.grad is None
    loss.backward()  # the gradient reaches the body through the bfloat16 features
    assert body.weight.grad is not None and bool(body.weight.grad.isfinite().all())
