"""A drive family's reference page (markdown), written from what its profile declares.

The docs site (``docs/hooks/drive_pages.py``) fills each family's page with it, and
``drivebus drive doc FILE`` prints the same page for any description. Nothing here is
typed by hand: link, addresses, baud rates and formats, pulses/rev, homing methods,
``drive_options`` with their types, ranges and defaults, the procedures and why one is
not supported, the vendor's exception codes, and for a described family its registers,
status decoding, procedures' steps and the twin's behaviour.
"""

from __future__ import annotations

import inspect
import re
from collections.abc import Iterable
from typing import Any

from drivebus.bus import Bus
from drivebus.drives.base import _PROCEDURES, DriveProfile, describe_values
from drivebus.drives.description import Description, Reg, Step
from drivebus.drives.registers import Access, Register, WordOrder
from drivebus.drives.registry import DriveFamily
from drivebus.errors import NotSupported
from drivebus.line import SerialLine
from drivebus.settings import LineSettings

__all__ = [
    "at_a_glance",
    "cell",
    "commissioning_section",
    "description_sections",
    "exceptions_section",
    "families_table",
    "family_page",
    "options_section",
    "parameters_section",
    "procedures",
    "procedures_section",
    "register_address",
    "registers_table",
]

_LINK = {"rtu": "Modbus RTU", "tcp": "Modbus TCP"}
_KINDS = {
    "serial": "serial (an RS-485 port)",
    "rtu-over-tcp": "rtu-over-tcp (a serial device server)",
    "tcp": "tcp (Modbus TCP; an RTU drive through a gateway)",
}
ORDER = {WordOrder.LOW_FIRST: "low word first", WordOrder.HIGH_FIRST: "high word first"}
ACCESS = {Access.R: "R", Access.W: "W", Access.RW: "RW"}


def cell(text: str) -> str:
    """``text`` fit for a markdown table cell."""
    return " ".join(text.split()).replace("|", "\\|")


def slug(name: str) -> str:
    """The page name of family ``name``: ``drives/<slug>.md``."""
    return name.lower()


def families_table(families: Iterable[DriveFamily]) -> str:
    """One row per family: link, addresses, baud rates, formats, what it cannot do."""
    rows = ["| Family | Drive | Link | Addresses | Baud rates | Formats | Cannot |",
            "|---|---|---|---|---|---|---|"]
    for f in families:
        p = f.profile
        cannot = [proc for proc, why in procedures(f) if why]
        rows.append(
            f"| [{f.name}]({slug(f.name)}.md) | {f.description} | "
            f"{_LINK.get(f.link, f.link)} | {_values(p.addresses)} | {_bauds(p)} | "
            f"{_formats(p)} | {', '.join(_PROCEDURES[c] for c in cannot) or '-'} |"
        )
    return "\n".join(rows)


def family_page(family: DriveFamily) -> str:
    """The whole generated page of a described family (``drivebus drive doc``)."""
    assert family.spec is not None
    d = family.spec
    p = family.profile
    head = (f"*Generated from `{p.__module__}.{p.__qualname__}`, the "
            f"{d.drive.engine} engine running the description "
            f"{'built into drivebus' if family.source == 'built in' else family.source}.*")
    parts = [head, *description_sections(family)]
    return "\n\n".join(x for x in parts if x)


def description_sections(family: DriveFamily) -> list[str]:
    """The sections of a described family's page."""
    assert family.spec is not None
    d = family.spec
    p = family.profile
    return [
        _about(d),
        at_a_glance(family),
        options_section(p),
        procedures_section(family),
        _unsupported(d),
        parameters_section(p),
        commissioning_section(p),
        exceptions_section(p),
        _status(d),
        _homing(d),
        _programs_io(d),
        registers_table(_described_registers(d),
                        "The register map of the description (0-based PDU addresses, as "
                        "the manual prints them), with the ranges every write is checked "
                        "against and where each register comes from:"),
        _examples(d),
        _steps(d),
        _twin(d),
    ]


