"""Views of a running machine shared by ``drivebus demo``, ``monitor`` and ``status``:
rich tables for terminals and plain lines for pipes and logs."""

from __future__ import annotations

from typing import Any

from rich.table import Table

from drivebus.motion import Axis, Machine
from drivebus.text import quantity

__all__ = ["axes_table", "axis_line", "axis_record", "slaves_table", "stats_lines"]


def _fmt(v: float | None, digits: int = 2) -> str:
    return "-" if v is None else f"{v:.{digits}f}"


def _unit(ax: Axis) -> str:
    return ax.config.unit


def _settings(m: Machine, ax: Axis) -> str:
    line = m.config.lines[ax.config.line]
    return "TCP" if line.kind == "tcp" else str(ax.config.settings or line.settings)


def _alarm(ax: Axis) -> str:
    """The drive's alarm, or why the axis is Offline or in ErrorStop."""
    st = ax.status
    if st is not None and st.alarm:
        return f"{st.alarm_code} {st.alarm_text}".strip()
    return "" if ax.error is None else str(ax.error)


def axes_table(m: Machine) -> Table:
    """A table of every axis (state, position, velocity, alarm) and per-line bus figures."""
    t = Table(title=f"drivebus: {m.config.name}", expand=False)
    for col in ("axis", "drive", "line", "settings", "state", "position", "velocity", "alarm"):
        t.add_column(col)
    for name, ax in m.axes.items():
        t.add_row(
            name,
            ax.profile.family,
            ax.config.line,
            _settings(m, ax),
            str(ax.state),
            quantity(ax.position, _unit(ax), 2, " "),
            quantity(ax.velocity, f"{_unit(ax)}/s", 2, " "),
            _alarm(ax),
        )
    for name, bus in m.buses.items():
        tot = bus.stats.total()
        t.add_row(
            f"[dim]line {name}", "", "", "", "", f"{bus.stats.transactions} tx",
            f"{bus.stats.utilisation:.0%} busy", f"{tot.errors} errors" if tot.errors else "",
        )
    return t


def slaves_table(m: Machine) -> Table:
    """Per-slave bus counters of every line: transactions, reply latency (p50/p99 of the
    last replies), retries, timeouts, CRC errors, exceptions and the last error."""
    t = Table(title="bus statistics per slave", expand=False)
    for col in ("line", "slave", "axis", "tx", "p50", "p99", "retries", "timeouts", "crc",
                "exc", "last error"):
        t.add_column(col)
    for line, address, axis, s in _slave_rows(m):
        t.add_row(
            line, str(address), axis, str(s.transactions), _ms(s.latency.quantile(0.5)),
            _ms(s.latency.quantile(0.99)), str(s.retries), str(s.timeouts),
            str(s.crc_errors), str(s.exceptions), s.last_error[:60],
        )
    return t


def _slave_rows(m: Machine) -> list[tuple[str, int, str, Any]]:
    names = {(a.config.line, a.config.address): n for n, a in m.axes.items()}
    rows = []
    for line, bus in m.buses.items():
        for address, s in sorted(bus.stats.slaves.items()):
            rows.append((line, address, names.get((line, address), ""), s))
    return rows


def axis_record(m: Machine, name: str) -> dict[str, Any]:
    """One axis as a JSON-able mapping (``drivebus status --json``)."""
    ax = m.axes[name]
    st = ax.status
    return {
        "axis": name,
        "drive": ax.profile.family,
        "line": ax.config.line,
        "address": ax.config.address,
        "settings": _settings(m, ax),
        "state": str(ax.state),
        "position": ax.position,
        "velocity": ax.velocity,
        "unit": _unit(ax),
        "enabled": None if st is None else st.enabled,
        "moving": None if st is None else st.moving,
        "homed": None if st is None else st.homed,
        "limit_negative": None if st is None else st.limit_negative,
        "limit_positive": None if st is None else st.limit_positive,
        "alarm": None if st is None or not st.alarm else _alarm(ax),
        "error": None if ax.error is None else {"type": type(ax.error).__name__,
                                                "message": str(ax.error)},
        "position_pulses": None if st is None else st.position,
    }


def axis_line(m: Machine, name: str) -> str:
    """One axis as a plain line for pipes and logs."""
    r = axis_record(m, name)
    flags = [k for k in ("enabled", "moving", "homed", "limit_negative", "limit_positive")
             if r[k]]
    alarm = f" alarm={r['alarm']}" if r["alarm"] else ""
    if r["error"] and not r["alarm"]:
        alarm = f" error={r['error']['message']!r}"
    return (
        f"{name}: {r['drive']} line={r['line']} address={r['address']} "
        f"settings={r['settings'].replace(' ', '-')} state={r['state']} "
        f"position={quantity(r['position'], r['unit'])} "
        f"velocity={quantity(r['velocity'], r['unit'] + '/s')} "
        f"flags={','.join(flags) or '-'}{alarm}"
    )


def stats_lines(m: Machine) -> list[str]:
    """Per-slave bus counters as plain lines."""
    return [
        f"line {line} slave {address}{f' ({axis})' if axis else ''}: tx={s.transactions} "
        f"retries={s.retries} timeouts={s.timeouts} crc={s.crc_errors} "
        f"exceptions={s.exceptions} latency_p50={_ms(s.latency.quantile(0.5))} "
        f"latency_p99={_ms(s.latency.quantile(0.99))}"
        + (f" last_error={s.last_error!r}" if s.last_error else "")
        for line, address, axis, s in _slave_rows(m)
    ]


def _ms(seconds: float | None) -> str:
    return "-" if seconds is None else f"{seconds * 1e3:.2f}ms"
