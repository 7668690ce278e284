"""The ``drivebus`` command line: commission and service drives from a terminal.

``scan`` finds the slaves on a line, ``status``/``move``/``home``/``jog``/``stop`` work on
the axes of a machine file, ``monitor`` watches them, ``sim`` serves a machine's simulated
drives to outside masters, ``check`` validates a machine file. Errors are one line on
stderr (``--debug`` anywhere on the command line shows the traceback); Ctrl-C during a
motion stops the axis before the command exits.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer
import typer.main

from drivebus import checks
from drivebus.cli.args import LocalOpt, ServerOpt, TokenOpt
from drivebus.cli.commissioning import commission as commission_command
from drivebus.cli.commissioning import params_app
from drivebus.cli.failures import fail, json_error, usage
from drivebus.cli.options import ConfigArg, JsonOpt
from drivebus.cli.options import owner as _owner
from drivebus.cli.positions import positions, teach
from drivebus.cli.record import record
from drivebus.errors import ArgumentError, ConfigError

try:  # typer vendors click from 0.2x on; before, it used click itself
    from typer._click.exceptions import UsageError
except ImportError:  # pragma: no cover
    from click.exceptions import UsageError  # type: ignore[no-redef]

app = typer.Typer(
    name="drivebus",
    help="Modbus stepper and servo drives on shared RS-485 lines and Modbus TCP. "
    "Global options (--trace, -v, --log-level, --debug) go before or after the command. "
    "Exit status: 0 done, 1 a runtime failure (a port, a drive, a motion), 2 a usage, "
    "argument or configuration error, 130 interrupted (143 by SIGTERM).",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)

from drivebus.cli.drive import drive_app  # noqa: E402  (drivebus drive check/doc/try)

app.add_typer(drive_app)

_LEVELS = ("debug", "info", "warning", "error")


def _version(value: bool) -> None:
    if value:
        from drivebus import __version__

        typer.echo(f"drivebus {__version__}")
        raise typer.Exit(0)


@app.callback()
def _options(
    verbose: Annotated[int, typer.Option(
        "--verbose", "-v", count=True,
        help="log more: -v warnings and progress (info), -vv everything (debug)")] = 0,
    log_level: Annotated[str | None, typer.Option(
        "--log-level", metavar="LEVEL", help=f"log level: {', '.join(_LEVELS)}")] = None,
    trace: Annotated[bool, typer.Option(
        "--trace", help="log every frame on the wire (time, direction, address, settings, "
        "bytes, the silence before it)")] = False,
    debug: Annotated[bool, typer.Option(
        "--debug", help="show the traceback of an error (anywhere on the command line)")]
    = False,
    version: Annotated[bool, typer.Option(
        "--version", callback=_version, is_eager=True, help="print the version and exit")]
    = False,
) -> None:
    """Modbus stepper and servo drives on shared RS-485 lines and Modbus TCP."""
    level = "error" if not verbose else "info" if verbose == 1 else "debug"
    if log_level is not None:
        if log_level.lower() not in _LEVELS:
            raise ArgumentError(f"--log-level: {log_level!r} is not one of {', '.join(_LEVELS)}")
        level = log_level.lower()
    from drivebus.cli.terminal import configure_logging

    configure_logging(level, trace=trace)


_SIGNED = {"ignore_unknown_options": True}
"""Let negative numbers through as arguments (``drivebus jog m.toml x -20``)."""

AxesArg = Annotated[
    list[str] | None, typer.Argument(help="axes (default: all)", metavar="[AXIS]...")
]
AxisArg = Annotated[str, typer.Argument(help="axis name", metavar="AXIS")]
TargetArg = Annotated[str, typer.Argument(
    metavar="TARGET",
    help="serial device or pty, sim://NAME, tcp://HOST[:PORT] or rtu+tcp://HOST:PORT")]
SettingsOpt = Annotated[str | None, typer.Option(
    "--settings", "-S", metavar="SETTINGS",
    help='serial settings, e.g. "19200 8E1" (default: 19200 8E1, Modbus\'s own)')]
BaudOpt = Annotated[int | None, typer.Option(
    "--baud", "-b", metavar="RATE", help="baud rate (as mbpoll -b; instead of --settings)")]
ParityOpt = Annotated[str | None, typer.Option(
    "--parity", "-P", metavar="PARITY", help="none, even or odd (as mbpoll -P; default even)")]
StopOpt = Annotated[int | None, typer.Option(
    "--stopbits", "-s", metavar="1|2", help="stop bits (as mbpoll -s; default 1)")]
FormatOpt = Annotated[str, typer.Option(
    "--format", "-f", metavar="FORMAT",
    help="hex, int (signed 16-bit), uint, int32-le, int32-be (low/high word first) or float")]
TimeoutOpt = Annotated[float, typer.Option(
    "--timeout", "-t", metavar="SECONDS", help="response timeout")]


@app.command()
def bench(
    quick: Annotated[bool, typer.Option("--quick", "-q", help="short runs")] = False,
    turnaround: Annotated[float, typer.Option(
        metavar="SECONDS", help="simulated slave turnaround")] = 0.001,
    json_path: Annotated[Path | None, typer.Option(
        "--json", metavar="FILE", help="also write the results as JSON to FILE")] = None,
    plots: Annotated[Path | None, typer.Option(
        metavar="DIR", help="write the motion scenario's plots here (an HTML report of "
        "its group moves, and a PNG with matplotlib)")] = Path("bench-plots"),
    no_plots: Annotated[bool, typer.Option("--no-plots", help="draw no plots")] = False,
    only: Annotated[list[str] | None, typer.Option(
        "--only", metavar="SCENARIO", help="run this scenario only, e.g. efficiency or "
        "motion (repeat for more; a wrong name lists them)")] = None,
) -> None:
    """Measure bus efficiency, stop latency, CPU per transaction and scale on simulated lines."""
    import anyio

    from drivebus.bench import format_table, results_json, run_bench, scenarios
    from drivebus.heap import settle

    if not 0 <= checks.finite("--turnaround", turnaround) <= 1:
        raise ArgumentError(f"--turnaround: {turnaround!r} s is outside 0..1 s")
    draw = None if no_plots else plots
    scenarios()  # (imports them all)
    settle()  # a process of drivebus's own, as the service: its start-up heap is frozen
    results = anyio.run(lambda: run_bench(quick=quick, turnaround=turnaround, plots=draw,
                                          only=only))
    typer.echo(format_table(results))
    if json_path is not None:
        json_path.write_text(results_json(results))
        typer.echo(f"\nresults written to {json_path}")
    if draw is not None and (only is None or "motion" in only):
        typer.echo(f"motion plots written to {draw}/")


@app.command()
def demo(
    config: Annotated[Path | None, typer.Argument(
        metavar="[CONFIG]",
        help="a simulated machine file (default: the built-in demo machine)")] = None,
    where: Annotated[bool, typer.Option(
        "--where", help="print where the built-in demo machine file is, and exit")] = False,
    write: Annotated[Path | None, typer.Option(
        "--write", metavar="FILE", help="copy the built-in demo machine file to FILE (a new "
        "file, or into a folder) as a start for your own machine file, and exit")] = None,
) -> None:
    """Run the demo job on the simulator: home, group moves, a jog, a stop."""
    from drivebus.cli.demo import DEFAULT_CONFIG, run_demo, write_demo

    if where or write is not None:
        if config is not None:
            raise ArgumentError("--where and --write are about the built-in demo machine: "
                                f"give them without CONFIG ({config})")
        if where:
            typer.echo(DEFAULT_CONFIG)
        if write is not None:
            written = write_demo(write)
            typer.echo(f"wrote {written}: the demo machine (sim:// lines); "
                       f"`drivebus demo {written}` runs it")
        return
    from drivebus.cli.terminal import run_guarded

    # Under the signal guard: SIGINT (once or twice) and SIGTERM stop every axis the demo
    # moves before it exits, on a running drivebus sim's twins too.
    raise typer.Exit(run_guarded(lambda: run_demo(config)))


# -- scan and the register tools -------------------------------------------------------------------


def _announce_port(port: str) -> None:
    """Say where a ``sim://NAME`` of another process (a running ``drivebus sim``) is."""
    if not port.startswith("sim://"):
        return
    from drivebus.sim.serve import published_sim
    from drivebus.sim.wire import lookup_wire

    name = port.removeprefix("sim://").strip("/")
    try:
        lookup_wire(name)
    except KeyError:
        path = published_sim(name)
        if path is None:
            raise ConfigError(
                f"no simulated line {name!r} is running: start it with `drivebus sim CONFIG` "
                f"(or scan the pty path it prints)"
            ) from None
        typer.echo(f"note: {port} is served by another process, on {path}", err=True)


