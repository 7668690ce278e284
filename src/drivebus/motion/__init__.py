"""The motion layer: axis actors, groups, the machine.

Its public names are imported on first use (``drivebus.lazy``), so that a module of the
layer (``drivebus.motion.lines``) can be imported without the axis and the machine.
"""

from typing import TYPE_CHECKING

from drivebus.lazy import lazy_exports

if TYPE_CHECKING:
    from drivebus.motion.axis import Axis, MotionPlan
    from drivebus.motion.events import MotionEvent
    from drivebus.motion.group import AxisGroup, GroupMotionError, GroupMoveReport
    from drivebus.motion.handle import BufferMode, MotionHandle, QueuePlan
    from drivebus.motion.machine import Machine, open_machine
    from drivebus.motion.recording import Recording
    from drivebus.motion.state import AxisState
    from drivebus.motion.units import Units

_HOMES = {
    "Axis": "axis", "MotionPlan": "axis", "MotionEvent": "events", "AxisGroup": "group",
    "GroupMotionError": "group", "GroupMoveReport": "group", "BufferMode": "handle",
    "MotionHandle": "handle", "QueuePlan": "handle", "Machine": "machine",
    "open_machine": "machine", "Recording": "recording", "AxisState": "state",
    "Units": "units",
}

__getattr__, __dir__ = lazy_exports(__name__, {k: f"{__name__}.{v}" for k, v in _HOMES.items()})

__all__ = [
    "Axis",
    "AxisGroup",
    "AxisState",
    "BufferMode",
    "GroupMotionError",
    "GroupMoveReport",
    "Machine",
    "MotionEvent",
    "MotionHandle",
    "MotionPlan",
    "QueuePlan",
    "Recording",
    "Units",
    "open_machine",
]
