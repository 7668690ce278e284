"""CL86R: RS-485 Modbus RTU closed-loop stepper drive (NEMA34), profile over the bus.

Source: shared/seeds/004_0f4a29f2f07be773.txt (extraction: shared/drives/004_cl86r.md).

The drive keeps plain 16-bit holding registers at 0x0000-0x00DF. Motion is started and
stopped through the bits of the movement control word 0x0036; the auxiliary control
register 0x0037 saves, resets, clears alarms and zeroes the position; 0x0038 enables.
32-bit values are stored high word first (high word at the lower address), except in the
16-entry position table, whose high words sit at 0x0060+n and low words at 0x0070+n.

Acceleration and deceleration are ramp *times* in ms (1..2000). The manual does not say
what the time refers to; this profile (and the twin) take it as the time from standstill
to the move's maximum speed (0x0033, or 0x0041 when homing), so a rate in rev/s² becomes
``|speed_rpm| / 60 / rate * 1000`` ms for the speed of that same move.

Manual contradictions resolved here (the CRC-valid example frames win):
* L469-471/L529 say 0x0010 = decelerating stop and 0x0020 = emergency stop, and L529 starts
  speed mode with 0x0001; the bit table (L245) and the CRC-valid examples use 0x0020 = stop,
  0x0040 = emergency stop, 0x0008 = start speed mode, 0x0010 = start homing.
* The homing block write printed at L710 has a wrong CRC (53 75); the frame this profile
  sends carries the correct one (44 A3). The FC03/FC06/FC10 examples of chapter 5.2 use
  another model's addresses and are not reproduced.
* The DI active-level register 0x0010 is printed with range 0~7 although it has 7 bits;
  0~127 is used.
"""

from __future__ import annotations

import enum
import math
from typing import Annotated, ClassVar

from pydantic import Field, StrictBool, StrictInt

from drivebus.bus import Priority, SlaveHandle
from drivebus.clock import monotonic
from drivebus.drives.base import (
    DriveOptions,
    DriveProfile,
    HomingParams,
    HomingSwitches,
    MoveParams,
    Parameter,
    WriteThrough,
    ramp_time_quantized,
)
from drivebus.drives.io import IOPoint, function_text
from drivebus.drives.programs import Completion, ProgramSupport
from drivebus.drives.registers import Access, Register, WordOrder
from drivebus.drives.status import DriveIdentity, DriveStatus
from drivebus.drives.units import ramp_time_ms
from drivebus.errors import LimitViolation
from drivebus.settings import LineSettings

__all__ = [
    "ACCEL_TIME",
    "AUTO_SAVE",
    "AUX_CONTROL",
    "CONTROL",
    "CURRENT_SPEED",
    "DATA_FORMATS",
    "DECEL_TIME",
    "DI_FUNCTIONS",
    "DI_LEVEL",
    "ENABLE",
    "ERROR_CODE",
    "HOME_CREEP",
    "HOME_MODE",
    "HOME_OFFSET",
    "HOME_RAMP",
    "HOME_SPEED",
    "HOMING_MODES",
    "MAX_SPEED",
    "MICROSTEP",
    "MODEL",
    "OPERATING_MODE",
    "POSITION",
    "SOFTWARE",
    "START_SPEED",
    "STATUS",
    "TARGET",
    "Aux",
    "CL86RProfile",
    "Control",
    "DataFormat",
    "OperatingMode",
    "StatusBit",
    "path_accel",
    "path_decel",
    "path_pulses",
    "path_speed",
    "ramp_time_ms",
]


# -- register map (addresses are the 0-based PDU addresses the manual prints) ------------------

MODEL = Register("drive model", 0x0000, access=Access.R)
SOFTWARE = Register("software version", 0x0001, access=Access.R)
OPERATING_MODE = Register("operating mode", 0x0002, access=Access.R)
STATUS = Register("status word", 0x0003, access=Access.R)
ERROR_CODE = Register("error code", 0x0004, access=Access.R)
INPUTS = Register("input terminal status", 0x0005, access=Access.R)
OUTPUTS = Register("output terminal status", 0x0006, access=Access.R)
POSITION = Register(
    "current position", 0x0007, words=2, signed=True, order=WordOrder.HIGH_FIRST,
    unit="pulses", access=Access.R,
)
CURRENT_SPEED = Register("current speed", 0x0009, signed=True, unit="rpm", access=Access.R)

