"""RtuLink: the master's side of RTU on a byte stream — silences, one frame out, its reply in.

Both the serial line and RTU over TCP use it, so the wire rules live in one place: the
silence is counted from the last byte that left (write time + n × character time) or
arrived; bytes that arrive while we wait are line activity and restart the count; after
a failure the count starts from now (plus ``latency`` where the medium adds delay).
The wait for silence is bounded: bytes that keep the line busy past the caller's
``quiet_by`` end it with ``LineNoise`` (nothing sent).
"""

from __future__ import annotations

from collections.abc import Callable

from drivebus.clock import PreciseTimer, monotonic
from drivebus.errors import LineNoise
from drivebus.line.base import Exchange
from drivebus.line.receiver import RtuReceiver
from drivebus.line.rtu import frame
from drivebus.pdu import LengthPredictor
from drivebus.timing import Timing

__all__ = ["RtuLink"]


class RtuLink:
    """Silence bookkeeping and the frame/reply exchange of one RTU master."""

    def __init__(self, *, latency: float = 0.0) -> None:
        self.latency = latency
        """Extra allowance after traffic whose end no reply marks (network delay)."""
        self.quiet_since = 0.0
        """When the line's last known activity ended."""
        self.timer = PreciseTimer()

    def last_activity(self, rx: RtuReceiver | None) -> float:
        """When the line's last known activity (a frame of ours, a byte received) ended."""
        return self.quiet_since if rx is None else max(self.quiet_since, rx.last_rx)

    def ready_at(self, rx: RtuReceiver | None, silence: float) -> float:
        """When ``silence`` will have passed since the last activity."""
        return self.last_activity(rx) + silence

    async def wait_quiet(
        self,
        rx: RtuReceiver,
        unit: int,
        silence: float,
        quiet_by: float,
    ) -> None:
        """Wait for ``silence`` since the last activity; drop bytes that came meanwhile.

        Bytes already received but not yet delivered by the event loop (a slave answering
        late) count as activity too (``rx.pending_bytes``). If received bytes still keep
        the line busy at ``quiet_by``, ``LineNoise`` (the silence our own traffic needs,
        e.g. after a broadcast, is waited in full).
        """
        started = monotonic()
        while True:
            quiet = self.last_activity(rx)
            ready = quiet + silence
            if ready > quiet_by and rx.last_rx > self.quiet_since:
                if monotonic() >= quiet_by:
                    raise self._noise(rx, unit, silence, monotonic() - started)
                await self.timer.sleep_until(quiet_by)  # perhaps the noise stops by then
                continue
            if ready > monotonic():
                await self.timer.sleep_until(ready)
            rx.take_pending()
            if rx.last_rx <= quiet:
                break  # nothing arrived while we waited
        rx.discard()

    @staticmethod
    def _noise(rx: RtuReceiver, unit: int, silence: float, waited: float) -> LineNoise:
        rx.discard()
        return LineNoise(
            f"slave {unit}: {rx.name} is noisy: no silence of {silence * 1e3:.2f} ms in "
            f"{waited * 1e3:.0f} ms (noise, a babbling device or a slave at another rate; "
            f"{rx.garbage_bytes} bytes discarded on this line so far); not sent",
            slave=unit,
            line=rx.line_name,
            sent=False,
        )

    async def exchange(
        self,
        rx: RtuReceiver,
        send: Callable[[bytes], None],
        unit: int,
        pdu: bytes,
        expect: LengthPredictor | None,
        tm: Timing,
        *,
        timeout: float,
        broadcast_delay: float,
        local_echo: bool = False,
    ) -> Exchange:
        """Send one frame (the silence already waited) and read its reply by length."""
        adu = frame(unit, pdu)
        try:
            tx_start = monotonic()
            send(adu)
            tx_end = tx_start + tm.frame_time(len(adu))
            self.quiet_since = tx_end
            if local_echo:
                await rx.take_echo(adu, tx_end + tm.t35 + 0.05)
            if expect is None:
                self.quiet_since = tx_end + self.latency + broadcast_delay
                return Exchange(b"", tx_start, tx_end, tx_end, len(adu), 0,
                                tm.frame_time(len(adu)))
            reply = await rx.read_reply(unit, expect, tx_end + timeout, tm.char_time, tm.t35)
        except BaseException:
            # No reply to time the silence from: whatever happened, start counting now.
            self.quiet_since = max(self.quiet_since + self.latency, monotonic())
            raise
        self.quiet_since = rx.last_rx
        n = len(reply) + 3
        return Exchange(
            reply, tx_start, tx_end, rx.last_rx, len(adu), n, tm.frame_time(len(adu) + n)
        )

    def close(self) -> None:
        """Release the timer."""
        self.timer.close()
