"""The one timing calculator: character times and Modbus RTU silences for line settings."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

from drivebus.settings import LineSettings

__all__ = ["Timing", "switch_silence", "timing"]

_FIXED_ABOVE = 19200  # Modbus over serial line v1.02, 2.5.1.1: fixed t1.5/t3.5 above 19200 baud
_FIXED_T35 = 1.75e-3
_FIXED_T15 = 0.75e-3


@dataclass(frozen=True, slots=True)
class Timing:
    """Wire timing of one line setting, all in seconds."""

    settings: LineSettings
    bits_per_char: int
    char_time: float
    t15: float
    t35: float

    def frame_time(self, nbytes: int) -> float:
        """Time ``nbytes`` characters occupy the wire."""
        return nbytes * self.char_time

    def transaction_time(self, request: int, response: int, turnaround: float) -> float:
        """Wire limit of one transaction: request + turnaround + response + t3.5."""
        return (request + response) * self.char_time + turnaround + self.t35


_by_id: dict[int, Timing] = {}


def timing(settings: LineSettings) -> Timing:
    """Timing for ``settings`` (cached per settings object; they are frozen)."""
    t = _by_id.get(id(settings))
    if t is not None and t.settings is settings:
        return t
    t = _compute(settings)
    if len(_by_id) > 4096:
        _by_id.clear()
    _by_id[id(settings)] = t  # t.settings keeps the object, so its id stays unique
    return t


@lru_cache(maxsize=256)
def _compute(settings: LineSettings) -> Timing:
    bits = 1 + settings.bytesize + (0 if settings.parity == "N" else 1) + settings.stopbits
    char = bits / settings.baudrate
    if settings.baudrate > _FIXED_ABOVE:
        t15, t35 = _FIXED_T15, _FIXED_T35
    else:
        t15, t35 = 1.5 * char, 3.5 * char
    return Timing(settings, bits, char, t15, t35)


def switch_silence(previous: LineSettings | None, following: LineSettings) -> float:
    """Silence required before a frame at ``following`` after traffic at ``previous``.

    When the settings change, every slave saw the other rate as garbage and needs t3.5
    at its own rate to resynchronise, so the longer of the two silences applies.
    """
    after = timing(following).t35
    if previous is None or previous is following or previous == following:
        return after
    return max(after, timing(previous).t35)
