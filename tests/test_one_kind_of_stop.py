"""A drive whose description has one kind of stop only still stops, however it is asked
(``stop()``, ``halt_now()``, a cancelled move, leaving the machine), and one with none
refuses a stop before it touches the motion under way: found by an outside audit, where
``halt_now()`` on the guide's own one-stop drive aborted the move, sent nothing and left
the motor running. The twin decides: it is at rest, and the wire carries the stop.
"""

from __future__ import annotations

import contextlib
import subprocess
import sys
from pathlib import Path
from typing import Any

import anyio
import pytest

from drivebus import AxisState, open_machine
from drivebus.errors import DrivebusError, MotionAborted, NotSupported
from waits import until

ROOT = Path(__file__).resolve().parents[1]
LEADSHINE = ROOT / "configs" / "drives" / "leadshine_pr.toml"
TRIGGER = 0x6002
"""The Leadshine's trigger register (Pr8.02): 0x10 starts path 0, 0x40 stops."""


def without(tmp_path: Path, *procedures: str) -> Path:
    """The Leadshine PR description less ``procedures``, as a user's extension of it."""
    path = tmp_path / f"leadshine_without_{'_'.join(procedures)}.toml"
    path.write_text(f'extends = "{LEADSHINE}"\n\n[remove]\nprocedures = {list(procedures)!r}\n'
                    .replace("'", '"'))
    return path


def machine(drive: Path, tag: str) -> dict[str, Any]:
    """One Leadshine axis (10 mm a revolution) on a simulated line of its own."""
    return {"name": f"one-stop-{tag}",
            "lines": {"l": {"port": f"sim://one-stop-{tag}", "settings": "115200 8N1"}},
            "axes": {"a": {"line": "l", "address": 1, "drive": str(drive),
                           "pulses_per_rev": 10000, "units_per_rev": 10.0, "speed": 20.0,
                           "accel": 200.0, "decel": 200.0,
                           "poll": {"moving": 0.01, "idle": 0.05}}}}


async def moving(m: Any) -> None:
    """Until the twin of axis a moves (bounded)."""
    await until(m.sim_drives["a"].is_moving, "axis a's twin to move", seconds=5,
                every=0.005)


def stops_after(m: Any, since: int) -> list[int]:
    """The values written to the trigger register since wire-log entry ``since``."""
    return [int.from_bytes(f.data[4:6], "big") for f in list(m.wires["l"].log)[since:]
            if f.direction == "request" and f.data[1] == 0x06
            and int.from_bytes(f.data[2:4], "big") == TRIGGER]


async def move(a: Any, target: float, outcome: list[BaseException | None]) -> None:
    """``a.move_to(target)``, its outcome kept: None, or how it was aborted."""
    try:
        await a.move_to(target)
        outcome.append(None)
    except MotionAborted as exc:
        outcome.append(exc)


@pytest.mark.parametrize("missing", ["emergency_stop", "stop"])
async def test_one_kind_of_stop_serves_for_both(tmp_path: Path, missing: str) -> None:
    async with open_machine(machine(without(tmp_path, missing), missing)) as m:
        a, twin = m.axes["a"], m.sim_drives["a"]
        await a.enable()
        for how in ("stop", "halt_now", "cancel"):
            outcome: list[BaseException | None] = []

            async with anyio.create_task_group() as tg:
                tg.start_soon(move, a, 400.0 if twin.position() < 20 else 0.0, outcome)
                await moving(m)
                since = len(m.wires["l"].log)
                if how == "cancel":  # the move's own stop goes out, shielded
                    tg.cancel_scope.cancel()
                else:
                    await getattr(a, how)()  # returns once a later status shows rest
            assert not twin.is_moving(), f"{how}() without {missing} left the motor running"
            assert 0x40 in stops_after(m, since), (how, stops_after(m, since))
            if how != "cancel":
                assert isinstance(outcome[0], MotionAborted), (how, outcome)
                assert a.state is AxisState.STANDSTILL

    # leaving the machine with a move under way (in a task of the caller's) stops it too
    async def move_on(a: Any, target: float) -> None:
        with contextlib.suppress(DrivebusError):  # its line closes under it
            await a.move_to(target)

    async with anyio.create_task_group() as outer:
        async with open_machine(machine(without(tmp_path, missing), f"{missing}-exit")) as m:
            a, twin = m.axes["a"], m.sim_drives["a"]
            await a.enable()
            outer.start_soon(move_on, a, 400.0)
            await moving(m)
            since = len(m.wires["l"].log)
        assert not twin.is_moving(), f"leaving the machine without {missing} left it running"
        assert 0x40 in stops_after(m, since)


def test_drive_check_says_what_stands_in_for_a_missing_stop(tmp_path: Path) -> None:
    def check(drive: Path) -> str:
        done = subprocess.run([sys.executable, "-m", "drivebus.cli", "drive", "check",
                               str(drive)], capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stdout + done.stderr
        return done.stdout

    assert "no procedure emergency_stop: the axis sends its stop instead" in check(
        without(tmp_path, "emergency_stop"))
    assert "no procedure stop: the axis sends its emergency_stop instead" in check(
        without(tmp_path, "stop"))
    out = check(without(tmp_path, "stop", "emergency_stop"))
    assert "no stop at all" in out and "stop() and halt_now() are refused" in out, out


async def test_a_drive_with_no_stop_refuses_one_and_leaves_the_move_alone(
        tmp_path: Path) -> None:
    drive = without(tmp_path, "stop", "emergency_stop")
    async with open_machine(machine(drive, "none")) as m:
        a, twin = m.axes["a"], m.sim_drives["a"]
        await a.enable()
        async with anyio.create_task_group() as tg:
            tg.start_soon(a.move_to, 5.0)
            await moving(m)
            since = len(m.wires["l"].log)
            for stop in (a.stop, a.halt_now):
                with pytest.raises(NotSupported):
                    await stop()
            assert a.state is AxisState.DISCRETE_MOTION  # still watched, not aborted
            assert stops_after(m, since) == []
        # the move ran to its end and returned normally
        assert not twin.is_moving() and a.position == pytest.approx(5.0)
