"""OD2000: the drive with a 2000h object-dictionary map on a non-standard Modbus-RTU port.

Source: ``shared/seeds/003_5f14fd9326f2e79a.txt`` (extraction ``shared/drives/003_od_drive.md``).
The manual names no product; it looks like the serial service port of an EtherCAT
closed-loop stepper drive. What it documents, and what this profile therefore offers:

* **Frames are not standard Modbus.** Every request carries a 16-bit object index *and* a
  sub-index byte: ``[addr][03][idxHi][idxLo][sub][cntHi][cntLo][crc]`` (9 bytes), FC06 the
  same with a value (the reply echoes it), FC10 ``[..][sub][cnt][bytes][data]`` with a
  9-byte reply. They go through the bus's raw path ``SlaveHandle.transact`` with
  ``reply_length`` as the reply-length predictor. The serial address is fixed at 1, the
  line at 9600 8N1; at most 16 registers per read.
* **No motion objects at all**: no control/status word, target, speed, ramp, homing or
  enable. Every motion procedure raises ``NotSupported`` naming the drive.
* What exists: monitoring (accumulated command position 2010h high word / 2011h low word,
  inputs 2014h, speed reference 2017h, position error 2018h, "motor does not move" code
  201Fh, fault list 201Ch), identity (201Ah.1-3), clear alarm (201Eh), clear fault log
  (201Dh), zero the position counter (2011h = 1), save / factory reset (2030h bit0 / bit1),
  and typed, range-checked access to every object (``read_object``/``write_object``).
* **Vendor exception codes** (table L466-492): 01 CRC error, 02 function code error,
  03 address out of range, 04 read count > 16, 05 access violation, 06 value out of range.
* **CRC errors** (manual contradiction, L395-401): the text says the drive discards a
  damaged frame silently, its example shows the reply ``01 83 01 80 F0``. Either way the
  frame was *not* executed, so the profile copes with both: silence is a timeout (the bus
  retries reads), exception 01 is retried here for any request, up to the slave's retries.

**Why this is code and not a drive description** (``drivebus/drives/descriptions/``):
a description's link speaks Modbus function codes over 16-bit register addresses; this
drive's requests carry an index *and* a sub-index byte, so none of its frames is a Modbus
PDU. Declaring them as a framing of the link would add a second frame grammar to the
bus's transaction rules (reply-length prediction, CRC and exception handling) for one
drive that has no motion objects to describe; its own codec here is shorter and is the
one place that knows the format. Its twin (``drivebus.sim.drives.od_drive``) is code for
the same reason.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar

from drivebus.bus import Priority, SlaveHandle
from drivebus.clock import monotonic
from drivebus.drives.base import DriveProfile, Parameter
from drivebus.drives.registers import Access, Register, WordOrder, join_words
from drivebus.drives.status import DriveIdentity, DriveStatus
from drivebus.errors import ConfigError, FrameError, ModbusException
from drivebus.settings import LineSettings

__all__ = [
    "ALARM_TEXTS",
    "BY_NAME",
    "DEFAULT_SETTINGS",
    "EXCEPTION_TEXTS",
    "OBJECTS",
    "SERIAL_ADDRESS",
    "ODDriveProfile",
    "ODObject",
    "read_pdu",
    "reply_length",
    "write_multiple_pdu",
    "write_pdu",
]

FAMILY = "OD2000"
DEFAULT_SETTINGS = LineSettings.parse("9600 8N1")
"""The only line format the manual lists (L9-16)."""
SERIAL_ADDRESS = 1
"""The serial address is fixed to 0x01 (L26); 2000h/2001h set the EtherCAT address."""
MAX_READ = 16
"""At most 16 registers per read (L346; exception 04 beyond)."""

FC_READ = 0x03
FC_WRITE = 0x06
FC_WRITE_MULTIPLE = 0x10
EXC_CRC = 0x01

EXCEPTION_TEXTS: dict[int, str] = {
    1: "CRC verification error: the drive discarded a damaged frame",
    2: "function code error: the drive accepts only function codes 03, 06 and 16",
    3: "address out of range: no such object index / sub-index",
    4: "read count overflow: at most 16 registers per read",
    5: "access violation: the object is read-only or write-only here "
    "(current-loop Kp/Ki are read-only while auto-tune 2007h = 1)",
    6: "value out of range: the written value is outside the object's range",
}

ALARM_TEXTS: dict[int, str] = {
    23: "current mode is not supported",
    30: "command overspeed",
}
"""The "motor does not move" codes of 201Fh the manual lists (L171-175); others are unnamed."""

WHY_NO_MOTION = (
    "its serial port has no motion objects (no control word, target, speed, ramp, homing "
    "or enable object); motion is commanded over the drive's fieldbus, which the manual "
    "does not cover"
)


# -- frames ----------------------------------------------------------------------------------


def _check_key(index: int, sub: int) -> None:
    if not 0 <= index <= 0xFFFF:
        raise ConfigError(f"object index {index:#x} is outside 0000h..FFFFh")
    if not 0 <= sub <= 0xFF:
        raise ConfigError(f"sub-index {sub} is outside 0..255")


def _check_word(value: int) -> None:
    if not 0 <= value <= 0xFFFF:
        raise ConfigError(f"word {value} is outside 0..65535")


def read_pdu(index: int, sub: int, count: int) -> bytes:
    """FC03 request PDU ``03 idxHi idxLo sub cntHi cntLo`` (no count limit: raw frames)."""
    _check_key(index, sub)
    _check_word(count)
    return struct.pack(">BHBH", FC_READ, index, sub, count)


def write_pdu(index: int, sub: int, word: int) -> bytes:
    """FC06 request PDU ``06 idxHi idxLo sub valHi valLo``; the drive echoes it."""
    _check_key(index, sub)
    _check_word(word)
    return struct.pack(">BHBH", FC_WRITE, index, sub, word)


def write_multiple_pdu(index: int, sub: int, words: Sequence[int]) -> bytes:
    """FC10 request PDU ``10 idxHi idxLo sub cntHi cntLo bytes data...``."""
    _check_key(index, sub)
    if not 1 <= len(words) <= 127:
        raise ConfigError(f"{len(words)} words do not fit one FC10 frame (1..127)")
    for w in words:
        _check_word(w)
    head = struct.pack(">BHBHB", FC_WRITE_MULTIPLE, index, sub, len(words), 2 * len(words))
    return head + struct.pack(f">{len(words)}H", *words)


def reply_length(pdu: bytes) -> int | None:
    """Reply-length predictor for the raw path: the reply PDU's length once it is known.

    FC03 replies are standard (``03 n data``); FC06 echoes its 6-byte PDU; FC10 answers
    ``10 idx sub cnt`` (6 bytes); exceptions are ``fc|80 code``.
    """
    if not pdu:
        return None
    fc = pdu[0]
    if fc & 0x80:
        return 2
    if fc == FC_READ:
        return 2 + pdu[1] if len(pdu) >= 2 else None
    if fc in (FC_WRITE, FC_WRITE_MULTIPLE):
        return 6
    return 2  # unknown reply: take two bytes; the CRC check then fails and the bus resyncs


# -- the object dictionary -------------------------------------------------------------------


@dataclass(frozen=True)
class ODObject:
    """One object-dictionary entry: index, sub-index and its register codec (range, access)."""

    index: int
    sub: int
    name: str
    register: Register
    saved: bool
    """The "S" attribute: kept in non-volatile memory by a save (2030h bit0)."""

    @property
    def key(self) -> tuple[int, int]:
        """``(index, sub)``."""
        return self.index, self.sub

    @property
    def label(self) -> str:
        """The manual's notation, e.g. ``2003h.1``."""
        return f"{self.index:04X}h.{self.sub}"

    @property
    def readable(self) -> bool:
        """True unless the object is write-only."""
        return self.register.access is not Access.W

    @property
    def writable(self) -> bool:
        """True unless the object is read-only."""
        return self.register.access is not Access.R


