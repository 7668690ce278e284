"""WS /api/ws against a real uvicorn server with a real WebSocket client (websockets):
the fixed axis message, motion events, jogs held by a connection, auth, errors."""

from __future__ import annotations

import json
import logging
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import anyio
import anyio.lowlevel
import pytest
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidStatus

from drivebus import AxisState
from drivebus.app import Event, EventHub
from drivebus.service import Service, TokenStore
from drivebus.service.fanout import Fanout
from service_rig import TOKENS, at_rest, auth, moving, running, token_file, until
from waits import within

AXES = {"x", "y", "z", "aux", "r"}


def ws_url(svc: Service) -> str:
    assert svc.url is not None
    return svc.url.replace("http://", "ws://") + "/api/ws"


@asynccontextmanager
async def ws(svc: Service, headers: dict[str, str] | None = None
             ) -> AsyncIterator[ClientConnection]:
    async with connect(ws_url(svc), additional_headers=headers) as conn:
        yield conn


async def recv(conn: ClientConnection) -> dict[str, Any]:
    with within(10, "the next WebSocket message"):
        msg = json.loads(await conn.recv())
    assert isinstance(msg, dict)
    return msg


async def recv_until(conn: ClientConnection, match: Callable[[dict[str, Any]], bool],
                     limit: int = 5000, seconds: float = 30,
                     what: str = "a matching WebSocket message") -> dict[str, Any]:
    """Read messages until one matches (bounded in count and time)."""
    with within(seconds, what):
        for _ in range(limit):
            msg = await recv(conn)
            if match(msg):
                return msg
    raise AssertionError(f"{what}: none in {limit} messages")


async def send(conn: ClientConnection, **msg: Any) -> None:
    await conn.send(json.dumps(msg))


async def test_subscribers_get_every_axis_in_the_fixed_shape_as_it_is_polled() -> None:
    async with running() as (svc, client), ws(svc) as conn:
        hello = await recv(conn)
        assert hello["type"] == "hello" and hello["machine"] == "demo"
        assert set(hello["axes"]) == AXES and hello["client"] == "anonymous"
        await send(conn, subscribe=["axes"])
        sub = await recv(conn)
        assert sub == {"type": "subscribed", "id": None, "topics": ["axes"], "max_rate": None}
        seen: set[str] = set()
        with within(30, f"a message of every axis ({sorted(AXES)})"):
            while seen != AXES:
                msg = await recv(conn)
                assert msg["type"] == "axis", msg  # nothing but what was subscribed
                assert {"axis", "state", "position", "velocity", "alarm", "homed"} <= set(msg)
                seen.add(msg["axis"])

        # 48 mm at 20 mm/s: 2.4 s of motion, polled every 20 ms (however late the polls
        # come on a busy machine, many more than the 5 positions asked for)
        await client.post("/api/axes/x/move", json={"target": 60.0, "speed": 20.0})
        positions: list[float] = []
        with within(60, "x's move to 60, message by message, until Standstill"):
            while True:
                msg = await recv(conn)
                if msg["axis"] != "x":
                    continue
                if msg["state"] == "DiscreteMotion":
                    positions.append(msg["position"])
                elif msg["state"] == "Standstill" and positions:
                    break
        assert len(set(positions)) >= 5, positions  # live positions, as polled
        assert positions == sorted(positions)
        assert msg["position"] == pytest.approx(60.0)


async def test_a_max_rate_thins_the_states_but_the_last_one_always_comes() -> None:
    async with running() as (svc, client), ws(svc) as every, ws(svc) as thin:
        for conn, rate in ((every, None), (thin, 2)):
            await recv(conn)
            await send(conn, subscribe=["axes"], max_rate=rate)
            assert (await recv(conn))["max_rate"] == rate
        posted = anyio.current_time()
        await client.post("/api/axes/x/move", json={"target": 150.0, "speed": 100.0})

        async def count_until_done(conn: ClientConnection) -> tuple[int, dict[str, Any]]:
            n, started = 0, False
            with within(60, "x's move to 150, message by message, until Standstill"):
                while True:
                    msg = await recv(conn)
                    if msg["axis"] != "x":
                        continue
                    started = started or msg["state"] == "DiscreteMotion"
                    n += started
                    if started and msg["state"] == "Standstill":
                        return n, msg

        n_every, last_every = await count_until_done(every)
        n_thin, last_thin = await count_until_done(thin)
        watched = anyio.current_time() - posted
        assert last_thin["position"] == pytest.approx(150.0) == last_every["position"]
        # every state the thin one got was sent while the test watched, at most 2 a second
        # (a busy machine only spaces them more); the other got every state polled
        assert n_thin <= 2 * watched + 1, (n_thin, watched)
        assert n_thin <= n_every, (n_thin, n_every)
        await send(thin, subscribe=["axes"], max_rate=0)
        reply = await recv_until(thin, lambda m: m["type"] == "reply")
        assert reply["error"]["error"] == "ArgumentError" and "max_rate" in reply["error"]["detail"]


