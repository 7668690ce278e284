"""Commands as they arrive over MQTT: the payload parsed and checked before anything runs.

A command's body is a JSON object (an empty payload is ``{}``) whose keys depend on the
verb; ``id`` (a string or a number) is echoed in every reply. Anything that cannot be
taken as asked (not UTF-8, not JSON, NaN or infinity, not an object, an unknown verb or
key, a value of the wrong type) is an ``ArgumentError`` naming the problem: the bridge
answers it with a ``failed`` reply, never with silence. A ``halt`` is the exception: an
emergency stop of the axis, it is taken whatever its payload (its ``id`` where one can be
read), as the e-stop topics are and as the service's halt is.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any

from drivebus import checks
from drivebus.errors import ArgumentError
from drivebus.motion.handle import check_buffer

__all__ = ["MAX_PAYLOAD", "MAX_TTL", "VERBS", "Command", "parse_command", "peek_id"]

MAX_PAYLOAD = 16 * 1024
"""Longest command payload taken, bytes."""

MAX_TTL = 10.0
"""Longest jog watchdog, s: a jog over MQTT must be fed at least this often."""

_NUMBERS: dict[str, tuple[str, ...]] = {
    "move": ("target", "by", "speed", "accel", "decel"),
    "home": (),
    "jog": ("speed", "ttl", "accel", "decel"),
    "stop": ("decel",),
    "halt": (),
    "enable": (),
    "disable": (),
    "reset": (),
    "override": ("factor",),
    "set_output": (),
}
"""Each verb's numeric keys besides ``id``."""

_OTHERS: dict[str, dict[str, type]] = {"set_output": {"output": str, "state": bool}}
"""Verbs with keys that are not numbers: key -> type (every one required)."""

_MODES: dict[str, tuple[str, ...]] = {"move": ("buffer",)}
"""Verbs with an optional buffer mode (``Axis.move_to``'s ``buffer``; default aborting)."""

VERBS = tuple(_NUMBERS)
"""The axis command verbs."""

Id = str | int | float | None


@dataclass(frozen=True)
class Command:
    """One parsed axis command."""

    verb: str
    axis: str
    id: Id = None
    args: dict[str, float] = field(default_factory=dict)
    """The verb's numeric arguments that were given, each finite."""
    values: dict[str, Any] = field(default_factory=dict)
    """Its other arguments (``set_output``: ``output``, ``state``; ``move``: ``buffer``
    if given), each of its type."""


def _load(payload: bytes) -> Any:
    """The payload as JSON data (an empty payload is an empty object)."""
    if len(payload) > MAX_PAYLOAD:
        raise ArgumentError(f"payload: {len(payload)} bytes, at most {MAX_PAYLOAD} are taken")
    try:
        text = payload.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ArgumentError(f"payload: not UTF-8 text (byte {exc.start})") from None
    if not text.strip():
        return {}
    return checks.load_json("payload", text)


def _id(data: dict[str, Any]) -> Id:
    v = data.get("id")
    if v is None or (isinstance(v, str | int) and not isinstance(v, bool)):
        return v
    if isinstance(v, float) and math.isfinite(v):
        return v
    raise ArgumentError(f"id: expected a string or a number, got {v!r}")


def peek_id(payload: bytes) -> Id:
    """The ``id`` of a payload if it has a usable one, read leniently (a reply to a bad
    command echoes it whenever it can be found)."""
    if len(payload) > MAX_PAYLOAD:
        return None
    try:
        data = json.loads(payload.decode("utf-8"))
        return _id(data) if isinstance(data, dict) else None
    except (ValueError, RecursionError, ArgumentError):
        return None


def parse_command(axis: str, verb: str, payload: bytes) -> Command:
    """The command ``verb`` for ``axis`` from its payload; ``ArgumentError`` naming what
    is wrong."""
    if verb not in _NUMBERS:
        raise ArgumentError(f"unknown verb {verb!r} (verbs: {', '.join(VERBS)})")
    if verb == "halt":  # an emergency stop of the axis: never refused for its payload
        return Command(verb, axis, peek_id(payload))
    data = _load(payload)
    if not isinstance(data, dict):
        raise ArgumentError(f"payload: expected a JSON object, got {type(data).__name__} "
                            f"{data!r:.60}")
    cid = _id(data)
    allowed = _NUMBERS[verb]
    others = _OTHERS.get(verb, {})
    modes = _MODES.get(verb, ())
    unknown = sorted(k for k in data if k != "id" and k not in allowed and k not in others
                     and k not in modes)
    if unknown:
        keys = ", ".join(("id", *allowed, *others, *modes))
        raise ArgumentError(f"{verb}: unknown key {', '.join(map(repr, unknown))} "
                            f"(keys: {keys})")
    args = {k: checks.finite(k, data[k]) for k in allowed if data.get(k) is not None}
    if verb == "move" and ("target" in args) == ("by" in args):
        raise ArgumentError("move: give exactly one of 'target' and 'by'")
    if verb == "jog":
        if "speed" not in args:
            raise ArgumentError("jog: 'speed' is required (units/s, signed; 0 stops)")
        ttl = checks.positive("ttl", args.get("ttl", 1.0), unit="s")
        if ttl > MAX_TTL:
            raise ArgumentError(f"ttl: {ttl:g} s is above {MAX_TTL:g} s: a jog over MQTT "
                                f"must be fed at least that often")
        args["ttl"] = ttl
    for k in ("speed", "accel", "decel"):
        if k in args and not (verb == "jog" and k == "speed"):
            checks.positive(k, args[k])
    if verb == "override" and "factor" not in args:
        raise ArgumentError("override: 'factor' is required (0 < factor <= 2)")
    values: dict[str, Any] = {}
    for key, kind in others.items():
        v = data.get(key)
        if not isinstance(v, kind) or (kind is not bool and isinstance(v, bool)):
            raise ArgumentError(f"{verb}: {key!r} is required, a JSON "
                                f"{'boolean' if kind is bool else 'string'}, not {v!r}")
        values[key] = v
    for key in modes:
        if data.get(key) is not None:
            values[key] = check_buffer(data[key])
    return Command(verb, axis, cid, args, values)
