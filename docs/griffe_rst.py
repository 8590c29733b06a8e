"""Griffe extension for the API reference: the reStructuredText markup of torchlie's docstrings
rendered as Markdown.

The docstrings are Google style (``Args:``, ``Returns:``, ``Example:`` with doctests) and use a
little reStructuredText inside: roles such as ``:func:`log```, literal blocks introduced by
``::`` and simple tables framed by ``====`` lines.  mkdocstrings reads docstrings as Markdown,
so before rendering this extension rewrites, in every docstring of the package:

* ``Example:`` section headers as ``Examples:``, the Google section whose ``>>>`` lines
  mkdocstrings shows as console code (an ``Example:`` header would be an admonition of prose);
* roles as cross-references: the target is looked up from the object's own scope outwards
  (class, module, parent packages, then absolute) and linked at the path where it is defined;
  a target outside the package (``torch.nn.Module``, ``repr``) stays plain code;
* doctest blocks of the prose (outside ``Examples:``) as console code;
* ``text::`` as ``text:`` (the indented block after it is already a Markdown code block);
* simple tables as Markdown tables (cell continuation lines joined).

Loaded from ``mkdocs.yml`` (``extensions: [docs/griffe_rst.py]``); the source files are not
changed.
"""

from __future__ import annotations

import html
import re
from typing import Any

import griffe

_ROLE = re.compile(r":(?:py:)?(?:func|class|mod|meth|data|attr|exc|obj):`(?P<body>[^`]+)`")
_TITLED = re.compile(r"^(?P<title>.*?)\s*<(?P<target>[^<>]+)>$")
_EXAMPLE = re.compile(r"^(?P<indent>\s*)Example:\s*$", re.M)
_BORDER = re.compile(r"^(?P<indent>\s*)=+( +=+)+\s*$")
_LITERAL = re.compile(r"(?<=\S)::$")


def _lookup(scope: griffe.Object, dotted: str) -> griffe.Object | None:
    """The object at ``dotted`` below ``scope``, aliases followed to their definition."""
    obj: Any = scope
    for part in dotted.split("."):
        members = getattr(obj, "members", None)
        if not members or part not in members:
            return None
        obj = members[part]
        if obj.is_alias:
            try:
                obj = obj.final_target
            except (griffe.AliasResolutionError, griffe.CyclicAliasError):
                return None
    return obj


def _resolve(target: str, where: griffe.Object, root: griffe.Module) -> str | None:
    """Path of the object that ``target`` names in a docstring of ``where``, or None."""
    scope: Any = where
    while scope is not None:
        found = _lookup(scope, target)
        if found is not None:
            return found.path
        scope = scope.parent
    if target == root.name:
        return root.path
    if target.startswith(root.name + "."):
        found = _lookup(root, target[len(root.name) + 1 :])
        return None if found is None else found.path
    return None


def _role(match: re.Match, where: griffe.Object, root: griffe.Module) -> str:
    body = " ".join(match["body"].split())  # a role may span lines
    titled = _TITLED.match(body)
    if titled:
        title, target = titled["title"], titled["target"]
    else:
        target = body.lstrip("~")
        title = target.rsplit(".", 1)[-1] if body.startswith("~") else target
    path = _resolve(target, where, root)
    if path is None:
        return f"`{title}`"
    return f'<autoref identifier="{path}" optional><code>{html.escape(title)}</code></autoref>'


def _split(line: str, starts: list[int]) -> list[str]:
    """The cells of one table line, cut at the columns' start positions."""
    ends = [*starts[1:], None]
    return [line[s:e].strip() for s, e in zip(starts, ends, strict=True)]


