"""The generic twin's behaviour the NT-family descriptions need (issue 22): input functions
with a polarity bit in their function entries and actions on their edges (``on_input``),
switches seen without a terminal (``direct``), an e-stop's deceleration changed while it
runs (``stopping``), bits computed from expressions (``twin``), the offset travelled past
the origin edge (``home_offset = "travel"``) and a TCP drive's default serial settings.
Each on the twin of a small description, driven register by register at given times."""

from __future__ import annotations

import tomllib

import pytest

from drivebus import LineSettings
from drivebus.drives.description import parse_description
from drivebus.errors import ConfigError
from drivebus.sim.described import DescribedDrive, described_twin
from drivebus.sim.drive import TwinSetup
from drivebus.sim.registers import SlaveException

TOML = """
[drive]
family = "INFN"

[link]
protocol = "{protocol}"
addresses = "1..31"

[link.refusals]
busy = 4

[units.pulses_per_rev]
default = 1000

[registers.status]
address = 0
access = "R"
bits.ENA = {{ bit = 0, means = "enabled" }}
bits.MOV = {{ bit = 1, means = "moving" }}
bits.POW = {{ bit = 2, twin = "True" }}
bits.RDY = {{ bit = 3, twin = "enabled and not alarm" }}
bits.TC = {{ bit = 4, twin = "stalled" }}

[registers.inputs]
address = 1
access = "R"
means = "inputs"

[registers.position]
address = 2
words = 2
signed = true
access = "R"
means = "position"

[registers.command]
address = 4
max = 9

[registers.speed]
address = 5
unit = "rpm"
max = 3000
default = 600

[registers.decel]
address = 6
unit = "r/s²"
min = 1
max = 1000
default = 10

[registers.in_setting]
address = 10
count = 3
first = 1
defaults = [4, 5, 12]
max = 0x3F

[registers.mode]
address = 13
max = 2

[registers.outputs]
address = 14
access = "R"
means = "outputs"

[registers.out_setting]
address = 15
count = 2
first = 1
defaults = [1, 0]
max = 0x1F

[registers.output_values]
address = 17
max = 3

[outputs]
state = "outputs"
functions = "out_setting"
function_mask = 0x0F
settable = 0
values = "output_values"
codes = {{ alarm = 1, enabled = 2 }}

[registers.home_offset]
address = 20
unit = "pulses"
max = 1000
default = 100

[inputs]
state = "inputs"
functions = "in_setting"
function_mask = 0x1F
polarity_bit = 0x20
names = ["IN1", "IN2", "IN3"]
first = 1
codes = {{ offline = 4, clear_fault = 5, start_homing = 12, limit_negative = 10 }}

[homing.methods.limit_negative]
code = 0
behaviour = "reference_edge"
reference = "limit_negative"
direction = -1

[homing.methods.electrical]
code = 1
behaviour = "move_to_offset"

[homing.methods.hard_stop_negative]
code = 2
behaviour = "hard_stop"
direction = -1

[twin]
stall_time = "0.05"
starts = "enabled and not alarm and not moving"
enabled = "not active.offline"
direct = ["limit_negative"]
home_offset = "travel"
options = ["mode"]

[[twin.on_write]]
register = "command"
when = "value == 1"
do = "run"
speed = "speed"
accel = "decel"
decel = "decel"
motion = "speed"
refuse = true

[[twin.on_write]]
register = "command"
when = "value == 5"
do = "emergency_stop"
decel = "decel"

[[twin.on_write]]
register = "command"
when = "value == 7"
do = "home"
method = "1"
speed = "speed"
accel = "1000"
offset = "home_offset"

[[twin.on_write]]
register = "command"
when = "value == 8"
do = "home"
method = "2"
creep = "60"
accel = "1000"
offset = "home_offset"

[[twin.on_write]]
register = "speed"
do = "set_speed"
speed = "speed"

[[twin.on_write]]
register = "decel"
when = "stopping == 'emergency_stop'"
do = "emergency_stop"
decel = "decel"

[[twin.on_input]]
input = "offline"
do = "disable"

[[twin.on_input]]
input = "offline"
edge = "fall"
do = "enable"

[[twin.on_input]]
input = "clear_fault"
do = "clear_alarm"

[[twin.on_input]]
input = "start_homing"
do = "home"
method = "0"
speed = "speed"
creep = "60"
accel = "1000"
offset = "home_offset"
"""


