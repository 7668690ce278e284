"""Serving a machine's simulated lines to outside masters (``drivebus sim``).

The simulators run in this process; each simulated line is published in a per-user
runtime directory under its ``sim://`` name: a serial line's pty path and its format
channel, a TCP line's loopback address. So ``SerialLine("sim://NAME")``, ``drivebus scan
sim://NAME`` and a machine file's ``sim://NAME`` line in another process reach it.

A pty carries baud rate and stop bits but not parity or byte size, so a drivebus master in
another process tells the wire the format it set through the line's format channel (a
Unix socket: ``F 8 E`` answered by ``ok``) before its next frame; outside masters (mbpoll,
a PLC) are taken to send 8 data bits without parity. Output goes to ``echo``.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import itertools
import math
import os
import secrets
import socket
import struct
import sys
import tempfile
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

import anyio
import anyio.abc
import anyio.streams.buffered

from drivebus import runtime
from drivebus.config import MachineConfig, load_config, machine_config_in_thread
from drivebus.errors import ConfigError, DrivebusError
from drivebus.sim.drive import SimDrive
from drivebus.sim.machine import SimLine, start_simulators
from drivebus.sim.masters import describe_process, pty_holders, second_master
from drivebus.sim.wire import VirtualWire, WireFrame
from drivebus.tasks import ServiceTasks

__all__ = [
    "CONSOLE_HELP",
    "PublishedSim",
    "ask_running_sim",
    "console_answer",
    "describe",
    "find_twin",
    "frame_text",
    "power_cycle",
    "publish",
    "published",
    "published_sim",
    "serve_simulators",
]


def _say(text: str) -> None:
    print(text, flush=True)


def _warn(text: str) -> None:
    print(f"warning: {text}", file=sys.stderr, flush=True)


@dataclass(frozen=True)
class PublishedSim:
    """Where a running ``drivebus sim`` serves one ``sim://`` line."""

    kind: str
    """"serial" (a pty) or "tcp" (a loopback TCP port: Modbus TCP or RTU over TCP)."""
    where: str
    """The pty path, or ``127.0.0.1:PORT``."""
    channel: str | None = None
    """A serial line's format channel (a Unix socket path), if it has one."""

    @property
    def host_port(self) -> tuple[str, int]:
        """A TCP line's host and port."""
        host, _, port = self.where.rpartition(":")
        return host, int(port)


def published(name: str) -> PublishedSim | None:
    """Where a running ``drivebus sim`` serves ``sim://name``, if one does."""
    found = runtime.lookup("sim", name)
    if not found:
        return None
    if found[0].startswith("tcp "):
        return PublishedSim("tcp", found[0].removeprefix("tcp "))
    if not Path(found[0]).exists():
        return None
    channel = found[1] if len(found) > 1 and Path(found[1]).exists() else None
    return PublishedSim("serial", found[0], channel)


def published_sim(name: str) -> str | None:
    """The pty path a running ``drivebus sim`` serves ``sim://name`` on, if one does."""
    found = published(name)
    return found.where if found is not None and found.kind == "serial" else None


def _channel_path(name: str) -> Path:
    """A short path (Unix socket paths are limited to 107 bytes) unique to this user's
    runtime directory and the line's name."""
    key = f"{runtime.runtime_dir('sim')}/{name}".encode()
    return Path(tempfile.gettempdir()) / f"drivebus-{hashlib.sha256(key).hexdigest()[:20]}.sock"


def _peer_pid(stream: anyio.abc.SocketStream) -> int | None:
    """The process at the other end of a Unix socket (its credentials), if known."""
    sock = stream.extra(anyio.abc.SocketAttribute.raw_socket)
    try:
        creds = sock.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, struct.calcsize("3i"))
    except (OSError, AttributeError):  # SO_PEERCRED is Linux's
        return None
    pid, _, _ = struct.unpack("3i", creds)
    return pid or None


async def _take_seat(wire: VirtualWire, holder: object, pid: int | None) -> str | None:
    """Seat the master at the far end of a format channel (process ``pid``): None, or why
    not (the line's master, or a process with the pty open that took no seat)."""
    who = describe_process(pid) if pid is not None else "a process"
    refused = wire.seat.take(holder, who)
    if refused is not None:
        # the master that has it may have closed its port a moment ago: let its end come
        for _ in range(50):
            await anyio.sleep(0.01)
            if wire.seat.holder is None:
                refused = wire.seat.take(holder, who)
                break
    if refused is not None:
        return refused
    others = await anyio.to_thread.run_sync(
        pty_holders, wire.slave_path, {os.getpid(), *([pid] if pid else [])})
    if others:
        wire.seat.free(holder)
        return second_master(wire.seat.line, ", ".join(map(describe_process, others)))
    return None


