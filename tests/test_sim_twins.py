"""What the simulated twins share: register specs, the base slave's dispatch and refusal
codes, each twin's vendor exception codes, and TwinSetup built from a machine config."""

from __future__ import annotations

import struct
from typing import ClassVar

import pytest

from drivebus.config import parse_config
from drivebus.drives.registers import Access
from drivebus.settings import LineSettings
from drivebus.sim.drive import SimDrive, TwinSetup
from drivebus.sim.drives.bhss import SimBHSS
from drivebus.sim.drives.cl86r import SimCL86R
from drivebus.sim.drives.nt_family import SimEPR60, SimNT86
from drivebus.sim.drives.od_drive import SimODDrive
from drivebus.sim.machine import make_twin
from drivebus.sim.registers import ExceptionCodes, RegisterSpec, SlaveException, signed16
from drivebus.sim.slave import SimSlave

CODES = ExceptionCodes(function=11, address=12, access=13, value=14, count=15, crc=16)


def test_register_spec_checks_access_and_the_signed_range() -> None:
    speed = RegisterSpec(60, -3000, 3000, signed=True)
    assert speed.check_write(0xFFFF - 99, CODES) == -100 == signed16(0xFF9C)
    with pytest.raises(SlaveException) as refused:
        speed.check_write(3001, CODES)
    assert refused.value.code == CODES.value
    with pytest.raises(SlaveException) as refused:
        RegisterSpec(access=Access.R).check_write(0, CODES)
    assert refused.value.code == CODES.access
    with pytest.raises(SlaveException) as refused:
        RegisterSpec(access=Access.W, command=True).check_read(CODES)
    assert refused.value.code == CODES.access
    RegisterSpec(command=True).check_read(CODES)  # a command register reads back 0


class _Bank(SimSlave):
    """Registers 10 (0..100) and 11 (read-only), answered with CODES."""

    register_map: ClassVar[dict[int, RegisterSpec]] = {
        10: RegisterSpec(5, 0, 100),
        11: RegisterSpec(7, access=Access.R),
    }
    exception_codes = CODES
    max_read = 2

    def __init__(self) -> None:
        super().__init__(1)
        self.words = {a: spec.default for a, spec in self.register_map.items()}
        self.advanced_to: list[float] = []

    def advance(self, now: float) -> None:
        self.advanced_to.append(now)

    def read_register(self, address: int, now: float) -> int:
        return self.words[address]

    def write_register(self, address: int, word: int, now: float) -> None:
        self.words[address] = word


def _exception(reply: bytes | None) -> int:
    assert reply is not None and reply[0] & 0x80, reply
    return reply[1]


def test_the_base_dispatch_answers_from_the_map_with_the_slaves_codes() -> None:
    bank = _Bank()
    assert bank.handle_pdu(struct.pack(">BHH", 3, 10, 2), 1.0) == bytes.fromhex("0304 0005 0007")
    assert bank.advanced_to == [1.0]
    assert bank.handle_pdu(struct.pack(">BHH", 6, 10, 42), 2.0) == struct.pack(">BHH", 6, 10, 42)
    assert bank.words[10] == 42
    assert _exception(bank.handle_pdu(struct.pack(">BHH", 3, 10, 3), 3.0)) == CODES.count
    assert _exception(bank.handle_pdu(struct.pack(">BHH", 3, 12, 1), 3.0)) == CODES.address
    assert _exception(bank.handle_pdu(struct.pack(">BHH", 6, 11, 1), 3.0)) == CODES.access
    assert _exception(bank.handle_pdu(struct.pack(">BHH", 6, 10, 101), 3.0)) == CODES.value
    assert _exception(bank.handle_pdu(bytes((0x2B, 0x0E, 1, 0)), 3.0)) == CODES.function
    bad_byte_count = struct.pack(">BHHB", 16, 10, 1, 4) + struct.pack(">H", 1)
    assert _exception(bank.handle_pdu(bad_byte_count, 3.0)) == CODES.value
    # A write is checked whole before anything is stored.
    write_both = struct.pack(">BHHB", 16, 10, 2, 4) + struct.pack(">HH", 1, 2)
    assert _exception(bank.handle_pdu(write_both, 4.0)) == CODES.access
    assert bank.words == {10: 42, 11: 7}
    assert bank.requests == 9


def test_a_bad_crc_is_answered_with_the_slaves_code_or_silence() -> None:
    bank = _Bank()
    assert bank.on_bad_crc(bytes((1, 3, 0, 10, 0, 1, 0, 0))) == bytes((0x83, 16))
    bank.crc_error_reply = False
    assert bank.on_bad_crc(bytes((1, 3, 0, 10, 0, 1, 0, 0))) is None
    assert bank.crc_errors == 2


def _read(address: int, count: int = 1, function: int = 3) -> bytes:
    return struct.pack(">BHH", function, address, count)


def _write(address: int, value: int) -> bytes:
    return struct.pack(">BHH", 6, address, value)


