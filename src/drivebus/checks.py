"""Argument checks at the public edge: one place that turns a bad value into a typed error.

Every public call that takes a number (positions, speeds, register addresses and values)
checks it here before anything is queued or sent, so a NaN, an infinity, a fraction where a
whole number belongs or a negative speed never reaches a register codec or the wire.

Call arguments fail with ``ArgumentError``; the same checks serve settings (a bus's
response timeout, a profile's options) with ``error=ConfigError``. Messages name the
parameter, the value and what is allowed.
"""

from __future__ import annotations

import json
import math
import re
import sys
from collections.abc import Sequence
from enum import IntEnum
from numbers import Integral, Real
from typing import TYPE_CHECKING, Any, TypeVar, get_args, get_origin

from drivebus.errors import ArgumentError, ConfigError, DrivebusError

if TYPE_CHECKING:  # pydantic is loaded by what validates, not by these checks
    from pydantic import BaseModel, ValidationError

__all__ = [
    "MAX_JSON_DEPTH",
    "MAX_RETRIES",
    "MAX_TIMEOUT",
    "check_json_depth",
    "check_json_numbers",
    "finite",
    "load_json",
    "member",
    "positive",
    "response_timeout",
    "retry_count",
    "validation_problems",
    "whole",
    "words",
]

MAX_TIMEOUT = 10.0
"""Longest response timeout a slave may have, seconds (a longer one only hides a fault)."""
MAX_RETRIES = 10
"""Most retries a transaction may have."""

MAX_JSON_DEPTH = 32
"""Deepest nesting of arrays and objects taken in JSON from outside (an MQTT command, a
WebSocket message, an HTTP body). Python's parser fails at a depth that depends on its
version and on the stack (3.11 from about 1000 levels, 3.12 and 3.13 later, and in
different ways), so the depth is checked before it parses: the same answer everywhere."""

E = TypeVar("E", bound=IntEnum)



def finite(name: str, value: object, *, error: type[DrivebusError] = ArgumentError) -> float:
    """``value`` as a float if it is a finite real number; else ``error``."""
    if isinstance(value, bool) or not isinstance(value, Real):
        raise error(f"{name}: expected a number, got {value!r}")
    try:
        v = float(value)
    except OverflowError:  # an int beyond any float (its repr may be too long to make)
        raise error(f"{name}: a number beyond ±{sys.float_info.max:.4g}") from None
    if not math.isfinite(v):
        raise error(f"{name}: {value!r} is not a finite number")
    return v


def positive(
    name: str, value: object, *, unit: str = "", error: type[DrivebusError] = ArgumentError
) -> float:
    """``value`` as a float if it is finite and > 0; else ``error``."""
    v = finite(name, value, error=error)
    if v <= 0:
        tail = f" {unit}" if unit else ""
        raise error(f"{name}: must be > 0{tail}, not {value!r}")
    return v


def whole(
    name: str, value: object, lo: int, hi: int, *, error: type[DrivebusError] = ArgumentError
) -> int:
    """``value`` as an int if it is a whole number in ``lo..hi``; else ``error``."""
    if type(value) is int and lo <= value <= hi:
        return value  # the common case, without the numeric-tower checks
    if isinstance(value, bool) or not isinstance(value, Integral | Real):
        raise error(f"{name}: expected a whole number in {lo}..{hi}, got {value!r}")
    if isinstance(value, Integral):
        v = int(value)
    else:
        f = float(value)
        if not math.isfinite(f) or f != int(f):
            raise error(f"{name}: expected a whole number in {lo}..{hi}, got {value!r}")
        v = int(f)
    if not lo <= v <= hi:
        raise error(f"{name}: {v} is outside {lo}..{hi}")
    return v


def words(
    name: str, values: object, max_count: int, *, error: type[DrivebusError] = ArgumentError
) -> list[int]:
    """``values`` as a list of 1..``max_count`` 16-bit words (whole numbers 0..65535)."""
    if isinstance(values, str | bytes | bytearray) or not isinstance(values, Sequence):
        raise error(f"{name}: expected a sequence of register values, got {values!r}")
    if not 1 <= len(values) <= max_count:
        raise error(f"{name}: {len(values)} values, but 1..{max_count} are allowed")
    return [whole(f"{name}[{i}]", v, 0, 0xFFFF, error=error) for i, v in enumerate(values)]