def _o(
    index: int,
    sub: int,
    name: str,
    lo: int,
    hi: int,
    access: Access = Access.RW,
    *,
    unit: str = "",
    signed: bool = False,
    saved: bool = True,
) -> ODObject:
    reg = Register(
        f"{name} ({index:04X}h.{sub})", index, signed=signed, unit=unit, minimum=lo,
        maximum=hi, access=access,
    )
    return ODObject(index, sub, name, reg, saved)


_R, _W = Access.R, Access.W

OBJECTS: tuple[ODObject, ...] = (
    _o(0x2000, 0, "ec_address", 0, 65535),
    # Printed range 0~1, but the value list documents 0, 1 and 2 (ESC EEPROM): 0..2 here.
    _o(0x2001, 0, "ec_address_source", 0, 2),
    _o(0x2002, 0, "direction", 0, 1),
    _o(0x2003, 1, "standstill_current_delay", 10, 3000, unit="ms"),
    _o(0x2003, 2, "standstill_current_percent", 0, 100, unit="%"),
    _o(0x2004, 0, "peak_current", 100, 7000),  # unit not stated, probably mA
    _o(0x2005, 0, "pulses_per_rev", 6400, 51200, unit="pulses/rev"),  # default 1000 (!)
    _o(0x2006, 0, "disable_mode", 0, 1),
    _o(0x2007, 0, "current_loop_autotune", 0, 1),
    _o(0x2008, 0, "current_loop_kp", 50, 32767),  # read-only while 2007h = 1
    _o(0x2009, 0, "current_loop_ki", 10, 2000),  # read-only while 2007h = 1
    _o(0x200A, 0, "current_loop_kc", 0, 32767, _R),
    _o(0x200B, 0, "soft_start_time", 10, 3000),  # default 0 (!), unit not stated
    _o(0x200C, 0, "soft_start_enable", 0, 1),
    _o(0x200D, 0, "bus_voltage", 0, 65535, _R, saved=False),
    _o(0x200E, 0, "following_error_alarm_enable", 0, 1),
    _o(0x200F, 0, "following_error_angle", 0, 360, unit="deg"),
    _o(0x2010, 0, "position_command_high", 0, 65535, _R, saved=False),
    _o(0x2011, 0, "position_command_low", 0, 65535, saved=False),  # write 1: clear
    _o(0x2012, 0, "speed_limit", 0, 3000, unit="rpm", saved=False),
    _o(0x2013, 0, "power_on_test_motion", 0, 1),
    _o(0x2014, 0, "inputs", 0, 65535, _R, saved=False),
    _o(0x2015, 0, "fir_filter_enable", 0, 1),
    _o(0x2016, 0, "fir_filter_time", 50, 25600),
    _o(0x2017, 0, "speed_reference", 0, 32767, _R, unit="rpm", saved=False),
    _o(0x2018, 0, "position_error", -32768, 32767, signed=True),
    _o(0x2019, 0, "closed_loop", 0, 1),
    _o(0x201A, 1, "software_version", 0, 32767, _R, saved=False),
    _o(0x201A, 2, "hardware_version", 0, 32767, _R, saved=False),
    _o(0x201A, 3, "bus_software_version", 0, 32767, _R, saved=False),
    _o(0x201B, 0, "fault_detection_mask", 0, 65535),
    *(_o(0x201C, n, f"fault_list_{n}", 0, 65535) for n in range(1, 10)),
    _o(0x201D, 0, "clear_fault_log", 0, 1, saved=False),
    _o(0x201E, 0, "clear_alarm", 0, 1, saved=False),
    _o(0x201F, 0, "stop_reason", 0, 32767, _R, saved=False),
    _o(0x2020, 0, "in_position_source", 0, 32767),
    # 2021h/2024h are bitmasks (5 inputs, 3 outputs) printed with range 0~1: widened here.
    _o(0x2021, 0, "input_polarity", 0, 0x1F),
    *(_o(0x2022, n, f"input_function_{n}", 0, 255) for n in range(1, 6)),
    # Printed 50~60000, 60001 ... 60004: a spreadsheet auto-fill artefact; 50..60000 for all.
    *(_o(0x2023, n, f"input_filter_{n}", 50, 60000) for n in range(1, 6)),
    _o(0x2024, 0, "output_polarity", 0, 0x07),
    *(_o(0x2025, n, f"output_function_{n}", 0, 255) for n in range(1, 4)),
    _o(0x2030, 0, "save_restore", 0, 255, _W),
)

