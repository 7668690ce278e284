"""Bus scan: find the slaves on a serial line across baud rates, formats and addresses.

The scan probes every address at one setting, then the next setting, skipping addresses
already found (a slave answers at one setting only). The probe is a read of holding
register 0 (any answer, a Modbus exception included, means a slave is there); then each
drive family's identification probe runs in turn. Drives with non-standard frames (the
OD2000) have a probe of their own, tried only where they can be (their fixed address and
line settings).
"""

from __future__ import annotations

import os
from collections.abc import Awaitable, Callable, Iterable, Sequence
from dataclasses import dataclass

from drivebus.bus import Bus, SlaveHandle
from drivebus.errors import (
    ConfigError,
    FrameError,
    LineConfigError,
    ModbusException,
    TransactionError,
)
from drivebus.line.serial import SerialLine
from drivebus.settings import LineSettings

__all__ = [
    "FAMILY_PROBES",
    "FamilyProbe",
    "Found",
    "parse_addresses",
    "parse_bauds",
    "parse_formats",
    "scan",
    "scan_settings",
]

UNKNOWN = "unknown Modbus slave"


@dataclass(frozen=True)
class Found:
    """A slave that answered: where, at which settings, and what it said it is."""

    address: int
    settings: LineSettings
    family: str
    """A drive family name (``drivebus.drives.registry``) or "unknown Modbus slave"."""
    detail: str = ""

    def as_dict(self) -> dict[str, object]:
        """JSON-able form for ``drivebus scan --json``."""
        return {
            "address": self.address,
            "baudrate": self.settings.baudrate,
            "format": self.settings.format,
            "settings": str(self.settings),
            "family": self.family,
            "detail": self.detail,
        }


Identify = Callable[[SlaveHandle], Awaitable[str | None]]


@dataclass(frozen=True)
class FamilyProbe:
    """How to recognise one drive family: ``identify`` returns a detail text, or None."""

    family: str
    identify: Identify
    standard: bool = True
    """Speaks standard Modbus frames, so it answers the presence probe."""
    applies: Callable[[int, LineSettings], bool] = lambda address, settings: True
    """Where the family can be at all (e.g. a fixed address or line format)."""


async def _words(slave: SlaveHandle, address: int, count: int) -> list[int] | None:
    try:
        return await slave.read_holding_registers(address, count)
    except (ModbusException, FrameError):
        return None


async def _bhss(slave: SlaveHandle) -> str | None:
    w = await _words(slave, 0x0000, 2)  # drive model 0x0305, driver version (BHSS manual)
    if w is None or w[0] != 0x0305:
        return None
    return f"BHSS-100-MBUS, model 0x{w[0]:04X}, version {w[1] >> 8}.{w[1] & 0xFF:02d}"


async def _cl86r(slave: SlaveHandle) -> str | None:
    w = await _words(slave, 0x0000, 2)  # model code 862, software version (CL86R manual)
    if w is None or w[0] != 862:
        return None
    return f"CL86R, model code {w[0]}, software {w[1]}"


_NT_IDS = {86: "NT86", 60: "EPR60"}
"""Drive ID register 93 values. The NT86 manual leaves the format undocumented; these
are the values drivebus's simulated twins report (an assumption for real drives)."""


def _nt(name: str) -> Identify:
    async def probe(slave: SlaveHandle) -> str | None:
        w = await _words(slave, 93, 3)  # drive ID, version, non-standard number
        if w is None or _NT_IDS.get(w[0]) != name:
            return None
        return f"{name}, drive ID {w[0]}, version {w[1]}"

    return probe


async def _od2000(slave: SlaveHandle) -> str | None:
    from drivebus.drives.od_drive import EXCEPTION_TEXTS, read_pdu, reply_length

    slave.exception_texts = dict(EXCEPTION_TEXTS)
    try:  # object 201Ah.1: software version (the drive has no model code)
        reply = await slave.transact(read_pdu(0x201A, 1, 1), expect=reply_length)
    except ModbusException as exc:
        return f"OD2000 object-dictionary drive (answered with exception {exc.code})"
    except FrameError:
        return None
    if len(reply) != 4 or reply[1] != 2:
        return None
    return f"OD2000 object-dictionary drive, software {int.from_bytes(reply[2:4], 'big')}"


def _od_applies(address: int, settings: LineSettings) -> bool:
    from drivebus.drives.od_drive import DEFAULT_SETTINGS, SERIAL_ADDRESS

    return address == SERIAL_ADDRESS and settings == DEFAULT_SETTINGS


FAMILY_PROBES: tuple[FamilyProbe, ...] = (
    FamilyProbe("BHSS", _bhss),
    FamilyProbe("CL86R", _cl86r),
    FamilyProbe("NT86", _nt("NT86")),
    FamilyProbe("EPR60", _nt("EPR60")),
    FamilyProbe("OD2000", _od2000, standard=False, applies=_od_applies),
)
"""Identification probes, tried in this order."""


