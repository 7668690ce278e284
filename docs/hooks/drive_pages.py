"""mkdocs hook: each drive family's page is filled from its profile's own declarations.

A page that holds the line ``<!-- drive-family: NAME -->`` gets, in its place, what the
code of family NAME (``drivebus.drives.registry.FAMILIES``) declares: link, addresses,
line kinds, baud rates and formats, pulses/rev, homing methods, the ``drive_options``
with their types, ranges and defaults, which procedures it supports and why not, the
vendor's exception codes and the register map. ``<!-- drive-families -->`` becomes the
table of every family. Nothing here is typed by hand, so the pages cannot drift from the
code; a family without a page, or a page naming an unknown family, fails the build.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import re
import textwrap
from collections.abc import Iterable, Iterator
from typing import Any

from mkdocs.config.defaults import MkDocsConfig
from mkdocs.exceptions import PluginError
from mkdocs.structure.files import Files
from mkdocs.structure.pages import Page

from drivebus.drives.base import DriveProfile
from drivebus.drives.pages import (
    at_a_glance,
    cell,
    exceptions_section,
    families_table,
    options_section,
    procedures_section,
    register_address,
    registers_table,
    slug,
)
from drivebus.drives.pages import (
    family_page as described_page,
)
from drivebus.drives.registers import Register
from drivebus.drives.registry import FAMILIES, DriveFamily

_MARK = re.compile(r"^<!--\s*drive-family:\s*(\S+)\s*-->\s*$", re.MULTILINE)
_TABLE_MARK = "<!-- drive-families -->"
_PAGE = "drives/{slug}.md"

_seen: set[str] = set()


# -- mkdocs events ----------------------------------------------------------------------------


def on_files(files: Files, config: MkDocsConfig) -> Files:
    """Every registered family must have its page."""
    _seen.clear()
    missing = [n for n in FAMILIES if files.get_file_from_path(_PAGE.format(slug=slug(n))) is None]
    if missing:
        raise PluginError(
            "drive_pages: no page for drive families "
            + ", ".join(f"{n} (docs/{_PAGE.format(slug=slug(n))})" for n in missing)
        )
    return files


def on_page_markdown(markdown: str, page: Page, config: MkDocsConfig, files: Files) -> str:
    """Replace the markers with the generated sections."""
    if _TABLE_MARK in markdown:
        markdown = markdown.replace(_TABLE_MARK, families_table(FAMILIES.values()))

    def fill(match: re.Match[str]) -> str:
        name = match.group(1)
        family = FAMILIES.get(name)
        if family is None:
            raise PluginError(
                f"drive_pages: {page.file.src_path} names drive family {name!r}; "
                f"known: {', '.join(FAMILIES)}"
            )
        _seen.add(name)
        return family_page(family)

    return _MARK.sub(fill, markdown)


def on_post_build(config: MkDocsConfig) -> None:
    """Every family's page must have had its marker."""
    missing = sorted(set(FAMILIES) - _seen)
    if missing:
        raise PluginError(
            "drive_pages: these families' pages lack <!-- drive-family: NAME -->: "
            + ", ".join(missing)
        )


# -- the generated markdown ---------------------------------------------------------------------


def family_page(family: DriveFamily) -> str:
    """The generated part of one family's page: a described family's whole page as
    ``drivebus drive doc`` prints it, or what a hand-written profile's code declares."""
    if family.spec is not None:
        return described_page(family)
    p = family.profile
    parts = [
        _about(family),
        at_a_glance(family),
        options_section(p),
        procedures_section(family),
        _limits(p),
        exceptions_section(p),
        _registers(family),
    ]
    return "\n\n".join(x for x in parts if x)


def _about(family: DriveFamily) -> str:
    p = family.profile
    module = inspect.getmodule(p)
    text = [f"*Generated from `{p.__module__}.{p.__qualname__}`.*"]
    if module is not None and module.__doc__:
        text.append("## About the profile\n\n" + _rst_to_md(module.__doc__))
    if p.__doc__:
        text.append(f"### `{p.__name__}`\n\n" + _rst_to_md(p.__doc__))
    return "\n\n".join(text)


def _limits(p: type[DriveProfile]) -> str:
    """Every ``self.unsupported(what, why)`` the profile's own code can raise, read from
    its source: the limits that depend on options, modes or arguments. (The calls in
    ``check_supported`` are the procedures table's.)"""
    found: list[tuple[str, str]] = []
    for cls in p.__mro__:
        if cls is DriveProfile or not issubclass(cls, DriveProfile):
            continue
        found += _unsupported_calls(cls, p)
    items = []
    for what, why in dict.fromkeys(found):
        items.append(f"- **cannot {what}**" + (f": {why}" if why else ""))
    if not items:
        return ""
    return ("## What it cannot do, and why\n\nEach `NotSupported` the profile's code can "
            "raise beyond the table above, as the code words it (`…` stands for a value "
            "known only at run time):\n\n" + "\n".join(items))


