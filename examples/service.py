"""Service-style embedding: one machine shared by several concurrent tasks.

A service backend owns the machine for its lifetime; independent request handlers
command different axes at the same time while a monitor task watches all of them.
Here three "clients" run concurrently: one moves x back and forth, one jogs z with a
watchdog it keeps feeding, one reads status, and the monitor prints state changes.

    .venv/bin/python examples/service.py [machine.toml]
"""

from __future__ import annotations

import sys
from pathlib import Path

import anyio

from drivebus import Machine, open_machine
from drivebus.config import MachineConfig, load_config
from drivebus.sim.machine import own_sim_lines

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "demo.toml"


async def shuttle(m: Machine, done: anyio.Event) -> None:
    """A client that moves x between two stations."""
    x = m.axes["x"]
    for k in range(3):
        await x.move_to(120.0 if k % 2 == 0 else 30.0)
        print(f"shuttle: x at {x.position:.2f}")
    done.set()


async def jogger(m: Machine, done: anyio.Event) -> None:
    """A client that jogs z while the shuttle runs, feeding the jog watchdog."""
    z = m.axes["z"]
    await z.jog(+5.0, watchdog=0.5)
    while not done.is_set():
        with anyio.move_on_after(0.2):
            await done.wait()
        z.feed()
    await z.stop()
    print(f"jogger: z stopped at {z.position:.2f}")


async def reporter(m: Machine, done: anyio.Event) -> None:
    """A client that reads the status of every axis now and then."""
    while not done.is_set():
        states = ", ".join(f"{n}={a.state}" for n, a in m.axes.items())
        print(f"reporter: {states}")
        with anyio.move_on_after(0.5):
            await done.wait()


async def monitor(m: Machine) -> None:
    """The service's monitor: prints every state change of y as it is polled."""
    y = m.axes["y"]
    last = None
    async for _ in y.watch():
        if y.state != last:
            print(f"monitor: y is {y.state}")
            last = y.state


async def main(config: Path | MachineConfig) -> None:
    async with open_machine(config) as m:
        await m.group("x", "y", "z").home()
        done = anyio.Event()
        async with anyio.create_task_group() as tg:
            tg.start_soon(monitor, m)
            async with anyio.create_task_group() as clients:
                clients.start_soon(shuttle, m, done)
                clients.start_soon(jogger, m, done)
                clients.start_soon(reporter, m, done)
                clients.start_soon(m.axes["y"].move_to, 80.0)
            tg.cancel_scope.cancel()  # the clients are done: stop monitoring
        print(f"service done: x={m.axes['x'].position:.2f} y={m.axes['y'].position:.2f} "
              f"z={m.axes['z'].position:.2f}")


if __name__ == "__main__":
    # no machine file: the demo machine on simulators of this process's own (a drivebus
    # sim serving configs/demo.toml is reached only when that file is named on purpose)
    anyio.run(main, Path(sys.argv[1]) if len(sys.argv) > 1 else own_sim_lines(load_config(CONFIG)))
