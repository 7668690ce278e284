"""Bus scheduler: priorities, faults, retries, cancellation, statistics."""

from __future__ import annotations

import asyncio
import bisect
import gc
import pickle
import random
import time
from collections.abc import Awaitable

import anyio
import anyio.lowlevel
import pytest

from drivebus import Bus, LineSettings, Priority
from drivebus.bus.sent import sent_requests
from drivebus.bus.stats import LATENCY_BUCKETS, LATENCY_WINDOW, Latency
from drivebus.errors import (
    ArgumentError,
    ConfigError,
    FrameError,
    LineClosed,
    ModbusException,
    ResponseTimeout,
    StateError,
    WrongResponder,
)
from drivebus.line.serial import SerialLine
from drivebus.sim import Fault, RegisterSlave, VirtualWire, sim_bus
from waits import until, within

FAST = LineSettings.parse("115200 8N1")


async def test_emergency_overtakes_every_queued_poll() -> None:
    slaves = [RegisterSlave(a, FAST) for a in range(1, 9)]
    async with sim_bus(slaves, FAST) as (wire, bus):
        handles = [bus.slave(a) for a in range(1, 9)]
        stop = anyio.Event()

        async def poller(h) -> None:  # type: ignore[no-untyped-def]
            while not stop.is_set():
                await h.read_holding_registers(0, 4, priority=Priority.POLL)

        async with anyio.create_task_group() as tg:
            for h in handles:
                for _ in range(3):  # 24 polls queued at any time
                    tg.start_soon(poller, h)
            for i in range(40):
                await wire.wait_requests(wire.request_count + 3 + i % 5)
                before = wire.request_count
                await handles[i % 8].write_register(100, i, priority=Priority.EMERGENCY)
                frames = wire.requests()
                mine = next(
                    k for k in range(len(frames) - 1, -1, -1)
                    if frames[k].data[1] == 0x06 and frames[k].data[4:6] == i.to_bytes(2, "big")
                )
                started_after = wire.request_count - (len(frames) - mine)  # frames before it
                # at most the one transaction already in flight went out before the stop
                assert started_after - before <= 1, (i, started_after - before)
            stop.set()
        assert wire.violations == 0


async def test_fifo_within_a_priority() -> None:
    s = LineSettings.parse("9600 8N1")
    async with sim_bus([RegisterSlave(1, s)], s) as (wire, bus):
        h = bus.slave(1)
        async with anyio.create_task_group() as tg:
            tg.start_soon(h.read_holding_registers, 0, 1)  # occupies the line
            await wire.wait_requests(0)
            await anyio.wait_all_tasks_blocked()
            for v in range(10):
                tg.start_soon(h.write_register, 5, v)
                await anyio.wait_all_tasks_blocked()
        writes = [f.data[4:6] for f in wire.requests() if f.data[1] == 0x06]
        assert writes == [v.to_bytes(2, "big") for v in range(10)]


@pytest.mark.parametrize(
    ("fault", "value", "error", "counter"),
    [
        (Fault.NO_REPLY, None, ResponseTimeout, "timeouts"),
        (Fault.CRC_DAMAGE, None, FrameError, "crc_errors"),
        (Fault.WRONG_ADDRESS, 9, WrongResponder, "wrong_responder"),
        # a reply long after the timeout, however late a busy machine runs the timers
        (Fault.SLOW_REPLY, 0.5, ResponseTimeout, "timeouts"),
    ],
)
async def test_each_fault_gives_its_typed_error_and_the_next_transaction_succeeds(
    fault: Fault, value: float | None, error: type[Exception], counter: str
) -> None:
    slave = RegisterSlave(3, FAST, initial=[(0, 42)])
    async with sim_bus([slave], FAST, timeout=0.05, retries=0) as (wire, bus):
        h = bus.slave(3)
        slave.faults.inject(fault, value=value)
        with pytest.raises(error) as exc:
            await h.read_holding_registers(0, 1)
        assert exc.value.slave == 3  # type: ignore[attr-defined]
        if fault is Fault.SLOW_REPLY:
            # the late reply still comes; it must not be taken for the next answer
            with within(5, "the request and its late reply on the wire"):
                await wire.wait_frames(2)
        assert await h.read_holding_registers(0, 1) == [42]
        st = bus.stats.slave(3)
        assert getattr(st, counter) == 1
        assert st.transactions == 1 and st.errors == 1
        assert wire.violations == 0


