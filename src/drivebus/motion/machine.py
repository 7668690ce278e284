"""Machine and open_machine: lines, buses, drives and axis actors from one config."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import sys
from collections.abc import AsyncIterator, Awaitable, Callable, Iterable, Mapping
from contextlib import asynccontextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

import anyio
import anyio.to_thread

from drivebus.bus import Bus
from drivebus.config import AxisConfig, MachineConfig, machine_config_in_thread
from drivebus.drives.base import DriveProfile
from drivebus.drives.registry import family
from drivebus.errors import (
    ArgumentError,
    ConfigError,
    ConnectionLost,
    DrivebusError,
    DriveOffline,
    NotSupported,
    StateError,
    TransactionError,
)
from drivebus.motion.axis import Axis
from drivebus.motion.group import AxisGroup, GroupMoveReport
from drivebus.motion.handle import BufferMode, check_override
from drivebus.motion.lines import make_line, open_line, provide_elsewhere, serves_elsewhere
from drivebus.motion.path import GroupHandle
from drivebus.motion.recording import Recording
from drivebus.motion.sigint import second_sigint_waits
from drivebus.motion.sigterm import stops_before_sigterm
from drivebus.motion.state import MOVING_STATES, AxisState
from drivebus.positions import PositionStore
from drivebus.tasks import ServiceTasks, where_tasks_wait

__all__ = ["Machine", "check_teachable", "open_machine"]

if TYPE_CHECKING:
    from drivebus.motion.workers import WorkerPool

log = logging.getLogger(__name__)

_LEAVE_TIMEOUT = 30.0
"""Longest the stops on leaving a machine may take before its lines close, seconds."""


class Machine:
    """The running machine: ``axes`` by name, ``buses`` by line name, and what line
    providers serve (the simulator's twins and wires)."""

    def __init__(self, config: MachineConfig) -> None:
        self.config = config
        self.buses: dict[str, Bus] = {}
        self.axes: dict[str, Axis] = {}
        self.sim_drives: dict[str, Any] = {}
        """The stand-in behind each axis on a provided line: on ``sim://`` lines, the
        simulated twin (``drivebus.sim.SimDrive``) the tests and the demo judge by."""
        self.wires: dict[str, Any] = {}
        self._pool: WorkerPool | None = None
        """What serves each provided line: on ``sim://`` lines, the simulator's wire or
        server (its wire log, faults)."""
        self._override = 1.0
        self.taught = PositionStore.of(config, config.source)
        """The taught positions and the file they are kept in (``drivebus.positions``)."""
        self._teaching = anyio.Lock()

    # -- speed override ---------------------------------------------------------------------

    @property
    def override(self) -> float:
        """The machine's speed override (a feed override: 1.0 the speeds as asked, 0.5 half
        of them). Setting it scales the speed of every later move and jog of every axis
        and, where the drive can change speed on the fly, of those under way (each axis's
        sequencer sends that at once; others keep their speed to the end, logged).
        Multiplies each axis's own ``override``; 0 < override <= 2."""
        return self._override

    @override.setter
    def override(self, value: float) -> None:
        self._override = check_override("machine override", value)
        for axis in self.axes.values():
            axis.override_changed()

    def _own(self, axis: Axis) -> Axis:
        """Make ``axis`` take this machine's override."""
        axis.machine_override = lambda: self._override
        return axis

    # -- taught positions -------------------------------------------------------------------

    @property
    def positions(self) -> dict[str, dict[str, float]]:
        """Every taught position: name -> axis -> position (the axis's units)."""
        return {n: dict(v) for n, v in self.taught.positions.items()}

    def position(self, name: str) -> dict[str, float]:
        """The taught position ``name`` (``NotFound`` naming those there are)."""
        return self.taught.get(name)

    async def move_to(
        self,
        position: str | Mapping[str, float],
        *,
        speed: float | None = None,
        accel: float | None = None,
        decel: float | None = None,
        duration: float | None = None,
        buffer: BufferMode = "aborting",
    ) -> GroupMoveReport | GroupHandle:
        """Move the axes of a taught ``position`` (its name) or of a mapping there
        together, as ``AxisGroup.move_to`` does (speed, ramps, duration, buffer mode)."""
        targets = self.position(position) if isinstance(position, str) else dict(position)
        return await self.group(*targets).move_to(targets, speed=speed, accel=accel,
                                                   decel=decel, duration=duration,
                                                   buffer=buffer)

    async def teach(self, name: str, axes: Iterable[str] | None = None) -> dict[str, float]:
        """Store the present positions of ``axes`` (default: those the position already
        has, or every axis that can move) as ``name`` and write it back to the machine
        file (or its positions file) atomically, comments kept; the position's other
        axes keep theirs. Each axis is read fresh and must be at rest. Returns the
        position as stored. An axis whose drive cannot move to a position (a
        monitoring-only drive) is refused before anything is read (``ArgumentError``)."""
        if axes is None:
            known = self.taught.positions.get(name)
            names = list(known) if known else [
                n for n, a in self.axes.items() if _can_move(a)]
        else:
            names = list(axes)
            self.group(*names)  # ConfigError naming an unknown axis
        if not names:
            raise ArgumentError(f"teach {name!r}: no axes to teach")
        for n in names:  # before anything is read: a refusal sends nothing
            check_teachable(n, self.axes[n].profile)
        values: dict[str, float] = {}
        async with self._teaching:
            for n in names:
                axis = self.axes[n]
                st = await axis.refresh()
                if st.moving or axis.busy:
                    raise StateError(f"axis {n} is moving: teach {name!r} at rest")
                if st.position is None:
                    raise StateError(f"axis {n}: its drive reports no position to teach")
                values[n] = axis.units.from_pulses(st.position)
            # (the file is parsed, written and flushed to disk in a worker thread: an
            # fsync may take long on a controller's flash, and the loop carries the stops)
            stored = await anyio.to_thread.run_sync(self.taught.teach, name, values)
        log.info("taught %s: %s%s", name, stored,
                 f" ({self.taught.path})" if self.taught.path else " (in memory)")
        return stored

    def group(self, *names: str) -> AxisGroup:
        """The named axes as a group (all axes if none are named)."""
        missing = [repr(n) for n in names if not isinstance(n, str) or n not in self.axes]
        if missing:
            raise ConfigError(f"no axis {', '.join(missing)} (axes: {', '.join(self.axes)})")
        return AxisGroup([self.axes[n] for n in (names or tuple(self.axes))])

    def record(
        self,
        axes: Iterable[str] | None = None,
        *,
        bus: bool = True,
        max_samples: int = 100_000,
        max_events: int = 10_000,
        max_transactions: int = 500_000,
    ) -> Recording:
        """A recording of ``axes`` (all if None) and, with ``bus``, of their lines'
        transactions: ``async with machine.record(axes=["x"]) as rec:``. It only listens
        (no bus traffic); memory is bounded by the ``max_*`` rings (``Recording``).
        ``ConfigError`` names an unknown axis."""
        return Recording(self, axes, bus=bus, max_samples=max_samples,
                         max_events=max_events, max_transactions=max_transactions)

    @property
    def workers(self) -> list[dict[str, Any]]:
        """The worker processes serving lines (``workers`` in the machine file): each one's
        lines, process id, restarts and state; empty where this process serves them all."""
        return [] if self._pool is None else self._pool.info()

    def _line_lost(self, lines: list[str], error: ConnectionLost) -> None:
        """The worker serving ``lines`` died: their axes go Offline now."""
        for axis in self.axes.values():
            if axis.config.line in lines:
                axis.line_lost(error)

    async def stop_all(self, *, only_commanded: bool = False) -> list[str]:
        """Stop every moving axis (or only those this machine set moving), in parallel,
        each returning once a status polled after its stop shows it at rest. Decelerating
        (``halt_now`` is the emergency stop). Errors are logged, never raised; returns the
        axes it stopped and saw at rest, each with its position ("x at 12.5000 mm").

        A command still being planned (a group move, a path) has not taken its axes yet:
        the axes at rest get a stop too, which sends nothing to an axis at rest but
        aborts what is planned on it, so that nothing starts once ``stop_all`` returns."""
        stopped: list[str] = []
        moving = self._moving(only_commanded)

        async def stop(axis: Axis) -> None:
            try:
                await axis.stop()
            except DrivebusError as exc:
                log.error("axis %s: stop failed: %s", axis.name, exc)
                return
            if axis in moving:
                where = "" if axis.position is None else \
                    f" at {axis.position:.4f} {axis.config.unit}"
                stopped.append(f"{axis.name}{where}")

        at_rest = [] if only_commanded else [
            a for a in self.axes.values() if a not in moving and a.state is not AxisState.OFFLINE]
        await self._each([*moving, *at_rest], stop)
        return stopped

    async def halt_now(self) -> dict[str, DrivebusError | None]:
        """Emergency stop of every axis, all lines in parallel: each axis's ``halt_now``
        (the drive's quick stop at ``Priority.EMERGENCY``, ahead of everything queued, its
        motion and queue aborted); returns once every drive that was moving is seen at
        rest. Never raises for an axis: returns each axis's outcome (None: at rest, else
        the error, also logged). ``stop_all`` is the decelerating stop."""
        outcome: dict[str, DrivebusError | None] = {}

        async def halt(axis: Axis) -> None:
            try:
                await axis.halt_now()
                outcome[axis.name] = None
            except DrivebusError as exc:
                log.error("axis %s: emergency stop failed: %s", axis.name, exc)
                outcome[axis.name] = exc

        log.warning("machine %s: emergency stop of every axis", self.config.name)
        await self._each(self.axes.values(), halt)
        return outcome

    def _moving(self, only_commanded: bool) -> list[Axis]:
        """The axes that may be moving (``only_commanded``: those this machine set going)."""
        out = []
        for a in self.axes.values():
            moving = (a.status is not None and a.status.moving) or a.started_unseen
            if a.commanded if only_commanded else a.state in MOVING_STATES or moving:
                out.append(a)
        return out

    @staticmethod
    async def _each(axes: Iterable[Axis], fn: Callable[[Axis], Awaitable[None]]) -> None:
        async with anyio.create_task_group() as tg:
            for a in axes:
                tg.start_soon(fn, a)


def check_teachable(axis: str, profile: DriveProfile) -> None:
    """``ArgumentError`` if a position taught for ``axis`` could never be moved to: its
    drive (``profile``) cannot make an absolute move, as a monitoring-only drive such as
    the OD2000 cannot. No I/O: ``teach`` asks before it reads anything."""
    try:
        profile.check_supported("move_absolute")
    except NotSupported as exc:
        if isinstance(exc, ConfigError):
            raise
        raise ArgumentError(f"axis {axis} cannot be taught: a taught position is moved "
                            f"to, and {exc}") from None


def _can_move(axis: Axis) -> bool:
    try:
        check_teachable(axis.name, axis.profile)
    except DrivebusError:
        return False
    return True


async def _make_axis(
    machine: Machine, name: str, cfg: AxisConfig, *, require: bool = True
) -> Axis:
    bus = machine.buses[cfg.line]
    fam = family(cfg.drive)
    slave = bus.slave(cfg.address, settings=cfg.settings)
    try:
        profile: DriveProfile = fam.profile(
            slave, pulses_per_rev=cfg.pulses_per_rev, **cfg.drive_options
        )
    except TypeError as exc:
        raise ConfigError(f"axes.{name}.drive_options: {exc}") from None
    axis = Axis(name, cfg, profile)
    axis.envelope.target_range()  # found now (some ms of dry runs), not at a first move
    try:
        await profile.read_status()
        await profile.learn()  # reads only: the drive is set up by the first command
        await axis.refresh()  # the axis starts knowing where its drive is
    except TransactionError as exc:
        error = DriveOffline(
            f"axis {name}: the {fam.name} drive at address {cfg.address} on line "
            f"{cfg.line} does not answer: {exc}"
        )
        if require:
            raise error from exc
        log.warning("%s; the axis starts Offline", error)
        axis.start_offline(error)
    return axis


@asynccontextmanager
async def open_machine(
    config: str | Path | Mapping[str, Any] | MachineConfig,
    *,
    stop_on_exit: bool = True,
    require_all: bool = True,
) -> AsyncIterator[Machine]:
    """Open every line, check every drive answers, start the axis actors.

    A drive that does not answer is a ``DriveOffline``, and nothing is left open; with
    ``require_all=False`` (a service, a status display) its axis starts Offline instead and
    is set up when the drive answers.

    On exit (normal, error or cancellation) every moving axis is stopped before the
    lines close. An observer that must not touch motion it did not start (a status or
    monitor tool) passes ``stop_on_exit=False``: then only motions commanded through
    this machine are stopped. ``sim://NAME`` lines start the built-in simulator with a
    twin per axis. ``config`` is a machine file's path, its content as a mapping, or a
    ``MachineConfig``; it is validated in full (``ConfigError``) before anything opens.
    Where the application leaves SIGTERM at its default, an open machine takes it: its
    axes are stopped before the process ends by it (``drivebus.motion.sigterm``); a
    second Ctrl-C waits for those stops (``drivebus.motion.sigint``).
    """
    cfg = await machine_config_in_thread(config)  # parsing descriptions: off the loop
    machine = Machine(cfg)
    # (where the application left SIGTERM to its default, SIGINT to Python or asyncio)
    with stops_before_sigterm(), second_sigint_waits():
        async with _opened(machine, cfg, stop_on_exit=stop_on_exit,
                           require_all=require_all) as opened:
            yield opened


@asynccontextmanager
async def _opened(machine: Machine, cfg: MachineConfig, *, stop_on_exit: bool,
                  require_all: bool) -> AsyncIterator[Machine]:
    """``open_machine``'s lines, workers and axes, and its stops on leaving."""
    async with contextlib.AsyncExitStack() as stack:
        groups = _placement(cfg)
        remote = {name for group in groups for name in group}
        if groups:  # (imported here: a machine without workers loads none of it)
            from drivebus.motion.workers import LineSpec, WorkerPool
        specs: dict[str, LineSpec] = {}
        buses: dict[str, Bus] = {}
        for name, line in cfg.lines.items():
            if name in remote:
                where, provided = await provide_elsewhere(cfg, name, stack)
                specs[name] = LineSpec(name, where, line.timeout, line.retries)
            else:
                ln, provided = await open_line(cfg, name, stack)
                buses[name] = await stack.enter_async_context(
                    Bus(ln, timeout=line.timeout, retries=line.retries))
            if provided is not None:
                machine.sim_drives.update(provided.twins)
                machine.wires[name] = provided.server
        if specs:
            machine._pool = await stack.enter_async_context(WorkerPool(
                [[specs[n] for n in group] for group in groups],
                {n: make_line(s.config) for n, s in specs.items()}, machine._line_lost))
        for name in cfg.lines:
            machine.buses[name] = buses[name] if name in buses else \
                machine._pool.buses[name]  # type: ignore[union-attr, assignment]
        for name, axis_cfg in cfg.axes.items():
            machine.axes[name] = machine._own(
                await _make_axis(machine, name, axis_cfg, require=require_all))
        actors = await stack.enter_async_context(ServiceTasks())
        for axis in machine.axes.values():
            actors.start_soon(axis.run, name=f"drivebus axis {axis.name}")
        try:
            yield machine
        finally:
            cancelled = await _stop_on_leaving(machine, only_commanded=not stop_on_exit)
            actors.cancel()
            if cancelled is not None and sys.exc_info()[1] is None:
                raise cancelled  # a cancellation that came during the stops, now


def _placement(cfg: MachineConfig) -> list[list[str]]:
    """The lines each worker serves (``workers`` of the machine file, ``"auto"`` by line
    count and cores); lines that another process cannot open stay here."""
    if not cfg.workers:
        return []
    from drivebus.motion.workers import auto_workers, placement

    n = auto_workers(len(cfg.lines)) if cfg.workers == "auto" else cfg.workers
    if not n:
        return []
    names = [name for name in cfg.lines if serves_elsewhere(cfg, name)]
    left = [name for name in cfg.lines if name not in names]
    if left:
        log.info("machine %s: line %s stays in this process (its provider cannot serve "
                 "another process)", cfg.name, ", ".join(left))
    return placement(names, min(n, len(names)))


async def _stop_on_leaving(
    machine: Machine, *, only_commanded: bool
) -> BaseException | None:
    """Stop every moving axis before the lines close, however the owner leaves: the
    stops are shielded and bounded (30 s), and a cancellation from outside that comes
    meanwhile (a second Ctrl-C, an event loop being torn down) does not cut them short:
    it is returned, to be raised once they are done. Buses and actors are service tasks
    (``ServiceTasks``), still running here; a bus owner cancelled from outside serves on
    (``Bus``), and an axis whose actor is gone polls for rest itself."""
    moving = [a.name for a in machine._moving(only_commanded)]
    if moving:
        log.warning("leaving machine %s: stopping %s", machine.config.name,
                    ", ".join(moving))
    cancelled: BaseException | None = None
    deadline = anyio.current_time() + _LEAVE_TIMEOUT
    stopped: list[str] = []
    while True:
        try:
            with anyio.CancelScope(shield=True), anyio.move_on_after(
                    deadline - anyio.current_time()) as scope:
                stopped = await machine.stop_all(only_commanded=only_commanded)
            if stopped:
                log.warning("leaving machine %s: stopped %s (at rest)", machine.config.name,
                            ", ".join(stopped))
            if scope.cancelled_caught:
                log.error("leaving machine %s: the stops did not end within %.0f s; the "
                          "tasks wait at:\n  %s", machine.config.name, _LEAVE_TIMEOUT,
                          "\n  ".join(where_tasks_wait()))
            return cancelled
        except anyio.get_cancelled_exc_class() as exc:
            cancelled = exc  # from outside (anyio's own cannot reach a shielded scope)
            task = asyncio.current_task()
            if task is not None:
                task.uncancel()
            log.warning("leaving machine %s: cancelled again while stopping the axes; "
                        "the stops go on", machine.config.name)
