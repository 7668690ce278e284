"""What the MQTT tests share: a real Mosquitto broker on a loopback port, the third-party
clients (mosquitto_pub, mosquitto_sub), an aiomqtt probe that sends commands and
collects replies, machine files for more nodes, and a bridge run in a task group."""

from __future__ import annotations

import contextlib
import itertools
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import uuid
from collections.abc import AsyncIterator, Callable, Iterator
from pathlib import Path
from typing import Any

import aiomqtt
import anyio
import anyio.abc
import pytest
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties

from drivebus.app import MachineSession
from drivebus.config import parse_broker_url
from drivebus.mqtt import Bridge, BridgeOptions
from drivebus.mqtt.bridge import NO_DELAY
from ports import reserve_port

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "configs" / "demo.toml"
FINAL = ("done", "aborted", "failed")

_MISSING = ("mosquitto is not installed (make test installs it with .ci/ensure-mosquitto, "
            "which needs root and apt-get)")


def _tool(name: str) -> str | None:
    return shutil.which(name) or next(
        (p for p in (f"/usr/sbin/{name}", f"/usr/bin/{name}") if os.access(p, os.X_OK)), None)


def require_tools() -> tuple[str, str, str]:
    """Paths of mosquitto, mosquitto_pub and mosquitto_sub, or skip saying why."""
    tools = [_tool(n) for n in ("mosquitto", "mosquitto_pub", "mosquitto_sub")]
    if not all(tools):
        pytest.skip(_MISSING)
    return tools[0], tools[1], tools[2]  # type: ignore[return-value]


class Broker:
    """A Mosquitto broker of the test's own on 127.0.0.1 (persistence off), on a port it
    holds from its creation to ``close`` (tests/ports.py): the same port after a restart,
    and nobody else's meanwhile."""

    def __init__(self, directory: Path) -> None:
        self.exe, self.pub_exe, self.sub_exe = require_tools()
        self._held = reserve_port()
        self.port = int(self._held.getsockname()[1])
        self.conf = directory / "mosquitto.conf"
        self.conf.write_text(
            f"listener {self.port} 127.0.0.1\nallow_anonymous true\npersistence false\n"
            f"set_tcp_nodelay true\n"
            f"max_queued_messages 100000\n"
        )
        self.log = directory / "mosquitto.log"
        self.proc: subprocess.Popen[bytes] | None = None

    @property
    def url(self) -> str:
        return f"mqtt://127.0.0.1:{self.port}"

    def start(self) -> None:
        """Start it and return once it accepts connections."""
        with self.log.open("ab") as log:
            self.proc = subprocess.Popen([self.exe, "-c", str(self.conf)], stdout=log,
                                         stderr=subprocess.STDOUT)
        deadline = time.monotonic() + 20
        while True:
            if self.proc.poll() is not None:
                raise RuntimeError(f"mosquitto exited: {self.log.read_text()[-2000:]}")
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=1):
                    return
            except OSError:
                if time.monotonic() > deadline:
                    raise RuntimeError("mosquitto does not accept connections") from None
                time.sleep(0.02)

    def kill(self) -> None:
        """SIGKILL it (a broker that dies) and reap it."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()

    def close(self) -> None:
        """Kill it and let its port go."""
        self.kill()
        self._held.close()

    def freeze(self) -> None:
        """SIGSTOP it: a hung broker (connections stay open, nothing is answered)."""
        assert self.proc is not None
        self.proc.send_signal(signal.SIGSTOP)

    def thaw(self) -> None:
        """SIGCONT after ``freeze``."""
        assert self.proc is not None
        self.proc.send_signal(signal.SIGCONT)

    # third-party clients ---------------------------------------------------------------

    def _args(self, exe: str) -> list[str]:
        return [exe, "-h", "127.0.0.1", "-p", str(self.port), "-V", "mqttv5"]

    async def pub(self, topic: str, payload: str | bytes | None, *extra: str) -> None:
        """``mosquitto_pub`` one message (None: an empty payload)."""
        args = [*self._args(self.pub_exe), "-t", topic, "-q", "1"]
        if payload is None:
            args.append("-n")
        elif isinstance(payload, bytes):
            args.append("-s")  # the message from stdin, bytes as they are
        else:
            args += ["-m", payload]
        await anyio.run_process([*args, *extra], input=payload if isinstance(payload, bytes)
                                else None, check=True)

    async def sub(self, *topics: str, count: int) -> list[str]:
        """``mosquitto_sub -v`` until ``count`` messages arrived (retained ones included)."""
        args = [*self._args(self.sub_exe), "-v", "-C", str(count), "-W", "60"]
        for t in topics:
            args += ["-t", t]
        with anyio.fail_after(90):
            out = await anyio.run_process(args, check=True)
        return out.stdout.decode().splitlines()

    @contextlib.asynccontextmanager
    async def watch(self, *topics: str) -> AsyncIterator[LineReader]:
        """``mosquitto_sub -v`` running inside the block; its output lines."""
        args = [*self._args(self.sub_exe), "-v"]
        for t in topics:
            args += ["-t", t]
        async with await anyio.open_process(args) as proc:
            assert proc.stdout is not None
            try:
                yield LineReader(proc.stdout)
            finally:
                proc.terminate()


class LineReader:
    """Lines of a child's output as they come."""

    def __init__(self, stream: anyio.abc.ByteReceiveStream) -> None:
        self._stream = stream
        self._buf = b""
        self.lines: list[str] = []

    async def until(self, pred: Callable[[list[str]], bool], timeout: float = 60) -> list[str]:
        """Read lines until ``pred(lines so far)``; the lines."""
        with anyio.fail_after(timeout):
            while not pred(self.lines):
                self._buf += await self._stream.receive()
                *done, self._buf = self._buf.split(b"\n")
                self.lines += [d.decode() for d in done]
        return self.lines


