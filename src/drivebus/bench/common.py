"""What every bench scenario shares: options, result records, wire-log figures, tables, JSON.

A scenario module (see ``drivebus.bench``) builds on these and nothing else of the
other scenarios, so scenarios can be added, changed or removed one module at a time.
"""

from __future__ import annotations

import asyncio
import gc
import itertools
import json
import statistics
import subprocess
import sys
import time
from collections.abc import Awaitable, Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any, Self

import anyio
import anyio.abc
from anyio.streams.buffered import BufferedByteReceiveStream

from drivebus.bus import Priority, SlaveHandle
from drivebus.clock import StolenSince
from drivebus.line.base import Exchange, Line
from drivebus.settings import LineSettings
from drivebus.sim.process import frame_from_record
from drivebus.sim.slave import RegisterSlave
from drivebus.sim.wire import WireFrame
from drivebus.timing import timing

__all__ = [
    "MIXED",
    "MIXED_PTY",
    "S9600",
    "S19200",
    "S38400",
    "S115200",
    "BenchOptions",
    "BenchResult",
    "ChildProcess",
    "Figure",
    "LoopSteps",
    "Scenario",
    "SimProcess",
    "StageFigures",
    "Target",
    "WireFigures",
    "at_least",
    "at_most",
    "format_table",
    "percentile",
    "poll_until",
    "record_exchanges",
    "register_slaves",
    "results_json",
    "stage_figures",
    "wire_figures",
    "wire_in_process",
]

S9600 = LineSettings.parse("9600 8N1")
S19200 = LineSettings.parse("19200 8E1")
S38400 = LineSettings.parse("38400 8N2")
S115200 = LineSettings.parse("115200 8N1")
MIXED = (S9600, S19200, S38400, S115200)
"""One slave at each of four settings: the per-slave reconfiguration case."""
MIXED_PTY = (S9600, LineSettings.parse("19200 8N2"), LineSettings.parse("38400 8N1"), S115200)
"""The mixed case with settings a pty carries to another process (rate and stop bits)."""

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
    plots: Path | None = None
    """Where the motion scenario writes its plots (an HTML report of its group moves,
    and a PNG where matplotlib is installed); None: none."""


@dataclass(frozen=True)
class Target:
    """What a figure should reach: at least (``">="``) or at most (``"<="``) ``value``."""

    op: str
    value: float

    def met(self, figure: Figure) -> bool | None:
        """Whether ``figure`` meets the target (None: not a number)."""
        if isinstance(figure, str) or figure != figure:  # text, or NaN
            return None
        return figure >= self.value if self.op == ">=" else figure <= self.value

    def __str__(self) -> str:
        return f"{'≥' if self.op == '>=' else '≤'} {self.value:g}"


def at_least(value: float) -> Target:
    """A figure that should be ``value`` or more."""
    return Target(">=", value)


def at_most(value: float) -> Target:
    """A figure that should be ``value`` or less."""
    return Target("<=", value)


@dataclass
class BenchResult:
    """One row of the bench's table: a scenario, the case it ran, its figures, and the
    target of those figures that have one."""

    scenario: str
    case: str
    figures: dict[str, Figure] = field(default_factory=dict)
    targets: dict[str, Target] = field(default_factory=dict)

    def missed(self) -> list[str]:
        """The figures that miss their target."""
        return [k for k, t in self.targets.items() if t.met(self.figures.get(k, "")) is False]


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


@dataclass
class StageFigures:
    """Where the time between a reply and the next request goes (medians, µs), from the
    wire's timestamps (another process) and the master's own, on the same clock."""

    reply_to_master_us: float
    """The reply's last byte on the wire until the master has it (pty, wake-up)."""
    master_late_us: float
    """The master's own lateness: its first byte out after its t3.5 from that moment."""
    request_to_wire_us: float
    """The master's write until the wire sees the request (pty, the wire's wake-up)."""


def record_exchanges(line: Line) -> list[Exchange]:
    """Keep every ``Exchange`` the line completes from now on (wraps its ``begin``, whose
    ``on_reply`` hears of every exchange, on a line that ``begins``; else ``transact``)."""
    kept: list[Exchange] = []
    if line.begins:
        begin = line.begin  # type: ignore[attr-defined]

        def recording_begin(*args: Any, on_reply: Any = None, **kwargs: Any) -> Any:
            def hook(ex: Exchange) -> None:
                kept.append(ex)
                if on_reply is not None:
                    on_reply(ex)

            return begin(*args, on_reply=hook, **kwargs)

        line.begin = recording_begin  # type: ignore[attr-defined]
        return kept
    transact = line.transact

    async def recording(*args: Any, **kwargs: Any) -> Exchange:
        ex = await transact(*args, **kwargs)
        kept.append(ex)
        return ex

    line.transact = recording  # type: ignore[method-assign]
    return kept


