"""The commissioning commands of ``drivebus``: ``params dump|diff|load`` and ``commission``.

``params`` backs up, compares and restores a drive's documented parameters
(``drivebus.app.params``); ``commission`` gives a new drive its address and line settings
(``drivebus.app.commission``). ``cli.py`` registers them; the work is in ``drivebus.app``,
this module parses and renders.
"""

from __future__ import annotations

import contextlib
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from drivebus import text
from drivebus.cli.args import LocalOpt, ServerOpt, TokenOpt
from drivebus.cli.options import ConfigArg, JsonOpt, check_output
from drivebus.errors import ArgumentError, ConfigError, LimitViolation, NotSupported

if TYPE_CHECKING:
    from drivebus.app.params import Difference, ParameterSet
    from drivebus.cli.terminal import Out
    from drivebus.service.client import ServiceClient

__all__ = ["commission", "params_app"]

params_app = typer.Typer(
    name="params",
    help="Back up, compare and restore a drive's parameters (a TOML file per drive).",
    no_args_is_help=True,
    rich_markup_mode=None,
)

MachineOpt = Annotated[Path | None, typer.Option(
    "--machine", "-m", metavar="CONFIG",
    help="the machine file (default: the one the parameter file names)")]


def _owner(config: Path, server: str | None, token: str | None, local: bool
           ) -> ServiceClient | None:
    from drivebus.cli.remote import service_owner

    return service_owner(config, server, token, local)


def _run(fn: Any, *, interrupt_ok: bool = False) -> None:
    from drivebus.cli.terminal import run_guarded

    raise typer.Exit(run_guarded(fn, interrupt_ok=interrupt_ok))


# -- params dump ----------------------------------------------------------------------------------


@params_app.command()
def dump(
    config: ConfigArg,
    axis: Annotated[str, typer.Argument(metavar="AXIS", help="axis name")],
    output: Annotated[Path | None, typer.Option(
        "--output", "-o", metavar="FILE", help="write the parameter file here (default: "
        "stdout)")] = None,
    as_json: JsonOpt = False,
    server: ServerOpt = None,
    token: TokenOpt = None,
    local: LocalOpt = False,
) -> None:
    """Read every documented parameter of AXIS's drive (value, unit, register, whether a
    save stores it) into a parameter file. Reads only: nothing is written to the drive."""
    from drivebus.app.params import ParameterSet, about_axis, open_drive, read_parameters
    from drivebus.cli.terminal import Out
    from drivebus.config import load_config

    cfg = load_config(config)
    if axis not in cfg.axes:
        raise ConfigError(f"no axis {axis!r} in machine {cfg.name} (axes: "
                          f"{', '.join(cfg.axes)})")
    if output is not None:
        check_output(output)  # before the drive is read
    out = Out(as_json=as_json)
    owner = _owner(config, server, token, local)
    source = str(config.resolve())

    async def run() -> int:
        started = time.monotonic()
        if owner is not None:
            data = await _call(owner.parameters, axis)
            pset = ParameterSet(data["family"], {k: v["value"] for k, v in
                                                 data["parameters"].items()},
                                about_axis(cfg, axis, source), data.get("description", ""))
        else:
            async with open_drive(cfg, axis) as profile:
                pset = await read_parameters(profile, about=about_axis(cfg, axis, source))
        seconds = time.monotonic() - started
        _write_set(out, pset, output)
        ax = cfg.axes[axis]
        _note(f"read {len(pset.values)} parameters of axis {axis} ({pset.family} at address "
              f"{ax.address} on line {ax.line}) in {seconds:.2f} s"
              + (f" into {output}" if output else ""))
        return 0

    _run(run)


