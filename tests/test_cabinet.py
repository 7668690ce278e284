"""At the cabinet with the command line only (issue 35): refusals that print only the
refusal, errors that name what to do (the output path, the settings a read used, the
token option), a line given where a machine file belongs.

Every check runs the real ``drivebus`` command in a subprocess and reads its exit status
and what it printed; subprocesses are synchronised on their output, never on sleeps.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from drivebus import Recording
from mqtt_helpers import running_broker
from service_rig import TOKENS, token_file
from test_cli import DEMO, SINGLE, Proc, drivebus, sim_server, spawn
from test_service_cli import Served

CLI = [sys.executable, "-m", "drivebus.cli"]


# -- params: a refusal is all that is printed (35.4), the output path is named (35.5) ---------


def test_a_refused_params_load_prints_only_the_refusal(tmp_path: Path) -> None:
    nt86 = tmp_path / "x.toml"
    r = drivebus("params", "dump", DEMO, "x", "-o", nt86)
    assert r.returncode == 0, r.stderr
    assert nt86.read_text().startswith("# drivebus parameters of an NT86 drive: axis x")
    r = drivebus("params", "load", nt86, "z", "--save")
    assert r.returncode == 2, r.stderr
    assert r.stdout == ""  # no "loading ... into axis z" before the refusal
    assert r.stderr == ("error: the parameters are an NT86 drive's; this drive is a CL86R\n")
    # a value out of range: the refusal only, and nothing written
    cl86r = tmp_path / "z.toml"
    assert drivebus("params", "dump", DEMO, "z", "-o", cl86r).returncode == 0
    text = cl86r.read_text()
    cl86r.write_text(re.sub(r"^jog_speed = \{ value = \d+", "jog_speed = { value = 99999",
                            text, flags=re.M))
    r = drivebus("params", "load", cl86r, "--save")
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr.startswith(f"error: {cl86r}: nothing written: jog_speed: value 99999")


def test_params_dump_names_an_unusable_output_path_before_it_reads_the_drive(
        tmp_path: Path) -> None:
    # the machine's port does not exist: had the drive been read first, that would be the error
    absent = tmp_path / "absent.toml"
    absent.write_text(SINGLE.read_text().replace("sim://single", "/dev/ttyDRIVEBUS-NONE"))
    r = drivebus("params", "dump", absent, "x", "-o", "/nonexistent/dir/z.toml")
    assert r.returncode == 2, r.stderr
    assert r.stderr == ("error: --output /nonexistent/dir/z.toml: no such directory "
                        "/nonexistent/dir: create it first, or write the file elsewhere\n")
    r = drivebus("params", "dump", absent, "x", "-o", tmp_path)
    assert r.returncode == 2 and f"--output {tmp_path}: is a directory" in r.stderr
    r = drivebus("params", "dump", absent, "x", "-o", tmp_path / "x.toml")
    assert r.returncode == 1 and "cannot open /dev/ttyDRIVEBUS-NONE" in r.stderr  # then the port
    assert not (tmp_path / "x.toml").exists()


# -- a line where a machine file belongs (35.7) -------------------------------------------------


def test_a_line_given_for_a_machine_file_is_named_as_a_line() -> None:
    r = drivebus("params", "dump", "sim://demo-rs485", "4")
    assert r.returncode == 2
    assert r.stderr.startswith(
        "error: CONFIG: sim://demo-rs485 is a line, not a machine file: `drivebus params "
        "dump` takes a machine file (TOML) and an axis: `drivebus params dump MACHINE.toml "
        "AXIS`; a slave on a line is read with `drivebus read sim://demo-rs485 ADDR REG -S "
        "SETTINGS`"), r.stderr
    r = drivebus("status", "tcp://192.0.2.1")
    assert r.returncode == 2
    assert "tcp://192.0.2.1 is a line, not a machine file: `drivebus status` takes a " \
           "machine file (TOML)" in r.stderr
    assert "no such config file" not in r.stderr


# -- read: no reply names the settings it was asked at (35.8) -----------------------------------


def test_no_reply_names_the_settings_and_the_option_that_sets_them() -> None:
    with sim_server(DEMO):  # the CL86R z talks 38400 8N2; a read at the default meets silence
        r = drivebus("read", "sim://demo-rs485", "4", "0", "-t", "0.1")
        assert r.returncode == 1
        assert r.stderr.startswith(
            "error: slave 4 on sim://demo-rs485: no reply at 19200 8E1 (the default: give the "
            "slave's own with --settings, e.g. -S \"115200 8N1\""), r.stderr
        r = drivebus("read", "sim://demo-rs485", "4", "0", "-t", "0.1", "-S", "9600 8N1")
        assert r.returncode == 1
        assert r.stderr.startswith("error: slave 4 on sim://demo-rs485: no reply at 9600 8N1;")
        r = drivebus("read", "sim://demo-rs485", "4", "0", "-S", "38400 8N2")
        assert r.returncode == 0 and r.stdout == "[0]: 862\n"  # where it is


# -- a service with tokens: the command line's options are named (35.9) --------------------------


def test_a_service_that_wants_a_token_names_the_option_and_the_variable(
        tmp_path: Path) -> None:
    served = Served(DEMO, "--port", "0", "--token-file", token_file(tmp_path))
    try:
        served.url()
        env = {k: v for k, v in os.environ.items() if k != "DRIVEBUS_TOKEN"}
        run = [*CLI, "status", str(DEMO), "x"]
        r = subprocess.run(run, capture_output=True, text=True, timeout=60, env=env)
        assert r.returncode == 1
        error = r.stderr.splitlines()[-1]
        assert re.fullmatch(r"error: the drivebus service at http://127\.0\.0\.1:\d+ needs a "
                            r"token and none was given; give one of its token file with "
                            r"--token TOKEN or in the environment, DRIVEBUS_TOKEN=TOKEN .*",
                            error), error
        assert "Authorization" not in r.stderr
        r = subprocess.run([*run, "--token", "not-a-token-of-its-file"], capture_output=True,
                           text=True, timeout=60, env=env)
        assert r.returncode == 1 and "does not know the token given; give one" in r.stderr
        viewer = {**env, "DRIVEBUS_TOKEN": TOKENS["viewer"][1]}
        r = subprocess.run(run, capture_output=True, text=True, timeout=60, env=viewer)
        assert r.returncode == 0, r.stderr
        assert json.loads(subprocess.run([*run, "--json"], capture_output=True, text=True,
                                         timeout=60, env=viewer).stdout)[0]["axis"] == "x"
        r = subprocess.run([*CLI, "stop", str(DEMO), "x"], capture_output=True, text=True,
                           timeout=60, env=viewer)
        assert r.returncode == 1
        assert "a token of scope 'command' with --token TOKEN or DRIVEBUS_TOKEN" in r.stderr
        code, _, err = served.end(signal.SIGTERM)
        assert code == 0, err
    finally:
        served.kill()


# -- params files show what each value takes; diff flags what is out of range (35.3) -------------


def test_a_parameter_file_shows_ranges_units_and_a_table_index_as_one(tmp_path: Path) -> None:
    backup = tmp_path / "y.toml"
    r = drivebus("params", "dump", DEMO, "y", "-o", backup)
    assert r.returncode == 0, r.stderr
    lines = {ln.split(" = ", 1)[0]: ln for ln in backup.read_text().splitlines()
             if " = { value = " in ln}
    ranges = json.loads(drivebus("params", "dump", DEMO, "y", "--json").stdout)["parameters"]
    assert set(lines) == set(ranges)
    for key, p in ranges.items():  # every value has its range (and unit) beside it
        lo, hi = p["range"]
        assert re.search(rf"# .*; allowed {lo}\.\.{hi}\b", lines[key]), lines[key]
    # the BHSS microstep is an index into a table of pulses/rev: both are said
    assert lines["microstep"].startswith(
        'microstep = { value = 8, unit = "table index", register = "17 (0x0011)"')
    assert lines["microstep"].endswith(
        "# microstep setting: 8 = 1000 pulses/rev; allowed 0..15, a table index selecting "
        "400, 800, 1600, 3200, 6400, 12800, 25600, 51200, 1000, 2000, 4000, 5000, 8000, "
        "10000, 20000, 40000 pulses/rev")
    assert ranges["microstep"]["meaning"] == "1000 pulses/rev"
    assert lines["accel_time"].endswith("# acceleration time; allowed 0..2000 ms")
    assert lines["data_format"].endswith(
        "# serial data format: 2 = 8E1; allowed 0..3: 0 = 8N1, 1 = 8N2, 2 = 8E1, 3 = 8O1")
    # diff flags a value outside its range, against the drive and against another file
    edited = tmp_path / "y-edited.toml"
    edited.write_text(backup.read_text().replace("accel_time = { value = 100",
                                                 "accel_time = { value = 5000").replace(
        "microstep = { value = 8", "microstep = { value = 9"))
    r = drivebus("params", "diff", edited)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines()[1:] == [
        "  microstep: < 9 (2000 pulses/rev) > 8 (1000 pulses/rev) table index  "
        "(microstep setting)",
        "  accel_time: < 5000 > 100 ms  (acceleration time)",
        f"    ! outside its range in {edited}: allowed 0..2000 ms (params load refuses it)"]
    assert r.stderr == "warning: 1 value outside its range: accel_time\n"
    r = drivebus("params", "diff", backup, edited, "--json", "--exit-code")
    assert r.returncode == 1
    found = {d["key"]: d for d in json.loads(r.stdout)["differences"]}
    assert found["accel_time"]["outside_range"] == ["b"]
    assert found["accel_time"]["range"] == [0, 2000]
    assert found["microstep"]["outside_range"] == []
    r = drivebus("params", "load", edited)
    assert r.returncode == 2 and "accel_time: value 5000 ms" in r.stderr and r.stdout == ""


# -- check --probe: an axis that does not answer is reported, the others still checked (35.6) ----


def test_check_probe_reports_an_axis_that_does_not_answer_and_goes_on(tmp_path: Path) -> None:
    with sim_server(DEMO) as (_, ends):
        # the demo's line by its pty (without the 8E1 BHSS: a pty carries no parity), the
        # CL86R z put at the wrong rate (115200, it talks 38400), then also at the wrong
        # address: a pty carries 8N1 and 8N2 only, and the search says so
        text = re.sub(r"\[axes\.y\].*?(?=\[axes\.z\])", "", DEMO.read_text(), flags=re.S)
        text = text.replace("sim://demo-rs485", ends["rs485"])
        wrong_rate = tmp_path / "rate.toml"
        wrong_rate.write_text(text.replace('settings = "38400 8N2"', 'settings = "115200 8N2"'))
        r = drivebus("check", wrong_rate, "--probe", timeout=120)
        assert r.returncode == 1, r.stderr
        ok = [ln for ln in r.stdout.splitlines() if ln.startswith("axis ")]
        assert [ln.split(":")[0] for ln in ok] == ["axis x", "axis aux", "axis r"]
        errors = [ln for ln in r.stderr.splitlines() if ln.startswith("error: ")]
        assert errors == [("error: axis z: no drive answers at address 4 at 115200 8N2; a "
                             "CL86R answers at address 4 at 38400 8N2: fix the machine file's "
                             "address/settings (or the drive's)")]
        wrong_both = tmp_path / "both.toml"
        wrong_both.write_text(wrong_rate.read_text().replace("address = 4\n", "address = 9\n"))
        r = drivebus("check", wrong_both, "--probe", timeout=120)
        assert r.returncode == 1, r.stderr
        assert "axis aux: OD2000 answers at address 1 at 9600 8N1" in r.stdout  # went on
        assert ("error: axis z: no CL86R answers at address 9 at 115200 8N2; tried address 9 "
                "at 9600, 19200, 38400, 115200 baud with 8N1, 8N2 and addresses 1-8, 10-31 at "
                "115200 8N2: check power, wiring and termination") in r.stderr.splitlines()


# -- scan: progress on stderr when piped, rich where a terminal shows it (35.10) ------------------


def test_scan_shows_its_progress_on_stderr_when_piped_and_rich_on_a_terminal() -> None:
    # (a probe timeout a simulator in another process answers within on a busy machine)
    scan = ["scan", "sim://demo-rs485", "-b", "9600,115200", "-f", "8N1,8N2", "-a", "1-4,7",
            "-t", "0.15"]
    with sim_server(DEMO):
        r = drivebus(*scan)  # stdout and stderr both pipes
        assert r.returncode == 0, r.stderr
        assert r.stdout.splitlines() == [
            "found address 1 at 9600 8N1: OD2000 (OD2000, firmware software 1)",
            "found address 2 at 115200 8N1: NT86 (NT86 (drive ID 86), firmware 100)",
            "2 slaves found on sim://demo-rs485"]
        progress = [ln for ln in r.stderr.splitlines() if ln.startswith("scanning ")]
        assert progress == [
            "scanning 9600 8N1 (1 of 4 settings): addresses 1-4, 7, 0 found so far",
            "scanning 9600 8N2 (2 of 4 settings): addresses 1-4, 7, 1 found so far",
            "scanning 115200 8N1 (3 of 4 settings): addresses 1-4, 7, 1 found so far",
            "scanning 115200 8N2 (4 of 4 settings): addresses 1-4, 7, 2 found so far"]
        # stdout into a file, stderr on a terminal: the terminal gets rich's progress bar
        terminal, stderr = os.openpty()
        with subprocess.Popen([*CLI, *scan], stdout=subprocess.PIPE, stderr=stderr,
                              text=True) as p:
            os.close(stderr)
            shown = b""
            while True:
                try:
                    chunk = os.read(terminal, 4096)
                except OSError:  # the terminal closed with the process
                    break
                if not chunk:
                    break
                shown += chunk
            out, _ = p.communicate(timeout=60)
        os.close(terminal)
        assert p.returncode == 0
        assert out.splitlines()[:2] == r.stdout.splitlines()[:2]  # the result on stdout
        screen = shown.decode(errors="replace")
        assert "\x1b[" in screen and "━" in screen  # rich: cursor control and a bar
        assert re.search(r"scanning 115200 8N2 address\s+7", screen), screen[-500:]
        assert "found address" not in screen


# -- status and monitor: each axis in its own unit (35.19) ---------------------------------------


def test_status_and_monitor_show_each_axis_in_its_unit(tmp_path: Path) -> None:
    want = {"x": "mm", "y": "mm", "z": "mm", "r": "deg", "aux": "units"}  # as configured

    def check(lines: list[str]) -> None:
        seen = {}
        for line in lines:
            m = re.search(r"(\w+): \S+ line=.* position=-?[\d.]+([a-z]+) "
                          r"velocity=(?:-|-?[\d.]+([a-z]+)/s) ", line)
            assert m is not None, line
            seen[m.group(1)] = m.group(2)
            assert m.group(3) in (None, m.group(2)), line  # velocity in the same unit/s
        assert seen == want

    with sim_server(DEMO):
        r = drivebus("status", DEMO)
        assert r.returncode == 0, r.stderr
        check(r.stdout.splitlines())
        assert "position=12.000mm velocity=0.000mm/s" in r.stdout
        r = drivebus("monitor", DEMO, "--count", "1")
        assert r.returncode == 0, r.stderr
        check([ln.split(" ", 1)[1] for ln in r.stdout.splitlines() if " line=" in ln])
        records = json.loads(drivebus("status", DEMO, "--json").stdout)
        assert {a["axis"]: a["unit"] for a in records} == want
    # through a running drivebus serve: the same units
    served = Served(DEMO, "--port", "0")
    try:
        served.url()
        r = drivebus("status", DEMO)
        assert r.returncode == 0, r.stderr
        assert "is served by a running drivebus serve" in r.stderr
        check(r.stdout.splitlines())
        assert served.end(signal.SIGTERM)[0] == 0
    finally:
        served.kill()


# -- serve --mqtt: the start line says the bridge runs and where (35.15) -------------------------


def test_serve_with_mqtt_says_where_its_bridge_publishes(tmp_path: Path) -> None:
    with contextlib.contextmanager(running_broker)(tmp_path) as broker:
        served = Served(DEMO, "--port", "0", "--mqtt", broker.url, "--node", "cabinet")
        try:
            served.url()
            start = served.out[0]
            assert re.fullmatch(
                r"drivebus serve: machine demo on http://127\.0\.0\.1:\d+/ \(API /api, docs "
                rf"/docs\); MQTT bridge to mqtt://127\.0\.0\.1:{broker.port} as node cabinet "
                r"\(topics drivebus/cabinet/\.\.\., Home Assistant discovery\); Ctrl-C or "
                r"SIGTERM stops it", start), start
            # and it does: mosquitto_sub sees the node's retained status there
            seen = subprocess.run(
                [broker.sub_exe, "-h", "127.0.0.1", "-p", str(broker.port), "-t",
                 "drivebus/cabinet/status", "-C", "1", "-W", "30"],
                capture_output=True, text=True, timeout=60)
            assert seen.stdout.strip() == "online", seen.stderr
            assert served.end(signal.SIGTERM)[0] == 0
        finally:
            served.kill()


# -- record while serve runs: through its recordings API (35.14) ---------------------------------


def test_record_while_serve_runs_records_through_the_service(tmp_path: Path) -> None:
    html, jsonl = tmp_path / "run.html", tmp_path / "run.jsonl"
    served = Served(DEMO, "--port", "0")
    try:
        url = served.url()
        r = drivebus("record", DEMO, "x", "y", "--during", "move x 30 y 20", "--during",
                     "move-by x -5", "--during", "move-by x 1 y 1", "-o", html, "-o", jsonl,
                     timeout=120)
        assert r.returncode == 0, r.stderr
        assert f"is served by a running drivebus serve at {url}: talking to it" in r.stderr
        assert r.stdout.splitlines()[0] == f"recorded through {url} (recording r1)"
        assert f"wrote {html}" in r.stdout and "5 moves" in r.stdout  # 2 + 1 + 2
        rec = Recording.from_jsonl(jsonl)
        assert list(rec.axes) == ["x", "y"]
        arrived = [(a.axis, a.what) for a in rec.arrivals() if a.outcome == "in_position"]
        assert ("x", "move by -5") in arrived and len(arrived) == 5, arrived
        assert "window.DRIVEBUS_REPORT" in html.read_text()
        with httpx.Client(base_url=url, timeout=30) as client:  # the service moved and kept it
            kept = client.get("/api/recordings").json()
            assert [(k["id"], k["running"], k["axes"]) for k in kept] == [("r1", False,
                                                                          ["x", "y"])]
            assert client.get("/api/axes/x").json()["position"] == pytest.approx(26.0, abs=0.01)
            assert client.get("/api/axes/y").json()["position"] == pytest.approx(21.0, abs=0.01)
        # a step naming no axis of the machine: refused before anything is recorded
        r = drivebus("record", DEMO, "--during", "move w 3", "-o", tmp_path / "a.html")
        assert r.returncode == 2 and "no axis 'w'" in r.stderr
        assert not (tmp_path / "a.html").exists()
        assert served.end(signal.SIGTERM)[0] == 0
    finally:
        served.kill()


# -- commission: an occupied address at any setting (35.1), a power cycle in the sim (35.2) -----

CABINET = """
name = "cabinet"