async def _follow_formats(
    wire: VirtualWire, stream: anyio.abc.SocketStream, pending: bytes,
) -> None:
    """The seated master's later formats (``f 8 E``, not answered), until it closes its
    port: read whenever the channel has data and before every read of the pty
    (``VirtualWire.format_source``), so a frame is judged at the format its master set
    before sending it, and the master never waits for this process's event loop."""
    sock = stream.extra(anyio.abc.SocketAttribute.raw_socket)
    buffer = bytearray(pending)

    def drain() -> bool:
        """Apply every whole message the channel holds; False once the master is gone."""
        open_ = True
        while True:
            try:
                chunk = sock.recv(4096)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                open_ = False
                break
            if not chunk:
                open_ = False
                break
            buffer.extend(chunk)
        while (end := buffer.find(b"\n")) >= 0:
            parts = buffer[:end].decode(errors="replace").split()
            del buffer[:end + 1]
            if len(parts) == 3 and parts[0] in ("f", "F") and parts[1].isdigit():
                wire.note_format(int(parts[1]), parts[2])
        if len(buffer) > 256:  # junk without an end: the channel is not a master's
            open_ = False
        return open_

    wire.format_source = drain
    try:
        while drain():
            await anyio.wait_readable(sock)
    finally:
        wire.format_source = None


async def _serve_format_channel(
    wire: VirtualWire, path: Path, control: Callable[[str], str] | None = None,
    ready: anyio.Event | None = None,
) -> None:
    """Answer the messages of other processes until cancelled: a master's format (``F 8
    E``, answered ``ok``; forgotten when that master closes its port; the first seats the
    master, one per line: another is answered ``busy`` and why) and a power cycle (``P
    AXIS|ADDRESS``, from ``drivebus sim CONFIG --power-cycle``: ``ok`` and where the drive
    answers now, or ``error`` and why); ``ready`` is set once the socket listens."""

    async def client(stream: anyio.abc.SocketStream) -> None:
        buffered = anyio.streams.buffered.BufferedByteReceiveStream(stream)
        seated = False
        try:
            async with stream:
                while True:
                    line = await buffered.receive_until(b"\n", 256)
                    parts = line.decode(errors="replace").split()
                    if len(parts) == 3 and parts[0] == "F" and parts[1].isdigit():
                        if not seated:
                            refused = await _take_seat(wire, stream, _peer_pid(stream))
                            if refused is not None:
                                await stream.send(f"busy {refused}\n".encode())
                                return
                            seated = True
                        wire.note_format(int(parts[1]), parts[2])
                        await stream.send(b"ok\n")
                        await _follow_formats(wire, stream, buffered.buffer)
                        return
                    elif len(parts) == 2 and parts[0] == "P" and control is not None:
                        try:
                            answer = f"ok {control(parts[1])}"
                        except ConfigError as exc:
                            answer = f"error {exc}"
                        await stream.send(answer.encode() + b"\n")
                    else:
                        await stream.send(b"error\n")
        except (anyio.EndOfStream, anyio.IncompleteRead, anyio.DelimiterNotFound,
                anyio.BrokenResourceError, anyio.ClosedResourceError):
            pass  # the master closed its port (or sent junk): the channel ends
        finally:
            if seated:
                wire.seat.free(stream)
                wire.forget_format()

    await anyio.Path(path).unlink(missing_ok=True)
    listener = await anyio.create_unix_listener(path)
    if ready is not None:
        ready.set()
    try:
        await listener.serve(client)
    finally:
        with anyio.CancelScope(shield=True):
            await anyio.Path(path).unlink(missing_ok=True)


async def serve_format_channel(wire: VirtualWire, stack: contextlib.AsyncExitStack) -> str:
    """Answer the format messages of a master in another process (a machine's worker)
    for ``wire`` until ``stack`` closes; the Unix socket's path (private to this
    process: nothing is published)."""
    path = Path(tempfile.gettempdir()) / f"drivebus-{os.getpid()}-{secrets.token_hex(6)}.sock"
    tasks = await stack.enter_async_context(ServiceTasks())
    ready = anyio.Event()

    async def serve() -> None:
        await _serve_format_channel(wire, path, ready=ready)

    tasks.start_soon(serve, name=f"sim wire {wire.name} format channel")
    await ready.wait()
    return str(path)


@contextlib.contextmanager
def publish(
    sims: dict[str, SimLine], warn: Callable[[str], None] = _warn
) -> Iterator[None]:
    """Publish where each simulated line is served (a serial line's pty path and format
    channel, a TCP line's address) for other processes; removed on exit (a line that
    cannot be published is a warning, not an error)."""
    entries: dict[str, list[str]] = {}
    for s in sims.values():
        if isinstance(s.server, VirtualWire):
            entries[s.config.sim_name] = [s.endpoint, str(_channel_path(s.config.sim_name))]
        else:
            entries[s.config.sim_name] = [f"tcp {s.endpoint}"]
    with runtime.publish("sim", entries) as problems:
        for p in problems:
            warn(p)
        yield


