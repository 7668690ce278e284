"""Axis: one drive as an axis, the public face of its rooms.

``Axis`` is the motion commands a user calls (``move_to``, ``move_by``, ``run_table``,
``home``, ``enable``, ``disable``, ``reset``, ``zero_position``), over the rooms that do
the work: the actor that owns the drive (``actor``: polls, state, the judge's verdicts),
the command lane (``lane``: one command at a time, refusals before any frame, stops that
never queue), the queue of buffered and blended motions (``queue``) and its sequencer
(``program``), jogging (``jog``) and digital I/O (``io``).

Limits are guarantees, not polls: a jog towards a soft limit runs as a position move to
the limit, so the drive itself brakes to land on it; a hardware limit switch reached during
a motion puts the axis in ErrorStop (``LimitViolation``) until ``reset()``, after which only
motion away from the switch is allowed. A drive that was unreachable, or looks reset, has
its volatile settings read back and set up again before the next command.
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Awaitable, Callable, Sequence

from drivebus import checks
from drivebus.clock import monotonic
from drivebus.drives.base import HomingParams
from drivebus.errors import (
    ArgumentError,
    DriveAlarm,
    MotionAborted,
    StateError,
)
from drivebus.motion.envelope import MotionPlan
from drivebus.motion.handle import (
    BufferMode,
    MotionHandle,
    check_buffer,
)
from drivebus.motion.io import AxisIO
from drivebus.motion.jog import Jogging
from drivebus.motion.motions import Motion
from drivebus.motion.state import AxisState
from drivebus.motion.trajectory import Phase, Trajectory

__all__ = ["Axis", "MotionPlan"]

log = logging.getLogger(__name__)



class Axis(Jogging, AxisIO):
    """A named axis: a drive profile, user units, limits, state and its actor."""

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
        self.check_drive(plan)  # first: a refusal in the axis's units, naming it
        params = self.drive_params(plan)
        what = f"move to {target:g}"
        if buffer == "aborting":
            await self._start_on_its_way()
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
        self, m: Motion, io: Callable[[], Awaitable[None]], timeout: float
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

    async def _start_on_its_way(self) -> None:
        """Aborting: wait for a move or jog whose start is still on its way to the drive
        (taken, its start not yet acknowledged), where the drive takes a new target on the
        fly, so that the new move takes it over instead of being refused. Bounded by that
        start's I/O; a stop meanwhile is not held up."""
        m = self._motion
        if (m is not None and not m.over and m.accepted_at is None
                and m.kind in ("move", "jog") and self.profile.programs.blends):
            await m.committed.wait()

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
        m = Motion("move", what, AxisState.STANDSTILL, direction=direction)
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
        if buffer == "aborting":
            await self._start_on_its_way()
        if (buffer != "aborting" and (self._motion is not None or self._queue)) or (
            buffer == "aborting" and self._may_take_over()
        ):
            self.profile.check_supported("move_absolute")
            self.check_drive(plan)
            params = self.drive_params(plan)
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
        self.check_drive(plan)  # first: a refusal in the axis's units, naming it
        params = self.drive_params(plan)
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

    def __repr__(self) -> str:
        return f"Axis({self.name!r}, {self.profile.family}, {self.state})"
