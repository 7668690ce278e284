"""Descriptions a user can trust on real hardware (issue 32): every value through its
scale whatever its unit, ranges in the user's units, conversions shown, writes that never
merge what the manual keeps apart, object-addressed maps, Modbus TCP unit ids, stops
that say what they can take; each on the real engine, its generic twin and the CLI."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path

import pytest

from drivebus import LineSettings, Priority
from drivebus.config import load_config
from drivebus.drives.description import Description, load_description
from drivebus.drives.engine import DescribedProfile, profile_class
from drivebus.errors import ConfigError
from drivebus.sim import VirtualWire, sim_bus
from drivebus.sim.described import DescribedDrive, described_twin

ROOT = Path(__file__).resolve().parents[1]
FAST = LineSettings.parse("115200 8N1")

SCALED = """
[drive]
family = "SCALED"

[units.pulses_per_rev]
default = 20000
register = "steps_per_rev"

[registers.status]
address = 0
access = "R"
bits.ENABLED = { bit = 0, means = "enabled" }
bits.MOVING = { bit = 1, means = "moving" }

[registers.steps_per_rev]     # the manual: "EG/2: steps per revolution / 2"
address = 52
unit = "steps/rev"
scale = 2
min = 100
max = 25600
default = 10000

[registers.current]
address = 60
unit = "A"
scale = 0.1
max = 80
default = 20

[registers.speed]
address = 29
unit = "rps"
scale = "1/240"
min = 1
max = 19200

[registers.accel]
address = 27
unit = "rps/s"
scale = "1/6"
min = 1
max = 30000

[registers.control]
address = 1

[procedures.setup]
steps = [{ write = { steps_per_rev = "pulses_per_rev", current = 1.5 } }]

[procedures.enable]
steps = [{ write = { control = 1 } }]
"""


def write(tmp_path: Path, text: str, name: str = "drive.toml") -> Path:
    p = tmp_path / name
    p.write_text(textwrap.dedent(text), encoding="utf-8")
    return p


def hexframes(wire: VirtualWire) -> list[str]:
    return [f.data.hex(" ").upper() for f in wire.requests()]


def cli(*args: str | Path, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    """Run ``drivebus ARGS`` as a user does."""
    return subprocess.run([sys.executable, "-m", "drivebus.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=timeout, check=False,
                          cwd=ROOT)


@asynccontextmanager
async def rig(d: Description, address: int = 1, **kwargs: object
              ) -> AsyncIterator[tuple[DescribedDrive, VirtualWire, DescribedProfile]]:
    twin = described_twin(d)(address, FAST)
    async with sim_bus([twin], FAST) as (wire, bus):
        yield twin, wire, profile_class(d)(bus.slave(address), **kwargs)  # type: ignore[arg-type]


# -- item 1: every value goes through its scale, whatever its unit's name -------------------


async def test_a_scale_applies_whatever_the_units_name(tmp_path: Path) -> None:
    d = load_description(write(tmp_path, SCALED))
    async with rig(d, pulses_per_rev=20000) as (twin, wire, profile):
        await profile.setup()
        # EG/2: 20 000 steps/rev is 10 000 (0x2710); 1.5 A in 0.1 A is 15 (0x000F)
        assert hexframes(wire)[:2] == ["01 06 00 34 27 10 D2 38", "01 06 00 3C 00 0F 09 C2"]
        assert twin.regs[52] == 10000 and twin.regs[60] == 15
        # the twin runs what the register says: 2 × 10 000 pulses a revolution
        assert twin.pulses_per_rev == 20000
        values = await profile._read_items(["steps_per_rev", "current"], None,
                                           Priority.CONFIG)
        assert values["steps_per_rev"] == 20000 and values["current"] == pytest.approx(1.5)


# -- item 2: ranges in the user's units, through the scale ----------------------------------


def test_pulses_per_rev_is_checked_through_its_registers_scale(tmp_path: Path) -> None:
    drive = write(tmp_path, SCALED, "scaled.toml")
    machine = """
        [lines.bus]
        port = "sim://scaled-ppr"
        [axes.a]
        line = "bus"
        address = 1
        drive = "scaled.toml"
        pulses_per_rev = PPR
    """
    ok = write(tmp_path, machine.replace("PPR", "51200"), "ok.toml")
    assert load_config(ok).axes["a"].pulses_per_rev == 51200
    for bad in ("150", "20001", "51202"):  # raw 75 (below 100), not a whole raw, raw 25601
        path = write(tmp_path, machine.replace("PPR", bad), f"bad{bad}.toml")
        with pytest.raises(ConfigError, match=r"axes\.a\.pulses_per_rev.*allowed: "
                                              r"200\.\.51200 in steps of 2"):
            load_config(path)
    done = cli("check", write(tmp_path, machine.replace("PPR", "150"), "cli.toml"))
    assert done.returncode == 2 and "200..51200 in steps of 2" in done.stderr, done.stderr
    done = cli("drive", "check", drive)
    assert done.returncode == 0, done.stderr
    assert "allowed 200..51200 in steps of 2" in done.stdout, done.stdout


# -- item 3: drive check shows every conversion on example values ---------------------------


def test_drive_check_shows_each_conversion_on_an_example_value(tmp_path: Path) -> None:
    done = cli("drive", "check", write(tmp_path, SCALED))
    assert done.returncode == 0, done.stderr
    out = done.stdout
    for line in ("steps_per_rev          20000 steps/rev → 52 (0x0034) = 10000   "
                 "(steps/rev × 2)",
                 "current                2 A → 60 (0x003C) = 20   (A × 0.1)",
                 "speed                  120 rpm (2 rev/s) → 29 (0x001D) = 480   (rps × 1/240)",
                 "accel                  100 rev/s² → 27 (0x001B) = 600   (rps/s × 1/6)"):
        assert line in out, (line, out)


# -- item 4: writes never merge what the manual keeps apart; exceptions name registers ------

FLAT402 = """
[drive]
family = "FLAT402"
engine = "cia402"