BY_KEY: dict[tuple[int, int], ODObject] = {o.key: o for o in OBJECTS}
BY_NAME: dict[str, ODObject] = {o.name: o for o in OBJECTS}

STATUS_BLOCK = 0x2010
STATUS_COUNT = 9
"""2010h.0 .. 2018h.0: all sub-0 objects at consecutive indexes, so one read is unambiguous."""
INPUT_FUNCTIONS = 0x2022
FN_ORIGIN, FN_LIMIT_POSITIVE, FN_LIMIT_NEGATIVE = 1, 2, 4
SAVE_BIT, RESTORE_BIT = 0x01, 0x02


_NOT_PARAMETERS = frozenset({"position_command_low", "speed_limit", "position_error",
                             *(f"fault_list_{n}" for n in range(1, 10))})
"""Readable RW objects that are no settings: the position counter (a write clears it),
the present speed limit, the live position error and the fault log."""

OD_PARAMETERS: tuple[Parameter, ...] = tuple(
    Parameter(o.name, o.register, stored=o.saved, where=o.label)
    for o in OBJECTS
    if o.readable and o.writable and o.name not in _NOT_PARAMETERS and o.saved
)
"""The OD2000's settings (its "S" objects that can be read and written), in index order;
``Parameter.register.address`` is the object's index (``lookup_name(key)`` has its sub)."""


