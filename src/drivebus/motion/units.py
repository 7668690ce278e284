"""The one unit converter: an axis's user units to drive units (pulses, rpm, rev/s²)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from drivebus.errors import ConfigError, LimitViolation

__all__ = ["Units"]


@dataclass(frozen=True)
class Units:
    """``pulses_per_rev`` pulses turn the motor once and move the axis ``units_per_rev``."""

    pulses_per_rev: int
    units_per_rev: float

    def __post_init__(self) -> None:
        if self.pulses_per_rev <= 0:
            raise ConfigError(f"pulses_per_rev must be > 0, not {self.pulses_per_rev}")
        if self.units_per_rev == 0:
            raise ConfigError("units_per_rev must not be 0")

    def to_pulses(self, units: float) -> int:
        """A position or distance in user units as whole pulses (rounded); ``LimitViolation``
        if it is not finite (a NaN, or so far that the count overflows)."""
        pulses = units / self.units_per_rev * self.pulses_per_rev
        if not math.isfinite(pulses):
            raise LimitViolation(f"{units!r} units is {pulses} pulses: beyond any drive's range")
        return round(pulses)

    def from_pulses(self, pulses: int) -> float:
        """Pulses as user units."""
        return pulses * self.units_per_rev / self.pulses_per_rev

    def to_rpm(self, units_per_s: float) -> float:
        """A speed in user units/s as motor rev/min; ``LimitViolation`` if that is not
        finite (a speed near the float range's end)."""
        return _finite(units_per_s / abs(self.units_per_rev) * 60.0, units_per_s,
                       "units/s", "rpm")

    def from_rpm(self, rpm: float) -> float:
        """Motor rev/min as user units/s."""
        return rpm / 60.0 * abs(self.units_per_rev)

    def to_rps2(self, units_per_s2: float) -> float:
        """An acceleration in user units/s² as motor rev/s²; ``LimitViolation`` if that is
        not finite."""
        return _finite(units_per_s2 / abs(self.units_per_rev), units_per_s2, "units/s²",
                       "rev/s²")

    def from_rps2(self, rps2: float) -> float:
        """Motor rev/s² as user units/s²."""
        return rps2 * abs(self.units_per_rev)


def _finite(converted: float, given: float, unit: str, drive_unit: str) -> float:
    """``converted`` if it is finite; else ``LimitViolation`` naming ``given``."""
    if not math.isfinite(converted):
        raise LimitViolation(f"{given!r} {unit} is {converted} {drive_unit}: beyond any "
                             f"drive's range")
    return converted
