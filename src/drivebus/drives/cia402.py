"""CiA 402 drive profile logic: controlword, statusword, state machine, modes, homing methods.

Pure logic, no I/O, independent of how a drive maps the objects onto registers: what a
CiA 402 engine needs to drive any servo or closed-loop drive that speaks the profile over
Modbus (or anything else), and what a simulated CiA 402 device needs to answer it.

References: CiA 402-2 / IEC 61800-7-201 (device control state machine, controlword and
statusword tables, profile position, profile velocity and homing modes, homing methods
1..35 and 37), and python-canopen's ``canopen/profiles/p402.py`` (statusword masks,
transition table, homing status bits), whose state masks this module shares. Object
names and indexes follow CiA 402-2 (e.g. 6040h controlword, 6041h statusword).
"""

from __future__ import annotations

import enum
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass

from drivebus.errors import ArgumentError, DrivebusError

__all__ = [
    "COMMAND_WORDS",
    "HOMING_METHODS",
    "MAX_STEPS",
    "OBJECTS",
    "Command",
    "Controlword",
    "DigitalInput",
    "HomeSignal",
    "HomeSwitch",
    "HomingMethod",
    "HomingStatus",
    "Mode",
    "ObjectInfo",
    "SetPointHandshake",
    "State",
    "Statusword",
    "StatuswordError",
    "Step",
    "Transition",
    "decode_command",
    "decode_state",
    "homing_method",
    "homing_status",
    "next_step",
    "transition",
]


class StatuswordError(DrivebusError, ValueError):
    """A statusword whose state bits match no CiA 402 state (the drive reported garbage)."""


# -- controlword and statusword bits --------------------------------------------------------


class Controlword(enum.IntFlag):
    """Controlword (6040h) bits. Bits 0-3 and 7 command the state machine; bits 4-6 and
    8-9 mean what the mode of operation says (profile position names shown; in homing
    mode bit 4 starts homing, in profile velocity bits 4-6 are reserved)."""

    SWITCH_ON = 0x0001
    ENABLE_VOLTAGE = 0x0002
    QUICK_STOP = 0x0004
    """Active low: 0 asks for a quick stop."""
    ENABLE_OPERATION = 0x0008
    NEW_SET_POINT = 0x0010
    """Profile position: a rising edge hands the drive a new set-point."""
    HOMING_START = 0x0010
    """Homing mode: a rising edge starts homing (same bit as NEW_SET_POINT)."""
    CHANGE_SET_IMMEDIATELY = 0x0020
    """Profile position: 1 = the new set-point replaces the one in progress at once."""
    RELATIVE = 0x0040
    """Profile position: 1 = the target position is relative, 0 = absolute."""
    FAULT_RESET = 0x0080
    """A rising edge resets a fault."""
    HALT = 0x0100
    """1 = stop the axis (decelerate and hold) without leaving Operation enabled."""
    CHANGE_ON_SET_POINT = 0x0200
    """Profile position: 1 = go on to the next set-point without stopping at this one."""


class Statusword(enum.IntFlag):
    """Statusword (6041h) bits. Bits 12-13 mean what the mode of operation says."""

    READY_TO_SWITCH_ON = 0x0001
    SWITCHED_ON = 0x0002
    OPERATION_ENABLED = 0x0004
    FAULT = 0x0008
    VOLTAGE_ENABLED = 0x0010
    QUICK_STOP = 0x0020
    """Active low: 0 = a quick stop is active (in Quick stop active)."""
    SWITCH_ON_DISABLED = 0x0040
    WARNING = 0x0080
    REMOTE = 0x0200
    """1 = the controlword is processed (the drive listens to the bus)."""
    TARGET_REACHED = 0x0400
    """The set-point (position, velocity, homing) is reached, or a halt has stopped the axis."""
    INTERNAL_LIMIT_ACTIVE = 0x0800
    """A limit (e.g. a limit switch, a software position limit) is active."""
    SET_POINT_ACKNOWLEDGE = 0x1000
    """Profile position: the drive took the new set-point."""
    HOMING_ATTAINED = 0x1000
    """Homing mode: homing completed (same bit as SET_POINT_ACKNOWLEDGE)."""
    SPEED_ZERO = 0x1000
    """Profile velocity: the speed is zero (same bit as SET_POINT_ACKNOWLEDGE)."""
    FOLLOWING_ERROR = 0x2000
    """Profile position: the following error exceeds its window."""
    HOMING_ERROR = 0x2000
    """Homing mode: homing failed (same bit as FOLLOWING_ERROR)."""
    MAX_SLIPPAGE_ERROR = 0x2000
    """Profile velocity: the maximum slippage was exceeded (same bit)."""


