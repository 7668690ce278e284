"""``WS /api/ws``: live updates and jogs for one client connection.

The client sends JSON objects with one operation each (and optionally an ``id`` that the
reply carries back):

- ``{"auth": "TOKEN"}``: first message, when the service has tokens and the handshake
  carried no ``Authorization: Bearer`` header (browsers cannot set one). A wrong or
  missing one gets one ``{"type": "error", ...}`` message and the close code 4401 with
  the cause as the reason; a wrong header refuses the handshake itself with a 401
  problem, as an HTTP route answers. Neither quotes the token.
- ``{"subscribe": ["axes", "lines", "motions", "errors"]}``: what to receive from now on
  (it replaces the previous set). Answered by ``{"type": "subscribed", "topics": [...]}``
  and then, for ``axes``, the present state of every axis. With ``"max_rate": N`` the
  messages come in batches N times a second, each axis's and line's newest state at most
  once per batch (a tablet on Wi-Fi needs no more); without it, as polled.
- ``{"jog": {"axis": "z", "speed": 5.0, "ttl": 0.5}}``: jog, or feed a running jog; the
  axis stops ``ttl`` seconds (at most 10) after the last feed, and at once when this
  connection closes. Speed 0 stops. Command scope.
- ``{"stop": {"axis": "z"}}``: decelerating stop (command scope); ``{"estop": {}}``: the
  emergency stop of every axis (any client). Neither waits behind queued jogs, and jogs
  this connection queued before them are dropped.
- ``{"ping": ...}``: answered by ``{"type": "pong"}``.

The service sends ``{"type": "hello", ...}`` once authenticated (with ``"clock"``: the
service's monotonic and wall-clock time at that moment, to place the axes' and lines'
``timestamp`` on a clock), then updates of the
subscribed topics: ``{"type": "axis", "axis": NAME, "state": ..., "position": ...,
"velocity": ..., ...}`` for every axis as it is polled (the fields of ``GET
/api/axes/NAME``), ``{"type": "line", ...}``, ``{"type": "motion", "event": "started" |
"done" | "aborted" | "failed", "id": ..., ...}``, ``{"type": "lease", ...}``, ``{"type":
"estop", ...}``, ``{"type": "error", "axis": ..., ...}``; commands are answered by
``{"type": "reply", "op": ..., "id": ..., "ok": true}`` or ``"ok": false`` with ``"error"``
(problem details as in HTTP). Axis and line states are latest-wins: a slow client gets
the newest state of each, never a backlog; motion events are kept up to a bound, and a
client that fell behind further is told ``{"type": "lost", "count": N}``.
"""

# No ``from __future__ import annotations`` here: FastAPI reads the annotations at runtime.

import json
import logging
import time
from typing import Annotated, Any

import anyio
import anyio.abc
from anyio.streams.memory import MemoryObjectReceiveStream, MemoryObjectSendStream
from fastapi import WebSocket, WebSocketDisconnect
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from drivebus import checks
from drivebus.app import Event, Subscription
from drivebus.clock import monotonic
from drivebus.errors import ArgumentError, DrivebusError, MotionAborted
from drivebus.service.auth import AuthError, Principal, bearer_token, require_command
from drivebus.service.deps import ServiceState
from drivebus.service.encoding import dumps
from drivebus.service.models import MAX_JOG_TTL
from drivebus.service.problems import problem_data, problem_response

__all__ = ["websocket_endpoint"]

log = logging.getLogger(__name__)

AUTH_TIMEOUT = 5.0
"""How long a connection may take to send ``{"auth": ...}``."""
COMMAND_QUEUE = 16
"""Jogs waiting per connection; beyond that a jog is refused, never queued."""
EVENT_CAPACITY = 256
"""Discrete events (motions, errors) kept per connection."""

CLOSE_UNAUTHORIZED = 4401
"""The close code of a connection the service does not let in (HTTP's 401 in the range
RFC 6455 leaves to applications); the close reason says why."""
MAX_CLOSE_REASON = 123
"""Longest close reason a close frame carries, bytes of UTF-8 (RFC 6455 5.5.1)."""

_OPS = ("auth", "subscribe", "jog", "stop", "estop", "ping")


class _JogBody(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)
    axis: str
    speed: Annotated[float, Field(allow_inf_nan=False)]
    ttl: Annotated[float, Field(gt=0, le=MAX_JOG_TTL, allow_inf_nan=False)] = 0.5
    accel: Annotated[float, Field(gt=0, allow_inf_nan=False)] | None = None
    decel: Annotated[float, Field(gt=0, allow_inf_nan=False)] | None = None


