"""Serving a machine's simulated lines to outside masters (``drivebus sim``).

The simulators run in this process; each simulated serial line's pty path is published in
a per-user runtime directory, so that ``SerialLine("sim://NAME")`` (and ``drivebus scan
sim://NAME``) in another process reaches it. Output goes to ``echo`` (a terminal's print).
"""

from __future__ import annotations

import contextlib
import math
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import anyio

from drivebus import runtime
from drivebus.config import MachineConfig, load_config
from drivebus.errors import ConfigError, DrivebusError
from drivebus.sim.machine import SimLine, start_simulators
from drivebus.sim.wire import VirtualWire, WireFrame

__all__ = ["describe", "frame_text", "publish", "published_sim", "serve_simulators"]


def _say(text: str) -> None:
    print(text, flush=True)


def _warn(text: str) -> None:
    print(f"warning: {text}", file=sys.stderr, flush=True)


def published_sim(name: str) -> str | None:
    """The pty path a running ``drivebus sim`` serves ``sim://name`` on, if one does."""
    found = runtime.lookup("sim", name)
    return found[0] if found and Path(found[0]).exists() else None


@contextlib.contextmanager
def publish(
    sims: dict[str, SimLine], warn: Callable[[str], None] = _warn
) -> Iterator[None]:
    """Publish the pty path of each simulated serial line for other processes; removed on
    exit (a line that cannot be published is a warning, not an error)."""
    entries = {s.config.sim_name: [s.endpoint] for s in sims.values()
               if isinstance(s.server, VirtualWire)}
    with runtime.publish("sim", entries) as problems:
        for p in problems:
            warn(p)
        yield


def describe(sim: SimLine, cfg: MachineConfig) -> list[str]:
    """``line NAME KIND WHERE`` and one line per slave on it."""
    kind = sim.config.kind
    lines = [f"line {sim.name} {kind} {sim.endpoint}"]
    for axis, twin in sim.twins.items():
        ac = cfg.axes[axis]
        where = "unit" if kind == "tcp" else "slave"
        settings = "" if kind == "tcp" else f" {twin.settings}"
        lines.append(f"  {where} {twin.address} {ac.drive}{settings} (axis {axis})")
    return lines


def frame_text(line: str, f: WireFrame) -> str:
    """One frame of a wire log as a line (the silence before it in ms, or in s when the
    line was idle for a second or more)."""
    note = f" [{f.note}]" if f.note else ""
    if math.isinf(f.gap):
        gap = "none-before"  # the first frame since the wire started
    else:
        gap = f"{f.gap * 1000:.2f}ms" if f.gap < 1.0 else f"{f.gap:.1f}s"
    return (f"{f.start:.6f} {line} {f.direction:<7} addr={f.address} "
            f"{str(f.settings).replace(' ', '-')} gap={gap} "
            f"{f.data.hex(' ')}{note}")


async def _echo_wire_log(name: str, wire: VirtualWire, echo: Callable[[str], None]) -> None:
    seen = wire.frames
    while True:
        await wire.wait_frames(seen + 1)
        new = wire.frames - seen
        seen = wire.frames
        for f in list(wire.log)[-new:]:
            echo(frame_text(name, f))


async def serve_simulators(
    config: str | Path,
    *,
    log: bool = False,
    echo: Callable[[str], None] = _say,
    warn: Callable[[str], None] = _warn,
) -> None:
    """Serve the ``sim://`` lines of ``config`` (a twin per axis) until cancelled."""
    cfg = load_config(config)
    for ln in cfg.lines.values():
        if ln.simulated and ln.kind == "serial" and (path := published_sim(ln.sim_name)):
            raise DrivebusError(
                f"{ln.port} is already served by another drivebus sim, on {path}: use that "
                f"one, or stop it first"
            )
    async with contextlib.AsyncExitStack() as stack:
        sims = await start_simulators(cfg, stack)
        if not sims:
            raise ConfigError(f"{config}: no sim:// lines: nothing to simulate")
        with publish(sims, warn):
            for s in sims.values():
                for text in describe(s, cfg):
                    echo(text)
            echo(f"simulating machine {cfg.name}: Ctrl-C or SIGTERM ends it")
            try:
                async with anyio.create_task_group() as tg:
                    if log:
                        for s in sims.values():
                            if isinstance(s.server, VirtualWire):
                                tg.start_soon(_echo_wire_log, s.name, s.server, echo)
                    await anyio.sleep_forever()
            finally:
                for s in sims.values():
                    for axis, twin in s.twins.items():
                        echo(f"twin {axis}: position={twin.position()} pulses "
                             f"moving={twin.is_moving()}")
