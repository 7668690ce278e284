"""Errors as RFC 9457 problem details (``application/problem+json``).

Every error the service answers carries the typed error's name (``title`` and ``error``),
its message (``detail``), the HTTP status and the request path (``instance``); a
``LeaseHeld`` names the ``holder``, a request that failed validation lists its
``errors``, a Modbus exception its ``code``. ``type`` is ``urn:drivebus:error:NAME``.
"""

from __future__ import annotations

import logging
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from drivebus.errors import (
    ArgumentError,
    ConfigError,
    ConnectionLost,
    DriveAlarm,
    DrivebusError,
    DriveOffline,
    LeaseHeld,
    LimitViolation,
    LineClosed,
    ModbusException,
    MotionAborted,
    MotionError,
    MotionTimeout,
    NotFound,
    NotSupported,
    PartialWrite,
    ResponseTimeout,
    StateError,
    TransactionError,
)
from drivebus.service.auth import AuthError

__all__ = ["PROBLEM", "install", "problem", "problem_data", "status_of"]

log = logging.getLogger(__name__)

PROBLEM = "application/problem+json"

_STATUS: tuple[tuple[type[DrivebusError], int], ...] = (
    (NotFound, 404),
    (LeaseHeld, 409),
    (StateError, 409),
    (MotionAborted, 409),
    (DriveAlarm, 409),
    (MotionError, 409),
    (LimitViolation, 422),
    (ArgumentError, 422),
    (ConfigError, 422),
    (NotSupported, 501),
    (DriveOffline, 503),
    (ConnectionLost, 503),
    (LineClosed, 503),
    (ResponseTimeout, 504),
    (MotionTimeout, 504),
    (ModbusException, 502),
    (PartialWrite, 502),
    (TransactionError, 502),
)
"""The first match wins: a typed error's HTTP status (anything else: 500)."""

_REASONS = {
    400: "BadRequest", 401: "Unauthorized", 403: "Forbidden", 404: "NotFound",
    405: "MethodNotAllowed", 409: "Conflict", 415: "UnsupportedMediaType",
    422: "ArgumentError", 500: "InternalError", 501: "NotSupported",
    503: "ServiceUnavailable",
}


def status_of(exc: BaseException) -> int:
    """The HTTP status for ``exc``."""
    if isinstance(exc, AuthError):
        return exc.status
    for cls, status in _STATUS:
        if isinstance(exc, cls):
            return status
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
    return data


def problem(status: int, data: dict[str, Any], headers: dict[str, str] | None = None
            ) -> JSONResponse:
    """A problem+json response."""
    return JSONResponse(data, status_code=status, media_type=PROBLEM, headers=headers)


def _respond(request: Request, exc: BaseException) -> JSONResponse:
    data = problem_data(exc, request.url.path)
    headers = None
    if isinstance(exc, AuthError) and exc.status == 401:
        headers = {"WWW-Authenticate": 'Bearer realm="drivebus"'}
    return problem(data["status"], data, headers)


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
