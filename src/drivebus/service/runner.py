"""Serving one machine: uvicorn and sibling tasks on one ``MachineSession``.

``open_service`` opens the machine, serves HTTP/WebSocket on a socket it binds itself and
runs the ``extra`` tasks (e.g. an MQTT bridge) beside the server, each given the same
session; leaving it stops every moving axis (also when left by cancellation) before the
machine closes. ``serve`` runs that until cancelled; ``run`` is ``drivebus serve``:
it serves until SIGINT/SIGTERM and says what it stopped.
"""

from __future__ import annotations

import contextlib
import ipaddress
import logging
import signal
import socket
import sys
from collections.abc import AsyncIterator, Awaitable, Callable, Iterator, Sequence
from contextlib import asynccontextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import anyio
import anyio.abc
import anyio.to_thread
import uvicorn

from drivebus import heap, runtime
from drivebus.app import MachineSession
from drivebus.config import MachineConfig
from drivebus.errors import ConfigError
from drivebus.service import systemd
from drivebus.service.api import create_app
from drivebus.service.auth import TokenStore
from drivebus.service.bodies import MAX_BODY

__all__ = [
    "Service",
    "SiblingTask",
    "check_host",
    "is_loopback",
    "open_service",
    "run",
    "serve",
]

log = logging.getLogger(__name__)

SiblingTask = Callable[[MachineSession], Awaitable[None]]
"""A task that runs beside the HTTP server on the same session (e.g. an MQTT bridge);
it is cancelled when the service ends."""

GRACEFUL_SHUTDOWN = 2
"""Seconds open requests get to finish when the service stops (then they are cancelled)."""
STOP_TIMEOUT = 30.0
"""Longest wait for the axes to come to rest when the service stops."""


@dataclass
class Service:
    """A running service: its session and URL; after it ended, what it stopped."""

    session: MachineSession
    url: str | None
    """``http://HOST:PORT`` (None without HTTP)."""
    stopped: dict[str, dict[str, str] | None] = field(default_factory=dict)
    """The axes the shutdown stopped, each with its outcome (None: at rest)."""
    rest: dict[str, dict[str, Any]] = field(default_factory=dict)
    """Each axis after the shutdown's stops: ``moving`` (as polled), ``position``, and
    ``twin_moving`` for a simulated axis (its twin's own word)."""

    @property
    def at_rest(self) -> bool:
        """True once every axis (and every simulated twin) was seen at rest."""
        return bool(self.rest) and not any(
            r["moving"] or r.get("twin_moving") for r in self.rest.values()
        )


