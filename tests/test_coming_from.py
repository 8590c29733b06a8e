"""The "Coming from ..." pages: every row of their function tables, checked against the peer.

A function table is a Markdown table whose header is ``| <peer> | torchlie | agreement |``.
Each of its rows holds one code span per expression: the peer's call and the torchlie
equivalent (with the adapter where the conventions differ).  Both are evaluated on the same
inputs (the symbols each page lists: rotation vectors with angles 0, tiny, generic, near and at
pi, quaternions of both signs, ...) in float64 and compared as the agreement cell says:

* ``equal``: the same numbers on every input, to ``1e-10``;
* qualifiers, in this order, relax it where the page says why:
  ``up to sign`` (``q`` and ``-q`` per element), ``modulo 2π`` (angles), ``as rotations``
  (rotation vectors compared through ``so3.exp``), ``away from π`` (only the inputs whose
  rotation angles are below ``pi - 1e-3``), ``away from gimbal lock`` (only the Euler triples
  whose middle angle is more than ``1e-6`` from 0, +-pi/2 and pi, the lock values of either
  kind of sequence), ``where the peer is finite`` (only the inputs where the peer returns finite
  numbers, at least half of them), ``within 1e-8`` (that tolerance instead of ``1e-10``).

So a row cannot be documented without being tested.  A page whose peer is not installed skips
its peer check (the torchlie column is still evaluated).
"""

from __future__ import annotations

import ast
import functools
import importlib.util
import math
import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import torch

from torchlie import conversions, nn, quaternion, se2, se3, sim3, so2, so3, statistics
from torchlie.kinematics import Chain, sample_robot

DOCS = Path(__file__).resolve().parent.parent / "docs" / "coming-from"

# page -> (module that must be importable, its table header name, quaternion order, twist order)
PAGES = {
    "scipy": ("scipy", "scipy", "xyzw", "phi_rho"),
    "roma": ("roma", "roma", "xyzw", "rho_phi"),
    "kornia": ("kornia", "kornia", "wxyz", "rho_phi"),
    "pytorch3d": ("pytorch3d", "pytorch3d", "wxyz", "rho_phi"),
    "pypose": ("pypose", "pypose", "xyzw", "rho_phi"),
    "pytorch-kinematics": ("pytorch_kinematics", "pytorch-kinematics", "wxyz", "rho_phi"),
}

AGREEMENT = re.compile(
    r"equal(?: up to sign)?(?: modulo 2π)?(?: as rotations)?(?: away from (?:π|gimbal lock))?"
    r"(?: where the peer is finite)?(?: within \d(?:\.\d+)?e-\d+)?"
)
ATOL = RTOL = 1e-10  # float64, values of order one
NEAR_PI = math.pi - 1e-3
LOCK = 1e-6  # Euler angles: middle angle this close to a gimbal-lock value


@dataclass(frozen=True)
class Row:
    page: str
    line: int
    peer: str
    torchlie: str
    agreement: str

    def __str__(self) -> str:
        return f"{self.page}.md:{self.line}: {self.peer}"


_CODE = re.compile(r"^`([^`]+)`$")


def cells(line: str) -> list[str]:
    """The cells of a Markdown table row (``\\|`` is a literal bar inside a cell)."""
    parts = re.split(r"(?<!\\)\|", line.strip().strip("|"))
    return [c.strip().replace("\\|", "|") for c in parts]


def function_rows(page: str) -> list[Row]:
    """Every row of the page's function tables; a malformed row fails the test."""
    header = PAGES[page][1]
    rows: list[Row] = []
    in_table = False
    for number, line in enumerate((DOCS / f"{page}.md").read_text().splitlines(), start=1):
        if not line.startswith("|"):
            in_table = False
            continue
        c = cells(line)
        if c[:3] == [header, "torchlie", "agreement"]:
            in_table = True
            continue
        if not in_table or set(line) <= set("|-: "):
            continue
        where = f"{page}.md:{number}"
        assert len(c) == 3, f"{where}: a function row has three cells, got {c}"
        peer, mine = _CODE.match(c[0]), _CODE.match(c[1])
        assert peer and mine, f"{where}: each expression must be one code span: {c[:2]}"
        agreement = AGREEMENT.match(c[2])
        assert agreement, f"{where}: the agreement must match {AGREEMENT.pattern}: {c[2]!r}"
        rows.append(Row(page, number, peer.group(1), mine.group(1), agreement.group(0)))
    return rows


