"""What ``drivebus drive check`` and ``drivebus drive doc`` say about a drive description.

``load`` reads a description file (or a family's name) the way a machine file would;
``check_report`` says what drivebus understood of it (link, units, registers, status
decoding, procedures, homing, what it cannot do and why) and warns about what an axis
will miss; ``doc_page`` is the page the docs site shows for a built-in family.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, field
from pathlib import Path

from drivebus.drives.base import _PROCEDURES, DriveProfile, describe_values
from drivebus.drives.description import (
    PROCEDURES,
    Description,
    HomingMethod,
    load_description,
)
from drivebus.drives.pages import family_page
from drivebus.drives.registry import (
    DriveFamily,
    family,
    family_from_description,
    is_file_reference,
)
from drivebus.drives.units import Kind
from drivebus.errors import LimitViolation

__all__ = ["DescriptionReport", "check_report", "doc_page", "load"]

_NEEDED = ("enable", "move_absolute", "move_relative", "speed_run", "stop", "emergency_stop")
"""The procedures an axis uses for its everyday commands."""


def load(ref: str | Path) -> DriveFamily:
    """The family of description file ``ref`` (or of a known family's name)."""
    text = str(ref)
    if isinstance(ref, Path) or is_file_reference(text) or Path(text).is_file():
        p = Path(text)
        return family_from_description(load_description(p), str(p.resolve()))
    return family(text)


@dataclass
class DescriptionReport:
    """What was understood, and the warnings."""

    lines: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    failed: list[str] = field(default_factory=list)
    """What the description gets wrong for certain: a manual's example frame it does not
    reproduce, a procedure that writes a value its register never takes. The check fails
    (``drivebus drive check`` exits 1)."""

    def text(self) -> str:
        """The report as text."""
        out = list(self.lines)
        if self.warnings:
            out += ["", "warnings:"] + [f"  - {w}" for w in self.warnings]
        if self.failed:
            out += ["", "failed:"] + [f"  - {f}" for f in self.failed]
        return "\n".join(out)


def check_report(fam: DriveFamily) -> DescriptionReport:
    """What drivebus understood of a described family."""
    d = fam.spec
    r = DescriptionReport()
    if d is None:
        r.lines.append(f"{fam.name}: a profile written as code ({fam.profile.__module__}); "
                       f"nothing to check")
        return r
    p = fam.profile
    link = d.link
    r.lines += [
        f"{d.family} ({d.drive.engine} engine): {d.drive.description or d.drive.model}",
        f"  source: {fam.source}",
        f"  link: {'Modbus RTU' if link.protocol == 'rtu' else 'Modbus TCP'} on "
        f"{line_kinds_text(link.protocol, p.line_kinds)}; "
        f"{'unit ids' if link.protocol == 'tcp' else 'addresses'} "
        f"{describe_values(p.addresses)}; "
        + ("" if link.protocol == "tcp" else
           f"baud {', '.join(map(str, link.baud_rates)) or 'any'}; formats "
           f"{', '.join(link.formats) or 'any'}; ")
        + f"32-bit values "
        f"{link.word_order.replace('_', ' ')}; function codes "
        f"{', '.join(f'{c:02d}' for c in link.functions)}; at most {link.max_read} registers "
        f"per read",
        f"  pulses/rev: {d.units.pulses_per_rev.default} by default, allowed "
        f"{describe_values(p.pulses_per_rev_allowed)}"
        + (f" (register {d.units.pulses_per_rev.reg})" if d.units.pulses_per_rev.reg else ""),
    ]
    regs = d.regs.values()
    tables = [f"{x.key} ×{x.d.count}" for x in regs if x.array]
    r.lines.append(
        f"  registers: {len(d.regs)} ({sum(x.d.access == 'R' for x in regs)} read-only, "
        f"{sum(x.d.access == 'W' for x in regs)} write-only, {sum(x.d.eeprom for x in regs)} "
        f"wear EEPROM, {sum(x.d.volatile for x in regs)} volatile)"
        + (f"; tables {', '.join(tables)}" if tables else ""))
    r.lines += provenance_lines(d, r)
    from drivebus.drives.examples import out_of_range_writes

    r.failed += out_of_range_writes(d)
    r.lines += conversion_lines(d)
    plan = p._status_plan  # type: ignore[attr-defined]
    by_space = {0: (3, plan.blocks + plan.object_blocks), 1: (4, plan.input_blocks),
                2: (1, plan.coil_blocks), 3: (2, plan.discrete_blocks)}
    r.lines.append("  status poll: " + ", ".join(  # in the order the poll reads them
        f"FC{fc:02d} {start} (0x{start:04X}) ×{count}"
        for fc, blocks in (by_space[space] for space in plan.space_order)
        for start, count in blocks))
    s = d.status
    if d.drive.engine == "cia402":
        _cia402_lines(fam, r)
        return r
    derived = d.status_exprs
    for name in ("enabled", "moving", "in_position", "homed", "homing", "alarm",
                 "alarm_code", "limit_positive", "limit_negative", "position", "velocity"):
        e = derived.get(name)
        how = "" if getattr(s, name) is not None or e is None else "   (from the meanings)"
        r.lines.append(f"    {name:<15} {e if e is not None else '-'}{how}")
        if e is None and name in ("enabled", "moving", "in_position", "alarm", "position"):
            r.warnings.append(f"status.{name} is not decoded: the axis will take it as "
                              f"{'0' if name == 'position' else 'false'}")
    r.lines.append("  procedures:")
    for name, proc in d.procedures.items():
        what = "" if name in PROCEDURES or hasattr(DriveProfile, name) else " (its own)"
        if proc.unsupported is not None:
            r.lines.append(f"    {name:<22} cannot: {proc.unsupported}")
        else:
            cond = f" when {proc.supported}" if proc.supported is not None else ""
            params = ", ".join(x.name for x in proc.params)
            head = f"{name}({params})" if params else name
            takes = ""
            if name == "stop":
                takes = "; takes a deceleration" if proc.honours("decel") else \
                    "; takes no deceleration (stop(decel=...) is refused)"
            r.lines.append(f"    {head:<22} {len(proc.steps)} step(s){cond}{what}{takes}")
    missing = [n for n in _PROCEDURES if n not in d.procedures]
    if missing:
        r.lines.append("  not described (NotSupported): " + ", ".join(missing))
    stops = [n for n in ("stop", "emergency_stop") if n in d.procedures
             and d.procedures[n].unsupported is None]
    for n in _NEEDED:
        if n in d.procedures:
            continue
        if n in ("stop", "emergency_stop") and stops:
            other = stops[0]
            r.warnings.append(f"no procedure {n}: the axis sends its {other} instead "
                              f"({'halt_now()' if n == 'emergency_stop' else 'stop()'} "
                              f"stops the motor, as the {other} does)")
        else:
            r.warnings.append(f"no procedure {n}: the axis cannot {_PROCEDURES[n]}")
    if not stops:
        r.warnings.append("no stop at all (neither procedures.stop nor emergency_stop): "
                          "nothing stops this drive's motor over Modbus: stop() and halt_now() "
                          "are refused, and leaving the machine cannot stop it")
    if d.homing is not None:
        r.lines.append("  homing methods: " + ", ".join(
            f"{n} ({m.code if m.code is not None else '-'}"
            f"{', CiA 402 ' + str(m.cia402) if m.cia402 is not None else ''})"
            for n, m in d.homing.methods.items()))
        known = list(HomingMethod.model_fields)
        for n, m in d.homing.methods.items():
            for key in m.extras:
                close = difflib.get_close_matches(key, known, n=1, cutoff=0.75)
                if close:
                    r.warnings.append(f"homing.methods.{n}.{key}: did you mean {close[0]!r}? "
                                      f"(taken as a value of the drive's own, home.{key})")
        waits = [n for n, m in d.homing.methods.items() if m.behaviour != "set"]
        if waits and derived.get("homed") is None:
            r.warnings.append(
                f"status.homed is not decoded: home() with {', '.join(waits)} waits for the "
                f"drive to report homed and cannot complete (a method that sets the position "
                f"at once, behaviour = \"set\", is homed when its procedure is done)")
    elif "home" in d.procedures:
        r.warnings.append("procedures.home exists but [homing.methods] lists no method")
    offers = [k for k in ("preload", "preload_braking", "retarget", "jog_speed")
              if getattr(d.programs, k)]
    r.lines.append("  motion programs: " + (", ".join(offers) or "nothing beyond buffering"))
    for io, kind in ((d.inputs, "inputs"), (d.outputs, "outputs")):
        if io is not None and io.names:
            r.lines.append(f"  {kind}: {', '.join(io.names)}")
    if d.alarms is None:
        r.warnings.append("no [alarms] section: alarms have no texts")
    ident = d.identify
    r.lines.append("  identify: " + (f"cannot ({ident.cannot})" if ident and ident.cannot else
                                     f"reads {', '.join(ident.read)}, matches {ident.match}"
                                     if ident else "not described: a scan lists it as an "
                                     "unknown Modbus slave"))
    numbers = [reg.d.address for reg in d.regs.values() if not reg.d.input]
    if d.link.register_base == 0 and numbers and all(40001 <= a <= 49999 for a in numbers):
        r.warnings.append(f"every register address is in 40001..49999 ({min(numbers)}..."
                          f"{max(numbers)}): if the manual numbers registers 4xxxx, set "
                          f"[link] register_base = 40001 (the frames carry the number - 40001)")
    if not d.twin.on_write:
        r.warnings.append("no [twin] on_write triggers: the simulated twin will not move "
                          "(drive try fails)")
    else:
        regs_t = sorted({t.reg for t in d.twin.on_write})
        r.lines.append(f"  twin: {len(d.twin.on_write)} triggers on {', '.join(regs_t)}")
    return r


def provenance_lines(d: Description, r: DescriptionReport) -> list[str]:
    """Where the registers, bits, procedures, homing methods and sections come from
    (counts of each kind), the inferred ones named, and the manual's example frames
    verified."""
    prov = d.provenance()
    total = sum(len(v) for v in prov.values())
    lines = [f"  provenance of {total} registers, bits, procedures, homing methods and "
             f"sections: "
             + ", ".join(f"{len(prov[k])} {k}" for k in ("manual", "code", "inferred",
                                                         "unnamed"))]
    for what, names in (("inferred (not from the manual or public code)", prov["inferred"]),
                        ("partly inferred (a manual or code source that says part is "
                         "inferred)", d.partly_inferred())):
        if names:
            lines.append(f"    {what}: " + ", ".join(names[:12])
                         + (f", and {len(names) - 12} more" if len(names) > 12 else ""))
    if prov["unnamed"]:
        r.warnings.append(f"{len(prov['unnamed'])} items name no source (give [drive] "
                          f"source or each its own source = 'manual: ...'): "
                          + ", ".join(prov["unnamed"][:6])
                          + (", ..." if len(prov["unnamed"]) > 6 else ""))
    if d.examples:
        from drivebus.drives.examples import verify_examples

        results = verify_examples(d)
        ok = sum(x.ok and x.ran for x in results)
        errata = sum(not x.ran for x in results)
        lines.append(f"  examples: {ok} of {len(results)} of the manual's example frames "
                     f"verified" + (f", {errata} listed, not run" if errata else ""))
        for x in results:
            mark = "ok  " if x.ok and x.ran else "said" if x.ok else "FAIL"
            lines.append(f"    {mark} {x.where}: {x.detail}")
            if not x.ok:
                r.failed.append(f"{x.where}: {x.detail}")
    else:
        lines.append("  examples: none (add the manual's example frames as [[examples]])")
    return lines


def line_kinds_text(protocol: str, kinds: frozenset[str]) -> str:
    """The kinds of line that reach a drive, each said with what it means."""
    said = {"serial": "serial (RS-485)",
            "rtu-over-tcp": "rtu-over-tcp (RS-485 behind a transparent serial server)",
            "tcp": "tcp (Modbus TCP" + (" through a Modbus TCP/RTU gateway)"
                                       if protocol == "rtu" else ")")}
    order = ("serial", "rtu-over-tcp", "tcp")
    return "lines " + ", ".join(said[k] for k in order if k in kinds)


_EXAMPLES = {Kind.SPEED: (120.0, "rpm (2 rev/s)"), Kind.ACCEL: (100.0, "rev/s²"),
             Kind.RAMP: (100.0, "rev/s²")}
"""The example value of each kind of register in the conversions ``drive check`` shows."""


def conversion_lines(d: Description) -> list[str]:
    """How every register with a unit or a scale converts an example value (a revolution,
    2 rev/s, 100 rev/s², its default, the pulses per revolution), so that a reader sees
    the scale at work: ``steps_per_rev  20000 steps/rev → 52 (0x0034) = 10000``."""
    ppr = d.units.pulses_per_rev
    out: list[str] = []
    for key, reg in d.regs.items():
        codec = reg.codec
        if (not codec.physical and key != ppr.reg) or codec.kind is Kind.TABLE:
            continue
        r = reg.at(reg.d.first) if reg.array else reg.register
        ref = None
        if key == ppr.reg:
            value: float = ppr.default
            unit = codec.unit or "pulses/rev"
        elif codec.kind is Kind.POSITION:
            value, unit = float(ppr.default), f"pulses (1 rev at {ppr.default} pulses/rev)"
        elif codec.kind in _EXAMPLES:
            value, unit = _EXAMPLES[codec.kind]
            if codec.kind is Kind.RAMP and not isinstance(codec.ramp, int | float):
                ref, unit = 600.0, f"rev/s² reaching 600 rpm (in {codec.ramp})"
        else:
            raw_example = reg.default_at(reg.d.first if reg.array else None) or 100
            value = codec.to_physical(raw_example)
            unit = codec.unit or "count"
        number = r.address + d.register_base(reg.d)
        where = f"{number} (0x{r.address:04X})" if d.link.register_base else \
            f"{r.address} (0x{r.address:04X})"
        try:
            raw: str = str(codec.to_raw(r, value, ppr=ppr.default, ref_rpm=ref))
        except LimitViolation as exc:
            raw = f"refused: {exc}"
        out.append(f"    {key:<22} {value:g} {unit} → {where} = {raw}   ({codec.describe()})")
    return ["  conversions (an example value of each register with a unit or scale):",
            *out] if out else []


def _cia402_lines(fam: DriveFamily, r: DescriptionReport) -> None:
    """The CiA 402 engine's part: objects, what the engine can do with them."""
    from drivebus.bus import Bus
    from drivebus.errors import NotSupported
    from drivebus.line import SerialLine
    from drivebus.settings import LineSettings

    d = fam.spec
    assert d is not None
    r.lines.append("  CiA 402 objects:")
    for name, reg in sorted(d.objects.items(), key=lambda nr: nr[1].register.address):
        x = reg.register
        how = reg.codec.describe()
        r.lines.append(f"    {name:<28} {x.address:5d} (0x{x.address:04X}) "
                       f"{16 * x.words}-bit{' signed' if x.signed else ''}"
                       + (f", {how}" if how else ""))
    for needed in ("modes_of_operation", "target_position", "profile_velocity",
                   "profile_acceleration", "profile_deceleration", "velocity_actual_value",
                   "position_actual_value", "target_velocity", "homing_method"):
        if needed not in d.objects:
            r.warnings.append(f"no register for the object {needed}")
    profile = fam.profile(Bus(SerialLine("/dev/null", LineSettings())).slave(
        max(min(fam.profile.addresses), 1)))
    r.lines.append("  procedures (engine's, or the description's own where it gives one):")
    for name in _PROCEDURES:
        try:
            profile.check_supported(name)
        except NotSupported as exc:
            r.lines.append(f"    {name:<22} cannot: {str(exc).split(': ', 1)[-1]}")
        else:
            own = " (the description's)" if name in d.procedures else ""
            r.lines.append(f"    {name:<22} yes{own}")
    if d.homing is not None:
        r.lines.append("  homing methods: " + ", ".join(
            f"{n} (CiA 402 {m.cia402 if m.cia402 is not None else m.code})"
            for n, m in d.homing.methods.items()))


def doc_page(fam: DriveFamily) -> str:
    """The family's reference page (markdown), as the docs site shows the built-ins."""
    if fam.spec is None:
        return f"# {fam.name}\n\n{fam.name} is a profile written as code; see the docs site."
    return f"# {fam.name}\n\n" + family_page(fam) + "\n"