[units.pulses_per_rev]
default = 4000

[link]
word_order = "high_first"

[registers.controlword]
address = 0x100
object = "6040"
[registers.statusword]
address = 0x101
object = "6041"
access = "R"
[registers.mode]
address = 0x102
object = "6060"
signed = true
[registers.mode_display]
address = 0x103
object = "6061"
signed = true
access = "R"
[registers.position]
address = 0x104
object = "6064"
words = 2
signed = true
unit = "pulses"
access = "R"
[registers.velocity]
address = 0x106
object = "606C"
words = 2
signed = true
unit = "rpm"
access = "R"
[registers.target]
address = 0x108
object = "607A"
words = 2
signed = true
unit = "pulses"
[registers.profile_velocity]
address = 0x10A
object = "6081"
words = 2
unit = "rpm"
[registers.profile_acceleration]
address = 0x10C
object = "6083"
words = 2
unit = "rps/s"
[registers.profile_deceleration]
address = 0x10E
object = "6084"
words = 2
unit = "rps/s"
"""


def fc16_starts(wire: VirtualWire) -> list[tuple[int, int]]:
    """(first address, count) of every FC16 on the wire."""
    return [(int.from_bytes(f.data[2:4], "big"), int.from_bytes(f.data[4:6], "big"))
            for f in wire.requests() if f.data[1] == 0x10]


async def test_cia402_objects_are_written_one_by_one_unless_a_block_says_so(
        tmp_path: Path) -> None:
    from drivebus.drives.base import MoveParams

    apart = load_description(write(tmp_path, FLAT402, "apart.toml"))
    async with rig(apart) as (_, wire, profile):
        await profile.enable()
        await profile.move_absolute(4000, MoveParams(60, 10, 10))
        # 6081, 6083, 6084 and 607A side by side, yet each in its own request
        assert {(0x10A, 2), (0x10C, 2), (0x10E, 2), (0x108, 2)} <= set(fc16_starts(wire))
        assert not [s for s in fc16_starts(wire) if s[1] > 2]
    together = load_description(write(tmp_path, FLAT402 + """
