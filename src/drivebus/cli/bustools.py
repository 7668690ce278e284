"""The bus tools of the ``drivebus`` command line: ``scan``, ``read`` and ``write``.

Each renders what ``drivebus.app.scan`` and ``drivebus.app.registers`` do, on a line this
process opens or through a running ``drivebus serve`` (``remote_read``/``remote_write``).
They need no machine file, so nothing here loads a drive description, the motion layer
or the simulator: a register read starts as fast as the serial stack it uses.
"""

from __future__ import annotations

import contextlib
import functools
import sys
import time
from collections.abc import Awaitable, Callable, Iterator, Sequence
from typing import TYPE_CHECKING

import anyio
import anyio.to_thread

from drivebus import text
from drivebus.app import registers
from drivebus.app.registers import RegisterValues, open_slave
from drivebus.app.targets import parse_target
from drivebus.cli.terminal import Out
from drivebus.errors import ResponseTimeout
from drivebus.settings import LineSettings

if TYPE_CHECKING:
    from rich.console import Console

    from drivebus.app.scan import Found
    from drivebus.service.client import ServiceClient

__all__ = [
    "found_line",
    "read_registers",
    "remote_read",
    "remote_write",
    "scan_line",
    "write_registers",
]


# -- scan ----------------------------------------------------------------------------------------


def found_line(f: Found) -> str:
    """One slave found by a scan, as a line."""
    detail = f" ({f.detail})" if f.detail else ""
    where = f"unit {f.address}" if f.settings is None else f"address {f.address} at {f.settings}"
    return f"{where}: {f.family}{detail}"


async def scan_line(
    out: Out, port: str, settings: list[LineSettings], addresses: list[int], timeout: float,
    *, quiet: bool = False,
) -> list[Found]:
    """Scan ``port`` (any target) showing its progress: a rich progress bar where a terminal
    shows it (stdout's, else stderr's), else a line on stderr as each setting is begun; a
    slave found is a line on stdout (``quiet``, as with ``--json``: no lines but the bar)."""
    from drivebus.app.scan import scan

    console = out.console if out.interactive else _stderr_console()
    if console is None:
        return await scan(port, settings, addresses, timeout=timeout,
                          on_probe=_plain_progress(settings, addresses, quiet))
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                  console=console, redirect_stdout=out.interactive) as prog:
        rounds = len(settings) if settings else 1
        task = prog.add_task("scanning", total=rounds * len(addresses))

        def show(a: int, s: LineSettings | None, hit: Found | None) -> None:
            extra = 0
            if hit is not None:
                if s is not None:
                    extra = len(settings) - settings.index(s) - 1  # not probed again
                if out.interactive:
                    prog.console.print(f"found {found_line(hit)}", markup=False)
                elif not quiet:
                    print(f"found {found_line(hit)}", flush=True)
            where = "unit" if s is None else f"{s} address"
            prog.update(task, advance=1 + extra, description=f"scanning {where} {a:>3}")

        return await scan(port, settings, addresses, timeout=timeout, on_probe=show)


def _stderr_console() -> Console | None:
    """A rich console on stderr when stderr is a terminal (stdout is not: a pipe, a file)."""
    if not sys.stderr.isatty():
        return None
    from rich.console import Console

    return Console(stderr=True, highlight=False)


def _plain_progress(settings: list[LineSettings], addresses: list[int], quiet: bool
                    ) -> Callable[[int, LineSettings | None, Found | None], None]:
    """A scan's progress as lines for a pipe: one on stderr as each setting is begun (none
    with ``quiet``), a slave found on stdout."""
    begun: set[str] = set()
    found = 0
    n = len(settings)
    where = text.ranges(addresses)

    def report(a: int, s: LineSettings | None, hit: Found | None) -> None:
        nonlocal found
        if quiet:
            return
        if s is not None and str(s) not in begun:
            begun.add(str(s))
            print(f"scanning {s} ({len(begun)} of {n} settings): addresses {where}, {found} "
                  f"found so far", file=sys.stderr, flush=True)
        if hit is not None:
            found += 1
            print(f"found {found_line(hit)}", flush=True)

    return report


# -- register tools ------------------------------------------------------------------------------


