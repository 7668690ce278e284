"""Commissioning at the cabinet, as a technician does it: ``drivebus params``, ``drivebus
commission``, ``check --probe``, a running ``drivebus sim`` reached by name, the CLI's
option handling and ``/metrics``, checked with third-party peers (mbpoll on the same
simulated drives, prometheus_client's parser on a real HTTP scrape).

Subprocesses are synchronised on what they print, never on sleeps.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import anyio
import anyio.lowlevel
import anyio.to_thread
import pytest
from prometheus_client.parser import text_string_to_metric_families

from drivebus.service.metrics import exposition
from drivebus.settings import LineSettings
from drivebus.sim import VirtualWire
from drivebus.sim.drives.cl86r import SimCL86R
from service_rig import running, until
from test_cli import DEMO, SINGLE, drivebus, sim_server

CLI = [sys.executable, "-m", "drivebus.cli"]


@pytest.fixture(autouse=True)
def _private_runtime_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``drivebus sim`` publishes its lines here: keep tests apart from a user's sims."""
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path / "run"))


def mbpoll(*args: str, ok: bool = True) -> subprocess.CompletedProcess[str]:
    """mbpoll in RTU mode, 0-based registers, one poll."""
    exe = shutil.which("mbpoll")
    if exe is None:
        pytest.skip("mbpoll is not installed (make test installs it with apt-get as root)")
    r = subprocess.run([exe, "-m", "rtu", "-0", "-1", "-o", "0.5", *args],
                       capture_output=True, text=True, timeout=20, check=False)
    if ok:
        assert r.returncode == 0, r.stdout + r.stderr
    return r


def mbpoll_values(r: subprocess.CompletedProcess[str]) -> dict[int, int]:
    return {int(a): int(v) for a, v in re.findall(r"^\[(\d+)\]:\s+(-?\d+)$", r.stdout, re.M)}


def logged_writes(lines: list[str]) -> list[str]:
    """The write requests (FC06/FC16) among ``drivebus sim --log`` lines."""
    return [x for x in lines if " request " in x and re.search(r"ms [0-9a-f]{2} (06|10) ", x)]


# -- params against a running drivebus sim, checked with mbpoll -----------------------------------


def test_params_dump_diff_load_on_a_running_sim_agree_with_mbpoll(tmp_path: Path) -> None:
    with sim_server(DEMO, "--log") as (sim, ends):
        pty = ends["rs485"]
        backup = tmp_path / "z.toml"
        r = drivebus("params", "dump", DEMO, "z", "-o", backup)
        assert r.returncode == 0, r.stderr
        assert "reaching the running drivebus sim" in r.stderr
        assert "read 47 parameters of axis z (CL86R at address 4" in r.stderr
        values = {k: v["value"] for k, v in json.loads(
            drivebus("params", "dump", DEMO, "z", "--json").stdout)["parameters"].items()}
        # mbpoll reads the same values from the same simulated drive (38400 8N2)
        theirs = mbpoll_values(mbpoll("-b", "38400", "-P", "none", "-s", "2", "-a", "4",
                                      "-r", "0x0030", "-c", "4", pty))
        assert [theirs[a] for a in range(0x30, 0x34)] == [
            values["start_speed"], values["accel_time"], values["decel_time"],
            values["max_speed"]]
        # the dumps wrote nothing: the simulator's wire log has no write request
        sim.expect(r"request addr=4 38400-8N2 .* 04 03 00 10 ")  # the dump's first read
        marker = drivebus("read", "sim://demo-rs485", "4", "0", "-S", "38400 8N2")
        assert marker.returncode == 0
        sim.expect(r"request addr=4 38400-8N2 gap=\S+ 04 03 00 00 00 01 ")
        assert logged_writes(sim.seen) == []
        # edit the backup: two values change, then diff shows exactly them
        text = backup.read_text()
        text = re.sub(r"^accel_time = \{ value = \d+", "accel_time = { value = 250", text,
                      flags=re.M)
        text = re.sub(r"^jog_speed = \{ value = \d+", "jog_speed = { value = 75", text,
                      flags=re.M)
        backup.write_text(text)
        r = drivebus("params", "diff", backup, "--json")
        assert r.returncode == 0, r.stderr
        assert [d["key"] for d in json.loads(r.stdout)["differences"]] == [
            "accel_time", "jog_speed"]
        r = drivebus("params", "diff", backup, "--exit-code")
        assert r.returncode == 1 and "accel_time: < 250 > " in r.stdout
        # load writes the two (and saves once); mbpoll sees the new values
        r = drivebus("params", "load", backup, "--dry-run")
        assert r.returncode == 0 and "dry run: 2 parameters of axis z would be written" in r.stdout
        r = drivebus("params", "load", backup, "--save")
        assert r.returncode == 0, r.stderr
        assert "wrote 2 parameters of axis z; stored in the drive's EEPROM" in r.stdout
        theirs = mbpoll_values(mbpoll("-b", "38400", "-P", "none", "-s", "2", "-a", "4",
                                      "-r", "0x0031", pty))
        assert theirs[0x31] == 250
        theirs = mbpoll_values(mbpoll("-b", "38400", "-P", "none", "-s", "2", "-a", "4",
                                      "-r", "0x0046", pty))
        assert theirs[0x46] == 75
        r = drivebus("params", "diff", backup)
        assert r.returncode == 0 and "no parameter differs" in r.stdout
        # a value out of range: nothing is written (exit 2), mbpoll sees the old values;
        # the file alone decides it: not even the drive is read (the log, between two marks)
        backup.write_text(text.replace("jog_speed = { value = 75", "jog_speed = { value = 7500"))

        def mark() -> int:
            r = drivebus("read", "sim://demo-rs485", "4", "0", "-S", "38400 8N2")
            assert r.returncode == 0, r.stderr
            sim.expect(r"request addr=4 38400-8N2 gap=\S+ 04 03 00 00 00 01 ")
            return len(sim.seen)

        before = mark()
        r = drivebus("params", "load", backup, "--save")
        assert r.returncode == 2 and "nothing written: jog_speed" in r.stderr
        after = mark()
        assert [x for x in sim.seen[before:after - 1] if " request " in x] == []
        theirs = mbpoll_values(mbpoll("-b", "38400", "-P", "none", "-s", "2", "-a", "4",
                                      "-r", "0x0046", pty))
        assert theirs[0x46] == 75
        # the BHSS at 19200 8E1 (parity, which no pty carries) is reached by its sim:// name
        r = drivebus("params", "dump", DEMO, "y", "--json")
        assert r.returncode == 0, r.stderr
        assert json.loads(r.stdout)["parameters"]["microstep"]["value"] == 8


