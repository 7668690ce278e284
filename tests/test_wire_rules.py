"""The wire rules, checked from the simulator's wire log over the real serial stack on a pty."""

from __future__ import annotations

import itertools
import math

import anyio
import pytest
import serial_asyncio

from drivebus import Bus, LineSettings, SerialLine, SlaveHandle
from drivebus.clock import monotonic
from drivebus.errors import LineClosed, ResponseTimeout
from drivebus.line.rtu import frame
from drivebus.sim import RegisterSlave, VirtualWire, WireFrame, sim_bus
from drivebus.timing import switch_silence, timing
from held_up import within_bound
from waits import within
from wirelog import frames_text

MIXED = {
    1: LineSettings.parse("9600 8N1"),
    2: LineSettings.parse("19200 8E1"),
    3: LineSettings.parse("38400 8N2"),
    4: LineSettings.parse("115200 8N1"),
}


async def test_mixed_settings_line_keeps_every_silence() -> None:
    slaves = [RegisterSlave(a, s, initial=[(0, a * 100)]) for a, s in MIXED.items()]
    # A generous timeout: a reply late by a loaded machine must not be retried (the test
    # counts frames); the silences it checks do not depend on the timeout.
    async with sim_bus(slaves, LineSettings.parse("115200 8N1"), timeout=1.0) as (wire, bus):
        handles = {a: bus.slave(a, settings=s) for a, s in MIXED.items()}
        # A deterministic but irregular order: runs of one slave and switches between all.
        order = [a for a in itertools.islice(itertools.cycle([1, 2, 2, 3, 4, 4, 4, 1, 3]), 2000)]
        for i, a in enumerate(order):
            if i % 7 == 0:
                await handles[a].write_register(1, i)
            else:
                assert await handles[a].read_holding_registers(0, 1) == [a * 100]
        requests = wire.requests()
        assert len(requests) == len(order)
        assert wire.violations == 0
        # The 4 000 frames are checked on a worker thread: ~30 ms of CPU (pydantic's
        # equality per frame), the test's own work, not a step of the loop under test.
        wrong = await anyio.to_thread.run_sync(_misplaced_requests, list(wire.log))
        assert wrong == []
        assert bus.stats.total().errors == 0
        assert bus.stats.slave(1).transactions == order.count(1)


def _misplaced_requests(log: list[WireFrame]) -> list[WireFrame]:
    """The requests of ``log`` not sent at their slave's settings after the silence
    required since the frame before (one assert for all: rewritten asserts cost ~2 us
    each)."""
    silences = {(p, s): switch_silence(p, s) for p in (None, *MIXED.values())
                for s in MIXED.values()}
    wrong = []
    previous = None
    for f in log:
        if f.direction == "request" and not (
            f.settings == MIXED[f.address]
            and math.isclose(f.required, silences[previous, f.settings])
            and f.gap >= f.required and f.note == ""
        ):
            wrong.append(f)
        previous = f.settings
    return wrong


async def test_slave_only_understands_its_own_settings() -> None:
    # Same baud rate, other parity: only the side channel can tell them apart on a pty.
    slave = RegisterSlave(5, LineSettings.parse("9600 8E1"))
    async with sim_bus([slave], LineSettings.parse("9600 8N1"), retries=0) as (wire, bus):
        with pytest.raises(ResponseTimeout):
            await bus.slave(5).read_holding_registers(0, 1)
        assert wire.log[-1].note == "settings mismatch"
        with pytest.raises(ResponseTimeout):
            fast = bus.slave(5, settings=LineSettings.parse("19200 8E1"))
            await fast.read_holding_registers(0, 1)
        assert await bus.slave(5, settings=LineSettings.parse("9600 8E1")).read_holding_registers(
            0, 2
        ) == [0, 0]
        assert wire.requests()[-1].settings == LineSettings.parse("9600 8E1")


