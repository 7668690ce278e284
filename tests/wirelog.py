"""The demo machine's wire logs read as commands: which frame started or stopped which
axis, and when (the simulator's own record of what went over each line)."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import anyio

from drivebus import AxisState
from drivebus.motion import Axis, Machine

__all__ = ["KINDS", "command_frames", "commands", "frames_text", "log_size", "reads_of",
           "request_pdus", "room", "settle", "write_frames", "write_requests"]


def _rtu_write(data: bytes) -> tuple[int, int] | None:
    """(register, value) of an FC06 RTU request frame, else None."""
    if len(data) >= 8 and data[1] == 0x06:
        return int.from_bytes(data[2:4], "big"), int.from_bytes(data[4:6], "big")
    return None


def _pdu_write(pdu: bytes) -> tuple[int, int] | None:
    """(register, value) of an FC06 PDU, else None."""
    if len(pdu) >= 5 and pdu[0] == 0x06:
        return int.from_bytes(pdu[1:3], "big"), int.from_bytes(pdu[3:5], "big")
    return None


def _nt_kind(reg: int, value: int) -> str | None:
    if reg == 18:
        return "start" if 1 <= value <= 4 else "stop" if value in (5, 6) else None
    if reg == 287 and value in (4, 5, 6):
        return "start"
    return None


def _bhss_kind(reg: int, value: int) -> str | None:
    if reg == 0x27 or (reg == 0x30 and value == 1):
        return "start"
    return "stop" if reg == 0x28 else None


def _cl86r_kind(reg: int, value: int) -> str | None:
    if reg != 0x36:
        return None
    if value & 0x60:
        return "stop"
    return "start" if value & 0x19 else None


KINDS: dict[str, Callable[[int, int], str | None]] = {
    "NT86": _nt_kind, "EPR60": _nt_kind, "BHSS": _bhss_kind, "CL86R": _cl86r_kind,
}


def commands(m: Machine, name: str, since: int = 0) -> list[str]:
    """The axis's start/stop commands on the wire, in wire order, from log index ``since``."""
    ax = m.axes[name]
    kind = KINDS[ax.profile.family]
    wire: Any = m.wires[ax.config.line]
    out: list[str] = []
    if ax.config.line == "eth":
        for req in wire.log[since:]:
            w = _pdu_write(req.pdu)
            k = kind(*w) if w and req.unit == ax.config.address else None
            if k:
                out.append(k)
        return out
    for f in list(wire.log)[since:]:
        if f.direction != "request" or f.address != ax.config.address:
            continue
        w = _rtu_write(f.data)
        k = kind(*w) if w else None
        if k:
            out.append(k)
    return out


def log_size(m: Machine, name: str) -> int:
    return len(m.wires[m.axes[name].config.line].log)  # type: ignore[union-attr]


async def settle(ax: Axis, timeout: float = 10.0) -> None:
    """Until the axis's actor has seen the drive at rest in a motion-free state."""
    with anyio.fail_after(timeout):
        async for st in ax.watch():
            if not st.moving and ax.state in (AxisState.STANDSTILL, AxisState.DISABLED):
                return


def room(ax: Axis, distance: float) -> float:
    """A target ``distance`` away from where the axis is, inside its soft limits."""
    pos = ax.position or 0.0
    lo, hi = ax.config.limits or (-math.inf, math.inf)
    return pos + distance if pos + distance < hi else pos - distance if pos - distance > lo \
        else (lo + hi) / 2


def command_frames(m: Machine, name: str, since: int = 0) -> list[tuple[str, float]]:
    """The axis's start/stop commands with the time each began to leave (RTU lines)."""
    ax = m.axes[name]
    kind = KINDS[ax.profile.family]
    wire: Any = m.wires[ax.config.line]
    out: list[tuple[str, float]] = []
    for f in list(wire.log)[since:]:
        if f.direction != "request" or f.address != ax.config.address:
            continue
        w = _rtu_write(f.data)
        k = kind(*w) if w else None
        if k:
            out.append((k, f.start))
    return out


def requests_between(m: Machine, line: str, after: float, before: float) -> int:
    """How many request frames began to leave on an RTU ``line`` in (after, before)."""
    wire: Any = m.wires[line]
    return sum(1 for f in list(wire.log)
               if f.direction == "request" and after < f.start < before)


_READS = (b"\x01", b"\x02", b"\x03", b"\x04")


def reads_of(m: Machine, name: str) -> list[float]:
    """When each read request (FC01-FC04) to the axis's address began to leave (RTU) or
    reached the server (TCP): its status polls."""
    ax = m.axes[name]
    wire: Any = m.wires[ax.config.line]
    if ax.config.line == "eth":
        return [r.received for r in list(wire.log)
                if r.unit == ax.config.address and r.pdu[:1] in _READS]
    return [f.start for f in list(wire.log)
            if f.direction == "request" and f.address == ax.config.address
            and f.data[1:2] in _READS]


def write_requests(m: Machine) -> list[str]:
    """Every request that writes (FC05/06/0F/10) on the lines of ``m`` so far (an RTU
    wire's log or a Modbus TCP simulator's), in hex: a refusal or a viewing command adds
    none."""
    out: list[str] = []
    for wire in m.wires.values():
        for f in list(wire.log):  # type: ignore[attr-defined]
            data = getattr(f, "data", None)
            if data is not None:
                if f.direction == "request" and len(data) > 1 and data[1] in (5, 6, 15, 16):
                    out.append(data.hex(" "))
            elif f.pdu and f.pdu[0] in (5, 6, 15, 16):
                out.append(f.pdu.hex(" "))
    return out


def write_frames(m: Machine) -> int:
    """How many ``write_requests`` the lines of ``m`` have carried so far."""
    return len(write_requests(m))


def request_pdus(wire: Any, since: float = -math.inf) -> list[bytes]:
    """The PDUs (address and CRC off) of an RTU wire's requests that started after
    ``since``, oldest first."""
    return [f.data[1:-2] for f in list(wire.log)
            if f.direction == "request" and f.start > since]


def frames_text(log: Any, after: float = -math.inf, before: float = math.inf,
                limit: int = 60) -> str:
    """The RTU wire log's frames in (after, before), the last ``limit`` of them, a line
    each (time, silence before it, direction, bytes, note): what a failing test shows."""
    frames = [f for f in list(log) if after < f.start < before][-limit:]
    return "\n".join(
        f"  {f.start:.6f} gap {f.gap * 1e3:8.3f} ms {f.direction:7} {f.data.hex(' ')}"
        f"{'  [' + f.note + ']' if f.note else ''}" for f in frames)
