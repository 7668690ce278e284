"""The promises checked from outside: tests written from the README, the guide and the
API reference only, on the demo machine's simulator, for combinations the promise
matrix (``test_promises.py``) does not reach:

- a stop or an emergency stop of ONE axis of a group move, a path or a motion program,
  given from another task, or from an axis on another line;
- a program's task cancelled twice (natively, as asyncio's teardown does), an
  exception in the machine's block while queued programs run, the machine left while
  a group move runs in a task that outlives it;
- the feed override raised while a jog or a move runs toward a soft limit, and bad
  overrides during a motion;
- the whole machine stopped (``stop_all``, ``halt_now``) while a path is planned;
- the stop latency while a long path is planned, while a group move sends its starts,
  while another axis is set up and while polls saturate the line.

Safety is judged by the simulated drives (``m.sim_drives``) and the wire log, never by
the axes' own view: every axis of the command at rest on its twin, no start frame of
it after its stop frame, the twin's travel within the soft limits."""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import anyio
import anyio.lowlevel
import pytest

from drivebus import AxisState, LineSettings, Priority, open_machine
from drivebus.app import MachineSession
from drivebus.errors import (
    ArgumentError,
    DrivebusError,
    GroupMotionError,
    LimitViolation,
    MotionAborted,
)
from drivebus.motion import Axis, Machine
from machines import DEMO, Machinefile, demo_machine
from waits import until, within
from wirelog import (
    command_frames,
    commands,
    frames_text,
    log_size,
    requests_between,
    settle,
    write_frames,
)


@pytest.fixture(params=[0, 1], ids=["in process", "1 worker"])
def demo(request: pytest.FixtureRequest) -> Machinefile:
    """The demo machine, its lines in this process or in one worker process."""
    return demo_machine(request.param)


def at_rest(m: Machine, names: list[str] | tuple[str, ...]) -> list[str]:
    """The named axes whose twin still moves (empty: all at rest)."""
    return [n for n in names if m.sim_drives[n].is_moving()]


def moving(m: Machine, name: str) -> Callable[[], bool]:
    return lambda: bool(m.sim_drives[name].is_moving())


def no_start_after_stop(m: Machine, name: str, mark: int) -> list[str]:
    """The axis's start/stop commands since ``mark``; asserts none starts after a stop."""
    cmds = commands(m, name, mark)
    if "stop" in cmds:
        assert "start" not in cmds[cmds.index("stop"):], (name, cmds)
    return cmds


def travel(m: Machine, name: str, t0: float) -> tuple[float, float]:
    """The lowest and highest position the twin of ``name`` passed since ``t0``, in the
    axis's units (from the twin's own motion history)."""
    twin = m.sim_drives[name]
    now = anyio.current_time()
    lo, hi = math.inf, -math.inf
    for s in twin.kin.trace(t0, now):
        a, b = max(s.t0, t0), min(s.t1, now)
        points = [s.at(a)[0], s.at(b)[0]]
        if s.a and a < s.t0 - s.v0 / s.a < b:
            points.append(s.at(s.t0 - s.v0 / s.a)[0])
        lo, hi = min(lo, *points), max(hi, *points)
    pos = twin.position()
    lo, hi = min(lo, pos), max(hi, pos)
    units = m.axes[name].units
    a, b = units.from_pulses(lo), units.from_pulses(hi)
    return min(a, b), max(a, b)


def far(m: Machine, name: str, fraction: float = 0.8) -> float:
    """A target across the axis's soft limits from where it is."""
    ax = m.axes[name]
    lo, hi = ax.config.limits or (-100.0, 100.0)
    pos = ax.position or 0.0
    return lo + (hi - lo) * (fraction if pos < (lo + hi) / 2 else 1 - fraction)


# -- one axis of a group move, a path or a program stopped from another task -----------------


