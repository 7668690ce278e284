"""JSON text of events, encoded once however many WebSocket clients receive them."""

from __future__ import annotations

import json
import math
from collections import OrderedDict
from typing import Any

from drivebus.app import Event

__all__ = ["EventEncoder", "dumps"]


def _finite(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


def dumps(data: Any) -> str:
    """Compact JSON; NaN and infinities (not JSON) become null."""
    try:
        return json.dumps(data, separators=(",", ":"), allow_nan=False)
    except ValueError:
        return json.dumps(_finite(data), separators=(",", ":"), allow_nan=False)


class EventEncoder:
    """Keeps the JSON of the most recent events: fifty watchers of one axis update cost
    one encoding, not fifty."""

    def __init__(self, size: int = 1024) -> None:
        self.size = size
        self._cache: OrderedDict[int, tuple[Event, str]] = OrderedDict()

    def encode(self, event: Event) -> str:
        """``event.data`` as JSON text."""
        key = id(event)
        hit = self._cache.get(key)
        if hit is not None and hit[0] is event:
            return hit[1]
        text = dumps(event.data)
        self._cache[key] = (event, text)  # holding the event keeps its id unique
        if len(self._cache) > self.size:
            self._cache.popitem(last=False)
        return text
