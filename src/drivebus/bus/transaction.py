"""One transaction the owner task awaits: run on the line, its failures judged, counted
and retried or failed."""

from __future__ import annotations

import heapq
import logging

from drivebus.bus.chain import Chains
from drivebus.bus.noise import NoiseWatch
from drivebus.bus.observe import Outcome
from drivebus.bus.request import Request
from drivebus.bus.state import trace
from drivebus.clock import monotonic
from drivebus.errors import (
    ConnectionLost,
    LineClosed,
    LineConfigError,
    LineNoise,
    ResponseTimeout,
    TransactionError,
    WrongResponder,
)
from drivebus.line.base import Begun, SendWithdrawn


class Transactions(Chains):
    """The scheduler's room for the transactions its owner task awaits."""

    async def _run_one(self, req: Request, noise: NoiseWatch, *, withdrawable: bool,
                       begun: Begun | None = None) -> None:
        try:
            await self._transact(req, noise, withdrawable=withdrawable, begun=begun)
        finally:
            self._ended(req)

    async def _transact(self, req: Request, noise: NoiseWatch, *, withdrawable: bool,
                        begun: Begun | None = None) -> None:
        h = req.handle
        line = self.line
        try:
            if begun is not None:  # a chained transaction: judge what it came to
                await line.finish(begun)  # type: ignore[attr-defined]
                return
            if line.waits_for_silence:
                # Such a line takes ``withdrawable`` and tells ``_replied`` of the exchange
                # as soon as it is complete (from its receiver's callback): the caller is
                # woken from there, before this task.
                self._replying = req
                self._replying_noise = noise
                await line.transact(  # type: ignore[call-arg]
                    h.address,
                    req.pdu,
                    expect=req.expect,
                    settings=h.settings,
                    timeout=h.timeout,
                    quiet_by=noise.deadline(req),
                    withdrawable=withdrawable,
                    on_reply=self._on_reply,
                )
                return
            ex = await line.transact(
                h.address,
                req.pdu,
                expect=req.expect,
                settings=h.settings,
                timeout=h.timeout,
                quiet_by=noise.deadline(req),
            )
        except SendWithdrawn:
            # Taken back before its frame went out: it keeps its place (same seq) and the
            # owner plans again (a more urgent request, a hold, or bytes on the line).
            heapq.heappush(self._queue, req)
            return
        except LineClosed as exc:
            if not req.future.done():
                req.future.set_exception(exc)
            raise
        except LineNoise as exc:
            if trace.isEnabledFor(logging.DEBUG):
                self._trace_failure(req, exc)
            st = self.stats.slave(h.address)
            noise.noted(monotonic())
            req.outcome = "no reply (drowned in noise)" if exc.sent else "not sent (noise)"
            if exc.sent:
                self.stats.transactions += 1
            elif req.sent:
                exc = LineNoise(
                    f"{exc} (an earlier attempt was sent)", slave=h.address, line=exc.line
                )
            req.sent = exc.sent
            st.line_noise += 1
            st.last_error = str(exc)
            if self._observers:
                self._tell(req, "noise")
            # Not retried: noise that outlasted the timeout (and, for a drowned reply, the
            # longest frame's wire time) would only hold the caller for another timeout.
            self._retry_or_fail(req, exc, retry=False)
            return
        except TransactionError as exc:
            if trace.isEnabledFor(logging.DEBUG):
                self._trace_failure(req, exc)
            st = self.stats.slave(h.address)
            noise.reset()
            req.sent = req.sent or not isinstance(exc, LineConfigError)
            req.outcome = f"failed: {exc}"
            self.stats.transactions += 1
            st.last_error = str(exc)
            if isinstance(exc, ResponseTimeout):
                st.timeouts += 1
            elif isinstance(exc, WrongResponder):
                st.wrong_responder += 1
            elif isinstance(exc, ConnectionLost):
                st.connection_errors += 1
            elif isinstance(exc, LineConfigError):
                pass  # refused before it reached the wire; not a wire error
            else:
                st.crc_errors += 1
            if self._observers:
                self._tell(req, _outcome(exc))
            self._retry_or_fail(req, exc, retry=not isinstance(exc, LineConfigError))
            return
        except (OSError, ValueError) as exc:
            # The port failed under us (unplugged adapter): this request fails, the line is gone.
            err = LineClosed(f"line {self.line.name} failed: {exc}")
            if not req.future.done():
                req.future.set_exception(err)
            raise err from exc
        self._succeeded(req, noise, ex)


def _outcome(exc: TransactionError) -> Outcome:
    """The observers' name for a failed attempt."""
    if isinstance(exc, ResponseTimeout):
        return "timeout"
    if isinstance(exc, WrongResponder):
        return "wrong_responder"
    if isinstance(exc, ConnectionLost):
        return "connection"
    if isinstance(exc, LineConfigError):
        return "refused"
    return "crc"
