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

No test waits for ever: every wait has its own bound (``tests/waits.py`` names what it
waited for), and an ``async`` test as a whole is cancelled after ``TEST_BOUND`` seconds,
well before pytest-timeout (300 s) would kill its worker. A test whose bound ran out, its
own or this one, fails naming the line of the test that was waiting and what it waited
on inside (``_bounded``), not with a bare ``TimeoutError``.
"""

from __future__ import annotations

import fcntl
import functools
import gc
import inspect
import os
import shutil
import traceback
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import anyio
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


TEST_BOUND = 180.0
"""Seconds an ``async`` test may run before its waits are cancelled (pytest's: 300)."""


def _waited_at(exc: BaseException) -> str:
    """Where a test was waiting when its bound cancelled the wait: the innermost line of
    the test suite in the cancelled wait's traceback, and the innermost line of all."""
    cancelled = exc.__context__ if exc.__context__ is not None else exc
    frames = traceback.extract_tb(cancelled.__traceback__)
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
