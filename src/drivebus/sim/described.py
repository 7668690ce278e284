"""A simulated twin built from a drive description: any described drive on ``sim://``.

The twin answers only the addresses the description documents (exception 02 elsewhere,
or its ``refusals``), refuses writes to read-only registers and values outside their
ranges with the codes the description gives, reads only with the function codes its
link lists, and acts on the writes its ``[twin]`` section describes (``on_write``
triggers: moves, speed runs, stops, homing, enable, alarm clear, zeroing, save, factory
reset) with the simulator's kinematics. Status registers and bits are computed from what
they *mean* (``means``: enabled, moving, in position, homed, alarm, position, velocity,
inputs, ...); inputs carry the home and limit switches as the description's ``[inputs]``
wiring says. Limit switches stop motion and block starts towards them; an alarm stops
the motor at once; a power cycle reloads registers from the twin's EEPROM (what a save
or a write-through stored) and the defaults of volatile registers, applies a changed
line format, starts the position counter at 0 and forgets the homed state.

Homing follows the CiA 402 method each of the description's methods names (``cia402``):
17/18 (limit switches), 19-30 (home switch, with a dog of ``home_switch_width`` or a
cam), 33-37 (the present position); the position at the origin edge becomes the offset.
The home cam covers the side the method in use searches towards (``home_cam`` names the
side instead). A limit switch the method does not reverse on stops the motor as the
description's ``[twin] limits`` say, and the homing fails (``homing_failed``).

With ``soft_address`` (where ``[link] address_register`` names the register), the twin's
address is that register's saved value from the next power-up on, as ``drivebus
commission`` sets it.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Collection, Iterator, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

from drivebus.clock import monotonic
from drivebus.drives.base import describe_values
from drivebus.drives.cia402 import (
    OBJECTS,
    HomeSignal,
    HomeSwitch,
    HomingMethod,
    State,
    homing_method,
)
from drivebus.drives.description import TWIN_MEANINGS, Description, Reg, Trigger, object_name
from drivebus.drives.description import HomingMethod as MethodDef
from drivebus.drives.expr import Expr, ExprError, Unknown
from drivebus.drives.registers import Access
from drivebus.drives.units import Kind
from drivebus.drives.values import Attrs, RegValue, Table, reg_value
from drivebus.errors import ArgumentError, ConfigError
from drivebus.pdu import READ_COILS, READ_DISCRETE, READ_HOLDING, READ_INPUT, WRITE_COIL
from drivebus.settings import LineSettings
from drivebus.sim.cia402_device import Cia402Device, Cia402Setup
from drivebus.sim.drive import HomeCam, SimDrive, Span, TwinSetup, time_or_present
from drivebus.sim.registers import ExceptionCodes, RegisterSpec, SlaveException, signed32

__all__ = ["DescribedCia402Drive", "DescribedDrive", "described_twin", "twin_of"]

_COMPUTED = {"position", "velocity", "command_velocity", "alarm_code", "motion", "inputs",
             "outputs"}
_STARTS = {"move_absolute", "move_relative", "run", "home", "run_table"}
_VALUES = _COMPUTED | {"constant", "address", "direction"}
"""Meanings that are a register's value (the others are a state: 1 or 0)."""
_SERIAL_TCP = LineSettings.parse("115200 8N1")
"""The line settings a Modbus TCP drive's twin takes on a serial sim wire by default."""


@dataclass(frozen=True)
class _Word:
    """Where an address sits: its register, table entry and which word of the value."""

    reg: Reg
    index: int | None
    word: int


@dataclass(frozen=True)
class _Phase:
    """One leg of a homing: run in ``direction`` (fast or creep) until one of the edges,
    then go on with the named leg ("done": the origin)."""

    direction: int
    fast: bool
    events: tuple[tuple[str, str], ...]


@dataclass
class _RefHoming:
    """A ``reference_edge`` homing under way: its phase, direction, speeds (pulses/s), rate
    (pulses/s²) and offset (pulses)."""

    reference: str
    phase: str
    direction: float
    speed: float
    creep: float
    rate: float
    offset: float
    reversed: bool = False
    final: float | None = None
    """The counter's value where the offset travel ends (None: as it is)."""
    stop: float | None = None
    """hard_stop: the end stop's position (counter frame; None: none ahead)."""
    until: float = math.inf
    """hard_stop: when the stall on the end stop makes it the origin."""
    may_reverse: bool = True
    """A limit switch met ahead in the search reverses it (``[twin.homing]``)."""
    offset_mode: str = "origin"
    """What the offset does: origin, move or travel (chosen as the homing starts)."""


_Handler = Callable[[float], None]


@dataclass
class _TableRun:
    """A ``run_table`` under way: the trigger and value that started it, the rows, the row
    running (0-based) and whether it moves or waits."""

    trig: Trigger
    value: Any
    rows: int
    repeat: bool
    row: int = 0
    phase: str = "move"
    until: float = math.inf


@dataclass
class _Homing:
    phases: dict[str, _Phase]
    phase: str
    t_dir: float
    speed: float
    creep: float
    rate: float
    offset: float


def _search_phases(method: int, home: bool, neg: bool, pos: bool
                   ) -> tuple[dict[str, _Phase], str] | None:
    """The legs of CiA 402 homing method ``method`` (``drivebus.drives.cia402``) and the
    first leg, given the switch states (home, negative limit, positive limit) at the start.

    The origin is the method's edge crossed in its final direction at the creep speed: a
    limit switch's edge (where it becomes inactive), or the home switch's lower or upper
    edge. The search runs at the fast speed in the method's initial direction (for a home
    switch that is a cam, where the switch's state says), reverses at the method's
    reversal limit switch, and backs off the edge to cross it again at the creep speed.
    Index pulses are not modelled (methods 1-14 home as 17-30).
    """
    try:
        m = homing_method(method)
    except ArgumentError:
        return None
    if m.signal is HomeSignal.NEGATIVE_LIMIT:
        legs = {"fast": _Phase(-1, True, (("limit_negative", "creep"),)),
                "creep": _Phase(+1, False, (("limit_negative", "done"),))}
        return legs, "creep" if neg else "fast"
    if m.signal is HomeSignal.POSITIVE_LIMIT:
        legs = {"fast": _Phase(+1, True, (("limit_positive", "creep"),)),
                "creep": _Phase(-1, False, (("limit_positive", "done"),))}
        return legs, "creep" if pos else "fast"
    if m.signal is not HomeSignal.HOME_SWITCH:
        return None
    edge = "home_high" if m.home_switch in (HomeSwitch.UPPER_EDGE, HomeSwitch.NEGATIVE) \
        else "home_low"
    f = m.final_direction
    # Crossing the edge moving f enters the switch (lower edge moving up, upper moving down)
    # or leaves it; entering needs a back-off to cross it again at the creep speed.
    entering = (edge == "home_low") == (f > 0)
    final = _Phase(f, False, ((edge, "done"),))
    legs: dict[str, _Phase] = {"final": final}
    if entering:
        legs["back"] = _Phase(-f, False, ((edge, "final"),))
        on_switch = "back"
    else:
        on_switch = "final"
    initial = m.initial_direction
    if m.home_switch in (HomeSwitch.POSITIVE, HomeSwitch.NEGATIVE):  # a cam on one side
        side = 1 if m.home_switch is HomeSwitch.POSITIVE else -1
        if not home:
            legs["fast"] = _Phase(side, True, ((edge, on_switch),))
            return legs, "fast"
        if f == -side:
            return legs, "final"  # leave the cam at the creep speed
        legs["off"] = _Phase(-side, True, ((edge, "final"),))
        return legs, "off"
    first_edge = "home_low" if initial > 0 else "home_high"
    other_edge = "home_high" if initial > 0 else "home_low"
    ahead = "limit_positive" if initial > 0 else "limit_negative"
    legs["fast"] = _Phase(initial, True, ((first_edge, on_switch), (ahead, "reverse")))
    legs["reverse"] = _Phase(-initial, True, ((other_edge, on_switch),))
    return legs, on_switch if home else "fast"


