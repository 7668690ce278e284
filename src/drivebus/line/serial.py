"""SerialLine: Modbus RTU on an RS-485 port, with the silences timed on the wire."""

from __future__ import annotations

import asyncio
import os
import termios
from collections.abc import Coroutine
from typing import Any

import serial
import serial.rs485
import serial_asyncio

from drivebus.clock import monotonic
from drivebus.errors import ConfigError, LineClosed, LineConfigError
from drivebus.line.base import Exchange, Line
from drivebus.line.baud import port_baudrate, rate_matches
from drivebus.line.link import Begun, ReplyHook, RtuJob, RtuLink
from drivebus.line.receiver import RtuReceiver
from drivebus.pdu import LengthPredictor
from drivebus.providers import line_provider, scheme_of
from drivebus.settings import LineSettings
from drivebus.timing import Timing, switch_silence, timing

__all__ = ["SerialLine"]

_PARITY = {"N": serial.PARITY_NONE, "E": serial.PARITY_EVEN, "O": serial.PARITY_ODD}


class _Transport(serial_asyncio.SerialTransport):
    """pyserial-asyncio's transport, reading the non-blocking descriptor directly.

    pyserial's ``read`` runs a ``select`` and builds timeout objects on every call; on
    the hot path one ``os.read`` per readable event is all that is needed.
    """

    def _read_ready(self) -> None:
        try:
            data = os.read(self._serial.fd, self._max_read_size)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            self._close(exc=serial.SerialException(f"read failed: {exc}"))
            return
        if data:
            self._protocol.data_received(data)


def _ask_low_latency(port: serial.Serial) -> bool:
    """Ask the port for low-latency mode (``ASYNC_LOW_LATENCY`` through TIOCSSERIAL, which
    ftdi_sio turns into a 1 ms latency timer instead of its default 16 ms, and other USB
    serial drivers into prompt delivery): True if it took it. Ports that refuse it (a pty,
    a driver without the ioctl, no permission) go on as they are, silently."""
    ask = getattr(port, "set_low_latency_mode", None)
    if ask is None:
        return False
    try:
        ask(True)
    except (ValueError, OSError, termios.error):
        return False
    return True


