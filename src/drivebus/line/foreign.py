"""Another master on the line: requests among the bytes nobody asked for.

On an RS-485 line every node hears every frame. Bytes that arrive outside the replies a
master waits for are normally noise, or a slave's reply that came after its timeout. A
frame among them with a good CRC that parses as a complete, plausible *request* (a known
function code, a count and byte count the protocol allows) was sent by another master:
two masters on one line is a wiring or configuration fault, to be reported as such and
not as noise. Our own frames (an adapter that hears its own transmitter) and late replies
to our own requests (an FC05/FC06 reply is the request's echo) are not counted.

``find_requests`` is the decision, a pure function of the bytes and what we sent.
"""

from __future__ import annotations

from collections.abc import Collection

from drivebus.line.rtu import crc_ok
from drivebus.pdu import response_length

__all__ = ["SCAN_LIMIT", "describe_request", "find_requests"]

SCAN_LIMIT = 512
"""Bytes looked at per call at most (a receiver keeps no more): bounded work on a flood."""

_FUNCTIONS = {
    0x01: "read coils", 0x02: "read discrete inputs", 0x03: "read holding registers",
    0x04: "read input registers", 0x05: "write coil", 0x06: "write register",
    0x0F: "write coils", 0x10: "write registers",
}


def _request_length(data: bytes, i: int) -> int | None:
    """The length of the plausible request frame starting at ``data[i]`` (address to CRC),
    or None if none can start there."""
    n = len(data) - i
    if n < 8 or data[i] > 247:
        return None
    fc = data[i + 1]
    if fc not in _FUNCTIONS:
        return None
    count = data[i + 4] << 8 | data[i + 5]
    if fc in (0x01, 0x02):
        ok = 1 <= count <= 2000
    elif fc in (0x03, 0x04):
        ok = 1 <= count <= 125
    elif fc == 0x05:
        ok = count in (0x0000, 0xFF00)
    elif fc == 0x06:
        ok = True
    else:  # 0x0F, 0x10: a count and the byte count that goes with it
        if n < 9:
            return None
        bytes_needed = (count + 7) // 8 if fc == 0x0F else 2 * count
        limit = 1968 if fc == 0x0F else 123
        ok = 1 <= count <= limit and data[i + 6] == bytes_needed
        return 9 + bytes_needed if ok and n >= 9 + bytes_needed else None
    return 8 if ok else None


def find_requests(data: bytes, asked: Collection[tuple[int, int]] = ()) -> list[bytes]:
    """The request frames from another master in ``data`` (bytes received outside any
    reply), oldest first. ``asked`` holds the (address, function) of our own recent
    requests: a frame that is also a reply to one of them (a late reply, an echo) is
    ours, not a foreign request. A frame repeating the one just before it (a slave's echo
    of another master's write) counts once. Looks at the first ``SCAN_LIMIT`` bytes."""
    data = data[:SCAN_LIMIT]
    found: list[bytes] = []
    i = 0
    while i + 8 <= len(data):
        length = _request_length(data, i)
        if length is None or not crc_ok(data[i : i + length]):
            i += 1
            continue
        frame = data[i : i + length]
        i += length
        if (frame[0], frame[1]) in asked and response_length(frame[1:]) == length - 3:
            continue  # parses as a reply to one of ours too: a late reply or our echo
        if found and found[-1] == frame:
            continue  # the slave's echo of that write
        found.append(frame)
    return found


def describe_request(frame: bytes) -> str:
    """A request frame as a sentence part: "read holding registers 0x0000 (2) from slave 5"."""
    fc = frame[1]
    address = frame[2] << 8 | frame[3]
    value = frame[4] << 8 | frame[5]
    what = _FUNCTIONS.get(fc, f"function 0x{fc:02X}")
    to = "every slave (broadcast)" if frame[0] == 0 else f"slave {frame[0]}"
    if fc in (0x05, 0x06):
        return f"{what} 0x{address:04X} = 0x{value:04X} to {to}"
    return f"{what} 0x{address:04X} ({value}) {'from' if fc <= 4 else 'to'} {to}"
