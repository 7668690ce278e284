"""Running a front end's work as a process: SIGINT and SIGTERM end it cleanly.

A signal cancels the work; its cleanup (stopping the axes it moved, saying ``offline``)
runs in full, shielded from further signals, before the process exits.
"""

from __future__ import annotations

import signal
from collections.abc import Awaitable, Callable

import anyio

__all__ = ["run_until_signalled"]


def run_until_signalled(
    fn: Callable[[], Awaitable[int]],
    *,
    interrupt_ok: bool = False,
    on_signal: Callable[[signal.Signals], None] | None = None,
) -> int:
    """Run ``fn`` in an event loop; SIGINT/SIGTERM cancel it and give exit status
    128+signal, or 0 if ``interrupt_ok`` (work that runs until stopped). ``on_signal`` is
    told which signal ended it. Further signals during the cleanup are ignored."""

    async def main() -> int:
        caught: list[int] = []
        result = 0
        with anyio.open_signal_receiver(signal.SIGINT, signal.SIGTERM) as signals:
            async with anyio.create_task_group() as tg:

                async def watch() -> None:
                    async for sig in signals:
                        caught.append(int(sig))
                        tg.cancel_scope.cancel()
                        return

                async def work() -> None:
                    nonlocal result
                    result = await fn()
                    tg.cancel_scope.cancel()

                tg.start_soon(watch)
                tg.start_soon(work)
        if caught:
            if on_signal is not None:
                on_signal(signal.Signals(caught[0]))
            return 0 if interrupt_ok else 128 + caught[0]
        return result

    return anyio.run(main)
