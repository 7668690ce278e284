"""The ``drivebus`` command line: commission and service drives from a terminal.

``scan`` finds the slaves on a line, ``status``/``move``/``home``/``jog``/``stop`` work on
the axes of a machine file, ``monitor`` watches them, ``sim`` serves a machine's simulated
drives to outside masters, ``check`` validates a machine file. Errors are one line on
stderr (``--debug`` anywhere on the command line shows the traceback); Ctrl-C during a
motion stops the axis before the command exits.
"""

from __future__ import annotations

import errno
import json
import os
import re
import sys
import termios
from pathlib import Path
from typing import Annotated, NoReturn

import anyio
import typer

from drivebus.errors import (
    ConfigError,
    DrivebusError,
    DriveOffline,
    LineClosed,
    TransactionError,
)

app = typer.Typer(
    name="drivebus",
    help="Modbus stepper and servo drives on shared RS-485 lines and Modbus TCP. "
    "Add --debug to any command to see the traceback of an error.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
)

_SIGNED = {"ignore_unknown_options": True}
"""Let negative numbers through as arguments (``drivebus jog m.toml x -20``)."""

ConfigArg = Annotated[Path, typer.Argument(help="machine file (TOML)", metavar="CONFIG")]
AxesArg = Annotated[list[str] | None, typer.Argument(help="axes (default: all)")]


@app.command()
def bench(
    quick: Annotated[bool, typer.Option("--quick", help="short runs (under a minute)")] = False,
    turnaround: Annotated[float, typer.Option(help="simulated slave turnaround, s")] = 0.001,
    json_path: Annotated[
        Path | None, typer.Option("--json", help="also write the results as JSON here")
    ] = None,
) -> None:
    """Measure bus efficiency, stop latency, CPU per transaction and scale on simulated lines."""
    from drivebus.bench import format_table, results_json, run_bench

    results = anyio.run(lambda: run_bench(quick=quick, turnaround=turnaround))
    typer.echo(format_table(results))
    if json_path is not None:
        json_path.write_text(results_json(results))
        typer.echo(f"\nresults written to {json_path}")


@app.command()
def demo(
    config: Annotated[
        Path | None, typer.Argument(help="machine file (default: the built-in demo machine)")
    ] = None,
) -> None:
    """Run the demo job on the built-in simulator: home, group moves, a jog, a stop."""
    from drivebus.demo import run_demo

    raise typer.Exit(anyio.run(run_demo, config))


# -- scan ------------------------------------------------------------------------------------------


def _resolve_port(port: str) -> str:
    """``sim://NAME`` of this process, else the pty of a running ``drivebus sim``."""
    if not port.startswith("sim://"):
        return port
    from drivebus.ops import published_sim
    from drivebus.sim.wire import lookup_wire

    name = port.removeprefix("sim://").strip("/")
    try:
        lookup_wire(name)
        return port
    except KeyError:
        pass
    path = published_sim(name)
    if path is None:
        raise ConfigError(
            f"no simulated line {name!r} is running: start it with `drivebus sim CONFIG` "
            f"(or scan the pty path it prints)"
        )
    typer.echo(f"note: {port} is served by another process, on {path}", err=True)
    return path


@app.command()
def scan(
    port: Annotated[str, typer.Argument(help="serial device, pty path, or sim://NAME")],
    baud: Annotated[
        str, typer.Option(help="baud rates to try, in order")
    ] = "9600,19200,38400,57600,115200",
    fmt: Annotated[
        str, typer.Option("--format", help="character formats to try, in order")
    ] = "8N1,8E1,8O1,8N2",
    address: Annotated[str, typer.Option(help="addresses, e.g. 1-31 or 1,3,5-7")] = "1-31",
    timeout: Annotated[float, typer.Option(help="response timeout per probe, s")] = 0.04,
    as_json: Annotated[bool, typer.Option("--json", help="print the result as JSON")] = False,
) -> None:
    """Find the slaves on a line: every address at every baud rate and format.

    All addresses are probed at one setting, then at the next, skipping addresses already
    found; a probe is one read of holding register 0 with no retries. An answering slave
    is identified by its drive family's identity registers where it has them.
    """
    from drivebus import scan as sc
    from drivebus.ops import Out, run_guarded, scan_line

    settings = sc.scan_settings(sc.parse_bauds(baud), sc.parse_formats(fmt))
    addresses = sc.parse_addresses(address)
    if not 0 < timeout <= 5:
        raise ConfigError(f"--timeout {timeout}: must be above 0 and at most 5 s")
    target = _resolve_port(port)
    if sc.is_pty(target):
        settings, dropped = sc.pty_usable(settings)
        if dropped:
            formats = ", ".join(dict.fromkeys(s.format for s in dropped))
            typer.echo(f"note: {target} is a pty: it cannot carry parity or 7 data bits, "
                       f"so {formats} are not probed", err=True)
    out = Out()
    found: list[sc.Found] = []

    async def run() -> int:
        found.extend(await scan_line(out, target, settings, addresses, timeout, quiet=as_json))
        return 0

    code = run_guarded(run)
    if as_json:
        typer.echo(json.dumps([f.as_dict() for f in found], indent=2))
    elif code == 0:
        typer.echo(f"{len(found)} slave(s) found on {port}")
    if code == 0 and not found:
        typer.echo(
            "error: no slave answered: check power, wiring (A/B, termination, common), and "
            "widen --baud/--format/--address or raise --timeout",
            err=True,
        )
        code = 1
    raise typer.Exit(code)


