"""Targets: where a register tool or a scan talks to, written as one string.

``/dev/ttyUSB0`` (or any serial device or pty), ``sim://NAME`` (a simulated line of this
process or of a running ``drivebus sim``), ``tcp://HOST[:PORT]`` (Modbus TCP, port 502 by
default) and ``rtu+tcp://HOST:PORT`` (RTU through a serial device server).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from drivebus.config import LineConfig
from drivebus.errors import ConfigError
from drivebus.settings import LineSettings

__all__ = ["Target", "parse_target"]

_TCP_PORT = 502


@dataclass(frozen=True)
class Target:
    """A parsed target: the kind of line and where it is."""

    kind: Literal["serial", "tcp", "rtu-over-tcp"]
    port: str | None = None
    host: str | None = None
    tcp_port: int = _TCP_PORT

    @property
    def serial(self) -> bool:
        """True when the target has serial line settings (serial, or RTU over TCP)."""
        return self.kind != "tcp"

    def line_config(self, settings: LineSettings | None = None, *, timeout: float = 0.1,
                    retries: int = 0) -> LineConfig:
        """A line config for this target (``settings`` for serial targets)."""
        data: dict[str, object] = {"kind": self.kind, "timeout": timeout, "retries": retries}
        if self.kind == "serial":
            data["port"] = self.port
        else:
            data.update(host=self.host, tcp_port=self.tcp_port)
        if settings is not None and self.serial:
            data["settings"] = settings
        return LineConfig.model_validate(data)

    def __str__(self) -> str:
        if self.kind == "serial":
            return str(self.port)
        scheme = "tcp" if self.kind == "tcp" else "rtu+tcp"
        return f"{scheme}://{self.host}:{self.tcp_port}"


def parse_target(text: str) -> Target:
    """``text`` as a target; ``ConfigError`` saying what targets look like."""
    if not isinstance(text, str) or not text.strip():
        raise ConfigError("a target is a serial port, sim://NAME, tcp://HOST[:PORT] or "
                          "rtu+tcp://HOST:PORT")
    text = text.strip()
    if text.startswith("tcp://"):
        host, port = _host_port(text, "tcp://", required=False)
        return Target("tcp", host=host, tcp_port=port)
    if text.startswith("rtu+tcp://"):
        host, port = _host_port(text, "rtu+tcp://", required=True)
        return Target("rtu-over-tcp", host=host, tcp_port=port)
    if "://" in text and not text.startswith("sim://"):
        raise ConfigError(f"target {text!r}: unknown scheme (serial port, sim://NAME, "
                          f"tcp://HOST[:PORT] or rtu+tcp://HOST:PORT)")
    return Target("serial", port=text)


def _host_port(text: str, scheme: str, *, required: bool) -> tuple[str, int]:
    rest = text.removeprefix(scheme).rstrip("/")
    host, sep, port_text = rest.rpartition(":") if ":" in rest else (rest, "", "")
    host = host.strip("[]")
    if not host:
        raise ConfigError(f"target {text!r}: no host (e.g. {scheme}192.168.1.10:502)")
    if required and not sep:
        raise ConfigError(f"target {text!r}: a serial device server needs its port "
                          f"({scheme}HOST:PORT)")
    try:
        port = int(port_text) if sep else _TCP_PORT
    except ValueError:
        raise ConfigError(f"target {text!r}: port {port_text!r} is not a number") from None
    if not 1 <= port <= 65535:
        raise ConfigError(f"target {text!r}: port {port} is outside 1..65535")
    return host, port
