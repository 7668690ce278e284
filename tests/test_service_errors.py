"""Every typed error answers its documented HTTP status: a walk over every
``DrivebusError`` subclass (every drivebus module imported, so a new class anywhere is
found) against the table in docs/guide/service.md and through a real uvicorn server;
and the group move whose drive timed out, which answered 500."""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import re
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import anyio
import httpx
import pytest
import uvicorn
from fastapi import FastAPI

import drivebus
from drivebus import AxisState
from drivebus.app import MachineSession
from drivebus.errors import DrivebusError, GroupMotionError
from drivebus.service import create_app
from drivebus.service.api import router
from drivebus.service.problems import PROBLEM, problem_data, status_of
from drivebus.service.runner import _listen, _serve_http, _Server, _url
from service_rig import DEMO, ROOT, running, until

GUIDE = ROOT / "docs" / "guide" / "service.md"


def every_error_class() -> list[type[DrivebusError]]:
    """``DrivebusError`` and each of its subclasses in drivebus, every module imported."""
    for info in pkgutil.walk_packages(drivebus.__path__, "drivebus."):
        if not info.name.endswith("__main__"):
            importlib.import_module(info.name)
    found: list[type[DrivebusError]] = []
    todo: list[type[DrivebusError]] = [DrivebusError]
    while todo:
        cls = todo.pop()
        if cls not in found and cls.__module__.startswith("drivebus."):
            found.append(cls)
            todo.extend(cls.__subclasses__())
    return sorted(found, key=lambda c: c.__name__)


def documented() -> dict[str, int]:
    """The guide's table of typed errors: name -> status."""
    rows = re.findall(r"^\| `(\w+)` \| (\d{3}) \|", GUIDE.read_text(encoding="utf-8"), re.M)
    table = {name: int(status) for name, status in rows}
    assert len(table) == len(rows), "a name twice in the guide's table"
    return table


SAMPLES: dict[str, Any] = {"code": 2, "function": 3, "holder": "bob", "axis": "y",
                           "written": ["jog_speed"], "responder": 5}
"""A value for each required constructor argument besides the message."""


def example(cls: type[DrivebusError]) -> DrivebusError:
    """An instance of ``cls`` built through its own constructor."""
    message = f"a {cls.__name__} raised by the test"
    init = next((k.__dict__["__init__"] for k in cls.__mro__ if "__init__" in k.__dict__
                 and k.__module__.startswith("drivebus.")), None)
    if init is None:  # Exception's own: a message
        return cls(message)
    args: list[Any] = []
    kwargs: dict[str, Any] = {}
    for p in list(inspect.signature(init).parameters.values())[1:]:
        if p.default is not p.empty or p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD):
            continue
        if p.name in ("message", "msg"):
            value: Any = message
        else:
            assert p.name in SAMPLES, f"{cls.__name__}({p.name}=...): add a sample value"
            value = SAMPLES[p.name]
        if p.kind is p.KEYWORD_ONLY:
            kwargs[p.name] = value
        else:
            args.append(value)
    return cls(*args, **kwargs)


ERRORS = every_error_class()


def test_the_walk_finds_the_errors_of_every_layer() -> None:
    names = {c.__name__ for c in ERRORS}
    assert {"DrivebusError", "ResponseTimeout", "GroupMotionError", "LineNoise",
            "StatuswordError", "ExprError", "UnknownMethod"} <= names, names


@pytest.mark.parametrize("cls", ERRORS, ids=[c.__name__ for c in ERRORS])
def test_each_error_class_has_its_documented_status(cls: type[DrivebusError]) -> None:
    table = documented()
    assert cls.__name__ in table, f"{cls.__name__}: not in the table of {GUIDE.name}"
    exc = example(cls)
    assert status_of(exc) == table[cls.__name__]
    assert (status_of(exc) == 500) == (cls is DrivebusError)  # only an untyped error is 500
    data = problem_data(exc, "/x")
    assert data["title"] == data["error"] == cls.__name__ and data["status"] == status_of(exc)
    assert data["detail"] == str(exc)