@pytest.mark.parametrize("how", ["stop", "halt_now"])
@pytest.mark.parametrize("who", ["y", "r"])
async def test_stopping_one_axis_of_a_group_move_stops_the_whole_group(
    who: str, how: str, demo: Machinefile,
) -> None:
    """y shares x's RS-485 line; r is alone on Modbus TCP: either one stopped from another
    task ends the group move on every axis, and nothing of it starts afterwards."""
    names = ("x", "y", "r")
    async with open_machine(demo) as m:
        for n in names:
            await settle(m.axes[n])
        marks = {n: log_size(m, n) for n in names}
        outcome: list[BaseException] = []

        async def group() -> None:
            try:
                await m.group(*names).move_to({n: far(m, n) for n in names})
            except (GroupMotionError, MotionAborted) as exc:
                outcome.append(exc)

        with within(60, f"the group move ended by {how} of {who}"):
            async with anyio.create_task_group() as tg:
                tg.start_soon(group)
                await until(moving(m, who), f"{who} moving in the group move")
                await getattr(m.axes[who], how)()
        assert outcome, "the group move returned as if it had arrived"
        assert not at_rest(m, names), at_rest(m, names)
        for n in names:
            no_start_after_stop(m, n, marks[n])


@pytest.mark.parametrize("how", ["stop", "halt_now"])
async def test_a_stop_of_one_axis_drops_the_queued_group_moves_of_a_program(
    how: str, demo: Machinefile,
) -> None:
    """A program: x's buffered move, then a group move queued behind it. y, idle in the
    queue, is stopped while x runs: the queued group move is dropped on both axes (x,
    arriving after y's stop, starts nothing more), x's own move runs on."""
    async with open_machine(demo) as m:
        x, y = m.axes["x"], m.axes["y"]
        await m.group("x", "y").move_to({"x": 20.0, "y": 10.0})
        marks = {n: log_size(m, n) for n in ("x", "y")}
        first = await x.move_to(120.0, speed=100.0, buffer="buffered")
        queued = await m.group("x", "y").move_to({"x": 60.0, "y": 50.0}, buffer="buffered")
        later = await m.group("x", "y").move_to({"x": 30.0, "y": 20.0}, buffer="buffered")
        await until(moving(m, "x"), "x running its first move")
        with within(30, f"y's {how}"):
            await getattr(y, how)()
        stopped_at = time.monotonic()
        for handle in (queued, later):
            with within(30, "the queued group moves to end"), pytest.raises(DrivebusError):
                await handle
        with within(30, "x's own move to end"):  # it runs on, or the failed group stops it
            try:
                await first
                assert m.sim_drives["x"].position() == x.units.to_pulses(120.0)
            except MotionAborted:
                pass
        assert not at_rest(m, ("x", "y"))
        assert commands(m, "y", marks["y"]).count("start") == 0
        late = [k for k, t in command_frames(m, "x", marks["x"]) if k == "start" and t > stopped_at]
        assert not late, "x started the dropped group move"
        assert x.queued == 0 and y.queued == 0


@pytest.mark.parametrize("when", ["moving", "planned"])
async def test_a_program_task_cancelled_twice_stops_every_axis_and_leaves_them_usable(
    when: str, demo: Machinefile,
) -> None:
    """asyncio's teardown cancels a task natively, and may do it again while the task's
    cleanup runs: the path's axes are at rest on their twins when the task ends, nothing
    starts after the stop, and the axes take the next command."""
    async with open_machine(demo) as m:
        xy = m.group("x", "y")
        await xy.move_to({"x": 20.0, "y": 10.0})
        marks = {n: log_size(m, n) for n in ("x", "y")}
        path = [{"x": 200.0}, {"y": 150.0}, {"x": 30.0}, {"y": 20.0}]
        if when == "planned":
            path = [{"x": w["x"] - 50.0, "y": w["y"] - 20.0} for w in WAYPOINTS]
        task = asyncio.get_running_loop().create_task(xy.path(path, speed=80.0))
        if when == "planned":
            for _ in range(3):
                await anyio.lowlevel.checkpoint()
        else:
            await until(moving(m, "x"), "the path under way")
        task.cancel()
        await anyio.lowlevel.checkpoint()
        task.cancel()  # again, while the path's cleanup stops the axes
        with within(30, "the twice-cancelled path task to end"), \
                pytest.raises(asyncio.CancelledError):
            await task
        assert not at_rest(m, ("x", "y")), at_rest(m, ("x", "y"))
        for n in ("x", "y"):
            cmds = no_start_after_stop(m, n, marks[n])
            assert "stop" in cmds if when == "moving" else "start" not in cmds, (n, cmds)
            assert m.axes[n].queued == 0
        with within(30, "a move after the cancelled path"):
            await xy.move_to({"x": 25.0, "y": 15.0})
        assert m.sim_drives["x"].position() == m.axes["x"].units.to_pulses(25.0)


