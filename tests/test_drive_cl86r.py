"""CL86R profile against its simulated twin: manual frames, motion, homing, alarms, units."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from dataclasses import replace

import anyio
import pytest

from drivebus import LineSettings
from drivebus.drives.base import MoveParams
from drivebus.drives.cl86r import (
    ACCEL_TIME,
    HOME_SPEED,
    MAX_SPEED,
    START_SPEED,
    CL86RProfile,
    ramp_time_ms,
)
from drivebus.drives.status import DriveStatus
from drivebus.errors import ConfigError, LimitViolation, ModbusException, NotSupported
from drivebus.line.rtu import crc_ok
from drivebus.sim import VirtualWire, sim_bus
from drivebus.sim.drive import TwinSetup
from drivebus.sim.drives.cl86r import SimCL86R

FAST = LineSettings.parse("115200 8N1")
FACTORY = LineSettings.parse("9600 8N1")
QUICK = MoveParams(1500, 300, 300)  # 25 rev/s, 83 ms ramps: short test moves
SLOW = MoveParams(600, 100, 100)
"""Long enough that a status read after its start sees it moving, on a busy machine too."""


def hexframes(wire: VirtualWire) -> list[str]:
    """The master's frames on the wire, as the manual prints them."""
    return [f.data.hex(" ").upper() for f in wire.requests()]


@asynccontextmanager
async def rig(
    sim: SimCL86R | None = None, settings: LineSettings = FAST, **options: object
) -> AsyncIterator[tuple[SimCL86R, VirtualWire, CL86RProfile]]:
    """A twin on a simulated line and a profile talking to it."""
    sim = sim or SimCL86R(1, settings)
    async with sim_bus([sim], settings) as (wire, bus):
        yield sim, wire, CL86RProfile(bus.slave(1), **options)  # type: ignore[arg-type]


async def wait_for(
    profile: CL86RProfile, condition: Callable[[DriveStatus], bool], timeout: float = 5.0
) -> DriveStatus:
    """Poll the drive through the profile until ``condition`` holds (bounded by a deadline)."""
    with anyio.fail_after(timeout):
        while True:
            st = await profile.read_status()
            if condition(st):
                return st
            await anyio.sleep(0.005)


def at_rest(st: DriveStatus) -> bool:
    return st.in_position and not st.moving


# -- the manual's example frames ----------------------------------------------------------------

ENABLE = "01 06 00 38 00 01 C9 C7"
STOP = "01 06 00 36 00 20 68 1C"
ESTOP = "01 06 00 36 00 40 68 34"


async def test_position_mode_example_frames_one_by_one() -> None:
    # Manual L473-505: start 30 rpm, 200 ms ramps, 120 rpm, 3200 pulses, relative start.
    # 200 ms to 120 rpm (2 rev/s) is 10 rev/s².
    async with rig(SimCL86R(1), FACTORY, start_speed_rpm=30, block_writes=False) as (
        _, wire, profile,
    ):
        await profile.enable()
        await profile.move_relative(3200, MoveParams(120, 10, 10))
        await profile.stop()
        await profile.emergency_stop()
        assert hexframes(wire) == [
            ENABLE,
            "01 06 00 30 00 1E 09 CD",
            "01 06 00 31 00 C8 D9 93",
            "01 06 00 32 00 C8 29 93",
            "01 06 00 33 00 78 79 E7",
            "01 10 00 34 00 02 04 00 00 0C 80 F5 E8",
            "01 06 00 36 00 01 A8 04",
            STOP,
            ESTOP,
        ]


async def test_position_mode_example_frames_all_at_once() -> None:
    async with rig(SimCL86R(1), FACTORY, start_speed_rpm=30) as (_, wire, profile):
        await profile.move_relative(3200, MoveParams(120, 10, 10))
        assert hexframes(wire) == [
            "01 10 00 30 00 06 0C 00 1E 00 C8 00 C8 00 78 00 00 0C 80 A4 48",
            "01 06 00 36 00 01 A8 04",
        ]