def import_block(page: str) -> str:
    """The page's first fenced Python block: its imports."""
    text = (DOCS / f"{page}.md").read_text()
    m = re.search(r"```python\n(.*?)```", text, re.S)
    assert m, f"{page}.md: no import block"
    return m.group(1)


# ----------------------------------------------------------------------------------------------
# Shared inputs
# ----------------------------------------------------------------------------------------------

# Rotation angles: 0, tiny, small, generic, near pi and pi (float64 pi is 1.2e-16 below pi).
ANGLES = (0.0, 1e-12, 1e-7, 1e-3, 0.5, 1.0, 2.0, 3.0, math.pi - 1e-3, math.pi - 1e-6, math.pi)


def rotvecs(gen: torch.Generator, angles) -> torch.Tensor:
    axis = torch.randn(len(angles), 3, generator=gen, dtype=torch.float64)
    axis = axis / axis.norm(dim=-1, keepdim=True)
    return axis * torch.tensor(angles, dtype=torch.float64)[:, None]


@functools.cache
def inputs(page: str) -> tuple[dict[str, object], torch.Tensor]:
    """The symbols of the tables (torch float64) and the batch elements away from pi."""
    _, _, quat_order, twist_order = PAGES[page]
    gen = torch.Generator().manual_seed(0)
    angles = (*ANGLES, math.pi, math.pi, math.pi)
    n = len(angles)
    w = rotvecs(gen, angles)
    v = rotvecs(gen, angles)  # the same angles about other axes
    # rotations by pi about coordinate axes (where the sign rules of the logs apply); the
    # pairs (w, v) of these differ by pi, pi and 0
    axes = torch.tensor(
        [[1.0, 0, 0], [0, -1, 0], [0, 0, 1], [0, 0, 1], [1, 0, 0], [0, 0, -1]], dtype=torch.float64
    )
    w[-3:], v[-3:] = math.pi * axes[:3], math.pi * axes[3:]
    # pairs whose relative rotation R^T S is by 1e-7 and by pi - 1e-7
    rel = rotvecs(gen, (1e-7, math.pi - 1e-7))
    v[3:5] = so3.log(so3.exp(w[3:5]) @ so3.exp(rel))
    away = (w.norm(dim=-1) < NEAR_PI) & (v.norm(dim=-1) < NEAR_PI)

    def rand(*shape: int) -> torch.Tensor:
        return torch.randn(n, *shape, generator=gen, dtype=torch.float64)

    def order(q: torch.Tensor) -> torch.Tensor:
        return quaternion.to_xyzw(q) if quat_order == "xyzw" else q

    sign = torch.where(torch.rand(n, 1, generator=gen, dtype=torch.float64) < 0.5, -1.0, 1.0)
    q = quaternion.from_rotvec(w) * sign
    p = quaternion.from_rotvec(v) * torch.where(torch.rand(n, 1, generator=gen) < 0.5, -1.0, 1.0)
    R, S = so3.exp(w), so3.exp(v)
    t, u = rand(3), rand(3)
    rho, sigma = rand(3), rand(3)
    xi = torch.cat((rho, w) if twist_order == "rho_phi" else (w, rho), dim=-1)
    eta = torch.cat((sigma, v) if twist_order == "rho_phi" else (v, sigma), dim=-1)
    e = (torch.rand(n, 3, generator=gen, dtype=torch.float64) * 2 - 1) * math.pi
    e[:, 1] /= 2  # Tait-Bryan middle angle in [-pi/2, pi/2]
    e[0] = 0.0
    e[1, 1] = math.pi / 2  # gimbal lock
    P = torch.randn(n, 8, 3, generator=gen, dtype=torch.float64)
    # planar: the same angles with alternating signs, and one more set of them
    signs = torch.tensor([(-1.0) ** i for i in range(n)], dtype=torch.float64)
    theta = (torch.tensor(angles, dtype=torch.float64) * signs)[:, None]
    C, D = so2.exp(theta), so2.exp(theta.flip(0))
    zeta = torch.cat((rand(2), theta), dim=-1)
    Q = (
        so3.act(R[:, None], P)
        + t[:, None]
        + 0.01 * torch.randn(P.shape, generator=gen, dtype=torch.float64)
    )
    chi = torch.cat((rho, w, 0.5 * rand(1)), dim=-1)  # Sim(3) tangents (rho, phi, sigma)
    symbols = {
        "chi": chi,
        "omega": rand(7),
        "Z": sim3.exp(chi),
        "w": w,
        "v": v,
        "q": order(q),
        "p": order(p),
        "h": order(q * (0.5 + torch.rand(n, 1, generator=gen, dtype=torch.float64))),
        "R": R,
        "S": S,
        "M": R + 0.2 * torch.tanh(rand(3, 3)),  # |M - R|_F < 1: positive determinant
        "t": t,
        "u": u,
        "T": se3.from_rt(R, t),
        "U": se3.from_rt(S, u),
        "xi": xi,
        "eta": eta,
        "x": rand(3),
        "a": rand(6),
        "e": e,
        "s": torch.linspace(0.0, 1.0, n, dtype=torch.float64),
        "P": P,
        "Q": Q,
        "n": n,
        "theta": theta,
        "C": C,
        "D": D,
        "zeta": zeta,
        "F": se2.exp(zeta),
        "G": se2.from_rt(D, rand(2)),
        "y": rand(2),
    }
    if page == "pytorch-kinematics":
        chain = Chain.from_urdf(sample_robot("arm7"), dtype=torch.float64)
        symbols["urdf"] = Path(sample_robot("arm7")).read_text()
        symbols["chain"] = chain
        symbols["th"] = chain.random_configuration(n, generator=gen).to(torch.float64)
    return symbols, away


