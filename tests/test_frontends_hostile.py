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

import anyio
import pytest
from websockets.asyncio.client import connect

from drivebus.motion import Machine
from drivebus.service.bodies import MAX_BODY
from mqtt_helpers import Broker, bridged, probe, require_tools, running_broker
from service_rig import DEMO, at_rest, moving, running
from waits import within
from wirelog import write_frames

HUGE = sys.float_info.max
"""The largest finite float: a valid JSON number, far beyond any drive."""


async def _nothing_sent(m: Machine, before: int) -> None:
    """No write frame since ``before`` and no twin moving (each axis polled once more,
    so that a write queued by the refused request would have gone out)."""
    for ax in m.axes.values():
        await ax.refresh()
    assert write_frames(m) == before
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
            before = write_frames(m)
            with within(20, f"the answer to {path} {body}"):
                r = await client.post(path, json=body)
            assert r.status_code == 422, (path, body, r.text)
            problem = r.json()
            assert problem["title"] == "LimitViolation", problem
            assert quantity in problem["detail"] and "at most" in problem["detail"], problem
            await _nothing_sent(m, before)
        # integers beyond any float and beyond Python's 4300 digits (a 400 "error parsing
        # the body" named no cause): a 422 that says so
        for digits in (400, 4400):
            before = write_frames(m)
            r = await client.post("/api/axes/x/move", content=b'{"target": 1' + b"0" * digits
                                  + b"}", headers={"content-type": "application/json"})
            assert r.status_code == 422, r.text[:300]
            assert f"{digits + 1} digits" in r.json()["detail"], r.text[:300]
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
            before = write_frames(m)
            await conn.send(json.dumps({"id": 1, "jog": {"axis": "y", "speed": HUGE}}))
            with within(20, "the reply to the jog"):
                reply = json.loads(await conn.recv())
            assert reply["type"] == "reply" and reply["ok"] is False, reply
            assert reply["error"]["title"] == "LimitViolation", reply
            # integers beyond any float, and beyond what Python converts (4300 digits):
            # refused as such, and the connection goes on (it used to be dropped)
            for digits in (400, 4400):
                await conn.send('{"id": 2, "jog": {"axis": "y", "speed": 1' + "0" * digits
                                + ', "ttl": 1.0}}')
                with within(20, f"the reply to a speed of {digits + 1} digits"):
                    reply = json.loads(await conn.recv())
                assert reply["type"] == "reply" and reply["ok"] is False, reply
                assert reply["error"]["title"] == "ArgumentError", reply
                assert f"{digits + 1} digits" in reply["error"]["detail"], reply
            await _nothing_sent(m, before)
            await conn.send(json.dumps({"id": 3, "ping": {}}))
            with within(10, "the pong after them"):
                assert json.loads(await conn.recv())["type"] == "pong"


@pytest.fixture
def broker(tmp_path: Path) -> Any:
    require_tools()
    yield from running_broker(tmp_path)


@pytest.mark.timeout(120)
async def test_numbers_beyond_the_drive_are_refused_over_mqtt(broker: Broker) -> None:
    """Speeds near the float range, an integer beyond any float, and a stop at a
    deceleration the drive's stop cannot take (it was ``accepted``, then ``failed``):
    each only ``failed``, nothing sent."""
    async with bridged(DEMO, broker.url) as (s, _), probe(broker.url) as p:
        m = s.machine
        for ax in m.axes.values():
            await ax.refresh()
        before = write_frames(m)
        for verb, body, error in (("move", {"target": 20.0, "speed": HUGE}, "LimitViolation"),
                                  ("jog", {"speed": -HUGE, "ttl": 1.0}, "LimitViolation"),
                                  ("move", {"target": 10**400}, "ArgumentError"),
                                  ("stop", {"decel": 50.0}, "LimitViolation")):
            with within(20, f"the reply to {verb} {body}"):
                replies = await p.command("demo", "x", verb, body)
            assert [r["status"] for r in replies] == ["failed"], replies  # no "accepted"
            assert replies[0]["error"]["type"] == error, replies
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
        before = write_frames(m)
        r = await client.post("/api/machine/group-move",
                              json={"targets": {"x": 30.0, "aux": 5.0}})
        assert r.status_code == 501, r.text
        problem = r.json()
        assert problem["title"] == "NotSupported" and "OD2000" in problem["detail"], problem
        assert (await client.get("/api/motions")).json() == []
        await _nothing_sent(m, before)


