"""Simulated lines in a process of their own: the bench's slaves, and outside masters.

``python -m drivebus.sim.process --slaves 8 --settings "115200 8N1" --turnaround 0.001``
prints the pty path to open on its first line and serves until stdin closes.

* ``--settings "9600 8N1,19200 8N2"``: the slaves take the settings in turn;
* ``--lines N``: N wires with the same slaves (the first line: their paths, space-separated);
* ``--machine FILE``: serve the ``sim://`` lines of a machine file (TOML or JSON), a twin
  per axis, instead (the first line: JSON ``{"line name": "pty path or host:port"}``).

While it runs it answers one command per line of stdin with one line on stdout, so that a
master in another process can judge the wire by what the wire saw, not by its own
bookkeeping (both processes read the same CLOCK_MONOTONIC):

* ``clear``: every wire forgets its log (answer ``ok``);
* ``log``: one JSON object, each wire's frames by line name (``frame_record``), and the
  process's CPU seconds so far under ``"cpu"``;
* ``babble paced``, ``babble flat`` and ``babble off``: a device on every wire sends junk
  without pause, at the line's rate or as fast as the pty takes it, until ``off``
  (answer: JSON ``{"noise_bytes": n}``, all wires' noise so far).

``--lenient``: slaves answer frames sent without the t3.5 silence (the violation is
only logged), as many real slaves do. ``--adapter-latency SECONDS``: the master's USB
adapter holds each reply until its latency timer ticks (FTDI's default: 0.016).

Without the in-process side channel the wire cannot observe parity or byte size: keep to
8N1/8N2 (a pty carries baud rate and stop bits only).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import anyio

from drivebus.settings import LineSettings
from drivebus.sim.segment import WireFrame
from drivebus.sim.slave import RegisterSlave
from drivebus.sim.wire import VirtualWire

if TYPE_CHECKING:
    from drivebus.config import MachineConfig

__all__ = ["frame_from_record", "frame_record", "main"]

FrameRecord = list[Any]
"""A wire frame as JSON: direction, address, data (hex), start, end, settings, gap,
required, note."""


def frame_record(f: WireFrame) -> FrameRecord:
    """``f`` as a JSON-able list (``frame_from_record`` reads it back)."""
    return [f.direction, f.address, f.data.hex(), f.start, f.end, str(f.settings), f.gap,
            f.required, f.note]


def frame_from_record(r: Sequence[Any]) -> WireFrame:
    """The wire frame a ``frame_record`` describes."""
    direction, address, data, start, end, settings, gap, required, note = r
    return WireFrame(str(direction), int(address), bytes.fromhex(data), float(start),
                     float(end), LineSettings.parse(settings), float(gap), float(required),
                     str(note))


async def _control(wires: dict[str, VirtualWire]) -> None:
    """Answer the commands on stdin until it closes."""
    async with contextlib.AsyncExitStack() as noise:
        while True:
            command = await anyio.to_thread.run_sync(sys.stdin.readline)
            if not command:
                return  # the parent closed our stdin: done
            print(await _answer(command.strip(), wires, noise), flush=True)


async def _answer(
    command: str, wires: dict[str, VirtualWire], noise: contextlib.AsyncExitStack
) -> str:
    """The answer to one control command."""
    if command.startswith("babble"):
        await noise.aclose()  # whatever babbled before stops
        mode = command.removeprefix("babble").strip()
        if mode in ("paced", "flat"):
            for w in wires.values():
                await noise.enter_async_context(w.babbling(flat_out=mode == "flat"))
        return json.dumps({"noise_bytes": sum(w.noise_bytes for w in wires.values())})
    if command == "clear":
        for w in wires.values():
            w.clear_log()
        return "ok"
    if command == "log":
        logs: dict[str, Any] = {n: [frame_record(f) for f in w.log] for n, w in wires.items()}
        logs["cpu"] = time.process_time()
        return json.dumps(logs)
    return json.dumps({"error": f"unknown command {command!r}"})


async def _serve_slaves(
    slaves: int, settings: Sequence[LineSettings], turnaround: float, lines: int, strict: bool,
    adapter_latency: float = 0.0,
) -> None:
    async with contextlib.AsyncExitStack() as stack:
        wires: dict[str, VirtualWire] = {}
        for i in range(lines):
            wire = await stack.enter_async_context(VirtualWire(
                f"process-{i}", strict=strict, adapter_latency=adapter_latency))
            for a in range(1, slaves + 1):
                s = settings[(a - 1) % len(settings)]
                wire.attach(RegisterSlave(a, s, size=64, turnaround=turnaround))
            wires[wire.name] = wire
        print(" ".join(w.slave_path for w in wires.values()), flush=True)
        await _control(wires)
        frames = sum(w.frames for w in wires.values())
        violations = sum(w.violations for w in wires.values())
        print(f"frames={frames} violations={violations}", flush=True)


async def _serve_machine(cfg: MachineConfig) -> None:
    from drivebus.sim.machine import start_simulators

    async with contextlib.AsyncExitStack() as stack:
        sims = await start_simulators(cfg, stack)
        print(json.dumps({name: s.endpoint for name, s in sims.items()}), flush=True)
        wires = {n: s.server for n, s in sims.items() if isinstance(s.server, VirtualWire)}
        await _control(wires)


def main(argv: list[str] | None = None) -> None:
    """Parse the arguments and serve the wires."""
    p = argparse.ArgumentParser(prog="python -m drivebus.sim.process")
    p.add_argument("--slaves", type=int, default=1)
    p.add_argument("--settings", default="115200 8N1",
                   help="one setting, or several separated by commas, taken in turn")
    p.add_argument("--turnaround", type=float, default=0.001)
    p.add_argument("--lines", type=int, default=1)
    p.add_argument("--machine", type=Path, default=None,
                   help="serve this machine file's sim:// lines instead")
    p.add_argument("--lenient", action="store_true",
                   help="slaves answer frames sent without the t3.5 silence")
    p.add_argument("--adapter-latency", type=float, default=0.0,
                   help="the master's adapter holds replies until its timer ticks (s)")
    a = p.parse_args(argv)
    if a.machine is not None:
        from drivebus.config import machine_config

        path: Path = a.machine
        cfg = machine_config(json.loads(path.read_text()) if path.suffix == ".json" else path)
        anyio.run(_serve_machine, cfg)
        return
    settings = [LineSettings.parse(s.strip()) for s in a.settings.split(",")]
    anyio.run(_serve_slaves, a.slaves, settings, a.turnaround, a.lines, not a.lenient,
              a.adapter_latency)


if __name__ == "__main__":
    main()
