"""NT86 profile against its simulated twin: manual frames, motion, homing, alarms, limits."""

from __future__ import annotations

from contextlib import AbstractAsyncContextManager
from typing import Any

import pytest

from drivebus import LineSettings
from drivebus.drives.base import MoveParams
from drivebus.drives.nt_family import NT86Profile, StatusBit, decode_alarm
from drivebus.drives.status import DriveStatus
from drivebus.errors import ConfigError, LimitViolation, ModbusException, NotSupported
from drivebus.line.rtu import crc_ok
from drivebus.sim import VirtualWire, sim_bus
from drivebus.sim.drive import TwinSetup
from drivebus.sim.drives.nt_family import SimNT86
from nt_helpers import FAST, QUICK, idle, nt_rig, sent, wait_for


def nt86(
    sim: SimNT86 | None = None, **opts: Any
) -> AbstractAsyncContextManager[tuple[VirtualWire, NT86Profile, SimNT86]]:
    """A twin on a 115200 8N1 sim bus and a set-up profile for it."""
    return nt_rig(sim or SimNT86(1), NT86Profile, **opts)


def replies(wire: VirtualWire) -> list[str]:
    return [f.data.hex(" ").upper() for f in wire.log if f.direction == "reply"]


def command_end(wire: VirtualWire, code: int) -> float:
    """When the last write of ``code`` to register 18 ended on the wire."""
    frame = bytes((1, 6, 0, 0x12, 0, code))
    return [f.end for f in wire.requests() if f.data.startswith(frame)][-1]


# -- the manual's frames ----------------------------------------------------------------------


async def test_manual_example_frames_byte_for_byte() -> None:
    sim = SimNT86(1)
    async with sim_bus([sim], FAST) as (wire, bus):
        profile = NT86Profile(bus.slave(1))
        await profile.setup()
        # Appendix A, FC06: write 18 = 0 (setup() puts the command register in its idle state).
        assert "01 06 00 12 00 00 29 CF" in sent(wire)
        assert "01 06 00 12 00 00 29 CF" in replies(wire)  # the echo
        wire.clear_log()
        # Appendix A, FC16: 75..78 = 100, 100, 600, 500 — a speed run at 600 rpm, 100 r/s².
        await profile.speed_run(600, 100, 100)
        assert sent(wire)[-2:] == [
            "01 10 00 4B 00 04 08 00 64 00 64 02 58 01 F4 86 EC",
            "01 06 00 12 00 03 69 CE",  # 18=3: run forward
        ]
        assert "01 10 00 4B 00 04 B1 DC" in replies(wire)
        await profile.emergency_stop()
        assert sent(wire)[-1] == "01 06 00 12 00 05 E9 CC"


async def test_computed_procedure_frames() -> None:
    async with nt86() as (wire, profile, _):
        await profile.move_relative(4000, MoveParams(600, 200, 200))
        assert sent(wire) == [
            "01 06 00 54 00 00 C8 1A",  # 84=0 incremental
            "01 10 00 46 00 05 0A 00 C8 00 C8 02 58 0F A0 00 00 1B 6E",  # 70..74
            "01 06 00 12 00 01 E8 0F",  # 18=1
        ]
        await wait_for(profile, idle)
        wire.clear_log()
        await profile.home("home_switch_positive", speed_rpm=50, creep_rpm=10, accel_rps2=200)
        assert sent(wire)[:3] == [
            "01 10 01 20 00 04 08 00 00 00 32 00 0A 00 C8 2D 14",  # 288..291
            "01 10 01 25 00 03 06 00 00 00 00 00 00 F3 06",  # 293..295
            "01 06 01 1F 00 04 B8 33",  # 287=4
        ]
        await profile.stop()
        await wait_for(profile, idle)
        wire.clear_log()
        await profile.save_parameters()
        await profile.home("set_origin")
        assert sent(wire)[0] == "01 06 00 5A 00 01 68 19"
        assert sent(wire)[-1] == "01 06 01 1F 00 06 39 F2"
        assert all(crc_ok(f.data) for f in wire.log)