def is_loopback(host: str) -> bool:
    """True for ``localhost`` and the loopback addresses (127.0.0.0/8, ::1)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def check_host(host: str, tokens: TokenStore) -> None:
    """``ConfigError`` if ``host`` is beyond loopback and there are no tokens."""
    if not is_loopback(host) and not tokens.enabled:
        raise ConfigError(
            f"--host {host}: refusing to serve beyond loopback without authentication; "
            f"give --token-file FILE (lines 'NAME read|command TOKEN'), or keep the "
            f"default --host 127.0.0.1"
        )


def _listen(host: str, port: int) -> socket.socket:
    """A socket bound to ``host:port`` (port 0: any free port)."""
    if not 0 <= port <= 65535:
        raise ConfigError(f"--port {port}: expected 0..65535 (0: any free port)")
    try:
        infos = socket.getaddrinfo(host.strip("[]"), port, type=socket.SOCK_STREAM,
                                   flags=socket.AI_PASSIVE)
    except socket.gaierror as exc:
        raise ConfigError(f"--host {host}: {exc.strerror}") from None
    family, kind, proto, _, address = infos[0]
    sock = socket.socket(family, kind, proto)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(address)
    except OSError as exc:
        sock.close()
        raise OSError(exc.errno, f"cannot listen on {host}:{port}: {exc.strerror}") from None
    return sock


def _url(sock: socket.socket) -> str:
    host, port = sock.getsockname()[:2]
    if ":" in host:
        host = f"[{host}]"
    return f"http://{host}:{port}"


class _Server(uvicorn.Server):
    """uvicorn without its own signal handling (the runner owns the signals), telling
    when it listens."""

    def __init__(self, config: uvicorn.Config) -> None:
        super().__init__(config)
        self.listening = anyio.Event()

    @contextlib.contextmanager
    def capture_signals(self) -> Iterator[None]:
        yield

    async def startup(self, sockets: list[socket.socket] | None = None) -> None:
        await super().startup(sockets)
        self.listening.set()


async def built_app(session: MachineSession, tokens: TokenStore) -> Any:
    """The service's app (``create_app``), made in a worker thread: its routes and their
    models take tens of milliseconds of CPU, which in one event-loop step would hold up
    every stop meanwhile (its lifespan builds FastAPI's routing the same way)."""
    return await anyio.to_thread.run_sync(create_app, session, tokens)


async def _serve_http(server: _Server, sock: socket.socket, *,
                      task_status: anyio.abc.TaskStatus[None]) -> None:
    """Run uvicorn on ``sock`` until cancelled, then let open requests finish (bounded)."""
    ended = anyio.Event()

    async def run() -> None:
        try:
            with anyio.CancelScope(shield=True):  # it ends by should_exit, gracefully
                await server.serve(sockets=[sock])
        finally:
            ended.set()

    async with anyio.create_task_group() as tg:
        tg.start_soon(run, name="drivebus service: uvicorn")
        try:
            await server.listening.wait()
            task_status.started()
            await ended.wait()
            raise RuntimeError("the HTTP server stopped by itself")
        finally:
            server.should_exit = True


async def _stop_when_cancelled(service: Service) -> None:
    """Stop every moving axis as soon as the service is told to end, while the HTTP
    server is still letting its open requests finish."""
    try:
        await anyio.sleep_forever()
    finally:
        with anyio.CancelScope(shield=True), anyio.move_on_after(STOP_TIMEOUT):
            service.stopped.update(await service.session.stop_all())


def _rest(session: MachineSession) -> dict[str, dict[str, Any]]:
    rest: dict[str, dict[str, Any]] = {}
    for name, axis in session.machine.axes.items():
        st = axis.status
        entry: dict[str, Any] = {"moving": bool(st is None or st.moving),
                                 "position": axis.position}
        twin = session.machine.sim_drives.get(name)
        if twin is not None:
            entry["twin_moving"] = twin.is_moving()
        rest[name] = entry
    return rest


@asynccontextmanager
async def open_service(
    config: str | Path | MachineConfig,
    *,
    host: str = "127.0.0.1",
    port: int = 8000,
    tokens: TokenStore | None = None,
    token_file: str | Path | None = None,
    http: bool = True,
    extra: Sequence[SiblingTask] = (),
    stats_period: float = 0.5,
) -> AsyncIterator[Service]:
    """Open the machine and serve it for the block: HTTP/WebSocket on ``host:port``
    (unless ``http`` is False) and the ``extra`` tasks beside it. On exit, however it is
    left, every moving axis is stopped before the machine closes (``Service.stopped``,
    ``Service.rest`` tell what happened). Refuses a ``host`` beyond loopback without
    tokens (``ConfigError``)."""
    if tokens is None:
        tokens = TokenStore.load(token_file) if token_file is not None else TokenStore()
    sock: socket.socket | None = None
    if http:
        check_host(host, tokens)
        sock = _listen(host, port)
    try:
        async with MachineSession.open(config, stats_period=stats_period,
                                       require_all=False) as session:
            service = Service(session, None if sock is None else _url(sock))
            try:
                async with anyio.create_task_group() as tg:
                    tg.start_soon(_stop_when_cancelled, service,
                                  name="drivebus service: stop on exit")
                    if sock is not None:
                        app = await built_app(session, tokens)
                        server = _Server(uvicorn.Config(
                            app,
                            lifespan="on",
                            log_config=None,
                            access_log=False,
                            ws="websockets-sansio",
                            ws_max_size=MAX_BODY,
                            ws_per_message_deflate=False,
                            timeout_graceful_shutdown=GRACEFUL_SHUTDOWN,
                        ))
                        await tg.start(_serve_http, server, sock)
                    for task in extra:
                        tg.start_soon(task, session,
                                      name=f"drivebus service: {getattr(task, '__name__', task)}")
                    try:
                        yield service
                    finally:
                        tg.cancel_scope.cancel()
            finally:
                # Anything a request started while the server was closing stops here too.
                with anyio.CancelScope(shield=True), anyio.move_on_after(STOP_TIMEOUT):
                    service.stopped.update(await session.stop_all())
                    service.rest = _rest(session)
    finally:
        if sock is not None:
            sock.close()


async def serve(
    config: str | Path | MachineConfig,
    *,
    host: str = "127.0.0.1",
    port: int = 8000,
    tokens: TokenStore | None = None,
    token_file: str | Path | None = None,
    http: bool = True,
    extra: Sequence[SiblingTask] = (),
    say: Callable[[str], object] = print,
    on_stop: Callable[[Service], object] | None = None,
    also: str = "",
) -> None:
    """Serve until cancelled (see ``open_service``); ``say`` gets one line when it is
    ready (with ``also``: what else runs, e.g. the MQTT bridge and where) and one after
    it stopped every moving axis, ``on_stop`` the ended service.

    Served from a machine file, its URL is published under that file (``drivebus.runtime``)
    so that one-shot commands on the same file talk to this process, the line's one owner.
    """
    service: Service | None = None
    file = None
    if not isinstance(config, MachineConfig):
        file = str(await anyio.Path(config).resolve())
    try:
        async with open_service(config, host=host, port=port, tokens=tokens,
                                token_file=token_file, http=http, extra=extra) as service:
            heap.settle()  # (start-up is over, before it says it is ready: drivebus.heap)
            where = f"on {service.url}/ (API /api, docs /docs)" if service.url else "without HTTP"
            entries = {file: [service.url]} if file and service.url else {}
            with runtime.publish("serve", entries) as problems:
                for p in problems:
                    say(f"drivebus serve: warning: {p}")
                say(f"drivebus serve: machine {service.session.name} {where}; "
                    + (f"{also}; " if also else "") + "Ctrl-C or SIGTERM stops it")
                systemd.notify(f"READY=1\nSTATUS=serving {service.session.name} {where}")
                try:
                    period = systemd.watchdog_period()
                    if period is None:
                        await anyio.sleep_forever()
                    else:  # fed from the event loop: a hung loop is restarted by systemd
                        await systemd.feed_watchdog(period)
                finally:
                    # the shutdown begins: stopping the axes may take up to TimeoutStopSec
                    systemd.notify("STOPPING=1\nSTATUS=stopping every moving axis")
    finally:
        if service is not None:
            say(report(service))
            if on_stop is not None:
                on_stop(service)


def report(service: Service) -> str:
    """One line: what the shutdown stopped and whether every axis is at rest."""
    parts = []
    for name, outcome in service.stopped.items():
        pos = service.rest.get(name, {}).get("position")
        where = "" if pos is None else f" at {pos:.3f}"
        parts.append(f"{name}{where}" if outcome is None
                     else f"{name} FAILED ({outcome['type']}: {outcome['message']})")
    stopped = f"stopped {', '.join(parts)}" if parts else "no axis was moving"
    twins = any("twin_moving" in r for r in service.rest.values())
    rest = ("every axis at rest" + (" (simulated twins checked)" if twins else "")
            if service.at_rest else
            "NOT at rest: " + ", ".join(n for n, r in service.rest.items()
                                        if r["moving"] or r.get("twin_moving")))
    return f"drivebus serve: {stopped}; {rest}"


def run(
    config: str | Path | MachineConfig,
    *,
    host: str = "127.0.0.1",
    port: int = 8000,
    token_file: str | Path | None = None,
    http: bool = True,
    extra: Sequence[SiblingTask] = (),
    also: str = "",
) -> int:
    """``drivebus serve``: serve until SIGINT or SIGTERM, then stop every moving axis and
    return the exit status (0; 1 if an axis could not be brought to rest); ``also`` goes
    in the start line. Bad arguments raise ``ConfigError`` before anything is opened."""
    tokens = TokenStore.load(token_file) if token_file is not None else TokenStore()
    if http:
        check_host(host, tokens)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    logging.getLogger("uvicorn.error").setLevel(logging.WARNING)
    ended: list[Service] = []

    def say(text: str) -> None:
        print(text, flush=True)

    async def main() -> None:
        with anyio.open_signal_receiver(signal.SIGINT, signal.SIGTERM) as signals:
            async with anyio.create_task_group() as tg:

                async def watch() -> None:
                    async for sig in signals:
                        say(f"drivebus serve: {signal.Signals(sig).name}: stopping")
                        tg.cancel_scope.cancel()
                        return

                tg.start_soon(watch)
                await serve(config, host=host, port=port, tokens=tokens, http=http,
                            extra=extra, say=say, on_stop=ended.append, also=also)

    anyio.run(main)
    return 0 if ended and ended[0].at_rest else 1