[cia402]
blocks = [["6081", "6083", "profile_deceleration"]]
""", "together.toml"))
    async with rig(together) as (_, wire, profile):
        await profile.enable()
        await profile.move_absolute(4000, MoveParams(60, 10, 10))
        assert (0x10A, 6) in fc16_starts(wire) and (0x108, 2) in fc16_starts(wire)
    with pytest.raises(ConfigError, match=r"cia402\.blocks\[0\]: profile_velocity .* and "
                                          r"target .* are not adjacent"):
        load_description(write(tmp_path, FLAT402 + """
[cia402]
blocks = [["6081", "607A"], ["6083", "6084"]]
""", "gap.toml"))


async def test_a_modbus_exception_names_function_addresses_and_registers(
        tmp_path: Path) -> None:
    from drivebus.errors import ModbusException

    text = SCALED + """
[registers.gain]
address = 40
name = "position gain (P1-01)"
valid = "value < 1000"

[registers.filter]
address = 41
name = "position filter (P1-02)"

[procedures.tune]
params = ["gain", "filter"]
steps = [{ write = { gain = "gain", filter = "filter" }, block = true }]

[procedures.set_gain]
params = ["gain"]
steps = [{ write = { gain = "gain" } }]
"""
    d = load_description(write(tmp_path, text))
    async with rig(d) as (_, _, profile):
        with pytest.raises(ModbusException) as err:
            await profile.tune(1500, 3)
        exc = err.value
        assert (exc.function, exc.address, exc.count, exc.code) == (0x10, 40, 2, 3)
        assert ("answered function 0x10 at 40..41 (0x0028..0x0029): position gain (P1-01), "
                "position filter (P1-02) with exception 0x03") in str(exc), str(exc)
        with pytest.raises(ModbusException, match=r"function 0x06 at 40 \(0x0028\): "
                                                  r"position gain \(P1-01\) with exception"):
            await profile.set_gain(1500)


# -- item 6: a Modbus TCP unit id is 0..255, an RTU address 1..247; address lists ------------

TCP_FF = """
[drive]
family = "UNIT-FF"

[link]
protocol = "tcp"
addresses = [255]          # the manual: "Unit Identifier: set FFh"

[units.pulses_per_rev]
default = 1000

[registers.status]
address = 0
access = "R"
bits.ENABLED = { bit = 0, means = "enabled" }
bits.MOVING = { bit = 1, means = "moving" }

[registers.control]
address = 1

[procedures.enable]
steps = [{ write = { control = 1 } }]

[[twin.on_write]]
register = "control"
when = "value == 1"
do = "enable"
"""


def machine(tmp_path: Path, kind: str, address: int, name: str) -> Path:
    line = (f'kind = "tcp"\nhost = "sim://{name}"' if kind == "tcp" else
            f'port = "sim://{name}"\nsettings = "115200 8N1"')
    return write(tmp_path, f"""
