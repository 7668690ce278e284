"""``drivebus serve``: one machine served over HTTP and WebSocket, with a live dashboard.

Built on ``drivebus.app.MachineSession`` (the service imports the app layer and the core,
never the other way round). ``create_app`` is the FastAPI application over a session;
``open_service``/``serve``/``run`` run it with uvicorn and sibling tasks on the same
session, and stop every moving axis before they end.
"""

from drivebus.service.api import create_app
from drivebus.service.auth import AuthError, Principal, TokenStore
from drivebus.service.runner import (
    Service,
    SiblingTask,
    check_host,
    is_loopback,
    open_service,
    run,
    serve,
)

__all__ = [
    "AuthError",
    "Principal",
    "Service",
    "SiblingTask",
    "TokenStore",
    "check_host",
    "create_app",
    "is_loopback",
    "open_service",
    "run",
    "serve",
]
