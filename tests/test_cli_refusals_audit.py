"""What a black-box audit of the command line found, judged by the wire: a ``drivebus sim
--log`` in its own process logs every frame its line carries.

``record`` only listens: on its end it stops what its own steps moved, never an axis that
was moving when it began. A 0 for ``-b``/``-s``, a value ``-f`` cannot hold and a position
name that is not one are refused (exit status 2) before a port opens; a ``move-by`` step
beyond the soft limits is the argument error it is for ``move --by``.
"""

from __future__ import annotations

import re
import signal
import subprocess
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from test_cli import DEMO, Proc, drivebus, sim_server, spawn, status_json
from test_cli_wire import Frame, requests, sync
from wirelog import KINDS

Z_SYNC = (4, "38400 8N2")  # a read of z (the CL86R at address 4): the log's bookmark


def _demo(tmp_path: Path, name: str, z_speed: float = 40.0) -> tuple[Path, str]:
    """A copy of the demo machine on lines of its own (``sim://NAME-rs485``), z at
    ``z_speed`` mm/s; the copy and its RS-485 line's URL."""
    text = DEMO.read_text().replace("sim://demo-", f"sim://{name}-")
    text = re.sub(r"^speed = 40\.0$", f"speed = {z_speed}", text, count=1, flags=re.M)
    cfg = tmp_path / f"{name}.toml"
    cfg.write_text(text)
    return cfg, f"sim://{name}-rs485"


def _between(sim: Proc, first: Frame, last: Frame) -> list[Frame]:
    """The request frames logged after ``first`` and before ``last``."""
    seen = requests(sim)
    return seen[seen.index(first) + 1:seen.index(last)]


def _writes(frames: list[Frame]) -> list[str]:
    return [f"{f.address}: {f.data.hex(' ')}" for f in frames if f.write]


def _kind(frame: Frame, drive: str) -> str | None:
    """``start``/``stop`` for an FC06 command frame of ``drive``."""
    d = frame.data
    if len(d) < 6 or d[1] != 0x06:
        return None
    return KINDS[drive](int.from_bytes(d[2:4], "big"), int.from_bytes(d[4:6], "big"))


def _z_commands(sim: Proc, mark: Frame) -> list[str]:
    """z's start/stop commands logged after ``mark``."""
    seen = requests(sim)
    return [k for f in seen[seen.index(mark) + 1:] if f.address == 4
            and (k := _kind(f, "CL86R"))]


def _leave_x_moving(cfg: Path) -> None:
    """Set x (the NT86) moving at 2 mm/s, some 140 s from its target, and kill the process
    that did it: the drive runs on, moved by someone else as far as later commands know."""
    with spawn("move", cfg, "x", "300", "--speed", "2") as move:
        pattern = r"^x: position=(\S+) .*state=DiscreteMotion"
        first = move.expect(pattern).group(1)
        while move.expect(pattern).group(1) == first:
            pass  # the start is on the wire once a position polled after it has changed
        move.popen.kill()
        move.popen.wait(10)
    assert status_json(cfg)["x"]["moving"] is True


def _one_error(r: subprocess.CompletedProcess[str], *needles: str) -> str:
    """The one ``error:`` line of a refused command (exit status 2, no traceback)."""
    lines = [ln for ln in r.stderr.splitlines() if not ln.startswith("note: ")]
    assert r.returncode == 2, (r.returncode, r.stderr)
    assert len(lines) == 1 and lines[0].startswith("error: "), r.stderr
    for n in needles:
        assert n in lines[0], (n, lines[0])
    return lines[0]


@pytest.mark.parametrize(("name", "how"), [
    ("recsecs", ["-s", "1"]), ("recz", ["z", "-s", "1"]), ("recwait", ["-d", "wait 1"])])
def test_record_leaves_an_axis_someone_else_set_moving_alone(
    tmp_path: Path, name: str, how: list[str],
) -> None:
    """A recording with no motion step of its own sends not one write, and the axis that
    was moving when it began (moved by another process) is moving when it has ended."""
    cfg, line = _demo(tmp_path, name)
    out = tmp_path / "run.jsonl"
    with sim_server(cfg, "--log") as (sim, _):
        _leave_x_moving(cfg)
        before = status_json(cfg)["x"]
        mark = sync(sim, line, 2, "115200 8N1")
        done = drivebus("record", cfg, *how, "-o", out)
        last = sync(sim, line, 2, "115200 8N1")
        after = status_json(cfg)["x"]
        sent = _between(sim, mark, last)
        assert drivebus("stop", cfg, "x").returncode == 0
    assert done.returncode == 0, done.stderr
    assert "wrote" in done.stdout
    assert any(f.address == 2 for f in sent), "the recording did not poll x"
    assert _writes(sent) == []
    assert after["moving"] is True, after
    assert after["position"] > before["position"], (before, after)


