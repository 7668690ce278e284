"""SegmentGate: the end of one segment of a group's path, shared by the group's axes.

Each axis runs its own queue; a group keeps its axes together by giving each segment's
moves the gate of the segment before: an axis starts its part of the next segment once
every axis that moved in that segment reported it there (buffered), or at the planned
corner moment (blended). An axis that had no part in it waits for the gate alone.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

import anyio

from drivebus.errors import MotionAborted

__all__ = ["SegmentGate"]


class SegmentGate:
    """Open once every named axis reported its part of the segment done."""

    def __init__(self, names: Iterable[str]) -> None:
        self._left = set(names)
        self._waiters: list[Callable[[], None]] = []
        self.opened = anyio.Event()
        self.opened_at: float | None = None
        """When the last axis reported (monotonic s)."""
        self.error: BaseException | None = None
        """What ended an axis's part instead (the segments after it are dropped)."""
        if not self._left:
            self.opened.set()

    @property
    def open(self) -> bool:
        """True once every axis is there."""
        return self.opened.is_set()

    def arrive(self, name: str, at: float) -> None:
        """Axis ``name`` is done with its part (at ``at``); the last one opens the gate."""
        if name not in self._left:
            return
        self._left.discard(name)
        if not self._left:
            self.opened_at = at
            self.opened.set()
            for wake in self._waiters:
                wake()

    def fail(self, name: str, error: BaseException) -> None:
        """Axis ``name``'s part failed (or was stopped): the gate opens failed."""
        if self.open:
            return
        self.error = MotionAborted(f"axis {name}'s part of the segment before it failed: "
                                   f"{error}")
        self._left.clear()
        self.opened.set()
        for wake in self._waiters:
            wake()

    def notify(self, wake: Callable[[], None]) -> None:
        """Call ``wake`` when the gate opens (at once if it is open)."""
        if self.open:
            wake()
        else:
            self._waiters.append(wake)
