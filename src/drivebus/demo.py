"""The demo: a simulated RS-485 line with drives at mixed settings, driven through the bus."""

from __future__ import annotations

import anyio

from drivebus.bus import Priority
from drivebus.settings import LineSettings
from drivebus.sim import RegisterSlave, sim_bus


async def run_demo() -> None:
    """Poll four slaves at four line settings on one simulated line and print the figures."""
    mixed = [LineSettings.parse(s) for s in ("9600 8N1", "19200 8E1", "38400 8N2", "115200 8N1")]
    slaves = [RegisterSlave(a, s, initial=[(0, a)]) for a, s in enumerate(mixed, start=1)]
    async with sim_bus(slaves, mixed[-1]) as (wire, bus):
        handles = [bus.slave(s.address, settings=s.settings) for s in slaves]

        async def poll(h) -> None:  # type: ignore[no-untyped-def]
            for _ in range(25):
                await h.read_holding_registers(0, 2, priority=Priority.POLL)

        async with anyio.create_task_group() as tg:
            for h in handles:
                tg.start_soon(poll, h)
        await handles[0].write_register(1, 1, priority=Priority.EMERGENCY)
        for s in slaves:
            st = bus.stats.slave(s.address)
            print(f"slave {s.address} at {s.settings}: {st.transactions} transactions, "
                  f"{st.errors} errors")
        print(f"line utilisation {bus.stats.utilisation:.0%}, frames {wire.frames}, "
              f"gap violations {wire.violations}")