def lookup(index: int, sub: int = 0) -> ODObject:
    """The object ``index.sub``; ``ConfigError`` naming it if the manual has no such entry."""
    obj = BY_KEY.get((index, sub))
    if obj is None:
        raise ConfigError(f"the {FAMILY} drive has no object {index:04X}h.{sub}")
    return obj


def lookup_name(name: str) -> ODObject:
    """The object called ``name`` (see ``BY_NAME``)."""
    try:
        return BY_NAME[name]
    except KeyError:
        raise ConfigError(f"the {FAMILY} drive has no object named {name!r}") from None


# -- the profile -----------------------------------------------------------------------------


class ODDriveProfile(DriveProfile):
    """Profile of the OD2000 drive: parameters, monitoring and alarms; no motion."""

    family: ClassVar[str] = FAMILY
    word_order: ClassVar[WordOrder] = WordOrder.HIGH_FIRST
    exception_texts: ClassVar[dict[int, str]] = EXCEPTION_TEXTS
    homing_methods: ClassVar[tuple[str, ...]] = ()
    # Enable/disable, moves, speed run, stops and homing stay the base's NotSupported:
    # no enable object (2006h only sets whether a disabled motor holds), no target, speed
    # or ramp, and the inputs can be origin/limit/quick stop (2022h) but homing and
    # stopping are the fieldbus master's.
    unsupported_reason: ClassVar[str] = WHY_NO_MOTION
    default_settings: ClassVar[LineSettings] = DEFAULT_SETTINGS
    parameter_list = OD_PARAMETERS
    comms_note = ("its serial address is fixed at 1 and its line at 9600 8N1; 2000h/2001h "
                  "set the EtherCAT address")

    pulses_per_rev_allowed = range(lookup_name("pulses_per_rev").register.lo,
                                   lookup_name("pulses_per_rev").register.hi + 1)
    addresses = range(SERIAL_ADDRESS, SERIAL_ADDRESS + 1)
    line_kinds = frozenset({"serial", "rtu-over-tcp"})  # its 9-byte frames pass no gateway
    baud_rates = (DEFAULT_SETTINGS.baudrate,)
    line_formats = (DEFAULT_SETTINGS.format,)

    def __init__(self, slave: SlaveHandle, *, pulses_per_rev: int = 10000) -> None:
        if slave.address not in self.addresses:
            raise ConfigError(
                f"the {FAMILY} drive's serial address is fixed at {SERIAL_ADDRESS}, "
                f"not {slave.address}"
            )
        super().__init__(slave, pulses_per_rev=pulses_per_rev)
        self._input_functions: list[int] | None = None

    # -- raw frames ------------------------------------------------------------------------

    async def _transact(self, pdu: bytes, *, priority: Priority, idempotent: bool) -> bytes:
        """One raw transaction; a drive-reported CRC error (01) is retried: it executed nothing."""
        attempt = 0
        while True:
            try:
                return await self.slave.transact(
                    pdu, expect=reply_length, priority=priority, idempotent=idempotent
                )
            except ModbusException as exc:
                if exc.code != EXC_CRC or attempt >= self.slave.retries:
                    raise
                attempt += 1

    async def read_words(
        self, index: int, sub: int = 0, count: int = 1, *, priority: Priority = Priority.CONFIG
    ) -> list[int]:
        """Raw FC03 of ``count`` words from ``index.sub`` (1..16), unchecked against the map.

        How the drive walks past one object in a multi-register read is not documented
        (L342-350); ``read_objects`` only allows the unambiguous case.
        """
        if not 1 <= count <= MAX_READ:
            raise ConfigError(
                f"the {FAMILY} drive reads 1..{MAX_READ} registers per request, not {count}"
            )
        reply = await self._transact(read_pdu(index, sub, count), priority=priority,
                                     idempotent=True)
        if len(reply) != 2 + 2 * count or reply[0] != FC_READ or reply[1] != 2 * count:
            raise FrameError(
                f"slave {self.slave.address}: read reply {reply.hex(' ')} does not carry "
                f"{count} registers",
                slave=self.slave.address,
            )
        return list(struct.unpack_from(f">{count}H", reply, 2))

    async def write_word(
        self,
        index: int,
        sub: int,
        word: int,
        *,
        priority: Priority = Priority.CONFIG,
        idempotent: bool = True,
    ) -> None:
        """Raw FC06 of one word to ``index.sub``; the reply must echo the request."""
        pdu = write_pdu(index, sub, word)
        reply = await self._transact(pdu, priority=priority, idempotent=idempotent)
        if reply != pdu:
            raise FrameError(
                f"slave {self.slave.address}: write reply {reply.hex(' ')} does not echo "
                f"the request {pdu.hex(' ')}",
                slave=self.slave.address,
            )

    async def write_words(
        self,
        index: int,
        sub: int,
        words: Sequence[int],
        *,
        priority: Priority = Priority.CONFIG,
        idempotent: bool = True,
    ) -> None:
        """Raw FC10 of ``words`` from ``index.sub``; the reply repeats index, sub and count."""
        pdu = write_multiple_pdu(index, sub, words)
        reply = await self._transact(pdu, priority=priority, idempotent=idempotent)
        if reply != pdu[:6]:
            raise FrameError(
                f"slave {self.slave.address}: write-multiple reply {reply.hex(' ')} does not "
                f"match the request",
                slave=self.slave.address,
            )

    # -- typed object access ------------------------------------------------------------------

    @staticmethod
    def _readable(obj: ODObject) -> ODObject:
        if not obj.readable:
            raise ConfigError(f"object {obj.register.name} of the {FAMILY} drive is write-only")
        return obj

    @staticmethod
    def _writable(obj: ODObject) -> ODObject:
        if not obj.writable:
            raise ConfigError(f"object {obj.register.name} of the {FAMILY} drive is read-only")
        return obj

    @staticmethod
    def _run(index: int, count: int) -> list[ODObject]:
        """Sub-0 objects at ``index`` .. ``index+count-1``: a multi-register transfer whose
        meaning does not depend on how the drive walks sub-indexes."""
        run = [BY_KEY.get((index + i, 0)) for i in range(count)]
        if any(o is None for o in run):
            raise ConfigError(
                f"{index:04X}h.0 + {count} does not stay within consecutive sub-0 objects; "
                "read sub-indexed objects one entry per request"
            )
        return [o for o in run if o is not None]

    async def read_object(
        self, index: int, sub: int = 0, *, priority: Priority = Priority.CONFIG
    ) -> int:
        """The value of object ``index.sub`` (signed where the object is INT16)."""
        obj = self._readable(lookup(index, sub))
        words = await self.read_words(index, sub, 1, priority=priority)
        return obj.register.decode(words)

    async def write_object(
        self,
        index: int,
        sub: int,
        value: int,
        *,
        priority: Priority = Priority.CONFIG,
        idempotent: bool = True,
    ) -> None:
        """Write object ``index.sub``; ``LimitViolation`` naming it and its range if outside."""
        obj = self._writable(lookup(index, sub))
        words = obj.register.encode(value)
        await self.write_word(index, sub, words[0], priority=priority, idempotent=idempotent)
        if index == INPUT_FUNCTIONS and self._input_functions is not None:
            self._input_functions[sub - 1] = value

    async def read_objects(
        self, index: int, count: int, *, priority: Priority = Priority.CONFIG
    ) -> list[int]:
        """Values of the sub-0 objects ``index.0`` .. ``index+count-1``.0 in one read."""
        objs = [self._readable(o) for o in self._run(index, count)]
        words = await self.read_words(index, 0, count, priority=priority)
        return [o.register.decode([w]) for o, w in zip(objs, words, strict=True)]

    async def write_objects(
        self,
        index: int,
        values: Sequence[int],
        *,
        priority: Priority = Priority.CONFIG,
        idempotent: bool = True,
    ) -> None:
        """Write the sub-0 objects from ``index.0`` on in one FC10 request, each range-checked."""
        objs = [self._writable(o) for o in self._run(index, len(values))]
        words = [o.register.encode(v)[0] for o, v in zip(objs, values, strict=True)]
        await self.write_words(index, 0, words, priority=priority, idempotent=idempotent)

    async def read_parameter(self, name: str, *, priority: Priority = Priority.CONFIG) -> int:
        """Read an object by its name in ``BY_NAME`` (e.g. ``"speed_limit"``)."""
        obj = lookup_name(name)
        return await self.read_object(obj.index, obj.sub, priority=priority)

    async def write_parameter(
        self, name: str, value: int, *, priority: Priority = Priority.CONFIG
    ) -> None:
        """Write an object by its name in ``BY_NAME``, range-checked."""
        obj = lookup_name(name)
        await self.write_object(obj.index, obj.sub, value, priority=priority)

    async def read_parameter_values(
        self, params: Sequence[Parameter], *, priority: Priority = Priority.CONFIG
    ) -> list[int]:
        """Each parameter by its object (index and sub-index), one read each."""
        values = []
        for p in params:
            obj = lookup_name(p.key)
            values.append(await self.read_object(obj.index, obj.sub, priority=priority))
        return values

    async def write_parameter_value(
        self, param: Parameter, value: int, *, priority: Priority = Priority.CONFIG
    ) -> None:
        """Write the parameter's object, range-checked."""
        await self.write_parameter(param.key, value, priority=priority)

    # -- set-up, status, identity -----------------------------------------------------------

    async def setup(self) -> None:
        """Write the microstep (2005h) if it differs, and learn which inputs are home/limits.

        2005h is only written when it differs, as it may be stored at once ("S").
        """
        ppr = lookup_name("pulses_per_rev")
        if await self.read_object(ppr.index, ppr.sub) != self.pulses_per_rev:
            await self.write_object(ppr.index, ppr.sub, self.pulses_per_rev)
        await self.learn()

    async def learn(self, *, priority: Priority = Priority.CONFIG) -> None:
        """Which inputs are origin and limit switches (2022h.1-5, read only)."""
        await self.read_input_functions(priority=priority)

    async def lost_settings(self, *, priority: Priority = Priority.COMMAND) -> list[str]:
        """The microstep (2005h) setup() writes, read back through the 2000h frames."""
        ppr = lookup_name("pulses_per_rev")
        value = await self.read_object(ppr.index, ppr.sub, priority=priority)
        return [] if value == self.pulses_per_rev else [
            f"{ppr.label} = {value}, not {self.pulses_per_rev}"
        ]

    async def read_input_functions(
        self, *, priority: Priority = Priority.CONFIG
    ) -> list[int]:
        """The function codes of inputs 1..5 (2022h.1-5: 1 origin, 2 +limit, 4 -limit, ...)."""
        # One entry per request: how a multi-read walks sub-indexes is not documented.
        functions = [
            await self.read_object(INPUT_FUNCTIONS, n, priority=priority) for n in range(1, 6)
        ]
        self._input_functions = functions
        return list(functions)

    async def read_status(self, *, priority: Priority = Priority.POLL) -> DriveStatus:
        """Monitoring objects as a ``DriveStatus``: two reads (2010h..2018h, then 201Fh).

        The drive has no status word, so several fields are derived (see comments).
        """
        if self._input_functions is None:
            await self.read_input_functions(priority=priority)
        assert self._input_functions is not None
        requested = monotonic()
        block = await self.read_words(STATUS_BLOCK, 0, STATUS_COUNT, priority=priority)
        (reason,) = await self.read_words(0x201F, 0, 1, priority=priority)
        hi, lo, _limit, _test, inputs, _fir, _fir_t, speed, perr = block
        home = neg = pos = False
        for n, function in enumerate(self._input_functions):
            if inputs >> n & 1:
                home |= bool(function & FN_ORIGIN)
                pos |= bool(function & FN_LIMIT_POSITIVE)
                neg |= bool(function & FN_LIMIT_NEGATIVE)
        alarm = reason != 0
        moving = speed != 0  # speed reference 2017h (r/min assumed; unsigned, no direction)
        raw = {f"{STATUS_BLOCK + i:04X}h": w for i, w in enumerate(block)}
        raw["201Fh"] = reason
        raw["home_input"] = int(home)
        raw["position_error"] = perr - 0x10000 if perr & 0x8000 else perr
        return DriveStatus(
            # No enable state over this port: "enabled" means nothing stops the motor
            # (no "motor does not move" code in 201Fh).
            enabled=not alarm,
            moving=moving,
            # No in-position bit (2020h only routes it to an output): derived as at rest
            # with no stop reason.
            in_position=not moving and not alarm,
            homed=False,  # homing is run by the fieldbus master, invisible here
            alarm=alarm,
            alarm_code=reason if alarm else None,
            alarm_text=ALARM_TEXTS.get(reason, f"stop reason {reason}") if alarm else "",
            limit_positive=pos,
            limit_negative=neg,
            # 2010h is the high word, 2011h the low word; read together, so never torn.
            position=join_words([hi, lo], self.word_order, signed=True),
            velocity_rpm=float(speed),
            raw=raw,
            timestamp=monotonic(),
            requested_at=requested,
        )

    standard_frames: ClassVar[bool] = False

    @classmethod
    async def identify(cls, slave: SlaveHandle) -> DriveIdentity | None:
        """Object 201Ah.1 (software version) in the drive's own frames: an answer in
        them, an exception reply included, is this drive (it has no model code)."""
        slave.exception_texts.update(EXCEPTION_TEXTS)
        try:
            reply = await slave.transact(read_pdu(0x201A, 1, 1), expect=reply_length)
        except ModbusException as exc:
            return DriveIdentity(FAMILY, model="", firmware=f"(answered exception {exc.code})")
        except FrameError:
            return None
        if len(reply) != 4 or reply[1] != 2:
            return None
        software = int.from_bytes(reply[2:4], "big")
        return DriveIdentity(FAMILY, firmware=f"software {software}",
                             raw={"software": software})

    async def read_identity(self) -> DriveIdentity:
        """Software, hardware and bus-side software versions (201Ah.1-3); no model code."""
        sw, hw, bus = [await self.read_object(0x201A, n) for n in (1, 2, 3)]
        return DriveIdentity(
            self.family,
            model="",
            firmware=f"software {sw}, bus software {bus}, hardware {hw}",
            raw={"software": sw, "hardware": hw, "bus_software": bus},
        )

    async def read_fault_history(self) -> list[int]:
        """Fault list 201Ch.1 (most recent) .. 201Ch.9, one entry per request."""
        return [await self.read_object(0x201C, n) for n in range(1, 10)]

    # -- procedures the port has --------------------------------------------------------------

    async def _command(self, index: int, value: int) -> None:
        await self.write_object(index, 0, value, priority=Priority.COMMAND, idempotent=False)

    async def clear_alarm(self) -> None:
        """Clear the current alarm (201Eh = 1); the fault list keeps it."""
        await self._command(0x201E, 1)

    async def clear_fault_history(self) -> None:
        """Clear the fault list 201Ch (201Dh = 1)."""
        await self._command(0x201D, 1)

    async def zero_position(self) -> None:
        """Clear the accumulated command-position counter 2010h/2011h (2011h = 1)."""
        await self._command(0x2011, 1)

    async def save_parameters(self) -> None:
        """Store the parameters in non-volatile memory (2030h bit0)."""
        await self._command(0x2030, SAVE_BIT)

    async def restore_factory_settings(self) -> None:
        """Restore the factory parameters (2030h bit1)."""
        await self._command(0x2030, RESTORE_BIT)