def twin_class(protocol: str = "rtu") -> type[DescribedDrive]:
    data = tomllib.loads(TOML.format(protocol=protocol))
    return described_twin(parse_description(data, "infn.toml"))


def status(twin: DescribedDrive, t: float) -> int:
    """The status register at ``t``, the twin brought up to ``t`` first (as a request)."""
    twin.advance(t)
    return twin.read_register(0, t)


def test_a_polarity_bit_is_an_edge_of_the_inputs_function() -> None:
    twin = twin_class()(1)
    assert status(twin, 0.0) == 0b1101  # enabled, powered, ready
    twin.write_register(10, 0x24, 0.1)  # IN1 'offline' inverted: active while open
    assert not twin.enabled and status(twin, 0.1) == 0b0100
    assert twin.read_register(1, 0.1) == 0  # the state shows the terminals as wired
    twin.set_input("IN1", True, 0.2)  # closed and inverted: inactive
    assert twin.enabled and twin.read_register(1, 0.2) == 0b001
    twin.raise_alarm(1, 0.3)
    assert not status(twin, 0.3) & 0b1000  # not ready in alarm
    twin.write_register(11, 0x05, 0.4)  # IN2 rewritten with its function: no edge
    assert twin.alarm_code == 1
    twin.write_register(11, 0x25, 0.5)  # its polarity flipped: 'clear fault' rises
    assert twin.alarm_code == 0 and status(twin, 0.5) == 0b1101
    twin.write_register(11, 0x3F, 0.6)  # another function: the mask leaves 0x1F
    twin.set_input(1, False, 0.7)  # IN1 counted from 1 ([inputs] first)
    assert not twin.enabled and twin.read_register(1, 0.7) == 0
    with pytest.raises(ConfigError, match=r"inputs IN1\.\.IN3"):
        twin.set_input(4, True)
    with pytest.raises(ConfigError, match=r"inputs IN1\.\.IN3"):
        twin.set_input(0, True)


def test_a_new_deceleration_applies_to_an_emergency_stop_under_way() -> None:
    twin = twin_class()(1)
    twin.write_register(4, 1, 0.0)  # run at 600 rpm, 10 r/s²: 10 000 pulses/s
    with pytest.raises(SlaveException) as err:
        twin.write_register(4, 1, 0.5)  # a start while it moves
    assert err.value.code == 4
    twin.write_register(5, 300, 2.0)  # a speed change applies at once
    assert twin.velocity(4.0) == pytest.approx(5000)
    twin.write_register(4, 5, 4.0)  # e-stop at 10 r/s²: 0.5 s
    assert twin.is_moving(4.2)
    twin.write_register(5, 600, 4.2)  # no restart while it stops
    twin.write_register(6, 1000, 4.2)  # faster: stopped at once
    assert not twin.is_moving(4.21)
    assert twin.velocity(4.3) == 0


def test_homing_on_a_direct_limit_travels_the_offset_to_position_zero() -> None:
    twin = twin_class()(1, setup=TwinSetup(position=0, limit_negative=-3000))
    assert twin.read_register(1, 0.0) == 0  # a direct switch is on no terminal
    twin.write_register(12, 0x2C, 0.0)  # IN3 'start homing' rises
    t = 0.1
    assert status(twin, t) & 0b10
    while status(twin, t) & 0b10:
        t += 0.05
        assert t < 30
    assert twin.homed and not twin.homing_failed
    assert twin.physical_position(t) == -3000 + 100 and twin.position(t) == 0


def test_a_tcp_drive_takes_115200_8n1_on_a_serial_sim_wire() -> None:
    assert twin_class("tcp")(1).settings == LineSettings.parse("115200 8N1")
    assert twin_class("tcp")(1, LineSettings.parse("9600 8E1")).settings.baudrate == 9600


