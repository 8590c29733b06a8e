"""The user documentation: the README's quick start prints what the README says, its links
resolve, the docs pages' code runs, and the API reference has a place for every public name.

The site itself is built with warnings as errors by ``mkdocs build --strict`` (``.ci/run``);
these tests need no MkDocs.
"""

from __future__ import annotations

import importlib
import pkgutil
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch

import torchlie

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
README = ROOT / "README.md"
PYTHON_BLOCK = re.compile(r"^```python\n(.*?)^```$", re.M | re.S)


def _run(code: str) -> str:
    """Run ``code`` in a fresh interpreter (so that it cannot change this process's torch
    settings) and return its standard output; fail with its error output if it fails."""
    done = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stderr
    return done.stdout


def _section(text: str, heading: str) -> str:
    start = text.index(f"\n## {heading}\n")
    end = text.find("\n## ", start + 1)
    return text[start : end if end >= 0 else len(text)]


def test_readme_quick_start_prints_what_the_readme_shows():
    quick = _section(README.read_text(encoding="utf-8"), "Quick start")
    code = re.search(r"```python\n(.*?)```", quick, re.S)
    shown = re.search(r"```text\n(.*?)```", quick, re.S)
    assert code is not None and shown is not None, "Quick start needs a python and a text block"
    assert code.start() < shown.start()
    assert _run(code[1]) == shown[1]


def test_readme_relative_links_resolve():
    text = README.read_text(encoding="utf-8")
    links = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)
    local = [link for link in links if "://" not in link]
    assert local, "the README links the docs, the licence and the changelog"
    missing = [link for link in local if not (ROOT / link).exists()]
    assert not missing, f"README links to files that do not exist: {missing}"


@pytest.mark.parametrize(
    "page", [README, *sorted(DOCS.rglob("*.md"))], ids=lambda p: str(p.relative_to(ROOT))
)
def test_pages_hold_no_control_characters(page):
    # a formula written through a non-raw string turns \r, \t, \f, \v into control characters,
    # which MkDocs renders without a warning
    text = page.read_bytes().decode("utf-8")
    bad = [
        (n, line)
        for n, line in enumerate(text.split("\n"), 1)
        if re.search(r"[\x00-\x08\x0b-\x1f\x7f]|\t", line)
    ]
    assert not bad, bad


def test_declared_torch_range_is_the_tested_one():
    """``pyproject.toml`` declares torch from the oldest release ``.ci/torch-range`` runs the
    suite on to the minor release after the newest, and the docs state that range."""
    script = (ROOT / ".ci" / "torch-range").read_text(encoding="utf-8")
    ends = re.search(r"^versions=\((\d+)\.(\d+)\.\d+ (\d+)\.(\d+)\.\d+\)$", script, re.M)
    assert ends is not None, ".ci/torch-range names its oldest and newest release"
    old_major, old_minor, new_major, new_minor = map(int, ends.groups())
    declared = f"torch>={old_major}.{old_minor},<{new_major}.{new_minor + 1}"
    pyproject = (ROOT / "pyproject.toml").read_text(encoding="utf-8")
    assert re.findall(r'"(torch[<>=].*?)"', pyproject) == [declared]
    stated = f"torch {old_major}.{old_minor} to {new_major}.{new_minor}"
    assert stated in README.read_text(encoding="utf-8")
    assert stated in (DOCS / "getting-started.md").read_text(encoding="utf-8")
    assert declared in (DOCS / "contributing.md").read_text(encoding="utf-8")


def _doc_pages() -> list:
    """The top-level docs pages with python blocks; a page whose code calls the compiled path
    compiles with Inductor (seconds per function) and is marked ``compile`` and ``slow``."""
    pages = []
    for page in sorted(DOCS.glob("*.md")):
        text = page.read_text(encoding="utf-8")
        if not PYTHON_BLOCK.search(text):
            continue
        compiles = any("torchlie.compiled import" in b for b in PYTHON_BLOCK.findall(text))
        marks = [pytest.mark.compile, pytest.mark.slow] if compiles else []
        pages.append(pytest.param(page, marks=marks, id=page.name))
    return pages


@pytest.mark.parametrize("page", _doc_pages())
def test_docs_page_code_runs(page):
    """The python blocks of a page run in order, in one namespace, without error."""
    blocks = PYTHON_BLOCK.findall(page.read_text(encoding="utf-8"))
    dtype = torch.get_default_dtype()
    try:
        exec(compile("\n".join(blocks), str(page), "exec"), {"__name__": "__docs__"})
    finally:
        torch.set_default_dtype(dtype)


# ----------------------------------------------------------------------------------------------
# API reference
# ----------------------------------------------------------------------------------------------

DIRECTIVE = re.compile(r"^::: (?P<path>[\w.]+)\n(?P<options>(?:[ \t]+.*\n?)*)", re.M)


def _directives() -> dict[str, list[str] | None]:
    """Module path -> the members its ``:::`` directive lists (None: all of ``__all__``)."""
    found: dict[str, list[str] | None] = {}
    for page in sorted((DOCS / "api").glob("*.md")):
        for m in DIRECTIVE.finditer(page.read_text(encoding="utf-8")):
            assert m["path"] not in found, f"{m['path']} is documented twice"
            options = m["options"]
            if re.search(r"^\s+members:\s*false\s*$", options, re.M):
                found[m["path"]] = []
            elif re.search(r"^\s+members:\s*$", options, re.M):
                listed = options.split("members:", 1)[1]
                found[m["path"]] = re.findall(r"^\s+- (\w+)\s*$", listed, re.M)
            else:
                found[m["path"]] = None
    return found


def _public_modules() -> list[str]:
    """Every module of the package whose dotted path has no private component."""
    names = ["torchlie"]
    for info in pkgutil.walk_packages(torchlie.__path__, "torchlie."):
        if not any(part.startswith("_") for part in info.name.split(".")):
            names.append(info.name)
    return sorted(names)


def test_every_public_module_has_its_api_page():
    documented = _directives()
    missing = [name for name in _public_modules() if name not in documented]
    assert not missing, f"public modules without a ':::' directive in docs/api/: {missing}"


def _renders(module: str, name: str, obj: object) -> bool:
    """Whether the API page of ``module`` renders ``obj`` under ``name``."""
    members = _directives()[module]
    mod = importlib.import_module(module)
    exported = getattr(mod, "__all__", ())
    return (
        name in exported
        and getattr(mod, name, None) is obj
        and (members is None or name in members)
    )


@pytest.mark.parametrize("module", [m for m in _public_modules() if m != "torchlie"])
def test_every_public_name_is_in_the_api_reference(module):
    """Each name of ``__all__`` is rendered by its module's directive, or, for a name
    re-exported from another public module, by that module's."""
    documented = _directives()
    mod = importlib.import_module(module)
    exported = getattr(mod, "__all__", None)
    assert exported, f"{module} declares its public names in __all__"
    missing = []
    for name in exported:
        members = documented.get(module)
        if members is None and module in documented or members and name in members:
            continue
        if any(
            _renders(other, name, getattr(mod, name)) for other in documented if other != module
        ):
            continue
        missing.append(name)
    assert not missing, f"{module}: not in the API reference: {missing}"