async def test_motion_events_lines_and_the_lease_come_to_subscribers() -> None:
    async with running(stats_period=0.05) as (svc, client), ws(svc) as conn:
        await recv(conn)
        await send(conn, subscribe=["motions", "lines"], id=1)
        assert (await recv(conn))["topics"] == ["lines", "motions"]
        line = await recv_until(conn, lambda m: m["type"] == "line")
        assert line["name"] in ("rs485", "eth") and "utilisation" in line
        rec = (await client.post("/api/axes/z/move", json={"target": 5.0})).json()
        events = []
        while "done" not in events:
            msg = await recv(conn)
            if msg["type"] == "motion" and msg["id"] == rec["id"]:
                events.append(msg["event"])
        assert events == ["started", "done"]
        await client.post("/api/lease", json={"ttl": 5})
        lease = await recv_until(conn, lambda m: m["type"] == "lease")
        assert lease["holder"] == "anonymous"
        await client.post("/api/estop")
        done = await recv_until(conn, lambda m: m["type"] == "estop" and m["event"] == "done")
        assert set(done["axes"]) == AXES


async def test_a_jog_over_the_websocket_is_fed_and_stops_when_feeding_stops() -> None:
    async with running() as (svc, _), ws(svc) as conn:
        z = svc.session.axis("z")
        await recv(conn)
        for n in range(3):  # start, then feed
            await send(conn, jog={"axis": "z", "speed": 5.0, "ttl": 0.3}, id=n)
            reply = await recv_until(conn, lambda m: m["type"] == "reply")
            assert reply == {"type": "reply", "op": "jog", "id": n, "ok": True}
        await moving(svc, "z")
        # the connection stays open, but nobody feeds the jog: its watchdog stops it
        await until(svc, lambda: z.state is AxisState.STANDSTILL)
        assert not svc.session.machine.sim_drives["z"].is_moving()

        await send(conn, jog={"axis": "z", "speed": -5.0, "ttl": 5.0})
        await moving(svc, "z")
        await send(conn, jog={"axis": "z", "speed": 0}, id="release")
        reply = await recv_until(conn, lambda m: m["type"] == "reply" and m["id"] == "release")
        assert reply["ok"] and not svc.session.machine.sim_drives["z"].is_moving()


@pytest.mark.parametrize("how", ["close", "abort"])
async def test_a_client_that_disconnects_mid_jog_stops_the_axis(how: str) -> None:
    async with running() as (svc, _):
        twin, z = svc.session.machine.sim_drives["z"], svc.session.axis("z")
        async with ws(svc) as conn:
            await recv(conn)
            # the longest watchdog there is: the stop below is the disconnect's doing
            await send(conn, jog={"axis": "z", "speed": 5.0, "ttl": 10.0})
            assert (await recv(conn))["ok"]
            await moving(svc, "z")
            if how == "abort":  # the connection is lost, no closing handshake
                conn.transport.abort()
        await until(svc, lambda: not twin.is_moving(), limit=8.0, what="z still jogging")
        await until(svc, lambda: z.state is AxisState.STANDSTILL)


