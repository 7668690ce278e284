"""DriveProfile: the shared base every drive family's profile implements.

A profile turns the common procedures (enable, move, speed run, stop, home, ...) into
its drive's register writes through a ``SlaveHandle``, and decodes the drive's status
registers into ``DriveStatus``. Quantities at this level are in drive units: positions
in pulses, speeds in rev/min, accelerations in rev/s². Each profile converts these into
its own register units (r/s², ramp time in ms, ...) with range checks that name the
register. What a drive cannot do raises ``NotSupported`` naming drive and function.
"""

from __future__ import annotations

import logging
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, field
from typing import ClassVar

from pydantic import BaseModel, ConfigDict, ValidationError

from drivebus.bus import Priority, SlaveHandle
from drivebus.checks import validation_problems
from drivebus.drives.io import IOPoint, decode_bits
from drivebus.drives.programs import Completion, ProgramSupport
from drivebus.drives.registers import Access, Register, WordOrder
from drivebus.drives.status import DriveIdentity, DriveStatus
from drivebus.errors import ConfigError, FrameError, ModbusException, NotSupported
from drivebus.settings import LineSettings

__all__ = [
    "LINE_KINDS",
    "DriveOptions",
    "DriveProfile",
    "HomingParams",
    "HomingSwitches",
    "MoveParams",
    "Parameter",
    "WriteThrough",
    "describe_values",
    "ramp_time_quantized",
]

log = logging.getLogger(__name__)

LINE_KINDS = frozenset({"serial", "rtu-over-tcp", "tcp"})
"""Every kind of line (as in a machine file's ``kind``)."""


