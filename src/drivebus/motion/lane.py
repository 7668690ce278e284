"""The axis's command lane: how a command reaches its drive, one at a time.

Commands from any task pass the lane one at a time. A refused command (bad argument, wrong
state, limit, not supported) changes nothing and sends nothing: every refusal is decided
before the drive is set up for commands (``set_up_if_due``). A motion is begun (the axis
taken, no I/O), its I/O run (cancellable by a stop), its start committed (after a lost
reply, read back before a start is ever resent), and its outcome awaited, decided by the
actor; a failure or a cancellation stops the axis (shielded) and returns with it at rest.
A stop or an emergency stop never queues: it aborts the motion being prepared or under
way, sends the stop at ``Priority.EMERGENCY`` once nothing of that motion can follow it
onto the wire, and returns when a status polled after it shows the drive at rest.
"""

from __future__ import annotations

import contextlib
import functools
import logging
from collections.abc import Awaitable, Callable
from dataclasses import replace

import anyio
import anyio.lowlevel

from drivebus import checks
from drivebus.bus import Priority
from drivebus.clock import monotonic
from drivebus.drives.base import MoveParams
from drivebus.drives.status import DriveStatus
from drivebus.errors import (
    ArgumentError,
    ConfigError,
    DrivebusError,
    DriveOffline,
    LimitViolation,
    ModbusException,
    MotionAborted,
    MotionTimeout,
    NotSupported,
    StateError,
    TransactionError,
)
from drivebus.motion.actor import AxisActor
from drivebus.motion.envelope import MotionPlan
from drivebus.motion.handle import (
    check_override,
)
from drivebus.motion.motions import Motion, MotionKind
from drivebus.motion.state import MOVING_STATES, AxisState
from drivebus.motion.trajectory import Trajectory
from drivebus.tasks import shielded
from drivebus.timing import Timing, timing

__all__ = ["CommandLane"]

log = logging.getLogger(__name__)

_COMMANDED_MOTION = frozenset(
    {AxisState.HOMING, AxisState.DISCRETE_MOTION, AxisState.CONTINUOUS_MOTION}
)
"""States of a motion under way (Stopping is a motion ending: at-rest commands wait)."""

_TURNAROUND = 0.001
"""Assumed time a drive takes to answer a command, seconds."""
_NETWORK = 0.0003
"""Assumed one-way delay of a command on a Modbus TCP line, seconds."""

_REFUSALS = (LimitViolation, StateError, ArgumentError, NotSupported, ConfigError, ModbusException)
"""Errors that mean nothing was started: raised before any frame, or the drive's own no."""

_NO_REST_WAIT = (StateError, ArgumentError, NotSupported, ConfigError, MotionAborted,
                 DriveOffline, TransactionError)
"""Errors a motion raises at once: refusals (nothing moved), an abort (whoever stopped the
axis waits for its rest), a drive that does not answer (no status could show rest)."""

