"""Axis actors and awaitable motion on the simulator: concurrency, cancellation, faults."""

from __future__ import annotations

from typing import Any

import anyio
import pytest

from drivebus import AxisState, open_machine
from drivebus.config import MachineConfig, parse_config
from drivebus.errors import (
    ConfigError,
    DriveAlarm,
    DriveOffline,
    LimitViolation,
    MotionAborted,
    StateError,
)
from drivebus.motion import GroupMotionError
from held_up import within_bound


def machine(n: int = 1, drive: str = "CL86R", **axis: Any) -> MachineConfig:
    axes = {
        f"a{i}": {
            "line": "rs485", "address": i, "drive": drive, "settings": "115200 8N1",
            "pulses_per_rev": 1000, "units_per_rev": 10.0, "speed": 100.0, "accel": 1000.0,
            "decel": 1000.0, "limits": [-500.0, 500.0], "poll": {"moving": 0.01, "idle": 0.05},
            **axis,
        }
        for i in range(1, n + 1)
    }
    return parse_config({
        "lines": {"rs485": {"port": f"sim://motion{n}{drive}", "settings": "115200 8N1",
                            "timeout": 0.05}},
        "axes": axes,
    })


async def test_move_to_and_move_by_land_on_target() -> None:
    async with open_machine(machine()) as m:
        x, sim = m.axes["a1"], m.sim_drives["a1"]
        await x.move_to(12.5)
        assert x.state is AxisState.STANDSTILL
        assert x.position == pytest.approx(12.5)
        assert sim.position() == 1250 and not sim.is_moving()
        await x.move_by(-20.0, speed=50.0)
        assert sim.position() == -750
        with pytest.raises(LimitViolation, match="soft limits"):
            await x.move_to(600.0)
        assert sim.position() == -750  # nothing was sent


async def test_eight_axes_move_poll_and_jog_at_once_from_independent_tasks() -> None:
    async with open_machine(machine(8)) as m:
        targets = {f"a{i}": 10.0 * i - 35.0 for i in range(1, 9)}
        jogged: list[str] = []

        async def mover(name: str) -> None:
            ax = m.axes[name]
            for k in range(3):
                await ax.move_to(targets[name] + k)
            await ax.move_to(targets[name])

        async def jogger(name: str) -> None:
            ax = m.axes[name]
            async with ax.jogging(-30.0):
                async for st in ax.watch():
                    if st.moving:
                        break
            jogged.append(name)
            await ax.move_to(targets[name])

        async def watcher() -> None:
            async for st in m.axes["a1"].watch():
                if not st.moving and m.axes["a1"].moves_done >= 4:
                    return

        with anyio.fail_after(60):
            async with anyio.create_task_group() as tg:
                for i in range(1, 9):
                    tg.start_soon(jogger if i in (3, 6) else mover, f"a{i}")
                tg.start_soon(watcher)
        assert sorted(jogged) == ["a3", "a6"]
        for name, target in targets.items():
            assert m.sim_drives[name].position() == round(target * 100), name
            assert not m.sim_drives[name].is_moving()
            assert m.axes[name].state is AxisState.STANDSTILL
        assert m.wires["rs485"].violations == 0  # type: ignore[union-attr]


async def test_cancelling_a_move_stops_the_drive() -> None:
    async with open_machine(machine(speed=20.0)) as m:
        x, sim = m.axes["a1"], m.sim_drives["a1"]
        with anyio.move_on_after(0.3):
            await x.move_to(400.0)
        with anyio.fail_after(5):
            async for st in x.watch():
                if not st.moving:
                    break
        assert not sim.is_moving()
        assert 0 < sim.position() < 40000
        assert x.state is AxisState.STANDSTILL


async def test_leaving_the_machine_stops_moving_axes() -> None:
    async with open_machine(machine(2, speed=20.0)) as m:
        sims = list(m.sim_drives.values())
        await m.axes["a1"].jog(15.0, watchdog=None)
        await m.axes["a2"].jog(-15.0, watchdog=None)
        assert all(s.is_moving() for s in sims)
    assert not any(s.is_moving() for s in sims)


async def test_leaving_the_machine_cancels_and_stops_a_move_in_flight() -> None:
    sims = []
    with anyio.move_on_after(0.5):
        async with open_machine(machine(speed=20.0)) as m:
            sims = list(m.sim_drives.values())
            await m.axes["a1"].move_to(300.0)  # cancelled mid-flight by the scope
    assert sims and not sims[0].is_moving()
    assert 0 < sims[0].position() < 30000