async def test_speed_mode_example_frames() -> None:
    # Manual L531-561; the start value is 0x0008 (the prose's 0x0001 at L529 is wrong).
    async with rig(SimCL86R(1), FACTORY, start_speed_rpm=30, block_writes=False) as (
        _, wire, profile,
    ):
        await profile.enable()
        await profile.speed_run(120, 10, 10)
        await profile.stop()
        await profile.emergency_stop()
        assert hexframes(wire) == [
            ENABLE,
            "01 06 00 30 00 1E 09 CD",
            "01 06 00 31 00 C8 D9 93",
            "01 06 00 32 00 C8 29 93",
            "01 06 00 33 00 78 79 E7",
            "01 06 00 36 00 08 68 02",
            STOP,
            ESTOP,
        ]
    async with rig(SimCL86R(1), FACTORY, start_speed_rpm=30) as (_, wire, profile):
        await profile.speed_run(120, 10, 10)
        await profile.emergency_stop()
        assert hexframes(wire)[:2] == [
            "01 10 00 30 00 04 08 00 1E 00 C8 00 C8 00 78 68 37",
            "01 06 00 36 00 08 68 02",
        ]


async def test_homing_example_frames() -> None:
    # Manual L684-722: mode 18, 120 rpm, creep 30 rpm, 100 ms (120 rpm in 0.1 s = 20 rev/s²).
    async with rig(SimCL86R(1), FACTORY, block_writes=False) as (_, wire, profile):
        await profile.enable()
        await profile.home("positive_limit", speed_rpm=120, creep_rpm=30, accel_rps2=20)
        await profile.stop()
        await profile.emergency_stop()
        assert hexframes(wire) == [
            ENABLE,
            "01 10 00 44 00 02 04 00 00 00 00 F6 6C",  # origin offset 0 (derived)
            "01 06 00 40 00 12 08 13",
            "01 06 00 41 00 78 D9 FC",
            "01 06 00 42 00 1E A9 D6",
            "01 06 00 43 00 64 79 F5",
            "01 06 00 36 00 10 68 08",
            STOP,
            ESTOP,
        ]


async def test_homing_block_frame_has_the_correct_crc_where_the_manual_misprints_it() -> None:
    printed = bytes.fromhex("01 10 00 40 00 04 08 00 12 00 78 00 1E 00 64 53 75")  # L710
    assert not crc_ok(printed)  # the manual's CRC is wrong; its other frames check out
    async with rig(SimCL86R(1), FACTORY) as (_, wire, profile):
        await profile.home("positive_limit", speed_rpm=120, creep_rpm=30, accel_rps2=20)
        await profile.emergency_stop()
        block = wire.requests()[1].data
        assert block[:-2] == printed[:-2]
        assert block[-2:] == bytes.fromhex("44 A3") and crc_ok(block)


@pytest.mark.parametrize(
    ("method", "frame"),
    [
        ("negative_limit", "01 06 00 40 00 11 48 12"),
        ("home_switch_positive", "01 06 00 40 00 18 88 14"),
        ("home_switch_negative", "01 06 00 40 00 1D 48 17"),
        ("current_position", "01 06 00 40 00 23 C9 C7"),
    ],
)
async def test_other_homing_mode_frames(method: str, frame: str) -> None:
    async with rig(block_writes=False) as (_, wire, profile):
        await profile.home(method, speed_rpm=120, creep_rpm=30, accel_rps2=20)
        await profile.emergency_stop()
        assert frame in hexframes(wire)


