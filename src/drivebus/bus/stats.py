"""Counters per slave and line utilisation, kept by the bus scheduler."""

from __future__ import annotations

from dataclasses import dataclass, field, fields

from drivebus.clock import monotonic

__all__ = ["BusStats", "SlaveStats"]


@dataclass
class SlaveStats:
    """What happened on the wire for one slave address."""

    transactions: int = 0
    """Transactions completed with a usable reply (exception replies included)."""
    retries: int = 0
    timeouts: int = 0
    crc_errors: int = 0
    """Unusable replies: bad CRC, short or malformed frames."""
    exceptions: int = 0
    wrong_responder: int = 0
    connection_errors: int = 0
    """Requests lost to a dropped network connection (TCP lines)."""
    line_noise: int = 0
    """Requests that failed because noise kept the line busy past their timeout (never
    sent) or drowned their reply (``LineNoise``)."""
    broadcasts: int = 0
    last_error: str = ""

    @property
    def errors(self) -> int:
        """All failed attempts."""
        return (
            self.timeouts
            + self.crc_errors
            + self.wrong_responder
            + self.connection_errors
            + self.line_noise
        )


@dataclass
class BusStats:
    """Per-slave counters and how busy the line was."""

    slaves: dict[int, SlaveStats] = field(default_factory=dict)
    started: float = field(default_factory=monotonic)
    wire_time: float = 0.0
    """Seconds the line carried frames (request and reply bytes)."""
    transactions: int = 0
    """Attempts that went on the wire, successful or not."""
    replies: int = 0
    """Replies received (exception replies included; broadcasts have none)."""
    reply_time: float = 0.0
    """Seconds from each request's last byte to its reply's last byte, added up: with
    ``replies``, the mean reply latency over any interval."""

    def slave(self, address: int) -> SlaveStats:
        """The counters of ``address`` (created on first use)."""
        st = self.slaves.get(address)
        if st is None:
            st = self.slaves[address] = SlaveStats()
        return st

    @property
    def utilisation(self) -> float:
        """Fraction of the time since the bus opened that frames occupied the line."""
        elapsed = monotonic() - self.started
        return self.wire_time / elapsed if elapsed > 0 else 0.0

    def total(self) -> SlaveStats:
        """All slaves' counters added up."""
        t = SlaveStats()
        counters = [f.name for f in fields(SlaveStats) if f.name != "last_error"]
        for s in self.slaves.values():
            for name in counters:
                setattr(t, name, getattr(t, name) + getattr(s, name))
        return t