def _provenance(d: Description) -> str:
    """Where the description's items come from, by kind; the inferred ones named; the
    sources the sections ``[identify]``, ``[link]``, ``[status]``, ``[alarms]`` name."""
    prov = d.provenance()
    total = sum(len(v) for v in prov.values())
    text = (f"Provenance of its {total} registers, bits, procedures, homing methods and "
            f"sections: " + ", ".join(f"{len(prov[k])} {k}" for k in (
                "manual", "code", "inferred", "unnamed") if prov[k]) + ".")
    own = {k: v for k, v in d.section_sources().items() if v}
    if own:
        text += ("\n\nWhere its sections come from" + (
            f" (the others: {d.drive.source})" if d.drive.source and len(own) < len(
                d.section_sources()) else "") + ":\n\n"
            + "\n".join(f"- `[{k}]`: {cell(v)}" for k, v in own.items()))
    partly = d.partly_inferred()
    if partly:
        text = (f"**{len(partly)} items are partly inferred** (their source says which "
                f"part; check it on the drive): " + ", ".join(f"`{x}`" for x in partly)
                + ".\n\n" + text)
    if prov["inferred"]:
        text = (f"**{len(prov['inferred'])} items are inferred** (neither the manual nor "
                f"public code says them; check them on the drive): "
                + ", ".join(f"`{x}`" for x in prov["inferred"]) + ".\n\n" + text)
    return text


def _examples(d: Description) -> str:
    """The manual's example frames the description carries (``drive check`` verifies
    each against the engine)."""
    if not d.examples:
        return ""
    rows = ["| Example | Request | Reply | Stands for |", "|---|---|---|---|"]
    for ex in d.examples:
        what = (f"write {', '.join(f'{k} = {v}' for k, v in (ex.write or {}).items())}"
                if ex.write is not None else "read " + ", ".join(
                    x if isinstance(x, str) else "..".join(x) for x in ex.read)
                if ex.read is not None else f"{ex.procedure}("
                + ", ".join(f"{k}={v}" for k, v in ex.args.items()) + ")"
                if ex.procedure is not None else "nothing this drive does")
        if ex.values:
            what += " → " + ", ".join(f"{k} = {v}" for k, v in ex.values.items())
        if ex.erratum:
            what += f" (erratum: {ex.erratum})"
        doc = ex.doc + (f" ({ex.source})" if ex.source else "")
        rows.append(f"| {cell(doc) or '-'} | `{'`<br>`'.join(ex.request)}` | "
                    + (f"`{'`<br>`'.join(ex.reply)}`" if ex.reply else "-")
                    + f" | {cell(what)} |")
    return ("## The manual's example frames\n\n`drivebus drive check` verifies that the "
            "engine sends exactly these bytes for what each stands for, and decodes the "
            "replies to the values printed:\n\n" + "\n".join(rows))


def _about(d: Description) -> str:
    text = []
    if d.drive.about.strip():
        text.append("## About the drive\n\n" + d.drive.about.strip())
    if d.drive.manual:
        text.append(f"Register tables from: {d.drive.manual}.")
    text.append(_provenance(d))
    return "\n\n".join(text)


def at_a_glance(family: DriveFamily) -> str:
    """The family's declarations as a table."""
    p = family.profile
    kinds = "<br>".join(_KINDS.get(k, k) for k in sorted(p.line_kinds))
    homing = ", ".join(
        f"`{m}`" + (" (default)" if i == 0 else "") for i, m in enumerate(p.homing_methods)
    ) or "none over Modbus"
    rows = [
        ("Drive", family.description),
        ("Profile", f"`{p.__module__}.{p.__qualname__}`"),
        ("Machine file", f'`drive = "{family.name}"`'),
        ("Link", _LINK.get(family.link, family.link)),
        ("Line kinds", kinds),
        ("Addresses (unit ids)", _values(p.addresses)),
        ("Baud rates", _bauds(p)),
        ("Line formats", _formats(p)),
        ("Pulses per revolution", _values(p.pulses_per_rev_allowed)),
        ("32-bit word order", ORDER[p.word_order]),
        ("Homing methods", homing),
        ("Standard Modbus frames", "yes" if p.standard_frames else
         "no (a scan asks the family itself)"),
    ]
    body = "\n".join(f"| {k} | {v} |" for k, v in rows)
    return f"## At a glance\n\n| Declaration | Value |\n|---|---|\n{body}"


def _values(values: Iterable[int]) -> str:
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


def options_section(p: type[DriveProfile]) -> str:
    """The ``drive_options`` table: type, allowed values, default."""
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
            allowed[-1] += f" ({cell(note)})"
    return " or ".join(kinds), "; ".join(allowed)


