"""Taught positions: kept in the machine file (or one beside it), taught back atomically
with comments kept, moved to by name from the library and the command line."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
import tomllib
from pathlib import Path

import anyio
import pytest

from drivebus import open_machine, positions
from drivebus.config import load_config
from drivebus.errors import ArgumentError, ConfigError, MotionAborted, NotFound, StateError
from drivebus.motion import Axis
from wirelog import command_frames, log_size

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "configs" / "demo.toml"


def demo_copy(tmp_path: Path, tag: str, extra: str = "") -> Path:
    """The demo machine on its own simulator names, with ``extra`` appended."""
    text = DEMO.read_text().replace("sim://demo-rs485", f"sim://{tag}-rs485")
    text = text.replace("sim://demo-eth", f"sim://{tag}-eth")
    path = tmp_path / "machine.toml"
    path.write_text(text + extra)
    return path


POSITIONS = """
# Where the gripper picks and places (taught on the machine).
[positions.pick]   # above the tray
x = 120.0          # mm
y = 40.0

[positions.place]
x = 300.0
y = 80.0
z = 5.0
"""


async def test_a_machine_moves_to_a_taught_position_by_name(tmp_path: Path) -> None:
    async with open_machine(demo_copy(tmp_path, "posmove", POSITIONS)) as m:
        assert m.position("pick") == {"x": 120.0, "y": 40.0}
        report = await m.move_to("pick")
        assert report.duration > 0
        for axis, value in m.position("pick").items():
            assert m.sim_drives[axis].position() == m.axes[axis].units.to_pulses(value)
        handle = await m.move_to("place", buffer="buffered")
        await handle
        assert m.sim_drives["z"].position() == m.axes["z"].units.to_pulses(5.0)
        with pytest.raises(NotFound, match="pick, place"):
            await m.move_to("drop")


async def test_teach_writes_back_atomically_and_keeps_the_comments(tmp_path: Path) -> None:
    path = demo_copy(tmp_path, "posteach", POSITIONS)
    async with open_machine(path) as m:
        await m.group("x", "y").move_to({"x": 130.5, "y": 42.25})
        stored = await m.teach("pick")  # the axes it already has
        assert stored == {"x": 130.5, "y": 42.25}
        await m.axes["z"].move_to(7.5)
        assert await m.teach("pick", axes=["z"]) == {"x": 130.5, "y": 42.25, "z": 7.5}
        r = m.axes["r"].units.from_pulses(m.sim_drives["r"].position())
        assert await m.teach("home_spot", axes=["r"]) == {"r": r}
        text = path.read_text()
        assert "# Where the gripper picks and places (taught on the machine)." in text
        assert "# above the tray" in text and "# mm" in text
        assert "# The demo machine, entirely on the built-in simulator" in text
        data = tomllib.loads(text)
        assert data["positions"]["pick"] == {"x": 130.5, "y": 42.25, "z": 7.5}
        assert data["positions"]["place"] == {"x": 300.0, "y": 80.0, "z": 5.0}
        assert data["positions"]["home_spot"] == {"r": r}
        assert [p for p in os.listdir(tmp_path) if p.endswith(".tmp")] == []
        with pytest.raises(ArgumentError, match="position name"):
            await m.teach("no spaces")
        async with anyio.create_task_group() as tg:
            tg.start_soon(m.axes["x"].move_to, 300.0)
            async for st in m.axes["x"].watch():
                if st.moving:
                    break
            with pytest.raises(StateError, match="at rest"):
                await m.teach("pick", axes=["x"])
        assert tomllib.loads(path.read_text())["positions"]["pick"]["x"] == 130.5
    assert load_config(path).positions["pick"] == {"x": 130.5, "y": 42.25, "z": 7.5}


async def test_a_stop_reaches_the_wire_while_a_teach_waits_for_a_slow_disk(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """x moves while y is taught, and the position's file write hangs in its flush (a
    controller's flash that takes its time): a stop of x goes out meanwhile, and the teach
    ends with the file written once the disk lets go. Before, the write ran on the event
    loop: the stop waited for the disk."""
    path = demo_copy(tmp_path, "posdisk", POSITIONS)
    writing, let_go = threading.Event(), threading.Event()
    replace = positions._replace
    written: list[float] = []

    def slow(target: Path, text: str) -> None:
        writing.set()
        let_go.wait(10)  # (bounded: the loop it holds, before, must not hang the test)
        replace(target, text)
        written.append(time.monotonic())

    monkeypatch.setattr(positions, "_replace", slow)
    async with open_machine(path) as m:
        await m.axes["x"].enable()
        with anyio.fail_after(60):
            async with anyio.create_task_group() as tg:
                tg.start_soon(_stopped_move, m.axes["x"], 390.0)
                async for st in m.axes["x"].watch():
                    if st.moving:
                        break
                mark = log_size(m, "x")
                tg.start_soon(m.teach, "pick", ["y"])
                assert await anyio.to_thread.run_sync(writing.wait, 30), "no write began"
                await m.axes["x"].stop()
                stops = [at for kind, at in command_frames(m, "x", mark) if kind == "stop"]
                hanging = not written
                let_go.set()
        assert stops, "no stop of x on the wire"
        assert hanging, "the stop waited for the disk"
        assert not m.sim_drives["x"].is_moving() and written
    assert tomllib.loads(path.read_text())["positions"]["pick"]["y"] == \
        m.axes["y"].units.from_pulses(m.sim_drives["y"].position())


async def _stopped_move(axis: Axis, target: float) -> None:
    """A move that a stop is to end."""
    with pytest.raises(MotionAborted):
        await axis.move_to(target)


async def test_an_axis_that_cannot_move_is_not_taught(tmp_path: Path) -> None:
    """aux (an OD2000: monitoring only) can never be moved to a position: teaching it is
    refused naming the axis and why, before anything is read or written; with no axes
    named, a position that already has it is refused the same way."""
    path = demo_copy(tmp_path, "posaux", POSITIONS + "\n[positions.watch]\naux = 0.0\n")
    before = path.read_text()
    async with open_machine(path) as m:
        for name, axes in (("pick", ["x", "aux"]), ("watch", None)):
            with pytest.raises(ArgumentError, match=r"axis aux cannot be taught: .*OD2000"):
                await m.teach(name, axes)
        assert m.positions["pick"] == {"x": 120.0, "y": 40.0}
    assert path.read_text() == before


async def test_positions_kept_in_a_file_beside_the_machine_file(tmp_path: Path) -> None:
    path = demo_copy(tmp_path, "posfile")
    text = path.read_text().replace('name = "demo"\n',
                                    'name = "demo"\npositions_file = "taught.toml"\n')
    path.write_text(text)
    beside = tmp_path / "taught.toml"
    beside.write_text("# taught on the machine\n[positions.rest]\nx = 10.0\n")
    async with open_machine(path) as m:
        assert m.positions == {"rest": {"x": 10.0}}
        await m.teach("rest", axes=["x", "y"])
    assert path.read_text() == text  # the machine file is not touched
    assert beside.read_text().startswith("# taught on the machine\n")
    assert tomllib.loads(beside.read_text())["positions"]["rest"] == {"x": 12.0, "y": 7.0}


@pytest.mark.parametrize(("extra", "problem"), [
    ("\n[positions.pick]\nx = 1000.0\n", r"positions\.pick\.x: 1000 is outside the soft limits"),
    ("\n[positions.pick]\nq = 1.0\n", r"positions\.pick\.q: no axis 'q'"),
    ("\n[positions.pick]\n", r"positions\.pick: expected a table"),
])
def test_a_bad_position_in_the_machine_file_is_a_config_error(
    tmp_path: Path, extra: str, problem: str
) -> None:
    with pytest.raises(ConfigError, match=problem):
        load_config(demo_copy(tmp_path, "posbad", extra))


def _drivebus(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "drivebus.cli", *args], capture_output=True,
                          text=True, timeout=120, cwd=ROOT)


def test_teach_and_move_to_a_position_from_the_command_line(tmp_path: Path) -> None:
    path = demo_copy(tmp_path, "poscli", POSITIONS)
    taught = _drivebus("teach", str(path), "load", "x", "z", "--local")
    assert taught.returncode == 0, taught.stderr
    assert taught.stdout.startswith("taught load: x=12.000 z=-1.000")
    assert tomllib.loads(path.read_text())["positions"]["load"] == {"x": 12.0, "z": -1.0}
    listed = _drivebus("positions", str(path))
    assert listed.stdout.splitlines() == [
        "pick: x=120.000 y=40.000", "place: x=300.000 y=80.000 z=5.000",
        "load: x=12.000 z=-1.000"]
    moved = _drivebus("move", str(path), "place", "--local")
    assert moved.returncode == 0, moved.stderr
    assert moved.stdout.startswith("at place: x=300.000 y=80.000 z=5.000")
    missing = _drivebus("move", str(path), "drop", "--local")
    assert missing.returncode != 0 and "no position 'drop'" in missing.stderr