def test_manual_fc03_example_response_decodes() -> None:
    # Appendix A: 01 03 0A 00 00 00 01 00 00 00 03 FF FF C5 C6 (registers 0-4).
    assert crc_ok(bytes.fromhex("01 03 0A 00 00 00 01 00 00 00 03 FF FF C5 C6"))
    profile = NT86Profile.__new__(NT86Profile)
    profile.closed_loop = None
    profile._homing = False
    st = profile.decode_status([0x0000, 0x0001, 0x0000, 0x0003, 0xFFFF])
    assert st.enabled and not st.alarm and not st.moving and st.in_position
    assert st.position is None  # registers 8/9 were not in that read
    assert decode_alarm(0x0006) == "OC: over-current; OV: over-voltage"


# -- moves ------------------------------------------------------------------------------------


async def test_relative_and_absolute_moves_land_on_target() -> None:
    async with nt86() as (_, profile, sim):
        await profile.move_relative(6000, QUICK)
        st = await profile.read_status()
        assert st.moving and not st.in_position
        st = await wait_for(profile, idle)
        assert st.position == 6000 and st.in_position
        await profile.move_relative(-10000, QUICK)
        st = await wait_for(profile, idle)
        assert st.position == -4000 == sim.position()
        await profile.move_absolute(-12345, QUICK)
        assert (await wait_for(profile, idle)).position == -12345
        await profile.move_absolute(2500, QUICK)
        assert (await wait_for(profile, idle)).position == 2500


async def test_start_while_moving_is_refused_with_devicefail_but_stops_are_obeyed() -> None:
    async with nt86() as (wire, profile, _):
        await profile.move_relative(200000, QUICK)
        with pytest.raises(ModbusException) as err:
            await profile.move_relative(1000, QUICK)
        assert err.value.code == 4
        assert "only" in err.value.text and "stop" in err.value.text
        assert "DEVICEFAIL" in str(err.value)
        await profile.stop()
        st = await wait_for(profile, idle)
        assert 0 < st.position < 200000
        assert sent(wire)[-1].startswith("01 03")


async def test_limit_violations_name_register_and_range() -> None:
    async with nt86() as (wire, profile, _):
        with pytest.raises(LimitViolation, match=r"point move acceleration.*70.*10\.\.1000"):
            await profile.move_relative(100, MoveParams(600, 5, 200))
        with pytest.raises(LimitViolation, match=r"point move speed.*72.*3000"):
            await profile.move_relative(100, MoveParams(3001, 200, 200))
        with pytest.raises(LimitViolation, match=r"distance/target.*-16777216\.\.16777216"):
            await profile.move_absolute(16777217, QUICK)
        with pytest.raises(LimitViolation, match="jog speed"):
            await profile.speed_run(0.3, 100, 100)
        assert not sent(wire)  # nothing reached the drive


async def test_unit_conversion_matches_hand_computed_registers_and_motion() -> None:
    sim = SimNT86(1)
    async with nt86(sim, pulses_per_rev=10000) as (wire, profile, _):
        assert sim.params[24] == 10000  # setup() wrote the pulses/rev
        # 599.6 rpm -> 600 = 0x0258; 199.6 r/s² -> 200 = 0x00C8; 40000 = 0x00009C40 low first.
        await profile.move_relative(40000, MoveParams(599.6, 199.6, 199.6))
        assert sent(wire)[1] == "01 10 00 46 00 05 0A 00 C8 00 C8 02 58 9C 40 00 00 37 DC"
        # 600 rpm at 10000 pulses/rev = 100000 pulses/s; 200 r/s² = 2e6 pulses/s²:
        # ramps of 0.05 s, so the move takes 40000/100000 + 0.05 = 0.45 s from the command.
        assert sim.kin.end_time() - command_end(wire, 1) == pytest.approx(0.45, abs=1e-9)
        st = await wait_for(profile, lambda s: bool(s.raw["status"] & StatusBit.ARRSPD))
        assert st.velocity_rpm == 600.0
        assert (await wait_for(profile, idle)).position == 40000


async def test_positions_round_trip_at_the_32_bit_boundaries() -> None:
    for start in (2**31 - 1, -(2**31), -1, 65536):
        async with nt86(SimNT86(1, setup=TwinSetup(position=start))) as (_, profile, _):
            st = await profile.read_status()
            assert st.position == start
    # Low word first on the wire: -2 = FF FE FF FF as registers 8 (low), 9 (high).
    async with nt86(SimNT86(1, setup=TwinSetup(position=-2))) as (_, profile, _):
        st = await profile.read_status()
        assert (st.raw["position_low"], st.raw["position_high"]) == (0xFFFE, 0xFFFF)
    # Extreme targets of register 73/74 and the counter wrapping like the drive's.
    async with nt86(SimNT86(1, setup=TwinSetup(position=-16777216 + 3000))) as (wire, profile, _):
        await profile.move_absolute(-16777216, QUICK)
        assert "00 00 FF 00" in sent(wire)[-2]  # -16777216 = 0xFF000000: low 0000, high FF00
        assert (await wait_for(profile, idle)).position == -16777216
    async with nt86(SimNT86(1, setup=TwinSetup(position=2**31 - 1000))) as (_, profile, sim):
        await profile.move_relative(3000, QUICK)
        st = await wait_for(profile, idle)
        assert st.position == -(2**31) + 2000 == sim.position()