DI_LEVEL = Register("DI active level", 0x0010, minimum=0, maximum=127)  # manual: "0~7" (7 bits)
DI_FILTER = Register("DI filter time", 0x0011, unit="ms", minimum=0, maximum=1000)
DO_LEVEL = Register("DO active level", 0x0012, minimum=0, maximum=7)
DI_FUNCTIONS = tuple(
    Register(f"X{i} function", 0x0013 + i, minimum=0, maximum=16) for i in range(7)
)
DO_FUNCTIONS = tuple(
    Register(f"Y{i} function", 0x001A + i, minimum=0, maximum=5) for i in range(3)
)
SLAVE_ADDRESS = Register("custom slave address", 0x0020, minimum=1, maximum=31)
DATA_FORMAT = Register("serial data format", 0x0021, minimum=0, maximum=3)
DIRECTION = Register("default direction", 0x0022, minimum=0, maximum=1)
MICROSTEP = Register(
    "microstep (pulses/rev)", 0x0023, unit="pulses/rev", minimum=400, maximum=51200
)
AUTO_SAVE = Register("auto-save RW/S writes", 0x0024, minimum=0, maximum=1)
LIMIT_STOP = Register("limit stop mode", 0x0025, minimum=0, maximum=1)

START_SPEED = Register("start speed", 0x0030, unit="rpm", minimum=2, maximum=300)
ACCEL_TIME = Register("acceleration time", 0x0031, unit="ms", minimum=1, maximum=2000)
DECEL_TIME = Register("deceleration time", 0x0032, unit="ms", minimum=1, maximum=2000)
MAX_SPEED = Register("maximum speed", 0x0033, signed=True, unit="rpm", minimum=-3000, maximum=3000)
TARGET = Register(
    "target position", 0x0034, words=2, signed=True, order=WordOrder.HIGH_FIRST, unit="pulses"
)
CONTROL = Register("movement control word", 0x0036, minimum=0, maximum=127)
AUX_CONTROL = Register("auxiliary control", 0x0037, minimum=0, maximum=8)
ENABLE = Register("motor enable", 0x0038, minimum=0, maximum=1)
PATH_TRIGGER_MODE = Register("multi-segment trigger mode", 0x0039, minimum=0, maximum=1)
PATH_ABSOLUTE = Register("multi-segment absolute mode", 0x003A, minimum=0, maximum=1)

HOME_MODE = Register("homing mode", 0x0040, minimum=0, maximum=35)
HOME_SPEED = Register("homing high speed", 0x0041, unit="rpm", minimum=5, maximum=3000)
HOME_CREEP = Register("homing creep speed", 0x0042, unit="rpm", minimum=5, maximum=300)
HOME_RAMP = Register("homing accel/decel time", 0x0043, unit="ms", minimum=1, maximum=2000)
# Each half is documented as 0~65535; the manual does not say the pair is signed.
HOME_OFFSET = Register("origin offset", 0x0044, words=2, order=WordOrder.HIGH_FIRST, unit="pulses")
JOG_SPEED = Register("JOG speed", 0x0046, unit="rpm", minimum=0, maximum=3000)
JOG_ACCEL = Register("JOG acceleration time", 0x0047, unit="ms", minimum=1, maximum=2000)
JOG_DECEL = Register("JOG deceleration time", 0x0048, unit="ms", minimum=1, maximum=2000)

LOOP_MODE = Register("open/closed loop", 0x0050, minimum=0, maximum=1)
ENCODER_LINES = Register("encoder resolution", 0x0051, minimum=0, maximum=1)
FOLLOWING_ERROR = Register("following-error threshold", 0x0052, minimum=400, maximum=65535)
IN_POSITION_WINDOW = Register("in-position threshold", 0x005C, minimum=1, maximum=200)
IN_POSITION_TIME = Register(
    "positioning completion time", 0x005D, unit="ms", minimum=1, maximum=1000
)


def path_pulses(n: int) -> Register:
    """Position path ``n``'s pulses: high word at 0x0060+n, low word 0x10 further on."""
    _check_path(n)
    return Register(
        f"position path {n} pulses", 0x0060 + n, words=2, signed=True, order=WordOrder.HIGH_FIRST,
        unit="pulses", low_address=0x0070 + n,
    )


def path_speed(n: int) -> Register:
    """Position path ``n``'s running speed."""
    _check_path(n)
    return Register(f"position path {n} speed", 0x0080 + n, unit="rpm", minimum=0, maximum=3000)


def path_accel(n: int) -> Register:
    """Position path ``n``'s acceleration time."""
    _check_path(n)
    return Register(f"position path {n} acceleration time", 0x0090 + n, unit="ms",
                    minimum=1, maximum=2000)


def path_decel(n: int) -> Register:
    """Position path ``n``'s deceleration time."""
    _check_path(n)
    return Register(f"position path {n} deceleration time", 0x00A0 + n, unit="ms",
                    minimum=1, maximum=2000)


def _check_path(n: int) -> None:
    if not 0 <= n <= 15:
        raise LimitViolation(f"CL86R path number {n} is outside 0..15")


