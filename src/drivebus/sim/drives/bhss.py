"""SimBHSS: simulated twin of the Bholanath BHSS-100-MBUS step-servo drive.

It answers with the manual's register map (0x0000..0x0136, gaps included), its own
exception codes (01 CRC .. 07 value out of range), its status bits and word order, and
runs motion in real time from the written speed and ramp *times*. State is computed
lazily from the ``now`` of each request. Modelled beyond plain registers:

- EEPROM: while 0x0016 = 0 (factory default) every register write is also an EEPROM
  write (``eeprom_writes`` counts them) and configuration values persist; a power cycle
  (``power_loss``/``power_restore``) reloads the registers from EEPROM, resets position,
  alarms and the homed bit, and applies the stored line settings (0x0014/0x0015).
- Inputs: the home switch is wired to X0, the positive limit to X1, the negative limit
  to X2; what the drive does with them follows the input function registers (by
  default X0 = origin, X1 = forward limit, X2 = backward limit for the switches given)
  and the active-level register 0x0040. Switch positions are physical: they stay put
  when the position counter is zeroed or homed (``position()`` is the counter,
  ``physical_position()`` the motor).
- Homing modes 0-3 as in manual §4.4; limit stops during moves (0x0017). The home switch
  is a cam from ``home_switch`` on the side the mode searches towards (0 forward, 1
  backward) unless ``home_cam`` names the side, or a dog of ``home_switch_width``.
- Alarms: ``raise_alarm(code)`` latches Err1..Err5; only Err4 clears with 0x002A,
  Err2/Err3 clear with ``supply_recovered()``, Err1/Err5 only by a power cycle.

Not modelled: the multi-position (PT) sequencer (its registers store values only),
external pulse input, the tuning registers' effect.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable

from drivebus.clock import monotonic
from drivebus.pdu import READ_HOLDING
from drivebus.settings import LineSettings
from drivebus.sim.drive import HomeCam, SimDrive, Span, TwinSetup, time_or_present
from drivebus.sim.registers import Access, ExceptionCodes, RegisterSpec, SlaveException

__all__ = ["FACTORY_SETTINGS", "SimBHSS"]

FACTORY_SETTINGS = LineSettings(baudrate=9600, bytesize=8, parity="N", stopbits=1)
"""SW6/SW7 ON with 0x0014 = 0 gives 9600; 0x0015 = 0 is 8N1 (manual §2.3.2, §2.4)."""

_SWITCH_BAUDS = (19200, 38400, 115200)  # SW7/SW6 = ON/OFF, OFF/ON, OFF/OFF
_CUSTOM_BAUDS = (9600, 14400, 128000, 256000)  # 0x0014 with SW6 = SW7 = ON
_FORMATS = ("8N1", "8N2", "8E1", "8O1")  # 0x0015
_PULSES_PER_REV = (400, 800, 1600, 3200, 6400, 12800, 25600, 51200,
                   1000, 2000, 4000, 5000, 8000, 10000, 20000, 40000)  # by 0x0011
_MAX_PULSE_RATE = 200_000.0  # pulses/s output cap
_MAP_END = 0x0136

# Exception codes (manual Table 11): 01 CRC parity error (the manual's example answers a
# bad CRC with it; its text says silence), 02 command error, 03 address unassigned inside
# the map, 04 address outside the map, 05 more than 16 registers read, 06 access error,
# 07 value out of range.
_EXCEPTION_CODES = ExceptionCodes(function=2, address=3, access=6, value=7, count=5, crc=1)
_OUTSIDE_MAP = 4


class InputFunction(enum.IntEnum):
    """Input function codes (0x0041-0x0047) that the twin acts on."""

    ORIGIN = 1
    FORWARD_LIMIT = 2
    BACKWARD_LIMIT = 3


_LIMITS = (InputFunction.FORWARD_LIMIT, InputFunction.BACKWARD_LIMIT)
_HOMING_REFERENCE = (  # by homing mode 0x0031: the input whose edges define the origin
    InputFunction.ORIGIN, InputFunction.ORIGIN, InputFunction.FORWARD_LIMIT,
    InputFunction.BACKWARD_LIMIT,
)


def _limit_towards(direction: float) -> InputFunction:
    """The limit input function that stops motion in ``direction``."""
    return InputFunction.FORWARD_LIMIT if direction > 0 else InputFunction.BACKWARD_LIMIT


def _parameter(minimum: int, maximum: int, default: int = 0) -> RegisterSpec:
    """A stored parameter: while write-through is on, a write also goes to the EEPROM."""
    return RegisterSpec(default, minimum, maximum, stored=True)


def _build_map() -> dict[int, RegisterSpec]:
    m = {a: RegisterSpec(access=Access.R) for a in range(0x0000, 0x000C)}
    rows = {
        0x0010: (0, 3, 0), 0x0011: (0, 15, 8), 0x0012: (0, 1, 0), 0x0013: (0, 127, 0),
        0x0014: (0, 3, 0), 0x0015: (0, 3, 0), 0x0016: (0, 1, 0), 0x0017: (0, 1, 0),
        0x0018: (0, 2, 0),
        0x0020: (2, 300, 5), 0x0021: (0, 2000, 100), 0x0022: (0, 2000, 100),
        0x0024: (0, 0xFFFF, 0), 0x0025: (0, 0xFFFF, 5000), 0x0026: (0, 1, 0),
        0x0031: (0, 3, 0), 0x0032: (5, 3000, 120), 0x0033: (5, 300, 60),
        0x0034: (30, 2000, 100), 0x0035: (0, 0xFFFF, 0), 0x0036: (0, 0xFFFF, 0),
        0x0040: (0, 0xFFFF, 0), 0x004B: (0, 0xFFFF, 0),
        0x0071: (0, 1, 0), 0x0072: (0, 1, 0),
    }
    for a, (lo, hi, d) in rows.items():
        m[a] = _parameter(lo, hi, d)
    m[0x0023] = RegisterSpec(60, -3000, 3000, signed=True, stored=True)
    m[0x0027] = RegisterSpec(0, 0, 6, access=Access.W, command=True)
    for a in (0x0028, 0x0029, 0x002A, 0x002B, 0x002C, 0x0030):
        m[a] = RegisterSpec(0, 0, 1, command=True)
    m[0x0070] = RegisterSpec(command=True)
    for a in range(0x0041, 0x0048):
        m[a] = _parameter(0, 20)
    for a in range(0x004C, 0x004F):
        m[a] = _parameter(0, 8)
    for base, lo, hi in ((0x80, 0, 16), (0x90, 0, 0xFFFF), (0xA0, 0, 0xFFFF), (0xB0, 10, 3000),
                         (0xC0, 30, 2000), (0xD0, 0, 0xFFFF), (0xE0, 0, 15), (0xF0, 0, 15)):
        for a in range(base, base + 16):
            m[a] = _parameter(lo, hi)
    tuning = {
        0x0110: (0, 1, 0), 0x0111: (0, 0xFFFF, 5), 0x0112: (0, 150, 100), 0x0113: (0, 100, 50),
        0x0114: (0, 100, 40), 0x0115: (100, 500, 100), 0x0116: (0, 20000, 4000),
        0x0117: (1, 4000, 10), 0x0118: (0, 1024, 5), 0x0119: (1, 256, 16),
        0x011A: (1, 256, 16), 0x011B: (0, 200, 162), 0x011C: (0, 30000, 8000),
        0x011D: (0, 1000, 48), 0x011E: (0, 0xFFFF, 358), 0x011F: (1, 200, 10),
        0x0120: (0, 1, 0), 0x0121: (0, 0xFFFF, 15360), 0x0122: (1, 50, 16),
    }
    gains = (10, 32, 320, 15, 33, 320, 20, 35, 320, 30, 38, 384, 40, 39, 512, 45, 40, 640)
    for i, d in enumerate(gains):
        tuning[0x0123 + i] = (1, 50, d) if i % 3 == 0 else (0, 0xFFFF, d)
    tuning[0x0135] = (0, 0xFFFF, 32)
    tuning[0x0136] = (0, 0xFFFF, 320)
    for a, (lo, hi, d) in tuning.items():
        m[a] = _parameter(lo, hi, d)
    return m


_MAP = _build_map()
_Handler = Callable[[float], None]


def _factory_registers() -> dict[int, int]:
    """Factory values of the stored parameters (not the status or command registers)."""
    return {a: spec.default for a, spec in _MAP.items() if spec.stored}


class _Home(enum.Enum):
    """Phases of the homing sequence (manual §4.4)."""

    IDLE = 0
    SEARCH = 1  # search speed until the reference input's rising edge
    BRAKE1 = 2  # ramp down after the rising edge
    BACKOFF = 3  # reverse until the falling edge
    BRAKE2 = 4  # ramp down after the falling edge
    CREEP = 5  # query speed until the rising edge: that is the origin
    OFFSET = 6  # compensation move


class SimBHSS(SimDrive):
    """Simulated BHSS-100-MBUS: map, exceptions, EEPROM, ramps in ms, homing, alarms."""

    family = "BHSS"
    register_map = _MAP
    exception_codes = _EXCEPTION_CODES
    read_functions = frozenset((READ_HOLDING,))
    max_read = 16

    def __init__(
        self,
        address: int,
        settings: LineSettings | None = None,
        setup: TwinSetup | None = None,
        *,
        crc_error_reply: bool = True,
        home_cam: HomeCam | None = None,
        home_switch_width: float | None = None,
    ) -> None:
        settings = settings or FACTORY_SETTINGS
        super().__init__(address, settings, setup)
        self.set_home_shape(home_cam, home_switch_width)
        self.crc_error_reply = crc_error_reply
        """Answer a bad-CRC frame with exception 01 (the manual's example) or stay silent."""
        self.regs: dict[int, int] = _factory_registers()
        self.regs[0x0043] = InputFunction.ORIGIN if self.home_switch is not None else 0
        self.regs[0x0044] = InputFunction.FORWARD_LIMIT if self.limit_positive is not None else 0
        self.regs[0x0045] = InputFunction.BACKWARD_LIMIT if self.limit_negative is not None else 0
        self._switch_baud = self._apply_line_settings(settings)
        self.eeprom: dict[int, int] = dict(self.regs)
        self.eeprom_writes = 0
        """EEPROM write cycles caused by Modbus writes (one per register written)."""
        self.homed = False
        self.reached = True  # status bit0
        self._move_active = False
        self._home = _Home.IDLE
        self._home_dir = 1.0
        self._home_accel = 1.0
        self._home_reversed = False
        self._latched_decel = math.inf
        self._last_dir = 0
        self._processed_until = 0.0  # events processed up to here
        self._last_event = -math.inf
        self._shift = 0.0
        """Position counter minus physical position (zeroing, homing, power-up)."""
        self._external = 0  # inputs driven from outside (set_input), by bit

    # -- line settings -------------------------------------------------------------------------

    def _apply_line_settings(self, settings: LineSettings) -> int | None:
        if settings.format not in _FORMATS:
            raise ValueError(f"the BHSS cannot talk {settings.format}: only {_FORMATS}")
        self.regs[0x0015] = _FORMATS.index(settings.format)
        if settings.baudrate in _SWITCH_BAUDS:
            return settings.baudrate
        if settings.baudrate in _CUSTOM_BAUDS:
            self.regs[0x0014] = _CUSTOM_BAUDS.index(settings.baudrate)
            return None
        raise ValueError(f"the BHSS cannot run at {settings.baudrate} baud")

    def _settings_from_registers(self) -> LineSettings:
        baud = self._switch_baud or _CUSTOM_BAUDS[self.regs[0x0014]]
        return LineSettings.parse(_FORMATS[self.regs[0x0015]], baudrate=baud)

    # -- what tests and the demo use -----------------------------------------------------------

    def position(self, now: float | None = None) -> int:
        """The drive's position counter (0x000A/0x000B) in whole pulses."""
        t = time_or_present(now)
        return round(self.kin.position(t) + self._shift)

    def physical_position(self, now: float | None = None) -> float:
        """Where the motor physically is (the frame of the switch positions), in pulses."""
        return self.kin.position(time_or_present(now))

    def raise_alarm(self, code: int, now: float | None = None) -> None:
        """Latch alarm Err``code`` (1..5): the drive locks and the motor stops at once."""
        if not 1 <= code <= 5:
            raise ValueError(f"BHSS alarm codes are 1..5, not {code}")
        t = time_or_present(now)
        self.advance(t)
        super().raise_alarm(code, t)
        self._end_motion()

    def supply_recovered(self) -> None:
        """The supply voltage is back in range: Err2/Err3 clear by themselves."""
        if self.alarm_code in (2, 3):
            self.alarm_code = 0

    def power_loss(self) -> None:
        """Power off: motion and RAM values are lost."""
        self.advance(monotonic())
        super().power_loss()
        self._end_motion()

    def power_restore(self) -> None:
        """Power on: registers from EEPROM, position 0, alarms cleared, settings applied."""
        super().power_restore()
        self.regs = dict(self.eeprom)
        self.settings = self._settings_from_registers()
        now = monotonic()
        self.kin.hold(now)
        self._shift = -self.kin.position(now)  # the counter starts at 0
        self.alarm_code = 0
        self.enabled = True
        self.homed = False
        self.reached = True
        self._end_motion()

    # -- protocol --------------------------------------------------------------------------------

    def check_count(self, count: int) -> None:
        """More than 16 registers is exception 05; a read of none reads nothing assigned (03)."""
        if count < 1:
            raise SlaveException(self.exception_codes.address)
        super().check_count(count)

    def register(self, address: int) -> RegisterSpec:
        """Past the end of the map is exception 04; unassigned inside it, 03."""
        if address > _MAP_END:
            raise SlaveException(_OUTSIDE_MAP)
        return super().register(address)

    def check_word(self, address: int, word: int) -> int:
        """Access and range; the start command also refuses mode 3 in bits 0-1."""
        value = super().check_word(address, word)
        if address == 0x0027 and value & 3 == 3:
            raise SlaveException(self.exception_codes.value)
        return value

    def write_register(self, address: int, word: int, now: float) -> None:
        """Store a parameter (with write-through on, also in the EEPROM) or run a command."""
        spec = _MAP[address]
        if self.regs[0x0016] == 0:  # write-through on before this write
            self.eeprom_writes += 1
            if spec.stored:
                self.eeprom[address] = word
        if spec.command:
            self._command(address, word, now)
        else:
            self.regs[address] = word

    # -- register values ---------------------------------------------------------------------------

    def read_register(self, address: int, now: float) -> int:
        """A stored parameter, the enable state, 0 for a command, or a status register."""
        if address in self.regs:
            return self.regs[address]
        if address == 0x0029:
            return int(self.enabled)
        if _MAP[address].command:
            return 0
        return self._status_value(address, now)

    def _status_value(self, a: int, now: float) -> int:
        moving = self.is_moving(now)
        if a == 0x0000:
            return 0x0305
        if a == 0x0001:
            return 0x0101
        if a == 0x0002:
            return self.address
        if a == 0x0003:
            return 1 if self._home is not _Home.IDLE else 0
        if a == 0x0004:
            return int(moving)
        if a == 0x0005:
            return 1 if self._last_dir < 0 else 0
        if a == 0x0006:
            return self.alarm_code
        if a == 0x0007:
            return self.status_bits(now)
        if a == 0x0008:
            return sum(1 << i for i in range(7) if self._input(i, self.kin.position(now)))
        if a == 0x0009:
            return self._outputs(now)
        pos = self.position(now) & 0xFFFFFFFF
        return pos >> 16 if a == 0x000A else pos & 0xFFFF

    def status_bits(self, now: float) -> int:
        """Register 0x0007 at ``now``."""
        moving = self.is_moving(now)
        bits = 0
        if self.reached and not moving:
            bits |= 1 << 0
        if self.homed:
            bits |= 1 << 1
        if moving:
            bits |= 1 << 2
        if self.alarm_code:
            bits |= 1 << 3
        if not self.enabled:
            bits |= 1 << 4
        if not moving:
            bits |= 1 << 5
        return bits

    def _outputs(self, now: float) -> int:
        bits = self.status_bits(now)
        signal = {1: bool(bits & 8), 2: bool(bits & 4), 3: self.homed, 4: bool(bits & 1)}
        return sum(1 << i for i in range(3) if signal.get(self.regs[0x004C + i], False))

    # -- inputs ------------------------------------------------------------------------------------

    def home_side(self) -> int:
        """The default home cam side: the direction of the homing mode (0x0031: 0/2
        forward, 1/3 backward)."""
        return -1 if self.regs[0x0031] in (1, 3) else 1

    def _span(self, index: int) -> Span | None:
        """Where the switch on input ``index`` (X0 home, X1 +limit, X2 -limit) is active."""
        if index == 2:
            return self.home_span()
        if index in (3, 4):
            return self.limit_span(1 if index == 3 else -1)
        return None

    def _physical(self, index: int, p: float) -> bool:
        """Switch state of input ``index`` (PU, DR, X0..X4) at position ``p``."""
        if self._external >> index & 1:
            return True
        span = self._span(index)
        return span is not None and span.active(p)

    def set_input(self, index: int, on: bool) -> None:
        """Drive input ``index`` (0 PU, 1 DR, 2-6 X0-X4) from outside: a sensor or a PLC
        wired to it (on top of the switches given in the setup)."""
        if not 0 <= index <= 6:
            raise ValueError(f"input {index}: the BHSS has inputs 0..6 (PU, DR, X0..X4)")
        bit = 1 << index
        self._external = self._external | bit if on else self._external & ~bit

    def _thresholds(self, index: int) -> tuple[float, ...]:
        """The positions where input ``index``'s switch changes state."""
        span = self._span(index)
        return () if span is None else tuple(x for x in (span.lo, span.hi) if math.isfinite(x))

    def _input(self, index: int, p: float) -> bool:
        """Valid level of input ``index`` at position ``p`` (after 0x0040's inversion)."""
        return self._physical(index, p) != bool(self.regs[0x0040] >> index & 1)

    def _inputs_with(self, function: int) -> list[int]:
        return [i for i in range(7) if self.regs[0x0041 + i] == function]

    def _function_active(self, function: int, p: float) -> bool:
        return any(self._input(i, p) for i in self._inputs_with(function))

    def _edge(self, function: int, rising: bool, t0: float, t1: float) -> float | None:
        """First time in [t0, t1] an input with ``function`` turns valid (or invalid)."""
        times = [self._input_edge(i, rising, t0, t1) for i in self._inputs_with(function)]
        found = [t for t in times if t is not None]
        return min(found) if found else None

    def _input_edge(self, index: int, rising: bool, t0: float, t1: float) -> float | None:
        """First time in [t0, t1] input ``index`` turns valid (``rising``) or invalid."""
        found = [self._threshold_edge(index, x, rising, t0, t1) for x in self._thresholds(index)]
        times = [t for t in found if t is not None]
        return min(times) if times else None

    def _threshold_edge(
        self, index: int, x: float, rising: bool, t0: float, t1: float
    ) -> float | None:
        """First time in [t0, t1] input ``index`` turns valid (or invalid) passing ``x``."""
        t = t0
        while t <= t1:
            tc = self.kin.crossing(x, t, t1)
            if tc is None:
                return self._boundary_edge(index, rising, t, t1)
            # Which way the motor passes x: at a start from rest (or a turnaround) the
            # velocity at tc is 0 and the way it leaves counts. If it stays at rest there
            # (a move that ended on the switch's edge, from either side), nothing crosses.
            v = self.kin.velocity(tc) or self.kin.velocity(tc + 1e-6)
            if v == 0.0:
                return None
            step = math.copysign(0.5, v)
            before, after = self._input(index, x - step), self._input(index, x + step)
            if before != after and after == rising:
                return tc
            t = tc + 1e-6
        return None

    def _level(self, index: int, t: float) -> bool:
        """Valid level of input ``index`` where the motor is at time ``t``."""
        return self._input(index, self.kin.position(t))

    def _boundary_edge(self, index: int, rising: bool, t0: float, t1: float) -> float | None:
        """An edge in [t0, t1] that ``Kinematics.crossing`` did not report, else None.

        ``crossing`` looks for a sign change inside each motion segment. When the switch
        sits exactly where one segment hands over to the next, rounding can leave the
        first segment's end a hair on one side of it and the next segment's start on the
        other, so neither segment sees the crossing. That is the normal case in homing:
        the back-off accelerates over exactly the distance the search braked over, so it
        reaches search speed right at the reference edge. ``crossing`` now accepts a start
        within 1e-6 pulses of ``x``, but the jump is speed times the clock's rounding and
        grows with both, so comparing the input level at both ends still backs it up;
        bisection finds the time of the edge.
        """
        start = self._level(index, t0)
        if start == self._level(index, t1) or self._level(index, t1) != rising:
            return None
        lo, hi = t0, t1
        for _ in range(64):
            mid = 0.5 * (lo + hi)
            if mid in (lo, hi):
                break
            if self._level(index, mid) == start:
                lo = mid
            else:
                hi = mid
        return hi

    # -- motion ------------------------------------------------------------------------------------

    @property
    def pulses_per_rev(self) -> int:
        """The resolution chosen in 0x0011."""
        return _PULSES_PER_REV[self.regs[0x0011]]

    def _pps(self, rpm: float) -> float:
        """Pulses/s for ``rpm`` (either sign) at the resolution, capped at 200 kHz."""
        return min(self.pulse_rate(abs(rpm)), _MAX_PULSE_RATE)

    def _ramp_rate(self, pps: float, ms: int) -> float:
        """Acceleration (pulses/s²) that ramps to ``pps`` in ``ms`` milliseconds."""
        return pps / max(ms / 1000.0, 0.001)

    def _can_move(self) -> bool:
        return self.enabled and not self.alarm_code and self.regs[0x0018] == 0

    def _end_motion(self) -> None:
        self._move_active = False
        self._home = _Home.IDLE

    def _max_speed(self) -> int:
        v = self.regs[0x0023]
        return v - 0x10000 if v & 0x8000 else v

    def _command(self, a: int, v: int, now: float) -> None:
        if a == 0x0027:
            self._start(v, now)
        elif a == 0x0028:
            self._stop(now, emergency=bool(v))
        elif a == 0x0029:
            self.enabled = bool(v)
            if not v:
                self.kin.stop(now, None)
                self._end_motion()
        elif a == 0x002A and v and self.alarm_code == 4:
            self.alarm_code = 0
        elif a == 0x002B and v:
            self.regs = _factory_registers()
            self.eeprom = dict(self.regs)
        elif a == 0x002C and v:
            self._shift = -self.kin.position(now)
        elif a == 0x0030 and v:
            self._start_homing(now)

    def _start(self, v: int, now: float) -> None:
        if not self._can_move() or self._home is not _Home.IDLE:
            return
        speed = self._max_speed()
        pps = self._pps(speed)
        acc = self._ramp_rate(pps, self.regs[0x0021])
        dec = self._ramp_rate(pps, self.regs[0x0022])
        if v & 3 == 2:  # speed mode: the sign of 0x0023 is the direction
            if pps == 0:
                self._stop(now, emergency=False)
                return
            signed = math.copysign(pps, speed)
            if self._function_active(_limit_towards(signed), self.kin.position(now)):
                return
            self._latched_decel = dec
            self.kin.run(now, signed, acc, dec)
            self._move_active = False
            self.reached = False
            self._last_dir = 1 if signed > 0 else -1
        elif v & 3 == 1 and pps > 0:
            d = self.regs[0x0024] << 16 | self.regs[0x0025]
            d = d - (1 << 32) if d & 0x80000000 else d
            here = self.kin.target if self.kin.target is not None else self.kin.position(now)
            target = d - self._shift if v & 4 else here + d
            direction = 1 if target > self.kin.position(now) else -1
            if self._function_active(_limit_towards(direction), self.kin.position(now)):
                return
            self._latched_decel = dec
            self.kin.move_to(now, target, pps, acc, dec)
            self._move_active = True
            self.reached = False
            self._last_dir = direction

    def _stop(self, now: float, *, emergency: bool) -> None:
        if self.is_moving(now):
            self.kin.stop(now, None if emergency else self._latched_decel)
        self._end_motion()

    def _start_homing(self, now: float) -> None:
        if not self._can_move() or self.is_moving(now):
            return
        mode = self.regs[0x0031]
        pps = self._pps(self.regs[0x0032])
        self._home_accel = self._ramp_rate(pps, self.regs[0x0034])
        self._home_dir = 1.0 if mode in (0, 2) else -1.0
        self.homed = False
        self.homing_failed = False
        self.reached = False
        self._move_active = False
        self._home_reversed = False
        p = self.kin.position(now)
        if self._function_active(self._reference(), p):
            # On the reference input already: the manual does not say; the twin backs off
            # to its falling edge first, as the NT86's and CL86R's manuals do.
            self._home = _Home.BRAKE1
            self._on_home_ramp_end(now)
            return
        self._home = _Home.SEARCH
        ahead = _limit_towards(self._home_dir)
        if ahead != self._reference() and self._function_active(ahead, p):
            self._home_dir = -self._home_dir  # on a limit already: "the turning will reverse"
            self._home_reversed = True
        self.kin.run(now, self._home_dir * pps, self._home_accel, self._home_accel)
        self._last_dir = int(self._home_dir)

    def _reference(self) -> int:
        """Input function whose edges define the origin in the present homing mode."""
        return _HOMING_REFERENCE[self.regs[0x0031]]

    # -- lazy event processing ---------------------------------------------------------------------

    def advance(self, now: float) -> None:
        """Run the drive's reactions (edges, limits, ends of ramps) up to ``now``."""
        for _ in range(64):
            t_from = max(self._processed_until, self._last_event + 1e-6)
            event = self._next_event(t_from, now)
            if event is None:
                break
            t, handler = event
            self._last_event = t
            handler(t)
        self._processed_until = max(self._processed_until, now)

    def _next_event(self, t0: float, t1: float) -> tuple[float, _Handler] | None:
        if t1 < t0:
            return None
        end = self.kin.end_time()
        phase = self._home
        reference = self._reference()
        if phase is _Home.SEARCH:
            return self._first(
                (self._edge(reference, True, t0, t1), self._on_reference_found),
                *self._homing_limits(t0, t1, reverse=not self._home_reversed),
            )
        if phase is _Home.BACKOFF:
            return self._first((self._edge(reference, False, t0, t1), self._on_falling),
                               *self._homing_limits(t0, t1))
        if phase is _Home.CREEP:
            return self._first((self._edge(reference, True, t0, t1), self._on_origin),
                               *self._homing_limits(t0, t1))
        if phase is _Home.OFFSET:
            return self._first((end if end <= t1 else None, self._on_home_ramp_end),
                               *self._homing_limits(t0, t1, offset=True))
        if phase in (_Home.BRAKE1, _Home.BRAKE2):
            return (end, self._on_home_ramp_end) if end <= t1 else None
        if self.is_moving(t0):
            return self._first(
                *((self._edge(limit, True, t0, t1), self._on_limit_stop) for limit in _LIMITS),
                (end if self._move_active and end <= t1 else None, self._on_move_done),
            )
        if self._move_active:
            return (max(end, t0), self._on_move_done)
        return None

    def _homing_limits(
        self, t0: float, t1: float, *, reverse: bool = False, offset: bool = False
    ) -> list[tuple[float | None, _Handler]]:
        """The limit inputs turning valid in [t0, t1] while homing, but the one homed on
        (in the compensation move, that one too): the search reverses at the first one
        (manual §4.4, L1184) if ``reverse``; any other stops homing."""
        handler = self._on_limit_reverse if reverse else self._on_homing_limit_stop
        return [(self._edge(limit, True, t0, t1), handler) for limit in _LIMITS
                if offset or limit != self._reference()]

    @staticmethod
    def _first(*candidates: tuple[float | None, _Handler]) -> tuple[float, _Handler] | None:
        found = [(t, h) for t, h in candidates if t is not None]
        return min(found, key=lambda c: c[0]) if found else None

    def _on_move_done(self, t: float) -> None:
        self._move_active = False
        self.reached = True

    def _on_limit_stop(self, t: float) -> None:
        emergency = self.regs[0x0017] == 1
        self.kin.stop(t, None if emergency else self._latched_decel)
        self._move_active = False

    def _on_limit_reverse(self, t: float) -> None:
        self._home_reversed = True
        self._home_dir = -self._home_dir
        pps = self._pps(self.regs[0x0032])
        self.kin.run(t, self._home_dir * pps, self._home_accel, self._home_accel)
        self._last_dir = int(self._home_dir)

    def _on_homing_limit_stop(self, t: float) -> None:
        """A limit input met while homing, other than the search's first one: the manual
        says only that the search reverses at a limit, not what follows (the other limit
        after that reversal, or one met backing off, creeping or compensating). The twin
        stops as 0x0017 says (0: ramp down at 0x0034's rate, 1: at once) and homing
        fails: reversing again would run between the limits for ever."""
        emergency = self.regs[0x0017] == 1
        self.kin.stop(t, None if emergency else self._home_accel)
        self._home = _Home.IDLE
        self.homing_failed = True

    def _on_reference_found(self, t: float) -> None:
        self.kin.stop(t, self._home_accel)
        self._home = _Home.BRAKE1

    def _on_falling(self, t: float) -> None:
        self.kin.stop(t, self._home_accel)
        self._home = _Home.BRAKE2

    def _on_home_ramp_end(self, t: float) -> None:
        if self._home is _Home.BRAKE1:
            self._home = _Home.BACKOFF
            pps = -self._home_dir * self._pps(self.regs[0x0032])
        elif self._home is _Home.BRAKE2:
            self._home = _Home.CREEP
            pps = self._home_dir * self._pps(self.regs[0x0033])
        else:
            self._finish_homing()
            return
        self.kin.run(t, pps, self._home_accel, self._home_accel)
        self._last_dir = 1 if pps > 0 else -1

    def _on_origin(self, t: float) -> None:
        # The manual does not say whether the counter is zeroed at the origin; the twin
        # zeroes it at the edge (absolute moves count from the origin, L452) and then runs
        # the compensation move, so the position after homing reads the offset.
        self.kin.hold(t)
        self._shift = -self.kin.position(t)
        offset = self.regs[0x0035] - self.regs[0x0036]
        if offset and self._function_active(
            _limit_towards(offset), self.kin.position(t) + math.copysign(0.5, offset)
        ):
            self._on_homing_limit_stop(t)  # the compensation would go into a limit switch
            return
        if offset:
            self._home = _Home.OFFSET
            creep = self._pps(self.regs[0x0033])
            target = self.kin.position(t) + offset
            self.kin.move_to(t, target, creep, self._home_accel, self._home_accel)
            self._last_dir = 1 if offset > 0 else -1
        else:
            self._finish_homing()

    def _finish_homing(self) -> None:
        self._home = _Home.IDLE
        self.homed = True
        self.reached = True
