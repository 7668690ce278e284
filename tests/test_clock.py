"""The clock's decisions on a busy machine: how a timer that woke late adapts, and how
long a reply deadline that passed while the process was stopped is extended."""

from __future__ import annotations

import asyncio
from collections.abc import Iterator

import pytest

from drivebus.clock import (
    STALL,
    STALL_GRACE,
    DeadlineTimer,
    PreciseTimer,
    cpu_wait,
    monotonic,
    stall_grace,
)


@pytest.fixture
def lead() -> Iterator[None]:
    """The timers' shared lead, restored afterwards."""
    saved = PreciseTimer.lead
    try:
        yield
    finally:
        PreciseTimer.lead = saved


@pytest.mark.usefixtures("lead")
def test_a_timer_woken_late_by_a_busy_machine_does_not_spin_longer() -> None:
    """The lead (how early a timer fires, to spin to its deadline) follows the wake-up
    latency. A wake-up 10 ms late is the process waiting for a CPU: had the lead followed
    it, every timer would spin 300 us from then on (before: 50 -> 300 us at once)."""
    PreciseTimer.lead = 50e-6
    PreciseTimer._reach(monotonic() - 0.010, adapt=True)
    assert PreciseTimer.lead == 50e-6
    PreciseTimer._reach(monotonic() - 100e-6, adapt=True)  # the timer's own latency
    assert 50e-6 < PreciseTimer.lead <= PreciseTimer._LEAD_MAX


def test_a_deadline_passed_in_a_stall_gets_back_the_time_lost() -> None:
    assert stall_grace(0.0) == stall_grace(STALL / 2, STALL / 2) == 0.0  # it ran all along
    # its timer ran late: a moment for a starved peer to answer
    assert stall_grace(STALL) == stall_grace(30.0) == STALL_GRACE
    # its thread waited for a CPU meanwhile: that time back, and the moment
    assert stall_grace(0.0, 0.3) == stall_grace(STALL, 0.3) == pytest.approx(0.3 + STALL_GRACE)
    assert stall_grace(0.0, 60.0) == 1.0  # bounded


def test_the_time_a_thread_waited_for_a_cpu_only_grows() -> None:
    first = cpu_wait()
    sum(range(200_000))
    assert 0.0 <= first <= cpu_wait()


async def test_a_deadline_timer_fires_from_the_loop_never_early_and_schedules_no_handle() -> None:
    """A reply's deadline (``DeadlineTimer``): its callback runs from the event loop once
    the deadline has come, never before and never from ``call_at`` itself; re-arming
    replaces it, ``cancel`` forgets it; and the event loop has no timer handle to look at
    on its turns meanwhile (the receiver's deadline was an asyncio timer before)."""
    loop = asyncio.get_running_loop()
    timer = DeadlineTimer()
    fired: list[tuple[str, float]] = []
    done = asyncio.Event()

    def note(name: str) -> None:
        fired.append((name, monotonic()))
        done.set()

    try:
        timer.call_at(monotonic() - 1.0, lambda: note("past"))  # has passed: at once...
        assert fired == []  # ...but from the loop
        await asyncio.wait_for(done.wait(), 1.0)  # bounded: the timer fires within 1 s
        assert [name for name, _ in fired] == ["past"]

        done.clear()
        scheduled = _timer_handles(loop)  # (the test's own bounds)
        timer.call_at(monotonic() + 10.0, lambda: note("replaced"))
        deadline = monotonic() + 0.005
        timer.call_at(deadline, lambda: note("deadline"))
        assert _timer_handles(loop) == scheduled  # no asyncio timer of its own
        await asyncio.wait_for(done.wait(), 1.0)
        assert [name for name, _ in fired] == ["past", "deadline"]
        assert fired[-1][1] >= deadline

        timer.call_at(monotonic() + 0.002, lambda: note("cancelled"))
        timer.cancel()
        await asyncio.sleep(0.02)  # (ten times its deadline: it would have fired by now)
        assert [name for name, _ in fired] == ["past", "deadline"]
    finally:
        timer.close()


def _timer_handles(loop: asyncio.AbstractEventLoop) -> set[asyncio.TimerHandle]:
    """The asyncio timers the event loop will look at on its turns."""
    return {h for h in loop._scheduled if not h.cancelled()}  # type: ignore[attr-defined]


def test_the_stolen_cpu_time_counts_up_and_a_mark_is_read_at_most_so_old(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """``cpu_stolen`` never goes back; ``StolenSince.mark`` reads /proc/stat again only
    once its last reading is ``FRESH`` old, and ``since`` is what was stolen after it."""
    from drivebus import clock

    first = clock.cpu_stolen()
    assert first >= 0.0 and clock.cpu_stolen() >= first
    readings = iter([10.0, 10.0, 10.5, 11.0])
    monkeypatch.setattr(clock, "cpu_stolen", lambda: next(readings))
    watch = clock.StolenSince()  # reads 10.0
    assert watch.mark() == 10.0  # fresh: not read again
    watch._at -= clock.StolenSince.FRESH * 2  # (as if time had passed)
    assert watch.mark() == 10.0  # read again: 10.0
    assert watch.since(10.0) == 0.5  # read: 10.5
    watch._at -= clock.StolenSince.FRESH * 2
    assert watch.mark() == 11.0