class Control(enum.IntFlag):
    """Bits of the movement control word 0x0036 (bit table at L245)."""

    START_POSITION = 0x0001
    ABSOLUTE = 0x0002
    INTERRUPT = 0x0004
    """A new command interrupts a running positioning move (else it is ignored)."""
    START_SPEED = 0x0008
    START_HOMING = 0x0010
    STOP = 0x0020
    EMERGENCY_STOP = 0x0040


class Aux(enum.IntFlag):
    """Values of the auxiliary control register 0x0037."""

    FACTORY_RESET = 0x0001
    SAVE = 0x0002
    CLEAR_ALARM = 0x0004
    ZERO_POSITION = 0x0008


class StatusBit(enum.IntFlag):
    """Bits of the status word 0x0003."""

    IN_PLACE = 0x0001
    HOMED = 0x0002
    RUNNING = 0x0004
    ALARM = 0x0008
    ENABLED = 0x0010


class OperatingMode(enum.IntEnum):
    """Values of the operating-mode register 0x0002."""

    NONE = 0
    POSITION = 1
    SPEED = 2
    HOMING = 3
    JOG = 4
    MULTI_POSITION = 5
    MULTI_SPEED = 6


class DataFormat(enum.IntEnum):
    """Values of the serial data format register 0x0021 (used at 19200 baud and up)."""

    N81 = 0
    N82 = 1
    E81 = 2
    O81 = 3


DATA_FORMATS: dict[str, int] = {"8N1": 0, "8N2": 1, "8E1": 2, "8O1": 3}
"""Line format -> value of 0x0021."""

HOMING_MODES: dict[str, int] = {
    "positive_limit": 18,
    "negative_limit": 17,
    "home_switch_positive": 24,
    "home_switch_negative": 29,
    "current_position": 35,
}
"""Homing method name -> value of 0x0040 (CiA-402 numbering). 18 is the manual's example."""

ALARM_TEXTS: dict[int, str] = {
    1: "overcurrent or phase-to-phase short circuit",
    2: "overvoltage",
    4: "position error too large (following error)",
}

_DI_HOME, _DI_LIMIT_POSITIVE, _DI_LIMIT_NEGATIVE = 1, 2, 3

DI_FUNCTION_NAMES: dict[int, str] = {
    0: "none", 1: "home switch", 2: "positive limit", 3: "negative limit",
    4: "motor release", 5: "alarm clear", 6: "stop", 7: "emergency stop", 8: "jog forward",
    9: "jog reverse", 10: "homing trigger", 11: "position path trigger",
    12: "speed path trigger", 13: "path address bit 0", 14: "path address bit 1",
    15: "path address bit 2", 16: "path address bit 3",
}
"""The input functions (0x0013-0x0019), with the manual's names (L218-L222)."""

DO_FUNCTION_NAMES: dict[int, str] = {
    0: "none", 1: "alarm", 2: "running", 3: "homing done", 4: "in position", 5: "brake",
}
"""The output functions (0x001A-0x001C), with the manual's names (L225-L227)."""
_MONITOR_WORDS = 10  # 0x0000..0x0009 in one read


def _whole_rpm(reg: Register, rpm: float, *, minimum: int | None = None) -> int:
    """``rpm`` rounded to the register's 1-rpm resolution, range-checked."""
    if not math.isfinite(rpm):
        raise LimitViolation(f"register {reg.name} (address {reg.address}): speed {rpm} rpm")
    v = reg.check(round(rpm))
    if minimum is not None and abs(v) < minimum:
        raise LimitViolation(
            f"speed {rpm} rpm for register {reg.name} (address {reg.address}) is outside "
            f"its usable range {minimum}..{reg.hi} rpm for this command"
        )
    return v


def _alarm_text(code: int) -> str:
    """The manual's meaning of error code ``code`` (its values look like bit flags)."""
    if code in ALARM_TEXTS:
        return ALARM_TEXTS[code]
    parts = [text for bit, text in ALARM_TEXTS.items() if code & bit]
    unknown = code & ~sum(ALARM_TEXTS)
    if unknown:
        parts.append(f"undocumented error bits 0x{unknown:04X}")
    return "; ".join(parts)


# -- parameters (``drivebus params``), in the manual's order (chapter 4) --------------------------
# The path tables 0x0060-0x00DF are left out (not used by drivebus); 0x0024 is the
# write-through switch itself (``CL86RProfile.write_through``). RW/S registers are kept in
# EEPROM by a save (0x0037 = 0x0002); the plain RW ones (IO functions, motion, JOG) too, the
# manual says, but it marks them RW, not RW/S: they are listed as stored as well (?).

