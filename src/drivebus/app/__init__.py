"""The application layer: what the CLI, the HTTP service and the MQTT bridge share.

No terminal, HTTP or MQTT code lives here: sessions over an open machine
(``MachineSession``), snapshots as plain data, motions with ids, leases, e-stop and an
event stream. Front ends render these and map the typed errors to their own conventions.
The public names are imported on first use (``drivebus.lazy``): a command that reads a
register (``drivebus.app.registers``) loads no session.
"""

from typing import TYPE_CHECKING

from drivebus.lazy import lazy_exports

if TYPE_CHECKING:
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

_HOMES = {
    **dict.fromkeys(["Event", "EventHub", "Subscription"], "events"),
    **dict.fromkeys(["Lease", "MachineSession", "MotionRecord", "MotionState"], "session"),
    **dict.fromkeys(["AxisSnapshot", "LineSnapshot", "MachineSnapshot", "axis_snapshot",
                     "error_record", "line_snapshot", "machine_snapshot"], "snapshots"),
}

__getattr__, __dir__ = lazy_exports(__name__, {k: f"{__name__}.{v}" for k, v in _HOMES.items()})

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
