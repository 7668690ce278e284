"""A pick-and-place cell: taught positions, a path, I/O, buffered moves, a speed override.

Run it on the built-in simulator:   .venv/bin/python examples/pick_and_place.py
or on your machine file:             .venv/bin/python examples/pick_and_place.py cell.toml

Without an argument it works on a copy of examples/pick_and_place.toml (it teaches a
position at the end, which rewrites the file it runs on).
"""

from __future__ import annotations

import shutil
import sys
import tempfile
from pathlib import Path

import anyio

from drivebus import Machine, open_machine

CELL = Path(__file__).resolve().with_name("pick_and_place.toml")
CLEAR = 2.0  # the lift's height for travelling, mm
PARTS = 3


async def feeder(m: Machine) -> None:
    """On the simulator: a part arrives in the nest (the sensor on IN4) whenever the
    gripper has taken the last one."""
    x, twin = m.axes["x"], m.sim_drives["x"]
    while True:
        await anyio.sleep(0.2)
        twin.set_input(4, True)
        async for _ in x.watch():
            if x.outputs.get("vacuum"):
                break
        twin.set_input(4, False)
        async for _ in x.watch():
            if not x.outputs.get("vacuum"):
                break


async def cycle(m: Machine, n: int) -> None:
    """One part: over the nest, down, vacuum on, up, along the path to the tray, down,
    vacuum off, up."""
    x, z = m.axes["x"], m.axes["z"]
    pick, place = m.position("pick"), m.position("place")
    await x.wait_input("part_present", timeout=10)
    await m.group("x", "y").move_to({"x": pick["x"], "y": pick["y"]}, speed=150.0)
    down = await z.move_to(pick["z"], buffer="buffered")
    await down
    await x.set_output("vacuum", True)
    await z.move_to(CLEAR)
    # over the tray: through a waypoint, corners blended where the drives can (they say)
    report = await m.group("x", "y").path(
        [{"x": 110.0, "y": 60.0}, {"x": place["x"], "y": place["y"]}], speed=150.0,
        blend=1.0)
    # the lift: down, then straight up again, queued back to back (no poll lost between)
    lower = await z.move_to(place["z"], buffer="buffered")
    await lower
    await x.set_output("vacuum", False)
    up = await z.move_to(CLEAR, buffer="buffered")
    await up
    corner = report.segments[0]
    print(f"part {n}: placed at x={x.position:.2f} y={m.axes['y'].position:.2f} "
          f"(path {report.duration:.2f} s, corner {corner.ends}: {corner.reason or 'blended'}"
          f"; deviation {report.max_deviation:.3f} mm)")


async def main(path: Path) -> None:
    async with open_machine(path) as m:
        await m.move_to("home")
        async with anyio.create_task_group() as tg:
            if m.sim_drives:
                tg.start_soon(feeder, m)
            for n in range(1, PARTS + 1):
                if n == PARTS:
                    m.override = 0.5  # the last part at half speed (a feed override)
                await cycle(m, n)
            tg.cancel_scope.cancel()
        m.override = 1.0
        last = await m.teach("last_place", axes=["x", "y"])
        await m.move_to("home")
        print(f"taught last_place: x={last['x']:.2f} y={last['y']:.2f} in {m.taught.path}")
        print(f"pick and place done: {PARTS} parts")


if __name__ == "__main__":
    if len(sys.argv) > 1:
        machine = Path(sys.argv[1])
    else:
        machine = Path(tempfile.mkdtemp(prefix="drivebus-cell-")) / CELL.name
        shutil.copy(CELL, machine)
    anyio.run(main, machine)
