"""The MQTT plant bridge: a ``MachineSession`` as a node on a Mosquitto broker.

``run_bridge(session, "mqtt://HOST:PORT", node=...)`` runs until cancelled (the topic
tree is in ``drivebus.mqtt.topics``); ``python -m drivebus.mqtt CONFIG --mqtt URL`` runs
a node from a machine file. This package uses ``drivebus.app`` and the core; nothing
there imports it.
"""

from drivebus.mqtt.bridge import Bridge, BridgeOptions, run_bridge, run_configured_bridge
from drivebus.mqtt.commands import VERBS, Command, parse_command
from drivebus.mqtt.topics import PLANT_ESTOP, Topics

__all__ = [
    "PLANT_ESTOP",
    "VERBS",
    "Bridge",
    "BridgeOptions",
    "Command",
    "Topics",
    "parse_command",
    "run_bridge",
    "run_configured_bridge",
]