def test_an_on_input_trigger_names_a_known_function() -> None:
    data = tomllib.loads(TOML.format(protocol="rtu").replace('input = "clear_fault"',
                                                            'input = "clear_faults"'))
    with pytest.raises(ConfigError, match=r"on_input\[2\]\.input: no input function "
                                          r"'clear_faults'"):
        parse_description(data, "infn.toml")


def test_addresses_twin_options_and_outputs_switched_over_modbus() -> None:
    cls = twin_class()
    with pytest.raises(ConfigError, match=r"INFN address 32: it has addresses 1\.\.31"):
        cls(32)
    assert "mode" in cls.twin_options()
    twin = cls(31, mode=2)
    assert twin.read_register(13, 0.0) == 2
    twin.write_register(13, 0, 0.0)
    twin.write_register(17, 0b11, 0.0)  # OUT2 has function 0: it follows bit 1
    assert twin.read_register(14, 0.0) == 0b10
    twin.raise_alarm(1, 0.1)  # OUT1 shows the alarm
    assert twin.read_register(14, 0.1) == 0b11
    twin.write_register(15, 0x12, 0.2)  # OUT1 'enabled' (bit 4 is its polarity: masked)
    assert twin.read_register(14, 0.2) == 0b11
    with pytest.raises(ConfigError, match=r"no option 'speed'.*mode"):
        cls(1, speed=3)


def test_homing_by_a_move_to_the_offset_stops_at_a_limit_switch() -> None:
    twin = twin_class()(1, setup=TwinSetup(position=500))
    twin.write_register(4, 7, 0.0)  # move to 100 at 600 rpm (10 000 pulses/s)
    assert status(twin, 0.01) & 0b10 and not twin.homed
    assert not status(twin, 1.0) & 0b10
    assert twin.homed and twin.position(1.0) == 100 == twin.physical_position(1.0)
    twin = twin_class()(1, setup=TwinSetup(position=500, limit_negative=300))
    twin.write_register(4, 7, 0.0)
    assert not status(twin, 1.0) & 0b10
    assert not twin.homed and twin.homing_failed
    assert 300 - 1 >= twin.physical_position(1.0) >= 300 - 10_000**2 / (2 * 1e6) - 1


def test_hard_stop_homing_stalls_on_the_end_stop_for_the_stall_time() -> None:
    cls = twin_class()
    assert {"hard_stop_negative", "hard_stop_positive"} <= set(cls.twin_options())
    twin = cls(1, hard_stop_negative=-700)
    twin.write_register(4, 8, 0.0)  # creep at 60 rpm (1000 pulses/s) into the stop at -700
    assert status(twin, 0.5) & 0b10 and not twin.stalled
    assert status(twin, 0.72) & 0b10000 and twin.physical_position(0.72) == -700  # TC
    assert not twin.homed and status(twin, 0.75) & 0b10000
    assert status(twin, 0.8) & 0b10010 == 0b10  # 0.05 s stalled: the origin; then
    assert not status(twin, 0.9) & 0b10  # 'travel': 100 pulses off it, that point is 0
    assert twin.homed and twin.position(0.9) == 0 and twin.physical_position(0.9) == -600
    twin = cls(1, setup=TwinSetup(limit_positive=50))
    twin.write_register(4, 8, 0.0)  # no end stop: it creeps on until stopped
    assert status(twin, 2.0) & 0b10 and not twin.homed
    twin.write_register(4, 5, 2.0)
    assert not status(twin, 3.0) & 0b10 and not twin.homed and not twin.homing_failed
    twin = cls(1, setup=TwinSetup(limit_negative=-300), hard_stop_negative=-700)
    twin.write_register(4, 8, 0.0)  # the limit switch before the end stop: it fails
    assert not status(twin, 2.0) & 0b10 and not twin.homed and twin.homing_failed
    assert -300 >= twin.physical_position(2.0) >= -301