async def test_garbage_before_a_reply_is_skipped_and_counted() -> None:
    slave = RegisterSlave(3, FAST, initial=[(0, 42)])
    async with sim_bus([slave], FAST, retries=0) as (_wire, bus):
        slave.faults.inject(Fault.GARBAGE, value=b"\x00\xff\x13")
        assert await bus.slave(3).read_holding_registers(0, 1) == [42]
        assert bus.line.garbage_bytes == 3
        assert await bus.slave(3).read_holding_registers(0, 1) == [42]


async def test_reads_are_retried_commands_never_blindly() -> None:
    slave = RegisterSlave(2, FAST, initial=[(0, 7)])
    async with sim_bus([slave], FAST, timeout=0.03, retries=2) as (wire, bus):
        h = bus.slave(2)
        slave.faults.inject(Fault.NO_REPLY, times=2)
        assert await h.read_holding_registers(0, 1) == [7]
        assert bus.stats.slave(2).retries == 2
        slave.faults.inject(Fault.NO_REPLY, times=1)
        with pytest.raises(ResponseTimeout):
            await h.write_register(18, 1, priority=Priority.COMMAND, idempotent=False)
        starts = [f for f in wire.requests() if f.data[1] == 0x06]
        assert len(starts) == 1  # the drive may have started: never sent twice
        assert slave.registers[18] == 1
        slave.faults.inject(Fault.NO_REPLY, times=1)
        await h.write_register(19, 5)  # an idempotent write may be retried
        assert len([f for f in wire.requests() if f.data[1] == 0x06]) == 3


async def test_modbus_exception_carries_code_and_vendor_text() -> None:
    async with sim_bus([RegisterSlave(4, FAST, size=10)], FAST) as (_wire, bus):
        h = bus.slave(4, exception_texts={2: "vendor: no such parameter"})
        with pytest.raises(ModbusException) as exc:
            await h.read_holding_registers(8, 5)
        assert exc.value.code == 2 and exc.value.function == 3
        assert "vendor: no such parameter" in str(exc.value)
        assert bus.stats.slave(4).exceptions == 1
        assert bus.stats.slave(4).retries == 0  # an exception is an answer, not a failure
        assert await h.read_holding_registers(0, 2) == [0, 0]


async def test_cancelled_request_never_reaches_the_wire() -> None:
    s = LineSettings.parse("9600 8N1")
    slave = RegisterSlave(1, s)
    async with sim_bus([slave], s) as (wire, bus):
        h = bus.slave(1)
        async with anyio.create_task_group() as tg:
            tg.start_soon(h.read_holding_registers, 0, 10)  # occupies the line
            await anyio.wait_all_tasks_blocked()
            with anyio.move_on_after(0):
                await h.write_register(50, 1, idempotent=False)
        await h.read_holding_registers(0, 1)
        assert slave.registers[50] == 0
        assert not [f for f in wire.requests() if f.data[1] == 0x06]


async def test_raw_pdu_path() -> None:
    slave = RegisterSlave(6, FAST, initial=[(1, 0xBEEF)])
    async with sim_bus([slave], FAST) as (wire, bus):
        reply = await bus.slave(6).transact(bytes.fromhex("03 00 01 00 01"))
        assert reply == bytes.fromhex("03 02 BE EF")
        assert wire.requests()[-1].data[:6] == bytes.fromhex("06 03 00 01 00 01")


async def test_bad_arguments_are_refused_before_the_wire() -> None:
    async with sim_bus([RegisterSlave(1, FAST)], FAST) as (wire, bus):
        with pytest.raises(ConfigError, match=r"outside 0\.\.247"):
            bus.slave(300)
        with pytest.raises(ConfigError, match="broadcast"):
            await bus.slave(0).read_holding_registers(0, 1)
        with pytest.raises(ArgumentError, match=r"register count: 0 is outside 1\.\.125"):
            await bus.slave(1).read_holding_registers(0, 0)
        with pytest.raises(ArgumentError, match="65536"):
            await bus.slave(1).write_register(0, 65536)
        assert wire.request_count == 0


async def test_a_refused_register_read_raises_where_it_is_awaited() -> None:
    """A register read is the bus's ``execute`` coroutine, made without a coroutine of its
    own: a read refused before the queue still raises when awaited, not when called (as
    any coroutine function's), and one never awaited sends nothing."""
    async with sim_bus([RegisterSlave(1, FAST, initial=[(0, 7), (1, 8)])], FAST) as (
            wire, bus):
        h = bus.slave(1)
        refused = [bus.slave(0).read_input_registers(0, 1), h.read_holding_registers(0, 0),
                   h.read_holding_registers(0, 1, priority=99)]  # type: ignore[arg-type]
        for read, error in zip(refused, (ConfigError, ArgumentError, ArgumentError),
                               strict=True):
            with pytest.raises(error):
                await read
        assert wire.request_count == 0
        assert await asyncio.gather(h.read_holding_registers(0, 2),
                                    h.read_input_registers(1, 1)) == [[7, 8], [8]]


