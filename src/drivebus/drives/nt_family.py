"""Rtelligent NT-family drives: the NT86 (Modbus RTU) and the EPR60/EPT60 (Modbus TCP).

Both share one register map (manuals: ``shared/seeds/000_…`` for the NT86, ``002_…`` for
the EPR60): status in registers 0/1, position in 8/9, motion by command codes written to
register 18, 32-bit values as two registers with the **low word at the lower address**.
Units are the drive's own: pulses, rpm and r/s², all integers.

Differences (per the EPR60 manual): the EPR60 keeps pulses/rev at 96/97 (32-bit) instead
of 24, homes on a limit switch with parameters 79-83 in application mode 20=1 and has no
Modbus homing trigger (the NT86's 287-298 block is absent), and its target 73/74 has no
documented range beyond int32.

Neither drive has an enable or alarm-reset register the manual explains; both documents
offer only input functions 4 "motor offline" and 5 "clear fault" (and 12 "start homing").
The NT86 manual's own way to trigger an input function over Modbus (sections 3.7-3.8) is
to toggle the polarity bit (bit 5) of the input's setting register; the profiles offer
that only as explicit opt-ins (``enable_input``, ``clear_alarm_input``, ``home_input``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Annotated, ClassVar

import anyio
from pydantic import Field, StrictBool, StrictFloat, StrictInt, model_validator

from drivebus.bus import Priority, SlaveHandle
from drivebus.clock import monotonic
from drivebus.drives.base import (
    DriveOptions,
    DriveProfile,
    HomingParams,
    HomingSwitches,
    MoveParams,
    Parameter,
)
from drivebus.drives.io import IOPoint, function_text
from drivebus.drives.programs import ProgramSupport
from drivebus.drives.registers import Access, Register, WordOrder
from drivebus.drives.status import DriveIdentity, DriveStatus
from drivebus.errors import ConfigError, DriveAlarm, LimitViolation, StateError

__all__ = [
    "ALARM_BITS",
    "NT86_MAP",
    "NT86Profile",
    "NTRegisterMap",
    "StatusBit",
    "decode_alarm",
]



class StatusBit:
    """Bits of status register 1 (NT86 manual 2.6.1.2, EPR60 manual 3.3)."""

    ENA = 1 << 0
    ALM = 1 << 1
    INPOS = 1 << 2  # closed-loop modes only
    MOV = 1 << 3  # while set, only stop commands (18=5/6) are obeyed
    HOME = 1 << 4
    RDY = 1 << 5
    ARRSPD = 1 << 6
    CLAMP = 1 << 7
    PL = 1 << 8
    NL = 1 << 9
    POW = 1 << 10
    TC = 1 << 11


ALARM_BITS: dict[int, str] = {
    0: "IVE: internal voltage error",
    1: "OC: over-current",
    2: "OV: over-voltage",
    3: "UV: under-voltage",
    4: "OT: over-temperature",
    5: "MEM: parameter checksum error",
    6: "MPE: motor phase loss",
    7: "POSE: following-error alarm",
    8: "ECDE1: encoder signal fault",
}
"""Bits of alarm register 0, with the manual's names."""


def decode_alarm(word: int) -> str:
    """The alarm register's set bits as text ("" when no bit is set)."""
    names = [text for bit, text in ALARM_BITS.items() if word & (1 << bit)]
    unknown = word & ~((1 << len(ALARM_BITS)) - 1)
    if unknown:
        names.append(f"reserved bits 0x{unknown:04X}")
    return "; ".join(names)


# Register 18 command codes.
CMD_IDLE, CMD_FORWARD, CMD_REVERSE, CMD_JOG_FWD, CMD_JOG_REV, CMD_ESTOP, CMD_STOP = range(7)

# Input functions (bits 0-4 of the input setting registers 60-65); bit 5 is the polarity.
FUNC_OFFLINE, FUNC_CLEAR_FAULT, FUNC_START_HOMING = 4, 5, 12
_FUNC_USER3 = 24  # the multi-segment start in application mode 20
POLARITY_BIT = 0x20

INPUT_FUNCTIONS: dict[int, str] = {
    0: "pulse input", 1: "direction input", 2: "encoder A", 3: "encoder B",
    4: "motor offline", 5: "clear fault", 6: "emergency stop", 7: "jog forward / start-stop",
    8: "jog reverse / direction", 9: "positive limit", 10: "negative limit",
    11: "home switch", 12: "start homing", 13: "reverse direction",
    **{14 + i: f"multi-speed select {i}" for i in range(4)},
    **{18 + i: f"multi-position select {i}" for i in range(4)},
    **{22 + i: f"USER{i + 1}" for i in range(10)},
}
"""The input functions (bits 0-4 of registers 60-65), with the manual's names (L881)."""

OUTPUT_FUNCTIONS: dict[int, str] = {
    0: "general-purpose output (register 68)", 1: "alarm", 2: "brake", 3: "in position",
    4: "speed reached", 5: "homing complete", 6: "ready", 7: "motor stopped",
    8: "positive limit", 9: "negative limit", 10: "power", 11: "torque reached",
}
"""The output functions (bits 0-3 of registers 66/67), with the manual's names (L901)."""

OUTPUT_SETTINGS = 66
"""Registers 66/67: OUT1/OUT2's function (bits 0-3) and polarity (bit 4)."""
OUTPUT_VALUES = Register("general-purpose output values", 68, minimum=0, maximum=3)


