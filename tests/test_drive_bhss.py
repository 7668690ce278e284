"""BHSS-100-MBUS profile against its simulated twin over a virtual wire."""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from typing import Any

import anyio
import pytest

from drivebus.bus import Priority
from drivebus.clock import monotonic
from drivebus.drives.base import MoveParams
from drivebus.drives.bhss import EXCEPTION_TEXTS, BHSSProfile, Regs
from drivebus.drives.status import DriveStatus
from drivebus.errors import ConfigError, DriveAlarm, LimitViolation, ModbusException, NotSupported
from drivebus.line.rtu import frame
from drivebus.settings import LineSettings
from drivebus.sim import sim_bus
from drivebus.sim.drive import TwinSetup
from drivebus.sim.drives.bhss import SimBHSS
from drivebus.sim.slave import Fault
from drivebus.sim.wire import VirtualWire
from wirelog import frames_text

FAST = LineSettings.parse("115200 8N1")
QUICK = MoveParams(speed_rpm=1200.0, accel_rps2=200.0, decel_rps2=200.0)  # 100 ms ramps


def hx(text: str) -> bytes:
    """Bytes of a hex string as printed in the manual."""
    return bytes.fromhex(text)


@asynccontextmanager
async def bhss(
    *, setup: bool = True, **options: Any
) -> AsyncIterator[tuple[VirtualWire, SimBHSS, BHSSProfile]]:
    """A twin at address 1 on a 115200 8N1 wire and a profile for it."""
    sim_opts = {k: options.pop(k) for k in list(options) if k in (
        "position", "home_switch", "limit_negative", "limit_positive")}
    sim = SimBHSS(1, FAST, TwinSetup(**sim_opts))
    async with sim_bus([sim], FAST) as (wire, bus):
        profile = BHSSProfile(bus.slave(1), **options)
        try:
            if setup:
                await profile.setup()
            yield wire, sim, profile
        except Exception as exc:  # what the wire saw, with the failure
            exc.add_note(f"the wire's last frames:\n{frames_text(wire.log, limit=20)}")
            raise


async def wait_for(
    profile: BHSSProfile, check: Callable[[DriveStatus], bool], timeout: float = 5.0
) -> DriveStatus:
    """Poll the drive's status until ``check`` holds (bounded by ``timeout``)."""
    with anyio.fail_after(timeout):
        while True:
            st = await profile.read_status()
            if check(st):
                return st
            await anyio.sleep(0.005)


def sent(wire: VirtualWire) -> list[bytes]:
    """Request frames on the wire, oldest first."""
    return [f.data for f in wire.requests()]


def replies(wire: VirtualWire) -> list[bytes]:
    """Reply frames on the wire, oldest first."""
    return [f.data for f in wire.log if f.direction == "reply"]


# -- the manual's example frames ---------------------------------------------------------------


async def test_a_first_status_poll_at_emergency_inside_a_hold_learns_at_that_priority(
) -> None:
    """A profile that has not learned (new, or its setup cut short by a stop) learns
    before its first status poll; an emergency poll inside a hold (an axis's poll right
    when a stop should have brought the drive to rest) does that at its own priority:
    it used to learn at CONFIG and wait for its own hold's end, so the line stopped."""
    async with bhss(setup=False) as (wire, _sim, profile):
        bus = profile.slave.bus
        with anyio.fail_after(10):
            async with bus.hold():
                st = await profile.read_status(priority=Priority.EMERGENCY)
        assert st.position is not None and not st.moving
        assert wire.requests()  # the learn reads and the poll went out


async def test_manual_position_mode_example_frames() -> None:
    # §3.3.5(1): start 10 rpm, accel/decel 100 ms, max 500 rpm, +1000 pulses, relative start.
    async with bhss(start_speed_rpm=10) as (wire, sim, profile):
        accel = 500 / 60 / 0.1  # rev/s² that ramps to 500 rpm in 100 ms
        wire.clear_log()
        await profile.move_relative(1000, MoveParams(500, accel, accel))
        assert sent(wire) == [
            hx("01 06 00 21 00 64 D8 2B"),
            hx("01 06 00 22 00 64 28 2B"),
            hx("01 06 00 23 01 F4 78 17"),
            hx("01 06 00 24 00 00 C9 C1"),
            hx("01 06 00 25 03 E8 98 BF"),
            hx("01 06 00 27 00 01 F8 01"),
        ]
        assert replies(wire) == sent(wire)  # every FC06 is echoed
        await wait_for(profile, lambda s: s.in_position)
        assert sim.position() == 1000


