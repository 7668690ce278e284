"""RtuLink: the master's side of RTU on a byte stream — silences, one frame out, its reply in.

Both the serial line and RTU over TCP use it, so the wire rules live in one place: the
silence is counted from the last byte that left (write time + n × character time) or
arrived; bytes that arrive while we wait are line activity and restart the count; after
a failure the count starts from now (plus ``latency`` where the medium adds delay).
The wait for silence is bounded: bytes that keep the line busy past the caller's
``quiet_by`` end it with ``LineNoise`` (nothing sent).

The frame goes out from the silence timer's own callback, right at the end of the
silence (no task switch between the deadline and the write), and the waiting task is
woken once, by the reply's first bytes. Until the frame has gone out a transaction
started ``withdrawable`` can be taken back (``withdraw()``, or bytes arriving during its
silence): it then ends with ``SendWithdrawn`` and its owner plans again.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable

from drivebus.clock import PreciseTimer, monotonic
from drivebus.errors import LineNoise
from drivebus.line.base import Exchange, SendWithdrawn
from drivebus.line.receiver import RtuReceiver
from drivebus.line.rtu import frame
from drivebus.pdu import LengthPredictor
from drivebus.settings import LineSettings
from drivebus.timing import Timing

__all__ = ["RtuLink"]

_FIRST_BYTES = 3
"""Reply bytes that end the wait for a reply: address, function code and a byte count
(the shortest reply has 4 bytes)."""


class _Job:
    """One frame waiting for its silence, then for the first bytes of its reply."""

    __slots__ = (
        "adu", "future", "quiet_by", "reply_wait", "rx", "seen", "send", "sent", "silence",
        "started", "timeout", "tm", "tx_end", "tx_start", "unit", "withdrawable",
    )

    def __init__(
        self, rx: RtuReceiver, send: Callable[[bytes], None], unit: int, adu: bytes,
        tm: Timing, silence: float, quiet_by: float, timeout: float, *, reply_wait: bool,
        withdrawable: bool, seen: float, future: asyncio.Future[None],
    ) -> None:
        self.rx = rx
        self.send = send
        self.unit = unit
        self.adu = adu
        self.tm = tm
        self.silence = silence
        self.quiet_by = quiet_by
        self.timeout = timeout
        self.reply_wait = reply_wait
        """After the frame, wait for the reply's first bytes (else: wake at once)."""
        self.withdrawable = withdrawable
        self.seen = seen
        """The line's last activity when the job began."""
        self.future = future
        self.started = monotonic()
        self.sent = False
        self.tx_start = 0.0
        self.tx_end = 0.0


