"""What every test shares: a private runtime directory, builds made once per run, and the
``serial`` marker.

``make test`` runs the suite in two pytest invocations: every test not marked ``serial``
on several xdist workers at once (``-n``; most tests wait on simulated wires, motors and
subprocesses, not on the CPU), then the ``serial`` ones alone, one after the other.

Mark a test ``@pytest.mark.serial`` (a module: ``pytestmark = pytest.mark.serial``) only
when it must run alone: when it asserts something the machine's load changes (a duration
bound such as a start skew or an arrival spread, a count against wall time) or measures
(the bench). Such a bound is judged with ``tests/held_up.py``'s ``within_bound``: an
attempt whose miss the process's own CPU wait covers (the twins run in it, and were held
up with it) is made again; any other miss fails. A test that shares something with
others is not serial: give it its own
(port 0, or ``ports.reserved_port()`` for a port chosen before its server listens;
``tmp_path``; a ``sim://`` name of its own; ``$XDG_RUNTIME_DIR`` is already its own). An
expensive build several tests read (the docs site, the wheel) is made once per run with
the ``built_once`` fixture. Plain ``pytest`` (no ``-n``) runs everything in one process.

No test waits for ever: every wait has its own bound (``tests/waits.py`` names what it
waited for), and an ``async`` test as a whole is cancelled after ``TEST_BOUND`` seconds,
well before pytest-timeout (300 s) would kill its worker. A test whose bound ran out, its
own or this one, fails naming the line of the test that was waiting and what it waited
on inside (``_bounded``), not with a bare ``TimeoutError``.
"""

from __future__ import annotations

import asyncio
import fcntl
import functools
import gc
import inspect
import os
import shutil
import ssl
import sys
import threading
import time
import traceback
from collections.abc import Awaitable, Callable, Iterator
from pathlib import Path
from typing import Any

import anyio
import pytest

import drivebus
from drivebus.clock import StolenSince

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


TEST_BOUND = 180.0
"""Seconds an ``async`` test may run before its waits are cancelled (pytest's: 300)."""


def _waited_at(exc: BaseException) -> str:
    """Where a test was waiting when its bound cancelled the wait: the innermost line of
    the test suite in the cancelled wait's traceback, and the innermost line of all (for
    a task group's exceptions, each task's)."""
    cancelled = exc.__context__ if exc.__context__ is not None else exc
    if isinstance(cancelled, BaseExceptionGroup):
        return "; ".join(f"{type(sub).__name__} at {_where(sub)}"
                         for sub in cancelled.exceptions) + " (the tasks of a task group)"
    return _where(cancelled)


def _where(exc: BaseException) -> str:
    """The innermost line of the suite and of all in ``exc``'s own traceback."""
    frames = traceback.extract_tb(exc.__traceback__)
    if not frames:
        return "(no traceback)"
    ours = [f for f in frames if f"{os.sep}tests{os.sep}" in f.filename
            and Path(f.filename).name != "conftest.py"]
    where = ours[-1] if ours else frames[-1]
    text = f"{Path(where.filename).name}:{where.lineno} `{where.line}`"
    inner = frames[-1]
    if inner is not where:
        text += f", inside {Path(inner.filename).name}:{inner.lineno} `{inner.line}`"
    return text


def _bounded(test: Callable[..., Awaitable[Any]], name: str) -> Callable[..., Awaitable[Any]]:
    """``test`` within ``TEST_BOUND``; a ``TimeoutError`` out of it (this bound's or the
    test's own ``fail_after``) becomes a failure that says where it was waiting."""

    @functools.wraps(test)
    async def bounded(*args: Any, **kwargs: Any) -> None:
        scope = None
        try:
            with anyio.fail_after(TEST_BOUND) as scope:
                await test(*args, **kwargs)
        except TimeoutError as exc:
            whose = (f"the test's bound of {TEST_BOUND:g} s (tests/conftest.py)"
                     if scope is not None and scope.cancel_called else "a bound of the test")
            raise AssertionError(f"{name}: {whose} ran out while it waited at "
                                 f"{_waited_at(exc)}") from exc

    bounded.__drivebus_bounded__ = True  # type: ignore[attr-defined]
    return bounded


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_call(item: pytest.Item) -> None:
    """Run every ``async`` test function within its bound (``_bounded``)."""
    test = getattr(item, "obj", None)
    if inspect.iscoroutinefunction(test) and not getattr(test, "__drivebus_bounded__", False):
        item.obj = _bounded(test, item.name)  # type: ignore[attr-defined]


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

