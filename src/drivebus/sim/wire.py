"""VirtualWire: a simulated RS-485 line behind a pty, with wire time and a wire log.

The master opens ``sim://NAME`` (or the pty path) with the real serial stack. The wire
reads the pty's master side and feeds what it reads to its ``Segment``, which plays every
attached ``SimSlave`` and logs the frames. The wire's own part is the transport:

* it observes the settings the master really set: baud rate and stop bits from the pty's
  termios (the kernel carries them across a pty), parity and byte size from the sim port
  class's side channel (a pty drops them) — never from the master's own bookkeeping;
* it writes the slaves' replies to the pty (and, with ``echo``, every master byte back);
* with ``babbling()`` a device on the wire sends junk without pause (a fault to inject).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import termios
import tty
from collections.abc import AsyncIterator, Awaitable, Callable, Collection
from types import TracebackType

import anyio

from drivebus.clock import monotonic
from drivebus.errors import ConfigError
from drivebus.line.baud import port_baudrate
from drivebus.settings import LineSettings
from drivebus.sim.masters import MasterSeat
from drivebus.sim.noise import babble_flat_out, babble_paced
from drivebus.sim.segment import Segment, SegmentView, WireFrame
from drivebus.sim.slave import SimSlave
from drivebus.tasks import ServiceTasks
from drivebus.timing import timing

__all__ = ["VirtualWire", "WireFrame", "lookup_wire"]

_REGISTRY: dict[str, VirtualWire] = {}

_SPEEDS = {
    getattr(termios, name): int(name[1:])
    for name in dir(termios)
    if name[:1] == "B" and name[1:].isdigit() and int(name[1:]) >= 50
}


def lookup_wire(name: str) -> VirtualWire:
    """The running wire called ``name``; KeyError if there is none."""
    return _REGISTRY[name]


class VirtualWire(SegmentView):
    """A simulated RS-485 line; use as ``async with VirtualWire("name") as wire``."""

    def __init__(
        self,
        name: str,
        *,
        echo: bool = False,
        strict: bool = True,
        log_size: int = 200_000,
        adapter_bauds: Collection[int] | None = None,
        adapter_formats: Collection[str] | None = None,
        adapter_latency: float = 0.0,
    ) -> None:
        self.name = name
        self.echo = echo
        """Send every master byte back, as adapters that hear their own transmitter do."""
        self.adapter_latency = adapter_latency
        """The master's simulated USB adapter holds received bytes until its latency timer
        ticks (every ``adapter_latency`` s; FTDI's default is 16 ms), as ftdi_sio does
        unless the port is in low-latency mode; 0: bytes pass at once."""
        self.adapter_bauds = tuple(sorted(adapter_bauds)) if adapter_bauds else None
        """The baud rates the master's simulated adapter can generate (None: any). Asked for
        another one, its driver runs (and reports) the nearest, as USB adapters' drivers do."""
        self.adapter_formats = frozenset(adapter_formats) if adapter_formats else None
        """The character formats (``8N1``...) the master's simulated port accepts (None: any);
        asked for another one, setting the port fails with EINVAL, as ``tcsetattr`` does on
        ports (and kernels' ptys) that refuse parity."""
        self.segment: Segment[None] = Segment(
            self._to_master,
            self.observed_settings,
            where=f"wire {name!r}",
            log_size=log_size,
            strict=strict,
        )
        self.seat = MasterSeat(f"sim://{name}")
        """The line's one master (``drivebus.sim.masters``): a second one is refused."""
        self.slave_path = ""
        self._master_fd = -1
        self._slave_fd = -1
        self._format: tuple[int, str] | None = None  # (bytesize, parity) from the side channel
        self.format_source: Callable[[], object] | None = None
        """Reads a master's pending format messages (a master in another process, through
        the line's format channel): called before every read of the pty."""
        self._observed: dict[tuple[int, int, str, int], LineSettings] = {}
        self._stack = contextlib.AsyncExitStack()

    # -- set-up -------------------------------------------------------------------------

    @property
    def slaves(self) -> dict[int, SimSlave]:
        """The slaves on the wire, by address."""
        return self.segment.slaves

    def attach(self, slave: SimSlave) -> SimSlave:
        """Put ``slave`` on the wire; its address must be free."""
        return self.segment.attach(slave)

    @property
    def url(self) -> str:
        """The URL a ``SerialLine`` opens to reach this wire."""
        return f"sim://{self.name}"

    async def __aenter__(self) -> VirtualWire:
        if self.name in _REGISTRY:
            raise ConfigError(
                f"sim://{self.name}: a simulated line of that name is already running in "
                f"this process: give each simulated line its own name"
            )
        async with contextlib.AsyncExitStack() as stack:  # undone in reverse by __aexit__
            self._master_fd, self._slave_fd = os.openpty()
            stack.callback(os.close, self._slave_fd)
            stack.callback(os.close, self._master_fd)
            tty.setraw(self._slave_fd)
            self.slave_path = os.ttyname(self._slave_fd)
            os.set_blocking(self._master_fd, False)
            _REGISTRY[self.name] = self
            stack.callback(_REGISTRY.pop, self.name, None)
            stack.callback(self.segment.close)
            tasks = await stack.enter_async_context(ServiceTasks())  # answers while users clean up
            tasks.start_soon(self.segment.run, name=f"sim wire {self.name} replies")
            loop = asyncio.get_running_loop()
            loop.add_reader(self._master_fd, self._on_readable)
            stack.callback(loop.remove_reader, self._master_fd)
            self._stack = stack.pop_all()
        return self

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None,
        tb: TracebackType | None,
    ) -> bool:
        return await self._stack.__aexit__(exc_type, exc, tb)

    # -- what the master set --------------------------------------------------------------

    def adapter_baud(self, baudrate: int) -> int:
        """The rate the simulated adapter runs when asked for ``baudrate``."""
        if self.adapter_bauds is None:
            return baudrate
        return min(self.adapter_bauds, key=lambda b: abs(b - baudrate))

    def note_format(self, bytesize: int, parity: str) -> None:
        """Side channel from the sim port class: the byte size and parity it configured."""
        self._format = (int(bytesize), str(parity))

    def forget_format(self) -> None:
        """The master that told the format is gone: an outside master (mbpoll, a PLC) is
        taken to send 8 data bits without parity again."""
        self._format = None

    def observed_settings(self) -> LineSettings:
        """The line settings the master's port has right now."""
        attrs = termios.tcgetattr(self._master_fd)  # the slave side's termios
        # termios2 carries any rate (BOTHER); the classic speed codes only the standard ones
        baud = port_baudrate(self._master_fd) or _SPEEDS.get(attrs[5], 0) or 38400
        stop = 2 if attrs[2] & termios.CSTOPB else 1
        bytesize, parity = self._format or (8, "N")
        key = (baud, bytesize, parity, stop)
        settings = self._observed.get(key)
        if settings is None:  # one object per setting seen: no model built per frame
            settings = self._observed[key] = LineSettings(
                baudrate=baud, bytesize=bytesize, parity=parity, stopbits=stop
            )
        return settings

    # -- the pty --------------------------------------------------------------------------------

    def _on_readable(self) -> None:
        now = monotonic()
        try:
            data = os.read(self._master_fd, 4096)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            return  # EIO: nobody has the pty open right now
        if not data:
            return
        if self.echo:
            os.write(self._master_fd, data)
        if self.format_source is not None:
            self.format_source()
        self.segment.feed(data, now, self.observed_settings(), None)

    def _to_master(self, data: bytes, _route: None) -> Awaitable[None] | None:
        """Hand a reply to the master's side of the pty now, or (an adapter with a latency
        timer) return what holds it until the timer's next tick and then hands it."""
        if self.adapter_latency > 0:
            return self._held_to_master(data)
        self._write_to_master(data)
        return None

    async def _held_to_master(self, data: bytes) -> None:
        now = monotonic()
        await anyio.sleep(math.ceil(now / self.adapter_latency) * self.adapter_latency - now)
        self._write_to_master(data)

    def _write_to_master(self, data: bytes) -> None:
        try:
            os.write(self._master_fd, data)
        except OSError:
            return  # master closed its side; a real wire just carries it to nobody

    # -- noise ---------------------------------------------------------------------------------

    @contextlib.asynccontextmanager
    async def babbling(
        self, settings: LineSettings | None = None, *, flat_out: bool = False
    ) -> AsyncIterator[None]:
        """While inside, a device on the wire sends junk without pause: at the character
        rate of ``settings`` (default: the master's settings now), the wire never quiet
        for t1.5; or, ``flat_out``, as fast as the pty takes it. Frames under way collide
        with it; ``noise_bytes`` counts it."""
        async with anyio.create_task_group() as tg:
            if flat_out:
                tg.start_soon(babble_flat_out, self._noise_flat_out, name=f"{self.name} babbler")
            else:
                tm = timing(settings or self.observed_settings())
                tg.start_soon(babble_paced, self._noise, tm, name=f"{self.name} babbler")
            try:
                yield
            finally:
                tg.cancel_scope.cancel()

    async def _noise(self, data: bytes) -> None:
        try:
            n = os.write(self._master_fd, data)
        except OSError:
            return  # pty full (bytes lost, as in an overrun) or nobody has it open
        self.segment.noise(n, monotonic())

    async def _noise_flat_out(self, data: bytes) -> None:
        await self._noise(data)
        loop = asyncio.get_running_loop()
        writable: asyncio.Future[None] = loop.create_future()
        loop.add_writer(self._master_fd, _set_done, writable)
        try:
            await writable  # the pty has room again (the master read some)
        finally:
            loop.remove_writer(self._master_fd)


def _set_done(future: asyncio.Future[None]) -> None:
    if not future.done():
        future.set_result(None)
