"""A coordinated multi-axis motion script: trace a rectangle with x/y while r indexes.

Run it on the built-in simulator:  .venv/bin/python examples/coordinated.py
or on your machine file:            .venv/bin/python examples/coordinated.py my_machine.toml
"""

from __future__ import annotations

import sys
from pathlib import Path

import anyio

from drivebus import open_machine
from drivebus.config import MachineConfig, load_config
from drivebus.sim.machine import own_sim_lines

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "demo.toml"

CORNERS = [(20.0, 10.0), (180.0, 10.0), (180.0, 90.0), (20.0, 90.0), (20.0, 10.0)]


async def main(config: Path | MachineConfig) -> None:
    async with open_machine(config) as m:
        xy = m.group("x", "y")
        await m.group("x", "y", "r").home()
        for i, (x, y) in enumerate(CORNERS):
            # x and y start together and arrive together; r indexes 90° on its own line (TCP)
            async with anyio.create_task_group() as tg:
                tg.start_soon(m.axes["r"].move_to, 90.0 * (i % 4))
                report = await xy.move_to({"x": x, "y": y})
            print(f"corner {i}: x={m.axes['x'].position:.2f} y={m.axes['y'].position:.2f} "
                  f"r={m.axes['r'].position:.1f}  (planned {report.duration:.2f} s, "
                  f"start skew {report.start_skew * 1000:.1f} ms)")
        print("rectangle done")


if __name__ == "__main__":
    # no machine file: the demo machine on simulators of this process's own (a drivebus
    # sim serving configs/demo.toml is reached only when that file is named on purpose)
    anyio.run(main, Path(sys.argv[1]) if len(sys.argv) > 1 else own_sim_lines(load_config(CONFIG)))
