"""The ``drivebus`` command line, run as a user runs it: in subprocesses, against the
built-in simulator (``sim://`` configs) and against ``drivebus sim`` serving a pty.

Subprocesses are synchronised on what they print (their output is read line by line
with deadlines), never on fixed sleeps.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import pty
import queue
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
import serial
from typer.testing import CliRunner

from drivebus.app.scan import scan_settings
from drivebus.cli.bustools import scan_line
from drivebus.cli.failures import fail
from drivebus.cli.machine import check_config
from drivebus.cli.root import app
from drivebus.cli.terminal import Out, explain
from drivebus.config import load_config
from drivebus.errors import ConfigError, DriveOffline, LineClosed
from drivebus.line.rtu import frame
from drivebus.settings import LineSettings
from drivebus.sim.machine import start_simulators

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "configs" / "demo.toml"
SINGLE = ROOT / "configs" / "single.toml"
CLI = [sys.executable, "-m", "drivebus.cli"]


def drivebus(*args: str | Path, timeout: float = 30) -> subprocess.CompletedProcess[str]:
    """Run ``drivebus ARGS`` to completion (stdout is a pipe: plain output)."""
    return subprocess.run(
        [*CLI, *map(str, args)], capture_output=True, text=True, timeout=timeout, check=False
    )


@dataclass
class Proc:
    """A running ``drivebus`` subprocess whose stdout is read line by line."""

    popen: subprocess.Popen[str]
    lines: queue.Queue[str] = field(default_factory=queue.Queue)
    seen: list[str] = field(default_factory=list)

    def expect(self, pattern: str, timeout: float = 60) -> re.Match[str]:
        """The first new stdout line matching ``pattern``; fails after ``timeout`` s (a hang
        guard: a command starts in about 1.5 s of CPU, several times that on a busy
        machine)."""
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            try:
                line = self.lines.get(timeout=max(0.0, left))
            except queue.Empty:
                pytest.fail(f"no line matching {pattern!r} within {timeout} s: {self.seen}")
            self.seen.append(line)
            if (m := re.search(pattern, line)) is not None:
                return m

    def interrupt(self, timeout: float = 20) -> int:
        """SIGINT, then the exit status."""
        self.popen.send_signal(signal.SIGINT)
        return self.popen.wait(timeout)

    def rest(self) -> str:
        """Everything printed after the last ``expect`` (after the process ended)."""
        out = []
        while not self.lines.empty():
            out.append(self.lines.get())
        self.seen += out
        return "\n".join(out)


@contextlib.contextmanager
def spawn(*args: str | Path, program: Sequence[str] = CLI) -> Iterator[Proc]:
    """Start ``drivebus ARGS`` (or ``program ARGS``); killed at the end if still running."""
    p = subprocess.Popen(
        [*program, *map(str, args)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
        text=True
    )
    proc = Proc(p)

    def pump() -> None:
        assert p.stdout is not None
        for line in p.stdout:
            proc.lines.put(line.rstrip("\n"))

    reader = threading.Thread(target=pump, daemon=True)
    reader.start()
    try:
        yield proc
    finally:
        if p.poll() is None:
            p.kill()
            p.wait(10)
        reader.join(5)


@contextlib.contextmanager
def sim_server(config: Path, *extra: str) -> Iterator[tuple[Proc, dict[str, str]]]:
    """``drivebus sim CONFIG``: the process and its endpoints by line name; stopped (and
    its clean exit checked) at the end."""
    with spawn("sim", config, *extra) as proc:
        endpoints: dict[str, str] = {}
        while True:
            m = proc.expect(r"^(?:line (\S+) \S+ (\S+)|simulating machine)")
            if m.group(1) is None:
                break
            endpoints[m.group(1)] = m.group(2)
        yield proc, endpoints
        if proc.popen.poll() is None:
            assert proc.interrupt() == 0


def pty_config(tmp_path: Path, pty: str) -> Path:
    """single.toml with its line on ``pty`` (a ``drivebus sim`` of single.toml)."""
    cfg = tmp_path / "client.toml"
    cfg.write_text(SINGLE.read_text().replace("sim://single", pty))
    return cfg


def status_json(config: Path) -> dict[str, dict[str, object]]:
    r = drivebus("status", config, "--json")
    assert r.returncode == 0, r.stderr
    return {a["axis"]: a for a in json.loads(r.stdout)}


# -- commands on the built-in simulator ------------------------------------------------------------


def test_help_lists_every_command() -> None:
    r = CliRunner().invoke(app, ["--help"])
    assert r.exit_code == 0
    for cmd in ("scan", "status", "move", "home", "jog", "stop", "monitor", "sim", "check",
                "demo", "bench"):
        assert cmd in r.output


def test_status_reports_every_axis_of_the_demo_machine() -> None:
    axes = status_json(DEMO)
    assert set(axes) == {"x", "y", "z", "aux", "r"}
    # the positions the simulator starts at (configs/demo.toml sim.position)
    assert axes["x"]["position"] == pytest.approx(12.0)
    assert axes["y"]["position"] == pytest.approx(7.0)
    assert axes["z"]["position"] == pytest.approx(-1.0)
    assert axes["y"]["settings"] == "19200 8E1"
    assert all(a["state"] == "Standstill" and a["moving"] is False for a in axes.values())
    plain = drivebus("status", DEMO, "y", "z")
    assert plain.returncode == 0
    assert [ln.split(":")[0] for ln in plain.stdout.splitlines()] == ["y", "z"]
    assert "\x1b[" not in plain.stdout  # not a terminal: no escapes, no live view


def test_move_home_jog_and_stop_one_shot() -> None:
    r = drivebus("move", SINGLE, "x", "30")
    assert r.returncode == 0, r.stderr
    assert re.search(r"x: move to 30 done in [\d.]+ s, position=30\.000 state=Standstill",
                     r.stdout)
    assert "state=DiscreteMotion" in r.stdout  # progress lines while it moved
    r = drivebus("move", SINGLE, "x", "-4", "--by", "--speed", "100")
    assert r.returncode == 0, r.stderr
    assert "position=-4.000" in r.stdout  # the simulator starts at 0
    r = drivebus("home", SINGLE, "x")
    assert r.returncode == 0, r.stderr
    assert "home (home_switch_positive) done" in r.stdout
    r = drivebus("jog", SINGLE, "x", "-20", "--for", "0.3")
    assert r.returncode == 0, r.stderr
    m = re.search(r"jog at -20/s for 0.3 s done in [\d.]+ s, position=(-[\d.]+) "
                  r"state=Standstill", r.stdout)
    assert m is not None and float(m.group(1)) < -3.0
    r = drivebus("stop", DEMO)
    assert r.returncode == 0, r.stderr
    assert len(re.findall(r"at standstill", r.stdout)) == 5


def test_monitor_prints_axes_and_per_slave_counters() -> None:
    r = drivebus("monitor", DEMO, "--count", "2", "--interval", "0.1")
    assert r.returncode == 0, r.stderr
    for axis in ("x", "y", "z", "aux", "r"):
        assert len(re.findall(rf"^\S+ {axis}: ", r.stdout, re.M)) == 2
    slaves = re.findall(r"line rs485 slave (\d) \(\w+\): tx=(\d+)", r.stdout)
    assert {a for a, _ in slaves} == {"1", "2", "3", "4"}
    assert all(int(tx) > 0 for _, tx in slaves)


def test_monitor_runs_until_ctrl_c() -> None:
    with spawn("monitor", SINGLE, "--interval", "0.1") as proc:
        proc.expect(r"line bus slave 1 \(x\): tx=\d+")
        assert proc.interrupt() == 0


def in_terminal(*args: str | Path, timeout: float = 30) -> tuple[int, str]:
    """Run ``drivebus ARGS`` with stdout on a pty (a terminal): exit status and output."""
    master, slave = pty.openpty()
    env = {**os.environ, "COLUMNS": "120", "TERM": "xterm"}
    p = subprocess.Popen([*CLI, *map(str, args)], stdin=subprocess.DEVNULL, stdout=slave,
                         stderr=slave, env=env)
    os.close(slave)
    chunks = []
    with alarm_after(timeout):
        while True:
            try:
                data = os.read(master, 65536)
            except OSError:  # EIO: the child closed the terminal
                break
            if not data:
                break
            chunks.append(data)
    os.close(master)
    return p.wait(timeout), b"".join(chunks).decode(errors="replace")


@contextlib.contextmanager
def alarm_after(seconds: float) -> Iterator[None]:
    """Fail the test if the block takes longer than ``seconds`` (SIGALRM)."""

    def expired(signum: int, frame: object) -> None:
        raise TimeoutError(f"terminal run took more than {seconds} s")

    old = signal.signal(signal.SIGALRM, expired)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def test_terminal_views() -> None:
    code, text = in_terminal("move", SINGLE, "x", "20")
    assert code == 0, text
    assert "━" in text and "move to 20" in text  # the progress bar
    assert "position=20.000 state=Standstill" in text
    code, text = in_terminal("monitor", DEMO, "--count", "2", "--interval", "0.1")
    assert code == 0, text
    assert "bus statistics per slave" in text and "OD2000" in text
    code, text = in_terminal("status", DEMO)
    assert code == 0, text
    assert "drivebus: demo" in text and "┃" in text  # the table


# The demo's simulated wire runs in the demo's process and stamps the master's bytes when
# it reads them: a stall of that process longer than the line's 0.1 s timeout, between
# the master's write and the wire's read, lets the master's retry follow its original
# closer on the wire than it did (a gap violation the wire saw, the master never sent).
@pytest.mark.serial
def test_demo_completes() -> None:
    r = drivebus("demo", timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "gap violations 0" in r.stdout


# -- check and errors ---------------------------------------------------------------------------


def test_check_reports_simulated_lines() -> None:
    r = drivebus("check", DEMO)
    assert r.returncode == 0
    assert "line rs485: simulated (sim://demo-rs485, serial)" in r.stdout
    assert "line eth: simulated (sim://demo-eth, tcp)" in r.stdout


def test_check_warns_about_a_usb_serial_latency_timer(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    port = tmp_path / "dev" / "ttyUSB0"
    port.parent.mkdir()
    port.touch()
    timer = tmp_path / "sys" / "bus" / "usb-serial" / "devices" / "ttyUSB0" / "latency_timer"
    timer.parent.mkdir(parents=True)
    timer.write_text("16\n")
    cfg = tmp_path / "m.toml"
    cfg.write_text(SINGLE.read_text().replace("sim://single", str(port)))
    assert check_config(Out(False), cfg, sysfs=tmp_path / "sys") == 0
    err = capsys.readouterr().err
    assert "latency timer is 16 ms" in err and "echo 1 | sudo tee" in err
    timer.write_text("1\n")
    assert check_config(Out(False), cfg, sysfs=tmp_path / "sys") == 0
    assert "latency" not in capsys.readouterr().err


def _one_error_line(r: subprocess.CompletedProcess[str], code: int, *needles: str) -> None:
    assert r.returncode == code, r.stdout + r.stderr
    assert "Traceback" not in r.stderr
    assert r.stderr.startswith("error: ")
    for n in needles:
        assert n in r.stderr


def test_errors_are_one_clear_line(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(DEMO.read_text().replace('drive = "CL86R"', 'drive = "CL99"'))
    _one_error_line(drivebus("status", bad), 2, "axes.z.drive", "unknown drive 'CL99'")
    _one_error_line(drivebus("check", tmp_path / "nope.toml"), 2, "no such config file")
    _one_error_line(drivebus("move", SINGLE, "q", "1"), 2, "no axis q", "axes: x")
    _one_error_line(drivebus("scan", "/dev/ttyUSB9", "--format", "8X1"), 2, "--format")
    missing = tmp_path / "missing.toml"
    missing.write_text(SINGLE.read_text().replace("sim://single", "/dev/ttyDRIVEBUS-NONE"))
    _one_error_line(drivebus("status", missing), 1, "/dev/ttyDRIVEBUS-NONE",
                    "does not exist")
    _one_error_line(drivebus("check", missing), 1, "does not exist")
    _one_error_line(drivebus("scan", "/dev/ttyDRIVEBUS-NONE"), 1, "does not exist")
    absent = tmp_path / "absent.toml"
    absent.write_text(SINGLE.read_text().replace("sim = {", "sim = { absent = true,"))
    r = drivebus("status", absent)  # every axis shown: the silent one Offline, with why
    _one_error_line(r, 1, "does not answer", "drivebus scan")
    assert "x: CL86R" in r.stdout and "state=Offline" in r.stdout, r.stdout
    _one_error_line(drivebus("move", absent, "x", "1"), 1, "does not answer")
    r = drivebus("move", absent, "x", "1", "--debug")
    assert r.returncode != 0 and "Traceback" in r.stderr


def _bad_file(tmp_path: Path, name: str, old: str, new: str) -> Path:
    text = DEMO.read_text()
    assert old in text
    f = tmp_path / f"{name}.toml"
    f.write_text(text.replace(old, new, 1))
    return f


def _hostile_cases(tmp_path: Path) -> list[tuple[list[str | Path], int, tuple[str, ...]]]:
    """(arguments, exit status, what the one line on stderr must name): issue 12's bad input
    at the command line, in files and in arguments."""
    nan_units = _bad_file(tmp_path, "nan", "units_per_rev = 10.0", "units_per_rev = nan")
    same_sim = _bad_file(tmp_path, "same", 'host = "sim://demo-eth"', 'host = "sim://demo-rs485"')
    homing = _bad_file(tmp_path, "homing", 'method = "home_switch_positive", speed = 40.0',
                       'method = "home_switch_postive", speed = 40.0')
    option = _bad_file(tmp_path, "option", "home_input = 5", "home_inptu = 5")
    baud = _bad_file(tmp_path, "baud", 'settings = "38400 8N2"', 'settings = "12345 8N2"')
    return [
        (["status", nan_units], 2, ("nan.toml", "axes.x.units_per_rev", "nan")),
        (["check", nan_units], 2, ("nan.toml", "axes.x.units_per_rev", "finite")),
        (["move", nan_units, "x", "1"], 2, ("axes.x.units_per_rev",)),
        (["status", same_sim], 2, ("lines.eth.host", "sim://demo-rs485", "already line rs485")),
        (["check", same_sim], 2, ("lines.eth.host",)),
        (["check", homing], 2, ("axes.x.homing.method", "'home_switch_postive'")),
        (["home", homing, "x"], 2, ("axes.x.homing.method",)),
        (["check", option], 2, ("axes.r.drive_options.home_inptu", "home_input")),
        (["status", option, "r"], 2, ("axes.r.drive_options.home_inptu",)),
        (["check", baud], 2, ("axes.z.settings", "12345", "CL86R")),
        (["move", SINGLE, "x", "nan"], 2, ("TARGET", "nan")),
        (["move", SINGLE, "x", "-inf", "--by"], 2, ("TARGET", "-inf")),
        (["move", SINGLE, "x", "5", "--speed", "-5"], 2, ("--speed", "-5", "> 0")),
        (["move", SINGLE, "x", "5", "--speed", "nan"], 2, ("--speed", "nan")),
        (["jog", SINGLE, "x", "inf"], 2, ("SPEED", "inf")),
        (["jog", SINGLE, "x", "0"], 2, ("SPEED", "must not be 0")),
        (["jog", SINGLE, "x", "5", "--for", "-1"], 2, ("--for", "-1")),
        (["monitor", SINGLE, "--interval", "nan"], 2, ("--interval", "nan")),
        (["monitor", SINGLE, "--count", "0"], 2, ("--count", "0")),
        (["scan", "/dev/ttyDRIVEBUS-NONE", "--address", "5-1"], 2, ("--address", "'5-1'")),
        (["scan", "/dev/ttyDRIVEBUS-NONE", "--address", "0-300"], 2, ("--address", "1 to 247")),
        (["scan", "/dev/ttyDRIVEBUS-NONE", "--baud", "9600,fast"], 2, ("--baud", "fast")),
        (["scan", "/dev/ttyDRIVEBUS-NONE", "--baud", "0"], 2, ("--baud", "300")),
        (["scan", "/dev/ttyDRIVEBUS-NONE", "--timeout", "inf"], 2, ("--timeout", "inf")),
        (["bench", "--turnaround", "-1"], 2, ("--turnaround", "-1")),
        (["move", SINGLE, "x"], 2, ("Missing argument 'TARGET'", "drivebus move --help")),
        (["move", SINGLE, "x", "far"], 2, ("'TARGET'", "drivebus move --help")),
        (["status", SINGLE, "--bogus"], 2, ("--bogus", "drivebus status --help")),
        (["frobnicate"], 2, ("No such command 'frobnicate'", "drivebus --help")),
    ]


def test_hostile_input_is_one_line_and_the_right_exit_status(tmp_path: Path) -> None:
    """Every bad file and argument: exit status 2, exactly one line on stderr naming the
    cause (key or option, value), no traceback, and nothing run (no output on stdout)."""
    cases = _hostile_cases(tmp_path)
    with ThreadPoolExecutor(4) as pool:  # independent processes: run a few at a time
        results = list(pool.map(lambda c: drivebus(*c[0]), cases))
    for (args, code, needles), r in zip(cases, results, strict=True):
        what = " ".join(map(str, args))
        assert r.returncode == code, (what, r.stdout, r.stderr)
        assert "Traceback" not in r.stderr, what
        lines = r.stderr.splitlines()
        assert len(lines) == 1 and lines[0].startswith("error: "), (what, r.stderr)
        for n in needles:
            assert n in lines[0], (what, lines[0])
        if args[0] != "check":
            assert r.stdout == "", (what, r.stdout)


def test_exception_groups_are_unwrapped_into_one_line_per_cause(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Task groups wrap errors: the lines name what is inside; an unexpected error is one
    line too (no traceback without --debug), and the gravest exit status wins."""
    group = BaseExceptionGroup("unhandled errors in a TaskGroup", [
        ExceptionGroup("inner", [ConfigError("m.toml: axes.x.speed: bad")]),
        DriveOffline("axis y: no answer"),
    ])
    with pytest.raises(SystemExit) as ex:
        fail(group, debug=False)
    assert ex.value.code == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0] == "error: m.toml: axes.x.speed: bad"
    assert err[1].startswith("error: axis y: no answer; check power") and len(err) == 2
    with pytest.raises(SystemExit) as ex:
        fail(ExceptionGroup("g", [ZeroDivisionError("division by zero")]), debug=False)
    assert ex.value.code == 1
    assert capsys.readouterr().err == (
        "internal error: ZeroDivisionError: division by zero (run the command again with "
        "--debug to see where, and please report it)\n")
    with pytest.raises(ExceptionGroup):
        fail(ExceptionGroup("g", [ZeroDivisionError()]), debug=True)


