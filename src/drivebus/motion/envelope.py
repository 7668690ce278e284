"""Envelope: what an axis may ask of its drive, checked before anything is sent.

Speed and ramps within the axis's defaults, its ``max_speed`` and what its drive runs;
targets within the soft limits and away from an active limit switch; user units turned
into pulses that stay within the limits. Every check is pure (configuration, profile and
the last polled status in, a typed error out), so a refused command changes nothing.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

from drivebus import checks
from drivebus.config import AxisConfig
from drivebus.drives.base import DriveProfile, MoveParams
from drivebus.drives.status import DriveStatus
from drivebus.errors import DrivebusError, LimitViolation
from drivebus.motion.units import Units

__all__ = ["Envelope", "MotionPlan"]

_POSITION_PULSES = 1 << 31
"""A position beyond every drive's counter (32 bits, signed)."""


def _edge(takes: Callable[[int], bool], far: int) -> int:
    """The magnitude of the farthest position towards ``far`` that ``takes`` accepts,
    given that it accepts 0 and its accepted positions around 0 are one interval."""
    if takes(far):
        return abs(far)
    sign = 1 if far > 0 else -1
    good, bad = 0, abs(far)
    while bad - good > 1:
        mid = (good + bad) // 2
        if takes(sign * mid):
            good = mid
        else:
            bad = mid
    return good


_EDGE_STEPS = 64
"""Most steps of the search for a drive's edge (it needs ~25 from the float range's ends)."""


@dataclass(frozen=True)
class MotionPlan:
    """Speed and ramps of one motion in user units (units/s, units/s²)."""

    speed: float
    accel: float
    decel: float

    def duration(self, distance: float) -> float:
        """Time a trapezoidal move of ``distance`` takes (triangular if it is short)."""
        d = abs(distance)
        v, a, b = self.speed, self.accel, self.decel
        ramp = v * v / (2 * a) + v * v / (2 * b)
        if d >= ramp:
            return d / v + v / (2 * a) + v / (2 * b)
        vp = math.sqrt(2 * d * a * b / (a + b))
        return vp / a + vp / b