def fresh(symbols: dict[str, object]) -> dict[str, object]:
    """Copies of the array inputs: a peer function that writes into its input (one does)
    must not change the inputs of the next row."""
    copies = {torch.Tensor: torch.clone, np.ndarray: np.copy}
    return {k: copies.get(type(v), lambda x: x)(v) for k, v in symbols.items()}


TORCHLIE = {
    "torch": torch,
    "conversions": conversions,
    "nn": nn,
    "quaternion": quaternion,
    "se2": se2,
    "se3": se3,
    "so2": so2,
    "sim3": sim3,
    "so3": so3,
    "statistics": statistics,
    "Chain": Chain,
    "sample_robot": sample_robot,
}


def as_tensor(value):
    """Peer results as plain tensors (from arrays, tensor subclasses, tuples); names as they are."""
    if isinstance(value, (tuple, list)) and all(isinstance(v, str) for v in value):
        return list(value)
    if isinstance(value, (tuple, list)):
        return tuple(as_tensor(v) for v in value)
    if isinstance(value, np.ndarray):
        return torch.from_numpy(value)
    if isinstance(value, torch.Tensor):
        return value.detach().as_subclass(torch.Tensor)
    return torch.as_tensor(value)


def compare(peer, mine, agreement: str, away: torch.Tensor, row: Row) -> None:
    """Assert the agreement (see the module docstring) between two results."""
    if isinstance(mine, list):  # names
        assert peer == mine, row
        return
    if isinstance(mine, tuple):
        assert isinstance(peer, tuple) and len(peer) == len(mine), row
        for a, b in zip(peer, mine, strict=True):
            compare(a, b, agreement, away, row)
        return
    assert peer.shape == mine.shape, f"{row}: shapes {tuple(peer.shape)} != {tuple(mine.shape)}"
    peer = peer.to(mine.dtype)
    if "away from π" in agreement:
        peer, mine = peer[away], mine[away]
    if "away from gimbal lock" in agreement:
        assert mine.shape[-1] == 3, f"{row}: gimbal lock is about Euler angles"
        middle = mine[..., 1, None]
        lock = torch.tensor([0.0, math.pi / 2, -math.pi / 2, math.pi], dtype=mine.dtype)
        free = ((middle - lock).abs() > LOCK).all(dim=-1)
        peer, mine = peer[free], mine[free]
    if "where the peer is finite" in agreement:
        finite = peer.flatten(1).isfinite().all(dim=-1)
        assert finite.float().mean() >= 0.5, f"{row}: the peer is finite on too few inputs"
        peer, mine = peer[finite], mine[finite]
    if "as rotations" in agreement:  # rotation vectors compared as the rotations they stand for
        peer, mine = so3.exp(peer), so3.exp(mine)
    if "up to sign" in agreement:
        dot = (peer * mine).sum(dim=-1, keepdim=True)
        peer = torch.where(dot < 0, -peer, peer)
    if "modulo 2π" in agreement:
        peer = mine + torch.remainder(peer - mine + math.pi, 2 * math.pi) - math.pi
    tol = float(agreement.rsplit(" ", 1)[1]) if " within " in agreement else ATOL
    torch.testing.assert_close(peer, mine, atol=tol, rtol=tol, msg=lambda m: f"{row}\n{m}")


