"""``Description``: a whole description file, its sections together, with the views the
engines and twins use (every register as a ``Reg``, the CiA 402 objects, how each
status field decodes, the parameters a backup holds) and where each item comes from.
"""

from __future__ import annotations

from functools import cached_property
from typing import Annotated, Literal

from pydantic import Field

from drivebus.drives.description.examples import ExampleDef
from drivebus.drives.description.fields import _KEY, SOURCE_KINDS, _Model, source_kind
from drivebus.drives.description.homing import HomingDef
from drivebus.drives.description.link import DriveInfo, Identify, Link
from drivebus.drives.description.objects import Cia402Def, _object_kind, object_name
from drivebus.drives.description.options import (
    EepromDef,
    OptionCheck,
    OptionDef,
    ProgramsDef,
    Units,
)
from drivebus.drives.description.procedures import PROCEDURES, Procedure
from drivebus.drives.description.registers import Reg, RegisterDef
from drivebus.drives.description.status import AlarmsDef, IoDef, SignalDef, StatusDef
from drivebus.drives.description.twin import TwinDef
from drivebus.drives.expr import Expr, ExprError
from drivebus.drives.registers import WordOrder
from drivebus.drives.units import UnitCodec


class Description(_Model):
    """A whole description file."""

    format: Literal[1] = 1
    drive: DriveInfo
    identify: Identify | None = None
    link: Link = Link()
    registers: dict[Annotated[str, Field(pattern=_KEY)], RegisterDef] = {}
    constants: dict[Annotated[str, Field(pattern=_KEY)], int] = {}
    state: dict[Annotated[str, Field(pattern=_KEY)], int | float | bool | str | None] = {}
    options: dict[Annotated[str, Field(pattern=_KEY)], OptionDef] = {}
    option_checks: list[OptionCheck] = []
    units: Units
    status: StatusDef = StatusDef()
    inputs: IoDef | None = None
    outputs: IoDef | None = None
    alarms: AlarmsDef | None = None
    homing: HomingDef | None = None
    signals: dict[Annotated[str, Field(pattern=_KEY)], SignalDef] = {}
    eeprom: EepromDef = EepromDef()
    programs: ProgramsDef = ProgramsDef()
    cia402: Cia402Def | None = None
    procedures: dict[Annotated[str, Field(pattern=_KEY)], Procedure] = {}
    twin: TwinDef = TwinDef()
    examples: list[ExampleDef] = []

    def sourced_items(self) -> list[tuple[str, str | None]]:
        """Every register, bit, procedure and homing method, and the sections
        ``[identify]``, ``[link]``, ``[status]`` and ``[alarms]`` (those it has), with the
        source that stands for it: its own ``source``, else the register's (for its
        bits), else ``[drive] source`` (None: none)."""
        default = self.drive.source
        items: list[tuple[str, str | None]] = []
        for key, r in self.registers.items():
            items.append((f"registers.{key}", r.source or default))
            items += [(f"registers.{key}.bits.{bit}", b.source or r.source or default)
                      for bit, b in r.bits.items()]
        items += [(f"procedures.{n}", p.source or default) for n, p in self.procedures.items()]
        items += [(f"homing.methods.{n}", m.source or default)
                  for n, m in (self.homing.methods.items() if self.homing else ())]
        items += [(f"[{n}]", s or default) for n, s in self.section_sources().items()]
        return items

    def provenance(self) -> dict[str, list[str]]:
        """Where each of ``sourced_items`` comes from, by kind (``manual``, ``code``,
        ``inferred``, ``unnamed``)."""
        out: dict[str, list[str]] = {k: [] for k in (*SOURCE_KINDS, "unnamed")}
        for name, source in self.sourced_items():
            out[source_kind(source)].append(name)
        return out

    def partly_inferred(self) -> list[str]:
        """The items whose source is the manual or code but says part of it is inferred
        (``"manual: 3602h:02 ...; the low byte is inferred"``): counted as the manual's,
        named apart so a reader checks that part on the drive."""
        return [name for name, source in self.sourced_items()
                if source and source_kind(source) in ("manual", "code")
                and "inferred" in source.lower()]

    def section_sources(self) -> dict[str, str | None]:
        """The own ``source`` of each of the sections ``identify``, ``link``, ``status``
        and ``alarms`` the description has (None: it has none of its own)."""
        sections = {"identify": self.identify, "link": self.link, "status": self.status,
                    "alarms": self.alarms}
        return {k: s.source for k, s in sections.items() if s is not None}

    # -- compiled views ---------------------------------------------------------------------

    @cached_property
    def regs(self) -> dict[str, Reg]:
        """Every register, by key (with those a CiA 402 address rule places)."""
        out = {}
        placed = {k: self._pdu_addresses(self._width(d)) for k, d in self.registers.items()}
        for key, d in {**placed, **self._generated()}.items():
            codec = UnitCodec.make(d.unit, d.scale, d.ramp, d.table, d.values)
            order = WordOrder(d.order) if d.order else self.link.order
            out[key] = Reg(key, d, codec, order, objects=self.link.map == "objects")
        return out

    @cached_property
    def pulses_per_rev_allowed(self) -> range | tuple[int, ...]:
        """The pulses per revolution the drive can be set to: ``[units.pulses_per_rev]``'s
        list or range, else what its register takes through its scale or table."""
        p = self.units.pulses_per_rev
        if p.allowed:
            return tuple(sorted(p.allowed))
        if p.range is not None:
            return range(p.range[0], p.range[1] + 1)
        if p.reg is not None and p.reg in self.regs:
            reg = self.regs[p.reg]
            if reg.codec.table:
                return tuple(sorted(reg.codec.table))
            return scaled_range(max(reg.register.lo, 1), reg.register.hi, reg.codec.scale)
        return range(1, 1 << 31)

    def register_base(self, d: RegisterDef) -> int:
        """What ``d``'s numbers count from (``link.register_base``; under 4xxxx numbering,
        input registers 3xxxx, coils 0xxxx, discrete inputs 1xxxx)."""
        base = self.link.register_base
        if base != 40001:
            return base
        return 30001 if d.input else 1 if d.coil else 10001 if d.discrete else base

    def _width(self, d: RegisterDef) -> RegisterDef:
        """``d`` with its width: its own ``words``, else ``[link] words`` (a coil or a
        discrete input: one bit)."""
        if d.words is not None:
            return d
        return d.model_copy(update={"words": 1 if d.coil or d.discrete else self.link.words})

    def _pdu_addresses(self, d: RegisterDef) -> RegisterDef:
        """``d`` with PDU addresses (its numbers less the register base; a number below
        the base stays as it is and the checks name it)."""
        base = self.register_base(d)
        if not base or d.address < base or (d.low_address is not None and
                                            d.low_address < base):
            return d
        low = None if d.low_address is None else d.low_address - base
        return d.model_copy(update={"address": d.address - base, "low_address": low})

    @cached_property
    def objects(self) -> dict[str, Reg]:
        """The registers of the CiA 402 objects, by object name."""
        out: dict[str, Reg] = {}
        for reg in self.regs.values():
            if reg.d.object is not None:
                name = object_name(reg.d.object)
                if name is not None:
                    out[name] = reg
        return out

    def _generated(self) -> dict[str, RegisterDef]:
        """Registers for the objects ``[cia402]`` places by its address rule."""
        from drivebus.drives.cia402 import OBJECTS

        c = self.cia402
        if c is None or c.address_rule is None:
            return {}
        taken = {object_name(d.object) for d in self.registers.values() if d.object}
        out: dict[str, RegisterDef] = {}
        for ref in c.objects:
            name = object_name(ref)
            if name is None or name in taken or name in self.registers:
                continue
            info = OBJECTS[name]
            try:
                address = int(c.address_rule({"index": info.index, "sub": info.subindex}))
            except (ExprError, TypeError, ValueError):
                continue  # reported by the checks
            kind = _object_kind(name)
            unit = getattr(c, kind) if kind else None
            out[name] = RegisterDef(
                address=address, words=2 if info.bits > 16 or c.words == 2 else 1,
                signed=info.signed,
                access="RW" if info.writable else "R", object=name,
                unit=unit.unit if unit else "", scale=unit.scale if unit else 1.0,
                name=info.text)
        return out

    @property
    def family(self) -> str:
        """The family name."""
        return self.drive.family

    @cached_property
    def status_exprs(self) -> dict[str, Expr]:
        """How each ``DriveStatus`` field decodes: ``[status]``'s expression, else one made
        from what the polled registers and bits *mean* (``means``), else ``enabled`` is
        taken as true (a drive that does not report it) and the others are absent."""
        s = self.status
        out: dict[str, Expr] = {}
        bits: dict[str, list[str]] = {}
        regs: dict[str, list[str]] = {}
        for reg in self.regs.values():
            if reg.d.access == "W" or reg.array:
                continue
            if reg.d.means and (reg.d.coil or reg.d.discrete):
                bits.setdefault(reg.d.means, []).append(reg.key)  # a one-bit state
            elif reg.d.means:
                regs.setdefault(reg.d.means, []).append(reg.key)
            for name, b in reg.d.bits.items():
                if b.means:
                    bits.setdefault(b.means, []).append(f"{reg.key}.{name}")

        def any_of(pos: str, neg: str | None = None) -> str | None:
            terms = list(bits.get(pos, []))
            if neg is not None:
                terms += [f"not {t}" for t in bits.get(neg, [])]
            return " or ".join(terms) or None

        derived: dict[str, str | None] = {
            "enabled": any_of("enabled", "disabled"),
            "moving": any_of("moving", "at_rest") or any_of("jogging"),
            "homed": any_of("homed"),
            "homing": any_of("homing"),
            "homing_error": any_of("homing_error"),
            "alarm": " or ".join(filter(None, [any_of("alarm", "no_alarm")] + [
                f"{k} != 0" for k in regs.get("alarm_code", [])])) or None,
            "alarm_code": (regs.get("alarm_code") or [None])[0],
            "position": (regs.get("position") or [None])[0],
            "velocity": (regs.get("velocity") or [None])[0],
        }
        for side in ("limit_positive", "limit_negative"):
            io = self.inputs
            if io is not None and (side in io.codes or side in io.bits):
                derived[side] = f"input.{side}"
            else:
                derived[side] = any_of(side)
        moving = s.moving.source if s.moving is not None else derived["moving"]
        alarm = s.alarm.source if s.alarm is not None else derived["alarm"]
        reached = any_of("in_position")
        if reached and moving:
            derived["in_position"] = f"({reached}) and not ({moving})"
        elif reached:
            derived["in_position"] = reached
        elif moving:
            derived["in_position"] = f"not ({moving})" + (f" and not ({alarm})" if alarm else "")
        else:
            derived["in_position"] = None
        for field, text in derived.items():
            given = getattr(s, field)
            if given is not None:
                out[field] = given
            elif text is not None:
                out[field] = Expr.parse(text)
        out.setdefault("enabled", Expr.parse(True))
        return out

    def parameter_regs(self) -> list[tuple[str, Reg, int | None]]:
        """The documented settings (key, register, table index) ``drivebus params`` backs
        up, in address order: each register's ``parameter`` flag or key, else every
        read/write register that is not volatile, shows no state and is not the EEPROM
        write-through switch."""
        wt = self.eeprom.write_through
        out = []
        for key, reg in self.regs.items():
            d = reg.d
            wanted = d.parameter if d.parameter is not None else (
                d.access == "RW" and not d.volatile and d.means is None
                and (wt is None or wt.reg != key))
            if wanted is False:
                continue
            for i in reg.indices if reg.array else [None]:
                out.append((self._parameter_key(key, reg, i), reg, i))
        return sorted(out, key=lambda kri: kri[1].at(kri[2]).address)

    @staticmethod
    def _parameter_key(key: str, reg: Reg, index: int | None) -> str:
        given = reg.d.parameter if isinstance(reg.d.parameter, str) else None
        if index is None:
            return given or key
        name = reg.d.names[index - reg.d.first] if reg.d.names else str(index)
        if given is None:
            return f"{key}_{index}"
        return given.format(i=index, name=_KeyName(name))

    def procedure_what(self, name: str) -> str:
        """How a NotSupported error says procedure ``name``."""
        if name in PROCEDURES:
            return PROCEDURES[name][0]
        proc = self.procedures.get(name)
        if proc is not None and proc.what is not None and not proc.what.names:
            return str(proc.what)
        return name.replace("_", " ")


class _KeyName(str):
    """A table entry's name in a parameter key: ``{name}``, ``{name:lower}``, ``{name:upper}``."""

    __slots__ = ()

    def __format__(self, spec: str) -> str:
        if spec == "lower":
            return self.lower()
        if spec == "upper":
            return self.upper()
        return format(str(self), spec)


def scaled_range(lo: int, hi: int, scale: float) -> range | tuple[int, ...]:
    """The whole values ``raw × scale`` for raw in ``lo..hi``: what a register of that
    range and scale can be set to, in the user's units (pulses/rev through EG/2)."""
    if scale == 1.0:
        return range(lo, hi + 1)
    if scale == int(scale):
        s = int(scale)
        return range(lo * s, hi * s + 1, s)
    inverse = 1.0 / scale
    if abs(inverse - round(inverse)) < 1e-9:
        n = round(inverse)
        return range(-(-lo // n), hi // n + 1)
    return tuple(sorted({round(raw * scale) for raw in range(lo, hi + 1)
                         if abs(raw * scale - round(raw * scale)) < 1e-9}))
