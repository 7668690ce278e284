"""Axis: one actor per axis that polls its drive, plus awaitable, cancellation-safe motion.

The actor task (``Axis.run``, owned by the machine's task group) polls the drive's status
at ``Priority.POLL`` — fast while a motion is under way or someone waits, slow at rest —
never with more than one poll of its own in flight. Each poll is published to waiting
motion coroutines and ``watch()`` subscribers. Motion coroutines send their command,
then wait for a status *polled after the command* that shows completion; they raise on
alarm, limit, timeout or offline drive, and stop the axis (shielded) when cancelled.
"""

from __future__ import annotations

import logging
import math
from collections.abc import AsyncIterator, Awaitable, Callable
from contextlib import asynccontextmanager
from dataclasses import dataclass

import anyio

from drivebus.bus import Priority
from drivebus.clock import monotonic
from drivebus.config import AxisConfig
from drivebus.drives.base import DriveProfile, MoveParams
from drivebus.drives.status import DriveStatus
from drivebus.errors import (
    DriveAlarm,
    DrivebusError,
    DriveOffline,
    LimitViolation,
    MotionAborted,
    MotionError,
    MotionTimeout,
    StateError,
    TransactionError,
)
from drivebus.motion.state import MOVING_STATES, AxisState
from drivebus.motion.units import Units

__all__ = ["Axis", "MotionPlan"]

log = logging.getLogger(__name__)

_S = AxisState


@dataclass(frozen=True)
class MotionPlan:
    """Speed and ramps of one motion in user units (units/s, units/s²)."""

    speed: float
    accel: float
    decel: float

    def duration(self, distance: float) -> float:
        """Time a trapezoidal move of ``distance`` takes (triangular if it is short)."""
        d = abs(distance)
        v, a, b = self.speed, self.accel, self.decel
        ramp = v * v / (2 * a) + v * v / (2 * b)
        if d >= ramp:
            return d / v + v / (2 * a) + v / (2 * b)
        vp = math.sqrt(2 * d * a * b / (a + b))
        return vp / a + vp / b


