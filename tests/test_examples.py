"""The example scripts run end to end on the simulator (as a user would run them)."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest

from waits import readline_within

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize(
    ("script", "last_line"),
    [("coordinated.py", "rectangle done"), ("service.py", "service done: x=120.00 y=80.00")],
)
def test_example_runs(script: str, last_line: str) -> None:
    proc = subprocess.run(
        [sys.executable, str(ROOT / "examples" / script)],
        capture_output=True, text=True, timeout=120, cwd=ROOT,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    lines = proc.stdout.strip().splitlines()
    assert lines[-1].startswith(last_line), proc.stdout[-2000:]
    if script == "coordinated.py":
        assert sum(line.startswith("corner") for line in lines) == 5
        assert "x=20.00 y=10.00 r=0.0" in lines[-2]
    else:
        assert any(line.startswith("jogger: z stopped") for line in lines)
        assert any("monitor: y is DiscreteMotion" in line for line in lines)


def test_pick_and_place_example_runs_on_a_copy_of_its_cell(tmp_path: Path) -> None:
    cell = tmp_path / "cell.toml"
    cell.write_text((ROOT / "examples" / "pick_and_place.toml").read_text())
    proc = subprocess.run(
        [sys.executable, str(ROOT / "examples" / "pick_and_place.py"), str(cell)],
        capture_output=True, text=True, timeout=180, cwd=ROOT,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    lines = proc.stdout.strip().splitlines()
    assert lines[-1] == "pick and place done: 3 parts", proc.stdout[-2000:]
    parts = [line for line in lines if line.startswith("part ")]
    assert len(parts) == 3 and all("placed at x=160.00 y=80.00" in p for p in parts)
    assert all("NT86 drive cannot take a new target" in p for p in parts)  # it says why
    assert "[positions.last_place]" in cell.read_text()  # taught, written back
    assert "# the feeder's nest" in cell.read_text()  # comments kept


def test_http_client_example_drives_a_running_service() -> None:
    served = subprocess.Popen(
        [sys.executable, "-m", "drivebus.cli", "serve", str(ROOT / "configs" / "demo.toml"),
         "--port", "0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
    )
    try:
        assert served.stdout is not None
        first = readline_within(served.stdout, 60, "drivebus serve's first line (its URL)")
        url = first.split(" on ", 1)[1].split("/ ", 1)[0]
        proc = subprocess.run(
            [sys.executable, str(ROOT / "examples" / "http_client.py"), url],
            capture_output=True, text=True, timeout=120, cwd=ROOT,
        )
        assert proc.returncode == 0, proc.stderr[-3000:]
        lines = proc.stdout.strip().splitlines()
        assert lines[0].startswith("machine demo: x=Standstill")
        assert sum(line.startswith("ws: ") for line in lines) == 5
        assert any(line.startswith("move m1 done: x at 120.00") for line in lines)
        assert any(line.startswith("refused: 422 LimitViolation") for line in lines)
        assert any(line.startswith("estop: ") and "x=at rest" in line for line in lines)
        assert "the long move ended aborted" in lines
        assert lines[-1] == "http client done: every axis at rest", proc.stdout
    finally:
        served.send_signal(signal.SIGTERM)
        assert served.wait(timeout=60) == 0
