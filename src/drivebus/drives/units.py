"""Units of drive registers: how a register holds a position, a speed or an acceleration.

Above the profiles, quantities are in drive units: positions in pulses, speeds in rev/min,
accelerations in rev/s². A register may hold them otherwise, and its description says how
(``unit`` and ``scale``: the physical value is the raw value times ``scale``, in ``unit``):

* positions: ``pulses`` (or ``counts``, the same);
* speeds: ``rpm``, ``rps``, ``pulses/s`` (e.g. ``unit = "rps", scale = "1/240"``);
* accelerations: ``r/s²``, ``rpm/s``, ``pulses/s²``;
* ramp times: ``ms`` or ``s`` with ``ramp`` naming what the ramp reaches from rest: the
  register holding the move's speed (``ramp = "max_speed"``: the time from 0 to that speed)
  or a fixed speed in rpm (``ramp = 1000``: "ms per 1000 rpm");
* a lookup table (``table = [400, 800, ...]``: the physical value is ``table[raw]``) or
  named values (``values = { "8N1" = 0, ... }``).

Any other unit must be one this module knows (``OTHER_UNITS``: ``V``, ``A``, ``°C``,
``%``, ``count``, ``steps/rev``, ``ms`` of a filter, ...): its value is the raw value times
``scale``, in that unit. A unit with a factor in its name (``"0.1 A"``, ``"×50 µs"``) or one
this module does not know is refused (``check_unit``): a scale that is silently not applied
is an axis that travels twice the distance it was told.
Conversions round to the register's resolution and range-check with errors that name the
register, its range and the value asked for.
"""

from __future__ import annotations

import enum
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from fractions import Fraction

from drivebus.drives.registers import Register
from drivebus.errors import LimitViolation

__all__ = ["OTHER_UNITS", "Kind", "UnitCodec", "check_unit", "parse_scale", "ramp_time_ms",
           "scale_text", "unit_kind"]


class Kind(enum.Enum):
    """What a register's value is."""

    PLAIN = "plain"
    POSITION = "position"
    SPEED = "speed"
    ACCEL = "acceleration"
    RAMP = "ramp time"
    TABLE = "table"
    NAMED = "named values"


_POSITION = {"pulses": 1.0, "pulse": 1.0, "counts": 1.0, "inc": 1.0, "steps": 1.0}
_SPEED = {"rpm": 1.0, "r/min": 1.0, "rev/min": 1.0, "rps": 60.0, "r/s": 60.0,
          "rev/s": 60.0}  # rpm per unit
_SPEED_PULSES = ("pulses/s", "pps", "counts/s", "inc/s")
_ACCEL = {"r/s²": 1.0, "r/s^2": 1.0, "rps2": 1.0, "rps/s": 1.0, "rev/s²": 1.0, "rev/s/s": 1.0,
          "r/s/s": 1.0, "rpm/s": 1 / 60}  # r/s² per unit
_ACCEL_PULSES = ("pulses/s²", "pulses/s^2", "pps2", "counts/s²", "inc/s²")
_TIME = {"ms": 0.001, "s": 1.0}

KNOWN_UNITS: tuple[str, ...] = (
    *_POSITION, *_SPEED, *_SPEED_PULSES, *_ACCEL, *_ACCEL_PULSES, *_TIME,
)
"""The units this module converts to drive units (pulses, rpm, rev/s²)."""

OTHER_UNITS: tuple[str, ...] = (
    "count", "steps/rev", "pulses/rev", "counts/rev", "ms", "s", "µs", "us", "min", "h",
    "V", "mV", "A", "mA", "W", "kW", "Ω", "mΩ", "H", "mH", "Hz", "kHz", "°C", "%", "‰",
    "mm", "µm", "°", "deg", "Nm", "N", "kg", "rpm/V", "bit/s", "baud",
)
"""Units whose value is the raw value times ``scale`` in that unit (not converted to
drive units): currents, voltages, temperatures, times of filters, counts."""

_FACTOR = re.compile(r"^\s*(?:[×x*]\s*)?([0-9]+(?:[.,][0-9]+)?)\s*(?:[×x*]\s*)?(\S.*)$")


def check_unit(unit: str, *, ramp: bool = False) -> str:
    """``unit`` stripped if this module knows it; else ``ValueError`` saying what to write
    (a factor in the unit's name is a ``scale``)."""
    u = unit.strip()
    if not u or u in KNOWN_UNITS or u in OTHER_UNITS or (ramp and u in _TIME):
        return u
    m = _FACTOR.match(u)
    if m is not None and m.group(2).strip() in (*KNOWN_UNITS, *OTHER_UNITS):
        factor, rest = m.group(1).replace(",", "."), m.group(2).strip()
        raise ValueError(f"unit {unit!r} has a factor in its name: write unit = {rest!r}, "
                         f"scale = {factor} (the value is the raw value times scale)")
    raise ValueError(
        f"unit {unit!r} is not one drivebus knows, so its scale could not be applied: "
        f"positions {', '.join(_POSITION)}; speeds {', '.join((*_SPEED, *_SPEED_PULSES))}; "
        f"accelerations {', '.join((*_ACCEL, *_ACCEL_PULSES))}; others (raw × scale) "
        f"{', '.join(OTHER_UNITS)}; a number of things is unit = \"count\"")


