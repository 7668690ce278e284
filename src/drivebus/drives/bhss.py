"""Bholanath BHSS-100-MBUS closed-loop stepper ("step servo"): register map and profile.

Source: the vendor manual (``shared/seeds/001_802d4bcf625a8273.txt``) and its extraction
(``shared/drives/001_bhss.md``). The drive is Modbus RTU only, answers FC03/FC06/FC16,
keeps 32-bit values high word first, starts motion with register 0x0027 and stops it with
0x0028. Accelerations are ramp *times* in ms (0x0021/0x0022/0x0034); this profile turns
the rev/s² it receives into ramp times as ``speed / accel`` (the time to ramp from rest
to the commanded speed), range-checked against the drive's 0..2000 ms (30..2000 ms for
homing). The start speed 0x0020 is left as it is unless the constructor sets it.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Annotated, ClassVar, Literal

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
from drivebus.errors import ConfigError, DriveAlarm, LimitViolation
from drivebus.settings import LineSettings

__all__ = [
    "ALARM_TEXTS",
    "EXCEPTION_TEXTS",
    "INPUT_FUNCTIONS",
    "INPUT_TERMINALS",
    "MICROSTEP_TABLE",
    "BHSSProfile",
    "Regs",
    "StatusBit",
]

log = logging.getLogger(__name__)



class Regs:
    """The BHSS register map (raw 0-based PDU addresses, manual Table 10)."""

    # status group (read-only)
    MODEL = Register("drive model", 0x0000, access=Access.R)
    FIRMWARE = Register("driver version", 0x0001, access=Access.R)
    NODE = Register("node number", 0x0002, access=Access.R)
    MODE = Register("drive mode", 0x0003, access=Access.R)
    MOTOR_STATE = Register("motor state", 0x0004, access=Access.R)
    DIRECTION = Register("motor direction", 0x0005, access=Access.R)
    ERROR_CODE = Register("current error code", 0x0006, access=Access.R)
    STATUS = Register("motion status bits", 0x0007, access=Access.R)
    INPUTS = Register("input terminal state", 0x0008, access=Access.R)
    OUTPUTS = Register("output terminal state", 0x0009, access=Access.R)
    POSITION = Register(
        "current position", 0x000A, words=2, signed=True, order=WordOrder.HIGH_FIRST, unit="pulses",
        access=Access.R,
    )
    # control group 1 (configuration)
    PULSE_POLARITY = Register("pulse/direction polarity", 0x0010, minimum=0, maximum=3)
    MICROSTEP = Register("microstep setting", 0x0011, minimum=0, maximum=15)
    LOOP_MODE = Register("open/closed loop", 0x0012, minimum=0, maximum=1)
    NODE_CUSTOM = Register("custom node number", 0x0013, minimum=0, maximum=127)
    BAUD_CUSTOM = Register("custom baud rate", 0x0014, minimum=0, maximum=3)
    DATA_FORMAT = Register("serial data format", 0x0015, minimum=0, maximum=3)
    EEPROM_UPDATE = Register("EEPROM update of Modbus writes", 0x0016, minimum=0, maximum=1)
    LIMIT_STOP = Register("stop method at a limit", 0x0017, minimum=0, maximum=1)
    CONTROL_SOURCE = Register("control source", 0x0018, minimum=0, maximum=2)
    # control group 2 (motion and commands)
    START_SPEED = Register("start speed", 0x0020, unit="rpm", minimum=2, maximum=300)
    ACCEL_TIME = Register("acceleration time", 0x0021, unit="ms", minimum=0, maximum=2000)
    DECEL_TIME = Register("deceleration time", 0x0022, unit="ms", minimum=0, maximum=2000)
    MAX_SPEED = Register(
        "maximum speed", 0x0023, signed=True, unit="rpm", minimum=-3000, maximum=3000
    )
    DISTANCE = Register("total number of pulses", 0x0024, words=2, signed=True,
                        order=WordOrder.HIGH_FIRST,
                        unit="pulses")
    DISTANCE_HIGH = Register("total number of pulses, high word", 0x0024)
    DISTANCE_LOW = Register("total number of pulses, low word", 0x0025)
    IO_ABSOLUTE = Register("relative/absolute (IO and PT moves)", 0x0026, minimum=0, maximum=1)
    START = Register("start command", 0x0027, minimum=0, maximum=6, access=Access.W)
    STOP = Register("stop command", 0x0028, minimum=0, maximum=1)
    ENABLE = Register("motor enable/release", 0x0029, minimum=0, maximum=1)
    CLEAR_ALARM = Register("clear alarm", 0x002A, minimum=0, maximum=1)
    FACTORY_RESET = Register("restore factory settings", 0x002B, minimum=0, maximum=1)
    ZERO_POSITION = Register("clear current position", 0x002C, minimum=0, maximum=1)
    # homing group
    HOME_START = Register("back to origin enable", 0x0030, minimum=0, maximum=1)
    HOME_MODE = Register("back to origin mode", 0x0031, minimum=0, maximum=3)
    HOME_SPEED = Register("back to origin speed", 0x0032, unit="rpm", minimum=5, maximum=3000)
    HOME_CREEP = Register("back to origin query speed", 0x0033, unit="rpm", minimum=5,
                          maximum=300)
    HOME_RAMP = Register("back to origin accel/decel time", 0x0034, unit="ms", minimum=30,
                         maximum=2000)
    HOME_OFFSET_POS = Register("origin positive compensation", 0x0035, unit="pulses",
                               minimum=0, maximum=65535)
    HOME_OFFSET_NEG = Register("origin negative compensation", 0x0036, unit="pulses",
                               minimum=0, maximum=65535)
    # input/output group
    INPUT_INVERT = Register("input active level", 0x0040)
    INPUT_FUNCTION_BASE = 0x0041  # PU, DR, X0..X4 at 0x0041..0x0047, range 0..20
    OUTPUT_INVERT = Register("output active level", 0x004B)


class StatusBit:
    """Bits of the motion status register 0x0007."""

    POSITION_REACHED = 1 << 0
    HOMED = 1 << 1
    TURNING = 1 << 2
    ALARM = 1 << 3
    RELEASED = 1 << 4
    AT_COMMAND = 1 << 5


MICROSTEP_TABLE: tuple[int, ...] = (
    400, 800, 1600, 3200, 6400, 12800, 25600, 51200,
    1000, 2000, 4000, 5000, 8000, 10000, 20000, 40000,
)
"""Pulses per revolution for each value of register 0x0011 (index = register value)."""

INPUT_TERMINALS: tuple[str, ...] = ("PU", "DR", "X0", "X1", "X2", "X3", "X4")
"""Input terminals in the order of their function registers 0x0041.. and of 0x0008's bits."""