class DescribedDrive(SimDrive):
    """A simulated drive that plays a drive description."""

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

    # -- the description's map ---------------------------------------------------------------

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

    # -- units ----------------------------------------------------------------------------

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

    # -- the position counter ----------------------------------------------------------------

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

    # -- switches ----------------------------------------------------------------------------

    def switch_states(self, now: float) -> tuple[bool, bool, bool]:
        """(home, limit negative, limit positive) at the physical position (with
        ``[twin] wiring``: as the drive sees them through its input functions)."""
        p = self._phys(now)
        if self.description.twin.wiring:
            return (self._signal_at("home_switch", p), self._signal_at("limit_negative", p),
                    self._signal_at("limit_positive", p))
        return self.switches_at(p)

    # -- wired input terminals (``[twin] wiring``) ------------------------------------------

    def _terminal(self, signal: str) -> int | None:
        """The bit of the terminal switch ``signal`` is wired to (None: not wired)."""
        d = self.description
        t = d.twin.wiring.get(signal)  # type: ignore[call-overload]
        if t is None:
            return None
        if isinstance(t, str):
            assert d.inputs is not None
            return d.inputs.names.index(t)
        return int(t)

    def _wire_switches(self) -> None:
        """Each switch the setup gives is wired to its terminal, whose function register
        is set to the switch's code (as the machine's builder configured it)."""
        d = self.description
        io = d.inputs
        if not d.twin.wiring or io is None or io.functions is None:
            return
        reg = d.regs[io.functions]
        given = {"home_switch": self.home_switch, "limit_positive": self.limit_positive,
                 "limit_negative": self.limit_negative}
        for signal in d.twin.wiring:
            bit = self._terminal(signal)
            if bit is None or signal not in io.codes:
                continue
            index = reg.indices[bit]
            self._store(self.regs, reg, index, io.codes[signal] if given[signal] is not None
                        else self._raw(reg, index))

    def _terminals(self) -> range:
        io = self.description.inputs
        return range(len(io.names) if io is not None and io.names else 16)

    def _switch_span(self, index: int) -> Span | None:
        for signal in self.description.twin.wiring:
            if self._terminal(signal) == index:
                if signal == "home_switch":
                    return self.home_span()
                return self.limit_span(1 if signal == "limit_positive" else -1)
        return None

    def _physical(self, index: int, p: float) -> bool:
        if self._external >> index & 1:
            return True
        span = self._switch_span(index)
        return span is not None and span.active(p)

    def _inverted(self, index: int, *, by_function: bool = True) -> bool:
        """Terminal ``index`` is inverted by the ``[inputs] polarity`` register, or (with
        ``by_function``) by the polarity bit of its function entry."""
        d = self.description
        io = d.inputs
        if io is None:
            return False
        inverted = io.polarity is not None and bool(
            self._raw(d.regs[io.polarity], None) >> index & 1)
        if by_function and io.polarity_bit is not None and io.functions is not None:
            reg = d.regs[io.functions]
            if index < len(reg.indices):
                inverted ^= bool(self._raw(reg, reg.indices[index]) & io.polarity_bit)
        return inverted

    def _level(self, index: int, p: float) -> bool:
        """The valid level of terminal ``index`` at physical position ``p`` (after the
        ``[inputs] polarity`` register or polarity bit)."""
        return self._physical(index, p) != self._inverted(index)

    def _carriers(self, signal: str) -> list[int]:
        """The terminals whose function is ``signal`` (or the one it is wired to)."""
        io = self.description.inputs
        if io is None or io.functions is None or signal not in io.codes:
            bit = self._terminal(signal)
            return [] if bit is None else [bit]
        reg = self.description.regs[io.functions]
        code = io.codes[signal]
        mask = io.function_mask
        return [n for n, i in enumerate(reg.indices) if self._raw(reg, i) & mask == code]

    def _direct_span(self, signal: str) -> Span | None:
        """The switch of ``signal`` if the drive sees it directly (``[twin] direct``)."""
        if signal not in self.description.twin.direct:
            return None
        if signal == "home_switch":
            return self.home_span()
        return self.limit_span(1 if signal == "limit_positive" else -1)

    def _signal_at(self, signal: str, p: float) -> bool:
        if signal in self.description.twin.direct:
            span = self._direct_span(signal)
            return span is not None and span.active(p)
        return any(self._level(i, p) for i in self._carriers(signal))

    def _signal_edge(self, signal: str, rising: bool, t0: float, t1: float) -> float | None:
        """First time in [t0, t1] a terminal carrying ``signal`` turns valid (or invalid)."""
        if signal in self.description.twin.direct:
            span = self._direct_span(signal)
            found = [] if span is None else [self._span_edge(span, span.active, rising, t0, t1)]
        else:
            found = [self._terminal_edge(i, rising, t0, t1) for i in self._carriers(signal)]
        times = [t for t in found if t is not None]
        return min(times) if times else None

    def _terminal_edge(self, index: int, rising: bool, t0: float, t1: float) -> float | None:
        span = self._switch_span(index)
        if span is None:
            return None
        return self._span_edge(span, lambda p: self._level(index, p), rising, t0, t1)

    def _span_edge(self, span: Span, level: Callable[[float], bool], rising: bool,
                   t0: float, t1: float) -> float | None:
        """First time in [t0, t1] ``level`` (of the physical position) turns valid (or
        invalid) at an end of ``span``."""
        xs = tuple(x for x in (span.lo, span.hi) if math.isfinite(x))
        found = [self._threshold_edge(level, x + self._shift, rising, t0, t1) for x in xs]
        times = [t for t in found if t is not None]
        return min(times) if times else None

    def _threshold_edge(self, level: Callable[[float], bool], x: float, rising: bool,
                        t0: float, t1: float) -> float | None:
        """First time in [t0, t1] ``level`` turns valid (or invalid) as the motor passes
        ``x`` (counter frame)."""
        t = t0
        while t <= t1:
            tc = self.kin.crossing(x, t, t1)
            if tc is None:
                return self._boundary_edge(level, rising, t, t1)
            # at a start from rest (or a turnaround) the way it leaves counts; resting on
            # the edge crosses nothing
            v = self.kin.velocity(tc) or self.kin.velocity(tc + 1e-6)
            if v == 0.0:
                return None
            step = math.copysign(0.5, v)
            p = x - self._shift
            if level(p - step) != level(p + step) and level(p + step) == rising:
                return tc
            t = tc + 1e-6
        return None

    def _boundary_edge(self, level: Callable[[float], bool], rising: bool, t0: float,
                       t1: float) -> float | None:
        """An edge in [t0, t1] that ``Kinematics.crossing`` missed where one motion segment
        hands over to the next on the switch's end (float rounding): the levels at both
        ends differ, bisection finds the time."""
        def level_at(t: float) -> bool:
            return level(self._phys(t))

        start = level_at(t0)
        if start == level_at(t1) or level_at(t1) != rising:
            return None
        lo, hi = t0, t1
        for _ in range(64):
            mid = 0.5 * (lo + hi)
            if mid in (lo, hi):
                break
            if level_at(mid) == start:
                lo = mid
            else:
                hi = mid
        return hi

    def home_side(self) -> int:
        """The side a home cam covers when ``home_cam`` does not say: the side the homing
        method in the drive's registers searches towards (+1 if none)."""
        try:
            method = self._method_def(self._method_code(monotonic()))
        except ExprError:  # the method depends on a write being made: the default side
            method = None
        if method is not None and method.behaviour == "reference_edge":
            return method.direction or 1
        m = _cia402_method(method)
        if m is None or m.home_switch is HomeSwitch.POSITIVE:
            return 1
        if m.home_switch is HomeSwitch.NEGATIVE:
            return -1
        return m.initial_direction or 1

    def _wired(self, signal: str) -> bool:
        """True if an input carries ``signal`` (home_switch, limit_positive, ...)."""
        io = self.description.inputs
        if io is None or signal in self.description.twin.direct:
            return True
        if signal in io.bits:
            return True
        if io.functions is None or signal not in io.codes:
            return False
        reg = self.description.regs[io.functions]
        code = io.codes[signal]
        return any(self._raw(reg, i) & io.function_mask == code for i in reg.indices)

    def _span(self, edge: str) -> Span | None:
        """Where the switch of ``edge`` is active (physical), if the drive can see it."""
        signal = "home_switch" if edge.startswith("home") else edge
        if not self._wired(signal):
            return None
        if signal == "home_switch":
            return self.home_span()
        return self.limit_span(1 if signal == "limit_positive" else -1)

    def _boundary(self, edge: str) -> float | None:
        """Counter position of a switch edge the drive can see, or None (an edge at
        infinity: a cam's or a limit's outer end)."""
        span = self._span(edge)
        if span is None:
            return None
        pos = span.hi if edge in ("home_high", "limit_negative") else span.lo
        return pos + self._shift if math.isfinite(pos) else None

    def _signals(self, now: float) -> dict[str, bool]:
        home, neg, pos = self.switch_states(now)
        moving = self.kin.moving(now) or self._table is not None
        alarm = bool(self.alarm_code)
        at_speed = moving and self.motion == "speed" and self.kin.cruising(now)
        return {
            "enabled": self.enabled, "disabled": not self.enabled, "moving": moving,
            "at_rest": not moving, "in_position": not moving and not alarm,
            "homed": self.homed, "alarm": alarm,
            "homing": self._homing is not None or self._ref is not None,
            "reached": not moving and (self.reached or self._completes),
            "no_alarm": not alarm, "limit_positive": pos, "limit_negative": neg,
            "home_switch": home, "at_speed": bool(at_speed), "ready": True,
            "jogging": moving and self.motion == "speed",
        }

    # -- reads --------------------------------------------------------------------------------

    def read_registers(self, function: int, address: int, count: int, now: float) -> list[int]:
        """Holding registers (FC03), or the description's input registers (FC04)."""
        if function != READ_INPUT:
            return super().read_registers(function, address, count, now)
        out = []
        for a in range(address, address + count):
            w = self._input_words.get(a)
            if w is None:
                raise SlaveException(self.exception_codes.address)
            raw = self._computed(w.reg, w.index, now) if _computed(w.reg) else \
                w.reg.default_at(w.index)
            words: dict[int, int] = {}
            self._store(words, w.reg, w.index, raw)
            out.append(words[a])
        return out

    def answer(self, pdu: bytes, now: float) -> bytes:
        """Coils (FC01, FC05) and discrete inputs (FC02) where the description has them;
        registers as any twin."""
        function = pdu[0]
        fcs = self.description.link.functions
        if function in (READ_COILS, READ_DISCRETE) and function in fcs:
            address, count = struct.unpack_from(">HH", pdu, 1)
            self.check_count(count)
            space = 2 if function == READ_COILS else 3
            states = [self._bit(space, a, now) for a in range(address, address + count)]
            packed = bytearray((count + 7) // 8)
            for i, on in enumerate(states):
                packed[i // 8] |= on << (i % 8)
            return bytes((function, len(packed))) + bytes(packed)
        if function == WRITE_COIL and function in fcs:
            address, value = struct.unpack_from(">HH", pdu, 1)
            w = self._bits.get((2, address))
            if w is None:
                raise SlaveException(self.exception_codes.address)
            if w.reg.d.access == "R":
                raise SlaveException(self.exception_codes.access)
            if value not in (0x0000, 0xFF00):
                raise SlaveException(self.exception_codes.value)
            before = dict(self.coils)
            self.coils[address] = 1 if value else 0
            self._act(w.reg, w.index, now, before)
            return pdu[:5]
        return super().answer(pdu, now)

    def _bit(self, space: int, address: int, now: float) -> int:
        """A coil's or discrete input's state: what it means now, else stored or fixed."""
        w = self._bits.get((space, address))
        if w is None:
            raise SlaveException(self.exception_codes.address)
        means = w.reg.d.means
        signals = self._signals(now)
        if means in signals:
            return int(signals[means])
        return self._raw(w.reg, w.index) & 1

    def read_register(self, address: int, now: float) -> int:
        """A stored word, or one computed now for registers that show the drive's state."""
        w = self._words[address]
        reg = w.reg
        if not _computed(reg):
            return self.regs[address]
        raw = self._computed(reg, w.index, now)
        words: dict[int, int] = {}
        self._store(words, reg, w.index, raw)
        return words[address]

    def _computed(self, reg: Reg, index: int | None, now: float) -> int:
        """The value of a register that shows the drive's state: from what it means, with
        the bits that have meanings set or cleared by the state."""
        means = reg.d.means
        if means == "position":
            counter = signed32(round(self.kin.position(now)))
            value = _clamp(reg, round(counter / reg.codec.scale))
        elif means in ("velocity", "command_velocity"):
            rpm = self.speed_rpm(now)
            if reg.codec.kind is Kind.SPEED:
                value = _clamp(reg, round(rpm / reg.codec.factor(self.pulses_per_rev)
                                          / reg.codec.scale))
            else:
                value = _clamp(reg, round(rpm))
        elif means == "alarm_code":
            value = self.alarm_code
        elif means == "motion":
            value = reg.d.values.get(self.motion or "none", 0)
        elif means == "address":
            value = self.address
        elif means == "direction":
            v = self.kin.velocity(now)
            if v:
                self._last_dir = -1 if v < 0 else 1
            value = int(self._last_dir < 0)
        elif means in TWIN_MEANINGS and means not in _VALUES:
            value = int(bool(self._signals(now).get(means, False)))
        elif means == "inputs":
            value = self._io_word("inputs", now)
        elif means == "outputs":
            value = self._io_word("outputs", now)
        elif means is None and reg.d.access == "R":
            value = 0
        else:
            value = self._raw(reg, index)
        bits = [b for b in reg.d.bits.values() if b.means is not None]
        if bits:
            signals = self._signals(now)
            for b in bits:
                if signals.get(b.means or "", False):
                    value |= b.mask
                else:
                    value &= ~b.mask
        for b in reg.d.bits.values():
            if b.twin is not None:
                value = value | b.mask if self._eval(b.twin, now) else value & ~b.mask
        return value

    def set_input(self, terminal: int | str, closed: bool, now: float | None = None) -> None:
        """Drive an input terminal from outside (a sensor or a PLC wired to it): its bit
        number in the inputs' state register (counted from ``[inputs] first``: IN1 = 1
        where the manual numbers so), or its name in ``[inputs] names``. The
        state register shows the terminal closed whatever the inversion register says
        (it inverts what a closed terminal means to the drive's functions); the
        switches given in the setup stay as they are."""
        io = self.description.inputs
        names = list(io.names) if io is not None else []
        reg = self.description.regs[io.state] if io is not None else None
        count = len(names) or (16 * reg.d.words if reg is not None else 0)
        first = io.first if io is not None else 0
        index = terminal - first if isinstance(terminal, int) and \
            not isinstance(terminal, bool) else terminal
        if isinstance(terminal, str):
            upper = [n.upper() for n in names]
            index = upper.index(terminal.upper()) if terminal.upper() in upper else -1
        if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < count:
            shown = f"{names[0]}..{names[-1]}" if names else f"{first}..{count - 1 + first}"
            raise ConfigError(f"input {terminal!r}: the simulated {self.family} has "
                              f"{f'inputs {shown}' if count else 'no inputs'}")
        bit = 1 << index
        t = time_or_present(now)
        self.advance(t)
        self._external = self._external | bit if closed else self._external & ~bit
        self._functions_changed(t)

    # -- input functions (``[twin] on_input``) -----------------------------------------------

    def _input_functions(self, now: float) -> dict[str, bool]:
        """Whether each input function an ``on_input`` trigger watches is active now."""
        if not self.description.twin.on_input:
            return {}
        p = self._phys(now)
        return {trig.input: self._signal_at(trig.input, p)
                for trig in self.description.twin.on_input}

    def _functions_changed(self, now: float) -> None:
        """Act on the input functions that turned active (or inactive) since last seen."""
        before = self._functions_seen
        after = self._input_functions(now)
        self._functions_seen = after
        for trig in self.description.twin.on_input:
            name = trig.input
            if before.get(name) == after[name] or after[name] != (trig.edge == "rise"):
                continue
            if trig.when is not None and not self._eval(trig.when, now):
                continue
            self._do(trig, None, now)

    def _io_word(self, which: str, now: float) -> int:
        d = self.description
        io = d.inputs if which == "inputs" else d.outputs
        if io is None:
            return 0
        if which == "inputs" and d.twin.wiring:  # the terminals' levels (polarity register)
            p = self._phys(now)
            return sum(1 << i for i in self._terminals()
                       if self._physical(i, p) != self._inverted(i, by_function=False))
        signals = self._signals(now)
        active = {k: v for k, v in signals.items()}
        word = 0
        if io.functions is not None:
            reg = d.regs[io.functions]
            by_code = {c: s for s, c in io.codes.items()}
            switched = self._raw(d.regs[io.values], None) if io.values is not None else 0
            for n, i in enumerate(reg.indices):
                code = self._raw(reg, i) & io.function_mask
                if io.values is not None and code == io.settable:
                    word |= (switched >> n & 1) << n  # switched over Modbus
                    continue
                sig = by_code.get(code)
                if sig is not None and active.get(sig, False):
                    word |= 1 << n
        for sig, bit in io.bits.items():
            if active.get(sig, False):
                word |= 1 << bit
        if io.invert is not None:
            word ^= self._raw(d.regs[io.invert], None)
        if which == "inputs":
            word |= self._external  # a terminal closed from outside reads closed
        return word

    # -- writes --------------------------------------------------------------------------------

    def check_write(self, address: int, values: list[int]) -> None:
        """Word by word, then each 32-bit register written whole against its range."""
        if len(values) > self.description.link.max_write:
            raise SlaveException(self.exception_codes.count)
        super().check_write(address, values)
        written = dict(zip(range(address, address + len(values)), values, strict=True))
        for a in written:
            pair = self._pairs.get(a)
            if pair is None:
                continue
            reg, index = pair
            r = reg.at(index)
            low = r.low_address if r.low_address is not None else r.address + 1
            if r.address in written and low in written:
                words = {**self.regs, **written}
                value = self._raw(reg, index, words)
                if (reg.d.min is not None and value < reg.d.min) or \
                        (reg.d.max is not None and value > reg.d.max):
                    raise SlaveException(self.exception_codes.value)

    def write_registers(self, address: int, values: list[int], now: float) -> None:
        """Store the words, then act on the registers written (in address order)."""
        self.check_write(address, values)
        before = dict(self.regs)
        touched: list[tuple[Reg, int | None]] = []
        write_through = self._write_through(now)
        for offset, word in enumerate(values):
            a = address + offset
            self.regs[a] = word
            w = self._words[a]
            if w.reg.d.eeprom and write_through:
                self.eeprom[a] = word
                self.eeprom_writes += 1
            if (w.reg, w.index) not in touched:
                touched.append((w.reg, w.index))
        try:
            for reg, index in touched:
                self._act(reg, index, now, before)
        except SlaveException:
            self.regs = before
            raise
        if self.description.twin.on_input:
            self._functions_changed(now)

    def _write_through(self, now: float) -> bool:
        """True while a write to an ``eeprom`` register is stored."""
        d = self.description
        if d.twin.eeprom_write_through is not None:
            return bool(self._eval(d.twin.eeprom_write_through, now))
        wt = d.eeprom.write_through
        return wt is not None and self._raw(d.regs[wt.reg], None) == wt.on

    def write_register(self, address: int, word: int, now: float) -> None:
        """One word (FC06): as a write of one register."""
        self.write_registers(address, [word], now)

    def _act(self, reg: Reg, index: int | None, now: float,
             before: Mapping[int, int] | None = None) -> None:
        triggers = self._triggers.get(reg.key, ())
        if not triggers:
            return
        value = RegValue(self._raw(reg, index), reg)
        # `previous`: what the register held before this write (a start on a 0->1 edge)
        self._previous = RegValue(self._raw(reg, index, before), reg) if before is not None \
            else value
        try:
            for trig in triggers:
                if trig.when is not None and not self._eval(trig.when, now, value):
                    continue
                started = self._do(trig, value, now)
                self._set_registers(trig.set, now, value)  # what the drive writes back
                if trig.ends:
                    self._ends = (trig, value)
                    if not started:
                        self._settle(now)
                if not trig.more:
                    return
        finally:
            self._previous = None

    def _set_registers(self, sets: Mapping[str, Expr], now: float, value: Any) -> None:
        """Store raw values the drive writes itself (a trigger's ``set`` or ``ends``)."""
        for key, e in sets.items():
            target = self.description.regs[key]
            self._store(self.coils if target.d.coil else self.regs, target, None,
                        int(self._eval(e, now, value)) & (1 if target.d.coil else -1))

    def _running(self, now: float) -> bool:
        """A motion, homing or table runs (or the motor still turns)."""
        return self._homing is not None or self._ref is not None or \
            self._table is not None or self.kin.moving(now)

    def _settle(self, now: float) -> None:
        """Set the ``ends`` registers of the trigger whose motion is over by ``now``."""
        if self._ends is not None and not self._running(now):
            trig, value = self._ends
            self._ends = None
            self._set_registers(trig.ends, now, value)

    def _active(self, now: float) -> dict[str, bool]:
        """Each input function of ``[inputs] codes``: active now."""
        io = self.description.inputs
        p = self._phys(now)
        return {} if io is None else {s: self._signal_at(s, p) for s in io.codes}

    # -- evaluation ---------------------------------------------------------------------------

    def _scope(self, now: float, value: Any = None,
               extra: Mapping[str, Any] | None = None) -> _Scope:
        return _Scope(self, now, value, extra)

    def _eval(self, e: Expr, now: float, value: Any = None,
              extra: Mapping[str, Any] | None = None) -> Any:
        try:
            return e(self._scope(now, value, extra))
        except Unknown as exc:
            raise ExprError(f"{e.source!r}: {exc}") from None

    def physical(self, reg: Reg, index: int | None, now: float, ref: float | None = None
                 ) -> Any:
        """The physical value register ``reg`` holds (a ramp time as a rate in r/s²)."""
        raw = self._computed(reg, index, now) if _computed(reg) else self._raw(reg, index)
        if reg.codec.kind is Kind.RAMP and isinstance(reg.codec.ramp, str) and ref is None:
            ref_reg = self.description.regs[reg.codec.ramp]
            ref_v = self.physical(ref_reg, index if ref_reg.array else None, now)
            ref = abs(float(ref_v)) or abs(self.speed_rpm(now))
        return reg_value(reg, raw, reg.codec.to_physical(raw, ppr=self.pulses_per_rev,
                                                        ref_rpm=ref))

    # -- actions -------------------------------------------------------------------------------

    def _param(self, trig: Trigger, name: str, now: float, value: Any) -> Any:
        e = getattr(trig, name)
        return None if e is None else self._eval(e, now, value)

    def _do(self, trig: Trigger, value: Any, now: float) -> bool:
        """Carry out ``trig``'s action; False if it is a start the drive did not obey."""
        do = trig.do
        refusals = self.description.link.refusals
        if do == "refuse":
            raise SlaveException(refusals.busy if refusals.busy is not None
                                 else refusals.value)
        if do in _STARTS and not self._eval(self.description.twin.starts, now, value):
            if trig.refuse and refusals.busy is not None:
                raise SlaveException(refusals.busy)
            return False
        p = self.pulses_per_rev
        if do in ("emergency_stop", "stop", "disable"):
            self._ref = None
            self._table = None
            self._completes = False
            self.stalled = False
        if do in ("emergency_stop", "stop"):  # an emergency stop without decel: at once
            self.stopping = do
            self._homing = None
            decel = self._param(trig, "decel", now, value)
            self.kin.stop(now, _rate(decel, p))
        elif do == "enable":
            self.enabled = True
        elif do == "disable":
            self.enabled = False
            self._homing = None
            self.kin.stop(now, None)  # released: the shaft is free, motion ends
        elif do == "clear_alarm":
            rule = self._clear_rule(self.alarm_code)
            if rule == "command":
                self.alarm_code = 0
        elif do == "zero_position":
            self._set_counter(now, 0)
        elif do == "set_position":
            self._set_counter(now, float(self._param(trig, "position", now, value)))
        elif do == "save":
            self.eeprom.update(self.regs)
        elif do == "factory_reset":
            self.regs.update(self.factory)
            self.eeprom.update(self.regs)
        elif do in ("move_absolute", "move_relative"):
            self._move(trig, value, now)
        elif do == "run":
            self._run(trig, value, now)
        elif do == "set_speed":
            self._set_speed(trig, value, now)
        elif do == "home":
            self._home(trig, value, now)
        elif do == "run_table":
            self._start_table(trig, value, now)
        return True

    def _clear_rule(self, code: int) -> str:
        alarms = self.description.alarms
        if alarms is None:
            return "command"
        return alarms.clears.get(code, "command")

    def _blocked(self, direction: float, now: float) -> bool:
        """True if a limit input in ``direction`` is active (the drive will not go on)."""
        if not self.description.twin.limits.block_start:
            return False
        _, neg, pos = self.switch_states(now)
        return (direction > 0 and pos and self._wired("limit_positive")) or (
            direction < 0 and neg and self._wired("limit_negative"))

    def _move(self, trig: Trigger, value: Any, now: float) -> None:
        ppr = self.pulses_per_rev
        speed = self._param(trig, "speed", now, value)
        accel = self._param(trig, "accel", now, value)
        decel = self._param(trig, "decel", now, value)
        if not _usable(speed, accel, decel):
            return
        p = self._wrap(now)
        if trig.do == "move_absolute":
            target = float(self._param(trig, "target", now, value))
        else:
            target = round(p) + float(self._param(trig, "distance", now, value))
        if self._blocked(target - p, now):
            return
        a, dc = float(accel) * ppr, float(decel) * ppr
        self.kin.move_to(now, target, self._pps(abs(float(speed))), a, dc)
        self._started(trig, "position", now, dc)

    def _run(self, trig: Trigger, value: Any, now: float) -> None:
        ppr = self.pulses_per_rev
        speed = float(self._param(trig, "speed", now, value) or 0.0)
        accel = self._param(trig, "accel", now, value)
        decel = self._param(trig, "decel", now, value)
        if self._blocked(speed, now):
            return
        self._wrap(now)
        a = float(accel) * ppr if _finite_pos(accel) else math.inf
        dc = float(decel) * ppr if _finite_pos(decel) else math.inf
        if speed == 0:
            self.kin.stop(now, dc)
        else:
            self.kin.run(now, self._pps(speed), a, dc)
        self._run_rates = (a, dc)
        self._started(trig, "speed", now, dc)

    def _set_speed(self, trig: Trigger, value: Any, now: float) -> None:
        if self.motion != "speed" or not self.kin.moving(now) or self.stopping:
            return  # a new speed does not restart a motor that is being stopped
        speed = float(self._param(trig, "speed", now, value) or 0.0)
        v = self.kin.velocity(now)
        signed = math.copysign(abs(speed), v) if v else speed
        a, dc = self._run_rates
        self.kin.run(now, self._pps(signed), a, dc)

    def _started(self, trig: Trigger, kind: str, now: float, decel: float) -> None:
        self.motion = trig.motion or kind
        self._watch_from = now
        self._motion_decel = decel
        self._homing = None
        self._ref = None
        self._table = None
        self.stopping = None
        self.reached = False
        self._completes = kind == "position"
        self._processed_until = max(self._processed_until, now)
        v = self.kin.velocity(now + 1e-3)
        if v:
            self._last_dir = -1 if v < 0 else 1

    # -- homing --------------------------------------------------------------------------------

    def _method_code(self, now: float) -> Any:
        """The homing method the drive's home trigger names now (its register's value)."""
        trig = next((t for ts in self._triggers.values() for t in ts if t.do == "home"), None)
        return None if trig is None else self._param(trig, "method", now, None)

    def _method_def(self, code: Any) -> MethodDef | None:
        """The description's homing method of ``code`` (a name or the drive's number)."""
        h = self.description.homing
        if h is None or code is None:
            return None
        if isinstance(code, str):
            return h.methods.get(code)
        return next((m for m in h.methods.values() if m.code is not None and
                     m.code == int(code)), None)

    def _home(self, trig: Trigger, value: Any, now: float) -> None:
        method = self._method_def(self._param(trig, "method", now, value))
        if method is None:
            return  # not a documented method: the drive does nothing
        ppr = self.pulses_per_rev
        speed = float(self._param(trig, "speed", now, value) or 0.0)
        creep = float(self._param(trig, "creep", now, value) or speed)
        accel = self._param(trig, "accel", now, value)
        offset = float(self._param(trig, "offset", now, value) or 0.0)
        self._wrap(now)
        self.motion = trig.motion or "homing"
        self.homed = False
        self.homing_failed = False
        self.stopping = None
        self._table = None
        if method.behaviour == "reference_edge":
            self._ref_home(method, speed, creep, accel, offset, now)
            return
        if method.behaviour == "move_to_offset":
            self._offset_home(speed, accel, offset, now)
            return
        if method.behaviour == "hard_stop":
            self._stop_home(method, speed, creep, accel, offset, now)
            return
        number = method.cia402
        if method.behaviour == "set" or number in (33, 34, 35, 37):
            self._set_counter(now, offset)
            self.homed = True
            return
        home, neg, pos = self.switch_states(now)
        plan = _search_phases(number or 0, home and self._wired("home_switch"),
                              neg and self._wired("limit_negative"),
                              pos and self._wired("limit_positive"))
        if plan is None:
            return
        phases, first = plan
        rate = float(accel) * ppr if _finite_pos(accel) else math.inf
        self._homing = _Homing(phases, first, now, self._pps(speed), self._pps(creep),
                               rate, offset)
        self._enter(first, now)

    def _enter(self, name: str, t: float) -> None:
        h = self._homing
        assert h is not None
        phase = h.phases[name]
        v = self.kin.velocity(t)
        self.kin.run(t, phase.direction * (h.speed if phase.fast else h.creep), h.rate, h.rate)
        h.t_dir = t + abs(v) / h.rate if v * phase.direction < 0 and h.rate > 0 else t
        h.phase = name

    def _next_edge(self, now: float) -> tuple[float, str] | None:
        h = self._homing
        assert h is not None
        phase = h.phases[h.phase]
        events = list(phase.events)
        ahead = "limit_positive" if phase.direction > 0 else "limit_negative"
        if all(name != ahead for name, _ in events):
            events.append((ahead, "abort"))
        t_from = h.t_dir + 1e-9
        best: tuple[float, str] | None = None
        for name, nxt in events:
            span = self._span(name)
            if name == ahead and span is not None and t_from <= now and \
                    span.active(self._phys(t_from)):
                return t_from, nxt  # the limit ahead is active as the leg sets off
            boundary = self._boundary(name)
            if boundary is None:
                continue
            tc = self.kin.crossing(boundary, t_from, now)
            if tc is not None and (best is None or tc < best[0]):
                best = (tc, nxt)
        return best

    def _advance_homing(self, now: float) -> None:
        for _ in range(16):
            h = self._homing
            if h is None:
                return
            edge = self._next_edge(now)
            if edge is None:
                return
            tc, nxt = edge
            if nxt == "done":
                self.kin.stop(tc, h.rate)
                self._set_counter(tc, h.offset)
                self.homed = True
                self._homing = None
            elif nxt == "abort":
                self.kin.stop(tc, self._limit_rate(tc))
                self._homing = None
                self.homing_failed = True
            else:
                self._enter(nxt, tc)

    # -- homing on a reference input's rising edge (``behaviour = "reference_edge"``) -----

    def _ref_home(self, method: MethodDef, speed: float, creep: float, accel: Any,
                  offset: float, now: float) -> None:
        """Search at ``speed`` in the method's direction until its reference input turns
        active, brake, back off (``[twin.homing]``: at ``speed`` or the creep speed) until
        it turns inactive, brake, creep back until it turns active: that edge is the
        origin (backing off with ``backoff_stop = "at_once"``, the edge it leaves is the
        origin). A limit switch ahead in the search reverses it once (where
        ``reverse_at_limit`` holds; else the homing fails there); any other stops the
        motor (as ``[twin] limits`` say) and the homing fails. Started on the reference,
        the twin backs off first."""
        ppr = self.pulses_per_rev
        assert method.reference is not None and method.direction is not None
        rate = float(accel) * ppr if _finite_pos(accel) else math.inf
        hd = self.description.twin.homing
        h = _RefHoming(method.reference, "search", float(method.direction),
                       self._pps(speed), self._pps(creep), rate, offset,
                       may_reverse=bool(self._eval(hd.reverse_at_limit, now)),
                       offset_mode=self._offset_mode(now))
        self._begin_ref(h, now)
        p = self._phys(now)
        if self._signal_at(h.reference, p):
            h.phase = "brake1"
            self._ref_ramp_end(now)
            return
        ahead = "limit_positive" if h.direction > 0 else "limit_negative"
        if ahead != h.reference and self._signal_at(ahead, p):
            if h.may_reverse:
                self._ref_reverse(now)  # on a limit already: the turning reverses
            else:
                self._ref_fail(now)
            return
        self._ref_run(now, h.direction * h.speed)

    def _offset_mode(self, now: float) -> str:
        """What a homing's offset does (``[twin.homing] offset``, else ``home_offset``)."""
        t = self.description.twin
        if t.homing.offset is None:
            return t.home_offset
        mode = self._eval(t.homing.offset, now)
        if mode not in ("origin", "move", "travel"):
            raise ExprError(f"twin.homing.offset {t.homing.offset.source!r} gave {mode!r}, "
                            "not 'origin', 'move' or 'travel'")
        return str(mode)

    def _begin_ref(self, h: _RefHoming, now: float) -> None:
        """Homing ``h`` runs from ``now`` (its legs are followed as the twin advances)."""
        self._ref = h
        self._homing = None
        self._motion_decel = h.rate
        self.reached = False
        self._completes = False
        self._processed_until = max(self._processed_until, now)

    def _ref_run(self, t: float, pps: float) -> None:
        h = self._ref
        assert h is not None
        self.kin.run(t, pps, h.rate, h.rate)
        self._last_dir = 1 if pps > 0 else -1

    def _ref_ramp_end(self, t: float) -> None:
        h = self._ref
        assert h is not None
        if h.phase == "brake1":
            h.phase = "backoff"
            back = h.creep if self.description.twin.homing.backoff == "creep" else h.speed
            self._ref_run(t, -h.direction * back)
        elif h.phase == "brake2":
            h.phase = "creep"
            self._ref_run(t, h.direction * h.creep)
        else:
            if h.phase == "offset" and h.final is not None:
                self._set_counter(t, h.final)  # "travel": the point reached is 0
            self._ref_done()

    def _ref_done(self) -> None:
        self._ref = None
        self.homed = True
        self.reached = True
        self.stalled = False

    def _stop_home(self, method: MethodDef, speed: float, creep: float, accel: Any,
                   offset: float, now: float) -> None:
        """``behaviour = "hard_stop"``: creep in the method's direction into the end stop
        (``hard_stop_positive``/``_negative``), stall there for ``[twin] stall_time``:
        that point is the origin (``home_offset`` as for an edge). A limit switch met
        first stops the motor and fails the homing; with neither it creeps on."""
        assert method.direction is not None
        rate = float(accel) * self.pulses_per_rev if _finite_pos(accel) else math.inf
        d = float(method.direction)
        stop = self.hard_stop_positive if d > 0 else self.hard_stop_negative
        h = _RefHoming("", "press", d, self._pps(speed), self._pps(creep), rate, offset,
                       offset_mode=self._offset_mode(now))
        h.stop = None if stop is None else stop + self._shift
        self._begin_ref(h, now)
        if h.stop is not None and (h.stop - self.kin.position(now)) * d <= 0:
            self._stall(now)  # on the end stop already
            return
        self._ref_run(now, d * h.creep)

    def _stall(self, t: float) -> None:
        h = self._ref
        assert h is not None
        self.kin.hold(t, h.stop)
        self.stalled = True
        h.phase = "stall"
        h.until = t + float(self._eval(self.description.twin.stall_time, t) or 0.0)

    def _press_end(self, t0: float, t1: float) -> float | None:
        """When the motor reaches the end stop ahead in [t0, t1] (None: not yet)."""
        h = self._ref
        assert h is not None
        return None if h.stop is None else self.kin.crossing(h.stop, t0, t1)

    def _ref_found(self, t: float) -> None:
        h = self._ref
        assert h is not None
        self.kin.stop(t, h.rate)
        h.phase = "brake1" if h.phase == "search" else "brake2"

    def _ref_reverse(self, t: float) -> None:
        """The search met the limit switch ahead: search the other way (``[twin.homing]
        after_reversal = "other_edge"``), or pass back through the reference to creep to
        the edge the search looked for (``"same_edge"``)."""
        h = self._ref
        assert h is not None
        h.reversed = True
        if self.description.twin.homing.after_reversal == "same_edge":
            h.phase = "pass"
            self._ref_run(t, -h.direction * h.speed)
            return
        h.direction = -h.direction
        self._ref_run(t, h.direction * h.speed)

    def _ref_passed(self, t: float) -> None:
        """Back through the reference after a reversal: brake, then creep back onto it."""
        h = self._ref
        assert h is not None
        self.kin.stop(t, h.rate)
        h.phase = "brake2"

    def _ref_left(self, t: float) -> None:
        """The back-off left the reference: brake and creep back, or (``backoff_stop =
        "at_once"``) stop at once on the edge, the origin."""
        if self.description.twin.homing.backoff_stop == "at_once":
            self._ref_origin(t)
        else:
            self._ref_found(t)

    def _ref_fail(self, t: float) -> None:
        """A limit switch met while homing (not the search's first): stop as ``[twin]
        limits`` say; the homing fails (reversing again would run between the limits)."""
        h = self._ref
        rate = None if self._eval(self.description.twin.limits.stop, t) == "immediate" \
            else (h.rate if h is not None else None)
        self.kin.stop(t, rate)
        self._ref = None
        self.stalled = False
        self.homing_failed = True

    def _ref_origin(self, t: float) -> None:
        """The origin edge: with ``home_offset = "move"`` the counter is 0 there and the
        compensation move of the offset follows at the creep speed; else the edge takes the
        offset as its position."""
        h = self._ref
        assert h is not None
        self.stalled = False
        if h.reference:
            self.kin.hold(t, self._on_edge(h.reference, self.kin.position(t)))
        mode = h.offset_mode
        if mode == "origin":
            self.kin.stop(t, h.rate)
            self._set_counter(t, h.offset)
            self._ref_done()
            return
        offset = h.offset
        if mode == "move" or not offset:
            self._set_counter(t, 0)
        if not offset:
            self._ref_done()
            return
        towards = "limit_positive" if offset > 0 else "limit_negative"
        if self._signal_at(towards, self._phys(t) + math.copysign(0.5, offset)):
            self._ref_fail(t)  # the compensation would go into a limit switch
            return
        h.phase = "offset"
        h.final = 0.0 if mode == "travel" else None
        speed = h.speed if self.description.twin.homing.offset_speed == "speed" else h.creep
        self.kin.move_to(t, self.kin.position(t) + offset, speed if speed > 0 else 1.0,
                         h.rate, h.rate)
        self._last_dir = 1 if offset > 0 else -1

    def _offset_home(self, speed: float, accel: Any, offset: float, now: float) -> None:
        """``behaviour = "move_to_offset"``: a move to the position ``offset`` at ``speed``;
        there it is homed. A limit switch met on the way stops it (as ``[twin] limits``
        say) and the homing fails."""
        ppr = self.pulses_per_rev
        rate = float(accel) * ppr if _finite_pos(accel) else math.inf
        pps = self._pps(speed)
        here = self.kin.position(now)
        if pps <= 0 or offset == here:
            self._set_counter(now, offset)
            self.homed = True
            return
        towards = "limit_positive" if offset > here else "limit_negative"
        if self._blocked(offset - here, now) or self._signal_at(
                towards, self._phys(now) + math.copysign(0.5, offset - here)):
            self.homing_failed = True
            return
        self._begin_ref(_RefHoming("", "offset", 1.0 if offset > here else -1.0, pps, pps,
                                   rate, offset), now)
        self.kin.move_to(now, offset, pps, rate, rate)
        self._last_dir = 1 if offset > here else -1

    def _on_edge(self, signal: str, x: float) -> float:
        """``x`` (counter frame) on the nearest end of ``signal``'s switch when it is that
        close (the edge a crossing time found, without its float rounding)."""
        span = self._direct_span(signal) if signal in self.description.twin.direct else \
            next((self._switch_span(i) for i in self._carriers(signal)), None)
        if span is None:
            return x
        ends = [e + self._shift for e in (span.lo, span.hi) if math.isfinite(e)]
        near = min(ends, key=lambda e: abs(e - x), default=x)
        return near if abs(near - x) < 1e-3 else x

    def _ref_limits(self, t0: float, t1: float, *, reverse: bool = False,
                    offset: bool = False) -> list[tuple[float | None, _Handler]]:
        h = self._ref
        assert h is not None
        handler = self._ref_reverse if reverse else self._ref_fail
        return [(self._signal_edge(lim, True, t0, t1), handler)
                for lim in ("limit_positive", "limit_negative")
                if offset or lim != h.reference]

    def _wired_event(self, t0: float, t1: float) -> tuple[float, _Handler] | None:
        """The next reaction in [t0, t1] of a twin with wired inputs."""
        if t1 < t0:
            return None
        end = self.kin.end_time()
        tr = self._table
        if tr is not None:
            if tr.phase == "wait":
                return (max(tr.until, t0), self._table_waited) if tr.until <= t1 else None
            return _first((max(end, t0) if end <= t1 else None, self._table_moved),
                          *((self._signal_edge(lim, True, t0, t1), self._table_limit)
                            for lim in ("limit_positive", "limit_negative")))
        h = self._ref
        if h is not None:
            if h.phase == "search":
                return _first((self._signal_edge(h.reference, True, t0, t1), self._ref_found),
                              *self._ref_limits(t0, t1,
                                                reverse=h.may_reverse and not h.reversed))
            if h.phase == "backoff":
                return _first((self._signal_edge(h.reference, False, t0, t1), self._ref_left),
                              *self._ref_limits(t0, t1))
            if h.phase == "pass":
                return _first((self._signal_edge(h.reference, False, t0, t1),
                               self._ref_passed), *self._ref_limits(t0, t1))
            if h.phase == "creep":
                return _first((self._signal_edge(h.reference, True, t0, t1), self._ref_origin),
                              *self._ref_limits(t0, t1))
            if h.phase == "offset":
                return _first((end if end <= t1 else None, self._ref_ramp_end),
                              *self._ref_limits(t0, t1, offset=True))
            if h.phase == "press":
                return _first((self._press_end(t0, t1), self._stall),
                              *self._ref_limits(t0, t1))
            if h.phase == "stall":
                return (h.until, self._ref_origin) if h.until <= t1 else None
            return (end, self._ref_ramp_end) if end <= t1 else None
        if self._homing is None and self.motion in ("position", "speed") and \
                self.kin.moving(t0):
            return _first(*((self._signal_edge(lim, True, t0, t1), self._wired_limit_stop)
                            for lim in ("limit_positive", "limit_negative")))
        return None

    # -- a table of moves (``do = "run_table"``) ------------------------------------------

    def _start_table(self, trig: Trigger, value: Any, now: float) -> None:
        """Run rows 1..``rows``: each a move (``target``, or ``distance`` where the target
        is None) at its speed and rates, then its ``wait``; the last row's wait only when
        the table repeats. The drive reports moving from start to end, waits included; a
        limit switch met stops the motor (as ``[twin] limits`` say) and the table."""
        rows = int(self._param(trig, "rows", now, value) or 0)
        if rows <= 0:
            return
        repeat = bool(self._param(trig, "repeat", now, value))
        self._wrap(now)
        self._table = _TableRun(trig, value, rows, repeat)
        self.motion = trig.motion or "table"
        self.stopping = None
        self._homing = None
        self._ref = None
        self.reached = False
        self._completes = False
        self._processed_until = max(self._processed_until, now)
        self._table_row(now)

    def _row(self, name: str, t: float) -> Any:
        """A row expression of the running table, with ``row`` its number (from 1)."""
        tr = self._table
        assert tr is not None
        e = getattr(tr.trig, name)
        return None if e is None else self._eval(e, t, tr.value, {"row": tr.row + 1})

    def _table_move(self, t: float) -> bool:
        """Start the present row's move; False if it has none (no distance, no speed)."""
        tr = self._table
        assert tr is not None
        ppr = self.pulses_per_rev
        speed, accel = self._row("speed", t), self._row("accel", t)
        decel = self._row("decel", t) if tr.trig.decel is not None else accel
        here = self.kin.position(t)
        target = self._row("target", t)
        if target is None and tr.trig.distance is not None:
            target = round(here) + float(self._row("distance", t))
        if target is None or not _usable(speed, accel, decel) or \
                abs(float(target) - here) < 0.5:
            return False
        if self._blocked(float(target) - here, t):
            self._table_end(t)
            return True
        a, dc = float(accel) * ppr, float(decel) * ppr
        self.kin.move_to(t, float(target), self._pps(abs(float(speed))), a, dc)
        self._motion_decel = dc
        self._last_dir = 1 if float(target) > here else -1
        tr.phase = "move"
        return True

    def _table_wait(self, t: float) -> bool:
        """Begin the present row's wait, if it has one (the last row's only when the
        table repeats)."""
        tr = self._table
        assert tr is not None
        if tr.row == tr.rows - 1 and not tr.repeat:
            return False
        wait = float(self._row("wait", t) or 0.0)
        if wait <= 0:
            return False
        tr.phase, tr.until = "wait", t + wait
        return True

    def _table_next(self, t: float) -> bool:
        """Go on to the next row (the first again when it repeats); False at the end."""
        tr = self._table
        assert tr is not None
        tr.row += 1
        if tr.row >= tr.rows:
            if not tr.repeat:
                self._table_end(t)
                return False
            tr.row = 0
        return True

    def _table_row(self, t: float) -> None:
        """Run rows from the present one until one moves or waits (a whole pass without
        either ends the table)."""
        tr = self._table
        assert tr is not None
        for _ in range(tr.rows + 1):
            if self._table_move(t) or self._table_wait(t) or not self._table_next(t):
                return
        self._table_end(t)

    def _table_moved(self, t: float) -> None:
        if not self._table_wait(t) and self._table_next(t):
            self._table_row(t)

    def _table_waited(self, t: float) -> None:
        if self._table_next(t):
            self._table_row(t)

    def _table_limit(self, t: float) -> None:
        self.kin.stop(t, self._limit_rate(t))
        self.stopping = "limit"
        self._table = None

    def _table_end(self, t: float) -> None:
        self._table = None
        self.reached = True

    def _wired_limit_stop(self, t: float) -> None:
        self.kin.stop(t, self._limit_rate(t))
        self.stopping = "limit"
        self._completes = False

    def _advance_wired(self, now: float) -> None:
        for _ in range(64):
            t_from = max(self._processed_until, self._last_event + 1e-6)
            event = self._wired_event(t_from, now)
            if event is None:
                break
            t, handler = event
            self._last_event = t
            handler(t)
        self._processed_until = max(self._processed_until, now)

    # -- limits, alarms, power ----------------------------------------------------------------

    def _limit_rate(self, t: float) -> float | None:
        lim = self.description.twin.limits
        mode = self._eval(lim.stop, t)
        if mode == "immediate":
            return None
        if lim.decel is not None:
            return _rate(self._eval(lim.decel, t), self.pulses_per_rev)
        return self._motion_decel

    def _limit_hit(self, now: float) -> float | None:
        hits = []
        for boundary, direction in ((self._boundary("limit_positive"), 1),
                                    (self._boundary("limit_negative"), -1)):
            if boundary is None:
                continue
            tc = self.kin.entering(boundary, direction, self._watch_from, now)
            if tc is not None:
                hits.append(tc)
        return min(hits) if hits else None

    def advance(self, now: float) -> None:
        """Bring homing legs, tables and limit stops up to ``now`` (state is computed
        lazily), then set the ``ends`` registers of a motion that is over."""
        self._advance(now)
        if self._ends is not None:
            self._settle(now)

    def _advance(self, now: float) -> None:
        twin = self.description.twin
        if (twin.wiring or twin.direct or self._ref is not None or
                self._table is not None) and self._homing is None:
            self._advance_wired(now)
            return
        if self._homing is not None:
            self._advance_homing(now)
            return
        if self.motion in ("position", "speed") and self.kin.moving(now):
            tc = self._limit_hit(now)
            if tc is not None:
                self.kin.stop(tc, self._limit_rate(tc))
                self.stopping = "limit"
                self._watch_from = now

    def raise_alarm(self, code: int, now: float | None = None) -> None:
        """Latch alarm ``code``: the motor stops at once."""
        t = time_or_present(now)
        self.advance(t)
        self._homing = None
        self._ref = None
        self._table = None
        self.stalled = False
        self._completes = False
        alarms = self.description.alarms
        if alarms is not None and alarms.kind == "flags":
            code |= self.alarm_code  # flags latch side by side
        super().raise_alarm(code, t)

    def power_loss(self) -> None:
        """Power cut: motion, homing and tables end with it (silent until restored)."""
        self.advance(monotonic())
        self._homing = None
        self._ref = None
        self._table = None
        super().power_loss()

    def supply_recovered(self) -> None:
        """The supply is back in range: alarms that clear with the supply clear."""
        if self._clear_rule(self.alarm_code) == "supply":
            self.alarm_code = 0

    def power_restore(self) -> None:
        """Power-up: stored words come back, volatile registers take their defaults, a
        stored line format applies, the counter starts at 0, the homed state is gone."""
        super().power_restore()
        now = monotonic()
        self.regs = dict(self.eeprom)
        self.coils = {}
        self._factory_words()  # the coils' defaults
        for reg in self.description.regs.values():
            if reg.d.volatile:
                for index in (reg.indices if reg.array else [None]):
                    self._store(self.regs, reg, index, reg.default_at(index))
        self._apply_baud_register(initial=False)
        self._apply_format_register(initial=False)
        if self.soft_address:
            key = self.description.link.address_register
            assert key is not None
            self.address = self._raw(self.description.regs[key], None)
        self.kin.hold(now)
        self._set_counter(now, 0)
        self.alarm_code = 0
        self.motion = None
        self.homed = False
        self._homing = None
        self._ref = None
        self._table = None
        self._ends = None
        self.reached = True
        self._completes = False
        self.stopping = None
        self.stalled = False
        self._functions_seen = self._input_functions(now)
        self.enabled = bool(self._eval(self.description.twin.enabled, now))

    def _apply_baud_register(self, *, initial: bool) -> None:
        """The baud rate register (``[link] baud_register``): a twin built at one of its
        named rates runs at the register's rate (its switches select the register): the
        rate is stored at first and the saved one applies at power-up. At another rate
        (set by switches) the register is not used."""
        d = self.description
        key = d.link.baud_register
        if key is None or self.settings is None:
            return
        reg = d.regs[key]
        if initial:
            code = reg.d.values.get(str(self.settings.baudrate))
            self._baud_by_register = code is not None
            if code is not None:
                self._store(self.regs, reg, None, code)
            return
        if not self._baud_by_register:
            return
        baud = {v: k for k, v in reg.d.values.items()}.get(self._raw(reg, None), "")
        if baud.isdigit():
            self.settings = LineSettings.parse(self.settings.format, baudrate=int(baud))

    def _apply_format_register(self, *, initial: bool) -> None:
        """The line format register: set from the settings at first, applied at power-up."""
        d = self.description
        key = d.link.format_register
        if key is None or self.settings is None:
            return
        reg = d.regs[key]
        values = reg.d.values
        allowed = _formats_at(d, self.settings.baudrate)
        if initial:
            code = values.get(self.settings.format, 0) if self.settings.format in allowed \
                else 0
            self._store(self.regs, reg, None, code)
            return
        names = {v: k for k, v in values.items()}
        fmt = names.get(self._raw(reg, None))
        if fmt is not None and fmt in allowed:
            self.settings = LineSettings.parse(fmt, baudrate=self.settings.baudrate)


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


def _first(*candidates: tuple[float | None, _Handler]) -> tuple[float, _Handler] | None:
    """The earliest of the events that happen (time not None)."""
    found = [(t, h) for t, h in candidates if t is not None]
    return min(found, key=lambda c: c[0]) if found else None


def _cia402_method(method: MethodDef | None) -> HomingMethod | None:
    """The CiA 402 method a description's homing method behaves as, if any."""
    if method is None or method.cia402 is None:
        return None
    try:
        return homing_method(method.cia402)
    except ArgumentError:
        return None


def _formats_at(d: Description, baud: int) -> list[str]:
    for rule in d.link.format_rules:
        if baud in rule.baud_rates:
            return list(rule.formats)
    return list(d.link.formats)


def _computed(reg: Reg) -> bool:
    return reg.d.means is not None or any(
        b.means is not None or b.twin is not None for b in reg.d.bits.values())


def _clamp(reg: Reg, value: int) -> int:
    r = reg.register
    bits = 16 * r.words
    lo = -(1 << (bits - 1)) if r.signed else 0
    hi = (1 << (bits - 1)) - 1 if r.signed else (1 << bits) - 1
    return max(lo, min(hi, value))


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


class _Scope(Mapping[str, Any]):
    """The names a twin expression sees: registers (physical values), constants, the
    written ``value`` and the twin's state."""

    def __init__(self, twin: DescribedDrive, now: float, value: Any,
                 extra: Mapping[str, Any] | None = None) -> None:
        self._twin = twin
        self._now = now
        self._value = value
        self._extra = extra or {}

    def __getitem__(self, key: str) -> Any:
        t = self._twin
        d = t.description
        if key in self._extra:
            return self._extra[key]
        if key == "value":
            if self._value is None:
                raise KeyError(key)
            return self._value
        if key == "previous":
            if t._previous is None:
                raise KeyError(key)
            return t._previous
        if key in d.constants:
            return d.constants[key]
        reg = d.regs.get(key)
        if reg is not None:
            if reg.array:
                return Table(reg, {i: t.physical(reg, i, self._now) for i in reg.indices})
            return t.physical(reg, None, self._now)
        now = self._now
        state = {
            "enabled": lambda: t.enabled,
            "moving": lambda: t.kin.moving(now) or t._table is not None,
            "alarm": lambda: bool(t.alarm_code),
            "homed": lambda: t.homed,
            "homing": lambda: t._homing is not None or t._ref is not None,
            "motion": lambda: t.motion,
            "speed_now": lambda: t.speed_rpm(now),
            "motion_decel": lambda: None if t._motion_decel is None or not
            math.isfinite(t._motion_decel) else t._motion_decel / t.pulses_per_rev,
            "pulses_per_rev": lambda: t.pulses_per_rev,
            "limit_positive": lambda: t.switch_states(now)[2],
            "limit_negative": lambda: t.switch_states(now)[1],
            "stopping": lambda: t.stopping if t.kin.moving(now) else None,
            "at_speed": lambda: t._signals(now)["at_speed"],
            "cruising": lambda: t.kin.steady(now),
            "stalled": lambda: t.stalled,
            "active": lambda: Attrs("active", t._active(now)),
        }
        if key in state:
            return state[key]()
        if key == "raw":
            return Attrs("raw", {k: t._raw(r, None) for k, r in d.regs.items()
                                 if not r.array})
        raise KeyError(key)

    def __iter__(self) -> Iterator[str]:
        return iter(())

    def __len__(self) -> int:
        return 0


# -- the twin class of a description -------------------------------------------------------


def _map(d: Description, *, inputs: bool = False
         ) -> tuple[dict[int, RegisterSpec], dict[int, _Word], dict[int, tuple[Reg, int | None]]]:
    """The twin's map of holding registers (or of input registers)."""
    specs: dict[int, RegisterSpec] = {}
    words: dict[int, _Word] = {}
    pairs: dict[int, tuple[Reg, int | None]] = {}
    for reg in d.regs.values():
        if reg.space != (1 if inputs else 0):  # coils and discrete inputs: _bits
            continue
        access = Access(reg.d.access)
        for index in (reg.indices if reg.array else [None]):
            r = reg.at(index)
            if r.words == 1:
                lo = r.lo
                hi = r.hi
                specs[r.address] = RegisterSpec(reg.default_at(index) & 0xFFFF, lo, hi, access,
                                                signed=r.signed, stored=reg.d.eeprom)
                words[r.address] = _Word(reg, index, 0)
                continue
            low = r.low_address if r.low_address is not None else r.address + 1
            for n, a in enumerate((r.address, low)):
                specs[a] = RegisterSpec(0, 0, 0xFFFF, access, stored=reg.d.eeprom)
                words[a] = _Word(reg, index, n)
                pairs[a] = (reg, index)
    return specs, words, pairs


def described_twin(d: Description) -> type[DescribedDrive]:
    """The twin class of description ``d``."""
    if d.link.map == "objects":
        raise ConfigError(f"{d.family}: the generic twin serves a flat word map only; an "
                          f"object-addressed map ([link] map = \"objects\") runs against "
                          f"its drive or an emulator of it")
    specs, words, pairs = _map(d)
    input_specs, input_words, _ = _map(d, inputs=True)
    r = d.link.refusals
    codes = ExceptionCodes(function=r.function, address=r.address, access=r.access,
                           value=r.value, count=r.count, crc=r.crc, read_access=r.read_access)
    reads = frozenset(f for f in (READ_HOLDING, READ_INPUT) if f in d.link.functions)
    triggers: dict[str, list[Trigger]] = {}
    for trig in d.twin.on_write:
        triggers.setdefault(trig.reg, []).append(trig)
    attrs: dict[str, Any] = {
        "__doc__": f"Simulated {d.family}, played from its description.",
        "__module__": __name__,
        "description": d,
        "family": d.family,
        "register_map": specs,
        "exception_codes": codes,
        "read_functions": reads,
        "max_read": d.link.max_read,
        "_map_end": max(specs, default=0),
        "_words": words,
        "_pairs": pairs,
        "_input_specs": input_specs,
        "_input_words": input_words,
        "_bits": {(reg.space, reg.at(i).address): _Word(reg, i, 0) for reg in d.regs.values()
                  if reg.space in (2, 3) for i in (reg.indices if reg.array else [None])},
        "_triggers": {k: tuple(v) for k, v in triggers.items()},
    }
    name = "Sim" + "".join(c if c.isalnum() else "_" for c in d.family)
    base: type[DescribedDrive] = DescribedDrive
    if d.drive.engine == "cia402":
        base = DescribedCia402Drive
        attrs["_objects"] = dict(d.objects)
    return type(name, (base,), attrs)


class DescribedCia402Drive(DescribedDrive):
    """A twin of a CiA 402 description: the registers mapped to CiA 402 objects are the
    simulated device's (``Cia402Device``: state machine, profile position and velocity,
    homing, on this twin's kinematics); the others are plain registers as in any twin."""

    _objects: ClassVar[dict[str, Reg]]

    @classmethod
    def twin_options(cls) -> list[str]:
        """The keyword options this twin takes (the device has no home cam side option)."""
        return [o for o in super().twin_options() if o not in ("home_cam", "soft_address")]

    def __init__(
        self,
        address: int,
        settings: LineSettings | None = None,
        setup: TwinSetup | None = None,
        *,
        home_switch_width: float | None = None,
        crc_error_reply: bool = True,
        **constants: int,
    ) -> None:
        super().__init__(address, settings, setup, home_switch_width=home_switch_width,
                         crc_error_reply=crc_error_reply, **constants)
        d = self.description
        s = setup or TwinSetup()
        ppr = self.pulses_per_rev
        methods = frozenset(m.cia402 for m in (d.homing.methods.values() if d.homing else [])
                            if m.cia402 is not None) or None
        self.device = Cia402Device(
            Cia402Setup(
                position=s.position, home_switch=s.home_switch,
                home_switch_width=home_switch_width, limit_negative=s.limit_negative,
                limit_positive=s.limit_positive, increments_per_rev=ppr,
                velocity_unit=_pulses_per_raw(d, "velocity", ppr),
                acceleration_unit=_pulses_per_raw(d, "acceleration", ppr),
                **({"homing_methods": methods} if methods else {}),
            ),
            defaults={name: reg.default_at(None) for name, reg in self._objects.items()
                      if reg.d.default and OBJECTS[name].writable},
            codes=self.exception_codes, kin=self.kin, now=0.0,
        )

    # -- the device's state as a twin shows it ------------------------------------------------

    @property  # type: ignore[override]
    def enabled(self) -> bool:
        """Operation enabled."""
        device = getattr(self, "device", None)
        return device is not None and device.state_at() is State.OPERATION_ENABLED

    @enabled.setter
    def enabled(self, value: bool) -> None:
        pass  # the state machine decides

    @property  # type: ignore[override]
    def alarm_code(self) -> int:
        """The device's error code while it is in a fault."""
        device = getattr(self, "device", None)
        if device is None:
            return 0
        state = device.state_at()
        return device.error_code if state in (State.FAULT, State.FAULT_REACTION_ACTIVE) else 0

    @alarm_code.setter
    def alarm_code(self, value: int) -> None:
        device = getattr(self, "device", None)
        if device is not None and value == 0:
            device.error_code = 0

    @property  # type: ignore[override]
    def homed(self) -> bool:
        """A homing of the device completed (its reference is set)."""
        device = getattr(self, "device", None)
        return device is not None and device.homed

    @homed.setter
    def homed(self, value: bool) -> None:
        pass  # the device's homing decides

    def position(self, now: float | None = None) -> int:
        return signed32(round(self.device.position(time_or_present(now))))

    def physical_position(self, now: float | None = None) -> float:
        return self.device.physical_position(time_or_present(now))

    def switch_states(self, now: float) -> tuple[bool, bool, bool]:
        return self.device.switch_states(now)

    def is_moving(self, now: float | None = None) -> bool:
        return self.device.is_moving(time_or_present(now))

    def velocity(self, now: float | None = None) -> float:
        return self.device.velocity(time_or_present(now))

    def advance(self, now: float) -> None:
        self.device.advance(now)

    def raise_alarm(self, code: int, now: float | None = None) -> None:
        """A fault with error code ``code``."""
        self.device.raise_fault(code, time_or_present(now))

    def power_loss(self) -> None:
        super().power_loss()
        self.device.power_loss(monotonic())

    def power_restore(self) -> None:
        SimDrive.power_restore(self)
        self.regs = dict(self.eeprom)
        self.device.power_restore(monotonic())

    # -- registers ---------------------------------------------------------------------------

    def _object_at(self, address: int) -> str | None:
        w = self._words.get(address)
        if w is None or w.reg.d.object is None:
            return None
        return object_name(w.reg.d.object)

    def read_register(self, address: int, now: float) -> int:
        name = self._object_at(address)
        if name is None:
            return super().read_register(address, now)
        reg = self._words[address].reg
        value = self.device.read(name, now)
        for b in reg.d.bits.values():  # a drive's own flags beside the object's bits
            on = self._eval(b.twin, now) if b.twin is not None else \
                self.homed if b.means == "homed" else None
            if on is not None:
                value = value | b.mask if on else value & ~b.mask
        words: dict[int, int] = {}
        self._store(words, reg, None, value)
        return words[address]

    def write_registers(self, address: int, values: list[int], now: float) -> None:
        """Plain registers as in any twin; objects checked whole, then written in address
        order (a 32-bit object needs both its words in the request or stored)."""
        self.check_write(address, values)
        written = dict(zip(range(address, address + len(values)), values, strict=True))
        objects: list[tuple[str, int]] = []
        plain: list[tuple[int, int]] = []
        seen: set[str] = set()
        for a, word in written.items():
            name = self._object_at(a)
            if name is None:
                plain.append((a, word))
                continue
            if name in seen:
                continue
            seen.add(name)
            reg = self._words[a].reg
            objects.append((name, self._raw(reg, None, {**self.regs, **written})))
        for name, value in objects:
            self.device.check(name, value)
        if plain:
            start = plain[0][0]
            if [a for a, _ in plain] == list(range(start, start + len(plain))):
                super().write_registers(start, [w for _, w in plain], now)
            else:
                for a, w in plain:
                    super().write_registers(a, [w], now)
        for a, word in written.items():
            if self._object_at(a) is not None:
                self.regs[a] = word
        for name, value in objects:
            self.device.write(name, value, now)


def _pulses_per_raw(d: Description, kind: str, ppr: int) -> float:
    """Pulses/s (or /s²) of one raw unit of the description's velocity (acceleration)
    objects."""
    names = ("profile_velocity", "target_velocity", "velocity_actual_value",
             "homing_speed_search") if kind == "velocity" else (
        "profile_acceleration", "profile_deceleration", "homing_acceleration")
    for name in names:
        reg = d.objects.get(name)
        if reg is None:
            continue
        v = float(reg.codec.to_physical(1, ppr=ppr))
        if reg.codec.kind is Kind.SPEED:
            return v * ppr / 60.0
        if reg.codec.kind is Kind.ACCEL:
            return v * ppr
        return v
    return 1.0


_described: dict[int, tuple[Description, type[DescribedDrive]]] = {}


def twin_of(d: Description) -> type[DescribedDrive]:
    """The twin class of description ``d`` (one class per description, made once)."""
    cached = _described.get(id(d))
    if cached is None or cached[0] is not d:
        cached = (d, described_twin(d))
        _described[id(d)] = cached
    return cached[1]
