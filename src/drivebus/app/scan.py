"""Bus scan: find the slaves on a serial line across baud rates, formats and addresses.

The scan probes every address at one setting, then the next setting, skipping addresses
already found (a slave answers at one setting only). The probe is a read of holding
register 0 (any answer, a Modbus exception included, means a slave is there); then every
drive family of the registry that could be there (its declared addresses, baud rates and
formats) identifies itself (``DriveProfile.identify``). A family with frames of its own
(the OD2000) is asked directly where it could be. The scan knows no vendor.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import anyio.to_thread

from drivebus.app.targets import parse_target
from drivebus.bus import Bus, SlaveHandle
from drivebus.drives.registry import DriveFamily, all_families
from drivebus.drives.status import DriveIdentity
from drivebus.errors import (
    ConfigError,
    LineConfigError,
    ModbusException,
    TransactionError,
)
from drivebus.motion.lines import make_line
from drivebus.settings import LineSettings

__all__ = [
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
    settings: LineSettings | None
    """None on Modbus TCP."""
    family: str
    """A drive family name (``drivebus.drives.registry``) or "unknown Modbus slave"."""
    detail: str = ""

    def as_dict(self) -> dict[str, object]:
        """JSON-able form for ``drivebus scan --json``."""
        return {
            "address": self.address,
            "baudrate": None if self.settings is None else self.settings.baudrate,
            "format": None if self.settings is None else self.settings.format,
            "settings": None if self.settings is None else str(self.settings),
            "family": self.family,
            "detail": self.detail,
        }


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


def _detail(ident: DriveIdentity) -> str:
    return ", ".join(p for p in (ident.model or ident.family, ident.firmware and
                                 f"firmware {ident.firmware}") if p)


async def probe(
    bus: Bus, address: int, settings: LineSettings | None, *, line_kind: str = "serial",
    timeout: float | None = None, retries: int | None = None,
) -> Found | None:
    """Probe one address at one setting; the slave found there, if any (``timeout`` and
    ``retries``: the probe's own, else the bus's).

    A standard slave is found by a plain read; then each drive family of the registry
    that could be there tries to identify it. A family with frames of its own (the
    OD2000) is asked directly where it could be.
    """
    slave = bus.slave(address, settings=settings, timeout=timeout, retries=retries)
    families = [f for f in all_families()
                if f.profile.could_be_at(address, line_kind, settings)]
    if await _present(slave):
        for fam in families:
            if fam.profile.standard_frames and (ident := await _identify(fam, slave)):
                return Found(address, settings, fam.name, _detail(ident))
        return Found(address, settings, UNKNOWN)
    for fam in families:
        if not fam.profile.standard_frames and (ident := await _identify(fam, slave)):
            return Found(address, settings, fam.name, _detail(ident))
    return None


async def _identify(fam: DriveFamily, slave: SlaveHandle) -> DriveIdentity | None:
    try:
        return await fam.profile.identify(slave)
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
    target: str,
    settings: Sequence[LineSettings],
    addresses: Iterable[int],
    *,
    timeout: float = 0.04,
    on_probe: Callable[[int, LineSettings | None, Found | None], None] | None = None,
) -> list[Found]:
    """Probe ``addresses`` at each of ``settings`` on ``target``; the slaves that answered.

    ``target`` is a serial port, ``sim://NAME``, ``tcp://HOST[:PORT]`` (unit ids, no line
    settings) or ``rtu+tcp://HOST:PORT``. All addresses at one setting, then the next; a
    found address is not probed again. ``on_probe`` is called after every probe.
    """
    t = parse_target(target)
    tried: list[LineSettings | None] = [None] if t.kind == "tcp" else list(settings)
    if not tried:
        raise ConfigError("nothing to scan: no line settings given")
    todo = list(dict.fromkeys(addresses))
    found: list[Found] = []
    # every description parsed before the line opens (not between probes), off the loop
    await anyio.to_thread.run_sync(all_families)
    line = make_line(t.line_config(tried[0], timeout=timeout))
    async with Bus(line, timeout=timeout, retries=0) as bus:
        for s in tried:
            for address in list(todo):
                hit = await probe(bus, address, s, line_kind=t.kind)
                if hit is not None:
                    found.append(hit)
                    todo.remove(address)
                if on_probe is not None:
                    on_probe(address, s, hit)
    return sorted(found, key=lambda f: f.address)


def parse_addresses(text: str, *, tcp: bool = False) -> list[int]:
    """Parse "1-31", "1,3,5-7" into addresses (1..247; unit ids 0..255 with ``tcp``);
    ConfigError naming the problem."""
    lowest, highest = (0, 255) if tcp else (1, 247)
    out: list[int] = []
    for part in text.replace(" ", "").split(","):
        lo, sep, hi = part.partition("-")
        try:
            a, b = int(lo), int(hi) if sep else int(lo)
        except ValueError:
            raise ConfigError(
                f"--address {text!r}: expected addresses like 1-31 or 1,3,5-7"
            ) from None
        if not lowest <= a <= b <= highest:
            raise ConfigError(f"--address {text!r}: addresses run from {lowest} to {highest}, "
                              f"low-high")
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
