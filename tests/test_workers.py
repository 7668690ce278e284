"""Lines served by worker processes (``workers`` in the machine file), judged by the twins
and the wire logs of the simulators, which stay in the test's process.

The axes, the application layer and the simulators stay here; each worker owns its
lines' schedulers and timing. Across the process boundary the promises hold: a stop
overtakes what was queued before it and reaches the wire within one transaction of the
line, a worker that dies makes its axes Offline at once and is started again, leaving
the machine stops every axis first, a cancelled write is reported.
"""

from __future__ import annotations

import contextlib
import functools
import gc
import os
import signal
import tomllib
from pathlib import Path
from typing import Any

import anyio
import pytest

from drivebus import AxisState, Priority, open_machine
from drivebus.bus.sent import sent_requests
from drivebus.config import machine_config
from drivebus.errors import (
    ConfigError,
    ConnectionLost,
    DriveOffline,
    ModbusException,
    MotionAborted,
)
from drivebus.motion import Axis, Machine
from drivebus.motion.workers import RemoteBus, auto_workers, placement

DEMO = Path(__file__).resolve().parents[1] / "configs" / "demo.toml"


def demo(name: str, workers: int | str = 1) -> dict[str, Any]:
    """The demo machine with a ``sim://`` name of its own, served by ``workers``."""
    cfg = tomllib.loads(DEMO.read_text())
    cfg["workers"] = workers
    for line in cfg["lines"].values():
        for key in ("port", "host"):
            if key in line:
                line[key] = line[key].replace("sim://demo", f"sim://{name}")
    return cfg


async def settle(ax: Axis, timeout: float = 10.0) -> None:
    """Until the axis's actor has seen the drive at rest in a motion-free state."""
    with anyio.fail_after(timeout):
        async for st in ax.watch():
            if not st.moving and ax.state in (AxisState.STANDSTILL, AxisState.DISABLED):
                return


async def until(what: str, check: Any, timeout: float = 10.0) -> None:
    """Until ``check()`` is true (bounded: ``timeout`` s, then the test fails naming it)."""
    with anyio.fail_after(timeout):
        while not check():  # noqa: ASYNC110 - the twins and the machine are the judges
            await anyio.sleep(0.005)
    assert check(), what


def test_workers_is_a_count_or_auto_and_auto_leaves_a_core_to_the_machine() -> None:
    assert machine_config(demo("w-cfg", "auto")).workers == "auto"
    assert machine_config(demo("w-cfg", 3)).workers == 3
    for bad in (-1, "many", 1.5, True, 65):
        with pytest.raises(ConfigError, match="workers"):
            machine_config(demo("w-cfg", bad))
    assert auto_workers(4, cores=16) == 0  # a few lines: one process serves them
    assert auto_workers(16, cores=1) == 0
    assert auto_workers(16, cores=2) == 1  # the other core is the machine's
    assert auto_workers(16, cores=16) == 4
    assert auto_workers(5, cores=16) == 2
    assert placement(["a", "b", "c"], 2) == [["a", "c"], ["b"]]
    assert placement(["a"], 4) == [["a"]]


async def test_a_machine_with_a_worker_moves_polls_and_reports_as_without() -> None:
    async with open_machine(demo("w-basic")) as m:
        assert all(isinstance(b, RemoteBus) for b in m.buses.values())
        (w,) = m.workers
        assert w["lines"] == ["rs485", "eth"] and w["pid"] != os.getpid()
        assert w["state"] == "serving"
        x = m.axes["x"]
        await x.enable()
        await x.move_to(20.0)
        assert m.sim_drives["x"].position() == x.units.to_pulses(20.0)
        await m.group("x", "y", "r").move_to({"x": 5.0, "y": 10.0, "r": 30.0})
        for name, target in (("x", 5.0), ("y", 10.0), ("r", 30.0)):
            ax = m.axes[name]
            assert m.sim_drives[name].position() == ax.units.to_pulses(target)
        # the worker's statistics and observed transactions come back
        seen: list[Any] = []
        end = m.buses["rs485"].observe(seen.append)
        await until("transactions observed", lambda: len(seen) >= 10)
        end()
        assert {t.slave for t in seen} <= {2, 3, 4, 1}
        await until("statistics reported",
                    lambda: m.buses["rs485"].stats.slave(2).transactions > 10)
        # a raw register read of a tool, and its exception reply, typed as without workers
        h = m.buses["rs485"].slave(2)
        assert len(await h.read_holding_registers(0, 2)) == 2
        with pytest.raises(ModbusException):
            await h.read_holding_registers(0x7FF0, 1)


