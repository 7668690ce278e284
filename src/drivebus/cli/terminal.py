"""The terminal side of the ``drivebus`` commands: output, signals and errors as one line.

Output goes through ``Out``: rich progress and live views on a terminal, plain lines (one
event per line, ``key=value`` fields) when stdout is a pipe or a file. ``run_guarded``
runs a command so that SIGINT/SIGTERM cancel it, its cleanup (stopping axes) included.
``explain`` turns an error into the one line a technician reads. The commands' own
renderings are beside it: ``bustools`` (scan, read, write), ``machine`` (the axes of a
machine file), ``remote`` (through a running ``drivebus serve``). This module imports no
layer below the application's entry points, and rich only when a terminal asks for it.
"""

from __future__ import annotations

import errno
import json
import logging
import os
import re
import signal
import sys
import termios
from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING

from drivebus import errors
from drivebus.errors import ArgumentError, ConfigError, DriveOffline, LineClosed, TransactionError

if TYPE_CHECKING:
    from rich.console import Console

__all__ = [
    "Out",
    "configure_logging",
    "explain",
    "fmt_number",
    "run_guarded",
]


def configure_logging(level: str, *, trace: bool = False) -> None:
    """Log to stderr at ``level`` (``debug``..``error``); ``trace`` also logs every frame
    (the ``drivebus.trace`` logger) whatever the level."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger("drivebus")
    root.handlers[:] = [handler]
    root.setLevel(level.upper())
    root.propagate = False
    logging.getLogger("drivebus.trace").setLevel(logging.DEBUG if trace else logging.WARNING)
    if trace and root.level > logging.DEBUG:
        root.setLevel(logging.DEBUG)
        for name in ("drivebus.motion", "drivebus.app", "drivebus.bus", "drivebus.line",
                     "drivebus.sim", "drivebus.drives"):
            logging.getLogger(name).setLevel(level.upper())


class Out:
    """Where command output goes: a rich console on a terminal, plain lines otherwise."""

    def __init__(self, interactive: bool | None = None, *, as_json: bool = False) -> None:
        self.as_json = as_json
        """Results as JSON on stdout (``--json``): no tables, no progress, no text lines."""
        self.interactive = (sys.stdout.isatty() if interactive is None else interactive) and (
            not as_json)
        self._console: Console | None = None

    @property
    def console(self) -> Console:
        """The rich console (made, and rich imported, on first use)."""
        if self._console is None:
            from rich.console import Console

            self._console = Console(highlight=False)
        return self._console

    def line(self, text: str) -> None:
        """One line of output (none with ``--json``)."""
        if self.as_json:
            return
        if self.interactive:
            self.console.print(text, markup=False)
        else:
            print(text, flush=True)

    results: int = 0
    """Results printed as JSON in this process (a failure then adds no JSON of its own)."""

    def result(self, data: object, *, indent: int | None = 2) -> None:
        """A command's result as JSON (with ``--json``; one line when ``indent`` is None)."""
        if self.as_json:
            print(json.dumps(data, indent=indent), flush=True)
            Out.results += 1

    def warn(self, text: str) -> None:
        """A warning on stderr."""
        print(f"warning: {text}", file=sys.stderr, flush=True)


# -- running under a signal guard ----------------------------------------------------------------


def run_guarded(fn: Callable[[], Awaitable[int]], *, interrupt_ok: bool = False) -> int:
    """Run a command: SIGINT/SIGTERM cancel it (its cleanup, e.g. stopping moving axes,
    runs in full) and give exit status 128+signal, or for Ctrl-C 0 if ``interrupt_ok``
    (commands that run until Ctrl-C: SIGTERM still ends them as 143); an interrupted
    command says so on stderr."""

    from drivebus.app.lifecycle import run_until_signalled

    caught: list[signal.Signals] = []

    def normal_end(sig: signal.Signals) -> bool:
        return interrupt_ok and sig is signal.SIGINT

    def said(sig: signal.Signals) -> None:
        caught.append(sig)
        if not normal_end(sig):
            print(f"interrupted ({sig.name})", file=sys.stderr, flush=True)

    code = run_until_signalled(fn, interrupt_ok=interrupt_ok, on_signal=said)
    if caught and not normal_end(caught[0]):
        code = 128 + caught[0]
    if caught:  # stopped and on its way out: a late Ctrl-C must not change its status
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
    return code


def fmt_number(v: float | None) -> str:
    """A position or velocity as printed (``-``: unknown)."""
    return "-" if v is None else f"{v:.3f}"


# -- errors as one line ----------------------------------------------------------------------------

_MISSING = "the port does not exist: plug in the adapter, check the name (ls /dev/serial/by-id/)"
_DENIED = ("add your user to the port's group (sudo usermod -aG dialout $USER) and log in "
           "again")
_PORT_HINTS = {
    errno.ENOENT: _MISSING,
    errno.ENODEV: _MISSING,
    errno.ENXIO: _MISSING,
    errno.EACCES: _DENIED,
    errno.EPERM: _DENIED,
    errno.EBUSY: "another program has the port open: close it (fuser -v PORT shows which)",
}


def _errno(exc: BaseException) -> int | None:
    seen: BaseException | None = exc
    while seen is not None:
        code = getattr(seen, "errno", None)
        if isinstance(code, int):
            return code
        seen = seen.__cause__ or seen.__context__
    return None


def explain(exc: BaseException) -> tuple[str, int]:
    """The one line to print for ``exc`` (cause; what to do) and the exit status."""
    if isinstance(exc, ConfigError | ArgumentError | errors.NotFound):  # NotFound: named a
        return f"error: {exc}", 2  # thing there is not (an axis, a position, a motion)
    code = _errno(exc)
    if isinstance(exc, LineClosed | OSError) and code in _PORT_HINTS:
        port = getattr(exc, "filename", None)
        if port is None and (m := re.search(r"serial port '([^']+)'", str(exc))):
            port = m.group(1)
        return f"error: cannot open {port or 'the port'}: {os.strerror(code)}; " \
               f"{_PORT_HINTS[code]}", 1
    if isinstance(exc, errors.ModbusException):
        return (f"error: {exc}; the slave answered, refusing the request: check the register "
                f"address, count and value against the drive's manual"), 1
    if isinstance(exc, errors.PartialWrite):
        return f"error: {exc}", 1
    if isinstance(exc, DriveOffline | TransactionError):
        return (f"error: {exc}; check power, wiring, address and line settings "
                f"(`drivebus scan PORT` lists the slaves that answer)"), 1
    if isinstance(exc, termios.error):
        return f"error: the serial port refused the line settings: {exc.args[-1]}", 1
    return f"error: {exc}", 1
