"""The simulator as a line provider: it serves a machine file's ``sim://NAME`` lines.

A line whose ``sim://NAME`` a running ``drivebus sim`` serves (in another process) is
reached there, its drives as that simulator has them; only when none runs is a private
simulator started for the machine, its twins afresh.

``open_machine`` finds it by the ``sim`` scheme (an entry point of the package, see
``drivebus.providers``), never by importing it. Loading it also teaches pyserial the
``sim://NAME`` URL (``drivebus.sim.protocol_sim``), so ``SerialLine("sim://NAME")`` reaches a
running virtual wire of this process.
"""

from __future__ import annotations

import contextlib
import inspect
import logging

import serial

from drivebus.config import AxisConfig, MachineConfig
from drivebus.errors import ConfigError
from drivebus.providers import ProvidedLine
from drivebus.sim.machine import adapter_options, start_sim_line
from drivebus.sim.serve import published, serve_format_channel
from drivebus.sim.twins import twin_class
from drivebus.sim.wire import VirtualWire

__all__ = ["SimLineProvider"]

log = logging.getLogger(__name__)

if "drivebus.sim" not in serial.protocol_handler_packages:
    serial.protocol_handler_packages.append("drivebus.sim")  # sim://NAME, protocol_sim.py

_POSITION_PULSES = 1 << 31
"""Every drive keeps its position in a signed 32-bit register."""

_TWIN_SET = frozenset({"turnaround", "position", "home_switch", "limit_negative",
                       "limit_positive"})
"""Twin constructor options that come from the ``sim`` section's own keys."""


class SimLineProvider:
    """Serves ``sim://NAME`` lines with a simulated twin per axis."""

    scheme = "sim"

    def problems(self, config: MachineConfig) -> list[str]:
        """Twin options, positions and switches of the simulated axes that cannot work."""
        out = []
        for lname, ln in config.lines.items():
            if ln.scheme == self.scheme and ln.kind == "serial":
                try:
                    adapter_options(ln)
                except ConfigError as exc:
                    out.append(f"lines.{lname}.port: {exc}")
        for name, ax in config.axes.items():
            line = config.lines.get(ax.line)
            if line is None or line.scheme != self.scheme or ax.sim.absent:
                continue
            out += [f"axes.{name}.sim{p}" for p in _axis_problems(ax)]
        return out

    async def open(
        self, config: MachineConfig, line: str, stack: contextlib.AsyncExitStack, *,
        elsewhere: bool = False,
    ) -> ProvidedLine:
        """Reach the ``drivebus sim`` that serves line ``line`` if one runs (its drives, as
        it left them: no twins here), else start a private simulator of the line (a twin
        per axis, afresh) that runs until ``stack`` closes. ``elsewhere``: the master of
        the line runs in another process (a machine's worker): a private simulated serial
        line then also answers that process's format messages, and its port says where
        (``sim://NAME?pty=PATH&channel=SOCKET``)."""
        cfg = config.lines[line]
        running = published(cfg.sim_name)
        if running is not None and (running.kind == "serial") == (cfg.kind == "serial"):
            log.info("%s: reaching the running drivebus sim on %s", cfg.port or cfg.host,
                     running.where)
            if running.kind == "serial":  # sim://NAME: the port class finds the pty
                return ProvidedLine(cfg, {}, None)
            host, port = running.host_port
            return ProvidedLine(cfg.model_copy(update={"host": host, "tcp_port": port}), {},
                                None)
        sim = await start_sim_line(config, line, stack)
        master = sim.master_config()
        if elsewhere and isinstance(sim.server, VirtualWire):
            channel = await serve_format_channel(sim.server, stack)
            master = master.model_copy(update={
                "port": f"{sim.server.url}?pty={sim.server.slave_path}&channel={channel}"})
        return ProvidedLine(master, dict(sim.twins), sim.server)


_SWITCHES = {"home_switch": "home switch", "limit_negative": "negative limit switch",
             "limit_positive": "positive limit switch"}


def _axis_problems(ax: AxisConfig) -> list[str]:
    """What makes the simulated axis unusable: unknown twin options, positions beyond the
    drive's range, switches that leave it no room (``.key: problem``)."""
    out = []
    s = ax.sim
    try:
        twin = twin_class(ax.drive)
    except ConfigError:
        return [f": the simulator has no twin of drive {ax.drive!r}"]
    options = getattr(twin, "twin_options", None)
    if options is not None:
        known = sorted(options())
    else:
        params = inspect.signature(twin.__init__).parameters
        known = sorted(p for p, v in params.items()
                       if v.kind is inspect.Parameter.KEYWORD_ONLY and p not in _TWIN_SET)
    for key in s.options:
        if key not in known:
            out.append(f".options.{key}: the simulated {ax.drive} has no option {key!r} "
                       f"(it has {', '.join(known) or 'none'})")
    sees = getattr(twin, "sees", None)
    for key in ("home_switch", "limit_negative", "limit_positive"):
        if getattr(s, key) is not None and sees is not None and not sees(key):
            out.append(f".{key}: drive {ax.drive} has no input for a {_SWITCHES[key]} "
                       f"(its description wires none and sees none directly): its twin "
                       f"would run through it; leave it out")
    pulses_per_unit = ax.pulses_per_rev / ax.units_per_rev
    for key in ("position", "home_switch", "limit_negative", "limit_positive"):
        v = getattr(s, key)
        if v is not None and not abs(v * pulses_per_unit) < _POSITION_PULSES:
            out.append(f".{key}: {v:g} units is {v * pulses_per_unit:g} pulses, beyond the "
                       f"drive's 32-bit position range")
    neg, pos = s.limit_negative, s.limit_positive
    if neg is not None and pos is not None and neg >= pos:
        out.append(f".limit_negative: {neg:g} is not below limit_positive {pos:g}: the axis "
                   f"would always be on a limit switch")
    if ax.limits is not None:
        lo, hi = ax.limits
        if neg is not None and hi <= neg:
            out.append(f".limit_negative: the switch at {neg:g} lies above the whole soft-limit "
                       f"range {lo:g}..{hi:g}: every allowed position is beyond it")
        if pos is not None and lo >= pos:
            out.append(f".limit_positive: the switch at {pos:g} lies below the whole soft-limit "
                       f"range {lo:g}..{hi:g}: every allowed position is beyond it")
    return out
