"""The command line judged by the wire: a ``drivebus sim --log`` in its own process logs
every frame its line carries, and its twins say at the end whether a motor still runs.

Refused commands (a bad argument, a target beyond the soft limits, a drive that cannot do
it, an unknown axis or position, an output that cannot be written) send nothing at all:
what the machine file decides is refused before a port opens. Every moving command that
is interrupted leaves its twins at rest, the stop on the wire before the process ends;
interrupted before anything opened, it says so in one line (exit status 130).
"""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import pytest

from drivebus.cli.failures import fail
from test_cli import DEMO, ROOT, SINGLE, Proc, drivebus, serving, sim_server, spawn
from wirelog import KINDS


@dataclass(frozen=True)
class Frame:
    """One request frame of a ``drivebus sim --log``: when, to whom, what."""

    at: float
    address: int
    data: bytes

    @property
    def write(self) -> bool:
        """A write function code (FC05, 06, 0F, 10, 17)."""
        return len(self.data) > 1 and self.data[1] in (0x05, 0x06, 0x0F, 0x10, 0x17)


_REQUEST = re.compile(r"^(\d+\.\d+) \S+ request addr=(\d+) \S+ gap=\S+ ([0-9a-f ]+)")


def requests(sim: Proc) -> list[Frame]:
    """Every request frame the simulator has logged so far (its lines read off the pipe)."""
    while not sim.lines.empty():
        sim.seen.append(sim.lines.get())
    return [Frame(float(m.group(1)), int(m.group(2)), bytes.fromhex(m.group(3)))
            for line in sim.seen if (m := _REQUEST.match(line))]


def sync(sim: Proc, port: str, address: int, settings: str) -> Frame:
    """Read register 0 of ``address`` through ``port`` and wait until the simulator has
    logged that request: every frame sent before it is in the log then."""
    before = len(requests(sim))
    r = drivebus("read", port, str(address), "0", "-S", settings)
    assert r.returncode == 0, r.stderr
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        new = requests(sim)[before:]
        if any(f.address == address and f.data[1] == 0x03 for f in new):
            return new[-1]
        time.sleep(0.05)
    pytest.fail(f"the simulator logged no read of slave {address} within 30 s")


def _machine(tmp_path: Path, name: str, speed: float) -> Path:
    """single.toml on a simulated line of its own, its axis at ``speed`` mm/s."""
    text = SINGLE.read_text().replace("sim://single", f"sim://{name}")
    text = re.sub(r"^speed = 50\.0 .*$", f"speed = {speed}", text, count=1, flags=re.M)
    cfg = tmp_path / f"{name}.toml"
    cfg.write_text(text)
    return cfg


def _refused(tmp_path: Path) -> list[tuple[list[str | Path], tuple[str, ...]]]:
    """Commands the machine file and the arguments refuse, and what the error names (on
    a copy of the demo machine: a refused ``teach`` must not touch the packaged one)."""
    demo = tmp_path / "demo.toml"
    demo.write_text(DEMO.read_text())
    watched = tmp_path / "watched.toml"  # a position that has aux, which cannot move
    watched.write_text(DEMO.read_text() + "\n[positions.watch]\naux = 0.0\n")
    out = tmp_path / "run.jsonl"
    nowhere = tmp_path / "no-such-dir" / "run.html"
    return [
        (["move", demo, "x", "1000"], ("TARGET", "soft limits")),
        (["move", demo, "x", "-6"], ("TARGET", "soft limits")),
        (["move", demo, "x", "10", "--speed", "1e9"], ("speed", "its drive runs at most")),
        (["jog", demo, "x", "1e9"], ("speed", "its drive runs at most")),
        (["move", demo, "aux", "10"], ("OD2000", "cannot make an absolute move")),
        (["home", demo, "aux"], ("OD2000", "cannot home")),
        (["jog", demo, "aux", "5", "--for", "1"], ("OD2000", "cannot")),
        (["move", demo, "nowhere"], ("no position 'nowhere'",)),
        (["teach", demo, "pick", "q"], ("no axis q",)),
        (["teach", demo, "pick", "x", "aux"], ("AXIS", "axis aux cannot be taught", "OD2000")),
        (["teach", watched, "watch"], ("AXIS", "axis aux cannot be taught", "OD2000")),
        (["record", demo, "-d", "move q 10", "-o", out], ("--during", "no axis 'q'")),
        (["record", demo, "q", "-s", "1", "-o", out], ("no axis q",)),
        (["record", demo, "-d", "move x 10", "-d", "move x 1000", "-o", out],
         ("soft limits",)),
        (["record", demo, "-d", "jog aux 5 1", "-o", out], ("OD2000", "cannot")),
        (["record", demo, "-d", "move x 10", "-o", nowhere], ("no such directory",)),
        (["record", demo, "-d", "move x 10", "--png", nowhere.with_suffix(".png")],
         ("no such directory",)),
    ]


