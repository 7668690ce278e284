"""Jogging: an axis run at a speed until stopped, with a watchdog by default.

A jog towards a soft limit is a position move to the limit, so the drive itself brakes to
land on it; without limits it is a speed run. A change of speed or direction goes on the
fly only where the description says the drive takes it (``[programs] jog_speed`` for a
speed run, ``retarget`` towards a limit); else the axis stops (decelerating) and starts
the jog again. A jog not fed within its watchdog period is stopped by the actor.
"""

from __future__ import annotations

import functools
import logging
import math
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from dataclasses import replace

from drivebus import checks
from drivebus.clock import monotonic
from drivebus.errors import (
    ArgumentError,
    MotionAborted,
)
from drivebus.motion.actor import _WRITE_REPLY_BYTES
from drivebus.motion.envelope import MotionPlan
from drivebus.motion.handle import (
    BufferMode,
    MotionHandle,
    check_buffer,
)
from drivebus.motion.lane import _TURNAROUND
from drivebus.motion.motions import Motion
from drivebus.motion.program import ProgramRunner
from drivebus.motion.state import AxisState
from drivebus.tasks import shielded

__all__ = ["Jogging"]

log = logging.getLogger(__name__)



class Jogging(ProgramRunner):
    """The jog commands of an axis (``jog``, ``feed``, ``jogging``)."""

    async def jog(
        self,
        speed: float,
        *,
        accel: float | None = None,
        decel: float | None = None,
        watchdog: float | None = 1.0,
        buffer: BufferMode = "aborting",
        accepted: Callable[[], object] | None = None,
    ) -> MotionHandle | None:
        """Run at ``speed`` units/s (sign = direction) until ``stop()`` or until the
        watchdog expires; returns once running. ``accepted()`` is called once every check
        has passed and the axis has taken the jog (as for ``move_to``).

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
            if accepted is not None:
                accepted()
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
            return self._queue_jog(what, speed, base, bound, watchdog, buffer, accepted)
        self.envelope.check_jog_room(speed, self.status)
        m = self._motion
        if m is not None and m.kind == "jog" and self.state is AxisState.CONTINUOUS_MOTION:
            if accepted is not None:
                accepted()
            if m.speed == speed and m.base_plan == base:
                self._arm_watchdog(watchdog)  # the same jog again: a feed
                return None
            await self._change_jog(m, speed, plan, bound, watchdog)
            m.base_plan = base
            return None
        m = self._begin("jog", what, AxisState.CONTINUOUS_MOTION,
                        direction=self.envelope.drive_direction(speed), accepted=accepted)
        m.speed, m.plan, m.target, m.buffer = speed, plan, bound, buffer
        m.base_plan = base
        await self._run_motion(m, lambda: self._start_jog(m), timeout=None, wait=False)
        self._arm_watchdog(watchdog)
        return None if buffer == "aborting" else self._handle(m)

    def _queue_jog(
        self, what: str, speed: float, base: MotionPlan, bound: int | None,
        watchdog: float | None, buffer: BufferMode,
        accepted: Callable[[], object] | None = None,
    ) -> MotionHandle:
        """Queue a jog behind the motions under way (checked against where they end)."""
        origin, _ = self._queue_origin(what)
        if origin is not None and self.status is not None:
            self.envelope.check_jog_room(speed, replace(self.status, position=origin))
        m = Motion("jog", what, AxisState.STANDSTILL,
                    direction=self.envelope.drive_direction(speed))
        m.speed, m.plan, m.target, m.start = speed, self._effective(base), bound, origin
        m.base_plan, m.buffer, m.watchdog = base, buffer, watchdog
        if bound is not None:

            async def retarget() -> None:
                m.plan = self._effective(base)
                await self.profile.retarget_absolute(bound, self.drive_params(m.plan))

            m.retarget = retarget
        return self._enqueue(m, accepted)

    async def _start_jog(self, m: Motion) -> None:
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
        self, m: Motion, speed: float, plan: MotionPlan, bound: int | None,
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
                # towards the same limit at another speed, given on the fly; not once the
                # move brakes onto the limit: a drive whose stop ramps by the ramp it was
                # last given would brake a gentler one's rounding past the limit
                before, limit = m.trajectory, self.units.from_pulses(bound)
                if before is None or not before.can_brake_by(
                        monotonic(), self.envelope.quantized(plan).decel,
                        lead=self._retarget_lead()):
                    log.info("axis %s: the jog brakes onto its limit already: its speed "
                             "is not changed", self.name)
                    m.speed, m.what = speed, f"jog at {speed:g}"
                    return
                await self.profile.retarget_absolute(bound, self.drive_params(plan))
                m.trajectory = before.retargeted(
                    self._drive_started(monotonic()), limit, self.envelope.quantized(plan))
            else:
                m.restarting = True
                await self.profile.send_stop()
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
            if not m.over:
                await shielded(functools.partial(
                    self._stop_now, f"changing the jog failed: {exc!r}", error=exc))
            raise
        self._arm_watchdog(watchdog)

    def _retarget_lead(self) -> float:
        """How long a new ramp given on the fly takes to reach the drive: its block write
        and its start, each a transaction (on Modbus TCP: 10 ms)."""
        wire = self._wire()
        if wire is None:
            return 0.01
        return 2 * wire.transaction_time(29, _WRITE_REPLY_BYTES, _TURNAROUND)

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
    ) -> AsyncIterator[Jogging]:
        """Jog while inside the block; stops on exit, on error and on cancellation. A jog
        that a fault ended inside the block (a limit switch, an alarm, the drive lost)
        raises its error as the block is left, as a move that meets one does."""
        await self.jog(speed, accel=accel, decel=decel, watchdog=None)
        m = self._motion
        try:
            yield self
        except BaseException:
            await shielded(self.stop)  # (a second cancel does not cut it short)
            raise
        fault = m.outcome if m is not None and m.over else None
        await shielded(self.stop)
        if fault is not None and not isinstance(fault, MotionAborted):
            raise fault