class RtuLink:
    """Silence bookkeeping and the frame/reply exchange of one RTU master."""

    def __init__(self, *, latency: float = 0.0) -> None:
        self.latency = latency
        """Extra allowance after traffic whose end no reply marks (network delay)."""
        self.quiet_since = 0.0
        """When the line's last known activity ended."""
        self.traffic: LineSettings | None = None
        """The settings of the last frame sent (what the silence after it is counted at)."""
        self.timer = PreciseTimer()
        self._job: _Job | None = None

    def last_activity(self, rx: RtuReceiver | None) -> float:
        """When the line's last known activity (a frame of ours, a byte received) ended."""
        return self.quiet_since if rx is None else max(self.quiet_since, rx.last_rx)

    def ready_at(self, rx: RtuReceiver | None, silence: float) -> float:
        """When ``silence`` will have passed since the last activity."""
        return self.last_activity(rx) + silence

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

    # -- the frame out, from the timer's callback ------------------------------------------

    def _step(self, job: _Job) -> None:
        """Send ``job``'s frame if the line has been quiet for its silence; else arm the
        timer to look again then. Failures go to the job's waiting task."""
        try:
            self._try_send(job)
        except Exception as exc:  # noise, a port that failed: the waiting task raises it
            self._job = None
            if not job.future.done():
                job.future.set_exception(exc)

    def _try_send(self, job: _Job) -> None:
        rx = job.rx
        while True:
            quiet = self.last_activity(rx)
            if job.withdrawable and quiet > job.seen:
                raise SendWithdrawn("bytes arrived during the silence")
            ready = quiet + job.silence
            now = monotonic()
            if ready > job.quiet_by and rx.last_rx > self.quiet_since:
                if now >= job.quiet_by:
                    raise self._noise(rx, job.unit, job.silence, now - job.started)
                self.timer.call_at(job.quiet_by, lambda: self._step(job))  # perhaps it stops
                return
            if ready > now:
                self.timer.call_at(ready, lambda: self._step(job))
                return
            # Bytes received but not delivered yet (a slave answering late) count too.
            rx.take_pending()
            if rx.last_rx <= quiet:
                break  # nothing arrived while we waited
            if job.withdrawable:
                raise SendWithdrawn("bytes arrived during the silence")
        rx.discard()
        rx.asked.append((job.unit, job.adu[1]))
        self._job = None
        job.tx_start = monotonic()
        job.sent = True
        job.send(job.adu)
        job.tx_end = job.tx_start + job.tm.frame_time(len(job.adu))
        self.quiet_since = job.tx_end
        self.traffic = job.tm.settings
        if job.reply_wait:
            rx.expect_bytes(_FIRST_BYTES, job.tx_end + job.timeout, job.future)
        else:
            job.future.set_result(None)

    def withdraw(self) -> bool:
        """Take back the transaction waiting for its silence, if it was started
        ``withdrawable`` and its frame has not gone out: it ends with ``SendWithdrawn``.
        False if there is none (or its frame is out)."""
        job = self._job
        if job is None or job.sent or not job.withdrawable or job.future.done():
            return False
        self._job = None
        self.timer.cancel()
        job.future.set_exception(SendWithdrawn("taken back by its owner"))
        return True

    # -- one transaction -----------------------------------------------------------------

    async def transact(
        self,
        rx: RtuReceiver,
        send: Callable[[bytes], None],
        unit: int,
        pdu: bytes,
        expect: LengthPredictor | None,
        tm: Timing,
        *,
        silence: float,
        quiet_by: float,
        timeout: float,
        broadcast_delay: float,
        local_echo: bool = False,
        withdrawable: bool = False,
    ) -> Exchange:
        """Wait for ``silence`` since the last activity, send one frame and read its reply
        by length (``expect=None``: a broadcast, no reply).

        Bytes received meanwhile are activity and restart the silence (``withdrawable``:
        they end the wait with ``SendWithdrawn``); if they keep the line busy until
        ``quiet_by``, ``LineNoise`` with nothing sent.
        """
        adu = frame(unit, pdu)
        job = _Job(
            rx, send, unit, adu, tm, silence, quiet_by, timeout,
            reply_wait=expect is not None and not local_echo,
            withdrawable=withdrawable,
            seen=self.last_activity(rx),
            future=asyncio.get_running_loop().create_future(),
        )
        self._job = job
        try:
            self._step(job)
            await job.future  # the frame is out and (with a reply to come) its first bytes
        except BaseException:
            if self._job is job:
                self._job = None
                self.timer.cancel()
            if job.sent:
                # No reply to time the silence from: whatever happened, count from now.
                self.quiet_since = max(self.quiet_since + self.latency, monotonic())
            raise
        finally:
            if job.reply_wait and job.sent:
                rx.release()  # whatever woke us, the reply's bytes are read below
        try:
            if local_echo:
                await rx.take_echo(adu, job.tx_end + tm.t35 + 0.05)
            if expect is None:
                self.quiet_since = job.tx_end + self.latency + broadcast_delay
                return Exchange(b"", job.tx_start, job.tx_end, job.tx_end, len(adu), 0,
                                tm.frame_time(len(adu)))
            reply = await rx.read_reply(unit, expect, job.tx_end + timeout, tm.char_time,
                                        tm.t35)
        except BaseException:
            self.quiet_since = max(self.quiet_since + self.latency, monotonic())
            raise
        self.quiet_since = rx.last_rx
        n = len(reply) + 3
        return Exchange(
            reply, job.tx_start, job.tx_end, rx.last_rx, len(adu), n,
            tm.frame_time(len(adu) + n),
        )

    def close(self) -> None:
        """Release the timer."""
        self.timer.close()
