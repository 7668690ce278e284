"""``drivebus record``: record a machine's axes and lines, write the report and exports.

``drivebus record MACHINE --during "move x 100" -o run.html`` opens the machine, records
while the ``--during`` steps run one after the other (and for ``--seconds``), and writes
each ``-o`` file by its suffix: ``.html`` the self-contained report, ``.jsonl`` the whole
recording, ``.csv`` and ``.parquet`` the samples table; ``--png`` a static picture. When a
``drivebus serve`` owns the machine, the recording is made by it (its recordings API) and
the steps are its motions, so the line keeps one master.
"""

from __future__ import annotations

import shlex
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from drivebus import checks
from drivebus.cli.options import ConfigArg, LocalOpt, ServerOpt, TokenOpt, check_output
from drivebus.errors import ArgumentError, ConfigError

if TYPE_CHECKING:
    from drivebus.config import MachineConfig
    from drivebus.motion import Recording
    from drivebus.service.client import ServiceClient

__all__ = ["Step", "parse_step", "record"]

OUTPUTS = (".html", ".htm", ".jsonl", ".csv", ".parquet")

_STEPS = ('"move AXIS TARGET [AXIS TARGET ...]" (several axes: a group move), '
          '"move-by AXIS DISTANCE [...]", "home AXIS", "jog AXIS SPEED SECONDS", '
          '"stop [AXIS ...]", "enable AXIS", "wait SECONDS"')


@dataclass(frozen=True)
class Step:
    """One ``--during`` step: an operation and its arguments."""

    op: str
    axes: tuple[str, ...]
    values: tuple[float, ...] = ()


def _number(text: str, what: str, step: str) -> float:
    try:
        return checks.finite(what, float(text))
    except ValueError:
        raise ArgumentError(f"--during {step!r}: {what} {text!r} is not a number") from None


def parse_step(text: str) -> Step:
    """A ``--during`` step from its text (``ArgumentError`` naming what is wrong)."""
    words = shlex.split(text)
    if not words:
        raise ArgumentError(f"--during: empty step; steps: {_STEPS}")
    op, args = words[0].lower(), words[1:]
    if op in ("move", "move-by"):
        if not args or len(args) % 2:
            raise ArgumentError(f"--during {text!r}: expected AXIS VALUE pairs")
        pairs = list(zip(args[::2], args[1::2], strict=True))
        return Step(op, tuple(a for a, _ in pairs),
                    tuple(_number(v, "position" if op == "move" else "distance", text)
                          for _, v in pairs))
    if op in ("home", "enable") and len(args) == 1:
        return Step(op, (args[0],))
    if op == "stop":
        return Step(op, tuple(args))
    if op == "jog" and len(args) == 3:
        seconds = checks.positive("--during jog SECONDS", _number(args[2], "SECONDS", text),
                                  unit="s")
        return Step(op, (args[0],), (_number(args[1], "SPEED", text), seconds))
    if op == "wait" and len(args) == 1:
        return Step(op, (), (checks.positive("--during wait", _number(args[0], "SECONDS",
                                                                       text), unit="s"),))
    raise ArgumentError(f"--during {text!r}: not a step; steps: {_STEPS}")


def _runner(step: Step, machine: object) -> Callable[[], Awaitable[object]]:
    import anyio

    from drivebus.cli.machine import check_goal, check_jog_room
    from drivebus.motion import Machine

    assert isinstance(machine, Machine)
    m = machine
    for name in step.axes:
        if name not in m.axes:
            raise ConfigError(f"--during: no axis {name!r} (axes: {', '.join(m.axes)})")
    targets = dict(zip(step.axes, step.values, strict=False))
    if step.op == "move":
        if len(targets) == 1:
            (name, target), = targets.items()
            return lambda: m.axes[name].move_to(target)
        return lambda: m.group(*targets).move_to(targets)
    if step.op == "move-by":

        async def move_by() -> None:
            for name, distance in targets.items():  # refused as `move --by` refuses it
                here = m.axes[name].position
                if here is not None:
                    check_goal(m.axes[name], here + distance, f"--during move-by {name}")
            if len(targets) == 1:
                (name, distance), = targets.items()
                await m.axes[name].move_by(distance)
            else:
                await m.group(*targets).move_by(targets)

        return move_by
    if step.op == "home":
        return m.axes[step.axes[0]].home
    if step.op == "enable":
        return m.axes[step.axes[0]].enable
    if step.op == "stop":
        return m.group(*step.axes).stop
    if step.op == "jog":
        axis, (speed, seconds) = m.axes[step.axes[0]], step.values

        async def jog() -> None:
            check_jog_room(axis, speed, f"--during jog {axis.name}")  # as `jog` refuses it
            async with axis.jogging(speed):
                await anyio.sleep(seconds)

        return jog
    return lambda: anyio.sleep(step.values[0])


