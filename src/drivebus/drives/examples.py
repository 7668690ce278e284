"""The manual's example frames as self-tests of a description (``[[examples]]``).

Each example is a frame the manual prints (a request, and where it prints one, the reply)
and what it stands for: registers written with values, registers read (and the values the
printed reply stands for), or a procedure with its arguments. ``verify_examples`` runs the
description's own engine against a recorder that answers as the printed replies say (and
echoes writes, zeros for other reads), and checks that the engine sends exactly the
printed bytes (the unit address and PDU; an RTU frame's printed CRC is checked too) and
decodes the printed reply to the printed values. Nothing reaches a wire.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import anyio

from drivebus.bus import Priority, SlaveHandle
from drivebus.drives.description import Description, ExampleDef
from drivebus.drives.engine import DescribedProfile, profile_class
from drivebus.drives.values import RegValue, Table
from drivebus.errors import DrivebusError, LimitViolation, ModbusException
from drivebus.line.rtu import crc16, crc_ok
from drivebus.pdu import LengthPredictor, ReplyDecoder

__all__ = ["ExampleResult", "Frame", "Recorder", "out_of_range_writes", "parse_frame",
           "verify_examples"]


@dataclass(frozen=True)
class Frame:
    """A printed frame: its unit address, its PDU and how it was framed."""

    unit: int
    pdu: bytes
    framing: str
    """"rtu" (address, PDU, CRC) or "tcp" (MBAP header, PDU)."""

    def rtu(self) -> str:
        """As an RTU frame, spaced hex."""
        body = bytes((self.unit,)) + self.pdu
        return (body + crc16(body)).hex(" ").upper()


def _bytes(text: str) -> bytes:
    tokens = [t for t in re.split(r"[\s,]+", text.strip()) if t]
    out = bytearray()
    for t in tokens:
        t = t.lower().removeprefix("0x").removesuffix("h")
        if len(t) % 2 or not re.fullmatch(r"[0-9a-f]+", t):
            raise ValueError(f"{text!r}: {t!r} is not hex bytes")
        out += bytes.fromhex(t)
    return bytes(out)


def parse_frame(text: str, protocol: str = "rtu", *, misprinted_crc: bool = False) -> Frame:
    """A printed frame: an RTU frame whose last two bytes are its CRC, or an MBAP frame
    (protocol id 0, its length field matching); ``ValueError`` saying which it is not
    (``misprinted_crc``: a wrong CRC is taken as the manual's misprint)."""
    data = _bytes(text)
    if len(data) >= 8 and data[2:4] == b"\0\0" and int.from_bytes(data[4:6], "big") == \
            len(data) - 6 and (protocol == "tcp" or not crc_ok(data)):
        return Frame(data[6], data[7:], "tcp")
    if len(data) < 4:
        raise ValueError(f"{text!r}: too short for a frame")
    if not crc_ok(data) and not misprinted_crc:
        body = data[:-2]
        raise ValueError(f"{text!r}: its CRC is {data[-2:].hex(' ').upper()}, the frame's "
                         f"is {crc16(body).hex(' ').upper()} (a misprint, or not an RTU "
                         f"frame)")
    return Frame(data[0], data[1:-2], "rtu")


@dataclass(frozen=True)
class ExampleResult:
    """One example verified: where it is, whether it holds, and what differed."""

    where: str
    ok: bool
    detail: str
    ran: bool = True
    """False for an erratum that stands for nothing the drive does (listed, not run)."""


class Recorder:
    """An executor that records every request and answers from the printed replies (and
    echoes writes, zeros for other reads)."""

    def __init__(self, replies: list[tuple[bytes, bytes]]) -> None:
        self.requests: list[tuple[int, bytes]] = []
        self._replies = replies

    async def execute(self, handle: SlaveHandle, pdu: bytes, *,
                      expect: LengthPredictor | None, priority: Priority,
                      idempotent: bool, decode: ReplyDecoder | None = None) -> Any:
        reply = self._answer(handle, pdu)
        return reply if decode is None else decode(reply, pdu, handle.address)

    def _answer(self, handle: SlaveHandle, pdu: bytes) -> bytes:
        self.requests.append((handle.address, pdu))
        for i, (request, reply) in enumerate(self._replies):
            if request == pdu:
                del self._replies[i]
                if reply[:1] and reply[0] & 0x80:
                    handle.raise_exception(reply, pdu)
                return reply
        fc = pdu[0]
        if fc in (3, 4):
            count = int.from_bytes(pdu[3:5], "big")
            return bytes((fc, 2 * count)) + bytes(2 * count)
        if fc in (1, 2):
            count = int.from_bytes(pdu[3:5], "big")
            return bytes((fc, (count + 7) // 8)) + bytes((count + 7) // 8)
        return pdu[:5]  # FC05/06 echo, FC16 address and count


def _same(value: Any, expected: Any) -> bool:
    if isinstance(value, RegValue):
        value = int(value)
    if isinstance(value, Table):
        return False
    if isinstance(expected, float) or isinstance(value, float):
        return isinstance(value, int | float) and math.isclose(
            float(value), float(expected), rel_tol=1e-9, abs_tol=1e-9)
    return bool(value == expected)


async def _run(d: Description, ex: ExampleDef, requests: list[Frame],
               replies: list[Frame]) -> tuple[list[tuple[int, bytes]], dict[str, Any]]:
    """The requests the engine sends for ``ex`` and what it read."""
    recorder = Recorder([(q.pdu, r.pdu) for q, r in zip(requests, replies, strict=False)])
    slave = SlaveHandle(recorder, requests[0].unit, settings=None, timeout=1.0, retries=0,
                        max_address=255)
    profile: DescribedProfile = profile_class(d)(  # type: ignore[call-arg]
        slave, pulses_per_rev=ex.pulses_per_rev or d.units.pulses_per_rev.default,
        **ex.options)
    values: dict[str, Any] = {}
    with anyio.fail_after(10):
        if ex.write is not None:
            await profile.write_values(ex.write, raw=ex.raw, block=ex.block)
        elif ex.read is not None:
            values = await profile._read_items(list(ex.read), None, Priority.CONFIG)
        else:
            assert ex.procedure is not None
            await profile.run(ex.procedure, **ex.args)
    return recorder.requests, values


def _check(d: Description, i: int, ex: ExampleDef) -> ExampleResult:
    where = f"examples[{i}]" + (f" ({ex.doc})" if ex.doc else "")
    misprint = bool(ex.erratum or ex.listed)  # a listed frame may carry a bad CRC on purpose
    try:
        requests = [parse_frame(f, d.link.protocol, misprinted_crc=misprint)
                    for f in ex.request]
        replies = [parse_frame(f, d.link.protocol, misprinted_crc=misprint)
                   for f in ex.reply]
    except ValueError as exc:
        return ExampleResult(where, False, str(exc))
    if ex.write is None and ex.read is None and ex.procedure is None:
        why = f"erratum: {ex.erratum}" if ex.erratum else ex.listed
        return ExampleResult(where, True, f"listed, not run: {why}", ran=False)
    try:
        sent, values = anyio.run(_run, d, ex, requests, replies)
    except ModbusException as exc:  # a printed exception reply: the drive refuses it
        printed = [r.pdu[1] for r in replies if r.pdu[:1] and r.pdu[0] & 0x80]
        if exc.code in printed:
            return ExampleResult(where, True, f"exception 0x{exc.code:02X} as printed: "
                                              f"{exc.text}")
        return ExampleResult(where, False, f"the engine refused it: {exc}")
    except (DrivebusError, ValueError, TypeError, TimeoutError) as exc:
        return ExampleResult(where, False, f"the engine refused it: {type(exc).__name__}: "
                                           f"{exc}")
    printed = [(f.unit, f.pdu) for f in requests]
    got = iter(sent)  # a procedure: the printed frames, in order, among its frames
    ok = sent == printed if ex.procedure is None else \
        all(any(p == s for s in got) for p in printed)
    if not ok:
        shown = "; ".join(Frame(u, p, "rtu").rtu() for u, p in sent) or "nothing"
        return ExampleResult(where, False, f"printed {'; '.join(f.rtu() for f in requests)}, "
                                           f"the engine sends {shown}")
    wrong = [f"{k} = {values.get(k)!r}, printed {v!r}" for k, v in ex.values.items()
             if not _same(values.get(k), v)]
    if wrong:
        return ExampleResult(where, False, "the reply decodes to " + "; ".join(wrong))
    n = len(requests)
    said = f"{n} frame{'s' * (n > 1)} as printed"
    if ex.erratum:
        said += f" (erratum: {ex.erratum})"
    if replies:
        said += f", {len(replies)} repl{'ies' if len(replies) > 1 else 'y'} decoded"
    return ExampleResult(where, True, said)


def verify_examples(d: Description) -> list[ExampleResult]:
    """Every ``[[examples]]`` entry of ``d``, verified against its engine (no I/O; not
    from inside an event loop: it runs its own)."""
    return [_check(d, i, ex) for i, ex in enumerate(d.examples)]


_WITHOUT_PARAMETERS = ("enable", "disable", "stop", "emergency_stop", "clear_alarm",
                       "zero_position", "save_parameters")
"""The common procedures whose writes need no argument: what they write is known now
(``setup`` and ``start_table`` write what the options and a prepared table say)."""


def out_of_range_writes(d: Description) -> list[str]:
    """The common procedures that take no argument, run dry on ``d``'s engine with its
    default options (as the axis runs them before their first frame; no I/O): each that
    writes a value outside its register's range, a constant the drive never takes, is
    named with the value (it would be refused every time it is called)."""
    slave = SlaveHandle(Recorder([]), 1, settings=None, timeout=1.0, retries=0,
                        max_address=255)
    try:
        profile: DescribedProfile = profile_class(d)(  # type: ignore[call-arg]
            slave, pulses_per_rev=d.units.pulses_per_rev.default)
    except DrivebusError:  # options it needs are not given: nothing to say without them
        return []
    out = []
    for name in _WITHOUT_PARAMETERS:
        proc = d.procedures.get(name)
        if proc is None or proc.unsupported is not None:
            continue
        try:
            profile.dry_run(name)
        except LimitViolation as exc:
            out.append(f"procedures.{name}: {exc}")
        except DrivebusError:  # not supported with these options, or needs the drive's
            continue           # answers: checked when it runs
    return out


def example_values(values: Mapping[str, Any]) -> str:
    """``key = value`` pairs, for texts."""
    return ", ".join(f"{k} = {v!r}" for k, v in values.items())