async def test_derived_command_frames() -> None:
    async with rig(SimCL86R(1), FACTORY, block_writes=False) as (_, wire, profile):
        await profile.move_relative(-3200, MoveParams(120, 10, 10))
        await profile.emergency_stop()
        await profile.zero_position()
        await profile.clear_alarm()
        await profile.save_parameters()
        await profile.disable()
        await profile.read_status()
        frames = hexframes(wire)
    assert "01 10 00 34 00 02 04 FF FF F3 80 B4 3C" in frames
    assert frames[-5:] == [
        "01 06 00 37 00 08 39 C2",
        "01 06 00 37 00 04 39 C7",
        "01 06 00 37 00 02 B9 C5",
        "01 06 00 38 00 00 08 07",
        "01 03 00 00 00 0A C5 CD",
    ]
    async with rig(SimCL86R(1), FACTORY, interrupt_moves=True) as (_, wire, profile):
        await profile.move_absolute(100, MoveParams(120, 10, 10))
        assert hexframes(wire)[-1] == "01 06 00 36 00 07 28 06"


# -- motion -------------------------------------------------------------------------------------


async def test_enable_relative_and_absolute_moves_land_on_target() -> None:
    async with rig() as (sim, _, profile):
        await profile.setup()
        await profile.disable()
        assert not (await profile.read_status()).enabled
        await profile.enable()
        assert (await profile.read_status()).enabled
        await profile.move_relative(5000, SLOW)  # (seen moving on a busy machine too)
        moving = await profile.read_status()
        assert moving.moving and not moving.in_position
        st = await wait_for(profile, at_rest)
        assert st.position == 5000 == sim.position()
        await profile.move_absolute(-2000, QUICK)
        st = await wait_for(profile, at_rest)
        assert st.position == -2000 == sim.position()
        await profile.move_relative(-500, QUICK)
        st = await wait_for(profile, at_rest)
        assert st.position == -2500


async def test_new_move_is_ignored_while_moving_unless_interrupt_is_set() -> None:
    slow = MoveParams(300, 300, 300)  # 5 rev/s
    async with rig() as (sim, _, profile):
        await profile.move_relative(3000, slow)
        await profile.move_absolute(-1000, slow)  # ignored: bit 2 clear
        st = await wait_for(profile, at_rest)
        assert st.position == 3000 == sim.position()
    async with rig(interrupt_moves=True) as (sim, _, profile):
        await profile.move_relative(3000, slow)
        await profile.move_absolute(-1000, slow)  # replaces the running move
        st = await wait_for(profile, at_rest)
        assert st.position == -1000 == sim.position()


async def test_speed_run_speed_change_and_decelerating_stop() -> None:
    async with rig() as (sim, wire, profile):
        await profile.speed_run(600, 200, 200)
        st = await wait_for(profile, lambda s: s.velocity_rpm == 600)
        assert st.moving and not st.in_position and st.raw["mode"] == 2
        await profile.speed_run(-300, 200, 100)  # reverse on the fly
        await wait_for(profile, lambda s: s.velocity_rpm == -300)
        await profile.speed_run(-900, 300, 100)  # faster
        await wait_for(profile, lambda s: s.velocity_rpm == -900)
        await profile.stop()
        stop_sent = wire.requests()[-1].end
        # 900 rpm (15 rev/s) at 100 rev/s² -> 150 ms ramp time in 0x0032, 0.15 s to rest
        assert sim.regs[0x0032] == 150
        assert sim.kin.end_time() - stop_sent == pytest.approx(0.15, abs=0.01)
        st = await wait_for(profile, lambda s: not s.moving)
        assert st.velocity_rpm == 0 and st.position == sim.position()


async def test_stop_with_its_own_deceleration() -> None:
    async with rig() as (sim, wire, profile):
        await profile.speed_run(600, 200, 200)
        await wait_for(profile, lambda s: s.velocity_rpm == 600)
        await profile.stop(decel_rps2=50)  # 10 rev/s at 50 rev/s² = 200 ms
        assert sim.regs[0x0032] == 200
        assert sim.kin.end_time() - wire.requests()[-1].end == pytest.approx(0.2, abs=0.01)
        await wait_for(profile, lambda s: not s.moving)