def _toml(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml(x)}" for k, x in v.items()) + " }"
    return repr(v)


def _idle_profile(p: type[DriveProfile]) -> DriveProfile:
    """A profile of ``p`` with its default options on a line never opened (no I/O: for
    what ``check_supported`` and ``save_problem`` read from its declarations)."""
    bus = Bus(SerialLine("/dev/null", LineSettings.parse("9600 8N1")))
    return p(bus.slave(min(p.addresses)))


def procedures(family: DriveFamily) -> list[tuple[str, str]]:
    """(procedure, why not or "") for every common procedure, asked of a profile built
    with its default options (no I/O: ``check_supported`` only reads declarations)."""
    profile = _idle_profile(family.profile)
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


def procedures_section(family: DriveFamily) -> str:
    """Which common procedures the drive supports, and why not."""
    rows = ["| Procedure | With the default options |", "|---|---|"]
    for proc, why in procedures(family):
        # "the NT86 drive cannot clear an alarm over Modbus: REASON" -> "no: REASON"
        reason = re.sub(r"^the \S+ drive cannot .*? over Modbus:?\s*", "", why)
        rows.append(f"| {_PROCEDURES[proc]} | {'yes' if not why else 'no: ' + cell(reason)} |")
    return ("## Procedures\n\nWhat the axis can ask of the drive, as the profile answers "
            "before anything is sent (a refused command raises `NotSupported` and changes "
            "nothing):\n\n" + "\n".join(rows))


def _unsupported(d: Description) -> str:
    items = []
    for name, proc in d.procedures.items():
        if proc.unsupported is not None:
            what = str(proc.what) if proc.what is not None else d.procedure_what(name)
            items.append(f"- **cannot {what}** (`{name}`): {proc.unsupported}")
        elif proc.supported is not None:
            items.append(f"- `{name}` only when `{proc.supported}`"
                         + (f": {proc.why}" if proc.why else ""))
    if not items:
        return ""
    return ("## What it cannot do, and why\n\nAs its description says (`…{…}` stands for "
            "a value known only at run time):\n\n" + "\n".join(items))


def exceptions_section(p: type[DriveProfile]) -> str:
    """The vendor's exception codes."""
    if not p.exception_texts:
        return ""
    rows = ["| Code | The vendor's meaning |", "|---|---|"]
    rows += [f"| {c:02d} | {cell(t)} |" for c, t in sorted(p.exception_texts.items())]
    return ("## Modbus exception codes\n\n`ModbusException` carries the code and this "
            "text (the vendor's own meaning where it redefines the standard codes):\n\n"
            + "\n".join(rows))


def parameters_section(p: type[DriveProfile]) -> str:
    """The parameters ``drivebus params`` backs up and restores, and how they are kept."""
    params = p.parameters()
    if not params:
        return ""
    rows = ["| Key | Name | Where | Range | Unit | Kept |", "|---|---|---|---|---|---|"]
    for prm in params:
        kept = "saved" if prm.stored else "volatile"
        if prm.comms:
            kept += ", address/line (only with `--include-comms`)"
        rows.append(f"| `{prm.key}` | {cell(prm.name)} | {prm.location} | "
                    f"{prm.register.lo}..{prm.register.hi} | {prm.unit or '-'} | {kept} |")
    wt = p.write_through
    how = "`--save` makes the drive store them once at the end (its save command)."
    if not p.saves_by_write_through and (why := _idle_profile(p).save_problem()):
        how = f"`--save` is refused: {cell(why)}."
    if p.saves_by_write_through and wt is not None:
        how = (f"The drive has no save command: with `--save` each value is stored as it is "
               f"written, with {cell(wt.register.name)} ({register_address(wt.register)}) = "
               f"{wt.on} for the load; without it that switch is {wt.off} (RAM only).")
    elif wt is not None:
        how += (f" {cell(wt.register.name)} ({register_address(wt.register)}) is kept at "
                f"{wt.off} during a load, so no write wears the EEPROM on its own.")
    return ("## Parameters\n\nWhat `drivebus params dump` backs up and `params load` "
            "restores (only what differs, in this order, every value checked against its "
            f"range before the first write). {how}\n\n" + "\n".join(rows))


