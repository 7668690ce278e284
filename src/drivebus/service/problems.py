"""Errors as RFC 9457 problem details (``application/problem+json``).

Every error the service answers carries the typed error's name (``title`` and ``error``),
its message (``detail``), the HTTP status and the request path (``instance``); a
``LeaseHeld`` names the ``holder``, a request that failed validation lists its
``errors``, a Modbus exception its ``code``, a ``GroupMotionError`` the ``axis`` that
failed and its ``cause``. ``type`` is ``urn:drivebus:error:NAME``. Each typed error has
its status in ``STATUS`` (timeouts 504, an absent drive or line 503, a drive's wrong
answer 502, ...); nothing drivebus raises on purpose is a 500.
"""

from __future__ import annotations

import logging
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from drivebus.drives.cia402 import StatuswordError
from drivebus.drives.expr import ExprError
from drivebus.errors import (
    ArgumentError,
    ConfigError,
    ConnectionLost,
    DriveAlarm,
    DrivebusError,
    DriveOffline,
    FrameError,
    GroupMotionError,
    InputTimeout,
    LeaseHeld,
    LimitViolation,
    LineClosed,
    LineConfigError,
    LineNoise,
    ModbusException,
    MotionAborted,
    MotionError,
    MotionTimeout,
    NotFound,
    NotSupported,
    PartialWrite,
    ResponseTimeout,
    ServiceUnreachable,
    StateError,
    TransactionError,
    UnknownMethod,
    WrongResponder,
)
from drivebus.service.auth import AuthError

__all__ = ["PROBLEM", "STATUS", "install", "is_json_type", "problem", "problem_data",
           "problem_response", "status_of"]

log = logging.getLogger(__name__)

PROBLEM = "application/problem+json"

STATUS: dict[type[DrivebusError], int] = {
    # the request cannot be carried out as asked: nothing was sent
    ArgumentError: 422, ConfigError: 422, LineConfigError: 422, ExprError: 422,
    LimitViolation: 422,
    NotFound: 404,
    # the machine's state (or another client) stands in the way, or a motion ended early
    LeaseHeld: 409, StateError: 409, MotionAborted: 409, MotionError: 409, DriveAlarm: 409,
    GroupMotionError: 409,  # with a typed cause: the cause's status
    NotSupported: 501, UnknownMethod: 501,
    # the drive (or the line) answered, but not with what was asked
    TransactionError: 502, ModbusException: 502, FrameError: 502, LineNoise: 502,
    WrongResponder: 502, StatuswordError: 502, PartialWrite: 502,
    # the drive, the line or a service is not there
    DriveOffline: 503, ConnectionLost: 503, LineClosed: 503, ServiceUnreachable: 503,
    # no answer in time
    ResponseTimeout: 504, MotionTimeout: 504, InputTimeout: 504,
    # an error without a type says nothing a client can act on
    DrivebusError: 500,
}
"""Each typed error's HTTP status; a class not listed gets its nearest listed base's
(the first in its MRO). docs/guide/service.md has the same table, and a test walks every
``DrivebusError`` subclass against both."""

_REASONS = {
    400: "BadRequest", 401: "Unauthorized", 403: "Forbidden", 404: "NotFound",
    405: "MethodNotAllowed", 409: "Conflict", 413: "ContentTooLarge",
    415: "UnsupportedMediaType",
    422: "ArgumentError", 500: "InternalError", 501: "NotSupported", 502: "BadGateway",
    503: "ServiceUnavailable", 504: "GatewayTimeout",
}


def status_of(exc: BaseException) -> int:
    """The HTTP status for ``exc``."""
    if isinstance(exc, AuthError):
        return exc.status
    if isinstance(exc, GroupMotionError) and isinstance(exc.__cause__, DrivebusError):
        return status_of(exc.__cause__)  # the axis's failure says what went wrong
    for cls in type(exc).__mro__:
        if cls in STATUS:
            return STATUS[cls]  # type: ignore[index]
    return 500


