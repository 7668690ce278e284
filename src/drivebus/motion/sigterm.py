"""SIGTERM for an application that embeds a machine and leaves the signal as it was.

Python's default for SIGTERM ends the process at once: an application that only runs
``open_machine`` in ``asyncio.run`` would die with its axes moving. Where nobody has
taken SIGTERM (its handler is still the default, in the main thread, on asyncio), an open
machine takes it while it is open: SIGTERM cancels the task that opened each machine, the
machines stop their moving axes as for any cancellation, and once the last one has left,
SIGTERM is raised again with its default action, so the process ends as it would have,
its axes stopped first. A front end that handles SIGTERM itself (the command line, the
service, the MQTT node) has taken it: nothing changes there.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import signal
import threading
from collections.abc import Iterator

__all__ = ["stops_before_sigterm"]

log = logging.getLogger(__name__)

_owners: list[asyncio.Task[object]] = []
_loop: asyncio.AbstractEventLoop | None = None
_received = False


def _on_sigterm() -> None:
    global _received
    _received = True
    log.warning("SIGTERM: stopping the machines' axes before the process ends")
    for task in _owners:
        task.cancel()


def _take() -> bool:
    """Take SIGTERM for the machines of this loop, if nobody has it; whether they have."""
    global _loop, _received
    if _owners:
        return _loop is not None
    if threading.current_thread() is not threading.main_thread():
        return False
    if signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL:
        return False  # the application (or a front end) handles it
    try:
        loop = asyncio.get_running_loop()
        loop.add_signal_handler(signal.SIGTERM, _on_sigterm)
    except (RuntimeError, NotImplementedError, ValueError):  # no asyncio loop (trio)
        return False
    _loop, _received = loop, False
    return True


@contextlib.contextmanager
def stops_before_sigterm() -> Iterator[None]:
    """While inside, SIGTERM cancels the task that entered (where nobody else handles
    SIGTERM); the last to leave after a SIGTERM ends the process by it."""
    task = asyncio.current_task() if _take() else None
    if task is not None:
        _owners.append(task)
    try:
        yield
    finally:
        if task is not None:
            _owners.remove(task)
            if not _owners:
                _give_back()


def _give_back() -> None:
    """SIGTERM back to its default; raised again if it came meanwhile."""
    global _loop
    loop, _loop = _loop, None
    if loop is not None and not loop.is_closed():
        loop.remove_signal_handler(signal.SIGTERM)  # (back to SIG_DFL)
    if _received:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        os.kill(os.getpid(), signal.SIGTERM)