@app.command()
def scan(
    target: TargetArg,
    baud: Annotated[str, typer.Option(
        "--baud", "-b", metavar="RATES", help="baud rates to try, in order")
    ] = "9600,19200,38400,57600,115200",
    fmt: Annotated[str, typer.Option(
        "--format", "-f", metavar="FORMATS", help="character formats to try, in order")
    ] = "8N1,8E1,8O1,8N2",
    address: Annotated[str, typer.Option(
        "--address", "-a", metavar="ADDRS",
        help="addresses (unit ids over TCP), e.g. 1-31 or 1,3,5-7")] = "1-31",
    timeout: Annotated[float, typer.Option(
        "--timeout", "-t", metavar="SECONDS", help="response timeout per probe")] = 0.04,
    one: Annotated[str | None, typer.Option(
        "--settings", "-S", metavar="SETTINGS",
        help='one setting only, e.g. "19200 8E1" (as read and write take it)')] = None,
    as_json: JsonOpt = False,
) -> None:
    """Find the slaves on a line: every address at every baud rate and format.

    All addresses are probed at one setting, then at the next, skipping addresses already
    found; a probe is one read of holding register 0 with no retries. An answering slave
    is identified by each drive family's own probe. Over Modbus TCP (tcp://HOST) the unit
    ids are probed; --baud and --format do not apply.
    """
    from drivebus.app import scan as sc
    from drivebus.app.targets import parse_target
    from drivebus.cli.bustools import scan_line
    from drivebus.cli.terminal import Out, run_guarded
    from drivebus.settings import LineSettings

    t = parse_target(target)
    if one is not None:
        only = LineSettings.parse(one)
        baud, fmt = str(only.baudrate), only.format
    settings = sc.scan_settings(sc.parse_bauds(baud), sc.parse_formats(fmt))
    addresses = sc.parse_addresses(address, tcp=t.kind == "tcp")
    if checks.positive("--timeout", timeout, unit="s") > 5:
        raise ArgumentError(f"--timeout: {timeout!r} s is above 5 s (a probe answers in ms)")
    _announce_port(target)
    if t.kind == "serial" and sc.is_pty(target):  # sim://NAME carries the format itself
        settings, dropped = sc.pty_usable(settings)
        if dropped:
            formats = ", ".join(dict.fromkeys(s.format for s in dropped))
            typer.echo(f"note: {target} is a pty: it cannot carry parity or 7 data bits, "
                       f"so {formats} are not probed (sim://NAME carries them)", err=True)
        if not settings:
            raise ArgumentError(f"--format: a pty cannot carry {formats}: nothing left to "
                                f"probe on {target} (scan the simulator's sim://NAME)")
    out = Out(as_json=as_json)
    found: list[sc.Found] = []

    async def run() -> int:
        found.extend(await scan_line(out, target, settings, addresses, timeout, quiet=as_json))
        return 0

    code = run_guarded(run)
    out.result([f.as_dict() for f in found])
    if code == 0:
        n = len(found)
        out.line(f"{n} slave{'' if n == 1 else 's'} found on {target}")
    if code == 0 and not found:
        typer.echo(
            "error: no slave answered: check power, wiring (A/B, termination, common), and "
            "widen --baud/--format/--address or raise --timeout",
            err=True,
        )
        code = 1
    raise typer.Exit(code)


