"""The bridge: one ``MachineSession`` on an MQTT broker, as a node of a plant.

Who owns what: ``Bridge.run`` owns one task group with the event collector (axis state
and line statistics into the outbox), one command worker per axis, the connection loop,
and the tasks of commands in progress. The connection loop owns the broker connection
and, while it is up, its receiver and publisher. Nothing the session does waits for the
broker: the collector only fills latest-wins buffers (``Outbox``), and commands run in
tasks of the bridge, never in the receiver.

Commands of one axis run in arrival order, one at a time (a move is taken up once the
axis has accepted the previous one); ``stop`` and ``halt`` never queue: they drop the
axis's queued commands (each gets ``aborted``) and go straight to the axis, which
preempts what it is doing. An e-stop (``drivebus/<node>/estop`` or ``drivebus/estop``,
any payload) is read ahead of every other message, drops every queued command and halts
every axis at once.

Replies: every command gets exactly one final reply, ``done``, ``aborted`` or ``failed``
(with the typed error's name and text); one that was taken up gets ``accepted`` before it
(a move or homing once the axis admitted it: its motion id comes with it; a jog once
the axis took it; a stop or halt at once; the others once they ran, or failed on the
way). A command that was refused (nothing sent) or could not be parsed gets only
``failed``. Replies go to the MQTT 5
response topic with the correlation data when the command has them, else to
``drivebus/<node>/replies``; the command's ``id`` is echoed either way.

Broker loss: jogs started over MQTT stop (and queued jogs are dropped); discrete moves
go on to their end and their replies wait in the outbox (bounded); the bridge reconnects
with exponential backoff and republishes ``online``, discovery and every axis's state.
"""

from __future__ import annotations

import asyncio
import collections
import itertools
import json
import logging
import random
import secrets
import socket
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any

import aiomqtt
import anyio
import anyio.abc
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties
from paho.mqtt.subscribeoptions import SubscribeOptions

from drivebus import checks
from drivebus.app import MachineSession, MotionRecord, error_record
from drivebus.config import BrokerUrl, MachineConfig, parse_broker_url
from drivebus.errors import (
    ArgumentError,
    ConfigError,
    DrivebusError,
    LeaseHeld,
    LimitViolation,
    MotionAborted,
    NotFound,
    NotSupported,
    StateError,
)
from drivebus.motion import GroupMotionError
from drivebus.mqtt.commands import Command, Id, parse_command, peek_id
from drivebus.mqtt.discovery import discovery_messages
from drivebus.mqtt.outbox import Outbox, Outgoing
from drivebus.mqtt.topics import PLANT_ESTOP, Topics, check_node

REFUSALS = (ArgumentError, StateError, NotSupported, LimitViolation, NotFound, LeaseHeld)
"""A command refused before it sent anything (promise 3): its only reply is ``failed``."""

__all__ = ["NO_DELAY", "Bridge", "BridgeOptions", "run_bridge", "run_configured_bridge"]

log = logging.getLogger(__name__)

_QUEUE = 64
"""Commands that may wait per axis; more get ``failed`` (busy)."""
_IN_FLIGHT = 16
"""Publishes awaiting the broker's acknowledgement at once."""
_INCOMING = 10_000
"""Messages received and not yet dispatched (dispatching never waits)."""
_RECONNECT_MIN = 0.2
"""First wait before reconnecting, s; it doubles up to ``reconnect_max``."""
_GOODBYE = 3.0
"""Longest a bridge that is being cancelled spends saying ``offline``, s."""
_LAST_REPLIES = 10.0
"""Longest a bridge that is being cancelled spends stopping the motions its commands
started and publishing their final replies, before it says ``offline``, s."""

