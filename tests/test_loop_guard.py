"""The loop-step guard (``conftest.py``) itself: it fails a test when drivebus code holds
the event loop, also for work a test's own client may do unblamed (a TLS trust store
loaded from drivebus code is drivebus holding the loop), and it leaves out that work of
a test's own client, which CI saw as a 22 ms step building an ``httpx.AsyncClient``."""

from __future__ import annotations

import ssl
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import certifi
import httpx
import pytest
from anyio.lowlevel import checkpoint

from drivebus import checks, open_machine
from drivebus.clock import cpu_stolen
from test_recording import machine

conftest = sys.modules["conftest"]
LIMIT = conftest.LOOP_STEP_LIMIT


@contextmanager
def watched() -> Iterator[Any]:
    """The slow loop steps that begin inside the block (the test's own guard sees none)."""
    assert conftest._STEPS is not None, "the loop-step guard is not watching this test"
    outer, conftest._STEPS = conftest._STEPS, conftest._LoopSteps()
    try:
        yield conftest._STEPS
    finally:
        conftest._STEPS = outer


def busy(seconds: float, work: Callable[[], object] = lambda: None) -> None:
    """Do ``work`` again and again, without yielding, until ``seconds`` of CPU time are
    used (time a virtual machine's hypervisor takes the CPU away not counted: the guard
    does not count it either)."""
    began, stolen = time.thread_time(), cpu_stolen()
    while time.thread_time() - began - (cpu_stolen() - stolen) < seconds:
        work()


def trust_store() -> None:
    """Load certifi's CA bundle (about 20 ms of CPU each here) until 70 ms of CPU are
    used (three loads once measured under the 40 ms limit, the guard leaving steal out)."""
    busy(0.07, lambda: ssl.create_default_context().load_verify_locations(certifi.where()))


async def move_with(work: Callable[[], None], monkeypatch: pytest.MonkeyPatch) -> list[Any]:
    """The slow steps of an axis's move whose argument check (drivebus code, on the
    loop) first does ``work``."""
    real = checks.finite

    def finite(*args: Any, **kwargs: Any) -> Any:
        work()
        return real(*args, **kwargs)

    async with open_machine(machine("guard")) as m:
        with watched() as steps:
            await checkpoint()
            monkeypatch.setattr(checks, "finite", finite)
            try:
                await m.axes["x"].move_to(1.0)
            finally:
                monkeypatch.setattr(checks, "finite", real)
    return list(steps.slow)


async def test_drivebus_code_holding_the_loop_fails_the_guard(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # (0.07 s of work: the guard's mark of the stolen time may be a few ms old)
    slow = await move_with(lambda: busy(0.07), monkeypatch)
    assert [s for s in slow if s[0] >= 0.06 and "Axis.move_to" in s[1]], slow


async def test_a_trust_store_loaded_by_drivebus_code_fails_the_guard(
        monkeypatch: pytest.MonkeyPatch) -> None:
    slow = await move_with(trust_store, monkeypatch)
    assert [s for s in slow if s[0] > LIMIT and "Axis.move_to" in s[1]], slow


async def test_a_tests_own_tls_client_setup_is_not_drivebus_holding_the_loop() -> None:
    clients = [httpx.AsyncClient(timeout=30)]  # its lazy imports (a step that imports
    # is left out anyway) before the step watched, and certifi's (its first where())
    certifi.where()
    with watched() as steps:
        await checkpoint()
        modules, began = len(sys.modules), time.thread_time()
        trust_store()
        clients += [httpx.AsyncClient(timeout=30) for _ in range(3)]  # verify on: certifi
        took = time.thread_time() - began
        assert len(sys.modules) == modules
        await checkpoint()
    for client in clients:
        await client.aclose()
    assert took > 2 * LIMIT  # in one step: what the guard would otherwise see
    assert steps.slow == []