class DigitalInput(enum.IntFlag):
    """Digital inputs (60FDh): the switches CiA 402 defines (bits 16-31 are the vendor's)."""

    NEGATIVE_LIMIT = 0x0001
    POSITIVE_LIMIT = 0x0002
    HOME_SWITCH = 0x0004
    INTERLOCK = 0x0008


# -- the state machine ----------------------------------------------------------------------


class State(enum.Enum):
    """The states of the CiA 402 device control state machine, with their statusword masks."""

    NOT_READY_TO_SWITCH_ON = ("Not ready to switch on", 0x4F, 0x00)
    SWITCH_ON_DISABLED = ("Switch on disabled", 0x4F, 0x40)
    READY_TO_SWITCH_ON = ("Ready to switch on", 0x6F, 0x21)
    SWITCHED_ON = ("Switched on", 0x6F, 0x23)
    OPERATION_ENABLED = ("Operation enabled", 0x6F, 0x27)
    QUICK_STOP_ACTIVE = ("Quick stop active", 0x6F, 0x07)
    FAULT_REACTION_ACTIVE = ("Fault reaction active", 0x4F, 0x0F)
    FAULT = ("Fault", 0x4F, 0x08)

    def __init__(self, text: str, mask: int, bits: int) -> None:
        self.text = text
        self.mask = mask
        """The statusword bits that identify the state."""
        self.bits = bits
        """Their values in this state (also the state's canonical statusword)."""

    def __str__(self) -> str:
        return self.text

    def matches(self, statusword: int) -> bool:
        """True if ``statusword`` shows this state."""
        return statusword & self.mask == self.bits

    @property
    def drive_function_enabled(self) -> bool:
        """True where the drive may apply torque (the power stage is on)."""
        return self in (State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE,
                        State.FAULT_REACTION_ACTIVE)


def decode_state(statusword: int) -> State:
    """The state a statusword shows (bits other than 0-3, 5 and 6 are ignored).

    ``StatuswordError`` names the word if its state bits match no state.
    """
    for state in State:
        if state.matches(statusword):
            return state
    raise StatuswordError(
        f"statusword 0x{statusword:04X} shows no CiA 402 state "
        f"(bits 0-3, 5, 6 = 0x{statusword & 0x6F:02X})"
    )


class Command(enum.Enum):
    """The state machine's controlword commands (CiA 402-2 controlword table)."""

    SHUTDOWN = "shutdown"
    SWITCH_ON = "switch on"
    ENABLE_OPERATION = "enable operation"
    DISABLE_VOLTAGE = "disable voltage"
    QUICK_STOP = "quick stop"
    DISABLE_OPERATION = "disable operation"
    """Same bits as SWITCH_ON (0x07): its name in Operation enabled (transition 5)."""
    FAULT_RESET = "fault reset"
    """The rising edge of bit 7; a word with bit 7 held carries no other command."""

    def __str__(self) -> str:
        return self.value


COMMAND_WORDS: Mapping[Command, int] = {
    Command.SHUTDOWN: 0x0006,
    Command.SWITCH_ON: 0x0007,
    Command.ENABLE_OPERATION: 0x000F,
    Command.DISABLE_VOLTAGE: 0x0000,
    Command.QUICK_STOP: 0x0002,
    Command.DISABLE_OPERATION: 0x0007,
    Command.FAULT_RESET: 0x0080,
}
"""The controlword to send for each command (mode bits 4-6, 8, 9 clear)."""

