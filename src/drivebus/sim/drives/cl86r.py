"""SimCL86R: a simulated CL86R closed-loop stepper drive (register map and behaviour per manual).

The register table here is written from the manual independently of the profile, so a
wrong address or word order in the profile shows up in tests. Where the manual is silent
the twin makes a documented choice:

* the control word acts on every write (not only on a rising edge); it keeps the value;
* accel/decel times are the time from standstill to the maximum speed (0x0033; 0x0041
  when homing); the start speed (0x0030) is stored but not modelled as a speed step;
* a speed-mode start while speed mode runs changes the speed on the fly;
* a new positioning, speed or homing start while the motor moves is ignored unless
  control bit 2 (interrupt) is set; a speed change in speed mode is always taken;
* motion starts are ignored while the motor is released or an alarm is latched; an alarm
  stops the motor at once and clears only with 0x0037 = 0x0004;
* a limit input stops a position or speed move (0x0025: 0 = decelerate, 1 = at once) and
  a start towards an active limit is ignored; while homing, a limit the manual's
  sequence does not name (any but 18's P-OT, 17's N-OT, and the one 24/29 reverse at
  in their search) stops the motor the same way and homing fails (``homing_failed``):
  the manual does not say what the drive does there;
* homing ends on the origin edge with a decelerating stop; the position at the edge
  becomes the origin offset (0x0044/0x0045, CiA-402 reading); mode 35 just sets it;
* the position counter is 32-bit: it wraps from 2^31-1 to -2^31;
* a frame with a bad CRC is answered with exception 04 (the manual's "CRC check error").

The home switch is a cam from ``home_switch`` on the side the homing mode searches
towards (29 negative, else positive; ``home_cam`` names the side instead) or, with
``home_switch_width``, a dog covering ``[home_switch, home_switch + width]``; 24(b) and
29(b), homing via the limit, need a dog behind the start. Baud rate is the DIP-switch
setting (``settings``; factory default taken as all switches ON = 9600, fixed 8N1); at
19200 and up the format is 0x0021, which takes effect at the next power-up.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from drivebus.clock import monotonic
from drivebus.errors import ConfigError
from drivebus.pdu import READ_HOLDING
from drivebus.settings import LineSettings
from drivebus.sim.drive import HomeCam, SimDrive, Span, TwinSetup, time_or_present
from drivebus.sim.registers import Access, ExceptionCodes, RegisterSpec, signed16, signed32

__all__ = ["SimCL86R"]

_BAUDS = (9600, 19200, 38400, 115200)
_FORMATS = ("8N1", "8N2", "8E1", "8O1")  # index = value of 0x0021

# Control word 0x0036 / auxiliary 0x0037 / status 0x0003 bits, written out from the manual.
_START, _ABS, _INTERRUPT, _SPEED, _HOME, _STOP, _ESTOP = 1, 2, 4, 8, 16, 32, 64
_AUX_RESET, _AUX_SAVE, _AUX_CLEAR, _AUX_ZERO = 1, 2, 4, 8
_MODE_NONE, _MODE_POSITION, _MODE_SPEED, _MODE_HOMING = 0, 1, 2, 3


def _table() -> dict[int, RegisterSpec]:
    """The parameter registers: factory value, range, RW/S (stored to the EEPROM on write
    while 0x0024 = 1), signed."""
    t = {
        0x0010: RegisterSpec(0, 0, 127, stored=True),  # manual prints 0~7 for a 7-bit mask
        0x0011: RegisterSpec(2, 0, 1000),
        0x0012: RegisterSpec(0, 0, 7, stored=True),
        0x0020: RegisterSpec(1, 1, 31, stored=True),
        0x0021: RegisterSpec(0, 0, 3, stored=True),
        0x0022: RegisterSpec(0, 0, 1, stored=True),
        0x0023: RegisterSpec(1000, 400, 51200, stored=True),
        0x0024: RegisterSpec(0, 0, 1, stored=True),
        0x0025: RegisterSpec(0, 0, 1, stored=True),
        0x0030: RegisterSpec(5, 2, 300),
        0x0031: RegisterSpec(100, 1, 2000),
        0x0032: RegisterSpec(100, 1, 2000),
        0x0033: RegisterSpec(60, -3000, 3000, signed=True),
        0x0034: RegisterSpec(0, 0, 0xFFFF),
        0x0035: RegisterSpec(5000, 0, 0xFFFF),
        0x0036: RegisterSpec(0, 0, 127),
        0x0037: RegisterSpec(0, 0, 8),
        0x0038: RegisterSpec(1, 0, 1),
        0x0039: RegisterSpec(0, 0, 1),
        0x003A: RegisterSpec(0, 0, 1),
        0x0040: RegisterSpec(0, 0, 35, stored=True),
        0x0041: RegisterSpec(120, 5, 3000, stored=True),
        0x0042: RegisterSpec(60, 5, 300, stored=True),
        0x0043: RegisterSpec(200, 1, 2000, stored=True),
        0x0044: RegisterSpec(0, 0, 0xFFFF, stored=True),
        0x0045: RegisterSpec(0, 0, 0xFFFF, stored=True),
        0x0046: RegisterSpec(60, 0, 3000),
        0x0047: RegisterSpec(100, 1, 2000),
        0x0048: RegisterSpec(100, 1, 2000),
        0x0050: RegisterSpec(1, 0, 1, stored=True),
        0x0051: RegisterSpec(0, 0, 1),
        0x0052: RegisterSpec(4000, 400, 65535, stored=True),
        0x0053: RegisterSpec(42, 0, 80, stored=True),
        0x0054: RegisterSpec(75, 0, 80, stored=True),
        0x0055: RegisterSpec(56, 0, 80, stored=True),
        0x0056: RegisterSpec(60, 0, 1024, stored=True),
        0x0057: RegisterSpec(1000, 1000, 1000, stored=True),  # "cannot be modified"
        0x0058: RegisterSpec(200, 200, 200, stored=True),  # "cannot be modified"
        0x0059: RegisterSpec(300, 0, 1000, stored=True),
        0x005A: RegisterSpec(400, 0, 1000, stored=True),
        0x005B: RegisterSpec(80, 0, 300, stored=True),
        0x005C: RegisterSpec(10, 1, 200, stored=True),
        0x005D: RegisterSpec(5, 1, 1000, stored=True),
    }
    for i, fn in enumerate((1, 2, 3, 0, 0, 0, 0)):
        t[0x0013 + i] = RegisterSpec(fn, 0, 16)
    for i, fn in enumerate((1, 2, 4)):
        t[0x001A + i] = RegisterSpec(fn, 0, 5)
    for n in range(16):
        t[0x0060 + n] = RegisterSpec(0, 0, 0xFFFF)
        t[0x0070 + n] = RegisterSpec(5000, 0, 0xFFFF)
        t[0x0080 + n] = RegisterSpec(120, 0, 3000)
        t[0x0090 + n] = RegisterSpec(100, 1, 2000)
        t[0x00A0 + n] = RegisterSpec(100, 1, 2000)
        t[0x00B0 + n] = RegisterSpec(120, -3000, 3000, signed=True)
        t[0x00C0 + n] = RegisterSpec(100, 1, 2000)
        t[0x00D0 + n] = RegisterSpec(100, 1, 2000)
    return t


_PARAMETERS = _table()
_MONITOR = range(0x0000, 0x000A)  # read-only, computed at read time
_MAP = {**{a: RegisterSpec(access=Access.R) for a in _MONITOR}, **_PARAMETERS}


def _factory_values() -> dict[int, int]:
    """The parameter registers' factory values as words."""
    return {a: spec.default & 0xFFFF for a, spec in _PARAMETERS.items()}