_CURRENTS = (
    ("base_current", Register("base (holding) current", 0x0053, unit="0.1 A", minimum=0,
                              maximum=80)),
    ("closed_loop_current", Register("closed-loop running current", 0x0054, unit="0.1 A",
                                     minimum=0, maximum=80)),
    ("open_loop_current", Register("open-loop running current", 0x0055, unit="0.1 A",
                                   minimum=0, maximum=80)),
    ("command_filter", Register("command filter time", 0x0056, unit="×50 µs", minimum=0,
                                maximum=1024)),
    ("current_kp", Register("current proportional gain", 0x0057, minimum=1000,
                            maximum=1000)),
    ("current_ki", Register("current integral gain", 0x0058, minimum=200, maximum=200)),
    ("position_kp", Register("position-loop P gain", 0x0059, minimum=0, maximum=1000)),
    ("speed_kp", Register("speed P gain", 0x005A, minimum=0, maximum=1000)),
    ("speed_feed_forward", Register("speed feed-forward gain", 0x005B, minimum=0,
                                    maximum=300)),
)

CL86R_PARAMETERS: tuple[Parameter, ...] = (
    Parameter("di_level", DI_LEVEL),
    Parameter("di_filter", DI_FILTER),
    Parameter("do_level", DO_LEVEL),
    *(Parameter(f"x{i}_function", r) for i, r in enumerate(DI_FUNCTIONS)),
    *(Parameter(f"y{i}_function", r) for i, r in enumerate(DO_FUNCTIONS)),
    Parameter("slave_address", SLAVE_ADDRESS, comms=True),
    Parameter("data_format", DATA_FORMAT, comms=True),
    Parameter("direction", DIRECTION),
    Parameter("microstep", MICROSTEP),
    Parameter("limit_stop", LIMIT_STOP),
    Parameter("start_speed", START_SPEED),
    Parameter("accel_time", ACCEL_TIME),
    Parameter("decel_time", DECEL_TIME),
    Parameter("max_speed", MAX_SPEED),
    Parameter("target", TARGET),
    Parameter("path_trigger_mode", PATH_TRIGGER_MODE),
    Parameter("path_absolute", PATH_ABSOLUTE),
    Parameter("homing_mode", HOME_MODE),
    Parameter("homing_speed", HOME_SPEED),
    Parameter("homing_creep", HOME_CREEP),
    Parameter("homing_ramp", HOME_RAMP),
    Parameter("home_offset", HOME_OFFSET),
    Parameter("jog_speed", JOG_SPEED),
    Parameter("jog_accel", JOG_ACCEL),
    Parameter("jog_decel", JOG_DECEL),
    Parameter("loop_mode", LOOP_MODE),
    Parameter("encoder_lines", ENCODER_LINES),
    Parameter("following_error", FOLLOWING_ERROR),
    *(Parameter(k, r) for k, r in _CURRENTS),
    Parameter("in_position_window", IN_POSITION_WINDOW),
    Parameter("in_position_time", IN_POSITION_TIME),
)
"""The CL86R's parameters (manual chapter 4), in address order."""


class CL86ROptions(DriveOptions):
    """The CL86R's options (see ``CL86RProfile``)."""

    start_speed_rpm: (
        Annotated[StrictInt, Field(ge=START_SPEED.lo, le=START_SPEED.hi)] | None
    ) = None
    interrupt_moves: StrictBool | None = None
    block_writes: StrictBool | None = None