INPUT_FUNCTIONS: dict[str, int] = {
    "none": 0, "origin": 1, "forward_limit": 2, "backward_limit": 3, "enable": 4,
    "release": 5, "alarm_clear": 6, "factory_reset": 7, "stop": 8, "emergency_stop": 9,
    "position_move": 10, "speed_run": 11, "jog_forward": 12, "jog_backward": 13,
    "home": 14, "pt_enable": 15, "pin0": 16, "pin1": 17, "pin2": 18, "pin3": 19, "pin4": 20,
}
"""Input function codes of registers 0x0041..0x0047 (3, 9 and 11 inferred from the order)."""

EXCEPTION_TEXTS: dict[int, str] = {
    1: "CRC parity error: the drive received a frame with a bad CRC",
    2: "command error: the drive does not accept this function code",
    3: "function code address error: no register at this address",
    4: "beyond the function code address: address outside the register map",
    5: "read count overflow: at most 16 registers per read",
    6: "read/write attribute error: the register is read-only or write-only",
    7: "write value error: the value is outside the register's range",
}
"""The BHSS's own meanings of exception codes 01-07 (manual Table 11); none is standard."""

ALARM_TEXTS: dict[int, str] = {
    1: "Err1 over-current or phase short circuit (clears only by a power cycle)",
    2: "Err2 supply voltage too high (clears by itself when the voltage recovers)",
    3: "Err3 supply voltage too low (clears by itself when the voltage recovers)",
    4: "Err4 EEPROM read/write error (clear alarm resets it)",
    5: "Err5 position deviation, following error (clears only by a power cycle)",
}
"""Alarm codes of register 0x0006 (manual table "Fault codes and treatment measures")."""

_HOMING_MODES: dict[str, int] = {
    "forward_limit_origin": 0,
    "backward_limit_origin": 1,
    "forward_limit": 2,
    "backward_limit": 3,
}

_START_RELATIVE = 1
_START_SPEED = 2
_START_ABSOLUTE = 5
_STATUS_BLOCK = (0x0003, 9)  # drive mode .. position low word, gap-free
_MAX_PULSE_RATE = 200_000  # the drive's pulse output cap (L438-L439)


# -- parameters (``drivebus params``), in the manual's order (Table 10) ---------------------------
# The multi-position (PT) tables 0x0080-0x00F0 are left out (not used by drivebus); 0x0016
# is the write-through switch itself (``BHSSProfile.write_through``).