def commissioning_section(p: type[DriveProfile]) -> str:
    """How the drive takes a new address or line settings (``drivebus commission``)."""
    if not p.comms_note:
        return ""
    can = p.comms_writes is not DriveProfile.comms_writes
    verb = ("`drivebus commission` writes them" if can else
            "`drivebus commission` cannot change them")
    return f"## Address and line settings\n\n{verb}: {cell(p.comms_note)}."


def _status(d: Description) -> str:
    s = d.status
    # the command engine decodes a field [status] does not give from the meanings
    derived = d.status_exprs if d.drive.engine == "command" else {}
    rows = ["| Field | From |", "|---|---|"]
    for field in ("enabled", "moving", "in_position", "homed", "homing", "homing_error",
                  "alarm", "alarm_code", "limit_positive", "limit_negative", "position",
                  "velocity"):
        e = getattr(s, field)
        how = ""
        if e is None and derived.get(field) is not None:
            e, how = derived[field], " (from the meanings)"
        rows.append(f"| {field} | {'`' + cell(str(e)) + '`' + how if e is not None else '-'} |")
    polled = ", ".join(f"[{a[0]}..{a[1]}]" if isinstance(a, list) else a for a in s.poll)
    text = "## Status\n\n" + (f"Polled: {polled}.\n\n" if polled else "") + "\n".join(rows)
    if d.alarms is not None and d.alarms.texts:
        text += "\n\nAlarm codes (" + d.alarms.reg + ", " + d.alarms.kind + "):\n\n"
        text += "| Code | Meaning |\n|---|---|\n" + "\n".join(
            f"| {c} | {cell(t)} |" for c, t in d.alarms.texts.items())
    return text


def _homing(d: Description) -> str:
    if d.homing is None:
        return ""
    rows = ["| Method | Code | CiA 402 equivalent | Notes |", "|---|---|---|---|"]
    for name, m in d.homing.methods.items():
        rows.append(f"| `{name}` | {'-' if m.code is None else m.code} | "
                    f"{'-' if m.cia402 is None else m.cia402} | {cell(m.doc)} |")
    return "## Homing methods\n\nThe first is the default.\n\n" + "\n".join(rows)


def _programs_io(d: Description) -> str:
    """``[programs]`` and the terminals of ``[inputs]``/``[outputs]``."""
    parts = []
    pr = d.programs
    rows = [(k, getattr(pr, k)) for k in ("preload", "preload_braking", "retarget", "jog_speed")]
    given = [f"| {k} | {cell(v)} |" for k, v in rows if v]
    if given:
        parts.append("## Motion programs\n\n| Mechanism | How |\n|---|---|\n"
                     + "\n".join(given))
    io_rows = []
    for io, kind in ((d.inputs, "inputs"), (d.outputs, "outputs")):
        if io is not None and io.names:
            io_rows.append(f"| {kind} | {', '.join(io.names)} | {io.state} | "
                           f"{io.functions or '-'} |")
    if io_rows:
        parts.append("## Digital I/O\n\n| Terminals | Names (bit 0 first) | State | "
                     "Functions |\n|---|---|---|---|\n" + "\n".join(io_rows))
    return "\n\n".join(parts)


def _described_registers(d: Description) -> list[tuple[str, Register, str]]:
    out = []
    for reg in d.regs.values():
        r = reg.register
        label = register_address(r)
        if reg.array:
            last = reg.at(reg.indices.stop - 1)
            label = f"{register_address(r)} .. {register_address(last)} (×{reg.d.count})"
        notes = _reg_notes(reg)
        source = reg.d.source or d.drive.source or "not named"
        out.append((label, r, f"{notes}; source: {source}" if notes else f"source: {source}"))
    return sorted(out, key=lambda x: x[1].address)


def _reg_notes(reg: Reg) -> str:
    notes = []
    how = reg.codec.describe()
    if how and how != reg.d.unit:
        notes.append(how)
    if reg.d.input or reg.d.coil or reg.d.discrete:
        notes.append("input register (FC04)" if reg.d.input else "coil (FC01/FC05)"
                     if reg.d.coil else "discrete input (FC02)")
    if reg.d.eeprom:
        notes.append("write wears EEPROM")
    if reg.d.volatile:
        notes.append("volatile")
    if reg.d.bits:
        notes.append("bits: " + ", ".join(f"{k}={b.bit}" for k, b in reg.d.bits.items()))
    if reg.d.doc:
        notes.append(reg.d.doc)
    return "; ".join(notes)


