"""The one line factory: a machine file's line section becomes a ``Line``.

A ``SCHEME://NAME`` line (the simulator's ``sim://``) is first handed to its provider
(``drivebus.providers``), which starts what serves it and points the config at it; every
line, provided or not, is then built here.
"""

from __future__ import annotations

import contextlib
import inspect
from typing import Any

from drivebus.config import LineConfig, MachineConfig
from drivebus.line.base import Line
from drivebus.line.serial import SerialLine
from drivebus.line.tcp import RtuOverTcpLine, TcpLine
from drivebus.providers import ProvidedLine, line_provider

__all__ = ["make_line", "open_line", "provide_elsewhere", "serves_elsewhere"]


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


def serves_elsewhere(config: MachineConfig, name: str) -> bool:
    """True if line ``name`` can be opened by another process (a machine's worker): any
    line that is not ``SCHEME://NAME``, and those of a provider that can serve one there
    (its ``open`` takes ``elsewhere``)."""
    scheme = config.lines[name].scheme
    if scheme is None:
        return True
    opener = line_provider(scheme).open
    return "elsewhere" in inspect.signature(opener).parameters


async def provide_elsewhere(
    config: MachineConfig, name: str, stack: contextlib.AsyncExitStack
) -> tuple[LineConfig, ProvidedLine | None]:
    """The config another process (a machine's worker) opens line ``name`` with, its
    provider started first here if it has one (it runs until ``stack`` closes)."""
    line = config.lines[name]
    if line.scheme is None:
        return line, None
    opener: Any = line_provider(line.scheme).open
    provided = await opener(config, name, stack, elsewhere=True)
    return provided.config, provided
