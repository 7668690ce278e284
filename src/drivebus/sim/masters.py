"""One master per simulated line: the line's master seat, and who else has its pty open.

A simulated serial line is a pty, and any process of the user can open it: a second
master on it (another ``drivebus`` on the same ``sim://NAME``, mbpoll on the published pty)
collides with the first, frame by frame, as two masters on an RS-485 line do. A master
takes the line's seat when it opens the line: a drivebus port through ``sim://NAME`` (in
this process, or in another one through the line's format channel, which names the
process by its socket's credentials); a second one is refused with an error naming the
line and the process that has it. Masters that open the pty path directly (mbpoll, a
PLC) take no seat: they are found among the processes that have the pty open (Linux's
``/proc``), when a drivebus master takes the seat and when the wire sees frames collide.
"""

from __future__ import annotations

import os
from collections.abc import Collection
from pathlib import Path

__all__ = ["MasterSeat", "describe_process", "pty_holders", "second_master"]


def describe_process(pid: int) -> str:
    """``process PID (its command line)``, as far as it can be read."""
    try:
        argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        cmd = " ".join(" ".join(a.decode(errors="replace") for a in argv if a).split())
    except OSError:
        cmd = ""
    if len(cmd) > 120:
        cmd = cmd[:117] + "..."
    return f"process {pid} ({cmd})" if cmd else f"process {pid}"


def pty_holders(path: str, exclude: Collection[int] = ()) -> list[int]:
    """The processes (other than ``exclude``) that have ``path`` open, by pid; empty where
    ``/proc`` cannot tell (not Linux, another user's processes)."""
    try:
        target = os.stat(path)
        pids = [int(p) for p in os.listdir("/proc") if p.isdigit()]
    except OSError:
        return []
    found = []
    for pid in pids:
        if pid in exclude:
            continue
        try:
            fds = os.listdir(f"/proc/{pid}/fd")
        except OSError:
            continue  # gone, or not ours to look at
        for fd in fds:
            try:
                st = os.stat(f"/proc/{pid}/fd/{fd}")
            except OSError:
                continue
            if st.st_rdev == target.st_rdev and st.st_ino == target.st_ino:
                found.append(pid)
                break
    return found


def second_master(line: str, holder: str) -> str:
    """The refusal of a second master on ``line``, naming who has it (``holder``)."""
    return (f"{line} already has a master: {holder} has the simulated line open; one master "
            f"per line (two masters' frames collide): stop it, or give this machine a "
            f"sim:// line of its own")


class MasterSeat:
    """The one master of a simulated line: taken when a master opens the line, freed when
    it closes it."""

    def __init__(self, line: str) -> None:
        self.line = line
        """What errors call the line (``sim://NAME``)."""
        self.holder: object | None = None
        """Whatever took the seat (a port, a channel connection); None: free."""
        self.who = ""
        """The master that has the seat, described (``process PID (command)``)."""

    def take(self, holder: object, who: str) -> str | None:
        """Take the seat for ``holder`` (described ``who``); None if it was free (or is
        ``holder``'s already), else the refusal naming the master that has it."""
        if self.holder is not None and self.holder is not holder:
            return second_master(self.line, self.who)
        self.holder, self.who = holder, who
        return None

    def free(self, holder: object) -> None:
        """``holder`` closed the line: the seat is free (if it had it)."""
        if self.holder is holder:
            self.holder, self.who = None, ""
