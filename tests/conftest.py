"""What every test shares: a private runtime directory, builds made once per run, and the
``serial`` marker.

``make test`` runs the suite in two pytest invocations: every test not marked ``serial``
on several xdist workers at once (``-n``; most tests wait on simulated wires, motors and
subprocesses, not on the CPU), then the ``serial`` ones alone, one after the other.

Mark a test ``@pytest.mark.serial`` (a module: ``pytestmark = pytest.mark.serial``) only
when it must run alone: when it asserts something the machine's load changes (a duration
bound such as a start skew or an arrival spread, a count against wall time) or measures
(the bench). A test that shares something with others is not serial: give it its own
(port 0, or ``ports.reserved_port()`` for a port chosen before its server listens;
``tmp_path``; a ``sim://`` name of its own; ``$XDG_RUNTIME_DIR`` is already its own). An
expensive build several tests read (the docs site, the wheel) is made once per run with
the ``built_once`` fixture. Plain ``pytest`` (no ``-n``) runs everything in one process.
"""

from __future__ import annotations

import asyncio
import fcntl
import gc
import os
import shutil
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

Build = Callable[[Path], None]
"""Fills the directory it is given (see ``built_once``)."""


def pytest_collection_finish(session: pytest.Session) -> None:
    """Freeze what exists once the tests are collected (modules, descriptions, models:
    about 75 000 objects) out of the cyclic garbage collector, as a long-running process
    does after its start-up. A full collection then scans only what the tests made: it
    takes 1-5 ms instead of 40-50 ms, a pause that otherwise lands, now and then, inside
    a test that bounds a dwell by one poll (20 ms). Hypothesis's check of the random
    generator Trio registers with it cannot see frozen referrers and would warn that it
    may be collected: it is not (Trio's module holds it), and no Hypothesis test runs on
    Trio."""
    session.config.addinivalue_line(
        "filterwarnings", "ignore:It looks like `register_random` was passed")
    gc.collect()
    gc.freeze()


@pytest.fixture(autouse=True)
def _private_runtime_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``drivebus sim`` publishes its pty paths and ``drivebus serve`` its URL under
    ``$XDG_RUNTIME_DIR`` (``drivebus.runtime``), where one-shot commands and ``sim://``
    lines of other processes find them: each test gets its own, so that tests running at
    once (and a user's own sims and services) never find each other's."""
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path / "run"))


@pytest.fixture(scope="session")
def built_once(tmp_path_factory: pytest.TempPathFactory) -> Callable[[str, Build], Path]:
    """``built_once(name, build)``: the directory ``name`` that ``build`` fills, built once
    per test run and shared by every xdist worker. The first to ask builds it under a file
    lock, the others wait for that build and read it; a build that fails leaves nothing,
    so the next to ask tries again (and fails the same way, in its own test)."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # the run's directory, above each worker's own

    def once(name: str, build: Build) -> Path:
        out, done = root / name, root / f"{name}.built"
        with (root / f"{name}.lock").open("w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
            if not done.exists():
                shutil.rmtree(out, ignore_errors=True)
                out.mkdir()
                build(out)
                done.touch()
        return out

    return once


# -- the loop-step guard ------------------------------------------------------------------

LOOP_STEP_LIMIT = 0.020
"""The most thread CPU time one event-loop step may take in a test, seconds: a step that
holds the loop longer delays every stop behind it (promise 1). CPU time, not wall time, so
a loaded machine does not trip it."""


class _LoopSteps:
    """The steps of the running test's event loops that took longer than the limit."""

    def __init__(self) -> None:
        self.slow: list[tuple[float, str]] = []


_STEPS: _LoopSteps | None = None


class _GcTime:
    """Thread CPU time spent in the garbage collector so far (``gc.callbacks``)."""

    def __init__(self) -> None:
        self.spent = 0.0
        self._began = 0.0

    def __call__(self, phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            self._began = time.thread_time()
        else:
            self.spent += time.thread_time() - self._began


_GC = _GcTime()
gc.callbacks.append(_GC)
_MAIN_THREAD = threading.get_ident()


def _guarded_run(run: Callable[[asyncio.Handle], None]) -> Callable[[asyncio.Handle], None]:
    def _run(self: asyncio.Handle) -> None:
        steps = _STEPS
        if steps is None or threading.get_ident() != _MAIN_THREAD:
            run(self)  # a loop of a worker thread (work moved off the test's loop) is free
            return
        modules = len(sys.modules)
        collected = _GC.spent
        started = time.thread_time()
        try:
            run(self)
        finally:
            # The garbage collector's pauses land in whichever step allocates: they are
            # the interpreter's, not the code's, and are not counted.
            took = time.thread_time() - started - (_GC.spent - collected)
            # A step that imported modules (a lazy import, once per process) is not the
            # code under test holding the loop.
            if took > LOOP_STEP_LIMIT and len(sys.modules) == modules:
                steps.slow.append((took, _describe(self)))

    return _run


asyncio.events.Handle._run = _guarded_run(asyncio.events.Handle._run)  # type: ignore[method-assign]


def _describe(handle: asyncio.Handle) -> str:
    """The step's callback and, for a task's step, where its coroutine stopped after it
    (the await that ended the step: the code that ran is just before it)."""
    text = repr(handle)[:200]
    task = getattr(getattr(handle, "_callback", None), "__self__", None)
    if isinstance(task, asyncio.Task):
        coro = task.get_coro()
        frames = []
        while coro is not None and len(frames) < 12:
            frame = getattr(coro, "cr_frame", None) or getattr(coro, "gi_frame", None)
            if frame is None:
                break
            frames.append(f"{frame.f_code.co_qualname}:{frame.f_lineno}")
            coro = getattr(coro, "cr_await", None) or getattr(coro, "gi_yieldfrom", None)
        text += f" task {task.get_name()!r} now at " + " > ".join(frames)
    return text


@pytest.fixture(autouse=True)
def _loop_steps(request: pytest.FixtureRequest) -> Iterator[None]:
    """Fail a test in which one event-loop step used more than ``LOOP_STEP_LIMIT`` of CPU
    time (``@pytest.mark.holds_loop(reason)`` exempts a test whose own code must)."""
    global _STEPS
    steps = _STEPS = _LoopSteps()
    try:
        yield
    finally:
        _STEPS = None
    if steps.slow and request.node.get_closest_marker("holds_loop") is None:
        took, step = max(steps.slow)
        pytest.fail(f"an event-loop step used {took * 1e3:.0f} ms of CPU time (limit "
                    f"{LOOP_STEP_LIMIT * 1e3:.0f} ms; {len(steps.slow)} such steps): {step}",
                    pytrace=False)