# -- axis operations ----------------------------------------------------------------------------


@app.command()
def status(
    config: ConfigArg,
    axes: AxesArg = None,
    as_json: Annotated[bool, typer.Option("--json", help="print the status as JSON")] = False,
) -> None:
    """Show the state, position, velocity, flags and alarm of the axes (exit 1 on alarm)."""
    from drivebus.ops import Out, run_guarded, show_status

    out = Out()
    raise typer.Exit(run_guarded(lambda: show_status(out, config, axes or [], as_json)))


@app.command(context_settings=_SIGNED)
def move(
    config: ConfigArg,
    axis: Annotated[str, typer.Argument(help="axis name")],
    target: Annotated[float, typer.Argument(help="target position in the axis's units")],
    by: Annotated[bool, typer.Option("--by", help="move by TARGET (relative)")] = False,
    speed: Annotated[float | None, typer.Option(help="speed, units/s")] = None,
) -> None:
    """Move an axis to TARGET (or by it) and wait until it is there; Ctrl-C stops it."""
    from drivebus.ops import Out, move_axis, run_guarded

    out = Out()
    raise typer.Exit(run_guarded(lambda: move_axis(out, config, axis, target, by, speed)))


@app.command()
def home(
    config: ConfigArg,
    axis: Annotated[str, typer.Argument(help="axis name")],
) -> None:
    """Run the axis's configured homing procedure; Ctrl-C stops it."""
    from drivebus.ops import Out, home_axis, run_guarded

    out = Out()
    raise typer.Exit(run_guarded(lambda: home_axis(out, config, axis)))


@app.command(context_settings=_SIGNED)
def jog(
    config: ConfigArg,
    axis: Annotated[str, typer.Argument(help="axis name")],
    speed: Annotated[float, typer.Argument(help="speed in units/s; the sign is the direction")],
    seconds: Annotated[
        float | None, typer.Option("--for", help="stop after this many seconds")
    ] = None,
) -> None:
    """Jog an axis at SPEED until Ctrl-C (or for --for seconds), then stop it."""
    from drivebus.ops import Out, jog_axis, run_guarded

    if seconds is not None and seconds <= 0:
        raise ConfigError(f"--for {seconds}: must be above 0 seconds")
    out = Out()
    code = run_guarded(lambda: jog_axis(out, config, axis, speed, seconds),
                       interrupt_ok=seconds is None)
    raise typer.Exit(code)


@app.command()
def stop(config: ConfigArg, axes: AxesArg = None) -> None:
    """Stop the axes (all if none are named) with their decelerating stop."""
    from drivebus.ops import Out, run_guarded, stop_axes

    out = Out()
    raise typer.Exit(run_guarded(lambda: stop_axes(out, config, axes or [])))


@app.command()
def monitor(
    config: ConfigArg,
    interval: Annotated[float, typer.Option(help="seconds between updates")] = 0.5,
    count: Annotated[int | None, typer.Option(help="stop after this many updates")] = None,
) -> None:
    """Watch every axis and the per-slave bus counters until Ctrl-C.

    On a terminal this is a live table; otherwise one line per axis and per slave at
    every update, each prefixed with the time.
    """
    from drivebus.ops import Out, run_guarded
    from drivebus.ops import monitor as run_monitor

    if interval <= 0:
        raise ConfigError(f"--interval {interval}: must be above 0 seconds")
    out = Out()
    raise typer.Exit(run_guarded(lambda: run_monitor(out, config, interval, count),
                                 interrupt_ok=True))