async def test_frames_take_wire_time() -> None:
    s = LineSettings.parse("9600 8N1")
    async with sim_bus([RegisterSlave(1, s, turnaround=0.002)], s) as (wire, bus):
        await bus.slave(1).read_holding_registers(0, 10)
        req, rep = wire.log[-2], wire.log[-1]
        tm = timing(s)
        assert req.end - req.start == pytest.approx(8 * tm.char_time)
        assert rep.end - rep.start == pytest.approx(25 * tm.char_time)
        assert rep.start - req.end >= 0.002  # the slave's turnaround


@pytest.mark.serial  # the wire stamps the master's bytes when it reads them: load shortens
async def test_broadcast_reaches_all_and_waits_the_turnaround_delay() -> None:
    # The wire stamps a frame when this process reads it from the pty: a process held up
    # between the broadcast's write and that read stamps the gap after it short.
    s = LineSettings.parse("115200 8N1")
    slaves = [RegisterSlave(a, s) for a in (1, 2, 3)]
    async with VirtualWire("bcast") as wire:
        for sl in slaves:
            wire.attach(sl)
        line = SerialLine(wire.url, s, broadcast_delay=0.02)
        async with Bus(line) as bus:

            async def broadcast(n: int) -> float:
                await bus.slave(0).write_registers(10, [7, n])
                assert await bus.slave(2).read_holding_registers(10, 2) == [7, n]
                assert [sl.registers[10:12] for sl in slaves] == [[7, n]] * 3
                bc, nxt = wire.requests()[-2:]
                assert bc.address == 0 and nxt.address == 2
                return 0.02 - (nxt.start - bc.end)

            attempts = await within_bound(broadcast, "20 ms after the broadcast", tries=5)
            assert not [f for f in wire.log if f.direction == "reply" and f.address == 0]
            assert bus.stats.slave(0).broadcasts == attempts


async def test_local_echo_is_consumed() -> None:
    s = LineSettings.parse("115200 8N1")
    async with VirtualWire("echoing", echo=True) as wire:
        wire.attach(RegisterSlave(1, s, initial=[(3, 33)]))
        async with Bus(SerialLine(wire.url, s, local_echo=True)) as bus:
            assert await bus.slave(1).read_holding_registers(3, 1) == [33]
            await bus.slave(1).write_register(3, 44)
            assert await bus.slave(1).read_holding_registers(3, 1) == [44]


async def test_missing_port_is_a_clear_error() -> None:
    with pytest.raises(LineClosed, match="/dev/ttyNOPE"):
        async with Bus(SerialLine("/dev/ttyNOPE")):
            pass
    with pytest.raises(LineClosed, match="no simulated line named 'nothing'"):
        async with Bus(SerialLine("sim://nothing")):
            pass


async def test_rs485_mode_on_a_pty_is_refused_clearly() -> None:
    async with VirtualWire("rs485") as wire:
        with pytest.raises(Exception, match="RS-485 mode"):
            async with Bus(SerialLine(wire.url, rs485=True)):
                pass


async def test_closing_fails_queued_requests_and_never_hangs() -> None:
    s = LineSettings.parse("9600 8N1")
    results: list[BaseException | list[int]] = []

    async def reader(h: SlaveHandle) -> None:
        try:
            results.append(await h.read_holding_registers(0, 1))
        except LineClosed as exc:
            results.append(exc)

    async with anyio.create_task_group() as tg, sim_bus([RegisterSlave(1, s)], s) as (wire, bus):
            h = bus.slave(1)
            for _ in range(20):
                tg.start_soon(reader, h)
            with anyio.fail_after(5):
                await wire.wait_requests(1)  # the first request is on the wire
        # leaving the bus fails what is still queued, and the one in flight
    closed = [r for r in results if isinstance(r, LineClosed)]
    done = [r for r in results if not isinstance(r, LineClosed)]
    assert len(results) == 20
    sent = len(wire.requests())
    assert sent <= 2
    assert len(done) <= sent  # nothing queued was sent after the close
    assert len(closed) == 20 - len(done) >= 18
    with pytest.raises(LineClosed):
        await h.read_holding_registers(0, 1)


