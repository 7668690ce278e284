"""The service's recordings, downloaded while the machine moves: the export of a long
recording (seconds of work: a service keeps 150 000 transactions a line) is made from a
copy in a worker thread, so a stop asked meanwhile reaches the wire before the download
ends; before, it ran on the event loop and every stop waited for it (promise 1)."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import anyio
import anyio.to_thread
import pytest

from drivebus.bus import Transaction
from drivebus.motion import Recording
from drivebus.motion.recording import Sample
from drivebus.service import report
from service_rig import moving, running
from wirelog import command_frames, log_size


async def _long(rec: Recording, transactions: int, samples: int) -> None:
    """Fill ``rec``'s rings as a long recording has them: made-up entries, in time order
    before what it has, on its first line and axis (made in a worker thread: the test's
    own setup, not to be taken for the service holding the loop)."""
    t0 = rec.started - 1000.0

    def entries() -> tuple[list[Transaction], list[Sample]]:
        return ([Transaction(1, 3, 1, t0 + i * 0.002, t0 + i * 0.002 + 0.001, 0.0009,
                             0.0004, "ok") for i in range(transactions)],
                [Sample(t0 + i * 0.01, i * 0.001, 10.0, "Moving", 100.0, True, False, None)
                 for i in range(samples)])

    made_transactions, made_samples = await anyio.to_thread.run_sync(entries)
    next(iter(rec.lines.values())).transactions.extendleft(reversed(made_transactions))
    next(iter(rec.axes.values())).samples.extendleft(reversed(made_samples))


STOP_WAIT = 30.0
"""How long the export waits for the stop, and the test for its frame, seconds."""


def _stops(m: Any, mark: int) -> list[float]:
    """When x's stop frames since ``mark`` went on the wire."""
    return [at for kind, at in command_frames(m, "x", mark) if kind == "stop"]


@pytest.mark.parametrize("what", ["jsonl", "report"])
async def test_a_stop_reaches_the_wire_while_a_long_recording_is_downloaded(
        what: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """x moves; a recording as long as a service keeps is downloaded (JSON lines, or its
    HTML report); a stop of x asked once the export has begun reaches the wire before the
    download is over, x's twin comes to rest, and the download holds every entry.

    The export, once begun, waits (bounded) until x's stop is on the wire: in a worker
    thread it lets the stop go first whatever the host's load (the report alone takes
    only some 100 ms); on the event loop it would hold the stop back until its bound ran
    out, and the stop would come after the download."""
    exporting = threading.Event()
    stop_on_wire = threading.Event()
    owner: Any = Recording if what == "jsonl" else report
    name = "to_jsonl" if what == "jsonl" else "report_html"
    export: Callable[..., Any] = getattr(owner, name)

    def marked(*args: Any, **kwargs: Any) -> Any:
        exporting.set()  # (the export has begun, wherever it runs)
        stop_on_wire.wait(STOP_WAIT)
        return export(*args, **kwargs)

    monkeypatch.setattr(owner, name, marked)
    async with running() as (svc, client):
        m = svc.session.machine
        r = await client.post("/api/recordings", json={"axes": ["x"]})
        rec_id = r.json()["id"]
        await _long(svc.session.recordings.get(rec_id).recording, 150_000, 30_000)
        await client.post("/api/axes/x/move", json={"target": 390.0, "speed": 20.0})
        await moving(svc, "x")
        mark = log_size(m, "x")
        done: list[float] = []

        async def download() -> None:
            path = "jsonl" if what == "jsonl" else "report"
            parts: list[bytes] = []
            async with client.stream("GET", f"/api/recordings/{rec_id}/{path}") as got:
                assert got.status_code == 200
                async for part in got.aiter_bytes():  # (as it comes: tens of megabytes)
                    parts.append(part)
            done.append(time.monotonic())
            def looked_at() -> tuple[int, int, bool]:  # (in a worker thread: the test's own)
                text = b"".join(parts).decode()
                return (text.count('"type": "transaction"'), text.count('"type": "sample"'),
                        text.rstrip().endswith("</html>"))

            transactions, samples, html = await anyio.to_thread.run_sync(looked_at)
            if what == "jsonl":
                assert transactions >= 150_000 and samples >= 30_000
            else:
                assert got.headers["content-type"].startswith("text/html") and html

        with anyio.fail_after(120):
            async with anyio.create_task_group() as tg:
                tg.start_soon(download)
                assert await anyio.to_thread.run_sync(exporting.wait, 60), \
                    "the export never began"
                try:
                    r = await client.post("/api/axes/x/stop")
                    assert r.status_code == 200
                    with anyio.move_on_after(STOP_WAIT):
                        while not _stops(m, mark):  # noqa: ASYNC110 (the wire log is polled)
                            await anyio.sleep(0.005)
                finally:
                    stop_on_wire.set()
        stops = _stops(m, mark)
        assert stops, "no stop of x on the wire"
        assert stops[0] < done[0], "the stop waited for the download"
        assert not m.sim_drives["x"].is_moving()


async def test_a_snapshot_keeps_what_was_recorded_while_the_recording_goes_on() -> None:
    """A snapshot is detached: what its recording records afterwards is not in it, and it
    exports what the recording held when it was taken."""
    async with running() as (svc, client):
        r = await client.post("/api/recordings", json={"axes": ["x"]})
        rec = svc.session.recordings.get(r.json()["id"]).recording
        await _long(rec, 1_000, 500)
        snap, same = rec.snapshot(), rec.snapshot()
        held = len(rec.axes["x"].samples)
        # (two copies of one moment: written out alike, in a worker thread)
        mine, its = await anyio.to_thread.run_sync(lambda: (snap.to_jsonl(), same.to_jsonl()))
        assert mine.split("\n")[1:] == its.split("\n")[1:] and mine.count("\n") > 1500
        await client.post("/api/axes/x/move", json={"target": 100.0, "speed": 50.0})
        await moving(svc, "x")
        await client.post("/api/axes/x/stop")
        assert len(rec.axes["x"].samples) > held == len(snap.axes["x"].samples) >= 500
        again = await anyio.to_thread.run_sync(snap.to_jsonl)
        assert len(Recording.from_jsonl(again).axes["x"].samples) == held
        assert snap.recording is False and rec.recording is True