ALL_ROWS = [row for page in PAGES for row in function_rows(page)]


@pytest.mark.parametrize("page", sorted(PAGES))
def test_page_has_function_tables_and_describes_their_inputs(page):
    rows = function_rows(page)
    assert len(rows) >= 10
    text = (DOCS / f"{page}.md").read_text()
    symbols, _ = inputs(page)
    setup = {
        target.id
        for node in ast.parse(import_block(page)).body
        if isinstance(node, ast.Assign)
        for target in node.targets
        if isinstance(target, ast.Name)
    }
    for row in rows:
        names = {
            node.id
            for expr in (row.peer, row.torchlie)
            for node in ast.walk(ast.parse(expr, mode="eval"))
            if isinstance(node, ast.Name)
        }
        for name in sorted(names & set(symbols) - setup):
            assert f"`{name}`" in text, f"{row}: the input `{name}` is not described on the page"


@pytest.mark.parametrize("row", ALL_ROWS, ids=str)
def test_torchlie_column_evaluates(row):
    """The torchlie expression runs on the page's inputs (every page, peer installed or not)."""
    symbols, _ = inputs(row.page)
    out = as_tensor(eval(row.torchlie, {**TORCHLIE, **fresh(symbols)}))
    if isinstance(out, list):
        assert out and all(isinstance(o, str) for o in out), row
        return
    for o in out if isinstance(out, tuple) else (out,):
        assert o.dtype in (torch.float64, torch.bool) and bool(o.isfinite().all()), row


@pytest.mark.parametrize("page", sorted(PAGES))
def test_rows_against_peer(page):
    module = PAGES[page][0]
    if importlib.util.find_spec(module) is None:
        pytest.skip(f"{module} is not installed: {page}.md is not checked here")
    symbols, away = inputs(page)
    namespace = dict(TORCHLIE)
    exec(import_block(page), namespace)
    peer_symbols = symbols
    if page == "scipy":  # scipy takes NumPy arrays
        peer_symbols = {
            k: v.numpy() if isinstance(v, torch.Tensor) else v for k, v in symbols.items()
        }
    failures = []
    for row in function_rows(page):
        try:
            with warnings.catch_warnings():  # scipy's gimbal-lock warning (the page says so)
                warnings.simplefilter("ignore", UserWarning)
                peer = as_tensor(eval(row.peer, {**namespace, **fresh(peer_symbols)}))
            mine = as_tensor(eval(row.torchlie, {**namespace, **fresh(symbols)}))
            compare(peer, mine, row.agreement, away, row)
        except Exception as e:  # collect every failing row, then fail once
            failures.append(f"{row}: {type(e).__name__}: {e}")
    assert not failures, "\n\n".join(failures)
