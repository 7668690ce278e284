"""The bridge's topic tree, fixed so that other tools can rely on it.

```
drivebus/<node>/status                    retained "online"; the last will sets "offline"
drivebus/<node>/axes/<axis>/state         retained JSON, on change, at most state_rate/s
drivebus/<node>/axes/<axis>/cmd/<verb>    JSON commands: move home jog stop halt enable
                                          disable reset override set_output
drivebus/<node>/replies                   replies to commands without a response topic
drivebus/<node>/estop                     e-stop of this node (any payload)
drivebus/estop                            plant-wide e-stop (any payload)
drivebus/<node>/bus/<line>/stats          line statistics at a low rate
homeassistant/<component>/drivebus_<node>/<object>/config   discovery (retained)
```
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from drivebus.config import NODE_PATTERN
from drivebus.errors import ConfigError

__all__ = ["PLANT_ESTOP", "PREFIX", "Topics", "check_node"]

PREFIX = "drivebus"
PLANT_ESTOP = f"{PREFIX}/estop"
"""The plant-wide e-stop: every node halts every axis on a message here."""


def check_node(node: object) -> str:
    """``node`` if it is a usable node name (one topic level: letters, digits, ``_``,
    ``-``); else ``ConfigError`` naming it."""
    if not isinstance(node, str) or not re.fullmatch(NODE_PATTERN, node):
        raise ConfigError(
            f"node name {node!r}: use 1..64 letters, digits, '_' or '-' (it is an MQTT "
            f"topic level; set it with --node or [mqtt] node)"
        )
    return node


@dataclass(frozen=True)
class Topics:
    """The topics of one node."""

    node: str

    @property
    def base(self) -> str:
        """``drivebus/<node>``."""
        return f"{PREFIX}/{self.node}"

    @property
    def status(self) -> str:
        """Retained ``online``/``offline``."""
        return f"{self.base}/status"

    @property
    def replies(self) -> str:
        """Replies to commands that gave no MQTT 5 response topic."""
        return f"{self.base}/replies"

    @property
    def estop(self) -> str:
        """This node's e-stop."""
        return f"{self.base}/estop"

    @property
    def commands(self) -> str:
        """The subscription that takes every axis command of this node."""
        return f"{self.base}/axes/+/cmd/+"

    def state(self, axis: str) -> str:
        """An axis's retained state."""
        return f"{self.base}/axes/{axis}/state"

    def command(self, axis: str, verb: str) -> str:
        """Where a command ``verb`` for ``axis`` is published."""
        return f"{self.base}/axes/{axis}/cmd/{verb}"

    def stats(self, line: str) -> str:
        """A line's statistics."""
        return f"{self.base}/bus/{line}/stats"

    def parse_command(self, topic: str) -> tuple[str, str] | None:
        """``(axis, verb)`` of a command topic of this node, else None."""
        parts = topic.split("/")
        if (len(parts) == 6 and parts[0] == PREFIX and parts[1] == self.node
                and parts[2] == "axes" and parts[4] == "cmd"):
            return parts[3], parts[5]
        return None

    def is_estop(self, topic: str) -> bool:
        """True for this node's e-stop topic and the plant-wide one."""
        return topic in (self.estop, PLANT_ESTOP)
