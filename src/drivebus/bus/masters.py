"""Another master's requests heard on a line: counted apart from noise, and said."""

from __future__ import annotations

from drivebus.bus.state import BusState, log
from drivebus.clock import monotonic
from drivebus.line.foreign import describe_request

FOREIGN_WARN_EVERY = 60.0
"""Seconds between two warnings about another master on a line (the first comes at once)."""


def heard_foreign(bus: BusState, request: bytes) -> None:
    """Another master's request heard on ``bus``'s line: counted apart from noise, and
    said (a warning at once, then at most once a minute)."""
    st = bus.stats
    st.foreign_requests += 1
    st.foreign_last = describe_request(request)
    now = monotonic()
    if now - st.foreign_warned >= FOREIGN_WARN_EVERY:
        st.foreign_warned = now
        log.warning("%s: another master is on the line: it sent %s (%d such requests heard "
                    "so far); one master per line", bus.line.name, st.foreign_last,
                    st.foreign_requests)