@dataclass(frozen=True)
class NTRegisterMap:
    """The registers an NT-family profile uses, as typed data (one instance per drive)."""

    alarm: Register
    status: Register
    inputs: Register
    position: Register
    speed: Register
    command_source: Register
    command: Register
    app_mode: Register
    control_mode: Register
    microstep: Register
    input_config: tuple[Register, ...]
    move_accel: Register
    move_decel: Register
    move_speed: Register
    move_target: Register
    jog_accel: Register
    jog_decel: Register
    jog_speed: Register
    estop_decel: Register
    position_mode: Register
    clear_counter: Register
    save: Register
    drive_id: Register
    version: Register
    custom_no: Register

    status_block: tuple[int, int] = (0, 11)
    """(first register, count) read by ``read_status``: alarm … commanded speed."""


def _u16(name: str, address: int, unit: str = "", lo: int = 0, hi: int = 0xFFFF) -> Register:
    return Register(name, address, unit=unit, minimum=lo, maximum=hi)


def _inputs() -> tuple[Register, ...]:
    return tuple(_u16(f"IN{n} setting", 59 + n, lo=0, hi=0x3F) for n in range(1, 7))


NT86_MAP = NTRegisterMap(
    alarm=Register("alarm code", 0, access=Access.R),
    status=Register("status word", 1, access=Access.R),
    inputs=Register("input port state", 2, access=Access.R),
    position=Register("absolute position", 8, 2, signed=True, order=WordOrder.LOW_FIRST,
                      unit="pulses", access=Access.R),
    speed=Register("command speed", 10, signed=True, unit="rpm", access=Access.R),
    command_source=_u16("command source", 17, lo=0, hi=1),
    command=_u16("motion command", 18, lo=0, hi=6),
    app_mode=_u16("application mode", 20, lo=0, hi=22),
    control_mode=_u16("control mode", 22, lo=0, hi=2),
    microstep=_u16("pulses per revolution", 24, "pulses/rev", 200, 65535),
    input_config=_inputs(),
    move_accel=_u16("point move acceleration", 70, "r/s²", 10, 1000),
    move_decel=_u16("point move deceleration", 71, "r/s²", 10, 1000),
    move_speed=_u16("point move speed", 72, "rpm", 0, 3000),
    move_target=Register(
        "point move distance/target",
        73,
        2,
        signed=True,
        order=WordOrder.LOW_FIRST,
        unit="pulses",
        minimum=-16777216,
        maximum=16777216,
    ),
    jog_accel=_u16("jog acceleration", 75, "r/s²", 10, 1000),
    jog_decel=_u16("jog deceleration", 76, "r/s²", 10, 1000),
    jog_speed=_u16("jog speed", 77, "rpm", 0, 3000),
    estop_decel=_u16("emergency stop deceleration", 78, "r/s²", 10, 1000),
    position_mode=_u16("incremental/absolute select", 84, lo=0, hi=1),
    clear_counter=_u16("clear internal pulse counter", 85, lo=0, hi=1),
    save=_u16("save parameters", 90, lo=0, hi=1),
    drive_id=Register("drive ID", 93, access=Access.R),
    version=Register("drive version", 94, access=Access.R),
    custom_no=Register("non-standard number", 95, access=Access.R),
)
"""The NT86 register map (NT86 manual chapter 2)."""

# NT86 homing block (287-298; 292 is reserved, so 288-291 and 293-295 are written apart).
NT86_HOME_TRIGGER = _u16("homing enable/trigger", 287, lo=0, hi=6)
NT86_HOME_METHOD = _u16("homing method", 288, lo=0, hi=5)
NT86_HOME_FAST = _u16("homing high speed", 289, "rpm", 0, 1000)
NT86_HOME_SLOW = _u16("homing low speed", 290, "rpm", 0, 1000)
NT86_HOME_ACCEL = _u16("homing acceleration", 291, "r/s²", 1, 1000)
NT86_HOME_OFFSET = Register(
    "home offset",
    293,
    2,
    signed=True,
    order=WordOrder.LOW_FIRST,
    unit="pulses",
    minimum=-1048576,
    maximum=1048576,
)
NT86_HOME_HANDLING = _u16("home offset and limit handling", 295, lo=0, hi=3)

# -- parameters (``drivebus params``), in the manuals' order --------------------------------------
# Every RW parameter is kept in flash by 90=1 (NT86 manual L955, EPR60 L957); none of them is
# a command (18, 85, 90, the homing trigger 287 and the latches 6/7/16 are left out).

_MOTOR_TYPE = _u16("motor type", 21, lo=0, hi=1)
_DIRECTION = _u16("direction invert", 23, lo=0, hi=1)
_RUN_CURRENT = _u16("open-loop run current", 25, "mA", 0, 6000)
_STANDBY_CURRENT = _u16("standby current", 26, "%", 0, 100)
_STANDBY_DELAY = _u16("standby delay", 27, "ms", 10, 65535)
_FILTER = _u16("command filter time", 28, "×50 µs", 1, 512)
NT86_STALL_TIME = _u16("stall-homing detect time", 296, "×50 µs", 1000, 65535)
NT86_STALL_SPEED = _u16("stall-homing speed threshold", 297, "rpm", 1, 1000)
NT86_STALL_CURRENT = _u16("stall-homing current threshold", 298, "mA", 1, 6000)


