"""``drivebus serve``: one machine served over HTTP and WebSocket, with a live dashboard.

Built on ``drivebus.app.MachineSession`` (the service imports the app layer and the core,
never the other way round). ``create_app`` is the FastAPI application over a session;
``open_service``/``serve``/``run`` run it with uvicorn and sibling tasks on the same
session, and stop every moving axis before they end.
"""

import importlib
from typing import Any

_HOMES = {
    "create_app": "api",
    "AuthError": "auth", "Principal": "auth", "TokenStore": "auth",
    "Service": "runner", "SiblingTask": "runner", "check_host": "runner",
    "is_loopback": "runner", "open_service": "runner", "run": "runner", "serve": "runner",
}
"""Where each public name lives: imported on first use, so that ``drivebus.service.client``
(used by every one-shot CLI command) does not load FastAPI and uvicorn."""

__all__ = sorted(_HOMES)


def __getattr__(name: str) -> Any:
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{home}"), name)
