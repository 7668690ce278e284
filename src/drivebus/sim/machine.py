"""The simulated side of a machine config: a twin per axis on each ``sim://`` line.

The simulator's line provider (``drivebus.sim.provider``, which ``open_machine`` finds by
the ``sim`` scheme) uses ``start_sim_line`` for every simulated line of a config;
``drivebus sim`` uses ``start_simulators`` to serve all of them standalone, so that an
outside master (mbpoll, a PLC, pymodbus) can talk to the simulated drives.
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass, field
from typing import Any

import anyio
import anyio.lowlevel

from drivebus.config import AxisConfig, LineConfig, MachineConfig
from drivebus.errors import ConfigError
from drivebus.sim.drive import SimDrive, TwinSetup
from drivebus.sim.tcp import SimSerialServer, SimTcpServer
from drivebus.sim.twins import twin_class
from drivebus.sim.wire import VirtualWire

__all__ = [
    "ADAPTER_OPTIONS",
    "SimLine",
    "adapter_options",
    "make_twin",
    "own_sim_lines",
    "start_sim_line",
    "start_simulators",
]

SimServer = VirtualWire | SimSerialServer | SimTcpServer


@dataclass
class SimLine:
    """One running simulated line: its config, the twins on it and what serves them."""

    name: str
    config: LineConfig
    server: SimServer
    twins: dict[str, SimDrive] = field(default_factory=dict)
    """The twin behind each axis on this line, by axis name."""

    def master_config(self) -> LineConfig:
        """The line's config pointed at this simulator: what a master connects to (the
        wire's ``sim://NAME`` port, or the server's loopback address)."""
        cfg, srv = self.config, self.server
        if isinstance(srv, VirtualWire):
            return cfg.model_copy(update={"port": srv.url})
        return cfg.model_copy(update={"host": "127.0.0.1", "tcp_port": srv.port})

    @property
    def endpoint(self) -> str:
        """Where an outside master connects: the pty path, or ``127.0.0.1:PORT``."""
        srv = self.server
        if isinstance(srv, VirtualWire):
            return srv.slave_path
        return f"127.0.0.1:{srv.port}"


def make_twin(axis: AxisConfig, line: LineConfig) -> SimDrive:
    """The simulated drive for ``axis``: its family's twin, set up from the axis's ``sim``
    section (switches and start position converted from user units to pulses) and given
    that section's family options."""
    twin = twin_class(axis.drive)
    units_per_pulse = axis.units_per_rev / axis.pulses_per_rev

    def pulses(v: float | None) -> float | None:
        return None if v is None else v / units_per_pulse

    sim = axis.sim
    setup = TwinSetup(
        turnaround=sim.turnaround,
        position=round(sim.position / units_per_pulse),
        home_switch=pulses(sim.home_switch),
        limit_negative=pulses(sim.limit_negative),
        limit_positive=pulses(sim.limit_positive),
    )
    settings = axis.settings or (line.settings if line.kind != "tcp" else None)
    return twin(axis.address, settings, setup, **sim.options)


ADAPTER_OPTIONS = ("latency", "echo")
"""What a ``sim://NAME?...`` serial line may say about the master's simulated adapter:
``latency`` (its latency timer, e.g. ``16ms`` or ``0.016``) and ``echo`` (it hears its own
transmitter: ``true``/``false``)."""


def adapter_options(line: LineConfig) -> dict[str, Any]:
    """The wire's keyword options from the line's ``sim://NAME?latency=16ms&echo=true``;
    ``ConfigError`` naming a bad one."""
    out: dict[str, Any] = {}
    for key, text in line.sim_options.items():
        if key == "latency":
            try:
                seconds = float(text[:-2]) / 1000 if text.endswith("ms") else float(text)
            except ValueError:
                seconds = -1.0
            if not 0 <= seconds <= 1:
                raise ConfigError(f"sim://{line.sim_name}?latency={text}: a latency timer is "
                                  f"0..1 s (e.g. 16ms)")
            out["adapter_latency"] = seconds
        elif key == "echo":
            if text not in ("true", "false", "1", "0"):
                raise ConfigError(f"sim://{line.sim_name}?echo={text}: true or false")
            out["echo"] = text in ("true", "1")
        else:
            raise ConfigError(f"sim://{line.sim_name}: no option {key!r} (it has "
                              f"{', '.join(ADAPTER_OPTIONS)})")
    return out


def own_sim_lines(config: MachineConfig) -> MachineConfig:
    """``config`` with each ``sim://NAME`` line renamed ``sim://NAME-PID`` for this
    process (options kept): simulators of its own, which no running ``drivebus sim`` serves
    and no other process shares. For a machine run on the simulator by default (the demo,
    an example without a machine file); a name given on purpose is left to reach a
    running ``drivebus sim``."""
    lines = {}
    for name, line in config.lines.items():
        if not line.simulated:
            lines[name] = line
            continue
        key = "port" if line.port else "host"
        address = getattr(line, key) or ""
        base, sep, options = address.partition("?")
        lines[name] = line.model_copy(update={key: f"{base}-{os.getpid()}{sep}{options}"})
    return config.model_copy(update={"lines": lines})


async def start_sim_line(
    config: MachineConfig, name: str, stack: contextlib.AsyncExitStack
) -> SimLine:
    """Start the simulator of line ``name`` (a ``sim://`` line) with a twin per present axis;
    it runs until ``stack`` closes."""
    line = config.lines[name]
    axes = {n: a for n, a in config.axes.items() if a.line == name and not a.sim.absent}
    twins = {}
    for n, a in axes.items():
        try:
            twins[n] = make_twin(a, line)
        except (ValueError, TypeError) as exc:  # ConfigError included
            raise ConfigError(f"axes.{n}.sim: the simulated {a.drive} refuses this axis: "
                              f"{exc}") from exc
        # A twin takes some milliseconds to build: one at a time, so that a machine
        # opening here never holds a loop whose other lines carry motion.
        await anyio.lowlevel.checkpoint()
    server: SimServer
    if line.kind == "serial":
        adapter = adapter_options(line)
        wire = await stack.enter_async_context(VirtualWire(line.sim_name, **adapter))
        for t in twins.values():
            wire.attach(t)
        server = wire
    elif line.kind == "tcp":
        server = await stack.enter_async_context(SimTcpServer(twins.values()))
    else:
        server = await stack.enter_async_context(SimSerialServer(twins.values(), line.settings))
    return SimLine(name, line, server, twins)


async def start_simulators(
    config: MachineConfig, stack: contextlib.AsyncExitStack
) -> dict[str, SimLine]:
    """Start every ``sim://`` line of ``config``; they run until ``stack`` closes."""
    return {
        name: await start_sim_line(config, name, stack)
        for name, line in config.lines.items()
        if line.simulated
    }