async def read_registers(
    out: Out, target: str, address: int, register: int, count: int, input_table: bool,
    settings: object, fmt: str, interval: float | None, polls: int | None, timeout: float,
) -> int:
    """Read registers once, or every ``interval`` s (``polls`` times, else until Ctrl-C)."""
    assert settings is None or isinstance(settings, LineSettings)
    async with open_slave(target, address, settings=settings, timeout=timeout) as slave:

        async def read() -> RegisterValues:
            with _naming_settings(target, settings):
                words, values = await registers.read_registers(
                    slave, register, count, input=input_table, fmt=fmt)
            return RegisterValues(target, address, register, input_table, words, fmt, values)

        return await _poll_registers(out, read, interval, polls)


@contextlib.contextmanager
def _naming_settings(target: str, settings: LineSettings | None) -> Iterator[None]:
    """A slave that does not reply is named with the line settings it was asked at, and
    when they were the default, with the option that gives the slave's own."""
    try:
        yield
    except ResponseTimeout as exc:
        if parse_target(target).kind == "tcp":
            raise
        used = settings or LineSettings()
        how = "" if settings is not None else (
            " (the default: give the slave's own with --settings, e.g. -S \"115200 8N1\", "
            "or -b/-P/-s as mbpoll takes them)")
        raise ResponseTimeout(f"{exc} at {used}{how}", slave=exc.slave) from None


async def _poll_registers(
    out: Out, read: Callable[[], Awaitable[RegisterValues]], interval: float | None,
    polls: int | None,
) -> int:
    """Print what ``read`` returns once, or every ``interval`` s (``polls`` times, else
    until Ctrl-C); exit status 0."""
    n = 0
    while True:
        record = await read()
        if out.as_json:
            out.result(record.as_dict(), indent=None if interval else 2)
        else:
            step = registers.words_per_value(record.format)
            stamp = f"{time.strftime('%H:%M:%S')} " if interval else ""
            for i, v in enumerate(record.values):
                out.line(f"{stamp}[{record.register + i * step}]: {v}")
        n += 1
        if interval is None or (polls is not None and n >= polls):
            return 0
        await anyio.sleep(interval)


async def write_registers(
    out: Out, target: str, address: int, register: int, values: Sequence[str],
    settings: object, fmt: str, timeout: float,
) -> int:
    """Write registers and say what went to the slave."""
    assert settings is None or isinstance(settings, LineSettings)
    async with open_slave(target, address, settings=settings, timeout=timeout,
                          broadcast=True) as slave:
        with _naming_settings(target, settings):
            words = await registers.write_registers(slave, register, values, fmt=fmt)
    whom = "every slave (broadcast, no reply)" if address == 0 else f"slave {address}"
    out.line(f"wrote {len(words)} register{'' if len(words) == 1 else 's'} from "
             f"[{register}] of {whom} on {target}: "
             f"{' '.join(f'0x{w:04X}' for w in words)}")
    out.result({"target": target, "address": address, "register": register,
                "format": fmt, "words": words})
    return 0


# -- through a running drivebus serve -------------------------------------------------------------


async def remote_read(
    out: Out, client: ServiceClient, line: str, address: int, register: int, count: int,
    input_table: bool, fmt: str, interval: float | None, polls: int | None,
) -> int:
    """``read`` through the service's bus (line ``line``), once or every ``interval`` s."""
    words_needed = count * registers.words_per_value(fmt)

    async def read() -> RegisterValues:
        words = await anyio.to_thread.run_sync(functools.partial(
            client.read, line, address, register, words_needed, input=input_table))
        return RegisterValues(f"{client.url} line {line}", address, register, input_table,
                              words, fmt, registers.decode(words, fmt))

    return await _poll_registers(out, read, interval, polls)


async def remote_write(out: Out, client: ServiceClient, line: str, address: int,
                       register: int, words: list[int]) -> int:
    """``write`` through the service's bus (line ``line``)."""
    await anyio.to_thread.run_sync(client.write, line, address, register, words)
    out.line(f"wrote {len(words)} register{'' if len(words) == 1 else 's'} from "
             f"[{register}] of slave {address} on line {line} of {client.url}: "
             f"{' '.join(f'0x{w:04X}' for w in words)}")
    out.result({"target": f"{client.url} line {line}", "address": address,
                "register": register, "words": words})
    return 0
