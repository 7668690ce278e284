"""The axis's queue of motions: what is queued behind the motion under way, and how each
queued motion will run (buffered, or blended where the drive takes a new target on the
fly). The sequencer that starts them is ``drivebus.motion.program``.
"""

from __future__ import annotations

import logging
from collections.abc import Awaitable, Callable

from drivebus.drives.base import MoveParams
from drivebus.errors import (
    LimitViolation,
    StateError,
)
from drivebus.motion.envelope import MotionPlan
from drivebus.motion.gate import SegmentGate
from drivebus.motion.handle import (
    BufferMode,
    MotionHandle,
)
from drivebus.motion.lane import CommandLane
from drivebus.motion.motions import Motion
from drivebus.motion.state import AxisState

__all__ = ["MotionQueue"]

log = logging.getLogger(__name__)



class MotionQueue(CommandLane):
    """The queueing side of an axis: buffered and blended moves and group segments, their
    handles, and where the axis will be when what is queued is done."""

    @property
    def queued(self) -> int:
        """How many motions wait in the axis's queue."""
        return len(self._queue)

    def _handle(self, m: Motion) -> MotionHandle:
        return MotionHandle(self.name, m, self.stop)

    def _queue_origin(self, what: str) -> tuple[int | None, int]:
        """Where the axis will be (pulses; None: unknown) and which way it will have gone
        when a motion queued now starts; ``StateError`` if nothing can be queued now."""
        if self._queue:
            last = self._queue[-1]
            return last.target, last.direction
        m = self._motion
        if m is None or self.state not in (AxisState.DISCRETE_MOTION,
                                           AxisState.CONTINUOUS_MOTION):
            raise StateError(f"axis {self.name}: cannot queue the {what} in state {self.state}")
        return m.target, m.direction

    def _enqueue(self, m: Motion, accepted: Callable[[], object] | None) -> MotionHandle:
        """Put ``m`` at the end of the queue (it passed every check) and decide how it runs."""
        before = self._queue[-1] if self._queue else self._motion
        m.runs, m.reason = "buffered", ""
        if m.buffer == "blending":
            m.reason = self._why_not_blend(m, before)
            if not m.reason:
                m.runs = "blended"
            else:
                log.info("axis %s: the %s is buffered, not blended: %s", self.name, m.what,
                         m.reason)
        self._queue.append(m)
        self._note("accepted", m.what, m=m, detail=f"queued ({m.runs})")
        if accepted is not None:
            accepted()
        self._wake_queue()
        self._poke_now()
        return self._handle(m)

    def _why_not_blend(self, m: Motion, before: Motion | None) -> str:
        """Why ``m`` cannot blend into ``before`` ("" if it can)."""
        support = self.profile.programs
        if not support.blends:
            return f"the {self.profile.family} drive cannot take a new target while it moves: " \
                   f"{support.no_retarget}"
        if before is None or before.target is None or before.kind == "home":
            return "the motion before it has no end position to blend at"
        if m.target is None or m.retarget is None:
            return "a jog without soft limits is a speed run: it starts when the motion " \
                   "before it is done"
        if (m.direction == 0 or m.direction != before.direction) and not m.may_reverse:
            return "it reverses: the axis stops at the point between them"
        return ""

    def _queue_move(
        self, what: str, target_p: int, base: MotionPlan,
        buffer: BufferMode, accepted: Callable[[], object] | None, *,
        origin: int | None = None,
        configure: Callable[[Motion], object] | None = None,
    ) -> MotionHandle:
        """Queue a move to ``target_p`` pulses at ``base`` (before the override) behind
        the motions under way (checked); ``origin``: where it starts (default: where the
        motions under way end); ``configure``: called with the motion before it is queued.
        Its speed takes the override in force when it is written to the drive."""
        if origin is None:
            origin, _ = self._queue_origin(what)
        direction = 0 if origin is None else (target_p > origin) - (target_p < origin)
        m = Motion("move", what, AxisState.STANDSTILL, direction=direction)
        m.start, m.target, m.plan, m.buffer = origin, target_p, self._effective(base), buffer
        m.base_plan = base
        profile = self.profile

        def params() -> MoveParams:
            assert m.plan is not None
            return self.drive_params(m.plan)

        def overridden() -> MotionPlan:
            """``base`` at the override in force now: a speed its drive cannot run is
            refused in the axis's units, naming the override, before anything is sent."""
            plan = self._effective(base)
            if plan != base:
                try:
                    self.check_drive(plan)
                except LimitViolation as exc:
                    raise LimitViolation(f"{exc}; the speed override in force when the "
                                         f"{what} was due: {self.effective_override:g}"
                                         ) from exc
            return plan

        async def prepare() -> None:
            m.plan = overridden()
            await profile.prepare_absolute(target_p, params())

        async def retarget() -> None:
            m.plan = overridden()
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

        def configure(m: Motion) -> None:
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
        m = Motion("move", "move", AxisState.STANDSTILL,
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