async def test_manual_start_speed_frame_comes_from_setup() -> None:
    async with bhss(setup=False, start_speed_rpm=10) as (wire, _sim, profile):
        await profile.setup()
        assert hx("01 06 00 20 00 0A 08 07") in sent(wire)


async def test_manual_speed_stop_home_and_absolute_frames() -> None:
    async with bhss(home_switch=500) as (wire, _sim, profile):
        accel = 500 / 60 / 0.1
        wire.clear_log()
        await profile.speed_run(500, accel, accel)  # §3.3.5(2)
        assert sent(wire) == [
            hx("01 06 00 21 00 64 D8 2B"),
            hx("01 06 00 22 00 64 28 2B"),
            hx("01 06 00 23 01 F4 78 17"),
            # The manual prints the echo as "00 01 B8 00": B8 00 is the CRC of value 2,
            # so the CRC-valid request is followed and the echo equals it.
            hx("01 06 00 27 00 02 B8 00"),
        ]
        assert replies(wire)[-1] == hx("01 06 00 27 00 02 B8 00")
        wire.clear_log()
        await profile.stop()
        await profile.emergency_stop()
        assert sent(wire) == [hx("01 06 00 28 00 00 09 C2"), hx("01 06 00 28 00 01 C8 02")]
        await wait_for(profile, lambda s: not s.moving)
        wire.clear_log()
        await profile.move_absolute(0, QUICK)
        assert sent(wire)[-1] == hx("01 06 00 27 00 05 F9 C2")  # §4.5.1
        await wait_for(profile, lambda s: s.in_position)
        wire.clear_log()
        await profile.home()
        assert sent(wire)[-1] == hx("01 06 00 30 00 01 48 05")  # §4.5.3


async def test_manual_acceleration_time_frame() -> None:
    # §3.3.2(2): acceleration time 500 ms, echoed unchanged.
    async with bhss() as (wire, _sim, profile):
        wire.clear_log()
        await profile.move_relative(10, MoveParams(500, 500 / 60 / 0.5, 100.0))
        assert sent(wire)[0] == hx("01 06 00 21 01 F4 D9 D7")
        assert replies(wire)[0] == hx("01 06 00 21 01 F4 D9 D7")


async def test_manual_fc16_example_with_write_multiple() -> None:
    # §3.3.3: the 5000-pulse distance in one FC16, and the drive's reply.
    async with bhss(write_multiple=True) as (wire, _sim, profile):
        wire.clear_log()
        await profile.move_relative(5000, QUICK)
        assert hx("01 10 00 24 00 02 04 00 00 13 88 FD 12") in sent(wire)
        assert hx("01 10 00 24 00 02 01 C3") in replies(wire)


async def test_manual_input_function_frame() -> None:
    # §5 sets X0/X1/X2 to origin/forward/backward limit but prints the value 1 in all three
    # frames; the register table's codes 1/2/3 are used, so only X0's frame is the manual's.
    inputs = {"X0": "origin", "X1": "forward_limit", "X2": "backward_limit"}
    async with bhss(inputs=inputs, home_switch=100) as (wire, sim, _profile):
        frames = sent(wire)
        assert hx("01 06 00 43 00 01 B9 DE") in frames
        assert hx("01 06 00 44 00 02 48 1E") in frames
        assert hx("01 06 00 45 00 03 D8 1E") in frames
        assert [sim.regs[a] for a in (0x43, 0x44, 0x45)] == [1, 2, 3]