def test_permission_denied_names_the_fix() -> None:
    cause = serial.SerialException(errno.EACCES, "could not open port /dev/ttyUSB0")
    exc = LineClosed("cannot open serial port '/dev/ttyUSB0': could not open port")
    exc.__cause__ = cause
    text, code = explain(exc)
    assert code == 1 and "Permission denied" in text and "dialout" in text
    text, _ = explain(PermissionError(errno.EACCES, "Permission denied", "/dev/ttyS0"))
    assert "/dev/ttyS0" in text and "dialout" in text


# -- scan ----------------------------------------------------------------------------------------


async def test_scan_in_process_finds_slaves_at_mixed_settings() -> None:
    """sim://NAME in this process: the side channel carries parity, so the 8E1 BHSS too."""
    cfg = load_config(DEMO)
    async with contextlib.AsyncExitStack() as stack:
        sims = await start_simulators(cfg, stack)
        wire = sims["rs485"].server
        settings = scan_settings([9600, 19200, 38400, 115200], ["8N1", "8E1", "8N2"])
        found = await scan_line(Out(False), "sim://demo-rs485", settings, [1, 2, 3, 4, 5],
                                0.04, quiet=True)
        probes = wire.requests()  # type: ignore[union-attr]
    got = {f.address: (str(f.settings), f.family) for f in found}
    assert got == {
        1: ("9600 8N1", "OD2000"),
        2: ("115200 8N1", "NT86"),
        3: ("19200 8E1", "BHSS"),
        4: ("38400 8N2", "CL86R"),
    }
    # all addresses at one setting, then the next; a found address is not probed again
    index = {str(s): i for i, s in enumerate(settings)}
    seq = [index[str(f.settings)] for f in probes]
    assert seq == sorted(seq)
    for f in probes:
        if f.address in got:
            assert seq[probes.index(f)] <= index[got[f.address][0]]
    assert [f.address for f in probes if str(f.settings) == "9600 8E1"] == [2, 3, 4, 5]


