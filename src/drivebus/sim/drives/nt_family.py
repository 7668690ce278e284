"""Simulated twins of the Rtelligent NT-family drives: ``SimNT86`` and ``SimEPR60`` (the
EPR60 is the generic twin of its description; the NT86 is still code here).

They answer with the manuals' register maps (written out here independently of the
profile's, so a profile mistake shows up), low-word-first 32-bit pairs, the status and
alarm bits, and exception codes 01-04 of the manuals' appendix B:

* 01 for any function but FC03/FC06/FC16;
* 02 for an unmapped or reserved address, or a write to a read-only register;
* 03 for a value outside the register's range (the manual does not say whether the drive
  refuses or clamps; the twin refuses);
* 04 DEVICEFAIL for a start command (18=1..4, or a homing trigger) while the motor moves,
  is disabled or has an alarm. The manual says a moving drive "can only respond to stop
  commands" without naming a code; of the four codes it lists, only 04 fits a well-formed
  request the drive cannot carry out. (A real drive may simply ignore it.)

Motion runs on ``self.kin`` in *physical* pulses (the frame in which the switch positions
are given); the drive's position counter 8/9 is that plus an offset that homing, 85=1
and power-up change. Events (switch edges, ends of ramps, stall timers) are processed
lazily, in time order, whenever the twin is asked anything. Twin assumptions where the
manuals are silent are marked "assumption".
"""

from __future__ import annotations

from collections.abc import Callable, Generator, Mapping
from dataclasses import dataclass
from typing import ClassVar

from drivebus.clock import monotonic
from drivebus.drives.registry import builtin_description
from drivebus.errors import ConfigError
from drivebus.pdu import READ_HOLDING
from drivebus.settings import LineSettings
from drivebus.sim.described import DescribedDrive, twin_of
from drivebus.sim.drive import HomeCam, SimDrive, Span, TwinSetup, time_or_present
from drivebus.sim.registers import Access, RegisterSpec, SlaveException, signed32

__all__ = ["SimEPR60", "SimNT86"]

_USER3 = 24
"""Input function 24, USER3: the multi-segment start in application mode 20 (3.7.4)."""

# Status register 1 bits, by the manual's names: enabled, alarm, in position, moving, homed,
# ready, at speed, brake released, positive limit, negative limit, powered, torque (stall).
ENA, ALM, INPOS, MOV, HOME, RDY, ARRSPD, CLAMP, PL, NL, POW, TC = (1 << b for b in range(12))

_NT86_BAUDS = (9600, 19200, 38400, 115200)


@dataclass(frozen=True)
class _Wait:
    """What a running motion program waits for next (the first of these to happen)."""

    cross: tuple[tuple[str, float, int], ...] = ()
    """(name, physical position, travel sign: +1/-1 only that way, 0 either)."""
    rest: bool = False
    until: float | None = None


Program = Generator[_Wait, tuple[str, float], None]


PairRanges = dict[int, tuple[int, int]]
"""The documented range of each 32-bit value, by the address of its low word."""


def _words_low_first(value: int) -> tuple[int, int]:
    """A 32-bit value as (low word, high word): the NT family's order."""
    u = value & 0xFFFFFFFF
    return u & 0xFFFF, u >> 16


def _edge_of(span: Span | None, direction: int, *, rising: bool) -> float | None:
    """Where a motor travelling in ``direction`` sees ``span`` turn active (``rising``)
    or inactive; None without a switch or such an edge."""
    return None if span is None else span.edge(direction, rising)


_READ_ONLY = RegisterSpec(access=Access.R)
_RESERVED = _READ_ONLY  # "-" in the map: reads 0, writes are refused like a read-only one


