"""Commissioning a drive: give it its address and line settings, check it answers there.

What ``drivebus commission`` does, as a coroutine: find the drive at its present address
and settings (its family identifies it), refuse if another slave already answers where it
is to go, write the drive's own address/baud/format registers (the profile says which:
``DriveProfile.comms_writes``; a drive set by DIP switches is ``NotSupported`` saying so),
store them the drive's way (one save, or write-through for a drive without a save
command), then wait for the drive to answer at the new address and settings: the drives
take them at power-up, so the technician power-cycles it meanwhile.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import anyio
import anyio.to_thread

from drivebus import text
from drivebus.app.scan import Found, is_pty, probe, pty_usable
from drivebus.app.targets import parse_target
from drivebus.bus import Bus
from drivebus.drives.base import DriveProfile, describe_values
from drivebus.drives.registry import all_families, family
from drivebus.errors import (
    ArgumentError,
    ConfigError,
    DriveOffline,
    LineConfigError,
    NotSupported,
    StateError,
)
from drivebus.motion.lines import make_line
from drivebus.settings import LineSettings

__all__ = ["AxisProbe", "CommissionReport", "commission", "occupancy_settings", "probe_axes"]


@dataclass
class CommissionReport:
    """What a commissioning did: the drive, the writes, and where it answers now."""

    family: str
    target: str
    address: int
    settings: LineSettings | None
    to_address: int
    to_settings: LineSettings | None
    identity: str = ""
    writes: list[tuple[str, int]] = field(default_factory=list)
    saved: bool = False
    answers_at_new: bool | None = None
    """None: not verified (``wait`` 0)."""
    seconds_to_answer: float | None = None

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready data."""
        return {
            "family": self.family, "target": self.target, "identity": self.identity,
            "from": {"address": self.address, "settings": _s(self.settings)},
            "to": {"address": self.to_address, "settings": _s(self.to_settings)},
            "writes": [{"register": n, "value": v} for n, v in self.writes],
            "saved": self.saved, "answers_at_new": self.answers_at_new,
            "seconds_to_answer": self.seconds_to_answer,
        }


def _s(settings: LineSettings | None) -> str | None:
    return None if settings is None else str(settings)


async def commission(
    target: str,
    drive: str,
    address: int,
    settings: LineSettings | None,
    *,
    to_address: int | None = None,
    to_settings: LineSettings | None = None,
    timeout: float = 0.2,
    wait: float = 60.0,
    say: Callable[[str], None] = lambda _: None,
    power_hint: str = "",
) -> CommissionReport:
    """Give the ``drive`` at ``address`` (talking ``settings``) on ``target`` the address
    ``to_address`` and settings ``to_settings`` (None: keep), then wait up to ``wait`` s for
    it to answer there (``say`` tells the technician to power-cycle it, and how:
    ``power_hint``). Raises before any write if the drive is not found, cannot take the
    change (``NotSupported``) or another slave answers at the new address at any setting
    a drive on the line could use (``StateError``)."""
    fam = await anyio.to_thread.run_sync(family, drive)  # parsing it: off the loop
    t = parse_target(target)
    if t.kind == "tcp":
        raise ArgumentError(f"{target}: drivebus commission is for serial lines (RS-485)")
    if to_address is None and to_settings is None:
        raise ArgumentError("nothing to change: give --to-address and/or --to-settings")
    settings = settings or LineSettings()
    new_address = address if to_address is None else to_address
    new_settings = settings if to_settings is None else to_settings
    if (new_address, new_settings) == (address, settings):
        raise ArgumentError(f"nothing to change: the drive is to answer at address {address} "
                            f"at {settings}, where it answers now (nothing was sent)")
    if new_address not in fam.profile.addresses:
        raise ArgumentError(f"--to-address: the {fam.name} drive has addresses "
                            f"{describe_values(fam.profile.addresses)}, "
                            f"not {new_address}")
    if to_settings is not None and (problem := fam.profile.settings_problem(to_settings)):
        raise ArgumentError(f"--to-settings: {problem}")
    if fam.profile.comms_writes is DriveProfile.comms_writes:  # nothing to write: say how
        raise NotSupported(f"the {fam.name} drive cannot change its address or line settings "
                           f"over Modbus: {fam.profile.comms_note}")
    report = CommissionReport(fam.name, target, address, settings, new_address, new_settings)
    line = make_line(t.line_config(settings, timeout=timeout))
    async with Bus(line, timeout=timeout, retries=1) as bus:
        slave = bus.slave(address, settings=settings)
        profile: DriveProfile = fam.profile(slave)
        writes = profile.comms_writes(to_address, to_settings, settings)  # NotSupported first
        ident = await fam.profile.identify(slave)
        if ident is None:
            raise DriveOffline(f"no {fam.name} drive answers at address {address} at "
                               f"{settings} on {target} (`drivebus scan {target}` lists the "
                               f"slaves that answer)")
        report.identity = ident.model or fam.name
        if (new_address, new_settings) != (address, settings):
            pty = t.kind == "serial" and is_pty(target)
            tried = [s for s in occupancy_settings(settings, new_settings, pty=pty,
                                                   fixed=t.kind == "rtu-over-tcp")
                     if not (new_address == address and s == settings)]
            await _refuse_occupied(bus, new_address, tried, t.kind, target,
                                   min(timeout, OCCUPANCY_TIMEOUT), say)
        await _write(profile, writes)
        report.writes = [(f"{r.name} ({r.address})", v) for r, v in writes]
        report.saved = True
        if wait <= 0:
            return report
        say(f"written and saved; power-cycle the {fam.name} now; waiting for it at address "
            f"{new_address} at {new_settings} on {target} (up to {wait:g} s; it takes them "
            f"at power-up){power_hint}")
        started = time.monotonic()
        with anyio.move_on_after(wait):
            while True:
                found = await probe(bus, new_address, new_settings, line_kind=t.kind)
                if found is not None and found.family == fam.name:
                    report.answers_at_new = True
                    report.seconds_to_answer = round(time.monotonic() - started, 2)
                    return report
                await anyio.sleep(0.2)
        report.answers_at_new = False
        old = await probe(bus, address, settings, line_kind=t.kind)
        raise DriveOffline(_not_there(fam.name, report, old, profile.comms_note))


