"""Axis: the actor that owns one drive — its polls, its command stream and its safety rules.

One actor task per axis (``Axis.run``, owned by the machine) polls the drive at
``Priority.POLL`` (fast while a motion runs or someone waits, slow at rest; never two polls
of its own in flight) and makes every state decision from what it polls: a motion is done,
failed or over at the poll that shows it, so a later command from another task can never
turn an outcome that was already decided into another one.

Commands (``move_to``, ``home``, ``jog``, ``enable``, ...) may come from any task. They pass
the axis's command lane one at a time, and a refused command (bad argument, wrong state,
limit, not supported) changes nothing. A stop or an emergency stop never queues: it aborts
the motion being prepared or under way (frames of it not yet on the wire are dropped, and
its caller gets ``MotionAborted``), sends the stop at ``Priority.EMERGENCY`` once nothing of
that motion can follow it onto the wire, and returns when a status polled after it shows
the drive at rest.

Limits are guarantees, not polls: a jog towards a soft limit runs as a position move to the
limit, so the drive itself brakes to land on it; a hardware limit switch reached during a
motion puts the axis in ErrorStop (``LimitViolation``) until ``reset()``, after which only
motion away from the switch is allowed. A drive that was unreachable, or looks reset, has
its volatile settings read back and set up again before the next command.
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import math
from collections.abc import AsyncIterator, Awaitable, Callable, Sequence
from contextlib import asynccontextmanager
from dataclasses import dataclass, field, replace
from typing import Literal

import anyio
import anyio.lowlevel

from drivebus import checks
from drivebus.bus import Priority
from drivebus.clock import monotonic
from drivebus.config import AxisConfig
from drivebus.drives.base import DriveProfile, HomingParams, HomingSwitches, MoveParams
from drivebus.drives.status import DriveStatus
from drivebus.errors import (
    ArgumentError,
    ConfigError,
    DriveAlarm,
    DrivebusError,
    DriveOffline,
    LimitViolation,
    ModbusException,
    MotionAborted,
    MotionError,
    MotionTimeout,
    NotSupported,
    StateError,
    TransactionError,
)
from drivebus.motion.envelope import Envelope, MotionPlan
from drivebus.motion.events import AxisListener, MotionEvent, MotionEventKind
from drivebus.motion.gate import SegmentGate
from drivebus.motion.handle import (
    BufferMode,
    MotionHandle,
    QueuePlan,
    Runs,
    check_buffer,
    check_override,
)
from drivebus.motion.io import AxisIO
from drivebus.motion.program import ProgramRunner
from drivebus.motion.state import MOVING_STATES, AxisState
from drivebus.motion.trajectory import Phase, Trajectory
from drivebus.motion.units import Units
from drivebus.timing import timing

__all__ = ["Axis", "MotionPlan"]

log = logging.getLogger(__name__)

_STOP_TIMEOUT = 30.0
"""Longest a stop waits for the drive to report rest before it raises MotionTimeout."""

_RESET_GAP = 0.5
"""A silence between two answered polls longer than this may have hidden a power cycle."""

_COMMANDED_MOTION = frozenset(
    {AxisState.HOMING, AxisState.DISCRETE_MOTION, AxisState.CONTINUOUS_MOTION}
)
"""States of a motion under way (Stopping is a motion ending: at-rest commands wait)."""

_WRITE_REPLY_BYTES = 8
"""An RTU reply to a register write (function 06 or 16): address, function, 4 bytes, CRC."""


MotionKind = Literal["move", "home", "jog"]


@dataclass(eq=False)
class _Motion:
    """One motion of the axis, from its submission until the actor decides its outcome."""

    kind: MotionKind
    what: str
    """What it is, for messages: "move to 12.5", "jog at -10", "homing"."""
    prior: AxisState
    """The state before it: where a refused motion leaves the axis."""
    direction: int = 0
    """Drive direction (+1 towards positive pulses, -1, 0 unknown or homing)."""
    start: int | None = None
    target: int | None = None
    """Target in pulses (a move, or a jog bounded by a soft limit)."""
    plan: MotionPlan | None = None
    """Its speed and ramps as the drive gets them (the speed override applied)."""
    base_plan: MotionPlan | None = None
    """Its speed and ramps as asked, before the speed override."""
    speed: float = 0.0
    """A jog's signed speed in user units/s."""
    committing: bool = False
    """The start command was sent or is on its way: the drive may be moving."""
    accepted_at: float | None = None
    """When the drive acknowledged the start; statuses polled later judge the motion."""
    seen_motion: bool = False
    restarting: bool = False
    """A jog being stopped and started again (new speed or direction): rest is no end."""
    switches: HomingSwitches = field(default_factory=HomingSwitches)
    """A homing's limit switches: those it homes on, those where the drive reverses."""
    overrun: float = 0.0
    """How far (pulses) a homing may run on into a switch it reverses at: its braking
    distance and one poll's travel."""
    switch_seen: dict[int, int] = field(default_factory=dict)
    """A homing's reversal switches seen active, by side, with the position first seen."""
    switch_left: set[int] = field(default_factory=set)
    """The reversal switches a homing has reversed away from (met again: a violation)."""
    io: anyio.CancelScope | None = None
    """Its command I/O while that runs: a stop cancels it."""
    io_done: anyio.Event | None = None
    """Set when the command I/O that ``io`` belongs to has ended."""
    finished: anyio.Event = field(default_factory=anyio.Event)
    outcome: BaseException | None = None
    trajectory: Trajectory | None = None
    """Where it will be when (user units, monotonic s), planned once the drive took it."""
    deadline: float | None = None
    """When it has failed if it is not over (MotionTimeout), for a motion nobody awaits."""
    buffer: BufferMode = "aborting"
    runs: Runs = "now"
    reason: str = ""
    """Why it buffers although a blend was asked (the drive, or the geometry)."""
    prepare: Callable[[], Awaitable[None]] | None = None
    """A queued move: write everything but its start (the next ``begin`` starts it)."""
    begin: Callable[[], Awaitable[None]] | None = None
    """A queued motion: its start command (after ``prepare``)."""
    retarget: Callable[[], Awaitable[None]] | None = None
    """A queued move that blends: the new target given on the fly."""
    prepared: bool = False
    blend_speed: float | None = None
    watchdog: float | None = None
    """A queued jog's watchdog period (armed when it starts)."""
    gate: SegmentGate | None = None
    """A group segment: it starts once every axis of the segment before it is there."""
    blend_before_end: float | None = None
    """A blended path corner: the new target reaches the drive this long before the
    motion before it would arrive (None: as that motion begins to brake)."""
    may_reverse: bool = False
    """A path corner may blend although this axis reverses there."""
    ready: Callable[[], Awaitable[None]] | None = None
    """A queued group start: awaited once the move is written, before its start."""
    reports: list[SegmentGate] = field(default_factory=list)
    """Group segments it is part of: told when it is done (or failed)."""
    began: float | None = None
    """When the drive took it (its start or its new target), monotonic s."""
    fresh: anyio.Event | None = None
    """A move a short read found in position: set once a full status polled after that
    was taken in (its handle returns then, with the axis's position up to date)."""
    arrived: tuple[float, float] | None = None
    """When it was seen in position: (the poll before, the poll that saw it)."""
    both_ways: bool = False
    """It goes both ways (a position table): a limit switch either way ends it."""

    def queue_plan(self) -> QueuePlan:
        """How it runs, for its handle."""
        t = self.trajectory
        return QueuePlan(self.buffer, self.runs, self.reason, self.blend_speed,
                         None if t is None else t.start, None if t is None else t.end)

    @property
    def over(self) -> bool:
        """True once its outcome is decided."""
        return self.finished.is_set()

    def finish(self, error: BaseException | None = None) -> None:
        """Decide the outcome (the first decision wins) and cancel its I/O if it runs."""
        if self.finished.is_set():
            return
        self.outcome = error
        self.finished.set()
        if self.io is not None:
            self.io.cancel()