def stage_figures(frames: Sequence[WireFrame], exchanges: Sequence[Exchange]) -> StageFigures:
    """Match the master's exchanges to the wire's frames and split the silences."""
    requests = [i for i, f in enumerate(frames) if f.direction == "request"]
    reply_in: list[float] = []
    late: list[float] = []
    out: list[float] = []
    j = 0
    previous: tuple[WireFrame, Exchange] | None = None
    for ex in sorted(exchanges, key=lambda e: e.tx_start):
        if not ex.reply:
            previous = None
            continue
        while j < len(requests) and frames[requests[j]].start < ex.tx_start:
            j += 1
        if j >= len(requests):
            break
        i = requests[j]
        request = frames[i]
        reply = frames[i + 1] if i + 1 < len(frames) else None
        if previous is not None:
            prev_reply, prev_ex = previous
            reply_in.append((prev_ex.rx_end - prev_reply.end) * 1e6)
            late.append((ex.tx_start - prev_ex.rx_end - request.required) * 1e6)
            out.append((request.start - ex.tx_start) * 1e6)
        previous = (reply, ex) if reply is not None and reply.direction == "reply" else None

    def med(v: list[float]) -> float:
        return statistics.median(v) if v else float("nan")

    return StageFigures(med(reply_in), med(late), med(out))


async def poll_until(
    handles: Sequence[SlaveHandle], deadline: float, per_slave: int = 1, registers: int = 2
) -> None:
    """Read ``registers`` registers from every handle (``per_slave`` readers each) until
    ``deadline``."""

    async def poller(h: SlaveHandle) -> None:
        while time.monotonic() < deadline:
            await h.read_holding_registers(0, registers, priority=Priority.POLL)

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


class ChildProcess:
    """``python -m MODULE ARGS`` as a child process that prints where it serves on its
    first line, answers one command per line on stdin and ends when stdin closes."""

    def __init__(self, module: str, *args: str) -> None:
        self.args = [sys.executable, "-m", module, *args]
        self.first_line = ""
        """What the process printed first (where it serves)."""
        self._proc: anyio.abc.Process | None = None
        self._out: BufferedByteReceiveStream | None = None
        self.cpu = 0.0
        """The process's CPU seconds when it last answered ``log``."""

    @property
    def pid(self) -> int:
        """The child's process id (once entered)."""
        assert self._proc is not None
        return self._proc.pid

    async def __aenter__(self) -> Self:
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



class SimProcess(ChildProcess):
    """Simulated lines served by ``drivebus.sim.process`` in a child process.

    The master under test then shares its event loop and its CPU time with nothing of
    the simulator, and its figures come from the wire log of the other process (the wire's
    timestamps, shipped back by ``logs()``), never from the master's own bookkeeping.
    """

    def __init__(self, *args: str) -> None:
        super().__init__("drivebus.sim.process", *args)

    @classmethod
    def slaves(
        cls, n: int, settings: Sequence[LineSettings], turnaround: float, *, lines: int = 1,
        strict: bool = True, adapter_latency: float = 0.0,
    ) -> SimProcess:
        """``lines`` wires, each with slaves 1..``n`` (settings taken in turn); not
        ``strict``: they answer frames sent without the silence too; ``adapter_latency``:
        the master's adapter holds each reply until its latency timer ticks."""
        return cls("--slaves", str(n), "--settings", ",".join(str(s) for s in settings),
                   "--turnaround", repr(turnaround), "--lines", str(lines),
                   "--adapter-latency", repr(adapter_latency),
                   *(() if strict else ("--lenient",)))

    async def babble(self, mode: str) -> int:
        """A device on every wire sends junk (``mode``: "paced", "flat" or "off"); the
        noise bytes sent so far."""
        return int(json.loads(await self._ask(f"babble {mode}"))["noise_bytes"])

    @property
    def paths(self) -> list[str]:
        """The pty path of each wire (slave mode)."""
        return self.first_line.split()

    async def clear(self) -> None:
        """Every wire forgets its log."""
        await self._ask("clear")

    async def logs(self) -> dict[str, list[WireFrame]]:
        """Each wire's log, by wire (or line) name (``cpu`` holds the CPU seconds)."""
        text = await self._ask("log")
        # tens of thousands of frames: read them in a thread, so that the loop (and the
        # bench's longest-loop-step figure) is not held for tens of milliseconds
        self.cpu, logs = await anyio.to_thread.run_sync(_read_logs, text)
        return logs