class Axis:
    """A named axis: a drive profile, user units, limits, state and its polling actor."""

    def __init__(self, name: str, config: AxisConfig, profile: DriveProfile) -> None:
        self.name = name
        self.config = config
        self.profile = profile
        self.units = Units(config.pulses_per_rev, config.units_per_rev)
        self.state: AxisState = _S.STANDSTILL
        self.status: DriveStatus | None = None
        self.error: DrivebusError | None = None
        """What put the axis into ErrorStop or Offline."""
        self._status_issued = 0.0  # when the poll behind ``status`` was sent
        self._tick = anyio.Event()
        self._poke = anyio.Event()
        self._waiters = 0
        self._generation = 0  # bumped by every command: a waiter of an older one is aborted
        self._busy: str | None = None
        self._commanded = False
        self._jog_deadline: float | None = None
        self._watchdog_period: float | None = None
        self._watchers: list[_Latest] = []
        self.moves_done = 0
        self.command_started_at = 0.0
        """When the last motion command was accepted by the drive (for start skew)."""

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
        return self.units.from_rpm(st.velocity_rpm)

    def plan(
        self, speed: float | None = None, accel: float | None = None, decel: float | None = None
    ) -> MotionPlan:
        """The axis's defaults with any of them overridden; checked against max_speed."""
        c = self.config
        p = MotionPlan(
            abs(speed) if speed is not None else c.speed,
            accel if accel is not None else c.accel,
            decel if decel is not None else c.decel,
        )
        if p.speed <= 0 or p.accel <= 0 or p.decel <= 0:
            raise LimitViolation(f"axis {self.name}: speed, accel and decel must be > 0 ({p})")
        if c.max_speed is not None and p.speed > c.max_speed:
            raise LimitViolation(
                f"axis {self.name}: speed {p.speed} exceeds max_speed {c.max_speed} units/s"
            )
        return p

    def drive_params(self, plan: MotionPlan) -> MoveParams:
        """``plan`` in drive units (rpm, rev/s²)."""
        u = self.units
        return MoveParams(u.to_rpm(plan.speed), u.to_rps2(plan.accel), u.to_rps2(plan.decel))

    def check_limits(self, target: float) -> None:
        """LimitViolation if ``target`` lies outside the soft limits; nothing is sent."""
        lim = self.config.limits
        if lim is not None and not lim[0] <= target <= lim[1]:
            raise LimitViolation(
                f"axis {self.name}: target {target} is outside the soft limits "
                f"{lim[0]}..{lim[1]}"
            )

    # -- the actor ------------------------------------------------------------------------------

    async def run(self) -> None:
        """Poll the drive until cancelled; owned by the machine's task group."""
        fails = 0
        poll = self.config.poll
        next_poll = monotonic()
        while True:
            fast = self.state in MOVING_STATES or self._waiters > 0
            next_poll = min(next_poll, monotonic() + (poll.moving if fast else poll.idle))
            with anyio.move_on_after(max(0.0, next_poll - monotonic())):
                await self._poke.wait()
            self._poke = anyio.Event()
            issued = monotonic()
            next_poll = issued + (poll.moving if fast else poll.idle)
            try:
                st = await self.profile.read_status(priority=Priority.POLL)
            except TransactionError as exc:
                fails += 1
                if fails >= poll.offline_after and self.state is not _S.OFFLINE:
                    self.error = DriveOffline(
                        f"axis {self.name}: drive {self.profile.family} at address "
                        f"{self.profile.slave.address} stopped answering ({exc})"
                    )
                    self.state = _S.OFFLINE
                    log.warning("%s", self.error)
                    self._publish()
                continue
            fails = 0
            orphaned = self.state is _S.OFFLINE and st.moving and self._busy is None
            self._apply(st, issued)
            if orphaned:
                # Back from Offline and still moving with nobody's command waiting on it
                # (the motion's caller already got DriveOffline): stop it.
                log.warning("axis %s: drive answers again while moving: stopping it", self.name)
                await self._send_stop(emergency=False)
            await self._watchdogs()

    def _apply(self, st: DriveStatus, issued: float) -> None:
        if self.state is _S.OFFLINE:
            log.info("axis %s: drive answers again", self.name)
            self.error = None
            self.state = _S.STOPPING if st.moving else _S.STANDSTILL
        if st.alarm and self.state is not _S.ERROR_STOP:
            self.error = DriveAlarm(
                f"axis {self.name}: drive alarm {st.alarm_code}: {st.alarm_text}".rstrip(": "),
                code=st.alarm_code,
                text=st.alarm_text,
            )
            self.state = _S.ERROR_STOP
        elif not st.alarm and not st.enabled and self.state is not _S.ERROR_STOP:
            self.state = _S.DISABLED
        elif self.state is _S.STANDSTILL and st.moving and not self._busy:
            self.state = _S.DISCRETE_MOTION  # moved by someone else (a panel, a PLC)
        elif self._settled(st, issued):
            self.state = _S.STANDSTILL
        self.status = st
        self._status_issued = issued
        self._publish()

    def _settled(self, st: DriveStatus, issued: float) -> bool:
        """True if a state the actor owns has come to rest (nobody's command waits on it)."""
        if self.state is _S.DISABLED:
            return st.enabled
        resting = not st.moving and issued > self.command_started_at
        if self.state is _S.STOPPING:
            return resting
        return self.state is _S.DISCRETE_MOTION and not self._busy and resting

    def _publish(self) -> None:
        tick, self._tick = self._tick, anyio.Event()
        tick.set()
        if self.status is not None:
            for w in self._watchers:
                w.put(self.status)

    async def _watchdogs(self) -> None:
        """Stop a jog whose application stopped feeding it, or that crossed a soft limit."""
        if self.state is not _S.CONTINUOUS_MOTION:
            return
        reason = ""
        if self._jog_deadline is not None and monotonic() > self._jog_deadline:
            reason = "jog watchdog expired (the application stopped feeding it)"
        lim, pos, st = self.config.limits, self.position, self.status
        if lim is not None and pos is not None and st is not None and st.velocity_rpm is not None:
            if (pos >= lim[1] and st.velocity_rpm > 0) or (pos <= lim[0] and st.velocity_rpm < 0):
                reason = f"soft limit reached at {pos:.3f}"
        elif lim is not None and pos is not None and not lim[0] <= pos <= lim[1]:
            reason = f"soft limit reached at {pos:.3f}"
        if reason:
            log.warning("axis %s: stopping: %s", self.name, reason)
            self._jog_deadline = None
            await self._send_stop(emergency=False)

    # -- waiting for the drive -------------------------------------------------------------------

    def _poke_now(self) -> None:
        self._poke.set()

    async def _wait_until(
        self,
        cond: Callable[[DriveStatus], bool],
        *,
        after: float,
        timeout: float,
        what: str,
        generation: int,
    ) -> DriveStatus:
        """Wait for a status polled after ``after`` that meets ``cond``."""
        self._waiters += 1
        self._poke_now()
        try:
            with anyio.fail_after(timeout):
                while True:
                    tick = self._tick
                    await tick.wait()
                    if generation != self._generation:
                        raise MotionAborted(f"axis {self.name}: {what} aborted by {self._busy}")
                    if self.state is _S.OFFLINE:
                        raise self.error or DriveOffline(f"axis {self.name} is offline")
                    st = self.status
                    if st is None or self._status_issued < after:
                        continue
                    if st.alarm:
                        raise self.error or DriveAlarm(f"axis {self.name}: drive alarm")
                    if cond(st):
                        return st
        except TimeoutError:
            st = self.status
            last = "" if st is None else (
                f" (last status: position {st.position}, moving={st.moving}, "
                f"in_position={st.in_position}, homed={st.homed})"
            )
            raise MotionTimeout(
                f"axis {self.name}: {what} did not complete within {timeout:.1f} s{last}"
            ) from None
        finally:
            self._waiters -= 1

    def _begin(self, state: AxisState, what: str, allowed: frozenset[AxisState]) -> int:
        if self.state not in allowed:
            detail = f" ({self.error})" if self.error is not None else ""
            raise StateError(
                f"axis {self.name}: cannot {what} in state {self.state}{detail}"
                + (f"; {self._busy} is running" if self._busy else "")
            )
        self._generation += 1
        self._busy = what
        self._commanded = True
        self.state = state
        self._jog_deadline = None
        return self._generation

    async def _fresh_status(self) -> DriveStatus:
        st = await self.profile.read_status(priority=Priority.COMMAND)
        self._apply(st, monotonic())
        return st

    async def _send_stop(self, *, emergency: bool) -> None:
        """Send a stop; failures are logged (the caller is already failing or cancelled)."""
        try:
            if emergency:
                await self.profile.emergency_stop()
            else:
                await self.profile.stop(None)
        except DrivebusError as exc:
            log.error("axis %s: stop failed: %s", self.name, exc)
            return
        self.command_started_at = monotonic()
        if self.state not in (_S.ERROR_STOP, _S.OFFLINE, _S.DISABLED):
            self.state = _S.STOPPING
        self._poke_now()

    @asynccontextmanager
    async def _stop_on_failure(self) -> AsyncIterator[None]:
        """Around a motion: on any failure or cancellation, stop the axis, then re-raise."""
        mine = self._busy
        try:
            yield
        except BaseException as exc:
            with anyio.CancelScope(shield=True):
                if not isinstance(exc, MotionAborted) and self.state in MOVING_STATES:
                    await self._send_stop(emergency=False)
            raise
        finally:
            if self._busy == mine:
                self._busy = None

    # -- commands --------------------------------------------------------------------------------

    async def enable(self) -> None:
        """Energise the motor (no-op if the drive already reports it enabled)."""
        st = self.status or await self._fresh_status()
        if st.enabled and not st.alarm:
            return
        await self.profile.enable()
        await self._fresh_status()

    async def disable(self) -> None:
        """De-energise the motor (only at rest)."""
        if self.state in MOVING_STATES:
            raise StateError(f"axis {self.name}: stop before disabling ({self.state})")
        await self.profile.disable()
        self.state = _S.DISABLED
        await self._fresh_status()

    async def move_to(
        self,
        target: float,
        *,
        speed: float | None = None,
        accel: float | None = None,
        decel: float | None = None,
        ready: Callable[[], Awaitable[None]] | None = None,
    ) -> None:
        """Move to ``target`` (user units); return when the drive reports it is there.

        With ``ready``, the move is prepared on the drive, then ``ready()`` is awaited
        before the start command goes out (a group starts its axes back to back).
        """
        self.check_limits(target)
        plan = self.plan(speed, accel, decel)
        await self._move(target, plan, relative=None, ready=ready)

    async def move_by(
        self,
        distance: float,
        *,
        speed: float | None = None,
        accel: float | None = None,
        decel: float | None = None,
    ) -> None:
        """Move by ``distance`` (user units) from the present position."""
        plan = self.plan(speed, accel, decel)
        st = await self._fresh_status()
        start = self.units.from_pulses(st.position or 0)
        self.check_limits(start + distance)
        await self._move(start + distance, plan, relative=distance)

    async def _move(
        self,
        target: float,
        plan: MotionPlan,
        *,
        relative: float | None,
        ready: Callable[[], Awaitable[None]] | None = None,
    ) -> None:
        gen = self._begin(_S.DISCRETE_MOTION, "move", frozenset({_S.STANDSTILL}))
        async with self._stop_on_failure():
            before = self.status
            target_p = self.units.to_pulses(target)
            params = self.drive_params(plan)
            start_p = before.position if before is not None and before.position is not None else 0
            distance = self.units.from_pulses(target_p - start_p)
            timeout = plan.duration(distance) * 1.5 + 1.0 + 4 * self.config.poll.moving
            t_cmd = monotonic()
            if relative is None and ready is not None:
                await self.profile.prepare_absolute(target_p, params)
                await ready()
                t_cmd = monotonic()
                await self.profile.start_absolute()
            elif relative is None:
                await self.profile.move_absolute(target_p, params)
            else:
                await self._start_relative(self.units.to_pulses(relative), params, before)
            self.command_started_at = monotonic()
            tol = self.config.in_position_tolerance
            seen_motion = False
            start_by = self.command_started_at + max(0.25, 5 * self.config.poll.moving)

            def arrived(st: DriveStatus) -> bool:
                nonlocal seen_motion
                seen_motion = seen_motion or st.moving
                if st.moving:
                    return False
                at = st.position is None or abs(st.position - target_p) <= tol
                if at and st.in_position:
                    return True
                if not seen_motion and st.position == start_p and monotonic() > start_by:
                    limits = [n for n, on in (("negative", st.limit_negative),
                                              ("positive", st.limit_positive)) if on]
                    why = f" ({' and '.join(limits)} limit switch active)" if limits else ""
                    raise MotionError(
                        f"axis {self.name}: the drive accepted the move to {target} but did "
                        f"not start it{why}"
                    )
                if seen_motion and not at:
                    side = (" at the positive limit" if st.limit_positive
                            else " at the negative limit" if st.limit_negative else "")
                    raise MotionError(
                        f"axis {self.name}: drive stopped at "
                        f"{self.units.from_pulses(st.position or 0):.4f}{side}, "
                        f"short of the target {target}"
                    )
                return False

            await self._wait_until(arrived, after=t_cmd, timeout=timeout, what="move",
                                   generation=gen)
            self.state = _S.STANDSTILL
            self.moves_done += 1

    async def _start_relative(
        self, distance: int, params: MoveParams, before: DriveStatus | None
    ) -> None:
        """Send a relative move; after a lost reply, read back before deciding (no blind retry)."""
        try:
            await self.profile.move_relative(distance, params)
        except TransactionError as exc:
            st = await self._fresh_status()
            moved = st.moving or (
                before is not None and st.position is not None and st.position != before.position
            )
            if moved:
                log.info("axis %s: relative move was accepted (reply lost: %s)", self.name, exc)
                return
            log.info("axis %s: relative move was not executed (%s); sending it again",
                     self.name, exc)
            await self.profile.move_relative(distance, params)

    async def home(self) -> None:
        """Run the configured homing procedure; return when the drive reports homed."""
        h = self.config.homing
        gen = self._begin(_S.HOMING, "home", frozenset({_S.STANDSTILL}))
        async with self._stop_on_failure():
            u = self.units
            t_cmd = monotonic()
            await self.profile.home(
                h.method,
                speed_rpm=u.to_rpm(h.speed),
                creep_rpm=u.to_rpm(h.creep),
                accel_rps2=u.to_rps2(h.accel),
                offset=u.to_pulses(h.offset),
            )
            self.command_started_at = monotonic()
            await self._wait_until(
                lambda st: st.homed and not st.homing and not st.moving,
                after=t_cmd,
                timeout=h.timeout,
                what="homing",
                generation=gen,
            )
            self.state = _S.STANDSTILL

    async def jog(
        self,
        speed: float,
        *,
        accel: float | None = None,
        decel: float | None = None,
        watchdog: float | None = 1.0,
    ) -> None:
        """Run at ``speed`` units/s (sign = direction) until ``stop()``.

        With a ``watchdog`` the application must call ``jog`` (or ``feed``) again within
        that many seconds, or the actor stops the axis. Calling it while jogging changes
        the speed.
        """
        if speed == 0:
            await self.stop()
            return
        plan = self.plan(speed, accel, decel)
        lim, pos = self.config.limits, self.position
        if lim is not None and pos is not None and (
            (speed > 0 and pos >= lim[1]) or (speed < 0 and pos <= lim[0])
        ):
            raise LimitViolation(f"axis {self.name}: at soft limit {pos:.3f}, cannot jog that way")
        self._begin(
            _S.CONTINUOUS_MOTION, "jog", frozenset({_S.STANDSTILL, _S.CONTINUOUS_MOTION})
        )
        async with self._stop_on_failure():
            p = self.drive_params(plan)
            rpm = math.copysign(p.speed_rpm, speed)
            await self.profile.speed_run(rpm, p.accel_rps2, p.decel_rps2)
            self.command_started_at = monotonic()
        self._jog_deadline = None if watchdog is None else monotonic() + watchdog
        self._watchdog_period = watchdog

    def feed(self) -> None:
        """Keep a watchdog-guarded jog going for another watchdog period."""
        if self._jog_deadline is not None and self.state is _S.CONTINUOUS_MOTION:
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

    async def stop(self, *, decel: float | None = None) -> None:
        """Decelerating stop; returns when the drive reports standstill."""
        await self._halt(emergency=False, decel=decel)

    async def halt_now(self) -> None:
        """Emergency stop; returns when the drive reports standstill."""
        await self._halt(emergency=True, decel=None)

    async def _halt(self, *, emergency: bool, decel: float | None) -> None:
        offline = self.state is _S.OFFLINE
        if not offline and self.state in (_S.STANDSTILL, _S.DISABLED) and not (
            self.status is not None and self.status.moving
        ):
            return
        self._generation += 1  # whoever waits for a motion is aborted
        self._busy = "halt_now()" if emergency else "stop()"
        self._jog_deadline = None
        try:
            t_cmd = monotonic()
            try:
                # Offline or not, the stop is sent: the drive may be back (a network blip)
                # and a motor must not keep running because our polls failed.
                if emergency:
                    await self.profile.emergency_stop()
                else:
                    await self.profile.stop(None if decel is None else self.units.to_rps2(decel))
            except TransactionError as exc:
                if offline:
                    raise (self.error or DriveOffline(f"axis {self.name} is offline")) from exc
                raise
            if offline:
                self.error = None
            self.command_started_at = monotonic()
            if self.state is not _S.ERROR_STOP:
                self.state = _S.STOPPING
            gen = self._generation
            await self._wait_until(lambda st: not st.moving, after=t_cmd, timeout=30.0,
                                   what="stop", generation=gen)
            if self.state is _S.STOPPING:
                self.state = _S.STANDSTILL
        finally:
            self._busy = None

    async def reset_alarm(self) -> None:
        """Clear the drive's alarm and leave ErrorStop (DriveAlarm if it stays)."""
        await self.profile.clear_alarm()
        st = await self._fresh_status()
        if st.alarm:
            raise DriveAlarm(
                f"axis {self.name}: alarm {st.alarm_code} is still active: {st.alarm_text}",
                code=st.alarm_code,
                text=st.alarm_text,
            )
        self.error = None
        self.state = _S.STANDSTILL if st.enabled else _S.DISABLED

    async def zero_position(self) -> None:
        """Make the present position zero (at rest)."""
        if self.state is not _S.STANDSTILL:
            raise StateError(f"axis {self.name}: cannot zero the position in state {self.state}")
        await self.profile.zero_position()
        await self._fresh_status()

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
