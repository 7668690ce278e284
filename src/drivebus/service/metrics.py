"""``GET /metrics``: the machine's bus and axis figures in Prometheus's text exposition
format (version 0.0.4), for Prometheus, Grafana Agent, VictoriaMetrics and the like.

Names follow Prometheus's conventions (the unit in the name, base units, ``_total``
counters, quantiles only on a summary) so that Grafana's defaults work:
``drivebus_transactions_total{line,slave,outcome}``, the reply latency as a histogram
``drivebus_reply_latency_seconds{line,slave}`` (``histogram_quantile()``) and the last
replies' quantiles as a summary ``drivebus_reply_latency_window_seconds``, retries, line
utilisation and wire time, the garbage collector's passes and longest pause (the event
loop is held meanwhile: ``drivebus.heap``), and each axis's position in a base unit
(``drivebus_axis_position_meters`` for an axis in mm, ``_radians`` for one in degrees,
``_revolutions`` of the motor for any other unit), state and whether it is online.
Hand-written: the format is a few lines of text, and drivebus takes no dependency for it.
With tokens, ``/metrics`` needs one (any scope), as every other route.
"""

# No ``from __future__ import annotations`` here: FastAPI reads the annotations at runtime.

import gc
import math
from collections.abc import Iterable
from typing import Annotated

import anyio.lowlevel
from fastapi import APIRouter, Depends, Request
from fastapi.responses import PlainTextResponse

from drivebus import heap
from drivebus.app import MachineSession
from drivebus.bus.stats import SlaveStats

__all__ = ["AXES_PER_STEP", "CONTENT_TYPE", "base_unit", "exposition", "install"]

CONTENT_TYPE = "text/plain; version=0.0.4; charset=utf-8"

_BASE_UNITS: dict[str, tuple[str, float]] = {
    **{u: ("meters", 1.0) for u in ("m", "meter", "meters", "metre", "metres")},
    **{u: ("meters", 1e-3) for u in ("mm", "millimeter", "millimeters", "millimetre",
                                     "millimetres")},
    "cm": ("meters", 1e-2),
    **{u: ("meters", 1e-6) for u in ("um", "µm", "μm", "micron", "microns")},
    **{u: ("meters", 0.0254) for u in ("in", "inch", "inches")},
    **{u: ("radians", math.pi / 180) for u in ("deg", "°", "degree", "degrees")},
    **{u: ("radians", 1.0) for u in ("rad", "radian", "radians")},
    **{u: ("radians", 2 * math.pi) for u in ("rev", "revs", "revolution", "revolutions",
                                              "turn", "turns")},
}
"""An axis unit (as machine files name them) -> the Prometheus base unit and its factor."""


def base_unit(unit: str, units_per_rev: float) -> tuple[str, float]:
    """The base unit an axis's position is exported in, and the factor from the axis's
    unit: metres or radians for the units known, else revolutions of the motor."""
    known = _BASE_UNITS.get(unit.strip().lower()) or _BASE_UNITS.get(unit.strip())
    return known if known is not None else ("revolutions", 1.0 / units_per_rev)

_OUTCOMES = (
    ("ok", lambda s: s.transactions - s.exceptions),
    ("exception", lambda s: s.exceptions),
    ("timeout", lambda s: s.timeouts),
    ("crc_error", lambda s: s.crc_errors),
    ("wrong_responder", lambda s: s.wrong_responder),
    ("connection_error", lambda s: s.connection_errors),
    ("line_noise", lambda s: s.line_noise),
    ("broadcast", lambda s: s.broadcasts),
)
"""Each outcome of a transaction attempt, from a slave's counters."""


def _label(value: object) -> str:
    return str(value).replace("\\", "\\\\").replace("\n", "\\n").replace('"', '\\"')


def _labels(**labels: object) -> str:
    if not labels:
        return ""
    return "{" + ",".join(f'{k}="{_label(v)}"' for k, v in labels.items()) + "}"


def _number(v: float) -> str:
    if v == float("inf"):
        return "+Inf"
    return repr(float(v)) if isinstance(v, float) else str(v)


class _Family:
    """One metric family: its help, type and samples."""

    def __init__(self, name: str, kind: str, help_text: str) -> None:
        self.name, self.kind, self.help = name, kind, help_text
        self.samples: list[str] = []

    def add(self, value: float, suffix: str = "", **labels: object) -> None:
        self.samples.append(f"{self.name}{suffix}{_labels(**labels)} {_number(value)}")

    def text(self) -> Iterable[str]:
        yield f"# HELP {self.name} {self.help}"
        yield f"# TYPE {self.name} {self.kind}"
        yield from self.samples


AXES_PER_STEP = 32
"""How many axes' figures are written in one step of the event loop."""