def find_twin(sims: Mapping[str, SimLine], what: str) -> tuple[str, SimLine, SimDrive]:
    """The twin ``what`` names: an axis, or the address a drive answers at now on a serial
    line (axis, line, twin); ``ConfigError`` naming the axes otherwise."""
    for s in sims.values():
        if what in s.twins:
            return what, s, s.twins[what]
    hits = [(axis, s, t) for s in sims.values() if s.config.kind != "tcp"
            for axis, t in s.twins.items() if what.isdigit() and t.address == int(what)]
    if len(hits) == 1:
        return hits[0]
    axes = ", ".join(a for s in sims.values() for a in s.twins)
    if hits:
        raise ConfigError(f"address {what} answers on lines "
                          f"{', '.join(s.name for _, s, _ in hits)}: name the axis ({axes})")
    raise ConfigError(f"no axis {what!r}" + (" and no drive at that address" if what.isdigit()
                                             else "") + f" (axes: {axes})")


def power_cycle(sims: Mapping[str, SimLine], what: str) -> str:
    """Switch the drive ``what`` names (an axis, or the address it answers at) off and on
    again (``SimDrive.power_cycle``); the line that says where it answers now."""
    axis, s, twin = find_twin(sims, what)
    twin.power_cycle()
    where = (f"unit {twin.address}" if s.config.kind == "tcp"
             else f"address {twin.address} at {twin.settings}")
    return f"power-cycled axis {axis} ({twin.family}): it answers at {where} on line {s.name}"


CONSOLE_HELP = ("type `power-cycle AXIS` (or the address it answers at) to switch a drive "
                "off and on, `help` for this")


def console_answer(sims: Mapping[str, SimLine], text: str) -> str | None:
    """The answer to one line typed on ``drivebus sim``'s console (None: an empty line)."""
    words = text.split()
    if not words:
        return None
    if words[0] in ("power-cycle", "power_cycle") and len(words) == 2:
        try:
            return power_cycle(sims, words[1])
        except ConfigError as exc:
            return f"error: {exc}"
    if words[0] in ("help", "?") and len(words) == 1:
        return CONSOLE_HELP
    return f"error: not a command: {text.strip()!r}; {CONSOLE_HELP}"


async def _console(sims: Mapping[str, SimLine], echo: Callable[[str], None]) -> None:
    """Answer what the technician types at the terminal ``drivebus sim`` runs in, until
    the terminal closes (only with stdin a terminal: a pipe it inherited is not read)."""
    fd = sys.stdin.fileno()
    echo(f"console: {CONSOLE_HELP}")
    pending = b""
    while True:
        await anyio.wait_readable(fd)
        data = os.read(fd, 4096)
        if not data:
            return
        pending += data
        while b"\n" in pending:
            line, pending = pending.split(b"\n", 1)
            answer = console_answer(sims, line.decode(errors="replace"))
            if answer is not None:
                echo(answer)


def ask_running_sim(config: str | Path, what: str) -> str:
    """Power-cycle the drive ``what`` names (an axis, or an address) in the running
    ``drivebus sim`` of ``config``, through a serial line's channel; what it answered
    (``ConfigError`` if no sim of the file runs, or it refused)."""
    cfg = load_config(config)
    found = [p for ln in cfg.lines.values() if ln.simulated
             and (p := published(ln.sim_name)) is not None and p.channel is not None]
    if not found:
        raise ConfigError(f"no drivebus sim of {config} is running with a serial line "
                          f"(start it with `drivebus sim {config}`; a TCP-only machine's "
                          f"drives are power-cycled at its console)")
    channel = found[0].channel
    assert channel is not None
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
            sock.settimeout(5.0)
            sock.connect(channel)
            sock.sendall(f"P {what}\n".encode())
            answer = b""
            while not answer.endswith(b"\n"):
                chunk = sock.recv(4096)
                if not chunk:
                    break
                answer += chunk
    except OSError as exc:
        raise DrivebusError(f"the drivebus sim of {config} does not answer on {channel}: "
                            f"{exc}") from None
    text = answer.decode(errors="replace").strip()
    if not text.startswith("ok "):
        raise ConfigError(text.removeprefix("error").strip() or "the sim refused it")
    return text.removeprefix("ok ")


def describe(sim: SimLine, cfg: MachineConfig) -> list[str]:
    """``line NAME KIND WHERE`` and one line per slave on it."""
    kind = sim.config.kind
    lines = [f"line {sim.name} {kind} {sim.endpoint}"]
    for axis, twin in sim.twins.items():
        ac = cfg.axes[axis]
        where = "unit" if kind == "tcp" else "slave"
        settings = "" if kind == "tcp" else f" {twin.settings}"
        lines.append(f"  {where} {twin.address} {ac.drive}{settings} (axis {axis})")
    return lines