def _check_register_call(target: str, address: int, register: int, fmt: str, *,
                         broadcast: bool = False) -> None:
    """TARGET, ADDR, REG and --format checked before anything opens (``broadcast``: a
    write may go to address 0, every slave)."""
    from drivebus.app.registers import words_per_value
    from drivebus.app.targets import parse_target

    tcp = parse_target(target).kind == "tcp"
    checks.whole("ADDR", address, 0 if tcp or broadcast else 1, 255 if tcp else 247)
    checks.whole("REG", register, 0, 65535)
    words_per_value(fmt)


def _settings(text: str | None, baud: int | None = None, parity: str | None = None,
              stopbits: int | None = None) -> object:
    """The line settings of ``-S "19200 8E1"``, or of mbpoll's ``-b``/``-P``/``-s``."""
    from drivebus.settings import LineSettings

    split = [n for n, v in (("--baud", baud), ("--parity", parity), ("--stopbits", stopbits))
             if v is not None]
    if text is not None:
        if split:
            raise ArgumentError(f"--settings and {', '.join(split)}: give one or the other")
        return LineSettings.parse(text)
    if not split:
        return None
    # Each given as it is (a 0 or an empty --parity is refused, not taken for the default).
    letter = "E" if parity is None else {"none": "N", "n": "N", "even": "E", "e": "E",
                                         "odd": "O", "o": "O"}.get(parity.lower())
    if letter is None:
        raise ArgumentError(f"--parity: {parity!r} is not none, even or odd")
    if stopbits is not None:
        checks.whole("--stopbits", stopbits, 1, 2)
    try:
        rate = LineSettings(**({} if baud is None else {"baudrate": baud})).baudrate
    except ConfigError as exc:
        raise ArgumentError(f"--baud: {baud} is not a baud rate: "
                            f"{str(exc).rsplit('baudrate: ', 1)[-1]}") from None
    return LineSettings.parse(f"{rate} 8{letter}{1 if stopbits is None else stopbits}")


