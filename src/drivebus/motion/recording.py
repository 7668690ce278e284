"""Recordings: what a machine's axes and lines did, kept for plots and exports.

``async with machine.record(axes=["x", "y"], bus=True) as rec:`` keeps, per axis, every
status its actor polls (time, position and velocity in the axis's units, state, target,
alarm) and its motion events (``MotionEvent``), and per line every transaction (time,
slave, function, duration, reply latency, outcome). It listens to what the actors and
the buses do anyway (``Axis.listen``, ``Bus.observe``): a recording adds no bus traffic.
Memory is bounded: each axis's samples and events and each line's transactions are
rings (``max_samples``, ``max_events``, ``max_transactions``); what a ring dropped is
counted in ``dropped``.

Three tables come out of a recording (``table=``): ``samples``, ``events`` and
``transactions``, with times in seconds since the recording started and each quantity's
unit in its column name (``position [mm]``; a machine with millimetres and degrees has
a column for each) or, in Parquet, in the field's metadata too. ``to_jsonl`` writes
everything with a header line and ``Recording.from_jsonl`` reads it back.
"""

from __future__ import annotations

import csv
import io
import json
import math
import time
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, Literal, Protocol

from drivebus.bus import Transaction
from drivebus.clock import monotonic
from drivebus.drives.status import DriveStatus
from drivebus.errors import ArgumentError, ConfigError
from drivebus.motion.events import MotionEvent

if TYPE_CHECKING:
    from drivebus.bus import Bus
    from drivebus.config import MachineConfig
    from drivebus.motion.axis import Axis


class Recorded(Protocol):
    """What a recording reads of the machine it records (a ``Machine``)."""

    config: MachineConfig
    axes: dict[str, Axis]
    buses: dict[str, Bus]

__all__ = [
    "FORMAT", "TABLES", "Arrival", "AxisTrace", "Column", "LineLoad", "LineTrace", "Recording",
    "Sample",
    "Table",
]

FORMAT = "drivebus-recording/1"
"""The JSONL header's ``format``: what ``from_jsonl`` reads."""

Table = Literal["samples", "events", "transactions"]
TABLES: tuple[Table, ...] = ("samples", "events", "transactions")


@dataclass(frozen=True, slots=True)
class Sample:
    """One polled status of one axis, in its user units."""

    time: float
    """When the status was read (monotonic s: the reply's arrival)."""
    position: float | None
    velocity: float | None
    state: str
    target: float | None
    """The target of the motion under way (None: none)."""
    moving: bool
    in_position: bool
    alarm: int | None
    """The drive's alarm code while it reports one (0 if it gives no code)."""


@dataclass
class AxisTrace:
    """What one axis did during a recording."""

    name: str
    unit: str
    line: str
    address: int
    drive: str
    samples: deque[Sample]
    events: deque[MotionEvent]

    def series(self, start: float) -> dict[str, list[Any]]:
        """The samples as columns, times in seconds since ``start`` (for plots)."""
        s = self.samples
        return {
            "t": [x.time - start for x in s],
            "position": [x.position for x in s],
            "velocity": [x.velocity for x in s],
            "target": [x.target for x in s],
            "state": [x.state for x in s],
        }


@dataclass
class LineTrace:
    """What one line carried during a recording."""

    name: str
    transactions: deque[Transaction]


@dataclass(frozen=True, slots=True)
class LineLoad:
    """A line's load in time bins: what a chart of its busyness shows."""

    t: list[float]
    """Each bin's start, seconds since the recording started."""
    utilisation: list[float]
    """Fraction of the bin the line carried frames."""
    rate: list[float]
    """Transactions per second."""
    latency: list[float | None]
    """Mean reply latency, seconds (None: no reply in the bin)."""


@dataclass(frozen=True, slots=True)
class Arrival:
    """One move: when it started, when its plan had it arrive, when a poll saw it there
    (seconds since the recording started; ``observed`` None: it did not arrive)."""

    axis: str
    what: str
    started: float
    planned: float | None
    observed: float | None
    outcome: str
    """``in_position``, or how it ended otherwise (``aborted``, ``error``)."""