def scale_text(scale: float) -> str:
    """``scale`` as the manual would write it: ``2``, ``0.1``, ``1/240``."""
    if scale == int(scale):
        return str(int(scale))
    short = f"{scale:g}"
    if len(short.replace("0.", "", 1)) <= 4:  # 0.1, 0.25, 0.001
        return short
    frac = Fraction(scale).limit_denominator(100000)
    if abs(float(frac) - scale) < 1e-12 * scale and frac.numerator < 100000:
        return f"{frac.numerator}/{frac.denominator}"
    return short


def unit_kind(unit: str, *, ramp: bool) -> Kind:
    """The kind of quantity ``unit`` is (``ramp``: the register is a ramp time)."""
    u = unit.strip()
    if ramp:
        return Kind.RAMP
    if u in _POSITION:
        return Kind.POSITION
    if u in _SPEED or u in _SPEED_PULSES:
        return Kind.SPEED
    if u in _ACCEL or u in _ACCEL_PULSES:
        return Kind.ACCEL
    return Kind.PLAIN


def parse_scale(scale: object) -> float:
    """A scale given as a number or a fraction text (``"1/240"``, ``"1875/512"``)."""
    if isinstance(scale, bool):
        raise ValueError(f"scale must be a number or a fraction like '1/240', not {scale!r}")
    if isinstance(scale, int | float):
        v = float(scale)
    elif isinstance(scale, str):
        try:
            v = float(Fraction(scale.replace(" ", "")))
        except (ValueError, ZeroDivisionError):
            raise ValueError(f"scale {scale!r} is not a number or a fraction like '1/240'") \
                from None
    else:
        raise ValueError(f"scale must be a number or a fraction like '1/240', not {scale!r}")
    if not math.isfinite(v) or v <= 0:
        raise ValueError(f"scale must be > 0, not {scale!r}")
    return v


def _where(reg: Register) -> str:
    return f"register {reg.name} (address {reg.address})"


def ramp_time_ms(reg: Register, speed_rpm: float, rate_rps2: float) -> int:
    """The ramp time (ms) to reach ``|speed_rpm|`` from rest at ``rate_rps2``, range-checked
    against ``reg``: ``LimitViolation`` naming it when the time is outside its range."""
    if not math.isfinite(rate_rps2) or rate_rps2 <= 0:
        raise LimitViolation(f"{_where(reg)}: the rate must be > 0 rev/s², not {rate_rps2}")
    ms = round(abs(speed_rpm) / 60.0 / rate_rps2 * 1000.0)
    try:
        return reg.check(ms)
    except LimitViolation as exc:
        raise LimitViolation(
            f"{exc} ({rate_rps2} rev/s² at {abs(speed_rpm)} rpm needs {ms} ms)"
        ) from None


