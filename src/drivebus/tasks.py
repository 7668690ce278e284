"""ServiceTasks: background tasks that keep serving while their users clean up.

A bus owner, an axis actor or a simulated wire must keep working while the code that
uses them is being cancelled: the shielded stop that a cancelled motion sends still needs
the bus, the actor's polls and the simulator. Each task here runs in its own shielded
cancel scope, so an outer cancellation does not reach it; it ends only when its owner
calls ``cancel()`` (or leaves the ``async with``), or when a sibling fails.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from types import TracebackType
from typing import Any, TypeVar

import anyio
import anyio.abc

__all__ = ["ServiceTasks", "shielded", "where_tasks_wait"]

T = TypeVar("T")


class ServiceTasks:
    """A task group whose tasks are shielded from outer cancellation until ``cancel()``."""

    def __init__(self) -> None:
        self._tg: anyio.abc.TaskGroup | None = None
        self._scopes: list[anyio.CancelScope] = []

    async def __aenter__(self) -> ServiceTasks:
        self._tg = anyio.create_task_group()
        await self._tg.__aenter__()
        return self

    def start_soon(
        self, fn: Callable[..., Awaitable[Any]], *args: Any, name: object = None
    ) -> None:
        """Start ``fn(*args)`` as a service task."""
        assert self._tg is not None, "ServiceTasks used outside its async with"
        scope = anyio.CancelScope(shield=True)
        self._scopes.append(scope)

        async def run() -> None:
            try:
                with scope:
                    await fn(*args)
            except BaseException:
                self.cancel()  # siblings are shielded: the group's own cancel cannot reach them
                raise
            finally:
                self._scopes.remove(scope)

        self._tg.start_soon(run, name=name)

    def cancel(self) -> None:
        """End every service task."""
        for s in list(self._scopes):
            s.cancel()
        if self._tg is not None:
            self._tg.cancel_scope.cancel()

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> bool | None:
        self.cancel()
        assert self._tg is not None
        try:
            return await self._tg.__aexit__(exc_type, exc, tb)
        except BaseExceptionGroup as group:
            # Only the body's own exception: give it back as it was raised, not wrapped,
            # so ``async with Bus(...)`` does not turn a DriveOffline into a group.
            if exc is not None and len(group.exceptions) == 1 and group.exceptions[0] is exc:
                raise exc from exc.__cause__
            raise


async def shielded(fn: Callable[[], Awaitable[T]]) -> T:
    """``fn()`` run to its end whatever cancels its caller meanwhile: a cleanup that must
    not be cut short (a cancelled motion's stop). An anyio shield does not hold off
    asyncio's own ``Task.cancel()`` (a second one while the first's cleanup runs, as a
    teardown or a timeout and an outer cancel give): on asyncio the cleanup runs as a task
    of its own, awaited again after each such cancel, and the cancellation is raised once
    it is done."""
    import asyncio

    try:
        loop = asyncio.get_running_loop()
    except RuntimeError:  # another backend: its shield holds
        with anyio.CancelScope(shield=True):
            return await fn()

    async def run() -> T:
        return await fn()

    inner = loop.create_task(run(), name="drivebus cleanup")  # awaited to its end below
    cancelled: BaseException | None = None
    while True:
        try:
            with anyio.CancelScope(shield=True):
                result = await asyncio.shield(inner)
            break
        except asyncio.CancelledError as exc:
            if inner.done():
                raise  # the cleanup itself was cancelled: nothing of ours to wait for
            cancelled = exc  # the caller's own cancel: the cleanup goes on
            task = asyncio.current_task()
            if task is not None:
                task.uncancel()
    if cancelled is not None:
        raise cancelled
    return result


def where_tasks_wait(*, limit: int = 40) -> list[str]:
    """Where each task of the running event loop waits (its await chain's innermost
    frames): what a bounded wait that ran out logs, so a stuck stop says what held it."""
    import asyncio

    found: list[str] = []
    for task in sorted(asyncio.all_tasks(), key=lambda t: t.get_name())[:limit]:
        frames: list[str] = []
        coro: Any = task.get_coro()
        while coro is not None and len(frames) < 64:
            frame = getattr(coro, "cr_frame", None) or getattr(coro, "ag_frame", None)
            if frame is not None:
                frames.append(f"{frame.f_code.co_name}:{frame.f_lineno}")
            coro = getattr(coro, "cr_await", None) or getattr(coro, "ag_await", None)
        found.append(f"{task.get_name()}: " + " > ".join(frames[-6:]))
    return found