class _StopBody(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)
    axis: str
    decel: Annotated[float, Field(gt=0, allow_inf_nan=False)] | None = None


def _invalid(op: str, exc: ValidationError) -> ArgumentError:
    parts = [f"{'.'.join(str(p) for p in e['loc']) or op}: {e['msg']}" for e in exc.errors()]
    return ArgumentError(f"{op}: {'; '.join(parts)}")


class _Connection:
    """One client's connection: its subscription, its queued jogs, its replies."""

    def __init__(self, ws: WebSocket, state: ServiceState, principal: Principal,
                 sub: Subscription, scope: anyio.CancelScope) -> None:
        self.ws = ws
        self.state = state
        self.session = state.session
        self.principal = principal
        self.id = f"{principal.name}#ws{next(state.connections)}"
        """The owner of this connection's jogs: they stop when it closes."""
        self.sub = sub
        self.scope = scope
        self._lost = 0
        self._interval = 0.0  # seconds between a key's states (0: as polled)
        self._epoch = 0  # bumped by an e-stop: queued jogs from before are dropped
        self._axis_epoch: dict[str, int] = {}  # bumped by a stop of that axis

    # -- sending -----------------------------------------------------------------------------

    async def send(self, text: str) -> None:
        """Send one message; a client that is gone ends the connection. A slow client
        only holds up its own sender (its mailbox keeps the latest states meanwhile)."""
        try:
            # Each send is one whole frame written at once (uvicorn queues the frames of
            # concurrent senders in order), so replies and events need no lock.
            await self.ws.send_text(text)
        except (WebSocketDisconnect, OSError) as exc:
            log.debug("websocket %s: send failed (%r): closing", self.id, exc)
            self.scope.cancel()

    async def reply(self, op: str, msg_id: Any, error: BaseException | None = None,
                    **extra: Any) -> None:
        """Answer a command."""
        data: dict[str, Any] = {"type": "reply", "op": op, "id": msg_id, "ok": error is None}
        if error is not None:
            data["error"] = problem_data(error)
        data.update(extra)
        await self.send(dumps(data))

    async def pump_events(self) -> None:
        """Send the subscribed events as they come (latest state first, bounded backlog);
        with a ``max_rate``, in batches at that rate: each axis's and line's newest state
        at most that often, what happened meanwhile with it."""
        while True:
            batch = [await self.sub.get()]
            if self._interval > 0:
                batch += self.sub.drain()
            if self.sub.lost != self._lost:
                await self.send(dumps({"type": "lost", "count": self.sub.lost - self._lost}))
                self._lost = self.sub.lost
            for event in batch:
                await self.send(self.state.encoder.encode(event))
            if self._interval > 0:
                await anyio.sleep(self._interval)  # meanwhile the mailbox keeps the newest

    # -- receiving ---------------------------------------------------------------------------

    async def receive_loop(self, jobs: MemoryObjectSendStream[tuple[int, int, Any, _JogBody]],
                           tg: anyio.abc.TaskGroup) -> None:
        """Read the client's messages until it disconnects."""
        while True:
            message = await self.ws.receive()
            if message["type"] == "websocket.disconnect":
                return
            text = message.get("text")
            if text is None:
                await self.reply("?", None, ArgumentError("send JSON text messages"))
                continue
            try:
                op, msg_id, body = _parse(text)
            except ArgumentError as exc:
                await self.reply("?", None, exc)
                continue
            try:
                await self.dispatch(op, msg_id, body, jobs, tg)
            except (DrivebusError, AuthError) as exc:
                await self.reply(op, msg_id, exc)

    async def dispatch(self, op: str, msg_id: Any, body: Any,
                       jobs: MemoryObjectSendStream[tuple[int, int, Any, _JogBody]],
                       tg: anyio.abc.TaskGroup) -> None:
        """Carry out one message (jogs go to the connection's queue)."""
        if op == "ping":
            await self.send(dumps({"type": "pong", "id": msg_id}))
        elif op == "auth":
            raise ArgumentError("this connection is already authenticated")
        elif op == "subscribe":
            topics, max_rate = body
            await self.subscribe(topics, msg_id, max_rate)
        elif op == "estop":
            self._epoch += 1
            tg.start_soon(self.estop, msg_id)
        elif op == "stop":
            require_command(self.principal)
            try:
                stop = _StopBody.model_validate(body)
            except ValidationError as exc:
                raise _invalid(op, exc) from None
            self.session.axis(stop.axis)
            self._axis_epoch[stop.axis] = self._axis_epoch.get(stop.axis, 0) + 1
            tg.start_soon(self.stop, stop, msg_id)
        elif op == "jog":
            require_command(self.principal)
            try:
                jog = _JogBody.model_validate(body)
            except ValidationError as exc:
                raise _invalid(op, exc) from None
            self.session.axis(jog.axis)
            if jog.speed == 0:  # a stop: never waits behind queued jogs
                self._axis_epoch[jog.axis] = self._axis_epoch.get(jog.axis, 0) + 1
                tg.start_soon(self.stop, _StopBody(axis=jog.axis), msg_id, "jog")
                return
            try:
                jobs.send_nowait((self._epoch, self._axis_epoch.get(jog.axis, 0), msg_id, jog))
            except anyio.WouldBlock:
                raise ArgumentError(f"jog: more than {COMMAND_QUEUE} jogs waiting on this "
                                    f"connection: slow down the feed") from None

    async def subscribe(self, body: Any, msg_id: Any, max_rate: Any = None) -> None:
        """Watch the topics in ``body`` (states at most ``max_rate`` times a second per axis
        or line; None: as polled); the present state of axes and lines follows."""
        if not isinstance(body, list) or not all(isinstance(t, str) for t in body):
            raise ArgumentError('subscribe: expected a list of topics, e.g. ["axes"]')
        if max_rate is not None and (isinstance(max_rate, bool) or not isinstance(
                max_rate, int | float) or not 0 < max_rate <= 1000):
            raise ArgumentError(f"max_rate: expected updates per second in (0, 1000] or "
                                f"null (as polled), got {max_rate!r}")
        topics = self.sub.set_topics(body)
        self._interval = 0.0 if max_rate is None else 1.0 / max_rate
        await self.send(dumps({"type": "subscribed", "id": msg_id, "topics": sorted(topics),
                               "max_rate": max_rate}))
        if "axes" in topics:
            for name in self.session.machine.axes:
                snap = self.session.axis_snapshot(name).as_dict()
                self.sub.put(Event("axes", name, {"type": "axis", "axis": name, **snap}))
        if "lines" in topics:
            for name in self.session.machine.buses:
                snap = self.session.line_snapshot(name).as_dict()
                self.sub.put(Event("lines", name, {"type": "line", **snap}))

    # -- commands ----------------------------------------------------------------------------

    async def run_jogs(
        self, jobs: MemoryObjectReceiveStream[tuple[int, int, Any, _JogBody]]
    ) -> None:
        """Start or feed the queued jogs in order; those a stop overtook are dropped."""
        async for epoch, axis_epoch, msg_id, jog in jobs:
            if epoch != self._epoch or axis_epoch != self._axis_epoch.get(jog.axis, 0):
                await self.reply("jog", msg_id, MotionAborted(
                    f"jog of {jog.axis}: dropped, a stop came after it"))
                continue
            try:
                await self.session.jog(jog.axis, jog.speed, ttl=jog.ttl, accel=jog.accel,
                                       decel=jog.decel, client=self.principal.name,
                                       owner=self.id)
            except DrivebusError as exc:
                await self.reply("jog", msg_id, exc)
            else:
                await self.reply("jog", msg_id)

    async def stop(self, body: _StopBody, msg_id: Any, op: str = "stop") -> None:
        """A decelerating stop; it completes even if the connection closes meanwhile."""
        error: DrivebusError | None = None
        with anyio.CancelScope(shield=True):
            try:
                await self.session.stop(body.axis, decel=body.decel,
                                        client=self.principal.name)
            except DrivebusError as exc:
                error = exc
        await self.reply(op, msg_id, error)

    async def estop(self, msg_id: Any) -> None:
        """The e-stop; it completes even if the connection closes meanwhile."""
        with anyio.CancelScope(shield=True):
            outcome = await self.session.estop()
        await self.reply("estop", msg_id, axes=outcome)


