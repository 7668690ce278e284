"""The promise matrix: every public command that moves or writes, against the promises a
stop, a cancellation, a refusal and leaving the machine make. Judged by the simulated
twins and the wire log of the demo machine, never by the axes' own view.

A command joins the matrix by one line in ``COMMANDS``: what it moves (``axes``), how it
runs from rest (``run``), an axis on the same RS-485 line it leaves alone (``bystander``)
and a call of it that must be refused (``refuse``). The promises:

- (a) a stop of the command's own axis, or of another (jogging) axis on its line, issued
  while it plans and sets up or while it moves, reaches the wire within one transaction
  of the line (at most one other request frame leaves between the call and the stop
  frame), and nothing of the command starts after it;
- (b) cancelling the command's caller stops what it started: its axes' twins at rest;
- (c) a refusal (a typed error) sends nothing: no write frame on any line;
- (d) leaving the machine, however its owner leaves (the block's end, an exception, a
  cancellation, a native cancellation twice), leaves every axis at rest.

The HTTP and MQTT routes of these commands are in ``test_promises_frontends.py``; a stop
during group planning, the loop-step guard (``conftest.py``) bounds every event-loop step
of every test.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

import anyio
import anyio.lowlevel
import pytest

from drivebus import open_machine
from drivebus.app.params import ParameterSet, load_parameters, read_parameters
from drivebus.errors import DrivebusError, GroupMotionError, MotionAborted
from drivebus.motion import Machine
from machines import Machinefile, demo_machine
from wirelog import (
    command_frames,
    frames_text,
    log_size,
    requests_between,
    settle,
    write_frames,
)


@pytest.fixture(params=[0, 1], ids=["in process", "1 worker"])
def demo(request: pytest.FixtureRequest) -> Machinefile:
    """The demo machine, its lines served by this process or by a worker process (the
    promises hold across the process boundary too)."""
    return demo_machine(request.param)


RS485 = ("x", "y", "z")
"""The demo's moving axes on its RS-485 line (r is on Modbus TCP, aux cannot move)."""

Run = Callable[[Machine], Awaitable[Any]]


def far(m: Machine, name: str, fraction: float = 0.8) -> float:
    """A target across the axis's soft limits from where it is (a long move)."""
    ax = m.axes[name]
    lo, hi = ax.config.limits or (-100.0, 100.0)
    pos = ax.position or 0.0
    return lo + (hi - lo) * (fraction if pos < (lo + hi) / 2 else 1 - fraction)


async def jog_forever(m: Machine, name: str, speed: float) -> None:
    """Jog ``name`` toward the far side until cancelled (stops on leaving)."""
    ax = m.axes[name]
    sign = 1.0 if (ax.position or 0.0) < far(m, name, 0.5) else -1.0
    async with ax.jogging(sign * speed):
        await anyio.sleep_forever()


async def buffered(m: Machine) -> None:
    x = m.axes["x"]
    first, second = far(m, "x", 0.5), far(m, "x")
    await x.move_to(first, speed=60.0, buffer="buffered")
    handle = await x.move_to(second, speed=60.0, buffer="buffered")
    assert handle is not None
    await handle


async def load_out_of_range(m: Machine) -> None:
    profile = m.axes["x"].profile
    current = await read_parameters(profile)
    key = next(iter(current.values))
    await load_parameters(profile, ParameterSet(current.family, {key: 10**9}))


@dataclass(frozen=True)
class Command:
    """One public command that moves or writes, as the matrix runs it."""

    name: str
    axes: tuple[str, ...]
    run: Run | None
    bystander: str | None
    refuse: Run


