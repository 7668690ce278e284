"""A third-party peer: drivebus's SerialLine and Bus against pymodbus's own RTU server.

Two ptys joined by a byte relay make a null-modem cable: pymodbus serves one end, our
SerialLine opens the other. Nothing of drivebus's simulator is involved.
"""

from __future__ import annotations

import asyncio
import os
import tty
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

import pytest
from pymodbus.server import ModbusSerialServer

from drivebus import Bus, LineSettings, SerialLine
from drivebus.errors import ModbusException
from pymodbus_servers import server_data


@asynccontextmanager
async def null_modem() -> AsyncIterator[tuple[str, str]]:
    """Two pty paths whose traffic is relayed both ways."""
    loop = asyncio.get_running_loop()
    ends = [os.openpty() for _ in range(2)]
    for _, slave in ends:
        tty.setraw(slave)
    masters = [m for m, _ in ends]

    def relay(src: int, dst: int) -> None:
        try:
            data = os.read(src, 4096)
        except OSError:
            return
        os.write(dst, data)

    loop.add_reader(masters[0], relay, masters[0], masters[1])
    loop.add_reader(masters[1], relay, masters[1], masters[0])
    try:
        yield os.ttyname(ends[0][1]), os.ttyname(ends[1][1])
    finally:
        for m in masters:
            loop.remove_reader(m)
        for m, s in ends:
            os.close(m)
            os.close(s)


@asynccontextmanager
async def pymodbus_rtu_server(port: str, baud: int) -> AsyncIterator[None]:
    devices = server_data({a: [a * 1000] * 200 for a in (1, 7)})
    server = ModbusSerialServer(devices, port=port, baudrate=baud, parity="N", stopbits=1)
    await server.serve_forever(background=True)
    try:
        yield
    finally:
        await server.shutdown()


@pytest.mark.parametrize("baud", [19200, 115200])
async def test_bus_against_pymodbus_serial_server(baud: int) -> None:
    settings = LineSettings(baudrate=baud, parity="N", stopbits=1)
    async with (
        null_modem() as (ours, theirs),
        pymodbus_rtu_server(theirs, baud),
        Bus(SerialLine(ours, settings), timeout=0.5, retries=0) as bus,
    ):
        one, seven = bus.slave(1), bus.slave(7)
        assert await one.read_holding_registers(0, 3) == [1000] * 3
        assert await seven.read_holding_registers(10, 2) == [7000] * 2
        await seven.write_register(10, 1234)
        await seven.write_registers(20, [1, 2, 3, 65535])
        assert await seven.read_holding_registers(10, 1) == [1234]
        assert await seven.read_holding_registers(20, 4) == [1, 2, 3, 65535]
        assert await one.read_holding_registers(10, 1) == [1000]  # other device untouched
        with pytest.raises(ModbusException) as exc:
            await one.read_holding_registers(190, 20)  # past the device's registers
        assert exc.value.code == 2
        for i in range(50):
            assert await one.read_holding_registers(i, 1) == [1000]
        assert bus.stats.slave(1).transactions == 53  # 2 + 1 + exception + 50
        assert bus.stats.slave(1).exceptions == 1
        assert bus.line.garbage_bytes == 0
