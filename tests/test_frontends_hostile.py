"""The front ends for backends under hostile input, attacked from outside: the service on a
real uvicorn server (HTTP and WebSocket) and the MQTT bridge on a real Mosquitto broker,
over the demo machine's simulator. Each bad request gets its typed error naming the cause
(HTTP: a 4xx problem; WebSocket: a failed reply; MQTT: one ``failed`` reply), at once; it
sends nothing to any drive (the simulator's wire log: no write function code), moves
nothing (the twins), and the front end goes on serving.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import pytest
from websockets.asyncio.client import connect

from drivebus.motion import Machine
from mqtt_helpers import Broker, bridged, probe, require_tools, running_broker
from service_rig import DEMO, at_rest, running
from test_promises_frontends import writes
from waits import within

HUGE = sys.float_info.max
"""The largest finite float: a valid JSON number, far beyond any drive."""


async def _nothing_sent(m: Machine, before: int) -> None:
    """No write frame since ``before`` and no twin moving (each axis polled once more,
    so that a write queued by the refused request would have gone out)."""
    for ax in m.axes.values():
        await ax.refresh()
    assert writes(m) == before
    assert not [n for n, t in m.sim_drives.items() if t.is_moving()]


HUGE_HTTP: list[tuple[str, dict[str, Any], str]] = [
    ("/api/axes/x/move", {"target": 20.0, "speed": HUGE}, "speed"),
    ("/api/axes/x/move", {"target": 20.0, "speed": 1e300}, "speed"),
    ("/api/axes/x/move", {"target": 20.0, "accel": HUGE}, "accel"),
    ("/api/axes/z/move", {"by": 1.0, "decel": HUGE}, "decel"),
    ("/api/axes/y/jog", {"speed": HUGE, "ttl": 1.0}, "speed"),
    ("/api/axes/y/jog", {"speed": -HUGE, "ttl": 1.0}, "speed"),
    ("/api/axes/x/jog", {"speed": 5.0, "accel": HUGE}, "accel"),
]


@pytest.mark.timeout(120)  # the bug this guards against held the event loop for ever
async def test_numbers_far_beyond_the_drive_are_refused_over_http_at_once() -> None:
    """A finite speed or ramp near the float range: 422 LimitViolation naming the quantity,
    nothing sent. It used to hold the service's event loop for ever (the search for the
    drive's edge overflowed to infinity): no stop, no poll, no answer."""
    async with running() as (svc, client):
        m = svc.session.machine
        await at_rest(svc)
        for path, body, quantity in HUGE_HTTP:
            before = writes(m)
            with within(20, f"the answer to {path} {body}"):
                r = await client.post(path, json=body)
            assert r.status_code == 422, (path, body, r.text)
            problem = r.json()
            assert problem["title"] == "LimitViolation", problem
            assert quantity in problem["detail"] and "at most" in problem["detail"], problem
            await _nothing_sent(m, before)
        r = await client.post("/api/axes/x/move", json={"target": 20.0})
        assert r.status_code == 202, r.text  # it goes on serving


@pytest.mark.timeout(120)
async def test_numbers_far_beyond_the_drive_are_refused_over_the_websocket() -> None:
    async with running() as (svc, _):
        m = svc.session.machine
        await at_rest(svc)
        assert svc.url is not None
        async with connect(svc.url.replace("http://", "ws://") + "/api/ws") as conn:
            with within(10, "hello"):
                assert json.loads(await conn.recv())["type"] == "hello"
            before = writes(m)
            await conn.send(json.dumps({"id": 1, "jog": {"axis": "y", "speed": HUGE}}))
            with within(20, "the reply to the jog"):
                reply = json.loads(await conn.recv())
            assert reply["type"] == "reply" and reply["ok"] is False, reply
            assert reply["error"]["title"] == "LimitViolation", reply
            await _nothing_sent(m, before)


@pytest.fixture
def broker(tmp_path: Path) -> Any:
    require_tools()
    yield from running_broker(tmp_path)


@pytest.mark.timeout(120)
async def test_numbers_far_beyond_the_drive_are_refused_over_mqtt(broker: Broker) -> None:
    async with bridged(DEMO, broker.url) as (s, _), probe(broker.url) as p:
        m = s.machine
        for ax in m.axes.values():
            await ax.refresh()
        before = writes(m)
        for verb, body in (("move", {"target": 20.0, "speed": HUGE}),
                           ("jog", {"speed": -HUGE, "ttl": 1.0})):
            with within(20, f"the reply to {verb} {body}"):
                replies = await p.command("demo", "x", verb, body)
            assert replies[-1]["status"] == "failed", replies
            assert replies[-1]["error"]["type"] == "LimitViolation", replies
        await _nothing_sent(m, before)
        ok = await p.command("demo", "x", "move", {"target": 13.0})
        assert ok[-1]["status"] == "done", ok


async def test_a_group_move_with_an_axis_that_cannot_move_is_refused_before_202() -> None:
    """The OD2000 (aux) has no motion over Modbus: a group with it is a 501 NotSupported
    naming it, as a move of the axis alone is; no motion record is made and nothing is
    sent. It used to answer 202 ``running`` and fail a moment later."""
    async with running() as (svc, client):
        m = svc.session.machine
        await at_rest(svc)
        before = writes(m)
        r = await client.post("/api/machine/group-move",
                              json={"targets": {"x": 30.0, "aux": 5.0}})
        assert r.status_code == 501, r.text
        problem = r.json()
        assert problem["title"] == "NotSupported" and "OD2000" in problem["detail"], problem
        assert (await client.get("/api/motions")).json() == []
        await _nothing_sent(m, before)