async def test_emergency_stop_halts_at_once() -> None:
    async with rig() as (sim, wire, profile):
        await profile.speed_run(1200, 100, 100)
        await wait_for(profile, lambda s: s.velocity_rpm == 1200)
        await profile.emergency_stop()
        assert sim.kin.end_time() == pytest.approx(wire.requests()[-1].end)
        st = await profile.read_status()
        assert not st.moving and st.velocity_rpm == 0


async def test_speed_run_stops_at_limit_switch_and_will_not_go_on() -> None:
    async with rig(SimCL86R(1, FAST, TwinSetup(limit_positive=2000))) as (sim, _, profile):
        await profile.setup()
        await profile.speed_run(600, 300, 300)
        st = await wait_for(profile, lambda s: s.limit_positive and not s.moving)
        assert st.position >= 2000
        await profile.speed_run(600, 300, 300)  # towards the active limit: ignored
        assert not (await profile.read_status()).moving
        await profile.move_relative(-1000, QUICK)  # away from it: fine
        st = await wait_for(profile, at_rest)
        assert not st.limit_positive and st.position == sim.position()


async def test_move_with_pulses_per_rev_from_setup() -> None:
    async with rig(pulses_per_rev=4000) as (sim, _, profile):
        await profile.setup()
        assert sim.regs[0x0023] == 4000
        await profile.speed_run(600, 300, 300)
        st = await wait_for(profile, lambda s: s.velocity_rpm == 600)
        assert sim.velocity() == pytest.approx(600 / 60 * 4000)
        await profile.emergency_stop()
        await profile.zero_position()
        await profile.move_relative(4000, QUICK)  # one revolution
        st = await wait_for(profile, at_rest)
        assert st.position == 4000


# -- homing -------------------------------------------------------------------------------------

DOG_FORWARD = TwinSetup(home_switch=2000, limit_positive=6000)  # 24: dog [2000, 2500]
DOG_REVERSE = TwinSetup(home_switch=2000, limit_negative=-3000)  # 29: dog [2000, 2500]
HOMING_CASES = [
    # method, twin switches, home dog width (None: a cam), start position, physical origin edge
    ("positive_limit", TwinSetup(limit_positive=3000), None, 0, 3000),
    ("positive_limit", TwinSetup(limit_positive=3000), None, 3400, 3000),  # starting on it
    ("negative_limit", TwinSetup(limit_negative=-3000), None, 0, -3000),
    ("negative_limit", TwinSetup(limit_negative=-3000), None, -3300, -3000),
    ("home_switch_positive", DOG_FORWARD, 500, 0, 2000),
    ("home_switch_positive", DOG_FORWARD, 500, 4000, 2000),  # (b) via the limit
    ("home_switch_positive", DOG_FORWARD, 500, 2200, 2000),  # (c) on the dog
    ("home_switch_positive", TwinSetup(home_switch=2000), None, 0, 2000),  # a cam, not a dog
    ("home_switch_negative", DOG_REVERSE, 500, 5000, 2500),
    ("home_switch_negative", DOG_REVERSE, 500, 0, 2500),  # (b) via the limit
    ("home_switch_negative", DOG_REVERSE, 500, 2200, 2500),  # (c) on the dog
]


@pytest.mark.parametrize(("method", "switches", "width", "start", "edge"), HOMING_CASES)
async def test_every_homing_method_finds_its_origin(
    method: str, switches: TwinSetup, width: float | None, start: int, edge: float
) -> None:
    sim = SimCL86R(1, FAST, replace(switches, position=start), home_switch_width=width)
    async with rig(sim) as (_, _, profile):
        await profile.setup()
        await profile.home(method, speed_rpm=600, creep_rpm=120, accel_rps2=400, offset=100)
        first = await profile.read_status()
        assert first.homing and not first.homed
        st = await wait_for(profile, lambda s: s.homed and not s.moving)
        assert not st.homing and st.in_position and st.raw["mode"] == 3
        # The origin edge reads as the offset; the creep stop overshoots by a few pulses.
        overshoot = sim.physical_position() - edge
        assert abs(overshoot) < 10
        assert st.position == round(100 + overshoot) == sim.position()