def _nt_parameters(regs: NTRegisterMap, homing: tuple[tuple[str, Register], ...]
                   ) -> tuple[Parameter, ...]:
    """The parameters both NT-family manuals document, with ``regs``'s own registers."""
    early = sorted(
        [("command_source", regs.command_source), ("application_mode", regs.app_mode),
         ("motor_type", _MOTOR_TYPE), ("control_mode", regs.control_mode),
         ("direction_invert", _DIRECTION), ("run_current", _RUN_CURRENT),
         ("standby_current", _STANDBY_CURRENT), ("standby_delay", _STANDBY_DELAY),
         ("command_filter", _FILTER), ("pulses_per_rev", regs.microstep)],
        key=lambda kr: kr[1].address,
    )
    inputs = [(f"in{n}_setting", r) for n, r in enumerate(regs.input_config, start=1)]
    motion = [
        ("move_accel", regs.move_accel), ("move_decel", regs.move_decel),
        ("move_speed", regs.move_speed), ("move_target", regs.move_target),
        ("jog_accel", regs.jog_accel), ("jog_decel", regs.jog_decel),
        ("jog_speed", regs.jog_speed), ("estop_decel", regs.estop_decel),
        ("absolute_mode", regs.position_mode),
    ]
    rows = [*early, *inputs, *motion, *homing]
    rows.sort(key=lambda kr: kr[1].address)
    return tuple(Parameter(k, r) for k, r in rows)


NT86_PARAMETERS = _nt_parameters(NT86_MAP, (
    ("homing_method", NT86_HOME_METHOD), ("homing_speed", NT86_HOME_FAST),
    ("homing_creep", NT86_HOME_SLOW), ("homing_accel", NT86_HOME_ACCEL),
    ("home_offset", NT86_HOME_OFFSET), ("home_handling", NT86_HOME_HANDLING),
    ("stall_time", NT86_STALL_TIME), ("stall_speed", NT86_STALL_SPEED),
    ("stall_current", NT86_STALL_CURRENT),
))
"""The NT86's parameters (manual chapter 2), in address order."""

_NT_EXCEPTIONS = {
    1: "ILLEGAL_FUNCTION: function code not supported (the drive knows FC03, FC06, FC16)",
    2: "ILLEGAL_DATA_ADD: register address not valid (unmapped, reserved or read-only)",
    3: "ILLEGAL_DATA_VAL: data value not valid (outside the register's range)",
    # The manual lists codes 1-4 only. A well-formed command the drive cannot carry out
    # now (a start while MOV=1, or while disabled/in alarm) fits none of 1-3, so the
    # simulated twin answers DEVICEFAIL; the manual only says such commands are not obeyed
    # (a real drive may ignore them silently: read the status back after a lost command).
    4: "DEVICEFAIL: the drive cannot carry out the request now (while the motor moves only "
    "stop commands 18=5/6 are accepted; no motion while disabled or in alarm)",
}


def _round_unit(reg: Register, value: float, *, nonzero: bool = False) -> int:
    """``value`` rounded to the register's integer unit, range-checked (LimitViolation)."""
    if not math.isfinite(value):
        raise LimitViolation(f"value {value} for register {reg.name} ({reg.address}) is not finite")
    v = round(value)
    if nonzero and v <= 0:
        raise LimitViolation(
            f"value {value} {reg.unit} for register {reg.name} (address {reg.address}) must be "
            f"at least 1 {reg.unit}; its range is {max(reg.lo, 1)}..{reg.hi} {reg.unit}"
        )
    return reg.check(v)


_Input = Annotated[StrictInt, Field(ge=1, le=6, description="input IN1..IN6")]


class _NTOptions(DriveOptions):
    """Options both NT-family drives take; an input serves one opted-in function only."""

    estop_decel_rps2: StrictFloat | None = Field(
        None, ge=NT86_MAP.estop_decel.lo, le=NT86_MAP.estop_decel.hi, description="r/s²"
    )
    enable_input: _Input | None = None
    clear_alarm_input: _Input | None = None
    general_outputs: (
        Annotated[list[Annotated[StrictInt, Field(ge=1, le=2)]], Field(max_length=2)] | None
    ) = None

    @model_validator(mode="after")
    def _one_function_per_input(self) -> _NTOptions:
        used: dict[int, str] = {}
        for name, n in self.model_dump().items():
            if name.endswith("_input") and n is not None:
                if n in used:
                    raise ValueError(f"{name} and {used[n]} are both IN{n}: give each its own "
                                     f"input")
                used[n] = name
        return self


class NT86Options(_NTOptions):
    """The NT86's options (see ``NT86Profile``)."""

    home_offset_moves: StrictBool | None = None
    home_reverse_at_limit: StrictBool | None = None