@app.command(context_settings=_SIGNED)
def read(
    target: TargetArg,
    address: Annotated[int, typer.Argument(metavar="ADDR", help="slave address (unit id)")],
    register: Annotated[int, typer.Argument(
        metavar="REG", help="first register, 0-based as the manuals print it (mbpoll -0 -r)")],
    count: Annotated[int, typer.Argument(metavar="[COUNT]", help="values to read")] = 1,
    input_registers: Annotated[bool, typer.Option(
        "--input", help="input registers (FC04) instead of holding registers (FC03)")] = False,
    settings: SettingsOpt = None,
    baud: BaudOpt = None,
    parity: ParityOpt = None,
    stopbits: StopOpt = None,
    fmt: FormatOpt = "uint",
    interval: Annotated[float | None, typer.Option(
        "--interval", "-i", metavar="SECONDS", help="poll every SECONDS until Ctrl-C")] = None,
    polls: Annotated[int | None, typer.Option(
        "--count", "-n", metavar="N", help="with --interval: stop after N polls")] = None,
    timeout: TimeoutOpt = 0.5,
    as_json: JsonOpt = False,
    server: Annotated[str | None, typer.Option(
        "--server", metavar="URL", envvar="DRIVEBUS_SERVER",
        help="through this drivebus serve: TARGET is then one of its lines")] = None,
    token: TokenOpt = None,
) -> None:
    """Read COUNT registers (or values of --format) of the slave at ADDR on TARGET."""
    from drivebus.app.registers import words_per_value
    from drivebus.cli.bustools import read_registers, remote_read
    from drivebus.cli.terminal import Out, run_guarded

    # The poll's own arguments, checked whoever reads (this process or a service).
    words_per_value(fmt)
    checks.whole("COUNT", count, 1, 125)
    if interval is not None:
        checks.positive("--interval", interval, unit="s")
    if polls is not None and polls < 1:
        raise ArgumentError(f"--count: must be at least 1 poll, not {polls}")
    if server is not None:
        from drivebus.cli.remote import command_line_client

        client = command_line_client(server, token)
        raise typer.Exit(run_guarded(
            lambda: remote_read(Out(as_json=as_json), client, target, address, register,
                                count, input_registers, fmt, interval, polls),
            interrupt_ok=interval is not None,
        ))
    _check_register_call(target, address, register, fmt)
    wanted_settings = _settings(settings, baud, parity, stopbits)
    checks.positive("--timeout", timeout, unit="s")
    out = Out(as_json=as_json)
    raise typer.Exit(run_guarded(
        lambda: read_registers(out, target, address, register, count, input_registers,
                               wanted_settings, fmt, interval, polls, timeout),
        interrupt_ok=interval is not None,
    ))


