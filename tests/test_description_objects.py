"""An object-addressed map (issue 32 item 5): a CiA 402 servo whose Modbus TCP register
list puts each object at its own index (6083h, 6084h and 6085h are three 32-bit objects at
consecutive addresses; 6099h holds sub-indices 1 and 2 behind one address), as the
MR-JE-C's manual lists them, reached with unit id 255 ("Set FFh").

The emulator is the independent Lexium 32 emulator of test_foreign_drives_more (its CiA
402 state machine, profile position, homing), seen through an object map: a request must
name one object's address and that object's width (6099h: sub-index 1, or both), anything
else is exception 02, as such a drive answers a request across two objects. Nothing of
``drivebus.sim`` is used."""

from __future__ import annotations

import textwrap
from pathlib import Path
from typing import Any

import anyio
import pytest

from drivebus import open_machine
from drivebus.drives.description import load_description
from drivebus.errors import ConfigError
from pymodbus_servers import PYMODBUS
from test_foreign_drives import serving
from test_foreign_drives_more import L_ACC as L_ACCEL
from test_foreign_drives_more import L_CONTROL as L_CW
from test_foreign_drives_more import L_DEC as L_DECEL
from test_foreign_drives_more import (
    L_ERROR,
    L_HM_HOME,
    L_HM_METHOD,
    L_HM_V,
    L_HM_V_OUT,
    L_OPMODE,
    L_OPMODE_ACT,
    L_P_ACT,
    L_PP_TARGET,
    L_PP_V,
    L_PV_TARGET,
    L_STATUS,
    L_V_ACT,
    Lexium32,
)

pytestmark = pytest.mark.skipif(PYMODBUS < (3, 13), reason="SimDevice actions: pymodbus 3.13+")

# object address -> (the emulator's parameters behind it, words each)
OBJECTS: dict[int, tuple[tuple[int, ...], int]] = {
    0x6040: ((L_CW,), 1), 0x6041: ((L_STATUS,), 1), 0x6060: ((L_OPMODE,), 1),
    0x6061: ((L_OPMODE_ACT,), 1), 0x603F: ((L_ERROR,), 1), 0x6064: ((L_P_ACT,), 2),
    0x606C: ((L_V_ACT,), 2), 0x607A: ((L_PP_TARGET,), 2), 0x607C: ((L_HM_HOME,), 2),
    0x6081: ((L_PP_V,), 2), 0x6083: ((L_ACCEL,), 2), 0x6084: ((L_DECEL,), 2),
    0x6098: ((L_HM_METHOD,), 1), 0x6099: ((L_HM_V, L_HM_V_OUT), 2), 0x60FF: ((L_PV_TARGET,), 2),
}
READ_ONLY = (0x6041, 0x6061, 0x603F, 0x6064, 0x606C)


class _Scratch(dict[int, int]):
    """Where the Lexium emulator copies its registers after each access (unused here)."""


