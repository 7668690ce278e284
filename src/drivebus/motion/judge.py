"""The judge: what a fresh status says of the motion under way. Pure functions, no I/O and
no clock of their own: (the motion, a status requested after its start, the axis's
settings) in, a ``Verdict`` out. The axis's actor feeds them only statuses whose request
left after the motion's start was acknowledged, and carries the verdict out (ends the
motion, changes the state, sends a stop); they are tested without an event loop.

A move is done when the drive reports it at rest and in position within the tolerance of
its target; a jog towards a soft limit when it came to rest there; a speed run that the
drive ended itself is over. A limit switch ahead of the motion (either way for a motion
that goes both ways, a position table) ends it with ``LimitViolation`` and a stop. A
motion the drive accepted but never started fails once it is late. A homing is done when
the drive reports homed and no longer homing; a homing error the drive reports ends it
at once; a limit switch is judged by the homing method's switches (those it homes on,
those where the drive reverses, and one met again after leaving it: no home switch).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal, Protocol

from drivebus.drives.base import HomingSwitches
from drivebus.drives.status import DriveStatus
from drivebus.errors import DrivebusError, LimitViolation, MotionError
from drivebus.motion.state import AxisState

__all__ = ["Judged", "Verdict", "drive_restarted", "judge", "judge_homing", "limit_error",
           "position_lost", "switch_ahead"]

Outcome = Literal["going", "arrived", "done", "failed"]


class Judged(Protocol):
    """What the judge reads of a motion (``drivebus.motion.motions.Motion``)."""

    kind: str
    what: str
    direction: int
    start: int | None
    target: int | None
    accepted_at: float | None
    seen_motion: bool
    both_ways: bool
    switches: HomingSwitches
    overrun: float
    switch_seen: dict[int, int]
    switch_left: set[int]


@dataclass(frozen=True)
class Verdict:
    """What a status says of a motion. ``going``: not over (``seen_motion``, and for a
    homing ``switch_seen``/``switch_left``, carry what it learned); ``arrived``: a move in
    position; ``done``: over without an error; ``failed``: over with ``error``. ``state``
    is where the axis goes (None: it stays), ``stop`` why a stop must be sent (""),
    ``check_settings`` that the drive may have been reset, ``note`` what to log."""

    outcome: Outcome
    seen_motion: bool
    error: DrivebusError | None = None
    state: AxisState | None = None
    stop: str = ""
    check_settings: bool = False
    note: str = ""
    switch_seen: Mapping[int, int] = field(default_factory=dict)
    switch_left: frozenset[int] = frozenset()


class Switches(Protocol):
    """A status's limit switches (a ``DriveStatus``, a short read's ``Completion``)."""

    limit_positive: bool
    limit_negative: bool


def switch_ahead(st: Switches, direction: int) -> bool:
    """True if the limit switch in drive ``direction`` is active in ``st``."""
    return (direction > 0 and st.limit_positive) or (direction < 0 and st.limit_negative)


def limit_error(axis: str, m: Judged, where: str, *, side: int = 0,
                why: str = "") -> LimitViolation:
    """The error of a limit switch (``side``, else the motion's direction) reached at
    ``where`` (user units, as text) during ``m``."""
    name = "positive" if (side or m.direction) > 0 else "negative"
    because = f" ({why})" if why else ""
    return LimitViolation(
        f"axis {axis}: the {name} limit switch was reached at {where} during the "
        f"{m.what}{because}; reset() the axis, then only motion away from the switch is "
        f"allowed")


def _limit(axis: str, m: Judged, st: DriveStatus, where: str, seen: bool, *, side: int = 0,
           why: str = "") -> Verdict:
    name = "positive" if (side or m.direction) > 0 else "negative"
    return Verdict("failed", seen, limit_error(axis, m, where, side=side, why=why),
                   AxisState.ERROR_STOP, stop=f"{name} limit switch")


def judge(axis: str, m: Judged, st: DriveStatus, issued: float, *, tolerance: int,
          late_after: float, where: str) -> Verdict:
    """A move's, jog's or table's verdict from ``st`` (requested at ``issued``, after
    the motion's start was acknowledged). ``tolerance``: pulses from the target that
    count as there; ``late_after``: seconds after its acceptance by which a drive that
    has not started never will; ``where``: ``st``'s position in user units, as text."""
    if m.kind == "home":
        return judge_homing(axis, m, st, issued, late_after=late_after, where=where)
    switch = switch_ahead(st, m.direction) or (
        m.both_ways and (st.limit_positive or st.limit_negative))
    side = (1 if st.limit_positive else -1) if m.both_ways else 0
    if st.moving:
        if switch:
            return _limit(axis, m, st, where, True, side=side)
        return Verdict("going", True)
    seen = m.seen_motion
    at = m.target is None or st.position is None or abs(st.position - m.target) <= tolerance
    late = issued > (m.accepted_at or 0.0) + late_after
    if m.kind == "move" and at:
        if st.in_position:
            return Verdict("arrived", seen, state=AxisState.STANDSTILL)
        return Verdict("going", seen)  # at the target, still settling
    if m.kind == "jog" and m.target is not None and at:
        return Verdict("done", seen, state=AxisState.STANDSTILL,
                       note=f"{m.what} came to rest at the soft limit {where}")
    started = seen or (st.position is not None and st.position != m.start)
    if switch and started:
        return _limit(axis, m, st, where, seen, side=side)
    if not started and not late:
        return Verdict("going", seen)  # not yet moving: the drive has a moment to start
    if not started:
        way = "positive" if m.direction > 0 else "negative"
        error: DrivebusError = (
            LimitViolation(f"axis {axis}: the drive did not start the {m.what}: the {way} "
                           f"limit switch is active") if switch
            else MotionError(f"axis {axis}: the drive accepted the {m.what} but did not "
                             f"start it"))
        return Verdict("failed", seen, error, AxisState.STANDSTILL, check_settings=True)
    if m.kind == "jog":  # nobody stopped it: the drive did, or was reset
        return Verdict("done", seen, state=AxisState.STANDSTILL, check_settings=True,
                       note=f"{m.what} ended at {where}")
    return Verdict("failed", seen, MotionError(
        f"axis {axis}: the drive stopped at {where}, short of the {m.what}"),
        AxisState.STANDSTILL, check_settings=True)


def judge_homing(axis: str, m: Judged, st: DriveStatus, issued: float, *,
                 late_after: float, where: str) -> Verdict:
    """A homing's verdict: done when the drive reports homed and no longer homing; a
    homing error ends it at once; a limit switch met while homing ends it (ErrorStop)
    unless the method homes on it; one where the drive reverses (or that was active at
    the start) may be run into by the braking distance (``m.overrun``), and not met
    again once left (the home switch is missing)."""
    if st.homing_error:
        return Verdict("failed", m.seen_motion, MotionError(
            f"axis {axis}: the drive reports a homing error (the homing failed at {where}); "
            f"reset() the axis before the next command"), AxisState.ERROR_STOP,
            stop="homing error" if st.moving else "")
    seen = m.seen_motion or st.moving
    if not st.moving and st.homed and not st.homing:
        return Verdict("done", seen, state=AxisState.STANDSTILL)
    position = st.position or 0
    switch_seen = dict(m.switch_seen)
    switch_left = set(m.switch_left)
    for side, active in ((1, st.limit_positive), (-1, st.limit_negative)):
        if side in m.switches.homes_on:
            continue
        if not active:
            if side in switch_seen:
                switch_left.add(side)
            continue
        if side in switch_left:
            why = "met again after leaving it: no home switch was found"
        elif side in m.switches.reverses_at or side in switch_seen:
            first = switch_seen.setdefault(side, position)
            if (position - first) * side <= m.overrun:
                if st.moving or seen or issued <= (m.accepted_at or 0.0) + late_after:
                    continue  # braking, reversing, or not yet started
                why = "the drive did not start the homing"
            else:
                why = "the drive ran on into it instead of reversing"
        else:
            why = "the homing method does not use it"
        return _limit(axis, m, st, where, seen, side=side, why=why)
    return Verdict("going", seen, switch_seen=switch_seen, switch_left=frozenset(switch_left))


def position_lost(before: DriveStatus, now: DriveStatus, *, tolerance: int,
                  back_from_offline: bool, disabled_by_command: bool) -> bool:
    """Whether the drive's position counter started again (a power cycle): at rest in both
    statuses, no motion of ours, it moved by more than ``tolerance`` pulses while it did
    not answer (``back_from_offline``) or while it dropped its enable on its own. Its home
    is lost then, whatever volatile settings it kept; a drive that only lost its enable
    (a fault, a safe torque off) kept its position, and so did one that rests where it
    was."""
    if not _moved_at_rest(before, now, tolerance):
        return False
    return back_from_offline or (before.enabled and not now.enabled
                                 and not disabled_by_command)


def drive_restarted(before: DriveStatus, now: DriveStatus, *, tolerance: int,
                    back_from_offline: bool, disabled_by_command: bool,
                    tracked: frozenset[str] = frozenset()) -> bool:
    """Whether the drive may have restarted between two statuses with no motion of ours:
    its position was lost (``position_lost``); or the profile only tracks its enable
    (``tracked``: the drive cannot say it dropped it) and it did not answer a while or
    its position moved at rest; or the profile only tracks its homed state and it
    dropped its enable on its own with no alarm (a power cycle back at the same position
    looks just so). What the profile tracked of it is then stale: the drive is taken for
    not enabled, not homed, and is set up again."""
    if "enabled" in tracked and (back_from_offline or _moved_at_rest(before, now, tolerance)):
        return True
    if "homed" in tracked and before.enabled and not now.enabled and not now.alarm and \
            not disabled_by_command and not before.moving and not now.moving:
        return True
    return position_lost(before, now, tolerance=tolerance, back_from_offline=back_from_offline,
                         disabled_by_command=disabled_by_command)


def _moved_at_rest(before: DriveStatus, now: DriveStatus, tolerance: int) -> bool:
    """At rest in both statuses, its position changed by more than ``tolerance``."""
    if before.moving or now.moving or before.position is None or now.position is None:
        return False
    return abs(now.position - before.position) > tolerance
