"""Noise on a line: the watch that notices bytes nobody asked for, and the decision
which queued requests' time to see the noisy line quiet has run out."""

from __future__ import annotations

import math
from collections.abc import Iterable

from drivebus.bus.request import Request
from drivebus.clock import monotonic
from drivebus.errors import LineNoise
from drivebus.line.base import Line


class NoiseWatch:
    """Tells the bus owner when bytes nobody asked for keep its line busy, and since when.

    While the owner waits for the line's silence it sends nothing, so if the line's last
    activity moves, bytes arrived that are no reply: noise. From then on each queued
    request has its own timeout to see the line quiet (counted from when it was queued,
    or from when the noise was noticed, whichever is later), never longer.
    """

    def __init__(self, line: Line) -> None:
        self.line = line
        self.activity = line.last_activity
        self.seen = line.last_activity()
        self.since: float | None = None
        """When noise was first noticed (None: the line is not known to be noisy)."""

    def reset(self, activity: float | None = None) -> None:
        """The line carried a transaction (or the owner was idle): start watching afresh
        (from ``activity``, the line's last activity, if the caller knows it)."""
        self.seen = self.activity() if activity is None else activity
        self.since = None

    def quiet(self) -> bool:
        """``look`` now, and whether the line is still not known to be noisy."""
        activity = self.activity()
        if activity > self.seen:
            self.seen = activity
            if self.since is None:
                self.since = monotonic()
        return self.since is None

    def look(self, now: float) -> None:
        """Note noise if the line was active since the last look."""
        activity = self.line.last_activity()
        if activity > self.seen:
            self.seen = activity
            if self.since is None:
                self.since = now

    def noted(self, now: float) -> None:
        """The line reported noise itself (a reply lost in it)."""
        if self.since is None:
            self.since = now
        self.seen = self.line.last_activity()

    def deadline(self, req: Request) -> float | None:
        """The latest time ``req`` may still go out, while the line is noisy."""
        if self.since is None:
            return None
        return quiet_deadline(req, self.since)


def quiet_deadline(req: Request, since: float) -> float:
    """The latest time ``req`` may still go out on a line noisy since ``since``: its
    timeout, counted from when it was queued or when the noise was noticed (the later)."""
    return max(req.queued_at, since) + req.handle.timeout


def expired(queue: Iterable[Request], since: float, now: float) -> tuple[list[Request], float]:
    """The requests of ``queue`` (their callers still waiting) whose time to see a line
    noisy since ``since`` quiet has run out by ``now``, and the next such deadline among
    the others (inf: none)."""
    nearest = math.inf
    out: list[Request] = []
    for req in queue:
        if req.future.done():
            continue
        deadline = quiet_deadline(req, since)
        if deadline > now:
            nearest = min(nearest, deadline)
            continue
        out.append(req)
    return out, nearest


def noise_error(req: Request, line: Line, since: float, now: float) -> LineNoise:
    """The error of a request whose time to see the noisy ``line`` quiet ran out."""
    h = req.handle
    garbage = (
        f"; {line.garbage_bytes} bytes discarded so far"
        if line.counts_garbage
        else ""
    )
    return LineNoise(
        f"slave {h.address}: {line.name} is noisy: bytes nobody asked for kept "
        f"it busy for {(now - since) * 1e3:.0f} ms, past the "
        f"{h.timeout * 1e3:.0f} ms timeout (noise, a babbling device or a slave at "
        f"another rate{garbage}); "
        + ("an earlier attempt was sent" if req.sent else "not sent"),
        slave=h.address,
        line=line.name,
        sent=req.sent,
    )
