"""Bench scenario "plant": node processes on one Mosquitto broker, each with simulated
lines of its own, bridged by ``drivebus.mqtt``.

Telemetry from every node while a stream of move commands keeps every axis busy gives
the telemetry rate (state and statistics messages received per second by one
subscriber) and the command round trip (publish of a ``move`` to its ``accepted`` reply:
the axis has admitted it and its start frames are on the wire). Then, with every axis
moving, one message on ``drivebus/estop``: the fan-out time runs from that publish to the
e-stop frame on each node's wire (the simulators' wire logs, CLOCK_MONOTONIC, shared by
the processes); the figure is the last node's first e-stop frame, ``estop_delivery`` the
last node's session being asked to e-stop (broker and bridge), and ``all_stopped`` the
last e-stop frame of every axis of the plant. All processes share this host's cores
(``node_cpu_cores`` is what the nodes and the broker used): on a plant each node has a
host of its own.

Needs ``mosquitto`` (Debian's package; ``make test`` installs it); without it the
scenario gives one row saying so. ``python -m drivebus.bench.plant CONFIG URL NODE`` is
one node process (a bridge plus a responder that reports its e-stop frames).
"""

from __future__ import annotations

import contextlib
import itertools
import json
import logging
import os
import random
import resource
import shutil
import socket
import sys
import tempfile
import time
import uuid
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import aiomqtt
import anyio
import anyio.abc
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties

from drivebus.bench.common import BenchOptions, BenchResult, Scenario, percentile
from drivebus.mqtt.bridge import NO_DELAY

__all__ = ["SCENARIO", "plant"]

_REPORT = "bench/plant/report"
"""Where the bench asks the nodes for their e-stop frames (answers on ``.../<node>``)."""


def _mosquitto() -> str | None:
    exe = shutil.which("mosquitto")
    if exe is None and os.access("/usr/sbin/mosquitto", os.X_OK):
        exe = "/usr/sbin/mosquitto"
    return exe


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def node_toml(name: str, lines: int, axes: int) -> str:
    """A node's machine file: ``lines`` simulated lines at 115200 8N1 with ``axes`` NT86
    drives each, on sim:// names of its own."""
    out = [f'name = "{name}"']
    for ln in range(lines):
        out += [f"[lines.l{ln}]", f'port = "sim://bench-{name}-l{ln}"',
                'settings = "115200 8N1"']
    for ln in range(lines):
        for a in range(1, axes + 1):
            out += [
                f"[axes.l{ln}a{a}]", f'line = "l{ln}"', f"address = {a}", 'drive = "NT86"',
                "pulses_per_rev = 4000", "units_per_rev = 10.0", "speed = 100.0",
                "accel = 1000.0", "decel = 1000.0", "limits = [0.0, 1000.0]",
                "poll = { moving = 0.05, idle = 0.5 }",
                "sim = { position = 500.0, limit_negative = -10.0, limit_positive = 1010.0 }",
            ]
    return "\n".join(out) + "\n"


@contextlib.asynccontextmanager
async def _broker(directory: Path, exe: str) -> AsyncIterator[int]:
    port = _free_port()
    conf = directory / "mosquitto.conf"
    conf.write_text(f"listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\n"
                    f"set_tcp_nodelay true\nmax_queued_messages 100000\n")
    async with await anyio.open_process([exe, "-c", str(conf)]) as proc:
        try:
            with anyio.fail_after(20):
                while True:
                    try:
                        stream = await anyio.connect_tcp("127.0.0.1", port)
                        await stream.aclose()
                        break
                    except OSError:
                        await anyio.sleep(0.02)
            yield port
        finally:
            proc.kill()


class _Orchestra:
    """The bench's MQTT client: counts telemetry, keeps states, routes replies."""

    def __init__(self, client: Any) -> None:
        self.client = client
        self.reply_topic = f"bench/plant/replies/{uuid.uuid4().hex[:8]}"
        self.telemetry = 0
        self.states: dict[tuple[str, str], dict[str, Any]] = {}
        self.status: dict[str, str] = {}
        self.reports: dict[tuple[int, str], dict[str, Any]] = {}
        self.replies: dict[bytes, list[tuple[float, dict[str, Any]]]] = {}
        self._changed = anyio.Event()
        self._ids = itertools.count(1)

    async def listen(self) -> None:
        for topic in (self.reply_topic, "drivebus/+/status", "drivebus/+/axes/+/state",
                      "drivebus/+/bus/+/stats", f"{_REPORT}/+"):
            await self.client.subscribe(topic, qos=1)
        async for msg in self.client.messages:
            now = time.monotonic()
            topic = msg.topic.value
            parts = topic.split("/")
            if topic == self.reply_topic:
                corr = bytes(msg.properties.CorrelationData)
                self.replies.setdefault(corr, []).append((now, json.loads(msg.payload)))
            elif parts[-1] == "status":
                self.status[parts[1]] = bytes(msg.payload).decode()
            elif parts[-1] == "state":
                self.telemetry += 1
                self.states[(parts[1], parts[3])] = json.loads(msg.payload)
            elif parts[-1] == "stats":
                self.telemetry += 1
            elif topic.startswith(_REPORT):
                rep = json.loads(msg.payload)
                self.reports[(rep["seq"], parts[-1])] = rep
            self._changed.set()
            self._changed = anyio.Event()

    async def until(self, pred: Any, timeout: float = 120.0) -> None:
        with anyio.fail_after(timeout):
            while not pred():
                await self._changed.wait()

    async def publish(self, topic: str, body: dict[str, Any]) -> tuple[bytes, float]:
        corr = f"b{next(self._ids)}".encode()
        props = Properties(PacketTypes.PUBLISH)
        props.ResponseTopic = self.reply_topic
        props.CorrelationData = corr
        t = time.monotonic()
        await self.client.publish(topic, json.dumps(body), qos=1, properties=props)
        return corr, t

    def final(self, corr: bytes) -> dict[str, Any] | None:
        got = self.replies.get(corr, [])
        return got[-1][1] if got and got[-1][1]["status"] != "accepted" else None


