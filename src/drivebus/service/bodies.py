"""Request bodies checked before the framework parses them: too large, or JSON nested too
deeply.

FastAPI reads a whole body into memory and parses it in one event-loop step: a body of
15 MB held the loop for a second, and every stop and poll behind it. ``BodyLimits``
answers a body larger than ``MAX_BODY`` with a 413 ``ContentTooLarge`` problem, from its
``Content-Length`` before reading it, else once that much has come.

FastAPI parses a JSON body with Python's own parser, which gives up at a nesting depth
that depends on the Python version and the stack (400 "error parsing the body" on one,
a 422 validation error on another), and fails on an integer of 4300 digits with a 400
that names no cause. ``BodyLimits`` reads a JSON body first and answers one nested deeper
than ``checks.MAX_JSON_DEPTH``, or with a number of more digits than any float, with a
422 ``ArgumentError`` naming the cause, on every version; any other body reaches the
application unchanged.

The e-stop and ``halt`` are never refused: they take no body, and their requests go to
the application unread, whatever body they carry.
"""

from __future__ import annotations

import re

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from drivebus import checks
from drivebus.errors import ArgumentError
from drivebus.service.problems import is_json_type, problem, problem_data

__all__ = ["MAX_BODY", "NEVER_REFUSED", "BodyLimits"]

MAX_BODY = 64 * 1024
"""Largest request body (and WebSocket message) taken, bytes: the largest real one (a
parameter set, a group of targets) is a few kilobytes."""

NEVER_REFUSED = re.compile(r"(?:/[^/]+)*/api/(?:estop|axes/[^/]+/halt)")
"""The paths whose requests go through unread (whole): the e-stop and the halt of an axis,
also where the application is mounted under a prefix."""


def _json_body(scope: Scope) -> bool:
    """Whether FastAPI would parse this request's body as JSON (no content type, or an
    ``application/json`` or ``application/*+json`` one)."""
    for name, value in scope.get("headers", ()):
        if name == b"content-type":
            return is_json_type(value.decode("latin-1"))
    return True


def _declared_length(scope: Scope) -> int | None:
    """The request's ``Content-Length`` (None if absent or unreadable)."""
    for name, value in scope.get("headers", ()):
        if name == b"content-length":
            try:
                return int(value)
            except ValueError:
                return None
    return None


class BodyLimits:
    """ASGI middleware: a request body over ``MAX_BODY`` is refused (413), a JSON body
    nested too deeply too (422); the e-stop and halt go through unread."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or NEVER_REFUSED.fullmatch(scope.get("path", "")):
            await self.app(scope, receive, send)
            return
        declared = _declared_length(scope)
        if declared is not None and declared > MAX_BODY:
            await self._refuse(scope, receive, send, f"{declared} bytes")
            return
        chunks: list[bytes] = []
        size = 0
        while True:
            message = await receive()
            if message["type"] != "http.request":  # the client went away
                await self.app(scope, _replay([message], receive), send)
                return
            chunk = message.get("body", b"")
            size += len(chunk)
            if size > MAX_BODY:
                await self._refuse(scope, receive, send, f"more than {MAX_BODY} bytes")
                return
            chunks.append(chunk)
            if not message.get("more_body", False):
                break
        body = b"".join(chunks)
        if _json_body(scope):
            try:
                checks.check_json_depth("body", body)
                checks.check_json_numbers("body", body)
            except ArgumentError as exc:
                await problem(422, problem_data(exc, scope.get("path")))(scope, receive, send)
                return
        whole: Message = {"type": "http.request", "body": body, "more_body": False}
        await self.app(scope, _replay([whole], receive), send)

    @staticmethod
    async def _refuse(scope: Scope, receive: Receive, send: Send, size: str) -> None:
        name = "ContentTooLarge"
        data = {"type": f"urn:drivebus:error:{name}", "title": name, "status": 413,
                "detail": f"the request body is {size}; at most {MAX_BODY} are taken",
                "error": name, "instance": scope.get("path")}
        await problem(413, data, {"Connection": "close"})(scope, receive, send)


def _replay(first: list[Message], receive: Receive) -> Receive:
    """``receive`` that gives ``first`` again before what comes next."""
    pending = list(first)

    async def again() -> Message:
        return pending.pop(0) if pending else await receive()

    return again