@pytest.mark.parametrize("cls", ERRORS, ids=[c.__name__ for c in ERRORS])
def test_a_group_motion_error_answers_with_its_cause_status(cls: type[DrivebusError]) -> None:
    cause = example(cls)
    try:
        raise GroupMotionError(f"axis y failed, the group was stopped: {cause}",
                               axis="y") from cause
    except GroupMotionError as exc:
        data = problem_data(exc)
    assert data["status"] == status_of(cause) and data["title"] == "GroupMotionError"
    assert data["axis"] == "y" and data["cause"] == {"error": cls.__name__,
                                                     "detail": str(cause)}


def test_the_table_names_no_error_that_does_not_exist() -> None:
    assert set(documented()) == {c.__name__ for c in ERRORS}


@asynccontextmanager
async def raising_service() -> AsyncIterator[httpx.AsyncClient]:
    """The service's application on a real uvicorn server, with one route more that
    raises the error named in its path (as a route would, from the session)."""
    async with MachineSession.open(DEMO) as session:
        app = create_app(session)
        by_name = {c.__name__: c for c in ERRORS}

        @app.post("/raise/{name}")
        async def raise_it(name: str) -> None:
            cause = example(by_name[name.removeprefix("group-")])
            if name.startswith("group-"):
                raise GroupMotionError(f"axis y failed: {cause}", axis="y") from cause
            raise cause

        sock = _listen("127.0.0.1", 0)
        server = _Server(uvicorn.Config(app, lifespan="on", log_config=None,
                                        access_log=False))
        try:
            async with anyio.create_task_group() as tg:
                await tg.start(_serve_http, server, sock)
                async with httpx.AsyncClient(base_url=_url(sock), timeout=30) as client:
                    yield client
                tg.cancel_scope.cancel()
        finally:
            sock.close()


async def test_each_error_class_answers_its_status_over_http() -> None:
    table = documented()
    async with raising_service() as client:
        for cls in ERRORS:
            for name in (cls.__name__, f"group-{cls.__name__}"):
                r = await client.post(f"/raise/{name}")
                assert r.status_code == table[cls.__name__], (name, r.text)
                assert r.headers["content-type"] == PROBLEM
                body = r.json()
                title = "GroupMotionError" if name.startswith("group-") else cls.__name__
                assert body["title"] == body["error"] == title, body
                assert body["type"] == f"urn:drivebus:error:{title}"
                assert body["instance"] == f"/raise/{name}" and body["detail"]


def test_the_api_docs_name_the_errors_behind_each_status() -> None:
    app = FastAPI()
    app.include_router(router)  # the service's routes, as create_app includes them
    spec = app.openapi()
    move = spec["paths"]["/api/axes/{name}/move"]["post"]["responses"]
    table = documented()
    for status in {s for s in table.values() if s != 500}:
        names = [n for n, s in table.items() if s == status]
        assert all(n in move[str(status)]["description"] for n in names), (status, names)


async def test_a_drive_that_times_out_during_a_group_move_is_a_504_naming_the_axis() -> None:
    async with running() as (svc, client):
        y = svc.session.machine.sim_drives["y"]
        y.power_loss()  # y stops answering; its axis is not Offline yet
        r = await client.post("/api/machine/group-move", json={"targets": {"x": 30, "y": 20}})
        assert r.status_code == 504, r.text
        assert r.headers["content-type"] == PROBLEM
        body = r.json()
        assert body["title"] == "GroupMotionError" and body["axis"] == "y"
        assert body["cause"]["error"] == "ResponseTimeout"
        assert "slave 3" in body["cause"]["detail"]
        twins = svc.session.machine.sim_drives
        assert not twins["x"].is_moving()
        y.power_restore()
        await until(svc, lambda: svc.session.axis("y").state is AxisState.STANDSTILL)
        assert not any(t.is_moving() for t in twins.values())