async def plant(nodes: int, lines: int, axes: int, seconds: float, estops: int
                ) -> BenchResult:
    """``nodes`` node processes with ``lines`` x ``axes`` simulated NT86 axes each."""
    exe = _mosquitto()
    case = f"{nodes} nodes x {lines} lines x {axes} axes"
    if exe is None:
        return BenchResult("plant", case, {"note": "skipped: mosquitto is not installed "
                                           "(.ci/ensure-mosquitto installs it)"})
    names = [f"n{i}" for i in range(nodes)]
    axis_names = [f"l{ln}a{a}" for ln in range(lines) for a in range(1, axes + 1)]
    rtt: list[float] = []
    fan_first: list[float] = []
    fan_all: list[float] = []
    delivery: list[float] = []
    cpu0, wall0 = resource.getrusage(resource.RUSAGE_CHILDREN), time.monotonic()
    with tempfile.TemporaryDirectory(prefix="drivebus-bench-plant-") as tmp:
        d = Path(tmp)
        async with _broker(d, exe) as port, contextlib.AsyncExitStack() as stack:
            url = f"mqtt://127.0.0.1:{port}"
            procs = []
            for n in names:
                cfg = d / f"{n}.toml"
                cfg.write_text(node_toml(n, lines, axes))
                procs.append(await stack.enter_async_context(await anyio.open_process(
                    [sys.executable, "-m", "drivebus.bench.plant", str(cfg), url, n],
                    stdout=None, stderr=None)))
            client = await stack.enter_async_context(aiomqtt.Client(
                "127.0.0.1", port, protocol=aiomqtt.ProtocolVersion.V5,
                max_queued_incoming_messages=0, socket_options=[NO_DELAY]))
            client.pending_calls_threshold = 1 << 30  # one command per axis in flight
            o = _Orchestra(client)
            async with anyio.create_task_group() as tg:
                tg.start_soon(o.listen)
                await o.until(lambda: all(o.status.get(n) == "online" for n in names))
                await o.until(lambda: len(o.states) == nodes * len(axis_names))

                # telemetry and a stream of commands: every axis kept moving
                async def keep_moving(node: str, axis: str, until: float) -> None:
                    rng = random.Random(f"{node}/{axis}")
                    while time.monotonic() < until:
                        target = rng.uniform(100.0, 900.0)
                        corr, t = await o.publish(f"drivebus/{node}/axes/{axis}/cmd/move",
                                                  {"target": round(target, 2)})
                        await o.until(lambda c=corr: bool(o.replies.get(c)))
                        first = o.replies[corr][0]
                        if first[1]["status"] == "accepted":
                            rtt.append(first[0] - t)
                        await o.until(lambda c=corr: o.final(c) is not None)

                t_start, n0 = time.monotonic(), o.telemetry
                async with anyio.create_task_group() as cmds:
                    for n in names:
                        for a in axis_names:
                            cmds.start_soon(keep_moving, n, a, t_start + seconds)
                tele_rate = (o.telemetry - n0) / (time.monotonic() - t_start)

                for seq in range(estops):
                    for n in names:  # everything moving, away from where it is
                        for a in axis_names:
                            pos = o.states[(n, a)]["position"] or 500.0
                            await o.publish(f"drivebus/{n}/axes/{a}/cmd/move",
                                            {"target": 50.0 if pos > 500 else 950.0})
                    await o.until(lambda: all(s["moving"] for s in o.states.values()))
                    corr, t0 = await o.publish("drivebus/estop", {"id": f"estop{seq}"})
                    await o.until(lambda c=corr: len([r for _, r in o.replies.get(c, [])
                                                      if r["status"] != "accepted"]) == nodes)
                    await client.publish(_REPORT, json.dumps({"seq": seq, "t0": t0}), qos=1)
                    await o.until(lambda s=seq: all((s, n) in o.reports for n in names))
                    reps = [o.reports[(seq, n)] for n in names]
                    fan_first.append(max(r["first"] for r in reps) - t0)
                    fan_all.append(max(r["last"] for r in reps) - t0)
                    delivery.append(max(r["received"] for r in reps) - t0)
                    await o.until(lambda: not any(s["moving"] for s in o.states.values()))
                tg.cancel_scope.cancel()
            for p in procs:
                p.terminate()
    cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)  # the nodes and the broker, reaped
    cores = (cpu1.ru_utime + cpu1.ru_stime - cpu0.ru_utime - cpu0.ru_stime) / (
        time.monotonic() - wall0)
    ms = [x * 1e3 for x in rtt]
    f1 = [x * 1e3 for x in fan_first]
    fa = [x * 1e3 for x in fan_all]
    return BenchResult("plant", case, {
        "telemetry_msgs_s": tele_rate,
        "commands": len(ms),
        "cmd_rtt_p50_ms": percentile(ms, 0.5),
        "cmd_rtt_p99_ms": percentile(ms, 0.99),
        "estops": len(f1),
        "estop_fanout_p50_ms": percentile(f1, 0.5),
        "estop_fanout_p99_ms": percentile(f1, 0.99),
        "estop_fanout_max_ms": max(f1) if f1 else float("nan"),
        "estop_delivery_p50_ms": percentile([x * 1e3 for x in delivery], 0.5),
        "estop_delivery_max_ms": max(delivery) * 1e3 if delivery else float("nan"),
        "all_stopped_p50_ms": percentile(fa, 0.5),
        "all_stopped_max_ms": max(fa) if fa else float("nan"),
        "node_cpu_cores": cores,
        "host_cores": os.cpu_count() or 0,
    })


