"""``drivebus teach`` and ``drivebus move MACHINE POSITION``: taught positions.

``drivebus teach MACHINE pick [AXIS]...`` reads the named axes (default: those the
position already has, or every axis that can move) and stores them as ``pick`` in the
machine file (or its positions file), comments kept; ``drivebus move MACHINE pick``
moves the position's axes there together. ``drivebus positions MACHINE`` lists them.
Through a running ``drivebus serve`` that owns the machine they go to the service.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from drivebus.cli.options import ConfigArg, JsonOpt, LocalOpt, ServerOpt, TokenOpt
from drivebus.cli.options import owner as _owner
from drivebus.errors import ArgumentError

if TYPE_CHECKING:
    from drivebus.cli.terminal import Out
    from drivebus.config import MachineConfig
    from drivebus.service.client import ServiceClient

__all__ = ["move_position", "positions", "teach"]

def _shown(position: dict[str, float]) -> str:
    return " ".join(f"{a}={v:.3f}" for a, v in position.items())


async def _teach_here(out: Out, config: MachineConfig, name: str, axes: list[str]) -> int:
    from drivebus.motion import open_machine

    async with open_machine(config, stop_on_exit=False) as m:
        stored = await m.teach(name, axes or None)
        where = m.taught.path or "memory"
    out.line(f"taught {name}: {_shown(stored)} ({where})")
    out.result({"position": name, "axes": stored, "file": str(where)})
    return 0


async def _teach_remote(out: Out, client: ServiceClient, name: str, axes: list[str]) -> int:
    from drivebus.cli.remote import call as _call

    result = await _call(client.request, "POST", f"/positions/{name}/teach",
                         {"axes": axes} if axes else {})
    out.line(f"taught {name}: {_shown(result['axes'])} ({result.get('file') or 'memory'})")
    out.result(result)
    return 0


NameArg = Annotated[str, typer.Argument(help="the position's name", metavar="POSITION")]


def teach(
    config: ConfigArg,
    name: NameArg,
    axes: Annotated[list[str] | None, typer.Argument(
        help="axes to teach (default: the position's, or every axis that can move)",
        metavar="[AXIS]...")] = None,
    as_json: JsonOpt = False,
    server: ServerOpt = None,
    token: TokenOpt = None,
    local: LocalOpt = False,
) -> None:
    """Store the axes' present positions as POSITION in the machine file (comments kept)."""
    from drivebus.cli.terminal import Out, run_guarded

    _check_name(name)  # whoever teaches: refused before anything opens or is asked
    out = Out(as_json=as_json)
    owner = _owner(config, server, token, local)
    if owner is not None:
        raise typer.Exit(run_guarded(lambda: _teach_remote(out, owner, name, axes or [])))
    cfg = _refuse_teaching(config, name, axes or [])
    raise typer.Exit(run_guarded(lambda: _teach_here(out, cfg, name, axes or [])))


def _check_name(name: str) -> None:
    """POSITION as a position's name (``drivebus.config.POSITION_NAME``), else an
    ``ArgumentError`` naming it (exit status 2)."""
    from drivebus.config import POSITION_NAME_RULE, is_position_name

    if not is_position_name(name):
        raise ArgumentError(f"POSITION: {name!r} is not a position's name: "
                            f"{POSITION_NAME_RULE}")


def _refuse_teaching(config: Path, name: str, axes: list[str]) -> MachineConfig:
    """The machine file, once what it alone refuses of ``teach`` has passed, before
    anything opens: an unknown axis (a ``ConfigError`` naming those there are), an axis
    whose drive cannot move to a position (``ArgumentError``, exit status 2), among the
    named axes or, with none named, the position's own."""
    from drivebus.app.operations import refuse_before_opening, subset
    from drivebus.config import load_config
    from drivebus.positions import PositionStore

    cfg = load_config(config)
    if name in cfg.axes:
        raise ArgumentError(f"POSITION: {name!r} is an axis's name: a position may not have "
                            f"one (drivebus move MACHINE {name} would be ambiguous)")
    subset(cfg, axes)
    chosen = axes or list(PositionStore.of(cfg, cfg.source).positions.get(name, {}))
    for axis in dict.fromkeys(chosen):
        try:
            refuse_before_opening(cfg, axis, "teach")
        except ArgumentError as exc:
            raise ArgumentError(f"AXIS: {exc}") from None
    return cfg


async def _move_here(out: Out, config: MachineConfig, name: str, speed: float | None) -> int:
    from drivebus.motion import GroupMoveReport, open_machine

    started = time.monotonic()
    async with open_machine(config) as m:
        target = m.position(name)
        report = await m.move_to(name, speed=speed)
        assert isinstance(report, GroupMoveReport)
        here = {a: m.axes[a].position for a in target}
    seconds = time.monotonic() - started
    out.line(f"at {name}: {_shown({a: v or 0.0 for a, v in here.items()})} (planned "
             f"{report.duration:.2f} s, arrival spread {report.arrival_spread * 1000:.1f} ms)")
    out.result({"position": name, "axes": here, "seconds": round(seconds, 4),
                "planned": report.duration, "arrival_spread": report.arrival_spread})
    return 0


async def _move_remote(out: Out, client: ServiceClient, name: str, speed: float | None) -> int:
    from drivebus.cli.remote import remote_motion

    body = {} if speed is None else {"speed": speed}
    return await remote_motion(out, client, "", f"move to {name}",
                               f"/positions/{name}/move", body)


def move_position(config: Path, name: str, speed: float | None, as_json: bool,
                  server: str | None, token: str | None, local: bool) -> int:
    """``drivebus move MACHINE POSITION``: the position's axes there, together."""
    from drivebus.cli.terminal import Out, run_guarded

    if not name or name[0].isdigit() or name[0] in "+-.":
        raise ArgumentError(f"drivebus move {config} {name}: give AXIS TARGET, or the name "
                            f"of a taught position")
    out = Out(as_json=as_json)
    owner = _owner(config, server, token, local)
    if owner is not None:
        return run_guarded(lambda: _move_remote(out, owner, name, speed))
    cfg = _refuse_moving(config, name, speed)
    return run_guarded(lambda: _move_here(out, cfg, name, speed))


def _refuse_moving(config: Path, name: str, speed: float | None) -> MachineConfig:
    """The machine file, once what it alone refuses of a move to the taught position
    ``name`` has passed, before anything opens: no such position, an axis of it that
    cannot move or not at ``speed`` (``ArgumentError``, exit status 2)."""
    from drivebus.cli.machine import refuse_early
    from drivebus.config import load_config
    from drivebus.errors import NotFound
    from drivebus.positions import PositionStore

    cfg = load_config(config)
    try:
        targets = PositionStore.of(cfg, cfg.source).get(name)
    except NotFound as exc:
        raise ArgumentError(f"POSITION: {exc}") from None
    for axis, target in targets.items():
        refuse_early(cfg, axis, "move", target=target, speed=speed)
    return cfg


async def _list(out: Out, config: Path) -> int:
    from drivebus.config import load_config
    from drivebus.positions import PositionStore

    cfg = load_config(config)
    store = PositionStore.of(cfg, cfg.source)
    for name, position in store.positions.items():
        out.line(f"{name}: {_shown(position)}")
    out.result({"file": str(store.path), "positions": store.positions})
    return 0


def positions(config: ConfigArg, as_json: JsonOpt = False) -> None:
    """List the machine's taught positions (reads the files only, no drive is opened)."""
    from drivebus.cli.terminal import Out, run_guarded

    out = Out(as_json=as_json)
    raise typer.Exit(run_guarded(lambda: _list(out, config)))