def _table(border: str, header: str | None, body: list[str]) -> list[str]:
    """A simple reStructuredText table as a Markdown table (continuation lines joined)."""
    indent = border[: len(border) - len(border.lstrip())]
    starts = [m.start() for m in re.finditer(r"=+", border)]
    rows: list[list[list[str]]] = []
    for line in body:
        if not line.strip():
            continue
        cells = _split(line, starts)
        if cells[0] or not rows:  # a row starts where its first column has text
            rows.append([[c] if c else [] for c in cells])
        else:
            for column, c in zip(rows[-1], cells, strict=True):
                column.extend([c] if c else [])
    head = _split(header, starts) if header is not None else [""] * len(starts)
    out = [f"{indent}| {' | '.join(head)} |", indent + "|" + " --- |" * len(starts)]
    for row in rows:
        cells = (" ".join(column).replace("|", r"\|") for column in row)
        out.append(f"{indent}| {' | '.join(cells)} |")
    return out


def _tables(text: str) -> str:
    """Every simple table of ``text`` (top border, optional header and its border, rows, bottom
    border) as a Markdown table."""
    lines = text.split("\n")
    out: list[str] = []
    i = 0
    while i < len(lines):
        if not _BORDER.match(lines[i]):
            out.append(lines[i])
            i += 1
            continue
        ends = [j for j in range(i + 1, len(lines)) if _BORDER.match(lines[j])]
        if not ends:
            out.append(lines[i])
            i += 1
            continue
        header = None
        end = ends[0]
        if end == i + 2 and len(ends) > 1 and lines[end + 1].strip():
            header, end = lines[i + 1], ends[1]
        body = lines[(i + 3 if header is not None else i + 1) : end]
        out.extend(_table(lines[i], header, body))
        i = end + 1
    return "\n".join(out)


def _doctests(text: str) -> str:
    """Doctest blocks of the prose (``>>>`` at the start of a line, up to the next blank line)
    as console code blocks; those of an ``Examples:`` section are indented and left to it."""
    lines = text.split("\n")
    out: list[str] = []
    i = 0
    while i < len(lines):
        if lines[i].startswith(">>>") and (i == 0 or not lines[i - 1].strip()):
            j = i
            while j < len(lines) and lines[j].strip():
                j += 1
            out += ["```pycon", *lines[i:j], "```"]
            i = j
        else:
            out.append(lines[i])
            i += 1
    return "\n".join(out)


def rewrite(text: str, where: griffe.Object, root: griffe.Module) -> str:
    """The Markdown form of one docstring of ``where`` (see the module docstring)."""
    text = _EXAMPLE.sub(r"\g<indent>Examples:", text)
    text = _doctests(text)
    text = _tables(text)
    text = "\n".join(_LITERAL.sub(":", line) for line in text.split("\n"))
    return _ROLE.sub(lambda m: _role(m, where, root), text)


def _comment_docstring(obj: griffe.Object) -> griffe.Docstring | None:
    """The ``#:`` comment lines right above an attribute's assignment, as its docstring."""
    if not obj.is_attribute or obj.lineno is None or obj.filepath is None:
        return None
    lines = obj.lines_collection[obj.filepath]
    comment: list[str] = []
    i = obj.lineno - 2  # lineno counts from 1; the line above the assignment
    while i >= 0 and lines[i].strip().startswith("#:"):
        comment.insert(0, lines[i].strip()[2:].strip())
        i -= 1
    return griffe.Docstring("\n".join(comment), parent=obj) if comment else None


class RstMarkup(griffe.Extension):
    """Rewrites every docstring of a loaded package (see the module docstring); an attribute
    documented by ``#:`` comments (Sphinx's form) gets them as its docstring."""

    def on_package(self, *, pkg: griffe.Module, **kwargs: Any) -> None:
        stack: list[griffe.Object] = [pkg]
        while stack:
            obj = stack.pop()
            if obj.docstring is None:
                obj.docstring = _comment_docstring(obj)
            if obj.docstring is not None:
                obj.docstring.value = rewrite(obj.docstring.value, obj, pkg)
            stack.extend(m for m in obj.members.values() if not m.is_alias)
