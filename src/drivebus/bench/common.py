"""What every bench scenario shares: options, result records, wire-log figures, tables, JSON.

A scenario module (see ``drivebus.bench``) builds on these and nothing else of the
other scenarios, so scenarios can be added, changed or removed one module at a time.
"""

from __future__ import annotations

import itertools
import json
import statistics
import subprocess
import sys
import time
from collections.abc import Awaitable, Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from types import TracebackType
from typing import Any

import anyio
import anyio.abc
from anyio.streams.buffered import BufferedByteReceiveStream

from drivebus.bus import Priority, SlaveHandle
from drivebus.settings import LineSettings
from drivebus.sim.process import frame_from_record
from drivebus.sim.slave import RegisterSlave
from drivebus.sim.wire import WireFrame
from drivebus.timing import timing

__all__ = [
    "MIXED",
    "S9600",
    "S19200",
    "S38400",
    "S115200",
    "BenchOptions",
    "BenchResult",
    "Figure",
    "Scenario",
    "SimProcess",
    "WireFigures",
    "format_table",
    "percentile",
    "poll_until",
    "register_slaves",
    "results_json",
    "wire_figures",
    "wire_in_process",
]

S9600 = LineSettings.parse("9600 8N1")
S19200 = LineSettings.parse("19200 8E1")
S38400 = LineSettings.parse("38400 8N2")
S115200 = LineSettings.parse("115200 8N1")
MIXED = (S9600, S19200, S38400, S115200)
"""One slave at each of four settings: the per-slave reconfiguration case."""

Figure = float | int | str
"""One measured value in a result row."""


@dataclass(frozen=True)
class BenchOptions:
    """How long and how hard to run: the same for every scenario of one bench run."""

    quick: bool = False
    """Short runs with small counts (the test suite and ``drivebus bench --quick``)."""
    seconds: float = 3.0
    """Length of each timed run."""
    turnaround: float = 0.001
    """Simulated slaves' turnaround (request end to reply start)."""


@dataclass
class BenchResult:
    """One row of the bench's table: a scenario, the case it ran, and its figures."""

    scenario: str
    case: str
    figures: dict[str, Figure] = field(default_factory=dict)


@dataclass(frozen=True)
class Scenario:
    """A bench scenario as its module declares it (``SCENARIO = Scenario(...)``)."""

    name: str
    """The ``scenario`` of the rows it returns, and the name ``run_bench(only=...)`` takes."""
    order: int
    """Where it runs in a full bench: lower first (the built-in ones use 10..60)."""
    run: Callable[[BenchOptions], Awaitable[list[BenchResult]]]


def percentile(values: Sequence[float], q: float) -> float:
    """The ``q`` quantile (0..1) of ``values`` by nearest rank; NaN if there are none."""
    if not values:
        return float("nan")
    s = sorted(values)
    return s[min(len(s) - 1, int(q * (len(s) - 1) + 0.5))]


@dataclass
class WireFigures:
    """What the wire log says about one run."""

    transactions: int
    tps: float
    limit_tps: float
    efficiency: float
    gap_median_us: float
    gap_p99_us: float
    gap_max_us: float
    violations: int


def wire_figures(frames: Sequence[WireFrame], turnaround: float) -> WireFigures:
    """Achieved against ideal timing for the request/reply pairs in ``frames``."""
    pairs: list[tuple[WireFrame, WireFrame]] = []
    pending: WireFrame | None = None
    for f in frames:
        if f.direction == "request":
            pending = f
        elif pending is not None:
            pairs.append((pending, f))
            pending = None
    actual = ideal = 0.0
    excess: list[float] = []
    for (req, rep), (nxt, _) in itertools.pairwise(pairs):
        actual += nxt.start - req.start
        tm = timing(req.settings)
        ideal += tm.frame_time(len(req.data) + len(rep.data)) + turnaround + nxt.required
        excess.append((nxt.gap - nxt.required) * 1e6)
    n = len(pairs) - 1
    violations = sum(1 for f in frames if f.direction == "request" and f.violation)
    return WireFigures(
        transactions=len(pairs),
        tps=n / actual if actual else 0.0,
        limit_tps=n / ideal if ideal else 0.0,
        efficiency=ideal / actual if actual else 0.0,
        gap_median_us=statistics.median(excess) if excess else float("nan"),
        gap_p99_us=percentile(excess, 0.99),
        gap_max_us=max(excess) if excess else float("nan"),
        violations=violations,
    )