async def test_homing_current_position_sets_the_offset_without_motion() -> None:
    async with rig(SimCL86R(1, FAST, TwinSetup(position=777))) as (sim, wire, profile):
        await profile.home("current_position", offset=1234)
        st = await profile.read_status()
        assert st.homed and not st.moving and st.position == 1234
        assert sim.physical_position() == 777
        assert "01 10 00 44 00 02 04 00 00 04 D2" in hexframes(wire)[0]


async def test_homing_can_be_stopped() -> None:
    async with rig(SimCL86R(1, FAST, TwinSetup(limit_positive=1_000_000))) as (_, _, profile):
        await profile.home("positive_limit", speed_rpm=600, creep_rpm=60, accel_rps2=400)
        await wait_for(profile, lambda s: s.homing)
        await profile.stop()
        st = await wait_for(profile, lambda s: not s.moving)
        assert not st.homed and not st.homing


async def test_homing_method_names_and_errors() -> None:
    async with rig() as (_, wire, profile):
        assert profile.homing_methods[0] == "positive_limit"
        assert profile.homing_mode(None) == 18 and profile.homing_mode("29") == 29
        with pytest.raises(NotSupported, match=r"CL86R.*method 'index_pulse'"):
            await profile.home("index_pulse")
        with pytest.raises(LimitViolation, match="origin offset"):
            await profile.home(offset=-1)  # the manual documents 0..65535 per half
        with pytest.raises(LimitViolation, match="homing creep speed"):
            await profile.home(creep_rpm=400)
        assert wire.requests() == []


# -- alarms, errors, not supported ---------------------------------------------------------------


async def test_alarm_latches_blocks_motion_and_clears_with_aux_control() -> None:
    async with rig() as (sim, _, profile):
        await profile.speed_run(600, 300, 300)
        await wait_for(profile, lambda s: s.velocity_rpm == 600)
        sim.raise_alarm(4)
        st = await profile.read_status()
        assert st.alarm and st.alarm_code == 4 and not st.moving and not st.in_position
        assert "position error" in st.alarm_text
        where = st.position
        await profile.move_relative(1000, QUICK)  # the drive does not start with an alarm
        st = await profile.read_status()
        assert st.alarm and not st.moving and st.position == where
        await profile.stop()  # a stop does not clear it either
        assert (await profile.read_status()).alarm
        await profile.clear_alarm()
        st = await profile.read_status()
        assert not st.alarm and st.alarm_code is None and st.alarm_text == ""
        await profile.move_relative(1000, QUICK)
        st = await wait_for(profile, at_rest)
        assert st.position == where + 1000


async def test_combined_error_code_text() -> None:
    async with rig() as (sim, _, profile):
        sim.raise_alarm(1 | 2)
        st = await profile.read_status()
        assert st.alarm_code == 3
        assert st.alarm_text == "overcurrent or phase-to-phase short circuit; overvoltage"


async def test_motion_is_ignored_while_released() -> None:
    async with rig() as (sim, _, profile):
        await profile.disable()
        await profile.move_relative(1000, QUICK)
        st = await profile.read_status()
        assert not st.enabled and not st.moving and sim.position() == 0


async def test_vendor_exception_codes() -> None:
    async with rig() as (sim, _, profile):
        with pytest.raises(ModbusException) as exc:
            await profile.slave.write_register(0x0031, 0)  # accel time 1..2000
        assert exc.value.code == 3 and exc.value.text == "illegal data"
        with pytest.raises(ModbusException) as exc:
            await profile.slave.read_holding_registers(0x000A, 2)  # the manual's FC03 example
        assert exc.value.code == 2 and exc.value.text == "illegal register address"
        with pytest.raises(ModbusException) as exc:
            await profile.slave.read_input_registers(0, 1)
        assert exc.value.code == 1 and exc.value.text == "illegal function code"
        with pytest.raises(ModbusException) as exc:
            await profile.slave.write_register(0x0003, 1)  # read-only status word
        assert exc.value.code == 2
        # A frame with a bad CRC is answered with the vendor's code 04.
        reply = sim.on_bad_crc(bytes.fromhex("01 06 00 38 00 01 00 00"))
        assert reply == b"\x86\x04" and sim.crc_errors == 1
        with pytest.raises(ModbusException, match="CRC check error") as exc:
            profile.slave.raise_exception(reply)
        assert exc.value.code == 4