[lines.l]
{line}
[axes.a]
line = "l"
address = {address}
drive = "unit_ff.toml"
""", f"{name}.toml")


async def test_a_modbus_tcp_unit_id_255_reaches_the_wire(tmp_path: Path) -> None:
    import anyio

    from drivebus import open_machine

    write(tmp_path, TCP_FF, "unit_ff.toml")
    cfg = load_config(machine(tmp_path, "tcp", 255, "unit-ff"))
    with anyio.fail_after(20):
        async with open_machine(cfg) as m:
            await m.axes["a"].enable()
            server = m.wires["l"]
            assert server.log and {r.unit for r in server.log} == {255}  # type: ignore[attr-defined]


def test_unit_ids_and_rtu_addresses_are_checked_naming_file_and_key(tmp_path: Path) -> None:
    write(tmp_path, TCP_FF, "unit_ff.toml")
    with pytest.raises(ConfigError, match=r"tcp-254\.toml: axes\.a\.address: the UNIT-FF "
                                          r"drive has addresses 255, not 254"):
        load_config(machine(tmp_path, "tcp", 254, "tcp-254"))
    rtu = write(tmp_path, TCP_FF.replace('protocol = "tcp"', 'protocol = "rtu"'), "rtu.toml")
    with pytest.raises(ConfigError, match=rf"{rtu}: link: .*addresses: 255 is outside "
                                          r"1\.\.247: an RTU address is 1\.\.247"):
        load_description(rtu)
    write(tmp_path, TCP_FF.replace('protocol = "tcp"\naddresses = [255]',
                                   'addresses = [1, 31]'), "unit_ff.toml")
    with pytest.raises(ConfigError, match=r"rtu-255\.toml: axes\.a\.address: 255 is outside "
                                          r"1\.\.247 \(an RTU address on serial line l"):
        load_config(machine(tmp_path, "serial", 255, "rtu-255"))
    # a list is the addresses themselves: [1, 31] is 1 and 31, not 1..31
    assert load_config(machine(tmp_path, "serial", 31, "rtu-31")).axes["a"].address == 31
    with pytest.raises(ConfigError, match=r"has addresses 1, 31, not 5"):
        load_config(machine(tmp_path, "serial", 5, "rtu-5"))


def test_drive_check_lists_the_line_kinds_the_description_allows(tmp_path: Path) -> None:
    done = cli("drive", "check", write(tmp_path, TCP_FF, "unit_ff.toml"))
    assert done.returncode == 0, done.stderr
    assert "Modbus TCP on lines tcp (Modbus TCP); unit ids 255;" in done.stdout, done.stdout
    done = cli("drive", "check", write(tmp_path, SCALED))
    assert ("Modbus RTU on lines serial (RS-485), rtu-over-tcp (RS-485 behind a transparent "
            "serial server), tcp (Modbus TCP through a Modbus TCP/RTU gateway); addresses "
            "1..247;") in done.stdout, done.stdout


# -- item 7: a stop says what it can take; drive try names the key to add -------------------

RELEASE = """
[drive]
family = "RELEASE"

[units.pulses_per_rev]
default = 1000

[registers.status]
address = 0
access = "R"
bits.ENABLED = { bit = 0, means = "enabled" }
bits.MOVING = { bit = 1, means = "moving" }

[registers.control]
address = 1
bits.RELEASE = 0

[registers.speed]
address = 2
unit = "rpm"
min = 1
max = 3000
signed = true

[registers.target]
address = 4
words = 2
signed = true
unit = "pulses"

[procedures.enable]
steps = [{ write = { control = 0 } }]

[procedures.move_absolute]
steps = [{ write = { target = "target", speed = { value = "speed", nonzero = true } } },
         { write = { control = 3 } }]

[procedures.speed_run]
steps = [{ write = { speed = "speed" } }, { write = { control = 1 } }]

[procedures.stop]
doc = "clearing the release bit: the drive ramps down on its own fixed ramp"
steps = [{ write = { control = 0 } }]

[[twin.on_write]]
register = "control"
when = "value == 3"
do = "move_absolute"
target = "target"
speed = "speed"
accel = 10
decel = 10

[[twin.on_write]]
register = "control"
when = "value & 1"
do = "run"
speed = "speed"
accel = 10
decel = 10

[[twin.on_write]]
register = "control"
when = "not value & 1"
do = "stop"
decel = 10
"""


async def test_a_stop_that_takes_no_deceleration_refuses_one_before_sending(
        tmp_path: Path) -> None:
    import anyio

    from drivebus import open_machine
    from drivebus.errors import NotSupported

    write(tmp_path, RELEASE, "release.toml")
    cfg = load_config(write(tmp_path, """
