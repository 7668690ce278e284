"""Counters per slave and line utilisation, kept by the bus scheduler.

Each slave's reply latency (from the end of the request to the end of its reply: the
slave's turnaround, the reply's wire time and whatever an adapter holds it) is kept twice:
the last ``LATENCY_WINDOW`` replies for percentiles (``p50``/``p99``), and a cumulative
histogram over ``LATENCY_BUCKETS`` for monitoring systems (Prometheus).
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass, field, fields
from itertools import islice
from typing import Any

from drivebus.clock import monotonic

__all__ = ["LATENCY_BUCKETS", "LATENCY_WINDOW", "BusStats", "Latency", "SlaveStats"]

LATENCY_WINDOW = 1000
"""Replies kept per slave for the latency percentiles."""

LATENCY_BUCKETS: tuple[float, ...] = (
    0.0005, 0.001, 0.002, 0.003, 0.005, 0.0075, 0.01, 0.015, 0.02, 0.03, 0.05, 0.1, 0.25,
    0.5, 1.0,
)
"""Upper bounds (s) of the latency histogram's buckets (and +Inf)."""


class Latency:
    """One slave's reply latencies: a window of the last ones and a cumulative histogram.

    ``add`` runs once per reply, so it only appends to the window and counts: the
    histogram and the sum take in the replies added since they were last brought up to
    date when they are read, or when the window is about to drop the oldest of them
    (``_bin``). The counts are those of binning each reply as it came, the sum the same
    to its last bits (``math.fsum`` of each batch).
    """

    __slots__ = ("_binned", "_buckets", "_sum", "count", "window")

    def __init__(self) -> None:
        self.window: deque[float] = deque(maxlen=LATENCY_WINDOW)
        self._buckets = [0] * (len(LATENCY_BUCKETS) + 1)
        self.count = 0
        self._sum = 0.0
        self._binned = 0
        """How many of the ``count`` replies are in ``_buckets`` and ``_sum`` (the others
        are the newest ones of the window)."""

    def add(self, seconds: float) -> None:
        """Record one reply's latency."""
        self.window.append(seconds)
        self.count += 1
        if self.count - self._binned >= LATENCY_WINDOW:  # the window is all unbinned
            self._bin()

    def _bin(self) -> None:
        """Bring the histogram and the sum up to date with the replies added since."""
        new = self.count - self._binned
        if not new:
            return
        window = self.window
        fresh = sorted(islice(window, len(window) - new, None))  # the newest ``new``
        buckets = self._buckets
        done = 0
        for i, bound in enumerate(LATENCY_BUCKETS):  # (a bucket's replies: up to its bound)
            upto = bisect.bisect_right(fresh, bound, done)
            buckets[i] += upto - done
            done = upto
        buckets[-1] += len(fresh) - done
        self._sum += math.fsum(fresh)
        self._binned = self.count

    @property
    def buckets(self) -> list[int]:
        """Replies per bucket (not cumulative); the last one is beyond the largest bound."""
        self._bin()
        return self._buckets

    @property
    def sum(self) -> float:
        """The latencies of all replies added up (s)."""
        self._bin()
        return self._sum

    def quantile(self, q: float) -> float | None:
        """The ``q`` quantile (0..1) of the window, None before the first reply."""
        return _quantile(sorted(self.window), q)

    def merge(self, other: Latency) -> None:
        """Add ``other``'s replies (a line's total)."""
        self._bin()
        self._buckets = [a + b for a, b in zip(self._buckets, other.buckets, strict=True)]
        self._sum += other.sum
        self.window.extend(other.window)
        self.count += other.count
        self._binned = self.count

    def cumulative(self) -> list[tuple[float, int]]:
        """(upper bound, replies at or below it), the last bound being +Inf."""
        out, n = [], 0
        for bound, k in zip((*LATENCY_BUCKETS, float("inf")), self.buckets, strict=True):
            n += k
            out.append((bound, n))
        return out

    def summary(self) -> dict[str, Any]:
        """p50/p99 of the window (ms) and the totals, as plain data."""
        ordered = sorted(self.window)  # (once for both: quantile would sort it twice)
        p50, p99 = _quantile(ordered, 0.5), _quantile(ordered, 0.99)
        return {"p50_ms": None if p50 is None else round(p50 * 1e3, 3),
                "p99_ms": None if p99 is None else round(p99 * 1e3, 3),
                "window": len(self.window), "count": self.count}


