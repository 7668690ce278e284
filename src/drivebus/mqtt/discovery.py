"""Home Assistant MQTT discovery: the node as a device with, per axis, a position sensor
(in the axis's unit: ``unit_of_measurement``, and the ``distance`` device class for the
length units Home Assistant knows), a state sensor and a stop button, plus an e-stop
button; all unavailable while the node's status topic says ``offline``."""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping

from drivebus.mqtt.outbox import Outgoing
from drivebus.mqtt.topics import Topics

__all__ = ["DISCOVERY_PREFIX", "discovery_messages"]

DISCOVERY_PREFIX = "homeassistant"

DISTANCE_UNITS = frozenset({"mm", "cm", "m", "km", "in", "ft", "yd", "mi"})
"""The units Home Assistant's ``distance`` device class takes."""


def discovery_messages(topics: Topics, machine: str, axes: Iterable[str],
                       units: Mapping[str, str] | None = None) -> list[Outgoing]:
    """The retained ``homeassistant/<component>/drivebus_<node>/<object>/config`` messages;
    ``units``: each axis's unit (its positions are published in it)."""
    node = topics.node
    device_id = f"drivebus_{node}"
    common = {
        "availability_topic": topics.status,
        "payload_available": "online",
        "payload_not_available": "offline",
        "device": {
            "identifiers": [device_id],
            "name": f"drivebus {node}",
            "manufacturer": "drivebus",
            "model": f"machine {machine}",
        },
    }
    out: list[tuple[str, str, dict[str, object]]] = []
    for axis in axes:
        state = topics.state(axis)
        position: dict[str, object] = {
            "name": f"{axis} position",
            "state_topic": state,
            "value_template": "{{ value_json.position }}",
            "state_class": "measurement",
            "json_attributes_topic": state,
        }
        unit = (units or {}).get(axis)
        if unit is not None:
            position["unit_of_measurement"] = unit
            if unit in DISTANCE_UNITS:
                position["device_class"] = "distance"
        out.append(("sensor", f"{axis}_position", position))
        out.append(("sensor", f"{axis}_state", {
            "name": f"{axis} state",
            "state_topic": state,
            "value_template": "{{ value_json.state }}",
        }))
        out.append(("button", f"{axis}_stop", {
            "name": f"{axis} stop",
            "command_topic": topics.command(axis, "stop"),
            "payload_press": "{}",
        }))
    out.append(("button", "estop", {
        "name": "e-stop",
        "command_topic": topics.estop,
        "payload_press": "{}",
        "icon": "mdi:alert-octagon",
    }))
    return [
        Outgoing(
            f"{DISCOVERY_PREFIX}/{component}/{device_id}/{obj}/config",
            json.dumps({**cfg, "unique_id": f"{device_id}_{obj}", "object_id":
                        f"{device_id}_{obj}", **common}).encode(),
            qos=1, retain=True,
        )
        for component, obj, cfg in out
    ]