OCCUPANCY_TIMEOUT = 0.05
"""Seconds a slave has to answer the check for an occupied address (a reply of a few bytes
takes under 15 ms at 9600 baud), so that the whole check takes a few seconds."""

COMMON_RATES = (9600, 19200, 38400, 57600, 115200)
"""The baud rates drives on an RS-485 line commonly use, beside each family's own."""

LINE_FORMATS = ("8N1", "8E1", "8O1", "8N2")


def occupancy_settings(now: LineSettings, new: LineSettings, *, pty: bool = False,
                       fixed: bool = False) -> list[LineSettings]:
    """The settings at which another slave could already answer at a drive's new address:
    the new ones and the present ones first, then every rate (the common ones and each
    known family's) with every format, those a pty cannot carry left out (``pty``);
    through a serial device server (``fixed``) only the two, its port runs one setting."""
    first = [new, now]
    if fixed:
        return list(dict.fromkeys(first))
    rates = sorted({*COMMON_RATES, *(b for f in all_families() for b in f.profile.baud_rates)})
    rest = [LineSettings.parse(f, baudrate=b) for b in rates for f in LINE_FORMATS]
    if pty:
        rest = pty_usable(rest)[0]
    return list(dict.fromkeys([*first, *rest]))


async def _refuse_occupied(bus: Bus, address: int, tried: list[LineSettings], kind: str,
                           target: str, timeout: float, say: Callable[[str], None]) -> None:
    """``StateError`` (before anything is written) if a slave answers at ``address`` at
    any of ``tried``; a setting the port cannot run is said and skipped."""
    say(f"checking that no other slave answers at address {address} at {len(tried)} line "
        f"settings (every rate and format a drive on the line could use)")
    skipped = []
    for s in tried:
        try:
            other = await probe(bus, address, s, line_kind=kind, timeout=timeout, retries=0)
        except LineConfigError:
            skipped.append(str(s))
            continue
        if other is not None:
            detail = f", {other.detail}" if other.detail else ""
            raise StateError(
                f"another slave already answers at address {address} at {s} on {target} "
                f"({text.a(other.family)}{detail}): give the drive a free address (nothing "
                f"was written)")
    if skipped:
        say(f"not checked at {', '.join(skipped)}: the port cannot run them")


async def _write(profile: DriveProfile, writes: list[tuple[Any, int]]) -> None:
    """The comms writes, stored the drive's way: write-through on for a drive without a
    save command (set back afterwards), else write then one save."""
    wt = profile.write_through
    if profile.saves_by_write_through and wt is not None:
        was = await profile.read(wt.register)
        if was != wt.on:
            await profile.write(wt.register, wt.on)
        try:
            for reg, value in writes:
                await profile.write(reg, value)
        finally:
            if was != wt.on:
                with anyio.CancelScope(shield=True):
                    await profile.write(wt.register, was)
        return
    if why := profile.save_problem():
        raise ConfigError(f"the new settings could not be stored: {why}")
    for reg, value in writes:
        await profile.write(reg, value)
    await profile.save_parameters()


def _not_there(name: str, r: CommissionReport, old: Found | None, note: str) -> str:
    where = f"address {r.to_address} at {r.to_settings}"
    if old is not None:
        return (f"the {name} does not answer at {where}: it still answers at address "
                f"{r.address} at {r.settings}, so it did not take the new settings (was it "
                f"power-cycled? {note})")
    return (f"the {name} does not answer at {where}, nor at address {r.address} at "
            f"{r.settings}: check its power and its switches ({note})")