# -- one behaviour for sim://NAME -----------------------------------------------------------------


def test_a_machine_file_reaches_the_running_sim_and_says_so(tmp_path: Path) -> None:
    r = drivebus("status", SINGLE, "-v")  # said on a terminal; in a pipe with -v
    assert r.returncode == 0 and "starting a private simulator" in r.stderr
    with sim_server(DEMO):
        r = drivebus("move", DEMO, "x", "97.6")
        assert r.returncode == 0, r.stderr
        r = drivebus("status", DEMO, "x", "y", "--json")
        assert r.returncode == 0, r.stderr
        assert "note: sim://demo-rs485: reaching the running drivebus sim on /dev/pts/" in (
            r.stderr)
        axes = {a["axis"]: a for a in json.loads(r.stdout)}
        assert axes["x"]["position"] == pytest.approx(97.6, abs=0.01)  # not a private 12.0
        assert axes["y"]["state"] == "Standstill"  # the 8E1 BHSS, through the format channel
        # register tools at parity through sim://NAME; a bare pty says why it cannot
        r = drivebus("read", "sim://demo-rs485", "3", "0", "2", "-b", "19200", "-P", "even")
        assert r.returncode == 0, r.stderr
        assert r.stdout.splitlines() == ["[0]: 773", "[1]: 257"]  # model 0x0305, v1.01
        r = drivebus("scan", "sim://demo-rs485", "-S", "19200 8E1", "-a", "1-4", "--json")
        assert [f["family"] for f in json.loads(r.stdout)] == ["BHSS"]
        pty = r.stderr.split("on ")[-1].strip() if "on /dev" in r.stderr else None
        assert pty is not None
        r = drivebus("read", pty, "3", "0", "-S", "19200 8E1")
        assert r.returncode == 2 and "it is a pty, which cannot carry parity" in r.stderr
        r = drivebus("scan", pty, "-f", "8E1")
        assert r.returncode == 2 and "a pty cannot carry 8E1: nothing left to probe" in r.stderr
        # check --probe: a wrong address in the file is found and reported
        wrong = tmp_path / "wrong.toml"
        wrong.write_text(DEMO.read_text().replace("address = 3\n", "address = 5\n"))
        r = drivebus("check", wrong, "--probe")
        assert r.returncode == 1
        assert "axis y: no drive answers at address 5 at 19200 8E1; a BHSS answers at " \
               "address 3 at 19200 8E1" in r.stderr
        assert "axis x: NT86 answers at address 2 at 115200 8N1" in r.stdout


