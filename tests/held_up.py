"""Timing bounds judged for a process that ran: a test that bounds how late something
happened (a gap the simulated wire stamps, a group's start skew, a blend's deviation)
measures this process as much as the code when the simulator runs in it. An attempt
that misses its bound by no more than the time its thread waited for a CPU meanwhile
(the kernel's schedstat, ``drivebus.clock.cpu_wait``), or the hypervisor took the
machine's CPUs away (``drivebus.clock.cpu_stolen``), was held up, not wrong: it is made
again, a bounded number of times. A miss that neither covers fails at once, so a real
lateness fails on a quiet machine and on a busy one alike."""

from __future__ import annotations

from collections.abc import Awaitable, Callable

import pytest

from drivebus.clock import cpu_stolen, cpu_wait

__all__ = ["within_bound"]


async def within_bound(attempt: Callable[[int], Awaitable[float]], what: str, *,
                       tries: int = 3) -> int:
    """Run ``attempt(n)`` (n = 1, 2, ...) until one keeps its bound; the number of the
    one that did. ``attempt`` makes its own assertions and returns by how much it missed
    its bound, in seconds (0 or less: it kept it; a distance converts at its speed).
    ``what`` names the bound in the failure."""
    held_up: list[tuple[float, float]] = []
    for n in range(1, tries + 1):
        waited = cpu_wait() + cpu_stolen()
        excess = await attempt(n)
        waited = cpu_wait() + cpu_stolen() - waited
        if excess <= 0:
            return n
        assert waited >= excess, (
            f"{what}: missed by {excess * 1e3:.3f} ms, and the process waited only "
            f"{waited * 1e3:.3f} ms for a CPU meanwhile (or had it taken away)")
        held_up.append((excess, waited))
    pytest.fail(f"{what}: held up on every attempt (missed by, CPU wait; s): {held_up}")