@app.command(context_settings=_SIGNED)
def write(
    target: TargetArg,
    address: Annotated[int, typer.Argument(metavar="ADDR", help="slave address (unit id)")],
    register: Annotated[int, typer.Argument(
        metavar="REG", help="first register, 0-based as the manuals print it")],
    values: Annotated[list[str], typer.Argument(
        metavar="VALUE...", help="values to write (0x1F, -5, 1.5 with --format float)")],
    settings: SettingsOpt = None,
    baud: BaudOpt = None,
    parity: ParityOpt = None,
    stopbits: StopOpt = None,
    fmt: FormatOpt = "uint",
    timeout: TimeoutOpt = 0.5,
    as_json: JsonOpt = False,
    server: Annotated[str | None, typer.Option(
        "--server", metavar="URL", envvar="DRIVEBUS_SERVER",
        help="through this drivebus serve: TARGET is then one of its lines")] = None,
    token: TokenOpt = None,
) -> None:
    """Write VALUEs from register REG of the slave at ADDR on TARGET (one: FC06, more: FC16;
    never retried, a write may be a command). ADDR 0 broadcasts to every slave (no reply)."""
    from drivebus.app.registers import encode
    from drivebus.cli.bustools import remote_write, write_registers
    from drivebus.cli.terminal import Out, run_guarded

    if server is not None:
        from drivebus.cli.remote import command_line_client

        words = encode(values, fmt)
        client = command_line_client(server, token)
        raise typer.Exit(run_guarded(lambda: remote_write(
            Out(as_json=as_json), client, target, address, register, words)))

    _check_register_call(target, address, register, fmt, broadcast=True)
    encode(values, fmt)  # every value checked before the port opens
    wanted_settings = _settings(settings, baud, parity, stopbits)
    checks.positive("--timeout", timeout, unit="s")
    out = Out(as_json=as_json)
    raise typer.Exit(run_guarded(
        lambda: write_registers(out, target, address, register, values,
                                wanted_settings, fmt, timeout)
    ))


# -- axis operations ----------------------------------------------------------------------------


@app.command()
def status(config: ConfigArg, axes: AxesArg = None, as_json: JsonOpt = False,
           server: ServerOpt = None, token: TokenOpt = None, local: LocalOpt = False) -> None:
    """Show every axis (or the named ones): state, position, velocity, flags, alarm; an axis
    whose drive does not answer is shown Offline with the reason (exit 1 then, and on an
    alarm)."""
    from drivebus.cli.machine import show_status
    from drivebus.cli.remote import remote_status
    from drivebus.cli.terminal import Out, run_guarded

    out = Out(as_json=as_json)
    owner = _owner(config, server, token, local)
    if owner is not None:
        raise typer.Exit(run_guarded(lambda: remote_status(out, owner, axes or [], as_json)))
    raise typer.Exit(run_guarded(lambda: show_status(out, config, axes or [], as_json)))


@app.command(context_settings=_SIGNED)
def move(
    ctx: typer.Context,
    config: ConfigArg,
    axis: Annotated[str, typer.Argument(
        metavar="AXIS|POSITION", help="axis name, or a taught position (no TARGET)")],
    target: Annotated[float | None, typer.Argument(
        metavar="TARGET", help="target position in the axis's units")] = None,
    by: Annotated[bool, typer.Option("--by", help="move by TARGET (relative)")] = False,
    speed: Annotated[float | None, typer.Option(
        "--speed", "-s", metavar="SPEED", help="speed, the axis's units/s")] = None,
    as_json: JsonOpt = False,
    server: ServerOpt = None,
    token: TokenOpt = None,
    local: LocalOpt = False,
) -> None:
    """Move an axis to TARGET (or by it), or the axes of a taught POSITION there together,
    and wait until they are there; Ctrl-C stops them."""
    from drivebus.cli.machine import move_axis, refuse_early
    from drivebus.cli.remote import remote_motion
    from drivebus.cli.terminal import Out, run_guarded

    if target is None:
        from drivebus.cli.positions import move_position
        from drivebus.config import load_config

        if by or axis in load_config(config).axes:  # an axis needs its TARGET
            raise UsageError("Missing argument 'TARGET'.", ctx)  # type: ignore[arg-type]
        raise typer.Exit(move_position(config, axis, speed, as_json, server, token, local))
    checks.finite("TARGET", target)
    if speed is not None:
        checks.positive("--speed", speed, unit="units/s")
    out = Out(as_json=as_json)
    owner = _owner(config, server, token, local)
    if owner is not None:
        body: dict[str, float] = {"by" if by else "target": target}
        if speed is not None:
            body["speed"] = speed
        what = f"move {'by' if by else 'to'} {target:g}"
        raise typer.Exit(run_guarded(lambda: remote_motion(
            out, owner, axis, what, f"/axes/{axis}/move", body)))
    cfg = refuse_early(config, axis, "move_by" if by else "move",
                       target=None if by else target, speed=speed)
    raise typer.Exit(run_guarded(lambda: move_axis(out, cfg, axis, target, by, speed)))


