"""The HTTP service against a real uvicorn server on loopback, on the demo machine:
every route, each error mapping, leases, tokens, e-stop; judged by the simulated twins."""

from __future__ import annotations

import mimetypes
from pathlib import Path
from typing import Any

import anyio
import httpx
import pytest

from drivebus import AxisState
from drivebus.app import MachineSession
from drivebus.service import TokenStore, open_service
from service_rig import DEMO, auth, moving, running, token_file, until

PROBLEM = "application/problem+json"


def problem(r: httpx.Response, status: int, error: str) -> dict[str, Any]:
    """Check ``r`` is an RFC 9457 problem of ``status`` naming ``error``."""
    assert r.status_code == status, r.text
    assert r.headers["content-type"] == PROBLEM, r.headers
    body = r.json()
    assert body["status"] == status and body["title"] == error and body["error"] == error
    assert body["type"] == f"urn:drivebus:error:{error}" and body["detail"]
    assert body["instance"] == r.request.url.path
    return body


async def finished(client: httpx.AsyncClient, motion_id: str,
                   headers: dict[str, str] | None = None) -> dict[str, Any]:
    """Poll the motion until it is no longer running (bounded)."""
    with anyio.fail_after(30):
        while True:
            r = await client.get(f"/api/motions/{motion_id}", headers=headers)
            assert r.status_code == 200, r.text
            if r.json()["state"] != "running":
                return r.json()
            await anyio.sleep(0.05)