[lines.rs485]
port = "sim://cabinet"
settings = "115200 8N1"

[axes.x]                 # an NT86 on its switches: address 2 at 115200 8N1
line = "rs485"
address = 2
drive = "NT86"
settings = "115200 8N1"
pulses_per_rev = 4000

[axes.z]                 # a CL86R with SW1-SW5 ON: its address is register 0x0020's
line = "rs485"
address = 4
drive = "CL86R"
settings = "38400 8N2"
pulses_per_rev = 1000
sim = { options = { soft_address = true } }
"""


def logged_writes(lines: list[str]) -> list[str]:
    """The write requests (FC06/FC16) among ``drivebus sim --log`` lines."""
    return [x for x in lines if " request " in x and re.search(r"ms [0-9a-f]{2} (06|10) ", x)]


def test_commission_refuses_an_address_taken_at_another_rate_before_writing(
        tmp_path: Path) -> None:
    machine = tmp_path / "cabinet.toml"
    machine.write_text(CABINET)
    with sim_server(machine, "--log") as (sim, _):
        # the NT86 answers at 2 at 115200 8N1; the CL86R talks 38400 8N2: refused all the same
        r = drivebus("commission", "sim://cabinet", "--drive", "CL86R", "--address", "4",
                     "-S", "38400 8N2", "--to-address", "2", "--wait", "5", timeout=60)
        assert r.returncode == 1, r.stdout + r.stderr
        assert r.stderr.startswith("error: another slave already answers at address 2 at "
                                   "115200 8N1 on sim://cabinet (an NT86, "), r.stderr
        assert r.stderr.endswith("give the drive a free address (nothing was written)\n")
        m = re.search(r"checking that no other slave answers at address 2 at (\d+) line "
                      r"settings", r.stdout)
        assert m is not None and int(m.group(1)) >= 20, r.stdout  # every rate and format
        # nothing was written: the wire log up to a marker read has no write request
        assert drivebus("read", "sim://cabinet", "4", "0", "-S", "38400 8N2").returncode == 0
        sim.expect(r"request addr=4 38400-8N2 gap=\S+ 04 03 00 00 00 01 ")
        assert logged_writes(sim.seen) == []
        assert any("request addr=2 115200-8N1" in x for x in sim.seen)  # it looked there


@contextlib.contextmanager
def sim_at_a_terminal(machine: Path) -> Iterator[tuple[Proc, int]]:
    """``drivebus sim MACHINE`` with a terminal on its stdin (a pty, as when a technician
    runs it): the process (stdout read line by line) and the terminal's end to type on."""
    console, stdin = os.openpty()
    p = subprocess.Popen([*CLI, "sim", str(machine)], stdin=stdin, stdout=subprocess.PIPE,
                         stderr=subprocess.STDOUT, text=True)
    os.close(stdin)
    proc = Proc(p)

    def pump() -> None:
        assert p.stdout is not None
        for line in p.stdout:
            proc.lines.put(line.rstrip("\n"))

    reader = threading.Thread(target=pump, daemon=True)
    reader.start()
    try:
        yield proc, console
    finally:
        os.close(console)
        if p.poll() is None:
            p.kill()
            p.wait(10)
        reader.join(5)