def decode_command(controlword: int, previous: int | None = 0) -> Command | None:
    """The command a controlword carries, given the ``previous`` one (for bit 7's edge).

    Bits 0-3 and 7 decide, as in the CiA 402-2 table: a rising edge of bit 7 is
    FAULT_RESET; while bit 7 stays set no command applies (None); then bit 1 = 0 is
    DISABLE_VOLTAGE, bit 2 = 0 QUICK_STOP, bit 0 = 0 SHUTDOWN, bit 3 = 0 SWITCH_ON (which
    is DISABLE_OPERATION in Operation enabled), else ENABLE_OPERATION. ``previous`` None
    means unknown: bit 7 then counts as no edge.
    """
    if controlword & Controlword.FAULT_RESET:
        rising = previous is not None and not previous & Controlword.FAULT_RESET
        return Command.FAULT_RESET if rising else None
    if not controlword & Controlword.ENABLE_VOLTAGE:
        return Command.DISABLE_VOLTAGE
    if not controlword & Controlword.QUICK_STOP:
        return Command.QUICK_STOP
    if not controlword & Controlword.SWITCH_ON:
        return Command.SHUTDOWN
    if not controlword & Controlword.ENABLE_OPERATION:
        return Command.SWITCH_ON
    return Command.ENABLE_OPERATION


@dataclass(frozen=True)
class Transition:
    """One transition of the state machine: its number in CiA 402-2 and where it leads."""

    number: int
    target: State


_S = State
_C = Command
_TRANSITIONS: dict[tuple[State, Command], Transition] = {
    (_S.SWITCH_ON_DISABLED, _C.SHUTDOWN): Transition(2, _S.READY_TO_SWITCH_ON),
    (_S.READY_TO_SWITCH_ON, _C.SWITCH_ON): Transition(3, _S.SWITCHED_ON),
    (_S.SWITCHED_ON, _C.ENABLE_OPERATION): Transition(4, _S.OPERATION_ENABLED),
    (_S.OPERATION_ENABLED, _C.SWITCH_ON): Transition(5, _S.SWITCHED_ON),
    (_S.SWITCHED_ON, _C.SHUTDOWN): Transition(6, _S.READY_TO_SWITCH_ON),
    (_S.READY_TO_SWITCH_ON, _C.DISABLE_VOLTAGE): Transition(7, _S.SWITCH_ON_DISABLED),
    (_S.READY_TO_SWITCH_ON, _C.QUICK_STOP): Transition(7, _S.SWITCH_ON_DISABLED),
    (_S.OPERATION_ENABLED, _C.SHUTDOWN): Transition(8, _S.READY_TO_SWITCH_ON),
    (_S.OPERATION_ENABLED, _C.DISABLE_VOLTAGE): Transition(9, _S.SWITCH_ON_DISABLED),
    (_S.SWITCHED_ON, _C.DISABLE_VOLTAGE): Transition(10, _S.SWITCH_ON_DISABLED),
    (_S.SWITCHED_ON, _C.QUICK_STOP): Transition(10, _S.SWITCH_ON_DISABLED),
    (_S.OPERATION_ENABLED, _C.QUICK_STOP): Transition(11, _S.QUICK_STOP_ACTIVE),
    (_S.QUICK_STOP_ACTIVE, _C.DISABLE_VOLTAGE): Transition(12, _S.SWITCH_ON_DISABLED),
    (_S.FAULT, _C.FAULT_RESET): Transition(15, _S.SWITCH_ON_DISABLED),
    (_S.QUICK_STOP_ACTIVE, _C.ENABLE_OPERATION): Transition(16, _S.OPERATION_ENABLED),
}
"""Commanded transitions. Automatic ones (0, 1, 13, 14, and 12 after a quick stop with
quick stop option code 1-4) are the drive's own; 16 exists only with option code 5-8."""
del _S, _C


def transition(state: State, command: Command) -> Transition | None:
    """The transition ``command`` makes from ``state``, or None (the drive ignores it)."""
    if command is Command.DISABLE_OPERATION:
        command = Command.SWITCH_ON  # the same bits; its name in Operation enabled
    return _TRANSITIONS.get((state, command))


