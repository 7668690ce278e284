"""The Nanotec PD4-C (tests/drives/nanotec_pd4c.toml), a CiA 402 drive written from its
public manual by a user who never saw it: its objects sit in the Modbus process image (the
Rx image from register 6000d, the Tx image from 5000d: manual, "Modbus RTU > Process data
objects (PDO)"), placed by the description's own 3502h mapping and 3602h's factory one. A
machine on its generic twin, driven through the public API, judged by the twin and the
wire log, not by the axis's own view."""

from __future__ import annotations

import contextlib
import itertools
import time
from pathlib import Path
from typing import Any

import anyio
import pytest

from drivebus import AxisState, open_machine
from drivebus.errors import DrivebusError, MotionAborted, NotSupported
from waits import until
from wirelog import request_pdus

ROOT = Path(__file__).resolve().parents[1]
PD4C = ROOT / "tests" / "drives" / "nanotec_pd4c.toml"
CONTROLWORD, MODE, TARGET, PROFILE_V, TARGET_V, HOMING_METHOD = 6000, 6001, 6002, 6004, 6010, 6012
STATUSWORD, POSITION, VELOCITY, ERROR_CODE = 5000, 5002, 5007, 5009
HALT, QUICK_STOP_CLEAR, NEW_SET_POINT = 0x0100, 0x0004, 0x0010
PPR = 3600            # tenths of a degree per revolution
SWITCH = 720.0        # the limit switches at +-720 degrees (2 revolutions)


def machine(tag: str, **sim: Any) -> dict[str, Any]:
    """One PD4-C in degrees (360 a revolution), soft limits inside its limit switches."""
    return {"name": f"pd4c-{tag}",
            "lines": {"l": {"port": f"sim://pd4c-{tag}", "settings": "115200 8N1",
                            "timeout": 0.1}},
            "axes": {"a": {"line": "l", "address": 1, "drive": str(PD4C),
                           "pulses_per_rev": PPR, "units_per_rev": 360.0, "speed": 360.0,
                           "accel": 3600.0, "decel": 3600.0, "limits": [-600.0, 600.0],
                           "sim": {"limit_negative": -SWITCH, "limit_positive": SWITCH,
                                   **sim},
                           "poll": {"moving": 0.01, "idle": 0.05}}}}


def writes(wire: Any, since: float = 0.0) -> list[tuple[int, list[int]]]:
    """(address, register values) of every FC06/FC16 after ``since``."""
    out = []
    for pdu in request_pdus(wire, since):
        address = int.from_bytes(pdu[1:3], "big")
        if pdu[0] == 6:
            out.append((address, [int.from_bytes(pdu[3:5], "big")]))
        elif pdu[0] == 16:
            n = int.from_bytes(pdu[3:5], "big")
            out.append((address, [int.from_bytes(pdu[6 + 2 * i:8 + 2 * i], "big")
                                  for i in range(n)]))
    return out


def controlwords(wire: Any, since: float = 0.0) -> list[int]:
    return [v[0] for a, v in writes(wire, since) if a == CONTROLWORD]


def assert_only_the_images(wire: Any) -> None:
    """Only 03, 06 and 16, only at the two images the manual's PDO chapter places."""
    for pdu in request_pdus(wire):
        assert pdu[0] in (3, 6, 16), pdu.hex(" ")
        address = int.from_bytes(pdu[1:3], "big")
        assert 5000 <= address < 5010 or 6000 <= address < 6021, pdu.hex(" ")


