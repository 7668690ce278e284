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

from drivebus import Bus, LineSettings, SerialLine
from drivebus.drives.base import _PROCEDURES, DriveProfile, describe_values
from drivebus.drives.registers import Access, Register, WordOrder
from drivebus.drives.registry import FAMILIES, DriveFamily
from drivebus.errors import NotSupported

_MARK = re.compile(r"^<!--\s*drive-family:\s*(\S+)[^>]*-->\s*$", re.MULTILINE)
_TABLE_MARK = "<!-- drive-families -->"
_TABLE_END = "<!-- /drive-families -->"
_PAGE = "drives/{slug}.md"
_DOCS = Path(__file__).resolve().parents[1]
_NOTE = "generated from the profile by `python docs/hooks/drive_pages.py`; do not edit"

_LINK = {"rtu": "Modbus RTU", "tcp": "Modbus TCP"}
_KINDS = {
    "serial": "serial (an RS-485 port)",
    "rtu-over-tcp": "rtu-over-tcp (a serial device server)",
    "tcp": "tcp (Modbus TCP; an RTU drive through a gateway)",
}
_ORDER = {WordOrder.LOW_FIRST: "low word first", WordOrder.HIGH_FIRST: "high word first"}
_ACCESS = {Access.R: "R", Access.W: "W", Access.RW: "RW"}

_seen: set[str] = set()


def slug(name: str) -> str:
    """The page name of family ``name``: ``drives/<slug>.md``."""
    return name.lower()


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
    return f"{head}{_TABLE_MARK}\n{families_table()}\n{_TABLE_END}{tail}"


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


def families_table() -> str:
    """One row per family: link, addresses, baud rates, formats, homing, what it cannot do."""
    rows = ["| Family | Drive | Link | Addresses | Baud rates | Formats | Cannot |",
            "|---|---|---|---|---|---|---|"]
    for name, f in FAMILIES.items():
        p = f.profile
        cannot = [proc for proc, why in procedures(f) if why]
        rows.append(
            f"| [{name}]({slug(name)}.md) | {f.description} | {_LINK.get(f.link, f.link)} | "
            f"{_values(p.addresses)} | {_bauds(p)} | {_formats(p)} | "
            f"{', '.join(_PROCEDURES[c] for c in cannot) or '-'} |"
        )
    return "\n".join(rows)