async def _quietly(call: Any, *args: Any, **kwargs: Any) -> None:
    """``call`` whose exception reply (a register the drive lacks) is expected."""
    with contextlib.suppress(ModbusException):
        await call(*args, **kwargs)


STOP_REGISTER = 0x7FF0
"""A register none of the demo's drives has: writes to it are answered with an exception,
after their frame was on the wire, which is all these tests look at."""


async def test_an_emergency_write_goes_before_the_polls_queued_after_it() -> None:
    async with open_machine(demo("w-order")) as m:
        bus = m.buses["rs485"]
        stop = bus.slave(2)
        polls = [bus.slave(a, settings=m.axes[n].config.settings)
                 for a, n in ((2, "x"), (3, "y"), (4, "z"))]
        wire: Any = m.wires["rs485"]
        for i in range(20):
            async with anyio.create_task_group() as tg:  # queued in this order, one turn
                tg.start_soon(functools.partial(_quietly, stop.write_register, STOP_REGISTER,
                                                i, priority=Priority.EMERGENCY))
                for k, h in enumerate(polls * 2):
                    tg.start_soon(_quietly, h.read_holding_registers, STOP_REGISTER + 1 + k,
                                  1 + i)
        frames = wire.requests()
        assert wire.violations == 0
        for i in range(20):
            order = [n for n, f in enumerate(frames)
                     if (f.data[1] == 0x06 and f.data[2:6] == bytes.fromhex("7ff0")
                         + i.to_bytes(2, "big"))
                     or (f.data[1] == 0x03 and f.data[4:6] == (1 + i).to_bytes(2, "big")
                         and int.from_bytes(f.data[2:4], "big") > STOP_REGISTER)]
            assert len(order) == 7, (i, order)
            assert frames[order[0]].data[1] == 0x06, i  # the stop left first


@pytest.mark.parametrize("how", [signal.SIGKILL, signal.SIGSTOP], ids=["dies", "hangs"])
async def test_a_worker_that_dies_makes_its_axes_offline_at_once_and_comes_back(
        how: signal.Signals) -> None:
    """Killed, or stopped (hung: its lines' stops could not leave; nothing noticed it, and
    a stop or a cancelled move waited 30 s for a drive that ran on): its axes go Offline,
    at once or once the watchdog has heard nothing for 1.5 s and killed it."""
    async with open_machine(demo(f"w-death-{how.name}")) as m:
        x = m.axes["x"]
        twin = m.sim_drives["x"]
        await x.enable()
        outcome: list[BaseException] = []

        async def move() -> None:
            try:
                await x.move_to(380.0)
            except (DriveOffline, MotionAborted, ConnectionLost) as exc:
                outcome.append(exc)

        async with anyio.create_task_group() as tg:
            tg.start_soon(move)
            await until("x moving", twin.is_moving)
            bus = m.buses["rs485"]
            counted = (bus.stats.transactions, bus.stats.wire_time, bus.stats.started)
            pid = m.workers[0]["pid"]
            os.kill(pid, how)
            # at once: every axis of its lines is Offline, the move ends with DriveOffline
            await until("axes offline",
                        lambda: all(a.state is AxisState.OFFLINE for a in m.axes.values()),
                        timeout=5.0)
        # the move ends with the drive Offline, or with the transaction the worker's death
        # cut off (a move still being committed): either names the worker
        assert len(outcome) == 1 and isinstance(outcome[0], DriveOffline | ConnectionLost)
        assert "worker process" in str(outcome[0])
        # started again: the axes answer again, and the drive that kept moving with no
        # command is stopped
        await until("worker restarted", lambda: m.workers[0]["pid"] not in (None, pid),
                    timeout=60.0)
        await until("axes back", lambda: all(
            a.state is not AxisState.OFFLINE for a in m.axes.values()), timeout=30.0)
        assert m.workers[0]["restarts"] == 1
        await settle(x, timeout=30.0)
        assert not twin.is_moving()
        await x.move_to(10.0)
        assert twin.position() == x.units.to_pulses(10.0)
        # the line's counters go on from where they were (the new worker's begin at 0)
        assert m.workers[0]["pid"] not in (None, pid)
        await until("the new worker's counters", lambda: bus.stats.transactions > counted[0])
        assert bus.stats.wire_time > counted[1] and bus.stats.started == counted[2]