class _Signal(enum.IntEnum):
    """A switch input, by its DI function code (the drive sees it where it is wired)."""

    HOME = 1
    LIMIT_POSITIVE = 2
    LIMIT_NEGATIVE = 3


_H, _P, _N = _Signal.HOME, _Signal.LIMIT_POSITIVE, _Signal.LIMIT_NEGATIVE


@dataclass(frozen=True)
class _Phase:
    """One leg of a homing method: run in ``direction`` at high or creep speed until one
    of ``events``' switches turns active (rising) or inactive, then go to the named leg
    (or "done")."""

    direction: int
    fast: bool
    events: tuple[tuple[_Signal, bool, str], ...]  # (switch, rising, next leg)


@dataclass
class _Homing:
    phases: dict[str, _Phase]
    phase: str
    t_dir: float  # from when the motor runs in the phase's direction


class SimCL86R(SimDrive):
    """Simulated CL86R: registers 0x0000-0x00DF, control word 0x0036, homing 17/18/24/29/35.

    ``soft_address``: DIP switches SW1-SW5 all ON, so the address is register 0x0020's
    (saved, taken at power-up), as ``drivebus commission`` sets it."""

    family = "CL86R"
    register_map = _MAP
    exception_codes = ExceptionCodes(crc=0x04)  # "CRC check error"
    read_functions = frozenset((READ_HOLDING,))

    def __init__(
        self,
        address: int,
        settings: LineSettings | None = None,
        setup: TwinSetup | None = None,
        *,
        home_switch_width: float | None = None,
        home_cam: HomeCam | None = None,
        crc_error_reply: bool = True,
        model: int = 862,
        software: int = 100,
        soft_address: bool = False,
    ) -> None:
        settings = settings or LineSettings.parse("9600 8N1")
        _check_line(settings)
        super().__init__(address, settings, setup)
        self.set_home_shape(home_cam, home_switch_width)
        self.crc_error_reply = crc_error_reply
        self.model = model
        self.software = software
        self.regs = _factory_values()
        self.regs[0x0021] = _FORMATS.index(settings.format) if settings.baudrate != 9600 else 0
        self.soft_address = soft_address
        """DIP switches SW1-SW5 all ON: the address is 0x0020's, taken at power-up."""
        if soft_address:
            self.regs[0x0020] = address
        self.eeprom = dict(self.regs)
        """Parameter values that survive a power cycle."""
        self.enabled = self.regs[0x0038] == 1
        self.mode = _MODE_NONE
        self.homed = False
        self._external = 0  # X0..X6 driven from outside (set_input), by bit
        self._homing: _Homing | None = None
        self._watch_from = 0.0
        self._shift = 0.0
        """Counter minus physical position: zeroing and homing move the counter, not the
        switches (whose positions are physical, in the initial counter's pulses)."""

    # -- switches and units ---------------------------------------------------------------------

    def position(self, now: float | None = None) -> int:
        """The drive's 32-bit position counter (it wraps at ±2^31)."""
        return signed32(super().position(now))

    def physical_position(self, now: float | None = None) -> float:
        """Where the axis physically is (the frame of the switch positions)."""
        return self.kin.position(time_or_present(now)) - self._shift

    def _set_counter(self, t: float, value: float) -> None:
        """Redefine the position counter at ``t`` as ``value`` (the axis does not move)."""
        old = self.kin.position(t)
        self.kin.set_position(t, value)
        self._shift += value - old

    def switch_states(self, now: float) -> tuple[bool, bool, bool]:
        """(home, limit negative, limit positive) at the physical position."""
        return self.switches_at(self.physical_position(now))

    def home_side(self) -> int:
        """The default home cam side: negative for mode 29, else positive."""
        return -1 if self.regs[0x0040] == 29 else 1

    def _wired(self, function: int) -> bool:
        """True if some input X0..X6 is assigned DI ``function`` (1 home, 2 +limit, 3 -limit)."""
        return any(self.regs[0x0013 + i] == function for i in range(7))

    @property
    def pulses_per_rev(self) -> int:
        """The microstep setting 0x0023."""
        return self.regs[0x0023]

    def _ramp_rate(self, speed_rpm: float, ms: int) -> float:
        """pulses/s² of a ramp reaching ``speed_rpm`` in ``ms``."""
        return self.pulse_rate(abs(speed_rpm)) / (ms / 1000.0)

    def _ramps(self, speed_rpm: float) -> tuple[float, float]:
        """Acceleration and deceleration (pulses/s²) of a move at ``speed_rpm``: the ramp
        times 0x0031/0x0032 reach it from standstill."""
        return (self._ramp_rate(speed_rpm, self.regs[0x0031]),
                self._ramp_rate(speed_rpm, self.regs[0x0032]))

    def _home_rate(self) -> float:
        return self._ramp_rate(self.regs[0x0041], self.regs[0x0043])

    def _span(self, signal: _Signal) -> Span | None:
        """Where ``signal``'s switch is active (physical), if the drive can see it."""
        if not self._wired(signal):
            return None
        if signal is _H:
            return self.home_span()
        return self.limit_span(1 if signal is _P else -1)

    def _boundary(self, signal: _Signal, direction: int, rising: bool) -> float | None:
        """Counter position where a motor travelling in ``direction`` sees ``signal``
        turn active (``rising``) or inactive; None if it cannot."""
        span = self._span(signal)
        edge = None if span is None else span.edge(direction, rising)
        return None if edge is None else edge + self._shift

    # -- registers ------------------------------------------------------------------------------

    def _status(self, now: float) -> int:
        """Status register 0x0003: in position, homed, moving, alarm, enabled."""
        moving = self.kin.moving(now)
        return (
            (0x01 if not moving and not self.alarm_code else 0)
            | (0x02 if self.homed else 0)
            | (0x04 if moving else 0)
            | (0x08 if self.alarm_code else 0)
            | (0x10 if self.enabled else 0)
        )

    def _inputs(self, now: float) -> int:
        """Input terminals 0x0005: each input's function's level, XOR its inversion bit."""
        home, neg, pos = self.switch_states(now)
        active = {1: home, 2: pos, 3: neg}
        inputs = self._external
        for i in range(7):
            if active.get(self.regs[0x0013 + i], False):
                inputs |= 1 << i
        return inputs ^ (self.regs[0x0010] & 0x7F)  # terminal state = logical level ^ inversion

    def set_input(self, index: int, closed: bool) -> None:
        """Drive input X``index`` (0-6) from outside: a sensor or a PLC wired to it (the
        switches given in the setup stay as they are)."""
        if not 0 <= index <= 6:
            raise ConfigError(f"X{index}: the CL86R has inputs X0..X6")
        bit = 1 << index
        self._external = self._external | bit if closed else self._external & ~bit

    def _outputs(self, now: float) -> int:
        """Output terminals 0x0006: each output's function's signal, XOR its inversion bit."""
        status = self._status(now)
        signals = {1: bool(self.alarm_code), 2: bool(status & 0x04), 3: self.homed,
                   4: bool(status & 0x01), 5: self.enabled}
        outputs = 0
        for i in range(3):
            if signals.get(self.regs[0x001A + i], False):
                outputs |= 1 << i
        return outputs ^ (self.regs[0x0012] & 0x07)

    def _monitor(self, address: int, now: float) -> int:
        """Monitor register ``address`` (0x0000-0x0009), computed at ``now``."""
        if address == 0x0000:
            return self.model
        if address == 0x0001:
            return self.software
        if address == 0x0002:
            return self.mode
        if address == 0x0003:
            return self._status(now)
        if address == 0x0004:
            return self.alarm_code
        if address == 0x0005:
            return self._inputs(now)
        if address == 0x0006:
            return self._outputs(now)
        if address in (0x0007, 0x0008):  # position counter, high word first
            counter = round(self.kin.position(now)) & 0xFFFFFFFF
            return counter >> 16 if address == 0x0007 else counter & 0xFFFF
        return round(self.speed_rpm(now))  # 0x0009, signed

    def read_register(self, address: int, now: float) -> int:
        """A monitor register (computed at read time) or a parameter."""
        if address in _MONITOR:
            return self._monitor(address, now)
        return self.regs[address]

    def write_register(self, address: int, word: int, now: float) -> None:
        """Store the parameter (RW/S ones also in the EEPROM while 0x0024 = 1), then act."""
        self.regs[address] = word
        if _MAP[address].stored and self.regs[0x0024] == 1:
            self.eeprom[address] = word
        self._effect(address, word, now)

    def _effect(self, address: int, value: int, now: float) -> None:
        if address == 0x0036:
            self._control(value, now)
        elif address == 0x0037:
            self._aux(value, now)
        elif address == 0x0038:
            self.enabled = value == 1
            if not self.enabled:
                self._homing = None
                self.kin.stop(now, None)  # released: the shaft is free, motion ends

    # -- commands -------------------------------------------------------------------------------

    def _aux(self, value: int, now: float) -> None:
        if value & _AUX_RESET:
            self.regs.update(_factory_values())
            self.eeprom.update(self.regs)
        if value & _AUX_SAVE:
            self.eeprom.update(self.regs)
        if value & _AUX_CLEAR:
            self.alarm_code = 0
        if value & _AUX_ZERO:
            self._set_counter(now, 0)

    def _control(self, word: int, now: float) -> None:
        if word & _ESTOP:
            self._homing = None
            self.kin.stop(now, None)
        elif word & _STOP:
            self._homing = None
            self.kin.stop(now, self._stop_rate(now))
        elif not self.enabled or self.alarm_code:
            return  # the drive does not start anything
        elif word & _HOME:
            self._start_homing(word, now)
        elif word & _SPEED:
            self._start_speed(word, now)
        elif word & _START:
            self._start_position(word, now)

    def _stop_rate(self, now: float) -> float:
        if self.mode == _MODE_HOMING:
            return self._home_rate()
        speed = abs(signed16(self.regs[0x0033]))
        ref = speed or abs(self.speed_rpm(now))
        return self._ramp_rate(ref, self.regs[0x0032]) if ref else math.inf

    def _busy(self, word: int, now: float) -> bool:
        """True if a start must be ignored: moving, and no interrupt bit."""
        return self.kin.moving(now) and not word & _INTERRUPT

    def _wrap(self, now: float) -> float:
        """Keep the 32-bit position counter in range; the present position."""
        p = self.kin.position(now)
        wrapped = signed32(round(p))
        if wrapped != round(p):
            self._set_counter(now, p + (wrapped - round(p)))
        return self.kin.position(now)

    def _blocked(self, direction: float, now: float) -> bool:
        """True if a limit input in ``direction`` is active (the drive will not go on)."""
        _, neg, pos = self.switch_states(now)
        return (direction > 0 and pos and self._wired(2)) or (
            direction < 0 and neg and self._wired(3)
        )

    def _start_position(self, word: int, now: float) -> None:
        speed = abs(signed16(self.regs[0x0033]))
        if speed == 0 or self._busy(word, now):
            return
        p = self._wrap(now)
        target = signed32((self.regs[0x0034] << 16) | self.regs[0x0035])
        if not word & _ABS:
            target += round(p)
        if self._blocked(target - p, now):
            return
        self.kin.move_to(now, target, self.pulse_rate(speed), *self._ramps(speed))
        self.mode = _MODE_POSITION
        self._watch_from = now

    def _start_speed(self, word: int, now: float) -> None:
        speed = signed16(self.regs[0x0033])
        changing = self.mode == _MODE_SPEED and self.kin.moving(now)
        if not changing and self._busy(word, now):
            return
        if self._blocked(speed, now):
            return
        self._wrap(now)
        if speed == 0:
            self.kin.stop(now, self._stop_rate(now))
        else:
            self.kin.run(now, self.pulse_rate(speed), *self._ramps(speed))
        self.mode = _MODE_SPEED
        self._watch_from = now

    # -- homing ---------------------------------------------------------------------------------

    def _offset(self) -> int:
        return (self.regs[0x0044] << 16) | self.regs[0x0045]

    def _phases(self, mode: int, now: float) -> tuple[dict[str, _Phase], str] | None:
        """The homing method's legs (manual 6.3) and the first one, from the switch state
        at ``now``."""
        home, neg, pos = self.switch_states(now)
        if mode in (17, 18):  # origin: the falling edge of N-OT (17) or P-OT (18)
            d, limit = (1, _P) if mode == 18 else (-1, _N)
            legs = {"fast": _Phase(d, True, ((limit, True, "creep"),)),
                    "creep": _Phase(-d, False, ((limit, False, "done"),))}
            on = (pos if d > 0 else neg) and self._wired(limit)
            return legs, "creep" if on else "fast"
        if mode in (24, 29):  # origin: HW's rising edge, met searching forward (24) or back
            d, limit = (1, _P) if mode == 24 else (-1, _N)
            legs = {
                # (a) fast to HW's rising edge; (b) the limit first: reverse at high speed
                "fast": _Phase(d, True, ((_H, True, "back"), (limit, True, "reverse"))),
                # (b) at HW's rising edge slow down, going on the same way
                "reverse": _Phase(-d, True, ((_H, True, "back"),)),
                # (a, b, and c: HW active at the start) slowly to HW's falling edge
                "back": _Phase(-d, False, ((_H, False, "final"),)),
                "final": _Phase(d, False, ((_H, True, "done"),)),
            }
            return legs, "back" if home and self._wired(_H) else "fast"
        return None

    def _start_homing(self, word: int, now: float) -> None:
        mode = self.regs[0x0040]
        if mode not in (17, 18, 24, 29, 35) or self._busy(word, now):
            return  # 0 (the factory value) and other numbers are not documented methods
        self._wrap(now)
        self.mode = _MODE_HOMING
        self.homed = False
        self.homing_failed = False
        if mode == 35:
            self._set_counter(now, self._offset())
            self.homed = True
            return
        plan = self._phases(mode, now)
        assert plan is not None
        phases, first = plan
        self._homing = _Homing(phases, first, now)
        self._enter(first, now)

    def _enter(self, name: str, t: float) -> None:
        """Start homing leg ``name`` at ``t`` (braking first if moving the other way)."""
        assert self._homing is not None
        phase = self._homing.phases[name]
        rate = self._home_rate()
        speed = self.regs[0x0041] if phase.fast else self.regs[0x0042]
        v = self.kin.velocity(t)
        self.kin.run(t, phase.direction * self.pulse_rate(speed), rate, rate)
        t_dir = t + abs(v) / rate if v * phase.direction < 0 else t
        self._homing.phase, self._homing.t_dir = name, t_dir

    def _next_edge(self, now: float) -> tuple[float, str] | None:
        """The first edge the current leg waits for (or a limit that aborts it) up to ``now``;
        a limit ahead that is already active when the leg sets off counts at once."""
        assert self._homing is not None
        phase = self._homing.phases[self._homing.phase]
        d = phase.direction
        ahead = _P if d > 0 else _N
        events = list(phase.events)
        if all(sig is not ahead or not rising for sig, rising, _ in events):
            events.append((ahead, True, "abort"))
        t_from = self._homing.t_dir + 1e-9
        best: tuple[float, str] | None = None
        for sig, rising, nxt in events:
            span = self._span(sig)
            if sig is ahead and rising and span is not None and span.active(
                self.physical_position(t_from)
            ):
                return t_from, nxt
            boundary = self._boundary(sig, d, rising)
            if boundary is None:
                continue
            tc = self.kin.crossing(boundary, t_from, now)
            if tc is not None and (best is None or tc < best[0]):
                best = (tc, nxt)
        return best

    def _advance_homing(self, now: float) -> None:
        for _ in range(16):
            if self._homing is None:
                return
            edge = self._next_edge(now)
            if edge is None:
                return
            tc, nxt = edge
            if nxt == "done":
                self.kin.stop(tc, self._home_rate())
                self._set_counter(tc, self._offset())
                self.homed = True
                self._homing = None
            elif nxt == "abort":
                self.kin.stop(tc, self._stop_rate(tc) if self.regs[0x0025] == 0 else None)
                self._homing = None
                self.homing_failed = True
            else:
                self._enter(nxt, tc)

    def _limit_hit(self, now: float) -> float | None:
        """When a position/speed move first ran into an active limit since its start."""
        hits = []
        for boundary, direction in ((self._boundary(_P, 1, True), 1),
                                    (self._boundary(_N, -1, True), -1)):
            if boundary is None:
                continue
            tc = self.kin.entering(boundary, direction, self._watch_from, now)
            if tc is not None:
                hits.append(tc)
        return min(hits) if hits else None

    def advance(self, now: float) -> None:
        """Bring homing legs and limit stops up to ``now`` (state is computed lazily)."""
        if self._homing is not None:
            self._advance_homing(now)
            return
        if self.mode in (_MODE_POSITION, _MODE_SPEED) and self.kin.moving(now):
            tc = self._limit_hit(now)
            if tc is not None:
                at_once = self.regs[0x0025] == 1
                self.kin.stop(tc, None if at_once else self._stop_rate(tc))
                self._watch_from = now

    # -- faults ---------------------------------------------------------------------------------

    def raise_alarm(self, code: int, now: float | None = None) -> None:
        """Latch error ``code`` (1 overcurrent, 2 overvoltage, 4 position error)."""
        t = time_or_present(now)
        self.advance(t)
        self._homing = None
        super().raise_alarm(code, t)

    def power_restore(self) -> None:
        """Power-up: EEPROM values come back, the position counter starts at 0.

        A format written to 0x0021 (and saved) takes effect now, at 19200 baud and up; with
        ``soft_address`` the address saved in 0x0020 too.
        """
        super().power_restore()
        now = monotonic()
        self.regs = dict(self.eeprom)
        for a in (0x0036, 0x0037, 0x0038):
            self.regs[a] = _PARAMETERS[a].default
        if self.settings.baudrate != 9600:
            self.settings = LineSettings.parse(
                _FORMATS[self.regs[0x0021]], baudrate=self.settings.baudrate
            )
        if self.soft_address:
            self.address = self.regs[0x0020]
        self.kin.hold(now)
        self._set_counter(now, 0)  # the counter starts at 0; the axis has not moved
        self.enabled = True
        self.alarm_code = 0
        self.mode = _MODE_NONE
        self.homed = False
        self._homing = None


def _check_line(settings: LineSettings) -> None:
    """The CL86R's DIP switches give 9600 (8N1 only), 19200, 38400 or 115200 baud."""
    if settings.baudrate not in _BAUDS:
        raise ConfigError(f"CL86R baud rate {settings.baudrate} is not one of {_BAUDS}")
    if settings.format not in _FORMATS:
        raise ConfigError(f"CL86R line format {settings.format} is not one of {_FORMATS}")
    if settings.baudrate == 9600 and settings.format != "8N1":
        raise ConfigError("the CL86R runs 8N1 at 9600 baud (0x0021 applies from 19200 up)")
