"""SerialLine: Modbus RTU on an RS-485 port, with the silences timed on the wire."""

from __future__ import annotations

import asyncio

import serial
import serial.rs485
import serial_asyncio

from drivebus.clock import PreciseTimer, monotonic
from drivebus.errors import (
    ConfigError,
    FrameError,
    LineClosed,
    ResponseTimeout,
    WrongResponder,
)
from drivebus.line.base import Exchange, Line
from drivebus.line.rtu import crc_ok, frame
from drivebus.pdu import LengthPredictor
from drivebus.settings import LineSettings
from drivebus.timing import switch_silence, timing

__all__ = ["SerialLine"]

if "drivebus.sim" not in serial.protocol_handler_packages:
    serial.protocol_handler_packages.append("drivebus.sim")  # sim://NAME virtual lines

_PARITY = {"N": serial.PARITY_NONE, "E": serial.PARITY_EVEN, "O": serial.PARITY_ODD}


class _Receiver(asyncio.Protocol):
    """Collects received bytes with the arrival time of the last one."""

    def __init__(self) -> None:
        self.buf = bytearray()
        self.last_rx = 0.0
        self.need = 0
        self.waiter: asyncio.Future[None] | None = None
        self.lost: BaseException | None = None
        self.transport: serial_asyncio.SerialTransport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def data_received(self, data: bytes) -> None:
        self.last_rx = monotonic()
        self.buf += data
        w = self.waiter
        if w is not None and len(self.buf) >= self.need and not w.done():
            w.set_result(None)

    def connection_lost(self, exc: Exception | None) -> None:
        self.lost = exc or LineClosed("serial port closed")
        w = self.waiter
        if w is not None and not w.done():
            w.set_exception(LineClosed(f"serial port lost: {self.lost}"))

    async def wait_for(self, n: int, deadline: float) -> bool:
        """Wait until ``n`` bytes are buffered; False if ``deadline`` passed first."""
        if len(self.buf) >= n:
            return True
        if self.lost is not None:
            raise LineClosed(f"serial port lost: {self.lost}")
        loop = asyncio.get_running_loop()
        w = self.waiter = loop.create_future()
        self.need = n
        handle = loop.call_at(_loop_time(loop, deadline), _expire, w)
        try:
            await w
        finally:
            handle.cancel()
            self.waiter = None
        return len(self.buf) >= n


def _expire(w: asyncio.Future[None]) -> None:
    if not w.done():
        w.set_result(None)


def _loop_time(loop: asyncio.AbstractEventLoop, t: float) -> float:
    # asyncio's loop clock is time.monotonic on every platform we support; keep the
    # conversion in one place in case a loop uses another clock.
    return t - monotonic() + loop.time()