@app.command()
def sim(
    config: ConfigArg,
    log: Annotated[bool, typer.Option("--log", help="print every frame on the wire")] = False,
) -> None:
    """Serve the machine's simulated drives (its sim:// lines) to outside masters.

    Prints one `line NAME KIND WHERE` per simulated line (WHERE is the pty path for a
    serial line, 127.0.0.1:PORT for TCP), then the slaves on it, and serves until Ctrl-C
    or SIGTERM. Point mbpoll, a PLC or pymodbus at the pty (`mbpoll -m rtu -b 115200 -P
    none -a 1 /dev/pts/N`). A pty carries baud rate and stop bits but not parity or byte
    size: an outside master is taken to send 8 data bits without parity, so only slaves
    at 8N1 or 8N2 understand it (drivebus's own sim://NAME ports tell the wire directly).
    `drivebus scan sim://NAME` in another shell finds this process's line.
    """
    from drivebus.ops import Out, run_guarded, serve_sim

    out = Out()
    raise typer.Exit(run_guarded(lambda: serve_sim(out, config, log), interrupt_ok=True))


@app.command()
def serve(
    config: ConfigArg,
    host: Annotated[str, typer.Option(help="address to listen on (beyond loopback only "
                                           "with --token-file)")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="TCP port (0: any free port)")] = 8000,
    token_file: Annotated[Path | None, typer.Option(
        help="bearer tokens, one 'NAME read|command TOKEN' per line")] = None,
) -> None:
    """Serve the machine over HTTP and WebSocket, with a live dashboard at /.

    Opens the machine once and serves until Ctrl-C or SIGTERM, then stops every moving
    axis before it exits. API docs at /docs.
    """
    from drivebus.service import run

    raise typer.Exit(run(config, host=host, port=port, token_file=token_file))


@app.command()
def check(config: ConfigArg) -> None:
    """Validate a machine file and check its serial ports and adapters.

    A real serial port must exist and be usable; a USB-serial adapter's latency timer
    above 1 ms is reported (it caps the transaction rate). sim:// lines are reported as
    simulated. Exit status 1 if a line cannot work, 2 if the file is invalid.
    """
    from drivebus.ops import Out, check_config

    raise typer.Exit(check_config(Out(), config))


# -- errors ----------------------------------------------------------------------------------------

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
    if isinstance(exc, ConfigError):
        return f"error: {exc}", 2
    code = _errno(exc)
    if isinstance(exc, LineClosed | OSError) and code in _PORT_HINTS:
        port = getattr(exc, "filename", None)
        if port is None and (m := re.search(r"serial port '([^']+)'", str(exc))):
            port = m.group(1)
        return f"error: cannot open {port or 'the port'}: {os.strerror(code)}; " \
               f"{_PORT_HINTS[code]}", 1
    if isinstance(exc, DriveOffline | TransactionError):
        return (f"error: {exc}; check power, wiring, address and line settings "
                f"(`drivebus scan PORT` lists the slaves that answer)"), 1
    if isinstance(exc, termios.error):
        return f"error: the serial port refused the line settings: {exc.args[-1]}", 1
    return f"error: {exc}", 1


def _leaves(exc: BaseException) -> list[BaseException]:
    if isinstance(exc, BaseExceptionGroup):
        return [leaf for e in exc.exceptions for leaf in _leaves(e)]
    return [exc]


def _fail(exc: BaseException, debug: bool) -> NoReturn:
    leaves = _leaves(exc)
    known = [e for e in leaves if isinstance(e, DrivebusError | OSError | termios.error)]
    if debug or not known:
        raise exc
    explained = [explain(e) for e in known]
    for text in dict.fromkeys(t for t, _ in explained):
        typer.echo(text, err=True)
    for e in leaves:
        if e not in known:
            typer.echo(f"internal error: {type(e).__name__}: {e} (--debug shows where)",
                       err=True)
    sys.exit(max(c for _, c in explained))


def main() -> None:
    """Console-script entry point: one clear line per error, no traceback."""
    debug = "--debug" in sys.argv
    if debug:
        sys.argv.remove("--debug")
    try:
        app()
    except KeyboardInterrupt:
        typer.echo("interrupted", err=True)
        sys.exit(130)
    except (DrivebusError, OSError, termios.error, BaseExceptionGroup) as exc:
        _fail(exc, debug)


__all__ = ["app", "explain", "main"]

if __name__ == "__main__":
    main()
