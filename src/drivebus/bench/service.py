"""Bench scenario "service": 50 WebSocket watchers and one commander on ``drivebus serve``.

The service (uvicorn in the machine's event loop, as ``drivebus serve`` runs it) masters
a simulated RS-485 line at 115200 8N1 with two NT86 axes and four more slaves that are
polled as fast as the bus allows: the line is saturated. The line is measured from the
wire's log, in turns: without clients (the 51 connections open but subscribed to
nothing and commanding nothing), then with 50 clients watching every axis over
``WS /api/ws`` and one jogging an axis back and forth over it, then the same with the
watchers at the dashboard's ``max_rate`` (20 states a second per axis); three rounds (one
under ``--quick``), medians reported. Reported: the line's efficiency without and with
them and the drop in points (target: at most 2), the status-update latency p50/p99 (from
the poll's reply to a watcher's receipt, on the system's monotonic clock), and the
service process's CPU.

The wire and the clients run in child processes of this module, as drives and clients
are other devices on a plant (``python -m drivebus.bench.service wire TURNAROUND`` and
``... clients URL CLIENTS``); the clients only use CPU time nobody else wants, since here
they share the machine's cores with the service and the wire.
"""

from __future__ import annotations

import asyncio
import json
import os
import statistics
import sys
import time
from collections.abc import AsyncIterator
from dataclasses import asdict
from types import TracebackType
from typing import Any

import anyio
import anyio.abc

from drivebus.bench.common import (
    S115200,
    BenchOptions,
    BenchResult,
    Scenario,
    percentile,
    poll_until,
    wire_figures,
)
from drivebus.config import parse_config
from drivebus.sim.machine import make_twin
from drivebus.sim.slave import RegisterSlave
from drivebus.sim.wire import VirtualWire

__all__ = ["SCENARIO", "service"]

WATCHERS = 50
DROP_TARGET = 2.0
"""Points of efficiency the watchers may cost at most."""
DASHBOARD_RATE = 20.0
"""The watchers' ``max_rate`` in the third case: what the dashboard asks for."""
POLLED = range(11, 15)
"""The slaves polled as fast as the bus allows, beside the two axes."""


def _machine(port: str, turnaround: float) -> dict[str, Any]:
    axis = {
        "line": "bench", "drive": "NT86", "settings": str(S115200), "pulses_per_rev": 4000,
        "units_per_rev": 10.0, "speed": 100.0, "accel": 1000.0, "decel": 1000.0,
        "limits": [-1000.0, 1000.0], "sim": {"position": 0.0, "turnaround": turnaround},
    }
    return {
        "name": "bench-service",
        "lines": {"bench": {"port": port, "settings": str(S115200)}},
        "axes": {"x": {**axis, "address": 1}, "y": {**axis, "address": 2}},
    }


class _Child:
    """A child process of this module, spoken to in lines on its stdin and stdout."""

    def __init__(self, *args: str) -> None:
        self.args = [sys.executable, "-m", "drivebus.bench.service", *args]

    async def __aenter__(self) -> _Child:
        self.proc = await anyio.open_process(self.args)
        assert self.proc.stdout is not None
        self._lines = _lines(self.proc.stdout)
        return self

    async def __aexit__(self, exc_type: type[BaseException] | None,
                        exc: BaseException | None, tb: TracebackType | None) -> None:
        with anyio.CancelScope(shield=True):
            if self.proc.stdin is not None:
                await self.proc.stdin.aclose()  # the child ends at the end of its input
            with anyio.move_on_after(10):
                await self.proc.wait()
            if self.proc.returncode is None:
                self.proc.kill()
            await self.proc.aclose()

    async def line(self) -> str:
        """The child's next line of output."""
        try:
            text = await anext(self._lines)
        except StopAsyncIteration:
            raise RuntimeError(f"bench child {self.args[3]}: ended early") from None
        if text.startswith("failed:"):
            raise RuntimeError(f"bench child {self.args[3]}: {text}")
        return text

    async def ask(self, command: str) -> str:
        """Send one command line; the answer line."""
        assert self.proc.stdin is not None
        await self.proc.stdin.send(f"{command}\n".encode())
        return await self.line()


async def _lines(stream: anyio.abc.ByteReceiveStream) -> AsyncIterator[str]:
    buf = b""
    async for chunk in stream:
        buf += chunk
        while b"\n" in buf:
            line, buf = buf.split(b"\n", 1)
            yield line.decode().strip()


