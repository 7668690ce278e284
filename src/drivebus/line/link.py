"""RtuLink: the master's side of RTU on a byte stream — silences, one frame out, its reply in.

Both the serial line and RTU over TCP use it, so the wire rules live in one place: the
silence is counted from the last byte that left (write time + n × character time) or
arrived; bytes that arrive while we wait are line activity and restart the count; after
a failure the count starts from now (plus ``latency`` where the medium adds delay).
The wait for silence is bounded: bytes that keep the line busy past the caller's
``quiet_by`` end it with ``LineNoise`` (nothing sent).

The frame goes out from the silence timer's own callback, right at the end of the
silence (no task switch between the deadline and the write); the reply is assembled by
the receiver as its bytes arrive, and once it is complete and sound the exchange is
finished in that same callback: ``on_reply`` hears of it there (the bus wakes the caller
from it), and the waiting task is woken once, with nothing left to do. A reply that is
not (noise, a bad CRC, a late or short frame) is judged by the task with ``read_reply``.
Until the frame has gone out a transaction started ``withdrawable`` can be taken back
(``withdraw()``, or bytes arriving during a silence it had to wait for): it then ends
with ``SendWithdrawn`` and its owner plans again.
"""

from __future__ import annotations

import asyncio
from asyncio import Future
from collections.abc import Callable

from drivebus.clock import STALL, STALL_GRACE, PreciseTimer, monotonic
from drivebus.errors import LineNoise
from drivebus.line.base import Begun, Exchange, SendWithdrawn
from drivebus.line.receiver import STALL_EXTENSIONS, RtuReceiver
from drivebus.line.rtu import frame
from drivebus.pdu import LengthPredictor
from drivebus.settings import LineSettings
from drivebus.timing import Timing

__all__ = ["Begun", "ReplyHook", "RtuJob", "RtuLink"]

ReplyHook = Callable[[Exchange], "bool | None"]
"""Told of a transaction's exchange as soon as it is complete, before ``transact``
returns it: from the receiver's callback when the reply came in whole. True from that
callback: the hook has taken the transaction over and nobody awaits the job's future,
which is then left as it is (a chained transaction, ``drivebus.bus.chain``)."""


