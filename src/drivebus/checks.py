"""Argument checks at the public edge: one place that turns a bad value into ``ArgumentError``.

Every public call that takes a number (positions, speeds, register addresses and values)
checks it here before anything is queued or sent, so a NaN, an infinity, a fraction where a
whole number belongs or a negative speed never reaches a register codec or the wire.
"""

from __future__ import annotations

import math
from numbers import Integral, Real

from drivebus.errors import ArgumentError

__all__ = ["finite", "positive", "whole"]


def finite(name: str, value: object) -> float:
    """``value`` as a float if it is a finite real number; else ``ArgumentError``."""
    if isinstance(value, bool) or not isinstance(value, Real):
        raise ArgumentError(f"{name}: expected a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise ArgumentError(f"{name}: {value!r} is not a finite number")
    return v


def positive(name: str, value: object, *, unit: str = "") -> float:
    """``value`` as a float if it is finite and > 0; else ``ArgumentError``."""
    v = finite(name, value)
    if v <= 0:
        tail = f" {unit}" if unit else ""
        raise ArgumentError(f"{name}: must be > 0{tail}, not {value!r}")
    return v


def whole(name: str, value: object, lo: int, hi: int) -> int:
    """``value`` as an int if it is a whole number in ``lo..hi``; else ``ArgumentError``."""
    if isinstance(value, bool) or not isinstance(value, Integral | Real):
        raise ArgumentError(f"{name}: expected a whole number in {lo}..{hi}, got {value!r}")
    if isinstance(value, Integral):
        v = int(value)
    else:
        f = float(value)
        if not math.isfinite(f) or f != int(f):
            raise ArgumentError(f"{name}: expected a whole number in {lo}..{hi}, got {value!r}")
        v = int(f)
    if not lo <= v <= hi:
        raise ArgumentError(f"{name}: {v} is outside {lo}..{hi}")
    return v