async def test_the_machine_its_axes_lines_and_the_dashboard_are_served(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(mimetypes, "inited", False)  # (as in a new process)
    async with running() as (svc, client):
        # the media types were read off the loop, before the first file is served
        assert mimetypes.inited
        r = await client.get("/api/machine")
        assert r.status_code == 200
        m = r.json()
        assert m["name"] == "demo" and m["lease"] == {"holder": None, "remaining": None}
        lines = {ln["name"]: ln for ln in m["lines"]}
        assert lines["rs485"]["kind"] == "serial" and lines["rs485"]["settings"] == "115200 8N1"
        assert lines["eth"]["kind"] == "tcp" and 0 <= lines["rs485"]["utilisation"] <= 1
        axes = {a["name"]: a for a in m["axes"]}
        assert set(axes) == {"x", "y", "z", "aux", "r"}
        assert axes["x"]["drive"] == "NT86" and axes["x"]["state"] == "Standstill"

        x = (await client.get("/api/axes/x")).json()
        for key in ("state", "position", "velocity", "enabled", "homed", "alarm_code",
                    "alarm_text", "limit_positive", "limit_negative", "soft_limits",
                    "units_per_rev", "pulses_per_rev"):
            assert key in x
        assert x["position"] == pytest.approx(12.0) and x["soft_limits"] == [-5.0, 400.0]
        assert [a["name"] for a in (await client.get("/api/axes")).json()] == list(axes)
        line = (await client.get("/api/lines/rs485")).json()
        assert line["transactions"] > 0 and set(line["slaves"]) == {"1", "2", "3", "4"}
        me = (await client.get("/api/client", headers={"X-Drivebus-Client": "cell-7"})).json()
        assert me == {"client": "cell-7", "scope": "command", "tokens": False,
                      "machine": "demo"}

        page = await client.get("/")
        assert page.status_code == 200 and "text/html" in page.headers["content-type"]
        assert "drivebus" in page.text
        assert (await client.get("/docs")).status_code == 200
        spec = (await client.get("/openapi.json")).json()
        for path in ("/api/machine", "/api/axes/{name}/move", "/api/motions/{motion_id}",
                     "/api/estop", "/api/lease", "/api/lines/{line}/read",
                     "/api/lines/{line}/write", "/api/machine/group-move"):
            assert path in spec["paths"], path
        assert svc.session.machine.sim_drives["x"].is_moving() is False


async def test_moves_homes_and_group_moves_run_as_motions_with_ids() -> None:
    async with running() as (svc, client):
        twins, units = svc.session.machine.sim_drives, svc.session.axis("x").units
        r = await client.post("/api/axes/x/move", json={"target": 20.0},
                              headers={"X-Drivebus-Client": "mes"})
        assert r.status_code == 202, r.text
        rec = r.json()
        assert rec["state"] == "running" and rec["id"] and rec["client"] == "mes"
        assert r.headers["location"] == f"/api/motions/{rec['id']}"
        done = await finished(client, rec["id"])
        assert done["state"] == "done" and done["error"] is None
        assert twins["x"].position() == units.to_pulses(20.0)

        r = await client.post("/api/axes/x/move", json={"by": -5, "speed": 50.0})
        assert (await finished(client, r.json()["id"]))["state"] == "done"
        assert twins["x"].position() == units.to_pulses(15.0)

        r = await client.post("/api/axes/z/home")
        assert r.status_code == 202 and r.headers["location"].endswith(r.json()["id"])
        assert (await finished(client, r.json()["id"]))["state"] == "done"
        assert (await client.get("/api/axes/z")).json()["homed"] is True

        r = await client.post("/api/machine/group-move", json={"targets": {"x": 30, "y": 20}})
        assert r.status_code == 202, r.text
        done = await finished(client, r.json()["id"])
        assert done["state"] == "done" and done["result"]["duration"] > 0
        assert twins["x"].position() == units.to_pulses(30.0)
        assert twins["y"].position() == svc.session.axis("y").units.to_pulses(20.0)
        ids = [m["id"] for m in (await client.get("/api/motions")).json()]
        assert len(ids) == 4 and ids[-1] == done["id"]


async def test_a_move_takes_a_buffer_mode_and_aborting_takes_over_on_the_fly() -> None:
    async with running() as (svc, client):
        z, twin = svc.session.axis("z"), svc.session.machine.sim_drives["z"]
        # back to back, the second while the first one's start is still on the wire
        first = (await client.post("/api/axes/z/move", json={"target": 90.0})).json()
        r = await client.post("/api/axes/z/move", json={"target": 10.0})
        assert r.status_code == 202, r.text
        assert r.json()["request"] == {"target": 10.0, "buffer": "aborting"}
        assert (await finished(client, r.json()["id"]))["state"] == "done"
        first = await finished(client, first["id"])
        assert first["state"] == "aborted" and first["error"]["type"] == "MotionAborted"
        assert twin.position() == z.units.to_pulses(10.0)

        t0 = anyio.current_time()
        first = (await client.post("/api/axes/z/move", json={"target": 30.0})).json()
        r = await client.post("/api/axes/z/move", json={"target": 2.0, "buffer": "buffered"})
        assert r.status_code == 202, r.text
        second = await finished(client, r.json()["id"])
        assert second["state"] == "done" and second["result"]["runs"] == "buffered"
        assert (await finished(client, first["id"]))["state"] == "done"
        assert twin.position() == z.units.to_pulses(2.0)
        here = z.units.to_pulses(30.0)  # it went to 30 first
        assert any(abs(seg.p0 - here) < 1 for seg in twin.kin.trace(t0, anyio.current_time()))

        body = problem(await client.post("/api/axes/z/move",
                                         json={"target": 5.0, "buffer": "sideways"}),
                       422, "ArgumentError")
        assert body["errors"][0]["loc"] == ["body", "buffer"] and "aborting" in body["detail"]
        # the NT86 takes no new target while it moves: aborting is a 409 there
        x, nt86 = svc.session.axis("x"), svc.session.machine.sim_drives["x"]
        first = (await client.post("/api/axes/x/move", json={"target": 100.0})).json()
        body = problem(await client.post("/api/axes/x/move", json={"target": 50.0}),
                       409, "StateError")
        assert "under way" in body["detail"]
        assert (await finished(client, first["id"]))["state"] == "done"
        assert nt86.position() == x.units.to_pulses(100.0) and not twin.is_moving()


async def test_delete_cancels_a_motion_and_the_twin_stops_short() -> None:
    async with running() as (svc, client):
        twin, units = svc.session.machine.sim_drives["x"], svc.session.axis("x").units
        rec = (await client.post("/api/axes/x/move",
                                 json={"target": 390.0, "speed": 50.0})).json()
        await moving(svc, "x")
        r = await client.delete(f"/api/motions/{rec['id']}")
        assert r.status_code == 200, r.text
        assert r.json()["state"] == "aborted"
        assert r.json()["error"]["type"] == "MotionAborted"
        assert not twin.is_moving()  # DELETE returned with the axis at rest
        assert twin.position() < units.to_pulses(390.0)
        assert (await client.get(f"/api/motions/{rec['id']}")).json()["state"] == "aborted"


async def test_direct_commands_return_when_done() -> None:
    async with running() as (svc, client):
        twin = svc.session.machine.sim_drives["x"]
        await client.post("/api/axes/x/move", json={"target": 390.0, "speed": 50.0})
        await moving(svc, "x")
        r = await client.post("/api/axes/x/stop")
        assert r.status_code == 200 and r.json()["state"] == "Standstill"
        assert not twin.is_moving()
        await client.post("/api/axes/x/move", json={"target": 10.0, "speed": 50.0})
        await moving(svc, "x")
        r = await client.post("/api/axes/x/halt")
        assert r.status_code == 200 and not twin.is_moving()

        problem(await client.post("/api/axes/x/disable"), 501, "NotSupported")  # NT86
        r = await client.post("/api/axes/z/disable")
        assert r.status_code == 200 and r.json()["state"] == "Disabled"
        assert r.json()["enabled"] is False
        problem(await client.post("/api/axes/z/move", json={"target": 5.0}), 409, "StateError")
        r = await client.post("/api/axes/z/enable")
        assert r.status_code == 200 and r.json()["state"] == "Standstill"
        r = await client.post("/api/axes/z/reset")
        assert r.status_code == 200 and r.json()["state"] == "Standstill"
        r = await client.post("/api/axes/x/stop", json={"decel": 100.0})
        assert r.status_code == 200  # a stop at rest is a no-op


async def test_a_jog_over_http_stops_when_its_client_stops_feeding_it() -> None:
    async with running() as (svc, client):
        z = svc.session.machine.sim_drives["z"]
        r = await client.post("/api/axes/z/jog", json={"speed": 5.0, "ttl": 0.3})
        assert r.status_code == 200 and r.json() == {"axis": "z", "speed": 5.0, "ttl": 0.3}
        await moving(svc, "z")
        # nobody feeds it: the watchdog stops it
        await until(svc, lambda: svc.session.axis("z").state is AxisState.STANDSTILL)
        assert not z.is_moving()
        await client.post("/api/axes/z/jog", json={"speed": -5.0, "ttl": 5.0})
        await moving(svc, "z")
        r = await client.post("/api/axes/z/jog", json={"speed": 0})
        assert r.status_code == 200 and not z.is_moving()  # speed 0 stops, at rest
        problem(await client.post("/api/axes/z/jog", json={"speed": 5.0, "ttl": 60}),
                422, "ArgumentError")


async def test_each_error_is_a_typed_problem() -> None:
    async with running() as (svc, client):
        body = problem(await client.get("/api/axes/w"), 404, "NotFound")
        assert "x, y, z, aux, r" in body["detail"]
        problem(await client.post("/api/axes/w/move", json={"target": 1.0}), 404, "NotFound")
        problem(await client.get("/api/motions/m999"), 404, "NotFound")
        problem(await client.delete("/api/motions/m999"), 404, "NotFound")
        problem(await client.get("/api/lines/can"), 404, "NotFound")
        problem(await client.get("/api/nothing-here"), 404, "NotFound")
        # an axis named in a body is looked up as in a path (they were 422 ConfigError)
        problem(await client.post("/api/recordings", json={"axes": ["w"]}), 404, "NotFound")
        problem(await client.post("/api/positions/p1/teach", json={"axes": ["x", "w"]}),
                404, "NotFound")
        problem(await client.put("/api/estop"), 405, "MethodNotAllowed")

        body = problem(await client.post("/api/axes/x/move", json={"target": 1000.0}),
                       422, "LimitViolation")
        assert "soft limits" in body["detail"]
        body = problem(await client.post("/api/axes/x/move", json={"target": "1"}),
                       422, "ArgumentError")
        assert body["errors"][0]["loc"] == ["body", "target"]
        problem(await client.post("/api/axes/x/move", json={"target": 1, "by": 2}),
                422, "ArgumentError")
        problem(await client.post("/api/axes/x/move", json={"target": 1, "sped": 2}),
                422, "ArgumentError")
        problem(await client.post("/api/axes/x/move", json={"target": 1, "speed": -2}),
                422, "ArgumentError")
        problem(await client.post("/api/axes/x/move", content=b'{"target": NaN}',
                                  headers={"content-type": "application/json"}),
                422, "ArgumentError")
        problem(await client.post("/api/axes/x/move", content=b"{not json",
                                  headers={"content-type": "application/json"}),
                422, "ArgumentError")
        problem(await client.post("/api/machine/group-move", json={"targets": {}}),
                422, "ArgumentError")
        problem(await client.post("/api/machine/group-move", json={"targets": {"q": 1}}),
                404, "NotFound")

        body = problem(await client.post("/api/axes/aux/move", json={"target": 1.0}),
                       501, "NotSupported")
        assert "OD2000" in body["detail"] or "aux" in body["detail"]

        await client.post("/api/axes/z/disable")
        problem(await client.post("/api/axes/z/home"), 409, "StateError")
        await client.post("/api/axes/z/enable")

        y = svc.session.machine.sim_drives["y"]
        y.power_loss()
        await until(svc, lambda: svc.session.axis("y").state is AxisState.OFFLINE)
        problem(await client.post("/api/axes/y/stop"), 503, "DriveOffline")
        assert (await client.get("/api/axes/y")).json()["state"] == "Offline"
        y.power_restore()
        await until(svc, lambda: svc.session.axis("y").state is not AxisState.OFFLINE)
        assert not any(t.is_moving() for t in svc.session.machine.sim_drives.values())


async def test_raw_registers_through_the_service() -> None:
    async with running() as (svc, client):
        twin = svc.session.machine.sim_drives["x"]  # NT86 at address 2
        r = await client.post("/api/lines/rs485/read", json={"address": 2, "register": 93})
        assert r.status_code == 200, r.text
        assert r.json() == {"line": "rs485", "address": 2, "register": 93,
                            "words": [twin.drive_id]}
        r = await client.post("/api/lines/rs485/write",
                              json={"address": 2, "register": 272, "values": [7]})
        assert r.status_code == 200 and r.json()["written"] == 1
        assert twin.params[272] == 7
        r = await client.post("/api/lines/rs485/read",
                              json={"address": 2, "register": 272, "count": 1, "input": False})
        assert r.json()["words"] == [7]
        r = await client.post("/api/lines/eth/read", json={"address": 1, "register": 0,
                                                           "count": 4})
        assert r.status_code == 200 and len(r.json()["words"]) == 4

        body = problem(await client.post("/api/lines/rs485/write",
                                         json={"address": 2, "register": 272,
                                               "values": [5000]}),
                       502, "ModbusException")
        assert body["code"] == 3 and body["slave"] == 2
        assert twin.params[272] == 7
        problem(await client.post("/api/lines/can/read", json={"address": 2, "register": 0}),
                404, "NotFound")
        body = problem(await client.post("/api/lines/rs485/read",  # nobody at address 9
                                         json={"address": 9, "register": 0}),
                       504, "ResponseTimeout")
        assert body["slave"] == 9
        for bad in ({"address": 0, "register": 0}, {"address": 2, "register": 70000},
                    {"address": 2, "register": 0, "count": 126},
                    {"address": 2, "register": 0, "count": 1.5},
                    {"address": 2}, {"address": 2, "register": 0, "extra": 1}):
            problem(await client.post("/api/lines/rs485/read", json=bad), 422, "ArgumentError")
        for bad in ({"address": 2, "register": 0, "values": []},
                    {"address": 2, "register": 0, "values": [65536]},
                    {"address": 2, "register": 0, "values": [-1]},
                    {"address": 2, "register": 65535, "values": [1, 2]}):
            problem(await client.post("/api/lines/rs485/write", json=bad),
                    422, "ArgumentError")


async def test_tokens_scopes_and_the_lease(tmp_path: Path) -> None:
    tokens = TokenStore.load(token_file(tmp_path))
    async with running(tokens=tokens) as (svc, client):
        twins = svc.session.machine.sim_drives
        problem(await client.get("/api/machine"), 401, "Unauthorized")
        r = await client.get("/api/machine", headers={"Authorization": "Bearer wrong-token"})
        assert problem(r, 401, "Unauthorized") and r.headers["www-authenticate"].startswith(
            "Bearer")
        problem(await client.get("/api/machine", headers={"Authorization": "Basic eDp5"}),
                401, "Unauthorized")
        assert (await client.get("/api/machine", headers=auth("viewer"))).status_code == 200
        me = (await client.get("/api/client", headers=auth("viewer"))).json()
        assert me["client"] == "viewer" and me["scope"] == "read" and me["tokens"] is True
        body = problem(await client.post("/api/axes/x/move", json={"target": 5.0},
                                         headers=auth("viewer")), 403, "Forbidden")
        assert "read-only" in body["detail"]
        problem(await client.post("/api/lease", headers=auth("viewer")), 403, "Forbidden")
        problem(await client.post("/api/lines/rs485/write", headers=auth("viewer"),
                                  json={"address": 2, "register": 272, "values": [1]}),
                403, "Forbidden")

        r = await client.post("/api/lease", json={"ttl": 60}, headers=auth("alice"))
        assert r.status_code == 200 and r.json()["holder"] == "alice"
        body = problem(await client.post("/api/lease", headers=auth("bob")), 409, "LeaseHeld")
        assert body["holder"] == "alice"
        body = problem(await client.post("/api/axes/x/move", json={"target": 5.0},
                                         headers=auth("bob")), 409, "LeaseHeld")
        assert body["holder"] == "alice" and "alice" in body["detail"]
        rec = (await client.post("/api/axes/x/move", json={"target": 390.0, "speed": 50.0},
                                 headers=auth("alice"))).json()
        await client.post("/api/axes/z/jog", json={"speed": 5.0, "ttl": 10.0},
                          headers=auth("alice"))
        await moving(svc, "x")
        await moving(svc, "z")
        problem(await client.post("/api/axes/x/stop", headers=auth("bob")), 409, "LeaseHeld")
        problem(await client.delete(f"/api/motions/{rec['id']}", headers=auth("bob")),
                409, "LeaseHeld")
        assert twins["x"].is_moving()

        r = await client.post("/api/estop", headers=auth("bob"))  # the lease does not matter
        assert r.status_code == 200, r.text
        assert r.json()["axes"] == {n: None for n in twins}
        assert not any(t.is_moving() for t in twins.values())
        assert (await finished(client, rec["id"], auth("viewer")))["state"] == "aborted"
        assert (await client.post("/api/estop", headers=auth("viewer"))).status_code == 200

        r = await client.delete("/api/lease", headers=auth("alice"))
        assert r.json() == {"holder": None, "remaining": None}
        r = await client.post("/api/lease", json={"ttl": 0.2}, headers=auth("bob"))
        assert r.json()["holder"] == "bob"
        with svc.session.events.subscribe({"axes"}) as polls, anyio.fail_after(10):
            while (await client.get("/api/lease", headers=auth("alice"))).json()["holder"]:
                await polls.get()  # leases expire
        r = await client.post("/api/axes/x/move", json={"target": 20.0}, headers=auth("alice"))
        assert r.status_code == 202 and r.json()["client"] == "alice"
        await finished(client, r.json()["id"], auth("alice"))


async def test_estop_gets_through_while_other_requests_are_in_flight() -> None:
    async with running() as (svc, client):
        twins, x = svc.session.machine.sim_drives, svc.session.axis("x")
        await client.post("/api/axes/x/move", json={"target": 390.0, "speed": 100.0})
        await client.post("/api/axes/r/move", json={"target": 700.0, "speed": 100.0})
        await until(svc, lambda: (x.velocity or 0.0) >= 99.0)
        await moving(svc, "r")
        slow_stop: list[httpx.Response] = []
        async with anyio.create_task_group() as tg:

            async def stop_gently() -> None:  # in flight for a second: a soft ramp
                slow_stop.append(await client.post("/api/axes/x/stop", json={"decel": 100.0}))

            tg.start_soon(stop_gently)
            await until(svc, lambda: x.state is AxisState.STOPPING)
            t0 = anyio.current_time()
            r = await client.post("/api/estop")
            assert r.status_code == 200 and all(v is None for v in r.json()["axes"].values())
            assert not any(t.is_moving() for t in twins.values())
        assert slow_stop[0].status_code == 200, slow_stop[0].text
        # 100 mm/s at 100 mm/s² takes 50 mm to stop: the e-stop cut that ramp short. Judged
        # by the twin's own ramps, not by the distance from when the test asked (on a busy
        # machine the e-stop's request takes a while to come through, the soft ramp going on
        # meanwhile): x ramped down at 100 mm/s², then came to rest on a steeper ramp (the
        # e-stop's), short of where the soft ramp would have ended.
        per_mm = x.config.pulses_per_rev / x.config.units_per_rev
        ramps = [sg for sg in twins["x"].kin.trace(t0, anyio.current_time()) if sg.a < 0]
        soft = next(sg for sg in ramps if sg.a == pytest.approx(-100.0 * per_mm))
        last = ramps[-1]
        assert last.a < 2 * soft.a, ramps  # the e-stop's ramp, at least twice as steep
        soft_end = soft.p0 + soft.v0 ** 2 / (2 * -soft.a)
        assert last.p0 + last.v0 ** 2 / (2 * -last.a) < soft_end - 1.0 * per_mm


async def test_sibling_tasks_share_the_session_and_http_can_be_left_out() -> None:
    seen: list[str] = []

    async def bridge(session: MachineSession) -> None:  # e.g. a plant bridge
        seen.append(session.name)
        try:
            await anyio.sleep_forever()
        finally:
            seen.append("cancelled")

    async with open_service(DEMO, http=False, extra=[bridge]) as svc:
        assert svc.url is None
        await until(svc, lambda: seen == ["demo"])
        await svc.session.start_move("x", target=300.0, speed=50.0)
        await moving(svc, "x")
    assert seen == ["demo", "cancelled"]
    assert svc.stopped == {"x": None} and svc.at_rest  # leaving it stopped x
    assert not svc.session.machine.sim_drives["x"].is_moving()