JSON = {"content-type": "application/json"}


async def test_a_body_beyond_the_limit_is_a_413_and_never_parsed() -> None:
    """A body over ``MAX_BODY`` (by its Content-Length, or chunked without one) is refused
    with 413 ContentTooLarge naming the limit, before FastAPI parses it: parsing 15 MB held
    the event loop for a second (every stop and poll behind it; the loop-step guard of
    tests/conftest.py fails a test whose step takes more than 40 ms)."""
    async with running() as (svc, client):
        m = svc.session.machine
        await at_rest(svc)
        before = write_frames(m)
        padded = json.dumps({"target": 20.0, "pad": "x" * MAX_BODY}).encode()
        r = await client.post("/api/axes/x/move", content=padded, headers=JSON)
        assert r.status_code == 413, r.text
        problem = r.json()
        assert problem["title"] == "ContentTooLarge", problem
        assert f"at most {MAX_BODY}" in problem["detail"], problem
        assert r.headers["content-type"] == "application/problem+json"

        # chunked, no Content-Length, from a raw socket: it sends a little more than the
        # limit and no end, then reads the answer
        assert svc.url is not None
        host, port = svc.url.removeprefix("http://").split(":")
        piece = b"[" + b"0," * 8191 + b"0]"
        async with await anyio.connect_tcp(host, int(port)) as sock:
            await sock.send(b"POST /api/machine/group-move HTTP/1.1\r\nHost: x\r\n"
                            b"Content-Type: application/json\r\n"
                            b"Transfer-Encoding: chunked\r\n\r\n")
            for _ in range(MAX_BODY // len(piece) + 1):
                await sock.send(b"%x\r\n%s\r\n" % (len(piece), piece))
            answer = b""
            with within(20, "the answer to a chunked body beyond the limit"):
                while b"}" not in answer:
                    answer += await sock.receive()
        head, _, rest = answer.partition(b"\r\n\r\n")
        assert head.startswith(b"HTTP/1.1 413"), answer[:300]
        assert b"ContentTooLarge" in rest and f"more than {MAX_BODY}".encode() in rest, rest
        await _nothing_sent(m, before)
        r = await client.post("/api/axes/x/move", json={"target": 20.0})
        assert r.status_code == 202, r.text  # it goes on serving


@pytest.mark.parametrize("path", ["/api/estop", "/api/axes/y/halt"])
async def test_the_estop_and_halt_are_never_refused_for_their_body(path: str) -> None:
    """They take no body: one nested too deeply, too large or not JSON does not keep them
    from stopping the axis (the depth check refused an e-stop with 422, the axis jogging
    on)."""
    bodies = [b"[" * 40 + b"]" * 40, b"[" + b"0," * MAX_BODY + b"0]", b"not json"]
    async with running() as (svc, client):
        await at_rest(svc)
        for body in bodies:
            r = await client.post("/api/axes/y/jog", json={"speed": 5.0, "ttl": 10.0})
            assert r.status_code == 200, r.text
            await moving(svc, "y")
            r = await client.post(path, content=body, headers=JSON)
            assert r.status_code == 200, (body[:20], r.text)
            assert not svc.session.machine.sim_drives["y"].is_moving()


@pytest.mark.parametrize("kind", [None, "text/plain", "application/x-www-form-urlencoded"])
async def test_a_json_body_sent_as_another_content_type_is_named_so(kind: str | None) -> None:
    """``curl -d '{"target": 20}'`` sends a form content type, a bare client none: FastAPI
    does not parse such a body as JSON. The 422 says to send Content-Type:
    application/json and what came (it said "Input should be a valid dictionary or object
    to extract fields from"), and nothing is sent."""
    async with running() as (svc, client):
        m = svc.session.machine
        await at_rest(svc)
        before = write_frames(m)
        headers = {} if kind is None else {"content-type": kind}
        r = await client.post("/api/axes/x/move", content=b'{"target": 20.0}', headers=headers)
        if r.status_code == 202:  # a FastAPI that parses a body without a type as JSON
            assert kind is None, r.text
            return
        assert r.status_code == 422, r.text
        problem = r.json()
        assert problem["title"] == "ArgumentError", problem
        assert "Content-Type: application/json" in problem["detail"], problem
        assert repr(kind or "") in problem["detail"] or "no Content-Type" in problem["detail"]
        await _nothing_sent(m, before)


async def test_a_position_name_with_a_trailing_newline_is_refused(tmp_path: Path) -> None:
    """``POST /api/positions/home%0A/teach``: the name pattern's ``$`` matched before a
    final newline, so ``[positions."home\\n"]`` was written into the machine file. It is a
    422 naming the name, and the file is left as it was."""
    machine = tmp_path / "m.toml"
    machine.write_text(DEMO.read_text())
    async with running(config=machine) as (svc, client):
        await at_rest(svc)
        for name in ("home%0A", "home%0D%0A", "%0Ahome"):
            r = await client.post(f"/api/positions/{name}/teach", json={"axes": ["x"]})
            assert r.status_code == 422, (name, r.text)
            assert r.json()["title"] == "ArgumentError" and "position name" in r.text
        assert (await client.get("/api/positions")).json() == {}
    assert machine.read_text() == DEMO.read_text()


async def test_a_client_name_with_a_trailing_newline_is_not_taken() -> None:
    """Without tokens a WebSocket client may name itself (``?client=``): a name with a
    final newline passed the name's pattern and went into lease holders, motion records
    and log lines as it came. It is not taken: the client is ``anonymous``."""
    async with running() as (svc, _):
        assert svc.url is not None
        url = svc.url.replace("http://", "ws://") + "/api/ws"
        for name, seen in (("alice", "alice"), ("alice%0A", "anonymous")):
            async with connect(f"{url}?client={name}") as conn:
                with within(10, "hello"):
                    hello = json.loads(await conn.recv())
                assert hello["type"] == "hello" and hello["client"] == seen, hello


@pytest.mark.parametrize("verb", ["home", "enable", "disable", "reset"])
async def test_a_command_without_parameters_refuses_a_body_that_gives_some(verb: str) -> None:
    """Home, enable, disable and reset take no parameters: a body that gives some (a
    homing method, speeds) is a 422 naming the key, not ignored; home used to answer 202
    and home with the machine file's method."""
    async with running() as (svc, client):
        m = svc.session.machine
        await at_rest(svc)
        before = write_frames(m)
        for body in ({"method": "limit_negative", "speed": 1}, [1, 2]):
            r = await client.post(f"/api/axes/x/{verb}", json=body)
            assert r.status_code == 422, (verb, body, r.text)
            assert "method" in r.text or "valid dictionary" in r.text, r.text
        r = await client.post(f"/api/axes/x/{verb}", content=b"not json",
                              headers={"content-type": "application/json"})
        assert r.status_code == 422, r.text
        await _nothing_sent(m, before)
        r = await client.post(f"/api/axes/x/{verb}", json={})  # an empty one is no parameter
        assert r.status_code in (200, 202, 501), r.text  # (x's NT86 cannot disable: 501)


async def test_a_stop_at_a_deceleration_the_drive_cannot_take_leaves_the_motion_alone() -> None:
    """``stop(decel=...)`` beyond the range of the drive's stop register: a 422 naming the
    axis and the deceleration in its units, nothing sent, and the jog under way goes on
    under the axis's watch (it used to be aborted first, the motor left running with the
    axis Stopping and no stop sent); a stop without decel then stops it."""
    async with running() as (svc, client):
        m = svc.session.machine
        await at_rest(svc)
        twin = m.sim_drives["x"]
        r = await client.post("/api/axes/x/jog", json={"speed": 20.0 if twin.position() < 0
                                                        else -20.0, "ttl": 5.0})
        assert r.status_code == 200, r.text
        await moving(svc, "x")
        before = write_frames(m)
        for decel in (50.0, 1e7):
            r = await client.post("/api/axes/x/stop", json={"decel": decel})
            assert r.status_code == 422, r.text
            detail = r.json()["detail"]
            assert detail.startswith(f"axis x: stop(decel={decel:g}) refused") and \
                "mm/s²" in detail, detail
        assert write_frames(m) == before and twin.is_moving()
        assert m.axes["x"].state.name == "CONTINUOUS_MOTION"
        r = await client.post("/api/axes/x/stop")
        assert r.status_code == 200 and not twin.is_moving(), r.text