@app.command()
def home(config: ConfigArg, axis: AxisArg, as_json: JsonOpt = False, server: ServerOpt = None,
         token: TokenOpt = None, local: LocalOpt = False) -> None:
    """Run the axis's configured homing procedure; Ctrl-C stops it."""
    from drivebus.cli.machine import home_axis, refuse_early
    from drivebus.cli.remote import remote_motion
    from drivebus.cli.terminal import Out, run_guarded

    out = Out(as_json=as_json)
    owner = _owner(config, server, token, local)
    if owner is not None:
        raise typer.Exit(run_guarded(lambda: remote_motion(
            out, owner, axis, "home", f"/axes/{axis}/home")))
    cfg = refuse_early(config, axis, "home")
    raise typer.Exit(run_guarded(lambda: home_axis(out, cfg, axis)))


@app.command(context_settings=_SIGNED)
def jog(
    config: ConfigArg,
    axis: AxisArg,
    speed: Annotated[float, typer.Argument(
        metavar="SPEED", help="speed in the axis's units/s; the sign is the direction")],
    seconds: Annotated[float | None, typer.Option(
        "--for", metavar="SECONDS", help="stop after SECONDS")] = None,
    as_json: JsonOpt = False,
    server: ServerOpt = None,
    token: TokenOpt = None,
    local: LocalOpt = False,
) -> None:
    """Jog an axis at SPEED until Ctrl-C (or for --for seconds), then stop it."""
    from drivebus.cli.machine import jog_axis, refuse_early
    from drivebus.cli.remote import remote_jog
    from drivebus.cli.terminal import Out, run_guarded

    if checks.finite("SPEED", speed) == 0:
        raise ArgumentError("SPEED: must not be 0 (units/s; its sign is the direction)")
    if seconds is not None:
        checks.positive("--for", seconds, unit="s")
    out = Out(as_json=as_json)
    owner = _owner(config, server, token, local)
    if owner is not None:
        raise typer.Exit(run_guarded(lambda: remote_jog(out, owner, axis, speed, seconds),
                                     interrupt_ok=seconds is None))
    cfg = refuse_early(config, axis, "jog", speed=speed, speed_name="SPEED")
    code = run_guarded(lambda: jog_axis(out, cfg, axis, speed, seconds),
                       interrupt_ok=seconds is None)
    raise typer.Exit(code)


@app.command()
def stop(config: ConfigArg, axes: AxesArg = None, as_json: JsonOpt = False,
         server: ServerOpt = None, token: TokenOpt = None, local: LocalOpt = False) -> None:
    """Stop the axes (all if none are named) with their decelerating stop."""
    from drivebus.cli.machine import stop_axes
    from drivebus.cli.remote import remote_stop
    from drivebus.cli.terminal import Out, run_guarded

    out = Out(as_json=as_json)
    owner = _owner(config, server, token, local)
    if owner is not None:
        raise typer.Exit(run_guarded(lambda: remote_stop(out, owner, axes or [])))
    raise typer.Exit(run_guarded(lambda: stop_axes(out, config, axes or [])))