async def test_manual_read_examples_from_factory_twin() -> None:
    async with bhss(setup=False) as (wire, _sim, profile):
        assert await profile.slave.read_holding_registers(0x0020, 4) == [5, 100, 100, 60]
        assert await profile.slave.read_holding_registers(0x0023, 1) == [60]
        assert sent(wire) == [hx("01 03 00 20 00 04 45 C3"), hx("01 03 00 23 00 01 75 C0")]
        assert replies(wire) == [
            hx("01 03 08 00 05 00 64 00 64 00 3C F0 D1"),
            hx("01 03 02 00 3C B8 55"),
        ]


@pytest.mark.parametrize(
    ("pdu", "query", "reply", "code"),
    [
        (bytes.fromhex("0300190001"), "01 03 00 19 00 01 55 CD", "01 83 03 01 31", 3),
        (bytes.fromhex("0300200020"), "01 03 00 20 00 20 45 D8", "01 83 05 81 33", 5),
        (bytes.fromhex("0300270001"), "01 03 00 27 00 01 34 01", "01 83 06 C1 32", 6),
        (bytes.fromhex("0600260008"), "01 06 00 26 00 08 69 C7", "01 86 07 03 A2", 7),
        # The manual prints "01 82 02 61 C1": its CRC bytes are swapped.
        (bytes.fromhex("0200000004"), "01 02 00 00 00 04 79 C9", "01 82 02 C1 61", 2),
        # The manual's request at 0xFF00 is garbled; its reply "01 86 04 43 A3" is valid.
        (bytes.fromhex("06FF000000"), None, "01 86 04 43 A3", 4),
    ],
)
async def test_manual_exception_examples(
    pdu: bytes, query: str | None, reply: str, code: int
) -> None:
    async with bhss(setup=False) as (wire, _sim, profile):
        with pytest.raises(ModbusException) as err:
            await profile.slave.transact(pdu)
        assert err.value.code == code
        assert err.value.text == EXCEPTION_TEXTS[code]
        if query is not None:
            assert sent(wire) == [hx(query)]
        assert replies(wire) == [hx(reply)]


def test_manual_crc_error_example_answers_exception_01() -> None:
    # The text says a bad CRC is dropped, the CRC-valid example reply is "01 83 01 80 F0":
    # the twin follows the example by default and can be told to stay silent.
    bad = hx("01 03 00 20 00 01 85 C1")
    reply = SimBHSS(1).on_bad_crc(bad)
    assert reply is not None
    assert frame(1, reply) == hx("01 83 01 80 F0")
    assert SimBHSS(1, crc_error_reply=False).on_bad_crc(bad) is None


# -- procedures ---------------------------------------------------------------------------------


async def test_identity_and_default_line_settings() -> None:
    sim = SimBHSS(3)
    assert sim.settings == LineSettings.parse("9600 8N1")  # the factory default
    async with sim_bus([sim], LineSettings.parse("9600 8N1")) as (_wire, bus):
        ident = await BHSSProfile(bus.slave(3)).read_identity()
    assert ident.family == "BHSS"
    assert ident.firmware == "1.01"
    assert ident.raw == {"model": 0x0305, "version": 0x0101}


def test_line_format_register_applies_after_power_cycle() -> None:
    sim = SimBHSS(1)
    sim.write_registers(0x0015, [2], 0.0)  # 8E1, stored: write-through is on
    assert sim.settings == LineSettings.parse("9600 8N1")
    sim.power_loss()
    sim.power_restore()
    assert sim.settings == LineSettings.parse("9600 8E1")
    assert SimBHSS(1, LineSettings.parse("115200 8O1")).regs[0x0015] == 3
    with pytest.raises(ValueError, match="7E1"):
        SimBHSS(1, LineSettings.parse("9600 7E1"))


async def test_enable_and_disable() -> None:
    async with bhss() as (_wire, sim, profile):
        await profile.disable()
        st = await profile.read_status()
        assert not st.enabled and not sim.enabled
        await profile.move_relative(500, QUICK)  # a released motor does not turn
        assert not (await profile.read_status()).moving
        await profile.enable()
        assert (await profile.read_status()).enabled
        await profile.move_relative(500, QUICK)
        st = await wait_for(profile, lambda s: s.in_position)
        assert st.position == 500