def _nt_common_map() -> tuple[dict[int, RegisterSpec], PairRanges]:
    """Registers 0-158 that the NT86 and EPR60 manuals share (defaults and ranges)."""
    w = {a: _READ_ONLY for a in (*range(0, 6), *range(8, 16), 29)}
    w.update({
        6: RegisterSpec(maximum=0x3F, command=True), 7: RegisterSpec(maximum=0x3F, command=True),
    })
    w[16] = RegisterSpec(maximum=1, command=True)
    w.update({
        17: RegisterSpec(0, 0, 1), 18: RegisterSpec(0, 0, 6, command=True),
        19: RegisterSpec(0, 0, 2), 20: RegisterSpec(0, 0, 22), 21: RegisterSpec(0, 0, 1),
        22: RegisterSpec(0, 0, 2), 23: RegisterSpec(0, 0, 1), 25: RegisterSpec(3000, 0, 6000),
        26: RegisterSpec(50, 0, 100), 27: RegisterSpec(500, 10, 65535),
        28: RegisterSpec(128, 1, 512), 30: RegisterSpec(0, 0, 1), 31: _READ_ONLY, 32: _READ_ONLY,
        33: RegisterSpec(1000, 100, 10000), 34: RegisterSpec(1, 1, 10),
        35: RegisterSpec(200, 0, 1000), 36: RegisterSpec(1000, 200, 10000),
        37: RegisterSpec(200, 0, 2000), 38: RegisterSpec(256, 0, 1024),
        39: RegisterSpec(0, 0, 1, command=True), 40: RegisterSpec(4000, 256, 65535),
        41: RegisterSpec(2000, 100, 65535), 42: RegisterSpec(10, 1), 43: RegisterSpec(50, 1),
        44: RegisterSpec(100, 1), 45: RegisterSpec(4000, 0, 5000), 46: RegisterSpec(50, 0, 100),
        47: RegisterSpec(200, 10, 5000), 48: RegisterSpec(600, 10, 5000),
        49: RegisterSpec(0, 0, 500), 50: RegisterSpec(3000), 51: RegisterSpec(1000),
        52: RegisterSpec(0), 53: RegisterSpec(800), 54: RegisterSpec(600),
        55: RegisterSpec(512, 0, 1024), 56: RegisterSpec(0), 57: RegisterSpec(0),
        58: RegisterSpec(5000, 10, 5000), 59: RegisterSpec(2000, 10, 5000),
    })
    for n, default in enumerate((0, 1, 4, 7, 12, 11)):  # IN1-IN6: function + polarity bit 5
        w[60 + n] = RegisterSpec(default, 0, 0x3F)
    w.update({
        66: RegisterSpec(1, 0, 0x1F), 67: RegisterSpec(4, 0, 0x1F), 68: RegisterSpec(0, 0, 3),
        69: _READ_ONLY, 70: RegisterSpec(200, 10, 1000), 71: RegisterSpec(200, 10, 1000),
        72: RegisterSpec(600, 0, 3000), 73: RegisterSpec(2000), 74: RegisterSpec(0),
        75: RegisterSpec(100, 10, 1000), 76: RegisterSpec(100, 10, 1000),
        77: RegisterSpec(600, 0, 3000), 78: RegisterSpec(500, 10, 1000), 84: RegisterSpec(0, 0, 1),
        85: RegisterSpec(0, 0, 1, command=True), 88: RegisterSpec(0, 0, 1),
        89: RegisterSpec(50, 0, 500), 90: RegisterSpec(0, 0, 1, command=True),
        91: RegisterSpec(0, 0, 1, command=True), 92: _RESERVED,
    })
    w.update({a: _READ_ONLY for a in (93, 94, 95, 104, 121)})
    w.update({
        100: RegisterSpec(200), 101: RegisterSpec(1000, 0, 3000), 102: RegisterSpec(1, 0, 0x1F),
        103: RegisterSpec(4, 0, 0x1F), 122: RegisterSpec(100, 100, 110),
    })
    for k in range(16):  # speed table 105-120, position table 125-156
        w[105 + k] = RegisterSpec(100 * k, 0, 3000)
        w[125 + 2 * k] = RegisterSpec(0)
        w[126 + 2 * k] = RegisterSpec(0)
    w.update({157: RegisterSpec(1000, 1), 158: RegisterSpec(15000)})
    pairs = {73: (-16777216, 16777216)}
    pairs.update({125 + 2 * k: (-16777216, 16777216) for k in range(16)})
    return w, pairs


def _nt86_map() -> tuple[dict[int, RegisterSpec], PairRanges]:
    """The NT86 manual's map: the common block plus 24, 79-83, 214-298."""
    w, pairs = _nt_common_map()
    w[24] = RegisterSpec(4000, 200, 65535)
    w.update({a: RegisterSpec(0) for a in range(79, 84)})  # summary-only legacy homing block
    w.update({
        214: RegisterSpec(4000), 215: RegisterSpec(0, 0, 0xF), 216: _READ_ONLY, 217: _READ_ONLY,
        218: RegisterSpec(5), 221: RegisterSpec(0, 0, 2), 222: RegisterSpec(16, 1, 16),
        223: RegisterSpec(0, 0, 1),
    })
    for n in range(16):  # multi-segment: speed, accel/decel, wait
        w.update({224 + 3 * n: RegisterSpec(100, 0, 3000), 225 + 3 * n: RegisterSpec(100, 1, 2000)})
        w[226 + 3 * n] = RegisterSpec(100)
    w.update({
        272: RegisterSpec(0, 0, 1650), 273: RegisterSpec(10, 0, 2000),
        274: RegisterSpec(50, 0, 1000), 275: RegisterSpec(0, 0, 1000),
        276: RegisterSpec(100, 0, 3000),
    })
    w.update({a: _READ_ONLY for a in (277, 278, 279)})
    w.update({a: RegisterSpec(0) for a in (280, 281, 282)})  # comms error counters, write resets
    w.update({
        287: RegisterSpec(1, 0, 6), 288: RegisterSpec(0, 0, 5), 289: RegisterSpec(50, 0, 1000),
        290: RegisterSpec(10, 0, 1000), 291: RegisterSpec(200, 1, 1000), 292: _RESERVED,
        293: RegisterSpec(0), 294: RegisterSpec(0), 295: RegisterSpec(0, 0, 3),
        296: RegisterSpec(5000, 1000), 297: RegisterSpec(5, 1, 1000),
        298: RegisterSpec(1000, 1, 6000),
    })
    pairs.update({214: (0, 0xFFFFF), 293: (-1048576, 1048576)})
    return w, pairs


_NT86_MAP, _NT86_PAIRS = _nt86_map()


