"""examples/drivebus.service: a unit systemd accepts, running `drivebus serve` as described.

The unit is parsed here in any case (sections, keys, the choices the docs state), and
checked by systemd itself (`systemd-analyze verify`, and `security --offline` for its
exposure) where systemd-analyze is installed.
"""

from __future__ import annotations

import configparser
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from waits import Deadline

ROOT = Path(__file__).resolve().parent.parent
UNIT = ROOT / "examples" / "drivebus.service"
SYSTEMD_ANALYZE = shutil.which("systemd-analyze")


def entries() -> dict[str, list[tuple[str, str]]]:
    """Every ``Key=Value`` of the unit by section, repeated keys kept, in order."""
    out: dict[str, list[tuple[str, str]]] = {}
    section = None
    for raw in UNIT.read_text().splitlines():
        line = raw.strip()
        if not line or line.startswith(("#", ";")):
            continue
        m = re.fullmatch(r"\[(\w+)\]", line)
        if m:
            section = m.group(1)
            out.setdefault(section, [])
            continue
        assert section is not None, f"{raw!r} comes before any section"
        key, sep, value = line.partition("=")
        assert sep and re.fullmatch(r"[A-Za-z]+", key), f"not a Key=Value line: {raw!r}"
        out[section].append((key, value))
    return out


def values(section: str, key: str) -> list[str]:
    return [v for k, v in entries()[section] if k == key]


def one(section: str, key: str) -> str:
    (v,) = values(section, key)
    return v


def test_configparser_reads_the_sections() -> None:
    parser = configparser.ConfigParser(strict=False, interpolation=None)
    parser.optionxform = str  # type: ignore[assignment,method-assign]  # keys keep their case
    parser.read_string(UNIT.read_text())
    assert parser.sections() == ["Unit", "Service", "Install"]
    assert parser["Install"]["WantedBy"] == "multi-user.target"


def test_it_runs_drivebus_serve_with_the_documented_arguments() -> None:
    cmd = one("Service", "ExecStart").split()
    assert cmd[0].endswith("/drivebus") and cmd[1] == "serve"
    assert cmd[2].endswith(".toml")
    for flag in ("--host", "--port", "--token-file"):
        assert flag in cmd
    token = cmd[cmd.index("--token-file") + 1]
    assert token == "${CREDENTIALS_DIRECTORY}/tokens"
    assert one("Service", "LoadCredential").startswith("tokens:")


def test_serial_ports_stay_reachable() -> None:
    assert one("Service", "SupplementaryGroups") == "dialout"
    assert one("Service", "User") != "root"
    assert values("Service", "PrivateDevices") in ([], ["no"])
    allowed = {v.split()[0] for v in values("Service", "DeviceAllow")}
    assert {"char-ttyUSB", "char-ttyS", "char-ttyACM"} <= allowed
    assert one("Service", "DevicePolicy") == "closed"


def test_restart_policy_and_watchdog_agree() -> None:
    assert one("Service", "Restart") == "on-failure"
    assert one("Service", "RestartSec")
    assert int(one("Unit", "StartLimitBurst")) > 1
    # drivebus serve notifies and feeds the watchdog (test below): the unit relies on both
    assert one("Service", "Type") == "notify" and one("Service", "NotifyAccess") == "main"
    assert one("Service", "WatchdogSec")


def test_serve_notifies_systemd_and_feeds_its_watchdog(tmp_path: Path) -> None:
    """`drivebus serve` under a notify socket, as systemd starts it: READY=1 once it
    serves, WATCHDOG=1 every WATCHDOG_USEC/2, STOPPING=1 on SIGTERM, then exit 0."""
    address = str(tmp_path / "notify")
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
        sock.bind(address)
        sock.settimeout(30)
        env = {**os.environ, "NOTIFY_SOCKET": address, "WATCHDOG_USEC": "200000"}
        env.pop("WATCHDOG_PID", None)
        drivebus = Path(sys.executable).with_name("drivebus")
        proc = subprocess.Popen([str(drivebus), "serve", str(ROOT / "configs" / "demo.toml"),
                                 "--port", "0"], env=env, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
        try:
            messages = [sock.recv(4096).decode()]
            assert messages[0].startswith("READY=1\nSTATUS=serving demo on http://127.0.0.1:")
            fed = Deadline(30, "three WATCHDOG=1 notifications")
            while sum(m == "WATCHDOG=1" for m in messages) < 3:  # fed, again and again
                if not fed.left():
                    raise fed.fail(messages[-5:])
                messages.append(sock.recv(4096).decode())
            proc.send_signal(signal.SIGTERM)
            stopping = Deadline(30, "STOPPING=1 after SIGTERM")
            while not messages[-1].startswith("STOPPING=1"):  # the watchdog is fed meanwhile
                if not stopping.left():
                    raise stopping.fail(messages[-5:])
                messages.append(sock.recv(4096).decode())
            assert proc.wait(timeout=30) == 0
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()


def _unit_for_systemd(tmp_path: Path) -> Path:
    """The unit with ExecStart pointing at this installation's drivebus (systemd checks
    that the command exists and is executable)."""
    drivebus = Path(sys.executable).with_name("drivebus")
    assert drivebus.exists(), f"{drivebus}: the drivebus command is not installed here"
    text = UNIT.read_text().replace("/opt/drivebus/bin/drivebus", str(drivebus))
    unit = tmp_path / "drivebus.service"
    unit.write_text(text)
    return unit


@pytest.mark.skipif(SYSTEMD_ANALYZE is None, reason="systemd-analyze is not installed")
def test_systemd_analyze_verify_finds_nothing(tmp_path: Path) -> None:
    unit = _unit_for_systemd(tmp_path)
    done = subprocess.run(
        [str(SYSTEMD_ANALYZE), "verify", "--man=no", str(unit)],
        capture_output=True, text=True, timeout=60,
    )
    # verify exits 0 even for unknown keys or bad values: it warns on stderr, naming the file
    warnings = [line for line in done.stderr.splitlines() if unit.name in line]
    assert done.returncode == 0 and not warnings, done.stderr


@pytest.mark.skipif(SYSTEMD_ANALYZE is None, reason="systemd-analyze is not installed")
def test_systemd_rates_the_hardening(tmp_path: Path) -> None:
    unit = _unit_for_systemd(tmp_path)
    done = subprocess.run(
        [str(SYSTEMD_ANALYZE), "security", "--offline=true", str(unit)],
        capture_output=True, text=True, timeout=60,
    )
    m = re.search(r"Overall exposure level for \S+: (\d+\.\d+)", done.stdout)
    if m is None and "--offline" in done.stderr:
        pytest.skip(f"this systemd-analyze cannot rate a unit file offline: {done.stderr}")
    assert m, done.stdout + done.stderr
    assert float(m.group(1)) <= 2.0, done.stdout  # systemd calls below 2.0-ish "OK"