class NT86Profile(DriveProfile):
    """Rtelligent NT86 over Modbus RTU (8N1, 9600-115200 baud by DIP switch).

    Opt-ins (the manual's input-function workaround, off by default):
    ``enable_input=n``: enable/disable by toggling the polarity bit of input IN n, which
    setup() gives function 4 "motor offline" (IN3 has it by default); leave that input
    unwired. ``clear_alarm_input=n``: clear alarms by pulsing the polarity bit of IN n,
    which setup() gives function 5 "clear fault" (its previous function is lost).
    ``home_offset_moves``: 295=1/3 (move by the offset after the origin, then position =
    offset) instead of 0/2 (position = offset at the origin). ``home_reverse_at_limit``:
    295=2/3 (reverse at a limit during the search) instead of 0/1 (stop).
    ``general_outputs=[n, ...]``: setup() gives OUT n function 0, general-purpose output
    switched by register 68, so ``set_output`` can switch it (its previous function is
    lost).
    """

    family: ClassVar[str] = "NT86"
    word_order: ClassVar[WordOrder] = WordOrder.LOW_FIRST
    io_inputs: ClassVar[tuple[str, ...]] = tuple(f"IN{n}" for n in range(1, 7))
    io_outputs: ClassVar[tuple[str, ...]] = ("OUT1", "OUT2")
    no_output_control: ClassVar[str] = (
        "an output follows register 68 only while its setting register (66/67) gives it "
        "function 0, general-purpose output (manual L894-L922)")
    programs: ClassVar[ProgramSupport] = ProgramSupport(
        preload="changes to 70-72 made during a point move apply from the next start "
        "(NT86 manual L1312); the target 73/74 is taken at the start as well",
        no_retarget="while it moves (MOV=1) the NT86 obeys only the stop commands 18=5/6 "
        "(manual L632)",
        jog_speed="register 77 (jog speed) takes effect at once during a jog (manual L1342)",
    )
    exception_texts: ClassVar[dict[int, str]] = dict(_NT_EXCEPTIONS)
    homing_methods: ClassVar[tuple[str, ...]] = (
        "home_switch_positive",  # 288=0
        "home_switch_negative",  # 288=1
        "limit_positive",  # 288=2
        "limit_negative",  # 288=3
        "hard_stop_positive",  # 288=4, closed loop only
        "hard_stop_negative",  # 288=5 (printed "positive", L1158), closed loop only
        "electrical",  # 287=5: move to the absolute offset at the high speed
        "set_origin",  # 287=6: the present position becomes the offset
    )
    regs: ClassVar[NTRegisterMap] = NT86_MAP
    options: ClassVar[type[DriveOptions]] = NT86Options
    parameter_list = NT86_PARAMETERS
    comms_note = ("its address and baud rate are set by DIP switches SW1-SW5 and SW6/SW7 "
                  "(8N1 only); the manual documents no register for them")
    pulses_per_rev_allowed = range(NT86_MAP.microstep.lo, NT86_MAP.microstep.hi + 1)
    addresses = range(1, 32)  # DIP switches SW1-SW5
    baud_rates = (9600, 19200, 38400, 115200)  # DIP switches SW6/SW7
    line_formats = ("8N1",)

    def __init__(
        self,
        slave: SlaveHandle,
        *,
        pulses_per_rev: int = 4000,
        estop_decel_rps2: float = 500.0,
        enable_input: int | None = None,
        clear_alarm_input: int | None = None,
        home_offset_moves: bool = False,
        home_reverse_at_limit: bool = False,
        general_outputs: list[int] | None = None,
    ) -> None:
        NT86Profile.check_options(dict(
            estop_decel_rps2=estop_decel_rps2, enable_input=enable_input,
            clear_alarm_input=clear_alarm_input, home_offset_moves=home_offset_moves,
            home_reverse_at_limit=home_reverse_at_limit, general_outputs=general_outputs,
        ))
        super().__init__(slave, pulses_per_rev=pulses_per_rev)
        self.estop_decel = _round_unit(self.regs.estop_decel, estop_decel_rps2)
        self.enable_input = enable_input
        self.clear_alarm_input = clear_alarm_input
        self.general_outputs = tuple(sorted(set(general_outputs or ())))
        """OUTn setup() makes general-purpose outputs (function 0, switched by 68)."""
        self._output_settings: list[tuple[Register, int]] = []
        self._table_input: int | None = None  # IN n armed as the table's start (USER3)
        self.home_offset_moves = home_offset_moves
        self.home_reverse_at_limit = home_reverse_at_limit
        self.closed_loop: bool | None = None
        """Control mode 22 != 0, learnt in setup() (None until then)."""
        self._jog_command: int | None = None
        self._estop_dirty = False
        self._homing = False
        self._seen_moving = False

    # -- setup and status ---------------------------------------------------------------

    async def setup(self) -> None:
        """Internal pulse commands (17=0), command idle (18=0), respond to reg 18 (20=0),
        pulses/rev, and the opted-in input functions. Learns the control mode (22)."""
        r = self.regs
        await self.write(r.command_source, 0)
        await self.write(r.command, CMD_IDLE)  # the manual's FC06 example frame
        await self.write(r.app_mode, 0)
        await self.write(r.microstep, self.pulses_per_rev)
        await self.learn()
        if self.enable_input is not None:
            await self._assign_input(self.enable_input, FUNC_OFFLINE)
        if self.clear_alarm_input is not None:
            await self._assign_input(self.clear_alarm_input, FUNC_CLEAR_FAULT)
        self._output_settings = []
        for n in self.general_outputs:  # function 0, the polarity bit kept
            reg = Register(f"OUT{n} setting", OUTPUT_SETTINGS + n - 1, maximum=0x1F)
            value = await self.read(reg)
            if value & 0x0F:
                await self.write(reg, value & 0x10)
            self._output_settings.append((reg, value & 0x10))
        self._jog_command = None

    async def learn(self) -> None:
        """The control mode (22): closed loop reports in-position (a read only)."""
        self.closed_loop = await self.read(self.regs.control_mode) != 0

    def homing_switches(self, method: str | None) -> HomingSwitches:
        """288=2/3 home on the limit switch; 288=0/1 reverse at the limit switch in the
        search direction when 295 = 2/3 (``home_reverse_at_limit``), else stop there."""
        m = self.homing_methods[0] if method is None else method
        on = {"limit_positive": 1, "limit_negative": -1}.get(m)
        if on is not None:
            return HomingSwitches(homes_on=frozenset({on}))
        search = {"home_switch_positive": 1, "home_switch_negative": -1}.get(m)
        if search is not None and self.home_reverse_at_limit:
            return HomingSwitches(reverses_at=frozenset({search}))
        return HomingSwitches()

    def volatile_settings(self) -> list[tuple[Register, int]]:
        """17=0, 20 (0, or 1 while an EPR60 homes) and pulses/rev: a power cycle reloads
        them from flash. (The position mode 84 is written with every move instead.)"""
        r = self.regs
        wanted = [
            (r.command_source, 0),
            (r.app_mode, self._expected_app_mode()),
            (r.microstep, self.pulses_per_rev),
        ]
        return wanted + self._output_settings

    def _expected_app_mode(self) -> int:
        return 20 if self._table_input is not None else 0

    def check_supported(self, procedure: str) -> None:
        """Enable/disable and alarm clearing exist only through the opted-in inputs."""
        super().check_supported(procedure)
        if procedure in ("enable", "disable") and self.enable_input is None:
            raise self.unsupported(
                "enable the motor" if procedure == "enable" else "disable the motor",
                "it has no enable register; pass enable_input=N to toggle IN N's polarity",
            )
        if procedure == "clear_alarm" and self.clear_alarm_input is None:
            raise self.unsupported(
                "clear an alarm",
                "it has no alarm-reset register; pass clear_alarm_input=N to pulse IN N",
            )

    async def _assign_input(self, n: int, function: int) -> None:
        """Give IN n ``function`` (keeping its polarity bit) unless it has it already."""
        reg = self.regs.input_config[n - 1]
        value = await self.read(reg)
        if value & 0x1F != function:
            await self.write(reg, (value & POLARITY_BIT) | function)

    async def _status_words(self, priority: Priority) -> list[int]:
        first, count = self.regs.status_block
        return await self.slave.read_holding_registers(first, count, priority=priority)

    async def read_status(self, *, priority: Priority = Priority.POLL) -> DriveStatus:
        """One FC03 of registers 0-10 (alarm, status, I/O, position, command speed)."""
        words = await self._status_words(priority)
        trigger = None
        if self._homing:
            trigger = await self._homing_trigger(priority)
        return self.decode_status(words, homing_trigger=trigger, timestamp=monotonic())

    async def _homing_trigger(self, priority: Priority) -> int | None:
        """NT86: register 287 reads 4/5/6 while a Modbus homing runs and 0 once it is done."""
        words = await self.slave.read_holding_registers(
            NT86_HOME_TRIGGER.address, 1, priority=priority
        )
        return words[0]

    def decode_status(
        self, words: list[int], *, homing_trigger: int | None = None, timestamp: float = 0.0
    ) -> DriveStatus:
        """Decode registers 0.. (at least 0-1; 0-10 for position and speed) into a status.

        ``in_position``: the INPOS bit exists in closed-loop modes only; in open loop the
        command position is the position, so the move is complete when MOV=0 and no
        homing runs (derived, not reported by the drive).
        """
        r = self.regs
        alarm, status = words[0], words[1]
        moving = bool(status & StatusBit.MOV)
        homing = self._update_homing(status, homing_trigger)
        complete = not moving and not homing
        in_position = complete and (bool(status & StatusBit.INPOS) if self.closed_loop else True)
        position = speed = None
        raw = {"alarm": alarm, "status": status}
        if len(words) >= 11:
            position = r.position.decode(words[8:10])
            speed = r.speed.decode(words[10:11])
            raw.update(
                inputs=words[2],
                outputs=words[3],
                position_low=words[8],
                position_high=words[9],
                speed=words[10],
            )
        has_alarm = bool(status & StatusBit.ALM) or alarm != 0
        return DriveStatus(
            enabled=bool(status & StatusBit.ENA),
            moving=moving,
            in_position=in_position and not has_alarm,
            homed=bool(status & StatusBit.HOME),
            alarm=has_alarm,
            alarm_code=alarm if has_alarm else None,
            alarm_text=decode_alarm(alarm),
            limit_positive=bool(status & StatusBit.PL),
            limit_negative=bool(status & StatusBit.NL),
            homing=homing,
            position=position,
            # Register 10 is the drive's *command* speed; it has no measured speed.
            velocity_rpm=float(speed) if speed is not None else None,
            raw=raw,
            timestamp=timestamp,
        )

    def _update_homing(self, status: int, trigger: int | None) -> bool:
        """Track a homing started by ``home()`` until the drive reports it over."""
        if not self._homing:
            return False
        moving = bool(status & StatusBit.MOV)
        self._seen_moving |= moving
        if trigger is not None:
            done = trigger == 0
        else:  # EPR60: no trigger register; over once it moved (or reports HOME) and rests
            done = self._seen_moving or bool(status & StatusBit.HOME)
        if done and not moving:
            self._homing = False
        return self._homing

    # -- identity, save, zero -------------------------------------------------------------

    DRIVE_ID: ClassVar[int] = 86
    """What drive ID register 93 reads. The manual leaves its format open: this is the
    value drivebus's simulated twin reports (an assumption for real drives)."""

    def is_own_identity(self, ident: DriveIdentity) -> bool:
        """Drive ID register 93 reads ``DRIVE_ID``."""
        return ident.raw.get("drive_id") == self.DRIVE_ID

    async def read_identity(self) -> DriveIdentity:
        """Drive ID (93), version (94) and non-standard number (95); formats undocumented."""
        r = self.regs
        ident, version, custom = await self.slave.read_holding_registers(r.drive_id.address, 3)
        return DriveIdentity(
            self.family,
            model=f"{self.family} (drive ID {ident})",
            firmware=str(version),
            raw={"drive_id": ident, "version": version, "non_standard": custom},
        )

    async def save_parameters(self) -> None:
        """90=1: store all parameters in flash (the register clears itself)."""
        await self.write(self.regs.save, 1, priority=Priority.CONFIG)

    async def zero_position(self) -> None:
        """85=1: clear the internal pulse counter, i.e. position 8/9 becomes 0."""
        await self.write(self.regs.clear_counter, 1, priority=Priority.COMMAND)

    # -- enable and alarm clear (opt-in workarounds) --------------------------------------

    async def enable(self) -> None:
        """Energise the motor (opt-in ``enable_input``: toggles that input's polarity)."""
        await self._set_enabled(True)

    async def disable(self) -> None:
        """De-energise the motor (opt-in ``enable_input``)."""
        await self._set_enabled(False)

    async def _set_enabled(self, on: bool) -> None:
        what = "enable the motor" if on else "disable the motor"
        if self.enable_input is None:
            raise self.unsupported(
                what,
                "it has no enable register; the manual offers only input function 4 "
                "'motor offline' (IN3 by default). Pass enable_input=N to toggle IN N's "
                "polarity bit instead (the manual's input-trigger technique)",
            )
        status = await self._read_status_word()
        if bool(status & StatusBit.ENA) == on:
            return
        await self._flip_polarity(self.enable_input)
        status = await self._read_status_word()
        if bool(status & StatusBit.ENA) != on:
            await self._flip_polarity(self.enable_input)
            raise StateError(
                f"{self.family}: toggling IN{self.enable_input}'s polarity did not "
                f"{'enable' if on else 'disable'} the drive; is that input wired, or not "
                f"set to function 4?"
            )

    async def clear_alarm(self) -> None:
        """Clear a latched alarm (opt-in ``clear_alarm_input``: pulses that input)."""
        if self.clear_alarm_input is None:
            raise self.unsupported(
                "clear an alarm",
                "it has no alarm-reset register; the manual offers only input function 5 "
                "'clear fault' or a power cycle. Pass clear_alarm_input=N to pulse IN N's "
                "polarity bit instead (the manual's input-trigger technique)",
            )
        await self._pulse_input(self.clear_alarm_input)
        words = await self.slave.read_holding_registers(0, 2, priority=Priority.COMMAND)
        if words[0] or words[1] & StatusBit.ALM:
            raise DriveAlarm(
                f"{self.family}: the alarm did not clear: {decode_alarm(words[0])}",
                code=words[0],
                text=decode_alarm(words[0]),
            )

    async def _read_status_word(self) -> int:
        words = await self.slave.read_holding_registers(
            self.regs.status.address, 1, priority=Priority.COMMAND
        )
        return words[0]

    async def _flip_polarity(self, n: int) -> None:
        reg = self.regs.input_config[n - 1]
        value = await self.read(reg, priority=Priority.COMMAND)
        await self.write(reg, value ^ POLARITY_BIT, priority=Priority.COMMAND, idempotent=False)

    async def _pulse_input(self, n: int) -> None:
        """Flip IN n's polarity bit and back: one of the two flips is an active edge."""
        reg = self.regs.input_config[n - 1]
        value = await self.read(reg, priority=Priority.COMMAND)
        for v in (value ^ POLARITY_BIT, value):
            await self.write(reg, v, priority=Priority.COMMAND, idempotent=False)

    # -- motion -----------------------------------------------------------------------------

    async def _command(self, code: int) -> None:
        """Write a start code to register 18 (never retried blindly)."""
        await self._ensure_command_mode()
        await self.write(self.regs.command, code, priority=Priority.COMMAND, idempotent=False)

    async def _ensure_command_mode(self) -> None:
        """Register 18 commands after a position table: back to application mode 0."""
        await self._leave_table()

    async def _restore_estop_decel(self) -> None:
        if self._estop_dirty:
            await self.write(self.regs.estop_decel, self.estop_decel, priority=Priority.COMMAND)
            self._estop_dirty = False

    async def _set_position_mode(self, mode: int) -> None:
        """84 = ``mode``, written before every move, never taken for granted: a power
        cycle between two polls resets it to 0 (incremental), which would make the next
        absolute move a relative one."""
        await self.write(self.regs.position_mode, mode, priority=Priority.COMMAND)

    def quantize(self, params: MoveParams) -> MoveParams:
        """Whole rpm (72) and whole r/s² (70/71)."""
        return MoveParams(
            float(round(params.speed_rpm)),
            float(round(params.accel_rps2)),
            float(round(params.decel_rps2)),
        )

    def check_move(self, params: MoveParams) -> None:
        """Range-check the speed and ramps of a move (registers 70-72)."""
        self._move_words(0, params)

    def _move_words(self, target: int, params: MoveParams) -> list[tuple[Register, int]]:
        r = self.regs
        return [
            (r.move_accel, _round_unit(r.move_accel, params.accel_rps2)),
            (r.move_decel, _round_unit(r.move_decel, params.decel_rps2)),
            (r.move_speed, _round_unit(r.move_speed, params.speed_rpm, nonzero=True)),
            (r.move_target, r.move_target.check(target)),
        ]

    async def move_relative(self, distance: int, params: MoveParams) -> None:
        """84=0, 70-74 in one FC16 (|distance|), then 18=1 forward or 18=2 reverse."""
        block = self._move_words(abs(int(distance)), params)
        await self._set_position_mode(0)
        await self._restore_estop_decel()
        await self.write_block(block, priority=Priority.COMMAND)
        self._jog_command = None
        await self._command(CMD_FORWARD if distance >= 0 else CMD_REVERSE)

    async def move_absolute(self, position: int, params: MoveParams) -> None:
        """84=1, 70-74 in one FC16 (signed target), then 18=1 (the manual's choice, L938)."""
        await self.prepare_absolute(position, params)
        await self.start_absolute()

    async def prepare_absolute(self, position: int, params: MoveParams) -> None:
        """84=1 and 70-74 (signed target): everything but the start."""
        block = self._move_words(int(position), params)
        await self._set_position_mode(1)
        await self._restore_estop_decel()
        await self.write_block(block, priority=Priority.COMMAND)

    async def start_absolute(self) -> None:
        """18=1 starts the prepared absolute move."""
        self._jog_command = None
        await self._command(CMD_FORWARD)

    async def speed_run(self, speed_rpm: float, accel_rps2: float, decel_rps2: float) -> None:
        """Run at ``speed_rpm`` (sign = direction) with 75-78 and 18=3/4.

        Called again in the same direction while running, only register 77 is written: the
        drive applies it at once (manual 3.2.2); new accel/decel values apply only from the
        next start. A change of direction (or a run while a point move is under way) needs
        a stop first (the drive obeys only stop commands while moving): this decelerates,
        waits for MOV=0 and restarts. Speed 0 is a decelerating stop.
        """
        r = self.regs
        if speed_rpm == 0:
            await self.stop(decel_rps2)
            return
        code = CMD_JOG_FWD if speed_rpm > 0 else CMD_JOG_REV
        speed = _round_unit(r.jog_speed, abs(speed_rpm), nonzero=True)
        accel = _round_unit(r.jog_accel, accel_rps2)
        decel = _round_unit(r.jog_decel, decel_rps2)
        status = await self._read_status_word()
        if status & StatusBit.MOV:
            if self._jog_command == code:
                await self.write(r.jog_speed, speed, priority=Priority.COMMAND)
                return
            await self.stop()
            await self._wait_stopped()
        await self.write_block(
            [
                (r.jog_accel, accel),
                (r.jog_decel, decel),
                (r.jog_speed, speed),
                (r.estop_decel, self.estop_decel),
            ],
            priority=Priority.COMMAND,
        )
        self._estop_dirty = False
        await self._command(code)
        self._jog_command = code

    async def _wait_stopped(self) -> None:
        """Poll until MOV=0, bounded by the longest possible stop (3000 rpm at 10 r/s²)."""
        with anyio.fail_after(3000.0 / 60.0 / 10.0 + 2.0):
            while True:
                if not await self._read_status_word() & StatusBit.MOV:
                    return
                await anyio.sleep(0.005)  # poll period; the status read is the condition

    async def stop(self, decel_rps2: float | None = None) -> None:
        """Decelerating stop: 18=6 (decel 71 for a point move, 76 for a run).

        With ``decel_rps2``: 71/76 changes apply only from the next start, but 78 applies
        even to a stop in progress (manual 3.2.1), so this writes 78 and uses 18=5; the
        configured e-stop decel is written back before the next start.
        """
        self._jog_command = None
        self._homing = False
        await self._leave_homing_mode()
        if decel_rps2 is None:
            await self.write(self.regs.command, CMD_STOP, priority=Priority.EMERGENCY)
            return
        value = _round_unit(self.regs.estop_decel, decel_rps2)
        await self.write(self.regs.estop_decel, value, priority=Priority.EMERGENCY)
        self._estop_dirty = value != self.estop_decel
        await self.write(self.regs.command, CMD_ESTOP, priority=Priority.EMERGENCY)

    async def emergency_stop(self) -> None:
        """18=5: stop at the e-stop deceleration (78; restored if ``stop`` changed it)."""
        self._jog_command = None
        self._homing = False
        await self._leave_homing_mode()
        await self.write(self.regs.command, CMD_ESTOP, priority=Priority.EMERGENCY)
        if self._estop_dirty:  # 78 applies to the e-stop already in progress
            await self.write(self.regs.estop_decel, self.estop_decel, priority=Priority.EMERGENCY)
            self._estop_dirty = False

    async def _leave_homing_mode(self) -> None:
        """Hook: EPR60 must leave application mode 1 before register 18 acts; NT86: nothing."""

    # -- digital I/O --------------------------------------------------------------------------

    async def io_points(self) -> list[IOPoint]:
        """IN1-IN6 with their functions (60-65), OUT1/OUT2 with theirs (66/67)."""
        words = await self.slave.read_holding_registers(60, 8, priority=Priority.CONFIG)
        inputs = [IOPoint(n, False, function_text(INPUT_FUNCTIONS, w & 0x1F))
                  for n, w in zip(self.io_inputs, words[:6], strict=True)]
        outputs = [IOPoint(n, True, function_text(OUTPUT_FUNCTIONS, w & 0x0F), w & 0x0F == 0)
                   for n, w in zip(self.io_outputs, words[6:8], strict=True)]
        return inputs + outputs

    async def set_output(self, name: str, state: bool) -> None:
        """OUTn with function 0 (general-purpose): bit n-1 of register 68 (read, then
        written); another function is ``NotSupported`` naming it."""
        n = self.io_outputs.index(name)
        setting = (await self.slave.read_holding_registers(
            OUTPUT_SETTINGS + n, 1, priority=Priority.COMMAND))[0]
        if setting & 0x0F:
            raise self.unsupported(
                f"switch its output {name}",
                f"{name} is set to function {setting & 0x0F} "
                f"({function_text(OUTPUT_FUNCTIONS, setting & 0x0F)}) in register "
                f"{OUTPUT_SETTINGS + n}; {self.no_output_control}")
        value = await self.read(OUTPUT_VALUES, priority=Priority.COMMAND)
        value = value | (1 << n) if state else value & ~(1 << n)
        await self.write(OUTPUT_VALUES, value, priority=Priority.COMMAND)

    # -- the multi-segment position table (manual 3.7.4) ----------------------------------

    table_rows: ClassVar[int] = 16
    no_table: ClassVar[str] = ""

    async def prepare_table(self, rows: Sequence[tuple[int, MoveParams, float]],
                            trigger: str) -> None:
        """Internal positions 1..n (125-156, absolute: 84=1), their speed, acceleration and
        wait (224-271, ms: 223=0), single pass through n segments (221=0, 222=n), the
        input ``trigger`` given function 24 USER3 (inactive), application mode 20. The
        manual's own way to start it over Modbus is to flip that input's polarity bit
        (3.7.4): ``start_table`` does. Leave the input unwired."""
        if not 1 <= len(rows) <= self.table_rows:
            raise LimitViolation(f"a position table has 1 to {self.table_rows} rows, "
                                 f"not {len(rows)}")
        r = self.regs
        positions: list[int] = []
        segments: list[int] = []
        for k, (pulses, params, wait) in enumerate(rows):
            positions.extend(r.move_target.encode(r.move_target.check(pulses)))
            speed = Register(f"segment {k + 1} speed", 224 + 3 * k, unit="rpm", maximum=3000)
            rate = Register(f"segment {k + 1} acceleration", 225 + 3 * k, unit="r/s²",
                            minimum=1, maximum=2000)
            pause = Register(f"segment {k + 1} wait", 226 + 3 * k, unit="ms")
            segments += [_round_unit(speed, params.speed_rpm, nonzero=True),
                         _round_unit(rate, params.accel_rps2),
                         _round_unit(pause, wait * 1000.0)]
        n = self.io_inputs.index(trigger) + 1
        await self.slave.write_registers(125, positions, priority=Priority.COMMAND)
        await self.slave.write_registers(224, segments, priority=Priority.COMMAND)
        await self.slave.write_registers(221, [0, len(rows), 0], priority=Priority.COMMAND)
        await self._set_position_mode(1)
        await self._restore_estop_decel()
        await self.write(self.regs.input_config[n - 1], _FUNC_USER3, priority=Priority.COMMAND)
        await self.write(self.regs.app_mode, 20, priority=Priority.COMMAND)
        self._table_input = n
        self._jog_command = None

    async def start_table(self) -> None:
        """Flip the trigger input's polarity bit: USER3 becomes active, the table runs."""
        assert self._table_input is not None, "prepare_table first"
        reg = self.regs.input_config[self._table_input - 1]
        await self.write(reg, _FUNC_USER3 | POLARITY_BIT, priority=Priority.COMMAND,
                         idempotent=False)

    async def _leave_table(self) -> None:
        """Release the table's trigger input and go back to application mode 0."""
        n, self._table_input = self._table_input, None
        if n is None:
            return
        await self.write(self.regs.input_config[n - 1], _FUNC_USER3,
                         priority=Priority.COMMAND)
        await self.write(self.regs.app_mode, 0, priority=Priority.COMMAND)

    # -- homing ---------------------------------------------------------------------------

    def _method(self, method: str | None) -> str:
        m = self.homing_methods[0] if method is None else method
        if m not in self.homing_methods:
            raise ConfigError(
                f"{self.family} has no homing method {m!r}; it has {', '.join(self.homing_methods)}"
            )
        return m

    async def start_homing(self, params: HomingParams) -> None:
        """Write 288-291 and 293-295 (292 is reserved), then 287=4 (mechanical homing),
        5 (electrical: move to the offset) or 6 (present position becomes the offset).

        After homing, position 8/9 equals ``offset``; with ``home_offset_moves`` the motor
        first travels ``offset`` pulses past the origin (295=1/3).
        """
        m = self._method(params.method)
        if m.startswith("hard_stop") and not self.closed_loop:
            raise self.unsupported(
                f"home with method {m!r}",
                "hard-stop homing (288=4/5) works only in closed-loop control mode "
                "(register 22 = 1 or 2; setup() reads it)",
            )
        handling = (1 if self.home_offset_moves else 0) + (2 if self.home_reverse_at_limit else 0)
        speeds = [
            (NT86_HOME_FAST, _round_unit(NT86_HOME_FAST, params.speed_rpm, nonzero=True)),
            (NT86_HOME_SLOW, _round_unit(NT86_HOME_SLOW, params.creep_rpm, nonzero=True)),
            (NT86_HOME_ACCEL, _round_unit(NT86_HOME_ACCEL, params.accel_rps2)),
        ]
        if m == "electrical":  # 288 (the method) is left as it is
            await self.write_block(speeds, priority=Priority.COMMAND)
        elif m != "set_origin":
            method_word = (NT86_HOME_METHOD, self.homing_methods.index(m))
            await self.write_block([method_word, *speeds], priority=Priority.COMMAND)
        await self.write_block(
            [(NT86_HOME_OFFSET, int(params.offset)), (NT86_HOME_HANDLING, handling)],
            priority=Priority.COMMAND,
        )
        trigger = {"electrical": 5, "set_origin": 6}.get(m, 4)
        self._jog_command = None
        await self.write(NT86_HOME_TRIGGER, trigger, priority=Priority.COMMAND, idempotent=False)
        self._homing = True
        self._seen_moving = False


def __getattr__(name: str) -> object:
    """``EPR60Profile``: the profile class of the built-in EPR60 description."""
    if name == "EPR60Profile":
        from drivebus.drives.registry import FAMILIES

        return FAMILIES["EPR60"].profile
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