async def test_a_scan_asks_the_installed_plugins_once_not_before_every_probe(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Each probe lists the drive families that could answer; finding the plug-ins'
    descriptions reads every installed distribution's metadata (16 ms on Python 3.11,
    60 ms on 3.13), which before every probe held the event loop that long."""
    import drivebus.drives.registry as registry

    asked: list[str] = []
    real = registry.entry_points

    def counted(**kwargs: Any) -> Any:
        asked.append(kwargs.get("group", ""))
        return real(**kwargs)

    monkeypatch.setattr(registry, "entry_points", counted)
    monkeypatch.setattr(registry, "_plugins", None, raising=False)  # (as a new process has it)
    cfg = load_config(DEMO)
    async with contextlib.AsyncExitStack() as stack:
        await start_simulators(cfg, stack)
        settings = scan_settings([9600, 115200], ["8N1"])
        found = await scan_line(Out(False), "sim://demo-rs485", settings, [1, 2, 3, 4, 5],
                                0.04, quiet=True)
    assert {f.address for f in found} == {1, 2}
    assert asked == [registry.ENTRY_POINT_GROUP]  # once, for 10 probes


def test_scan_of_a_drivebus_sim_from_another_process() -> None:
    with sim_server(DEMO) as (_, ends):
        pty = ends["rs485"]
        # (a probe timeout a simulator in another process answers within on a busy machine)
        r = drivebus("scan", pty, "--baud", "9600,38400,115200", "--address", "1-5", "--json",
                     "--timeout", "0.15")
        assert r.returncode == 0, r.stderr
        got = {f["address"]: (f["settings"], f["family"]) for f in json.loads(r.stdout)}
        # 8N1/8N2 only across a pty: the 8E1 BHSS cannot be reached from outside
        assert got == {1: ("9600 8N1", "OD2000"), 2: ("115200 8N1", "NT86"),
                       4: ("38400 8N2", "CL86R")}
        assert "8E1, 8O1 are not probed" in r.stderr
        r = drivebus("scan", "sim://demo-rs485", "--baud", "38400", "--address", "3-4",
                     "--timeout", "0.15")
        assert r.returncode == 0, r.stderr
        assert "found address 4 at 38400 8N2: CL86R" in r.stdout
        r = drivebus("scan", pty, "--baud", "57600", "--format", "8N1", "--address", "1-3")
        assert r.returncode == 1
        assert "no slave answered" in r.stderr
    r = drivebus("scan", "sim://demo-rs485")
    assert r.returncode == 2 and "drivebus sim CONFIG" in r.stderr


def test_mbpoll_reads_registers_from_drivebus_sim() -> None:
    mbpoll = shutil.which("mbpoll")
    if mbpoll is None:
        pytest.skip("mbpoll is not installed (make test installs it with apt-get as root)")
    with sim_server(DEMO) as (_, ends):
        r = subprocess.run(
            [mbpoll, "-m", "rtu", "-b", "38400", "-P", "none", "-s", "2", "-a", "4",
             "-t", "4", "-r", "1", "-c", "2", "-1", "-o", "1", ends["rs485"]],
            capture_output=True, text=True, timeout=20, check=False,
        )
    assert r.returncode == 0, r.stdout + r.stderr
    # CL86R holding registers 0x0000-0x0001: model code 862, software version
    assert re.search(r"^\[1\]:\s+862$", r.stdout, re.M), r.stdout
    assert re.search(r"^\[2\]:\s+\d+$", r.stdout, re.M)


# -- Ctrl-C and a drive left moving ---------------------------------------------------------------


def test_ctrl_c_during_move_stops_the_axis(tmp_path: Path) -> None:
    with sim_server(SINGLE) as (sim, ends):
        cfg = pty_config(tmp_path, ends["bus"])
        with spawn("move", cfg, "x", "150", "--speed", "20") as move:
            # the move's own progress lines: positions polled from the drive
            move.expect(r"position=([3-9]|\d\d)\.\d+ .*state=DiscreteMotion")
            assert move.interrupt() == 130
            assert re.search(r"x: move to 150 stopped after [\d.]+ s, position=[\d.]+ "
                             r"state=Standstill", move.rest())
        first, second = status_json(cfg)["x"], status_json(cfg)["x"]
        assert first["moving"] is False and first["state"] == "Standstill"
        assert first["position"] == second["position"]  # at rest across two reads
        assert 3.0 < first["position"] < 100.0  # well short of the target
        assert sim.interrupt() == 0
        twin = re.search(r"twin x: position=(-?\d+) pulses moving=False", sim.rest())
        assert twin is not None
        assert int(twin.group(1)) * 5.0 / 1000 == pytest.approx(first["position"])


def test_stop_halts_a_drive_left_moving_by_a_dead_process(tmp_path: Path) -> None:
    with sim_server(SINGLE) as (_, ends):
        cfg = pty_config(tmp_path, ends["bus"])
        # 2 mm/s: the soft limit (200 mm) is 100 s away, however slowly the commands
        # below start on a busy machine; the drive is still running when they look
        with spawn("jog", cfg, "x", "2") as jog:
            jog.expect(r"position=[1-9]\.\d+ .*state=ContinuousMotion")
            jog.popen.kill()  # no clean-up: the drive keeps running
            jog.popen.wait(10)
        r = drivebus("stop", cfg)
        assert r.returncode == 0, r.stderr
        # "stopped": its first poll found the drive moving ("at standstill" otherwise)
        assert re.search(r"x: stopped at position=[\d.]+ state=Standstill", r.stdout)
        assert status_json(cfg)["x"]["moving"] is False


def test_status_and_monitor_leave_a_running_drive_alone(tmp_path: Path) -> None:
    with sim_server(SINGLE) as (_, ends):
        cfg = pty_config(tmp_path, ends["bus"])
        # 2 mm/s: the soft limit (200 mm) is 100 s away, however slowly the three commands
        # below start on a busy machine (at 10 mm/s it was reached: the drive stopped there)
        with spawn("jog", cfg, "x", "2") as jog:
            jog.expect(r"position=[1-9]\.\d+ .*state=ContinuousMotion")
            jog.popen.kill()  # the drive keeps running with nobody watching it
            jog.popen.wait(10)
        first = status_json(cfg)["x"]
        assert drivebus("monitor", cfg, "--count", "2").returncode == 0
        second = status_json(cfg)["x"]
        assert first["moving"] is True and second["moving"] is True  # observers stop nothing
        assert second["position"] > first["position"]
        assert drivebus("stop", cfg).returncode == 0
        assert status_json(cfg)["x"]["moving"] is False


def test_ctrl_c_ends_an_open_ended_jog_cleanly(tmp_path: Path) -> None:
    with sim_server(SINGLE) as (_, ends):
        cfg = pty_config(tmp_path, ends["bus"])
        with spawn("jog", cfg, "x", "-10") as jog:
            jog.expect(r"position=-[1-9]\.\d+ .*state=ContinuousMotion")
            assert jog.interrupt() == 0  # Ctrl-C is how an open-ended jog ends
            assert "stopped after" in jog.rest()
        assert status_json(cfg)["x"]["moving"] is False


def test_sigterm_ends_an_open_ended_jog_as_143(tmp_path: Path) -> None:
    """Ctrl-C is the normal end of an open-ended jog; SIGTERM (a supervisor ending it) is
    not: the axis stops as for Ctrl-C, and the status says the signal (it was 0)."""
    with sim_server(SINGLE) as (_, ends):
        cfg = pty_config(tmp_path, ends["bus"])
        with spawn("jog", cfg, "x", "-10") as jog:
            jog.expect(r"position=-[1-9]\.\d+ .*state=ContinuousMotion")
            jog.popen.send_signal(signal.SIGTERM)
            assert jog.popen.wait(30) == 143
            assert "interrupted (SIGTERM)" in jog.rest()
        assert status_json(cfg)["x"]["moving"] is False


def test_sim_log_prints_frames(tmp_path: Path) -> None:
    with sim_server(SINGLE, "--log") as (sim, ends):
        cfg = pty_config(tmp_path, ends["bus"])
        assert drivebus("status", cfg).returncode == 0
        sim.expect(r"bus request addr=1 115200-8N1 gap=[\d.]+ms 01 03 ")
        sim.expect(r"bus reply   addr=1 115200-8N1 gap=[\d.]+ms 01 03 ")


def test_pty_settings_are_8n1_or_8n2_only() -> None:
    from drivebus.app.scan import pty_usable

    ok, dropped = pty_usable([LineSettings.parse(t) for t in ("9600 8N1", "9600 8E1",
                                                              "9600 8N2", "9600 7O1")])
    assert [str(s) for s in ok] == ["9600 8N1", "9600 8N2"]
    assert [str(s) for s in dropped] == ["9600 8E1", "9600 7O1"]


# -- register tools, conventions -------------------------------------------------------------------


def _mbpoll(*args: str) -> str:
    mbpoll = shutil.which("mbpoll")
    if mbpoll is None:
        pytest.skip("mbpoll is not installed (make test installs it with apt-get as root)")
    r = subprocess.run([mbpoll, "-m", "rtu", "-P", "none", "-0", "-1", "-o", "1", *args],
                       capture_output=True, text=True, timeout=20, check=False)
    assert r.returncode == 0, r.stdout + r.stderr
    return r.stdout


def _mbpoll_values(out: str) -> dict[int, int]:
    return {int(a): int(v) for a, v in re.findall(r"^\[(\d+)\]:\s+(-?\d+)$", out, re.M)}


def test_read_and_write_agree_with_mbpoll_on_a_drivebus_sim() -> None:
    with sim_server(DEMO) as (_, ends):
        pty = ends["rs485"]
        # CL86R (38400 8N2) model code and software version, by both tools
        r = drivebus("read", "sim://demo-rs485", "4", "0", "2", "-S", "38400 8N2", "--json")
        assert r.returncode == 0, r.stderr
        ours = json.loads(r.stdout)
        theirs = _mbpoll_values(_mbpoll("-b", "38400", "-s", "2", "-a", "4", "-r", "0",
                                        "-c", "2", pty))
        assert ours["words"] == [theirs[0], theirs[1]] and ours["words"][0] == 862
        # NT86 (115200 8N1): drivebus writes, mbpoll reads; mbpoll writes, drivebus reads
        r = drivebus("write", "sim://demo-rs485", "2", "70", "300", "310", "320",
                     "-S", "115200 8N1")
        assert r.returncode == 0, r.stderr
        assert "wrote 3 registers from [70] of slave 2" in r.stdout
        assert _mbpoll_values(_mbpoll("-b", "115200", "-a", "2", "-r", "70", "-c", "3",
                                      pty)) == {70: 300, 71: 310, 72: 320}
        _mbpoll("-b", "115200", "-a", "2", "-r", "72", pty, "555")
        r = drivebus("read", pty, "2", "70", "3", "-S", "115200 8N1")
        assert r.returncode == 0, r.stderr
        assert r.stdout.splitlines() == ["[70]: 300", "[71]: 310", "[72]: 555"]
        # formats: hex words, and the 32-bit position (8/9, low word first) as one value
        r = drivebus("read", pty, "2", "72", "-S", "115200 8N1", "-f", "hex")
        assert r.stdout.strip() == "[72]: 0x022B"
        r = drivebus("read", pty, "2", "8", "-S", "115200 8N1", "-f", "int32-le", "-j")
        pos = json.loads(r.stdout)
        assert len(pos["words"]) == 2 and pos["values"][0] == (
            (pos["words"][1] << 16 | pos["words"][0]) - (1 << 32 if pos["words"][1] & 0x8000
                                                       else 0))
        # poll mode: one JSON line per poll
        r = drivebus("read", pty, "4", "0", "-S", "38400 8N2", "-i", "0.05", "-n", "3", "-j")
        assert r.returncode == 0, r.stderr
        lines = r.stdout.splitlines()
        assert len(lines) == 3 and all(json.loads(x)["words"] == [862] for x in lines)


def test_trace_logs_every_frame_as_the_wire_carried_it() -> None:
    with sim_server(DEMO) as (_, ends):
        pty = ends["rs485"]
        r = drivebus("--trace", "read", pty, "4", "0", "2", "-S", "38400 8N2")
        assert r.returncode == 0, r.stderr
        frames = [x for x in r.stderr.splitlines() if x.startswith("DEBUG drivebus.trace:")]
        assert len(frames) == 2, r.stderr
        tx, rx = frames
        # the request and the reply, with their CRCs, as mbpoll would see them on the wire
        request = frame(4, bytes.fromhex("03 0000 0002"))  # FC03, register 0, count 2
        assert "38400 8N2 tx slave 4" in tx and tx.endswith(request.hex(" "))
        words = [int(w.split(": ")[1]) for w in r.stdout.splitlines()]
        reply = bytes((3, 4)) + b"".join(w.to_bytes(2, "big") for w in words)
        assert "rx slave 4 after" in rx and rx.endswith(frame(4, reply).hex(" "))
        # without --trace, no frame is logged
        r = drivebus("read", pty, "4", "0", "2", "-S", "38400 8N2")
        assert r.returncode == 0 and "drivebus.trace" not in r.stderr


def test_register_tool_arguments_are_checked_before_anything_is_sent(tmp_path: Path) -> None:
    _one_error_line(drivebus("read", "sim://nowhere", "1", "0", "-f", "octal"), 2, "--format")
    _one_error_line(drivebus("read", "tcp://", "1", "0"), 2, "no host")
    _one_error_line(drivebus("read", "ftp://x", "1", "0"), 2, "unknown scheme")
    _one_error_line(drivebus("write", "/dev/ttyDRIVEBUS-NONE", "1", "0", "70000"), 2,
                    "VALUE 1", "70000")
    _one_error_line(drivebus("read", "/dev/ttyDRIVEBUS-NONE", "300", "0"), 2, "ADDR")
    _one_error_line(drivebus("read", "/dev/ttyDRIVEBUS-NONE", "1", "0", "-S", "9600 8X1"), 2,
                    "9600 8X1")
    # through a service too: checked here, before the (unreachable) service is asked
    for args, needle in ((["0"], "COUNT"), (["1", "-i", "-1"], "--interval"),
                         (["1", "-i", "0.1", "-n", "0"], "--count")):
        _one_error_line(drivebus("read", "--server", "http://127.0.0.1:9", "rs485", "1", "0",
                                 *args), 2, needle)


def test_version_and_readable_help() -> None:
    r = drivebus("--version")
    assert r.returncode == 0 and re.fullmatch(r"drivebus \d+\.\d+\.\d+\S*\n", r.stdout)
    for cmd in ([], ["scan"], ["read"], ["move"], ["monitor"], ["status"]):
        r = drivebus(*cmd, "--help")
        assert r.returncode == 0, r.stderr
        options = r.stdout.split("Options:", 1)[-1]  # every option has a readable metavar
        assert "<bool>" not in options and "<str>" not in options and "<float>" not in options
    r = drivebus("--help")
    for flag in ("--debug", "--verbose", "-v", "--log-level", "--trace", "--version"):
        assert flag in r.stdout
    assert "-s, --speed SPEED" in drivebus("move", "--help").stdout
    assert "-i, --interval SECONDS" in drivebus("monitor", "--help").stdout


def test_json_on_every_command_that_prints_results(tmp_path: Path) -> None:
    r = drivebus("move", SINGLE, "x", "3", "--json")
    assert r.returncode == 0, r.stderr
    op = json.loads(r.stdout)
    assert op["done"] is True and op["position"] == pytest.approx(3.0)
    r = drivebus("stop", SINGLE, "-j")
    assert json.loads(r.stdout)[0]["axis"] == "x"
    r = drivebus("check", SINGLE, "-j")
    report = json.loads(r.stdout)
    assert report["machine"] == "single" and report["problems"] == []
    r = drivebus("monitor", SINGLE, "-i", "0.05", "-n", "2", "-j")
    assert r.returncode == 0, r.stderr
    updates = [json.loads(x) for x in r.stdout.splitlines()]
    assert len(updates) == 2 and updates[0]["axes"][0]["axis"] == "x"
    r = drivebus("home", SINGLE, "x", "-j")
    assert r.returncode == 0 and json.loads(r.stdout)["done"] is True
    r = drivebus("jog", SINGLE, "x", "5", "--for", "0.2", "-j")
    assert r.returncode == 0 and json.loads(r.stdout)["what"].startswith("jog")


# -- one owner of a line ---------------------------------------------------------------------------


@contextlib.contextmanager
def serving(config: Path) -> Iterator[tuple[Proc, str]]:
    """``drivebus serve CONFIG --port 0``: the process and its URL; SIGINT at the end."""
    with spawn("serve", config, "--port", "0") as proc:
        m = proc.expect(r"drivebus serve: machine \S+ on (http://127\.0\.0\.1:\d+)/", 30)
        yield proc, m.group(1)
        if proc.popen.poll() is None:
            assert proc.interrupt(30) == 0


def test_one_shot_commands_talk_to_the_serve_that_owns_the_machine() -> None:
    with serving(SINGLE) as (proc, url):
        r = drivebus("move", SINGLE, "x", "50")
        assert r.returncode == 0, r.stderr
        assert "served by a running drivebus serve" in r.stderr
        # the same machine, not a fresh simulator: x is still where the move left it
        assert status_json(SINGLE)["x"]["position"] == pytest.approx(50.0)
        r = drivebus("move", SINGLE, "x", "-5", "--by", "--json")
        assert json.loads(r.stdout)["position"] == pytest.approx(45.0)
        r = drivebus("read", "bus", "1", "0", "2", "--server", url, "--json")
        assert r.returncode == 0, r.stderr
        assert json.loads(r.stdout)["words"][0] == 862  # the CL86R's model code
        r = drivebus("move", SINGLE, "x", "1000")  # its typed error, through the service
        assert r.returncode == 2, r.stderr  # a refusal, as when the machine is opened here
        assert r.stderr.splitlines()[-1].startswith("error: axis x: target 1000 is outside "
                                                    "the soft limits")
        assert "stopped after" not in r.stdout, r.stdout  # nothing was started to stop
        with spawn("move", SINGLE, "x", "150", "--speed", "20") as move:
            # the move runs in the service; Ctrl-C here cancels it there
            move.expect(r"x: position=\S+ .*state=DiscreteMotion")
            assert move.interrupt() == 130
        first, second = status_json(SINGLE)["x"], status_json(SINGLE)["x"]
        assert first["state"] == "Standstill" and first["moving"] is False
        assert first["position"] == second["position"] < 150.0
        r = drivebus("status", SINGLE, "--local")  # --local opens the machine here
        assert r.returncode == 0 and "served by" not in r.stderr
    out = proc.rest()
    assert "every axis at rest" in out


def test_a_serial_line_in_another_process_finds_a_running_drivebus_sim() -> None:
    with sim_server(SINGLE):
        code = (
            "import anyio\n"
            "from drivebus import Bus, LineSettings, SerialLine\n"
            "async def main():\n"
            "    line = SerialLine('sim://single', LineSettings.parse('115200 8N1'))\n"
            "    async with Bus(line) as bus:\n"
            "        print(await bus.slave(1).read_holding_registers(0, 1))\n"
            "anyio.run(main)\n"
        )
        r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                           timeout=30, check=False)
        assert r.returncode == 0, r.stderr
        assert r.stdout.strip() == "[862]"


async def test_a_format_switch_on_a_drivebus_sim_never_waits_for_that_process() -> None:
    """A line on a ``drivebus sim`` of another process, switching per request between the
    8E1 BHSS and the 8N1 NT86: the sim judges each frame at the format told before it. A
    switch does not wait for the sim's answer: with its process stopped (SIGSTOP), a read
    that switches times out as on a silent line (it does not fail on the format channel),
    and once the process runs again the next frame is judged at the format told then."""
    from drivebus import Bus, SerialLine
    from drivebus.errors import ResponseTimeout
    from drivebus.sim.serve import published

    with sim_server(DEMO) as (proc, _):
        # published only once its format channel listens: a master that comes at once
        # gets its parity through (it used to find the line without its channel now and
        # then, and the 8E1 BHSS did not answer it)
        found = published("demo-rs485")
        assert found is not None and found.channel is not None, found
        line = SerialLine("sim://demo-rs485", LineSettings.parse("115200 8N1"))
        async with Bus(line) as bus:
            # (another process answers: on a loaded machine it may be slow to)
            bhss = bus.slave(3, settings=LineSettings.parse("19200 8E1"), timeout=1.0)
            nt86 = bus.slave(2, settings=LineSettings.parse("115200 8N1"), timeout=1.0)
            for _ in range(3):  # every switch judged right: each drive answers
                assert len(await bhss.read_holding_registers(0, 1)) == 1
                assert len(await nt86.read_holding_registers(0, 1)) == 1
            os.kill(proc.popen.pid, signal.SIGSTOP)
            try:
                for address, settings in ((3, "19200 8E1"), (2, "115200 8N1"),
                                          (3, "19200 8E1")):
                    silent = bus.slave(address, settings=LineSettings.parse(settings),
                                       timeout=0.2, retries=0)
                    with pytest.raises(ResponseTimeout):  # not the channel's LineConfigError
                        await silent.read_holding_registers(0, 1)
            finally:
                os.kill(proc.popen.pid, signal.SIGCONT)
            for _ in range(3):
                assert len(await nt86.read_holding_registers(0, 1)) == 1
                assert len(await bhss.read_holding_registers(0, 1)) == 1


def test_demo_where_and_write_give_the_packaged_machine(tmp_path: Path) -> None:
    from drivebus.machines import DEMO as PACKAGED

    r = drivebus("demo", "--where")
    assert r.returncode == 0 and Path(r.stdout.strip()) == PACKAGED, r
    r = drivebus("demo", "--write", tmp_path)  # a folder: the file goes into it
    assert r.returncode == 0, r
    assert (tmp_path / "demo.toml").read_bytes() == PACKAGED.read_bytes()
    mine = tmp_path / "demo.toml"
    mine.write_text("# mine\n")
    r = drivebus("demo", "--write", mine)
    assert r.returncode == 2 and f"{mine} exists" in r.stderr, r
    assert mine.read_text() == "# mine\n"  # never overwritten
    r = drivebus("demo", "--write", tmp_path / "no" / "such" / "folder.toml")
    assert r.returncode == 2 and "No such file or directory" in r.stderr, r
    r = drivebus("demo", DEMO, "--where")
    assert r.returncode == 2 and "without CONFIG" in r.stderr, r