async def exposition(session: MachineSession) -> str:
    """The machine's figures as Prometheus text, a line's slaves (or ``AXES_PER_STEP``
    axes) per step of the event loop: a machine of 16 lines of 8 drives takes 15-24 ms
    of CPU to write out on a 2-core host, which in one step would hold up every stop."""
    tx = _Family("drivebus_transactions_total", "counter",
                 "Transaction attempts per slave by outcome (retries count again).")
    retries = _Family("drivebus_retries_total", "counter", "Retried attempts per slave.")
    latency = _Family("drivebus_reply_latency_seconds", "histogram",
                      "Reply latency per slave: end of the request to end of the reply.")
    window = _Family("drivebus_reply_latency_window_seconds", "summary",
                     "Reply latency per slave: quantiles of the last replies, sum and "
                     "count of all.")
    util = _Family("drivebus_line_utilisation_ratio", "gauge",
                   "Fraction of the time since the line opened that frames occupied it.")
    wire = _Family("drivebus_line_wire_seconds_total", "counter",
                   "Seconds the line carried frames.")
    foreign = _Family("drivebus_line_foreign_requests_total", "counter",
                      "Requests of another master heard on the line (one master per line).")
    positions = {base: _Family(f"drivebus_axis_position_{base}", "gauge", text) for base, text
                 in (("meters", "Position of a linear axis, metres."),
                     ("radians", "Position of a rotary axis, radians."),
                     ("revolutions", "Position of an axis in a unit of its own, "
                                     "motor revolutions."))}
    state = _Family("drivebus_axis_state", "gauge", "1 for the axis's PLCopen state.")
    online = _Family("drivebus_axis_online", "gauge", "1 while the axis's drive answers.")
    gc_passes = _Family("python_gc_collections_total", "counter",
                        "Passes of Python's garbage collector per generation.")
    gc_pause = _Family("drivebus_gc_pause_max_seconds", "gauge",
                       "Longest pass of the garbage collector per generation since the "
                       "service started: the event loop was held that long.")
    frozen = _Family("python_gc_frozen_objects", "gauge",
                     "Objects frozen at start-up, which the collector no longer scans.")
    for generation, figures in enumerate(gc.get_stats()):
        gc_passes.add(figures["collections"], generation=generation)
        gc_pause.add(heap.PAUSES.longest[generation], generation=generation)
    frozen.add(heap.frozen())
    m = session.machine
    for line, bus in list(m.buses.items()):
        util.add(bus.stats.utilisation, line=line)
        wire.add(bus.stats.wire_time, line=line)
        foreign.add(bus.stats.foreign_requests, line=line)
        for address, s in sorted(bus.stats.slaves.items()):
            _slave(tx, retries, latency, window, line, address, s)
        await anyio.lowlevel.checkpoint()
    for i, (name, ax) in enumerate(list(m.axes.items()), 1):
        if ax.position is not None:
            base, factor = base_unit(ax.config.unit, ax.config.units_per_rev)
            positions[base].add(ax.position * factor, axis=name)
        state.add(1, axis=name, state=str(ax.state))
        online.add(0 if str(ax.state) == "Offline" else 1, axis=name)
        if i % AXES_PER_STEP == 0:
            await anyio.lowlevel.checkpoint()
    families = (tx, retries, latency, window, util, wire, foreign,
                *(f for f in positions.values() if f.samples), state, online, gc_passes,
                gc_pause, frozen)
    return "\n".join(line for f in families for line in f.text()) + "\n"


def _slave(tx: _Family, retries: _Family, latency: _Family, window: _Family, line: str,
           address: int, s: SlaveStats) -> None:
    for outcome, count in _OUTCOMES:
        tx.add(count(s), line=line, slave=address, outcome=outcome)
    retries.add(s.retries, line=line, slave=address)
    for bound, n in s.latency.cumulative():
        latency.add(n, "_bucket", line=line, slave=address, le=_number(bound))
    latency.add(s.latency.sum, "_sum", line=line, slave=address)
    latency.add(s.latency.count, "_count", line=line, slave=address)
    for q in (0.5, 0.99):
        v = s.latency.quantile(q)
        if v is not None:
            window.add(v, line=line, slave=address, quantile=q)
    window.add(s.latency.sum, "_sum", line=line, slave=address)
    window.add(s.latency.count, "_count", line=line, slave=address)


def _session(request: Request) -> MachineSession:
    session: MachineSession = request.app.state.drivebus.session
    return session


def install(app_router: APIRouter, reader: object) -> None:
    """Add ``GET /metrics`` to ``app_router``, readable by whoever ``reader`` admits (the
    garbage collector's pauses are watched from now on)."""
    heap.PAUSES.install()

    @app_router.get("/metrics", tags=["machine"], response_class=PlainTextResponse)
    async def metrics(session: Annotated[MachineSession, Depends(_session)],
                      _: Annotated[object, Depends(reader)]) -> PlainTextResponse:
        """The bus and axis figures in Prometheus's text format."""
        return PlainTextResponse(await exposition(session), media_type=CONTENT_TYPE)