class SimNT86(SimDrive):
    """Simulated Rtelligent NT86: Modbus RTU at 8N1 only, 9600/19200/38400/115200 baud.

    Family options: ``home_cam`` — the home switch is a cam active on the "positive" or
    "negative" side of ``home_switch`` (default: the side 288 searches towards, as the
    manual draws 288=0 and mirrors it for 288=1); ``home_switch_width`` — instead a dog
    over ``[home_switch, home_switch + width]``; ``hard_stop_negative`` /
    ``hard_stop_positive`` — mechanical end stops for hard-stop homing (288=4/5, closed
    loop only); ``control_mode`` — register 22 at power-up (0 open loop, 1/2 closed loop).
    Physical inputs: IN6 conducts while the home switch is active (its default function 11);
    ``set_input(n, on)`` drives IN1-IN5 (nothing is wired by default). The limit switches
    feed input functions 9/10 directly (assumption: the default input setup has none).
    """

    family: ClassVar[str] = "NT86"
    drive_id: ClassVar[int] = 86  # assumption: registers 93/94 formats are undocumented
    drive_version: ClassVar[int] = 100
    register_map: ClassVar[Mapping[int, RegisterSpec]] = _NT86_MAP
    pair_ranges: ClassVar[PairRanges] = _NT86_PAIRS
    read_functions = frozenset((READ_HOLDING,))

    def __init__(
        self,
        address: int,
        settings: LineSettings | None = None,
        setup: TwinSetup | None = None,
        *,
        home_cam: HomeCam | None = None,
        home_switch_width: float | None = None,
        hard_stop_negative: float | None = None,
        hard_stop_positive: float | None = None,
        control_mode: int = 0,
    ) -> None:
        settings = settings or LineSettings.parse("115200 8N1")
        self._check_line(address, settings)
        super().__init__(address, settings, setup)
        self.set_home_shape(home_cam, home_switch_width)
        self.hard_stop_negative = hard_stop_negative
        self.hard_stop_positive = hard_stop_positive
        self.params: dict[int, int] = {a: s.default for a, s in self.register_map.items()}
        self.params[22] = control_mode
        self.flash: dict[int, int] = dict(self.params)
        self._inputs = 0
        self._offset = 0.0
        self.homed = False
        self._program: Program | None = None
        self._program_kind = ""
        self._wait: _Wait | None = None
        self._wait_from = 0.0
        self._jog: tuple[int, float, float] | None = None  # (direction, accel, decel)
        self._stop_decel = 0.0
        self._cmd_speed = 0.0
        self._estopping = False
        self._stalled = False
        self._ready_at = 0.0
        self._crc_base = 0
        self._clear_trigger = True
        self.enabled = not self._function_active(4, 0.0)
        self._register_getters = self._getters()
        self._write_actions = self._actions()

    # -- configuration ---------------------------------------------------------------------

    @classmethod
    def _check_line(cls, address: int, settings: LineSettings) -> None:
        """The NT86 has DIP-switch addresses 1-31 and baud rates; 8N1 only."""
        if not 1 <= address <= 31:
            raise ConfigError(f"NT86 address {address}: DIP switches SW1-SW5 give 1..31")
        if settings.format != "8N1" or settings.baudrate not in _NT86_BAUDS:
            raise ConfigError(
                f"NT86 line settings {settings}: the drive does 8N1 only, at "
                f"{', '.join(map(str, _NT86_BAUDS))} baud (DIP switches SW6/SW7)"
            )

    # -- helpers ---------------------------------------------------------------------------

    @property
    def pulses_per_rev(self) -> int:
        """Microstep setting (register 24)."""
        return self.params[24]

    def _pair_value(self, low: int) -> int:
        value = self.params[low] | (self.params[low + 1] << 16)
        minimum, _ = self.pair_ranges[low]
        return signed32(value) if minimum < 0 else value

    def _physical(self, t: float) -> float:
        return self.kin.position(t)

    def counter(self, t: float) -> int:
        """Position register 8/9 at ``t`` (signed 32-bit, wraps like the drive's counter)."""
        return signed32(round(self._physical(t) + self._offset))

    def _set_counter(self, t: float, value: int) -> None:
        self._offset = value - self._physical(t)

    def home_side(self) -> int:
        """The default home cam side: negative for 288=1, else positive (288=0 searches
        positive; 2-5 do not use the home switch)."""
        return -1 if self.params.get(288) == 1 else 1

    def _input_mask(self, t: float) -> int:
        home, _, _ = self.switch_states(t)
        return self._inputs | (0x20 if home else 0)

    def _function_active(self, function: int, t: float) -> bool:
        """Input function ``function`` is active on some input at ``t``.

        Assumption on the polarity bit (bit 5), which the manual contradicts (L880 says
        1 = normally open is the default, yet every default value has bit 5 = 0): bit 5 = 0
        makes a function active while its input conducts. This is the only reading under
        which the default IN3 = 4 "motor offline", unwired, leaves the drive enabled at
        power-up as L635 says; setting bit 5 inverts the input.
        """
        mask = self._input_mask(t)
        for n in range(6):
            cfg = self.params[60 + n]
            if cfg & 0x1F == function and bool(mask >> n & 1) != bool(cfg & 0x20):
                return True
        return False

    # -- public test helpers ---------------------------------------------------------------

    def position(self, now: float | None = None) -> int:
        """The drive's position counter (register 8/9) in pulses."""
        t = time_or_present(now)
        self.advance(t)
        return self.counter(t)

    def physical_position(self, now: float | None = None) -> int:
        """The motor's position in the switch positions' frame, in whole pulses."""
        t = time_or_present(now)
        self.advance(t)
        return round(self._physical(t))

    def is_moving(self, now: float | None = None) -> bool:
        """True while the motor turns or a homing runs (status bit MOV)."""
        t = time_or_present(now)
        self.advance(t)
        return self._moving(t)

    def set_input(self, n: int, conducting: bool, now: float | None = None) -> None:
        """Drive physical input IN n (1-5; IN6 follows the home switch)."""
        if not 1 <= n <= 5:
            raise ConfigError(f"IN{n}: the twin drives IN1..IN5 (IN6 is the home switch)")
        t = time_or_present(now)
        self.advance(t)
        before = self._functions(t)
        self._inputs = (
            (self._inputs | (1 << (n - 1))) if conducting else (self._inputs & ~(1 << (n - 1)))
        )
        self._functions_changed(before, t)

    def raise_alarm(self, code: int, now: float | None = None) -> None:
        """Latch alarm bits ``code`` (register 0 layout, e.g. 0x02 over-current).

        The motor stops at once. It clears only by input function 5 "clear fault" or a
        power cycle (the NT86 has no alarm-reset register).
        """
        if not 0 < code <= 0x1FF:
            raise ConfigError(f"alarm code 0x{code:X}: register 0 has bits 0-8")
        t = time_or_present(now)
        self.advance(t)
        self._abort_program(t)
        self._jog = None
        super().raise_alarm(self.alarm_code | code, t)

    def power_loss(self) -> None:
        """Power cut: silent until restored; motion is lost."""
        t = monotonic()
        self.advance(t)
        self._abort_program(t)
        self._jog = None
        super().power_loss()

    def power_restore(self) -> None:
        """Power back: parameters from flash, counter 0, not homed, alarms cleared."""
        t = monotonic()
        super().power_restore()
        self.params = dict(self.flash)
        self.alarm_code = 0
        self.homed = False
        self._estopping = False
        self._set_counter(t, 0)
        self.enabled = not self._function_active(4, t)
        self._ready_at = t + 0.1

    # -- Modbus hooks ----------------------------------------------------------------------

    def read_register(self, address: int, now: float) -> int:
        """A computed register, 0 for a command register, else the stored parameter."""
        getter = self._register_getters.get(address)
        if getter is not None:
            return getter(now)
        return 0 if self.register_map[address].command else self.params[address]

    def check_write(self, address: int, values: list[int]) -> None:
        """Every register's access and range (02/03), then the range of each 32-bit value
        written whole (03)."""
        super().check_write(address, values)
        addresses = range(address, address + len(values))
        for low, (minimum, maximum) in self.pair_ranges.items():
            if low in addresses and low + 1 in addresses:
                raw = values[low - address] | (values[low + 1 - address] << 16)
                value = signed32(raw) if minimum < 0 else raw
                if not minimum <= value <= maximum:
                    raise SlaveException(self.exception_codes.value)

    def _getters(self) -> dict[int, Callable[[float], int]]:
        return {
            0: lambda t: self.alarm_code,
            1: self._status,
            2: self._input_mask,
            3: self._outputs,
            8: lambda t: _words_low_first(self.counter(t))[0],
            9: lambda t: _words_low_first(self.counter(t))[1],
            10: self._speed_rpm,
            11: lambda t: 48,  # bus voltage (the manual's unit is unclear)
            29: lambda t: self.counter(t),
            93: lambda t: self.drive_id,
            94: lambda t: self.drive_version,
            281: lambda t: self.crc_errors - self._crc_base,
        }

    def write_register(self, address: int, word: int, now: float) -> None:
        """Store the parameter (a command register keeps nothing), then act on the write."""
        old = self.params.get(address, 0)
        before = self._functions(now) if 60 <= address <= 65 else None
        if not self.register_map[address].command:
            self.params[address] = word
        if before is not None:  # an input's function or polarity changed
            self._functions_changed(before, now)
        action = self._write_actions.get(address)
        if action is not None:
            action(word, old, now)

    def _actions(self) -> dict[int, Callable[[int, int, float], None]]:
        acts: dict[int, Callable[[int, int, float], None]] = {
            18: lambda v, old, t: self._command(v, t),
            77: self._on_jog_speed,
            78: self._on_estop_decel,
            85: lambda v, old, t: self._set_counter(t, 0) if v else None,
            90: lambda v, old, t: self._save() if v else None,
            91: lambda v, old, t: self._factory_reset(t) if v else None,
            281: lambda v, old, t: setattr(self, "_crc_base", self.crc_errors),
            287: self._on_home_trigger,
        }
        return acts

    # -- status ----------------------------------------------------------------------------

    def _moving(self, t: float) -> bool:
        return self.kin.moving(t) or self._program_kind in ("homing", "table")

    def _status(self, t: float) -> int:
        _, neg, pos = self.switch_states(t)
        moving = self._moving(t)
        s = POW
        if self.enabled:
            s |= ENA | CLAMP
            if t >= self._ready_at and not self.alarm_code:
                s |= RDY
            if self.params[22] and not moving:
                s |= INPOS  # closed loop: settled (the twin has no following error)
        s |= ALM if self.alarm_code else 0
        s |= MOV if moving else 0
        s |= HOME if self.homed else 0
        s |= ARRSPD if self._at_speed(t) else 0
        s |= (PL if pos else 0) | (NL if neg else 0) | (TC if self._stalled else 0)
        return s

    def _at_speed(self, t: float) -> bool:
        v = abs(self.kin.velocity(t))
        return self._cmd_speed > 0 and abs(v - self._cmd_speed) < 1e-6 * self._cmd_speed

    def _speed_rpm(self, t: float) -> int:
        rpm = round(self.speed_rpm(t))
        return max(-32768, min(32767, rpm))

    def _outputs(self, t: float) -> int:
        """OUT1/OUT2 (registers 66/67 functions; polarity not modelled)."""
        status = self._status(t)
        active = {
            0: None,
            1: status & ALM,
            3: status & INPOS,
            4: status & ARRSPD,
            5: status & HOME,
            6: status & RDY,
            7: not status & MOV,
            8: status & PL,
            9: status & NL,
            10: True,
            11: status & TC,
        }
        out = 0
        for n, reg in enumerate((66, 67)):
            function = self.params[reg] & 0x0F
            on = self.params[68] >> n & 1 if function == 0 else active.get(function)
            out |= (1 << n) if on else 0
        return out

    # -- commands --------------------------------------------------------------------------

    def _check_can_start(self, t: float) -> None:
        """A start is refused (04) while moving, disabled or in alarm."""
        if self._moving(t) or not self.enabled or self.alarm_code:
            raise SlaveException(4)

    def _command(self, code: int, t: float) -> None:
        if self.params[20] not in (0, 20):
            return  # register 18 acts in application modes 0 and 20 (manual 3.7.1-3.7.2)
        if code == 5:
            self._estop(t)
        elif code == 6:
            self._decel_stop(t)
        elif code in (1, 2):
            self._check_can_start(t)
            self._start_move(code, t)
        elif code in (3, 4):
            self._check_can_start(t)
            self._start_jog(1 if code == 3 else -1, t)

    def _estop(self, t: float) -> None:
        self._abort_program(t)
        self._jog = None
        self._estopping = True
        self.kin.stop(t, self.pulse_acceleration(self.params[78]))

    def _decel_stop(self, t: float) -> None:
        decel = self._stop_decel
        self._abort_program(t)
        self._jog = None
        self.kin.stop(t, decel)

    def _blocked_by_limit(self, direction: int, t: float) -> bool:
        """Assumption: a start towards an active limit switch is not obeyed."""
        _, neg, pos = self.switch_states(t)
        return (direction > 0 and pos) or (direction < 0 and neg)

    def _start_move(self, code: int, t: float) -> None:
        speed = self.pulse_rate(self.params[72])
        accel = self.pulse_acceleration(self.params[70])
        decel = self.pulse_acceleration(self.params[71])
        value = self._pair_value(73)
        here = self._physical(t)
        if self.params[84] == 0:
            target = here + (abs(value) if code == 1 else -abs(value))
        else:
            target = value - self._offset
        if speed <= 0 or target == here or self._blocked_by_limit(1 if target > here else -1, t):
            return
        self._estopping = False
        self._stop_decel, self._cmd_speed = decel, speed
        self.kin.move_to(t, target, speed, accel, decel)
        self._run_program(self._watch_limits(), "motion", t)

    def _start_jog(self, direction: int, t: float) -> None:
        speed = self.pulse_rate(self.params[77])
        accel = self.pulse_acceleration(self.params[75])
        decel = self.pulse_acceleration(self.params[76])
        if self._blocked_by_limit(direction, t):
            return
        self._estopping = False
        self._jog = (direction, accel, decel)
        self._stop_decel, self._cmd_speed = decel, speed
        self.kin.run(t, direction * speed, accel, decel)
        self._run_program(self._watch_limits(), "motion", t)

    def _on_jog_speed(self, v: int, old: int, t: float) -> None:
        """77 takes effect at once during a jog (manual 3.2.2), with the latched ramps."""
        if self._jog is not None and self.kin.moving(t):
            direction, accel, decel = self._jog
            self._cmd_speed = self.pulse_rate(v)
            self.kin.run(t, direction * self._cmd_speed, accel, decel)

    def _on_estop_decel(self, v: int, old: int, t: float) -> None:
        """78 applies even to an emergency stop in progress (manual 3.2.1)."""
        if self._estopping and self.kin.moving(t):
            self.kin.stop(t, self.pulse_acceleration(v))

    def _save(self) -> None:
        self.flash = dict(self.params)

    def _factory_reset(self, t: float) -> None:
        before = self._functions(t)
        control = self.params[22]
        self.params = {a: s.default for a, s in self.register_map.items()}
        self.params[22] = control  # keeps the twin's wiring choice
        self._functions_changed(before, t)

    # -- input functions -------------------------------------------------------------------

    def _functions(self, t: float) -> dict[int, bool]:
        return {f: self._function_active(f, t) for f in (4, 5, 6, 12, _USER3)}

    def _functions_changed(self, before: dict[int, bool], t: float) -> None:
        after = self._functions(t)
        if after[4] and not before[4]:  # motor offline
            self.enabled = False
            self._abort_program(t)
            self._jog = None
            self.kin.stop(t, None)
        elif before[4] and not after[4]:
            self.enabled = True
            self._ready_at = t + 0.1  # RDY about 100 ms after enabling
        if after[5] and not before[5]:  # clear fault
            self.alarm_code = 0
        if after[6] and not before[6]:  # emergency stop input
            self._estop(t)
        if after[_USER3] and not before[_USER3]:  # multi-segment start (mode 20)
            self._on_table_start(t)
        if after[12] and not before[12]:  # start homing
            self._on_start_homing_input(t)

    def _on_start_homing_input(self, t: float) -> None:
        """287=1: mechanical, 287=2: electrical homing, started by function 12."""
        mode = self.params[287]
        hard_stop_open_loop = self.params[288] in (4, 5) and self.params[22] == 0
        if mode in (1, 2) and self._may_start(t) and not (mode == 1 and hard_stop_open_loop):
            self._start_homing(4 if mode == 1 else 5, t, clear_trigger=False)

    def _may_start(self, t: float) -> bool:
        return not self._moving(t) and self.enabled and not self.alarm_code

    # -- programs --------------------------------------------------------------------------

    def _run_program(self, program: Program, kind: str, t: float) -> None:
        self._program, self._program_kind = program, kind
        self._wait_from = t
        try:
            self._wait = next(program)
        except StopIteration:
            self._program, self._program_kind, self._wait = None, "", None

    def _abort_program(self, t: float) -> None:
        if self._program_kind == "homing":
            self._homing_aborted()
        self._program, self._program_kind, self._wait = None, "", None
        self._stalled = False

    def advance(self, now: float) -> None:
        """Process the running program's events up to ``now``, in time order."""
        for _ in range(1000):  # a program takes a handful of steps; never spin forever
            if self._program is None or self._wait is None:
                return
            event = self._next_event(self._wait, self._wait_from, now)
            if event is None:
                return
            self._wait_from = event[1]
            try:
                self._wait = self._program.send(event)
            except StopIteration:
                self._program, self._program_kind, self._wait = None, "", None

    def _next_event(self, wait: _Wait, t0: float, t1: float) -> tuple[str, float] | None:
        best: tuple[str, float] | None = None
        for name, p, sign in wait.cross:
            tc = self._crossing(p, t0, t1, sign)
            if tc is not None and (best is None or tc < best[1]):
                best = (name, tc)
        if wait.rest:
            end = max(self.kin.end_time(), t0)
            if end <= t1 and (best is None or end < best[1]):
                best = ("rest", end)
        if wait.until is not None and wait.until <= t1 and (best is None or wait.until < best[1]):
            best = ("timer", max(wait.until, t0))
        return best

    def _crossing(self, p: float, t0: float, t1: float, sign: int) -> float | None:
        """First time in [t0, t1] the motor passes ``p`` travelling in direction ``sign``."""
        if t0 <= t1 and abs(self.kin.position(t0) - p) < 1e-6:
            v = self.kin.velocity(t0) or self.kin.velocity(min(t0 + 1e-6, t1))
            if sign == 0 or v * sign > 0:
                return t0
        for _ in range(8):
            tc = self.kin.crossing(p, t0, t1)
            if tc is None:
                return None
            v = self.kin.velocity(tc) or self.kin.velocity(tc + 1e-6)
            if sign == 0 or v * sign > 0:
                return tc
            t0 = tc + 1e-6
            if t0 > t1:
                return None
        return None

    def _limit_crossings(self) -> tuple[tuple[str, float, int], ...]:
        """The limit switches as ``_Wait`` crossings, each met going outwards."""
        cross = []
        if self.limit_positive is not None:
            cross.append(("limit", self.limit_positive, 1))
        if self.limit_negative is not None:
            cross.append(("limit", self.limit_negative, -1))
        return tuple(cross)

    def _watch_limits(self) -> Program:
        """A move or jog: a limit switch reached going outwards stops it at the 78 decel
        (assumption: the manual does not say how the drive reacts to a limit input)."""
        name, t = yield _Wait(cross=self._limit_crossings(), rest=True)
        if name == "rest":
            return
        self._jog = None
        self.kin.stop(t, self.pulse_acceleration(self.params[78]))
        yield _Wait(rest=True)

    # -- multi-segment position mode (NT86 manual 3.7.4, registers 121-156, 221-271) ----------

    def _on_table_start(self, t: float) -> None:
        """USER3 (input function 24) became active in application mode 20 with 221 = 0/1:
        run segments 1..222 (assumptions where the manual is silent: the start is the
        level's rising edge; a position is absolute when 84 = 1, else relative; MOV
        stays set through the waits, the sequence being one motion)."""
        if self.params[20] != 20 or self.params[221] not in (0, 1) or not self._may_start(t):
            return
        self._estopping = False
        self._jog = None
        self._run_program(self._table(), "table", t)

    def _table(self) -> Program:
        t = self._wait_from
        unit = 1.0 if self.params[223] else 0.001
        while True:
            for k in range(self.params[222]):
                value = self._pair_value(125 + 2 * k)
                here = self._physical(t)
                target = value - self._offset if self.params[84] == 1 else here + value
                speed = self.pulse_rate(self.params[224 + 3 * k])
                rate = self.pulse_acceleration(self.params[225 + 3 * k])
                if speed > 0 and target != here:
                    if self._blocked_by_limit(1 if target > here else -1, t):
                        return
                    self._stop_decel, self._cmd_speed = rate, speed
                    self.kin.move_to(t, target, speed, rate, rate)
                    name, t = yield from self._segment()
                    if name == "limit":
                        return
                last = k == self.params[222] - 1
                wait = self.params[226 + 3 * k] * unit
                if wait > 0 and not (last and self.params[221] == 0):
                    _, t = yield _Wait(until=t + wait)
            if self.params[221] == 0:
                return

    def _segment(self) -> Generator[_Wait, tuple[str, float], tuple[str, float]]:
        """One segment to rest; a limit switch reached going outwards stops it (78)."""
        name, t = yield _Wait(cross=self._limit_crossings(), rest=True)
        if name == "limit":
            self.kin.stop(t, self.pulse_acceleration(self.params[78]))
            _, t = yield _Wait(rest=True)
        return name, t

    # -- homing (NT86: 287-298) ------------------------------------------------------------

    def _on_home_trigger(self, v: int, old: int, t: float) -> None:
        """287=4/5/6 start homing over Modbus (refused with 04 while moving etc.)."""
        if v in (4, 5, 6):
            if not self._may_start(t):
                self.params[287] = old
                raise SlaveException(4)
            self._start_homing(v, t, clear_trigger=True)

    def _start_homing(self, mode: int, t: float, *, clear_trigger: bool) -> None:
        method = self.params[288]
        if mode == 4 and method in (4, 5) and self.params[22] == 0:
            self.params[287] = 0
            raise SlaveException(4)  # hard-stop homing works only in closed loop
        self.homed = False
        self.homing_failed = False
        self._jog = None
        self._estopping = False
        self._clear_trigger = clear_trigger
        if mode == 6:
            self._set_counter(t, self._pair_value(293))
            self.homed = True
            self.params[287] = 0
            return
        self._stop_decel = self.pulse_acceleration(self.params[291])
        program = self._home_electrical() if mode == 5 else self._home_mechanical(t)
        self._run_program(program, "homing", t)

    def _homing_aborted(self) -> None:
        if self._clear_trigger:
            self.params[287] = 0

    def _homing_done(self, t: float, coordinate: int) -> None:
        """The origin is found: the counter becomes ``coordinate``; 287 clears (4/5/6)."""
        self._set_counter(t, coordinate)
        self.homed = True
        self._stalled = False
        if self._clear_trigger and 287 in self.params:
            self.params[287] = 0

    def _homing_failed(self, t: float, decel: float) -> None:
        """Homing stops without its origin (at a limit switch): decelerate to rest at
        ``decel``; HOME stays 0 and 287 clears, so a new trigger is needed (the manual's
        "stop and wait for a new trigger", 295=0/1)."""
        self.kin.stop(t, decel)
        self.homing_failed = True
        self._homing_aborted()

    def _until(
        self, direction: int, edge: float | None, reference: Span | None = None,
        *, rest: bool = False,
    ) -> Generator[_Wait, tuple[str, float], tuple[str, float]]:
        """Follow the motion just planned, travelling in ``direction``, to the first of:
        "edge" (it reaches ``edge`` going that way), "rest" (if ``rest``) or "limit" (it
        meets the limit switch ahead, at once if that one is already active), unless that
        switch is ``reference``, the signal the method homes on. With nothing to wait for
        the motor runs until stopped."""
        t = self._wait_from
        ahead = self.limit_span(direction)
        cross: list[tuple[str, float, int]] = []
        if edge is not None:
            cross.append(("edge", edge, direction))
        if ahead is not None and ahead != reference:
            if ahead.active(self._physical(t)):
                return "limit", t
            inner = ahead.edge(direction, True)
            assert inner is not None  # a limit switch's inner end is finite
            cross.append(("limit", inner, direction))
        return (yield _Wait(cross=tuple(cross), rest=rest))

    def _home_electrical(self) -> Program:
        """287=5: move to the absolute position 293/294 at speed 289 (accel 291). A limit
        switch on the way stops it, not homed (assumption: the manual is silent)."""
        t = self._wait_from
        here = self._physical(t)
        target = self._pair_value(293) - self._offset
        speed, acc = self.pulse_rate(self.params[289]), self.pulse_acceleration(self.params[291])
        if speed > 0 and acc > 0 and target != here:
            self.kin.move_to(t, target, speed, acc, acc)
            name, t = yield from self._until(1 if target > here else -1, None, rest=True)
            if name == "limit":
                self._homing_failed(t, acc)
                return
        self._homing_done(t, self._pair_value(293))

    def _reference(self, method: int) -> Span | None:
        """Where the signal 288 homes on is active: the home switch (0/1), the positive
        (2) or the negative (3) limit switch."""
        if method in (0, 1):
            return self.home_span()
        return self.limit_span(1 if method == 2 else -1)

    def _home_mechanical(self, t0: float) -> Program:
        """288=0-3: the switch search of manual 3.1.2; 288=4/5: creep into the hard stop.
        Then 295=1/3 travel the offset further; the origin's coordinate is 293/294."""
        method, handling = self.params[288], self.params[295]
        d = 1 if method in (0, 2, 4) else -1
        fast, slow = self.pulse_rate(self.params[289]), self.pulse_rate(self.params[290])
        acc = self.pulse_acceleration(self.params[291])
        if method in (4, 5):
            found = yield from self._hard_stop(d, slow, acc)
        else:
            found = yield from self._switch_search(method, d, fast, slow, acc, handling >= 2)
        if found is None:
            return  # stopped at a limit switch: not homed, 287 cleared
        t = found
        offset = self._pair_value(293)
        if handling in (1, 3) and offset:
            self.kin.move_to(t, self._physical(t) + offset, max(fast, 1.0), acc, acc)
            # A limit switch ahead stops the offset travel (assumption: the manual is silent).
            name, t = yield from self._until(1 if offset > 0 else -1, None, rest=True)
            if name == "limit":
                self._homing_failed(t, acc)
                return
        self._homing_done(t, offset)

    def _switch_search(
        self, method: int, d: int, fast: float, slow: float, acc: float, reverse_at_limit: bool
    ) -> Generator[_Wait, tuple[str, float], float | None]:
        """Manual 3.1.2 for 288=0-3, searching in direction ``d``: with the signal inactive,
        search at P289 for its rising edge and decelerate at P291 (①); with it active (②),
        or after that, back off at P290 to its falling edge and stop at once; then creep at
        P290 to the rising edge and stop at once there: the origin. A limit switch met in
        the search (③; 288=0/1, the limit ahead) stops homing with 295=0/1, and with 295=2/3
        reverses it at P289 to the signal's falling edge, decelerates and creeps back.
        Any other limit switch met, the other one after that reversal included, stops
        homing (assumption: the manual does not say; a second reversal would run on for
        ever without a home switch). The time of the origin, None if homing stopped."""
        span = self._reference(method)
        t = self._wait_from
        back_off = True
        if span is None or not span.active(self._physical(t)):
            self.kin.run(t, d * fast, acc, acc)
            name, t = yield from self._until(d, _edge_of(span, d, rising=True), span)
            if name == "limit":
                if not reverse_at_limit:
                    self._homing_failed(t, acc)
                    return None
                self.kin.run(t, -d * fast, acc, acc)
                name, t = yield from self._until(-d, _edge_of(span, -d, rising=False), span)
                if name == "limit":
                    self._homing_failed(t, acc)
                    return None
                back_off = False  # ③: past the falling edge already
            self.kin.stop(t, acc)  # decelerate at P291 past the edge
            _, t = yield _Wait(rest=True)
        assert span is not None  # an edge was reached, or the signal is active
        if back_off:
            edge = span.edge(-d, rising=False)
            self.kin.run(t, -d * slow, acc, acc)
            name, t = yield from self._until(-d, edge, span)
            if name == "limit" or edge is None:
                self._homing_failed(t, acc)
                return None
            self.kin.hold(t, edge)  # stop at once, on the edge
        return (yield from self._creep(span, d, slow, acc))

    def _creep(
        self, span: Span, d: int, slow: float, acc: float
    ) -> Generator[_Wait, tuple[str, float], float | None]:
        """Creep at P290 in direction ``d`` to the signal's rising edge and stop there at
        once (the origin's time); None if a limit switch stops homing first."""
        edge = span.edge(d, rising=True)
        self.kin.run(self._wait_from, d * slow, acc, acc)
        name, t = yield from self._until(d, edge, span)
        if name == "limit" or edge is None:
            self._homing_failed(t, acc)
            return None
        self.kin.hold(t, edge)
        return t

    def _hard_stop(
        self, d: int, slow: float, acc: float
    ) -> Generator[_Wait, tuple[str, float], float | None]:
        """Creep at 290 until the motor stalls on the end stop for 296 x 50 µs. A limit
        switch met first stops homing (assumption: the manual is silent); without an end
        stop or limit switch ahead it creeps until stopped."""
        stop = self.hard_stop_positive if d > 0 else self.hard_stop_negative
        self.kin.run(self._wait_from, d * slow, acc, acc)
        name, t = yield from self._until(d, stop)
        if name == "limit" or stop is None:
            self._homing_failed(t, acc)
            return None
        self.kin.hold(t, stop)
        self._stalled = True
        _, t = yield _Wait(until=t + self.params[296] * 50e-6)
        return t


SimEPR60: type[DescribedDrive] = twin_of(builtin_description("EPR60"))
"""Simulated Rtelligent EPR60/EPT60: the generic twin of its built-in description
(``drivebus/drives/descriptions/epr60.toml``, whose ``[twin]`` section says how it behaves)."""