def family_page(family: DriveFamily) -> str:
    """The generated part of one family's page."""
    p = family.profile
    parts = [
        _about(family),
        _at_a_glance(family),
        _options(p),
        _procedures(family),
        _limits(p),
        _parameters(p),
        _commissioning(p),
        _exceptions(p),
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


def _at_a_glance(family: DriveFamily) -> str:
    p = family.profile
    kinds = "<br>".join(_KINDS.get(k, k) for k in sorted(p.line_kinds))
    homing = ", ".join(
        f"`{m}`" + (" (default)" if i == 0 else "") for i, m in enumerate(p.homing_methods)
    ) or "none over Modbus"
    ppr = p.pulses_per_rev_allowed
    rows = [
        ("Drive", family.description),
        ("Profile", f"`{p.__module__}.{p.__qualname__}`"),
        ("Machine file", f'`drive = "{family.name}"`'),
        ("Link", _LINK.get(family.link, family.link)),
        ("Line kinds", kinds),
        ("Addresses (unit ids)", _values(p.addresses)),
        ("Baud rates", _bauds(p)),
        ("Line formats", _formats(p)),
        ("Pulses per revolution", _values(ppr)),
        ("32-bit word order", _ORDER[p.word_order]),
        ("Homing methods", homing),
        ("Standard Modbus frames", "yes" if p.standard_frames else
         "no (a scan asks the family itself)"),
    ]
    body = "\n".join(f"| {k} | {v} |" for k, v in rows)
    return f"## At a glance\n\n| Declaration | Value |\n|---|---|\n{body}"


def _values(values: Iterable[int]) -> str:
    """``lo..hi`` for a range (one value alone), else the values listed."""
    if isinstance(values, range) and len(values) == 1:
        return str(values.start)
    if isinstance(values, range):
        return describe_values(values)
    return ", ".join(map(str, values))


def _bauds(p: type[DriveProfile]) -> str:
    if "serial" not in p.line_kinds:
        return "- (not on a serial line)"
    return ", ".join(map(str, p.baud_rates)) or "any"


def _formats(p: type[DriveProfile]) -> str:
    if "serial" not in p.line_kinds:
        return "- (not on a serial line)"
    return ", ".join(p.line_formats) or "any"


def _options(p: type[DriveProfile]) -> str:
    schema = p.options.model_json_schema()
    props: dict[str, Any] = schema.get("properties", {})
    head = "## `drive_options`\n\n"
    if not props:
        return head + (f"The {p.family} profile takes no `drive_options` (only "
                       "`pulses_per_rev`, a key of the axis itself).")
    defaults = _constructor_defaults(p)
    rows = ["| Option | Type | Allowed | Default |", "|---|---|---|---|"]
    for name, prop in props.items():
        kind, allowed = _describe_schema(prop)
        default = defaults.get(name, inspect.Parameter.empty)
        shown = ("-" if default is inspect.Parameter.empty else
                 "not set" if default is None else f"`{_toml(default)}`")
        rows.append(f"| `{name}` | {kind} | {allowed} | {shown} |")
    example = {k: v for k, v in defaults.items() if k in props and v is not None}
    toml = ", ".join(f"{k} = {_toml(v)}" for k, v in example.items())
    text = head + "\n".join(rows)
    text += ("\n\nTypes are strict (a float option takes a number, a whole option an "
             "integer, a flag `true`/`false`); a machine file that gives anything else, "
             "an unknown option or a value out of range is refused at load time with one "
             "`ConfigError` naming the key, the value and what is allowed.")
    if toml:
        text += (f"\n\nIn a machine file, with the defaults spelt out:\n\n```toml\n"
                 f"[axes.x]\ndrive = \"{p.family}\"\ndrive_options = {{ {toml} }}\n```")
    return text


def _constructor_defaults(p: type[DriveProfile]) -> dict[str, Any]:
    params = inspect.signature(p.__init__).parameters
    return {
        n: prm.default for n, prm in params.items()
        if prm.kind is inspect.Parameter.KEYWORD_ONLY and n != "pulses_per_rev"
    }


def _describe_schema(prop: dict[str, Any]) -> tuple[str, str]:
    """(type, allowed values) of one option's JSON schema (its None branch dropped)."""
    branches = [b for b in prop.get("anyOf", [prop]) if b.get("type") != "null"]
    kinds, allowed = [], []
    for b in branches:
        t = b.get("type")
        note = b.get("description") or prop.get("description") or ""
        if t == "object":
            keys = b.get("propertyNames", {}).get("enum")
            values = b.get("additionalProperties", {}).get("enum")
            kinds.append("table")
            allowed.append(
                "keys: " + (", ".join(f"`{k}`" for k in keys) if keys else "any")
                + "<br>values: " + (", ".join(f"`{v}`" for v in values) if values else "any")
            )
            continue
        kinds.append({"number": "float", "integer": "int", "boolean": "bool",
                      "string": "string"}.get(t, str(t)))
        if "enum" in b:
            allowed.append(", ".join(f"`{v}`" for v in b["enum"]))
        elif t in ("number", "integer"):
            lo = b.get("minimum", b.get("exclusiveMinimum"))
            hi = b.get("maximum", b.get("exclusiveMaximum"))
            lo_op = "<" if "exclusiveMinimum" in b else "≤"
            hi_op = "<" if "exclusiveMaximum" in b else "≤"
            rng = " ".join(
                x for x in (f"{lo} {lo_op}" if lo is not None else "", "x",
                            f"{hi_op} {hi}" if hi is not None else "") if x
            )
            allowed.append(rng if rng != "x" else "any")
        elif t == "boolean":
            allowed.append("`true`, `false`")
        else:
            allowed.append("any")
        if note:
            allowed[-1] += f" ({note})"
    return " or ".join(kinds), "; ".join(allowed)


def _toml(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml(x)}" for k, x in v.items()) + " }"
    return repr(v)


def procedures(family: DriveFamily) -> list[tuple[str, str]]:
    """(procedure, why not or "") for every common procedure, asked of a profile built
    with its default options (no I/O: ``check_supported`` only reads declarations)."""
    p = family.profile
    address = min(p.addresses)
    bus = Bus(SerialLine("/dev/null", LineSettings.parse("9600 8N1")))
    profile = p(bus.slave(address))
    out = []
    for proc in _PROCEDURES:
        try:
            profile.check_supported(proc)
        except NotSupported as exc:
            out.append((proc, str(exc)))
        else:
            why = profile.save_problem() if proc == "save_parameters" else None
            out.append((proc, why or ""))
    return out


