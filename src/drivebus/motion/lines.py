"""The one line factory: a machine file's line section becomes a ``Line``.

A ``SCHEME://NAME`` line (the simulator's ``sim://``) is first handed to its provider
(``drivebus.providers``), which starts what serves it and points the config at it; every
line, provided or not, is then built here.
"""

from __future__ import annotations

import contextlib

from drivebus.config import LineConfig, MachineConfig
from drivebus.line.base import Line
from drivebus.line.serial import SerialLine
from drivebus.line.tcp import RtuOverTcpLine, TcpLine
from drivebus.providers import ProvidedLine, line_provider

__all__ = ["make_line", "open_line"]


def make_line(config: LineConfig) -> Line:
    """The ``Line`` for ``config`` (not opened): serial, Modbus TCP or RTU over TCP."""
    if config.kind == "serial":
        assert config.port is not None
        return SerialLine(config.port, config.settings, local_echo=config.local_echo,
                          rs485=config.rs485)
    assert config.host is not None
    if config.kind == "tcp":
        return TcpLine(config.host, config.tcp_port)
    return RtuOverTcpLine(config.host, config.tcp_port, config.settings)


async def open_line(
    config: MachineConfig, name: str, stack: contextlib.AsyncExitStack
) -> tuple[Line, ProvidedLine | None]:
    """The line ``name`` of ``config``, its provider started first if it has one (it runs
    until ``stack`` closes); with what the provider serves."""
    line = config.lines[name]
    if line.scheme is None:
        return make_line(line), None
    provided = await line_provider(line.scheme).open(config, name, stack)
    return make_line(provided.config), provided