# -- commission: a drive's address and format, checked with mbpoll --------------------------------


async def _commission(wire: VirtualWire, twin: SimCL86R, *args: str) -> tuple[int, str]:
    """Run ``drivebus commission`` on the wire's pty; power-cycle the twin when told."""
    async with await anyio.open_process([*CLI, "commission", wire.slave_path, *args],
                                        stderr=subprocess.STDOUT) as proc:
        assert proc.stdout is not None
        out = b""
        with anyio.fail_after(60):
            async for chunk in proc.stdout:
                out += chunk
                if b"power-cycle" in chunk:
                    twin.power_cycle()
            await proc.wait()
    return proc.returncode or 0, out.decode()


async def test_commission_gives_a_drive_its_address_and_format() -> None:
    s8n1 = LineSettings.parse("38400 8N1")
    async with VirtualWire("commission") as wire:
        twin = wire.attach(SimCL86R(1, s8n1, soft_address=True))
        other = wire.attach(SimCL86R(9, s8n1))
        # another slave answers at the new address: refused, nothing written
        code, out = await _commission(wire, twin, "--drive", "CL86R", "--address", "1",
                                      "-S", "38400 8N1", "--to-address", "9", "--wait", "5")
        assert code == 1 and "another slave already answers at address 9" in out, out
        assert not [f for f in wire.log if f.direction == "request" and f.data[1] == 0x06]
        # where it answers already: nothing to change, refused with nothing sent at all (it
        # wrote the same address again and saved it, an EEPROM write for nothing)
        frames = wire.frames
        code, out = await _commission(wire, twin, "--drive", "CL86R", "--address", "1",
                                      "-S", "38400 8N1", "--to-address", "1")
        assert code == 2 and "nothing to change" in out and "address 1" in out, out
        assert wire.frames == frames
        # a free address and 8N2: written, saved, the drive answers there after power-up
        code, out = await _commission(wire, twin, "--drive", "CL86R", "--address", "1",
                                      "-S", "38400 8N1", "--to-address", "7",
                                      "--to-settings", "38400 8N2", "--wait", "20")
        assert code == 0, out
        assert "the CL86R answers at address 7 at 38400 8N2" in out
        assert (twin.address, str(twin.settings)) == (7, "38400 8N2")
        assert (twin.eeprom[0x0020], twin.eeprom[0x0021]) == (7, 1)
        # mbpoll, a third-party master, finds it at its new address and settings only
        r = await anyio.to_thread.run_sync(lambda: mbpoll(
            "-b", "38400", "-P", "none", "-s", "2", "-a", "7", "-r", "0", "-c", "2",
            wire.slave_path))
        assert mbpoll_values(r)[0] == 862
        r = await anyio.to_thread.run_sync(lambda: mbpoll(
            "-b", "38400", "-P", "none", "-s", "1", "-a", "1", "-r", "0", wire.slave_path,
            ok=False))
        assert r.returncode != 0
        assert other.address == 9
        # a drive set by DIP switches says so: a refusal, with nothing sent (exit status 2,
        # as for any command its drive cannot do)
        frames = wire.frames
        code, out = await _commission(wire, twin, "--drive", "NT86", "--address", "1",
                                      "--to-address", "3")
        assert code == 2 and "DIP switches" in out
        assert wire.frames == frames


# -- the CLI's option handling --------------------------------------------------------------------


def test_options_anywhere_and_misspelt_ones_named(tmp_path: Path) -> None:
    r = drivebus("read", "/dev/ttyDRIVEBUS-NONE", "1", "0", "--setings", "9600 8N1")
    assert r.returncode == 2
    assert "no such option --setings; did you mean --settings" in r.stderr
    r = drivebus("jog", SINGLE, "x", "-20", "--fro", "1")
    assert r.returncode == 2 and "did you mean --for?" in r.stderr
    r = drivebus("params", "dump", SINGLE, "x", "--outptu", "f")
    assert r.returncode == 2 and "did you mean --output?" in r.stderr
    with sim_server(SINGLE) as (_, ends):
        r = drivebus("read", ends["bus"], "1", "0", "-S", "115200 8N1", "--trace", "-v")
        assert r.returncode == 0, r.stderr
        assert len([x for x in r.stderr.splitlines() if "drivebus.trace" in x]) == 2
        # an exception reply: the slave answered (no "check power, wiring")
        r = drivebus("read", ends["bus"], "1", "20480", "-S", "115200 8N1")
        assert r.returncode == 1 and "the slave answered" in r.stderr
        assert "check power" not in r.stderr
        # --json: a failure is JSON on stdout too; a dead address included
        r = drivebus("read", ends["bus"], "17", "0", "-S", "115200 8N1", "--json",
                     "-t", "0.05")
        assert r.returncode == 1
        assert json.loads(r.stdout)["error"]["type"] == "ResponseTimeout"
        # broadcast writes are allowed
        r = drivebus("write", ends["bus"], "0", "49", "120", "-S", "115200 8N1")
        assert r.returncode == 0 and "every slave (broadcast, no reply)" in r.stdout
    # a target beyond the soft limits is a bad argument: exit 2, the error in the JSON
    r = drivebus("move", SINGLE, "x", "5000", "--json")
    assert r.returncode == 2
    assert "outside the soft limits" in json.loads(r.stdout)["error"]["message"]
    r = drivebus("--help")
    assert "Exit status: 0 done, 1 a runtime failure" in " ".join(r.stdout.split())