async def test_a_queued_group_move_cancelled_twice_at_once_starts_nothing(
    demo: Machinefile,
) -> None:
    """Two tasks cancel the same queued group move while the move before it runs, and a
    third awaits it: all return, the axes at rest, the queued move never starts."""
    async with open_machine(demo) as m:
        x = m.axes["x"]
        await m.group("x", "y").move_to({"x": 20.0, "y": 10.0})
        marks = {n: log_size(m, n) for n in ("x", "y")}
        await x.move_to(200.0, speed=100.0, buffer="buffered")
        queued = await m.group("x", "y").move_to({"x": 60.0, "y": 50.0}, buffer="buffered")
        await until(moving(m, "x"), "x running the move before")
        waited: list[BaseException] = []

        async def waiter() -> None:
            try:
                await queued
            except DrivebusError as exc:
                waited.append(exc)

        with within(30, "two cancellations of the queued group move"):
            async with anyio.create_task_group() as tg:
                tg.start_soon(waiter)
                tg.start_soon(queued.cancel)
                tg.start_soon(queued.cancel)
        called = time.monotonic()
        assert waited, "the cancelled group move returned as if it had arrived"
        assert not at_rest(m, ("x", "y"))
        assert "start" not in commands(m, "y", marks["y"])
        assert not [t for k, t in command_frames(m, "x", marks["x"])
                    if k == "start" and t > called]
        assert x.queued == 0 and m.axes["y"].queued == 0
        with within(30, "a move after the cancellations"):
            await m.group("x", "y").move_to({"x": 25.0, "y": 15.0})


async def test_a_session_group_move_cancelled_twice_at_once_stops_both_axes() -> None:
    """The embedding API (docs/guide/embedding.md): a group motion started by
    ``start_group_move``, cancelled by two callers at once: both get its record,
    aborted; both axes at rest, no start after their stops."""
    async with MachineSession.open(DEMO) as session:
        m = session.machine
        marks = {n: log_size(m, n) for n in ("x", "y")}
        record = await session.start_group_move({"x": 300.0, "y": 150.0}, client="cell")
        await until(moving(m, "x"), "the session's group move under way")
        states: list[str] = []

        async def cancel() -> None:
            states.append((await session.cancel_motion(record.id, client="cell")).state)

        with within(30, "two cancellations of the session's group move"):
            async with anyio.create_task_group() as tg:
                tg.start_soon(cancel)
                tg.start_soon(cancel)
        assert states == ["aborted", "aborted"] and record.state == "aborted"
        assert not at_rest(m, ("x", "y"))
        for n in ("x", "y"):
            assert "stop" in no_start_after_stop(m, n, marks[n])


class _Boom(Exception):
    pass


async def test_an_exception_in_the_machine_block_stops_every_queued_program(
    demo: Machinefile,
) -> None:
    """Buffered moves on x and z and a queued group move, none awaited, when the block
    raises: every axis at rest on its twin after the block, and no start after a stop."""
    names = ("x", "y", "z")
    marks: dict[str, int] = {}
    box: dict[str, Machine] = {}
    with within(90, "the machine to close after the exception"), pytest.raises(_Boom):
        async with open_machine(demo) as m:
            box["m"] = m
            for n in names:
                await settle(m.axes[n])
            marks.update({n: log_size(m, n) for n in names})
            x, z = m.axes["x"], m.axes["z"]
            await x.move_to(300.0, speed=100.0, buffer="buffered")
            await x.move_to(40.0, speed=100.0, buffer="buffered")
            await z.move_to(80.0, speed=20.0, buffer="buffered")
            await z.move_to(10.0, speed=20.0, buffer="buffered")
            await m.group("x", "y").move_to({"x": 100.0, "y": 100.0}, buffer="buffered")
            await until(moving(m, "x"), "x under way")
            await until(moving(m, "z"), "z under way")
            raise _Boom
    m = box["m"]
    assert not at_rest(m, names), at_rest(m, names)
    for n in names:
        no_start_after_stop(m, n, marks[n])
    assert "start" not in commands(m, "y", marks["y"])