async def test_not_supported_functions_name_drive_and_function() -> None:
    async with rig() as (_, wire, profile):
        with pytest.raises(NotSupported, match=r"CL86R drive cannot set its baud rate.*DIP"):
            await profile.set_baudrate(38400)
        with pytest.raises(NotSupported, match=r"CL86R drive cannot start its JOG.*speed_run"):
            await profile.jog()
        with pytest.raises(NotSupported, match="CL86R drive cannot start position/speed path 3"):
            await profile.start_path(3)
        assert wire.requests() == []


async def test_identity() -> None:
    async with rig() as (_, _, profile):
        ident = await profile.read_identity()
        assert ident.family == "CL86R" and ident.raw == {"model": 862, "software": 100}
        assert "862" in ident.model and ident.firmware == "100"


# -- 32-bit positions ---------------------------------------------------------------------------


async def test_positions_at_the_32_bit_boundaries_round_trip() -> None:
    top, bottom = 2**31 - 1, -(2**31)
    async with rig(SimCL86R(1, FAST, TwinSetup(position=top - 1000))) as (sim, wire, profile):
        await profile.move_absolute(top, QUICK)
        assert wire.requests()[-2].data[15:19] == bytes.fromhex("7F FF FF FF")  # high first
        st = await wait_for(profile, at_rest)
        assert st.position == top and (st.raw["position_high"], st.raw["position_low"]) == (
            0x7FFF, 0xFFFF,
        )
        # The drive's counter is 32 bits: going on wraps to the negative end.
        await profile.move_relative(1001, QUICK)
        st = await wait_for(profile, at_rest)
        assert st.position == bottom + 1000 == sim.position()
        await profile.move_absolute(bottom, QUICK)
        st = await wait_for(profile, at_rest)
        assert st.position == bottom
        assert (st.raw["position_high"], st.raw["position_low"]) == (0x8000, 0x0000)
        with pytest.raises(LimitViolation, match=r"target position.*-2147483648\.\.2147483647"):
            await profile.move_absolute(2**31, QUICK)


async def test_negative_targets_round_trip() -> None:
    async with rig(SimCL86R(1, FAST, TwinSetup(position=-70000))) as (sim, _, profile):
        st = await profile.read_status()
        assert st.position == -70000
        assert (st.raw["position_high"], st.raw["position_low"]) == (0xFFFE, 0xEE90)
        await profile.move_absolute(-71234, QUICK)
        assert sim.regs[0x0034] == 0xFFFE and sim.regs[0x0035] == 0xE9BE
        st = await wait_for(profile, at_rest)
        assert st.position == -71234


async def test_position_table_keeps_its_halves_0x10_apart() -> None:
    async with rig() as (sim, wire, profile):
        await profile.write_position_path(3, -70000, 600, 100, 100)
        assert (sim.regs[0x0063], sim.regs[0x0073]) == (0xFFFE, 0xEE90)
        assert (sim.regs[0x0083], sim.regs[0x0093], sim.regs[0x00A3]) == (600, 100, 100)
        assert hexframes(wire)[:2] == [
            "01 06 00 63 FF FE B9 A4", "01 06 00 73 EE 90 35 DD",
        ]
        assert await profile.read_position_path_pulses(3) == -70000
        with pytest.raises(LimitViolation, match=r"0..15"):
            await profile.write_position_path(16, 0, 600, 100, 100)


# -- units --------------------------------------------------------------------------------------


