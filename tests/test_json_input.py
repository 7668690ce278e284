"""JSON from outside is judged alike on every supported Python: an MQTT command's payload,
a WebSocket message and an HTTP body nested deeper than ``checks.MAX_JSON_DEPTH`` are an
``ArgumentError`` saying so, whatever depth the interpreter's own parser would reach (a
``RecursionError`` from about 1000 levels on 3.11, deeper and other errors on 3.12 and
3.13). The service's checks run against a real uvicorn server and a real WebSocket client.
"""

from __future__ import annotations

import json
from collections.abc import AsyncIterator

import anyio
import pytest
from websockets.asyncio.client import connect

from drivebus.checks import MAX_JSON_DEPTH, check_json_depth, load_json
from drivebus.errors import ArgumentError
from drivebus.mqtt.commands import parse_command
from service_rig import running

DEEP = [
    "[" * 5000,  # never closed
    "[" * 5000 + "]" * 5000,  # valid JSON, parsed by 3.12 and 3.13 but not by 3.11
    '{"target": 1, "x": ' + "[" * 8000 + "]" * 8000 + "}",
    '{"a": ' * (MAX_JSON_DEPTH + 1) + "1" + "}" * (MAX_JSON_DEPTH + 1),  # one level too many
]


def nested(depth: int) -> str:
    """Arrays ``depth`` deep around a 1."""
    return "[" * depth + "1" + "]" * depth


def test_the_depth_counts_arrays_and_objects_not_brackets_in_strings() -> None:
    def deep(text: str) -> bool:
        try:
            check_json_depth("body", text.encode(), max_depth=3)
        except ArgumentError:
            return True
        return False

    assert not deep('{"a": [1, {"b": 2}], "c": {}}')  # 3 levels: [{ and ]} alike
    assert deep('{"a": [1, {"b": []}], "c": {}}')
    assert not deep('{"id": "[[[[{{{{"}') and not deep('"never closed [[[[')
    assert not deep(r'{"id": "\"[[[[", "k": [[2]]}')  # an escaped quote stays in its string
    assert deep(r'["\\", [[[]]]]')  # an escaped backslash does not escape the quote after it
    assert not deep(r'["\\", [[]]]')
    assert not deep("][" * 1000) and not deep("[]" * 1000 + "[[[]]]")  # wide, not deep
    assert deep("[" * 4) and not deep("[" * 3)  # brackets left open count as levels
    assert not deep("[" * 3 + "[[[]]]")  # 3 left open around 3 closed: judged by the 3 open


def test_load_json_takes_the_depth_limit_and_refuses_one_more() -> None:
    assert load_json("payload", nested(MAX_JSON_DEPTH)) == json.loads(nested(MAX_JSON_DEPTH))
    assert load_json("payload", json.dumps({"id": "[" * 100})) == {"id": "[" * 100}
    for text in [nested(MAX_JSON_DEPTH + 1), *DEEP]:
        with pytest.raises(ArgumentError, match=r"^payload: JSON nested too deeply \(more "
                           rf"than {MAX_JSON_DEPTH} levels\)$"):
            load_json("payload", text)
    with pytest.raises(ArgumentError, match=r"^payload: not JSON \(Expecting value at line "
                       r"1 column 2\)"):
        load_json("payload", "[")
    with pytest.raises(ArgumentError, match="NaN is not a finite number"):
        load_json("payload", '{"target": NaN}')


def test_an_mqtt_command_nested_too_deeply_is_named_so() -> None:
    for text in DEEP:
        with pytest.raises(ArgumentError, match="payload: JSON nested too deeply"):
            parse_command("x", "move", text.encode())


async def test_a_websocket_message_nested_too_deeply_is_refused_and_the_connection_lives(
) -> None:
    async with running() as (svc, _), connect(
        (svc.url or "").replace("http://", "ws://") + "/api/ws"
    ) as conn:

        async def reply() -> dict[str, object]:
            with anyio.fail_after(10):  # bound: the service answers every message
                while True:
                    msg = json.loads(await conn.recv())
                    if msg["type"] in ("reply", "pong"):
                        return dict(msg)

        for text in DEEP:
            await conn.send(text)
            got = await reply()
            assert got["type"] == "reply" and got["ok"] is False, got
            error = got["error"]
            assert isinstance(error, dict) and error["error"] == "ArgumentError", got
            assert "message: JSON nested too deeply" in str(error["detail"]), got
        await conn.send(json.dumps({"ping": {}, "id": 7}))
        assert await reply() == {"type": "pong", "id": 7}  # still served


async def test_an_http_body_nested_too_deeply_is_a_422_naming_it() -> None:
    async with running() as (svc, client):
        for text in DEEP:
            r = await client.post("/api/axes/x/move", content=text.encode(),
                                  headers={"content-type": "application/json"})
            assert r.status_code == 422, r.text
            body = r.json()
            assert body["error"] == "ArgumentError", body
            assert body["detail"] == (f"body: JSON nested too deeply (more than "
                                      f"{MAX_JSON_DEPTH} levels)"), body
            assert body["instance"] == "/api/axes/x/move"
        assert not svc.session.machine.sim_drives["x"].is_moving()  # nothing was sent

        async def pieces() -> AsyncIterator[bytes]:  # a chunked body reaches the route whole
            for part in (b'{"address": 2, ', b'"register": 93, ', b'"count": 1}'):
                yield part

        twin = svc.session.machine.sim_drives["x"]
        r = await client.post("/api/lines/rs485/read", content=pieces(),
                              headers={"content-type": "application/json"})
        assert r.status_code == 200, r.text
        assert r.json()["words"] == [twin.drive_id]
        r = await client.post("/api/lines/rs485/read", content=DEEP[0].encode(),
                              headers={"content-type": "text/plain"})
        assert r.status_code == 422 and "nested" not in r.text  # not JSON: not looked into
