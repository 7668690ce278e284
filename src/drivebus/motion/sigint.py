"""A second Ctrl-C while an application leaves its machine waits for the axes' stops.

Under ``asyncio.run`` (and ``anyio.run`` on asyncio) the first SIGINT cancels the main
task, and an open machine stops its moving axes as it leaves; the second raises
``KeyboardInterrupt`` wherever the main thread is at that moment. One that landed while
the stops were being handed to the lines cut them short, and the axes ran on after the
process had ended. While a machine is open, the second SIGINT is held until every open
machine has left (its axes stopped), then handed to the handler it was meant for; a
third goes through at once, the way out of an application that hangs on its own.

Only the handlers Python and asyncio install are wrapped (in the main thread); a front
end that handles SIGINT itself (the command line, the service, the MQTT node) keeps it.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import signal
import threading
from collections.abc import Callable, Iterator
from types import FrameType
from typing import Any

__all__ = ["second_sigint_waits"]

log = logging.getLogger(__name__)

_Handler = Callable[[int, FrameType | None], Any]

_owners = 0
_prev: _Handler | None = None
_received = 0
_held = False


def _wrappable(handler: object) -> bool:
    """Python's default SIGINT handler, or the one ``asyncio.Runner`` installs."""
    if handler is signal.default_int_handler:
        return True
    return isinstance(handler, functools.partial) and \
        getattr(handler.func, "__name__", "") == "_on_sigint"


def _on_sigint(signum: int, frame: FrameType | None) -> None:
    global _received, _held
    _received += 1
    if _received == 2:
        _held = True
        log.warning("SIGINT again: the machines stop their axes first (once more to "
                    "interrupt them)")
        return
    assert _prev is not None
    _prev(signum, frame)


def _take() -> bool:
    """Wrap SIGINT's handler for the machines of this process, if it is Python's or
    asyncio's; whether the machines have it."""
    global _owners, _prev, _received, _held
    if _owners:
        _owners += 1
        return True
    if threading.current_thread() is not threading.main_thread():
        return False
    handler = signal.getsignal(signal.SIGINT)
    if not _wrappable(handler):
        return False
    signal.signal(signal.SIGINT, _on_sigint)
    _owners, _prev, _received, _held = 1, handler, 0, False  # type: ignore[assignment]
    return True


def _give_back() -> None:
    """The last machine has left: SIGINT's handler back; one that was held goes to it."""
    global _owners, _prev
    _owners -= 1
    if _owners:
        return
    prev, _prev = _prev, None
    if signal.getsignal(signal.SIGINT) is _on_sigint and prev is not None:
        signal.signal(signal.SIGINT, prev)
    if _held and prev is not None:
        log.warning("SIGINT: the machines have stopped their axes; interrupting now")
        prev(signal.SIGINT, None)


@contextlib.contextmanager
def second_sigint_waits() -> Iterator[None]:
    """While inside, a second SIGINT is held until the last machine inside has left
    (where SIGINT's handler is Python's or asyncio's, in the main thread)."""
    taken = _take()
    try:
        yield
    finally:
        if taken:
            _give_back()