def register_address(reg: Register) -> str:
    """A register's address(es) as hex and decimal."""
    if reg.words == 2 and reg.low_address is not None:
        return f"0x{reg.address:04X} / 0x{reg.low_address:04X} ({reg.address} / {reg.low_address})"
    if reg.words == 2:
        return f"0x{reg.address:04X}-0x{reg.address + 1:04X} ({reg.address}-{reg.address + 1})"
    return f"0x{reg.address:04X} ({reg.address})"


def registers_table(regs: Iterable[tuple[str, Register, str]], intro: str) -> str:
    """The registers as a table."""
    regs = list(regs)
    if not regs:
        return ""
    with_notes = any(notes for _, _, notes in regs)
    rows = ["| Address | Name | Width | Range | Unit | Access |" + (" Notes |" if with_notes
                                                                    else ""),
            "|---|---|---|---|---|---|" + ("---|" if with_notes else "")]
    for label, r, notes in regs:
        width = "16 bit" if r.words == 1 else f"32 bit, {ORDER[r.order]}"
        if r.signed:
            width += ", signed"
        rows.append(f"| {label} | {cell(r.name)} | {width} | {r.lo}..{r.hi} | "
                    f"{r.unit or '-'} | {ACCESS[r.access]} |"
                    + (f" {cell(notes) or '-'} |" if with_notes else ""))
    return "## Registers\n\n" + intro + "\n\n" + "\n".join(rows)


def _step_text(step: Step) -> str:
    a = step.action
    if a == "write" and step.write is not None:
        body = ", ".join(f"{k} = {v.value}{' (raw)' if v.raw else ''}"
                         for k, v in step.write.items())
        how = "" if step.block is None else " (one FC16)" if step.block.constant else \
            f" (one FC16 when {step.block})"
        text = f"write {body}{how}"
    elif a == "read":
        text = "read " + ", ".join(f"[{x[0]}..{x[1]}]" if isinstance(x, list) else x
                                   for x in step.read or [])
    elif a == "modify":
        text = f"modify {step.modify}"
    elif a == "call":
        text = f"call {step.call}"
    elif a == "check":
        text = f"check {step.check}"
    elif a == "wait":
        text = f"wait until {step.wait} (at most {step.timeout} s)"
    elif a == "set":
        text = "set " + ", ".join(f"{k} = {v}" for k, v in (step.set or {}).items())
    elif a == "fail":
        text = f"refuse: {step.fail}"
    else:
        text = f"return {step.return_}"
    if step.each is not None:
        text += f", for each {step.each}"
    if step.if_changed:
        text += ", each only where it differs from what the drive holds"
    if step.when is not None:
        text += f", when {step.when}"
    if step.start:
        text += " (the start of a prepared move)"
    if step.volatile:
        text += " (volatile: checked after a power cycle)"
    return text


def _steps(d: Description) -> str:
    parts = []
    for name, proc in d.procedures.items():
        if proc.unsupported is not None:
            continue
        params = ", ".join(p.name for p in proc.params)
        head = f"### `{name}({params})`" if params else f"### `{name}`"
        body = [proc.doc.strip()] if proc.doc else []
        items = "\n".join(f"{i}. `{' '.join(_step_text(s).split())}`"
                          for i, s in enumerate(proc.steps, 1))
        parts.append("\n\n".join([head, *body, items]))
    if not parts:
        return ""
    return "## Procedure steps\n\n" + "\n\n".join(parts)


def _twin(d: Description) -> str:
    t = d.twin
    if not t.on_write:
        return ""
    rows = ["| Register | When | The drive |", "|---|---|---|"]
    for trig in t.on_write:
        params = ", ".join(f"{k} = {getattr(trig, k)}" for k in
                           ("target", "distance", "speed", "accel", "decel", "method",
                            "offset", "position") if getattr(trig, k) is not None)
        rows.append(f"| {trig.reg} | `{cell(str(trig.when or 'any write'))}` | "
                    f"{trig.do}{' (' + cell(params) + ')' if params else ''} |")
    return ("## Behaviour (the simulated twin)\n\nWhat the drive does on a write, as its "
            f"simulated twin plays it; a start needs `{t.starts}`.\n\n" + "\n".join(rows))
