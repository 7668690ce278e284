"""EPR60/EPT60 profile against its twin (served on the RTU sim wire: same register map)."""

from __future__ import annotations

from contextlib import AbstractAsyncContextManager
from typing import Any

import pytest

from drivebus import LineSettings
from drivebus.drives.nt_family import EPR60Profile, NT86Profile
from drivebus.errors import ConfigError, LimitViolation, ModbusException, NotSupported
from drivebus.line.rtu import crc_ok
from drivebus.sim import VirtualWire, sim_bus
from drivebus.sim.drive import TwinSetup
from drivebus.sim.drives.nt_family import SimEPR60
from nt_helpers import FAST, QUICK, idle, nt_rig, sent, wait_for

HOMING = {"speed_rpm": 500, "creep_rpm": 200, "accel_rps2": 1000}


def epr60(
    sim: SimEPR60 | None = None, **opts: Any
) -> AbstractAsyncContextManager[tuple[VirtualWire, EPR60Profile, SimEPR60]]:
    """A twin on a 115200 8N1 sim bus and a set-up profile for it."""
    return nt_rig(sim or SimEPR60(1), EPR60Profile, **opts)


async def test_setup_writes_microstep_to_96_97_low_word_first() -> None:
    sim = SimEPR60(1)
    assert sim.settings == LineSettings.parse("115200 8N1")
    async with sim_bus([sim], FAST) as (wire, bus):
        profile = EPR60Profile(bus.slave(1), pulses_per_rev=4000)
        await profile.setup()
        frames = sent(wire)
        assert "01 10 00 60 00 02 04 0F A0 00 00 F6 B1" in frames  # 96=0x0FA0, 97=0
        assert "01 06 00 12 00 00 29 CF" in frames  # the manual's FC06 example
        assert not any(f.startswith("01 06 00 18") for f in frames)  # no register 24
        with pytest.raises(ModbusException) as err:
            await bus.slave(1).read_holding_registers(24, 1)
        assert err.value.code == 2
        with pytest.raises(ModbusException) as err:
            await bus.slave(1).read_holding_registers(287, 1)  # no NT86 homing block
        assert err.value.code == 2
    with pytest.raises(ConfigError, match=r"pulses_per_rev: .* 100 pulses/rev.*200\.\.65535"):
        EPR60Profile(profile.slave, pulses_per_rev=100)


async def test_manual_jog_frame_speed_change_and_emergency_stop() -> None:
    async with epr60() as (wire, profile, sim):
        await profile.speed_run(600, 100, 100)
        assert sent(wire)[-2:] == [
            "01 10 00 4B 00 04 08 00 64 00 64 02 58 01 F4 86 EC",
            "01 06 00 12 00 03 69 CE",
        ]
        await wait_for(profile, lambda s: s.velocity_rpm == 600)
        await profile.speed_run(300, 100, 100)  # 77 applies at once (manual: L1121)
        st = await wait_for(profile, lambda s: s.velocity_rpm == 300)
        assert st.moving
        await profile.emergency_stop()
        assert sent(wire)[-1] == "01 06 00 12 00 05 E9 CC"
        st = await wait_for(profile, idle)
        assert st.velocity_rpm == 0 and not sim.is_moving()


async def test_moves_and_int32_extremes_round_trip() -> None:
    async with epr60() as (_, profile, _):
        await profile.move_relative(-7000, QUICK)
        assert (await wait_for(profile, idle)).position == -7000
        await profile.move_absolute(1500, QUICK)
        assert (await wait_for(profile, idle)).position == 1500
        await profile.move_relative(400000, QUICK)  # 2 s at 3000 rpm
        with pytest.raises(ModbusException) as err:
            await profile.move_relative(100, QUICK)  # while MOV=1
        assert err.value.code == 4
        await profile.emergency_stop()
        await wait_for(profile, idle)
    # The EPR60 documents no range for 73/74 beyond int32: the extremes are reachable.
    for start, target in ((2**31 - 9000, 2**31 - 1), (-(2**31) + 9000, -(2**31))):
        async with epr60(SimEPR60(1, setup=TwinSetup(position=start))) as (wire, profile, sim):
            assert (await profile.read_status()).position == start
            await profile.move_absolute(target, QUICK)
            low, high = target & 0xFFFF, (target >> 16) & 0xFFFF
            assert sent(wire)[-2].startswith(  # 70..74 with the target low word first
                f"01 10 00 46 00 05 0A 03 E8 03 E8 0B B8 {low >> 8:02X} {low & 0xFF:02X} "
                f"{high >> 8:02X} {high & 0xFF:02X}"
            )
            assert (await wait_for(profile, idle)).position == target == sim.position()
    async with epr60() as (_, profile, _):
        with pytest.raises(LimitViolation, match="distance/target"):
            await profile.move_absolute(2**31, QUICK)


