"""What an attempt came to: counted, told to the observers and the trace, its caller
answered or its retry queued, and a request that reached the wire noted."""

from __future__ import annotations

import heapq
import logging

from drivebus.bus.noise import NoiseWatch
from drivebus.bus.observe import Outcome, Transaction
from drivebus.bus.request import Request
from drivebus.bus.sent import SentRequest, note_sent
from drivebus.bus.state import BusState, trace
from drivebus.clock import monotonic
from drivebus.errors import (
    TransactionError,
)
from drivebus.line.base import Exchange
from drivebus.line.rtu import frame


class Outcomes(BusState):
    """The scheduler's room for what its transactions came to."""

    def _tell(self, req: Request, outcome: Outcome, ex: Exchange | None = None) -> None:
        """Tell the observers how an attempt of ``req`` ended."""
        if ex is None:
            now = monotonic()
            tx = Transaction(req.handle.address, req.pdu[0] if req.pdu else 0, req.priority,
                             now, now, 0.0, None, outcome)
        else:
            tx = Transaction(req.handle.address, req.pdu[0] if req.pdu else 0, req.priority,
                             ex.tx_start, ex.rx_end, ex.wire_time,
                             None if req.expect is None else ex.rx_end - ex.tx_end, outcome)
        for observer in self._observers:
            observer(tx)

    def _note(self, req: Request, outcome: str, *, cancelled: bool = False) -> None:
        """Tell a ``sent_requests`` block that ``req`` reached the wire."""
        note_sent(SentRequest(req.handle.address, req.pdu[0] if req.pdu else 0, req.pdu,
                              outcome, cancelled))

    def _succeeded(self, req: Request, noise: NoiseWatch, ex: Exchange,
                   activity: float | None = None) -> None:
        """Count ``req``'s exchange, tell the observers, give its caller the reply
        (``activity``: the line's last activity, if known)."""
        if trace.isEnabledFor(logging.DEBUG):
            self._trace_exchange(req, ex)
        if activity is None:
            noise.reset()
        else:  # (``reset``, written out: it runs per transaction)
            noise.seen, noise.since = activity, None
        req.sent = True
        reply = ex.reply
        if req.landed is not None:
            req.outcome = (f"exception 0x{reply[1]:02X}" if reply[:1] and
                           reply[0] & 0x80 and len(reply) > 1 else
                           "no reply (a broadcast)" if req.expect is None else "acknowledged")
        stats = self.stats
        stats.transactions += 1
        stats.wire_time += ex.wire_time
        st = stats.slaves.get(req.handle.address) or stats.slave(req.handle.address)
        outcome: Outcome = "ok"
        if req.expect is None:
            st.broadcasts += 1
            outcome = "broadcast"
        else:
            st.transactions += 1  # (and so the bus's ``replies``)
            st.latency.add(ex.rx_end - ex.tx_end)  # (and so its ``reply_time``)
            if reply and reply[0] & 0x80:
                st.exceptions += 1
                outcome = "exception"
        if self._observers:
            self._tell(req, outcome, ex)
        if not req.future.done():
            req.future.set_result(reply)

    def _frame_hex(self, unit: int, pdu: bytes) -> str:
        """The bytes of a frame as on the wire (RTU: with its CRC; TCP: unit and PDU)."""
        if self.line.settings is None:
            return f"unit {unit}: {pdu.hex(' ')}"
        return frame(unit, pdu).hex(" ")

    def _trace_exchange(self, req: Request, ex: Exchange) -> None:
        """Log a completed transaction's request and reply on ``drivebus.trace``."""
        h = req.handle
        at = h.settings or self.line.settings
        fmt = f" {at}" if at is not None else ""
        silence = ""  # on an RTU line, the silence since the previous traced frame ended
        if self._traced_end and self.line.settings is not None:
            silence = f" after {(ex.tx_start - self._traced_end) * 1e3:.3f} ms silence"
        trace.debug("%.6f %s%s tx slave %d%s: %s", ex.tx_start, self.line.name, fmt,
                    h.address, silence, self._frame_hex(h.address, req.pdu))
        if req.expect is None:
            trace.debug("%.6f %s%s -- broadcast, no reply", ex.tx_end, self.line.name, fmt)
        else:
            trace.debug("%.6f %s%s rx slave %d after %.3f ms: %s", ex.rx_end, self.line.name,
                        fmt, h.address, (ex.rx_end - ex.tx_end) * 1e3,
                        self._frame_hex(h.address, ex.reply))
        self._traced_end = ex.rx_end

    def _trace_failure(self, req: Request, exc: TransactionError) -> None:
        """Log a transaction that failed on ``drivebus.trace``."""
        h = req.handle
        trace.debug("%.6f %s tx slave %d %s: %s: %s", monotonic(), self.line.name, h.address,
                    self._frame_hex(h.address, req.pdu), type(exc).__name__, exc)
        self._traced_end = monotonic()

    def _retry_or_fail(self, req: Request, exc: TransactionError, *, retry: bool) -> None:
        """Queue ``req`` again if it may be retried and has retries left, else fail it."""
        if req.future.done():
            return  # its caller gave up
        if retry and req.retries_left > 0:
            req.retries_left -= 1
            self.stats.slave(req.handle.address).retries += 1
            heapq.heappush(self._queue, req)  # same seq: keeps its place in line
            self._wake_owner()
        else:
            req.future.set_exception(exc)