async def test_alarm_during_move_raises_puts_error_stop_and_reset_recovers() -> None:
    async with open_machine(machine(speed=20.0)) as m:
        x, sim = m.axes["a1"], m.sim_drives["a1"]

        async def fault_soon() -> None:
            async for st in x.watch():
                if st.moving:
                    sim.raise_alarm(0x04)
                    return

        async with anyio.create_task_group() as tg:
            tg.start_soon(fault_soon)
            with pytest.raises(DriveAlarm) as exc:
                await x.move_to(300.0)
        assert exc.value.code is not None
        assert x.state is AxisState.ERROR_STOP
        with pytest.raises(StateError, match="ErrorStop"):
            await x.move_to(0.0)
        await x.reset_alarm()
        assert x.state is AxisState.STANDSTILL
        await x.move_to(1.0)
        assert sim.position() == 100


async def test_power_loss_makes_the_axis_offline_and_it_comes_back() -> None:
    async with open_machine(machine(2, speed=20.0)) as m:
        x, y = m.axes["a1"], m.axes["a2"]
        sim = m.sim_drives["a1"]

        async def cut_power() -> None:
            async for st in x.watch():
                if st.moving:
                    sim.power_loss()
                    return

        async with anyio.create_task_group() as tg:
            tg.start_soon(cut_power)
            with pytest.raises(DriveOffline, match="stopped answering"):
                await x.move_to(200.0)
        assert x.state is AxisState.OFFLINE
        await y.move_to(5.0)  # the other axis keeps working
        assert m.sim_drives["a2"].position() == 500
        with pytest.raises(DriveOffline):
            await x.stop()
        sim.power_restore()
        with anyio.fail_after(5):
            async for _ in x.watch():
                if x.state is not AxisState.OFFLINE:
                    break
        assert x.state in (AxisState.STANDSTILL, AxisState.DISABLED)
        await x.move_to(2.0)
        assert sim.position() == 200


@pytest.mark.serial  # bounds arrivals within a poll period plus the start skew: load stretches it
async def test_group_arrives_together_and_reports_start_skew() -> None:
    async with open_machine(machine(3)) as m:
        g = m.group("a1", "a2", "a3")

        async def group_move(attempt: int) -> float:
            arrived: dict[str, float] = {}

            async def note_arrival(name: str) -> None:
                async for st in m.axes[name].watch():
                    if st.moving:
                        break
                async for st in m.axes[name].watch():
                    if not st.moving:
                        arrived[name] = anyio.current_time()
                        return

            there = {"a1": 40.0, "a2": 10.0, "a3": -20.0}
            async with anyio.create_task_group() as tg:
                for n in ("a1", "a2", "a3"):
                    tg.start_soon(note_arrival, n)
                report = await g.move_to(
                    there if attempt % 2 else {n: 0.0 for n in there})  # (again: back)
            assert report.duration > 0 and report.start_skew >= 0
            assert [m.sim_drives[n].position() for n in ("a1", "a2", "a3")] == (
                [4000, 1000, -2000] if attempt % 2 else [0, 0, 0])
            # the short moves were slowed down to match the long one
            assert report.plans["a2"].speed < report.plans["a1"].speed
            poll = m.config.axes["a1"].poll.moving
            spread = max(arrived.values()) - min(arrived.values())
            return spread - (poll + report.start_skew + 0.01)

        await within_bound(group_move, "arrivals within a poll and the start skew")


async def test_a_fault_on_one_axis_stops_the_group() -> None:
    async with open_machine(machine(3, speed=20.0)) as m:
        bad = m.sim_drives["a2"]

        async def fault() -> None:
            async for st in m.axes["a2"].watch():
                if st.moving:
                    bad.raise_alarm(0x04)
                    return

        async with anyio.create_task_group() as tg:
            tg.start_soon(fault)
            with pytest.raises(GroupMotionError) as exc:
                await m.group().move_to({"a1": 100.0, "a2": 100.0, "a3": 100.0})
        assert exc.value.axis == "a2"
        with anyio.fail_after(5):
            for name in ("a1", "a3"):
                async for st in m.axes[name].watch():
                    if not st.moving:
                        break
        assert not any(s.is_moving() for s in m.sim_drives.values())