def running_broker(directory: Path) -> Iterator[Broker]:
    """A started broker, killed when the generator closes (for fixtures)."""
    b = Broker(directory)
    try:
        b.start()
        yield b
    finally:
        b.close()


async def until(pred: Callable[[], Any], timeout: float = 60) -> Any:
    """Poll ``pred`` (state with no event to wait on) until truthy; its value."""
    with anyio.fail_after(timeout):
        while not (v := pred()):  # noqa: ASYNC110 - nothing to wait on but the value
            await anyio.sleep(0.02)
    return v


def node_config(tmp_path: Path, name: str) -> Path:
    """A copy of the demo machine named ``name`` with simulated lines of its own."""
    text = DEMO.read_text().replace('name = "demo"', f'name = "{name}"')
    text = text.replace("sim://demo-", f"sim://{name}-")
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    return path


@contextlib.asynccontextmanager
async def bridged(
    config: Path, url: str, **options: Any
) -> AsyncIterator[tuple[MachineSession, Bridge]]:
    """A session on ``config`` with its bridge running (and connected) inside the block."""
    async with MachineSession.open(config) as session, anyio.create_task_group() as tg:
        options.setdefault("node", session.name)
        bridge = Bridge(session, BridgeOptions(parse_broker_url(url), **options))
        tg.start_soon(bridge.run)
        with anyio.fail_after(30):
            await bridge.wait_connected()
        yield session, bridge
        tg.cancel_scope.cancel()


class Probe:
    """An aiomqtt client for tests: commands with MQTT 5 response topic and correlation
    data, and every message of its subscriptions kept per topic."""

    def __init__(self, client: aiomqtt.Client) -> None:
        self.client = client
        self.reply_topic = f"test/replies/{uuid.uuid4().hex[:8]}"
        self.replies: dict[bytes, list[dict[str, Any]]] = {}
        self.messages: list[tuple[str, bytes, bool]] = []
        self._changed = anyio.Event()
        self._n = itertools.count(1)

    async def run(self) -> None:
        async for msg in self.client.messages:
            topic = msg.topic.value
            corr = getattr(msg.properties, "CorrelationData", None) if msg.properties else None
            if topic == self.reply_topic and corr is not None:
                self.replies.setdefault(bytes(corr), []).append(json.loads(msg.payload))
            self.messages.append((topic, bytes(msg.payload), bool(msg.retain)))
            self._changed.set()
            self._changed = anyio.Event()

    async def wait(self, pred: Callable[[], Any], timeout: float = 60) -> Any:
        """Wait until ``pred()`` is truthy (re-checked at every message); its value."""
        with anyio.fail_after(timeout):
            while not (v := pred()):
                await self._changed.wait()
        return v

    async def send(self, node: str, axis: str, verb: str, body: Any = None, *,
                   raw: bytes | None = None) -> bytes:
        """Publish a command with a response topic; its correlation data."""
        corr = f"c{next(self._n)}".encode()
        props = Properties(PacketTypes.PUBLISH)
        props.ResponseTopic = self.reply_topic
        props.CorrelationData = corr
        payload = raw if raw is not None else json.dumps({} if body is None else body)
        await self.client.publish(f"drivebus/{node}/axes/{axis}/cmd/{verb}", payload, qos=1,
                                  properties=props)
        return corr

    async def final(self, corr: bytes) -> list[dict[str, Any]]:
        """The replies to ``corr`` once its final one came."""
        return await self.wait(lambda: (r := self.replies.get(corr)) and
                               r[-1]["status"] in FINAL and r)

    async def command(self, node: str, axis: str, verb: str, body: Any = None
                      ) -> list[dict[str, Any]]:
        """Send a command and return its replies once the final one came."""
        return await self.final(await self.send(node, axis, verb, body))

    def latest(self, topic: str) -> dict[str, Any] | None:
        """The newest JSON message seen on ``topic``."""
        for t, payload, _ in reversed(self.messages):
            if t == topic:
                return json.loads(payload)
        return None


@contextlib.asynccontextmanager
async def probe(url: str, *topics: str) -> AsyncIterator[Probe]:
    """A connected ``Probe`` subscribed to its reply topic and ``topics``."""
    port = int(url.rsplit(":", 1)[1])
    async with aiomqtt.Client("127.0.0.1", port, protocol=aiomqtt.ProtocolVersion.V5,
                              identifier=f"probe-{uuid.uuid4().hex[:8]}",
                              socket_options=[NO_DELAY]) as client:
        p = Probe(client)
        await client.subscribe(p.reply_topic, qos=1)
        for t in topics:
            await client.subscribe(t, qos=1)
        async with anyio.create_task_group() as tg:
            tg.start_soon(p.run)
            yield p
            tg.cancel_scope.cancel()


class NodeProcess:
    """``python -m drivebus.mqtt CONFIG --mqtt URL --node NAME`` as a child process."""

    def __init__(self, config: Path, url: str, node: str, *extra: str) -> None:
        self.node = node
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "drivebus.mqtt", str(config), "--mqtt", url, "--node", node,
             *extra],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
        )

    def stop(self) -> tuple[int, str, str]:
        """SIGTERM, then its exit status and output."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        out, err = self.proc.communicate(timeout=60)
        return self.proc.returncode, out, err

    def kill(self) -> None:
        """SIGKILL: a node that dies without a word."""
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.communicate(timeout=30)
