"""The promises at their edges, each a case that once broke them: a force-quit embedded
app, a write cancelled while it waits for the line's silence, a timeout decided on a
stale status, an error raised while the axis still brakes, the machine-wide emergency
stop, a homing that failed yet left the axis homed, a status older than a command
judging it. Judged by the twins (in this process or another) and the wire log."""

from __future__ import annotations

import contextlib
import math
import os
import random
import signal
import subprocess
import sys
import textwrap
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import anyio
import anyio.lowlevel
import httpx
import pytest

from drivebus import AxisState, Priority, open_machine
from drivebus.bus.sent import sent_requests
from drivebus.clock import monotonic
from drivebus.drives.status import DriveStatus
from drivebus.errors import GroupMotionError, MotionAborted, MotionTimeout
from drivebus.settings import LineSettings
from drivebus.sim.harness import sim_bus
from drivebus.sim.slave import Fault
from drivebus.sim.twins import twin_class
from ports import reserved_port
from wirelog import (
    command_frames,
    commands,
    frames_text,
    log_size,
    reads_of,
    requests_between,
    settle,
)

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "configs" / "demo.toml"
STF = ROOT / "configs" / "drives" / "moons_stf.toml"


# -- group planning never holds the loop ----------------------------------------------------


async def test_planning_a_group_move_and_a_long_path_holds_no_loop_step() -> None:
    """Planned on the loop: the loop-step guard (conftest) fails the test if one step of
    the 4-axis plan or of the path's 24 segments takes more than 20 ms of CPU."""
    async with open_machine(DEMO) as m:
        g = m.group("x", "y", "z", "r")
        report = await g.move_to({"x": 60.0, "y": 40.0, "z": 20.0, "r": 90.0})
        assert report.duration > 0
        xy = m.group("x", "y")
        corners = [{"x": 70.0 - 10 * (i % 2), "y": 45.0 - 5 * (i % 3)} for i in range(24)]
        path = await xy.path(corners, speed=300.0)
        assert len(path.segments) == len(corners)


LONG_PATH = [{"x": 20.0 + (i * 37) % 360, "y": 5.0 + (i * 53) % 180, "z": float((i * 29) % 95)}
             for i in range(1, 301)]
"""300 waypoints of x, y and z: minutes of motion, 900 queued parts."""


@pytest.mark.parametrize("how", ["stop one axis", "cancel the path"])
async def test_ending_a_long_path_sends_one_stop_an_axis_at_once(how: str) -> None:
    """Ending a path of hundreds of segments (a stop of one of its axes, or cancelling
    its caller) stops each axis with a stop or two, as soon as one transaction allows: the
    loop-step guard (conftest) fails a step over its limit. An outside audit found the
    stop held the loop for 100-260 ms (ending every queued part at once), and each of the
    other axes' queued parts sent a stop of its own: a stop per waypoint, for seconds."""
    async with open_machine(DEMO) as m:
        names = ("x", "y", "z")
        for n in names:
            await settle(m.axes[n])
        marks = {n: log_size(m, n) for n in names}
        failed: list[BaseException] = []
        with anyio.fail_after(60):
            async with anyio.create_task_group() as tg:

                async def run() -> None:
                    try:
                        await m.group(*names).path(LONG_PATH, speed=50.0)
                    except GroupMotionError as exc:
                        failed.append(exc)

                tg.start_soon(run)
                seen = 0  # the path is under way: two polls of y show it moving
                async for st in m.axes["y"].watch():
                    seen += st.moving
                    if seen == 2:
                        break
                if how == "stop one axis":
                    await m.axes["x"].stop()  # the path ends by itself, failed
                else:
                    tg.cancel_scope.cancel()
        assert bool(failed) == (how == "stop one axis"), (how, failed)
        for n in names:
            await settle(m.axes[n])
        assert not [n for n in names if m.sim_drives[n].is_moving()], how
        for n in names:
            frames = command_frames(m, n, marks[n])
            stops = [t for k, t in frames if k == "stop"]
            assert 1 <= len(stops) <= 2, (how, n, frames[-6:])
            assert not [t for k, t in frames if k != "stop" and t > stops[0]], (how, n)


