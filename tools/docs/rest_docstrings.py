"""A griffe extension for `make docs`: sm_bt's docstrings are written in reST's inline style, which
the API reference renders as Markdown. Before they are rendered:

- a role (``:class:`~sm_bt.ModeManager```, ``:meth:`change_mode```, ...) becomes the name in code,
  linked to its entry in the reference when the name resolves to an sm_bt object that has one
  (resolved from the docstring's own scope outwards, as Sphinx does); other names stay plain code;
- a paragraph ending in ``::`` ends in ``:``, and the indented literal block after it becomes a
  fenced code block.

Nothing else changes: ``double backticks`` and ``*emphasis*`` read the same in Markdown.
"""

from __future__ import annotations

import html
import re
import textwrap
from typing import Any

import griffe

ROLE = re.compile(r":(?:py:)?(?:class|func|meth|attr|mod|data|exc|obj|const):`(~?)([^`<>]+)`")
PACKAGE = "sm_bt"


class RestDocstrings(griffe.Extension):
    def on_package(self, *, pkg: griffe.Module, loader: griffe.GriffeLoader, **kwargs: Any) -> None:
        if pkg.name != PACKAGE:
            return
        for obj in _objects(pkg):
            if obj.docstring is not None:
                obj.docstring.value = literal_blocks(roles(obj.docstring.value, obj, loader))


def _objects(obj: griffe.Object) -> list[griffe.Object]:
    """``obj`` and every object defined in it (aliases, such as imported names, are left out)."""
    found = [obj]
    for member in obj.members.values():
        if not member.is_alias:
            found.extend(_objects(member))  # type: ignore[arg-type]
    return found


def roles(text: str, obj: griffe.Object, loader: griffe.GriffeLoader) -> str:
    def link(match: re.Match[str]) -> str:
        short, name = match.group(1) == "~", match.group(2).strip()
        bare = name.removesuffix("()")
        shown = bare.rsplit(".", 1)[-1] + ("()" if name.endswith("()") else "") if short else name
        code = f"<code>{html.escape(shown)}</code>"
        target = resolve(bare.lstrip("."), obj, loader)
        if target is None:
            return code
        return f'<autoref identifier="{html.escape(target)}" optional>{code}</autoref>'

    return ROLE.sub(link, text)


def resolve(name: str, obj: griffe.Object, loader: griffe.GriffeLoader) -> str | None:
    """The path of the sm_bt object ``name`` names in ``obj``'s scope, or ``None``."""
    first, _, rest = name.partition(".")
    scope: griffe.Object | None = obj
    while scope is not None:
        if first in scope.members:
            member = scope.members[first]
            return _checked(f"{member.path}.{rest}" if rest else member.path, loader)
        scope = scope.parent
    return _checked(name, loader)


def _checked(path: str, loader: griffe.GriffeLoader) -> str | None:
    if path.split(".", 1)[0] != PACKAGE:
        return None
    try:
        found = loader.modules_collection.get_member(path)
    except (KeyError, ValueError, griffe.AliasResolutionError, griffe.CyclicAliasError):
        return None
    try:
        return str(found.final_target.path) if found.is_alias else str(found.path)
    except (griffe.AliasResolutionError, griffe.CyclicAliasError):
        return None


def literal_blocks(text: str) -> str:
    lines = text.splitlines()
    out: list[str] = []
    index = 0
    while index < len(lines):
        line = lines[index]
        if not line.rstrip().endswith("::"):
            out.append(line)
            index += 1
            continue
        head = line.rstrip()[:-2].rstrip()
        if head:
            out.append(head + ":")
        index += 1
        block: list[str] = []
        while index < len(lines) and (not lines[index].strip() or lines[index].startswith((" ", "\t"))):
            block.append(lines[index])
            index += 1
        while block and not block[-1].strip():
            block.pop()
        while block and not block[0].strip():
            block.pop(0)
        if block:
            out.extend(["", "```", *textwrap.dedent("\n".join(block)).splitlines(), "```", ""])
    return "\n".join(out)