def _quantile(ordered: list[float], q: float) -> float | None:
    """The ``q`` quantile (0..1) of sorted values, None for none."""
    if not ordered:
        return None
    return ordered[min(len(ordered) - 1, round(q * (len(ordered) - 1)))]


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
    latency: Latency = field(default_factory=Latency, repr=False, compare=False)
    """Reply latencies (see the module's docstring)."""

    def as_dict(self) -> dict[str, Any]:
        """The counters and the latency summary as plain data."""
        d: dict[str, Any] = {f.name: getattr(self, f.name) for f in fields(self)
                             if f.name != "latency"}
        d["latency"] = self.latency.summary()
        return d

    def add(self, other: SlaveStats) -> None:
        """Count ``other``'s attempts and reply latencies in with these."""
        for name in _COUNTERS:
            setattr(self, name, getattr(self, name) + getattr(other, name))
        self.latency.merge(other.latency)

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


_COUNTERS = tuple(f.name for f in fields(SlaveStats) if f.name not in ("last_error",
                                                                          "latency"))
"""The counters of ``SlaveStats`` (what adds up)."""


@dataclass
class BusStats:
    """Per-slave counters and how busy the line was."""

    slaves: dict[int, SlaveStats] = field(default_factory=dict)
    started: float = field(default_factory=monotonic)
    wire_time: float = 0.0
    """Seconds the line carried frames (request and reply bytes)."""
    transactions: int = 0
    """Attempts that went on the wire, successful or not."""
    foreign_requests: int = 0
    """Requests of another master heard on the line (two masters on one line is a fault:
    see ``drivebus.line.foreign``); noise is not counted here."""
    foreign_last: str = ""
    """The last of them, described ("read holding registers 0x0000 (2) from slave 5")."""
    foreign_warned: float = field(default=-math.inf, repr=False, compare=False)
    """When a warning last said so (monotonic s; the bus warns at most once a minute)."""

    def slave(self, address: int) -> SlaveStats:
        """The counters of ``address`` (created on first use)."""
        st = self.slaves.get(address)
        if st is None:
            st = self.slaves[address] = SlaveStats()
        return st

    @property
    def replies(self) -> int:
        """Replies received (exception replies included; broadcasts have none): the
        slaves' ``transactions`` added up (counted once per reply, not twice)."""
        return sum(st.transactions for st in self.slaves.values())

    @property
    def reply_time(self) -> float:
        """Seconds from each request's last byte to its reply's last byte, added up: with
        ``replies``, the mean reply latency over any interval (the slaves' latency sums)."""
        return math.fsum(st.latency.sum for st in self.slaves.values())

    @property
    def utilisation(self) -> float:
        """Fraction of the time since the bus opened that frames occupied the line."""
        elapsed = monotonic() - self.started
        return self.wire_time / elapsed if elapsed > 0 else 0.0

    def after(self, earlier: BusStats) -> BusStats:
        """These counters carried on from ``earlier``'s: a line served anew (its worker
        process started again, with counters of its own from zero) goes on counting from
        where it was, never back."""
        out = BusStats(started=earlier.started, wire_time=earlier.wire_time + self.wire_time,
                       transactions=earlier.transactions + self.transactions,
                       foreign_requests=earlier.foreign_requests + self.foreign_requests,
                       foreign_last=self.foreign_last or earlier.foreign_last,
                       foreign_warned=max(earlier.foreign_warned, self.foreign_warned))
        for part in (earlier, self):
            for address, st in part.slaves.items():
                mine = out.slave(address)
                mine.add(st)
                mine.last_error = st.last_error or mine.last_error
        return out

    def total(self) -> SlaveStats:
        """All slaves' counters added up."""
        t = SlaveStats()
        for s in self.slaves.values():
            t.add(s)
        return t