class Envelope:
    """The limits of one axis (its name, configuration, drive profile and units)."""

    def __init__(self, name: str, config: AxisConfig, profile: DriveProfile, units: Units) -> None:
        self.name = name
        self.config = config
        self.profile = profile
        self.units = units
        self._target_range: tuple[int, int] | None = None

    # -- speed and ramps ----------------------------------------------------------------------

    def plan(
        self, speed: float | None = None, accel: float | None = None, decel: float | None = None
    ) -> MotionPlan:
        """The axis's defaults with any of them overridden; checked (ArgumentError,
        LimitViolation beyond max_speed). Values are magnitudes: > 0."""
        c = self.config

        def given(name: str, value: float | None, default: float, unit: str) -> float:
            if value is None:
                return default
            return checks.positive(f"axis {self.name}: {name}", value, unit=f"{c.unit}{unit}")

        p = MotionPlan(
            given("speed", speed, c.speed, "/s"),
            given("accel", accel, c.accel, "/s²"),
            given("decel", decel, c.decel, "/s²"),
        )
        if c.max_speed is not None and p.speed > c.max_speed:
            raise LimitViolation(
                f"axis {self.name}: speed {p.speed:g} exceeds max_speed {c.max_speed:g} {c.unit}/s"
            )
        return p

    def drive_params(self, plan: MotionPlan) -> MoveParams:
        """``plan`` in drive units (rpm, rev/s²)."""
        u = self.units
        return MoveParams(u.to_rpm(plan.speed), u.to_rps2(plan.accel), u.to_rps2(plan.decel))

    def quantized(self, plan: MotionPlan) -> MotionPlan:
        """``plan`` as its drive runs it (whole rpm, its ramps' resolution), in user units."""
        q = self.profile.quantize(self.drive_params(plan))
        u = self.units
        return MotionPlan(u.from_rpm(abs(q.speed_rpm)), u.from_rps2(q.accel_rps2),
                          u.from_rps2(q.decel_rps2))

    def check_drive(self, plan: MotionPlan) -> None:
        """``LimitViolation`` in the axis's units if its drive cannot run ``plan``: the
        speed, acceleration or deceleration and the most the drive takes of it (found
        from the profile's own range checks, which speak in register units)."""
        try:
            self.profile.check_move(self.drive_params(plan))
        except LimitViolation as exc:
            raise LimitViolation(f"axis {self.name}: {self._beyond_drive(plan)} "
                                 f"(drive {self.profile.family}: {exc})") from exc

    def _beyond_drive(self, plan: MotionPlan) -> str:
        """Which of ``plan``'s values its drive cannot run, in user units, and its limit:
        each value is searched between itself and the axis's default for it, the other
        two held at their defaults."""
        unit = self.config.unit
        names = {"speed": f"{unit}/s", "accel": f"{unit}/s²", "decel": f"{unit}/s²"}
        defaults = MotionPlan(self.config.speed, self.config.accel, self.config.decel)
        for quantity, unit_name in names.items():
            value = getattr(plan, quantity)

            def fits(v: float, quantity: str = quantity) -> bool:
                trial = dataclasses.replace(defaults, **{quantity: v})
                try:
                    self.profile.check_move(self.drive_params(trial))
                except LimitViolation:
                    return False
                return True

            good = getattr(defaults, quantity)
            if fits(value) or not fits(good):
                continue
            lo, hi = sorted((value, good))
            # the edge between a value that fits and one that does not, halving the ratio's
            # logarithm each step: ~25 steps even from the float range's ends. The mean of
            # the square roots, not the root of the product, which overflows to infinity
            # for values near the float range (and then never gets closer).
            for _ in range(_EDGE_STEPS):
                if hi / lo <= 1.0001:
                    break
                mid = math.sqrt(lo) * math.sqrt(hi)
                if fits(mid) == (value > good):
                    lo = mid
                else:
                    hi = mid
            if value > good:
                return (f"{quantity} {value:g} {unit_name} is beyond the {_round3(lo):g} "
                        f"{unit_name} its drive runs at most")
            return (f"{quantity} {value:g} {unit_name} is below the {_round3(hi):g} "
                    f"{unit_name} its drive runs at least")
        return "its drive cannot run this speed with these ramps"

    def motion_timeout(self, plan: MotionPlan, distance: float) -> float:
        """How long a motion of ``distance`` at ``plan`` may take before it has failed."""
        return plan.duration(distance) * 1.5 + 1.0 + 4 * self.config.poll.moving

    # -- where the axis may go ----------------------------------------------------------------

    def check_limits(self, target: float) -> None:
        """LimitViolation if ``target`` lies outside the soft limits or beyond what the
        drive's target position takes; nothing is sent."""
        lim = self.config.limits
        if lim is not None and not lim[0] <= target <= lim[1]:
            raise LimitViolation(
                f"axis {self.name}: target {target:g} is outside the soft limits "
                f"{lim[0]:g}..{lim[1]:g}"
            )
        lo, hi = self.target_range()
        p = self.units.to_pulses(target)
        if not lo <= p <= hi:
            u = self.units
            raise LimitViolation(
                f"axis {self.name}: target {target:g} {self.config.unit} is {p} pulses, "
                f"beyond what drive {self.profile.family}'s target position takes "
                f"({u.from_pulses(lo):g}..{u.from_pulses(hi):g} {self.config.unit}, "
                f"{lo}..{hi} pulses)")

    def target_range(self) -> tuple[int, int]:
        """The pulses an absolute move of the drive can target (its target register's
        range, found once from the profile's own range check; 32 bits where it has none)."""
        if self._target_range is not None:
            return self._target_range
        params = self.drive_params(self.plan())

        def takes(p: int) -> bool:
            try:
                self.profile.check_move(params, p)
            except DrivebusError:
                return False
            return True

        if not takes(0):  # no absolute moves, or its default speed refused: they say why
            self._target_range = (-_POSITION_PULSES, _POSITION_PULSES - 1)
        else:
            self._target_range = (-_edge(takes, -_POSITION_PULSES),
                                  _edge(takes, _POSITION_PULSES - 1))
        return self._target_range

    def pulses(self, target: float) -> int:
        """``target`` (user units, within the soft limits) as pulses that stay within them."""
        p = self.units.to_pulses(target)
        lim = self.config.limits
        if lim is None:
            return p
        for candidate in (p, p - 1, p + 1):
            if lim[0] <= self.units.from_pulses(candidate) <= lim[1]:
                return candidate
        return p  # a limit range narrower than one pulse: nothing better exists

    def drive_direction(self, user_direction: float) -> int:
        """The pulse direction of a motion in user direction ``user_direction``."""
        if user_direction == 0:
            return 0
        return 1 if (user_direction > 0) == (self.units.units_per_rev > 0) else -1

    def check_switch(self, direction: int, status: DriveStatus | None) -> None:
        """LimitViolation if a hardware limit switch is active in drive ``direction``
        (as ``status`` shows; None: nothing known yet)."""
        if status is None or direction == 0:
            return
        if (direction > 0 and status.limit_positive) or (direction < 0 and status.limit_negative):
            side = "positive" if direction > 0 else "negative"
            raise LimitViolation(
                f"axis {self.name}: the {side} limit switch is active; only motion away "
                f"from it is allowed"
            )

    def jog_bound(self, speed: float) -> int | None:
        """Pulses of the soft limit a jog at ``speed`` runs towards, or of the end of what
        the drive's target position takes where that comes first (None: no limits)."""
        lim = self.config.limits
        if lim is None:
            return None
        lo, hi = self.target_range()
        return min(max(self.pulses(lim[1] if speed > 0 else lim[0]), lo), hi)

    def check_jog_room(self, speed: float, status: DriveStatus | None) -> None:
        """LimitViolation if a jog at ``speed`` has no room before a limit switch or a
        soft limit, from ``status`` (nothing sent)."""
        self.check_switch(self.drive_direction(speed), status)
        lim = self.config.limits
        if status is None or status.position is None or lim is None:
            return
        pos = self.units.from_pulses(status.position)
        if (speed > 0 and pos >= lim[1]) or (speed < 0 and pos <= lim[0]):
            raise LimitViolation(
                f"axis {self.name}: at the soft limit ({pos:.4f}), cannot jog "
                f"{'up' if speed > 0 else 'down'} (limits {lim[0]:g}..{lim[1]:g})"
            )


def _round3(v: float) -> float:
    """``v`` to three significant digits (a limit found by a search, for a message)."""
    return float(f"{v:.3g}")
