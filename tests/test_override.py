"""Speed override: on the fly where the drive can change speed (judged by the twins'
velocity), from the next motion where it cannot."""

from __future__ import annotations

from pathlib import Path

import anyio
import pytest

from drivebus import open_machine
from drivebus.errors import ArgumentError
from drivebus.motion import Axis
from test_axis_guarantees import _no_soft_limits

DEMO = Path(__file__).resolve().parents[1] / "configs" / "demo.toml"


def speed_of(ax: Axis, twin: object) -> float:
    """The twin's |velocity| now, in the axis's units/s."""
    return abs(ax.units.from_pulses(twin.velocity()))  # type: ignore[attr-defined]


async def cruising(ax: Axis, twin: object, speed: float) -> None:
    """Until the twin runs at ``speed`` (units/s)."""
    with anyio.fail_after(10):
        async for _ in ax.watch():
            if speed_of(ax, twin) == pytest.approx(speed, rel=1e-3):
                return


def cruise_speeds(ax: Axis, twin: object, t0: float) -> list[float]:
    """The constant speeds the twin ran at since ``t0`` (units/s), in order."""
    segments = twin.kin.trace(t0, anyio.current_time())  # type: ignore[attr-defined]
    return [round(abs(ax.units.from_pulses(s.v0)), 3) for s in segments
            if s.a == 0 and s.v0 != 0]


async def test_an_override_halves_the_speed_of_a_move_in_progress() -> None:
    async with open_machine(DEMO) as m:
        z, twin = m.axes["z"], m.sim_drives["z"]
        t0 = anyio.current_time()
        async with anyio.create_task_group() as tg:
            tg.start_soon(z.move_to, 90.0)  # awaited: its deadline follows the slower speed
            await cruising(z, twin, 40.0)
            m.override = 0.5
            await cruising(z, twin, 20.0)
        assert twin.position() == z.units.to_pulses(90.0)
        assert cruise_speeds(z, twin, t0) == [40.0, 20.0]


async def test_an_override_a_drive_cannot_apply_on_the_fly_applies_from_the_next_move() -> None:
    async with open_machine(DEMO) as m:
        x, twin = m.axes["x"], m.sim_drives["x"]
        t0 = anyio.current_time()
        async with anyio.create_task_group() as tg:
            tg.start_soon(x.move_to, 250.0)
            await cruising(x, twin, 200.0)
            m.override = 0.5  # the NT86 obeys only stops while it moves
        assert cruise_speeds(x, twin, t0) == [200.0]
        await x.move_to(50.0)
        assert cruise_speeds(x, twin, t0) == [200.0, 100.0]
        x.override = 0.5  # the axis's own, times the machine's
        assert x.effective_override == 0.25
        handle = await x.move_to(150.0, buffer="buffered")
        await handle
        assert cruise_speeds(x, twin, t0)[-1] == 50.0


async def test_an_override_changes_a_running_jog_where_the_drive_takes_a_new_speed(
    tmp_path: Path,
) -> None:
    async with open_machine(_no_soft_limits(tmp_path)) as m:
        x, twin = m.axes["x"], m.sim_drives["x"]  # no soft limits: a speed run (register 77)
        async with x.jogging(80.0):
            await cruising(x, twin, 80.0)
            m.override = 0.25
            await cruising(x, twin, 20.0)
        assert not twin.is_moving()


async def test_a_bad_override_is_refused_and_changes_nothing() -> None:
    async with open_machine(DEMO) as m:
        for bad in (0.0, -1.0, 2.5, float("nan"), "fast"):
            with pytest.raises(ArgumentError, match="override"):
                m.override = bad  # type: ignore[assignment]
            with pytest.raises(ArgumentError, match="override"):
                m.axes["x"].override = bad  # type: ignore[assignment]
        assert m.override == 1.0 and m.axes["x"].override == 1.0