def _parse(text: str) -> tuple[str, Any, Any]:
    try:
        msg = checks.load_json("message", text)
    except ArgumentError:
        if _asks_estop(text):  # a NaN or a huge number beside it refuses nothing
            return "estop", None, {}
        raise
    if not isinstance(msg, dict):
        raise ArgumentError("expected a JSON object with one operation")
    if "estop" in msg:  # an emergency stop is never refused for what comes with it
        return "estop", msg.get("id"), msg["estop"]
    ops = [k for k in msg if k in _OPS]
    unknown = [k for k in msg if k not in _OPS and k != "id"
               and not (k == "max_rate" and ops == ["subscribe"])]
    if len(ops) != 1 or unknown:
        raise ArgumentError(f"expected one operation of {', '.join(_OPS)} (and an optional "
                            f"id), got {', '.join(map(str, msg)) or 'nothing'}")
    if ops[0] == "subscribe":
        return ops[0], msg.get("id"), (msg["subscribe"], msg.get("max_rate"))
    return ops[0], msg.get("id"), msg[ops[0]]


def _asks_estop(text: str) -> bool:
    """Whether ``text``, refused as a message for a number in it (NaN, infinity, too
    many digits), is a JSON object with ``estop`` in it: read leniently, numbers aside."""
    try:
        msg = json.loads(text, parse_constant=lambda _: None, parse_int=lambda _: 0)
    except (ValueError, RecursionError):
        return False
    return isinstance(msg, dict) and "estop" in msg


