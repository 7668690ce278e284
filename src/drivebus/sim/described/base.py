"""The described twin's state: its description's map (stored words, coils, factory
values), the address and line settings it takes, its units and its position counter.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping
from typing import Any, ClassVar

from drivebus.drives.base import describe_values
from drivebus.drives.description import Description, Reg, Trigger
from drivebus.drives.values import RegValue
from drivebus.errors import ConfigError
from drivebus.settings import LineSettings
from drivebus.sim.described.state import _Homing, _RefHoming, _TableRun, _Word
from drivebus.sim.drive import HomeCam, SimDrive, TwinSetup, time_or_present
from drivebus.sim.registers import RegisterSpec, SlaveException, signed32

_SERIAL_TCP = LineSettings.parse("115200 8N1")
"""The line settings a Modbus TCP drive's twin takes on a serial sim wire by default."""


class TwinBase(SimDrive):
    """The state of a described twin: the description and its map, the stored words,
    the line settings and address it takes, its units and position counter. The rooms
    (``switches``, ``registers``, ``triggers``, ``motion``, ``homing``, ``reference``,
    ``tables``, ``io``, ``power``) add what it does; ``DescribedDrive`` is them all."""

    description: ClassVar[Description]
    _words: ClassVar[dict[int, _Word]]
    _pairs: ClassVar[dict[int, tuple[Reg, int | None]]]
    _input_specs: ClassVar[dict[int, RegisterSpec]]
    _input_words: ClassVar[dict[int, _Word]]
    _bits: ClassVar[dict[tuple[int, int], _Word]]
    """Coils (space 2) and discrete inputs (space 3) by (space, address)."""
    _triggers: ClassVar[dict[str, tuple[Trigger, ...]]]
    _map_end: ClassVar[int]

    def __init__(
        self,
        address: int,
        settings: LineSettings | None = None,
        setup: TwinSetup | None = None,
        *,
        home_switch_width: float | None = None,
        home_cam: HomeCam | None = None,
        crc_error_reply: bool = True,
        soft_address: bool = False,
        hard_stop_negative: float | None = None,
        hard_stop_positive: float | None = None,
        **constants: int,
    ) -> None:
        d = self.description
        if settings is None and d.link.protocol == "rtu":
            settings = _factory_settings(d)
        elif settings is None:
            settings = _SERIAL_TCP  # a TCP drive served on a serial sim wire
        if settings is not None and d.link.protocol == "rtu":
            self._check_line(settings)
        self._check_address(address, soft_address=soft_address)
        super().__init__(address, settings, setup)
        self.set_home_shape(home_cam, home_switch_width)
        self.crc_error_reply = crc_error_reply
        self.hard_stop_negative = hard_stop_negative
        self.hard_stop_positive = hard_stop_positive
        """Mechanical end stops (physical positions) a hard_stop homing creeps into."""
        self.stalled = False
        """The motor stalls on an end stop (a hard_stop homing's torque reached)."""
        if soft_address and d.link.address_register is None:
            raise ConfigError(f"the simulated {d.family} has no soft_address: its description "
                              "names no [link] address_register")
        self.soft_address = soft_address
        """The address is the address register's saved value, taken at power-up."""
        self.coils: dict[int, int] = {}
        """Coil states by address (their own address space)."""
        self.factory = self._factory_words()
        for key, value in constants.items():
            reg = d.regs.get(key)
            if reg is None or (reg.d.means != "constant" and key not in d.twin.options):
                raise ConfigError(f"the simulated {d.family} has no option {key!r} (options: "
                                  f"{', '.join(self.twin_options())})")
            self._store(self.factory, reg, None, int(value))
        self.regs: dict[int, int] = dict(self.factory)
        if soft_address:
            assert d.link.address_register is not None
            self._store(self.regs, d.regs[d.link.address_register], None, address)
        self._baud_by_register = False
        self._apply_baud_register(initial=True)
        self._apply_format_register(initial=True)
        self._external = 0
        """Input terminals driven from outside (``set_input``), by bit."""
        self._wire_switches()
        self.eeprom: dict[int, int] = dict(self.regs)
        """Register words that survive a power cycle."""
        self.eeprom_writes = 0
        self.motion: str | None = None
        """The kind of motion last started (a ``motion``-meaning register shows it)."""
        self.homed = False
        self._homing: _Homing | None = None
        self._watch_from = 0.0
        self._motion_decel: float | None = None
        self._run_rates = (math.inf, math.inf)
        self._shift = 0.0
        self.reached = True
        """A position move or homing ran to its end (``reached`` meaning)."""
        self._completes = False
        self._last_dir = 0
        self._ref: _RefHoming | None = None
        self._processed_until = 0.0
        self._last_event = -math.inf
        self._previous: RegValue | None = None
        """While a write's triggers run: what the register held before it."""
        self.stopping: str | None = None
        """What stops the motion under way: stop, emergency_stop or limit (None: none)."""
        self._table: _TableRun | None = None
        self._ends: tuple[Trigger, Any] | None = None
        """The trigger whose ``ends`` registers are set once its motion is over."""
        self._functions_seen = self._input_functions(0.0)
        self.enabled = bool(self._eval(d.twin.enabled, 0.0))

    @property
    def params(self) -> dict[int, int]:
        """The stored register words by address (the drive's parameters)."""
        return self.regs

    @classmethod
    def sees(cls, switch: str) -> bool:
        """Whether the drive can see ``switch`` (home_switch, limit_positive,
        limit_negative) at all. A twin with ``[twin] wiring`` or ``direct`` sees the
        switches wired to its terminals and those it sees directly; one without sees every
        switch where it has no ``[inputs]``, else those on an input bit of that name or a
        terminal whose function code it has. One it cannot see, the twin runs through,
        as the drive would."""
        d = cls.description
        twin, io = d.twin, d.inputs
        if twin.wiring or twin.direct:
            return switch in twin.direct or switch in twin.wiring
        return io is None or switch in io.bits or (
            io.functions is not None and switch in io.codes)

    @classmethod
    def twin_options(cls) -> list[str]:
        """The keyword options this twin takes (a machine file's ``sim.options``)."""
        d = cls.description
        consts = [k for k, r in d.regs.items() if r.d.means == "constant"]
        soft = ["soft_address"] if d.link.address_register is not None else []
        stops = ["hard_stop_negative", "hard_stop_positive"] if d.homing is not None and any(
            m.behaviour == "hard_stop" for m in d.homing.methods.values()) else []
        return ["home_switch_width", "home_cam", "crc_error_reply", *soft, *stops, *consts,
                *d.twin.options]

    def _check_address(self, address: int, *, soft_address: bool) -> None:
        """An address the drive can have: ``[link] addresses`` (or, with
        ``soft_address``, ``register_addresses`` too); ``ConfigError`` else."""
        link = self.description.link
        sets: list[Collection[int]] = [link.address_set]
        if soft_address and link.register_addresses is not None:
            lo, hi = link.register_addresses
            sets.append(range(lo, hi + 1))
        if not any(address in s for s in sets):
            shown = " or ".join(describe_values(s) for s in sets)
            raise ConfigError(f"{self.description.family} address {address}: it has "
                              f"addresses {shown}")

    def _check_line(self, settings: LineSettings) -> None:
        d = self.description
        link = d.link
        bauds = ", ".join(map(str, link.baud_rates))
        if link.baud_rates and settings.baudrate not in link.baud_rates:
            raise ConfigError(f"{d.family} baud rate {settings.baudrate}: it runs at {bauds} "
                              "baud")
        if link.formats and settings.format not in link.formats:
            raise ConfigError(f"{d.family} line format {settings.format}: it runs "
                              f"{', '.join(link.formats)} only")
        for rule in link.format_rules:
            if settings.baudrate in rule.baud_rates and settings.format not in rule.formats:
                why = f" ({rule.why})" if rule.why else ""
                raise ConfigError(f"the {d.family} runs {'/'.join(rule.formats)} at "
                                  f"{settings.baudrate} baud{why}")

    def _factory_words(self) -> dict[int, int]:
        words: dict[int, int] = {}
        for reg in self.description.regs.values():
            if reg.space == 1 or reg.space == 3:
                continue  # input registers, discrete inputs: computed or fixed
            if reg.space == 2:  # coils: their own space, kept apart
                self.coils.update({reg.at(i).address: reg.default_at(i) & 1
                                   for i in (reg.indices if reg.array else [None])})
                continue
            for index in (reg.indices if reg.array else [None]):
                self._store(words, reg, index, reg.default_at(index))
        return words

    @staticmethod
    def _store(words: dict[int, int], reg: Reg, index: int | None, value: int) -> None:
        r = reg.at(index)
        if r.words == 1:
            words[r.address] = value & 0xFFFF
            return
        u = value & 0xFFFFFFFF
        hi, lo = u >> 16, u & 0xFFFF
        low_addr = r.low_address if r.low_address is not None else r.address + 1
        if r.low_address is None and r.order.value == "low_first":
            words[r.address], words[low_addr] = lo, hi
        else:
            words[r.address], words[low_addr] = hi, lo

    def _raw(self, reg: Reg, index: int | None, words: Mapping[int, int] | None = None) -> int:
        if reg.d.input or reg.d.discrete:
            return reg.default_at(index)
        r = reg.at(index)
        if reg.d.coil:
            return (self.coils if words is None else words).get(r.address, 0)
        w = self.regs if words is None else words
        if r.words == 1:
            return r.decode([w[r.address]])
        low = r.low_address if r.low_address is not None else r.address + 1
        return r.decode([w[r.address], w[low]])

    def register(self, address: int) -> RegisterSpec:
        """An address past the last documented one is ``refusals.outside`` where given."""
        outside = self.description.link.refusals.outside
        if outside is not None and address > self._map_end:
            raise SlaveException(outside)
        return super().register(address)

    def check_word(self, address: int, word: int) -> int:
        """Access and range, then the register's ``valid`` condition."""
        value = super().check_word(address, word)
        w = self._words.get(address)
        valid = None if w is None or w.reg.register.words != 1 else w.reg.d.valid
        if valid is not None and w is not None and \
                not self._eval(valid, 0.0, RegValue(value, w.reg)):
            raise SlaveException(self.exception_codes.value)
        return value

    @property
    def pulses_per_rev(self) -> int:
        """The pulses per revolution (the description's register, or its default)."""
        p = self.description.units.pulses_per_rev
        if p.reg is None:
            return p.default
        reg = self.description.regs[p.reg]
        v = reg.codec.to_physical(self._raw(reg, None), ppr=1)
        return int(v) if v else p.default

    def _pps(self, rpm: float) -> float:
        """Pulses/s of a speed in rpm, capped at ``[twin] max_pulse_rate``."""
        v = rpm * self.pulses_per_rev / 60.0
        cap = self.description.twin.max_pulse_rate
        return v if cap is None else math.copysign(min(abs(v), cap), v)

    def position(self, now: float | None = None) -> int:
        """The drive's 32-bit position counter (it wraps at ±2^31), events up to ``now``
        processed."""
        t = time_or_present(now)
        self.advance(t)
        return signed32(super().position(t))

    def physical_position(self, now: float | None = None) -> float:
        """Where the axis physically is (the frame of the switch positions), events up to
        ``now`` processed."""
        t = time_or_present(now)
        self.advance(t)
        return self._phys(t)

    def _phys(self, t: float) -> float:
        """The physical position at ``t`` as planned (no events processed)."""
        return self.kin.position(t) - self._shift

    def is_moving(self, now: float | None = None) -> bool:
        """True while the motor turns or a homing or table runs (events up to ``now``
        processed)."""
        t = time_or_present(now)
        self.advance(t)
        return self._running(t)

    def _set_counter(self, t: float, value: float) -> None:
        old = self.kin.position(t)
        self.kin.set_position(t, value)
        self._shift += value - old

    def _wrap(self, now: float) -> float:
        p = self.kin.position(now)
        wrapped = signed32(round(p))
        if wrapped != round(p):
            self._set_counter(now, p + (wrapped - round(p)))
        return self.kin.position(now)


