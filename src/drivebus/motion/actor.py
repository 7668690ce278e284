"""The axis's actor: the part of an axis that owns its drive between commands.

One actor task per axis (``run``, owned by the machine) polls the drive at
``Priority.POLL`` (fast while a motion runs or someone waits, slow at rest; never two
polls of its own in flight) and makes every state decision from what it polls: the judge
(``drivebus.motion.judge``) says what a status requested after a motion's start means for
it, and the actor carries the verdict out, so a later command from another task can never
turn an outcome that was already decided into another one. It keeps the PLCopen state,
the motion under way and the queue behind it, the stops waiting for rest, the listeners
and watchers; it sends the stops the polls ask for (a limit switch, an alarm, a watchdog,
a deadline) and sets the drive up again after a reset.
"""

from __future__ import annotations

import contextlib
import logging
import math
from collections.abc import Awaitable, Callable, Iterator
from dataclasses import replace

import anyio
import anyio.lowlevel

from drivebus.bus import Priority
from drivebus.clock import monotonic
from drivebus.config import AxisConfig
from drivebus.drives.base import DriveProfile
from drivebus.drives.status import DriveStatus
from drivebus.errors import (
    DriveAlarm,
    DrivebusError,
    DriveOffline,
    MotionAborted,
    MotionTimeout,
    TransactionError,
)
from drivebus.motion.envelope import Envelope
from drivebus.motion.events import MotionEventKind
from drivebus.motion.judge import drive_restarted, judge
from drivebus.motion.motions import Motion, RestWait
from drivebus.motion.observers import AxisObservers
from drivebus.motion.state import MOVING_STATES, AxisState
from drivebus.motion.units import Units
from drivebus.tasks import where_tasks_wait
from drivebus.timing import timing

__all__ = ["AxisActor"]

log = logging.getLogger(__name__)

_STOP_TIMEOUT = 30.0

_IO_END_BOUND = 5.0
"""Seconds a stop waits for the I/O of the motion it aborted to end (it ends within its
transaction in flight, a fraction of that): past it, the stop goes out regardless and the
error says where that I/O waits."""
"""Longest a stop waits for the drive to report rest before it raises MotionTimeout."""

_RESET_GAP = 0.5
"""A silence between two answered polls longer than this may have hidden a power cycle."""

_WRITE_REPLY_BYTES = 8
"""An RTU reply to a register write (function 06 or 16): address, function, 4 bytes, CRC."""

