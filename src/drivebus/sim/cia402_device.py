"""Cia402Device: a simulated CiA 402 drive addressed by object names, not registers.

Whatever maps CiA 402 objects onto a bus (a generic twin built from a drive description,
a test) reads and writes the device by object name (``drivebus.drives.cia402.OBJECTS``)
and gets values of the objects' data types; refusals raise ``SlaveException`` with the
codes given (the twin's own). The device runs the device control state machine of
CiA 402-2 / IEC 61800-7-201 (the transition table of ``drivebus.drives.cia402``),
profile position with the new-set-point handshake, profile velocity and homing, on the
simulator's real-time kinematics (``Kinematics``, as the other twins); its state is
computed lazily at each access (``advance``), so no task runs behind it.

Choices where the profile leaves room (documented here, asserted in tests/test_cia402.py):

* commands act on the controlword as written (bits 0-3, 7; fault reset on the rising edge
  of bit 7); enable operation in Ready to switch on is ignored unless ``switch_on_enables``;
  transition 16 (Quick stop active -> Operation enabled) needs quick stop option code 5-8;
* leaving Operation enabled by shutdown or disable voltage releases the motor at once;
  disable operation (transition 5) ramps it down with the profile deceleration;
* quick stop follows the quick stop option code (605Ah: 0, 3, 4, 7, 8 at once; 1, 5 with
  the profile deceleration; 2, 6 with the quick stop deceleration; 1-4 then go to Switch
  on disabled when stopped); a fault goes through Fault reaction active while the motor
  stops on the quick stop deceleration (0: at once), then to Fault; a fault reset clears it;
* profile position: one set-point may wait behind the one in progress (set-point
  acknowledge stays 1 while it waits); change set immediately replaces the motion at once;
  change on set-point (bit 9) is taken as a stop at each set-point; a relative target adds
  to the last target, or to the actual position after a motion that ended short (halt,
  quick stop, limit switch, disable); a set-point whose profile velocity, acceleration or
  deceleration is 0 is acknowledged but never moves (target reached stays 0);
* target reached (bit 10): profile position, standing at the target or stopped after a
  halt or a limit switch; profile velocity, at the target velocity or stopped by a halt;
  homing, as the homing status table says; other states, standing still;
* halt (bit 8) decelerates per the halt option code (605Dh: 1 profile deceleration, 2
  quick stop deceleration, 3 and 4 at once) and holds; profile position drops its
  set-points (a new edge of bit 4 is ignored while halt is set), profile velocity resumes
  the target velocity when halt clears, homing is interrupted (as by bit 4 falling);
* a limit switch (60FDh bits 0, 1) in the way stops a profile position or velocity motion
  on the quick stop deceleration and sets internal limit active (bit 11) while active; a
  motion toward an active limit switch does not start; the axis may only leave it; while
  the axis still stops into a limit switch, a new set-point or target velocity waits for
  the stop to end, and no other stop ramps slower than the quick stop;
* homing starts from standstill (else a homing error); the legs that search a switch run
  at the search speed, the final approach over the homing edge (and on to the index
  pulse) at the zero speed, all on the homing acceleration. The drive decides from its
  inputs as a real one: a method's home switch side (positive, negative, over part of
  the travel) is its assumption, the switch positions are the machine's. It reverses
  once on the method's reversal limit switch; any other limit switch met is a homing
  error (stop on the quick stop deceleration). At the home position the position actual
  value becomes the home offset and the axis comes to rest on the homing acceleration;
  35 and 37 take the current position;
* a mode of operation written takes effect at once (the motion of the previous mode stops
  on the profile deceleration); modes other than the supported ones are refused;
* power loss: the motor stops at once; at power-up the device is in Not ready to switch
  on for ``boot_time``, then Switch on disabled; objects return to their factory values
  except ``retained`` ones; the position counter starts at 0 (incremental encoder) unless
  ``absolute_encoder``; the axis is no longer homed.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Literal

from drivebus.drives.cia402 import (
    HOMING_METHODS,
    OBJECTS,
    Command,
    Controlword,
    DigitalInput,
    HomeSignal,
    HomeSwitch,
    HomingMethod,
    Mode,
    State,
    Statusword,
    decode_command,
    transition,
)
from drivebus.sim.drive import time_or_present
from drivebus.sim.kinematics import Kinematics
from drivebus.sim.registers import ExceptionCodes, SlaveException, signed32

__all__ = ["FACTORY_VALUES", "Cia402Device", "Cia402Setup"]

FACTORY_VALUES: Mapping[str, int] = {
    "controlword": 0,
    "quick_stop_option_code": 2,
    "halt_option_code": 1,
    "modes_of_operation": 0,
    "target_position": 0,
    "home_offset": 0,
    "profile_velocity": 10_000,
    "profile_acceleration": 100_000,
    "profile_deceleration": 100_000,
    "quick_stop_deceleration": 1_000_000,
    "homing_method": 0,
    "homing_speed_search": 10_000,
    "homing_speed_zero": 1_000,
    "homing_acceleration": 100_000,
    "target_velocity": 0,
}
"""The writable objects' values at power-up (in the objects' units), unless the device is
given others."""

_QUICK_STOP_OPTIONS = range(0, 9)
_AT_ONCE = 1e12
"""Increments/s² of a ramp that an acceleration object of 0 asks for (no ramp)."""
_HALT_OPTIONS = range(1, 5)
_SUPPORTED = frozenset({Mode.PROFILE_POSITION, Mode.PROFILE_VELOCITY, Mode.HOMING})


@dataclass(frozen=True, kw_only=True)
class Cia402Setup:
    """How a simulated CiA 402 drive and its axis are built: units, switches, encoder."""

    position: int = 0
    """The position counter (increments) at power-up; the switches' frame."""
    home_switch: float | None = None
    """Where the home switch's edge is (its lower edge for a switch of ``home_switch_width``)."""
    home_cam: Literal["positive", "negative"] = "positive"
    """Without a width: the home switch is active on this side of ``home_switch``."""
    home_switch_width: float | None = None
    """The home switch covers [home_switch, home_switch + width] (homing methods 7-14, 23-30)."""
    limit_negative: float | None = None
    """The negative limit switch is active at and below this position."""
    limit_positive: float | None = None
    """The positive limit switch is active at and above this position."""
    increments_per_rev: int = 10_000
    """Encoder increments per motor revolution: one index pulse each."""
    index_offset: float = 0.0
    """A position where an index pulse is (the others are a revolution apart)."""
    velocity_unit: float = 1.0
    """Increments/s of one unit of the velocity objects (e.g. increments_per_rev / 60 for rpm)."""
    acceleration_unit: float = 1.0
    """Increments/s² of one unit of the acceleration objects."""
    modes: frozenset[Mode] = _SUPPORTED
    """The modes of operation the drive accepts (a subset of PP, PV, homing)."""
    homing_methods: frozenset[int] = frozenset(HOMING_METHODS)
    """The homing methods the drive accepts (0 is always accepted: no method)."""
    switch_on_enables: bool = False
    """Enable operation in Ready to switch on goes on to Operation enabled (3 then 4)."""
    boot_time: float = 0.0
    """Seconds in Not ready to switch on after power-up."""
    absolute_encoder: bool = False
    """The position survives a power cycle (else the counter restarts at 0)."""

    def __post_init__(self) -> None:
        if not self.modes <= _SUPPORTED:
            raise ValueError(f"the simulated CiA 402 device runs only {sorted(_SUPPORTED)}")
        if self.increments_per_rev <= 0 or self.velocity_unit <= 0 or self.acceleration_unit <= 0:
            raise ValueError("increments per revolution and units must be > 0")


