"""Recordings on the simulator: what ``machine.record`` keeps is what the twins did, and
its exports (CSV, JSONL, Parquet) read back to the same values with their units."""

from __future__ import annotations

import csv
import gc
import io
import json
from pathlib import Path
from typing import Any

import pytest

from drivebus import MotionEvent, Recording, open_machine
from drivebus.config import MachineConfig, parse_config
from drivebus.errors import ConfigError
from held_up import within_bound
from waits import within
from wirelog import frames_text

POLL = 0.01


def machine(name: str) -> MachineConfig:
    """Two CL86R axes in mm and one in degrees on one simulated line."""
    def axis(address: int, unit: str, units_per_rev: float, speed: float) -> dict[str, Any]:
        return {"line": "rs485", "address": address, "drive": "CL86R",
                "settings": "115200 8N1", "pulses_per_rev": 1000,
                "units_per_rev": units_per_rev, "unit": unit, "speed": speed,
                "accel": 10 * speed, "decel": 10 * speed, "limits": [-500.0, 500.0],
                "poll": {"moving": POLL, "idle": 0.05}}

    return parse_config({
        "name": name,
        "lines": {"rs485": {"port": f"sim://{name}", "settings": "115200 8N1",
                            "timeout": 0.05}},
        "axes": {"x": axis(1, "mm", 10.0, 100.0), "y": axis(2, "mm", 5.0, 40.0),
                 "r": axis(3, "deg", 360.0, 360.0)},
    })


async def test_a_recorded_move_follows_the_twin_within_one_poll_period() -> None:
    # A full garbage collection takes about 20 ms here, two poll periods: one falling in
    # the move would stall a poll past the window checked below. Collect first (the next
    # full collection then waits for the long-lived objects to grow by a quarter).
    gc.collect()
    async with open_machine(machine("rec-twin")) as m:
        x, twin = m.axes["x"], m.sim_drives["x"]
        async with m.record(axes=["x"]) as rec:
            # 2 s at 20 mm/s: polled every 10 ms, enough samples however late polls come
            await x.move_to(40.0, speed=20.0)
        trace = rec.axes["x"]
        moving = [s for s in trace.samples if s.moving]
        assert len(moving) >= 10, "a 2 s move polled every 10 ms gave too few samples"
        reads = [t for t in rec.lines["rs485"].transactions if t.slave == 1 and t.function == 3]
        for s in trace.samples:
            assert s.position is not None
            pulses = round(s.position / 10.0 * 1000)
            # The drive was read (one FC03: the CL86R's status) between the request and the
            # reply; the sample's time is when the reply was decoded, after it. So the twin
            # passed the recorded position between that read's start and the sample's time
            # (the move is monotonic: it lies between the twin's positions then). That
            # window is the read's own, however late the poll ran on a busy machine.
            # (an axis decodes one status before it reads the next: the last read that
            # ended by the sample's time is the one)
            read = max((t for t in reads if t.end <= s.time), key=lambda t: t.end)
            lo, hi = sorted((twin.position(read.start), twin.position(s.time)))
            assert lo - 1 <= pulses <= hi + 1, (s, read, lo, hi)
        # the samples carry the axis's units and its motion
        assert trace.unit == "mm"
        assert trace.samples[-1].position == pytest.approx(40.0)
        assert {s.state for s in moving} == {"DiscreteMotion"}
        assert all(s.target == pytest.approx(40.0) for s in moving)
        # the events, in order, with a planned and an observed arrival
        kinds = [e.kind for e in trace.events]
        assert kinds == ["accepted", "started", "in_position"]
        started, arrived = trace.events[1], trace.events[2]
        assert started.planned_end is not None and started.target == pytest.approx(40.0)
        assert started.time < arrived.time
        # the line's transactions: every one observed, none added by recording
        txs = rec.lines["rs485"].transactions
        bad = [t for t in txs if t.outcome != "ok" or t.slave not in (1, 2, 3)]
        assert txs
        assert bad == [], f"{bad[:3]}; the wire around the first:\n" + frames_text(
            m.wires["rs485"].log, bad[0].start - 0.1, bad[0].end + 0.1)  # type: ignore[union-attr]
        assert all(t.start <= t.end and t.latency is not None for t in txs)


async def test_recording_adds_no_transaction_and_keeps_bounded_rings() -> None:
    async with open_machine(machine("rec-ring")) as m:
        bus = m.buses["rs485"]
        y = m.axes["y"]
        async with m.record(max_samples=5, max_transactions=7) as rec:
            before = bus.stats.transactions
            await y.move_by(2.0)
            # more polls of y than the ring keeps, however few the short move got on a
            # busy machine (each status watched is at least one more poll)
            with within(10, "six more polls of axis y"):
                polls = 0
                async for _ in y.watch():
                    polls += 1
                    if polls == 6:
                        break
            during = bus.stats.transactions - before
        assert len(rec.axes["y"].samples) == 5
        assert len(rec.lines["rs485"].transactions) == 7
        assert rec.dropped.transactions == during - 7 > 0
        assert rec.dropped.samples > 0
        # after stop() nothing more is kept
        kept = len(rec.lines["rs485"].transactions), rec.dropped.transactions
        await y.move_by(-2.0)
        assert (len(rec.lines["rs485"].transactions), rec.dropped.transactions) == kept