async def test_an_exception_while_a_long_path_is_planned_starts_nothing(
    demo: Machinefile,
) -> None:
    names = ("x", "y")
    marks: dict[str, int] = {}
    box: dict[str, Machine] = {}
    with within(90, "the machine to close after the exception"), \
            pytest.raises(BaseExceptionGroup) as caught:
        async with open_machine(demo) as m:
            box["m"] = m
            await m.group(*names).move_to({"x": 60.0, "y": 30.0})
            marks.update({n: log_size(m, n) for n in names})
            async with anyio.create_task_group() as tg:
                tg.start_soon(lambda: m.group(*names).path(WAYPOINTS, speed=200.0))
                for _ in range(3):
                    await anyio.lowlevel.checkpoint()
                raise _Boom
    assert caught.group_contains(_Boom)
    m = box["m"]
    assert not at_rest(m, names)
    for n in names:
        assert starts(m, n, marks[n]) == 0, (n, commands(m, n, marks[n]))


@pytest.mark.parametrize("what", ["group move", "path", "queued group move", "planned path"])
async def test_leaving_the_machine_while_a_task_outside_it_runs_a_group_move(
    what: str, demo: Machinefile,
) -> None:
    """The motion's task outlives the machine's block: leaving stops every axis of it,
    the task ends with an error (it does not hang), and nothing starts afterwards."""
    names = ("x", "y")
    marks: dict[str, int] = {}
    ended: list[BaseException | None] = []
    box: dict[str, Machine] = {}

    async def program(m: Machine) -> None:
        xy = m.group(*names)
        try:
            if what == "group move":
                await xy.move_to({"x": 300.0, "y": 150.0}, speed=60.0)
            elif what == "path":
                await xy.path([{"x": 200.0}, {"y": 150.0}, {"x": 30.0}], speed=60.0)
            elif what == "planned path":
                await xy.path(WAYPOINTS, speed=200.0)
            else:
                await m.axes["x"].move_to(250.0, speed=60.0, buffer="buffered")
                handle = await xy.move_to({"x": 30.0, "y": 150.0}, buffer="buffered")
                await handle
            ended.append(None)
        except Exception as exc:  # any error will do: it must end
            ended.append(exc)

    with within(90, f"the machine left during a {what}, and its task's end"):
        async with anyio.create_task_group() as tg:
            async with open_machine(demo) as m:
                box["m"] = m
                await m.group(*names).move_to({"x": 20.0, "y": 10.0})
                marks.update({n: log_size(m, n) for n in names})
                tg.start_soon(program, m)
                if what == "planned path":  # left while it is being planned
                    for _ in range(3):
                        await anyio.lowlevel.checkpoint()
                else:
                    await until(moving(m, "x"), f"the {what} under way")
            left = time.monotonic()
            m = box["m"]
            assert not at_rest(m, names), at_rest(m, names)
    m = box["m"]
    assert ended and ended[0] is not None, "the motion returned as if it had arrived"
    if what == "planned path":
        assert all(starts(m, n, marks[n]) == 0 for n in names), \
            {n: commands(m, n, marks[n]) for n in names}
    assert not at_rest(m, names)
    for n in names:
        no_start_after_stop(m, n, marks[n])
        late = [k for k, t in command_frames(m, n, marks[n]) if k == "start" and t > left]
        assert not late, (n, "a start after the machine was left")


# -- the feed override against the soft limits ------------------------------------------------


LIMITED = ["x", "y", "z", "r"]