def _refuse_early(config: Path, axes: list[str], steps: list[Step]) -> MachineConfig:
    """The machine file, once what it refuses alone of the recording and its steps has
    passed, before anything opens: an unknown axis, a drive that cannot do a step, a
    target beyond the soft limits (``drivebus.cli.machine.refuse_early``)."""
    from drivebus.app.operations import subset
    from drivebus.cli.machine import refuse_early
    from drivebus.config import load_config

    cfg = load_config(config)
    subset(cfg, axes)
    for step in steps:
        for name in step.axes:
            if name not in cfg.axes:
                raise ConfigError(f"--during: no axis {name!r} (axes: {', '.join(cfg.axes)})")
        procedure = {"move": "move", "move-by": "move_by", "home": "home", "jog": "jog"}.get(
            step.op)
        if procedure is None:
            continue
        for i, name in enumerate(step.axes):
            value = step.values[i] if i < len(step.values) else None
            try:
                refuse_early(cfg, name, procedure, target=value if step.op == "move" else None,
                             speed=value if step.op == "jog" else None)
            except ArgumentError as exc:
                raise ArgumentError(f"--during {step.op} {name}: "
                                    f"{str(exc).split(': ', 1)[-1]}") from None
    return cfg


def _refuse_relative(steps: list[Step], machine: object) -> None:
    """Each ``move-by`` whose start is known before the steps run (where the axis is, or
    a ``move`` step's target before it) refused beyond the soft limits, as ``move --by``."""
    from drivebus.cli.machine import check_goal
    from drivebus.motion import Machine

    assert isinstance(machine, Machine)
    at = {name: ax.position for name, ax in machine.axes.items()}
    for step in steps:
        for name, value in zip(step.axes, step.values, strict=False):
            if step.op == "move":
                at[name] = value
            elif step.op == "move-by" and (here := at[name]) is not None:
                check_goal(machine.axes[name], here + value, f"--during move-by {name}")
                at[name] = here + value
        if step.op in ("home", "jog"):  # where they end is the drive's to say
            at.update(dict.fromkeys(step.axes))


async def _record(config: Path | MachineConfig, axes: list[str], steps: list[Step],
                  seconds: float | None, outputs: list[Path], png: Path | None) -> int:
    import anyio

    from drivebus.motion import open_machine

    # A recording only listens: on its end it stops what its own steps set moving, never
    # an axis that was moving when it began (the observer's rule, as status and teach).
    async with open_machine(config, stop_on_exit=False) as m:
        runs = [_runner(s, m) for s in steps]  # every step checked before anything moves
        _refuse_relative(steps, m)
        async with m.record(axes=axes or None) as rec:
            for run in runs:
                await run()
            rest = (seconds or 0.0) - rec.duration
            await anyio.sleep(max(rest, 0.25 if steps else 0.0))
    _write(rec, outputs, png)
    return 0


async def _record_through(client: ServiceClient, axes: list[str], steps: list[Step],
                          seconds: float | None, outputs: list[Path], png: Path | None) -> int:
    """``record`` through the running ``drivebus serve`` that owns the machine (the line's
    one owner): a recording of its recordings API while the steps run as its motions,
    then its JSON lines, written here like a recording of this process."""
    import time

    import anyio

    from drivebus.cli.remote import call
    from drivebus.motion import Recording

    machine = await call(client.machine)
    known = [a["name"] for a in machine["axes"]]
    for name in [*axes, *(a for s in steps for a in s.axes)]:
        if name not in known:  # every step checked before anything starts
            raise ConfigError(f"--during: no axis {name!r} (axes: {', '.join(known)})")
    started = time.monotonic()
    rec = await call(client.request, "POST", "/recordings", {"axes": axes} if axes else None)
    try:
        for step in steps:
            await _remote_step(client, step)
        rest = (seconds or 0.0) - (time.monotonic() - started)
        await anyio.sleep(max(rest, 0.25 if steps else 0.0))
    finally:
        with anyio.CancelScope(shield=True):
            await call(client.request, "POST", f"/recordings/{rec['id']}/stop")
    text = await call(client.text, f"/recordings/{rec['id']}/jsonl")
    typer.echo(f"recorded through {client.url} (recording {rec['id']})")
    _write(Recording.from_jsonl(text), outputs, png)
    return 0