class DriveOptions(BaseModel):
    """Declares the keyword options a profile's constructor takes (a machine file's
    ``drive_options``): one field per option, with its type and range. Every field
    defaults to None ("not given"), so that the options given are checked on their own;
    the constructor's signature holds the real defaults."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


def describe_values(values: Collection[int]) -> str:
    """``lo..hi`` for a range, else the values listed."""
    if isinstance(values, range):
        if values.step != 1:
            return f"{values.start}..{values[-1]} in steps of {values.step}"
        return f"{values.start}..{values.stop - 1}"
    return ", ".join(map(str, values))

_PROCEDURES: dict[str, str] = {
    "enable": "enable the motor",
    "disable": "disable the motor",
    "move_absolute": "make an absolute move",
    "move_relative": "make a relative move",
    "speed_run": "run at a set speed",
    "stop": "stop with deceleration",
    "emergency_stop": "make an emergency stop",
    "home": "home",
    "clear_alarm": "clear an alarm",
    "zero_position": "set its position to zero",
    "save_parameters": "save parameters",
    "set_output": "switch its outputs",
}
"""Procedures a profile may lack, and how its NotSupported error says them."""


@dataclass(frozen=True)
class HomingParams:
    """One homing in drive units: the family's method name (None: its default), speeds
    in rev/min, acceleration in rev/s², the offset in pulses."""

    method: str | None = None
    speed_rpm: float = 60.0
    creep_rpm: float = 10.0
    accel_rps2: float = 10.0
    offset: int = 0


@dataclass(frozen=True)
class HomingSwitches:
    """Which limit switches a homing method may meet, as directions (+1 the positive
    switch, -1 the negative one): those it homes on, and those where the drive reverses
    and carries on searching. Any other limit switch met while homing, or a reversal
    switch met again or driven past, is a limit violation the axis stops at once."""

    homes_on: frozenset[int] = frozenset()
    reverses_at: frozenset[int] = frozenset()


@dataclass(frozen=True)
class MoveParams:
    """Speed and ramps of one move or speed run, in drive units."""

    speed_rpm: float
    accel_rps2: float
    decel_rps2: float


def ramp_time_quantized(params: MoveParams) -> MoveParams:
    """``params`` as a drive with whole-rpm speeds and whole-millisecond ramp times runs them."""
    rpm = float(round(abs(params.speed_rpm)))

    def rate(rps2: float) -> float:
        ms = round(rpm / 60.0 / rps2 * 1000.0) if rps2 > 0 else 0
        return rpm / 60.0 / (ms / 1000.0) if ms > 0 and rpm > 0 else rps2

    return MoveParams(rpm, rate(params.accel_rps2), rate(params.decel_rps2))



@dataclass(frozen=True)
class Parameter:
    """A documented, readable drive parameter: what ``drivebus params`` backs up, compares
    and restores. ``key`` names it in a parameter file; ``register`` says where it is, its
    unit, width and range (a load is range-checked against it before the first write)."""

    key: str
    register: Register
    stored: bool = True
    """Kept across a power cycle once saved (EEPROM or flash); False: volatile, RAM only."""
    comms: bool = False
    """Sets the drive's own address or line settings (after a power cycle): a load writes
    it only when asked; ``drivebus commission`` is the tool for it."""
    where: str = ""
    """The manual's notation of where it is, if not its register address (``2005h.0``)."""
    table: tuple[int, ...] = ()
    """A table-index register's table: the value is an index into these (in ``unit``)."""
    meanings: Mapping[int, str] = field(default_factory=dict)
    """What named values mean (``{0: "open", 1: "closed"}``)."""

    @property
    def location(self) -> str:
        """Where the parameter is, as the manual writes it: ``35 (0x0023)`` or ``2005h.0``."""
        if self.where:
            return self.where
        a = self.register.address
        return f"{a} (0x{a:04X})"

    @property
    def name(self) -> str:
        """The manual's name of the parameter."""
        return self.register.name

    @property
    def unit(self) -> str:
        """Its unit ("" when it has none)."""
        return self.register.unit

    @property
    def writable(self) -> bool:
        """True unless the drive only lets it be read."""
        return self.register.access is not Access.R

    @property
    def value_unit(self) -> str:
        """The unit of the value itself: a table-index register's value is an index."""
        return "table index" if self.table else self.unit

    def in_range(self, value: int) -> bool:
        """True if ``value`` is one the register takes (its documented range)."""
        return self.register.lo <= value <= self.register.hi

    def meaning(self, value: int) -> str:
        """What ``value`` stands for ("1000 pulses/rev" for a table index, a named value's
        name), or ""."""
        if self.table and 0 <= value < len(self.table):
            return f"{self.table[value]} {self.unit}".rstrip()
        return self.meanings.get(value, "")

    def allowed(self) -> str:
        """The values it takes, in a line: "0..3000 rpm", "0..15, a table index: 0 = 400,
        1 = 800, ... pulses/rev", "0..1: 0 = open, 1 = closed"."""
        lo, hi = self.register.lo, self.register.hi
        if self.table:
            return (f"{lo}..{hi}, a table index selecting "
                    f"{', '.join(map(str, self.table))} {self.unit}".rstrip())
        if self.meanings:
            named = ", ".join(f"{v} = {n}" for v, n in sorted(self.meanings.items()))
            return f"{lo}..{hi}: {named}"
        return f"{lo}..{hi} {self.unit}".rstrip()


@dataclass(frozen=True)
class WriteThrough:
    """A drive's switch that makes every Modbus write an EEPROM write while it holds ``on``
    (``off``: writes go to RAM only). A parameter load turns it off for its writes."""

    register: Register
    on: int
    off: int