async def rested(ax: Axis) -> None:
    """Until the axis is at rest; out of ErrorStop if its twin's limit switch stopped it
    first (the demo's y has its negative switch at -2 mm, inside its soft limit, -5)."""
    await until(lambda: ax.state in (AxisState.STANDSTILL, AxisState.ERROR_STOP),
                f"{ax.name} at rest")
    if ax.state is AxisState.ERROR_STOP:
        assert "limit switch" in str(ax.error), ax.error
        await ax.reset()
    await settle(ax)


@pytest.mark.parametrize("when", ["at once", "near the limit", "jogged faster near it"])
@pytest.mark.parametrize("name", LIMITED)
async def test_an_override_raised_during_a_jog_never_carries_the_axis_past_its_soft_limit(
    name: str, when: str,
) -> None:
    """Toward each soft limit at half speed under an override of 0.5, then the override
    raised to 2 (or the jog given again at twice its speed, near the limit): the twin
    never passes the limit."""
    async with open_machine(DEMO) as m:
        ax = m.axes[name]
        lo, hi = ax.config.limits  # type: ignore[misc]
        span = ax.config.speed * 0.2  # a fifth of a second at full speed
        await ax.move_to(hi - span)
        m.override = 0.5
        t0 = anyio.current_time()
        with within(30, f"{name}'s jog to its positive soft limit"):
            await ax.jog(ax.config.speed * 0.5, watchdog=None)
            await until(moving(m, name), f"{name} jogging")
            if when != "at once":
                await until(lambda: ax.units.from_pulses(m.sim_drives[name].position())
                            > hi - span * 0.3, f"{name} near its limit")
            if when == "jogged faster near it":
                await ax.jog(ax.config.speed, watchdog=None)
            m.override = 2.0
            await until(lambda: not m.sim_drives[name].is_moving(),
                        f"{name} at rest at its limit")
            await rested(ax)
        low, high = travel(m, name, t0)
        assert high <= hi + 1e-9, (name, when, high, hi)
        at = ax.units.from_pulses(m.sim_drives[name].position())
        assert lo <= at <= hi, (name, at)
        # and back toward the negative one, raised the same way
        await ax.move_to(lo + span)
        m.override = 0.5
        t1 = anyio.current_time()
        with within(30, f"{name}'s jog to its negative soft limit"):
            await ax.jog(-ax.config.speed * 0.5, watchdog=None)
            await until(moving(m, name), f"{name} jogging back")
            m.override = 2.0
            await until(lambda: not m.sim_drives[name].is_moving(),
                        f"{name} at rest at its negative limit")
            await rested(ax)
        low, high = travel(m, name, t1)
        assert low >= lo - 1e-9, (name, low, lo)


@pytest.mark.parametrize("name", LIMITED)
async def test_an_override_raised_during_a_move_to_the_limit_lands_on_it(
    name: str, demo: Machinefile,
) -> None:
    """A move whose target is the soft limit, its speed raised on the fly where the drive
    can (the CL86R) or from the next move: the twin never passes the target."""
    async with open_machine(demo) as m:
        ax = m.axes[name]
        lo, hi = ax.config.limits  # type: ignore[misc]
        await ax.move_to(lo + (hi - lo) * 0.6)
        m.override = 0.25
        t0 = anyio.current_time()
        with within(60, f"{name}'s move to its limit"):
            async with anyio.create_task_group() as tg:
                tg.start_soon(ax.move_to, hi)
                await until(moving(m, name), f"{name} moving")
                m.override = 2.0
        _, high = travel(m, name, t0)
        assert high <= hi + 1e-9, (name, high, hi)
        assert m.sim_drives[name].position() == ax.units.to_pulses(hi)