def frame_text(line: str, f: WireFrame) -> str:
    """One frame of a wire log as a line (the silence before it in ms, or in s when the
    line was idle for a second or more)."""
    note = f" [{f.note}]" if f.note else ""
    if math.isinf(f.gap):
        gap = "none-before"  # the first frame since the wire started
    else:
        gap = f"{f.gap * 1000:.2f}ms" if f.gap < 1.0 else f"{f.gap:.1f}s"
    return (f"{f.start:.6f} {line} {f.direction:<7} addr={f.address} "
            f"{str(f.settings).replace(' ', '-')} gap={gap} "
            f"{f.data.hex(' ')}{note}")


_LOOK_EVERY = 2.0
"""Seconds between two looks at a served line for frames that collided."""
_TROUBLE = frozenset({"collision", "gap violation", "incomplete"})
"""Notes of frames that two masters on one line leave in the wire log."""


async def _watch_for_masters(
    sim: SimLine, wire: VirtualWire, warn: Callable[[str], None]
) -> None:
    """Say when a second master is on the line: when frames collided since the last look
    and more than one process has the line's pty open (a master that took no seat, such
    as mbpoll on the pty, beside the one that did); once per set of processes."""
    seen, told = wire.frames, frozenset[int]()
    while True:
        await anyio.sleep(_LOOK_EVERY)
        new, seen = wire.frames - seen, wire.frames
        if new <= 0 or not any(f.note in _TROUBLE for f in itertools.islice(
                reversed(wire.log), min(new, 2000))):
            continue
        holders = frozenset(await anyio.to_thread.run_sync(
            pty_holders, wire.slave_path, {os.getpid()}))
        if len(holders) > 1 and holders != told:
            told = holders
            warn(f"sim://{sim.config.sim_name} (line {sim.name}) has {len(holders)} masters: "
                 f"{', '.join(describe_process(p) for p in sorted(holders))} have it open and "
                 f"their frames collide; one master per line")


async def _echo_wire_log(name: str, wire: VirtualWire, echo: Callable[[str], None]) -> None:
    seen = wire.frames
    while True:
        await wire.wait_frames(seen + 1)
        new = wire.frames - seen
        seen = wire.frames
        for f in list(wire.log)[-new:]:
            echo(frame_text(name, f))


async def serve_simulators(
    config: str | Path,
    *,
    log: bool = False,
    echo: Callable[[str], None] = _say,
    warn: Callable[[str], None] = _warn,
    console: bool = True,
) -> None:
    """Serve the ``sim://`` lines of ``config`` (a twin per axis) until cancelled; with
    ``console`` and a terminal on stdin, answer what is typed there (``power-cycle z``)."""
    cfg = await machine_config_in_thread(config)  # parsing descriptions: off the loop
    for ln in cfg.lines.values():
        if ln.simulated and (other := published(ln.sim_name)):
            raise DrivebusError(
                f"{ln.port or ln.host} is already served by another drivebus sim, on "
                f"{other.where}: use that one, or stop it first"
            )
    async with contextlib.AsyncExitStack() as stack:
        sims = await start_simulators(cfg, stack)
        if not sims:
            raise ConfigError(f"{config}: no sim:// lines: nothing to simulate")
        async with anyio.create_task_group() as tg:
            # The format channels listen before the lines are published: a master that
            # finds a line at once gets its parity through (else it would open the pty
            # without its channel, and a drive at 8E1 would not answer it).
            for s in sims.values():
                if isinstance(s.server, VirtualWire):
                    listening = anyio.Event()
                    tg.start_soon(functools.partial(
                        _serve_format_channel, s.server, _channel_path(s.config.sim_name),
                        functools.partial(power_cycle, sims), ready=listening))
                    await listening.wait()
            with publish(sims, warn):
                for s in sims.values():
                    for text in describe(s, cfg):
                        echo(text)
                echo(f"simulating machine {cfg.name}: Ctrl-C or SIGTERM ends it")
                try:
                    for s in sims.values():
                        if isinstance(s.server, VirtualWire):
                            tg.start_soon(_watch_for_masters, s, s.server, warn)
                    if console and sys.stdin is not None and sys.stdin.isatty():
                        tg.start_soon(_console, sims, echo)
                    if log:
                        for s in sims.values():
                            if isinstance(s.server, VirtualWire):
                                tg.start_soon(_echo_wire_log, s.name, s.server, echo)
                    await anyio.sleep_forever()
                finally:
                    for s in sims.values():
                        for axis, twin in s.twins.items():
                            echo(f"twin {axis}: position={twin.position()} pulses "
                                 f"moving={twin.is_moving()}")