class AxisActor(AxisObservers):
    """The state and the actor of one axis: its name, configuration, drive profile, units and
    envelope; the status and state it polls and decides; the motion under way and the
    queue; the poll loop (``run``)."""

    def __init__(self, name: str, config: AxisConfig, profile: DriveProfile) -> None:
        self.name = name
        self.config = config
        self.profile = profile
        self.units = Units(config.pulses_per_rev, config.units_per_rev)
        self.envelope = Envelope(name, config, profile, self.units)
        """What the axis may ask of its drive: plans, limits, pulses (checks only)."""
        self.state: AxisState = AxisState.STANDSTILL
        self.status: DriveStatus | None = None
        self.error: DrivebusError | None = None
        """What put the axis into ErrorStop or Offline."""
        self.moves_done = 0
        self.command_started_at = 0.0
        """When the drive last accepted a motion's start command (for start skew)."""
        self.arrived_at = 0.0
        """When the poll that showed the last move complete was sent (for arrival spread)."""
        self.arrived_after = 0.0
        """When the poll before that one was sent (it saw the drive still on its way)."""
        self.arrived_by = 0.0
        """When the reply of the poll that showed the move complete came in: the move
        ended between ``arrived_after`` and this."""
        self._status_issued = 0.0  # when the poll behind ``status`` was sent
        self._last_answer = 0.0  # when the drive last answered a poll
        self._poke = anyio.Event()
        self._waiters = 0  # callers waiting on a poll: poll fast
        self._lane = anyio.Lock()
        self._motion: Motion | None = None
        self._rest_waits: list[RestWait] = []
        self._stop_sent_at = 0.0
        """When the last stop was sent (its reply came in): only a status requested after
        it, with no stop on its way, may take the axis from Stopping to Standstill."""
        self._stops_on_way = 0  # stops being sent now (``_stop_on_its_way``)
        self._stop_due: str | None = None  # the actor must send a stop (and why)
        self._poll_at = math.inf  # poll no later than this (a stop's expected rest)
        self._check_due = False  # read the volatile settings back before the next command
        self._setup_due = True  # set the drive up before the first command, never to look
        self._learn_due = False  # the drive did not answer at open: learn when it does
        self.setup_changes: list[str] = []
        """What the last setup changed on the drive ("name (register) = was, not wanted"):
        a setting the drive held (pulses/rev, microstep, ...) that setup overwrote."""
        self._homed_lost = False
        self._commanded = False
        self._jog_deadline: float | None = None
        self._watchdog_period: float | None = None
        self._watchers = []
        self._listeners = []
        self._queue: list[Motion] = []
        self._queue_wake = anyio.Event()
        self._unconfirmed: list[Motion] = []  # ended by a short read, no full status since
        self._override = 1.0
        self.machine_override: Callable[[], float] = lambda: 1.0
        """The machine's speed override (set by the machine that owns the axis)."""
        self._override_due = False  # the sequencer applies a new override to the motion
        self._actor_running = False  # the actor polls: a stop waits on its polls
        self._routine_poll: anyio.CancelScope | None = None  # a poll at POLL priority
        self._poll_starved = False  # the last routine poll waited too long in the queue
        self.stops = 0
        """How many times ``stop()`` or ``halt_now()`` was called: a command that plans
        before it takes the axis (a group move) is aborted by a stop meanwhile."""

    @property
    def commanded(self) -> bool:
        """True if a motion commanded through this axis may still be under way."""
        return self._commanded and (self.state in MOVING_STATES or self.started_unseen)

    @property
    def started_unseen(self) -> bool:
        """True if a start was acknowledged after the last status was requested: the
        drive may be moving whatever that status said (one that stopped answering right
        after its start went Offline with an older status at rest)."""
        return self.command_started_at > self._status_issued

    @property
    def position(self) -> float | None:
        """Last polled position in user units."""
        st = self.status
        return None if st is None or st.position is None else self.units.from_pulses(st.position)

    @property
    def velocity(self) -> float | None:
        """Last polled velocity in user units/s, where the drive reports it."""
        st = self.status
        if st is None or st.velocity_rpm is None:
            return None
        return self.units.from_rpm(st.velocity_rpm) * (1 if self.units.units_per_rev > 0 else -1)

    @property
    def target(self) -> float | None:
        """The target of the motion under way in user units (None: none, or a jog with
        no soft limit ahead)."""
        m = self._motion
        return None if m is None or m.target is None else self.units.from_pulses(m.target)

    @property
    def homed(self) -> bool:
        """True if the drive reports homed and has not lost its position since (a reset)."""
        st = self.status
        return st is not None and st.homed and not self._homed_lost

    async def run(self) -> None:
        """Poll the drive, keep its safety rules and run its queue until cancelled; owned
        by the machine."""
        self._actor_running = True
        try:
            async with anyio.create_task_group() as tg:
                tg.start_soon(self._sequence, name=f"drivebus axis {self.name} queue")
                await self._poll_forever()
        finally:
            self._actor_running = False

    async def _poll_forever(self) -> None:
        fails = 0
        poll = self.config.poll
        next_poll = monotonic()
        while True:
            fast = (self.state in MOVING_STATES or self._waiters > 0
                    or self._motion is not None or bool(self._queue))
            period = poll.moving if fast else poll.idle
            now = monotonic()
            next_poll = min(next_poll, now + period)
            priority = Priority.COMMAND if self._rest_waits else Priority.POLL
            quiet: contextlib.AbstractAsyncContextManager[None] = contextlib.nullcontext()
            if self._rest_waits and now < self._poll_at <= now + period:
                # A stop's drive should come to rest within this period: a poll before
                # then would only see it still moving. The next one goes out right then,
                # the line kept quiet for it from half a period before (other slaves'
                # transactions would delay it; only stops go ahead of it).
                next_poll = self._poll_at
                await anyio.sleep(max(0.0, self._poll_at - period / 2 - now))
                quiet, priority = self.profile.slave.bus.hold(), Priority.EMERGENCY
            try:
                async with quiet:
                    delay = next_poll - monotonic()
                    if delay > 0:  # a poll already due needs no cancel scope
                        with anyio.move_on_after(delay):
                            await self._poke.wait()
                    else:
                        await anyio.lowlevel.checkpoint()
                    self._poke = anyio.Event()
                    issued = monotonic()
                    next_poll = issued + period
                    if issued >= self._poll_at:
                        self._poll_at = math.inf
                    # A stop waits on this poll to tell it the drive is at rest: it goes
                    # ahead of the other axes' routine polls. A routine poll queued when a
                    # stop begins to wait is taken back (``_wait_rest``); one held back
                    # for long goes again at CONFIG, in turn with what held it.
                    routine = anyio.CancelScope()
                    if priority is Priority.POLL:
                        self._routine_poll = routine
                        if self._poll_starved:
                            priority = Priority.CONFIG
                        else:
                            routine.deadline = anyio.current_time() + max(4 * period, 1.0)
                    try:
                        with routine:
                            st = await self.profile.read_status(priority=priority)
                    finally:
                        self._routine_poll = None
                    if routine.cancelled_caught:
                        self._poll_starved = not self._rest_waits
                        continue
                    self._poll_starved = False
                    issued = st.requested_at or issued  # when its request was queued
            except TransactionError as exc:
                fails += 1
                self._check_due = True  # it may be a power cycle
                if fails >= poll.offline_after and self.state is not AxisState.OFFLINE:
                    self._go_offline(exc)
                continue
            fails = 0
            if self._last_answer and issued - self._last_answer > _RESET_GAP:
                self._check_due = True
            self._last_answer = monotonic()
            self._apply(st, issued)
            await self._act()

    def start_offline(self, error: DriveOffline) -> None:
        """Begin Offline: the drive did not answer when the machine opened. The actor sets
        it up once it answers; until then commands raise ``StateError``/``DriveOffline``."""
        self.error = error
        self.state = AxisState.OFFLINE
        self._learn_due = True

    def line_lost(self, exc: TransactionError) -> None:
        """Its line is gone for now (the worker process serving it died): Offline at once,
        its motion and queue ended, as when the drive stops answering; the actor takes it
        back once the drive answers again."""
        if self.state is not AxisState.OFFLINE:
            self._go_offline(exc)

    def _go_offline(self, exc: TransactionError) -> None:
        self.error = DriveOffline(
            f"axis {self.name}: drive {self.profile.family} at address "
            f"{self.profile.slave.address} stopped answering ({exc})"
        )
        self.state = AxisState.OFFLINE
        log.warning("%s", self.error)
        self._drop_queue(MotionAborted(f"axis {self.name}: the queue was dropped: {self.error}"))
        if self._motion is not None:
            self._end_motion(self._motion, self.error, None)
        else:
            self._note("error", "offline", detail=str(self.error))
        for w in self._rest_waits:
            w.error = self.error
            w.event.set()
        self._rest_waits.clear()
        self._take_fresh(math.inf)
        self._publish()

    def _apply(self, st: DriveStatus, issued: float) -> None:
        """Take a polled status: decide motions, state and waiting stops (no I/O)."""
        if issued < self._status_issued:
            return  # an older read that finished late
        prev, prev_issued = self.status, self._status_issued
        if prev is not None and self._motion is None and drive_restarted(
                prev, st, tolerance=self.config.in_position_tolerance,
                back_from_offline=self.state is AxisState.OFFLINE,
                disabled_by_command=self.state is AxisState.DISABLED,
                tracked=self.profile.tracked):
            st = self._restarted(prev, st)
        if self.state is AxisState.OFFLINE:
            log.info("axis %s: drive answers again", self.name)
            self.error = None
            self.state = AxisState.STOPPING if st.moving else AxisState.STANDSTILL
            self._check_due = True
            if st.moving and self._motion is None:
                # Back from Offline, still moving, and nobody's motion waits on it (its
                # caller already got DriveOffline): stop it.
                self._stop_due = "the drive answers again while moving with no command"
        elif prev is not None and (
            (prev.homed and not st.homed)
            or (self._motion is None and not st.moving and not prev.moving
                and st.position != prev.position)
        ):
            self._check_due = True  # lost its home, or moved at rest: maybe reset
        self.status, self._status_issued = st, issued
        m = self._motion
        if st.alarm and self.state is not AxisState.ERROR_STOP:
            self.error = DriveAlarm(
                f"axis {self.name}: drive alarm {st.alarm_code}: {st.alarm_text}".rstrip(": "),
                code=st.alarm_code,
                text=st.alarm_text,
            )
            if m is not None:
                self._end_motion(m, self.error, None)
            else:
                self._note("error", "drive alarm", detail=str(self.error))
            self.state = AxisState.ERROR_STOP
            if st.moving:
                self._stop_due = "drive alarm"
        elif m is not None:
            if m.accepted_at is not None and not m.restarting and issued > m.accepted_at:
                self._judge(m, st, issued, prev_issued)
        elif self.state is AxisState.ERROR_STOP:
            pass  # only reset() leaves it
        elif not st.enabled and not st.moving:
            self.state = AxisState.DISABLED
        elif self.state is AxisState.DISABLED:
            self.state = AxisState.STANDSTILL
        elif self.state is AxisState.STANDSTILL and st.moving:
            self.state = AxisState.DISCRETE_MOTION  # moved by someone else (a panel, a PLC)
        elif self.state in (AxisState.STOPPING, AxisState.DISCRETE_MOTION) and not st.moving and (
            issued > self._stop_sent_at and not self._stops_on_way
        ) and not self._queue:
            self.state = AxisState.STANDSTILL
        if not st.moving:
            for w in [w for w in self._rest_waits if issued > w.after]:
                w.event.set()
                self._rest_waits.remove(w)
        self._take_fresh(issued)
        for listener in self._listeners:
            listener(st)
        self._publish()

    def _take_fresh(self, issued: float) -> None:
        """A full status polled at ``issued``: the moves a short read ended before it may
        return to their callers now."""
        for m in [m for m in self._unconfirmed if m.arrived is None or issued > m.arrived[1]]:
            self._unconfirmed.remove(m)
            if m.fresh is not None:
                m.fresh.set()

    def _judge(self, m: Motion, st: DriveStatus, issued: float, prev_issued: float) -> None:
        """Carry out the judge's verdict on ``m`` from a status requested after it started
        (``drivebus.motion.judge``): done, failed, or going on."""
        v = judge(self.name, m, st, issued, tolerance=self.config.in_position_tolerance,
                  late_after=max(0.25, 5 * self.config.poll.moving),
                  where=f"{self.units.from_pulses(st.position or 0):.4f}")
        m.seen_motion = v.seen_motion
        if v.outcome == "going":
            if m.kind == "home":
                m.switch_seen, m.switch_left = dict(v.switch_seen), set(v.switch_left)
            return
        if v.note:
            log.info("axis %s: %s", self.name, v.note)
        if v.check_settings:
            self._check_due = True
        if v.outcome == "arrived":
            self.moves_done += 1
            self.arrived_at = issued
            self.arrived_after = max(prev_issued, m.accepted_at or 0.0)
            self.arrived_by = max(st.timestamp or issued, issued)
            m.arrived = (self.arrived_after, self.arrived_by)
        elif v.outcome == "done" and m.kind == "home":
            self._homed_lost = False
        if v.state is AxisState.ERROR_STOP:
            self.error = v.error
        self._end_motion(m, v.error, v.state)
        if v.stop:
            self._stop_due = v.stop

    def _end_motion(self, m: Motion, error: BaseException | None, state: AxisState | None,
                    *, detail: str = "") -> None:
        """Decide ``m``'s outcome; the axis goes to ``state`` (None: leave it). An error
        drops the queue behind it; a success with a queue behind it keeps the axis in
        motion for the queue's next (``detail``: what to tell of a success).

        A motion that ended in an error the drive caused (it stopped short, did not start,
        an alarm) may hide a reset: the drive's settings are checked before the next
        command."""
        if error is not None and not isinstance(error, MotionAborted):
            self._check_due = True
        if error is not None and m.kind == "home" and not m.over:
            # A homing that failed, timed out or was stopped homed nothing: the axis is
            # not homed until one completes, whatever the drive's flag says meanwhile.
            self._homed_lost = True
        if not m.over:
            log.debug("axis %s: %s ends: %s", self.name, m.what, error or detail or "done")
            if self._listeners:
                kind: MotionEventKind = (
                    "error" if error is not None and not isinstance(error, MotionAborted)
                    else "aborted" if error is not None
                    else "in_position" if m.kind == "move" and not detail else "done")
                self._note(kind, m.what, m=m, detail=detail if error is None else str(error),
                           at=self.arrived_at if kind == "in_position" else None)
        m.finish(error)
        for gate in m.reports:
            if error is None:
                gate.arrive(self.name, monotonic())
            else:
                gate.fail(self.name, error)
        if error is not None and self._queue and self._motion is m:
            self._drop_queue(MotionAborted(
                f"axis {self.name}: the queue was dropped: the {m.what} ended: {error}"))
        if self._motion is m:
            self._motion = None
            self._jog_deadline = None
            if state is AxisState.STANDSTILL and self._queue:
                state = None  # the queue's next starts now
            if state is not None:
                self.state = state
        self._wake_queue()

    def _restarted(self, prev: DriveStatus, st: DriveStatus) -> DriveStatus:
        """The drive may have restarted (``drive_restarted``): not homed, set up again
        before the next command, the profile's tracked state forgotten; ``st`` as it reads
        then (a drive whose enable is only tracked is not enabled after a restart)."""
        if prev.homed and not self._homed_lost:
            log.warning("axis %s: taken for restarted (position %s -> %s pulses at rest, "
                        "the drive %s): the axis is no longer homed", self.name,
                        prev.position, st.position,
                        "did not answer a while" if self.state is AxisState.OFFLINE
                        else "reports no enable of its own"
                        if "enabled" in self.profile.tracked
                        else "dropped its enable")
        self._homed_lost = self._setup_due = True
        self.profile.restarted()
        return replace(st, enabled=False) if "enabled" in self.profile.tracked else st

    async def _act(self) -> None:
        """What a poll asked for: a stop (limit, watchdog, alarm), a settings check."""
        reason = self._stop_due
        m = self._motion
        if (reason is None and m is not None and m.deadline is not None and not m.over
                and self._status_issued > m.deadline):  # a status requested after it
            timeout = MotionTimeout(f"axis {self.name}: the {m.what} did not complete in time "
                                    f"(its deadline passed {monotonic() - m.deadline:.1f} s ago)")
            log.warning("%s", timeout)
            await self._stop_now(str(timeout), error=timeout)
        if (
            reason is None
            and self.state is AxisState.CONTINUOUS_MOTION
            and self._jog_deadline is not None
            and monotonic() > self._jog_deadline
        ):
            reason = "jog watchdog expired (the application stopped feeding it)"
        if reason is not None:
            self._stop_due = None
            log.warning("axis %s: stopping: %s", self.name, reason)
            await self._stop_now(reason)
        st = self.status
        if self._learn_due and not self._lane.locked():
            try:
                async with self._lane:
                    await self.profile.learn()
                    self._learn_due = False
                    log.info("axis %s: the drive answers", self.name)
            except TransactionError as exc:
                log.info("axis %s: reading the drive failed, trying again later: %s",
                         self.name, exc)
        if (
            self._check_due
            and not self._setup_due
            and self._motion is None
            and not self._lane.locked()
            and st is not None
            and not st.moving
        ):
            try:
                async with self._lane:
                    await self._check_settings()
            except TransactionError as exc:
                log.info("axis %s: settings check failed, trying again later: %s", self.name, exc)

    async def _check_settings(self) -> list[str]:
        """Read back the volatile settings (reads only): if a reset lost them, the drive is
        set up again before the next command, and its position is no longer homed. The
        settings lost ([] = intact)."""
        self._check_due = False
        try:
            lost = await self.profile.lost_settings()
        except TransactionError:
            self._check_due = True
            raise
        if lost:
            log.warning("axis %s: the drive was reset (%s): it is set up again before the "
                        "next command; its position is no longer homed",
                        self.name, "; ".join(lost))
            self._setup_due = self._homed_lost = True
            self.profile.restarted()
            self._publish()
        return lost

    async def _stop_now(self, reason: str, *, error: BaseException | None = None) -> None:
        """Abort the motion under way and send a decelerating stop, not waiting for rest.

        For the actor (limit, watchdog, alarm) and for a motion whose caller failed or was
        cancelled; errors are logged (the caller is already failing).
        """
        m = self._motion
        self._note("stop", "stop", m=m, detail=reason)
        pending = self._drop_queue(MotionAborted(
            f"axis {self.name}: the queue was dropped: the axis was stopped: {reason}"))
        if m is not None:
            running = m.io is not None
            self._end_motion(m, error or MotionAborted(
                f"axis {self.name}: the {m.what} was stopped: {reason}"), None)
            if running and m.io_done is not None:
                pending.append(m.io_done)
        self._jog_deadline = None
        try:
            with self._stop_on_its_way():
                await self._send_stop_first(pending, self.profile.send_stop)
        except DrivebusError as exc:
            log.error("axis %s: stop failed: %s", self.name, exc)
            return
        self._poke_now()

    @contextlib.contextmanager
    def _stop_on_its_way(self) -> Iterator[None]:
        """Around sending a stop: the axis is Stopping (unless in ErrorStop, Offline or
        Disabled) until a status requested after the stop's reply shows it at rest. A
        status requested before that (a poll already on the wire) says nothing of the stop,
        and a second stop meanwhile is not one of an axis at rest: it sends its own. On
        leaving (sent, failed or cancelled), the stop's time is taken."""
        self._stops_on_way += 1
        if self.state not in (AxisState.ERROR_STOP, AxisState.OFFLINE, AxisState.DISABLED):
            self.state = AxisState.STOPPING
        try:
            yield
        finally:
            self._stops_on_way -= 1
            self._stop_sent_at = monotonic()

    async def _send_stop_first(self, pending: list[anyio.Event],
                               send: Callable[[], Awaitable[None]]) -> None:
        """Send the stop (``send``) now, ahead of the I/O of the motions it aborted
        (``pending``, cancelled: each ends with its transaction in flight), so that nothing
        of theirs follows it: the line begins nothing below ``Priority.EMERGENCY``
        (``hold_now``) until that I/O has ended, bounded (a stop never waits on I/O that
        does not end). The stop is queued in this step, before any stop its abort leads to
        (a group's other axes), and leaves after the transaction in flight however late the
        aborted tasks run on a busy machine. A failed stop is raised once that I/O ended."""
        if not pending:
            await send()
            return
        release = self.profile.slave.bus.hold_now()
        failure: DrivebusError | None = None  # raised as it is, not in a group

        async def aborted_io_ended() -> None:
            try:
                with anyio.move_on_after(_IO_END_BOUND) as scope:
                    for done in pending:
                        await done.wait()
            finally:
                release()  # a step of the stop below EMERGENCY may go from here on
            if scope.cancelled_caught:
                log.error("axis %s: the I/O of the motion a stop aborted did not end within "
                          "%.0f s: the line was let go regardless; the tasks wait at:\n  %s",
                          self.name, _IO_END_BOUND, "\n  ".join(where_tasks_wait()))

        try:
            async with anyio.create_task_group() as tg:
                tg.start_soon(aborted_io_ended)
                try:
                    await send()
                except DrivebusError as exc:
                    failure = exc
        finally:
            release()
        if failure is not None:
            raise failure

    def _poke_now(self) -> None:
        self._poke.set()

    async def _wait_rest(self, after: float, what: str) -> DriveStatus:
        """Wait for a status polled after ``after`` that shows the drive at rest (polled
        here where no actor runs: a machine whose tasks were cancelled from outside)."""
        if not self._actor_running:
            return await self._poll_rest(after, what)
        w = RestWait(after)
        self._rest_waits.append(w)
        self._waiters += 1
        self._poke_now()
        if self._routine_poll is not None:
            self._routine_poll.cancel()
        try:
            with anyio.fail_after(_STOP_TIMEOUT):
                await w.event.wait()
        except TimeoutError:
            seen = "the drive still reports motion" if self._status_issued > after else \
                "no status requested since could be read"
            raise MotionTimeout(
                f"axis {self.name}: {what}: {seen} after {_STOP_TIMEOUT:.0f} s") from None
        finally:
            self._waiters -= 1
            if w in self._rest_waits:
                self._rest_waits.remove(w)
        if w.error is not None:
            raise w.error
        assert self.status is not None
        return self.status

    async def _poll_rest(self, after: float, what: str) -> DriveStatus:
        """``_wait_rest`` without the actor: poll until a status shows the drive at rest."""
        with anyio.move_on_after(_STOP_TIMEOUT):
            while True:
                st = await self.refresh()  # sent now: after ``after``
                if not st.moving:
                    return st
                await anyio.sleep(self.config.poll.moving)
        raise MotionTimeout(f"axis {self.name}: {what}: the drive still reports motion "
                            f"after {_STOP_TIMEOUT:.0f} s")

    def _poll_when_at_rest(self, stopped: float, m: Motion | None,
                           decel_rps2: float | None) -> None:
        """Have the actor poll when a stop sent at ``stopped`` should have brought the
        drive to rest (from its speed and the deceleration), not a poll period later."""
        st = self.status
        speed = None
        if st is not None and st.velocity_rpm is not None:
            speed = abs(self.units.from_rpm(st.velocity_rpm))
        elif m is not None and m.plan is not None:
            speed = m.plan.speed
        decel = (self.units.from_rps2(decel_rps2) if decel_rps2 is not None
                 else m.plan.decel if m is not None and m.plan is not None
                 else self.config.decel)
        if speed and decel > 0:
            # The drive brakes from when the stop request arrived: one reply (8 bytes on
            # RTU, a write's echo) before ``stopped``, when its reply had come in.
            slave = self.profile.slave
            settings = slave.settings or slave.bus.line.settings
            reply = timing(settings).frame_time(_WRITE_REPLY_BYTES) if settings else 0.0
            self._poll_at = stopped - reply + speed / decel
            self._poke_now()

    def _wake_queue(self) -> None:
        self._queue_wake.set()

    def _drop_queue(self, error: BaseException) -> list[anyio.Event]:
        """End every queued motion with ``error`` (the first decision wins) and cancel
        what of it is on its way; the events of their I/O that still has to end."""
        pending: list[anyio.Event] = []
        queue, self._queue = self._queue, []
        for q in queue:
            if q.io is not None and q.io_done is not None:
                pending.append(q.io_done)
            if not q.over:
                self._note("aborted", q.what, m=q, detail=str(error))
            q.finish(error)
        if queue:
            self._wake_queue()
        return pending
