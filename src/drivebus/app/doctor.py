"""The adapter doctor: what can make a real serial port fail or slow, found before use.

A port must exist and be usable; a USB-serial adapter's latency timer above 1 ms holds
every reply in the adapter that long, capping the line's transaction rate (``SerialLine``
asks the driver for low-latency mode when it opens the port, which ftdi_sio turns into a
1 ms timer; the doctor says what the line reaches either way). Read from sysfs only: the
port is not opened.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from drivebus.settings import LineSettings
from drivebus.timing import timing

__all__ = ["Adapter", "PortReport", "adapter_of", "check_serial_port", "latency_timer",
           "poll_efficiency"]


@dataclass
class Adapter:
    """A serial port's adapter as sysfs shows it."""

    driver: str | None
    """The kernel driver (``ftdi_sio``, ``cp210x``, ``ch341``, ...; None: unknown)."""
    latency_timer_ms: int | None
    """The USB-serial latency timer (ms), where the driver has one."""


@dataclass
class PortReport:
    """Problems (the port cannot work) and warnings (it works, worse than it could)."""

    problems: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    adapter: Adapter | None = None


def adapter_of(port: str, sysfs: Path = Path("/sys")) -> Adapter:
    """The driver and latency timer behind ``port`` (from sysfs)."""
    tty = Path(os.path.realpath(port)).name
    link = sysfs / "class" / "tty" / tty / "device" / "driver"
    try:
        driver: str | None = Path(os.readlink(link)).name
    except OSError:
        driver = None
    return Adapter(driver, latency_timer(port, sysfs))


def poll_efficiency(settings: LineSettings, held: float, turnaround: float = 0.001
                    ) -> tuple[float, float]:
    """(wire time of a 4-register poll, the fraction of the line it can use) when each
    reply is held ``held`` s in the adapter (the slave's ``turnaround`` assumed)."""
    tm = timing(settings)
    wire = tm.frame_time(8) + tm.frame_time(13)  # FC03 request, 4-register reply
    return wire, wire / (wire + tm.t35 + turnaround + held)


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
    report.adapter = adapter_of(port, sysfs)
    lt = report.adapter.latency_timer_ms
    if lt is not None and lt > 1:
        tty = Path(os.path.realpath(port)).name
        report.warnings.append(
            f"{port}: the USB-serial latency timer is {lt} ms: every reply waits up to "
            f"{lt} ms in the adapter, capping the line at about {1000 // (lt + 1)} "
            f"transactions/s. drivebus asks the driver for low-latency mode (1 ms) when it "
            f"opens the port; where the driver ignores that, set it: echo 1 | sudo tee "
            f"/sys/bus/usb-serial/devices/{tty}/latency_timer (or a udev rule)"
        )
    if "/pts/" in os.path.realpath(port):
        report.warnings.append(f"{port} is a pty (a simulator or virtual port): parity and "
                               f"byte size are not carried; keep its slaves at 8N1/8N2")
    return report
