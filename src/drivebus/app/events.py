"""Events: what a running machine tells its watchers, fanned out without ever blocking.

State updates (an axis polled, a line's counters) are coalesced per key: a slow watcher
gets the latest state of each axis, never a backlog. Discrete events (a motion started,
done, aborted or failed, an error, an e-stop) are kept in order up to a bound; a watcher
that falls that far behind loses the oldest and is told how many (``lost``).
"""

from __future__ import annotations

import itertools
from collections import OrderedDict
from collections.abc import AsyncIterator, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import anyio

from drivebus.errors import ArgumentError

__all__ = ["TOPICS", "Event", "EventHub", "Subscription"]

TOPICS = frozenset({"axes", "lines", "motions", "errors"})
"""What a watcher can subscribe to."""


@dataclass(frozen=True)
class Event:
    """One message: its topic, the key it coalesces on (None: never coalesced), its data."""

    topic: str
    key: str | None
    data: dict[str, Any] = field(default_factory=dict)


class Subscription:
    """One watcher's bounded mailbox."""

    def __init__(self, topics: Iterable[str], capacity: int = 256) -> None:
        self.topics = set(topics)
        self.capacity = capacity
        self.lost = 0
        """Discrete events dropped because this watcher fell too far behind."""
        self._box: OrderedDict[tuple[str, str] | int, Event] = OrderedDict()
        self._discrete = 0
        self._seq = itertools.count()
        self._ready = anyio.Event()

    def set_topics(self, topics: Iterable[str]) -> set[str]:
        """Watch ``topics`` from now on (``ArgumentError`` naming the topics there are);
        waiting events of topics no longer watched are dropped. Returns the new set."""
        wanted = set(topics)
        unknown = wanted - TOPICS
        if unknown:
            raise ArgumentError(f"no topic {', '.join(sorted(unknown))} "
                                f"(topics: {', '.join(sorted(TOPICS))})")
        self.topics = wanted
        for slot, event in list(self._box.items()):
            if event.topic not in wanted:
                del self._box[slot]
                if isinstance(slot, int):
                    self._discrete -= 1
        return wanted

    def put(self, event: Event) -> None:
        """Take ``event`` if subscribed: replace the same key's older state, or queue it."""
        if event.topic not in self.topics:
            return
        if event.key is not None:
            slot: tuple[str, str] | int = (event.topic, event.key)
            self._box.pop(slot, None)  # the newest state goes to the back of the line
        else:
            slot = next(self._seq)
            self._discrete += 1
            if self._discrete > self.capacity:
                for old in self._box:
                    if isinstance(old, int):
                        del self._box[old]
                        self._discrete -= 1
                        self.lost += 1
                        break
        self._box[slot] = event
        self._ready.set()

    async def get(self) -> Event:
        """The oldest waiting event (waits for one)."""
        while not self._box:
            await self._ready.wait()
            self._ready = anyio.Event()
        slot, event = self._box.popitem(last=False)
        if isinstance(slot, int):
            self._discrete -= 1
        return event

    def drain(self) -> list[Event]:
        """Every waiting event, oldest first, without waiting (a paced reader's batch)."""
        events = list(self._box.values())
        self._box.clear()
        self._discrete = 0
        return events

    def __aiter__(self) -> AsyncIterator[Event]:
        return self._iterate()

    async def _iterate(self) -> AsyncIterator[Event]:
        while True:
            yield await self.get()


class EventHub:
    """Fans events out to every subscription; publishing never waits."""

    def __init__(self) -> None:
        self._subs: list[Subscription] = []

    @contextmanager
    def subscribe(self, topics: Iterable[str], capacity: int = 256) -> Iterator[Subscription]:
        """A subscription to ``topics`` for the ``with`` block."""
        sub = Subscription(topics, capacity)
        self._subs.append(sub)
        try:
            yield sub
        finally:
            self._subs.remove(sub)

    def publish(self, event: Event) -> None:
        """Give ``event`` to every subscription that wants it."""
        for sub in self._subs:
            sub.put(event)

    @property
    def subscribers(self) -> int:
        """How many subscriptions are open."""
        return len(self._subs)