async def run(opts: BenchOptions) -> list[BenchResult]:
    """4 nodes x 4 lines x 8 axes, 20 e-stops (quick: 2 nodes x 1 line x 4 axes, 3)."""
    if opts.quick:
        return [await plant(2, 1, 4, opts.seconds, 3)]
    return [await plant(4, 4, 8, max(opts.seconds, 5.0), 20)]


SCENARIO = Scenario("plant", 80, run)


# -- one node process --------------------------------------------------------------------------


def _estop_frames(session: Any, t0: float) -> list[float]:
    """Start times of the first e-stop frame (NT86: register 18 = 5) to each axis after
    ``t0``, from the wire logs of the node's simulated lines."""
    from drivebus.drives.nt_family import CMD_ESTOP

    first: dict[tuple[str, int], float] = {}
    for line, wire in session.machine.wires.items():
        for f in list(wire.log):
            if (f.start >= t0 and f.direction == "request" and len(f.data) >= 6
                    and f.data[1] == 0x06 and int.from_bytes(f.data[2:4], "big") == 18
                    and int.from_bytes(f.data[4:6], "big") == CMD_ESTOP):
                first.setdefault((line, f.address), f.start)
    return sorted(first.values())


async def _node(config: str, url: str, node: str) -> None:
    from drivebus.app import MachineSession
    from drivebus.mqtt import run_bridge

    host, port = url.removeprefix("mqtt://").split(":")
    async with MachineSession.open(config) as session, anyio.create_task_group() as tg:
        tg.start_soon(lambda: run_bridge(session, url, node=node, discovery=False,
                                         stats_period=1.0))
        received: list[float] = []  # when the session was asked for each e-stop

        async def estops() -> None:
            with session.events.subscribe({"motions"}) as sub:
                async for ev in sub:
                    if ev.data.get("type") == "estop" and ev.data.get("event") == "requested":
                        received.append(time.monotonic())

        tg.start_soon(estops)
        async with aiomqtt.Client(host, int(port), protocol=aiomqtt.ProtocolVersion.V5,
                                  socket_options=[NO_DELAY]) as c:
            await c.subscribe(_REPORT, qos=1)
            async for msg in c.messages:
                req = json.loads(msg.payload)
                frames = _estop_frames(session, req["t0"])
                nan = float("nan")
                await c.publish(f"{_REPORT}/{node}", json.dumps({
                    "seq": req["seq"], "first": frames[0] if frames else nan,
                    "last": frames[-1] if frames else nan, "n": len(frames),
                    "received": next((t for t in received if t >= req["t0"]), nan),
                }), qos=1)


def _main() -> None:
    from drivebus.app.lifecycle import run_until_signalled

    config, url, node = sys.argv[1:4]
    logging.basicConfig(level=logging.ERROR)  # the bench's own table is the output

    async def go() -> int:
        await _node(config, url, node)
        return 0

    sys.exit(run_until_signalled(go, interrupt_ok=True))


if __name__ == "__main__":
    _main()