def _unsupported_calls(cls: type[DriveProfile], profile: type[DriveProfile]
                       ) -> Iterator[tuple[str, str]]:
    """(what, why) of each ``self.unsupported(...)`` in the methods of ``cls`` that
    ``profile`` really runs (a method a subclass overrides is not the subclass's)."""
    try:
        source = textwrap.dedent(inspect.getsource(cls))
    except (OSError, TypeError):
        return
    module = vars(inspect.getmodule(cls) or object)
    (klass,) = ast.parse(source).body
    assert isinstance(klass, ast.ClassDef)
    for node in klass.body:
        if not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        if node.name == "check_supported" or getattr(profile, node.name, None) is not vars(
            cls
        ).get(node.name):
            continue
        local: dict[str, ast.expr | None] = {
            a.arg: None for a in (*node.args.posonlyargs, *node.args.args,
                                  *node.args.kwonlyargs)
        }
        local.update({
            a.targets[0].id: a.value
            for a in ast.walk(node)
            if isinstance(a, ast.Assign) and len(a.targets) == 1
            and isinstance(a.targets[0], ast.Name)
        })
        for call in ast.walk(node):
            if (
                isinstance(call, ast.Call)
                and isinstance(call.func, ast.Attribute)
                and call.func.attr == "unsupported"
                and isinstance(call.func.value, ast.Name)
                and call.func.value.id == "self"
            ):
                args = [_render(a, local, module) for a in call.args]
                what = args[0] if args else "…"
                why = args[1] if len(args) > 1 else ""
                yield what, cell(why)


def _render(node: ast.expr, local: dict[str, ast.expr | None], module: dict[str, Any]
            ) -> str:
    """A string expression as text: evaluated when it uses no argument or local of the
    method (only the module's own tables), else its literal parts with ``…`` for
    run-time values."""
    used = {n.id for n in ast.walk(node) if isinstance(n, ast.Name)}
    if not used & set(local):
        try:
            value = eval(compile(ast.Expression(node), "<drive_pages>", "eval"), dict(module))
        except Exception:  # any failure: render it structurally instead
            value = None
        if isinstance(value, str):
            return value
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value
    if isinstance(node, ast.JoinedStr):
        return "".join(
            v.value if isinstance(v, ast.Constant) else "…" for v in node.values
        )
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add):
        return _render(node.left, local, module) + _render(node.right, local, module)
    if isinstance(node, ast.IfExp):  # "a" if cond else "b"
        return f"{_render(node.body, local, module)} / {_render(node.orelse, local, module)}"
    value_node = local.get(node.id) if isinstance(node, ast.Name) else None
    if value_node is not None:  # a local set once before
        assert isinstance(node, ast.Name)
        return _render(value_node, {k: v for k, v in local.items() if k != node.id}, module)
    return "…"


def registers(family: DriveFamily) -> list[tuple[str, Register]]:
    """(label, register) of every register the family's profile module declares for it."""
    p = family.profile
    module = inspect.getmodule(p)
    assert module is not None
    out: list[tuple[str, Register]] = []
    regs = getattr(p, "regs", None)
    if dataclasses.is_dataclass(regs):  # a register map object (the NT family)
        for f in dataclasses.fields(regs):
            out += _labelled(getattr(regs, f.name))
    shared = [f for f in FAMILIES.values() if inspect.getmodule(f.profile) is module]
    prefix = f"{family.name.upper()}_" if len(shared) > 1 else ""
    for name, value in vars(module).items():
        if name.startswith("_") or (prefix and not name.startswith(prefix)):
            continue
        if inspect.isclass(value) and value.__module__ == module.__name__:
            out += _labelled(v for k, v in vars(value).items() if not k.startswith("_"))
        else:
            out += _labelled(value)
    unique: dict[tuple[str, int, int | None], tuple[str, Register]] = {}
    for label, reg in out:
        unique.setdefault((reg.name, reg.address, reg.low_address), (label, reg))
    return sorted(unique.values(), key=lambda lr: (lr[1].address, lr[0]))


def _labelled(value: Any) -> list[tuple[str, Register]]:
    if isinstance(value, Register):
        return [(register_address(value), value)]
    if hasattr(value, "register") and isinstance(value.register, Register):  # OD objects
        return [(getattr(value, "label", register_address(value.register)), value.register)]
    if isinstance(value, tuple | list) or inspect.isgenerator(value):
        items: Iterable[Any] = value
        return [x for v in items for x in _labelled(v)]
    return []


def _registers(family: DriveFamily) -> str:
    return registers_table(
        ((label, r, "") for label, r in registers(family)),
        "The register map the profile declares (0-based PDU addresses, as the manuals "
        "print them), with the ranges every write is checked against:")


def _rst_to_md(doc: str) -> str:
    """A docstring as markdown: dedented, ``literal`` as `literal`, bullets kept."""
    lines = inspect.cleandoc(re.sub(r"``([^`]+)``", r"`\1`", doc)).splitlines()
    out: list[str] = []
    for line in lines:
        bullet = re.match(r"[*-] ", line)
        if bullet and out and out[-1].strip() and not re.match(r"\s*[*-] |\s+\S", out[-1]):
            out.append("")  # markdown needs a blank line before a list
        out.append(line)
    return "\n".join(out)