# -- speed runs and stops ---------------------------------------------------------------------


async def test_speed_run_speed_change_reverse_and_stop() -> None:
    async with nt86() as (wire, profile, sim):
        await profile.speed_run(600, 1000, 1000)
        st = await wait_for(profile, lambda s: s.velocity_rpm == 600)
        assert st.moving and not st.in_position
        wire.clear_log()
        await profile.speed_run(1200, 1000, 1000)  # same direction: only 77 changes
        assert sent(wire) == ["01 03 00 01 00 01 D5 CA", "01 06 00 4D 04 B0 1A A9"]
        await wait_for(profile, lambda s: s.velocity_rpm == 1200)
        wire.clear_log()
        await profile.speed_run(-300, 1000, 1000)  # reverse: stop, wait, restart
        frames = sent(wire)
        assert "01 06 00 12 00 06 A9 CD" in frames and frames[-1] == "01 06 00 12 00 04 28 0C"
        st = await wait_for(profile, lambda s: s.velocity_rpm == -300)
        assert sim.is_moving()
        await profile.stop()
        st = await wait_for(profile, idle)
        assert st.velocity_rpm == 0 and st.in_position and not sim.is_moving()


async def test_emergency_stop_uses_register_78_and_stop_with_decel() -> None:
    async with nt86() as (wire, profile, sim):
        await profile.speed_run(3000, 1000, 10)
        await wait_for(profile, lambda s: s.velocity_rpm == 3000)
        await profile.emergency_stop()
        # 3000 rpm = 200000 pulses/s at 4000 pulses/rev; 500 r/s² = 2e6 pulses/s²: 0.1 s.
        assert sim.kin.end_time() - command_end(wire, 5) == pytest.approx(0.1, abs=1e-9)
        await wait_for(profile, idle)
        # stop(decel): 76 would only apply at the next start, so 78 + 18=5 carry it.
        await profile.speed_run(3000, 1000, 10)
        await wait_for(profile, lambda s: s.velocity_rpm == 3000)
        wire.clear_log()
        await profile.stop(decel_rps2=250)
        assert sent(wire) == ["01 06 00 4E 00 FA 69 9E", "01 06 00 12 00 05 E9 CC"]
        assert sim.kin.end_time() - command_end(wire, 5) == pytest.approx(0.2, abs=1e-9)
        await wait_for(profile, idle)
        wire.clear_log()
        await profile.move_relative(100, QUICK)  # 78 goes back to the configured 500
        assert sent(wire)[:2] == ["01 06 00 54 00 00 C8 1A", "01 06 00 4E 01 F4 E9 CA"]
        assert sim.params[78] == 500


async def test_limit_switch_stops_motion() -> None:
    sim = SimNT86(1, setup=TwinSetup(limit_positive=20000, limit_negative=-20000))
    async with nt86(sim) as (_, profile, _):
        await profile.speed_run(1500, 1000, 1000)
        st = await wait_for(profile, idle)
        assert st.limit_positive and st.position > 20000
        await profile.move_relative(5000, QUICK)  # further into the limit: not obeyed
        st = await profile.read_status()
        assert not st.moving
        await profile.move_relative(-30000, QUICK)  # away from it: fine
        st = await wait_for(profile, idle)
        assert not st.limit_positive


# -- homing -----------------------------------------------------------------------------------

HOMING = {"speed_rpm": 1000, "creep_rpm": 200, "accel_rps2": 1000}


async def home_and_wait(profile: NT86Profile, method: str, **kw: Any) -> DriveStatus:
    await profile.home(method, **{**HOMING, **kw})
    st = await profile.read_status()
    assert st.homing and st.moving and not st.homed
    return await wait_for(profile, lambda s: not s.homing)