LOOP_STEP_LIMIT = 0.040 if os.environ.get("PYTEST_XDIST_WORKER") else 0.020
"""The most thread CPU time one event-loop step may take in a test, seconds: a step that
holds the loop longer delays every stop behind it (promise 1). CPU time, not wall time, so
preemption does not trip it. 20 ms for a test run alone; 40 ms in the parallel part of
``make test`` (six workers on two cores), where the same work measures up to twice the
CPU time it takes alone (shared caches and cores: the simulator's pty reader, up to 18 ms
alone on a slow 2-core host, and a test's own setup, 24 ms alone for three descriptions
parsed in one step, measured 36-47 ms there: such setup goes to a worker thread). Either
catches what the guard is for:
steps of 100 ms to seconds (the group planning of issue 30 held the loop 1-4 s); the exact
longest steps are bench figures (``longest_loop_step_ms``)."""


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
_DRIVEBUS = str(Path(drivebus.__file__).parent) + os.sep


class _TestsOwnSetup:
    """Thread CPU time the tests' own clients spent in one-time third-party setup so far:
    loading a TLS trust store (an ``httpx.AsyncClient`` with ``verify`` on loads
    certifi's bundle, ~20 ms of CPU, in the step that builds it). Counted only when no
    drivebus code is on the stack: the same call made by drivebus holds the loop."""

    def __init__(self) -> None:
        self.spent = 0.0

    def wrap(self, owner: type, name: str) -> None:
        call = getattr(owner, name)

        @functools.wraps(call)
        def timed(*args: Any, **kwargs: Any) -> Any:
            if threading.get_ident() != _MAIN_THREAD or _drivebus_on_stack():
                return call(*args, **kwargs)
            began = time.thread_time()
            try:
                return call(*args, **kwargs)
            finally:
                self.spent += time.thread_time() - began

        setattr(owner, name, timed)


def _drivebus_on_stack() -> bool:
    frame: Any = sys._getframe(2)
    while frame is not None:
        if frame.f_code.co_filename.startswith(_DRIVEBUS):
            return True
        frame = frame.f_back
    return False


_SETUP = _TestsOwnSetup()
for _name in ("load_verify_locations", "load_default_certs", "set_default_verify_paths"):
    _SETUP.wrap(ssl.SSLContext, _name)


_STOLEN = StolenSince()


def _guarded_run(run: Callable[[asyncio.Handle], None]) -> Callable[[asyncio.Handle], None]:
    def _run(self: asyncio.Handle) -> None:
        steps = _STEPS
        if steps is None or threading.get_ident() != _MAIN_THREAD:
            run(self)  # a loop of a worker thread (work moved off the test's loop) is free
            return
        modules = len(sys.modules)
        collected, setup = _GC.spent, _SETUP.spent
        stolen_mark = _STOLEN.mark()
        started = time.thread_time()
        try:
            run(self)
        finally:
            # The garbage collector's pauses land in whichever step allocates: they are
            # the interpreter's, not the code's, and are not counted; nor is a test's own
            # client loading a TLS trust store (not drivebus's work: _TestsOwnSetup).
            took = (time.thread_time() - started - (_GC.spent - collected)
                    - (_SETUP.spent - setup))
            # A step that imported modules (a lazy import, once per process) is not the
            # code under test holding the loop; nor is the time a virtual machine's
            # hypervisor took the CPU away, which the thread's clock counts as its own.
            if took > LOOP_STEP_LIMIT and len(sys.modules) == modules:
                took -= _STOLEN.since(stolen_mark)
                if took > LOOP_STEP_LIMIT:
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
