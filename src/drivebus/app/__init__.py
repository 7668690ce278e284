"""The application layer: what the CLI, the HTTP service and the MQTT bridge share.

No terminal, HTTP or MQTT code lives here: sessions over an open machine
(``MachineSession``), snapshots as plain data, motions with ids, leases, e-stop and an
event stream. Front ends render these and map the typed errors to their own conventions.
"""

from drivebus.app.events import Event, EventHub, Subscription
from drivebus.app.session import Lease, MachineSession, MotionRecord, MotionState
from drivebus.app.snapshots import (
    AxisSnapshot,
    LineSnapshot,
    MachineSnapshot,
    axis_snapshot,
    error_record,
    line_snapshot,
    machine_snapshot,
)

__all__ = [
    "AxisSnapshot",
    "Event",
    "EventHub",
    "Lease",
    "LineSnapshot",
    "MachineSession",
    "MachineSnapshot",
    "MotionRecord",
    "MotionState",
    "Subscription",
    "axis_snapshot",
    "error_record",
    "line_snapshot",
    "machine_snapshot",
]
