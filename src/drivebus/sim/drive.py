"""SimDrive: what every simulated drive shares — motion in real time, switches, alarms.

Each drive family's twin (``drivebus.sim.drives.<family>``) subclasses this and maps its
own registers, status bits and procedures onto these mechanics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar, Literal

from drivebus.clock import monotonic
from drivebus.errors import ConfigError
from drivebus.settings import LineSettings
from drivebus.sim.kinematics import Kinematics
from drivebus.sim.slave import Fault, SimSlave

__all__ = ["HomeCam", "SimDrive", "Span", "TwinSetup", "time_or_present"]

HomeCam = Literal["positive", "negative"]
"""The side of ``home_switch`` a home cam covers."""


def time_or_present(now: float | None) -> float:
    """``now``, or the present time where the caller gave none (tests usually do not)."""
    return monotonic() if now is None else now


@dataclass(frozen=True, kw_only=True)
class TwinSetup:
    """How a simulated drive sits on its machine, whatever its family: how fast it answers,
    where its axis starts and where the axis's switches are, in the drive's pulses."""

    turnaround: float = 0.001
    """Seconds from the end of a request to the start of the reply."""
    position: int = 0
    """The position at power-up."""
    home_switch: float | None = None
    """Where the home switch's cam or dog begins (see ``SimDrive.home_span``)."""
    limit_negative: float | None = None
    """The negative limit switch is active at and below this position."""
    limit_positive: float | None = None
    """The positive limit switch is active at and above this position."""


_ON_EDGE = 1e-3
"""Pulses within which a position counts as on a switch's end: the float rounding of a stop
planned onto it (its time solved at a monotonic clock near 1e5 s, at up to 1e7 pulses/s)."""


@dataclass(frozen=True)
class Span:
    """Where a switch is active on the axis: from ``lo`` to ``hi``, ends included (physical
    pulses; an end may be infinite, as a limit switch's or a home cam's outer end)."""

    lo: float = -math.inf
    hi: float = math.inf

    def active(self, p: float) -> bool:
        """The switch is active at position ``p`` (a motor planned to stop on an end, and
        off it by a float's rounding only, is on it)."""
        return self.lo - _ON_EDGE <= p <= self.hi + _ON_EDGE

    def edge(self, direction: float, rising: bool) -> float | None:
        """Where a motor travelling in ``direction`` sees the switch turn active (``rising``)
        or inactive; None if it never does that way."""
        x = self.lo if (direction > 0) == rising else self.hi
        return x if math.isfinite(x) else None