# Each twin's answers to the refusals its manual documents (and the twin's documented
# choices where the manual is silent): these must not change.
REFUSALS = [
    (SimNT86, _read(0, 1, function=4), 0x01),  # only FC03/06/16
    (SimNT86, _read(300), 0x02),  # unmapped
    (SimNT86, _write(0, 1), 0x02),  # read-only
    (SimNT86, _write(70, 5), 0x03),  # accel 10..1000
    (SimNT86, _read(0, 126), 0x03),  # count
    (SimNT86, struct.pack(">BHHB", 16, 73, 2, 4) + struct.pack(">HH", 0, 0x0200), 0x03),  # 32-bit
    (SimBHSS, _read(0, 1, function=4), 0x02),  # command error
    (SimBHSS, _read(0x0019), 0x03),  # unassigned inside the map
    (SimBHSS, _read(0x0200), 0x04),  # outside the map
    (SimBHSS, _read(0x0020, 17), 0x05),  # more than 16
    (SimBHSS, _read(0x0027), 0x06),  # the start command is write-only
    (SimBHSS, _write(0x0000, 1), 0x06),  # read-only
    (SimBHSS, _write(0x0021, 2001), 0x07),  # ramp 0..2000 ms
    (SimBHSS, _write(0x0027, 3), 0x07),  # no mode 3
    (SimCL86R, _read(0, 1, function=4), 0x01),
    (SimCL86R, _read(0x00E0), 0x02),
    (SimCL86R, _write(0x0003, 1), 0x02),  # a monitor register
    (SimCL86R, _write(0x0033, 3001), 0x03),
]


@pytest.mark.parametrize(("twin", "request_pdu", "code"), REFUSALS)
def test_each_twin_refuses_with_its_manuals_code(
    twin: type[SimDrive], request_pdu: bytes, code: int
) -> None:
    reply = twin(1).handle_pdu(request_pdu, 1.0)
    assert reply == bytes((request_pdu[0] | 0x80, code))


def test_the_od2000_twin_refuses_in_its_own_frames() -> None:
    od = SimODDrive()
    assert od.handle_pdu(struct.pack(">BHBH", 4, 0x2000, 0, 1), 1.0) == bytes((0x84, 0x02))
    assert od.handle_pdu(struct.pack(">BHBH", 3, 0x2000, 5, 1), 1.0) == bytes((0x83, 0x03))
    assert od.handle_pdu(struct.pack(">BHBH", 3, 0x2000, 0, 17), 1.0) == bytes((0x83, 0x04))
    assert od.handle_pdu(struct.pack(">BHBH", 6, 0x200A, 0, 1), 1.0) == bytes((0x86, 0x05))
    assert od.handle_pdu(struct.pack(">BHBH", 3, 0x2030, 0, 1), 1.0) == bytes((0x83, 0x05))
    assert od.handle_pdu(struct.pack(">BHBH", 6, 0x2003, 1, 5), 1.0) == bytes((0x86, 0x06))
    assert od.on_bad_crc(bytes((1, 3))) == bytes((0x83, 0x01))
    assert SimNT86(1).on_bad_crc(bytes((1, 3))) is None  # the NT family stays silent
    assert SimCL86R(1).on_bad_crc(bytes((1, 3))) == bytes((0x83, 0x04))


def test_make_twin_sets_the_twin_up_from_the_axis_sim_section_in_pulses() -> None:
    config = parse_config({
        "name": "twin-setup",
        "lines": {"bus": {"port": "sim://twin-setup", "settings": "115200 8N1"}},
        "axes": {"x": {
            "line": "bus", "address": 3, "drive": "NT86", "pulses_per_rev": 4000,
            "units_per_rev": 8.0,  # 500 pulses per unit
            "sim": {"position": 2.5, "home_switch": -1.0, "limit_negative": -10.0,
                    "limit_positive": 12.0, "turnaround": 0.004,
                    "options": {"home_cam": "negative"}},
        }},
    })
    twin = make_twin(config.axes["x"], config.lines["bus"])
    assert isinstance(twin, SimNT86) and twin.address == 3
    assert twin.settings == LineSettings.parse("115200 8N1")
    assert twin.position(0.0) == 1250 and twin.turnaround == 0.004
    assert (twin.home_switch, twin.limit_negative, twin.limit_positive) == (-500, -5000, 6000)
    assert twin.home_cam == "negative"


def test_every_family_takes_a_twin_setup() -> None:
    setup = TwinSetup(position=-40, home_switch=100.0, limit_positive=900.0, turnaround=0.002)
    for twin in (SimNT86(1, setup=setup), SimEPR60(2, setup=setup), SimBHSS(3, setup=setup),
                 SimCL86R(4, setup=setup), SimODDrive(setup=setup)):
        assert twin.position(0.0) == -40 and twin.turnaround == 0.002
        assert (twin.home_switch, twin.limit_negative, twin.limit_positive) == (100, None, 900)