async def _present(slave: SlaveHandle) -> bool:
    """True if a standard Modbus slave answers (data or an exception) at this address."""
    try:
        await slave.read_holding_registers(0, 1)
    except ModbusException:
        return True
    except LineConfigError:
        raise  # the port cannot run this setting: say so, do not report "nobody"
    except TransactionError:
        return False  # timeout, or a garbled answer (a slave at other settings)
    return True


async def probe(bus: Bus, address: int, settings: LineSettings) -> Found | None:
    """Probe one address at one setting; the slave found there, if any."""
    slave = bus.slave(address, settings=settings)
    usable = [p for p in FAMILY_PROBES if p.applies(address, settings)]
    if await _present(slave):
        for p in usable:
            if p.standard and (detail := await _identify(p, slave)):
                return Found(address, settings, p.family, detail)
        return Found(address, settings, UNKNOWN)
    for p in usable:
        if not p.standard and (detail := await _identify(p, slave)):
            return Found(address, settings, p.family, detail)
    return None


async def _identify(p: FamilyProbe, slave: SlaveHandle) -> str | None:
    try:
        return await p.identify(slave)
    except LineConfigError:
        raise
    except TransactionError:
        return None


def is_pty(port: str) -> bool:
    """True if ``port`` is a pseudo-terminal (a simulator's, or a virtual port)."""
    return os.path.realpath(port).startswith("/dev/pts/")


def pty_usable(settings: Sequence[LineSettings]) -> tuple[list[LineSettings], list[LineSettings]]:
    """Split ``settings`` into those a pty can carry (8 data bits, no parity) and the rest:
    a pty drops parity and byte size, and some kernels refuse parity on it outright."""
    ok = [s for s in settings if s.bytesize == 8 and s.parity == "N"]
    return ok, [s for s in settings if s not in ok]


def scan_settings(bauds: Sequence[int], formats: Sequence[str]) -> list[LineSettings]:
    """Every baud rate with every format, in the order given (baud rates outermost)."""
    return [LineSettings.parse(f, baudrate=b) for b in bauds for f in formats]


async def scan(
    port: str,
    settings: Sequence[LineSettings],
    addresses: Iterable[int],
    *,
    timeout: float = 0.04,
    on_probe: Callable[[int, LineSettings, Found | None], None] | None = None,
) -> list[Found]:
    """Probe ``addresses`` at each of ``settings`` on ``port``; the slaves that answered.

    All addresses at one setting, then the next setting; a found address is not probed
    again. ``on_probe`` is called after every probe (progress displays).
    """
    if not settings:
        raise ConfigError("nothing to scan: no line settings given")
    todo = list(dict.fromkeys(addresses))
    found: list[Found] = []
    line = SerialLine(port, settings[0])
    async with Bus(line, timeout=timeout, retries=0) as bus:
        for s in settings:
            for address in list(todo):
                hit = await probe(bus, address, s)
                if hit is not None:
                    found.append(hit)
                    todo.remove(address)
                if on_probe is not None:
                    on_probe(address, s, hit)
    return sorted(found, key=lambda f: f.address)


def parse_addresses(text: str) -> list[int]:
    """Parse "1-31", "1,3,5-7" into addresses (1..247); ConfigError naming the problem."""
    out: list[int] = []
    for part in text.replace(" ", "").split(","):
        lo, sep, hi = part.partition("-")
        try:
            a, b = int(lo), int(hi) if sep else int(lo)
        except ValueError:
            raise ConfigError(
                f"--address {text!r}: expected addresses like 1-31 or 1,3,5-7"
            ) from None
        if not 1 <= a <= b <= 247:
            raise ConfigError(f"--address {text!r}: addresses run from 1 to 247, low-high")
        out.extend(range(a, b + 1))
    return list(dict.fromkeys(out))


def parse_bauds(text: str) -> list[int]:
    """Parse "9600,19200" into baud rates."""
    try:
        bauds = [int(b) for b in text.replace(" ", "").split(",") if b]
    except ValueError:
        raise ConfigError(f"--baud {text!r}: expected baud rates like 9600,19200") from None
    if not bauds or any(not 300 <= b <= 4_000_000 for b in bauds):
        raise ConfigError(f"--baud {text!r}: baud rates run from 300 to 4000000")
    return bauds


def parse_formats(text: str) -> list[str]:
    """Parse "8N1,8E1" into formats (checked)."""
    formats = [f for f in text.replace(" ", "").upper().split(",") if f]
    if not formats:
        raise ConfigError(f"--format {text!r}: expected formats like 8N1,8E1,8N2")
    for f in formats:
        try:
            LineSettings.parse(f, baudrate=9600)
        except ConfigError:
            raise ConfigError(
                f"--format {text!r}: {f!r} is not a format like 8N1, 8E1, 8O1 or 8N2"
            ) from None
    return formats
