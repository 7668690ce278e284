"""The frame leaves from the silence timer's callback and a waiting request can be taken
back: zero gap violations and correct replies whichever way a request goes. No timing
is asserted."""

from __future__ import annotations

import anyio

from drivebus import LineSettings, Priority
from drivebus.sim import RegisterSlave, sim_bus

SLOW = LineSettings.parse("9600 8N1")  # t3.5 of 4 ms: requests wait long in their silence
MIXED = [LineSettings.parse(s) for s in ("9600 8N1", "19200 8E1", "38400 8N2", "115200 8N1")]


def _slaves(settings: list[LineSettings]) -> list[RegisterSlave]:
    return [
        RegisterSlave(a, settings[(a - 1) % len(settings)],
                      initial=[(r, 100 * a + r) for r in range(8)])
        for a in range(1, 5)
    ]


async def _poller(h, stop: anyio.Event, bad: list[object]) -> None:  # type: ignore[no-untyped-def]
    while not stop.is_set():
        got = await h.read_holding_registers(1, 3, priority=Priority.POLL)
        if got != [100 * h.address + r for r in (1, 2, 3)]:
            bad.append((h.address, got))


async def test_a_hold_takes_back_the_poll_waiting_for_its_silence() -> None:
    async with sim_bus(_slaves([SLOW]), SLOW) as (wire, bus):
        handles = [bus.slave(a) for a in range(1, 5)]
        stop = anyio.Event()
        bad: list[object] = []
        async with anyio.create_task_group() as tg:
            for h in handles:
                tg.start_soon(_poller, h, stop, bad)
            for i in range(10):
                await wire.wait_requests(wire.request_count + 2)
                async with anyio.create_task_group() as starts, bus.hold():
                    before = wire.request_count
                    for h in handles:  # a group's start commands, queued while held
                        starts.start_soon(h.write_register, 7, i)
                    await anyio.sleep(0.01)  # polls queue meanwhile, and wait
                    assert wire.request_count == before  # nothing left while held
                # the commands left first, back to back, no poll among them
                burst = wire.requests()[before: before + 4]
                assert [f.data[1] for f in burst] == [0x06] * 4, burst
            stop.set()
        assert bad == []
        assert wire.violations == 0


async def test_per_slave_settings_switched_during_the_silence_keep_the_wire_rules() -> None:
    async with sim_bus(_slaves(MIXED), MIXED[0]) as (wire, bus):
        handles = [bus.slave(a, settings=MIXED[(a - 1) % 4]) for a in range(1, 5)]
        stop = anyio.Event()
        bad: list[object] = []
        async with anyio.create_task_group() as tg:
            for h in handles:
                for _ in range(2):
                    tg.start_soon(_poller, h, stop, bad)
            for i in range(20):  # stops overtaking polls queued at other settings
                await wire.wait_requests(wire.request_count + 3)
                await handles[i % 4].write_register(7, i, priority=Priority.EMERGENCY)
            stop.set()
        assert bad == []
        assert wire.violations == 0
        assert all(f.note == "" for f in wire.log), [f for f in wire.log if f.note][:3]