async def test_a_handle_collected_in_another_thread_leaves_the_worker_channel_working(
) -> None:
    """A slave handle of a worker's line, collected by the garbage collector in a worker
    thread (a handle in a reference cycle: an exception's traceback is enough): its
    finalizer, which tells the worker, ran in that thread, found no event loop and left
    the channel to the worker stuck, every later request waiting for ever."""
    async with open_machine(demo("w-gc")) as m:
        bus = m.buses["rs485"]
        assert isinstance(bus, RemoteBus)
        tmp = bus.slave(2)  # x's NT86, at the line's settings
        await tmp.read_holding_registers(0, 2)  # the worker knows the handle now
        cycle: list[Any] = [tmp]
        cycle.append(cycle)
        del tmp, cycle
        await anyio.to_thread.run_sync(gc.collect)  # its finalizer runs in that thread
        with anyio.fail_after(10):
            assert len(await bus.slave(2).read_holding_registers(0, 2)) == 2
            await m.axes["x"].refresh()


async def test_leaving_a_machine_with_workers_stops_every_axis_first() -> None:
    targets = {"x": 390.0, "y": 190.0, "z": 95.0, "r": 700.0}
    aborted: list[str] = []

    async def move(m: Machine, name: str) -> None:
        try:
            await m.axes[name].move_to(targets[name])
        except (MotionAborted, DriveOffline):
            aborted.append(name)

    async with anyio.create_task_group() as outer:  # the moves outlive the machine's block
        async with open_machine(demo("w-leave")) as m:
            twins = {n: m.sim_drives[n] for n in targets}
            for name in targets:
                await m.axes[name].enable()
                outer.start_soon(move, m, name)
            await until("all moving", lambda: all(t.is_moving() for t in twins.values()))
        # left while all four moved: each was stopped before its line closed
        assert not any(t.is_moving() for t in twins.values())
    assert sorted(aborted) == sorted(targets)


async def test_a_write_cancelled_before_or_on_the_wire_is_reported_through_the_worker(
) -> None:
    async with open_machine(demo("w-cancel")) as m:
        h = m.buses["rs485"].slave(2)
        wire: Any = m.wires["rs485"]
        for i, delay in enumerate((0.0, 0.0003, 0.0006, 0.001, 0.002, 0.003, 0.005, 0.01)):
            with sent_requests() as sent:
                async with anyio.create_task_group() as tg:
                    tg.start_soon(_quietly, h.write_register, STOP_REGISTER, 100 + i)
                    await anyio.sleep(delay)
                    tg.cancel_scope.cancel()
            # either withdrawn before its first byte (not listed) or on the wire and listed
            on_wire = [f for f in wire.requests() if f.data[1] == 0x06
                       and f.data[2:6] == STOP_REGISTER.to_bytes(2, "big")
                       + (100 + i).to_bytes(2, "big")]
            assert len(sent) == len(on_wire) <= 1, (delay, sent, on_wire)
            assert all(s.slave == 2 and s.function == 0x06 for s in sent)


async def test_a_worker_bus_takes_the_slave_addresses_its_line_takes() -> None:
    """A slave handle on a worker's line is made and checked as ``Bus.slave`` makes it:
    Modbus TCP's unit id 255 is taken, an RTU address above 247 is refused."""
    async with open_machine(demo("w-addresses")) as m:
        assert isinstance(m.buses["eth"], RemoteBus)
        assert m.buses["eth"].slave(255).address == 255
        with pytest.raises(ConfigError, match=r"248 is outside 0\.\.247"):
            m.buses["rs485"].slave(248)