class DriveProfile:
    """Base of the drive-family profiles; unsupported procedures raise ``NotSupported``."""

    family: ClassVar[str] = "generic"
    description_file: ClassVar[str] = ""
    """The description file the family was loaded from (a drive given as a file, not
    known by name): what finds the family again (``drivebus.drives.registry.family``)."""
    word_order: ClassVar[WordOrder] = WordOrder.HIGH_FIRST
    exception_texts: ClassVar[dict[int, str]] = {}
    unsupported_reason: ClassVar[str] = ""
    """Why the family lacks the procedures it does not override (said with each error)."""
    homing_methods: ClassVar[tuple[str, ...]] = ()
    """Names of the homing methods ``home()`` accepts, the first is the default."""

    # -- what the drive accepts (checked by machine files and by the constructor) ---------------

    options: ClassVar[type[DriveOptions]] = DriveOptions
    """The constructor's keyword options beyond ``pulses_per_rev``, typed and ranged."""
    pulses_per_rev_allowed: ClassVar[Collection[int]] = range(1, 1 << 31)
    """The pulses per revolution the drive can be set to."""
    addresses: ClassVar[range] = range(1, 248)
    """The slave addresses (Modbus TCP: unit ids) the drive can have."""
    line_kinds: ClassVar[frozenset[str]] = LINE_KINDS
    """The kinds of line that can reach it ("tcp" for an RTU drive: through a gateway)."""
    baud_rates: ClassVar[tuple[int, ...]] = ()
    """The baud rates it can run on a serial line (empty: any)."""
    line_formats: ClassVar[tuple[str, ...]] = ()
    """The character formats (``8N1``...) it can run on a serial line (empty: any)."""

    standard_frames: ClassVar[bool] = True
    """Speaks standard Modbus frames (a scan finds it by a plain register read first)."""

    # -- parameters (``drivebus params``): data, in the manual's order --------------------------

    parameter_list: ClassVar[tuple[Parameter, ...]] = ()
    """The drive's documented readable parameters (commands and status excluded)."""
    write_through: ClassVar[WriteThrough | None] = None
    """The drive's EEPROM write-through switch, if it has one."""
    saves_by_write_through: ClassVar[bool] = False
    """The drive has no save command: a value is stored only when written with write-through
    on (``save_parameters`` then cannot store values written before)."""

    @classmethod
    def parameters(cls) -> tuple[Parameter, ...]:
        """The drive's documented readable parameters, in the manual's order."""
        return cls.parameter_list

    parameter_read_words: ClassVar[int] = 16
    """The most registers ``read_parameter_values`` reads in one request: 16, the
    smallest limit among the drives, or a description's ``[link] max_read`` below it."""

    async def read_parameter_values(
        self, params: Sequence[Parameter], *, priority: Priority = Priority.CONFIG
    ) -> list[int]:
        """The values of ``params`` (reads only: registers side by side in one read, at
        most ``parameter_read_words`` words)."""
        values: list[int] = []
        i = 0
        while i < len(params):
            first = params[i].register
            group = [first]
            end = first.address + first.words
            if first.contiguous:
                for p in params[i + 1 :]:
                    r = p.register
                    if not r.contiguous or r.address != end or (
                            end + r.words - first.address > self.parameter_read_words):
                        break
                    group.append(r)
                    end += r.words
            if len(group) == 1:
                values.append(await self.read(first, priority=priority))
            else:
                words = await self.slave.read_holding_registers(
                    first.address, end - first.address, priority=priority
                )
                for r in group:
                    values.append(r.decode(words[r.address - first.address :][: r.words]))
            i += len(group)
        return values

    async def write_parameter_value(
        self, param: Parameter, value: int, *, priority: Priority = Priority.CONFIG
    ) -> None:
        """Write one parameter (range-checked by its register)."""
        await self.write(param.register, value, priority=priority)

    def save_problem(self) -> str | None:
        """Why ``save_parameters`` cannot store the parameters now, or None (no I/O)."""
        try:
            self.check_supported("save_parameters")
        except NotSupported as exc:
            return str(exc)
        return None

    # -- commissioning (``drivebus commission``): the drive's own address and line settings --

    comms_note: ClassVar[str] = ""
    """How the drive takes a new address or line settings (switches, a power cycle)."""

    def comms_writes(
        self, address: int | None, settings: LineSettings | None, current: LineSettings | None
    ) -> list[tuple[Register, int]]:
        """The register writes that give the drive ``address`` and ``settings`` (None: keep),
        talking at ``current`` now; ``NotSupported`` saying how it is done instead."""
        raise self.unsupported("change its address or line settings",
                               self.comms_note or "the manual documents no register for them")
    io_inputs: ClassVar[tuple[str, ...]] = ()
    """The input terminals by the manual's names, in the order of the bits of the input
    state the status carries (``raw["inputs"]``); empty: none readable."""
    io_outputs: ClassVar[tuple[str, ...]] = ()
    """The output terminals likewise (``raw["outputs"]``)."""
    no_output_control: ClassVar[str] = (
        "its manual documents no way to switch an output over Modbus")
    """Why ``set_output`` cannot (said in its NotSupported error)."""

    programs: ClassVar[ProgramSupport] = ProgramSupport()
    """What the drive offers motion programs (buffered and blended moves, speed changes
    on the fly), each with its manual's reason; by default nothing."""

    def __init__(self, slave: SlaveHandle, *, pulses_per_rev: int = 10000) -> None:
        self.slave = slave
        self.pulses_per_rev = self.check_pulses_per_rev(pulses_per_rev)
        slave.exception_texts.update(self.exception_texts)

    # -- who the drive is (a scan asks every family in the registry) ----------------------------

    @classmethod
    def could_be_at(cls, address: int, line_kind: str, settings: LineSettings | None) -> bool:
        """Whether a drive of this family can answer at ``address`` on a ``line_kind`` line
        with ``settings`` (from its declarations; no I/O)."""
        if address not in cls.addresses or line_kind not in cls.line_kinds:
            return False
        if settings is None or line_kind == "tcp":
            return True
        return (not cls.baud_rates or settings.baudrate in cls.baud_rates) and (
            not cls.line_formats or settings.format in cls.line_formats
        )

    @classmethod
    async def identify(cls, slave: SlaveHandle) -> DriveIdentity | None:
        """Probe ``slave``: this family's identity (model and firmware where the drive
        tells them) if it is a drive of this family, else None. A refusal or an unusable
        answer means "not this family"; a timeout or a port error propagates."""
        profile = cls(slave)
        try:
            ident = await profile.read_identity()
        except (ModbusException, FrameError):
            return None
        return ident if profile.is_own_identity(ident) else None

    def is_own_identity(self, ident: DriveIdentity) -> bool:
        """Whether ``ident`` (as ``read_identity`` read it) is this family's."""
        return False

    @classmethod
    def option_problems(cls, options: Mapping[str, object], *, prefix: str = "") -> list[str]:
        """``name: problem (got value)`` for each of ``options`` the drive does not take
        (``prefix`` goes before each name)."""
        try:
            cls.options.model_validate(dict(options))
        except ValidationError as exc:
            return validation_problems(exc, model=cls.options, prefix=prefix)
        return []

    @classmethod
    def check_options(cls, options: Mapping[str, object]) -> None:
        """``ConfigError`` naming each option the drive does not take, its value and range."""
        problems = cls.option_problems(options)
        if problems:
            raise ConfigError(f"{cls.family} drive options: {'; '.join(problems)}")

    @classmethod
    def pulses_per_rev_problem(cls, pulses_per_rev: object) -> str | None:
        """Why the drive cannot be set to ``pulses_per_rev``, or None if it can."""
        ok = cls.pulses_per_rev_allowed
        if isinstance(pulses_per_rev, int) and not isinstance(pulses_per_rev, bool) and (
            pulses_per_rev in ok
        ):
            return None
        return (f"the {cls.family} drive cannot run {pulses_per_rev!r} pulses/rev "
                f"(allowed: {describe_values(ok)})")

    @classmethod
    def check_pulses_per_rev(cls, pulses_per_rev: int) -> int:
        """``pulses_per_rev`` if the drive can be set to it; else ``ConfigError``."""
        problem = cls.pulses_per_rev_problem(pulses_per_rev)
        if problem:
            raise ConfigError(f"pulses_per_rev: {problem}")
        return pulses_per_rev

    @classmethod
    def settings_problem(cls, settings: LineSettings) -> str | None:
        """Why the drive cannot talk at ``settings`` on a serial line, or None if it can."""
        if cls.baud_rates and settings.baudrate not in cls.baud_rates:
            return (f"the {cls.family} drive cannot run {settings.baudrate} baud "
                    f"(it runs {describe_values(cls.baud_rates)})")
        if cls.line_formats and settings.format not in cls.line_formats:
            return (f"the {cls.family} drive cannot talk {settings.format} "
                    f"(it talks {', '.join(cls.line_formats)})")
        return None

    @classmethod
    def axis_problems(
        cls,
        *,
        address: int,
        line_kind: str,
        settings: LineSettings | None,
        pulses_per_rev: int,
        homing_method: str | None,
        options: Mapping[str, object],
    ) -> list[str]:
        """``axis key: problem`` for every setting of an axis that this drive cannot take:
        what a machine file is checked against before anything is opened."""
        out: list[str] = []
        if address not in cls.addresses:
            out.append(f"address: the {cls.family} drive has addresses "
                       f"{describe_values(cls.addresses)}, not {address}")
        if line_kind not in cls.line_kinds:
            kinds = ", ".join(sorted(cls.line_kinds))
            out.append(f"line: the {cls.family} drive cannot be reached on a {line_kind} line "
                       f"(only on {kinds} lines)")
        elif settings is not None and line_kind != "tcp":
            problem = cls.settings_problem(settings)
            if problem:
                out.append(f"settings: {settings}: {problem}")
        problem = cls.pulses_per_rev_problem(pulses_per_rev)
        if problem:
            out.append(f"pulses_per_rev: {problem}")
        if homing_method is not None and homing_method not in cls.homing_methods:
            methods = ", ".join(cls.homing_methods)
            has = f"it has {methods}" if methods else "it cannot home over Modbus"
            out.append(f"homing.method: the {cls.family} drive has no homing method "
                       f"{homing_method!r} ({has})")
        out += cls.option_problems(options, prefix="drive_options")
        return out

    def unsupported(self, what: str, why: str = "") -> NotSupported:
        """The error for a procedure this drive lacks."""
        why = why or self.unsupported_reason
        tail = f": {why}" if why else ""
        return NotSupported(f"the {self.family} drive cannot {what} over Modbus{tail}")

    def check_supported(self, procedure: str) -> None:
        """``NotSupported`` if this drive cannot do ``procedure`` at all (no I/O).

        The axis asks before it changes state, so a refused command leaves it as it was.
        The default: a procedure the profile does not override is not supported; profiles
        whose support depends on options (an opted-in input, say) extend this.
        """
        what = _PROCEDURES[procedure]
        method = "start_homing" if procedure == "home" else procedure
        if getattr(type(self), method) is getattr(DriveProfile, method):
            raise self.unsupported(what)

    def check_stop(self, decel_rps2: float | None) -> None:
        """``NotSupported`` (before anything is sent) if ``stop`` cannot honour
        ``decel_rps2``: a drive whose stop takes no deceleration (its ramp is fixed, or it
        stops by clearing a release bit) refuses one rather than ignore it."""
        if decel_rps2 is not None and not self.stop_takes_decel():
            raise self.unsupported(f"stop with a deceleration of {decel_rps2:g} rev/s²",
                                   "its stop takes no deceleration (it stops on its own "
                                   "ramp): call stop() without decel")

    def stop_takes_decel(self) -> bool:
        """Whether ``stop`` honours a deceleration (the default: it does)."""
        return True

    def check_homing(self, params: HomingParams) -> None:
        """``NotSupported``/``UnknownMethod``/``LimitViolation`` if ``start_homing(params)``
        would be refused (no I/O): the axis asks before anything is sent."""
        self.check_supported("home")

    @property
    def tracked(self) -> frozenset[str]:
        """The status fields (``enabled``, ``homed``) that are only what the profile
        commanded or saw, not read from the drive: a restart goes unseen by them."""
        return frozenset()

    def restarted(self) -> None:
        """The drive may have restarted (a power cycle, a reset): forget what the profile
        tracked of it (no I/O; the axis sets the drive up again before its next command)."""

    def volatile_settings(self) -> list[tuple[Register, int]]:
        """The (register, value) pairs this profile wrote that a power cycle undoes.

        ``setup()`` writes them (or the profile caches what it wrote since, like a position
        mode); after the drive was unreachable or looks reset, the axis reads them back with
        ``lost_settings()`` and runs ``setup()`` again before the next command if any differs.
        """
        return []

    async def lost_settings(self, *, priority: Priority = Priority.COMMAND) -> list[str]:
        """Names of the volatile settings the drive no longer holds (read back; [] = intact)."""
        wanted = sorted(self.volatile_settings(), key=lambda rv: (rv[0].address,
                                                                   rv[0].offset))
        lost: list[str] = []
        i = 0
        while i < len(wanted):
            first = wanted[i][0]
            group = wanted[i : i + 1]
            if first.contiguous:
                for reg, value in wanted[i + 1 :]:
                    if not reg.follows(group[-1][0]):
                        break  # only registers side by side: a gap may be unmapped
                    group.append((reg, value))
                last = group[-1][0]
                start = first.address
                count = (last.offset + last.words) if first.objects else \
                    last.address + last.words - start
                words = await self.slave.read_holding_registers(start, count,
                                                                priority=priority)
                seen = {
                    (r.address, r.offset): r.decode(
                        words[r.offset if r.objects else r.address - start :][: r.words])
                    for r, _ in group
                }
            else:
                seen = {(first.address, 0): await self.read(first, priority=priority)}
            lost.extend(
                f"{r.name} ({r.address}) = {seen[r.address, r.offset]}, not {v}"
                for r, v in group
                if seen[r.address, r.offset] != v
            )
            i += len(group)
        return lost

    # -- register helpers (one register codec) -----------------------------------------------

    async def read(self, reg: Register, *, priority: Priority = Priority.CONFIG) -> int:
        """Read one register (both words of a 32-bit one; a sub-index behind its object's
        address with the object's words before it)."""
        if reg.contiguous:
            words = await self.slave.read_holding_registers(
                reg.address, reg.offset + reg.words, priority=priority
            )
            return reg.decode(words[reg.offset:])
        assert reg.low_address is not None
        hi = await self.slave.read_holding_registers(reg.address, 1, priority=priority)
        lo = await self.slave.read_holding_registers(reg.low_address, 1, priority=priority)
        return reg.decode([hi[0], lo[0]])

    async def write(
        self,
        reg: Register,
        value: int,
        *,
        priority: Priority = Priority.CONFIG,
        idempotent: bool = True,
    ) -> None:
        """Write one register, range-checked (a 32-bit one in one transaction if contiguous;
        a sub-index behind its object's address with the object's words before it, as
        read)."""
        words = reg.encode(value)
        if reg.offset:
            head = await self.slave.read_holding_registers(reg.address, reg.offset,
                                                           priority=priority)
            await self.slave.write_registers(reg.address, [*head, *words], priority=priority,
                                             idempotent=idempotent)
        elif len(words) == 1:
            await self.slave.write_register(
                reg.address, words[0], priority=priority, idempotent=idempotent
            )
        elif reg.contiguous:
            await self.slave.write_registers(
                reg.address, words, priority=priority, idempotent=idempotent
            )
        else:
            assert reg.low_address is not None
            for address, word in ((reg.address, words[0]), (reg.low_address, words[1])):
                await self.slave.write_register(
                    address, word, priority=priority, idempotent=idempotent
                )

    async def write_block(
        self,
        regs: Sequence[tuple[Register, int]],
        *,
        priority: Priority = Priority.CONFIG,
        idempotent: bool = True,
    ) -> None:
        """Write registers that follow on (``Register.follows``: consecutive addresses, or
        the sub-indices of one object) in one FC16 transaction."""
        first = regs[0][0]
        values: list[int] = []
        if first.offset:  # the object's words before it, as the drive holds them
            values = await self.slave.read_holding_registers(first.address, first.offset,
                                                             priority=priority)
        for i, (reg, v) in enumerate(regs):
            if (i and not reg.follows(regs[i - 1][0])) or not reg.contiguous:
                raise ValueError(f"register {reg.name} does not follow on from "
                                 f"{regs[i - 1][0].name if i else 'nothing'}")
            values.extend(reg.encode(v))
        await self.slave.write_registers(first.address, values, priority=priority,
                                         idempotent=idempotent)

    # -- procedures ---------------------------------------------------------------------------

    async def learn(self, *, priority: Priority = Priority.CONFIG) -> None:
        """Read what decoding the status needs (input functions, control mode): reads
        only, never a write. An axis calls it when it opens; a viewing command never
        goes further. ``priority``: its reads' (a status poll that learns first reads at
        its own, so an emergency poll inside a hold never waits for the hold's end)."""

    async def setup(self) -> None:
        """Configure the drive for commands (no motion): the writes an axis makes before
        the first command it is given, never for viewing. It learns too."""
        await self.learn()

    def homing_switches(self, method: str | None) -> HomingSwitches:
        """The limit switches homing with ``method`` (None: the default) homes on or
        reverses at (by default none: any limit switch met while homing stops it)."""
        return HomingSwitches()

    async def read_status(self, *, priority: Priority = Priority.POLL) -> DriveStatus:
        """Poll the drive's status into a ``DriveStatus``."""
        raise self.unsupported("report its status")

    async def read_identity(self) -> DriveIdentity:
        """Model and firmware, where the drive tells them."""
        return DriveIdentity(self.family)

    async def enable(self) -> None:
        """Energise the motor."""
        raise self.unsupported("enable the motor")

    async def disable(self) -> None:
        """De-energise the motor."""
        raise self.unsupported("disable the motor")

    def check_move(self, params: MoveParams, position: int = 0) -> None:
        """LimitViolation if the drive cannot take ``params``, or an absolute move to
        ``position`` pulses (no I/O; planners use it)."""

    def quantize(self, params: MoveParams) -> MoveParams:
        """The speed and ramps the drive really runs for ``params``, after its registers'
        rounding (whole rpm, whole r/s² or whole-millisecond ramp times); no range check.
        A group plans with these so that axes on different drives arrive together."""
        return params

    async def move_absolute(self, position: int, params: MoveParams) -> None:
        """Start a move to ``position`` pulses; returns once the drive accepted it."""
        raise self.unsupported("make an absolute move")

    async def prepare_absolute(self, position: int, params: MoveParams) -> None:
        """Write everything a move to ``position`` needs except its start.

        ``start_absolute()`` then starts it with as little traffic as the drive allows, so a
        group can prepare every axis first and start them back to back. The default keeps
        the arguments and makes the whole move at the start.
        """
        self._prepared = (position, params)

    async def start_absolute(self) -> None:
        """Start the move that ``prepare_absolute`` prepared."""
        position, params = self._prepared
        await self.move_absolute(position, params)

    async def move_relative(self, distance: int, params: MoveParams) -> None:
        """Start a move by ``distance`` pulses; returns once the drive accepted it."""
        raise self.unsupported("make a relative move")

    async def speed_run(self, speed_rpm: float, accel_rps2: float, decel_rps2: float) -> None:
        """Run at ``speed_rpm`` (sign = direction); called again it changes the speed."""
        raise self.unsupported("run at a set speed")

    async def stop(self, decel_rps2: float | None = None) -> None:
        """Decelerating stop."""
        raise self.unsupported("stop with deceleration")

    async def emergency_stop(self) -> None:
        """Stop as fast as the drive can."""
        raise self.unsupported("make an emergency stop")

    def check_can_stop(self) -> None:
        """``NotSupported`` (no I/O) if this drive has neither a stop nor an emergency stop:
        a stop is then refused before the motion under way is touched."""
        try:
            self.check_supported("stop")
            return
        except NotSupported as exc:
            refused = exc
        try:
            self.check_supported("emergency_stop")
        except NotSupported:
            raise refused from None

    async def send_stop(self, decel_rps2: float | None = None, *, emergency: bool = False
                        ) -> None:
        """The stop asked for (``emergency``: the emergency stop), or the other one where
        this drive cannot make it: a motor must not run on because its description lacks
        one kind of stop. ``NotSupported`` (nothing sent) only if it can make neither."""
        try:
            if emergency:
                await self.emergency_stop()
            else:
                await self.stop(decel_rps2)
            return
        except NotSupported as exc:
            refused = exc
        log.warning("%s: %s instead", refused,
                    "a decelerating stop" if emergency else "an emergency stop")
        try:
            if emergency:
                await self.stop(None)
            else:
                await self.emergency_stop()
        except NotSupported:
            raise refused from None

    async def home(
        self,
        method: str | None = None,
        *,
        speed_rpm: float = 60.0,
        creep_rpm: float = 10.0,
        accel_rps2: float = 10.0,
        offset: int = 0,
    ) -> None:
        """Start homing with ``method`` (one of ``homing_methods``), speeds in rev/min,
        acceleration in rev/s², ``offset`` in pulses (``start_homing`` does it)."""
        await self.start_homing(HomingParams(method, speed_rpm, creep_rpm, accel_rps2, offset))

    async def start_homing(self, params: HomingParams) -> None:
        """Start the homing ``params`` describe; each family that can home overrides this."""
        raise self.unsupported("home")

    async def clear_alarm(self) -> None:
        """Clear a latched alarm."""
        raise self.unsupported("clear an alarm")

    async def zero_position(self) -> None:
        """Make the present position zero."""
        raise self.unsupported("set its position to zero")

    async def save_parameters(self) -> None:
        """Store the parameters in the drive's non-volatile memory."""
        raise self.unsupported("save parameters")

    # -- motion programs ------------------------------------------------------------------

    async def retarget_absolute(self, position: int, params: MoveParams) -> None:
        """Give a running motion a new target (and speed) without stopping, where the
        drive's manual allows it (``programs.retarget``); at rest it is an absolute move."""
        raise self.unsupported("take a new target while it moves", self.programs.no_retarget)

    async def read_completion(self, *, priority: Priority = Priority.COMMAND) -> Completion | None:
        """A short read that tells whether a motion has ended (a buffered move starts on
        it); None: the family's full status read is as short (``read_status`` is used)."""
        return None

    # -- digital I/O --------------------------------------------------------------------------

    def io_state(self, status: DriveStatus) -> tuple[dict[str, bool], dict[str, bool]]:
        """The inputs' and outputs' states (by name) in a polled ``status``."""
        return (decode_bits(self.io_inputs, status.raw.get("inputs")),
                decode_bits(self.io_outputs, status.raw.get("outputs")))

    async def io_points(self) -> list[IOPoint]:
        """Every terminal and what it is set to do (reads the drive's I/O settings)."""
        return ([IOPoint(n, False) for n in self.io_inputs]
                + [IOPoint(n, True) for n in self.io_outputs])

    async def set_output(self, name: str, state: bool) -> None:
        """Switch output ``name`` on or off, where the drive lets Modbus drive it."""
        raise self.unsupported(f"switch its output {name}", self.no_output_control)

    async def check_output(self, name: str, state: bool) -> None:
        """``NotSupported`` if ``set_output(name, state)`` would be refused, decided by
        reads alone (nothing is written): the axis asks before it sets the drive up."""
        self.check_supported("set_output")

    # -- position tables ----------------------------------------------------------------------

    table_rows: ClassVar[int] = 0
    """How many rows the drive's own position table has that Modbus can run (0: none)."""
    no_table: ClassVar[str] = "drivebus knows no way to start its position table over Modbus"
    """Why ``prepare_table`` cannot (said in its NotSupported error)."""

    async def prepare_table(self, rows: Sequence[tuple[int, MoveParams, float]],
                            trigger: str) -> None:
        """Write ``rows`` (absolute position in pulses, speed and ramp, wait after it in
        seconds) into the drive's position table, armed to run once from its first row
        when ``start_table`` pulls the input ``trigger``'s function."""
        raise self.unsupported("run its position table", self.no_table)

    async def start_table(self) -> None:
        """Start the table ``prepare_table`` wrote."""
        raise self.unsupported("run its position table", self.no_table)