def _read_logs(text: str) -> tuple[float, dict[str, list[WireFrame]]]:
    """The CPU seconds and each wire's frames from the simulator's JSON answer."""
    raw: dict[str, Any] = json.loads(text)
    cpu = float(raw.pop("cpu", 0.0))
    return cpu, {name: [frame_from_record(r) for r in frames] for name, frames in raw.items()}


def results_json(results: Sequence[BenchResult]) -> str:
    """The results as JSON text: each row's figures, targets (op and value) and the figures
    that missed theirs."""
    rows = []
    for r in results:
        row = asdict(r)
        row["missed"] = r.missed()
        rows.append(row)
    return json.dumps(rows, indent=2)


def _cell(v: Figure | None) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        if v != v:
            return "-"
        return f"{v:.3f}" if abs(v) < 10 else f"{v:.1f}" if abs(v) < 1000 else f"{v:.0f}"
    return str(v)


def format_table(results: Sequence[BenchResult]) -> str:
    """The results as plain-text tables, one per scenario: a column per figure, the
    targets in the row under the names, and ``!`` after a figure that misses its target;
    a row's ``note`` goes under the table as ``note=...``."""
    blocks: dict[str, list[BenchResult]] = {}
    for r in results:
        blocks.setdefault(r.scenario, []).append(r)
    out: list[str] = []
    for scenario, all_rows in blocks.items():
        out.append(f"\n== {scenario}")
        notes = [f"  {r.case}: note={r.figures['note']}" for r in all_rows if "note" in r.figures]
        rows = [r for r in all_rows if any(k != "note" for k in r.figures)]
        if not rows:
            out.extend(notes)
            continue
        names = list(dict.fromkeys(k for r in rows for k in r.figures if k != "note"))
        targets: dict[str, Target] = {}
        for r in rows:
            for k, t in r.targets.items():
                targets.setdefault(k, t)
        table = [["case", *names], ["target", *(str(targets.get(k, "")) for k in names)]]
        for r in rows:
            cells = [r.case]
            for k in names:
                cell = _cell(r.figures.get(k))
                t = r.targets.get(k)
                if t is not None and t.met(r.figures.get(k, "")) is False:
                    cell += "!"
                cells.append(cell)
            table.append(cells)
        widths = [max(len(row[i]) for row in table) for i in range(len(table[0]))]
        for row in table:
            out.append("  " + "  ".join(c.ljust(w) if i == 0 else c.rjust(w)
                                         for i, (c, w) in enumerate(zip(row, widths, strict=True))))
        out.extend(notes)
    return "\n".join(out)


class LoopSteps:
    """The longest event-loop step (thread CPU time) while installed: how long anything
    in this process held the loop, during which no stop could go out; and the longest
    pass of Python's garbage collector, which runs inside whatever step allocates (a full
    pass over a large heap is usually the longest step)."""

    def __init__(self) -> None:
        self.longest = 0.0
        self.longest_gc = 0.0
        self._run: Any = None
        self._gc_started = 0.0

    def _on_gc(self, phase: str, info: dict[str, Any]) -> None:
        if phase == "start":
            self._gc_started = time.thread_time()
        else:
            self.longest_gc = max(self.longest_gc, time.thread_time() - self._gc_started)

    def __enter__(self) -> LoopSteps:
        run = self._run = asyncio.events.Handle._run
        steps = self

        stolen = StolenSince()

        def timed(handle: asyncio.Handle) -> None:
            mark = stolen.mark()
            started = time.thread_time()
            try:
                run(handle)
            finally:
                took = time.thread_time() - started
                if took > steps.longest:
                    # (on a virtual machine, the time its hypervisor took the CPU away
                    # counts in the thread's clock: not the step's)
                    took -= stolen.since(mark)
                    if took > steps.longest:
                        steps.longest = took

        asyncio.events.Handle._run = timed  # type: ignore[method-assign]
        gc.callbacks.append(self._on_gc)
        return self

    def __exit__(self, *exc: object) -> None:
        gc.callbacks.remove(self._on_gc)
        asyncio.events.Handle._run = self._run  # type: ignore[method-assign]
