"""systemd's notify protocol for ``drivebus serve`` (``Type=notify``, ``WatchdogSec=``).

``READY=1`` once the machine is open and the server listens, ``WATCHDOG=1`` from the event
loop every half watchdog period (so a hung loop is restarted by systemd), ``STOPPING=1``
when the shutdown begins. Without ``$NOTIFY_SOCKET`` (not started by systemd) nothing is
sent. The protocol is one datagram per message on a Unix socket: no library needed.
"""

from __future__ import annotations

import logging
import os
import socket

import anyio

__all__ = ["feed_watchdog", "notify", "watchdog_period"]

log = logging.getLogger(__name__)


def notify(state: str) -> bool:
    """Send ``state`` (e.g. ``"READY=1"``) to systemd; False if not run under systemd or
    the socket cannot be reached (logged once per failure, never raised)."""
    address = os.environ.get("NOTIFY_SOCKET")
    if not address:
        return False
    if address.startswith("@"):  # an abstract socket
        address = "\0" + address[1:]
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC) as s:
            s.sendto(state.encode(), address)
    except OSError as exc:
        log.warning("cannot notify systemd at %s: %s", os.environ["NOTIFY_SOCKET"], exc)
        return False
    return True


def watchdog_period() -> float | None:
    """Seconds between watchdog messages (half of ``$WATCHDOG_USEC``), or None when
    systemd watches no process or another one (``$WATCHDOG_PID``)."""
    pid = os.environ.get("WATCHDOG_PID")
    usec = os.environ.get("WATCHDOG_USEC")
    if not usec or (pid and pid != str(os.getpid())):
        return None
    try:
        period = int(usec) / 2e6
    except ValueError:
        log.warning("WATCHDOG_USEC=%r is not a number of microseconds: no watchdog", usec)
        return None
    return period if period > 0 else None


async def feed_watchdog(period: float) -> None:
    """Send ``WATCHDOG=1`` every ``period`` seconds until cancelled."""
    while True:
        notify("WATCHDOG=1")
        await anyio.sleep(period)