class CL86RProfile(DriveProfile):
    """The CL86R closed-loop stepper drive over Modbus RTU (control word 0x0036).

    Options:
    * ``start_speed_rpm``: the start speed written with every move or speed run
      (0x0030, 2..300 rpm; factory default 5, the manual's examples use 30).
    * ``interrupt_moves``: set control bit 2 so a new move replaces a running one
      (default off, as in the manual's example: the drive then ignores a new move
      while a positioning move runs).
    * ``block_writes``: write a command's parameters in one FC10 frame (the manual's
      "all at once" form, default) or register by register with FC06 (its other form).
    """

    family: ClassVar[str] = "CL86R"
    parameter_list = CL86R_PARAMETERS
    write_through = WriteThrough(AUTO_SAVE, on=1, off=0)
    comms_note = (
        "its baud rate is set by DIP switches SW6/SW7 (9600 is always 8N1); the address "
        "comes from register 0x0020 (1-31) only when SW1-SW5 are all ON, the format from "
        "0x0021 at 19200 baud and up; both take effect after a save and a power cycle"
    )
    no_table: ClassVar[str] = ("its position table starts only from an input assigned "
                               "function 11, its row chosen on inputs 13-16 (manual "
                               "L724-L782); no control-word bit starts it")
    io_inputs: ClassVar[tuple[str, ...]] = tuple(f"X{i}" for i in range(7))
    io_outputs: ClassVar[tuple[str, ...]] = ("Y0", "Y1", "Y2")
    no_output_control: ClassVar[str] = (
        "its outputs Y0-Y2 follow drive functions 0-5 (0x001A-0x001C: none, alarm, running, "
        "homed, in position, brake); none is switched by a register (manual L225-L229)")
    programs: ClassVar[ProgramSupport] = ProgramSupport(
        preload_braking="the manual does not say a move latches its values, and a stop "
        "ramps down with the deceleration time 0x0032 holds at that moment: the next move "
        "is written only as the one before it comes to rest, and only if it brakes no "
        "gentler",
        retarget="control word bit 2: a new command interrupts the running move and runs at "
        "once (CL86R manual L245)",
    )
    word_order: ClassVar[WordOrder] = WordOrder.HIGH_FIRST
    exception_texts: ClassVar[dict[int, str]] = {
        1: "illegal function code",
        2: "illegal register address",
        3: "illegal data",
        4: "CRC check error",
    }
    homing_methods: ClassVar[tuple[str, ...]] = tuple(HOMING_MODES)
    options: ClassVar[type[DriveOptions]] = CL86ROptions
    pulses_per_rev_allowed = range(MICROSTEP.lo, MICROSTEP.hi + 1)
    addresses = range(1, 32)  # DIP switches SW1-SW5, or register 0x0020 (1..31)
    baud_rates = (9600, 19200, 38400, 115200)  # DIP switches SW6/SW7
    line_formats = tuple(DATA_FORMATS)  # register 0x0021, from 19200 baud up

    def __init__(
        self,
        slave: SlaveHandle,
        *,
        pulses_per_rev: int = 1000,
        start_speed_rpm: int = 5,
        interrupt_moves: bool = False,
        block_writes: bool = True,
    ) -> None:
        self.check_options(dict(start_speed_rpm=start_speed_rpm,
                                interrupt_moves=interrupt_moves, block_writes=block_writes))
        super().__init__(slave, pulses_per_rev=pulses_per_rev)
        self.start_speed_rpm = start_speed_rpm
        self.interrupt_moves = interrupt_moves
        self.block_writes = block_writes
        self._di_functions: tuple[int, ...] = (1, 2, 3, 0, 0, 0, 0)  # factory X0..X6
        self._di_invert = 0
        self._speed_rpm: int | None = None
        """|maximum speed| last written: the reference of a stop's decel time."""

    @classmethod
    def settings_problem(cls, settings: LineSettings) -> str | None:
        """As declared, and at 9600 baud the format is fixed at 8N1 (0x0021 is ignored)."""
        problem = super().settings_problem(settings)
        if problem is None and settings.baudrate == 9600 and settings.format != "8N1":
            return "the CL86R runs 8N1 only at 9600 baud (0x0021 applies from 19200 up)"
        return problem

    # -- helpers --------------------------------------------------------------------------------

    async def _write_params(
        self, pairs: list[tuple[Register, int]], *, priority: Priority = Priority.COMMAND
    ) -> None:
        """Write parameter registers (all checked first) in one FC10 or one by one."""
        for reg, value in pairs:
            reg.check(value)
        if self.block_writes:
            await self.write_block(pairs, priority=priority)
            return
        for reg, value in pairs:
            await self.write(reg, value, priority=priority)

    async def _control(self, word: int, *, priority: Priority, idempotent: bool) -> None:
        await self.write(CONTROL, word, priority=priority, idempotent=idempotent)

    def _input(self, inputs: int, function: int) -> bool:
        """True if an input assigned ``function`` is active (level inversion applied)."""
        for i, fn in enumerate(self._di_functions):
            if fn == function and ((inputs ^ self._di_invert) >> i) & 1:
                return True
        return False

    # -- procedures -----------------------------------------------------------------------------

    async def setup(self) -> None:
        """Write the pulses per revolution (0x0023) and learn the input assignments.

        The drive has no mode-select register: the mode follows the control-word bit.
        """
        await self.write(MICROSTEP, self.pulses_per_rev)
        await self.learn()

    async def learn(self) -> None:
        """The input levels and functions (0x0010.., read only): where the switches are."""
        words = await self.slave.read_holding_registers(DI_LEVEL.address, 10)
        self._di_invert = words[0]
        self._di_functions = tuple(words[3:10])

    def volatile_settings(self) -> list[tuple[Register, int]]:
        """The pulses per revolution setup() wrote (0x0023; a power cycle restores the
        EEPROM value)."""
        return [(MICROSTEP, self.pulses_per_rev)]

    async def read_status(self, *, priority: Priority = Priority.POLL) -> DriveStatus:
        """One read of 0x0000-0x0009: mode, status word, error code, inputs, position, speed."""
        w = await self.slave.read_holding_registers(0, _MONITOR_WORDS, priority=priority)
        status, error, inputs = w[3], w[4], w[5]
        running = bool(status & StatusBit.RUNNING)
        homed = bool(status & StatusBit.HOMED)
        alarm = bool(status & StatusBit.ALARM) or error != 0
        return DriveStatus(
            enabled=bool(status & StatusBit.ENABLED),
            moving=running,
            in_position=bool(status & StatusBit.IN_PLACE) and not running,
            homed=homed,
            alarm=alarm,
            alarm_code=error if alarm else None,
            alarm_text=_alarm_text(error) if alarm and error else "",
            limit_positive=self._input(inputs, _DI_LIMIT_POSITIVE),
            limit_negative=self._input(inputs, _DI_LIMIT_NEGATIVE),
            homing=w[2] == OperatingMode.HOMING and running and not homed,
            position=POSITION.decode(w[7:9]),
            velocity_rpm=float(CURRENT_SPEED.decode([w[9]])),
            raw={
                "mode": w[2], "status": status, "error": error, "inputs": inputs,
                "outputs": w[6], "position_high": w[7], "position_low": w[8], "speed": w[9],
            },
            timestamp=monotonic(),
        )

    MODEL_CODE: ClassVar[int] = 862
    """What register 0x0000 reads on a CL86R (manual: the model code)."""

    def is_own_identity(self, ident: DriveIdentity) -> bool:
        """Model code 862."""
        return ident.raw.get("model") == self.MODEL_CODE

    async def read_identity(self) -> DriveIdentity:
        """Model code (0x0000, 862 for the CL86R) and software version (0x0001)."""
        model, software = await self.slave.read_holding_registers(MODEL.address, 2)
        return DriveIdentity(
            self.family,
            model=f"CL86R (model code {model})",
            firmware=str(software),
            raw={"model": model, "software": software},
        )

    async def enable(self) -> None:
        """Enable the motor: 0x0038 = 1."""
        await self.write(ENABLE, 1, priority=Priority.COMMAND)

    async def disable(self) -> None:
        """Release the motor (free shaft): 0x0038 = 0."""
        await self.write(ENABLE, 0, priority=Priority.COMMAND)

    def quantize(self, params: MoveParams) -> MoveParams:
        """Whole rpm, and ramps as whole milliseconds to reach it (0x0031/0x0032)."""
        return ramp_time_quantized(params)

    def check_move(self, params: MoveParams) -> None:
        """Range-check the speed and the ramp times a move would write."""
        speed = _whole_rpm(MAX_SPEED, abs(params.speed_rpm), minimum=1)
        ramp_time_ms(ACCEL_TIME, speed, params.accel_rps2)
        ramp_time_ms(DECEL_TIME, speed, params.decel_rps2)

    async def _move(self, target: int, params: MoveParams, *, absolute: bool) -> None:
        await self._write_move(target, params)
        await self._start_move(absolute=absolute)

    async def _write_move(self, target: int, params: MoveParams) -> None:
        speed = _whole_rpm(MAX_SPEED, abs(params.speed_rpm), minimum=1)
        accel = ramp_time_ms(ACCEL_TIME, speed, params.accel_rps2)
        decel = ramp_time_ms(DECEL_TIME, speed, params.decel_rps2)
        await self._write_params([
            (START_SPEED, self.start_speed_rpm), (ACCEL_TIME, accel), (DECEL_TIME, decel),
            (MAX_SPEED, speed), (TARGET, target),
        ])
        self._speed_rpm = speed

    async def _start_move(self, *, absolute: bool) -> None:
        word = Control.START_POSITION
        if absolute:
            word |= Control.ABSOLUTE
        if self.interrupt_moves:
            word |= Control.INTERRUPT
        await self._control(int(word), priority=Priority.COMMAND, idempotent=False)

    async def move_absolute(self, position: int, params: MoveParams) -> None:
        """Write 0x0030-0x0035 (speed is positive; the target's sign gives direction), 0x0036=3."""
        await self._move(position, params, absolute=True)

    async def prepare_absolute(self, position: int, params: MoveParams) -> None:
        """0x0030-0x0035: everything but the start."""
        await self._write_move(position, params)

    async def start_absolute(self) -> None:
        """0x0036 = 3 starts the prepared absolute move."""
        await self._start_move(absolute=True)

    async def move_relative(self, distance: int, params: MoveParams) -> None:
        """Write 0x0030-0x0035 (signed distance), then 0x0036 = 0x0001."""
        await self._move(distance, params, absolute=False)

    async def speed_run(self, speed_rpm: float, accel_rps2: float, decel_rps2: float) -> None:
        """Speed mode: write 0x0030-0x0033 (signed speed), then 0x0036 = 0x0008.

        This is also the only way to jog over Modbus: the drive's JOG function
        (0x0046-0x0048) runs only from inputs assigned functions 8/9. Calling again while
        running writes the new speed and re-issues the start; the manual does not say
        whether the drive changes speed on the fly (the twin does). A speed that rounds to
        0 rpm is a decelerating stop.
        """
        speed = _whole_rpm(MAX_SPEED, speed_rpm)
        if speed == 0:
            await self.stop(decel_rps2)
            return
        accel = ramp_time_ms(ACCEL_TIME, speed, accel_rps2)
        decel = ramp_time_ms(DECEL_TIME, speed, decel_rps2)
        await self._write_params([
            (START_SPEED, self.start_speed_rpm), (ACCEL_TIME, accel), (DECEL_TIME, decel),
            (MAX_SPEED, speed),
        ])
        self._speed_rpm = abs(speed)
        await self._control(int(Control.START_SPEED), priority=Priority.COMMAND, idempotent=False)

    async def stop(self, decel_rps2: float | None = None) -> None:
        """Decelerating stop: 0x0036 = 0x0020 (with ``decel_rps2``, 0x0032 is rewritten first).

        The new decel time refers to the last speed this profile wrote; without one the
        drive's present deceleration time is used.
        """
        if decel_rps2 is not None and self._speed_rpm:
            decel = ramp_time_ms(DECEL_TIME, self._speed_rpm, decel_rps2)
            await self.write(DECEL_TIME, decel, priority=Priority.EMERGENCY)
        await self._control(int(Control.STOP), priority=Priority.EMERGENCY, idempotent=True)

    async def emergency_stop(self) -> None:
        """Emergency stop: 0x0036 = 0x0040."""
        await self._control(
            int(Control.EMERGENCY_STOP), priority=Priority.EMERGENCY, idempotent=True
        )

    def homing_mode(self, method: str | None) -> int:
        """The 0x0040 value for ``method`` (a name of ``homing_methods`` or its mode number)."""
        name = self.homing_methods[0] if method is None else method
        if name in HOMING_MODES:
            return HOMING_MODES[name]
        if name.isdigit() and int(name) in HOMING_MODES.values():
            return int(name)
        raise self.unsupported(
            f"home with method {method!r}",
            "it documents " + ", ".join(f"{k} ({v})" for k, v in HOMING_MODES.items()),
        )

    def homing_switches(self, method: str | None) -> HomingSwitches:
        """17/18 home on the negative/positive limit switch; 24/29 search the home switch
        positive/negative and reverse at the limit switch in that direction (CiA 402)."""
        mode = self.homing_mode(method)
        on = {17: -1, 18: 1}.get(mode)
        if on is not None:
            return HomingSwitches(homes_on=frozenset({on}))
        reverse = {24: 1, 29: -1}.get(mode)
        return HomingSwitches(reverses_at=frozenset({reverse} if reverse else ()))

    async def start_homing(self, params: HomingParams) -> None:
        """Write the origin offset (0x0044/45), mode and speeds (0x0040-0x0043), 0x0036 = 0x0010.

        ``accel_rps2`` becomes the homing ramp time referred to ``speed_rpm``. The offset
        is the position the drive assigns to the origin edge (CiA-402 reading, the manual
        is silent); its documented range is 0..2^32-1.
        """
        mode = self.homing_mode(params.method)
        high = _whole_rpm(HOME_SPEED, params.speed_rpm)
        creep = _whole_rpm(HOME_CREEP, params.creep_rpm)
        ramp = ramp_time_ms(HOME_RAMP, high, params.accel_rps2)
        HOME_OFFSET.check(params.offset)
        await self.write(HOME_OFFSET, params.offset, priority=Priority.COMMAND)
        await self._write_params(
            [(HOME_MODE, mode), (HOME_SPEED, high), (HOME_CREEP, creep), (HOME_RAMP, ramp)]
        )
        await self._control(int(Control.START_HOMING), priority=Priority.COMMAND, idempotent=False)

    async def clear_alarm(self) -> None:
        """Clear a latched alarm: 0x0037 = 0x0004 (remove the cause first)."""
        await self.write(AUX_CONTROL, int(Aux.CLEAR_ALARM), priority=Priority.COMMAND)

    async def zero_position(self) -> None:
        """Make the present absolute position zero: 0x0037 = 0x0008."""
        await self.write(
            AUX_CONTROL, int(Aux.ZERO_POSITION), priority=Priority.COMMAND, idempotent=False
        )

    def comms_writes(
        self, address: int | None, settings: LineSettings | None, current: LineSettings | None
    ) -> list[tuple[Register, int]]:
        """0x0020 (address 1-31, used with SW1-SW5 all ON) and 0x0021 (format, at 19200 up);
        the baud rate is the DIP switches'."""
        writes: list[tuple[Register, int]] = []
        if address is not None:
            SLAVE_ADDRESS.check(address)
            writes.append((SLAVE_ADDRESS, address))
        if settings is not None:
            if current is not None and settings.baudrate != current.baudrate:
                raise self.unsupported(
                    f"change its baud rate to {settings.baudrate}",
                    "the baud rate is set by DIP switches SW6/SW7 only")
            if settings.baudrate == 9600 and settings.format != "8N1":
                raise self.unsupported(f"talk {settings.format} at 9600 baud",
                                       "at 9600 baud it talks 8N1 only")
            writes.append((DATA_FORMAT, DATA_FORMATS[settings.format]))
        return writes

    async def save_parameters(self) -> None:
        """Store the parameters in EEPROM: 0x0037 = 0x0002."""
        await self.write(AUX_CONTROL, int(Aux.SAVE))

    async def factory_reset(self) -> None:
        """Restore the factory settings: 0x0037 = 0x0001."""
        await self.write(AUX_CONTROL, int(Aux.FACTORY_RESET), idempotent=False)

    # -- motion programs --------------------------------------------------------------------

    async def retarget_absolute(self, position: int, params: MoveParams) -> None:
        """0x0030-0x0035, then 0x0036 = 0x0007: an absolute move that interrupts the one
        running (bit 2) and runs at once from the present speed (manual L245)."""
        await self._write_move(position, params)
        word = Control.START_POSITION | Control.ABSOLUTE | Control.INTERRUPT
        await self._control(int(word), priority=Priority.COMMAND, idempotent=False)

    async def read_completion(self, *, priority: Priority = Priority.COMMAND) -> Completion:
        """0x0003..0x0005 (status word, error code, inputs): three registers of the ten."""
        status, error, inputs = await self.slave.read_holding_registers(
            STATUS.address, 3, priority=priority)
        running = bool(status & StatusBit.RUNNING)
        return Completion(
            moving=running,
            in_position=bool(status & StatusBit.IN_PLACE) and not running,
            alarm=bool(status & StatusBit.ALARM) or error != 0,
            limit_positive=self._input(inputs, _DI_LIMIT_POSITIVE),
            limit_negative=self._input(inputs, _DI_LIMIT_NEGATIVE),
        )

    # -- digital I/O --------------------------------------------------------------------------

    async def io_points(self) -> list[IOPoint]:
        """X0-X6 with their functions (0x0013-0x0019), Y0-Y2 with theirs (0x001A-0x001C)."""
        words = await self.slave.read_holding_registers(DI_FUNCTIONS[0].address, 10,
                                                        priority=Priority.CONFIG)
        return ([IOPoint(n, False, function_text(DI_FUNCTION_NAMES, w))
                 for n, w in zip(self.io_inputs, words[:7], strict=True)]
                + [IOPoint(n, True, function_text(DO_FUNCTION_NAMES, w))
                   for n, w in zip(self.io_outputs, words[7:], strict=True)])

    # -- CL86R specifics ------------------------------------------------------------------------

    async def set_line_format(self, fmt: str) -> None:
        """Write the serial data format (0x0021: 8N1/8N2/8E1/8O1).

        It applies at 19200 baud and up (9600 is always 8N1) and, as the manual reads,
        only after the drive is powered up again.
        """
        code = DATA_FORMATS.get(fmt.upper())
        if code is None:
            raise LimitViolation(
                f"line format {fmt!r} for register {DATA_FORMAT.name} (address "
                f"{DATA_FORMAT.address}) is not one of {', '.join(DATA_FORMATS)}"
            )
        await self.write(DATA_FORMAT, code)

    async def set_baudrate(self, baudrate: int) -> None:
        """Not possible: the baud rate is set only by DIP switches."""
        raise self.unsupported(
            f"set its baud rate to {baudrate}", "only DIP switches SW6/SW7 select it"
        )

    async def jog(self, forward: bool = True) -> None:
        """Not possible as such: JOG has no Modbus command. Use ``speed_run``."""
        raise self.unsupported(
            "start its JOG function",
            "JOG (0x0046-0x0048) runs only from inputs assigned functions 8/9; "
            "jog over Modbus with speed_run() (speed mode)",
        )

    async def start_path(self, path: int) -> None:
        """Not possible: the position/speed tables are started only from inputs."""
        raise self.unsupported(
            f"start position/speed path {path}",
            "paths are triggered only by inputs assigned functions 11/12",
        )

    async def write_position_path(
        self, path: int, pulses: int, speed_rpm: float, accel_rps2: float, decel_rps2: float
    ) -> None:
        """Fill position-table entry ``path`` (0..15) for input-triggered use."""
        speed = _whole_rpm(path_speed(path), speed_rpm, minimum=1)
        accel = ramp_time_ms(path_accel(path), speed, accel_rps2)
        decel = ramp_time_ms(path_decel(path), speed, decel_rps2)
        path_pulses(path).check(pulses)
        await self.write(path_pulses(path), pulses)
        await self.write(path_speed(path), speed)
        await self.write(path_accel(path), accel)
        await self.write(path_decel(path), decel)

    async def read_position_path_pulses(self, path: int) -> int:
        """The pulses of position-table entry ``path`` (high and low word read apart)."""
        return await self.read(path_pulses(path))
