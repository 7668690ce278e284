"""Flooded lines: a babbling device (or a peer sending junk) costs bounded work, fails only
its own line's calls, typed and within their timeout, and the line recovers when it stops.

Every case runs a heartbeat task and a healthy serial line polled beside the flooded one;
progress and ordering are asserted, never timings (the max loop lag is in the bench).

Flat out (and Modbus TCP junk) the medium always holds junk the master has not read yet,
so every call must end in ``LineNoise``. At the line's rate the simulated babbler shares
this process: if the machine stalls the whole process for longer than t3.5, the noise
really pauses and the master is right to send in the gap; such a call may then end in
another transaction error (bad frame, no reply), still typed and naming the line.
"""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass

import anyio
import pytest

from drivebus import Bus, LineSettings, Priority, RtuOverTcpLine, SerialLine, TcpLine
from drivebus.errors import FrameError, LineNoise, ResponseTimeout, TransactionError
from drivebus.sim import RegisterSlave, SimSerialServer, SimTcpServer, VirtualWire

HEALTHY = LineSettings.parse("115200 8N1")
FLOODED = LineSettings.parse("9600 8N1")
HOST = "127.0.0.1"


class Progress:
    """Counters that background tasks advance: heartbeats of the event loop, healthy polls."""

    def __init__(self) -> None:
        self.beats = 0
        self.polls = 0
        self._changed = anyio.Event()

    def beat(self) -> None:
        self.beats += 1
        self._notify()

    def poll(self) -> None:
        self.polls += 1
        self._notify()

    def _notify(self) -> None:
        self._changed.set()
        self._changed = anyio.Event()

    def snapshot(self) -> tuple[int, int]:
        return self.beats, self.polls

    def advanced_since(self, snap: tuple[int, int]) -> bool:
        return self.beats > snap[0] and self.polls > snap[1]

    async def wait_advance(self, snap: tuple[int, int]) -> None:
        while not self.advanced_since(snap):
            await self._changed.wait()


@dataclass
class Flooded:
    """A line that can be flooded: its bus, the slave on it, and the noise source."""

    bus: Bus
    victim: RegisterSlave
    line_name: str
    babbling: Callable[[], contextlib.AbstractAsyncContextManager[None]]
    noise_bytes: Callable[[], int]
    request_violations: Callable[[float], int]
    """Requests that started after the given time without their silence."""


@contextlib.asynccontextmanager
async def flooded_line(kind: str) -> AsyncIterator[Flooded]:
    """``kind``: "serial", "serial flat-out", "rtu+tcp", "rtu+tcp flat-out", "tcp"."""
    victim = RegisterSlave(1, FLOODED, initial=[(0, 22)])
    flat_out = kind.endswith("flat-out")
    if kind.startswith("serial"):
        async with (
            VirtualWire(f"flood-{kind.replace(' ', '-')}") as wire,
            Bus(SerialLine(wire.url, FLOODED), timeout=0.1, retries=2) as bus,
        ):
            wire.attach(victim)
            yield Flooded(
                bus, victim, wire.url, lambda: wire.babbling(flat_out=flat_out),
                lambda: wire.noise_bytes,
                lambda t: sum(f.violation for f in wire.requests() if f.start > t),
            )
    elif kind.startswith("rtu+tcp"):
        async with SimSerialServer([victim], FLOODED) as srv:
            line = RtuOverTcpLine(HOST, srv.port, FLOODED)
            async with Bus(line, timeout=0.1, retries=2) as bus:
                yield Flooded(
                    bus, victim, line.name, lambda: srv.babbling(flat_out=flat_out),
                    lambda: srv.segment.noise_bytes,
                    lambda t: sum(f.violation for f in srv.requests() if f.start > t),
                )
    else:
        async with SimTcpServer([victim]) as srv:
            line = TcpLine(HOST, srv.port)
            async with Bus(line, timeout=0.1, retries=2) as bus:
                yield Flooded(
                    bus, victim, line.name, srv.babbling, lambda: srv.noise_bytes, lambda t: 0
                )


@pytest.mark.parametrize(
    "kind", ["serial", "serial flat-out", "rtu+tcp", "rtu+tcp flat-out", "tcp"]
)
async def test_flooded_line_fails_its_calls_typed_and_recovers(kind: str) -> None:
    progress = Progress()
    async with (
        VirtualWire(f"flood-healthy-{kind.replace(' ', '-')}") as healthy_wire,
        Bus(SerialLine(healthy_wire.url, HEALTHY)) as healthy,
        flooded_line(kind) as flood,
        anyio.create_task_group() as tg,
    ):
        healthy_wire.attach(RegisterSlave(1, HEALTHY, initial=[(0, 11)]))

        async def heartbeat() -> None:
            while True:
                await anyio.sleep(0.002)
                progress.beat()

        async def poller() -> None:
            while True:
                assert await healthy.slave(1).read_holding_registers(0, 1) == [11]
                progress.poll()

        tg.start_soon(heartbeat)
        tg.start_soon(poller)
        target = flood.bus.slave(1)
        assert await target.read_holding_registers(0, 1) == [22]
        strict = kind.endswith("flat-out") or kind == "tcp"
        expected = LineNoise if strict else (LineNoise, FrameError, ResponseTimeout)
        async with flood.babbling():
            for i in range(4):
                snap = progress.snapshot()
                with anyio.fail_after(10), pytest.raises(TransactionError) as exc:  # hang guard
                    if i % 2:
                        await target.write_register(
                            5, 100 + i, priority=Priority.COMMAND, idempotent=False
                        )
                    else:
                        await target.read_holding_registers(0, 1)
                err = exc.value
                assert isinstance(err, expected), err
                assert flood.line_name in str(err) and err.slave == 1, err
                if isinstance(err, LineNoise):
                    assert err.line == flood.line_name
                    if not err.sent:  # not sent: certainly not executed
                        assert (5, [100 + i]) not in flood.victim.writes
                # the event loop and the healthy line keep going while the flood goes on
                with anyio.fail_after(10):
                    await progress.wait_advance(snap)
        # A request the master sent just before the babbler's last bytes (the same event
        # loop runs both) may reach the server after them: a collision with a device
        # that never waits, not a silence the master skipped. Judge what left after it.
        quiet_since = anyio.current_time() + 0.01
        assert flood.noise_bytes() > 0
        with anyio.fail_after(10):  # recovered by itself
            assert await target.read_holding_registers(0, 1) == [22]
            await target.write_register(5, 7, priority=Priority.COMMAND, idempotent=False)
            assert flood.victim.registers[5] == 7
            await progress.wait_advance(progress.snapshot())
        tg.cancel_scope.cancel()
        st = flood.bus.stats.slave(1)
        assert st.errors >= 4 and st.line_noise >= (4 if strict else 0)
        assert flood.bus.line.garbage_bytes > 0
        assert healthy.stats.slave(1).errors == 0
    assert healthy_wire.violations == 0
    # Nothing went out without its silence after the noise stopped. (During the flood a
    # request sent in a pause may meet junk the babbler wrote while the request was still
    # on its way through the pty or socket: a collision with a device that never waits.)
    assert flood.request_violations(quiet_since) == 0
