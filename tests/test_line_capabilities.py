"""Lines declare what they can do; the bus reads the declarations, it does not probe."""

from __future__ import annotations

import pytest

from drivebus import Bus, LineSettings, RtuOverTcpLine, SerialLine, TcpLine
from drivebus.errors import ConfigError
from drivebus.line import Line
from drivebus.sim import RegisterSlave, SimSerialServer, VirtualWire

S = LineSettings.parse("19200 8E1")


def test_each_line_declares_its_capabilities() -> None:
    serial = SerialLine("/dev/ttyUSB0", S, local_echo=True)
    tcp = TcpLine("127.0.0.1", 502, max_in_flight=4)
    rtu_tcp = RtuOverTcpLine("127.0.0.1", 4001, S)
    rows = {
        line: (line.per_slave_settings, line.local_echo, line.max_in_flight, line.counts_garbage)
        for line in (serial, tcp, rtu_tcp)
    }
    assert rows[serial] == (True, True, 1, True)
    assert rows[tcp] == (False, False, 4, True)
    assert rows[rtu_tcp] == (False, False, 1, True)
    assert (Line.per_slave_settings, Line.local_echo, Line.max_in_flight, Line.counts_garbage) == (
        False, False, 1, False
    )


async def test_per_slave_settings_follow_the_declaration() -> None:
    other = LineSettings.parse("9600 8N1")
    async with VirtualWire("caps") as wire:
        wire.attach(RegisterSlave(1, other))
        async with Bus(SerialLine(wire.url, S)) as bus:
            assert await bus.slave(1, settings=other).read_holding_registers(0, 1) == [0]
    async with (
        SimSerialServer([RegisterSlave(1, S)], S) as srv,
        Bus(RtuOverTcpLine("127.0.0.1", srv.port, S)) as bus,
    ):
        with pytest.raises(ConfigError, match="one setting for all slaves"):
            bus.slave(1, settings=other)
        assert await bus.slave(1, settings=S).read_holding_registers(0, 1) == [0]