def problem_data(exc: BaseException, instance: str | None = None) -> dict[str, Any]:
    """``exc`` as problem details (also used in WebSocket replies)."""
    status = status_of(exc)
    if isinstance(exc, AuthError):
        name = exc.name
    elif isinstance(exc, DrivebusError):
        name = type(exc).__name__
    else:
        name = "InternalError"
    detail = str(exc) if isinstance(exc, DrivebusError | AuthError) else (
        "internal error: see the service's log")
    data: dict[str, Any] = {
        "type": f"urn:drivebus:error:{name}",
        "title": name,
        "status": status,
        "detail": detail,
        "error": name,
    }
    if instance is not None:
        data["instance"] = instance
    if isinstance(exc, LeaseHeld):
        data["holder"] = exc.holder
    if isinstance(exc, ModbusException):
        data["code"], data["function"] = exc.code, exc.function
    if isinstance(exc, TransactionError) and exc.slave is not None:
        data["slave"] = exc.slave
    if isinstance(exc, GroupMotionError):
        data["axis"] = exc.axis
        cause = exc.__cause__
        if isinstance(cause, DrivebusError):
            data["cause"] = {"error": type(cause).__name__, "detail": str(cause)}
    return data


def is_json_type(content_type: str) -> bool:
    """Whether a ``Content-Type`` is JSON's: ``application/json`` or ``application/*+json``
    (parameters such as ``charset`` aside)."""
    base = content_type.split(";", 1)[0].strip().lower()
    return base == "application/json" or (
        base.startswith("application/") and base.endswith("+json"))


def _not_json(content_type: str | None) -> str | None:
    """What a request's content type is if it is not JSON's (None if it is)."""
    if content_type is None:
        return "no Content-Type"
    return None if is_json_type(content_type) else f"Content-Type {content_type!r}"


def problem(status: int, data: dict[str, Any], headers: dict[str, str] | None = None
            ) -> JSONResponse:
    """A problem+json response."""
    return JSONResponse(data, status_code=status, media_type=PROBLEM, headers=headers)


def problem_response(exc: BaseException, instance: str | None = None) -> JSONResponse:
    """``exc`` as a problem+json response (a 401 with ``WWW-Authenticate``): what an
    HTTP route answers, and what a WebSocket handshake is refused with."""
    data = problem_data(exc, instance)
    headers = None
    if isinstance(exc, AuthError) and exc.status == 401:
        headers = {"WWW-Authenticate": 'Bearer realm="drivebus"'}
    return problem(data["status"], data, headers)


def _respond(request: Request, exc: BaseException) -> JSONResponse:
    return problem_response(exc, request.url.path)


def install(app: FastAPI) -> None:
    """Make every error ``app`` answers a problem+json response."""

    @app.exception_handler(DrivebusError)
    async def drivebus_error(request: Request, exc: DrivebusError) -> JSONResponse:
        if status_of(exc) == 500:
            log.error("%s %s: %s: %s", request.method, request.url.path,
                      type(exc).__name__, exc)
        return _respond(request, exc)

    @app.exception_handler(AuthError)
    async def auth_error(request: Request, exc: AuthError) -> JSONResponse:
        return _respond(request, exc)

    @app.exception_handler(RequestValidationError)
    async def invalid(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = [
            {"loc": list(e.get("loc", ())), "msg": e.get("msg", ""), "type": e.get("type", "")}
            for e in exc.errors()
        ]
        detail = "; ".join(
            f"{'.'.join(str(p) for p in e['loc'][1:]) or 'body'}: {e['msg']}" for e in errors
        ) or "invalid request"
        kind = _not_json(request.headers.get("content-type"))
        if kind and any(e["loc"] == ["body"] and e["type"] != "missing" for e in errors):
            detail = (f"body: not read as JSON ({kind}): send it with "
                      f"'Content-Type: application/json'")
        data = {
            "type": "urn:drivebus:error:ArgumentError",
            "title": "ArgumentError",
            "status": 422,
            "detail": detail,
            "error": "ArgumentError",
            "instance": request.url.path,
            "errors": errors,
        }
        return problem(422, data)

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        name = _REASONS.get(exc.status_code, f"HTTP{exc.status_code}")
        data = {
            "type": f"urn:drivebus:error:{name}",
            "title": name,
            "status": exc.status_code,
            "detail": str(exc.detail),
            "error": name,
            "instance": request.url.path,
        }
        return problem(exc.status_code, data, dict(exc.headers or {}) or None)

    @app.exception_handler(Exception)
    async def internal(request: Request, exc: Exception) -> JSONResponse:
        log.exception("%s %s failed", request.method, request.url.path)
        return _respond(request, exc)