async def poll_until(handles: Sequence[SlaveHandle], deadline: float, per_slave: int = 1) -> None:
    """Read two registers from every handle (``per_slave`` readers each) until ``deadline``."""

    async def poller(h: SlaveHandle) -> None:
        while time.monotonic() < deadline:
            await h.read_holding_registers(0, 2, priority=Priority.POLL)

    async with anyio.create_task_group() as tg:
        for h in handles:
            for _ in range(per_slave):
                tg.start_soon(poller, h)


def register_slaves(
    n: int, settings: Sequence[LineSettings], turnaround: float
) -> list[RegisterSlave]:
    """Slaves 1..``n``, their settings taken in turn from ``settings``."""
    return [
        RegisterSlave(a, settings[(a - 1) % len(settings)], size=16, turnaround=turnaround)
        for a in range(1, n + 1)
    ]


@contextmanager
def wire_in_process(slaves: int, settings: LineSettings, turnaround: float) -> Iterator[str]:
    """A simulated wire in a child process; yields the pty path to open."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "drivebus.sim.process", "--slaves", str(slaves),
         "--settings", str(settings), "--turnaround", str(turnaround)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )
    try:
        assert proc.stdout is not None
        yield proc.stdout.readline().strip()
    finally:
        proc.communicate(timeout=10)


class SimProcess:
    """Simulated lines served by ``drivebus.sim.process`` in a child process.

    The master under test then shares its event loop and its CPU time with nothing of
    the simulator, and its figures come from the wire log of the other process (the wire's
    timestamps, shipped back by ``logs()``), never from the master's own bookkeeping.
    """

    def __init__(self, *args: str) -> None:
        self.args = [sys.executable, "-m", "drivebus.sim.process", *args]
        self.first_line = ""
        """What the process printed first: its pty paths, or JSON for ``--machine``."""
        self._proc: anyio.abc.Process | None = None
        self._out: BufferedByteReceiveStream | None = None

    @classmethod
    def slaves(
        cls, n: int, settings: Sequence[LineSettings], turnaround: float, *, lines: int = 1
    ) -> SimProcess:
        """``lines`` wires, each with slaves 1..``n`` (settings taken in turn)."""
        return cls("--slaves", str(n), "--settings", ",".join(str(s) for s in settings),
                   "--turnaround", repr(turnaround), "--lines", str(lines))

    @property
    def paths(self) -> list[str]:
        """The pty path of each wire (slave mode)."""
        return self.first_line.split()

    async def __aenter__(self) -> SimProcess:
        self._proc = await anyio.open_process(self.args, stderr=None)
        assert self._proc.stdout is not None
        self._out = BufferedByteReceiveStream(self._proc.stdout)
        try:
            self.first_line = await self._line()
        except BaseException:
            with anyio.CancelScope(shield=True):
                await self._end()
            raise
        return self

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        with anyio.CancelScope(shield=True):
            await self._end()

    async def _end(self) -> None:
        proc = self._proc
        if proc is None:
            return
        self._proc = None
        if proc.stdin is not None:
            await proc.stdin.aclose()  # the process ends when its stdin closes
        with anyio.move_on_after(10):
            await proc.wait()
            return
        proc.kill()
        await proc.wait()

    async def _line(self) -> str:
        assert self._out is not None
        with anyio.fail_after(30):
            data = await self._out.receive_until(b"\n", 1 << 30)
        return data.decode()

    async def _ask(self, command: str) -> str:
        assert self._proc is not None and self._proc.stdin is not None
        await self._proc.stdin.send(command.encode() + b"\n")
        return await self._line()

    async def clear(self) -> None:
        """Every wire forgets its log."""
        await self._ask("clear")

    async def logs(self) -> dict[str, list[WireFrame]]:
        """Each wire's log, by wire (or line) name."""
        raw: dict[str, Any] = json.loads(await self._ask("log"))
        raw.pop("cpu", None)
        return {name: [frame_from_record(r) for r in frames] for name, frames in raw.items()}


def results_json(results: Sequence[BenchResult]) -> str:
    """The results as JSON text."""
    return json.dumps([asdict(r) for r in results], indent=2)


def format_table(results: Sequence[BenchResult]) -> str:
    """The results as a plain-text table, one scenario per block."""
    lines: list[str] = []
    last = None
    for r in results:
        if r.scenario != last:
            lines.append(f"\n== {r.scenario}")
            last = r.scenario
        cells = ", ".join(
            f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}" for k, v in r.figures.items()
        )
        lines.append(f"  {r.case:<28} {cells}")
    return "\n".join(lines)
