"""What the service's routes share (the HTTP routes, the programs' routes and the
WebSocket): the service state, the session and the caller as FastAPI dependencies
(``Session``, ``Reader``, ``Commander``), and the problem answers every route may give.
"""

# No ``from __future__ import annotations`` here: FastAPI reads the annotations at runtime.

import itertools
from dataclasses import dataclass, field
from typing import Annotated, Any

from fastapi import Depends, Header, Request, Response
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from drivebus.app import MachineSession
from drivebus.service import problems
from drivebus.service.auth import Principal, TokenStore, require_command
from drivebus.service.encoding import EventEncoder
from drivebus.service.fanout import Fanout

__all__ = ["ERRORS", "Commander", "Reader", "ServiceState", "Session", "accepted", "reader",
           "service_state"]

_bearer = HTTPBearer(auto_error=False, description="a token from the service's token file")


@dataclass
class ServiceState:
    """What the routes share: the session, the tokens, one JSON encoder for events."""

    session: MachineSession
    tokens: TokenStore
    encoder: EventEncoder = field(default_factory=EventEncoder)
    connections: itertools.count = field(default_factory=lambda: itertools.count(1))
    fanout: Fanout = field(init=False)
    """The session's events to the WebSocket connections (run by the app's lifespan)."""

    def __post_init__(self) -> None:
        self.fanout = Fanout(self.session.events)


def service_state(request: Request) -> ServiceState:
    state: ServiceState = request.app.state.drivebus
    return state


def session_of(request: Request) -> MachineSession:
    return service_state(request).session


def reader(
    request: Request,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
    x_drivebus_client: Annotated[str | None, Header(
        description="the client's name when the service runs without tokens")] = None,
) -> Principal:
    token = None if credentials is None else credentials.credentials
    return service_state(request).tokens.authenticate(token, x_drivebus_client)


def commander(principal: Annotated[Principal, Depends(reader)]) -> Principal:
    return require_command(principal)


Session = Annotated[MachineSession, Depends(session_of)]
Reader = Annotated[Principal, Depends(reader)]
Commander = Annotated[Principal, Depends(commander)]

def error_responses() -> dict[int | str, dict[str, Any]]:
    """The problem+json answers every route may give, by status, naming the typed errors
    behind each (from ``problems.STATUS``: one place)."""
    names: dict[int, list[str]] = {401: ["Unauthorized (no or unknown bearer token)"],
                                   403: ["Forbidden (the token's scope does not allow it)"],
                                   422: ["an invalid request body"]}
    for cls, status in problems.STATUS.items():
        if status != 500:
            names.setdefault(status, []).append(cls.__name__)
    return {status: {"description": ", ".join(sorted(names[status], key=str.lower)),
                     "content": {problems.PROBLEM: {}}} for status in sorted(names)}


ERRORS = error_responses()


def accepted(response: Response, record_id: str) -> None:
    response.headers["Location"] = f"/api/motions/{record_id}"
