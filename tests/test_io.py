"""Digital I/O by name: inputs read from the polled status (the twins toggling them),
outputs switched where the drive lets Modbus drive them, NotSupported naming the drive
otherwise; names from the machine file."""

from __future__ import annotations

from pathlib import Path

import anyio
import pytest

from drivebus import open_machine
from drivebus.config import load_config
from drivebus.errors import ArgumentError, ConfigError, InputTimeout, NotSupported

DEMO = Path(__file__).resolve().parents[1] / "configs" / "demo.toml"


def named_io(tmp_path: Path) -> Path:
    """The demo machine with names for some of x's and z's terminals."""
    text = DEMO.read_text().replace("sim://demo-rs485", "sim://io-rs485")
    text = text.replace("sim://demo-eth", "sim://io-eth")
    text = text.replace(
        'homing = { method = "home_switch_positive", speed = 40.0, creep = 10.0, '
        'accel = 1000.0 }',
        'homing = { method = "home_switch_positive", speed = 40.0, creep = 10.0, '
        'accel = 1000.0 }\nio = { part_present = "IN4", vacuum = "OUT1" }', 1)
    path = tmp_path / "io.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize(("name", "terminal", "toggle"), [
    ("x", "IN4", lambda t, on: t.set_input(4, on)),   # NT86: IN1-IN6
    ("y", "X3", lambda t, on: t.set_input(5, on)),    # BHSS: PU, DR, X0-X4
    ("z", "X4", lambda t, on: t.set_input(4, on)),    # CL86R: X0-X6
], ids=["NT86", "BHSS", "CL86R"])
async def test_wait_input_returns_when_the_twin_switches_the_input(
    name: str, terminal: str, toggle: object
) -> None:
    async with open_machine(DEMO) as m:
        ax, twin = m.axes[name], m.sim_drives[name]
        assert ax.inputs[terminal] is False
        switched: list[float] = []

        async def sensor() -> None:
            await anyio.sleep(0.3)
            toggle(twin, True)  # type: ignore[operator]
            switched.append(anyio.current_time())

        async with anyio.create_task_group() as tg:
            tg.start_soon(sensor)
            await ax.wait_input(terminal, True, timeout=5)
            assert switched, "returned before the input was switched"
        assert ax.inputs[terminal] is True
        toggle(twin, False)  # type: ignore[operator]
        await ax.wait_input(terminal.lower(), False, timeout=5)  # names are case-blind
        with pytest.raises(InputTimeout, match=f"input {terminal} was not on within 0.2 s"):
            await ax.wait_input(terminal, True, timeout=0.2)


async def test_an_output_is_switched_where_modbus_drives_it_and_refused_elsewhere() -> None:
    async with open_machine(DEMO) as m:
        x, z, y = m.axes["x"], m.axes["z"], m.axes["y"]
        with pytest.raises(NotSupported, match=r"NT86.*OUT1 is set to function 1 \(alarm\)"):
            await x.set_output("OUT1", True)
        assert x.outputs["OUT1"] is False
        # commissioning: OUT1 becomes a general-purpose output (function 0, register 66)
        await x.profile.slave.write_register(66, 0)
        points = {p.name: p for p in await x.io_points()}
        assert points["OUT1"].settable and not points["OUT2"].settable
        await x.set_output("OUT1", True)
        assert x.outputs["OUT1"] is True
        assert m.sim_drives["x"].read_register(3, anyio.current_time()) & 1
        await x.set_output("OUT1", False)
        assert x.outputs["OUT1"] is False
        with pytest.raises(NotSupported, match=r"CL86R.*Y0-Y2 follow drive functions"):
            await z.set_output("Y1", True)
        with pytest.raises(NotSupported, match=r"BHSS.*PT\) sequencer"):
            await y.set_output("Y0", True)
        with pytest.raises(NotSupported, match="OD2000 drive has no inputs"):
            await m.axes["aux"].wait_input("IN1")
        with pytest.raises(ArgumentError, match=r"no output 'OUT3'.*OUT1, OUT2"):
            await x.set_output("OUT3", True)


async def test_the_machine_file_names_terminals(tmp_path: Path) -> None:
    async with open_machine(named_io(tmp_path)) as m:
        x, twin = m.axes["x"], m.sim_drives["x"]
        assert x.inputs["part_present"] is False and x.outputs["vacuum"] is False
        twin.set_input(4, True)
        await x.wait_input("part_present", timeout=5)
        await x.profile.slave.write_register(66, 0)
        await x.set_output("vacuum", True)
        assert x.outputs["vacuum"] is True and x.outputs["OUT1"] is True
    bad = tmp_path / "bad.toml"
    bad.write_text(named_io(tmp_path).read_text().replace('"OUT1"', '"OUT7"'))
    with pytest.raises(ConfigError, match=r"axes\.x\.io\.vacuum: the NT86 drive has no "
                                          r"terminal 'OUT7'"):
        load_config(bad)
