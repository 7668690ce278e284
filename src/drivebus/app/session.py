"""MachineSession: one open machine serving many clients.

What the service, the MQTT bridge and the CLI share, with no terminal or network code:
snapshots as plain data, motions that run in the session with an id and a state that
clients can poll or cancel, stops and e-stop, jogs held by a client's watchdog, a command
lease, and an event stream (axes as polled, line counters, motion events, errors).

Every operation raises the typed errors of ``drivebus.errors``; a front end maps them
(HTTP status, MQTT reply, exit code). An e-stop is never refused: not by a lease, not by
a state, not behind a queue.
"""

from __future__ import annotations

import itertools
import logging
import time
from collections import OrderedDict
from collections.abc import AsyncIterator, Awaitable, Callable, Mapping
from contextlib import asynccontextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import anyio
import anyio.abc
import anyio.lowlevel

from drivebus import checks
from drivebus.app.events import Event, EventHub
from drivebus.app.params import LoadReport, ParameterSet, load_parameters, read_parameters
from drivebus.app.recordings import Recordings
from drivebus.app.snapshots import (
    AxisSnapshot,
    LineSnapshot,
    MachineSnapshot,
    axis_snapshot,
    error_record,
    line_snapshot,
    machine_snapshot,
)
from drivebus.bus import Bus, Priority, SlaveHandle
from drivebus.clock import monotonic
from drivebus.config import MachineConfig
from drivebus.drives.status import DriveStatus
from drivebus.errors import (
    ArgumentError,
    DrivebusError,
    LeaseHeld,
    MotionAborted,
    NotFound,
    StateError,
)
from drivebus.motion import (
    Axis,
    AxisState,
    BufferMode,
    GroupMotionError,
    GroupMoveReport,
    Machine,
    MotionEvent,
)
from drivebus.motion.handle import check_buffer
from drivebus.motion.machine import open_machine
from drivebus.motion.state import MOVING_STATES
from drivebus.tasks import shielded

__all__ = ["Lease", "MachineSession", "MotionRecord", "MotionState"]

log = logging.getLogger(__name__)

MotionState = Literal["running", "done", "aborted", "failed"]

_KEEP_FINISHED = 1000
"""Finished motion records kept for clients to look up."""


