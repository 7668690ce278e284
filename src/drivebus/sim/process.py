"""A virtual wire with register slaves in a process of its own (bench and outside masters).

``python -m drivebus.sim.process --slaves 8 --settings "115200 8N1" --turnaround 0.001``
prints the pty path to open on its first line and serves until stdin closes. Without
the in-process side channel the wire cannot observe parity or byte size: keep to 8N1/8N2.
"""

from __future__ import annotations

import argparse
import sys

import anyio

from drivebus.settings import LineSettings
from drivebus.sim.slave import RegisterSlave
from drivebus.sim.wire import VirtualWire

__all__ = ["main"]


async def _serve(slaves: int, settings: LineSettings, turnaround: float) -> None:
    async with VirtualWire("process") as wire:
        for a in range(1, slaves + 1):
            wire.attach(RegisterSlave(a, settings, size=64, turnaround=turnaround))
        print(wire.slave_path, flush=True)
        await anyio.to_thread.run_sync(sys.stdin.read)  # until the parent closes our stdin
        print(f"frames={wire.frames} violations={wire.violations}", flush=True)


def main(argv: list[str] | None = None) -> None:
    """Parse the arguments and serve the wire."""
    p = argparse.ArgumentParser(prog="python -m drivebus.sim.process")
    p.add_argument("--slaves", type=int, default=1)
    p.add_argument("--settings", default="115200 8N1")
    p.add_argument("--turnaround", type=float, default=0.001)
    a = p.parse_args(argv)
    anyio.run(_serve, a.slaves, LineSettings.parse(a.settings), a.turnaround)


if __name__ == "__main__":
    main()