NO_DELAY = (socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
"""Small messages (an e-stop, a reply) leave at once, not after Nagle's wait for an ACK."""

_STATE_KEYS = (
    "state", "position", "velocity", "enabled", "moving", "homed", "alarm", "alarm_code",
    "alarm_text", "limit_positive", "limit_negative", "error", "soft_limits", "units",
    "units_per_rev", "pulses_per_rev", "drive", "line", "address", "inputs", "outputs",
    "override", "queued",
)
"""What an axis's state message carries (from its snapshot)."""


@dataclass(frozen=True)
class BridgeOptions:
    """How a bridge connects and publishes; ``resolve`` merges a machine file's ``[mqtt]``
    section with command-line values."""

    broker: BrokerUrl
    node: str
    discovery: bool = True
    state_rate: float = 10.0
    """Most state messages per axis per second (state is published on change)."""
    stats_period: float = 5.0
    """Seconds between a line's statistics messages."""
    keepalive: int = 5
    reconnect_max: float = 10.0

    def __post_init__(self) -> None:
        check_node(self.node)
        checks.positive("state_rate", self.state_rate, unit="/s", error=ConfigError)
        checks.positive("stats_period", self.stats_period, unit="s", error=ConfigError)
        checks.whole("keepalive", self.keepalive, 1, 3600, error=ConfigError)
        checks.positive("reconnect_max", self.reconnect_max, unit="s", error=ConfigError)

    @classmethod
    def resolve(
        cls,
        config: MachineConfig,
        *,
        url: str | None = None,
        node: str | None = None,
        discovery: bool | None = None,
        state_rate: float | None = None,
        stats_period: float | None = None,
    ) -> BridgeOptions:
        """Options from ``config.mqtt`` with the given values taking precedence; the node
        defaults to the machine's name. ``ConfigError`` if no broker URL is given anywhere
        or a value is unusable."""
        m = config.mqtt
        url = url if url is not None else (m.url if m else None)
        if url is None:
            raise ConfigError("no MQTT broker: give --mqtt mqtt://HOST[:PORT] or set url in "
                              "the machine file's [mqtt] section")
        return cls(
            broker=parse_broker_url(url),
            node=node if node is not None else (m.node if m and m.node else config.name),
            discovery=discovery if discovery is not None else (m.discovery if m else True),
            state_rate=state_rate if state_rate is not None else (m.state_rate if m else 10.0),
            stats_period=stats_period if stats_period is not None
            else (m.stats_period if m else 5.0),
            keepalive=m.keepalive if m else 5,
            reconnect_max=m.reconnect_max if m else 10.0,
        )


@dataclass
class _ReplyTo:
    """Where a command's replies go, and what identifies them there."""

    topic: str
    correlation: bytes | None = None
    id: Id = None
    answered: bool = False
    """Its final reply is out (there is exactly one)."""


@dataclass
class _AxisQueue:
    """An axis's commands waiting for its worker (bounded)."""

    items: collections.deque[tuple[Command, _ReplyTo]] = field(
        default_factory=collections.deque)
    ready: anyio.Event = field(default_factory=anyio.Event)

    async def get(self) -> tuple[Command, _ReplyTo]:
        while not self.items:
            await self.ready.wait()
            self.ready = anyio.Event()
        return self.items.popleft()


def _is_abort(exc: BaseException) -> bool:
    if isinstance(exc, GroupMotionError):
        return isinstance(exc.__cause__, MotionAborted)
    return isinstance(exc, MotionAborted)


class _UrgentFirst(asyncio.Queue):  # type: ignore[type-arg]
    """aiomqtt's incoming queue with e-stops ahead of everything else; an e-stop is taken
    even when the queue is full. ``overtaken``: the message just taken arrived before an
    e-stop already taken (the e-stop drops it, as it drops the commands queued)."""

    def _init(self, maxsize: int) -> None:
        self._queue: collections.deque[tuple[int, aiomqtt.Message]] = collections.deque()
        self._urgent: collections.deque[tuple[int, aiomqtt.Message]] = collections.deque()
        self._arrivals = itertools.count()
        self._estop_arrived = -1
        self.overtaken = False

    def _put(self, item: aiomqtt.Message) -> None:
        entry = (next(self._arrivals), item)
        if _is_estop_topic(item.topic.value):
            self._urgent.append(entry)
        else:
            self._queue.append(entry)

    def _get(self) -> aiomqtt.Message:
        if self._urgent:
            arrived, item = self._urgent.popleft()
            self._estop_arrived = max(self._estop_arrived, arrived)
            self.overtaken = False
        else:
            arrived, item = self._queue.popleft()
            self.overtaken = arrived < self._estop_arrived
        return item

    def qsize(self) -> int:
        return len(self._queue) + len(self._urgent)

    def empty(self) -> bool:
        return not self._queue and not self._urgent

    def put_nowait(self, item: aiomqtt.Message) -> None:
        if _is_estop_topic(item.topic.value) and self.full():
            self._put(item)
            self._wakeup_next(self._getters)  # type: ignore[attr-defined]
            return
        super().put_nowait(item)


def _is_estop_topic(topic: str) -> bool:
    return topic == PLANT_ESTOP or (topic.endswith("/estop") and topic.count("/") == 2)


class Bridge:
    """A ``MachineSession`` bridged to an MQTT broker as the node ``options.node``."""

    def __init__(self, session: MachineSession, options: BridgeOptions) -> None:
        self.session = session
        self.options = options
        self.topics = Topics(options.node)
        self.client_name = f"mqtt:{options.node}"
        """The session client the bridge's commands, jogs and lease checks run as."""
        self.identifier = f"drivebus-{options.node}-{secrets.token_hex(4)}"
        """The MQTT client identifier (unique per process, the same across reconnects)."""
        self.outbox = Outbox()
        self.connections = 0
        """Successful connections so far."""
        self.acknowledged: dict[str, bytes] = {}
        """Per retained topic, the last payload the broker acknowledged (QoS 1)."""
        self._up = False
        self._up_event = anyio.Event()
        self._queues = {name: _AxisQueue() for name in session.machine.axes}
        self._last_state: dict[str, dict[str, Any]] = {}
        self._tg: anyio.abc.TaskGroup | None = None
        self._open: dict[int, tuple[Command, _ReplyTo, MotionRecord | None]] = {}
        """Commands taken up and not answered finally yet (by ``id`` of their _ReplyTo)."""
        self._replies_sending = 0

    # -- observing --------------------------------------------------------------------------

    @property
    def connected(self) -> bool:
        """True while the broker connection is up (subscribed, ``online`` published)."""
        return self._up

    async def wait_connected(self) -> None:
        """Return once the bridge is connected."""
        while not self._up:
            await self._up_event.wait()

    # -- running ----------------------------------------------------------------------------

    async def run(self) -> None:
        """Bridge until cancelled; then stop the motions and jogs its commands started,
        publish every command's final reply, and say ``offline``: the broker connection
        outlives the rest of the bridge for that (bounded)."""
        link = anyio.CancelScope(shield=True)

        async def connection() -> None:
            with link:
                await self._connect_loop()

        with self.session.events.subscribe({"axes", "lines"}) as sub:
            try:
                async with anyio.create_task_group() as tg:
                    self._tg = tg
                    tg.start_soon(connection, name="mqtt connection")
                    tg.start_soon(self._collect, sub, name="mqtt collector")
                    for axis in self._queues:
                        tg.start_soon(self._axis_worker, axis, name=f"mqtt axis {axis}")
                    try:
                        await anyio.sleep_forever()
                    finally:
                        with anyio.CancelScope(shield=True):
                            with anyio.move_on_after(_LAST_REPLIES):
                                await self._answer_the_rest()
                            link.cancel()  # now ``offline``
            finally:
                self._tg = None
                with anyio.CancelScope(shield=True):
                    await self.session.release(self.client_name)

    async def _answer_the_rest(self) -> None:
        """Leaving: queued commands are dropped, the motions commands started are stopped
        and answered when at rest, the rest answered ``aborted``; then the replies go out
        (while the broker is there)."""
        for axis in self._queues:
            self._drop_queued(axis, "the node is shutting down")
        await self.session.release(self.client_name)  # its jogs stop
        running = [(cmd, rt, rec) for cmd, rt, rec in self._open.values()
                   if rec is not None and not rec.done.is_set()]
        for axis in dict.fromkeys(cmd.axis for cmd, _, _ in running):
            try:
                await self.session.stop(axis, client=self.client_name)
            except DrivebusError as exc:
                log.error("mqtt %s: leaving, axis %s: %s", self.options.node, axis, exc)
        for cmd, rt, rec in list(self._open.values()):
            if rec is not None:
                await rec.done.wait()
                self._final(rt, cmd.axis, cmd.verb, rec.error, motion=rec.id,
                            result=rec.result)
            else:
                self._final(rt, cmd.axis, cmd.verb, MotionAborted(
                    f"axis {cmd.axis}: the {cmd.verb} was cut short: the node is shutting "
                    f"down"))
        while self._up and (self.outbox.replies_waiting or self._replies_sending):
            await self.outbox.sent.wait()

    async def _connect_loop(self) -> None:
        delay = _RECONNECT_MIN
        url = self.options.broker
        while True:
            before = self.connections
            try:
                await self._connection()
            except (aiomqtt.MqttError, OSError) as exc:
                if self.connections > before:
                    log.warning("mqtt %s: connection to %s lost: %s", self.options.node, url,
                                exc)
                else:
                    log.info("mqtt %s: cannot connect to %s: %s", self.options.node, url, exc)
            if self.connections > before:
                delay = _RECONNECT_MIN
                await self._connection_lost()
            await anyio.sleep(delay * random.uniform(0.8, 1.2))
            delay = min(delay * 2, self.options.reconnect_max)

    def _client(self) -> aiomqtt.Client:
        b = self.options.broker
        client = aiomqtt.Client(
            b.host, b.port, username=b.username, password=b.password,
            identifier=self.identifier,
            protocol=aiomqtt.ProtocolVersion.V5,
            will=aiomqtt.Will(self.topics.status, "offline", qos=1, retain=True),
            keepalive=self.options.keepalive,
            timeout=10.0,
            queue_type=_UrgentFirst,
            max_queued_incoming_messages=_INCOMING,
            logger=logging.getLogger("drivebus.mqtt.client"),
            socket_options=[NO_DELAY],
        )
        client.pending_calls_threshold = _IN_FLIGHT + 8  # we bound them: no warning
        return client

    async def _connection(self) -> None:
        """One broker connection, from connecting until it fails (or is cancelled)."""
        client = self._client()
        await client.__aenter__()
        try:
            fresh = SubscribeOptions(qos=1, retainHandling=SubscribeOptions.RETAIN_DO_NOT_SEND)
            await client.subscribe([(self.topics.commands, fresh), (self.topics.estop, fresh),
                                    (PLANT_ESTOP, fresh)])
            await client.publish(self.topics.status, "online", qos=1, retain=True)
            self._up = True
            self.connections += 1
            self._up_event.set()
            self._up_event = anyio.Event()
            log.info("mqtt %s: connected to %s", self.options.node, self.options.broker)
            self._announce()
            try:
                async with anyio.create_task_group() as tg:
                    tg.start_soon(self._receive, client, name="mqtt receiver")
                    tg.start_soon(self._publish, client, tg, name="mqtt publisher")
            except* (aiomqtt.MqttError, OSError) as group:
                raise aiomqtt.MqttError(str(group.exceptions[0])) from None
        finally:
            was_up, self._up = self._up, False
            with anyio.CancelScope(shield=True), anyio.move_on_after(_GOODBYE):
                await self._goodbye(client, was_up)

    async def _goodbye(self, client: aiomqtt.Client, was_up: bool) -> None:
        """Say ``offline`` (if still connected) and disconnect cleanly."""
        try:
            if was_up:
                await client.publish(self.topics.status, "offline", qos=1, retain=True,
                                     timeout=_GOODBYE)
        except aiomqtt.MqttError:
            pass  # the connection is gone: the broker publishes the last will instead
        try:
            await client.__aexit__(None, None, None)
        except aiomqtt.MqttError as exc:
            log.debug("mqtt %s: disconnect: %s", self.options.node, exc)
        lost = getattr(client, "_disconnected", None)  # why it dropped: consumed, not raised
        if isinstance(lost, asyncio.Future) and lost.done() and not lost.cancelled():
            lost.exception()

    async def _connection_lost(self) -> None:
        """The broker is gone: jogs held over MQTT stop, queued jogs are dropped."""
        for axis, q in self._queues.items():
            keep = collections.deque[tuple[Command, _ReplyTo]]()
            for cmd, rt in q.items:
                if cmd.verb == "jog":
                    self._final(rt, cmd.axis, cmd.verb, MotionAborted(
                        f"axis {axis}: the jog was dropped: the broker connection was lost"))
                else:
                    keep.append((cmd, rt))
            q.items = keep
        await self.session.release(self.client_name)

    def _announce(self) -> None:
        """After connecting: discovery and every axis's latest state, at once."""
        if self.options.discovery:
            units = {name: ax.config.unit for name, ax in self.session.machine.axes.items()}
            for msg in discovery_messages(self.topics, self.session.name, self._queues, units):
                self.outbox.put(msg)
        for axis in self._queues:
            state = self._last_state.get(axis)
            if state is None:
                state = self._state(self.session.axis_snapshot(axis).as_dict())
                self._last_state[axis] = state
            self.outbox.put(self._state_message(axis, state), interval=self._state_interval)
        self.outbox.forget_rates()

    async def _receive(self, client: aiomqtt.Client) -> None:
        incoming = getattr(client, "_queue", None)  # (aiomqtt makes it: our _UrgentFirst)
        async for msg in client.messages:
            overtaken = isinstance(incoming, _UrgentFirst) and incoming.overtaken
            self._dispatch(msg, overtaken=overtaken)

    async def _publish(self, client: aiomqtt.Client, tg: anyio.abc.TaskGroup) -> None:
        slots = anyio.Semaphore(_IN_FLIGHT)
        while True:
            msg = await self.outbox.get()
            await slots.acquire()
            tg.start_soon(self._send, client, msg, slots)

    async def _send(self, client: aiomqtt.Client, msg: Outgoing, slots: anyio.Semaphore) -> None:
        self._replies_sending += msg.reply
        try:
            await client.publish(msg.topic, msg.payload, qos=msg.qos, retain=msg.retain,
                                 properties=msg.properties)
            if msg.retain and msg.qos:
                self.acknowledged[msg.topic] = msg.payload
        except aiomqtt.MqttError:
            if msg.reply:
                self.outbox.reply(msg, first=True)  # not sent: it goes after reconnecting
            raise
        finally:
            self._replies_sending -= msg.reply
            slots.release()
            self.outbox.note_sent()

    # -- state and statistics ---------------------------------------------------------------

    @property
    def _state_interval(self) -> float:
        return 1.0 / self.options.state_rate

    def _state(self, snapshot: dict[str, Any]) -> dict[str, Any]:
        return {k: snapshot.get(k) for k in _STATE_KEYS}

    def _state_message(self, axis: str, state: dict[str, Any]) -> Outgoing:
        body = {"node": self.options.node, "axis": axis, **state, "ts": time.time()}
        return Outgoing(self.topics.state(axis), json.dumps(body).encode(), qos=1, retain=True)

    async def _collect(self, sub: Any) -> None:
        async for ev in sub:
            if ev.topic == "axes" and ev.key in self._queues:
                state = self._state(ev.data)
                if state != self._last_state.get(ev.key):
                    self._last_state[ev.key] = state
                    self.outbox.put(self._state_message(ev.key, state),
                                    interval=self._state_interval)
            elif ev.topic == "lines" and ev.key is not None:
                body = {k: v for k, v in ev.data.items() if k != "type"}
                body["ts"] = time.time()
                self.outbox.put(Outgoing(self.topics.stats(ev.key), json.dumps(body).encode(),
                                         qos=0), interval=self.options.stats_period)

    # -- commands ---------------------------------------------------------------------------

    def _reply_to(self, msg: aiomqtt.Message) -> tuple[_ReplyTo, str | None]:
        """Where replies to ``msg`` go, and a problem with its response topic if any."""
        props = msg.properties
        topic = getattr(props, "ResponseTopic", None) if props is not None else None
        corr = getattr(props, "CorrelationData", None) if props is not None else None
        if topic is None:
            return _ReplyTo(self.topics.replies, corr), None
        if not topic or "+" in topic or "#" in topic:
            return _ReplyTo(self.topics.replies, corr), (
                f"response topic {topic!r}: not a topic one can publish to")
        return _ReplyTo(topic, corr), None

    def _send_reply(self, rt: _ReplyTo, body: dict[str, Any]) -> None:
        props = None
        if rt.correlation is not None:
            props = Properties(PacketTypes.PUBLISH)
            props.CorrelationData = rt.correlation
        self.outbox.reply(Outgoing(rt.topic, json.dumps(body).encode(), qos=1,
                                   properties=props, reply=True))

    def _body(self, rt: _ReplyTo, axis: str | None, verb: str, status: str) -> dict[str, Any]:
        return {"id": rt.id, "node": self.options.node, "axis": axis, "verb": verb,
                "status": status}

    def _accepted(self, rt: _ReplyTo, axis: str | None, verb: str, **extra: Any) -> None:
        self._send_reply(rt, {**self._body(rt, axis, verb, "accepted"), **extra})

    def _final(
        self, rt: _ReplyTo, axis: str | None, verb: str, error: BaseException | None,
        **extra: Any,
    ) -> None:
        if rt.answered:
            return  # exactly one final reply
        rt.answered = True
        self._open.pop(id(rt), None)
        status = "done" if error is None else "aborted" if _is_abort(error) else "failed"
        self._send_reply(rt, {**self._body(rt, axis, verb, status),
                              "error": error_record(error), **extra})

    def _dispatch(self, msg: aiomqtt.Message, *, overtaken: bool = False) -> None:
        """Take one incoming message; never waits, never raises. ``overtaken``: it came
        before an e-stop that was taken ahead of it: a command is dropped, as if queued."""
        topic = msg.topic.value
        try:
            if self.topics.is_estop(topic):
                self._estop(msg)
                return
            parsed = self.topics.parse_command(topic)
            if parsed is None:
                log.warning("mqtt %s: message on unexpected topic %s", self.options.node, topic)
                return
            axis, verb = parsed
            rt, problem = self._reply_to(msg)
            rt.id = peek_id(msg.payload)
            if problem is not None and verb != "halt":  # (a halt's replies go to replies)
                self._final(rt, axis, verb, ArgumentError(problem))
                return
            try:
                cmd = parse_command(axis, verb, msg.payload)
                self.session.axis(axis)
            except DrivebusError as exc:
                self._final(rt, axis, verb, exc)
                return
            if verb in ("stop", "halt"):
                self._drop_queued(axis, f"a {verb} of axis {axis} arrived before it ran")
                self._spawn(self._direct, cmd, rt)
                return
            if overtaken:
                self._final(rt, axis, verb, MotionAborted(
                    f"axis {axis}: the {verb} was dropped: an e-stop arrived before it ran"))
                return
            q = self._queues[axis]
            if len(q.items) >= _QUEUE:
                self._final(rt, axis, verb, DrivebusError(
                    f"axis {axis}: {len(q.items)} commands are waiting already; try again"))
                return
            q.items.append((cmd, rt))
            q.ready.set()
        except Exception as exc:  # a bug must not end the bridge or leave a command unanswered
            log.exception("mqtt %s: internal error on %s", self.options.node, topic)
            self._final(_ReplyTo(self.topics.replies, None, peek_id(msg.payload)), None,
                        topic.rsplit("/", 1)[-1], DrivebusError(f"internal error: {exc!r}"))

    def _drop_queued(self, axis: str, why: str) -> None:
        q = self._queues[axis]
        while q.items:
            cmd, rt = q.items.popleft()
            self._final(rt, axis, cmd.verb, MotionAborted(f"axis {axis}: the {cmd.verb} was "
                                                          f"dropped: {why}"))

    def _spawn(self, fn: Callable[..., Awaitable[None]], *args: Any) -> None:
        """Run a command's task in the bridge's task group. Their number is bounded by
        what can be in progress: a stop per stop command until the axis is at rest, an
        e-stop, a watcher per motion running."""
        assert self._tg is not None, "the bridge is not running"
        self._tg.start_soon(fn, *args)

    def _estop(self, msg: aiomqtt.Message) -> None:
        for axis in self._queues:
            self._drop_queued(axis, "an e-stop arrived before it ran")
        rt, _ = self._reply_to(msg)
        rt.id = peek_id(msg.payload)
        self._spawn(self._run_estop, rt, msg.topic.value)

    async def _run_estop(self, rt: _ReplyTo, topic: str) -> None:
        scope = "plant" if topic == PLANT_ESTOP else "node"
        log.warning("mqtt %s: e-stop (%s) from %s", self.options.node, scope, topic)
        self._accepted(rt, None, "estop", scope=scope)
        outcome = await self.session.estop()
        bad = next((v for v in outcome.values() if v is not None), None)
        self._send_reply(rt, {**self._body(rt, None, "estop", "done" if bad is None
                                           else "failed"),
                              "error": bad, "scope": scope, "result": {"axes": outcome}})

    async def _axis_worker(self, axis: str) -> None:
        q = self._queues[axis]
        while True:
            cmd, rt = await q.get()
            await self._queued(cmd, rt)

    async def _queued(self, cmd: Command, rt: _ReplyTo) -> None:
        """A queued command (everything but stop and halt), in the axis's worker."""
        s, a, client = self.session, cmd.axis, self.client_name
        self._open[id(rt)] = (cmd, rt, None)
        try:
            if cmd.verb == "move":
                rec = await s.start_move(
                    a, target=cmd.args.get("target"), by=cmd.args.get("by"),
                    speed=cmd.args.get("speed"), accel=cmd.args.get("accel"),
                    decel=cmd.args.get("decel"),
                    buffer=cmd.values.get("buffer", "aborting"), client=client)
            elif cmd.verb == "home":
                rec = await s.start_home(a, client=client)
            else:
                await self._direct(cmd, rt)
                return
        except DrivebusError as exc:
            self._final(rt, a, cmd.verb, exc)
            return
        self._accepted(rt, a, cmd.verb, motion=rec.id)
        if not rt.answered:
            self._open[id(rt)] = (cmd, rt, rec)
        self._spawn(self._motion_end, cmd, rt, rec)

    async def _motion_end(self, cmd: Command, rt: _ReplyTo, rec: MotionRecord) -> None:
        await rec.done.wait()
        self._final(rt, cmd.axis, cmd.verb, rec.error, motion=rec.id, result=rec.result)

    async def _direct(self, cmd: Command, rt: _ReplyTo) -> None:
        """A command that returns when it is over (stop, halt, enable, disable, reset, jog)."""
        s, a, client, args = self.session, cmd.axis, self.client_name, cmd.args
        self._open.setdefault(id(rt), (cmd, rt, None))
        try:
            if cmd.verb != "halt":
                s.authorize(client)  # refused by a lease: only a failed reply
            if cmd.verb == "stop":  # a deceleration the drive cannot take: the same
                s.axis(a).check_stop(args.get("decel"))
        except DrivebusError as exc:
            self._final(rt, a, cmd.verb, exc)
            return
        # A stop or halt is taken up at once (nothing refuses it but a lease or a stop's
        # deceleration); the others once they are over or failed on the way: a refusal
        # (nothing sent) only fails. A jog is accepted once the axis took it.
        at_end = cmd.verb not in ("stop", "halt", "jog")
        if cmd.verb in ("stop", "halt"):
            self._accepted(rt, a, cmd.verb)
        try:
            if cmd.verb == "stop":
                await s.stop(a, decel=args.get("decel"), client=client)
            elif cmd.verb == "halt":
                await s.halt(a, client=client)
            elif cmd.verb == "enable":
                await s.enable(a, client=client)
            elif cmd.verb == "disable":
                await s.disable(a, client=client)
            elif cmd.verb == "reset":
                await s.reset(a, client=client)
            elif cmd.verb == "override":
                s.set_override(args["factor"], axis=a, client=client)
            elif cmd.verb == "set_output":
                await s.set_output(a, cmd.values["output"], cmd.values["state"], client=client)
            elif cmd.verb == "jog":
                await s.jog(a, args["speed"], ttl=args["ttl"], accel=args.get("accel"),
                            decel=args.get("decel"), client=client,
                            accepted=lambda: self._accepted(rt, a, "jog"))
                if not self._up:  # the broker went away while it started: no feed can come
                    await s.release(client)
                    raise MotionAborted(f"axis {a}: the jog was stopped: the broker "
                                        f"connection was lost")
            else:  # pragma: no cover - parse_command knows the verbs
                raise ArgumentError(f"unknown verb {cmd.verb!r}")
        except DrivebusError as exc:
            if at_end and not isinstance(exc, REFUSALS):
                self._accepted(rt, a, cmd.verb)  # taken up, then failed on the way
            self._final(rt, a, cmd.verb, exc)
            return
        if at_end:
            self._accepted(rt, a, cmd.verb)
        self._final(rt, a, cmd.verb, None)


async def run_bridge(
    session: MachineSession,
    url: str,
    *,
    node: str | None = None,
    discovery: bool = True,
    state_rate: float = 10.0,
    stats_period: float = 5.0,
    keepalive: int = 5,
    reconnect_max: float = 10.0,
) -> None:
    """Bridge ``session`` to the broker at ``url`` (``mqtt://HOST[:PORT]``) as ``node``
    (default: the machine's name) until cancelled. ``ConfigError`` at once for unusable
    options; a broker that is down or goes away is retried, never an error."""
    options = BridgeOptions(
        broker=parse_broker_url(url),
        node=session.name if node is None else node,
        discovery=discovery, state_rate=state_rate, stats_period=stats_period,
        keepalive=keepalive, reconnect_max=reconnect_max,
    )
    await Bridge(session, options).run()


async def run_configured_bridge(
    session: MachineSession,
    *,
    url: str | None = None,
    node: str | None = None,
    discovery: bool | None = None,
) -> None:
    """``run_bridge`` with the machine file's ``[mqtt]`` section; the values given here
    (e.g. ``--mqtt``, ``--node``, ``--no-discovery``) take precedence."""
    options = BridgeOptions.resolve(session.machine.config, url=url, node=node,
                                    discovery=discovery)
    await Bridge(session, options).run()
