"""Bounded waits that say what they waited for: every wait in a test has its own bound,
well under pytest's (300 s), and a test that runs out of it fails naming the wait, not
with a bare ``TimeoutError`` (or a hang until pytest-timeout kills the worker)."""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import IO, TypeVar

import anyio

__all__ = ["Deadline", "readline_within", "until", "within"]

T = TypeVar("T")


@contextmanager
def within(seconds: float, what: str) -> Iterator[None]:
    """Bound the waits inside the block: after ``seconds`` they are cancelled and the
    test fails with "waited N s for WHAT" (the cancelled wait shows in the traceback)."""
    try:
        with anyio.fail_after(seconds):
            yield
    except TimeoutError as exc:
        raise AssertionError(f"waited {seconds:g} s for {what}") from exc


async def until(check: Callable[[], T], what: str, *, seconds: float = 10.0,
                every: float = 0.01) -> T:
    """Look at ``check()`` every ``every`` s until it is truthy (for state that has no
    event to wait on: a twin, an emulator); its value. Fails after ``seconds``."""
    with within(seconds, what):
        while not (value := check()):  # noqa: ASYNC110 - nothing to wait on but the value
            await anyio.sleep(every)
    return value


class Deadline:
    """A bound for blocking (thread, subprocess) waits: ``left()`` is what remains of it
    for the next wait; ``fail()`` says what was awaited."""

    def __init__(self, seconds: float, what: str) -> None:
        self.seconds = seconds
        self.what = what
        self.at = time.monotonic() + seconds

    def left(self) -> float:
        """Seconds until the deadline (0 once it has passed)."""
        return max(0.0, self.at - time.monotonic())

    def fail(self, seen: object = "") -> AssertionError:
        """The error to raise when the deadline has passed."""
        extra = f": {seen}" if seen else ""
        return AssertionError(f"waited {self.seconds:g} s for {self.what}{extra}")


def readline_within(stream: IO[str], seconds: float, what: str) -> str:
    """The next line of a subprocess's pipe, read in a thread so that the wait is bounded
    (a process that prints nothing and does not exit fails the test, naming ``what``)."""
    box: queue.Queue[str] = queue.Queue()
    threading.Thread(target=lambda: box.put(stream.readline()), daemon=True).start()
    try:
        return box.get(timeout=seconds)
    except queue.Empty:
        raise AssertionError(f"waited {seconds:g} s for {what}") from None