@dataclass
class AxisProbe:
    """What ``check --probe`` found for one axis: whether its drive answers where the
    machine file says, and if not, where a drive of its family answers instead."""

    axis: str
    family: str
    address: int
    settings: str | None
    ok: bool
    identity: str = ""
    problem: str = ""

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready data."""
        return {"axis": self.axis, "family": self.family, "address": self.address,
                "settings": self.settings, "ok": self.ok, "identity": self.identity,
                "problem": self.problem}


async def probe_axes(config: Any, *, timeout: float = 0.1) -> list[AxisProbe]:
    """Read each configured drive's identity where the machine file puts it (reads only);
    for a drive that is not there, look for one of its family at the other addresses at
    the configured settings and at its other settings at the configured address."""
    from contextlib import AsyncExitStack

    from drivebus.config import machine_config_in_thread
    from drivebus.motion.lines import open_line

    cfg = await machine_config_in_thread(config)  # parsing descriptions: off the loop
    out: list[AxisProbe] = []
    async with AsyncExitStack() as stack:
        for name, line_cfg in cfg.lines.items():
            axes = {n: a for n, a in cfg.axes.items() if a.line == name}
            if not axes:
                continue
            line, _ = await open_line(cfg, name, stack)
            bus = await stack.enter_async_context(Bus(line, timeout=timeout, retries=1))
            for n, ax in axes.items():
                out.append(await _probe_axis(bus, n, ax, line_cfg.kind, line_cfg.port or ""))
    return out


async def _probe_axis(bus: Bus, name: str, ax: Any, kind: str, port: str) -> AxisProbe:
    fam = family(ax.drive)
    settings = ax.settings or (bus.line.settings if kind != "tcp" else None)
    rec = AxisProbe(name, fam.name, ax.address, None if settings is None else str(settings),
                    False)
    here = f"address {ax.address}" + (f" at {settings}" if settings else "")
    try:
        hit = await probe(bus, ax.address, settings, line_kind=kind)
    except LineConfigError as exc:
        rec.problem = f"not probed at {here}: {exc}"
        return rec
    if hit is not None and hit.family == fam.name:
        rec.ok, rec.identity = True, hit.detail or hit.family
        return rec
    if hit is not None:
        rec.problem = f"{text.a(hit.family)} answers at {here}, not {text.a(fam.name)}"
        return rec
    rates, formats, addresses = _elsewhere(fam.profile, ax.address, settings, kind,
                                           pty=kind == "serial" and is_pty(port))
    others = [(ax.address, LineSettings.parse(f, baudrate=b)) for b in rates for f in formats]
    others += [(a, settings) for a in addresses]
    skipped: list[str] = []
    for a, s in others:
        if (a, s) == (ax.address, settings):
            continue
        try:
            found = await probe(bus, a, s, line_kind=kind)
        except LineConfigError:  # this port cannot run it: try the rest
            skipped.append(str(s))
            continue
        if found is not None and found.family == fam.name:
            where = f"address {a}" + (f" at {s}" if s else "")
            rec.problem = (f"no drive answers at {here}; {text.a(fam.name)} answers at {where}: "
                           f"fix the machine file's address/settings (or the drive's)")
            return rec
    tried = []
    if rates:
        tried.append(f"address {ax.address} at {', '.join(map(str, rates))} baud with "
                     f"{', '.join(formats)}")
    if addresses:
        at = f" at {settings}" if settings else ""
        tried.append(f"addresses {text.ranges(addresses)}{at}")
    cannot = f" ({', '.join(dict.fromkeys(skipped))}: the port cannot run them)" if skipped \
        else ""
    rec.problem = (f"no {fam.name} answers at {here}; tried {' and '.join(tried) or 'nothing else'}"
                   f"{cannot}: check power, wiring and termination")
    return rec


def _elsewhere(profile: type[DriveProfile], address: int, settings: LineSettings | None,
               kind: str, *, pty: bool) -> tuple[list[int], list[str], list[int]]:
    """Where else a drive of ``profile`` missing at ``address``/``settings`` may answer:
    the rates and formats it runs (at its address; a pty's formats only: 8N1, 8N2) and
    up to 31 other addresses (at its settings)."""
    rates: list[int] = []
    formats: list[str] = []
    if kind != "tcp" and settings is not None:
        rates = list(profile.baud_rates or (settings.baudrate,))
        formats = list(profile.line_formats or (settings.format,))
        if pty:
            formats = [f for f in formats if f in ("8N1", "8N2")] or formats[:0]
    addresses = [a for a in profile.addresses if a != address][:31]
    return rates, formats, addresses