@dataclass(frozen=True, slots=True)
class Column:
    """One column of an exported table: its name (with the unit), type and unit."""

    name: str
    type: Literal["float", "int", "str", "bool"]
    unit: str = ""


@dataclass
class _Counts:
    samples: int = 0
    events: int = 0
    transactions: int = 0


class Recording:
    """Samples, motion events and transactions of a machine, kept while recording.

    Made by ``Machine.record``; used as ``async with`` (or ``with``), or with
    ``start()``/``stop()``. A recording read back with ``from_jsonl`` is detached.
    """

    def __init__(
        self,
        machine: Recorded | None = None,
        axes: Iterable[str] | None = None,
        *,
        bus: bool = True,
        max_samples: int = 100_000,
        max_events: int = 10_000,
        max_transactions: int = 500_000,
    ) -> None:
        for what, n in (("max_samples", max_samples), ("max_events", max_events),
                        ("max_transactions", max_transactions)):
            if isinstance(n, bool) or not isinstance(n, int) or n < 1:
                raise ArgumentError(f"{what}: expected a whole number ≥ 1, got {n!r}")
        self.machine_name = "" if machine is None else machine.config.name
        self.started = monotonic()
        """When recording started (monotonic s): the tables' time zero."""
        self.started_wall = time.time()
        """The same moment as wall-clock time (Unix s)."""
        self.stopped: float | None = None
        self.axes: dict[str, AxisTrace] = {}
        self.lines: dict[str, LineTrace] = {}
        self.dropped = _Counts()
        """What the rings dropped (oldest first) because the recording ran long."""
        self.bus = bus
        self._max_samples, self._max_events = max_samples, max_events
        self._max_transactions = max_transactions
        self._machine = machine
        self._ends: list[Any] = []
        if machine is None:
            return
        names = list(machine.axes) if axes is None else list(axes)
        unknown = [n for n in names if n not in machine.axes]
        if unknown or not names:
            raise ConfigError(f"record: no axis {', '.join(map(repr, unknown)) or '(none named)'}"
                              f" (axes: {', '.join(machine.axes)})")
        for n in dict.fromkeys(names):
            a = machine.axes[n]
            self.axes[n] = AxisTrace(n, a.config.unit, a.config.line, a.config.address,
                                     a.profile.family, deque(maxlen=max_samples),
                                     deque(maxlen=max_events))
        if bus:
            for line in dict.fromkeys(t.line for t in self.axes.values()):
                self.lines[line] = LineTrace(line, deque(maxlen=max_transactions))

    # -- recording ---------------------------------------------------------------------------

    @property
    def recording(self) -> bool:
        """True between ``start()`` and ``stop()``."""
        return bool(self._ends)

    def start(self) -> Recording:
        """Begin listening to the axes and lines (time zero is reset to now)."""
        if self._machine is None:
            raise ConfigError("this recording was read from a file: it cannot record")
        if self._ends:
            return self
        self.started, self.started_wall, self.stopped = monotonic(), time.time(), None
        for trace in self.axes.values():
            axis = self._machine.axes[trace.name]
            self._ends.append(axis.listen(self._axis_listener(axis, trace)))
        for trace_ in self.lines.values():
            self._ends.append(self._machine.buses[trace_.name].observe(
                self._line_observer(trace_)))
        return self

    def stop(self) -> Recording:
        """Stop listening; what was recorded stays."""
        while self._ends:
            self._ends.pop()()
        if self.stopped is None:
            self.stopped = monotonic()
        return self

    def __enter__(self) -> Recording:
        return self.start()

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()

    async def __aenter__(self) -> Recording:
        return self.start()

    async def __aexit__(self, exc_type: type[BaseException] | None,
                        exc: BaseException | None, tb: TracebackType | None) -> None:
        self.stop()

    def _axis_listener(self, axis: Axis, trace: AxisTrace) -> Any:
        samples, events, dropped = trace.samples, trace.events, self.dropped

        def listener(item: DriveStatus | MotionEvent) -> None:
            if isinstance(item, MotionEvent):
                if len(events) == events.maxlen:
                    dropped.events += 1
                events.append(item)
                return
            if len(samples) == samples.maxlen:
                dropped.samples += 1
            samples.append(Sample(
                item.timestamp or monotonic(), axis.position, axis.velocity, str(axis.state),
                axis.target, item.moving, item.in_position,
                (item.alarm_code or 0) if item.alarm else None))

        return listener

    def _line_observer(self, trace: LineTrace) -> Any:
        ring, dropped = trace.transactions, self.dropped

        def observer(tx: Transaction) -> None:
            if len(ring) == ring.maxlen:
                dropped.transactions += 1
            ring.append(tx)

        return observer

    def snapshot(self) -> Recording:
        """A detached copy of what is recorded so far (its rings copied, their entries
        shared: they do not change): what an export reads away from the event loop while
        this recording goes on. Its end is now if this one still records."""
        copy = Recording(max_samples=self._max_samples, max_events=self._max_events,
                         max_transactions=self._max_transactions)
        copy.machine_name, copy.bus = self.machine_name, self.bus
        copy.started, copy.started_wall = self.started, self.started_wall
        copy.stopped = self.stopped if self.stopped is not None else monotonic()
        copy.axes = {n: replace(t, samples=deque(t.samples), events=deque(t.events))
                     for n, t in self.axes.items()}
        copy.lines = {n: LineTrace(n, deque(t.transactions)) for n, t in self.lines.items()}
        copy.dropped = replace(self.dropped)
        return copy

    # -- looking at it -----------------------------------------------------------------------

    @property
    def duration(self) -> float:
        """Seconds recorded (so far)."""
        return (self.stopped if self.stopped is not None else monotonic()) - self.started

    def events(self) -> list[MotionEvent]:
        """Every axis's events, in time order."""
        return sorted((e for t in self.axes.values() for e in t.events), key=lambda e: e.time)

    def arrivals(self) -> list[Arrival]:
        """Every move started while recording, with its planned and observed arrival (a
        group move: one per axis, planned to arrive together)."""
        out: list[Arrival] = []
        t0 = self.started
        for trace in self.axes.values():
            started: MotionEvent | None = None
            for e in trace.events:
                if e.kind == "started" and e.planned_end is not None:
                    started = e
                elif started is not None and e.kind in ("in_position", "aborted", "error"):
                    out.append(Arrival(
                        trace.name, started.what, started.time - t0,
                        None if started.planned_end is None else started.planned_end - t0,
                        e.time - t0 if e.kind == "in_position" else None, e.kind))
                    started = None
            if started is not None:
                out.append(Arrival(trace.name, started.what, started.time - t0,
                                   (started.planned_end or t0) - t0, None, "running"))
        return sorted(out, key=lambda a: a.started)

    def line_load(self, line: str, bin: float = 0.1) -> LineLoad:
        """``line``'s utilisation, transactions/s and mean reply latency per ``bin`` s."""
        if not bin > 0:
            raise ArgumentError(f"bin: expected seconds > 0, got {bin!r}")
        n = max(1, math.ceil(self.duration / bin))
        wire, count, replies, latency = [0.0] * n, [0] * n, [0] * n, [0.0] * n
        for tx in self.lines[line].transactions:
            i = min(n - 1, max(0, int((tx.start - self.started) / bin)))
            wire[i] += tx.wire_time
            count[i] += 1
            if tx.latency is not None:
                replies[i] += 1
                latency[i] += tx.latency
        return LineLoad(
            [i * bin for i in range(n)],
            [min(1.0, w / bin) for w in wire],
            [c / bin for c in count],
            [latency[i] / replies[i] if replies[i] else None for i in range(n)],
        )

    # -- tables ------------------------------------------------------------------------------

    def _units(self) -> list[str]:
        return list(dict.fromkeys(t.unit for t in self.axes.values()))

    def columns(self, table: Table = "samples") -> list[Column]:
        """The columns of ``table``, units in their names."""
        units = self._units()
        if table == "samples":
            return [Column("time [s]", "float", "s"), Column("axis", "str"),
                    *(c for u in units for c in (
                        Column(f"position [{u}]", "float", u),
                        Column(f"velocity [{u}/s]", "float", f"{u}/s"),
                        Column(f"target [{u}]", "float", u))),
                    Column("state", "str"), Column("moving", "bool"),
                    Column("in_position", "bool"), Column("alarm", "int")]
        if table == "events":
            return [Column("time [s]", "float", "s"), Column("axis", "str"),
                    Column("event", "str"), Column("what", "str"),
                    *(Column(f"target [{u}]", "float", u) for u in units),
                    Column("planned_end [s]", "float", "s"), Column("detail", "str")]
        if table == "transactions":
            return [Column("time [s]", "float", "s"), Column("line", "str"),
                    Column("slave", "int"), Column("function", "int"),
                    Column("priority", "int"), Column("duration [s]", "float", "s"),
                    Column("latency [s]", "float", "s"), Column("wire_time [s]", "float", "s"),
                    Column("outcome", "str")]
        raise ArgumentError(f"no table {table!r} (tables: {', '.join(TABLES)})")

    def rows(self, table: Table = "samples") -> list[tuple[Any, ...]]:
        """The rows of ``table`` in time order, matching ``columns(table)``."""
        units = self._units()
        t0 = self.started

        def per_unit(unit: str, values: Sequence[Any]) -> list[Any]:
            out: list[Any] = []
            for u in units:
                out += values if u == unit else [None] * len(values)
            return out

        if table == "samples":
            rows = [
                (s.time - t0, t.name, *per_unit(t.unit, (s.position, s.velocity, s.target)),
                 s.state, s.moving, s.in_position, s.alarm)
                for t in self.axes.values() for s in t.samples
            ]
        elif table == "events":
            rows = [
                (e.time - t0, e.axis, e.kind, e.what,
                 *per_unit(self.axes[e.axis].unit, (e.target,)),
                 None if e.planned_end is None else e.planned_end - t0, e.detail)
                for t in self.axes.values() for e in t.events
            ]
        else:
            self.columns(table)  # names the tables when ``table`` is none of them
            rows = [
                (x.start - t0, name, x.slave, x.function, x.priority, x.end - x.start,
                 x.latency, x.wire_time, x.outcome)
                for name, lt in self.lines.items() for x in lt.transactions
            ]
        rows.sort(key=lambda r: r[0])
        return rows

    # -- exports -----------------------------------------------------------------------------

    def to_csv(self, path: str | Path | None = None, table: Table = "samples") -> str:
        """``table`` as CSV (header: names with units; empty cell: no value); written to
        ``path`` if given. Floats are written exactly (``repr``)."""
        out = io.StringIO()
        w = csv.writer(out, lineterminator="\n")
        w.writerow([c.name for c in self.columns(table)])
        for row in self.rows(table):
            w.writerow(["" if v is None else repr(v) if isinstance(v, float) else v
                        for v in row])
        text = out.getvalue()
        if path is not None:
            Path(path).write_text(text)
        return text

    def header(self) -> dict[str, Any]:
        """What the recording is: machine, times, axes (units, drives), lines, tables."""
        return {
            "format": FORMAT,
            "machine": self.machine_name,
            "started": self.started_wall,
            "started_iso": time.strftime("%Y-%m-%dT%H:%M:%S%z", time.localtime(
                self.started_wall)),
            "duration": self.duration,
            "clock": "seconds since started",
            "axes": {n: {"unit": t.unit, "line": t.line, "address": t.address,
                         "drive": t.drive} for n, t in self.axes.items()},
            "lines": list(self.lines),
            "dropped": asdict(self.dropped),
            "units": {"time": "s", "position": "axis unit", "velocity": "axis unit/s",
                      "target": "axis unit", "duration": "s", "latency": "s",
                      "wire_time": "s"},
        }

    def to_jsonl(self, path: str | Path | None = None) -> str:
        """Everything as JSON lines: a header, then samples, events and transactions (each
        with ``"type"``), times in seconds since the start; ``from_jsonl`` reads it back."""
        t0 = self.started
        lines = [json.dumps({"type": "header", **self.header()})]
        dumps = json.dumps
        for t in self.axes.values():  # (fields read plainly: ``asdict`` costs 4x as much)
            lines += [dumps({"type": "sample", "axis": t.name,
                             **{n: getattr(s, n) for n in _SAMPLE_FIELDS},
                             "time": s.time - t0}) for s in t.samples]
            lines += [dumps({"type": "event", **_event_dict(e, t0)}) for e in t.events]
        for name, lt in self.lines.items():
            lines += [dumps({"type": "transaction", "line": name,
                             **{n: getattr(x, n) for n in _TRANSACTION_FIELDS},
                             "start": x.start - t0, "end": x.end - t0})
                      for x in lt.transactions]
        text = "\n".join(lines) + "\n"
        if path is not None:
            Path(path).write_text(text)
        return text

    @classmethod
    def from_jsonl(cls, source: str | Path) -> Recording:
        """A recording read back from ``to_jsonl``'s output: a path, or the text itself
        (a string that starts with ``{``). Its times start at 0."""
        text = source if isinstance(source, str) and source.startswith("{") else (
            Path(source).read_text())
        rec = cls()
        rec.started, rec.stopped = 0.0, None
        for number, line in enumerate(text.splitlines(), 1):
            if not line.strip():
                continue
            try:
                d = json.loads(line)
                kind = d.pop("type")
                if kind == "header":
                    if d.get("format") != FORMAT:
                        raise ValueError(f"format {d.get('format')!r}, expected {FORMAT}")
                    rec.machine_name, rec.started_wall = d["machine"], d["started"]
                    rec.stopped = d["duration"]
                    for n, a in d["axes"].items():
                        rec.axes[n] = AxisTrace(n, a["unit"], a["line"], a["address"],
                                                a["drive"], deque(), deque())
                    for n in d["lines"]:
                        rec.lines[n] = LineTrace(n, deque())
                    rec.dropped = _Counts(**d.get("dropped", {}))
                elif kind == "sample":
                    rec.axes[d.pop("axis")].samples.append(Sample(**d))
                elif kind == "event":
                    rec.axes[d["axis"]].events.append(MotionEvent(**d))
                elif kind == "transaction":
                    rec.lines[d.pop("line")].transactions.append(Transaction(**d))
                else:
                    raise ValueError(f"unknown record type {kind!r}")
            except (ValueError, KeyError, TypeError) as exc:
                raise ConfigError(f"recording line {number}: {exc}") from None
        return rec

    def to_parquet(self, path: str | Path, table: Table = "samples") -> None:
        """``table`` as Parquet (pandas, polars, DuckDB read it): typed columns, each
        field's unit in its metadata, the recording's header in the schema's. Needs
        pyarrow (``pip install drivebus[parquet]``)."""
        try:
            import pyarrow as pa
            import pyarrow.parquet as pq
        except ImportError:
            raise ConfigError("Parquet export needs pyarrow: pip install 'drivebus[parquet]'"
                              ) from None
        types = {"float": pa.float64(), "int": pa.int64(), "str": pa.string(),
                 "bool": pa.bool_()}
        cols = self.columns(table)
        schema = pa.schema(
            [pa.field(c.name, types[c.type], metadata={"unit": c.unit} if c.unit else None)
             for c in cols],
            metadata={"drivebus": json.dumps({**self.header(), "table": table})},
        )
        rows = self.rows(table)
        arrays = [pa.array([r[i] for r in rows], type=types[c.type])
                  for i, c in enumerate(cols)]
        pq.write_table(pa.Table.from_arrays(arrays, schema=schema), str(path))


_SAMPLE_FIELDS = tuple(f.name for f in fields(Sample))
_TRANSACTION_FIELDS = tuple(f.name for f in fields(Transaction))


def _event_dict(e: MotionEvent, t0: float) -> dict[str, Any]:
    d = asdict(e)
    d["time"] = e.time - t0
    if e.planned_end is not None:
        d["planned_end"] = e.planned_end - t0
    return d

