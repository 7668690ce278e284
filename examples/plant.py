"""A plant script: two drivebus nodes coordinated through an MQTT broker.

It starts nothing itself: the broker and the nodes run already, e.g.

    mosquitto -p 1883
    python -m drivebus.mqtt configs/demo.toml --mqtt mqtt://127.0.0.1:1883 --node cellA
    python -m drivebus.mqtt other.toml --mqtt mqtt://127.0.0.1:1883 --node cellB
    python examples/plant.py mqtt://127.0.0.1:1883 cellA cellB

It waits for both nodes to be online, runs a coordinated sequence across them (each step
waits for every axis of the step to report ``done``), then starts long moves everywhere
and stops the whole plant with one message on ``drivebus/estop``.
"""

from __future__ import annotations

import itertools
import json
import sys
import uuid
from typing import Any

import aiomqtt
import anyio
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties


class Plant:
    """The plant as this script sees it: commands with replies, and every axis's state."""

    def __init__(self, client: aiomqtt.Client) -> None:
        self.client = client
        self.reply_topic = f"plant/replies/{uuid.uuid4().hex[:8]}"
        self.states: dict[tuple[str, str], dict[str, Any]] = {}
        self.status: dict[str, str] = {}
        self._replies: dict[bytes, list[dict[str, Any]]] = {}
        self._changed = anyio.Event()
        self._ids = itertools.count(1)

    async def listen(self) -> None:
        """Keep the states, statuses and replies (runs in a task)."""
        await self.client.subscribe(self.reply_topic, qos=1)
        await self.client.subscribe("drivebus/+/status", qos=1)
        await self.client.subscribe("drivebus/+/axes/+/state", qos=1)
        async for msg in self.client.messages:
            parts = msg.topic.value.split("/")
            if msg.topic.value == self.reply_topic:
                corr = bytes(msg.properties.CorrelationData)  # type: ignore[union-attr]
                self._replies.setdefault(corr, []).append(json.loads(msg.payload))
            elif parts[-1] == "status":
                self.status[parts[1]] = bytes(msg.payload).decode()
            elif parts[-1] == "state":
                self.states[(parts[1], parts[3])] = json.loads(msg.payload)
            self._changed.set()
            self._changed = anyio.Event()

    async def until(self, what: str, pred: Any, timeout: float = 60.0) -> None:
        """Wait until ``pred()`` holds; ``TimeoutError`` naming ``what``."""
        try:
            with anyio.fail_after(timeout):
                while not pred():
                    await self._changed.wait()
        except TimeoutError:
            raise TimeoutError(f"gave up waiting for {what}") from None

    async def _publish(self, topic: str, body: dict[str, Any]) -> bytes:
        corr = f"plant-{next(self._ids)}".encode()
        props = Properties(PacketTypes.PUBLISH)
        props.ResponseTopic = self.reply_topic
        props.CorrelationData = corr
        await self.client.publish(topic, json.dumps(body), qos=1, properties=props)
        return corr

    async def command(self, node: str, axis: str, verb: str, **body: Any) -> dict[str, Any]:
        """Send a command and wait for its final reply (an error unless it is ``done``)."""
        corr = await self._publish(f"drivebus/{node}/axes/{axis}/cmd/{verb}", body)
        await self.until(f"{node}/{axis} {verb}", lambda: any(
            r["status"] in ("done", "aborted", "failed") for r in self._replies.get(corr, [])))
        final = self._replies[corr][-1]
        if final["status"] != "done":
            raise RuntimeError(f"{node}/{axis} {verb}: {final['status']}: {final['error']}")
        return final

    async def start(self, node: str, axis: str, verb: str, **body: Any) -> bytes:
        """Send a command and wait until it is accepted; its correlation data."""
        corr = await self._publish(f"drivebus/{node}/axes/{axis}/cmd/{verb}", body)
        await self.until(f"{node}/{axis} {verb} accepted", lambda: bool(
            self._replies.get(corr)))
        first = self._replies[corr][0]
        if first["status"] != "accepted":
            raise RuntimeError(f"{node}/{axis} {verb}: {first['status']}: {first['error']}")
        return corr

    async def estop(self, nodes: list[str]) -> list[dict[str, Any]]:
        """Plant-wide e-stop; the final reply of every node."""
        corr = await self._publish("drivebus/estop", {"id": "plant-estop"})

        def finals() -> list[dict[str, Any]]:
            return [r for r in self._replies.get(corr, []) if r["status"] != "accepted"]

        await self.until("every node's e-stop reply", lambda: {r["node"] for r in finals()}
                         >= set(nodes))
        return finals()

    async def together(self, *steps: tuple[str, str, str, dict[str, Any]]) -> None:
        """Run several commands at once; return when all are done."""
        async with anyio.create_task_group() as tg:
            for node, axis, verb, body in steps:
                tg.start_soon(lambda n=node, a=axis, v=verb, b=body: self.command(n, a, v, **b))


async def main(url: str, a: str, b: str) -> None:
    host, _, port = url.removeprefix("mqtt://").partition(":")
    async with aiomqtt.Client(host, int(port or 1883),
                              protocol=aiomqtt.ProtocolVersion.V5) as client:
        plant = Plant(client)
        async with anyio.create_task_group() as tg:
            tg.start_soon(plant.listen)
            await plant.until("both nodes online", lambda: all(
                plant.status.get(n) == "online" for n in (a, b)))
            print(f"nodes {a} and {b} online", flush=True)

            await plant.together((a, "x", "move", {"target": 50.0}),
                                 (b, "x", "move", {"target": 50.0}))
            print(f"step 1: x of {a} and {b} at 50", flush=True)
            await plant.together((a, "y", "move", {"target": 30.0}),
                                 (b, "z", "move", {"target": 20.0}),
                                 (a, "r", "move", {"target": 180.0}))
            print(f"step 2: {a} y at 30, r at 180; {b} z at 20", flush=True)
            await plant.together((a, "x", "move", {"by": -20.0}),
                                 (b, "y", "move", {"target": 15.0}))
            print(f"step 3: {a} x at 30; {b} y at 15", flush=True)

            # long moves everywhere (a few seconds each: all four are under way at once
            # however long each start takes to be accepted), then one message stops the
            # plant
            moving = [(n, "x", 390.0) for n in (a, b)] + [(n, "r", 700.0) for n in (a, b)]
            speeds = {"x": 50.0, "r": 90.0}
            for node, axis, target in moving:
                await plant.start(node, axis, "move", target=target, speed=speeds[axis])
            await plant.until("the long moves", lambda: all(
                plant.states.get((n, ax), {}).get("moving") for n, ax, _ in moving))
            replies = await plant.estop([a, b])
            halted = sum(len(r["result"]["axes"]) for r in replies)
            await plant.until("every axis at rest", lambda: all(
                not s.get("moving") for (n, _), s in plant.states.items() if n in (a, b)))
            for node, axis, _ in moving:
                print(f"{node}/{axis} stopped at {plant.states[(node, axis)]['position']:.2f}",
                      flush=True)
            tg.cancel_scope.cancel()
    print(f"plant done: e-stop halted {halted} axes on {len(replies)} nodes", flush=True)


if __name__ == "__main__":
    if len(sys.argv) != 4:
        sys.exit("usage: python examples/plant.py mqtt://HOST:PORT NODE_A NODE_B")
    anyio.run(main, *sys.argv[1:])