@dataclass(frozen=True)
class Step:
    """One step toward a goal state: the controlword to send (None: send nothing, the
    drive moves on by itself) and the state the drive should show next."""

    controlword: int | None
    expect: State
    command: Command | None = None


_WAIT = {
    State.NOT_READY_TO_SWITCH_ON: State.SWITCH_ON_DISABLED,  # transition 1, automatic
    State.FAULT_REACTION_ACTIVE: State.FAULT,  # transition 14, automatic
}

_PREFERENCE = (
    Command.DISABLE_VOLTAGE,
    Command.SHUTDOWN,
    Command.SWITCH_ON,
    Command.ENABLE_OPERATION,
    Command.FAULT_RESET,
)
"""The commands a path is made of, in order of preference where paths tie. QUICK_STOP is
never a step (it only leads where DISABLE_VOLTAGE leads, or to Quick stop active), nor is
transition 16 (optional in the profile)."""

MAX_STEPS = 6
"""The most steps ``next_step`` can give on the way from any state to any goal:
Fault reaction active -> Fault -> (bit 7 low) -> Switch on disabled -> Ready to switch
on -> Switched on -> Operation enabled. A caller that has taken more is stuck."""


def _first_command(state: State, goal: State) -> Command | None:
    """The first command on a shortest path from ``state`` to ``goal`` (breadth first)."""
    first: dict[State, Command | None] = {state: None}
    queue = deque([state])
    while queue:
        here = queue.popleft()
        if here is goal:
            return first[here]
        for command in _PREFERENCE:
            t = _TRANSITIONS.get((here, command))
            if t is None or t.number == 16 or t.target in first:
                continue
            first[t.target] = first[here] or command
            queue.append(t.target)
    return None


def next_step(state: State, goal: State = State.OPERATION_ENABLED,
              last_controlword: int | None = None) -> Step | None:
    """The next step from ``state`` toward ``goal``; None once there.

    Goals are the states a master can command: Switch on disabled (disabled),
    Ready to switch on, Switched on and Operation enabled. From Fault the step first
    clears bit 7 when ``last_controlword`` had it set (or is unknown, None) so that the
    fault reset is a rising edge; from Quick stop active it disables voltage (transition
    16 back to Operation enabled is optional in the profile). Following the steps reaches
    any goal in at most ``MAX_STEPS`` steps.
    """
    if goal not in (State.SWITCH_ON_DISABLED, State.READY_TO_SWITCH_ON, State.SWITCHED_ON,
                    State.OPERATION_ENABLED):
        raise ArgumentError(f"the CiA 402 state {goal} cannot be commanded as a goal")
    if state is goal:
        return None
    if state in _WAIT:
        return Step(None, _WAIT[state])
    if state is State.FAULT and (last_controlword is None
                                 or last_controlword & Controlword.FAULT_RESET):
        # bit 7 low first, so that the reset is a rising edge
        return Step(COMMAND_WORDS[Command.DISABLE_VOLTAGE], State.FAULT, Command.DISABLE_VOLTAGE)
    command = _first_command(state, goal)
    assert command is not None, f"no path from {state} to {goal}"
    target = _TRANSITIONS[(state, command)].target
    return Step(COMMAND_WORDS[command], target, command)


# -- modes of operation -----------------------------------------------------------------------


class Mode(enum.IntEnum):
    """Modes of operation (6060h) and modes of operation display (6061h)."""

    NO_MODE = 0
    PROFILE_POSITION = 1
    VELOCITY = 2
    PROFILE_VELOCITY = 3
    PROFILE_TORQUE = 4
    HOMING = 6
    INTERPOLATED_POSITION = 7
    CYCLIC_SYNC_POSITION = 8
    CYCLIC_SYNC_VELOCITY = 9
    CYCLIC_SYNC_TORQUE = 10

    @property
    def supported_bit(self) -> int:
        """This mode's bit in supported drive modes (6502h); 0 for NO_MODE."""
        return 0 if self is Mode.NO_MODE else 1 << (self.value - 1)


