"""Buffer modes on one axis, judged by the twins (their motion history) and the wire log.

Buffered moves start the moment the move before them is in position (no standstill longer
than one poll period); blended moves never let the drive reach zero speed between them;
a drive that cannot blend buffers and says why; a stop, an emergency stop or a handle's
cancellation in the middle of a queue leaves the drive at rest and drops the rest of the
queue (no start frame after the stop frame).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import anyio
import pytest

from drivebus import AxisState, open_machine
from drivebus.errors import ArgumentError, DriveAlarm, LimitViolation, MotionAborted, StateError
from drivebus.motion import Axis, MotionHandle
from held_up import within_bound
from test_axis_guarantees import commands, log_size, settle
from wirelog import reads_of

DEMO = Path(__file__).resolve().parents[1] / "configs" / "demo.toml"
KINDS = {"x": "NT86", "y": "BHSS", "z": "CL86R", "r": "EPR60"}


def motion_between(twin: Any, t0: float, t1: float) -> list[Any]:
    """The twin's segments from its first motion after ``t0`` to its last before ``t1``."""
    segs = twin.kin.trace(t0, t1)
    moving = [i for i, s in enumerate(segs) if s.v0 != 0 or s.a != 0]
    return segs[moving[0]: moving[-1] + 1]


def standstills(segments: list[Any]) -> list[float]:
    """How long the axis stood still between its motions, each time (seconds)."""
    return [s.duration for s in segments if s.v0 == 0 and s.a == 0]


def lowest_speed(segments: list[Any]) -> float:
    """The lowest |velocity| along ``segments`` (0 if any ramp passes through zero)."""
    low = float("inf")
    for s in segments:
        v_end = s.v0 + s.a * s.duration
        if s.v0 * v_end <= 0:
            return 0.0
        low = min(low, abs(s.v0), abs(v_end))
    return low


def base(ax: Axis) -> float:
    lo, hi = ax.config.limits or (0.0, 100.0)
    return lo + 0.2 * (hi - lo)


def standstill_spans(segments: list[Any]) -> list[tuple[float, float]]:
    """(start, end) of each standstill between motions, on the twin's clock."""
    return [(s.t0, s.t0 + s.duration) for s in segments if s.v0 == 0 and s.a == 0]


@pytest.mark.parametrize("name", list(KINDS), ids=list(KINDS.values()))
async def test_a_buffered_sequence_of_ten_moves_never_stands_still_longer_than_a_poll(
    name: str,
) -> None:
    """The next move starts on the first status that can show the last one arrived: no
    more than one status read of the axis begins during a standstill (a poll period at
    most, whatever the machine's load does to the period itself)."""
    async with open_machine(DEMO) as m:
        ax, twin = m.axes[name], m.sim_drives[name]
        start = base(ax)
        step = ax.config.units_per_rev * 0.5
        targets = [start + step * ((i + 1) % 2) + 0.1 * i for i in range(10)]

        async def sequence(attempt: int) -> float:
            await ax.move_to(start)
            t0 = anyio.current_time()
            handles = [await ax.move_to(t, buffer="buffered") for t in targets]
            assert all(isinstance(h, MotionHandle) for h in handles)
            assert [h.plan.runs for h in handles] == ["now"] + ["buffered"] * 9
            with anyio.fail_after(30):
                for h in handles:
                    await h
            assert all(h.done and h.error is None for h in handles)
            assert twin.position() == ax.units.to_pulses(targets[-1])
            segments = motion_between(twin, t0, anyio.current_time())
            assert len(standstills(segments)) == 9  # it stopped at each target, in position
            reads = reads_of(m, name)
            # The start follows the first poll after each arrival: a second read that
            # began during a standstill says the start came that much too late.
            late = [b - inside[1] for a, b in standstill_spans(segments)
                    if len(inside := sorted(t for t in reads if a < t < b)) > 1]
            assert ax.state is AxisState.STANDSTILL and ax.queued == 0
            return max(late, default=-1.0)

        await within_bound(sequence, "each start before a second poll of its standstill")


