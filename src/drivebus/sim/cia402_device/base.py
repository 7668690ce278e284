"""The simulated CiA 402 device's state: objects by name, the axis, the statusword,
faults and power, units.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Literal

from drivebus.drives.cia402 import (
    HOMING_METHODS,
    OBJECTS,
    DigitalInput,
    HomeSwitch,
    Mode,
    State,
    Statusword,
)
from drivebus.sim.cia402_device.state import (
    _HALT_OPTIONS,
    _QUICK_STOP_OPTIONS,
    FACTORY_VALUES,
    Cia402Setup,
    _Homing,
    _Profile,
)
from drivebus.sim.drive import time_or_present
from drivebus.sim.kinematics import Kinematics
from drivebus.sim.registers import ExceptionCodes, SlaveException, signed32


class DeviceBase:
    """The simulated CiA 402 device's state: its objects by name (checked, read and
    written), the axis it moves, what tests and twins look at (position, switches,
    statusword), faults and power, its units. The rooms (``machine``, ``profiles``,
    ``homing``) add what it does; ``Cia402Device`` is them all."""

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

    def cam_side(self) -> int:
        """The side of ``home_switch`` a home cam covers: ``home_cam``'s, else the side the
        homing method in 6098h expects (its home switch's, else the side it searches
        first; +1 with no method)."""
        s = self.setup
        if s.home_cam is not None:
            return 1 if s.home_cam == "positive" else -1
        method = HOMING_METHODS.get(self.values.get("homing_method", 0))
        if method is None or method.home_switch is HomeSwitch.POSITIVE:
            return 1
        if method.home_switch is HomeSwitch.NEGATIVE:
            return -1
        return method.initial_direction or 1

    def _switches(self, now: float) -> tuple[bool, bool, bool]:
        """The switches on the motion planned so far (no events run)."""
        p = self._physical(now)
        s = self.setup
        if s.home_switch is None:
            home = False
        elif s.home_switch_width is not None:
            home = s.home_switch <= p <= s.home_switch + s.home_switch_width
        else:
            home = p >= s.home_switch if self.cam_side() > 0 else p <= s.home_switch
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