# -- profile position: the new-set-point handshake ------------------------------------------


class SetPointHandshake:
    """The master's side of the profile position new-set-point handshake.

    1. wait until set-point acknowledge (statusword bit 12) is 0 (the drive can take a
       set-point); 2. send the controlword with new set-point (bit 4) set, with change set
       immediately (bit 5) and relative (bit 6) as asked; 3. when the drive sets
       acknowledge, send it with bit 4 clear: the set-point is taken (``accepted``), and
       the drive clears acknowledge in turn. ``controlword(statusword)`` gives what to send
       at each statusword seen (None: nothing, keep polling); the caller bounds the polls.
    """

    def __init__(self, base: int = COMMAND_WORDS[Command.ENABLE_OPERATION], *,
                 immediate: bool = False, relative: bool = False,
                 change_on_set_point: bool = False) -> None:
        mode_bits = (Controlword.NEW_SET_POINT | Controlword.CHANGE_SET_IMMEDIATELY
                     | Controlword.RELATIVE | Controlword.CHANGE_ON_SET_POINT)
        self.base = base & ~mode_bits & 0xFFFF
        """The controlword around the handshake bits (Enable operation, halt clear)."""
        if immediate:
            self.base |= Controlword.CHANGE_SET_IMMEDIATELY
        if relative:
            self.base |= Controlword.RELATIVE
        if change_on_set_point:
            self.base |= Controlword.CHANGE_ON_SET_POINT
        self.requested = False
        """The new set-point bit has been sent."""
        self.accepted = False
        """The drive acknowledged and bit 4 went back to 0: the set-point is the drive's."""

    @property
    def request(self) -> int:
        """The controlword that hands over the set-point (bit 4 set)."""
        return self.base | Controlword.NEW_SET_POINT

    def controlword(self, statusword: int) -> int | None:
        """What to send after seeing ``statusword`` (None: nothing yet)."""
        ack = bool(statusword & Statusword.SET_POINT_ACKNOWLEDGE)
        if self.accepted:
            return None
        if not self.requested:
            if ack:
                return None  # the drive holds a set-point it cannot replace yet
            self.requested = True
            return self.request
        if ack:
            self.accepted = True
            return self.base
        return None


# -- homing ----------------------------------------------------------------------------------


class HomingStatus(enum.Enum):
    """Homing mode's statusword bits 13 (error), 12 (attained) and 10 (target reached)."""

    IN_PROGRESS = (0, 0, 0)
    INTERRUPTED = (0, 0, 1)
    """Interrupted (halt) or not started."""
    ATTAINED = (0, 1, 0)
    """Homing attained, target not reached (still moving to rest)."""
    COMPLETED = (0, 1, 1)
    ERROR_MOVING = (1, 0, 0)
    ERROR_STOPPED = (1, 0, 1)
    RESERVED = (1, 1, 0)

    @property
    def error(self) -> bool:
        """True for the two homing error codes (and the reserved ones)."""
        return self.value[0] == 1


def homing_status(statusword: int) -> HomingStatus:
    """The homing status a statusword shows (in homing mode)."""
    error = 1 if statusword & Statusword.HOMING_ERROR else 0
    attained = 1 if statusword & Statusword.HOMING_ATTAINED else 0
    reached = 1 if statusword & Statusword.TARGET_REACHED else 0
    if error and attained:
        return HomingStatus.RESERVED
    return HomingStatus((error, attained, reached))


class HomeSignal(enum.Enum):
    """What a homing method homes on."""

    NEGATIVE_LIMIT = "negative limit switch"
    POSITIVE_LIMIT = "positive limit switch"
    HOME_SWITCH = "home switch"
    INDEX_PULSE = "index pulse"
    CURRENT_POSITION = "current position"


class HomeSwitch(enum.Enum):
    """The home switch a method expects, and which of its edges homes."""

    POSITIVE = "positive home switch (active on the positive side of its edge)"
    NEGATIVE = "negative home switch (active on the negative side of its edge)"
    LOWER_EDGE = "home switch over part of the travel, its lower (negative) edge"
    UPPER_EDGE = "home switch over part of the travel, its upper (positive) edge"