async def _authenticate(ws: WebSocket, state: ServiceState) -> Principal | None:
    """The caller, from the handshake's header or a first ``{"auth": TOKEN}`` message;
    None (the connection refused, saying why) if it is not allowed in."""
    tokens = state.tokens
    client = ws.headers.get("x-drivebus-client") or ws.query_params.get("client")
    header = ws.headers.get("authorization")
    if header or not tokens.enabled:
        try:
            principal = tokens.authenticate(bearer_token(header), client)
        except AuthError as exc:
            await _refuse_handshake(ws, exc)
            return None
        await ws.accept()
        return principal
    await ws.accept()
    try:
        with anyio.fail_after(AUTH_TIMEOUT):
            message = await ws.receive()
        if message["type"] == "websocket.disconnect":
            return None
        return tokens.check(_first_token(message.get("text") or ""))
    except TimeoutError:
        error = AuthError(401, f'no {{"auth": "TOKEN"}} within {AUTH_TIMEOUT:g} s')
    except AuthError as exc:
        error = exc
    await _refuse(ws, error)
    return None


def _first_token(text: str) -> str:
    """The token of a first message ``{"auth": TOKEN}``; ``AuthError`` 401 for anything
    else, never quoting the message (it may be a token sent bare)."""
    try:
        op, _, token = _parse(text)
    except ArgumentError:
        op, token = "", None
    if op != "auth" or not isinstance(token, str):
        raise AuthError(401, 'this service needs a token: send {"auth": "TOKEN"} first')
    return token


async def _refuse_handshake(ws: WebSocket, error: AuthError) -> None:
    """Refuse a handshake whose ``Authorization`` header does not let it in as an HTTP
    route refuses a request: ``401`` with ``WWW-Authenticate`` and the problem+json body
    naming the cause (the WebSocket Denial Response extension, which uvicorn offers). A
    server without it gets ``_refuse``: accepted, told why, closed. Nothing else is
    sent either way."""
    if "websocket.http.response" in (ws.scope.get("extensions") or {}):
        await ws.send_denial_response(problem_response(error, ws.url.path))
        return
    await ws.accept()
    await _refuse(ws, error)


async def _refuse(ws: WebSocket, error: AuthError) -> None:
    """Close an accepted connection that is not let in: the problem as an ``error``
    message, then close code ``CLOSE_UNAUTHORIZED`` with its detail as the reason."""
    await ws.send_text(dumps({"type": "error", "error": problem_data(error)}))
    reason = str(error).encode()[:MAX_CLOSE_REASON].decode(errors="ignore")
    await ws.close(code=CLOSE_UNAUTHORIZED, reason=reason)


async def websocket_endpoint(ws: WebSocket) -> None:
    """The ``/api/ws`` endpoint (protocol in the module's doc)."""
    state: ServiceState = ws.app.state.drivebus
    try:
        principal = await _authenticate(ws, state)
    except (WebSocketDisconnect, OSError):
        return
    if principal is None:
        return
    session = state.session
    send_jobs, jobs = anyio.create_memory_object_stream[tuple[int, int, Any, _JogBody]](
        COMMAND_QUEUE)
    with state.fanout.attach(capacity=EVENT_CAPACITY) as sub:
        conn: _Connection | None = None
        try:
            async with anyio.create_task_group() as tg, send_jobs, jobs:
                conn = _Connection(ws, state, principal, sub, tg.cancel_scope)
                await conn.send(dumps({
                    "type": "hello", "machine": session.name, "client": principal.name,
                    "scope": principal.scope, "connection": conn.id,
                    "axes": list(session.machine.axes), "lines": list(session.machine.buses),
                    "clock": {"monotonic": monotonic(), "wall": time.time()},
                }))
                tg.start_soon(conn.pump_events)
                tg.start_soon(conn.run_jogs, jobs)
                try:
                    await conn.receive_loop(send_jobs, tg)
                except (WebSocketDisconnect, OSError) as exc:
                    log.debug("websocket %s: %r", conn.id, exc)
                tg.cancel_scope.cancel()
        finally:
            if conn is not None:
                with anyio.CancelScope(shield=True):
                    await session.release(conn.id)  # its jogs stop now