@pytest.mark.serial  # bounds wire time against wall time: load stretches it
async def test_stats_and_utilisation() -> None:
    s = LineSettings.parse("19200 8E1")
    async with sim_bus([RegisterSlave(1, s)], s) as (_wire, bus):
        for _ in range(50):
            await bus.slave(1).read_holding_registers(0, 2)
        st = bus.stats
        assert st.slave(1).transactions == 50 and st.transactions == 50
        # The bus's replies and reply time are its slaves' (counted once, per slave).
        assert st.replies == 50
        assert st.reply_time == pytest.approx(sum(st.slave(1).latency.window))
        assert st.reply_time > 50 * 9 * 11 / 19200  # each reply's own bytes, at least
        per = (8 + 9) * 11 / 19200
        assert st.wire_time == pytest.approx(50 * per)
        assert 0.2 < st.utilisation < 1.0


def test_the_latency_histogram_and_sum_take_in_every_reply() -> None:
    """Replies are binned in batches (``Latency.add`` only appends and counts): whenever
    read, the histogram, the sum and the count are those of every reply added, well
    beyond the window, also after a pickle (a worker's report) and a merge."""
    rng = random.Random(37)
    values = [rng.choice(LATENCY_BUCKETS) if i % 7 == 0 else rng.uniform(0.0, 1.2)
              for i in range(2 * LATENCY_WINDOW + 345)]  # (a bound is in its own bucket)
    lat = Latency()
    buckets = [0] * (len(LATENCY_BUCKETS) + 1)
    total = 0.0
    for i, v in enumerate(values):  # read early, then not for more than a window
        lat.add(v)
        buckets[bisect.bisect_left(LATENCY_BUCKETS, v)] += 1
        total += v
        if i in (0, 5, LATENCY_WINDOW - 2, LATENCY_WINDOW - 1):
            assert lat.buckets == buckets and lat.sum == pytest.approx(total), i
    assert lat.count == len(values) and list(lat.window) == values[-LATENCY_WINDOW:]
    copy = pickle.loads(pickle.dumps(lat))  # (unbinned replies travel in the window)
    assert copy.buckets == buckets and copy.sum == pytest.approx(total)
    assert lat.cumulative()[-1] == (float("inf"), len(values))
    assert [n for _, n in lat.cumulative()] == [sum(buckets[:k + 1])
                                                 for k in range(len(buckets))]
    other = Latency()
    for v in values[:123]:
        other.add(v)
    line = Latency()
    line.merge(lat)
    line.merge(other)
    assert line.count == len(values) + 123
    assert line.buckets == [a + b for a, b in zip(buckets, other.buckets, strict=True)]
    assert line.sum == pytest.approx(total + sum(values[:123]))
    line.add(0.004)  # (a merged total goes on counting)
    assert line.count == len(values) + 124 and line.buckets[4] == buckets[4] + \
        other.buckets[4] + 1


async def test_a_hold_takes_back_a_request_waiting_for_its_silence_and_it_goes_after() -> None:
    """A request still waiting for its silence when a hold begins is taken back: the
    hold's stop goes first, the request after the hold. Each round begins with a
    broadcast, after which the line keeps quiet for its broadcast delay (0.5 s), so that
    the request surely still waits when the hold begins (with the line's own 4 ms alone, a
    test task held up that long on a loaded machine found it sent)."""
    s = LineSettings.parse("9600 8N1")
    async with VirtualWire("hold-takes-back") as wire:
        wire.attach(RegisterSlave(1, s))
        async with Bus(SerialLine(wire.url, s, broadcast_delay=0.5), timeout=0.1) as bus:
            h, everyone = bus.slave(1), bus.slave(0)
            for i in range(3):
                await everyone.write_register(70, i)  # the line is kept quiet for 0.5 s
                async with anyio.create_task_group() as tg:
                    tg.start_soon(h.read_holding_registers, 7, 1 + i)  # waits its silence
                    await anyio.wait_all_tasks_blocked()
                    async with bus.hold():  # takes it back: nothing else but stops goes out
                        await h.write_register(60, i, priority=Priority.EMERGENCY)
    frames = wire.requests()
    for i in range(3):
        stop = next(k for k, f in enumerate(frames)
                    if f.data[1] == 0x06 and f.data[2:4] == (60).to_bytes(2, "big")
                    and f.data[4:6] == i.to_bytes(2, "big"))
        poll = next(k for k, f in enumerate(frames)
                    if f.data[1] == 0x03 and f.data[2:4] == (7).to_bytes(2, "big")
                    and f.data[4:6] == (1 + i).to_bytes(2, "big"))
        assert stop < poll, (i, stop, poll)  # the poll went after the hold's stop
    assert wire.violations == 0