def test_sigterm_stops_what_the_recording_moved_and_nothing_else(tmp_path: Path) -> None:
    """SIGTERM during a ``move z`` step (1 mm/s: a long move) stops z before the process
    ends (exit status 143), and x, moving before the recording began, is not stopped."""
    cfg, line = _demo(tmp_path, "recterm", z_speed=1.0)
    with sim_server(cfg, "--log") as (sim, _):
        _leave_x_moving(cfg)
        mark = sync(sim, line, *Z_SYNC)
        with spawn("record", cfg, "-d", "move z 90", "-o", tmp_path / "run.jsonl") as rec:
            deadline = time.monotonic() + 60
            while "start" not in _z_commands(sim, mark):
                assert time.monotonic() < deadline, "no start of z on the wire within 60 s"
                time.sleep(0.05)
            rec.popen.send_signal(signal.SIGTERM)
            code = rec.popen.wait(60)
            said = rec.rest()
        last = sync(sim, line, *Z_SYNC)
        sent = _between(sim, mark, last)
        after = status_json(cfg)
        assert drivebus("stop", cfg, "x").returncode == 0
    assert code == 143, said
    z = [k for f in sent if f.address == 4 and (k := _kind(f, "CL86R"))]
    assert "stop" in z[z.index("start"):], z  # z: stopped after its start
    assert [f for f in sent if f.write and f.address != 4] == []  # x: not one write
    assert after["z"]["moving"] is False and after["x"]["moving"] is True, after


def test_bad_line_settings_values_and_position_names_send_nothing(tmp_path: Path) -> None:
    """A 0 (or an empty --parity) is refused, not taken for the default; a value beyond
    what --format holds is an argument error naming it and the range; a position's name
    that is not one is refused before the machine opens: exit status 2, one line, and not
    one frame on the line."""
    cfg, line = _demo(tmp_path, "refaud")
    far = "http://127.0.0.1:9"  # no service: a value is checked before it is asked
    cases: list[tuple[list[str | Path], tuple[str, ...]]] = [
        (["write", line, "3", "0", "1", "-s", "0"], ("--stopbits", "0", "1..2")),
        (["write", line, "3", "0", "1", "-b", "0"], ("--baud", "0", "300")),
        (["write", line, "3", "0", "1", "-b", "0", "-s", "0"], ("--stopbits", "0")),
        (["write", line, "3", "0", "1", "-P", ""], ("--parity", "''")),
        (["read", line, "3", "0", "-b", "0"], ("--baud", "0")),
        (["read", line, "3", "0", "-s", "0"], ("--stopbits", "0")),
        (["write", line, "4", "0", "1e40", "-f", "float"],
         ("VALUE 1", "1e40", "float", "3.4028235e+38")),
        (["write", line, "4", "0", "1", "-3.5e38", "-f", "float"],
         ("VALUE 2", "-3.5e38", "float")),
        (["write", "--server", far, "rs485", "4", "0", "1e40", "-f", "float"],
         ("VALUE 1", "1e40", "float")),
        (["teach", cfg, "a b", "x"], ("POSITION", "'a b'", "a letter or _")),
        (["teach", cfg, "", "x"], ("POSITION", "''")),
        (["teach", cfg, "p.q", "x"], ("POSITION", "'p.q'")),
        (["teach", cfg, "x"], ("POSITION", "'x'", "an axis's name")),
    ]
    with sim_server(cfg, "--log") as (sim, _):
        mark = sync(sim, line, *Z_SYNC)
        with ThreadPoolExecutor(2) as pool:
            results = list(pool.map(lambda c: drivebus(*c[0]), cases))
        last = sync(sim, line, *Z_SYNC)
        sent = _between(sim, mark, last)
    assert [f"{f.address}: {f.data.hex(' ')}" for f in sent] == []
    for (args, needles), r in zip(cases, results, strict=True):
        _one_error(r, *needles)
        assert "internal error" not in r.stderr, args
    assert "[positions" not in cfg.read_text()  # nothing taught


def test_a_move_by_step_beyond_the_soft_limits_is_refused_as_move_by_is(
    tmp_path: Path,
) -> None:
    """``record -d "move-by x 1000"`` exits 2 naming the soft limits, as ``move x 1000
    --by``; after a ``move x 10`` step too (10 + 1000: refused before that move starts).
    Not one write on the line, no file written."""
    cfg, line = _demo(tmp_path, "recby")
    out = tmp_path / "run.jsonl"
    with sim_server(cfg, "--log") as (sim, _):
        mark = sync(sim, line, *Z_SYNC)
        move = drivebus("move", cfg, "x", "1000", "--by")
        alone = drivebus("record", cfg, "-d", "move-by x 1000", "-o", out)
        after = drivebus("record", cfg, "-d", "move x 10", "-d", "move-by x 1000", "-o", out)
        last = sync(sim, line, *Z_SYNC)
        sent = _between(sim, mark, last)
    _one_error(move, "TARGET", "soft limits")
    _one_error(alone, "--during move-by x", "target 1012 is outside the soft limits")
    _one_error(after, "--during move-by x", "target 1010 is outside the soft limits")
    assert _writes(sent) == []
    assert not out.exists()


def test_a_machine_files_speed_its_drive_cannot_run_is_the_files_error(tmp_path: Path) -> None:
    """An axis whose machine-file accel its drive cannot run: ``check`` names the axis and
    exits 1, and a ``move`` without ``--speed`` is refused (exit status 2, nothing opened)
    naming the machine file's axis, not a ``--speed`` that was never given (an outside
    audit)."""
    cfg, _ = _demo(tmp_path, "fileaccel")
    cfg.write_text(re.sub(r"^accel = 400\.0$", "accel = 1e12", cfg.read_text(), count=1,
                          flags=re.M))
    r = drivebus("check", cfg)
    assert r.returncode == 1, (r.returncode, r.stderr)
    assert "axis z: its speed, accel and decel" in r.stderr and "acceleration" in r.stderr
    line = _one_error(drivebus("move", cfg, "z", "10"), "axes.z: its speed, accel and decel",
                      "acceleration time")
    assert "--speed" not in line