def test_ramp_time_conversion_by_hand() -> None:
    # time = rpm / 60 / (rev/s²) * 1000 ms
    assert ramp_time_ms(ACCEL_TIME, 120, 10) == 200  # the manual's 200 ms at 120 rpm
    assert ramp_time_ms(ACCEL_TIME, 600, 50) == 200
    assert ramp_time_ms(ACCEL_TIME, -3000, 1000) == 50
    assert ramp_time_ms(ACCEL_TIME, 1500, 300) == 83  # 83.33 ms rounded
    assert ramp_time_ms(HOME_SPEED, 120, 20) == 100
    with pytest.raises(LimitViolation, match=r"acceleration time.*1\.\.2000 ms"):
        ramp_time_ms(ACCEL_TIME, 3000, 1)  # 50 s
    with pytest.raises(LimitViolation, match=r"acceleration time.*1\.\.2000 ms"):
        ramp_time_ms(ACCEL_TIME, 60, 10_000)  # 0.1 ms rounds to 0
    with pytest.raises(LimitViolation, match="rate must be > 0"):
        ramp_time_ms(ACCEL_TIME, 60, 0)


async def test_move_parameters_reach_the_registers_as_computed() -> None:
    async with rig(start_speed_rpm=30) as (sim, wire, profile):
        await profile.move_relative(10, MoveParams(900, 75, 150))
        # 900 rpm = 15 rev/s: 15/75 = 200 ms up, 15/150 = 100 ms down
        assert [sim.regs[a] for a in range(0x0030, 0x0036)] == [30, 200, 100, 900, 0, 10]
        await wait_for(profile, at_rest)
        n = len(wire.requests())
        with pytest.raises(LimitViolation, match=r"maximum speed.*-3000\.\.3000 rpm"):
            await profile.speed_run(3001, 100, 100)
        with pytest.raises(LimitViolation, match="deceleration time"):
            await profile.move_relative(10, MoveParams(3000, 100, 1))
        with pytest.raises(LimitViolation, match="maximum speed"):
            await profile.move_relative(10, MoveParams(0.2, 100, 100))
        assert len(wire.requests()) == n  # nothing half-written
    with pytest.raises(ConfigError, match=r"start_speed_rpm: .* equal to 2 \(got 1\)"):
        CL86RProfile(profile.slave, start_speed_rpm=1)
    with pytest.raises(ConfigError, match=r"pulses_per_rev: .* 200 pulses/rev.*400\.\.51200"):
        CL86RProfile(profile.slave, pulses_per_rev=200)
    assert MAX_SPEED.encode(-120) == [0xFF88]


# -- line settings, EEPROM ----------------------------------------------------------------------


def test_twin_line_settings_default_and_checks() -> None:
    assert SimCL86R(1).settings == FACTORY  # DIP switches all ON: 9600, fixed 8N1
    assert SimCL86R(1, LineSettings.parse("19200 8E1")).regs[0x0021] == 2
    with pytest.raises(ConfigError, match="8N1 at 9600"):
        SimCL86R(1, LineSettings.parse("9600 8E1"))
    with pytest.raises(ConfigError, match="baud rate 57600"):
        SimCL86R(1, LineSettings.parse("57600 8N1"))


async def test_saved_parameters_and_line_format_survive_a_power_cycle() -> None:
    sim = SimCL86R(1, FAST)
    async with sim_bus([sim], FAST) as (_, bus):
        profile = CL86RProfile(bus.slave(1))
        await profile.write(HOME_SPEED, 500)
        await profile.set_line_format("8E1")
        await profile.save_parameters()
        await profile.write(START_SPEED, 77)  # not saved
        sim.power_loss()
        sim.power_restore()
        assert sim.settings == LineSettings.parse("115200 8E1")
        even = CL86RProfile(bus.slave(1, settings=LineSettings.parse("115200 8E1")))
        assert await even.read(HOME_SPEED) == 500
        assert await even.read(START_SPEED) == 5
        with pytest.raises(LimitViolation, match="serial data format"):
            await even.set_line_format("7E1")
