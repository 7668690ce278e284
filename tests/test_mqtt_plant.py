"""A plant of nodes on one real Mosquitto broker: the plant-wide and per-node e-stop on
two nodes (each with simulated lines of its own), the last will of a killed node process,
a node process's clean end, and examples/plant.py run against two node processes."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import anyio
import pytest
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties

from drivebus import AxisState
from drivebus.app import MachineSession
from mqtt_helpers import (
    DEMO,
    ROOT,
    Broker,
    NodeProcess,
    bridged,
    node_config,
    probe,
    running_broker,
)

pytestmark = pytest.mark.timeout(240)

MOVES = {"x": (390.0, 50.0), "y": (190.0, 20.0), "z": (95.0, 10.0), "r": (700.0, 90.0)}
"""Long moves (target, speed) on every axis that moves (aux is a monitoring-only drive)."""


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[Broker]:
    yield from running_broker(tmp_path)


async def _all_moving(s: MachineSession) -> None:
    for name in MOVES:
        async for st in s.axis(name).watch():
            if st.moving:
                break


async def test_the_plant_estop_stops_every_axis_of_two_nodes(broker: Broker, tmp_path: Path
                                                              ) -> None:
    async with bridged(node_config(tmp_path, "cellA"), broker.url) as (a, _), \
            bridged(node_config(tmp_path, "cellB"), broker.url) as (b, _), \
            probe(broker.url, "drivebus/+/replies") as p:
        sessions = {"cellA": a, "cellB": b}
        # a node's own e-stop stops that node only
        for node, s in sessions.items():
            for axis, (target, speed) in MOVES.items():
                await p.send(node, axis, "move", {"target": target, "speed": speed})
            await _all_moving(s)
        await broker.pub("drivebus/cellA/estop", json.dumps({"id": "a-only"}))
        await p.wait(lambda: [m for t, m, _ in p.messages if t == "drivebus/cellA/replies"
                              and json.loads(m)["id"] == "a-only"
                              and json.loads(m)["status"] == "done"])
        assert not any(t.is_moving() for t in a.machine.sim_drives.values())
        assert all(b.machine.sim_drives[axis].is_moving() for axis in MOVES)
        # start cellA again; then one message on drivebus/estop stops both nodes
        for axis, (target, speed) in MOVES.items():
            await p.send("cellA", axis, "move", {"target": target - 50, "speed": speed})
        await _all_moving(a)
        await broker.pub("drivebus/estop", None)  # any payload, even none
        done = await p.wait(lambda: (d := {t.split("/")[1]: json.loads(m) for t, m, _
                                           in p.messages if t.endswith("/replies")
                                           and json.loads(m)["verb"] == "estop"
                                           and json.loads(m)["status"] == "done"
                                           and json.loads(m)["scope"] == "plant"})
                            and len(d) == 2 and d)
        for node, s in sessions.items():
            assert done[node]["result"]["axes"] == {name: None for name in s.machine.axes}
            for axis, twin in s.machine.sim_drives.items():
                assert not twin.is_moving(), (node, axis)
            assert all(s.axis(n).state is AxisState.STANDSTILL for n in MOVES)
            for axis, (target, _) in MOVES.items():
                assert twin_position(s, axis) < target - 1
        # every move that was running was aborted, with the typed error
        aborted = [r for rs in p.replies.values() for r in rs if r["status"] == "aborted"]
        assert len(aborted) == 3 * len(MOVES)
        assert {r["error"]["type"] for r in aborted} == {"MotionAborted"}


def twin_position(s: MachineSession, axis: str) -> float:
    """Where the twin of ``axis`` is, in user units."""
    return s.axis(axis).units.from_pulses(s.machine.sim_drives[axis].position())


async def test_the_last_will_marks_a_killed_node_offline(broker: Broker, tmp_path: Path
                                                         ) -> None:
    node = NodeProcess(node_config(tmp_path, "doomed"), broker.url, "doomed",
                       "--no-discovery")
    try:
        async with probe(broker.url, "drivebus/doomed/status", "homeassistant/#") as p:
            await p.wait(lambda: ("drivebus/doomed/status", b"online", False) in p.messages
                         or ("drivebus/doomed/status", b"online", True) in p.messages,
                         timeout=120)
            node.kill()  # SIGKILL: no goodbye, the broker publishes the will
            await p.wait(lambda: any(t == "drivebus/doomed/status" and m == b"offline"
                                     for t, m, _ in p.messages))
            assert not any(t.startswith("homeassistant/") for t, _, _ in p.messages)
        assert await broker.sub("drivebus/doomed/status", count=1) == [
            "drivebus/doomed/status offline"]
    finally:
        node.kill()


async def test_a_node_process_says_offline_and_stops_its_axes_on_sigterm(
    broker: Broker, tmp_path: Path
) -> None:
    node = NodeProcess(node_config(tmp_path, "calm"), broker.url, "calm")
    try:
        async with probe(broker.url, "drivebus/calm/status", "drivebus/calm/axes/x/state") as p:
            await p.wait(lambda: any(m == b"online" for _, m, _ in p.messages), timeout=120)
            await p.command("calm", "x", "jog", {"speed": 20.0, "ttl": 5.0})
            move = await p.send("calm", "y", "move", {"target": 190.0, "speed": 5.0})
            await p.wait(lambda: (st := p.latest("drivebus/calm/axes/x/state"))
                         and st["moving"])
            await p.wait(lambda: (r := p.replies.get(move)) and r[-1]["status"] == "accepted")
            code, out, err = await anyio.to_thread.run_sync(node.stop)
            assert code == 0, err
            assert out.startswith("node calm: machine calm on mqtt://127.0.0.1:")
            await p.wait(lambda: any(m == b"offline" for _, m, _ in p.messages))
            # the move under way got its one final reply, before the node went offline
            # (it had only ever been accepted)
            replies = await p.final(move)
            assert [r["status"] for r in replies] == ["accepted", "aborted"], replies
            assert replies[-1]["error"]["type"] == "MotionAborted"
            said = [m for _, m, _ in p.messages]
            final = next(i for i, m in enumerate(said) if b'"aborted"' in m)
            assert final < said.index(b"offline")
    finally:
        node.kill()
    with pytest.raises(subprocess.CalledProcessError) as bad:
        await anyio.run_process([sys.executable, "-m", "drivebus.mqtt", str(DEMO), "--mqtt",
                                 "http://nowhere"], check=True)
    assert bad.value.returncode == 2
    err_lines = bad.value.stderr.decode().strip().splitlines()
    assert len(err_lines) == 1 and "mqtt://" in err_lines[0], err_lines


async def test_the_plant_example_runs_a_sequence_on_two_nodes_then_stops_the_plant(
    broker: Broker, tmp_path: Path
) -> None:
    nodes = [NodeProcess(node_config(tmp_path, n), broker.url, n) for n in ("cellA", "cellB")]
    try:
        proc = await anyio.run_process(
            [sys.executable, str(ROOT / "examples" / "plant.py"), broker.url, "cellA", "cellB"],
            check=False, cwd=ROOT)
        out = proc.stdout.decode()
        assert proc.returncode == 0, proc.stderr.decode()[-3000:]
        lines = out.strip().splitlines()
        assert lines[0] == "nodes cellA and cellB online"
        assert [ln.split(":")[0] for ln in lines[1:4]] == ["step 1", "step 2", "step 3"]
        assert sum(" stopped at " in ln for ln in lines) == 4
        assert lines[-1] == "plant done: e-stop halted 10 axes on 2 nodes", out
    finally:
        for n in nodes:
            n.stop()


async def test_an_estop_drops_the_commands_that_came_before_it(broker: Broker,
                                                               tmp_path: Path) -> None:
    """150 buffered moves of z (0.2 mm each), then an e-stop, on one connection. The e-stop is read
    ahead of every other message, and the moves still waiting in the incoming queue ran
    after it: z went on 27 mm after the e-stop said done (an outside audit). A command
    that arrived before an e-stop taken ahead of it is dropped, as a queued one is."""
    async with bridged(node_config(tmp_path, "cellE"), broker.url) as (s, _), \
            probe(broker.url, "drivebus/cellE/replies") as p:
        twin = s.machine.sim_drives["z"]
        await s.axis("z").enable()
        start = s.axis("z").position or 0.0
        sent = []
        for i in range(150):  # at QoS 0, in one burst: they wait in the node's queue
            props = Properties(PacketTypes.PUBLISH)
            props.ResponseTopic, props.CorrelationData = p.reply_topic, f"m{i}".encode()
            sent.append(props.CorrelationData)
            await p.client.publish("drivebus/cellE/axes/z/cmd/move", json.dumps(
                {"target": start + 0.2 * (i + 1), "buffer": "buffered"}), qos=0,
                properties=props)
        await p.client.publish("drivebus/cellE/estop", json.dumps({"id": "halt"}), qos=0)
        await p.wait(lambda: [m for t, m, _ in p.messages if t == "drivebus/cellE/replies"
                              and json.loads(m)["id"] == "halt"
                              and json.loads(m)["status"] in ("done", "failed")])
        at_estop = twin.position()
        assert not twin.is_moving()
        finals = [await p.final(c) for c in sent]  # every move answered, none left running
        await anyio.sleep(0.3)
        assert twin.position() == at_estop and not twin.is_moving()
        failed = [r[-1] for r in finals if r[-1]["status"] == "failed"]
        assert not failed, [f["error"] for f in failed[:3]]
