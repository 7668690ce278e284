"""OD2000 (2000h object-dictionary drive): profile against its simulated twin over a sim wire.

Every CRC-valid frame of the manual (shared/seeds/003_5f14fd9326f2e79a.txt, L328-464) is
reproduced byte for byte, requests by the profile and replies (including the exception
examples) by the twin.
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable

import anyio
import pytest
import serial_asyncio

from drivebus import LineSettings
from drivebus.clock import monotonic
from drivebus.drives import DriveStatus, MoveParams
from drivebus.drives.od_drive import (
    EXCEPTION_TEXTS,
    ODDriveProfile,
    read_pdu,
    reply_length,
    write_multiple_pdu,
    write_pdu,
)
from drivebus.errors import (
    ConfigError,
    LimitViolation,
    ModbusException,
    NotSupported,
    ResponseTimeout,
)
from drivebus.line.rtu import frame
from drivebus.providers import line_provider
from drivebus.sim import VirtualWire, sim_bus
from drivebus.sim.drive import TwinSetup
from drivebus.sim.drives.od_drive import SimODDrive
from waits import within

LINE = LineSettings.parse("9600 8N1")


def hx(text: str) -> bytes:
    """Bytes of a hex string as the manual prints it."""
    return bytes.fromhex(text)


def requests(wire: VirtualWire) -> list[bytes]:
    """Request frames on the wire, oldest first."""
    return [f.data for f in wire.requests()]


def replies(wire: VirtualWire) -> list[bytes]:
    """Reply frames on the wire, oldest first."""
    return [f.data for f in wire.log if f.direction == "reply"]


def last_exchange(wire: VirtualWire) -> tuple[bytes, bytes]:
    """The last request frame and the last reply frame."""
    return requests(wire)[-1], replies(wire)[-1]


# -- the manual's worked examples (L328-389) ---------------------------------------------------


async def test_manual_read_one_register() -> None:
    async with sim_bus([SimODDrive()], LINE) as (wire, bus):
        profile = ODDriveProfile(bus.slave(1))
        assert await profile.read_object(0x2000) == 1
        assert last_exchange(wire) == (hx("01 03 20 00 00 00 01 4B F4"), hx("01 03 02 00 01 79 84"))


async def test_manual_read_four_registers_walks_entries() -> None:
    # The manual's reply values 1, 2, 0, 500 (its CRC is printed as "fc": FC C0 computed).
    sim = SimODDrive(objects={(0x2001, 0): 2, (0x2003, 1): 500})
    async with sim_bus([sim], LINE) as (wire, bus):
        profile = ODDriveProfile(bus.slave(1))
        assert await profile.read_words(0x2000, 0, 4) == [1, 2, 0, 500]
        assert last_exchange(wire) == (
            hx("01 03 20 00 00 00 04 8B F7"),
            hx("01 03 08 00 01 00 02 00 00 01 F4 FC C0"),
        )


async def test_manual_write_pulses_per_rev_from_setup() -> None:
    sim = SimODDrive()
    async with sim_bus([sim], LINE) as (wire, bus):
        profile = ODDriveProfile(bus.slave(1), pulses_per_rev=10000)
        await profile.setup()
        write = hx("01 06 20 05 00 27 10 90 91")
        assert write in requests(wire)
        assert write in replies(wire)  # the echo
        assert sim.pulses_per_rev == 10000
        wire.clear_log()
        await profile.setup()  # already right: read, not written again
        assert write not in requests(wire)


async def test_manual_save_parameters() -> None:
    sim = SimODDrive()
    async with sim_bus([sim], LINE) as (wire, bus):
        await ODDriveProfile(bus.slave(1)).save_parameters()
        frame_ = hx("01 06 20 30 00 00 01 44 A1")
        assert last_exchange(wire) == (frame_, frame_)
        assert sim.saves == 1


async def test_manual_write_sub_index() -> None:
    sim = SimODDrive(objects={(0x2003, 1): 200})
    async with sim_bus([sim], LINE) as (wire, bus):
        profile = ODDriveProfile(bus.slave(1))
        await profile.write_object(0x2003, 1, 50)
        frame_ = hx("01 06 20 03 01 00 32 5A 30")
        assert last_exchange(wire) == (frame_, frame_)
        assert sim.values[(0x2003, 1)] == 50
        assert await profile.read_parameter("standstill_current_delay") == 50


async def test_manual_write_multiple() -> None:
    sim = SimODDrive(objects={(0x2000, 0): 7})
    async with sim_bus([sim], LINE) as (wire, bus):
        profile = ODDriveProfile(bus.slave(1))
        await profile.write_objects(0x2000, [1, 1])
        assert last_exchange(wire) == (
            hx("01 10 20 00 00 00 02 04 00 01 00 01 AC 49"),
            hx("01 10 20 00 00 00 02 09 56"),
        )
        assert (sim.values[(0x2000, 0)], sim.values[(0x2001, 0)]) == (1, 1)
        assert await profile.read_objects(0x2000, 3) == [1, 1, 0]


# -- the manual's error examples (L391-464) ----------------------------------------------------

Call = Callable[[ODDriveProfile], Awaitable[object]]

ERROR_EXAMPLES: list[tuple[str, Call, str, str, int]] = [
    (
        "function code 02",
        lambda p: p.slave.transact(hx("02 00 00 00 00 04"), expect=reply_length),
        "01 02 00 00 00 00 04 0B E1",
        "01 82 02 C1 61",
        2,
    ),
    (
        "index 2031h out of range",
        lambda p: p.read_words(0x2031, 0, 1),
        "01 03 20 31 00 00 01 45 08",
        "01 83 03 01 31",
        3,
    ),
    (
        "32 registers at once",
        lambda p: p.slave.transact(read_pdu(0x2000, 0, 32), expect=reply_length),
        "01 03 20 00 00 00 20 8B EC",
        "01 83 04 40 F3",
        4,
    ),
    (
        "read of write-only 2030h",
        lambda p: p.read_words(0x2030, 0, 1),
        "01 03 20 30 00 00 01 44 F4",
        "01 83 05 81 33",
        5,
    ),
    (
        "8 written to 2001h",
        lambda p: p.write_word(0x2001, 0, 8),
        "01 06 20 01 00 00 08 8A 5B",
        "01 86 06 C2 62",
        6,
    ),
]


@pytest.mark.parametrize(
    ("call", "sent", "answer", "code"),
    [e[1:] for e in ERROR_EXAMPLES],
    ids=[e[0] for e in ERROR_EXAMPLES],
)
async def test_manual_error_examples(call: Call, sent: str, answer: str, code: int) -> None:
    async with sim_bus([SimODDrive()], LINE) as (wire, bus):
        profile = ODDriveProfile(bus.slave(1))
        with pytest.raises(ModbusException) as info:
            await call(profile)
        assert info.value.code == code
        assert info.value.text == EXCEPTION_TEXTS[code]  # the vendor's meaning, not Modbus's
        assert last_exchange(wire) == (hx(sent), hx(answer))
        assert len(requests(wire)) == 1  # exceptions are answers: never retried


async def _read_frame(reader: asyncio.StreamReader, n: int) -> bytes:
    with within(10, f"a reply of {n} bytes on the raw port"):
        return await reader.readexactly(n)


async def test_manual_crc_error_example_reply_and_silent_mode() -> None:
    # The profile cannot send a bad CRC, so this one goes out on a raw port.
    line_provider("sim")  # teaches pyserial sim://NAME, as a SerialLine does when it opens
    bad = hx("01 03 20 00 00 00 01 4B F3")
    for crc_error_reply in (True, False):
        sim = SimODDrive(crc_error_reply=crc_error_reply)
        async with VirtualWire(f"od-crc-{crc_error_reply}") as wire:
            wire.attach(sim)
            reader, writer = await serial_asyncio.open_serial_connection(
                url=wire.url, baudrate=9600
            )
            try:
                writer.write(bad)
                if crc_error_reply:
                    assert await _read_frame(reader, 5) == hx("01 83 01 80 F0")
                else:
                    # Silence: send a good frame after the line's t3.5 (about 4 ms at 9600
                    # 8N1) after the bad frame's end as the wire saw it (not after a sleep
                    # from our write: on a busy machine the wire may read it late); the
                    # first answer on the wire is then the one to the good frame.
                    with within(5, "the bad frame on the wire"):
                        await wire.wait_requests(1)
                    await anyio.sleep(max(0.0, wire.requests()[0].end + 0.01 - monotonic()))
                    writer.write(hx("01 03 20 00 00 00 01 4B F4"))
                    assert await _read_frame(reader, 7) == hx("01 03 02 00 01 79 84")
                    assert len(replies(wire)) == 1
                assert wire.requests()[0].note == "bad crc"
                assert sim.crc_errors == 1
            finally:
                writer.close()


# -- the profile copes with both CRC-error behaviours ------------------------------------------


async def test_drive_reported_crc_error_is_retried() -> None:
    sim = SimODDrive()
    async with sim_bus([sim], LINE, retries=2) as (wire, bus):
        profile = ODDriveProfile(bus.slave(1))
        sim.damage_requests(1)
        assert await profile.read_object(0x2000) == 1
        assert requests(wire) == [hx("01 03 20 00 00 00 01 4B F4")] * 2
        assert replies(wire) == [hx("01 83 01 80 F0"), hx("01 03 02 00 01 79 84")]
        # Exception 01 means the drive executed nothing: even a command is sent again.
        sim.raise_alarm(30)
        sim.damage_requests(1)
        await profile.clear_alarm()
        assert sim.alarm_code == 0
        # More damaged frames than retries: the vendor's error comes out.
        sim.damage_requests(3)
        with pytest.raises(ModbusException) as info:
            await profile.read_object(0x2000)
        assert info.value.code == 1
        assert "CRC" in info.value.text


async def test_silent_crc_error_is_a_timeout() -> None:
    sim = SimODDrive(crc_error_reply=False)
    async with sim_bus([sim], LINE, retries=2) as (wire, bus):
        profile = ODDriveProfile(bus.slave(1))
        sim.damage_requests(1)
        assert await profile.read_object(0x2000) == 1  # the bus retried the read
        assert len(requests(wire)) == 2
        # A command is not retried blindly after silence: the caller reads back.
        sim.raise_alarm(30)
        sim.damage_requests(1)
        with pytest.raises(ResponseTimeout):
            await profile.clear_alarm()
        assert (await profile.read_status()).alarm_code == 30


# -- frames the extraction derived from the table (§6.2) ---------------------------------------


async def test_derived_frames() -> None:
    sim = SimODDrive(bus_voltage=240)
    cases: list[tuple[Call, str]] = [
        (lambda p: p.clear_alarm(), "01 06 20 1E 00 00 01 4D 89"),
        (lambda p: p.clear_fault_history(), "01 06 20 1D 00 00 01 4D CD"),
        (lambda p: p.restore_factory_settings(), "01 06 20 30 00 00 02 04 A0"),
        (lambda p: p.zero_position(), "01 06 20 11 00 00 01 4E 9D"),
        (lambda p: p.write_parameter("closed_loop", 1), "01 06 20 19 00 00 01 4C FD"),
        (lambda p: p.read_object(0x201C, 1), "01 03 20 1C 01 00 01 1D A4"),
        (lambda p: p.read_object(0x201F), "01 03 20 1F 00 00 01 4C 20"),
        (lambda p: p.read_object(0x200D), "01 03 20 0D 00 00 01 49 58"),
        (lambda p: p.read_object(0x2014), "01 03 20 14 00 00 01 4E 04"),
        (lambda p: p.read_object(0x2018), "01 03 20 18 00 00 01 4D 54"),
        (lambda p: p.read_object(0x2017), "01 03 20 17 00 00 01 4E 40"),
        (lambda p: p.read_object(0x2010), "01 03 20 10 00 00 01 4F 34"),
        (lambda p: p.read_object(0x2011), "01 03 20 11 00 00 01 4E C8"),
    ]
    async with sim_bus([sim], LINE) as (wire, bus):
        profile = ODDriveProfile(bus.slave(1))
        for call, expected in cases:
            await call(profile)
            assert requests(wire)[-1] == hx(expected), expected
        assert await profile.read_parameter("bus_voltage") == 240
        identity = await profile.read_identity()
        assert requests(wire)[-3:] == [
            hx("01 03 20 1A 01 00 01 1D 2C"),
            hx("01 03 20 1A 02 00 01 ED 2C"),
            hx("01 03 20 1A 03 00 01 BC EC"),
        ]
        assert identity.family == "OD2000"
        assert identity.raw == {"software": 1, "hardware": 0, "bus_software": 1}
        assert identity.firmware == "software 1, bus software 1, hardware 0"


# -- typed access and range checks -------------------------------------------------------------


async def test_range_and_access_checked_before_sending() -> None:
    async with sim_bus([SimODDrive()], LINE) as (wire, bus):
        profile = ODDriveProfile(bus.slave(1))
        with pytest.raises(LimitViolation, match=r"2001h\.0.*0\.\.2"):
            await profile.write_object(0x2001, 0, 8)
        with pytest.raises(LimitViolation, match=r"pulses_per_rev \(2005h\.0\).*6400\.\.51200"):
            await profile.write_parameter("pulses_per_rev", 1000)
        with pytest.raises(LimitViolation, match=r"standstill_current_percent"):
            await profile.write_object(0x2003, 2, 101)
        with pytest.raises(ConfigError, match="write-only"):
            await profile.read_object(0x2030)
        with pytest.raises(ConfigError, match="read-only"):
            await profile.write_object(0x201A, 1, 5)
        with pytest.raises(ConfigError, match=r"no object 2031h\.0"):
            await profile.read_object(0x2031)
        with pytest.raises(ConfigError, match=r"1\.\.16"):
            await profile.read_words(0x2000, 0, 17)
        with pytest.raises(ConfigError, match="one entry per request"):
            await profile.read_objects(0x2002, 2)  # runs into 2003h, which has no sub 0
        with pytest.raises(ConfigError, match="no object named"):
            await profile.read_parameter("max_speed")
        assert requests(wire) == []
        with pytest.raises(ConfigError, match=r"pulses_per_rev: .* 1000 pulses/rev.*6400\.\.51200"):
            ODDriveProfile(bus.slave(1), pulses_per_rev=1000)
        with pytest.raises(ConfigError, match="fixed at 1"):
            ODDriveProfile(bus.slave(2))
    with pytest.raises(ValueError, match="fixed at 1"):
        SimODDrive(2)


async def test_signed_object_and_autotune_lock() -> None:
    sim = SimODDrive()
    async with sim_bus([sim], LINE) as (wire, bus):
        profile = ODDriveProfile(bus.slave(1))
        await profile.write_object(0x2018, 0, -5)
        assert requests(wire)[-1] == frame(1, hx("06 20 18 00 FF FB"))
        assert await profile.read_object(0x2018) == -5
        # Kp/Ki are read-only while current-loop auto-tune (2007h) is on: exception 05.
        with pytest.raises(ModbusException) as info:
            await profile.write_parameter("current_loop_kp", 400)
        assert info.value.code == 5
        assert "access violation" in info.value.text
        await profile.write_parameter("current_loop_autotune", 0)
        await profile.write_parameter("current_loop_kp", 400)
        assert await profile.read_parameter("current_loop_kp") == 400


async def test_save_survives_power_cycle_and_factory_reset() -> None:
    sim = SimODDrive()
    async with sim_bus([sim], LINE) as (_wire, bus):
        profile = ODDriveProfile(bus.slave(1))
        await profile.write_parameter("peak_current", 2000)
        await profile.write_parameter("speed_limit", 2500)  # R/W, no "S": not stored
        await profile.save_parameters()
        await profile.write_parameter("peak_current", 3000)  # not saved
        sim.power_loss()
        sim.power_restore()
        assert await profile.read_parameter("peak_current") == 2000
        assert await profile.read_parameter("speed_limit") == 1600
        await profile.restore_factory_settings()
        assert await profile.read_parameter("peak_current") == 1000


# -- status ------------------------------------------------------------------------------------


@pytest.mark.parametrize("position", [2**31 - 1, -(2**31), -1, -5, 0x12345678, 65535, 65536])
async def test_position_round_trips_high_word_first(position: int) -> None:
    sim = SimODDrive(setup=TwinSetup(position=position))
    async with sim_bus([sim], LINE) as (wire, bus):
        profile = ODDriveProfile(bus.slave(1))
        status = await profile.read_status()
        assert status.position == position
        u = position & 0xFFFFFFFF
        assert (status.raw["2010h"], status.raw["2011h"]) == (u >> 16, u & 0xFFFF)
        # One read of 2010h..2018h (position never torn), then 201Fh.
        assert requests(wire)[-2:] == [
            frame(1, read_pdu(0x2010, 0, 9)),
            frame(1, read_pdu(0x201F, 0, 1)),
        ]
        assert replies(wire)[-2][3:7] == u.to_bytes(4, "big")


async def _status_until(
    profile: ODDriveProfile, ok: Callable[[DriveStatus], bool]
) -> DriveStatus:
    with anyio.fail_after(5):
        while True:
            status = await profile.read_status()
            if ok(status):
                return status


async def test_speed_and_motion_from_the_fieldbus_master() -> None:
    sim = SimODDrive()
    async with sim_bus([sim], LINE) as (_wire, bus):
        profile = ODDriveProfile(bus.slave(1), pulses_per_rev=10000)
        await profile.setup()
        rest = await profile.read_status()
        assert (rest.moving, rest.in_position, rest.enabled, rest.velocity_rpm) == (
            False, True, True, 0.0
        )
        sim.external_run(600, 200)
        status = await _status_until(profile, lambda s: s.velocity_rpm == 600.0)
        # 600 r/min at 10000 pulses/rev = 100000 pulses/s; 2017h reads 600 (r/min).
        assert sim.velocity() == pytest.approx(100_000)
        assert status.raw["2017h"] == 600
        assert status.moving and not status.in_position
        sim.external_stop(200)
        status = await _status_until(profile, lambda s: not s.moving)
        assert status.in_position and status.velocity_rpm == 0.0
        assert status.position == sim.position()
        sim.external_move_to(-123_456, 1200, 500)
        status = await _status_until(profile, lambda s: s.in_position and s.position != 0
                                     and not s.moving)
        assert status.position == -123_456
        await profile.zero_position()
        assert (await profile.read_status()).position == 0
        assert sim.position() == 0


async def test_limit_and_home_inputs_follow_input_functions() -> None:
    setup = TwinSetup(position=2000, home_switch=500, limit_negative=-1000, limit_positive=1000)
    sim = SimODDrive(setup=setup)
    async with sim_bus([sim], LINE) as (_wire, bus):
        profile = ODDriveProfile(bus.slave(1))
        status = await profile.read_status()  # learns the input functions first
        # Defaults: DI2 origin (bit1), DI3 +limit (bit2), DI4 -limit (bit3).
        assert status.raw["2014h"] == 0b0110
        assert (status.limit_positive, status.limit_negative, status.raw["home_input"]) == (
            True, False, 1
        )
        sim.kin.hold(monotonic(), -2000)
        status = await profile.read_status()
        assert status.raw["2014h"] == 0b1000
        assert (status.limit_positive, status.limit_negative, status.raw["home_input"]) == (
            False, True, 0
        )
        # Make DI3 a negative limit too: the profile's map follows its own write.
        await profile.write_object(0x2022, 3, 4)
        sim.kin.hold(monotonic(), 2000)
        status = await profile.read_status()
        assert not status.limit_positive and not status.limit_negative
        assert await profile.read_input_functions() == [32, 1, 4, 4, 16]


async def test_alarm_latches_and_clears_only_by_201eh() -> None:
    sim = SimODDrive()
    async with sim_bus([sim], LINE) as (_wire, bus):
        profile = ODDriveProfile(bus.slave(1))
        sim.external_run(300, 100)
        sim.raise_alarm(30)
        status = await profile.read_status()
        assert status.alarm and status.alarm_code == 30
        assert status.alarm_text == "command overspeed"
        assert not status.enabled and not status.in_position and not status.moving
        with pytest.raises(RuntimeError):
            sim.external_run(300, 100)  # the motor will not move while the alarm is latched
        assert (await profile.read_status()).alarm  # still latched after reading
        await profile.clear_alarm()
        status = await profile.read_status()
        assert not status.alarm and status.alarm_code is None and status.enabled
        sim.raise_alarm(77)
        status = await profile.read_status()
        assert status.alarm_text == "stop reason 77"
        await profile.clear_alarm()
        assert await profile.read_fault_history() == [77, 30, 0, 0, 0, 0, 0, 0, 0]
        await profile.clear_fault_history()
        assert await profile.read_fault_history() == [0] * 9


# -- what the port cannot do -------------------------------------------------------------------


async def test_motion_procedures_are_not_supported() -> None:
    params = MoveParams(speed_rpm=100.0, accel_rps2=10.0, decel_rps2=10.0)
    async with sim_bus([SimODDrive()], LINE) as (wire, bus):
        profile = ODDriveProfile(bus.slave(1))
        calls: list[Awaitable[None]] = [
            profile.enable(),
            profile.disable(),
            profile.move_absolute(1000, params),
            profile.move_relative(-1000, params),
            profile.speed_run(100.0, 10.0, 10.0),
            profile.stop(),
            profile.emergency_stop(),
            profile.home(),
        ]
        for call in calls:
            with pytest.raises(NotSupported, match=r"the OD2000 drive cannot .*fieldbus"):
                await call
        assert ODDriveProfile.homing_methods == ()
        assert requests(wire) == []


# -- framing helpers ---------------------------------------------------------------------------


def test_frame_lengths() -> None:
    sim = SimODDrive()
    pdu = write_multiple_pdu(0x2000, 0, [1, 1])
    assert sim.request_length(pdu[:6]) is None
    assert sim.request_length(pdu[:7]) == len(pdu) == 11
    assert sim.request_length(read_pdu(0x2000, 0, 1)[:1]) == 6
    assert sim.request_length(write_pdu(0x2005, 0, 10000)) == 6
    assert reply_length(hx("03")) is None
    assert reply_length(hx("03 08")) == 10
    assert reply_length(hx("06")) == reply_length(hx("10")) == 6
    assert reply_length(hx("83")) == 2
    with pytest.raises(ConfigError):
        read_pdu(0x2000, 256, 1)