class RtuJob(Exchange):
    """One frame waiting for its silence, then for its reply: made by ``RtuLink.begin``
    (or by a line that begins its transactions itself, with the same arguments: making a
    job begins it), ``step`` (the silence timer's callback) sends it, ``replied`` (the
    receiver's) finishes it.

    A job is also the ``Exchange`` it makes (one object per transaction, not two): its
    ``tx_start``/``tx_end`` are set when the frame goes out, the reply's fields by
    ``replied``; ``complete`` says they are all there.

    Its ``future`` is made when something needs it: the task that awaits the job
    (``RtuLink.finish``), or an outcome that is not a sound reply. A sound reply that its
    ``on_reply`` takes over (a chained transaction) needs none. The job is also the
    receiver's waiter (``done``, ``set_result``, ``set_exception``: its future's)."""

    __slots__ = (
        "_future", "adu", "broadcast_delay", "complete", "expect", "link", "local_echo",
        "on_done", "on_reply", "quiet_by", "reply_wait", "rx", "seen", "send", "sent",
        "silence", "stalls", "started", "timeout", "tm", "unit", "waited", "withdrawable",
    )

    def __init__(
        self, link: RtuLink, rx: RtuReceiver, send: Callable[[bytes], None], unit: int,
        pdu: bytes, expect: LengthPredictor | None, tm: Timing, silence: float,
        quiet_by: float, timeout: float, broadcast_delay: float, local_echo: bool = False,
        withdrawable: bool = False, on_reply: ReplyHook | None = None,
    ) -> None:
        self.link = link
        self.rx = rx
        self.send = send
        self.unit = unit
        self.adu = frame(unit, pdu)
        self.tm = tm
        self.silence = silence
        self.quiet_by = quiet_by
        self.timeout = timeout
        self.expect = expect
        self.local_echo = local_echo
        self.reply_wait = expect is not None and not local_echo
        """After the frame, wait for the reply (else: wake at once)."""
        self.withdrawable = withdrawable
        self.waited = False
        """It had to wait for its silence (only then can it be withdrawn)."""
        q, r = link.quiet_since, rx.last_rx
        self.seen = seen = r if r > q else q
        """The line's last activity when the job began."""
        if link.loop is None:  # (the loop its future will belong to)
            link.loop = asyncio.get_running_loop()
        self._future: asyncio.Future[None] | None = None
        self.on_done: Callable[[asyncio.Future[None]], None] | None = None
        """Added to the future's done callbacks when it is made (``future``)."""
        self.on_reply = on_reply
        self.complete = False
        """The receiver's callback finished the exchange (``replied``)."""
        self.started = now = monotonic()
        self.sent = False
        self.tx_start = 0.0
        self.tx_end = 0.0
        self.broadcast_delay = broadcast_delay
        self.stalls = STALL_EXTENSIONS
        """Times ``quiet_by`` may still move for a process that was held up (``step``)."""
        link._job = self
        ready = seen + silence
        if ready > now and (ready <= quiet_by or r <= q):
            # ``step``'s first look, written out for its usual outcome (it runs per
            # transaction): the silence has yet to pass, and no noise keeps it past
            # ``quiet_by``: look again when it has passed.
            self.waited = True
            link.timer.call_at(ready, self.step)
        else:
            self.step()

    def __repr__(self) -> str:  # (Exchange's would read the reply's fields before they are set)
        return f"RtuJob(unit={self.unit}, sent={self.sent}, complete={self.complete})"

    @property
    def future(self) -> asyncio.Future[None]:
        """Done when the transaction needs its owner no more, or needs ``finish``: made on
        first use, with ``on_done`` as its done callback."""
        future = self._future
        if future is None:
            # (the loop's create_future, less its Python frame)
            future = self._future = Future(loop=self.link.loop)
            if self.on_done is not None:
                future.add_done_callback(self.on_done)
        return future

    def done(self) -> bool:
        """Whether the future is done (False while none has been made)."""
        future = self._future
        return future is not None and future.done()

    def set_result(self, result: None) -> None:
        """Resolve the future (the receiver's wake-up: the task judges what is there)."""
        self.future.set_result(result)

    def set_exception(self, exc: BaseException) -> None:
        """Fail the future (the receiver's: the stream was lost)."""
        self.future.set_exception(exc)

    def step(self) -> None:
        """Send the frame if the line has been quiet for its silence; else arm the timer
        to look again then. Failures go to the job's future."""
        link = self.link
        rx = self.rx
        try:
            while True:
                q, r = link.quiet_since, rx.last_rx
                quiet = r if r > q else q
                if self.waited and self.withdrawable and quiet > self.seen:
                    raise SendWithdrawn("bytes arrived during the silence")
                ready = quiet + self.silence
                now = monotonic()
                if ready > self.quiet_by and r > q:
                    if now >= self.quiet_by:
                        if self.stalls and now - self.quiet_by >= STALL:
                            # Not the line's noise: the process was held up past the
                            # deadline, and what arrived meanwhile (a late reply) was taken
                            # in just now. The silence gets a fair chance to follow it.
                            self.stalls -= 1
                            self.quiet_by = now + self.silence + STALL_GRACE
                            continue
                        raise link._noise(rx, self.unit, self.silence, now - self.started)
                    self.waited = True
                    link.timer.call_at(self.quiet_by, self.step)  # perhaps it stops by then
                    return
                if ready > now:
                    self.waited = True
                    link.timer.call_at(ready, self.step)
                    return
                # Bytes received but not delivered yet (a slave answering late) count too.
                rx.take_pending()
                if rx.last_rx <= quiet:
                    break  # nothing arrived while we waited
                if self.waited and self.withdrawable:
                    raise SendWithdrawn("bytes arrived during the silence")
            if rx.buf:
                rx.discard()
            adu = self.adu
            rx.asked.append(adu)
            link._job = None
            self.tx_start = now = monotonic()
            self.sent = True
            self.send(adu)
        except Exception as exc:  # noise, a port that failed: the waiting task raises it
            link._job = None
            if not self.future.done():
                self.future.set_exception(exc)
            return
        tm = self.tm
        link.quiet_since = self.tx_end = tx_end = now + len(adu) * tm.char_time
        link.traffic = tm.settings
        if self.reply_wait:  # (so ``expect`` is not None)
            rx.expect_reply(self.unit, self.expect, tx_end + self.timeout,  # type: ignore[arg-type]
                            self, self.replied, now)
        else:
            self.future.set_result(None)

    def replied(self, reply: bytes) -> None:
        """The receiver has the whole reply: finish the exchange here and now."""
        rx = self.rx
        rx.waiter = None  # (``release``: the receiver is done with this reply)
        self.link.quiet_since = self.rx_end = rx.last_rx
        self.reply = reply
        self.reply_bytes = n = len(reply) + 3
        self.request_bytes = nbytes = len(self.adu)
        self.wire_time = (nbytes + n) * self.tm.char_time
        self.complete = True
        on_reply = self.on_reply
        if on_reply is not None:
            try:
                if on_reply(self):
                    return  # taken over: nobody awaits the future (see ``ReplyHook``)
            except Exception as exc:  # an observer that failed: the waiting task raises it
                self.future.set_exception(exc)
                return
        self.future.set_result(None)


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
        self.loop: asyncio.AbstractEventLoop | None = None
        """The event loop the link runs in (from its first transaction; ``close()`` ends
        it)."""
        self._job: RtuJob | None = None

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

    def withdraw(self) -> bool:
        """Take back the transaction waiting for its silence, if it was started
        ``withdrawable`` and its frame has not gone out: it ends with ``SendWithdrawn``.
        False if there is none (or its frame is out)."""
        job = self._job
        if job is None or job.sent or not job.withdrawable or job.done():
            return False
        self._job = None
        self.timer.cancel()
        job.future.set_exception(SendWithdrawn("taken back by its owner"))
        return True

    # -- one transaction -----------------------------------------------------------------

    def begin(
        self,
        rx: RtuReceiver,
        send: Callable[[bytes], None],
        unit: int,
        pdu: bytes,
        expect: LengthPredictor | None,
        tm: Timing,
        silence: float,
        quiet_by: float,
        timeout: float,
        broadcast_delay: float,
        local_echo: bool = False,
        withdrawable: bool = False,
        on_reply: ReplyHook | None = None,
    ) -> Begun:
        """Start one transaction (see ``transact``) without waiting for it: its frame goes
        out from the silence timer's callback and its reply is assembled by the receiver.
        ``on_reply`` hears of a sound exchange from the callback that completed it; the
        returned job's ``future`` is done when the transaction needs its owner no more
        (a sound reply, or anything for ``finish`` to judge)."""
        return RtuJob(self, rx, send, unit, pdu, expect, tm, silence, quiet_by, timeout,
                      broadcast_delay, local_echo, withdrawable, on_reply)

    async def finish(self, begun: Begun) -> Exchange:
        """The exchange of a transaction of ``begin``: the one the receiver's callback
        completed, or the reply read here (a typed error if there is none)."""
        job = begun
        assert isinstance(job, RtuJob)
        rx = job.rx
        try:
            await job.future  # the frame is out and (with a reply to come) the reply is in
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
        if job.complete:
            return job  # finished by the receiver's callback (``RtuJob.replied``)
        adu, tm, unit, expect = job.adu, job.tm, job.unit, job.expect
        try:
            if job.local_echo:
                await rx.take_echo(adu, job.tx_end + tm.t35 + 0.05)
            if expect is None:
                self.quiet_since = job.tx_end + self.latency + job.broadcast_delay
                ex = Exchange(b"", job.tx_start, job.tx_end, job.tx_end, len(adu), 0,
                              tm.frame_time(len(adu)))
            else:
                reply = await rx.read_reply(unit, expect, job.tx_end + job.timeout,
                                            tm.char_time, tm.t35)
                self.quiet_since = rx.last_rx
                n = len(reply) + 3
                ex = Exchange(reply, job.tx_start, job.tx_end, rx.last_rx, len(adu), n,
                              tm.frame_time(len(adu) + n))
        except BaseException:
            self.quiet_since = max(self.quiet_since + self.latency, monotonic())
            raise
        if job.on_reply is not None:
            job.on_reply(ex)
        return ex

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
        on_reply: ReplyHook | None = None,
    ) -> Exchange:
        """Wait for ``silence`` since the last activity, send one frame and read its reply
        by length (``expect=None``: a broadcast, no reply).

        Bytes received meanwhile are activity and restart the silence (``withdrawable``:
        they end a wait for it with ``SendWithdrawn``); if they keep the line busy until
        ``quiet_by``, ``LineNoise`` with nothing sent. ``on_reply`` is told of the
        exchange as soon as it is complete, before this returns it.
        """
        return await self.finish(self.begin(
            rx, send, unit, pdu, expect, tm, silence, quiet_by, timeout, broadcast_delay,
            local_echo, withdrawable, on_reply))

    def close(self) -> None:
        """Release the timer (and forget the event loop)."""
        self.timer.close()
        self.loop = None