async def test_the_public_commands_on_the_twin() -> None:
    with anyio.fail_after(60):
        async with open_machine(machine("api")) as m:
            a, twin, wire = m.axes["a"], m.sim_drives["a"], m.wires["l"]
            st = await a.refresh()
            assert not st.enabled
            await a.enable()
            assert twin.enabled and not twin.is_moving()
            await a.move_to(90.0)  # a quarter turn = 900 tenths of a degree
            assert twin.position() == 900 and not twin.is_moving()
            st = await a.refresh()
            assert st.in_position and a.position == pytest.approx(90.0)
            assert st.raw["position_actual"] == 900
            async with a.jogging(-90.0):
                await until(twin.is_moving, "the jog to run on the twin")
                st = await a.refresh()
                assert st.moving and st.velocity_rpm is not None and st.velocity_rpm < 0
            assert not twin.is_moving() and a.state is AxisState.STANDSTILL
            await a.move_by(-45.0)
            assert not twin.is_moving()
            done = anyio.Event()

            async def long_move() -> None:
                with contextlib.suppress(MotionAborted):
                    await a.move_to(-500.0, speed=90.0)
                done.set()

            async with anyio.create_task_group() as tg:
                tg.start_soon(long_move)
                await until(twin.is_moving, "the long move to run on the twin")
                since = time.monotonic()
                await a.stop()
                assert not twin.is_moving()
                assert any(w & HALT for w in controlwords(wire, since))
                await done.wait()
            async with anyio.create_task_group() as tg:
                tg.start_soon(long_move)
                await until(twin.is_moving, "the long move to run on the twin")
                since = time.monotonic()
                await a.halt_now()
                assert not twin.is_moving()
                assert any(not w & QUICK_STOP_CLEAR for w in controlwords(wire, since))
            await a.reset()
            assert not twin.is_moving()
            assert_only_the_images(wire)


async def test_status_decodes_through_scale_and_unit() -> None:
    """Positions in tenths of a degree, speeds in rpm: a jog at 180 degrees/s (30 rpm)
    shows 30 rpm; the position is the twin's, in degrees."""
    with anyio.fail_after(30):
        async with open_machine(machine("units")) as m:
            a, twin = m.axes["a"], m.sim_drives["a"]
            await a.enable()
            await a.jog(180.0, watchdog=None)
            await until(lambda: twin.speed_rpm() == pytest.approx(30.0),
                        "the jog to reach its speed on the twin")
            st = await a.refresh()
            assert st.velocity_rpm == pytest.approx(30.0) and st.raw["velocity_actual"] == 30
            await a.stop()
            st = await a.refresh()
            assert st.position == twin.position() == st.raw["position_actual"]
            assert a.position == pytest.approx(twin.position() / 10.0)


@pytest.mark.parametrize("left", ["velocity", "position", "homing"])
async def test_a_set_point_left_from_before_does_not_run_on_enable(left: str) -> None:
    """A target velocity (profile velocity) or a new target (profile position) left in the
    Rx image by an earlier master: enabling, and a reset after a fault, never move."""
    with anyio.fail_after(30):
        async with open_machine(machine(f"stale-{left}")) as m:
            a, twin = m.axes["a"], m.sim_drives["a"]
            slave = a.profile.slave
            if left == "velocity":
                await slave.write_registers(TARGET_V, [0, 300])
                await slave.write_register(MODE, 3)
            elif left == "homing":
                await slave.write_register(HOMING_METHOD, 17)
                await slave.write_register(MODE, 6)
                await slave.write_register(CONTROLWORD, NEW_SET_POINT)  # homing start bit
            else:
                await slave.write_registers(TARGET, [0, 3000])
                await slave.write_register(MODE, 1)
                await slave.write_register(CONTROLWORD, NEW_SET_POINT)
            await a.enable()
            with anyio.move_on_after(0.3):
                await until(twin.is_moving, "(not) a stale set-point")
            assert not twin.is_moving() and twin.position() == 0
            twin.raise_alarm(0x3210)
            await a.refresh()
            await a.reset()
            await a.enable()
            with anyio.move_on_after(0.3):
                await until(twin.is_moving, "(not) a stale set-point")
            assert not twin.is_moving() and twin.position() == 0


async def trace_homing(a: Any, twin: Any) -> list[float]:
    trace: list[float] = []
    async with anyio.create_task_group() as tg:
        async def watch() -> None:
            while True:
                trace.append(float(twin.physical_position()))
                await anyio.sleep(0.002)
        tg.start_soon(watch)
        await a.home()
        tg.cancel_scope.cancel()
    return trace