async def _remote_step(client: ServiceClient, step: Step) -> None:
    """One ``--during`` step as the service's motions and commands; a motion that does not
    complete raises its typed error."""
    import anyio

    from drivebus.cli.remote import call, follow_motion, motion_error

    targets = dict(zip(step.axes, step.values, strict=False))
    what = f"{step.op} {' '.join(step.axes)}".strip()
    if step.op == "move-by" and len(targets) > 1:  # a group moves to targets: from here
        here = {a: (await call(client.axis, a)).get("position") for a in targets}
        if any(v is None for v in here.values()):
            raise ConfigError(f"--during {what}: a position is unknown")
        targets = {a: float(here[a]) + d for a, d in targets.items()}  # type: ignore[arg-type]
    if step.op in ("move", "move-by") and len(targets) > 1:
        record = await follow_motion(client, "/machine/group-move", {"targets": targets})
    elif step.op in ("move", "move-by"):
        (name, value), = targets.items()
        record = await follow_motion(client, f"/axes/{name}/move",
                                     {"target" if step.op == "move" else "by": value})
    elif step.op == "home":
        record = await follow_motion(client, f"/axes/{step.axes[0]}/home")
    elif step.op == "jog":
        name, (speed, seconds) = step.axes[0], step.values
        try:
            with anyio.move_on_after(seconds):
                while True:  # fed every 0.2 s: a 0.5 s watchdog stops it if this stops
                    await call(client.command, name, "jog", {"speed": speed, "ttl": 0.5})
                    await anyio.sleep(0.2)
        finally:
            with anyio.CancelScope(shield=True):
                await call(client.command, name, "stop")
        return
    elif step.op in ("enable", "stop"):
        names = step.axes or tuple(a["name"] for a in (await call(client.machine))["axes"])
        for name in names:
            await call(client.command, name, step.op)
        return
    else:  # wait
        await anyio.sleep(step.values[0])
        return
    if record["state"] != "done":
        raise motion_error(record, what)


def _write(rec: Recording, outputs: list[Path], png: Path | None) -> None:
    """Write ``rec`` to each output by its suffix, and the PNG; say what was recorded."""
    from drivebus.service.report import report_html, report_png

    for path in outputs:
        suffix = path.suffix.lower()
        if suffix in (".html", ".htm"):
            path.write_text(report_html(rec), encoding="utf-8")
        elif suffix == ".jsonl":
            rec.to_jsonl(path)
        elif suffix == ".csv":
            rec.to_csv(path)
        else:
            rec.to_parquet(path)
        typer.echo(f"wrote {path}")
    if png is not None:
        report_png(rec, png)
        typer.echo(f"wrote {png}")
    moves = rec.arrivals()
    typer.echo(f"recorded {rec.duration:.2f} s: {sum(len(t.samples) for t in rec.axes.values())}"
               f" samples, {sum(len(t.events) for t in rec.axes.values())} events, "
               f"{sum(len(t.transactions) for t in rec.lines.values())} transactions, "
               f"{len(moves)} moves")


def record(
    config: ConfigArg,
    axes: Annotated[list[str] | None, typer.Argument(
        help="axes to record (default: all)", metavar="[AXIS]...")] = None,
    seconds: Annotated[float | None, typer.Option(
        "--seconds", "-s", metavar="N",
        help="record at least N seconds (default: until the --during steps end, or 5 s)")]
    = None,
    during: Annotated[list[str] | None, typer.Option(
        "--during", "-d", metavar="STEP",
        help=f"a step to run while recording, repeatable, in order: {_STEPS}")] = None,
    output: Annotated[list[Path] | None, typer.Option(
        "--output", "-o", metavar="FILE",
        help="write FILE by its suffix: .html report, .jsonl recording, .csv or .parquet "
             "samples; repeatable")] = None,
    png: Annotated[Path | None, typer.Option(
        "--png", metavar="FILE", help="also draw the report as a PNG (matplotlib)")] = None,
    server: ServerOpt = None,
    token: TokenOpt = None,
    local: LocalOpt = False,
) -> None:
    """Record the axes' positions, velocities and events and the lines' transactions while
    --during steps run; write a self-contained HTML report (-o run.html) and exports.

    When a drivebus serve owns the machine, it records through it (its recordings API;
    the steps run as its motions): the line keeps its one master. At its end (Ctrl-C,
    SIGTERM too) it stops only what its steps moved: an axis moving before goes on."""
    from drivebus.cli.remote import service_owner
    from drivebus.cli.terminal import run_guarded

    steps = [parse_step(s) for s in during or []]
    if seconds is not None:
        checks.positive("--seconds", seconds, unit="s")
    elif not steps:
        seconds = 5.0
    outputs = list(output or [])
    bad = [str(p) for p in outputs if p.suffix.lower() not in OUTPUTS]
    if bad:
        raise ArgumentError(f"--output {', '.join(bad)}: the suffix says what to write: "
                            f"{', '.join(OUTPUTS)}")
    if not outputs and png is None:
        raise ArgumentError("nothing to write: give -o run.html (or .jsonl, .csv, .parquet) "
                            "or --png FILE")
    for path in outputs:  # a file that cannot be written: refused before anything moves
        check_output(path, "--output", "run.html")
    if png is not None:
        check_output(png, "--png", "run.png")
    owner = service_owner(config, server, token, local)
    if owner is not None:
        raise typer.Exit(run_guarded(lambda: _record_through(owner, axes or [], steps,
                                                             seconds, outputs, png)))
    cfg = _refuse_early(config, axes or [], steps)
    raise typer.Exit(run_guarded(lambda: _record(cfg, axes or [], steps, seconds,
                                                 outputs, png)))