async def test_relative_and_absolute_moves_land_on_target() -> None:
    async with bhss() as (_wire, sim, profile):
        await profile.move_relative(3000, QUICK)
        st = await profile.read_status()
        assert st.moving and not st.in_position
        st = await wait_for(profile, lambda s: s.in_position)
        assert st.position == 3000 == sim.position()
        await profile.move_absolute(-1500, QUICK)
        st = await wait_for(profile, lambda s: s.in_position)
        assert st.position == -1500 == sim.position()
        await profile.move_relative(-500, QUICK)
        st = await wait_for(profile, lambda s: s.in_position)
        assert st.position == -2000
        await profile.zero_position()
        assert (await profile.read_status()).position == 0
        await profile.move_absolute(250, QUICK)
        assert (await wait_for(profile, lambda s: s.in_position)).position == 250


def planned_velocity(sim: SimBHSS, after: float = 2.0) -> float:
    """The twin's velocity (pulses/s) ``after`` seconds from now, from its motion plan."""
    return sim.velocity(monotonic() + after)


async def test_speed_run_change_and_decelerating_stop() -> None:
    async with bhss() as (wire, sim, profile):
        await profile.speed_run(600, 100.0, 50.0)  # 10000 p/s, 100 ms up, 200 ms down
        assert (sim.regs[0x21], sim.regs[0x22], sim.regs[0x23]) == (100, 200, 600)
        assert planned_velocity(sim) == pytest.approx(10000)
        await wait_for(profile, lambda s: s.moving)
        await profile.speed_run(-300, 100.0, 50.0)  # speed change with reversal
        assert sim.regs[0x23] == 0x10000 - 300
        assert planned_velocity(sim) == pytest.approx(-5000)
        await wait_for(profile, lambda s: s.moving and s.raw["direction"] == 1)  # CW = negative
        sent = len(wire.requests())
        with pytest.raises(NotSupported, match="its stop takes no deceleration"):
            await profile.stop(decel_rps2=1000.0)  # 0x0028 = 0 cannot take one (L1229)
        assert len(wire.requests()) == sent  # refused before anything was sent
        await profile.stop()  # ramps down with the decel latched at the start
        stop_end = wire.requests()[-1].end
        # 300 rpm at 50 rev/s² -> 100 ms = 50000 pulses/s² at 1000 pulses/rev.
        ramp = abs(sim.velocity(stop_end)) / 50_000
        assert sim.kin.end_time() - stop_end == pytest.approx(ramp, abs=1e-6)
        st = await wait_for(profile, lambda s: not s.moving)
        assert not st.in_position  # stopped, not a completed position move


async def test_emergency_stop_halts_at_once() -> None:
    async with bhss() as (_wire, sim, profile):
        await profile.speed_run(1200, 200.0, 10.0)  # 2 s ramp down
        await wait_for(profile, lambda s: s.moving)
        await profile.emergency_stop()
        assert not sim.is_moving()
        assert not (await profile.read_status()).moving


@pytest.mark.parametrize("which", ["stop", "emergency_stop"])
async def test_a_stop_whose_reply_is_lost_is_sent_again(which: str) -> None:
    # A stop is not a start: sending it again after a lost reply can only stop a motor that
    # the first one did not reach (its frame lost on the wire). Before, both stops were
    # marked not idempotent: one lost reply was a ResponseTimeout and no second stop.
    async with bhss() as (wire, sim, profile):
        await profile.speed_run(600, 100.0, 50.0)
        await wait_for(profile, lambda s: s.moving)
        sim.faults.inject(Fault.NO_REPLY)  # the next reply: the stop's
        before = len(wire.requests())
        await getattr(profile, which)()
        stops = [f for f in sent(wire)[before:] if f[1] == 0x06 and f[2:4] == b"\x00\x28"]
        assert len(stops) == 2, frames_text(wire.log, limit=6)  # the stop, then again
        await wait_for(profile, lambda s: not s.moving)
        assert not sim.is_moving()