def test_a_refused_command_sends_nothing_at_all(tmp_path: Path) -> None:
    """Each refusal: exit status 2, one line on stderr naming the cause, no traceback,
    and not one frame on the line (the simulator's log, up to a read made after them)."""
    cases = _refused(tmp_path)
    with sim_server(DEMO, "--log") as (sim, _):
        mark = len(requests(sim))
        with ThreadPoolExecutor(3) as pool:
            results = list(pool.map(lambda c: drivebus(*c[0]), cases))
        last = sync(sim, "sim://demo-rs485", 4, "38400 8N2")
        sent = [f for f in requests(sim)[mark:] if f != last]
    for (args, needles), r in zip(cases, results, strict=True):
        what = " ".join(map(str, args))
        assert r.returncode == 2, (what, r.stdout, r.stderr)
        lines = [ln for ln in r.stderr.splitlines() if not ln.startswith("note: ")]
        assert len(lines) == 1 and lines[0].startswith("error: "), (what, r.stderr)
        for n in needles:
            assert n in lines[0], (what, lines[0])
    assert sent == [], [f"{f.address}: {f.data.hex(' ')}" for f in sent]


def test_a_jog_with_no_room_before_the_soft_limit_is_refused_with_nothing_written(
    tmp_path: Path,
) -> None:
    """At the negative soft limit, a jog down is refused as a move beyond it is (exit
    status 2, the limit named) with not one write on the line; up, it runs."""
    cfg = _machine(tmp_path, "edge", 50.0)
    with sim_server(cfg, "--log") as (sim, _):
        assert drivebus("move", cfg, "x", "-10").returncode == 0
        mark = sync(sim, "sim://edge", 1, "115200 8N1")
        down = drivebus("jog", cfg, "x", "-5", "--for", "1")
        last = sync(sim, "sim://edge", 1, "115200 8N1")
        between = requests(sim)
        between = between[between.index(mark) + 1:between.index(last)]
        up = drivebus("jog", cfg, "x", "5", "--for", "0.2")
    assert down.returncode == 2, down.stderr
    assert down.stderr.splitlines()[-1].startswith("error: SPEED: axis x: at the soft limit")
    assert [f.data.hex(" ") for f in between if f.write] == []
    assert up.returncode == 0, up.stderr


def test_a_command_the_serve_refuses_sends_nothing_and_exits_2(tmp_path: Path) -> None:
    """The same refusals through the ``drivebus serve`` that owns the machine (on a running
    simulator): exit status 2 as when the machine is opened here, and not one write on
    the line; a refused jog sends no stop either: it stopped someone else's motion."""
    demo = tmp_path / "demo.toml"
    demo.write_text(DEMO.read_text())
    cases: list[tuple[list[str | Path], str]] = [
        (["jog", demo, "x", "1e9", "--for", "1"], "its drive runs at most"),
        (["move", demo, "x", "1000"], "soft limits"),
        (["move", demo, "aux", "10"], "cannot make an absolute move"),
        (["home", demo, "aux"], "cannot home"),
        (["move", demo, "nowhere"], "no position 'nowhere'"),
        (["status", demo, "q"], "no axis 'q'"),
        (["teach", demo, "pick", "aux"], "axis aux cannot be taught"),
    ]
    # someone else's motion on x (5 mm/s: a minute long) runs meanwhile
    with (sim_server(demo, "--log") as (sim, _), serving(demo),
          spawn("move", demo, "x", "300", "--speed", "5") as move):
        move.expect(r"x: position=\S+ .*state=DiscreteMotion")
        start = _await_start(sim, 2, "NT86", 0.0)  # the move's own frames: up to this one
        began = start.at
        results = [drivebus(*args) for args, _ in cases]
        ended = time.monotonic()
        deadline = ended + 30  # the service polls: a frame after them shows they are in
        while not any(f.at > ended for f in requests(sim)) and time.monotonic() < deadline:
            time.sleep(0.05)
        sent = [f for f in requests(sim) if f.at > began]
        assert move.popen.poll() is None, move.rest()  # not stopped by a refusal
        assert move.interrupt() == 130
    assert any(f.at > ended for f in sent), "the service's polls were not logged"
    assert [f for f in sent if f.write] == [], [f.data.hex(" ") for f in sent if f.write]
    for (args, needle), r in zip(cases, results, strict=True):
        what = " ".join(map(str, args))
        assert r.returncode == 2, (what, r.stderr)
        assert "served by a running drivebus serve" in r.stderr, what
        assert r.stderr.splitlines()[-1].startswith("error: ") and needle in r.stderr, what


def _kind(frame: Frame, drive: str = "CL86R") -> str | None:
    """``start``/``stop`` for a command frame of ``drive`` (FC06 to its control word)."""
    d = frame.data
    if len(d) < 6 or d[1] != 0x06:
        return None
    return KINDS[drive](int.from_bytes(d[2:4], "big"), int.from_bytes(d[4:6], "big"))


def _await_start(sim: Proc, address: int, drive: str, after: float) -> Frame:
    """The first start command to ``address`` logged after ``after`` (monotonic s)."""
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        for f in requests(sim):
            if f.at > after and f.address == address and _kind(f, drive) == "start":
                return f
        time.sleep(0.05)
    pytest.fail(f"no start command to slave {address} within 30 s")


