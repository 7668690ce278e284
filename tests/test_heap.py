"""The heap of a long-running drivebus process: ``settle()`` freezes what start-up left
alive, so that the garbage collector's later full passes (each an event-loop step no stop
can interrupt) scan only what came after; ``PAUSES`` keeps each generation's longest."""

from __future__ import annotations

import gc
from collections.abc import Iterator

import pytest
from anyio.lowlevel import checkpoint

from drivebus import heap
from drivebus.bench.common import LoopSteps, start_up_over
from test_loop_guard import busy


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


@pytest.mark.holds_loop("it holds its own event loop, to see which steps the bench counts")
async def test_the_bench_leaves_out_the_step_that_freezes_its_start_up(unfrozen: None) -> None:
    """``drivebus bench``'s scale scenario freezes its machine's heap once it is open, as
    ``drivebus serve`` does: that step (a full collection) is start-up, not a hold of the
    loop while the machine moves; a step after it counts again."""
    with LoopSteps() as steps:
        await checkpoint()
        busy(0.05)
        await checkpoint()
        counted = steps.longest
        assert counted >= 0.03  # (less what the hypervisor took, in 10 ms ticks)
        start_up = [[i] for i in range(50_000)]  # what a machine's start-up leaves alive
        gc_before = steps.longest_gc
        start_up_over()
        busy(0.15)  # the rest of that step
        await checkpoint()
        assert steps.longest == counted  # left out, and its collection too
        assert steps.longest_gc == gc_before  # (its full collection: some 10-70 ms here)
        assert gc.get_freeze_count() >= len(start_up)
        busy(0.1)
        await checkpoint()
        assert steps.longest >= 0.08  # the next step counts
    assert LoopSteps.installed == []