@dataclass(frozen=True)
class HomingMethod:
    """A CiA 402 homing method (6098h): what it homes on, in which direction it starts,
    which limit switches it may meet, and from which side it makes its final approach.

    The home position is the edge of ``signal`` crossed while moving ``final_direction``
    (a limit switch's edge: where it becomes inactive), or with ``index_pulse`` the first
    index pulse after that edge in ``final_direction``; INDEX_PULSE alone: the first
    index pulse in ``final_direction``; CURRENT_POSITION: where the axis stands.
    """

    number: int
    text: str
    signal: HomeSignal
    index_pulse: bool
    final_direction: int
    """+1 or -1 (0 for the current position)."""
    initial_direction: int
    """+1 or -1; 0 where the home switch's state at the start decides."""
    home_switch: HomeSwitch | None = None
    reversal_limit: HomeSignal | None = None
    """The limit switch the method reverses on if it meets it before the home switch."""

    @property
    def limit_switches(self) -> frozenset[HomeSignal]:
        """The limit switches this method may run into as part of its procedure (any
        other limit switch met ends it with a homing error)."""
        limits = {HomeSignal.NEGATIVE_LIMIT, HomeSignal.POSITIVE_LIMIT}
        return frozenset(s for s in (self.signal, self.reversal_limit) if s in limits)

    @property
    def moves(self) -> bool:
        """False for the current-position methods (35, 37)."""
        return self.signal is not HomeSignal.CURRENT_POSITION


_LOWER = "home switch's lower edge"
_UPPER = "home switch's upper edge"
_START_POS = " (start positive, reverse on the positive limit switch)"
_START_NEG = " (start negative, reverse on the negative limit switch)"


def _homing_methods() -> dict[int, HomingMethod]:
    """Methods 1..14 (index pulse), 17..30 (the same without it), 33, 34, 35, 37."""
    neg, pos, home = HomeSignal.NEGATIVE_LIMIT, HomeSignal.POSITIVE_LIMIT, HomeSignal.HOME_SWITCH
    hs = HomeSwitch
    # number: (signal, final direction, initial direction, home switch, reversal limit, text)
    base: dict[int, tuple[HomeSignal, int, int, HomeSwitch | None, HomeSignal | None, str]] = {
        1: (neg, +1, -1, None, None, "negative limit switch"),
        2: (pos, -1, +1, None, None, "positive limit switch"),
        3: (home, -1, 0, hs.POSITIVE, None, "positive home switch"),
        4: (home, +1, 0, hs.POSITIVE, None, "positive home switch"),
        5: (home, +1, 0, hs.NEGATIVE, None, "negative home switch"),
        6: (home, -1, 0, hs.NEGATIVE, None, "negative home switch"),
        7: (home, -1, +1, hs.LOWER_EDGE, pos, _LOWER + _START_POS),
        8: (home, +1, +1, hs.LOWER_EDGE, pos, _LOWER + _START_POS),
        9: (home, -1, +1, hs.UPPER_EDGE, pos, _UPPER + _START_POS),
        10: (home, +1, +1, hs.UPPER_EDGE, pos, _UPPER + _START_POS),
        11: (home, +1, -1, hs.UPPER_EDGE, neg, _UPPER + _START_NEG),
        12: (home, -1, -1, hs.UPPER_EDGE, neg, _UPPER + _START_NEG),
        13: (home, +1, -1, hs.LOWER_EDGE, neg, _LOWER + _START_NEG),
        14: (home, -1, -1, hs.LOWER_EDGE, neg, _LOWER + _START_NEG),
    }
    methods: dict[int, HomingMethod] = {}
    for n, (signal, final, initial, switch, reversal, text) in base.items():
        side = "positive" if final > 0 else "negative"
        methods[n] = HomingMethod(n, f"{text}; the first index pulse on its {side} side",
                                  signal, True, final, initial, switch, reversal)
        methods[n + 16] = HomingMethod(n + 16, f"{text}; its edge, approached moving {side}",
                                       signal, False, final, initial, switch, reversal)
    methods[33] = HomingMethod(33, "the first index pulse in the negative direction",
                               HomeSignal.INDEX_PULSE, True, -1, -1)
    methods[34] = HomingMethod(34, "the first index pulse in the positive direction",
                               HomeSignal.INDEX_PULSE, True, +1, +1)
    for n in (35, 37):
        methods[n] = HomingMethod(n, "the current position", HomeSignal.CURRENT_POSITION,
                                  False, 0, 0)
    return dict(sorted(methods.items()))


