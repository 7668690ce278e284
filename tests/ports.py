"""Loopback TCP ports a test chooses before its server listens on them.

A port found free and let go (bind to port 0, close) can be taken by any other process
before the test's server binds it, or while that server is down for a restart: another
test running at once, its outgoing connections included. A reserved port is held instead.
"""

from __future__ import annotations

import contextlib
import socket
from collections.abc import Iterator

__all__ = ["reserve_port", "reserved_port"]


def reserve_port(host: str = "127.0.0.1") -> socket.socket:
    """A socket holding a free port of ``host`` (``getsockname()[1]``) until it is closed.

    It is bound with ``SO_REUSEADDR`` and never listens: connections to the port are
    refused until a server listens on it, no other bind to port 0 and no outgoing
    connection gets it, and a server binding it with ``SO_REUSEADDR`` (anyio's and
    asyncio's listeners, Mosquitto) can listen on it, stop and listen again."""
    s = socket.socket()
    try:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind((host, 0))
    except OSError:
        s.close()
        raise
    return s


@contextlib.contextmanager
def reserved_port(host: str = "127.0.0.1") -> Iterator[int]:
    """``reserve_port`` for the block: the port number."""
    with reserve_port(host) as s:
        yield int(s.getsockname()[1])