@pytest.mark.parametrize(("method", "code", "origin"), [
    ("negative_limit", 17, -SWITCH), ("positive_limit", 18, SWITCH),
    ("home_switch_forward", 24, 90.0), ("current_position", 35, None)])
async def test_every_homing_method_homes_and_never_passes_a_limit_switch(
        method: str, code: int, origin: float | None) -> None:
    with anyio.fail_after(60):
        cfg = machine(f"home-{code}", home_switch=90.0)
        cfg["axes"]["a"]["homing"] = {"method": method, "speed": 360.0, "creep": 15.0,
                                      "accel": 3600.0}
        braking = 10 * 360.0 ** 2 / (2 * 3600.0) + 1  # pulses, from the search speed
        async with open_machine(cfg) as m:
            a, twin, wire = m.axes["a"], m.sim_drives["a"], m.wires["l"]
            await a.enable()
            await a.move_to(-45.0)
            here = twin.physical_position()
            since = time.monotonic()
            trace = await trace_homing(a, twin)
            assert [v for ad, v in writes(wire, since) if ad == HOMING_METHOD] == [[code]]
            st = await a.refresh()
            assert st.homed and not twin.is_moving() and not twin.homing_failed
            assert twin.position() == pytest.approx(0, abs=30)  # home is 0 (no offset)
            lo, hi = -SWITCH * 10 - braking, SWITCH * 10 + braking
            assert all(lo <= p <= hi for p in trace), (min(trace), max(trace))
            if origin is None:
                assert twin.physical_position() == here
            else:
                assert abs(twin.physical_position() - origin * 10) <= 60


async def test_a_mode_change_never_starts_motion() -> None:
    """Jog (profile velocity) then a move (profile position) then a jog again: no mode
    change moves the twin by itself, and a stopped jog leaves target velocity 0."""
    with anyio.fail_after(30):
        async with open_machine(machine("modes")) as m:
            a, twin, wire = m.axes["a"], m.sim_drives["a"], m.wires["l"]
            await a.enable()
            await a.jog(90.0, watchdog=None)
            await until(twin.is_moving, "the jog")
            await a.stop()
            assert [v for ad, v in writes(wire) if ad == TARGET_V][-1] == [0, 0]
            since = time.monotonic()
            at = twin.position()
            await a.profile.slave.write_register(MODE, 3)  # back to velocity by hand
            with anyio.move_on_after(0.3):
                await until(twin.is_moving, "(not) the old jog")
            assert not twin.is_moving() and twin.position() == at
            await a.move_to(0.0)
            assert twin.position() == 0
            assert writes(wire, since)


async def test_what_it_cannot_do_is_refused_before_any_frame() -> None:
    with anyio.fail_after(30):
        async with open_machine(machine("refuse")) as m:
            a, wire = m.axes["a"], m.wires["l"]
            await a.enable()
            await a.refresh()
            since = time.monotonic()
            for refused in (a.profile.save_parameters, lambda: a.set_output("OUT1", True)):
                with pytest.raises(NotSupported):
                    await refused()
            with pytest.raises(DrivebusError):
                await a.move_to(1000.0)  # beyond the soft limit
            with pytest.raises(DrivebusError):
                await a.move_to(10.0, speed=1e6)  # profile velocity's 1..3000 rpm
            assert not writes(wire, since)


async def test_a_fault_shows_its_code_and_resets() -> None:
    with anyio.fail_after(30):
        async with open_machine(machine("fault")) as m:
            a, twin, wire = m.axes["a"], m.sim_drives["a"], m.wires["l"]
            await a.enable()
            twin.raise_alarm(0x3210)
            st = await a.refresh()
            assert st.alarm and st.alarm_code == 0x3210 and st.alarm_text == "overvoltage"
            assert a.state is AxisState.ERROR_STOP
            since = time.monotonic()
            await a.reset()
            assert any(w & 0x80 for w in controlwords(wire, since))
            st = await a.refresh()
            assert not st.alarm and not twin.is_moving()


