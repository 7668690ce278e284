"""SimDrive: what every simulated drive shares — motion in real time, switches, alarms.

Each drive family's twin (``drivebus.sim.drives.<family>``) subclasses this and maps its
own registers, status bits and procedures onto these mechanics.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from drivebus.clock import monotonic
from drivebus.settings import LineSettings
from drivebus.sim.kinematics import Kinematics
from drivebus.sim.slave import Fault, SimSlave

__all__ = ["SimDrive", "TwinSetup", "time_or_present"]


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
    """Where the home switch's cam begins (each family says which side it covers)."""
    limit_negative: float | None = None
    """The negative limit switch is active at and below this position."""
    limit_positive: float | None = None
    """The positive limit switch is active at and above this position."""


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

    def switch_states(self, now: float) -> tuple[bool, bool, bool]:
        """(home, limit negative, limit positive) inputs at ``now``.

        The home switch is active on the positive side of ``home_switch`` (a cam that
        covers the axis from there on); limits are active beyond their positions.
        """
        p = self.kin.position(now)
        home = self.home_switch is not None and p >= self.home_switch
        neg = self.limit_negative is not None and p <= self.limit_negative
        pos = self.limit_positive is not None and p >= self.limit_positive
        return home, neg, pos