COMMANDS = [
    Command("move_to", ("x",), lambda m: m.axes["x"].move_to(far(m, "x"), speed=40.0), "z",
            lambda m: m.axes["x"].move_to(1000.0)),
    Command("move_by", ("y",), lambda m: m.axes["y"].move_by(
        far(m, "y") - (m.axes["y"].position or 0.0), speed=20.0), "z",
            lambda m: m.axes["y"].move_by(1e6)),
    Command("jog", ("z",), lambda m: jog_forever(m, "z", 5.0), "x",
            lambda m: m.axes["z"].jog(math.nan)),
    Command("home", ("x",), lambda m: m.axes["x"].home(), "z",
            lambda m: m.axes["aux"].home()),
    Command("buffered moves", ("x",), buffered, "y",
            lambda m: m.axes["x"].move_to(1000.0, buffer="buffered")),
    Command("group.move_to", ("x", "y", "r"), lambda m: m.group("x", "y", "r").move_to(
        {"x": far(m, "x"), "y": far(m, "y"), "r": far(m, "r")}), "z",
            lambda m: m.group("x", "y").move_to({"x": 10.0, "y": 500.0})),
    Command("group.path", ("x", "y"), lambda m: m.group("x", "y").path(
        [{"x": far(m, "x", 0.4)}, {"y": far(m, "y", 0.6)}, {"x": far(m, "x", 0.7)}],
        speed=40.0), "z",
            lambda m: m.group("x", "y").path([{"x": 20.0}, {"y": -50.0}])),
    Command("machine.move_to", ("x", "z"), lambda m: m.move_to(
        {"x": far(m, "x"), "z": far(m, "z")}), "y",
            lambda m: m.move_to("no such position")),
    Command("run_table", ("x",), lambda m: m.axes["x"].run_table(
        [far(m, "x", 0.3), far(m, "x", 0.6), far(m, "x", 0.4)], speed=60.0,
        trigger_input="IN5"), "z",
            lambda m: m.axes["y"].run_table([10.0, 20.0], trigger_input="X3")),
    Command("set_output", (), None, None, lambda m: m.axes["y"].set_output("Y1", True)),
    Command("set_output CL86R", (), None, None, lambda m: m.axes["z"].set_output("Y0", True)),
    Command("params load", (), None, None, load_out_of_range),
]

MOVING = [c for c in COMMANDS if c.run is not None]


def ids(c: Command) -> str:
    return c.name


async def until(what: str, ok: Callable[[], bool], timeout: float = 20.0) -> None:
    """Wait (bounded, polling the twins at 5 ms) until ``ok()``; fail naming ``what``."""
    with anyio.move_on_after(timeout):
        while not ok():  # noqa: ASYNC110 (the twins have no events: they are polled)
            await anyio.sleep(0.005)
        return
    pytest.fail(f"{what} did not happen within {timeout:g} s")


def twins_at_rest(m: Machine, names: tuple[str, ...] | list[str]) -> list[str]:
    """The named axes whose twin still moves (empty: all at rest)."""
    return [n for n in names if m.sim_drives[n].is_moving()]


class Running:
    """A command run from rest in a task (``main``), and how it ended (``ended``, None
    while it runs or once cancelled), for ``reach`` to name rather than wait out."""

    def __init__(self, c: Command, m: Machine) -> None:
        self.c = c
        self.m = m
        self.ended: str | None = None

    async def main(self) -> None:
        """The command; its end by a stop or a cancellation is taken as such (judged by
        the twins and the wire)."""
        assert self.c.run is not None
        try:
            await self.c.run(self.m)
        except (MotionAborted, GroupMotionError) as exc:
            self.ended = f"ended with {exc!r}"
        else:
            self.ended = "returned"


async def reach(m: Machine, run: Running, point: str) -> None:
    """Let the command reach ``point``: "setup" (a few loop turns in: it plans, checks
    and writes its set-up), "moving" (its first axis's twin moves)."""
    if point == "setup":
        for _ in range(3):
            await anyio.lowlevel.checkpoint()
        return
    c = run.c
    ax = m.axes[c.axes[0]]
    twin = m.sim_drives[ax.name]
    try:
        await until(f"{c.name}: axis {ax.name} moving",
                    lambda: twin.is_moving() or run.ended is not None)
        if not twin.is_moving():
            pytest.fail(f"{c.name} {run.ended} before axis {ax.name} moved")
    except pytest.fail.Exception as exc:  # what the axis and its line did meanwhile
        exc.add_note(f"axis {ax.name}: {ax.state.name}, error {ax.error!r}, queued {ax.queued}; "
                     f"its line's last frames:\n"
                     f"{frames_text(m.wires[ax.config.line].log, limit=40)}")  # type: ignore[union-attr]
        raise


def check_stop(m: Machine, name: str, mark: int, called: float, what: str) -> None:
    """After ``name``'s stop (called at ``called``): its stop frame left within one
    transaction of the call, no start frame of it after that, its twin at rest.

    With the line in a worker process, the transaction counts from when the worker took
    the stop (``RemoteBus.stops_taken``, on the host's clock): the hop between the
    processes is the operating system's scheduling, which the bench's scale scenario
    measures (the stop latency across processes), not a transaction of the line."""
    frames = command_frames(m, name, mark)
    stops = [t for k, t in frames if k == "stop" and t > called]
    if stops:
        line = m.axes[name].config.line
        taken = [t for t in getattr(m.buses[line], "stops_taken", ()) if t > called]
        since = taken[0] if taken else called
        between = requests_between(m, line, since, stops[0])
        assert between <= 1, (what, f"{between} request frames left before the stop")
        after = stops[0]
    else:
        after = called  # nothing ran: nothing may start after the call either
    starts = [t for k, t in frames if k == "start" and t > after]
    assert not starts, (what, frames)
    assert not m.sim_drives[name].is_moving(), what