_OUTPUT_FUNCTIONS = tuple(
    Register(f"Y{i} output function", 0x004C + i, minimum=0, maximum=8) for i in range(3)
)
_TUNING = (
    ("encoder_lines", Register("encoder resolution", 0x0110, minimum=0, maximum=1)),
    ("closed_loop_current", Register("closed-loop current", 0x0112, unit="%", minimum=0,
                                     maximum=150)),
    ("open_loop_current", Register("open-loop current", 0x0113, unit="%", minimum=0,
                                   maximum=100)),
    ("lock_current", Register("lock current", 0x0114, unit="%", minimum=0, maximum=100)),
    ("lock_current_delay", Register("lock current delay", 0x0115, minimum=100, maximum=500)),
    ("deviation_alarm", Register("position deviation alarm threshold", 0x0116, minimum=0,
                                 maximum=20000)),
    ("in_position_window", Register("position-reached threshold", 0x0117, minimum=1,
                                    maximum=4000)),
    ("speed_smoothing", Register("speed smoothing", 0x0118, minimum=0, maximum=1024)),
)
_BAUD_CODES = (9600, 14400, 128000, 256000)  # 0x0014, used with SW6 = SW7 = ON
_FORMAT_CODES = ("8N1", "8N2", "8E1", "8O1")  # 0x0015

BHSS_PARAMETERS: tuple[Parameter, ...] = (
    Parameter("pulse_polarity", Regs.PULSE_POLARITY),
    Parameter("microstep", Regs.MICROSTEP),
    Parameter("loop_mode", Regs.LOOP_MODE),
    Parameter("custom_node", Regs.NODE_CUSTOM, comms=True),
    Parameter("custom_baud", Regs.BAUD_CUSTOM, comms=True),
    Parameter("data_format", Regs.DATA_FORMAT, comms=True),
    Parameter("limit_stop", Regs.LIMIT_STOP),
    Parameter("control_source", Regs.CONTROL_SOURCE),
    Parameter("start_speed", Regs.START_SPEED),
    Parameter("accel_time", Regs.ACCEL_TIME),
    Parameter("decel_time", Regs.DECEL_TIME),
    Parameter("max_speed", Regs.MAX_SPEED),
    Parameter("distance", Regs.DISTANCE),
    Parameter("io_absolute", Regs.IO_ABSOLUTE),
    Parameter("homing_mode", Regs.HOME_MODE),
    Parameter("homing_speed", Regs.HOME_SPEED),
    Parameter("homing_creep", Regs.HOME_CREEP),
    Parameter("homing_ramp", Regs.HOME_RAMP),
    Parameter("home_offset_positive", Regs.HOME_OFFSET_POS),
    Parameter("home_offset_negative", Regs.HOME_OFFSET_NEG),
    Parameter("input_invert", Regs.INPUT_INVERT),
    *(Parameter(f"{t.lower()}_function", Register(f"{t} input function",
                                                  Regs.INPUT_FUNCTION_BASE + i,
                                                  minimum=0, maximum=20))
      for i, t in enumerate(INPUT_TERMINALS)),
    Parameter("output_invert", Regs.OUTPUT_INVERT),
    *(Parameter(f"y{i}_function", r) for i, r in enumerate(_OUTPUT_FUNCTIONS)),
    *(Parameter(k, r) for k, r in _TUNING),
)
"""The BHSS's parameters (manual Table 10), in address order."""

_OUTPUT_FUNCTION_NAMES: dict[int, str] = {
    0: "undefined", 1: "alarm", 2: "running", 3: "homing complete", 4: "position reached",
    5: "PT mode", 6: "POUT0", 7: "POUT1", 8: "POUT2",
}
"""The output functions (0x004C-0x004E), with the manual's names (L525-L536)."""

_Terminal = Literal[INPUT_TERMINALS]  # type: ignore[valid-type]
_InputFunction = Literal[tuple(INPUT_FUNCTIONS)]  # type: ignore[valid-type]


class BHSSOptions(DriveOptions):
    """The BHSS's options (see ``BHSSProfile``)."""

    eeprom_write_through: StrictBool | None = None
    start_speed_rpm: (
        Annotated[StrictInt, Field(ge=Regs.START_SPEED.lo, le=Regs.START_SPEED.hi)] | None
    ) = None
    write_multiple: StrictBool | None = None
    inputs: dict[_Terminal, _InputFunction] | None = None


def _input_function_register(index: int) -> Register:
    """The function register of input terminal ``index`` (PU, DR, X0..X4)."""
    return Register(f"{INPUT_TERMINALS[index]} input function",
                    Regs.INPUT_FUNCTION_BASE + index, minimum=0, maximum=20)