def _factory_settings(d: Description) -> LineSettings:
    """A twin's line settings when none are given: ``[link] factory``, else the Modbus
    default (19200 8E1) where the drive runs it, else its fastest rate in its first
    format (the manual states no default: the switches all off, for the NT86)."""
    if d.link.factory:
        return LineSettings.parse(d.link.factory)
    default = LineSettings()
    bauds, formats = d.link.baud_rates, d.link.formats
    if (not bauds or default.baudrate in bauds) and (not formats or default.format in formats):
        return default
    return LineSettings.parse(formats[0] if formats else default.format,
                              baudrate=max(bauds) if bauds else default.baudrate)


def _formats_at(d: Description, baud: int) -> list[str]:
    for rule in d.link.format_rules:
        if baud in rule.baud_rates:
            return list(rule.formats)
    return list(d.link.formats)


def _finite_pos(v: Any) -> bool:
    return isinstance(v, int | float) and math.isfinite(v) and v > 0


def _usable(speed: Any, accel: Any, decel: Any) -> bool:
    return _finite_pos(abs(speed) if isinstance(speed, int | float) else speed) and \
        _finite_pos(accel) and _finite_pos(decel)


def _rate(decel: Any, ppr: int) -> float | None:
    """A deceleration in r/s² as pulses/s² (None: at once)."""
    if decel is None or not isinstance(decel, int | float) or not math.isfinite(decel) or \
            decel <= 0:
        return None
    return float(decel) * ppr
