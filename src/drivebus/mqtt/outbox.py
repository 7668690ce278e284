"""The bridge's outbox: bounded buffers between everything that wants to publish and the
one task that talks to the broker.

Producers never wait: state is latest-wins per topic (a slow or absent broker gets the
newest state of each axis, never a backlog) and each topic can have a minimum interval
(the state rate, the statistics period); replies are kept in order up to a bound and go
out first. The publisher takes what is due; while the broker is gone everything waits here.
"""

from __future__ import annotations

import logging
import math
from collections import OrderedDict, deque
from dataclasses import dataclass

import anyio
from paho.mqtt.properties import Properties

from drivebus.clock import monotonic

__all__ = ["Outbox", "Outgoing"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Outgoing:
    """One message to publish."""

    topic: str
    payload: bytes
    qos: int = 1
    retain: bool = False
    properties: Properties | None = None
    reply: bool = False
    """A reply to a command (kept in order, never coalesced)."""


class Outbox:
    """Latest-wins state per topic plus a bounded queue of replies; ``get`` gives what is
    due next (replies first)."""

    def __init__(self, max_replies: int = 1000) -> None:
        self.max_replies = max_replies
        self.dropped_replies = 0
        """Replies dropped because ``max_replies`` were waiting (a long broker outage)."""
        self._replies: deque[Outgoing] = deque()
        self._latest: OrderedDict[str, Outgoing] = OrderedDict()
        self._interval: dict[str, float] = {}
        self._sent_at: dict[str, float] = {}
        self._changed = anyio.Event()
        self.sent = anyio.Event()
        """Set when a publish ended (``note_sent``): a new one each time."""

    def __len__(self) -> int:
        return len(self._replies) + len(self._latest)

    def pending_replies(self) -> list[Outgoing]:
        """The replies waiting for the broker, oldest first."""
        return list(self._replies)

    @property
    def replies_waiting(self) -> int:
        """Replies queued and not yet taken to be published."""
        return len(self._replies)

    def note_sent(self) -> None:
        """A publish ended (acknowledged or failed): wake who waits for ``sent``."""
        self.sent.set()
        self.sent = anyio.Event()

    def reply(self, msg: Outgoing, *, first: bool = False) -> None:
        """Queue a reply (``first``: ahead of the others, e.g. one whose publish failed)."""
        if first:
            self._replies.appendleft(msg)
        else:
            self._replies.append(msg)
        while len(self._replies) > self.max_replies:
            self._replies.popleft()
            self.dropped_replies += 1
            if self.dropped_replies in (1, 10, 100) or self.dropped_replies % 1000 == 0:
                log.warning("mqtt: %d replies dropped: the broker has been unreachable for "
                            "too long", self.dropped_replies)
        self._changed.set()

    def put(self, msg: Outgoing, *, interval: float = 0.0) -> None:
        """Set the latest message of ``msg.topic`` (replacing one not yet sent); it goes
        out no sooner than ``interval`` seconds after the topic's previous message."""
        self._latest[msg.topic] = msg
        self._interval[msg.topic] = interval
        self._changed.set()

    def forget_rates(self) -> None:
        """Let every waiting message go at once (after a reconnection)."""
        self._sent_at.clear()
        self._changed.set()

    def _due(self) -> tuple[Outgoing | None, float]:
        """The next message to send now, or None and how long until one is due."""
        if self._replies:
            return self._replies.popleft(), 0.0
        now = monotonic()
        wait = math.inf
        for topic, msg in self._latest.items():
            due = self._sent_at.get(topic, -math.inf) + self._interval.get(topic, 0.0)
            if due <= now:
                del self._latest[topic]
                self._sent_at[topic] = now
                return msg, 0.0
            wait = min(wait, due - now)
        return None, wait

    async def get(self) -> Outgoing:
        """The next message that is due (waits for one)."""
        while True:
            msg, wait = self._due()
            if msg is not None:
                return msg
            self._changed = anyio.Event()
            with anyio.move_on_after(None if math.isinf(wait) else wait):
                await self._changed.wait()