async def test_stop_aborts_a_waiting_move() -> None:
    async with open_machine(machine(speed=20.0)) as m:
        x = m.axes["a1"]
        async with anyio.create_task_group() as tg:

            async def stopper() -> None:
                async for st in x.watch():
                    if st.moving:
                        await x.stop()
                        return

            tg.start_soon(stopper)
            with pytest.raises(MotionAborted):
                await x.move_to(300.0)
        assert not m.sim_drives["a1"].is_moving()
        assert x.state is AxisState.STANDSTILL


async def test_jog_watchdog_stops_an_unfed_jog() -> None:
    async with open_machine(machine()) as m:
        x = m.axes["a1"]
        await x.jog(10.0, watchdog=0.1)
        with anyio.fail_after(5):
            async for st in x.watch():
                if x.state is AxisState.STANDSTILL and not st.moving:
                    break
        assert not m.sim_drives["a1"].is_moving()


def test_config_errors_name_file_key_and_allowed(tmp_path: Any) -> None:
    from drivebus.config import load_config

    bad = tmp_path / "bad.toml"
    bad.write_text('[lines.l]\nport = "sim://x"\n[axes.x]\nline = "l"\naddress = 1\n'
                   'drive = "NOPE"\n')
    with pytest.raises(ConfigError, match=r"bad.toml: axes.x.drive: .*known drives are NT86"):
        load_config(bad)
    bad.write_text('[lines.l]\nport = "sim://x"\nsettings = "9600 8X1"\n')
    with pytest.raises(ConfigError, match=r"bad\.toml"):
        load_config(bad)
    bad.write_text('[lines.l]\nport = "sim://x"\n[axes.x]\nline = "m"\naddress = 1\n'
                   'drive = "BHSS"\n')
    with pytest.raises(ConfigError, match="no line 'm'"):
        load_config(bad)
    with pytest.raises(ConfigError, match="no such config file"):
        load_config(tmp_path / "missing.toml")


async def test_unreachable_drive_is_named_and_nothing_is_left_running() -> None:
    from drivebus.sim import lookup_wire

    data = machine(2).model_dump()
    data["axes"]["a2"]["sim"]["absent"] = True  # configured, but not on the wire
    with pytest.raises(DriveOffline, match="axis a2: the CL86R drive at address 2"):
        async with open_machine(parse_config(data)):
            pass  # pragma: no cover
    with pytest.raises(KeyError):
        lookup_wire("motion2CL86R")  # the simulated line was closed again


@pytest.mark.parametrize("name", ["demo.toml", "single.toml", "template.toml"])
def test_shipped_configs_validate(name: str) -> None:
    from pathlib import Path

    from drivebus.config import load_config

    cfg = load_config(Path(__file__).resolve().parents[1] / "configs" / name)
    assert cfg.axes


@pytest.mark.serial  # bounds the start skew (20 ms): load stretches it
async def test_group_prepares_every_axis_then_starts_them_back_to_back() -> None:
    async with open_machine(machine(3)) as m:
        wire = m.wires["rs485"]

        async def group_move(attempt: int) -> float:
            wire.clear_log()  # type: ignore[union-attr]
            there = {"a1": 30.0, "a2": -20.0, "a3": 10.0}
            report = await m.group().move_to(
                there if attempt % 2 else {n: 0.0 for n in there})  # (again: back)
            frames = wire.requests()  # type: ignore[union-attr]
            # CL86R: parameters go to 0x0030.. (FC16), the start is a write of 0x0036 (FC06)
            def at(fc: int, reg: bytes) -> list[int]:
                return [i for i, f in enumerate(frames) if f.data[1] == fc and f.data[2:4] == reg]

            params, starts = at(0x10, b"\x00\x30"), at(0x06, b"\x00\x36")
            assert len(params) == 3 and len(starts) == 3
            assert max(params) < min(starts)  # every axis prepared before any starts
            assert starts[-1] - starts[0] <= 3  # back to back (at most a poll in flight between)
            return report.start_skew - 0.02

        await within_bound(group_move, "a start skew under 20 ms")


async def test_group_move_by_moves_each_axis_from_where_it_is() -> None:
    async with open_machine(machine(2)) as m:
        await m.axes["a1"].move_to(5.0)
        await m.group().move_by({"a1": 10.0, "a2": -3.0})
        assert [m.sim_drives[n].position() for n in ("a1", "a2")] == [1500, -300]