async def test_a_jog_without_soft_limits_stops_at_the_limit_switch() -> None:
    """No soft limits: a jog is a speed run, and the drive stops it at its limit switch
    (60FDh bit 0, the negative limit: CiA 402); the status shows the switch."""
    cfg = machine("switch")
    del cfg["axes"]["a"]["limits"]
    with anyio.fail_after(30):
        async with open_machine(cfg) as m:
            a, twin = m.axes["a"], m.sim_drives["a"]
            await a.enable()
            await a.jog(-360.0, watchdog=None)
            await until(lambda: twin.physical_position() < -SWITCH * 10 + 10,
                        "the jog to reach the negative limit switch")
            await until(lambda: not twin.is_moving(), "the twin to stop at the switch")
            assert twin.physical_position() >= -SWITCH * 10 - 120  # braking at 60 rpm
            st = await a.refresh()
            assert st.limit_negative and not st.limit_positive
            assert st.raw["digital_inputs"] & 1


async def test_a_stopped_move_never_resumes() -> None:
    """A stop is a halt (controlword bit 8); a CiA 402 drive continues the interrupted
    positioning when halt clears without a new set-point, and the twin does too: no
    command after the stop (reset, enable, a jog, a move) clears halt that way."""
    with anyio.fail_after(60):
        async with open_machine(machine("resume")) as m:
            a, twin = m.axes["a"], m.sim_drives["a"]
            await a.enable()

            async def long_move() -> None:
                with contextlib.suppress(MotionAborted):
                    await a.move_to(-500.0, speed=90.0)

            async with anyio.create_task_group() as tg:
                tg.start_soon(long_move)
                await until(lambda: twin.position() < -300, "the long move to run")
                await a.stop()
            stopped = twin.position()
            for command in (a.reset, a.enable):
                await command()
                with anyio.move_on_after(0.3):
                    await until(twin.is_moving, "(not) the stopped move")
                assert not twin.is_moving() and twin.position() == stopped
            await a.move_to(0.0)
            assert twin.position() == 0
            async with anyio.create_task_group() as tg:
                tg.start_soon(long_move)
                await until(lambda: twin.position() < -300, "the long move to run")
                await a.stop()
            async with a.jogging(90.0):
                await until(twin.is_moving, "the jog")
            assert not twin.is_moving() and twin.position() > -500 * 10 + 1


async def test_a_negative_home_switch_homes_on_the_cia402_twin(tmp_path: Path) -> None:
    """CiA 402 methods 21 and 22 expect a home switch active on the negative side of its
    edge; the machine's `sim.options.home_cam = "negative"` puts one there, and without
    the option the twin's cam covers the side the method in 6098h expects, as the
    simulator guide says (before, it was a positive cam, and from either side the
    homing ran into a limit switch or timed out). Earlier still the described CiA 402
    twin refused `home_cam`, so no description offering 5, 6, 21 or 22 could home."""
    text = PD4C.read_text().replace(
        "[homing.methods]\n",
        '[homing.methods]\nhome_switch_negative = { code = 21, cia402 = 21, '
        'source = "manual: Homing (CiA 402 method 21)" }\n', 1)
    drive = tmp_path / "pd4c21.toml"
    drive.write_text(text)
    for options, start in itertools.product(({"home_cam": "negative"}, {}), (0.0, 180.0)):
        # the switch active, then inactive at the start
        cfg = machine(f"home21-{int(start)}-{len(options)}", home_switch=90.0,
                      options=options, position=start)
        cfg["axes"]["a"]["drive"] = str(drive)
        cfg["axes"]["a"]["homing"] = {"method": "home_switch_negative", "speed": 360.0,
                                      "creep": 15.0, "accel": 3600.0}
        with anyio.fail_after(30):
            async with open_machine(cfg) as m:
                a, twin = m.axes["a"], m.sim_drives["a"]
                await a.enable()
                await a.home()
                assert (await a.refresh()).homed and not twin.homing_failed
                assert abs(twin.physical_position() - 900) <= 60