async def service(seconds: float, turnaround: float, rounds: int = 3,
                  watchers: int = WATCHERS) -> list[BenchResult]:
    """``rounds`` turns of ``seconds`` without and with ``watchers`` + 1 commander."""
    from drivebus.service import open_service

    async with _Child("wire", str(turnaround)) as wire:
        config = parse_config(_machine(await wire.line(), turnaround), "bench service")
        async with open_service(config, port=0, stats_period=0.5) as svc:
            assert svc.url is not None
            handles = [svc.session.line("bench").slave(a) for a in POLLED]

            async def measure() -> dict[str, Any]:
                await wire.ask("clear")
                c0, t0 = time.process_time(), time.monotonic()
                await poll_until(handles, t0 + seconds)
                figures = dict(json.loads(await wire.ask("figures")))
                figures["cpu"] = (time.process_time() - c0) / (time.monotonic() - t0)
                return figures

            async with _Child("clients", svc.url, str(watchers)) as clients:
                await clients.line()  # connected
                await poll_until(handles, time.monotonic() + 0.2)  # warm-up
                alone, watched, thinned = [], [], []
                for _ in range(rounds):
                    alone.append(await measure())
                    await clients.ask("watch")
                    watched.append(await measure())
                    await clients.ask("idle")
                    await clients.ask(f"watch {DASHBOARD_RATE}")
                    thinned.append(await measure())
                    await clients.ask("idle")
                report = json.loads(await clients.ask("report"))

    def summary(runs: list[dict[str, Any]]) -> dict[str, Any]:
        return {
            "efficiency": statistics.median(r["efficiency"] for r in runs),
            "transactions": sum(r["transactions"] for r in runs),
            "violations": sum(r["violations"] for r in runs),
            "gap_p99_us": statistics.median(r["gap_p99_us"] for r in runs),
            "service_cpu_cores": statistics.median(r["cpu"] for r in runs),
            "rounds": len(runs),
        }

    def with_clients(runs: list[dict[str, Any]], figures: dict[str, Any]) -> dict[str, Any]:
        row = summary(runs)
        return {**row, "drop_points": (without["efficiency"] - row["efficiency"]) * 100,
                "drop_target_points": DROP_TARGET, "updates": figures["updates"],
                "update_p50_ms": figures["p50_ms"], "update_p99_ms": figures["p99_ms"],
                "jog_feeds": figures["feeds"]}

    without = summary(alone)
    return [
        BenchResult("service", "saturated line, no clients", without),
        BenchResult("service", f"+ {watchers} watchers, 1 commander",
                    with_clients(watched, report["as polled"])),
        BenchResult("service", f"+ {watchers} at max_rate {DASHBOARD_RATE:g}, 1 commander",
                    with_clients(thinned, report["thinned"])),
    ]


async def run(opts: BenchOptions) -> list[BenchResult]:
    """Three rounds of the timed run's length (quick: one round of half a second)."""
    if opts.quick:
        return await service(max(opts.seconds, 0.5), opts.turnaround, rounds=1)
    return await service(opts.seconds, opts.turnaround)


SCENARIO = Scenario("service", 70, run)


# -- the child processes -----------------------------------------------------------------------


async def _wire(turnaround: float) -> None:
    """The simulated line: the two NT86 twins and the polled slaves on a pty; prints its
    path, then answers ``clear`` (the wire log) and ``figures`` (JSON) until stdin ends."""
    config = parse_config(_machine("sim://bench-service", turnaround), "bench wire")
    line = config.lines["bench"]
    async with VirtualWire("bench-service") as wire:
        for axis in config.axes.values():
            wire.attach(make_twin(axis, line))
        for address in POLLED:
            wire.attach(RegisterSlave(address, S115200, size=16, turnaround=turnaround))
        print(wire.slave_path, flush=True)
        async for command in anyio.wrap_file(sys.stdin):
            if command.strip() == "clear":
                wire.clear_log()
                print("ok", flush=True)
            elif command.strip() == "figures":
                print(json.dumps(asdict(wire_figures(list(wire.log), turnaround))), flush=True)