@pytest.mark.parametrize("how", ["SIGTERM", "SIGINT twice"])
def test_an_interrupted_demo_leaves_its_twins_at_rest(tmp_path: Path, how: str) -> None:
    """``drivebus demo CONFIG`` on a running simulator, interrupted in its first group
    move (1 mm/s: some 40 s long): the stop is on the wire after the move's start, the
    twin is at rest when the command has ended, and the exit status says the signal."""
    cfg = _machine(tmp_path, "slowdemo", 1.0)
    with sim_server(cfg, "--log") as (sim, _):
        with spawn("demo", cfg) as demo:
            demo.expect(r"^home x: done")
            homed = time.monotonic()  # CLOCK_MONOTONIC: the simulator's log clock too
            start = _await_start(sim, 1, "CL86R", homed)  # the group move's
            if how == "SIGTERM":
                demo.popen.send_signal(signal.SIGTERM)
            else:
                demo.popen.send_signal(signal.SIGINT)
                demo.popen.send_signal(signal.SIGINT)
            code = demo.popen.wait(30)
            said = demo.rest()
        assert code == (143 if how == "SIGTERM" else 130), said
        assert f"interrupted ({how.split()[0]})" in said
        stops = [f for f in requests(sim) if f.at > start.at and _kind(f) == "stop"]
        assert stops, "no stop on the wire after the move's start"
        assert sim.interrupt() == 0
        twins = sim.rest()
    assert re.search(r"^twin x: position=-?\d+ pulses moving=False$", twins, re.M), twins


_APP = """
import sys

import anyio

from drivebus import open_machine


async def main() -> None:  # an application that leaves SIGTERM as Python sets it
    async with open_machine(sys.argv[1]) as m:
        x = m.axes["x"]
        await x.enable()
        async with anyio.create_task_group() as tg:
            tg.start_soon(x.move_to, 190.0)
            async for st in x.watch():
                if st.moving:
                    print("moving", flush=True)
                    break
            await anyio.sleep_forever()


anyio.run(main)
"""


def test_sigterm_to_an_application_embedding_a_machine_stops_its_axes_first(
        tmp_path: Path) -> None:
    """An application that runs ``open_machine`` and leaves SIGTERM at Python's default
    (which ends the process at once: it died with its axis moving) gets its axes stopped
    first, then ends by SIGTERM as it would have."""
    cfg = _machine(tmp_path, "sigterm-app", 1.0)
    app = tmp_path / "app.py"
    app.write_text(_APP)
    with sim_server(cfg, "--log") as (sim, _):
        began = time.monotonic()  # CLOCK_MONOTONIC: the simulator's log clock too
        with spawn(app, cfg, program=[sys.executable]) as proc:
            proc.expect(r"^moving$")
            start = _await_start(sim, 1, "CL86R", began)
            proc.popen.send_signal(signal.SIGTERM)
            code = proc.popen.wait(60)
            said = proc.rest()
        assert code == -signal.SIGTERM, (code, said)
        assert said.startswith("SIGTERM: stopping the machines' axes") and \
            "axis x: stopped at" in said, said
        stops = [f for f in requests(sim) if f.at > start.at and _kind(f) == "stop"]
        assert stops, "no stop on the wire after the move's start"
        assert sim.interrupt() == 0
        twins = sim.rest()
    assert re.search(r"^twin x: position=-?\d+ pulses moving=False$", twins, re.M), twins


_CTRL_C_AT = """
import sys

class CtrlC:  # Ctrl-C that lands while MODULE is being imported
    def find_spec(self, name, path=None, target=None):
        if name == MODULE:
            raise KeyboardInterrupt
        return None

sys.meta_path.insert(0, CtrlC())
sys.argv = ["drivebus", *ARGS]
from drivebus.cli import main
main()
"""


@pytest.mark.parametrize("module", ["drivebus.cli.commissioning", "drivebus.motion"])
def test_ctrl_c_while_the_command_starts_is_130_without_a_traceback(module: str) -> None:
    """Ctrl-C during the imports of the start-up (the entry point's, then the command's
    own), made deterministic by an import hook that raises it there: exit status 130, at
    most the one line ``interrupted``, no traceback."""
    program = _CTRL_C_AT.replace("MODULE", repr(module)).replace(
        "ARGS", repr(["move", str(SINGLE), "x", "10"]))
    r = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True,
                       timeout=60, check=False, cwd=ROOT)
    assert r.returncode == 130, (r.returncode, r.stderr[-2000:])
    assert r.stderr in ("", "interrupted\n"), r.stderr[-2000:]
    assert r.stdout == ""


def test_an_error_raised_because_of_ctrl_c_is_an_interruption(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A library that wraps the Ctrl-C that hit it (pydantic building a model: a
    SchemaError whose context is the KeyboardInterrupt) is ``interrupted``, 130, not an
    internal error."""
    try:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise RuntimeError('Error building "literal" validator')  # noqa: B904
    except RuntimeError as exc:
        wrapped = exc
    with pytest.raises(SystemExit) as ex:
        fail(wrapped, debug=False)
    assert ex.value.code == 130
    assert capsys.readouterr().err == "interrupted\n"