[lines.l]
port = "sim://release-stop"
settings = "115200 8N1"
[axes.a]
line = "l"
address = 1
drive = "release.toml"
pulses_per_rev = 1000
""", "m.toml"))
    with anyio.fail_after(20):
        async with open_machine(cfg) as m:
            a, wire = m.axes["a"], m.wires["l"]
            await a.enable()
            async with a.jogging(2.0):
                with pytest.raises(NotSupported, match=r"stop with a deceleration of .* its "
                                                       r"stop takes no deceleration"):
                    await a.stop(decel=5.0)
                writes = [f for f in wire.requests() if f.data[1] in (0x06, 0x10)]  # type: ignore[attr-defined]
                assert writes[-1].data[2:6] == bytes([0, 1, 0, 1])  # still the release: run
            await a.stop()
    d = load_description(write(tmp_path, RELEASE.replace(
        'doc = "clearing', 'takes = ["decel"]\ndoc = "clearing'), "claims.toml"))
    assert d.procedures["stop"].honours("decel")  # said so: taken (and passed to the steps)
    assert not load_description(tmp_path / "release.toml").procedures["stop"].honours("decel")


def test_drive_try_names_the_key_a_failing_step_needs(tmp_path: Path) -> None:
    moons = (ROOT / "configs" / "drives" / "moons_stf.toml").read_text(encoding="utf-8")
    lacking = moons.replace('bits.IN_POSITION = { bit = 3, means = "in_position" }',
                            'bits.IN_POSITION = { bit = 3 }')
    assert lacking != moons
    done = cli("drive", "try", write(tmp_path, lacking, "moons_lacking.toml"))
    assert done.returncode == 1
    line = next(x for x in done.stdout.splitlines() if x.strip().startswith("move absolute"))
    assert "FAIL" in line and 'add means = "in_position" (or "reached": a move ran to its ' \
        'end) (or twin = "...") to registers.status.bits.IN_POSITION' in line, line


# -- items 8 and 9: every item's source, the manual's example frames as self-tests ----------

EXAMPLES = SCALED.replace('[drive]\nfamily = "SCALED"\n', '''[drive]
family = "SCALED"
source = "manual: ACME-ST Modbus manual, chapter 4 (register list)"
''').replace('[registers.current]\n', '''[registers.current]
source = "inferred: the manual prints 'current' without a unit; 0.1 A from the dip-switch table"
''') + '''
[[examples]]
doc = "set the electronic gearing to 20000 steps/rev"
source = "manual: 4.3, p. 27"
request = "01 06 00 34 27 10 D2 38"
write = { steps_per_rev = 20000 }

[[examples]]
doc = "read the current: 1.5 A"
request = "01 03 00 3C 00 01 44 06"
reply = "01 03 02 00 0F F8 40"
read = ["current"]
values = { current = 1.5 }

[[examples]]
doc = "enable"
request = "01 06 00 01 00 01 19 CA"
procedure = "enable"

[[examples]]
doc = "EG = 0 as printed (CRC misprinted: C8 05)"
request = "01 06 00 34 00 00 C8 05"
erratum = "the printed CRC is C8 05; the frame's is C8 04"
write = { steps_per_rev = 0 }
'''


def test_drive_check_counts_sources_and_verifies_the_manuals_example_frames(
        tmp_path: Path) -> None:
    done = cli("drive", "check", write(tmp_path, EXAMPLES, "examples.toml"))
    assert done.returncode == 1, done.stderr  # an example fails: so does the check
    out = done.stdout
    # 6 registers, 2 bits, 2 procedures, [link] and [status]: all from the manual but the
    # inferred current
    assert "provenance of 12 registers, bits, procedures, homing methods and sections: " \
        "11 manual, 0 code, 1 inferred, 0 unnamed" in out, out
    assert "inferred (not from the manual or public code): registers.current" in out
    assert "examples: 3 of 4 of the manual's example frames verified" in out, out
    assert "ok   examples[0] (set the electronic gearing to 20000 steps/rev): 1 frame as " \
        "printed" in out
    assert "ok   examples[1] (read the current: 1.5 A): 1 frame as printed, 1 reply decoded" \
        in out
    assert "ok   examples[2] (enable): 1 frame as printed" in out
    # EG/2 = 0 is below the register's 100: the engine refuses what the manual printed
    assert "FAIL examples[3]" in out and "outside its range 100..25600" in out, out
    assert "failed:\n  - examples[3]" in out, out
    # without the failing example the check passes
    passing = EXAMPLES[:EXAMPLES.rindex("[[examples]]")]
    done = cli("drive", "check", write(tmp_path, passing, "passing.toml"))
    assert done.returncode == 0, done.stdout + done.stderr
    assert "examples: 3 of 3 of the manual's example frames verified" in done.stdout
    # a wrong scale is caught by the manual's own frame
    wrong = EXAMPLES.replace("scale = 2\n", "", 1)
    done = cli("drive", "check", write(tmp_path, wrong, "wrong.toml"))
    assert "FAIL examples[0] (set the electronic gearing to 20000 steps/rev): printed " \
        "01 06 00 34 27 10 D2 38, the engine sends 01 06 00 34 4E 20" in done.stdout, done.stdout
    misread = EXAMPLES.replace("values = { current = 1.5 }", "values = { current = 15 }")
    done = cli("drive", "check", write(tmp_path, misread, "misread.toml"))
    assert "FAIL examples[1] (read the current: 1.5 A): the reply decodes to current = 1.5, " \
        "printed 15" in done.stdout, done.stdout


def test_the_drive_page_names_each_registers_source_and_the_inferred_items(
        tmp_path: Path) -> None:
    done = cli("drive", "doc", write(tmp_path, EXAMPLES, "examples.toml"))
    assert done.returncode == 0, done.stderr
    page = done.stdout
    assert "**1 items are inferred** (neither the manual nor public code says them; check " \
        "them on the drive): `registers.current`." in page, page
    assert "source: inferred: the manual prints 'current' without a unit" in page
    assert "source: manual: ACME-ST Modbus manual, chapter 4 (register list) |" in page
    assert "## The manual's example frames" in page
    assert "| set the electronic gearing to 20000 steps/rev (manual: 4.3, p. 27) | " \
        "`01 06 00 34 27 10 D2 38` | - | write steps_per_rev = 20000 |" in page


SECTIONS = EXAMPLES.replace('[registers.status]\n', '''[identify]
read = ["steps_per_rev"]
match = "steps_per_rev > 0"
source = "inferred: any drive answering at 52 is taken for one"

[link]
baud_rates = [9600]
source = "manual: 2.1, p. 9 (communication settings)"

[status]
poll = ["status"]
moving = "status.MOVING"
source = "manual: 4.2 (status word)"

[alarms]
register = "current"
texts = { 1 = "over-current" }
source = "code: github.com/acme/st-driver alarms.py"

[registers.status]
''', 1)


def test_the_sections_name_their_sources_too(tmp_path: Path) -> None:
    """[identify], [link], [status] and [alarms] take ``source`` as items do: checked the
    same way, counted by ``drive check`` (an inferred one named), listed on the page."""
    d = load_description(write(tmp_path, SECTIONS, "sections.toml"))
    assert d.section_sources() == {
        "identify": "inferred: any drive answering at 52 is taken for one",
        "link": "manual: 2.1, p. 9 (communication settings)",
        "status": "manual: 4.2 (status word)",
        "alarms": "code: github.com/acme/st-driver alarms.py"}
    prov = d.provenance()
    assert "[identify]" in prov["inferred"] and "[link]" in prov["manual"]
    assert "[alarms]" in prov["code"] and "[status]" in prov["manual"]
    out = cli("drive", "check", tmp_path / "sections.toml").stdout
    assert "provenance of 14 registers, bits, procedures, homing methods and sections: " \
        "11 manual, 1 code, 2 inferred, 0 unnamed" in out, out
    assert "inferred (not from the manual or public code): registers.current, " \
        "[identify]" in out, out
    page = cli("drive", "doc", tmp_path / "sections.toml").stdout
    assert "`registers.current`, `[identify]`." in page, page
    assert "- `[link]`: manual: 2.1, p. 9 (communication settings)" in page, page
    assert "- `[alarms]`: code: github.com/acme/st-driver alarms.py" in page, page
    for section, source in d.section_sources().items():
        bad = SECTIONS.replace(f'source = "{source}"', 'source = "p. 12"')
        with pytest.raises(ConfigError, match=rf"{section}\.source: .*say where it comes "
                                              r"from, starting with manual"):
            load_description(write(tmp_path, bad, "bad.toml"))


# -- item 10: the shipped descriptions re-checked against their manuals ---------------------


async def test_the_stf_seeks_home_on_the_edge_its_sensor_type_gives() -> None:
    """920-0176: SH's condition is an edge of the input: a normally-open sensor reached
    closes it (F), a normally-closed one opens it (R); the wrong one runs past it."""
    d = load_description(ROOT / "configs" / "drives" / "moons_stf.toml")
    for options, edge in (({}, 0x46), ({"home_sensor": "normally_closed"}, 0x52)):
        async with rig(d, **options) as (_, wire, profile):
            await profile.enable()
            await profile.home(speed_rpm=60, creep_rpm=10, accel_rps2=10)
            params = [f.data for f in wire.requests() if f.data[1] == 0x10 and f.data[3] == 125]
            assert params and params[-1][7:11] == bytes([0, 0x33, 0, edge]), params


ROOT = Path(__file__).resolve().parent.parent
PACKAGED = sorted([*(ROOT / "src/drivebus/drives/descriptions").glob("*.toml"),
                   *(ROOT / "configs/drives").glob("*.toml")])


@pytest.mark.parametrize("path", PACKAGED, ids=lambda p: p.stem)
def test_no_packaged_stop_is_marked_never_to_be_sent_again(path: Path) -> None:
    # ``idempotent = false`` is for a start. A stop sent again after a lost reply can only
    # stop a motor the first one did not reach; one that is not leaves it running.
    d = load_description(path)
    for name in ("stop", "emergency_stop", "quick_stop", "halt"):
        proc = d.procedures.get(name)
        if proc is None:
            continue
        assert all(step.idempotent for step in proc.steps), (path.name, name)


def test_a_manual_source_that_says_part_is_inferred_is_named_apart(tmp_path: Path) -> None:
    """A source such as "manual: 3602h:03; the object in the low byte is inferred" counts
    as the manual's, but `drive check` and the drive's page name it apart, so a reader
    (or an auditor counting inferred items) sees it. Before: it was counted as the
    manual's and nowhere named, as a source that was the manual's throughout."""
    text = SECTIONS.replace('source = "manual: 2.1, p. 9 (communication settings)"',
                            'source = "manual: 2.1, p. 9; the word order is inferred"')
    path = write(tmp_path, text, "partly.toml")
    done = cli("drive", "check", path)
    assert done.returncode == 1, done.stderr  # (only its examples[3] fails, as above)
    assert "failed:\n  - examples[3]" in done.stdout
    assert "partly inferred (a manual or code source that says part is inferred): [link]" \
        in done.stdout, done.stdout
    page = cli("drive", "doc", path).stdout
    assert "**1 items are partly inferred** (their source says which part; check it on " \
        "the drive): `[link]`." in page, page
    assert "partly inferred" not in cli("drive", "check", write(tmp_path, SECTIONS,
                                                                "whole.toml")).stdout
