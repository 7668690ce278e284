"""The drive families' pages, generated from the profiles' own declarations.

Each family's page (``docs/drives/<family>.md``) and the families table of
``docs/drives/index.md`` are what the code of the family (``drivebus.drives.registry.
FAMILIES``) declares: link, addresses, line kinds, baud rates and formats, pulses/rev,
homing methods, the ``drive_options`` with their types, ranges and defaults, which
procedures it supports and why not, its parameters (``drivebus params``), how it takes a
new address or line settings, the vendor's exception codes and the register map. The
pages are generated and committed (``python docs/hooks/drive_pages.py`` writes them), so
the repository holds them as a user reads them; as an mkdocs hook this module fails the
build while a page differs from what the code declares (``tests/test_docs.py`` checks
the same), or while a registered family has no page.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import re
import textwrap
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from mkdocs.config.defaults import MkDocsConfig
from mkdocs.exceptions import PluginError
from mkdocs.structure.files import Files
from mkdocs.structure.pages import Page

from drivebus.drives.base import DriveProfile
from drivebus.drives.pages import (
    at_a_glance,
    cell,
    commissioning_section,
    exceptions_section,
    families_table,
    options_section,
    parameters_section,
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

_MARK = re.compile(r"^<!--\s*drive-family:\s*(\S+)[^>]*-->\s*$", re.MULTILINE)
_TABLE_MARK = "<!-- drive-families -->"
_TABLE_END = "<!-- /drive-families -->"
_PAGE = "drives/{slug}.md"
_DOCS = Path(__file__).resolve().parents[1]
_NOTE = "generated from the profile by `python docs/hooks/drive_pages.py`; do not edit"

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
    """Check that a drive page is what the code declares (it is committed generated)."""
    match = _MARK.search(markdown)
    if match is not None:
        name = match.group(1)
        family = FAMILIES.get(name)
        if family is None:
            raise PluginError(
                f"drive_pages: {page.file.src_path} names drive family {name!r}; "
                f"known: {', '.join(FAMILIES)}"
            )
        _seen.add(name)
        if markdown != page_text(family):
            raise PluginError(f"drive_pages: docs/{page.file.src_path} is not what the "
                              f"{name} profile declares: run python docs/hooks/drive_pages.py")
    if _TABLE_MARK in markdown and markdown != index_text(markdown):
        raise PluginError("drive_pages: docs/drives/index.md's families table is stale: run "
                          "python docs/hooks/drive_pages.py")
    return markdown


def page_text(family: DriveFamily) -> str:
    """The whole page of ``family``, as committed."""
    return (f"# {family.name}\n\n<!-- drive-family: {family.name} ({_NOTE}) -->\n\n"
            f"{family_page(family)}\n")


def index_text(current: str) -> str:
    """``docs/drives/index.md`` with the families table between its markers renewed."""
    head, _, rest = current.partition(_TABLE_MARK)
    _, _, tail = rest.partition(_TABLE_END)
    return f"{head}{_TABLE_MARK}\n{families_table(FAMILIES.values())}\n{_TABLE_END}{tail}"


def write_pages(docs: Path = _DOCS) -> list[Path]:
    """Write every family's page and the families table; the files that changed."""
    changed = []
    index = docs / "drives" / "index.md"
    pages = {index: index_text(index.read_text())}
    pages.update({docs / _PAGE.format(slug=slug(n)): page_text(f) for n, f in FAMILIES.items()})
    for path, text in pages.items():
        if not path.exists() or path.read_text() != text:
            path.write_text(text)
            changed.append(path)
    return changed


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
        parameters_section(p),
        commissioning_section(p),
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


_SOURCES = re.compile(r"\s*\((?:[^()]*?)`?shared/(?:seeds|drives)/[^()]*\)|"
                      r"`?shared/(?:seeds|drives)/[^\s`),]*`?")


def _no_build_paths(text: str) -> str:
    """``text`` without the paths of the manuals' copies in drivebus's own build
    environment (a user has the vendor's manual, not those files)."""
    return _SOURCES.sub(lambda m: "" if m.group(0).lstrip().startswith("(") else
                        "the vendor's manual", text)


def _rst_to_md(doc: str) -> str:
    """A docstring as markdown: dedented, ``literal`` as `literal`, bullets kept, no
    build-environment paths."""
    doc = _no_build_paths(re.sub(r"``([^`]+)``", r"`\1`", doc))
    lines = inspect.cleandoc(doc).splitlines()
    out: list[str] = []
    for line in lines:
        bullet = re.match(r"[*-] ", line)
        if bullet and out and out[-1].strip() and not re.match(r"\s*[*-] |\s+\S", out[-1]):
            out.append("")  # markdown needs a blank line before a list
        out.append(line)
    return "\n".join(out)


if __name__ == "__main__":
    for written in write_pages():
        print(f"wrote {written.relative_to(_DOCS.parent)}")