class BHSSProfile(DriveProfile):
    """Profile of the Bholanath BHSS-100-MBUS (Modbus RTU, 8N1/8N2/8E1/8O1).

    EEPROM wear: out of the box the drive writes *every* Modbus write to EEPROM (register
    0x0016 = 0), so each move's speed, ramp, target and start writes would wear it out.
    ``setup()`` therefore writes 0x0016 = 1 (Modbus writes go to RAM only) unless the
    profile is built with ``eeprom_write_through=True``, which makes ``setup()`` write
    0x0016 = 0 instead: every Modbus write, configuration and motion command alike, is then
    stored (the factory behaviour). The drive has no "save now" command, so
    ``save_parameters()`` only works with ``eeprom_write_through=True`` (where it has
    nothing left to do) and otherwise raises ``NotSupported``.

    Other options: ``start_speed_rpm`` makes ``setup()`` write the start speed 0x0020
    (None leaves it); ``write_multiple=True`` writes a move's 32-bit distance with one FC16
    instead of two FC06 writes (the manual documents FC16 with a working example although
    its error table claims only 03/06 are accepted, so FC06 is the default); ``inputs``
    maps terminals ("PU", "DR", "X0".."X4") to functions (keys of ``INPUT_FUNCTIONS``,
    e.g. ``{"X0": "origin", "X1": "forward_limit", "X2": "backward_limit"}``) and makes
    ``setup()`` write them. ``setup()`` reads the input functions back to know which input
    bits are the limit switches reported in ``DriveStatus``.
    """

    family: ClassVar[str] = "BHSS"
    no_table: ClassVar[str] = ("drivebus does not drive its multi-position (PT) "
                               "sequencer (0x0070) yet")
    io_inputs: ClassVar[tuple[str, ...]] = INPUT_TERMINALS
    io_outputs: ClassVar[tuple[str, ...]] = ("Y0", "Y1", "Y2")
    no_output_control: ClassVar[str] = (
        "its outputs follow drive functions (0x004C-0x004E); POUT0-2 (functions 6-8) are "
        "switched by the multi-position (PT) sequencer's segments, not by a register "
        "(manual L991-L1000)")
    programs: ClassVar[ProgramSupport] = ProgramSupport(
        preload="a motion latches its ramps when it starts (a stop uses the deceleration time "
        "in effect at the start, BHSS manual L1229-L1233); speed and distance are taken at "
        "the 0x0027 start as well",
        no_retarget="its manual does not say what a start (0x0027) does while the motor turns",
    )
    word_order: ClassVar[WordOrder] = WordOrder.HIGH_FIRST
    exception_texts: ClassVar[dict[int, str]] = EXCEPTION_TEXTS
    homing_methods: ClassVar[tuple[str, ...]] = tuple(_HOMING_MODES)
    options: ClassVar[type[DriveOptions]] = BHSSOptions
    pulses_per_rev_allowed = tuple(sorted(MICROSTEP_TABLE))  # register 0x0011's table
    addresses = range(1, 128)  # 1-31 by DIP switch, 32-127 in register 0x0013
    baud_rates = (9600, 14400, 19200, 38400, 115200, 128000, 256000)  # switches, or 0x0014
    line_formats = ("8N1", "8N2", "8E1", "8O1")  # register 0x0015
    parameter_list = BHSS_PARAMETERS
    write_through = WriteThrough(Regs.EEPROM_UPDATE, on=0, off=1)
    saves_by_write_through = True
    comms_note = (
        "addresses 32-127 come from register 0x0013 when DIP switches SW1-SW5 are all OFF "
        "(1-31 are set by the switches); baud rates 9600, 14400, 128000 and 256000 from "
        "0x0014 when SW6 = SW7 = ON (19200, 38400, 115200 by the switches); the format "
        "from 0x0015; all take effect after a power cycle"
    )

    def __init__(
        self,
        slave: SlaveHandle,
        *,
        pulses_per_rev: int = 1000,
        eeprom_write_through: bool = False,
        start_speed_rpm: int | None = None,
        write_multiple: bool = False,
        inputs: Mapping[str, str] | None = None,
    ) -> None:
        self.check_options(dict(
            eeprom_write_through=eeprom_write_through, start_speed_rpm=start_speed_rpm,
            write_multiple=write_multiple, inputs=None if inputs is None else dict(inputs),
        ))
        super().__init__(slave, pulses_per_rev=pulses_per_rev)
        self.eeprom_write_through = eeprom_write_through
        self.start_speed_rpm = start_speed_rpm
        self.write_multiple = write_multiple
        self.inputs = self._check_inputs(inputs or {})
        self._limit_bits: tuple[int, int] | None = None  # (positive mask, negative mask)

    @staticmethod
    def _check_inputs(inputs: Mapping[str, str]) -> dict[int, int]:
        """Terminal index -> function code (names checked by ``BHSSOptions``)."""
        return {INPUT_TERMINALS.index(t): INPUT_FUNCTIONS[f] for t, f in inputs.items()}

    # -- unit conversion --------------------------------------------------------------------

    @staticmethod
    def ramp_ms(reg: Register, speed_rpm: float, accel_rps2: float) -> int:
        """Ramp time (ms) for ``reg`` that reaches ``speed_rpm`` at ``accel_rps2``, checked."""
        if accel_rps2 <= 0:
            raise LimitViolation(
                f"acceleration {accel_rps2} rev/s² for register {reg.name} "
                f"(address {reg.address}) must be > 0"
            )
        ms = round(abs(speed_rpm) / 60.0 / accel_rps2 * 1000.0)
        try:
            return reg.check(ms)
        except LimitViolation as exc:
            raise LimitViolation(
                f"{abs(speed_rpm):g} rpm at {accel_rps2:g} rev/s² needs a ramp of {ms} ms: {exc}"
            ) from exc

    def speed_word(self, speed_rpm: float, *, move: bool) -> int:
        """The max-speed register value (whole rpm) for ``speed_rpm``, checked."""
        rpm = round(speed_rpm)
        reg = Regs.MAX_SPEED
        if move and rpm <= 0:
            raise LimitViolation(
                f"move speed {speed_rpm} rpm for register {reg.name} (address {reg.address}) "
                f"must be at least 1 rpm (range 1..{reg.hi} rpm)"
            )
        reg.check(rpm)
        rate = abs(rpm) * self.pulses_per_rev / 60.0
        if rate > _MAX_PULSE_RATE:
            top = _MAX_PULSE_RATE * 60 // self.pulses_per_rev
            raise LimitViolation(
                f"{rpm} rpm for register {reg.name} (address {reg.address}) is outside the "
                f"range the drive's 200 kHz pulse output allows at {self.pulses_per_rev} "
                f"pulses/rev: -{top}..{top} rpm"
            )
        return rpm

    # -- set-up -------------------------------------------------------------------------------

    async def setup(self) -> None:
        """EEPROM write-through first, then resolution, bus control, start speed, inputs."""
        cfg = await self.slave.read_holding_registers(0x0010, 9, priority=Priority.CONFIG)
        wanted = [
            (Regs.EEPROM_UPDATE, 0 if self.eeprom_write_through else 1),
            (Regs.MICROSTEP, MICROSTEP_TABLE.index(self.pulses_per_rev)),
            (Regs.CONTROL_SOURCE, 0),
        ]
        for reg, value in wanted:
            if cfg[reg.address - 0x0010] != value:
                await self.write(reg, value)
        if self.start_speed_rpm is not None:
            await self.write(Regs.START_SPEED, self.start_speed_rpm)
        for index, function in sorted(self.inputs.items()):
            await self.write(_input_function_register(index), function)
        await self.learn()

    async def learn(self) -> None:
        """Which inputs are the limit switches (0x0050.., read only)."""
        await self._load_limit_bits()

    def volatile_settings(self) -> list[tuple[Register, int]]:
        """EEPROM write-through, resolution, bus control, start speed and the input
        functions setup() wrote (a power cycle reloads the registers from EEPROM)."""
        wanted = [
            (Regs.EEPROM_UPDATE, 0 if self.eeprom_write_through else 1),
            (Regs.MICROSTEP, MICROSTEP_TABLE.index(self.pulses_per_rev)),
            (Regs.CONTROL_SOURCE, 0),
        ]
        if self.start_speed_rpm is not None:
            wanted.append((Regs.START_SPEED, self.start_speed_rpm))
        wanted.extend(
            (_input_function_register(index), function)
            for index, function in sorted(self.inputs.items())
        )
        return wanted

    async def _load_limit_bits(self) -> None:
        funcs = await self.slave.read_holding_registers(
            Regs.INPUT_FUNCTION_BASE, len(INPUT_TERMINALS), priority=Priority.CONFIG
        )
        pos = sum(1 << i for i, f in enumerate(funcs) if f == INPUT_FUNCTIONS["forward_limit"])
        neg = sum(1 << i for i, f in enumerate(funcs) if f == INPUT_FUNCTIONS["backward_limit"])
        self._limit_bits = (pos, neg)

    # -- status and identity --------------------------------------------------------------------

    async def read_status(self, *, priority: Priority = Priority.POLL) -> DriveStatus:
        """One read of 0x0003..0x000B decoded into a ``DriveStatus``.

        ``in_position`` is status bit0 (position reached) while bit2 (turning) is clear;
        the drive has no velocity register, so ``velocity_rpm`` stays None.
        """
        if self._limit_bits is None:
            await self._load_limit_bits()
        assert self._limit_bits is not None
        start, count = _STATUS_BLOCK
        w = await self.slave.read_holding_registers(start, count, priority=priority)
        mode, motor, direction, code, bits, inputs, outputs = w[:7]
        moving = bool(bits & StatusBit.TURNING) or motor == 1
        alarm = bool(bits & StatusBit.ALARM) or code != 0
        pos_mask, neg_mask = self._limit_bits
        return DriveStatus(
            enabled=not bits & StatusBit.RELEASED,
            moving=moving,
            in_position=bool(bits & StatusBit.POSITION_REACHED) and not moving,
            homed=bool(bits & StatusBit.HOMED),
            alarm=alarm,
            alarm_code=code if alarm else None,
            alarm_text=ALARM_TEXTS.get(code, f"alarm code {code}") if alarm else "",
            limit_positive=bool(inputs & pos_mask),
            limit_negative=bool(inputs & neg_mask),
            homing=mode == 1,
            position=Regs.POSITION.decode(w[7:9]),
            raw={
                "mode": mode, "motor_state": motor, "direction": direction, "error_code": code,
                "status": bits, "inputs": inputs, "outputs": outputs,
                "position_high": w[7], "position_low": w[8],
            },
            timestamp=monotonic(),
        )

    MODEL_WORD: ClassVar[int] = 0x0305
    """What register 0x0000 reads on a BHSS-100-MBUS (manual Table 10)."""

    def is_own_identity(self, ident: DriveIdentity) -> bool:
        """Model word 0x0305."""
        return ident.raw.get("model") == self.MODEL_WORD

    async def read_identity(self) -> DriveIdentity:
        """Model word 0x0000 (0x0305) and driver version 0x0001 (0x0101 = "1.01")."""
        model, version = await self.slave.read_holding_registers(0x0000, 2)
        return DriveIdentity(
            self.family,
            model=f"BHSS-100-MBUS (model 0x{model:04X})",
            firmware=f"{version >> 8}.{version & 0xFF:02d}",
            raw={"model": model, "version": version},
        )

    # -- procedures ------------------------------------------------------------------------------

    async def enable(self) -> None:
        """Lock the shaft: 0x0029 = 1."""
        await self.write(Regs.ENABLE, 1, priority=Priority.COMMAND)

    async def disable(self) -> None:
        """Release the shaft: 0x0029 = 0."""
        await self.write(Regs.ENABLE, 0, priority=Priority.COMMAND)

    def quantize(self, params: MoveParams) -> MoveParams:
        """Whole rpm, and ramps as whole milliseconds to reach it (0x0021/0x0022)."""
        return ramp_time_quantized(params)

    def check_move(self, params: MoveParams) -> None:
        """Range-check the speed and the ramp times a move would write."""
        speed = self.speed_word(params.speed_rpm, move=True)
        self.ramp_ms(Regs.ACCEL_TIME, speed, params.accel_rps2)
        self.ramp_ms(Regs.DECEL_TIME, speed, params.decel_rps2)

    async def _write_profile(self, params: MoveParams) -> None:
        speed = self.speed_word(params.speed_rpm, move=True)
        acc = self.ramp_ms(Regs.ACCEL_TIME, speed, params.accel_rps2)
        dec = self.ramp_ms(Regs.DECEL_TIME, speed, params.decel_rps2)
        await self.write(Regs.ACCEL_TIME, acc, priority=Priority.COMMAND)
        await self.write(Regs.DECEL_TIME, dec, priority=Priority.COMMAND)
        await self.write(Regs.MAX_SPEED, speed, priority=Priority.COMMAND)

    async def _write_distance(self, pulses: int) -> None:
        words = Regs.DISTANCE.encode(pulses)
        if self.write_multiple:
            await self.slave.write_registers(Regs.DISTANCE.address, words,
                                             priority=Priority.COMMAND)
            return
        # High word first, as in the manual's position-mode example (steps 5 and 6).
        await self.write(Regs.DISTANCE_HIGH, words[0], priority=Priority.COMMAND)
        await self.write(Regs.DISTANCE_LOW, words[1], priority=Priority.COMMAND)

    async def _start(self, command: int) -> None:
        await self.write(Regs.START, command, priority=Priority.COMMAND, idempotent=False)

    async def move_absolute(self, position: int, params: MoveParams) -> None:
        """Ramps, speed and target, then 0x0027 = 5 (position mode, absolute)."""
        await self.prepare_absolute(position, params)
        await self.start_absolute()

    async def prepare_absolute(self, position: int, params: MoveParams) -> None:
        """Ramps, speed and target: everything but the start."""
        Regs.DISTANCE.check(position)
        await self._write_profile(params)
        await self._write_distance(position)

    async def start_absolute(self) -> None:
        """0x0027 = 5 starts the prepared absolute move."""
        await self._start(_START_ABSOLUTE)

    async def move_relative(self, distance: int, params: MoveParams) -> None:
        """Ramps, speed and distance, then 0x0027 = 1 (position mode, relative)."""
        Regs.DISTANCE.check(distance)
        await self._write_profile(params)
        await self._write_distance(distance)
        await self._start(_START_RELATIVE)

    async def speed_run(self, speed_rpm: float, accel_rps2: float, decel_rps2: float) -> None:
        """Speed mode: ramps, signed max speed, then 0x0027 = 2; again = change of speed.

        The manual does not say whether 0x0023 is taken while running, so a speed change
        re-sends the speed-mode start after the new speed. The decel time is written too:
        the drive's normal stop uses the one in effect when the motion started. Speed 0
        is a decelerating stop.
        """
        speed = self.speed_word(speed_rpm, move=False)
        if speed == 0:
            await self.stop()
            return
        acc = self.ramp_ms(Regs.ACCEL_TIME, speed, accel_rps2)
        dec = self.ramp_ms(Regs.DECEL_TIME, speed, decel_rps2)
        await self.write(Regs.ACCEL_TIME, acc, priority=Priority.COMMAND)
        await self.write(Regs.DECEL_TIME, dec, priority=Priority.COMMAND)
        await self.write(Regs.MAX_SPEED, speed, priority=Priority.COMMAND)
        await self._start(_START_SPEED)

    async def stop(self, decel_rps2: float | None = None) -> None:
        """Normal stop: 0x0028 = 0.

        The drive ramps down with the deceleration time latched when the motion started
        (manual L1229-L1233); a different ``decel_rps2`` cannot take effect and is ignored.
        """
        if decel_rps2 is not None:
            log.debug("BHSS stop: decel %s rev/s² ignored, the drive uses the latched one",
                      decel_rps2)
        await self.write(Regs.STOP, 0, priority=Priority.EMERGENCY, idempotent=False)

    async def emergency_stop(self) -> None:
        """Emergency stop without ramp: 0x0028 = 1."""
        await self.write(Regs.STOP, 1, priority=Priority.EMERGENCY, idempotent=False)

    def homing_switches(self, method: str | None) -> HomingSwitches:
        """Modes 2/3 home on the forward/backward limit; modes 0/1 search the origin
        forward/backward and reverse at the limit switch in that direction (L1184)."""
        mode = _HOMING_MODES.get(method or self.homing_methods[0])
        side = {0: 1, 1: -1, 2: 1, 3: -1}.get(mode if mode is not None else -1)
        if side is None:
            return HomingSwitches()
        if mode in (2, 3):
            return HomingSwitches(homes_on=frozenset({side}))
        return HomingSwitches(reverses_at=frozenset({side}))

    async def start_homing(self, params: HomingParams) -> None:
        """Write mode, speeds, ramp and offset (0x0031..0x0036), then 0x0030 = 1.

        The offset is a compensation move after the origin is found: positive values go
        to 0x0035 (counter-clockwise = positive), negative ones to 0x0036.
        """
        name = params.method or self.homing_methods[0]
        if name not in _HOMING_MODES:
            raise ConfigError(
                f"BHSS homing method {name!r} is not one of {self.homing_methods}"
            )
        ramp = self.ramp_ms(Regs.HOME_RAMP, params.speed_rpm, params.accel_rps2)
        p = Priority.COMMAND
        await self.write(Regs.HOME_MODE, _HOMING_MODES[name], priority=p)
        await self.write(Regs.HOME_SPEED, round(params.speed_rpm), priority=p)
        await self.write(Regs.HOME_CREEP, round(params.creep_rpm), priority=p)
        await self.write(Regs.HOME_RAMP, ramp, priority=p)
        await self.write(Regs.HOME_OFFSET_POS, max(params.offset, 0), priority=p)
        await self.write(Regs.HOME_OFFSET_NEG, max(-params.offset, 0), priority=p)
        await self.write(Regs.HOME_START, 1, priority=p, idempotent=False)

    async def clear_alarm(self) -> None:
        """0x002A = 1, then check 0x0006: an alarm that stays raises ``DriveAlarm``.

        Only Err4 clears this way; Err2/Err3 clear when the supply recovers and
        Err1/Err5 need a power cycle.
        """
        await self.write(Regs.CLEAR_ALARM, 1, priority=Priority.COMMAND, idempotent=False)
        code = await self.read(Regs.ERROR_CODE, priority=Priority.COMMAND)
        if code:
            text = ALARM_TEXTS.get(code, f"alarm code {code}")
            raise DriveAlarm(f"BHSS alarm persists after clear: {text}", code=code, text=text)

    async def zero_position(self) -> None:
        """0x002C = 1: the present position becomes 0."""
        await self.write(Regs.ZERO_POSITION, 1, priority=Priority.COMMAND, idempotent=False)

    async def restore_factory_settings(self) -> None:
        """0x002B = 1: the drive's factory parameters (line settings apply after power-up)."""
        await self.write(Regs.FACTORY_RESET, 1, priority=Priority.COMMAND, idempotent=False)
        self._limit_bits = None

    def save_problem(self) -> str | None:
        """Without write-through the drive cannot store what was written before."""
        if self.eeprom_write_through:
            return None
        return (f"the {self.family} drive has no save command: it stores a value only when "
                f"it is written while register 0x0016 is 0 (write-through)")

    def comms_writes(
        self, address: int | None, settings: LineSettings | None, current: LineSettings | None
    ) -> list[tuple[Register, int]]:
        """0x0013 (addresses 32-127), 0x0014 (9600/14400/128000/256000), 0x0015 (format)."""
        writes: list[tuple[Register, int]] = []
        if address is not None:
            if not 32 <= address <= 127:
                raise self.unsupported(
                    f"take address {address} from a register",
                    "addresses 1-31 are set by DIP switches SW1-SW5; 0x0013 gives 32-127 "
                    "with all five OFF")
            writes.append((Regs.NODE_CUSTOM, address))
        if settings is not None:
            if current is None or settings.baudrate != current.baudrate:
                if settings.baudrate not in _BAUD_CODES:
                    raise self.unsupported(
                        f"take {settings.baudrate} baud from a register",
                        "19200, 38400 and 115200 are set by DIP switches SW6/SW7; 0x0014 "
                        f"gives {', '.join(map(str, _BAUD_CODES))} with SW6 = SW7 = ON")
                writes.append((Regs.BAUD_CUSTOM, _BAUD_CODES.index(settings.baudrate)))
            if settings.format not in _FORMAT_CODES:
                raise self.unsupported(f"talk {settings.format}",
                                       f"0x0015 gives {', '.join(_FORMAT_CODES)}")
            writes.append((Regs.DATA_FORMAT, _FORMAT_CODES.index(settings.format)))
        return writes

    async def save_parameters(self) -> None:
        """Nothing to do with EEPROM write-through on; otherwise ``NotSupported``."""
        if self.eeprom_write_through:
            return  # every Modbus write is already stored
        raise self.unsupported(
            "save parameters",
            "it has no save command; it stores each Modbus write in EEPROM only while "
            "register 0x0016 is 0: build the profile with eeprom_write_through=True for that "
            "(every write, motion commands included, then wears the EEPROM)",
        )

    # -- motion programs --------------------------------------------------------------------

    async def read_completion(self, *, priority: Priority = Priority.COMMAND) -> Completion:
        """0x0007 (status bits) alone, one register of the status's nine, so a buffered
        move starts sooner at 19200 baud (a position move turns while bit2 is set; a
        move stopped at a limit switch has not reached its position, and the full polls
        judge it)."""
        bits = (await self.slave.read_holding_registers(0x0007, 1, priority=priority))[0]
        moving = bool(bits & StatusBit.TURNING)
        return Completion(
            moving=moving,
            in_position=bool(bits & StatusBit.POSITION_REACHED) and not moving,
            alarm=bool(bits & StatusBit.ALARM),
        )

    # -- digital I/O --------------------------------------------------------------------------

    async def io_points(self) -> list[IOPoint]:
        """PU, DR, X0-X4 with their functions (0x0041-0x0047), Y0-Y2 with theirs
        (0x004C-0x004E)."""
        ins = await self.slave.read_holding_registers(Regs.INPUT_FUNCTION_BASE,
                                                      len(INPUT_TERMINALS),
                                                      priority=Priority.CONFIG)
        outs = await self.slave.read_holding_registers(0x004C, 3, priority=Priority.CONFIG)
        names = {v: k.replace("_", " ") for k, v in INPUT_FUNCTIONS.items()}
        return ([IOPoint(n, False, function_text(names, w))
                 for n, w in zip(self.io_inputs, ins, strict=True)]
                + [IOPoint(n, True, function_text(_OUTPUT_FUNCTION_NAMES, w))
                   for n, w in zip(self.io_outputs, outs, strict=True)])