def member(
    name: str, value: object, kind: type[E], *, error: type[DrivebusError] = ArgumentError
) -> E:
    """``value`` as a member of the int enum ``kind``; else ``error`` listing its members."""
    if type(value) is kind:
        return value  # type: ignore[return-value]  # a member already
    allowed = ", ".join(f"{m.name} ({m.value})" for m in kind)
    if isinstance(value, bool) or not isinstance(value, Integral):
        raise error(f"{name}: expected one of {allowed}, got {value!r}")
    try:
        return kind(int(value))
    except ValueError:
        raise error(f"{name}: expected one of {allowed}, got {value!r}") from None


def response_timeout(
    name: str, value: object, *, error: type[DrivebusError] = ConfigError
) -> float:
    """A response timeout: finite, > 0 and at most ``MAX_TIMEOUT`` seconds."""
    v = positive(name, value, unit="s", error=error)
    if v > MAX_TIMEOUT:
        raise error(f"{name}: {value!r} s is above the longest response timeout, "
                    f"{MAX_TIMEOUT:g} s")
    return v


MAX_GUARD = 1.0
"""The longest guard interval before a slave's frames, s."""


def guard_interval(name: str, value: object, *, error: type[DrivebusError] = ConfigError
                   ) -> float:
    """A guard interval: finite, 0..``MAX_GUARD`` seconds."""
    v = finite(name, value, error=error)
    if not 0 <= v <= MAX_GUARD:
        raise error(f"{name}: {value!r} s is outside 0..{MAX_GUARD:g} s")
    return v


def retry_count(name: str, value: object, *, error: type[DrivebusError] = ConfigError) -> int:
    """A retry count: a whole number 0..``MAX_RETRIES``."""
    return whole(name, value, 0, MAX_RETRIES, error=error)


def _key_path(loc: Sequence[int | str]) -> str:
    path = ""
    for part in loc:
        if part == "[key]":  # pydantic's marker for a bad dict key: the key itself is named
            continue
        path += f"[{part}]" if isinstance(part, int) else (f".{part}" if path else str(part))
    return path


def _allowed_keys(model: type[BaseModel] | None, loc: Sequence[int | str]) -> list[str]:
    """The keys the model allows where ``loc`` (ending in an unknown key) points."""
    from pydantic import BaseModel

    node: Any = model
    for part in loc[:-1]:
        if isinstance(node, type) and issubclass(node, BaseModel):
            field = _fields_by_key(node).get(str(part))
            node = field.annotation if field is not None else None
            args = get_args(node)
            if get_origin(node) is dict and args:
                node = ("dict", args[1])
            elif args:
                node = next((a for a in args if isinstance(a, type)
                             and issubclass(a, BaseModel)), None)
        elif isinstance(node, tuple):
            node = node[1]  # the value type of a dict, whatever the key
        else:
            return []
    if isinstance(node, type) and issubclass(node, BaseModel):
        return list(_fields_by_key(node))
    return []


def _fields_by_key(model: type[BaseModel]) -> dict[str, Any]:
    """A model's fields by the key a file writes: the alias where a field has one (the
    ``register`` of ``[alarms]``, not its Python name ``reg``)."""
    return {(f.alias or name): f for name, f in model.model_fields.items()}


