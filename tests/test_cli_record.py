"""``drivebus record`` as a user runs it: a subprocess on the demo machine's simulator."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from drivebus import Recording

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "configs" / "demo.toml"


def drivebus(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "drivebus.cli", *map(str, args)],
                          cwd=ROOT, capture_output=True, text=True, timeout=120)


def test_record_writes_the_report_the_recording_and_a_picture(tmp_path: Path) -> None:
    html, jsonl, png = tmp_path / "run.html", tmp_path / "run.jsonl", tmp_path / "run.png"
    done = drivebus("record", DEMO, "x", "y", "--during", "move x 30 y 20",
                    "--during", "move-by x -5", "-o", html, "-o", jsonl, "--png", png,
                    "--local")
    assert done.returncode == 0, done.stderr
    assert f"wrote {html}" in done.stdout and "3 moves" in done.stdout
    page = html.read_text()
    assert "window.DRIVEBUS_REPORT" in page and "https://" not in page.split(
        "window.DRIVEBUS_REPORT")[1]
    rec = Recording.from_jsonl(jsonl)
    assert list(rec.axes) == ["x", "y"]
    arrived = [a for a in rec.arrivals() if a.outcome == "in_position"]
    assert [(a.axis, a.what) for a in arrived] == [
        ("x", "move to 30"), ("y", "move to 20"), ("x", "move by -5")]
    assert rec.axes["x"].samples[-1].position is not None
    assert abs(rec.axes["x"].samples[-1].position - 25.0) < 1e-9
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_record_refuses_bad_steps_and_outputs_before_opening_anything(tmp_path: Path) -> None:
    done = drivebus("record", DEMO, "--during", "fly x 3", "-o", tmp_path / "a.html")
    assert done.returncode == 2 and "not a step" in done.stderr
    done = drivebus("record", DEMO, "--during", "move x", "-o", tmp_path / "a.html")
    assert done.returncode == 2 and "AXIS VALUE pairs" in done.stderr
    done = drivebus("record", DEMO, "-o", tmp_path / "a.txt")
    assert done.returncode == 2 and ".html" in done.stderr
    done = drivebus("record", DEMO, "--during", "move w 3", "-o", tmp_path / "a.html",
                    "--local")
    assert done.returncode == 2 and "no axis 'w'" in done.stderr
    assert not (tmp_path / "a.html").exists()