HOMING_METHODS: Mapping[int, HomingMethod] = _homing_methods()
"""The CiA 402 homing methods by number (negative numbers are the vendors' own; 15, 16,
31, 32 and 36 are reserved)."""


def homing_method(number: int) -> HomingMethod:
    """The homing method ``number``; ``ArgumentError`` for a reserved or vendor number."""
    try:
        return HOMING_METHODS[number]
    except KeyError:
        raise ArgumentError(
            f"homing method {number} is not a CiA 402 method (1..14, 17..30, 33, 34, 35, 37;"
            " negative numbers are the vendor's own)"
        ) from None


# -- the objects ------------------------------------------------------------------------------


@dataclass(frozen=True)
class ObjectInfo:
    """A CiA 402 object the profile logic uses: where it sits in the object dictionary,
    its data type and whether a master may write it."""

    index: int
    subindex: int
    bits: int
    signed: bool
    writable: bool
    text: str

    @property
    def minimum(self) -> int:
        """The smallest value of the data type."""
        return -(1 << (self.bits - 1)) if self.signed else 0

    @property
    def maximum(self) -> int:
        """The largest value of the data type."""
        return (1 << (self.bits - 1)) - 1 if self.signed else (1 << self.bits) - 1


def _o(index: int, sub: int, bits: int, signed: bool, writable: bool, text: str) -> ObjectInfo:
    return ObjectInfo(index, sub, bits, signed, writable, text)


OBJECTS: Mapping[str, ObjectInfo] = {
    "error_code": _o(0x603F, 0, 16, False, False, "error code of the last fault"),
    "controlword": _o(0x6040, 0, 16, False, True, "controlword"),
    "statusword": _o(0x6041, 0, 16, False, False, "statusword"),
    "quick_stop_option_code": _o(0x605A, 0, 16, True, True, "quick stop option code"),
    "halt_option_code": _o(0x605D, 0, 16, True, True, "halt option code"),
    "modes_of_operation": _o(0x6060, 0, 8, True, True, "modes of operation"),
    "modes_of_operation_display": _o(0x6061, 0, 8, True, False, "modes of operation display"),
    "position_actual_value": _o(0x6064, 0, 32, True, False, "position actual value"),
    "velocity_actual_value": _o(0x606C, 0, 32, True, False, "velocity actual value"),
    "target_position": _o(0x607A, 0, 32, True, True, "target position"),
    "home_offset": _o(0x607C, 0, 32, True, True, "home offset"),
    "profile_velocity": _o(0x6081, 0, 32, False, True, "profile velocity"),
    "profile_acceleration": _o(0x6083, 0, 32, False, True, "profile acceleration"),
    "profile_deceleration": _o(0x6084, 0, 32, False, True, "profile deceleration"),
    "quick_stop_deceleration": _o(0x6085, 0, 32, False, True, "quick stop deceleration"),
    "homing_method": _o(0x6098, 0, 8, True, True, "homing method"),
    "homing_speed_search": _o(0x6099, 1, 32, False, True, "speed during search for switch"),
    "homing_speed_zero": _o(0x6099, 2, 32, False, True, "speed during search for zero"),
    "homing_acceleration": _o(0x609A, 0, 32, False, True, "homing acceleration"),
    "digital_inputs": _o(0x60FD, 0, 32, False, False, "digital inputs"),
    "target_velocity": _o(0x60FF, 0, 32, True, True, "target velocity"),
    "supported_drive_modes": _o(0x6502, 0, 32, False, False, "supported drive modes"),
}
"""The CiA 402 objects by the names descriptions and the simulated device use."""