class SerialLine(Line):
    """An RS-485 line on a serial port (a device, a pty, or ``sim://NAME``).

    ``settings`` are the line's defaults; a transaction may ask for others (per-slave
    baud/format) and the port is then reconfigured in place after the longer silence.
    """

    per_slave_settings = True
    counts_garbage = True
    waits_for_silence = True
    begins = True
    settings: LineSettings

    def __init__(
        self,
        port: str,
        settings: LineSettings | None = None,
        *,
        local_echo: bool = False,
        rs485: bool = False,
        broadcast_delay: float = 0.1,
    ) -> None:
        self.port = port
        self.name = port
        self.settings = settings or LineSettings()
        self.local_echo = local_echo
        self.rs485 = rs485
        if broadcast_delay < 0:
            raise ConfigError("broadcast_delay must be >= 0 seconds")
        self.broadcast_delay = broadcast_delay
        self._rx: RtuReceiver | None = None
        self._serial: serial.Serial | None = None
        self._current: LineSettings | None = None
        self._link = RtuLink()
        self._send_cb = self._send  # (one bound method, not one per transaction)
        self._closed = True
        self._fd = -1
        self._garbage_closed = 0  # counted by receivers of earlier openings
        self._canon: dict[int, tuple[LineSettings, LineSettings, Timing]] = {}
        self.low_latency: bool | None = None
        """Whether the port took low-latency mode when it opened (None: not opened yet)."""

    def _canonical(self, settings: LineSettings | None) -> LineSettings:
        """One object per distinct setting: every slave handle has its own (equal) settings
        object, and comparing models field by field on each transaction costs more than
        the rest of the silence bookkeeping; equal settings are then the same object."""
        return self._known(settings)[0]

    def _known(self, settings: LineSettings | None) -> tuple[LineSettings, Timing]:
        """The canonical object for ``settings`` (see ``_canonical``) and its timing."""
        if settings is None:
            settings = self.settings
        known = self._canon.get(id(settings))
        if known is not None and known[0] is settings:
            return known[1], known[2]
        same = next((c for _, c, _ in self._canon.values() if c == settings), settings)
        tm = timing(same)
        self._canon[id(settings)] = (settings, same, tm)  # keeps the object: its id stays
        return same, tm

    @property
    def garbage_bytes(self) -> int:
        """Bytes received outside any reply (late answers, noise), discarded, since the
        line was created."""
        rx = self._rx.garbage_bytes if self._rx is not None else 0
        return self._garbage_closed + rx

    @property
    def current_settings(self) -> LineSettings | None:
        """The settings the port is configured with right now."""
        return self._current

    async def open(self) -> None:
        """Open the port at the default settings."""
        s = self.settings
        loop = asyncio.get_running_loop()
        rx = RtuReceiver(f"serial port {self.port}", line_name=self.name)
        scheme = scheme_of(self.port)
        if scheme is not None:
            # SCHEME://NAME: a provider's port (the simulator's); loading the provider
            # teaches pyserial the URL.
            line_provider(scheme)
        try:
            port = serial.serial_for_url(
                self.port,
                baudrate=s.baudrate,
                bytesize=s.bytesize,
                parity=_PARITY[s.parity],
                stopbits=s.stopbits,
            )
        except (ValueError, termios.error) as exc:  # the port refused the settings
            raise ConfigError(self._cannot_run(s, exc)) from exc
        except (serial.SerialException, OSError) as exc:
            raise LineClosed(f"cannot open serial port {self.port!r}: {exc}") from exc
        actual = port_baudrate(port.fileno())
        if not rate_matches(s.baudrate, actual):
            port.close()
            raise ConfigError(self._cannot_run(s, f"its driver set {actual} baud"))
        try:  # the transport sets the port non-blocking: a second tcsetattr
            transport = _Transport(loop, rx, port)
        except (ValueError, termios.error) as exc:  # (a pty refuses parity here)
            port.close()
            raise ConfigError(self._cannot_run(s, exc)) from exc
        self.low_latency = _ask_low_latency(port)
        self._serial = port
        self._fd = port.fileno()
        rx.watch(self._fd)
        rx.on_foreign = self._heard_foreign
        self._rx = rx
        self._current = s
        if self.rs485:
            try:
                self._serial.rs485_mode = serial.rs485.RS485Settings()
            except (ValueError, OSError, termios.error, serial.SerialException) as exc:
                self._serial.rs485_mode = None
                transport.close()
                raise ConfigError(
                    f"serial port {self.port!r} does not support RS-485 mode (RTS direction "
                    f"control): {exc}; set rs485 = false if the adapter switches by itself"
                ) from exc
        self._link.quiet_since = monotonic()
        self._link.traffic = self._current = self._canonical(s)
        self._closed = False

    async def close(self) -> None:
        """Close the port; a waiting transaction fails with ``LineClosed``."""
        self._closed = True
        rx, self._rx = self._rx, None
        if rx is not None:
            self._garbage_closed += rx.garbage_bytes
            if rx.transport is not None:
                rx.transport.close()
                rx.connection_lost(None)
        self._link.close()
        self._serial = None
        if rx is not None and rx.transport is not None:
            # serial_asyncio closes the port from a loop callback: let it run, so that the
            # port is closed (free to open again) once this returns
            await asyncio.sleep(0)

    def _cannot_run(self, s: LineSettings, why: object) -> str:
        if s.parity != "N" and os.path.realpath(self.port).startswith("/dev/pts/"):
            return (f"serial port {self.port!r} cannot run {s} ({why}): it is a pty, which "
                    f"cannot carry parity; reach a drivebus sim by its sim://NAME instead "
                    f"(its format channel carries the parity)")
        return (f"serial port {self.port!r} cannot run {s} ({why}): use a baud rate and "
                f"format that the adapter and the drives support")

    def _apply(self, s: LineSettings) -> None:
        port = self._serial
        assert port is not None
        # Set all fields, then apply once: one tcsetattr, no close/reopen.
        port._baudrate = s.baudrate
        port._bytesize = s.bytesize
        port._parity = _PARITY[s.parity]
        port._stopbits = s.stopbits
        port._reconfigure_port()

    def _reconfigure(self, s: LineSettings, unit: int) -> None:
        """Switch the port to ``s``; ``LineConfigError`` (this request fails, the line goes
        on at its previous settings) if the port refuses them or runs another rate."""
        why: str | None = None
        try:
            self._apply(s)
        except (ValueError, OSError, termios.error) as exc:
            why = str(exc) or type(exc).__name__
        else:
            actual = port_baudrate(self._fd)
            if not rate_matches(s.baudrate, actual):
                why = f"its driver set {actual} baud"
        if why is not None:
            try:
                if self._current is not None:
                    self._apply(self._current)
            except (ValueError, OSError, termios.error) as exc:
                raise LineClosed(f"serial port {self.port!r} failed: {exc}") from exc
            raise LineConfigError(f"slave {unit}: {self._cannot_run(s, why)}", slave=unit)
        self._current = s

    def last_activity(self) -> float:
        """When the last frame sent or byte received ended."""
        q = self._link.quiet_since
        rx = self._rx
        return q if rx is None or rx.last_rx < q else rx.last_rx

    def ready_at(self, settings: LineSettings | None) -> float:
        """When the silence before a frame at ``settings`` will have passed."""
        silence = switch_silence(self._link.traffic, self._canonical(settings))
        return self._link.ready_at(self._rx, silence)

    def withdraw(self) -> bool:
        """Take back the request waiting for its silence, if its frame is not out yet."""
        return self._link.withdraw()

    def _send(self, adu: bytes) -> None:
        try:
            written = os.write(self._fd, adu)
        except BlockingIOError:
            written = 0
        if written < len(adu):
            assert self._rx is not None
            self._rx.send(adu[written:])

    def begin(  # (its arguments may be given in order: the bus does, per transaction)
        self,
        unit: int,
        pdu: bytes,
        expect: LengthPredictor | None,
        settings: LineSettings | None = None,
        timeout: float = 0.1,
        quiet_by: float | None = None,
        withdrawable: bool = False,
        on_reply: ReplyHook | None = None,
    ) -> Begun:
        """Start the transaction ``transact`` runs, without waiting for it (see
        ``Line.begin``); ``LineClosed``/``LineConfigError`` at once if it cannot start."""
        rx = self._rx
        if self._closed or rx is None:
            raise LineClosed(f"serial line {self.port} is closed")
        asked = self.settings if settings is None else settings
        known = self._canon.get(id(asked))
        if known is not None and known[0] is asked:
            target, tm = known[1], known[2]
        else:
            target, tm = self._known(asked)
        if target is not self._current:
            self._reconfigure(target, unit)
        link = self._link
        traffic = link.traffic
        return RtuJob(  # (``link.begin``, less its frame: positional, once per transaction)
            link, rx, self._send_cb, unit, pdu, expect, tm,
            tm.t35 if traffic is target else switch_silence(traffic, target),
            monotonic() + timeout if quiet_by is None else quiet_by, timeout,
            self.broadcast_delay, self.local_echo, withdrawable, on_reply)

    def finish(self, begun: Begun) -> Coroutine[Any, Any, Exchange]:
        """The exchange of a transaction of ``begin`` (a typed error if there is none)."""
        return self._link.finish(begun)

    def transact(  # a coroutine function: it returns the link's, one frame less per step
        self,
        unit: int,
        pdu: bytes,
        *,
        expect: LengthPredictor | None,
        settings: LineSettings | None = None,
        timeout: float = 0.1,
        quiet_by: float | None = None,
        withdrawable: bool = False,
        on_reply: ReplyHook | None = None,
    ) -> Coroutine[Any, Any, Exchange]:
        """Send one frame after the silence and, unless ``expect`` is None, read its reply
        by length (``LineNoise`` if the line is not quiet by ``quiet_by``); ``on_reply``
        is told of the exchange as soon as it is complete.

        The port is switched to ``settings`` before the silence, not after it: the
        silence is counted at the slower of the last frame's settings and these, and
        whatever arrives meanwhile is garbage at either rate; the switch is then off the
        path between the end of the silence and the first byte.
        """
        try:
            begun = self.begin(unit, pdu, expect=expect, settings=settings, timeout=timeout,
                               quiet_by=quiet_by, withdrawable=withdrawable,
                               on_reply=on_reply)
        except (LineClosed, LineConfigError) as exc:
            return _fail(exc)
        return self._link.finish(begun)

    def __repr__(self) -> str:
        return f"SerialLine({self.port!r}, {self.settings})"


async def _fail(exc: BaseException) -> Exchange:
    """A transaction refused before anything was sent: raises ``exc`` when awaited."""
    raise exc
