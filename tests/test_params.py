"""Parameter backup, compare and restore (``drivebus.app.params``) on the simulated twins.

What reached each drive is judged by the simulator's wire log (the frames the wire
carried) and the twins' own registers and EEPROM, never by the master's bookkeeping.
"""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from drivebus.app.params import (
    ParameterSet,
    diff_parameters,
    load_parameters,
    read_parameters,
)
from drivebus.bus import Bus
from drivebus.config import load_config
from drivebus.drives.base import DriveProfile
from drivebus.drives.registry import FAMILIES, family
from drivebus.errors import ConfigError, LimitViolation, NotSupported, PartialWrite
from drivebus.motion.lines import make_line
from drivebus.pdu import WRITE_MULTIPLE, WRITE_SINGLE
from drivebus.sim import Fault, VirtualWire
from drivebus.sim.machine import SimLine, start_simulators

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "configs" / "demo.toml"


@contextlib.asynccontextmanager
async def demo_drives() -> AsyncIterator[tuple[dict[str, DriveProfile], dict[str, SimLine]]]:
    """The demo machine's simulated lines and a bare profile per axis on them: no set-up,
    no actor, nothing written by anyone but the test."""
    cfg = load_config(DEMO)
    async with contextlib.AsyncExitStack() as stack:
        sims = await start_simulators(cfg, stack)
        buses = {n: await stack.enter_async_context(Bus(make_line(s.master_config()),
                                                        timeout=0.2, retries=1))
                 for n, s in sims.items()}
        profiles = {}
        for name, ax in cfg.axes.items():
            slave = buses[ax.line].slave(ax.address, settings=ax.settings)
            profiles[name] = family(ax.drive).profile(slave, pulses_per_rev=ax.pulses_per_rev,
                                                      **ax.drive_options)
        yield profiles, sims


def writes(wire: VirtualWire, address: int | None = None) -> list[bytes]:
    """The write requests (FC06/FC16) the wire carried (to ``address``)."""
    return [f.data for f in wire.log if f.direction == "request"
            and f.data[1] in (WRITE_SINGLE, WRITE_MULTIPLE)
            and (address is None or f.data[0] == address)]


def written_registers(frames: list[bytes]) -> list[tuple[int, int]]:
    """(register, first value) of each write request frame."""
    out = []
    for f in frames:
        reg = int.from_bytes(f[2:4], "big")
        value = int.from_bytes(f[4:6] if f[1] == WRITE_SINGLE else f[7:9], "big")
        out.append((reg, value))
    return out


def test_every_family_declares_documented_parameters() -> None:
    for fam in FAMILIES.values():
        params = fam.profile.parameters()
        assert params, fam.name
        keys = [p.key for p in params]
        assert len(keys) == len(set(keys)), fam.name
        for p in params:
            assert p.name and p.location
            assert p.register.lo <= p.register.hi
        if fam.name != "OD2000":  # objects by index and sub-index
            addresses = [p.register.address for p in params]
            assert addresses == sorted(addresses), f"{fam.name}: not in the manual's order"


async def test_dump_reads_every_family_and_writes_nothing() -> None:
    async with demo_drives() as (profiles, sims):
        wire = sims["rs485"].server
        assert isinstance(wire, VirtualWire)
        wire.clear_log()
        for name, profile in profiles.items():
            pset = await read_parameters(profile)
            assert list(pset.values) == [p.key for p in profile.parameters()], name
            twin = sims[profile_line(name)].twins[name]
            spot_check(name, pset, twin)
        assert writes(wire) == []  # a viewing operation: zero writes on the wire
        assert len([f for f in wire.log if f.direction == "request"]) > 20


def profile_line(axis: str) -> str:
    return "eth" if axis == "r" else "rs485"


def spot_check(axis: str, pset: ParameterSet, twin: object) -> None:
    """A few values against the twin's own registers (read from the twin, not the wire)."""
    v = pset.values
    if axis == "x":
        assert v["pulses_per_rev"] == twin.params[24] and v["move_speed"] == twin.params[72]
    elif axis == "y":
        assert v["microstep"] == twin.regs[0x0011] and v["homing_speed"] == twin.regs[0x0032]
    elif axis == "z":
        assert v["microstep"] == twin.regs[0x0023] and v["jog_speed"] == twin.regs[0x0046]