async def test_speed_run_zero_is_a_stop() -> None:
    async with bhss() as (_wire, sim, profile):
        await profile.speed_run(600, 100.0, 100.0)
        await wait_for(profile, lambda s: s.moving)
        await profile.speed_run(0, 100.0, 100.0)
        assert planned_velocity(sim) == 0.0
        await wait_for(profile, lambda s: not s.moving)


@pytest.mark.parametrize(
    ("method", "switches", "start", "offset"),
    [
        ("forward_limit_origin", {"home_switch": 2000, "limit_positive": 9000}, 0, 500),
        ("backward_limit_origin", {"home_switch": 2000, "limit_negative": -3000}, 5000, 0),
        ("forward_limit", {"limit_positive": 3000, "limit_negative": -9000}, 0, -400),
        ("backward_limit", {"limit_negative": -3000}, 1000, 300),
    ],
)
async def test_every_homing_method(
    method: str, switches: dict[str, float], start: int, offset: int
) -> None:
    async with bhss(position=start, **switches) as (_wire, sim, profile):
        await profile.home(method, speed_rpm=600, creep_rpm=120, accel_rps2=100.0,
                           offset=offset)
        assert sim.regs[0x0031] == BHSSProfile.homing_methods.index(method)
        st = await profile.read_status()
        assert st.homing and not st.homed
        st = await wait_for(profile, lambda s: s.homed and not s.moving, timeout=10.0)
        assert not st.homing and st.in_position
        assert st.position == offset
        edge = switches["home_switch" if "origin" in method else
                        "limit_positive" if method == "forward_limit" else "limit_negative"]
        assert sim.physical_position() == pytest.approx(edge + offset, abs=1)
        # The counter now counts from the origin (the edge found is position 0).
        await profile.move_absolute(2 * offset, QUICK)
        st = await wait_for(profile, lambda s: s.in_position)
        assert st.position == 2 * offset
        assert sim.physical_position() == pytest.approx(edge + 2 * offset, abs=1)


async def test_limit_switch_stops_a_speed_run_and_is_reported() -> None:
    async with bhss(limit_positive=2000) as (_wire, _sim, profile):
        await profile.speed_run(600, 100.0, 100.0)
        st = await wait_for(profile, lambda s: s.limit_positive and not s.moving)
        assert not st.limit_negative
        # 10000 pulses/s braked over 100 ms: the stop overshoots the switch by 500 pulses.
        assert st.position == 2500
        await profile.move_relative(500, QUICK)  # into the limit: refused
        assert not (await profile.read_status()).moving
        # Away from it: allowed. Going back by just the overshoot would end on the switch
        # edge itself (active there, p >= 2000), so go back well past it.
        await profile.move_relative(-1000, QUICK)
        st = await wait_for(profile, lambda s: s.in_position)
        assert st.position == 1500
        assert not st.limit_positive


async def test_move_ending_on_the_limit_edge_completes() -> None:
    # Coming back from beyond the switch to exactly its edge is not a rising limit edge:
    # the move completes (the switch is active at its edge, p >= 2000).
    async with bhss(limit_positive=2000, position=2500) as (_wire, sim, profile):
        await profile.move_relative(-500, QUICK)
        st = await wait_for(profile, lambda s: s.in_position)
        assert st.position == 2000 == sim.position()
        assert st.limit_positive


async def test_resettable_alarm_raised_and_cleared() -> None:
    async with bhss() as (_wire, sim, profile):
        await profile.speed_run(600, 100.0, 100.0)
        sim.raise_alarm(4)
        st = await profile.read_status()
        assert st.alarm and st.alarm_code == 4 and "EEPROM" in st.alarm_text
        assert not st.moving
        await profile.move_relative(100, QUICK)  # a locked drive ignores motion
        assert not (await profile.read_status()).moving
        await profile.clear_alarm()
        st = await profile.read_status()
        assert not st.alarm and st.alarm_code is None