async def test_an_override_raised_during_a_blended_program_never_passes_the_limit(
    demo: Machinefile,
) -> None:
    """z (CL86R) blends into a last move whose target is its soft limit; the override
    is raised to 2 while the first runs and again while it blends: the twin ends on the
    limit and never passes it."""
    async with open_machine(demo) as m:
        z = m.axes["z"]
        _, hi = z.config.limits  # type: ignore[misc]
        await z.move_to(40.0)
        m.override = 0.25
        t0 = anyio.current_time()
        await z.move_to(70.0, buffer="blending")
        await z.move_to(90.0, buffer="blending")
        last = await z.move_to(hi, buffer="blending")
        with within(60, "z's blended program to its limit"):
            await until(moving(m, "z"), "z moving")
            m.override = 2.0
            await until(lambda: z.units.from_pulses(m.sim_drives["z"].position()) > 80.0,
                        "z past 80")
            m.override = 1.0
            m.override = 2.0
            await last
        _, high = travel(m, "z", t0)
        assert high <= hi + 1e-9, (high, hi)
        assert m.sim_drives["z"].position() == z.units.to_pulses(hi)


async def test_an_override_past_what_the_drive_runs_refuses_the_queued_move_with_none_sent(
    demo: Machinefile,
) -> None:
    """x (NT86, at most 500 mm/s; no ``max_speed`` in the file) runs a buffered move at
    200 mm/s with another queued; the machine's and the axis's overrides raised to 2 each
    (800 mm/s): the queued move is refused when it would be written, a LimitViolation,
    none of it sent, and x comes to rest where the first move ends."""
    async with open_machine(demo) as m:
        x = m.axes["x"]
        await x.move_to(20.0)
        mark = log_size(m, "x")
        first = await x.move_to(300.0, buffer="buffered")
        queued = await x.move_to(100.0, buffer="buffered")
        await until(moving(m, "x"), "x moving")
        m.override = 2.0
        x.override = 2.0
        with within(30, "the queued move's end"):
            await first
            with pytest.raises(LimitViolation, match=r"axis x: speed 800 mm/s is beyond the "
                               r"500 mm/s .*speed override .*: 4"):
                await queued
        assert commands(m, "x", mark).count("start") == 1, commands(m, "x", mark)
        assert not at_rest(m, ("x",))
        assert m.sim_drives["x"].position() == x.units.to_pulses(300.0)
        assert x.queued == 0



BAD = [0.0, -0.0, -1.0, math.nan, math.inf, -math.inf, 1e308, 2.0000001, None, "0.5"]


async def test_a_bad_override_during_a_jog_is_refused_with_nothing_sent(tmp_path: Path) -> None:
    """While z (CL86R: speed changes go on the fly) jogs and x (NT86) moves: each bad
    override is an ArgumentError, the override stays, no frame is written, the twins run
    on at their speed."""
    async with open_machine(DEMO) as m:
        x, z = m.axes["x"], m.axes["z"]
        await z.jog(10.0, watchdog=None)
        async with anyio.create_task_group() as tg:
            tg.start_soon(lambda: x.move_to(300.0))
            await until(moving(m, "x"), "x moving")
            await until(lambda: abs(z.units.from_pulses(m.sim_drives["z"].velocity()))
                        == pytest.approx(10.0, rel=1e-3), "z cruising at 10 mm/s")
            speeds = {n: m.sim_drives[n].velocity() for n in ("x", "z")}
            before = write_frames(m)
            for bad in BAD:
                with pytest.raises(ArgumentError, match="override"):
                    m.override = bad  # type: ignore[assignment]
                with pytest.raises(ArgumentError, match="override"):
                    z.override = bad  # type: ignore[assignment]
            for n in ("x", "z"):  # a poll of each after the refusals
                await m.axes[n].refresh()
            assert write_frames(m) == before
            assert m.override == 1.0 and z.override == 1.0 and x.effective_override == 1.0
            assert m.sim_drives["z"].velocity() == speeds["z"]
            await z.stop()
            tg.cancel_scope.cancel()
        assert not at_rest(m, ("x", "z"))


# -- the stop latency while planning, setting up, and under saturating polls ------------------