@dataclass
class MotionRecord:
    """A motion a client started: its id, what it is, and how it went."""

    id: str
    kind: str
    """"move", "home" or "group-move"."""
    axes: list[str]
    request: dict[str, Any]
    client: str | None = None
    state: MotionState = "running"
    error: DrivebusError | None = None
    result: dict[str, Any] | None = None
    started: float = field(default_factory=time.time)
    """Wall-clock time it was accepted."""
    finished: float | None = None
    done: anyio.Event = field(default_factory=anyio.Event, repr=False)
    scope: anyio.CancelScope | None = field(default=None, repr=False)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready data."""
        return {
            "id": self.id,
            "kind": self.kind,
            "axes": list(self.axes),
            "request": dict(self.request),
            "client": self.client,
            "state": self.state,
            "error": error_record(self.error),
            "result": self.result,
            "started": self.started,
            "finished": self.finished,
        }


@dataclass(frozen=True)
class Lease:
    """Who holds the command lease, and until when (monotonic seconds)."""

    holder: str
    expires: float

    @property
    def remaining(self) -> float:
        """Seconds left."""
        return max(0.0, self.expires - monotonic())


def _report(report: GroupMoveReport) -> dict[str, Any]:
    return {
        "duration": report.duration,
        "start_skew": report.start_skew,
        "arrival_spread": report.arrival_spread,
        "planned_arrival_spread": report.planned_arrival_spread,
        "observed_arrival_spread": report.observed_arrival_spread,
        "observed_resolution": report.observed_resolution,
    }


class MachineSession:
    """An open machine for many clients; build it with ``MachineSession.open(config)``."""

    def __init__(
        self, machine: Machine, tasks: anyio.abc.TaskGroup, *, stats_period: float = 0.5
    ) -> None:
        self.machine = machine
        self.events = EventHub()
        self.stats_period = stats_period
        self._tasks = tasks
        self._motions: OrderedDict[str, MotionRecord] = OrderedDict()
        self._ids = itertools.count(1)
        self._lease: Lease | None = None
        self._jogs: dict[str, str] = {}  # axis -> client whose jog it is
        self.recordings = Recordings(machine)
        """Recordings clients started (the dashboard's Record button)."""

    @classmethod
    @asynccontextmanager
    async def open(
        cls,
        config: str | Path | MachineConfig,
        *,
        stats_period: float = 0.5,
        stop_on_exit: bool = True,
        require_all: bool = True,
    ) -> AsyncIterator[MachineSession]:
        """Open the machine and serve it until the block ends; then every running motion
        is cancelled and every moving axis stopped (also when left by cancellation).
        ``require_all=False``: an axis whose drive does not answer starts Offline."""
        stats_period = checks.positive("stats_period", stats_period, unit="s")
        async with (
            open_machine(config, stop_on_exit=stop_on_exit, require_all=require_all) as machine,
            anyio.create_task_group() as tg,
        ):
            session = cls(machine, tg, stats_period=stats_period)
            for axis in machine.axes.values():
                tg.start_soon(session._pump_axis, axis, name=f"session pump {axis.name}")
            tg.start_soon(session._pump_lines, name="session line stats")
            try:
                yield session
            finally:
                session.recordings.close()
                tg.cancel_scope.cancel()

    # -- looking --------------------------------------------------------------------------

    @property
    def name(self) -> str:
        """The machine's name."""
        return self.machine.config.name

    def axis(self, name: str) -> Axis:
        """The axis called ``name``; ``NotFound`` naming the axes there are."""
        try:
            return self.machine.axes[name]
        except KeyError:
            raise NotFound(
                f"no axis {name!r} in machine {self.name} (axes: "
                f"{', '.join(self.machine.axes)})"
            ) from None

    def snapshot(self) -> MachineSnapshot:
        """The machine, its lines and axes as plain data."""
        return machine_snapshot(self.machine)

    def axis_snapshot(self, name: str) -> AxisSnapshot:
        """One axis as plain data (``NotFound`` if there is none)."""
        return axis_snapshot(self.axis(name))

    def motion(self, motion_id: str) -> MotionRecord:
        """The motion with ``motion_id``; ``NotFound`` if there is none (or it is long gone)."""
        try:
            return self._motions[motion_id]
        except KeyError:
            raise NotFound(f"no motion {motion_id!r}") from None

    def motions(self) -> list[MotionRecord]:
        """Every motion still known, oldest first."""
        return list(self._motions.values())

    # -- the command lease ----------------------------------------------------------------

    @property
    def lease(self) -> Lease | None:
        """The command lease if someone holds it."""
        if self._lease is not None and self._lease.remaining <= 0:
            self._lease = None
        return self._lease

    def acquire_lease(self, client: str, ttl: float) -> Lease:
        """Take (or renew) the command lease for ``ttl`` seconds; ``LeaseHeld`` if another
        client holds it."""
        ttl = checks.positive("ttl", ttl, unit="s")
        self.authorize(client)
        self._lease = Lease(client, monotonic() + ttl)
        self._publish_lease()
        return self._lease

    def release_lease(self, client: str) -> None:
        """Give the lease back (a no-op if ``client`` does not hold it)."""
        if self.lease is not None and self.lease.holder == client:
            self._lease = None
            self._publish_lease()

    def authorize(self, client: str | None) -> None:
        """``LeaseHeld`` if another client than ``client`` holds the command lease."""
        lease = self.lease
        if lease is not None and lease.holder != client:
            raise LeaseHeld(
                f"the command lease is held by {lease.holder} for another "
                f"{lease.remaining:.1f} s",
                holder=lease.holder,
            )

    def _publish_lease(self) -> None:
        lease = self.lease
        self.events.publish(Event("motions", None, {
            "type": "lease",
            "holder": None if lease is None else lease.holder,
            "remaining": None if lease is None else lease.remaining,
        }))

    # -- motions with an id ---------------------------------------------------------------

    async def start_move(
        self,
        axis: str,
        *,
        target: float | None = None,
        by: float | None = None,
        speed: float | None = None,
        accel: float | None = None,
        decel: float | None = None,
        buffer: BufferMode = "aborting",
        client: str | None = None,
    ) -> MotionRecord:
        """Start a move to ``target`` or by ``by``; returns once the axis accepted it
        (a refusal raises: bad argument, limit, state, lease) with its record running.

        ``buffer`` as for ``Axis.move_to``: ``"aborting"`` takes over the motion under way
        where the drive takes a new target on the fly (that motion's record ends
        ``aborted``), else it is a ``StateError``; ``"buffered"`` and ``"blending"`` queue
        it behind the motions under way (its record runs until it is done, and its
        ``result`` says how it ran: ``runs``, ``reason``)."""
        if (target is None) == (by is None):
            raise ArgumentError("a move takes exactly one of 'target' and 'by'")
        buffer = check_buffer(buffer)
        ax = self.axis(axis)
        self.authorize(client)
        request = {k: v for k, v in
                   {"target": target, "by": by, "speed": speed, "accel": accel,
                    "decel": decel, "buffer": buffer}.items() if v is not None}

        async def run(accepted: Callable[[], object]) -> dict[str, Any] | None:
            if target is not None:
                handle = await ax.move_to(target, speed=speed, accel=accel, decel=decel,
                                          buffer=buffer, accepted=accepted)
            else:
                assert by is not None
                handle = await ax.move_by(by, speed=speed, accel=accel, decel=decel,
                                          buffer=buffer, accepted=accepted)
            if handle is None:
                return None
            await handle
            plan = handle.plan
            return {"runs": plan.runs, "reason": plan.reason, "blend_speed": plan.blend_speed}

        return await self._launch("move", [axis], request, run, client)

    async def start_home(self, axis: str, *, client: str | None = None) -> MotionRecord:
        """Start the axis's homing; returns once accepted (see ``start_move``)."""
        ax = self.axis(axis)
        self.authorize(client)

        async def run(accepted: Callable[[], object]) -> None:
            await ax.home(accepted=accepted)

        return await self._launch("home", [axis], {}, run, client)

    async def start_group_move(
        self, targets: Mapping[str, float], *, client: str | None = None
    ) -> MotionRecord:
        """Start a coordinated move of several axes to ``targets``; returns once accepted."""
        if not isinstance(targets, Mapping) or not targets:
            raise ArgumentError("targets: expected a non-empty mapping of axis name to target")
        for name in targets:
            self.axis(name)
        self.authorize(client)
        group = self.machine.group(*targets)

        async def run(accepted: Callable[[], object]) -> dict[str, Any]:
            return _report(await group.move_to(targets, accepted=accepted))

        return await self._launch("group-move", list(targets), {"targets": dict(targets)},
                                  run, client)

    async def _launch(
        self,
        kind: str,
        axes: list[str],
        request: dict[str, Any],
        run: Callable[[Callable[[], object]], Awaitable[Any]],
        client: str | None,
    ) -> MotionRecord:
        record = MotionRecord(f"m{next(self._ids)}", kind, axes, request, client)

        async def body(*, task_status: anyio.abc.TaskStatus[None]) -> None:
            accepted = False

            def accept() -> None:
                nonlocal accepted
                if not accepted:
                    accepted = True
                    self._remember(record)
                    self._motion_event(record, "started")
                    task_status.started()

            scope = record.scope = anyio.CancelScope()
            try:
                with scope:
                    result = await run(accept)
                    accept()
                    record.result = result if isinstance(result, dict) else None
            except DrivebusError as exc:
                if not accepted:
                    raise  # refused: the caller of start_... hears it
                self._finish(record, "aborted" if _is_abort(exc) else "failed", exc)
                return
            except BaseException:  # cancelled from outside: the session is closing
                if accepted:  # its axes were stopped (shielded) before this came
                    self._finish(record, "aborted", MotionAborted(
                        f"the {kind} of {', '.join(axes)} was cut short: the machine "
                        f"session is closing"))
                raise
            finally:
                record.scope = None
            if scope.cancelled_caught:
                self._finish(record, "aborted", MotionAborted(
                    f"the {kind} of {', '.join(axes)} was cancelled by a client"))
            else:
                self._finish(record, "done", None)

        await self._tasks.start(body, name=f"session motion {record.id}")
        return record

    def _remember(self, record: MotionRecord) -> None:
        self._motions[record.id] = record
        while len(self._motions) > _KEEP_FINISHED:
            oldest = next(iter(self._motions.values()))
            if oldest.state == "running":
                break
            self._motions.popitem(last=False)

    def _finish(
        self, record: MotionRecord, state: MotionState, error: DrivebusError | None
    ) -> None:
        record.state, record.error, record.finished = state, error, time.time()
        record.done.set()
        self._motion_event(record, state)

    def _motion_event(self, record: MotionRecord, what: str) -> None:
        self.events.publish(Event("motions", None, {
            "type": "motion", "event": what, **record.as_dict(),
        }))

    async def cancel_motion(self, motion_id: str, *, client: str | None = None) -> MotionRecord:
        """Cancel a running motion: its axes are stopped; returns once they are at rest."""
        record = self.motion(motion_id)
        self.authorize(client)
        if record.state == "running" and record.scope is not None:
            record.scope.cancel()
            await record.done.wait()
            async with anyio.create_task_group() as tg:
                for name in record.axes:
                    tg.start_soon(self.axis(name).stop)
        return record

    # -- direct commands (they return when done) ------------------------------------------

    async def stop(self, axis: str, *, decel: float | None = None,
                   client: str | None = None) -> None:
        """Decelerating stop; returns at rest."""
        ax = self.axis(axis)
        self.authorize(client)
        self._jogs.pop(axis, None)
        await ax.stop(decel=decel)

    async def halt(self, axis: str, *, client: str | None = None) -> None:
        """Emergency stop of one axis; returns at rest. Never refused by a lease."""
        ax = self.axis(axis)
        self._jogs.pop(axis, None)
        await ax.halt_now()

    async def enable(self, axis: str, *, client: str | None = None) -> None:
        """Energise the motor."""
        ax = self.axis(axis)
        self.authorize(client)
        await ax.enable()

    async def disable(self, axis: str, *, client: str | None = None) -> None:
        """De-energise the motor (at rest)."""
        ax = self.axis(axis)
        self.authorize(client)
        await ax.disable()

    async def reset(self, axis: str, *, client: str | None = None) -> None:
        """Leave ErrorStop (clear the drive's alarm if it has one)."""
        ax = self.axis(axis)
        self.authorize(client)
        await ax.reset()

    async def estop(self) -> dict[str, dict[str, str] | None]:
        """Emergency-stop every axis at once; never refused, never queued behind anything.

        Returns each axis's outcome (None: at rest; else the typed error as data).
        """
        self._jogs.clear()
        self.events.publish(Event("motions", None, {"type": "estop", "event": "requested"}))
        outcome = {name: None if exc is None else error_record(exc)
                   for name, exc in (await self.machine.halt_now()).items()}
        self.events.publish(Event("motions", None, {
            "type": "estop", "event": "done", "axes": outcome,
        }))
        return outcome

    async def stop_all(self) -> dict[str, dict[str, str] | None]:
        """Decelerating stop of every axis that is moving (never refused by a lease): what a
        service does before it exits. Returns the outcome of each axis it stopped (None: at
        rest; else the typed error as data); an empty mapping if none was moving."""
        self._jogs.clear()
        outcome: dict[str, dict[str, str] | None] = {}

        async def stop(ax: Axis) -> None:
            try:
                await ax.stop()
                outcome[ax.name] = None
            except DrivebusError as exc:
                outcome[ax.name] = error_record(exc)

        async with anyio.create_task_group() as tg:
            for ax in self.machine.axes.values():
                if ax.state in MOVING_STATES or (ax.status is not None and ax.status.moving):
                    tg.start_soon(stop, ax)
        return outcome

    # -- jogs held by a client --------------------------------------------------------------

    async def jog(
        self,
        axis: str,
        speed: float,
        *,
        ttl: float = 0.5,
        client: str | None = None,
        accel: float | None = None,
        decel: float | None = None,
        owner: str | None = None,
        accepted: Callable[[], object] | None = None,
    ) -> None:
        """Jog at ``speed`` for a client: it stops ``ttl`` seconds after the last call
        unless fed by another (the same speed feeds, another changes it; 0 stops).
        ``accepted()`` is called once the axis has taken it (every check passed).

        The jog is held by ``owner`` (default: ``client``): ``release(owner)`` stops it.
        A front end passes one owner per connection, so that a connection that goes away
        stops its own jogs while the lease is still checked against the client.
        """
        ax = self.axis(axis)
        ttl = checks.positive("ttl", ttl, unit="s")
        self.authorize(client)
        if checks.finite("speed", speed) == 0:
            self._jogs.pop(axis, None)
            if accepted is not None:
                accepted()
            await ax.stop()
            return
        await ax.jog(speed, watchdog=ttl, accel=accel, decel=decel, accepted=accepted)
        self._jogs[axis] = owner or client or ""

    async def release(self, client: str) -> None:
        """A client (or a jog owner) went away: stop the jogs it holds that are still
        running and give its lease back."""
        self.release_lease(client)
        held = [a for a, c in self._jogs.items() if c == client]
        for a in held:
            self._jogs.pop(a, None)
        # A jog its watchdog already ended may have been followed by another client's
        # motion: that one is not ours to stop.
        mine = [a for a in held if self.axis(a).state is AxisState.CONTINUOUS_MOTION]

        async def stop_mine() -> None:
            async with anyio.create_task_group() as tg:
                for a in mine:
                    tg.start_soon(self._stop_quietly, self.axis(a))

        await shielded(stop_mine)  # (a second cancel does not cut the stops short)

    @staticmethod
    async def _stop_quietly(axis: Axis) -> None:
        try:
            await axis.stop()
        except DrivebusError as exc:
            log.error("axis %s: stop after its client left failed: %s", axis.name, exc)

    # -- drive parameters (backup, compare, restore) ------------------------------------------

    async def read_parameters(self, axis: str) -> ParameterSet:
        """Every documented parameter of ``axis``'s drive, read between its polls (reads
        only: a viewing operation)."""
        ax = self.axis(axis)
        about = {"machine": self.name, "axis": axis, "line": ax.config.line,
                 "address": ax.config.address}
        return await read_parameters(ax.profile, about=about)

    async def load_parameters(
        self, axis: str, values: Mapping[str, int], *, save: bool = False,
        dry_run: bool = False, include_comms: bool = False, client: str | None = None,
    ) -> LoadReport:
        """Write the parameters of ``values`` that differ from the drive's (``load_parameters``
        of ``drivebus.app.params``); refused while the axis moves, and by the lease."""
        ax = self.axis(axis)
        wanted = ParameterSet.from_mapping(ax.profile.family, values,
                                           ax.profile.description_file)
        if not dry_run:
            self.authorize(client)
            if ax.state in MOVING_STATES:
                raise StateError(f"axis {axis} is {ax.state}: parameters are loaded at rest")
        return await load_parameters(ax.profile, wanted, save=save, dry_run=dry_run,
                                     include_comms=include_comms)
    # -- motion programs: taught positions, speed override, digital I/O ---------------------

    async def start_position_move(
        self, name: str, *, speed: float | None = None, duration: float | None = None,
        client: str | None = None,
    ) -> MotionRecord:
        """Start a move of a taught position's axes there, together; returns once
        accepted (``NotFound`` naming the positions if there is none)."""
        targets = self.machine.position(name)
        self.authorize(client)
        group = self.machine.group(*targets)

        async def run(accepted: Callable[[], object]) -> dict[str, Any]:
            report = await group.move_to(targets, speed=speed, duration=duration,
                                         accepted=accepted)
            assert isinstance(report, GroupMoveReport)
            return _report(report)

        request = {k: v for k, v in {"position": name, "speed": speed,
                                     "duration": duration}.items() if v is not None}
        return await self._launch("group-move", list(targets), request, run, client)

    async def teach(self, name: str, axes: list[str] | None = None, *,
                    client: str | None = None) -> dict[str, float]:
        """Store the axes' present positions as ``name`` (``Machine.teach``); ``NotFound``
        for an unknown axis."""
        self.authorize(client)
        for axis in axes or ():
            self.axis(axis)
        stored = await self.machine.teach(name, axes)
        self.events.publish(Event("motions", None, {
            "type": "position", "name": name, "axes": stored}))
        return stored

    def set_override(self, factor: float, *, axis: str | None = None,
                     client: str | None = None) -> float:
        """Set the machine's speed override (or ``axis``'s own); returns the factor the
        axis (or the machine) now applies. Not refused by the lease: slowing down is
        always allowed; speeding up is a command and needs it."""
        factor = checks.finite("override", factor)
        current = self.machine.override if axis is None else self.axis(axis).override
        if factor > current:
            self.authorize(client)
        if axis is None:
            self.machine.override = factor
            value = self.machine.override
        else:
            self.axis(axis).override = factor
            value = self.axis(axis).effective_override
        self.events.publish(Event("motions", None, {
            "type": "override", "axis": axis, "factor": factor}))
        return value

    async def set_output(self, axis: str, output: str, state: bool, *,
                         client: str | None = None) -> None:
        """Switch an output of ``axis``'s drive (``Axis.set_output``)."""
        ax = self.axis(axis)
        self.authorize(client)
        await ax.set_output(output, state)

    # -- raw registers (commissioning, tools that talk to a running service) ----------------

    def line(self, name: str) -> Bus:
        """The bus of line ``name``; ``NotFound`` naming the lines there are."""
        try:
            return self.machine.buses[name]
        except KeyError:
            raise NotFound(
                f"no line {name!r} in machine {self.name} (lines: "
                f"{', '.join(self.machine.buses)})"
            ) from None

    def line_snapshot(self, name: str) -> LineSnapshot:
        """One line as plain data (``NotFound`` if there is none)."""
        bus = self.line(name)
        cfg = self.machine.config.lines[name]
        endpoint = cfg.port or f"{cfg.host}:{cfg.tcp_port}"
        return line_snapshot(name, bus, cfg.kind, endpoint)

    def _slave(self, line: str, address: int) -> SlaveHandle:
        """The handle for ``address`` on ``line``: the axis's own (its settings and the
        vendor's exception texts) if an axis sits there, else one at the line's settings."""
        bus = self.line(line)
        for ax in self.machine.axes.values():
            if ax.config.line == line and ax.config.address == address:
                return ax.profile.slave
        return bus.slave(address)

    async def read_registers(
        self, line: str, address: int, register: int, count: int = 1, *, input: bool = False
    ) -> list[int]:
        """Read ``count`` holding (or ``input``) registers from slave ``address`` on ``line``.
        Needs no lease. At ``Priority.POLL``, in turn with the axes' polls: a client
        reading in a loop never starves them (nor delays a command)."""
        address = checks.whole("address", address, 1, 247)
        register = checks.whole("register", register, 0, 0xFFFF)
        count = checks.whole("count", count, 1, 125)
        if register + count > 0x10000:
            raise ArgumentError(f"register {register} + count {count} passes 65535")
        h = self._slave(line, address)
        if input:
            return await h.read_input_registers(register, count, priority=Priority.POLL)
        return await h.read_holding_registers(register, count, priority=Priority.POLL)

    async def write_registers(
        self,
        line: str,
        address: int,
        register: int,
        values: list[int],
        *,
        client: str | None = None,
    ) -> None:
        """Write ``values`` to consecutive registers of slave ``address`` on ``line`` (one
        value: FC06, more: FC16; address 0 broadcasts), never retried: a raw write may be
        a command. Bypasses the axes: for commissioning; the lease applies."""
        address = checks.whole("address", address, 0, 247)
        register = checks.whole("register", register, 0, 0xFFFF)
        if not isinstance(values, list | tuple) or not 1 <= len(values) <= 123:
            raise ArgumentError("values: expected a list of 1 to 123 register values")
        words = [checks.whole(f"values[{i}]", v, 0, 0xFFFF) for i, v in enumerate(values)]
        if register + len(words) > 0x10000:
            raise ArgumentError(f"register {register} + {len(words)} values passes 65535")
        h = self._slave(line, address)
        self.authorize(client)
        if len(words) == 1:
            await h.write_register(register, words[0], idempotent=False)
        else:
            await h.write_registers(register, words, idempotent=False)

    # -- event pumps ------------------------------------------------------------------------

    async def _pump_axis(self, axis: Axis) -> None:
        last_state = axis.state
        polled: tuple[DriveStatus, float | None] | None = None

        def take_target(item: DriveStatus | MotionEvent) -> None:
            # The target as each status comes in: this task runs later, perhaps after a
            # command set another target (the page charts each poll with its own).
            nonlocal polled
            if isinstance(item, DriveStatus):
                polled = (item, axis.target)

        unlisten = axis.listen(take_target)
        try:
            async for _ in axis.watch():
                snap = axis_snapshot(axis, target_at=polled)
                self.events.publish(Event("axes", axis.name, {
                    "type": "axis", "axis": axis.name, **snap.as_dict(),
                }))
                if axis.state is not last_state and axis.state in (
                    AxisState.ERROR_STOP, AxisState.OFFLINE
                ):
                    self.events.publish(Event("errors", None, {
                        "type": "error", "axis": axis.name, "state": str(axis.state),
                        "error": error_record(axis.error),
                    }))
                last_state = axis.state
        finally:
            unlisten()

    async def _pump_lines(self) -> None:
        while True:
            for name in self.machine.buses:
                snap = self.line_snapshot(name)
                self.events.publish(Event("lines", name, {"type": "line", **snap.as_dict()}))
                await anyio.lowlevel.checkpoint()  # (a line's snapshot at a time: many lines)
            await anyio.sleep(self.stats_period)


def _is_abort(exc: DrivebusError) -> bool:
    """A stop (or a cancellation) ended it, rather than a fault."""
    if isinstance(exc, GroupMotionError):
        return isinstance(exc.__cause__, MotionAborted)
    return isinstance(exc, MotionAborted)