@dataclass(frozen=True)
class _Edge:
    """A switch edge the homing may cross: its physical position and the side (+1/-1) on
    which the switch is active."""

    position: float
    active_side: int
    name: str


_BAND = 2e-6
"""Increments past an edge at which the homing takes it as passed: a tiny hysteresis, so
that an axis that turns round on an edge (or starts on one) is seen to pass it each time."""


@dataclass
class _Watch:
    """An edge the homing watches, and the side of it (+1/-1) the axis is on."""

    kind: Literal["home", "index", "limit"]
    edge: _Edge
    side: int


@dataclass
class _Homing:
    """A homing in progress."""

    method: HomingMethod
    direction: int
    watches: list[_Watch]
    final: bool = False
    reversed: bool = False
    t_from: float = 0.0  # events are looked for from here on


@dataclass
class _PointSet:
    """A profile position set-point as the drive took it."""

    target: float
    velocity: float
    acceleration: float
    deceleration: float


@dataclass
class _Profile:
    """Profile position bookkeeping."""

    target: float | None = None  # the set-point in progress or last reached (counter frame)
    pending: _PointSet | None = None  # waits behind the one in progress
    acknowledge: bool = False
    ended_short: bool = False  # halt, limit switch, quick stop: relative moves start here
    stalled: bool = False  # taken but cannot move (no speed or ramp)


_Action = Callable[[float], None]


@dataclass
class _Events:
    """Candidates for the next internal event: (time, action at that time); earliest wins."""

    items: list[tuple[float, _Action]] = field(default_factory=list)

    def add(self, t: float | None, action: _Action) -> None:
        """A candidate at ``t`` (None: none)."""
        if t is not None:
            self.items.append((t, action))

    def first(self) -> tuple[float, _Action] | None:
        """The earliest candidate (the first added among equals)."""
        return min(self.items, key=lambda item: item[0]) if self.items else None