def stop_within_one_transaction(m: Machine, name: str, mark: int, called: float,
                                what: str) -> None:
    """``name``'s stop frame left within one transaction of ``called`` (at most one other
    request frame on its line between them), and nothing of it started afterwards."""
    frames = command_frames(m, name, mark)
    stops = [t for k, t in frames if k == "stop" and t > called]
    line = m.axes[name].config.line
    assert stops, (what, "no stop frame", frames_text(m.wires[line].log, after=called))  # type: ignore[union-attr]
    between = requests_between(m, line, called, stops[0])
    assert between <= 1, (what, f"{between} request frames before the stop",
                          frames_text(m.wires[line].log, after=called, before=stops[0]))  # type: ignore[union-attr]
    assert not [t for k, t in frames if k == "start" and t > stops[0]], (what, frames)
    assert not m.sim_drives[name].is_moving(), what


def starts(m: Machine, name: str, mark: int) -> int:
    return commands(m, name, mark).count("start")


WAYPOINTS = [{"x": 70.0 + 20 * (i % 2), "y": 35.0 + 10 * (i % 3)} for i in range(400)]


async def test_a_stop_of_another_axis_reaches_the_wire_while_a_long_path_is_planned() -> None:
    async with open_machine(DEMO) as m:
        z = m.axes["z"]
        await m.group("x", "y").move_to({"x": 60.0, "y": 30.0})
        await z.jog(5.0, watchdog=None)
        await until(moving(m, "z"), "z jogging")
        marks = {n: log_size(m, n) for n in ("x", "y", "z")}
        async with anyio.create_task_group() as tg:
            tg.start_soon(lambda: m.group("x", "y").path(WAYPOINTS, speed=200.0))
            for _ in range(3):  # the path task runs and plans
                await anyio.lowlevel.checkpoint()
            assert not starts(m, "x", marks["x"]) and not starts(m, "y", marks["y"]), \
                "the path started before the stop: nothing was being planned"
            called = time.monotonic()
            with within(10, "z's stop during the planning"):
                await z.stop()
            stop_within_one_transaction(m, "z", marks["z"], called, "during path planning")
            tg.cancel_scope.cancel()
        assert not at_rest(m, ("x", "y", "z"))


async def test_a_stop_of_a_path_axis_while_it_is_planned_starts_nothing(
    demo: Machinefile,
) -> None:
    async with open_machine(demo) as m:
        await m.group("x", "y").move_to({"x": 60.0, "y": 30.0})
        marks = {n: log_size(m, n) for n in ("x", "y")}
        outcome: list[BaseException] = []

        async def path() -> None:
            try:
                await m.group("x", "y").path(WAYPOINTS, speed=200.0)
            except DrivebusError as exc:
                outcome.append(exc)

        with within(30, "the path stopped while planned"):
            async with anyio.create_task_group() as tg:
                tg.start_soon(path)
                for _ in range(3):
                    await anyio.lowlevel.checkpoint()
                await m.axes["y"].stop()
        assert outcome, "the path ran to its end"
        assert starts(m, "x", marks["x"]) == 0 and starts(m, "y", marks["y"]) == 0
        assert not at_rest(m, ("x", "y"))


@pytest.mark.parametrize("how", ["stop_all", "halt_now"])
async def test_stopping_the_whole_machine_while_a_path_is_planned_starts_nothing(
    how: str, demo: Machinefile,
) -> None:
    """``machine.stop_all()`` and ``machine.halt_now()`` issued while a long path is
    planned (no axis moves yet): the path is aborted, nothing of it ever starts."""
    async with open_machine(demo) as m:
        await m.group("x", "y").move_to({"x": 60.0, "y": 30.0})
        marks = {n: log_size(m, n) for n in ("x", "y")}
        outcome: list[BaseException | None] = []

        async def path() -> None:
            try:
                await m.group("x", "y").path(WAYPOINTS, speed=200.0)
                outcome.append(None)
            except DrivebusError as exc:
                outcome.append(exc)

        with within(60, f"the path after {how}"):
            async with anyio.create_task_group() as tg:
                tg.start_soon(path)
                for _ in range(3):
                    await anyio.lowlevel.checkpoint()
                assert not starts(m, "x", marks["x"]), "the path started before the stop"
                await getattr(m, how)()
        assert outcome and isinstance(outcome[0], MotionAborted), outcome
        assert starts(m, "x", marks["x"]) == 0 and starts(m, "y", marks["y"]) == 0, \
            {n: commands(m, n, marks[n]) for n in ("x", "y")}
        assert not at_rest(m, ("x", "y"))


