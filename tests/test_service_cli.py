"""``drivebus serve`` as a user runs it: a subprocess that serves the demo machine until
SIGTERM/SIGINT and stops every moving axis before it exits; refusals of unsafe setups."""

from __future__ import annotations

import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx
import pytest

from drivebus.errors import ConfigError
from drivebus.service import TokenStore, check_host, is_loopback
from service_rig import DEMO, TOKENS, auth, token_file

CLI = [sys.executable, "-m", "drivebus.cli"]


class Served:
    """A running ``drivebus serve`` subprocess; its stdout is read line by line."""

    def __init__(self, *args: str | Path) -> None:
        self.p = subprocess.Popen([*CLI, "serve", *map(str, args)], stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True)
        self.lines: queue.Queue[str] = queue.Queue()
        self.out: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.p.stdout is not None
        for line in self.p.stdout:
            self.lines.put(line.rstrip("\n"))

    def line(self, timeout: float = 30) -> str:
        """The next line of stdout."""
        text = self.lines.get(timeout=timeout)
        self.out.append(text)
        return text

    def url(self) -> str:
        first = self.line()
        assert first.startswith("drivebus serve: machine demo on http://127.0.0.1:"), first
        return first.split(" on ", 1)[1].split("/ ", 1)[0]

    def end(self, sig: signal.Signals) -> tuple[int, list[str], str]:
        """Send ``sig``; the exit status, the remaining stdout lines and stderr."""
        self.p.send_signal(sig)
        code = self.p.wait(timeout=60)
        assert self.p.stderr is not None
        err = self.p.stderr.read()
        rest = []
        while True:
            try:
                rest.append(self.line(timeout=5))
            except queue.Empty:
                break
            if rest[-1].startswith("drivebus serve: stopped") or "no axis" in rest[-1]:
                break
        return code, rest, err

    def kill(self) -> None:
        if self.p.poll() is None:
            self.p.kill()
            self.p.wait(timeout=10)


def wait_for(
    client: httpx.Client, axis: str, state: str, *, moving: bool = False
) -> dict[str, object]:
    """Poll GET /api/axes/AXIS until its state is ``state`` (and, with ``moving``, its
    drive is seen moving: the first command sets the drive up before it starts it)."""
    for _ in range(500):
        snap = client.get(f"/api/axes/{axis}").json()
        if snap["state"] == state and (snap.get("moving") or not moving):
            return dict(snap)
        time.sleep(0.02)
    raise AssertionError(f"axis {axis} never reached {state}")


def test_sigterm_stops_every_moving_axis_before_the_service_exits() -> None:
    served = Served(DEMO, "--port", "0")
    try:
        with httpx.Client(base_url=served.url(), timeout=30) as client:
            r = client.post("/api/axes/x/move", json={"target": 390.0, "speed": 20.0})
            assert r.status_code == 202, r.text
            assert client.post("/api/axes/r/move", json={"target": 700.0, "speed": 90.0}
                               ).status_code == 202
            assert client.post("/api/axes/z/jog", json={"speed": 2.0, "ttl": 10.0}
                               ).status_code == 200
            wait_for(client, "x", "DiscreteMotion", moving=True)
            wait_for(client, "r", "DiscreteMotion", moving=True)
            wait_for(client, "z", "ContinuousMotion", moving=True)
            code, rest, err = served.end(signal.SIGTERM)
        assert code == 0, err[-3000:]
        assert rest[0] == "drivebus serve: SIGTERM: stopping", rest
        last = rest[-1]
        # the process stopped the three moving axes (positions short of the targets), saw
        # every axis at rest in a poll after the stops, and asked the twins themselves
        assert last.startswith("drivebus serve: stopped "), last
        stopped = dict(part.split(" at ") for part in
                       last.removeprefix("drivebus serve: stopped ").split(";")[0].split(", "))
        assert set(stopped) == {"x", "r", "z"}, last
        assert float(stopped["x"]) < 390.0 and float(stopped["r"]) < 700.0
        assert last.endswith("every axis at rest (simulated twins checked)"), last
        with pytest.raises(httpx.ConnectError):  # and it is gone
            httpx.get(client.base_url.join("/api/machine"), timeout=5)
    finally:
        served.kill()