# -- /metrics -------------------------------------------------------------------------------------


async def test_metrics_are_written_out_a_line_per_step_of_the_event_loop() -> None:
    """``/metrics`` lets the loop's other tasks run between one line's slaves and the
    next (a machine of 16 lines of 8 drives took 15-24 ms to write out in one step, which
    held up every stop meanwhile): a task that counts its turns of the loop gets one at
    least per line while the exposition is written."""
    async with running() as (svc, _client):
        turns = 0
        written = False

        async def counter() -> None:
            nonlocal turns
            while not written:
                await anyio.lowlevel.checkpoint()
                turns += 1

        async with anyio.create_task_group() as tg:
            tg.start_soon(counter)
            await anyio.lowlevel.checkpoint()  # (the counter runs)
            before = turns
            text = await exposition(svc.session)
            during = turns - before
            written = True
        assert during >= len(svc.session.machine.buses) == 2, during
        assert text.endswith("\n") and "drivebus_axis_state{axis=\"aux\"" in text


async def test_metrics_are_scraped_and_parsed_by_prometheus_client() -> None:
    async with running() as (svc, client):
        bus = svc.session.machine.buses["rs485"]
        await until(svc, lambda: bus.stats.slave(2).latency.count >= 5)  # the axes' polls
        r = await client.get("/metrics")
        assert r.status_code == 200
        assert r.headers["content-type"].startswith("text/plain; version=0.0.4")
        families = await anyio.to_thread.run_sync(  # (the test's own parse: 10 ms and more)
            lambda: {f.name: f for f in text_string_to_metric_families(r.text)})
        tx = families["drivebus_transactions"]
        ok = [s for s in tx.samples if s.labels == {"line": "rs485", "slave": "2",
                                                     "outcome": "ok"}]
        assert ok and ok[0].value >= 5
        hist = families["drivebus_reply_latency_seconds"]
        assert hist.type == "histogram"
        count = next(s.value for s in hist.samples if s.name.endswith("_count")
                     and s.labels == {"line": "rs485", "slave": "2"})
        inf = next(s.value for s in hist.samples if s.name.endswith("_bucket")
                   and s.labels.get("slave") == "2" and s.labels["le"] == "+Inf")
        assert count == inf >= 5
        window = families["drivebus_reply_latency_window_seconds"]
        p50, p99 = (next(s.value for s in window.samples if s.labels["slave"] == "2"
                         and s.labels["quantile"] == q) for q in ("0.5", "0.99"))
        assert 0 < p50 <= p99 < 1
        states = families["drivebus_axis_state"]
        assert {s.labels["axis"] for s in states.samples} == {"x", "y", "z", "aux", "r"}
        snap = (await client.get("/api/lines/rs485")).json()
        assert snap["slaves"]["2"]["latency"]["p50_ms"] > 0
        # one master on the line: no other's requests heard (tests/test_one_master.py)
        assert (snap["foreign_requests"], snap["foreign_master"]) == (0, "")
        foreign = families["drivebus_line_foreign_requests"]
        assert {s.labels["line"]: s.value for s in foreign.samples
                if s.name.endswith("_total")} == {"rs485": 0, "eth": 0}
        # GET/PUT parameters through the service
        params = (await client.get("/api/axes/z/parameters")).json()
        assert params["family"] == "CL86R" and "microstep" in params["parameters"]
        r = await client.put("/api/axes/z/parameters",
                             json={"values": {"jog_speed": 99999}})
        assert r.status_code == 422 and "nothing written" in r.json()["detail"]
        r = await client.put("/api/axes/z/parameters", json={"values": {"jog_speed": 90},
                                                              "save": True})
        assert r.status_code == 200 and r.json()["written"] == ["jog_speed"]
        assert svc.session.machine.sim_drives["z"].eeprom[0x0046] == 90
