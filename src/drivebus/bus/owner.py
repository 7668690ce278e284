"""The bus's owner task: one transaction at a time (each after its silence) or a pipeline
of them, highest priority first; it serves on when cancelled from outside."""

from __future__ import annotations

import asyncio
import heapq
import math

import anyio

from drivebus.bus.cancel import Cancellations
from drivebus.bus.noise import NoiseWatch, expired, noise_error
from drivebus.bus.priority import Priority
from drivebus.bus.request import Request
from drivebus.bus.state import log
from drivebus.bus.transaction import Transactions
from drivebus.clock import monotonic
from drivebus.errors import LineClosed


class Owner(Transactions, Cancellations):
    """The scheduler's room for its owner task."""

    async def _owner(self) -> None:
        told = False
        while True:
            try:
                if self.line.max_in_flight > 1:
                    await self._pipeline()
                else:
                    await self._one_at_a_time()
            except BaseException as exc:
                if self._open and _only_cancelled(exc):
                    # Cancelled from outside while the bus is still open: the event loop
                    # is being torn down (asyncio.run's end, a server's force quit). The
                    # stops of the shutdown still need the line: serve on until the bus
                    # is closed by its owner.
                    task = asyncio.current_task()
                    if task is not None:
                        task.uncancel()
                    self._recover_interrupted()
                    if not told:
                        log.warning("bus on %s: its owner task was cancelled from outside "
                                    "(the event loop is shutting down?); it serves on until "
                                    "the bus is closed, so the stops still go out",
                                    self.line.name)
                        told = True
                    continue
                self._open = False
                if not isinstance(exc, LineClosed):
                    exc = LineClosed(f"bus owner on {self.line.name} stopped: {exc!r}")
                self._fail_queued(exc)
                raise

    async def _pipeline(self) -> None:
        """Up to ``line.max_in_flight`` transactions at once (a line that keeps no silences
        and matches replies by id): the head of the queue goes out as soon as a slot is
        free. The last slot is kept for ``Priority.EMERGENCY``, so a stop never waits for
        a pipelined poll to come back; a hold lets only those out."""
        loop = asyncio.get_running_loop()
        limit = self.line.max_in_flight
        noise = NoiseWatch(self.line)
        try:
            await self._dispatch(loop, limit, noise)
        except BaseExceptionGroup as group:
            if len(group.exceptions) == 1:  # one flight failed (the line is gone): say why
                raise group.exceptions[0] from None
            raise

    async def _dispatch(
        self, loop: asyncio.AbstractEventLoop, limit: int, noise: NoiseWatch
    ) -> None:
        async with anyio.create_task_group() as flights:
            while True:
                if self._queue and self._queue[0].future.done():
                    heapq.heappop(self._queue)  # its caller gave up while it was queued
                    continue
                room = limit - len(self._flying)
                if self._queue:
                    req = self._queue[0]
                    if req.priority < Priority.EMERGENCY:
                        room = 0 if self._holds else room - 1
                    if room > 0:
                        heapq.heappop(self._queue)
                        self._flying.add(req)
                        flights.start_soon(self._fly, req, noise)
                        continue
                self._work = loop.create_future()
                await self._work  # a request, a free slot or the end of a hold

    async def _fly(self, req: Request, noise: NoiseWatch) -> None:
        """One pipelined transaction; its slot is free again when it ends."""
        try:
            await self._run_one(req, noise, withdrawable=False)
        except asyncio.CancelledError:
            if self._open:  # cut off from outside: the owner serves on (``_owner``)
                self._interrupted(req)
            raise
        finally:
            self._landed(req)
            self._wake_owner()

    async def _one_at_a_time(self) -> None:
        """One transaction at a time, highest priority first, each after its silence."""
        loop = asyncio.get_running_loop()
        line = self.line
        waits = line.waits_for_silence
        noise = self._noise
        while True:
            adopt = self._adopt
            if adopt is not None:  # a chained transaction that needs judging here
                self._adopt = None
                req, begun = adopt
                self._waiting_for = req
                try:
                    await self._run_one(req, noise, withdrawable=True, begun=begun)
                finally:
                    self._waiting_for = None
                self._landed(req)
                continue
            if not self._queue or self._chained is not None:
                self._parked = self._chains and self._chained is None
                self._work = loop.create_future()
                try:
                    await self._work
                finally:
                    self._parked = False
                if self._adopt is None:
                    noise.reset()
                # else: a chained transaction needs judging; what the watch knows from
                # before it began stays (bytes that arrived during its silence, withdrawn:
                # a noisy line, waited out by the owner with its deadline, not begun again)
                continue
            req = self._queue[0]
            if req.future.done():  # the caller gave up (or ran out of time) while queued
                heapq.heappop(self._queue)
                continue
            now = monotonic()
            noise.look(now)
            next_expiry = math.inf
            if noise.since is not None:
                next_expiry = self._expire_noisy(noise.since, now)
                if req.future.done():
                    continue
            if self._holds and req.priority < Priority.EMERGENCY:
                self._work = loop.create_future()
                await self._work  # held: only an emergency request or the end of it
                continue
            extra = req.handle.guard + self._trail
            if waits and not extra and noise.since is None:
                # The line waits for the silence itself and sends right at its end (at
                # once if it has passed); it gives the request back if a more urgent one
                # comes, a hold begins or bytes arrive meanwhile.
                deferred = True
            else:
                ready = line.ready_at(req.handle.settings)
                guarded = False
                if extra:
                    # This slave's guard interval and the frame timeout of the slave that
                    # answered last: the owner itself keeps the line quiet that much longer
                    # than its silence (since the last traffic) before the frame.
                    ready = max(ready, line.last_activity(), self._last_end) + extra
                    guarded = ready > now
                # On a line known to be noisy (or with a guard to keep) the owner waits
                # itself, watching every deadline.
                deferred = ready > now and waits and noise.since is None and not guarded
                if ready > now and not deferred:
                    self._waiting_for = req
                    try:
                        await self._timer.sleep_until(min(ready, next_expiry))
                    finally:
                        self._waiting_for = None
                    continue  # the queue's head may have changed meanwhile
            heapq.heappop(self._queue)
            if deferred and self._chains and self._begin(req):
                continue  # it runs from callbacks; the owner waits for what needs it
            self._flying.add(req)
            self._waiting_for = req if deferred else None
            try:
                await self._run_one(req, noise, withdrawable=deferred)
            finally:
                self._waiting_for = None
            self._landed(req)
            # No yield here: a reply that came in whole woke its caller from the line's
            # callback before us, so a request it makes at once is in the queue already.

    def _expire_noisy(self, since: float, now: float) -> float:
        """Fail the queued requests whose time to see the noisy line quiet has run out;
        return the next such deadline (inf: none)."""
        out, nearest = expired(self._queue, since, now)
        for req in out:
            exc = noise_error(req, self.line, since, now)
            st = self.stats.slave(req.handle.address)
            st.line_noise += 1
            st.last_error = str(exc)
            req.future.set_exception(exc)
        return nearest


def _only_cancelled(exc: BaseException) -> bool:
    """True if ``exc`` is a cancellation, or a group of nothing but cancellations."""
    if isinstance(exc, asyncio.CancelledError):
        return True
    if isinstance(exc, BaseExceptionGroup):
        return all(_only_cancelled(e) for e in exc.exceptions)
    return False