class SerialLine(Line):
    """An RS-485 line on a serial port (a device, a pty, or ``sim://NAME``).

    ``settings`` are the line's defaults; a transaction may ask for others (per-slave
    baud/format) and the port is then reconfigured in place after the longer silence.
    """

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
        self._rx: _Receiver | None = None
        self._serial: serial.Serial | None = None
        self._current: LineSettings | None = None
        self._quiet_since = 0.0
        self._timer = PreciseTimer()
        self._closed = True
        self.garbage_bytes = 0
        """Bytes received outside any reply (late answers, noise), discarded."""

    @property
    def current_settings(self) -> LineSettings | None:
        """The settings the port is configured with right now."""
        return self._current

    async def open(self) -> None:
        """Open the port at the default settings."""
        s = self.settings
        loop = asyncio.get_running_loop()
        rx = _Receiver()
        try:
            transport, _ = await serial_asyncio.create_serial_connection(
                loop,
                lambda: rx,
                url=self.port,
                baudrate=s.baudrate,
                bytesize=s.bytesize,
                parity=_PARITY[s.parity],
                stopbits=s.stopbits,
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise LineClosed(f"cannot open serial port {self.port!r}: {exc}") from exc
        self._serial = transport.serial
        self._rx = rx
        self._current = s
        if self.rs485:
            try:
                self._serial.rs485_mode = serial.rs485.RS485Settings()
            except (ValueError, OSError, serial.SerialException) as exc:
                transport.close()
                raise ConfigError(
                    f"serial port {self.port!r} does not support RS-485 mode (RTS direction "
                    f"control): {exc}; set rs485 = false if the adapter switches by itself"
                ) from exc
        self._quiet_since = monotonic()
        self._closed = False

    async def close(self) -> None:
        """Close the port; a waiting transaction fails with ``LineClosed``."""
        self._closed = True
        rx, self._rx = self._rx, None
        if rx is not None and rx.transport is not None:
            rx.transport.close()
            rx.connection_lost(None)
        self._timer.close()
        self._serial = None

    def _reconfigure(self, s: LineSettings) -> None:
        port = self._serial
        assert port is not None
        # Set all fields, then apply once: one tcsetattr, no close/reopen.
        port._baudrate = s.baudrate
        port._bytesize = s.bytesize
        port._parity = _PARITY[s.parity]
        port._stopbits = s.stopbits
        port._reconfigure_port()
        self._current = s

    def ready_at(self, settings: LineSettings | None) -> float:
        """When the silence before a frame at ``settings`` will have passed."""
        rx = self._rx
        last = max(self._quiet_since, rx.last_rx if rx is not None else 0.0)
        return last + switch_silence(self._current, settings or self.settings)

    async def _wait_quiet(self, silence: float) -> None:
        """Wait until the line has been silent for ``silence`` since its last activity."""
        rx = self._rx
        assert rx is not None
        while True:
            quiet = max(self._quiet_since, rx.last_rx)
            await self._timer.sleep_until(quiet + silence)
            if rx.last_rx <= quiet:
                break  # nothing arrived while we waited
        if rx.buf:
            self.garbage_bytes += len(rx.buf)
            rx.buf.clear()

    async def transact(
        self,
        unit: int,
        pdu: bytes,
        *,
        expect: LengthPredictor | None,
        settings: LineSettings | None = None,
        timeout: float = 0.1,
    ) -> Exchange:
        """Send one frame and, unless ``expect`` is None, read its reply by length."""
        if self._closed or self._rx is None:
            raise LineClosed(f"serial line {self.port} is closed")
        target = settings or self.settings
        tm = timing(target)
        await self._wait_quiet(switch_silence(self._current, target))
        if target != self._current:
            self._reconfigure(target)
        rx = self._rx
        adu = frame(unit, pdu)
        try:
            tx_start = monotonic()
            written = self._serial.write(adu)  # type: ignore[union-attr]
            if written < len(adu):
                rx.transport.write(adu[written:])  # type: ignore[union-attr]
            tx_end = tx_start + tm.frame_time(len(adu))
            self._quiet_since = tx_end
            if self.local_echo:
                await self._take_echo(adu, tx_end + tm.t35 + 0.05)
            if expect is None:
                self._quiet_since = tx_end + self.broadcast_delay
                return Exchange(b"", tx_start, tx_end, tx_end, len(adu), 0, tm.frame_time(len(adu)))
            reply = await self._read_reply(unit, expect, tx_end + timeout, tm.char_time, tm.t35)
        except BaseException:
            # Whatever happened, the line must be silent before the next frame.
            self._quiet_since = max(self._quiet_since, monotonic())
            raise
        rx_end = rx.last_rx
        self._quiet_since = rx_end
        n = len(reply) + 3
        return Exchange(
            reply, tx_start, tx_end, rx_end, len(adu), n, tm.frame_time(len(adu) + n)
        )

    async def _take_echo(self, adu: bytes, deadline: float) -> None:
        rx = self._rx
        assert rx is not None
        if not await rx.wait_for(len(adu), deadline) or bytes(rx.buf[: len(adu)]) != adu:
            got = bytes(rx.buf[: len(adu)])
            rx.buf.clear()
            raise FrameError(
                f"local echo {got.hex(' ')} differs from the frame sent {adu.hex(' ')}: "
                "bus collision, or the adapter does not echo (set local_echo = false)"
            )
        del rx.buf[: len(adu)]

    async def _read_reply(
        self, unit: int, expect: LengthPredictor, deadline: float, char: float, t35: float
    ) -> bytes:
        rx = self._rx
        assert rx is not None
        buf = rx.buf
        need = 2
        extended = False
        while True:
            if not await rx.wait_for(need, deadline):
                if buf:
                    return await self._resync(unit, expect, t35, deadline)
                raise ResponseTimeout(f"slave {unit}: no reply", slave=unit)
            if buf[0] != unit:
                return await self._resync(unit, expect, t35, deadline)
            length = expect(bytes(buf[1:need]))
            if length is None:
                need += 1
                continue
            total = 1 + length + 2
            if not extended:
                deadline += total * char  # allow the reply's own wire time
                extended = True
            if len(buf) < total:
                need = total
                continue
            adu = bytes(buf[:total])
            if not crc_ok(adu):
                return await self._resync(unit, expect, t35, deadline)
            del buf[:total]  # anything after it is garbage, dropped before the next frame
            return adu[1:-2]

    async def _resync(
        self, unit: int, expect: LengthPredictor, t35: float, deadline: float
    ) -> bytes:
        """Error path: wait for t3.5 of silence, then look for a valid frame in the bytes."""
        rx = self._rx
        assert rx is not None
        limit = deadline + 0.5  # a babbling line must not hold us forever
        while monotonic() < limit:
            quiet_at = rx.last_rx + t35
            if monotonic() >= quiet_at:
                break
            await rx.wait_for(len(rx.buf) + 1, min(quiet_at, limit))
        data = bytes(rx.buf)
        rx.buf.clear()
        other: int | None = None
        for i in range(len(data) - 3):
            length = expect(data[i + 1 :])
            if length is None or i + length + 3 > len(data):
                continue
            adu = data[i : i + length + 3]
            if crc_ok(adu):
                if adu[0] == unit:
                    self.garbage_bytes += len(data) - len(adu)
                    return adu[1:-2]
                other = adu[0] if other is None else other
        self.garbage_bytes += len(data)
        if other is not None:
            raise WrongResponder(
                f"slave {unit}: reply came from address {other}", slave=unit, responder=other
            )
        kind = "bad CRC" if len(data) >= 4 else "short frame"
        raise FrameError(
            f"slave {unit}: unusable reply ({kind}, {len(data)} bytes: {data[:32].hex(' ')})",
            slave=unit,
        )

    def __repr__(self) -> str:
        return f"SerialLine({self.port!r}, {self.settings})"