def _procedures(family: DriveFamily) -> str:
    rows = ["| Procedure | With the default options |", "|---|---|"]
    for proc, why in procedures(family):
        # "the NT86 drive cannot clear an alarm over Modbus: REASON" -> "no: REASON"
        reason = re.sub(r"^the \S+ drive cannot .*? over Modbus:?\s*", "", why)
        rows.append(f"| {_PROCEDURES[proc]} | {'yes' if not why else 'no: ' + _cell(reason)} |")
    return ("## Procedures\n\nWhat the axis can ask of the drive, as the profile answers "
            "before anything is sent (a refused command raises `NotSupported` and changes "
            "nothing):\n\n" + "\n".join(rows))


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
                yield what, _cell(why)


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


def _parameters(p: type[DriveProfile]) -> str:
    params = p.parameters()
    if not params:
        return ""
    rows = ["| Key | Name | Where | Range | Unit | Kept |", "|---|---|---|---|---|---|"]
    for prm in params:
        kept = "saved" if prm.stored else "volatile"
        if prm.comms:
            kept += ", address/line (only with `--include-comms`)"
        rows.append(f"| `{prm.key}` | {_cell(prm.name)} | {prm.location} | "
                    f"{prm.register.lo}..{prm.register.hi} | {prm.unit or '-'} | {kept} |")
    wt = p.write_through
    how = "`--save` makes the drive store them once at the end (its save command)."
    if p.saves_by_write_through and wt is not None:
        how = (f"The drive has no save command: with `--save` each value is stored as it is "
               f"written, with {_cell(wt.register.name)} ({_address(wt.register)}) = "
               f"{wt.on} for the load; without it that switch is {wt.off} (RAM only).")
    elif wt is not None:
        how += (f" {_cell(wt.register.name)} ({_address(wt.register)}) is kept at {wt.off} "
                f"during a load, so no write wears the EEPROM on its own.")
    return ("## Parameters\n\nWhat `drivebus params dump` backs up and `params load` "
            "restores (only what differs, in this order, every value checked against its "
            f"range before the first write). {how}\n\n" + "\n".join(rows))


def _commissioning(p: type[DriveProfile]) -> str:
    if not p.comms_note:
        return ""
    can = p.comms_writes is not DriveProfile.comms_writes
    verb = ("`drivebus commission` writes them" if can else
            "`drivebus commission` cannot change them")
    return f"## Address and line settings\n\n{verb}: {_cell(p.comms_note)}."


def _exceptions(p: type[DriveProfile]) -> str:
    if not p.exception_texts:
        return ""
    rows = ["| Code | The vendor's meaning |", "|---|---|"]
    rows += [f"| {c:02d} | {_cell(t)} |" for c, t in sorted(p.exception_texts.items())]
    return ("## Modbus exception codes\n\n`ModbusException` carries the code and this "
            "text (the vendor's own meaning where it redefines the standard codes):\n\n"
            + "\n".join(rows))


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
        return [(_address(value), value)]
    if hasattr(value, "register") and isinstance(value.register, Register):  # OD objects
        return [(getattr(value, "label", _address(value.register)), value.register)]
    if isinstance(value, tuple | list) or inspect.isgenerator(value):
        items: Iterable[Any] = value
        return [x for v in items for x in _labelled(v)]
    return []


def _address(reg: Register) -> str:
    if reg.words == 2 and reg.low_address is not None:
        return f"0x{reg.address:04X} / 0x{reg.low_address:04X} ({reg.address} / {reg.low_address})"
    if reg.words == 2:
        return f"0x{reg.address:04X}-0x{reg.address + 1:04X} ({reg.address}-{reg.address + 1})"
    return f"0x{reg.address:04X} ({reg.address})"


def _registers(family: DriveFamily) -> str:
    regs = registers(family)
    if not regs:
        return ""
    rows = ["| Address | Name | Width | Range | Unit | Access |", "|---|---|---|---|---|---|"]
    for label, r in regs:
        width = "16 bit" if r.words == 1 else f"32 bit, {_ORDER[r.order]}"
        if r.signed:
            width += ", signed"
        rows.append(f"| {label} | {_cell(r.name)} | {width} | {r.lo}..{r.hi} | "
                    f"{r.unit or '-'} | {_ACCESS[r.access]} |")
    return ("## Registers\n\nThe register map the profile declares (0-based PDU "
            "addresses, as the manuals print them), with the ranges every write is checked "
            "against:\n\n" + "\n".join(rows))


def _cell(text: str) -> str:
    return " ".join(text.split()).replace("|", "\\|")


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
