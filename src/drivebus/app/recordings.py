"""Recordings a service keeps for its clients: started and stopped by id, bounded.

A client (the dashboard's Record button) starts a recording of the machine, stops it, and
fetches it (its report, its JSONL). Recording only listens (``Machine.record``), so any
client may record, read scope included. At most ``MAX_RUNNING`` run at once and the
last ``KEEP`` are kept; each one's rings are sized for a service (``MAX_SAMPLES`` per
axis, ``MAX_TRANSACTIONS`` per line), so a forgotten recording costs bounded memory.
"""

from __future__ import annotations

import itertools
import time
from collections import OrderedDict
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from drivebus.errors import NotFound, StateError
from drivebus.motion import Machine, Recording

__all__ = ["RecordingRecord", "Recordings"]

MAX_RUNNING = 4
KEEP = 8
MAX_SAMPLES = 30_000
"""Per axis: five minutes at a 10 ms poll."""
MAX_TRANSACTIONS = 150_000
"""Per line: five minutes at 500 transactions/s."""


@dataclass
class RecordingRecord:
    """One recording with its id and who started it."""

    id: str
    recording: Recording
    client: str | None = None
    created: float = field(default_factory=time.time)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready facts about it (not its data)."""
        rec = self.recording
        return {
            "id": self.id,
            "client": self.client,
            "running": rec.recording,
            "started": rec.started_wall,
            "duration": round(rec.duration, 3),
            "axes": list(rec.axes),
            "lines": list(rec.lines),
            "samples": sum(len(t.samples) for t in rec.axes.values()),
            "events": sum(len(t.events) for t in rec.axes.values()),
            "transactions": sum(len(t.transactions) for t in rec.lines.values()),
        }


class Recordings:
    """The recordings of one machine, by id."""

    def __init__(self, machine: Machine) -> None:
        self.machine = machine
        self._all: OrderedDict[str, RecordingRecord] = OrderedDict()
        self._ids = itertools.count(1)

    def start(self, axes: Iterable[str] | None = None, *, client: str | None = None
              ) -> RecordingRecord:
        """Start recording ``axes`` (all if None) and their lines; ``StateError`` if
        ``MAX_RUNNING`` already run, ``NotFound`` for an unknown axis."""
        axes = None if axes is None else list(axes)
        for name in axes or ():
            if name not in self.machine.axes:
                raise NotFound(f"no axis {name!r} in machine {self.machine.config.name} "
                               f"(axes: {', '.join(self.machine.axes)})")
        running = [r for r in self._all.values() if r.recording.recording]
        if len(running) >= MAX_RUNNING:
            raise StateError(f"{len(running)} recordings are running "
                             f"({', '.join(r.id for r in running)}): stop one first")
        rec = self.machine.record(axes, max_samples=MAX_SAMPLES,
                                  max_transactions=MAX_TRANSACTIONS)
        record = RecordingRecord(f"r{next(self._ids)}", rec.start(), client)
        self._all[record.id] = record
        while len(self._all) > KEEP:
            old = next(r for r in self._all.values())
            old.recording.stop()
            del self._all[old.id]
        return record

    def get(self, rec_id: str) -> RecordingRecord:
        """The recording ``rec_id``; ``NotFound`` if there is none (or it is gone)."""
        try:
            return self._all[rec_id]
        except KeyError:
            raise NotFound(f"no recording {rec_id!r}") from None

    def stop(self, rec_id: str) -> RecordingRecord:
        """Stop recording ``rec_id`` (a no-op if it stopped already)."""
        record = self.get(rec_id)
        record.recording.stop()
        return record

    def all(self) -> list[RecordingRecord]:
        """Every recording kept, oldest first."""
        return list(self._all.values())

    def close(self) -> None:
        """Stop every recording (the machine is closing)."""
        for r in self._all.values():
            r.recording.stop()