def validation_problems(
    exc: ValidationError,
    *,
    model: type[BaseModel] | None = None,
    prefix: str = "",
    limit: int = 5,
) -> list[str]:
    """A pydantic ``ValidationError`` as ``key.path: what is wrong (got value)`` lines, one
    per problem (at most ``limit``, then a count); ``prefix`` goes before every key path.
    ``model`` (the validated model) lets an unknown key be answered with the keys allowed
    there."""
    from pydantic import BaseModel

    out = []
    for e in exc.errors(include_url=False)[:limit]:
        loc = tuple(e["loc"])
        msg = str(e["msg"]).removeprefix("Value error, ")
        value = e.get("input")
        if e["type"] != "missing" and not isinstance(value, dict | list | tuple | BaseModel):
            msg += f" (got {value!r})"
        if e["type"] == "extra_forbidden":
            allowed = _allowed_keys(model, loc)
            msg = f"unknown key, set to {value!r}" if "(got" in msg else "unknown key"
            msg += f" (allowed: {', '.join(allowed)})" if allowed else ""
        where = _key_path((prefix, *loc) if prefix else loc)
        out.append(f"{where}: {msg}" if where else msg)
    more = len(exc.errors()) - limit
    return out + ([f"and {more} more"] if more > 0 else [])


_PARENS = bytes.maketrans(b"[{]}", b"(())")
_NOT_BRACKETS = bytes(c for c in range(256) if c not in b"[]{}")


def _brackets(data: str | bytes) -> bytes:
    """The arrays' and objects' brackets of JSON ``data`` outside its strings, each as
    ``(`` or ``)`` (bytes operations only: fast on a large body)."""
    raw = data.encode("utf-8", "surrogatepass") if isinstance(data, str) else data
    if b'"' in raw:  # escaped backslashes, then escaped quotes, then every string's content
        unescaped = raw.replace(b"\\\\", b"").replace(b'\\"', b"")
        raw = b"".join(unescaped.split(b'"')[::2])
    return raw.translate(_PARENS, _NOT_BRACKETS)


def check_json_depth(name: str, data: str | bytes, *, max_depth: int = MAX_JSON_DEPTH) -> None:
    """``ArgumentError`` naming ``name`` if JSON ``data`` nests its arrays and objects
    deeper than ``max_depth`` (brackets inside strings do not count; text that leaves
    brackets open is judged by how many it leaves open). Balanced pairs are peeled a level
    at a time: a body of megabytes takes a fraction of what parsing it takes."""
    pairs = _brackets(data)
    if pairs.count(b"(") <= max_depth:
        return
    for _ in range(max_depth):
        peeled = pairs.replace(b"()", b"")
        if peeled == pairs:
            break
        pairs = peeled
    if b"()" in pairs or pairs.count(b"(") - pairs.count(b")") > max_depth:
        raise ArgumentError(f"{name}: JSON nested too deeply (more than {max_depth} levels)")


_MAX_INT_DIGITS = 309
"""The longest integer JSON from outside may hold: about the largest float's."""
_LONG_DIGITS = re.compile(rb"\d{%d,}" % (_MAX_INT_DIGITS + 1))


def check_json_numbers(name: str, data: bytes) -> None:
    """``ArgumentError`` naming ``name`` if JSON ``data`` holds a run of digits longer than
    any number a drive takes (for a parser that would fail on it without saying why:
    Python refuses integers of 4300 digits with a ``ValueError``)."""
    long = _LONG_DIGITS.search(data)
    if long is not None:
        raise ArgumentError(f"{name}: a number of {len(long.group())} digits is beyond any "
                            f"number a drive takes")


def load_json(name: str, text: str, *, max_depth: int = MAX_JSON_DEPTH) -> Any:
    """JSON ``text`` from outside as data, alike on every Python version: nested at most
    ``max_depth`` deep, no NaN or infinity; else ``ArgumentError`` naming ``name`` (e.g.
    "payload") and the problem."""
    check_json_depth(name, text, max_depth=max_depth)

    def no_constant(constant: str) -> Any:
        raise ArgumentError(f"{name}: {constant} is not a finite number (JSON has no "
                            f"{constant})")

    def integer(digits: str) -> int:
        if len(digits) > _MAX_INT_DIGITS:  # (Python refuses 4300 digits, a float 309)
            raise ArgumentError(f"{name}: an integer of {len(digits)} digits is beyond any "
                                f"number a drive takes")
        return int(digits)

    try:
        return json.loads(text, parse_constant=no_constant, parse_int=integer)
    except json.JSONDecodeError as exc:
        raise ArgumentError(f"{name}: not JSON ({exc.msg} at line {exc.lineno} column "
                            f"{exc.colno}): {text[:80]!r}") from None
