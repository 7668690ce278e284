"""The clock's decisions on a busy machine: how a timer that woke late adapts, and how
long a reply deadline that passed while the process was stopped is extended."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from drivebus.clock import STALL, STALL_GRACE, PreciseTimer, cpu_wait, monotonic, stall_grace


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
