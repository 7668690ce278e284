"""The adapter doctor: what can make a real serial port fail or slow, found before use.

A port must exist and be usable; a USB-serial adapter's latency timer above 1 ms holds
every reply in the adapter that long, capping the line's transaction rate.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["PortReport", "check_serial_port", "latency_timer"]


@dataclass
class PortReport:
    """Problems (the port cannot work) and warnings (it works, worse than it could)."""

    problems: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


def latency_timer(port: str, sysfs: Path = Path("/sys")) -> int | None:
    """The USB-serial adapter's latency timer (ms) behind ``port``, if it has one."""
    tty = Path(os.path.realpath(port)).name
    f = sysfs / "bus" / "usb-serial" / "devices" / tty / "latency_timer"
    try:
        return int(f.read_text().strip())
    except (OSError, ValueError):
        return None


def check_serial_port(port: str, sysfs: Path = Path("/sys")) -> PortReport:
    """What stands in the way of ``port``: missing, no permission, a slow adapter, a pty."""
    report = PortReport()
    if not os.path.exists(port):
        report.problems.append(f"port {port} does not exist: plug in the adapter, check the "
                               f"name (ls /dev/serial/by-id/)")
        return report
    if not os.access(port, os.R_OK | os.W_OK):
        report.problems.append(f"no permission to open {port}: add your user to its group "
                               f"(sudo usermod -aG dialout $USER) and log in again")
        return report
    lt = latency_timer(port, sysfs)
    if lt is not None and lt > 1:
        tty = Path(os.path.realpath(port)).name
        report.warnings.append(
            f"{port}: the USB-serial latency timer is {lt} ms: every reply waits up to "
            f"{lt} ms in the adapter, capping the line at about {1000 // (lt + 1)} "
            f"transactions/s; set it to 1 ms: echo 1 | sudo tee "
            f"/sys/bus/usb-serial/devices/{tty}/latency_timer (or a udev rule)"
        )
    if "/pts/" in os.path.realpath(port):
        report.warnings.append(f"{port} is a pty (a simulator or virtual port): parity and "
                               f"byte size are not carried; keep its slaves at 8N1/8N2")
    return report