@app.command()
def monitor(
    config: ConfigArg,
    interval: Annotated[float, typer.Option(
        "--interval", "-i", metavar="SECONDS", help="time between updates")] = 0.5,
    count: Annotated[int | None, typer.Option(
        "--count", "-n", metavar="N", help="stop after N updates")] = None,
    as_json: Annotated[bool, typer.Option(
        "--json", "-j", help="one JSON line per update")] = False,
    server: ServerOpt = None,
    token: TokenOpt = None,
    local: LocalOpt = False,
) -> None:
    """Watch every axis and the per-slave bus counters until Ctrl-C.

    On a terminal this is a live table; otherwise one line per axis and per slave at
    every update, each prefixed with the time (--json: one JSON line per update).
    """
    from drivebus.cli.machine import monitor as run_monitor
    from drivebus.cli.terminal import Out, run_guarded

    checks.positive("--interval", interval, unit="s")
    if count is not None and count < 1:
        raise ArgumentError(f"--count: must be at least 1 update, not {count}")
    out = Out(as_json=as_json)
    owner = _owner(config, server, token, local)
    if owner is not None:
        from drivebus.cli.remote import remote_monitor

        raise typer.Exit(run_guarded(lambda: remote_monitor(out, owner, interval, count),
                                     interrupt_ok=True))
    raise typer.Exit(run_guarded(lambda: run_monitor(out, config, interval, count),
                                 interrupt_ok=True))


@app.command()
def sim(
    config: ConfigArg,
    log: Annotated[bool, typer.Option("--log", help="print every frame on the wire")] = False,
    power_cycle: Annotated[str | None, typer.Option(
        "--power-cycle", metavar="AXIS|ADDR",
        help="switch a drive of the running drivebus sim of CONFIG off and on (it takes "
        "an address or line settings it was given), then exit")] = None,
) -> None:
    """Serve the machine's simulated drives (its sim:// lines) to outside masters.

    Prints one `line NAME KIND WHERE` per simulated line (WHERE is the pty path for a
    serial line, 127.0.0.1:PORT for TCP), then the slaves on it, and serves until Ctrl-C
    or SIGTERM. Run in a terminal, it takes commands typed there: `power-cycle AXIS` (or
    the address a drive answers at) switches a drive off and on, as `drivebus commission`
    asks; `drivebus sim CONFIG --power-cycle AXIS` does it from another terminal.

    Point mbpoll, a PLC or pymodbus at the pty (`mbpoll -m rtu -b 115200 -P
    none -a 1 /dev/pts/N`): a pty carries baud rate and stop bits but not parity or byte
    size, so such a master reaches only the slaves at 8N1 or 8N2. drivebus in another
    process reaches every slave by sim://NAME (a machine file's sim:// line, `drivebus
    status CONFIG`, `read`/`scan sim://NAME`, `SerialLine("sim://NAME")`): the line's
    format channel carries the parity, and the command says it reached this simulator.
    """
    from drivebus.cli.machine import serve_sim
    from drivebus.cli.terminal import Out, run_guarded

    if power_cycle is not None:
        from drivebus.sim.serve import ask_running_sim

        typer.echo(ask_running_sim(config, power_cycle))
        raise typer.Exit(0)
    out = Out()
    raise typer.Exit(run_guarded(lambda: serve_sim(out, config, log), interrupt_ok=True))


