"""sim_bus: a running virtual wire with slaves plus a Bus on it, in one ``async with``."""

from __future__ import annotations

import itertools
from collections.abc import AsyncIterator, Iterable
from contextlib import asynccontextmanager

from drivebus.bus import Bus
from drivebus.line.serial import SerialLine
from drivebus.settings import LineSettings
from drivebus.sim.slave import SimSlave
from drivebus.sim.wire import VirtualWire

__all__ = ["sim_bus"]

_names = itertools.count(1)


@asynccontextmanager
async def sim_bus(
    slaves: Iterable[SimSlave],
    settings: LineSettings | None = None,
    *,
    name: str | None = None,
    timeout: float = 0.1,
    retries: int = 2,
) -> AsyncIterator[tuple[VirtualWire, Bus]]:
    """Start a virtual wire with ``slaves`` and open a ``Bus`` on it at ``settings``."""
    wire_name = name or f"harness{next(_names)}"
    async with VirtualWire(wire_name) as wire:
        for s in slaves:
            wire.attach(s)
        line = SerialLine(wire.url, settings or LineSettings())
        async with Bus(line, timeout=timeout, retries=retries) as bus:
            yield wire, bus