@dataclass(frozen=True)
class UnitCodec:
    """How one register holds its value (see the module's text)."""

    kind: Kind = Kind.PLAIN
    unit: str = ""
    scale: float = 1.0
    ramp: str | float | None = None
    """A ramp time's reference: a register key, or a fixed speed in rpm."""
    table: tuple[int, ...] = ()
    values: Mapping[str, int] = field(default_factory=dict)

    @classmethod
    def make(
        cls,
        unit: str = "",
        scale: float = 1.0,
        ramp: str | float | None = None,
        table: Sequence[int] = (),
        values: Mapping[str, int] | None = None,
    ) -> UnitCodec:
        """The codec of a register with these declarations."""
        if table:
            kind = Kind.TABLE
        elif values:
            kind = Kind.NAMED
        else:
            kind = unit_kind(unit, ramp=ramp is not None)
        return cls(kind, unit.strip(), scale, ramp, tuple(table), dict(values or {}))

    @property
    def physical(self) -> bool:
        """True if values pass through a conversion (a scale, a unit, a ramp or a table;
        not a plain register of scale 1 or named values)."""
        return self.kind is not Kind.NAMED and (self.kind is not Kind.PLAIN or
                                                self.scale != 1.0)

    # -- physical <-> register units ------------------------------------------------------

    def factor(self, ppr: int) -> float:
        """Drive units (pulses, rpm, r/s²) per register unit before ``scale``."""
        u = self.unit
        if self.kind is Kind.POSITION:
            return _POSITION[u]
        if self.kind is Kind.SPEED:
            return _SPEED[u] if u in _SPEED else 60.0 / ppr
        if self.kind is Kind.ACCEL:
            return _ACCEL[u] if u in _ACCEL else 1.0 / ppr
        return 1.0

    def to_raw(
        self, reg: Register, value: object, *, ppr: int = 1, ref_rpm: float | None = None
    ) -> int:
        """The raw value ``reg`` must hold for the physical ``value``, range-checked."""
        if self.kind is Kind.NAMED and isinstance(value, str):
            if value not in self.values:
                raise LimitViolation(
                    f"value {value!r} for {_where(reg)} is not one of "
                    f"{', '.join(self.values)}")
            return reg.check(self.values[value])
        if isinstance(value, str):
            raise LimitViolation(f"value {value!r} for {_where(reg)} is not a number")
        if isinstance(value, bool):
            value = int(value)
        if not isinstance(value, int | float) or not math.isfinite(value):
            raise LimitViolation(f"value {value!r} for {_where(reg)} is not a finite number")
        if self.kind is Kind.TABLE:
            if value not in self.table:
                shown = ", ".join(str(v) for v in sorted(self.table))
                unit = f" {self.unit}" if self.unit else ""
                raise LimitViolation(
                    f"value {value:g}{unit} for {_where(reg)} is not one it can hold ({shown})")
            return reg.check(self.table.index(int(value)))
        if self.kind is Kind.RAMP:
            return self._ramp_raw(reg, float(value), ref_rpm)
        if self.kind is Kind.NAMED or (self.kind is Kind.PLAIN and self.scale == 1.0):
            return reg.check(value)  # type: ignore[arg-type]
        raw = round(value / self.factor(ppr) / self.scale)
        try:
            return reg.check(raw)
        except LimitViolation as exc:
            if self.scale == 1.0 and self.factor(ppr) == 1.0:
                raise
            unit = f" {self.drive_unit}" if self.drive_unit else ""
            raise LimitViolation(f"{exc} ({value:g}{unit} is {raw}: {self.describe()})"
                                 ) from None

    def _ramp_raw(self, reg: Register, rate: float, ref_rpm: float | None) -> int:
        ref = self.ramp if isinstance(self.ramp, int | float) else ref_rpm
        if ref is None:
            raise LimitViolation(f"{_where(reg)}: a ramp time needs the speed it reaches")
        if not math.isfinite(rate) or rate <= 0:
            raise LimitViolation(f"{_where(reg)}: the rate must be > 0 rev/s², not {rate}")
        seconds = abs(ref) / 60.0 / rate
        raw = round(seconds / _TIME.get(self.unit, 0.001) / self.scale)
        try:
            return reg.check(raw)
        except LimitViolation as exc:
            t = raw * self.scale
            raise LimitViolation(
                f"{exc} ({rate} rev/s² at {abs(ref)} rpm needs {t:g} {self.unit})"
            ) from None

    def to_physical(
        self, raw: int, *, ppr: int = 1, ref_rpm: float | None = None
    ) -> int | float:
        """The physical value of a raw register value (a ramp time as a rate in r/s²:
        ``inf`` for a zero time, 0 when the reference speed is 0)."""
        if self.kind is Kind.TABLE:
            return self.table[raw] if 0 <= raw < len(self.table) else raw
        if self.kind is Kind.NAMED or (self.kind is Kind.PLAIN and self.scale == 1.0):
            return raw
        if self.kind is Kind.RAMP:
            ref = self.ramp if isinstance(self.ramp, int | float) else ref_rpm
            seconds = raw * self.scale * _TIME.get(self.unit, 0.001)
            if ref is None:
                return math.nan
            return math.inf if seconds <= 0 else abs(ref) / 60.0 / seconds
        v = raw * self.scale * self.factor(ppr)
        if self.kind in (Kind.POSITION, Kind.PLAIN) and v == int(v):
            return int(v)
        return float(v)

    @property
    def drive_unit(self) -> str:
        """The drive unit of the physical value: pulses, rpm or r/s²."""
        return {Kind.POSITION: "pulses", Kind.SPEED: "rpm", Kind.ACCEL: "rev/s²",
                Kind.RAMP: "rev/s²"}.get(self.kind, self.unit)

    def describe(self) -> str:
        """How the register holds its value, in words (for ``drive check`` and docs)."""
        if self.kind is Kind.TABLE:
            return f"table of {len(self.table)} values"
        if self.kind is Kind.NAMED:
            return ", ".join(f"{k}={v}" for k, v in self.values.items())
        scale = "" if self.scale == 1.0 else f" × {scale_text(self.scale)}"
        if self.kind is Kind.RAMP:
            ref = f"{self.ramp:g} rpm" if isinstance(self.ramp, int | float) else \
                f"the speed in {self.ramp}"
            return f"ramp time in {self.unit}{scale} to reach {ref}"
        if not self.unit:
            return f"count{scale}" if scale else ""
        return f"{self.unit}{scale}"

    def raw_unit(self) -> str:
        """What one step of the raw value is, for texts about raw values (``1/240 rps``,
        ``0.1 A``; the unit itself at scale 1)."""
        if self.kind in (Kind.TABLE, Kind.NAMED, Kind.RAMP) or self.scale == 1.0:
            return self.unit
        return f"{scale_text(self.scale)} {self.unit}".strip()