class Cia402Device:
    """A simulated CiA 402 drive: objects by name, state machine, PP, PV and homing."""

    def __init__(
        self,
        setup: Cia402Setup | None = None,
        *,
        defaults: Mapping[str, int] | None = None,
        retained: Iterable[str] = (),
        codes: ExceptionCodes | None = None,
        kin: Kinematics | None = None,
        now: float | None = None,
    ) -> None:
        now = time_or_present(now)
        self.setup = setup or Cia402Setup()
        self.codes = codes or ExceptionCodes()
        """The exception codes a refusal raises (``SlaveException``)."""
        self.factory = dict(FACTORY_VALUES)
        for name, value in (defaults or {}).items():
            self._check(name, value)
            self.factory[name] = value
        self.retained = frozenset(retained)
        """Objects whose written values survive a power cycle."""
        for name in self.retained:
            self._info(name)
        self.kin = kin if kin is not None else Kinematics(self.setup.position)
        """The axis's motion (shared with a twin that has one)."""
        self.kin.hold(now, self.setup.position)
        self._shift = 0.0
        """Position counter minus physical position (homing moves the counter, not the
        switches)."""
        self.values = dict(self.factory)
        self._saved: dict[str, int] = {}
        self.powered = True
        self.error_code = 0
        self.homed = False
        self._power_up(now)

    # -- objects -------------------------------------------------------------------------------

    def _info(self, name: str) -> None:
        if name not in OBJECTS:
            raise SlaveException(self.codes.address)

    def _check(self, name: str, value: int) -> None:
        """Refuse an unknown object, a write to a read-only one, a value out of range."""
        self._info(name)
        info = OBJECTS[name]
        if not info.writable:
            raise SlaveException(self.codes.access)
        if not info.minimum <= value <= info.maximum:
            raise SlaveException(self.codes.value)
        if name == "modes_of_operation" and value != 0 and value not in self.setup.modes:
            raise SlaveException(self.codes.value)
        if name == "quick_stop_option_code" and value not in _QUICK_STOP_OPTIONS:
            raise SlaveException(self.codes.value)
        if name == "halt_option_code" and value not in _HALT_OPTIONS:
            raise SlaveException(self.codes.value)
        if name == "homing_method" and value != 0 and value not in self.setup.homing_methods:
            raise SlaveException(self.codes.value)

    def check(self, name: str, value: int) -> None:
        """Refuse (``SlaveException``) a write of ``value`` to ``name`` without applying it:
        a twin checks a whole request first, then writes."""
        self._check(name, value)

    def read(self, name: str, now: float) -> int:
        """The value of object ``name`` at ``now`` (in its data type: signed where signed)."""
        self._info(name)
        self.advance(now)
        if name == "statusword":
            return self.statusword(now)
        if name == "modes_of_operation_display":
            return self.mode
        if name == "position_actual_value":
            return signed32(round(self.kin.position(now)))
        if name == "velocity_actual_value":
            return signed32(round(self.kin.velocity(now) / self.setup.velocity_unit))
        if name == "digital_inputs":
            return self.digital_inputs(now)
        if name == "error_code":
            return self.error_code
        if name == "supported_drive_modes":
            return sum(m.supported_bit for m in self.setup.modes)
        return self.values[name]

    def write(self, name: str, value: int, now: float) -> None:
        """Write object ``name`` at ``now`` and act on it (refusals raise ``SlaveException``)."""
        self._check(name, value)
        self.advance(now)
        old = self.values[name]
        self.values[name] = value
        if name in self.retained:
            self._saved[name] = value
        if name == "controlword":
            self._controlword(value, old, now)
        elif name == "modes_of_operation":
            self._set_mode(value, now)
        elif (name in ("target_velocity", "profile_acceleration", "profile_deceleration")
              and self._running(Mode.PROFILE_VELOCITY) and not self._halted):
            self._velocity(now)

    # -- what tests and twins look at ----------------------------------------------------------

    def position(self, now: float | None = None) -> float:
        """The position counter (increments) at ``now``."""
        now = time_or_present(now)
        self.advance(now)
        return self.kin.position(now)

    def velocity(self, now: float | None = None) -> float:
        """The velocity in increments/s at ``now``."""
        now = time_or_present(now)
        self.advance(now)
        return self.kin.velocity(now)

    def is_moving(self, now: float | None = None) -> bool:
        """True while the motor turns."""
        now = time_or_present(now)
        self.advance(now)
        return self.kin.moving(now)

    def physical_position(self, now: float | None = None) -> float:
        """Where the axis physically is (the frame of the switch positions)."""
        now = time_or_present(now)
        self.advance(now)
        return self._physical(now)

    def state_at(self, now: float | None = None) -> State:
        """The state machine's state at ``now``."""
        now = time_or_present(now)
        self.advance(now)
        return self.state

    def switch_states(self, now: float | None = None) -> tuple[bool, bool, bool]:
        """(home, limit negative, limit positive) at ``now``."""
        now = time_or_present(now)
        self.advance(now)
        return self._switches(now)

    def _physical(self, now: float) -> float:
        """The physical position on the motion planned so far (no events run)."""
        return self.kin.position(now) - self._shift

    def _switches(self, now: float) -> tuple[bool, bool, bool]:
        """The switches on the motion planned so far (no events run)."""
        p = self._physical(now)
        s = self.setup
        if s.home_switch is None:
            home = False
        elif s.home_switch_width is not None:
            home = s.home_switch <= p <= s.home_switch + s.home_switch_width
        else:
            home = p >= s.home_switch if s.home_cam == "positive" else p <= s.home_switch
        neg = s.limit_negative is not None and p <= s.limit_negative
        pos = s.limit_positive is not None and p >= s.limit_positive
        return home, neg, pos

    def digital_inputs(self, now: float | None = None) -> int:
        """Digital inputs (60FDh): negative limit, positive limit, home switch."""
        now = time_or_present(now)
        home, neg, pos = self._switches(now)
        return ((DigitalInput.NEGATIVE_LIMIT if neg else 0)
                | (DigitalInput.POSITIVE_LIMIT if pos else 0)
                | (DigitalInput.HOME_SWITCH if home else 0))

    def statusword(self, now: float | None = None) -> int:
        """The statusword (6041h) at ``now``."""
        now = time_or_present(now)
        self.advance(now)
        word = self.state.bits | Statusword.VOLTAGE_ENABLED | Statusword.REMOTE
        if self.state in (State.READY_TO_SWITCH_ON, State.SWITCHED_ON, State.OPERATION_ENABLED):
            word |= Statusword.QUICK_STOP
        _, neg, pos = self._switches(now)
        if neg or pos:
            word |= Statusword.INTERNAL_LIMIT_ACTIVE
        moving = self.kin.moving(now)
        if self.state is not State.OPERATION_ENABLED:
            return word | (0 if moving else Statusword.TARGET_REACHED)
        if self.mode == Mode.PROFILE_POSITION:
            word |= self._pp_bits(now, moving)
        elif self.mode == Mode.PROFILE_VELOCITY:
            word |= self._pv_bits(now, moving)
        elif self.mode == Mode.HOMING:
            word |= self._homing_bits(moving)
        elif not moving:
            word |= Statusword.TARGET_REACHED
        return word

    # -- faults and power ----------------------------------------------------------------------

    def raise_fault(self, code: int, now: float | None = None) -> None:
        """A fault with error code ``code`` (603Fh): Fault reaction active while the motor
        stops on the quick stop deceleration, then Fault."""
        now = time_or_present(now)
        self.advance(now)
        self.error_code = code & 0xFFFF
        self._end_motion(now, self._rate("quick_stop_deceleration"))
        self.state = State.FAULT_REACTION_ACTIVE

    def power_loss(self, now: float | None = None) -> None:
        """The power is cut: the motor stops at once; nothing is kept but retained objects
        (and the position, with an absolute encoder)."""
        now = time_or_present(now)
        self.advance(now)
        self._end_motion(now, None)
        self.powered = False

    def power_restore(self, now: float | None = None) -> None:
        """Power-up: Not ready to switch on for the boot time, then Switch on disabled."""
        now = time_or_present(now)
        self.powered = True
        self.values = {**self.factory, **self._saved}
        if not self.setup.absolute_encoder:
            self._set_counter(now, 0.0)
        self._power_up(now)

    def _power_up(self, now: float) -> None:
        self.state = State.NOT_READY_TO_SWITCH_ON
        self._boot_until = now + self.setup.boot_time
        self.error_code = 0
        self.homed = False
        self.mode = self.values["modes_of_operation"]
        self._halted = False
        self._profile = _Profile()
        self._homing: _Homing | None = None
        self._homing_result: Literal["none", "attained", "error", "interrupted"] = "none"
        self._watch_from: float | None = None  # a PP/PV motion watches the limit switches
        self._pv_deferred = False  # a target velocity waits for a limit stop to end
        self.advance(now)

    # -- units ---------------------------------------------------------------------------------

    def _rate(self, name: str) -> float | None:
        """An acceleration object in increments/s² (None where 0: at once)."""
        value = self.values[name]
        return value * self.setup.acceleration_unit if value > 0 else None

    def _speed(self, name: str) -> float:
        """A velocity object in increments/s (signed where the object is)."""
        return self.values[name] * self.setup.velocity_unit

    def _set_counter(self, t: float, value: float) -> None:
        """The position counter reads ``value`` at ``t`` (the axis does not move)."""
        old = self.kin.position(t)
        self.kin.set_position(t, value)
        self._shift += value - old

    # -- the state machine ---------------------------------------------------------------------

    def _running(self, mode: Mode) -> bool:
        return self.state is State.OPERATION_ENABLED and self.mode == mode

    def _controlword(self, word: int, old: int, now: float) -> None:
        command = decode_command(word, old)
        if command is not None:
            self._command(command, now)
        if self.state is State.OPERATION_ENABLED:
            self._mode_bits(word, old, now)

    def _command(self, command: Command, now: float) -> None:
        before = self.state
        t = transition(before, command)
        if before is State.READY_TO_SWITCH_ON and command is Command.ENABLE_OPERATION:
            if self.setup.switch_on_enables:
                self._enter_enabled(now)
            return
        if t is None or (t.number == 16 and self.values["quick_stop_option_code"] < 5):
            return
        if t.number == 11:
            self._quick_stop(now)
            return
        self.state = t.target
        if t.target is State.OPERATION_ENABLED:
            self._enter_enabled(now)
        elif before is State.OPERATION_ENABLED:
            ramp = self._rate("profile_deceleration") if t.number == 5 else None
            self._end_motion(now, ramp)
        elif t.number == 15:
            self.error_code = 0

    def _enter_enabled(self, now: float) -> None:
        """Operation enabled: the axis holds where it is; no set-point in progress."""
        self.state = State.OPERATION_ENABLED
        self._profile = _Profile()
        self._halted = bool(self.values["controlword"] & Controlword.HALT)
        if self._running(Mode.PROFILE_VELOCITY) and not self._halted:
            self._velocity(now)

    def _quick_stop(self, now: float) -> None:
        option = self.values["quick_stop_option_code"]
        if option in (1, 5):
            ramp = self._rate("profile_deceleration")
        elif option in (2, 6):
            ramp = self._rate("quick_stop_deceleration")
        else:
            ramp = None
        self._end_motion(now, ramp)
        self.state = State.QUICK_STOP_ACTIVE

    def _end_motion(self, now: float, ramp: float | None) -> None:
        """Stop whatever runs (on ``ramp``, None: at once) and forget its set-points."""
        self._stop(now, ramp)
        if self._homing is not None:
            self._homing = None
            self._homing_result = "interrupted"
        self._drop_set_points()

    def _drop_set_points(self) -> None:
        """Forget the waiting set-point (acknowledge drops unless bit 4 is still held); the
        motion in progress ended short."""
        self._profile.pending = None
        self._profile.ended_short = True
        if not self.values["controlword"] & Controlword.NEW_SET_POINT:
            self._profile.acknowledge = False
        self._watch_from = None

    def _set_mode(self, value: int, now: float) -> None:
        if value == self.mode:
            return
        if self.kin.moving(now) or self._homing is not None:
            self._end_motion(now, self._rate("profile_deceleration"))
        self.mode = value
        self._profile = _Profile()
        if self._running(Mode.PROFILE_VELOCITY) and not self._halted:
            self._velocity(now)

    # -- mode bits -----------------------------------------------------------------------------

    def _mode_bits(self, word: int, old: int, now: float) -> None:
        halt = bool(word & Controlword.HALT)
        rising = word & Controlword.NEW_SET_POINT and not old & Controlword.NEW_SET_POINT
        falling = old & Controlword.NEW_SET_POINT and not word & Controlword.NEW_SET_POINT
        if halt and not self._halted:
            self._halt(now)
        self._halted = halt
        if self.mode == Mode.PROFILE_POSITION:
            if rising and not halt:
                self._new_set_point(word, now)
            elif falling and self._profile.pending is None:
                self._profile.acknowledge = False
        elif self.mode == Mode.PROFILE_VELOCITY:
            if not halt and old & Controlword.HALT:
                self._velocity(now)
        elif self.mode == Mode.HOMING:
            if rising and not halt:
                self._start_homing(now)
            elif falling and self._homing is not None:
                self._end_motion(now, self._rate("homing_acceleration"))

    def _halt(self, now: float) -> None:
        option = self.values["halt_option_code"]
        if self.mode == Mode.HOMING:
            ramp = self._rate("homing_acceleration")
        elif option == 1:
            ramp = self._rate("profile_deceleration")
        elif option == 2:
            ramp = self._rate("quick_stop_deceleration")
        else:
            ramp = None
        self._end_motion(now, ramp)

    # -- profile position ----------------------------------------------------------------------

    def _new_set_point(self, word: int, now: float) -> None:
        prof = self._profile
        busy = self.kin.moving(now) and prof.target is not None
        immediate = bool(word & Controlword.CHANGE_SET_IMMEDIATELY)
        if self._into_limit(now):  # the limit stop goes on; the set-point waits for it
            busy, immediate = True, False
        if busy and not immediate and prof.pending is not None:
            return  # the one waiting slot is taken: no acknowledge
        target = float(self.values["target_position"])
        if word & Controlword.RELATIVE:
            base = (prof.pending.target if prof.pending is not None and not immediate
                    else prof.target)
            if base is None or (prof.ended_short and prof.pending is None):
                base = self.kin.position(now)
            target += base
        point = _PointSet(target, self._speed("profile_velocity"),
                          self.values["profile_acceleration"] * self.setup.acceleration_unit,
                          self.values["profile_deceleration"] * self.setup.acceleration_unit)
        prof.acknowledge = True
        if busy and not immediate:
            prof.pending = point
        else:
            prof.pending = None
            self._start_point(point, now)

    def _start_point(self, point: _PointSet, now: float) -> None:
        prof = self._profile
        prof.target, prof.ended_short, prof.stalled = point.target, False, False
        p = self.kin.position(now)
        if min(point.velocity, point.acceleration, point.deceleration) <= 0:
            prof.stalled = True
            self._stop(now, point.deceleration or None)
            return
        if self._blocked(point.target - p, now):
            prof.ended_short = True
            self.kin.stop(now, self._rate("quick_stop_deceleration"))
            return
        self.kin.move_to(now, point.target, point.velocity, point.acceleration,
                         point.deceleration)
        self._watch_from = now

    def _pp_bits(self, now: float, moving: bool) -> int:
        prof = self._profile
        word = Statusword.SET_POINT_ACKNOWLEDGE if prof.acknowledge else 0
        if moving or prof.pending is not None or prof.stalled:
            return word
        at_target = prof.target is None or abs(self.kin.position(now) - prof.target) < 0.5
        if at_target or prof.ended_short:
            word |= Statusword.TARGET_REACHED
        return word

    # -- profile velocity ----------------------------------------------------------------------

    def _velocity(self, now: float) -> None:
        """Run at the target velocity (a limit switch in the way: stand)."""
        speed = self._speed("target_velocity")
        if self._into_limit(now):
            self._pv_deferred = True  # the limit stop goes on; the velocity counts after it
            return
        if self._blocked(speed, now):
            self.kin.stop(now, self._rate("quick_stop_deceleration"))
            self._watch_from = None
            return
        accel = self._rate("profile_acceleration") or _AT_ONCE
        decel = self._rate("profile_deceleration") or _AT_ONCE
        if speed == 0.0:
            self._stop(now, decel)
        else:
            self.kin.run(now, speed, accel, decel)
        self._watch_from = now

    def _pv_bits(self, now: float, moving: bool) -> int:
        v = self.kin.velocity(now)
        word = Statusword.SPEED_ZERO if abs(v) < 1e-9 else 0
        if self._halted or self._watch_from is None:  # halted, or stopped by a limit switch
            return word | (0 if moving else Statusword.TARGET_REACHED)
        if abs(v - self._speed("target_velocity")) < 1e-6 and not self._ramping(now):
            word |= Statusword.TARGET_REACHED
        return word

    def _ramping(self, now: float) -> bool:
        """True while the velocity is still changing."""
        last = self.kin.end_time()
        if not math.isinf(last):
            return now < last
        return abs(self.kin.velocity(now) - self.kin.velocity(now + 1e-3)) > 1e-9

    # -- limit switches ------------------------------------------------------------------------

    def _blocked(self, direction: float, now: float) -> bool:
        """True if a limit switch in ``direction`` is active: the drive will not go on."""
        _, neg, pos = self._switches(now)
        return (direction > 0 and pos) or (direction < 0 and neg)

    def _into_limit(self, now: float) -> bool:
        """True while the axis still moves into an active limit switch (stopping)."""
        v = self.kin.velocity(now)
        return v != 0.0 and self._blocked(v, now)

    def _stop(self, now: float, ramp: float | None) -> None:
        """Stop on ``ramp`` (None: at once), never slower than the quick stop ramp while
        the axis moves into an active limit switch."""
        if ramp is not None and self._into_limit(now):
            quick = self._rate("quick_stop_deceleration")
            ramp = None if quick is None else max(ramp, quick)
        self.kin.stop(now, ramp)

    def _limit_edges(self) -> list[_Edge]:
        s, edges = self.setup, []
        if s.limit_negative is not None:
            edges.append(_Edge(s.limit_negative, -1, "negative limit"))
        if s.limit_positive is not None:
            edges.append(_Edge(s.limit_positive, +1, "positive limit"))
        return edges

    def _crossing(self, edge: _Edge, t_from: float, now: float,
                  direction: int | None = None) -> float | None:
        """When the axis first crosses ``edge`` in [t_from, now] (moving ``direction`` if
        given, +1 or -1), in the physical frame."""
        p = edge.position + self._shift
        t0 = t_from
        for _ in range(8):
            tc = self.kin.crossing(p, t0, now)
            if tc is None:
                return None
            v = self.kin.velocity(tc)
            if v != 0.0 and (direction is None or v * direction > 0):
                return tc
            t0 = tc + 1e-6
            if t0 > now:
                return None
        return None

    def _limit_hit(self, now: float) -> float | None:
        """When a PP or PV motion ran into a limit switch since it started (or None)."""
        if self._watch_from is None:
            return None
        hits = [tc for edge in self._limit_edges()
                if (tc := self._crossing(edge, self._watch_from, now, edge.active_side))
                is not None]
        return min(hits) if hits else None

    def _stop_at_limit(self, tc: float) -> None:
        self.kin.stop(tc, self._rate("quick_stop_deceleration"))
        self._drop_set_points()

    # -- homing --------------------------------------------------------------------------------

    def _home_edge(self, method: HomingMethod) -> _Edge | None:
        """The physical edge of the method's home signal (None where it has none here)."""
        s = self.setup
        if method.signal is HomeSignal.NEGATIVE_LIMIT and s.limit_negative is not None:
            return _Edge(s.limit_negative, -1, "negative limit")
        if method.signal is HomeSignal.POSITIVE_LIMIT and s.limit_positive is not None:
            return _Edge(s.limit_positive, +1, "positive limit")
        if method.signal is not HomeSignal.HOME_SWITCH or s.home_switch is None:
            return None
        if s.home_switch_width is not None:
            if method.home_switch is HomeSwitch.UPPER_EDGE:
                return _Edge(s.home_switch + s.home_switch_width, -1, "home switch upper edge")
            return _Edge(s.home_switch, +1, "home switch lower edge")
        return _Edge(s.home_switch, +1 if s.home_cam == "positive" else -1, "home switch")

    def _start_homing(self, now: float) -> None:
        self.homed = False
        number = self.values["homing_method"]
        method = HOMING_METHODS.get(number)
        creep, fast = self._speed("homing_speed_zero"), self._speed("homing_speed_search")
        unable = self.kin.moving(now) or (method is not None and method.moves and (
            creep <= 0 or fast <= 0 or self._rate("homing_acceleration") is None))
        if method is None or unable:
            self._homing_result = "error"
            return
        if not method.moves:
            self._set_counter(now, self.values["home_offset"])
            self.homed = True
            self._homing_result = "attained"
            return
        self._homing_result = "none"
        f = method.final_direction
        edge = self._home_edge(method)
        watches = [self._watch("limit", e, now) for e in self._limit_edges() if e != edge]
        if method.signal is HomeSignal.INDEX_PULSE:
            index = _Edge(self._next_index(self._physical(now), f), 0, "index pulse")
            watches.append(_Watch("index", index, -f))
            self._homing = _Homing(method, f, watches, final=True, t_from=now)
            self._run_leg(now)
            return
        if edge is not None:
            watches.append(self._watch("home", edge, now))
        side = self._side(method, now)
        # On the side where the final approach ends: cross the edge the other way, which
        # starts the final approach; on the other side: go over it first. Unknown: search.
        direction = method.initial_direction if side is None else (-f if side == f else f)
        self._homing = _Homing(method, direction, watches, t_from=now)
        ahead = HomeSignal.POSITIVE_LIMIT if direction > 0 else HomeSignal.NEGATIVE_LIMIT
        if self._blocked(direction, now) and ahead is not method.signal:
            # Standing on the limit switch it would run into: its reversal limit turns it
            # round at once; any other is an error.
            if ahead is not method.reversal_limit:
                self._homing_error(now)
                return
            self._homing.direction, self._homing.reversed = -direction, True
        self._run_leg(now)

    def _watch(self, kind: Literal["home", "limit"], edge: _Edge, now: float) -> _Watch:
        """Watch ``edge`` from ``now``: the axis is on its active side where the switch is
        active (edges included), else on the other."""
        p = self._physical(now)
        active = (p - edge.position) * edge.active_side >= 0
        return _Watch(kind, edge, edge.active_side if active else -edge.active_side)

    def _side(self, method: HomingMethod, now: float) -> int | None:
        """On which side (+1/-1) of the homing edge the drive believes it is, from its
        inputs and the method's assumptions (None: it cannot tell, it searches)."""
        home, neg, pos = self._switches(now)
        if method.signal is HomeSignal.NEGATIVE_LIMIT:
            return -1 if neg else +1
        if method.signal is HomeSignal.POSITIVE_LIMIT:
            return +1 if pos else -1
        if method.home_switch is HomeSwitch.POSITIVE:
            return +1 if home else -1
        if method.home_switch is HomeSwitch.NEGATIVE:
            return -1 if home else +1
        if not home:
            return None
        return +1 if method.home_switch is HomeSwitch.LOWER_EDGE else -1

    def _next_index(self, p: float, direction: int) -> float:
        """The physical position of the first index pulse beyond ``p`` in ``direction``."""
        period, offset = self.setup.increments_per_rev, self.setup.index_offset
        k = (p - offset) / period
        n = math.floor(k) + 1 if direction > 0 else math.ceil(k) - 1
        return offset + n * period

    def _run_leg(self, t: float) -> None:
        h = self._homing
        assert h is not None
        speed = self._speed("homing_speed_zero" if h.final else "homing_speed_search")
        rate = self._rate("homing_acceleration")
        assert rate is not None
        self.kin.run(t, h.direction * speed, rate, rate)

    def _homing_event(self, now: float) -> tuple[float, _Action] | None:
        """The next edge the homing in progress passes up to ``now``, and what it does."""
        h = self._homing
        assert h is not None
        events = _Events()
        for w in h.watches:
            far = w.edge.position - w.side * _BAND + self._shift
            events.add(self.kin.crossing(far, h.t_from, now), functools.partial(self._passed, w))
        return events.first()

    def _passed(self, w: _Watch, tc: float) -> None:
        """The axis passed ``w``'s edge at ``tc`` (moving toward -w.side)."""
        h = self._homing
        assert h is not None
        moving = w.side = -w.side
        h.t_from = tc
        if w.kind == "index":
            self._home_found(tc, w.edge.position)
        elif w.kind == "limit":
            if moving != w.edge.active_side:
                return  # it left the limit switch
            into = HomeSignal.NEGATIVE_LIMIT if moving < 0 else HomeSignal.POSITIVE_LIMIT
            if into is h.method.reversal_limit and not h.reversed:
                h.reversed, h.direction = True, -h.direction
                self._run_leg(tc)
            else:
                self._homing_error(tc)
        else:
            self._home_edge_passed(w, moving, tc)

    def _home_edge_passed(self, w: _Watch, moving: int, tc: float) -> None:
        h = self._homing
        assert h is not None
        f = h.method.final_direction
        if h.final and moving == f:
            if not h.method.index_pulse:
                self._home_found(tc, w.edge.position)
                return
            index = _Edge(self._next_index(w.edge.position, f), 0, "index pulse")
            h.watches = [x for x in h.watches if x.kind != "home"] + [_Watch("index", index, -f)]
            return
        if moving == -f:  # now on the side the final approach starts from
            h.final, h.direction = True, f
        else:
            h.final, h.direction = False, -f
        self._run_leg(tc)

    def _home_found(self, tc: float, home: float) -> None:
        """The home position (physical) was passed at ``tc``: it reads the home offset; the
        axis comes to rest on the homing acceleration."""
        self.kin.stop(tc, self._rate("homing_acceleration"))
        past = self._physical(tc) - home
        self._set_counter(tc, self.values["home_offset"] + past)
        self.homed = True
        self._homing = None
        self._homing_result = "attained"

    def _homing_error(self, tc: float) -> None:
        self.kin.stop(tc, self._rate("quick_stop_deceleration"))
        self._homing = None
        self._homing_result = "error"

    def _homing_bits(self, moving: bool) -> int:
        reached = 0 if moving else Statusword.TARGET_REACHED
        if self._homing is not None:
            return 0
        if self._homing_result == "attained":
            return Statusword.HOMING_ATTAINED | reached
        if self._homing_result == "error":
            return Statusword.HOMING_ERROR | reached
        return reached

    # -- time ----------------------------------------------------------------------------------

    def advance(self, now: float) -> None:
        """Run what happened up to ``now``: the end of booting, of a quick stop or fault
        reaction, a waiting set-point's start, limit switches met, homing legs."""
        for _ in range(64):
            event = self._next_event(now)
            if event is None:
                return
            t, action = event
            action(t)
        raise RuntimeError("the simulated CiA 402 device did not settle (an event loop)")

    def _next_event(self, now: float) -> tuple[float, _Action] | None:
        if not self.powered:
            return None
        events = _Events()
        end = self.kin.end_time()
        stopped = end if end <= now else None
        if self.state is State.NOT_READY_TO_SWITCH_ON and self._boot_until <= now:
            events.add(self._boot_until, self._to(State.SWITCH_ON_DISABLED))
        elif self.state is State.FAULT_REACTION_ACTIVE:
            events.add(stopped, self._to(State.FAULT))  # transition 14
        elif (self.state is State.QUICK_STOP_ACTIVE
              and self.values["quick_stop_option_code"] in range(0, 5)):
            events.add(stopped, self._to(State.SWITCH_ON_DISABLED))  # transition 12
        elif self.state is State.OPERATION_ENABLED:
            if self._homing is not None:
                homing = self._homing_event(now)
                if homing is not None:
                    events.add(*homing)
            else:
                events.add(self._limit_hit(now), self._stop_at_limit)
            if self._profile.pending is not None and self.mode == Mode.PROFILE_POSITION:
                events.add(stopped, self._take_pending)
            if self._pv_deferred:
                events.add(stopped, self._resume_velocity)
        return events.first()

    def _resume_velocity(self, t: float) -> None:
        self._pv_deferred = False
        if self._running(Mode.PROFILE_VELOCITY) and not self._halted:
            self._velocity(t)

    def _to(self, state: State) -> _Action:
        """An automatic transition to ``state``."""
        def action(_t: float) -> None:
            self.state = state
        return action

    def _take_pending(self, t: float) -> None:
        prof = self._profile
        assert prof.pending is not None
        point, prof.pending = prof.pending, None
        if not self.values["controlword"] & Controlword.NEW_SET_POINT:
            prof.acknowledge = False
        self._start_point(point, t)