@pytest.mark.parametrize(
    ("method", "setup", "options", "origin"),
    [
        ("home_switch_positive", TwinSetup(home_switch=8000), {}, 8000),
        ("home_switch_positive", TwinSetup(home_switch=-3000), {}, -3000),  # starts on the cam
        ("home_switch_negative", TwinSetup(home_switch=-6000), {"home_cam": "negative"}, -6000),
        ("limit_positive", TwinSetup(limit_positive=12000), {}, 12000),
        ("limit_negative", TwinSetup(limit_negative=-9000), {}, -9000),
        ("hard_stop_positive", None, {"hard_stop_positive": 5000, "control_mode": 1}, 5000),
        ("hard_stop_negative", None, {"hard_stop_negative": -4000, "control_mode": 2}, -4000),
    ],
)
async def test_mechanical_homing_methods(
    method: str, setup: TwinSetup | None, options: dict[str, Any], origin: int
) -> None:
    sim = SimNT86(1, setup=setup, **options)
    async with nt86(sim) as (_, profile, _):
        if method.startswith("hard_stop"):
            await profile.slave.write_register(296, 1000)  # stall time 50 ms
        st = await home_and_wait(profile, method, offset=700)
        assert st.homed and not st.moving and st.in_position
        assert sim.physical_position() == origin  # stopped on the switch edge
        assert st.position == 700  # 295=0: the origin gets the offset as coordinate
        assert await profile.read(profile.regs.command) == 0
        assert (await profile.slave.read_holding_registers(287, 1)) == [0]


async def test_homing_offset_moves_and_electrical_and_set_origin() -> None:
    sim = SimNT86(1, setup=TwinSetup(home_switch=4000))
    async with nt86(sim, home_offset_moves=True) as (wire, profile, _):
        st = await home_and_wait(profile, "home_switch_positive", offset=-1500)
        assert sent(wire)[1] == "01 10 01 25 00 03 06 FA 24 FF FF 00 01 56 BF"
        assert st.homed and st.position == -1500 and sim.physical_position() == 2500
        await profile.move_absolute(3000, QUICK)
        await wait_for(profile, idle)
        st = await home_and_wait(profile, "electrical", offset=-2000)
        assert st.homed and st.position == -2000 and sim.physical_position() == 2000
        await profile.home("set_origin", offset=1234)
        st = await wait_for(profile, lambda s: not s.homing)
        assert st.homed and st.position == 1234 and sim.physical_position() == 2000


async def test_homing_limit_handling_reverse_or_stop() -> None:
    # The switch (a dog over [-5000, -4500]) lies behind the start: the positive search
    # runs into the positive limit (manual 3.1.2 ③). Reversed, the search passes the dog
    # to its falling edge at -5000, then creeps forward to its rising edge there.
    setup = TwinSetup(home_switch=-5000, limit_positive=6000)
    sim = SimNT86(1, setup=setup, home_switch_width=500)
    async with nt86(sim, home_reverse_at_limit=True) as (_, profile, _):
        st = await home_and_wait(profile, "home_switch_positive")
        assert st.homed and st.position == 0 and sim.physical_position() == -5000
    sim = SimNT86(1, setup=setup, home_switch_width=500)
    async with nt86(sim) as (_, profile, _):  # 295=0: stop at the limit, not homed
        st = await home_and_wait(profile, "home_switch_positive")
        assert not st.homed and st.limit_positive and not st.moving


async def test_homing_errors() -> None:
    async with nt86(SimNT86(1, hard_stop_positive=100)) as (_, profile, _):
        with pytest.raises(NotSupported, match=r"NT86.*closed-loop"):
            await profile.home("hard_stop_positive")
        with pytest.raises(ConfigError, match="no homing method"):
            await profile.home("index_pulse")
        with pytest.raises(LimitViolation, match=r"home offset.*1048576"):
            await profile.home(offset=2_000_000)


# -- enable, alarms, power -------------------------------------------------------------------


async def test_not_supported_without_opt_in() -> None:
    async with nt86() as (wire, profile, _):
        for call in (profile.enable, profile.disable, profile.clear_alarm):
            with pytest.raises(NotSupported, match=r"NT86 drive cannot .* over Modbus"):
                await call()
        assert not sent(wire)