async def test_load_writes_only_what_differs_in_order_and_saves_once() -> None:
    async with demo_drives() as (profiles, sims):
        wire = sims["rs485"].server
        z, twin = profiles["z"], sims["rs485"].twins["z"]
        saved = await read_parameters(z)
        wanted = ParameterSet("CL86R", {**saved.values, "jog_speed": 120, "accel_time": 250,
                                        "di_filter": 5})
        assert [d.key for d in diff_parameters(saved, wanted)] == [
            "di_filter", "accel_time", "jog_speed"]  # the manual's order, not the file's
        twin.regs[0x0024] = 1  # auto-save on: the load must turn it off for its writes
        wire.clear_log()
        report = await load_parameters(z, wanted, save=True)
        assert report.written == ["di_filter", "accel_time", "jog_speed"] and report.saved
        regs = written_registers(writes(wire, 4))
        assert regs == [(0x0024, 0), (0x0011, 5), (0x0031, 250), (0x0046, 120),
                        (0x0037, 2), (0x0024, 1)]
        assert [r for r in regs if r[0] == 0x0037] == [(0x0037, 2)]  # one save, at the end
        assert (twin.eeprom[0x0011], twin.eeprom[0x0031], twin.eeprom[0x0046]) == (5, 250, 120)
        # loaded again: nothing differs, nothing is written
        wire.clear_log()
        again = await load_parameters(z, wanted)
        assert again.writes == [] and writes(wire) == []


async def test_a_value_out_of_range_writes_nothing() -> None:
    async with demo_drives() as (profiles, sims):
        wire = sims["rs485"].server
        x = profiles["x"]
        current = await read_parameters(x)
        bad = ParameterSet("NT86", {**current.values, "move_speed": 400, "jog_speed": 9999,
                                    "pulses_per_rev": 100})
        wire.clear_log()
        with pytest.raises(LimitViolation,
                           match=r"nothing written: pulses_per_rev: .*; jog_speed: "):
            await load_parameters(x, bad, save=True)
        assert writes(wire) == []
        assert sims["rs485"].twins["x"].params[72] == current.values["move_speed"]


async def test_an_interrupted_load_says_what_was_written() -> None:
    async with demo_drives() as (profiles, sims):
        wire = sims["rs485"].server
        x, twin = profiles["x"], sims["rs485"].twins["x"]
        current = await read_parameters(x)
        wanted = ParameterSet("NT86", {**current.values, "move_accel": 300, "move_decel": 310,
                                       "jog_speed": 700})

        def after(w: object) -> None:  # the drive goes silent after the first write
            twin.faults.inject(Fault.NO_REPLY, times=None)

        with pytest.raises(PartialWrite, match=r"stopped at move_decel.*written before it: "
                           r"move_accel; move_decel itself may or may not have been taken.*"
                           r"not written: jog_speed; nothing was saved") as info:
            await load_parameters(x, wanted, save=True, on_write=after)
        assert info.value.written == ["move_accel"]
        twin.faults.clear(Fault.NO_REPLY)
        # the twin took move_decel (only its reply was lost), never jog_speed, and no save
        assert (twin.params[70], twin.params[71]) == (300, 310)
        assert twin.params[77] == current.values["jog_speed"]
        assert 90 not in [r for r, _ in written_registers(writes(wire, 2))]


async def test_bhss_stores_by_write_through_and_comms_parameters_need_asking() -> None:
    async with demo_drives() as (profiles, sims):
        wire = sims["rs485"].server
        y, twin = profiles["y"], sims["rs485"].twins["y"]
        twin.regs[0x0016] = 1  # RAM only, as drivebus's set-up leaves it
        current = await read_parameters(y)
        wanted = ParameterSet("BHSS", {**current.values, "start_speed": 30,
                                       "data_format": 1})
        before = twin.eeprom_writes
        wire.clear_log()
        report = await load_parameters(y, wanted, save=True)
        assert report.written == ["start_speed"] and report.skipped == ["data_format"]
        assert written_registers(writes(wire, 3)) == [(0x0016, 0), (0x0020, 30), (0x0016, 1)]
        assert twin.eeprom[0x0020] == 30 and twin.regs[0x0015] == current.values["data_format"]
        assert twin.eeprom_writes - before <= 2  # the value, and the switch itself
        with_comms = await load_parameters(y, wanted, include_comms=True, dry_run=True)
        assert [w.parameter.key for w in with_comms.writes] == ["data_format"]