# -- (a) a stop wins -------------------------------------------------------------------


@pytest.mark.parametrize("c", MOVING, ids=ids)
async def test_a_stop_of_its_own_axis_wins_at_every_point(c: Command, demo: Machinefile) -> None:
    async with open_machine(demo) as m:
        for point in ("setup", "moving"):
            for n in c.axes:
                await settle(m.axes[n])
            ax = m.axes[c.axes[0]]
            mark = log_size(m, ax.name)
            with anyio.fail_after(60):
                async with anyio.create_task_group() as tg:
                    run = Running(c, m)
                    tg.start_soon(run.main)
                    await reach(m, run, point)
                    called = time.monotonic()
                    await ax.stop()
                    if c.name == "jog":
                        tg.cancel_scope.cancel()  # a jog held by its block: leave it
            check_stop(m, ax.name, mark, called, f"{c.name} stopped at {point}")
            assert not twins_at_rest(m, c.axes), (c.name, point)


@pytest.mark.parametrize("c", [c for c in MOVING if c.bystander in RS485], ids=ids)
async def test_a_stop_of_another_axis_on_its_line_is_never_held_up(
    c: Command, demo: Machinefile,
) -> None:
    async with open_machine(demo) as m:
        assert c.bystander is not None
        by = m.axes[c.bystander]
        for point in ("setup", "moving"):
            for n in (*c.axes, by.name):
                await settle(m.axes[n])
            await by.jog(2.0 if (by.position or 0.0) < far(m, by.name, 0.5) else -2.0,
                         watchdog=None)
            await until(f"the bystander {by.name} moving",
                        lambda: m.sim_drives[by.name].is_moving())
            mark = log_size(m, by.name)
            with anyio.fail_after(60):
                async with anyio.create_task_group() as tg:
                    run = Running(c, m)
                    tg.start_soon(run.main)
                    await reach(m, run, point)
                    called = time.monotonic()
                    await by.stop()
                    check_stop(m, by.name, mark, called, f"{by.name} during {c.name} {point}")
                    tg.cancel_scope.cancel()  # the command itself: (b) says it stops
            assert not twins_at_rest(m, [*c.axes, by.name]), (c.name, point)


GROUPS = [c for c in MOVING if c.name.startswith("group.")]


@pytest.mark.parametrize("c", GROUPS, ids=ids)
async def test_a_stop_goes_out_before_the_stops_it_leads_to(
        c: Command, demo: Machinefile) -> None:
    """A stop of one axis of a group move or path stops the group: that axis's own stop is
    the first stop frame on its line, whichever loop step of the command it meets (its
    I/O in flight, a round trip to a worker under way). It had waited for the aborted
    I/O to end first, while the group's other stops went out ahead of it."""
    async with open_machine(demo) as m:
        first, other = c.axes[0], c.axes[1]
        for steps in range(0, 20, 4):
            for n in c.axes:
                await settle(m.axes[n])
            marks = {n: log_size(m, n) for n in (first, other)}
            with anyio.fail_after(60):
                async with anyio.create_task_group() as tg:
                    run = Running(c, m)
                    tg.start_soon(run.main)
                    for _ in range(steps):
                        await anyio.lowlevel.checkpoint()
                    called = time.monotonic()
                    await m.axes[first].stop()
            stops = {n: [t for k, t in command_frames(m, n, marks[n]) if k == "stop"
                         and t > called] for n in (first, other)}
            if stops[other]:
                assert stops[first] and stops[first][0] < stops[other][0], (
                    c.name, steps, stops)
            assert not twins_at_rest(m, c.axes), (c.name, steps)


# -- (b) cancelling the caller stops what it started --------------------------------------


@pytest.mark.parametrize("c", MOVING, ids=ids)
async def test_cancelling_its_caller_stops_what_it_started(c: Command, demo: Machinefile) -> None:
    async with open_machine(demo) as m:
        for point in ("setup", "moving"):
            for n in c.axes:
                await settle(m.axes[n])
            with anyio.fail_after(60):
                async with anyio.create_task_group() as tg:
                    run = Running(c, m)
                    tg.start_soon(run.main)
                    await reach(m, run, point)
                    tg.cancel_scope.cancel()
            # the cancelled caller's shielded stop confirmed rest before it re-raised;
            # the twins are asked right away
            assert not twins_at_rest(m, c.axes), (c.name, point)


