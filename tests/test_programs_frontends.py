"""Motion programs through the front ends: taught positions, speed override and digital
I/O over HTTP (a real uvicorn server on loopback) and MQTT (a real Mosquitto broker),
judged by the twins."""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest

from mqtt_helpers import Broker, bridged, probe, running_broker
from service_rig import DEMO, running, until
from test_service import finished, problem


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[Broker]:
    yield from running_broker(tmp_path)


def demo_with_positions(tmp_path: Path) -> Path:
    path = tmp_path / "demo.toml"
    shutil.copy(DEMO, path)
    path.write_text(path.read_text() + "\n[positions.pick]\nx = 100.0\ny = 50.0\n")
    return path


async def test_positions_override_and_io_over_http(tmp_path: Path) -> None:
    path = demo_with_positions(tmp_path)
    async with running(config=path) as (svc, client):
        twins = svc.session.machine.sim_drives
        assert (await client.get("/api/positions")).json() == {"pick": {"x": 100.0, "y": 50.0}}
        r = await client.post("/api/positions/pick/move", json={"speed": 60.0})
        assert r.status_code == 202, r.text
        assert (await finished(client, r.json()["id"]))["state"] == "done"
        assert twins["x"].position() == svc.session.axis("x").units.to_pulses(100.0)
        r = await client.post("/api/positions/drop/move")
        problem(r, 404, "NotFound")
        r = await client.post("/api/positions/pick/teach", json={"axes": ["z"]})
        assert r.status_code == 200 and r.json()["axes"] == {"x": 100.0, "y": 50.0, "z": -1.0}
        assert "[positions.pick]" in path.read_text() and "z = -1.0" in path.read_text()
        before = path.read_text()  # aux (OD2000) cannot move: a position for it is no use
        r = await client.post("/api/positions/pick/teach", json={"axes": ["z", "aux"]})
        data = problem(r, 422, "ArgumentError")
        assert "axis aux cannot be taught" in data["detail"] and "OD2000" in data["detail"]
        assert path.read_text() == before

        r = await client.put("/api/override", json={"factor": 0.5})
        assert r.status_code == 200 and r.json() == {"machine": 0.5}
        snapshot = (await client.get("/api/axes/z")).json()
        assert snapshot["override"] == 0.5 and snapshot["queued"] == 0
        problem(await client.put("/api/override", json={"factor": 3.0}), 422, "ArgumentError")
        r = await client.put("/api/axes/z/override", json={"factor": 0.5})
        assert r.json() == {"axis": "z", "own": 0.5, "applied": 0.25}
        await client.put("/api/override", json={"factor": 1.0})

        io = (await client.get("/api/axes/x/io")).json()
        assert io["inputs"]["IN6"] is True and io["outputs"] == {"OUT1": False, "OUT2": False}
        assert {"name": "OUT1", "output": True, "function": "alarm", "settable": False} \
            in io["terminals"]
        problem(await client.put("/api/axes/x/outputs/OUT1", json={"state": True}),
                501, "NotSupported")
        twins["x"].set_input(4, True)
        await until(svc, lambda: svc.session.axis("x").inputs["IN4"])
        assert (await client.get("/api/axes/x")).json()["inputs"]["IN4"] is True
        await client.post("/api/lines/rs485/write",
                          json={"address": 2, "register": 66, "values": [0]})
        r = await client.put("/api/axes/x/outputs/OUT1", json={"state": True})
        assert r.status_code == 200 and r.json()["outputs"]["OUT1"] is True


async def test_override_and_outputs_over_mqtt(broker: Broker) -> None:
    async with bridged(DEMO, broker.url, state_rate=50.0) as (s, _), \
            probe(broker.url, "drivebus/demo/axes/+/state") as p:
        z, twin = s.axis("z"), s.machine.sim_drives["z"]
        move = await p.send("demo", "z", "move", {"target": 90.0})
        async for _ in z.watch():
            if twin.is_moving():
                break
        replies = await p.command("demo", "z", "override", {"factor": 0.5})
        assert [r["status"] for r in replies] == ["accepted", "done"]
        assert z.effective_override == 0.5
        assert (await p.final(move))[-1]["status"] == "done"
        assert twin.position() == z.units.to_pulses(90.0)
        # it finished at half speed: the twin's last cruise ran at 20 mm/s
        cruise = [abs(z.units.from_pulses(seg.v0)) for seg in twin.kin.trace(0, 1e12)
                  if seg.a == 0 and seg.v0 != 0]
        assert cruise[-1] == pytest.approx(20.0)
        bad = await p.command("demo", "z", "override", {"factor": "fast"})
        assert bad[-1]["status"] == "failed" and bad[-1]["error"]["type"] == "ArgumentError"
        refused = await p.command("demo", "z", "set_output", {"output": "Y1", "state": True})
        assert refused[-1]["status"] == "failed"
        assert refused[-1]["error"]["type"] == "NotSupported"
        await s.write_registers("rs485", 2, 66, [0])
        done = await p.command("demo", "x", "set_output", {"output": "OUT1", "state": True})
        assert done[-1]["status"] == "done" and s.axis("x").outputs["OUT1"] is True
        await p.wait(lambda: (p.latest("drivebus/demo/axes/x/state") or {}).get(
            "outputs", {}).get("OUT1"))
        assert p.latest("drivebus/demo/axes/z/state")["override"] == 0.5