def _write_set(out: Out, pset: ParameterSet, output: Path | None) -> None:
    if output is not None:
        try:
            output.write_text(pset.to_toml())
        except OSError as exc:
            raise ArgumentError(f"--output {output}: cannot write it: "
                                f"{exc.strerror or exc}") from None
        out.result(pset.as_dict())
    elif out.as_json:
        out.result(pset.as_dict())
    else:
        sys.stdout.write(pset.to_toml())
        sys.stdout.flush()


def _note(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


async def _call(fn: Any, *args: Any) -> Any:
    import functools

    import anyio.to_thread

    return await anyio.to_thread.run_sync(functools.partial(fn, *args))


# -- params diff ----------------------------------------------------------------------------------


def _machine_of(pset: ParameterSet, machine: Path | None, where: Path) -> Path:
    if machine is not None:
        return machine
    named = pset.about.get("machine")
    if not isinstance(named, str) or not named:
        raise ArgumentError(f"{where} names no machine file: give --machine CONFIG")
    return Path(named)


def _axis_of(pset: ParameterSet, axis: str | None, where: Path) -> str:
    if axis is not None:
        return axis
    named = pset.about.get("axis")
    if not isinstance(named, str) or not named:
        raise ArgumentError(f"{where} names no axis: give AXIS")
    return named


@contextlib.asynccontextmanager
async def _drive_set(config: Path, axis: str, owner: ServiceClient | None) -> Any:
    """The parameters the drive of ``axis`` holds now (reads only)."""
    from drivebus.app.params import ParameterSet, open_drive, read_parameters

    if owner is not None:
        data = await _call(owner.parameters, axis)
        yield ParameterSet(data["family"],
                           {k: v["value"] for k, v in data["parameters"].items()},
                           description=data.get("description", ""))
        return
    async with open_drive(config, axis) as profile:
        yield await read_parameters(profile)


@params_app.command()
def diff(
    file: Annotated[Path, typer.Argument(metavar="FILE", help="a parameter file")],
    other: Annotated[str | None, typer.Argument(
        metavar="[AXIS|FILE]", help="the axis whose drive to compare with (default: the "
        "file's), or a second parameter file")] = None,
    machine: MachineOpt = None,
    exit_code: Annotated[bool, typer.Option(
        "--exit-code", help="exit 1 when they differ (as git diff --exit-code)")] = False,
    as_json: JsonOpt = False,
    server: ServerOpt = None,
    token: TokenOpt = None,
    local: LocalOpt = False,
) -> None:
    """Show the parameters that differ between FILE and a drive (or a second file).
    Reads only: nothing is written to the drive."""
    from drivebus.app.params import ParameterSet, diff_parameters
    from drivebus.cli.terminal import Out

    a = ParameterSet.load(file)
    out = Out(as_json=as_json)
    if other is not None and (other.endswith(".toml") or Path(other).is_file()):
        b = ParameterSet.load(other)
        changes = diff_parameters(a, b)
        _show_diff(out, changes, str(file), other)
        raise typer.Exit(1 if exit_code and changes else 0)
    axis = _axis_of(a, other, file)
    config = _machine_of(a, machine, file)
    owner = _owner(config, server, token, local)

    async def run() -> int:
        async with _drive_set(config, axis, owner) as b:
            changes = diff_parameters(a, b)
        _show_diff(out, changes, str(file), f"axis {axis}")
        return 1 if exit_code and changes else 0

    _run(run)


def _show_diff(out: Out, changes: list[Difference], a: str, b: str) -> None:
    out.result({"a": a, "b": b, "differences": [c.as_dict() for c in changes]})
    if not changes:
        out.line(f"no parameter differs between {a} and {b}")
        return
    out.line(f"{len(changes)} parameter{'s differ' if len(changes) > 1 else ' differs'} "
             f"between {a} (<) and {b} (>):")
    for c in changes:
        unit = f" {c.unit}" if c.unit else ""
        out.line(f"  {c.key}: < {c.shown(c.a)} > {c.shown(c.b)}{unit}  ({c.name})")
        if c.outside and c.parameter is not None:
            sides = " and ".join({"a": a, "b": b}[side] for side in c.outside)
            out.line(f"    ! outside its range in {sides}: allowed {c.parameter.allowed()} "
                     f"(params load refuses it)")
    outside = [c.key for c in changes if c.outside]
    if outside:
        _note(f"warning: {text.count(len(outside), 'value', 'values')} outside its range: "
              f"{', '.join(outside)}")


# -- params load ----------------------------------------------------------------------------------


@params_app.command()
def load(
    file: Annotated[Path, typer.Argument(metavar="FILE", help="a parameter file")],
    axis: Annotated[str | None, typer.Argument(
        metavar="[AXIS]", help="the axis whose drive gets them (default: the file's)")] = None,
    machine: MachineOpt = None,
    dry_run: Annotated[bool, typer.Option(
        "--dry-run", "-n", help="only show what would be written")] = False,
    save: Annotated[bool, typer.Option(
        "--save", help="store the parameters in the drive's EEPROM (once, at the end)")]
    = False,
    include_comms: Annotated[bool, typer.Option(
        "--include-comms", help="also write the drive's address and line settings "
        "(they apply after a power cycle; see drivebus commission)")] = False,
    as_json: JsonOpt = False,
    server: ServerOpt = None,
    token: TokenOpt = None,
    local: LocalOpt = False,
) -> None:
    """Write the parameters of FILE that differ from the drive's, in the manual's order.

    Every value is range-checked before the first write (one out of range: nothing is
    written). With --save the drive stores them once at the end. An interrupted load says
    which parameters were written."""
    from drivebus.app.params import LoadReport, ParameterSet, load_parameters, open_drive
    from drivebus.cli.terminal import Out

    wanted = ParameterSet.load(file)
    axis = _axis_of(wanted, axis, file)
    config = _machine_of(wanted, machine, file)
    out = Out(as_json=as_json)
    owner = _owner(config, server, token, local)
    report = LoadReport(wanted.family, [])

    def said(w: Any) -> None:
        if len(report.written) == 1:  # the first write: every value passed its checks
            out.line(f"loading {file} into axis {axis} ({report.family}):")
        unit = f" {w.parameter.unit}" if w.parameter.unit else ""
        out.line(f"  {w.parameter.key}: {w.old} -> {w.new}{unit}")

    async def run() -> int:
        try:
            if owner is not None:
                data = await _call(lambda: owner.load_parameters(
                    axis, wanted.values, save=save, dry_run=dry_run,
                    include_comms=include_comms))
                _show_load(out, data, axis, remote=True)
                return 0
            async with open_drive(config, axis) as profile:
                await load_parameters(profile, wanted, save=save, dry_run=dry_run,
                                      include_comms=include_comms, report=report,
                                      on_write=None if dry_run else said)
        except LimitViolation as exc:  # a value of the file out of range: a bad file
            raise ConfigError(f"{file}: {exc}") from None
        except BaseException:
            if report.written:
                _note(f"written before the load stopped: {', '.join(report.written)}")
            raise
        _show_load(out, report.as_dict(), axis, remote=False)
        return 0

    _run(run)


def _show_load(out: Out, data: dict[str, Any], axis: str, *, remote: bool) -> None:
    out.result(data)
    writes = data["writes"]
    if data["dry_run"]:
        out.line(f"dry run: {len(writes)} parameter{'' if len(writes) == 1 else 's'} of axis "
                 f"{axis} would be written:")
        for w in writes:
            unit = f" {w['unit']}" if w["unit"] else ""
            out.line(f"  {w['key']}: {w['old']} -> {w['new']}{unit}")
    else:
        if remote:
            for w in writes:
                out.line(f"  {w['key']}: {w['old']} -> {w['new']}")
        n = len(data["written"])
        out.line(f"wrote {n} parameter{'' if n == 1 else 's'} of axis {axis}"
                 + ("; stored in the drive's EEPROM" if data["saved"] else
                    "; not saved: a power cycle restores the stored ones (--save stores "
                    "them)" if n else ""))
    for note in data["notes"]:
        out.line(f"note: {note}")
    if data["skipped"]:
        _note(f"not written (address and line settings; --include-comms writes them): "
              f"{', '.join(data['skipped'])}")


# -- commission -----------------------------------------------------------------------------------


def commission(
    target: Annotated[str, typer.Argument(
        metavar="TARGET", help="serial device or pty, sim://NAME or rtu+tcp://HOST:PORT")],
    drive: Annotated[str, typer.Option(
        "--drive", "-d", metavar="FAMILY", help="the drive's family (NT86, BHSS, CL86R, ...)")],
    address: Annotated[int, typer.Option(
        "--address", "-a", metavar="ADDR", help="the address it answers at now")],
    settings: Annotated[str | None, typer.Option(
        "--settings", "-S", metavar="SETTINGS",
        help='the settings it talks now, e.g. "9600 8N1" (default: 19200 8E1)')] = None,
    to_address: Annotated[int | None, typer.Option(
        "--to-address", metavar="ADDR", help="its new address")] = None,
    to_settings: Annotated[str | None, typer.Option(
        "--to-settings", metavar="SETTINGS", help='its new settings, e.g. "38400 8E1"')]
    = None,
    wait: Annotated[float, typer.Option(
        "--wait", metavar="SECONDS",
        help="how long to wait for it to answer at the new settings (0: do not check)")]
    = 60.0,
    timeout: Annotated[float, typer.Option(
        "--timeout", "-t", metavar="SECONDS", help="response timeout")] = 0.2,
    as_json: JsonOpt = False,
) -> None:
    """Give a drive its address and line settings through its own registers.

    Finds the drive at --address/--settings, refuses if another slave already answers at
    the new address, writes and stores the new address and settings, then waits for the
    drive to answer there: power-cycle it when told. Drives set by DIP switches say so."""
    from drivebus import checks
    from drivebus.app.commission import commission as run_commission
    from drivebus.cli.terminal import Out
    from drivebus.settings import LineSettings

    now = None if settings is None else LineSettings.parse(settings)
    new = None if to_settings is None else LineSettings.parse(to_settings)
    checks.whole("--address", address, 1, 247)
    if to_address is not None:
        checks.whole("--to-address", to_address, 1, 247)
    checks.positive("--timeout", timeout, unit="s")
    if checks.finite("--wait", wait) < 0:
        raise ArgumentError(f"--wait: {wait!r} s is negative")
    out = Out(as_json=as_json)

    hint = _power_hint(target, address)

    async def run() -> int:
        try:
            report = await run_commission(target, drive, address, now, to_address=to_address,
                                          to_settings=new, timeout=timeout, wait=wait,
                                          say=out.line, power_hint=hint)
        except NotSupported as exc:  # decided before anything is sent: a refusal
            raise ArgumentError(f"--drive {drive}: {exc}") from None
        out.result(report.as_dict())
        for name, value in report.writes:
            out.line(f"  wrote {name} = {value}")
        if report.answers_at_new:
            out.line(f"the {report.family} answers at address {report.to_address} at "
                     f"{report.to_settings} (after {report.seconds_to_answer} s)")
        elif report.answers_at_new is None:
            out.line("not checked (--wait 0): the drive takes the new settings at power-up")
        return 0

    _run(run)


def _power_hint(target: str, address: int) -> str:
    """How to power-cycle the drive when ``target`` is a running ``drivebus sim``'s line."""
    if not target.startswith("sim://"):
        return ""
    from drivebus.sim.serve import published

    if published(target.removeprefix("sim://").strip("/")) is None:
        return ""
    return (f"; on this drivebus sim: type `power-cycle {address}` at its console, or run "
            f"`drivebus sim MACHINE.toml --power-cycle {address}`")