@pytest.mark.parametrize("code", [1, 5])
async def test_power_cycle_alarm_needs_power_cycle(code: int) -> None:
    async with bhss() as (_wire, sim, profile):
        await profile.move_relative(700, QUICK)
        await wait_for(profile, lambda s: s.in_position)
        sim.raise_alarm(code)
        with pytest.raises(DriveAlarm) as err:
            await profile.clear_alarm()
        assert err.value.code == code and "power cycle" in err.value.text
        sim.power_loss()
        sim.power_restore()
        st = await profile.read_status()
        assert not st.alarm and st.position == 0  # incremental encoder: counter restarts


async def test_supply_alarm_clears_by_itself() -> None:
    async with bhss() as (_wire, sim, profile):
        sim.raise_alarm(3)
        with pytest.raises(DriveAlarm):
            await profile.clear_alarm()
        sim.supply_recovered()
        assert not (await profile.read_status()).alarm


async def test_not_supported_and_missing_values() -> None:
    async with bhss() as (_wire, _sim, profile):
        with pytest.raises(NotSupported, match=r"BHSS.*save parameters"):
            await profile.save_parameters()
        assert (await profile.read_status()).velocity_rpm is None
    async with bhss(eeprom_write_through=True) as (_wire, _sim, profile):
        await profile.save_parameters()  # every write is already stored
    with pytest.raises(ConfigError, match="pulses/rev"):
        BHSSProfile(None, pulses_per_rev=1234)  # type: ignore[arg-type]
    async with bhss() as (_wire, _sim, profile):
        with pytest.raises(ConfigError, match="homing method"):
            await profile.home("index_pulse")


# -- positions and word order ---------------------------------------------------------------------


async def test_positions_round_trip_near_the_32_bit_limits() -> None:
    top = 2**31 - 1
    async with bhss(position=top - 100) as (wire, sim, profile):
        assert (await profile.read_status()).position == top - 100
        wire.clear_log()
        await profile.move_absolute(top, QUICK)
        assert hx("01 06 00 24 7F FF") == sent(wire)[-3][:6]  # high word first
        assert hx("01 06 00 25 FF FF") == sent(wire)[-2][:6]
        st = await wait_for(profile, lambda s: s.in_position)
        assert st.position == top
        assert (st.raw["position_high"], st.raw["position_low"]) == (0x7FFF, 0xFFFF)
        with pytest.raises(LimitViolation, match="total number of pulses"):
            await profile.move_absolute(top + 1, QUICK)
    bottom = -(2**31)
    async with bhss(position=bottom + 100, write_multiple=True) as (wire, sim, profile):
        wire.clear_log()
        await profile.move_relative(-100, QUICK)
        assert sent(wire)[-2][7:11] == hx("FF FF FF 9C")  # -100, high word first
        st = await wait_for(profile, lambda s: s.in_position)
        assert st.position == bottom == sim.position()
        assert (st.raw["position_high"], st.raw["position_low"]) == (0x8000, 0x0000)
        await profile.move_absolute(bottom + 40, QUICK)
        assert (await wait_for(profile, lambda s: s.in_position)).position == bottom + 40
        with pytest.raises(LimitViolation):
            await profile.move_relative(bottom - 1, QUICK)


# -- units ----------------------------------------------------------------------------------------


async def test_ramp_time_conversion_against_hand_computed_registers() -> None:
    async with bhss() as (_wire, sim, profile):
        # 600 rpm = 10 rev/s: at 50 rev/s² the ramp is 0.2 s, at 25 rev/s² 0.4 s.
        await profile.move_relative(2000, MoveParams(600, 50.0, 25.0))
        assert (sim.regs[0x21], sim.regs[0x22], sim.regs[0x23]) == (200, 400, 600)
        # 1500 rpm = 25 rev/s at 12.5 rev/s² = 2000 ms: the top of the range.
        await wait_for(profile, lambda s: s.in_position)
        await profile.move_relative(10, MoveParams(1500, 12.5, 300.0))
        assert (sim.regs[0x21], sim.regs[0x22]) == (2000, 83)
        await wait_for(profile, lambda s: s.in_position, timeout=10.0)
        # Homing: 300 rpm = 5 rev/s at 50 rev/s² -> 100 ms in 0x0034.
        await profile.home(speed_rpm=300, creep_rpm=60, accel_rps2=50.0, offset=-7)
        assert [sim.regs[a] for a in range(0x31, 0x37)] == [0, 300, 60, 100, 0, 7]
        await profile.emergency_stop()
    assert BHSSProfile.ramp_ms(Regs.ACCEL_TIME, -600, 50.0) == 200


