"""AxisState: the PLCopen axis state diagram, plus Offline when the drive stops answering."""

from __future__ import annotations

import enum

__all__ = ["MOVING_STATES", "AxisState"]


class AxisState(enum.StrEnum):
    """Where an axis is in the PLCopen state diagram."""

    DISABLED = "Disabled"
    STANDSTILL = "Standstill"
    HOMING = "Homing"
    DISCRETE_MOTION = "DiscreteMotion"
    CONTINUOUS_MOTION = "ContinuousMotion"
    STOPPING = "Stopping"
    ERROR_STOP = "ErrorStop"
    OFFLINE = "Offline"


MOVING_STATES = frozenset(
    {
        AxisState.HOMING,
        AxisState.DISCRETE_MOTION,
        AxisState.CONTINUOUS_MOTION,
        AxisState.STOPPING,
    }
)