async def test_unknown_axes_and_bad_sizes_are_refused() -> None:
    async with open_machine(machine("rec-bad")) as m:
        with pytest.raises(ConfigError, match="no axis 'w'"):
            m.record(axes=["x", "w"])
        with pytest.raises(Exception, match="max_samples"):
            m.record(max_samples=0)


async def recorded_group_move(name: str) -> Recording:
    async with open_machine(machine(name)) as m, m.record() as rec:
        await m.group("x", "y", "r").move_to({"x": 20.0, "y": -8.0, "r": 90.0})
        await m.axes["x"].move_to(25.0)
    return rec


async def test_exports_read_back_with_their_units(tmp_path: Path) -> None:
    rec = await recorded_group_move("rec-export")
    samples = rec.rows("samples")
    names = [c.name for c in rec.columns("samples")]
    assert names[:8] == ["time [s]", "axis", "position [mm]", "velocity [mm/s]",
                         "target [mm]", "position [deg]", "velocity [deg/s]", "target [deg]"]

    # CSV: the header names the units; values come back exactly
    for table in ("samples", "events", "transactions"):
        text = rec.to_csv(tmp_path / f"{table}.csv", table=table)
        assert (tmp_path / f"{table}.csv").read_text() == text
        rows = list(csv.reader(io.StringIO(text)))
        assert rows[0] == [c.name for c in rec.columns(table)]
        assert len(rows) - 1 == len(rec.rows(table)) > 0
    rows = list(csv.DictReader(io.StringIO(rec.to_csv())))
    for got, want in zip(rows, samples, strict=True):
        assert float(got["time [s]"]) == want[0] and got["axis"] == want[1]
        if want[1] == "r":
            assert float(got["position [deg]"]) == want[5] and got["position [mm]"] == ""
        else:
            assert float(got["position [mm]"]) == want[2] and got["position [deg]"] == ""

    # JSONL: a header with the units, and the whole recording back
    path = tmp_path / "run.jsonl"
    rec.to_jsonl(path)
    header = json.loads(path.read_text().splitlines()[0])
    assert header["axes"]["r"]["unit"] == "deg" and header["axes"]["x"]["unit"] == "mm"
    back = Recording.from_jsonl(path)
    for table in ("samples", "events", "transactions"):
        _same(back.rows(table), rec.rows(table))
    assert isinstance(back.axes["x"].events[0], MotionEvent)
    with pytest.raises(ConfigError, match="line 1"):
        Recording.from_jsonl('{"type": "header", "format": "other"}')

    # Parquet: typed columns, units in the fields' metadata, read by pyarrow
    pq = pytest.importorskip("pyarrow.parquet", reason="pyarrow is in the test extra")
    rec.to_parquet(tmp_path / "samples.parquet")
    table = pq.read_table(tmp_path / "samples.parquet")
    assert table.column_names == names
    field = table.schema.field("velocity [deg/s]")
    assert field.metadata == {b"unit": b"deg/s"}
    assert json.loads(table.schema.metadata[b"drivebus"])["axes"]["y"]["unit"] == "mm"
    got = table.to_pylist()
    assert [tuple(r.values()) for r in got] == samples
    rec.to_parquet(tmp_path / "tx.parquet", table="transactions")
    assert pq.read_table(tmp_path / "tx.parquet").num_rows == len(rec.rows("transactions"))


def _same(a: list[tuple[Any, ...]], b: list[tuple[Any, ...]]) -> None:
    """Rows equal (floats to 1e-12: a duration is recomputed from relative times)."""
    assert len(a) == len(b)
    for ra, rb in zip(a, b, strict=True):
        for va, vb in zip(ra, rb, strict=True):
            assert va == pytest.approx(vb, rel=1e-12, abs=1e-12) if isinstance(
                vb, float) else va == vb


@pytest.mark.serial  # planned ends within 20 ms of each other: CPU load from other tests
# moves the group's starts (and the ends planned from them) further apart
async def test_a_group_move_records_planned_and_observed_arrivals() -> None:

    async def recorded(attempt: int) -> float:
        rec = await recorded_group_move(f"rec-group-{attempt}")
        started = {e.axis: e for e in rec.events() if e.kind == "started"}
        arrived = {e.axis: e for e in rec.events() if e.kind == "in_position"}
        assert set(started) == set(arrived) == {"x", "y", "r"}
        for n in ("y", "r"):
            assert arrived[n].time >= started[n].time
        # one plan: the group's axes are planned to arrive together (within the group's
        # own tolerance and its start offsets' rounding), and each was seen arriving after
        # it; a held-up process (the twins' too) sends a start late, and its end with it
        ends = [started[n].planned_end or 0.0 for n in ("y", "r")]
        return max(ends) - min(ends) - 0.02

    await within_bound(recorded, "the recorded planned ends within 20 ms")