def test_commission_finishes_on_drivebus_sim_power_cycled_from_the_command_line_and_console(
        tmp_path: Path) -> None:
    machine = tmp_path / "cabinet.toml"
    machine.write_text(CABINET)
    with sim_at_a_terminal(machine) as (sim, console):
        sim.expect(r"^simulating machine cabinet")
        sim.expect(r"^console: type `power-cycle AXIS`")
        # 1. from another terminal: drivebus sim CONFIG --power-cycle ADDRESS (each
        # commission with a response timeout that the simulator in another process
        # answers within on a busy machine)
        with spawn("commission", "sim://cabinet", "--drive", "CL86R", "--address", "4",
                   "-S", "38400 8N2", "--to-address", "6", "--to-settings", "38400 8E1",
                   "--wait", "30", "--timeout", "0.5") as commission:
            asked = commission.expect(r"power-cycle the CL86R now", timeout=30).string
            assert asked == (
                "written and saved; power-cycle the CL86R now; waiting for it at address 6 at "
                "38400 8E1 on sim://cabinet (up to 30 s; it takes them at power-up); on this "
                "drivebus sim: type `power-cycle 4` at its console, or run `drivebus sim "
                "MACHINE.toml --power-cycle 4`"), asked
            r = drivebus("sim", machine, "--power-cycle", "4")
            assert r.returncode == 0, r.stderr
            assert r.stdout == ("power-cycled axis z (CL86R): it answers at address 6 at "
                                "38400 8E1 on line rs485\n")
            commission.expect(r"^the CL86R answers at address 6 at 38400 8E1 \(after ",
                              timeout=30)
            assert commission.popen.wait(30) == 0
        r = drivebus("read", "sim://cabinet", "6", "0", "-S", "38400 8E1")
        assert r.returncode == 0 and r.stdout == "[0]: 862\n"
        # 2. at drivebus sim's console: back to 4 at 38400 8N2
        with spawn("commission", "sim://cabinet", "--drive", "CL86R", "--address", "6",
                   "-S", "38400 8E1", "--to-address", "4", "--to-settings", "38400 8N2",
                   "--wait", "30", "--timeout", "0.5") as commission:
            commission.expect(r"power-cycle the CL86R now", timeout=30)
            os.write(console, b"power-cycle z\n")
            sim.expect(r"^power-cycled axis z \(CL86R\): it answers at address 4 at 38400 8N2 "
                       r"on line rs485$")
            commission.expect(r"^the CL86R answers at address 4 at 38400 8N2", timeout=30)
            assert commission.popen.wait(30) == 0
        os.write(console, b"power-cycle w\n")
        sim.expect(r"^error: no axis 'w' \(axes: x, z\)$")
        r = drivebus("sim", machine, "--power-cycle", "9")
        assert r.returncode == 2
        assert r.stderr == "error: no axis '9' and no drive at that address (axes: x, z)\n"
        assert sim.interrupt() == 0