class _Clients:
    """``n`` watchers and one commander over WS /api/ws, idle until told to watch."""

    def __init__(self, url: str, n: int) -> None:
        self.url = url.replace("http://", "ws://") + "/api/ws"
        self.n = n
        self.latencies: dict[str, list[float]] = {"as polled": [], "thinned": []}
        self.case = "as polled"
        self.feeds: dict[str, int] = {"as polled": 0, "thinned": 0}
        self.watching = False
        self.conns: list[Any] = []
        self.subscribed: list[asyncio.Event] = []
        self.jogging: asyncio.Task[None] | None = None

    async def watcher(self, k: int, connected: asyncio.Event) -> None:
        from websockets.asyncio.client import connect

        async with connect(self.url, max_queue=None, open_timeout=60) as ws:
            self.conns[k] = ws
            await ws.recv()  # hello
            connected.set()
            async for text in ws:
                now = time.monotonic()
                msg = json.loads(text)
                if msg["type"] == "axis" and self.watching and msg["timestamp"]:
                    self.latencies[self.case].append(now - msg["timestamp"])
                elif msg["type"] == "subscribed":
                    self.subscribed[k].set()

    async def subscribe(self, topics: list[str], max_rate: float | None = None) -> None:
        for event in self.subscribed:
            event.clear()
        for ws in self.conns:
            await ws.send(json.dumps({"subscribe": topics, "max_rate": max_rate}))
        await asyncio.gather(*(e.wait() for e in self.subscribed))

    async def jog(self, ws: Any) -> None:
        sign = 1.0
        while True:
            for _ in range(5):  # 0.5 s one way, fed every 100 ms
                await ws.send(json.dumps({"jog": {"axis": "x", "speed": 50.0 * sign,
                                                  "ttl": 0.5}}))
                self.feeds[self.case] += 1
                await asyncio.sleep(0.1)
            sign = -sign

    async def run(self) -> None:
        from websockets.asyncio.client import connect

        self.conns = [None] * self.n
        self.subscribed = [asyncio.Event() for _ in range(self.n)]
        connected = [asyncio.Event() for _ in range(self.n)]
        async with asyncio.TaskGroup() as tg, connect(self.url, open_timeout=60) as commander:
            await commander.recv()  # hello
            watchers = [tg.create_task(self.watcher(k, c)) for k, c in enumerate(connected)]
            await asyncio.wait_for(asyncio.gather(*(c.wait() for c in connected)), 60)
            print("connected", flush=True)
            while command := (await asyncio.to_thread(sys.stdin.readline)).strip():
                if command.startswith("watch"):
                    rate = float(command.split()[1]) if " " in command else None
                    self.case = "as polled" if rate is None else "thinned"
                    await self.subscribe(["axes"], rate)
                    self.watching = True
                    self.jogging = tg.create_task(self.jog(commander))
                    print("ok", flush=True)
                elif command == "idle":
                    self.watching = False
                    if self.jogging is not None:
                        self.jogging.cancel()
                    await commander.send(json.dumps({"jog": {"axis": "x", "speed": 0}}))
                    await self.subscribe([])
                    print("ok", flush=True)
                elif command == "report":
                    report = {}
                    for case, seconds in self.latencies.items():
                        ms = [x * 1e3 for x in seconds]
                        report[case] = {"updates": len(ms), "p50_ms": percentile(ms, 0.5),
                                        "p99_ms": percentile(ms, 0.99),
                                        "feeds": self.feeds[case]}
                    print(json.dumps(report), flush=True)
            for ws in self.conns:
                await ws.close()
            for task in watchers:
                task.cancel()


def _background() -> None:
    """Run on the CPU time others leave (on a plant, clients are other machines): the
    lowest share, not none (SCHED_IDLE got no CPU at all beside CPU-bound processes, and
    the clients' connections timed out)."""
    os.nice(19)


def main() -> None:
    """The child processes: ``wire TURNAROUND`` or ``clients URL CLIENTS``."""
    try:
        if sys.argv[1] == "wire":
            anyio.run(_wire, float(sys.argv[2]))
        else:
            _background()
            asyncio.run(_Clients(sys.argv[2], int(sys.argv[3])).run())
    except Exception as exc:  # the parent reads this line instead of the one it waits for
        causes = exc.exceptions if isinstance(exc, ExceptionGroup) else []
        detail = "".join(f"; {type(e).__name__}: {e}" for e in causes[:3])
        print(f"failed: {type(exc).__name__}: {exc}{detail}", flush=True)
        raise


if __name__ == "__main__":
    main()
