"""What a description says a drive does is what the axis does (issue 31, items 6 and 7).

* A jog's new speed goes to the drive on the fly only where its description says the drive
  takes it (``[programs] jog_speed``); elsewhere the axis stops the jog, decelerating, and
  starts it again. The MOONS' STF's jog (CJ) takes JS when it starts: "a new speed stops the
  jog first" (its description, from the Host Command Reference), and its twin plays a CJ
  sent while the motor turns as not obeyed. Judged on the wire log and on the twin.
* The Kinco FD's statusword bit 15 says the drive has found its home ("bit15=1 indicates
  home is found", FD5P manual ch. 10, table 10-1): a machine opened on a homed drive shows
  it homed, on the twin and on the independent emulator of tests/test_foreign_drives.py.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import anyio
import pytest

from drivebus import AxisState, open_machine
from drivebus.drives.description import load_description
from drivebus.drives.engine import profile_class
from drivebus.settings import LineSettings
from drivebus.sim import sim_bus
from drivebus.sim.described import described_twin
from drivebus.sim.drive import TwinSetup
from pymodbus_servers import PYMODBUS
from test_no_stale_motion import TWINS, twin_machine, until, written

ROOT = Path(__file__).resolve().parents[1]
DRIVES = ROOT / "configs" / "drives"
FAST = LineSettings.parse("115200 8N1")

STF_COMMAND = 124  # the opcode register 40125
CJ, SKD = 0x96, 0xE2  # commence jog; stop (kill the buffer) with the deceleration DE


def values_written(wire: Any, address: int) -> list[int]:
    """The values written to one register (FC06, or the first of an FC16) on a simulated
    RTU wire, in wire order."""
    out = []
    for f in wire.requests():
        pdu = f.data[1:-2]
        if pdu[:1] == b"\x06" and int.from_bytes(pdu[1:3], "big") == address:
            out.append(int.from_bytes(pdu[3:5], "big"))
        elif pdu[:1] == b"\x10" and int.from_bytes(pdu[1:3], "big") == address:
            out.append(int.from_bytes(pdu[6:8], "big"))
    return out


async def test_a_jog_speed_change_stops_and_restarts_where_the_drive_takes_none() -> None:
    """MOONS' STF (no ``jog_speed``): jog(+5), then jog(+8): CJ, a decelerating stop (SKD),
    CJ, never a second CJ while the motor turns; the twin ends at the new speed."""
    spec = next(t for t in TWINS if t[0] == "stf")
    with anyio.fail_after(30):
        async with open_machine(twin_machine(*spec[:5], tag="jog-speed")) as m:
            a, twin = m.axes["a"], m.sim_drives["a"]
            wire: Any = m.wires["l"]
            assert not a.profile.programs.jog_speed
            await a.enable()
            wire.clear_log()
            await a.jog(5.0, watchdog=None)
            await until(lambda: twin.speed_rpm() == pytest.approx(30.0),
                        "the twin to run at 5 units/s (30 rpm)")
            await a.jog(8.0, watchdog=None)
            assert values_written(wire, STF_COMMAND) == [CJ, SKD, CJ]
            await until(lambda: twin.speed_rpm() == pytest.approx(48.0),
                        "the twin to run at 8 units/s (48 rpm)")
            assert a.state is AxisState.CONTINUOUS_MOTION
            await a.stop()
            assert values_written(wire, STF_COMMAND)[-1] == SKD and not twin.is_moving()


async def test_a_jog_speed_change_goes_on_the_fly_where_the_description_says_so() -> None:
    """Kinco FD (``jog_speed``: profile velocity takes a new target velocity at once): the
    second jog writes 60FFh and no halt comes between."""
    spec = next(t for t in TWINS if t[0] == "kinco")
    with anyio.fail_after(30):
        async with open_machine(twin_machine(*spec[:5], tag="jog-speed")) as m:
            a, twin = m.axes["a"], m.sim_drives["a"]
            wire: Any = m.wires["l"]
            assert a.profile.programs.jog_speed
            await a.enable()
            await a.jog(5.0, watchdog=None)
            await until(lambda: twin.speed_rpm() == pytest.approx(30.0), "the jog at 30 rpm")
            wire.clear_log()
            await a.jog(8.0, watchdog=None)
            objects = twin.description.objects
            assert not [w for w in values_written(
                wire, objects["controlword"].register.address) if w & 0x100]  # no halt
            assert any(objects["target_velocity"].register.address in w
                       for w in written(wire))
            await until(lambda: twin.speed_rpm() == pytest.approx(48.0), "the jog at 48 rpm")
            await a.stop()


# -- item 7: the Kinco FD's "home found" bit -------------------------------------------------

KINCO = DRIVES / "kinco_fd.toml"


async def test_a_kinco_twin_homed_before_the_session_shows_homed() -> None:
    """Home the twin with one profile (a session), then read it with a new one (the next
    session, nothing remembered): statusword bit 15 says homed."""
    desc = load_description(KINCO)
    twin = described_twin(desc)(1, FAST, TwinSetup(limit_negative=-3000, position=0))
    async with sim_bus([twin], FAST) as (_, bus):
        first = profile_class(desc)(bus.slave(1))
        assert not (await first.read_status()).homed
        await first.enable()
        await first.home("negative_limit", speed_rpm=60, creep_rpm=30, accel_rps2=50)
        with anyio.fail_after(10):
            while twin.is_moving() or not twin.homed:  # noqa: ASYNC110 - the twin decides
                await anyio.sleep(0.005)
        st = await profile_class(desc)(bus.slave(1)).read_status()
        assert st.homed and st.raw["statusword"] & 0x8000


@pytest.mark.skipif(PYMODBUS < (3, 13), reason="SimDevice actions: pymodbus 3.13+")
async def test_a_machine_opened_on_a_homed_kinco_emulator_shows_homed() -> None:
    from test_foreign_drives import K_READ_ONLY, Kinco, machine, served

    drive = Kinco()
    with anyio.fail_after(60):
        async with served(drive, K_READ_ONLY) as line, open_machine(machine(line, KINCO)) as m:
            a = m.axes["a"]
            assert not (await a.refresh()).homed
            await a.enable()
            await a.home()
            assert drive.homing_done and a.homed
        async with served(drive, K_READ_ONLY) as line, open_machine(machine(line, KINCO)) as m:
            assert (await m.axes["a"].refresh()).homed and m.axes["a"].homed