async def test_stop_and_estop_over_the_websocket_overtake_queued_jogs() -> None:
    async with running() as (svc, client), ws(svc) as conn:
        twins = svc.session.machine.sim_drives
        await recv(conn)
        await client.post("/api/axes/x/move", json={"target": 390.0, "speed": 50.0})
        await send(conn, jog={"axis": "z", "speed": 5.0, "ttl": 5.0}, id="j")
        await moving(svc, "x")
        await moving(svc, "z")
        await send(conn, stop={"axis": "z"}, id="s")
        reply = await recv_until(conn, lambda m: m.get("id") == "s")
        assert reply["ok"] and not twins["z"].is_moving() and twins["x"].is_moving()
        # with a key of the client's own beside it: an e-stop is never refused for that
        # (it was, as one operation and an unknown key, and x ran on)
        await send(conn, estop={}, id="e", reason="operator pressed the e-stop")
        reply = await recv_until(conn, lambda m: m.get("id") == "e")
        assert reply["ok"] and reply["axes"] == {n: None for n in AXES}
        assert not any(t.is_moving() for t in twins.values())


@pytest.mark.parametrize("raw", ['{"estop": {}, "id": NaN}', '{"estop": {"why": Infinity}}',
                                 '{"estop": {}, "x": ' + "9" * 5000 + "}"])
async def test_an_estop_is_not_refused_for_a_number_json_cannot_carry_beside_it(
        raw: str) -> None:
    """A NaN, an infinity or a 5000-digit integer anywhere in an e-stop message: the
    message's numbers were checked first, the e-stop refused, and x ran on."""
    async with running() as (svc, client), ws(svc) as conn:
        twins = svc.session.machine.sim_drives
        await recv(conn)
        await client.post("/api/axes/x/move", json={"target": 390.0, "speed": 50.0})
        await moving(svc, "x")
        await conn.send(raw)
        reply = await recv_until(conn, lambda m: m["type"] == "reply")
        assert reply["ok"] and reply["op"] == "estop", reply
        assert not any(t.is_moving() for t in twins.values())


async def test_bad_messages_get_typed_error_replies_and_the_connection_lives_on() -> None:
    async with running() as (svc, _), ws(svc) as conn:
        await recv(conn)

        async def error_of(raw: str) -> dict[str, Any]:
            await conn.send(raw)
            reply = await recv_until(conn, lambda m: m["type"] == "reply")
            assert reply["ok"] is False
            return reply["error"]

        assert (await error_of("{nope"))["error"] == "ArgumentError"
        assert (await error_of("[1, 2]"))["error"] == "ArgumentError"
        assert (await error_of('{"fly": 1}'))["error"] == "ArgumentError"
        assert (await error_of('{"jog": {"axis": "z", "speed": NaN}}'))["error"] == \
            "ArgumentError"
        err = await error_of('{"subscribe": ["axes", "bogus"]}')
        assert err["error"] == "ArgumentError" and "bogus" in err["detail"]
        err = await error_of('{"jog": {"axis": "w", "speed": 1}}')
        assert err["error"] == "NotFound" and err["status"] == 404
        err = await error_of('{"jog": {"axis": "z", "speed": 1, "ttl": 60}}')
        assert err["error"] == "ArgumentError" and "ttl" in err["detail"]
        err = await error_of('{"jog": {"axis": "aux", "speed": 1}}')
        assert err["error"] == "NotSupported" and err["status"] == 501
        await send(conn, ping=1, id=9)
        assert await recv_until(conn, lambda m: m["type"] == "pong") == {"type": "pong", "id": 9}
        await at_rest(svc)


async def _refused_in_the_handshake(svc: Service, authorization: str, cause: str) -> None:
    """A handshake with this ``Authorization`` header is refused as an HTTP route refuses
    it: 401, ``WWW-Authenticate``, a problem naming ``cause``; the token not in it."""
    with pytest.raises(InvalidStatus) as refused:
        async with ws(svc, {"Authorization": authorization}):
            pass
    r = refused.value.response
    assert r.status_code == 401 and r.headers["WWW-Authenticate"] == 'Bearer realm="drivebus"'
    assert r.headers["Content-Type"] == "application/problem+json"
    body = json.loads(r.body)
    assert body["error"] == "Unauthorized" and body["status"] == 401, body
    assert cause in body["detail"] and body["instance"] == "/api/ws", body
    assert authorization.split()[-1] not in r.body.decode()


