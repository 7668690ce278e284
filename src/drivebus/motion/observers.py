"""What an axis tells those who look: its polled statuses (``watch``) and its motion
events (``listen``); neither adds bus traffic, and a slow reader never blocks the actor."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable

from drivebus.clock import monotonic
from drivebus.drives.status import DriveStatus
from drivebus.motion.events import AxisListener, MotionEvent, MotionEventKind
from drivebus.motion.motions import Latest, Motion
from drivebus.motion.units import Units

__all__ = ["AxisObservers"]


class AxisObservers:
    """The watchers and listeners of an axis (the actor publishes to them)."""

    name: str
    units: Units
    status: DriveStatus | None
    _watchers: list[Latest]
    _listeners: list[AxisListener]

    def listen(self, listener: AxisListener) -> Callable[[], None]:
        """Call ``listener`` with every status polled and every ``MotionEvent`` from now
        on (quick, never raising: it runs in the actor); returns the function that ends it.
        It adds no bus traffic."""
        self._listeners.append(listener)

        def end() -> None:
            if listener in self._listeners:
                self._listeners.remove(listener)

        return end

    def _note(self, kind: MotionEventKind, what: str, *, m: Motion | None = None,
              detail: str = "", at: float | None = None, planned_end: float | None = None
              ) -> None:
        """Tell the listeners a motion event (nothing is built when nobody listens)."""
        if not self._listeners:
            return
        target = None if m is None or m.target is None else self.units.from_pulses(m.target)
        event = MotionEvent(self.name, kind, monotonic() if at is None else at, what,
                            target, planned_end, detail)
        for listener in self._listeners:
            listener(event)

    def _publish(self) -> None:
        if self.status is not None:
            for w in self._watchers:
                w.put(self.status)

    async def watch(self) -> AsyncIterator[DriveStatus]:
        """Statuses as they are polled; a slow reader gets the latest, never blocks the actor."""
        slot = Latest()
        self._watchers.append(slot)
        try:
            while True:
                yield await slot.get()
        finally:
            self._watchers.remove(slot)
