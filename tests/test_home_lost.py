"""`homed` means a homing completed: a drive whose position counter started again (a power
cycle, answered on or noticed only as a failed poll) leaves its axis not homed, on drives
whose description keeps the homed flag itself (CiA 402, MOONS') as on those that report
it; a seek home that a limit switch ended found nothing. And nothing passes a limit: a
simulated switch the drive has no input for (its twin would run through it) is refused.
Judged by the twins.
"""

from __future__ import annotations

import itertools
from dataclasses import replace
from pathlib import Path
from typing import Any

import anyio
import pytest

from drivebus import AxisState, open_machine
from drivebus.drives.status import DriveStatus
from drivebus.errors import ConfigError, LimitViolation
from drivebus.motion import Axis
from drivebus.motion.judge import drive_restarted, position_lost
from waits import until

DRIVES = Path(__file__).resolve().parents[1] / "configs" / "drives"
_names = itertools.count()

FAMILIES: dict[str, tuple[dict[str, Any], str, bool]] = {
    # name: (axis settings, a homing method on the home switch, on Modbus TCP)
    "NT86": ({"address": 2, "drive": "NT86", "settings": "115200 8N1",
              "pulses_per_rev": 4000}, "home_switch_positive", False),
    "Kinco FD (CiA 402)": ({"address": 6, "drive": str(DRIVES / "kinco_fd.toml"),
                            "pulses_per_rev": 10000}, "home_switch_positive_19", False),
    "Lexium 32": ({"address": 1, "drive": str(DRIVES / "lexium32.toml"),
                   "pulses_per_rev": 16384}, "negative_limit", True),
    "MOONS' STF": ({"address": 5, "drive": str(DRIVES / "moons_stf.toml"),
                    "pulses_per_rev": 20000}, "home_switch_positive", False),
    "Nanotec PD4-C (CiA 402, no homed flag)": (
        {"address": 1, "drive": str(Path(__file__).parent / "drives" / "nanotec_pd4c.toml"),
         "pulses_per_rev": 3600}, "home_switch_forward", False),
}


def machine(family: str, sim: dict[str, float]) -> dict[str, Any]:
    """One axis of ``family`` (10 mm/rev, soft limits ±15 mm, switches at ±20 mm)."""
    settings, method, tcp = FAMILIES[family]
    name = f"home-lost-{next(_names)}"
    line = ({"kind": "tcp", "host": f"sim://{name}"} if tcp else
            {"port": f"sim://{name}", "settings": "115200 8N1", "timeout": 0.1,
             "retries": 2})
    axis = {**settings, "line": "l", "units_per_rev": 10.0, "unit": "mm", "speed": 20.0,
            "accel": 200.0, "decel": 200.0, "limits": [-15.0, 15.0],
            "homing": {"method": method, "speed": 20.0, "creep": 5.0, "accel": 200.0},
            "sim": sim}
    return {"name": "home-lost", "lines": {"l": line}, "axes": {"x": axis}}


SWITCHES = {"position": -10.0, "home_switch": 5.0, "limit_negative": -20.0,
            "limit_positive": 20.0}


async def cycle_power(ax: Axis, twin: Any, how: str) -> None:
    """Switch the twin off and on: at once (between two polls), or for long enough that
    the axis goes Offline first."""
    if how == "answered at once":
        twin.power_cycle()
        return
    twin.power_loss()
    async for _ in ax.watch():
        if ax.state is AxisState.OFFLINE:
            break
    twin.power_restore()


@pytest.mark.parametrize("how", ["answered at once", "offline a while"])
@pytest.mark.parametrize("family", list(FAMILIES))
async def test_a_power_cycle_leaves_the_axis_not_homed(family: str, how: str) -> None:
    async with open_machine(machine(family, SWITCHES)) as m:
        ax, twin = m.axes["x"], m.sim_drives["x"]
        with anyio.fail_after(60):
            await ax.enable()
            await ax.home()
            assert ax.homed
            await ax.move_by(3.0)
            before = twin.position()
            assert before != 0
            await cycle_power(ax, twin, how)
            async for st in ax.watch():  # a status polled after the power came back
                if ax.state is not AxisState.OFFLINE and st.position == twin.position():
                    break
            assert twin.position() != before  # the twin's counter started again
            assert not ax.homed, (family, how, ax.state)
            await ax.reset()
            await ax.enable()
            await ax.home()  # and a homing makes it homed again
            assert ax.homed


@pytest.mark.parametrize("how", ["answered at once", "offline a while"])
@pytest.mark.parametrize("family", list(FAMILIES))
async def test_a_power_cycle_at_the_homed_position_leaves_the_axis_not_homed(
        family: str, how: str) -> None:
    """Homing set 0 and the axis rests there: a power cycle starts the counter at 0
    again, so it did not move. The CiA 402 engine (and any profile that alone records
    the homing) kept homed=True, and a move went to a position the drive no longer
    knew (an outside audit)."""
    async with open_machine(machine(family, SWITCHES)) as m:
        ax, twin = m.axes["x"], m.sim_drives["x"]
        with anyio.fail_after(60):
            await ax.enable()
            await ax.home()
            await ax.move_to(ax.units.from_pulses(0))
            assert ax.homed and twin.position() == 0
            await cycle_power(ax, twin, how)
            async for st in ax.watch():  # a status polled after the power came back
                if ax.state is not AxisState.OFFLINE and (
                        not st.enabled or not st.homed or not twin.enabled):
                    break
            async for _ in ax.watch():  # and the next: the change is judged
                break
            assert not ax.homed, (family, how, ax.state)


