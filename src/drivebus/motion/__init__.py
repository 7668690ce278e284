"""The motion layer: axis actors, groups, the machine."""

from drivebus.motion.axis import Axis, MotionPlan
from drivebus.motion.events import MotionEvent
from drivebus.motion.group import AxisGroup, GroupMotionError, GroupMoveReport
from drivebus.motion.handle import BufferMode, MotionHandle, QueuePlan
from drivebus.motion.machine import Machine, open_machine
from drivebus.motion.recording import Recording
from drivebus.motion.state import AxisState
from drivebus.motion.units import Units

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