@dataclass(eq=False)
class _RestWait:
    """A stop waiting for a status polled after ``after`` that shows the drive at rest."""

    after: float
    event: anyio.Event = field(default_factory=anyio.Event)
    error: DrivebusError | None = None


_REFUSALS = (LimitViolation, StateError, ArgumentError, NotSupported, ConfigError, ModbusException)
"""Errors that mean nothing was started: raised before any frame, or the drive's own no."""

_NO_REST_WAIT = (StateError, ArgumentError, NotSupported, ConfigError, MotionAborted,
                 DriveOffline, TransactionError)
"""Errors a motion raises at once: refusals (nothing moved), an abort (whoever stopped the
axis waits for its rest), a drive that does not answer (no status could show rest)."""


class Axis(ProgramRunner, AxisIO):
    """A named axis: a drive profile, user units, limits, state and its actor."""

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
        self._motion: _Motion | None = None
        self._rest_waits: list[_RestWait] = []
        self._stop_sent_at = 0.0
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
        self._watchers: list[_Latest] = []
        self._listeners: list[AxisListener] = []
        self._queue: list[_Motion] = []
        self._queue_wake = anyio.Event()
        self._unconfirmed: list[_Motion] = []  # ended by a short read, no full status since
        self._override = 1.0
        self.machine_override: Callable[[], float] = lambda: 1.0
        """The machine's speed override (set by the machine that owns the axis)."""
        self._override_due = False  # the sequencer applies a new override to the motion
        self._actor_running = False  # the actor polls: a stop waits on its polls
        self.stops = 0
        """How many times ``stop()`` or ``halt_now()`` was called: a command that plans
        before it takes the axis (a group move) is aborted by a stop meanwhile."""

    # -- reading -----------------------------------------------------------------------------

    @property
    def commanded(self) -> bool:
        """True if a motion commanded through this axis may still be under way."""
        return self._commanded and self.state in MOVING_STATES

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

    # -- limits (the envelope's checks, as the axis's own) --------------------------------------

    def plan(
        self, speed: float | None = None, accel: float | None = None, decel: float | None = None
    ) -> MotionPlan:
        """The axis's defaults with any of them overridden, checked (``Envelope.plan``)."""
        return self.envelope.plan(speed, accel, decel)

    def drive_params(self, plan: MotionPlan) -> MoveParams:
        """``plan`` in drive units (rpm, rev/s²)."""
        return self.envelope.drive_params(plan)

    # -- speed override --------------------------------------------------------------------------

    @property
    def override(self) -> float:
        """The axis's own speed override (1.0: the speeds as asked; the machine's
        ``override`` multiplies it). Setting it scales every later motion's speed and, where
        the drive can change speed on the fly, the motion under way (the axis's sequencer
        sends that at once); ramps are kept. 0 < override <= 2; a faster speed is held to
        ``max_speed``. A per-axis override slows that axis alone: a group's axes then no
        longer arrive together (use the machine's)."""
        return self._override

    @override.setter
    def override(self, value: float) -> None:
        self._override = check_override(f"axis {self.name}: override", value)
        self.override_changed()

    @property
    def effective_override(self) -> float:
        """The speed factor the axis applies: its own override times the machine's."""
        return self._override * self.machine_override()

    def override_changed(self) -> None:
        """The factor changed: later motions use it; the sequencer applies it on the fly."""
        self._override_due = True
        self._wake_queue()

    def _effective(self, plan: MotionPlan) -> MotionPlan:
        """``plan`` with the speed override applied (held to ``max_speed``)."""
        factor = self.effective_override
        if factor == 1.0:
            return plan
        speed = plan.speed * factor
        top = self.config.max_speed
        return replace(plan, speed=min(speed, top) if top is not None else speed)

    def check_drive(self, plan: MotionPlan) -> None:
        """``LimitViolation`` in the axis's units if its drive cannot run ``plan``."""
        self.envelope.check_drive(plan)

    def check_limits(self, target: float) -> None:
        """LimitViolation if ``target`` lies outside the soft limits; nothing is sent."""
        self.envelope.check_limits(target)

    # -- the actor ------------------------------------------------------------------------------

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
                    # ahead of the other axes' routine polls.
                    st = await self.profile.read_status(priority=priority)
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
            issued > self._stop_sent_at
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

    def _judge(self, m: _Motion, st: DriveStatus, issued: float, prev_issued: float) -> None:
        """Decide from a status polled after ``m`` started: done, failed, or going on."""
        if m.kind == "home":
            self._judge_homing(m, st, issued)
            return
        switch = self._switch_ahead(st, m.direction) or (
            m.both_ways and (st.limit_positive or st.limit_negative))
        side = (1 if st.limit_positive else -1) if m.both_ways else 0
        if st.moving:
            m.seen_motion = True
            if switch:
                self._limit_hit(m, st, side=side)
            return
        tol = self.config.in_position_tolerance
        at = m.target is None or st.position is None or abs(st.position - m.target) <= tol
        late = issued > (m.accepted_at or 0.0) + max(0.25, 5 * self.config.poll.moving)
        here = f"{self.units.from_pulses(st.position or 0):.4f}"
        if m.kind == "move" and at:
            if st.in_position:
                self.moves_done += 1
                self.arrived_at = issued
                self.arrived_after = max(prev_issued, m.accepted_at or 0.0)
                self.arrived_by = max(st.timestamp or issued, issued)
                m.arrived = (self.arrived_after, self.arrived_by)
                self._end_motion(m, None, AxisState.STANDSTILL)
            return  # at the target, still settling
        if m.kind == "jog" and m.target is not None and at:
            log.info("axis %s: %s came to rest at the soft limit %s", self.name, m.what, here)
            self._end_motion(m, None, AxisState.STANDSTILL)
            return
        started = m.seen_motion or (st.position is not None and st.position != m.start)
        if switch and started:
            self._limit_hit(m, st, side=side)
        elif not started and not late:
            return  # not yet moving: the drive has a moment to start
        elif not started:
            why: DrivebusError = (
                LimitViolation(f"axis {self.name}: the drive did not start the {m.what}: the "
                               f"{'positive' if m.direction > 0 else 'negative'} limit switch "
                               f"is active")
                if switch
                else MotionError(f"axis {self.name}: the drive accepted the {m.what} but did "
                                 f"not start it")
            )
            self._end_motion(m, why, AxisState.STANDSTILL)
        elif m.kind == "jog":
            log.info("axis %s: %s ended at %s", self.name, m.what, here)
            self._check_due = True  # nobody stopped it: the drive did, or was reset
            self._end_motion(m, None, AxisState.STANDSTILL)
        else:
            self._end_motion(m, MotionError(
                f"axis {self.name}: the drive stopped at {here}, short of the {m.what}"
            ), AxisState.STANDSTILL)

    def _judge_homing(self, m: _Motion, st: DriveStatus, issued: float) -> None:
        """A homing is done when the drive reports homed at rest. A limit switch met while
        homing stops it at once (LimitViolation, ErrorStop) unless the method homes on it;
        one where the drive reverses (or that was active at the start) may be run into by
        the braking distance, and not met again once left (the home switch is missing)."""
        if st.homing_error:
            self.error = MotionError(f"axis {self.name}: the drive reports a homing error "
                                     f"(the homing failed at "
                                     f"{self.units.from_pulses(st.position or 0):.4f}); "
                                     f"reset() the axis before the next command")
            self._end_motion(m, self.error, AxisState.ERROR_STOP)
            if st.moving:
                self._stop_due = "homing error"
            return
        if st.moving:
            m.seen_motion = True
        elif st.homed and not st.homing:
            self._homed_lost = False
            self._end_motion(m, None, AxisState.STANDSTILL)
            return
        position = st.position or 0
        for side, active in ((1, st.limit_positive), (-1, st.limit_negative)):
            if side in m.switches.homes_on:
                continue
            if not active:
                if side in m.switch_seen:
                    m.switch_left.add(side)
                continue
            if side in m.switch_left:
                why = "met again after leaving it: no home switch was found"
            elif side in m.switches.reverses_at or side in m.switch_seen:
                first = m.switch_seen.setdefault(side, position)
                if (position - first) * side <= m.overrun:
                    if st.moving or m.seen_motion or issued <= (m.accepted_at or 0.0) + max(
                        0.25, 5 * self.config.poll.moving
                    ):
                        continue  # braking, reversing, or not yet started
                    why = "the drive did not start the homing"
                else:
                    why = "the drive ran on into it instead of reversing"
            else:
                why = "the homing method does not use it"
            self._limit_hit(m, st, side=side, why=why)
            return

    @staticmethod
    def _switch_ahead(st: DriveStatus, direction: int) -> bool:
        return (direction > 0 and st.limit_positive) or (direction < 0 and st.limit_negative)

    def _limit_hit(self, m: _Motion, st: DriveStatus, *, side: int = 0, why: str = "") -> None:
        name = "positive" if (side or m.direction) > 0 else "negative"
        because = f" ({why})" if why else ""
        self.error = LimitViolation(
            f"axis {self.name}: the {name} limit switch was reached at "
            f"{self.units.from_pulses(st.position or 0):.4f} during the {m.what}{because}; "
            f"reset() the axis, then only motion away from the switch is allowed"
        )
        self._end_motion(m, self.error, AxisState.ERROR_STOP)
        self._stop_due = f"{name} limit switch"

    def _end_motion(self, m: _Motion, error: BaseException | None, state: AxisState | None,
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
            self._publish()
        return lost

    async def _verify_settings(self) -> None:
        """Before a command: set the drive up if it is not (the first command, or a reset
        lost its settings), else check it still holds them."""
        if self._setup_due:
            await self._set_up()
        elif lost := await self._check_settings():
            await self._set_up(lost)  # what the check just read: not read again

    async def _set_up(self, changes: list[str] | None = None) -> None:
        """Write the profile's setup; a setting the drive held that it changes (``changes``
        if just read, else read now) is logged (warning) and kept in ``setup_changes``."""
        if changes is None:
            changes = await self.profile.lost_settings()
        if changes:
            log.warning("axis %s: setting up the %s drive changes %s", self.name,
                        self.profile.family, "; ".join(changes))
        await self.profile.setup()
        self.setup_changes = changes
        self._setup_due = self._check_due = self._learn_due = False
        log.info("axis %s: the %s drive is set up for commands", self.name, self.profile.family)

    async def setup(self) -> list[str]:
        """Set the drive up for commands now (the first command does it otherwise): the
        settings it changed, as in ``setup_changes``. Only at rest."""
        await self._settle("set the drive up")
        self._setup_due = True  # the command lane sets the drive up before ``io``

        async def io() -> None:
            self._at_rest_or_raise("set the drive up")

        await self._exclusive(io)
        return list(self.setup_changes)

    def listen(self, listener: AxisListener) -> Callable[[], None]:
        """Call ``listener`` with every status polled and every ``MotionEvent`` from now
        on (quick, never raising: it runs in the actor); returns the function that ends it.
        It adds no bus traffic."""
        self._listeners.append(listener)

        def end() -> None:
            if listener in self._listeners:
                self._listeners.remove(listener)

        return end

    def _note(self, kind: MotionEventKind, what: str, *, m: _Motion | None = None,
              detail: str = "", at: float | None = None, planned_end: float | None = None
              ) -> None:
        """Tell the listeners a motion event (nothing is built when nobody listens)."""
        if not self._listeners:
            return
        target = None if m is None or m.target is None else self.units.from_pulses(m.target)
        event = MotionEvent(self.name, kind, monotonic() if at is None else at, what,
                            target, planned_end, detail)
        for listener in self._listeners:
            listener(event)

    def _publish(self) -> None:
        if self.status is not None:
            for w in self._watchers:
                w.put(self.status)

    def _poke_now(self) -> None:
        self._poke.set()

    # -- the command lane ------------------------------------------------------------------------

    async def _exclusive(
        self, io: Callable[[], Awaitable[None]], *, motion: _Motion | None = None,
        setup_first: bool = True,
    ) -> None:
        """Run ``io`` alone on the axis; a motion's I/O can be cancelled by a stop. The
        drive is set up (if due) before ``io``; with ``setup_first=False``, ``io`` does it
        itself (``set_up_if_due``) after the refusals it decides from reads."""
        async with self._lane:
            await self._locked_io(io, motion=motion, setup_first=setup_first)

    async def set_up_if_due(self) -> None:
        """Set the drive up (or check it still is) if that is due: a command's I/O calls
        it before its first write, once every refusal is decided. Only in the lane."""
        if self._check_due or self._setup_due:
            await self._verify_settings()

    async def _locked_io(
        self, io: Callable[[], Awaitable[None]], *, motion: _Motion | None = None,
        setup_first: bool = True,
    ) -> None:
        """``_exclusive``'s body, for a caller that holds the lane."""
        if motion is not None and motion.over:
            raise motion.outcome or MotionAborted(f"axis {self.name}: {motion.what} aborted")
        scope, done = anyio.CancelScope(), anyio.Event()
        if motion is not None:
            motion.io, motion.io_done = scope, done
        try:
            with scope:
                if setup_first:
                    await self.set_up_if_due()
                await io()
        finally:
            if motion is not None:
                motion.io = None
            done.set()
            self._wake_queue()
        if motion is not None and scope.cancelled_caught:
            raise motion.outcome or MotionAborted(f"axis {self.name}: {motion.what} aborted")

    def _begin(
        self,
        kind: MotionKind,
        what: str,
        state: AxisState,
        *,
        direction: int = 0,
        allowed: frozenset[AxisState] = frozenset({AxisState.STANDSTILL}),
        accepted: Callable[[], object] | None = None,
    ) -> _Motion:
        """Take the axis for a motion (no I/O: StateError leaves everything as it was),
        then tell ``accepted``."""
        self.check_free(what, allowed)
        m = _Motion(kind, what, self.state, direction=direction)
        if self.status is not None:
            m.start = self.status.position
        log.debug("axis %s: %s begins (from %s)", self.name, what, m.start)
        self._motion = m
        self.state = state
        self._jog_deadline = None
        self._note("accepted", what)
        if accepted is not None:
            accepted()
        return m

    def check_free(
        self,
        what: str = "motion",
        allowed: frozenset[AxisState] = frozenset({AxisState.STANDSTILL}),
    ) -> None:
        """``StateError`` unless the axis may start a motion now (at rest, nothing under
        way); no I/O, nothing changes."""
        if self.state not in allowed or self._motion is not None or self._queue:
            detail = f" ({self.error})" if self.error is not None else ""
            running = f"; the {self._motion.what} is under way" if self._motion else ""
            if self._queue:
                running += f"; {len(self._queue)} more queued"
            raise StateError(
                f"axis {self.name}: cannot start the {what} in state {self.state}{detail}"
                f"{running}"
            )

    async def _run_motion(
        self,
        m: _Motion,
        io: Callable[[], Awaitable[None]],
        *,
        timeout: float | None,
        wait: bool = True,
        setup_first: bool = True,
    ) -> None:
        """Start ``m`` with ``io`` and (``wait``) await its outcome; clean up on any failure
        (``setup_first``: as for ``_exclusive``).

        A motion error (a timeout, a limit, an alarm, a drive that stopped short) is
        raised once the axis is at rest, so the next command finds it there (or the error
        says that it is still braking); a cancellation stops the axis and is re-raised at
        once."""
        try:
            await self._exclusive(io, motion=m, setup_first=setup_first)
            if not wait:
                return
            self._waiters += 1
            self._poke_now()
            if timeout is not None and m.deadline is None:
                m.deadline = monotonic() + timeout  # a speed override may push it back
            try:
                await self._outcome(m, timeout)
            finally:
                self._waiters -= 1
            if m.outcome is not None:
                raise m.outcome
        except BaseException as exc:
            with anyio.CancelScope(shield=True):
                await self._after_failure(m, exc)
                if not isinstance(exc, _NO_REST_WAIT):  # an error, or a cancellation
                    await self._come_to_rest(exc if isinstance(exc, DrivebusError) else None)
            raise

    async def _outcome(self, m: _Motion, timeout: float | None) -> None:
        """Wait until ``m``'s outcome is decided. At its deadline the drive is asked once
        more (a status requested after the deadline): ``MotionTimeout`` only if that too
        shows the motion unfinished, so a slow poll on a busy machine is no timeout."""
        while not m.finished.is_set():
            left = None if m.deadline is None else m.deadline - monotonic()
            if left is not None and left <= 0:
                with contextlib.suppress(TransactionError):  # the actor sees to Offline
                    await self.refresh()
                if m.finished.is_set():
                    return
                st = self.status
                where = "unknown" if st is None or st.position is None else (
                    f"{self.units.from_pulses(st.position):.4f} {self.config.unit}"
                )
                last = "" if st is None else (
                    f" (last status: position {where}, moving={st.moving}, "
                    f"in_position={st.in_position}, homed={st.homed})"
                )
                raise MotionTimeout(
                    f"axis {self.name}: the {m.what} did not complete within "
                    f"{timeout or 0:.1f} s{last}"
                )
            with anyio.move_on_after(left):
                await m.finished.wait()

    async def _come_to_rest(self, error: DrivebusError | None) -> None:
        """After a motion error (None: a cancellation) that stopped the axis: wait
        (bounded) for a status showing the drive at rest, so the caller goes on with the
        axis there; an error that it is not says so."""
        moving = self.status is not None and self.status.moving
        if not moving and self.state is not AxisState.STOPPING:
            return
        try:
            st = await self._wait_rest(monotonic(), "after the motion failed" if error else
                                       "after the motion was cancelled")
            if error is None:
                where = "" if st.position is None else \
                    f" at {self.units.from_pulses(st.position):.4f} {self.config.unit}"
                log.warning("axis %s: stopped%s (at rest)", self.name, where)
        except DrivebusError as exc:
            if error is not None:
                error.args = (f"{error} (and the axis did not come to rest: {exc})",
                              *error.args[1:])
            else:
                log.error("axis %s: %s", self.name, exc)

    async def _after_failure(self, m: _Motion, exc: BaseException) -> None:
        """Leave the axis right after ``m`` failed: unchanged if nothing moved, else stopped."""
        if m.over:
            return  # decided by the actor or a stop, which also saw to the axis
        maybe_moving = m.accepted_at is not None or (
            m.committing and not isinstance(exc, _REFUSALS)
        )
        if maybe_moving:
            cancelled = isinstance(exc, anyio.get_cancelled_exc_class())
            if cancelled:
                log.warning("axis %s: the %s was cancelled: stopping the axis", self.name,
                            m.what)
            await self._stop_now(f"the {m.what} was cancelled" if cancelled else
                                 f"the {m.what} failed: {exc!r}", error=exc)
            return
        m.finish(exc)
        if self._motion is m:  # refused before anything moved: back to where it was
            self._motion = None
            self.state = m.prior
            self._jog_deadline = None

    async def _commit(
        self,
        m: _Motion,
        start: Callable[[], Awaitable[None]],
        *,
        prepare: Callable[[], Awaitable[None]] | None = None,
        trajectory: Callable[[float], Trajectory] | None = None,
    ) -> None:
        """Send ``m``'s start command. If the drive may have been reset since it was
        prepared (a poll failed meanwhile), check its settings and ``prepare`` it again
        first. After a lost reply, read back before deciding: a start is never sent twice
        unless the drive shows it did not act on the first."""
        if prepare is not None and (self._check_due or self._setup_due):
            await self._verify_settings()
            await prepare()
        before = self.status
        m.committing = True
        try:
            await start()
        except ModbusException:
            raise  # the drive answered: it refused the start
        except TransactionError as exc:
            st = await self.refresh()
            if st.moving or (before is not None and st.position != before.position):
                log.info("axis %s: the %s was accepted (its reply was lost: %s)",
                         self.name, m.what, exc)
            else:
                log.info("axis %s: the %s was not executed (%s); sending it again",
                         self.name, m.what, exc)
                await start()
        m.accepted_at = self.command_started_at = monotonic()
        log.debug("axis %s: %s started (target %s pulses)", self.name, m.what, m.target)
        drive_start = m.began = self._drive_started(m.accepted_at)
        if trajectory is not None:
            m.trajectory = trajectory(drive_start)
        elif m.plan is not None and m.target is not None and m.start is not None:
            u = self.units
            m.trajectory = Trajectory.point_to_point(
                u.from_pulses(m.start), u.from_pulses(m.target),
                self.envelope.quantized(m.plan), t0=drive_start)
        if self._listeners:
            planned = None
            if m.plan is not None and m.target is not None and m.start is not None:
                distance = abs(self.units.from_pulses(m.target - m.start))
                planned = m.accepted_at + m.plan.duration(distance)
            self._note("started", m.what, m=m, at=m.accepted_at, planned_end=planned)
        self._commanded = True
        self._poke_now()
        self._wake_queue()

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
        for done in pending:
            await done.wait()
        self._jog_deadline = None
        try:
            await self.profile.stop(None)
        except DrivebusError as exc:
            log.error("axis %s: stop failed: %s", self.name, exc)
            return
        self._stop_sent_at = monotonic()
        if self.state not in (AxisState.ERROR_STOP, AxisState.OFFLINE, AxisState.DISABLED):
            self.state = AxisState.STOPPING
        self._poke_now()

    async def refresh(self) -> DriveStatus:
        """Read the drive's status now (at command priority) and take it in."""
        issued = monotonic()
        st = await self.profile.read_status(priority=Priority.COMMAND)
        self._apply(st, st.requested_at or issued)
        return st

    # -- motion commands -------------------------------------------------------------------------

    async def move_to(
        self,
        target: float,
        *,
        speed: float | None = None,
        accel: float | None = None,
        decel: float | None = None,
        buffer: BufferMode = "aborting",
        ready: Callable[[], Awaitable[None]] | None = None,
        accepted: Callable[[], object] | None = None,
    ) -> MotionHandle | None:
        """Move to ``target`` (user units); return when the drive reports it is there.

        ``buffer`` (PLCopen buffer mode) says what it does to a motion under way:
        ``"aborting"`` (the default) takes over where the drive takes a new target on the
        fly (the motion under way ends with ``MotionAborted``), else it is a
        ``StateError``. ``"buffered"`` queues it to start the moment the motion before it
        is in position; ``"blending"`` queues it to reach the drive before the motion
        before it brakes, so the axis does not stop (a drive that cannot buffers, and
        says why in the handle's ``plan``). Both return a ``MotionHandle`` once the move
        is taken (at once if nothing runs): await it for the move's outcome.

        With ``ready``, the move is prepared on the drive, then ``ready()`` is awaited
        before the start command goes out (a group starts its axes back to back).
        ``accepted()`` is called once every check has passed and the axis has taken the
        move (a service answers "running" then; a refusal raises before it).
        """
        buffer = check_buffer(buffer)
        target = checks.finite(f"axis {self.name}: target", target)
        base = self.plan(speed, accel, decel)
        plan = self._effective(base)
        self.check_limits(target)
        self.profile.check_supported("move_absolute")
        target_p = self.envelope.pulses(target)
        params = self.drive_params(plan)
        self.check_drive(plan)
        what = f"move to {target:g}"
        if buffer != "aborting" and (self._motion is not None or self._queue):
            return self._queue_move(what, target_p, base, buffer, accepted)
        if buffer == "aborting" and self._may_take_over():
            await self._take_over(what, target_p, base, accepted)
            return None
        here = self.status.position if self.status is not None else None
        direction = 0 if here is None else (target_p > here) - (target_p < here)
        self.envelope.check_switch(direction, self.status)
        m = self._begin("move", what, AxisState.DISCRETE_MOTION,
                        direction=direction, accepted=accepted)
        m.target, m.plan, m.base_plan, m.buffer = target_p, plan, base, buffer

        async def prepare() -> None:
            await self.profile.prepare_absolute(target_p, params)

        async def io() -> None:
            if m.start is None:  # no status polled yet: find out where the drive is
                st = await self.refresh()
                m.start = st.position
                if st.position is not None:
                    m.direction = (target_p > st.position) - (target_p < st.position)
                self.envelope.check_switch(m.direction, st)
            await self.set_up_if_due()
            await prepare()
            if ready is not None:
                await ready()
            await self._commit(m, self.profile.start_absolute, prepare=prepare)

        distance = self.units.from_pulses(target_p - (m.start or 0))
        return await self._run_or_hand(m, io, self.envelope.motion_timeout(plan, distance))

    async def _run_or_hand(
        self, m: _Motion, io: Callable[[], Awaitable[None]], timeout: float
    ) -> MotionHandle | None:
        """Start ``m``: aborting, await it (None); else return its handle once started
        (its deadline kept by the actor). ``io`` sets the drive up itself, after the
        refusals it decides from a fresh status (``set_up_if_due``)."""
        if m.buffer == "aborting":
            await self._run_motion(m, io, timeout=timeout, setup_first=False)
            return None
        await self._run_motion(m, io, timeout=None, wait=False, setup_first=False)
        m.deadline = monotonic() + timeout
        return self._handle(m)

    def _queue_move(
        self, what: str, target_p: int, base: MotionPlan,
        buffer: BufferMode, accepted: Callable[[], object] | None, *,
        origin: int | None = None,
        configure: Callable[[_Motion], object] | None = None,
    ) -> MotionHandle:
        """Queue a move to ``target_p`` pulses at ``base`` (before the override) behind
        the motions under way (checked); ``origin``: where it starts (default: where the
        motions under way end); ``configure``: called with the motion before it is queued.
        Its speed takes the override in force when it is written to the drive."""
        if origin is None:
            origin, _ = self._queue_origin(what)
        direction = 0 if origin is None else (target_p > origin) - (target_p < origin)
        m = _Motion("move", what, AxisState.STANDSTILL, direction=direction)
        m.start, m.target, m.plan, m.buffer = origin, target_p, self._effective(base), buffer
        m.base_plan = base
        profile = self.profile

        def params() -> MoveParams:
            assert m.plan is not None
            return self.drive_params(m.plan)

        async def prepare() -> None:
            m.plan = self._effective(base)
            await profile.prepare_absolute(target_p, params())

        async def retarget() -> None:
            m.plan = self._effective(base)
            await profile.retarget_absolute(target_p, params())

        m.prepare, m.begin, m.retarget = prepare, profile.start_absolute, retarget
        if configure is not None:
            configure(m)
        return self._enqueue(m, accepted)

    def queue_segment(
        self,
        what: str,
        target: float,
        plan: MotionPlan,
        *,
        origin: float,
        gate: SegmentGate | None = None,
        reports: SegmentGate | None = None,
        blend: bool = False,
        blend_before_end: float | None = None,
        ready: Callable[[], Awaitable[None]] | None = None,
    ) -> MotionHandle:
        """Queue a group segment's move to ``target`` (from ``origin``, where the segment
        before it ends) with the group's fitted ``plan``; it starts once ``gate`` is open
        (and ``ready()`` has returned), or blends ``blend_before_end`` s before the motion
        before it would arrive (``blend``: as it begins to brake); it tells ``reports``
        when it is done. Checked like ``move_to``; for ``AxisGroup``."""
        self.check_limits(target)
        self.profile.check_supported("move_absolute")
        self.check_drive(plan)
        target_p, origin_p = self.envelope.pulses(target), self.units.to_pulses(origin)

        def configure(m: _Motion) -> None:
            m.gate, m.ready, m.blend_before_end = gate, ready, blend_before_end
            m.may_reverse = blend_before_end is not None
            if reports is not None:
                m.reports.append(reports)

        blends = blend or blend_before_end is not None
        return self._queue_move(what, target_p, plan,
                                "blending" if blends else "buffered",
                                None, origin=origin_p, configure=configure)

    @property
    def busy(self) -> bool:
        """True while a motion commanded through the axis runs or waits in its queue."""
        return self._motion is not None or bool(self._queue)

    def blend_problem(self, target: float) -> str:
        """Why a move to ``target`` could not blend into the motions under way ("" if it
        could), as ``move_to(..., buffer="blending")`` would decide."""
        before = self._queue[-1] if self._queue else self._motion
        origin = None if before is None else before.target
        target_p = self.envelope.pulses(target)
        m = _Motion("move", "move", AxisState.STANDSTILL,
                    direction=0 if origin is None else (target_p > origin) - (target_p < origin))
        m.target = target_p
        m.retarget = self.profile.retarget_absolute  # type: ignore[assignment]
        return self._why_not_blend(m, before)

    def report_to(self, gate: SegmentGate) -> bool:
        """Have the last motion under way or queued tell ``gate`` when it is done; False
        if nothing runs (the axis is there already)."""
        last = self._queue[-1] if self._queue else self._motion
        if last is None or last.over:
            return False
        last.reports.append(gate)
        return True

    @property
    def planned_end(self) -> float | None:
        """Where the axis will be when the motions under way and queued are done (user
        units; None: a motion without an end position); at rest: its position."""
        last = self._queue[-1] if self._queue else self._motion
        if last is None:
            return self.position
        return None if last.target is None else self.units.from_pulses(last.target)

    def _may_take_over(self) -> bool:
        """True if a new move may replace the motion under way on the fly (aborting)."""
        m = self._motion
        return (
            m is not None and self.profile.programs.blends and m.kind in ("move", "jog")
            and m.target is not None and m.accepted_at is not None and m.io is None
            and not m.over
            and self.state in (AxisState.DISCRETE_MOTION, AxisState.CONTINUOUS_MOTION)
        )

    async def _take_over(
        self, what: str, target_p: int, base: MotionPlan,
        accepted: Callable[[], object] | None,
    ) -> None:
        """Replace the motion under way by a move to ``target_p`` given on the fly (the
        drive's retarget): the motion and the queue end with ``MotionAborted``."""
        cur = self._motion
        assert cur is not None
        here = self.status.position if self.status is not None else cur.target
        assert here is not None
        direction = (target_p > here) - (target_p < here)
        self.envelope.check_switch(direction, self.status)
        self._drop_queue(MotionAborted(
            f"axis {self.name}: the queued motions were dropped: the {what} takes over"))
        self._end_motion(cur, MotionAborted(
            f"axis {self.name}: the {cur.what} was aborted by the {what} (aborting)"), None)
        plan = self._effective(base)
        params = self.drive_params(plan)
        m = _Motion("move", what, AxisState.STANDSTILL, direction=direction)
        m.start, m.target, m.plan, m.runs = here, target_p, plan, "taken over"
        m.base_plan = base
        m.seen_motion, m.accepted_at = True, cur.accepted_at  # the drive is moving already
        self._motion, self.state, self._jog_deadline = m, AxisState.DISCRETE_MOTION, None
        self._note("accepted", what, m=m, detail="takes over")
        if accepted is not None:
            accepted()
        before, goal = cur.trajectory, self.units.from_pulses(target_p)
        quantized = self.envelope.quantized(plan)

        def trajectory(t0: float) -> Trajectory:
            if before is not None:
                return before.retargeted(t0, goal, quantized)
            return Trajectory.point_to_point(self.units.from_pulses(here), goal, quantized,
                                             t0=t0)

        async def retarget() -> None:
            await self.profile.retarget_absolute(target_p, params)

        async def io() -> None:
            await self._commit(m, retarget, trajectory=trajectory)

        distance = self.units.from_pulses(target_p - here)
        await self._run_motion(m, io, timeout=self.envelope.motion_timeout(plan, distance))

    async def move_by(
        self,
        distance: float,
        *,
        speed: float | None = None,
        accel: float | None = None,
        decel: float | None = None,
        buffer: BufferMode = "aborting",
        accepted: Callable[[], object] | None = None,
    ) -> MotionHandle | None:
        """Move by ``distance`` (user units) from the present position (``buffer``,
        ``accepted``: as for ``move_to``). Queued (buffered or blending), the distance
        counts from where the motion before it ends, PLCopen's reading."""
        buffer = check_buffer(buffer)
        distance = checks.finite(f"axis {self.name}: distance", distance)
        base = self.plan(speed, accel, decel)
        plan = self._effective(base)
        what = f"move by {distance:g}"
        if (buffer != "aborting" and (self._motion is not None or self._queue)) or (
            buffer == "aborting" and self._may_take_over()
        ):
            self.profile.check_supported("move_absolute")
            params = self.drive_params(plan)
            self.check_drive(plan)
            if buffer == "aborting":
                origin = self.status.position if self.status is not None else None
            else:
                origin, _ = self._queue_origin(what)
            if origin is None:
                raise StateError(f"axis {self.name}: the {what} has no start to count from: "
                                 f"the motion before it has no end position")
            target = self.units.from_pulses(origin) + distance
            self.check_limits(target)
            target_p = self.envelope.pulses(target)
            if buffer == "aborting":
                await self._take_over(what, target_p, base, accepted)
                return None
            return self._queue_move(what, target_p, base, buffer, accepted)
        self.profile.check_supported("move_relative")
        params = self.drive_params(plan)
        self.check_drive(plan)
        if self.position is not None:
            self.check_limits(self.position + distance)
        direction = self.envelope.drive_direction(distance)
        self.envelope.check_switch(direction, self.status)
        m = self._begin("move", what, AxisState.DISCRETE_MOTION,
                        direction=direction, accepted=accepted)
        m.plan, m.base_plan, m.buffer = plan, base, buffer

        async def io() -> None:
            st = await self.refresh()
            start = st.position or 0
            self.check_limits(self.units.from_pulses(start) + distance)
            self.envelope.check_switch(direction, st)
            target = self.envelope.pulses(self.units.from_pulses(start) + distance)
            m.start, m.target = start, target
            await self.set_up_if_due()
            await self._commit(m, lambda: self.profile.move_relative(target - start, params))

        return await self._run_or_hand(m, io, self.envelope.motion_timeout(plan, distance))

    async def run_table(
        self,
        targets: Sequence[float],
        *,
        speed: float | None = None,
        accel: float | None = None,
        dwell: float = 0.0,
        trigger_input: str,
    ) -> None:
        """Run ``targets`` (user units, absolute) one after the other from the drive's own
        position table: written first, then started with one command, so no bus latency
        falls between the moves (each waits ``dwell`` seconds at its target). Returns when
        the drive is at the last one. ``trigger_input``: an unwired input the drive's
        manual lets Modbus pull to start the table (NT86: its function becomes USER3,
        application mode 20; the next command restores mode 0). ``NotSupported`` naming
        the drive's reason where it has no table Modbus can start. A stop works as for
        any move."""
        if not isinstance(targets, Sequence) or isinstance(targets, str) or not targets:
            raise ArgumentError(f"axis {self.name}: a table needs a list of positions")
        goals = [checks.finite(f"axis {self.name}: table position {i + 1}", t)
                 for i, t in enumerate(targets)]
        dwell = checks.finite(f"axis {self.name}: dwell", dwell)
        if dwell < 0:
            raise ArgumentError(f"axis {self.name}: dwell {dwell:g} s is below 0")
        if not self.profile.table_rows:
            raise self.profile.unsupported("run its position table", self.profile.no_table)
        if len(goals) > self.profile.table_rows:
            raise ArgumentError(f"axis {self.name}: the {self.profile.family}'s table has "
                                f"{self.profile.table_rows} rows, not {len(goals)}")
        base = self.plan(speed, accel, accel)
        plan = self._effective(base)
        self.check_drive(plan)
        for t in goals:
            self.check_limits(t)
        trigger = self._terminal(trigger_input, output=False)
        pulses = [self.envelope.pulses(t) for t in goals]
        params = self.drive_params(plan)
        rows = [(p, params, dwell) for p in pulses]
        here = self.status.position if self.status is not None else None
        m = self._begin("move", f"table of {len(goals)} positions", AxisState.DISCRETE_MOTION,
                        direction=0)
        m.target, m.plan, m.base_plan, m.both_ways = pulses[-1], plan, base, True

        async def prepare() -> None:
            await self.profile.prepare_table(rows, trigger)

        def trajectory(t0: float) -> Trajectory:
            q = self.envelope.quantized(plan)
            phases: list[Phase] = []
            at = self.units.from_pulses(m.start if m.start is not None else pulses[0])
            for goal in goals:
                leg = Trajectory.point_to_point(at, goal, q, t0=t0)
                phases += leg.phases
                t0 = leg.end
                if dwell and goal is not goals[-1]:
                    phases.append(Phase(t0, dwell, goal, 0.0, 0.0))
                    t0 += dwell
                at = goal
            return Trajectory(tuple(phases), goals[-1])

        async def io() -> None:
            await prepare()
            await self._commit(m, self.profile.start_table, prepare=prepare,
                               trajectory=trajectory)

        start = self.units.from_pulses(here) if here is not None else goals[0]
        path = [start, *goals]
        distance = sum(abs(b - a) for a, b in itertools.pairwise(path))
        timeout = self.envelope.motion_timeout(plan, distance) + dwell * len(goals) + (
            len(goals) * plan.speed / plan.accel)
        await self._run_motion(m, io, timeout=timeout)

    async def home(self, *, accepted: Callable[[], object] | None = None) -> None:
        """Run the configured homing procedure; return when the drive reports homed
        (``accepted``: as for ``move_to``)."""
        h = self.config.homing
        self.profile.check_supported("home")
        switches = self.profile.homing_switches(h.method)
        u = self.units
        params = HomingParams(h.method, speed_rpm=u.to_rpm(h.speed), creep_rpm=u.to_rpm(h.creep),
                              accel_rps2=u.to_rps2(h.accel), offset=u.to_pulses(h.offset))
        self.profile.check_homing(params)  # every refusal before anything is sent
        m = self._begin("home", "homing", AxisState.HOMING, accepted=accepted)
        m.switches = switches
        # A reversing drive brakes into its switch, seen up to two polls late.
        travel = h.speed * h.speed / (2 * h.accel) + h.speed * 2 * self.config.poll.moving
        m.overrun = abs(u.to_pulses(travel)) + self.config.in_position_tolerance
        st = self.status
        if st is not None:  # a switch active at the start: the drive may turn away from it
            here = st.position or 0
            m.switch_seen = {side: here for side, on in ((1, st.limit_positive),
                                                         (-1, st.limit_negative)) if on}

        async def io() -> None:
            await self._commit(m, lambda: self.profile.start_homing(params))

        await self._run_motion(m, io, timeout=h.timeout)

    async def jog(
        self,
        speed: float,
        *,
        accel: float | None = None,
        decel: float | None = None,
        watchdog: float | None = 1.0,
        buffer: BufferMode = "aborting",
    ) -> MotionHandle | None:
        """Run at ``speed`` units/s (sign = direction) until ``stop()`` or until the
        watchdog expires; returns once running.

        The ``watchdog`` is on by default: the application must call ``jog`` (or ``feed``)
        again within ``watchdog`` seconds (1 s by default), or the actor stops the axis and
        logs a warning. ``watchdog=None`` jogs until ``stop()`` (``jogging()`` does that,
        and stops on leaving its block). With soft limits the jog is a position move to
        the limit in its direction, so it comes to rest on the limit at the latest.

        Called again while jogging with the same values it feeds the watchdog; with
        another speed or direction it changes the jog: on the fly where the description
        says the drive takes it (``[programs] jog_speed``: a new speed in the same
        direction; ``retarget``: towards a limit, a new target), else by a decelerating
        stop and a new start.

        ``buffer="buffered"`` (or ``"blending"``) queues the jog behind the motions under
        way, as for ``move_to``, and returns a ``MotionHandle``; its watchdog starts with
        it. A blend needs soft limits (the jog is then a move to the limit).
        """
        buffer = check_buffer(buffer)
        speed = checks.finite(f"axis {self.name}: speed", speed)
        if watchdog is not None:
            watchdog = checks.positive(f"axis {self.name}: watchdog", watchdog, unit="s")
        if speed == 0 and buffer == "aborting":
            await self.stop()
            return None
        if speed == 0:
            raise ArgumentError(f"axis {self.name}: a queued jog needs a speed other than 0")
        base = self.plan(abs(speed), accel, decel)
        plan = self._effective(base)
        bound = self.envelope.jog_bound(speed)
        procedure = "move_absolute" if bound is not None else "speed_run"
        self.profile.check_supported(procedure)
        self.check_drive(plan)
        what = f"jog at {speed:g}"
        if buffer != "aborting" and (self._motion is not None or self._queue):
            return self._queue_jog(what, speed, base, bound, watchdog, buffer)
        self.envelope.check_jog_room(speed, self.status)
        m = self._motion
        if m is not None and m.kind == "jog" and self.state is AxisState.CONTINUOUS_MOTION:
            if m.speed == speed and m.base_plan == base:
                self._arm_watchdog(watchdog)  # the same jog again: a feed
                return None
            await self._change_jog(m, speed, plan, bound, watchdog)
            m.base_plan = base
            return None
        m = self._begin("jog", what, AxisState.CONTINUOUS_MOTION,
                        direction=self.envelope.drive_direction(speed))
        m.speed, m.plan, m.target, m.buffer = speed, plan, bound, buffer
        m.base_plan = base
        await self._run_motion(m, lambda: self._start_jog(m), timeout=None, wait=False)
        self._arm_watchdog(watchdog)
        return None if buffer == "aborting" else self._handle(m)

    def _queue_jog(
        self, what: str, speed: float, base: MotionPlan, bound: int | None,
        watchdog: float | None, buffer: BufferMode,
    ) -> MotionHandle:
        """Queue a jog behind the motions under way (checked against where they end)."""
        origin, _ = self._queue_origin(what)
        if origin is not None and self.status is not None:
            self.envelope.check_jog_room(speed, replace(self.status, position=origin))
        m = _Motion("jog", what, AxisState.STANDSTILL,
                    direction=self.envelope.drive_direction(speed))
        m.speed, m.plan, m.target, m.start = speed, self._effective(base), bound, origin
        m.base_plan, m.buffer, m.watchdog = base, buffer, watchdog
        if bound is not None:

            async def retarget() -> None:
                m.plan = self._effective(base)
                await self.profile.retarget_absolute(bound, self.drive_params(m.plan))

            m.retarget = retarget
        return self._enqueue(m, None)

    async def _start_jog(self, m: _Motion) -> None:
        assert m.plan is not None
        params = self.drive_params(m.plan)
        if m.target is not None:
            target = m.target

            async def prepare() -> None:
                await self.profile.prepare_absolute(target, params)

            await prepare()
            await self._commit(m, self.profile.start_absolute, prepare=prepare)
            return
        rpm = math.copysign(params.speed_rpm, m.direction)
        await self._commit(m, lambda: self.profile.speed_run(
            rpm, params.accel_rps2, params.decel_rps2))

    async def _change_jog(
        self, m: _Motion, speed: float, plan: MotionPlan, bound: int | None,
        watchdog: float | None,
    ) -> None:
        """A running jog at a new speed or direction: on the fly where the description says
        the drive takes it (``[programs] jog_speed``, ``retarget``), else a decelerating
        stop and a new start (a drive that obeys no second start while it runs)."""
        direction = self.envelope.drive_direction(speed)
        programs = self.profile.programs

        async def io() -> None:
            if bound is None and direction == m.direction and programs.jog_speed:
                params = self.drive_params(plan)
                rpm = math.copysign(params.speed_rpm, direction)
                await self.profile.speed_run(rpm, params.accel_rps2, params.decel_rps2)
            elif bound is not None and direction == m.direction and programs.blends:
                # towards the same limit at another speed, given on the fly
                await self.profile.retarget_absolute(bound, self.drive_params(plan))
                before, limit = m.trajectory, self.units.from_pulses(bound)
                if before is not None:
                    m.trajectory = before.retargeted(
                        self._drive_started(monotonic()), limit, self.envelope.quantized(plan))
            else:
                m.restarting = True
                await self.profile.stop(None)
                after = self._stop_sent_at = monotonic()
                st = await self._wait_rest(after, f"the {m.what}'s change of speed")
                self.envelope.check_switch(direction, st)
                m.start, m.seen_motion, m.accepted_at = st.position, False, None
                m.restarting = False
                m.direction, m.target = direction, bound
                m.plan, m.speed, m.what = plan, speed, f"jog at {speed:g}"
                await self._start_jog(m)
            m.plan, m.speed, m.what = plan, speed, f"jog at {speed:g}"

        try:
            await self._exclusive(io, motion=m)
        except BaseException as exc:
            m.restarting = False
            with anyio.CancelScope(shield=True):
                if not m.over:
                    await self._stop_now(f"changing the jog failed: {exc!r}", error=exc)
            raise
        self._arm_watchdog(watchdog)

    def _arm_watchdog(self, watchdog: float | None) -> None:
        self._watchdog_period = watchdog
        self._jog_deadline = None if watchdog is None else monotonic() + watchdog

    def feed(self) -> None:
        """Keep a watchdog-guarded jog going for another watchdog period."""
        if self._jog_deadline is not None and self.state is AxisState.CONTINUOUS_MOTION:
            self._jog_deadline = monotonic() + (self._watchdog_period or 0.0)

    @asynccontextmanager
    async def jogging(
        self, speed: float, *, accel: float | None = None, decel: float | None = None
    ) -> AsyncIterator[Axis]:
        """Jog while inside the block; stops on exit, on error and on cancellation."""
        await self.jog(speed, accel=accel, decel=decel, watchdog=None)
        try:
            yield self
        finally:
            with anyio.CancelScope(shield=True):
                await self.stop()

    # -- stopping --------------------------------------------------------------------------------

    async def stop(self, *, decel: float | None = None) -> None:
        """Decelerating stop; returns when a status polled after it shows the drive at rest.

        It aborts whatever motion is being prepared or under way (its caller gets
        ``MotionAborted``); a later command from another task does not change its outcome.
        """
        decel_rps2 = None
        if decel is not None:
            decel_rps2 = self.units.to_rps2(checks.positive(f"axis {self.name}: decel", decel,
                                                           unit="units/s²"))
        await self._halt(emergency=False, decel_rps2=decel_rps2)

    async def halt_now(self) -> None:
        """Emergency stop; returns when a status polled after it shows the drive at rest."""
        await self._halt(emergency=True, decel_rps2=None)

    async def _halt(self, *, emergency: bool, decel_rps2: float | None) -> None:
        by = "halt_now()" if emergency else "stop()"
        self.stops += 1
        log.debug("axis %s: %s in state %s", self.name, by, self.state)
        offline = self.state is AxisState.OFFLINE
        m = self._motion
        self._note("stop", by, m=m)
        queued = bool(self._queue)
        pending = self._drop_queue(MotionAborted(
            f"axis {self.name}: the queued motions were dropped by {by}"))
        running = m is not None and m.io is not None
        if m is not None:
            self._end_motion(m, MotionAborted(f"axis {self.name}: the {m.what} was aborted by "
                                              f"{by}"), None)
        self._jog_deadline = None
        moving = self.status is not None and self.status.moving
        if m is None and not queued and not offline and not moving and self.state in (
            AxisState.STANDSTILL, AxisState.DISABLED, AxisState.ERROR_STOP
        ):
            return
        if self.state not in (AxisState.ERROR_STOP, AxisState.OFFLINE, AxisState.DISABLED):
            self.state = AxisState.STOPPING
        if running and m is not None and m.io_done is not None:
            pending.append(m.io_done)
        for done in pending:
            await done.wait()  # nothing of the aborted motions can follow the stop now
        try:
            # Offline or not, the stop is sent: the drive may be back (a network blip) and a
            # motor must not keep running because our polls failed.
            if emergency:
                await self.profile.emergency_stop()
            else:
                await self.profile.stop(decel_rps2)
        except TransactionError as exc:
            if offline:
                raise (self.error or DriveOffline(f"axis {self.name} is offline")) from exc
            raise
        self._stop_sent_at = after = monotonic()
        if not emergency:
            self._poll_when_at_rest(after, m, decel_rps2)
        await self._wait_rest(after, by)

    def _poll_when_at_rest(self, stopped: float, m: _Motion | None,
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

    async def _wait_rest(self, after: float, what: str) -> DriveStatus:
        """Wait for a status polled after ``after`` that shows the drive at rest (polled
        here where no actor runs: a machine whose tasks were cancelled from outside)."""
        if not self._actor_running:
            return await self._poll_rest(after, what)
        w = _RestWait(after)
        self._rest_waits.append(w)
        self._waiters += 1
        self._poke_now()
        try:
            with anyio.fail_after(_STOP_TIMEOUT):
                await w.event.wait()
        except TimeoutError:
            raise MotionTimeout(
                f"axis {self.name}: {what}: the drive still reports motion after "
                f"{_STOP_TIMEOUT:.0f} s"
            ) from None
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

    # -- other commands --------------------------------------------------------------------------

    def _at_rest_or_raise(self, what: str) -> None:
        if self._motion is not None or self._queue or self.state in MOVING_STATES or (
            self.status is not None and self.status.moving
        ):
            raise StateError(f"axis {self.name}: stop before you {what} ({self.state})")

    async def _settle(self, what: str) -> None:
        """Before a command that needs the drive at rest: ``StateError`` if a motion is
        under way; else decide on a status polled from now on, not a stale one. A drive
        still braking from a stop (Stopping, ErrorStop) is waited for, bounded."""
        if self._motion is not None or self._queue or self.state in _COMMANDED_MOTION:
            self._at_rest_or_raise(what)
        if self.state is AxisState.OFFLINE:
            return
        st = self.status
        if st is None or st.moving or self.state is AxisState.STOPPING:
            await self._wait_rest(monotonic(), what)
        self._at_rest_or_raise(what)

    async def enable(self) -> None:
        """Energise the motor (no-op if the drive already reports it enabled)."""

        async def io() -> None:
            st = self.status or await self.refresh()
            if st.enabled and not st.alarm:
                return
            self.profile.check_supported("enable")
            await self.set_up_if_due()
            await self.profile.enable()
            await self.refresh()

        await self._exclusive(io, setup_first=False)

    async def disable(self) -> None:
        """De-energise the motor (only at rest)."""
        self.profile.check_supported("disable")
        await self._settle("disable the motor")

        async def io() -> None:
            self._at_rest_or_raise("disable the motor")
            await self.profile.disable()
            self.state = AxisState.DISABLED
            await self.refresh()

        await self._exclusive(io)

    async def reset(self) -> None:
        """Leave ErrorStop (PLCopen MC_Reset): clear the drive's alarm if it has one.

        After a limit switch stopped the axis, only motion away from it is allowed.
        ``DriveAlarm`` if the alarm stays; ``NotSupported`` if the drive cannot clear it.
        A drive still braking from the stop that put the axis into ErrorStop is waited
        for (bounded); the decision is made on a status polled after the call.
        """
        await self._settle("reset the axis")

        async def io() -> None:
            self._at_rest_or_raise("reset the axis")
            st = await self.refresh()
            if st.alarm:
                self.profile.check_supported("clear_alarm")
                await self.set_up_if_due()
                await self.profile.clear_alarm()
                st = await self.refresh()
                if st.alarm:
                    raise DriveAlarm(
                        f"axis {self.name}: alarm {st.alarm_code} is still active: "
                        f"{st.alarm_text}",
                        code=st.alarm_code,
                        text=st.alarm_text,
                    )
            if self.state in (AxisState.ERROR_STOP, AxisState.STANDSTILL, AxisState.DISABLED):
                self.error = None
                self.state = AxisState.STANDSTILL if st.enabled else AxisState.DISABLED
            self._publish()

        await self._exclusive(io, setup_first=False)

    async def reset_alarm(self) -> None:
        """Clear the drive's alarm and leave ErrorStop (the same as ``reset()``)."""
        await self.reset()

    async def zero_position(self) -> None:
        """Make the present position zero (at rest)."""
        self.profile.check_supported("zero_position")
        await self._settle("zero the position")
        if self.state is not AxisState.STANDSTILL:
            raise StateError(f"axis {self.name}: cannot zero the position in state {self.state}")

        async def io() -> None:
            self._at_rest_or_raise("zero the position")
            await self.profile.zero_position()
            await self.refresh()

        await self._exclusive(io)

    # -- watching ----------------------------------------------------------------------------------

    async def watch(self) -> AsyncIterator[DriveStatus]:
        """Statuses as they are polled; a slow reader gets the latest, never blocks the actor."""
        slot = _Latest()
        self._watchers.append(slot)
        try:
            while True:
                yield await slot.get()
        finally:
            self._watchers.remove(slot)

    def __repr__(self) -> str:
        return f"Axis({self.name!r}, {self.profile.family}, {self.state})"


class _Latest:
    """A one-value mailbox: put overwrites, get waits for something new."""

    def __init__(self) -> None:
        self._value: DriveStatus | None = None
        self._event = anyio.Event()

    def put(self, value: DriveStatus) -> None:
        self._value = value
        self._event.set()

    async def get(self) -> DriveStatus:
        await self._event.wait()
        self._event = anyio.Event()
        assert self._value is not None
        return self._value
