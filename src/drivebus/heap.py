"""The garbage collector in a long-running drivebus process (the service, a worker).

A full pass of Python's garbage collector runs inside whatever event-loop step allocates
and scans every object the collector tracks. In a service over the demo machine (about
90 000 of them after start-up, most living as long as the process: modules, models,
routes, descriptions) one such pass took 58 ms on a 2-core host, once in 40 s of motion:
58 ms in which no stop could go out. ``settle()`` collects once when start-up is over
and freezes what is alive (``gc.freeze``), so that later passes scan only what came
after. ``PAUSES`` keeps the longest pass of each generation, for ``/metrics``.
"""

from __future__ import annotations

import gc
import time
from typing import Any

__all__ = ["PAUSES", "GcPauses", "frozen", "settle"]


class GcPauses:
    """The longest pass of the garbage collector per generation (wall-clock seconds: the
    time the event loop was held) since it was installed (``install``)."""

    def __init__(self) -> None:
        self.longest = [0.0, 0.0, 0.0]
        self._began = 0.0

    def __call__(self, phase: str, info: dict[str, Any]) -> None:
        if phase == "start":
            self._began = time.perf_counter()
            return
        took = time.perf_counter() - self._began
        generation = info.get("generation", 2)
        if 0 <= generation < 3 and took > self.longest[generation]:
            self.longest[generation] = took

    def install(self) -> GcPauses:
        """Watch the collector from now on (once per process, however often asked)."""
        if self not in gc.callbacks:
            gc.callbacks.append(self)
        return self


PAUSES = GcPauses()
"""The process's watch of the collector's passes (installed by ``settle``)."""

_frozen = 0


def frozen() -> int:
    """How many objects ``settle`` froze (0 before it ran). For ``/metrics``: asking the
    collector (``gc.get_freeze_count``) walks every frozen object, 5-13 ms for the
    service's 68 000 on a 2-core host, too long for a step of the event loop."""
    return _frozen


def settle() -> int:
    """Collect once and freeze every object alive (start-up is over: what is here now
    lives as long as the process); returns how many are frozen. For a process that
    drivebus owns, once, before it carries motion: a library leaves the heap of its host
    application alone."""
    global _frozen
    PAUSES.install()
    gc.collect()
    gc.freeze()
    _frozen = gc.get_freeze_count()
    return _frozen