async def test_a_stop_to_another_slave_does_not_wait_out_a_guard_interval() -> None:
    """A stop queued while the owner keeps a slave's guard interval (here 1 s) is planned
    again at once: it leaves after the line's own silence, long before the guard is over,
    and the guarded read still keeps its whole guard after the stop. Before, the owner
    woke for the stop and then spun on the clock until the guard's end (holding the event
    loop that long: the loop-step guard fails that too), so the stop waited it out."""
    async with sim_bus([RegisterSlave(1, FAST), RegisterSlave(2, FAST)], FAST) as (wire, bus):
        guarded, other = bus.slave(1, guard=1.0), bus.slave(2)
        await other.read_holding_registers(0, 1)
        with within(30, "the stop, then the guarded read"):
            async with anyio.create_task_group() as tg:
                tg.start_soon(guarded.read_holding_registers, 7, 1)  # waits its 1 s guard
                await anyio.wait_all_tasks_blocked()
                await other.write_register(60, 1, priority=Priority.EMERGENCY)
        last_read, stop, read = wire.requests()[-3:]
        assert (stop.address, stop.data[1], read.address) == (2, 0x06, 1)
        replies = [f for f in wire.log if f.direction == "reply"]
        before_stop = max(f.end for f in replies if f.end <= stop.start)
        assert before_stop >= last_read.end
        assert stop.start - before_stop < 0.5  # it did not wait for the guard's 1 s
        stop_reply = min((f for f in replies if f.start >= stop.end), key=lambda f: f.start)
        assert read.start - stop_reply.end >= 1.0  # the guard, counted from the stop's reply
        assert wire.violations == 0


async def test_a_request_below_emergency_inside_its_own_hold_is_refused_not_hung() -> None:
    """Inside its own hold a task's request below EMERGENCY would wait for the hold's end
    (forever): it is refused at once, nothing sent; an emergency one goes out, and
    another task's request waits for the hold and then goes."""
    s = LineSettings.parse("115200 8N1")
    async with sim_bus([RegisterSlave(1, s)], s) as (wire, bus):
        h = bus.slave(1)
        await h.read_holding_registers(0, 1)
        others: list[list[int]] = []
        with anyio.fail_after(10):
            async with anyio.create_task_group() as tg, bus.hold():
                before = len(wire.requests())
                for priority in (Priority.POLL, Priority.CONFIG, Priority.COMMAND):
                    with pytest.raises(StateError, match="inside this task's own hold"):
                        await h.read_holding_registers(0, 1, priority=priority)
                assert len(wire.requests()) == before  # nothing was sent
                tg.start_soon(lambda: _append(others, h.read_holding_registers(0, 2)))
                await h.write_register(3, 7, priority=Priority.EMERGENCY)
                assert others == []  # the other task's read waits for the hold
        assert others == [[0, 0]]
        frames = wire.requests()[before:]
        assert [f.data[1] for f in frames] == [0x06, 0x03]  # the stop, then the read


async def _append(out: list[list[int]], read: Awaitable[list[int]]) -> None:
    out.append(await read)


async def test_a_write_cancelled_in_its_silence_is_withdrawn_or_reported() -> None:
    s = LineSettings.parse("9600 8N1")
    slave = RegisterSlave(1, s)
    async with sim_bus([slave], s) as (wire, bus):
        h = bus.slave(1)
        for i, delay in enumerate((0.0, 0.001, 0.002, 0.003, 0.004, 0.006, 0.01, 0.02)):
            await h.read_holding_registers(0, 1)  # the line just carried a reply
            with sent_requests() as sent:
                with anyio.move_on_after(delay):
                    await h.write_register(50, 100 + i, idempotent=False)
            on_wire = [f for f in wire.requests() if f.data[1] == 0x06
                       and f.data[4:6] == (100 + i).to_bytes(2, "big")]
            # withdrawn before its first byte (nothing on the wire, nothing reported) or
            # on the wire and reported (its caller cancelled or not)
            assert len(on_wire) == len(sent) <= 1, (delay, on_wire, sent)
            assert (slave.registers[50] == 100 + i) == bool(on_wire), delay
        assert wire.violations == 0