async def test_two_whole_frames_in_one_read_are_two_requests_and_the_last_is_answered() -> None:
    """A pty hides the silence between frames: a master's retry read late, together with
    the request it retries, is two requests on the wire, not one with a bad CRC. The
    first is acted on and goes unanswered (its master has moved on); the second is
    answered, and neither is a violation."""
    s = LineSettings.parse("9600 8N1")
    slave = RegisterSlave(1, s, initial=[(5, 862)])
    write = frame(1, bytes.fromhex("06 0005 0007"))
    read = frame(1, bytes.fromhex("03 0005 0001"))
    async with VirtualWire("two-in-one-read") as wire:
        wire.attach(slave)
        reader, writer = await serial_asyncio.open_serial_connection(
            url=wire.slave_path, baudrate=9600
        )
        try:
            writer.write(write + read)  # one write: the wire reads both at once
            try:
                with within(10, "the reply to the second frame on the raw port"):
                    assert await reader.readexactly(7) == frame(1, bytes.fromhex("03 02 0007"))
            except AssertionError as exc:  # what the wire saw and answered, with the failure
                exc.add_note(f"the wire's frames:\n{frames_text(wire.log)}")
                raise
            first, second = wire.requests()
            assert (first.data, first.note) == (write, "unanswered: the next request came with it")
            assert (second.data, second.note) == (read, "")
            assert second.start >= first.end + second.required and wire.violations == 0
            assert [f.data for f in wire.log if f.direction == "reply"] == [
                frame(1, bytes.fromhex("03 02 0007"))
            ]
        finally:
            writer.close()


def rounding_short(before: float, n: int, s: LineSettings) -> float:
    """A time not after ``before`` at which a frame of ``n`` bytes ending then, plus t3.5,
    minus that end, comes out short of t3.5 in floating point (as near half the times
    of the clock do): the wire judged such a silence a violation and answered nothing,
    flakily, with the hour of the clock."""
    tm = timing(s)
    silence = switch_silence(s, s)
    # Whether it rounds short depends mostly on the binade of the time (at some hours of
    # the clock no time within milliseconds does): look in each lower binade in turn.
    base = before
    while base > 1.0:
        for k in range(200):
            t = base - k * 1e-6
            end = t + tm.frame_time(n)
            if (end + silence) - end < silence:
                return t
        base /= 2
    raise AssertionError("no time whose silence rounds short")  # pragma: no cover


async def test_two_frames_handed_over_in_pieces_are_two_requests_and_the_last_is_answered(
) -> None:
    """The kernel may hand one write of two frames to the wire's side in pieces (its
    buffer ending inside the second frame): a whole frame and the start of another are
    not yet a request. Before, the wire took them for one frame with a bad CRC and the
    rest for the start of a broadcast, and nothing was answered. The pieces go straight
    to the wire's segment here, with the times a pty read would give them, at a time whose
    silence between the frames rounds short of t3.5 in floating point."""
    s = LineSettings.parse("9600 8N1")
    slave = RegisterSlave(1, s, initial=[(5, 862)])
    write = frame(1, bytes.fromhex("06 0005 0007"))
    read = frame(1, bytes.fromhex("03 0005 0001"))
    async with VirtualWire("two-in-pieces") as wire:
        wire.attach(slave)
        reader, writer = await serial_asyncio.open_serial_connection(
            url=wire.slave_path, baudrate=9600
        )
        try:
            now = rounding_short(monotonic(), len(write), s)
            wire.segment.feed(write + read[:2], now, s, None)
            assert wire.requests() == []  # not yet: the second frame is still coming
            wire.segment.feed(read[2:], now + 0.0001, s, None)
            try:
                with within(10, "the reply to the second frame on the raw port"):
                    assert await reader.readexactly(7) == frame(1, bytes.fromhex("03 02 0007"))
            except AssertionError as exc:  # what the wire saw and answered, with the failure
                exc.add_note(f"the wire's frames:\n{frames_text(wire.log)}")
                raise
            first, second = wire.requests()
            assert (first.data, first.note) == (write, "unanswered: the next request came with it")
            assert (second.data, second.note) == (read, "")
            assert slave.registers[5] == 7 and wire.violations == 0
        finally:
            writer.close()