async def test_a_save_the_drive_cannot_do_is_refused_before_any_write() -> None:
    async with demo_drives() as (profiles, sims):
        wire = sims["rs485"].server
        aux = profiles["aux"]
        current = await read_parameters(aux)
        assert aux.save_problem() is None
        x = profiles["x"]
        x.save_problem = lambda: "no save here"  # type: ignore[method-assign]
        wanted = ParameterSet("NT86", {**(await read_parameters(x)).values, "jog_speed": 650})
        wire.clear_log()
        with pytest.raises(NotSupported, match="no save here"):
            await load_parameters(x, wanted, save=True)
        assert writes(wire) == [] and current.values


def test_parameter_files_round_trip_and_bad_ones_name_the_problem(tmp_path: Path) -> None:
    pset = ParameterSet("CL86R", {"microstep": 2000, "jog_speed": 60},
                        {"axis": "z", "machine": "/m.toml"})
    text = pset.to_toml()
    assert 'microstep = { value = 2000, unit = "pulses/rev", register = "35 (0x0023)"' in text
    back = ParameterSet.from_toml(text)
    assert back.values == {"microstep": 2000, "jog_speed": 60} and back.about["axis"] == "z"
    with pytest.raises(ConfigError, match="has no parameter warp_drive"):
        ParameterSet.from_toml(text.replace("jog_speed", "warp_drive"))
    with pytest.raises(ConfigError, match=r"parameters\.microstep: .*whole number"):
        ParameterSet.from_toml(text.replace("value = 2000", 'value = "2000"'))
    with pytest.raises(ConfigError, match=r"x\.toml: no \[drive\] table"):
        ParameterSet.from_toml("[parameters]\n", "x.toml")
    with pytest.raises(ConfigError, match="cannot compare a CL86R"):
        diff_parameters(pset, ParameterSet("NT86", {}))


# -- a drive given as a description file (the Arcus TITAN-SVX: at most a pair a read) -------


SVX = ROOT / "tests" / "drives" / "arcus_titan_svx.toml"


def svx_machine(tmp_path: Path) -> Path:
    config = tmp_path / "machine.toml"
    config.write_text(f"""
name = "svx-params"
[lines.l]
port = "sim://svx-params"
settings = "115200 8N1"
timeout = 0.1
[axes.a]
line = "l"
address = 1
drive = "{SVX}"
pulses_per_rev = 10000
""")
    return config


async def test_dump_reads_no_more_registers_at_once_than_the_drive_takes(
        tmp_path: Path) -> None:
    """HSPD, ACC and DEC side by side were read in one FC03 of 6 registers (at most 16,
    whatever the description's ``[link] max_read``); the TITAN reads a pair at a time
    and refuses it (its twin too: illegal data address)."""
    from drivebus.app.params import open_drive

    async with open_drive(load_config(svx_machine(tmp_path)), "a") as profile:
        assert (await read_parameters(profile)).values == {"hspd": 1000, "acc": 300,
                                                           "dec": 300}


async def test_dump_diff_and_load_of_a_drive_given_as_a_description_file(
        tmp_path: Path) -> None:
    """``drive = "drives/x.toml"`` (the guide's way to add a drive): its parameter file
    names the description file, so diff and load find the family again. Before: every
    ``params`` command failed with "unknown drive 'ARCUS-TITAN-SVX'" (the family was looked
    up by name)."""
    from drivebus.app.params import about_axis, open_drive

    cfg = load_config(svx_machine(tmp_path))
    async with open_drive(cfg, "a") as profile:
        dumped = await read_parameters(profile, about=about_axis(cfg, "a"))
        text = dumped.to_toml()
        assert f'description = "{SVX}"' in text
        path = tmp_path / "a.toml"
        path.write_text(text.replace("hspd = { value = 1000", "hspd = { value = 2000"))
        wanted = ParameterSet.load(path)
        assert wanted.description == str(SVX) and wanted.values["hspd"] == 2000
        assert [d.key for d in diff_parameters(wanted, dumped)] == ["hspd"]
        report = await load_parameters(profile, wanted)
        assert report.written == ["hspd"]
        assert (await read_parameters(profile)).values["hspd"] == 2000
        assert ParameterSet.from_mapping(profile.family, {"acc": 100},
                                         profile.description_file).values == {"acc": 100}