@app.command()
def serve(
    config: ConfigArg,
    host: Annotated[str, typer.Option(
        "--host", metavar="ADDRESS",
        help="address to listen on (beyond loopback only with --token-file)")] = "127.0.0.1",
    port: Annotated[int, typer.Option(
        "--port", "-p", metavar="PORT", help="TCP port (0: any free port)")] = 8000,
    token_file: Annotated[Path | None, typer.Option(
        "--token-file", metavar="FILE",
        help="bearer tokens, one 'NAME read|command TOKEN' per line")] = None,
    mqtt: Annotated[str | None, typer.Option(
        "--mqtt", metavar="URL",
        help="also bridge the machine to an MQTT broker, mqtt://HOST[:PORT] (default: the "
        "machine file's [mqtt] url, if any)")] = None,
    node: Annotated[str | None, typer.Option(
        "--node", metavar="NAME", help="node name in the MQTT topics (default: the "
        "machine's name)")] = None,
    no_discovery: Annotated[bool, typer.Option(
        "--no-discovery", help="publish no Home Assistant discovery over MQTT")] = False,
    no_http: Annotated[bool, typer.Option(
        "--no-http", help="no HTTP service: only the MQTT bridge")] = False,
) -> None:
    """Serve the machine over HTTP and WebSocket (a live dashboard at /, API docs at /docs),
    and over MQTT with --mqtt (or an [mqtt] section in the machine file).

    Opens the machine once and serves until Ctrl-C or SIGTERM, then stops every moving
    axis before it exits. An axis whose drive does not answer starts Offline and is set up
    when it answers.
    """
    import functools

    from drivebus.config import load_config
    from drivebus.service import run

    cfg = load_config(config)
    bridge = mqtt is not None or (cfg.mqtt is not None and cfg.mqtt.url is not None)
    if no_http and not bridge:
        raise ArgumentError("--no-http: with no HTTP service there must be an MQTT bridge "
                            "(--mqtt URL, or [mqtt] url in the machine file)")
    extra = []
    also = ""
    if bridge:
        from drivebus.mqtt import BridgeOptions, run_configured_bridge

        discovery = False if no_discovery else None
        opts = BridgeOptions.resolve(cfg, url=mqtt, node=node, discovery=discovery)
        ha = ", Home Assistant discovery" if opts.discovery else ""
        also = (f"MQTT bridge to {opts.broker} as node {opts.node} (topics "
                f"drivebus/{opts.node}/...{ha})")
        extra.append(functools.partial(run_configured_bridge, url=mqtt, node=node,
                                       discovery=discovery))
    elif node is not None or no_discovery:
        raise ArgumentError("--node and --no-discovery go with an MQTT bridge (--mqtt URL)")
    raise typer.Exit(run(config, host=host, port=port, token_file=token_file,
                         http=not no_http, extra=extra, also=also))


app.command()(record)  # drivebus record: in its own module
app.command()(teach)  # drivebus teach, positions: in cli_positions
app.command()(positions)


@app.command()
def check(config: ConfigArg, as_json: JsonOpt = False, probe: Annotated[bool, typer.Option(
        "--probe", help="also read each drive's identity where the file puts it (reads "
        "only) and report a wrong address or settings")] = False) -> None:
    """Validate a machine file exactly as opening it does, and check its serial ports.

    A real serial port must exist and be usable; a USB-serial adapter is reported (its
    driver, latency timer and what it lets the line reach). sim:// lines are reported as
    simulated. With --probe each drive is asked who it is. Exit status 1 if a line or a
    drive cannot work, 2 if the file is invalid.
    """
    from drivebus.cli.machine import check_config
    from drivebus.cli.terminal import Out

    raise typer.Exit(check_config(Out(as_json=as_json), config, probe=probe))


# -- commissioning (drivebus.cli.commissioning) ----------------------------------------

app.add_typer(params_app, name="params")
app.command(name="commission")(commission_command)


def main() -> None:
    """Console-script entry point: one clear line per error, no traceback (unless --debug).

    Exit status: 0 done, 1 a runtime failure (a port, a drive, a motion), 2 a usage or
    configuration error, 130 interrupted, 143 by SIGTERM (after stopping what the command
    started).
    """
    from drivebus.cli.args import hoist_global_options, parse_command_line

    debug = "--debug" in sys.argv
    if debug:  # anywhere on the command line, not only before the command
        sys.argv.remove("--debug")
    args = hoist_global_options(sys.argv[1:])  # --trace, -v, --log-level: anywhere too
    as_json = False
    try:
        command = typer.main.get_command(app)  # built once: it is most of the start-up
        line = parse_command_line(command, args)
        as_json = line.json
        code = command.main(args=args, standalone_mode=False, prog_name="drivebus")
    except UsageError as exc:
        if debug:
            raise
        usage(exc)
    except (KeyboardInterrupt, typer.Abort):
        typer.echo("interrupted", err=True)
        sys.exit(130)
    except (Exception, BaseExceptionGroup) as exc:
        if as_json and not debug:
            json_error(exc)
        fail(exc, debug)
    sys.exit(code if isinstance(code, int) else 0)


__all__ = ["app", "main"]

