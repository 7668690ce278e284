"""ProgramRunner: the part of an axis that runs its queue of buffered and blended motions.

A motion given with ``buffer="buffered"`` or ``"blending"`` while another runs waits in
the axis's queue; the axis's sequencer task (a child of its actor) starts each one from
what the drive will do, not from the next routine poll:

* buffered: the next move is written to the drive while the one before it runs, where
  the drive latches a move's values at its start (``ProgramSupport.preload``); at the
  moment the running move is predicted to arrive the line is kept quiet, a short status
  read confirms the drive is in position, and the start command goes out at once.
* blending: where the drive takes a new target on the fly (``ProgramSupport.retarget``),
  the next target is sent so that it reaches the drive as the running move begins to
  brake: the axis passes the point between them without stopping. A drive that cannot,
  a reversal, or a motion before it that has no end, buffers instead and the motion's
  plan says why.

A stop, an emergency stop, a failed motion, an alarm or a lost drive drops the whole
queue (each queued motion ends with ``MotionAborted`` naming the cause) before anything
else is sent; frames of a queued motion not yet on the wire are dropped, so no start
ever follows a stop.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Awaitable, Callable
from typing import Any

import anyio
import anyio.lowlevel

from drivebus.bus import Priority
from drivebus.clock import PreciseTimer, monotonic
from drivebus.drives.programs import Completion
from drivebus.errors import (
    DrivebusError,
    MotionAborted,
)
from drivebus.motion.judge import switch_ahead
from drivebus.motion.motions import Motion
from drivebus.motion.queue import MotionQueue
from drivebus.motion.state import AxisState
from drivebus.motion.trajectory import Trajectory
from drivebus.tasks import shielded

__all__ = ["ProgramRunner"]

log = logging.getLogger(__name__)

_HOLD_LEAD = 0.04
"""The line is kept quiet from this long before a program's timed command, so that no
other transaction (a slow slave's poll) is on the wire then, seconds."""
_ARRIVAL_MARGIN = 0.0005
"""A confirming read reaches the drive this long after the predicted arrival, seconds."""
_CONFIRM_TRIES = 10
"""Short reads a buffered start makes at most before it leaves the rest to the polls
(back to back: the drive is due, each read takes its own wire time)."""
_TURNAROUND = 0.001
"""Assumed time a drive takes to answer, seconds."""
_BLEND_WORDS = 8
"""Registers a retarget writes before its command, at most (for its lead time)."""

class ProgramRunner(MotionQueue):
    """The sequencer task that runs the axis's queue (a child of its actor): it starts each
    queued motion from what the drive will do, not from the next routine poll."""

    async def _sequence(self) -> None:
        """Run the queue for ever (a child of the actor): each step returns when to look
        again; the queue, the running motion's start or its end wake it sooner."""
        self._timer = PreciseTimer()
        try:
            await self._sequence_steps()
        finally:
            self._timer.close()

    async def _sleep_until(self, deadline: float, over: anyio.Event) -> None:
        """Sleep to ``deadline`` on the clock, not the event loop's coarser timer; return
        early once ``over`` is set (the motion it times ended: a stop, say, which must
        not wait for a line this sequencer keeps quiet)."""
        if over.is_set():
            return
        async with anyio.create_task_group() as tg:

            async def cut_short() -> None:
                await over.wait()
                tg.cancel_scope.cancel()

            tg.start_soon(cut_short)
            await self._timer.sleep_until(deadline)
            tg.cancel_scope.cancel()

    async def _sequence_steps(self) -> None:
        while True:
            wake = self._queue_wake
            due = await self._queue_step()
            delay = due - monotonic()
            if delay > 0:
                with anyio.move_on_after(delay if math.isfinite(delay) else None):
                    await wake.wait()
            else:
                await anyio.lowlevel.checkpoint()
            if self._queue_wake is wake and wake.is_set():
                self._queue_wake = anyio.Event()

    async def _queue_step(self) -> float:
        """One step for the queue's head; when to look again (inf: when woken)."""
        if self._override_due:
            await self._apply_override()
        while self._queue and self._queue[0].over:
            self._queue.pop(0)
        cur = self._motion
        if not self._queue:
            if cur is not None and self._awaited(cur):
                return await self._report_arrival(cur)
            return math.inf
        head = self._queue[0]
        gate = head.gate
        if cur is None and gate is not None and not gate.open:
            if head.kind == "move" and not head.prepared:  # at rest: written while it waits
                async with self._lane:
                    if self._motion is None and not head.over:
                        head.prepared = await self._run_queued_io(
                            head, self._prepare_of(head), current=False)
            gate.notify(self._wake_queue)
            return math.inf
        if cur is None and gate is not None and gate.error is not None:
            head.finish(gate.error)
            self._drop_queue(gate.error)
            return monotonic()
        if cur is None:  # the motion before it ended in position
            async with self._lane:
                if self._queue and self._queue[0] is head and self._motion is None:
                    await self._start_queued(head)
            return monotonic()
        if cur.accepted_at is None or cur.trajectory is None or cur.io is not None:
            return math.inf  # not started yet, or no planned end (woken when it ends)
        if head.runs == "blended":
            return await self._blend_step(head, cur)
        return await self._buffered_step(head, cur)

    async def _buffered_step(self, head: Motion, cur: Motion) -> float:
        """Write the head while ``cur`` runs where the drive allows it, then at ``cur``'s
        predicted arrival confirm it by a short read and start the head at once."""
        assert cur.trajectory is not None
        move = head.kind == "move" and not head.prepared
        if move and self.profile.programs.preload:
            async with self._lane:
                if not head.over and cur is self._motion:
                    head.prepared = await self._run_queued_io(head, self._prepare_of(head),
                                                              current=False)
            return monotonic()
        arrive = cur.trajectory.end
        early = move and self._may_preload_braking(head, cur)
        write_at = arrive - self._write_lead()
        begin = (write_at if early else arrive) - _HOLD_LEAD
        if monotonic() < begin:
            return begin
        bus = self.profile.slave.bus
        async with self._lane:
            if early:
                async with bus.hold():
                    await self._sleep_until(write_at, cur.finished)
                if cur is self._motion and not head.over:
                    head.prepared = await self._run_queued_io(head, self._prepare_of(head),
                                                              current=False)
            async with bus.hold():
                arrived = await self._confirm_arrival(cur, arrive)
            if arrived and self._queue and self._queue[0] is head and self._motion is None:
                if head.gate is not None and not head.gate.open:
                    return monotonic()  # the others of the group are not all there yet
                if head.gate is None or head.gate.error is None:
                    await self._start_queued(head)
                return monotonic()
        return monotonic() + self.config.poll.moving

    @staticmethod
    def _awaited(m: Motion) -> bool:
        """True if other axes of a group wait for ``m`` to arrive."""
        return m.trajectory is not None and m.accepted_at is not None and m.io is None and any(
            not gate.open for gate in m.reports)

    async def _report_arrival(self, cur: Motion) -> float:
        """Confirm ``cur``'s arrival at its predicted moment (others wait for it)."""
        assert cur.trajectory is not None
        arrive = cur.trajectory.end
        if monotonic() < arrive - _HOLD_LEAD:
            return arrive - _HOLD_LEAD
        async with self._lane, self.profile.slave.bus.hold():
            await self._confirm_arrival(cur, arrive)
        return math.inf if cur.over else monotonic() + self.config.poll.moving

    def _prepare_of(self, head: Motion) -> Callable[[], Awaitable[None]]:
        assert head.prepare is not None
        return head.prepare

    def _may_preload_braking(self, head: Motion, cur: Motion) -> bool:
        """True if the drive lets the head be written as ``cur`` brakes (and it brakes no
        gentler than ``cur``)."""
        if not self.profile.programs.preload_braking or head.plan is None or cur.plan is None:
            return False
        quantized = self.envelope.quantized
        return quantized(head.plan).decel >= quantized(cur.plan).decel * (1 - 1e-9)

    async def _confirm_arrival(self, cur: Motion, arrive: float) -> bool:
        """Read the drive's completion right after ``arrive`` (again a little later while
        it still moves): True once ``cur`` is done in position."""
        wire = self._wire()
        request = 0.0 if wire is None else wire.frame_time(8)
        retry = 0.001
        await self._sleep_until(arrive + _ARRIVAL_MARGIN - request, cur.finished)
        for _ in range(_CONFIRM_TRIES):
            if cur.over:
                break
            issued = monotonic()
            if cur.kind == "move":
                c = await self.profile.read_completion(priority=Priority.EMERGENCY)
            else:
                c = None
            if c is None:
                st = await self.profile.read_status(priority=Priority.EMERGENCY)
                self._apply(st, issued)
            else:
                self._judge_completion(cur, c, issued)
            if cur.over:
                break
            await anyio.sleep(retry)
        return cur.over and cur.outcome is None

    def _judge_completion(self, m: Motion, c: Completion, issued: float) -> None:
        """A short read that shows ``m`` (a move) in position ends it; anything else (an
        alarm, a limit switch, a stop short) is left to the full status polls."""
        if m.over or m.accepted_at is None or issued <= m.accepted_at:
            return
        if c.alarm or c.moving or not c.in_position or switch_ahead(c, m.direction):
            if c.alarm:
                self._poke_now()
            return
        self.moves_done += 1
        self.arrived_at = issued
        self.arrived_after = max(self._status_issued, m.accepted_at)
        m.arrived = (self.arrived_after, issued)
        m.fresh = anyio.Event()  # its handle waits for a full status (the position)
        self._unconfirmed.append(m)
        self._poke_now()
        self._end_motion(m, None, AxisState.STANDSTILL)

    async def _blend_step(self, head: Motion, cur: Motion) -> float:
        """Send the head's target so that it reaches the drive as ``cur`` begins to brake."""
        assert cur.trajectory is not None
        lead = self._blend_lead()
        if head.blend_before_end is not None:
            send = cur.trajectory.end - head.blend_before_end - lead
        else:
            send = cur.trajectory.braking_starts() - lead
        now = monotonic()
        if cur.trajectory.end - lead <= now:
            head.runs = "buffered"
            head.reason = ("the move before it was about to arrive when its turn came: too "
                           "late to blend")
            log.info("axis %s: the %s is buffered: %s", self.name, head.what, head.reason)
            return now
        if now < send - _HOLD_LEAD:
            return send - _HOLD_LEAD
        async with self._lane:
            async with self.profile.slave.bus.hold():
                await self._sleep_until(send, cur.finished)
            if self._queue and self._queue[0] is head and self._motion is cur and not cur.over:
                await self._blend_into(head, cur)
        return monotonic()

    async def _blend_into(self, head: Motion, cur: Motion) -> None:
        """Hand the drive ``head``'s target on the fly: ``cur`` is done (blended), ``head``
        runs from the speed the drive has."""
        assert cur.trajectory is not None and head.retarget is not None
        assert cur.target is not None and head.target is not None and head.plan is not None
        self._queue.pop(0)
        passed = self.units.from_pulses(cur.target)
        before = cur.trajectory
        self._end_motion(cur, None, None, detail=f"blended into the {head.what}")
        target = self.units.from_pulses(head.target)

        def trajectory(t0: float) -> Trajectory:
            assert head.plan is not None  # as the retarget wrote it (the override in force)
            return before.retargeted(t0, target, self.envelope.quantized(head.plan))

        head.seen_motion = True
        self._promote(head)
        retarget = head.retarget

        async def io() -> None:
            await self._commit(head, retarget, trajectory=trajectory)

        if await self._run_queued_io(head, io) and head.trajectory is not None:
            head.blend_speed = head.trajectory.speed_at(passed)

    async def _start_queued(self, head: Motion) -> None:
        """Start the queue's head from rest (the lane is held): its start command (after
        writing it, if that was not done while the motion before it ran)."""
        self._queue.pop(0)
        if head.start is None and self.status is not None:
            head.start = self.status.position  # behind a jog that had no end position
            if head.start is not None and head.target is not None and head.kind == "move":
                head.direction = (head.target > head.start) - (head.target < head.start)
        self._promote(head)

        async def io() -> None:
            self.envelope.check_switch(head.direction, self.status)
            if head.kind == "jog":
                await self._start_jog(head)
                return
            assert head.begin is not None and head.prepare is not None
            if head.base_plan is not None and self._effective(head.base_plan) != head.plan:
                head.prepared = False  # the override changed since it was written
            if not head.prepared:
                await head.prepare()
            if head.ready is not None:
                await head.ready()
            await self._commit(head, head.begin, prepare=head.prepare)

        if await self._run_queued_io(head, io) and head.kind == "jog":
            self._arm_watchdog(head.watchdog)

    def _promote(self, head: Motion) -> None:
        """Make the queue's head the motion under way."""
        self._motion = head
        self.state = (AxisState.CONTINUOUS_MOTION if head.kind == "jog"
                      else AxisState.DISCRETE_MOTION)
        self._jog_deadline = None

    async def _run_queued_io(
        self, m: Motion, io: Callable[[], Awaitable[Any]], *, current: bool = True
    ) -> bool:
        """Run a queued motion's I/O (the lane is held); True if it went through. A failure
        ends the motion (the axis stopped if it may move) and drops the queue."""
        try:
            await self._locked_io(io, motion=m)
        except BaseException as exc:
            failure = exc

            async def clean_up() -> None:
                if current:
                    await self._after_failure(m, failure)
                elif not m.over:
                    self._note("error", m.what, m=m, detail=str(failure))
                    m.finish(failure)
                self._drop_queue(MotionAborted(
                    f"axis {self.name}: the queue was dropped: the {m.what} failed: "
                    f"{failure}"))

            await shielded(clean_up)
            if not isinstance(exc, DrivebusError):
                raise
            log.warning("axis %s: %s", self.name, exc)
            return False
        if current and m.plan is not None and m.target is not None and m.start is not None:
            distance = self.units.from_pulses(m.target - m.start)
            m.deadline = monotonic() + self.envelope.motion_timeout(m.plan, distance)
        return True

    async def _apply_override(self) -> None:
        """Give the motion under way the speed the override now asks, where the drive can
        change it on the fly: a jog's speed run (its running speed), a move or a bounded
        jog by its target given again at the new speed (a drive that takes a new target
        on the fly). Otherwise the new speed applies from the next motion (logged)."""
        self._override_due = False
        m = self._motion
        if (m is None or m.over or m.accepted_at is None or m.io is not None
                or m.base_plan is None or m.plan is None):
            return
        plan = self._effective(m.base_plan)
        if plan == m.plan:
            return
        try:
            self.check_drive(plan)
        except DrivebusError as exc:
            log.warning("axis %s: the override cannot apply to the %s: %s", self.name,
                        m.what, exc)
            return
        params = self.drive_params(plan)
        profile, target = self.profile, m.target
        if m.kind == "jog" and target is None and profile.programs.jog_speed:
            rpm = math.copysign(params.speed_rpm, m.direction)

            async def io() -> None:
                await profile.speed_run(rpm, params.accel_rps2, params.decel_rps2)
        elif m.kind in ("move", "jog") and target is not None and profile.programs.blends:

            async def io() -> None:
                await profile.retarget_absolute(target, params)
        else:
            log.info("axis %s: the %s drive cannot change the speed of the %s under way: the "
                     "override applies from the next motion", self.name, profile.family,
                     m.what)
            return
        async with self._lane:
            if m is not self._motion or m.over:
                return
            before, deadline = m.trajectory, m.deadline
            if not await self._run_queued_io(m, io, current=True):
                return
            m.plan, m.deadline = plan, deadline
            if before is not None and target is not None:
                now = monotonic()
                m.trajectory = before.retargeted(self._drive_started(now),
                                                 self.units.from_pulses(target),
                                                 self.envelope.quantized(plan))
                if m.deadline is not None:  # a slower motion may take longer
                    rest = m.trajectory.end - now
                    m.deadline = max(m.deadline, now + rest * 1.5 + 1.0
                                     + 4 * self.config.poll.moving)
        log.info("axis %s: the %s now runs at %g %s/s (override %g)", self.name, m.what,
                 plan.speed, self.config.unit, self.effective_override)

    def _write_lead(self) -> float:
        """How long a block write of a move's values takes, its silence included."""
        wire = self._wire()
        if wire is None:
            return 0.002
        return wire.transaction_time(9 + 2 * _BLEND_WORDS, 8, _TURNAROUND) + wire.t35 + 0.001

    def _blend_lead(self) -> float:
        """How long before the drive must have a new target it is sent: a block write of
        the move's values, then its command."""
        wire = self._wire()
        if wire is None:
            return 0.005
        return self._write_lead() + wire.frame_time(8) + 0.001
