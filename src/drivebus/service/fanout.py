"""Fan-out: the session's events to every WebSocket connection, a little at a time.

The service shares its event loop with the bus schedulers, whose frames must leave on
time. Fifty watchers woken at once by one axis update would run fifty sends back to
back and hold the loop for a millisecond or more; here one task takes the session's
events and hands each to one connection per loop turn, so the senders wake one by one
and the line's work slips in between. Each connection's mailbox is latest-wins for
states and bounded for events, like any subscription.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from contextlib import contextmanager

import anyio
import anyio.lowlevel
from anyio.abc import TaskStatus

from drivebus.app import EventHub, Subscription
from drivebus.app.events import TOPICS

__all__ = ["Fanout"]

log = logging.getLogger(__name__)


class Fanout:
    """Carries the events of ``hub`` to the attached mailboxes; ``run`` is its task."""

    def __init__(self, hub: EventHub, backlog: int = 1024) -> None:
        self.hub = hub
        self.backlog = backlog
        self._boxes: list[Subscription] = []

    @contextmanager
    def attach(self, capacity: int = 256) -> Iterator[Subscription]:
        """A mailbox (watching no topic until ``set_topics``) for the ``with`` block."""
        box = Subscription((), capacity)
        self._boxes.append(box)
        try:
            yield box
        finally:
            self._boxes.remove(box)

    @property
    def connections(self) -> int:
        """Mailboxes attached."""
        return len(self._boxes)

    async def run(self, *, task_status: TaskStatus[None] = anyio.TASK_STATUS_IGNORED) -> None:
        """Deliver events until cancelled, one mailbox per event-loop turn."""
        lost = 0
        with self.hub.subscribe(TOPICS, capacity=self.backlog) as events:
            task_status.started()
            while True:
                event = await events.get()
                if events.lost != lost:
                    log.warning("websocket fan-out fell %d events behind", events.lost - lost)
                    lost = events.lost
                for box in list(self._boxes):
                    if event.topic in box.topics:
                        box.put(event)
                        await anyio.lowlevel.checkpoint()