async def test_enable_disable_through_input_polarity_opt_in() -> None:
    sim = SimNT86(1)
    async with nt86(sim, enable_input=3) as (wire, profile, _):
        await profile.move_relative(100000, QUICK)
        await profile.disable()
        assert "01 06 00 3E 00 24 E8 1D" in sent(wire)  # 62 = 0x24: IN3 "motor offline"
        st = await profile.read_status()
        assert not st.enabled and not st.moving and not sim.is_moving()
        with pytest.raises(ModbusException) as err:
            await profile.move_relative(100, QUICK)
        assert err.value.code == 4
        await profile.enable()
        assert sent(wire)[-2] == "01 06 00 3E 00 04 E9 C5"
        assert (await profile.read_status()).enabled
        # Someone wires IN3: the drive goes offline; enable() finds the polarity that works.
        sim.set_input(3, True)
        assert not (await profile.read_status()).enabled
        await profile.enable()
        assert (await profile.read_status()).enabled and sim.params[62] == 0x24


async def test_alarm_latches_and_clears_only_by_input_or_power_cycle() -> None:
    sim = SimNT86(1)
    async with nt86(sim, clear_alarm_input=4) as (wire, profile, _):
        assert sim.params[63] == 5  # setup() gave IN4 function 5 "clear fault"
        await profile.speed_run(1000, 1000, 1000)
        sim.raise_alarm(0x02)
        st = await profile.read_status()
        assert st.alarm and st.alarm_code == 0x02 and st.alarm_text == "OC: over-current"
        assert not st.moving and not st.in_position
        with pytest.raises(ModbusException):
            await profile.speed_run(1000, 1000, 1000)
        assert (await profile.read_status()).alarm  # still latched
        wire.clear_log()
        await profile.clear_alarm()
        assert sent(wire)[1:3] == ["01 06 00 3F 00 25 78 1D", "01 06 00 3F 00 05 79 C5"]
        st = await profile.read_status()
        assert not st.alarm and st.alarm_code is None
    sim = SimNT86(1)
    async with nt86(sim) as (_, profile, _):
        await profile.move_relative(5000, QUICK)
        await wait_for(profile, idle)
        await profile.slave.write_register(70, 300)
        await profile.save_parameters()
        await profile.slave.write_register(71, 333)
        sim.raise_alarm(0x80)
        sim.power_loss()
        sim.power_restore()
        st = await profile.read_status()
        assert not st.alarm and st.position == 0 and not st.homed
        assert await profile.slave.read_holding_registers(70, 2) == [300, 1000]  # 71=333 unsaved


async def test_zero_position_and_identity() -> None:
    async with nt86(SimNT86(1, setup=TwinSetup(position=777))) as (_, profile, _):
        await profile.zero_position()
        assert (await profile.read_status()).position == 0
        ident = await profile.read_identity()
        assert ident.family == "NT86" and "NT86" in ident.model
        assert ident.raw["drive_id"] == 86


async def test_exception_codes_and_texts() -> None:
    async with nt86() as (_, profile, _):
        slave = profile.slave
        with pytest.raises(ModbusException) as err:
            await slave.read_input_registers(0, 1)
        assert err.value.code == 1 and "FC03, FC06, FC16" in err.value.text
        with pytest.raises(ModbusException) as err:
            await slave.read_holding_registers(86, 1)
        assert err.value.code == 2 and "ILLEGAL_DATA_ADD" in err.value.text
        with pytest.raises(ModbusException) as err:
            await slave.write_register(1, 0)  # status is read-only
        assert err.value.code == 2
        with pytest.raises(ModbusException) as err:
            await slave.write_register(70, 5)
        assert err.value.code == 3 and "range" in err.value.text
        with pytest.raises(ModbusException) as err:
            await slave.write_registers(73, [0x0001, 0x0100])  # 0x01000001 > 16777216
        assert err.value.code == 3


async def test_line_settings_are_8n1_and_dip_switch_bauds() -> None:
    assert SimNT86(1).settings == LineSettings.parse("115200 8N1")
    with pytest.raises(ConfigError, match="8N1 only"):
        SimNT86(1, LineSettings.parse("19200 8E1"))
    with pytest.raises(ConfigError, match="9600, 19200, 38400, 115200"):
        SimNT86(1, LineSettings.parse("57600 8N1"))
    with pytest.raises(ConfigError, match=r"1\.\.31"):
        SimNT86(32)
    slow = LineSettings.parse("9600 8N1")
    async with sim_bus([SimNT86(5, slow)], slow) as (_, bus):
        assert (await NT86Profile(bus.slave(5)).read_status()).enabled