@pytest.mark.parametrize(
    ("method", "sim_kw", "origin"),
    [
        ("limit_negative", {"limit_negative": -6000}, -6000 + 100),
        ("limit_positive", {"limit_positive": 7000}, 7000 - 100),
    ],
)
async def test_homing_methods(method: str, sim_kw: dict[str, Any], origin: int) -> None:
    sim = SimEPR60(1, setup=TwinSetup(**sim_kw))
    async with epr60(sim, home_input=5) as (wire, profile, _):
        await profile.home(method, offset=100, **HOMING)
        code = 0 if method == "limit_negative" else 1
        frames = sent(wire)
        assert frames[0].startswith(f"01 10 00 4F 00 05 0A 00 0{code} 01 F4 00 C8 03 E8 00 64")
        assert frames[1:] == [
            "01 06 00 14 00 01 08 0E",  # 20=1 homing mode
            "01 03 00 01 00 01 D5 CA",  # status: HOME before the start
            "01 03 00 40 00 01 85 DE",  # IN5 setting (function 12)
            "01 06 00 40 00 2C 89 C3",  # polarity flipped: start homing
            "01 06 00 40 00 0C 88 1B",  # and back
        ]
        st = await profile.read_status()
        assert st.homing and st.moving and not st.homed
        st = await wait_for(profile, lambda s: not s.homing)
        assert st.homed and not st.moving and st.in_position and st.position == 0
        assert sim.physical_position() == origin  # 83 pulses off the limit's edge
        wire.clear_log()
        away = 500 if method == "limit_negative" else -500
        await profile.move_relative(away, QUICK)  # back to register-18 mode first
        assert sent(wire)[-2] == "01 06 00 14 00 00 C9 CE"
        assert (await wait_for(profile, idle)).position == away


async def test_an_earlier_homings_home_bit_does_not_end_the_next_one() -> None:
    """No trigger register reads back: a homing is over once it moved and rests, or once
    it reports a HOME it did not report when it began. A drive that keeps HOME from an
    earlier homing and raises MOV a little late had its new homing taken for done on the
    first status after the start."""
    sim = SimEPR60(1, setup=TwinSetup(limit_negative=-6000))
    async with epr60(sim, home_input=5) as (_, profile, _):
        await profile.home("limit_negative", **HOMING)
        st = await wait_for(profile, lambda s: not s.homing)
        assert st.homed and not st.moving  # the twin rests with HOME set
        assert not profile.state["home_before"]
        # a new homing just started, nothing moved yet, HOME still set from the last one
        profile.state.update(homing=True, seen_moving=False, home_before=True)
        st = await profile.read_status()
        assert st.homing, "an earlier homing's HOME ended this one"
        profile.state.update(home_before=False)  # HOME came up since it began: done
        assert not (await profile.read_status()).homing


async def test_homing_needs_opt_in_and_stop_aborts_it() -> None:
    async with epr60(SimEPR60(1, setup=TwinSetup(limit_negative=-200000))) as (wire, profile, _):
        with pytest.raises(NotSupported, match=r"EPR60 drive cannot start homing.*home_input"):
            await profile.home()
        assert not sent(wire)
    twin = SimEPR60(1, setup=TwinSetup(limit_negative=-200000))
    async with epr60(twin, home_input=5) as (wire, profile, sim):
        await profile.home(**HOMING)
        await wait_for(profile, lambda s: s.moving)
        wire.clear_log()
        await profile.stop()
        assert sent(wire) == ["01 06 00 14 00 00 C9 CE", "01 06 00 12 00 06 A9 CD"]
        st = await wait_for(profile, idle)
        assert not st.homed and not sim.is_moving()
        with pytest.raises(LimitViolation, match=r"offset after homing.*0\.\.1000"):
            await profile.home(offset=-5)


async def test_enable_and_alarm_opt_ins() -> None:
    async with epr60() as (_, profile, _):
        for call in (profile.enable, profile.disable, profile.clear_alarm):
            with pytest.raises(NotSupported, match="EPR60 drive cannot"):
                await call()
    sim = SimEPR60(1)
    async with epr60(sim, enable_input=3, clear_alarm_input=4) as (wire, profile, _):
        await profile.disable()
        assert not (await profile.read_status()).enabled
        await profile.enable()
        assert (await wait_for(profile, lambda s: bool(s.raw["status"] & 0x20))).enabled  # RDY
        sim.raise_alarm(0x10)
        st = await profile.read_status()
        assert st.alarm and st.alarm_text == "OT: over-temperature"
        await profile.clear_alarm()
        assert not (await profile.read_status()).alarm
        ident = await profile.read_identity()
        assert ident.family == "EPR60" and ident.raw["drive_id"] == 60
        assert all(crc_ok(f.data) for f in wire.log)


def test_profile_differences_are_data() -> None:
    assert EPR60Profile.regs.microstep.address == 96 and EPR60Profile.regs.microstep.words == 2
    assert NT86Profile.regs.microstep.address == 24
    assert EPR60Profile.regs.move_target.hi == 2**31 - 1
    assert NT86Profile.regs.move_target.hi == 16777216
    assert EPR60Profile.homing_methods[0] == "limit_negative"
    assert EPR60Profile.word_order is NT86Profile.word_order