async def _told_and_closed(conn: ClientConnection, cause: str) -> None:
    """The connection gets one ``error`` message naming ``cause`` (no hello, no topic
    data), then is closed with code 4401 and ``cause`` in the reason."""
    msg = await recv(conn)
    assert msg["type"] == "error" and msg["error"]["error"] == "Unauthorized", msg
    assert cause in msg["error"]["detail"] and "0123456789" not in json.dumps(msg), msg
    with pytest.raises(ConnectionClosed) as closed:
        await recv(conn)
    assert closed.value.rcvd is not None and closed.value.rcvd.code == 4401
    assert cause in closed.value.rcvd.reason and "0123456789" not in closed.value.rcvd.reason


async def test_websocket_authentication_and_scopes(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.DEBUG)
    tokens = TokenStore.load(token_file(tmp_path))
    async with running(tokens=tokens) as (svc, client):
        await _refused_in_the_handshake(svc, "Bearer wrong-token-0123456789", "unknown token")
        await _refused_in_the_handshake(svc, "Basic d3Jvbmc6dG9rZW4=", "Bearer TOKEN")
        async with ws(svc) as conn:  # no header: the first message must authenticate
            await send(conn, subscribe=["axes"])
            await _told_and_closed(conn, 'send {"auth": "TOKEN"} first')
        async with ws(svc) as conn:  # a token sent bare (not JSON) is never quoted back
            await conn.send("wrong-token-0123456789")
            await _told_and_closed(conn, 'send {"auth": "TOKEN"} first')
        async with ws(svc) as conn:
            await send(conn, auth="wrong-token-0123456789")
            await _told_and_closed(conn, "unknown token")
        async with ws(svc) as conn:  # a browser: the token as its first message
            await send(conn, auth=TOKENS["viewer"][1])
            hello = await recv(conn)
            assert hello["client"] == "viewer" and hello["scope"] == "read"
            await send(conn, jog={"axis": "z", "speed": 5.0}, id=1)
            reply = await recv_until(conn, lambda m: m["type"] == "reply")
            assert reply["error"]["error"] == "Forbidden" and reply["error"]["status"] == 403
            await send(conn, estop={}, id=2)  # anyone may press the e-stop
            assert (await recv_until(conn, lambda m: m.get("id") == 2))["ok"]
        async with ws(svc, auth("alice")) as conn:
            hello = await recv(conn)
            assert hello["client"] == "alice" and hello["scope"] == "command"
            r = await client.post("/api/lease", json={"ttl": 30}, headers=auth("bob"))
            assert r.status_code == 200
            await send(conn, jog={"axis": "z", "speed": 5.0}, id=3)
            reply = await recv_until(conn, lambda m: m["type"] == "reply")
            assert reply["error"]["error"] == "LeaseHeld" and reply["error"]["holder"] == "bob"
            assert not svc.session.machine.sim_drives["z"].is_moving()
    said = [r.getMessage() for r in caplog.records if r.name.startswith("drivebus")]
    assert said and not [m for m in said if "0123456789" in m]  # tokens never logged


async def test_the_fan_out_feeds_every_mailbox_and_a_slow_one_keeps_only_the_latest() -> None:
    hub = EventHub()
    fanout = Fanout(hub)
    got: list[int] = []
    async with anyio.create_task_group() as tg:
        await tg.start(fanout.run)
        with fanout.attach() as fast, fanout.attach() as slow:
            fast.set_topics(["axes"])
            slow.set_topics(["axes"])

            caught_up = anyio.Event()

            async def drain() -> None:
                while not got or got[-1] != 99:
                    got.append((await fast.get()).data["i"])
                caught_up.set()

            tg.start_soon(drain)
            for i in range(100):
                hub.publish(Event("axes", "x", {"i": i}))
                for _ in range(4):  # let the fan-out and the fast reader run
                    await anyio.lowlevel.checkpoint()
            # nobody read the slow mailbox: it holds one state, the newest
            assert (await slow.get()).data["i"] == 99
            with anyio.move_on_after(0.05):
                await slow.get()
                raise AssertionError("the slow mailbox kept a backlog")
            with anyio.fail_after(5):
                await caught_up.wait()
        assert fanout.connections == 0
        tg.cancel_scope.cancel()
    assert len(got) > 50 and got == sorted(got) and got[-1] == 99  # the fast one kept up