def test_the_served_process_freezes_its_start_up_heap_and_reports_its_gc_pauses() -> None:
    """``drivebus serve`` settles its heap before it says it is ready (``drivebus.heap``):
    /metrics shows tens of thousands of frozen objects, and the collector's passes and
    longest pause per generation."""
    served = Served(DEMO, "--port", "0")
    try:
        with httpx.Client(base_url=served.url(), timeout=30) as client:
            text = client.get("/metrics").text
            code, _, err = served.end(signal.SIGTERM)
        assert code == 0, err[-3000:]
    finally:
        served.kill()
    figures = dict(line.rsplit(" ", 1) for line in text.splitlines()
                   if line and not line.startswith("#"))
    assert int(figures["python_gc_frozen_objects"]) > 10_000
    for generation in range(3):
        assert float(figures[f'drivebus_gc_pause_max_seconds{{generation="{generation}"}}']) >= 0
        assert int(figures[f'python_gc_collections_total{{generation="{generation}"}}']) >= 0


def test_sigint_with_tokens_serves_only_authenticated_clients(tmp_path: Path) -> None:
    served = Served(DEMO, "--port", "0", "--token-file", token_file(tmp_path))
    try:
        with httpx.Client(base_url=served.url(), timeout=30) as client:
            assert client.get("/api/machine").status_code == 401
            assert client.get("/api/machine", headers=auth("viewer")).status_code == 200
            code, rest, err = served.end(signal.SIGINT)
        assert code == 0, err
        assert rest[-1] == "drivebus serve: no axis was moving; every axis at rest " \
                           "(simulated twins checked)", rest
        everything = "\n".join(served.out) + err
        assert not any(token in everything for _, token in TOKENS.values())  # never logged
    finally:
        served.kill()


def test_serving_beyond_loopback_without_tokens_is_refused() -> None:
    r = subprocess.run([*CLI, "serve", str(DEMO), "--host", "0.0.0.0"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2, r.stderr
    assert r.stderr.startswith("error: --host 0.0.0.0: refusing to serve beyond loopback "
                               "without authentication; give --token-file"), r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and r.stdout == ""


def test_a_bad_token_file_is_refused_naming_the_line_not_the_token(tmp_path: Path) -> None:
    p = tmp_path / "tokens.txt"
    p.write_text("ops command tooshort\n")
    r = subprocess.run([*CLI, "serve", str(DEMO), "--token-file", str(p)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and f"{p}:1: the token must be at least 16" in r.stderr
    assert "tooshort" not in r.stderr
    for text, needle in (("a read\n", "expected 'NAME SCOPE TOKEN'"),
                         ("a admin 0123456789abcdef0\n", "scope 'admin'"),
                         ("a read 0123456789abcdef0\na read 0123456789abcdefX\n", "twice"),
                         ("# nothing\n", "no tokens")):
        p.write_text(text)
        with pytest.raises(ConfigError, match=needle):
            TokenStore.load(p)
    with pytest.raises(ConfigError, match="cannot read"):
        TokenStore.load(tmp_path / "missing.txt")


def test_only_loopback_goes_without_tokens(tmp_path: Path) -> None:
    assert all(map(is_loopback, ("127.0.0.1", "127.0.0.2", "::1", "[::1]", "localhost")))
    assert not any(map(is_loopback, ("0.0.0.0", "::", "192.168.1.10", "cell7.plant")))
    for host in ("127.0.0.1", "localhost", "::1"):
        check_host(host, TokenStore())
    with pytest.raises(ConfigError, match=r"--host 0\.0\.0\.0: refusing"):
        check_host("0.0.0.0", TokenStore())
    check_host("0.0.0.0", TokenStore.load(token_file(tmp_path)))
