"""The promise matrix's front-end rows: the service's HTTP routes (a real uvicorn) and the
MQTT bridge's commands (a real Mosquitto) that move or write, against the same promises
as ``test_promises.py``: a stop of the command's own axis and of another axis wins (the
route returns with the twin at rest, nothing of the command starts after the stop frame),
cancelling the command (``DELETE /api/motions/{id}``) stops what it started, a refused
request sends nothing, and leaving the service leaves every axis at rest. A route joins
by one line in ``ROUTES``. Judged by the twins and the wire log."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import anyio
import pytest

from drivebus.motion import Machine
from mqtt_helpers import Broker, bridged, probe, require_tools, running_broker
from service_rig import DEMO, at_rest, moving, running
from wirelog import command_frames, log_size, write_frames


@dataclass(frozen=True)
class Route:
    """A route that moves: its request, the axes it moves, a bystander on its line, and a
    request of it that must be refused."""

    name: str
    method: str
    path: str
    body: Callable[[Machine], dict[str, Any]]
    axes: tuple[str, ...]
    bystander: str
    refused: dict[str, Any]
    refused_path: str = ""
    """Where the refused request goes (default: ``path``)."""


def _far(m: Machine, name: str) -> float:
    ax = m.axes[name]
    lo, hi = ax.config.limits or (-100.0, 100.0)
    return lo + (hi - lo) * (0.8 if (ax.position or 0.0) < (lo + hi) / 2 else 0.2)


ROUTES = [
    Route("move", "POST", "/api/axes/x/move", lambda m: {"target": _far(m, "x"), "speed": 30.0},
          ("x",), "z", {"target": 1e6}),
    Route("group move", "POST", "/api/machine/group-move",
          lambda m: {"targets": {"x": _far(m, "x"), "y": _far(m, "y")}}, ("x", "y"), "z",
          {"targets": {"x": 10.0, "y": 1e6}}),
    Route("home", "POST", "/api/axes/z/home", lambda m: {}, ("z",), "x",
          {}, "/api/axes/aux/home"),
    Route("jog", "POST", "/api/axes/y/jog", lambda m: {"speed": 5.0, "ttl": 10.0}, ("y",),
          "z", {"speed": "fast"}),
]


def ids(r: Route) -> str:
    return r.name



@pytest.mark.parametrize("r", ROUTES, ids=ids)
async def test_a_route_is_stopped_by_its_own_axis_and_never_holds_up_another(r: Route) -> None:
    async with running() as (svc, client):
        m = svc.session.machine
        by = m.axes[r.bystander]
        await at_rest(svc)
        # a bystander jogs on the same line: its stop goes out while the route's command runs
        assert (await client.post(f"/api/axes/{by.name}/jog", json={
            "speed": 2.0 if (by.position or 0) < 40 else -2.0, "ttl": 10.0})).status_code == 200
        await moving(svc, by.name)
        started = await client.request(r.method, r.path, json=r.body(m))
        assert started.status_code in (200, 202), (started.status_code, started.text)
        await moving(svc, r.axes[0])
        for name in (by.name, r.axes[0]):
            mark = log_size(m, name)
            called = time.monotonic()
            stopped = await client.post(f"/api/axes/{name}/stop")
            assert stopped.status_code == 200, stopped.text
            assert not m.sim_drives[name].is_moving(), name  # it returned at rest
            frames = command_frames(m, name, mark)
            stops = [t for k, t in frames if k == "stop" and t > called]
            assert stops, (name, frames)
            assert not [t for k, t in frames if k == "start" and t > stops[0]], frames
        await at_rest(svc, *r.axes)


@pytest.mark.parametrize("r", [r for r in ROUTES if r.name != "jog"], ids=ids)
async def test_deleting_a_motion_stops_what_it_started(r: Route) -> None:
    async with running() as (svc, client):
        m = svc.session.machine
        await at_rest(svc)
        started = await client.request(r.method, r.path, json=r.body(m))
        assert started.status_code == 202, started.text
        await moving(svc, r.axes[0])
        gone = await client.delete(started.headers["location"])
        assert gone.status_code == 200, gone.text
        assert not [n for n in r.axes if m.sim_drives[n].is_moving()], r.name


@pytest.mark.parametrize("r", ROUTES, ids=ids)
async def test_a_refused_request_sends_nothing(r: Route) -> None:
    async with running() as (svc, client):
        m = svc.session.machine
        await at_rest(svc)
        before = write_frames(m)
        refused = await client.request(r.method, r.refused_path or r.path, json=r.refused)
        assert 400 <= refused.status_code < 500 or refused.status_code == 501, refused.text
        for ax in m.axes.values():
            await ax.refresh()
        assert write_frames(m) == before, (r.name, refused.text)


async def test_leaving_the_service_leaves_every_axis_at_rest() -> None:
    twins: dict[str, Any] = {}
    async with running() as (svc, client):
        m = svc.session.machine
        twins.update(m.sim_drives)
        await at_rest(svc)
        for path, body in (("/api/axes/x/move", {"target": _far(m, "x"), "speed": 30.0}),
                           ("/api/axes/y/jog", {"speed": 5.0, "ttl": 10.0}),
                           ("/api/axes/z/move", {"target": _far(m, "z"), "speed": 5.0})):
            started = await client.post(path, json=body)
            assert started.status_code in (200, 202), (path, started.text)
        for name in ("x", "y", "z"):
            await moving(svc, name)
    assert not [n for n, t in twins.items() if t.is_moving()]


# -- MQTT ----------------------------------------------------------------------------------


@pytest.fixture
def broker(tmp_path: Path) -> Any:
    require_tools()
    yield from running_broker(tmp_path)


async def test_mqtt_commands_keep_the_promises(broker: Broker) -> None:
    """A move stopped by a stop of its own axis (the twin at rest, nothing started after
    the stop frame), a jog of another axis stopped meanwhile, and refused commands (bad
    JSON, out of limits) that send nothing."""
    async with bridged(DEMO, broker.url) as (s, _), probe(broker.url) as p:
        m = s.machine
        for ax in m.axes.values():
            async for st in ax.watch():
                if not st.moving:
                    break
        before = write_frames(m)
        for raw in (b'{"target": 1000000}', b'{"target": "far"}', b'{"target": NaN}',
                    b"not json"):
            replies = await p.final(await p.send("demo", "x", "move", raw=raw))
            assert replies[-1]["status"] == "failed", (raw, replies)
        for ax in m.axes.values():
            await ax.refresh()
        assert write_frames(m) == before
        await p.send("demo", "z", "jog", {"speed": 2.0, "ttl": 10.0})
        move = await p.send("demo", "x", "move", {"target": _far(m, "x"), "speed": 30.0})
        with anyio.fail_after(20):
            while not (m.sim_drives["x"].is_moving()  # noqa: ASYNC110 (twins are polled)
                       and m.sim_drives["z"].is_moving()):
                await anyio.sleep(0.01)
        for name in ("z", "x"):
            mark = log_size(m, name)
            called = time.monotonic()
            done = await p.command("demo", name, "stop")
            assert done[-1]["status"] == "done", done
            assert not m.sim_drives[name].is_moving(), name
            frames = command_frames(m, name, mark)
            stops = [t for k, t in frames if k == "stop" and t > called]
            assert stops and not [t for k, t in frames if k == "start" and t > stops[0]]
        assert (await p.final(move))[-1]["status"] == "aborted"