async def test_a_moons_seek_home_ended_by_a_limit_switch_homed_nothing() -> None:
    """No home switch: the seek runs onto the limit switch, which ends it (the drive's AL
    limit bit). It had been taken for homed once the drive's HOMING bit cleared."""
    sim = {k: v for k, v in SWITCHES.items() if k != "home_switch"}
    async with open_machine(machine("MOONS' STF", sim)) as m:
        ax, twin = m.axes["x"], m.sim_drives["x"]
        with anyio.fail_after(60):
            await ax.enable()
            with pytest.raises(LimitViolation, match="limit switch"):
                await ax.home()
        assert not ax.homed
        assert ax.state is AxisState.ERROR_STOP
        await until(lambda: not twin.is_moving(), "the twin at rest after the stop")
        assert twin.position() <= ax.units.to_pulses(21.0)  # at the switch, braked
        assert not ax.homed


@pytest.mark.parametrize("drive", ["iai_robo_cylinder.toml", "smc_lec6.toml"])
async def test_a_switch_the_drive_cannot_see_is_refused_on_its_twin(drive: str) -> None:
    """The IAI and SMC controllers see only their negative stroke end (where they home):
    a positive limit switch on their twin was accepted and run through (a move to 30 mm
    ended at rest 10 mm beyond it)."""
    axis = {"line": "l", "address": 1, "drive": str(DRIVES / drive), "pulses_per_rev": 10000,
            "units_per_rev": 10.0, "unit": "mm", "speed": 20.0, "accel": 200.0,
            "decel": 200.0, "sim": {"position": 18.0, "limit_positive": 20.0}}
    cfg = {"name": "unseen", "lines": {"l": {"port": f"sim://unseen-{next(_names)}",
                                            "settings": "115200 8N1"}}, "axes": {"x": axis}}
    with pytest.raises(ConfigError, match=r"sim\.limit_positive: .*no input for a positive "
                       r"limit switch"):
        async with open_machine(cfg):
            pass
    del axis["sim"]["limit_positive"]  # its negative stroke end is seen: accepted
    axis["sim"]["limit_negative"] = -20.0
    async with open_machine(cfg) as m:
        assert m.sim_drives["x"].limit_negative is not None


def _status(position: int, *, enabled: bool = True, moving: bool = False) -> DriveStatus:
    return DriveStatus(enabled=enabled, moving=moving, in_position=not moving, homed=True,
                       alarm=False, position=position)


@pytest.mark.parametrize(("before", "now", "offline", "by_command", "lost"), [
    (_status(12000), _status(0, enabled=False), False, False, True),  # power cycle
    (_status(12000), _status(0), True, False, True),  # not answering meanwhile
    (_status(12000), _status(12001, enabled=False), False, False, False),  # within 2
    (_status(12000), _status(11000, enabled=False), False, True, False),  # disable()
    (_status(12000), _status(12000, enabled=False), False, False, False),  # a fault
    (_status(12000), _status(0), False, False, False),  # enabled throughout
    (_status(12000, moving=True), _status(0, enabled=False), True, False, False),
])
def test_position_lost_is_decided_from_two_statuses(
        before: DriveStatus, now: DriveStatus, offline: bool, by_command: bool,
        lost: bool) -> None:
    assert position_lost(before, now, tolerance=2, back_from_offline=offline,
                         disabled_by_command=by_command) is lost


ENABLED, HOMED = frozenset({"enabled"}), frozenset({"homed"})


@pytest.mark.parametrize(("before", "now", "offline", "tracked", "restarted"), [
    (_status(12000), _status(12000), True, ENABLED, True),  # silent: it cannot say
    (_status(12000), _status(12000), True, frozenset(), False),  # it says it is enabled
    (_status(12000), _status(0), False, ENABLED, True),  # its counter moved at rest
    (_status(12000), _status(12001), False, ENABLED, False),  # within 2
    (_status(12000), _status(0, enabled=False), False, frozenset(), True),  # position lost
    (_status(12000, moving=True), _status(0), False, ENABLED, False),  # moving: no rest
    (_status(0), _status(0, enabled=False), False, HOMED, True),  # back at 0, disabled
    (_status(0), _status(0, enabled=False), False, frozenset(), False),  # its flag tells
    (_status(0), replace(_status(0, enabled=False), alarm=True), False, HOMED, False),
])
def test_a_restart_is_decided_from_two_statuses(
        before: DriveStatus, now: DriveStatus, offline: bool, tracked: frozenset[str],
        restarted: bool) -> None:
    """A drive whose enable the profile only tracks cannot say it dropped it: its silence
    or its counter moving at rest is taken for a restart. Where only the profile keeps
    the homed state, an enable dropped on its own with no alarm is one (a fault is not)."""
    assert drive_restarted(before, now, tolerance=2, back_from_offline=offline,
                           disabled_by_command=False, tracked=tracked) is restarted