class CommandLane(AxisActor):
    """The axis's command lane, its stops and the speed override over its actor."""

    def plan(
        self, speed: float | None = None, accel: float | None = None, decel: float | None = None
    ) -> MotionPlan:
        """The axis's defaults with any of them overridden, checked (``Envelope.plan``)."""
        return self.envelope.plan(speed, accel, decel)

    def drive_params(self, plan: MotionPlan) -> MoveParams:
        """``plan`` in drive units (rpm, rev/s²)."""
        return self.envelope.drive_params(plan)

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

    async def _exclusive(
        self, io: Callable[[], Awaitable[None]], *, motion: Motion | None = None,
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
        self, io: Callable[[], Awaitable[None]], *, motion: Motion | None = None,
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

    def _begin(
        self,
        kind: MotionKind,
        what: str,
        state: AxisState,
        *,
        direction: int = 0,
        allowed: frozenset[AxisState] = frozenset({AxisState.STANDSTILL}),
        accepted: Callable[[], object] | None = None,
    ) -> Motion:
        """Take the axis for a motion (no I/O: StateError leaves everything as it was),
        then tell ``accepted``."""
        self.check_free(what, allowed)
        m = Motion(kind, what, self.state, direction=direction)
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
            if self.state is AxisState.DISABLED:  # what the user does next
                running += ": enable it first"
            raise StateError(
                f"axis {self.name}: cannot start the {what} in state {self.state}{detail}"
                f"{running}"
            )

    async def _run_motion(
        self,
        m: Motion,
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
            failure = exc

            async def clean_up() -> None:
                await self._after_failure(m, failure)
                if not isinstance(failure, _NO_REST_WAIT):  # an error, or a cancellation
                    await self._come_to_rest(
                        failure if isinstance(failure, DrivebusError) else None)

            await shielded(clean_up)  # (a second cancel does not cut the stop short)
            raise

    async def _outcome(self, m: Motion, timeout: float | None) -> None:
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

    async def _after_failure(self, m: Motion, exc: BaseException) -> None:
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
        m: Motion,
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
        m.committed.set()
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

    async def refresh(self) -> DriveStatus:
        """Read the drive's status now (at command priority) and take it in."""
        issued = monotonic()
        st = await self.profile.read_status(priority=Priority.COMMAND)
        self._apply(st, st.requested_at or issued)
        return st

    async def stop(self, *, decel: float | None = None) -> None:
        """Decelerating stop; returns when a status polled after it shows the drive at rest.

        It aborts whatever motion is being prepared or under way (its caller gets
        ``MotionAborted``); a later command from another task does not change its outcome.
        """
        await self._halt(emergency=False, decel_rps2=self.check_stop(decel))

    def check_stop(self, decel: float | None = None) -> float | None:
        """Refuse ``stop(decel=...)`` as it would be refused, nothing sent and the motion
        left as it is: a deceleration that is no positive number, or that the drive's stop
        cannot take (``ArgumentError``, ``NotSupported``, ``LimitViolation``); else the
        deceleration in rev/s² (None: the drive's own)."""
        if decel is None:
            return None
        decel_rps2 = self.units.to_rps2(checks.positive(f"axis {self.name}: decel", decel,
                                                       unit="units/s²"))
        try:
            self.profile.check_stop(decel_rps2)
        except LimitViolation as exc:
            raise LimitViolation(
                f"axis {self.name}: stop(decel={decel:g}) refused: {decel:g} "
                f"{self.config.unit}/s² is outside what its drive's stop takes (drive "
                f"{self.profile.family}: {exc}); stop() without decel stops on the "
                f"axis's own") from exc
        return decel_rps2

    async def halt_now(self) -> None:
        """Emergency stop; returns when a status polled after it shows the drive at rest."""
        await self._halt(emergency=True, decel_rps2=None)

    async def _halt(self, *, emergency: bool, decel_rps2: float | None) -> None:
        by = "halt_now()" if emergency else "stop()"
        log.debug("axis %s: %s in state %s", self.name, by, self.state)
        offline = self.state is AxisState.OFFLINE
        m = self._motion
        queued = bool(self._queue)
        moving = self.status is not None and self.status.moving
        at_rest = m is None and not queued and not offline and not moving and not (
            self._stops_on_way
        ) and self.state in (AxisState.STANDSTILL, AxisState.DISABLED, AxisState.ERROR_STOP)
        if not at_rest:
            self.profile.check_can_stop()  # a drive with no stop at all: refused, untouched
        self.stops += 1
        self._note("stop", by, m=m)
        pending = self._drop_queue(MotionAborted(
            f"axis {self.name}: the queued motions were dropped by {by}"))
        running = m is not None and m.io is not None
        if m is not None:
            self._end_motion(m, MotionAborted(f"axis {self.name}: the {m.what} was aborted by "
                                              f"{by}"), None)
        self._jog_deadline = None
        if at_rest:
            return  # nothing under way, no stop on its way (else it sends its own)
        if running and m is not None and m.io_done is not None:
            pending.append(m.io_done)
        try:
            with self._stop_on_its_way():
                # Offline or not, the stop is sent: the drive may be back (a network blip)
                # and a motor must not keep running because our polls failed.
                await self._send_stop_first(pending, functools.partial(
                    self.profile.send_stop, decel_rps2, emergency=emergency))
        except TransactionError as exc:
            if offline:
                raise (self.error or DriveOffline(f"axis {self.name} is offline")) from exc
            raise
        after = self._stop_sent_at
        if not emergency:
            self._poll_when_at_rest(after, m, decel_rps2)
        await self._wait_rest(after, by)

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

    def _wire(self) -> Timing | None:
        """The timing of the axis's frames (None: a Modbus TCP line)."""
        slave = self.profile.slave
        settings = slave.settings or slave.bus.line.settings
        return timing(settings) if settings is not None else None

    def _drive_started(self, accepted: float) -> float:
        """When the drive acted on a command whose reply came in at ``accepted``."""
        wire = self._wire()
        if wire is None:
            return accepted - _NETWORK
        return accepted - wire.frame_time(8) - _TURNAROUND
