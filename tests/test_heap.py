"""The heap of a long-running drivebus process: ``settle()`` freezes what start-up left
alive, so that the garbage collector's later full passes (each an event-loop step no stop
can interrupt) scan only what came after; ``PAUSES`` keeps each generation's longest."""

from __future__ import annotations

import gc
from collections.abc import Iterator

import pytest

from drivebus import heap


@pytest.fixture
def unfrozen() -> Iterator[None]:
    """The test process's heap as it was: frozen objects back in the collector's care."""
    try:
        yield
    finally:
        gc.unfreeze()


def test_settle_freezes_what_is_alive_and_later_passes_leave_it_alone(unfrozen: None) -> None:
    alive = len(gc.get_objects())
    frozen = heap.settle()
    assert frozen == gc.get_freeze_count() >= alive // 2
    assert heap.frozen() == frozen  # (kept: asking the collector walks every frozen object)
    assert heap.PAUSES in gc.callbacks and gc.callbacks.count(heap.PAUSES) == 1
    heap.settle()  # (again: the watch is not installed twice)
    assert gc.callbacks.count(heap.PAUSES) == 1
    made = [[i] for i in range(1000)]  # after start-up: the collector's to scan
    assert len(gc.get_objects(generation=0)) + len(gc.get_objects(generation=1)) + \
        len(gc.get_objects(generation=2)) < frozen // 2
    del made
    before = list(heap.PAUSES.longest)
    gc.collect()
    assert heap.PAUSES.longest[2] > 0.0 and heap.PAUSES.longest[2] >= before[2]


def test_the_pause_watch_keeps_the_longest_pass_of_each_generation() -> None:
    watch = heap.GcPauses()
    for generation, took in ((0, 0.001), (2, 0.05), (0, 0.0005), (2, 0.01)):
        watch("start", {"generation": generation})
        watch._began -= took  # (as if the pass had taken that long)
        watch("stop", {"generation": generation})
    assert watch.longest[0] == pytest.approx(0.001, abs=1e-4)
    assert watch.longest[1] == 0.0
    assert watch.longest[2] == pytest.approx(0.05, abs=1e-4)
