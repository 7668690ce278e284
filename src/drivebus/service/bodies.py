"""Request bodies checked before the framework parses them: JSON nested too deeply.

FastAPI parses a JSON body with Python's own parser, which gives up at a nesting depth
that depends on the Python version and the stack (400 "error parsing the body" on one,
a 422 validation error on another). ``JsonDepthLimit`` reads a JSON body first and answers
one nested deeper than ``checks.MAX_JSON_DEPTH`` with a 422 ``ArgumentError`` naming the
cause, on every version; any other body reaches the application unchanged.
"""

from __future__ import annotations

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from drivebus import checks
from drivebus.errors import ArgumentError
from drivebus.service.problems import problem, problem_data

__all__ = ["JsonDepthLimit"]


def _json_body(scope: Scope) -> bool:
    """Whether FastAPI would parse this request's body as JSON (no content type, or an
    ``application/json`` or ``application/*+json`` one)."""
    for name, value in scope.get("headers", ()):
        if name == b"content-type":
            kind = value.split(b";", 1)[0].strip().lower()
            return kind == b"application/json" or (
                kind.startswith(b"application/") and kind.endswith(b"+json"))
    return True


class JsonDepthLimit:
    """ASGI middleware: a JSON request body nested too deeply is refused (422)."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or not _json_body(scope):
            await self.app(scope, receive, send)
            return
        chunks: list[bytes] = []
        while True:
            message = await receive()
            if message["type"] != "http.request":  # the client went away
                await self.app(scope, _replay([message], receive), send)
                return
            chunks.append(message.get("body", b""))
            if not message.get("more_body", False):
                break
        body = b"".join(chunks)
        try:
            checks.check_json_depth("body", body)
        except ArgumentError as exc:
            await problem(422, problem_data(exc, scope.get("path")))(scope, receive, send)
            return
        whole: Message = {"type": "http.request", "body": body, "more_body": False}
        await self.app(scope, _replay([whole], receive), send)


def _replay(first: list[Message], receive: Receive) -> Receive:
    """``receive`` that gives ``first`` again before what comes next."""
    pending = list(first)

    async def again() -> Message:
        return pending.pop(0) if pending else await receive()

    return again