@pytest.mark.serial  # the next move must reach the drive before it stops: a deadline that
# CPU load from other tests moves (the standstill it leaves is what the bench measures)
async def test_a_blended_sequence_never_reaches_zero_speed_between_its_moves() -> None:
    async with open_machine(DEMO) as m:
        z, twin = m.axes["z"], m.sim_drives["z"]

        async def sequence(attempt: int) -> float:
            await z.move_to(5.0)
            targets = [10.0, 14.0, 20.0, 26.0, 30.0]
            t0 = anyio.current_time()
            handles = [await z.move_to(t, buffer="blending", speed=s)
                       for t, s in zip(targets, (40.0, 30.0, 40.0, 20.0, 40.0), strict=True)]
            assert [h.plan.runs for h in handles] == ["now"] + ["blended"] * 4
            with anyio.fail_after(30):
                for h in handles:
                    await h
            assert twin.position() == z.units.to_pulses(30.0)
            speeds = [h.plan.blend_speed for h in handles[1:]]
            assert all(s is not None and s > 0 for s in speeds), speeds
            segments = motion_between(twin, t0, anyio.current_time())
            # A move that reached the drive late (a held-up process: the twin runs in it)
            # let it stop, for about as long as it was late.
            if standstills(segments) or lowest_speed(segments[1:-1]) <= 0:
                return max(standstills(segments), default=0.0) + 1e-6
            return -1.0

        await within_bound(sequence, "a blended sequence without a standstill")


@pytest.mark.parametrize("name", ["x", "y", "r"], ids=["NT86", "BHSS", "EPR60"])
async def test_a_drive_that_cannot_blend_buffers_and_its_plan_says_why(name: str) -> None:
    async with open_machine(DEMO) as m:
        ax = m.axes[name]
        start = base(ax)
        await ax.move_to(start)
        step = ax.config.units_per_rev * 0.5
        first = await ax.move_to(start + step, buffer="blending")
        second = await ax.move_to(start + 2 * step, buffer="blending")
        assert first.plan.runs == "now"
        assert second.plan.runs == "buffered"
        assert KINDS[name] in second.plan.reason and "manual" in second.plan.reason
        await second
        assert ax.position == pytest.approx(start + 2 * step, abs=0.01)


async def test_a_blend_that_reverses_buffers_and_says_so() -> None:
    async with open_machine(DEMO) as m:
        z = m.axes["z"]
        await z.move_to(5.0)
        first = await z.move_to(20.0, buffer="blending")
        back = await z.move_to(10.0, buffer="blending")
        assert back.plan.runs == "buffered" and "reverses" in back.plan.reason
        await first
        await back
        assert z.position == pytest.approx(10.0, abs=0.01)


@pytest.mark.parametrize("stopper", ["stop", "halt_now", "cancel"])
@pytest.mark.parametrize("name", list(KINDS), ids=list(KINDS.values()))
async def test_a_stop_in_the_middle_of_a_queue_leaves_the_drive_at_rest_and_drops_the_rest(
    name: str, stopper: str
) -> None:
    async with open_machine(DEMO) as m:
        ax, twin = m.axes[name], m.sim_drives[name]
        start = base(ax)
        await ax.move_to(start)
        step = ax.config.units_per_rev * 0.4
        for delay in (0.0, 0.004, 0.03, 0.12, 0.3):
            await settle(ax)
            mark = log_size(m, name)
            handles = [await ax.move_to(start + step * ((i + 1) % 2), buffer="buffered")
                       for i in range(6)]
            await anyio.sleep(delay)
            with anyio.fail_after(15):
                if stopper == "cancel":
                    await handles[-1].cancel()
                else:
                    await getattr(ax, stopper)()
            assert not twin.is_moving(), (name, delay)
            assert ax.queued == 0
            outcomes = [h.error for h in handles]
            assert all(h.done for h in handles)
            assert any(isinstance(e, MotionAborted) for e in outcomes), (delay, outcomes)
            first_aborted = next(i for i, e in enumerate(outcomes) if e is not None)
            assert all(isinstance(e, MotionAborted) for e in outcomes[first_aborted:])
            await settle(ax)
            cmds = commands(m, name, mark)
            assert "stop" in cmds, cmds
            assert "start" not in cmds[cmds.index("stop"):], (name, delay, cmds)
            assert not twin.is_moving()
            assert ax.state is AxisState.STANDSTILL


async def test_cancelling_the_task_that_awaits_a_handle_stops_the_axis() -> None:
    async with open_machine(DEMO) as m:
        x, twin = m.axes["x"], m.sim_drives["x"]
        await x.move_to(20.0)
        first = await x.move_to(120.0, buffer="buffered")
        second = await x.move_to(20.0, buffer="buffered")
        with anyio.move_on_after(0.1):
            await first
        assert not twin.is_moving()
        assert isinstance(first.error, MotionAborted)
        assert isinstance(second.error, MotionAborted)
        with pytest.raises(MotionAborted):
            await second


async def test_handles_cancelled_together_stop_their_axis_once() -> None:
    """Sixty queued moves awaited in tasks of one group, cancelled together: the first
    cancelled wait stops the axis and ends the queue; the others had each sent a stop
    of their own (58 stops, found by an outside audit of a long group path)."""
    async with open_machine(DEMO) as m:
        x, twin = m.axes["x"], m.sim_drives["x"]
        await x.move_to(20.0)
        handles = [await x.move_to(20.0 + 50 * (i % 2 == 0), buffer="buffered")
                   for i in range(60)]
        mark = log_size(m, "x")
        async with anyio.create_task_group() as tg:
            for h in handles:
                tg.start_soon(h.wait)
            async for st in x.watch():  # under way
                if st.moving:
                    break
            tg.cancel_scope.cancel()
        assert not twin.is_moving()
        assert all(isinstance(h.error, MotionAborted) for h in handles)
        assert commands(m, "x", mark).count("stop") == 1, commands(m, "x", mark)