async def test_out_of_range_values_name_the_register() -> None:
    async with bhss() as (wire, _sim, profile):
        wire.clear_log()
        with pytest.raises(LimitViolation, match=r"acceleration time.*0\.\.2000 ms"):
            await profile.move_relative(100, MoveParams(600, 1.0, 100.0))  # 10 s ramp
        with pytest.raises(LimitViolation, match=r"maximum speed.*at least 1 rpm"):
            await profile.move_relative(100, MoveParams(0.2, 100.0, 100.0))
        with pytest.raises(LimitViolation, match=r"maximum speed.*-3000\.\.3000"):
            await profile.speed_run(3500, 100.0, 100.0)
        with pytest.raises(LimitViolation, match=r"back to origin accel/decel time.*30\.\.2000"):
            await profile.home(speed_rpm=60, accel_rps2=100.0)  # 10 ms ramp
        with pytest.raises(LimitViolation, match=r"back to origin query speed.*5\.\.300"):
            await profile.home(speed_rpm=600, creep_rpm=400, accel_rps2=100.0)
        with pytest.raises(LimitViolation, match="must be > 0"):
            await profile.speed_run(100, 0.0, 100.0)
        assert not [f for f in sent(wire) if f[1] == 0x06 and f[3] == 0x27]  # nothing started
    async with bhss(pulses_per_rev=51200) as (_wire, sim, profile):
        assert sim.regs[0x0011] == 7
        with pytest.raises(LimitViolation, match=r"200 kHz.*-234\.\.234 rpm"):
            await profile.speed_run(300, 100.0, 100.0)


# -- EEPROM wear -----------------------------------------------------------------------------


async def test_motion_after_setup_does_not_write_eeprom() -> None:
    async with bhss(setup=False, home_switch=3000) as (_wire, sim, profile):
        await profile.move_relative(100, QUICK)  # factory state: every write hits EEPROM
        assert sim.eeprom_writes == 6
        await wait_for(profile, lambda s: s.in_position)
        await profile.setup()
        assert sim.regs[0x0016] == 1 and sim.eeprom[0x0016] == 1
        assert sim.eeprom_writes == 7  # only the write that turned write-through off
        await profile.move_relative(1000, QUICK)
        await wait_for(profile, lambda s: s.in_position)
        await profile.move_absolute(-200, QUICK)
        await profile.stop()
        await profile.speed_run(300, 100.0, 100.0)
        await profile.speed_run(-300, 100.0, 100.0)
        await profile.emergency_stop()
        await profile.home(speed_rpm=300, creep_rpm=60, accel_rps2=50.0)
        await wait_for(profile, lambda s: s.homed and not s.moving)
        await profile.zero_position()
        await profile.disable()
        await profile.enable()
        assert sim.eeprom_writes == 7
        await profile.setup()  # nothing left to change: no EEPROM write either
        assert sim.eeprom_writes == 7


async def test_ram_only_writes_are_lost_on_power_cycle() -> None:
    async with bhss() as (_wire, sim, profile):
        await profile.move_relative(10, MoveParams(600, 50.0, 50.0))
        assert sim.regs[0x21] == 200
        sim.power_loss()
        sim.power_restore()
        assert sim.regs[0x21] == 100  # the EEPROM still holds the factory value
        assert sim.regs[0x16] == 1  # write-through stays off


async def test_opting_in_to_eeprom_write_through() -> None:
    async with bhss(eeprom_write_through=True) as (_wire, sim, profile):
        assert sim.regs[0x0016] == 0
        before = sim.eeprom_writes
        await profile.move_relative(10, MoveParams(600, 50.0, 50.0))
        assert sim.eeprom_writes == before + 6
        assert sim.eeprom[0x21] == 200