# -- a force-quit embedded app ---------------------------------------------------------------

APP = """
import contextlib, os
from fastapi import FastAPI
from drivebus.app import MachineSession

@contextlib.asynccontextmanager
async def lifespan(app):
    async with MachineSession.open(os.environ["DRIVEBUS_TEST_MACHINE"]) as session:
        app.state.session = session
        yield

app = FastAPI(lifespan=lifespan)

@app.post("/move")
async def move():
    await app.state.session.start_move("x", target=390.0, speed=20.0)
    return {"ok": True}

@app.get("/x")
async def x():
    return {"state": str(app.state.session.axis("x").state)}
"""


class _Lines:
    """A subprocess's output lines, read on a thread, waited for with a bound."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        self.proc = proc
        self.seen: list[str] = []
        self._cv = threading.Condition()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            with self._cv:
                self.seen.append(line.rstrip())
                self._cv.notify_all()

    def all_of_it(self, timeout: float = 30.0) -> str:
        """Every line, once the process has ended and the last one was read (the reader
        thread may lag behind the process's end on a busy machine)."""
        self._reader.join(timeout)
        assert not self._reader.is_alive(), f"output still open after {timeout:g} s"
        return "\n".join(self.seen)

    def wait_for(self, text: str, timeout: float = 60.0) -> None:
        with self._cv:
            if not self._cv.wait_for(lambda: any(text in s for s in self.seen), timeout):
                raise AssertionError(f"no {text!r} within {timeout:g} s: {self.seen[-30:]}")


@pytest.fixture
def demo_sim() -> Iterator[_Lines]:
    """``drivebus sim`` of the demo machine, in its own process (this test's runtime dir)."""
    sim = subprocess.Popen([sys.executable, "-m", "drivebus.cli", "sim", str(DEMO)],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                           cwd=ROOT)
    lines = _Lines(sim)
    try:
        lines.wait_for("simulating machine")
        yield lines
    finally:
        sim.send_signal(signal.SIGINT)
        try:
            sim.wait(20)
        except subprocess.TimeoutExpired:
            sim.kill()


def test_a_force_quit_embedded_app_leaves_no_axis_moving(
        tmp_path: Path, demo_sim: _Lines) -> None:
    """An own FastAPI app with ``MachineSession.open`` in its lifespan, under uvicorn,
    against ``drivebus sim`` in another process; x moves at 20 mm/s and uvicorn gets a
    second Ctrl-C while it shuts down (a force quit: no lifespan shutdown, every task
    cancelled at the event loop's end). x's twin must be at rest once the app is gone."""
    (tmp_path / "app.py").write_text(textwrap.dedent(APP))
    env = {**os.environ, "DRIVEBUS_TEST_MACHINE": str(DEMO)}
    with reserved_port() as port:
        app = subprocess.Popen(
            [sys.executable, "-m", "uvicorn", "app:app", "--port", str(port),
             "--host", "127.0.0.1"], cwd=tmp_path, env=env, text=True,
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        out = _Lines(app)
        try:
            out.wait_for("Application startup complete")
            with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=30) as client:
                assert client.post("/move").status_code == 200
                deadline = time.monotonic() + 20
                while client.get("/x").json()["state"] != "DiscreteMotion":
                    assert time.monotonic() < deadline, "x never moved"
                    time.sleep(0.02)
            app.send_signal(signal.SIGINT)
            out.wait_for("Shutting down")
            app.send_signal(signal.SIGINT)  # the force quit
            code = app.wait(60)
        finally:
            if app.poll() is None:
                app.kill()
    said = out.all_of_it()
    # the log says what was stopped and that it came to rest (by the motion's own
    # cancellation or by leaving the machine, whichever came first)
    assert ("axis x: stopped at" in said or "stopped x at" in said) and "(at rest)" in said, \
        said
    assert code is not None

    async def check() -> None:  # the twin, asked over its own line after the app is gone
        async with open_machine(DEMO, stop_on_exit=False) as m:
            x = m.axes["x"]
            first = await x.refresh()
            await anyio.sleep(0.3)
            second = await x.refresh()
            assert not first.moving and not second.moving, said
            assert first.position == second.position, said

    anyio.run(check)


PROGRAM = """
import asyncio, sys
import anyio
from drivebus import open_machine

async def main():
    async with open_machine(sys.argv[1]) as m:
        await m.axes["x"].jog(20.0, watchdog=None)
        await m.axes["y"].jog(-20.0, watchdog=None)
        print("jogging", flush=True)
        await anyio.sleep_forever()

asyncio.run(main()) if sys.argv[2] == "asyncio" else anyio.run(main)
"""


async def _axes_at_rest(said: str) -> None:
    """The demo's twins at rest, asked over their own line once the program is gone."""
    async with open_machine(DEMO, stop_on_exit=False) as m:
        for name in ("x", "y"):
            first = await m.axes[name].refresh()
            await anyio.sleep(0.2)
            second = await m.axes[name].refresh()
            assert not first.moving and not second.moving, (name, said)
            assert first.position == second.position, (name, said)


@pytest.mark.parametrize("runner", ["asyncio", "anyio"])
def test_a_second_ctrl_c_at_once_waits_for_the_stops(
        tmp_path: Path, demo_sim: _Lines, runner: str) -> None:
    """A library program under asyncio.run / anyio.run, x and y jogging, gets two SIGINTs
    0.5 ms apart: the first cancels its main task and the machine stops the axes as it
    leaves; the second raised KeyboardInterrupt among the stops being handed to the line,
    and the axes ran on after the process had ended (12 of 16 runs, an outside audit)."""
    (tmp_path / "program.py").write_text(textwrap.dedent(PROGRAM))
    for attempt in range(3):
        app = subprocess.Popen([sys.executable, "program.py", str(DEMO), runner],
                               cwd=tmp_path, text=True, stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT)
        out = _Lines(app)
        try:
            out.wait_for("jogging")
            app.send_signal(signal.SIGINT)
            time.sleep(0.0005)  # (two at once are one: the second while the first is taken)
            app.send_signal(signal.SIGINT)
            code = app.wait(60)
        finally:
            if app.poll() is None:
                app.kill()
        said = out.all_of_it()
        assert code != 0 and "KeyboardInterrupt" in said, said  # it did end by Ctrl-C
        anyio.run(_axes_at_rest, f"attempt {attempt}: {said}")


async def test_a_drive_that_goes_silent_right_after_its_start_is_stopped_on_leaving() -> None:
    """x's jog is acknowledged, then x stops answering (its replies lost, its commands
    still obeyed) before any status after the start: it went Offline on a status at rest,
    and leaving the machine stopped nothing (an outside audit: 4 of 8 runs in process,
    5 of 5 with a worker). A start acknowledged after the last status was requested may
    be moving: the stop goes out."""
    with anyio.fail_after(60):
        async with open_machine(DEMO) as m:
            x, twin = m.axes["x"], m.sim_drives["x"]
            await x.enable()
            await x.jog(20.0, watchdog=None)
            twin.faults.inject(Fault.NO_REPLY, times=None)  # no await since the start
            async for _ in x.watch():
                if x.state is AxisState.OFFLINE:
                    break
            assert twin.is_moving()
        said = commands(m, "x")
        assert said[-1] == "stop" and "start" in said, said
        assert not twin.is_moving()


@pytest.mark.parametrize("priority", [None, Priority.CONFIG])
async def test_a_stop_is_confirmed_while_clients_read_parameters(
        priority: Priority | None) -> None:
    """Three clients read every parameter of x's drive over and over (the service's GET
    parameters) while x jogs, then x is halted. The reads went at CONFIG, above the
    axes' polls: the actor's routine poll never left the queue, no status after the
    halt was read, and halt_now() failed after 30 s with a MotionTimeout (an outside
    audit: the e-stop reply took 30 s from two readers on). Reads of one's own at CONFIG
    too: the routine poll queued behind them is taken back, the stop's goes first, and a
    routine poll held back for a second goes again in turn with them."""
    from drivebus.app.params import read_parameters

    async with open_machine(DEMO) as m:
        x, twin = m.axes["x"], m.sim_drives["x"]
        await x.enable()
        await x.jog(20.0, watchdog=None)

        async def reader() -> None:
            while True:
                if priority is None:
                    await read_parameters(x.profile)
                else:
                    await read_parameters(x.profile, priority=priority)

        async with anyio.create_task_group() as tg:
            for _ in range(3):
                tg.start_soon(reader)
            await anyio.sleep(0.3)  # the queue full of reads
            with anyio.fail_after(10):  # (30 s before: the stop's status never came)
                await x.halt_now()
            assert not twin.is_moving()
            polled = x.status
            with anyio.fail_after(10):  # the routine polls go on beside the reads
                async for st in x.watch():
                    if st is not polled:
                        break
            tg.cancel_scope.cancel()


# -- a write cancelled while it waits for the line's silence ---------------------------------


async def test_a_cancelled_write_is_withdrawn_before_its_first_byte_or_reported() -> None:
    """Writes at 9600 baud (a long silence before each frame) behind a read, their
    callers cancelled at every moment of the wait: each write either never reached the
    wire, or is in the ``sent_requests`` record with its outcome."""
    settings = LineSettings.parse("9600 8N1")
    twin = twin_class("NT86")(1, settings)
    async with sim_bus([twin], settings) as (wire, bus):
        slave = bus.slave(1)
        rng = random.Random(7)
        for i in range(60):
            value = 100 + i  # register 72 (point move speed) takes 0..3000
            with sent_requests() as sent, anyio.move_on_after(rng.uniform(0.0, 0.012)):
                async with anyio.create_task_group() as tg:  # a read ahead of it
                    tg.start_soon(slave.read_holding_registers, 0, 2)
                    await anyio.lowlevel.checkpoint()
                    await slave.write_register(72, value, priority=Priority.CONFIG)
            on_wire = any(f.direction == "request" and f.data[1] == 0x06
                          and int.from_bytes(f.data[4:6], "big") == value
                          for f in list(wire.log))
            reported = any(r.function == 0x06 and r.pdu[3:5] == value.to_bytes(2, "big")
                           for r in sent)
            assert on_wire == reported, (i, on_wire, sent)


# -- a timeout decided on a fresh status; errors raised at rest --------------------------------


def _stf(name: str, **axis: Any) -> dict[str, Any]:
    return {"name": name, "lines": {"l": {"port": f"sim://{name}", "settings": "115200 8N1",
                                          "timeout": 0.1}},
            "axes": {"x": {"line": "l", "address": 1, "drive": str(STF), "unit": "mm",
                           "pulses_per_rev": 20000, "units_per_rev": 10.0, "speed": 20.0,
                           "accel": 200.0, "decel": 200.0, "limits": [-100.0, 100.0],
                           **axis}}}


async def test_a_move_is_not_timed_out_on_a_status_polled_before_it_arrived() -> None:
    """Polls once a second while moving: the move (0.6 s) is over before its deadline
    but no poll has shown it. The deadline asks the drive once more: no MotionTimeout."""
    cfg = {"name": "fresh-timeout", "lines": {"l": {"port": "sim://fresh-timeout",
                                                    "settings": "115200 8N1"}},
           "axes": {"x": {"line": "l", "address": 1, "drive": "NT86", "unit": "mm",
                          "pulses_per_rev": 4000, "units_per_rev": 10.0, "speed": 20.0,
                          "accel": 200.0, "decel": 200.0,
                          "poll": {"moving": 1.0, "idle": 1.0}}}}
    async with open_machine(cfg) as m:
        x = m.axes["x"]
        await x.move_to(10.0)  # the deadline (1.5 × 0.6 s + 1 s + 4 polls) is far off
        # a deadline shorter than the next poll: only a fresh read can show the arrival
        x.envelope.motion_timeout = lambda plan, distance: plan.duration(distance) + 0.2
        with anyio.fail_after(10):
            await x.move_to(20.0)
        assert m.sim_drives["x"].position() == x.units.to_pulses(20.0)


async def test_a_homing_timeout_is_raised_with_the_axis_at_rest() -> None:
    """A homing whose switch is never found times out: MotionTimeout comes once the
    drive is at rest (never while Stopping), the axis is not homed, and the next command
    runs at once."""
    async with open_machine(_stf("homing-timeout", homing={
            "method": "home_switch_positive", "speed": 5.0, "creep": 1.0, "accel": 100.0,
            "timeout": 0.8})) as m:
        x, twin = m.axes["x"], m.sim_drives["x"]
        await x.enable()
        with pytest.raises(MotionTimeout):
            await x.home()
        assert not twin.is_moving()
        assert x.state is not AxisState.STOPPING
        assert not x.homed
        await x.move_to(-5.0)
        assert twin.position() == x.units.to_pulses(-5.0)
        assert not x.homed


async def test_a_homing_stopped_half_way_leaves_the_axis_not_homed() -> None:
    async with open_machine(_stf("homing-stopped", homing={
            "method": "home_switch_positive", "speed": 5.0, "creep": 1.0,
            "accel": 100.0})) as m:
        x, twin = m.axes["x"], m.sim_drives["x"]
        await x.enable()
        async with anyio.create_task_group() as tg:

            async def home() -> None:
                with contextlib.suppress(MotionAborted):  # by the stop below
                    await x.home()

            tg.start_soon(home)
            with anyio.fail_after(10):
                while not twin.is_moving():  # noqa: ASYNC110 (a twin is polled)
                    await anyio.sleep(0.005)
            await x.stop()
        await settle(x)
        for _ in range(3):  # and stays so in the statuses that follow
            await x.refresh()
            assert not x.homed


# -- the machine-wide emergency stop ---------------------------------------------------------


async def test_machine_halt_now_stops_every_axis_on_every_line() -> None:
    async with open_machine(DEMO) as m:
        for name in ("x", "y", "z", "r"):
            ax = m.axes[name]
            await ax.jog(5.0 if (ax.position or 0) < 50 else -5.0, watchdog=None)
        with anyio.fail_after(20):
            while not all(m.sim_drives[n].is_moving()  # noqa: ASYNC110 (twins are polled)
                          for n in ("x", "y", "z", "r")):
                await anyio.sleep(0.005)
        outcome = await m.halt_now()
        assert set(outcome) == set(m.axes)
        assert all(v is None for v in outcome.values()), outcome
        assert not any(t.is_moving() for t in m.sim_drives.values())
        assert all(m.axes[n].state is not AxisState.CONTINUOUS_MOTION
                   for n in ("x", "y", "z", "r"))


# -- no command judged by a status older than its reply --------------------------------------


async def test_no_motion_is_judged_by_a_status_requested_before_its_start() -> None:
    """Replies delayed at random (0-40 ms, legal reply times): every move ends in position
    on its target, by the twin, and the status that ended it was requested after the
    start's reply (``arrived_at``: when that status's request was queued)."""
    async with open_machine(DEMO) as m:
        x, twin = m.axes["x"], m.sim_drives["x"]
        rng = random.Random(11)
        for target in (30.0, 10.0, 45.0, 12.0, 60.0, 20.0):
            twin.faults.inject(Fault.SLOW_REPLY, times=None, value=rng.uniform(0.0, 0.04))
            await x.move_to(target, speed=100.0)
            twin.faults.clear()
            assert twin.position() == x.units.to_pulses(target)
            assert not twin.is_moving()
            assert x.arrived_at > x.command_started_at, target


# -- a status requested before a stop's reply says nothing of the stop -----------------------


@pytest.mark.parametrize("stopper", ["stop", "halt_now", "cancel"])
async def test_a_stop_on_its_way_keeps_the_axis_stopping_until_a_status_after_it(
    stopper: str,
) -> None:
    """A move whose drive is already at rest (to where it is) is stopped while a poll of
    it is on the wire (its reply held back 0.6 s): by ``stop()``, ``halt_now()`` or by
    cancelling its caller (the axis's own stop). That poll shows the drive at rest, but it
    was requested before the stop's reply: the axis stays Stopping (it once went
    Standstill there, and a second stop then returned at once, with the first one still
    on its way). A second ``halt_now()`` called at that status returns only after a
    status requested after its call, and only a status requested after the stop's reply
    (of the last stop on its way) makes the axis Standstill."""
    cfg = {"name": f"stop-way-{stopper}",
           "lines": {"l": {"port": f"sim://stop-way-{stopper}", "settings": "115200 8N1",
                           "timeout": 2.0}},
           "axes": {"x": {"line": "l", "address": 1, "drive": "NT86", "unit": "mm",
                          "pulses_per_rev": 4000, "units_per_rev": 10.0, "speed": 20.0,
                          "accel": 200.0, "decel": 200.0}}}
    async with open_machine(cfg) as m:
        x, twin, wire = m.axes["x"], m.sim_drives["x"], m.wires["l"]
        await settle(x)
        seen: list[tuple[float, float, AxisState]] = []  # (when, requested_at, state)
        started = anyio.Event()
        started_at = triggered = math.inf
        held_status = anyio.Event()

        def listener(item: Any) -> None:
            nonlocal started_at
            if isinstance(item, DriveStatus):
                seen.append((monotonic(), item.requested_at, x.state))
                if monotonic() > triggered:
                    held_status.set()
            elif item.kind == "started":
                twin.faults.inject(Fault.SLOW_REPLY, value=0.6)  # the next poll's reply
                started_at = monotonic()
                started.set()

        end_listening = x.listen(listener)
        outcome: list[BaseException | None] = []

        async def move(scope: anyio.CancelScope) -> None:
            with scope:
                try:
                    await x.move_to(x.position or 0.0)
                    outcome.append(None)
                except MotionAborted as exc:
                    outcome.append(exc)

        second_returned = math.inf
        second_called = math.inf

        async def second_halt() -> None:
            nonlocal second_called, second_returned
            await held_status.wait()
            second_called = monotonic()
            await x.halt_now()
            second_returned = monotonic()

        with anyio.fail_after(20):
            async with anyio.create_task_group() as tg:
                scope = anyio.CancelScope()
                tg.start_soon(move, scope)
                await started.wait()
                while not any(r > started_at for r in reads_of(m, "x")):  # noqa: ASYNC110
                    await anyio.sleep(0.002)  # (the wire log is polled) the held poll left
                tg.start_soon(second_halt)
                triggered = monotonic()
                if stopper == "cancel":
                    scope.cancel()
                else:
                    await getattr(x, stopper)()
        end_listening()
        assert not twin.is_moving()
        # the stop's reply and the second one's (emergency stop) both end Stopping
        stop_replied = max(f.end for f in wire.log
                           if f.direction == "reply" and f.address == 1
                           and f.start > triggered and f.data[1] == 0x06)
        after_trigger = [(r, s) for when, r, s in seen if when > triggered]
        assert any(r < triggered for r, _ in after_trigger), "the held poll came back first"
        # the move was ended by the stop (a cancelled caller hears nothing)
        assert [type(e) for e in outcome] == ([] if stopper == "cancel" else [MotionAborted])
        for requested, state in after_trigger:
            if requested < stop_replied:
                assert state is AxisState.STOPPING, (requested - triggered, state, seen)
        assert any(s is AxisState.STANDSTILL and r > stop_replied for r, s in after_trigger)
        # the second emergency stop waited for a status requested after its call
        assert any(second_called < r < second_returned for r in reads_of(m, "x")), (
            frames_text(wire.log, triggered - 0.01))
        assert x.state is AxisState.STANDSTILL


# -- a stop that waits for an aborted motion's I/O keeps the line for itself meanwhile -------


async def test_a_stop_waiting_for_aborted_io_lets_no_other_frame_go_first() -> None:
    """x's move is stopped while its write is on the wire (x's replies come 30 ms late): the
    stop waits for that transaction to end. y's read is queued behind it, and when x's
    reply comes in the process is held up for 5 ms (an observer that blocks the loop, as
    a starved machine does): y's read would find its silence over and leave from the
    reply's callback, before the stopping task runs again. The line begins nothing but
    the stop after the stop was called: no frame leaves between the call and the stop."""
    cfg = {"name": "stop-keeps-line",
           "lines": {"l": {"port": "sim://stop-keeps-line", "settings": "115200 8N1",
                           "timeout": 0.5}},
           "axes": {n: {"line": "l", "address": a, "drive": "NT86", "unit": "mm",
                        "pulses_per_rev": 4000, "units_per_rev": 10.0, "speed": 20.0,
                        "accel": 200.0, "decel": 200.0, "poll": {"moving": 1.0, "idle": 1.0}}
                    for n, a in (("x", 1), ("y", 2))}}
    async with open_machine(cfg) as m:
        x, twin, wire, bus = m.axes["x"], m.sim_drives["x"], m.wires["l"], m.buses["l"]
        await settle(x)
        await x.enable()  # (set up now: the move's I/O is its own writes)
        await x.move_to(1.0)
        twin.faults.inject(Fault.SLOW_REPLY, value=0.03, times=None)
        held_up = False

        def observer(t: Any) -> None:
            nonlocal held_up
            if t.slave == 1 and t.function in (0x06, 0x10) and called < t.end and not held_up:
                held_up = True
                time.sleep(0.005)  # the point: a loop held up (as by the OS)

        called = math.inf
        end_observing = bus.observe(observer)
        outcome: list[str] = []

        async def move() -> None:
            try:
                await x.move_to(3.0)
                outcome.append("done")
            except MotionAborted:
                outcome.append("aborted")

        async def bystander() -> None:
            await bus.slave(2).read_holding_registers(0, 2, priority=Priority.POLL)

        mark = len(wire.log)
        with anyio.fail_after(20):
            async with anyio.create_task_group() as tg:
                tg.start_soon(move)
                while not any(f.direction == "request" and f.address == 1  # noqa: ASYNC110
                              and f.data[1] in (0x06, 0x10) for f in list(wire.log)[mark:]):
                    await anyio.sleep(0.001)  # (the wire log is polled) x's write is out
                tg.start_soon(bystander)
                await anyio.lowlevel.checkpoint()  # y's read is queued behind it
                called = monotonic()
                await x.stop()
        end_observing()
        twin.faults.clear()
        assert held_up, "x's write did not end after the stop was called"
        assert outcome == ["aborted"]
        assert not twin.is_moving()
        stops = [t for k, t in command_frames(m, "x", mark) if k == "stop" and t > called]
        assert stops, frames_text(wire.log, called - 0.05)
        between = requests_between(m, "l", called, stops[0])
        assert between == 0, frames_text(wire.log, called - 0.05)
        cmds = commands(m, "x", mark)
        assert "start" not in cmds[cmds.index("stop"):], cmds