async def test_a_stop_reaches_the_wire_while_a_group_move_starts_its_axes() -> None:
    """z jogs; a group move of x, y and r holds the lines and sends its starts back to
    back: z's stop, called the moment x's start is on the wire, still leaves within one
    transaction (the start gate lets emergencies through)."""
    async with open_machine(DEMO) as m:
        z = m.axes["z"]
        names = ("x", "y", "r")
        for attempt in range(3):
            for n in (*names, "z"):
                await settle(m.axes[n])
            await z.jog(5.0 if (z.position or 0.0) < 50.0 else -5.0, watchdog=None)
            await until(moving(m, "z"), "z jogging")
            marks = {n: log_size(m, n) for n in (*names, "z")}
            async with anyio.create_task_group() as tg:
                tg.start_soon(lambda: m.group(*names).move_to({n: far(m, n) for n in names}))
                mark_x = marks["x"]
                await until(lambda mark_x=mark_x: starts(m, "x", mark_x) > 0,
                            "x's start of the group move on the wire", every=0.0002)
                called = time.monotonic()
                with within(10, "z's stop during the group's starts"):
                    await z.stop()
                stop_within_one_transaction(m, "z", marks["z"], called,
                                            f"during the group's starts, attempt {attempt}")
                tg.cancel_scope.cancel()
            assert not at_rest(m, (*names, "z"))


async def test_a_stop_reaches_the_wire_while_another_axis_is_set_up() -> None:
    """y (BHSS at 19200 8E1, the slowest format on the line) is set up, several config
    writes, while z jogs: z's stop overtakes them."""
    async with open_machine(DEMO) as m:
        z, y = m.axes["z"], m.axes["y"]
        await z.jog(5.0, watchdog=None)
        await until(moving(m, "z"), "z jogging")
        mark = log_size(m, "z")
        wire: Any = m.wires["rs485"]
        y_writes_before = sum(1 for f in list(wire.log) if f.direction == "request"
                              and f.address == 3 and f.data[1] in (6, 16))
        async with anyio.create_task_group() as tg:
            tg.start_soon(y.setup)
            await until(lambda: sum(1 for f in list(wire.log) if f.direction == "request"
                                    and f.address == 3 and f.data[1] in (6, 16))
                        > y_writes_before, "y's first set-up write on the wire", every=0.0005)
            called = time.monotonic()
            with within(10, "z's stop during y's set-up"):
                await z.stop()
            stop_within_one_transaction(m, "z", mark, called, "during another axis's set-up")
        assert not at_rest(m, ("y", "z"))


async def test_a_stop_reaches_the_wire_while_polls_saturate_the_line() -> None:
    """Eight readers keep the RS-485 line busy at poll priority (reads of x and y, the
    slower format): z's stop still leaves within one transaction."""
    async with open_machine(DEMO) as m:
        z = m.axes["z"]
        bus = m.buses["rs485"]
        readers = [bus.slave(2, settings=LineSettings.parse("115200 8N1")),
                   bus.slave(3, settings=LineSettings.parse("19200 8E1"))]
        await z.jog(5.0, watchdog=None)
        await until(moving(m, "z"), "z jogging")
        reads = [0]

        async def hammer(i: int) -> None:
            while True:
                await readers[i % 2].read_holding_registers(0, 2, priority=Priority.POLL)
                reads[0] += 1

        async with anyio.create_task_group() as tg:
            for i in range(8):
                tg.start_soon(hammer, i)
            await until(lambda: reads[0] >= 40, "the readers saturating the line")
            for round_ in range(3):
                mark = log_size(m, "z")
                called = time.monotonic()
                with within(10, "z's stop on a saturated line"):
                    await z.stop()
                stop_within_one_transaction(m, "z", mark, called, f"saturated, round {round_}")
                await z.jog(-5.0 if round_ % 2 == 0 else 5.0, watchdog=None)
                await until(moving(m, "z"), "z jogging again")
            await z.stop()
            tg.cancel_scope.cancel()
        assert not at_rest(m, ("z",))