@pytest.mark.parametrize("c", MOVING, ids=ids)
async def test_cancelling_its_caller_twice_stops_what_it_started(
        c: Command, demo: Machinefile) -> None:
    """asyncio's own ``Task.cancel()`` twice in a row (a teardown, a timeout and an outer
    cancel): an anyio shield does not hold off the second, which cut the cancelled
    motion's stop short: no stop sent, the motor running, the axis left Stopping."""
    async with open_machine(demo) as m:
        for n in c.axes:
            await settle(m.axes[n])
        run = Running(c, m)
        task = asyncio.ensure_future(run.main())
        with anyio.fail_after(60):
            await reach(m, run, "moving")
            seen = 0  # under way: two statuses polled show the axis moving
            async for st in m.axes[c.axes[0]].watch():
                seen += st.moving
                if seen == 2:
                    break
            task.cancel()
            await anyio.lowlevel.checkpoint()  # the first is taken: its stop is on its way
            task.cancel()
            with pytest.raises(asyncio.CancelledError):
                await task
        assert not twins_at_rest(m, c.axes), c.name


# -- (c) a refusal sends nothing -----------------------------------------------------------



@pytest.mark.parametrize("c", COMMANDS, ids=ids)
async def test_a_refusal_sends_nothing(c: Command, demo: Machinefile) -> None:
    async with open_machine(demo) as m:
        for ax in m.axes.values():
            await settle(ax)
        before = write_frames(m)
        with pytest.raises(DrivebusError):
            await c.refuse(m)
        for ax in m.axes.values():  # a full poll round later: still nothing written
            await ax.refresh()
        assert write_frames(m) == before, c.name


# -- (d) leaving the machine leaves every axis at rest ---------------------------------------


class _Leaving(logging.Handler):
    def __init__(self) -> None:
        super().__init__()
        self.said: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.said.append(record.getMessage())


class _Boom(Exception):
    pass


@pytest.mark.parametrize("how", ["exit", "exception", "cancel", "native cancel twice"])
@pytest.mark.parametrize("c", MOVING, ids=ids)
async def test_leaving_the_machine_leaves_every_axis_at_rest(
    c: Command, how: str, demo: Machinefile,
) -> None:
    twins: dict[str, Any] = {}
    moving = anyio.Event()

    async def owner() -> None:
        async with open_machine(demo) as m:
            twins.update(m.sim_drives)
            for n in c.axes:
                await settle(m.axes[n])
            if how == "exit" and c.name == "jog":
                await m.axes["z"].jog(5.0 if (m.axes["z"].position or 0) < 50 else -5.0,
                                      watchdog=None)  # runs on with no task: exit stops it
                await until("z moving", lambda: m.sim_drives["z"].is_moving())
                return
            async with anyio.create_task_group() as tg:
                run = Running(c, m)
                tg.start_soon(run.main)
                await reach(m, run, "moving")
                moving.set()
                if how == "exception":
                    raise _Boom
                if how == "exit":
                    tg.cancel_scope.cancel()
                    return
                await anyio.sleep_forever()

    said = _Leaving()
    logging.getLogger("drivebus.motion.machine").addHandler(said)
    try:
        with anyio.fail_after(90):
            if how in ("exit",):
                await owner()
            elif how == "exception":
                with pytest.raises(BaseExceptionGroup) as caught:
                    await owner()
                if not caught.group_contains(_Boom):
                    raise caught.value  # (whatever came instead, with its notes)
            elif how == "cancel":
                async with anyio.create_task_group() as tg:
                    tg.start_soon(owner)
                    await moving.wait()
                    tg.cancel_scope.cancel()
            else:
                task = asyncio.get_running_loop().create_task(owner())
                await moving.wait()
                task.cancel()
                await until("the owner to begin leaving", lambda: task.done() or any(
                    s.startswith("leaving machine") for s in said.said))
                task.cancel()  # again, while it stops the axes
                with pytest.raises(asyncio.CancelledError):
                    await task
    finally:
        logging.getLogger("drivebus.motion.machine").removeHandler(said)
    still = [n for n, t in twins.items() if t.is_moving()]
    assert not still, (c.name, how, still, said.said)