class ObjectServo(Lexium32):
    """The Lexium 32 emulator behind an object-addressed map."""

    def __init__(self) -> None:
        super().__init__()
        self.requests: list[tuple[int, int, int]] = []
        """(function, address, count) of every request served."""
        self.refused: list[tuple[int, int, int]] = []

    def words_of(self, address: int) -> list[int]:
        params, width = OBJECTS[address]
        out: list[int] = []
        for p in params:
            out += [self.regs[p], self.regs[p + 1]] if width == 2 else [self.regs[p + 1]]
        return out

    async def action(self, function: int, start: int, address: int, count: int,
                     registers: list[int], values: Any) -> Any:
        from pymodbus.constants import ExcCodes

        self.requests.append((function, address, count))
        entry = OBJECTS.get(address)
        whole = None if entry is None else len(entry[0]) * entry[1]
        if whole is None or count not in {whole, entry[1]}:  # type: ignore[index]
            self.refused.append((function, address, count))
            return ExcCodes.ILLEGAL_ADDRESS  # a request across objects, or a part of one
        params, width = entry  # type: ignore[misc]
        if values is not None:
            if address in READ_ONLY:
                return ExcCodes.ILLEGAL_ADDRESS
            words = list(values)
            for i, p in enumerate(params[: count // width]):
                part = words[i * width:(i + 1) * width]
                pair = part if width == 2 else [0xFFFF if part[0] & 0x8000 else 0, part[0]]
                await super().action(function, p, p, 2, _Scratch(), pair)  # type: ignore[arg-type]
        else:  # bring the emulator up to date (its status, position, mode display)
            await super().action(3, L_STATUS, L_STATUS, 2, _Scratch(), None)  # type: ignore[arg-type]
        for i, w in enumerate(self.words_of(address)[:count]):
            registers[address - start + i] = w
        return None


MRJEC = """
[drive]
family = "OBJECT-SERVO"
engine = "cia402"

[link]
protocol = "tcp"
addresses = [255]              # "Unit Identifier: set FFh"
map = "objects"                # each object at its index, read and written by itself
functions = [3, 16]
word_order = "high_first"

[units.pulses_per_rev]
default = 16384

[registers.controlword]
address = 0x6040
object = "6040"
[registers.statusword]
address = 0x6041
object = "6041"
access = "R"
[registers.error_code]
address = 0x603F
object = "603F"
access = "R"
[registers.mode]
address = 0x6060
object = "6060"
signed = true
[registers.mode_display]
address = 0x6061
object = "6061"
signed = true
access = "R"
[registers.position]
address = 0x6064
object = "6064"
words = 2
signed = true
unit = "pulses"
access = "R"
[registers.velocity]
address = 0x606C
object = "606C"
words = 2
signed = true
unit = "rpm"
access = "R"
[registers.target]
address = 0x607A
object = "607A"
words = 2
signed = true
unit = "pulses"
[registers.home_offset]
address = 0x607C
object = "607C"
words = 2
signed = true
unit = "pulses"
[registers.profile_velocity]
address = 0x6081
object = "6081"
words = 2
unit = "rpm"
[registers.profile_acceleration]
address = 0x6083
object = "6083"
words = 2
unit = "rpm/s"
[registers.profile_deceleration]
address = 0x6084
object = "6084"
words = 2
unit = "rpm/s"
[registers.homing_method]
address = 0x6098
object = "6098"
signed = true
[registers.homing_speed_search]
address = 0x6099
object = "6099:01"
words = 2
unit = "rpm"
[registers.homing_speed_zero]
address = 0x6099
offset = 2                     # sub-index 2: the object's words 2-3, behind its address
object = "6099:02"
words = 2
unit = "rpm"
[registers.target_velocity]
address = 0x60FF
object = "60FF"
words = 2
signed = true
unit = "rpm"

[homing.methods]
negative_limit = { cia402 = 17 }
"""


def write(tmp_path: Path, text: str, name: str = "servo.toml") -> Path:
    p = tmp_path / name
    p.write_text(textwrap.dedent(text), encoding="utf-8")
    return p


def machine(line: dict[str, Any], drive: Path) -> dict[str, Any]:
    return {"name": "objects", "lines": {"bus": line}, "axes": {"a": {
        "line": "bus", "address": 255, "drive": str(drive), "pulses_per_rev": 16384,
        "units_per_rev": 10.0, "speed": 60.0, "accel": 600.0, "decel": 600.0,
        "limits": [-100.0, 200.0], "poll": {"moving": 0.01, "idle": 0.05},
        "homing": {"method": "negative_limit", "speed": 60.0, "creep": 10.0, "accel": 600.0},
    }}}


async def test_an_object_addressed_cia402_servo_is_driven_object_by_object(
        tmp_path: Path) -> None:
    from pymodbus.simulator import DataType, SimData, SimDevice

    servo = ObjectServo()
    drive = write(tmp_path, MRJEC)
    device = [SimDevice(255, simdata=[SimData(0x6000, values=[0] * 0x110,
                                              datatype=DataType.REGISTERS)],
                        action=servo.action)]
    with anyio.fail_after(60):
        async with serving(device, "tcp") as line, open_machine(machine(line, drive)) as m:
            a = m.axes["a"]
            await a.enable()
            assert servo.state == "operation_enabled"
            await a.move_to(20.0)
            assert servo.position == 32768 and a.position == 20.0
            # 60 units/s at 10 units/rev = 360 rpm, each object in its own request
            assert (servo.get(L_PP_V), servo.get(L_ACCEL), servo.get(L_DECEL)) == \
                (360, 3600, 3600)
            writes = [(addr, n) for fc, addr, n in servo.requests if fc == 16]
            assert {(0x6081, 2), (0x6083, 2), (0x6084, 2), (0x607A, 2)} <= set(writes)
            await a.home()
            assert a.homed and servo.homed and servo.position == 0
            # 6099h: sub-indices 1 and 2 in one request from the object's address
            assert (16, 0x6099, 4) in servo.requests
            assert (servo.get(L_HM_V), servo.get(L_HM_V_OUT)) == (360, 60)
            st = await a.refresh()
            assert st.position == 0 and not st.moving
    assert servo.refused == [], servo.refused  # never a request across objects
    reads = {(addr, n) for fc, addr, n in servo.requests if fc == 3}
    assert reads and all(n == OBJECTS[addr][1] * len(OBJECTS[addr][0]) or
                         n == OBJECTS[addr][1] for addr, n in reads), reads


def test_an_object_map_is_checked_by_objects_not_by_words(tmp_path: Path) -> None:
    d = load_description(write(tmp_path, MRJEC))
    assert d.objects["homing_speed_zero"].register.offset == 2
    # the same list as a flat word array: 6083h's second word is 6084h
    flat = MRJEC.replace('map = "objects"', 'map = "words"')
    with pytest.raises(ConfigError, match=r"address 24708 \(0x6084\) is also register "
                                          r"profile_acceleration"):
        load_description(write(tmp_path, flat.replace("offset = 2", ""), "flat.toml"))
    # two registers on one word of one object
    with pytest.raises(ConfigError, match=r"registers\.homing_speed_zero\.address: address "
                                          r"24729 \(0x6099, word 0 of the object\) is also "
                                          r"register homing_speed_search"):
        load_description(write(tmp_path, MRJEC.replace("offset = 2", "offset = 0"), "o.toml"))
    with pytest.raises(ConfigError, match=r"cia402\.blocks\[0\]: profile_acceleration "
                                          r"\(object 24707.* are not adjacent"):
        load_description(write(tmp_path, MRJEC + '\n[cia402]\nblocks = [["6083", "6084"]]\n',
                               "b.toml"))
