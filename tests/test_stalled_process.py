"""A process held up (not running: a busy machine, a stopped VM, a long GC) is not a
line fault: bytes that arrived while it could not read them, taken in when it runs again,
do not make the next frame's wait for silence a ``LineNoise``."""

from __future__ import annotations

import os
import threading
import time

import anyio
import pytest

from drivebus import LineSettings, SerialLine
from drivebus.clock import monotonic
from drivebus.pdu import response_length
from drivebus.sim import RegisterSlave, VirtualWire

S = LineSettings.parse("9600 8N1")  # t3.5 = 4 ms


@pytest.mark.holds_loop("the test holds its own event loop: a process that was not running")
async def test_bytes_taken_in_after_a_stall_are_not_noise() -> None:
    async with VirtualWire("stalled-process") as wire:
        wire.attach(RegisterSlave(1, S, initial=[(0, 7)]))
        async with SerialLine(wire.url, S) as line:
            ex = await line.transact(1, b"\x03\x00\x00\x00\x01", expect=response_length,
                                     timeout=0.1)
            assert ex.reply == b"\x03\x02\x00\x07"
            # A stray byte reaches the port while the process cannot run (a thread writes
            # it into the pty's other end 50 ms into a 150 ms stall of the event loop).
            fd = wire._master_fd
            junk = threading.Timer(0.05, os.write, (fd, b"\x00"))
            started = monotonic()
            got: list[bytes] = []

            async def read() -> None:
                ex = await line.transact(1, b"\x03\x00\x00\x00\x01", expect=response_length,
                                         timeout=0.1, quiet_by=started + 0.1)
                got.append(ex.reply)

            with anyio.fail_after(5, shield=False):
                async with anyio.create_task_group() as tg:
                    tg.start_soon(read)
                    await anyio.lowlevel.checkpoint()  # it waits for its silence now
                    junk.start()
                    time.sleep(0.15)  # noqa: ASYNC251 (the stall: nothing of this process runs)
            junk.join(1)
            assert got == [b"\x03\x02\x00\x07"]