async def test_aborting_takes_over_on_the_fly_where_the_drive_can_else_refuses() -> None:
    async with open_machine(DEMO) as m:
        z, twin = m.axes["z"], m.sim_drives["z"]
        await z.move_to(2.0)
        t0 = anyio.current_time()
        outcome: list[BaseException | None] = []

        async def long_move() -> None:
            try:
                await z.move_to(60.0)
                outcome.append(None)
            except MotionAborted as exc:
                outcome.append(exc)

        async with anyio.create_task_group() as tg:
            tg.start_soon(long_move)
            async for st in z.watch():
                if st.moving:
                    break
            await z.move_to(30.0, speed=20.0)  # aborting: takes over without a stop
        assert isinstance(outcome[0], MotionAborted)
        assert twin.position() == z.units.to_pulses(30.0)
        assert standstills(motion_between(twin, t0, anyio.current_time())) == []
        x = m.axes["x"]
        async with anyio.create_task_group() as tg:
            tg.start_soon(x.move_to, 200.0)
            async for st in x.watch():
                if st.moving:
                    break
            with pytest.raises(StateError, match="under way"):
                await x.move_to(100.0)  # the NT86 obeys only stops while it moves
        assert x.position == pytest.approx(200.0)


async def test_a_jog_queued_behind_a_move_starts_when_the_move_is_in_position() -> None:
    async with open_machine(DEMO) as m:
        x, twin = m.axes["x"], m.sim_drives["x"]
        await x.move_to(20.0)
        move = await x.move_to(40.0, buffer="buffered")
        jog = await x.jog(50.0, buffer="buffered", watchdog=None)
        assert jog.plan.runs == "buffered"
        await move
        async for _ in x.watch():
            if x.state is AxisState.CONTINUOUS_MOTION and twin.is_moving():
                break
        assert not jog.done
        await x.stop()
        assert isinstance(jog.error, MotionAborted)
        assert not twin.is_moving() and x.position is not None and x.position > 40.0


async def test_a_refused_queued_move_changes_nothing_and_a_bad_mode_is_an_argument_error() -> None:
    async with open_machine(DEMO) as m:
        x = m.axes["x"]
        await x.move_to(20.0)
        h = await x.move_to(60.0, buffer="buffered")
        with pytest.raises(LimitViolation, match="soft limits"):
            await x.move_to(1000.0, buffer="buffered")
        with pytest.raises(LimitViolation, match="soft limits"):
            await x.move_by(1000.0, buffer="buffered")  # counts from 60
        with pytest.raises(ArgumentError, match="buffer"):
            await x.move_to(30.0, buffer="later")  # type: ignore[arg-type]
        assert x.queued == 0 and not h.done
        await h
        assert x.position == pytest.approx(60.0)
        started = await x.move_to(30.0, buffer="buffered")  # nothing runs: it starts at once
        assert started.plan.runs == "now"
        queued = await x.move_to(40.0, buffer="buffered")
        with pytest.raises(StateError, match="1 more queued"):
            await x.home()
        await queued
        assert started.done and x.position == pytest.approx(40.0)


async def test_an_alarm_in_the_middle_of_a_queue_fails_the_motion_and_drops_the_rest() -> None:
    async with open_machine(DEMO) as m:
        z, twin = m.axes["z"], m.sim_drives["z"]
        await z.move_to(2.0)
        handles = [await z.move_to(t, buffer="buffered") for t in (30.0, 2.0, 30.0)]
        async for st in z.watch():
            if st.moving:
                break
        twin.raise_alarm(1)
        with pytest.raises(DriveAlarm):
            await handles[0]
        for h in handles[1:]:
            with pytest.raises(MotionAborted, match="dropped"):
                await h
        assert z.state is AxisState.ERROR_STOP and z.queued == 0
        await z.reset()


async def test_move_by_queued_counts_from_where_the_move_before_it_ends() -> None:
    async with open_machine(DEMO) as m:
        y, twin = m.axes["y"], m.sim_drives["y"]
        await y.move_to(10.0)
        first = await y.move_by(5.0, buffer="buffered")
        second = await y.move_by(5.0, buffer="buffered")
        third = await y.move_by(-2.5, buffer="buffered")
        for h in (first, second, third):
            await h
        assert twin.position() == y.units.to_pulses(17.5)