class SimDrive(SimSlave):
    """A simulated drive: an axis in pulses with optional home and limit switches."""

    family: ClassVar[str] = "generic"
    """The drive family this twin simulates (the name in the machine config)."""

    def __init__(
        self,
        address: int,
        settings: LineSettings | None = None,
        setup: TwinSetup | None = None,
    ) -> None:
        setup = setup or TwinSetup()
        super().__init__(address, settings, turnaround=setup.turnaround)
        self.kin = Kinematics(setup.position)
        self.home_switch = setup.home_switch
        self.limit_negative = setup.limit_negative
        self.limit_positive = setup.limit_positive
        self.enabled = True
        self.alarm_code = 0
        """Latched alarm (0: none); the family's twin decides how it clears."""
        self.home_cam: HomeCam | None = None
        """The side of ``home_switch`` the home cam covers; None: the side the homing
        method in use searches towards (as the manuals draw their methods)."""
        self.home_switch_width: float | None = None
        """With a width, the home switch is a dog over ``[home_switch, home_switch + width]``."""
        self.homing_failed = False
        """The last homing ended at a limit switch without finding its origin."""

    def set_home_shape(self, home_cam: str | None, home_switch_width: float | None) -> None:
        """The home switch's shape from the family options ``home_cam`` / ``home_switch_width``
        (``ConfigError`` for a side that is neither, a width that is not > 0, or both)."""
        cams: dict[object, HomeCam] = {"positive": "positive", "negative": "negative"}
        if home_cam is not None and home_cam not in cams:
            raise ConfigError(f"home_cam must be 'positive' or 'negative', not {home_cam!r}")
        if home_switch_width is not None and not (
            math.isfinite(home_switch_width) and home_switch_width > 0
        ):
            raise ConfigError(f"home_switch_width must be > 0, not {home_switch_width!r}")
        if home_cam is not None and home_switch_width is not None:
            raise ConfigError("give home_cam (a cam) or home_switch_width (a dog), not both")
        self.home_cam = None if home_cam is None else cams[home_cam]
        self.home_switch_width = home_switch_width

    # -- what tests and the demo look at ------------------------------------------------------

    def position(self, now: float | None = None) -> int:
        """The simulated motor position in whole pulses."""
        return round(self.kin.position(time_or_present(now)))

    def velocity(self, now: float | None = None) -> float:
        """The simulated velocity in pulses/s."""
        return self.kin.velocity(time_or_present(now))

    def is_moving(self, now: float | None = None) -> bool:
        """True while the simulated motor turns."""
        return self.kin.moving(time_or_present(now))

    def speed_rpm(self, now: float | None = None) -> float:
        """The simulated speed in r/min (signed) at the drive's microstep setting."""
        return self.velocity(now) * 60.0 / self.pulses_per_rev

    def raise_alarm(self, code: int, now: float | None = None) -> None:
        """Latch alarm ``code``: the motor stops at once (as a drive's fault reaction)."""
        t = time_or_present(now)
        self.alarm_code = code
        self.kin.stop(t, None)

    def power_loss(self) -> None:
        """Cut the power: no replies until ``power_restore``; motion is lost."""
        self.faults.inject(Fault.POWER_LOSS, times=None)
        self.kin.stop(monotonic(), None)

    def power_restore(self) -> None:
        """Power comes back (the drive answers again)."""
        self.faults.clear(Fault.POWER_LOSS)

    def power_cycle(self) -> None:
        """Switch the drive off and on again: it starts as at power-up, with what it
        stored (an address or line settings it was given take effect now); motion is lost."""
        self.power_loss()
        self.power_restore()

    # -- units of the drive's registers ---------------------------------------------------------

    @property
    def pulses_per_rev(self) -> int:
        """The drive's microstep setting: pulses per motor revolution (from its registers)."""
        raise NotImplementedError(f"{type(self).__name__} has no microstep setting")

    def pulse_rate(self, rpm: float) -> float:
        """Pulses/s of a speed of ``rpm`` r/min at the microstep setting."""
        return rpm * self.pulses_per_rev / 60.0

    def pulse_acceleration(self, rps2: float) -> float:
        """Pulses/s² of an acceleration of ``rps2`` r/s² at the microstep setting."""
        return rps2 * self.pulses_per_rev

    # -- switches ------------------------------------------------------------------------------

    def home_side(self) -> int:
        """The side (+1/-1) a home cam covers when ``home_cam`` does not say: the direction
        the homing method in use searches in (families override; +1 here)."""
        return 1

    def home_span(self) -> Span | None:
        """Where the home switch is active: a dog of ``home_switch_width``, else a cam from
        ``home_switch`` on, on the side ``home_cam`` (or ``home_side()``) names."""
        x = self.home_switch
        if x is None:
            return None
        if self.home_switch_width is not None:
            return Span(x, x + self.home_switch_width)
        side = {"positive": 1, "negative": -1}.get(self.home_cam or "", self.home_side())
        return Span(lo=x) if side > 0 else Span(hi=x)

    def limit_span(self, direction: float) -> Span | None:
        """Where the limit switch towards ``direction`` is active (beyond its position)."""
        if direction > 0:
            return None if self.limit_positive is None else Span(lo=self.limit_positive)
        return None if self.limit_negative is None else Span(hi=self.limit_negative)

    def switches_at(self, p: float) -> tuple[bool, bool, bool]:
        """(home, limit negative, limit positive) at physical position ``p``."""
        spans = (self.home_span(), self.limit_span(-1), self.limit_span(1))
        home, neg, pos = (s is not None and s.active(p) for s in spans)
        return home, neg, pos

    def switch_states(self, now: float) -> tuple[bool, bool, bool]:
        """(home, limit negative, limit positive) inputs at ``now`` (``home_span``;
        limits are active at and beyond their positions)."""
        return self.switches_at(self.kin.position(now))