async def _stalled_read(bus: Bus, wire: VirtualWire, *, after_read: bool) -> list[int]:
    """One read during which the whole process stops for 0.2 s, four timeouts (as a busy
    machine stops it): right after the request went out, or once the slave read it."""

    async def stall() -> None:
        if after_read:
            await wire.wait_requests(wire.request_count + 1)
        else:
            await anyio.lowlevel.checkpoint()
        time.sleep(0.2)  # noqa: ASYNC251 - the process stops, the simulated slave with it

    async with anyio.create_task_group() as tg:
        tg.start_soon(stall)
        try:
            return await bus.slave(1).read_holding_registers(0, 1)
        except ResponseTimeout as exc:
            timeout = exc  # raised here, not in the task group's exception group
    raise timeout


async def test_a_stalled_process_is_no_timeout_of_a_slave_in_it() -> None:
    """The simulated slave runs in the master's process: when the process stops past the
    reply's deadline, the slave could not answer either. The master does not decide that
    deadline until the slave has had a moment to run (it had the reply ready, or it reads
    the request now): no false ``ResponseTimeout`` (before: 4 in 10 such reads)."""
    slave = RegisterSlave(1, FAST, initial=[(0, 42)])
    async with sim_bus([slave], FAST, timeout=0.05, retries=0) as (wire, bus):
        for i in range(10):
            assert await _stalled_read(bus, wire, after_read=i % 2 == 0) == [42]
        assert bus.stats.slave(1).timeouts == 0
        # a slave that is dead still times out, stall or no stall
        slave.faults.inject(Fault.NO_REPLY, times=2)
        with pytest.raises(ResponseTimeout):
            await _stalled_read(bus, wire, after_read=True)
        with pytest.raises(ResponseTimeout):
            await bus.slave(1).read_holding_registers(0, 1)


async def test_a_reply_deadline_puts_no_timer_in_the_event_loop() -> None:
    """A reply's deadline is a kernel timer (``DeadlineTimer``; issue 37): the receiver's
    asyncio timer used to sit in the event loop's heap, and each turn of the loop read
    the clock and worked out its timeout (11k of 165k instructions per transaction). The
    deadline itself still holds (``test_each_fault_gives_its_typed_error...``, no reply)."""
    async with sim_bus([RegisterSlave(1, FAST)], FAST) as (_wire, bus):
        h = bus.slave(1)
        for _ in range(3):
            assert await h.read_holding_registers(0, 2) == [0, 0]
        loop = asyncio.get_running_loop()
        owners = {type(getattr(t._callback, "__self__", None)).__name__
                  for t in loop._scheduled if not t.cancelled()}  # type: ignore[attr-defined]
        assert "RtuReceiver" not in owners, owners


async def test_closing_the_bus_mid_transaction_reports_it_and_leaves_no_outcome_unread() -> None:
    """A read begun from its caller onto an idle line (a chained transaction) is on the
    wire when the bus closes: its caller gets LineClosed, and the line's own record of
    that transaction (its job, failed by the line's loss) is read too: asyncio logs
    "Future exception was never retrieved" for none of them."""
    loop = asyncio.get_running_loop()
    unread: list[str] = []
    previous = loop.get_exception_handler()
    loop.set_exception_handler(lambda _loop, ctx: unread.append(str(ctx.get("message"))))
    try:
        outcomes: list[str] = []
        for delay in (0.002, 0.01, 0.02):
            slave = RegisterSlave(1)
            slave.faults.inject(Fault.SLOW_REPLY, value=0.05, times=None)  # still on the wire
            async with anyio.create_task_group() as tg, \
                    sim_bus([slave], timeout=0.5) as (wire, bus):

                async def read(bus: Bus = bus) -> None:
                    try:
                        await bus.slave(1).read_holding_registers(0, 2)
                        outcomes.append("read")
                    except LineClosed:
                        outcomes.append("LineClosed")

                tg.start_soon(read)
                await until(lambda w=wire: w.request_count > 0, "the read on the wire",
                            every=0.001)
                await anyio.sleep(delay)
        gc.collect()
        await anyio.lowlevel.checkpoint()
        gc.collect()
        assert outcomes == ["LineClosed"] * 3
        assert unread == []
    finally:
        loop.set_exception_handler(previous)
